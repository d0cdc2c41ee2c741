"""Markdown report of a gate run, in two parts. The summary (:func:`summary`, the file ``--report`` names) is
short: the verdict, a failing run's disagreements with their severity, vote, hint and reproduce command (and any
other failure), what was run, the worst ratio, what was checked and skipped and why (with the task point of a case
whose task condition broke down at most states), the pictures of the mechanism, one line per case. The details
(``crosscheck.reports.gate_details``, next to it as ``NAME-details.md``): the tolerance policy, counts per verdict,
suspects, voters, the task points, the per-quantity table, the self-test, coverage, known divergences, stale registry
entries, breakdowns, the invariance and conservation checks, the constraint power audit, the drift's parts, the worst
state per case and the timing.

Same seed, same report byte for byte, apart from the timing section at the end of the details.

The harness's own failures (``crosscheck.engine.internal``) come first after the verdict, in both parts (the details
with the traceback's frames in the project). A section the harness fails to write is replaced by a line saying so and
the failure joins them as the run's internal error ``report: <section>`` (:func:`sections`); the report is written
whatever happens (:func:`write_fallback` when even that fails).
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from crosscheck.core.compare import DISAGREE, KNOWN, NOT_COMPARED
from crosscheck.core.tolerance import BREAKDOWN_LIMITS
from crosscheck.engine import internal
from crosscheck.engine.divergences import Applied
from crosscheck.engine.outcomes import GateResult
from crosscheck.reports import gate_closeness
from crosscheck.reports.gate_details import breakdowns_of, details, limits_line
from crosscheck.reports.gate_lines import (INTERNAL_HEADING, MAX_LISTED_FAILURES, all_comparisons, backend_errors,
                                           counted, failed_states, internal_lines, ratio_of, registry_line,
                                           section, sections, self_test_line, state_detail, task_broken_states,
                                           task_point_lines, typical_state, verdict_text, where_worst)


#: At most this many pictures of the mechanism per report.
MAX_FIGURES = 3


def mechanism_figures(result: GateResult, report: Path) -> dict[str, str]:
    """Stick figures of the mechanism (``crosscheck.reports.plots.stick_figure``) written next to ``report`` where they
    help: for each failing case at its worst failing state, else for each case where a task condition was in BREAKDOWN
    at most states (the picture shows where the task point sits), at most :data:`MAX_FIGURES`; {case: file name}."""
    from crosscheck.reports import plots

    chosen = []
    for case in result.cases:
        failed = [s for s in case.states if s.failed]
        broken = task_broken_states(case)
        if failed:
            chosen.append((case, max(failed, key=lambda s: s.worst_ratio), "worst failing state"))
        elif len(broken) > len(case.states) / 2:
            chosen.append((case, typical_state(broken), "task condition in BREAKDOWN"))
    out = {}
    for case, state, why in chosen[:MAX_FIGURES]:
        name = f"{report.stem}_{case.spec.name}_state{state.state.index}.png"
        plots.stick_figure(case.model, np.array(state.state.q), report.parent / name,
                           f"{case.spec.name}, state #{state.state.index} ({why})")
        out[case.spec.name] = name
    return out


def figure_lines(figures: dict[str, str]) -> list[str]:
    """The report's links to the pictures :func:`mechanism_figures` wrote."""
    if not figures:
        return []
    return ["Pictures of the mechanism (joint origins, links, task point; from the reference's forward kinematics):",
            ""] + [f"- {case}: ![{case}]({name})" for case, name in figures.items()] + [""]


def details_path(path: str | Path) -> Path:
    """Where the details of the report at ``path`` go: next to it, ``gate.md`` -> ``gate-details.md``."""
    path = Path(path)
    return path.with_name(f"{path.stem}-details{path.suffix or '.md'}")


def write(result: GateResult, command: str, path: str | Path, applied: Applied | None = None,
          figures: dict[str, str] | None = None) -> tuple[Path, Path]:
    """Write the short report to ``path`` (:func:`summary`, linking ``figures``: :func:`mechanism_figures`) and
    everything else next to it (:func:`details`, at :func:`details_path`); the two paths."""
    path, more = Path(path), details_path(path)
    try:
        first, second = _both(result, lambda found: (
            summary(result, command, applied, details_link=more.name, figures=figures, closeness=found),
            details(result, command, applied, summary_link=path.name, closeness=found)))
    except Exception as exc:  # noqa: BLE001 - the report is written whatever happens: what is known, and why
        result.internal.setdefault("report", internal.of(exc))
        first, second = write_fallback(result, command), ""
    path.write_text(first)
    more.write_text(second)
    return path, more


def _both(result: GateResult, render_with) -> tuple[str, str]:
    """``render_with(closeness)``: the two parts, rendered again when the harness failed in a section (a failure in the
    details joins the summary's internal errors: the second rendering has it from the start)."""
    before = dict(result.internal)
    found = section(result, "per-backend closeness", lambda: gate_closeness.of(result), None)
    parts = render_with(found)
    return render_with(found) if result.internal != before else parts


def write_fallback(result: GateResult, command: str) -> str:
    """The least report: the verdict (FAIL), the command, and the harness's internal errors (the one that stopped the
    report among them), each in as few steps as possible so that it can be written when the full report cannot."""
    lines = ["# crosscheck gate report", "", "**FAIL**: the harness failed while writing this report; what follows is "
             "what it knows (internal errors of the harness below; exit 3).", "", f"- command: `{command}`", ""]
    try:
        lines += internal_lines(result, traces=True)
    except Exception:  # noqa: BLE001 - the very least: the run's own errors, as they were recorded
        lines += [INTERNAL_HEADING, ""] + [f"- **{check}**: `{error}`" for check, error in result.internal.items()]
    return "\n".join(lines) + "\n"


def read(path: str | Path) -> str:
    """The whole report :func:`write` left at ``path``: the summary, then the details (when there are any)."""
    path, more = Path(path), details_path(path)
    return path.read_text() + ("\n" + more.read_text() if more.exists() else "")


def render(result: GateResult, command: str, applied: Applied | None = None,
           figures: dict[str, str] | None = None) -> str:
    """The whole report as one markdown text: the summary (:func:`summary`), then the details (:func:`details`);
    ``command`` is the gate command that produced it, ``applied`` the divergence registry as applied to ``result``
    (``crosscheck.engine.divergences.apply``), if any, ``figures`` the pictures of the mechanism to link
    (:func:`mechanism_figures`). The command line writes the two parts to two files (:func:`write`)."""
    first, second = _both(result, lambda found: (summary(result, command, applied, figures=figures, closeness=found),
                                                 details(result, command, applied, closeness=found)))
    return first + "\n" + second


def _headline(result: GateResult) -> list[str]:
    """The title, the PARTIAL warning of an interrupted run, and the verdict line with the counts."""
    n_states = sum(len(c.states) for c in result.cases)
    broken = sum(bool(s.breakdowns) for c in result.cases for s in c.states)
    known = sum(c.verdict == KNOWN for case in result.cases for s in case.states for c in all_comparisons(s))
    partial = [f"**PARTIAL REPORT: the run was interrupted {result.interrupted}.** It holds only the states "
               "evaluated until then and gives no verdict (a disagreement below is still one).", ""]
    found = len(internal.occurrences(result))
    harness = [f"**The harness itself failed**: {counted(found, 'internal error', 'internal errors')} of crosscheck's "
               "own code (below): the checks named were left out where they raised, so the run does not pass.",
               ""] if found else []
    return ["# crosscheck gate report", "", *(partial if result.interrupted else []), *harness,
            f"**{verdict_text(result)}**: {len(failed_states(result))} of {n_states} states disagree or fail "
            f"across {len(result.cases)} case(s) and {len(result.backends)} backends "
            f"({', '.join(result.backends)}); {known} known divergence(s) (KNOWN, not failures); "
            f"{broken} state(s) with a backend in BREAKDOWN.", "", compared_line(result), ""]


def compared_line(result: GateResult) -> str:
    """Which backends were compared in each case: every one, or per case the ones that were not and why (declined
    the model, raised, or out of the vote by BREAKDOWN at most states)."""
    missing = []
    for case in result.cases:
        compared, mostly = result.compared(case), case.mostly_broken()
        for name in result.backends:
            if name in mostly:
                missing.append(f"{case.spec.name}: {name} in BREAKDOWN at {mostly[name]} of {len(case.states)} "
                               "states" + (" (allowed)" if name in result.allow_breakdown else ""))
            elif name not in compared:
                missing.append(f"{case.spec.name}: {name} not compared")
    if not missing:
        return f"Compared: every backend in every case ({len(result.backends)})."
    return "Compared: every backend but " + "; ".join(missing) + "."


def _model_findings(result: GateResult) -> list[str]:
    """The models' findings (``cases.model.Model.findings``), first: what is physically impossible in a model the
    backends were still compared on."""
    found = [f"- {case.spec.name}: {finding}" for case in result.cases for finding in case.model.findings]
    if not found:
        return []
    return ["## Model findings", "", "Physically impossible data that still gives a positive-definite M: the backends "
            "were compared on the model as given (`--strict-model` refuses it).", "", *found, ""]


def _worst_line(result: GateResult) -> str:
    """The largest error/tolerance of the run over every comparison and check, and where it was."""
    found = [(case, state, key, comp) for case in result.cases for state in case.states
             for key, comp in {**state.comparisons, **state.checks}.items() if comp.verdict != NOT_COMPARED]
    if not found:
        return "- worst error/tolerance: - (nothing compared)"
    case, state, key, comp = max(found, key=lambda f: ratio_of(f[3]))
    return (f"- worst error/tolerance: {comp.worst_ratio:.3g} ({case.spec.name}, {key}, state "
            f"#{state.state.index}; below 1 agrees)")


def _run_lines(result: GateResult, command: str, applied: Applied | None) -> list[str]:
    """What was run: the command, seed and sample size, the joint limits the states keep, what the model files read
    apart from the loader were compared on, the self-test and the divergence registry."""
    return [f"- command: `{command}`", f"- seed {result.seed}, {result.samples} states per case",
            *limits_line(result), *_loader_lines(result), self_test_line(result), registry_line(applied)]


def _loader_lines(result: GateResult) -> list[str]:
    """Per case loaded from a file: what was compared with the file read apart from the loader, and what it found."""
    return [f"- {case.spec.name}: read apart from the loader: {case.loader.line()}"
            for case in result.cases if case.loader is not None]


def _failures_section(result: GateResult) -> list[str]:
    """What failed the run, first: the loader findings (``crosscheck.guards.loader``), what the backends raised (once
    per backend and message), the disagreeing states with their reproduce commands, degenerate samples, required
    backends that compared nothing, missed canaries."""
    loader = [f"- **{case.spec.name}**: {finding}" for case in result.cases for finding in case.loader_findings]
    lines = ["## Loader findings", "", "The model file, read a second time apart from the loader "
             "(`crosscheck/guards/loader.py`), disagrees with the model every backend and the reference were given: "
             "the vote cannot see this, so the case fails.", "", *loader, ""] if loader else []
    errors = [line for case in result.cases for line in backend_errors(case)]
    lines += ["## Backend errors", "", *errors, ""] if errors else []
    failed = [(case, state) for case, state in failed_states(result)      # not the states that only raised: above
              if any(c.verdict == DISAGREE for c in all_comparisons(state))]
    if failed:
        lines += ["## Disagreements", ""]
        for case, state in failed[:MAX_LISTED_FAILURES]:
            lines += state_detail(case, state, f"{case.spec.name}, state #{state.state.index}", result.seed,
                                   full=False)
        if len(failed) > MAX_LISTED_FAILURES:
            lines += [f"... and {len(failed) - MAX_LISTED_FAILURES} more disagreeing states.", ""]
    other = [f"- **{case.spec.name}: degenerate sample**: {p}" for case in result.cases
             for p in (case.coverage.problems if case.coverage else ())]
    other += [f"- **FAIL: {name} took part in no comparison** (named on the command line; it raised, declined or "
              f"was in BREAKDOWN at every state). Name it with `--optional {name}` if that is expected."
              for name in result.absent]
    other += [f"- **{case}: {name} was in BREAKDOWN (out of the vote) at {count} of {len(by_name[case].states)} "
              f"states**: it checked almost nothing there (the breakdowns below say which condition). Name it with "
              f"`--allow-breakdown {name}` if that is expected."
              for by_name in [{c.spec.name: c for c in result.cases}]
              for case, found in result.broken.items() for name, count in found.items()]
    other += [f"- **self-test: {line}**" for line in (result.self_test.failures() if result.self_test else ())]
    if other:
        lines += ["## Other failures", ""] + other + [""]
    return lines


def _case_table(result: GateResult) -> list[str]:
    """One line per case: states, failing, KNOWN, BREAKDOWN states, the worst comparison and the worst check."""
    rows = []
    for case in result.cases:
        worst = [(s, k, c) for s in case.states for k, c in s.comparisons.items() if c.verdict != NOT_COMPARED]
        checks = [(s, k, c) for s in case.states for k, c in s.checks.items() if c.verdict != NOT_COMPARED]
        known = sum(c.verdict == KNOWN for s in case.states for c in all_comparisons(s))
        broken = sum(bool(s.breakdowns) for s in case.states)
        rows.append(f"| {case.spec.name} | {case.model.n} | {len(case.states)} | "
                    f"{sum(s.failed for s in case.states)} | {known} | {broken} | "
                    f"{where_worst(worst)} | {where_worst(checks)} | "
                    f"{'**degenerate**' if case.coverage and case.coverage.degenerate else 'ok'} |")
    return ["## Cases", "",
            "| case | n | states | failing | KNOWN | BREAKDOWN states | worst quantity (error/tolerance, state) | "
            "worst check | sample |", "|---|---|---|---|---|---|---|---|---|"] + rows + [""]


def _checked_lines(result: GateResult) -> list[str]:
    """What the run checked besides the backends' comparison, and what it left out and why (an option, or a case
    where a check does not apply)."""
    c = result.checks
    on = {"chart invariance": (c.charts, "--no-charts"), "frame changes": (c.frames, "--frames 0"),
          "energy and Christoffel conservation": (c.conservation, "--no-conservation"),
          "linearizations A, B (eq. 11)": (c.linearization, "--no-linearization"),
          "the article's closed forms as a voter": (c.closed_forms, "--no-closed-forms"),
          "self-test canaries": (c.self_test, "--no-self-test")}
    shown = {"frame changes": f"{c.frames} frame change(s) per case"}
    lines = ["- checked: every quantity every backend supplies, "
             + ", ".join(shown.get(k, k) for k, (v, _) in on.items() if v)]
    off = [f"{k} ({flag})" for k, (v, flag) in on.items() if not v]
    if off:
        lines.append("- skipped by option: " + ", ".join(off))
    if c.charts:
        none = [case.spec.name for case in result.cases if not case.charts]
        if none:
            lines.append(f"- no chart applies (spherical or free joints: quaternion coordinates): {', '.join(none)}")
    if c.closed_forms:
        none = [case.spec.name for case in result.cases if case.closed_form.startswith("none")]
        if none:
            lines.append(f"- no closed form: {', '.join(none)}")
    lines += _not_supplied_lines(result) + _breakdown_lines(result) + _silent_lines(result)
    return lines


def _breakdown_lines(result: GateResult) -> list[str]:
    """Per backend and condition, the cases and states where it was in BREAKDOWN (left out of the comparisons)."""
    found: dict[tuple[str, str], dict[str, int]] = {}
    for case, _, backend, name, _ in breakdowns_of(result):
        per_case = found.setdefault((backend, name), {})
        per_case[case.spec.name] = per_case.get(case.spec.name, 0) + 1
    parts = [f"{backend} cond {name} > {BREAKDOWN_LIMITS[name]:.3g} (" + ", ".join(
        f"{case} {counted(n, 'state', 'states')}" for case, n in per_case.items()) + ")"
        for (backend, name), per_case in found.items()]
    return ["- in BREAKDOWN, so left out of the comparisons there (ill-conditioned method, not a failure): "
            + "; ".join(parts)] if parts else []


def _not_supplied_lines(result: GateResult) -> list[str]:
    """Per quantity, the backends that do not supply it (NOT COMPARED for them, declared unsupported)."""
    missing: dict[str, set[str]] = {}
    for case in result.cases:
        for state in case.states:
            for quantity, comp in state.comparisons.items():
                missing.setdefault(quantity, set()).update(comp.not_compared)
    parts = [f"{q}: {', '.join(sorted(names))}" for q, names in missing.items() if names]
    return ["- not supplied (declared unsupported, so not compared for that backend): " + "; ".join(parts)] if parts \
        else []


def _silent_lines(result: GateResult) -> list[str]:
    """Backends that took part in no comparison of a case, or were in BREAKDOWN at most of its states."""
    lines = []
    for case in result.cases:
        voted = case.voted()
        silent = [name for name in result.backends if name not in voted]
        broken = [f"{name} ({sum(bool(s.breakdowns.get(name)) for s in case.states)} of {len(case.states)} states)"
                  for name in result.backends
                  if sum(bool(s.breakdowns.get(name)) for s in case.states) > len(case.states) / 2]
        if silent:
            lines.append(f"- {case.spec.name}: took part in no comparison: {', '.join(silent)}")
        if broken:
            lines.append(f"- {case.spec.name}: in BREAKDOWN at most states (checks little here): {', '.join(broken)}")
    return lines


def summary(result: GateResult, command: str, applied: Applied | None = None, details_link: str | None = None,
            figures: dict[str, str] | None = None, closeness: gate_closeness.Closeness | None = None) -> str:
    """The report's first part, short: the verdict, a failing run's failures with their reproduce commands, what
    was run, one line per case, the worst ratio, what was checked and skipped, the task point of each case where a
    task condition was in BREAKDOWN at most states and why, the pictures of the mechanism (``figures``);
    ``details_link`` the file holding :func:`details` (None: they follow in the same text); ``closeness`` the
    per-backend table's cells (``gate_closeness.of``, computed here if None)."""
    where = f"[{details_link}]({details_link})" if details_link else "below"
    body = sections(result, [
        ("model findings", lambda: _model_findings(result)),
        ("failures", lambda: _failures_section(result)),
        ("what was run", lambda: _run_lines(result, command, applied) + [_worst_line(result)]
         + _checked_lines(result)),
        ("task points", lambda: [line for case in result.cases if len(explained := task_point_lines(case)) > 1
                                 for line in explained]),
        ("details link", lambda: [
            f"- details {where}: suspects, voters, task points, per-quantity table, self-test, sampling coverage, "
            "known divergences, breakdowns, invariance and conservation checks, power audit, external load power, "
            "the drift's parts, worst state per case, timing, tolerance policy", ""]),
        ("pictures", lambda: figure_lines(figures or {})),
        ("cases", lambda: _case_table(result)),
        ("per-backend closeness", lambda: gate_closeness.closeness_section(result, closeness))])
    first = sections(result, [("headline", lambda: _headline(result))])      # after the others: it counts their
    found = sections(result, [("internal errors", lambda: internal_lines(result))])   # failures too
    return "\n".join(first + found + body) + "\n"
