"""``crosscheck trajectory``: forward ZTCF trajectories of one case per backend (crosscheck/campaigns/trajectory.py),
or the report (``--report [DIR]``: DIR/trajectories.md and its charts, crosscheck/reports/trajectory_report.py; DIR
defaults to the output directory, ``crosscheck-out``; ``crosscheck reports`` writes the committed one in reports/).

Exit codes: 0 every backend inside the envelope, 1 a backend outside it (named), 2 bad input (one line).
"""

from __future__ import annotations

import json
import math
import sys
from dataclasses import replace
from pathlib import Path

import numpy as np

import cases
from crosscheck.campaigns import trajectory as T
from crosscheck.cli.options import OUTPUT_DIR, add_workers_option, workers
from crosscheck.core.sampling import project_configuration, project_velocity
from crosscheck.reports import trajectory_report
import formalisms

OUTPUT_INTERVAL = 0.05


def add_parser(sub) -> None:
    """The ``trajectory`` subcommand on ``sub``."""
    tr = sub.add_parser("trajectory", help="forward ZTCF trajectories per backend against a 50-digit reference "
                        f"(--report: {OUTPUT_DIR}/trajectories.md)")
    tr.add_argument("--case", help="a built-in case (crosscheck cases), revolute and prismatic joints only")
    tr.add_argument("--q", help="start configuration, comma-separated (default 0.3 per joint, projected onto the "
                    "constraints)")
    tr.add_argument("--v", help="start velocity, comma-separated (default 0, projected onto Jc v = 0)")
    tr.add_argument("--horizon", type=float, help="seconds to integrate (> 0)")
    tr.add_argument("--dt", type=float, default=0.01, help="step of rk4 and gauss (default 0.01 s)")
    tr.add_argument("--integrator", default="rk4", help="rk4 | gauss | adaptive (default rk4)")
    tr.add_argument("--formalism", action="append", default=[], metavar="NAME",
                    help="backend to integrate (repeatable; default the five formalisms and pinocchio)")
    tr.add_argument("--project", default="none", help="none | project | baumgarte (constrained cases)")
    tr.add_argument("--json", action="store_true", help="print the table as JSON")
    tr.add_argument("--report", nargs="?", const=OUTPUT_DIR, metavar="DIR",
                    help=f"write DIR/trajectories.md and its charts (default DIR: {OUTPUT_DIR})")
    add_workers_option(tr, "job of --report")
    tr.set_defaults(run=cmd_trajectory)


def _fail(message: str) -> int:
    print(f"crosscheck: error: {message}", file=sys.stderr)
    return 2


def _numbers(text: str, n: int, label: str) -> np.ndarray:
    try:
        values = [float(x) for x in text.split(",")]
    except ValueError:
        raise ValueError(f"--{label} must be comma-separated numbers, got {text!r}") from None
    if len(values) != n:
        raise ValueError(f"--{label} has {len(values)} entries; the case needs {n}")
    if not all(math.isfinite(x) for x in values):
        raise ValueError(f"--{label} entries must be finite, got {text!r}")
    return np.array(values)


def start_state(model, q_text: str | None, v_text: str | None):
    """The start state: given or the defaults (module doc of the parser); constrained states made admissible."""
    q = _numbers(q_text, model.n, "q") if q_text else np.full(model.n, 0.3)
    v = _numbers(v_text, model.nv, "v") if v_text else np.zeros(model.nv)
    if model.constraints:
        q = project_configuration(model, q)
        v = project_velocity(model, q, v)
    return q, v


def cmd_trajectory(args) -> int:
    if args.report is not None:
        settings = replace(trajectory_report.Settings(), workers=workers(args.workers, math.inf))
        path = trajectory_report.write(Path(args.report), settings)
        print(f"wrote {path}")
        return 0
    try:
        if args.workers is not None:
            raise ValueError("--workers applies to --report (one trajectory run is evaluated in this process)")
        if not args.case:
            raise ValueError("--case NAME is required (or --report)")
        if args.case not in cases.names():
            raise ValueError(f"unknown case '{args.case}'; see 'crosscheck cases'")
        if args.horizon is None or not args.horizon > 0 or not math.isfinite(args.horizon):
            raise ValueError(f"--horizon must be a positive number of seconds, got {args.horizon}")
        if not args.dt > 0 or not math.isfinite(args.dt) or args.dt > args.horizon:
            raise ValueError(f"--dt must be positive and at most the horizon, got {args.dt}")
        if args.integrator not in T.INTEGRATORS:
            raise ValueError(f"unknown integrator '{args.integrator}'; valid: {', '.join(T.INTEGRATORS)}")
        if args.project not in T.PROJECTIONS:
            raise ValueError(f"unknown projection '{args.project}'; valid: {', '.join(T.PROJECTIONS)}")
        names = args.formalism or [*formalisms.names(), T.PINOCCHIO]
        for name in names:
            if name != T.PINOCCHIO and name not in formalisms.names():
                raise ValueError(f"unknown formalism '{name}'; valid: {', '.join(formalisms.names())}, pinocchio")
        model = cases.load(args.case)
        T.check_model(model)
        q0, v0 = start_state(model, args.q, args.v)
        every = max(1, int(round(OUTPUT_INTERVAL / args.dt)))
        interval = every * args.dt
        horizon = interval * max(1, int(round(args.horizon / interval)))
        runs = [T.simulate(model, b, q0, v0, horizon, args.dt, args.integrator, args.project, every) for b in names]
    except (ValueError, cases.CaseError) as exc:
        return _fail(" ".join(str(exc).split()))
    closed = {} if args.case == "double_pendulum" else None
    ref = T.reference_trajectory(model, q0, v0, horizon, interval, closed_form=closed)
    lyap = T.lyapunov(model, ref)
    sigma = T.rounding_rate(model, ref, args.dt if args.integrator != "adaptive" else interval, args.integrator)
    verdict = T.judge(runs, ref, lyap, sigma)
    rows = []
    for r in runs:
        rows.append({"backend": r.backend, "error_at_end": float(T.errors(r, ref)[-1]),
                     "max_energy_error": float(np.max(T.energy_error(model, r, ref))),
                     "max_constraint_drift": float(np.max(T.constraint_drift(model, r))),
                     "digits_gone_at": T.digits_gone(r, ref), "inside_envelope": r.backend not in verdict.outside,
                     "failure": r.failure, "evaluations": r.evals, "seconds": round(r.seconds, 3)})
    summary = {"case": args.case, "q0": q0.tolist(), "v0": v0.tolist(), "horizon": horizon, "dt": args.dt,
               "integrator": args.integrator, "project": args.project, "reference_error_estimate": ref.error_estimate,
               "ftle": lyap.ftle, "lambda_env": lyap.exponent, "sigma": sigma, "judged_until": verdict.judged_until,
               "outside": verdict.outside, "backends": rows}
    if args.json:
        print(json.dumps(summary, indent=1, default=float))
    else:
        print(f"{args.case}: {args.integrator} dt = {args.dt:g}, project = {args.project}, horizon {horizon:g} s; "
              f"reference error estimate {ref.error_estimate:.1e}; FTLE {lyap.ftle:.3f} 1/s (lambda_env "
              f"{lyap.exponent:.3f}); judged until {verdict.judged_until:.2f} s")
        print(f"{'backend':<22}{'error at end':>14}{'max |dE|':>12}{'max drift':>12}{'digits gone':>13}  verdict")
        for row in rows:
            gone = row["digits_gone_at"]
            print(f"{row['backend']:<22}{row['error_at_end']:>14.2e}{row['max_energy_error']:>12.2e}"
                  f"{row['max_constraint_drift']:>12.2e}{('never' if gone == math.inf else f'{gone:.2f} s'):>13}  "
                  + ("inside" if row["inside_envelope"] else "OUTSIDE the envelope")
                  + (f" ({row['failure']})" if row["failure"] else ""))
    return 1 if verdict.outside else 0
