"""Recursive Newton–Euler in twist/wrench form (article 6.2.5 and eq. 27; Lynch & Park ch. 8.2-8.3), in body frames.

Every quantity of body ``i`` is taken in body frame ``i`` about the body-frame origin, so that no moment is taken
about the world origin: a moment there is ``|p| |f|`` large where the joint torque it feeds is ``lever |f|``, and
summing it loses digits ``eps |p|^2`` to cancellation. All functions take a stack of states (leading axes, as in
:mod:`~formalisms.screw.kinematics`):

* ``G_i`` the 6x6 spatial inertia of body ``i`` about its origin, kept as its blocks (:class:`Inertias`):
  rotational ``I_o = I_c - m [c]^2``, first moment ``m c`` and mass ``m``, so that ``G (w, v) = (I_o w + m c x v,
  m v - m c x w)``;
* ``M = sum_i J_b,i^T G_i J_b,i`` (the kinetic-energy metric, L&P eq. 8.39 with body Jacobians): ``M_jk = sum_i
  (J_b,i e_j) . G_i (J_b,i e_k)``, each column of ``J_b,i`` the lever of joint ``j`` about body ``i``'s origin;
* eq. (27) body by body, with the body twist ``V_i`` and acceleration ``Vdot_i`` of Lynch & Park's forward
  iterations (:func:`~formalisms.screw.kinematics.body_motion`), and the backward pass, tip to base::

      F_i = G_i Vdot_i - ad_{V_i}^T (G_i V_i) - W_gravity,i - W_ext,i + sum_children Ad_{T_c,i}^T F_c

  with ``W_gravity,i`` the weight applied at the COM (no accelerating-base trick), ``W_ext,i`` any other wrench applied
  to the body (the constraint wrenches ``W_constr`` of eq. 27) and ``T_c,i = T_c^-1 T_i`` (child <- parent), whose
  adjoint transposed carries the child's wrench to the parent. ``F_i`` is the wrench the parent exerts on body ``i``
  through joint ``i`` and its generalized force is ``tau_i = B_i^T F_i`` (``B_i`` the body screw axis).

Spherical and free joints (article 2.1-2.2, 6.2): the same two passes, with the body twists and accelerations of a
group joint (:mod:`~formalisms.screw.kinematics`: ``V_i = Ad_{g_i^-1 M^-1} V_parent + E_i v_i``, the acceleration
with the ``ad`` term); the backward pass is unchanged, and the joint's generalized forces are the projections ``tau_j
= E_j^T F_i`` on its constant unit twists: a spherical joint carries the moment ``m`` (body frame) and a free joint
``(f, m)``, all of ``F_i``, in the order ``(linear, angular)`` of its velocity block. So a free root's ``F_i`` is the
input's wrench on it (zero when unactuated), and ``M``'s block of a free body is ``E^T G E``, ``G`` reordered.

External loads (``cases.loads``, article 2.3, 6.2.5): each declaration is a body wrench ``W_ext,i = (offset x f +
m, f)`` in body frame ``i`` about its origin (:func:`external_wrenches`: a world vector is ``R_i^T x`` there, a
spring's force formed from the point ``p_i + R_i offset``); they enter eq. (27) as ``W_ext`` and their generalized
force is ``tau_ext = sum_i J_b,i^T W_ext,i`` through the body Jacobians (:func:`external_forces`), the dual of the
body twists ``V_b,i = J_b,i qd``: no pass over the tree.

Armature (``Body.armature`` a, a rotor geared to the joint): its kinetic energy ``1/2 a |v_j|^2`` is a constant
metric on the joint's velocity columns, so ``M = sum_i J_b,i^T G_i J_b,i + diag(a)`` and the joint's generalized
force gains ``a_j qdd_j`` (:class:`Inertias` ``rotors``); it has no twist of its own, so the wrench recursion, ``h``
and the joint wrenches are the links' alone.

Sign convention: the article writes eq. (27) as ``I Vdot + ad*_V (I V) + W_g = W_ctrl + ...`` with the coadjoint
``ad*_V = -ad_V^T`` (Featherstone's ``V x*``) and ``W_g`` the gravity load moved to the left side (``-W_gravity``);
with the transpose ``ad_V^T`` it reads ``G Vdot - ad_V^T (G V) - W_gravity``, as here.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from cases.loads import ExternalWrench, PointSpring
from cases.model import JOINT_DOF, Model
from formalisms.interface import joint_vectors
from formalisms.screw import kinematics, lie
from formalisms.screw.kinematics import Kinematics


def spatial_inertias(model: Model) -> np.ndarray:
    """``G_i`` (nb, 6, 6) about body ``i``'s origin, for twists ``(w, v)``: with ``C = [c_i]``,
    ``G = [[I_c - m C C, m C], [-m C, m 1]]`` (the COM inertia moved to the origin by the parallel-axis rule)."""
    mass = np.array([b.mass for b in model.bodies])[:, None, None]
    C = lie.hat3(np.array([b.com for b in model.bodies]))
    G = np.empty((len(model.bodies), 6, 6))
    G[:, :3, :3] = np.array([b.inertia for b in model.bodies]) - mass * (C @ C)
    G[:, :3, 3:] = mass * C
    G[:, 3:, :3] = -mass * C
    G[:, 3:, 3:] = mass * np.eye(3)
    return G


@dataclass(frozen=True)
class Inertias:
    """The ``G_i`` of :func:`spatial_inertias`: ``matrix`` (n, 6, 6) and its blocks (module docstring), ``rotational``
    ``I_o`` (n, 3, 3), ``first_moment`` ``m c`` (n, 3), ``mass`` (n,); and the joints' rotors, ``rotors`` (nv,): each
    velocity's armature (module docstring, "Armature")."""

    matrix: np.ndarray
    rotational: np.ndarray
    first_moment: np.ndarray
    mass: np.ndarray
    rotors: np.ndarray

    @classmethod
    def of(cls, model: Model) -> "Inertias":
        """``spatial_inertias(model)`` and its blocks, and the rotors of the joints' velocity columns."""
        G = spatial_inertias(model)
        rotors = np.array([b.armature for b in model.bodies for _ in range(JOINT_DOF[b.joint][1])], dtype=float)
        return cls(G, G[:, :3, :3], lie.vee3(G[:, :3, 3:]), G[:, 3, 3], rotors)

    def apply(self, V: np.ndarray) -> np.ndarray:  # noqa: N803
        """``G_i V_i = (I_o w + h x v, m v - h x w)``, ``h = m c``, for twists ``V = (w, v)`` (..., nb, 6) in the body
        frames: the spatial momentum about the body origins."""
        w, v, h = V[..., :3], V[..., 3:], self.first_moment
        return lie.join(lie.rotate(self.rotational, w) + lie.cross(h, v), self.mass[:, None] * v - lie.cross(h, w))


def mass_matrix_of(kin: Kinematics, G: Inertias) -> np.ndarray:  # noqa: N803
    """``M`` (..., nv, nv) of eq. (2) as ``sum_i J_b,i^T G_i J_b,i`` (module docstring), symmetrized exactly; ``G`` the
    bodies' inertias (:meth:`Inertias.of`)."""
    columns = kin.body_columns                                   # [..., i, j, :] = J_b,i e_j
    momenta = columns @ np.swapaxes(G.matrix, -1, -2)            # [..., i, j, :] = G_i J_b,i e_j
    P = (columns @ np.swapaxes(momenta, -1, -2)).sum(axis=-3)
    return 0.5 * (P + np.swapaxes(P, -1, -2)) + np.diag(G.rotors)


def gravity_wrenches(model: Model, kin: Kinematics) -> np.ndarray:
    """``W_gravity,i = (c x m g_i, m g_i)`` with ``g_i = R_i^T g``: the weight of body ``i`` acting at its COM, as a
    wrench in body frame ``i`` about its origin (..., nb, 6)."""
    mass = np.array([b.mass for b in model.bodies])[:, None]
    g = lie.rotate_back(kin.poses[..., :3, :3], np.asarray(model.gravity, dtype=float))
    return lie.join(lie.cross(mass * np.array([b.com for b in model.bodies]), g), mass * g)


def external_wrenches(model: Model, kin: Kinematics) -> np.ndarray | None:
    """The external loads as body wrenches ``(moment about body i's origin, force)`` in body frame ``i``, summed per
    body (..., nb, 6) (module docstring); None without loads."""
    if not model.loads:
        return None
    R, origin = kin.poses[..., :3, :3], kin.poses[..., :3, 3]
    W = np.zeros(kin.q.shape[:-1] + (len(model.bodies), 6))
    for load in model.loads:
        i = model.body_index(load.body)
        offset = np.asarray(load.offset, dtype=float)
        couple = np.zeros(3)
        if isinstance(load, PointSpring):
            d = origin[..., i, :] + lie.rotate(R[..., i, :, :], offset) - load.anchor
            length = np.sqrt(lie.dot(d, d))[..., None]
            scale = -load.stiffness * ((1.0 - load.rest_length / length) if load.rest_length else 1.0)
            f = lie.rotate_back(R[..., i, :, :], scale * d)
        elif load.frame == "world":
            f = lie.rotate_back(R[..., i, :, :], np.asarray(load.force, dtype=float))
            if isinstance(load, ExternalWrench):
                couple = lie.rotate_back(R[..., i, :, :], np.asarray(load.moment, dtype=float))
        else:
            f = np.broadcast_to(np.asarray(load.force, dtype=float), W.shape[:-2] + (3,))
            if isinstance(load, ExternalWrench):
                couple = np.asarray(load.moment, dtype=float)
        W[..., i, :] += about_origin(np.broadcast_to(offset, f.shape), f, couple)
    return W


def about_origin(offset: np.ndarray, f: np.ndarray, couple) -> np.ndarray:
    """The body wrench ``(offset x f + couple, f)`` about the body origin of a force ``f`` at the body point ``offset``
    and a couple (body frame, stacks)."""
    return lie.join(lie.cross(offset, f) + couple, f)


def external_forces(kin: Kinematics, W: np.ndarray) -> np.ndarray:  # noqa: N803
    """``tau_ext = sum_i J_b,i^T W_i`` (..., nv) for body wrenches ``W`` (..., nb, 6): the power ``W_i . V_b,i`` of each
    body's wrench on its body twist, per joint rate."""
    return (kin.body_columns @ W[..., :, :, None])[..., 0].sum(axis=-2)


def _wrench_to_parent(Ad_child_parent: np.ndarray, F_child: np.ndarray) -> np.ndarray:  # noqa: N803
    """``Ad_{T_c,p}^T F_c``: the wrench ``F_c = (m, f)`` (rows, child's frame, moment about its origin) in the parent's
    frame about the parent's origin, ``T_c,p`` the parent's frame in the child's (:attr:`Kinematics.from_parent`). A
    wrench maps by the inverse transpose of the twist map ``Ad_{T_p,c} = Ad_{T_c,p}^-1``, which keeps the power
    ``F . V`` invariant (article 7.4). Row form: ``(Ad^T F^T)^T = F Ad``."""
    return (F_child[..., None, :] @ Ad_child_parent)[..., 0, :]


def wrenches(kin: Kinematics, G: Inertias, qd: np.ndarray, qdd: np.ndarray | None, gravity,  # noqa: N803
             external: np.ndarray | None = None) -> np.ndarray:
    """Eq. (27) in body frames (module docstring) with the bodies' inertias ``G`` (:meth:`Inertias.of`), for rates
    ``qd``, ``qdd`` (None: zero) (..., nv), the weight ``gravity`` (1 on, 0 off) and ``external`` (..., nb, 6), when
    given, further wrenches applied to the bodies, ``(moment about body i's origin, force)`` in body frame ``i``;
    the leading axes broadcast.

    Returns (..., nb, 6): the wrench ``(moment, force)`` the parent exerts on body ``i`` through joint ``i``, about
    body ``i``'s origin in body frame ``i``.
    """
    model = kin.model
    V, Vdot = kinematics.body_motion(kin, qd, qdd)
    weight = np.asarray(gravity, dtype=float)[..., None, None] * gravity_wrenches(model, kin)
    F = G.apply(Vdot) - lie.coad(V, G.apply(V)) - weight
    if external is not None:
        F = F - external
    for i in reversed(model.topological_order):                # backward pass, tip to base
        p = model.parent_index[i]
        if p >= 0:
            F[..., p, :] += _wrench_to_parent(kin.from_parent_adjoint[..., i, :, :], F[..., i, :])
    return F


def generalized_forces(kin: Kinematics, F: np.ndarray) -> np.ndarray:  # noqa: N803
    """``tau_j = E_j^T F_i`` (..., nv) from the body wrenches the joints carry (..., nb, 6): ``B_i^T F_i`` for a
    screw joint, the components of ``F_i`` along a group joint's unit twists."""
    return lie.dot(kin.screws.unit_twists, kinematics.at_columns(kin, F))


def terms(kin: Kinematics, G: Inertias,  # noqa: N803
          qd: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """``(M, h, C qd, g)`` of eq. (2) at one state or a stack (``qd`` (..., nv) with the kinematics' leading axes): M
    from the body Jacobians, and eq. (27) for three columns, ``h = C qd + g`` (``qdd = 0``), ``C qd`` (gravity off)
    and ``g`` (``qd = 0``)."""
    rates = np.stack([qd, qd, np.zeros_like(qd)])
    weights = np.array([1.0, 0.0, 1.0]).reshape((3,) + (1,) * (np.ndim(qd) - 1))
    tau = generalized_forces(kin, wrenches(kin, G, rates, None, weights))
    return mass_matrix_of(kin, G), tau[0], tau[1], tau[2]


def inverse_dynamics(model: Model, q, qd, qdd, gravity: bool = True) -> np.ndarray:
    """The generalized force ``M qdd + C qd (+ g)`` of eq. (2), from the wrench balance of eq. (27)."""
    q, qd, qdd = joint_vectors(model, q, qd, qdd)
    kin, G = kinematics.forward_kinematics(model, q), Inertias.of(model)
    return generalized_forces(kin, wrenches(kin, G, qd, qdd, float(gravity))) + G.rotors * qdd


def mass_matrix(model: Model, q) -> np.ndarray:
    """``M(q)`` of eq. (2) from the body Jacobians (:func:`mass_matrix_of`)."""
    (q,) = joint_vectors(model, q)
    return mass_matrix_of(kinematics.forward_kinematics(model, q), Inertias.of(model))
