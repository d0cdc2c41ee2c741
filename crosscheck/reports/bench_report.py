"""The bench's markdown report and charts (``reports/speed_accuracy.md``, ``speed_accuracy.png``,
``speed_scaling.png``) from :class:`crosscheck.campaigns.bench.Results`, as measured or as saved in
``speed_accuracy.json`` (:func:`write_from_json`: ``python -m crosscheck.reports.bench_report
reports/speed_accuracy.json`` renders them again without measuring)."""

from __future__ import annotations

from pathlib import Path

from crosscheck.campaigns.bench import Results
from crosscheck.reports import plots

#: Relative errors below this are drawn at it on log axes (an exact answer has error 0).
ERROR_FLOOR = 1e-18
GATE_TARGET_S = 60.0
PREP_TARGETS_S = {"cold": 60.0, "cached": 1.0}


def _us(seconds: float) -> str:
    us = seconds * 1e6
    return f"{us:.3g}" if us < 100 else f"{us:,.0f}"


def _ratio(x: float) -> str:
    return f"{x:.2g}" if x < 10 else f"{x:,.0f}"


def _err(x: float | None) -> str:
    if x is None or x != x:
        return "-"
    return "0" if x == 0.0 else f"{x:.1e}"


def _targets(res: Results, target: str) -> list[str]:
    lines = ["| target | backend | measured | limit | met |", "|---|---|---|---|---|"]
    for m in (m for m in res.measurements if m.scene == target):
        ok = m.batch_s <= m.aba_s
        verdict = "yes" if ok else f"no: {m.batch_s / m.aba_s:.2g}x over"
        lines.append(f"| batched time per state, {target}, N = {m.batch_n:,} | {m.backend} | {_us(m.batch_s)} us | "
                     f"aba {_us(m.aba_s)} us | {verdict} |")
    for p in (p for p in res.preparations if p.scene == target and p.backend == "euler_lagrange"):
        for kind, value in (("cold", p.cold_s), ("cached", p.cached_s)):
            limit = PREP_TARGETS_S[kind]
            lines.append(f"| Euler–Lagrange preparation, {target}, {kind} | euler_lagrange | {value:.2f} s | "
                         f"{limit:g} s | {'yes' if value < limit else 'no'} |")
    if res.gate_s is not None:
        lines.append(f"| default `crosscheck gate`, all built-in cases | all | {res.gate_s:.0f} s | "
                     f"{GATE_TARGET_S:g} s "
                     f"| {'yes' if res.gate_s < GATE_TARGET_S else 'no'} |")
    return lines


def _scene_table(res: Results) -> list[str]:
    lines = ["| scene | n | backend | single call (us) | x aba | batch (us/state) | x aba | N | own batch | "
             "total error median | max | lam error max | BREAKDOWN states |",
             "|---|---|---|---|---|---|---|---|---|---|---|---|---|"]
    for m in res.measurements:
        lam = m.error_max.get("lam")
        lines.append(f"| {m.scene} | {m.n} | {m.backend} | {_us(m.single_s)} | {_ratio(m.single_s / m.aba_s)} | "
                     f"{_us(m.batch_s)} | {_ratio(m.batch_s / m.aba_s)} | {m.batch_n:,} | "
                     f"{'yes' if m.own_batch else 'looped'} | {_err(m.error_median['total'])} | "
                     f"{_err(m.error_max['total'])} | {_err(lam)} | {m.breakdowns} of {m.error_states} |")
    return lines


def _error_table(res: Results) -> list[str]:
    names = ("drift", "ctrl", "total", "lam", "lam_drift")
    lines = ["| scene | backend | " + " | ".join(f"{n} (median / max)" for n in names) + " |",
             "|---|---|" + "---|" * len(names)]
    for m in res.measurements:
        cells = [f"{_err(m.error_median[n])} / {_err(m.error_max[n])}" if n in m.error_max else "-" for n in names]
        lines.append(f"| {m.scene} | {m.backend} | " + " | ".join(cells) + " |")
    return lines


def _prep_table(res: Results) -> list[str]:
    lines = ["| scene | backend | cold (s) | cached (s) |", "|---|---|---|---|"]
    lines += [f"| {p.scene} | {p.backend} | {p.cold_s:.3f} | {p.cached_s:.3f} |" for p in res.preparations]
    return lines


def _representation_table(res: Results) -> list[str]:
    lines = ["| scene | backend | minimal (us/call) | general 3-D (us/call) | cost of 3-D | max answer difference "
             "(/ accel scale) |", "|---|---|---|---|---|---|"]
    lines += [f"| {r.scene} | {r.backend} | {_us(r.minimal_s)} | {_us(r.general_s)} | "
              f"{r.general_s / r.minimal_s:.2f}x | {r.difference:.1e} |" for r in res.representations]
    return lines


def _order(values) -> list:
    return list(dict.fromkeys(values))


def family(m) -> str:
    """The scene family a measurement belongs to: the planar chain of any length is one family."""
    return "n_link_pendulum" if m.links is not None else m.scene


def _error(m) -> float | None:
    """The largest relative error of the total drawn on log axes (at least :data:`ERROR_FLOOR`), None for NaN."""
    e = m.error_max["total"]
    return None if e != e else max(e, ERROR_FLOOR)


def chart_speed_accuracy(res: Results, path: Path) -> None:
    """Time per state against the largest relative error of the total (log-log), one panel per scene family; a
    colour per backend (the same in every figure), a filled circle for a single call and an open square for a batch
    (the chain's lengths joined by a line, n growing with the time); the same axes in every panel; the legend under
    the panels."""
    plt = plots.pyplot()
    names = _order(m.backend for m in res.measurements)
    families = _order(family(m) for m in res.measurements)
    cols = 2 if len(families) > 1 else 1
    rows = max(1, -(-len(families) // cols))   # an interrupted bench may have measured nothing yet
    fig, axes = plt.subplots(rows, cols, figsize=(plots.WIDTH_IN, 3.3 * rows + 0.9), squeeze=False, sharex=True,
                             sharey=True, layout="constrained")
    for ax, fam in zip(axes.flat, families):
        for name in names:
            colour = plots.backend_colour(name, names)
            for attr, marker, face in (("single_s", "o", colour), ("batch_s", "s", "none")):
                ms = sorted((m for m in res.measurements if family(m) == fam and m.backend == name
                             and _error(m) is not None), key=lambda m: m.links or 0)
                x, y = [getattr(m, attr) * 1e6 for m in ms], [_error(m) for m in ms]
                ax.plot(x, y, marker=marker, ls="-" if len(ms) > 1 else "", lw=0.8, ms=5, color=colour,
                        markerfacecolor=face, markeredgecolor=colour)
        links = sorted({m.links for m in res.measurements if family(m) == fam and m.links is not None})
        title = fam + (f" (n = {', '.join(map(str, links))})" if links else "")
        ax.set(xscale="log", yscale="log", title=title)
        ax.grid(True, which="major", alpha=0.3)
    for ax in axes[-1]:
        ax.set_xlabel("time per state (us)")
    for ax in axes[:, 0]:
        ax.set_ylabel("max relative error of total")
    for ax in list(axes.flat)[len(families):]:
        ax.set_visible(False)
    handles = [plt.Line2D([], [], color=plots.backend_colour(n, names), marker="o", ls="", label=n) for n in names]
    handles += [plt.Line2D([], [], color="0.3", marker="o", ls="", label="single call"),
                plt.Line2D([], [], color="0.3", marker="s", markerfacecolor="none", ls="", label="batch")]
    fig.suptitle("Speed against accuracy (error against the 50-digit reference; same axes in every panel)")
    plots.legend_below(fig, handles, columns=4)
    plots.save(fig, path)


def chart_scaling(res: Results, path: Path) -> None:
    """Time per state against the number of links of the planar chain: solid single call, dashed batch, dotted
    Pinocchio aba; the legend right of the panel."""
    plt = plots.pyplot()
    chain = [m for m in res.measurements if m.links is not None]
    names = _order(m.backend for m in chain)
    fig, ax = plt.subplots(figsize=(plots.WIDTH_IN, 4.5))
    for name in names:
        rows = sorted((m for m in chain if m.backend == name), key=lambda m: m.links)
        x = [m.links for m in rows]
        colour = plots.backend_colour(name, names)
        ax.plot(x, [m.single_s * 1e6 for m in rows], "-o", color=colour, ms=3, label=f"{name} single")
        ax.plot(x, [m.batch_s * 1e6 for m in rows], "--", color=colour, label=f"{name} batch")
    aba = sorted({(m.links, m.aba_s) for m in chain if m.backend == names[0]}) if names else []
    ax.plot([a for a, _ in aba], [t * 1e6 for _, t in aba], ":k", lw=2, label="pinocchio aba (anchor)")
    ax.set(yscale="log", xscale="log", xlabel="links n", ylabel="time per state (us)",
           title="planar n-link chain")
    links = sorted({m.links for m in chain})
    ax.set_xticks(links, [str(n) for n in links])
    ax.minorticks_off()
    ax.grid(True, which="major", alpha=0.3)
    plots.legend_right(fig, ax.get_legend_handles_labels()[0], width=0.25)
    plots.save(fig, path)


def render(res: Results, target: str = "panda", interrupted: str = "") -> str:
    """The markdown report; ``interrupted``, for a run ended by Ctrl-C, says what was running (the report then
    holds what was measured until then)."""
    m = res.machine
    partial = [f"**PARTIAL**: the run was interrupted while {interrupted}; only what was measured until then is "
               "below.", ""] if interrupted else []
    lines = [
        "# Speed against accuracy",
        "",
        *partial,
        f"Written by `crosscheck bench{' --quick' if res.plan == 'quick' else ''}` ({res.plan} plan, "
        f"{res.seconds:.0f} s). Machine: {m['cpus']} CPUs, {m['machine']}, Python {m['python']}, numpy {m['numpy']}, "
        f"Pinocchio {m['pinocchio']}, casadi {m['casadi']}, sympy {m['sympy']}. One BLAS thread.",
        "",
        "Times are the minimum over repeated loops (the least disturbed estimate on a shared machine) and are also "
        "given as ratios to Pinocchio's `aba` called once per state from Python on the same model in the same run "
        "(`x aba`). Errors are relative to the 50-digit reference (`crosscheck.references.precise`, norm-wise: "
        "max |x - x_ref| / max |x_ref|) for the floating-point inputs taken as exact.",
        "",
        "## Targets",
        "",
        "The targets. A batched split returns drift, ctrl and total: three solves per state (one factorization "
        "and three right-hand sides, or three recursions), where `aba` is one. Pinocchio's own batched split (three "
        "`abaInParallel` passes, row `pinocchio`) shows what that costs with compiled code.",
        "",
        *_targets(res, target),
        "",
        "## Time and error per scene",
        "",
        "A single call computes the whole `Split` (conditioning, task quantities, loads, constraint terms); a batch "
        "computes drift, ctrl, total and the multipliers (`SplitBatch`). `aba` computes the total only.",
        "",
        *_scene_table(res),
        "",
        "![time per state against error](speed_accuracy.png)",
        "",
        "![time per state against chain length](speed_scaling.png)",
        "",
        "## Errors by quantity",
        "",
        *_error_table(res),
        "",
        "## Preparation (first call of a fresh process minus a steady call)",
        "",
        "Cold: empty Euler–Lagrange disk cache. Cached: the cache the cold run wrote. The other backends keep no "
        "disk "
        "cache; their cold and cached runs do the same work (casadi graph construction, Pinocchio model build).",
        "",
        *_prep_table(res),
        "",
        "## Minimal model against general 3-D body frames",
        "",
        "The same scene written with every body frame turned (`cases.representation.general_3d`): unaligned joint "
        "axes, rotated placements, dense COM offsets. Same joint coordinates, same physics.",
        "",
        *_representation_table(res),
        "",
    ]
    return "\n".join(lines)


def write_from_json(json_path: Path, out_dir: Path | None = None) -> Path:
    """Render the report and its charts again from the raw numbers a bench saved (``speed_accuracy.json``), into
    ``out_dir`` (default: beside the JSON), without measuring anything; returns the markdown's path."""
    json_path = Path(json_path)
    return write(Results.from_json(json_path.read_text()), Path(out_dir) if out_dir else json_path.parent)


def write(res: Results, out_dir: Path, interrupted: str = "") -> Path:
    """``speed_accuracy.md``, its two charts and the raw numbers (``speed_accuracy.json``) in ``out_dir``;
    ``interrupted``: :func:`render`."""
    out_dir.mkdir(parents=True, exist_ok=True)
    chart_speed_accuracy(res, out_dir / "speed_accuracy.png")
    chart_scaling(res, out_dir / "speed_scaling.png")
    (out_dir / "speed_accuracy.json").write_text(res.to_json() + "\n")
    path = out_dir / "speed_accuracy.md"
    path.write_text(render(res, interrupted=interrupted))
    return path
