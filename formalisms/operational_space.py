"""Operational-space formalism (article 6.3): the dynamics seen from a task point, in Jacobian language.

Kinematics (world frame, frames of ``cases.model``): ``X_body = X_parent * (rotation, translation) * motion(q_i)``
gives every body's rotation ``R_i`` and origin ``o_i``; joint ``j`` has the world axis ``z_j`` and, when
revolute, the origin ``o_j`` (a rotation about the axis leaves the body origin on it). Joint ``j`` moves body
``i`` when it is ``i``'s own joint or an ancestor's. A point ``p`` fixed in body ``i`` has the geometric Jacobian

    linear column j:   z_j x (p - o_j)  (revolute)   or   z_j  (prismatic)
    angular column j:  z_j              (revolute)   or   0

and the CLASSICAL bias ``Jdot qd`` (the point's acceleration at ``qdd = 0``, DESIGN.md) is the sum of the
analytic column derivatives times ``qd_j``: with ``zdot_j = w_j x z_j`` (the axis is fixed in body ``j`` and, for
a revolute joint, in its parent too), a revolute column changes by ``zdot_j x (p - o_j) + z_j x (pdot - odot_j)``
and a prismatic one by ``zdot_j``. Velocities are Jacobian sums as well: ``w_i = sum_j z_j qd_j`` over the
revolute joints moving ``i``, ``odot_i = J_v(o_i) qd``.

Joint-space terms by projection (Kane's form), from the COM Jacobians ``J_v,i`` and ``J_w,i``:

    M    = sum_i m_i J_v,i^T J_v,i + J_w,i^T I_i J_w,i                       (I_i: COM inertia, world)
    C qd = sum_i m_i J_v,i^T (Jdot_v,i qd) + J_w,i^T (I_i Jdot_w,i qd + w_i x I_i w_i)
    g    = -sum_i m_i J_v,i^T gravity

Task space (eq. 22) for ``x_task = D p``: ``J = D J_v(p)``, ``A = J M^-1 J^T = Lambda^-1``,
``mu = Lambda (J M^-1 C qd - Jdot qd)``, ``p = Lambda J M^-1 g``, ``J_bar = M^-1 J^T Lambda`` (the dynamically
consistent inverse), ``N = 1 - J_bar J``, ``F_ctrl = J_bar^T B u``. Eq. (22) solved for the task acceleration:
``xdd = A (F - mu - p)``. With ``F = J_bar^T tau`` this is

    xdd = J M^-1 tau - J M^-1 C qd + Jdot qd - J M^-1 g = J M^-1 (tau - h) + Jdot qd,

so at ``tau = 0`` it is eq. (23): ``xdd_drift = J qdd_drift + Jdot qd``.

The joint answer is RECOMPOSED from task space plus the dynamically consistent null-space part:

    qdd = J_bar (xdd - Jdot qd) + M^-1 N^T (tau - h)
        = [M^-1 J^T Lambda J M^-1 + M^-1 - M^-1 J^T Lambda J M^-1] (tau - h) = M^-1 (tau - h),

(using ``xdd - Jdot qd = J M^-1 (tau - h)`` and ``N^T = 1 - J^T Lambda J M^-1``): drift at ``tau = 0``, total at
``tau = B u``, and ctrl, the control increment computed directly, ``J_bar xdd_ctrl + M^-1 N^T B u`` with
``xdd_ctrl = A F_ctrl = J M^-1 B u`` (no bias). For a square task Jacobian (the double pendulum's endpoint)
``J_bar = J^-1`` and ``N = 0``: the joint acceleration comes entirely from task space.

Breakdown (6.3.4): the method inverts ``A``, so every result carries ``cond = cond_2(A)`` (``Split.conditions
["task"]``); the harness declares states above its limit a BREAKDOWN. Where ``A`` is numerically singular (its
smallest eigenvalue is not positive, not finite, or below ``k eps lambda_max``, eigvalsh's absolute accuracy for
a k x k matrix, so indistinguishable from zero) ``cond`` is ``inf`` and every task-space quantity and joint
acceleration is NaN: no crash, and no plausible-looking garbage.

Constraints (article 5, eqs. 12-17; in operational space they are the ``F_constr`` of eq. 22, article 7.2): ``phi``,
``Jc`` and ``Jcdot qd`` come from the same point kinematics as the task, the world position, ``J_v`` and classical
bias of each constrained point, combined row by row as ``cases.constraints`` fixes them (a circle:
``d = P (p - c)``, ``phi = d.d - R^2``, ``Jc = 2 d^T P J_v``, ``Jcdot qd = 2 |P J_v qd|^2 + 2 d^T P (Jdot_v qd)``).
The constraint is treated as a second operational space with its own inertia (Khatib's constraint space):
``Lambda_c = S^+`` with ``S = Jc M^-1 Jc^T``, the pseudo-inverse from S's eigendecomposition without the
eigen-directions below ``CONSTRAINT_RCOND`` times the largest eigenvalue (redundant or degenerate rows give the
minimum-norm multipliers). With ``a`` the free accelerations recomposed as above, eq. (13) gives

    lam = Lambda_c (-Jcdot qd - Jc a)    (total: a = M^-1 (B u - h); drift, eq. 14: a = -M^-1 h)
    lam_ctrl = -Lambda_c Jc M^-1 B u      (the reaction to the input alone, eq. 15's lam - lam_0)

and the generalized constraint forces ``Jc^T lam`` enter eq. (22) as ``F_constr = J_bar^T Jc^T lam`` beside
``F_ctrl``: the same recomposition with ``tau + Jc^T lam`` for ``tau`` returns ``qdd = a + M^-1 Jc^T lam``. For the
control part that is eq. (17), ``ctrl = B_c B u = M^-1 [I - Jc^T Lambda_c Jc M^-1] B u``, computed directly from
``M^-1 B u`` (never ``total - drift``). Degenerate but consistent rows still give a unique ``qdd`` and ``Jc^T lam``;
inconsistent ones (``H_t`` empty, eq. 16) finite least-squares numbers, which the harness flags from the conditions
``constrained_split`` adds. A singular task space keeps its meaning: every acceleration is NaN there, with or
without constraints.

Numerics: near a singularity ``Lambda``, ``mu``, ``p`` and ``F_ctrl`` grow like ``1 / lambda_min(A)`` along the
lost direction. In the model's task coordinates their rounding lands in every component, ``A``'s large
eigenvalue turns it into an ``eps cond(A)`` error of ``xdd``, and ``J_bar`` (norm ~ ``sqrt(cond(A))``) amplifies it
again: ``eps cond(A)^1.5`` was measured. So eq. (22) is evaluated and solved in the principal axes of ``A``
(``x' = V^T x``, ``Lambda' = diag(1 / eig)``), where each component keeps its own relative precision, and the
results are rotated back. What remains is inherent to the recomposition: ``Jdot qd`` has an O(1) component along
the lost direction while ``J qdd`` there is O(sigma_min(J)), so ``xdd - Jdot qd`` cancels and ``J_bar`` amplifies
the rounding: a joint error of about ``eps |Jdot qd| sqrt(cond(A) / lambda_max(A))``, the error the breakdown
limit is calibrated against (tests/test_operational_space.py).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import scipy.linalg

from cases.constraints import JointCoupling, PointOnCircle, PointOnLine, PointsCoincide
from cases.model import Model
from formalisms.interface import (Formalism, Split, check_state, conditioning, constrained_split, factor_mass_matrix,
                                  redundant_below, singular_below, unconstrained_split)



@dataclass(frozen=True)
class Kinematics:
    """World-frame kinematics of every body at ``(q, qd)`` (rows indexed by body = coordinate index).

    R (n, 3, 3) world <- body rotations; o (n, 3) body origins; z (n, 3) joint axes; revolute (n,) joint kinds;
    moves (n, n) ``moves[i, j]``: joint ``j`` moves body ``i`` (``j == i`` or an ancestor); qd (n,) joint rates;
    w (n, 3) angular velocities; odot (n, 3) origin velocities; zdot (n, 3) axis rates ``w_j x z_j``.
    """

    R: np.ndarray
    o: np.ndarray
    z: np.ndarray
    revolute: np.ndarray
    moves: np.ndarray
    qd: np.ndarray
    w: np.ndarray
    odot: np.ndarray
    zdot: np.ndarray


@dataclass(frozen=True)
class TaskSpace:
    """The task-space quantities of eq. (22) at one state, for one task point (k task coordinates).

    J (k, n), Jdot_qd (k,) classical bias, A = J M^-1 J^T (k, k), Lambda = A^-1, mu, p (k,), J_bar (n, k),
    N (n, n), F_ctrl = J_bar^T B u (k,), F_constr and F_constr_drift = J_bar^T Jc^T lam (k,) with and without input
    (zero without constraints), xdd_drift = A (F_constr_drift - mu - p) (eq. 23), xdd_ctrl = A (F_ctrl + J_bar^T
    Jc^T lam_ctrl), xdd_total = A (F_ctrl + F_constr - mu - p) (k,), cond = cond_2(A).
    Everything but J, Jdot_qd and A is NaN where ``cond`` is inf (A numerically singular).
    """

    J: np.ndarray
    Jdot_qd: np.ndarray
    A: np.ndarray
    Lambda: np.ndarray
    mu: np.ndarray
    p: np.ndarray
    J_bar: np.ndarray
    N: np.ndarray
    F_ctrl: np.ndarray
    F_constr: np.ndarray
    F_constr_drift: np.ndarray
    xdd_drift: np.ndarray
    xdd_ctrl: np.ndarray
    xdd_total: np.ndarray
    cond: float


def _cross(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """``a x b`` over the last axis of stacked 3-vectors, broadcasting (np.cross pays for axis handling)."""
    a0, a1, a2 = a[..., 0], a[..., 1], a[..., 2]
    b0, b1, b2 = b[..., 0], b[..., 1], b[..., 2]
    return np.stack([a1 * b2 - a2 * b1, a2 * b0 - a0 * b2, a0 * b1 - a1 * b0], axis=-1)


def _axis_rotations(axes: np.ndarray, angles: np.ndarray) -> np.ndarray:
    """Rotations by ``angles`` about the unit ``axes`` (Rodrigues), stacked (n, 3, 3)."""
    x, y, z = axes.T
    zero = np.zeros_like(x)
    K = np.stack([np.stack([zero, -z, y], -1), np.stack([z, zero, -x], -1), np.stack([-y, x, zero], -1)], -2)
    return np.eye(3) + np.sin(angles)[:, None, None] * K + (1.0 - np.cos(angles))[:, None, None] * (K @ K)


def _moves(model: Model) -> np.ndarray:
    """``moves[i, j]``: joint ``j`` is body ``i``'s own joint or one of its ancestors' joints."""
    moves = np.zeros((model.n, model.n), dtype=bool)
    for i in model.topological_order:
        p = model.parent_index[i]
        if p >= 0:
            moves[i] = moves[p]
        moves[i, i] = True
    return moves


def _linear_columns(z, o, revolute, moves_rows, points) -> np.ndarray:
    """Linear Jacobian columns (k, n, 3) of world points (k, 3): ``z_j x (p - o_j)`` (revolute) or ``z_j``
    (prismatic) for the joints in ``moves_rows`` (k, n), zero elsewhere."""
    lever = _cross(z, points[:, None, :] - o)
    return np.where(revolute[:, None], lever, z) * moves_rows[:, :, None]


def kinematics(model: Model, q, qd) -> Kinematics:
    """World poses from ``X_body = X_parent * (rotation, translation) * motion(q_i)``; angular velocities, origin
    velocities and axis rates as Jacobian sums (module docstring)."""
    q, qd, _ = check_state(model, q, qd, np.zeros(model.m))
    return _kinematics(model, q, qd)


def _kinematics(model: Model, q: np.ndarray, qd: np.ndarray) -> Kinematics:
    n = model.n
    revolute = np.array([b.joint == "revolute" for b in model.bodies])
    axes = np.array([b.axis for b in model.bodies])
    local = np.array([b.rotation for b in model.bodies])
    motion = _axis_rotations(axes, np.where(revolute, q, 0.0))
    R, o, z = np.empty((n, 3, 3)), np.empty((n, 3)), np.empty((n, 3))
    for i in model.topological_order:
        b, p = model.bodies[i], model.parent_index[i]
        R_p, o_p = (np.eye(3), np.zeros(3)) if p < 0 else (R[p], o[p])
        joint_frame = R_p @ local[i]
        z[i] = joint_frame @ axes[i]
        R[i] = joint_frame @ motion[i]
        o[i] = o_p + R_p @ b.translation + (0.0 if revolute[i] else q[i] * z[i])
    moves = _moves(model)
    w = (moves * np.where(revolute, qd, 0.0)) @ z
    odot = np.einsum("ija,j->ia", _linear_columns(z, o, revolute, moves, o), qd)
    return Kinematics(R, o, z, revolute, moves, qd, w, odot, _cross(w, z))


def point_jacobian(kin: Kinematics, body: np.ndarray, points: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Geometric Jacobians ``(J_v, J_w)``, each (k, 3, n), of the world points ``points`` (k, 3) fixed in bodies
    ``body`` (k,): linear column ``z_j x (p - o_j)`` (revolute) or ``z_j`` (prismatic), angular column ``z_j``
    (revolute) or 0, for every joint ``j`` moving the body; zero columns elsewhere."""
    mask = kin.moves[body]
    Jv = _linear_columns(kin.z, kin.o, kin.revolute, mask, points)
    Jw = (kin.z * kin.revolute[:, None]) * mask[:, :, None]
    return Jv.transpose(0, 2, 1), Jw.transpose(0, 2, 1)


def point_bias(kin: Kinematics, body: np.ndarray, points: np.ndarray, velocities: np.ndarray) -> np.ndarray:
    """The CLASSICAL bias ``Jdot qd`` (k, 3) of world points fixed in bodies ``body`` moving with ``velocities``:
    the second time derivative of each point's position at ``qdd = 0``, summed over the Jacobian columns,
    ``(zdot_j x (p - o_j) + z_j x (pdot - odot_j)) qd_j`` (revolute) and ``zdot_j qd_j`` (prismatic)."""
    rel, rel_v = points[:, None, :] - kin.o, velocities[:, None, :] - kin.odot
    revolute_rate = _cross(kin.zdot, rel) + _cross(kin.z, rel_v)            # (k, n, 3)
    columns = np.where(kin.revolute[:, None], revolute_rate, kin.zdot)
    return np.einsum("kja,kj->ka", columns, kin.moves[body] * kin.qd)


def _angular_bias(kin: Kinematics) -> np.ndarray:
    """``Jdot_w,i qd`` of every body: the sum of ``zdot_j qd_j`` over the revolute joints moving it."""
    return (kin.moves * np.where(kin.revolute, kin.qd, 0.0)) @ kin.zdot


def _world_inertia(R: np.ndarray, inertia: np.ndarray) -> np.ndarray:  # noqa: N803
    """The COM inertias (n, 3, 3) rotated from the body frames to the world: ``R I R^T``."""
    return R @ inertia @ R.transpose(0, 2, 1)


def _gyroscopic(inertia: np.ndarray, w: np.ndarray) -> np.ndarray:
    """The gyroscopic moments ``w x (I w)`` (n, 3) of bodies with world inertias ``I`` and angular velocities ``w``."""
    return _cross(w, np.einsum("iab,ib->ia", inertia, w))


def _terms(model: Model, kin: Kinematics) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """``M``, ``C qd``, ``g`` projected from the COM Jacobians (Kane's form, module docstring)."""
    bodies = np.arange(model.n)
    mass = np.array([b.mass for b in model.bodies])
    com = kin.o + np.einsum("iab,ib->ia", kin.R, np.array([b.com for b in model.bodies]))
    inertia = _world_inertia(kin.R, np.array([b.inertia for b in model.bodies]))
    Jv, Jw = point_jacobian(kin, bodies, com)
    v = np.einsum("iaj,j->ia", Jv, kin.qd)
    a_bias = point_bias(kin, bodies, com, v)
    torque = np.einsum("iab,ib->ia", inertia, _angular_bias(kin)) + _gyroscopic(inertia, kin.w)
    M = np.einsum("i,iaj,iak->jk", mass, Jv, Jv) + np.einsum("iaj,iab,ibk->jk", Jw, inertia, Jw)
    Cqd = np.einsum("iaj,ia->j", Jv, mass[:, None] * a_bias) + np.einsum("iaj,ia->j", Jw, torque)
    g = -np.einsum("iaj,ia->j", Jv, mass[:, None] * model.gravity)
    return 0.5 * (M + M.T), Cqd, g


def joint_space_terms(model: Model, q, qd) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """``(M, C qd, g)`` of eq. (2), projected through the COM Jacobians (Kane's form, module docstring)."""
    q, qd, _ = check_state(model, q, qd, np.zeros(model.m))
    return _terms(model, _kinematics(model, q, qd))


def _point_kinematics(model: Model, kin: Kinematics, body: str | None,
                      offset: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """World position ``p`` (3,), linear Jacobian ``J_v`` (3, n) and classical bias ``Jdot_v qd`` (3,) of the point
    ``offset`` fixed in ``body``; with ``body = None`` the fixed world point ``offset`` (zero Jacobian and bias)."""
    if body is None:
        return np.asarray(offset, dtype=float), np.zeros((3, model.n)), np.zeros(3)
    i = np.array([model.body_index(body)])
    p = kin.o[i] + kin.R[i] @ offset
    Jv = point_jacobian(kin, i, p)[0]
    return p[0], Jv[0], point_bias(kin, i, p, Jv @ kin.qd)[0]


def _task_kinematics(model: Model, kin: Kinematics, point: str | None) -> tuple[np.ndarray, np.ndarray]:
    """``J = D J_v(p)`` (k, n) and the classical ``Jdot qd = D (point bias)`` (k,) of a task point."""
    tp = model.task_point(point)
    _, Jv, bias = _point_kinematics(model, kin, tp.body, tp.offset)
    return tp.directions @ Jv, tp.directions @ bias


def _cond(model: Model, eig: np.ndarray) -> float:
    """``cond_2`` of ``A = J M^-1 J^T`` from its ascending eigenvalues; ``inf`` when it is numerically singular
    (smallest eigenvalue not finite, not positive, below ``k eps`` times the largest or below the degenerate floor:
    ``interface.singular_below``; a task Jacobian of rounding size, 1e-135, once passed as cond 1)."""
    if not singular_below(model, eig) < eig[0]:
        return float("inf")
    return float(eig[-1] / eig[0])


def _task_space(model, J, Jdot_qd, Minv, Cqd, g, tau_ctrl, tau_constr) -> tuple[TaskSpace, TaskSpace]:
    """Eq. (22) and ``xdd = A (F - mu - p)`` (eq. 23 at ``F = 0``), evaluated in the principal axes of ``A``
    (``x' = V^T x`` with ``A = V diag(eig) V^T``, where ``Lambda = diag(1 / eig)``; module docstring, numerics).
    ``tau_constr`` (3, n) holds the generalized constraint forces ``Jc^T lam`` at the drift, of the input alone and
    at the total (zero without constraints); their images ``J_bar^T Jc^T lam`` are the ``F_constr`` of eq. (22).
    Returns the :class:`TaskSpace` in those axes and rotated back to the task coordinates (``J``, ``Jdot qd`` and
    ``A`` there as assembled). All NaN, ``cond`` inf, where ``A`` is numerically singular."""
    n, k = Minv.shape[0], J.shape[0]
    A = J @ Minv @ J.T
    A = 0.5 * (A + A.T)
    eig, V = np.linalg.eigh(A)
    cond = _cond(model, eig)
    if cond == np.inf:
        eig = np.full(k, np.nan)
    Jp, bias = V.T @ J, V.T @ Jdot_qd
    Minv_JT = Minv @ Jp.T
    mu = (Minv_JT.T @ Cqd - bias) / eig                    # Lambda (J M^-1 C qd - Jdot qd)
    p = (Minv_JT.T @ g) / eig                              # Lambda J M^-1 g
    J_bar = Minv_JT / eig                                  # M^-1 J^T Lambda
    F_ctrl = J_bar.T @ tau_ctrl
    F_constr_drift, F_constr_ctrl, F_constr = tau_constr @ J_bar
    principal = TaskSpace(J=Jp, Jdot_qd=bias, A=np.diag(eig), Lambda=np.diag(1.0 / eig), mu=mu, p=p, J_bar=J_bar,
                          N=np.eye(n) - J_bar @ Jp, F_ctrl=F_ctrl, F_constr=F_constr, F_constr_drift=F_constr_drift,
                          xdd_drift=eig * (F_constr_drift - mu - p), xdd_ctrl=eig * (F_ctrl + F_constr_ctrl),
                          xdd_total=eig * (F_ctrl + F_constr - mu - p), cond=cond)
    Lambda = V @ principal.Lambda @ V.T
    reported = TaskSpace(J=J, Jdot_qd=Jdot_qd, A=A, Lambda=0.5 * (Lambda + Lambda.T), mu=V @ mu, p=V @ p,
                         J_bar=J_bar @ V.T, N=principal.N, F_ctrl=V @ F_ctrl, F_constr=V @ F_constr,
                         F_constr_drift=V @ F_constr_drift, xdd_drift=V @ principal.xdd_drift,
                         xdd_ctrl=V @ principal.xdd_ctrl, xdd_total=V @ principal.xdd_total, cond=cond)
    return principal, reported


def _recompose(ts: TaskSpace, Minv: np.ndarray, h: np.ndarray, tau_ctrl: np.ndarray,
               tau_constr: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The joint accelerations from the principal-axes task space plus the dynamically consistent null space
    (module docstring): ``drift = J_bar (xdd_drift - Jdot qd) + M^-1 N^T (Jc^T lam_0 - h)``, ``ctrl = J_bar xdd_ctrl
    + M^-1 N^T (B u + Jc^T lam_ctrl)`` (directly), ``total = J_bar (xdd_total - Jdot qd) + M^-1 N^T (B u + Jc^T lam
    - h)``, with the constraint forces ``tau_constr`` of :func:`_task_space`."""
    null = Minv @ ts.N.T
    f_drift, f_ctrl, f_total = tau_constr
    return (ts.J_bar @ (ts.xdd_drift - ts.Jdot_qd) + null @ (f_drift - h),
            ts.J_bar @ ts.xdd_ctrl + null @ (tau_ctrl + f_ctrl),
            ts.J_bar @ (ts.xdd_total - ts.Jdot_qd) + null @ (tau_ctrl + f_total - h))


def _circle(model: Model, kin: Kinematics, q: np.ndarray, c) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """PointOnCircle: ``d = P (p - c)``, ``phi = d.d - R^2``, ``Jc = 2 d^T P J_v``,
    ``Jcdot qd = 2 |P J_v qd|^2 + 2 d^T P (Jdot_v qd)``."""
    p, Jv, bias = _point_kinematics(model, kin, c.body, c.offset)
    d, PJ = c.plane @ (p - c.center), c.plane @ Jv
    v = PJ @ kin.qd
    return np.array([d @ d - c.radius**2]), (2.0 * d @ PJ)[None], np.array([2.0 * v @ v + 2.0 * d @ (c.plane @ bias)])


def _coincide(model: Model, kin: Kinematics, q: np.ndarray, c) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """PointsCoincide: ``D (p_a - p_b)``, ``D (J_a - J_b)``, ``D (Jdot_a qd - Jdot_b qd)`` (body_b None: a world
    point, zero Jacobian and bias)."""
    pa, Ja, ba = _point_kinematics(model, kin, c.body_a, c.offset_a)
    pb, Jb, bb = _point_kinematics(model, kin, c.body_b, c.offset_b)
    D = c.directions
    return D @ (pa - pb), D @ (Ja - Jb), D @ (ba - bb)


def _line(model: Model, kin: Kinematics, q: np.ndarray, c) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """PointOnLine: ``N (p - origin)``, ``N J_v``, ``N Jdot_v qd``."""
    p, Jv, bias = _point_kinematics(model, kin, c.body, c.offset)
    return c.normals @ (p - c.origin), c.normals @ Jv, c.normals @ bias


def _coupling(model: Model, kin: Kinematics, q: np.ndarray, c) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """JointCoupling: ``sum_j c_j q_j - offset``, a constant row, zero bias."""
    row = np.zeros(model.n)
    row[[model.body_index(name) for name in c.joints]] = c.coefficients
    return np.array([row @ q - c.offset]), row[None], np.zeros(1)


#: The rows of each declaration of ``cases.constraints``, by its type.
_DECLARATIONS = {PointOnCircle: _circle, PointsCoincide: _coincide, PointOnLine: _line, JointCoupling: _coupling}


def _constraint_rows(model: Model, kin: Kinematics, q: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """``phi`` (k,), ``Jc`` (k, n) and ``Jcdot qd`` (k,) of every declaration, in model order, from the point
    kinematics (module docstring, constraints)."""
    rows = []
    for c in model.constraints:
        if type(c) not in _DECLARATIONS:
            raise TypeError(f"model '{model.name}': the operational-space backend does not know the constraint "
                            f"{type(c).__name__} ({c.name!r}); known: {[t.__name__ for t in _DECLARATIONS]}")
        rows.append(_DECLARATIONS[type(c)](model, kin, q, c))
    phi, Jc, bias = (np.concatenate(column) for column in zip(*rows))
    return phi, Jc, bias


def _constraint_inertia(model: Model, Jc: np.ndarray, Minv: np.ndarray) -> np.ndarray:
    """``Lambda_c = S^+``, ``S = Jc M^-1 Jc^T``: the constraint-space inertia, from S's eigendecomposition without
    the eigen-directions below ``CONSTRAINT_RCOND`` times the largest eigenvalue (minimum-norm multipliers)."""
    S = Jc @ Minv @ Jc.T
    w, U = np.linalg.eigh(0.5 * (S + S.T))
    keep = w > redundant_below(model, w[-1])
    return (U[:, keep] / w[keep]) @ U[:, keep].T


@dataclass(frozen=True)
class ConstraintSpace:
    """The constraint space at one state (eqs. 12-17; k constraint rows, module docstring).

    phi (k,), Jc (k, n), bias = Jcdot qd (k,), Lambda = S^+ (k, k) the constraint-space inertia; the multipliers
    lam_drift (eq. 14, u = 0), lam_ctrl (the input's share ``lam - lam_0`` of eq. 15, solved directly) and lam
    (eq. 12), each (k,).
    """

    phi: np.ndarray
    Jc: np.ndarray
    bias: np.ndarray
    Lambda: np.ndarray
    lam_drift: np.ndarray
    lam_ctrl: np.ndarray
    lam: np.ndarray

    @property
    def forces(self) -> np.ndarray:
        """The generalized constraint forces ``Jc^T lam`` (3, n): at the drift, of the input alone, at the total."""
        return np.stack([self.lam_drift, self.lam_ctrl, self.lam]) @ self.Jc


def _constraint_space(model: Model, kin: Kinematics, q: np.ndarray, Minv: np.ndarray, free) -> ConstraintSpace:
    """Eq. (13) solved for the multipliers in constraint space, ``lam = Lambda_c (-Jcdot qd - Jc a)``, from the free
    accelerations ``free = (a_drift, a_ctrl, a_total)`` (``M^-1 (-h)``, ``M^-1 B u``, ``M^-1 (B u - h)``)."""
    phi, Jc, bias = _constraint_rows(model, kin, q)
    Lambda = _constraint_inertia(model, Jc, Minv)
    a_drift, a_ctrl, a_total = free
    return ConstraintSpace(phi=phi, Jc=Jc, bias=bias, Lambda=Lambda, lam_drift=Lambda @ (-bias - Jc @ a_drift),
                           lam_ctrl=-Lambda @ (Jc @ a_ctrl), lam=Lambda @ (-bias - Jc @ a_total))


def _inverse_mass_matrix(model: Model, M: np.ndarray, q: np.ndarray) -> np.ndarray:
    """``M^-1`` from a Cholesky factor (symmetrized)."""
    Minv = scipy.linalg.cho_solve(factor_mass_matrix(model, M, q), np.eye(model.n))
    return 0.5 * (Minv + Minv.T)


@dataclass(frozen=True)
class _Solution:
    """One state solved: the joint-space terms, the reported task space, (drift, ctrl, total), the constraint space
    (None without constraints)."""

    M: np.ndarray
    Cqd: np.ndarray
    g: np.ndarray
    tau_ctrl: np.ndarray
    task: TaskSpace
    accelerations: tuple[np.ndarray, np.ndarray, np.ndarray]
    constraint: ConstraintSpace | None


def _solve(model: Model, q: np.ndarray, qd: np.ndarray, u: np.ndarray, point: str | None) -> _Solution:
    """The free split through the task space of ``point``; with constraints, their multipliers from it and the split
    again with the constraint forces as ``F_constr`` (module docstring, constraints)."""
    kin = _kinematics(model, q, qd)
    M, Cqd, g = _terms(model, kin)
    Minv, tau_ctrl = _inverse_mass_matrix(model, M, q), model.input_map @ u
    J, Jdot_qd = _task_kinematics(model, kin, point)

    def through_task_space(tau_constr):
        ts, reported = _task_space(model, J, Jdot_qd, Minv, Cqd, g, tau_ctrl, tau_constr)
        return reported, _recompose(ts, Minv, Cqd + g, tau_ctrl, tau_constr)

    task, accelerations = through_task_space(np.zeros((3, model.n)))
    constraint = None
    if model.constraints:
        constraint = _constraint_space(model, kin, q, Minv, accelerations)
        task, accelerations = through_task_space(constraint.forces)
    return _Solution(M, Cqd, g, tau_ctrl, task, accelerations, constraint)


def task_space(model: Model, q, qd, u, point: str | None = None) -> TaskSpace:
    """The :class:`TaskSpace` of eq. (22) for the task point named ``point`` (default: ``model.task_point()``),
    in its task coordinates ``x_task = D p``; with constraints, ``F_constr`` included."""
    q, qd, u = check_state(model, q, qd, u)
    return _solve(model, q, qd, u, point).task


def split(model: Model, q, qd, u) -> Split:
    """The drift–control split (eq. 9) recomposed from task space (module docstring), in the principal axes:
    ``drift = J_bar (xdd_drift - Jdot qd) - M^-1 N^T h``, ``ctrl = J_bar xdd_ctrl + M^-1 N^T B u`` (directly),
    ``total = J_bar (xdd_total - Jdot qd) + M^-1 N^T (B u - h)``. With constraints the same with the constraint
    forces added (eqs. 12-17: lam, lam_drift; ctrl = B_c B u).

    ``task_drift`` is eq. (23) for ``model.task_point()``; ``task_inertia`` its ``Lambda`` (eq. 22, the reported one
    of ``extras["task"]``; with constraints still ``(J M^-1 J^T)^-1`` of the unconstrained M, the constraints
    entering eq. 22 as ``F_constr``); ``conditions = {"task": cond_2(A)}``;
    ``extras = {"task": TaskSpace}`` in the task coordinates, and with constraints ``"constraint_inertia"``
    (``Lambda_c``). NaN accelerations where A is numerically singular.
    """
    q, qd, u = check_state(model, q, qd, u)
    s = _solve(model, q, qd, u, None)
    drift, ctrl, total = s.accelerations
    common = dict(drift=drift, ctrl=ctrl, total=total, tau_ctrl=s.tau_ctrl, qd=qd, task_drift=s.task.xdd_drift,
                  conditions={"task": s.task.cond}, kinetic_energy=0.5 * qd @ s.M @ qd, task_inertia=s.task.Lambda)
    c = s.constraint
    if c is None:
        cond_M, accel_scale = conditioning(model, s.M, s.Cqd, s.g, s.tau_ctrl, qd)
        return unconstrained_split(cond_M=cond_M, accel_scale=accel_scale, extras={"task": s.task}, **common)
    return constrained_split(model, M=s.M, Cqd=s.Cqd, g=s.g, phi=c.phi, Jc=c.Jc, bias=c.bias, lam=c.lam,
                             lam_drift=c.lam_drift, extras={"task": s.task, "constraint_inertia": c.Lambda},
                             **common)


FORMALISM = Formalism(
    name="operational_space",
    summary="Operational space (article 6.3, eqs. 22-23): Kane-projected M, C qd, g; task-space Lambda, mu, p; "
            "joint answer recomposed from task space plus the dynamically consistent null space; constraints as a "
            "constraint space (Lambda_c = S^+, eqs. 12-17) whose forces enter eq. 22 as F_constr",
    split=split,
)
