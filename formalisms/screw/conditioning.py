"""The screw backend's own conditioning and scales (docs/design.md, "Independence is the product"): every number it
reports about its solves comes from its own ``M``, ``C qd``, ``g``, ``Jc``, ``Jcdot qd`` and task Jacobian, by its own
algorithms: the eigendecomposition of ``M`` (``scipy.linalg.eigh``), of ``S = A A^T`` with Gauss's ``A = Jc L^-T``
(:mod:`~formalisms.screw.constraints`), and the singular values of ``J L^-T`` for the task-space inertia.

The definitions are the harness's (every backend reports the same quantities, each computed its own way):

* ``accel_scale = ||M^-1|| H`` with ``H = |C qd|_1 + |g|_1 + |B u|_1 + ||M|| |qd|^2 + |gravity|_1 sqrt(m_total ||M||)``:
  the generalized forces summed in ``B u - C qd - g``, with configuration-robust sizes of the velocity products and
  of gravity (a mass times a lever arm), since the computed ``C qd`` and ``g`` can cancel while their terms do not;
* a row of ``J M^-1 J^T`` (``J`` = ``Jc`` or a task Jacobian) below the degenerate floor ``(DEGENERATE_ROW L)^2 /
  inertia_scale`` (L the model's length scale) is a row that vanishes here, not a direction;
* an eigenvalue of ``S = Jc M^-1 Jc^T`` at or below ``max(CONSTRAINT_RCOND w_max, floor)`` is a redundant direction
  (article 5.6): ``cond S = max(w_max, floor) / w_min`` (inf when ``w_min <= 0``), ``cond_kept`` the same over the
  directions kept, ``lam_scale = (|Jcdot qd|_1 + ||Jc|| accel_scale) / w_kept,min`` the size of the multipliers the
  summed terms could produce, ``force_scale = ||M^-1|| ||Jc|| lam_scale`` the accelerations the constraint force
  can produce, and the inconsistency ``max |U_0^T r| / max(|r|, 1e-6 L accel_scale)`` over the right-hand sides ``r =
  -Jcdot qd - Jc M^-1 f`` (``f = B u - h`` and ``-h``), ``U_0`` the redundant eigenvectors: non-zero when ``H_t`` is
  empty (eq. 16);
* ``A = J M^-1 J^T`` of a task point is numerically singular when its smallest eigenvalue is not above ``max(k eps
  w_max, floor)``; then ``Lambda`` (eq. 22) is NaN and its condition inf.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import scipy.linalg

from cases.model import Model
from formalisms.interface import CONSTRAINT_RCOND, DEGENERATE_ROW
from formalisms.screw.linalg import Cholesky


def degenerate_floor(model: Model) -> float:
    """The smallest eigenvalue of ``J M^-1 J^T`` that is a direction and not a vanished row (module docstring)."""
    return (DEGENERATE_ROW * model.length_scale) ** 2 / model.inertia_scale


@dataclass(frozen=True)
class MassConditioning:
    """``cond`` = cond_2(M), ``inverse_norm`` = ``||M^-1||_2`` and ``accel_scale`` (module docstring) at one state."""

    cond: float
    inverse_norm: float
    accel_scale: float


def of_mass(model: Model, M: np.ndarray, c_qd: np.ndarray, g: np.ndarray, tau: np.ndarray,  # noqa: N803
            qd: np.ndarray) -> MassConditioning:
    """cond(M), ``||M^-1||`` and ``accel_scale`` from the eigenvalues of ``M`` (``scipy.linalg.eigh``); 1-norms, so
    tiny vectors do not underflow."""
    w = scipy.linalg.eigh(M, eigvals_only=True)
    m_total = sum(b.mass for b in model.bodies)
    H = (np.abs(c_qd).sum() + np.abs(g).sum() + np.abs(tau).sum() + w[-1] * float(qd @ qd)
         + np.abs(model.gravity).sum() * np.sqrt(m_total * w[-1]))
    return MassConditioning(float(w[-1] / w[0]), float(1.0 / w[0]), float(H / w[0]))


@dataclass(frozen=True)
class ConstraintConditioning:
    """The conditioning of ``S = Jc M^-1 Jc^T`` at one state (module docstring)."""

    cond_S: float
    cond_kept: float
    rank: int
    inconsistency: float
    lam_scale: float
    force_scale: float


def _inconsistency(model: Model, redundant: np.ndarray, factor: Cholesky, Jc: np.ndarray,  # noqa: N803
                   bias: np.ndarray, forces, accel_scale: float) -> float:
    """``max |U_0^T r| / max(|r|, 1e-6 L accel_scale)`` over ``r = -Jcdot qd - Jc M^-1 f`` for the ``forces`` f, ``U_0``
    the ``redundant`` eigenvectors of S (k, r) (module docstring)."""
    worst = 0.0
    for f in forces:
        r = -bias - Jc @ factor.solve(f[None, :, None])[0, :, 0]
        size = max(float(np.linalg.norm(r)), 1e-6 * model.length_scale * accel_scale)
        if size > 0.0:
            worst = max(worst, float(np.linalg.norm(redundant.T @ r)) / size)
    return worst


def of_constraints(model: Model, factor: Cholesky, A: np.ndarray, Jc: np.ndarray, bias: np.ndarray,  # noqa: N803
                   forces, mass: MassConditioning) -> ConstraintConditioning:
    """The conditioning of the constrained problem at one state from Gauss's ``A = Jc L^-T`` (k, n): the eigenvalues
    and eigenvectors of ``S = A A^T`` (``scipy.linalg.eigh``), the rank decision on them, and the inconsistency of the
    right-hand sides ``-Jcdot qd - Jc M^-1 f`` for the ``forces`` f (``B u - h`` and ``-h``) in the redundant
    eigen-directions."""
    w, U = scipy.linalg.eigh(A @ A.T)
    floor = degenerate_floor(model)
    kept = w > max(CONSTRAINT_RCOND * w[-1], floor)
    rank = int(kept.sum())
    w_max = max(float(w[-1]), floor)
    jc_norm = float(np.sqrt(scipy.linalg.eigh(Jc @ Jc.T, eigvals_only=True)[-1]))
    lam_scale = (np.abs(bias).sum() + jc_norm * mass.accel_scale) / float(w[kept][0]) if rank else 0.0
    inconsistency = (_inconsistency(model, U[:, ~kept], factor, Jc, bias, forces, mass.accel_scale)
                     if rank < len(w) else 0.0)
    return ConstraintConditioning(cond_S=w_max / float(w[0]) if w[0] > 0.0 else np.inf,
                                  cond_kept=w_max / float(w[kept][0]) if rank else 1.0, rank=rank,
                                  inconsistency=inconsistency, lam_scale=float(lam_scale),
                                  force_scale=mass.inverse_norm * jc_norm * float(lam_scale))


def task_inertia(model: Model, J: np.ndarray, factor: Cholesky) -> tuple[np.ndarray, float]:  # noqa: N803
    """``(Lambda, cond)``: ``Lambda = (J M^-1 J^T)^-1`` (eq. 22) and ``cond_2(J M^-1 J^T)`` for a task Jacobian ``J``
    (k, n), from the singular value decomposition ``L^-1 J^T = U s V^T``: ``J M^-1 J^T = V s^2 V^T`` (eigenvalues 0
    for ``k > n``), so ``Lambda = V s^-2 V^T``. NaN and inf where ``J M^-1 J^T`` is numerically singular (module
    docstring)."""
    k = len(J)
    _, s, Vt = np.linalg.svd(factor.forward(J.T[None])[0], full_matrices=True)
    w = np.zeros(k)
    w[:len(s)] = s**2                                          # eigenvalues, descending, with the rows of Vt
    floor = max(k * np.finfo(float).eps * w[0], degenerate_floor(model))
    if not (np.all(np.isfinite(w)) and floor < w[-1]):
        return np.full((k, k), np.nan), float("inf")
    Lambda = (Vt.T / w) @ Vt
    return 0.5 * (Lambda + Lambda.T), float(w[0] / w[-1])
