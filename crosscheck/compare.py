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
    pairs = {(a, b): float(np.max(np.abs(present[a] - present[b]))) / tol
             for a, b in combinations(present, 2)}
    worst = max(pairs.values())
    if not worst <= 1.0:  # also catches NaN
        return Comparison(quantity, DISAGREE, tol, worst, pairs, _outlier(list(present), pairs), skipped, present)
    return Comparison(quantity, AGREE, tol, worst, pairs, None, skipped)


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
