"""The high-precision reference (crosscheck.references.precise): exact against closed forms, consistent with Pinocchio to
double precision on every built-in case and on random trees, and converged in the working precision."""

from __future__ import annotations

import mpmath
import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

import cases
from closed_forms import cartesian_lam_mp, pendulum_terms_mp
from crosscheck.references import precise
from crosscheck.references.pinocchio import reference
from crosscheck.core import sampling
from crosscheck import testing
from crosscheck.core import tolerance as policy
from formalisms.interface import StateError

QUANTITIES = ("drift", "ctrl", "total")
MULTIPLIERS = ("lam", "lam_drift")
#: The closed forms are evaluated this much above the reference's precision, so their own rounding does not count.
CLOSED_FORM_DIGITS = precise.DIGITS + 20
#: Pinocchio (double precision) against the exact answer: this fraction of the accelerations' (multipliers') scale.
DOUBLE_AGREEMENT = 1e-12

PENDULUM_PARAMETERS = [
    {},
    {"m1": 0.7, "m2": 2.3, "l1": 1.3, "l2": 0.6},
    {"m1": 3.0, "m2": 0.2, "l1": 0.4, "l2": 1.7, "g": 1.62},
]
PENDULUM_STATES = [  # (q, qd, u): home, a generic state, nearly stretched and fast, nearly folded over the top
    ((0.0, 0.0), (0.5, -1.0), (1.0, -2.0)),
    ((0.785, 0.524), (2.0, -1.0), (5.0, -2.0)),
    ((-2.1, 1e-7), (-3.0, 2.5), (0.0, 7.5)),
    ((3.1, -3.0), (0.25, 1.75), (-4.0, 0.5)),
]


def _closed_form_split(params: dict, q, qd, u):
    """M, h and the split of the double pendulum (B = I) from eqs. (6)-(8), solved in mpmath at high precision."""
    keys = {k: params[k] for k in params if k in ("m1", "m2", "l1", "l2", "g")}
    with mpmath.workdps(CLOSED_FORM_DIGITS):
        M, Cqd, grav = pendulum_terms_mp(q, qd, **keys)
        h = Cqd + grav
        tau = mpmath.matrix([mpmath.mpf(x) for x in u])
        solve = (lambda b: list(mpmath.lu_solve(M, b)))
        return M, list(h), {"drift": solve(-h), "ctrl": solve(tau), "total": solve(tau - h)}


@pytest.mark.parametrize("params", PENDULUM_PARAMETERS)
def test_double_pendulum_closed_forms_to_30_digits(params):
    """Article section 3: M (eq. 6), h = C qd + g (eqs. 7, 8) and drift, ctrl, total agree with the closed forms to
    30 digits at several states, for several parameter sets."""
    model = cases.load("double_pendulum", **params)
    for q, qd, u in PENDULUM_STATES:
        M_exact, h_exact, split_exact = _closed_form_split(params, q, qd, u)
        M = precise.mass_matrix(model, q)
        assert precise.relative_error(list(M), list(M_exact)) < 1e-30
        assert precise.relative_error(precise.bias_forces(model, q, qd), h_exact) < 1e-30
        result = precise.split(model, q, qd, u)
        assert result.lam is None and result.lam_drift is None and result.digits == precise.DIGITS
        for name in QUANTITIES:
            assert precise.relative_error(getattr(result, name), split_exact[name]) < 1e-30, name


def test_cartesian_pendulum_multiplier_to_30_digits():
    """The cartesian pendulum's lam (closed form, cases.cartesian_pendulum) at states exactly on the circle:
    p = (3, -4) and (0, -5) on |p| = 5 with velocities along the tangent, all binary-exact."""
    model = cases.load("cartesian_pendulum", m=2.5, L=5.0)
    for q, qd, u in (((3.0, -4.0), (2.0, 1.5), (1.0, -3.0)), ((0.0, -5.0), (-0.75, 0.0), (4.5, 2.0))):
        result = precise.split(model, q, qd, u)
        with mpmath.workdps(CLOSED_FORM_DIGITS):
            lam = cartesian_lam_mp(q, qd, u, m=2.5, L=5.0)
            lam_drift = cartesian_lam_mp(q, qd, (0.0, 0.0), m=2.5, L=5.0)
        assert precise.relative_error(result.lam, [lam]) < 1e-30
        assert precise.relative_error(result.lam_drift, [lam_drift]) < 1e-30


def test_redundant_rows_give_minimum_norm_multipliers():
    """A duplicated circle row makes S singular: the accelerations are the single row's and the minimum-norm
    multipliers split its lam equally, to 30 digits."""
    single = cases.load("double_pendulum_circle")
    circle = single.constraints[0]
    twice = cases.build_model("circle_twice", single.bodies, gravity=single.gravity, input_map=single.input_map,
                              task_points=single.task_points,
                              constraints=[circle, cases.PointOnCircle("again", circle.body, circle.offset,
                                                                       circle.center, circle.radius)])
    state = sampling.sample_states(single, 2, 0, "double_pendulum_circle")[1]
    one, two = precise.split(single, state.q, state.qd, state.u), precise.split(twice, state.q, state.qd, state.u)
    for name in QUANTITIES:
        assert precise.relative_error(getattr(two, name), getattr(one, name)) < 1e-30, name
    for name in MULTIPLIERS:
        with mpmath.workdps(precise.DIGITS):                        # mpmath rounds to the context's precision
            half = [x / 2 for x in getattr(one, name)] * 2
        assert precise.relative_error(getattr(two, name), half) < 1e-30, name


def _assert_pinocchio_close(model, q, qd, u, tolerance) -> None:
    """Pinocchio's split is within ``tolerance(quantity, pinocchio_split)`` of the exact one, for the accelerations
    and (constrained) the multipliers the harness compares at this state (not those it declares BREAKDOWN)."""
    exact, ref = precise.split(model, q, qd, u), reference.split(model, q, qd, u)
    names = QUANTITIES
    if model.k:
        assert len(exact.lam) == len(exact.lam_drift) == model.k
        names += tuple(m for m in MULTIPLIERS if m not in policy.left_out(policy.breakdown(ref)))
    else:
        assert exact.lam is None and exact.floats("lam") is None
    for name in names:
        err = np.abs(exact.floats(name) - getattr(ref, name))         # entry by entry (a tolerance may be per entry)
        assert np.all(err <= tolerance(name, ref)), (model.name, name, q, err, tolerance(name, ref))


@pytest.mark.parametrize("case", cases.names())
def test_agrees_with_pinocchio_on_built_in_cases(case):
    """At the gate's sampled states (home included) Pinocchio is within 1e-12 of the accelerations' (multipliers')
    scale of the exact answer."""
    model = cases.load(case)
    for state in sampling.sample_states(model, 3, 0, case):
        _assert_pinocchio_close(model, state.q, state.qd, state.u, lambda name, ref: DOUBLE_AGREEMENT * (
            ref.lam_scale if name in MULTIPLIERS else ref.accel_scale))


@settings(max_examples=20, deadline=None)
@given(st.data())
def test_agrees_with_pinocchio_on_random_trees(data):
    """On random mechanisms (constraints sometimes) Pinocchio's error against the exact answer is within the
    harness's own tolerance for it (crosscheck.core.tolerance)."""
    model = data.draw(testing.models(max_bodies=4, constraints=None))
    state = data.draw(testing.states(model))

    def harness_tolerance(name, ref):
        return policy.tolerance(name, policy.scales([ref], model, np.array(state.q), np.array(state.qd)))

    _assert_pinocchio_close(model, state.q, state.qd, state.u, harness_tolerance)


@settings(max_examples=30, deadline=None)
@given(st.data())
def test_agrees_with_pinocchio_on_random_group_trees(data):
    """On random trees with spherical and free joints (constraints sometimes) Pinocchio's error against the exact
    answer is within the harness's own tolerance for it: quaternions, body-frame velocity columns and their bias
    accelerations mean the same in both."""
    model = data.draw(testing.models(max_bodies=3, group=True, constraints=None))
    state = data.draw(testing.states(model))

    def harness_tolerance(name, ref):
        return policy.tolerance(name, policy.scales([ref], model, np.array(state.q), np.array(state.qd)))

    _assert_pinocchio_close(model, state.q, state.qd, state.u, harness_tolerance)


def test_free_body_drift_is_eulers_equations_to_30_digits():
    """The torque-free body (free joint, COM c off the body origin, zero gravity): the angular drift is Euler's
    ``wd = -I^-1 (w x I w)`` and the body-frame linear drift keeps the COM's world velocity ``R (v + w x c)``
    constant: ``vd = -w x (v + w x c) - wd x c`` (the derivative of the body twist, not of p's second derivative)."""
    model = cases.load("free_body")
    body = model.bodies[0]
    quaternion = np.array([0.3, -0.5, 0.1, 0.8]) / np.linalg.norm([0.3, -0.5, 0.1, 0.8])
    q = [0.1, -0.2, 0.3, *quaternion]
    for qd in ((0.4, -0.3, 0.2, 1.5, -2.0, 0.7), (0.0, 0.0, 0.0, -3.0, 0.5, 2.5), (1.0, 2.0, -0.5, 0.0, 0.0, 0.0)):
        result = precise.split(model, q, qd, np.zeros(model.m))
        with mpmath.workdps(CLOSED_FORM_DIGITS):
            inertia = mpmath.matrix([[mpmath.mpf(float(x)) for x in row] for row in body.inertia])
            c = mpmath.matrix([mpmath.mpf(float(x)) for x in body.com])
            v, w = (mpmath.matrix([mpmath.mpf(x) for x in part]) for part in (qd[:3], qd[3:]))
            cross = (lambda a, b: mpmath.matrix([a[1] * b[2] - a[2] * b[1], a[2] * b[0] - a[0] * b[2],
                                                 a[0] * b[1] - a[1] * b[0]]))
            wd = -mpmath.lu_solve(inertia, cross(w, inertia * w))
            vd = -cross(w, v + cross(w, c)) - cross(wd, c)
            expected = list(vd) + list(wd)
        assert precise.relative_error(result.drift, expected) < 1e-30, qd


@pytest.mark.parametrize("case", ["panda", "double_pendulum_absolute_loop", "four_bar", "solo12_standing"])
def test_more_digits_change_the_answer_below_the_precision(case):
    """From 40 to 60 digits every quantity moves by less than 1e-30 (relative): the answer is converged; and the
    directly computed ctrl adds up with the drift to the total to the working precision."""
    model = cases.load(case)
    state = sampling.sample_states(model, 2, 1, case)[1]
    low, high = (precise.split(model, state.q, state.qd, state.u, digits=d) for d in (40, 60))
    for name in QUANTITIES + (MULTIPLIERS if model.k else ()):
        assert precise.relative_error(getattr(low, name), getattr(high, name)) < 1e-30, name
    with mpmath.workdps(60):
        additivity = [d + c for d, c in zip(high.drift, high.ctrl)]
    assert precise.relative_error(additivity, high.total) < 1e-50


def test_relative_error_is_normwise_and_absolute_against_zero():
    exact = (mpmath.mpf(2), mpmath.mpf(-4))
    assert precise.relative_error([2.0, -3.0], exact) == 0.25
    assert precise.relative_error(np.array([0.5, -0.25]), (mpmath.mpf(0), mpmath.mpf(0))) == 0.5
    assert precise.relative_error([np.nan, 0.0], exact) == float("inf")
    with pytest.raises(ValueError, match="entries"):
        precise.relative_error([1.0], exact)


def test_bad_input_is_rejected():
    model = cases.load("double_pendulum")
    with pytest.raises(ValueError, match="digits"):
        precise.split(model, [0.0, 0.0], [0.0, 0.0], [0.0, 0.0], digits=16)
    with pytest.raises(StateError, match="needs 2"):
        precise.split(model, [0.0], [0.0, 0.0], [0.0, 0.0])
    with pytest.raises(ValueError, match="no quantity"):
        precise.split(model, [0.0, 0.0], [0.0, 0.0], [0.0, 0.0]).floats("qdd")
