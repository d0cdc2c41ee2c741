"""Markdown report of a gate run: the summary (verdict, counts, suspects) first, then every disagreement with its
severity, vote, hint and reproduce command, the known divergences, stale registry entries, breakdowns, the checks,
the constraint power audit and the worst states.

Same seed, same report byte for byte, apart from the timing section at the end.
"""

from __future__ import annotations

import shlex

import numpy as np

from crosscheck import backends, charts, reference
from crosscheck.compare import (AGREE, DISAGREE, KNOWN, NOT_COMPARED, SEVERITY, Comparison, suspect, suspects,
                                vote)
from crosscheck.gate import CaseOutcome, GateResult, StateOutcome
from crosscheck.registry import Applied
from formalisms.interface import Unsupported
from crosscheck.tolerance import BREAKDOWN_LIMITS, BREAKDOWN_SCOPE, EXACT, TOLERANCES, quantities

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
    """The canaries (``crosscheck.selftest``): each known fault, where it was injected, whether the gate caught it
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
    """What each case's sample spans (``crosscheck.coverage``), and what made a sample degenerate."""
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
        built = reference.provenance(case.model) if reference.REFERENCE.name in result.backends else None
        if built:
            lines.append(f"- {case.spec.name}: the reference (pinocchio) is {built}")
    return (["Voters:", ""] + lines + [""]) if lines else []


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


def render(result: GateResult, command: str, applied: Applied | None = None) -> str:
    """The whole report as markdown; ``command`` is the gate command that produced it, ``applied`` the divergence
    registry as applied to ``result`` (``crosscheck.registry.apply``), if any."""
    verdict = "PARTIAL" if result.interrupted else "PASS" if result.passed else "FAIL"
    n_states = sum(len(c.states) for c in result.cases)
    failed = [(c, s) for c in result.cases for s in c.states if s.failed]
    broken = sum(bool(s.breakdowns) for c in result.cases for s in c.states)
    known = sum(c.verdict == KNOWN for case in result.cases for s in case.states for c in _all(s))
    partial = [f"**PARTIAL REPORT: the run was interrupted {result.interrupted}.** It holds only the states "
               "evaluated until then and gives no verdict (a disagreement below is still one).", ""]
    lines = ["# crosscheck gate report", "", *(partial if result.interrupted else []),
             f"**{verdict}**: {len(failed)} of {n_states} states disagree or fail "
             f"across {len(result.cases)} case(s) and {len(result.backends)} backends "
             f"({', '.join(result.backends)}); {known} known divergence(s) (KNOWN, not failures); "
             f"{broken} state(s) with a backend in BREAKDOWN.", "",
             f"- command: `{command}`", f"- seed {result.seed}, {result.samples} states per case",
             _self_test_line(result),
             _registry_line(applied),
             "- tolerance per quantity: " + ", ".join(f"{q}: {f:g} eps x {k} scale"
                                                     for q, (k, f) in TOLERANCES.items()),
             "  (accelerations: one tolerance per coordinate, |M^-1| (f + Mterm |x| + d d.|x|), the sizes of the terms"
             " summed in M and h (crosscheck.tolerance.acceleration_bound);",
             "  task scale = L (sum of the acceleration scales + |qd|_1^2), L the task point's lever arm)",
             "- severity of a DISAGREE by error/tolerance: " + ", ".join(
                 f"{name} up to {bound:g}" if bound != float("inf") else f"{name} above (or NaN)"
                 for bound, name in SEVERITY),
             "- BREAKDOWN limits: " + ", ".join(f"cond {k} > {v:.3g}" for k, v in BREAKDOWN_LIMITS.items()), "",
             "## Summary", "",
             "Comparisons per verdict (quantities and checks) and states:", ""]
    lines += _counts_rows(result) + [""]
    lines += _suspects_section(result)
    lines += _voters_section(result)
    lines += ["Per quantity:", "",
              "| case | n | quantity | agree | DISAGREE | KNOWN | not compared | worst error/tolerance | severity | "
              "at state | not supplied by |",
              "|---|---|---|---|---|---|---|---|---|---|---|"]
    for case in result.cases:
        lines += _summary_rows(case)
    lines.append("")
    if failed:
        lines += ["## Disagreements", ""]
        for case, state in failed[:MAX_LISTED_FAILURES]:
            lines += _state_detail(case, state, f"{case.spec.name}, state #{state.state.index}", result.seed,
                                   full=False)
        if len(failed) > MAX_LISTED_FAILURES:
            lines += [f"... and {len(failed) - MAX_LISTED_FAILURES} more failing states.", ""]
    lines += _self_test_section(result)
    lines += _coverage_section(result)
    lines += _known_section(result)
    lines += _registry_section(applied)
    lines += _breakdown_section(result)
    lines += _checks_section(result)
    lines += _power_audit(result)
    lines += _drift_parts_section(result)
    lines += ["## Worst state per case", ""]
    for case in result.cases:
        worst = max(case.states, key=lambda s: s.worst_ratio, default=None)
        if worst is not None:
            lines += _state_detail(case, worst, f"{case.spec.name}, state #{worst.state.index}", result.seed)
    lines += ["## Timing (varies run to run)", "", "| case | backend | first call (s, includes preparation) | "
              "per state (ms) |", "|---|---|---|---|"]
    for case in result.cases:
        for name in result.backends:
            if name in case.per_state_s:
                lines.append(f"| {case.spec.name} | {name} | {case.first_call_s[name]:.3f} | "
                             f"{1e3 * case.per_state_s[name]:.3f} |")
    return "\n".join(lines) + "\n"
