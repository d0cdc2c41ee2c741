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

The drift–control split (eq. 9, 10) solves ``M qdd = B u - h`` with one Cholesky factor of ``M``.

Constraints (article 5; DESIGN.md, constraints). ``phi``, ``Jc`` and ``Jcdot qd`` come from the recursion's own
point kinematics: the world position of a body point from the placements; column ``j`` of its Jacobian is the
point's classical acceleration from the forward pass at ``qd = 0``, ``qdd = e_j`` (the velocity of the point at
``qd = e_j``: with no velocity there is no bias), i.e. the very passes that build the columns of ``M``; and
``Jdot qd`` of the point is its classical acceleration from the forward pass at ``qdd = 0``. The multipliers come
from the range-space (Schur complement) method on the Cholesky factor of ``M``: with ``f = B u - h``,

    S = Jc M^-1 Jc^T,   lam = S^+ (-Jcdot qd - Jc M^-1 f),   qdd = M^-1 (f + Jc^T lam)        (eq. 12, 13)

``S^+`` from the eigendecomposition of ``S`` with the eigenvalues below ``CONSTRAINT_RCOND`` times the largest
dropped: redundant rows get the minimum-norm multipliers and an inconsistent system (an empty ``H_t``) finite
least-squares numbers. The drift is the same solve with ``u = 0`` (eq. 14) and ``ctrl = B_c B u`` directly
(eq. 17).

In Newton–Euler the constraints are joint reactions (article 7.2): each multiplier's force is applied in the
backward pass as an external point force on the bodies it acts on (a circle: ``2 P^T P (p - c) lam`` at the
point; a loop closure: ``D^T lam`` on body a at ``p_a`` and ``-D^T lam`` on body b at ``p_b``, nothing on the
world; a line: ``N^T lam``), so the joint reactions carry the loop forces and their axis components are the
actuation ``B u``. A joint coupling (a gear) is no point force: its generalized force ``c_j lam`` acts on the joints
themselves like an actuator, so it appears in the axis components of the reactions, which then equal
``B u + (coupling rows of Jc)^T lam``.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Callable

import numpy as np
import scipy.linalg

from cases.constraints import JointCoupling, PointOnCircle, PointOnLine, PointsCoincide
from cases.model import Model
from formalisms.interface import (redundant_below, Formalism, Split, check_state, conditioning, constrained_split,
                                  factor_mass_matrix, joint_vectors, unconstrained_split)


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


def _origins(model: Model, kin) -> list[np.ndarray]:
    """World position of every body-frame origin: ``o_i = o_parent + W_parent r_i``."""
    _, r, W = kin
    origin = [None] * model.n
    for i in model.topological_order:
        p = model.parent_index[i]
        origin[i] = r[i] if p < 0 else origin[p] + W[p] @ r[i]
    return origin


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


def _unit_motions(model: Model, kin) -> list:
    """The forward pass at ``qd = 0``, ``qdd = e_j`` for every joint ``j``: the columns of ``M`` (backward pass,
    no gravity) and of every point Jacobian (a point's classical acceleration)."""
    zero = np.zeros(model.n)
    return [_forward(model, kin, zero, e) for e in np.eye(model.n)]


def _com_acceleration(a: np.ndarray, wd: np.ndarray, w: np.ndarray, com: np.ndarray) -> np.ndarray:
    """Classical acceleration of the COM ``c`` from the body origin's: ``a_c = a + wd x c + w x (w x c)``."""
    return a + _cross(wd, com) + _cross(w, _cross(w, com))


def _body_gravity(W: np.ndarray, gravity: np.ndarray) -> np.ndarray:  # noqa: N803
    """The world gravity vector in the body frame: ``W^T gravity`` (``W``: world <- body)."""
    return W.T @ gravity


def _gyroscopic(inertia: np.ndarray, w: np.ndarray) -> np.ndarray:
    """The gyroscopic moment ``w x (I w)`` of eq. (19)."""
    return _cross(w, inertia @ w)


def _backward(model: Model, kin, motion, gravity: bool, external: np.ndarray | None = None):
    """Backward pass, tip to base: the joint loads ``f, n`` (n x 3 each), the force and the moment about body
    ``i``'s origin that the parent exerts on body ``i``, in body frame ``i``. Eq. (18) and (19) solved for the
    inboard load; ``external`` (n x 6, rows ``[force, moment about the origin]`` in body frame ``i``) are further
    loads applied to the bodies."""
    P, r, W = kin
    w, wd, a = motion
    f, n = np.zeros((model.n, 3)), np.zeros((model.n, 3))
    for i in reversed(model.topological_order):
        b = model.bodies[i]
        F = b.mass * _com_acceleration(a[i], wd[i], w[i], b.com)   # eq. (18): m a_c
        if gravity:
            F = F - b.mass * _body_gravity(W[i], model.gravity)     # external force m g, moved to the left side
        f[i] += F
        n[i] += b.inertia @ wd[i] + _gyroscopic(b.inertia, w[i]) + _cross(b.com, F)   # eq. (19)
        if external is not None:
            f[i] -= external[i, :3]
            n[i] -= external[i, 3:]
        p = model.parent_index[i]
        if p >= 0:                                           # the child pushes back on its parent
            fp = P[i] @ f[i]
            f[p] += fp
            n[p] += P[i] @ n[i] + _cross(r[i], fp)
    return f, n


def _recursion(model: Model, kin, qd: np.ndarray, qdd: np.ndarray, gravity: bool):
    """Both passes of the recursive Newton–Euler algorithm (6.1.3): the joint loads ``f, n``."""
    return _backward(model, kin, _forward(model, kin, qd, qdd), gravity)


def _point_acceleration(kin, motion, body: int, offset: np.ndarray) -> np.ndarray:
    """Classical acceleration (world frame) of the point ``offset`` fixed in ``body``: ``a + wd x r + w x (w x r)``
    of the forward pass, rotated to the world."""
    w, wd, a = (x[body] for x in motion)
    return kin[2][body] @ (a + _cross(wd, offset) + _cross(w, _cross(w, offset)))


def _task_acceleration(model: Model, kin, motion) -> np.ndarray:
    """Classical acceleration of the default task point in its task coordinates ``D p`` (eq. 23)."""
    tp = model.task_point()
    return tp.directions @ _point_acceleration(kin, motion, model.body_index(tp.body), tp.offset)


def _joint_torques(model: Model, f: np.ndarray, n: np.ndarray) -> np.ndarray:
    """``tau_i = axis . n_i`` (revolute) or ``axis . f_i`` (prismatic)."""
    return np.array([b.axis @ (n[i] if b.joint == "revolute" else f[i]) for i, b in enumerate(model.bodies)])


def inverse_dynamics(model: Model, q, qd, qdd, gravity: bool = True) -> np.ndarray:
    """RNEA: the generalized force ``M qdd + C qd (+ g)`` of eq. (2), from eq. (18) and (19) body by body."""
    q, qd, qdd = joint_vectors(model, q, qd, qdd)
    f, n = _recursion(model, _placements(model, q), qd, qdd, gravity)
    return _joint_torques(model, f, n)


def _mass_matrix(model: Model, kin, units) -> np.ndarray:
    """Column ``j`` of ``M`` = the backward pass (no gravity) of the unit motion ``e_j``, symmetrized."""
    M = np.column_stack([_joint_torques(model, *_backward(model, kin, motion, gravity=False)) for motion in units])
    return 0.5 * (M + M.T)


def mass_matrix(model: Model, q) -> np.ndarray:
    """``M(q)`` of eq. (2), column ``j`` = RNEA with ``qd = 0``, no gravity and ``qdd = e_j`` (n passes).

    The placements are computed once and shared by the columns; the result is symmetrized to remove rounding.
    """
    (q,) = joint_vectors(model, q)
    kin = _placements(model, q)
    return _mass_matrix(model, kin, _unit_motions(model, kin))


def joint_reactions(model: Model, q, qd, qdd) -> np.ndarray:
    """Full joint loads (6.1.5), gravity included: row ``i`` = ``[force(3), moment(3)]`` the parent exerts on
    body ``i`` through joint ``i``, moment about the body-frame origin (the joint origin on body ``i``'s side),
    both in body frame ``i``. The actuated component (along the axis) is included. No constraint forces: for a
    constrained model, ``split``'s extras carry the reactions with the loop forces applied."""
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
    """One declaration's rows: ``phi``, ``Jc``, ``Jcdot qd``, and ``loads``: the point forces its multipliers
    apply, as ``(body index, offset in the body, F)`` with ``F`` (3 x rows) the world force per unit multiplier."""

    phi: np.ndarray
    jacobian: np.ndarray
    bias: np.ndarray
    loads: tuple = ()


@dataclass(frozen=True)
class _Point:
    """A point's world position ``p``, Jacobian ``dp/dq`` (3 x n) and bias acceleration ``Jdot qd``; ``body`` is
    None for a fixed world point."""

    body: int | None
    offset: np.ndarray
    p: np.ndarray
    J: np.ndarray
    a: np.ndarray


def _point_kinematics(model: Model, kin, units, bias_motion) -> Callable[[str | None, np.ndarray], _Point]:
    """``point(body name, offset)``: the kinematics of a body point from the recursion (module docstring); a body
    of None makes ``offset`` a fixed world point."""
    origins = _origins(model, kin)

    def point(body: str | None, offset: np.ndarray) -> _Point:
        if body is None:
            return _Point(None, offset, offset, np.zeros((3, model.n)), np.zeros(3))
        i = model.body_index(body)
        J = np.column_stack([_point_acceleration(kin, motion, i, offset) for motion in units])
        return _Point(i, offset, origins[i] + kin[2][i] @ offset, J,
                      _point_acceleration(kin, bias_motion, i, offset))

    return point


def _circle(model: Model, c, point, q, qd) -> _Rows:
    """``phi = |P d|^2 - R^2`` with ``d = p - c``: ``Jc = 2 (P d)^T P J``, ``Jcdot qd = 2 |P v|^2 + 2 (P d)^T P a``;
    the force ``2 P^T P d lam`` at the point."""
    x = point(c.body, c.offset)
    d = c.plane @ (x.p - c.center)
    grad = 2.0 * c.plane.T @ d                               # dphi/dp, world
    v = c.plane @ (x.J @ qd)
    return _Rows(np.array([d @ d - c.radius**2]), (grad @ x.J)[None, :], np.array([2.0 * v @ v + grad @ x.a]),
                 ((x.body, x.offset, grad[:, None]),))


def _coincide(model: Model, c, point, q, qd) -> _Rows:
    """``phi = D (p_a - p_b)``: ``Jc = D (J_a - J_b)``, ``Jcdot qd = D (a_a - a_b)``; ``D^T lam`` on body a at
    ``p_a``, ``-D^T lam`` on body b at ``p_b`` (nothing when b is the world)."""
    xa, xb = point(c.body_a, c.offset_a), point(c.body_b, c.offset_b)
    D = c.directions
    loads = ((xa.body, xa.offset, D.T),) + (() if xb.body is None else ((xb.body, xb.offset, -D.T),))
    return _Rows(D @ (xa.p - xb.p), D @ (xa.J - xb.J), D @ (xa.a - xb.a), loads)


def _line(model: Model, c, point, q, qd) -> _Rows:
    """``phi = N (p - origin)``: ``Jc = N J``, ``Jcdot qd = N a``; the force ``N^T lam`` at the point."""
    x = point(c.body, c.offset)
    N = c.normals
    return _Rows(N @ (x.p - c.origin), N @ x.J, N @ x.a, ((x.body, x.offset, N.T),))


def _coupling(model: Model, c, point, q, qd) -> _Rows:
    """``phi = sum_j c_j q_j - offset``: a constant row, no bias, and no point force (a joint torque)."""
    row = np.zeros(model.n)
    for name, coefficient in zip(c.joints, c.coefficients):
        row[model.body_index(name)] += coefficient
    return _Rows(np.array([row @ q - c.offset]), row[None, :], np.zeros(1))


#: The rows of each declaration of ``cases.constraints``, by its type.
_DECLARATIONS = {PointOnCircle: _circle, PointsCoincide: _coincide, PointOnLine: _line, JointCoupling: _coupling}


def _constraint_rows(model: Model, kin, units, bias_motion, q: np.ndarray, qd: np.ndarray) -> list[_Rows]:
    """The rows of every declaration, in model order."""
    point = _point_kinematics(model, kin, units, bias_motion)
    rows = []
    for c in model.constraints:
        if type(c) not in _DECLARATIONS:
            raise TypeError(f"model '{model.name}': the Newton–Euler backend does not know the constraint "
                            f"declaration {c!r} of type {type(c).__name__}; "
                            f"known: {[t.__name__ for t in _DECLARATIONS]}")
        rows.append(_DECLARATIONS[type(c)](model, c, point, q, qd))
    return rows


def _constraint_loads(model: Model, kin, rows: list[_Rows], lam: np.ndarray) -> np.ndarray:
    """The point forces of the multipliers ``lam`` as external loads on the bodies (n x 6, rows ``[force, moment
    about the body origin]`` in body frame ``i``), for the backward pass."""
    loads, start = np.zeros((model.n, 6)), 0
    for r in rows:
        part, start = lam[start:start + len(r.phi)], start + len(r.phi)
        for i, offset, F in r.loads:
            f = kin[2][i].T @ (F @ part)
            loads[i, :3] += f
            loads[i, 3:] += _cross(offset, f)
    return loads


@dataclass(frozen=True)
class _RangeSpace:
    """The range-space (Schur complement) method on the Cholesky factor of ``M``: ``X = M^-1 Jc^T`` and
    ``S^+`` with ``S = Jc X`` (eigenvalues below ``CONSTRAINT_RCOND`` times the largest dropped)."""

    factor: tuple
    Jc: np.ndarray
    bias: np.ndarray
    X: np.ndarray
    S_pinv: np.ndarray

    @classmethod
    def build(cls, model: Model, factor, Jc: np.ndarray, bias: np.ndarray) -> "_RangeSpace":
        X = scipy.linalg.cho_solve(factor, Jc.T)
        S = Jc @ X
        w, U = np.linalg.eigh(0.5 * (S + S.T))
        keep = w > redundant_below(model, w[-1])
        return cls(factor, Jc, bias, X, (U[:, keep] / w[keep]) @ U[:, keep].T)

    def solve(self, f: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """``(qdd, lam)`` of eq. (12, 13) for the generalized force ``f``: ``lam = S^+ (-Jcdot qd - Jc M^-1 f)``,
        ``qdd = M^-1 f + X lam``."""
        a = scipy.linalg.cho_solve(self.factor, f)
        lam = self.S_pinv @ (-self.bias - self.Jc @ a)
        return a + self.X @ lam, lam

    def input_map(self, tau: np.ndarray) -> np.ndarray:
        """``B_c tau`` of eq. (17): ``M^-1 tau - X S^+ Jc M^-1 tau``."""
        a = scipy.linalg.cho_solve(self.factor, tau)
        return a - self.X @ (self.S_pinv @ (self.Jc @ a))


# ----------------------------------------------------------------------------------------------------------
# The split
# ----------------------------------------------------------------------------------------------------------

def _extras(model: Model, kin, qd: np.ndarray, total: np.ndarray, drift: np.ndarray, loads=None,
            loads_drift=None):
    """The joint reactions at the total and at the drift (with the external ``loads``, ``loads_drift`` applied),
    the former also in the world frame; and the drift's forward pass."""
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
    A constrained model goes through the range-space solve of eq. (12)-(17) instead (module docstring).

    extras: ``joint_reactions`` at ``(q, qd, total)`` and ``joint_reactions_drift`` at ``(q, qd, drift)`` (body
    frames; with the constraint forces of ``lam`` and ``lam_drift`` applied), ``joint_reactions_world`` (the former
    in the world frame, moments about the world origin); ``joint_wrenches`` and ``joint_wrenches_drift`` are the
    first two; ``task_drift`` is the default task point's classical acceleration from the forward pass at the drift.
    """
    q, qd, u = check_state(model, q, qd, u)
    kin, zero = _placements(model, q), np.zeros(model.n)
    units, bias_motion = _unit_motions(model, kin), _forward(model, kin, qd, zero)
    h = _joint_torques(model, *_backward(model, kin, bias_motion, gravity=True))     # RNEA at qdd = 0
    c_qd = _joint_torques(model, *_backward(model, kin, bias_motion, gravity=False))
    g = _joint_torques(model, *_recursion(model, kin, zero, zero, gravity=True))
    M = _mass_matrix(model, kin, units)
    factor = factor_mass_matrix(model, M, q)
    tau_ctrl = model.input_map @ u
    if not model.constraints:
        drift, ctrl, total = (scipy.linalg.cho_solve(factor, f) for f in (-h, tau_ctrl, tau_ctrl - h))
        extras, drift_motion = _extras(model, kin, qd, total, drift)
        cond_M, accel_scale = conditioning(model, M, c_qd, g, tau_ctrl, qd)
        return unconstrained_split(drift=drift, ctrl=ctrl, total=total, tau_ctrl=tau_ctrl, qd=qd,
                                   cond_M=cond_M, accel_scale=accel_scale, extras=extras,
                                   task_drift=_task_acceleration(model, kin, drift_motion),
                                   kinetic_energy=0.5 * qd @ M @ qd, **_wrenches(extras))
    rows = _constraint_rows(model, kin, units, bias_motion, q, qd)
    Jc, bias = np.vstack([r.jacobian for r in rows]), np.concatenate([r.bias for r in rows])
    schur = _RangeSpace.build(model, factor, Jc, bias)
    (total, lam), (drift, lam_drift) = schur.solve(tau_ctrl - h), schur.solve(-h)        # eq. (12, 13), (14)
    extras, drift_motion = _extras(model, kin, qd, total, drift, _constraint_loads(model, kin, rows, lam),
                                   _constraint_loads(model, kin, rows, lam_drift))
    return constrained_split(model, M=M, Cqd=c_qd, g=g, tau_ctrl=tau_ctrl, qd=qd,
                             phi=np.concatenate([r.phi for r in rows]), Jc=Jc, bias=bias, drift=drift,
                             ctrl=schur.input_map(tau_ctrl), total=total, lam=lam, lam_drift=lam_drift,
                             extras=extras, task_drift=_task_acceleration(model, kin, drift_motion),
                             kinetic_energy=0.5 * qd @ M @ qd, **_wrenches(extras))


FORMALISM = Formalism(
    name="newton_euler",
    summary="Recursive Newton–Euler in body frames (article 6.1, eqs. 18-19): 3-vector force balance per body",
    split=split,
)
