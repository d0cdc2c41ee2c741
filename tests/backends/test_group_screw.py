"""Spherical and free joints in the screw backend (article 2.1-2.2: SO(3), SE(3); 6.2: body twists, Ad, ad, ad*).

A spherical joint's quaternion and a free joint's ``(p, quat)`` are group elements ``g_i`` formed by the backend
itself (``lie.quaternion_rotation``: the exponential of the rotation vector), its velocity columns constant body-frame
unit twists, and the recursions are the screw ones (``formalisms.screw.kinematics`` docstring). References here:

* the quaternion's rotation against the polynomial ``I + 2 w [u] + 2 [u]^2`` of ``cases.model``, and the poses
  against the model's composition ``X_parent (rotation, translation) motion(q_i)``, both written in this file;
* Pinocchio (``crosscheck.references.pinocchio.reference.split``: JointModelSpherical / JointModelFreeFlyer) on every field of the split,
  on the four group cases and on random trees with spherical and free joints, constrained or not, to ``RTOL`` of each
  field's scale (:func:`scales`), and through the gate's comparison (``testing.assert_backends_agree``);
* ``split_batch`` rows against ``split``;
* Euler's equations of the torque-free body, ``I_c wd + w x I_c w = 0`` and a COM that does not accelerate (or falls
  with gravity), in closed form;
* the screw faults of ``crosscheck.faults.backend_catalog`` still reach the group-joint code paths.
"""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

import cases
import cases.constraints
from cases.build import build_model
from crosscheck.faults import backend_catalog
from crosscheck.checks import frames
from crosscheck.references.pinocchio import reference
from crosscheck import testing
from crosscheck.faults.injection import injected
from crosscheck.core.sampling import sample_states
from crosscheck.core.tolerance import BREAKDOWN_LIMITS, BREAKDOWN_SCOPE
from formalisms import screw
from formalisms.screw import kinematics, lie

GROUP_CASES = ("free_body", "ball_pendulum", "ball_double_pendulum", "satellite_arm")
#: Allowed difference from the reference, relative to the field's scale (:func:`scales`); measured: below 1e-13.
RTOL = 1e-9
#: Allowed difference of a batch row from ``split``, in units of ``cond(M) accel_scale`` (tests/backends/test_split_batch.py).
BATCH_RTOL = 100 * np.finfo(float).eps

EPS = np.finfo(float).eps
#: Fields built on the smallest eigenvalue of M or S: cond(M), ``accel_scale``, ``lam_scale``.
SPECTRAL = ("cond_M", "accel_scale", "lam_scale")
#: Fields compared with the reference; each scaled by :func:`scales`.
FIELDS = ("drift", "ctrl", "total", "lam", "lam_drift", "power_ctrl", "power_ctrl_per_coord", "power_constr",
          "power_constr_per_coord", "cond_M", "accel_scale", "task_drift", "kinetic_energy", "joint_wrenches",
          "joint_wrenches_drift", "task_inertia", "constraint_value", "constraint_jacobian", "constraint_bias",
          "constraint_velocity", "constraint_force", "constraint_force_drift", "lam_scale")


# ----------------------------------------------------------------------------------------------------------
# Group elements from the configuration
# ----------------------------------------------------------------------------------------------------------

def polynomial_rotation(quat):
    """``R(quat) = I + 2 w [u] + 2 [u]^2`` (``cases.model``), ``quat = (x, y, z, w)``, ``u = (x, y, z)``."""
    x, y, z, w = quat
    U = np.array([[0.0, -z, y], [z, 0.0, -x], [-y, x, 0.0]])
    return np.eye(3) + 2.0 * w * U + 2.0 * U @ U


def transform(R, p):
    T = np.eye(4)
    T[:3, :3], T[:3, 3] = R, p
    return T


unit_quaternions = st.tuples(*[st.floats(-1.0, 1.0)] * 4).map(np.array).filter(
    lambda v: np.linalg.norm(v) > 1e-3).map(lambda v: v / np.linalg.norm(v))


@given(unit_quaternions)
def test_quaternion_rotation_is_the_polynomial_of_the_model(quat):
    R = lie.quaternion_rotation(quat)
    assert np.allclose(R, polynomial_rotation(quat), rtol=0, atol=1e-14)
    assert np.allclose(lie.quaternion_rotation(-quat), R, rtol=0, atol=1e-14)     # q and -q: one rotation


@pytest.mark.parametrize("quat", [(0.0, 0.0, 0.0, 1.0), (0.0, 0.0, 0.0, -1.0), (1.0, 0.0, 0.0, 0.0),
                                  (0.0, np.sqrt(0.5), 0.0, -np.sqrt(0.5)), (1e-170, 0.0, 0.0, 1.0),
                                  (3e-9, -4e-9, 1e-9, -np.sqrt(1.0 - 2.6e-17))])
def test_quaternion_rotation_at_the_identity_a_half_turn_and_tiny_angles(quat):
    quat = np.array(quat)
    R = lie.quaternion_rotation(quat)
    assert np.allclose(R, polynomial_rotation(quat), rtol=0, atol=1e-15)
    assert np.allclose(R @ R.T, np.eye(3), rtol=0, atol=1e-15)


def model_poses(model, q):
    """``X_i = X_parent (rotation, translation) motion(q_i)`` (``cases.model``) with the polynomial rotation."""
    poses = [None] * len(model.bodies)
    for i in model.topological_order:
        b, p = model.bodies[i], model.parent_index[i]
        qi = np.asarray(q)[model.q_index[i]:]
        if b.joint == "revolute":
            K = lie.hat3(b.axis)
            motion = transform(np.eye(3) + np.sin(qi[0]) * K + (1 - np.cos(qi[0])) * K @ K, np.zeros(3))
        elif b.joint == "prismatic":
            motion = transform(np.eye(3), qi[0] * np.asarray(b.axis))
        elif b.joint == "spherical":
            motion = transform(polynomial_rotation(qi[:4]), np.zeros(3))
        else:
            motion = transform(polynomial_rotation(qi[3:7]), qi[:3])
        X = transform(b.rotation, b.translation) @ motion
        poses[i] = X if p < 0 else poses[p] @ X
    return np.array(poses)


@pytest.mark.parametrize("case", GROUP_CASES)
def test_poses_and_body_twists_follow_the_model_composition(case):
    """The PoE poses (factors ``M_i g_i M_i^-1``) are the model's composition, and the body twists are ``T^-1 Tdot``
    along ``q (+) t v`` (a central difference of the composition, integrated here on the group)."""
    model = cases.load(case)
    for s in sample_states(model, 4, 11, case):
        kin = kinematics.forward_kinematics(model, np.array(s.q))
        T = model_poses(model, s.q)
        assert np.allclose(kin.poses, T, rtol=0, atol=1e-13)
        h = 1e-5
        dT = (model_poses(model, _integrate(model, s.q, s.qd, h)) - model_poses(model, _integrate(model, s.q, s.qd,
                                                                                                    -h))) / (2 * h)
        body = lie.vee6(np.linalg.inv(T) @ dT)
        assert np.allclose(kinematics.body_twists(kin, np.array(s.qd)), body, rtol=0, atol=1e-8)


def _integrate(model, q, v, t):
    """``q (+) t v``: revolute/prismatic ``q + t v``, a group joint moved by ``exp(t v)`` on the right (body frame),
    with the exponentials of scipy (independent of ``lie``)."""
    import scipy.linalg
    from scipy.spatial.transform import Rotation

    q, v = np.array(q, dtype=float), np.asarray(v, dtype=float)
    for i, b in enumerate(model.bodies):
        a, c = model.q_index[i], model.v_index[i]
        if b.joint in ("revolute", "prismatic"):
            q[a] += t * v[c]
        elif b.joint == "spherical":
            R = polynomial_rotation(q[a:a + 4]) @ scipy.linalg.expm(lie.hat3(t * v[c:c + 3]))
            q[a:a + 4] = Rotation.from_matrix(R).as_quat()
        else:
            twist = np.zeros((4, 4))
            twist[:3, :3], twist[:3, 3] = lie.hat3(t * v[c + 3:c + 6]), t * v[c:c + 3]
            X = transform(polynomial_rotation(q[a + 3:a + 7]), q[a:a + 3]) @ scipy.linalg.expm(twist)
            q[a:a + 3], q[a + 3:a + 7] = X[:3, 3], Rotation.from_matrix(X[:3, :3]).as_quat()
    return q


# ----------------------------------------------------------------------------------------------------------
# Agreement with the reference, field by field
# ----------------------------------------------------------------------------------------------------------

def scales(model, ref, state) -> dict[str, float]:
    """The scale of each field at this state: the reference's own size, at least the size of the terms it is made of
    (a field that is zero, such as an unactuated free root's drift wrench, is compared absolutely): accelerations
    ``A = accel_scale``, forces ``m_total (|g| + L A)`` times the length scale ``L`` for moments and wrenches."""
    A, L = ref.accel_scale, model.length_scale
    qd = max(float(np.abs(state.qd).max(initial=0.0)), 1.0)
    W = sum(b.mass for b in model.bodies) * (float(np.abs(model.gravity).max()) + L * A) * L
    tau = float(np.abs(model.input_map @ np.asarray(state.u)).sum())
    floor = {"drift": A, "ctrl": A, "total": A, "task_drift": L * A, "joint_wrenches": W, "joint_wrenches_drift": W,
             "power_ctrl": tau * qd, "power_ctrl_per_coord": tau * qd, "power_constr": W * qd,
             "power_constr_per_coord": W * qd, "constraint_force": W, "constraint_force_drift": W,
             "lam": ref.lam_scale, "lam_drift": ref.lam_scale, "constraint_value": L * L, "constraint_jacobian": L * L,
             "constraint_bias": L * L * (A + qd * qd), "constraint_velocity": L * L * qd}
    out = {}
    for name in FIELDS:
        value = getattr(ref, name)
        size = 0.0 if value is None else float(np.nanmax(np.abs(value), initial=0.0))
        out[name] = max(size, floor.get(name, 0.0))
    return out


def assert_agrees_with_reference(model, state, worst: dict | None = None) -> None:
    """Every field of the screw split against Pinocchio's at ``state``, to :data:`RTOL` of its scale; the multipliers
    and joint loads only where they are unique (``S`` of full rank, ``tolerance.BREAKDOWN_SCOPE``)."""
    q, qd, u = (np.array(x) for x in (state.q, state.qd, state.u))
    mine, ref = screw.split(model, q, qd, u), reference.split(model, q, qd, u)
    assert mine.constraint_rank == ref.constraint_rank
    unique = mine.constraint_rank is None or mine.constraint_rank == model.k
    # An eigenvalue at the bottom of a spectrum is known to eps times the top one: the scales built on the smallest
    # eigenvalue of M (and of S) are relative to eps times the condition numbers.
    spectral = max(RTOL, 1e3 * EPS * (ref.cond_M + ref.conditions.get("constraint_kept", 1.0)))
    bad = []
    for name, scale in scales(model, ref, state).items():
        a, b = getattr(mine, name), getattr(ref, name)
        if a is None or b is None:
            assert a is None and b is None, f"{name}: {a} against {b}"
            continue
        if not unique and name in BREAKDOWN_SCOPE["constraint"] + ("lam_scale",):
            continue
        a, b = np.asarray(a, dtype=float), np.asarray(b, dtype=float)
        assert a.shape == b.shape, f"{name}: shape {a.shape} against {b.shape}"
        assert np.array_equal(np.isnan(a), np.isnan(b)), f"{name}: NaN pattern {a} against {b}"
        difference = float(np.max(np.abs(np.where(np.isnan(b), 0.0, a - b)), initial=0.0))
        error = difference / scale if scale > 0 else float(difference > 0.0)
        if worst is not None:
            worst[name] = max(worst.get(name, 0.0), error)
        if not error <= (spectral if name in SPECTRAL else RTOL):
            bad.append(f"{name}: relative error {error:.3g} (scale {scale:.3g})\n  screw {a}\n  ref   {b}")
    for key in set(mine.conditions) & set(ref.conditions):
        a, b = mine.conditions[key], ref.conditions[key]
        limit = BREAKDOWN_LIMITS[key]
        if a > limit and b > limit or key == "constraint_consistency" and a <= limit and b <= limit:
            continue                                    # both in BREAKDOWN (or both consistent): the verdict agrees
        if not (a == b or abs(a - b) <= max(RTOL, 1e3 * EPS * max(a, b)) * max(abs(b), 1.0)):
            bad.append(f"conditions[{key}]: {a} against {b}")
    assert not bad, f"model '{model.name}' at q = {list(q)}, qd = {list(qd)}, u = {list(u)}:\n" + "\n".join(bad)


@pytest.mark.parametrize("case", GROUP_CASES)
def test_the_group_cases_agree_with_pinocchio_on_every_field(case):
    """Also through the gate's comparison, with its conservation checks and a moved scene (frame invariance)."""
    model = cases.load(case)
    for state, frame in zip(sample_states(model, 6, 17, case), frames.sampled(17, case, count=6)):
        assert_agrees_with_reference(model, state)
        testing.assert_backends_agree(model, state, backends=["screw", "pinocchio"], frame=frame)


def assert_batch_rows_equal_split(model, states) -> None:
    Q, QD, U = (np.array([getattr(s, f) for s in states]) for f in ("q", "qd", "u"))
    batch = screw.split_batch(model, Q, QD, U)
    assert batch.drift.shape == batch.ctrl.shape == batch.total.shape == (len(Q), model.nv)
    for i, s in enumerate(states):
        one = screw.split(model, Q[i], QD[i], U[i])
        tol = BATCH_RTOL * one.cond_M * one.accel_scale
        for name in ("drift", "ctrl", "total"):
            assert np.abs(getattr(batch, name)[i] - getattr(one, name)).max() <= tol, (name, i)
        if model.k:
            for name in ("lam", "lam_drift"):
                err = np.abs(getattr(batch, name)[i] - getattr(one, name)).max()
                assert err <= BATCH_RTOL * one.cond_M * one.lam_scale, (name, i)
        else:
            assert batch.lam is None and batch.lam_drift is None


@pytest.mark.parametrize("case", GROUP_CASES)
def test_split_batch_rows_equal_split_on_the_group_cases(case):
    model = cases.load(case)
    assert_batch_rows_equal_split(model, sample_states(model, 9, 5, case))


@settings(max_examples=80, deadline=None, suppress_health_check=[HealthCheck.too_slow, HealthCheck.filter_too_much])
@given(st.data())
def test_random_trees_with_group_joints_agree_with_pinocchio(data):
    model = data.draw(testing.models(max_bodies=4, group=True, constraints=None))
    states = [data.draw(testing.states(model, index=i)) for i in range(2)]
    for state in states:
        assert_agrees_with_reference(model, state)
        testing.assert_backends_agree(model, state, backends=["screw", "pinocchio"])
    assert_batch_rows_equal_split(model, states)


@settings(max_examples=30, deadline=None, suppress_health_check=[HealthCheck.too_slow, HealthCheck.filter_too_much])
@given(st.data())
def test_constrained_random_trees_with_group_joints_agree_with_pinocchio(data):
    """Point constraints on bodies at and below spherical and free joints (``Jc`` k x nv)."""
    model = data.draw(testing.models(max_bodies=4, group=True, constraints=True))
    state = data.draw(testing.states(model))
    assert_agrees_with_reference(model, state)
    testing.assert_backends_agree(model, state, backends=["screw", "pinocchio"])
    assert_batch_rows_equal_split(model, [state])


# ----------------------------------------------------------------------------------------------------------
# Euler's equations of the free body (closed form)
# ----------------------------------------------------------------------------------------------------------

@pytest.mark.parametrize("g", [0.0, 9.81])
def test_the_free_body_obeys_eulers_equations_under_the_drift(g):
    """Body twist ``(v, w)`` (origin velocity, angular velocity, body frame) and the drift ``(vd, wd)``. About the COM
    ``c`` (body frame), torque-free: ``I_c wd + w x I_c w = 0``; the COM's acceleration, in the body frame
    ``vd + w x v + wd x c + w x (w x c)`` (``v = R^T pdot`` so ``R^T pddot = vd + w x v``), is ``R^T g``: zero in free
    fall without gravity, the fall otherwise."""
    model = cases.load("free_body", g=g)
    body = model.bodies[0]
    I, c = np.asarray(body.inertia), np.asarray(body.com)
    rng = np.random.default_rng(7)
    states = sample_states(model, 5, 23, "free_body")
    fast = [(s.q, tuple(rng.uniform(-20, 20, 6)), s.u) for s in states]
    for q, qd, u in [(s.q, s.qd, s.u) for s in states] + fast:
        split = screw.split(model, q, qd, u)
        v, w = np.array(qd[:3]), np.array(qd[3:])
        vd, wd = split.drift[:3], split.drift[3:]
        size = np.abs(I).max() * (np.abs(w).max() ** 2 + 1.0)
        assert np.abs(I @ wd + np.cross(w, I @ w)).max() <= 1e-13 * size
        R = polynomial_rotation(q[3:7])
        com = vd + np.cross(w, v) + np.cross(wd, c) + np.cross(w, np.cross(w, c))
        assert np.abs(com - R.T @ model.gravity).max() <= 1e-13 * (np.abs(qd).max() ** 2 + g + 1.0)
        # The unactuated drift's joint load is zero; the total's is the input's wrench (force, moment), body frame.
        assert np.abs(split.joint_wrenches_drift).max() <= 1e-13 * (size + body.mass * (g + 1.0))
        assert np.allclose(split.joint_wrenches[0], model.input_map @ np.asarray(u), rtol=0, atol=1e-12)


# ----------------------------------------------------------------------------------------------------------
# The fault catalog reaches the group-joint paths
# ----------------------------------------------------------------------------------------------------------

def _caught(model, states) -> bool:
    """Whether the comparison with the reference (:func:`assert_agrees_with_reference`) fails at one of ``states``
    (a backend that refuses the state, its mass matrix no longer positive definite, counts as caught)."""
    for state in states:
        try:
            assert_agrees_with_reference(model, state)
        except (AssertionError, ValueError):
            return True
    return False


@pytest.mark.parametrize("fault", backend_catalog.SCREW, ids=lambda f: f.name)
def test_the_reference_comparison_catches_each_screw_fault_on_the_group_cases(fault):
    """Every screw fault of the catalog, injected, makes the comparison above fail on some group case: the functions
    the faults patch (``lie.coad``, ``dynamics._wrench_to_parent``, ``spatial_inertias``, ``gravity_wrenches``,
    ``kinematics.classical_acceleration``, ``point_jacobian``) are the ones the group paths call, and the comparison
    is tight enough to see them."""
    models = [cases.load(case) for case in GROUP_CASES] + _with_loads_and_a_knife_edge()
    names = [m.name for m in models]
    samples = [sample_states(m, 3, 29, m.name)[1:] for m in models]
    assert not any(_caught(m, s) for m, s in zip(models, samples))
    with injected(fault):
        caught = [name for name, m, s in zip(names, models, samples) if _caught(m, s)]
    assert caught, f"{fault.name} is not caught on {names}"


def _with_loads_and_a_knife_edge() -> list:
    """satellite_arm (a free base and an arm) once with a world-frame wrench at an offset point of its elbow and a
    body-frame force on its base, once with a knife edge on its elbow (on the base alone its row would be constant in
    the base's body-frame velocity, Adot qd = 0): the external-load and Pfaffian paths of the
    group code, which the catalog's load and Pfaffian faults patch."""
    base = cases.load("satellite_arm")
    loads = [cases.ExternalWrench("gust", "elbow", (0.1, -0.2, 0.05), (0.3, 0.5, -0.2), (0.4, 0.2, -0.1), "world"),
             cases.ExternalForce("thrust", "base", (0.2, 0.1, 0.0), (0.5, 1.0, 0.3), "body")]
    edge = [cases.constraints.KnifeEdge("runner", "elbow", (0.2, 0.0, -0.1), (0.0, 1.0, 0.0))]
    return [build_model(f"satellite_arm_{what}", base.bodies, base.gravity, base.input_map, base.task_points,
                        tuple(base.constraints) + tuple(extra), loads=load)
            for what, extra, load in (("loaded", (), loads), ("knife_edge", edge, ()))]
