"""The ``crosscheck`` command line: cases, formalisms, gate, eval, faults, fuzz, replay, merge, bench, stability,
trajectory, reports.

Outputs: every command writes under :data:`OUTPUT_DIR` (``crosscheck-out/``, git-ignored) unless told otherwise; the
committed reports in :data:`REPORTS_DIR` are written only by ``crosscheck reports`` (:data:`REPORTS`).

Exit codes: 0 all agree, 1 a disagreement (or a backend error), 2 bad input or usage, 130 interrupted (Ctrl-C:
one line on stderr; gate, faults and bench write a partial report of what completed, fuzz its campaign's report).
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import math
import os
import shlex
import sys
import warnings
from pathlib import Path

import numpy as np
from threadpoolctl import threadpool_limits

import cases
import cases.urdf
from cases import configuration
from cases.model import ModelError
from cases.build import TaskPointError
from crosscheck import backends
from crosscheck.checks import charts, frames, linearization
from crosscheck.core import sampling
from crosscheck.core import tolerance as policy
from crosscheck.reports import diagnosis, junit
from crosscheck.engine import evaluation
from crosscheck.engine import run
from crosscheck.engine import phases
from crosscheck.guards import preflight
from crosscheck.engine import divergences
from crosscheck.engine.specs import DEFAULT_SAMPLES, CaseSpec, Checks
from crosscheck.engine.run import run_gate
from crosscheck.core.compare import DISAGREE, KNOWN, worst_of
from crosscheck.engine.progress import Display
from crosscheck.reports import gate_summary
from crosscheck.reports.gate_lines import task_point_lines
from formalisms import UnknownFormalism
from formalisms.interface import UNSUPPORTED, ModelNotSupported, StateError

#: Where every command writes by default: untracked (``.gitignore``), so running a command never dirties a clone.
OUTPUT_DIR = "crosscheck-out"
#: The committed reports, written only by ``crosscheck reports`` (:data:`REPORTS`).
REPORTS_DIR = "reports"
DEFAULT_REPORT = f"{OUTPUT_DIR}/gate.md"
#: ``fuzz --out`` and ``replay --dir`` (``crosscheck.campaigns.fuzz.settings.DEFAULT_DIR`` for the Python API).
DEFAULT_FUZZ_DIR = f"{OUTPUT_DIR}/fuzz"
#: Exit code of a run ended by Ctrl-C (128 + SIGINT, as a shell reports it).
INTERRUPTED = 130


class UsageError(Exception):
    """Bad input from the command line: reported in one line, exit code 2."""


class _Parser(argparse.ArgumentParser):
    def error(self, message):
        raise UsageError(f"{message} (see '{self.prog} --help')")


def _one_line(exc: BaseException) -> str:
    return " ".join(str(exc).replace("\n  - ", "; ").split())


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
    actuated = None if actuated is None else tuple(name.strip() for name in actuated.split(","))
    specs += [CaseSpec(Path(path).stem, path=path, base=base, actuated=actuated) for path in args.model]
    point = getattr(args, "task_point", None)
    if point is not None and len(specs) != 1:
        raise UsageError("--task-point needs exactly one --case or --model (a body of that model)")
    return [dataclasses.replace(spec, task_point=point) for spec in specs]


def _backends(selected: list[str] | None):
    return [backends.get(name) for name in (selected or backends.names())]


def add_plugin_option(parser: argparse.ArgumentParser) -> None:
    """``--plugin MODULE:OBJECT`` (repeatable) on a subcommand. :func:`main` loads the plugins before the command
    runs, so they are in ``backends.names()``; a worker process loads them from ``backends.plugin_specs()``."""
    parser.add_argument("--plugin", action="append", default=[], metavar="MODULE:OBJECT",
                        help="also evaluate your own backend, e.g. mypkg.dynamics:BACKEND (repeatable)")


def add_task_point_option(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--task-point", metavar="BODY[:x,y,z]",
                        help="the task point: a body's point at offset x,y,z in its frame (m); BODY alone: its centre "
                        "of mass (an offset point of it if that lies on a joint axis). Default: the model's own")


def add_quiet_option(parser: argparse.ArgumentParser) -> None:
    """``--quiet`` on a long-running subcommand: no progress display and no progress lines on stderr (CI logs)."""
    parser.add_argument("--quiet", action="store_true",
                        help="no progress on stderr (the bar on a terminal, the per-step lines elsewhere)")


def cmd_cases(args) -> int:
    for info in cases.catalog():
        params = ", ".join(f"{k}={v}" for k, v in info.parameters.items()) or "no parameters"
        print(f"{info.name:18s} {info.summary}\n{'':18s} parameters: {params}")
    return 0


def cmd_formalisms(args) -> int:
    width = max(map(len, backends.names()))
    plugins = backends.plugin_sources()
    for name in backends.names():
        tag = " (external reference)" if name == backends.REFERENCE_NAME else ""
        tag = f" ({plugins[name]})" if name in plugins else tag
        formalism = backends.get(name)
        print(f"{name:{width}s}  {formalism.summary}{tag}")
        evaluation = getattr(formalism, "evaluation", None)  # a plugin need not have the field
        if evaluation is not None:
            print(f"{'':{width}s}  evaluation: {evaluation()}")
    return 0


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


def _required(args) -> list[str]:
    """The backends named on the command line (``--formalism``, ``--plugin``) and not ``--optional``: each must take
    part in some comparison."""
    named = list(args.formalism or []) + [backends.load_plugin(spec).name for spec in args.plugin]
    for name in args.optional:
        if name not in named:
            raise UsageError(f"--optional {name}: name it with --formalism or --plugin as well (named: "
                             f"{', '.join(named) or 'none'})")
    return [name for name in dict.fromkeys(named) if name not in args.optional]


def cmd_gate(args) -> int:
    if args.samples < 1:
        raise UsageError("--samples must be at least 1")
    if not 0 <= args.frames <= MAX_FRAMES:
        raise UsageError(f"--frames takes 0 (off) to {MAX_FRAMES} frame changes per case, got {args.frames}")
    specs = _specs(args)
    count = workers(args.workers, len(specs))
    chosen = _backends(args.formalism)
    for model in [spec.build() for spec in specs]:  # every model first, so bad input fails before any work
        preflight.check_model(model)
    known = _registry(args)
    placeholder = "# crosscheck gate\n\nThe run writing this report has not finished (interrupted or failed).\n"
    report = preflight.claim_output(args.report, "report", placeholder)
    preflight.claim_output(gate_summary.details_path(report), "report (its details file)", placeholder)
    if args.junit:
        preflight.claim_output(args.junit, "junit", "")
    checks = Checks(charts=not args.no_charts, frames=args.frames, conservation=not args.no_conservation,
                    closed_forms=not args.no_closed_forms, self_test=not args.no_self_test,
                    linearization=not args.no_linearization, joint_limits=not args.ignore_limits)
    with Display("gate", "states", args.samples * len(specs), quiet=args.quiet) as display:
        try:
            result = run_gate(specs, chosen, args.samples, args.seed, _gate_progress(display), checks,
                              workers=count, required=_required(args))
        except run.Interrupted as stop:
            result = stop.result
    applied = divergences.apply(known, result) if known else None
    command = "crosscheck " + " ".join(shlex.quote(a) for a in args.argv)
    if result.interrupted:   # what completed, without the hints (they evaluate again): the user wants out
        gate_summary.write(result, command, report, applied)
        return _interrupted(f"{result.interrupted}; partial report written to {report}")
    diagnosis.annotate(result, chosen)
    _, details = gate_summary.write(result, command, report, applied, gate_summary.mechanism_figures(result, report))
    if args.junit:
        junit.write(result, args.junit)
    for entry in applied.stale if applied else ():
        print(f"crosscheck: warning: stale {entry.describe()} in {applied.registry.source}: compared in this run "
              "but explained no disagreement", file=sys.stderr)
    for case in result.cases:
        bad = sum(s.failed for s in case.states)
        broken = sum(bool(s.breakdowns) for s in case.states)
        worst = worst_of(s.worst_ratio for s in case.states)
        checked = [c.worst_ratio for s in case.states for c in s.checks.values()]
        status = "FAIL" if bad else "ok"
        known_here = sum(c.verdict == KNOWN for s in case.states for c in [*s.comparisons.values(),
                                                                           *s.checks.values()])
        print(f"{status:4s} {case.spec.name:18s} {len(case.states)} states, {bad} failing, {known_here} known, "
              f"{broken} breakdown, "
              f"worst error/tolerance {worst:.3g}; {len(checked)} invariance/conservation comparisons, worst "
              f"{worst_of(checked):.3g}")
    for case in result.cases:
        for why in task_point_lines(case)[1:]:   # a task condition in BREAKDOWN at most states: say why
            print(f"note {case.spec.name}: {why.strip(' -')}", file=sys.stderr)
    for case in result.cases:
        for problem in case.coverage.problems if case.coverage else ():
            print(f"FAIL {case.spec.name}: degenerate sample: {problem}", file=sys.stderr)
    for name in result.absent:
        raised = [s.errors[name] for case in result.cases for s in case.states if name in s.errors]
        why = (f"it raised at {len(raised)} states, first: {raised[0]}" if raised
               else "it declined every case or was in BREAKDOWN everywhere")
        print(f"FAIL: backend {name} took part in no comparison ({why}); name it with --optional {name} if that "
              "is expected", file=sys.stderr)
    if result.self_test is not None:
        failures = result.self_test.failures()
        for line in failures:
            print(f"FAIL self-test: {line}", file=sys.stderr)
        print(f"self-test: {len(result.self_test.results) - len(failures)} of {len(result.self_test.results)} "
              "canaries caught and named", file=sys.stderr)
    print(f"{'PASS' if result.passed else 'FAIL'}: report written to {report} (details in {details})")
    return 0 if result.passed else 1


def _gate_progress(display: Display):
    """The gate's progress callback (``crosscheck.engine.phases.Step``) on ``display``: the states evaluated over every case,
    what runs now, and a line per case evaluated."""
    finished = 0

    def progress(step: phases.Step) -> None:
        nonlocal finished
        if step.phase == phases.DONE:
            finished += step.done
            display.note(f"  {step.text}")
        display.update(completed=finished + (0 if step.phase == phases.DONE else step.done))
        display.doing(step.text)

    return progress


def _interrupted(detail: str = "") -> int:
    """Ctrl-C: one line on stderr (``detail``: where the run stopped, what it left behind); exit code 130."""
    print("crosscheck: interrupted" + (f" {detail}" if detail else ""), file=sys.stderr)
    return INTERRUPTED


def _jsonable(value):
    if dataclasses.is_dataclass(value) and not isinstance(value, type):
        return {f.name: _jsonable(getattr(value, f.name)) for f in dataclasses.fields(value)}
    if isinstance(value, np.ndarray):
        return value.tolist()
    if isinstance(value, dict):
        return {k: _jsonable(v) for k, v in value.items()}
    if isinstance(value, (np.floating, np.integer)):
        return value.item()
    if value is None or isinstance(value, (int, float, str, list)):
        return value
    return repr(value)


def _length(values: list[float], size: int, label: str) -> np.ndarray:
    if len(values) != size:
        raise UsageError(f"--{label} has {len(values)} entries; this model needs {size}")
    return np.array(values)


def _inputs(args, model, chart, p) -> tuple[np.ndarray, np.ndarray]:
    """(u, tau_p): the actuator inputs and the generalized force in the chart, from ``--u`` or ``--tau``."""
    if args.u is not None and args.tau is not None:
        raise UsageError("give either --u (actuator inputs) or --tau (generalized force in the chart), not both")
    if args.tau is None:
        u = _length(_vector(args.u, "u"), model.m, "u") if args.u is not None else np.zeros(model.m)
        return u, charts.force_to_chart(chart, p, model.input_map @ u)
    tau_p = _length(_vector(args.tau, "tau"), model.n, "tau")
    tau_q = charts.force_from_chart(chart, p, tau_p)
    u, *_ = np.linalg.lstsq(model.input_map, tau_q, rcond=None)
    off = float(np.abs(model.input_map @ u - tau_q).max())
    if off > 1e-9 * (1.0 + float(np.abs(tau_q).max())):
        raise UsageError(f"--tau is not a force the inputs can produce: in joint coordinates it is {tau_q.tolist()}, "
                         f"and the nearest B u misses it by {off:.3g} (the model has {model.m} inputs for "
                         f"{model.n} joints)")
    return u, tau_p


def _chart_split(backend, model, chart, p, pd, u, tau_p) -> tuple[str, object]:
    """(how it was evaluated, split in the chart). A joint-chart answer is mapped into the chart."""
    q = chart.q_of(p)
    qd = chart.jacobian(p) @ pd
    if chart.name == "identity":
        return "joint chart", backend.split(model, q, qd, u)
    if backend.split_chart is not None:
        return f"in chart {chart.name}", backend.split_chart(model, chart, p, pd, tau_p)
    split = backend.split(model, q, qd, u)
    mapped = {name: charts.acceleration_to_chart(chart, p, pd, getattr(split, name), with_rate=name != "ctrl")
              for name in ("drift", "ctrl", "total")}
    return "joint chart, mapped by Dpsi^-1", dataclasses.replace(split, **mapped)


def _non_finite(split) -> list[str]:
    """The fields of ``split`` holding NaN or inf at a finite state: the backend failed, unless a condition it
    reports in BREAKDOWN covers the field (a task singularity's Lambda is inf; ``tolerance.left_out``)."""
    broken = policy.breakdown(split)
    if policy.whole(broken):
        return []
    excused = policy.left_out(broken) | {"conditions"}
    return [key for key in split.__dataclass_fields__ if key not in excused
            and isinstance(value := getattr(split, key), (float, np.ndarray)) and not np.all(np.isfinite(value))]


def _chart_splits(model, chart, p, pd, u, tau_p, chosen):
    """Per backend: (how it was evaluated, split in the chart); the backends written for other models
    (``ModelNotSupported``): name -> their reason; and the backends that failed at this valid state (raised, or
    answered NaN or inf): name -> what happened, as the gate reports a backend error."""
    out, unsupported, errors = {}, {}, {}
    for backend in chosen:
        try:
            out[backend.name] = _chart_split(backend, model, chart, p, pd, u, tau_p)
        except ModelNotSupported as exc:
            unsupported[backend.name] = str(exc)
            continue
        except Exception as exc:  # a backend that raises on a valid state has failed: report it, exit 1
            errors[backend.name] = f"{type(exc).__name__}: {_one_line(exc)}"
            continue
        bad = _non_finite(out[backend.name][1])
        if bad:
            errors[backend.name] = f"non-finite values (NaN or inf) in {', '.join(bad)}"
    return out, unsupported, errors


#: eval accepts a constrained state when |phi| and |Jc qd| are below this times the model's length scale squared
#: (times 1 + |qd|_1 for the velocity): loose enough for states pasted from a report, tight against a wrong one.
ADMISSIBLE = 1e-9


def _constraint_rows(model) -> list[str]:
    return [c.name if c.size == 1 else f"{c.name}[{i}]" for c in model.constraints for i in range(c.size)]


def _admissible(model, chart, p, pd, project: bool) -> tuple[np.ndarray, np.ndarray]:
    """(p, pd) when the state satisfies the constraints (article 5.1: phi(q) = 0 and Jc qd = 0); with ``project``
    the state moved onto the manifold and its tangent space; otherwise a UsageError saying how far off it is."""
    from crosscheck.references.pinocchio.kinematics import constraint_kinematics

    q, qd = chart.q_of(p), chart.jacobian(p) @ pd
    phi, Jc, _ = constraint_kinematics(model, q, qd)
    vel = Jc @ qd
    scale = model.length_scale ** 2
    tol_q, tol_v = ADMISSIBLE * scale, ADMISSIBLE * scale * (1.0 + float(np.abs(qd).sum()))
    if np.abs(phi).max() <= tol_q and np.abs(vel).max() <= tol_v:
        return p, pd
    if not project:
        rows = _constraint_rows(model)
        worst_q, worst_v = rows[int(np.abs(phi).argmax())], rows[int(np.abs(vel).argmax())]
        raise UsageError(f"the state is not admissible for model '{model.name}' (article 5.1): |phi(q)|_inf = "
                         f"{np.abs(phi).max():.3g} (row {worst_q}; allowed {tol_q:.1g}), |Jc qd|_inf = "
                         f"{np.abs(vel).max():.3g} (row {worst_v}; allowed {tol_v:.1g}); give a state on the "
                         "constraint manifold or pass --project to move it there (q by Gauss–Newton, qd onto the "
                         "tangent space)")
    q = sampling.project_configuration(model, q)
    qd = sampling.project_velocity(model, q, qd)
    p = chart.p_of(q)
    pd = charts.velocity_to_chart(chart, p, qd)
    print(f"projected onto the constraint manifold: q = {p.tolist()}, qd = {pd.tolist()}", file=sys.stderr)
    return p, pd


def cmd_eval(args) -> int:
    if args.case and args.model:
        raise UsageError("give either --case or --model, not both")
    if not args.case and not args.model:
        raise UsageError("eval needs --case NAME or --model PATH")
    spec = _specs(argparse.Namespace(case=[args.case] if args.case else [], model=[args.model] if args.model else [],
                                     base=args.base, actuated=args.actuated, task_point=args.task_point,
                                     param=args.param))[0]
    model = spec.build()
    preflight.check_model(model)
    if args.frame is not None:
        model = frames.move_scene(model, _frame(args.frame, args.seed, spec.name))
    chart = charts.get(args.chart or "identity", model, args.seed, spec.name)
    on_q = chart.name == "identity" or isinstance(chart, charts.VelocityRepresentation)   # p is q itself (nq)
    p = _length(_vector(args.q, "q"), model.nq if on_q else model.n, "q")
    pd = _length(_vector(args.qd, "qd"), model.nv, "qd") if args.qd is not None else np.zeros(model.nv)
    if on_q:
        p = _unit_quaternions(model, p, args.normalize)
    _in_chart_domain(chart, p, pd)
    if model.constraints:
        p, pd = _admissible(model, chart, p, pd, args.project)
    for problem in sampling.outside_limits(model, p) if on_q else ():
        print(f"crosscheck: warning: {problem}; evaluated there all the same", file=sys.stderr)
    u, tau_p = _inputs(args, model, chart, p)
    chosen = _backends(args.formalism)
    closed = None if args.formalism else spec.closed_form()       # the case's closed form votes in the gate too
    splits, unsupported, errors = _chart_splits(model, chart, p, pd, u, tau_p, chosen + ([closed] if closed else []))
    out = {name: {key: _jsonable(getattr(split, key)) for key in split.__dataclass_fields__}
           for name, (_, split) in splits.items()}
    verdict = _eval_verdict(model, chart, p, pd, u, splits, errors, chosen)
    linear = _eval_linearize(model, chart, p, pd, u, splits, chosen, verdict) if args.linearize else None
    if args.json:
        print(json.dumps({"case": spec.name, "params": dict(spec.params), "chart": chart.name,
                          "frame": args.frame, "q": p.tolist(), "qd": pd.tolist(), "u": u.tolist(),
                          "tau": tau_p.tolist(), "formalisms": {name: _nulled(v) for name, v in out.items()},
                          "unsupported_quantities": {name: _unsupported_keys(v) for name, v in out.items()
                                                     if _unsupported_keys(v)},
                          "not_supported": unsupported, "errors": errors, "verdict": verdict,
                          **({"linearization": linear} if linear is not None else {})}, indent=1))
        return 1 if errors or verdict["agree"] is False else 0
    where = f" in chart {chart.name} (q = psi(p))" if chart.name != "identity" else ""
    if isinstance(chart, charts.VelocityRepresentation):
        where = f" in velocity representation {chart.name} (q as given, qd = w with v = T(q) w)"
    print(f"case {model.name}{where}: q = {p.tolist()}, qd = {pd.tolist()}, u = {u.tolist()}, "
          f"generalized force = {tau_p.tolist()}")
    for name, values in out.items():
        how, split = splits[name]
        broken = policy.breakdown(split)
        print(f"{name} ({how}):" + (" BREAKDOWN (" + ", ".join(
            f"cond {k} = {v:.3g} > {policy.BREAKDOWN_LIMITS[k]:.3g}" for k, v in broken.items()) + ")"
            if broken else ""))
        keys = ("drift", "ctrl", "total", "task_drift", "power_ctrl", "kinetic_energy", "task_inertia",
                "joint_wrenches", "joint_wrenches_drift", "cond_M", "conditions")
        if model.constraints:
            keys += ("lam", "lam_drift", "constraint_force", "power_constr", "power_constr_per_coord",
                     "constraint_rank")
        if model.loads:                   # the external loads' generalized force tau_ext and its power
            keys += ("external_force", "power_ext")
        for key in keys:
            print(f"  {key:22s} {values[key]}")
    for name, reason in unsupported.items():
        print(f"{name}: NOT COMPARED ({reason})")
    for name, error in errors.items():
        print(f"{name}: ERROR at this state: {error}")
    if linear is not None:
        _print_linearization(linear)
    print(f"verdict: {verdict['text']}")
    return 1 if errors or verdict["agree"] is False else 0


def _eval_linearize(model, chart, p, pd, u, splits: dict, chosen: list, verdict: dict) -> dict:
    """``eval --linearize``: each backend's A, B (eq. 11, ``crosscheck.checks.linearization``) and the eigenvalues of A, the
    reference's, and the gate's comparison of their blocks; a DISAGREE turns the verdict (joint chart only)."""
    if chart.name != "identity":
        raise UsageError("--linearize evaluates in the joint chart (the convention of formalisms.interface."
                         "Linearization); leave out --chart")
    state = sampling.State(0, tuple(p), tuple(pd), tuple(u))
    found, errors, unsupported = linearization.linearizations(model, state, chosen)
    trusted = [split for _, split in splits.values()]
    out = {"convention": "x = (dq, v), q (+) dq on Lie groups; A (2nv x 2nv), B (2nv x m)",
           "backends": {name: {"A": lin.A.tolist(), "B": lin.B.tolist(),
                               "eigenvalues": [[float(w.real), float(w.imag)] for w in lin.eigenvalues]}
                        for name, lin in found.items()},
           "not_supported": unsupported, "errors": errors, "checks": {}}
    if trusted:
        at = policy.scales(trusted, model, p, pd, u=u)
        comparisons = linearization.compared(model, state, found, unsupported, at)
        out["checks"] = {name: {"verdict": c.verdict, "worst_ratio": c.worst_ratio, "outlier": c.outlier}
                         for name, c in comparisons.items()}
        failing = [name for name, c in comparisons.items() if c.verdict == DISAGREE]
        if failing or errors:
            verdict.update(agree=False, text=verdict["text"] + f"; linearization DISAGREE: "
                           f"{', '.join(failing) or 'errors from ' + ', '.join(errors)}")
    return out


def _print_linearization(linear: dict) -> None:
    print(f"linearization ({linear['convention']}):")
    with np.printoptions(precision=6, suppress=False, linewidth=160):
        for name, lin in linear["backends"].items():
            print(f"{name}:\n  A =\n{np.array(lin['A'])}\n  B =\n{np.array(lin['B'])}")
            print("  eigenvalues of A: " + ", ".join(f"{re:.6g}{im:+.6g}i" for re, im in lin["eigenvalues"]))
    for name in linear["not_supported"]:
        print(f"{name}: linearization NOT COMPARED (no linearize)")
    for name, error in linear["errors"].items():
        print(f"{name}: ERROR in linearize: {error}")
    for name, c in linear["checks"].items():
        print(f"{name}: {c['verdict']} (worst ratio {c['worst_ratio']:.3g})"
              + (f", outlier {c['outlier']}" if c["outlier"] else ""))


def _unsupported_keys(values: dict) -> list[str]:
    return [key for key, value in values.items() if value == repr(UNSUPPORTED)]


def _nulled(values: dict) -> dict:
    """A backend's JSON fields with null for a quantity it does not supply (listed in ``unsupported_quantities``)."""
    return {key: None if value == repr(UNSUPPORTED) else value for key, value in values.items()}


def _eval_verdict(model, chart, p, pd, u, splits: dict, errors: dict, chosen: list) -> dict:
    """The gate's comparison of the backends at this state (``crosscheck.engine.evaluation.judge``: the tolerance table, the
    conditioning audit, the vote for an outlier) in the joint chart; in another chart or velocity representation the
    gate judges through the chart checks instead, so no verdict is given here. ``agree`` is None then, or when fewer
    than two answers can be compared."""
    if chart.name != "identity":
        return {"agree": None, "text": f"not judged in chart {chart.name} (the gate compares charts through its chart "
                                       "checks: run crosscheck gate)"}
    found = {name: (split, None) for name, (_, split) in splits.items()} | {n: (None, e) for n, e in errors.items()}
    outcome = evaluation.outcome_of(sampling.State(0, tuple(p), tuple(pd), tuple(u)), found)
    evaluation.judge(model, outcome, chosen)
    verdicts = [*outcome.comparisons.values(), *outcome.checks.values()]
    compared = [c for c in verdicts if len(c.voters) >= 2]
    failing = [c for c in verdicts if c.verdict == DISAGREE]
    worst = max((c.worst_ratio for c in compared), default=0.0)
    outliers = sorted({c.outlier for c in failing if c.outlier})
    if errors or failing:
        named = ", ".join(c.quantity for c in failing[:6]) + (", ..." if len(failing) > 6 else "")
        text = (f"DISAGREE: {named or 'errors'} (worst ratio {worst:.3g} of the tolerance"
                + (f"; outlier {', '.join(outliers)}" if outliers else "; no single outlier") + ")"
                + (f"; errors from {', '.join(errors)}" if errors else ""))
        return {"agree": False, "worst_ratio": worst, "outliers": outliers, "failing": [c.quantity for c in failing],
                "text": text}
    if not compared:
        return {"agree": None, "text": "nothing to compare (fewer than two backends answered)"}
    return {"agree": True, "worst_ratio": worst, "outliers": [], "failing": [],
            "text": f"agree (worst ratio {worst:.3g} of the tolerance, {len(compared)} quantities compared)"}


def _unit_quaternions(model, q: np.ndarray, normalize: bool) -> np.ndarray:
    """``q`` when its quaternions (spherical and free joints, ``(x, y, z, w)``) are unit; with ``normalize`` each
    divided by its norm; otherwise a UsageError naming each one that is not."""
    if normalize:
        try:
            return configuration.normalized(model, q)
        except ValueError as exc:
            raise UsageError(str(exc)) from None
    problems = configuration.quaternion_problems(model, q)
    if problems:
        raise UsageError("; ".join(problems) + " (or pass --normalize)")
    return q


def _in_chart_domain(chart, p, pd) -> None:
    """The chart maps (p, pd) to a finite joint state below the state limit, or a UsageError says it does not."""
    with np.errstate(all="ignore"):
        q, qd = chart.q_of(p), chart.jacobian(p) @ pd
        cond = float(np.linalg.cond(chart.jacobian(p))) if np.all(np.isfinite(p)) else 0.0
    if cond > charts.GIMBAL_LIMIT:
        raise UsageError(f"chart {chart.name} has lost a direction at this p (cond(Dpsi) = {cond:.3g}; for zyx: pitch "
                         "at +-pi/2, gimbal lock), so no coordinates of it can express the motion; evaluate in the "
                         "joint chart (leave out --chart) or at another p")
    if getattr(chart, "at_centre", None) is not None and np.all(np.isfinite(p)) and chart.at_centre(p):
        raise UsageError(f"chart {chart.name}: an orientation block of p is within {charts.EXP_CENTRE_LIMIT:g} of the "
                         "chart's centre (p = 0), where the chart-native backends' derivatives of psi are 0/0 "
                         "(sin(t/2)/t); evaluate at another p or in the joint chart (leave out --chart)")
    try:
        preflight.check_vector("q (mapped to joint coordinates)", q)
        preflight.check_vector("qd (mapped to joint coordinates)", qd)
    except preflight.PreflightError as exc:
        raise UsageError(f"chart {chart.name}: {exc}") from None


def _frame(name: str, seed: int, case: str) -> frames.Frame:
    if not (name.startswith("g") and name[1:].isdigit() and int(name[1:]) < MAX_FRAMES):
        raise UsageError(f"--frame takes a sampled frame name g0 ... g{MAX_FRAMES - 1} (as in the gate report), "
                         f"got '{name}'")
    return frames.sampled(seed, case, int(name[1:]) + 1)[-1]


DEFAULT_FAULTS_REPORT = f"{OUTPUT_DIR}/faults.md"


def _chosen_faults(args):
    """(backend faults, common-mode faults) named by ``--fault`` (either catalog), or both whole catalogs."""
    from crosscheck.faults import common_mode
    from crosscheck.faults import backend_catalog
    from crosscheck.faults import injection

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
    import time

    from crosscheck.faults import common_mode, sensitivity
    from crosscheck.faults import injection

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
    ``crosscheck.faults.common_mode``), appending to ``hunts`` and ``shared_hunts`` as each ends (so that an interrupted run
    keeps them); a line per fault on stdout. ``--workers`` (:func:`workers`, one process per fault at most): in this
    process, or in a pool (:func:`_hunt_in_pool`), with the same hunts in the same order."""
    from crosscheck.faults import common_mode
    from crosscheck.faults import injection

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


def _init_hunter() -> None:
    """A fault-hunting worker process: Ctrl-C ignored (the parent stops the pool), one BLAS thread."""
    import signal

    global _HUNTER_LIMITS
    signal.signal(signal.SIGINT, signal.SIG_IGN)
    _HUNTER_LIMITS = threadpool_limits(limits=BLAS_THREADS, user_api="blas")


_HUNTER_LIMITS = None


def _hunt_one(shared: bool, name: str, samples: int, seed: int, known):
    """One fault hunted in a worker process, found by name in its catalog. The hunt comes back without its fault (a
    fault holds its faulty function, which does not pickle): the parent puts it back."""
    from crosscheck.faults import common_mode
    from crosscheck.faults import backend_catalog
    from crosscheck.faults import injection

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

    from crosscheck.faults import common_mode
    from crosscheck.faults import injection
    from crosscheck.engine import workers as worker_processes

    ctx = multiprocessing.get_context("spawn")
    jobs = [(False, f) for f in chosen] + [(True, f) for f in shared]
    display.doing(f"{len(jobs)} faults in {count} worker processes")
    with worker_processes.spawning(), ctx.Pool(count, initializer=_init_hunter) as pool:
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
    from crosscheck.faults import injection
    from crosscheck.faults import sensitivity

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


def _shard(text: str) -> tuple[int, int]:
    index, sep, count = text.partition("/")
    if not (sep and index.isdigit() and count.isdigit()):
        raise UsageError(f"--shard takes i/N (e.g. 0/4), got '{text}'")
    return int(index), int(count)


def _fuzz_chunks(args) -> float:
    """The chunks this shard of the campaign runs (the units its ``--workers`` share out); inf for ``--minutes``."""
    from crosscheck.campaigns.fuzz import runs
    from crosscheck.campaigns.fuzz import replay
    from crosscheck.campaigns.fuzz import settings
    from crosscheck.reports import fuzz_report

    if args.minutes is not None:
        return float("inf")
    index, count = _shard(args.shard)
    chunks = math.ceil((args.examples or settings.DEFAULT_EXAMPLES) / max(args.chunk_examples or settings.CHUNK_EXAMPLES, 1))
    return len(range(index, chunks, count)) if count else 0   # a bad shard or count: settings.config says what is wrong


def cmd_fuzz(args) -> int:
    from crosscheck.campaigns.fuzz import runs
    from crosscheck.campaigns.fuzz import replay
    from crosscheck.campaigns.fuzz import settings
    from crosscheck.reports import fuzz_report

    if args.examples is not None and args.minutes is not None:
        raise UsageError("give either --examples or --minutes, not both")
    if args.minutes is not None and not 0.0 < args.minutes < np.inf:
        raise UsageError(f"--minutes takes a positive, finite number of minutes, got {args.minutes}")
    bound = {"examples": args.examples, "minutes": args.minutes}
    if args.examples is None and args.minutes is None:
        bound["examples"] = settings.DEFAULT_EXAMPLES
    if args.chunk_examples is not None:
        bound["chunk_examples"] = args.chunk_examples
    try:
        cfg = settings.config(seed=args.seed, workers=workers(args.workers, _fuzz_chunks(args)), shard=_shard(args.shard),
                          out=args.out,
                          backends=tuple(args.formalism or ()), plugins=backends.plugin_specs(),
                          max_bodies=args.max_bodies, max_states=args.max_states,
                          constraints=settings.CONSTRAINT_CHOICES[args.constraints],
                          loads=settings.CONSTRAINT_CHOICES[args.loads],
                          group_joints=args.joints == "all", charts=not args.no_charts,
                          frames=not args.no_frames, conservation=not args.no_conservation,
                          linearization=not args.no_linearization, pfaffian=args.pfaffian, **bound)
        result = runs.run_campaign(cfg, "crosscheck " + " ".join(shlex.quote(a) for a in args.argv), args.quiet)
    except settings.FuzzError as exc:
        raise UsageError(str(exc)) from None
    print(fuzz_report.summary(result))
    if result.interrupted:
        return _interrupted("(the chunks in flight saved what they held); report written to "
                            f"{result.out / 'report.md'}; the same command again resumes the campaign")
    return 1 if result.findings else 0


def cmd_replay(args) -> int:
    from crosscheck.campaigns.fuzz import runs
    from crosscheck.campaigns.fuzz import replay
    from crosscheck.campaigns.fuzz import settings
    from crosscheck.reports import fuzz_report
    from crosscheck.testing import describe_failure

    try:
        finding = replay.find(Path(args.dir), args.id)
    except settings.FuzzError as exc:
        raise UsageError(str(exc)) from None
    missing = [name for name in (args.formalism or finding["backends"]) if name not in backends.names()]
    if missing:
        command = fuzz_report.replay_command(finding["id"], Path(args.dir), fuzz_report.campaign_plugins(Path(args.dir)))
        raise UsageError(f"finding {finding['id']} was evaluated with backend(s) {', '.join(missing)}, not loaded "
                         f"here; run `{command}`")
    outcome = replay.replay(finding, args.formalism)
    print(f"finding {finding['id']} (chunk {finding['campaign']['chunk']} of the campaign with seed "
          f"{finding['campaign']['seed']}), chart {finding['chart']['name']}, frame {finding['frame']['name']}:")
    if outcome.failed:
        print("FAILS " + describe_failure(outcome))
        return 1
    worst = max((c.worst_ratio for c in [*outcome.comparisons.values(), *outcome.checks.values()]), default=0.0)
    print(f"passes now: {len(outcome.comparisons) + len(outcome.checks)} comparisons and checks agree, worst "
          f"error/tolerance {worst:.3g}")
    return 0


def cmd_merge(args) -> int:
    from crosscheck.campaigns.fuzz import runs
    from crosscheck.campaigns.fuzz import replay
    from crosscheck.campaigns.fuzz import settings
    from crosscheck.reports import fuzz_report

    try:
        result = runs.merge([Path(d) for d in args.dirs], Path(args.out),
                            "crosscheck " + " ".join(shlex.quote(a) for a in args.argv))
    except settings.FuzzError as exc:
        raise UsageError(str(exc)) from None
    print(fuzz_report.summary(result))
    return 1 if result.findings else 0


def cmd_stability(args) -> int:
    """``crosscheck stability``: true errors, condition numbers and the gate's verdicts along paths into trouble
    (``crosscheck.campaigns.stability``), written to DIR/stability.md and its charts. Exit 0: it measures."""
    from crosscheck.reports import stability_report

    preflight.claim_directory(args.out, "out")
    report = stability_report.write_report(Path(args.out), quick=args.quick,
                                           progress=lambda path, i, n: print(f"{path}: {i}/{n}", file=sys.stderr,
                                                                             flush=True))
    print(f"stability: {report}")
    return 0


def cmd_bench(args) -> int:
    """``crosscheck bench``: time and error of every backend (DIR/speed_accuracy.md and its charts), then the
    stability maps (DIR/stability.md), so one command regenerates both reports. Exit 0: it measures."""
    from crosscheck.campaigns import bench
    from crosscheck.reports import bench_report

    preflight.claim_directory(args.out, "out")
    if args.scale:
        return _bench_scale(args)
    plan = bench.QUICK if args.quick else bench.FULL
    names = args.formalism or None
    for name in names or []:
        backends.get(name)
    with Display("bench", "steps", bench.steps(plan, names or backends.names()), quiet=args.quiet) as display:
        try:
            results = bench.run(plan, names, getattr(args, "plugin", []), display)
        except bench.Interrupted as stop:
            path = bench_report.write(stop.results, Path(args.out), stop.where)
            return _interrupted(f"while {stop.where}; partial report written to {path}")
        speed = bench_report.write(results, Path(args.out))
        print(f"speed and accuracy: {speed}")
        if not args.no_stability:
            try:
                print(f"stability: {_stability_maps(args.out, args.quick, display)}")
            except KeyboardInterrupt:
                return _interrupted(f"during the stability maps; {speed} is complete, stability.md not updated")
    return 0


def _bench_scale(args) -> int:
    """``crosscheck bench --scale``: large robots and campaigns as whole processes (DIR/scale.md)."""
    from crosscheck.campaigns import scale

    plan = scale.QUICK if args.quick else scale.FULL
    with Display("bench --scale", "steps", scale.steps(plan), quiet=args.quiet) as display:
        try:
            results = scale.run(plan, display)
        except KeyboardInterrupt:
            return _interrupted("scale measurements not written")
    print(f"scale: {scale.write(results, Path(args.out))}")
    return 0


def _stability_maps(out: str, quick: bool, display: Display) -> Path:
    """The stability maps (``crosscheck.campaigns.stability``), a step on ``display`` per point; the report's path."""
    from crosscheck.campaigns import stability
    from crosscheck.reports import stability_report

    display.stage("stability points", sum(len(p.points) for p in stability.paths(quick, backends.names())))

    def measured(path: str, done: int, count: int) -> None:
        display.advance()
        display.doing(f"stability: {path} {done}/{count}")

    return stability_report.write_report(Path(out), quick=quick, progress=measured)


#: The committed reports (in :data:`REPORTS_DIR`) and the command that writes each there: ``crosscheck reports``
#: runs these, so the reports carry the command that regenerates them.
REPORTS = {
    "gate": ["gate", "--report", f"{REPORTS_DIR}/gate.md"],
    "faults": ["faults", "--report", f"{REPORTS_DIR}/faults.md"],
    "bench": ["bench", "--no-stability", "--out", REPORTS_DIR],
    "stability": ["stability", "--out", REPORTS_DIR],
    "scale": ["bench", "--scale", "--out", REPORTS_DIR],
    "trajectories": ["trajectory", "--report", REPORTS_DIR],
}
#: The commands of :data:`REPORTS` that take ``--quiet``.
QUIET = ("gate", "faults", "bench", "scale")


def _only(text: str) -> list[str]:
    """``--only a,b``: report names of :data:`REPORTS`, in the order given."""
    names = [name.strip() for name in text.split(",") if name.strip()]
    unknown = [name for name in names if name not in REPORTS]
    if unknown or not names:
        raise UsageError(f"--only takes report names separated by commas from {', '.join(REPORTS)}; got '{text}'")
    return list(dict.fromkeys(names))


def cmd_reports(args) -> int:
    """``crosscheck reports``: regenerate the committed reports in :data:`REPORTS_DIR` by running each report's own
    command (:data:`REPORTS`) in turn. Exit 0 when each command exits 0, 130 at Ctrl-C (the reports not yet run keep
    their old contents), else 1 (a failing gate or fault hunt still writes its report)."""
    chosen = _only(args.only) if args.only else list(REPORTS)
    if not Path(REPORTS_DIR).is_dir():
        raise UsageError(f"there is no {REPORTS_DIR}/ directory here ({Path.cwd()}): run crosscheck reports from the "
                         "repository's root, where the committed reports are")
    codes = {}
    for name in chosen:
        argv = REPORTS[name] + (["--quiet"] if args.quiet and name in QUIET else [])
        print(f"reports: {name}: crosscheck {' '.join(argv)}", flush=True)
        sub = build_parser().parse_args(argv)
        sub.argv = argv
        codes[name] = sub.run(sub)
        if codes[name] == INTERRUPTED:
            return _interrupted(f"while regenerating {name}; not run: {', '.join(chosen[len(codes):]) or 'none'}")
    failed = [name for name, code in codes.items() if code]
    print(f"reports: {len(chosen)} regenerated in {REPORTS_DIR}/" + (f"; exit non-zero: {', '.join(failed)}"
                                                                     if failed else ""))
    return 1 if failed else 0


def add_reports_parser(sub) -> None:
    rep = sub.add_parser("reports", help=f"regenerate the committed reports in {REPORTS_DIR}/ (every other command "
                         f"writes to {OUTPUT_DIR}/ by default)")
    rep.add_argument("--only", metavar="NAMES", help=f"comma-separated, from {', '.join(REPORTS)} (default: all; "
                     "each a full run: the faults took about 17 minutes on 2 CPUs in one process)")
    rep.add_argument("--quiet", action="store_true", help="no progress on stderr")
    rep.set_defaults(run=cmd_reports)


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
    sub.add_parser("cases", help="list the built-in cases and their parameters").set_defaults(run=cmd_cases)
    listing = sub.add_parser("formalisms", help="list the formalisms, the reference and the plugins")
    add_plugin_option(listing)
    listing.set_defaults(run=cmd_formalisms)

    gate = sub.add_parser("gate", help="sample states per case, compare every backend, write a report")
    gate.add_argument("--case", action="append", default=[], help="a built-in case (repeatable; default: all)")
    gate.add_argument("--param", action="append", default=[], metavar="K=V", help="case parameter (one --case)")
    gate.add_argument("--model", action="append", default=[], metavar="PATH",
                      help="a URDF (.urdf) or MJCF (.xml) file (repeatable)")
    gate.add_argument("--base", choices=("fixed", "free"),
                      help="a URDF's base: welded to the world, or on a free joint (default: as the file says)")
    gate.add_argument("--actuated", metavar="JOINTS", help="a URDF's actuated joints, comma-separated, in the order "
                      "of u (default: every joint but a free base's)")
    gate.add_argument("--samples", type=int, default=DEFAULT_SAMPLES,
                      help=f"states per case (default {DEFAULT_SAMPLES})")
    gate.add_argument("--seed", type=_seed, default=0, help="random seed (default 0)")
    gate.add_argument("--formalism", action="append", help="restrict to these backends (repeatable)")
    gate.add_argument("--report", default=DEFAULT_REPORT, metavar="PATH",
                      help=f"markdown report path (default {DEFAULT_REPORT}); its details go next to it, "
                           "NAME-details.md")
    gate.add_argument("--frames", type=int, default=2, help="rigid frame changes per case (default 2; 0: off)")
    gate.add_argument("--no-charts", action="store_true", help="skip the chart invariance checks")
    gate.add_argument("--no-conservation", action="store_true", help="skip the energy and Christoffel checks")
    gate.add_argument("--no-linearization", action="store_true",
                      help="skip the comparison of the linearizations A, B (eq. 11) at the first states of each case")
    gate.add_argument("--no-closed-forms", action="store_true",
                      help="leave the article's closed forms (voter closed_form) out of the vote")
    gate.add_argument("--ignore-limits", action="store_true", help="draw the states freely, also where a model "
                      "(a URDF or MJCF file) declares joint limits (default: within them)")
    gate.add_argument("--no-self-test", action="store_true",
                      help="skip the self-test canaries (known tiny faults the gate must catch)")
    gate.add_argument("--optional", action="append", default=[], metavar="NAME",
                      help="a backend named with --formalism or --plugin that may take part in no comparison "
                           "(otherwise that fails the run)")
    gate.add_argument("--registry", metavar="PATH", help="divergence registry of known, explained divergences "
                      f"(default: {divergences.DEFAULT_PATH} in the current directory, if present)")
    gate.add_argument("--no-registry", action="store_true", help="use no divergence registry")
    gate.add_argument("--junit", metavar="PATH", help="also write a JUnit XML report there")
    add_workers_option(gate, "case")
    add_task_point_option(gate)
    add_plugin_option(gate)
    add_quiet_option(gate)
    gate.set_defaults(run=cmd_gate)

    ev = sub.add_parser("eval", help="evaluate the backends at one state")
    ev.add_argument("--case", help="a built-in case")
    ev.add_argument("--param", action="append", default=[], metavar="K=V", help="case parameter (repeatable)")
    ev.add_argument("--model", metavar="PATH", help="a URDF (.urdf) or MJCF (.xml) file instead of --case")
    ev.add_argument("--base", choices=("fixed", "free"),
                    help="a URDF's base: welded to the world, or on a free joint (default: as the file says)")
    ev.add_argument("--actuated", metavar="JOINTS", help="a URDF's actuated joints, comma-separated, in the order "
                    "of u (default: every joint but a free base's)")
    ev.add_argument("--q", required=True, help="positions in the chart (joint positions by default; q itself with "
                    "--chart world or mixed), comma-separated")
    ev.add_argument("--qd", help="velocities in the chart (default zeros; with --chart world or mixed the base "
                    "velocity w in that representation, v = T(q) w)")
    ev.add_argument("--u", help="actuator inputs, one per column of B (default zeros)")
    ev.add_argument("--tau", help="instead of --u: the generalized force in the chart (a covector, n entries)")
    ev.add_argument("--chart", choices=charts.names(),
                    help="evaluate in this chart q = psi(p) (default identity; zyx and exp: the charts of spherical "
                         "and free joints, p with one entry per velocity)")
    ev.add_argument("--frame", help="move the scene by the gate's sampled frame g0, g1, ... (with --seed)")
    ev.add_argument("--seed", type=_seed, default=0,
                    help="seed of the gate run (the affine chart, the exp chart's centres, the frames)")
    ev.add_argument("--formalism", action="append", help="restrict to these backends (repeatable)")
    ev.add_argument("--project", action="store_true",
                    help="constrained case: move the state onto the constraint manifold first (else it is refused)")
    ev.add_argument("--normalize", action="store_true",
                    help="divide each quaternion of --q (spherical and free joints) by its norm (else a quaternion "
                         "that is not unit is refused)")
    ev.add_argument("--linearize", action="store_true",
                    help="also print each backend's linearization A, B (eq. 11) and the eigenvalues of A, compared")
    ev.add_argument("--json", action="store_true", help="print JSON")
    add_task_point_option(ev)
    add_plugin_option(ev)
    ev.set_defaults(run=cmd_eval)

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

    fz = sub.add_parser("fuzz", help="fuzzing campaign: random models and states, failures shrunk and saved")
    fz.add_argument("--examples", type=int, help="examples to generate over all shards (default 100 when --minutes "
                    "is not given)")
    fz.add_argument("--minutes", type=float, help="run for this long instead (the chunks in flight then finish)")
    fz.add_argument("--seed", type=_seed, default=0, help="campaign seed (default 0)")
    add_workers_option(fz, "chunk")   # a worker is replaced every few chunks: that bounds a campaign's memory
    fz.add_argument("--shard", default="0/1", metavar="i/N", help="run the chunks k with k %% N == i (default 0/1)")
    fz.add_argument("--out", default=DEFAULT_FUZZ_DIR, metavar="DIR",
                    help=f"campaign directory: findings, chunk log, report.md (default {DEFAULT_FUZZ_DIR})")
    fz.add_argument("--formalism", action="append", help="restrict to these backends (repeatable)")
    fz.add_argument("--max-bodies", type=int, default=4, help="largest drawn model (default 4 bodies)")
    fz.add_argument("--chunk-examples", type=int, default=None, metavar="N",
                    help="examples per chunk (part of the campaign's identity; default 10)")
    fz.add_argument("--max-states", type=int, default=4, help="states per drawn model (default up to 4)")
    fz.add_argument("--constraints", choices=["never", "sometimes", "always"], default="sometimes",
                    help="constrained models (default sometimes)")
    fz.add_argument("--pfaffian", action="store_true",
                    help="the drawn constraints may also be Pfaffian: knife edges, point velocities, rolling contacts")
    fz.add_argument("--loads", choices=["never", "sometimes", "always"], default="sometimes",
                    help="models with external loads: forces, wrenches, springs (default sometimes)")
    fz.add_argument("--joints", choices=["all", "scalar"], default="all",
                    help="joint types drawn: all (revolute, prismatic, spherical, free; default) or scalar (revolute "
                         "and prismatic only)")
    fz.add_argument("--no-charts", action="store_true", help="skip the chart invariance checks")
    fz.add_argument("--no-frames", action="store_true", help="skip the frame invariance checks")
    fz.add_argument("--no-conservation", action="store_true", help="skip the energy and Christoffel checks")
    fz.add_argument("--no-linearization", action="store_true",
                    help="skip the comparison of the linearizations A, B (eq. 11) at each example's first state")
    add_plugin_option(fz)
    add_quiet_option(fz)
    fz.set_defaults(run=cmd_fuzz)

    rp = sub.add_parser("replay", help="evaluate a saved fuzzing finding again")
    rp.add_argument("id", help="the finding's ID (or a unique prefix), as in the campaign report")
    rp.add_argument("--dir", default=DEFAULT_FUZZ_DIR, help=f"campaign directory (default {DEFAULT_FUZZ_DIR})")
    rp.add_argument("--formalism", action="append", help="evaluate these backends instead of the finding's")
    add_plugin_option(rp)
    rp.set_defaults(run=cmd_replay)

    mg = sub.add_parser("merge", help="combine the directories of fuzzing shards into one, with its report")
    mg.add_argument("dirs", nargs="+", metavar="DIR", help="campaign directories (shards of one campaign)")
    mg.add_argument("--out", required=True, metavar="DIR", help="the merged campaign directory")
    mg.set_defaults(run=cmd_merge)

    bn = sub.add_parser("bench", help="speed against accuracy of every backend, stability maps (speed_accuracy.md, "
                        "stability.md and their charts)", description="Runs in this process, no --workers: the "
                        "timings need the machine as quiet as it gets.")
    bn.add_argument("--quick", action="store_true", help="few scenes, states and repeats (CI; about a minute)")
    bn.add_argument("--out", default=OUTPUT_DIR, metavar="DIR", help=f"report directory (default {OUTPUT_DIR})")
    bn.add_argument("--formalism", action="append", help="restrict to these backends (repeatable)")
    bn.add_argument("--no-stability", action="store_true", help="skip the stability maps (DIR/stability.md)")
    bn.add_argument("--scale", action="store_true", help="instead: the gate on tiago, g1 and solo12, Euler–Lagrange "
                    "preparation against joints, fuzz throughput, each a whole process (DIR/scale.md)")
    add_plugin_option(bn)
    add_quiet_option(bn)
    bn.set_defaults(run=cmd_bench)

    st = sub.add_parser("stability", help="true errors and condition numbers along paths into trouble "
                        "(stability.md)")
    st.add_argument("--quick", action="store_true", help="a few points per path (CI; well under a minute)")
    st.add_argument("--out", default=OUTPUT_DIR, metavar="DIR", help=f"report directory (default {OUTPUT_DIR})")
    st.set_defaults(run=cmd_stability)
    from crosscheck.cli import trajectory_cli
    trajectory_cli.add_parser(sub, _Parser, OUTPUT_DIR, add_workers_option)
    add_reports_parser(sub)
    return parser


#: BLAS threads for a command. Every matrix here is tiny (n <= 30); a threaded BLAS level-3 call on one (e.g. a
#: triangular solve with a few right-hand sides) costs milliseconds in thread hand-off on a busy 2-core machine:
#: a constrained Euler–Lagrange split measured 40 ms with the default threads, 1 ms with one.
BLAS_THREADS = 1


def _notice(message, category, filename, lineno, file=None, line=None) -> None:
    """A loader's notice (``cases.urdf.BaseNotice``) or the gate's (``gate.PreparationNotice``) as one line; other
    warnings as Python prints them."""
    from crosscheck.engine.run import PreparationNotice

    if issubclass(category, (cases.urdf.BaseNotice, PreparationNotice)):
        print(f"crosscheck: notice: {message}", file=sys.stderr if file is None else file)
    else:
        _show_warning(message, category, filename, lineno, file, line)


_show_warning = warnings.showwarning


def main(argv: list[str] | None = None) -> int:
    with warnings.catch_warnings():     # the loaders' notices as one line each, for this command only
        warnings.showwarning = _notice
        return _main(argv)


def _main(argv: list[str] | None) -> int:
    argv = list(sys.argv[1:] if argv is None else argv)
    try:
        args = build_parser().parse_args(argv)
        args.argv = argv
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

