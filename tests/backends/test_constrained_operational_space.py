"""Constrained dynamics of the operational-space backend (article 5, eqs. 12-17; 6.3 and 7.2: the constraint force
as ``F_constr``): what only this backend has. The references every backend shares (the cartesian pendulum's
multiplier, the circle's KKT solve, ``ctrl`` solved directly, the absolute loop and its pin forces, the split
identities, a duplicated constraint, the four-bar at its change point) are in ``test_constrained_backends.py``.

* The task-space quantities on the double pendulum's circle (article 5.6) against the 3x3 KKT solve of
  ``closed_forms.py`` (eqs. 5-8, the constraint differentiated by hand): ``Lambda_c`` of S, the task point's
  constrained accelerations and ``F_constr`` (eq. 22).
* The four-bar's default task point at the change point: a task BREAKDOWN.
* A planar point-mass chain written out here with a slider line and a gear coupling.
"""

from __future__ import annotations

import functools

import numpy as np
import pytest

import cases
from cases.constraints import JointCoupling, PointOnLine
from cases.build import build_model
from closed_forms import (circle_state, circle_terms, constrained_input_map, endpoint_jacobian, inv2, kkt_solve,
                          pendulum_terms, tip_bias)
from crosscheck.core import tolerance as policy
from formalisms import operational_space as op

TOL = 1e-12


@functools.lru_cache(maxsize=None)
def model_of(name, **params):
    return cases.load(name, **params)


def close(actual, expected, scale=1.0):
    np.testing.assert_allclose(actual, expected, rtol=0, atol=TOL * (scale + np.abs(expected).max()))


def tangent(Jc, rng):
    """A random velocity in null(Jc) (article 5.1: ``Jc qd = 0``), from the SVD of ``Jc``."""
    _, s, Vt = np.linalg.svd(np.atleast_2d(Jc))
    basis = Vt[int((s > 1e-12 * s[0]).sum()):]
    return rng.uniform(-2.0, 2.0, len(basis)) @ basis


def check_split_identities(s):
    """Eq. (9) additivity, eqs. (13) and (16) for total and drift, and 5.5: ``P_constr = (Jc^T lam) . qd = 0``."""
    scale = s.accel_scale
    close(s.additivity, 0.0, scale)
    close(s.admissibility_total, 0.0, scale * np.abs(s.constraint_jacobian).max())
    close(s.admissibility_drift, 0.0, scale * np.abs(s.constraint_jacobian).max())
    close(s.constraint_force, s.constraint_jacobian.T @ s.lam, np.abs(s.lam).max())
    assert s.power_constr == pytest.approx(0.0, abs=TOL * np.abs(s.constraint_force).max())


# ----------------------------------------------------------------------------------------------------------
# Double pendulum with its endpoint on a circle (article 5.6): the task-space quantities
# ----------------------------------------------------------------------------------------------------------

CIRCLE = dict(m1=1.0, m2=1.0, l1=1.0, l2=1.0, g=9.81, xc=1.0, yc=-1.0, R=0.5)
CIRCLE_ODD = dict(m1=0.7, m2=1.9, l1=1.2, l2=0.8, g=9.81, xc=0.4, yc=-1.3, R=0.6)


@pytest.mark.parametrize("params", [CIRCLE, CIRCLE_ODD], ids=["default", "odd"])
@pytest.mark.parametrize("beta, elbow, speed, u", [(np.pi / 2, 1, 1.3, (2.0, -1.0)), (0.4, -1, -2.0, (0.0, 3.0)),
                                                   (-2.5, 1, 0.6, (-4.0, 1.5)), (2.0, -1, 2.5, (1.0, 1.0))])
def test_double_pendulum_circle_task_space(params, beta, elbow, speed, u):
    """``Lambda_c = (Jc M^-1 Jc^T)^-1``; eq. (22) with ``F_constr``: the task point's accelerations are the constrained
    ones (``J qdd + Jdot qd``), ``A (F_ctrl + F_constr - mu - p)`` recomposes them, and ``F_constr = J^-T Jc^T lam``;
    M, C qd, g of eqs. (6)-(8), ``Jc``, ``Jcdot qd`` by hand, qdd and lam from the 3x3 KKT solve."""
    model = model_of("double_pendulum_circle", **params)
    m1, m2, l1, l2, g = (params[k] for k in ("m1", "m2", "l1", "l2", "g"))
    geometry = {k: params[k] for k in ("l1", "l2", "xc", "yc", "R")}
    t, td = circle_state(beta, elbow, speed, **geometry)
    _, Jc, bias = circle_terms(t, td, **geometry)
    M, Cqd, grav = pendulum_terms(t, td, m1, m2, l1, l2, g)
    u = np.array(u)
    s = op.split(model, t, td, u)
    qdd, lam = kkt_solve(M, Jc, u - Cqd - grav, bias)
    J = endpoint_jacobian(t, l1, l2)
    close(s.extras["constraint_inertia"], [[1.0 / (Jc @ inv2(M) @ Jc)]])
    ts = s.extras["task"]
    close(ts.xdd_total, J @ qdd + tip_bias(t, td, l1, l2), s.accel_scale)
    close(ts.A @ (ts.F_ctrl + ts.F_constr - ts.mu - ts.p), ts.xdd_total, s.accel_scale)
    close(ts.F_constr, np.linalg.solve(J.T, Jc * lam[0]), s.lam_scale * np.abs(Jc).max())


# ----------------------------------------------------------------------------------------------------------
# The four-bar at its change point with the default task point (elsewhere: a y-only task point)
# ----------------------------------------------------------------------------------------------------------

CHANGE_POINT = np.array([np.pi / 2, 0.0, np.pi / 2])


def test_four_bar_change_point_with_the_default_task_is_a_task_breakdown():
    """At the change point every point of the collinear links moves along y, so the default x-y task point makes
    ``A`` singular there: a task BREAKDOWN (NaN accelerations), the constraint kinematics still finite."""
    s = op.split(model_of("four_bar"), CHANGE_POINT, [1.0, -1.0, 1.0], [1.0, 2.0, 3.0])
    assert s.conditions["task"] == np.inf and "task" in policy.breakdown(s)
    assert np.all(np.isnan(s.total)) and np.all(np.isfinite(s.constraint_jacobian))


# ----------------------------------------------------------------------------------------------------------
# A slider line and a gear coupling on a planar three-link chain written out here
# ----------------------------------------------------------------------------------------------------------

def chain_kinematics(q, qd, length):
    """Point masses at the link ends of a planar chain (relative angles from hanging down): positions (n, 2),
    Jacobians (n, 2, n) and classical biases ``Jdot qd`` (n, 2), from p_i = sum_{j <= i} l (sin s_j, -cos s_j),
    s = cumsum(q)."""
    n = len(q)
    s, sd = np.cumsum(q), np.cumsum(qd)
    seg = length * np.stack([np.sin(s), -np.cos(s)], axis=1)
    dseg = length * np.stack([np.cos(s), np.sin(s)], axis=1)
    p = np.cumsum(seg, axis=0)
    J = np.zeros((n, 2, n))
    for i in range(n):
        for k in range(i + 1):
            J[i, :, k] = dseg[k:i + 1].sum(axis=0)
    bias = np.cumsum(-seg * sd[:, None] ** 2, axis=0)
    return p, J, bias


@pytest.mark.parametrize("seed", range(4))
def test_line_and_coupling_on_a_chain(seed):
    """Three-link chain, tip on a line (normal at angle gamma) and gear ``q1 - 2 q2 = offset``: phi, Jc, Jcdot qd
    as ``cases.constraints`` fixes them, the KKT solution (M, C qd, g of the point masses), ``H_t`` residual and
    ``P_constr`` zero."""
    rng = np.random.default_rng(seed)
    n, mass, length = 3, 1.3, 0.8
    base = model_of("n_link_pendulum", n=n, m=mass, l=length)
    q = rng.uniform(-np.pi, np.pi, n)
    p, J, _ = chain_kinematics(q, np.zeros(n), length)
    gamma = rng.uniform(-np.pi, np.pi)
    normal = np.array([np.cos(gamma), np.sin(gamma)])
    origin = p[-1] + rng.uniform(-1.0, 1.0) * np.array([-normal[1], normal[0]])
    line = PointOnLine("rail", "link3", (0.0, -length, 0.0), (*origin, 0.0), [[*normal, 0.0]])
    gear = JointCoupling("gear", ("link1", "link2"), (1.0, -2.0), q[0] - 2.0 * q[1])
    model = build_model("chain_rail_gear", base.bodies, gravity=base.gravity, task_points=base.task_points,
                        constraints=[line, gear])
    Jc = np.vstack([normal @ J[-1], [1.0, -2.0, 0.0]])
    qd, u = tangent(Jc, rng), rng.uniform(-5.0, 5.0, n)
    p, J, bias = chain_kinematics(q, qd, length)
    gravity = base.gravity[:2]
    M = mass * np.einsum("iak,ial->kl", J, J)
    Cqd = mass * np.einsum("iak,ia->k", J, bias)
    g = -mass * np.einsum("iak,a->k", J, gravity)
    Jc_bias = np.array([normal @ bias[-1], 0.0])
    s = op.split(model, q, qd, u)
    close(s.constraint_value, [normal @ (p[-1] - origin), 0.0], length)
    close(s.constraint_jacobian, Jc)
    close(s.constraint_bias, Jc_bias, np.abs(qd).max() ** 2)
    for tau, qdd, lam in ((u, s.total, s.lam), (np.zeros(n), s.drift, s.lam_drift)):
        want_qdd, want_lam = kkt_solve(M, Jc, tau - Cqd - g, Jc_bias)
        close(qdd, want_qdd, s.accel_scale)
        close(lam, want_lam, s.lam_scale)
    close(s.ctrl, constrained_input_map(M, Jc) @ u, s.accel_scale)
    assert s.constraint_rank == 2
    check_split_identities(s)
