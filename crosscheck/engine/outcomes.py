"""What a gate run found: one state's outcome (every backend's split, the comparisons, the checks, the backends in
BREAKDOWN), one case's (its states, timings, coverage) and the run's (:class:`GateResult`: passed or not)."""

from __future__ import annotations

from dataclasses import dataclass, field

from cases.model import Model
from crosscheck.checks.frames import Frame
from crosscheck.core import tolerance
from crosscheck.core.compare import DISAGREE, backend_of, Comparison, worst_of
from crosscheck.core.sampling import State
from crosscheck.engine.internal import InternalError
from crosscheck.engine.specs import CaseSpec, Checks
from crosscheck.guards import coverage as coverage_of
from crosscheck.guards.loader import LoaderCheck
from formalisms.interface import Split


@dataclass
class StateOutcome:
    """All backends at one state: their splits, any errors they raised, the backends in BREAKDOWN (condition name
    -> value above its limit; left out of the comparisons) and one comparison per quantity; ``hint``, for a failing
    state, what the shape of the error suggests (``crosscheck.reports.diagnosis``); ``scales``, the tolerance scales of
    the trusted splits (None when no split is trusted); ``internal``, the harness's own failures at this state, by
    check (``crosscheck.engine.internal``: ``chart zyx`` -> the exception it raised), each failing the state."""

    state: State
    splits: dict[str, Split]
    errors: dict[str, str]
    comparisons: dict[str, Comparison]
    breakdowns: dict[str, dict[str, float]] = field(default_factory=dict)
    checks: dict[str, Comparison] = field(default_factory=dict)
    hint: str = ""
    scales: tolerance.Scales | None = None
    internal: dict[str, InternalError] = field(default_factory=dict)

    @property
    def failed(self) -> bool:
        return (bool(self.errors) or bool(self.internal) or any(c.verdict == DISAGREE for c in self.comparisons.values())
                or any(c.verdict == DISAGREE for c in self.checks.values()))

    @property
    def trusted(self) -> dict[str, Split]:
        """The splits of the backends not wholly in BREAKDOWN (a narrower breakdown, e.g. non-unique multipliers,
        leaves out only its quantities: ``tolerance.BREAKDOWN_SCOPE``)."""
        return {name: split for name, split in self.splits.items()
                if not tolerance.whole(self.breakdowns.get(name, {}))}

    def voters(self, quantity: str) -> dict[str, Split]:
        """The trusted splits that vote on ``quantity``."""
        return {name: split for name, split in self.trusted.items()
                if quantity not in tolerance.left_out(self.breakdowns.get(name, {}))}

    @property
    def worst_ratio(self) -> float:
        return worst_of(c.worst_ratio for c in self.comparisons.values())


@dataclass
class CaseOutcome:
    """One case's states and timings (first call includes one-off preparation such as symbolic derivation);
    ``internal``, the harness's own failures in setting up or running the case outside its states, by check (``file
    reading``, ``case setup``, ``sampling``, ``coverage``, ``case``: ``crosscheck.engine.internal``), each failing the
    case; ``loader``, the model checked against its file read apart from the loader (``crosscheck.guards.loader``;
    None: no file, or not checked), each of whose findings fails the case."""

    spec: CaseSpec
    model: Model
    states: list[StateOutcome]
    first_call_s: dict[str, float] = field(default_factory=dict)
    per_state_s: dict[str, float] = field(default_factory=dict)
    charts: tuple[str, ...] = ()
    frames: tuple[Frame, ...] = ()
    coverage: coverage_of.Coverage | None = None
    closed_form: str = ""
    internal: dict[str, InternalError] = field(default_factory=dict)
    loader: LoaderCheck | None = None

    @property
    def loader_findings(self) -> tuple:
        """The loader findings of the case's model (``crosscheck.guards.loader``), each failing the case."""
        return self.loader.findings if self.loader is not None else ()

    @property
    def failed(self) -> bool:
        return (any(s.failed for s in self.states) or (self.coverage is not None and self.coverage.degenerate)
                or bool(self.internal) or bool(self.loader_findings))

    def mostly_broken(self) -> dict[str, int]:
        """The backends wholly in BREAKDOWN (``tolerance.whole``: out of the vote) at more than half of this case's
        states, with their number of such states: a backend that checks almost nothing of the case."""
        counts: dict[str, int] = {}
        for s in self.states:
            for name, conditions in s.breakdowns.items():
                if tolerance.whole(conditions):
                    counts[name] = counts.get(name, 0) + 1
        return {name: k for name, k in counts.items() if 2 * k > len(self.states)}

    def voted(self) -> set[str]:
        """The backends that took part in at least one comparison or check of this case."""
        pairs: set[tuple[str, str]] = set()
        for s in self.states:
            for c in (*s.comparisons.values(), *s.checks.values()):
                pairs.update(c.pairs)
        return {backend_of(name) for pair in pairs for name in pair}


@dataclass
class GateResult:
    """A gate run. ``required`` are the backends named on the command line without ``--optional``: each must take
    part in some comparison (a backend that declines every model, or is in BREAKDOWN everywhere, checks nothing);
    ``self_test`` the canaries' outcome (``crosscheck.guards.selftest``), None when skipped; ``interrupted``, for a run
    ended by Ctrl-C, where it stopped ("after 37/100 states of case 'panda'"; :class:`Interrupted`), "" otherwise;
    ``allow_breakdown`` the backends that may be in BREAKDOWN at most states of a case (:attr:`broken`); ``internal``
    the harness's own failures outside the cases (the self-test, a section of the report), by check
    (``crosscheck.engine.internal``)."""

    seed: int
    samples: int
    backends: tuple[str, ...]
    cases: list[CaseOutcome]
    checks: Checks = Checks()
    required: tuple[str, ...] = ()
    self_test: object = None
    interrupted: str = ""
    allow_breakdown: tuple[str, ...] = ()
    internal: dict[str, InternalError] = field(default_factory=dict)

    @property
    def absent(self) -> tuple[str, ...]:
        """The required backends that took part in no comparison of any case."""
        if not self.required:
            return ()
        voted = set().union(*(case.voted() for case in self.cases)) if self.cases else set()
        return tuple(name for name in self.required if name not in voted)

    @property
    def broken(self) -> dict[str, dict[str, int]]:
        """Case name -> the backends wholly in BREAKDOWN at most of its states (:meth:`CaseOutcome.mostly_broken`) and
        not in ``allow_breakdown`` (``--allow-breakdown``, ``--optional``): each fails the run, since a backend left
        out of the vote at most states checks almost nothing there."""
        found = {case.spec.name: {name: k for name, k in case.mostly_broken().items()
                                  if name not in self.allow_breakdown} for case in self.cases}
        return {name: backends for name, backends in found.items() if backends}

    def compared(self, case: CaseOutcome) -> tuple[str, ...]:
        """The backends of the run that took part in some comparison of ``case``, in the run's order."""
        voted = case.voted()
        return tuple(name for name in self.backends if name in voted)

    @property
    def passed(self) -> bool:
        """Whether the run finished and nothing failed (an interrupted run never passes, nor one where the harness
        failed: :attr:`has_internal_errors`)."""
        return (not self.interrupted and not any(c.failed for c in self.cases) and not self.absent
                and not self.broken and (self.self_test is None or self.self_test.passed)
                and not self.has_internal_errors)

    @property
    def has_internal_errors(self) -> bool:
        """Whether the harness's own code failed anywhere in the run (``crosscheck.engine.internal``)."""
        return bool(self.internal) or any(c.internal or any(s.internal for s in c.states) for c in self.cases)
