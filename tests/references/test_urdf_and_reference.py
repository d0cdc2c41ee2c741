"""The URDF loader and the Pinocchio reference.

* ``from_urdf`` against Pinocchio's own URDF model (same joints, order, gravity, dynamics), and on a tiny URDF
  whose merged inertia, placements and task point are worked out by hand here;
* the reference (for a model without a file source, a Pinocchio model built from OUR data) against the article's
  closed forms (eqs. 6-8) and against an energy-based mass matrix / gravity computed here from finite-differenced
  kinematics. The reference built from a URDF itself is tested in ``test_file_reference.py``.
"""

from __future__ import annotations

import textwrap

import numpy as np
import pinocchio as pin
import pytest

import cases
from cases import Body, ModelError, UrdfError, build_model, from_urdf
from crosscheck.references.pinocchio.reference import REFERENCE, split
from crosscheck.references.pinocchio.build import to_pinocchio
from closed_forms import inv2, pendulum_terms

PANDA_LINKS = [f"panda_link{i}" for i in range(1, 8)] + ["panda_leftfinger", "panda_rightfinger"]


def _sym(X):
    return np.triu(X) + np.triu(X, 1).T


def _close(a, b, rtol=1e-10):
    a, b = np.asarray(a), np.asarray(b)
    assert np.abs(a - b).max() <= rtol * max(1.0, np.abs(b).max()), (a, b)


# --------------------------------------------------------------------------------------------------- Panda


@pytest.fixture(scope="module")
def panda_path():
    from cases.factories import panda_urdf_path

    return str(panda_urdf_path())


def test_panda_structure_follows_pinocchio(panda_path):
    model = from_urdf(panda_path, name="panda")
    direct = pin.buildModelFromUrdf(panda_path)
    assert model.n == 9 == direct.nq == direct.nv
    assert [b.name for b in model.bodies] == PANDA_LINKS
    assert [b.parent for b in model.bodies] == [None] + PANDA_LINKS[:6] + ["panda_link7", "panda_link7"]
    assert [b.joint for b in model.bodies] == ["revolute"] * 7 + ["prismatic"] * 2
    np.testing.assert_array_equal(model.gravity, [0.0, 0.0, -9.81])
    np.testing.assert_array_equal(model.gravity, direct.gravity.linear)
    np.testing.assert_allclose(model.bodies[-1].axis, [0.0, -1.0, 0.0])  # finger 2 moves the other way
    for j in range(1, direct.njoints):
        b = model.bodies[j - 1]
        np.testing.assert_array_equal(b.rotation, direct.jointPlacements[j].rotation)
        np.testing.assert_array_equal(b.translation, direct.jointPlacements[j].translation)
        assert b.mass == direct.inertias[j].mass
    # panda_link0 is welded to the world and left out; the TCP leaf comes first, on link 7 (merged hand)
    assert [tp.name for tp in model.task_points] == ["panda_hand_tcp", "panda_leftfinger", "panda_rightfinger"]
    tcp = model.task_point()
    assert tcp.body == "panda_link7"
    np.testing.assert_allclose(tcp.offset, [0.0, 0.0, 0.107 + 0.1034], atol=1e-12)


def _compare_dynamics(ours: pin.Model, direct: pin.Model, to_direct_q, rng, n_states=5):
    d1, d2 = ours.createData(), direct.createData()
    for _ in range(n_states):
        q = rng.uniform(-1.5, 1.5, ours.nq)
        v = rng.uniform(-2.0, 2.0, ours.nv)
        tau = rng.uniform(-5.0, 5.0, ours.nv)
        a = rng.uniform(-3.0, 3.0, ours.nv)
        qd = to_direct_q(q)
        _close(pin.aba(ours, d1, q, v, tau), pin.aba(direct, d2, qd, v, tau))
        _close(pin.rnea(ours, d1, q, v, a), pin.rnea(direct, d2, qd, v, a))
        _close(_sym(pin.crba(ours, d1, q)), _sym(pin.crba(direct, d2, qd)))


def test_reference_from_converted_panda_matches_pinocchio_urdf(panda_path):
    ours = to_pinocchio(cases.load("panda"))
    direct = pin.buildModelFromUrdf(panda_path)
    _compare_dynamics(ours, direct, lambda q: q, np.random.default_rng(7))


def test_reference_split_on_panda_against_direct_pinocchio(panda_path):
    """The panda is constrained by its finger mimic (q8 = q7): against Pinocchio's own reduced mimic model
    (``mimic=True``: 8 coordinates, q = G q_r), total = G M_r^-1 (G^T u - h_r); cond_M is the full model's."""
    model = cases.load("panda")
    direct, full = pin.buildModelFromUrdf(panda_path, mimic=True), pin.buildModelFromUrdf(panda_path)
    data = direct.createData()
    rng = np.random.default_rng(3)
    G = np.vstack([np.eye(8), np.eye(8)[7]])
    q_r, qd_r, u = rng.uniform(-1, 1, 8), rng.uniform(-1, 1, 8), rng.uniform(-3, 3, 9)
    s = REFERENCE.split(model, G @ q_r, G @ qd_r, u)
    M = _sym(pin.crba(direct, data, q_r))
    h = pin.rnea(direct, data, q_r, qd_r, np.zeros(8))
    _close(s.drift, G @ np.linalg.solve(M, -h), 1e-8)
    _close(s.ctrl, G @ np.linalg.solve(M, G.T @ u), 1e-8)
    _close(s.total, G @ np.linalg.solve(M, G.T @ u - h), 1e-8)
    assert s.cond_M == pytest.approx(np.linalg.cond(_sym(pin.crba(full, full.createData(), G @ q_r))), rel=1e-8)


# ---------------------------------------------------------------------------------------------- tiny URDF

INERTIA_A = dict(ixx=0.010, ixy=0.001, ixz=-0.0005, iyy=0.020, iyz=0.0008, izz=0.025)
INERTIA_F = dict(ixx=0.001, ixy=0.0, ixz=0.0, iyy=0.002, iyz=0.0, izz=0.0025)
LIMIT = '<limit lower="-3" upper="3" effort="10" velocity="5"/>'


def _inertia_xml(d):
    return "<inertia " + " ".join(f'{k}="{v}"' for k, v in d.items()) + "/>"


def _tensor(d):
    return np.array([[d["ixx"], d["ixy"], d["ixz"]], [d["ixy"], d["iyy"], d["iyz"]], [d["ixz"], d["iyz"], d["izz"]]])


TINY = textwrap.dedent(f"""\
    <?xml version="1.0"?>
    <robot name="tiny">
      <link name="base">
        <inertial><origin xyz="0 0 0"/><mass value="3"/>{_inertia_xml(INERTIA_F)}</inertial>
      </link>
      <joint name="j_a" type="revolute">
        <parent link="base"/><child link="a"/>
        <origin xyz="0 0 0.1" rpy="0.1 0.2 0.3"/><axis xyz="0 0 1"/>{LIMIT}
      </joint>
      <link name="a">
        <inertial><origin xyz="0.1 0 0"/><mass value="1.5"/>{_inertia_xml(INERTIA_A)}</inertial>
      </link>
      <joint name="j_fix" type="fixed">
        <parent link="a"/><child link="a_fixed"/><origin xyz="0.3 0 0" rpy="0 0 0.5"/>
      </joint>
      <link name="a_fixed">
        <inertial><origin xyz="0.05 0.02 0"/><mass value="0.5"/>{_inertia_xml(INERTIA_F)}</inertial>
      </link>
      <joint name="j_b" type="continuous">
        <parent link="a_fixed"/><child link="b"/><origin xyz="0.1 0 0" rpy="0.3 0 0"/><axis xyz="1 0 0"/>
      </joint>
      <link name="b">
        <inertial><origin xyz="0 0.1 0.02"/><mass value="0.8"/>{_inertia_xml(INERTIA_A)}</inertial>
      </link>
      <joint name="j_c" type="prismatic">
        <parent link="b"/><child link="c"/>
        <origin xyz="0 0.2 0" rpy="0 0.4 0"/><axis xyz="0.6 0.8 0"/>{LIMIT}
      </joint>
      <link name="c">
        <inertial><origin xyz="0.02 0 0.03"/><mass value="0.4"/>{_inertia_xml(INERTIA_F)}</inertial>
      </link>
      <joint name="j_tool" type="fixed">
        <parent link="c"/><child link="tool"/><origin xyz="0.05 0 0.1"/>
      </joint>
      <link name="tool"/>
    </robot>
    """)


def _rx(a):
    c, s = np.cos(a), np.sin(a)
    return np.array([[1, 0, 0], [0, c, -s], [0, s, c]])


def _ry(a):
    c, s = np.cos(a), np.sin(a)
    return np.array([[c, 0, s], [0, 1, 0], [-s, 0, c]])


def _rz(a):
    c, s = np.cos(a), np.sin(a)
    return np.array([[c, -s, 0], [s, c, 0], [0, 0, 1]])


@pytest.fixture
def tiny_path(tmp_path):
    path = tmp_path / "tiny.urdf"
    path.write_text(TINY)
    return path


def test_tiny_urdf_conversion(tiny_path):
    model = from_urdf(tiny_path)
    assert model.name == "tiny"
    assert [b.name for b in model.bodies] == ["a", "b", "c"]
    assert [b.parent for b in model.bodies] == [None, "a", "b"]
    assert [b.joint for b in model.bodies] == ["revolute", "revolute", "prismatic"]
    a, b, c = model.bodies
    np.testing.assert_allclose(a.axis, [0, 0, 1])
    np.testing.assert_allclose(b.axis, [1, 0, 0])  # continuous -> revolute, one angle
    np.testing.assert_allclose(c.axis, [0.6, 0.8, 0.0], atol=1e-12)  # unaligned prismatic
    np.testing.assert_allclose(a.rotation, _rz(0.3) @ _ry(0.2) @ _rx(0.1), atol=1e-12)  # URDF rpy
    np.testing.assert_allclose(a.translation, [0, 0, 0.1], atol=1e-12)
    # b hangs from the merged link a_fixed: its placement is the fixed joint's composed with j_b's
    np.testing.assert_allclose(b.rotation, _rz(0.5) @ _rx(0.3), atol=1e-12)
    np.testing.assert_allclose(b.translation, [0.3, 0, 0] + _rz(0.5) @ [0.1, 0, 0], atol=1e-12)
    np.testing.assert_allclose(c.rotation, _ry(0.4), atol=1e-12)
    # merged inertia of a + a_fixed (fixed joint: masses add, COM averages, parallel-axis theorem)
    assert a.mass == pytest.approx(2.0, abs=1e-12)
    c1, m1, I1 = np.array([0.1, 0, 0]), 1.5, _tensor(INERTIA_A)
    R2, c2, m2 = _rz(0.5), np.array([0.3, 0, 0]) + _rz(0.5) @ [0.05, 0.02, 0], 0.5
    I2 = R2 @ _tensor(INERTIA_F) @ R2.T
    com = (m1 * c1 + m2 * c2) / (m1 + m2)
    np.testing.assert_allclose(a.com, com, atol=1e-12)

    def shift(m, d):
        return m * (d @ d * np.eye(3) - np.outer(d, d))

    np.testing.assert_allclose(a.inertia, I1 + shift(m1, c1 - com) + I2 + shift(m2, c2 - com), atol=1e-12)
    assert b.mass == pytest.approx(0.8) and c.mass == pytest.approx(0.4)
    np.testing.assert_allclose(b.com, [0, 0.1, 0.02], atol=1e-12)
    # the one leaf link, 'tool', is welded to c
    assert [(tp.name, tp.body) for tp in model.task_points] == [("tool", "c")]
    np.testing.assert_allclose(model.task_point().offset, [0.05, 0, 0.1], atol=1e-12)
    np.testing.assert_allclose(model.gravity, [0, 0, -9.81])


def test_tiny_urdf_dynamics_match_pinocchio_with_continuous_joint_chart(tiny_path):
    ours = to_pinocchio(from_urdf(tiny_path))
    direct = pin.buildModelFromUrdf(str(tiny_path))
    assert ours.nq == 3 and direct.nq == 4 and direct.nv == 3  # continuous: (cos, sin) in Pinocchio's q

    def to_direct_q(q):
        return np.array([q[0], np.cos(q[1]), np.sin(q[1]), q[2]])

    _compare_dynamics(ours, direct, to_direct_q, np.random.default_rng(11))


def test_unsupported_joint_type_is_named(tmp_path):
    urdf = TINY.replace('<joint name="j_b" type="continuous">', '<joint name="j_b" type="planar">')
    path = tmp_path / "bad.urdf"
    path.write_text(urdf)
    with pytest.raises(ModelError) as info:
        from_urdf(path)
    msg = str(info.value)
    assert "j_b" in msg and "Planar" in msg and str(path) in msg


def test_a_floating_joint_loads_as_a_free_joint(tmp_path):
    """A URDF ``floating`` joint is Pinocchio's FreeFlyer: our ``free`` joint (nq 7, nv 6), same state layout."""
    urdf = TINY.replace('<joint name="j_b" type="continuous">', '<joint name="j_b" type="floating">')
    path = tmp_path / "floating.urdf"
    path.write_text(urdf)
    model = from_urdf(path, base="fixed")
    direct = pin.buildModelFromUrdf(str(path))
    assert [b.joint for b in model.bodies].count("free") == 1
    assert (model.nq, model.nv) == (direct.nq, direct.nv) == (9, 8)


def test_missing_and_unparsable_files_name_the_path(tmp_path):
    missing = tmp_path / "nope.urdf"
    with pytest.raises(FileNotFoundError, match="nope.urdf"):
        from_urdf(missing)
    garbage = tmp_path / "garbage.urdf"
    garbage.write_text("<robot name='x'><link name='a'></robot")
    with pytest.raises(UrdfError) as info:
        from_urdf(garbage)
    assert str(garbage) in str(info.value)


# ------------------------------------------------------------------------------- reference vs closed forms


def test_reference_split_matches_article_4_7_3():
    q, qd, tau = np.array([np.pi / 4, np.pi / 6]), np.array([2.0, -1.0]), np.array([5.0, -2.0])
    M, Cqd, grav = pendulum_terms(q, qd)
    Minv = inv2(M)
    s = split(cases.load("double_pendulum"), q, qd, tau)
    _close(s.drift, -Minv @ (Cqd + grav), 1e-12)
    _close(s.ctrl, Minv @ tau, 1e-12)
    _close(s.total, Minv @ (tau - Cqd - grav), 1e-12)
    _close(s.drift + s.ctrl, s.total, 1e-12)
    assert s.power_ctrl == pytest.approx(5.0 * 2.0 + (-2.0) * (-1.0), rel=1e-14)
    np.testing.assert_allclose(s.power_ctrl_per_coord, [10.0, 2.0])
    assert s.lam is None and s.power_constr is None
    assert s.cond_M == pytest.approx(np.linalg.cond(M), rel=1e-10)
    # accel_scale = ||M^-1|| H, H = |C qd|_1 + |g|_1 + |tau|_1 + ||M|| |qd|^2 + |gravity|_1 sqrt(m_total ||M||)
    w = np.linalg.eigvalsh(M)
    H = np.abs(Cqd).sum() + np.abs(grav).sum() + np.abs(tau).sum() + w[-1] * qd @ qd + 9.81 * np.sqrt(2.0 * w[-1])
    assert s.accel_scale == pytest.approx(H / w[0], rel=1e-10)


def test_reference_with_other_parameters_and_random_states():
    p = dict(m1=1.3, m2=0.7, l1=0.9, l2=1.4, g=9.7)
    model = cases.load("double_pendulum", **p)
    rng = np.random.default_rng(5)
    for _ in range(10):
        q, qd, tau = rng.uniform(-3, 3, 2), rng.uniform(-3, 3, 2), rng.uniform(-5, 5, 2)
        M, Cqd, grav = pendulum_terms(q, qd, **p)
        s = REFERENCE.split(model, q, qd, tau)
        _close(s.drift, np.linalg.solve(M, -(Cqd + grav)), 1e-11)
        _close(s.ctrl, np.linalg.solve(M, tau), 1e-11)


def test_reference_respects_our_coordinate_order_when_bodies_are_listed_child_first():
    """Pinocchio needs parents first; the reference must permute in and out, not reorder our coordinates."""
    z = (0.0, 0.0, 1.0)
    reordered = build_model("dp_reversed", [
        Body("link2", "link1", "revolute", z, 1.0, com=(0, -1.0, 0), translation=(0, -1.0, 0)),
        Body("link1", None, "revolute", z, 1.0, com=(0, -1.0, 0)),
    ], gravity=(0, -9.81, 0))
    q, qd, tau = np.array([np.pi / 6, np.pi / 4]), np.array([-1.0, 2.0]), np.array([-2.0, 5.0])  # (theta2, theta1)
    M, Cqd, grav = pendulum_terms(q[::-1], qd[::-1])
    s = split(reordered, q, qd, tau)
    _close(s.drift, (-inv2(M) @ (Cqd + grav))[::-1], 1e-12)
    _close(s.ctrl, (inv2(M) @ tau[::-1])[::-1], 1e-12)


def test_reference_on_a_branched_tree_whose_parents_first_order_is_not_depth_first():
    """b0 carries b1 and b2, b1 carries b3: listed parents first, b3 follows its uncle b2. Pinocchio's subtree
    algorithms (computeMinverse) need each subtree contiguous; this order once gave a wrong M^-1 (ctrl off by O(1))."""
    z, x = (0.0, 0.0, 1.0), (1.0, 0.0, 0.0)
    tree = build_model("branched", [
        Body("b0", None, "revolute", z, 2.0, com=(0.3, 0, 0), inertia=np.diag([0.01, 0.02, 0.02])),
        Body("b1", "b0", "revolute", x, 1.0, com=(0, 0.2, 0), translation=(0.5, 0, 0),
             inertia=np.diag([0.02, 0.01, 0.02])),
        Body("b2", "b0", "prismatic", z, 0.5, com=(0.1, 0, 0), translation=(-0.4, 0.1, 0)),
        Body("b3", "b1", "revolute", z, 0.7, com=(0.2, 0, 0.1), translation=(0, 0.4, 0),
             inertia=np.diag([0.01, 0.01, 0.005])),
    ], gravity=(0, -9.81, 0))
    rng = np.random.default_rng(3)
    for _ in range(5):
        q, qd, u = rng.uniform(-1, 1, 4), rng.uniform(-2, 2, 4), rng.uniform(-5, 5, 4)
        s = split(tree, q, qd, u)
        M = s.extras["M"]
        np.testing.assert_allclose(M, M.T, atol=0)
        _close(s.ctrl, np.linalg.solve(M, u), 1e-10)
        _close(s.drift, -np.linalg.solve(M, s.extras["Cqd"] + s.extras["g"]), 1e-10)


def test_reference_ctrl_is_backward_stable_on_a_single_rotor():
    """A rotor of Izz = 1/640 driven by u = 1 accelerates at exactly 640 rad/s^2; computeMinverse once gave
    640.0000000000364 (256 eps, a fuzz finding), beyond the ctrl tolerance of a perfectly conditioned M."""
    rotor = build_model("rotor", [Body("r", None, "revolute", (0, 0, 1), 1.0, inertia=np.diag([0.1, 0.1, 1 / 640]),
                                       translation=(0, 1, 0))], gravity=(0, 0, -9.81))
    s = split(rotor, np.zeros(1), np.zeros(1), np.ones(1))
    assert abs(s.ctrl[0] - 640.0) <= 4 * np.finfo(float).eps * 640.0


def test_reference_is_pure():
    dp, arm = cases.load("double_pendulum"), cases.load("spatial_arm")
    args_dp = (np.array([0.3, -0.2]), np.array([1.0, 0.5]), np.array([0.1, 0.2]))
    args_arm = (np.linspace(-1, 1, 6), np.linspace(1, -1, 6), np.linspace(0, 2, 6))
    first = split(dp, *args_dp)
    split(arm, *args_arm)
    split(dp, np.array([2.0, 1.0]), np.array([-3.0, 4.0]), np.array([9.0, 9.0]))
    again = split(dp, *args_dp)
    for name in ("drift", "ctrl", "total"):
        np.testing.assert_array_equal(getattr(first, name), getattr(again, name))
    assert to_pinocchio(dp) is to_pinocchio(cases.load("double_pendulum"))  # cached by digest


def test_reference_acrobot_uses_the_input_map():
    model = cases.load("acrobot")
    q, qd, u = np.array([0.5, -0.3]), np.array([0.2, 1.0]), np.array([3.0])
    s = split(model, q, qd, u)
    M = s.extras["M"]
    _close(s.ctrl, np.linalg.solve(M, [0.0, 3.0]), 1e-12)
    assert s.power_ctrl == pytest.approx(3.0 * 1.0)
    np.testing.assert_allclose(s.power_ctrl_per_coord, [0.0, 3.0])
    # acrobot mass matrix (Spong): d11 = m1 lc1^2 + m2 (l1^2 + lc2^2 + 2 l1 lc2 cos q2) + I1 + I2, etc.
    m1, m2, l1, lc1, lc2, I1, I2 = 1.0, 1.0, 1.0, 0.5, 1.0, 0.083, 0.33
    c2 = np.cos(q[1])
    d11 = m1 * lc1**2 + m2 * (l1**2 + lc2**2 + 2 * l1 * lc2 * c2) + I1 + I2
    d12 = m2 * (lc2**2 + l1 * lc2 * c2) + I2
    d22 = m2 * lc2**2 + I2
    _close(M, [[d11, d12], [d12, d22]], 1e-12)


# ------------------------------------------------- reference on the 3-D arm vs energy (finite differences)


def _rodrigues(axis, angle):
    k = np.asarray(axis, float)
    K = np.array([[0, -k[2], k[1]], [k[2], 0, -k[0]], [-k[1], k[0], 0]])
    return np.eye(3) + np.sin(angle) * K + (1 - np.cos(angle)) * K @ K


def _poses(model, q):
    poses = {}
    for i, b in enumerate(model.bodies):  # spatial_arm lists parents first
        Rp, pp = (np.eye(3), np.zeros(3)) if b.parent is None else poses[b.parent]
        Rj, pj = Rp @ b.rotation, pp + Rp @ b.translation
        if b.joint == "revolute":
            poses[b.name] = (Rj @ _rodrigues(b.axis, q[i]), pj)
        else:
            poses[b.name] = (Rj, pj + Rj @ (q[i] * np.asarray(b.axis)))
    return poses


def test_reference_mass_matrix_and_gravity_on_spatial_arm_from_energy():
    """M = sum m Jv^T Jv + Jw^T R I R^T Jw and g = dV/dq, with Jacobians by central differences of our FK."""
    model = cases.load("spatial_arm")
    n, h = model.n, 1e-6
    q = np.array([0.4, -0.8, 0.5, 0.07, 1.1, -0.6])
    base = _poses(model, q)
    M = np.zeros((n, n))
    Jv = {b.name: np.zeros((3, n)) for b in model.bodies}
    Jw = {b.name: np.zeros((3, n)) for b in model.bodies}
    grav = np.zeros(n)

    def potential(qq):
        P = _poses(model, qq)
        return -sum(b.mass * model.gravity @ (P[b.name][1] + P[b.name][0] @ b.com) for b in model.bodies)

    for k in range(n):
        e = np.zeros(n)
        e[k] = h
        Pp, Pm = _poses(model, q + e), _poses(model, q - e)
        for b in model.bodies:
            (Rp, pp), (Rm, pm) = Pp[b.name], Pm[b.name]
            Jv[b.name][:, k] = ((pp + Rp @ b.com) - (pm + Rm @ b.com)) / (2 * h)
            W = (Rp - Rm) / (2 * h) @ base[b.name][0].T  # dR/dq_k R^T = skew(omega_k)
            Jw[b.name][:, k] = [W[2, 1], W[0, 2], W[1, 0]]
        grav[k] = (potential(q + e) - potential(q - e)) / (2 * h)
    for b in model.bodies:
        R = base[b.name][0]
        M += b.mass * Jv[b.name].T @ Jv[b.name] + Jw[b.name].T @ R @ b.inertia @ R.T @ Jw[b.name]
    s = split(model, q, np.zeros(n), np.zeros(n))
    _close(s.extras["M"], M, 1e-7)
    _close(s.extras["g"], grav, 1e-7)
    _close(s.drift, -np.linalg.solve(M, grav), 1e-6)


def test_massless_moving_link_is_reported_with_the_file(tmp_path):
    urdf = TINY.replace('<mass value="0.8"/>', '<mass value="0"/>')
    path = tmp_path / "massless.urdf"
    path.write_text(urdf)
    found = from_urdf(path).findings                     # physically impossible, M still regular: a finding
    assert len(found) == 1 and "body 'b'" in found[0] and "zero mass but a non-zero inertia" in found[0]
