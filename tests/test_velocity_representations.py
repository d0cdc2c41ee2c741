"""The base-velocity representations ``world`` and ``mixed`` (``crosscheck.charts.VelocityRepresentation``): the
harness's map ``v = T(q) w`` and its rate ``Tdot w`` against the group operations (``cases.configuration``) by finite
differences, the native evaluations of Euler–Lagrange and geometric against Pinocchio, and the gate's chart check."""

from __future__ import annotations

import numpy as np
import pytest

import cases
from cases import configuration
from crosscheck import charts, sampling

CASES = ("free_body", "satellite_arm", "ball_pendulum", "solo12")
H = 1e-6


def _blocks(model):
    """(joint type, q slice start, v slice start) of every group joint."""
    return [(model.bodies[i].joint, model.q_index[i], model.v_index[i]) for i in model.group_joints]


def _pose(quat_pos_q, joint, j):
    """(R, p) of a group joint read from q (p = 0 for a spherical joint)."""
    q = np.asarray(quat_pos_q)
    if joint == "spherical":
        return configuration.rotation(q[j:j + 4]), np.zeros(3)
    return configuration.rotation(q[j + 3:j + 7]), q[j:j + 3]


def _states(model, case, count=3):
    return sampling.sample_states(model, count + 1, 3, case)[1:]


@pytest.mark.parametrize("case", CASES)
@pytest.mark.parametrize("name", charts.REPRESENTATIONS)
def test_T_maps_the_representation_to_the_body_velocity(case, name):
    """Moving q by ``+-h v`` (``integrate``, v = T w) moves each group joint's pose at ``pdot`` and ``omega_s`` (central
    differences, in the joint's reference frame); w must be ``(pdot - omega_s x p, omega_s)`` in world,
    ``(pdot, omega_s)`` in mixed, ``omega_s`` for a ball joint, and the scalar rates unchanged."""
    model = cases.load(case)
    chart = charts.get(name, model)
    rng = np.random.default_rng(3)
    for s in _states(model, case):
        q = np.array(s.q)
        assert np.array_equal(chart.p_of(q), q) and np.array_equal(chart.q_of(q), q)
        w = rng.standard_normal(model.nv)
        v = chart.jacobian(q) @ w
        ahead, behind = configuration.integrate(model, q, H * v), configuration.integrate(model, q, -H * v)
        scalar = np.ones(model.nv, dtype=bool)
        for joint, j, k in _blocks(model):
            (Ra, pa), (Rb, pb), (R, p) = (_pose(x, joint, j) for x in (ahead, behind, q))
            omega = (Ra - Rb) / (2 * H) @ R.T
            omega_s = np.array([omega[2, 1], omega[0, 2], omega[1, 0]])
            if joint == "spherical":
                np.testing.assert_allclose(omega_s, w[k:k + 3], atol=1e-8)
                scalar[k:k + 3] = False
                continue
            pdot = (pa - pb) / (2 * H)
            expected_linear = pdot - np.cross(omega_s, p) if name == "world" else pdot
            np.testing.assert_allclose(expected_linear, w[k:k + 3], atol=1e-8)
            np.testing.assert_allclose(omega_s, w[k + 3:k + 6], atol=1e-8)
            scalar[k:k + 6] = False
        np.testing.assert_array_equal(v[scalar], w[scalar])


@pytest.mark.parametrize("case", CASES)
@pytest.mark.parametrize("name", charts.REPRESENTATIONS)
def test_the_rate_term_is_the_derivative_of_T_w(case, name):
    """``vdot = T wdot + Tdot w``: the central difference of ``T(q(t)) w(t)`` along ``q(t) = q (+) t v``,
    ``w(t) = w + t wdot`` (the ``t^2`` term of q(t) cancels in a central difference)."""
    model = cases.load(case)
    chart = charts.get(name, model)
    rng = np.random.default_rng(5)
    for s in _states(model, case):
        q = np.array(s.q)
        w, wdot = rng.standard_normal(model.nv), rng.standard_normal(model.nv)
        v = chart.jacobian(q) @ w
        ahead = chart.jacobian(configuration.integrate(model, q, H * v)) @ (w + H * wdot)
        behind = chart.jacobian(configuration.integrate(model, q, -H * v)) @ (w - H * wdot)
        rate = chart.jacobian_rate(q, w)
        np.testing.assert_allclose((ahead - behind) / (2 * H), chart.jacobian(q) @ wdot + rate, atol=1e-7)
        if name == "world" or not any(j == "free" for j, _, _ in _blocks(model)):
            assert not rate.any()                # exactly zero: ad_V V = 0
        else:
            assert np.abs(rate).max() > 1e-3     # the mixed rate is not vacuous with a free joint


def test_which_representations_apply():
    names = lambda case: [c.name for c in charts.sampled(cases.load(case), 0, case)]  # noqa: E731
    assert names("free_body") == ["zyx", "world", "mixed"]
    assert names("ball_pendulum") == ["zyx", "world"]
    assert charts.get("world", cases.load("free_body")).key != charts.get("mixed", cases.load("free_body")).key
    with pytest.raises(charts.ChartError, match="chart 'world' .* no spherical or free joint"):
        charts.get("world", cases.load("double_pendulum"))
