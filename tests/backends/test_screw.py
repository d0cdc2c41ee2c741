"""Tests of the screw / product-of-exponentials backend (article 6.2, eqs. 20, 21, 27).

References written independently here: closed-form SE(3) exponentials, finite differences of the poses along
trajectories, the double-pendulum closed forms (article eqs. 4 and 21 here, eqs. 5-8 from closed_forms.py), a direct
composition of the model's placements and joint motions (scipy's matrix exponential), the 50-digit reference
(``crosscheck.references.precise``) for the rounding of M and h, and, across formalisms, Newton–Euler's joint reactions and
conditioning.
"""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest
import scipy.linalg
from hypothesis import given
from hypothesis import strategies as st

import cases
import formalisms
from closed_forms import endpoint_jacobian, pendulum_terms
from scenes import panda_arm
from crosscheck import backends
from crosscheck.checks import frames
from crosscheck.references import precise
from crosscheck.reports import gate_summary
from crosscheck.engine.specs import CaseSpec
from crosscheck.engine.run import run_gate
from crosscheck.core.sampling import sample_states
from formalisms import newton_euler as ne
from formalisms import screw
from formalisms.interface import StateError
from formalisms.screw import dynamics, kinematics, lie

G = 9.81
SPATIAL_ARM, PANDA = cases.load("spatial_arm"), panda_arm()

finite = st.floats(-1.0, 1.0)
vec3 = st.tuples(finite, finite, finite).map(np.array)
vec6 = st.tuples(*[finite] * 6).map(np.array)
unit3 = vec3.filter(lambda v: np.linalg.norm(v) > 0.1).map(lambda v: v / np.linalg.norm(v))


def transform(R, p):
    T = np.eye(4)
    T[:3, :3], T[:3, 3] = R, p
    return T


def rot_z(angle):
    c, s = np.cos(angle), np.sin(angle)
    return np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])


def random_transform(rotvec, p):
    """An SE(3) element built with scipy's matrix exponential, independent of ``lie.exp3``."""
    return transform(scipy.linalg.expm(lie.hat3(3.0 * rotvec)), 2.0 * p)


transforms = st.builds(random_transform, vec3, vec3)


def d_dt(f, h):
    """Fourth-order central first difference of f at 0."""
    return (-f(2 * h) + 8 * f(h) - 8 * f(-h) + f(-2 * h)) / (12 * h)


def d2_dt2(f, h):
    """Fourth-order central second difference of f at 0."""
    return (-f(2 * h) + 16 * f(h) - 30 * f(0.0) + 16 * f(-h) - f(-2 * h)) / (12 * h * h)


def time_scale(qd, qdd=0.0):
    """The trajectory's time scale, about min(1/|qd|, 1/sqrt|qdd|): difference steps are fractions of it."""
    return 1.0 / (1.0 + np.abs(qd).max() + np.sqrt(np.abs(qdd).max()))


# ----------------------------------------------------------------------------------------------------------
# SE(3) helpers against closed forms
# ----------------------------------------------------------------------------------------------------------

@given(st.floats(-2 * np.pi, 2 * np.pi), st.floats(0.1, 3.0))
def test_exp6_of_rotation_about_z_through_a_point(theta, length):
    """The screw of a rotation about z through (l, 0, 0) is S = (0, 0, 1, 0, -l, 0) (v = -omega x point); its
    exponential rotates by theta about that line: [[Rz(theta), (l (1 - cos theta), -l sin theta, 0)], [0, 1]]."""
    S = np.array([0.0, 0.0, 1.0, 0.0, -length, 0.0])
    expected = transform(rot_z(theta), [length * (1 - np.cos(theta)), -length * np.sin(theta), 0.0])
    np.testing.assert_allclose(lie.exp6(S, theta), expected, rtol=0, atol=1e-14)


@given(unit3, st.floats(-3.0, 3.0))
def test_exp6_of_pure_translation(axis, theta):
    np.testing.assert_allclose(lie.exp6(np.r_[0.0, 0.0, 0.0, axis], theta), transform(np.eye(3), theta * axis),
                               rtol=0, atol=1e-15)


angles = st.one_of(st.floats(0.0, 1e-3), st.floats(1e-3, np.pi - 1e-3), st.floats(np.pi - 1e-3, np.pi),
                   st.sampled_from([0.0, 1e-12, 0.19999, 0.2, 0.20001, np.pi / 2, np.pi - 1e-9, np.pi]))


@given(unit3, angles, vec3)
def test_exp_log_round_trip_near_zero_and_pi(axis, angle, rho):
    """exp6(log6(T)) = T everywhere; log6(exp6(V)) = V while |omega| < pi (at pi the axis sign is free).
    The exponentials are checked against scipy's matrix exponential of the 4x4 twist matrix."""
    V = np.r_[angle * axis, rho]
    T = lie.exp6(V)
    np.testing.assert_allclose(T, scipy.linalg.expm(lie.hat6(V)), rtol=0, atol=1e-14)
    np.testing.assert_allclose(lie.exp3(V[:3]), T[:3, :3], rtol=0, atol=1e-15)
    np.testing.assert_allclose(lie.exp6(lie.log6(T)), T, rtol=0, atol=1e-13)
    np.testing.assert_allclose(lie.exp3(lie.log3(T[:3, :3])), T[:3, :3], rtol=0, atol=1e-14)
    if angle < np.pi - 1e-6:
        np.testing.assert_allclose(lie.log6(T), V, rtol=0, atol=1e-12 / (np.pi - angle))


@given(transforms, transforms)
def test_adjoint_is_a_homomorphism(T1, T2):
    np.testing.assert_allclose(lie.Ad(T1 @ T2), lie.Ad(T1) @ lie.Ad(T2), rtol=0, atol=1e-12)
    np.testing.assert_allclose(lie.Ad(lie.inv(T1)), np.linalg.inv(lie.Ad(T1)), rtol=0, atol=1e-12)
    np.testing.assert_allclose(lie.inv(T1), np.linalg.inv(T1), rtol=0, atol=1e-12)   # expm: R^T R = I to ~1e-14


@given(transforms, vec6)
def test_adjoint_is_conjugation(T, V):
    """[Ad_T V] = T [V] T^-1, and the hat/vee maps invert each other."""
    np.testing.assert_allclose(lie.hat6(lie.Ad(T) @ V), T @ lie.hat6(V) @ lie.inv(T), rtol=0, atol=1e-12)
    np.testing.assert_array_equal(lie.vee6(lie.hat6(V)), V)
    np.testing.assert_array_equal(lie.vee3(lie.hat3(V[:3])), V[:3])


@given(vec6, vec6, vec6)
def test_small_adjoint_is_the_derivative_of_Ad(X, V, F):  # noqa: N802
    """ad_X = d/dt Ad_{exp(t X)} at t = 0 (central differences), ad_V V = 0, and the matrix-free bracket and
    coadjoint agree with the matrix."""
    derivative = d_dt(lambda t: lie.Ad(lie.exp6(X, t)), 1e-3)
    np.testing.assert_allclose(lie.ad(X), derivative, rtol=0, atol=1e-11)
    np.testing.assert_allclose(lie.ad(V) @ V, np.zeros(6), rtol=0, atol=1e-15)
    np.testing.assert_allclose(lie.bracket(X, V), lie.ad(X) @ V, rtol=0, atol=1e-15)
    np.testing.assert_allclose(lie.coad(X, F), lie.ad(X).T @ F, rtol=0, atol=1e-15)
    np.testing.assert_allclose(lie.cross(X[:3], V[:3]), np.cross(X[:3], V[:3]), rtol=0, atol=1e-15)


@given(transforms, vec6, vec6)
def test_power_is_invariant_under_a_change_of_frame(T, V, F):
    """Article 7.4: twists map by Ad_T, wrenches by Ad_T^-T, and F . V does not change."""
    F_new = np.linalg.inv(lie.Ad(T)).T @ F
    np.testing.assert_allclose(F_new, lie.Ad(lie.inv(T)).T @ F, rtol=0, atol=1e-12)
    assert F_new @ (lie.Ad(T) @ V) == pytest.approx(F @ V, abs=1e-12)


# ----------------------------------------------------------------------------------------------------------
# Double pendulum (article section 3 and 6.2.4)
# ----------------------------------------------------------------------------------------------------------

pendulum_states = st.tuples(st.floats(-np.pi, np.pi), st.floats(-np.pi, np.pi), st.floats(-5, 5), st.floats(-5, 5))
lengths = st.tuples(st.floats(0.2, 2.0), st.floats(0.2, 2.0))
masses = st.tuples(st.floats(0.2, 3.0), st.floats(0.2, 3.0))


@given(lengths)
def test_double_pendulum_screw_axes_are_article_eq_21_in_a_rotated_space_frame(ls):
    """Eq. (21) puts the arm along +x at q = 0 (S_2 is a rotation about z through (l1, 0, 0)); our pendulum hangs
    along -y (article section 3: angles from hanging down), so joint 2 is at (0, -l1, 0) and S_2 = (0, 0, 1,
    -l1, 0, 0). The article's space frame is ours rotated so that our -y becomes its +x: coordinates map by
    g = Rot_z(+90 deg), which sends (0, -1, 0) to (1, 0, 0), and screws by Ad_g. Exact (g has entries 0, +-1)."""
    l1, l2 = ls
    sc = kinematics.screws(cases.load("double_pendulum", l1=l1, l2=l2))
    g = transform(np.array([[0.0, -1.0, 0.0], [1.0, 0.0, 0.0], [0.0, 0.0, 1.0]]), np.zeros(3))
    eq21 = np.array([[0.0, 0.0, 1.0, 0.0, 0.0, 0.0], [0.0, 0.0, 1.0, 0.0, -l1, 0.0]])
    np.testing.assert_array_equal((lie.Ad(g) @ sc.space_axes.T).T, eq21)
    np.testing.assert_array_equal(sc.space_axes[1], [0.0, 0.0, 1.0, -l1, 0.0, 0.0])


@given(lengths, pendulum_states)
def test_double_pendulum_space_jacobian_gives_article_eq_5(ls, state):
    """J_s = [S_1, Ad_{exp(S_1 theta_1)} S_2] (6.2.4); the tip velocity p_dot = v + w x p, planar rows, is eq. (5)
    times qd."""
    (l1, l2), (t1, t2, w1, w2) = ls, state
    model = cases.load("double_pendulum", l1=l1, l2=l2)
    kin = kinematics.forward_kinematics(model, np.array([t1, t2]))
    S = kin.screws.space_axes
    J_s = kinematics.space_jacobian(kin, 1)
    np.testing.assert_allclose(J_s, np.column_stack([S[0], lie.Ad(lie.exp6(S[0], t1)) @ S[1]]), rtol=0, atol=1e-15)
    V = J_s @ [w1, w2]
    p = (kin.poses[1] @ [0.0, -l2, 0.0, 1.0])[:3]
    p_dot = V[3:] + np.cross(V[:3], p)
    J5 = endpoint_jacobian((t1, t2), l1, l2)  # eq. (5)
    np.testing.assert_allclose(p_dot[:2], J5 @ [w1, w2], rtol=0, atol=1e-13)
    assert p_dot[2] == 0.0
    np.testing.assert_allclose(p, [l1 * np.sin(t1) + l2 * np.sin(t1 + t2),                      # eq. (4)
                                   -l1 * np.cos(t1) - l2 * np.cos(t1 + t2), 0.0], rtol=0, atol=1e-14)


@given(masses, lengths, pendulum_states)
def test_double_pendulum_inverse_dynamics_matches_eqs_6_to_8(ms, ls, state):
    (m1, m2), (l1, l2), (t1, t2, w1, w2) = ms, ls, state
    model = cases.load("double_pendulum", m1=m1, m2=m2, l1=l1, l2=l2)
    q, qd, zero = np.array([t1, t2]), np.array([w1, w2]), np.zeros(2)
    M, Cqd, g = pendulum_terms(q, qd, m1, m2, l1, l2, g=G)  # eqs. (6), (7), (8)
    scale = 1e-13 * (1 + np.abs(M).max() * (1 + qd @ qd) + np.abs(g).max())
    np.testing.assert_allclose(dynamics.mass_matrix(model, q), M, rtol=0, atol=scale)
    np.testing.assert_allclose(dynamics.inverse_dynamics(model, q, qd, zero, gravity=False), Cqd, rtol=0, atol=scale)
    np.testing.assert_allclose(dynamics.inverse_dynamics(model, q, zero, zero), g, rtol=0, atol=scale)
    qdd = np.array([0.3, -1.2])
    np.testing.assert_allclose(dynamics.inverse_dynamics(model, q, qd, qdd), M @ qdd + Cqd + g, rtol=0, atol=scale)


# ----------------------------------------------------------------------------------------------------------
# Kinematics on a 3-D tree with a prismatic joint: eq. (20), twists, bias, task acceleration
# ----------------------------------------------------------------------------------------------------------

def arm_states(model, speed=2.0):
    n = model.n
    bounds = np.array([np.pi if b.joint == "revolute" else 0.5 for b in model.bodies])
    return st.tuples(st.tuples(*[finite] * n), st.tuples(*[finite] * n)).map(
        lambda t: (bounds * np.array(t[0]), speed * np.array(t[1])))


def composed_poses(model, q):
    """World <- body transforms by direct composition, parent * placement * motion(q_i) (cases.model), with the
    motion from scipy's matrix exponential: independent of the product of exponentials."""
    poses = [None] * model.n
    for i in model.topological_order:
        b, p = model.bodies[i], model.parent_index[i]
        motion = transform(scipy.linalg.expm(lie.hat3(b.axis * q[i])), np.zeros(3)) if b.joint == "revolute" \
            else transform(np.eye(3), b.axis * q[i])
        poses[i] = (np.eye(4) if p < 0 else poses[p]) @ transform(b.rotation, b.translation) @ motion
    return np.array(poses)


def poses_at(model, q):
    return kinematics.forward_kinematics(model, q).poses


@given(arm_states(SPATIAL_ARM))
def test_product_of_exponentials_equals_composed_placements(state):
    """Eq. (20) on the tree, and S_i = Ad_{M_i} B_i with M_i the pose at q = 0."""
    q, _ = state
    model = SPATIAL_ARM
    np.testing.assert_allclose(poses_at(model, q), composed_poses(model, q), rtol=0, atol=1e-14)
    sc = kinematics.screws(model)
    np.testing.assert_allclose(sc.home, composed_poses(model, np.zeros(model.n)), rtol=0, atol=1e-15)
    for i, b in enumerate(model.bodies):
        B = np.r_[b.axis, 0, 0, 0] if b.joint == "revolute" else np.r_[0, 0, 0, b.axis]
        np.testing.assert_array_equal(sc.body_axes[i], B)
        np.testing.assert_allclose(sc.space_axes[i], lie.Ad(sc.home[i]) @ B, rtol=0, atol=1e-15)


@given(arm_states(SPATIAL_ARM))
def test_twists_are_derivatives_of_the_poses(state):
    """[V_b] = T^-1 Tdot and [V_s] = Tdot T^-1, Tdot by central differences along q + t qd; V_b = J_b qd."""
    q, qd = state
    model = SPATIAL_ARM
    s = screw.split(model, q, qd, np.zeros(model.m))
    T = s.extras["poses"]
    T_dot = d_dt(lambda t: poses_at(model, q + t * qd), 1e-3 * time_scale(qd))
    tol = 1e-10 * (1 + np.abs(qd).max())
    np.testing.assert_allclose(s.extras["twists_body"], lie.vee6(lie.inv(T) @ T_dot), rtol=0, atol=tol)
    np.testing.assert_allclose(s.extras["twists_space"], lie.vee6(T_dot @ lie.inv(T)), rtol=0, atol=tol)
    kin = kinematics.forward_kinematics(model, q)
    for i in range(model.n):       # the forward iteration over the placements is Ad_{T_i^-1} of the PoE Jacobian
        np.testing.assert_allclose(kinematics.body_jacobian(kin, i), kin.to_body[i] @ kinematics.space_jacobian(kin, i),
                                   rtol=0, atol=1e-14)


@given(arm_states(SPATIAL_ARM))
def test_bias_acceleration_is_the_derivative_of_the_jacobian(state):
    """Jdot_s qd = d/dt J_s(q + t qd) qd at t = 0 (central differences), for every body."""
    q, qd = state
    model = SPATIAL_ARM
    expected = d_dt(lambda t: kinematics.twists(kinematics.forward_kinematics(model, q + t * qd), qd),
                    1e-3 * time_scale(qd))
    got = kinematics.bias_accelerations(kinematics.forward_kinematics(model, q), qd)
    np.testing.assert_allclose(got, expected, rtol=0, atol=1e-9 * (1 + np.abs(expected).max()))


@given(arm_states(SPATIAL_ARM))
def test_body_motion_is_the_derivative_of_the_body_twists(state):
    """Lynch & Park's forward iterations: V = J_b qd and Ad_{T^-1} V_s; at qdd = 0, Vdot = Jdot_b qd = d/dt J_b(q +
    t qd) qd at t = 0 (central differences) and Ad_{T^-1} Jdot_s qd; and Vdot - Vdot(qdd = 0) = J_b qdd."""
    q, qd = state
    model = SPATIAL_ARM
    kin = kinematics.forward_kinematics(model, q)
    V, bias = kinematics.body_motion(kin, qd)
    np.testing.assert_allclose(V, kinematics.body_twists(kin, qd), rtol=0, atol=1e-14 * (1 + np.abs(V).max()))
    np.testing.assert_allclose(V, (kin.to_body @ kinematics.twists(kin, qd)[..., None])[..., 0], rtol=0,
                               atol=1e-14 * (1 + np.abs(V).max()))
    expected = d_dt(lambda t: kinematics.body_twists(kinematics.forward_kinematics(model, q + t * qd), qd),
                    1e-3 * time_scale(qd))
    np.testing.assert_allclose(bias, expected, rtol=0, atol=1e-9 * (1 + np.abs(expected).max()))
    space = (kin.to_body @ kinematics.bias_accelerations(kin, qd)[..., None])[..., 0]
    np.testing.assert_allclose(bias, space, rtol=0, atol=1e-13 * (1 + np.abs(space).max()))
    qdd = qd[::-1]
    _, Vdot = kinematics.body_motion(kin, qd, qdd)
    np.testing.assert_allclose(Vdot - bias, kinematics.body_twists(kin, qdd), rtol=0,
                               atol=1e-13 * (1 + np.abs(Vdot).max()))


@given(arm_states(SPATIAL_ARM))
def test_spatial_accelerations_and_task_drift_are_second_derivatives(state):
    """Along q(t) = q + t qd + t^2/2 qdd: accelerations_space (at qdd = total) is d/dt of the space twists, and
    task_drift (at qdd = drift) is D times the second derivative of the task point's world position."""
    q, qd = state
    model = SPATIAL_ARM
    u = np.linspace(-3.0, 3.0, model.m)
    s = screw.split(model, q, qd, u)

    def space_twists(t):
        return kinematics.twists(kinematics.forward_kinematics(model, q + t * qd + 0.5 * t * t * s.total),
                                 qd + t * s.total)

    expected = d_dt(space_twists, 1e-3 * time_scale(qd, s.total))
    np.testing.assert_allclose(s.extras["accelerations_space"], expected, rtol=0,
                               atol=1e-7 * (1 + np.abs(expected).max()))
    tp = model.task_point()
    i = model.body_index(tp.body)

    def task_point(t):
        return (poses_at(model, q + t * qd + 0.5 * t * t * s.drift)[i] @ np.r_[tp.offset, 1.0])[:3]

    expected = tp.directions @ d2_dt2(task_point, 1e-2 * time_scale(qd, s.drift))
    np.testing.assert_allclose(s.task_drift, expected, rtol=0, atol=1e-7 * (1 + np.abs(expected).max()))


# ----------------------------------------------------------------------------------------------------------
# Wrenches: against Newton–Euler, joint torques, and a change of world frame (article 7.4)
# ----------------------------------------------------------------------------------------------------------

@pytest.mark.parametrize("model", [SPATIAL_ARM, PANDA], ids=["spatial_arm", "panda"])
def test_wrenches_equal_newton_euler_joint_reactions(model):
    """Newton–Euler rows are [force, moment] about the same point (body origin) in the same frame (body i)."""
    rng = np.random.default_rng(3)
    for _ in range(5):
        q, qd, u = rng.uniform(-1, 1, model.n), rng.uniform(-3, 3, model.n), rng.uniform(-10, 10, model.m)
        s = screw.split(model, q, qd, u)
        for key, qdd in (("wrenches_body", s.total), ("wrenches_body_drift", s.drift)):
            reactions = ne.joint_reactions(model, q, qd, qdd)
            expected = np.hstack([reactions[:, 3:], reactions[:, :3]])
            np.testing.assert_allclose(s.extras[key], expected, rtol=0, atol=1e-11 * np.abs(expected).max())
        axis_load = np.einsum("ia,ia->i", kinematics.screws(model).body_axes, s.extras["wrenches_body"])
        np.testing.assert_allclose(axis_load, model.input_map @ u, rtol=0, atol=1e-10)
        axis_load_drift = np.einsum("ia,ia->i", kinematics.screws(model).body_axes, s.extras["wrenches_body_drift"])
        np.testing.assert_allclose(axis_load_drift, np.zeros(model.n), rtol=0, atol=1e-10)


def moved(model, g):
    """The same scene moved rigidly by g (world coordinates x -> g x): root placements and gravity move."""
    R, p = g[:3, :3], g[:3, 3]
    bodies = [dataclasses.replace(b, rotation=R @ b.rotation, translation=R @ b.translation + p)
              if b.parent is None else b for b in model.bodies]
    return cases.build_model(model.name + "_moved", bodies, gravity=R @ model.gravity, input_map=model.input_map,
                             task_points=model.task_points)


@given(transforms, arm_states(SPATIAL_ARM))
def test_a_change_of_world_frame_maps_twists_by_Ad_and_wrenches_by_Ad_inverse_transpose(g, state):  # noqa: N802
    """Article 7.4: poses -> g T, space twists and accelerations -> Ad_g, space wrenches -> Ad_g^-T; body
    quantities and joint accelerations do not change; power F_s . V_s = F_b . V_b."""
    q, qd = state
    u = np.linspace(-5.0, 5.0, SPATIAL_ARM.m)
    a, b = screw.split(SPATIAL_ARM, q, qd, u), screw.split(moved(SPATIAL_ARM, g), q, qd, u)
    Ad_g, coAd_g = lie.Ad(g), lie.Ad(lie.inv(g)).T
    scale = 1e-10 * (1 + max(np.abs(x).max() for x in a.extras.values()))
    np.testing.assert_allclose(b.extras["poses"], g @ a.extras["poses"], rtol=0, atol=scale)
    for key, X in (("twists_space", Ad_g), ("accelerations_space", Ad_g), ("wrenches_space", coAd_g)):
        np.testing.assert_allclose(b.extras[key], a.extras[key] @ X.T, rtol=0, atol=scale, err_msg=key)
    for key in ("twists_body", "wrenches_body", "wrenches_body_drift"):
        np.testing.assert_allclose(b.extras[key], a.extras[key], rtol=0, atol=scale, err_msg=key)
    np.testing.assert_allclose(b.total, a.total, rtol=0, atol=1e-12 * a.accel_scale)
    power_s = np.einsum("ia,ia->i", a.extras["wrenches_space"], a.extras["twists_space"])
    power_b = np.einsum("ia,ia->i", a.extras["wrenches_body"], a.extras["twists_body"])
    np.testing.assert_allclose(power_s, power_b, rtol=0, atol=scale)


# ----------------------------------------------------------------------------------------------------------
# The split, the contract, and a fault the gate must catch
# ----------------------------------------------------------------------------------------------------------

# ----------------------------------------------------------------------------------------------------------
# Rounding: M and h against the 50-digit reference; the conditioning against Newton–Euler's
# ----------------------------------------------------------------------------------------------------------

def scenes(name):
    """A 3-D case and the same scene moved rigidly (up to 1 m from the origin): world distances grow, levers do not."""
    model = cases.load(name)
    return [model, frames.move_scene(model, frames.sampled(0, name, 2)[1])]


@pytest.mark.parametrize("name", ["panda", "spatial_arm"])
def test_mass_matrix_and_bias_round_on_levers_not_on_world_distances(name):
    """M = sum_i J_b,i^T G_i J_b,i and eq. (27) in body frames, the body Jacobians by the forward iteration over the
    placements: no moment is taken about the world origin, so an entry of M rounds like eps m lever^2 and of h like
    eps lever |force|, in place and moved. Against the 50-digit reference, scaled by D = sqrt(diag M) (what the solve
    sees): |dM| / (D D^T) and |D^-1 dh| / max|D^-1 h| within 20 eps (measured: 7 eps; composite inertias about the
    world origin gave 180 to 550 eps for M, 30 to 50 eps for h)."""
    eps = np.finfo(float).eps
    for model in scenes(name):
        for state in sample_states(model, 6, 0, name):
            q, qd = np.array(state.q), np.array(state.qd)
            exact_M = np.array(precise.mass_matrix(model, q).tolist(), dtype=float)
            exact_h = np.array([float(x) for x in precise.bias_forces(model, q, qd)])
            d = np.sqrt(np.diag(exact_M))
            M, h, _, _ = dynamics.terms(kinematics.forward_kinematics(model, q), dynamics.Inertias.of(model), qd)
            assert np.max(np.abs(M - exact_M) / np.outer(d, d)) < 20 * eps, model.name
            assert np.max(np.abs(h - exact_h) / d) < 20 * eps * np.max(np.abs(exact_h) / d), model.name


@pytest.mark.parametrize("name", ["double_pendulum", "acrobot", "n_link_pendulum", "spatial_arm", "panda"])
def test_conditioning_agrees_with_newton_euler(name):
    """This backend's cond(M) and accel_scale (eigenvalues of M) and Newton–Euler's (singular values of its Cholesky
    factor), each from its own M, C qd and g: equal to rounding; the power u . B^T qd here, (B u) . qd there."""
    model = cases.load(name)
    for state in sample_states(model, 5, 0, name):
        a, b = (be.split(model, state.q, state.qd, state.u) for be in (screw, ne))
        assert a.cond_M == pytest.approx(b.cond_M, rel=1e-9)
        assert a.accel_scale == pytest.approx(b.accel_scale, rel=1e-9)
        assert a.power_ctrl == pytest.approx(b.power_ctrl, rel=1e-13, abs=1e-13 * np.abs(b.power_ctrl_per_coord).sum())
        np.testing.assert_array_equal(a.power_ctrl_per_coord, b.power_ctrl_per_coord)


@given(arm_states(PANDA, speed=5.0))
def test_split_round_trip_on_panda(state):
    q, qd = state
    u = np.linspace(-20.0, 20.0, PANDA.m)
    s = screw.split(PANDA, q, qd, u)
    M = dynamics.mass_matrix(PANDA, q)
    np.testing.assert_array_equal(M, M.T)
    tol = 1e-12 * np.linalg.norm(M, 2) * s.accel_scale
    np.testing.assert_allclose(dynamics.inverse_dynamics(PANDA, q, qd, s.total), PANDA.input_map @ u, atol=tol)
    np.testing.assert_allclose(dynamics.inverse_dynamics(PANDA, q, qd, s.drift), np.zeros(PANDA.n), atol=tol)
    np.testing.assert_allclose(M @ s.ctrl, PANDA.input_map @ u, rtol=0, atol=tol)
    assert s.lam is None and s.power_ctrl == pytest.approx((PANDA.input_map @ u) @ qd, rel=1e-13, abs=1e-300)


def test_bad_input_is_rejected_at_the_boundary():
    model = cases.load("double_pendulum")
    with pytest.raises(StateError, match="q has 1 entries but model 'double_pendulum' needs 2"):
        screw.split(model, [0.0], [0.0, 0.0], [0.0, 0.0])
    with pytest.raises(StateError, match="non-finite"):
        screw.split(model, [0.0, np.inf], [0.0, 0.0], [0.0, 0.0])
    with pytest.raises(StateError, match="sizes"):
        dynamics.inverse_dynamics(model, [0.0, 0.0], [0.0, 0.0], [0.0])
    with pytest.raises(TypeError, match="screw backend does not know the constraint declaration 'placeholder'"):
        screw.split(dataclasses.replace(model, constraints=("placeholder",)), [0.0, 0.0], [0.0, 0.0], [0.0, 0.0])


def test_singular_mass_matrix_names_model_and_eigenvalues():
    """A point mass on its own revolute axis has no inertia about that axis: M = [[0]]."""
    model = cases.build_model("mass_on_axis", [cases.Body("p", None, "revolute", axis=(0.0, 0.0, 1.0), mass=1.0)])
    with pytest.raises(ValueError, match=r"mass_on_axis.*not positive definite.*eigenvalues \[0\.0\]"):
        screw.split(model, [0.3], [0.0], [1.0])


def test_registry_entry():
    assert formalisms.get("screw") is screw.FORMALISM
    assert screw.FORMALISM.name == "screw" and screw.FORMALISM.split is screw.split


def test_wrench_mapped_like_a_twist_fails_the_gate_and_names_screw(monkeypatch):
    """The classic screw bug: carrying a child's wrench to its parent with the twist map Ad_{T_p,c} instead of
    Ad_{T_c,p}^T = Ad_{T_p,c}^-T. The gate must fail and the vote must single out the screw backend."""
    def as_twist(Ad_child_parent, F_child):  # noqa: N803
        Ad_parent_child = np.linalg.inv(Ad_child_parent)          # rows: Ad_{T_p,c} F = Ad_{T_c,p}^-1 F
        return (F_child[..., None, :] @ np.swapaxes(Ad_parent_child, -1, -2))[..., 0, :]

    monkeypatch.setattr(dynamics, "_wrench_to_parent", as_twist)
    chosen = [backends.get(name) for name in backends.names()]
    result = run_gate([CaseSpec("spatial_arm")], chosen, samples=5, seed=0)
    assert not result.passed
    outliers = {c.outlier for s in result.cases[0].states for c in s.comparisons.values()}
    assert "screw" in outliers
    assert "outlier **screw**" in gate_summary.render(result, "cmd")
