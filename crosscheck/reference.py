"""Pinocchio as the external reference (DESIGN.md: kept apart from the five formalisms).

:func:`to_pinocchio` builds a ``pinocchio.Model`` from OUR model data (never from a URDF), so the reference
checks the same physics the formalisms see. :func:`split` is the shared ``split`` contract on top of
Pinocchio's ABA / CRBA / RNEA; :data:`REFERENCE` wraps it as a :class:`~formalisms.interface.Formalism`.

Constraints: :func:`constraint_kinematics` forms ``phi``, ``Jc`` and ``Jcdot qd`` of the declarations
(``cases.constraints``) from Pinocchio's frame placements, frame Jacobians and classical frame accelerations, and
the constrained split uses Pinocchio's own KKT solver (``pinocchio.forwardDynamics(q, v, tau, J, gamma)``) for
total / lam and drift / lam_drift. The harness's sampler uses the same kinematics to put states on the
constraint manifold, so admissibility is decided outside the five formalisms. At a degenerate state (``S = Jc
M^-1 Jc^T`` singular up to ``CONSTRAINT_RCOND``) Pinocchio's Cholesky-based KKT solve has no answer: the reference
gives it the independent combinations of the rows (S's eigen-directions above the threshold, as the formalisms
keep them) and maps the multipliers back, which gives the minimum-norm multipliers the formalisms return.

Joint loads and task inertia (the compared ``joint_wrenches`` and ``task_inertia``): ``data.f[j]`` after
``pinocchio.rnea(q, v, a)`` is the spatial force ``(linear, angular)`` the parent transmits to body ``j`` through
joint ``j``, in joint ``j``'s local frame (which is our body frame: the inertia is appended at the joint frame),
moment about its origin; RNEA's accelerating base (``a_gf = a - g``) puts the weight in it exactly, so ``data.f``
at ``a = total`` (``drift``) is ``joint_wrenches`` (``joint_wrenches_drift``), rows read back in our coordinate
order. With constraints the point forces of ``lam`` (``lam_drift``), which no KKT solve reports per body, are
applied as RNEA's external forces ``fext`` (local frame, moment about the joint origin), as the formalisms apply
them; a joint coupling's ``c_j lam`` is not a point force, so RNEA leaves it in the coupled joint's own load, the
convention of ``Split.joint_wrenches``. ``task_inertia`` is ``(J M^-1 J^T)^-1`` with J the task frame's
``LOCAL_WORLD_ALIGNED`` linear Jacobian in the task directions and ``M^-1`` by Cholesky on CRBA's M, with
``conditions["task_inertia"]`` = cond(J M^-1 J^T) (NaN and inf where that is numerically singular).

Joint order: Pinocchio needs parents before children, so joints are added in ``model.topological_order``;
states and results are permuted in and out, so callers always use our coordinate order.
"""

from __future__ import annotations

import threading
from dataclasses import dataclass

import numpy as np
import pinocchio as pin
import scipy.linalg

from cases.constraints import JointCoupling, PointOnCircle, PointOnLine, PointsCoincide
from cases.model import Model
from formalisms.interface import (Formalism, Split, SplitBatch, check_batch, check_state, conditioning,
                                  constrained_split, redundant_below, singular_below, split_batch_by_loop,
                                  unconstrained_split)

_ALIGNED = {
    ("revolute", 0): pin.JointModelRX, ("revolute", 1): pin.JointModelRY, ("revolute", 2): pin.JointModelRZ,
    ("prismatic", 0): pin.JointModelPX, ("prismatic", 1): pin.JointModelPY, ("prismatic", 2): pin.JointModelPZ,
}
_UNALIGNED = {"revolute": pin.JointModelRevoluteUnaligned, "prismatic": pin.JointModelPrismaticUnaligned}


@dataclass(frozen=True)
class _Compiled:
    model: pin.Model
    order: np.ndarray  # order[k] = our coordinate index of Pinocchio's k-th velocity
    task_frame: int    # frame id of the model's default task point
    points: dict       # (body name, offset tuple) -> frame id of each constrained body point


_CACHE: dict[str, _Compiled] = {}
_LOCK = threading.Lock()


def _joint_model(joint: str, axis: np.ndarray):
    for k in range(3):
        unit = np.zeros(3)
        unit[k] = 1.0
        if np.array_equal(axis, unit):
            return _ALIGNED[(joint, k)]()
    return _UNALIGNED[joint](np.array(axis, dtype=float))


def _depth_first(model: Model) -> list[int]:
    """The bodies in depth-first pre-order (each subtree contiguous, children in the model's order). Pinocchio's
    algorithms that walk subtree ranges (computeMinverse, CRBA) need joints added in this order; a merely
    parents-first order gave a wrong M^-1 on branched trees."""
    children: dict[int, list[int]] = {}
    for i in model.topological_order:
        children.setdefault(int(model.parent_index[i]), []).append(i)
    order, stack = [], list(reversed(children.get(-1, [])))
    while stack:
        i = stack.pop()
        order.append(i)
        stack.extend(reversed(children.get(i, [])))
    return order


def _build(model: Model) -> _Compiled:
    pm = pin.Model()
    pm.name = model.name
    joint_id = {}
    for i in _depth_first(model):
        b = model.bodies[i]
        parent = 0 if model.parent_index[i] < 0 else joint_id[model.parent_index[i]]
        placement = pin.SE3(np.array(b.rotation), np.array(b.translation))
        jid = pm.addJoint(parent, _joint_model(b.joint, b.axis), placement, b.name)
        pm.appendBodyToJoint(jid, pin.Inertia(float(b.mass), np.array(b.com), np.array(b.inertia)), pin.SE3.Identity())
        joint_id[i] = jid
    pm.gravity = pin.Motion(np.array(model.gravity), np.zeros(3))
    order = np.empty(model.n, dtype=int)
    for i, jid in joint_id.items():
        order[pm.joints[jid].idx_v] = i
    tp = model.task_point()
    task_frame = pm.addFrame(pin.Frame(f"task:{tp.name}", joint_id[model.body_index(tp.body)],
                                       pin.SE3(np.eye(3), np.array(tp.offset)), pin.FrameType.OP_FRAME))
    points = {}
    for c in model.constraints:
        for body, offset in _constrained_points(c):
            if body is not None and (body, tuple(offset)) not in points:
                points[(body, tuple(offset))] = pm.addFrame(pin.Frame(
                    f"constraint:{c.name}:{len(points)}", joint_id[model.body_index(body)],
                    pin.SE3(np.eye(3), np.array(offset)), pin.FrameType.OP_FRAME))
    return _Compiled(pm, order, task_frame, points)


def _constrained_points(c) -> list:
    """The (body, offset) points a declaration constrains; body None is a world point."""
    if isinstance(c, PointsCoincide):
        return [(c.body_a, c.offset_a), (c.body_b, c.offset_b)]
    if isinstance(c, (PointOnCircle, PointOnLine)):
        return [(c.body, c.offset)]
    return []


def _compiled(model: Model) -> _Compiled:
    key = model.digest()
    with _LOCK:
        hit = _CACHE.get(key)
        if hit is None:
            hit = _CACHE[key] = _build(model)
    return hit


def to_pinocchio(model: Model) -> pin.Model:
    """A ``pinocchio.Model`` of ``model`` (cached by ``model.digest()``; joint k = ``model.topological_order[k]``).

    Treat it as read-only: it is shared between calls.
    """
    return _compiled(model).model


def _sym(upper: np.ndarray) -> np.ndarray:
    """Pinocchio fills only the upper triangle of M (crba)."""
    return np.triu(upper) + np.triu(upper, 1).T


def mass_matrix(model: Model, q) -> np.ndarray:
    """``M(q)`` from Pinocchio's CRBA in our coordinate order (for the harness's tolerance scales)."""
    c = _compiled(model)
    M_p = _sym(np.array(pin.crba(c.model, c.model.createData(), np.asarray(q, dtype=float)[c.order])))
    M = np.empty_like(M_p)
    M[np.ix_(c.order, c.order)] = M_p
    return M


def _inverse(M: np.ndarray) -> np.ndarray:
    """``M^-1`` by Cholesky on CRBA's M: backward stable, where computeMinverse lost 256 eps on a single rotor (a fuzz
    finding: ctrl 640.0000000000364 against the exact 640)."""
    return scipy.linalg.cho_solve(scipy.linalg.cho_factor(M), np.eye(len(M)))


def _point_kinematics(c: _Compiled, data, body, offset, n: int):
    """World position, linear Jacobian (3 x n, Pinocchio order) and classical acceleration at qdd = 0 of a
    body point; a world point (body None) is fixed. Needs forwardKinematics(q, v, 0) and computeJointJacobians."""
    if body is None:
        return np.array(offset, dtype=float), np.zeros((3, n)), np.zeros(3)
    fid = c.points[(body, tuple(offset))]
    pos = np.array(data.oMf[fid].translation)
    J = np.array(pin.getFrameJacobian(c.model, data, fid, pin.LOCAL_WORLD_ALIGNED)).reshape(6, n)[:3]
    acc = np.array(pin.getFrameClassicalAcceleration(c.model, data, fid, pin.LOCAL_WORLD_ALIGNED).linear)
    return pos, J, acc


def _rows(model: Model, c: _Compiled, data, con, q: np.ndarray, v_p: np.ndarray):
    """phi, Jc (Pinocchio order) and Jcdot qd of one declaration (the formulas of ``cases.constraints``)."""
    n = model.n
    if isinstance(con, JointCoupling):
        row = np.zeros(n)
        for name, coeff in zip(con.joints, con.coefficients):
            row[model.body_index(name)] += coeff
        return np.array([row @ q - con.offset]), row[c.order][None, :], np.zeros(1)
    if isinstance(con, PointsCoincide):
        pa, Ja, aa = _point_kinematics(c, data, con.body_a, con.offset_a, n)
        pb, Jb, ab = _point_kinematics(c, data, con.body_b, con.offset_b, n)
        D = con.directions
        return D @ (pa - pb), D @ (Ja - Jb), D @ (aa - ab)
    p, J, a = _point_kinematics(c, data, con.body, con.offset, n)
    if isinstance(con, PointOnLine):
        return con.normals @ (p - con.origin), con.normals @ J, con.normals @ a
    P = con.plane
    d = P @ (p - con.center)
    return (np.array([d @ d - con.radius**2]), (2.0 * d @ P @ J)[None, :],
            np.array([2.0 * np.sum((P @ J @ v_p) ** 2) + 2.0 * d @ P @ a]))


def _constraint_terms(model: Model, c: _Compiled, data, q: np.ndarray, qd: np.ndarray):
    """phi, Jc (Pinocchio's coordinate order), Jcdot qd; leaves data with the kinematics at (q, qd, 0)."""
    qp, vp = q[c.order], qd[c.order]
    pin.forwardKinematics(c.model, data, qp, vp, np.zeros(model.n))
    pin.computeJointJacobians(c.model, data, qp)
    pin.updateFramePlacements(c.model, data)
    rows = [_rows(model, c, data, con, q, vp) for con in model.constraints]
    return (np.concatenate([r[0] for r in rows]), np.vstack([r[1] for r in rows]),
            np.concatenate([r[2] for r in rows]))


def constraint_kinematics(model: Model, q, qd) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """``phi(q)`` (k,), ``Jc = dphi/dq`` (k x n, our coordinate order) and ``Jcdot qd`` (k,) from Pinocchio's
    kinematics; the harness's view of the constraints (admissibility, projection onto the manifold)."""
    q, qd = (np.asarray(x, dtype=float) for x in (q, qd))
    c = _compiled(model)
    phi, Jc_p, bias = _constraint_terms(model, c, c.model.createData(), q, qd)
    Jc = np.empty_like(Jc_p)
    Jc[:, c.order] = Jc_p
    return phi, Jc, bias


def _task_inertia(model: Model, c: _Compiled, data, Minv_p: np.ndarray) -> dict:
    """``task_inertia`` (eq. 22) of the default task point from the task frame's Jacobian (needs
    computeJointJacobians) and ``M^-1``, and ``conditions["task_inertia"]``; NaN and inf where ``J M^-1 J^T`` is
    numerically singular (below ``k eps`` times its largest eigenvalue)."""
    J6 = np.array(pin.getFrameJacobian(c.model, data, c.task_frame, pin.LOCAL_WORLD_ALIGNED)).reshape(6, model.n)
    J = model.task_point().directions @ J6[:3]                  # A does not depend on the coordinate order
    A = J @ Minv_p @ J.T
    w = np.linalg.eigvalsh(A)
    if not singular_below(model, w) < w[0]:
        return {"task_inertia": np.full(A.shape, np.nan), "conditions": {"task_inertia": float("inf")}}
    Lambda = np.linalg.inv(A)
    return {"task_inertia": 0.5 * (Lambda + Lambda.T), "conditions": {"task_inertia": float(w[-1] / w[0])}}


def _joint_wrenches(c: _Compiled, data, q_p, v_p, a_p, fext=None) -> np.ndarray:
    """``data.f`` after ``rnea(q, v, a, fext)``: row ``i`` (our order) = ``[force, moment]`` the parent transmits to
    body ``i``, in its frame, about its origin (module docstring)."""
    if fext is None:
        pin.rnea(c.model, data, q_p, v_p, a_p)
    else:
        pin.rnea(c.model, data, q_p, v_p, a_p, fext)
    out = np.empty((len(c.order), 6))
    for jid in range(1, c.model.njoints):
        f = data.f[jid]
        out[c.order[c.model.joints[jid].idx_v]] = np.concatenate([f.linear, f.angular])
    return out


def _point_forces(c: _Compiled, data, con, part: np.ndarray) -> list:
    """The point forces ``(body, offset, world force)`` the multipliers ``part`` of one declaration apply (none on
    the world, none for a coupling): a circle ``2 P^T P (p - c) lam``, a loop ``D^T lam`` on a and ``-D^T lam`` on
    b, a line ``N^T lam``. Needs the frame placements."""
    if isinstance(con, PointsCoincide):
        force = con.directions.T @ part
        return [(b, o, s * force) for b, o, s in ((con.body_a, con.offset_a, 1.0), (con.body_b, con.offset_b, -1.0))
                if b is not None]
    if isinstance(con, PointOnLine):
        return [(con.body, con.offset, con.normals.T @ part)]
    if isinstance(con, PointOnCircle):
        p = np.array(data.oMf[c.points[(con.body, tuple(con.offset))]].translation)
        return [(con.body, con.offset, 2.0 * con.plane.T @ (con.plane @ (p - con.center)) * part[0])]
    return []


def _constraint_fext(model: Model, c: _Compiled, data, lam: np.ndarray) -> list:
    """The constraint forces of ``lam`` as RNEA's external forces: per joint a ``pinocchio.Force`` in its local frame
    (``R^T f``, moment ``offset x R^T f`` about the joint origin). Needs the placements (``data.oMi``, ``oMf``)."""
    fext = [pin.Force.Zero() for _ in range(c.model.njoints)]
    start = 0
    for con in model.constraints:
        part, start = lam[start:start + con.size], start + con.size
        for body, offset, force in _point_forces(c, data, con, part):
            jid = c.model.getJointId(body)
            local = np.array(data.oMi[jid].rotation).T @ force
            fext[jid] = fext[jid] + pin.Force(local, np.cross(offset, local))
    return fext


def split(model: Model, q, qd, u) -> Split:
    """Drift / control / total accelerations from Pinocchio (ABA twice; ``M^-1 B u`` by a Cholesky solve on CRBA's M:
    computeMinverse lost 256 eps on a single rotor, a fuzz finding);
    task drift from the classical acceleration of a frame at the default task point (getFrameClassicalAcceleration).
    A constrained model goes through :func:`_constrained_split` (Pinocchio's KKT forward dynamics)."""
    q, qd, u = check_state(model, q, qd, u)
    if model.constraints:
        return _constrained_split(model, q, qd, u)
    c = _compiled(model)
    pm, order = c.model, c.order
    data = pm.createData()  # fresh Data: the result cannot depend on call history
    tau_ctrl = model.input_map @ u
    qp, vp, tp = q[order], qd[order], tau_ctrl[order]
    zero = np.zeros(model.n)

    total_p = np.array(pin.aba(pm, data, qp, vp, tp))
    drift_p = np.array(pin.aba(pm, data, qp, vp, zero))
    pin.forwardKinematics(pm, data, qp, vp, drift_p)
    task_accel = pin.getFrameClassicalAcceleration(pm, data, c.task_frame, pin.LOCAL_WORLD_ALIGNED).linear
    M_p = _sym(np.array(pin.crba(pm, data, qp)))
    Minv_p = _inverse(M_p)
    g_p = np.array(pin.computeGeneralizedGravity(pm, data, qp))
    Cqd_p = np.array(pin.rnea(pm, data, qp, vp, zero)) - g_p

    def ours(vec_p):
        out = np.empty(model.n)
        out[order] = vec_p
        return out

    M = np.empty((model.n, model.n))
    M[np.ix_(order, order)] = M_p
    ctrl = scipy.linalg.cho_solve(scipy.linalg.cho_factor(M), tau_ctrl)
    Cqd, g = ours(Cqd_p), ours(g_p)
    cond_M, accel_scale = conditioning(model, M, Cqd, g, tau_ctrl, qd)
    pin.computeJointJacobians(pm, data, qp)
    return unconstrained_split(drift=ours(drift_p), ctrl=ctrl, total=ours(total_p), tau_ctrl=tau_ctrl, qd=qd,
                               cond_M=cond_M, accel_scale=accel_scale,
                               extras={"M": M, "Cqd": Cqd, "g": g},
                               task_drift=model.task_point().directions @ np.array(task_accel),
                               kinetic_energy=float(pin.computeKineticEnergy(pm, data, qp, vp)),
                               joint_wrenches=_joint_wrenches(c, data, qp, vp, total_p),
                               joint_wrenches_drift=_joint_wrenches(c, data, qp, vp, drift_p),
                               **_task_inertia(model, c, data, Minv_p))


def _to_ours(order: np.ndarray, vec_p: np.ndarray) -> np.ndarray:
    out = np.empty(len(order))
    out[order] = vec_p
    return out


def _kkt(c: _Compiled, data, q_p, v_p, tau_p, Jc_p, bias):
    """Pinocchio's constrained forward dynamics (KKT): ``M a + b = tau + J^T lambda_c``, ``J a + gamma = 0``."""
    a = np.array(pin.forwardDynamics(c.model, data, q_p, v_p, tau_p, Jc_p, bias, 0.0))
    return a, np.array(data.lambda_c)


def _constrained_split(model: Model, q, qd, u) -> Split:
    """Eq. (12)-(17) with Pinocchio: total / lam and drift / lam_drift from ``pinocchio.forwardDynamics`` with
    our ``Jc`` and ``gamma = Jcdot qd``; ctrl = B_c B u with ``M^-1`` by Cholesky on CRBA's M (eq. 17)."""
    c = _compiled(model)
    pm, order = c.model, c.order
    data = pm.createData()
    phi, Jc_p, bias = _constraint_terms(model, c, data, q, qd)
    tau_ctrl = model.input_map @ u
    qp, vp = q[order], qd[order]
    M_p = _sym(np.array(pin.crba(pm, data, qp)))
    g_p = np.array(pin.computeGeneralizedGravity(pm, data, qp))
    Cqd_p = np.array(pin.rnea(pm, data, qp, vp, np.zeros(model.n))) - g_p
    Minv_p = _inverse(M_p)
    S = Jc_p @ Minv_p @ Jc_p.T
    S_pinv, rows = _pinv_sym(model, S)
    if rows.shape[1] == len(S):     # regular: the rows as declared
        rows = np.eye(len(S))
    # singular S: Pinocchio's KKT on the independent combinations of the rows, the redundant directions dropped as
    # the formalisms drop them; lam = rows lam_r is then the minimum-norm multiplier
    J_r, bias_r = rows.T @ Jc_p, rows.T @ bias
    total_p, lam_r = _kkt(c, data, qp, vp, tau_ctrl[order], J_r, bias_r)
    drift_p, lam_drift_r = _kkt(c, data, qp, vp, np.zeros(model.n), J_r, bias_r)
    lam, lam_drift = rows @ lam_r, rows @ lam_drift_r
    B_c = Minv_p - Minv_p @ Jc_p.T @ S_pinv @ Jc_p @ Minv_p
    pin.computeJointJacobians(pm, data, qp)                      # placements and Jacobians at q, afresh
    pin.updateFramePlacements(pm, data)
    inertia = _task_inertia(model, c, data, Minv_p)
    fext, fext_drift = _constraint_fext(model, c, data, lam), _constraint_fext(model, c, data, lam_drift)
    wrenches = _joint_wrenches(c, data, qp, vp, total_p, fext), _joint_wrenches(c, data, qp, vp, drift_p, fext_drift)
    pin.forwardKinematics(pm, data, qp, vp, drift_p)
    task_accel = pin.getFrameClassicalAcceleration(pm, data, c.task_frame, pin.LOCAL_WORLD_ALIGNED).linear
    M, Jc = np.empty_like(M_p), np.empty_like(Jc_p)
    M[np.ix_(order, order)] = M_p
    Jc[:, order] = Jc_p
    return constrained_split(
        model, M=M, Cqd=_to_ours(order, Cqd_p), g=_to_ours(order, g_p), tau_ctrl=tau_ctrl, qd=qd, phi=phi, Jc=Jc,
        bias=bias, drift=_to_ours(order, drift_p), ctrl=_to_ours(order, B_c @ tau_ctrl[order]),
        total=_to_ours(order, total_p), lam=lam, lam_drift=lam_drift,
        extras={"M": M, "Cqd": _to_ours(order, Cqd_p), "g": _to_ours(order, g_p)},
        task_drift=model.task_point().directions @ np.array(task_accel),
        kinetic_energy=float(pin.computeKineticEnergy(pm, data, qp, vp)), joint_wrenches=wrenches[0],
        joint_wrenches_drift=wrenches[1], **inertia)


def _pinv_sym(model: Model, S: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Pseudo-inverse of a symmetric positive semi-definite matrix, eigenvalues below CONSTRAINT_RCOND dropped, and
    an orthonormal basis of its range (the kept eigenvectors)."""
    w, U = np.linalg.eigh(S)
    keep = w > redundant_below(model, w[-1])
    return (U[:, keep] / w[keep]) @ U[:, keep].T, U[:, keep]


_POOLS: dict[str, tuple] = {}


def _pools(model: Model) -> tuple:
    """Pinocchio ModelPools of the model and of a gravity-free copy (for ``M^-1 tau = ABA(q, 0, tau)``), cached."""
    key, pm = model.digest(), _compiled(model).model
    with _LOCK:
        if key not in _POOLS:
            still = pin.Model(pm)
            still.gravity = pin.Motion.Zero()
            _POOLS[key] = (pin.ModelPool(pm, 1), pin.ModelPool(still, 1))
    return _POOLS[key]


def split_batch(model: Model, Q, QD, U) -> SplitBatch:
    """N states with Pinocchio's batched ABA (``abaInParallel`` on one thread): total ``ABA(q, qd, B u)``, drift
    ``ABA(q, qd, 0)``, ctrl ``ABA(q, 0, B u)`` of the gravity-free model, which is ``M^-1 B u`` (eq. 9) computed
    directly. A constrained model goes state by state through :func:`split` (Pinocchio's KKT solve has no batched
    form in its Python API)."""
    Q, QD, U = check_batch(model, Q, QD, U)
    if model.constraints or not len(Q):
        return split_batch_by_loop(split)(model, Q, QD, U)
    order = _compiled(model).order
    pool, still = _pools(model)
    qp, vp = np.asfortranarray(Q[:, order].T), np.asfortranarray(QD[:, order].T)
    tp = np.asfortranarray((U @ model.input_map.T)[:, order].T)
    rest = np.zeros_like(vp)
    out = {}
    for name, (p, v, t) in {"total": (pool, vp, tp), "drift": (pool, vp, rest), "ctrl": (still, rest, tp)}.items():
        a = np.empty_like(vp)
        a[order] = np.reshape(pin.abaInParallel(1, p, qp, v, t), vp.shape)
        out[name] = a.T
    return SplitBatch(**out)


REFERENCE = Formalism(
    name="pinocchio",
    summary="External reference: Pinocchio's ABA (total, drift), CRBA (ctrl by Cholesky), RNEA (conditioning), "
            "built from our model data",
    split=split,
    split_batch=split_batch,
)

__all__ = ["REFERENCE", "constraint_kinematics", "split", "to_pinocchio"]
