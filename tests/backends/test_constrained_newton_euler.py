"""Constrained dynamics in the Newton–Euler backend (article 5, eq. 12-17; 6.1; 7.2: constraints as joint
reactions): what only this backend has. The references every backend shares (the cartesian pendulum's multiplier,
the circle's KKT solve, the absolute loop's accelerations, a gear, the split identities, a duplicated constraint, the
four-bar at its change point) are in ``test_constrained_backends.py``.

* the absolute-coordinate double pendulum's multipliers are the joint-coordinate model's joint forces;
* a gear's torques ``Jc^T lam`` act on the joints (in the axis components of the joint reactions), and a duplicated
  circle leaves the actuation there;
* a spatial loop and a spatial model with every declaration, against finite differences of ``phi`` and the
  equations of motion with the backend's own ``M`` and ``h``;
* the joint reactions with the loop forces applied: their axis components are the actuation ``B u``;
* the backend's own conditioning (cond S, rank, consistency, lam_scale, accel_scale) on the cartesian pendulum in
  closed form.
"""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest
import scipy.linalg

import cases
from cases.model import Body
from cases.build import build_model
from closed_forms import absolute_loop_state, circle_state
from crosscheck.core.sampling import sample_states
from formalisms import newton_euler as ne

CONSTRAINED_CASES = ("double_pendulum_circle", "four_bar", "slider_crank", "cartesian_pendulum",
                     "double_pendulum_absolute_loop")


def axis_components(model, reactions):
    """The component of each joint reaction along its joint axis (the joint torque / force)."""
    return np.array([b.axis @ (reactions[i, 3:] if b.joint == "revolute" else reactions[i, :3])
                     for i, b in enumerate(model.bodies)])


def assert_small(value, scale, rel=1e-12, what=""):
    assert np.abs(value).max() <= rel * max(scale, 1.0), f"{what}: {np.abs(value).max():.3e} (scale {scale:.3e})"


# ----------------------------------------------------------------------------------------------------------
# The loop multipliers and the gear's torques in the joint reactions
# ----------------------------------------------------------------------------------------------------------

@pytest.mark.parametrize("t, td, tau", [((0.3, 0.5), (0.7, -1.1), (1.0, -0.5)),
                                        ((-2.0, 1.2), (-2.5, 3.0), (0.0, 4.0)),
                                        ((3.0, -0.2), (0.0, 0.0), (-6.0, 2.0))])
def test_absolute_loop_multipliers_are_the_joint_models_joint_forces(t, td, tau):
    """The shoulder multipliers are the force the world exerts on link 1 at the shoulder and the elbow ones the force
    link 1 exerts on link 2: the joint model's joint forces (its joint reactions, rotated to the world)."""
    params = dict(m1=1.3, m2=0.8, l1=0.9, l2=1.2, I1=0.05, I2=0.2)
    loop = cases.load("double_pendulum_absolute_loop", **params)
    joint = cases.load("double_pendulum", **params)
    t, td, tau = (np.array(x) for x in (t, td, tau))
    q, qd = absolute_loop_state(t, td, params["l1"])
    s, ref = ne.split(loop, q, qd, tau), ne.split(joint, t, td, tau)
    R = [_rot((0.0, 0.0, 1.0), a) for a in (q[2], q[5])]                         # link frames in the world
    for lam, reactions in ((s.lam, ref.extras["joint_reactions"]), (s.lam_drift, ref.extras["joint_reactions_drift"])):
        forces = np.array([R[0] @ reactions[0, :3], R[1] @ reactions[1, :3]])[:, :2].reshape(-1)
        np.testing.assert_allclose(lam, forces, rtol=0, atol=1e-12 * np.abs(forces).max())


def test_joint_coupling_acts_as_a_joint_torque():
    """No point force: the gear's torques ``Jc^T lam`` act on the joints, so they are in the axis components."""
    gear = cases.JointCoupling("gear", ("link1", "link2"), (1.0, -2.0), 0.1)
    base = cases.load("double_pendulum")
    model = build_model("geared", base.bodies, gravity=base.gravity, task_points=base.task_points,
                        constraints=[gear])
    t, td, tau = np.array([0.7, 0.3]), np.array([1.4, 0.7]), np.array([2.0, -3.0])
    s = ne.split(model, t, td, tau)
    np.testing.assert_allclose(axis_components(model, s.extras["joint_reactions"]),
                               tau + np.array([1.0, -2.0]) * s.lam[0], rtol=0, atol=1e-12 * np.abs(s.lam).max())


def test_a_duplicated_constraint_leaves_the_actuation_in_the_joint_reactions():
    single = cases.load("double_pendulum_circle")
    (circle,) = single.constraints
    double = build_model("circle_twice", single.bodies, gravity=single.gravity, task_points=single.task_points,
                         constraints=[circle, dataclasses.replace(circle, name="again")])
    t, td = circle_state(1.1, 1.0, 1.3)
    tau = np.array([1.5, -2.0])
    two = ne.split(double, t, td, tau)
    np.testing.assert_allclose(axis_components(double, two.extras["joint_reactions"]), tau, rtol=0, atol=1e-12)


# ----------------------------------------------------------------------------------------------------------
# The conditioning, in closed form
# ----------------------------------------------------------------------------------------------------------

@pytest.mark.parametrize("m, L", [(1.0, 1.0), (2.5, 0.4)])
def test_conditioning_of_the_cartesian_pendulum_in_closed_form(m, L):  # noqa: N803
    """``M = m I``, ``Jc = 2 p^T``, ``Jcdot qd = 2 |v|^2`` with ``|p| = L``: ``S = 4 L^2 / m``, one direction kept (cond
    1, consistent). The scales by their definitions (``formalisms.interface.Split``): ``accel_0 = ||M^-1|| (|g|_1 +
    |u|_1 + ||M|| |v|^2 + |gravity|_1 sqrt(m_total ||M||)) = (2 m G + |u|_1 + m |v|^2) / m``, ``lam_scale = (|Jcdot
    qd|_1 + ||Jc|| accel_0) / S`` and ``accel_scale = accel_0 + ||M^-1|| ||Jc|| lam_scale``."""
    model = cases.load("cartesian_pendulum", m=m, L=L)
    for a, w, u in ((0.3, 1.5, (1.0, -2.0)), (2.0, -0.7, (0.0, 3.0)), (-1.2, 0.0, (0.0, 0.0))):
        p, v = L * np.array([np.sin(a), -np.cos(a)]), w * L * np.array([np.cos(a), np.sin(a)])
        s = ne.split(model, p, v, np.array(u))
        accel_0 = (2.0 * m * 9.81 + np.abs(u).sum() + m * v @ v) / m
        lam_scale = (2.0 * v @ v + 2.0 * L * accel_0) / (4.0 * L**2 / m)
        assert s.cond_M == pytest.approx(1.0, rel=1e-15) and s.constraint_rank == 1
        assert s.conditions["constraint"] == pytest.approx(1.0, rel=1e-15)
        assert s.conditions["constraint_kept"] == pytest.approx(1.0, rel=1e-15)
        assert s.conditions["constraint_consistency"] == 0.0
        assert s.lam_scale == pytest.approx(lam_scale, rel=1e-13)
        assert s.accel_scale == pytest.approx(accel_0 + 2.0 * L * lam_scale / m, rel=1e-13)
        force = 2.0 * p * s.lam[0]
        np.testing.assert_allclose(s.constraint_force, force, rtol=0, atol=1e-14 * np.abs(force).max())
        assert s.power_constr == pytest.approx(force @ v, abs=1e-14 * np.abs(force).max() * np.abs(v).sum())


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
