"""What a long command is doing, on stderr: the progress display of gate, fuzz, faults and bench.

On a terminal it is a live rich bar: the command, the count done of the total (states, examples, faults, steps)
with the elapsed time and an ETA, the command's own fields (fuzz: rate, worst ratio, findings) and what runs now
("panda: preparing euler_lagrange", "shrinking a failure"). Elsewhere (a CI log, a pipe) there is no bar and no line
per step: the notes, one line each (a case evaluated, a bench measurement), and a heartbeat line at least every
:data:`HEARTBEAT_S` seconds while the command runs (what runs now, the count done, the elapsed time and an ETA), from
a timer thread, so a long derivation that makes no progress calls still shows the run is alive. ``quiet`` shows
nothing at all.
"""

from __future__ import annotations

import sys
import threading
import time

from rich.console import Console
from rich.progress import (BarColumn, MofNCompleteColumn, Progress, TextColumn, TimeElapsedColumn,
                           TimeRemainingColumn)


#: The longest a command is silent without a terminal (module doc): a CI job that prints nothing for minutes looks hung.
HEARTBEAT_S = 10.0


def _clock(seconds: float) -> str:
    minutes, seconds = divmod(int(round(seconds)), 60)
    return f"{minutes}:{seconds:02d}"


class Display:
    """The progress display of one command (module doc). ``label`` names the command, ``unit`` what is counted
    (``total`` of them; None when not known: the bar then only shows the count); ``extra`` are rich column
    templates over the task's fields, whose first values are ``fields`` (fuzz: ``"worst {task.fields[worst]:.3g}"``
    with ``worst=0.0``). A context manager: the bar shows inside the ``with`` block."""

    def __init__(self, label: str, unit: str, total: int | None = None, *, quiet: bool = False,
                 console: Console | None = None, extra: tuple[str, ...] = (), **fields):
        self.console = console or Console(stderr=True)
        self.quiet = quiet
        live = not quiet and self.console.is_terminal
        self.progress = Progress(TextColumn("[bold]{task.description}"), BarColumn(), MofNCompleteColumn(),
                                 TextColumn("{task.fields[unit]}"), TimeElapsedColumn(), TextColumn("ETA"),
                                 TimeRemainingColumn(), *map(TextColumn, extra), TextColumn("{task.fields[doing]}"),
                                 console=self.console, disable=not live, redirect_stdout=live and _stdout_shared())
        self.task = self.progress.add_task(label, total=total, unit=unit, doing="", **fields)
        self.current = ""
        self.label = label
        self._started = time.monotonic()
        self._stopped = threading.Event()
        self._heartbeat = None if quiet or live else threading.Thread(target=self._beat, daemon=True,
                                                                      name="crosscheck-heartbeat")

    def __enter__(self) -> "Display":
        self.progress.__enter__()
        self._started = time.monotonic()
        if self._heartbeat is not None:
            self._heartbeat.start()
        return self

    def __exit__(self, kind, value, trace) -> None:
        self._stopped.set()
        if kind is None:   # finished: nothing runs now (interrupted, the bar keeps what ran)
            self.doing("")
        self.progress.__exit__(kind, value, trace)

    def _beat(self) -> None:
        """Every :data:`HEARTBEAT_S` seconds until the display closes: :meth:`heartbeat`'s line."""
        while not self._stopped.wait(HEARTBEAT_S):
            self.console.print(self.heartbeat(), markup=False, highlight=False, soft_wrap=True)

    def heartbeat(self) -> str:
        """One line of where the command is: ``crosscheck gate: 35/100 states, 0:12 elapsed, ETA 0:20; panda:
        preparing euler_lagrange`` (no ETA before the first count or without a total)."""
        task = self.progress.tasks[0]
        elapsed = time.monotonic() - self._started
        count = f"{task.completed:.0f}" + (f"/{task.total:.0f}" if task.total is not None else "")
        eta = (f", ETA {_clock(elapsed * (task.total - task.completed) / task.completed)}"
               if task.total is not None and task.completed else "")
        doing = f"; {self.current}" if self.current else ""
        return f"crosscheck {self.label}: {count} {task.fields['unit']}, {_clock(elapsed)} elapsed{eta}{doing}"

    def advance(self, count: int = 1, **fields) -> None:
        """``count`` more done; ``fields`` update the ``extra`` columns."""
        self.progress.update(self.task, advance=count, **fields)

    def update(self, **fields) -> None:
        """Set the task's fields (``completed``, ``total`` or those of the ``extra`` columns)."""
        self.progress.update(self.task, **fields)

    def doing(self, text: str) -> None:
        """What runs now (kept in ``current``, for an interruption's message), shown on the bar (nothing without
        one)."""
        self.current = text
        self.progress.update(self.task, doing=text)

    def stage(self, unit: str, total: int) -> None:
        """Start counting something else from 0 (faults: the sensitivity terms after the faults)."""
        fields = {**self.progress.tasks[0].fields, "unit": unit, "doing": ""}
        self.progress.reset(self.task, total=total, **fields)

    def note(self, line: str) -> None:
        """A line to keep: above the bar on a terminal, on stderr otherwise, nowhere when quiet."""
        if not self.quiet:
            self.console.print(line, markup=False, highlight=False, soft_wrap=True)


def silent() -> Display:
    """A display that shows nothing (the default of the functions that take one)."""
    return Display("", "", quiet=True)


def _stdout_shared() -> bool:
    """Whether stdout is a terminal too: its lines then go above the bar, which they would otherwise break; a
    redirected stdout keeps its lines."""
    return sys.stdout.isatty()
