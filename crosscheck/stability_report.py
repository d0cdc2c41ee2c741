"""The stability report: ``stability.md`` (tables and conclusions from the numbers) and one PNG chart per path.

Everything here is computed from :class:`crosscheck.stability.PathResult` values, so the same run gives the same
report byte for byte, apart from the total runtime on its last line.
"""

from __future__ import annotations

from crosscheck.compare import DISAGREE
from crosscheck.stability import Measurement, PathResult

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
constraints) lam are compared with the exact split of `crosscheck.precise` (mpmath, 50 digits): the **relative
error** is `max|value - exact| / max|exact|`, the **true err / tol** the absolute error over the tolerance the gate
uses for that quantity at that state. The verdicts are the gate's own (`gate.CaseSetup.evaluate`: the same
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
    lines.append(f"Total runtime: {seconds:.0f} s.")
    return "\n".join(lines) + "\n"


def _spans(xs: list[float], flags: list[bool]) -> list[tuple[float, float]]:
    """Intervals around the flagged points, bounded by the geometric midpoints to their neighbours."""
    edges = [xs[0]] + [(a * b) ** 0.5 for a, b in zip(xs, xs[1:])] + [xs[-1]]
    return [(edges[i], edges[i + 1]) for i, f in enumerate(flags) if f]


def _line(ax, points, label, marker) -> None:
    """Finite points as a line; an infinite one (no finite answer, or a singular matrix) as a triangle at the top."""
    finite = [(x, y) for x, y in points if y < float("inf")]
    line, = ax.loglog(*zip(*finite), marker=marker, ms=3, label=label) if finite else ax.loglog([], [], label=label)
    top = [x for x, y in points if y == float("inf")]
    if top:
        ax.plot(top, [1.0] * len(top), "^", ms=5, color=line.get_color(), transform=ax.get_xaxis_transform(),
                clip_on=False)


def plot(result: PathResult, file) -> None:
    """Three panels against the path parameter (log-log): relative error per backend, true error over the gate's
    tolerance with the line 1, condition numbers; points where the gate has some backend in BREAKDOWN for a
    measured quantity shaded, an infinite value (a NaN answer, a singular matrix) a triangle on the top edge."""
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    from matplotlib import ticker

    ms, path = result.measurements, result.path
    xs = [m.point.x for m in ms]
    fig, (err, tol, cond) = plt.subplots(3, 1, figsize=(6.4, 7.6), sharex=True, constrained_layout=True)
    for b in result.backends:
        _line(err, [(m.point.x, max(worst_error(m, b), FLOOR)) for m in ms if b in m.point.backends], _short(b), "o")
        _line(tol, [(m.point.x, max(r, FLOOR)) for m in ms for r in [_ratio(m, b)] if r == r], _short(b), "o")
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
    err.legend(fontsize=7, ncol=4)
    cond.legend(fontsize=7)
    fig.savefig(file, dpi=90)
    plt.close(fig)


def _ratio(m: Measurement, backend: str) -> float:
    """The backend's largest true error over the gate's tolerance (NaN where the gate compared nothing)."""
    ratios = [r for r in m.ratios.get(backend, {}).values() if r == r]
    return max(ratios, default=float("nan"))


__all__ = ["conclusions", "plot", "point_table", "render", "summary_table"]
