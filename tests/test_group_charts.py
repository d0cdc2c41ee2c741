"""The ZYX Euler-angle chart of spherical and free joints (``crosscheck.charts.EulerZYX``): the harness's own map
between the chart and the group, checked against the group operations (``cases.configuration``) by finite
differences, and its gimbal lock."""

from __future__ import annotations

import numpy as np
import pytest

import cases
from cases import configuration
from crosscheck import charts, invariance, reference, sampling

GROUP_CASES = ("free_body", "ball_pendulum", "ball_double_pendulum", "satellite_arm")


def _rotation(quat) -> np.ndarray:
    return configuration.rotation(np.asarray(quat, dtype=float))


@pytest.mark.parametrize("case", GROUP_CASES)
def test_the_chart_is_a_chart_of_the_group(case):
    """p -> q -> p is the identity; q -> p -> q gives the same rotations (a quaternion or its negative)."""
    model = cases.load(case)
    chart = charts.get("zyx", model)
    for s in sampling.sample_states(model, 6, 1, case):
        q = np.array(s.q)
        p = chart.p_of(q)
        back = chart.q_of(p)
        for _, sl in configuration.quaternion_slices(model):
            np.testing.assert_allclose(_rotation(back[sl]), _rotation(q[sl]), atol=1e-14)
        np.testing.assert_allclose(chart.p_of(back), p, atol=1e-12)


@pytest.mark.parametrize("case", GROUP_CASES)
def test_dpsi_and_its_rate_are_the_velocity_and_acceleration_maps(case):
    """``v = Dpsi pd``: moving p by ``h pd`` moves q as integrating ``h v`` on the group; ``vdot = Dpsi pdd + rate``:
    the central difference of ``Dpsi(p(t)) pd(t)`` along ``p(t) = p + t pd + t^2/2 pdd``."""
    model = cases.load(case)
    chart = charts.get("zyx", model)
    rng = np.random.default_rng(7)
    for s in sampling.sample_states(model, 4, 2, case)[1:]:
        p = chart.p_of(np.array(s.q))
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
    assert [c.name for c in charts.sampled(group, 0, "satellite_arm")] == ["zyx", "world", "mixed"]
    assert "zyx" not in [c.name for c in charts.sampled(scalar, 0, "double_pendulum")]
    with pytest.raises(charts.ChartError, match=r"does not apply .* \(its chart: zyx\)"):
        charts.get("nonlinear", group)
    with pytest.raises(charts.ChartError, match="chart 'zyx' .* does not apply"):
        charts.get("zyx", scalar)


def test_the_state_carried_into_the_chart_rounds_the_power():
    """A fuzz finding (seed 1701): a ball joint turning about body x with the input about z does no work, so the
    joint-chart power and every one of its terms is exactly 0, while the chart's pd = Dpsi^-1 v came out with 4.5e-16
    in yaw and both chart evaluations reported a power of 7.6e-17 against a tolerance of 1.7e-30. The chart power's
    tolerance now carries the rounding of the state's transfer into the chart (``invariance._transfer``)."""
    import json
    from pathlib import Path

    from crosscheck import fuzz

    finding = json.loads((Path(__file__).parent / "findings" / "charts" / "3a211f395087.json").read_text())
    outcome = fuzz.replay(finding)
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
