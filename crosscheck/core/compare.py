"""Comparison of one quantity across backends at one state, and the verdict (docs/design.md, verdicts).

A DISAGREE carries its severity (how many tolerances the worst pair is apart, :data:`SEVERITY`) and the vote:
the outlier when three or more voters allow one, or why none is named (:func:`vote`). A DISAGREE that the
divergence registry explains becomes KNOWN (``crosscheck.engine.divergences``): reported with its reason, not a failure.

Shared code. In a chart or frame check the voters are of two kinds, told apart by their labels: plain ones
(``newton_euler``: a joint-chart answer, mapped into the chart by the harness; an answer in the original scene) and
marked ones (``newton_euler@zyx``: a chart-native answer; ``newton_euler@g1``: an answer in the scene the harness moved).
Between the two sits code every backend shares (``compare(..., shared="chart map zyx")``). When the disagreement
separates exactly along it (the plain voters agree with each other, the marked ones too, and every pair across
disagrees), every backend moved together and none is to blame: the shared code is the outlier (``Comparison.shared``)
when each side has two voters or more; with one voter alone on its side, the vote cannot tell the shared code from
that voter's backend and names neither.
"""

from __future__ import annotations

import functools
from collections import Counter
from dataclasses import dataclass, field
from itertools import combinations
from typing import Iterable

import numpy as np

from formalisms.interface import Unsupported

AGREE, DISAGREE, KNOWN, NOT_COMPARED = "agree", "DISAGREE", "KNOWN", "NOT COMPARED"

#: Severity of a DISAGREE from its worst error/tolerance ratio r: (upper bound on r, name), the first band that
#: holds. The tolerance is 100 eps times the sizes of the summed terms, so r counts rounding budgets, and on the
#: double pendulum r ~ 2.5e11 (median; 4e10 to 1.3e12 over states) times the relative error of a perturbed mass:
#:
#: - marginal, 1 < r <= 10: within the reach of rounding the tolerance model may under-estimate near an
#:   ill-conditioned state (look at the conditioning before the physics), or an error in the 10th digit;
#: - clear, 10 < r <= 1e4: no rounding explains it, but the answers match to 7-10 digits (a mass off by a relative
#:   1e-8 gives median r = 2.5e3): a parameter wrong in a late digit, a truncated constant, a lost-precision formula;
#: - gross, r > 1e4 or NaN: a relative error of ~1e-7 or more (mass off by 1e-6: median r = 2.5e5); a wrong term,
#:   sign or factor gives r = 1e10 and more.
SEVERITY: tuple[tuple[float, str], ...] = ((10.0, "marginal"), (1e4, "clear"), (np.inf, "gross"))


class ToleranceError(ValueError):
    """A tolerance that is NaN or negative: the harness's own failure (``crosscheck.engine.internal``), which no
    answer of the backends could agree or disagree with. Raised by :func:`compare` for what its caller computed."""

    caller_to_blame = True


@dataclass(frozen=True)
class Comparison:
    """Verdict for one quantity: the worst pairwise error/tolerance ratio and, when a vote allows, the outlier.

    ``pairs`` maps (backend_a, backend_b) to the largest difference divided by its tolerance (entry by entry when
    the tolerance is one per entry, e.g. per coordinate of an acceleration); ``tolerance`` is the tolerance where the
    worst pair is worst.
    ``outlier`` is the backend whose removal makes all others agree while it disagrees with each of them;
    None when everything agrees or no single backend explains the disagreement. ``values`` (voter -> value) is
    kept for a disagreement only, for the report. ``severity`` (:data:`SEVERITY`) is set for a disagreement;
    ``reason`` is the registry's explanation of a KNOWN one. :meth:`closeness` says how close each backend came.
    ``shared``: the shared code (module doc: ``chart map zyx``, ``frame move g1``) when the disagreement separates
    exactly along it; it is then the outlier, unless one side has a single voter (the outlier is then None: that voter's
    backend or the shared code). None otherwise.
    """

    quantity: str
    verdict: str
    tolerance: float
    worst_ratio: float
    pairs: dict[tuple[str, str], float] = field(default_factory=dict)
    outlier: str | None = None
    not_compared: tuple[str, ...] = ()
    values: dict[str, np.ndarray] = field(default_factory=dict)
    severity: str | None = None
    reason: str | None = None
    shared: str | None = None

    @property
    def voters(self) -> tuple[str, ...]:
        """The voters compared, in order of first appearance in ``pairs``."""
        return tuple(dict.fromkeys(name for pair in self.pairs for name in pair))

    def closeness(self) -> dict[str, float]:
        """Each voter that is a backend: how close it came, from the pairs alone (nothing more is kept per comparison,
        so it costs the evaluation nothing): its error/tolerance against a voter that is not a backend (the exact
        value) when there is one, else the lower median of its error/tolerance against each other voter, NaN above
        every finite figure (its own figure is NaN when most of its pairs are). An outlier's figure is its distance
        from the others; another voter's, its distance from the typical voter, which one outlier does not move."""
        theirs: dict[str, list[float]] = {}
        for (a, b), ratio in self.pairs.items():
            theirs.setdefault(a, []).append(ratio)
            theirs.setdefault(b, []).append(ratio)
        known = [v for v in self.voters if v in NOT_BACKENDS]
        if known:
            return {v: self.pairs.get((v, known[0]), self.pairs.get((known[0], v))) for v in theirs
                    if v not in NOT_BACKENDS}
        return {v: _low_median(ratios) for v, ratios in theirs.items() if v not in NOT_BACKENDS}

    @property
    def disagreeing_pairs(self) -> list[tuple[str, str]]:
        """The pairs further apart than the tolerance (NaN included)."""
        return [pair for pair, ratio in self.pairs.items() if not ratio <= 1.0]


def _low_median(ratios: list[float]) -> float:
    """The lower median of error/tolerance ratios (a ratio one pair has: with one other voter wrong, a voter's figure is
    still one of its good pairs'), a NaN above every number."""
    ordered = sorted(ratios, key=lambda r: float("inf") if r != r else r)
    return ordered[(len(ordered) - 1) // 2]


def severity(ratio: float) -> str:
    """The :data:`SEVERITY` band of an error/tolerance ratio above 1 (NaN is gross)."""
    return next((name for bound, name in SEVERITY if ratio <= bound), SEVERITY[-1][1])


def worst_of(ratios) -> float:
    """The largest error/tolerance ratio, NaN when any is NaN (a plain ``max`` may skip a NaN); 0 when empty."""
    ratios = list(ratios)
    return float("nan") if any(r != r for r in ratios) else max(ratios, default=0.0)


def _as_vector(value) -> np.ndarray:
    return np.atleast_1d(np.asarray(value, dtype=float))


def compare(quantity: str, values: dict[str, object], tol, shared: str | None = None) -> Comparison:
    """Compare ``values`` (backend name -> value, None or UNSUPPORTED) pairwise against ``tol``: one tolerance for
    every entry, or an array of one per entry of the values (flattened). ``shared``: the name of the code every
    backend shares between the plain voters and the ``backend@scene`` ones (module doc), blamed when the disagreement
    separates exactly along it."""
    present = {k: _as_vector(v) for k, v in values.items() if v is not None and not isinstance(v, Unsupported)}
    skipped = tuple(k for k, v in values.items() if isinstance(v, Unsupported))
    tols = np.asarray(tol, dtype=float).ravel()
    if not (tols >= 0.0).all():
        raise ToleranceError(f"the tolerance for {quantity} is {tols[~(tols >= 0.0)][0]:g} (NaN or negative): the "
                             "harness cannot judge it, whatever the backends answer")
    if len(present) < 2:
        return Comparison(quantity, NOT_COMPARED, float(tols.max(initial=0.0)), 0.0, not_compared=skipped)
    ratios = _ratios(_pairwise(list(present.values())), tols)          # (pairs, entries)
    if ratios.shape[1] == 0:                                           # empty values (B of a model with no input)
        return Comparison(quantity, AGREE, 0.0, 0.0, dict.fromkeys(combinations(present, 2), 0.0), None, skipped)
    per_pair = ratios.max(axis=1)                                      # NaN where a pair has one
    worst_pair, entry = _worst(ratios, per_pair)
    pairs = dict(zip(combinations(present, 2), per_pair.tolist()))
    worst = float(per_pair[worst_pair])
    at = float(tols[entry if tols.size > 1 else 0])
    if not worst <= 1.0:
        sides = _sides(list(present), pairs) if shared is not None else None
        if sides is None:
            return Comparison(quantity, DISAGREE, at, worst, pairs, _outlier(list(present), pairs), skipped, present,
                              severity(worst))
        outlier = shared if min(len(side) for side in sides) >= 2 else None
        return Comparison(quantity, DISAGREE, at, worst, pairs, outlier, skipped, present, severity(worst),
                          shared=shared)
    return Comparison(quantity, AGREE, at, worst, pairs, None, skipped)


def _worst(ratios: np.ndarray, per_pair: np.ndarray) -> tuple[int, int]:
    """The worst pair (row of ``ratios``, the first of the largest ``per_pair``, NaN the worst) and its worst entry."""
    if not np.isnan(per_pair).any():
        worst_pair = int(per_pair.argmax())
        return worst_pair, int(ratios[worst_pair].argmax())
    worst_pair = int(np.argmax(np.where(np.isnan(per_pair), np.inf, per_pair)))
    return worst_pair, int(np.argmax(np.where(np.isnan(ratios[worst_pair]), np.inf, ratios[worst_pair])))


def _ratios(differences: np.ndarray, tol: np.ndarray) -> np.ndarray:
    """error / tolerance entry by entry; an exact match is 0 whatever the tolerance (a tolerance that underflows to 0
    at a state at rest, qd = 0, would otherwise make 0 / 0 a NaN and a false DISAGREE)."""
    if tol.size not in (1, differences.shape[1]):
        raise ValueError(f"{tol.size} tolerances for values of {differences.shape[1]} entries")
    with np.errstate(divide="ignore", invalid="ignore"):
        return np.where(differences == 0.0, 0.0, differences / tol)


@functools.lru_cache(maxsize=None)
def _pair_indices(count: int) -> tuple[np.ndarray, np.ndarray]:
    """The rows of every pair of ``count`` voters, in ``itertools.combinations`` order (read-only)."""
    i, j = np.triu_indices(count, 1)
    i.flags.writeable = j.flags.writeable = False
    return i, j


def _pairwise(vectors: list[np.ndarray]) -> np.ndarray:
    """Absolute differences of every pair (rows, in ``itertools.combinations`` order) entry by entry (columns), in one
    array operation; a scalar (the exact voter) is compared with every entry."""
    size = max(v.size for v in vectors)
    if any(v.size not in (1, size) for v in vectors):
        raise ValueError(f"values of different sizes cannot be compared: {[v.shape for v in vectors]}")
    V = np.array([v.ravel() if v.size == size else np.full(size, v.flat[0]) for v in vectors])
    i, j = _pair_indices(len(vectors))
    return np.abs(V[i] - V[j])


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


def marked(voter: str) -> bool:
    """Whether a voter is on the marked side of a shared code (module doc): ``backend@scene``."""
    return "@" in voter


def _sides(names: list[str], pairs: dict[tuple[str, str], float]) -> tuple[list[str], list[str]] | None:
    """(plain voters, marked voters) when a disagreement among three or more separates exactly between them: every
    pair on one side agrees, every pair across disagrees; else None."""
    plain, marks = [n for n in names if not marked(n)], [n for n in names if marked(n)]
    if len(names) < 3 or not plain or not marks:
        return None
    if any((marked(a) != marked(b)) == (r <= 1.0) for (a, b), r in pairs.items()):
        return None
    return plain, marks


#: Voters that are not backends: a value known exactly (``exact``) and a condition the harness computed itself
#: (``independent``, ``crosscheck.guards.conditioning``). A disagreement is never blamed on them by elimination.
NOT_BACKENDS = ("exact", "independent")


def backend_of(voter: str) -> str:
    """The backend behind a voter label: ``newton_euler@g1`` (moved scene), ``geometric@affine`` (chart-native),
    ``screw (Ad-mapped)`` (a frame law's prediction) all belong to their backend; ``exact`` stays ``exact``."""
    return voter.split("@")[0].split(" (")[0]


def suspect(comp: Comparison) -> str | None:
    """The backend a disagreement points at: the outlier's backend; or the one backend behind every voter of a
    comparison that involves only it (a frame law: its prediction against its moved answer); or the one backend
    in every disagreeing pair while two or more other voters remain (a chart or frame check, where a backend votes
    twice, in the joint chart and in the chart or the moved scene); else None. A disagreement along shared code
    (``Comparison.shared``) points at that code (its name) when the vote names it, else at no one."""
    if comp.shared is not None:
        return comp.shared if comp.outlier == comp.shared else None
    if comp.outlier is not None:
        return backend_of(comp.outlier)
    behind = {backend_of(v) for v in comp.voters} - set(NOT_BACKENDS)
    if len(behind) == 1:
        return behind.pop()
    pairs = comp.disagreeing_pairs
    found = [b for b in sorted(behind) if pairs and all(b in (backend_of(x), backend_of(y)) for x, y in pairs)]
    if len(found) != 1:
        return None
    return found[0] if sum(backend_of(v) != found[0] for v in comp.voters) >= 2 else None


def vote(comp: Comparison) -> str:
    """How the vote on a disagreement came out, in words: the outlier, or why none is named."""
    named = suspect(comp)
    if comp.shared is not None:
        return _shared_vote(comp)
    if comp.outlier == "exact":
        return "outlier exact: the backends agree with each other against the exact value (the state or the claim)"
    if comp.outlier == "independent":
        return ("outlier independent: the backends agree with each other against the condition the harness computed "
                "from Pinocchio's M and J")
    if comp.outlier is not None:
        return f"outlier {comp.outlier}"
    mine = [v for v in comp.voters if backend_of(v) == named]
    if named is not None and len(mine) == len(comp.voters):
        return f"one backend only ({named}): {' vs '.join(comp.voters)}"
    if named is not None:
        return f"outlier {named} (its voters {', '.join(mine)} against the others)"
    if len(comp.voters) == 2:
        return f"only two voters ({', '.join(comp.voters)}): no vote, either may be wrong"
    split = ", ".join(f"{a}/{b}" for a, b in comp.disagreeing_pairs)
    return f"split vote: no single backend explains it among {len(comp.voters)} voters (apart: {split})"


def _shared_vote(comp: Comparison) -> str:
    """:func:`vote` for a disagreement along shared code (``Comparison.shared``)."""
    sides = _sides(list(comp.voters), comp.pairs)
    if sides is None:       # a check of one backend blamed on the shared code by the state's other checks (frame laws)
        return (f"outlier {comp.shared} (shared code) — every backend moves together: the other checks of the state "
                f"separate along it, so {' vs '.join(comp.voters)} is not one backend's")
    few, many = sorted(sides, key=len)
    if comp.outlier == comp.shared:
        return (f"outlier {comp.shared} (shared code) — every backend moves together: the {len(few)} voters "
                f"{', '.join(few)} agree with each other against the {len(many)} others, which agree with each other")
    return (f"{comp.shared} (shared code) or {few[0]}, the only voter on its side: the {len(many)} others agree with "
            f"each other against it; one voter alone cannot tell its backend from the shared code")


@dataclass(frozen=True)
class Suspects:
    """Who the disagreements among some comparisons point at: per backend the number of disagreements where it is
    the suspect (:func:`suspect`), and the disagreements no single backend explains (``split``: three or more
    voters; ``undecided``: two voters of different backends)."""

    by_backend: dict[str, int]
    split: int = 0
    undecided: int = 0

    def __bool__(self) -> bool:
        return bool(self.by_backend or self.split or self.undecided)


def suspects(comparisons: Iterable[Comparison]) -> Suspects:
    """Tally the DISAGREE comparisons among ``comparisons`` by suspect, most frequent first."""
    named, split, undecided = Counter(), 0, 0
    for comp in comparisons:
        if comp.verdict != DISAGREE:
            continue
        who = suspect(comp)
        if who is not None:
            named[who] += 1
        elif len(comp.voters) == 2:
            undecided += 1
        else:
            split += 1
    return Suspects(dict(sorted(named.items(), key=lambda kv: (-kv[1], kv[0]))), split, undecided)
