"""Comparison of one quantity across backends at one state, and the verdict (DESIGN.md, verdicts)."""

from __future__ import annotations

from dataclasses import dataclass, field
from itertools import combinations

import numpy as np

from formalisms.interface import Unsupported

AGREE, DISAGREE, NOT_COMPARED = "agree", "DISAGREE", "NOT COMPARED"


@dataclass(frozen=True)
class Comparison:
    """Verdict for one quantity: the worst pairwise error/tolerance ratio and, when a vote allows, the outlier.

    ``pairs`` maps (backend_a, backend_b) to the max-norm difference divided by the tolerance.
    ``outlier`` is the backend whose removal makes all others agree while it disagrees with each of them;
    None when everything agrees or no single backend explains the disagreement. ``values`` (voter -> value) is
    kept for a disagreement only, for the report.
    """

    quantity: str
    verdict: str
    tolerance: float
    worst_ratio: float
    pairs: dict[tuple[str, str], float] = field(default_factory=dict)
    outlier: str | None = None
    not_compared: tuple[str, ...] = ()
    values: dict[str, np.ndarray] = field(default_factory=dict)


def _as_vector(value) -> np.ndarray:
    return np.atleast_1d(np.asarray(value, dtype=float))


def compare(quantity: str, values: dict[str, object], tol: float) -> Comparison:
    """Compare ``values`` (backend name -> value, None or UNSUPPORTED) pairwise against ``tol``."""
    present = {k: _as_vector(v) for k, v in values.items() if v is not None and not isinstance(v, Unsupported)}
    skipped = tuple(k for k, v in values.items() if isinstance(v, Unsupported))
    if len(present) < 2:
        return Comparison(quantity, NOT_COMPARED, tol, 0.0, not_compared=skipped)
    pairs = dict(zip(combinations(present, 2), (_pairwise(list(present.values())) / tol).tolist()))
    worst = max(pairs.values())
    if not worst <= 1.0:  # also catches NaN
        return Comparison(quantity, DISAGREE, tol, worst, pairs, _outlier(list(present), pairs), skipped, present)
    return Comparison(quantity, AGREE, tol, worst, pairs, None, skipped)


def _pairwise(vectors: list[np.ndarray]) -> np.ndarray:
    """Max-norm differences of every pair (in ``itertools.combinations`` order), in one array operation; a scalar
    (the exact voter) is compared with every entry."""
    size = max(v.size for v in vectors)
    if any(v.size not in (1, size) for v in vectors):
        raise ValueError(f"values of different sizes cannot be compared: {[v.shape for v in vectors]}")
    V = np.array([v.ravel() if v.size == size else np.full(size, v.flat[0]) for v in vectors])
    i, j = np.triu_indices(len(vectors), 1)
    return np.abs(V[i] - V[j]).max(axis=1)


def _outlier(names: list[str], pairs: dict[tuple[str, str], float]) -> str | None:
    """The single backend that disagrees with every other while the others agree (needs >= 3 voters)."""
    if len(names) < 3:
        return None
    for suspect in names:
        with_it = [r for (a, b), r in pairs.items() if suspect in (a, b)]
        without = [r for (a, b), r in pairs.items() if suspect not in (a, b)]
        if all(r <= 1.0 for r in without) and all(not r <= 1.0 for r in with_it):
            return suspect
    return None
