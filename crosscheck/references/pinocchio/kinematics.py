"""The harness's own kinematics, from Pinocchio on the model built from OUR data (never a vote).

The harness's own helpers, :func:`mass_matrix` (tolerance scales), :func:`bias_forces` and
  :func:`task_jacobian` (the independent conditions a backend's BREAKDOWN claims are audited against) and
  :func:`constraint_kinematics` (admissible states, projection onto the constraint manifold), always use the model
  built from our data: they describe the problem the formalisms are given, not a vote.

Constraints: :func:`constraint_kinematics` forms ``phi``, ``Jc`` and ``Jcdot qd`` of the declarations
(``cases.constraints``) from Pinocchio's frame placements, frame Jacobians and classical frame accelerations (a
Pfaffian declaration's ``A`` and ``Adot qd``, ``phi`` 0, from the joint Jacobian, velocity and classical acceleration
of its body: :func:`_pfaffian_rows`),.
"""

from __future__ import annotations

from typing import NamedTuple

import numpy as np
import pinocchio as pin

from cases.constraints import JointCoupling, KnifeEdge, PointOnLine, PointsCoincide, PointVelocity, RollingContact
from cases.model import Model
from crosscheck.references.pinocchio.build import Compiled, coupling_row, from_data, ours, ours_matrix, symmetric


def mass_matrix(model: Model, q) -> np.ndarray:
    """``M(q)`` from Pinocchio's CRBA on the model of our data (:func:`to_pinocchio`; the joints' armature on its
    diagonal), in our coordinate order: the problem the formalisms are given, for the harness's tolerance scales."""
    c = from_data(model)
    M_p = symmetric(np.array(pin.crba(c.model, c.model.createData(), c.configuration(np.asarray(q, dtype=float)))))
    return ours_matrix(c.order, M_p)


def bias_forces(model: Model, q, qd) -> tuple[np.ndarray, np.ndarray]:
    """``(C qd, g)`` from RNEA on the model of our data (:func:`to_pinocchio`), in our coordinate order: the problem
    the formalisms are given."""
    c = from_data(model)
    q, qd = (np.asarray(x, dtype=float) for x in (q, qd))
    data = c.model.createData()
    q_p = c.configuration(q)
    g = np.array(pin.computeGeneralizedGravity(c.model, data, q_p))
    Cqd = np.array(pin.rnea(c.model, data, q_p, qd[c.order], np.zeros(model.n))) - g
    return ours(c.order, Cqd), ours(c.order, g)


def task_jacobian(model: Model, q) -> np.ndarray:
    """``J = D dp/dq`` (k x n, our coordinate order) of the default task point ``p`` in its task directions ``D``,
    from the model of our data (:func:`to_pinocchio`): the problem the formalisms are given."""
    c = from_data(model)
    data = c.model.createData()
    pin.computeJointJacobians(c.model, data, c.configuration(np.asarray(q, dtype=float)))
    J_p = task_rows(model, c, data)
    J = np.empty_like(J_p)
    J[:, c.order] = J_p
    return J


def body_origins(model: Model, q) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """World positions at ``q`` of every body frame's origin (its joint's origin) and centre of mass (bodies x 3
    each, in body order) and of the default task point, from the model of our data (:func:`to_pinocchio`): for
    pictures of the mechanism."""
    c = from_data(model)
    data = c.model.createData()
    pin.forwardKinematics(c.model, data, c.configuration(np.asarray(q, dtype=float)))
    pin.updateFramePlacements(c.model, data)
    joints = [c.joint_of[b.name] for b in model.bodies]
    origins = np.array([data.oMi[j].translation for j in joints])
    coms = np.array([data.oMi[j].act(c.model.inertias[j].lever) for j in joints])
    return origins, coms, np.array(data.oMf[c.task_frame].translation)


def centroidal_momentum_map(model: Model, q, qd) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The rate of the centroidal momentum ``h_G = (P, L_G)`` (linear momentum, angular momentum about the centre of
    mass; world axes) as an affine function of the accelerations, ``dh_G/dt = A_G qdd + b``: ``(A_G, b, c)`` with
    ``A_G`` (6 x nv, our order) from Pinocchio's ``ccrba``, ``b = dh_G/dt`` at ``qdd = 0``
    (``computeCentroidalMomentumTimeVariation``) and c the centre of mass (world), from the model of our data
    (:func:`to_pinocchio`): the harness's view, for the momentum checks of ``crosscheck.checks.conservation``."""
    c = from_data(model)
    data = c.model.createData()
    q_p, v_p = c.configuration(np.asarray(q, dtype=float)), np.asarray(qd, dtype=float)[c.order]
    A_p = np.array(pin.ccrba(c.model, data, q_p, v_p)).reshape(6, model.nv)
    A = np.empty_like(A_p)
    A[:, c.order] = A_p
    rate = pin.computeCentroidalMomentumTimeVariation(c.model, data, q_p, v_p, np.zeros(model.nv))
    b = np.concatenate([np.array(data.dhg.linear), np.array(data.dhg.angular)]) if rate is not None else None
    return A, b, np.array(data.com[0])


def constraint_kinematics(model: Model, q, qd) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """``phi(q)`` (k,), ``Jc = dphi/dq`` (k x n, our coordinate order) and ``Jcdot qd`` (k,) from Pinocchio's
    kinematics of the model of our data (:func:`to_pinocchio`): the harness's view of the constraints the
    formalisms are given (admissibility, projection onto the manifold)."""
    q, qd = (np.asarray(x, dtype=float) for x in (q, qd))
    c = from_data(model)
    phi, Jc_p, bias = constraint_terms(model, c, c.model.createData(), q, qd)
    Jc = np.empty_like(Jc_p)
    Jc[:, c.order] = Jc_p
    return phi, Jc, bias


def contact_sines(model: Model, q) -> np.ndarray:
    """For each RollingContact of the model (in order), ``|n x a|``: the sine of the angle between the disk's axle
    ``a = R axis`` and the ground's normal n at ``q``, from Pinocchio's placements of the model of our data (0 where
    the disk lies flat and has no contact point; the harness's tolerance scales grow as it shrinks)."""
    contacts = [con for con in model.constraints if isinstance(con, RollingContact)]
    if not contacts:
        return np.zeros(0)
    c = from_data(model)
    data = c.model.createData()
    pin.framesForwardKinematics(c.model, data, c.configuration(np.asarray(q, dtype=float)))
    return np.array([np.linalg.norm(np.cross(np.cross(con.plane[0], con.plane[1]),
                                             np.array(data.oMi[c.joint_of[con.body]].rotation) @ con.axis))
                     for con in contacts])


def _point_kinematics(c: Compiled, data, body, offset, n: int):
    """World position, linear Jacobian (3 x n, Pinocchio order) and classical acceleration at qdd = 0 of a
    body point; a world point (body None) is fixed. Needs forwardKinematics(q, v, 0) and computeJointJacobians."""
    if body is None:
        return np.array(offset, dtype=float), np.zeros((3, n)), np.zeros(3)
    fid = c.points[(body, tuple(offset))]
    pos = np.array(data.oMf[fid].translation)
    J = np.array(pin.getFrameJacobian(c.model, data, fid, pin.LOCAL_WORLD_ALIGNED)).reshape(6, n)[:3]
    acc = np.array(pin.getFrameClassicalAcceleration(c.model, data, fid, pin.LOCAL_WORLD_ALIGNED).linear)
    return pos, J, acc


class _Material(NamedTuple):
    """A body's joint placement (``R``, origin ``o``), angular velocity ``w`` (world), and the linear Jacobian ``J``
    (3 x n, Pinocchio order) and classical acceleration ``a`` at qdd = 0 of its material point at world ``p``."""

    R: np.ndarray
    o: np.ndarray
    w: np.ndarray
    J: np.ndarray
    a: np.ndarray


def _material_point(c: Compiled, data, body: str, at, n: int) -> _Material:
    """:class:`_Material` of ``body`` at the world point ``at(R, o)`` from Pinocchio's joint Jacobian and the joint's
    velocity and classical acceleration (LOCAL_WORLD_ALIGNED): ``J = J_v - [r]x J_w``, ``a = a_o + wd x r + w x (w x
    r)`` with ``r = p - o``. Needs forwardKinematics(q, v, 0) and computeJointJacobians."""
    jid = c.joint_of[body]
    R, o = np.array(data.oMi[jid].rotation), np.array(data.oMi[jid].translation)
    J6 = np.array(pin.getJointJacobian(c.model, data, jid, pin.LOCAL_WORLD_ALIGNED)).reshape(6, n)
    velocity = pin.getVelocity(c.model, data, jid, pin.LOCAL_WORLD_ALIGNED)
    w = np.array(velocity.angular)
    a_o = np.array(pin.getClassicalAcceleration(c.model, data, jid, pin.LOCAL_WORLD_ALIGNED).linear)
    wd = np.array(pin.getAcceleration(c.model, data, jid, pin.LOCAL_WORLD_ALIGNED).angular)
    r = at(R, o) - o
    return _Material(R, o, w, J6[:3] - np.cross(r, J6[3:].T).T, a_o + np.cross(wd, r) + np.cross(w, np.cross(w, r)))


def contact(con: RollingContact, R: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """A rolling contact's ``u`` (unit, in the disk plane, away from the ground), ``|n - (n.a) a|`` and the axis
    ``a = R axis`` (``cases.constraints``)."""
    n, a = np.cross(con.plane[0], con.plane[1]), R @ con.axis
    raw = n - (n @ a) * a
    return raw / np.linalg.norm(raw), np.linalg.norm(raw), a


def rolling_direction(con: RollingContact, a: np.ndarray) -> tuple[np.ndarray, float]:
    """A rolling contact's rolling direction ``t = (a x n) / |a x n|`` and ``|a x n|`` (``cases.constraints``)."""
    b = np.cross(a, np.cross(con.plane[0], con.plane[1]))
    size = float(np.linalg.norm(b))
    return b / size, size


def _pfaffian_rows(model: Model, c: Compiled, data, con, v_p: np.ndarray):
    """phi (0), A (Pinocchio order) and Adot qd of a Pfaffian declaration (``cases.constraints``), from
    :func:`_material_point`: a knife edge's ``e = R d`` turns with ``w``; a rolling contact's material point at the
    contact ``p_c = c - r u`` has ``A = T J`` and ``Adot qd = T (a + w x (edot - w x e))``, ``e = -r u``, ``edot = -r
    udot`` (the contact slides over the disk); with ``lateral=False`` the one row ``t^T J`` along the rolling direction
    ``t = (a x n) / |a x n|``, its bias ``t . (a + w x (edot - w x e)) + tdot . (J qd)``, ``tdot = (bdot - t (t.bdot))
    / |a x n|``, ``bdot = (w x a) x n``."""
    n = model.n
    if isinstance(con, PointVelocity):
        x = _material_point(c, data, con.body, lambda R, o: o + R @ con.offset, n)
        return np.zeros(con.size), con.directions @ x.J, con.directions @ x.a
    if isinstance(con, KnifeEdge):
        x = _material_point(c, data, con.body, lambda R, o: o + R @ con.offset, n)
        e = x.R @ con.direction
        return np.zeros(1), (e @ x.J)[None, :], np.array([np.cross(x.w, e) @ (x.J @ v_p) + e @ x.a])
    x = _material_point(c, data, con.body,
                        lambda R, o: o + R @ con.center - con.radius * contact(con, R)[0], n)
    u, length, a = contact(con, x.R)
    n_ground = np.cross(con.plane[0], con.plane[1])
    a_dot = np.cross(x.w, a)
    raw_dot = -(n_ground @ a_dot) * a - (n_ground @ a) * a_dot
    e, e_dot = -con.radius * u, -con.radius * (raw_dot - (u @ raw_dot) * u) / length
    rate = x.a + np.cross(x.w, e_dot - np.cross(x.w, e))
    if not con.lateral:     # the rolling direction t = b / |b|, b = a x n; tdot = (bdot - t (t.bdot)) / |b|
        t, size = rolling_direction(con, a)
        b_dot = np.cross(a_dot, n_ground)
        t_dot = (b_dot - (t @ b_dot) * t) / size
        return np.zeros(1), (t @ x.J)[None, :], np.array([t @ rate + t_dot @ (x.J @ v_p)])
    return np.zeros(2), con.plane @ x.J, con.plane @ rate


def _rows(model: Model, c: Compiled, data, con, q: np.ndarray, v_p: np.ndarray):
    """phi, Jc (Pinocchio order) and Jcdot qd of one declaration (the formulas of ``cases.constraints``)."""
    n = model.n
    if not con.holonomic:
        return _pfaffian_rows(model, c, data, con, v_p)
    if isinstance(con, JointCoupling):
        phi = coupling_row(model, con, "q_index") @ q - con.offset
        return np.array([phi]), coupling_row(model, con)[c.order][None, :], np.zeros(1)
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


def constraint_terms(model: Model, c: Compiled, data, q: np.ndarray, qd: np.ndarray):
    """phi, Jc (Pinocchio's coordinate order), Jcdot qd; leaves data with the kinematics at (q, qd, 0)."""
    qp, vp = c.configuration(q), qd[c.order]
    pin.forwardKinematics(c.model, data, qp, vp, np.zeros(model.n))
    pin.computeJointJacobians(c.model, data, qp)
    pin.updateFramePlacements(c.model, data)
    rows = [_rows(model, c, data, con, q, vp) for con in model.constraints]
    return (np.concatenate([r[0] for r in rows]), np.vstack([r[1] for r in rows]),
            np.concatenate([r[2] for r in rows]))


def task_rows(model: Model, c: Compiled, data) -> np.ndarray:
    """The task Jacobian ``D J`` (k x n, Pinocchio's order): the task frame's ``LOCAL_WORLD_ALIGNED`` linear
    Jacobian in the task directions. Needs computeJointJacobians."""
    J6 = np.array(pin.getFrameJacobian(c.model, data, c.task_frame, pin.LOCAL_WORLD_ALIGNED)).reshape(6, model.n)
    return model.task_point().directions @ J6[:3]
