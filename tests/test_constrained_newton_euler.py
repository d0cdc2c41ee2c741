"""Constrained dynamics in the Newton–Euler backend (article 5, eq. 12-17; 6.1; 7.2: constraints as joint
reactions), against references written here:

* the cartesian pendulum's multiplier in closed form (``cases.constrained.cartesian_pendulum``);
* the double pendulum with its tip on a circle (article 5.6) at an admissible state found by hand (inverse
  kinematics), against the 3x3 KKT system of 5.6 built from the article's closed forms (closed_forms.py) with
  ``Jc`` and ``Jcdot qd`` differentiated by hand from eq. (4);
* the absolute-coordinate double pendulum (6 coordinates, 4 loop rows) against the same machine in joint
  coordinates: same joint accelerations, and multipliers equal to the joint-coordinate model's joint forces;
* a gear (joint coupling) on the article's double pendulum, against its KKT system;
* redundant rows and a four-bar at its change point (minimum-norm multipliers, unique accelerations, no raise);
* a spatial loop and a spatial model with every declaration, against finite differences of ``phi`` and the
  equations of motion with the backend's own ``M`` and ``h``;
* the joint reactions with the loop forces applied: their axis components are the actuation ``B u``.
"""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest
import scipy.linalg

import cases
from cases.model import Body, build_model
from closed_forms import article_Cqd, article_g, article_M, endpoint_jacobian
from crosscheck.sampling import sample_states
from formalisms import newton_euler as ne

G = 9.81
CONSTRAINED_CASES = ("double_pendulum_circle", "four_bar", "slider_crank", "cartesian_pendulum",
                     "double_pendulum_absolute_loop")


def axis_components(model, reactions):
    """The component of each joint reaction along its joint axis (the joint torque / force)."""
    return np.array([b.axis @ (reactions[i, 3:] if b.joint == "revolute" else reactions[i, :3])
                     for i, b in enumerate(model.bodies)])


def assert_small(value, scale, rel=1e-12, what=""):
    assert np.abs(value).max() <= rel * max(scale, 1.0), f"{what}: {np.abs(value).max():.3e} (scale {scale:.3e})"


# ----------------------------------------------------------------------------------------------------------
# Cartesian pendulum: lam = -m (|v|^2 + p . (gravity + u/m)) / (2 L^2)
# ----------------------------------------------------------------------------------------------------------

@pytest.mark.parametrize("m, L, angle, rate, u", [
    (1.0, 1.0, 0.3, 0.0, (0.0, 0.0)),
    (1.0, 1.0, -1.2, 2.5, (3.0, -1.0)),
    (2.5, 0.7, 2.8, -1.7, (-4.0, 6.0)),
    (0.3, 2.0, np.pi / 2, 0.9, (0.5, 0.5)),
])
def test_cartesian_pendulum_multiplier_closed_form(m, L, angle, rate, u):  # noqa: N803
    model = cases.load("cartesian_pendulum", m=m, L=L)
    p = L * np.array([np.sin(angle), -np.cos(angle)])
    v = rate * L * np.array([np.cos(angle), np.sin(angle)])            # tangent to the circle
    u = np.array(u)
    gravity = np.array([0.0, -G])
    s = ne.split(model, p, v, u)
    for lam, force in ((s.lam, u), (s.lam_drift, np.zeros(2))):
        expected = -m * (v @ v + p @ (gravity + force / m)) / (2.0 * L**2)
        assert lam == pytest.approx([expected], rel=1e-13, abs=1e-13)
    lam, lam0 = s.lam[0], s.lam_drift[0]
    np.testing.assert_allclose(s.total, gravity + u / m + 2.0 * lam * p / m, rtol=0, atol=1e-12)
    np.testing.assert_allclose(s.drift, gravity + 2.0 * lam0 * p / m, rtol=0, atol=1e-12)
    np.testing.assert_allclose(s.drift + s.ctrl, s.total, rtol=0, atol=1e-13 * max(1.0, np.abs(s.total).max()))
    np.testing.assert_allclose(s.constraint_jacobian, [2.0 * p], rtol=0, atol=1e-15)
    assert s.constraint_bias == pytest.approx([2.0 * v @ v], rel=1e-14, abs=1e-15)


# ----------------------------------------------------------------------------------------------------------
# Double pendulum with its tip on a circle (article 5.6), against the KKT system of the closed forms
# ----------------------------------------------------------------------------------------------------------

CENTER, RADIUS = np.array([1.0, -1.0]), 0.5           # the case's defaults (l1 = l2 = 1, m1 = m2 = 1)


def circle_state(beta: float, speed: float):
    """An admissible (theta, thetad): the tip at angle ``beta`` on the circle by inverse kinematics of eq. (4)
    (elbow sign +), and a velocity along the circle."""
    tip = CENTER + RADIUS * np.array([np.cos(beta), np.sin(beta)])
    t2 = np.arccos((tip @ tip - 2.0) / 2.0)
    t1 = np.arctan2(tip[0], -tip[1]) - np.arctan2(np.sin(t2), 1.0 + np.cos(t2))
    t = np.array([t1, t2])
    Jc, _ = circle_rows(t, np.zeros(2))
    return t, speed * np.array([Jc[1], -Jc[0]]) / np.linalg.norm(Jc)


def tip_bias(t, td):
    """``Jdot td`` of the tip, from x2 = l1 sin t1 + l2 sin(t1 + t2), y2 = -l1 cos t1 - l2 cos(t1 + t2)."""
    w = td[0] + td[1]
    return np.array([-np.sin(t[0]) * td[0] ** 2 - np.sin(t[0] + t[1]) * w**2,
                     np.cos(t[0]) * td[0] ** 2 + np.cos(t[0] + t[1]) * w**2])


def circle_rows(t, td):
    """``Jc = 2 d^T J`` and ``Jcdot qd = 2 |J td|^2 + 2 d . (Jdot td)``, d = tip - centre, J of eq. (5)."""
    tip = np.array([np.sin(t[0]) + np.sin(t[0] + t[1]), -np.cos(t[0]) - np.cos(t[0] + t[1])])
    d, J = tip - CENTER, endpoint_jacobian(t)
    return 2.0 * d @ J, 2.0 * (J @ td) @ (J @ td) + 2.0 * d @ tip_bias(t, td)


def kkt(M, f, Jc, bias):
    """Article 5.6: [[M, -Jc^T], [Jc, 0]] [qdd, lam] = [f, -Jcdot qd]."""
    Jc = np.atleast_2d(Jc)
    k = Jc.shape[0]
    K = np.block([[M, -Jc.T], [Jc, np.zeros((k, k))]])
    x = np.linalg.solve(K, np.r_[f, -np.atleast_1d(bias)])
    return x[:len(f)], x[len(f):]


@pytest.mark.parametrize("beta, speed, tau", [(0.4, 0.0, (2.0, -1.0)), (2.0, 1.5, (-3.0, 4.0)),
                                              (-2.5, -2.2, (0.5, 0.0)), (np.pi, 0.7, (0.0, 0.0))])
def test_circle_matches_article_kkt(beta, speed, tau):
    t, td = circle_state(beta, speed)
    tau = np.array(tau)
    M, h = article_M(t[1]), article_Cqd(t[1], *td) + article_g(*t)
    Jc, bias = circle_rows(t, td)
    total, lam = kkt(M, tau - h, Jc, bias)
    drift, lam0 = kkt(M, -h, Jc, bias)
    Minv = np.linalg.inv(M)
    B_c = Minv @ (np.eye(2) - np.outer(Jc, Jc) @ Minv / (Jc @ Minv @ Jc))     # eq. (17)

    s = ne.split(cases.load("double_pendulum_circle"), t, td, tau)
    scale = max(1.0, np.abs(total).max(), np.abs(drift).max())
    np.testing.assert_allclose(s.constraint_value, [0.0], rtol=0, atol=1e-14)
    np.testing.assert_allclose(s.constraint_jacobian, [Jc], rtol=0, atol=1e-14)
    np.testing.assert_allclose(s.constraint_bias, [bias], rtol=0, atol=1e-13 * max(1.0, abs(bias)))
    for name, expected in (("total", total), ("drift", drift), ("ctrl", B_c @ tau)):
        np.testing.assert_allclose(getattr(s, name), expected, rtol=0, atol=1e-12 * scale, err_msg=name)
    np.testing.assert_allclose(s.lam, lam, rtol=1e-12, atol=1e-12)
    np.testing.assert_allclose(s.lam_drift, lam0, rtol=1e-12, atol=1e-12)
    assert_small(s.drift + s.ctrl - s.total, scale, 1e-14, "additivity")
    for name, qdd in (("total", s.total), ("drift", s.drift)):                 # on H_t (eq. 16)
        assert_small(Jc @ qdd + bias, np.abs(Jc).max() * scale, 1e-14, f"H_t residual of {name}")
    assert_small(Jc @ s.ctrl, np.abs(Jc).max() * scale, 1e-14, "Jc ctrl")
    assert_small(np.array([s.power_constr]), np.abs(Jc * lam[0]).max() * np.abs(td).max(), 1e-13, "power_constr")
    np.testing.assert_allclose(s.power_constr_per_coord, Jc * lam[0] * td, rtol=0, atol=1e-12 * np.abs(lam).max())
    tip_acc = endpoint_jacobian(t) @ drift + tip_bias(t, td)                   # eq. (23) at the drift
    np.testing.assert_allclose(s.task_drift, tip_acc, rtol=0, atol=1e-12 * scale)
    assert s.kinetic_energy == pytest.approx(0.5 * td @ M @ td, rel=1e-13, abs=1e-15)
    assert s.constraint_rank == 1 and s.conditions["constraint_consistency"] == 0.0


# ----------------------------------------------------------------------------------------------------------
# The double pendulum in absolute coordinates (two free bodies and 4 loop rows) vs joint coordinates
# ----------------------------------------------------------------------------------------------------------

@pytest.mark.parametrize("t, td, tau", [((0.3, 0.5), (0.7, -1.1), (1.0, -0.5)),
                                        ((-2.0, 1.2), (-2.5, 3.0), (0.0, 4.0)),
                                        ((3.0, -0.2), (0.0, 0.0), (-6.0, 2.0))])
def test_absolute_loop_matches_joint_coordinates(t, td, tau):
    """theta1dd = phi1dd, theta2dd = phi2dd - phi1dd; the shoulder multipliers are the force the world exerts on
    link 1 at the shoulder and the elbow ones the force link 1 exerts on link 2: the joint model's joint forces."""
    params = dict(m1=1.3, m2=0.8, l1=0.9, l2=1.2, I1=0.05, I2=0.2)
    loop = cases.load("double_pendulum_absolute_loop", **params)
    joint = cases.load("double_pendulum", **params)
    t, td, tau = (np.array(x) for x in (t, td, tau))
    phi, phid = np.array([t[0], t.sum()]), np.array([td[0], td.sum()])
    elbow = params["l1"] * np.array([np.sin(phi[0]), -np.cos(phi[0])])
    elbow_d = params["l1"] * phid[0] * np.array([np.cos(phi[0]), np.sin(phi[0])])
    q = np.r_[0.0, 0.0, phi[0], elbow, phi[1]]
    qd = np.r_[0.0, 0.0, phid[0], elbow_d, phid[1]]

    s, ref = ne.split(loop, q, qd, tau), ne.split(joint, t, td, tau)
    scale = max(1.0, np.abs(ref.total).max())
    to_joint = lambda a: np.array([a[2], a[5] - a[2]])  # noqa: E731
    for name in ("total", "drift", "ctrl"):
        np.testing.assert_allclose(to_joint(getattr(s, name)), getattr(ref, name), rtol=0, atol=1e-12 * scale,
                                   err_msg=name)
    np.testing.assert_allclose(s.constraint_value, np.zeros(4), rtol=0, atol=1e-15)
    assert_small(s.admissibility_total, scale, 1e-13, "H_t residual")
    assert_small(s.constraint_force @ qd, np.abs(s.constraint_force).max(), 1e-13, "power_constr")
    R = [_rot((0.0, 0.0, 1.0), a) for a in phi]                                   # link frames in the world
    for lam, reactions in ((s.lam, ref.extras["joint_reactions"]), (s.lam_drift, ref.extras["joint_reactions_drift"])):
        forces = np.array([R[0] @ reactions[0, :3], R[1] @ reactions[1, :3]])[:, :2].reshape(-1)
        np.testing.assert_allclose(lam, forces, rtol=0, atol=1e-12 * np.abs(forces).max())
    np.testing.assert_allclose(s.task_drift, ref.task_drift, rtol=0, atol=1e-12 * scale)
    assert s.kinetic_energy == pytest.approx(ref.kinetic_energy, rel=1e-13, abs=1e-15)
    assert s.power_ctrl == pytest.approx(ref.power_ctrl, rel=1e-13, abs=1e-15)


# ----------------------------------------------------------------------------------------------------------
# A gear: the coupling theta1 - 2 theta2 = 0.1 on the article's double pendulum
# ----------------------------------------------------------------------------------------------------------

def test_joint_coupling_matches_kkt_and_acts_as_a_joint_torque():
    gear = cases.JointCoupling("gear", ("link1", "link2"), (1.0, -2.0), 0.1)
    base = cases.load("double_pendulum")
    model = build_model("geared", base.bodies, gravity=base.gravity, task_points=base.task_points,
                        constraints=[gear])
    t, td, tau = np.array([0.7, 0.3]), np.array([1.4, 0.7]), np.array([2.0, -3.0])
    Jc = np.array([1.0, -2.0])
    M, h = article_M(t[1]), article_Cqd(t[1], *td) + article_g(*t)
    total, lam = kkt(M, tau - h, Jc, 0.0)
    s = ne.split(model, t, td, tau)
    np.testing.assert_allclose(s.constraint_value, [0.0], atol=1e-15)
    np.testing.assert_allclose(s.total, total, rtol=0, atol=1e-12 * np.abs(total).max())
    np.testing.assert_allclose(s.lam, lam, rtol=1e-12)
    np.testing.assert_allclose(s.constraint_bias, [0.0], atol=0)
    # no point force: the gear's torques c lam act on the joints, so they are in the axis components
    np.testing.assert_allclose(axis_components(model, s.extras["joint_reactions"]), tau + Jc * lam[0],
                               rtol=0, atol=1e-12 * np.abs(lam).max())


# ----------------------------------------------------------------------------------------------------------
# Degenerate constraints: duplicated rows, the four-bar's change point
# ----------------------------------------------------------------------------------------------------------

def test_duplicated_constraint_gives_the_same_motion_and_half_multipliers():
    single = cases.load("double_pendulum_circle")
    (circle,) = single.constraints
    double = build_model("circle_twice", single.bodies, gravity=single.gravity, task_points=single.task_points,
                         constraints=[circle, dataclasses.replace(circle, name="again")])
    t, td = circle_state(1.1, 1.3)
    tau = np.array([1.5, -2.0])
    one, two = ne.split(single, t, td, tau), ne.split(double, t, td, tau)
    scale = max(1.0, np.abs(one.total).max())
    for name in ("total", "drift", "ctrl", "constraint_force", "constraint_force_drift"):
        np.testing.assert_allclose(getattr(two, name), getattr(one, name), rtol=0, atol=1e-12 * scale, err_msg=name)
    np.testing.assert_allclose(two.lam, [one.lam[0] / 2] * 2, rtol=1e-12)
    np.testing.assert_allclose(two.lam_drift, [one.lam_drift[0] / 2] * 2, rtol=1e-12)
    assert two.constraint_rank == 1 and one.constraint_rank == 1
    assert two.conditions["constraint_consistency"] < 1e-12
    np.testing.assert_allclose(axis_components(double, two.extras["joint_reactions"]), tau, rtol=0, atol=1e-12)


CHANGE_POINT = np.array([np.pi / 2, 0.0, np.pi / 2])


def test_four_bar_change_point_is_consistent_at_rest_and_unique():
    """At q = (pi/2, 0, pi/2) the loop Jacobian has rank 1. At rest the system is consistent: the accelerations
    and Jc^T lam are unique and equal those of the one independent row (a KKT solve written here)."""
    model = cases.load("four_bar")
    qd, u = np.zeros(3), np.array([1.0, -2.0, 0.5])
    s = ne.split(model, CHANGE_POINT, qd, u)
    assert s.constraint_rank == 1 and s.conditions["constraint_consistency"] < 1e-12
    assert all(np.all(np.isfinite(x)) for x in (s.total, s.drift, s.ctrl, s.lam, s.lam_drift))
    U, sv, _ = np.linalg.svd(s.constraint_jacobian)
    assert sv[1] < 1e-12 * sv[0]
    row = U[:, 0] @ s.constraint_jacobian
    M, h = ne.mass_matrix(model, CHANGE_POINT), ne.inverse_dynamics(model, CHANGE_POINT, qd, np.zeros(3))
    for qdd, force, lam in ((s.total, u - h, s.lam), (s.drift, -h, s.lam_drift)):
        expected, mu = kkt(M, force, row, U[:, 0] @ s.constraint_bias)
        np.testing.assert_allclose(qdd, expected, rtol=0, atol=1e-12 * np.abs(expected).max())
        np.testing.assert_allclose(s.constraint_jacobian.T @ lam, row * mu[0], rtol=0, atol=1e-12 * abs(mu[0]))
        assert np.linalg.norm(lam) == pytest.approx(abs(mu[0]), rel=1e-12)               # minimum norm
    assert_small(s.drift + s.ctrl - s.total, np.abs(s.total).max(), 1e-14, "additivity")


def test_four_bar_change_point_in_motion_returns_finite_numbers():
    """Moving through the change point off both branches, H_t can be empty: no raise, finite least-squares
    numbers, the inconsistency reported for the harness."""
    model = cases.load("four_bar")
    for qd in (np.array([1.0, -1.0, 1.0]), np.array([0.5, 0.0, 0.0]), np.array([0.0, 2.0, 0.0])):
        s = ne.split(model, CHANGE_POINT, qd, np.array([0.3, 0.0, -1.0]))
        assert all(np.all(np.isfinite(x)) for x in (s.total, s.drift, s.ctrl, s.lam, s.lam_drift))
        assert s.constraint_rank == 1 and np.isfinite(s.conditions["constraint_consistency"])
        assert_small(s.drift + s.ctrl - s.total, np.abs(s.total).max(), 1e-13, "additivity")


# ----------------------------------------------------------------------------------------------------------
# The loop forces in the joint reactions: axis components = B u on every constrained case
# ----------------------------------------------------------------------------------------------------------

@pytest.mark.parametrize("case", CONSTRAINED_CASES)
def test_constrained_joint_reactions_carry_the_loop_forces(case):
    """With the constraint forces applied as point forces in the backward pass, each joint transmits along its
    axis exactly the actuation (B u with the input, 0 at the drift). Without them (``ne.joint_reactions``, the
    open tree) the axis components are B u + Jc^T lam: the check sees the loop forces."""
    model = cases.load(case)
    for state in sample_states(model, 3, 11, case):
        q, qd, u = (np.array(x) for x in (state.q, state.qd, state.u))
        s = ne.split(model, q, qd, u)
        Bu = model.input_map @ u
        scale = max(1.0, np.abs(s.constraint_force).max(), np.abs(Bu).max())
        np.testing.assert_allclose(axis_components(model, s.extras["joint_reactions"]), Bu, rtol=0,
                                   atol=1e-12 * scale)
        np.testing.assert_allclose(axis_components(model, s.extras["joint_reactions_drift"]), 0.0, rtol=0,
                                   atol=1e-12 * scale)
        np.testing.assert_allclose(axis_components(model, ne.joint_reactions(model, q, qd, s.total)),
                                   Bu + s.constraint_force, rtol=0, atol=1e-12 * scale)
        assert_small(s.admissibility_total, np.abs(s.total).max(), 1e-12, "H_t residual")


# ----------------------------------------------------------------------------------------------------------
# Spatial models: a closed 3-D loop, and every declaration at once
# ----------------------------------------------------------------------------------------------------------

def _unit(v):
    v = np.asarray(v, dtype=float)
    return v / np.linalg.norm(v)


def _box(name, parent, joint, axis, mass, com, translation=(0.0, 0.0, 0.0), rotation=np.eye(3)):
    inertia = mass * np.diag([0.03, 0.02, 0.04])
    return Body(name, parent, joint, _unit(axis), mass, com=com, inertia=inertia, rotation=rotation,
                translation=translation)


def _rot(axis, angle):
    """Rotation by ``angle`` about ``axis`` (the matrix exponential of its skew matrix)."""
    x, y, z = _unit(axis) * angle
    return scipy.linalg.expm(np.array([[0.0, -z, y], [z, 0.0, -x], [-y, x, 0.0]]))


BODIES_3D = [
    _box("a1", None, "revolute", (0, 0, 1), 1.0, (0.0, -0.25, 0.0)),
    _box("a2", "a1", "revolute", (1, 0, 0), 0.8, (0.0, -0.2, 0.05), (0.0, -0.5, 0.0), _rot((0, 1, 0), 0.3)),
    _box("a3", "a2", "prismatic", (0, -1, 0), 0.5, (0.0, -0.1, 0.0), (0.0, -0.3, 0.1)),
    _box("b1", None, "revolute", (0, 1, 0), 1.2, (0.1, -0.3, 0.0), (0.8, 0.0, 0.2)),
    _box("b2", "b1", "revolute", (1, 1, 0), 0.6, (0.0, -0.25, 0.0), (0.0, -0.6, 0.0), _rot((1, 0, 1), -0.4)),
]
B_3D = np.eye(5)[:, [0, 1, 3]] + 0.3 * np.eye(5)[:, [2, 4, 2]]
Q0 = np.array([0.4, -0.3, 0.1, 0.7, -0.5])
GRAVITY_3D = (0.0, -9.81, 0.0)


def pose(bodies, q, body):
    """World <- body transform by composing 4x4 placements and joint motions (written here)."""
    index = {b.name: i for i, b in enumerate(bodies)}
    T, name = np.eye(4), body
    chain = []
    while name is not None:
        chain.append(index[name])
        name = bodies[index[name]].parent
    for i in reversed(chain):
        b = bodies[i]
        X, motion = np.eye(4), np.eye(4)
        X[:3, :3], X[:3, 3] = b.rotation, b.translation
        if b.joint == "revolute":
            motion[:3, :3] = _rot(b.axis, q[i])
        else:
            motion[:3, 3] = q[i] * np.asarray(b.axis)
        T = T @ X @ motion
    return T


def closed_loop_3d():
    """The tip point of chain a joined to chain b in all three directions, body b's point placed where a's point
    is at Q0 (so Q0 is on the manifold); 5 joints, 3 rows, 2 degrees of freedom."""
    tip_a = np.array([0.0, -0.2, 0.0])
    offset_b = (np.linalg.inv(pose(BODIES_3D, Q0, "b2")) @ pose(BODIES_3D, Q0, "a3") @ np.r_[tip_a, 1.0])[:3]
    loop = cases.PointsCoincide("tips", "a3", tip_a, "b2", offset_b)
    return build_model("loop_3d", BODIES_3D, gravity=GRAVITY_3D, input_map=B_3D, constraints=[loop])


def every_declaration_3d():
    """All four declarations on the spatial bodies (4 rows, 1 degree of freedom); Q0 is not on the manifold."""
    plane = _rot((1, 2, 3), 0.7)[:2]
    return build_model("every_declaration_3d", BODIES_3D, gravity=GRAVITY_3D, input_map=B_3D, constraints=[
        cases.PointOnCircle("circle", "a3", (0.05, -0.2, 0.0), (0.3, -0.6, 0.1), 0.4, plane),
        cases.PointOnLine("line", "b2", (0.0, -0.3, 0.1), (0.5, -0.5, 0.0), [_unit((1, -1, 2))]),
        cases.JointCoupling("gear", ("a1", "b1"), (1.0, -0.5), 0.2),
        cases.PointsCoincide("pin", "a2", (0.0, -0.1, 0.0), None, (0.1, -0.4, 0.0), [[0.0, 0.0, 1.0]]),
    ])


def finite_difference_rows(model, q, qd, step=1e-6):
    """``dphi/dq`` by central differences of ``phi`` and ``Jcdot qd = d/dt (Jc(q + t qd)) qd`` likewise."""
    phi = lambda x: ne.split(model, x, qd, np.zeros(model.m)).constraint_value  # noqa: E731
    Jc = np.column_stack([(phi(q + step * e) - phi(q - step * e)) / (2 * step) for e in np.eye(model.n)])
    jac = lambda x: ne.split(model, x, qd, np.zeros(model.m)).constraint_jacobian  # noqa: E731
    bias = (jac(q + step * qd) - jac(q - step * qd)) @ qd / (2 * step)
    return Jc, bias


@pytest.mark.parametrize("build", [closed_loop_3d, every_declaration_3d])
def test_spatial_constraint_kinematics_and_equations_of_motion(build):
    model = build()
    rng = np.random.default_rng(3)
    for _ in range(3):
        q = Q0 + 0.3 * rng.standard_normal(5) if model.name != "loop_3d" else Q0
        s0 = ne.split(model, q, np.zeros(5), np.zeros(3))
        null = np.linalg.svd(s0.constraint_jacobian)[2][model.k:]
        qd = rng.standard_normal(len(null)) @ null * 2.0 if model.name == "loop_3d" else rng.standard_normal(5)
        u = rng.uniform(-3.0, 3.0, 3)
        s = ne.split(model, q, qd, u)
        Jc_fd, bias_fd = finite_difference_rows(model, q, qd)
        np.testing.assert_allclose(s.constraint_jacobian, Jc_fd, rtol=0, atol=1e-8)
        np.testing.assert_allclose(s.constraint_bias, bias_fd, rtol=0, atol=1e-7 * max(1.0, np.abs(bias_fd).max()))
        M, h = ne.mass_matrix(model, q), ne.inverse_dynamics(model, q, qd, np.zeros(5))
        scale = max(1.0, np.abs(s.total).max(), np.abs(s.drift).max())
        force_scale = np.abs(M).max() * scale
        for qdd, force, lam in ((s.total, B_3D @ u - h, s.lam), (s.drift, -h, s.lam_drift)):   # eq. (12, 13)
            assert_small(M @ qdd - force - s.constraint_jacobian.T @ lam, force_scale, 1e-12, "eq. (12)")
            assert_small(s.constraint_jacobian @ qdd + s.constraint_bias, scale * np.abs(s.constraint_jacobian).max(),
                         1e-12, "eq. (13)")
        assert_small(s.drift + s.ctrl - s.total, scale, 1e-14, "additivity")
        coupling = np.zeros(5)
        if model.name != "loop_3d":          # the gear's torque is a joint torque, in the axis components
            coupling[[0, 3]] = np.array([1.0, -0.5]) * s.lam[2]
        np.testing.assert_allclose(axis_components(model, s.extras["joint_reactions"]), B_3D @ u + coupling,
                                   rtol=0, atol=1e-12 * max(force_scale, np.abs(s.lam).max()))
        if model.name == "loop_3d":
            assert s.constraint_rank == 3
            np.testing.assert_allclose(s.constraint_value, np.zeros(3), rtol=0, atol=1e-14)
            assert_small(np.array([s.power_constr]), np.abs(s.constraint_force).max() * np.abs(qd).max(), 1e-12,
                         "power_constr")
