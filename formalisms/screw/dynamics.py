"""Recursive Newton–Euler in twist/wrench form (article 6.2.5 and eq. 27; Lynch & Park ch. 8.2-8.3).

The forward dynamics needs ``M`` and ``h = C qd + g`` of eq. (2); both come from the world-frame (space) form, which
needs no frame change between bodies and so evaluates a whole stack of states at once (leading axes, as in
:mod:`~formalisms.screw.kinematics`):

* the spatial inertia of body ``i`` in the world frame, about the world origin, ``G_s,i = Ad_{T_i^-1}^T G_i
  Ad_{T_i^-1}``, kept as its blocks: rotational ``I_s = R I_c R^T - m [c_w]^2``, first moment ``h_s = m c_w``
  (``c_w`` the COM in the world) and mass ``m``, so that ``G_s (w, v) = (I_s w + h_s x v, m v - h_s x w)``;
* ``M = sum_i J_s,i^T G_s,i J_s,i`` (the kinetic-energy metric, L&P eq. 8.39 with space Jacobians), summed as
  ``M_jk = S_j(q)^T G_c,k S_k(q)`` for ``j`` at or before ``k``, ``G_c,k`` the composite inertia of the bodies
  joint ``k`` moves (0 where neither joint moves the other's body);
* eq. (27) in the world frame: the momentum ``G_s V_s`` changes as ``G_s Vdot_s - ad_{V_s}^T (G_s V_s)``, so the
  wrench joint ``i`` carries is ``F_s,i = sum over the bodies it moves of (G_s Vdot_s - ad_{V_s}^T (G_s V_s) -
  W_gravity - W_ext)`` and its generalized force is ``tau_i = S_i(q)^T F_s,i``.

The joint loads (``wrenches``) use the body-frame form: every quantity of body ``i`` in body frame ``i`` about the
body-frame origin, the body twist ``V_i = Ad_{T_i^-1} J_s,i qd`` and acceleration ``Vdot_i = Ad_{T_i^-1} (J_s,i
qdd + Jdot_s,i qd)`` (the values of Lynch & Park's forward iterations), and the backward pass, tip to base::

      F_i = G_i Vdot_i - ad_{V_i}^T (G_i V_i) - W_gravity,i - W_ext,i + sum_children Ad_{T_c,i}^T F_c

with ``G_i`` the 6x6 spatial inertia about the body-frame origin, ``W_gravity,i`` the weight applied at the COM
(no accelerating-base trick), ``W_ext,i`` any other wrench applied to the body (the constraint wrenches ``W_constr``
of eq. 27) and ``T_c,i = T_c^-1 T_i`` (child <- parent), whose adjoint transposed carries the child's wrench to the
parent.

Sign convention: the article writes eq. (27) as ``I Vdot + ad*_V (I V) + W_g = W_ctrl + ...`` with the coadjoint
``ad*_V = -ad_V^T`` (Featherstone's ``V x*``) and ``W_g`` the gravity load moved to the left side (``-W_gravity``);
with the transpose ``ad_V^T`` it reads ``G Vdot - ad_V^T (G V) - W_gravity``, as here.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from cases.model import Model
from formalisms.interface import joint_vectors
from formalisms.screw import kinematics, lie
from formalisms.screw.kinematics import Kinematics


def spatial_inertias(model: Model) -> np.ndarray:
    """``G_i`` (n, 6, 6) about body ``i``'s origin, for twists ``(w, v)``: with ``C = [c_i]``,
    ``G = [[I_c - m C C, m C], [-m C, m 1]]`` (the COM inertia moved to the origin by the parallel-axis rule)."""
    mass = np.array([b.mass for b in model.bodies])[:, None, None]
    C = lie.hat3(np.array([b.com for b in model.bodies]))
    G = np.empty((model.n, 6, 6))
    G[:, :3, :3] = np.array([b.inertia for b in model.bodies]) - mass * (C @ C)
    G[:, :3, 3:] = mass * C
    G[:, 3:, :3] = -mass * C
    G[:, 3:, 3:] = mass * np.eye(3)
    return G


@dataclass(frozen=True)
class SpaceInertias:
    """``G_s`` of every body (or composite of bodies) in the world frame about the world origin, by blocks
    (module docstring): ``rotational`` (..., n, 3, 3), ``first_moment`` ``m c_w`` (..., n, 3), ``mass`` (n,)."""

    rotational: np.ndarray
    first_moment: np.ndarray
    mass: np.ndarray

    def apply(self, V: np.ndarray) -> np.ndarray:  # noqa: N803
        """``G_s V = (I_s w + h x v, m v - h x w)`` for twists ``V = (w, v)`` (..., n, 6): the spatial momentum."""
        w, v, h = V[..., :3], V[..., 3:], self.first_moment
        return lie.join(lie.rotate(self.rotational, w) + lie.cross(h, v), self.mass[:, None] * v - lie.cross(h, w))


def space_inertias(kin: Kinematics) -> SpaceInertias:
    """``G_s,i = Ad_{T_i^-1}^T G_i Ad_{T_i^-1}`` from the blocks of :func:`spatial_inertias`: ``I_s = R I_c R^T -
    m [c_w]^2`` with ``I_c = I_o + m [c]^2`` (``I_o`` the rotational block about the body origin) and ``m [c_w]^2 =
    h c_w^T - (h . c_w) 1``, ``h = m c_w``. Bodies without rotational inertia (point masses) skip ``R I_c R^T``."""
    model = kin.model
    G = spatial_inertias(model)
    mass, first = G[:, 3, 3], lie.vee3(G[:, :3, 3:])           # m, m c (body frame)
    com = np.array([b.com for b in model.bodies])
    inertia_com = G[:, :3, :3] + lie.hat3(first) @ lie.hat3(com)
    R, p = kin.poses[..., :3, :3], kin.poses[..., :3, 3]
    h = mass[:, None] * p + lie.rotate(R, first)
    c_w = p + lie.rotate(R, com)
    rotational = lie.dot(h, c_w)[..., None, None] * np.eye(3) - h[..., :, None] * c_w[..., None, :]
    spinning = np.flatnonzero(np.any(inertia_com != 0.0, axis=(1, 2)))
    if len(spinning):
        Rs = R[..., spinning, :, :]
        rotational[..., spinning, :, :] += lie.matmul(lie.matmul(Rs, inertia_com[spinning]), np.swapaxes(Rs, -1, -2))
    return SpaceInertias(rotational, h, mass)


def composite(kin: Kinematics, G: SpaceInertias) -> SpaceInertias:
    """``G_c,j``: the sum of ``G_s,i`` over the bodies joint ``j`` moves (its subtree)."""
    shape = G.rotational.shape
    rotational = kinematics.subtree_sum(kin, G.rotational.reshape(shape[:-2] + (9,))).reshape(shape)
    return SpaceInertias(rotational, kinematics.subtree_sum(kin, G.first_moment),
                         kin.screws.support.T @ G.mass)


def mass_matrix_of(kin: Kinematics, G: SpaceInertias) -> np.ndarray:
    """``M`` (..., n, n) of eq. (2) as ``sum_i J_s,i^T G_s,i J_s,i``: ``M_jk = S_j^T G_c,k S_k`` for ``j`` at or before
    ``k`` (module docstring), mirrored."""
    S = kin.columns
    Y = composite(kin, G).apply(S)                             # G_c,k S_k
    P = lie.matmul(S, np.swapaxes(Y, -1, -2))                 # P_jk = S_j . G_c,k S_k
    support = kin.screws.support
    return P * support.T + np.swapaxes(P * (support.T - np.eye(len(support))), -1, -2)


def gravity_wrenches(model: Model, kin: Kinematics, G: SpaceInertias | None = None) -> np.ndarray:
    """``W_gravity,i = (c_w x m g, m g) = (h_s x g, m g)``: the weight of body ``i`` acting at its COM, as a wrench
    in the world frame about the world origin (..., n, 6); ``G`` from :func:`space_inertias` when at hand."""
    G = space_inertias(kin) if G is None else G
    gravity = np.asarray(model.gravity, dtype=float)
    force = G.mass[:, None] * gravity
    return lie.join(lie.cross(G.first_moment, gravity), force)


def space_wrenches(kin: Kinematics, G: SpaceInertias, qd: np.ndarray, qdd: np.ndarray | None, gravity) -> np.ndarray:
    """Eq. (27) in the world frame (module docstring): the wrench ``F_s,i`` (..., n, 6) joint ``i`` carries, moment
    about the world origin, for rates ``qd``, ``qdd`` (None: zero) (..., n) and the weight ``gravity`` (1 on, 0 off;
    broadcast against the leading axes)."""
    V = kinematics.twists(kin, qd)
    Vdot = (kinematics.bias_accelerations(kin, qd) if qdd is None
            else kinematics.spatial_accelerations(kin, qd, qdd))
    weight = np.asarray(gravity, dtype=float)[..., None, None] * gravity_wrenches(kin.model, kin, G)
    own = G.apply(Vdot) - lie.coad(V, G.apply(V)) - weight
    return kinematics.subtree_sum(kin, own)


def generalized_forces(kin: Kinematics, F: np.ndarray) -> np.ndarray:  # noqa: N803
    """``tau_i = S_i(q)^T F_s,i`` (..., n) from the space wrenches the joints carry."""
    return lie.dot(kin.columns, F)


def terms(kin: Kinematics, qd: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """``(M, h, C qd, g)`` of eq. (2) at one state: M from the composite inertias, and eq. (27) for three
    columns, ``h = C qd + g`` (``qdd = 0``), ``C qd`` (gravity off) and ``g`` (``qd = 0``)."""
    G = space_inertias(kin)
    rates = np.stack([qd, qd, np.zeros_like(qd)])
    tau = generalized_forces(kin, space_wrenches(kin, G, rates, None, np.array([1.0, 0.0, 1.0])))
    return mass_matrix_of(kin, G), tau[0], tau[1], tau[2]


def inverse_dynamics(model: Model, q, qd, qdd, gravity: bool = True) -> np.ndarray:
    """The generalized force ``M qdd + C qd (+ g)`` of eq. (2), from the wrench balance of eq. (27)."""
    q, qd, qdd = joint_vectors(model, q, qd, qdd)
    kin = kinematics.forward_kinematics(model, q)
    return generalized_forces(kin, space_wrenches(kin, space_inertias(kin), qd, qdd, float(gravity)))


def mass_matrix(model: Model, q) -> np.ndarray:
    """``M(q)`` of eq. (2) from the composite inertias (:func:`mass_matrix_of`)."""
    (q,) = joint_vectors(model, q)
    kin = kinematics.forward_kinematics(model, q)
    return mass_matrix_of(kin, space_inertias(kin))


def _child_to_parent(kin: Kinematics) -> np.ndarray:
    """``Ad_{T_i,parent}`` (n, 6, 6) with ``T_i,parent = T_i^-1 T_parent``: maps a twist from the parent's frame to
    body ``i``'s frame (the world's for a root). One state."""
    model = kin.model
    parents = np.array(model.parent_index)
    parent_poses = np.where((parents < 0)[:, None, None], np.eye(4), kin.poses[parents])
    return lie.Ad(lie.inv(kin.poses) @ parent_poses)


def _wrench_to_parent(Ad_child_parent: np.ndarray, F_child: np.ndarray) -> np.ndarray:  # noqa: N803
    """``Ad_{T_c,p}^T F_c``: the wrench ``F_c`` (rows of ``(moment, force)`` in the child's frame) expressed in the
    parent's frame. A wrench maps by the inverse transpose of the twist map ``Ad_{T_p,c} = Ad_{T_c,p}^-1``, which
    keeps the power ``F . V`` invariant (article 7.4). Row form: ``(Ad^T F^T)^T = F Ad``."""
    return F_child @ Ad_child_parent


def wrenches(kin: Kinematics, qd: np.ndarray, qdd: np.ndarray, gravity: np.ndarray,
             external: np.ndarray | None = None) -> np.ndarray:
    """The body-frame form of eq. (27) (module docstring) at one state for ``k`` columns: ``qd``, ``qdd`` (k, n) and
    ``gravity`` (k,) weights (1 on, 0 off); ``external`` (k, n, 6), when given, are further wrenches applied to the
    bodies, ``(moment about body i's origin, force)`` in body frame ``i``.

    Returns (k, n, 6): for each column and body ``i``, the wrench ``(moment, force)`` the parent exerts on body
    ``i`` through joint ``i``, about body ``i``'s origin in body frame ``i``.
    """
    model = kin.model
    V = (kin.to_body @ kinematics.twists(kin, qd)[..., None])[..., 0]
    Vdot = (kin.to_body @ kinematics.spatial_accelerations(kin, qd, qdd)[..., None])[..., 0]
    G = spatial_inertias(model)
    weight = lie.wrench_to_body(kin.poses, gravity_wrenches(model, kin))      # F_b = Ad_{T_i}^T F_s
    F = ((G @ Vdot[..., None])[..., 0] - lie.coad(V, (G @ V[..., None])[..., 0])
         - np.asarray(gravity, dtype=float)[:, None, None] * weight)
    if external is not None:
        F = F - external
    Ad_cp = _child_to_parent(kin)
    for i in reversed(model.topological_order):                # backward pass, tip to base
        p = model.parent_index[i]
        if p >= 0:
            F[:, p] += _wrench_to_parent(Ad_cp[i], F[:, i])
    return F
