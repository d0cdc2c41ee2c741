"""The charts of spherical and free joints: ZYX Euler angles (``crosscheck.checks.charts.EulerZYX``) and exponential
coordinates about a seeded centre (``crosscheck.checks.charts.ExponentialCoordinates``). The harness's own maps between
each chart and the group, checked against the group operations (``cases.configuration``) by finite differences;
zyx's gimbal lock; exp's series branch near ``p = 0`` against the closed forms (and an independent high-precision
evaluation), its limit at ``p = 0``, its domain (``|p| <= pi``, ``cond(J_r) <= pi/2``) and its seeded centre."""

from __future__ import annotations

import math

import numpy as np
import pytest

import cases
from cases import configuration
from crosscheck.checks import charts, invariance
from crosscheck.references.pinocchio import reference
from crosscheck.core import sampling

GROUP_CASES = ("free_body", "ball_pendulum", "ball_double_pendulum", "satellite_arm")
GROUP_CHARTS = ("zyx", "exp")


def _rotation(quat) -> np.ndarray:
    return configuration.rotation(np.asarray(quat, dtype=float))


@pytest.mark.parametrize("name", GROUP_CHARTS)
@pytest.mark.parametrize("case", GROUP_CASES)
def test_the_chart_is_a_chart_of_the_group(case, name):
    """p -> q -> p is the identity; q -> p -> q gives the same rotations (a quaternion or its negative)."""
    model = cases.load(case)
    chart = charts.get(name, model)
    for s in sampling.sample_states(model, 6, 1, case):
        q = np.array(s.q)
        p = chart.p_of(q)
        back = chart.q_of(p)
        for _, sl in configuration.quaternion_slices(model):
            np.testing.assert_allclose(_rotation(back[sl]), _rotation(q[sl]), atol=1e-14)
        np.testing.assert_allclose(chart.p_of(back), p, atol=1e-12)


@pytest.mark.parametrize("name", GROUP_CHARTS)
@pytest.mark.parametrize("case", GROUP_CASES)
def test_dpsi_and_its_rate_are_the_velocity_and_acceleration_maps(case, name):
    """``v = Dpsi pd``: moving p by ``h pd`` moves q as integrating ``h v`` on the group; ``vdot = Dpsi pdd + rate``:
    the central difference of ``Dpsi(p(t)) pd(t)`` along ``p(t) = p + t pd + t^2/2 pdd``."""
    model = cases.load(case)
    chart = charts.get(name, model)
    rng = np.random.default_rng(7)
    for s in sampling.sample_states(model, 4, 2, case)[1:]:
        _check_maps(model, chart, chart.p_of(np.array(s.q)), rng)


def _check_maps(model, chart, p, rng):
    """At p, along random pd and pdd: ``v = Dpsi pd`` (moving p by ``h pd`` is integrating ``h v`` on the group) and
    ``vdot = Dpsi pdd + rate`` (the central difference of ``Dpsi(p(t)) pd(t)``)."""
    pd, pdd = rng.standard_normal(model.nv), rng.standard_normal(model.nv)
    h = 1e-6
    moved = configuration.integrate(model, chart.q_of(p), h * chart.jacobian(p) @ pd)
    assert np.abs(moved - chart.q_of(p + h * pd)).max() < 1e-10
    ahead = chart.jacobian(p + h * pd + h * h / 2 * pdd) @ (pd + h * pdd)
    behind = chart.jacobian(p - h * pd + h * h / 2 * pdd) @ (pd - h * pdd)
    np.testing.assert_allclose((ahead - behind) / (2 * h), chart.jacobian(p) @ pdd + chart.jacobian_rate(p, pd),
                               atol=1e-7)


def test_gimbal_lock_leaves_the_chart_check_out():
    """At pitch = pi/2 the chart has no coordinates for one rotation: cond(Dpsi) is infinite, and the chart check is
    left out there rather than compared through a singular map."""
    model = cases.load("ball_pendulum")
    chart = charts.get("zyx", model)
    locked = chart.q_of([0.3, np.pi / 2, -0.2])
    assert np.linalg.cond(chart.jacobian(chart.p_of(locked))) > charts.GIMBAL_LIMIT
    state = sampling.State(0, tuple(locked), (0.5, -0.2, 1.0), (0.0, 0.0, 0.0))
    joint = {"pinocchio": reference.split(model, state.q, state.qd, state.u)}
    assert invariance.chart_checks(model, state, chart, joint, [reference.REFERENCE], {}) == {}


def test_which_charts_apply():
    group, scalar = cases.load("satellite_arm"), cases.load("double_pendulum")
    assert [c.name for c in charts.sampled(group, 0, "satellite_arm")] == ["zyx", "exp", "world", "mixed"]
    assert not {"zyx", "exp", "world", "mixed"} & {c.name for c in charts.sampled(scalar, 0, "double_pendulum")}
    with pytest.raises(charts.ChartError, match=r"does not apply .* \(its charts: zyx, exp, and the velocity"):
        charts.get("nonlinear", group)
    with pytest.raises(charts.ChartError, match="chart 'zyx' .* does not apply"):
        charts.get("zyx", scalar)
    with pytest.raises(charts.ChartError, match="chart 'exp' .* does not apply"):
        charts.get("exp", scalar)


def test_the_state_carried_into_the_chart_rounds_the_power():
    """A fuzz finding (seed 1701): a ball joint turning about body x with the input about z does no work, so the
    joint-chart power and every one of its terms is exactly 0, while the chart's pd = Dpsi^-1 v came out with 4.5e-16
    in yaw and both chart evaluations reported a power of 7.6e-17 against a tolerance of 1.7e-30. The chart power's
    tolerance now carries the rounding of the state's transfer into the chart (``invariance._transfer``)."""
    import json
    from pathlib import Path

    from crosscheck.campaigns.fuzz import replay

    finding = json.loads((Path(__file__).parents[1] / "findings" / "charts" / "3a211f395087.json").read_text())
    outcome = replay.replay(finding)
    power = outcome.checks["chart zyx: power_ctrl"]
    assert not outcome.failed and 0.0 < power.worst_ratio < 1e-2, power


def test_eval_refuses_a_chart_point_in_gimbal_lock(capsys):
    """At pitch pi/2 the zyx chart has no coordinates for the motion: eval says so in one line (exit 2) instead of
    reporting the chart-native backends' singular M_p as their errors."""
    from crosscheck import cli

    code = cli.main(["eval", "--case", "free_body", "--chart", "zyx", f"--q=0.1,0.2,0.3,0.4,{np.pi / 2!r},0.6",
                     "--qd=1,2,3,4,5,6"])
    err = capsys.readouterr().err
    assert code == 2 and len(err.splitlines()) == 1 and "gimbal lock" in err


# ------------------------------------------------------------------------------ exponential coordinates (exp)

def _exp_coefficients_exact(t: float) -> tuple[float, ...]:
    """``(a, b, A, B)`` of ``charts._exp_coefficients`` from their closed forms in 120-digit arithmetic (no series; at
    t = 1e-12 the numerators cancel 50 digits)."""
    import mpmath

    with mpmath.workdps(120):
        t = mpmath.mpf(t)
        s, c = mpmath.sin(t), mpmath.cos(t)
        return tuple(float(x) for x in ((1 - c) / t**2, (t - s) / t**3, (t * s - 2 * (1 - c)) / t**4,
                                        (t * (1 - c) - 3 * (t - s)) / t**5))


@pytest.mark.parametrize("t", [0.0, 1e-12, 1e-6, 1e-3, 0.05, 0.25, 0.5, 0.9, 0.999999, 1.0, 1.0001, 1.5, 2.0, 3.0,
                               np.pi])
def test_exp_coefficients_are_accurate_on_both_sides_of_the_series_branch(t):
    """Below ``EXP_SERIES_BELOW`` the Taylor series, above it the closed forms: both against the closed forms in high
    precision (t = 0 against the series' limits 1/2, 1/6, -1/12, -1/60), to a few units of rounding. (With the branch
    at 0.25 and series through t^8, the series was off by 4e-15 just below it and the closed form of B by 1.4e-12 just
    above: B's numerator cancels, eps / t^4 relatively.)"""
    got = charts._exp_coefficients(t)
    exact = (0.5, 1 / 6, -1 / 12, -1 / 60) if t == 0.0 else _exp_coefficients_exact(t)
    np.testing.assert_allclose(got, exact, rtol=1e-15 if t < charts.EXP_SERIES_BELOW else 4e-15)


def test_exp_series_branch_meets_the_closed_form():
    """At the branch point both formulas give the same coefficients (to rounding); J_r and its rate in the series
    branch equal the closed forms evaluated in high precision, to rounding of their own size (|J_r| ~ 1, the rate
    ~ |pd|^2), from 1e-7 to just below the branch."""
    t0 = charts.EXP_SERIES_BELOW
    below, above = charts._exp_coefficients(t0 * (1 - 1e-15)), charts._exp_coefficients(t0)
    np.testing.assert_allclose(below, above, rtol=4e-15)
    rng = np.random.default_rng(3)
    for t in (1e-7, 1e-4, 0.01, 0.1, 0.5, 0.99):
        w = rng.standard_normal(3)
        w *= t / np.linalg.norm(w)
        wd = rng.standard_normal(3)
        a, b, A, B = _exp_coefficients_exact(t)
        K, Kd = charts._skew(w), charts._skew(wd)
        exact_J = np.eye(3) - a * K + b * K @ K
        along = w @ wd
        exact_rate = -A * along * (K @ wd) + B * along * (K @ K @ wd) + b * (Kd @ K @ wd)
        ExpC = charts.ExponentialCoordinates
        np.testing.assert_allclose(ExpC.right_jacobian(w), exact_J, rtol=0, atol=4e-16)
        np.testing.assert_allclose(ExpC.right_jacobian_rate(w, wd), exact_rate, rtol=0, atol=4e-16 * wd @ wd)


def test_exp_psi_at_zero_is_the_centre():
    """With Python floats psi at ``p = 0`` exactly returns the limit, the centre (Euler–Lagrange's unit probe
    evaluates there with math.sin); next to 0 psi is continuous, Dpsi is the identity and the rate vanishes."""
    model = cases.load("satellite_arm")
    chart = charts.get("exp", model)
    zero = [0.0] * model.nv
    q = chart.psi(zero, math.sin, math.cos)
    np.testing.assert_array_equal(q[3:7], chart.centers[0])
    assert q[:3] == [0.0, 0.0, 0.0] and q[7:] == [0.0] * (model.nq - 7)
    near = chart.q_of(np.full(model.nv, 1e-9))
    assert np.abs(near - np.array(q)).max() < 1e-8
    np.testing.assert_array_equal(chart.p_of(np.array(q)), zero)
    np.testing.assert_allclose(chart.jacobian(zero)[3:6, 3:6], np.eye(3), atol=0)
    np.testing.assert_array_equal(chart.jacobian_rate(zero, np.ones(model.nv))[3:6], 0.0)


def test_exp_near_its_centre_by_finite_differences():
    """Dpsi and its rate in the series branch (|p| well below ``EXP_SERIES_BELOW``), against the group's integrate
    and central differences as in the sampled-state test."""
    model = cases.load("ball_double_pendulum")
    chart = charts.get("exp", model)
    rng = np.random.default_rng(11)
    for size in (1e-5, 1e-2, 0.5):
        p = rng.standard_normal(model.nv)
        _check_maps(model, chart, p * size / np.linalg.norm(p), rng)


def test_exp_domain_has_no_singularity():
    """p_of takes the shortest rotation (|p| <= pi; the quaternion's sign does not matter), and there
    ``cond(J_r) <= pi/2``, reached at |p| = pi: the gate's gimbal-lock limit never applies to this chart."""
    model = cases.load("ball_pendulum")
    chart = charts.get("exp", model)
    rng = np.random.default_rng(5)
    worst = 0.0
    for _ in range(200):
        quat = configuration.random_quaternion(rng)
        for sign in (1.0, -1.0):
            p = chart.p_of(sign * quat)
            assert np.linalg.norm(p) <= np.pi + 1e-12
            np.testing.assert_allclose(_rotation(chart.q_of(p)), _rotation(quat), atol=1e-14)
            worst = max(worst, np.linalg.cond(chart.jacobian(p)))
    assert worst <= np.pi / 2 + 1e-12
    edge = np.array([0.3, -0.5, 0.7])
    edge *= np.pi / np.linalg.norm(edge)
    assert np.linalg.cond(chart.jacobian(edge)) == pytest.approx(np.pi / 2, rel=1e-12)
    assert np.pi / 2 < charts.GIMBAL_LIMIT


def test_exp_centre_is_seeded_per_case_and_keeps_sampled_states_off_its_origin():
    """The centres are part of the chart (its key) and drawn from (seed, case): the same chart every run, another for
    another case or seed. The gate's state 0 of a free body has the identity orientation, which a chart centred at the
    identity would put at p = 0 (the removable 0/0); the drawn centre puts it at an angle of order 1."""
    model = cases.load("free_body")
    chart = charts.get("exp", model, 0, "free_body")
    assert chart.key == charts.get("exp", model, 0, "free_body").key
    assert chart.key != charts.get("exp", model, 1, "free_body").key
    assert chart.key != charts.get("exp", model, 0, "other").key
    assert chart.key != charts.get("zyx", model).key
    assert abs(np.linalg.norm(chart.centers[0]) - 1.0) < 1e-15
    state = sampling.sample_states(model, 1, 0, "free_body")[0]
    np.testing.assert_array_equal(state.q[3:7], (0.0, 0.0, 0.0, 1.0))
    assert np.linalg.norm(chart.p_of(np.array(state.q))[3:6]) > 0.1


def test_exp_at_its_centre_is_left_out_and_refused_by_eval(capsys):
    """Within ``EXP_CENTRE_LIMIT`` of p = 0 the chart-native backends differentiate the 0/0 of sin(t/2)/t (their
    answers are rounding there, a division by zero at 0 exactly): the chart check leaves such a state out, and eval
    refuses it in one line."""
    from crosscheck import cli

    model = cases.load("ball_pendulum")
    chart = charts.get("exp", model)
    limit = charts.EXP_CENTRE_LIMIT
    assert chart.at_centre([0.0, 0.0, 0.0]) and chart.at_centre([0.5 * limit, 0.0, 0.0])
    assert not chart.at_centre([2.0 * limit, 0.0, 0.0])
    from crosscheck import backends

    native = [backends.get(name) for name in ("euler_lagrange", "geometric")]
    for p, checked in (([1e-7, 0.0, 0.0], False), ([0.0, 1.2 * limit, -0.6 * limit], True)):
        state = sampling.State(0, tuple(chart.q_of(p)), (0.5, -0.2, 1.0), (0.3, -0.1, 0.2))
        joint = {"pinocchio": reference.split(model, state.q, state.qd, state.u)}
        checks = invariance.chart_checks(model, state, chart, joint, native, {})
        assert bool(checks) == checked
        # just outside the limit the native answers still agree with room to spare (the limit is where they stop to)
        assert all(c.worst_ratio < 0.1 for c in checks.values()), \
            {k: c.worst_ratio for k, c in checks.items()}
    code = cli.main(["eval", "--case", "free_body", "--chart", "exp", "--q=0.1,0.2,0.3,0,0,0", "--qd=1,2,3,4,5,6"])
    err = capsys.readouterr().err
    assert code == 2 and len(err.splitlines()) == 1 and "centre" in err


def test_a_wrong_exp_jacobian_in_the_harness_is_caught_by_the_native_evaluations(monkeypatch):
    """The chart check of exp can fail: with the harness's Dpsi taken as the LEFT Jacobian ``J_l = J_r^T`` (the
    exponential's other trivialization), every joint-chart answer is mapped wrongly, and the chart-native Euler–Lagrange
    and geometric answers, derived through psi alone, disagree with it."""
    from crosscheck import backends

    model = cases.load("ball_pendulum")
    chart = charts.get("exp", model, 0, "ball_pendulum")
    state = sampling.sample_states(model, 3, 0, "ball_pendulum")[2]
    joint = {"pinocchio": reference.split(model, state.q, state.qd, state.u)}
    native = [backends.get(name) for name in ("euler_lagrange", "geometric")]
    right = invariance.chart_checks(model, state, chart, joint, native, {})
    assert right and max(c.worst_ratio for c in right.values()) < 0.1
    monkeypatch.setattr(charts.ExponentialCoordinates, "right_jacobian",
                        staticmethod(lambda w, J=charts.ExponentialCoordinates.right_jacobian: J(w).T))
    left = invariance.chart_checks(model, state, chart, joint, native, {})
    assert left["chart exp: drift"].worst_ratio > 1e6 and left["chart exp: total"].worst_ratio > 1e6
