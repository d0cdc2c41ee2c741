"""Constrained dynamics of the operational-space backend (article 5, eqs. 12-17; 6.3 and 7.2: the constraint force
as ``F_constr``) against references written independently here: the cartesian pendulum's closed-form multiplier,
a 3x3 KKT solve of the double pendulum on a circle from the article's closed forms (closed_forms.py, eqs. 5-8) with
the constraint Jacobian and bias derived by hand, the joint-coordinate double pendulum for its absolute-coordinate
loop model, Newton's second law for the loop's pin forces, and a planar point-mass chain written out here for a
slider line and a gear coupling.
"""

from __future__ import annotations

import dataclasses
import functools

import numpy as np
import pytest

import cases
from cases.constraints import JointCoupling, PointOnLine
from cases.model import TaskPoint, build_model
from closed_forms import article_Cqd, article_g, article_M, endpoint_jacobian, inv2, pendulum_terms
from crosscheck import tolerance as policy
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
# Cartesian pendulum: the closed-form multiplier (cases.constrained.cartesian_pendulum)
# ----------------------------------------------------------------------------------------------------------

@pytest.mark.parametrize("a, w, u", [(0.3, 1.5, (2.0, -1.0)), (-2.0, -0.7, (0.0, 0.0)), (np.pi / 2, 3.0, (5.0, 4.0)),
                                     (3.0, 0.0, (-3.0, 7.0))])
@pytest.mark.parametrize("m, L", [(1.0, 1.0), (2.5, 0.4)])
def test_cartesian_pendulum_multiplier_has_the_closed_form(a, w, u, m, L):
    """``lam = -m (|v|^2 + p . (gravity + u / m)) / (2 L^2)``; u = 0 gives lam_drift (eq. 14)."""
    model = model_of("cartesian_pendulum", m=m, L=L)
    p = L * np.array([np.sin(a), -np.cos(a)])
    v = w * L * np.array([np.cos(a), np.sin(a)])
    u = np.array(u)
    s = op.split(model, p, v, u)
    gravity = model.gravity[:2]

    def lam(force):
        return -m * (v @ v + p @ (gravity + force / m)) / (2.0 * L**2)

    scale = m * (v @ v + L * (np.abs(gravity).sum() + np.abs(u).sum() / m)) / L**2
    close(s.lam, [lam(u)], scale)
    close(s.lam_drift, [lam(np.zeros(2))], scale)
    # eq. (12) with M = m I, B = I, Jc = 2 p^T
    close(s.total, gravity + (u + 2.0 * p * lam(u)) / m, s.accel_scale)
    close(s.constraint_value, [0.0], L**2)
    check_split_identities(s)


# ----------------------------------------------------------------------------------------------------------
# Double pendulum with its endpoint on a circle (article 5.6): a 3x3 KKT solve from the closed forms
# ----------------------------------------------------------------------------------------------------------

def circle_state(beta, elbow, model_params):
    """(theta1, theta2) with the tip at ``c + R (cos beta, sin beta)`` (inverse kinematics by the cosine rule)."""
    l1, l2, xc, yc, R = (model_params[k] for k in ("l1", "l2", "xc", "yc", "R"))
    x, y = xc + R * np.cos(beta), yc + R * np.sin(beta)
    t2 = elbow * np.arccos((x * x + y * y - l1**2 - l2**2) / (2.0 * l1 * l2))
    t1 = np.arctan2(x, -y) - np.arctan2(l2 * np.sin(t2), l1 + l2 * np.cos(t2))
    return np.array([t1, t2])


def tip_and_bias(t, td, l1, l2):
    """Tip ``(x2, y2)`` and its classical bias ``Jdot qd``, differentiating x2 = l1 sin t1 + l2 sin(t1 + t2),
    y2 = -l1 cos t1 - l2 cos(t1 + t2) twice at ``tdd = 0``."""
    s1, c1, s12, c12 = np.sin(t[0]), np.cos(t[0]), np.sin(t[0] + t[1]), np.cos(t[0] + t[1])
    w1, w12 = td[0], td[0] + td[1]
    tip = np.array([l1 * s1 + l2 * s12, -l1 * c1 - l2 * c12])
    bias = np.array([-l1 * s1 * w1**2 - l2 * s12 * w12**2, l1 * c1 * w1**2 + l2 * c12 * w12**2])
    return tip, bias


CIRCLE = dict(m1=1.0, m2=1.0, l1=1.0, l2=1.0, g=9.81, xc=1.0, yc=-1.0, R=0.5)
CIRCLE_ODD = dict(m1=0.7, m2=1.9, l1=1.2, l2=0.8, g=9.81, xc=0.4, yc=-1.3, R=0.6)


@pytest.mark.parametrize("params", [CIRCLE, CIRCLE_ODD], ids=["default", "odd"])
@pytest.mark.parametrize("beta, elbow, speed, u", [(np.pi / 2, 1, 1.3, (2.0, -1.0)), (0.4, -1, -2.0, (0.0, 3.0)),
                                                   (-2.5, 1, 0.6, (-4.0, 1.5)), (2.0, -1, 2.5, (1.0, 1.0))])
def test_double_pendulum_circle_against_kkt(params, beta, elbow, speed, u):
    """Article 5.6: ``[[M, -Jc^T], [Jc, 0]] [qdd; lam] = [tau - C qd - g; -Jcdot qd]`` with M, C qd, g of eqs.
    (6)-(8), ``Jc = 2 d^T J`` (eq. 5) and ``Jcdot qd = 2 |J qd|^2 + 2 d . (Jdot qd)``; drift at u = 0 (eq. 14),
    ctrl = B_c u (eq. 17), task drift eq. (23)."""
    model = model_of("double_pendulum_circle", **params)
    m1, m2, l1, l2, g = (params[k] for k in ("m1", "m2", "l1", "l2", "g"))
    t = circle_state(beta, elbow, params)
    tip, _ = tip_and_bias(t, np.zeros(2), l1, l2)
    d = tip - (params["xc"], params["yc"])
    J = endpoint_jacobian(t, l1, l2)
    Jc = 2.0 * d @ J
    td = speed * np.array([Jc[1], -Jc[0]]) / np.linalg.norm(Jc)
    _, tip_bias = tip_and_bias(t, td, l1, l2)
    bias = 2.0 * (J @ td) @ (J @ td) + 2.0 * d @ tip_bias
    M, Cqd, grav = pendulum_terms(t, td, m1, m2, l1, l2, g)
    assert np.allclose(M, article_M(t[1], m1, m2, l1, l2)) and np.allclose(Cqd, article_Cqd(t[1], *td, m2, l1, l2))
    assert np.allclose(grav, article_g(*t, m1, m2, l1, l2, g))
    KKT = np.block([[M, -Jc[:, None]], [Jc[None, :], np.zeros((1, 1))]])

    def kkt(tau):
        sol = np.linalg.solve(KKT, np.r_[tau - Cqd - grav, -bias])
        return sol[:2], sol[2:]

    u = np.array(u)
    s = op.split(model, t, td, u)
    qdd, lam = kkt(u)
    qdd0, lam0 = kkt(np.zeros(2))
    Minv = inv2(M)
    B_c = Minv - np.outer(Minv @ Jc, Jc @ Minv) / (Jc @ Minv @ Jc)
    close(s.constraint_value, [0.0], params["R"] ** 2)
    close(s.constraint_jacobian, Jc[None, :])
    close(s.constraint_bias, [bias], np.abs(td).max() ** 2)
    close(s.total, qdd, s.accel_scale)
    close(s.drift, qdd0, s.accel_scale)
    close(s.ctrl, B_c @ u, s.accel_scale)
    close(s.lam, lam, s.lam_scale)
    close(s.lam_drift, lam0, s.lam_scale)
    close(s.constraint_force_drift, Jc * lam0[0], s.lam_scale * np.abs(Jc).max())
    close(s.task_drift, J @ qdd0 + tip_bias, s.accel_scale)
    close(s.extras["constraint_inertia"], [[1.0 / (Jc @ Minv @ Jc)]])
    assert s.constraint_rank == 1 and not policy.breakdown(s)
    check_split_identities(s)
    ts = s.extras["task"]   # eq. (22) with F_constr: the task point's accelerations are the constrained ones
    close(ts.xdd_total, J @ qdd + tip_bias, s.accel_scale)
    close(ts.A @ (ts.F_ctrl + ts.F_constr - ts.mu - ts.p), ts.xdd_total, s.accel_scale)
    close(ts.F_constr, np.linalg.solve(J.T, Jc * lam[0]), s.lam_scale * np.abs(Jc).max())


def test_ctrl_is_solved_directly_not_total_minus_drift():
    """Where the drift dwarfs the control, ``total - drift`` would lose every digit of ``ctrl = B_c u``."""
    model = model_of("double_pendulum_circle")
    t = circle_state(0.4, 1, CIRCLE)
    tip, _ = tip_and_bias(t, np.zeros(2), 1.0, 1.0)
    Jc = 2.0 * (tip - (1.0, -1.0)) @ endpoint_jacobian(t)
    td, u = 3e3 * np.array([Jc[1], -Jc[0]]), np.array([1e-6, -2e-6])
    Minv = inv2(article_M(t[1]))
    B_c = Minv - np.outer(Minv @ Jc, Jc @ Minv) / (Jc @ Minv @ Jc)
    np.testing.assert_allclose(op.split(model, t, td, u).ctrl, B_c @ u, rtol=1e-12, atol=0)


# ----------------------------------------------------------------------------------------------------------
# The double pendulum as two free bodies and four loop rows: the joint model's accelerations, Newton's pin forces
# ----------------------------------------------------------------------------------------------------------

@pytest.mark.parametrize("t, td, u", [((0.3, 1.1), (0.5, -1.2), (2.0, -1.0)), ((-2.0, 0.4), (2.0, 1.5), (0.0, 0.0)),
                                      ((2.9, -2.2), (-1.0, 3.0), (-5.0, 3.0))])
@pytest.mark.parametrize("params", [dict(m1=1.0, m2=1.0, l1=1.0, l2=1.0, g=9.81, I1=0.1, I2=0.1),
                                    dict(m1=0.6, m2=1.7, l1=1.3, l2=0.7, g=9.81, I1=0.05, I2=0.3)],
                         ids=["default", "odd"])
def test_absolute_loop_matches_the_joint_model(t, td, u, params):
    """``double_pendulum_absolute_loop`` at the image of the joint state: theta1dd = phi1dd, theta2dd = phi2dd -
    phi1dd for drift, ctrl and total, as eqs. (6)-(8) with the links' moments about z (``T`` gains
    ``1/2 I1 t1d^2 + 1/2 I2 (t1d + t2d)^2``) and as this backend's unconstrained ``double_pendulum``; the pin
    multipliers are the pin forces: the elbow ``m2 (a2 - gravity)`` on link 2, the shoulder ``m1 a1 + m2 a2 -
    (m1 + m2) gravity`` on the whole chain (Newton: the torques are couples)."""
    model = model_of("double_pendulum_absolute_loop", **params)
    m1, m2, l1, l2, g, I1, I2 = (params[k] for k in ("m1", "m2", "l1", "l2", "g", "I1", "I2"))
    t, td, u = np.array(t), np.array(td), np.array(u)
    s1, c1 = np.sin(t[0]), np.cos(t[0])
    q = np.array([0.0, 0.0, t[0], l1 * s1, -l1 * c1, t[0] + t[1]])
    qd = np.array([0.0, 0.0, td[0], l1 * c1 * td[0], l1 * s1 * td[0], td[0] + td[1]])
    s = op.split(model, q, qd, u)
    joint = op.split(model_of("double_pendulum", **params), t, td, u)
    M, Cqd, grav = pendulum_terms(t, td, m1, m2, l1, l2, g)
    M = M + np.array([[I1 + I2, I2], [I2, I2]])
    expected = {"drift": np.linalg.solve(M, -Cqd - grav), "ctrl": np.linalg.solve(M, u),
                "total": np.linalg.solve(M, u - Cqd - grav)}
    for name, tdd in expected.items():
        phidd = s.quantity(name)[[2, 5]]
        close(np.array([phidd[0], phidd[1] - phidd[0]]), tdd, s.accel_scale)
        close(joint.quantity(name), tdd, joint.accel_scale)
    close(s.task_drift, joint.task_drift, s.accel_scale)
    check_split_identities(s)

    def mass_accelerations(tdd):
        a1 = l1 * np.array([c1 * tdd[0] - s1 * td[0] ** 2, s1 * tdd[0] + c1 * td[0] ** 2])
        f, fd, fdd = t[0] + t[1], td[0] + td[1], tdd[0] + tdd[1]
        return a1, a1 + l2 * np.array([np.cos(f) * fdd - np.sin(f) * fd**2, np.sin(f) * fdd + np.cos(f) * fd**2])

    gravity = model.gravity[:2]
    for lam, tdd in ((s.lam, expected["total"]), (s.lam_drift, expected["drift"])):
        a1, a2 = mass_accelerations(tdd)
        close(lam[2:], m2 * (a2 - gravity), s.lam_scale)
        close(lam[:2], m1 * a1 + m2 * a2 - (m1 + m2) * gravity, s.lam_scale)


# ----------------------------------------------------------------------------------------------------------
# Degenerate constraints: duplicated rows, the four-bar at its change point
# ----------------------------------------------------------------------------------------------------------

def test_duplicated_constraint_halves_the_multiplier():
    """Two copies of the circle: S is singular, the minimum-norm multipliers split the single one in halves, and
    the accelerations and the generalized constraint force ``Jc^T lam`` are the single constraint's."""
    single = model_of("double_pendulum_circle")
    circle = single.constraints[0]
    double = build_model("double_circle", single.bodies, gravity=single.gravity, task_points=single.task_points,
                         constraints=[circle, dataclasses.replace(circle, name="again")])
    rng = np.random.default_rng(11)
    for beta in (0.3, 2.2, -1.9):
        t = circle_state(beta, 1, CIRCLE)
        td = tangent(op.split(single, t, np.zeros(2), np.zeros(2)).constraint_jacobian, rng)
        u = rng.uniform(-5.0, 5.0, 2)
        one, two = op.split(single, t, td, u), op.split(double, t, td, u)
        assert two.constraint_rank == 1
        for name in ("drift", "ctrl", "total"):
            close(two.quantity(name), one.quantity(name), one.accel_scale)
        close(two.constraint_force, one.constraint_force, one.lam_scale)
        close(two.constraint_force_drift, one.constraint_force_drift, one.lam_scale)
        close(two.lam, np.repeat(one.lam / 2.0, 2), one.lam_scale)
        close(two.lam_drift, np.repeat(one.lam_drift / 2.0, 2), one.lam_scale)
        assert two.conditions["constraint"] > 1e12 and two.conditions["constraint_consistency"] < 1e-12


CHANGE_POINT = np.array([np.pi / 2, 0.0, np.pi / 2])


def four_bar_tracking_y():
    """The four-bar with its task point moving in y only: at the change point every point of the collinear links
    moves along y, so the default x-y task point makes ``A`` singular there (task BREAKDOWN)."""
    model = model_of("four_bar")
    tp = model.task_point()
    return build_model("four_bar_y", model.bodies, gravity=model.gravity, constraints=model.constraints,
                       task_points=[TaskPoint(tp.name, tp.body, tp.offset, [[0.0, 1.0, 0.0]])])


def test_four_bar_change_point_with_the_default_task_is_a_task_breakdown():
    s = op.split(model_of("four_bar"), CHANGE_POINT, [1.0, -1.0, 1.0], [1.0, 2.0, 3.0])
    assert s.conditions["task"] == np.inf and "task" in policy.breakdown(s)
    assert np.all(np.isnan(s.total)) and np.all(np.isfinite(s.constraint_jacobian))


def test_four_bar_change_point_consistent_branch():
    """q = (pi/2, 0, pi/2): the loop Jacobian loses its x row (rank 1). Moving along the parallelogram branch,
    qd = (1, -1, 1), the x row's bias vanishes too, so ``H_t`` is not empty: the answer is unique and equals the
    solve with the redundant row dropped (KKT with the y row only, M from the backend), with lam_x = 0."""
    model = four_bar_tracking_y()
    qd, u = np.array([1.0, -1.0, 1.0]), np.array([1.0, 2.0, -3.0])
    s = op.split(model, CHANGE_POINT, qd, u)
    close(s.constraint_jacobian, [[0.0, 0.0, 0.0], [3.0, 2.0, -1.0]])
    close(s.constraint_bias[0], 0.0, 1.0)
    assert s.constraint_rank == 1 and s.conditions["constraint_consistency"] < 1e-12
    M, Cqd, g = op.joint_space_terms(model, CHANGE_POINT, qd)
    Jy = s.constraint_jacobian[1:]
    KKT = np.block([[M, -Jy.T], [Jy, np.zeros((1, 1))]])
    for tau, qdd, lam in ((u, s.total, s.lam), (np.zeros(3), s.drift, s.lam_drift)):
        sol = np.linalg.solve(KKT, np.r_[tau - Cqd - g, -s.constraint_bias[1:]])
        close(qdd, sol[:3], s.accel_scale)
        close(lam, [0.0, sol[3]], s.lam_scale)
    check_split_identities(s)


def test_four_bar_change_point_inconsistent_branch_is_finite():
    """qd = (0, 1, 2) is in null(Jc) but leaves both branches: the x row's bias is 2 while its Jacobian row is 0,
    so ``H_t`` is empty. No exception: finite least-squares numbers and a non-zero consistency condition."""
    s = op.split(four_bar_tracking_y(), CHANGE_POINT, [0.0, 1.0, 2.0], [1.0, 2.0, -3.0])
    close(s.constraint_bias[0], 2.0, 1.0)
    for name in ("drift", "ctrl", "total", "lam", "lam_drift", "task_drift"):
        assert np.all(np.isfinite(s.quantity(name))), name
    assert s.constraint_rank == 1 and s.conditions["constraint_consistency"] > 0.1
    close(s.additivity, 0.0, s.accel_scale)
    close(s.admissibility_total[1:], 0.0, s.accel_scale * 3.0)


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
    KKT = np.block([[M, -Jc.T], [Jc, np.zeros((2, 2))]])
    for tau, qdd, lam in ((u, s.total, s.lam), (np.zeros(n), s.drift, s.lam_drift)):
        sol = np.linalg.solve(KKT, np.r_[tau - Cqd - g, -Jc_bias])
        close(qdd, sol[:n], s.accel_scale)
        close(lam, sol[n:], s.lam_scale)
    Minv = np.linalg.inv(M)
    B_c = Minv - Minv @ Jc.T @ np.linalg.solve(Jc @ Minv @ Jc.T, Jc @ Minv)
    close(s.ctrl, B_c @ u, s.accel_scale)
    assert s.constraint_rank == 2
    check_split_identities(s)
