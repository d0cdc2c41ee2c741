"""Product-of-exponentials kinematics on the model's tree (article 6.2.2, eq. 20), in screw language.

Frames (``cases.model``): body ``i``'s frame is its joint frame moved by the joint,
``X_i = X_parent * (rotation, translation) * motion(q_i)``, so the joint moves body ``i`` about (revolute) or
along (prismatic) ``axis`` through the body-frame origin. Hence, with ``{s}`` the world (space) frame:

* home configuration ``M_i = T_{s,i}(0) = M_parent (rotation, translation)``;
* body screw axis ``B_i = (axis, 0)`` (revolute) or ``(0, axis)`` (prismatic), in body frame ``i``, and
  ``motion(q_i) = exp([B_i] q_i)``;
* space screw axis ``S_i = Ad_{M_i} B_i``, in the world frame at ``q = 0``.

Eq. (20) on a tree: ``T_i(q) = P_i(q) M_i`` with ``P_i = P_parent(i) exp([S_i] q_i)`` the product of the
exponentials of ``i`` and its ancestors, root first. The space Jacobian of body ``i`` has column
``S_j(q) = Ad_{P_parent(j)} S_j`` for each ``j`` that is ``i`` or an ancestor of ``i``, and zero elsewhere.

A point fixed in body ``i`` at world position ``p`` moves with the body's space twist ``(w, v)``: velocity
``v + w x p`` (so ``dp/dq = [-[p] | I] J_s,i``) and classical acceleration ``vd + wd x p + w x (v + w x p)``.

Body frames (Lynch & Park 8.3.2): body ``i`` sees its parent's frame at ``T_i,parent(i) = exp(-[B_i] q_i)
M_parent(i),i^-1`` (``M_parent(i),i`` the placement ``(rotation, translation)``), and its body Jacobian follows by the
forward iteration ``J_b,i = [Ad_{T_i,parent(i)} J_b,parent(i) | B_i]``. Built from the placements alone, with no world
coordinates, its columns round on the levers between the joints, not on the distances from the world origin.

Joints on a Lie group (article 2.1-2.2, 6.2). A spherical or free joint has no single screw: its configuration is a
group element ``g_i = motion(q_i)`` itself, formed here from the quaternion (and position) block of ``q``
(:func:`lie.quaternion_rotation`): ``g_i = (R(quat), 0)`` in SO(3) (spherical) or ``(R(quat), p)`` in SE(3) (free).
Its velocity block ``v_i`` is the body twist of ``g_i``: ``[g_i^-1 gdot_i] = [E_i v_i]`` with constant body-frame unit
twists ``E_i`` as columns, the three angular ones ``(e_k, 0)`` for a spherical joint, and for a free joint the six in
the order of ``v_i = (R^T pdot, omega)``: ``(0, e_k)`` (linear) then ``(e_k, 0)`` (angular). So every velocity
column ``j`` is a constant unit twist ``E_j`` in the frame of the body that owns it (``E_j = B_i`` for a revolute
or prismatic joint), and:

* eq. (20) keeps its form with ``M_i g_i M_i^-1`` in place of ``exp([S_i] q_i)`` (which is ``M_i exp([B_i] q_i)
  M_i^-1``): ``P_i = P_parent(i) M_i g_i M_i^-1``, ``T_i = P_i M_i``;
* the space Jacobian column of ``j`` (owned by body ``i``) is ``S_j(q) = Ad_{T_i} E_j = Ad_{P_i} Ad_{M_i} E_j``;
* body ``i`` sees its parent at ``T_i,parent(i) = g_i^-1 M_parent(i),i^-1``, the body twists follow ``V_i =
  Ad_{T_i,parent(i)} V_parent + E_i v_i`` and the accelerations ``Vdot_i = Ad_{T_i,parent(i)} Vdot_parent + [V_i, E_i
  v_i] + E_i vdot_i`` (:func:`body_motion`; ``d/dt Ad_{g^-1} X = -[E v, Ad_{g^-1} X]``), exact for a group joint as
  for a screw, since ``E_i`` is constant in body frame ``i``.

Velocities, accelerations and generalized forces have ``nv`` entries (``Model.v_index``), configurations ``nq``
(``Model.q_index``). With revolute and prismatic joints only, column ``j`` is body ``j``'s and every function
below reduces to the screw formulas above, operation for operation.

Quantities of all bodies are stacked along a body axis, in model order, after any leading axes of ``q``: a stack
of N configurations ``q`` (N, nq) gives poses (N, nb, 4, 4), twists (N, nb, 6), ... (``nb`` bodies; the batched
split evaluates all states in one pass); one configuration gives (nb, 4, 4), (nb, 6), ... Rates such as ``qd``
(N, nv) broadcast the same way; per-column quantities (Jacobian columns) have an axis of ``nv``.
"""

from __future__ import annotations

from dataclasses import dataclass
from functools import cached_property

import numpy as np

from cases.model import JOINT_DOF, Model
from formalisms.screw import lie


@dataclass(frozen=True)
class Screws:
    """The configuration-independent screw description of a model.

    home         (nb, 4, 4)  ``M_i``, world <- body ``i`` at ``q = 0`` (identity orientations: the neutral one)
    placements   (nb, 4, 4)  ``M_parent(i),i = M_parent^-1 M_i``: the model's ``(rotation, translation)`` of body ``i``
    body_axes    (nb, 6)     ``B_i`` in body frame ``i`` (zero for a spherical or free joint: no single screw)
    space_axes   (nb, 6)     ``S_i = Ad_{M_i} B_i`` in the world frame (zero likewise)
    support      (nb, nv)    ``support[i, j] = 1`` when velocity column ``j`` belongs to body ``i`` or an ancestor of
                             ``i`` (joint ``j`` moves body ``i``), else 0; row ``i`` masks body ``i``'s Jacobian
    unit_twists  (nv, 6)     ``E_j``: column ``j``'s constant unit twist in its body's frame (module docstring)
    owner        (nv,)       the body whose joint column ``j`` belongs to
    ownership    (nb, nv)    ``ownership[i, j] = 1`` when column ``j`` is body ``i``'s
    group        (ng,)       the bodies on spherical or free joints (``Model.group_joints``)
    simple                   no such body: column ``j`` is body ``j``'s, ``unit_twists`` is ``body_axes``
    """

    home: np.ndarray
    placements: np.ndarray
    body_axes: np.ndarray
    space_axes: np.ndarray
    support: np.ndarray
    unit_twists: np.ndarray
    owner: np.ndarray
    ownership: np.ndarray
    group: tuple[int, ...]
    simple: bool


@dataclass(frozen=True)
class Kinematics:
    """The PoE kinematics at a configuration ``q`` (..., nq); the leading axes ``...`` are those of ``q``.

    q           (..., nq)        the configuration
    poses       (..., nb, 4, 4)  ``T_i(q)``, world <- body ``i`` (eq. 20)
    columns     (..., nv, 6)     ``S_j(q) = Ad_{P_parent(j)} S_j``: joint ``j``'s screw axis in the world frame at ``q``
                                 (a group joint's: ``Ad_{T_i} E_j``, module docstring)
    """

    model: Model
    screws: Screws
    q: np.ndarray
    poses: np.ndarray
    columns: np.ndarray

    @cached_property
    def to_body(self) -> np.ndarray:
        """(..., nb, 6, 6) ``Ad_{T_i^-1}``: maps a twist from the world frame to body frame ``i``."""
        return lie.Ad(lie.inv(self.poses))

    @cached_property
    def from_parent(self) -> np.ndarray:
        """(..., nb, 4, 4) ``T_i,parent(i) = exp(-[B_i] q_i) M_parent(i),i^-1`` (Lynch & Park 8.3.2): the parent's frame
        (the world's for a root) in body ``i``'s. ``Ad`` of it maps a twist from the parent's frame to body ``i``'s, its
        transpose a wrench from body ``i``'s frame to the parent's. A group joint's is ``g_i^-1
        M_parent(i),i^-1``."""
        sc = self.screws
        if sc.simple:
            return lie.compose(lie.exp6(sc.body_axes, -self.q), lie.inv(sc.placements))
        inverse_motions = lie.exp6(sc.body_axes, -joint_coordinates(self.model, self.q))
        inverse_motions[..., list(sc.group), :, :] = lie.inv(group_motions(self.model, self.q))
        return lie.compose(inverse_motions, lie.inv(sc.placements))

    @cached_property
    def from_parent_adjoint(self) -> np.ndarray:
        """(..., nb, 6, 6) ``Ad_{T_i,parent(i)}`` of :attr:`from_parent`, for the passes over the tree."""
        return lie.Ad(self.from_parent)

    @cached_property
    def body_columns(self) -> np.ndarray:
        """(..., nb, nv, 6): ``[..., i, j, :]`` is column ``j`` of the body Jacobian ``J_b,i`` (``= Ad_{T_i^-1}
        J_s,i``), joint ``j``'s screw axis in body frame ``i`` where joint ``j`` moves body ``i``, else 0; by the
        forward iteration ``J_b,i = [Ad_{T_i,parent(i)} J_b,parent(i) | E_i]`` (module docstring; ``E_i = B_i`` for a
        screw joint, the constant unit twists of a group joint)."""
        model, E = self.model, self.screws.unit_twists
        X = np.zeros(self.q.shape[:-1] + (len(model.bodies), model.nv, 6))
        for i in model.topological_order:
            p = model.parent_index[i]
            if p >= 0:
                X[..., i, :, :] = _into_child(self.from_parent_adjoint[..., i, :, :], X[..., p, :, :])
            own = slice(model.v_index[i], model.v_index[i] + JOINT_DOF[model.bodies[i].joint][1])
            X[..., i, own, :] = E[own]
        return X


def _into_child(Ad: np.ndarray, rows: np.ndarray) -> np.ndarray:  # noqa: N803
    """``Ad_{T_i,parent(i)} V`` for twists ``V`` stored as rows (..., r, 6) of the parent's frame: body ``i``'s view."""
    return rows @ np.swapaxes(Ad, -1, -2)


#: The constant body-frame unit twists ``(omega, v)`` of a group joint's velocity block, in the order of the block
#: (``cases.model``): a spherical joint's angular velocity; a free joint's ``(R^T pdot, omega)``, linear first.
GROUP_UNIT_TWISTS = {"spherical": np.hstack([np.eye(3), np.zeros((3, 3))]),
                     "free": np.vstack([np.hstack([np.zeros((3, 3)), np.eye(3)]),
                                        np.hstack([np.eye(3), np.zeros((3, 3))])])}


def screws(model: Model) -> Screws:
    """Home configurations, placements, body and space screw axes, the velocity columns' unit twists and owners, and
    the support mask of ``model``."""
    nb, nv = len(model.bodies), model.nv
    home, placements = np.empty((nb, 4, 4)), np.zeros((nb, 4, 4))
    body_axes = np.zeros((nb, 6))
    support, ownership = np.zeros((nb, nv)), np.zeros((nb, nv))
    unit_twists, owner = np.zeros((nv, 6)), np.zeros(nv, dtype=int)
    for i in model.topological_order:
        b, p = model.bodies[i], model.parent_index[i]
        own = slice(model.v_index[i], model.v_index[i] + JOINT_DOF[b.joint][1])
        placements[i, :3, :3], placements[i, :3, 3], placements[i, 3, 3] = b.rotation, b.translation, 1.0
        home[i] = placements[i] if p < 0 else home[p] @ placements[i]
        if b.joint in GROUP_UNIT_TWISTS:
            unit_twists[own] = GROUP_UNIT_TWISTS[b.joint]
        else:
            start = 0 if b.joint == "revolute" else 3
            body_axes[i, start:start + 3] = b.axis
            unit_twists[own] = body_axes[i]
        owner[own], ownership[i, own] = i, 1.0
        if p >= 0:
            support[i] = support[p]
        support[i, own] = 1.0
    space_axes = (lie.Ad(home) @ body_axes[..., None])[..., 0]
    group = tuple(model.group_joints)
    return Screws(home, placements, body_axes, space_axes, support, unit_twists, owner, ownership, group, not group)


def joint_coordinates(model: Model, q: np.ndarray) -> np.ndarray:
    """(..., nb): the revolute and prismatic joints' coordinates ``q_i`` (the exponents of eq. 20), 0 for a group
    joint, from ``q`` (..., nq)."""
    x = np.asarray(q, dtype=float)[..., list(model.q_index)]
    x[..., list(model.group_joints)] = 0.0
    return x


def group_motions(model: Model, q: np.ndarray) -> np.ndarray:
    """(..., ng, 4, 4): ``g_i = motion(q_i)`` of the group joints (``Model.group_joints``), from ``q`` (..., nq):
    ``(R(quat), 0)`` for a spherical joint, ``(R(quat), p)`` for a free one (``q_i = (p, quat)``), with ``R(quat)``
    the exponential of :func:`lie.quaternion_rotation`."""
    q = np.asarray(q, dtype=float)
    g = np.zeros(q.shape[:-1] + (len(model.group_joints), 4, 4))
    for k, i in enumerate(model.group_joints):
        start, free = model.q_index[i], model.bodies[i].joint == "free"
        quat = q[..., start + 3:start + 7] if free else q[..., start:start + 4]
        g[..., k, :, :] = lie.transform(lie.quaternion_rotation(quat), q[..., start:start + 3] if free else None)
    return g


def _body_major(shape: tuple) -> np.ndarray:
    """An empty (..., nb, 4, 4) array stored body by body, then entry by entry, the leading (state) axes innermost: one
    body's transforms of a stack of states are then a contiguous block for the loop over the tree."""
    lead = len(shape) - 3
    return np.empty(shape[-3:] + shape[:-3]).transpose(tuple(range(3, lead + 3)) + (0, 1, 2))


def forward_kinematics(model: Model, q: np.ndarray) -> Kinematics:
    """Eq. (20) on the tree: ``T_i(q) = (prod over j in root..i of exp([S_j] q_j)) M_i``, and the Jacobian
    columns ``S_j(q) = Ad_{P_parent(j)} S_j``. ``q`` is a float array (..., nq). A group joint's factor is ``M_i g_i
    M_i^-1`` and its columns are ``Ad_{P_i} Ad_{M_i} E_j`` (module docstring)."""
    sc = screws(model)
    if not sc.simple:
        return _group_kinematics(model, sc, np.asarray(q, dtype=float))
    factors = lie.exp6(sc.space_axes, q)                  # exp([S_j] q_j), all joints at once
    products = _body_major(factors.shape)                 # P_i = P_parent(i) exp([S_i] q_i)
    before = _body_major(factors.shape)                   # P_parent(i) (identity at a root)
    for i in model.topological_order:
        p = model.parent_index[i]
        if p < 0:
            before[..., i, :, :], products[..., i, :, :] = np.eye(4), factors[..., i, :, :]
        else:
            before[..., i, :, :] = products[..., p, :, :]
            products[..., i, :, :] = lie.compose(products[..., p, :, :], factors[..., i, :, :])
    return Kinematics(model, sc, q, lie.compose(products, sc.home), lie.adjoint(before, sc.space_axes))


def _group_kinematics(model: Model, sc: Screws, q: np.ndarray) -> Kinematics:
    """:func:`forward_kinematics` of a model with group joints: the same product over the tree, with the factors
    ``M_i g_i M_i^-1`` of the group joints, and every column moved by the product of its own body."""
    factors = lie.exp6(sc.space_axes, joint_coordinates(model, q))
    home = sc.home[list(sc.group)]
    factors[..., list(sc.group), :, :] = lie.compose(home, lie.compose(group_motions(model, q), lie.inv(home)))
    products = _body_major(factors.shape)
    for i in model.topological_order:
        p = model.parent_index[i]
        if p < 0:
            products[..., i, :, :] = factors[..., i, :, :]
        else:
            products[..., i, :, :] = lie.compose(products[..., p, :, :], factors[..., i, :, :])
    space_units = lie.adjoint(sc.home[sc.owner], sc.unit_twists)          # Ad_{M_i} E_j
    return Kinematics(model, sc, q, lie.compose(products, sc.home), lie.adjoint(products[..., sc.owner, :, :],
                                                                                  space_units))


def at_columns(kin: Kinematics, per_body: np.ndarray) -> np.ndarray:
    """Per-body rows (..., nb, c) repeated for each velocity column of the body (..., nv, c) (the same array when
    every column is its own body's)."""
    return per_body if kin.screws.simple else per_body[..., kin.screws.owner, :]


def _to_bodies(kin: Kinematics, per_column: np.ndarray) -> np.ndarray:
    """Per-column rows (..., nv, c) summed over each body's own columns (..., nb, c) (the same array when every
    column is its own body's)."""
    return per_column if kin.screws.simple else _over_bodies(kin, per_column, kin.screws.ownership)


def joint_twists(kin: Kinematics, rates: np.ndarray) -> np.ndarray:
    """``E_i v_i`` (..., nb, 6): each joint's own twist (body frame) for rates (..., nv)."""
    return _to_bodies(kin, kin.screws.unit_twists * np.asarray(rates, dtype=float)[..., None])


def _joint_rates(kin: Kinematics, rates: np.ndarray) -> np.ndarray:
    """``S_j(q) rate_j`` per column: (..., nv, 6) for rates (..., nv) (leading axes broadcast with the
    kinematics')."""
    return kin.columns * np.asarray(rates, dtype=float)[..., None]


def _over_bodies(kin: Kinematics, x: np.ndarray, mix: np.ndarray) -> np.ndarray:
    """``out_i = sum_j mix[i, j] x_j`` over the axis -2 of ``x`` (..., nv, c): one matrix product, the components
    kept stored part by part (:func:`lie.components`). The kinematics' leading axes (one per state) go outermost and
    each state keeps a single state's order (components, any stack of rates before the states, columns), so that a
    state's sums are those of the state alone in a stack of any length (with the states among the rows of the
    product, the last state of a stack rounded differently)."""
    d, lead = x.ndim, kin.q.ndim - 1
    stack = d - 2 - lead
    order = tuple(range(stack, stack + lead)) + (d - 1,) + tuple(range(stack)) + (d - 2,)
    return (x.transpose(order) @ mix.T).transpose(tuple(np.argsort(order)))


def _accumulate(kin: Kinematics, per_joint: np.ndarray) -> np.ndarray:
    """Sum per-column terms over each body's supporting joints: ``out_i = sum_{j <= i} per_joint_j`` (..., nb, c)."""
    return _over_bodies(kin, per_joint, kin.screws.support)


def space_jacobian(kin: Kinematics, body: int) -> np.ndarray:
    """``J_s,i`` (..., 6, nv): column ``j`` is ``S_j(q)`` if joint ``j`` moves body ``i``, else 0 (article 6.2.2)."""
    return np.swapaxes(kin.columns, -1, -2) * kin.screws.support[body]


def body_jacobian(kin: Kinematics, body: int) -> np.ndarray:
    """``J_b,i = Ad_{T_i^-1} J_s,i`` (..., 6, nv), in body frame ``i`` (:attr:`Kinematics.body_columns`)."""
    return np.swapaxes(kin.body_columns[..., body, :, :], -1, -2)


def body_twists(kin: Kinematics, qd: np.ndarray) -> np.ndarray:
    """Body twists ``V_b,i = J_b,i qd`` of every body, (..., nb, 6) for qd (..., nv): ``[V_b] = T^-1 Tdot``, body frame
    ``i`` (``v`` the velocity of the body-frame origin); the twists of :func:`body_motion`, from the Jacobians."""
    return (np.asarray(qd, dtype=float)[..., None, None, :] @ kin.body_columns)[..., 0, :]


def body_motion(kin: Kinematics, qd: np.ndarray, qdd: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray]:
    """Body twists ``V_i`` and accelerations ``Vdot_i`` (..., nb, 6) of every body for rates ``qd``, ``qdd`` (...,
    nv; None: zero): Lynch & Park's forward iterations (8.3.2), base to tip, in body frames::

        V_i = Ad_{T_i,parent(i)} V_parent + B_i qd_i
        Vdot_i = Ad_{T_i,parent(i)} Vdot_parent + [V_i, B_i qd_i] + B_i qdd_i,   [V_i, B_i qd_i] = -qd_i [B_i, V_i]

    with nothing inboard of a root (gravity is applied as a load, no accelerating base); a group joint's own terms are
    ``sum_j (E_j vdot_j - v_j [E_j, V_i])`` over its columns (module docstring). The twists summed are ``V_i = J_b,i
    qd`` (:func:`body_twists`), so only the accelerations are iterated; ``Vdot_i = J_b,i qdd + Jdot_b,i qd``, the time
    derivative of ``V_i``, and ``Ad_{T_i^-1}`` of the space acceleration.
    """
    qd = np.asarray(qd, dtype=float)
    qdd = np.zeros_like(qd) if qdd is None else np.asarray(qdd, dtype=float)
    axes, Ad = kin.screws.unit_twists, kin.from_parent_adjoint
    V = body_twists(kin, qd)
    Vdot = _to_bodies(kin, axes * qdd[..., None] - qd[..., None] * lie.bracket(axes, at_columns(kin, V)))
    for i in kin.model.topological_order:
        p = kin.model.parent_index[i]
        if p >= 0:
            Vdot[..., i, :] += _into_child(Ad[..., i, :, :], Vdot[..., p, None, :])[..., 0, :]
    return V, Vdot


def twists(kin: Kinematics, qd: np.ndarray) -> np.ndarray:
    """Space twists ``V_s,i = J_s,i qd`` of every body, (..., nb, 6) for qd (..., nv).

    ``V_s = (w, v)``: ``w`` the angular velocity and ``v`` the velocity of the body-fixed point at the world
    origin, both in the world frame (``[V_s] = Tdot T^-1``).
    """
    return _accumulate(kin, _joint_rates(kin, qd))


def bias_accelerations(kin: Kinematics, qd: np.ndarray) -> np.ndarray:
    """``Jdot_s,i qd = sum_{j <= i} ad_{V_s,parent(j)} S_j(q) qd_j`` (article 6.2.2), (..., nb, 6).

    Each column moves with everything inboard of it: ``d/dt S_j(q) = [V_s,parent(j), S_j(q)]``.
    Since ``[S_j, S_j] = 0``, ``V_s,parent(j)`` may be replaced by ``V_s,j``, which is what is used. A group joint's
    column ``Ad_{T_i} E_j`` moves with its own body: ``d/dt Ad_{T_i} E_j = [V_s,i, Ad_{T_i} E_j]`` (``E_j`` constant),
    so there ``V_s,i`` is the exact factor.
    """
    rates = _joint_rates(kin, qd)
    return _accumulate(kin, lie.bracket(at_columns(kin, _accumulate(kin, rates)), rates))


def spatial_accelerations(kin: Kinematics, qd: np.ndarray, qdd: np.ndarray) -> np.ndarray:
    """``Vdot_s,i = J_s,i qdd + Jdot_s,i qd`` (article 6.2.2): the time derivative of the space twists,
    (..., nb, 6)."""
    return _accumulate(kin, _joint_rates(kin, qdd)) + bias_accelerations(kin, qd)


def classical_acceleration(V: np.ndarray, Vdot: np.ndarray, p: np.ndarray) -> np.ndarray:
    """Classical acceleration (the second time derivative of the position, world frame) of the point at world
    position ``p`` moving with a body of space twist ``V = (w, v)`` and spatial acceleration ``Vdot = (wd, vd)``.

    The point's velocity is ``pdot = v + w x p`` (``Tdot = [V] T``); differentiating once more,
    ``pddot = vd + wd x p + w x pdot = ([Vdot] + [V]^2) (p, 1)``: the spatial acceleration alone (``vd + wd x p``)
    misses the ``w x pdot`` term.
    """
    pdot = V[..., 3:] + lie.cross(V[..., :3], p)
    return Vdot[..., 3:] + lie.cross(Vdot[..., :3], p) + lie.cross(V[..., :3], pdot)


def point_position(kin: Kinematics, body: int, offset: np.ndarray) -> np.ndarray:
    """World position ``T_i (offset, 1)`` of the point ``offset`` fixed in ``body`` (body-frame coordinates)."""
    return lie.rotate(kin.poses[..., body, :3, :3], offset) + kin.poses[..., body, :3, 3]


def point_jacobian(kin: Kinematics, body: int, p: np.ndarray) -> np.ndarray:
    """``dp/dq`` (..., 3, nv) of the body-fixed point at world position ``p`` (..., 3): column ``j`` is the velocity
    ``v_j + w_j x p`` the space twist ``S_j(q)`` gives the point."""
    S = kin.columns * kin.screws.support[body][:, None]
    # each state's columns stored as one state's are (an (nv, 3) block), so that products with J are one state's
    return np.swapaxes(np.ascontiguousarray(S[..., 3:] + lie.cross(S[..., :3], p[..., None, :])), -1, -2)


def point_acceleration(kin: Kinematics, body: int, offset: np.ndarray, qd: np.ndarray, qdd: np.ndarray) -> np.ndarray:
    """Classical acceleration (world frame) of the point ``offset`` fixed in ``body`` (body-frame coordinates),
    from the body's space twist and spatial acceleration (:func:`classical_acceleration`)."""
    return classical_acceleration(twists(kin, qd)[..., body, :], spatial_accelerations(kin, qd, qdd)[..., body, :],
                                  point_position(kin, body, offset))
