"""Tests of the geometric backend (article 6.4, eqs. 24-25): metric, Levi-Civita connection, intrinsic drift field.

References written independently of the backend:
* the double pendulum's closed forms (``closed_forms.py``: article eqs. 5-8 in relative angles, and the Lagrangian
  written directly in absolute angles, 6.4.6);
* textbook Christoffel symbols and curvature of the flat plane in polar coordinates, the unit sphere and the
  hyperbolic half-plane;
* the harness's analytic chart maps (``crosscheck.checks.charts``: ``qd = Dpsi pd``, ``tau_p = Dpsi^T tau``,
  ``pdd = Dpsi^-1 (qdd - (d/dt Dpsi) pd)``) for chart invariance;
* classical identities: symmetry of the connection in its lower indices, ``Mdot - 2C`` skew-symmetric, energy
  balance ``dE/dt = tau . qd`` (section 9), central differences of the metric.
Agreement with Pinocchio is tests/references/test_against_pinocchio.py (it iterates every registered formalism).
"""

from __future__ import annotations

import casadi as ca
import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

import cases
import formalisms
from closed_forms import absolute_terms, article_M, endpoint_jacobian, inv2, pendulum_terms
from scenes import panda_arm
from crosscheck.checks import charts
from formalisms import geometric as geo
from formalisms.interface import StateError

PENDULUM, SPATIAL_ARM, PANDA = cases.load("double_pendulum"), cases.load("spatial_arm"), panda_arm()
angle = st.floats(-np.pi, np.pi)
rate = st.floats(-5.0, 5.0)
torque = st.floats(-20.0, 20.0)


def states(model):
    """(q, qd, u): revolute angles in [-pi, pi], prismatic in [-0.5, 0.5], rates in [-5, 5], inputs in [-20, 20]."""
    q = st.tuples(*[angle if b.joint == "revolute" else st.floats(-0.5, 0.5) for b in model.bodies])
    return st.tuples(q, st.tuples(*[rate] * model.n), st.tuples(*[torque] * model.m)).map(
        lambda t: tuple(np.array(x, dtype=float) for x in t))


def assert_close(got, want, tol, what):
    err = np.abs(np.asarray(got, dtype=float) - np.asarray(want, dtype=float)).max()
    assert err <= tol, f"{what}: error {err:.3e} > tolerance {tol:.3e}\n  got  {np.asarray(got).tolist()}\n" \
                       f"  want {np.asarray(want).tolist()}"


def pendulum_answer(M, Cqd, g, tau):
    """(drift, ctrl, total) from closed-form terms, with the article's 2x2 inverse, and the size of the summed
    accelerations (the scale of a relative tolerance)."""
    Minv = inv2(M)
    scale = np.abs(Minv).sum() * (np.abs(Cqd).sum() + np.abs(g).sum() + np.abs(tau).sum()) + 1e-300
    return -Minv @ (Cqd + g), Minv @ tau, Minv @ (tau - Cqd - g), scale


def test_registered():
    assert "geometric" in formalisms.names()
    f = formalisms.get("geometric")
    assert f.split is geo.split and f.split_chart is geo.split_chart and "6.4" in f.summary


# ------------------------------------------------------------------------------------ double pendulum, article


@given(states(PENDULUM))
def test_double_pendulum_matches_the_article_closed_forms(state):
    """Relative angles: drift = -M^-1 (C qd + g), ctrl = M^-1 u, total = M^-1 (u - C qd - g) (eqs. 6-10), the
    metric is eq. (6), M Gamma(qd, qd) is eq. (7), T = 1/2 qd^T M qd, and the task drift is the endpoint's
    classical acceleration J qdd + Jdot qd (eqs. 4, 5, 23)."""
    q, qd, u = state
    M, Cqd, g = pendulum_terms(q, qd)
    drift, ctrl, total, scale = pendulum_answer(M, Cqd, g, u)
    s = geo.split(PENDULUM, q, qd, u)
    for name, want in (("drift", drift), ("ctrl", ctrl), ("total", total)):
        assert_close(getattr(s, name), want, 1e-12 * scale, name)
    assert_close(s.additivity, 0.0, 1e-13 * scale, "additivity")
    assert_close(geo.metric(PENDULUM, q), M, 1e-14 * np.abs(M).max(), "metric vs eq. (6)")
    Gamma = geo.christoffel(PENDULUM, q)
    assert_close(M @ np.einsum("ijk,j,k->i", Gamma, qd, qd), Cqd, 1e-12 * (np.abs(M).max() * qd @ qd + 1e-300),
                 "M Gamma(qd, qd) vs eq. (7)")
    assert abs(s.kinetic_energy - 0.5 * qd @ M @ qd) <= 1e-13 * (np.abs(M).max() * qd @ qd + 1e-300)
    assert abs(s.power_ctrl - u @ qd) <= 1e-13 * np.abs(u) @ np.abs(qd) + 1e-300
    phi, phid = q[0] + np.array([0.0, q[1]]), qd[0] + np.array([0.0, qd[1]])
    bias = (phid**2 * np.array([-np.sin(phi), np.cos(phi)])).sum(axis=1)  # endpoint acceleration at qdd = 0
    task = endpoint_jacobian(q) @ drift + bias
    assert_close(s.task_drift, task, 1e-12 * (3 * scale + 2 * phid @ phid), "task drift vs eqs. (5), (23)")


@given(st.floats(0.3, 3.0), st.floats(0.3, 3.0), st.floats(0.3, 2.0), st.floats(0.3, 2.0), states(PENDULUM))
@settings(max_examples=10)
def test_double_pendulum_other_parameters(m1, m2, l1, l2, state):
    """The closed forms with unequal masses and lengths (a backend that hard-wires 1s fails here)."""
    q, qd, u = state
    model = cases.load("double_pendulum", m1=m1, m2=m2, l1=l1, l2=l2, g=3.7)
    M, Cqd, g = pendulum_terms(q, qd, m1, m2, l1, l2, 3.7)
    drift, ctrl, total, scale = pendulum_answer(M, Cqd, g, u)
    s = geo.split(model, q, qd, u)
    for name, want in (("drift", drift), ("ctrl", ctrl), ("total", total)):
        assert_close(getattr(s, name), want, 1e-12 * scale, name)


@given(states(PENDULUM))
def test_double_pendulum_in_absolute_angles(state):
    """Article 6.4.6: in phi = (theta1, theta1 + theta2) the metric and connection differ but the motion does not.
    (a) split_chart equals the closed form written from the Lagrangian in phi (absolute_terms) with
    tau_p = Dpsi^T tau = (tau1 - tau2, tau2); (b) it equals the relative-angle answer mapped,
    phi_dd = (theta1_dd, theta1_dd + theta2_dd); the metric is absolute_terms' M; power and T are the joint ones."""
    q, qd, u = state
    chart = charts.get("absolute", PENDULUM)
    phi, phid = np.array([q[0], q[0] + q[1]]), np.array([qd[0], qd[0] + qd[1]])
    assert_close(chart.q_of(phi), q, 1e-15 * (1 + np.abs(q).max()), "the chart is q = psi(phi)")
    tau_p = np.array([u[0] - u[1], u[1]])
    s = geo.split_chart(PENDULUM, chart, phi, phid, tau_p)
    M_a, Cqd_a, g_a = absolute_terms(phi, phid)
    drift, ctrl, total, scale = pendulum_answer(M_a, Cqd_a, g_a, tau_p)
    for name, want in (("drift", drift), ("ctrl", ctrl), ("total", total)):
        assert_close(getattr(s, name), want, 1e-12 * scale, f"absolute {name} vs absolute_terms")
    M, Cqd, g = pendulum_terms(q, qd)
    rel = pendulum_answer(M, Cqd, g, u)
    to_phi = np.array([[1.0, 0.0], [1.0, 1.0]])
    for name, want in zip(("drift", "ctrl", "total"), rel[:3]):
        assert_close(getattr(s, name), to_phi @ want, 2e-12 * (scale + rel[3]), f"absolute {name} vs relative")
    assert_close(geo.metric(PENDULUM, phi, chart), M_a, 1e-14 * np.abs(M_a).max(), "metric vs absolute_terms")
    joint = geo.split(PENDULUM, q, qd, u)
    assert abs(s.kinetic_energy - joint.kinetic_energy) <= 1e-13 * (joint.kinetic_energy + 1e-300)
    assert abs(s.power_ctrl - joint.power_ctrl) <= 1e-13 * (np.abs(u) @ np.abs(qd) + np.abs(tau_p) @ np.abs(phid)) \
        + 1e-300
    assert_close(s.task_drift, joint.task_drift, 1e-12 * (3 * scale + 2 * phid @ phid), "task drift")


def test_absolute_chart_changes_the_coordinate_expressions():
    """The Christoffel symbols are chart-dependent (6.4.4): different numbers in phi than in theta, so the test
    above compares genuinely different computations."""
    q = np.array([0.4, 1.1])
    chart = charts.get("absolute", PENDULUM)
    G_theta = geo.christoffel(PENDULUM, q)
    G_phi = geo.christoffel(PENDULUM, chart.p_of(q), chart)
    assert np.abs(G_theta - G_phi).max() > 0.1


# ------------------------------------------------------------------------------------- generic metric machinery


def polar(x):
    return ca.diag(ca.vertcat(1, x[0] ** 2))


def sphere(x):
    return ca.diag(ca.vertcat(1, ca.sin(x[0]) ** 2))


def half_plane(x):
    return ca.SX.eye(2) / x[1] ** 2


def gaussian_curvature(metric_fn, x):
    """Sectional curvature of the (0, 1) plane: g_0i R^i_101 / (g_00 g_11 - g_01^2) (curvature_of's convention)."""
    R = geo.curvature_of(metric_fn, x)
    G = np.array(ca.DM(metric_fn(ca.DM(x))).full())
    return G[0] @ R[:, 1, 0, 1] / (G[0, 0] * G[1, 1] - G[0, 1] ** 2), R


@given(st.floats(0.2, 5.0), angle)
def test_polar_coordinates_connection_without_curvature(r, th):
    """Flat plane in polar coordinates (6.4.4): Gamma^r_thth = -r, Gamma^th_rth = Gamma^th_thr = 1/r, the other five
    zero, yet the curvature vanishes."""
    Gamma = geo.christoffel_of(polar, [r, th])
    want = np.zeros((2, 2, 2))
    want[0, 1, 1] = -r
    want[1, 0, 1] = want[1, 1, 0] = 1.0 / r
    assert_close(Gamma, want, 1e-14 * (r + 1 / r), "polar Christoffel symbols")
    assert_close(geo.curvature_of(polar, [r, th]), 0.0, 1e-13 * (1 + 1 / r**2), "polar curvature")


@given(st.floats(0.2, np.pi - 0.2), angle)
def test_curved_metrics_have_curvature(th, ph):
    """The curvature check can fail: the unit sphere (theta, phi) has R^th_{ph th ph} = sin^2 theta and Gaussian
    curvature +1; the hyperbolic half-plane has -1. R is antisymmetric in its last two indices."""
    K, R = gaussian_curvature(sphere, [th, ph])
    assert abs(R[0, 1, 0, 1] - np.sin(th) ** 2) <= 1e-13
    assert abs(K - 1.0) <= 1e-12
    assert_close(R, -R.transpose(0, 1, 3, 2), 1e-14, "antisymmetry in (k, l)")
    K, _ = gaussian_curvature(half_plane, [ph, 0.5 + th])
    assert abs(K + 1.0) <= 1e-12


@given(angle, angle)
def test_christoffel_of_the_article_metric_equals_the_mechanism_connection(t1, t2):
    """christoffel_of on eq. (6) typed in as a casadi metric equals the mechanism's connection (the same formula
    applied to a metric the backend derived itself from the model)."""
    def article_metric(x):
        c2 = ca.cos(x[1])
        return ca.vertcat(ca.horzcat(3 + 2 * c2, 1 + c2), ca.horzcat(1 + c2, 1))

    q = np.array([t1, t2])
    assert_close(geo.christoffel_of(article_metric, q), geo.christoffel(PENDULUM, q), 1e-13, "Gamma")
    assert_close(article_metric(ca.DM(q)).full(), article_M(t2), 1e-15, "the typed-in metric is eq. (6)")


def test_generic_metric_errors():
    with pytest.raises(ValueError, match="2x2"):
        geo.christoffel_of(lambda x: ca.SX.eye(3), [1.0, 2.0])
    with pytest.raises(ValueError, match="positive definite"):
        geo.christoffel_of(lambda x: ca.diag(ca.vertcat(1, -1)), [1.0, 2.0])
    with pytest.raises(ValueError, match="symmetric"):
        geo.christoffel_of(lambda x: ca.vertcat(ca.horzcat(2, x[0]), ca.horzcat(0, 2)), [1.0, 2.0])


# ------------------------------------------------------------------------------ connection identities, 3-D arms


def first_kind_and_mdot(model, q, qd):
    """(M, M Gamma, Mdot, dM) with Mdot from the backend's own metric derivatives along qd."""
    M, dM, Gamma = geo.metric(model, q), geo.metric_derivatives(model, q), geo.christoffel(model, q)
    return M, np.einsum("il,ljk->ijk", M, Gamma), np.einsum("kij,k->ij", dM, qd), dM


@pytest.mark.parametrize("model", [SPATIAL_ARM, PANDA], ids=lambda m: m.name)
@given(data=st.data())
@settings(max_examples=8)
def test_connection_identities(model, data):
    """Gamma^i_jk = Gamma^i_kj; with C_ij = sum_k (M Gamma)_ijk qd_k (first kind), Mdot - 2C is skew-symmetric
    (classical passivity identity) and C qd = M Gamma(qd, qd); dM is the derivative of the metric (central
    differences of ``metric`` along each coordinate)."""
    q, qd, _ = data.draw(states(model))
    Gamma = geo.christoffel(model, q)
    assert_close(Gamma, Gamma.transpose(0, 2, 1), 1e-15 * np.abs(Gamma).max(), "symmetric lower indices")
    M, first, Mdot, dM = first_kind_and_mdot(model, q, qd)
    C = np.einsum("ijk,k->ij", first, qd)
    N = Mdot - 2 * C
    scale = np.abs(dM).max() * np.abs(qd).sum()
    assert_close(N, -N.T, 1e-13 * scale, "Mdot - 2C skew")
    assert_close(C @ qd, M @ np.einsum("ijk,j,k->i", Gamma, qd, qd), 1e-13 * scale * np.abs(qd).sum(), "C qd")
    h = 1e-3
    for k in range(model.n):
        e = np.eye(model.n)[k]
        fd = (-geo.metric(model, q + 2 * h * e) + 8 * geo.metric(model, q + h * e)
              - 8 * geo.metric(model, q - h * e) + geo.metric(model, q - 2 * h * e)) / (12 * h)
        assert_close(dM[k], fd, 1e-9 * (np.abs(M).max() + np.abs(dM).max()), f"dM/dq_{k} vs differences")


def test_skew_identity_can_fail():
    """The skew check catches a wrong connection: with the Christoffel formula's last term sign flipped
    (Gamma_{l,jk} = 1/2 (d_j M_lk + d_k M_lj + d_l M_jk)) Mdot - 2C is far from skew."""
    rng = np.random.default_rng(3)
    q, qd = rng.uniform(-1, 1, PANDA.n), rng.uniform(-2, 2, PANDA.n)
    dM = geo.metric_derivatives(PANDA, q)
    wrong = 0.5 * (dM.transpose(1, 0, 2) + dM.transpose(1, 2, 0) + dM)
    N = np.einsum("kij,k->ij", dM, qd) - 2 * np.einsum("ijk,k->ij", wrong, qd)
    assert np.abs(N + N.T).max() > 1e-3 * np.abs(dM).max() * np.abs(qd).sum()


# ----------------------------------------------------------------------------------------- chart invariance


def invariance_tolerance(chart, p, s_q, s_p):
    """1e-12 of the accelerations the summed terms could produce in either chart, times cond(Dpsi) (the map)."""
    return 1e-12 * (s_q.accel_scale + s_p.accel_scale) * np.linalg.cond(chart.jacobian(p))


def chart_cases():
    out = []
    for model in (PENDULUM, SPATIAL_ARM):
        out.append((model, charts.get("nonlinear", model)))
        out.append((model, charts.random_affine(model, 7, model.name)))
    return out


@pytest.mark.parametrize("model, chart", chart_cases(), ids=lambda x: getattr(x, "name", None))
@given(data=st.data())
@settings(max_examples=10)
def test_chart_invariance(model, chart, data):
    """split_chart at (p, pd = Dpsi^-1 qd, tau_p = Dpsi^T B u) equals split at (q, qd, u) mapped into the chart
    (ctrl without the rate term); T, power and the (physical) task drift are the same."""
    q, qd, u = data.draw(states(model))
    p = chart.p_of(q)
    assert_close(chart.q_of(p), q, 1e-12 * (1 + np.abs(q).max()), "chart inverse")
    pd = charts.velocity_to_chart(chart, p, qd)
    tau = model.input_map @ u
    tau_p = charts.force_to_chart(chart, p, tau)
    s_p = geo.split_chart(model, chart, p, pd, tau_p)
    s_q = geo.split(model, q, qd, u)
    tol = invariance_tolerance(chart, p, s_q, s_p)
    for name in ("drift", "total"):
        assert_close(getattr(s_p, name), charts.acceleration_to_chart(chart, p, pd, getattr(s_q, name)), tol, name)
    assert_close(s_p.ctrl, charts.acceleration_to_chart(chart, p, pd, s_q.ctrl, with_rate=False), tol, "ctrl")
    assert abs(s_p.kinetic_energy - s_q.kinetic_energy) <= 1e-12 * (s_q.kinetic_energy + 1e-300)
    power_scale = np.abs(tau) @ np.abs(qd) + np.abs(tau_p) @ np.abs(pd)  # the summed terms in both charts
    assert abs(s_p.power_ctrl - s_q.power_ctrl) <= 1e-13 * power_scale + 1e-300
    assert_close(s_p.task_drift, s_q.task_drift, 1e-10 * (s_q.accel_scale + qd @ qd), "task drift")


def test_chart_invariance_can_fail():
    """Mapping a chart's answer without the rate term (d/dt Dpsi) pd is visibly wrong: the comparison above sees
    the chart's own velocity-product term."""
    chart = charts.get("nonlinear", SPATIAL_ARM)
    rng = np.random.default_rng(5)
    q, qd, u = rng.uniform(-1, 1, 6), rng.uniform(-2, 2, 6), rng.uniform(-5, 5, 6)
    p = chart.p_of(q)
    pd = charts.velocity_to_chart(chart, p, qd)
    s_p = geo.split_chart(SPATIAL_ARM, chart, p, pd, charts.force_to_chart(chart, p, u))
    s_q = geo.split(SPATIAL_ARM, q, qd, u)
    wrong = charts.acceleration_to_chart(chart, p, pd, s_q.drift, with_rate=False)
    assert np.abs(s_p.drift - wrong).max() > 1e3 * invariance_tolerance(chart, p, s_q, s_p)


# ------------------------------------------------------------------------------------------- energy balance


def energy_cases():
    return [(PENDULUM, None), (PENDULUM, charts.get("nonlinear", PENDULUM)), (PANDA, None),
            (PANDA, charts.get("nonlinear", PANDA))]


@pytest.mark.parametrize("model, chart", energy_cases(),
                         ids=lambda x: x.name if x is not None else "joint")
@given(data=st.data())
@settings(max_examples=8)
def test_energy_rate(model, chart, data):
    """Section 9: dE/dt = 0 along the drift and tau . pd along the total (automatic differentiation of E = T + V),
    in the joint chart and in a nonlinear chart; the momentum dT/dpd is M pd, T = 1/2 pd^T M pd; and a wrong
    acceleration (the drift without its Christoffel term, -grad V) breaks the balance."""
    q, qd, u = data.draw(states(model))
    tau = model.input_map @ u
    if chart is None:
        p, pd, tau_p = q, qd, tau
        s = geo.split(model, q, qd, u)
    else:
        p = chart.p_of(q)
        pd = charts.velocity_to_chart(chart, p, qd)
        tau_p = charts.force_to_chart(chart, p, tau)
        s = geo.split_chart(model, chart, p, pd, tau_p)
    at_drift = geo.energy_rate(model, p, pd, s.drift, chart)
    assert abs(at_drift.rate) <= 1e-12 * at_drift.magnitude + 1e-300
    at_total = geo.energy_rate(model, p, pd, s.total, chart)
    assert abs(at_total.rate - tau_p @ pd) <= 1e-12 * (at_total.magnitude + np.abs(tau_p) @ np.abs(pd)) + 1e-300
    M = geo.metric(model, p, chart)
    assert_close(at_drift.momentum, M @ pd, 1e-13 * np.abs(M).max() * np.abs(pd).sum() + 1e-300, "momentum")
    T, V = geo.energy(model, p, pd, chart)
    assert abs(T - 0.5 * pd @ M @ pd) <= 1e-13 * np.abs(M).max() * pd @ pd + 1e-300
    assert abs(T - s.kinetic_energy) <= 1e-13 * (T + 1e-300)
    gamma = np.einsum("ijk,j,k->i", geo.christoffel(model, p, chart), pd, pd)
    wrong = geo.energy_rate(model, p, pd, s.drift + gamma, chart)
    if np.abs(M @ gamma) @ np.abs(pd) > 1e-6 * at_drift.magnitude:  # not a state where Gamma(pd, pd) . M pd ~ 0
        assert abs(wrong.rate) > 1e-8 * wrong.magnitude


def test_energy_matches_the_closed_form_potential():
    """V = -(m1 + m2) g l1 cos t1 - m2 g l2 cos(t1 + t2) for the double pendulum (absolute_terms' docstring)."""
    q = np.array([0.7, -1.9])
    T, V = geo.energy(PENDULUM, q, np.zeros(2))
    assert T == 0.0
    assert abs(V - (-2 * 9.81 * np.cos(0.7) - 9.81 * np.cos(0.7 - 1.9))) <= 1e-13


# ---------------------------------------------------------------------------------------- the drift field


@given(states(SPATIAL_ARM))
@settings(max_examples=10)
def test_drift_field(state):
    """Eq. (25): f = (qd, -Gamma(qd, qd) - grad V); with grad V = M^-1 dV/dq recovered from the qd = 0 field."""
    q, qd, u = state
    f = geo.drift_field(SPATIAL_ARM, q, qd)
    s = geo.split(SPATIAL_ARM, q, qd, u)
    assert f.shape == (12,) and np.array_equal(f[:6], qd) and np.array_equal(f[6:], s.drift)
    grad_V = -geo.drift_field(SPATIAL_ARM, q, np.zeros(6))[6:]
    gamma = np.einsum("ijk,j,k->i", geo.christoffel(SPATIAL_ARM, q), qd, qd)
    assert_close(f[6:], -gamma - grad_V, 1e-12 * s.accel_scale, "drift = -Gamma(qd, qd) - grad V")


# ---------------------------------------------------------------------------------------- purity, caching, input


def test_repeated_evaluation_is_pure_and_cached():
    """The shared evaluation buffer leaks nothing between states, results are not views into it, and the compiled
    Function is built once per (model, chart) (a renamed copy of a model shares it)."""
    rng = np.random.default_rng(11)
    a = [rng.uniform(-1, 1, 9) for _ in range(3)]
    b = [rng.uniform(-1, 1, 9) for _ in range(3)]
    first = geo.split(PANDA, *a)
    drift = first.drift.copy()
    geo.split(PANDA, *b)
    again = geo.split(PANDA, *a)
    assert np.array_equal(first.drift, drift) and np.array_equal(again.drift, drift)
    assert geo._compiled(PANDA, None) is geo._compiled(PANDA, None)
    copy = cases.build_model("renamed", PENDULUM.bodies, gravity=PENDULUM.gravity, task_points=PENDULUM.task_points)
    assert geo._compiled(copy, None) is geo._compiled(PENDULUM, None)
    nl = charts.get("nonlinear", PENDULUM)
    assert geo._compiled(PENDULUM, nl) is not geo._compiled(PENDULUM, None)


def test_bad_input_is_a_state_error_naming_sizes():
    chart = charts.get("nonlinear", PENDULUM)
    with pytest.raises(StateError, match=r"p has shape \(3,\) \(3 entries\).*needs 2"):
        geo.split_chart(PENDULUM, chart, [0.1, 0.2, 0.3], [0.0, 0.0], [0.0, 0.0])
    with pytest.raises(StateError, match=r"tau_p .*1 entries.*needs 2"):
        geo.split_chart(PENDULUM, chart, [0.1, 0.2], [0.0, 0.0], [0.0])
    with pytest.raises(StateError, match="pd has non-finite entries"):
        geo.split_chart(PENDULUM, chart, [0.1, 0.2], [np.nan, 0.0], [0.0, 0.0])
    with pytest.raises(StateError, match="q has 3 entries but model 'double_pendulum' needs 2"):
        geo.split(PENDULUM, [0.1, 0.2, 0.3], [0.0, 0.0], [0.0, 0.0])
    with pytest.raises(StateError, match="qd has non-finite"):
        geo.split(PENDULUM, [0.1, 0.2], [np.inf, 0.0], [0.0, 0.0])
    with pytest.raises(StateError, match="pdd"):
        geo.energy_rate(PENDULUM, [0.1, 0.2], [0.0, 0.0], [0.0])
    with pytest.raises(StateError, match="p has"):
        geo.metric(PENDULUM, [0.1])


def test_a_chart_of_the_wrong_dimension_is_refused():
    class Short:
        name, key = "short", "short-chart-test"

        def psi(self, p, sin, cos):
            return [p[0]]

    with pytest.raises(ValueError, match="chart 'short' maps 2 coordinates to 1 joint values"):
        geo.split_chart(PENDULUM, Short(), [0.1, 0.2], [0.0, 0.0], [0.0, 0.0])


def test_a_singular_chart_is_reported_with_the_chart():
    """``q = (p0, 2 p0)`` is no chart (its Jacobian is singular), so the pulled-back metric is singular."""
    class Collapsed:
        name, key = "collapsed", "collapsed-geometric-test"

        def psi(self, p, sin, cos):
            return [p[0], 2 * p[0]]

    with pytest.raises(ValueError, match=r"at p = \[0.1, 0.2\] in chart 'collapsed' \(M_p = Dpsi\^T M Dpsi"):
        geo.split_chart(PENDULUM, Collapsed(), [0.1, 0.2], [0.0, 0.0], [0.0, 0.0])


def test_batch_over_several_blocks_equals_split(monkeypatch):
    """Blocks of 4 states: a batch of 10 crosses two block boundaries and ends on a partial block (each block size
    its own mapped Function); every row is what ``split`` gives (1e-9 of the state's accel_scale)."""
    monkeypatch.setattr(geo, "BATCH_BLOCK", 4)
    rng = np.random.default_rng(5)
    Q, QD, U = (rng.uniform(-2.0, 2.0, (10, size)) for size in (SPATIAL_ARM.n, SPATIAL_ARM.n, SPATIAL_ARM.m))
    batch = geo.split_batch(SPATIAL_ARM, Q, QD, U)
    assert batch.lam is None and batch.lam_drift is None
    for i in range(len(Q)):
        s = geo.split(SPATIAL_ARM, Q[i], QD[i], U[i])
        for name in ("drift", "ctrl", "total"):
            err = np.abs(getattr(batch, name)[i] - getattr(s, name)).max()
            assert err <= 1e-9 * s.accel_scale, f"state {i}: {name} differs by {err:.3g}"


