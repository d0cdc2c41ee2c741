"""The stability report: ``stability.md`` (tables and conclusions from the numbers) and one PNG chart per path;
:func:`write_report` measures the paths (``crosscheck.campaigns.stability``) and writes both.

Everything here is computed from :class:`crosscheck.campaigns.stability.PathResult` values, so the same run gives the
same report byte for byte, apart from the total runtime on its last line.
"""

from __future__ import annotations

import time
from pathlib import Path
from typing import Sequence

from crosscheck import backends
from crosscheck.campaigns import stability
from crosscheck.campaigns.stability import Measurement, PathResult
from crosscheck.checks.charts import GIMBAL_LIMIT as GIMBAL
from crosscheck.core.compare import DISAGREE
from crosscheck.reports import plots

#: Short backend labels for the tables (a plugin keeps its name).
SHORT = {"euler_lagrange": "EL", "newton_euler": "NE", "screw": "screw", "operational_space": "OS",
         "geometric": "geom", "pinocchio": "pin"}
CONDITION_LABELS = {"M": "cond M", "task": "cond task", "constraint": "cond S"}
#: Relative errors below this are drawn at it (an exact answer has relative error 0).
FLOOR = 1e-17


def _g(x: float) -> str:
    return "-" if x != x else ("inf" if x == float("inf") else ("0" if x == 0 else f"{x:.1e}"))


def _short(name: str) -> str:
    return SHORT.get(name, name)


def worst_error(m: Measurement, backend: str) -> float:
    """The backend's largest relative error over the measured quantities (NaN when not evaluated)."""
    return max(m.errors.get(backend, {}).values(), default=float("nan"))


def broken(m: Measurement, backend: str) -> bool:
    """Whether the gate leaves ``backend`` out of a measured quantity here (BREAKDOWN or an error)."""
    return backend in m.point.backends and bool(m.left_out(backend))


def first(result: PathResult, test) -> float | None:
    """The path parameter of the first point where ``test(measurement)`` holds, else None."""
    return next((m.point.x for m in result.measurements if test(m)), None)


def _cell(m: Measurement, backend: str) -> str:
    if backend not in m.point.backends:
        return ""
    marks = {"ERROR": " E", DISAGREE: " D"}.get(m.verdicts[backend], "")
    if any(b == backend for b, _ in m.over.get("silent", ())):
        marks += " !"
    return _g(worst_error(m, backend)) + (" B" if broken(m, backend) else "") + marks


def _gate_cell(m: Measurement) -> str:
    """The gate's verdict: its alarms, else the BREAKDOWN conditions by backend, else agree."""
    if m.alarms:
        return "**" + "; ".join(m.alarms) + "**"
    groups: dict[str, list[str]] = {}
    for backend, conditions in m.breakdowns.items():
        key = ", ".join(f"{name} {value:.0e}" if name in ("task", "constraint") else name
                        for name, value in sorted(conditions.items()))
        groups.setdefault(key, []).append(_short(backend))
    return "; ".join(f"BREAKDOWN {'/'.join(b)} ({k})" for k, b in groups.items()) or "agree"


def point_table(result: PathResult) -> list[str]:
    names, conds = result.backends, ("M",) + result.path.conditions
    head = ([result.path.parameter] + [CONDITION_LABELS.get(c, f"cond {c}") for c in conds]
            + [_short(b) for b in names] + ["true err / tol", "gate"])
    lines = ["| " + " | ".join(head) + " |", "|" + "---|" * len(head)]
    for m in result.measurements:
        row = ([f"{m.point.x:.3g}"] + [_g(m.conditions.get(c, float("nan"))) for c in conds]
               + [_cell(m, b) for b in names] + [_g(m.voting_ratio()) if m.tolerances else "-", _gate_cell(m)])
        lines.append("| " + " | ".join(row) + " |")
    return lines


def _over_tolerance(m: Measurement, backend: str) -> bool:
    return any(backend == b for pairs in m.over.values() for b, _ in pairs)


def backend_table(result: PathResult) -> list[str]:
    """Per backend: error at the start, largest error and where, largest true error/tolerance while voting, where
    BREAKDOWN is first flagged and where the true error first exceeds the tolerance."""
    lines = ["| backend | rel. error at start | largest rel. error (at) | largest true err / tol while voting (at) "
             "| BREAKDOWN at | first true err > tol |", "|---|---|---|---|---|---|"]
    for b in result.backends:
        ms = [m for m in result.measurements if b in m.point.backends]
        worst = max(ms, key=lambda m: _sortable(worst_error(m, b)))
        voting = [(r, m.point.x) for m in ms for q, r in m.ratios.get(b, {}).items()
                  if q not in m.left_out(b) and r == r]
        ratio, at = max(voting, default=(float("nan"), None))
        lines.append(f"| {b} | {_g(worst_error(ms[0], b))} | {_g(worst_error(worst, b))} ({worst.point.x:.3g}) "
                     f"| {_g(ratio)}{'' if at is None else f' ({at:.3g})'} "
                     f"| {flagged_at(result, b)} "
                     f"| {_x(first(result, lambda m: _over_tolerance(m, b)))} |")
    return lines


def _sortable(x: float) -> float:
    return -1.0 if x != x else x


def flagged_at(result: PathResult, backend: str) -> str:
    """Where the gate leaves ``backend`` out of a measured quantity: the range of the path parameter and the number
    of points, or ``never``."""
    xs = [m.point.x for m in result.measurements if broken(m, backend)]
    if not xs:
        return "never"
    return f"{min(xs):.3g} to {max(xs):.3g} ({len(xs)} points)" if len(xs) > 1 else f"{xs[0]:.3g} (1 point)"


def _x(x: float | None) -> str:
    return "never" if x is None else f"{x:.3g}"


def conclusions(result: PathResult) -> list[str]:
    """What the numbers show on this path: errors above tolerance by kind, false alarms, unflagged errors."""
    ms = result.measurements
    silent = [(m.point.x, b, q) for m in ms for b, q in m.over.get("silent", ())]
    caught = sum(len(m.over.get("caught", ())) for m in ms)
    flagged = sum(len(m.over.get("flagged", ())) for m in ms)
    alarms = [m for m in ms if m.false_alarm]
    blind = [m.point.x for m in ms if not m.tolerances]
    out = [_growth(result), f"- True error above the gate's tolerance: {flagged} (backend, quantity) cases under "
           f"BREAKDOWN, {caught} caught by a DISAGREE, {len(silent)} silent."]
    out += [f"  - **silent: {b} {q} at {result.path.parameter} = {x:.3g}** (a real finding)" for x, b, q in silent]
    out.append("- False alarms (a DISAGREE while every true error is within tolerance): "
               + (", ".join(f"at {m.point.x:.3g} ({'; '.join(m.alarms)})" for m in alarms) if alarms else "none."))
    ratios = [(m.voting_ratio(), m.point.x) for m in ms if m.tolerances]
    if ratios:
        (low, x_low), (high, x_high) = min(ratios), max(ratios)
        out.append(f"- Sensitivity: the largest true err / tol among the voting backends runs from {_g(low)} "
                   f"(at {x_low:.3g}) to {_g(high)} (at {x_high:.3g}): the tolerance is 1 / ratio times the largest "
                   "true error there, the room a wrong answer has before it is caught.")
    if blind:
        out.append(f"- {len(blind)} points with every backend in BREAKDOWN (from {blind[0]:.3g} on): the gate "
                   "compares nothing there, so no tolerance; their true errors are in the table.")
    notes: dict[str, list[str]] = {}
    for b in result.backends:
        note = _breakdown_note(result, b)
        if note:
            notes.setdefault(note, []).append(b)
    out += [f"- {', '.join(names)}: {note}" for note, names in notes.items()]
    return out


def _growth(result: PathResult) -> str:
    """Per backend, the largest relative error on the path over the one at its start."""
    parts = []
    for b in result.backends:
        errors = [worst_error(m, b) for m in result.measurements if b in m.point.backends]
        start, top = errors[0], max(errors)
        growth = "no finite answer at some points" if top == float("inf") else (
            f"x {top / start:.2g}" if start > 0 else f"up to {_g(top)}")
        parts.append(f"{_short(b)} {growth}")
    return "- Error growth (largest relative error on the path / at its start): " + ", ".join(parts) + "."


def _breakdown_note(result: PathResult, b: str) -> str:
    """Where ``b`` is in BREAKDOWN and how wrong it was there, or where its true error first exceeds the tolerance
    and whether BREAKDOWN was flagged at an earlier point of the path; empty when neither happens."""
    ms = result.measurements
    flag = first(result, lambda m: broken(m, b))
    wrong = first(result, lambda m: _over_tolerance(m, b))
    if wrong is not None:
        order = [m.point.x for m in ms]
        if flag is not None and order.index(flag) <= order.index(wrong):
            return f"true error first above tolerance at {wrong:.3g}; BREAKDOWN flagged before, from {flag:.3g}."
        return (f"true error first above tolerance at {wrong:.3g}; BREAKDOWN "
                f"{'only from ' + format(flag, '.3g') if flag is not None else 'never'}: **not flagged before**.")
    if flag is None:
        return ""
    under = [m for m in ms if broken(m, b)]
    rel = max(worst_error(m, b) for m in under)
    ratios = [r for m in under for r in [_ratio(m, b)] if r == r]
    return (f"BREAKDOWN at {flagged_at(result, b)}, largest relative error there {_g(rel)}; "
            + (f"largest true err / tol there {_g(max(ratios))}: a conservative flag." if ratios else
               "the gate has no tolerance there (every backend left out)."))


def summary_table(results: list[PathResult]) -> list[str]:
    lines = ["| path | points | largest true err / tol while voting | > tol: flagged / caught / silent "
             "| false alarms | BREAKDOWN at |", "|---|---|---|---|---|---|"]
    for r in results:
        ms = r.measurements
        counts = "/".join(str(sum(len(m.over.get(k, ())) for m in ms)) for k in ("flagged", "caught", "silent"))
        groups: dict[str, list[str]] = {}
        for backend in r.backends:
            groups.setdefault(flagged_at(r, backend), []).append(_short(backend))
        seen = "; ".join(f"{'/'.join(names)}: {where}" for where, names in groups.items() if where != "never") or "none"
        lines.append(f"| [{r.path.name}](#{r.path.name}) | {len(ms)} | {_g(max(m.voting_ratio() for m in ms))} "
                     f"| {counts} | {sum(m.false_alarm for m in ms)} | {seen} |")
    return lines


INTRO = """\
Error and condition numbers along paths into trouble. At every point each backend's drift, ctrl, total and (with
constraints) lam are compared with the exact split of `crosscheck.references.precise` (mpmath, 50 digits): the
**relative error** is `max|value - exact| / max|exact|`, the **true err / tol** the absolute error over the tolerance
the gate uses for that quantity at that state. The verdicts are the gate's own (`gate.CaseSetup.evaluate`: the same
comparisons, tolerances, BREAKDOWN rule and, unless a path says otherwise, the chart, frame and conservation checks).

A true error above its tolerance is *flagged* when the gate has the backend in BREAKDOWN for that quantity, *caught*
when the gate's comparison of it is a DISAGREE involving the backend, and *silent* otherwise (the tolerance policy
let a real error through). A *false alarm* is a DISAGREE (comparison or check) or a backend error while every true
error is within its tolerance.

Cells: the backend's largest relative error over the measured quantities; `B` the gate leaves it out of a
measured quantity there (BREAKDOWN), `D` it is in a disagreeing pair, `!` a silent error, `E` it raised, empty:
not evaluated; `inf` a non-finite answer (NaN). In the charts a triangle on the top edge marks an infinite value.
`true err / tol` is the largest over the backends and quantities that vote there (`-`: the gate compared nothing).
`cond task` is cond(J M^-1 J^T) of the tip (the operational-space backend's BREAKDOWN condition, limit 1e3; the
backends that report Lambda stop voting on it alone above 1e8), `cond S` of `Jc M^-1 Jc^T` (limit 1e8).
"""


def render(results: list[PathResult], quick: bool, seconds: float) -> str:
    lines = ["# Stability maps", "", f"Generated by `crosscheck stability{' --quick' if quick else ''}`.", "",
             INTRO, "## Summary", "", *summary_table(results), ""]
    for r in results:
        lines += [f"## {r.path.name}", "", f"**{r.path.title}.**" + (f" {r.path.note}" if r.path.note else ""), "",
                  f"![{r.path.name}](stability_{r.path.name}.png)", "", *conclusions(r), "", *backend_table(r), "",
                  *point_table(r), ""]
        if has_chart(r):
            lines += chart_section(r)
    lines.append(f"Total runtime: {seconds:.0f} s.")
    return "\n".join(lines) + "\n"


def _spans(xs: list[float], flags: list[bool]) -> list[tuple[float, float]]:
    """Intervals around the flagged points, bounded by the geometric midpoints to their neighbours."""
    edges = [xs[0]] + [(a * b) ** 0.5 for a, b in zip(xs, xs[1:])] + [xs[-1]]
    return [(edges[i], edges[i + 1]) for i, f in enumerate(flags) if f]


def _line(ax, points, label, marker, colour=None) -> None:
    """Finite points as a line; an infinite one (no finite answer, or a singular matrix) as a triangle at the top."""
    finite = [(x, y) for x, y in points if y < float("inf")]
    line, = (ax.loglog(*zip(*finite), marker=marker, ms=3, label=label, color=colour) if finite
             else ax.loglog([], [], label=label, color=colour))
    top = [x for x, y in points if y == float("inf")]
    if top:
        ax.plot(top, [1.0] * len(top), "^", ms=5, color=line.get_color(), transform=ax.get_xaxis_transform(),
                clip_on=False)


def _legends_outside(err, tol, cond) -> None:
    """The voters' legend right of the error panel (the tolerance panel has the same lines) and the conditions'
    right of theirs, outside the data."""
    err.legend(loc="upper left", bbox_to_anchor=(1.01, 1.0), frameon=False)
    cond.legend(loc="upper left", bbox_to_anchor=(1.01, 1.0), frameon=False)
    tol.text(1.02, 0.5, "colours as above;\ndashed: the limit 1", transform=tol.transAxes, va="center")


def plot(result: PathResult, file) -> None:
    """Three panels against the path parameter (log-log): relative error per backend, true error over the gate's
    tolerance with the line 1, condition numbers; points where the gate has some backend in BREAKDOWN for a
    measured quantity shaded, an infinite value (a NaN answer, a singular matrix) a triangle on the top edge."""
    from matplotlib import ticker

    plt = plots.pyplot()

    ms, path = result.measurements, result.path
    xs = [m.point.x for m in ms]
    fig, (err, tol, cond) = plt.subplots(3, 1, figsize=(plots.WIDTH_IN, 8.0), sharex=True, layout="constrained")
    for b in result.backends:
        colour = plots.backend_colour(b, result.backends)
        _line(err, [(m.point.x, max(worst_error(m, b), FLOOR)) for m in ms if b in m.point.backends], _short(b), "o",
              colour)
        _line(tol, [(m.point.x, max(r, FLOOR)) for m in ms for r in [_ratio(m, b)] if r == r], _short(b), "o", colour)
    for c in ("M",) + path.conditions:
        _line(cond, [(m.point.x, m.conditions[c]) for m in ms if c in m.conditions],
              CONDITION_LABELS.get(c, f"cond {c}"), "s")
    tol.axhline(1.0, color="k", lw=0.8, ls="--")
    flags = [any(broken(m, b) for b in m.point.backends) for m in ms]
    who = sorted({_short(b) for m in ms for b in m.point.backends if broken(m, b)})
    for ax in (err, tol, cond):
        for i, (lo, hi) in enumerate(_spans(xs, flags)):
            ax.axvspan(lo, hi, color="tab:red", alpha=0.12, lw=0,
                       label=f"BREAKDOWN ({', '.join(who)})" if i == 0 and ax is err else None)
        ax.grid(True, which="major", alpha=0.3)
    if xs[0] > xs[-1]:
        err.invert_xaxis()
    if max(xs) / min(xs) < 1e3:            # a short range (the chain lengths): label 1, 2, 5, 10, 20, 50 plainly
        cond.xaxis.set_major_locator(ticker.LogLocator(subs=(1.0, 2.0, 5.0)))
        cond.xaxis.set_major_formatter(ticker.FuncFormatter(lambda v, _: f"{v:g}"))
        cond.xaxis.set_minor_formatter(ticker.NullFormatter())
    err.set(title=path.title, ylabel="relative error")
    tol.set(ylabel="true error / tolerance")
    cond.set(ylabel="condition number", xlabel=path.parameter)
    _legends_outside(err, tol, cond)
    plots.save(fig, file)


def _ratio(m: Measurement, backend: str) -> float:
    """The backend's largest true error over the gate's tolerance (NaN where the gate compared nothing)."""
    ratios = [r for r in m.ratios.get(backend, {}).values() if r == r]
    return max(ratios, default=float("nan"))


# ----------------------------------------------------------------------------------------------- chart paths

EPS = 2.0**-52


def has_chart(result: PathResult) -> bool:
    return any(m.chart is not None for m in result.measurements)


def _voter(label: str) -> str:
    name, _, chart = label.partition("@")
    return f"{_short(name)}@{chart}" if chart else f"{_short(name)} (mapped)"


def chart_voters(result: PathResult) -> list[str]:
    """The chart voters of the path, natives first."""
    labels = dict.fromkeys(v for m in result.measurements if m.chart for v in m.chart.voters if v != "harness map")
    return sorted(labels, key=lambda v: ("@" not in v, list(labels).index(v)))


def _chart_gate(c) -> str:
    if not c.compared:
        return f"BREAKDOWN (cond Dpsi {_g(c.cond_D)} > {_g(GIMBAL)}): left out"
    disagree = [q for q, v in c.verdicts.items() if v == DISAGREE]
    return "**DISAGREE " + ", ".join(disagree) + "**" if disagree else "compared: agree"


def chart_table(result: PathResult) -> list[str]:
    voters = chart_voters(result)
    head = ([result.path.parameter, "cond Dpsi", "cond Dpsi (exact)", "cond M_p", "state map"]
            + [_voter(v) for v in voters] + ["true err / chart tol", "gate (chart)"])
    lines = ["| " + " | ".join(head) + " |", "|" + "---|" * len(head)]
    for m in result.measurements:
        c = m.chart
        if c is None:
            continue
        cells = []
        for v in voters:
            if v in c.raised:
                cells.append("raised")
                continue
            cell = _g(c.worst(v))
            if v in c.own:
                cell += f" (own {_g(max(c.own[v].values()))})"
            if any(lbl == v for lbl, _ in c.over.get("silent", ())):
                cell += " !"
            cells.append(cell)
        ratio = max((c.ratio(v) for v in c.voters if c.ratio(v) == c.ratio(v)), default=float("nan"))
        row = ([f"{m.point.x:.3g}", _g(c.cond_D), _g(c.cond_D_exact), _g(c.cond_Mp), _g(c.state_map)] + cells
               + [_g(ratio) + (" (would be)" if c.would_be else ""), _chart_gate(c)])
        lines.append("| " + " | ".join(row) + " |")
    return lines


def _range(values) -> str:
    values = [v for v in values if v == v and 0 < v < float("inf")]
    return f"{_g(min(values))} to {_g(max(values))}" if values else "-"


def chart_conclusions(result: PathResult) -> list[str]:
    """What the chart measurements show, in words computed from the numbers."""
    ms = [m for m in result.measurements if m.chart is not None]
    voters = chart_voters(result)
    natives = [v for v in voters if "@" in v]
    mapped = [v for v in voters if "@" not in v]
    compared = [m for m in ms if m.chart.compared]
    out = []
    last = compared[-1] if compared else None
    beyond = next((m for m in ms if not m.chart.compared), None)
    if last is not None and beyond is not None:
        out.append(f"- The gate compares the chart while cond(Dpsi) <= {_g(GIMBAL)}: the last compared point is "
                   f"{result.path.parameter} = {last.point.x:.3g} (cond Dpsi {_g(last.chart.cond_D)}), the first left "
                   f"out {beyond.point.x:.3g} (cond Dpsi {_g(beyond.chart.cond_D)}); cond(Dpsi) is about "
                   f"{_g(ms[0].chart.cond_D_exact * ms[0].point.x)} / delta, so the limit sits at delta ~ "
                   f"{_g(ms[0].chart.cond_D_exact * ms[0].point.x / GIMBAL)}.")
    finite = [m for m in ms if m.chart.cond_Mp < float("inf")]
    for v in natives:
        own = [(max(m.chart.own[v].values()) / (EPS * m.chart.cond_Mp), m.point.x) for m in finite
               if v in m.chart.own and max(m.chart.own[v].values()) < 0.1]
        raised = [m.point.x for m in ms if v in m.chart.raised]
        text = (f"- {_voter(v)} (native): its own error (against the exact answer for the float chart inputs it was "
                f"given) is eps cond(M_p) times {_range(r for r, _ in own)} wherever it is below 10 %: it grows like "
                "eps cond(M_p), and cond(M_p) grows like cond(Dpsi)^2 (1 / delta^2).")
        if raised:
            text += f" It raised (Cholesky of the singular M_p) at {', '.join(f'{x:.3g}' for x in raised)}."
        out.append(text)
    if mapped:
        rows = [(max(m.chart.worst(v) for v in mapped), m) for m in ms if all(v in m.chart.errors for v in mapped)]
        rows = [(e, m) for e, m in rows if 0 < e < 0.1]
        if rows:
            ratios = _range(e / (EPS * m.chart.cond_D_exact ** 2) for e, m in rows)
            out.append(f"- The joint-chart answers mapped into the chart ({', '.join(_voter(v) for v in mapped)}) all "
                       f"carry the same error, the harness's own: the rounding of p = psi^-1(q) and pd = Dpsi^-1 qd "
                       f"(`state map`); it is eps cond(Dpsi)^2 times {ratios} where below 10 %, i.e. the map loses "
                       f"about 2 log10 cond(Dpsi) digits ("
                       + ", ".join(f"{_log10(e / EPS):.0f} digits lost at {m.point.x:.3g}" for e, m in rows)
                       + ").")
    silent = [(m.point.x, v, q) for m in ms for v, q in m.chart.over.get("silent", ())]
    out.append(f"- True error above the chart comparison's tolerance while the gate compared: "
               f"{len(silent)} silent, {sum(len(m.chart.over.get('caught', ())) for m in ms)} caught.")
    out += [f"  - **silent: {_voter(v)} {q} at {x:.3g}** (a real finding)" for x, v, q in silent]
    if compared:
        ratios = [(max(m.chart.ratio(v) for v in m.chart.voters if m.chart.ratio(v) == m.chart.ratio(v)), m)
                  for m in compared]
        rooms = [(max(m.chart.worst(v) for v in natives if v in m.chart.errors) / r, m) for r, m in ratios
                 if r > 0 and natives]
        if rooms:
            room = [r for r, _ in ratios if r > 0]
            pace = ("it loosens faster than the errors grow" if max(room) / min(room) > 100.0 else
                    "it keeps pace with the native errors (their ratio to it stays within a factor 100)")
            out.append("- The chart comparison's tolerance, as a relative error it would accept (largest native error "
                       "/ its ratio): " + ", ".join(f"{_g(t)} at {m.point.x:.3g}" for t, m in rooms)
                       + f": {pace}; a wrong answer of that relative size would pass there.")
    would = [m for m in ms if m.chart.would_be]
    if would:
        worst = max(would, key=lambda m: max(m.chart.worst(v) for v in m.chart.errors))
        top = max(worst.chart.worst(v) for v in worst.chart.errors)
        wr = max(m.chart.ratio(v) for m in would for v in m.chart.voters if m.chart.ratio(v) == m.chart.ratio(v))
        failing = [m for m in would if any(m.chart.ratio(v) > 1.0 for v in m.chart.voters)]
        if not failing:
            out.append(f"- Past the limit, with the limit lifted the check would have passed every point (largest true "
                       f"err / tol {_g(wr)}), even at {worst.point.x:.3g} where the mapped answers are off by {_g(top)} "
                       "relative: the limit, not the tolerance, is what keeps such answers out of the vote.")
        else:
            out.append(f"- Past the limit, with the limit lifted the tolerance would have rejected "
                       f"{len(failing)} of {len(would)} points (largest true err / tol {_g(wr)}, from "
                       f"{min(m.point.x for m in failing):.3g}); where it would have passed, the answers are off by "
                       "no more than the rounding the tolerance allows for there.")
    return out


def _log10(x: float) -> float:
    import math

    return math.log10(x) if x > 0 else float("-inf")


def chart_section(result: PathResult) -> list[str]:
    name = result.path.name
    return [f"### {name}: the answers in the chart", "",
            "Relative error of the chart accelerations pdd (largest over drift, ctrl, total) against the exact split "
            "at the state carried into the chart in mpmath (`precise.chart_split`). `@zyx`: evaluated natively "
            "(`split_chart`) at the chart point the gate computes, with its own error in parentheses (against the "
            "exact answer for those float inputs, `precise.chart_split_at`); `(mapped)`: the joint-chart answer "
            "carried by `invariance.mapped`. `state map`: how far the harness's rounding of the state into the "
            "chart moves the exact answer. `true err / chart tol`: against the gate's chart comparison tolerance "
            "(`would be`: past the limit, the tolerance it would use with the limit lifted). `raised`: an exception "
            "(the Cholesky of the singular M_p).", "",
            f"![{name} chart](stability_{name}_chart.png)", "", *chart_conclusions(result), "",
            *chart_table(result), ""]


def plot_chart(result: PathResult, file) -> None:
    """Three panels against delta: relative error per chart voter (natives solid, mapped dashed), true error over the
    chart tolerance, cond(Dpsi) and cond(M_p) with the limit; the points the gate leaves out shaded."""
    plt = plots.pyplot()
    ms = [m for m in result.measurements if m.chart is not None]
    xs = [m.point.x for m in ms]
    fig, (err, tol, cond) = plt.subplots(3, 1, figsize=(plots.WIDTH_IN, 8.0), sharex=True, layout="constrained")
    for v in chart_voters(result):
        native = "@" in v
        points = [(m.point.x, max(m.chart.worst(v), FLOOR)) for m in ms if v in m.chart.voters]
        _line(err, points, _voter(v), "o" if native else ".")
        if not native:
            err.lines[-1].set_linestyle("--")
        _line(tol, [(m.point.x, max(m.chart.ratio(v), FLOOR)) for m in ms if m.chart.ratio(v) == m.chart.ratio(v)],
              _voter(v), "o" if native else ".")
    _line(cond, [(m.point.x, m.chart.cond_D) for m in ms], "cond Dpsi (gate)", "s")
    _line(cond, [(m.point.x, m.chart.cond_D_exact) for m in ms], "cond Dpsi (exact)", "x")
    _line(cond, [(m.point.x, m.chart.cond_Mp) for m in ms], "cond M_p", "s")
    cond.axhline(GIMBAL, color="k", lw=0.8, ls=":", label="GIMBAL_LIMIT")
    tol.axhline(1.0, color="k", lw=0.8, ls="--")
    for ax in (err, tol, cond):
        for i, (lo, hi) in enumerate(_spans(xs, [not m.chart.compared for m in ms])):
            ax.axvspan(lo, hi, color="tab:red", alpha=0.12, lw=0,
                       label="chart left out (BREAKDOWN)" if i == 0 and ax is err else None)
        ax.grid(True, which="major", alpha=0.3)
    err.invert_xaxis()
    err.set(title="Ball pendulum in the zyx chart, pitch -> pi/2", ylabel="relative error of pdd")
    tol.set(ylabel="true error / chart tolerance")
    cond.set(ylabel="condition number", xlabel=result.path.parameter)
    _legends_outside(err, tol, cond)
    plots.save(fig, file)


__all__ = ["chart_conclusions", "chart_table", "conclusions", "plot", "plot_chart", "point_table", "render",
           "summary_table"]


def write_report(out_dir, quick: bool, progress=None) -> Path:
    """Run every path (``quick``: a few points each) and write ``stability.md`` and its ``stability_<path>.png``
    charts into ``out_dir``; returns the markdown's path."""
    start = time.perf_counter()
    results = [stability.run_path(path, progress) for path in stability.paths(quick, backends.names())]
    return write(results, out_dir, quick, time.perf_counter() - start)


def write(results: Sequence[PathResult], out_dir, quick: bool, seconds: float) -> Path:
    """Write the report of measured ``results`` (``stability.md`` and one chart per path) into ``out_dir``."""
    out_dir = Path(out_dir)
    out_dir.mkdir(parents=True, exist_ok=True)
    for result in results:
        plot(result, out_dir / f"stability_{result.path.name}.png")
        if has_chart(result):
            plot_chart(result, out_dir / f"stability_{result.path.name}_chart.png")
    report = out_dir / "stability.md"
    report.write_text(render(list(results), quick, seconds))
    return report
