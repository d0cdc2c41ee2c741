"""The gate's cases in spawned worker processes: the same outcomes as in this process, in case order."""

from __future__ import annotations

import pickle
import signal
import warnings
from typing import Callable, Sequence

from cases.urdf import LoadNotice
from crosscheck.backends import load_plugins, plugin_specs
from crosscheck.engine import workers as worker_processes
from crosscheck.engine.outcomes import CaseOutcome
from crosscheck.engine.phases import DONE, IN_WORKER, Step
from crosscheck.engine.specs import CaseSpec, Checks
from formalisms.interface import Formalism


def picklable(backends: Sequence[Formalism]) -> bool:
    try:
        pickle.dumps(list(backends))
    except Exception:  # any object a user registers: pickling may fail in many ways
        return False
    return True


_BACKENDS: list[Formalism] = []
_LIMITS = None


def _init_worker(chosen: list[Formalism], plugins: Sequence[str], show: Callable | None = None) -> None:
    """A worker process: Ctrl-C ignored (the parent stops the pool), warnings shown as the parent shows them
    (``show``: ``workers.warning_display``) but for the loaders' notices, which the parent showed when it built every
    model to order the cases (:func:`in_pool`), one BLAS thread, the parent's plugins, the backends of the run."""
    global _LIMITS
    from threadpoolctl import threadpool_limits

    signal.signal(signal.SIGINT, signal.SIG_IGN)
    worker_processes.show_warnings_with(show)
    warnings.filterwarnings("ignore", category=LoadNotice)
    _LIMITS = threadpool_limits(limits=1, user_api="blas")
    load_plugins(plugins)
    _BACKENDS[:] = chosen


def _worker_case(run_case: Callable[..., CaseOutcome], spec: CaseSpec, samples: int, seed: int,
                 checks: Checks) -> CaseOutcome:
    """``run_case`` (the engine's, passed by its caller) on a case in a worker process, with the run's backends."""
    return run_case(spec, _BACKENDS, samples, seed, None, checks)


def in_pool(run_case: Callable[..., CaseOutcome], specs: Sequence[CaseSpec], backends: Sequence[Formalism],
             samples: int, seed: int, tell: Callable[[Step], None], checks: Checks, workers: int,
             outcomes: list[CaseOutcome], failed: Callable[[CaseSpec, Exception], CaseOutcome] | None = None,
             passing: tuple[type[BaseException], ...] = ()) -> None:
    """The cases, each run by ``run_case``, in ``workers`` spawned processes, the largest models (most coordinates)
    first so that no worker is left with a large case at the end; their outcomes added to ``outcomes`` in case order. On
    Ctrl-C the outcomes already in, in case order, are kept there, and the workers are stopped. ``failed``: the outcome
    of a case whose worker raised (the harness's failure: ``crosscheck.engine.run.failed_case``), the exceptions of
    ``passing`` (bad input) aside, which propagate; None: every exception propagates."""
    import multiprocessing

    ctx = multiprocessing.get_context("spawn")
    order = sorted(range(len(specs)), key=lambda k: -specs[k].build().n)
    with worker_processes.spawning(), ctx.Pool(workers, initializer=_init_worker,
                                               initargs=(list(backends), plugin_specs(),
                                                         worker_processes.warning_display())) as pool:
        pending = {k: pool.apply_async(_worker_case, (run_case, specs[k], samples, seed, checks)) for k in order}
        try:
            for k, spec in enumerate(specs):
                tell(Step(spec.name, 0, samples, IN_WORKER))
                outcomes.append(_outcome(pending[k], spec, failed, passing))
                tell(Step(spec.name, samples, samples, DONE))
        except KeyboardInterrupt:
            outcomes[:] = [pending[k].get() for k in range(len(specs))
                           if pending[k].ready() and pending[k].successful()]
            raise


def _outcome(pending, spec: CaseSpec, failed: Callable[[CaseSpec, Exception], CaseOutcome] | None,
             passing: tuple[type[BaseException], ...]) -> CaseOutcome:
    """A worker's outcome of ``spec``, or ``failed(spec, exc)`` for what it raised (module doc of
    ``crosscheck.engine.internal``: the harness's failure in a worker process is the case's internal error)."""
    if failed is None:
        return pending.get()
    try:
        return pending.get()
    except passing:
        raise
    except Exception as exc:  # noqa: BLE001 - the harness's failure in the worker (its traceback is the cause)
        return failed(spec, exc)
