"""Markdown report of a gate run, in two parts. The summary (:func:`summary`, the file ``--report`` names) is
short: the verdict, a failing run's disagreements with their severity, vote, hint and reproduce command (and any
other failure), what was run, the worst ratio, what was checked and skipped and why (with the task point of a case
whose task condition broke down at most states), the pictures of the mechanism, one line per case. The details
(:func:`details`, next to it as ``NAME-details.md``): the tolerance policy, counts per verdict, suspects, voters, the
task points, the per-quantity table, the self-test, coverage, known divergences, stale registry entries, breakdowns,
the invariance and conservation checks, the constraint power audit, the drift's parts, the worst state per case and
the timing.

Same seed, same report byte for byte, apart from the timing section at the end of the details.
"""

from __future__ import annotations

import shlex
from pathlib import Path

import numpy as np

from cases import task
from crosscheck import backends
from crosscheck.checks import charts
from crosscheck.references.pinocchio import build
from crosscheck.references.pinocchio import reference
from crosscheck.core import sampling
from crosscheck.core.compare import (AGREE, DISAGREE, KNOWN, NOT_COMPARED, SEVERITY, Comparison, suspect, suspects,
                                vote)
from crosscheck.engine.outcomes import CaseOutcome, GateResult, StateOutcome
from crosscheck.engine.divergences import Applied
from formalisms.interface import Unsupported
from crosscheck.core.tolerance import BREAKDOWN_LIMITS, BREAKDOWN_SCOPE, EXACT, TOLERANCES, quantities

MAX_LISTED_FAILURES = 20
VERDICTS = (AGREE, DISAGREE, KNOWN, NOT_COMPARED)


def _vec(x) -> str:
    """A number, or an array flattened row by row, with 10 significant digits."""
    return "[" + ", ".join(f"{v:.10g}" for v in np.ravel(x)) + "]" if hasattr(x, "__len__") else f"{x:.10g}"


def _no_chart(model) -> str:
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


def _summary_rows(case: CaseOutcome) -> list[str]:
    rows = []
    for quantity in quantities(case.model):
        comps = [(s, s.comparisons[quantity]) for s in case.states if quantity in s.comparisons]
        counts = {v: sum(c.verdict == v for _, c in comps) for v in VERDICTS}
        worst_state, worst = max(comps, key=lambda sc: _ratio(sc[1]), default=(None, None))
        ratio = f"{worst.worst_ratio:.3g}" if worst else "-"
        where = f"#{worst_state.state.index}" if worst_state else "-"
        unsupported = sorted({name for _, c in comps for name in c.not_compared})
        rows.append(f"| {case.spec.name} | {case.model.n} | {quantity} | {counts[AGREE]} | {counts[DISAGREE]} | "
                    f"{counts[KNOWN]} | {counts[NOT_COMPARED]} | {ratio} | {_severity(worst)} | {where} | "
                    f"{', '.join(unsupported) or '-'} |")
    errors = sum(bool(s.errors) for s in case.states)
    if errors:
        rows.append(f"| {case.spec.name} | {case.model.n} | backend errors | - | {errors} | - | - | - | - | - | - |")
    return rows


def _ratio(comp: Comparison) -> float:
    """The worst ratio for ordering, NaN last-but-worst."""
    return comp.worst_ratio if comp.worst_ratio == comp.worst_ratio else float("inf")


def _severity(comp: Comparison | None) -> str:
    return comp.severity if comp is not None and comp.severity else "-"


def _all(state: StateOutcome) -> list[Comparison]:
    return list(state.comparisons.values()) + list(state.checks.values())


def _counts_rows(result: GateResult) -> list[str]:
    """Per case and in total: comparisons (quantities and checks) per verdict, and states failing, in BREAKDOWN,
    with a backend error."""
    rows, total = [], [0] * 8
    for case in result.cases:
        found = [c for s in case.states for c in _all(s)]
        row = [len(case.states), sum(s.failed for s in case.states)]
        row += [sum(c.verdict == v for c in found) for v in VERDICTS]
        row += [sum(bool(s.breakdowns) for s in case.states), sum(bool(s.errors) for s in case.states)]
        total = [a + b for a, b in zip(total, row)]
        rows.append(f"| {case.spec.name} | " + " | ".join(map(str, row)) + " |")
    if len(result.cases) > 1:
        rows.append("| **all** | " + " | ".join(map(str, total)) + " |")
    return ["| case | states | failing states | agree | DISAGREE | KNOWN | NOT COMPARED | BREAKDOWN states | "
            "states with a backend error |", "|---|---|---|---|---|---|---|---|---|"] + rows


def _state_tally(state: StateOutcome) -> list[tuple[str, int, int]]:
    """(suspect, quantities, checks) at one state, the unexplained disagreements as two pseudo-suspects."""
    q, c = suspects(state.comparisons.values()), suspects(state.checks.values())
    rows = [(name, q.by_backend.get(name, 0), c.by_backend.get(name, 0))
            for name in dict.fromkeys([*q.by_backend, *c.by_backend])]
    rows += [("no single backend (split vote)", q.split, c.split), ("no vote (two voters only)", q.undecided,
                                                                      c.undecided)]
    return [row for row in rows if row[1] or row[2]]


def _case_suspects(case: CaseOutcome) -> list[str]:
    """Who the case's disagreements point at: per backend the quantities, checks and states where it is the
    suspect; then the disagreements no single backend explains."""
    tally: dict[str, list[int]] = {}
    for state in case.states:
        for label, q, c in _state_tally(state):
            t = tally.setdefault(label, [0, 0, 0])
            t[0], t[1], t[2] = t[0] + q, t[1] + c, t[2] + 1
    order = sorted(tally, key=lambda k: (k.startswith("no "), -tally[k][2], k))
    return [f"| {case.spec.name} | {k} | {tally[k][0]} | {tally[k][1]} | {tally[k][2]} |" for k in order]


def _suspects_section(result: GateResult) -> list[str]:
    rows = [row for case in result.cases for row in _case_suspects(case)]
    if not rows:
        return ["Suspects: none (no disagreement).", ""]
    return ["Suspects (the backend each disagreement points at: the outlier of a vote of three or more, or the one "
            "backend behind a frame law):", "",
            "| case | suspect | quantities | checks | states |", "|---|---|---|---|---|"] + rows + [""]


def check_family(key: str) -> str:
    """The report row a check belongs to: ``chart affine``, ``frame``, ``frame law``, or a conservation check."""
    return key if key.startswith("conservation") else key.split(":")[0]


def _check_groups(case: CaseOutcome) -> dict[str, list[tuple[StateOutcome, str, Comparison]]]:
    groups: dict[str, list] = {}
    for state in case.states:
        for key, comp in state.checks.items():
            groups.setdefault(check_family(key), []).append((state, key, comp))
    return groups


def _checks_section(result: GateResult) -> list[str]:
    rows, totals = [], {}
    for case in result.cases:
        for family, found in _check_groups(case).items():
            states = len({s.state.index for s, _, _ in found})
            bad = sum(c.verdict == DISAGREE for _, _, c in found)
            state, key, worst = max(found, key=lambda f: f[2].worst_ratio if f[2].worst_ratio == f[2].worst_ratio
                                    else float("inf"))
            rows.append(f"| {case.spec.name} | {family} | {states} | {len(found)} | {bad} | "
                        f"{worst.worst_ratio:.3g} | {worst.tolerance:.3g} | "
                        f"{key.split(': ', 1)[-1] if key != family else '-'} | "
                        f"#{state.state.index} |")
            t = totals.setdefault(family, [0, 0, 0, 0.0, 0])
            t[0] += 1
            t[1] += states
            t[2] += len(found)
            t[3] = max(t[3], worst.worst_ratio)
            t[4] += bad
    if not rows:
        return []
    c = result.checks
    lines = ["## Invariance and conservation checks", "",
             f"Charts: {'every built-in chart that applies (identity is the joint chart)' if c.charts else 'off'}; "
             f"frames: {c.frames} sampled rigid transforms per case (state i in frame i mod {c.frames}); "
             f"conservation: {'on' if c.conservation else 'off'}.", ""]
    lines += [f"- {family}: {states} states in {cases} case(s), {comps} comparisons, {bad} DISAGREE, "
              f"worst error/tolerance {worst:.3g}" for family, (cases, states, comps, worst, bad) in totals.items()]
    lines += ["", "| case | check | states | comparisons | DISAGREE | worst error/tolerance | tolerance at worst | "
              "quantity | at state |", "|---|---|---|---|---|---|---|---|---|"] + rows + [""]
    charts_used = [f"{case.spec.name}: {', '.join(case.charts) or _no_chart(case.model)}" for case in result.cases]
    frames_used = [f"{case.spec.name}: " + "; ".join(
        f"{f.name} = (R = {_vec(f.rotation.ravel())}, t = {_vec(f.translation)})" for f in case.frames)
        for case in result.cases if case.frames]
    lines += ["Charts per case: " + "; ".join(charts_used) + ".", ""]
    lines += [f"- frames {line}" for line in frames_used] + [""]
    return lines


def _limits_line(result: GateResult) -> list[str]:
    """How the states of models with joint limits were drawn (none for a run without such a model)."""
    limited = [(case.spec.name, len(sampling.limited_joints(case.model)), len(case.model.bodies))
               for case in result.cases if sampling.limited_joints(case.model)]
    if not limited:
        return []
    where = ", ".join(f"{name} {k} of {n} joints" for name, k, n in limited)
    if result.checks.joint_limits:
        return [f"- states drawn within the joint limits the models declare ({where}); `--ignore-limits` draws "
                "them freely"]
    return [f"- joint limits ignored (`--ignore-limits`): states drawn freely, also where the models declare limits "
            f"({where})"]


def _condition(state: StateOutcome, backend: str, name: str, value: float) -> str:
    """``cond NAME = v > limit``, with the rank of ``Jc M^-1 Jc^T`` for the constraint condition (5.6)."""
    text = f"cond {name} = {value:.3g} > {BREAKDOWN_LIMITS[name]:.3g}"
    split = state.splits.get(backend)
    if name == "constraint" and split is not None and split.constraint_rank is not None:
        text += f" (rank {split.constraint_rank} of {len(split.constraint_bias)})"
    return text


def _scope(name: str) -> str:
    return ", ".join(BREAKDOWN_SCOPE[name]) if name in BREAKDOWN_SCOPE else "all"


def _breakdowns(result: GateResult) -> list[tuple[CaseOutcome, StateOutcome, str, str, float]]:
    """Every (case, state, backend, condition, value) above its breakdown limit, in run order."""
    return [(case, state, backend, name, value)
            for case in result.cases for state in case.states
            for backend, conditions in state.breakdowns.items() for name, value in conditions.items()]


def _transfer(per_coord: np.ndarray) -> float:
    """Rate at which the constraint moves energy between coordinates: the power it injects into the coordinates
    that gain (``sum_i max(P_i, 0)``), equal to what it takes from the others when the total is zero (5.5)."""
    return float(np.clip(per_coord, 0.0, None).sum())


def _coordinates(model, per_coord: np.ndarray, sign: float) -> str:
    """The velocity coordinates (by body name, with its component for a ball or free joint: ``Model.velocity_labels``)
    the constraint feeds (sign +1) or drains (sign -1), largest first."""
    order = np.argsort(-sign * per_coord)
    labels = model.velocity_labels
    picked = [f"{labels[i]} ({per_coord[i]:+.3g} W)" for i in order if sign * per_coord[i] > 0.0]
    return ", ".join(picked[:2]) or "-"


def _external_power(result: GateResult) -> list[str]:
    """The external loads' power beside the input's (article 2.3, 5.5; ``cases.loads``): per case with loads, the
    largest ``|tau_ext . qd|`` and ``|u . B^T qd|`` over the states (medians over the backends that report them)."""
    rows = []
    for case in result.cases:
        if not case.model.loads:
            continue
        sizes = []
        for state in case.states:
            voters = state.voters("power_ext")
            if voters:
                sizes.append((float(np.median([abs(s.power_ext) for s in voters.values()])),
                              float(np.median([abs(s.power_ctrl) for s in voters.values()]))))
        if sizes:
            rows.append(f"| {case.spec.name} | {len(case.model.loads)} | {len(sizes)} | "
                        f"{max(e for e, _ in sizes):.4g} | {max(c for _, c in sizes):.4g} |")
    if not rows:
        return []
    return ["## External load power (article 2.3)", "",
            "The external loads' generalized force `tau_ext` (compared above as external_force) does work `P_ext = "
            "tau_ext . qd` beside the input's `P_ctrl = u . B^T qd` (compared as power_ext; the energy balance checks "
            "`dE/dt = P_ctrl + P_ext`). Largest magnitudes over the states, medians over the backends.", "",
            "| case | loads | states | max abs P_ext (W) | max abs P_ctrl (W) |", "|---|---|---|---|---|", *rows, ""]


def _power_audit(result: GateResult) -> list[str]:
    """Section 5.5: the constraint power is zero in total but moves energy between coordinates."""
    rows = []
    for case in result.cases:
        audited = []
        for state in case.states:
            voters = state.voters("power_constr_per_coord")
            if case.model.constraints and voters:
                per = np.median([split.power_constr_per_coord for split in voters.values()], axis=0)
                ctrl = float(np.median([abs(split.power_ctrl) for split in voters.values()]))
                audited.append((state, per, ctrl))
        if not audited:
            continue
        total = max(abs(float(per.sum())) for _, per, _ in audited)
        state, per, ctrl = max(audited, key=lambda a: _transfer(a[1]))
        rows.append(f"| {case.spec.name} | {len(audited)} | {total:.3g} | {_transfer(per):.4g} | "
                    f"#{state.state.index} | {_coordinates(case.model, per, -1.0)} | "
                    f"{_coordinates(case.model, per, 1.0)} | {ctrl:.4g} |")
    if not rows:
        return []
    return ["## Constraint power audit (article 5.5)", "",
            "The constraint does no net work, `P_constr = (Jc^T lam) . qd = 0` at admissible states (compared against "
            "0 above as power_constr), but per coordinate `P_constr,i = [Jc^T lam]_i qd_i` it moves energy from some "
            "joints to others. Per case: the largest |P_constr| over the states, and the state where the constraint "
            "moves energy fastest (the power it injects into the gaining coordinates), with the joints it drains and "
            "feeds and the input power |P_ctrl| there for comparison. Median over the backends; per-coordinate power "
            "depends on the coordinates (5.5), so these are joint-chart numbers.", "",
            "| case | states | max abs P_constr (W) | largest transfer (W) | at state | from | to | "
            "abs P_ctrl there (W) |",
            "|---|---|---|---|---|---|---|---|"] + rows + [""]


def _drift_parts_section(result: GateResult) -> list[str]:
    """Article 4.5-4.6: the drift is gravity's part (the ZVCF, the drift at rest) plus the velocity products'; which
    one dominates each state (the larger max-norm, median over the backends that report both)."""
    rows = []
    for case in result.cases:
        ratios = []
        for state in case.states:
            voters = state.voters("zvcf")
            parts = [(np.abs(s.zvcf).max(), np.abs(s.drift_velocity).max()) for s in voters.values()
                     if not isinstance(s.zvcf, Unsupported) and not isinstance(s.drift_velocity, Unsupported)]
            if parts:
                gravity, velocity = np.median(np.array(parts), axis=0)
                ratios.append(np.inf if gravity == 0.0 else velocity / gravity)   # no gravity in the motion: a level plane
        if ratios:
            ratios = np.array(ratios)
            rows.append(f"| {case.spec.name} | {len(ratios)} | {int((ratios < 1).sum())} | {int((ratios >= 1).sum())} "
                        f"| {np.median(ratios):.3g} |")
    if not rows:
        return []
    return ["## The drift's parts (article 4.5-4.6)", "",
            "The drift (the ZTCF) is the zero-velocity counterfactual (ZVCF: gravity alone, the drift at the same q "
            "at rest) plus the velocity-product part `-M^-1 C qd`; each backend computes both directly and the gate "
            "compares them (zvcf, drift_velocity) and their sum with the drift (drift_parts). Per case, the states "
            "where each dominates (larger max-norm; median over the backends):", "",
            "| case | states | gravity dominates | velocity products dominate | median size ratio, velocity part to ZVCF |",
            "|---|---|---|---|---|"] + rows + [""]


def _breakdown_section(result: GateResult) -> list[str]:
    found = _breakdowns(result)
    if not found:
        return []
    groups: dict[tuple[str, str, str], list] = {}
    for case, state, backend, name, value in found:
        groups.setdefault((case.spec.name, backend, name), []).append((state.state.index, value))
    lines = ["## Breakdowns (ill-conditioned methods: reported, not failures)", "",
             "| case | backend | condition | limit | not compared | states | largest | at state |",
             "|---|---|---|---|---|---|---|---|"]
    for (case_name, backend, name), hits in groups.items():
        index, value = max(hits, key=lambda h: h[1] if h[1] == h[1] else float("inf"))
        lines.append(f"| {case_name} | {backend} | cond {name} | {BREAKDOWN_LIMITS[name]:.3g} | {_scope(name)} | "
                     f"{len(hits)} | {value:.3g} | #{index} |")
    lines.append("")
    for case, state, backend, name, value in found[:MAX_LISTED_FAILURES]:
        lines.append(f"- {case.spec.name} #{state.state.index}: {backend} {_condition(state, backend, name, value)}; "
                     f"reproduce: `{reproduce_command(case, state)}`")
    if len(found) > MAX_LISTED_FAILURES:
        lines.append(f"- ... and {len(found) - MAX_LISTED_FAILURES} more.")
    return lines + [""]


def _self_test_section(result: GateResult) -> list[str]:
    """The canaries (``crosscheck.guards.selftest``): each known fault, where it was injected, whether the gate caught it
    and named its backend, and the ratio."""
    test = result.self_test
    if test is None:
        return ["## Self-test", "", "Skipped (`--no-self-test`): this run did not prove it can see small errors.", ""]
    lines = ["## Self-test: canaries", "",
             "Known tiny faults injected into one backend's answer at fixed states; each must be caught and its "
             "backend named, or the gate has lost sensitivity. Sizes are calibrated so that each is caught at "
             "2 to 10 times its tolerance: a tolerance loosened tenfold misses them.", "",
             "| canary | case | backend | caught by | error/tolerance | named | verdict |",
             "|---|---|---|---|---|---|---|"]
    for r in test.results:
        c = r.canary
        size = f" ({c.size:.0e})" if c.size else ""
        verdict = f"skipped: {r.skipped}" if r.skipped else "ok" if r.passed else "**FAIL**"
        lines.append(f"| {c.kind}{size} | {c.case} #{c.state} | {c.backend} | {r.quantity} | {r.ratio:.3g} | "
                     f"{'yes' if r.named else 'no'} | {verdict} |")
    return lines + [""] + [f"- **{line}**" for line in test.failures()] + ([""] if test.failures() else [])


def _span(rows: np.ndarray) -> str:
    return ", ".join(f"[{lo:.3g}, {hi:.3g}]" for lo, hi in rows) if len(rows) else "-"


def _coverage_section(result: GateResult) -> list[str]:
    """What each case's sample spans (``crosscheck.guards.coverage``), and what made a sample degenerate."""
    lines = ["## Sampling coverage", "",
             "The ranges of q, qd and u over the sampled states (per coordinate, [min, max]); a sample whose rates or "
             "inputs are all zero, or whose configurations lie in a sliver of the joint ranges, fails.", "",
             "| case | states | q | qd | u | rank Jc | verdict |", "|---|---|---|---|---|---|---|"]
    problems = []
    for case in result.cases:
        cov = case.coverage
        if cov is None:
            continue
        rank = "-" if cov.constraint_rank is None else "..".join(map(str, sorted(set(cov.constraint_rank))))
        lines.append(f"| {case.spec.name} | {cov.states} | {_span(cov.q)} | {_span(cov.qd)} | {_span(cov.u)} | "
                     f"{rank} | {'**degenerate**' if cov.degenerate else 'ok'} |")
        problems += [f"- **{case.spec.name}**: {p}" for p in cov.problems]
    return lines + [""] + problems + ([""] if problems else [])


def _voters_section(result: GateResult) -> list[str]:
    """Backends that checked nothing: a required one that took part in no comparison (a failure), any backend in no
    comparison of a case or in BREAKDOWN at most of its states (flagged), and what each case's closed form covers."""
    lines = []
    for name in result.absent:
        lines.append(f"- **FAIL: {name} took part in no comparison** (named on the command line; it declined every "
                     f"case or was in BREAKDOWN everywhere). Name it with `--optional {name}` if that is expected.")
    for case in result.cases:
        voted = case.voted()
        silent = [name for name in result.backends if name not in voted]
        if silent:
            lines.append(f"- {case.spec.name}: took part in no comparison: {', '.join(silent)}")
        for name in result.backends:
            broken = sum(bool(s.breakdowns.get(name)) for s in case.states)
            if broken > len(case.states) / 2:
                lines.append(f"- {case.spec.name}: **{name} in BREAKDOWN at {broken} of {len(case.states)} states** "
                             "(it checks little here)")
        if case.closed_form:
            lines.append(f"- {case.spec.name}: closed form: {case.closed_form}")
        built = build.provenance(case.model) if reference.REFERENCE.name in result.backends else None
        if built:
            lines.append(f"- {case.spec.name}: the reference (pinocchio) is {built}")
    return (["Voters:", ""] + lines + [""]) if lines else []


#: The conditions of a task point (``crosscheck.core.tolerance.BREAKDOWN_LIMITS``): a BREAKDOWN on them is the task's.
TASK_CONDITIONS = ("task", "task_jacobian", "task_inertia")


def _task_broken(case: CaseOutcome) -> list[StateOutcome]:
    """The states where some backend was in BREAKDOWN on a task condition."""
    return [s for s in case.states if any(set(c) & set(TASK_CONDITIONS) for c in s.breakdowns.values())]


def _typical(states: list[StateOutcome]) -> StateOutcome:
    """The first of ``states`` away from the home configuration q = 0 (a stretched chain is singular anyway)."""
    return next((s for s in states if any(s.state.q)), states[0])


def task_point_lines(case: CaseOutcome) -> list[str]:
    """The task point a case used (name, body, offset, directions) and how it was chosen; when a backend was in
    BREAKDOWN on a task condition at most states, why, from the model's own point kinematics at such a state
    (``cases.task.rank_deficiency``: "task Jacobian rank 1 < 2: the point lies on the axis of joint 'link2'")."""
    tp = case.model.task_point()
    choice = tp.choice or "declared with the model"
    lines = [f"- {case.spec.name}: task point `{tp.name}` on body `{tp.body}` at {_vec(tp.offset)} m in its frame, "
             f"task directions {np.round(tp.directions, 6).tolist()}; {choice}"]
    broken = _task_broken(case)
    if broken and len(broken) > len(case.states) / 2:
        first = _typical(broken)
        why = task.rank_deficiency(case.model, np.array(first.state.q))
        worst = max(v for s in broken for c in s.breakdowns.values() for k, v in c.items() if k in TASK_CONDITIONS)
        lines.append(f"  - a task condition was in BREAKDOWN at {len(broken)} of {len(case.states)} states (worst "
                     f"{worst:.3g}); at state #{first.state.index}: " +
                     (why or "the task Jacobian has full rank there: a near-singular configuration") +
                     f". Choose another point with `--task-point BODY[:x,y,z]`.")
    return lines


#: At most this many pictures of the mechanism per report.
MAX_FIGURES = 3


def mechanism_figures(result: GateResult, report: Path) -> dict[str, str]:
    """Stick figures of the mechanism (``crosscheck.reports.plots.stick_figure``) written next to ``report`` where they help:
    for each failing case at its worst failing state, else for each case where a task condition was in BREAKDOWN at
    most states (the picture shows where the task point sits), at most :data:`MAX_FIGURES`; {case: file name}."""
    from crosscheck.reports import plots

    chosen = []
    for case in result.cases:
        failed = [s for s in case.states if s.failed]
        broken = _task_broken(case)
        if failed:
            chosen.append((case, max(failed, key=lambda s: s.worst_ratio), "worst failing state"))
        elif len(broken) > len(case.states) / 2:
            chosen.append((case, _typical(broken), "task condition in BREAKDOWN"))
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


def _verdict_line(key: str, comp: Comparison) -> str:
    """``- **key**: VERDICT (severity), worst error/tolerance r (tolerance t), outlier **x**`` and, for a
    disagreement without an outlier, how the vote came out; for a KNOWN one, the registry's reason."""
    severity = f" ({comp.severity})" if comp.severity else ""
    line = (f"- **{key}**: {comp.verdict}{severity}, worst error/tolerance {comp.worst_ratio:.3g} "
            f"(tolerance {comp.tolerance:.3g})")
    if comp.outlier:
        line += f", outlier **{comp.outlier}**"
    elif comp.verdict in (DISAGREE, KNOWN):
        line += f"; {vote(comp)}"
    if comp.verdict == KNOWN:
        line += f"; known divergence: {comp.reason}"
    return line


def _count(n: int, one: str, many: str) -> str:
    return f"{n} {one if n == 1 else many}"


def _state_suspects(state: StateOutcome) -> str:
    """The state-level suspect summary: per backend the quantities and checks it is the suspect in, and the
    disagreements no single backend explains."""
    q, c = suspects(state.comparisons.values()), suspects(state.checks.values())
    parts = [f"{name} in {_count(q.by_backend.get(name, 0), 'quantity', 'quantities')} and "
             f"{_count(c.by_backend.get(name, 0), 'check', 'checks')}"
             for name in dict.fromkeys([*q.by_backend, *c.by_backend])]
    alone = [key for key, comp in {**state.comparisons, **state.checks}.items()
             if comp.verdict == DISAGREE and suspect(comp) is None]
    if alone:
        parts.append(f"no single backend explains {', '.join(alone)}")
    return "; ".join(parts) or "none"


def _state_detail(case: CaseOutcome, state: StateOutcome, heading: str, seed: int, full: bool = True) -> list[str]:
    """One state: its vector, reproduce command, hint and suspects, then each comparison with the voters' values
    (``full``) or only the disagreeing and known ones, the agreeing ones on one line."""
    s = state.state
    lines = [f"### {heading}", "",
             f"- q = `{_vec(s.q)}`", f"- qd = `{_vec(s.qd)}`", f"- u = `{_vec(s.u)}`",
             f"- reproduce: `{reproduce_command(case, state)}`"]
    if state.hint:
        lines.append(f"- hint: {state.hint}")
    if state.failed:
        lines.append(f"- suspects: {_state_suspects(state)}")
    lines.append("")
    for name, message in state.errors.items():
        lines.append(f"- **{name} raised** `{message}`")
    for name, conditions in state.breakdowns.items():
        lines.append(f"- {name}: BREAKDOWN, not compared: " + "; ".join(
            f"{_scope(k)} ({_condition(state, name, k, v)})" for k, v in conditions.items()))
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
        lines += [f"  | {name} | `{_vec(split.quantity(quantity))}` |"
                  for name, split in state.voters(quantity).items()
                  if not isinstance(split.quantity(quantity), Unsupported)]
        if quantity in EXACT:
            lines.append(f"  | exact | `{_vec(EXACT[quantity])}` |")
        lines.append("")
    if agreeing:
        lines += [f"- agree (worst error/tolerance): {', '.join(agreeing)}", ""]
    for key, comp in state.checks.items():
        if comp.verdict not in (DISAGREE, KNOWN):
            continue
        lines += [f"{_verdict_line(key, comp)}; reproduce: "
                  f"`{check_reproduce_command(case, state, check_family(key), seed)}`", "",
                  "  | voter | value |", "  |---|---|"]
        lines += [f"  | {name} | `{_vec(value)}` |" for name, value in comp.values.items()] + [""]
    if state.splits:
        first = next(iter(state.splits.values()))
        lines.append(f"- cond(M) = {first.cond_M:.3g}, acceleration scale = {first.accel_scale:.3g}")
    return lines + [""]


def _known_section(result: GateResult) -> list[str]:
    """The disagreements the divergence registry explains, grouped by case, key and reason."""
    groups: dict[tuple[str, str, str], list] = {}
    for case in result.cases:
        for state in case.states:
            for key, comp in {**state.comparisons, **state.checks}.items():
                if comp.verdict == KNOWN:
                    groups.setdefault((case.spec.name, key, comp.reason), []).append((state, comp))
    if not groups:
        return []
    lines = ["## Known divergences (explained in the registry: reported, not failures)", "",
             "| case | quantity or check | suspect | states | worst error/tolerance | severity | at state | reason |",
             "|---|---|---|---|---|---|---|---|"]
    for (case_name, key, reason), hits in groups.items():
        state, worst = max(hits, key=lambda h: _ratio(h[1]))
        who = ", ".join(sorted({suspect(c) or "-" for _, c in hits}))
        lines.append(f"| {case_name} | {key} | {who} | {len(hits)} | {worst.worst_ratio:.3g} | {worst.severity} | "
                     f"#{state.state.index} | {reason} |")
    return lines + [""]


def _registry_section(applied: Applied | None) -> list[str]:
    """Stale entries (exercised by the run, explained nothing: a warning) and entries the run did not exercise."""
    if applied is None or not (applied.stale or applied.unexercised):
        return []
    lines = ["## Stale registry entries (warnings, not failures)", ""]
    lines += [f"- **stale**: {e.describe()} in `{applied.registry.source}` was compared in this run but explained "
              f"no disagreement; remove it if the divergence is fixed. Reason given: {e.reason}"
              for e in applied.stale]
    lines += [f"- not exercised: {e.describe()} (its backend, case or quantity was not compared in this run)"
              for e in applied.unexercised]
    return lines + [""]


def _registry_line(applied: Applied | None) -> str:
    if applied is None:
        return "- divergence registry: none"
    return (f"- divergence registry: `{applied.registry.source}`, {len(applied.registry.entries)} entries; "
            f"{applied.known} comparison(s) KNOWN, {_count(len(applied.stale), 'stale entry', 'stale entries')}")


def _self_test_line(result: GateResult) -> str:
    test = result.self_test
    if test is None:
        return "- self-test: " + ("not run (interrupted)" if result.interrupted and result.checks.self_test
                                  else "skipped")
    return f"- self-test: {sum(r.passed for r in test.results)} of {len(test.results)} canaries caught and named"


def details_path(path: str | Path) -> Path:
    """Where the details of the report at ``path`` go: next to it, ``gate.md`` -> ``gate-details.md``."""
    path = Path(path)
    return path.with_name(f"{path.stem}-details{path.suffix or '.md'}")


def write(result: GateResult, command: str, path: str | Path, applied: Applied | None = None,
          figures: dict[str, str] | None = None) -> tuple[Path, Path]:
    """Write the short report to ``path`` (:func:`summary`, linking ``figures``: :func:`mechanism_figures`) and
    everything else next to it (:func:`details`, at :func:`details_path`); the two paths."""
    path, more = Path(path), details_path(path)
    path.write_text(summary(result, command, applied, details_link=more.name, figures=figures))
    more.write_text(details(result, command, applied, summary_link=path.name))
    return path, more


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
    return summary(result, command, applied, figures=figures) + "\n" + details(result, command, applied)


def _verdict(result: GateResult) -> str:
    return "PARTIAL" if result.interrupted else "PASS" if result.passed else "FAIL"


def _failed(result: GateResult) -> list[tuple[CaseOutcome, StateOutcome]]:
    return [(c, s) for c in result.cases for s in c.states if s.failed]


def _headline(result: GateResult) -> list[str]:
    """The title, the PARTIAL warning of an interrupted run, and the verdict line with the counts."""
    n_states = sum(len(c.states) for c in result.cases)
    broken = sum(bool(s.breakdowns) for c in result.cases for s in c.states)
    known = sum(c.verdict == KNOWN for case in result.cases for s in case.states for c in _all(s))
    partial = [f"**PARTIAL REPORT: the run was interrupted {result.interrupted}.** It holds only the states "
               "evaluated until then and gives no verdict (a disagreement below is still one).", ""]
    return ["# crosscheck gate report", "", *(partial if result.interrupted else []),
            f"**{_verdict(result)}**: {len(_failed(result))} of {n_states} states disagree or fail "
            f"across {len(result.cases)} case(s) and {len(result.backends)} backends "
            f"({', '.join(result.backends)}); {known} known divergence(s) (KNOWN, not failures); "
            f"{broken} state(s) with a backend in BREAKDOWN.", ""]


def _worst_line(result: GateResult) -> str:
    """The largest error/tolerance of the run over every comparison and check, and where it was."""
    found = [(case, state, key, comp) for case in result.cases for state in case.states
             for key, comp in {**state.comparisons, **state.checks}.items() if comp.verdict != NOT_COMPARED]
    if not found:
        return "- worst error/tolerance: - (nothing compared)"
    case, state, key, comp = max(found, key=lambda f: _ratio(f[3]))
    return (f"- worst error/tolerance: {comp.worst_ratio:.3g} ({case.spec.name}, {key}, state "
            f"#{state.state.index}; below 1 agrees)")


def _run_lines(result: GateResult, command: str, applied: Applied | None) -> list[str]:
    """What was run: the command, seed and sample size, the joint limits the states keep, the self-test and the
    divergence registry."""
    return [f"- command: `{command}`", f"- seed {result.seed}, {result.samples} states per case",
            *_limits_line(result), _self_test_line(result), _registry_line(applied)]


def _policy_lines() -> list[str]:
    """The tolerance table, the severity bands and the breakdown limits the verdicts used."""
    return ["- tolerance per quantity: " + ", ".join(f"{q}: {f:g} eps x {k} scale" for q, (k, f) in TOLERANCES.items()),
            "  (accelerations: one tolerance per coordinate, |M^-1| (f + Mterm |x| + d d.|x|), the sizes of the terms"
            " summed in M and h (crosscheck.core.tolerance.acceleration_bound);",
            "  task scale = L (sum of the acceleration scales + |qd|_1^2), L the task point's lever arm)",
            "- severity of a DISAGREE by error/tolerance: " + ", ".join(
                f"{name} up to {bound:g}" if bound != float("inf") else f"{name} above (or NaN)"
                for bound, name in SEVERITY),
            "- BREAKDOWN limits: " + ", ".join(f"cond {k} > {v:.3g}" for k, v in BREAKDOWN_LIMITS.items())]


def _failures_section(result: GateResult) -> list[str]:
    """What failed the run, first: the failing states with their reproduce commands, degenerate samples, required
    backends that compared nothing, missed canaries."""
    failed = _failed(result)
    lines = []
    if failed:
        lines += ["## Disagreements", ""]
        for case, state in failed[:MAX_LISTED_FAILURES]:
            lines += _state_detail(case, state, f"{case.spec.name}, state #{state.state.index}", result.seed,
                                   full=False)
        if len(failed) > MAX_LISTED_FAILURES:
            lines += [f"... and {len(failed) - MAX_LISTED_FAILURES} more failing states.", ""]
    other = [f"- **{case.spec.name}: degenerate sample**: {p}" for case in result.cases
             for p in (case.coverage.problems if case.coverage else ())]
    other += [f"- **FAIL: {name} took part in no comparison** (named on the command line; it declined every case or "
              f"was in BREAKDOWN everywhere). Name it with `--optional {name}` if that is expected."
              for name in result.absent]
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
        known = sum(c.verdict == KNOWN for s in case.states for c in _all(s))
        broken = sum(bool(s.breakdowns) for s in case.states)
        rows.append(f"| {case.spec.name} | {case.model.n} | {len(case.states)} | "
                    f"{sum(s.failed for s in case.states)} | {known} | {broken} | "
                    f"{_where_worst(worst)} | {_where_worst(checks)} | "
                    f"{'**degenerate**' if case.coverage and case.coverage.degenerate else 'ok'} |")
    return ["## Cases", "",
            "| case | n | states | failing | KNOWN | BREAKDOWN states | worst quantity (error/tolerance, state) | "
            "worst check | sample |", "|---|---|---|---|---|---|---|---|---|"] + rows + [""]


def _where_worst(found: list[tuple[StateOutcome, str, Comparison]]) -> str:
    if not found:
        return "-"
    state, key, comp = max(found, key=lambda f: _ratio(f[2]))
    return f"{key} {comp.worst_ratio:.3g} #{state.state.index}"


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
    for case, _, backend, name, _ in _breakdowns(result):
        per_case = found.setdefault((backend, name), {})
        per_case[case.spec.name] = per_case.get(case.spec.name, 0) + 1
    parts = [f"{backend} cond {name} > {BREAKDOWN_LIMITS[name]:.3g} (" + ", ".join(
        f"{case} {_count(n, 'state', 'states')}" for case, n in per_case.items()) + ")"
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
            figures: dict[str, str] | None = None) -> str:
    """The report's first part, short: the verdict, a failing run's failures with their reproduce commands, what
    was run, one line per case, the worst ratio, what was checked and skipped, the task point of each case where a
    task condition was in BREAKDOWN at most states and why, the pictures of the mechanism (``figures``);
    ``details_link`` the file holding :func:`details` (None: they follow in the same text)."""
    where = f"[{details_link}]({details_link})" if details_link else "below"
    lines = _headline(result) + _failures_section(result)
    lines += _run_lines(result, command, applied) + [_worst_line(result)] + _checked_lines(result)
    lines += [line for case in result.cases if len(explained := task_point_lines(case)) > 1 for line in explained]
    lines += [f"- details {where}: suspects, voters, task points, per-quantity table, self-test, sampling coverage, "
              "known divergences, breakdowns, invariance and conservation checks, power audit, external load power, "
              "the drift's parts, worst state per case, timing, tolerance policy", ""]
    lines += figure_lines(figures or {})
    lines += _case_table(result)
    return "\n".join(lines) + "\n"


def details(result: GateResult, command: str, applied: Applied | None = None, summary_link: str | None = None) -> str:
    """The report's second part: the tolerance policy, suspects, voters, task points, the per-quantity table, then
    each section (self-test, coverage, known divergences, stale registry entries, breakdowns, checks, power audit,
    the drift's parts), the worst state per case and the timing; ``summary_link`` the file holding :func:`summary`,
    if any."""
    back = f" (summary: [{summary_link}]({summary_link}))" if summary_link else ""
    lines = [f"# crosscheck gate report: details{back}", "",
             f"**{_verdict(result)}**; command `{command}`, seed {result.seed}.", ""]
    lines += _policy_lines() + ["", "## Summary", "", "Comparisons per verdict (quantities and checks) and states:",
                                ""]
    lines += _counts_rows(result) + [""]
    lines += _suspects_section(result)
    lines += _voters_section(result)
    lines += ["Task points:", ""] + [line for case in result.cases for line in task_point_lines(case)] + [""]
    lines += ["Per quantity:", "",
              "| case | n | quantity | agree | DISAGREE | KNOWN | not compared | worst error/tolerance | severity | "
              "at state | not supplied by |",
              "|---|---|---|---|---|---|---|---|---|---|---|"]
    for case in result.cases:
        lines += _summary_rows(case)
    lines.append("")
    lines += _self_test_section(result)
    lines += _coverage_section(result)
    lines += _known_section(result)
    lines += _registry_section(applied)
    lines += _breakdown_section(result)
    lines += _checks_section(result)
    lines += _power_audit(result)
    lines += _external_power(result)
    lines += _drift_parts_section(result)
    lines += _worst_states_section(result)
    lines += _timing_section(result)
    return "\n".join(lines) + "\n"


def _worst_states_section(result: GateResult) -> list[str]:
    lines = ["## Worst state per case", ""]
    for case in result.cases:
        worst = max(case.states, key=lambda s: s.worst_ratio, default=None)
        if worst is not None:
            lines += _state_detail(case, worst, f"{case.spec.name}, state #{worst.state.index}", result.seed)
    return lines


def _timing_section(result: GateResult) -> list[str]:
    lines = ["## Timing (varies run to run)", "", "| case | backend | first call (s, includes preparation) | "
             "per state (ms) |", "|---|---|---|---|"]
    for case in result.cases:
        for name in result.backends:
            if name in case.per_state_s:
                lines.append(f"| {case.spec.name} | {name} | {case.first_call_s[name]:.3f} | "
                             f"{1e3 * case.per_state_s[name]:.3f} |")
    return lines
