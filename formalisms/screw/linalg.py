"""The solves of the forward dynamics for a stack of states: Cholesky factors ``M = L L^T`` of N small mass matrices
and the triangular solves with them, vectorized over the stack.

The loops run over rows and columns, each step a few numpy operations on the whole stack; LAPACK called matrix by
matrix (``np.linalg.cholesky`` on a stack) costs more in calls than in arithmetic at n ~ 10. The state axis comes first
(arrays (N, n, n), (N, n, r)), so that every state's numbers are summed exactly as a stack of one sums them: a
reduction over a state's own axes sees the same layout whatever N (with the states innermost, a sum of eight or more
terms was pairwise for one state and sequential for a stack). The arithmetic is the textbook one (Golub & Van Loan
alg. 4.2.1; forward and back substitution).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np


@dataclass(frozen=True)
class Cholesky:
    """``L`` (N, n, n): the lower Cholesky factors of N matrices; ``positive`` (N,): False where a matrix is not
    (numerically) positive definite (its factor then holds NaN)."""

    L: np.ndarray
    positive: np.ndarray

    @classmethod
    def of(cls, M: np.ndarray) -> "Cholesky":  # noqa: N803
        """The factors of the symmetric matrices ``M`` (N, n, n) (the lower triangle is read)."""
        A = np.asarray(M, dtype=float)
        n, N = A.shape[-1], A.shape[0]
        L, positive = np.zeros(A.shape), np.ones(N, dtype=bool)
        for j in range(n):
            d = A[:, j, j] - np.sum(L[:, j, :j] ** 2, axis=-1)
            positive &= d > 0.0
            L[:, j, j] = np.sqrt(np.where(d > 0.0, d, np.nan))
            column = A[:, j + 1:, j] - np.sum(L[:, j + 1:, :j] * L[:, j, None, :j], axis=-1)
            L[:, j + 1:, j] = column / L[:, j, j, None]
        return cls(L, positive)

    def state(self, i: int) -> "Cholesky":
        """The factor of state ``i`` alone (a stack of one)."""
        return Cholesky(self.L[i:i + 1], self.positive[i:i + 1])

    def forward(self, b: np.ndarray) -> np.ndarray:
        """``L^-1 b`` for right-hand sides ``b`` (N, n, r), by forward substitution."""
        L, y = self.L, np.empty(np.shape(b))
        for i in range(L.shape[-1]):
            y[:, i] = (b[:, i] - np.sum(L[:, i, :i, None] * y[:, :i], axis=1)) / L[:, i, i, None]
        return y

    def backward(self, y: np.ndarray) -> np.ndarray:
        """``L^-T y`` for right-hand sides ``y`` (N, n, r), by back substitution."""
        L, x = self.L, np.empty(np.shape(y))
        for i in reversed(range(L.shape[-1])):
            x[:, i] = (y[:, i] - np.sum(L[:, i + 1:, i, None] * x[:, i + 1:], axis=1)) / L[:, i, i, None]
        return x

    def solve(self, b: np.ndarray) -> np.ndarray:
        """``M^-1 b`` for right-hand sides ``b`` (N, n, r)."""
        return self.backward(self.forward(b))
