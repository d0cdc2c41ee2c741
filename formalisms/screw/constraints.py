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
* JointCoupling: the constant row ``c``, no bias; the torques ``c_j`` on the joints.

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
``S`` below ``CONSTRAINT_RCOND`` times its largest): minimum-norm multipliers for redundant rows, least-squares
numbers for an inconsistent system. ``M qdd = f + Jc^T lam`` holds because ``Jc^T lam = L A^+ A A^+ r = L A^+ r``.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Callable

import numpy as np
import scipy.linalg

from cases.constraints import JointCoupling, PointOnCircle, PointOnLine, PointsCoincide
from cases.model import Model
from formalisms.interface import redundant_below
from formalisms.screw import kinematics, lie
from formalisms.screw.kinematics import Kinematics


@dataclass(frozen=True)
class ConstraintTerms:
    """The constraint rows at one state: ``phi`` (k,), ``jacobian`` ``Jc`` (k, n), ``bias`` ``Jcdot qd`` (k,),
    ``unit_wrenches`` (k, n, 6): the space wrench ``(moment about the world origin, force)`` a unit multiplier of
    row ``r`` exerts on body ``i``, and ``coupling`` (k,): the rows of joint couplings."""

    phi: np.ndarray
    jacobian: np.ndarray
    bias: np.ndarray
    unit_wrenches: np.ndarray
    coupling: np.ndarray

    def wrenches(self, lam: np.ndarray) -> np.ndarray:
        """The constraint wrench on every body (n, 6), space frame, for the multipliers ``lam``."""
        return np.einsum("r,rib->ib", lam, self.unit_wrenches)

    def coupling_torques(self, lam: np.ndarray) -> np.ndarray:
        """The joint torques (n,) of the couplings' multipliers, ``(coupling rows of Jc)^T lam``: what the
        couplings make each joint carry, like an actuator."""
        return self.jacobian[self.coupling].T @ lam[self.coupling]


@dataclass(frozen=True)
class _Point:
    """A point's body index (None for a fixed world point), world position, ``dp/dq`` (3, n) and ``Jdot qd``."""

    body: int | None
    p: np.ndarray
    J: np.ndarray
    a: np.ndarray


def _point_kinematics(kin: Kinematics, qd: np.ndarray) -> Callable[[str | None, np.ndarray], _Point]:
    """``point(body name, offset)``: a body point's kinematics from the space twists and bias accelerations (module
    docstring); a body of None makes ``offset`` a fixed world point."""
    model = kin.model
    V, A = kinematics.twists(kin, qd), kinematics.bias_accelerations(kin, qd)

    def point(body: str | None, offset: np.ndarray) -> _Point:
        if body is None:
            return _Point(None, offset, np.zeros((3, model.n)), np.zeros(3))
        i = model.body_index(body)
        p = kinematics.point_position(kin, i, offset)
        return _Point(i, p, kinematics.point_jacobian(kin, i, p), kinematics.classical_acceleration(V[i], A[i], p))

    return point


def _force_wrenches(n: int, loads) -> np.ndarray:
    """(rows, n, 6) space wrenches of point forces: ``loads`` holds ``(point, F)`` with ``F`` (3, rows) the world
    force per unit multiplier at the point; a world point takes none."""
    W = np.zeros((next(iter(loads))[1].shape[1], n, 6))
    for x, F in loads:
        if x.body is not None:
            W[:, x.body, :3] += lie.cross(x.p, F.T)
            W[:, x.body, 3:] += F.T
    return W


def _circle(kin: Kinematics, c, point, q, qd):
    x = point(c.body, c.offset)
    d = c.plane @ (x.p - c.center)
    grad = 2.0 * c.plane.T @ d                                # dphi/dp, world
    v = c.plane @ (x.J @ qd)
    return (np.array([d @ d - c.radius**2]), (grad @ x.J)[None, :], np.array([2.0 * v @ v + grad @ x.a]),
            _force_wrenches(kin.model.n, [(x, grad[:, None])]))


def _coincide(kin: Kinematics, c, point, q, qd):
    xa, xb = point(c.body_a, c.offset_a), point(c.body_b, c.offset_b)
    D = c.directions
    return (D @ (xa.p - xb.p), D @ (xa.J - xb.J), D @ (xa.a - xb.a),
            _force_wrenches(kin.model.n, [(xa, D.T), (xb, -D.T)]))


def _line(kin: Kinematics, c, point, q, qd):
    x = point(c.body, c.offset)
    N = c.normals
    return N @ (x.p - c.origin), N @ x.J, N @ x.a, _force_wrenches(kin.model.n, [(x, N.T)])


def _coupling(kin: Kinematics, c, point, q, qd):
    model = kin.model
    row, W = np.zeros(model.n), np.zeros((1, model.n, 6))
    for name, coefficient in zip(c.joints, c.coefficients):
        j = model.body_index(name)
        row[j] += coefficient
        wrench = coefficient * (kin.to_body[j].T @ kin.screws.body_axes[j])   # Ad_{T_j^-1}^T (c_j B_j)
        W[0, j] += wrench
        if model.parent_index[j] >= 0:
            W[0, model.parent_index[j]] -= wrench
    return np.array([row @ q - c.offset]), row[None, :], np.zeros(1), W


#: The rows of each declaration of ``cases.constraints``, by its type.
_DECLARATIONS = {PointOnCircle: _circle, PointsCoincide: _coincide, PointOnLine: _line, JointCoupling: _coupling}


def terms(kin: Kinematics, q: np.ndarray, qd: np.ndarray) -> ConstraintTerms:
    """The rows of every declaration of ``kin.model``, in model order (module docstring)."""
    model: Model = kin.model
    point = _point_kinematics(kin, qd)
    parts = []
    for c in model.constraints:
        if type(c) not in _DECLARATIONS:
            raise TypeError(f"model '{model.name}': the screw backend does not know the constraint declaration "
                            f"{c!r} of type {type(c).__name__}; known: {[t.__name__ for t in _DECLARATIONS]}")
        parts.append(_DECLARATIONS[type(c)](kin, c, point, q, qd))
    phi, Jc, bias, W = (np.concatenate(column) for column in zip(*parts))
    coupling = np.concatenate([np.full(c.size, isinstance(c, JointCoupling)) for c in model.constraints])
    return ConstraintTerms(phi, Jc, bias, W, coupling)


@dataclass(frozen=True)
class Gauss:
    """Gauss's principle on the Cholesky factor of ``M`` (module docstring): ``L`` with ``M = L L^T``, and
    ``A^+`` of ``A = Jc L^-T``."""

    factor: tuple
    L: np.ndarray
    Jc: np.ndarray
    bias: np.ndarray
    A_pinv: np.ndarray

    @classmethod
    def build(cls, model: Model, factor, Jc: np.ndarray, bias: np.ndarray) -> "Gauss":
        """From ``scipy.linalg.cho_factor(M)`` and the constraint rows."""
        c, lower = factor
        L = np.tril(c) if lower else np.triu(c).T
        # row by row: OpenBLAS threads its many-right-hand-side triangular solver, which costs milliseconds on
        # matrices this small when the cores are busy
        A = np.array([scipy.linalg.solve_triangular(L, row, lower=True) for row in Jc])
        U, s, Vt = np.linalg.svd(A, full_matrices=False)
        keep = s**2 > redundant_below(model, s.max(initial=0.0) ** 2)   # s^2: the eigenvalues of S = A A^T
        return cls(factor, L, Jc, bias, (Vt[keep].T / s[keep]) @ U[:, keep].T)

    def _lift(self, y: np.ndarray) -> np.ndarray:
        """``L^-T y``."""
        return scipy.linalg.solve_triangular(self.L, y, lower=True, trans="T")

    def solve(self, f: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """``(qdd, lam)`` of eq. (12, 13) for the generalized force ``f``, by Gauss's principle."""
        a = scipy.linalg.cho_solve(self.factor, f)
        y = self.A_pinv @ (-self.bias - self.Jc @ a)
        return a + self._lift(y), self.A_pinv.T @ y

    def input_map(self, tau: np.ndarray) -> np.ndarray:
        """``B_c tau`` of eq. (17): ``M^-1 tau - L^-T A^+ Jc M^-1 tau``."""
        a = scipy.linalg.cho_solve(self.factor, tau)
        return a - self._lift(self.A_pinv @ (self.Jc @ a))
