"""Signals during a campaign (``crosscheck.campaigns.fuzz``, "Interruptions and crashes"): SIGINT and SIGTERM are an
orderly stop, noted and acted on at the next example or chunk, never breaking a save or a log append; a worker
watches its parent and the stop flag."""

from __future__ import annotations

import contextlib
import os
import signal
import sys
import threading
import time
from dataclasses import dataclass
from typing import Iterator

from crosscheck.campaigns.fuzz.settings import POLL


# ------------------------------------------------------------------------------------------------ interrupts


@dataclass
class _Interrupts:
    """How this process takes SIGINT and SIGTERM (module doc): ``requested`` once one came; ``phase`` is ``"idle"``
    (no chunk running here), ``"chunk"`` (a chunk setting up or saving) or ``"test"`` (its Hypothesis run);
    ``worker`` in a pool worker process, ``stop`` there the campaign's stop flag (:func:`watch`)."""

    requested: bool = False
    phase: str = "idle"
    worker: bool = False
    stop: object = None

    def on_signal(self, signum: int, frame) -> None:
        """The first signal during a chunk's Hypothesis run raises KeyboardInterrupt there (the chunk saves the
        failure in hand); any other only sets ``requested``, which the property and the loops poll. In a worker's
        chunk, SIGTERM once an interrupt is under way or once the campaign's ``stop`` flag is set ends the process:
        that is how the pool stops its workers, and a worker must not outlive it."""
        first, self.requested = not self.requested, True
        if self.worker and signum == signal.SIGTERM and (not first or self.stop.value):
            raise SystemExit(128 + signum)
        if self.phase == "test" and first:
            raise KeyboardInterrupt

    def poll(self) -> None:
        """Called at each example: an interrupt noted outside the Hypothesis run stops the chunk now."""
        if self.requested:
            raise KeyboardInterrupt

    @contextlib.contextmanager
    def during(self, phase: str) -> Iterator[None]:
        """In ``phase``. The KeyboardInterrupt :meth:`on_signal` raises can land in code that cannot raise (a garbage
        collector callback of Hypothesis's), which Python reports as "Exception ignored" with a traceback: that
        report is dropped here, since the interrupt is noted (``requested``) and the next example stops the chunk."""
        before, self.phase = self.phase, phase
        hook = sys.unraisablehook

        def quiet(unraisable) -> None:
            if not (self.requested and issubclass(unraisable.exc_type, KeyboardInterrupt)):
                hook(unraisable)

        sys.unraisablehook = quiet
        try:
            yield
        finally:
            self.phase = before
            sys.unraisablehook = hook

    @contextlib.contextmanager
    def chunk(self) -> Iterator[None]:
        """A chunk runs here. A worker takes SIGTERM by :meth:`on_signal` only meanwhile; idle, the default action
        ends it at once. (A Python handler runs in the main thread, and a signal the kernel hands to another thread
        does not wake the main thread from a blocking wait: an idle worker waiting for a task would outlive the
        pool's SIGTERM.)"""
        if self.worker:
            signal.signal(signal.SIGTERM, self.on_signal)
        try:
            with self.during("chunk"):
                yield
        finally:
            if self.worker:
                signal.signal(signal.SIGTERM, signal.SIG_DFL)


INTERRUPTS = _Interrupts()
_SIGNALS = (signal.SIGINT, signal.SIGTERM)


@contextlib.contextmanager
def signals_handled() -> Iterator[None]:
    """SIGINT and SIGTERM taken by :data:`INTERRUPTS` while in the block (in the main thread; elsewhere Python
    cannot set handlers), the previous handlers restored after."""
    INTERRUPTS.requested = False
    if threading.current_thread() is not threading.main_thread():
        yield
        return
    previous = {signum: signal.signal(signum, INTERRUPTS.on_signal) for signum in _SIGNALS}
    try:
        yield
    finally:
        for signum, handler in previous.items():
            signal.signal(signum, handler)
        INTERRUPTS.requested = False


def watch(stop, parent: int, main_thread: int) -> None:
    """A worker's watcher thread: the campaign's stop flag interrupts the worker's main thread (as SIGINT would);
    the death of the parent ends the worker at once (a SIGKILLed campaign leaves no worker writing into its
    directory; the chunk runs again on resume). The flag is a lock-free shared byte: a worker killed while it held a
    lock (a multiprocessing Event's) would block every other process that takes it."""
    while not stop.value:
        if os.getppid() != parent:
            os._exit(1)
        time.sleep(POLL)
    signal.pthread_kill(main_thread, signal.SIGINT)
    while os.getppid() == parent:
        time.sleep(POLL)
    os._exit(1)
