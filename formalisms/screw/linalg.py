"""The solves of the forward dynamics for a stack of states: Cholesky factors ``M = L L^T`` of N small mass matrices
and the triangular solves with them, vectorized over the stack.

The loops run over rows and columns with the state axis innermost (arrays (n, n, N), (n, r, N)), so each step is
a few numpy operations on N numbers; LAPACK called matrix by matrix (``np.linalg.cholesky`` on a stack) costs more
in calls than in arithmetic at n ~ 10. The arithmetic is the textbook one (Golub & Van Loan alg. 4.2.1; forward
and back substitution).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np


@dataclass(frozen=True)
class Cholesky:
    """``L`` (n, n, N): the lower Cholesky factors of N matrices, the state axis last; ``positive`` (N,): False where a
    matrix is not (numerically) positive definite (its factor then holds NaN)."""

    L: np.ndarray
    positive: np.ndarray

    @classmethod
    def of(cls, M: np.ndarray) -> "Cholesky":  # noqa: N803
        """The factors of the symmetric matrices ``M`` (N, n, n) (the lower triangle is read)."""
        A = np.moveaxis(np.asarray(M, dtype=float), 0, -1)
        n, N = A.shape[0], A.shape[-1]
        L, positive = np.zeros(A.shape), np.ones(N, dtype=bool)
        for j in range(n):
            d = A[j, j] - np.sum(L[j, :j] ** 2, axis=0)
            positive &= d > 0.0
            L[j, j] = np.sqrt(np.where(d > 0.0, d, np.nan))
            L[j + 1:, j] = (A[j + 1:, j] - np.sum(L[j + 1:, :j] * L[j, :j], axis=1)) / L[j, j]
        return cls(L, positive)

    def forward(self, b: np.ndarray) -> np.ndarray:
        """``L^-1 b`` for right-hand sides ``b`` (n, r, N), by forward substitution."""
        L, y = self.L, np.empty(np.shape(b))
        for i in range(len(L)):
            y[i] = (b[i] - np.sum(L[i, :i, None] * y[:i], axis=0)) / L[i, i]
        return y

    def backward(self, y: np.ndarray) -> np.ndarray:
        """``L^-T y`` for right-hand sides ``y`` (n, r, N), by back substitution."""
        L, x = self.L, np.empty(np.shape(y))
        for i in reversed(range(len(L))):
            x[i] = (y[i] - np.sum(L[i + 1:, i, None] * x[i + 1:], axis=0)) / L[i, i]
        return x

    def solve(self, b: np.ndarray) -> np.ndarray:
        """``M^-1 b`` for right-hand sides ``b`` (n, r, N)."""
        return self.backward(self.forward(b))
