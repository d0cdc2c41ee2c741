"""Newton–Euler's linearization (``newton_euler.linearize``, article 4.8, eq. 11) and the drift's parts
(``Split.zvcf``, ``drift_velocity``), against references outside the backend.

Unconstrained models: Pinocchio's analytical ABA derivatives (``crosscheck.references.pinocchio.reference.linearize``, same tangent-space
convention on Lie groups). Constrained ones: central differences of the exact KKT split of the harness's
high-precision reference (``crosscheck.references.precise``, 50 digits, h = 1e-20: the derivative to double precision; a float
difference of ``reference.split`` at h = 1e-6 has 1e-8 of rounding, and at h = 1e-4 steps across the rank changes of
degenerate rows that random models have within 1e-4); with group joints (solo12 standing) float differences of the
reference along ``integrate`` (:func:`_group_differences`). The bar is the issue's: every block of A and B within 1e-8
relative (max abs error / max abs entry of the reference block, :func:`_errors`); measured 1e-13 against Pinocchio
and 1e-14 against the exact differences.
"""

from __future__ import annotations

import mpmath
import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

import cases
import formalisms
from cases.configuration import integrate, random_configuration
from crosscheck.references import precise
from crosscheck.references.pinocchio import kinematics
from crosscheck.references.pinocchio import reference
from crosscheck.core import sampling
from crosscheck import testing
from formalisms import newton_euler as ne
from formalisms.interface import StateError

RTOL = 1e-8
#: The smallest block scale counted, relative to the largest entry of the linearization (:func:`_errors`).
FLOOR = 1e-4


def _blocks(model, lin):
    """The dynamic blocks ``dvdot/dq``, ``dvdot/dv``, ``dvdot/du`` of a linearization, by name."""
    nv = model.nv
    return {"dq": lin.A[nv:, :nv], "dv": lin.A[nv:, nv:], "du": lin.B[nv:]}


def _errors(model, lin, want: dict, q, v, u) -> dict:
    """Per block: max abs error over what the bar allows, in units of :data:`RTOL` (1 = at the bar). The bar is RTOL
    of the reference block's max abs entry, that entry taken as at least :data:`FLOOR` of the largest entry of all
    blocks and of the unconstrained input map ``M^-1 B`` (a block that vanishes, e.g. dvdot/dv at qd = 0, or B_c B of
    an input on a locked joint, is exactly 0 on one side and rounding on the other), plus the rounding of the solves
    the accelerations come from: ``100 eps cond(M) cond_kept(S)`` of that largest entry (cond S reaches 1e4 on random
    constrained models, where a block that is zero in exact arithmetic is 1e-11 here)."""
    free_input = np.linalg.solve(kinematics.mass_matrix(model, q), model.input_map)
    whole = max([np.abs(block).max(initial=0.0) for block in want.values()] + [np.abs(free_input).max(initial=0.0)])
    ref = reference.split(model, q, v, u)
    rounding = 100 * np.finfo(float).eps * ref.cond_M * ref.conditions.get("constraint_kept", 1.0) * whole
    return {name: np.abs(got - want[name]).max(initial=0.0) * RTOL
            / (RTOL * max(np.abs(want[name]).max(initial=0.0), FLOOR * whole) + rounding + 1e-300)
            for name, got in _blocks(model, lin).items()}


def _assert_agrees_with_pinocchio(model, q, v, u):
    lin, ref = ne.linearize(model, q, v, u), reference.linearize(model, q, v, u)
    errors = _errors(model, lin, _blocks(model, ref), q, v, u)
    assert max(errors.values()) <= RTOL, errors
    np.testing.assert_array_equal(lin.A[:model.nv], ref.A[:model.nv])      # the shared kinematic rows
    np.testing.assert_allclose(lin.vdot, ref.vdot, rtol=0, atol=1e-10 * reference.split(model, q, v, u).accel_scale)


def _differences(model, q, v, u, digits: int = 50, h: str = "1e-20"):
    """``d total / d(q, v, u)`` of the exact KKT split (``crosscheck.references.precise``, ``digits`` significant digits) by
    central differences at ``h``: truncation ``h^2``, rounding ``10^-digits / h``, so the derivative of the float data
    to double precision (a test's tool). Revolute and prismatic joints only, where ``q (+) dq = q + dq``."""
    assert not model.group_joints
    with mpmath.workdps(digits):
        h = mpmath.mpf(h)
        q, v, u = ([mpmath.mpf(float(x)) for x in vector] for vector in (q, v, u))
        B = [[mpmath.mpf(float(x)) for x in row] for row in model.input_map]

        def total(q, v, u):
            tau = [mpmath.fsum(b * x for b, x in zip(row, u)) for row in B]
            return precise._split(model, q, v, tau, digits).total

        def column(vectors, which: int, j: int):
            def at(s):
                moved = [list(x) for x in vectors]
                moved[which][j] += s
                return total(*moved)
            return [float((a - b) / (2 * h)) for a, b in zip(at(h), at(-h))]
        return {name: np.array([column((q, v, u), which, j) for j in range(size)], dtype=float).T.reshape(
            model.nv, size) for name, which, size in (("dq", 0, model.nv), ("dv", 1, model.nv), ("du", 2, model.m))}


def _assert_agrees_with_differences(model, q, v, u):
    lin = ne.linearize(model, q, v, u)
    errors = _errors(model, lin, _differences(model, q, v, u), q, v, u)
    assert max(errors.values()) <= RTOL, errors
    ref = reference.split(model, q, v, u)
    np.testing.assert_allclose(lin.vdot, ref.total, rtol=0, atol=1e-10 * ref.accel_scale)


def _group_differences(model, q, v, u, h=5e-4):
    """The derivatives of ``reference.split(...).total`` for a model with group joints: along ``integrate`` by the
    fourth-order central stencil (truncation and rounding near 1e-11 relative at h = 5e-4), and along v and u by the
    second-order one at h = 1 (the KKT solution is quadratic in v and linear in u: the stencil is then exact, up to
    rounding near 1e-15)."""
    f = lambda q, v, u: reference.split(model, q, v, u).total  # noqa: E731

    def fourth(g):
        return (8.0 * (g(h) - g(-h)) - (g(2 * h) - g(-2 * h))) / (12.0 * h)

    def exact(g):
        return (g(1.0) - g(-1.0)) / 2.0
    return {"dq": np.column_stack([fourth(lambda s: f(integrate(model, q, s * e), v, u)) for e in np.eye(model.nv)]),
            "dv": np.column_stack([exact(lambda s: f(q, v + s * e, u)) for e in np.eye(model.nv)]),
            "du": np.column_stack([exact(lambda s: f(q, v, u + s * e)) for e in np.eye(model.m)]).reshape(
                model.nv, model.m)}


def _random_state(model, seed):
    rng = np.random.default_rng(seed)
    return random_configuration(model, rng, 1.0, 0.3), rng.normal(size=model.nv), rng.normal(size=model.m)


@pytest.mark.parametrize("name", ["double_pendulum", "spatial_arm", "free_body", "solo12", "ball_double_pendulum",
                                  "satellite_arm"])
def test_agrees_with_pinocchio_on_the_builtin_trees(name):
    model = cases.load(name)
    for seed in (1, 2):
        _assert_agrees_with_pinocchio(model, *_random_state(model, seed))


@pytest.mark.parametrize("name", ["panda", "four_bar", "slider_crank", "double_pendulum_circle",
                                  "double_pendulum_rail", "double_pendulum_absolute_loop"])
def test_agrees_with_the_differentiated_reference_kkt_on_constrained_cases(name):
    """Admissible states of the gate's sampler (the first at home, a boundary state; panda, the slowest reference,
    at the second only)."""
    model = cases.load(name)
    for state in sampling.sample_states(model, 2, 5, name)[1 if name == "panda" else 0:]:
        _assert_agrees_with_differences(model, *(np.array(x) for x in (state.q, state.qd, state.u)))


def test_agrees_with_the_reference_kkt_on_a_floating_base_on_its_feet():
    """solo12 standing (a free base, 12 contact rows): the q directions on SE(3) along ``integrate``."""
    model = cases.load("solo12_standing")
    state = sampling.sample_states(model, 2, 5, "solo12_standing")[1]
    q, v, u = (np.array(x) for x in (state.q, state.qd, state.u))
    lin = ne.linearize(model, q, v, u)
    errors = _errors(model, lin, _group_differences(model, q, v, u), q, v, u)
    assert max(errors.values()) <= RTOL, errors


def test_the_constrained_derivative_holds_off_the_manifold():
    """The KKT solution is a function of (q, v, u) also where ``phi(q) != 0`` and ``Jc v != 0`` (the contract): a
    random state of the four-bar, not projected."""
    model = cases.load("four_bar")
    _assert_agrees_with_differences(model, *_random_state(model, 4))


@settings(max_examples=15, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(st.data())
def test_agrees_with_the_exact_reference_on_random_trees(data):
    """Random trees against the 50-digit reference: on ill-conditioned ones Pinocchio's ABA derivatives are the less
    accurate side (a free body carrying a 100 kg point mass, cond M 2e5: Pinocchio 1.5e-8 from the exact dvdot/dq,
    every backend 2e-12 to 3e-10)."""
    from crosscheck.references import precise
    model = data.draw(testing.models(max_bodies=4, group=True))
    state = data.draw(testing.states(model))
    q, v, u = (np.array(x) for x in (state.q, state.qd, state.u))
    lin = ne.linearize(model, q, v, u)
    errors = _errors(model, lin, _blocks(model, precise.linearize(model, q, v, u)), q, v, u)
    assert max(errors.values()) <= RTOL, errors


@settings(max_examples=6, deadline=None, suppress_health_check=[HealthCheck.too_slow, HealthCheck.filter_too_much])
@given(st.data())
def test_agrees_with_the_differentiated_reference_kkt_on_random_constrained_models(data):
    model = data.draw(testing.models(max_bodies=4, constraints=True))
    state = data.draw(testing.states(model))
    _assert_agrees_with_differences(model, *(np.array(x) for x in (state.q, state.qd, state.u)))


def test_is_registered_and_validates_the_state():
    model = cases.load("double_pendulum")
    assert formalisms.get("newton_euler").linearize is ne.linearize
    with pytest.raises(StateError, match="qd has 3 entries"):
        ne.linearize(model, np.zeros(2), np.zeros(3), np.zeros(model.m))
    with pytest.raises(StateError, match="norm"):
        ne.linearize(cases.load("free_body"), np.r_[0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 2.0], np.zeros(6),
                     np.zeros(cases.load("free_body").m))


# ----------------------------------------------------------------------------------------------------------
# The drift's parts
# ----------------------------------------------------------------------------------------------------------

def _assert_parts_add_up(split):
    assert np.abs(split.drift_parts).max() <= 1e-13 * max(np.abs(split.zvcf).max(), np.abs(split.drift).max(),
                                                          np.abs(split.drift_velocity).max())


@pytest.mark.parametrize("name", ["spatial_arm", "solo12", "ball_double_pendulum"])
def test_drift_parts_against_the_reference_mass_matrix_and_bias_forces(name):
    model = cases.load(name)
    q, v, u = _random_state(model, 7)
    split = ne.split(model, q, v, u)
    M = kinematics.mass_matrix(model, q)
    c_qd, g = kinematics.bias_forces(model, q, v)
    for got, force in ((split.zvcf, g), (split.drift_velocity, c_qd)):
        want = -np.linalg.solve(M, force)
        np.testing.assert_allclose(got, want, rtol=0, atol=1e-10 * np.abs(want).max() + 1e-12)
    _assert_parts_add_up(split)


@pytest.mark.parametrize("name", ["panda", "four_bar", "double_pendulum_circle", "geared_pendulums"])
def test_constrained_drift_parts_against_the_reference(name):
    """With ``qd = 0`` the KKT system has no Coriolis force and no bias: the zvcf at ``(q, qd)`` is the reference's
    drift at ``(q, 0)``; the velocity part is the rest of the reference's drift."""
    model = cases.load(name)
    for state in sampling.sample_states(model, 2, 9, name):
        q, v, u = (np.array(x) for x in (state.q, state.qd, state.u))
        split = ne.split(model, q, v, u)
        at_rest, drift = reference.split(model, q, np.zeros(model.nv), u).drift, reference.split(model, q, v, u).drift
        scale = max(np.abs(drift).max(), np.abs(at_rest).max())
        np.testing.assert_allclose(split.zvcf, at_rest, rtol=0, atol=1e-10 * scale)
        np.testing.assert_allclose(split.drift_velocity, drift - at_rest, rtol=0, atol=1e-10 * scale)
        _assert_parts_add_up(split)
