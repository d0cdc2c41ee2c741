"""The 50-digit reference's algebra in mpmath: 3-vectors and 3x3 matrices as lists, and the linear algebra of its
solves (a Cholesky factorization, its solves, the range-space pseudo-solver for redundant constraint rows) with the
rank decided as the backends decide it."""

from __future__ import annotations

import functools
from typing import Callable

import mpmath
import numpy as np
from mpmath import mpf

from cases.model import Model
from crosscheck.guards.conditioning import redundant_below


ZERO3 = (mpf(0), mpf(0), mpf(0))


# ----------------------------------------------------------------------------------------------- 3-vector algebra


def add3(a, b):
    return (a[0] + b[0], a[1] + b[1], a[2] + b[2])


def sub3(a, b):
    return (a[0] - b[0], a[1] - b[1], a[2] - b[2])


def scale3(s, a):
    return (s * a[0], s * a[1], s * a[2])


def dot3(a, b):
    return mpmath.fdot(a, b)


def cross3(a, b):
    return (a[1] * b[2] - a[2] * b[1], a[2] * b[0] - a[0] * b[2], a[0] * b[1] - a[1] * b[0])


def matvec3(A, x):
    return tuple(dot3(row, x) for row in A)


def matmul3(A, B):
    cols = tuple(zip(*B))
    return tuple(tuple(dot3(row, col) for col in cols) for row in A)


def transpose3(A):
    return tuple(zip(*A))


# ----------------------------------------------------------------------------------------------- linear algebra


def cholesky(model: Model, M, q) -> list:
    L = _cholesky_factor(M)
    if L is None:
        raise ValueError(f"model '{model.name}': the mass matrix is not positive definite at q = {list(q)} "
                         "(multiprecision Cholesky failed)")
    return L


def _cholesky_factor(M) -> list | None:
    """The lower Cholesky factor of the symmetric matrix M (lists of mpf), None when M is not positive definite."""
    n = len(M)
    L = [[mpf(0)] * n for _ in range(n)]
    for j in range(n):
        d = M[j][j] - mpmath.fdot(L[j][:j], L[j][:j])
        if d <= 0:
            return None
        L[j][j] = mpmath.sqrt(d)
        for i in range(j + 1, n):
            L[i][j] = (M[i][j] - mpmath.fdot(L[i][:j], L[j][:j])) / L[j][j]
    return L


def cho_solve(L, b) -> list:
    n = len(L)
    y = [mpf(0)] * n
    for i in range(n):
        y[i] = (b[i] - mpmath.fdot(L[i][:i], y[:i])) / L[i][i]
    x = [mpf(0)] * n
    for i in reversed(range(n)):
        x[i] = (y[i] - mpmath.fdot([L[k][i] for k in range(i + 1, n)], x[i + 1:])) / L[i][i]
    return x


def matvec_n(A, x) -> list:
    return [mpmath.fdot(row, x) for row in A]


#: A float eigenvalue of S this much (times the largest) above the redundancy floor is above it in exact arithmetic
#: too: rounding S to floats moves its eigenvalues by at most ``k eps max|S_ij|``, below 1e-14 of the largest.
_CLEAR_OF_FLOOR = 1e-12


def _pseudo_solver(model: Model, S) -> Callable[[list], list]:
    """``r -> S^+ r`` for the symmetric k x k S (lists of mpf), eigenvalues at or below ``redundant_below`` dropped
    (the backends' rank rule). When every eigenvalue of S rounded to floats is clear of the floor
    (:data:`_CLEAR_OF_FLOOR`), none is dropped in exact arithmetic either and ``S^+ = S^-1`` by Cholesky; otherwise
    the multiprecision eigendecomposition decides, eigenvalue by eigenvalue (many times the cost)."""
    k = len(S)
    w = np.linalg.eigvalsh(np.array([[float(x) for x in row] for row in S]))
    if np.all(np.isfinite(w)) and w[0] - redundant_below(model, w[-1]) > _CLEAR_OF_FLOOR * abs(w[-1]):
        L = _cholesky_factor(S)
        if L is not None:
            return functools.partial(cho_solve, L)
    w, U = mpmath.eigsy(mpmath.matrix(S))
    floor = redundant_below(model, float(max(w[i] for i in range(k))))
    kept = [i for i in range(k) if w[i] > floor]
    pinv = [[sum((U[r, i] * U[c, i] / w[i] for i in kept), mpf(0)) for c in range(k)] for r in range(k)]
    return functools.partial(matvec_n, pinv)


class RangeSpace:
    """``X = M^-1 Jc^T`` and ``r -> S^+ r`` (S = Jc X, eigenvalues at or below ``redundant_below`` dropped)."""

    def __init__(self, model: Model, L, Jc, bias):
        self.L, self.Jc, self.bias = L, Jc, bias
        cols = [cho_solve(L, row) for row in Jc]                  # columns of X
        self.X = [list(r) for r in zip(*cols)]
        k = len(Jc)
        S = [[mpf(0)] * k for _ in range(k)]
        for r in range(k):
            for s in range(r, k):
                S[r][s] = S[s][r] = mpmath.fdot(Jc[r], cols[s])
        self.S_solve = _pseudo_solver(model, S)

    def solve(self, f) -> tuple[list, list]:
        """``(qdd, lam)`` of eq. (12, 13) for the generalized force ``f``."""
        a = cho_solve(self.L, f)
        r = [-b - jc for b, jc in zip(self.bias, matvec_n(self.Jc, a))]
        lam = self.S_solve(r)
        return [x + y for x, y in zip(a, matvec_n(self.X, lam))], lam

    def input_map(self, tau) -> list:
        """``B_c tau`` of eq. (17): ``M^-1 tau - X S^+ Jc M^-1 tau``."""
        a = cho_solve(self.L, tau)
        corr = matvec_n(self.X, self.S_solve(matvec_n(self.Jc, a)))
        return [x - y for x, y in zip(a, corr)]
