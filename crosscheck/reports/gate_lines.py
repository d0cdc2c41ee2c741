"""The pieces both parts of the gate report use: reproduce commands (a state, a check), check families, a verdict's
line, one state's detail, the self-test and registry lines and a case's task point in words."""

from __future__ import annotations

import shlex

import numpy as np

from cases import task
from crosscheck import backends
from crosscheck.checks import charts
from crosscheck.core.compare import (AGREE, DISAGREE, KNOWN, NOT_COMPARED, SEVERITY, Comparison, backend_of, suspect,
                                     suspects, vote)
from crosscheck.core.tolerance import BREAKDOWN_LIMITS, BREAKDOWN_SCOPE, EXACT, TOLERANCES
from crosscheck.engine import internal
from crosscheck.engine.divergences import Applied
from crosscheck.engine.outcomes import CaseOutcome, GateResult, StateOutcome
from formalisms.interface import Unsupported


MAX_LISTED_FAILURES = 20
#: Different messages listed per backend and case (:func:`backend_errors`); the rest are counted.
MAX_LISTED_MESSAGES = 5
VERDICTS = (AGREE, DISAGREE, KNOWN, NOT_COMPARED)


def vec_text(x) -> str:
    """A number, or an array flattened row by row, with 10 significant digits."""
    return "[" + ", ".join(f"{v:.10g}" for v in np.ravel(x)) + "]" if hasattr(x, "__len__") else f"{x:.10g}"


def no_chart(model) -> str:
    """Why a case has no chart checked: "-", or that joint-coordinate charts do not apply to its group joints."""
    return "-" if charts.applies(model) else "none apply (spherical or free joints: quaternion coordinates)"


def _arg(values) -> str:
    return ",".join(repr(float(v)) for v in values)


def reproduce_command(case: CaseOutcome, state: StateOutcome) -> str:
    """A command that evaluates every backend at exactly this state (floats round-trip through repr)."""
    s = state.state
    return (f"crosscheck eval {case.spec.cli_args()} --q={_arg(s.q)} --qd={_arg(s.qd)} --u={_arg(s.u)}"
            + _plugin_args())


def _plugin_args() -> str:
    """``--plugin SPEC`` for every plugin loaded by spec in this run (entry points load themselves)."""
    return "".join(f" --plugin {shlex.quote(spec)}" for spec in backends.plugin_specs())


def check_reproduce_command(case: CaseOutcome, state: StateOutcome, family: str, seed: int) -> str:
    """The eval command for a failing chart or frame check: the state expressed in that chart (p, pd and the
    generalized force), or the moved scene."""
    s = state.state
    if family.startswith("chart "):
        chart = charts.get(family.split(" ", 1)[1], case.model, seed, case.spec.name)
        p = chart.p_of(np.array(s.q))
        pd = charts.velocity_to_chart(chart, p, np.array(s.qd))
        tau = charts.force_to_chart(chart, p, case.model.input_map @ np.array(s.u))
        return (f"crosscheck eval {case.spec.cli_args()} --chart {chart.name} --seed {seed} --q={_arg(p)} "
                f"--qd={_arg(pd)} --tau={_arg(tau)}" + _plugin_args())
    if family.startswith("frame") and case.frames:
        frame = case.frames[s.index % len(case.frames)]
        return f"{reproduce_command(case, state)} --frame {frame.name} --seed {seed}"
    return reproduce_command(case, state)


def ratio_of(comp: Comparison) -> float:
    """The worst ratio for ordering, NaN last-but-worst."""
    return comp.worst_ratio if comp.worst_ratio == comp.worst_ratio else float("inf")


def severity_of(comp: Comparison | None) -> str:
    return comp.severity if comp is not None and comp.severity else "-"


def all_comparisons(state: StateOutcome) -> list[Comparison]:
    return list(state.comparisons.values()) + list(state.checks.values())


def check_family(key: str) -> str:
    """The report row a check belongs to: ``chart affine``, ``frame``, ``frame law``, or a conservation check."""
    return key if key.startswith("conservation") else key.split(":")[0]


def check_groups(case: CaseOutcome) -> dict[str, list[tuple[StateOutcome, str, Comparison]]]:
    groups: dict[str, list] = {}
    for state in case.states:
        for key, comp in state.checks.items():
            groups.setdefault(check_family(key), []).append((state, key, comp))
    return groups


def condition_text(state: StateOutcome, backend: str, name: str, value: float) -> str:
    """``cond NAME = v > limit``, with the rank of ``Jc M^-1 Jc^T`` for the constraint condition (5.6)."""
    text = f"cond {name} = {value:.3g} > {BREAKDOWN_LIMITS[name]:.3g}"
    split = state.splits.get(backend)
    if name == "constraint" and split is not None and split.constraint_rank is not None:
        text += f" (rank {split.constraint_rank} of {len(split.constraint_bias)})"
    return text


def scope_text(name: str) -> str:
    return ", ".join(BREAKDOWN_SCOPE[name]) if name in BREAKDOWN_SCOPE else "all"


#: The conditions of a task point (``crosscheck.core.tolerance.BREAKDOWN_LIMITS``): a BREAKDOWN on them is the task's.
TASK_CONDITIONS = ("task", "task_jacobian", "task_inertia")


def task_broken_states(case: CaseOutcome) -> list[StateOutcome]:
    """The states where some backend was in BREAKDOWN on a task condition."""
    return [s for s in case.states if any(set(c) & set(TASK_CONDITIONS) for c in s.breakdowns.values())]


def typical_state(states: list[StateOutcome]) -> StateOutcome:
    """The first of ``states`` away from the home configuration q = 0 (a stretched chain is singular anyway)."""
    return next((s for s in states if any(s.state.q)), states[0])


def task_point_lines(case: CaseOutcome) -> list[str]:
    """The task point a case used (name, body, offset, directions) and how it was chosen; when a backend was in
    BREAKDOWN on a task condition at most states, why, from the model's own point kinematics at such a state
    (``cases.task.rank_deficiency``: "task Jacobian rank 1 < 2: the point lies on the axis of joint 'link2'")."""
    tp = case.model.task_point()
    choice = tp.choice or "declared with the model"
    lines = [f"- {case.spec.name}: task point `{tp.name}` on body `{tp.body}` at {vec_text(tp.offset)} m in its frame, "
             f"task directions {np.round(tp.directions, 6).tolist()}; {choice}"]
    broken = task_broken_states(case)
    if broken and len(broken) > len(case.states) / 2:
        first = typical_state(broken)
        why = task.rank_deficiency(case.model, np.array(first.state.q))
        worst = max(v for s in broken for c in s.breakdowns.values() for k, v in c.items() if k in TASK_CONDITIONS)
        lines.append(f"  - a task condition was in BREAKDOWN at {len(broken)} of {len(case.states)} states (worst "
                     f"{worst:.3g}); at state #{first.state.index}: " +
                     (why or _full_rank_why(first)) +
                     f". Choose another point with `--task-point BODY[:x,y,z]`.")
    return lines


def _full_rank_why(state: StateOutcome) -> str:
    """Why a task condition broke down at ``state`` where the task Jacobian has full rank: the conditions above their
    limits, and what each means."""
    found = {k: v for c in state.breakdowns.values() for k, v in c.items() if k in TASK_CONDITIONS}
    meaning = ("near-singular: cond(J M^-1 J^T) above its limit" if "task" in found or "task_inertia" in found else
               "short in every direction: the recomposition amplifies the rounding of the task bias (task_jacobian "
               "= L ||M^-1 J^T Lambda||) above its limit")
    values = ", ".join(f"{k} {v:.3g} > {BREAKDOWN_LIMITS[k]:.3g}" for k, v in sorted(found.items()))
    return f"the task Jacobian has full rank there ({values}), but is {meaning}"


def _verdict_line(key: str, comp: Comparison) -> str:
    """``- **key**: VERDICT (severity), worst error/tolerance r (tolerance t), outlier **x**`` and, for a
    disagreement without an outlier, how the vote came out; for a KNOWN one, the registry's reason."""
    severity = f" ({comp.severity})" if comp.severity else ""
    line = (f"- **{key}**: {comp.verdict}{severity}, worst error/tolerance {comp.worst_ratio:.3g} "
            f"(tolerance {comp.tolerance:.3g})")
    if comp.shared is not None:          # along code every backend shares: why, in words (compare, shared code)
        line += f"; {vote(comp)}"
    elif comp.outlier:
        line += f", outlier **{comp.outlier}**"
    elif comp.verdict in (DISAGREE, KNOWN):
        line += f"; {vote(comp)}"
    if comp.verdict == KNOWN:
        line += f"; known divergence: {comp.reason}"
    return line


def counted(n: int, one: str, many: str) -> str:
    return f"{n} {one if n == 1 else many}"


def _state_suspects(state: StateOutcome) -> str:
    """The state-level suspect summary: per backend the quantities and checks it is the suspect in, and the
    disagreements no single backend explains."""
    q, c = suspects(state.comparisons.values()), suspects(state.checks.values())
    parts = [f"{name} in {counted(q.by_backend.get(name, 0), 'quantity', 'quantities')} and "
             f"{counted(c.by_backend.get(name, 0), 'check', 'checks')}"
             for name in dict.fromkeys([*q.by_backend, *c.by_backend])]
    alone = [key for key, comp in {**state.comparisons, **state.checks}.items()
             if comp.verdict == DISAGREE and suspect(comp) is None]
    if alone:
        parts.append(f"no single backend explains {', '.join(alone)}")
    return "; ".join(parts) or "none"


def state_detail(case: CaseOutcome, state: StateOutcome, heading: str, seed: int, full: bool = True) -> list[str]:
    """One state: its vector, reproduce command, hint and suspects, then each comparison with the voters' values
    (``full``) or only the disagreeing and known ones, the agreeing ones on one line."""
    s = state.state
    lines = [f"### {heading}", "",
             f"- q = `{vec_text(s.q)}`", f"- qd = `{vec_text(s.qd)}`", f"- u = `{vec_text(s.u)}`",
             f"- reproduce: `{reproduce_command(case, state)}`"]
    if state.hint:
        lines.append(f"- hint: {state.hint}")
    if state.failed:
        lines.append(f"- suspects: {_state_suspects(state)}")
    lines.append("")
    if state.errors:
        lines.append(f"- raised here: {', '.join(state.errors)} (what each raised: Backend errors)")
    if state.internal:
        lines.append(f"- the harness failed here in: {', '.join(state.internal)} (Internal errors of the harness)")
    for name, conditions in state.breakdowns.items():
        lines.append(f"- {name}: BREAKDOWN, not compared: " + "; ".join(
            f"{scope_text(k)} ({condition_text(state, name, k, v)})" for k, v in conditions.items()))
    agreeing = []
    for quantity, comp in state.comparisons.items():
        if comp.verdict == NOT_COMPARED:
            if full:
                lines.append(f"- {quantity}: NOT COMPARED ({', '.join(comp.not_compared) or 'fewer than two values'})")
            continue
        if comp.verdict == AGREE and not full:
            agreeing.append(f"{quantity} ({comp.worst_ratio:.3g})")
            continue
        lines += [_verdict_line(quantity, comp), "", "  | backend | value |", "  |---|---|"]
        lines += [f"  | {name} | `{vec_text(split.quantity(quantity))}` |"
                  for name, split in state.voters(quantity).items()
                  if not isinstance(split.quantity(quantity), Unsupported)]
        if quantity in EXACT:
            lines.append(f"  | exact | `{vec_text(EXACT[quantity])}` |")
        lines.append("")
    if agreeing:
        lines += [f"- agree (worst error/tolerance): {', '.join(agreeing)}", ""]
    for key, comp in state.checks.items():
        if comp.verdict not in (DISAGREE, KNOWN):
            continue
        lines += [f"{_verdict_line(key, comp)}; reproduce: "
                  f"`{check_reproduce_command(case, state, check_family(key), seed)}`", "",
                  "  | voter | value |", "  |---|---|"]
        lines += [f"  | {name} | `{vec_text(value)}` |" for name, value in comp.values.items()] + [""]
    if state.splits:
        first = next(iter(state.splits.values()))
        lines.append(f"- cond(M) = {first.cond_M:.3g}, acceleration scale = {first.accel_scale:.3g}")
    return lines + [""]


def registry_line(applied: Applied | None) -> str:
    if applied is None:
        return "- divergence registry: none"
    return (f"- divergence registry: `{applied.registry.source}`, {len(applied.registry.entries)} entries; "
            f"{applied.known} comparison(s) KNOWN, {counted(len(applied.stale), 'stale entry', 'stale entries')}")


def self_test_line(result: GateResult) -> str:
    test = result.self_test
    if test is None:
        return "- self-test: " + ("not run (interrupted)" if result.interrupted and result.checks.self_test
                                  else "skipped")
    return f"- self-test: {canary_count(test)}"


def canary_count(test) -> str:
    """How many canaries were caught and named, of those run, and over how many checks."""
    judged = [r for r in test.results if not r.skipped]
    checks = {r.canary.check for r in judged}
    skipped = len(test.results) - len(judged)
    return (f"{sum(r.passed for r in judged)} of {len(judged)} canaries caught and named, over {len(checks)} checks"
            + (f" ({skipped} not run: their check is off)" if skipped else ""))


INTERNAL_HEADING = "## Internal errors of the harness"


_A_LINE = object()


def section(result: GateResult, name: str, make, failed=_A_LINE):
    """``make()``: a report section's lines (or a value the report needs); when the harness fails in it, ``failed``
    (by default one line saying the section could not be written), the failure recorded as the run's internal error
    ``report: <name>`` (``crosscheck.engine.internal``)."""
    try:
        return make()
    except Exception as exc:  # noqa: BLE001 - one section failing leaves the rest of the report
        error = internal.of(exc)
        result.internal.setdefault(f"report: {name}", error)
        return [f"(The section '{name}' could not be written: the harness failed there: `{error}`.)", ""] \
            if failed is _A_LINE else failed


def sections(result: GateResult, made) -> list[str]:
    """The lines of each (name, make) of ``made`` in order, each made under :func:`section`."""
    return [line for name, make in made for line in section(result, name, make)]


def internal_lines(result: GateResult, traces: bool = False) -> list[str]:
    """The report's section on the harness's own failures (``crosscheck.engine.internal``), empty when there are none:
    each once, with the check it happened in, the case, the first state and how many, the exception and the last frame
    of the traceback in the project's code (``traces``: the project's frames, innermost last)."""
    found = internal.occurrences(result)
    if not found:
        return []
    states = {case.spec.name: len(case.states) for case in result.cases}
    lines = [INTERNAL_HEADING, "",
             f"The harness's own code raised ({counted(len(found), 'entry', 'entries')}, each once per check, case and "
             "place): a bug in crosscheck, not in a backend (a backend raising is under Backend errors). Each check "
             "named was left out where it raised; every other check and state ran. The run does not pass (exit 3).",
             ""]
    for o in found:
        scope = [o.case] if o.case else ["the run"]
        if o.states:
            scope.append(f"{o.states} of {states.get(o.case, o.states)} states, first #{o.first}")
        elif o.case:
            scope.append("its sampling coverage was not measured" if o.check == "coverage"
                         else "none of its states was evaluated")
        lines.append(f"- **internal error in {o.check}** ({', '.join(scope)}): `{o.error.error}` at "
                     f"`{o.error.where}`")
        if traces and o.error.trace:
            lines.append(f"  - traceback in the project (innermost first, each called from the next): "
                         f"{' <- '.join(reversed(o.error.trace))}")
    return lines + [""]


def verdict_text(result: GateResult) -> str:
    return "PARTIAL" if result.interrupted else "PASS" if result.passed else "FAIL"


def failed_states(result: GateResult) -> list[tuple[CaseOutcome, StateOutcome]]:
    return [(c, s) for c in result.cases for s in c.states if s.failed]


def backend_errors(case: CaseOutcome) -> list[str]:
    """What the backends raised in ``case``, one line per backend and message (its moved scenes and linearization
    counted with it: ``crosscheck.core.compare.backend_of``) with the number of states and the first, at most
    :data:`MAX_LISTED_MESSAGES` messages per backend: a plugin that cannot build its model at any state is one line,
    not one per state."""
    found: dict[str, dict[str, list[tuple[int, str]]]] = {}
    for state in case.states:
        for label, message in state.errors.items():
            found.setdefault(backend_of(label), {}).setdefault(message, []).append((state.state.index, label))
    lines = []
    for name, messages in found.items():
        for message, where in list(messages.items())[:MAX_LISTED_MESSAGES]:
            index, label = where[0]
            states = len({i for i, _ in where})
            lines.append(f"- **{name} raised** `{message}` ({case.spec.name}: {states} of {len(case.states)} "
                         f"states, first #{index}{'' if label == name else f' as {label}'})")
        rest = list(messages.values())[MAX_LISTED_MESSAGES:]
        if rest:
            lines.append(f"- **{name}** raised {len(rest)} other messages at "
                         f"{len({i for where in rest for i, _ in where})} states of {case.spec.name}")
    return lines


def policy_lines() -> list[str]:
    """The tolerance table, the severity bands and the breakdown limits the verdicts used."""
    return ["- tolerance per quantity: " + ", ".join(f"{q}: {f:g} eps x {k} scale" for q, (k, f) in TOLERANCES.items()),
            "  (accelerations: one tolerance per coordinate, |M^-1| (f + Mterm |x| + d d.|x|), the sizes of the terms"
            " summed in M and h (crosscheck.core.tolerance.acceleration_bound);",
            "  task scale = L (sum of the acceleration scales + |qd|_1^2), L the task point's lever arm)",
            "- severity of a DISAGREE by error/tolerance: " + ", ".join(
                f"{name} up to {bound:g}" if bound != float("inf") else f"{name} above (or NaN)"
                for bound, name in SEVERITY),
            "- BREAKDOWN limits: " + ", ".join(f"cond {k} > {v:.3g}" for k, v in BREAKDOWN_LIMITS.items())]


def where_worst(found: list[tuple[StateOutcome, str, Comparison]]) -> str:
    if not found:
        return "-"
    state, key, comp = max(found, key=lambda f: ratio_of(f[2]))
    return f"{key} {comp.worst_ratio:.3g} #{state.state.index}"
