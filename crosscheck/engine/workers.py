"""Worker processes and Ctrl-C: a pool's workers never print a KeyboardInterrupt traceback.

Ctrl-C at a terminal sends SIGINT to the whole process group, so to the workers of a gate or fuzz pool as well as to
the command. The command stops its pool itself (the gate ends its workers; a fuzzing campaign tells them to save
what they hold), so a worker must not die of the signal on its own: a spawned worker still importing the harness
would print a traceback. :func:`spawning` marks the workers a pool starts, also those it starts later in place of
others, and ``crosscheck/__init__.py`` makes a marked process ignore SIGINT from its first import of the harness on;
the worker's initializer then sets what it takes (the gate's ignores it, the campaign's handles it).

Warnings a worker raises (a loader's ``BaseNotice``, the gate's ``PreparationNotice``) are shown as the command shows
them in its own process, one line each (``crosscheck.cli``): :func:`warning_display` hands the worker this process's
way of showing them and :func:`show_warnings_with` installs it there.
"""

from __future__ import annotations

import contextlib
import os
import pickle
import warnings
from typing import Callable, Iterator

from crosscheck import WORKER


@contextlib.contextmanager
def spawning() -> Iterator[None]:
    """Around the life of a pool of spawned workers: the workers this process starts meanwhile are marked."""
    before = os.environ.get(WORKER)
    os.environ[WORKER] = str(os.getpid())
    try:
        yield
    finally:
        if before is None:
            os.environ.pop(WORKER, None)
        else:
            os.environ[WORKER] = before


def warning_display() -> Callable | None:
    """This process's way of showing warnings (``warnings.showwarning``: during a command, the command line's one line
    per notice) when a spawned worker can be given it (a module-level function, sent by its name), else None."""
    show = warnings.showwarning
    try:
        pickle.dumps(show)
    except Exception:  # a local function or a bound method of some object: the worker keeps Python's own display
        return None
    return show


def show_warnings_with(show: Callable | None) -> None:
    """In a worker: show warnings with ``show`` (:func:`warning_display` of the parent); Python's display if None."""
    if show is not None:
        warnings.showwarning = show
