"""Deriving ahead: a helper process does a case's one-off preparation (``Formalism.prepare``: Euler–Lagrange's symbolic
derivations of the charts and of its linearization's program) while the process that evaluates the case starts on the
joint chart, on a machine with a CPU to spare.

The helper rebuilds the case from its spec (the same charts: they are drawn from the seed) and prepares the charts
in reverse order, so that the evaluating process, which needs them in order, meets it in the middle; an entry being
derived is locked (``formalisms.euler_lagrange._cached_text``), so whichever process gets there second waits and
reads it. Nothing is derived that the run does not evaluate: the charts of the case, and the linearization's program
only when the linearization check runs. The helper is stopped when the case ends (or is interrupted); what it
finished stays in the cache.
"""

from __future__ import annotations

import contextlib
import multiprocessing
import os
import signal
import warnings
from typing import Sequence

import formalisms
from crosscheck.engine.evaluation import CaseSetup
from crosscheck.engine.specs import CaseSpec, Checks
from formalisms.interface import Formalism, ModelNotSupported

#: Estimated CPU seconds of preparation (``Formalism.preparation``) above which a helper process derives ahead: a
#: spawned process costs about a second of imports.
AHEAD_S = 5.0


def _prepare(spec: CaseSpec, seed: int, checks: Checks, names: Sequence[str]) -> None:
    """The helper process: every chart of the case in reverse order, then the joint chart (with the linearization's
    program when that check runs), by each named built-in backend's ``prepare``. Silent: Ctrl-C at a terminal reaches
    the whole process group, and the evaluating process stops the helper itself; a derivation that fails here fails
    again in the evaluating process, which reports it where it belongs; and so does any warning (the loader's notices
    when the case is built again here)."""
    signal.signal(signal.SIGINT, signal.SIG_IGN)
    warnings.simplefilter("ignore")
    try:
        setup = CaseSetup.build(spec, seed, checks)
        for name in names:
            prepare = formalisms.get(name).prepare
            for chart in reversed(setup.charts):
                with contextlib.suppress(ModelNotSupported):
                    prepare(setup.model, chart, False)
            prepare(setup.model, None, checks.linearization)
    except Exception:  # noqa: BLE001 - reported by the evaluating process, which derives it again
        pass


def ahead(setup: CaseSetup, backends: Sequence[Formalism], seconds: float, checks: Checks,
          seed: int) -> multiprocessing.process.BaseProcess | None:
    """Start the helper for ``setup`` when its preparation is estimated above :data:`AHEAD_S` and this machine has
    more than one CPU; None otherwise. Only built-in backends are prepared ahead (a plugin's objects stay in this
    process)."""
    names = [b.name for b in backends if b.prepare is not None and b.name in formalisms.names()
             and formalisms.get(b.name) is b]
    if seconds <= AHEAD_S or not names or (os.cpu_count() or 1) < 2:
        return None
    process = multiprocessing.get_context("spawn").Process(
        target=_prepare, args=(setup.spec, seed, checks, names), daemon=True,
        name=f"crosscheck-prepare-{setup.spec.name}")
    try:
        process.start()
    except OSError:            # no process to spare (a limit, a sandbox): the evaluating process derives alone
        return None
    return process


def stop(process: multiprocessing.process.BaseProcess | None) -> None:
    """End the helper (what it finished stays in the cache; an entry it was writing is never half written)."""
    if process is not None and process.is_alive():
        process.terminate()
        process.join(timeout=5)
