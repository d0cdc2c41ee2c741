"""Newton–Euler formalism (article section 6.1): body-by-body force balance in classical 3-vector form.

Every quantity of body ``i`` is expressed in body frame ``i`` (frames: ``cases.model``). The recursion is the
article's two-pass algorithm (6.1.3):

* forward pass, base to tip: angular velocity ``w``, angular acceleration ``wd`` and the acceleration ``a`` of
  the body-frame origin, then the COM acceleration ``a_c = a + wd x c + w x (w x c)``;
* backward pass, tip to base: Newton (eq. 18) ``f = m a_c - m g - f_ext + sum children`` and Euler (eq. 19)
  ``n = I wd + w x (I w) + c x (m a_c - m g) - n_ext + sum children`` about the body-frame origin, with gravity
  applied to every body as the external force ``m g`` (no "accelerating base" trick) and ``(f_ext, n_ext)`` the
  other external loads on the body (the constraint forces below). ``(f, n)`` is the load the parent exerts on the
  body through its joint; the joint torque is its component along the joint axis.

Spherical and free joints (article 2.1-2.2: the configuration of such a joint is a point of the Lie group SO(3) or
SE(3), not a vector of angles; 6.2, 6.4: velocities live in the tangent space, here as body-frame twists). The
conventions are the model's (``cases.model``, Pinocchio's): a ball joint's coordinates are a unit quaternion
``(x, y, z, w)``, its velocity the body's angular velocity ``w_rel`` relative to the joint frame, in the body frame;
a free joint's coordinates are ``(p, quat)``, its velocity the body twist ``(v_lin, w_rel)`` with ``v_lin = R^T pdot``
the velocity of the body origin relative to the joint frame, in the body frame. The accelerations are the time
derivatives of these velocities. In the backend's 3-vector language such a joint is ``nv`` motions of the body
frame, the columns of its motion subspace ``(S_w, S_v)`` (the relative angular velocity ``S_w v_i`` and origin
velocity ``S_v v_i``): ``(I, 0)`` for a ball, ``([0 I], [I 0])`` for a free joint.

* placements: ``R(quat) = I + 2 w [x y z]x + 2 [x y z]x^2`` formed here from the quaternion's entries; the body
  origin sits at the joint origin (ball) or at ``p`` in the joint frame (free);
* forward pass: ``w = w_in + w_rel``, ``wd = wd_in + d/dt w_rel + w_in x w_rel``, ``a = a_origin + (w_in + w) x v_lin +
  d/dt v_lin`` with ``w_in``, ``wd_in`` the parent's and ``a_origin`` the acceleration of the parent's point at the
  body origin, all in the body frame (``_group_motion``);
* backward pass: unchanged, ``(f, n)`` is the full load the joint transmits; its projection onto the joint's
  columns, ``S_w^T n + S_v^T f``, is the generalized force: the whole moment about the ball's centre, the whole body
  wrench ``[f, n]`` of a free joint (for a free joint to the world, the input's wrench on the body);
* ``M`` column ``j`` is the backward pass of the unit motion ``vdot = e_j`` at rest, as for 1-DOF joints, and a
  point's Jacobian column (``Jc`` is ``k x nv``) that motion's point acceleration; ``Jdot v`` the point acceleration
  at ``vdot = 0``. Every velocity-like vector has ``nv`` entries, ``q`` has ``nq``; the power is ``(B u)_i v_i``.

A joint-coordinate chart ``q = psi(p)`` does not apply to a model with such joints, and the backend has no
``split_chart``.

External loads (``cases.loads``; article 6.1: "apply external/contact loads at each body") are body loads of the
backward pass, like gravity: each declaration becomes the force and the moment about the body origin it applies,
in body frame ``i`` (:func:`_external_loads`: a world vector ``x`` is ``W_i^T x`` there; a wrench's couple joins
``offset x f``; a spring's force ``-k (|d| - L0) d / |d|`` from the point's world position ``o_i + W_i offset``). The
backward pass at ``qdd = 0`` with them applied is ``h - tau_ext`` (and at rest ``g - tau_ext``), so the drift and its
part at rest include them (eq. 14); the joint reactions carry them; ``tau_ext`` itself, reported, is the backward
pass of the loads alone (no motion, no gravity), negated.

Armature (``Body.armature`` a: a rotor geared to the joint, moving with the joint velocity alone). The actuator's
generalized force first accelerates the rotor, ``a_k qdd_k`` per velocity, and the rest is the axis component of
the joint load the backward pass gives: ``tau_k = S_k^T (f, n) + a_k qdd_k``. The rotor has no velocity-product or
gravity term, so ``h`` is the passes' alone, ``M``'s column ``k`` gains ``a_k`` on the diagonal (the rotor's torque
under ``vdot = e_k``), and the joint reactions are the links' loads (without the rotor's torque).

The drift–control split (eq. 9, 10) solves ``M qdd = B u - h`` with one Cholesky factor of ``M``. The drift's parts
(4.5-4.6) are solved directly on the same factor: the zero-velocity counterfactual ``zvcf = -M^-1 g`` and
``drift_velocity = -M^-1 C qd`` (``g`` the backward pass at rest, ``C qd`` the pass at ``qdd = 0`` without gravity), so
that they add up to the drift to rounding.

Linearization (4.8, eq. 11; :func:`linearize`): the passes differentiated in forward mode, every body carrying the
directional derivatives of its placement, velocities, accelerations and loads along all ``2 nv`` state directions at
once (a trailing axis). A q direction ``q_i (+) e`` turns body ``i``'s frame by ``S_w e`` and moves its origin by
``S_v e`` (the joint's own motion, in its frame), so ``dP_i = P_i [S_w e]x``; the whole body turns by ``Th_i =
P_i^T Th_parent + th_i`` (``dW_i = W_i [Th_i]x``), which rotates gravity in the body frame, the loop forces and the
external loads' world vectors (a spring's force also follows its point: :func:`_external_tangents`). With
``qdd = vdot`` held fixed the backward pass gives ``dID/dx``, and ``dvdot/dx = -M^-1 dID/dx``, ``dvdot/du = M^-1 B``
(the KKT system differentiated with constraints, below).

Constraints (article 5; docs/design.md, constraints). ``phi``, ``Jc`` and ``Jcdot qd`` come from the recursion's own
point kinematics: the world position of a body point from the placements; column ``j`` of its Jacobian is the
point's classical acceleration from the forward pass at ``qd = 0``, ``qdd = e_j`` (the velocity of the point at
``qd = e_j``: with no velocity there is no bias), i.e. the very passes that build the columns of ``M``; and
``Jdot qd`` of the point is its classical acceleration from the forward pass at ``qdd = 0``. The multipliers come
from the range-space (Schur complement) method on the Cholesky factor of ``M``: with ``f = B u - h``,

    S = Jc M^-1 Jc^T,   lam = S^+ (-Jcdot qd - Jc M^-1 f),   qdd = M^-1 (f + Jc^T lam)        (eq. 12, 13)

``S^+`` from the eigendecomposition of ``S`` with the eigenvalues below ``CONSTRAINT_RCOND`` times the largest
dropped: redundant rows get the minimum-norm multipliers and an inconsistent system (an empty ``H_t``) finite
least-squares numbers. The drift is the same solve with ``u = 0`` (eq. 14) and ``ctrl = B_c B u`` directly
(eq. 17); the drift's parts are the solves with ``f = -g`` and no bias (``zvcf``) and with ``f = -C qd`` and the bias
``Jcdot qd`` (``drift_velocity``). The linearization differentiates the KKT system: ``M dvdot - Jc^T dlam = -dG``,
``Jc dvdot = -dc`` with ``G = ID(q, qd, vdot) - Jc^T lam`` (the backward pass with the multipliers' point forces,
``lam`` fixed, their world directions turning with the bodies) and ``c = Jc vdot + Jcdot qd`` (the rows' second
derivatives, from the points' accelerations at ``qdd = vdot``), solved by the same range-space method and rank rule.

The numbers the split reports about its solves are this backend's own, by singular values rather than the
eigendecomposition the solve uses: cond(M) and ``||M^-1||`` from those of the Cholesky factor ``L`` (``M = L L^T``),
and the eigenvalues of ``S = X^T X`` (rank, cond S, the consistency of the right-hand sides) from those of
``X = L^-1 Jc^T``.

In Newton–Euler the constraints are joint reactions (article 7.2): each multiplier's force is applied in the
backward pass as an external point force on the bodies it acts on (a circle: ``2 P^T P (p - c) lam`` at the
point; a loop closure: ``D^T lam`` on body a at ``p_a`` and ``-D^T lam`` on body b at ``p_b``, nothing on the
world; a line: ``N^T lam``), so the joint reactions carry the loop forces and their axis components are the
actuation ``B u``. A joint coupling (a gear) is no point force: its generalized force ``c_j lam`` acts on the joints
themselves like an actuator, so it appears in the axis components of the reactions, which then equal
``B u + (coupling rows of Jc)^T lam``.
"""

from __future__ import annotations

from dataclasses import dataclass, replace
from typing import Callable

import numpy as np

from cases.constraints import (JointCoupling, KnifeEdge, PointOnCircle, PointOnLine, PointsCoincide, PointVelocity,
                               RollingContact)
from cases.loads import ExternalWrench, PointSpring
from cases.model import JOINT_DOF, Model
from formalisms.interface import (CONSTRAINT_RCOND, DEGENERATE_ROW, Formalism, Linearization, Split, SplitBatch,
                                  check_batch, check_state, joint_vectors, state_space)

#: States per block of ``split_batch`` (bounds the memory of the passes: a peak near 20 MB on panda).
BLOCK = 2048
#: Velocities per joint type (``cases.model.JOINT_DOF``).
_NV = {joint: nv for joint, (_, nv) in JOINT_DOF.items()}


# ----------------------------------------------------------------------------------------------------------
# 3-vector algebra on component-first arrays: a vector is (3, *B), a rotation (3, 3, *B) with B the batch axes
# (none for a single state, so a single state's arrays are plain 3-vectors and 3 x 3 matrices)
# ----------------------------------------------------------------------------------------------------------

def _cross(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """``a x b`` componentwise (np.cross is general and several times slower on 3-vectors)."""
    return np.array([a[1] * b[2] - a[2] * b[1], a[2] * b[0] - a[0] * b[2], a[0] * b[1] - a[1] * b[0]])


def _mv(A: np.ndarray, v: np.ndarray) -> np.ndarray:  # noqa: N803
    """``A v`` for a batch of rotations ``A`` (3, 3, *B) and vectors ``v`` (3, *B) (B of ``v`` may add axes); one
    rotation (3, 3) multiplies ``v`` (3, ...) as a matrix."""
    if A.ndim == 2:
        return A @ v
    return A[:, 0] * v[0] + A[:, 1] * v[1] + A[:, 2] * v[2]


def _over_motions(x: np.ndarray, axes: int) -> np.ndarray:
    """A batch of rotations (``axes`` = 2) or vectors (1) with a unit axis inserted after the component axes, to
    broadcast over the motions of :func:`_unit_motions`; one state's (3, 3) or (3,) as is."""
    return x if x.ndim == axes else np.expand_dims(x, axes)


def _mm(A: np.ndarray, B: np.ndarray) -> np.ndarray:  # noqa: N803
    """``A B`` for two batches of 3 x 3 matrices (3, 3, *B)."""
    return A[:, 0, None] * B[None, 0] + A[:, 1, None] * B[None, 1] + A[:, 2, None] * B[None, 2]


def _cmv(C: np.ndarray, v: np.ndarray) -> np.ndarray:  # noqa: N803
    """``C v`` for one constant matrix ``C`` (r x c, or a c-vector for a dot product) and a batch ``v`` (c, *B)."""
    return (C @ v.reshape(len(v), -1)).reshape(C.shape[:-1] + v.shape[1:])


def _column(c: np.ndarray, batch: tuple) -> np.ndarray:
    """A constant array ``c`` repeated over the batch axes: shape ``c.shape + batch`` (a read-only view)."""
    return np.broadcast_to(c.reshape(c.shape + (1,) * len(batch)), c.shape + batch)


def _axis_rotation(axis: np.ndarray, angle) -> np.ndarray:
    """Rotation by ``angle`` (scalar or batch) about the unit vector ``axis`` (Rodrigues), shape (3, 3, *B)."""
    x, y, z = axis
    K = np.array([[0.0, -z, y], [z, 0.0, -x], [-y, x, 0.0]])
    return (_column(np.eye(3), np.shape(angle)) + np.multiply.outer(K, np.sin(angle))
            + np.multiply.outer(K @ K, 1.0 - np.cos(angle)))


# ----------------------------------------------------------------------------------------------------------
# Kinematics and the two passes, for one state (q of shape (n,)) or a batch (q of shape (n, *B))
# ----------------------------------------------------------------------------------------------------------

def _quaternion_rotation(quat: np.ndarray) -> np.ndarray:
    """``R(quat) = I + 2 w [v]x + 2 [v]x^2`` of a unit quaternion ``(x, y, z, w)`` (4, *B) (article 2.1-2.2: an
    orientation is a point of SO(3); ``cases.model``), written out entry by entry, shape (3, 3, *B)."""
    x, y, z, w = quat
    return np.array([[1.0 - 2.0 * (y * y + z * z), 2.0 * (x * y - w * z), 2.0 * (x * z + w * y)],
                     [2.0 * (x * y + w * z), 1.0 - 2.0 * (x * x + z * z), 2.0 * (y * z - w * x)],
                     [2.0 * (x * z - w * y), 2.0 * (y * z + w * x), 1.0 - 2.0 * (x * x + y * y)]])


def _placements(model: Model, q: np.ndarray):
    """Per body: rotation ``P`` (parent frame <- body frame), body origin ``r`` in the parent frame, and the
    world <- body rotation ``W``. ``X_body = X_parent * (rotation, translation) * motion(q_i)``, with ``q_i`` body
    ``i``'s block ``q[q_index[i]:]``: a revolute angle, a prismatic displacement, a spherical joint's quaternion
    (``motion = (R(quat), 0)``) or a free joint's ``(p, quat)`` (``motion = (R(quat), p)``)."""
    batch = np.shape(q)[1:]
    P, r, W = [None] * len(model.bodies), [None] * len(model.bodies), [None] * len(model.bodies)
    for i in model.topological_order:
        b, p, k = model.bodies[i], model.parent_index[i], model.q_index[i]
        if b.joint == "revolute":
            R = _axis_rotation(b.axis, q[k])
            P[i] = (b.rotation @ R.reshape(3, -1)).reshape(R.shape)
            r[i] = _column(b.translation, batch)
        elif b.joint == "prismatic":
            P[i] = _column(b.rotation, batch)
            r[i] = _column(b.translation, batch) + np.multiply.outer(b.rotation @ b.axis, q[k])
        else:
            free = b.joint == "free"
            R = _quaternion_rotation(q[k + 3:k + 7] if free else q[k:k + 4])
            P[i] = (b.rotation @ R.reshape(3, -1)).reshape(R.shape)
            r[i] = _column(b.translation, batch) + (_cmv(b.rotation, q[k:k + 3]) if free else 0.0)
        W[i] = P[i] if p < 0 else _mm(W[p], P[i])
    return P, r, W


def _origins(model: Model, kin) -> list[np.ndarray]:
    """World position of every body-frame origin: ``o_i = o_parent + W_parent r_i``."""
    _, r, W = kin
    origin = [None] * len(model.bodies)
    for i in model.topological_order:
        p = model.parent_index[i]
        origin[i] = r[i] if p < 0 else origin[p] + _mv(W[p], r[i])
    return origin


def _group_motion(joint: str, w_in, wd_in, a_origin, v, vd):
    """A spherical or free joint's step of the forward pass (article 2.2, 6.1.3), body frame: ``w_in``, ``wd_in``,
    ``a_origin`` are the parent's angular velocity, angular acceleration and the classical acceleration of the point
    of the parent that coincides with the body origin, all in the body frame; ``v``, ``vd`` the joint's velocity
    block and its time derivative: the relative angular velocity ``w_rel`` (spherical: ``v``; free: ``v[3:]``) and, for
    a free joint, the velocity ``v_lin = v[:3]`` of the body origin relative to the joint frame, in the body frame.

        w  = w_in + w_rel
        wd = wd_in + d/dt w_rel + w_in x w_rel
        a  = a_origin + (w_in + w) x v_lin + d/dt v_lin

    The last line is ``R^T`` of ``d/dt (R v_lin)`` (``pdot = R v_lin``, ``Rdot = R [w_rel]x``) plus the parent's
    Coriolis term ``2 w_in x v_lin``."""
    if joint == "spherical":
        return w_in + v, wd_in + vd + _cross(w_in, v), a_origin
    v_lin, w_rel = v[:3], v[3:]
    w = w_in + w_rel
    return w, wd_in + vd[3:] + _cross(w_in, w_rel), a_origin + _cross(w_in + w, v_lin) + vd[:3]


def _forward(model: Model, kin, qd: np.ndarray, qdd: np.ndarray):
    """Forward pass, base to tip: angular velocity ``w``, angular acceleration ``wd`` and the classical
    acceleration ``a`` of each body-frame origin (n x 3 x *B each, body frame). ``qd``, ``qdd``: the velocities
    (nv, *B) and their time derivatives; body ``i`` reads its block at ``v_index[i]`` (:func:`_group_motion` for a
    spherical or free joint)."""
    P, r, _ = kin
    w, wd, a = [None] * len(model.bodies), [None] * len(model.bodies), [None] * len(model.bodies)
    zero = np.zeros((3,) + np.shape(qd)[1:])
    for i in model.topological_order:
        b, p, k = model.bodies[i], model.parent_index[i], model.v_index[i]
        w_p, wd_p, a_p = (zero, zero, zero) if p < 0 else (w[p], wd[p], a[p])
        E = P[i].swapaxes(0, 1)                             # body <- parent
        w_in = _mv(E, w_p)
        a_origin = _mv(E, a_p + _cross(wd_p, r[i]) + _cross(w_p, _cross(w_p, r[i])))
        if b.joint == "revolute":
            s = np.multiply.outer(b.axis, qd[k])            # s: joint rate along the axis
            w[i] = w_in + s
            wd[i] = _mv(E, wd_p) + np.multiply.outer(b.axis, qdd[k]) + _cross(w_in, s)
            a[i] = a_origin
        elif b.joint == "prismatic":
            s = np.multiply.outer(b.axis, qd[k])
            w[i] = w_in
            wd[i] = _mv(E, wd_p)
            a[i] = a_origin + 2.0 * _cross(w[i], s) + np.multiply.outer(b.axis, qdd[k])
        else:
            nv = _NV[b.joint]
            w[i], wd[i], a[i] = _group_motion(b.joint, w_in, _mv(E, wd_p), a_origin, qd[k:k + nv], qdd[k:k + nv])
    return np.array(w), np.array(wd), np.array(a)


def _paths(model: Model) -> list[list[int]]:
    """Per body, the velocities of the joints on its path from the root, root first (the body's own joint's block
    last): indices into ``v``."""
    path = [None] * len(model.bodies)
    for i in model.topological_order:
        p, k = model.parent_index[i], model.v_index[i]
        path[i] = ([] if p < 0 else path[p]) + list(range(k, k + _NV[model.bodies[i].joint]))
    return path


def _subspace(joint: str) -> tuple[np.ndarray, np.ndarray]:
    """The motion subspace of a spherical or free joint in the body frame: ``(S_w, S_v)`` (3 x nv each), the
    relative angular velocity ``S_w v_i`` and velocity of the body origin ``S_v v_i`` its velocity block produces.
    Spherical ``(I, 0)``; free ``([0 I], [I 0])`` (the body twist: linear, then angular)."""
    eye, zero = np.eye(3), np.zeros((3, 3))
    return (eye, zero) if joint == "spherical" else (np.hstack([zero, eye]), np.hstack([eye, zero]))


def _unit_motions(model: Model, kin) -> tuple[list, list]:
    """The forward pass at ``qd = 0``, ``qdd = e_j`` for every joint ``j``: the columns of ``M`` (backward pass,
    no gravity) and of every point Jacobian (a point's classical acceleration).

    At ``qd = 0`` every ``w`` vanishes, and body ``i`` moves only under the joints on its path from the root
    (:func:`_paths`), so body ``i`` carries ``wd`` and ``a`` for those motions only, on a second axis
    (3, len(path), *B). A spherical or free joint contributes one motion per velocity: the columns of its motion
    subspace (:func:`_subspace`), ``wd = S_w e``, ``a = S_v e``.
    """
    P, r, _ = kin
    wd, a = [None] * len(model.bodies), [None] * len(model.bodies)
    for i in model.topological_order:
        b, p = model.bodies[i], model.parent_index[i]
        if b.joint in ("revolute", "prismatic"):
            unit = _column(b.axis, r[i].shape[1:])[:, None]        # qdd_i = 1 along the axis
            own_wd, own_a = (unit, np.zeros_like(unit)) if b.joint == "revolute" else (np.zeros_like(unit), unit)
        else:                                                      # the columns of the joint's motion subspace
            own_wd, own_a = (_column(S, r[i].shape[1:]) for S in _subspace(b.joint))
        if p < 0:
            wd[i], a[i] = own_wd, own_a
            continue
        E, r_i = _over_motions(P[i].swapaxes(0, 1), 2), _over_motions(r[i], 1)
        wd[i] = np.concatenate([_mv(E, wd[p]), own_wd], axis=1)
        a[i] = np.concatenate([_mv(E, a[p] + _cross(wd[p], r_i)), own_a], axis=1)
    return wd, a


def _com_acceleration(a: np.ndarray, wd: np.ndarray, w: np.ndarray, com: np.ndarray) -> np.ndarray:
    """Classical acceleration of the COM ``c`` from the body origin's: ``a_c = a + wd x c + w x (w x c)``."""
    return a + _cross(wd, com) + _cross(w, _cross(w, com))


def _body_gravity(W: np.ndarray, gravity: np.ndarray) -> np.ndarray:  # noqa: N803
    """The world gravity vector in the body frame: ``W^T gravity`` (``W``: world <- body)."""
    return (gravity @ W.reshape(3, -1)).reshape(W.shape[1:])


def _gyroscopic(inertia: np.ndarray, w: np.ndarray) -> np.ndarray:
    """The gyroscopic moment ``w x (I w)`` of eq. (19)."""
    return _cross(w, _cmv(inertia, w))


def _body_load(model: Model, i: int, W: np.ndarray, w, wd, a, gravity: bool):  # noqa: N803
    """Body ``i``'s own terms of eq. (18) and (19): ``F = m a_c (- m g)`` and ``I wd + w x (I w) + c x F``; ``w``
    None for a body at rest (the unit motions: no velocity terms). A massless body has no force terms and a body
    without rotational inertia (a point mass) no inertia terms."""
    b = model.bodies[i]
    F = np.zeros_like(a)
    if b.mass:
        a_c = a + _cross(wd, b.com) if w is None else _com_acceleration(a, wd, w, b.com)
        F = b.mass * a_c                                                 # eq. (18): m a_c
        if gravity:
            F = F - b.mass * _body_gravity(W, model.gravity)             # external force m g, moved to the left side
    n = _cross(b.com, F)
    if b.inertia.any():
        n = n + _cmv(b.inertia, wd)                                      # eq. (19)
        if w is not None:
            n = n + _gyroscopic(b.inertia, w)
    return F, n


def _external_loads(model: Model, kin) -> np.ndarray | None:
    """The model's external loads (``cases.loads``) as body loads: (bodies, 6, *B), row ``i`` = ``[force, moment about
    the body origin]`` in body frame ``i`` summed over the loads on body ``i`` (module docstring); None without loads.
    A world-frame vector ``x`` is ``W_i^T x`` in the body; a spring's force is formed in the world from the point
    ``o_i + W_i offset``."""
    if not model.loads:
        return None
    W = kin[2]
    batch = W[0].shape[2:]
    origins = _origins(model, kin) if any(isinstance(x, PointSpring) for x in model.loads) else None
    rows = np.zeros((len(model.bodies), 6) + batch)
    for load in model.loads:
        i = model.body_index(load.body)
        to_body = W[i].swapaxes(0, 1)
        offset = _column(load.offset, batch)
        moment = 0.0
        if isinstance(load, PointSpring):
            d = origins[i] + _mv(W[i], offset) - _column(load.anchor, batch)
            length = np.sqrt((d * d).sum(axis=0))
            stretch = 1.0 if load.rest_length == 0.0 else 1.0 - load.rest_length / length
            f = _mv(to_body, -load.stiffness * stretch * d)
        else:
            world = load.frame == "world"
            f = _mv(to_body, _column(load.force, batch)) if world else _column(load.force, batch)
            if isinstance(load, ExternalWrench):
                moment = _mv(to_body, _column(load.moment, batch)) if world else _column(load.moment, batch)
        rows[i, :3] += f
        rows[i, 3:] += _moment_about_origin(offset, f, moment)
    return rows


def _moment_about_origin(offset, f, couple):
    """The moment about the body origin of a force ``f`` at the body point ``offset`` and a couple: ``couple + offset x
    f`` (body frame)."""
    return couple + _cross(offset, f)


def _external_torques(model: Model, kin, external: np.ndarray) -> np.ndarray:
    """``tau_ext`` (nv, *B): the backward pass of the external body loads alone (no motion, no gravity) is the load
    the joints must apply to hold them, ``-tau_ext``."""
    zero = np.zeros((len(model.bodies), 3) + external.shape[2:])
    return -_joint_torques(model, *_backward(model, kin, (zero, zero, zero), False, external))


def _backward(model: Model, kin, motion, gravity: bool, external: np.ndarray | None = None):
    """Backward pass, tip to base: the joint loads ``f, n`` (n x 3 x *B each), the force and the moment about body
    ``i``'s origin that the parent exerts on body ``i``, in body frame ``i``. Eq. (18) and (19) solved for the
    inboard load; ``external`` (n x 6 (x *B), rows ``[force, moment about the origin]`` in body frame ``i``) are
    further loads applied to the bodies."""
    P, r, W = kin
    w, wd, a = motion
    f, n = [0.0] * len(model.bodies), [0.0] * len(model.bodies)  # the children's loads, summed
    for i in reversed(model.topological_order):
        F, N = _body_load(model, i, W[i], w[i], wd[i], a[i], gravity)
        f[i], n[i] = f[i] + F, n[i] + N
        if external is not None:
            f[i], n[i] = f[i] - external[i, :3], n[i] - external[i, 3:]
        p = model.parent_index[i]
        if p >= 0:                                           # the child pushes back on its parent
            fp = _mv(P[i], f[i])
            f[p] = f[p] + fp
            n[p] = n[p] + _mv(P[i], n[i]) + _cross(r[i], fp)
    return np.array(f), np.array(n)


def _recursion(model: Model, kin, qd: np.ndarray, qdd: np.ndarray, gravity: bool):
    """Both passes of the recursive Newton–Euler algorithm (6.1.3): the joint loads ``f, n``."""
    return _backward(model, kin, _forward(model, kin, qd, qdd), gravity)


def _point_acceleration(kin, motion, body: int, offset: np.ndarray) -> np.ndarray:
    """Classical acceleration (world frame) of the point ``offset`` fixed in ``body``: ``a + wd x r + w x (w x r)``
    of the forward pass, rotated to the world."""
    w, wd, a = (x[body] for x in motion)
    return _mv(kin[2][body], a + _cross(wd, offset) + _cross(w, _cross(w, offset)))


def _task_acceleration(model: Model, kin, motion) -> np.ndarray:
    """Classical acceleration of the default task point in its task coordinates ``D p`` (eq. 23)."""
    tp = model.task_point()
    return tp.directions @ _point_acceleration(kin, motion, model.body_index(tp.body), tp.offset)


def _joint_torques(model: Model, f: np.ndarray, n: np.ndarray) -> np.ndarray:
    """The generalized forces: each joint load projected onto the joint's velocity columns, ``S_w^T n_i + S_v^T
    f_i``, shape (nv, *B): ``axis . n_i`` (revolute) or ``axis . f_i`` (prismatic), the whole moment ``n_i`` about the
    ball's centre (spherical), the whole load ``[f_i, n_i]`` (free: the body wrench, dual of the body twist)."""
    if not model.group_joints:
        return np.array([_cmv(b.axis, n[i] if b.joint == "revolute" else f[i]) for i, b in enumerate(model.bodies)])
    blocks = []
    for i, b in enumerate(model.bodies):
        if b.joint in ("revolute", "prismatic"):
            blocks.append(_cmv(b.axis, n[i] if b.joint == "revolute" else f[i])[None])
        else:
            blocks.append(n[i] if b.joint == "spherical" else np.concatenate([f[i], n[i]]))
    return np.concatenate(blocks)


def inverse_dynamics(model: Model, q, qd, qdd, gravity: bool = True) -> np.ndarray:
    """RNEA: the generalized force ``M qdd + C qd (+ g)`` of eq. (2), from eq. (18) and (19) body by body. ``q`` has
    ``nq`` entries (quaternions for ball and free joints), ``qd`` and ``qdd`` ``nv`` (velocities and their time
    derivatives, module docstring); the result has ``nv``."""
    q, qd, qdd = joint_vectors(model, q, qd, qdd)
    f, n = _recursion(model, _placements(model, q), qd, qdd, gravity)
    return _joint_torques(model, f, n) + _rotor_torques(model, qdd)


def _mass_matrix(model: Model, kin, units) -> np.ndarray:
    """``M`` (n x n x *B): column ``j`` is the backward pass (no gravity, ``w = 0``) of the unit motion ``e_j``.

    Body ``i``'s load under the motions of its path (:func:`_unit_motions`) sums the loads of its subtree; its axis
    component is ``M[i, j]`` for ``j`` on the path, and symmetry gives ``M[j, i]`` (the entries off the paths are
    zero: neither joint moves the other's subtree). A spherical or free joint's rows are the projections ``S_w^T n
    + S_v^T f`` onto its velocity columns (:func:`_subspace`); its own diagonal block is symmetrized (the two
    triangles are the same numbers, formed by different cross products)."""
    P, r, _ = kin
    wd, a = units
    path = _paths(model)
    M = np.zeros((model.nv, model.nv) + r[0].shape[1:])
    f, n = [0.0] * len(model.bodies), [0.0] * len(model.bodies)  # children's loads, parent's motions
    for i in reversed(model.topological_order):
        F, N = _body_load(model, i, None, None, wd[i], a[i], gravity=False)
        f_i, n_i = f[i] + F, n[i] + N
        b, p, k = model.bodies[i], model.parent_index[i], model.v_index[i]
        if b.joint in ("revolute", "prismatic"):
            own = 1
            column = _cmv(b.axis, n_i if b.joint == "revolute" else f_i)
            M[k, path[i]] = column
            M[path[i], k] = column
        else:                                                # S^T [f; n] over the joint's velocity columns
            S_w, S_v = _subspace(b.joint)
            own = S_w.shape[1]
            block = _cmv(S_w.T, n_i) + _cmv(S_v.T, f_i)     # (own, len(path), *B)
            M[k:k + own, path[i]] = block
            M[path[i], k:k + own] = block.swapaxes(0, 1)
            diagonal = block[:, -own:]
            M[k:k + own, k:k + own] = 0.5 * (diagonal + diagonal.swapaxes(0, 1))
        if p >= 0:                                           # the parent does not move under joint i: drop it
            E, r_i = _over_motions(P[i], 2), _over_motions(r[i], 1)
            fp = _mv(E, f_i[:, :-own])
            f[p] = f[p] + fp
            n[p] = n[p] + _mv(E, n_i[:, :-own]) + _cross(r_i, fp)
        if b.armature:                                       # the rotor's torque a vdot_k under vdot = e_k
            for k_own in range(k, k + own):
                M[k_own, k_own] = M[k_own, k_own] + b.armature
    return M


def _rotor_torques(model: Model, qdd: np.ndarray) -> np.ndarray:
    """The torques that accelerate the joints' rotors, ``a_k qdd_k`` per velocity (module docstring, "Armature"):
    what a joint's actuator spends on its rotor before the link feels it."""
    return np.concatenate([np.full(_NV[b.joint], b.armature) for b in model.bodies]) * qdd


def mass_matrix(model: Model, q) -> np.ndarray:
    """``M(q)`` of eq. (2) (nv x nv, ``q`` of ``nq`` entries), column ``j`` = RNEA with ``qd = 0``, no gravity and
    ``qdd = e_j`` (:func:`_mass_matrix`).

    The placements are computed once and shared by the columns."""
    (q,) = joint_vectors(model, q)
    kin = _placements(model, q)
    return _mass_matrix(model, kin, _unit_motions(model, kin))


def joint_reactions(model: Model, q, qd, qdd) -> np.ndarray:
    """Full joint loads (6.1.5), gravity included: row ``i`` = ``[force(3), moment(3)]`` the parent exerts on
    body ``i`` through joint ``i``, moment about the body-frame origin (the joint origin on body ``i``'s side),
    both in body frame ``i`` (one row per body; ``q`` of ``nq`` entries, ``qd`` and ``qdd`` of ``nv``). The actuated
    component (along the axis; the whole moment of a ball joint, the whole load of a free joint) is included. No
    constraint forces: for a constrained model, ``split``'s extras carry the reactions with the loop forces applied."""
    q, qd, qdd = joint_vectors(model, q, qd, qdd)
    return np.hstack(_recursion(model, _placements(model, q), qd, qdd, gravity=True))


def _reactions_in_world(model: Model, kin, reactions: np.ndarray) -> np.ndarray:
    """Body-frame joint loads ``[f, n]`` re-expressed in the world frame, the moment taken about the world origin:
    ``[W f, W n + o x W f]`` with ``o`` the body-frame origin in the world. A change of world frame maps these
    rows as wrenches (article 7.4), while the body-frame rows do not change."""
    W = kin[2]
    out = np.empty_like(reactions)
    for i, origin in enumerate(_origins(model, kin)):
        f, n = W[i] @ reactions[i, :3], W[i] @ reactions[i, 3:]
        out[i] = np.concatenate([f, n + _cross(origin, f)])
    return out


# ----------------------------------------------------------------------------------------------------------
# Constraints (article 5): phi, Jc, Jcdot qd from the recursion's point kinematics, and the loop forces
# ----------------------------------------------------------------------------------------------------------

@dataclass(frozen=True)
class _Rows:
    """One declaration's rows: ``phi`` (rows, *B), ``Jc`` (rows, n, *B), ``Jcdot qd`` (rows, *B), and ``loads``: the
    point forces its multipliers apply, as ``(body index, offset in the body, F)`` with ``F`` (3 x rows) the world
    force per unit multiplier (used for one state)."""

    phi: np.ndarray
    jacobian: np.ndarray
    bias: np.ndarray
    loads: tuple = ()


@dataclass(frozen=True)
class _Point:
    """A point's world position ``p`` (3, *B), Jacobian ``dp/dq`` (3, n, *B) and bias acceleration ``Jdot qd``
    (3, *B); ``body`` is None for a fixed world point."""

    body: int | None
    offset: np.ndarray
    p: np.ndarray
    J: np.ndarray
    a: np.ndarray


def _point_kinematics(model: Model, kin, units, bias_motion) -> Callable[[str | None, np.ndarray], _Point]:
    """``point(body name, offset)``: the kinematics of a body point from the recursion (module docstring); a body
    of None makes ``offset`` a fixed world point. Jacobian column ``j`` is the point's acceleration under the unit
    motion ``e_j`` (``w = 0``: ``W (a + wd x offset)``), zero for the joints off the body's path."""
    origins, path, W = _origins(model, kin), _paths(model), kin[2]
    batch = kin[1][0].shape[1:]

    def point(body: str | None, offset: np.ndarray) -> _Point:
        if body is None:
            return _Point(None, offset, _column(offset, batch), np.zeros((3, model.nv) + batch), np.zeros((3,) + batch))
        i = model.body_index(body)
        J = np.zeros((3, model.nv) + batch)
        J[:, path[i]] = _mv(_over_motions(W[i], 2), units[1][i] + _cross(units[0][i], offset))
        return _Point(i, offset, origins[i] + _mv(W[i], offset), J, _point_acceleration(kin, bias_motion, i, offset))

    return point


def _dot(x: np.ndarray, y: np.ndarray) -> np.ndarray:
    """``x . y`` over the first (component) axis."""
    return (x * y).sum(axis=0)


def _circle(model: Model, c, point, q, qd) -> _Rows:
    """``phi = |P d|^2 - R^2`` with ``d = p - c``: ``Jc = 2 (P d)^T P J``, ``Jcdot qd = 2 |P v|^2 + 2 (P d)^T P a``;
    the force ``2 P^T P d lam`` at the point."""
    x = point(c.body, c.offset)
    d = _cmv(c.plane, x.p - _column(c.center, x.p.shape[1:]))
    grad = _cmv(2.0 * c.plane.T, d)                          # dphi/dp, world
    v = _cmv(c.plane, (x.J * qd[None]).sum(axis=1))
    return _Rows((_dot(d, d) - c.radius**2)[None], _dot(grad[:, None], x.J)[None],
                 (2.0 * _dot(v, v) + _dot(grad, x.a))[None], ((x.body, x.offset, grad[:, None]),))


def _coincide(model: Model, c, point, q, qd) -> _Rows:
    """``phi = D (p_a - p_b)``: ``Jc = D (J_a - J_b)``, ``Jcdot qd = D (a_a - a_b)``; ``D^T lam`` on body a at
    ``p_a``, ``-D^T lam`` on body b at ``p_b`` (nothing when b is the world)."""
    xa, xb = point(c.body_a, c.offset_a), point(c.body_b, c.offset_b)
    D = c.directions
    loads = ((xa.body, xa.offset, D.T),) + (() if xb.body is None else ((xb.body, xb.offset, -D.T),))
    return _Rows(_cmv(D, xa.p - xb.p), _cmv(D, xa.J - xb.J), _cmv(D, xa.a - xb.a), loads)


def _line(model: Model, c, point, q, qd) -> _Rows:
    """``phi = N (p - origin)``: ``Jc = N J``, ``Jcdot qd = N a``; the force ``N^T lam`` at the point."""
    x = point(c.body, c.offset)
    N = c.normals
    return _Rows(_cmv(N, x.p - _column(c.origin, x.p.shape[1:])), _cmv(N, x.J), _cmv(N, x.a),
                 ((x.body, x.offset, N.T),))


def _coupling(model: Model, c, point, q, qd) -> _Rows:
    """``phi = sum_j c_j q_j - offset``: a constant row, no bias, and no point force (a joint torque). The joints are
    revolute or prismatic (``cases.model``), whose coordinate ``q[q_index]`` and velocity ``v[v_index]`` are one."""
    row, row_q = np.zeros(model.nv), np.zeros(model.nq)
    for name, coefficient in zip(c.joints, c.coefficients):
        i = model.body_index(name)
        row[model.v_index[i]] += coefficient
        row_q[model.q_index[i]] += coefficient
    batch = q.shape[1:]
    return _Rows((np.tensordot(row_q, q, axes=1) - c.offset)[None], _column(row[None, :], batch),
                 np.zeros((1,) + batch))


# Pfaffian rows (``cases.constraints``: ``A(q) qd = 0``, no phi; reported phi = 0): ``A`` and ``Adot qd`` from the
# recursion's point kinematics and the body's angular velocity ``w = W w_body`` of the forward pass at ``qdd = 0``,
# its angular Jacobian ``W wd`` of the unit motions and its bias angular acceleration ``W wd`` at ``qdd = 0``.

@dataclass(frozen=True)
class _Spin:
    """A body's world rotation ``W`` (3, 3, *B), angular velocity ``w`` (3, *B), angular Jacobian ``Jw`` (3, n, *B)
    and bias angular acceleration ``wd`` (``Jw_dot qd``, 3, *B), all world frame."""

    W: np.ndarray
    w: np.ndarray
    Jw: np.ndarray
    wd: np.ndarray


def _spin(model: Model, kin, units, bias_motion, body: str) -> _Spin:
    """The angular kinematics of ``body`` (:class:`_Spin`) from the unit motions and the forward pass at qdd = 0."""
    i, W = model.body_index(body), kin[2][model.body_index(body)]
    batch = kin[1][0].shape[1:]
    Jw = np.zeros((3, model.nv) + batch)
    Jw[:, _paths(model)[i]] = _mv(_over_motions(W, 2), units[0][i])
    return _Spin(W, _mv(W, bias_motion[0][i]), Jw, _mv(W, bias_motion[1][i]))


def _zero_phi(rows: int, batch: tuple) -> np.ndarray:
    """The reported ``phi`` of Pfaffian rows: 0 (they have no position-level function)."""
    return np.zeros((rows,) + batch)


def _point_velocity(model: Model, c, point, spin, q, qd) -> _Rows:
    """PointVelocity: ``A = D J``, ``Adot qd = D a`` (D world-fixed); the force ``D^T lam`` at the point."""
    x = point(c.body, c.offset)
    D = c.directions
    return _Rows(_zero_phi(len(D), x.p.shape[1:]), _cmv(D, x.J), _cmv(D, x.a), ((x.body, x.offset, D.T),))


def _knife_edge(model: Model, c, point, spin, q, qd) -> _Rows:
    """KnifeEdge: ``e = W d`` turns with the body, so ``A = e^T J``, ``Adot qd = (w x e) . v + e . a`` with ``v = J
    qd`` the point's velocity; the force ``e lam`` at the point (one state)."""
    x, s = point(c.body, c.offset), spin(c.body)
    e = _mv(s.W, c.direction)
    v = (x.J * qd[None]).sum(axis=1)
    bias = _dot(_cross(s.w, e), v) + _dot(e, x.a)
    return _Rows(_zero_phi(1, x.p.shape[1:]), _dot(e[:, None], x.J)[None], bias[None],
                 ((x.body, x.offset, e[:, None]),))


def _contact_rate(w: np.ndarray, a: np.ndarray, n: np.ndarray, u: np.ndarray, length: np.ndarray) -> np.ndarray:
    """``udot`` of the contact direction ``u = (n - (n.a) a) / length`` as the axle turns (``adot = w x a``): ``(I - u
    u^T) (-(n.adot) a - (n.a) adot) / length``. It follows the ground, not the disk: ``w x u`` would be the rate of a
    body-fixed direction."""
    a_dot = _cross(w, a)
    raw_dot = -_dot(n, a_dot) * a - _dot(n, a) * a_dot
    return (raw_dot - _dot(u, raw_dot) * u) / length


def _rolling(model: Model, c, point, spin, q, qd) -> _Rows:
    """RollingContact: with ``a = W axis``, ``u = (n - (n.a) a) / |.|``, the contact ``p_c = c - r u`` and ``e = p_c
    - c``, the material point at the contact moves with ``v_c + w x e``: ``A = T (J_c + Jw x e)`` (column by
    column). Its time derivative at ``qdd = 0`` is ``T (a_c + wd x e + w x edot)`` with ``edot = -r udot``, ``udot =
    (I - u u^T) wdot / |.|``, ``wdot = -(n.adot) a - (n.a) adot``, ``adot = w x a``: the contact point slides over
    the disk, so it is not the body-fixed point's ``w x (w x e)``. The force ``T^T lam`` at the contact (one
    state: its body-frame offset ``W^T (p_c - o)``)."""
    x, s = point(c.body, c.center), spin(c.body)
    batch = x.p.shape[1:]
    n, T, r = _column(np.cross(c.plane[0], c.plane[1]), batch), c.plane, c.radius
    a = _mv(s.W, c.axis)
    w_raw = n - _dot(n, a) * a
    length = np.sqrt(_dot(w_raw, w_raw))
    u = w_raw / length
    e = -r * u
    J = x.J + _cross(s.Jw, e[:, None])
    acc = x.a + _cross(s.wd, e) + _cross(s.w, -r * _contact_rate(s.w, a, n, u, length))
    if not c.lateral:
        return _rolling_direction(c, x, s, a, n, e, J, acc, qd, batch)
    loads = () if batch else ((x.body, c.center + s.W.T @ e, T.T),)     # p_c - o = W center + e
    return _Rows(_zero_phi(2, batch), _cmv(T, J), _cmv(T, acc), loads)


def _rolling_turn(b: np.ndarray, b_dot: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """``(t, |b|, tdot)`` of the rolling direction ``t = b / |b|`` (``b = a x n``) turning at ``bdot = (w x a) x n``:
    ``tdot = (bdot - t (t . bdot)) / |b|`` (one vector or a batch, components first)."""
    size = np.sqrt(_dot(b, b))
    t = b / size
    return t, size, (b_dot - _dot(t, b_dot) * t) / size


def _rolling_direction(c, x, s, a, n, e, J, acc, qd, batch) -> _Rows:
    """RollingContact with ``lateral=False``: the one row ``t . v_pc`` along the rolling direction ``t = b / |b|``,
    ``b = a x n``, which turns with the axle: ``A = t^T (J_c + Jw x e)`` and ``Adot qd = t . acc + tdot . v_pc`` with
    ``acc`` the contact's rate of :func:`_rolling`, ``v_pc = (J_c + Jw x e) qd``, ``tdot = (bdot - t (t . bdot)) /
    |b|``, ``bdot = (w x a) x n``. The force ``t lam`` at the contact (one state)."""
    t, _, t_dot = _rolling_turn(_cross(a, n), _cross(_cross(s.w, a), n))
    v = (J * qd[None]).sum(axis=1)
    bias = _dot(t, acc) + _dot(t_dot, v)
    loads = () if batch else ((x.body, c.center + s.W.T @ e, t[:, None]),)
    return _Rows(_zero_phi(1, batch), _dot(t[:, None], J)[None], bias[None], loads)


#: The rows of each declaration of ``cases.constraints``, by its type.
_DECLARATIONS = {PointOnCircle: _circle, PointsCoincide: _coincide, PointOnLine: _line, JointCoupling: _coupling}
#: The Pfaffian declarations' rows (they also read the body's angular kinematics).
_PFAFFIAN = {PointVelocity: _point_velocity, KnifeEdge: _knife_edge, RollingContact: _rolling}


def _constraint_rows(model: Model, kin, units, bias_motion, q: np.ndarray, qd: np.ndarray) -> list[_Rows]:
    """The rows of every declaration, in model order."""
    point = _point_kinematics(model, kin, units, bias_motion)
    spin = (lambda body: _spin(model, kin, units, bias_motion, body))  # noqa: E731
    rows = []
    for c in model.constraints:
        if type(c) in _PFAFFIAN:
            rows.append(_PFAFFIAN[type(c)](model, c, point, spin, q, qd))
            continue
        if type(c) not in _DECLARATIONS:
            raise TypeError(f"model '{model.name}': the Newton–Euler backend does not know the constraint "
                            f"declaration {c!r} of type {type(c).__name__}; "
                            f"known: {[t.__name__ for t in (*_DECLARATIONS, *_PFAFFIAN)]}")
        rows.append(_DECLARATIONS[type(c)](model, c, point, q, qd))
    return rows


def _constraint_loads(model: Model, kin, rows: list[_Rows], lam: np.ndarray) -> np.ndarray:
    """The point forces of the multipliers ``lam`` (one state) as external loads on the bodies (n x 6, rows
    ``[force, moment about the body origin]`` in body frame ``i``), for the backward pass."""
    loads, start = np.zeros((len(model.bodies), 6)), 0
    for r in rows:
        part, start = lam[start:start + len(r.phi)], start + len(r.phi)
        for i, offset, F in r.loads:
            f = kin[2][i].T @ (F @ part)
            loads[i, :3] += f
            loads[i, 3:] += _cross(offset, f)
    return loads


# ----------------------------------------------------------------------------------------------------------
# The solves, for a batch of states on the last axis (vectors (n, N), matrices (n, n, N); one state is N = 1)
# ----------------------------------------------------------------------------------------------------------

def _cholesky(model: Model, M: np.ndarray, q: np.ndarray) -> np.ndarray:  # noqa: N803
    """Lower Cholesky factors ``L`` of the mass matrices ``M = L L^T`` (n, n, N) at the configurations ``q`` (n, N),
    column by column (a loop over the joints). A mass matrix that is not positive definite is a ValueError naming
    the model, the first such state's q and the eigenvalues of its M."""
    L = np.zeros_like(M)
    for j in range(len(M)):
        d = M[j, j] - (L[j, :j] ** 2).sum(axis=0)
        if not np.all(d > 0.0):
            bad = int(np.flatnonzero(~(d > 0.0))[0])
            raise ValueError(f"model '{model.name}': the mass matrix is not positive definite at q = "
                             f"{q[:, bad].tolist()} (Cholesky failed at joint {j}); eigenvalues "
                             f"{np.linalg.eigvalsh(M[:, :, bad]).tolist()}")
        L[j, j] = np.sqrt(d)
        L[j + 1:, j] = (M[j + 1:, j] - (L[j + 1:, :j] * L[j, :j][None]).sum(axis=1)) / L[j, j]
    return L


def _lower_solve(L: np.ndarray, b: np.ndarray) -> np.ndarray:  # noqa: N803
    """``L^-1 b`` for the factors ``L`` (n, n, N) and ``b`` (n, m, N): forward substitution (a loop over the joints)."""
    y = np.empty_like(b)
    for i in range(len(L)):
        y[i] = (b[i] - (L[i, :i, None] * y[:i]).sum(axis=0)) / L[i, i]
    return y


def _cho_solve(L: np.ndarray, b: np.ndarray) -> np.ndarray:  # noqa: N803
    """``M^-1 b`` from the factors ``L`` (n, n, N) of ``M = L L^T``, ``b`` (n, m, N): forward then back substitution
    (a loop over the joints)."""
    y, x = _lower_solve(L, b), np.empty_like(b)
    for i in reversed(range(len(L))):
        x[i] = (y[i] - (L[i + 1:, i, None] * x[i + 1:]).sum(axis=0)) / L[i, i]
    return x


def _times(A: np.ndarray, x: np.ndarray) -> np.ndarray:  # noqa: N803
    """``A x`` per state: ``A`` (r, c, N), ``x`` (c, N)."""
    return (A * x[None]).sum(axis=1)


@dataclass(frozen=True)
class _RangeSpace:
    """The range-space (Schur complement) method on the Cholesky factors ``L`` of ``M``, per state: ``X = M^-1 Jc^T``
    and ``S^+`` with ``S = Jc X`` (eigenvalues at or below :func:`_redundant_below` dropped). States on the last
    axis."""

    L: np.ndarray
    Jc: np.ndarray
    bias: np.ndarray
    X: np.ndarray
    S_pinv: np.ndarray

    @classmethod
    def build(cls, model: Model, L: np.ndarray, Jc: np.ndarray, bias: np.ndarray) -> "_RangeSpace":  # noqa: N803
        X = _cho_solve(L, Jc.swapaxes(0, 1))
        S = np.einsum("kin,ijn->nkj", Jc, X)                  # (N, k, k) for eigh
        w, U = np.linalg.eigh(0.5 * (S + S.swapaxes(1, 2)))
        keep = w > _redundant_below(model, w[:, -1:])
        inverse = np.divide(1.0, w, out=np.zeros_like(w), where=keep)
        return cls(L, Jc, bias, X, np.moveaxis((U * inverse[:, None, :]) @ U.swapaxes(1, 2), 0, -1))

    def solve(self, f: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """``(qdd, lam)`` of eq. (12, 13) for the generalized forces ``f`` (n, N): ``lam = S^+ (-Jcdot qd - Jc M^-1
        f)``, ``qdd = M^-1 f + X lam``."""
        a = _cho_solve(self.L, f[:, None])[:, 0]
        lam = _times(self.S_pinv, -self.bias - _times(self.Jc, a))
        return a + _times(self.X, lam), lam

    def input_map(self, tau: np.ndarray) -> np.ndarray:
        """``B_c tau`` of eq. (17): ``M^-1 tau - X S^+ Jc M^-1 tau``."""
        a = _cho_solve(self.L, tau[:, None])[:, 0]
        return a - _times(self.X, _times(self.S_pinv, _times(self.Jc, a)))


# ----------------------------------------------------------------------------------------------------------
# Conditioning and scales, this backend's own (docs/design.md, "Independence is the product"): from the singular values
# of its Cholesky factor L of M and of L^-1 Jc^T (one state)
# ----------------------------------------------------------------------------------------------------------

def _redundant_below(model: Model, w_max):
    """Eigenvalues of ``J M^-1 J^T`` at or below this are not directions (article 5.6): ``CONSTRAINT_RCOND`` times the
    largest ``w_max`` (redundant rows), and never less than ``(DEGENERATE_ROW L)^2 / inertia_scale`` (L the model's
    length scale: a row that vanishes here, which some kinematics round to 1e-17 L instead of 0). ``w_max`` may be an
    array (one per state)."""
    floor = (DEGENERATE_ROW * model.length_scale) ** 2 / model.inertia_scale
    return np.maximum(CONSTRAINT_RCOND * np.asarray(w_max, dtype=float), floor)


@dataclass(frozen=True)
class _MassScales:
    """cond_2(M), ``||M^-1||_2`` and ``accel_scale`` at one state (:func:`_mass_scales`)."""

    cond: float
    inverse_norm: float
    accel_scale: float


def _mass_scales(model: Model, L: np.ndarray, c_qd: np.ndarray, g: np.ndarray, tau: np.ndarray,  # noqa: N803
                 qd: np.ndarray) -> _MassScales:
    """The eigenvalues of ``M = L L^T`` are the squared singular values of its Cholesky factor ``L`` (n, n):
    cond(M) = ``(s_max / s_min)^2``, ``||M|| = s_max^2``, ``||M^-1|| = s_min^-2``. ``accel_scale = ||M^-1|| H`` with
    ``H = |C qd|_1 + |g|_1 + |B u|_1 + ||M|| |qd|^2 + |gravity|_1 sqrt(m_total ||M||)``: the generalized forces summed
    in ``B u - C qd - g``, with configuration-robust sizes of the velocity products and of gravity (a mass times a
    lever arm), since the computed ``C qd`` and ``g`` can cancel while their terms do not. 1-norms, so tiny vectors do
    not underflow."""
    s = np.linalg.svd(L, compute_uv=False)
    largest, smallest = float(s[0]) ** 2, float(s[-1]) ** 2
    m_total = sum(b.mass for b in model.bodies)
    H = (np.abs(c_qd).sum() + np.abs(g).sum() + np.abs(tau).sum() + largest * float(qd @ qd)
         + np.abs(model.gravity).sum() * np.sqrt(m_total * largest))
    return _MassScales(largest / smallest, 1.0 / smallest, float(H) / smallest)


@dataclass(frozen=True)
class _ConstraintScales:
    """The conditioning of ``S = Jc M^-1 Jc^T`` at one state (:func:`_constraint_scales`)."""

    cond_S: float         # largest / smallest eigenvalue of S (inf when S is singular)
    cond_kept: float      # largest / smallest eigenvalue kept (what the multipliers' solve amplifies)
    rank: int
    inconsistency: float  # share of the KKT right-hand sides in S's redundant directions (0 when none)
    lam_scale: float
    force_scale: float    # ||M^-1|| ||Jc|| lam_scale: the accelerations the constraint force can produce


def _eigen_of_schur(L: np.ndarray, Jc: np.ndarray) -> tuple[np.ndarray, np.ndarray]:  # noqa: N803
    """``(w, V)``: the eigenvalues of ``S = X^T X``, ``X = L^-1 Jc^T`` (n, k), in descending order, as the squared
    singular values of ``X`` (zeros beyond the n-th when k > n), and the eigenvectors, the right singular vectors
    (columns of V, k x k)."""
    X = _lower_solve(L[..., None], Jc.T[..., None])[..., 0]
    _, s, Vt = np.linalg.svd(X, full_matrices=True)
    w = np.zeros(len(Jc))
    w[:len(s)] = s**2
    return w, Vt.T


def _constraint_scales(model: Model, L: np.ndarray, Jc: np.ndarray, bias: np.ndarray, forces,  # noqa: N803
                       mass: _MassScales) -> _ConstraintScales:
    """The multipliers solve ``S lam = r``, ``r = -Jcdot qd - Jc M^-1 f`` (``f = B u - h`` and ``-h``: ``forces``).
    Eigenvalues of S at or below :func:`_redundant_below` are redundant directions; ``lam_scale = (|Jcdot qd|_1 + ||Jc||
    accel_scale) / w_kept,min`` bounds the multipliers from the magnitudes summed into r; ``inconsistency = max |V_0^T
    r| / max(|r|, 1e-6 L accel_scale)`` over the right-hand sides, V_0 the redundant eigenvectors: non-zero means
    ``H_t`` is empty (eq. 16; where every row is degenerate r itself is rounding, hence the floor on |r|)."""
    w, V = _eigen_of_schur(L, Jc)
    rank = int((w > _redundant_below(model, w[0])).sum())     # descending: the kept directions come first
    w_max = max(float(w[0]), float(_redundant_below(model, 0.0)))
    jc_norm = float(np.linalg.norm(Jc, 2))
    lam_scale = (np.abs(bias).sum() + jc_norm * mass.accel_scale) / w[rank - 1] if rank else 0.0
    inconsistency = 0.0
    for f in forces if rank < len(w) else ():
        r = -bias - Jc @ _cho_solve(L[..., None], f[:, None, None])[:, 0, 0]
        size = max(float(np.linalg.norm(r)), 1e-6 * model.length_scale * mass.accel_scale)
        if size > 0.0:
            inconsistency = max(inconsistency, float(np.linalg.norm(V[:, rank:].T @ r)) / size)
    return _ConstraintScales(cond_S=w_max / w[-1] if w[-1] > 0.0 else np.inf,
                             cond_kept=w_max / w[rank - 1] if rank else 1.0, rank=rank, inconsistency=inconsistency,
                             lam_scale=float(lam_scale), force_scale=mass.inverse_norm * jc_norm * float(lam_scale))


# ----------------------------------------------------------------------------------------------------------
# The split
# ----------------------------------------------------------------------------------------------------------

def _dynamics(model: Model, q: np.ndarray, qd: np.ndarray):
    """The recursion's terms at ``(q, qd)`` (shapes (n, *B)): placements, unit motions, the forward pass at
    ``qdd = 0``, ``h = C qd + g - tau_ext`` (the RNEA at ``qdd = 0`` with the external loads applied, (n, *B); ``h``
    itself without loads) and ``M`` (n, n, *B)."""
    kin = _placements(model, q)
    units, bias_motion = _unit_motions(model, kin), _forward(model, kin, qd, np.zeros_like(qd))
    h = _joint_torques(model, *_backward(model, kin, bias_motion, True, _external_loads(model, kin)))
    return kin, units, bias_motion, h, _mass_matrix(model, kin, units)


def _constraint_terms(model: Model, kin, units, bias_motion, q, qd) -> tuple[list[_Rows], np.ndarray, np.ndarray]:
    """The rows of every declaration, ``Jc`` (k, n, *B) and ``Jcdot qd`` (k, *B)."""
    rows = _constraint_rows(model, kin, units, bias_motion, q, qd)
    return rows, np.concatenate([r.jacobian for r in rows]), np.concatenate([r.bias for r in rows])


def _extras(model: Model, kin, qd: np.ndarray, total: np.ndarray, drift: np.ndarray, loads=None,
            loads_drift=None):
    """The joint reactions at the total and at the drift (with the external ``loads``, ``loads_drift`` applied),
    the former also in the world frame; and the drift's forward pass (one state)."""
    drift_motion = _forward(model, kin, qd, drift)
    reactions = np.hstack(_backward(model, kin, _forward(model, kin, qd, total), True, loads))
    extras = {"joint_reactions": reactions,
              "joint_reactions_drift": np.hstack(_backward(model, kin, drift_motion, True, loads_drift)),
              "joint_reactions_world": _reactions_in_world(model, kin, reactions)}
    return extras, drift_motion


def _wrenches(extras: dict) -> dict:
    """The compared joint loads (``Split.joint_wrenches``, ``joint_wrenches_drift``): the reactions of
    :func:`_extras` themselves, rows ``[force, moment about the body origin]`` in body frames."""
    return {"joint_wrenches": extras["joint_reactions"], "joint_wrenches_drift": extras["joint_reactions_drift"]}


def split(model: Model, q, qd, u) -> Split:
    """The drift–control split of eq. (9): ``drift = -M^-1 h`` (eq. 10, ZTCF), ``ctrl = M^-1 B u`` solved
    directly, ``total = M^-1 (B u - h)`` solved on its own, with ``h = C qd + g`` from the RNEA at ``qdd = 0``.
    A constrained model goes through the range-space solve of eq. (12)-(17) instead (module docstring). The
    recursion and the solves are those of :func:`split_batch` on a batch of one; the conditioning is this backend's
    own (:func:`_mass_scales`, :func:`_constraint_scales`), the power ``(B u)_i qd_i`` summed.

    extras: ``joint_reactions`` at ``(q, qd, total)`` and ``joint_reactions_drift`` at ``(q, qd, drift)`` (body
    frames; with the constraint forces of ``lam`` and ``lam_drift`` applied), ``joint_reactions_world`` (the former
    in the world frame, moments about the world origin); ``joint_wrenches`` and ``joint_wrenches_drift`` are the
    first two; ``task_drift`` is the default task point's classical acceleration from the forward pass at the drift.
    """
    q, qd, u = check_state(model, q, qd, u)
    kin, units, bias_motion, h, M = _dynamics(model, q, qd)
    zero = np.zeros(model.nv)
    c_qd = _joint_torques(model, *_backward(model, kin, bias_motion, gravity=False))
    external = _external_loads(model, kin)
    g = _joint_torques(model, *_backward(model, kin, _forward(model, kin, zero, zero), True, external))  # g - tau_ext
    L = _cholesky(model, M[..., None], q[:, None])
    tau_ctrl = model.input_map @ u
    tau_ext = None if external is None else _external_torques(model, kin, external)
    mass = _mass_scales(model, L[..., 0], c_qd, g, tau_ctrl if tau_ext is None else np.abs(tau_ctrl) + np.abs(tau_ext),
                        qd)
    power = tau_ctrl * qd
    common = dict(power_ctrl=float(power.sum()), power_ctrl_per_coord=power, cond_M=mass.cond,
                  kinetic_energy=0.5 * qd @ M @ qd, external_force=tau_ext,
                  power_ext=None if tau_ext is None else float(tau_ext @ qd))
    if model.constraints:
        return _constrained_split(model, kin, units, bias_motion, q, qd, h, L, tau_ctrl, mass, common, (g, c_qd),
                                  external)
    drift, ctrl, total, zvcf, drift_velocity = _cho_solve(
        L, np.column_stack([-h, tau_ctrl, tau_ctrl - h, -g, -c_qd])[..., None])[..., 0].T
    extras, drift_motion = _extras(model, kin, qd, total, drift, external, external)
    return Split(drift=drift, ctrl=ctrl, total=total, lam=None, lam_drift=None, power_constr=None,
                 power_constr_per_coord=None, accel_scale=mass.accel_scale, extras=extras,
                 task_drift=_task_acceleration(model, kin, drift_motion), zvcf=zvcf, drift_velocity=drift_velocity,
                 **_wrenches(extras), **common)


def _constrained_split(model: Model, kin, units, bias_motion, q, qd, h, L, tau_ctrl, mass: _MassScales,  # noqa: N803
                       common: dict, parts: tuple, external: np.ndarray | None = None) -> Split:
    """Eq. (12)-(17) by the range-space method (a batch of one), the reactions with the loop forces applied, and the
    constraint's own quantities (article 5.5): ``Jc^T lam`` and its power ``(Jc^T lam)_i qd_i``, ``Jc qd`` and the
    conditioning of S; ``accel_scale`` adds what the constraint force can produce. The drift's parts (4.5-4.6) are
    the same solve with ``f = -g`` and no bias (``zvcf``) and with ``f = -C qd`` and the bias ``Jcdot qd``
    (``drift_velocity``); ``parts = (g, C qd)``, ``h`` and ``g`` with the external loads applied (``- tau_ext``), whose
    body loads ``external`` the reactions carry too."""
    rows, Jc, bias = _constraint_terms(model, kin, units, bias_motion, q, qd)
    schur = _RangeSpace.build(model, L, Jc[..., None], bias[..., None])
    (total, lam), (drift, lam_drift) = (x[:, 0] for x in schur.solve((tau_ctrl - h)[:, None])), (
        x[:, 0] for x in schur.solve(-h[:, None]))                                      # eq. (12, 13), (14)
    g, c_qd = parts
    zvcf = replace(schur, bias=np.zeros_like(schur.bias)).solve(-g[:, None])[0][:, 0]
    drift_velocity = schur.solve(-c_qd[:, None])[0][:, 0]
    applied = 0.0 if external is None else external
    extras, drift_motion = _extras(model, kin, qd, total, drift, _constraint_loads(model, kin, rows, lam) + applied,
                                   _constraint_loads(model, kin, rows, lam_drift) + applied)
    cs = _constraint_scales(model, L[..., 0], Jc, bias, (tau_ctrl - h, -h), mass)
    force = Jc.T @ lam
    power = force * qd
    return Split(drift=drift, ctrl=schur.input_map(tau_ctrl[:, None])[:, 0], total=total, lam=lam,
                 lam_drift=lam_drift, power_constr=float(power.sum()), power_constr_per_coord=power,
                 accel_scale=mass.accel_scale + cs.force_scale, extras=extras,
                 task_drift=_task_acceleration(model, kin, drift_motion), zvcf=zvcf, drift_velocity=drift_velocity,
                 conditions={"constraint": cs.cond_S, "constraint_consistency": cs.inconsistency,
                             "constraint_kept": cs.cond_kept},
                 constraint_value=np.concatenate([r.phi for r in rows]), constraint_jacobian=Jc, constraint_bias=bias,
                 constraint_velocity=Jc @ qd, constraint_force=force, constraint_force_drift=Jc.T @ lam_drift,
                 constraint_rank=cs.rank, lam_scale=cs.lam_scale, **_wrenches(extras), **common)


def _split_block(model: Model, Q: np.ndarray, QD: np.ndarray, U: np.ndarray) -> SplitBatch:  # noqa: N803
    """:func:`split_batch` on one block of states (rows of ``Q``, ``QD``, ``U``)."""
    q, qd = np.ascontiguousarray(Q.T), np.ascontiguousarray(QD.T)
    kin, units, bias_motion, h, M = _dynamics(model, q, qd)
    L, tau = _cholesky(model, M, q), model.input_map @ U.T
    if not model.constraints:
        drift, ctrl, total = _cho_solve(L, np.stack([-h, tau, tau - h], axis=1)).transpose(1, 2, 0)
        return SplitBatch(drift, ctrl, total)
    _, Jc, bias = _constraint_terms(model, kin, units, bias_motion, q, qd)
    schur = _RangeSpace.build(model, L, Jc, bias)
    (total, lam), (drift, lam_drift) = schur.solve(tau - h), schur.solve(-h)             # eq. (12, 13), (14)
    return SplitBatch(drift.T, schur.input_map(tau).T, total.T, lam.T, lam_drift.T)


def split_batch(model: Model, Q, QD, U) -> SplitBatch:  # noqa: N803
    """The split of N states at once (rows of ``Q``, ``QD``, ``U``; :class:`SplitBatch`): the recursion of
    :func:`split` with the states on a trailing axis of every 3-vector, in blocks of :data:`BLOCK` states, and the
    same solves per state; rows equal ``split``'s."""
    Q, QD, U = check_batch(model, Q, QD, U)
    blocks = [_split_block(model, Q[s:s + BLOCK], QD[s:s + BLOCK], U[s:s + BLOCK])
              for s in range(0, len(Q), BLOCK)]
    if not blocks:
        lam = (np.zeros((0, model.k)),) * 2 if model.k else (None, None)
        return SplitBatch(np.zeros((0, model.nv)), np.zeros((0, model.nv)), np.zeros((0, model.nv)), *lam)
    stack = (lambda name: None if getattr(blocks[0], name) is None
             else np.concatenate([getattr(b, name) for b in blocks]))
    return SplitBatch(*(stack(name) for name in ("drift", "ctrl", "total", "lam", "lam_drift")))


# ----------------------------------------------------------------------------------------------------------
# Linearization (article 4.8, eq. 11): the recursion's own passes differentiated in forward mode, one state, all
# 2 nv state directions at once on a trailing axis (D): q directions ``q (+) s e_j`` first, then v directions
# ----------------------------------------------------------------------------------------------------------

@dataclass(frozen=True)
class _Tangents:
    """Per body, one state: the placement's tangents and the forward pass with its tangents at ``(qd, qdd)``.

    ``th`` (3, D) the rotation of the body's own joint (body frame): ``d P_i = P_i [th_i]x``; ``dr`` (3, D) the
    change of the body origin in the parent frame; ``Th`` (3, D) the body's whole rotation, ``d W_i = W_i [Th_i]x``
    (``Th_i = P_i^T Th_parent + th_i``); ``o``, ``do`` the origin's world position and its tangent. ``motion`` is
    ``(w, wd, a)`` of :func:`_forward`, ``V`` the origin's velocity (body frame), and ``dw, dwd, da, dV`` their
    tangents (3, D)."""

    th: list
    dr: list
    Th: list
    o: list
    do: list
    motion: tuple
    V: list
    dw: list
    dwd: list
    da: list
    dV: list


def _joint_tangent(model: Model, kin, i: int, directions: int) -> tuple[np.ndarray, np.ndarray]:
    """``(th_i, dr_i)``: ``q_i (+) e`` moves body ``i``'s frame by the rotation ``S_w e`` and the origin by ``S_v e``
    (body frame; :func:`_subspace`, the axis for a 1-DOF joint), so ``dP_i = P_i [S_w e]x``, ``dr_i = P_i S_v e`` (a
    free joint: ``dp = R(quat) e_lin``, the first order of ``integrate``), nonzero in the body's own q columns."""
    b, k = model.bodies[i], model.v_index[i]
    if b.joint in ("revolute", "prismatic"):
        axis, zero = b.axis[:, None], np.zeros((3, 1))
        S_w, S_v = (axis, zero) if b.joint == "revolute" else (zero, axis)
    else:
        S_w, S_v = _subspace(b.joint)
    th, dr = np.zeros((3, directions)), np.zeros((3, directions))
    th[:, k:k + S_w.shape[1]] = S_w
    dr[:, k:k + S_w.shape[1]] = kin[0][i] @ S_v
    return th, dr


def _rotated(E: np.ndarray, th: np.ndarray, x: np.ndarray, dx: np.ndarray) -> tuple:  # noqa: N803
    """``E x`` (``E = P_i^T``: body <- parent) and its tangent ``E dx + (E x) x th_i`` (``dE = -[th_i]x E``)."""
    Ex = E @ x
    return Ex, E @ dx + _cross(Ex, th)


def _joint_step_tangents(b, k: int, qd: np.ndarray, dqd: np.ndarray, w_in, dw_in, dwd_in, da_origin, V_in, dV_in,
                         w_i: np.ndarray) -> tuple:
    """The joint's own lines of :func:`_forward` (and :func:`_group_motion`) differentiated at fixed ``qdd``: the
    tangents ``(dw, dwd, da)`` of body ``b`` and its origin velocity ``V`` with its tangent, from the inboard terms
    (``w_in``, ``V_in`` and the tangents of ``w_in``, ``wd_in``, ``a_origin``, ``V_in``); ``w_i`` the body's ``w``. The
    joint's velocity block moves only along the v directions (``dqd``)."""
    if b.joint in ("revolute", "prismatic"):
        s, ds = b.axis * qd[k], np.multiply.outer(b.axis, dqd[k])
        if b.joint == "revolute":                            # w = w_in + s, wd = wd_in + axis qdd + w_in x s
            return dw_in + ds, dwd_in + _cross(dw_in, s) + _cross(w_in, ds), da_origin, V_in, dV_in
        return (dw_in, dwd_in, da_origin + 2.0 * (_cross(dw_in, s) + _cross(w_in, ds)),   # a += 2 w x s + axis qdd
                V_in + s, dV_in + ds)
    S_w, S_v = _subspace(b.joint)
    block = slice(k, k + S_w.shape[1])
    w_rel, v_lin, dw_rel, dv_lin = S_w @ qd[block], S_v @ qd[block], S_w @ dqd[block], S_v @ dqd[block]
    dw = dw_in + dw_rel
    return (dw, dwd_in + _cross(dw_in, w_rel) + _cross(w_in, dw_rel),
            da_origin + _cross(dw_in + dw, v_lin) + _cross(w_in + w_i, dv_lin), V_in + v_lin, dV_in + dv_lin)


def _forward_tangents(model: Model, kin, qd: np.ndarray, qdd: np.ndarray) -> _Tangents:
    """:func:`_forward` at ``(qd, qdd)`` (``qdd`` held fixed) and its tangents along the 2 nv state directions, each
    line of the pass differentiated by the product rule (:func:`_rotated` for the parent's terms moved into the body
    frame, :func:`_joint_step_tangents` for the joint's own); the origin velocity follows ``V_i = E (V_p + w_p x r_i)
    + S_v v_i`` (its time derivative is the pass's ``a``), the origin ``o_i = o_p + W_p r_i``."""
    P, r, W = kin
    nb, nv = len(model.bodies), model.nv
    w, wd, a = _forward(model, kin, qd, qdd)
    dqd = np.hstack([np.zeros((nv, nv)), np.eye(nv)])                  # the v directions move qd
    th, dr, Th, o, do = ([None] * nb for _ in range(5))
    V, dw, dwd, da, dV = ([None] * nb for _ in range(5))
    zero, dzero = np.zeros(3), np.zeros((3, 2 * nv))
    for i in model.topological_order:
        p = model.parent_index[i]
        th[i], dr[i] = _joint_tangent(model, kin, i, 2 * nv)
        if p < 0:
            w_p = wd_p = a_p = V_p = o_p = zero
            dw_p = dwd_p = da_p = dV_p = Th_p = do_p = dzero
            W_p = np.eye(3)
        else:
            w_p, wd_p, a_p, V_p, o_p, W_p = w[p], wd[p], a[p], V[p], o[p], W[p]
            dw_p, dwd_p, da_p, dV_p, Th_p, do_p = dw[p], dwd[p], da[p], dV[p], Th[p], do[p]
        E, r_i, dr_i = P[i].T, r[i], dr[i]
        Th[i] = E @ Th_p + th[i]
        o[i], do[i] = o_p + W_p @ r_i, do_p + W_p @ (_cross(Th_p, r_i) + dr_i)
        wxr = _cross(w_p, r_i)
        w_in, dw_in = _rotated(E, th[i], w_p, dw_p)
        _, dwd_in = _rotated(E, th[i], wd_p, dwd_p)
        _, da_origin = _rotated(E, th[i], a_p + _cross(wd_p, r_i) + _cross(w_p, wxr),
                                da_p + _cross(dwd_p, r_i) + _cross(wd_p, dr_i) + _cross(dw_p, wxr)
                                + _cross(w_p, _cross(dw_p, r_i) + _cross(w_p, dr_i)))
        V_in, dV_in = _rotated(E, th[i], V_p + wxr, dV_p + _cross(dw_p, r_i) + _cross(w_p, dr_i))
        dw[i], dwd[i], da[i], V[i], dV[i] = _joint_step_tangents(
            model.bodies[i], model.v_index[i], qd, dqd, w_in, dw_in, dwd_in, da_origin, V_in, dV_in, w[i])
    return _Tangents(th, dr, Th, o, do, (w, wd, a), V, dw, dwd, da, dV)


def _backward_tangents(model: Model, kin, t: _Tangents, loads=None, couples=None) -> tuple[np.ndarray, np.ndarray]:
    """The tangents (bodies, 3, D) of :func:`_backward` (gravity applied) along the directions of ``t``: eq. (18),
    (19) and the transfer to the parent differentiated, with ``d(W^T g) = (W^T g) x Th`` and ``dP x = P (th x x)``.
    ``loads`` (body -> ``[(offset, f, df)]`` or ``[(offset, f, df, doffset)]``: a force ``f`` at the body point
    ``offset``, its moment about the origin ``offset x f``, body frame; ``doffset`` the offset's tangent where the
    point moves over the body, a rolling contact) are the multipliers' point forces (:func:`_constraint_tangents`) and
    the external loads' forces, ``couples`` (body -> ``[(m, dm)]``) the external couples
    (:func:`_external_tangents`)."""
    P, r, W = kin
    w, wd, a = t.motion
    nb = len(model.bodies)
    f, n = [0.0] * nb, [0.0] * nb
    df, dn = [0.0] * nb, [0.0] * nb
    for i in reversed(model.topological_order):
        b = model.bodies[i]
        F, N = _body_load(model, i, W[i], w[i], wd[i], a[i], gravity=True)
        c, inertia = b.com, b.inertia
        wxc = _cross(w[i], c)
        da_c = t.da[i] + _cross(t.dwd[i], c) + _cross(t.dw[i], wxc) + _cross(w[i], _cross(t.dw[i], c))
        dF = b.mass * (da_c - _cross(_body_gravity(W[i], model.gravity), t.Th[i]))
        dN = (_cross(c, dF) + inertia @ t.dwd[i] + _cross(t.dw[i], inertia @ w[i])
              + _cross(w[i], inertia @ t.dw[i]))
        f[i], n[i], df[i], dn[i] = f[i] + F, n[i] + N, df[i] + dF, dn[i] + dN
        for offset, fe, dfe, *moving in (loads or {}).get(i, ()):
            doffset = moving[0] if moving else None
            f[i], n[i] = f[i] - fe, n[i] - _cross(offset, fe)
            df[i], dn[i] = df[i] - dfe, dn[i] - _cross(offset, dfe)
            if doffset is not None:                  # a point that moves over the body (a rolling contact)
                dn[i] = dn[i] - _cross(doffset, fe[:, None])
        for me, dme in (couples or {}).get(i, ()):
            n[i], dn[i] = n[i] - me, dn[i] - dme
        p = model.parent_index[i]
        if p >= 0:
            fp, dfp = P[i] @ f[i], P[i] @ (df[i] + _cross(t.th[i], f[i]))
            f[p], df[p] = f[p] + fp, df[p] + dfp
            n[p] = n[p] + P[i] @ n[i] + _cross(r[i], fp)
            dn[p] = dn[p] + P[i] @ (dn[i] + _cross(t.th[i], n[i])) + _cross(t.dr[i], fp) + _cross(r[i], dfp)
    return np.array(df), np.array(dn)


@dataclass(frozen=True)
class _PointTangent:
    """A body point's world position, velocity and classical acceleration at ``(qd, qdd)`` and their tangents (3, D):
    ``p = o + W x``, ``pv = W (V + w x x)``, ``acc = W (a + wd x x + w x (w x x))`` (:func:`_point_acceleration`),
    each ``d(W y) = W (Th x y + dy)``. A world point (body None) is fixed: zero tangents."""

    body: int | None
    offset: np.ndarray
    p: np.ndarray
    dp: np.ndarray
    pv: np.ndarray
    dpv: np.ndarray
    acc: np.ndarray
    dacc: np.ndarray


def _point_tangent(kin, t: _Tangents, body: int | None, offset: np.ndarray) -> _PointTangent:
    """:class:`_PointTangent` of the point ``offset`` of ``body`` (an index, None for the world)."""
    if body is None:
        zero, dzero = np.zeros(3), np.zeros((3, t.th[0].shape[1]))
        return _PointTangent(None, offset, offset, dzero, zero, dzero, zero, dzero)
    W, (w, wd, a) = kin[2][body], (x[body] for x in t.motion)
    wxo, Th = _cross(w, offset), t.Th[body]
    y = a + _cross(wd, offset) + _cross(w, wxo)
    dy = t.da[body] + _cross(t.dwd[body], offset) + _cross(t.dw[body], wxo) + _cross(w, _cross(t.dw[body], offset))
    z, dz = t.V[body] + wxo, t.dV[body] + _cross(t.dw[body], offset)
    return _PointTangent(body, offset, t.o[body] + W @ offset, t.do[body] + W @ _cross(Th, offset), W @ z,
                         W @ (_cross(Th, z) + dz), W @ y, W @ (_cross(Th, y) + dy))


def _circle_tangent(model: Model, c, point):
    """:func:`_circle` differentiated: ``c = Jc qdd + Jcdot qd = 2 |P pv|^2 + grad . acc`` with ``grad = 2 P^T P (p -
    center)``, so ``dc = 4 (P pv) . (P dpv) + dgrad . acc + grad . dacc``, ``dgrad = 2 P^T P dp``; the force ``grad
    lam`` at the point changes by ``dgrad lam``."""
    x = point(c.body, c.offset)
    gram = c.plane.T @ c.plane
    grad, dgrad = 2.0 * gram @ (x.p - c.center), 2.0 * gram @ x.dp
    dc = 4.0 * (c.plane @ x.pv) @ (c.plane @ x.dpv) + x.acc @ dgrad + grad @ x.dacc
    return dc[None], ((x, grad[:, None], dgrad[:, None]),)


def _coincide_tangent(model: Model, c, point):
    """:func:`_coincide` differentiated: ``dc = D (dacc_a - dacc_b)``; the forces ``+-D^T lam`` are constant."""
    xa, xb = point(c.body_a, c.offset_a), point(c.body_b, c.offset_b)
    D, none = c.directions, np.zeros((3, len(c.directions), xa.dp.shape[1]))
    return c.directions @ (xa.dacc - xb.dacc), ((xa, D.T, none), (xb, -D.T, none))


def _line_tangent(model: Model, c, point):
    """:func:`_line` differentiated: ``dc = N dacc``; the force ``N^T lam`` is constant."""
    x = point(c.body, c.offset)
    return c.normals @ x.dacc, ((x, c.normals.T, np.zeros(c.normals.T.shape + x.dp.shape[1:])),)


def _coupling_tangent(model: Model, c, point):
    """:func:`_coupling` differentiated: a constant row, ``dc = 0``, no point force."""
    return np.zeros((1, 2 * model.nv)), ()


#: The derivative of each declaration's rows (``dc`` of ``Jc qdd + Jcdot qd`` and the point forces), by its type.
_TANGENTS = {PointOnCircle: _circle_tangent, PointsCoincide: _coincide_tangent, PointOnLine: _line_tangent,
             JointCoupling: _coupling_tangent}


@dataclass(frozen=True)
class _SpinTangent:
    """A body's world rotation ``W``, its tangent ``Th`` (``dW = W [Th]x``), and its world angular velocity ``w`` and
    angular acceleration ``wd`` at ``(qd, qdd)`` with their tangents (3, D): ``d(W y) = W (Th x y + dy)``."""

    W: np.ndarray
    Th: np.ndarray
    w: np.ndarray
    dw: np.ndarray
    wd: np.ndarray
    dwd: np.ndarray


def _spin_tangent(kin, t: _Tangents, body: int) -> _SpinTangent:
    """:class:`_SpinTangent` of ``body`` from the forward pass's tangents."""
    W, Th, w, wd = kin[2][body], t.Th[body], t.motion[0][body], t.motion[1][body]
    return _SpinTangent(W, Th, W @ w, W @ (_cross(Th, w) + t.dw[body]), W @ wd, W @ (_cross(Th, wd) + t.dwd[body]))


@dataclass(frozen=True)
class _MovingPoint:
    """A load's point whose body-frame ``offset`` changes with the state (a rolling contact): ``doffset`` (3, D)."""

    body: int
    offset: np.ndarray
    doffset: np.ndarray


def _along(x: np.ndarray, dy: np.ndarray) -> np.ndarray:
    """``x . dy`` (D,) of a vector (3,) and a tangent (3, D)."""
    return x @ dy


def _point_velocity_tangent(model: Model, c, point, spin):
    """:func:`_point_velocity` differentiated: ``dc = D dacc``; the force ``D^T lam`` is constant."""
    x = point(c.body, c.offset)
    D = c.directions
    return D @ x.dacc, ((x, D.T, np.zeros(D.T.shape + x.dp.shape[1:])),)


def _knife_edge_tangent(model: Model, c, point, spin):
    """:func:`_knife_edge` differentiated: ``c = (w x e) . pv + e . acc`` with ``e = W d`` (``de = W (Th x d)``), so
    ``dc = (dw x e + w x de) . pv + (w x e) . dpv + de . acc + e . dacc``; the force ``e lam`` turns: ``de lam``."""
    x, s = point(c.body, c.offset), spin(model.body_index(c.body))
    e, de = s.W @ c.direction, s.W @ _cross(s.Th, c.direction)
    we = _cross(s.w, e)
    dwe = _cross(s.dw, e[:, None]) + _cross(s.w[:, None], de)
    dc = (dwe * x.pv[:, None]).sum(axis=0) + _along(we, x.dpv) + _along(x.acc, de) + _along(e, x.dacc)
    return dc[None], ((x, e[:, None], de[:, None, :]),)


def _rolling_tangent(model: Model, c, point, spin):
    """:func:`_rolling` differentiated: ``c = T (a_c + wd x e + w x edot)`` at the ``qdd`` of the tangents, with the
    contact terms of :func:`_contact_rate` differentiated by the chain rule (``a = W axis``, ``raw = n - (n.a) a``,
    ``u = raw / |raw|``, ``e = -r u``, ``adot = w x a``, ``edot = -r (I - u u^T) rawdot / |raw|``); the force ``T^T
    lam`` is constant, its point (the contact, ``center + W^T e`` in the body) moves: ``d(W^T e) = W^T de - Th x W^T
    e``. With ``lateral=False`` the row ``t . acc + tdot . v_pc`` (:func:`_rolling_direction`) is differentiated
    factor by factor, and its force ``t lam`` turns with the axle: ``dt = (db - t (t . db)) / |b|``, ``db = da x n``."""
    i = model.body_index(c.body)
    x, s = point(c.body, c.center), spin(i)
    n, r, col = np.cross(c.plane[0], c.plane[1]), c.radius, (lambda v: v[:, None])  # noqa: E731
    a, da = s.W @ c.axis, s.W @ _cross(s.Th, c.axis)
    raw, draw = n - (n @ a) * a, -col(a) * (n @ da) - (n @ a) * da
    length = float(np.sqrt(raw @ raw))
    u = raw / length
    dlength = u @ draw
    du = (draw - col(u) * (u @ draw)) / length
    a_dot = _cross(s.w, a)
    da_dot = _cross(s.dw, col(a)) + _cross(col(s.w), da)
    raw_dot = -(n @ a_dot) * a - (n @ a) * a_dot
    draw_dot = -col(a) * (n @ da_dot) - col(a_dot) * (n @ da) - (n @ a_dot) * da - (n @ a) * da_dot
    u_dot = (raw_dot - u * (u @ raw_dot)) / length
    du_dot = ((draw_dot - du * (u @ raw_dot) - col(u) * (raw_dot @ du + u @ draw_dot)) / length
              - col(u_dot) * dlength / length)
    e, de, e_dot, de_dot = -r * u, -r * du, -r * u_dot, -r * du_dot
    dacc = (x.dacc + _cross(s.dwd, col(e)) + _cross(col(s.wd), de) + _cross(s.dw, col(e_dot))
            + _cross(col(s.w), de_dot))
    local = s.W.T @ e
    contact = _MovingPoint(i, c.center + local, s.W.T @ de - _cross(s.Th, col(local)))
    if not c.lateral:
        # the rolling direction alone (:func:`_rolling_direction`): c = t . acc + tdot . v_pc, with b = a x n, t = b /
        # |b|, bdot = adot x n, tdot = (bdot - t (t . bdot)) / |b|, every factor differentiated
        acc = x.acc + _cross(s.wd, e) + _cross(s.w, e_dot)
        v, dv = x.pv + _cross(s.w, e), x.dpv + _cross(s.dw, col(e)) + _cross(col(s.w), de)
        b, db = _cross(a, n), _cross(da, col(n))
        b_dot, db_dot = _cross(a_dot, n), _cross(da_dot, col(n))
        t, size, t_dot = _rolling_turn(b, b_dot)
        dsize = t @ db
        dt = (db - col(t) * (t @ db)) / size
        dt_dot = ((db_dot - dt * (t @ b_dot) - col(t) * (b_dot @ dt + t @ db_dot)) / size
                  - col(t_dot) * dsize / size)
        dc = acc @ dt + t @ dacc + v @ dt_dot + t_dot @ dv
        return dc[None], ((contact, col(t), dt[:, None, :]),)
    return c.plane @ dacc, ((contact, c.plane.T, np.zeros(c.plane.T.shape + x.dp.shape[1:])),)


#: The Pfaffian declarations' derivatives (they also read the body's angular kinematics and its tangents).
_PFAFFIAN_TANGENTS = {PointVelocity: _point_velocity_tangent, KnifeEdge: _knife_edge_tangent,
                      RollingContact: _rolling_tangent}


def _constraint_tangents(model: Model, kin, t: _Tangents, lam: np.ndarray):
    """``dc`` (k, D), the tangents of ``Jc qdd + Jcdot qd`` at the ``qdd`` of ``t`` (every declaration's rows
    differentiated, :data:`_TANGENTS`, :data:`_PFAFFIAN_TANGENTS`), and the multipliers' point forces as body loads
    with their tangents: body -> ``[(offset, f, df, doffset)]``, ``f = W^T F lam`` in the body frame, ``df = f x Th +
    W^T dF lam``, ``doffset`` the tangent of a moving point's offset (None for a body-fixed point)."""
    point = (lambda name, offset: _point_tangent(kin, t, None if name is None else model.body_index(name), offset))
    spin = (lambda body: _spin_tangent(kin, t, body))  # noqa: E731
    rows, loads, start = [], {}, 0
    for c in model.constraints:
        dc, forces = (_PFAFFIAN_TANGENTS[type(c)](model, c, point, spin) if type(c) in _PFAFFIAN_TANGENTS
                      else _TANGENTS[type(c)](model, c, point))
        part, start = lam[start:start + len(dc)], start + len(dc)
        for x, F, dF in forces:
            if x.body is not None:
                W = kin[2][x.body]
                f = W.T @ (F @ part)
                loads.setdefault(x.body, []).append(
                    (x.offset, f, _cross(f, t.Th[x.body]) + W.T @ np.einsum("rjd,j->rd", dF, part),
                     getattr(x, "doffset", None)))
        rows.append(dc)
    return np.concatenate(rows), loads


def _external_tangents(model: Model, kin, t: _Tangents) -> tuple[dict, dict]:
    """The external loads (``cases.loads``) with their tangents along the directions of ``t``, for
    :func:`_backward_tangents`: forces body -> ``[(offset, f, df)]`` and couples body -> ``[(m, dm)]``, body frame. A
    world vector ``x`` is ``W^T x`` there, whose tangent is ``(W^T x) x Th`` (the body turns under it); a body-frame
    vector is constant; a spring's world force ``F = -k (1 - L0 / |d|) d`` (``d = p - anchor``) changes with the
    point, ``dF = -k [(1 - L0 / |d|) dd + L0 (d . dd) d / |d|^3]`` with ``dd = dp`` (:func:`_point_tangent`)."""
    forces, couples = {}, {}
    W = kin[2]
    for load in model.loads:
        i = model.body_index(load.body)
        offset = np.asarray(load.offset, dtype=float)
        if isinstance(load, PointSpring):
            x = _point_tangent(kin, t, i, offset)
            d, dd = x.p - load.anchor, x.dp
            length = float(np.sqrt(d @ d))
            if load.rest_length:
                F = -load.stiffness * (1.0 - load.rest_length / length) * d
                dF = -load.stiffness * ((1.0 - load.rest_length / length) * dd
                                        + load.rest_length * np.outer(d, d @ dd) / length**3)
            else:
                F, dF = -load.stiffness * d, -load.stiffness * dd
            f = W[i].T @ F
            forces.setdefault(i, []).append((offset, f, _cross(f, t.Th[i]) + W[i].T @ dF))
            continue
        world = load.frame == "world"
        f = W[i].T @ load.force if world else np.asarray(load.force, dtype=float)
        df = _cross(f, t.Th[i]) if world else np.zeros_like(t.Th[i])
        forces.setdefault(i, []).append((offset, f, df))
        if isinstance(load, ExternalWrench):
            m = W[i].T @ load.moment if world else np.asarray(load.moment, dtype=float)
            couples.setdefault(i, []).append((m, _cross(m, t.Th[i]) if world else np.zeros_like(t.Th[i])))
    return forces, couples


def linearize(model: Model, q, qd, u) -> Linearization:
    """A and B of eq. (11) (:class:`Linearization`, the tangent-space convention on Lie groups) from the recursion's
    own derivatives: the forward and backward passes differentiated in forward mode along all ``2 nv`` state
    directions at once (:func:`_forward_tangents`, :func:`_backward_tangents`), at ``qdd = vdot`` held fixed.

    Unconstrained: ``ID(q, qd, vdot) = B u``, so ``dvdot/dx = -M^-1 dID/dx`` and ``dvdot/du = M^-1 B`` (the Cholesky
    factor of :func:`split`). Constrained (eq. 12, 13): the KKT system differentiated, ``M dvdot - Jc^T dlam = -dG``,
    ``Jc dvdot = -dc``, with ``G = ID(q, qd, vdot) - Jc^T lam`` (the backward pass with the multipliers' point forces
    applied, :func:`_constraint_tangents`, ``lam`` held fixed) and ``c = Jc vdot + Jcdot qd`` (the rows' point
    accelerations), solved by the range-space method of the split with its rank rule; ``dvdot/du = B_c B`` (eq. 17)."""
    q, qd, u = check_state(model, q, qd, u)
    kin, units, bias_motion, h, M = _dynamics(model, q, qd)
    L = _cholesky(model, M[..., None], q[:, None])
    tau = model.input_map @ u
    if model.constraints:
        _, Jc, bias = _constraint_terms(model, kin, units, bias_motion, q, qd)
        schur = _RangeSpace.build(model, L, Jc[..., None], bias[..., None])
        vdot, lam = (x[:, 0] for x in schur.solve((tau - h)[:, None]))
        t = _forward_tangents(model, kin, qd, vdot)
        dc, loads = _constraint_tangents(model, kin, t, lam)
        applied, couples = _external_tangents(model, kin, t)
        for body, entries in applied.items():
            loads.setdefault(body, []).extend(entries)
        dG = _joint_torques(model, *_backward_tangents(model, kin, t, loads, couples))
        dvdot, dvdot_du = replace(schur, bias=dc).solve(-dG)[0], schur.input_map(model.input_map)
    else:
        vdot = _cho_solve(L, (tau - h)[:, None, None])[:, 0, 0]
        t = _forward_tangents(model, kin, qd, vdot)
        dID = _joint_torques(model, *_backward_tangents(model, kin, t, *_external_tangents(model, kin, t)))
        dvdot, dvdot_du = -_cho_solve(L, dID[..., None])[..., 0], _cho_solve(L, model.input_map[..., None])[..., 0]
    return state_space(model, qd, dvdot[:, :model.nv], dvdot[:, model.nv:], dvdot_du, vdot)


FORMALISM = Formalism(
    name="newton_euler",
    summary="Recursive Newton–Euler in body frames (article 6.1, eqs. 18-19): 3-vector force balance per body",
    split=split,
    split_batch=split_batch,
    linearize=linearize,
)
