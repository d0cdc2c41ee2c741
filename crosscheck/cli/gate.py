"""``crosscheck gate``: sample states per case, compare every backend, write the report (a summary and a details
file, a JUnit file on request) and a line per case (with, for a failing case, the ``crosscheck eval`` command that
reproduces its first failing state), the run's progress on the display.

Exit codes: 0 the gate passed, 1 it failed (a disagreement, a backend error, ...), 2 bad input (refused before the
run), 3 the harness itself failed (an internal error: ``crosscheck.engine.internal``; the report is written all the same,
with a section saying where, and the exit is 3 whatever else failed), 130/143 interrupted."""

from __future__ import annotations

import shlex
import sys

from crosscheck import backends
from crosscheck.cli.options import (MAX_FRAMES, OUTPUT_DIR, _backends, _interrupted, _registry, _seed, _specs,
                                    add_plugin_option, add_quiet_option, add_task_point_option, add_workers_option,
                                    UsageError, workers)
from crosscheck.core.compare import KNOWN, worst_of
from crosscheck.engine import divergences, internal, phases, run
from crosscheck.engine.outcomes import GateResult
from crosscheck.engine.progress import Display
from crosscheck.engine.run import run_gate
from crosscheck.engine.specs import DEFAULT_SAMPLES, Checks
from crosscheck.guards import preflight
from crosscheck.reports import diagnosis, gate_summary, junit
from crosscheck.reports.gate_lines import canary_count, reproduce_command, task_point_lines

DEFAULT_REPORT = f"{OUTPUT_DIR}/gate.md"
#: The exit code of a run where the harness itself failed (module doc).
INTERNAL_ERROR = 3


def _required(args) -> list[str]:
    """The backends named on the command line (``--formalism``, ``--plugin``) and not ``--optional``: each must take
    part in some comparison."""
    named = list(args.formalism or []) + [backends.load_plugin(spec).name for spec in args.plugin]
    for name in args.optional:
        if name not in named:
            raise UsageError(f"--optional {name}: name it with --formalism or --plugin as well (named: "
                             f"{', '.join(named) or 'none'})")
    return [name for name in dict.fromkeys(named) if name not in args.optional]


def _allowed_breakdown(args, chosen) -> tuple[str, ...]:
    """The backends that may be in BREAKDOWN at most states of a case: ``--allow-breakdown`` (a backend of the run)
    and ``--optional``."""
    names = [b.name for b in chosen]
    for name in args.allow_breakdown:
        if name not in names:
            raise UsageError(f"--allow-breakdown {name}: not a backend of this run ({', '.join(names)})")
    return tuple(dict.fromkeys([*args.allow_breakdown, *args.optional]))


def _model_findings(model, strict: bool) -> None:
    """A model's findings (``Model.findings``: physically impossible data that still gives a positive-definite M):
    one notice line each, or with ``--strict-model`` a refusal."""
    if strict and model.findings:
        raise UsageError(f"--strict-model: model '{model.name}' has {len(model.findings)} finding(s): "
                         f"{'; '.join(model.findings)}; fix the file, or leave --strict-model out to compare the "
                         "backends on it with the findings reported")
    for finding in model.findings:
        print(f"crosscheck: model finding: {model.name}: {finding}", file=sys.stderr)


def cmd_gate(args) -> int:
    return gated(args)[0]


def gated(args) -> tuple[int, GateResult]:
    """Run the gate of ``args`` (the ``gate`` subcommand's options), write its report and lines: the exit code and
    the result (``crosscheck simulators`` reads it further)."""
    if args.samples < 1:
        raise UsageError("--samples must be at least 1")
    if not 0 <= args.frames <= MAX_FRAMES:
        raise UsageError(f"--frames takes 0 (off) to {MAX_FRAMES} frame changes per case, got {args.frames}")
    specs = _specs(args)
    count = workers(args.workers, len(specs))
    chosen = _backends(args.formalism)
    for model in [spec.build() for spec in specs]:  # every model first, so bad input fails before any work
        preflight.check_model(model)
        _model_findings(model, args.strict_model)
    known = _registry(args)
    placeholder = "# crosscheck gate\n\nThe run writing this report has not finished (interrupted or failed).\n"
    report = preflight.claim_output(args.report, "report", placeholder)
    preflight.claim_output(gate_summary.details_path(report), "report (its details file)", placeholder)
    if args.junit:
        preflight.claim_output(args.junit, "junit", "")
    checks = Checks(charts=not args.no_charts, frames=args.frames, conservation=not args.no_conservation,
                    closed_forms=not args.no_closed_forms, self_test=not args.no_self_test,
                    linearization=not args.no_linearization, joint_limits=not args.ignore_limits)
    required, allowed = _required(args), _allowed_breakdown(args, chosen)
    with Display("gate", "states", args.samples * len(specs), quiet=args.quiet) as display:
        try:
            result = run_gate(specs, chosen, args.samples, args.seed, _gate_progress(display), checks,
                              workers=count, required=required, allow_breakdown=allowed)
        except run.Interrupted as stop:
            result = stop.result
        except run.INPUT_ERRORS:
            raise
        except Exception as exc:  # noqa: BLE001 - the harness failing outside every guard: reported, exit 3
            result = GateResult(args.seed, args.samples, tuple(b.name for b in chosen), [], checks, tuple(required),
                                allow_breakdown=allowed, internal={"run": internal.of(exc)})
    command = "crosscheck " + " ".join(shlex.quote(a) for a in args.argv)
    written: list[bool] = []
    try:
        return _report(args, result, chosen, known, report, command, written), result
    except Exception as exc:  # noqa: BLE001 - the report is written whatever happens, and the exit says why
        check = "terminal lines" if written else "report"
        result.internal.setdefault(check, internal.of(exc))
        if not written:
            report.write_text(gate_summary.write_fallback(result, command))
        print(f"FAIL {internal.Occurrence(check, result.internal[check]).describe()}")
        print(f"FAIL: the harness itself failed; report written to {report}")
        return INTERNAL_ERROR, result


def _report(args, result: GateResult, chosen, known, report, command: str, written: list[bool]) -> int:
    """After the run: the registry applied, the hints, the report, the JUnit file and the lines on the terminal; the
    exit code. The harness failing in one of them is the run's internal error (``crosscheck.engine.internal``);
    ``written`` gets an entry once the report is."""
    applied = None
    if known:
        with internal.guarded(result.internal, "divergence registry"):
            applied = divergences.apply(known, result)
    if result.interrupted:   # what completed, without the hints (they evaluate again): the user wants out
        gate_summary.write(result, command, report, applied)
        return _interrupted(f"{result.interrupted}; partial report written to {report}")
    diagnosis.annotate(result, chosen)
    figures = {}
    with internal.guarded(result.internal, "report: pictures"):
        figures = gate_summary.mechanism_figures(result, report)
    if args.junit:           # before the report: a failure in writing it is in the report
        with internal.guarded(result.internal, "junit"):
            junit.write(result, args.junit)
    _, details = gate_summary.write(result, command, report, applied, figures)
    written.append(True)
    for entry in applied.stale if applied else ():
        print(f"crosscheck: warning: stale {entry.describe()} in {applied.registry.source}: compared in this run "
              "but explained no disagreement", file=sys.stderr)
    for case in result.cases:
        bad = sum(s.failed for s in case.states)
        broken = sum(bool(s.breakdowns) for s in case.states)
        worst = worst_of(s.worst_ratio for s in case.states)
        checked = [c.worst_ratio for s in case.states for c in s.checks.values()]
        status = "FAIL" if bad or case.internal or case.loader_findings or case.spec.name in result.broken else "ok"
        known_here = sum(c.verdict == KNOWN for s in case.states for c in [*s.comparisons.values(),
                                                                           *s.checks.values()])
        print(f"{status:4s} {case.spec.name:18s} {len(case.states)} states, {bad} failing, {known_here} known, "
              f"{broken} breakdown, "
              f"worst error/tolerance {worst:.3g}; {len(checked)} invariance/conservation comparisons, worst "
              f"{worst_of(checked):.3g}")
        first = next((s for s in case.states if s.failed), None)
        if first is not None:       # the README's promise: a command that reproduces a failing state, here too
            print(f"     reproduce state #{first.state.index}: {reproduce_command(case, first)}")
    for case in result.cases:
        for why in task_point_lines(case)[1:]:   # a task condition in BREAKDOWN at most states: say why
            print(f"note {case.spec.name}: {why.strip(' -')}", file=sys.stderr)
    for case in result.cases:
        for finding in case.loader_findings:
            print(f"FAIL {case.spec.name}: {finding}", file=sys.stderr)
    for case in result.cases:
        for problem in case.coverage.problems if case.coverage else ():
            print(f"FAIL {case.spec.name}: degenerate sample: {problem}", file=sys.stderr)
    states = {case.spec.name: len(case.states) for case in result.cases}
    for case, backends_out in result.broken.items():
        for name, count in backends_out.items():
            print(f"FAIL {case}: backend {name} was in BREAKDOWN (out of the vote) at {count} of {states[case]} "
                  f"states; the report says which condition and why. Name it with --allow-breakdown {name} if "
                  "that is expected", file=sys.stderr)
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
        print(f"self-test: {canary_count(result.self_test)}", file=sys.stderr)
    print(gate_summary.compared_line(result))
    for found in internal.occurrences(result):
        print(f"FAIL {found.describe()}")
    findings = sum(len(case.model.findings) for case in result.cases)
    noted = f" with {findings} model finding(s) at its top" if findings else ""
    harness = " (the harness itself failed: Internal errors of the harness)" if result.has_internal_errors else ""
    print(f"{'PASS' if result.passed else 'FAIL'}: report written to {report}{noted}{harness} (details in {details})")
    return INTERNAL_ERROR if result.has_internal_errors else 0 if result.passed else 1


def _gate_progress(display: Display):
    """The gate's progress callback (``crosscheck.engine.phases.Step``) on ``display``: the states evaluated over every
    case, what runs now, and a line per case evaluated."""
    finished = 0

    def progress(step: phases.Step) -> None:
        nonlocal finished
        if step.phase == phases.DONE:
            finished += step.done
            display.note(f"  {step.text}")
        display.update(completed=finished + (0 if step.phase == phases.DONE else step.done))
        display.doing(step.text)

    return progress


def add_parser(sub) -> None:
    """The ``gate`` subcommand on ``sub``."""
    gate = sub.add_parser("gate", help="sample states per case, compare every backend, write a report")
    gate.add_argument("--case", action="append", default=[], help="a built-in case (repeatable; default: all)")
    gate.add_argument("--param", action="append", default=[], metavar="K=V", help="case parameter (one --case)")
    gate.add_argument("--model", action="append", default=[], metavar="PATH",
                      help="a URDF (.urdf) or MJCF (.xml) file (repeatable)")
    gate.add_argument("--base", choices=("fixed", "free"),
                      help="a URDF's base: welded to the world, or on a free joint (default: as the file says)")
    gate.add_argument("--actuated", metavar="JOINTS", help="a URDF's actuated joints, comma-separated, in the order "
                      "of u (default: every joint but a free base's; \"\": none, a passive model)")
    gate.add_argument("--armature", metavar="JOINT=VALUE[,...]",
                      help="a URDF's joints' armature (rotor inertia on M's diagonal; kg m^2, kg for a slide), e.g. shoulder=0.01,elbow=0.005 (an MJCF file declares its own)")
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
    gate.add_argument("--allow-breakdown", action="append", default=[], metavar="NAME",
                      help="a backend that may be in BREAKDOWN (ill-conditioned, out of the vote) at most states of "
                      "a case (otherwise that fails the run; repeatable)")
    gate.add_argument("--strict-model", action="store_true", help="refuse a model with findings (an inertia "
                      "violating the triangle inequality, a massless body with inertia) instead of reporting them "
                      "at the top of the report and comparing the backends")
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
