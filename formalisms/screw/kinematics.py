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

Quantities of all bodies are stacked along a body axis, in model order, after any leading axes of ``q``: a stack
of N configurations ``q`` (N, n) gives poses (N, n, 4, 4), twists (N, n, 6), ... (the batched split evaluates all
states in one pass); one configuration gives (n, 4, 4), (n, 6), ... Rates such as ``qd`` broadcast the same way.
"""

from __future__ import annotations

from dataclasses import dataclass
from functools import cached_property

import numpy as np

from cases.model import Model
from formalisms.screw import lie


@dataclass(frozen=True)
class Screws:
    """The configuration-independent screw description of a model.

    home        (n, 4, 4)  ``M_i``, world <- body ``i`` at ``q = 0``
    placements  (n, 4, 4)  ``M_parent(i),i = M_parent^-1 M_i``: the model's ``(rotation, translation)`` of body ``i``
    body_axes   (n, 6)     ``B_i`` in body frame ``i``
    space_axes  (n, 6)     ``S_i = Ad_{M_i} B_i`` in the world frame
    support     (n, n)     ``support[i, j] = 1`` when body ``j`` is ``i`` or an ancestor of ``i`` (joint ``j``
                           moves body ``i``), else 0; row ``i`` masks the columns of body ``i``'s Jacobian
    """

    home: np.ndarray
    placements: np.ndarray
    body_axes: np.ndarray
    space_axes: np.ndarray
    support: np.ndarray


@dataclass(frozen=True)
class Kinematics:
    """The PoE kinematics at a configuration ``q`` (..., n); the leading axes ``...`` are those of ``q``.

    q           (..., n)        the configuration
    poses       (..., n, 4, 4)  ``T_i(q)``, world <- body ``i`` (eq. 20)
    columns     (..., n, 6)     ``S_j(q) = Ad_{P_parent(j)} S_j``: joint ``j``'s screw axis in the world frame at ``q``
    """

    model: Model
    screws: Screws
    q: np.ndarray
    poses: np.ndarray
    columns: np.ndarray

    @cached_property
    def to_body(self) -> np.ndarray:
        """(..., n, 6, 6) ``Ad_{T_i^-1}``: maps a twist from the world frame to body frame ``i``."""
        return lie.Ad(lie.inv(self.poses))

    @cached_property
    def from_parent(self) -> np.ndarray:
        """(..., n, 4, 4) ``T_i,parent(i) = exp(-[B_i] q_i) M_parent(i),i^-1`` (Lynch & Park 8.3.2): the parent's frame
        (the world's for a root) in body ``i``'s. ``Ad`` of it maps a twist from the parent's frame to body ``i``'s, its
        transpose a wrench from body ``i``'s frame to the parent's."""
        return lie.compose(lie.exp6(self.screws.body_axes, -self.q), lie.inv(self.screws.placements))

    @cached_property
    def from_parent_adjoint(self) -> np.ndarray:
        """(..., n, 6, 6) ``Ad_{T_i,parent(i)}`` of :attr:`from_parent`, for the passes over the tree."""
        return lie.Ad(self.from_parent)

    @cached_property
    def body_columns(self) -> np.ndarray:
        """(..., n, n, 6): ``[..., i, j, :]`` is column ``j`` of the body Jacobian ``J_b,i`` (``= Ad_{T_i^-1} J_s,i``),
        joint ``j``'s screw axis in body frame ``i`` where joint ``j`` moves body ``i``, else 0; by the forward
        iteration ``J_b,i = [Ad_{T_i,parent(i)} J_b,parent(i) | B_i]`` (module docstring)."""
        X = np.zeros(self.q.shape[:-1] + (self.model.n, self.model.n, 6))
        for i in self.model.topological_order:
            p = self.model.parent_index[i]
            if p >= 0:
                X[..., i, :, :] = _into_child(self.from_parent_adjoint[..., i, :, :], X[..., p, :, :])
            X[..., i, i, :] = self.screws.body_axes[i]
        return X


def _into_child(Ad: np.ndarray, rows: np.ndarray) -> np.ndarray:  # noqa: N803
    """``Ad_{T_i,parent(i)} V`` for twists ``V`` stored as rows (..., r, 6) of the parent's frame: body ``i``'s view."""
    return rows @ np.swapaxes(Ad, -1, -2)


def screws(model: Model) -> Screws:
    """Home configurations, placements, body and space screw axes, and the support mask of ``model``."""
    n = model.n
    home, placements = np.empty((n, 4, 4)), np.zeros((n, 4, 4))
    body_axes = np.zeros((n, 6))
    support = np.zeros((n, n))
    for i in model.topological_order:
        b, p = model.bodies[i], model.parent_index[i]
        placements[i, :3, :3], placements[i, :3, 3], placements[i, 3, 3] = b.rotation, b.translation, 1.0
        home[i] = placements[i] if p < 0 else home[p] @ placements[i]
        start = 0 if b.joint == "revolute" else 3
        body_axes[i, start:start + 3] = b.axis
        if p >= 0:
            support[i] = support[p]
        support[i, i] = 1.0
    space_axes = (lie.Ad(home) @ body_axes[..., None])[..., 0]
    return Screws(home, placements, body_axes, space_axes, support)


def _body_major(shape: tuple) -> np.ndarray:
    """An empty (..., n, 4, 4) array stored body by body, then entry by entry, the leading (state) axes innermost: one
    body's transforms of a stack of states are then a contiguous block for the loop over the tree."""
    lead = len(shape) - 3
    return np.empty(shape[-3:] + shape[:-3]).transpose(tuple(range(3, lead + 3)) + (0, 1, 2))


def forward_kinematics(model: Model, q: np.ndarray) -> Kinematics:
    """Eq. (20) on the tree: ``T_i(q) = (prod over j in root..i of exp([S_j] q_j)) M_i``, and the Jacobian
    columns ``S_j(q) = Ad_{P_parent(j)} S_j``. ``q`` is a float array (..., n), n = ``model.n``."""
    sc = screws(model)
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


def _joint_rates(kin: Kinematics, rates: np.ndarray) -> np.ndarray:
    """``S_j(q) rate_j`` per joint: (..., n, 6) for rates (..., n) (leading axes broadcast with the kinematics')."""
    return kin.columns * np.asarray(rates, dtype=float)[..., None]


def _over_bodies(x: np.ndarray, mix: np.ndarray) -> np.ndarray:
    """``out_i = sum_j mix[i, j] x_j`` over the body axis -2 of ``x`` (..., n, c): one matrix product, the components
    kept stored part by part (:func:`lie.components`)."""
    d = x.ndim
    return (x.transpose((d - 1,) + tuple(range(d - 1))) @ mix.T).transpose(tuple(range(1, d)) + (0,))


def _accumulate(kin: Kinematics, per_joint: np.ndarray) -> np.ndarray:
    """Sum per-joint terms over each body's supporting joints: ``out_i = sum_{j <= i} per_joint_j`` (body axis -2)."""
    return _over_bodies(per_joint, kin.screws.support)


def space_jacobian(kin: Kinematics, body: int) -> np.ndarray:
    """``J_s,i`` (..., 6, n): column ``j`` is ``S_j(q)`` if joint ``j`` moves body ``i``, else 0 (article 6.2.2)."""
    return np.swapaxes(kin.columns, -1, -2) * kin.screws.support[body]


def body_jacobian(kin: Kinematics, body: int) -> np.ndarray:
    """``J_b,i = Ad_{T_i^-1} J_s,i`` (..., 6, n), in body frame ``i`` (:attr:`Kinematics.body_columns`)."""
    return np.swapaxes(kin.body_columns[..., body, :, :], -1, -2)


def body_twists(kin: Kinematics, qd: np.ndarray) -> np.ndarray:
    """Body twists ``V_b,i = J_b,i qd`` of every body, (..., n, 6) for qd (..., n): ``[V_b] = T^-1 Tdot``, body frame
    ``i`` (``v`` the velocity of the body-frame origin); the twists of :func:`body_motion`, from the Jacobians."""
    return (np.asarray(qd, dtype=float)[..., None, None, :] @ kin.body_columns)[..., 0, :]


def body_motion(kin: Kinematics, qd: np.ndarray, qdd: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray]:
    """Body twists ``V_i`` and accelerations ``Vdot_i`` (..., n, 6) of every body for rates ``qd``, ``qdd`` (..., n;
    None: zero): Lynch & Park's forward iterations (8.3.2), base to tip, in body frames::

        V_i = Ad_{T_i,parent(i)} V_parent + B_i qd_i
        Vdot_i = Ad_{T_i,parent(i)} Vdot_parent + [V_i, B_i qd_i] + B_i qdd_i,   [V_i, B_i qd_i] = -qd_i [B_i, V_i]

    with nothing inboard of a root (gravity is applied as a load, no accelerating base). The twists summed are ``V_i
    = J_b,i qd`` (:func:`body_twists`), so only the accelerations are iterated; ``Vdot_i = J_b,i qdd + Jdot_b,i qd``,
    the time derivative of ``V_i``, and ``Ad_{T_i^-1}`` of the space acceleration.
    """
    qd = np.asarray(qd, dtype=float)
    qdd = np.zeros_like(qd) if qdd is None else np.asarray(qdd, dtype=float)
    axes, Ad = kin.screws.body_axes, kin.from_parent_adjoint
    V = body_twists(kin, qd)
    Vdot = axes * qdd[..., None] - qd[..., None] * lie.bracket(axes, V)          # each body's own terms
    for i in kin.model.topological_order:
        p = kin.model.parent_index[i]
        if p >= 0:
            Vdot[..., i, :] += _into_child(Ad[..., i, :, :], Vdot[..., p, None, :])[..., 0, :]
    return V, Vdot


def twists(kin: Kinematics, qd: np.ndarray) -> np.ndarray:
    """Space twists ``V_s,i = J_s,i qd`` of every body, (..., n, 6) for qd (..., n).

    ``V_s = (w, v)``: ``w`` the angular velocity and ``v`` the velocity of the body-fixed point at the world
    origin, both in the world frame (``[V_s] = Tdot T^-1``).
    """
    return _accumulate(kin, _joint_rates(kin, qd))


def bias_accelerations(kin: Kinematics, qd: np.ndarray) -> np.ndarray:
    """``Jdot_s,i qd = sum_{j <= i} ad_{V_s,parent(j)} S_j(q) qd_j`` (article 6.2.2), (..., n, 6).

    Each column moves with everything inboard of it: ``d/dt S_j(q) = [V_s,parent(j), S_j(q)]``.
    Since ``[S_j, S_j] = 0``, ``V_s,parent(j)`` may be replaced by ``V_s,j``, which is what is used.
    """
    rates = _joint_rates(kin, qd)
    return _accumulate(kin, lie.bracket(_accumulate(kin, rates), rates))


def spatial_accelerations(kin: Kinematics, qd: np.ndarray, qdd: np.ndarray) -> np.ndarray:
    """``Vdot_s,i = J_s,i qdd + Jdot_s,i qd`` (article 6.2.2): the time derivative of the space twists,
    (..., n, 6)."""
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
    """``dp/dq`` (..., 3, n) of the body-fixed point at world position ``p`` (..., 3): column ``j`` is the velocity
    ``v_j + w_j x p`` the space twist ``S_j(q)`` gives the point."""
    S = kin.columns * kin.screws.support[body][:, None]
    return np.swapaxes(S[..., 3:] + lie.cross(S[..., :3], p[..., None, :]), -1, -2)


def point_acceleration(kin: Kinematics, body: int, offset: np.ndarray, qd: np.ndarray, qdd: np.ndarray) -> np.ndarray:
    """Classical acceleration (world frame) of the point ``offset`` fixed in ``body`` (body-frame coordinates),
    from the body's space twist and spatial acceleration (:func:`classical_acceleration`)."""
    return classical_acceleration(twists(kin, qd)[..., body, :], spatial_accelerations(kin, qd, qdd)[..., body, :],
                                  point_position(kin, body, offset))
