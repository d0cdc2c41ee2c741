"""The bench's markdown report and charts (``reports/speed_accuracy.md``, ``speed_accuracy.png``,
``speed_scaling.png``) from :class:`crosscheck.bench.Results`."""

from __future__ import annotations

from pathlib import Path

from crosscheck.bench import Results

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


def _marker_styles(names: list[str]) -> dict:
    markers = "osD^v<>PX*h"
    return {name: markers[i % len(markers)] for i, name in enumerate(names)}


def _order(values) -> list:
    return list(dict.fromkeys(values))


def chart_speed_accuracy(res: Results, path: Path) -> None:
    """Time per state against the largest relative error of the total (log-log): one marker per backend, one colour
    per scene; single calls left, batches right."""
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    names, scenes = _order(m.backend for m in res.measurements), _order(m.scene for m in res.measurements)
    marker, colour = _marker_styles(names), {s: plt.cm.tab20(i % 20) for i, s in enumerate(scenes)}
    fig, axes = plt.subplots(1, 2, figsize=(12, 5), sharey=True)
    for ax, attr, title in ((axes[0], "single_s", "single call"), (axes[1], "batch_s", "batch")):
        for m in res.measurements:
            if not m.error_max["total"] == m.error_max["total"]:
                continue
            ax.scatter(getattr(m, attr) * 1e6, max(m.error_max["total"], ERROR_FLOOR), marker=marker[m.backend],
                       color=colour[m.scene], s=36, edgecolors="black", linewidths=0.3)
        ax.set(xscale="log", yscale="log", xlabel="time per state (us)", title=title)
        ax.grid(True, which="major", alpha=0.3)
    axes[0].set_ylabel("max relative error of total vs 50-digit reference")
    handles = [plt.Line2D([], [], marker=marker[n], linestyle="", color="grey", label=n) for n in names]
    handles += [plt.Line2D([], [], marker="s", linestyle="", color=colour[s], label=s) for s in scenes]
    fig.legend(handles=handles, loc="center right", fontsize=7, frameon=False)
    fig.subplots_adjust(right=0.8)
    fig.savefig(path, dpi=110)
    plt.close(fig)


def chart_scaling(res: Results, path: Path) -> None:
    """Time per state against the number of links of the planar chain: solid single call, dashed batch, dotted
    Pinocchio aba."""
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    chain = [m for m in res.measurements if m.links is not None]
    names = _order(m.backend for m in chain)
    fig, ax = plt.subplots(figsize=(10, 5))
    for i, name in enumerate(names):
        rows = sorted((m for m in chain if m.backend == name), key=lambda m: m.links)
        x = [m.links for m in rows]
        colour = plt.cm.tab10(i % 10)
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
    ax.legend(fontsize=7, loc="center left", bbox_to_anchor=(1.01, 0.5), frameon=False)
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)


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
        "(`x aba`). Errors are relative to the 50-digit reference (`crosscheck.precise`, norm-wise: "
        "max |x - x_ref| / max |x_ref|) for the floating-point inputs taken as exact.",
        "",
        "## Targets",
        "",
        "The issue's targets. A batched split returns drift, ctrl and total: three solves per state (one factorization "
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

