"""What the commands share: the parser class and :class:`UsageError` (exit code 2), the output directories, exit
code 130 and its one line, the BLAS threads, the ``--workers`` policy, the options several commands declare
(``--workers``, ``--plugin``, ``--task-point``, ``--quiet``) and the readers of ``--seed``, ``--param``, ``--case``
and ``--model``, ``--formalism`` and ``--registry``. Each command module adds its own subparser with these."""

from __future__ import annotations

import argparse
import dataclasses
import os
import sys
from pathlib import Path

import numpy as np

import cases
from crosscheck import adapters, backends
from crosscheck.engine import divergences
from crosscheck.engine.specs import CaseSpec
from crosscheck.guards import preflight

#: Where every command writes by default: untracked (``.gitignore``), so running a command never dirties a clone.
OUTPUT_DIR = "crosscheck-out"
#: The committed reports, written only by ``crosscheck reports`` (``crosscheck.cli.reports.REPORTS``).
REPORTS_DIR = "reports"
#: Exit code of a run ended by Ctrl-C (128 + SIGINT, as a shell reports it).
INTERRUPTED = 130
#: Exit code of a run ended by SIGTERM (``timeout``, a CI job's time limit, a scheduler): 128 + 15.
TERMINATED = 143


class Terminated(KeyboardInterrupt):
    """SIGTERM, raised in the main thread by :func:`on_sigterm`: a KeyboardInterrupt, so every command stops and writes
    its partial report exactly as at Ctrl-C; :func:`_interrupted` then says so and exits with :data:`TERMINATED`."""


_SIGNALLED: list[str] = []


def on_sigterm(signum, frame) -> None:
    """The SIGTERM handler of a command (``crosscheck.cli.main`` installs it): stop as Ctrl-C does
    (:class:`Terminated`). Once: a second SIGTERM while the partial report is written is ignored."""
    if not _SIGNALLED:
        _SIGNALLED.append("SIGTERM")
        raise Terminated("SIGTERM")

#: BLAS threads for a command. Every matrix here is tiny (n <= 30); a threaded BLAS level-3 call on one (e.g. a
#: triangular solve with a few right-hand sides) costs milliseconds in thread hand-off on a busy 2-core machine:
#: a constrained Euler–Lagrange split measured 40 ms with the default threads, 1 ms with one. Here rather than in
#: ``crosscheck.cli`` (which sets it around every command) because the fault hunters' worker processes set it too.
BLAS_THREADS = 1


class UsageError(Exception):
    """Bad input from the command line: reported in one line, exit code 2."""


class _Parser(argparse.ArgumentParser):
    def error(self, message):
        raise UsageError(f"{message} (see '{self.prog} --help')")


def _one_line(exc: BaseException) -> str:
    """An error's message on one line: a list of problems (``- ...`` lines, as a ModelError gives) after its colon,
    separated by semicolons."""
    return " ".join(str(exc).replace(":\n  - ", ": ").replace("\n  - ", "; ").split())


def _vector(text: str, label: str) -> list[float]:
    """Comma-separated numbers (spaces allowed around them); an empty entry or a non-number is an error, never
    skipped, and so is a number that is not finite (``1e309`` reads as inf)."""
    parts = [p.strip() for p in text.split(",")] if text.strip() else []
    try:
        values = [float(p) for p in parts if p]
    except ValueError:
        raise UsageError(f"--{label} takes comma-separated numbers, got '{text}'") from None
    if len(values) < len(parts):
        raise UsageError(f"--{label} has an empty entry (position {parts.index('') + 1}) in '{text}'; give one "
                         "number per coordinate, separated by commas")
    preflight.check_vector(label, np.array(values))
    return values


#: Largest seed: numpy's and Hypothesis' generators take any non-negative integer; 2^63 - 1 keeps it one int64.
MAX_SEED = 2**63 - 1


#: Worker processes per CPU at most (``--workers`` of gate, fuzz, faults, trajectory): each holds the backends,
#: Pinocchio and the models' compiled code (hundreds of MB), and more processes than CPUs only share them.
WORKERS_PER_CPU = 2


def workers(requested: int | None, units: float) -> int:
    """The worker processes of a command (``--workers``, one meaning in every command): 0 runs the work in this
    process, N >= 1 in N spawned worker processes, never more than the ``units`` of work there are (cases, chunks,
    jobs); None, the default, is one per CPU, but this process when there is only one unit (a pool of one would only
    add its start-up). At most :data:`WORKERS_PER_CPU` per CPU."""
    cpus = os.cpu_count() or 1
    most = WORKERS_PER_CPU * cpus
    if requested is None:
        return 0 if units <= 1 else int(min(cpus, units))
    if not 0 <= requested <= most:
        raise UsageError(f"--workers takes 0 to {most} ({WORKERS_PER_CPU} per CPU) processes, got {requested}")
    return int(min(requested, max(units, 1)))


def add_workers_option(parser: argparse.ArgumentParser, unit: str) -> None:
    """``--workers N`` with the one meaning of :func:`workers`; ``unit`` names what the processes share out."""
    parser.add_argument("--workers", type=int, default=None, metavar="N",
                        help=f"0: run in this process; N >= 1: N worker processes, at most one per {unit} (default: "
                             f"one per CPU, or this process when there is only one {unit}; at most "
                             f"{WORKERS_PER_CPU} per CPU)")


#: Most rigid frame changes a gate run samples (``--frames``); ``eval --frame gK`` takes K below it.
MAX_FRAMES = 16


def _seed(text: str) -> int:
    """``--seed``: an integer from 0 to :data:`MAX_SEED`."""
    try:
        value = int(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"takes an integer from 0 to {MAX_SEED}, got '{text}'") from None
    if not 0 <= value <= MAX_SEED:
        raise argparse.ArgumentTypeError(f"takes an integer from 0 to {MAX_SEED}, got {value}")
    return value


def _params(pairs: list[str]) -> tuple[tuple[str, str], ...]:
    out = []
    for pair in pairs:
        key, sep, value = pair.partition("=")
        if not sep or not key:
            raise UsageError(f"--param takes KEY=VALUE, got '{pair}'")
        out.append((key, value))
    return tuple(out)


def _armature(text: str) -> tuple[tuple[str, float], ...]:
    """``--armature JOINT=VALUE[,JOINT=VALUE...]`` as (joint, value) pairs; a UsageError for anything else (the
    loader checks the names against the file and the values' range)."""
    pairs = []
    for item in filter(None, (part.strip() for part in text.split(","))):
        joint, sep, value = item.partition("=")
        try:
            number = float(value)
        except ValueError:
            number = None
        if not sep or not joint.strip() or number is None:
            raise UsageError(f"--armature takes JOINT=VALUE[,JOINT=VALUE...] (a URDF joint's rotor inertia: kg m^2 for "
                             f"a revolute joint, kg for a prismatic one), got '{item}'")
        pairs.append((joint.strip(), number))
    if not pairs:
        raise UsageError("--armature takes JOINT=VALUE[,JOINT=VALUE...], got nothing")
    names = [joint for joint, _ in pairs]
    if len(set(names)) < len(names):
        raise UsageError(f"--armature names a joint more than once: {', '.join(names)}")
    return tuple(pairs)


def _specs(args) -> list[CaseSpec]:
    params = _params(args.param)
    names = args.case or ([] if args.model else cases.names())
    if params and len(names) != 1:
        raise UsageError("--param needs exactly one --case")
    for name in names:
        if name not in cases.names():
            raise UsageError(f"unknown case '{name}'; valid cases: {', '.join(cases.names())}")
    specs = [CaseSpec(name, params) for name in names]
    base = getattr(args, "base", None)
    if base is not None and not args.model:
        raise UsageError("--base applies to a --model URDF file (fixed: the root link welded to the world; free: a "
                         "free joint added above it)")
    actuated = getattr(args, "actuated", None)
    if actuated is not None and not args.model:
        raise UsageError("--actuated applies to a --model URDF file (its joint names, e.g. --actuated joint1,joint3); "
                         "a built-in case has its own input map")
    actuated = None if actuated is None else tuple(filter(None, (name.strip() for name in actuated.split(","))))
    armature = getattr(args, "armature", None)
    if armature is not None and not args.model:
        raise UsageError("--armature applies to a --model URDF file (its joint names, e.g. --armature "
                         "shoulder=0.01,elbow=0.005); a built-in case has its own (the pendulums: --param a1=...)")
    armature = None if armature is None else _armature(armature)
    specs += [CaseSpec(Path(path).stem, path=path, base=base, actuated=actuated, armature=armature)
              for path in args.model]
    point = getattr(args, "task_point", None)
    if point is not None and len(specs) != 1:
        raise UsageError("--task-point needs exactly one --case or --model (a body of that model)")
    return [dataclasses.replace(spec, task_point=point) for spec in specs]


def _backends(selected: list[str] | None):
    return [backends.get(name) for name in (selected or backends.names())]


def add_plugin_option(parser: argparse.ArgumentParser) -> None:
    """``--plugin MODULE:OBJECT`` (repeatable) on a subcommand. :func:`crosscheck.cli.main` loads the plugins before
    the command runs, so they are in ``backends.names()``; a worker process loads them from
    ``backends.plugin_specs()``."""
    parser.add_argument("--plugin", action="append", default=[], metavar="MODULE:OBJECT",
                        help="also evaluate your own backend, e.g. mypkg.dynamics:BACKEND (repeatable)")
    parser.add_argument("--simulator", action="append", dest="plugin", type=_simulator,
                        metavar="NAME[:DEFAULT,...]",
                        help=f"also evaluate a simulator reading the model file ({', '.join(adapters.SIMULATORS)}), "
                        "every model-changing default off but those named, e.g. mujoco:damping (repeatable; "
                        "docs/simulators.md)")


def _simulator(text: str) -> str:
    """``--simulator NAME[:DEFAULT,...]`` as the ``--plugin`` spec of that adapter (``crosscheck.adapters``)."""
    try:
        return adapters.plugin_spec(text)
    except adapters.SimulatorError as exc:
        raise argparse.ArgumentTypeError(str(exc)) from None


def add_task_point_option(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--task-point", metavar="BODY[:x,y,z]",
                        help="the task point: a body's point at offset x,y,z in its frame (m); BODY alone: its centre "
                        "of mass (an offset point of it if that lies on a joint axis). Default: the model's own")


def add_quiet_option(parser: argparse.ArgumentParser) -> None:
    """``--quiet`` on a long-running subcommand: no progress display and no progress lines on stderr (CI logs)."""
    parser.add_argument("--quiet", action="store_true",
                        help="no progress on stderr (the bar on a terminal, the per-step lines elsewhere)")


def _registry(args) -> divergences.Registry | None:
    """The divergence registry of a gate run: ``--registry PATH``, else ``divergences.toml`` in the current
    directory when there is one; none with ``--no-registry``."""
    if args.no_registry and args.registry:
        raise UsageError("give either --registry PATH or --no-registry, not both")
    path = None if args.no_registry else args.registry or (
        divergences.DEFAULT_PATH if Path(divergences.DEFAULT_PATH).is_file() else None)
    try:
        return divergences.load(path) if path else None
    except divergences.RegistryError as exc:
        raise UsageError(str(exc)) from None


def _interrupted(detail: str = "") -> int:
    """Ctrl-C: one line on stderr (``detail``: where the run stopped, what it left behind); exit code 130. After SIGTERM
    (:func:`on_sigterm`) the line says so and the exit code is 143."""
    if _SIGNALLED:
        print("crosscheck: terminated by SIGTERM" + (f" {detail}" if detail else ""), file=sys.stderr)
        return TERMINATED
    print("crosscheck: interrupted" + (f" {detail}" if detail else ""), file=sys.stderr)
    return INTERRUPTED
