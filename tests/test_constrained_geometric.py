"""Constrained dynamics of the geometric backend (article section 5, eqs. 12-17; 6.4.5; 7.2 reaction covectors).

References written independently of the backend:
* the cartesian pendulum's multiplier in closed form (``cases.constrained.cartesian_pendulum``) and its projected
  input map ``(I - p p^T / L^2) / m``;
* the article's double pendulum (``closed_forms.py``: eqs. 6-8) with the endpoint-on-a-circle constraint of 5.6,
  whose ``Jc`` and ``Jcdot qd`` are written out by hand here, solved as the 3x3 KKT system of 5.6 and with
  ``B_c`` of eq. (17);
* the same machine as two free bodies joined by loop constraints, against the joint-coordinate model;
* the chart maps of ``crosscheck.charts`` (multipliers are chart-invariant, accelerations map by
  ``pdd = Dpsi^-1 (qdd - (d/dt Dpsi) pd)``, forces as covectors);
* central differences of ``phi`` and of ``Jc qd`` for every constrained case.
"""

from __future__ import annotations

import time

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

import cases
from cases.constraints import JointCoupling, PointOnCircle, PointOnLine
from cases.model import build_model
from closed_forms import article_Cqd, article_g, article_M
from crosscheck import charts
from formalisms import geometric as geo

CIRCLE = cases.load("double_pendulum_circle")
FOUR_BAR = cases.load("four_bar")
CONSTRAINED = ("cartesian_pendulum", "double_pendulum_circle", "four_bar", "slider_crank",
               "double_pendulum_absolute_loop")


def assert_close(got, want, tol, what):
    err = np.abs(np.asarray(got, dtype=float) - np.asarray(want, dtype=float)).max()
    assert err <= tol, f"{what}: error {err:.3e} > tolerance {tol:.3e}\n  got  {np.asarray(got).tolist()}\n" \
                       f"  want {np.asarray(want).tolist()}"


# ------------------------------------------------------------------------------------------ cartesian pendulum


@given(st.floats(-np.pi, np.pi), st.floats(-5.0, 5.0), st.floats(-20.0, 20.0), st.floats(-20.0, 20.0),
       st.sampled_from([(1.0, 1.0), (2.5, 0.7)]))
@settings(max_examples=30)
def test_cartesian_pendulum_multiplier_in_closed_form(a, speed, ux, uy, params):
    """At x = L sin a, y = -L cos a with v tangent: ``lam = -m (|v|^2 + p . (gravity + u / m)) / (2 L^2)``, lam_drift
    the same with u = 0, ctrl = (I - p p^T / L^2) u / m (the input projected on the tangent), admissible
    accelerations, zero constraint power."""
    m, L = params
    model = cases.load("cartesian_pendulum", m=m, L=L)
    gravity = np.array([0.0, -9.81])
    p = L * np.array([np.sin(a), -np.cos(a)])
    v = speed * np.array([np.cos(a), np.sin(a)])
    u = np.array([ux, uy])
    s = geo.split(model, p, v, u)
    scale = m * (v @ v + L * (9.81 + np.abs(u).sum() / m)) / L**2
    assert_close(s.lam, [-m * (v @ v + p @ (gravity + u / m)) / (2 * L**2)], 1e-13 * scale, "lam")
    assert_close(s.lam_drift, [-m * (v @ v + p @ gravity) / (2 * L**2)], 1e-13 * scale, "lam_drift")
    assert_close(s.ctrl, (np.eye(2) - np.outer(p, p) / L**2) @ u / m, 1e-14 * np.abs(u).sum() / m, "ctrl")
    assert_close(s.admissibility_total, 0.0, 1e-13 * scale * L, "H_t (total)")
    assert abs(s.power_constr) <= 1e-12 * scale * L * (abs(speed) + 1e-300)
    assert s.constraint_rank == 1


# ------------------------------------------------------------------------------- double pendulum on a circle


def circle_state(beta, elbow, rate, l1=1.0, l2=1.0, xc=1.0, yc=-1.0, R=0.5):
    """An admissible state of the article 5.6 system, by hand: the tip at angle ``beta`` on the circle, the inverse
    kinematics of the two links (``elbow`` = +-1 picks the branch), and qd along the null vector of Jc."""
    tip = np.array([xc + R * np.cos(beta), yc + R * np.sin(beta)])
    r2 = tip @ tip
    t2 = elbow * np.arccos((r2 - l1**2 - l2**2) / (2 * l1 * l2))
    t1 = np.arctan2(tip[0], -tip[1]) - np.arctan2(l2 * np.sin(t2), l1 + l2 * np.cos(t2))
    q = np.array([t1, t2])
    Jc = circle_jacobian(q, l1, l2, xc, yc)
    return q, rate * np.array([Jc[0, 1], -Jc[0, 0]]) / np.linalg.norm(Jc)


def tip_position(q, l1=1.0, l2=1.0):
    """x2 = l1 sin t1 + l2 sin(t1 + t2), y2 = -l1 cos t1 - l2 cos(t1 + t2) (article eq. 4)."""
    t1, t12 = q[0], q[0] + q[1]
    return np.array([l1 * np.sin(t1) + l2 * np.sin(t12), -l1 * np.cos(t1) - l2 * np.cos(t12)])


def circle_jacobian(q, l1=1.0, l2=1.0, xc=1.0, yc=-1.0):
    """Jc = 2 (x2 - xc, y2 - yc) J_tip with J_tip = d(x2, y2)/dq written out."""
    t1, t12 = q[0], q[0] + q[1]
    J = np.array([[l1 * np.cos(t1) + l2 * np.cos(t12), l2 * np.cos(t12)],
                  [l1 * np.sin(t1) + l2 * np.sin(t12), l2 * np.sin(t12)]])
    return (2 * (tip_position(q, l1, l2) - [xc, yc]) @ J)[None, :]


def circle_bias(q, qd, l1=1.0, l2=1.0, xc=1.0, yc=-1.0):
    """Jcdot qd = 2 |tip'|^2 + 2 (tip - c) . (Jdot qd), the second derivative of phi at qdd = 0, with
    Jdot qd = (-l1 sin t1 t1d^2 - l2 sin t12 t12d^2, l1 cos t1 t1d^2 + l2 cos t12 t12d^2)."""
    t1, t12, w1, w12 = q[0], q[0] + q[1], qd[0], qd[0] + qd[1]
    tip_rate = np.array([l1 * np.cos(t1) * w1 + l2 * np.cos(t12) * w12, l1 * np.sin(t1) * w1 + l2 * np.sin(t12) * w12])
    Jdot_qd = np.array([-l1 * np.sin(t1) * w1**2 - l2 * np.sin(t12) * w12**2,
                        l1 * np.cos(t1) * w1**2 + l2 * np.cos(t12) * w12**2])
    return np.array([2 * tip_rate @ tip_rate + 2 * (tip_position(q, l1, l2) - [xc, yc]) @ Jdot_qd])


def kkt(M, Jc, rhs_force, bias):
    """The KKT system of article 5.6: [[M, -Jc^T], [Jc, 0]] [qdd; lam] = [tau - C qd - g; -Jcdot qd]."""
    n, k = M.shape[0], Jc.shape[0]
    A = np.block([[M, -Jc.T], [Jc, np.zeros((k, k))]])
    x = np.linalg.solve(A, np.concatenate([rhs_force, -bias]))
    return x[:n], x[n:]


@given(st.floats(-np.pi, np.pi), st.sampled_from([-1.0, 1.0]), st.floats(-4.0, 4.0), st.floats(-20.0, 20.0),
       st.floats(-20.0, 20.0))
@settings(max_examples=30)
def test_double_pendulum_circle_against_the_kkt_system(beta, elbow, rate, u1, u2):
    """Article 5.6 at an admissible state: qdd and lam (with and without u) equal an independent 3x3 KKT solve on
    eqs. (6)-(8) and the hand-written Jc, Jcdot qd; drift + ctrl = total; ctrl = B_c u of eq. (17); the
    accelerations lie on H_t (eq. 16); the constraint does no work (5.5)."""
    q, qd = circle_state(beta, elbow, rate)
    u = np.array([u1, u2])
    M, Cqd, g = article_M(q[1]), article_Cqd(q[1], *qd), article_g(*q)
    Jc, bias = circle_jacobian(q), circle_bias(q, qd)
    total, lam = kkt(M, Jc, u - Cqd - g, bias)
    drift, lam_drift = kkt(M, Jc, -Cqd - g, bias)
    Minv = np.linalg.inv(M)
    B_c = Minv @ (np.eye(2) - Jc.T @ np.linalg.solve(Jc @ Minv @ Jc.T, Jc @ Minv))
    s = geo.split(CIRCLE, q, qd, u)
    force_size = np.abs(Cqd).sum() + np.abs(g).sum() + np.abs(u).sum() + np.abs(bias).sum()
    accel = np.linalg.cond(M) * np.abs(Minv).sum() * force_size
    lam_scale = force_size / np.abs(Jc).max()
    assert_close(s.constraint_value, [0.0], 1e-14, "phi at an admissible q")
    assert_close(s.constraint_jacobian, Jc, 1e-14 * np.abs(Jc).max(), "Jc")
    assert_close(s.constraint_bias, bias, 1e-13 * (np.abs(bias).max() + qd @ qd), "Jcdot qd")
    assert_close(s.total, total, 1e-12 * accel, "total vs KKT")
    assert_close(s.drift, drift, 1e-12 * accel, "drift vs KKT (u = 0, eq. 14)")
    assert_close(s.lam, lam, 1e-12 * lam_scale * np.linalg.cond(M), "lam vs KKT")
    assert_close(s.lam_drift, lam_drift, 1e-12 * lam_scale * np.linalg.cond(M), "lam_drift vs KKT")
    assert_close(s.drift + s.ctrl, s.total, 1e-13 * accel, "drift + ctrl = total")
    assert_close(s.ctrl, B_c @ u, 1e-12 * accel, "ctrl = B_c u (eq. 17)")
    assert_close(s.admissibility_total, 0.0, 1e-12 * accel * np.abs(Jc).max(), "H_t residual (total)")
    assert_close(s.admissibility_drift, 0.0, 1e-12 * accel * np.abs(Jc).max(), "H_t residual (drift)")
    assert abs(s.power_constr) <= 1e-12 * lam_scale * np.abs(Jc).max() * (np.abs(qd).sum() + 1e-300)
    assert_close(s.constraint_force, Jc.T @ lam, 1e-11 * lam_scale * np.abs(Jc).max(), "Jc^T lam")
    assert s.constraint_rank == 1 and s.conditions["constraint_consistency"] <= 1e-12
    assert abs(s.kinetic_energy - 0.5 * qd @ M @ qd) <= 1e-13 * (qd @ qd) * np.abs(M).max() + 1e-300


def test_ctrl_is_computed_directly_not_as_total_minus_drift(monkeypatch):
    """ctrl is ``Z (Z^T M Z)^-1 Z^T tau``: dropping the input from the total's force leaves ctrl unchanged and breaks
    additivity (so the additivity check can fail)."""
    q, qd = circle_state(0.4, 1.0, 1.5)
    u = np.array([3.0, -2.0])
    good = geo.split(CIRCLE, q, qd, u)
    solve = geo._cho_solve

    def no_input_in_total(factor, rhs):
        x = solve(factor, rhs)
        x[:, 0] = x[:, 1]  # the total's projection replaced by the drift's
        return x

    monkeypatch.setattr(geo, "_cho_solve", no_input_in_total)
    bad = geo.split(CIRCLE, q, qd, u)
    assert_close(bad.ctrl, good.ctrl, 0.0, "ctrl unchanged")
    assert np.abs(bad.additivity).max() > 0.1


# ----------------------------------------------------------------------------- the loop-closed double pendulum


@given(st.floats(-np.pi, np.pi), st.floats(-np.pi, np.pi), st.floats(-4.0, 4.0), st.floats(-4.0, 4.0),
       st.floats(-20.0, 20.0), st.floats(-20.0, 20.0))
@settings(max_examples=20)
def test_absolute_loop_equals_the_joint_coordinate_pendulum(t1, t2, w1, w2, u1, u2):
    """Two free bodies pinned together (4 rows, 6 coordinates) are the double pendulum: at the mapped admissible
    state and the same u, theta1dd = phi1dd and theta2dd = phi2dd - phi1dd for total, drift and ctrl; the
    kinetic energy, control power and tip acceleration are the same; the pins do no work."""
    l1, I1, I2 = 1.0, 0.1, 0.1
    loop = cases.load("double_pendulum_absolute_loop", I1=I1, I2=I2)
    joint = cases.load("double_pendulum", I1=I1, I2=I2)
    x = np.array([0.0, 0.0, t1, l1 * np.sin(t1), -l1 * np.cos(t1), t1 + t2])
    xd = np.array([0.0, 0.0, w1, l1 * np.cos(t1) * w1, l1 * np.sin(t1) * w1, w1 + w2])
    u = np.array([u1, u2])
    s_loop, s_joint = geo.split(loop, x, xd, u), geo.split(joint, np.array([t1, t2]), np.array([w1, w2]), u)
    scale = s_joint.accel_scale
    for name in ("total", "drift", "ctrl"):
        a = getattr(s_loop, name)
        assert_close([a[2], a[5] - a[2]], getattr(s_joint, name), 1e-12 * scale, name)
    assert abs(s_loop.kinetic_energy - s_joint.kinetic_energy) <= 1e-13 * (s_joint.kinetic_energy + 1e-300)
    assert abs(s_loop.power_ctrl - s_joint.power_ctrl) <= 1e-12 * np.abs(u).sum() * (abs(w1) + abs(w2) + 1e-300)
    assert_close(s_loop.task_drift, s_joint.task_drift, 1e-12 * scale, "tip acceleration at the drift")
    assert_close(s_loop.admissibility_total, 0.0, 1e-12 * scale, "H_t residual")
    assert abs(s_loop.power_constr) <= 1e-11 * s_loop.lam_scale * (np.abs(xd).sum() + 1e-300)
    assert s_loop.constraint_rank == 4


# --------------------------------------------------------------------------------------- degenerate constraints


def with_duplicate(model):
    """``model`` with its (single) constraint declared twice: two identical rows, S singular."""
    (c,) = model.constraints
    twin = PointOnCircle(c.name + "_again", c.body, c.offset, c.center, c.radius, c.plane)
    return build_model(model.name + "_duplicated", model.bodies, gravity=model.gravity, input_map=model.input_map,
                       task_points=model.task_points, constraints=[c, twin])


def test_duplicated_constraint_gives_the_same_motion_and_half_multipliers():
    """Redundant rows never raise: the same qdd and Jc^T lam as the single constraint, the minimum-norm multipliers
    (half each), rank 1, consistent."""
    doubled = with_duplicate(CIRCLE)
    for beta, rate, u in ((0.4, 1.5, (3.0, -2.0)), (-2.0, -3.0, (0.0, 0.0)), (2.9, 0.0, (-10.0, 5.0))):
        q, qd = circle_state(beta, 1.0, rate)
        one, two = geo.split(CIRCLE, q, qd, np.array(u)), geo.split(doubled, q, qd, np.array(u))
        scale = one.accel_scale
        for name in ("total", "drift", "ctrl"):
            assert_close(getattr(two, name), getattr(one, name), 1e-12 * scale, name)
        assert_close(two.lam, [one.lam[0] / 2] * 2, 1e-12 * one.lam_scale, "lam split in half")
        assert_close(two.lam_drift, [one.lam_drift[0] / 2] * 2, 1e-12 * one.lam_scale, "lam_drift split in half")
        assert_close(two.constraint_force, one.constraint_force, 1e-12 * one.lam_scale, "Jc^T lam")
        assert two.constraint_rank == 1 and two.conditions["constraint_consistency"] <= 1e-12


def test_four_bar_change_point_returns_finite_numbers():
    """At the change point q = (pi/2, 0, pi/2) Jc loses rank. At rest H_t is not empty: an admissible qdd that
    satisfies eq. (12) (gravity from the same bodies without the loop), eq. (15), and the minimum-norm lam (no
    component along the redundant direction of Jc^T). Moving along null(Jc), off both branches, H_t is empty:
    finite least-squares numbers, flagged by the consistency condition, no exception."""
    q = np.array([np.pi / 2, 0.0, np.pi / 2])
    u = np.array([1.0, -2.0, 0.5])
    tau = FOUR_BAR.input_map @ u
    rest = geo.split(FOUR_BAR, q, np.zeros(3), u)
    open_chain = build_model("four_bar_open", FOUR_BAR.bodies, gravity=FOUR_BAR.gravity,
                             task_points=FOUR_BAR.task_points)
    M = geo.metric(open_chain, q)
    g = -M @ geo.split(open_chain, q, np.zeros(3), np.zeros(3)).drift
    scale = rest.accel_scale * np.abs(M).max()
    assert rest.constraint_rank == 1
    assert_close(rest.constraint_value, 0.0, 1e-15, "phi at the change point")
    assert_close(rest.admissibility_total, 0.0, 1e-12 * rest.accel_scale, "H_t residual at rest")
    assert_close(M @ rest.total + g - tau - rest.constraint_force, 0.0, 1e-12 * scale, "eq. (12) residual")
    assert_close(M @ rest.ctrl - tau - rest.constraint_force + rest.constraint_force_drift, 0.0, 1e-12 * scale,
                 "eq. (15): M ctrl = tau + Jc^T (lam - lam_drift)")
    U, sv, Vt = np.linalg.svd(rest.constraint_jacobian)
    assert sv[1] < 1e-12 * sv[0]
    assert abs(U[:, 1] @ rest.lam) <= 1e-12 * rest.lam_scale, "minimum-norm multipliers"
    moving = geo.split(FOUR_BAR, q, Vt[1:].T @ np.array([0.7, -0.3]), u)
    for name in ("total", "drift", "ctrl", "lam", "lam_drift"):
        assert np.all(np.isfinite(getattr(moving, name))), name
    assert moving.constraint_rank == 1 and moving.conditions["constraint_consistency"] > 1e-3


# ------------------------------------------------------------------------- every constrained case, by hand


def phi_by_hand(name, q):
    """The declarations' phi for the default parameters, written out from the scene descriptions
    (``cases.constrained``; angles from hanging down, ``(sin a, -cos a)`` the direction of a link at angle a)."""
    def link(a, length):
        return length * np.array([np.sin(a), -np.cos(a)])
    if name == "cartesian_pendulum":
        return np.array([q @ q - 1.0])
    if name == "double_pendulum_circle":
        d = link(q[0], 1.0) + link(q[0] + q[1], 1.0) - [1.0, -1.0]
        return np.array([d @ d - 0.25])
    if name == "four_bar":  # coupler end minus rocker end; crank 1, coupler 2, rocker 1, ground 2
        return link(q[0], 1.0) + link(q[0] + q[1], 2.0) - ([2.0, 0.0] + link(q[2], 1.0))
    if name == "slider_crank":  # rod end minus the slider at (x, 0.1); crank 0.5, rod 1.5
        return link(q[0], 0.5) + link(q[0] + q[1], 1.5) - [q[2], 0.1]
    # double_pendulum_absolute_loop: pivot 1 at the origin, pivot 2 at link 1's end
    return np.concatenate([q[:2], q[3:5] - (q[:2] + link(q[2], 1.0))])


def numeric_jacobian(name, q, h=1e-30):
    """``d phi_by_hand / dq`` by the complex step ``Im phi(q + i h e) / h``: exact to rounding, no AD."""
    return np.column_stack([phi_by_hand(name, q + 1j * h * e).imag / h for e in np.eye(len(q))])


def admissible_state(name, rng):
    """q on phi = 0 by Gauss-Newton from a random start (hand phi, complex-step Jacobian), qd a random vector of
    null(Jc)."""
    n = cases.load(name).n
    q = rng.uniform(-1.5, 1.5, n)
    for _ in range(100):
        step = np.linalg.lstsq(numeric_jacobian(name, q), -phi_by_hand(name, q), rcond=None)[0]
        q = q + step
        if np.abs(step).max() < 1e-15:
            break
    assert np.abs(phi_by_hand(name, q)).max() < 1e-13, "the projection onto phi = 0 did not converge"
    _, sv, Vt = np.linalg.svd(numeric_jacobian(name, q))
    Z = Vt[int(np.count_nonzero(sv > 1e-8 * sv[0])):].T
    return q, Z @ rng.uniform(-3.0, 3.0, Z.shape[1])


@pytest.mark.parametrize("name", CONSTRAINED)
def test_constraint_kinematics_match_the_hand_written_phi(name):
    """phi equals the hand-written function at arbitrary (not admissible) configurations, Jc its complex-step
    derivative, and Jcdot qd the central second difference of phi along q + t qd (where qdd = 0)."""
    model, rng = cases.load(name), np.random.default_rng(11)
    for _ in range(5):
        q, qd = rng.uniform(-2.0, 2.0, model.n), rng.uniform(-2.0, 2.0, model.n)
        s = geo.split(model, q, qd, np.zeros(model.m))
        assert_close(s.constraint_value, phi_by_hand(name, q), 1e-14 * (1 + np.abs(q).max() ** 2), "phi")
        assert_close(s.constraint_jacobian, numeric_jacobian(name, q), 1e-13 * (1 + np.abs(q).max()), "Jc")
        h = 1e-4
        second = (phi_by_hand(name, q + h * qd) - 2 * phi_by_hand(name, q) + phi_by_hand(name, q - h * qd)) / h**2
        assert_close(s.constraint_bias, second, 1e-5 * (1 + qd @ qd), "Jcdot qd")


@pytest.mark.parametrize("name", CONSTRAINED)
def test_identities_at_admissible_states(name):
    """Eqs. (12)-(17) as identities: drift + ctrl = total, both on H_t, eq. (15) ``M ctrl = tau + Jc^T (lam -
    lam_drift)`` with the metric of the backend, zero constraint power (5.5), full rank, consistent."""
    model, rng = cases.load(name), np.random.default_rng(5)
    for _ in range(5):
        q, qd = admissible_state(name, rng)
        u = rng.uniform(-10.0, 10.0, model.m)
        s = geo.split(model, q, qd, u)
        M, tau = geo.metric(model, q), model.input_map @ u
        scale, Jn = s.accel_scale, np.abs(s.constraint_jacobian).max()
        assert_close(s.additivity, 0.0, 1e-13 * scale, "drift + ctrl = total")
        assert_close(s.admissibility_total, 0.0, 1e-12 * scale * Jn, "H_t (total)")
        assert_close(s.admissibility_drift, 0.0, 1e-12 * scale * Jn, "H_t (drift)")
        assert_close(M @ s.ctrl, tau + s.constraint_force - s.constraint_force_drift,
                     1e-12 * scale * np.abs(M).max(), "eq. (15)")
        assert abs(s.power_constr) <= 1e-11 * s.lam_scale * Jn * (np.abs(qd).sum() + 1e-300)
        assert s.constraint_rank == model.k and s.conditions["constraint_consistency"] <= 1e-10


# -------------------------------------------------------------------------------------------------- charts


@pytest.mark.parametrize("name", CONSTRAINED)
def test_split_chart_in_a_nonlinear_chart(name):
    """phi(psi(p)) is the same function, so in the nonlinear chart (crosscheck.charts) lam and lam_drift are the
    joint chart's, ``Jc_p = Jc Dpsi``, the constraint force is the covector ``Dpsi^T Jc^T lam``, and the
    accelerations map by ``pdd = Dpsi^-1 (qdd - (d/dt Dpsi) pd)`` (ctrl without the rate term)."""
    model, rng = cases.load(name), np.random.default_rng(3)
    chart = charts.get("nonlinear", model)
    for _ in range(3):
        q, qd = admissible_state(name, rng)
        u = rng.uniform(-10.0, 10.0, model.m)
        p = chart.p_of(q)
        pd = charts.velocity_to_chart(chart, p, qd)
        s_q = geo.split(model, q, qd, u)
        s_p = geo.split_chart(model, chart, p, pd, charts.force_to_chart(chart, p, model.input_map @ u))
        D = chart.jacobian(p)
        tol = 1e-11 * s_q.accel_scale * np.linalg.cond(D)
        assert_close(s_p.lam, s_q.lam, 1e-11 * s_q.lam_scale, "lam")
        assert_close(s_p.lam_drift, s_q.lam_drift, 1e-11 * s_q.lam_scale, "lam_drift")
        assert_close(s_p.constraint_value, s_q.constraint_value, 1e-14, "phi")
        assert_close(s_p.constraint_jacobian, s_q.constraint_jacobian @ D, 1e-13 * np.abs(D).max(), "Jc Dpsi")
        assert_close(s_p.constraint_force, D.T @ s_q.constraint_force, 1e-11 * s_q.lam_scale * np.abs(D).max(),
                     "reaction covector")
        for what in ("total", "drift"):
            assert_close(getattr(s_p, what), charts.acceleration_to_chart(chart, p, pd, getattr(s_q, what)), tol,
                         what)
        assert_close(s_p.ctrl, charts.acceleration_to_chart(chart, p, pd, s_q.ctrl, with_rate=False), tol, "ctrl")
        assert abs(s_p.kinetic_energy - s_q.kinetic_energy) <= 1e-12 * (s_q.kinetic_energy + 1e-300)
        assert s_p.extras["chart"] == "nonlinear"


def test_drift_field_is_the_constrained_drift():
    q, qd = circle_state(1.0, -1.0, 2.0)
    field = geo.drift_field(CIRCLE, q, qd)
    assert_close(field, np.concatenate([qd, geo.split(CIRCLE, q, qd, np.zeros(2)).drift]), 0.0, "drift field")


def test_a_constrained_split_is_fast():
    """One compiled casadi call, one SVD and one small Cholesky factor per state: well under 5 ms."""
    q, qd = circle_state(0.3, 1.0, 1.0)
    geo.split(CIRCLE, q, qd, np.ones(2))  # compile
    start = time.perf_counter()
    for _ in range(50):
        geo.split(CIRCLE, q, qd, np.ones(2))
    assert (time.perf_counter() - start) / 50 < 5e-3


def test_joint_coupling_and_point_on_line():
    """The two declarations no registered case uses. A gear ``q1 - 2 q2 - 0.1`` on the double pendulum: phi and
    Jc = (1, -2) as declared, admissible accelerations. The cartesian pendulum's bob also on the line x = 0.6 (no
    freedom left): at rest qdd = 0 and Jc^T lam = -(B u - dV/dq) solved by hand with Jc = [[2x, 2y], [1, 0]]."""
    pendulum = cases.load("double_pendulum")
    geared = build_model("geared", pendulum.bodies, gravity=pendulum.gravity, task_points=pendulum.task_points,
                         constraints=[JointCoupling("gear", ("link1", "link2"), (1.0, -2.0), 0.1)])
    q, qd = np.array([0.7, 0.3]), np.array([2.0, 1.0])
    s = geo.split(geared, q, qd, np.array([1.0, -1.0]))
    assert_close(s.constraint_value, [q[0] - 2 * q[1] - 0.1], 1e-15, "gear phi")
    assert_close(s.constraint_jacobian, [[1.0, -2.0]], 1e-15, "gear Jc")
    assert_close(s.constraint_bias, [0.0], 1e-15, "gear Jcdot qd")
    assert_close(s.admissibility_total, 0.0, 1e-13 * s.accel_scale, "gear H_t")
    bob = cases.load("cartesian_pendulum")
    line = PointOnLine("x", "bob", np.zeros(3), np.array([0.6, 0.0, 0.0]), np.array([[1.0, 0.0, 0.0]]))
    locked = build_model("locked", bob.bodies, gravity=bob.gravity, task_points=bob.task_points,
                         constraints=[*bob.constraints, line])
    x, u = np.array([0.6, -0.8]), np.array([1.0, 1.0])
    s = geo.split(locked, x, np.zeros(2), u)
    Jc = np.array([[2 * x[0], 2 * x[1]], [1.0, 0.0]])
    assert_close(s.constraint_value, 0.0, 1e-15, "phi")
    assert_close(s.constraint_jacobian, Jc, 1e-15, "Jc")
    for what in ("total", "drift", "ctrl"):
        assert_close(getattr(s, what), 0.0, 1e-14, what)
    assert_close(s.lam, np.linalg.solve(Jc.T, -(u - [0.0, 9.81])), 1e-13, "lam")
    assert s.constraint_rank == 2
