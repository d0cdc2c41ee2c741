"""Tests of the Newton–Euler backend (article 6.1) against references written independently here:
the double-pendulum closed forms (article eqs. 6-8 and the 4.7.2 inverse, from closed_forms.py; eq. 4
differentiated here) and, for a 3-D tree, the Euler–Lagrange residual of a kinetic + potential energy computed
from poses by 4x4 homogeneous transforms and matrix exponentials.
"""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest
import scipy.linalg
from hypothesis import given, settings
from hypothesis import strategies as st

from cases.model import Body
from cases.build import build_model
from closed_forms import inv2, pendulum_terms
from formalisms import newton_euler as ne
from formalisms.interface import StateError

G = 9.81


# ----------------------------------------------------------------------------------------------------------
# Double pendulum of article section 3 (point masses at the link ends, angles from hanging down, relative)
# ----------------------------------------------------------------------------------------------------------

def double_pendulum(m1=1.0, m2=1.0, l1=1.0, l2=1.0):
    z = (0.0, 0.0, 1.0)
    return build_model("article_double_pendulum", [
        Body("link1", None, "revolute", axis=z, mass=m1, com=(0.0, -l1, 0.0)),
        Body("link2", "link1", "revolute", axis=z, mass=m2, com=(0.0, -l2, 0.0), translation=(0.0, -l1, 0.0)),
    ], gravity=(0.0, -G, 0.0))


def point_accelerations(t, td, tdd, l1=1.0, l2=1.0):
    """Accelerations of the two point masses: eq. (4) differentiated twice by hand (world x, y, z)."""
    phi, phid, phidd = t[0] + t[1], td[0] + td[1], tdd[0] + tdd[1]
    a1 = l1 * np.array([np.cos(t[0]) * tdd[0] - np.sin(t[0]) * td[0] ** 2,
                        np.sin(t[0]) * tdd[0] + np.cos(t[0]) * td[0] ** 2, 0.0])
    a2 = a1 + l2 * np.array([np.cos(phi) * phidd - np.sin(phi) * phid ** 2,
                             np.sin(phi) * phidd + np.cos(phi) * phid ** 2, 0.0])
    return a1, a2


def rot_z(angle):
    c, s = np.cos(angle), np.sin(angle)
    return np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])


THETA, THETAD, TAU = np.array([np.pi / 4, np.pi / 6]), np.array([2.0, -1.0]), np.array([5.0, -2.0])


def accel_scale(model, M, Cqd, g, tau, qd):
    """``Split.accel_scale`` by its definition: ``||M^-1|| (|C qd|_1 + |g|_1 + |B u|_1 + ||M|| |qd|^2 + |gravity|_1
    sqrt(m_total ||M||))``, the norms from the eigenvalues of the closed-form M."""
    ev = np.linalg.eigvalsh(M)
    m_total = sum(b.mass for b in model.bodies)
    H = (np.abs(Cqd).sum() + np.abs(g).sum() + np.abs(tau).sum() + ev[-1] * qd @ qd
         + np.abs(model.gravity).sum() * np.sqrt(m_total * ev[-1]))
    return H / ev[0]


def test_double_pendulum_split_matches_article_closed_form():
    M, Cqd, g = pendulum_terms(THETA, THETAD, g=G)
    Minv = inv2(M)
    drift, ctrl, total = -Minv @ (Cqd + g), Minv @ TAU, Minv @ (TAU - Cqd - g)
    s = ne.split(double_pendulum(), THETA, THETAD, TAU)
    for name, expected in (("drift", drift), ("ctrl", ctrl), ("total", total)):
        np.testing.assert_allclose(getattr(s, name), expected, rtol=0, atol=1e-12, err_msg=name)
    np.testing.assert_allclose(s.drift + s.ctrl, s.total, rtol=0, atol=4 * np.finfo(float).eps * np.abs(total).max())
    np.testing.assert_allclose(ne.mass_matrix(double_pendulum(), THETA), M, rtol=0, atol=1e-14)
    np.testing.assert_allclose(ne.inverse_dynamics(double_pendulum(), THETA, THETAD, np.zeros(2)), Cqd + g,
                               rtol=0, atol=1e-13)
    ev = np.linalg.eigvalsh(M)
    assert s.cond_M == pytest.approx(ev[1] / ev[0], rel=1e-12)
    assert s.accel_scale == pytest.approx(accel_scale(double_pendulum(), M, Cqd, g, TAU, THETAD), rel=1e-12)
    assert s.power_ctrl == pytest.approx(TAU @ THETAD, rel=1e-15)
    assert s.lam is None and s.lam_drift is None


@pytest.mark.parametrize("which", ["joint_reactions", "joint_reactions_drift"])
def test_double_pendulum_joint_reactions_match_point_mass_newton(which):
    """6.1.5: joint 2 carries m2 (a2 - g); joint 1 carries everything outboard. Moments about the joint origins."""
    M, Cqd, g = pendulum_terms(THETA, THETAD, g=G)
    tau = TAU if which == "joint_reactions" else np.zeros(2)
    qdd = inv2(M) @ (tau - Cqd - g)
    a1, a2 = point_accelerations(THETA, THETAD, qdd)
    grav = np.array([0.0, -G, 0.0])
    F1_world, F2_world = 1.0 * (a1 - grav), 1.0 * (a2 - grav)
    R1, R2 = rot_z(THETA[0]), rot_z(THETA.sum())
    f2 = R2.T @ F2_world
    n2 = np.cross([0.0, -1.0, 0.0], f2)
    p1, p2 = R1 @ [0.0, -1.0, 0.0], R1 @ [0.0, -1.0, 0.0] + R2 @ [0.0, -1.0, 0.0]
    f1 = R1.T @ (F1_world + F2_world)
    n1 = R1.T @ (np.cross(p1, F1_world) + np.cross(p2, F2_world))
    reactions = ne.split(double_pendulum(), THETA, THETAD, TAU).extras[which]
    assert reactions.shape == (2, 6)
    np.testing.assert_allclose(reactions[1], np.r_[f2, n2], rtol=0, atol=1e-12)
    np.testing.assert_allclose(reactions[0], np.r_[f1, n1], rtol=0, atol=1e-12)
    np.testing.assert_allclose(reactions[:, 5], tau, rtol=0, atol=1e-12)   # the axis component is the torque
    np.testing.assert_allclose(ne.joint_reactions(double_pendulum(), THETA, THETAD, qdd), reactions,
                               rtol=0, atol=1e-13)


def test_double_pendulum_gravity_compensation_and_spd_sweep():
    model = double_pendulum(m1=1.3, m2=0.7, l1=0.9, l2=1.4)
    for t1 in np.linspace(-np.pi, np.pi, 9):
        for t2 in np.linspace(-np.pi, np.pi, 9):
            t = np.array([t1, t2])
            M, _, g = pendulum_terms(t, np.zeros(2), m1=1.3, m2=0.7, l1=0.9, l2=1.4, g=G)
            assert np.abs(ne.split(model, t, np.zeros(2), g).total).max() < 1e-12
            Mne = ne.mass_matrix(model, t)
            np.testing.assert_array_equal(Mne, Mne.T)
            assert np.linalg.eigvalsh(Mne)[0] > 0
            np.testing.assert_allclose(Mne, M, rtol=0, atol=1e-14)


# ----------------------------------------------------------------------------------------------------------
# A 3-D tree: full inertia tensors, COM offsets, a prismatic joint, non-parallel axes, branching, a non-square B
# ----------------------------------------------------------------------------------------------------------

def skew(v):
    return np.array([[0.0, -v[2], v[1]], [v[2], 0.0, -v[0]], [-v[1], v[0], 0.0]])


def quat_rot(axis, angle):
    """Rotation by ``angle`` about unit ``axis`` via the unit quaternion (cos(angle/2), sin(angle/2) axis):
    the test's own rotation helper, analytic in ``angle`` so complex-step differentiation works through it."""
    w, (x, y, z) = np.cos(angle / 2), np.sin(angle / 2) * np.asarray(axis)
    return np.array([[1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y)],
                     [2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x)],
                     [2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)]])


def expm_rot(rotvec):
    """Rotation matrix exp([rotvec]x), for the fixed placements (independent of the quaternion helper)."""
    return scipy.linalg.expm(skew(np.asarray(rotvec, dtype=float)))


def inertia(principal, rotvec):
    Q = expm_rot(np.array(rotvec, dtype=float))
    return Q @ np.diag(principal) @ Q.T


def unit(v):
    v = np.array(v, dtype=float)
    return v / np.linalg.norm(v)


GRAVITY_3D = np.array([0.4, -1.1, -9.6])
B_3D = np.array([[1.0, 0.0, 0.3], [0.2, 1.0, 0.0], [0.0, -0.5, 1.0], [0.7, 0.0, 0.4]])


def _tree_model(input_map=B_3D):
    """Bodies listed out of topological order on purpose ('arm' before its parent 'slider')."""
    bodies = [
        Body("base", None, "revolute", axis=unit([1, 2, 2]), mass=2.0, com=(0.1, 0.05, -0.3),
             inertia=inertia([0.30, 0.40, 0.50], [0.3, -0.2, 0.5]),
             rotation=expm_rot([0.2, 0.1, -0.4]), translation=(0.1, -0.2, 0.3)),
        Body("arm", "slider", "revolute", axis=unit([0.8, 0.0, 0.6]), mass=1.0, com=(0.2, 0.1, 0.0),
             inertia=inertia([0.05, 0.07, 0.09], [-0.6, 0.2, 0.1]),
             rotation=expm_rot([-0.3, 0.5, 0.2]), translation=(0.0, 0.3, 0.1)),
        Body("slider", "base", "prismatic", axis=unit([0.0, 0.6, 0.8]), mass=1.5, com=(0.05, -0.1, 0.2),
             inertia=inertia([0.10, 0.12, 0.15], [0.4, 0.4, -0.1]),
             rotation=expm_rot([0.5, -0.2, 0.3]), translation=(0.2, 0.0, -0.4)),
        Body("side", "base", "revolute", axis=unit([0.3, 1.0, -0.2]), mass=0.7, com=(0.0, 0.1, -0.25),
             inertia=inertia([0.02, 0.03, 0.04], [0.1, 0.7, 0.0]),
             rotation=expm_rot([0.0, 0.3, 0.9]), translation=(-0.3, 0.1, 0.0)),
    ]
    return build_model("tree_3d", bodies, gravity=GRAVITY_3D, input_map=input_map)


TREE, TREE_IDENTITY_B = _tree_model(), _tree_model(input_map=None)


def homogeneous(R, p):
    T = np.eye(4, dtype=np.result_type(R, p))
    T[:3, :3], T[:3, 3] = R, p
    return T


def world_poses(model, q):
    """4x4 world transforms of every body by name: parent * placement * joint motion (real or complex q)."""
    by_name = {b.name: (i, b) for i, b in enumerate(model.bodies)}
    poses = {}

    def pose(name):
        if name not in poses:
            i, b = by_name[name]
            parent = np.eye(4) if b.parent is None else pose(b.parent)
            if b.joint == "revolute":
                motion = homogeneous(quat_rot(b.axis, q[i]), np.zeros(3))
            else:
                motion = homogeneous(np.eye(3), q[i] * b.axis)
            poses[name] = parent @ homogeneous(b.rotation, b.translation) @ motion
        return poses[name]

    return [pose(b.name) for b in model.bodies]


def body_motion(model, q, qd, h=1e-20):
    """Per body: world rotation R, body origin o, COM position p, COM velocity v and angular momentum about the
    COM L = (R I R^T) w (world), the velocities by complex-step differentiation of the poses along qd."""
    out = []
    for b, X, Xc in zip(model.bodies, world_poses(model, q), world_poses(model, q + 1j * h * qd)):
        R, Rdot = X[:3, :3], Xc[:3, :3].imag / h
        W = Rdot @ R.T
        w = np.array([W[2, 1], W[0, 2], W[1, 0]])
        v = (Xc @ np.r_[b.com, 1.0]).imag[:3] / h
        out.append((R, X[:3, 3], (X @ np.r_[b.com, 1.0])[:3], v, w, R @ b.inertia @ R.T @ w))
    return out


def kinetic_energy(model, q, qd):
    """T = sum 1/2 m |v_c|^2 + 1/2 w . (R I R^T) w."""
    return sum(0.5 * b.mass * v @ v + 0.5 * w @ L
               for b, (_, _, _, v, w, L) in zip(model.bodies, body_motion(model, q, qd)))


def potential_energy(model, q):
    """V = -sum m gravity . p_com (cases.model docstring), real or complex q."""
    poses = world_poses(model, q)
    return -sum(b.mass * (GRAVITY_3D @ (X @ np.r_[b.com, 1.0])[:3]) for b, X in zip(model.bodies, poses))


def d_stencil(f, h):
    """Fourth-order central difference of f at 0."""
    return (-f(2 * h) + 8 * f(h) - 8 * f(-h) + f(-2 * h)) / (12 * h)


def lagrange_residual(model, q, qd, qdd):
    """d/dt(dT/dqd) - dT/dq + dV/dq along q(t) = q + t qd + t^2/2 qdd.

    dT/dqd by central differences with step 1 (exact: T is quadratic in qd), d/dt and dT/dq by a
    fourth-order stencil with step 1e-3, dV/dq by complex step.
    """
    n = model.n
    E = np.eye(n)

    def momentum(qq, vv):
        return np.array([(kinetic_energy(model, qq, vv + e) - kinetic_energy(model, qq, vv - e)) / 2 for e in E])

    ddt = d_stencil(lambda t: momentum(q + t * qd + 0.5 * t * t * qdd, qd + t * qdd), 1e-3)
    dT_dq = np.array([d_stencil(lambda s: kinetic_energy(model, q + s * e, qd), 1e-3) for e in E])
    dV_dq = np.array([potential_energy(model, q + 1e-20j * e).imag / 1e-20 for e in E])
    return ddt - dT_dq + dV_dq


def kinetic_hessian(model, q):
    """d^2 T / dqd^2 by central second differences with step 1 (exact for a quadratic form)."""
    n, E = model.n, np.eye(model.n)
    T = lambda v: kinetic_energy(model, q, v)  # noqa: E731
    return np.array([[(T(E[j] + E[k]) - T(E[j] - E[k]) - T(-E[j] + E[k]) + T(-E[j] - E[k])) / 4
                      for k in range(n)] for j in range(n)])


Q3 = np.array([0.7, -0.4, 0.35, 1.1])
QD3 = np.array([1.8, -2.2, 0.9, 2.5])
QDD3 = np.array([-0.6, 1.3, 2.0, -0.9])


def test_3d_inverse_dynamics_equals_euler_lagrange_residual():
    model = TREE
    expected = lagrange_residual(model, Q3, QD3, QDD3)
    got = ne.inverse_dynamics(model, Q3, QD3, QDD3)
    np.testing.assert_allclose(got, expected, rtol=0, atol=1e-9 * max(1.0, np.abs(expected).max()))
    # velocity-product terms alone (no gravity, no acceleration) carry the gyroscopic and Coriolis terms
    expected_cqd = lagrange_residual(model, Q3, QD3, np.zeros(4)) - lagrange_residual(model, Q3, 0 * QD3, 0 * QDD3)
    got_cqd = ne.inverse_dynamics(model, Q3, QD3, np.zeros(4), gravity=False)
    np.testing.assert_allclose(got_cqd, expected_cqd, rtol=0, atol=1e-9 * max(1.0, np.abs(expected_cqd).max()))


def test_3d_mass_matrix_is_kinetic_energy_hessian():
    model = TREE
    for q in (Q3, np.array([-2.0, 0.5, -0.3, 2.9])):
        expected = kinetic_hessian(model, q)
        np.testing.assert_allclose(ne.mass_matrix(model, q), expected, rtol=0, atol=1e-12 * np.abs(expected).max())


def test_3d_forward_inverse_round_trip_and_reactions():
    model = TREE
    u = np.array([3.0, -1.5, 2.2])
    s = ne.split(model, Q3, QD3, u)
    np.testing.assert_allclose(ne.inverse_dynamics(model, Q3, QD3, s.total), B_3D @ u, rtol=0, atol=1e-12)
    np.testing.assert_allclose(ne.inverse_dynamics(model, Q3, QD3, s.drift), np.zeros(4), rtol=0, atol=1e-12)
    np.testing.assert_allclose(s.drift + s.ctrl, s.total, rtol=0, atol=1e-13 * s.accel_scale)
    axis_load = lambda R: np.array([b.axis @ (R[i, 3:] if b.joint == "revolute" else R[i, :3])  # noqa: E731
                                    for i, b in enumerate(model.bodies)])
    np.testing.assert_allclose(axis_load(s.extras["joint_reactions"]), B_3D @ u, rtol=0, atol=1e-12)
    np.testing.assert_allclose(axis_load(s.extras["joint_reactions_drift"]), np.zeros(4), rtol=0, atol=1e-12)
    assert s.power_ctrl == pytest.approx((B_3D @ u) @ QD3, rel=1e-14)


def test_3d_joint_reactions_equal_subtree_momentum_rates():
    """Newton and Euler for each whole subtree: the load through joint i equals the rate of change of the
    subtree's linear momentum minus its weight, and of its angular momentum about body i's origin minus the
    moment of its weight (world frame, by finite differences along the trajectory), rotated into body i."""
    model = TREE
    step = lambda t: body_motion(model, Q3 + t * QD3 + 0.5 * t * t * QDD3, QD3 + t * QDD3)  # noqa: E731
    acc = d_stencil(lambda t: np.array([v for (_, _, _, v, _, _) in step(t)]), 1e-3)
    Ldot = d_stencil(lambda t: np.array([L for (*_, L) in step(t)]), 1e-3)
    now = step(0.0)
    expected = []
    for i, b in enumerate(model.bodies):
        R, origin = now[i][0], now[i][1]
        f, n = np.zeros(3), np.zeros(3)
        for k, bk in enumerate(model.bodies):
            anc = bk.name
            while anc is not None and anc != b.name:
                anc = model.bodies[model.body_index(anc)].parent
            if anc is None:
                continue                                   # body k is not in body i's subtree
            load = bk.mass * (acc[k] - GRAVITY_3D)
            f += load
            n += np.cross(now[k][2] - origin, load) + Ldot[k]
        expected.append(np.r_[R.T @ f, R.T @ n])
    expected = np.array(expected)
    got = ne.joint_reactions(model, Q3, QD3, QDD3)
    np.testing.assert_allclose(got, expected, rtol=0, atol=1e-9 * np.abs(expected).max())


def test_ctrl_is_solved_directly_not_total_minus_drift():
    """Where the drift dwarfs the control, ``total - drift`` loses every digit of ctrl; M^-1 tau keeps them."""
    t, td, tau = np.array([0.3, 1.1]), np.array([3e4, -2e4]), np.array([1e-6, 2e-6])
    M, Cqd, g = pendulum_terms(t, td, g=G)
    s = ne.split(double_pendulum(), t, td, tau)
    np.testing.assert_allclose(s.ctrl, inv2(M) @ tau, rtol=1e-12, atol=0)
    np.testing.assert_array_equal(ne.split(double_pendulum(), t, td, np.zeros(2)).ctrl, np.zeros(2))


def test_3d_gravity_compensation_and_spd_sweep():
    model = TREE_IDENTITY_B
    rng = np.random.default_rng(7)
    for _ in range(20):
        q = rng.uniform(-np.pi, np.pi, 4)
        g = np.array([potential_energy(model, q + 1e-20j * e).imag / 1e-20 for e in np.eye(4)])
        assert np.abs(ne.split(model, q, np.zeros(4), g).total).max() < 1e-12
        M = ne.mass_matrix(model, q)
        np.testing.assert_array_equal(M, M.T)
        assert np.linalg.eigvalsh(M)[0] > 1e-6


BOUNDS = [np.pi, np.pi, 1.0, np.pi]


@settings(deadline=None, max_examples=40)
@given(st.lists(st.floats(-1.0, 1.0), min_size=15, max_size=15))
def test_round_trip_property(x):
    x = np.array(x)
    q, qd, u = x[:4] * BOUNDS, 3.0 * x[4:8], 10.0 * x[8:11]
    model = TREE
    s = ne.split(model, q, qd, u)
    M = ne.mass_matrix(model, q)
    tol = 1e-12 * np.linalg.norm(M, 2) * s.accel_scale
    np.testing.assert_allclose(ne.inverse_dynamics(model, q, qd, s.total), B_3D @ u, rtol=0, atol=tol)
    np.testing.assert_allclose(M @ s.ctrl, B_3D @ u, rtol=0, atol=tol)
    np.testing.assert_allclose(s.drift + s.ctrl, s.total, rtol=0, atol=1e-13 * s.accel_scale)


# ----------------------------------------------------------------------------------------------------------
# Contract: bad states, singular mass matrices, constraints, the registry entry
# ----------------------------------------------------------------------------------------------------------

def test_bad_state_is_rejected():
    with pytest.raises(StateError, match="needs 2"):
        ne.split(double_pendulum(), [0.0], [0.0, 0.0], [0.0, 0.0])
    with pytest.raises(StateError, match="non-finite"):
        ne.split(double_pendulum(), [0.0, np.nan], [0.0, 0.0], [0.0, 0.0])
    with pytest.raises(StateError, match="sizes"):
        ne.inverse_dynamics(double_pendulum(), [0.0, 0.0], [0.0, 0.0], [0.0])


def test_singular_mass_matrix_names_model_and_eigenvalues():
    """A point mass on its own revolute axis has no inertia about that axis: M = [[0]]."""
    model = build_model("mass_on_axis", [Body("p", None, "revolute", axis=(0.0, 0.0, 1.0), mass=1.0)])
    with pytest.raises(ValueError, match=r"mass_on_axis.*not positive definite.*eigenvalues \[0\.0\]"):
        ne.split(model, [0.3], [0.0], [1.0])


def test_unknown_constraint_declaration_is_rejected():
    """Constrained models are handled (tests/backends/test_constrained_newton_euler.py); a declaration that is none of
    ``cases.constraints`` is a TypeError naming the known ones."""
    model = dataclasses.replace(double_pendulum(), constraints=("placeholder",))
    with pytest.raises(TypeError, match="does not know the constraint declaration 'placeholder'.*PointOnCircle"):
        ne.split(model, THETA, THETAD, TAU)


def test_registry_entry():
    import formalisms

    assert formalisms.get("newton_euler") is ne.FORMALISM
    assert ne.FORMALISM.name == "newton_euler" and ne.FORMALISM.split is ne.split
    assert ne.FORMALISM.split_batch is ne.split_batch
