"""Newton–Euler formalism (article section 6.1): body-by-body force balance in classical 3-vector form.

Every quantity of body ``i`` is expressed in body frame ``i`` (frames: ``cases.model``). The recursion is the
article's two-pass algorithm (6.1.3):

* forward pass, base to tip: angular velocity ``w``, angular acceleration ``wd`` and the acceleration ``a`` of
  the body-frame origin, then the COM acceleration ``a_c = a + wd x c + w x (w x c)``;
* backward pass, tip to base: Newton (eq. 18) ``f = m a_c - m g + sum children`` and Euler (eq. 19)
  ``n = I wd + w x (I w) + c x (m a_c - m g) + sum children`` about the body-frame origin, with gravity applied
  to every body as the external force ``m g`` (no "accelerating base" trick). ``(f, n)`` is the load the parent
  exerts on the body through its joint; the joint torque is its component along the joint axis.

The drift–control split (eq. 9, 10) solves ``M qdd = B u - h`` with one Cholesky factor of ``M``.
"""

from __future__ import annotations

import numpy as np
import scipy.linalg

from cases.model import Model
from formalisms.interface import (Formalism, Split, check_state, conditioning, factor_mass_matrix, joint_vectors,
                                  unconstrained_split)


def _cross(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """``a x b`` for 3-vectors (np.cross is general and several times slower on single vectors)."""
    return np.array([a[1] * b[2] - a[2] * b[1], a[2] * b[0] - a[0] * b[2], a[0] * b[1] - a[1] * b[0]])


def _axis_rotation(axis: np.ndarray, angle: float) -> np.ndarray:
    """Rotation by ``angle`` about the unit vector ``axis`` (Rodrigues)."""
    x, y, z = axis
    K = np.array([[0.0, -z, y], [z, 0.0, -x], [-y, x, 0.0]])
    return np.eye(3) + np.sin(angle) * K + (1.0 - np.cos(angle)) * (K @ K)


def _placements(model: Model, q: np.ndarray):
    """Per body: rotation ``P`` (parent frame <- body frame), body origin ``r`` in the parent frame, and the
    world <- body rotation ``W``. ``X_body = X_parent * (rotation, translation) * motion(q_i)``."""
    P, r, W = [None] * model.n, [None] * model.n, [None] * model.n
    for i in model.topological_order:
        b, p = model.bodies[i], model.parent_index[i]
        if b.joint == "revolute":
            P[i] = b.rotation @ _axis_rotation(b.axis, q[i])
            r[i] = b.translation
        else:
            P[i] = b.rotation
            r[i] = b.translation + q[i] * (b.rotation @ b.axis)
        W[i] = P[i] if p < 0 else W[p] @ P[i]
    return P, r, W


def _forward(model: Model, kin, qd: np.ndarray, qdd: np.ndarray):
    """Forward pass, base to tip: angular velocity ``w``, angular acceleration ``wd`` and the classical
    acceleration ``a`` of each body-frame origin (n x 3 each, body frame)."""
    P, r, _ = kin
    nb = model.n
    w, wd, a = np.zeros((nb, 3)), np.zeros((nb, 3)), np.zeros((nb, 3))
    zero = np.zeros(3)
    for i in model.topological_order:
        b, p = model.bodies[i], model.parent_index[i]
        w_p, wd_p, a_p = (zero, zero, zero) if p < 0 else (w[p], wd[p], a[p])
        E = P[i].T                                          # body <- parent
        w_in, s = E @ w_p, b.axis * qd[i]                   # s: joint rate along the axis
        a_origin = E @ (a_p + _cross(wd_p, r[i]) + _cross(w_p, _cross(w_p, r[i])))
        if b.joint == "revolute":
            w[i] = w_in + s
            wd[i] = E @ wd_p + b.axis * qdd[i] + _cross(w_in, s)
            a[i] = a_origin
        else:
            w[i] = w_in
            wd[i] = E @ wd_p
            a[i] = a_origin + 2.0 * _cross(w[i], s) + b.axis * qdd[i]
    return w, wd, a


def _backward(model: Model, kin, motion, gravity: bool):
    """Backward pass, tip to base: the joint loads ``f, n`` (n x 3 each), the force and the moment about body
    ``i``'s origin that the parent exerts on body ``i``, in body frame ``i``. Eq. (18) and (19) solved for the
    inboard load."""
    P, r, W = kin
    w, wd, a = motion
    f, n = np.zeros((model.n, 3)), np.zeros((model.n, 3))
    for i in reversed(model.topological_order):
        b = model.bodies[i]
        a_c = a[i] + _cross(wd[i], b.com) + _cross(w[i], _cross(w[i], b.com))
        F = b.mass * a_c                                     # eq. (18): m a_c
        if gravity:
            F = F - b.mass * (W[i].T @ model.gravity)        # external force m g, moved to the left side
        f[i] += F
        n[i] += b.inertia @ wd[i] + _cross(w[i], b.inertia @ w[i]) + _cross(b.com, F)   # eq. (19)
        p = model.parent_index[i]
        if p >= 0:                                           # the child pushes back on its parent
            fp = P[i] @ f[i]
            f[p] += fp
            n[p] += P[i] @ n[i] + _cross(r[i], fp)
    return f, n


def _recursion(model: Model, kin, qd: np.ndarray, qdd: np.ndarray, gravity: bool):
    """Both passes of the recursive Newton–Euler algorithm (6.1.3): the joint loads ``f, n``."""
    return _backward(model, kin, _forward(model, kin, qd, qdd), gravity)


def _task_acceleration(model: Model, kin, motion) -> np.ndarray:
    """Classical acceleration of the default task point in its task coordinates ``D p`` (eq. 23):
    ``a + wd x r + w x (w x r)`` of the point ``r`` fixed in its body, rotated to the world."""
    tp = model.task_point()
    i = model.body_index(tp.body)
    w, wd, a = (x[i] for x in motion)
    return tp.directions @ (kin[2][i] @ (a + _cross(wd, tp.offset) + _cross(w, _cross(w, tp.offset))))


def _joint_torques(model: Model, f: np.ndarray, n: np.ndarray) -> np.ndarray:
    """``tau_i = axis . n_i`` (revolute) or ``axis . f_i`` (prismatic)."""
    return np.array([b.axis @ (n[i] if b.joint == "revolute" else f[i]) for i, b in enumerate(model.bodies)])


def inverse_dynamics(model: Model, q, qd, qdd, gravity: bool = True) -> np.ndarray:
    """RNEA: the generalized force ``M qdd + C qd (+ g)`` of eq. (2), from eq. (18) and (19) body by body."""
    q, qd, qdd = joint_vectors(model, q, qd, qdd)
    f, n = _recursion(model, _placements(model, q), qd, qdd, gravity)
    return _joint_torques(model, f, n)


def mass_matrix(model: Model, q) -> np.ndarray:
    """``M(q)`` of eq. (2), column ``j`` = RNEA with ``qd = 0``, no gravity and ``qdd = e_j`` (n passes).

    The placements are computed once and shared by the columns; the result is symmetrized to remove rounding.
    """
    (q,) = joint_vectors(model, q)
    kin, zero = _placements(model, q), np.zeros(model.n)
    M = np.empty((model.n, model.n))
    for j, e in enumerate(np.eye(model.n)):
        M[:, j] = _joint_torques(model, *_recursion(model, kin, zero, e, gravity=False))
    return 0.5 * (M + M.T)


def joint_reactions(model: Model, q, qd, qdd) -> np.ndarray:
    """Full joint loads (6.1.5), gravity included: row ``i`` = ``[force(3), moment(3)]`` the parent exerts on
    body ``i`` through joint ``i``, moment about the body-frame origin (the joint origin on body ``i``'s side),
    both in body frame ``i``. The actuated component (along the axis) is included."""
    q, qd, qdd = joint_vectors(model, q, qd, qdd)
    return _reactions(model, _placements(model, q), qd, qdd)


def _reactions(model: Model, kin, qd: np.ndarray, qdd: np.ndarray) -> np.ndarray:
    return np.hstack(_recursion(model, kin, qd, qdd, gravity=True))


def _reactions_in_world(model: Model, kin, reactions: np.ndarray) -> np.ndarray:
    """Body-frame joint loads ``[f, n]`` re-expressed in the world frame, the moment taken about the world origin:
    ``[W f, W n + o x W f]`` with ``o`` the body-frame origin in the world. A change of world frame maps these
    rows as wrenches (article 7.4), while the body-frame rows do not change."""
    P, r, W = kin
    out = np.empty_like(reactions)
    origin = [None] * model.n
    for i in model.topological_order:
        p = model.parent_index[i]
        origin[i] = r[i] if p < 0 else origin[p] + W[p] @ r[i]
        f, n = W[i] @ reactions[i, :3], W[i] @ reactions[i, 3:]
        out[i] = np.concatenate([f, n + _cross(origin[i], f)])
    return out


def split(model: Model, q, qd, u) -> Split:
    """The drift–control split of eq. (9): ``drift = -M^-1 h`` (eq. 10, ZTCF), ``ctrl = M^-1 B u`` solved
    directly, ``total = M^-1 (B u - h)`` solved on its own, with ``h = C qd + g`` from the RNEA at ``qdd = 0``.

    extras: ``joint_reactions`` at ``(q, qd, total)`` and ``joint_reactions_drift`` at ``(q, qd, drift)`` (body
    frames), ``joint_reactions_world`` (the former in the world frame, moments about the world origin);
    ``task_drift`` is the default task point's classical acceleration from the forward pass at the drift.
    """
    if model.constraints:
        raise NotImplementedError(f"model '{model.name}': the Newton–Euler backend does not handle constraints "
                                  "yet; constraints arrive with the constraint issue")
    q, qd, u = check_state(model, q, qd, u)
    kin, zero = _placements(model, q), np.zeros(model.n)

    def bias(v: np.ndarray, grav: bool) -> np.ndarray:     # RNEA at qdd = 0
        return _joint_torques(model, *_recursion(model, kin, v, zero, grav))

    h, c_qd, g = bias(qd, True), bias(qd, False), bias(zero, True)
    M = mass_matrix(model, q)
    factor = factor_mass_matrix(model, M, q)
    tau_ctrl = model.input_map @ u
    drift = scipy.linalg.cho_solve(factor, -h)
    ctrl = scipy.linalg.cho_solve(factor, tau_ctrl)
    total = scipy.linalg.cho_solve(factor, tau_ctrl - h)
    cond_M, accel_scale = conditioning(model, M, c_qd, g, tau_ctrl, qd)
    drift_motion = _forward(model, kin, qd, drift)
    reactions = _reactions(model, kin, qd, total)
    extras = {"joint_reactions": reactions,
              "joint_reactions_drift": np.hstack(_backward(model, kin, drift_motion, gravity=True)),
              "joint_reactions_world": _reactions_in_world(model, kin, reactions)}
    return unconstrained_split(drift=drift, ctrl=ctrl, total=total, tau_ctrl=tau_ctrl, qd=qd,
                               cond_M=cond_M, accel_scale=accel_scale, extras=extras,
                               task_drift=_task_acceleration(model, kin, drift_motion),
                               kinetic_energy=0.5 * qd @ M @ qd)


FORMALISM = Formalism(
    name="newton_euler",
    summary="Recursive Newton–Euler in body frames (article 6.1, eqs. 18-19): 3-vector force balance per body",
    split=split,
)
