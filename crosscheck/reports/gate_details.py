"""The gate report's second part (``NAME-details.md`` next to the summary): the harness's internal errors (with their
tracebacks' frames in the project), the tolerance policy, counts per verdict, suspects, voters, the task points, the
per-quantity table, the self-test, coverage, known divergences, stale registry entries, breakdowns, the invariance and
conservation checks, the constraint power audit, the external load power, the drift's parts, the worst state per case
and the timing (the only part that changes between runs of one seed)."""

from __future__ import annotations

import numpy as np

from crosscheck.core import sampling
from crosscheck.core.compare import AGREE, DISAGREE, KNOWN, NOT_COMPARED, suspect, suspects
from crosscheck.core.tolerance import BREAKDOWN_LIMITS, quantities
from crosscheck.engine.divergences import Applied
from crosscheck.engine.outcomes import CaseOutcome, GateResult, StateOutcome
from crosscheck.references.pinocchio import build, reference
from crosscheck.reports import gate_closeness
from crosscheck.reports.gate_lines import (MAX_LISTED_FAILURES, VERDICTS, all_comparisons, check_groups, condition_text,
                                           internal_lines, no_chart, policy_lines, ratio_of, reproduce_command,
                                           scope_text, sections, severity_of, state_detail, task_point_lines, vec_text,
                                           verdict_text)
from formalisms.interface import Unsupported


def _summary_rows(case: CaseOutcome) -> list[str]:
    rows = []
    for quantity in quantities(case.model):
        comps = [(s, s.comparisons[quantity]) for s in case.states if quantity in s.comparisons]
        counts = {v: sum(c.verdict == v for _, c in comps) for v in VERDICTS}
        worst_state, worst = max(comps, key=lambda sc: ratio_of(sc[1]), default=(None, None))
        ratio = f"{worst.worst_ratio:.3g}" if worst else "-"
        where = f"#{worst_state.state.index}" if worst_state else "-"
        unsupported = sorted({name for _, c in comps for name in c.not_compared})
        rows.append(f"| {case.spec.name} | {case.model.n} | {quantity} | {counts[AGREE]} | {counts[DISAGREE]} | "
                    f"{counts[KNOWN]} | {counts[NOT_COMPARED]} | {ratio} | {severity_of(worst)} | {where} | "
                    f"{', '.join(unsupported) or '-'} |")
    errors = sum(bool(s.errors) for s in case.states)
    if errors:
        rows.append(f"| {case.spec.name} | {case.model.n} | backend errors | - | {errors} | - | - | - | - | - | - |")
    return rows


def _counts_rows(result: GateResult) -> list[str]:
    """Per case and in total: comparisons (quantities and checks) per verdict, and states failing, in BREAKDOWN,
    with a backend error."""
    rows, total = [], [0] * 8
    for case in result.cases:
        found = [c for s in case.states for c in all_comparisons(s)]
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
            "backend behind a frame law; or the shared code every backend moved together with, a chart map or a frame "
            "move):", "",
            "| case | suspect | quantities | checks | states |", "|---|---|---|---|---|"] + rows + [""]


def _checks_section(result: GateResult) -> list[str]:
    rows, totals = [], {}
    for case in result.cases:
        for family, found in check_groups(case).items():
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
    charts_used = [f"{case.spec.name}: {', '.join(case.charts) or no_chart(case.model)}" for case in result.cases]
    frames_used = [f"{case.spec.name}: " + "; ".join(
        f"{f.name} = (R = {vec_text(f.rotation.ravel())}, t = {vec_text(f.translation)})" for f in case.frames)
        for case in result.cases if case.frames]
    lines += ["Charts per case: " + "; ".join(charts_used) + ".", ""]
    lines += [f"- frames {line}" for line in frames_used] + [""]
    return lines


def limits_line(result: GateResult) -> list[str]:
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


def breakdowns_of(result: GateResult) -> list[tuple[CaseOutcome, StateOutcome, str, str, float]]:
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
    found = breakdowns_of(result)
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
        lines.append(f"| {case_name} | {backend} | cond {name} | {BREAKDOWN_LIMITS[name]:.3g} | {scope_text(name)} | "
                     f"{len(hits)} | {value:.3g} | #{index} |")
    lines.append("")
    for case, state, backend, name, value in found[:MAX_LISTED_FAILURES]:
        lines.append(f"- {case.spec.name} #{state.state.index}: {backend} {condition_text(state, backend, name, value)}; "
                     f"reproduce: `{reproduce_command(case, state)}`")
    if len(found) > MAX_LISTED_FAILURES:
        lines.append(f"- ... and {len(found) - MAX_LISTED_FAILURES} more.")
    return lines + [""]


def _self_test_section(result: GateResult) -> list[str]:
    """The canaries (``crosscheck.guards.selftest``): each known fault, where it was injected, whether the gate caught
    it and named its backend, and the ratio."""
    test = result.self_test
    if test is None:
        return ["## Self-test", "", "Skipped (`--no-self-test`): this run did not prove it can see small errors.", ""]
    lines = ["## Self-test: canaries", "",
             "A known tiny fault per check of the gate (the comparisons, the multipliers on cases with several "
             "constraint rows, the charts, the moved scenes, conservation, the linearizations and equilibria, the "
             "conditions audit, the closed forms, the sampling coverage), each run through that check as the gate "
             "runs it: the check itself must catch it and name the faulty voter, or it has lost its power. Sizes are "
             "calibrated so that each is caught at 2 to 10 times its tolerance: a check loosened tenfold misses them.",
             "",
             "| check | canary | case | caught by | error/tolerance | named | verdict |",
             "|---|---|---|---|---|---|---|"]
    for r in test.results:
        c = r.canary
        size = f" ({c.size:.2g})" if c.size else ""
        what = f"{c.kind}{size}" + (f" of {c.quantity}" if c.quantity else "") + (f" in {c.backend}" if c.backend
                                                                                  else "")
        verdict = (f"**internal error**: {r.error}" if r.error else f"skipped: {r.skipped}" if r.skipped
                   else "ok" if r.passed else "**FAIL**")
        ratio = "-" if c.check == "coverage" or r.skipped else f"{r.ratio:.3g}"
        lines.append(f"| {c.check} | {what} | {c.case} #{c.state} | {r.where.replace('|', '/')} | {ratio} | "
                     f"{'-' if c.check == 'coverage' else 'yes' if r.named else 'no'} | {verdict} |")
    return lines + [""] + [f"- **{line}**" for line in test.failures()] + ([""] if test.failures() else [])


def _span(rows: np.ndarray) -> str:
    return ", ".join(f"[{lo:.3g}, {hi:.3g}]" for lo, hi in rows) if len(rows) else "-"


def _coverage_section(result: GateResult) -> list[str]:
    """What each case's sample spans (``crosscheck.guards.coverage``), which joint limits it was measured against,
    and what made a sample degenerate."""
    lines = ["## Sampling coverage", "",
             "The ranges of q, qd and u over the sampled states (per coordinate, [min, max]); a sample whose rates or "
             "inputs are all zero, whose states repeat, whose configurations lie in a sliver of the joint ranges, pile "
             "into a band or at the joint limits, or whose model's joint limits differ from its file's (a loader "
             "finding), fails.", "",
             "| case | states | q | qd | u | rank Jc | verdict |", "|---|---|---|---|---|---|---|"]
    problems, limits = [], []
    for case in result.cases:
        cov = case.coverage
        if cov is None:
            continue
        rank = "-" if cov.constraint_rank is None else "..".join(map(str, sorted(set(cov.constraint_rank))))
        lines.append(f"| {case.spec.name} | {cov.states} | {_span(cov.q)} | {_span(cov.qd)} | {_span(cov.u)} | "
                     f"{rank} | {'**degenerate**' if cov.degenerate else 'ok'} |")
        problems += [f"- **{case.spec.name}**: {p}" for p in cov.problems]
        if cov.limits_source and (case.model.source is not None or any(lim is not None for lim in cov.limits)):
            limits.append(f"- {case.spec.name}: joint limits measured against {cov.limits_source}")
    return lines + [""] + limits + ([""] if limits else []) + problems + ([""] if problems else [])


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
        state, worst = max(hits, key=lambda h: ratio_of(h[1]))
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


def details(result: GateResult, command: str, applied: Applied | None = None, summary_link: str | None = None,
            closeness: gate_closeness.Closeness | None = None) -> str:
    """The report's second part: the tolerance policy, suspects, voters, task points, the per-quantity table, then
    each section (self-test, coverage, known divergences, stale registry entries, breakdowns, checks, power audit,
    the drift's parts), the worst state per case and the timing; ``summary_link`` the file holding :func:`summary`,
    if any; ``closeness`` the per-backend table's cells (``gate_closeness.of``, computed here if None)."""
    back = f" (summary: [{summary_link}]({summary_link}))" if summary_link else ""
    body = sections(result, [
        ("tolerance policy", lambda: policy_lines() + [""]),
        ("counts", lambda: ["## Summary", "", "Comparisons per verdict (quantities and checks) and states:", ""]
         + _counts_rows(result) + [""]),
        ("suspects", lambda: _suspects_section(result)),
        ("voters", lambda: _voters_section(result)),
        ("task points", lambda: ["Task points:", ""] + [line for case in result.cases
                                                        for line in task_point_lines(case)] + [""]),
        ("per quantity", lambda: _per_quantity(result)),
        ("per-backend closeness per case", lambda: gate_closeness.case_closeness_section(result, closeness)),
        ("self-test", lambda: _self_test_section(result)),
        ("coverage", lambda: _coverage_section(result)),
        ("known divergences", lambda: _known_section(result)),
        ("registry", lambda: _registry_section(applied)),
        ("breakdowns", lambda: _breakdown_section(result)),
        ("checks", lambda: _checks_section(result)),
        ("power audit", lambda: _power_audit(result)),
        ("external power", lambda: _external_power(result)),
        ("drift parts", lambda: _drift_parts_section(result)),
        ("worst states", lambda: _worst_states_section(result)),
        ("timing", lambda: _timing_section(result))])
    head = sections(result, [("details headline", lambda: [
        f"# crosscheck gate report: details{back}", "",
        f"**{verdict_text(result)}**; command `{command}`, seed {result.seed}.", ""])])
    found = sections(result, [("internal errors", lambda: internal_lines(result, traces=True))])
    return "\n".join(head + found + body) + "\n"


def _per_quantity(result: GateResult) -> list[str]:
    lines = ["Per quantity:", "",
             "| case | n | quantity | agree | DISAGREE | KNOWN | not compared | worst error/tolerance | severity | "
             "at state | not supplied by |",
             "|---|---|---|---|---|---|---|---|---|---|---|"]
    for case in result.cases:
        lines += _summary_rows(case)
    return lines + [""]


def _worst_states_section(result: GateResult) -> list[str]:
    lines = ["## Worst state per case", ""]
    for case in result.cases:
        worst = max(case.states, key=lambda s: s.worst_ratio, default=None)
        if worst is not None:
            lines += state_detail(case, worst, f"{case.spec.name}, state #{worst.state.index}", result.seed)
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
