"""The trajectory report: ``reports/trajectories.md`` and its charts.

One command regenerates everything: ``crosscheck trajectory --report [DIR]``. The work is a list of independent
jobs (each backend's run per integrator, the reference and its verification and Lyapunov runs, the stability-map
points) spread over a process pool; the tables and the text are computed from the numbers, so the same settings give
the same report apart from the timings.
"""

from __future__ import annotations

import math
import time
from concurrent.futures import Future, ProcessPoolExecutor
from dataclasses import dataclass, field, replace
from pathlib import Path

import numpy as np

import cases
from crosscheck.campaigns import trajectory as T
from crosscheck.core.sampling import project_configuration, project_velocity
from crosscheck.references.pinocchio import reference

SHORT = {"euler_lagrange": "EL", "newton_euler": "NE", "screw": "screw", "operational_space": "OS",
         "geometric": "geom", "pinocchio": "pin"}
COLORS = {"rk4": "tab:blue", "gauss": "tab:green", "adaptive": "tab:red"}


@dataclass(frozen=True)
class Settings:
    """What the report computes (:func:`quick` for tests)."""

    q0: tuple = (2.0, 1.0)                 # double pendulum released from rest, chaotic (article section 3 angles)
    v0: tuple = (0.0, 0.0)
    horizon: float = 4.0
    interval: float = 0.02                 # output grid = the reference's interval
    dt: float = 0.01                       # rk4 and gauss
    backends: tuple = ("euler_lagrange", "newton_euler", "screw", "operational_space", "geometric", "pinocchio")
    fault: float = 1e-10                   # the injected relative drift error the judgment must flag
    # constrained
    constrained: tuple = (("four_bar", (("coupler", 2.5), ("rocker", 2.0))), ("slider_crank", ()))
    c_horizon: float = 0.5
    c_interval: float = 0.05
    c_backends: tuple = ("euler_lagrange", "geometric", "pinocchio")
    # stability maps
    ratios: tuple = (1.0, 10.0, 100.0, 1e3, 1e4)
    map_q0: tuple = (0.1, 0.1)             # map (a): small oscillation from rest, both modes excited
    periods: float = 10.0                  # map (a): horizon in periods of the fastest mode
    drift_dts: tuple = (0.04, 0.02, 0.01)
    drift_horizon: float = 5.0
    drift_bound: float = 1e-6
    energy_dt: float = 0.1
    energy_horizon: float = 200.0
    energy_q0: tuple = (0.8, 0.4)
    map_backend: str = "pinocchio"
    workers: int = 2                       # 0: every job in this process; N >= 1: N worker processes


def quick() -> Settings:
    return Settings(horizon=0.2, backends=("euler_lagrange", "pinocchio"), constrained=(("four_bar", (("coupler", 2.5),
                    ("rocker", 2.0))),), c_horizon=0.1, c_backends=("euler_lagrange", "pinocchio"), ratios=(1.0,),
                    periods=3.0, drift_dts=(0.04,), drift_horizon=0.4, energy_horizon=2.0, workers=1)


# ----------------------------------------------------------------------------------------------- jobs


def _model(case: str, params: tuple):
    return cases.load(case, **dict(params))


def _job(kind: str, args: tuple):
    """One unit of work, run in a worker (top level so that it pickles)."""
    from threadpoolctl import threadpool_limits

    with threadpool_limits(limits=1, user_api="blas"):
        if kind == "run":
            case, params, backend, q0, v0, horizon, dt, integrator, project, every = args
            if isinstance(backend, tuple):          # ("fault", name, rel)
                backend = T.FaultyBackend(backend[1], backend[2])
            return T.simulate(_model(case, params), backend, q0, v0, horizon, dt, integrator, project, every)
        if kind == "ref":
            case, params, x0, interval, intervals, tol, closed_form, perturb = args
            start = time.perf_counter()
            xs, evals = T.reference_run(_model(case, params), x0, interval, intervals, tol, None, T.DIGITS,
                                        closed_form, perturb)
            return xs, evals, time.perf_counter() - start
        if kind == "rk4_stable":
            return _largest_stable_step(*args)
        raise ValueError(kind)


def fastest_frequency(model, q) -> float:
    """``omega_max = sqrt(max |eig(d drift / dq)|)`` at ``(q, v = 0)``: the fastest small-oscillation frequency, from
    central differences (step 1e-6) of the Pinocchio reference's drift."""
    h, n = 1e-6, model.n
    J = np.empty((n, n))
    for k in range(n):
        e = np.zeros(n)
        e[k] = h
        J[:, k] = (reference.split(model, q + e, np.zeros(n), np.zeros(model.m)).drift
                   - reference.split(model, q - e, np.zeros(n), np.zeros(model.m)).drift) / (2 * h)
    return float(np.sqrt(np.max(np.abs(np.linalg.eigvals(J)))))


def _largest_stable_step(ratio: float, q0, v0, periods: float, backend: str):
    """Map (a): for m2/m1 = ratio, the fastest small-oscillation frequency (at the hanging equilibrium) and the
    largest RK4 step (bisection on a log scale) whose run over ``periods`` periods of that mode does not let the
    energy grow by more than 10 % of its scale (``|E0| + m_total g (l1 + l2)``) and keeps the state finite (RK4 damps
    when stable: energy loss is accuracy, not instability)."""
    model = cases.load("double_pendulum", m1=1.0, m2=ratio)
    omega = fastest_frequency(model, np.zeros(model.n))       # at the hanging equilibrium
    E0 = T.energy(model, q0, v0)
    scale = abs(E0) + float(np.sum([b.mass for b in model.bodies])) * 9.81 * 2.0

    def stable(dt: float) -> bool:
        horizon = periods * 2 * math.pi / omega
        run = T.simulate(model, backend, q0, v0, horizon, dt, "rk4", "none", every=max(1, int(horizon / dt) // 50))
        if run.failure:
            return False
        return all(T.energy(model, q, v) - E0 <= 0.1 * scale for q, v in zip(run.q, run.v))
    lo, hi = 0.1 / omega, 10.0 / omega         # lo stable, hi unstable (checked)
    if not stable(lo):
        return ratio, omega, float("nan")
    if stable(hi):
        return ratio, omega, float("inf")
    for _ in range(8):
        mid = math.sqrt(lo * hi)
        lo, hi = (mid, hi) if stable(mid) else (lo, mid)
    return ratio, omega, lo


# ----------------------------------------------------------------------------------------------- computing


@dataclass
class Row:
    backend: str
    integrator: str
    project: str
    end_error: float
    energy: float
    constraint: float
    gone: float
    gone_extrapolated: bool
    inside: bool
    run: T.Run = field(repr=False)


@dataclass
class Family:
    """One case and integrator family: the reference, the Lyapunov growth, the runs and their judgments."""

    case: str
    params: tuple
    ref: T.Reference
    lyap: T.Lyapunov
    rows: list
    judgments: dict          # (integrator, project) -> Judgment
    sigmas: dict


def _gone(run: T.Run, ref: T.Reference, lam: float) -> tuple[float, bool]:
    """Digits-gone time: measured, else extrapolated from the last error with the FTLE (exp(lam t) growth)."""
    t = T.digits_gone(run, ref)
    if math.isfinite(t) or run.failure or lam <= 0:
        return t, False
    e = T.errors(run, ref)[-1]
    size = float(np.abs(ref.x[len(run.t) - 1]).max())
    if e <= 0:
        return float("inf"), True
    return float(run.t[-1] + math.log(size / e) / lam), True


def _family(pool, case: str, params: tuple, q0, v0, horizon: float, s: Settings, integrators, projects, backends,
            closed_form, fault: bool, interval: float) -> Family:
    model = _model(case, params)
    s = replace(s, interval=interval)
    intervals = int(round(horizon / s.interval))
    every = int(round(s.interval / s.dt))
    x0 = np.concatenate([np.asarray(q0, float), np.asarray(v0, float)])
    d = T.perturbation_direction(model, np.asarray(q0, float))
    futures = {}
    futures["main"] = pool.submit(_job, "ref", (case, params, x0, s.interval, intervals, T.REFERENCE_TOL, closed_form,
                                                None))
    futures["fine"] = pool.submit(_job, "ref", (case, params, x0, s.interval, intervals, T.VERIFY_TOL, closed_form,
                                                None))
    futures["lyap"] = pool.submit(_job, "ref", (case, params, x0, s.interval, intervals, T.VERIFY_TOL, closed_form,
                                                tuple(d)))
    jobs = []
    for integrator in integrators:
        for project in projects:
            if integrator == "adaptive" and project == "project":
                continue
            names = list(backends) + ([("fault", backends[0], s.fault)] if fault and integrator == "rk4" else [])
            for b in names:
                jobs.append(((integrator, project, b), pool.submit(_job, "run", (case, params, b, tuple(q0), tuple(v0),
                                                                                 horizon, s.dt, integrator, project,
                                                                                 every))))
    main, e1, s1 = futures["main"].result()
    fine, e2, s2 = futures["fine"].result()
    pert, e3, s3 = futures["lyap"].result()
    ref = T.assemble_reference(model, main, fine, s.interval, e1 + e2, s1 + s2, T.DIGITS, closed_form)
    lyap = T.lyapunov(model, ref, perturbed=pert)
    runs: dict = {}
    for key, fut in jobs:
        runs.setdefault(key[:2], []).append(fut.result())
    rows, judgments, sigmas = [], {}, {}
    for (integrator, project), rs in runs.items():
        dt = s.dt if integrator != "adaptive" else s.interval
        sigma = T.rounding_rate(model, ref, dt, integrator)
        sigmas[(integrator, project)] = sigma
        judgments[(integrator, project)] = T.judge(rs, ref, lyap, sigma)
        for r in rs:
            gone, extra = _gone(r, ref, lyap.ftle)
            e = T.errors(r, ref)
            rows.append(Row(r.backend, integrator, project, float(e[-1]), float(np.max(T.energy_error(model, r, ref))),
                            float(np.max(T.constraint_drift(model, r))), gone, extra,
                            r.backend not in judgments[(integrator, project)].outside, r))
    return Family(case, params, ref, lyap, rows, judgments, sigmas)


def _drift_horizon(case, params, q0, v0, dt, horizon, bound, backend):
    model = _model(case, params)
    run = T.simulate(model, backend, q0, v0, horizon, dt, "rk4", "none", every=max(1, int(round(0.02 / dt))))
    drift = T.constraint_drift(model, run)
    over = np.nonzero(drift > bound)[0]
    return dt, run.t, drift, (float(run.t[over[0]]) if over.size else float("inf"))


def _energy_long(q0, dt, horizon, integrator, backend):
    model = cases.load("double_pendulum")
    run = T.simulate(model, backend, q0, (0.0, 0.0), horizon, dt, integrator, "none", every=10)
    E0 = T.energy(model, q0, (0.0, 0.0))
    return integrator, run.t, np.array([T.energy(model, q, v) - E0 for q, v in zip(run.q, run.v)]), run.iterations


def _job2(kind, args):
    from threadpoolctl import threadpool_limits

    with threadpool_limits(limits=1, user_api="blas"):
        return {"drift": _drift_horizon, "energy": _energy_long}[kind](*args)


def _start_state(case: str, params: tuple):
    """An admissible start of a constrained case: its home configuration projected, a unit rate on the first joint
    projected onto the tangent space."""
    model = _model(case, params)
    q = project_configuration(model, np.full(model.n, 0.3))
    v = project_velocity(model, q, np.eye(model.n)[0] * 2.0)
    return q, v


class _InProcess:
    """The executor of ``workers`` 0: each job runs in this process when it is submitted."""

    def __enter__(self) -> "_InProcess":
        return self

    def __exit__(self, *exc) -> bool:
        return False

    def submit(self, fn, *args) -> Future:
        future = Future()
        try:
            future.set_result(fn(*args))
        except Exception as exc:  # the job's error, raised where its result is asked for, as from a worker
            future.set_exception(exc)
        return future


def _executor(workers: int):
    """``workers`` 0: this process (:class:`_InProcess`); N >= 1: N forked worker processes."""
    import multiprocessing

    if workers == 0:
        return _InProcess()
    return ProcessPoolExecutor(max_workers=workers, mp_context=multiprocessing.get_context("fork"))


def compute(s: Settings):
    start = time.perf_counter()
    with _executor(s.workers) as pool:
        maps_a = [pool.submit(_job, "rk4_stable", (r, s.map_q0, (0.0, 0.0), s.periods, s.map_backend))
                  for r in s.ratios]
        fb_case, fb_params = s.constrained[0]
        fq, fv = _start_state(fb_case, fb_params)
        maps_b = [pool.submit(_job2, "drift", (fb_case, fb_params, fq, fv, dt, s.drift_horizon, s.drift_bound,
                                               s.map_backend)) for dt in s.drift_dts]
        maps_c = [pool.submit(_job2, "energy", (s.energy_q0, s.energy_dt, s.energy_horizon, i, s.map_backend))
                  for i in ("rk4", "gauss")]
        dp = _family(pool, "double_pendulum", (), s.q0, s.v0, s.horizon, s, T.INTEGRATORS, ("none",), s.backends, {},
                     True, s.interval)
        constrained = []
        for case, params in s.constrained:
            q, v = _start_state(case, params)
            constrained.append(_family(pool, case, params, q, v, s.c_horizon, s, ("rk4",), T.PROJECTIONS,
                                       s.c_backends, None, False, s.c_interval))
        a = [f.result() for f in maps_a]
        b = [f.result() for f in maps_b]
        c = [f.result() for f in maps_c]
    import resource

    cpu = sum(getattr(resource.getrusage(who), f) for who in (resource.RUSAGE_SELF, resource.RUSAGE_CHILDREN)
              for f in ("ru_utime", "ru_stime"))
    return dp, constrained, (a, b, c), (time.perf_counter() - start, cpu)


# ----------------------------------------------------------------------------------------------- writing


def _g(x: float) -> str:
    if x != x:
        return "-"
    if x == float("inf"):
        return "never"
    return f"{x:.1e}"


def _t(x: float, extra: bool = False) -> str:
    if x == float("inf"):
        return "never"
    return ("~" if extra else "") + f"{x:.2f}"


def _color(backend: str) -> str:
    """One colour per backend in every panel; a faulty wrapper takes its backend's colour (drawn dashed)."""
    order = list(SHORT)
    name = backend.split("+")[0]
    if "+" in backend:
        return "black"
    return f"C{order.index(name) if name in order else len(order)}"


def _plt():
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    return plt


def _chart_family(fam: Family, path: Path, title: str) -> None:
    plt = _plt()
    keys = list(fam.judgments)
    fig, axes = plt.subplots(3, len(keys), figsize=(4.2 * len(keys) + 1.6, 8.4), squeeze=False, sharex=True,
                             constrained_layout=True)
    t = fam.ref.t
    for col, key in enumerate(keys):
        integrator, project = key
        err_ax, pair_ax, e_ax = axes[0, col], axes[1, col], axes[2, col]
        rows = [r for r in fam.rows if (r.integrator, r.project) == key]
        for r in rows:
            style = "--" if "+" in r.backend else "-"
            e = T.errors(r.run, fam.ref)
            err_ax.semilogy(r.run.t, np.maximum(e, 1e-18), style, lw=1, color=_color(r.backend),
                            label=SHORT.get(r.backend, r.backend))
            e_ax.semilogy(r.run.t, np.maximum(T.constraint_drift(_model(fam.case, fam.params), r.run)
                                              if fam.case != "double_pendulum" else
                                              np.abs(T.energy_error(_model(fam.case, fam.params), r.run, fam.ref)),
                                              1e-18), style, lw=1, color=_color(r.backend))
        size = np.abs(fam.ref.x).max(axis=1)
        err_ax.semilogy(t, size, "k:", lw=1, label="|x| (digits gone)")
        err_ax.semilogy(t, np.maximum(fam.ref.error, 1e-40), color="gray", lw=1, label="reference's own error")
        err_ax.set_title(f"{integrator}, project={project}", fontsize=9)
        base = rows[0]
        for r in rows[1:]:
            k = min(len(base.run.t), len(r.run.t))
            d = np.abs(base.run.x[:k] - r.run.x[:k]).max(axis=1)
            pair_ax.semilogy(base.run.t[:k], np.maximum(d, 1e-18), "--" if "+" in r.backend else "-", lw=1,
                             color=_color(r.backend), label=f"{SHORT.get(r.backend, r.backend)} - {SHORT.get(base.backend, base.backend)}")
        j = fam.judgments[key]
        pair_ax.semilogy(t[:len(j.envelope)], j.envelope, "k-", lw=2, label="envelope")
        pair_ax.axvline(j.judged_until, color="gray", ls=":", lw=1)
        err_ax.set_ylabel("|x - x_ref|_inf")
        pair_ax.set_ylabel("|x_a - x_b|_inf")
        e_ax.set_ylabel("|E - E0| (J)" if fam.case == "double_pendulum" else "max(|phi|, |Jc v|)")
        e_ax.set_xlabel("t (s)")
        for ax in (err_ax, pair_ax, e_ax):
            ax.grid(True, which="major", alpha=0.3)
    for row in (0, 1):          # the first column has every line (the fault runs with rk4 only): its legend, outside
        handles, labels = axes[row, 0].get_legend_handles_labels()
        axes[row, -1].legend(handles, labels, fontsize=7, loc="upper left", bbox_to_anchor=(1.02, 1.0))
    fig.suptitle(title, fontsize=10)
    fig.savefig(path, dpi=90)
    plt.close(fig)


def _chart_lyapunov(fam: Family, path: Path) -> None:
    plt = _plt()
    fig, ax = plt.subplots(figsize=(6.4, 3.6), constrained_layout=True)
    t = fam.lyap.t
    ax.semilogy(t, fam.lyap.growth, label="G(t) measured (1e-20 apart)")
    ax.semilogy(t, fam.lyap.worst, label="Ghat(lag): worst growth over any window")
    ax.semilogy(t, np.exp(fam.lyap.ftle * t), "k:", label=f"exp({fam.lyap.ftle:.2f} t) (FTLE)")
    ax.set_xlabel("t, or lag (s)")
    ax.set_ylabel("growth")
    ax.grid(True, alpha=0.3)
    ax.legend(fontsize=8, loc="upper left", bbox_to_anchor=(1.02, 1.0))
    fig.savefig(path, dpi=90)
    plt.close(fig)


def _chart_maps(maps, s: Settings, path: Path) -> None:
    plt = _plt()
    a, b, c = maps
    fig, (ax_a, ax_b, ax_c) = plt.subplots(1, 3, figsize=(15, 4.4), constrained_layout=True)
    ratios = [r for r, _, _ in a]
    ax_a.loglog(ratios, [h for _, _, h in a], "o-", label="largest stable RK4 step (measured)")
    ax_a.loglog(ratios, [2 * math.sqrt(2) / w for _, w, _ in a], "k--", label="2.83 / omega_max (linear theory)")
    ax_a.set_xlabel("m2 / m1")
    ax_a.set_ylabel("dt (s)")
    ax_a.set_title("(a) RK4 step vs stiffness (double pendulum)", fontsize=9)
    ax_a.legend(fontsize=7, loc="lower left")
    for dt, t, drift, _ in b:
        ax_b.semilogy(t, np.maximum(drift, 1e-18), lw=1, label=f"dt = {dt:g}")
    ax_b.axhline(s.drift_bound, color="k", ls=":", label=f"bound {s.drift_bound:g}")
    ax_b.set_xlabel("t (s)")
    ax_b.set_ylabel("max(|phi|, |Jc v|)")
    ax_b.set_title("(b) constraint drift, four_bar, RK4, no projection", fontsize=9)
    ax_b.legend(fontsize=7, loc="lower right")
    for integrator, t, dE, _ in c:
        ax_c.plot(t, dE, lw=1, color=COLORS[integrator], label=integrator)
    ax_c.set_xlabel("t (s)")
    ax_c.set_ylabel("E - E0 (J)")
    ax_c.set_title(f"(c) energy error, dt = {s.energy_dt:g}, double pendulum", fontsize=9)
    ax_c.legend(fontsize=7, loc="lower left")
    for ax in (ax_a, ax_b, ax_c):
        ax.grid(True, which="major", alpha=0.3)
    fig.savefig(path, dpi=90)
    plt.close(fig)


def _table(fam: Family, constrained: bool) -> list[str]:
    head = ("| integrator | project | backend | error at end | max energy error (J) | "
            + ("max constraint drift | " if constrained else "") + "digits gone at (s) | verdict |")
    out = [head, "|" + "---|" * (head.count("|") - 1)]
    for r in fam.rows:
        verdict = "inside" if r.inside else "**OUTSIDE**"
        out.append(f"| {r.integrator} | {r.project} | {r.backend} | {_g(r.end_error)} | {_g(r.energy)} | "
                   + (f"{_g(r.constraint)} | " if constrained else "") + f"{_t(r.gone, r.gone_extrapolated)} | "
                   f"{verdict} |")
    return out


def _judgment_lines(fam: Family) -> list[str]:
    out = []
    for (integrator, project), j in fam.judgments.items():
        worst = max(j.ratio.items(), key=lambda kv: kv[1]) if j.ratio else (("-", "-"), 0.0)
        clean = [r for (a, b), r in j.ratio.items() if a not in j.outside and b not in j.outside]
        named = ", ".join(j.outside) if j.outside else "none"
        out.append(f"- {integrator}, project={project}: sigma = {j.sigma:.2e} per s; judged until t = "
                   f"{j.judged_until:.2f} s; largest pair ratio |x_a - x_b| / E = {worst[1]:.2e} "
                   f"({worst[0][0]} vs {worst[0][1]}); among pairs of backends not named: {max(clean, default=0.0):.2e}; "
                   f"outside the envelope: {named}")
    return out


def write(out: Path, s: Settings | None = None) -> Path:
    s = s or Settings()
    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    dp, constrained, maps, seconds = compute(s)
    _chart_family(dp, out / "trajectories_double_pendulum.png",
                  f"double pendulum from q = {s.q0}, v = {s.v0}: error vs 50-digit reference; backends' differences vs "
                  "the envelope; energy error")
    _chart_lyapunov(dp, out / "trajectories_lyapunov.png")
    for fam in constrained:
        _chart_family(fam, out / f"trajectories_{fam.case}.png",
                      f"{fam.case}: RK4 dt = {s.dt:g}, without and with projection, Baumgarte alpha = "
                      f"{T.BAUMGARTE_ALPHA:g}")
    _chart_maps(maps, s, out / "trajectories_maps.png")
    lines = _markdown(dp, constrained, maps, s, seconds)
    path = out / "trajectories.md"
    path.write_text("\n".join(lines) + "\n")
    return path


def _markdown(dp: Family, constrained, maps, s: Settings, seconds: float) -> list[str]:
    ref, ly = dp.ref, dp.lyap
    a, b, c = maps
    L = ["# Forward ZTCF trajectories", "",
         "Generated by `crosscheck trajectory --report` (crosscheck/reports/trajectory_report.py; the methods are "
         "documented in crosscheck/campaigns/trajectory.py). A pointwise ZTCF sample is the drift at one instant "
         "(article 4.5, 10.3); here "
         "the drift (u = 0) is integrated forward by every backend through the same integrators and compared with a "
         "50-digit reference trajectory and with each other.", "",
         "## Double pendulum (chaotic)", "",
         f"State q = {s.q0}, v = {s.v0} (released from rest, article section 3's angles), horizon {s.horizon:g} s, "
         f"output every {s.interval:g} s. RK4 and Gauss–Legendre (2 stages, fixed-point iteration to "
         f"{T.GAUSS_TOL:.1e} |x|) with dt = {s.dt:g}; DOP853 with rtol = atol = {T.ADAPTIVE_TOL:g}.", "",
         f"- Reference: Gragg–Bulirsch–Stoer of order {2 * T.GBS_LEVELS} at {T.DIGITS} digits on the article's "
         f"eqs. (6)-(8), local tolerance {T.REFERENCE_TOL:g}; verification run at {T.VERIFY_TOL:.1e} (what halving "
         f"every step gives): largest difference over the horizon **{ref.error_estimate:.1e}**; energy conserved "
         f"to {max(abs(float(e - ref.energy[0])) for e in ref.energy):.1e} J; {ref.evals} evaluations, "
         f"{ref.seconds:.0f} s of CPU.",
         f"- Lyapunov: two reference trajectories {T.LYAPUNOV_EPS:g} apart; growth G({s.horizon:g} s) = "
         f"{ly.growth[-1]:.2e}, finite-time Lyapunov exponent **{ly.ftle:.2f} 1/s**; worst growth over any "
         f"window of lag >= {T.WINDOW:g} s gives lambda_env = {ly.exponent:.2f} 1/s "
         "(the envelope uses the measured worst growth per lag, crosscheck/campaigns/trajectory.py).",
         f"- The judgment is shown to fail: `{s.backends[0]}+{s.fault:g}` is {s.backends[0]} with its drift "
         f"multiplied by 1 + {s.fault:g} (RK4 only).", "",
         f"![double pendulum](trajectories_double_pendulum.png)", "",
         "![Lyapunov growth](trajectories_lyapunov.png)", ""]
    L += _table(dp, False) + [""]
    L += ["Digits-gone times marked ~ are extrapolated past the horizon with the FTLE: t_end + ln(|x| / error) / "
          "lambda.", "", "Judgment per integrator:", ""] + _judgment_lines(dp) + [""]
    for fam in constrained:
        L += [f"## {fam.case} {dict(fam.params) if fam.params else ''}".rstrip(), "",
              f"RK4 dt = {s.dt:g} over {s.c_horizon:g} s from an admissible state; reference from the generic "
              f"{T.DIGITS}-digit split (crosscheck.references.precise), error estimate "
              f"{fam.ref.error_estimate:.1e}; FTLE "
              f"{fam.lyap.ftle:.2f} 1/s. Projection: `project` moves q onto phi = 0 and v onto Jc v = 0 after every "
              f"step; `baumgarte` adds the stabilizing term with alpha = {T.BAUMGARTE_ALPHA:g} 1/s.", "",
              f"![{fam.case}](trajectories_{fam.case}.png)", ""]
        L += _table(fam, True) + ["", "Judgment:", ""] + _judgment_lines(fam) + [""]
    L += ["## Stability maps", "", "![maps](trajectories_maps.png)", "",
          f"(a) RK4's largest stable step against m2/m1 (double pendulum from rest at q = {s.map_q0}, backend "
          f"{s.map_backend}; stable = the energy grows by at most 10 % of its scale over {s.periods:g} periods of the "
          "fastest mode, bisection; omega_max = sqrt of the largest |eigenvalue| of d drift / dq at the hanging "
          "equilibrium, the fast mode's small-oscillation frequency):", "",
          "| m2/m1 | omega_max (1/s) | largest stable dt (s) | omega_max dt |", "|---|---|---|---|"]
    for r, w, h in a:
        L.append(f"| {r:g} | {w:.2f} | {_g(h)} | {w * h:.2f} |")
    L += ["", f"RK4's stability interval on the imaginary axis is |omega dt| <= 2.83; the measured product is "
          "listed in the last column.", "",
          f"(b) four_bar without projection, RK4: time until max(|phi|, |Jc v|) exceeds {s.drift_bound:g}:", "",
          "| dt (s) | time over the bound (s) |", "|---|---|"]
    for dt, _, _, tb in b:
        L.append(f"| {dt:g} | {_t(tb)} |")
    L += ["", f"(c) energy over {s.energy_horizon:g} s at dt = {s.energy_dt:g} from q = {s.energy_q0}:", "",
          "| integrator | E - E0 at the end (J) | max |E - E0| (J) |", "|---|---|---|"]
    for integrator, _, dE, _ in c:
        L.append(f"| {integrator} | {dE[-1]:.2e} | {np.max(np.abs(dE)):.2e} |")
    L += ["", "RK4 is not symplectic: its energy error drifts secularly; the Gauss–Legendre scheme's stays bounded "
          "(oscillates) over the horizon.", "",
          f"Runtime: {seconds[0]:.0f} s wall, {seconds[1]:.0f} s CPU (all processes; {s.workers or 'no'} worker processes)."]
    return L
