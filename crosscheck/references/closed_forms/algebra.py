"""What every closed form needs: its number system (:class:`Arithmetic`: double precision or mpmath) and small linear
algebra typed in here (the 2x2 inverse of article 4.7.2, eigenvalues, condition numbers, the task inertia of eq. 22),
so that no numeric helper of the harness or of a backend is used."""

from __future__ import annotations

from dataclasses import dataclass
from typing import Callable

import mpmath
import numpy as np


EPS = float(np.finfo(float).eps)


@dataclass(frozen=True)
class Arithmetic:
    """What a closed form needs from a number system: ``sin``, ``cos`` and ``array`` (rows to a matrix, a list to a
    vector): double precision (:data:`FLOAT`, numpy arrays) or mpmath (:data:`MPMATH`, mpmath matrices)."""

    sin: Callable
    cos: Callable
    array: Callable


FLOAT = Arithmetic(np.sin, np.cos, lambda rows: np.array(rows, dtype=float))
MPMATH = Arithmetic(mpmath.sin, mpmath.cos, mpmath.matrix)


# ------------------------------------------------------------------------------------- small linear algebra


def inv2(M):
    """The 2x2 inverse of article 4.7.2: M^-1 = (1 / det M) [[M22, -M12], [-M21, M11]], det M = M11 M22 - M12 M21
    (the article writes M12^2: M is symmetric)."""
    det = M[0, 0] * M[1, 1] - M[0, 1] * M[1, 0]
    return np.array([[M[1, 1], -M[0, 1]], [-M[1, 0], M[0, 0]]]) / det


def eigenvalues(A) -> np.ndarray:
    """Ascending eigenvalues of a symmetric matrix: in closed form for 1x1 and 2x2 ``[[a, b], [b, c]]`` (the larger
    ``(a + c) / 2 + hypot((a - c) / 2, b)``, the smaller ``det / larger``, which keeps the smaller one's relative
    accuracy when it is tiny), numpy's ``eigvalsh`` beyond."""
    A = np.atleast_2d(np.asarray(A, dtype=float))
    if A.shape == (1, 1):
        return A[0].copy()
    if A.shape == (2, 2):
        a, b, c = A[0, 0], 0.5 * (A[0, 1] + A[1, 0]), A[1, 1]
        high = 0.5 * (a + c) + np.hypot(0.5 * (a - c), b)
        low = (a * c - b * b) / high if high > 0.0 else 0.5 * (a + c) - np.hypot(0.5 * (a - c), b)
        return np.array([low, high])
    return np.linalg.eigvalsh(A)


def condition(A) -> float:
    """cond(A) of a symmetric positive (semi-)definite A (:func:`eigenvalues`), inf where A is numerically singular:
    its smallest eigenvalue not above ``k eps`` times its largest (an eigensolver's absolute accuracy), or not
    finite."""
    w = eigenvalues(A)
    return float(w[-1] / w[0]) if np.all(np.isfinite(w)) and w[0] > len(w) * EPS * w[-1] else float("inf")


def task_inertia_square(J, M) -> tuple[np.ndarray, float]:
    """Eq. (22) for a square task Jacobian: ``Lambda = (J M^-1 J^T)^-1 = J^-T M J^-1`` and ``cond(J M^-1 J^T) =
    cond(Lambda)``, with J's 2x2 inverse (4.7.2); ``(NaN, inf)`` where J or Lambda is numerically singular."""
    if J[0, 0] * J[1, 1] - J[0, 1] * J[1, 0] == 0.0:
        return np.full((2, 2), np.nan), float("inf")
    Jinv = inv2(J)
    Lambda = Jinv.T @ M @ Jinv
    cond = condition(Lambda)
    return (Lambda if np.isfinite(cond) else np.full((2, 2), np.nan)), cond


def task_inertia(J, Minv) -> tuple[np.ndarray, float]:
    """Eq. (22): ``Lambda = (J M^-1 J^T)^-1`` and ``cond(J M^-1 J^T)`` for a k x n J (1 x 1 and 2 x 2 by hand, 4.7.2;
    numpy's inverse beyond); ``(NaN, inf)`` where ``J M^-1 J^T`` is numerically singular, and always when k > n (more
    task directions than joints)."""
    J = np.atleast_2d(J)
    A = J @ Minv @ J.T
    cond = condition(A) if J.shape[0] <= J.shape[1] else float("inf")
    if not np.isfinite(cond):
        return np.full(A.shape, np.nan), cond
    return (1.0 / A if A.shape == (1, 1) else inv2(A) if A.shape == (2, 2) else np.linalg.inv(A)), cond


def turn(a, v, angle):
    """``v`` turned by ``angle`` about the unit axis ``a`` (Rodrigues): v cos + (a x v) sin + a (a . v)(1 - cos).
    Its derivative in the angle is ``a x turn(a, v, angle)``."""
    a, v = np.asarray(a, dtype=float), np.asarray(v, dtype=float)
    return v * np.cos(angle) + np.cross(a, v) * np.sin(angle) + a * (a @ v) * (1.0 - np.cos(angle))


def hat(a) -> np.ndarray:
    return np.array([[0.0, -a[2], a[1]], [a[2], 0.0, -a[0]], [-a[1], a[0], 0.0]])
