"""Evaluating states: every backend's split over a block of states, the comparisons of each quantity (judging) and
the checks (charts, moved scenes, conservation, linearizations, equilibria) of one case's setup (:class:`CaseSetup`).

Each backend runs once per state and scene (joint chart, each chart, the moved scene); the tolerance scales of the
trusted joint-chart splits are computed once per state and shared by every check. A case's states are evaluated in
blocks (:meth:`CaseSetup.evaluate_block`): a backend with a block form (``formalisms.interface.with_block_form``)
splits a block's states in one call in the joint chart and in each moved scene, with the very numbers of its
state-by-state ``split``, so the outcomes are those of one state at a time.

The gate evaluates with ``guard=True``: an exception the harness's own code raises in a check (a tolerance, a chart
map, a frame move) is recorded as an internal error of that check in ``outcome.internal``
(``crosscheck.engine.internal``), and the other checks and states go on; a backend raising is its error, as always.
Without ``guard`` (``crosscheck eval``, the fuzzer, the self-test's own calls) such an exception propagates."""

from __future__ import annotations

from dataclasses import dataclass
from typing import Iterator, Sequence

import numpy as np

from cases.model import Model
from crosscheck.checks import charts as chart_catalog, conservation, equilibria, frames, invariance, linearization
from crosscheck.core import tolerance
from crosscheck.core.compare import compare
from crosscheck.core.sampling import State
from crosscheck.engine.internal import guarded
from crosscheck.engine.outcomes import StateOutcome
from crosscheck.engine.phases import Clock
from crosscheck.engine.specs import CaseSpec, Checks
from crosscheck.guards import conditioning
from formalisms.interface import UNSUPPORTED, block_form, Formalism, ModelNotSupported, Split


def run_backends(model: Model, state: State, backends: Sequence[Formalism], clock: Clock | None = None,
                 guard: bool = False) -> StateOutcome:
    """Every backend's split at ``state``, the errors they raised and the backends in BREAKDOWN, without the
    comparisons (what a moved scene needs: :func:`add_checks`). A backend raising ``ModelNotSupported`` is in
    neither ``splits`` nor ``errors``. ``guard``: the harness's own failure is an internal error (module doc)."""
    return run_block(model, [state], backends, clock, guard)[0]


def run_block(model: Model, states: Sequence[State], backends: Sequence[Formalism], clock: Clock | None = None,
              guard: bool = False) -> list[StateOutcome]:
    """:func:`run_backends` at each of ``states``, every backend over the block at once (:func:`_split_states`);
    ``clock`` receives each state's share of a backend's time on the block."""
    clock = clock or Clock()
    found = {backend.name: clock.timed(backend.name, lambda: _split_states(backend, model, states), len(states))
             for backend in backends}
    return [outcome_of(state, {name: splits[k] for name, splits in found.items()}, guard)
            for k, state in enumerate(states)]


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


def outcome_of(state: State, found: dict[str, tuple[Split | None, str | None]], guard: bool = False
               ) -> StateOutcome:
    """The outcome at ``state`` of the backends' splits and errors (:func:`_split_one`, by backend), without the
    comparisons; the backends in BREAKDOWN found from their splits (``guard``: the harness failing to find them is
    the internal error ``breakdown conditions``, and no backend is in BREAKDOWN)."""
    splits = {name: split for name, (split, _) in found.items() if split is not None}
    errors = {name: error for name, (_, error) in found.items() if error is not None}
    internal: dict = {}
    breakdowns: dict[str, dict[str, float]] = {}
    with guarded(internal if guard else None, "breakdown conditions"):
        breakdowns = {name: b for name, split in splits.items() if (b := tolerance.breakdown(split))}
    return StateOutcome(state, splits, errors, {}, breakdowns, internal=internal)


def evaluate(model: Model, state: State, backends: Sequence[Formalism], clock: Clock | None = None) -> StateOutcome:
    """Every backend's split at ``state`` and the comparison of each quantity in the tolerance table.

    A backend whose method is ill-conditioned here (``tolerance.breakdown``) is reported as BREAKDOWN and left
    out of the comparisons (all, or the quantities the condition concerns) and of the tolerance scales: its answer
    is not trusted there, and it is not a bug. That is a claim, and it is audited (``crosscheck.guards.conditioning``):
    the ``conditions: <name>`` checks compare every reported condition with the harness's own, and a BREAKDOWN where
    the problem is well-conditioned is dropped, so that backend votes. A backend that raises ``ModelNotSupported``
    (written for other mechanisms) is NOT COMPARED: it joins every comparison as UNSUPPORTED, so the report lists it
    as not supplied. The tolerance scales of the trusted splits are kept in ``outcome.scales`` for the checks
    (:func:`add_checks`).
    """
    outcome = run_backends(model, state, backends, clock)
    judge(model, outcome, backends)
    return outcome


def judge(model: Model, outcome: StateOutcome, backends: Sequence[Formalism], guard: bool = False) -> None:
    """What :func:`evaluate` does once the ``backends`` have run at ``outcome``'s state: the conditioning audit and
    the comparisons, the backends that declined the model joining them as UNSUPPORTED. ``guard``: the harness failing
    in either is the internal error ``conditions audit`` or ``comparisons`` (module doc)."""
    found = outcome.internal if guard else None
    with guarded(found, "conditions audit"):
        outcome.checks.update(conditioning.audit(model, outcome.state, outcome.splits, outcome.breakdowns))
    with guarded(found, "comparisons"):
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
    at = outcome.scales = tolerance.scales(outcome.trusted.values(), model, state.q, state.qd, u=state.u)
    for quantity in tolerance.quantities(model):
        values = {name: split.quantity(quantity) for name, split in outcome.voters(quantity).items()}
        values.update(dict.fromkeys(unsupported, UNSUPPORTED))
        if quantity in tolerance.EXACT:
            values["exact"] = tolerance.EXACT[quantity]
        outcome.comparisons[quantity] = compare(quantity, values, tolerance.tolerance(quantity, at))


def add_checks(model: Model, outcome: StateOutcome, backends: Sequence[Formalism],
               case_charts: Sequence[chart_catalog.Chart], scene: tuple[frames.Frame, Model] | None,
               do_conservation: bool, there: StateOutcome | None = None, guard: bool = False) -> None:
    """Add the chart checks, the frame checks against the moved ``scene`` (frame, moved model) and the conservation
    checks at ``outcome``'s state to it; a backend raising in a chart or in the moved scene is an error there. The
    trusted splits' scales are computed once (``outcome.scales``, else here) and shared by every check. ``there``:
    the backends' outcome in the moved scene when the caller has run them (:func:`run_block`), else they run here.
    ``guard``: the harness failing in a check is an internal error of that check (``chart zyx``, ``frame g1``,
    ``conservation``; module doc), and the other checks go on."""
    state = outcome.state
    found = outcome.internal if guard else None
    supported = [b for b in backends if b.name in outcome.splits or b.name in outcome.errors]  # not ModelNotSupported

    def scales() -> tolerance.Scales | None:
        """The trusted splits' scales, computed on first use (inside the check that uses them first)."""
        if outcome.scales is None and outcome.trusted:
            outcome.scales = tolerance.scales(outcome.trusted.values(), model, state.q, state.qd, u=state.u)
        return outcome.scales

    for chart in case_charts:
        with guarded(found, f"chart {chart.name}"):
            outcome.checks.update(invariance.chart_checks(model, state, chart, outcome.trusted, supported,
                                                          outcome.errors, scales()))
    if scene is not None:
        frame, moved = scene
        with guarded(found, f"frame {frame.name}"):
            there = run_backends(moved, state, backends, guard=guard) if there is None else there
            outcome.errors.update({f"{name}@{frame.name}": message for name, message in there.errors.items()})
            for check, error in there.internal.items():      # the harness failing in the moved scene's outcome
                outcome.internal.setdefault(f"frame {frame.name}: {check}", error)
            outcome.checks.update(invariance.frame_checks(model, frame, state, outcome.trusted, there.trusted,
                                                          scales(), moved))
    with guarded(found, "conservation"):
        if do_conservation and outcome.trusted:
            outcome.checks.update(conservation.checks(model, state, outcome.trusted, scales()))


def add_linearization_checks(model: Model, outcome: StateOutcome, backends: Sequence[Formalism],
                             guard: bool = False) -> None:
    """Add the comparisons of the backends' linearizations (``crosscheck.checks.linearization``) at ``outcome``'s state,
    the backends that raised in ``linearize`` joining its errors; nothing when no split is trusted (no scales).
    ``guard``: the harness failing here is the internal error ``linearization`` (module doc)."""
    if outcome.scales is None:
        return
    supported = [b for b in backends if b.name in outcome.splits or b.name in outcome.errors]
    with guarded(outcome.internal if guard else None, "linearization"):
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
    def build(cls, spec: CaseSpec, seed: int, checks: Checks = Checks(), model: Model | None = None) -> "CaseSetup":
        """The case set up from ``spec`` (``model``: ``spec.build()`` when the caller has built it already)."""
        model = spec.build() if model is None else model
        case_charts = chart_catalog.sampled(model, seed, spec.name) if checks.charts else []
        case_frames = frames.sampled(seed, spec.name, checks.frames) if checks.frames > 0 else []
        scenes = tuple((frame, frames.move_scene(model, frame)) for frame in case_frames)
        closed = spec.closed_form() if checks.closed_forms else None
        return cls(spec, model, tuple(case_charts), scenes, checks.conservation, (closed,) if closed else (),
                   checks.linearization)

    def scene(self, state: State) -> tuple[frames.Frame, Model] | None:
        """The moved scene state ``i`` is checked in: frame ``i mod frames``."""
        return self.scenes[state.index % len(self.scenes)] if self.scenes else None

    def evaluate(self, state: State, backends: Sequence[Formalism], clock: Clock | None = None,
                 guard: bool = False) -> StateOutcome:
        """Everything the gate does at one state: the comparisons (:func:`evaluate`) among ``backends`` and the case's
        own voters (its closed form), and the checks (:func:`add_checks`); ``guard`` as in :meth:`evaluate_block`."""
        (outcome,) = self.evaluate_block([state], backends, clock, guard)
        return outcome

    def evaluate_block(self, states: Sequence[State], backends: Sequence[Formalism],
                       clock: Clock | None = None, guard: bool = False) -> Iterator[StateOutcome]:
        """:meth:`evaluate` at each of ``states``, yielded as each is done: the backends run over the block at once in
        the joint chart and in each moved scene (the states checked there, :func:`run_block`), then state by state
        come the comparisons and the checks. ``guard`` (the gate): the harness failing in a check is an internal error
        of that check at that state (module doc), and the other checks and states go on."""
        backends, own = [*backends, *self.voters], backends
        outcomes = run_block(self.model, states, backends, clock, guard)
        moved = self._moved(states, backends, guard)
        for outcome, there in zip(outcomes, moved):
            judge(self.model, outcome, backends, guard)
            add_checks(self.model, outcome, backends, self.charts, self.scene(outcome.state), self.conservation, there,
                       guard)
            if self.linearization and outcome.state.index < linearization.STATES:
                add_linearization_checks(self.model, outcome, own, guard)
            if self.linearization and outcome.state.index == 0:
                with guarded(outcome.internal if guard else None, "equilibria"):
                    self._equilibria(outcome, own)
            yield outcome

    def _equilibria(self, outcome: StateOutcome, backends: Sequence[Formalism]) -> None:
        """Add the checks of the case's equilibria with closed-form eigenvalues (``crosscheck.checks.equilibria``) to
        the outcome of its first state (a built-in case only: a model file has no closed form)."""
        if self.spec.path is not None:
            return
        params = equilibria.case_params(self.spec.name, {k: float(v) for k, v in self.spec.params})
        for equilibrium in equilibria.of_case(self.spec.name, params):
            found, errors = equilibria.checks(equilibrium, params, self.model, backends, self.charts)
            outcome.checks.update(found)
            outcome.errors.update(errors)

    def _moved(self, states: Sequence[State], backends: Sequence[Formalism], guard: bool = False
               ) -> list[StateOutcome | None]:
        """The backends' outcome at each of ``states`` in the moved scene it is checked in (:meth:`scene`), each
        scene's states as one block; None for every state when the case has no moved scenes."""
        out: list[StateOutcome | None] = [None] * len(states)
        for k, (_, moved) in enumerate(self.scenes):
            at = [j for j, state in enumerate(states) if state.index % len(self.scenes) == k]
            for j, there in zip(at, run_block(moved, [states[j] for j in at], backends, guard=guard)):
                out[j] = there
        return out
