"""The operational-space backend (article 6.3) on spherical and free joints (article 2.1-2.2, 6.2, 6.4; conventions of
``cases.model``, Pinocchio's: unit quaternions ``(x, y, z, w)``, body-frame velocities, accelerations ``d/dt v``).

References written independently of the backend:

* the Pinocchio reference (``crosscheck.references.pinocchio.reference.split``, ``JointModelSpherical`` / ``JointModelFreeFlyer``) on every
  field the backend reports, each within ``REL`` of a scale of that field (:func:`field_errors`), on the four group
  cases at sampled states, on hand-built constrained group models (a free base with a coupled arm whose gripper runs
  on a line; a ball-jointed limb with its hand pinned) and on Hypothesis-drawn trees with spherical and free joints
  (maybe constrained), besides the gate's own comparison (``crosscheck.testing.assert_backends_agree``);
* Euler's equations ``I wdot + w x I w = 0`` and the unaccelerated centre of mass of the torque-free ``free_body``
  (the drift at zero gravity), and the body-frame Newton–Euler equations of one rigid body for its total under an
  input wrench and gravity, written out here;
* world positions from 4x4 transforms with scipy's quaternions and rotation vectors, and finite differences along the
  group curves ``X(t) = X exp(t v^)`` (scipy's ``expm``), on which the body velocities are constant: ``J v`` is the
  first and the classical ``Jdot v`` the second derivative of a point's position.
"""

from __future__ import annotations

import functools

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from scipy.linalg import expm
from scipy.spatial.transform import Rotation

import cases
from cases import JointCoupling, PointOnLine, PointsCoincide, TaskPoint, build_model
from crosscheck.references.pinocchio import reference
from crosscheck.core import sampling
from crosscheck import testing
from crosscheck.core import tolerance as policy
from formalisms import operational_space as op
from formalisms.interface import Unsupported

CASES = ("free_body", "ball_pendulum", "ball_double_pendulum", "satellite_arm")
#: Largest allowed error of a field, relative to its scale (:func:`field_errors`).
REL = 1e-9
BACKENDS = ["operational_space", "pinocchio"]


# ----------------------------------------------------------------------------------------------------------
# Models
# ----------------------------------------------------------------------------------------------------------

def rebuilt(model, name, **changes):
    """``model`` built again with some of its arguments changed (task points, constraints)."""
    args = dict(bodies=model.bodies, gravity=model.gravity, input_map=model.input_map,
                task_points=model.task_points, constraints=model.constraints)
    return build_model(name, **{**args, **changes})


@functools.lru_cache(maxsize=None)
def model_of(name):
    """The registered cases, and variants: ``ball_pendulum_xy``, the ball pendulum tracking its bob along world x and y
    (as the registered case does); ``ball_pendulum_xyz``, tracking it in three directions, singular everywhere (the
    bob cannot move along its radius);
    ``satellite_on_rail``, the satellite arm with its shoulder and elbow geared 2:1 and its gripper on a line (a
    coupling of one-number joints after a free base: q and v indices differ); ``limb_pinned``, the ball-jointed limb
    with its hand pinned to a world point (3 rows; 3 degrees of freedom left)."""
    if name in ("ball_pendulum_xy", "ball_pendulum_xyz"):
        base = cases.load("ball_pendulum")
        tp = base.task_point()
        rows = np.eye(3)[:2] if name == "ball_pendulum_xy" else np.eye(3)
        return rebuilt(base, name, task_points=[TaskPoint(tp.name, tp.body, tp.offset, rows)])
    if name == "satellite_on_rail":
        base = cases.load("satellite_arm")
        rail = PointOnLine("rail", "extension", (0.25, 0.0, 0.0), origin=(1.0, 0.2, 0.3),
                           normals=np.array([[0.0, 1.0, 0.0], [0.0, 0.0, 1.0]]))
        gear = JointCoupling("gear", ("shoulder", "elbow"), (1.0, -2.0), 0.1)
        return rebuilt(base, name, constraints=[rail, gear])
    if name == "limb_pinned":
        base = cases.load("ball_double_pendulum")
        pin = PointsCoincide("pin", "lower", (0.0, 0.0, -0.5), None, (0.3, 0.2, -0.8))
        return rebuilt(base, name, constraints=[pin])
    return cases.load(name)


def sampled(name, count=6, seed=17):
    return [tuple(np.array(x) for x in (s.q, s.qd, s.u)) for s in sampling.sample_states(model_of(name), count, seed,
                                                                                          name)]


# ----------------------------------------------------------------------------------------------------------
# Field-by-field comparison with the reference
# ----------------------------------------------------------------------------------------------------------

def _err(a, b, scale):
    a, b = np.asarray(a, dtype=float), np.asarray(b, dtype=float)
    assert a.shape == b.shape, (a.shape, b.shape)
    return float(np.max(np.abs(a - b), initial=0.0)) / max(float(scale), 1e-300)


def field_errors(model, ours, ref, q, qd, u):
    """Error / scale of every field of ``ours`` against the reference's ``ref`` (each must be at most ``REL``).

    Scales: accelerations ``accel_scale`` (the reference's: ``||M^-1||`` times the forces summed); the task drift
    ``L (accel_scale + |qd|_1^2)``; M its size; ``C qd`` and g the generalized forces of ``accel_scale``, ``|C qd|_1 +
    |g|_1 + ||M|| |qd|_1^2 + |gravity|_1 sqrt(m_total ||M||)`` (the terms that cancel included); powers the sums of
    the magnitudes of their products; the kinetic energy itself; the condition numbers and ``accel_scale``
    themselves (times ``1 + 1e-7 cond``: an eigenvalue solver's smallest eigenvalue is accurate to ``eps cond``); the
    task inertia its size times ``1 + 1e-7 cond(A)``; the constraint rows the model's length scale L; the multipliers
    ``lam_scale`` and the constraint forces ``||Jc|| lam_scale``. A BREAKDOWN of the operational-space task (cond A
    above the gate's limit) leaves out what goes through task space (NaN there); one of the constraint space the
    multipliers and ``lam_scale``, which are then not unique."""
    L, a_scale = model.length_scale, ref.accel_scale
    task_broken = not (ours.conditions["task"] <= policy.BREAKDOWN_LIMITS["task"]
                       and ours.conditions["task_jacobian"] <= policy.BREAKDOWN_LIMITS["task_jacobian"])
    cond_M = ref.cond_M
    cond_factor = 1.0 + 1e-7 * cond_M
    M, Cqd, g = op.joint_space_terms(model, q, qd)
    M_norm, m_total = np.linalg.norm(ref.extras["M"], 2), sum(b.mass for b in model.bodies)
    forces = (np.abs(ref.extras["Cqd"]).sum() + np.abs(ref.extras["g"]).sum() + M_norm * np.abs(qd).sum() ** 2
              + np.abs(model.gravity).sum() * np.sqrt(m_total * M_norm) + 1e-300)
    tau = model.input_map @ u
    errors = {
        "M": _err(M, ref.extras["M"], np.abs(ref.extras["M"]).max()),
        "Cqd": _err(Cqd, ref.extras["Cqd"], forces),
        "g": _err(g, ref.extras["g"], forces),
        "power_ctrl": _err(ours.power_ctrl, ref.power_ctrl, np.abs(tau) @ np.abs(qd) + 1e-300),
        "power_ctrl_per_coord": _err(ours.power_ctrl_per_coord, ref.power_ctrl_per_coord,
                                     np.abs(tau) @ np.abs(qd) + 1e-300),
        "cond_M": _err(ours.cond_M, cond_M, cond_M * cond_factor),
        "accel_scale": _err(ours.accel_scale, a_scale, a_scale * cond_factor),
        "kinetic_energy": _err(ours.kinetic_energy, ref.kinetic_energy, ref.kinetic_energy + 1e-300),
    }
    if not task_broken:
        for name in ("drift", "ctrl", "total"):
            errors[name] = _err(getattr(ours, name), getattr(ref, name), a_scale)
        errors["task_drift"] = _err(ours.task_drift, ref.task_drift, L * (a_scale + np.abs(qd).sum() ** 2))
    cond_A = ref.conditions["task_inertia"]
    if cond_A <= policy.BREAKDOWN_LIMITS["task_inertia"] and not task_broken:
        Lambda = ref.task_inertia
        errors["task_inertia"] = _err(ours.task_inertia, Lambda, np.abs(Lambda).max() * (1.0 + 1e-7 * cond_A))
        errors["conditions: task"] = _err(ours.conditions["task"], cond_A, cond_A * (1.0 + 1e-7 * cond_A))
    if model.constraints:
        lam_scale = ref.lam_scale
        jc_norm = np.linalg.norm(ref.constraint_jacobian, 2)
        force_scale = jc_norm * lam_scale + 1e-300
        constraint_broken = not ours.conditions["constraint"] <= policy.BREAKDOWN_LIMITS["constraint"]
        rows = (1.0 + L) ** 2
        errors.update({
            "constraint_value": _err(ours.constraint_value, ref.constraint_value, rows),
            "constraint_jacobian": _err(ours.constraint_jacobian, ref.constraint_jacobian, rows),
            "constraint_bias": _err(ours.constraint_bias, ref.constraint_bias, rows * (1.0 + np.abs(qd).sum() ** 2)),
            "constraint_velocity": _err(ours.constraint_velocity, ref.constraint_velocity,
                                        rows * (1.0 + np.abs(qd).sum())),
            "constraint_rank": float(ours.constraint_rank != ref.constraint_rank),
            "conditions: constraint_consistency": _err(ours.conditions["constraint_consistency"],
                                                       ref.conditions["constraint_consistency"], 1.0),
        })
        for name in ("constraint", "constraint_kept"):
            c, limit = ref.conditions[name], policy.BREAKDOWN_LIMITS[name]
            if c <= limit:
                errors[f"conditions: {name}"] = _err(ours.conditions[name], c, c * (1.0 + 1e-7 * c))
            else:                                         # both past the limit (their tiny eigenvalues are rounding)
                errors[f"conditions: {name}"] = 0.0 if ours.conditions[name] > limit else 1.0
        if not task_broken:
            errors.update({
                "constraint_force": _err(ours.constraint_force, ref.constraint_force, force_scale),
                "constraint_force_drift": _err(ours.constraint_force_drift, ref.constraint_force_drift, force_scale),
                "power_constr": _err(ours.power_constr, ref.power_constr, force_scale * np.abs(qd).sum()),
                "power_constr_per_coord": _err(ours.power_constr_per_coord, ref.power_constr_per_coord,
                                               force_scale * np.abs(qd).sum()),
            })
            if not constraint_broken:
                errors.update({
                    "lam": _err(ours.lam, ref.lam, lam_scale),
                    "lam_drift": _err(ours.lam_drift, ref.lam_drift, lam_scale),
                    "lam_scale": _err(ours.lam_scale, lam_scale,
                                      lam_scale * (1.0 + 1e-7 * ref.conditions["constraint"])),
                })
    return errors


def assert_fields_agree(model, q, qd, u):
    ours, ref = op.split(model, q, qd, u), reference.split(model, q, qd, u)
    errors = field_errors(model, ours, ref, q, qd, u)
    bad = {name: e for name, e in errors.items() if not e <= REL}
    assert not bad, f"{model.name} at q = {q.tolist()}, qd = {qd.tolist()}, u = {u.tolist()}: error/scale {bad}"
    assert isinstance(ours.joint_wrenches, Unsupported) and isinstance(ours.joint_wrenches_drift, Unsupported)
    return ours, ref, errors


# ----------------------------------------------------------------------------------------------------------
# The group cases and constrained group models against Pinocchio
# ----------------------------------------------------------------------------------------------------------

@pytest.mark.parametrize("name", ["free_body", "ball_pendulum_xy", "ball_double_pendulum", "satellite_arm",
                                  "satellite_on_rail", "limb_pinned"])
def test_group_models_agree_with_pinocchio_on_every_field(name):
    model = model_of(name)
    assert model.group_joints and model.nq > model.nv
    compared = 0
    for q, qd, u in sampled(name):
        ours, _, errors = assert_fields_agree(model, q, qd, u)
        compared += "total" in errors
        testing.assert_backends_agree(model, sampling.State(0, tuple(q), tuple(qd), tuple(u)), backends=BACKENDS)
    assert compared >= 4, "most sampled states must be regular and compared in full"


def test_the_gear_row_uses_velocity_and_coordinate_indices():
    """The satellite's shoulder is velocity 6 but coordinate 7 (after the free base's 7 coordinates and 6
    velocities): the coupling row ``q_shoulder - 2 q_elbow - 0.1`` and its Jacobian sit there."""
    model = model_of("satellite_on_rail")
    q, qd, u = sampled("satellite_on_rail", count=2)[1]
    s = op.split(model, q, qd, u)
    row = np.zeros(model.nv)
    row[[6, 7]] = (1.0, -2.0)
    np.testing.assert_array_equal(s.constraint_jacobian[-1], row)
    assert s.constraint_value[-1] == pytest.approx(q[7] - 2.0 * q[8] - 0.1, abs=1e-15)
    assert abs(s.constraint_value[-1]) < 1e-9 and abs(row @ s.total) < 1e-9 * s.accel_scale


def test_the_ball_pendulums_three_direction_task_is_a_breakdown_everywhere():
    """Tracking the ball pendulum's bob in three directions, when it moves on a sphere about the ball joint: ``J M^-1
    J^T`` is singular at every state (the reference says so too). The backend returns NaN for everything that goes
    through task space and cond inf (a BREAKDOWN, not compared), and the rest still agrees."""
    model = model_of("ball_pendulum_xyz")
    for q, qd, u in sampled("ball_pendulum_xyz", count=4):
        ours, ref = op.split(model, q, qd, u), reference.split(model, q, qd, u)
        assert ours.conditions["task"] == np.inf and ref.conditions["task_inertia"] > 1e8
        assert np.isnan(ours.total).all() and np.isnan(ours.task_inertia).all() and np.isnan(ours.task_drift).all()
        errors = field_errors(model, ours, ref, q, qd, u)
        assert "total" not in errors and max(errors.values()) <= REL
        outcome = testing.assert_backends_agree(model, sampling.State(0, tuple(q), tuple(qd), tuple(u)),
                                                backends=BACKENDS)
        assert "task" in outcome.breakdowns["operational_space"]


@settings(max_examples=40, deadline=None)
@given(data=st.data())
def test_random_trees_with_group_joints_agree_with_pinocchio(data):
    model = data.draw(testing.models(max_bodies=4, group=True, constraints=None), label="model")
    state = data.draw(testing.states(model), label="state")
    testing.assert_backends_agree(model, state, backends=BACKENDS)
    assert_fields_agree(model, *(np.array(x) for x in (state.q, state.qd, state.u)))


# ----------------------------------------------------------------------------------------------------------
# split_batch
# ----------------------------------------------------------------------------------------------------------

@pytest.mark.parametrize("name", CASES + ("ball_pendulum_xy", "satellite_on_rail", "limb_pinned"))
def test_split_batch_rows_equal_split(name):
    model = model_of(name)
    Q, QD, U = (np.array(x) for x in zip(*sampled(name, count=7, seed=5)))
    size = op.BLOCK_ENTRIES
    try:
        op.BLOCK_ENTRIES = 3 * model.nv**2                    # blocks of three states: 3 + 3 + 1
        batch = op.split_batch(model, Q, QD, U)
    finally:
        op.BLOCK_ENTRIES = size
    for row, (q, qd, u) in enumerate(zip(Q, QD, U)):
        s = op.split(model, q, qd, u)
        for field in ("drift", "ctrl", "total") + (("lam", "lam_drift") if model.constraints else ()):
            expected = getattr(s, field)
            scale = s.lam_scale if field.startswith("lam") else s.accel_scale
            np.testing.assert_allclose(getattr(batch, field)[row], expected, rtol=0, atol=1e-12 * scale + 1e-300,
                                       err_msg=f"{name} row {row} {field}")


# ----------------------------------------------------------------------------------------------------------
# Closed forms of one rigid body
# ----------------------------------------------------------------------------------------------------------

def skew(v):
    return np.array([[0.0, -v[2], v[1]], [v[2], 0.0, -v[0]], [-v[1], v[0], 0.0]])


def test_free_body_drift_obeys_eulers_equations():
    """Torque-free (zero gravity) body: its drift ``(vdot, wdot)`` (body twist rates) satisfies Euler's equations
    ``I wdot + w x I w = 0`` about the COM (principal inertia ``diag(I1, I2, I3)`` in the body frame), and its COM
    ``c = o + R r`` does not accelerate: ``R^T cddot = vdot + w x v + wdot x r + w x (w x r) = 0``."""
    model = model_of("free_body")
    body = model.bodies[0]
    I, r = np.diag(np.diag(body.inertia)), body.com
    np.testing.assert_array_equal(I, body.inertia)
    assert not np.any(model.gravity)
    for q, qd, u in sampled("free_body", count=8, seed=3):
        qd = 3.0 * qd                                         # faster spins: larger gyroscopic terms
        drift = op.split(model, q, qd, u).drift
        v, w, vdot, wdot = qd[:3], qd[3:], drift[:3], drift[3:]
        scale = np.abs(I).max() * (np.abs(w).sum() ** 2 + np.abs(wdot).sum())
        np.testing.assert_allclose(I @ wdot + np.cross(w, I @ w), 0.0, rtol=0, atol=1e-13 * scale)
        assert np.abs(np.cross(w, I @ w)).max() > 1e-3 * scale      # the gyroscopic term is not trivially zero
        com = vdot + np.cross(w, v) + np.cross(wdot, r) + np.cross(w, np.cross(w, r))
        np.testing.assert_allclose(com, 0.0, rtol=0, atol=1e-13 * (np.abs(w).sum() * np.abs(v).sum()
                                                                    + np.abs(w).sum() ** 2 * np.abs(r).sum()))


def test_free_body_total_obeys_newton_euler_in_the_body_frame():
    """With gravity and the input a body wrench (force ``f`` at the origin, moment ``n`` about it, body frame: the
    generalized forces of the body twist), the total satisfies Newton's ``m (vdot + w x v + wdot x r + w x (w x r))
    = f + m R^T gravity`` (the COM acceleration in the body frame) and Euler's ``I_c wdot + w x I_c w = n - r x f``
    about the COM (the weight acts there; f at the origin, ``-r`` from it); R from scipy's (x, y, z, w) quaternion."""
    model = cases.load("free_body", g=9.81)
    body = model.bodies[0]
    m, I, r = body.mass, body.inertia, body.com
    for q, qd, u in sampled("free_body", count=6, seed=8):
        total = op.split(model, q, qd, u).total
        R = Rotation.from_quat(q[3:7]).as_matrix()
        v, w, vdot, wdot = qd[:3], qd[3:], total[:3], total[3:]
        weight = m * R.T @ model.gravity
        com_acceleration = vdot + np.cross(w, v) + np.cross(wdot, r) + np.cross(w, np.cross(w, r))
        f, n = u[:3], u[3:]
        scale = (np.abs(u).sum() + np.abs(weight).sum() + m * np.abs(qd).sum() ** 2
                 + np.abs(I).max() * np.abs(w).sum() ** 2)
        np.testing.assert_allclose(m * com_acceleration, f + weight, rtol=0, atol=1e-13 * scale)
        np.testing.assert_allclose(I @ wdot + np.cross(w, I @ w), n - np.cross(r, f), rtol=0, atol=1e-13 * scale)


# ----------------------------------------------------------------------------------------------------------
# Kinematics on the groups: positions, J v and the classical Jdot v by finite differences along group curves
# ----------------------------------------------------------------------------------------------------------

def hat(v):
    """The 4x4 matrix of a body twist ``(linear, angular)``."""
    X = np.zeros((4, 4))
    X[:3, :3], X[:3, 3] = skew(v[3:]), v[:3]
    return X


def joint_motion(model, i, q, t, v):
    """Body ``i``'s joint motion (4x4) at ``q (+) t v``: one-number joints at ``q_i + t v_i``; a spherical or free
    joint at ``X exp(t v^)`` with X from scipy's (x, y, z, w) quaternion; and the joint block of ``q`` there."""
    b, iq, iv = model.bodies[i], model.q_index[i], model.v_index[i]
    T = np.eye(4)
    if b.joint == "revolute":
        T[:3, :3] = Rotation.from_rotvec((q[iq] + t * v[iv]) * b.axis).as_matrix()
        return T, [q[iq] + t * v[iv]]
    if b.joint == "prismatic":
        T[:3, 3] = (q[iq] + t * v[iv]) * b.axis
        return T, [q[iq] + t * v[iv]]
    if b.joint == "spherical":
        T[:3, :3] = Rotation.from_quat(q[iq:iq + 4]).as_matrix() @ expm(t * skew(v[iv:iv + 3]))
        return T, list(Rotation.from_matrix(T[:3, :3]).as_quat())
    T[:3, :3], T[:3, 3] = Rotation.from_quat(q[iq + 3:iq + 7]).as_matrix(), q[iq:iq + 3]
    T = T @ expm(t * hat(v[iv:iv + 6]))
    return T, list(T[:3, 3]) + list(Rotation.from_matrix(T[:3, :3]).as_quat())


def along(model, q, v, t):
    """``(q(t), poses(t))``: the configuration and the body poses (4x4, world) on the curve with constant body
    velocities ``v`` through ``q``."""
    q_t, poses = np.empty(model.nq), [None] * len(model.bodies)
    for i in model.topological_order:
        b, p = model.bodies[i], model.parent_index[i]
        placement = np.eye(4)
        placement[:3, :3], placement[:3, 3] = b.rotation, b.translation
        motion, block = joint_motion(model, i, q, t, v)
        q_t[model.q_index[i]:model.q_index[i] + len(block)] = block
        poses[i] = (np.eye(4) if p < 0 else poses[p]) @ placement @ motion
    return q_t, poses


def derivatives(f, h=1e-3):
    """Fourth-order central first and second differences of f at 0."""
    values = {k: f(k * h) for k in (-2, -1, 0, 1, 2)}
    first = (-values[2] + 8 * values[1] - 8 * values[-1] + values[-2]) / (12 * h)
    second = (-values[2] + 16 * values[1] - 30 * values[0] + 16 * values[-1] - values[-2]) / (12 * h * h)
    return first, second


@pytest.mark.parametrize("name", ["free_body", "ball_double_pendulum", "satellite_arm"])
def test_point_kinematics_match_finite_differences_along_group_curves(name):
    model = model_of(name)
    tp = model.task_point()
    points = [(tp.body, tp.offset)] + [(b.name, b.com) for b in model.bodies]
    body = np.array([model.body_index(n) for n, _ in points])
    offsets = np.array([o for _, o in points])
    for q, v, _ in sampled(name, count=3, seed=11):
        def world(t):
            _, poses = along(model, q, v, t)
            return np.array([(poses[i] @ np.r_[o, 1.0])[:3] for i, o in zip(body, offsets)])

        def jacobian_times_v(t):
            q_t, _ = along(model, q, v, t)
            kin = op.kinematics(model, q_t, v)
            p = kin.o[body] + np.einsum("kab,kb->ka", kin.R[body], offsets)
            return op.point_jacobian(kin, body, p)[0] @ v

        kin = op.kinematics(model, q, v)
        p = kin.o[body] + np.einsum("kab,kb->ka", kin.R[body], offsets)
        np.testing.assert_allclose(p, world(0.0), rtol=0, atol=1e-14 * (1 + np.abs(p).max()))
        Jv, Jw = op.point_jacobian(kin, body, p)
        velocity, acceleration = derivatives(world)
        np.testing.assert_allclose(Jv @ v, velocity, rtol=0, atol=1e-8 * (1 + np.abs(velocity).max()))
        np.testing.assert_allclose(op.point_velocity(kin, body, p), Jv @ v, rtol=0, atol=1e-13 * (1 + np.abs(p).max()))
        bias = op.point_bias(kin, body, p, Jv @ v)
        np.testing.assert_allclose(bias, acceleration, rtol=0, atol=1e-6 * (1 + np.abs(bias).max()))
        np.testing.assert_allclose(bias, derivatives(jacobian_times_v)[0], rtol=0, atol=1e-8 * (1 + np.abs(bias).max()))
        _, poses = along(model, q, v, 0.0)
        np.testing.assert_allclose(kin.R, [T[:3, :3] for T in poses], rtol=0, atol=1e-14)
        rotation = lambda t: np.array([T[:3, :3] for T in along(model, q, v, t)[1]])  # noqa: E731
        w_fd = derivatives(rotation)[0] @ np.swapaxes(kin.R, -1, -2)    # Rdot R^T = [w]x
        np.testing.assert_allclose(kin.w, np.stack([w_fd[:, 2, 1], w_fd[:, 0, 2], w_fd[:, 1, 0]], -1), rtol=0,
                                   atol=1e-8 * (1 + np.abs(kin.w).max()))
        np.testing.assert_allclose(Jw @ v, kin.w[body], rtol=0, atol=1e-13 * (1 + np.abs(kin.w).max()))


def test_a_quaternion_and_its_negative_give_the_same_split():
    """``q`` and ``-q`` are the same rotation: every number the backend reports is the same."""
    model = model_of("ball_double_pendulum")
    for q, qd, u in sampled("ball_double_pendulum", count=3, seed=2):
        flipped = q.copy()
        flipped[4:8] *= -1.0
        a, b = op.split(model, q, qd, u), op.split(model, flipped, qd, u)
        for field in ("drift", "ctrl", "total", "task_drift", "task_inertia"):
            np.testing.assert_allclose(getattr(b, field), getattr(a, field), rtol=1e-13, atol=1e-13 * a.accel_scale)
