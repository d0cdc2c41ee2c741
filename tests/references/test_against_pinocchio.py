"""Every registered formalism against the external Pinocchio reference (``crosscheck.references.pinocchio.reference``).

Parametrized over formalism x case, at Hypothesis-drawn states: q in [-pi, pi] for revolute and [-0.5, 0.5]
for prismatic joints, qd in [-5, 5], u in [-20, 20]. drift, ctrl and total must agree within
``1e-10 * accel_scale`` (Split.accel_scale: ||M^-1|| times the size of the summed forces, the size of the
accelerations the summed terms could produce, taken from the reference); ``power_ctrl`` must equal ``u . (B^T qd)``
computed here.
``task_drift``, where a formalism supplies it, must match Pinocchio's classical frame acceleration at zero torque
within ``1e-10 * L (accel_scale + |qd|_1^2)`` (crosscheck.core.tolerance, task scale). A state where the formalism
reports a BREAKDOWN (crosscheck.core.tolerance.breakdown, e.g. a singular task Jacobian) is not compared: that it is
flagged there instead is tested with the backend.
A new formalism in ``formalisms.names()`` is picked up automatically.

Run time: the first Euler–Lagrange evaluation of ``panda`` derives and compiles it (about 8 s); later runs load
the generated source from the disk cache. The ``ci`` profile keeps the example count modest.
"""

from __future__ import annotations

import functools

import numpy as np
import pytest
from hypothesis import given
from hypothesis import strategies as st

import cases
import formalisms
from crosscheck.references.pinocchio import reference
from crosscheck.core import tolerance as policy
from formalisms.interface import Unsupported

CASES = {
    "double_pendulum": {},
    "n_link_pendulum": {"n": 4},
    "acrobot": {},
    "spatial_arm": {},
    "panda": {},
}
REL_TOL = 1e-10


@functools.lru_cache(maxsize=None)
def model_of(name):
    return cases.load(name, **CASES[name])


def state_strategy(model):
    q = st.tuples(*[st.floats(-np.pi, np.pi) if b.joint == "revolute" else st.floats(-0.5, 0.5)
                    for b in model.bodies])
    qd = st.tuples(*[st.floats(-5.0, 5.0)] * model.n)
    u = st.tuples(*[st.floats(-20.0, 20.0)] * model.m)
    return st.tuples(q, qd, u).map(lambda t: tuple(np.array(x, dtype=float) for x in t))


def accel_scale(model, ref, u):
    """The reference's ``accel_scale`` (``Split.accel_scale``); + 1e-290 keeps the tolerance above 1e-300,
    where results are subnormal (no relative precision left)."""
    return ref.accel_scale + 1e-290


def test_every_case_has_a_joint_range():
    for name in CASES:
        model = model_of(name)
        assert {b.joint for b in model.bodies} <= {"revolute", "prismatic"}, name
    assert any(b.joint == "prismatic" for b in model_of("spatial_arm").bodies)
    assert any(b.joint == "prismatic" for b in model_of("panda").bodies)


def test_every_formalism_is_compared():
    assert formalisms.names(), "no formalism registered: this file would compare nothing"


@pytest.mark.parametrize("case", list(CASES))
@pytest.mark.parametrize("formalism", formalisms.names())
@given(data=st.data())
def test_split_agrees_with_pinocchio(formalism, case, data):
    model = model_of(case)
    q, qd, u = data.draw(state_strategy(model), label="q, qd, u")
    ref = reference.split(model, q, qd, u)
    got = formalisms.get(formalism).split(model, q, qd, u)
    if policy.breakdown(got):
        return
    tol = REL_TOL * accel_scale(model, ref, u)
    for quantity in ("drift", "ctrl", "total"):
        a, b = np.asarray(got.quantity(quantity)), np.asarray(ref.quantity(quantity))
        assert a.shape == b.shape == (model.n,), f"{formalism} {quantity} shape {a.shape}"
        err = np.abs(a - b).max()
        assert err <= tol, (f"{formalism} vs pinocchio on {case}: {quantity} differs by {err:.3e} "
                            f"(tolerance {tol:.3e} = {REL_TOL:g} * accel_scale {tol / REL_TOL:.3e})\n"
                            f"  q = {q.tolist()}\n  qd = {qd.tolist()}\n  u = {u.tolist()}\n"
                            f"  {formalism}: {a.tolist()}\n  pinocchio: {b.tolist()}")

    if not isinstance(got.task_drift, Unsupported):
        at = policy.scales([ref], model, q, qd)
        task_tol = REL_TOL * at.lever * (at.accel_scale + at.rate_sq) + 1e-290
        err = np.abs(np.asarray(got.task_drift) - ref.task_drift).max()
        assert err <= task_tol, (f"{formalism} vs pinocchio on {case}: task_drift differs by {err:.3e} "
                                 f"(tolerance {task_tol:.3e})\n  q = {q.tolist()}\n  qd = {qd.tolist()}\n"
                                 f"  {formalism}: {got.task_drift.tolist()}\n  pinocchio: {ref.task_drift.tolist()}")

    tau_ctrl = model.input_map @ u
    expected_power = float(tau_ctrl @ qd)
    power_tol = 1e-12 * (np.abs(tau_ctrl) @ np.abs(qd)) + 1e-300
    assert abs(got.power_ctrl - expected_power) <= power_tol, (
        f"{formalism} power_ctrl {got.power_ctrl!r} != u . (B^T qd) = {expected_power!r}")
    assert abs(got.power_ctrl - ref.power_ctrl) <= power_tol
    np.testing.assert_allclose(got.power_ctrl_per_coord, tau_ctrl * qd, rtol=1e-13, atol=1e-300)


@pytest.mark.parametrize("formalism", formalisms.names())
def test_the_comparison_can_fail(formalism):
    """A wrong answer is caught at this tolerance: the formalism on a model with a 1 % heavier link vs the
    reference on the original (at a fixed generic state)."""
    model = model_of("spatial_arm")
    bodies = list(model.bodies)
    b = bodies[2]
    bodies[2] = type(b)(b.name, b.parent, b.joint, b.axis, b.mass * 1.01, b.com, b.inertia, b.rotation,
                        b.translation)
    heavier = cases.build_model("spatial_arm_heavier", bodies, gravity=model.gravity,
                                task_points=model.task_points)
    rng = np.random.default_rng(1)
    q, qd, u = rng.uniform(-1, 1, 6), rng.uniform(-2, 2, 6), rng.uniform(-5, 5, 6)
    ref = reference.split(model, q, qd, u)
    got = formalisms.get(formalism).split(heavier, q, qd, u)
    assert np.abs(got.total - ref.total).max() > REL_TOL * ref.accel_scale * 1e3
