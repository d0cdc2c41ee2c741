"""Spherical and free joints in the Euler–Lagrange backend (``formalisms/euler_lagrange.py``, module docstring
"Group joints"): the Lagrangian in local exponential coordinates ``q (+) xi`` around the state, evaluated at
``xi = 0`` (article 2.1-2.2, 6.2, 6.4).

* The four Lie-group cases (``free_body``, ``ball_pendulum``, ``ball_double_pendulum``, ``satellite_arm``) and two
  constrained variants written here, at sampled states, against the Pinocchio reference on every field the backend
  reports (:func:`assert_agrees_with_reference`: relative ``RTOL`` of each field's scale); the fields it does not
  report (task and joint-load quantities) are UNSUPPORTED, as on every model.
* Hypothesis: random trees with revolute, prismatic, spherical and free joints, unconstrained or not, against the
  reference (every field) and through the gate's own comparison (``testing.assert_backends_agree``).
* ``split_batch`` rows equal ``split``.
* The free body obeys Euler's equations at its centre of mass under the drift (closed form written here, with and
  without gravity), and its mass matrix is the spatial inertia at the body origin (closed form).
* ``terms`` (M, C qd, g) is Pinocchio's CRBA, ``rnea(q, v, 0) - g`` and ``rnea(q, 0, 0)`` in this chart.
* The claims the chart rests on: ``d/dt v = xi_ddot`` at ``xi = 0`` (finite differences of the harness's own
  ``cases.configuration.integrate``, not of the backend; away from 0 the same check sees the difference), and the
  exponential series truncated after the second order is exact at ``xi = 0`` (orders 3 and 4 give the same numbers,
  order 1 does not).
* The chart is part of the disk-cache key; charts ``q = psi(p)`` of scalar coordinates are refused
  (ModelNotSupported); derivation time.
* The zyx chart (``crosscheck.checks.charts.EulerZYX``, issue 17): ``split_chart`` derived in Euler angles through
  ``R(quat(psi(p)))`` against the reference mapped into the chart with the harness's Dpsi (cases, constrained
  variants, solo12_standing, random trees), the gate's own chart check (with solo12), M_p in closed form, its
  cache entry, charts that are not charts of the group refused, and cold derivation time in the chart.

All derivations go to a scratch cache (fixture ``fresh_derivation_cache``), so they test the current code.
"""

from __future__ import annotations

import functools
import math
import time

import numpy as np
import pytest
from hypothesis import assume, given, settings
from hypothesis import strategies as st

import cases
from cases import PointOnCircle, PointsCoincide, build_model
from cases import configuration as geometry  # the harness's group operations (the backend has its own)
from crosscheck.checks import charts
from crosscheck.references.pinocchio import kinematics
from crosscheck.references.pinocchio import reference
from crosscheck.core import sampling
from crosscheck import testing
from crosscheck.core import tolerance as policy
from formalisms import euler_lagrange as el
from formalisms.interface import ModelNotSupported, Unsupported

pytestmark = pytest.mark.usefixtures("fresh_derivation_cache")  # conftest.py: derive afresh, into a scratch cache

GROUP_CASES = ("free_body", "ball_pendulum", "ball_double_pendulum", "satellite_arm")
CONSTRAINED_CASES = ("ball_double_pendulum_on_cylinder", "satellite_arm_docked")
#: Relative tolerance of every compared field, in units of that field's scale (:func:`assert_agrees_with_reference`).
RTOL = 1e-9
EPS = np.finfo(float).eps


def _constrained(name: str, base: str, *constraints) -> cases.Model:
    m = cases.load(base)
    return build_model(name, m.bodies, gravity=m.gravity, input_map=m.input_map, task_points=m.task_points,
                       constraints=constraints)


@functools.lru_cache(maxsize=None)
def model_of(name: str) -> cases.Model:
    """A registered case, or one of the constrained variants: the ball double pendulum's hand on a vertical cylinder
    (1 row below two ball joints), the satellite arm's gripper docked at a world point (3 rows closing a loop through
    the free base)."""
    if name == "ball_double_pendulum_on_cylinder":
        return _constrained(name, "ball_double_pendulum",
                            PointOnCircle("cylinder", "lower", (0.0, 0.0, -0.5), (0.0, 0.0, 0.0), 0.5))
    if name == "satellite_arm_docked":
        return _constrained(name, "satellite_arm",
                            PointsCoincide("dock", "extension", (0.25, 0.0, 0.0), None, (1.0, 0.2, 0.3)))
    return cases.load(name)


def states_of(model: cases.Model, count: int = 4, seed: int = 17):
    return [tuple(np.array(x, dtype=float) for x in (s.q, s.qd, s.u))
            for s in sampling.sample_states(model, count, seed, model.name)]


# ----------------------------------------------------------------------------------------------------------
# Every field against the reference
# ----------------------------------------------------------------------------------------------------------

def _relative_scale(value: float, condition: float = 1.0) -> float:
    """The scale of a conditioning number: itself, widened by ``1e-6 condition`` for a value computed from extreme
    eigenvalues (bisection or SVD: each has an absolute error of eps times the largest, so a relative one of eps
    times the condition number)."""
    return abs(value) * (1.0 + 1e-6 * condition)


def assert_agrees_with_reference(model, q, qd, u, evaluated=None) -> dict[str, float]:
    """The backend's split against ``crosscheck.references.pinocchio.reference.split`` on every field it reports, each
    within ``RTOL`` of its scale: accelerations of ``accel_scale``; powers of ``|B u| . |qd|``; T of itself; ``cond_M``,
    ``accel_scale``, the conditions and ``lam_scale`` relatively; multipliers of ``lam_scale``; constraint forces of
    ``||Jc|| lam_scale``; phi, Jc of the length scale L; ``Jc qd`` of ``L |qd|``; ``Jcdot qd`` of ``L |qd|^2``.
    Multipliers and the rank are compared where neither side reports a constraint BREAKDOWN (they are not unique
    there). Returns each field's error over its scale. ``evaluated``: the model the backend is given (default
    ``model``, a changed one to show the comparison can fail)."""
    got, ref = el.split(evaluated or model, q, qd, u), reference.split(model, q, qd, u)
    errors: dict[str, float] = {}

    def check(name, a, b, scale):
        a, b = np.asarray(a, dtype=float), np.asarray(b, dtype=float)
        assert a.shape == b.shape, f"{model.name} {name}: shape {a.shape} against the reference's {b.shape}"
        if a.size and np.all(np.isinf(a) & (a == b)):
            return
        err = float(np.max(np.abs(a - b), initial=0.0))
        errors[name] = err / (scale + 1e-300)
        assert err <= RTOL * scale + 1e-300, (
            f"{model.name} {name}: differs by {err:.3e} (tolerance {RTOL * scale:.3e})\n  q = {q.tolist()}\n"
            f"  qd = {qd.tolist()}\n  u = {u.tolist()}\n  euler_lagrange: {a.tolist()}\n  pinocchio: {b.tolist()}")

    tau = model.input_map @ u
    for name in ("drift", "ctrl", "total"):
        check(name, getattr(got, name), getattr(ref, name), ref.accel_scale)
    power = float(np.abs(tau) @ np.abs(qd))
    check("power_ctrl", got.power_ctrl, ref.power_ctrl, power)
    check("power_ctrl_per_coord", got.power_ctrl_per_coord, ref.power_ctrl_per_coord, power)
    check("kinetic_energy", got.kinetic_energy, ref.kinetic_energy, ref.kinetic_energy)
    check("cond_M", got.cond_M, ref.cond_M, _relative_scale(ref.cond_M, ref.cond_M))
    check("accel_scale", got.accel_scale, ref.accel_scale, _relative_scale(ref.accel_scale, ref.cond_M))
    for name in ("task_drift", "joint_wrenches", "joint_wrenches_drift", "task_inertia"):
        assert isinstance(getattr(got, name), Unsupported), f"{name} is reported: compare it here"
    if not model.constraints:
        assert got.lam is ref.lam is None and got.power_constr is ref.power_constr is None
        assert got.constraint_jacobian is None and not got.conditions
        return errors

    broken = bool(policy.breakdown(got) or policy.breakdown(ref))
    cond_S = ref.conditions["constraint_kept"]  # what the solve amplifies (finite even where S is singular)
    for key, value in got.conditions.items():
        if key == "constraint_consistency":
            check(f"conditions[{key}]", value, ref.conditions[key], 1.0)
        elif not broken:
            check(f"conditions[{key}]", value, ref.conditions[key], _relative_scale(ref.conditions[key], cond_S))
    L = model.length_scale
    jc_norm = float(np.linalg.norm(ref.constraint_jacobian, 2))
    rate = float(np.abs(qd).sum())
    check("constraint_value", got.constraint_value, ref.constraint_value, L)
    check("constraint_jacobian", got.constraint_jacobian, ref.constraint_jacobian, L)
    check("constraint_velocity", got.constraint_velocity, ref.constraint_velocity, L * rate)
    check("constraint_bias", got.constraint_bias, ref.constraint_bias, L * rate**2)
    force = jc_norm * ref.lam_scale * (1.0 + 1e-6 * cond_S)
    for name in ("constraint_force", "constraint_force_drift"):
        check(name, getattr(got, name), getattr(ref, name), force)
    check("power_constr", got.power_constr, ref.power_constr, force * rate)
    check("power_constr_per_coord", got.power_constr_per_coord, ref.power_constr_per_coord, force * rate)
    if not broken:
        assert got.constraint_rank == ref.constraint_rank
        check("lam_scale", got.lam_scale, ref.lam_scale, _relative_scale(ref.lam_scale, cond_S))
        for name in ("lam", "lam_drift"):
            check(name, getattr(got, name), getattr(ref, name), ref.lam_scale * (1.0 + 1e-6 * cond_S))
    return errors


@pytest.mark.parametrize("name", GROUP_CASES + CONSTRAINED_CASES)
def test_cases_agree_with_the_reference_on_every_field(name):
    model = model_of(name)
    assert model.group_joints
    for q, qd, u in states_of(model, count=5):
        assert_agrees_with_reference(model, q, qd, u)


@settings(max_examples=15)
@given(data=st.data())
def test_random_trees_with_group_joints_agree_with_the_reference(data):
    model = data.draw(testing.models(max_bodies=4, group=True, constraints=None), label="model")
    assume(model.group_joints)
    state = data.draw(testing.states(model), label="state")
    assert_agrees_with_reference(model, *(np.array(x, dtype=float) for x in (state.q, state.qd, state.u)))
    testing.assert_backends_agree(model, state, backends=["euler_lagrange", "pinocchio"])


@settings(max_examples=8)
@given(data=st.data())
def test_random_constrained_trees_with_group_joints_agree_with_the_reference(data):
    """``constraints=None`` rarely draws a constraint, so the constraint fields get a property of their own."""
    model = data.draw(testing.models(max_bodies=4, group=True, constraints=True), label="model")
    assume(model.group_joints)
    state = data.draw(testing.states(model), label="state")
    assert_agrees_with_reference(model, *(np.array(x, dtype=float) for x in (state.q, state.qd, state.u)))
    testing.assert_backends_agree(model, state, backends=["euler_lagrange", "pinocchio"])


def test_the_comparison_can_fail(change=1e-6):
    """The reference comparison sees a relative change of 1e-6 of one principal moment of the free body."""
    model = model_of("free_body")
    b = model.bodies[0]
    inertia = b.inertia.copy()
    inertia[0, 0] *= 1.0 + change
    changed = build_model("free_body", [type(b)(b.name, b.parent, b.joint, b.axis, b.mass, b.com, inertia,
                                                b.rotation, b.translation)], gravity=model.gravity)
    q, qd, u = states_of(model)[1]
    with pytest.raises(AssertionError, match="free_body [a-z_]+: differs"):
        assert_agrees_with_reference(model, q, qd, u, evaluated=changed)


# ----------------------------------------------------------------------------------------------------------
# Batches
# ----------------------------------------------------------------------------------------------------------

@pytest.mark.parametrize("name", GROUP_CASES + CONSTRAINED_CASES)
def test_split_batch_rows_equal_split(name):
    model = model_of(name)
    Q, QD, U = (np.array(column) for column in zip(*states_of(model, count=6, seed=5)))
    batch = el.split_batch(model, Q, QD, U)
    assert batch.drift.shape == (len(Q), model.nv)
    for i in range(len(Q)):
        s = el.split(model, Q[i], QD[i], U[i])
        tol = 100 * EPS * s.cond_M * s.accel_scale
        for field in ("drift", "ctrl", "total"):
            np.testing.assert_allclose(getattr(batch, field)[i], getattr(s, field), rtol=0, atol=tol)
        if model.k:
            for field in ("lam", "lam_drift"):
                np.testing.assert_allclose(getattr(batch, field)[i], getattr(s, field), rtol=0,
                                           atol=100 * EPS * s.cond_M * s.lam_scale)
        else:
            assert batch.lam is None


# ----------------------------------------------------------------------------------------------------------
# Closed forms: the free body (Euler's equations) and its spatial inertia
# ----------------------------------------------------------------------------------------------------------

def _hat(w):
    return np.array([[0.0, -w[2], w[1]], [w[2], 0.0, -w[0]], [-w[1], w[0], 0.0]])


def _rotation(quat):
    """``R(quat)`` of a unit quaternion (x, y, z, w), written here (Rodrigues: angle 2 atan2(|u|, w))."""
    u, w = np.asarray(quat[:3]), quat[3]
    s = np.linalg.norm(u)
    if s == 0.0:
        return np.eye(3)
    angle, K = 2.0 * math.atan2(s, w), _hat(u / s)
    return np.eye(3) + math.sin(angle) * K + (1.0 - math.cos(angle)) * K @ K


def euler_drift(q, qd, m, com, inertia, gravity):
    """The free body's drift (body twist derivative at the body origin) in closed form: Euler's equations at the
    COM, ``I wd + w x I w = 0`` (torque-free: gravity acts at the COM), and the COM accelerating with gravity,
    ``d/dt [R (v + w x c)] = gravity``, i.e. ``vd = R^T gravity - w x v - w x (w x c) - wd x c``."""
    R = _rotation(q[3:7])
    v, w = qd[:3], qd[3:]
    wd = -np.linalg.solve(inertia, np.cross(w, inertia @ w))
    vd = R.T @ gravity - np.cross(w, v) - np.cross(w, np.cross(w, com)) - np.cross(wd, com)
    return np.concatenate([vd, wd])


@pytest.mark.parametrize("g", [0.0, 9.81])
def test_free_body_obeys_eulers_equations(g):
    model = cases.load("free_body", g=g)
    (b,) = model.bodies
    for q, qd, u in states_of(model, count=6, seed=23):
        s = el.split(model, q, qd, u)
        expected = euler_drift(q, qd, b.mass, b.com, b.inertia, model.gravity)
        scale = s.accel_scale
        assert np.abs(s.drift - expected).max() <= 1e-12 * scale, (s.drift, expected)
        assert np.abs(s.ctrl - np.linalg.solve(spatial_inertia(b.mass, b.com, b.inertia), u)).max() <= 1e-12 * scale


def spatial_inertia(m, c, inertia):
    """The body's spatial inertia at its origin in the body frame, twist order (linear, angular):
    ``[[m 1, -m [c]x], [m [c]x, I_c - m [c]x^2]]`` (``T = 1/2 m |v + w x c|^2 + 1/2 w^T I_c w``)."""
    C = _hat(c)
    return np.block([[m * np.eye(3), -m * C], [m * C, inertia - m * C @ C]])


def test_free_body_mass_matrix_is_the_spatial_inertia_everywhere():
    model = model_of("free_body")
    (b,) = model.bodies
    expected = spatial_inertia(b.mass, b.com, b.inertia)
    for q, qd, _ in states_of(model):
        M, _, g = el.terms(model, q, qd)
        np.testing.assert_allclose(M, expected, rtol=0, atol=1e-15 * np.abs(expected).max())
        assert not np.any(g)


# ----------------------------------------------------------------------------------------------------------
# terms(): the local chart's M, C qd, g are the reference's v-space ones
# ----------------------------------------------------------------------------------------------------------

@pytest.mark.parametrize("name", GROUP_CASES)
def test_terms_are_the_reference_terms_in_velocity_space(name):
    model = model_of(name)
    for q, qd, _ in states_of(model):
        M, Cqd, g = el.terms(model, q, qd)
        M_ref = kinematics.mass_matrix(model, q)
        Cqd_ref, g_ref = kinematics.bias_forces(model, q, qd)
        size = np.linalg.norm(M_ref, 2)
        np.testing.assert_allclose(M, M_ref, rtol=0, atol=1e-13 * size)
        np.testing.assert_allclose(Cqd, Cqd_ref, rtol=0, atol=1e-12 * size * (1.0 + float(qd @ qd)))
        weight = np.abs(model.gravity).sum() * math.sqrt(sum(b.mass for b in model.bodies) * size)
        np.testing.assert_allclose(g, g_ref, rtol=0, atol=1e-12 * weight + 1e-300)


# ----------------------------------------------------------------------------------------------------------
# The claims the chart rests on
# ----------------------------------------------------------------------------------------------------------

def _pose(model, q):
    """``(R, p)`` of the single group joint of ``model`` at ``q`` (harness geometry: ``cases.configuration``)."""
    if model.bodies[0].joint == "free":
        return geometry.rotation(q[3:7]), q[:3]
    return geometry.rotation(q[:4]), np.zeros(3)


def _velocity(model, q_of, t, h=1e-5):
    """The joint velocity v at time t of the motion ``q_of(t)``, by central differences: ``[w] = R^T Rdot``, for a
    free joint ``(R^T pdot, w)``."""
    (Ra, pa), (Rb, pb) = _pose(model, q_of(t - h)), _pose(model, q_of(t + h))
    R, _ = _pose(model, q_of(t))
    W = R.T @ (Rb - Ra) / (2 * h)
    w = 0.5 * np.array([W[2, 1] - W[1, 2], W[0, 2] - W[2, 0], W[1, 0] - W[0, 1]])
    return np.concatenate([R.T @ (pb - pa) / (2 * h), w]) if model.bodies[0].joint == "free" else w


def _acceleration(model, q_of, h=1e-3):
    """``d/dt v`` at t = 0 by a Richardson-extrapolated central difference of :func:`_velocity`."""
    def central(step):
        return (_velocity(model, q_of, step) - _velocity(model, q_of, -step)) / (2 * step)
    return (4 * central(h / 2) - central(h)) / 3


@pytest.mark.parametrize("name", ["ball_pendulum", "free_body"])
def test_velocity_derivative_is_the_second_derivative_of_xi_at_the_origin(name):
    """The module docstring's claim: along ``q(t) = q0 (+) xi(t)`` with ``xi(t) = a t + b t^2 / 2`` (so ``xi(0) = 0``,
    ``xid = a``, ``xidd = b``), ``v(0) = a`` and ``d/dt v (0) = b`` exactly (dexp(0) = I and ``ad_a a = 0``). Around
    ``xi0 != 0`` instead, ``d/dt v`` differs from ``xidd`` (the term ``-ad_xid xid / 2`` vanishes, but dexp(xi0) is
    not I): the finite differences resolve that, so they could see a failure of the claim."""
    model = model_of(name)
    rng = np.random.default_rng(4)
    for q0, _, _ in states_of(model, count=3, seed=9)[1:]:
        a, b = rng.uniform(-2.0, 2.0, model.nv), rng.uniform(-2.0, 2.0, model.nv)

        def q_of(t, xi0=np.zeros(model.nv)):
            return geometry.integrate(model, q0, xi0 + a * t + b * t * t / 2)

        np.testing.assert_allclose(_velocity(model, q_of, 0.0), a, rtol=0, atol=1e-8)
        np.testing.assert_allclose(_acceleration(model, q_of), b, rtol=0, atol=1e-7)
        xi0 = np.full(model.nv, 0.4)
        away = _acceleration(model, functools.partial(q_of, xi0=xi0))
        assert np.abs(away - b).max() > 1e-2


def _evaluator(model, order):
    """The generated code's ``evaluate(q, qd)``, the model's world data after q (as the backend passes them)."""
    namespace = {"sin": math.sin, "cos": math.cos, "sqrt": math.sqrt}
    exec(el.generate_source(model, order=order), namespace)
    world = el._world_values(model).tolist()
    return lambda q, qd: namespace["evaluate"](list(q) + world, qd)


@pytest.mark.parametrize("name", ["ball_pendulum", "free_body"] + list(CONSTRAINED_CASES))
def test_second_order_exponential_is_exact_at_the_origin(name):
    """Every output of the generated code (M, C qd, g, T, phi, Jc, Jcdot qd) with the series truncated after order 3
    (the cached derivation, ``EXP_ORDER``) equals orders 2 and 4 to rounding, and order 1 (``exp(X) ~ I + X``, which
    loses the ``X(xid)^2`` of ``Eddot``) gets C qd (and Jcdot qd) wrong: only derivatives of order <= 2 in xi are
    evaluated. The constrained variants hold the unconstrained cases' M, C qd, g (two ball joints; a free base and an
    arm)."""
    model = model_of(name)
    evaluators = {order: _evaluator(model, order) for order in (1, 2, 4)}
    labels = ("M", "Cqd", "g", "T", "phi", "Jc", "bias")
    for q, qd, _ in states_of(model, count=3, seed=31):
        M, Cqd, g, T = el.evaluate_terms(model, q, qd)[:4]
        cons = el.evaluate(model, q, qd)[1]
        size = np.linalg.norm(M, 2) * (1.0 + float(qd @ qd)) + 1.0
        second = dict(zip(labels, (M[np.triu_indices(model.nv)], Cqd, g, T, cons.phi, cons.Jc.ravel(), cons.bias)))
        for order, evaluate in evaluators.items():
            other = dict(zip(labels, (np.array(x, dtype=float) for x in evaluate(q.tolist(), qd.tolist()))))
            diff = {k: float(np.max(np.abs(other[k] - second[k]), initial=0.0)) for k in labels}
            if order == 1:
                assert diff["Cqd"] > 1e-3 * size, diff
                if model.k:
                    assert diff["bias"] > 1e-3 * model.length_scale * float(qd @ qd), diff
            else:
                assert max(diff.values()) <= 1e-12 * size, (order, diff)


# ----------------------------------------------------------------------------------------------------------
# Cache, charts, derivation time
# ----------------------------------------------------------------------------------------------------------

def test_the_local_chart_is_part_of_the_cache_key(tmp_path, monkeypatch):
    monkeypatch.setenv("CROSSCHECK_CACHE", str(tmp_path))
    group, plain = model_of("ball_pendulum"), cases.load("double_pendulum")
    key, plain_key = el.cache_key(group), el.cache_key(plain)
    source = el.cached_source(group)
    assert "local exponential coordinates" in source.splitlines()[0]
    assert el.GROUP_CHART.format(order=el.EXP_ORDER) in source.splitlines()[0]
    header, body = source.split("\n", 1)
    assert "def evaluate(q, qd):" in body and "q0, q1, q2, q3, world0, " in body and "xi" not in body
    with monkeypatch.context() as mp:
        mp.setattr(el, "EXP_ORDER", 4)
        assert el.cache_key(group) != key, "another truncation of the chart must be another cache entry"
        assert el.cache_key(plain) == plain_key, "a model without group joints does not depend on the group chart"
        assert "order4" in el.cached_source(group).splitlines()[0]
    assert len(list(tmp_path.rglob("*.py"))) == 2
    assert el.cached_source(group) == source


def test_charts_are_refused_for_group_models():
    model = model_of("ball_double_pendulum")
    chart = type("Identity", (), {"name": "identity", "key": "identity-6",
                                  "psi": staticmethod(lambda p, sin, cos: list(p))})()
    with pytest.raises(ModelNotSupported, match="spherical or free"):
        el.split_chart(model, chart, np.zeros(6), np.zeros(6), np.zeros(6))
    offset = type("Offset", (), {"name": "offset", "key": "offset-6",
                                 "psi": staticmethod(lambda p, sin, cos: [x + 1 for x in p])})()
    with pytest.raises(ModelNotSupported):
        el.derivation(model, offset)


@pytest.mark.parametrize("name", GROUP_CASES)
def test_each_case_derives_in_seconds(name):
    """Derived once per model (the orientation is a parameter, not a state): well under a minute each (measured
    0.03-0.5 s; the bound is loose for a shared machine)."""
    start = time.perf_counter()
    el.generate_source(model_of(name))
    assert time.perf_counter() - start < 20.0


# ----------------------------------------------------------------------------------------------------------
# The zyx chart (issue 17): split_chart in Euler angles, derived in p with the poses R(quat(psi(p)))
# ----------------------------------------------------------------------------------------------------------

#: States whose chart Jacobian is worse conditioned than this are near gimbal lock (pitch = +-pi/2): left out.
CHART_COND = 1e3


def chart_arguments(model, chart, q, qd, u):
    """``(p, pd, tau_p)`` of a joint state, as the gate's chart check forms them (``crosscheck.checks.invariance``)."""
    p = chart.p_of(q)
    return p, charts.velocity_to_chart(chart, p, qd), charts.force_to_chart(chart, p, model.input_map @ u)


def assert_chart_agrees_with_reference(model, q, qd, u, chart_name="zyx") -> dict[str, float] | None:
    """``el.split_chart`` in the zyx chart against ``crosscheck.references.pinocchio.reference.split`` mapped into the
    chart with the harness's own ``Dpsi`` (never given to the backend): ``pdd = Dpsi^-1 (vdot - (d/dt Dpsi) pd)`` (the
    ctrl without the rate term), invariant fields equal (T, powers, multipliers, constraint values and velocities, S's
    conditions), covariant ones mapped (``Jc_p = Jc Dpsi``, ``Jcdot_p pd = Jcdot v + Jc (d/dt Dpsi) pd``,
    ``Jc_p^T lam = Dpsi^T Jc^T lam``) and ``cond_M`` that of ``M_p = Dpsi^T M Dpsi``; each within ``RTOL`` of its
    scale. None (nothing compared) near gimbal lock. Returns each field's error over its scale."""
    chart = charts.get(chart_name, model)
    p, pd, tau_p = chart_arguments(model, chart, q, qd, u)
    D = chart.jacobian(p)
    if np.linalg.cond(D) >= CHART_COND:
        return None
    got, ref = el.split_chart(model, chart, p, pd, tau_p), reference.split(model, q, qd, u)
    rate = chart.jacobian_rate(p, pd)
    errors: dict[str, float] = {}

    def check(name, a, b, scale):
        a, b = np.asarray(a, dtype=float), np.asarray(b, dtype=float)
        assert a.shape == b.shape, f"{model.name} {name}: shape {a.shape} against {b.shape}"
        err = float(np.max(np.abs(a - b), initial=0.0))
        errors[name] = err / (scale + 1e-300)
        assert err <= RTOL * scale + 1e-300, (
            f"{model.name} {chart_name} {name}: differs by {err:.3e} (tolerance {RTOL * scale:.3e})\n  q = {q.tolist()}\n"
            f"  qd = {qd.tolist()}\n  u = {u.tolist()}\n  euler_lagrange: {a.tolist()}\n  mapped reference: "
            f"{b.tolist()}")

    inverse = float(np.linalg.norm(np.linalg.inv(D), 2))
    accel = inverse * (ref.accel_scale + np.abs(rate).sum())
    for name in ("drift", "ctrl", "total"):
        expected = charts.acceleration_to_chart(chart, p, pd, getattr(ref, name), with_rate=name != "ctrl")
        check(name, getattr(got, name), expected, accel)
    assert got.drift.shape == (model.nv,)
    check("kinetic_energy", got.kinetic_energy, ref.kinetic_energy, ref.kinetic_energy)
    # the summed terms in both charts, and pd's own rounding: pd solves Dpsi pd = qd by LU with pivoting, whose error is
    # normwise, up to cond_inf(Dpsi) |pd|_inf eps in every entry; a rate that is ~0 next to a large one (qd = (1, 6e-17,
    # ...)) is then all rounding, times the chart's force there
    rounding = np.linalg.norm(np.linalg.inv(D), np.inf) * np.linalg.norm(D, np.inf) * np.abs(pd).max()
    power = max(float(np.abs(tau_p) @ np.abs(pd)), float(np.abs(model.input_map @ u) @ np.abs(qd)),
                float(np.abs(tau_p).sum() * rounding))
    check("power_ctrl", got.power_ctrl, ref.power_ctrl, power)
    check("power_ctrl_per_coord", got.power_ctrl_per_coord, tau_p * pd, power)
    M_p = D.T @ kinematics.mass_matrix(model, q) @ D
    cond = float(np.linalg.cond(M_p))
    check("cond_M", got.cond_M, cond, _relative_scale(cond, cond))
    for name in ("task_drift", "task_inertia"):
        assert isinstance(getattr(got, name), Unsupported)
    if not model.constraints:
        assert got.lam is None and got.constraint_jacobian is None and not got.conditions
        return errors
    broken = bool(policy.breakdown(got) or policy.breakdown(ref))
    cond_S = ref.conditions["constraint_kept"]
    L, velocity = model.length_scale, float(np.abs(qd).sum())
    Jc = ref.constraint_jacobian
    check("constraint_value", got.constraint_value, ref.constraint_value, L)
    check("constraint_jacobian", got.constraint_jacobian, Jc @ D, L * np.linalg.norm(D, 2))
    check("constraint_velocity", got.constraint_velocity, ref.constraint_velocity, L * velocity)
    check("constraint_bias", got.constraint_bias, ref.constraint_bias + Jc @ rate,
          L * (velocity**2 + np.abs(rate).sum() * np.linalg.norm(D, 2)))
    force = float(np.linalg.norm(Jc, 2)) * ref.lam_scale * (1.0 + 1e-6 * cond_S)
    for name in ("constraint_force", "constraint_force_drift"):
        check(name, getattr(got, name), D.T @ getattr(ref, name), force * np.linalg.norm(D, 2))
    check("power_constr", got.power_constr, ref.power_constr, force * velocity)
    if not broken:
        assert got.constraint_rank == ref.constraint_rank
        for key in ("constraint", "constraint_kept"):  # S = Jc_p M_p^-1 Jc_p^T = Jc M^-1 Jc^T: invariant
            check(f"conditions[{key}]", got.conditions[key], ref.conditions[key],
                  _relative_scale(ref.conditions[key], cond_S))
        for name in ("lam", "lam_drift"):
            check(name, getattr(got, name), getattr(ref, name), ref.lam_scale * (1.0 + 1e-6 * cond_S))
    return errors


@pytest.mark.parametrize("chart_name", ("zyx", "exp"))
@pytest.mark.parametrize("name", GROUP_CASES + CONSTRAINED_CASES + ("solo12_standing",))
def test_zyx_chart_agrees_with_the_reference_mapped_into_the_chart(name, chart_name):
    model = model_of(name)
    compared = [assert_chart_agrees_with_reference(model, *state, chart_name=chart_name)
                for state in states_of(model, count=2 if name.startswith("solo") else 5, seed=41)]
    assert sum(e is not None for e in compared) >= 2, "every sampled state near gimbal lock: nothing compared"


@pytest.mark.parametrize("chart_name", ("zyx", "exp"))
@pytest.mark.parametrize("name", GROUP_CASES + CONSTRAINED_CASES + ("solo12",))
def test_zyx_chart_check_of_the_gate(name, chart_name, tmp_path, monkeypatch):
    """The gate's own chart check (``crosscheck.checks.invariance.chart_checks`` through
    ``testing.assert_backends_agree``): the backend's native answers in the zyx chart, and in the exp chart (exponential
    coordinates about the centre drawn for the case), against Pinocchio's joint-chart split mapped into it, on every
    quantity the gate compares there (the checks exist: the backend is not left out of the chart), from a cold
    derivation (an empty cache; its
    time is measured by ``crosscheck bench``, not asserted here)."""
    model = model_of(name)
    chart = charts.get(chart_name, model, 0, name)
    monkeypatch.setenv("CROSSCHECK_CACHE", str(tmp_path))
    el.cached_code(model, chart)
    checked = 0
    for s in sampling.sample_states(model, 2 if name.startswith("solo") else 3, 43, name):
        outcome = testing.assert_backends_agree(model, s, backends=["euler_lagrange", "pinocchio"], chart=chart)
        keys = [k for k in outcome.checks if k.startswith(f"chart {chart_name}: ")]
        checked += bool(keys)
        assert all(f"euler_lagrange@{chart_name}" in outcome.checks[k].voters for k in keys)
        assert not keys or f"chart {chart_name}: drift" in keys
        if model.k and keys:
            assert f"chart {chart_name}: lam" in keys
    assert checked >= 1


@settings(max_examples=6)
@given(data=st.data())
def test_random_group_trees_in_the_zyx_chart(data):
    model = data.draw(testing.models(max_bodies=4, group=True, constraints=None), label="model")
    assume(model.group_joints)
    state = data.draw(testing.states(model), label="state")
    q, qd, u = (np.array(x, dtype=float) for x in (state.q, state.qd, state.u))
    assume(assert_chart_agrees_with_reference(model, q, qd, u) is not None)
    testing.assert_backends_agree(model, state, backends=["euler_lagrange", "pinocchio"],
                                  chart=charts.get("zyx", model), conservation=False)


@settings(max_examples=5)
@given(data=st.data())
def test_random_constrained_group_trees_in_the_zyx_chart(data):
    model = data.draw(testing.models(max_bodies=4, group=True, constraints=True), label="model")
    assume(model.group_joints)
    state = data.draw(testing.states(model), label="state")
    q, qd, u = (np.array(x, dtype=float) for x in (state.q, state.qd, state.u))
    assume(assert_chart_agrees_with_reference(model, q, qd, u) is not None)


def _euler_rates(pitch, roll):
    """Body angular velocity per (yaw, pitch, roll) rate of ``R = Rz(yaw) Ry(pitch) Rx(roll)``, written here: ``w =
    Rx^T Ry^T e_z yawdot + Rx^T e_y pitchdot + e_x rolldot``."""
    sp, cp, sr, cr = math.sin(pitch), math.cos(pitch), math.sin(roll), math.cos(roll)
    return np.array([[-sp, 0.0, 1.0], [cp * sr, cr, 0.0], [cp * cr, -sr, 0.0]])


def _zyx_rotation(yaw, pitch, roll):
    def about(axis, a):
        c, s = math.cos(a), math.sin(a)
        i, j = [(1, 2), (2, 0), (0, 1)][axis]
        R = np.eye(3)
        R[i, i] = R[j, j] = c
        R[i, j], R[j, i] = -s, s
        return R
    return about(2, yaw) @ about(1, pitch) @ about(0, roll)


@pytest.mark.parametrize("name", ["ball_pendulum", "free_body"])
def test_zyx_mass_matrix_in_closed_form(name):
    """The chart's own M_p (from its Lagrangian in Euler angles) in closed form: the ball pendulum's ``E^T I_o E``
    (I_o the inertia about the joint, E the Euler-rate map written here); the free body's ``J^T M J`` with the
    spatial inertia M and ``J = diag(R^T, E)`` (``v = R^T pdot``). Also its energy ``1/2 pd^T M_p pd`` is T."""
    model = model_of(name)
    chart = charts.get("zyx", model)
    (b,) = model.bodies
    rng = np.random.default_rng(3)
    for _ in range(4):
        p = rng.uniform(-1.2, 1.2, model.nv)
        pd = rng.uniform(-2.0, 2.0, model.nv)
        M_p, _, g_p, T = el.evaluate_terms(model, p, pd, chart)[:4]
        E = _euler_rates(p[-2], p[-1])
        if name == "ball_pendulum":
            C = _hat(b.com)
            expected = E.T @ (b.inertia - b.mass * C @ C) @ E
        else:
            J = np.zeros((6, 6))
            J[:3, :3], J[3:, 3:] = _zyx_rotation(*p[3:]).T, E
            expected = J.T @ spatial_inertia(b.mass, b.com, b.inertia) @ J
        np.testing.assert_allclose(M_p, expected, rtol=0, atol=1e-13 * np.abs(expected).max())
        assert abs(T - 0.5 * pd @ expected @ pd) <= 1e-13 * abs(T)


def test_zyx_chart_cache_entry(tmp_path, monkeypatch):
    """The zyx chart's derivation is its own disk-cache entry (keyed by the chart's key and the way group joints
    enter it), in p with no local coordinates; a second read serves the same source; the joint chart's entry is
    unchanged; another model's zyx chart (other joints, so another chart key) is another entry."""
    monkeypatch.setenv("CROSSCHECK_CACHE", str(tmp_path))
    model = model_of("ball_double_pendulum")
    chart = charts.get("zyx", model)
    joint_source = el.cached_source(model)
    key = el.cache_key(model, chart)
    assert key != el.cache_key(model) and key != el.cache_key(model_of("ball_pendulum"),
                                                               charts.get("zyx", model_of("ball_pendulum")))
    source = el.cached_source(model, chart)
    header, body = source.split("\n", 1)
    assert f"chart 'zyx' ({chart.key})" in header and el.GROUP_IN_CHART in header
    assert "def evaluate(p, pd):" in body and "p0, p1, p2, p3, p4, p5, world0, " in body and "xi" not in body
    assert (tmp_path / "euler_lagrange" / f"{key}.py").read_text() == source
    assert el.cached_source(model, chart) == source and el.cached_source(model) == joint_source
    assert len(list(tmp_path.rglob("*.py"))) == 2


def test_charts_other_than_a_chart_of_the_group_are_refused():
    """A chart whose quaternions are not unit (R(quat) would not be a rotation) and the harness's group identity
    (q itself, no psi on nv coordinates) are ModelNotSupported, each with its reason; at gimbal lock the zyx chart
    itself has a singular M_p, a ValueError naming the chart."""
    model = model_of("ball_pendulum")
    chart = charts.get("zyx", model)
    stretched = type("Stretched", (), {"name": "stretched", "key": "stretched-4",
                                       "psi": staticmethod(lambda p, sin, cos: [1.5 * x for x in
                                                                                chart.psi(p, sin, cos)])})()
    with pytest.raises(ModelNotSupported, match="quaternion of norm"):
        el.split_chart(model, stretched, np.zeros(3), np.zeros(3), np.zeros(3))
    with pytest.raises(ModelNotSupported, match="does not evaluate on 3 coordinates"):
        el.split_chart(model, charts.get("identity", model), np.zeros(3), np.zeros(3), np.zeros(3))
    with pytest.raises(ModelNotSupported, match="split's"):
        el.split_chart(model, None, np.zeros(3), np.zeros(3), np.zeros(3))
    with pytest.raises(ValueError, match="chart 'zyx'.*singular wherever Dpsi is"):  # gimbal lock: M_p singular
        el.split_chart(model, chart, np.array([0.3, np.pi / 2, -0.2]), np.ones(3), np.zeros(3))

