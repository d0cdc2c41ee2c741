"""Constrained dynamics of the geometric backend (article section 5, eqs. 12-17; 6.4.5; 7.2 reaction covectors): what
only this backend has. The references every backend shares (the cartesian pendulum's multiplier, the circle's KKT
solve, the absolute loop, a gear and a rail, the split identities, a duplicated constraint, the four-bar at its change
point) are in ``test_constrained_backends.py``.

References written independently of the backend:
* ``phi`` of every constrained case written out by hand, its complex-step derivative and second difference;
* the chart maps of ``crosscheck.checks.charts`` (multipliers are chart-invariant, accelerations map by
  ``pdd = Dpsi^-1 (qdd - (d/dt Dpsi) pd)``, forces as covectors);
* ``ctrl`` computed directly (a broken total leaves it unchanged), the drift field, the cost of a split.
"""

from __future__ import annotations


import numpy as np
import pytest

import cases
from closed_forms import circle_state
from crosscheck.checks import charts
from formalisms import geometric as geo

CIRCLE = cases.load("double_pendulum_circle")
CONSTRAINED = ("cartesian_pendulum", "double_pendulum_circle", "four_bar", "slider_crank",
               "double_pendulum_absolute_loop")


def assert_close(got, want, tol, what):
    err = np.abs(np.asarray(got, dtype=float) - np.asarray(want, dtype=float)).max()
    assert err <= tol, f"{what}: error {err:.3e} > tolerance {tol:.3e}\n  got  {np.asarray(got).tolist()}\n" \
                       f"  want {np.asarray(want).tolist()}"


# ------------------------------------------------------------------------------- double pendulum on a circle


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


# -------------------------------------------------------------------------------------------------- charts


@pytest.mark.parametrize("name", CONSTRAINED)
def test_split_chart_in_a_nonlinear_chart(name):
    """phi(psi(p)) is the same function, so in the nonlinear chart (crosscheck.checks.charts) lam and lam_drift are the
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
