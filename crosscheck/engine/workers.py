"""Worker processes and Ctrl-C: a pool's workers never print a KeyboardInterrupt traceback.

Ctrl-C at a terminal sends SIGINT to the whole process group, so to the workers of a gate or fuzz pool as well as to
the command. The command stops its pool itself (the gate ends its workers; a fuzzing campaign tells them to save
what they hold), so a worker must not die of the signal on its own: a spawned worker still importing the harness
would print a traceback. :func:`spawning` marks the workers a pool starts, also those it starts later in place of
others, and ``crosscheck/__init__.py`` makes a marked process ignore SIGINT from its first import of the harness on;
the worker's initializer then sets what it takes (the gate's ignores it, the campaign's handles it).
"""

from __future__ import annotations

import contextlib
import os
from typing import Iterator

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
