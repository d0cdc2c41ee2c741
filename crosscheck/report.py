"""Markdown report of a gate run: summary first, then every disagreement, then the worst states.

Same seed, same report byte for byte, apart from the timing section at the end.
"""

from __future__ import annotations

from crosscheck.compare import AGREE, DISAGREE, NOT_COMPARED
from crosscheck.gate import CaseOutcome, GateResult, StateOutcome
from crosscheck.tolerance import EXACT, QUANTITIES, TOLERANCES

MAX_LISTED_FAILURES = 20


def _vec(x) -> str:
    return "[" + ", ".join(f"{v:.10g}" for v in x) + "]" if hasattr(x, "__len__") else f"{x:.10g}"


def _arg(values) -> str:
    return ",".join(repr(float(v)) for v in values)


def reproduce_command(case: CaseOutcome, state: StateOutcome) -> str:
    """A command that evaluates every backend at exactly this state (floats round-trip through repr)."""
    s = state.state
    return (f"crosscheck eval {case.spec.cli_args()} --q={_arg(s.q)} --qd={_arg(s.qd)} --u={_arg(s.u)}")


def _summary_rows(case: CaseOutcome) -> list[str]:
    rows = []
    for quantity in QUANTITIES:
        comps = [(s, s.comparisons[quantity]) for s in case.states if quantity in s.comparisons]
        counts = {v: sum(c.verdict == v for _, c in comps) for v in (AGREE, DISAGREE, NOT_COMPARED)}
        worst_state, worst = max(comps, key=lambda sc: sc[1].worst_ratio, default=(None, None))
        ratio = f"{worst.worst_ratio:.3g}" if worst else "-"
        where = f"#{worst_state.state.index}" if worst_state else "-"
        rows.append(f"| {case.spec.name} | {case.model.n} | {quantity} | {counts[AGREE]} | {counts[DISAGREE]} | "
                    f"{counts[NOT_COMPARED]} | {ratio} | {where} |")
    errors = sum(bool(s.errors) for s in case.states)
    if errors:
        rows.append(f"| {case.spec.name} | {case.model.n} | backend errors | - | {errors} | - | - | - |")
    return rows


def _state_detail(case: CaseOutcome, state: StateOutcome, heading: str) -> list[str]:
    s = state.state
    lines = [f"### {heading}", "",
             f"- q = `{_vec(s.q)}`", f"- qd = `{_vec(s.qd)}`", f"- u = `{_vec(s.u)}`",
             f"- reproduce: `{reproduce_command(case, state)}`", ""]
    for name, message in state.errors.items():
        lines.append(f"- **{name} raised** `{message}`")
    for quantity, comp in state.comparisons.items():
        if comp.verdict == NOT_COMPARED:
            lines.append(f"- {quantity}: NOT COMPARED ({', '.join(comp.not_compared) or 'fewer than two values'})")
            continue
        blame = f", outlier **{comp.outlier}**" if comp.outlier else ""
        lines += [f"- **{quantity}**: {comp.verdict}, worst error/tolerance {comp.worst_ratio:.3g} "
                  f"(tolerance {comp.tolerance:.3g}){blame}", "",
                  "  | backend | value |", "  |---|---|"]
        lines += [f"  | {name} | `{_vec(split.quantity(quantity))}` |" for name, split in state.splits.items()]
        if quantity in EXACT:
            lines.append(f"  | exact | `{_vec(EXACT[quantity])}` |")
        lines.append("")
    if state.splits:
        first = next(iter(state.splits.values()))
        lines.append(f"- cond(M) = {first.cond_M:.3g}, acceleration scale = {first.accel_scale:.3g}")
    return lines + [""]


def render(result: GateResult, command: str) -> str:
    """The whole report as markdown; ``command`` is the gate command that produced it."""
    verdict = "PASS" if result.passed else "FAIL"
    n_states = sum(len(c.states) for c in result.cases)
    failed = [(c, s) for c in result.cases for s in c.states if s.failed]
    lines = ["# crosscheck gate report", "",
             f"**{verdict}**: {len(failed)} of {n_states} states disagree or fail "
             f"across {len(result.cases)} case(s) and {len(result.backends)} backends "
             f"({', '.join(result.backends)}).", "",
             f"- command: `{command}`", f"- seed {result.seed}, {result.samples} states per case",
             "- tolerance per quantity: " + ", ".join(f"{q}: {f:g} eps x {k} scale"
                                                     for q, (k, f) in TOLERANCES.items()),
             "  (acceleration scale = cond(M) ||M^-1|| H, H the size of the forces summed; median over backends)", "",
             "## Summary", "",
             "| case | n | quantity | agree | DISAGREE | not compared | worst error/tolerance | at state |",
             "|---|---|---|---|---|---|---|---|"]
    for case in result.cases:
        lines += _summary_rows(case)
    lines.append("")
    if failed:
        lines += ["## Disagreements", ""]
        for case, state in failed[:MAX_LISTED_FAILURES]:
            lines += _state_detail(case, state, f"{case.spec.name}, state #{state.state.index}")
        if len(failed) > MAX_LISTED_FAILURES:
            lines += [f"... and {len(failed) - MAX_LISTED_FAILURES} more failing states.", ""]
    lines += ["## Worst state per case", ""]
    for case in result.cases:
        worst = max(case.states, key=lambda s: s.worst_ratio, default=None)
        if worst is not None:
            lines += _state_detail(case, worst, f"{case.spec.name}, state #{worst.state.index}")
    lines += ["## Timing (varies run to run)", "", "| case | backend | first call (s, includes preparation) | "
              "per state (ms) |", "|---|---|---|---|"]
    for case in result.cases:
        for name in result.backends:
            if name in case.per_state_s:
                lines.append(f"| {case.spec.name} | {name} | {case.first_call_s[name]:.3f} | "
                             f"{1e3 * case.per_state_s[name]:.3f} |")
    return "\n".join(lines) + "\n"
