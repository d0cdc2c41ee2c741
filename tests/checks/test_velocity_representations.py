"""The base-velocity representations ``world`` and ``mixed`` (``crosscheck.checks.charts.VelocityRepresentation``): the
harness's map ``v = T(q) w`` and its rate ``Tdot w`` against the group operations (``cases.configuration``) by finite
differences, the native evaluations of Euler–Lagrange and geometric against Pinocchio, and the gate's chart check."""

from __future__ import annotations

import numpy as np
import pytest

import cases
from cases import configuration
from crosscheck.checks import charts
from crosscheck.core import sampling

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
    assert names("free_body") == ["zyx", "exp", "world", "mixed"]
    assert names("ball_pendulum") == ["zyx", "exp", "world"]
    assert charts.get("world", cases.load("free_body")).key != charts.get("mixed", cases.load("free_body")).key
    with pytest.raises(charts.ChartError, match="chart 'world' .* no spherical or free joint"):
        charts.get("world", cases.load("double_pendulum"))


# ------------------------------------------------------------------------------ native evaluations vs Pinocchio

def _hat(a):
    return np.array([[0.0, -a[2], a[1]], [a[2], 0.0, -a[0]], [-a[1], a[0], 0.0]])


def _expected_free(name, R, p, v_b, w_b, a_b, alpha_b, f, n):
    """(w, wdot, tau_w) of a free body in ``name`` from its body twist, body acceleration (``dv/dt`` of the body
    twist, Pinocchio's ``aba``) and body wrench (f, n): the test's own algebra, not the chart's ``T``."""
    pdot, omega_s = R @ v_b, R @ w_b
    pddot = R @ (a_b + np.cross(w_b, v_b))             # the classical acceleration of the body origin
    omegadot_s = R @ alpha_b                            # R (alpha_b + w_b x w_b)
    if name == "mixed":
        return (np.r_[pdot, omega_s], np.r_[pddot, omegadot_s], np.r_[R @ f, R @ n])
    v_s = pdot - np.cross(omega_s, p)
    vdot_s = pddot - np.cross(omegadot_s, p) - np.cross(omega_s, pdot)
    return np.r_[v_s, omega_s], np.r_[vdot_s, omegadot_s], np.r_[R @ f, np.cross(p, R @ f) + R @ n]


def _native(name):
    from formalisms import euler_lagrange, geometric
    return {"euler_lagrange": euler_lagrange.split_chart, "geometric": geometric.split_chart}


@pytest.mark.parametrize("case", ("free_body", "ball_pendulum"))
@pytest.mark.parametrize("name", charts.REPRESENTATIONS)
def test_native_answers_are_pinocchios_aba_in_the_representation(case, name):
    """Euler–Lagrange and geometric evaluated in the representation (``split_chart``: q, w, tau_w) give the
    representation's acceleration ``wdot``: Pinocchio's ``aba`` (body-frame ``vdot``) carried into world or mixed by
    the test's own algebra (``_expected_free``; a ball joint: ``omega_s = R w_b``, ``d/dt omega_s = R alpha_b``,
    ``tau = R n``). Drift with u = 0, total with the input."""
    import pinocchio as pin

    from crosscheck.references.pinocchio import build
    model = cases.load(case)
    pm = build.to_pinocchio(model)
    data = pm.createData()
    assert (pm.nq, pm.nv) == (model.nq, model.nv)          # one joint: the same coordinates
    chart = charts.get(name, model)
    rng = np.random.default_rng(11)
    for s in _states(model, case, 4):
        q, v = np.array(s.q), np.array(s.qd)
        force = rng.standard_normal(model.nv)                # a v-space generalized force (body wrench)
        for tau_v in (np.zeros(model.nv), force):
            vdot = np.array(pin.aba(pm, data, q, v, tau_v))
            if case == "free_body":
                R, p = configuration.rotation(q[3:7]), q[:3]
                w, wdot, tau_w = _expected_free(name, R, p, v[:3], v[3:], vdot[:3], vdot[3:], tau_v[:3], tau_v[3:])
            else:
                R = configuration.rotation(q[:4])
                w, wdot, tau_w = R @ v, R @ vdot, R @ tau_v
            scale = 1.0 + np.abs(wdot).max()
            for backend, split_chart in _native(name).items():
                got = split_chart(model, chart, q, w, tau_w)
                assert np.abs(got.total - wdot).max() <= 1e-12 * scale, (backend, got.total, wdot)
                if not tau_v.any():
                    assert np.abs(got.drift - wdot).max() <= 1e-12 * scale, (backend, got.drift, wdot)
                M = np.triu(pin.crba(pm, data, q))
                M = M + np.triu(M, 1).T
                assert got.kinetic_energy == pytest.approx(0.5 * v @ M @ v, rel=1e-12, abs=1e-12)
                assert got.power_ctrl == pytest.approx(tau_v @ v, rel=1e-12, abs=1e-12)


@pytest.mark.parametrize("case", ("satellite_arm", "ball_double_pendulum", "solo12"))
@pytest.mark.parametrize("name", charts.REPRESENTATIONS)
def test_native_answers_match_the_reference_on_trees(case, name):
    """On trees with a floating base or ball joints and revolute joints, the native ``wdot`` equals the Pinocchio
    reference's ``vdot`` (``crosscheck.references.pinocchio.reference``, our coordinate order) carried by the chart's map
    ``wdot = T^-1 (vdot - Tdot w)``, checked by ``T`` and ``Tdot w`` of the finite-difference tests above."""
    from crosscheck.references.pinocchio import build
    from crosscheck.references.pinocchio import reference
    model = cases.load(case)
    chart = charts.get(name, model)
    for s in _states(model, case, 2):
        q, v, u = np.array(s.q), np.array(s.qd), np.array(s.u)
        w = charts.velocity_to_chart(chart, q, v)
        tau_w = charts.force_to_chart(chart, q, model.input_map @ u)
        ref = reference.split(model, q, v, u)
        want = charts.acceleration_to_chart(chart, q, w, ref.total)
        for backend, split_chart in _native(name).items():
            got = split_chart(model, chart, q, w, tau_w)
            assert np.abs(got.total - want).max() <= 1e-9 * (1.0 + np.abs(want).max()), backend


def test_a_representation_is_refused_without_group_joints():
    from formalisms import euler_lagrange, geometric
    from formalisms.interface import ModelNotSupported
    model = cases.load("double_pendulum")
    chart = charts.VelocityRepresentation("world", "world", tuple(b.joint for b in model.bodies))
    for split_chart in (euler_lagrange.split_chart, geometric.split_chart):
        with pytest.raises(ModelNotSupported, match="no spherical or free joint"):
            split_chart(model, chart, np.zeros(model.nq), np.zeros(model.nv), np.zeros(model.nv))


# ----------------------------------------------------------------------------------------- the gate's chart check

@pytest.mark.parametrize("case", ("free_body", "ball_pendulum", "ball_double_pendulum", "satellite_arm", "solo12"))
def test_the_chart_check_passes_with_every_native_backend_voting(case):
    """``invariance.chart_checks`` in world (and mixed, with a free joint) on the group cases: every comparison agrees,
    and both native backends vote on the accelerations (a harness-side map alone would check nothing)."""
    from crosscheck import backends
    from crosscheck.checks import invariance
    model = cases.load(case)
    chosen = [backends.get(n) for n in backends.names()]
    for chart in charts.representations_sampled(model):
        for s in _states(model, case, 3):
            q, v, u = np.array(s.q), np.array(s.qd), np.array(s.u)
            joint = {b.name: b.split(model, q, v, u) for b in chosen}
            errors: dict = {}
            checks = invariance.chart_checks(model, s, chart, joint, chosen, errors)
            assert not errors, errors
            total = checks[f"chart {chart.name}: total"]
            assert {f"euler_lagrange@{chart.name}", f"geometric@{chart.name}"} <= set(total.voters), total.voters
            bad = {k: (c.verdict, c.worst_ratio) for k, c in checks.items() if c.verdict != "agree"}
            assert not bad, bad
