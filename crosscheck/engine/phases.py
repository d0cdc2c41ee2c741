"""The progress protocol of a gate run: where it is (:class:`Step`, a case's states evaluated and what runs now) and
the seconds of each backend's calls (:class:`Clock`)."""

from __future__ import annotations

import time
from dataclasses import dataclass, field
from typing import Callable


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
