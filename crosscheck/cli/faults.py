"""``crosscheck faults``: hunt each catalogued fault with the default gate, in this process or a pool of spawned
worker processes (``--workers``), then measure the sensitivity table; the report and a line per fault."""

from __future__ import annotations

import dataclasses
import shlex
import signal
import time

from threadpoolctl import threadpool_limits

from crosscheck.cli.options import (BLAS_THREADS, OUTPUT_DIR, _interrupted, _registry, _seed, add_quiet_option,
                                    add_workers_option, UsageError, workers)
from crosscheck.engine import divergences, workers as worker_processes
from crosscheck.engine.progress import Display
from crosscheck.engine.specs import DEFAULT_SAMPLES
from crosscheck.faults import backend_catalog, common_mode, injection, sensitivity
from crosscheck.guards import preflight

DEFAULT_FAULTS_REPORT = f"{OUTPUT_DIR}/faults.md"


def _chosen_faults(args):
    """(backend faults, common-mode faults) named by ``--fault`` (either catalog), or both whole catalogs."""
    if not args.fault:
        return list(backend_catalog.CATALOG), list(common_mode.CATALOG)
    backend, shared = [], []
    for name in args.fault:
        if name in common_mode.names():
            shared.append(common_mode.get(name))
            continue
        try:
            backend.append(backend_catalog.get(name))
        except injection.FaultError:
            raise UsageError(f"unknown fault '{name}'; valid faults: {', '.join(backend_catalog.names())}; "
                             f"common-mode: {', '.join(common_mode.names())}") from None
    return backend, shared


def cmd_faults(args) -> int:
    """Inject each catalog fault in turn and hunt it with the default gate (``crosscheck.faults.injection``), then each
    common-mode fault in shared code (``crosscheck.faults.common_mode``), then measure the sensitivity table
    (``crosscheck.faults.sensitivity``); exit 0 only when every fault is caught and the 3-D claim is met."""
    if args.samples < 1:
        raise UsageError("--samples must be at least 1")
    if args.sensitivity_states < 0:
        raise UsageError("--sensitivity-states must be 0 (skip) or more")
    chosen, shared = _chosen_faults(args)
    if args.list:
        width = max([len(f.name) for f in [*chosen, *shared]], default=0)
        for f in chosen:
            print(f"{f.name:{width}s}  {f.backend:17s}  {f.target}{' (derivation)' if f.derived else ''}\n"
                  f"{'':{width}s}  {f.bug}")
        for f in shared:
            print(f"{f.name:{width}s}  {'shared: ' + f.area:17s}  {', '.join(f.targets)}\n{'':{width}s}  {f.bug} "
                  f"Guard: {f.guard}.")
        return 0
    known = _registry(args)
    report = preflight.claim_output(args.report, "report", "# crosscheck faults\n\nThe run writing this report "
                                    "has not finished (interrupted or failed).\n")
    command = "crosscheck " + " ".join(shlex.quote(a) for a in args.argv)
    start = time.perf_counter()
    hunts, shared_hunts = [], []
    with Display("faults", "faults", len(chosen) + len(shared), quiet=args.quiet) as display:
        try:
            _hunt_faults(args, chosen, shared, known, display, hunts, shared_hunts)
            table = _sensitivity(args, display)
        except KeyboardInterrupt:
            done = len(hunts) + len(shared_hunts)
            where = ("during the sensitivity table (every fault hunted)" if done == len(chosen) + len(shared)
                     else f"after {done}/{len(chosen) + len(shared)} faults")
            report.write_text(injection.render(hunts, command, time.perf_counter() - start, args.samples, args.seed,
                                            where) + common_mode.render(shared_hunts))
            return _interrupted(f"{where}; partial report written to {report}")
    seconds = time.perf_counter() - start
    summary = injection.summarize(hunts)
    report.write_text(injection.render(hunts, command, seconds, args.samples, args.seed)
                      + common_mode.render(shared_hunts) + ("\n".join(sensitivity.render(table)) if table else ""))
    missed = sum(not h.caught for h in shared_hunts)
    claim = table is None or table.claim_met()
    print(f"caught {summary.caught}/{summary.faults} ({100 * summary.rate:.0f} %); states needed median "
          f"{summary.median_states:g}, max {summary.max_states}; outlier named = faulty backend for "
          f"{summary.named_faulty}/{summary.caught}; common-mode caught {len(shared_hunts) - missed}/"
          f"{len(shared_hunts)}" + ("" if table is None else f"; 3-D sensitivity claim {'met' if claim else 'NOT met'}")
          + f"; {seconds:.1f} s; report written to {report}")
    return 0 if summary.caught == summary.faults and not missed and claim else 1


def _hunt_faults(args, chosen, shared, known, display: Display, hunts: list, shared_hunts: list) -> None:
    """Hunt each backend fault, then each common-mode fault, with the default gate (``crosscheck.faults.injection``,
    ``crosscheck.faults.common_mode``), appending to ``hunts`` and ``shared_hunts`` as each ends (so that an
    interrupted run keeps them); a line per fault on stdout. ``--workers`` (:func:`workers`, one process per fault at
    most): in this process, or in a pool (:func:`_hunt_in_pool`), with the same hunts in the same order."""
    count = workers(args.workers, len(chosen) + len(shared))
    if count:
        return _hunt_in_pool(args, chosen, shared, known, display, hunts, shared_hunts, count)
    for fault in chosen:
        hunts.append(injection.hunt(fault, samples=args.samples, seed=args.seed, known=known,
                                 progress=_hunting(display, fault.name)))
        print(injection.line(hunts[-1]), flush=True)
        display.advance()
    for fault in shared:
        shared_hunts.append(common_mode.hunt(fault, samples=args.samples, seed=args.seed, known=known,
                                             progress=_hunting(display, fault.name)))
        print(common_mode.line(shared_hunts[-1]), flush=True)
        display.advance()


def _init_hunter(show=None) -> None:
    """A fault-hunting worker process: Ctrl-C ignored (the parent stops the pool), warnings shown as the parent shows
    them (``show``: ``workers.warning_display``), one BLAS thread."""
    global _HUNTER_LIMITS
    signal.signal(signal.SIGINT, signal.SIG_IGN)
    worker_processes.show_warnings_with(show)
    _HUNTER_LIMITS = threadpool_limits(limits=BLAS_THREADS, user_api="blas")


_HUNTER_LIMITS = None


def _hunt_one(shared: bool, name: str, samples: int, seed: int, known):
    """One fault hunted in a worker process, found by name in its catalog. The hunt comes back without its fault (a
    fault holds its faulty function, which does not pickle): the parent puts it back."""
    if shared:
        found = common_mode.hunt(common_mode.get(name), samples=samples, seed=seed, known=known)
    else:
        found = injection.hunt(backend_catalog.get(name), samples=samples, seed=seed, known=known)
    return dataclasses.replace(found, fault=None)


def _hunt_in_pool(args, chosen, shared, known, display: Display, hunts: list, shared_hunts: list,
                  count: int) -> None:
    """:func:`_hunt_faults` in ``count`` spawned processes: every fault submitted at once, the hunts taken back in
    catalog order (each printed and appended as it comes, so Ctrl-C keeps the ones in before it)."""
    import multiprocessing

    ctx = multiprocessing.get_context("spawn")
    jobs = [(False, f) for f in chosen] + [(True, f) for f in shared]
    display.doing(f"{len(jobs)} faults in {count} worker processes")
    with worker_processes.spawning(), ctx.Pool(count, initializer=_init_hunter,
                                                   initargs=(worker_processes.warning_display(),)) as pool:
        pending = [pool.apply_async(_hunt_one, (is_shared, f.name, args.samples, args.seed, known))
                   for is_shared, f in jobs]
        for (is_shared, fault), result in zip(jobs, pending):
            found = dataclasses.replace(result.get(), fault=fault)
            (shared_hunts if is_shared else hunts).append(found)
            print((common_mode.line if is_shared else injection.line)(found), flush=True)
            display.advance()


def _hunting(display: Display, fault: str):
    """A hunt's progress callback: the fault and the state under evaluation, on ``display``."""
    return lambda case, index: display.doing(f"{fault}: {case} state #{index}")


def _sensitivity(args, display: Display):
    """The sensitivity table (``crosscheck.faults.sensitivity``), None when skipped (``--sensitivity-states 0`` or
    ``--fault``); a line per backend and term measured."""
    if not args.sensitivity_states or args.fault:
        return None
    chosen = injection.default_backends()
    display.stage("sensitivity terms", len([b for b in chosen if b.name in sensitivity.TERM_HOOKS])
                  * len(sensitivity.TERMS))
    display.doing("sensitivity: the smallest error each check catches")

    def measured(line: str) -> None:
        display.note(line)
        display.advance()

    return sensitivity.run(chosen, args.sensitivity_states, args.seed, measured)


def add_parser(sub) -> None:
    """The ``faults`` subcommand on ``sub``."""
    hunt = sub.add_parser("faults", help="inject each catalogued fault and measure whether the default gate "
                          "catches it")
    hunt.add_argument("--fault", action="append", default=[], metavar="NAME",
                      help="run only this fault (repeatable; default: the whole catalog, see --list)")
    hunt.add_argument("--samples", type=int, default=DEFAULT_SAMPLES,
                      help=f"at most this many states per case, as the default gate (default {DEFAULT_SAMPLES})")
    hunt.add_argument("--seed", type=_seed, default=0, help="random seed of the gate's states (default 0)")
    hunt.add_argument("--report", default=DEFAULT_FAULTS_REPORT,
                      help=f"markdown report path (default {DEFAULT_FAULTS_REPORT})")
    hunt.add_argument("--list", action="store_true", help="print the catalog (or the chosen faults) and exit")
    hunt.add_argument("--sensitivity-states", type=int, default=30, metavar="N",
                      help="states per case for the sensitivity table (default 30; 0: skip it; skipped with --fault)")
    hunt.add_argument("--registry", metavar="PATH", help="divergence registry, as for gate "
                      f"(default: {divergences.DEFAULT_PATH} in the current directory, if present)")
    hunt.add_argument("--no-registry", action="store_true", help="use no divergence registry")
    add_workers_option(hunt, "fault")
    add_quiet_option(hunt)
    hunt.set_defaults(run=cmd_faults)
