"""The harness's own failures (docs/design.md, "Internal errors"): an exception raised by the harness's code in one of
the gate's checks, recorded as an internal error of that check, so that the run goes on, the report is written and
the gate fails (exit 3), instead of a traceback ending the run.

An internal error is not a backend error: a backend raising in ``split``, ``split_chart`` or ``linearize`` is caught
where the backend is called (``crosscheck.engine.evaluation``, ``crosscheck.checks.invariance.chart_checks``,
``crosscheck.checks.linearization``) and reported as that backend's error. What reaches a guard here is the harness's
own code failing: a tolerance, a chart map, a frame move, a comparison, the coverage measure, a case's setup.

Each guarded place records under the name of its check: at a state ``comparisons``,
``conditions audit``, ``chart zyx``, ``frame g1``, ``conservation``, ``linearization``, ``equilibria``, ``breakdown
conditions``; for a case ``file reading``, ``case setup``, ``sampling``, ``coverage`` or ``case`` (anything else in running it); for the
run ``self-test`` and the report's own sections (``report: <section>``). Only ``Exception`` is caught: Ctrl-C
(KeyboardInterrupt) and SystemExit still end the run.
"""

from __future__ import annotations

import contextlib
import re
import traceback
from dataclasses import dataclass
from pathlib import Path
from typing import Iterator

import crosscheck

#: The project's root: frames under it (not in a virtual environment or site-packages) are "our code".
ROOT = Path(crosscheck.__file__).resolve().parent.parent
#: The longest message kept (one line); the rest is cut with an ellipsis.
MAX_MESSAGE = 300
#: Frames of the project kept in ``InternalError.trace``, innermost last.
MAX_FRAMES = 8


@dataclass(frozen=True)
class InternalError:
    """One exception the harness raised: ``error`` (``TypeError: message``, on one line), ``where`` (the last frame of
    the traceback in the project's code: ``crosscheck/checks/charts.py:123 in acceleration_to_chart``) and ``trace``
    (the project's frames, innermost last)."""

    error: str
    where: str
    trace: tuple[str, ...] = ()

    def __str__(self) -> str:
        return f"{self.error} ({self.where})"

    @property
    def kind(self) -> str:
        """The exception's type name (``TypeError``)."""
        return self.error.split(":", 1)[0]


def _ours(filename: str) -> str | None:
    """``filename`` relative to the project root when it is the project's own code, else None."""
    try:
        path = Path(filename).resolve()
        relative = path.relative_to(ROOT)
    except (ValueError, OSError):
        return None
    parts = relative.parts
    if not parts or any(p in ("site-packages", "dist-packages") or p.startswith(".") for p in parts):
        return None
    return relative.as_posix()


#: This module (its guard's frame is no place the harness failed).
_HERE = Path(__file__).resolve().relative_to(ROOT).as_posix()

#: A frame of a formatted traceback (a worker process's, sent back as text: ``multiprocessing.pool.RemoteTraceback``).
_FRAME = re.compile(r'File "(?P<file>[^"]+)", line (?P<line>\d+), in (?P<name>\S+)')


def _frames(exc: BaseException) -> list[tuple[str, int, str]]:
    """(file, line, function) of every frame of ``exc``'s traceback, outermost first; for an exception raised in a
    worker process, the worker's frames (its formatted traceback is the exception's cause)."""
    cause = exc.__cause__
    if cause is not None and type(cause).__name__ == "RemoteTraceback":
        return [(m["file"], int(m["line"]), m["name"]) for m in _FRAME.finditer(str(cause))]
    return [(f.filename, f.lineno or 0, f.name) for f in traceback.extract_tb(exc.__traceback__)]


def message(exc: BaseException) -> str:
    """``Type: message`` on one line, at most :data:`MAX_MESSAGE` characters."""
    text = " ".join(f"{type(exc).__name__}: {exc}".split())
    return text if len(text) <= MAX_MESSAGE else text[:MAX_MESSAGE - 3] + "..."


def of(exc: BaseException) -> InternalError:
    """The internal error ``exc`` is: its message, the last frame in the project's code, and the project's frames."""
    ours = [f"{path}:{line} in {name}" for file, line, name in _frames(exc)
            if (path := _ours(file)) is not None and path != _HERE]
    if ours:      # an exception that says its caller is to blame (a NaN tolerance given to compare) names the caller
        where = ours[-2] if getattr(exc, "caller_to_blame", False) and len(ours) > 1 else ours[-1]
    else:
        frames = _frames(exc)
        where = f"{Path(frames[-1][0]).name}:{frames[-1][1]} in {frames[-1][2]}" if frames else "unknown"
    return InternalError(message(exc), where, tuple(ours[-MAX_FRAMES:]))


@contextlib.contextmanager
def guarded(found: dict[str, InternalError] | None, check: str,
            passing: tuple[type[BaseException], ...] = ()) -> Iterator[None]:
    """Run the block; an ``Exception`` it raises is recorded in ``found`` under ``check`` (the first one kept) and the
    block is left; one of ``passing`` (bad input) propagates. ``found`` None: nothing is caught (the caller is not the
    gate: the exception propagates)."""
    if found is None:
        yield
        return
    try:
        yield
    except passing:
        raise
    except Exception as exc:  # noqa: BLE001 - the harness's own failure: recorded and reported, the run goes on
        found.setdefault(check, of(exc))


@dataclass(frozen=True)
class Occurrence:
    """An internal error as the report lists it: once per case, check, place and exception type, with the first state
    it happened at and the number of states (``first`` None and ``states`` 0 for a case's or the run's own)."""

    check: str
    error: InternalError
    case: str | None = None
    first: int | None = None
    states: int = 0

    def describe(self) -> str:
        """One line: ``internal error in chart zyx (double_pendulum: 3 states, first #0): TypeError: ... (where)``."""
        scope = ", ".join(([self.case] if self.case else [])
                          + ([f"{self.states} state{'s' if self.states != 1 else ''}, first #{self.first}"]
                             if self.states else []))
        return f"internal error in {self.check}" + (f" ({scope})" if scope else "") + f": {self.error}"


def occurrences(result) -> list[Occurrence]:
    """Every internal error of a gate run (``GateResult``), grouped (:class:`Occurrence`): the cases' in case order
    (the case's own first, then its states'), then the run's."""
    out: list[Occurrence] = []
    for case in result.cases:
        out += [Occurrence(check, error, case.spec.name) for check, error in case.internal.items()]
        grouped: dict[tuple[str, str, str], list] = {}
        for state in case.states:
            for check, error in state.internal.items():
                grouped.setdefault((check, error.where, error.kind), []).append((state.state.index, error))
        out += [Occurrence(check, found[0][1], case.spec.name, found[0][0], len({i for i, _ in found}))
                for (check, _, _), found in grouped.items()]
    out += [Occurrence(check, error) for check, error in result.internal.items()]
    return out
