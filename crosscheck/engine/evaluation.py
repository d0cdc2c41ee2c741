"""Evaluating states: every backend's split over a block of states, the comparisons of each quantity (judging) and
the checks (charts, moved scenes, conservation, linearizations, equilibria) of one case's setup (:class:`CaseSetup`).

Each backend runs once per state and scene (joint chart, each chart, the moved scene); the tolerance scales of the
trusted joint-chart splits are computed once per state and shared by every check. A case's states are evaluated in
blocks (:meth:`CaseSetup.evaluate_block`): a backend with a block form (``formalisms.interface.with_block_form``)
splits a block's states in one call in the joint chart and in each moved scene, with the very numbers of its
state-by-state ``split``, so the outcomes are those of one state at a time."""

from __future__ import annotations

from dataclasses import dataclass
from typing import Iterator, Sequence

import numpy as np

from cases.model import Model
from crosscheck.checks import charts as chart_catalog, conservation, equilibria, frames, invariance, linearization
from crosscheck.core import tolerance
from crosscheck.core.compare import compare
from crosscheck.core.sampling import State
from crosscheck.engine.outcomes import StateOutcome
from crosscheck.engine.phases import Clock
from crosscheck.engine.specs import CaseSpec, Checks
from crosscheck.guards import conditioning
from formalisms.interface import UNSUPPORTED, block_form, Formalism, ModelNotSupported, Split


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
    breakdowns = {name: b for name, split in splits.items() if (b := tolerance.breakdown(split))}
    return StateOutcome(state, splits, errors, {}, breakdowns)


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
    at = outcome.scales = tolerance.scales(outcome.trusted.values(), model, state.q, state.qd, u=state.u)
    for quantity in tolerance.quantities(model):
        values = {name: split.quantity(quantity) for name, split in outcome.voters(quantity).items()}
        values.update(dict.fromkeys(unsupported, UNSUPPORTED))
        if quantity in tolerance.EXACT:
            values["exact"] = tolerance.EXACT[quantity]
        outcome.comparisons[quantity] = compare(quantity, values, tolerance.tolerance(quantity, at))


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
        outcome.scales = tolerance.scales(trusted.values(), model, state.q, state.qd, u=state.u)
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
    """Add the comparisons of the backends' linearizations (``crosscheck.checks.linearization``) at ``outcome``'s state,
    the backends that raised in ``linearize`` joining its errors; nothing when no split is trusted (no scales)."""
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
        """Add the checks of the case's equilibria with closed-form eigenvalues (``crosscheck.checks.equilibria``) to
        the outcome of its first state (a built-in case only: a model file has no closed form)."""
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
