"""Recursive Newton–Euler in twist/wrench form (article 6.2.5 and eq. 27; Lynch & Park ch. 8.3).

Every quantity of body ``i`` is expressed in body frame ``i`` about the body-frame origin:

* forward pass: the body twist ``V_i = Ad_{T_i^-1} J_s,i qd`` and acceleration
  ``Vdot_i = Ad_{T_i^-1} (J_s,i qdd + Jdot_s,i qd)`` from the product-of-exponentials kinematics (eq. 20); these
  are the values of Lynch & Park's forward iterations ``V_i = Ad_{T_i,parent} V_parent + B_i qd_i``;
* backward pass, tip to base, the wrench balance of eq. (27) solved for the wrench ``F_i = (moment, force)``
  the parent exerts on body ``i`` through joint ``i``::

      F_i = G_i Vdot_i - ad_{V_i}^T (G_i V_i) - W_gravity,i - W_ext,i + sum_children Ad_{T_c,i}^T F_c

  with ``G_i`` the 6x6 spatial inertia about the body-frame origin, ``W_gravity,i = (c_i x m_i g_i, m_i g_i)``
  the weight applied at the COM (``g_i`` gravity in body frame ``i``; no accelerating-base trick), ``W_ext,i``
  any other wrench applied to the body (the constraint wrenches ``W_constr`` of eq. 27) and
  ``T_c,i = T_c^-1 T_i`` (child <- parent), whose adjoint transposed carries the child's wrench to the parent.

Sign convention: the article writes eq. (27) as ``I Vdot + ad*_V (I V) + W_g = W_ctrl + ...`` with the coadjoint
``ad*_V = -ad_V^T`` (Featherstone's ``V x*``) and ``W_g`` the gravity load moved to the left side (``-W_gravity``);
with the transpose ``ad_V^T`` it reads ``G Vdot - ad_V^T (G V) - W_gravity``, as here.

The joint torque is the wrench's component along the joint screw, ``tau_i = B_i^T F_i``. The recursion is
vectorized over columns: ``k`` sets of ``(qd, qdd, gravity on/off)`` go through one pass.
"""

from __future__ import annotations

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


def gravity_wrenches(model: Model, kin: Kinematics) -> np.ndarray:
    """``W_gravity,i = (c_i x f_i, f_i)`` with ``f_i = m_i R_i^T gravity``: the weight of body ``i`` acting at its
    COM, as a wrench about the body-frame origin in body frame ``i`` (n, 6)."""
    mass = np.array([b.mass for b in model.bodies])[:, None]
    force = mass * (model.gravity @ kin.poses[:, :3, :3])      # row i: R_i^T gravity, times m_i
    com = np.array([b.com for b in model.bodies])
    return np.concatenate([lie.cross(com, force), force], axis=1)


def _child_to_parent(kin: Kinematics) -> np.ndarray:
    """``Ad_{T_i,parent}`` (n, 6, 6) with ``T_i,parent = T_i^-1 T_parent``: maps a twist from the parent's frame to
    body ``i``'s frame (the world's for a root)."""
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
    """Eq. (27) for ``k`` columns: ``qd``, ``qdd`` (n, k) and ``gravity`` (k,) weights (1 on, 0 off);
    ``external`` (n, k, 6), when given, are further wrenches applied to the bodies, ``(moment about body i's
    origin, force)`` in body frame ``i``.

    Returns (n, k, 6): for each body ``i`` and column, the wrench ``(moment, force)`` the parent exerts on body
    ``i`` through joint ``i``, about body ``i``'s origin in body frame ``i``.
    """
    model = kin.model
    to_body = kin.to_body[:, None]                            # broadcast over the columns
    V = (to_body @ kinematics.twists(kin, qd)[..., None])[..., 0]
    Vdot = (to_body @ kinematics.spatial_accelerations(kin, qd, qdd)[..., None])[..., 0]
    G = spatial_inertias(model)[:, None]
    F = ((G @ Vdot[..., None])[..., 0] - lie.coad(V, (G @ V[..., None])[..., 0])
         - gravity[None, :, None] * gravity_wrenches(model, kin)[:, None, :])
    if external is not None:
        F = F - external
    Ad_cp = _child_to_parent(kin)
    for i in reversed(model.topological_order):                # backward pass, tip to base
        p = model.parent_index[i]
        if p >= 0:
            F[p] += _wrench_to_parent(Ad_cp[i], F[i])
    return F


def joint_torques(kin: Kinematics, F: np.ndarray) -> np.ndarray:
    """``tau_i = B_i^T F_i`` for every body and column: (n, k) from wrenches (n, k, 6)."""
    return np.einsum("ia,ika->ik", kin.screws.body_axes, F)


def inverse_dynamics(model: Model, q, qd, qdd, gravity: bool = True) -> np.ndarray:
    """The generalized force ``M qdd + C qd (+ g)`` of eq. (2), from the wrench balance of eq. (27)."""
    q, qd, qdd = joint_vectors(model, q, qd, qdd)
    kin = kinematics.forward_kinematics(model, q)
    F = wrenches(kin, qd[:, None], qdd[:, None], np.array([float(gravity)]))
    return joint_torques(kin, F)[:, 0]


def terms(kin: Kinematics, qd: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """``(M, h, C qd, g)`` of eq. (2) from one vectorized pass of eq. (27) over ``n + 3`` columns.

    Column ``j < n`` is ``M e_j`` (``qd = 0``, no gravity, ``qdd = e_j``); then ``h = C qd + g`` (``qdd = 0``),
    ``C qd`` (gravity off) and ``g`` (``qd = 0``). M is symmetrized to remove rounding.
    """
    n = kin.model.n
    zero = np.zeros((n, 1))
    rates = np.hstack([np.zeros((n, n)), qd[:, None], qd[:, None], zero])
    accelerations = np.hstack([np.eye(n), zero, zero, zero])
    gravity = np.r_[np.zeros(n), 1.0, 0.0, 1.0]
    tau = joint_torques(kin, wrenches(kin, rates, accelerations, gravity))
    M = tau[:, :n]
    return 0.5 * (M + M.T), tau[:, n], tau[:, n + 1], tau[:, n + 2]


def mass_matrix(model: Model, q) -> np.ndarray:
    """``M(q)`` of eq. (2): column ``j`` is eq. (27) with ``qd = 0``, no gravity and ``qdd = e_j``, all in one pass."""
    (q,) = joint_vectors(model, q)
    kin, n = kinematics.forward_kinematics(model, q), model.n
    M = joint_torques(kin, wrenches(kin, np.zeros((n, n)), np.eye(n), np.zeros(n)))
    return 0.5 * (M + M.T)
