"""Spherical and free joints in the Newton–Euler backend (issue 17; article 2.1-2.2, 6.1, 6.2, 6.4).

The backend runs its two passes with a ball joint's quaternion and a free joint's ``(p, quat)`` as coordinates and the
body angular velocity / body twist as velocities (Pinocchio's conventions, ``cases.model``). Checked here:

* the four Lie-group cases (``free_body``, ``ball_pendulum``, ``ball_double_pendulum``, ``satellite_arm``) and two
  constrained variants (a ball-jointed limb with its hand pinned to the world; the satellite's gripper on a circle
  and its shoulder geared to its elbow) at sampled states against Pinocchio (``crosscheck.references.pinocchio.reference``) field by
  field, each to 1e-9 of the field's scale, and through the harness's own comparison (``assert_backends_agree``);
* a Hypothesis property over random trees with revolute, prismatic, spherical and free joints, maybe constrained;
* ``split_batch`` rows equal ``split``;
* the torque-free body: the drift obeys Euler's equations ``I wd + w x I w = 0`` at the COM, the COM does not
  accelerate, and the kinetic energy is ``1/2 m |v_c|^2 + 1/2 w . I w``: closed forms written here;
* the public functions take ``q`` of ``nq`` entries and velocities of ``nv``.
"""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

import cases
from cases.constraints import JointCoupling, PointOnCircle, PointsCoincide
from cases.build import build_model
from crosscheck.references.pinocchio import reference
from crosscheck import testing
from crosscheck.core.sampling import sample_states
from formalisms import newton_euler as ne
from formalisms.interface import StateError

GROUP_CASES = ("free_body", "ball_pendulum", "ball_double_pendulum", "satellite_arm")
#: Relative tolerance on every compared field, of the field's scale (:func:`field_scales`).
RTOL = 1e-9


def _rebuilt(model, name, constraints):
    return build_model(name, model.bodies, gravity=model.gravity, input_map=model.input_map,
                       task_points=model.task_points, constraints=constraints)


def hand_pinned():
    """``ball_double_pendulum`` with the hand (lower link's end) pinned to a world point in reach: 3 rows, 3 degrees
    of freedom left."""
    return _rebuilt(cases.load("ball_double_pendulum"), "ball_hand_pinned",
                    [PointsCoincide("pin", "lower", np.array([0.0, 0.0, -0.5]), None, np.array([0.3, 0.2, -0.7]))])


def satellite_on_circle():
    """``satellite_arm`` with the gripper on a circle in the world's xy plane and shoulder geared to elbow (a joint
    coupling on a model whose q and v blocks are offset by the base's quaternion)."""
    return _rebuilt(cases.load("satellite_arm"), "satellite_on_circle",
                    [PointOnCircle("ring", "extension", np.array([0.25, 0.0, 0.0]), np.zeros(3), 1.0),
                     JointCoupling("gear", ("shoulder", "elbow"), (1.0, -0.5), 0.1)])


CONSTRAINED = {"ball_hand_pinned": hand_pinned, "satellite_on_circle": satellite_on_circle}


def model_named(name):
    return CONSTRAINED[name]() if name in CONSTRAINED else cases.load(name)


def _max(x) -> float:
    return float(np.max(np.abs(np.asarray(x, dtype=float)), initial=0.0))


def field_scales(model, ref, qd, u) -> dict[str, float]:
    """The size of each compared field at a state, from the reference's numbers and the state: accelerations by
    ``accel_scale``, loads by the largest load, input, weight or inertial load, powers by ``|B u| |qd|``, constraint
    terms by ``||Jc||``, the multipliers by ``lam_scale``."""
    acc, L = ref.accel_scale, model.length_scale
    tau = model.input_map @ u
    weight = sum(b.mass for b in model.bodies) * _max(model.gravity) * L
    scales = {"drift": acc, "ctrl": acc, "total": acc, "task_drift": acc * L, "cond_M": ref.cond_M,
              "accel_scale": acc, "kinetic_energy": model.inertia_scale * float(qd @ qd) + 1e-300,
              "power_ctrl": float(np.abs(tau * qd).sum()) + 1e-300,
              "power_ctrl_per_coord": float(np.abs(tau * qd).sum()) + 1e-300}
    motion = _max(ref.total) + _max(ref.drift) + float(qd @ qd)       # the accelerations of the bodies, per metre
    inertial = (sum(b.mass for b in model.bodies) * L + sum(np.trace(b.inertia) for b in model.bodies) / L) * motion
    scales["joint_wrenches"] = scales["joint_wrenches_drift"] = max(
        _max(ref.joint_wrenches), _max(ref.joint_wrenches_drift), _max(tau), weight, inertial, 1e-300)
    if model.k:
        jc = max(_max(ref.constraint_jacobian), L)
        force = jc * ref.lam_scale
        scales.update(lam=ref.lam_scale, lam_drift=ref.lam_scale, constraint_value=max(L, L * L),
                      constraint_jacobian=jc, constraint_bias=max(_max(ref.constraint_bias), jc * float(qd @ qd)),
                      constraint_velocity=jc * float(np.abs(qd).sum()) + 1e-300, constraint_force=force,
                      constraint_force_drift=force, power_constr=force * float(np.abs(qd).sum()) + 1e-300,
                      power_constr_per_coord=force * float(np.abs(qd).sum()) + 1e-300, lam_scale=ref.lam_scale)
    return scales


def field_errors(model, ours, ref, qd, u) -> dict[str, float]:
    """Per compared field: the largest difference from the reference over the field's scale. The conditions are
    compared relative to themselves (cond S only where S has full rank and is well conditioned: with a redundant or
    degenerate row it is rounding over rounding), the rank exactly (an error of 1 when it differs)."""
    errors = {}
    for name, scale in field_scales(model, ref, qd, u).items():
        mine, theirs = np.asarray(getattr(ours, name), dtype=float), np.asarray(getattr(ref, name), dtype=float)
        assert mine.shape == theirs.shape, f"{name}: shape {mine.shape}, reference {theirs.shape}"
        errors[name] = _max(mine - theirs) / max(scale, 1e-300)
    if model.k:
        errors["constraint_rank"] = float(ours.constraint_rank != ref.constraint_rank)
        for key in ("constraint", "constraint_kept"):
            a, b = ours.conditions[key], ref.conditions[key]
            if key == "constraint" and not (ref.constraint_rank == model.k and b < 1e8):
                continue
            errors[f"conditions[{key}]"] = 0.0 if a == b else abs(a - b) / max(abs(b), 1.0)
        errors["conditions[constraint_consistency]"] = abs(ours.conditions["constraint_consistency"]
                                                           - ref.conditions["constraint_consistency"])
    return errors


def assert_matches_reference(model, q, qd, u, rtol=RTOL, conditioned=False):
    """Every field of :func:`field_errors` within ``rtol`` of its scale; ``conditioned``: ``rtol`` grows with cond(M)
    beyond 1e6 and with the kept cond S beyond 1e4 (rounding amplified by the solves, for random models)."""
    ours, ref = ne.split(model, q, qd, u), reference.split(model, q, qd, u)
    if conditioned:
        rtol *= max(1.0, ref.cond_M / 1e6) * max(1.0, ref.conditions.get("constraint_kept", 1.0) / 1e4)
    errors = field_errors(model, ours, ref, np.asarray(qd, dtype=float), np.asarray(u, dtype=float))
    bad = {k: f"{v:.3g}" for k, v in errors.items() if not v <= rtol}
    assert not bad, f"{model.name} at q = {list(q)}, qd = {list(qd)}, u = {list(u)}: off the reference by {bad}"
    return errors


# ----------------------------------------------------------------------------------------------------------
# The cases against Pinocchio
# ----------------------------------------------------------------------------------------------------------

@pytest.mark.parametrize("name", GROUP_CASES + tuple(CONSTRAINED))
def test_group_cases_match_the_reference_field_by_field(name):
    model = model_named(name)
    assert model.group_joints
    for state in sample_states(model, 6, seed=17, case=name):
        assert_matches_reference(model, state.q, state.qd, state.u)
        testing.assert_backends_agree(model, state, backends=["newton_euler", "pinocchio"], conservation=False)


def test_group_cases_have_body_rows_of_loads_and_velocity_sized_vectors():
    model = cases.load("satellite_arm")
    state = sample_states(model, 2, seed=4, case="satellite_arm")[1]
    s = ne.split(model, state.q, state.qd, state.u)
    assert (model.nq, model.nv) == (10, 9)
    assert s.drift.shape == s.power_ctrl_per_coord.shape == (model.nv,)
    assert s.joint_wrenches.shape == s.joint_wrenches_drift.shape == (len(model.bodies), 6)
    # the base is unactuated: the world exerts nothing on it through its free joint, at the total and the drift
    scale = _max(s.joint_wrenches)
    assert _max(s.joint_wrenches[0]) <= 1e-12 * scale and _max(s.joint_wrenches_drift[0]) <= 1e-12 * scale


# ----------------------------------------------------------------------------------------------------------
# Random trees with group joints
# ----------------------------------------------------------------------------------------------------------

@settings(max_examples=100)
@given(st.data())
def test_random_group_trees_match_the_reference(data):
    model = data.draw(testing.models(max_bodies=4, group=True, constraints=None))
    state = data.draw(testing.states(model))
    assert_matches_reference(model, state.q, state.qd, state.u, conditioned=True)
    testing.assert_backends_agree(model, state, backends=["newton_euler", "pinocchio"], conservation=False)


# ----------------------------------------------------------------------------------------------------------
# split_batch
# ----------------------------------------------------------------------------------------------------------

@pytest.mark.parametrize("name", GROUP_CASES + tuple(CONSTRAINED))
def test_split_batch_rows_equal_split(name):
    model = model_named(name)
    states = sample_states(model, 7, seed=5, case=name)
    Q, QD, U = (np.array([getattr(s, f) for s in states]) for f in ("q", "qd", "u"))  # noqa: N806
    batch = ne.split_batch(model, Q, QD, U)
    assert batch.drift.shape == (len(Q), model.nv)
    for i in range(len(Q)):
        s = ne.split(model, Q[i], QD[i], U[i])
        tol = 100 * np.finfo(float).eps * s.cond_M
        for field in ("drift", "ctrl", "total"):
            assert _max(getattr(batch, field)[i] - getattr(s, field)) <= tol * s.accel_scale, (field, i)
        for field in ("lam", "lam_drift") if model.k else ():
            assert _max(getattr(batch, field)[i] - getattr(s, field)) <= tol * s.lam_scale, (field, i)
    assert (batch.lam is None) == (model.k == 0)


# ----------------------------------------------------------------------------------------------------------
# The torque-free rigid body: Euler's equations (closed form)
# ----------------------------------------------------------------------------------------------------------

def _quat_rotation(x, y, z, w):
    """``R`` of a unit quaternion (x, y, z, w), by the half-angle form ``(w^2 - v.v) I + 2 v v^T + 2 w [v]x``."""
    v = np.array([x, y, z])
    K = np.array([[0.0, -z, y], [z, 0.0, -x], [-y, x, 0.0]])
    return (w * w - v @ v) * np.eye(3) + 2.0 * np.outer(v, v) + 2.0 * w * K


@pytest.mark.parametrize("seed", range(4))
def test_free_body_drift_obeys_eulers_equations(seed):
    """Zero gravity, no input: ``I wd = -w x I w`` about the COM (Euler), and the COM moves uniformly, so the body
    origin's twist derivative is ``vd = -wd x c - w x (v + w x c)`` (the COM velocity in the body frame is ``v_c = v
    + w x c``, and ``d/dt (R v_c) = R (w x v_c + vd_c) = 0``). The marker's classical acceleration is ``R (wd x d + w
    x (w x d))`` with ``d`` its offset from the COM, and the kinetic energy ``1/2 m |v_c|^2 + 1/2 w . I w``."""
    model = cases.load("free_body")
    body = model.bodies[0]
    I, c, m = body.inertia, body.com, body.mass                 # noqa: E741
    rng = np.random.default_rng(seed)
    quat = rng.standard_normal(4)
    q = np.concatenate([rng.uniform(-1, 1, 3), quat / np.linalg.norm(quat)])
    qd, u = rng.uniform(-3, 3, 6), rng.uniform(-5, 5, 6)
    v, w = qd[:3], qd[3:]
    wd = -np.linalg.solve(I, np.cross(w, I @ w))
    vd = -np.cross(wd, c) - np.cross(w, v + np.cross(w, c))
    s = ne.split(model, q, qd, u)
    scale = np.abs(qd).max() ** 2 * (1.0 + np.linalg.norm(c))
    np.testing.assert_allclose(s.drift, np.concatenate([vd, wd]), rtol=0, atol=1e-13 * scale)
    # the torque-free body's Euler equations hold for the computed drift itself
    residual = I @ s.drift[3:] + np.cross(w, I @ w)
    assert _max(residual) <= 1e-13 * _max(I) * scale
    d = model.task_points[0].offset - c
    marker = _quat_rotation(*q[3:]) @ (np.cross(wd, d) + np.cross(w, np.cross(w, d)))
    np.testing.assert_allclose(s.task_drift, marker, rtol=0, atol=1e-13 * scale)
    v_c = v + np.cross(w, c)
    assert s.kinetic_energy == pytest.approx(0.5 * m * v_c @ v_c + 0.5 * w @ I @ w, rel=1e-13)
    # the control: a body wrench (f, n) about the origin, i.e. (f, n - c x f) about the COM
    f, n = u[:3], u[3:] - np.cross(c, u[:3])
    wd_u = np.linalg.solve(I, n)
    vd_u = f / m - np.cross(wd_u, c)
    np.testing.assert_allclose(s.ctrl, np.concatenate([vd_u, wd_u]), rtol=0,
                               atol=1e-13 * _max(np.concatenate([vd_u, wd_u])))
    np.testing.assert_allclose(s.joint_wrenches[0], u, rtol=0, atol=1e-12 * _max(u))


# ----------------------------------------------------------------------------------------------------------
# The public functions on nq / nv vectors
# ----------------------------------------------------------------------------------------------------------

def test_public_functions_take_q_of_nq_and_velocities_of_nv():
    model = cases.load("ball_double_pendulum")
    state = sample_states(model, 2, seed=9, case="ball_double_pendulum")[1]
    q, qd, u = (np.array(x) for x in (state.q, state.qd, state.u))
    M = ne.mass_matrix(model, q)
    assert M.shape == (6, 6) and np.array_equal(M, M.T)
    h = ne.inverse_dynamics(model, q, qd, np.zeros(6))
    s = ne.split(model, q, qd, u)
    np.testing.assert_allclose(ne.inverse_dynamics(model, q, qd, s.total), model.input_map @ u, rtol=0,
                               atol=1e-12 * (_max(h) + _max(u)))
    np.testing.assert_allclose(M @ qd, ne.inverse_dynamics(model, q, np.zeros(6), qd, gravity=False), rtol=0,
                               atol=1e-13 * _max(M) * _max(qd))
    reactions = ne.joint_reactions(model, q, qd, s.total)
    np.testing.assert_allclose(reactions, s.joint_wrenches, rtol=0, atol=1e-12 * _max(reactions))
    np.testing.assert_allclose(reactions[:, 3:].ravel(), model.input_map @ u, rtol=0, atol=1e-12 * _max(reactions))
    with pytest.raises(StateError):
        ne.inverse_dynamics(model, q[:6], qd, qd)
    with pytest.raises(StateError):
        ne.split(model, q * 1.001, qd, u)                        # quaternions not unit
