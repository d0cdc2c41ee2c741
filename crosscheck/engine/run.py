"""The gate's run: each case set up (its model, charts, moved scenes and closed form), its seeded states evaluated in
blocks (``crosscheck.engine.evaluation``), the self-test canaries after the cases (``crosscheck.guards.selftest``), and
the result (``crosscheck.engine.outcomes.GateResult``).

A model loaded from a file is checked against its file read apart from the loader as soon as it is built, before any
dynamics runs (``crosscheck.guards.loader``: ``CaseOutcome.loader``); a loader finding fails the case, whose states
are still evaluated (what they show is reported as well).

``run_gate(..., workers=W)`` runs the cases in W spawned processes (``crosscheck.engine.pool``) with the same
outcomes, in case order. ``run_gate(..., progress=...)`` tells a progress display where the run is
(``crosscheck.engine.phases.Step``: the case, the states evaluated, what runs now). Ctrl-C (KeyboardInterrupt) ends
the run with :class:`Interrupted`, which carries the partial result: every state evaluated until then, marked as
interrupted, never passing.

The harness's own failures do not end the run (``crosscheck.engine.internal``): an exception its code raises in a
check at a state is an internal error of that check there (``CaseSetup.evaluate_block(..., guard=True)``); one in
reading a case's file apart from the loader, setting up a case (its charts, moved scenes, closed form), drawing its
states or measuring their coverage, or anywhere else in running it, is the case's (the case fails, the other cases
run); one in the self-test is the run's. A model
that is bad input (``cases.CaseError``, ``cases.model.ModelError``, ...: :data:`INPUT_ERRORS`) still raises, as
before: the command line refuses it before the run.
"""

from __future__ import annotations

import warnings
from typing import Callable, Iterator, Sequence

import cases
from cases.build import TaskPointError
from cases.model import ModelError
from crosscheck import isolation
from crosscheck.core.sampling import ProjectionError, sample_states, State
from crosscheck.engine import pool, prepare
from crosscheck.engine.evaluation import CaseSetup
from crosscheck.engine.internal import guarded, InternalError, of as internal_error
from crosscheck.engine.outcomes import CaseOutcome, GateResult, StateOutcome
from crosscheck.engine.phases import DONE, EVALUATING, SELF_TEST, SETTING_UP, _ignore, Clock, Step
from crosscheck.engine.specs import CaseSpec, Checks
from crosscheck.guards import coverage as coverage_of, loader, selftest
from crosscheck.guards.loader import LoaderCheck
from crosscheck.references import closed_forms
from formalisms.interface import Formalism, ModelNotSupported, StateError


#: What a model or its states that are bad input raise: the user's error, not the harness's. It propagates from a
#: case (``crosscheck.cli`` turns it into exit 2), never becoming an internal error.
INPUT_ERRORS = (cases.CaseError, cases.UrdfError, ModelError, StateError, TaskPointError, ProjectionError)

#: States a case evaluates as one block after its first state (:func:`run_case`): enough that a backend's block form
#: spreads numpy's per-call cost over many states, few enough that the splits of a block take little memory.
BLOCK = 50


class Interrupted(KeyboardInterrupt):
    """Ctrl-C during :func:`run_gate`: ``result`` is the partial run, every state evaluated until then, with
    ``result.interrupted`` saying where it stopped."""

    def __init__(self, result: GateResult):
        super().__init__(f"gate interrupted {result.interrupted}")
        self.result = result


class _CaseInterrupted(KeyboardInterrupt):
    """Ctrl-C during :func:`run_case`: ``case`` holds the states evaluated until then."""

    def __init__(self, case: CaseOutcome):
        super().__init__(f"case {case.spec.name} interrupted")
        self.case = case


def run_case(spec: CaseSpec, backends: Sequence[Formalism], samples: int, seed: int,
             progress: Callable[[Step], None] | None = None, checks: Checks = Checks(),
             derive_ahead: bool = False) -> CaseOutcome:
    """The case's ``samples`` seeded states, each evaluated (:meth:`CaseSetup.evaluate`); ``progress`` is told
    every :class:`Step`. ``derive_ahead``: a CPU is free for a helper process that derives the charts ahead
    (``crosscheck.engine.prepare``). A plugin that crashed too often in the case before is tried again
    (``crosscheck.isolation.new_case``). Ctrl-C raises :class:`_CaseInterrupted` with the states evaluated until
    then. The harness failing in setting up the case or in running it outside a state's checks is an internal error
    of the case (module doc); a model that is bad input raises (:data:`INPUT_ERRORS`)."""
    tell = progress or _ignore
    tell(Step(spec.name, 0, samples, SETTING_UP))
    isolation.new_case()
    model = spec.build()                 # bad input raises here (the command line refused it before the run)
    internal: dict[str, InternalError] = {}
    checked = None
    with guarded(internal, "file reading"):  # the model against its file read apart from the loader, before dynamics
        checked = loader.check(model)
    with guarded(internal, "case setup"):
        setup = CaseSetup.build(spec, seed, checks, model)
    if "case setup" in internal:
        tell(Step(spec.name, 0, 0, DONE))
        return CaseOutcome(spec, model, [], internal=internal, loader=checked)
    seconds = announce_preparation(setup, backends)
    helper = prepare.ahead(setup, backends, seconds, checks, seed) if derive_ahead else None
    try:
        return _run_case(setup, backends, samples, seed, tell, checks, internal, checked)
    finally:
        prepare.stop(helper)


def _run_case(setup: CaseSetup, backends: Sequence[Formalism], samples: int, seed: int,
              tell: Callable[[Step], None], checks: Checks, internal: dict[str, InternalError],
              checked: LoaderCheck | None) -> CaseOutcome:
    """The case's states evaluated (:func:`run_case`); ``internal`` holds the case's internal errors so far and
    ``checked`` its loader check (``crosscheck.guards.loader``), both carried into its outcome."""
    spec = setup.spec
    states: list[State] = []
    with guarded(internal, "sampling", passing=INPUT_ERRORS):
        states = sample_states(setup.model, samples, seed, spec.name, limits=checks.joint_limits)
    outcomes: list[StateOutcome] = []

    def at(phase: str) -> None:
        tell(Step(spec.name, len(outcomes), len(states), phase))

    clock = Clock(preparing=lambda name: at(EVALUATING if name is None else f"preparing {name}"))
    try:
        at(EVALUATING)
        for block in _blocks(states):
            for outcome in setup.evaluate_block(block, backends, clock, guard=True):
                outcomes.append(outcome)
                if len(outcomes) < len(states):
                    at(EVALUATING)
    except KeyboardInterrupt:
        raise _CaseInterrupted(_case_outcome(setup, outcomes, clock, None, checks, internal, checked)) from None
    at(DONE)
    coverage = None
    with guarded(internal, "coverage"):
        coverage = coverage_of.measure(setup.model, states) if states else None
    return _case_outcome(setup, outcomes, clock, coverage, checks, internal, checked)


#: CPU seconds of one-off preparation of one backend on one case above which the gate says so before it starts.
PREPARATION_NOTICE_S = 20.0


class PreparationNotice(UserWarning):
    """A backend's one-off preparation of a case (a symbolic derivation, a compilation) will take long: shown before it
    starts, with the estimate and the ways around it."""


def preparation_seconds(setup: CaseSetup, backend: Formalism) -> float:
    """The backend's estimated preparation of the case (``Formalism.preparation``): the joint chart and each sampled
    chart; 0 for a backend without an estimate. The moved scenes are the model's with other world data, which a
    backend that prepares (Euler–Lagrange) takes as parameters of the model's own preparation."""
    if backend.preparation is None:
        return 0.0
    model = setup.model
    try:
        return backend.preparation(model, None) + sum(backend.preparation(model, c) for c in setup.charts)
    except ModelNotSupported:
        return 0.0
    except Exception:  # noqa: BLE001 - a backend's estimate failing: no notice; its own calls report its errors
        return 0.0


def announce_preparation(setup: CaseSetup, backends: Sequence[Formalism]) -> float:
    """Warn (:class:`PreparationNotice`) before a case whose preparation by some backend is estimated above
    :data:`PREPARATION_NOTICE_S`, saying how long, that it is done once (cached on disk) and how to skip it. Returns
    the estimated seconds, summed over the backends."""
    total = 0.0
    for backend in backends:
        seconds = preparation_seconds(setup, backend)
        total += seconds
        if seconds > PREPARATION_NOTICE_S:
            warnings.warn(PreparationNotice(
                f"{backend.name}: preparing case '{setup.spec.name}' ({setup.model.n} coordinates) in the joint chart "
                f"and {len(setup.charts)} chart(s) takes about {seconds:.0f} s of CPU before its first answers (once: "
                "then cached on disk); --no-charts leaves out the charts, --formalism (naming the others) leaves it "
                "out"), stacklevel=2)
    return total


def _case_outcome(setup: CaseSetup, outcomes: list[StateOutcome], clock: Clock,
                  coverage: coverage_of.Coverage | None, checks: Checks,
                  internal: dict[str, InternalError] | None = None, checked: LoaderCheck | None = None) -> CaseOutcome:
    """The case's outcome from its evaluated states (coverage None: not measured, for an interrupted case);
    ``internal`` the case's own internal errors, ``checked`` its loader check."""
    return CaseOutcome(setup.spec, setup.model, outcomes, clock.first(), clock.per_state(),
                       tuple(c.name for c in setup.charts), tuple(frame for frame, _ in setup.scenes), coverage,
                       _closed_form_coverage(setup.spec, checks), dict(internal or {}), checked)


def run_case_guarded(spec: CaseSpec, backends: Sequence[Formalism], samples: int, seed: int,
                     progress: Callable[[Step], None] | None = None, checks: Checks = Checks(),
                     derive_ahead: bool = False) -> CaseOutcome:
    """:func:`run_case`, with any exception it raises but bad input (:data:`INPUT_ERRORS`) and Ctrl-C turned into the
    case's internal error ``case``: the case fails, with no states, and the run goes on."""
    try:
        return run_case(spec, backends, samples, seed, progress, checks, derive_ahead)
    except INPUT_ERRORS:
        raise
    except Exception as exc:  # noqa: BLE001 - the harness's own failure: the case's internal error
        (progress or _ignore)(Step(spec.name, 0, 0, DONE))
        return failed_case(spec, exc)


def failed_case(spec: CaseSpec, exc: Exception) -> CaseOutcome:
    """The outcome of a case whose run raised ``exc`` (the harness's failure): no states, the internal error
    ``case``."""
    return CaseOutcome(spec, spec.build(), [], internal={"case": internal_error(exc)})


def _blocks(states: Sequence[State]) -> Iterator[Sequence[State]]:
    """The first state alone (the report's first call, which includes the backends' one-off preparation), then blocks
    of :data:`BLOCK` states."""
    if states:
        yield states[:1]
    for start in range(1, len(states), BLOCK):
        yield states[start:start + BLOCK]


def _closed_form_coverage(spec: CaseSpec, checks: Checks) -> str:
    """What the case's closed form covers, in words, for the report ("" when closed forms are off)."""
    if not checks.closed_forms:
        return ""
    if spec.path is not None:
        return "none (a model file; its reference is built from the file)"

    given = " (not the task quantities: --task-point given)" if spec.task_point is not None else ""
    return closed_forms.coverage(spec.name, dict(spec.params)) + given


def run_gate(specs: Sequence[CaseSpec], backends: Sequence[Formalism], samples: int, seed: int,
             progress: Callable[[Step], None] | None = None, checks: Checks = Checks(),
             workers: int = 0, required: Sequence[str] = (), allow_breakdown: Sequence[str] = ()) -> GateResult:
    """Run the gate over the cases; the result passes when no state shows a disagreement or an error, no case's
    sample is degenerate (``crosscheck.guards.coverage``), every ``required`` backend took part in some comparison, no
    backend but those in ``allow_breakdown`` is out of the vote (BREAKDOWN) at most states of a case
    (``GateResult.broken``) and the self-test canaries are caught (``crosscheck.guards.selftest``, unless
    ``checks.self_test`` is off).

    ``workers`` 0 runs the cases in this process; N >= 1 in N spawned processes
    (:func:`crosscheck.engine.pool.in_pool`), at most one per case (``crosscheck.cli.options.workers``: the one
    meaning of ``--workers``); the outcomes are the same as in this process and come back in case order, so the report
    is too (its timings apart). Backends that cannot be sent to another process (not picklable: a lambda, a local
    function) keep the run in this process. ``progress`` is told every :class:`Step` of a case run here, and only the
    start and the end of a case run in a worker process. Ctrl-C raises :class:`Interrupted` with the partial result."""
    tell = progress or _ignore
    count = min(workers, len(specs))
    pooled = count >= 1 and pool.picklable(backends)
    outcomes: list[CaseOutcome] = []
    result = GateResult(seed, samples, tuple(b.name for b in backends), outcomes, checks, tuple(required),
                        allow_breakdown=tuple(allow_breakdown))
    try:
        if pooled:
            pool.in_pool(run_case_guarded, specs, backends, samples, seed, tell, checks, count, outcomes,
                         failed_case, INPUT_ERRORS)
        else:
            for spec in specs:      # one case at a time here: the other CPUs may derive ahead
                outcomes.append(run_case_guarded(spec, backends, samples, seed, tell, checks, derive_ahead=True))
        if checks.self_test:
            tell(Step("", 0, 0, SELF_TEST))
            with guarded(result.internal, "self-test"):
                result.self_test = selftest.run(checks=checks)
            for r in result.self_test.results if result.self_test else ():
                if r.error:     # the harness failing in a check's canary: an internal error of that check
                    result.internal.setdefault(f"self-test ({r.canary.check} canary)", InternalError(
                        r.error, f"the {r.canary.check} canary"))
    except KeyboardInterrupt as exc:
        result.interrupted = _where(exc, specs, samples, outcomes, pooled)
        raise Interrupted(result) from None
    return result


def _where(exc: KeyboardInterrupt, specs: Sequence[CaseSpec], samples: int, outcomes: list[CaseOutcome],
           pooled: bool) -> str:
    """Where a run stopped, in words; a case interrupted part way joins ``outcomes`` with the states it evaluated."""
    if isinstance(exc, _CaseInterrupted):
        outcomes.append(exc.case)
        return f"after {len(exc.case.states)}/{samples} states of case '{exc.case.spec.name}'"
    if len(outcomes) == len(specs):
        return "during the self-test (every case evaluated)"
    if pooled:
        return (f"after {len(outcomes)}/{len(specs)} cases (run in worker processes: the cases in flight are not "
                "in the report)")
    return f"after 0/{samples} states of case '{specs[len(outcomes)].name}' (setting it up)"
