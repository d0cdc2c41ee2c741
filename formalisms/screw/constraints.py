"""Constraints in screw language (article 5; 7.2: they appear as constraint wrenches): ``phi``, ``Jc`` and
``Jcdot qd`` of the declarations (``cases.constraints``) from the product-of-exponentials kinematics, the wrench a
multiplier exerts on each body, and the constrained forward dynamics by Gauss's principle (Udwadia–Kalaba).

Point kinematics. A point at world position ``p`` fixed in body ``i`` moves with the body's space twist
``V = (w, v) = J_s,i qd``: ``pdot = v + w x p``, so ``dp/dq = [-[p] | I] J_s,i`` (:func:`kinematics.point_jacobian`),
and its classical acceleration at ``qdd = 0`` is ``Jdot_p qd = vd + wd x p + w x pdot`` with
``(wd, vd) = Jdot_s,i qd`` the bias acceleration (:func:`kinematics.classical_acceleration`).

The rows, for the functions of ``cases.constraints`` (``J``, ``a``: a point's Jacobian and bias acceleration),
and the force a unit multiplier applies:

* PointOnCircle: ``Jc = 2 (P d)^T P J`` with ``d = p - c``, ``Jcdot qd = 2 |P pdot|^2 + 2 (P d)^T P a``; the
  force ``2 P^T P d`` at ``p``;
* PointsCoincide: ``Jc = D (J_a - J_b)``, ``Jcdot qd = D (a_a - a_b)``; ``D^T`` at ``p_a`` on body a and ``-D^T``
  at ``p_b`` on body b (none on the world);
* PointOnLine: ``Jc = N J``, ``Jcdot qd = N a``; ``N^T`` at ``p``;
* JointCoupling: the constant row ``c`` (``phi = sum_j c_j q_j - offset``; the couplings join revolute and prismatic
  joints only, so ``q_j`` is at ``Model.q_index[j]`` and its row entry at ``Model.v_index[j]``), no bias; the torques
  ``c_j`` on the joints.

Constraint wrenches. A force ``f`` at the world point ``p`` is the space wrench ``(p x f, f)`` (moment about the
world origin). A coupling's torque ``tau = c_j lam`` on joint ``j`` is the wrench ``tau B_j`` (the body screw axis
read as ``(moment, force)`` about body ``j``'s origin in its frame: a couple about a revolute axis, a force along
a prismatic one) on body ``j`` and its opposite on the parent (none on the world), mapped to the world frame by
``Ad_{T_j^-1}^T``. Either way ``sum_i J_s,i^T W_i = Jc^T lam``: the wrenches are the generalized constraint force
body by body. A change of world frame ``g`` maps them by ``Ad_g^-T``.

Gauss's principle. The constrained acceleration is the admissible one closest to the free acceleration
``a = M^-1 f`` in the metric of ``M``: minimize ``(qdd - a)^T M (qdd - a)`` subject to ``Jc qdd = -Jcdot qd``
(eq. 13). With ``M = L L^T`` and ``A = Jc L^-T`` the minimizer is (Udwadia–Kalaba)

    qdd = a + L^-T A^+ (-Jcdot qd - Jc a),      lam = (A^+)^T A^+ (-Jcdot qd - Jc a) = (A A^T)^+ (...)

with ``A^+`` from the singular value decomposition of ``A``, the singular values below
``sqrt(CONSTRAINT_RCOND)`` times the largest dropped (``A A^T = Jc M^-1 Jc^T``, so this drops the eigenvalues of
``S`` below ``CONSTRAINT_RCOND`` times its largest, and those below the degenerate floor of
:mod:`~formalisms.screw.conditioning`: rows that vanish here): minimum-norm multipliers for redundant rows,
least-squares numbers for an inconsistent system. ``M qdd = f + Jc^T lam`` holds because ``Jc^T lam = L A^+ A A^+ r =
L A^+ r``.

The rows and the solve take a stack of states (leading axes, as :mod:`~formalisms.screw.kinematics`): the batched
split evaluates N states in one pass; the split is the stack of one.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from functools import cached_property
from typing import Callable

import numpy as np

from cases.constraints import (JointCoupling, KnifeEdge, PointOnCircle, PointOnLine, PointsCoincide, PointVelocity,
                               RollingContact)
from cases.model import Model
from formalisms.interface import CONSTRAINT_RCOND
from formalisms.screw import kinematics, lie
from formalisms.screw.conditioning import degenerate_floor
from formalisms.screw.kinematics import Kinematics
from formalisms.screw.linalg import Cholesky


@dataclass(frozen=True)
class ConstraintTerms:
    """The constraint rows at a state (leading axes ``...`` those of the state): ``phi`` (..., k), ``jacobian``
    ``Jc`` (..., k, n), ``bias`` ``Jcdot qd`` (..., k), and ``coupling`` (k,): the rows of joint couplings. At one
    state also ``unit_wrenches`` (k, n, 6): the space wrench ``(moment about the world origin, force)`` a unit
    multiplier of row ``r`` exerts on body ``i`` (k, nb, 6)."""

    phi: np.ndarray
    jacobian: np.ndarray
    bias: np.ndarray
    coupling: np.ndarray
    loads: tuple[Callable[[], np.ndarray], ...] = field(repr=False)

    @cached_property
    def unit_wrenches(self) -> np.ndarray:
        """(k, nb, 6), one state: the declarations' unit wrenches, in row order."""
        return np.concatenate([load() for load in self.loads])

    def wrenches(self, lam: np.ndarray) -> np.ndarray:
        """The constraint wrench on every body (nb, 6), space frame, for the multipliers ``lam`` (one state)."""
        return np.einsum("r,rib->ib", lam, self.unit_wrenches)

    def coupling_torques(self, lam: np.ndarray) -> np.ndarray:
        """The joint torques (nv,) of the couplings' multipliers, ``(coupling rows of Jc)^T lam``: what the
        couplings make each joint carry, like an actuator (one state)."""
        return self.jacobian[self.coupling].T @ lam[self.coupling]


@dataclass(frozen=True)
class _Point:
    """A point's body index (None for a fixed world point), world position (..., 3), ``dp/dq`` (..., 3, n) and
    ``Jdot qd`` (..., 3)."""

    body: int | None
    p: np.ndarray
    J: np.ndarray
    a: np.ndarray


def _point_kinematics(kin: Kinematics, qd: np.ndarray) -> Callable[[str | None, np.ndarray], _Point]:
    """``point(body name, offset)``: a body point's kinematics from the space twists and bias accelerations (module
    docstring); a body of None makes ``offset`` a fixed world point."""
    model = kin.model
    V, A = kinematics.twists(kin, qd), kinematics.bias_accelerations(kin, qd)
    batch = V.shape[:-2]

    def point(body: str | None, offset: np.ndarray) -> _Point:
        if body is None:
            return _Point(None, np.broadcast_to(offset, batch + (3,)), np.zeros(batch + (3, model.n)),
                          np.zeros(batch + (3,)))
        i = model.body_index(body)
        p = kinematics.point_position(kin, i, offset)
        return _Point(i, p, kinematics.point_jacobian(kin, i, p),
                      kinematics.classical_acceleration(V[..., i, :], A[..., i, :], p))

    return point


def _force_wrenches(n: int, loads) -> Callable[[], np.ndarray]:
    """The (rows, n, 6) space wrenches of point forces at one state, when called: ``loads`` holds ``(point, F)``
    with ``F`` (3, rows) the world force per unit multiplier at the point; a world point takes none."""
    def build() -> np.ndarray:
        W = np.zeros((next(iter(loads))[1].shape[1], n, 6))
        for x, F in loads:
            if x.body is not None:
                W[:, x.body, :3] += lie.cross(x.p, F.T)
                W[:, x.body, 3:] += F.T
        return W
    return build


def _rows_of(D: np.ndarray, J: np.ndarray) -> np.ndarray:  # noqa: N803
    """``D J``: constant row directions (r, 3) times point Jacobians (..., 3, n)."""
    return np.einsum("ra,...an->...rn", D, J)


def _circle(kin: Kinematics, c, point, q, qd):
    x = point(c.body, c.offset)
    d = (x.p - c.center) @ c.plane.T
    grad = 2.0 * d @ c.plane                                  # dphi/dp, world
    v = np.einsum("...an,...n->...a", x.J, qd) @ c.plane.T
    return (np.sum(d * d, axis=-1, keepdims=True) - c.radius**2, np.einsum("...a,...an->...n", grad, x.J)[..., None, :],
            2.0 * np.sum(v * v, axis=-1, keepdims=True) + np.sum(grad * x.a, axis=-1, keepdims=True),
            _force_wrenches(len(kin.model.bodies), [(x, grad[:, None])]))


def _coincide(kin: Kinematics, c, point, q, qd):
    xa, xb = point(c.body_a, c.offset_a), point(c.body_b, c.offset_b)
    D = c.directions
    return ((xa.p - xb.p) @ D.T, _rows_of(D, xa.J - xb.J), (xa.a - xb.a) @ D.T,
            _force_wrenches(len(kin.model.bodies), [(xa, D.T), (xb, -D.T)]))


def _line(kin: Kinematics, c, point, q, qd):
    x = point(c.body, c.offset)
    N = c.normals
    return (x.p - c.origin) @ N.T, _rows_of(N, x.J), x.a @ N.T, _force_wrenches(len(kin.model.bodies), [(x, N.T)])


def _coupling(kin: Kinematics, c, point, q, qd):
    model = kin.model
    row, coordinates = np.zeros(model.nv), np.zeros(model.nq)   # the same vector without group joints
    for name, coefficient in zip(c.joints, c.coefficients):
        j = model.body_index(name)
        row[model.v_index[j]] += coefficient
        coordinates[model.q_index[j]] += coefficient

    def build() -> np.ndarray:
        W = np.zeros((1, len(model.bodies), 6))
        for name, coefficient in zip(c.joints, c.coefficients):
            j = model.body_index(name)
            wrench = coefficient * (kin.to_body[j].T @ kin.screws.body_axes[j])   # Ad_{T_j^-1}^T (c_j B_j)
            W[0, j] += wrench
            if model.parent_index[j] >= 0:
                W[0, model.parent_index[j]] -= wrench
        return W

    batch = q.shape[:-1]
    return ((q @ coordinates - c.offset)[..., None], np.broadcast_to(row, batch + (1, model.n)), np.zeros(batch + (1,)),
            build)


# Pfaffian rows (``A(q) qd = 0``, reported phi = 0). A body-fixed point at world position ``p`` has ``dp/dq`` from
# :func:`kinematics.point_jacobian` and classical bias acceleration ``vd + wd x p + w x pdot`` from the body's space
# twist ``V = (w, v)`` and bias acceleration; a world direction fixed in the body, ``e = R d``, has ``edot = w x e``.

def _pfaffian_point(kin: Kinematics, qd: np.ndarray, body: str, p: np.ndarray) -> tuple:
    """``(J, a, w)``: the Jacobian (..., 3, n) and classical bias acceleration (..., 3) of the material point of
    ``body`` at world position ``p`` (..., 3), and the body's angular velocity ``w`` (..., 3)."""
    i = kin.model.body_index(body)
    V, A = kinematics.twists(kin, qd)[..., i, :], kinematics.bias_accelerations(kin, qd)[..., i, :]
    return kinematics.point_jacobian(kin, i, p), kinematics.classical_acceleration(V, A, p), V[..., :3]


def _zero_phi(batch: tuple, rows: int) -> np.ndarray:
    """The reported ``phi`` of Pfaffian rows: 0 (no position-level function)."""
    return np.zeros(batch + (rows,))


def _point_velocity(kin: Kinematics, c, point, q, qd):
    """PointVelocity: ``A = D J``, ``Adot qd = D a``; the force ``D^T`` at the point."""
    x = point(c.body, c.offset)
    D = c.directions
    return (_zero_phi(q.shape[:-1], len(D)), _rows_of(D, x.J), x.a @ D.T,
            _force_wrenches(len(kin.model.bodies), [(x, D.T)]))


def _knife_edge(kin: Kinematics, c, point, q, qd):
    """KnifeEdge: ``e = R d``, ``A = e^T J``, ``Adot qd = (w x e) . pdot + e . a``; the force ``e`` at the point."""
    i = kin.model.body_index(c.body)
    x = point(c.body, c.offset)
    e = lie.rotate(kin.poses[..., i, :3, :3], c.direction)
    _, _, w = _pfaffian_point(kin, qd, c.body, x.p)
    pdot = np.einsum("...an,...n->...a", x.J, qd)
    bias = np.sum(lie.cross(w, e) * pdot + e * x.a, axis=-1, keepdims=True)
    return (_zero_phi(q.shape[:-1], 1), np.einsum("...a,...an->...n", e, x.J)[..., None, :], bias,
            _force_wrenches(len(kin.model.bodies), [(x, e.reshape(3, 1) if e.ndim == 1 else e[..., None])]))


def _rolling(kin: Kinematics, c, point, q, qd):
    """RollingContact: the material point at the contact ``p_c = c - r u`` (``cases.constraints``) as a body-fixed
    point of the space twist, ``A = T dp/dq`` and the body-fixed point's classical acceleration ``a_P``; the contact
    slides over the disk, so ``Adot qd = T (a_P + w x (edot - w x e))`` with ``e = p_c - c = -r u``, ``edot = -r udot``
    (``udot`` from ``adot = w x a``, ``a = R axis``). The force ``T^T`` at the contact. With ``lateral=False`` the one
    row along the rolling direction ``t = (a x n) / |a x n|``: ``A = t^T dp/dq``, ``Adot qd = t . (a_P + w x (edot - w
    x e)) + tdot . pdot`` (t turns with the axle), the force ``t`` at the contact."""
    i = kin.model.body_index(c.body)
    R = kin.poses[..., i, :3, :3]
    center, a = point(c.body, c.center).p, lie.rotate(R, c.axis)
    n = np.cross(c.plane[0], c.plane[1])
    raw = n - np.sum(n * a, axis=-1, keepdims=True) * a
    length = np.linalg.norm(raw, axis=-1, keepdims=True)
    u = raw / length
    e = -c.radius * u
    J, acc, w = _pfaffian_point(kin, qd, c.body, center + e)
    a_dot = lie.cross(w, a)
    raw_dot = -np.sum(n * a_dot, axis=-1, keepdims=True) * a - np.sum(n * a, axis=-1, keepdims=True) * a_dot
    u_dot = (raw_dot - np.sum(u * raw_dot, axis=-1, keepdims=True) * u) / length
    slide = lie.cross(w, -c.radius * u_dot - lie.cross(w, e))
    contact = _Point(i, center + e, J, acc)
    if not c.lateral:
        # the rolling direction t = b / |b|, b = a x n, alone: A = t^T J, Adot qd = t . (a_P + slide) + tdot . pdot
        # with the material point's velocity pdot = J qd and tdot = (bdot - t (t . bdot)) / |b|, bdot = adot x n
        b = lie.cross(a, n)
        size = np.linalg.norm(b, axis=-1, keepdims=True)
        t = b / size
        b_dot = lie.cross(a_dot, n)
        t_dot = (b_dot - np.sum(t * b_dot, axis=-1, keepdims=True) * t) / size
        pdot = np.einsum("...an,...n->...a", J, qd)
        bias = np.sum(t * (acc + slide) + t_dot * pdot, axis=-1, keepdims=True)
        return (_zero_phi(q.shape[:-1], 1), np.einsum("...a,...an->...n", t, J)[..., None, :], bias,
                _force_wrenches(len(kin.model.bodies), [(contact, t.reshape(3, 1) if t.ndim == 1 else t[..., None])]))
    return (_zero_phi(q.shape[:-1], 2), _rows_of(c.plane, J), (acc + slide) @ c.plane.T,
            _force_wrenches(len(kin.model.bodies), [(contact, c.plane.T)]))


#: The rows of each declaration of ``cases.constraints``, by its type.
_DECLARATIONS = {PointOnCircle: _circle, PointsCoincide: _coincide, PointOnLine: _line, JointCoupling: _coupling,
                 PointVelocity: _point_velocity, KnifeEdge: _knife_edge, RollingContact: _rolling}


def terms(kin: Kinematics, q: np.ndarray, qd: np.ndarray) -> ConstraintTerms:
    """The rows of every declaration of ``kin.model``, in model order (module docstring); ``q`` (..., nq), ``qd``
    (..., nv)."""
    model: Model = kin.model
    point = _point_kinematics(kin, qd)
    parts = []
    for c in model.constraints:
        if type(c) not in _DECLARATIONS:
            raise TypeError(f"model '{model.name}': the screw backend does not know the constraint declaration "
                            f"{c!r} of type {type(c).__name__}; known: {[t.__name__ for t in _DECLARATIONS]}")
        parts.append(_DECLARATIONS[type(c)](kin, c, point, q, qd))
    phi, bias = (np.concatenate([part[i] for part in parts], axis=-1) for i in (0, 2))
    Jc = np.concatenate([part[1] for part in parts], axis=-2)
    coupling = np.concatenate([np.full(c.size, isinstance(c, JointCoupling)) for c in model.constraints])
    return ConstraintTerms(phi, Jc, bias, coupling, tuple(part[3] for part in parts))


def _column(x: np.ndarray) -> np.ndarray:
    """(N, n) -> (N, n, 1): one vector per state as the right-hand side of its :class:`Cholesky` solve."""
    return x[..., None]


@dataclass(frozen=True)
class Gauss:
    """Gauss's principle (module docstring) for N states: the Cholesky factors of ``M``, the rows ``Jc`` (N, k, n)
    and ``Jcdot qd`` (N, k), ``A = Jc L^-T`` (N, k, n) and its pseudo-inverse ``A^+`` (N, n, k)."""

    factor: Cholesky
    Jc: np.ndarray
    bias: np.ndarray
    A: np.ndarray
    A_pinv: np.ndarray

    @classmethod
    def build(cls, model: Model, factor: Cholesky, Jc: np.ndarray, bias: np.ndarray) -> "Gauss":  # noqa: N803
        """From the factors of ``M`` and the constraint rows. Singular values of ``A`` whose square (an eigenvalue of
        ``S = A A^T``) is at or below ``CONSTRAINT_RCOND s_max^2`` or the degenerate floor (redundant or vanished rows,
        :mod:`~formalisms.screw.conditioning`) are dropped, state by state."""
        A = np.swapaxes(factor.forward(np.swapaxes(Jc, 1, 2)), 1, 2)                  # (L^-1 Jc^T)^T
        U, s, Vt = np.linalg.svd(A, full_matrices=False)
        keep = s**2 > np.maximum(CONSTRAINT_RCOND * s[:, :1] ** 2, degenerate_floor(model))
        inverse = np.divide(1.0, s, out=np.zeros_like(s), where=keep)
        return cls(factor, Jc, bias, A, np.einsum("Nrn,Nr,Nkr->Nnk", Vt, inverse, U))

    def _lift(self, y: np.ndarray) -> np.ndarray:
        """``L^-T y`` (N, n)."""
        return self.factor.backward(_column(y))[..., 0]

    def solve(self, f: np.ndarray, bias: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray]:
        """``(qdd, lam)`` (N, n), (N, k) of eq. (12, 13) for the generalized forces ``f`` (N, n), by Gauss's
        principle, with the rows' ``Jcdot qd`` or the given ``bias`` (N, k) (0 for the zero-velocity counterfactual)."""
        a = self.factor.solve(_column(f))[..., 0]
        bias = self.bias if bias is None else bias
        y = np.einsum("Nnk,Nk->Nn", self.A_pinv, -bias - np.einsum("Nkn,Nn->Nk", self.Jc, a))
        return a + self._lift(y), np.einsum("Nnk,Nn->Nk", self.A_pinv, y)

    def input_map(self, tau: np.ndarray) -> np.ndarray:
        """``B_c tau`` (N, n) of eq. (17): ``M^-1 tau - L^-T A^+ Jc M^-1 tau``."""
        a = self.factor.solve(_column(tau))[..., 0]
        return a - self._lift(np.einsum("Nnk,Nk->Nn", self.A_pinv, np.einsum("Nkn,Nn->Nk", self.Jc, a)))
