"""The ``crosscheck`` command line: cases, formalisms, gate, eval, faults, fuzz, replay, merge, bench, stability,
trajectory, reports, cache.

Each command lives in its own module of this package, which adds its subparser (``add_parser(sub)``) and runs it:
``listing`` (cases, formalisms), ``gate``, ``eval``, ``faults``, ``fuzz`` (fuzz, replay, merge), ``bench`` (also
``--scale``), ``stability``, ``trajectory``, ``reports`` and ``cache``; what they share (the parser class, the common
options, the ``--workers`` policy, the output directories) is in ``options``. This module assembles the parser and runs
a command (:func:`main`, the ``crosscheck`` console script); the command modules never import it.

Outputs: every command writes under ``options.OUTPUT_DIR`` (``crosscheck-out/``, git-ignored) unless told otherwise;
the committed reports in ``options.REPORTS_DIR`` are written only by ``crosscheck reports`` (``reports.REPORTS``).

Exit codes: 0 all agree, 1 a disagreement (or a backend error), 2 bad input or usage, 3 the harness itself failed
(``gate``: an internal error, ``crosscheck.engine.internal``; the report says where), 130 interrupted (Ctrl-C:
one line on stderr; gate, faults and bench write a partial report of what completed, fuzz its campaign's report), 143
terminated by SIGTERM (``timeout``, a CI job's limit: the same partial report as at Ctrl-C).
"""

from __future__ import annotations

import argparse
import contextlib
import signal
import sys
import threading
import warnings
from typing import Iterator

from threadpoolctl import threadpool_limits

import cases
from cases.build import TaskPointError
from cases.model import ModelError
import cases.urdf
from crosscheck import backends
from crosscheck.checks import charts
from crosscheck.cli import (bench, cache, eval, faults, fuzz, gate, listing, options, reports, simulators, stability,
                            trajectory)
from crosscheck.cli.options import BLAS_THREADS, _interrupted, _one_line, _Parser, UsageError
from crosscheck.core import sampling
from crosscheck.engine.run import PreparationNotice
from crosscheck.guards import preflight
from formalisms import UnknownFormalism
from formalisms.cache import cache_limit
from formalisms.interface import StateError

#: The command modules in the order ``crosscheck --help`` lists their subcommands.
COMMANDS = (listing, gate, simulators, eval, faults, fuzz, bench, stability, trajectory, reports, cache)


def _version() -> str:
    """The installed distribution's version, or why there is none (run from a checkout without installing)."""
    import importlib.metadata

    try:
        return importlib.metadata.version("crosscheck")
    except importlib.metadata.PackageNotFoundError:
        return "(not installed: run from a source tree)"


def build_parser() -> argparse.ArgumentParser:
    parser = _Parser(prog="crosscheck", description="Cross-formalism verification of rigid multibody dynamics.")
    parser.add_argument("--version", action="version", version=f"crosscheck {_version()}")
    sub = parser.add_subparsers(dest="command", required=True, parser_class=_Parser)
    for command in COMMANDS:
        command.add_parser(sub)
    return parser


def _notice(message, category, filename, lineno, file=None, line=None) -> None:
    """A loader's notice (``cases.urdf.LoadNotice``) or the gate's (``engine.run.PreparationNotice``) as one line;
    other warnings as Python prints them."""
    if issubclass(category, (cases.urdf.LoadNotice, PreparationNotice)):
        print(f"crosscheck: notice: {message}", file=sys.stderr if file is None else file)
    else:
        _show_warning(message, category, filename, lineno, file, line)


_show_warning = warnings.showwarning


def main(argv: list[str] | None = None) -> int:
    with warnings.catch_warnings(), _sigterm_stops():   # the loaders' notices as one line each, for this command only
        warnings.showwarning = _notice
        return _main(argv)


@contextlib.contextmanager
def _sigterm_stops() -> Iterator[None]:
    """SIGTERM ends the command as Ctrl-C does (partial report, one line; exit 143: ``options.on_sigterm``), for this
    command only; nothing when not in the main thread (signals go to the main thread alone)."""
    if threading.current_thread() is not threading.main_thread():
        yield
        return
    options._SIGNALLED.clear()
    previous = signal.signal(signal.SIGTERM, options.on_sigterm)
    try:
        yield
    finally:
        signal.signal(signal.SIGTERM, previous)


def _main(argv: list[str] | None) -> int:
    argv = list(sys.argv[1:] if argv is None else argv)
    try:
        args = build_parser().parse_args(argv)
        args.argv = argv
        try:
            cache_limit()            # a bad CROSSCHECK_CACHE_LIMIT is named here, not by a backend's first write
        except ValueError as exc:
            raise UsageError(str(exc)) from None
        backends.load_plugins(getattr(args, "plugin", []))
        with threadpool_limits(limits=BLAS_THREADS, user_api="blas"):
            return args.run(args)
    except (UsageError, cases.CaseError, cases.UrdfError, ModelError, StateError, UnknownFormalism, TaskPointError,
            backends.PluginError, charts.ChartError, sampling.ProjectionError, preflight.PreflightError,
            OSError) as exc:
        print(f"crosscheck: error: {_one_line(exc)}", file=sys.stderr)
        return 2
    except KeyboardInterrupt:   # a command without a partial report of its own, or a second Ctrl-C
        return _interrupted()
