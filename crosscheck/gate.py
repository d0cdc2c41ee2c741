"""The equivalence gate: sample states per case, evaluate every backend, compare, collect verdicts.

Besides the cross-backend comparison at each state, the gate checks by default (:class:`Checks`) that the
answers do not depend on the chart (every built-in chart that applies; ``crosscheck.invariance``), on the world
frame (state ``i`` in sampled frame ``i mod frames``) or break conservation (``crosscheck.conservation``).

Each backend runs once per state and scene (joint chart, each chart, the moved scene); the tolerance scales of the
trusted joint-chart splits are computed once per state and shared by every check. A case's states are evaluated in
blocks (:meth:`CaseSetup.evaluate_block`): a backend with a block form (``formalisms.interface.with_block_form``)
splits a block's states in one call in the joint chart and in each moved scene, with the very numbers of its
state-by-state ``split``, so the outcomes are those of one state at a time. ``run_gate(..., workers=W)`` runs the
cases in W spawned processes with the same outcomes, in case order.


``run_gate(..., progress=...)`` tells a progress display where the run is (:class:`Step`: the case, the states
evaluated, what runs now). Ctrl-C (KeyboardInterrupt) ends the run with :class:`Interrupted`, which carries the
partial result: every state evaluated until then, marked as interrupted, never passing.
"""

from __future__ import annotations

import dataclasses
import pickle
import signal
import time
import warnings
from dataclasses import dataclass, field
from functools import partial
from typing import Callable, Iterator, Sequence

import numpy as np

import cases
from cases import task as task_points
from cases.model import Model
from crosscheck import charts as chart_catalog
from crosscheck import conditioning, conservation, equilibria, frames, invariance, linearization
from crosscheck import coverage as coverage_of
from crosscheck import tolerance as tolerance_policy
from crosscheck import workers as worker_processes
from crosscheck.backends import load_plugins, plugin_specs
from crosscheck.compare import DISAGREE, Comparison, backend_of, compare, worst_of
from crosscheck.sampling import State, sample_states
from formalisms.interface import UNSUPPORTED, Formalism, ModelNotSupported, Split, block_form

#: States per case of a default run (``--samples``). Every check runs at every state, so the run's time is linear in
#: it: 50 states of the 26 built-in cases keep the default gate near a minute on 2 cores. The fault catalog's every
#: fault is caught within the first two states of some case (docs/faults.md), and a fault that shows at a share p of
#: a case's states is missed with probability (1 - p)^50; longer runs: ``--samples``, ``crosscheck fuzz``.
DEFAULT_SAMPLES = 50

#: States a case evaluates as one block after its first state (:func:`run_case`): enough that a backend's block form
#: spreads numpy's per-call cost over many states, few enough that the splits of a block take little memory.
BLOCK = 50


@dataclass(frozen=True)
class Checks:
    """Which checks the gate runs besides the cross-backend comparison: invariance and conservation, the closed
    forms of the cases that have them (``crosscheck.closed_forms``) and the self-test canaries
    (``crosscheck.selftest``)."""

    charts: bool = True
    frames: int = 2
    conservation: bool = True
    closed_forms: bool = True
    self_test: bool = True
    linearization: bool = True
    joint_limits: bool = True   # sample within the joint limits a model declares (``--ignore-limits``: freely)


@dataclass(frozen=True)
class CaseSpec:
    """How to build one case: a built-in factory with parameters, or a model file (URDF or MJCF, ``path``) with the
    URDF ``base`` ("fixed", "free", or None: the file's own) and ``actuated`` joints (None: every joint but a free
    base's; ``cases.from_file``); ``task_point``, when given, the default task point as ``BODY[:x,y,z]``
    (``cases.task.with_task_point``; a ``cases.task.TaskPointError`` for an unknown body or bad numbers)."""

    name: str
    params: tuple[tuple[str, str], ...] = ()
    path: str | None = None
    base: str | None = None
    actuated: tuple[str, ...] | None = None
    task_point: str | None = None

    def build(self) -> Model:
        if self.path is not None:
            model = cases.from_file(self.path, name=self.name, base=self.base, actuated=self.actuated)
        else:
            model = cases.load(self.name, **dict(self.params))
        return model if self.task_point is None else task_points.with_task_point(model, *task_points.parse(
            self.task_point))

    def closed_form(self):
        """The ``closed_form`` voter bound to this built-in case and its parameters (``crosscheck.closed_forms``),
        None when the case has none (a model file never has one). With a ``task_point`` given, it votes on
        everything but the task quantities, which its equations have for the case's own task point."""
        if self.path is not None:
            return None
        from crosscheck import closed_forms

        voter = closed_forms.voter(self.name, dict(self.params))
        if voter is None or self.task_point is None:
            return voter
        return dataclasses.replace(voter, split=partial(_without_task, voter.split),
                                   summary=f"{voter.summary} (not the task quantities: --task-point given)")

    def cli_args(self) -> str:
        """The command-line arguments that select this case."""
        point = f" --task-point {self.task_point}" if self.task_point is not None else ""
        if self.path is not None:
            return (f"--model {self.path}" + (f" --base {self.base}" if self.base else "")
                    + (f" --actuated {','.join(self.actuated)}" if self.actuated is not None else "") + point)
        return " ".join([f"--case {self.name}"] + [f"--param {k}={v}" for k, v in self.params]) + point


def _without_task(split: Callable[..., Split], model: Model, q, qd, u) -> Split:
    """``split``'s answer with the task drift, the task inertia and its condition declared unsupported."""
    s = split(model, q, qd, u)
    return dataclasses.replace(s, task_drift=UNSUPPORTED, task_inertia=UNSUPPORTED,
                               conditions={k: v for k, v in s.conditions.items() if k != "task_inertia"})


@dataclass
class StateOutcome:
    """All backends at one state: their splits, any errors they raised, the backends in BREAKDOWN (condition name
    -> value above its limit; left out of the comparisons) and one comparison per quantity; ``hint``, for a failing
    state, what the shape of the error suggests (``crosscheck.diagnosis``); ``scales``, the tolerance scales of the
    trusted splits (None when no split is trusted)."""

    state: State
    splits: dict[str, Split]
    errors: dict[str, str]
    comparisons: dict[str, Comparison]
    breakdowns: dict[str, dict[str, float]] = field(default_factory=dict)
    checks: dict[str, Comparison] = field(default_factory=dict)
    hint: str = ""
    scales: tolerance_policy.Scales | None = None

    @property
    def failed(self) -> bool:
        return bool(self.errors) or any(c.verdict == DISAGREE for c in self.comparisons.values()) or any(
            c.verdict == DISAGREE for c in self.checks.values())

    @property
    def trusted(self) -> dict[str, Split]:
        """The splits of the backends not wholly in BREAKDOWN (a narrower breakdown, e.g. non-unique multipliers,
        leaves out only its quantities: ``tolerance.BREAKDOWN_SCOPE``)."""
        return {name: split for name, split in self.splits.items()
                if not tolerance_policy.whole(self.breakdowns.get(name, {}))}

    def voters(self, quantity: str) -> dict[str, Split]:
        """The trusted splits that vote on ``quantity``."""
        return {name: split for name, split in self.trusted.items()
                if quantity not in tolerance_policy.left_out(self.breakdowns.get(name, {}))}

    @property
    def worst_ratio(self) -> float:
        return worst_of(c.worst_ratio for c in self.comparisons.values())


@dataclass
class CaseOutcome:
    """One case's states and timings (first call includes one-off preparation such as symbolic derivation)."""

    spec: CaseSpec
    model: Model
    states: list[StateOutcome]
    first_call_s: dict[str, float] = field(default_factory=dict)
    per_state_s: dict[str, float] = field(default_factory=dict)
    charts: tuple[str, ...] = ()
    frames: tuple[frames.Frame, ...] = ()
    coverage: coverage_of.Coverage | None = None
    closed_form: str = ""

    @property
    def failed(self) -> bool:
        return any(s.failed for s in self.states) or (self.coverage is not None and self.coverage.degenerate)

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
    ``self_test`` the canaries' outcome (``crosscheck.selftest``), None when skipped; ``interrupted``, for a run
    ended by Ctrl-C, where it stopped ("after 37/100 states of case 'panda'"; :class:`Interrupted`), "" otherwise."""

    seed: int
    samples: int
    backends: tuple[str, ...]
    cases: list[CaseOutcome]
    checks: Checks = Checks()
    required: tuple[str, ...] = ()
    self_test: object = None
    interrupted: str = ""

    @property
    def absent(self) -> tuple[str, ...]:
        """The required backends that took part in no comparison of any case."""
        if not self.required:
            return ()
        voted = set().union(*(case.voted() for case in self.cases)) if self.cases else set()
        return tuple(name for name in self.required if name not in voted)

    @property
    def passed(self) -> bool:
        """Whether the run finished and nothing failed (an interrupted run never passes)."""
        return (not self.interrupted and not any(c.failed for c in self.cases) and not self.absent
                and (self.self_test is None or self.self_test.passed))


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


#: :attr:`Step.phase` besides ``"preparing <backend>"``.
SETTING_UP = "setting up (model, charts, frames, states)"
EVALUATING = "evaluating"
IN_WORKER = "running in a worker process"
DONE = "done"
SELF_TEST = "self-test canaries"


@dataclass(frozen=True)
class Step:
    """Where a gate run is, for a progress display: ``done`` of the ``states`` states of case ``case`` evaluated, and
    what runs now (``phase``): :data:`SETTING_UP`; :data:`EVALUATING` state ``done + 1``; ``"preparing <backend>"``
    (that state includes the backend's first call on the case, with its one-off preparation: symbolic derivation,
    compilation); :data:`IN_WORKER` (a worker process reports only the case's end); :data:`DONE`; after the cases
    :data:`SELF_TEST` (``case`` empty)."""

    case: str
    done: int
    states: int
    phase: str

    @property
    def text(self) -> str:
        """The step in words: "panda: evaluating state 38/100", "panda: preparing euler_lagrange"."""
        if not self.case:
            return self.phase
        if self.phase == DONE:
            return f"{self.case}: {self.done} states evaluated"
        if self.phase == EVALUATING:
            return f"{self.case}: evaluating state {self.done + 1}/{self.states}"
        return f"{self.case}: {self.phase}"


def _ignore(step: Step) -> None:
    """No progress display."""


@dataclass
class Clock:
    """Seconds of each backend's calls on one case, in call order (the first includes one-off preparation: symbolic
    derivation, compilation). ``preparing``, when set, is called with a backend's name before its first call and
    with None once that call is over."""

    calls: dict[str, list[float]] = field(default_factory=dict)
    preparing: Callable[[str | None], None] | None = None

    def timed(self, name: str, call: Callable[[], object], states: int = 1) -> object:
        """``call()``, timed as backend ``name``'s on ``states`` states (each state gets an equal share)."""
        first = name not in self.calls and self.preparing is not None
        if first:
            self.preparing(name)
        start = time.perf_counter()
        try:
            return call()
        finally:
            self.calls.setdefault(name, []).extend([(time.perf_counter() - start) / max(states, 1)] * states)
            if first:
                self.preparing(None)

    def first(self) -> dict[str, float]:
        return {name: times[0] for name, times in self.calls.items()}

    def per_state(self) -> dict[str, float]:
        """Mean seconds of the calls after the first (the first when there is no other)."""
        return {name: (sum(times[1:]) / (len(times) - 1) if len(times) > 1 else times[0])
                for name, times in self.calls.items()}


def run_backends(model: Model, state: State, backends: Sequence[Formalism], clock: Clock | None = None
                 ) -> StateOutcome:
    """Every backend's split at ``state``, the errors they raised and the backends in BREAKDOWN, without the
    comparisons (what a moved scene needs: :func:`add_checks`). A backend raising ``ModelNotSupported`` is in
    neither ``splits`` nor ``errors``."""
    return run_block(model, [state], backends, clock)[0]


def run_block(model: Model, states: Sequence[State], backends: Sequence[Formalism], clock: Clock | None = None
              ) -> list[StateOutcome]:
    """:func:`run_backends` at each of ``states``, every backend over the block at once (:func:`_split_states`);
    ``clock`` receives each state's share of a backend's time on the block."""
    clock = clock or Clock()
    found = {backend.name: clock.timed(backend.name, lambda: _split_states(backend, model, states), len(states))
             for backend in backends}
    return [outcome_of(state, {name: splits[k] for name, splits in found.items()}) for k, state in enumerate(states)]


def _split_states(backend: Formalism, model: Model, states: Sequence[State]) -> list[tuple[Split | None, str | None]]:
    """:func:`_split_one` at each of ``states``: in one call of the backend's block form when it has one (its elements
    are ``split``'s, bit for bit) and there are several states; else state by state, and so when the block raises:
    each state then gives the split or the error it gives alone."""
    many = block_form(backend)
    if many is not None and len(states) > 1:
        try:
            return [(split, None) for split in many(model, *_rows(model, states))]
        except Exception:  # some state of the block fails: each state on its own says which, and how
            pass
    return [_split_one(backend, model, state) for state in states]


def _rows(model: Model, states: Sequence[State]) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """``(Q, QD, U)``: the states' ``q``, ``qd`` and ``u`` as the rows of three arrays."""
    return tuple(np.array([getattr(s, name) for s in states], dtype=float).reshape(len(states), width)
                 for name, width in (("q", model.nq), ("qd", model.nv), ("u", model.m)))


def _split_one(backend: Formalism, model: Model, state: State) -> tuple[Split | None, str | None]:
    """``backend``'s split at ``state`` or the error it raised (as reported); neither when it declines the model
    (``ModelNotSupported``)."""
    try:
        return backend.split(model, state.q, state.qd, state.u), None
    except ModelNotSupported:
        return None, None
    except Exception as exc:  # a backend that raises on a valid state has failed; report, don't crash
        return None, f"{type(exc).__name__}: {exc}"


def outcome_of(state: State, found: dict[str, tuple[Split | None, str | None]]) -> StateOutcome:
    """The outcome at ``state`` of the backends' splits and errors (:func:`_split_one`, by backend), without the
    comparisons; the backends in BREAKDOWN found from their splits."""
    splits = {name: split for name, (split, _) in found.items() if split is not None}
    errors = {name: error for name, (_, error) in found.items() if error is not None}
    breakdowns = {name: b for name, split in splits.items() if (b := tolerance_policy.breakdown(split))}
    return StateOutcome(state, splits, errors, {}, breakdowns)


def evaluate(model: Model, state: State, backends: Sequence[Formalism], clock: Clock | None = None) -> StateOutcome:
    """Every backend's split at ``state`` and the comparison of each quantity in the tolerance table.

    A backend whose method is ill-conditioned here (``tolerance.breakdown``) is reported as BREAKDOWN and left
    out of the comparisons (all, or the quantities the condition concerns) and of the tolerance scales: its answer
    is not trusted there, and it is not a bug. That is a claim, and it is audited (``crosscheck.conditioning``):
    the ``conditions: <name>`` checks compare every reported condition with the harness's own, and a BREAKDOWN where
    the problem is well-conditioned is dropped, so that backend votes. A backend that raises ``ModelNotSupported``
    (written for other mechanisms) is NOT COMPARED: it joins every comparison as UNSUPPORTED, so the report lists it
    as not supplied. The tolerance scales of the trusted splits are kept in ``outcome.scales`` for the checks
    (:func:`add_checks`).
    """
    outcome = run_backends(model, state, backends, clock)
    judge(model, outcome, backends)
    return outcome


def judge(model: Model, outcome: StateOutcome, backends: Sequence[Formalism]) -> None:
    """What :func:`evaluate` does once the ``backends`` have run at ``outcome``'s state: the conditioning audit and
    the comparisons, the backends that declined the model joining them as UNSUPPORTED."""
    outcome.checks.update(conditioning.audit(model, outcome.state, outcome.splits, outcome.breakdowns))
    compare_all(model, outcome, [b.name for b in backends if b.name not in outcome.splits
                                 and b.name not in outcome.errors])


def compare_all(model: Model, outcome: StateOutcome, unsupported: Sequence[str] = ()) -> None:
    """The comparison of each quantity in the tolerance table among ``outcome``'s trusted splits (the ``unsupported``
    backends joining as UNSUPPORTED), with the tolerance scales of those splits kept in ``outcome.scales``."""
    state = outcome.state
    outcome.comparisons.clear()
    outcome.scales = None
    if not outcome.trusted:
        return
    at = outcome.scales = tolerance_policy.scales(outcome.trusted.values(), model, state.q, state.qd, u=state.u)
    for quantity in tolerance_policy.quantities(model):
        values = {name: split.quantity(quantity) for name, split in outcome.voters(quantity).items()}
        values.update(dict.fromkeys(unsupported, UNSUPPORTED))
        if quantity in tolerance_policy.EXACT:
            values["exact"] = tolerance_policy.EXACT[quantity]
        outcome.comparisons[quantity] = compare(quantity, values, tolerance_policy.tolerance(quantity, at))


def add_checks(model: Model, outcome: StateOutcome, backends: Sequence[Formalism],
               case_charts: Sequence[chart_catalog.Chart], scene: tuple[frames.Frame, Model] | None,
               do_conservation: bool, there: StateOutcome | None = None) -> None:
    """Add the chart checks, the frame checks against the moved ``scene`` (frame, moved model) and the conservation
    checks at ``outcome``'s state to it; a backend raising in a chart or in the moved scene is an error there. The
    trusted splits' scales are computed once (``outcome.scales``, else here) and shared by every check. ``there``:
    the backends' outcome in the moved scene when the caller has run them (:func:`run_block`), else they run here."""
    state, trusted = outcome.state, outcome.trusted
    supported = [b for b in backends if b.name in outcome.splits or b.name in outcome.errors]  # not ModelNotSupported
    if trusted and outcome.scales is None:
        outcome.scales = tolerance_policy.scales(trusted.values(), model, state.q, state.qd, u=state.u)
    for chart in case_charts:
        outcome.checks.update(invariance.chart_checks(model, state, chart, trusted, supported, outcome.errors,
                                                      outcome.scales))
    if scene is not None:
        frame, moved = scene
        there = run_backends(moved, state, backends) if there is None else there
        outcome.errors.update({f"{name}@{frame.name}": message for name, message in there.errors.items()})
        outcome.checks.update(invariance.frame_checks(model, frame, state, trusted, there.trusted, outcome.scales,
                                                      moved))
    if do_conservation and trusted:
        outcome.checks.update(conservation.checks(model, state, trusted, outcome.scales))


def add_linearization_checks(model: Model, outcome: StateOutcome, backends: Sequence[Formalism]) -> None:
    """Add the comparisons of the backends' linearizations (``crosscheck.linearization``) at ``outcome``'s state, the
    backends that raised in ``linearize`` joining its errors; nothing when no split is trusted (no scales)."""
    if outcome.scales is None:
        return
    supported = [b for b in backends if b.name in outcome.splits or b.name in outcome.errors]
    found, errors = linearization.checks(model, outcome.state, supported, outcome.scales)
    outcome.checks.update(found)
    outcome.errors.update({f"{name} (linearize)": message for name, message in errors.items()})


@dataclass(frozen=True)
class CaseSetup:
    """One case as the gate checks it (seeded): the model, its charts, its moved scenes (frame, moved model) and
    whether the conservation checks run."""

    spec: CaseSpec
    model: Model
    charts: tuple[chart_catalog.Chart, ...]
    scenes: tuple[tuple[frames.Frame, Model], ...]
    conservation: bool
    voters: tuple[Formalism, ...] = ()
    linearization: bool = False

    @classmethod
    def build(cls, spec: CaseSpec, seed: int, checks: Checks = Checks()) -> "CaseSetup":
        model = spec.build()
        case_charts = chart_catalog.sampled(model, seed, spec.name) if checks.charts else []
        case_frames = frames.sampled(seed, spec.name, checks.frames) if checks.frames > 0 else []
        scenes = tuple((frame, frames.move_scene(model, frame)) for frame in case_frames)
        closed = spec.closed_form() if checks.closed_forms else None
        return cls(spec, model, tuple(case_charts), scenes, checks.conservation, (closed,) if closed else (),
                   checks.linearization)

    def scene(self, state: State) -> tuple[frames.Frame, Model] | None:
        """The moved scene state ``i`` is checked in: frame ``i mod frames``."""
        return self.scenes[state.index % len(self.scenes)] if self.scenes else None

    def evaluate(self, state: State, backends: Sequence[Formalism], clock: Clock | None = None) -> StateOutcome:
        """Everything the gate does at one state: the comparisons (:func:`evaluate`) among ``backends`` and the case's
        own voters (its closed form), and the checks (:func:`add_checks`)."""
        (outcome,) = self.evaluate_block([state], backends, clock)
        return outcome

    def evaluate_block(self, states: Sequence[State], backends: Sequence[Formalism],
                       clock: Clock | None = None) -> Iterator[StateOutcome]:
        """:meth:`evaluate` at each of ``states``, yielded as each is done: the backends run over the block at once in
        the joint chart and in each moved scene (the states checked there, :func:`run_block`), then state by state
        come the comparisons and the checks."""
        backends, own = [*backends, *self.voters], backends
        outcomes = run_block(self.model, states, backends, clock)
        moved = self._moved(states, backends)
        for outcome, there in zip(outcomes, moved):
            judge(self.model, outcome, backends)
            add_checks(self.model, outcome, backends, self.charts, self.scene(outcome.state), self.conservation, there)
            if self.linearization and outcome.state.index < linearization.STATES:
                add_linearization_checks(self.model, outcome, own)
            if self.linearization and outcome.state.index == 0:
                self._equilibria(outcome, own)
            yield outcome

    def _equilibria(self, outcome: StateOutcome, backends: Sequence[Formalism]) -> None:
        """Add the checks of the case's equilibria with closed-form eigenvalues (``crosscheck.equilibria``) to the
        outcome of its first state (a built-in case only: a model file has no closed form)."""
        if self.spec.path is not None:
            return
        params = equilibria.case_params(self.spec.name, {k: float(v) for k, v in self.spec.params})
        for equilibrium in equilibria.of_case(self.spec.name, params):
            found, errors = equilibria.checks(equilibrium, params, self.model, backends, self.charts)
            outcome.checks.update(found)
            outcome.errors.update(errors)

    def _moved(self, states: Sequence[State], backends: Sequence[Formalism]) -> list[StateOutcome | None]:
        """The backends' outcome at each of ``states`` in the moved scene it is checked in (:meth:`scene`), each
        scene's states as one block; None for every state when the case has no moved scenes."""
        out: list[StateOutcome | None] = [None] * len(states)
        for k, (_, moved) in enumerate(self.scenes):
            at = [j for j, state in enumerate(states) if state.index % len(self.scenes) == k]
            for j, there in zip(at, run_block(moved, [states[j] for j in at], backends)):
                out[j] = there
        return out


def run_case(spec: CaseSpec, backends: Sequence[Formalism], samples: int, seed: int,
             progress: Callable[[Step], None] | None = None, checks: Checks = Checks()) -> CaseOutcome:
    """The case's ``samples`` seeded states, each evaluated (:meth:`CaseSetup.evaluate`); ``progress`` is told
    every :class:`Step`. Ctrl-C raises :class:`_CaseInterrupted` with the states evaluated until then."""
    tell = progress or _ignore
    tell(Step(spec.name, 0, samples, SETTING_UP))
    setup = CaseSetup.build(spec, seed, checks)
    announce_preparation(setup, backends)
    states = sample_states(setup.model, samples, seed, spec.name, limits=checks.joint_limits)
    outcomes: list[StateOutcome] = []

    def at(phase: str) -> None:
        tell(Step(spec.name, len(outcomes), len(states), phase))

    clock = Clock(preparing=lambda name: at(EVALUATING if name is None else f"preparing {name}"))
    try:
        at(EVALUATING)
        for block in _blocks(states):
            for outcome in setup.evaluate_block(block, backends, clock):
                outcomes.append(outcome)
                if len(outcomes) < len(states):
                    at(EVALUATING)
    except KeyboardInterrupt:
        raise _CaseInterrupted(_case_outcome(setup, outcomes, clock, None, checks)) from None
    at(DONE)
    return _case_outcome(setup, outcomes, clock, coverage_of.measure(setup.model, states), checks)


#: CPU seconds of one-off preparation of one backend on one case above which the gate says so before it starts.
PREPARATION_NOTICE_S = 20.0


class PreparationNotice(UserWarning):
    """A backend's one-off preparation of a case (a symbolic derivation, a compilation) will take long: shown before it
    starts, with the estimate and the ways around it."""


def preparation_seconds(setup: CaseSetup, backend: Formalism) -> float:
    """The backend's estimated preparation of the case (``Formalism.preparation``): the joint chart, each sampled chart
    and each moved scene (a moved model is another model to prepare); 0 for a backend without an estimate."""
    if backend.preparation is None:
        return 0.0
    model = setup.model
    try:
        return (backend.preparation(model, None) + sum(backend.preparation(model, c) for c in setup.charts)
                + sum(backend.preparation(moved, None) for _, moved in setup.scenes))
    except ModelNotSupported:
        return 0.0


def announce_preparation(setup: CaseSetup, backends: Sequence[Formalism]) -> None:
    """Warn (:class:`PreparationNotice`) before a case whose preparation by some backend is estimated above
    :data:`PREPARATION_NOTICE_S`, saying how long, that it is done once (cached on disk) and how to skip it."""
    for backend in backends:
        seconds = preparation_seconds(setup, backend)
        if seconds > PREPARATION_NOTICE_S:
            warnings.warn(PreparationNotice(
                f"{backend.name}: preparing case '{setup.spec.name}' ({setup.model.n} coordinates) in the joint chart, "
                f"{len(setup.charts)} chart(s) and {len(setup.scenes)} moved scene(s) takes about {seconds:.0f} s of "
                "CPU before its first answers (once: then cached on disk); --no-charts and --frames 0 leave out "
                "the charts and the moved scenes, --formalism (naming the others) leaves it out"), stacklevel=2)


def _case_outcome(setup: CaseSetup, outcomes: list[StateOutcome], clock: Clock,
                  coverage: coverage_of.Coverage | None, checks: Checks) -> CaseOutcome:
    """The case's outcome from its evaluated states (coverage None: not measured, for an interrupted case)."""
    return CaseOutcome(setup.spec, setup.model, outcomes, clock.first(), clock.per_state(),
                       tuple(c.name for c in setup.charts), tuple(frame for frame, _ in setup.scenes), coverage,
                       _closed_form_coverage(setup.spec, checks))


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
    from crosscheck import closed_forms

    given = " (not the task quantities: --task-point given)" if spec.task_point is not None else ""
    return closed_forms.coverage(spec.name, dict(spec.params)) + given


def run_gate(specs: Sequence[CaseSpec], backends: Sequence[Formalism], samples: int, seed: int,
             progress: Callable[[Step], None] | None = None, checks: Checks = Checks(),
             workers: int = 0, required: Sequence[str] = ()) -> GateResult:
    """Run the gate over the cases; the result passes when no state shows a disagreement or an error, no case's
    sample is degenerate (``crosscheck.coverage``), every ``required`` backend took part in some comparison and the
    self-test canaries are caught (``crosscheck.selftest``, unless ``checks.self_test`` is off).

    ``workers`` 0 runs the cases in this process; N >= 1 in N spawned processes (:func:`_in_pool`), at most one per
    case (``crosscheck.cli.workers``: the one meaning of ``--workers``); the outcomes are the same as in this
    process and come back in case order, so the report is too (its timings apart). Backends that cannot be sent to
    another process (not picklable: a lambda, a local function) keep the run in this process. ``progress`` is told every :class:`Step` of a case run here, and only the start and the end
    of a case run in a worker process. Ctrl-C raises :class:`Interrupted` with the partial result."""
    tell = progress or _ignore
    count = min(workers, len(specs))
    pooled = count >= 1 and _picklable(backends)
    outcomes: list[CaseOutcome] = []
    result = GateResult(seed, samples, tuple(b.name for b in backends), outcomes, checks, tuple(required))
    try:
        if pooled:
            _in_pool(specs, backends, samples, seed, tell, checks, count, outcomes)
        else:
            for spec in specs:
                outcomes.append(run_case(spec, backends, samples, seed, tell, checks))
        if checks.self_test:
            from crosscheck import selftest

            tell(Step("", 0, 0, SELF_TEST))
            result.self_test = selftest.run()
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


def _picklable(backends: Sequence[Formalism]) -> bool:
    try:
        pickle.dumps(list(backends))
    except Exception:  # any object a user registers: pickling may fail in many ways
        return False
    return True


_BACKENDS: list[Formalism] = []
_LIMITS = None


def _init_worker(chosen: list[Formalism], plugins: Sequence[str]) -> None:
    """A worker process: Ctrl-C ignored (the parent stops the pool), one BLAS thread, the parent's plugins, the
    backends of the run."""
    global _LIMITS
    from threadpoolctl import threadpool_limits

    signal.signal(signal.SIGINT, signal.SIG_IGN)
    _LIMITS = threadpool_limits(limits=1, user_api="blas")
    load_plugins(plugins)
    _BACKENDS[:] = chosen


def _worker_case(spec: CaseSpec, samples: int, seed: int, checks: Checks) -> CaseOutcome:
    return run_case(spec, _BACKENDS, samples, seed, None, checks)


def _in_pool(specs: Sequence[CaseSpec], backends: Sequence[Formalism], samples: int, seed: int,
             tell: Callable[[Step], None], checks: Checks, workers: int, outcomes: list[CaseOutcome]) -> None:
    """The cases in ``workers`` spawned processes, the largest models (most coordinates) first so that no worker
    is left with a large case at the end; their outcomes added to ``outcomes`` in case order. On Ctrl-C the
    outcomes already in, in case order, are kept there, and the workers are stopped."""
    import multiprocessing

    ctx = multiprocessing.get_context("spawn")
    order = sorted(range(len(specs)), key=lambda k: -specs[k].build().n)
    with worker_processes.spawning(), ctx.Pool(workers, initializer=_init_worker,
                                               initargs=(list(backends), plugin_specs())) as pool:
        pending = {k: pool.apply_async(_worker_case, (specs[k], samples, seed, checks)) for k in order}
        try:
            for k, spec in enumerate(specs):
                tell(Step(spec.name, 0, samples, IN_WORKER))
                outcomes.append(pending[k].get())
                tell(Step(spec.name, samples, samples, DONE))
        except KeyboardInterrupt:
            outcomes[:] = [pending[k].get() for k in range(len(specs))
                           if pending[k].ready() and pending[k].successful()]
            raise
