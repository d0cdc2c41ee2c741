"""``crosscheck eval``: the backends at one state, in a chart or a moved frame if asked, with the gate's verdict
there (``--linearize``: also A, B of eq. 11), as text or JSON; the state is checked first (length, unit quaternions,
the chart's domain, the constraints)."""

from __future__ import annotations

import argparse
import dataclasses
import json
import sys

import numpy as np

from cases import configuration
from crosscheck.checks import charts, frames, linearization
from crosscheck.cli.options import (MAX_FRAMES, _backends, _one_line, _seed, _specs, _vector, add_plugin_option,
                                    add_task_point_option, UsageError)
from crosscheck.core import sampling, tolerance
from crosscheck.core.compare import DISAGREE
from crosscheck.engine import evaluation
from crosscheck.guards import preflight
from crosscheck.references.pinocchio.kinematics import constraint_kinematics
from formalisms.interface import UNSUPPORTED, ModelNotSupported


def _jsonable(value):
    if dataclasses.is_dataclass(value) and not isinstance(value, type):
        return {f.name: _jsonable(getattr(value, f.name)) for f in dataclasses.fields(value)}
    if isinstance(value, np.ndarray):
        return value.tolist()
    if isinstance(value, dict):
        return {k: _jsonable(v) for k, v in value.items()}
    if isinstance(value, (np.floating, np.integer)):
        return value.item()
    if value is None or isinstance(value, (int, float, str, list)):
        return value
    return repr(value)


def _length(values: list[float], size: int, label: str) -> np.ndarray:
    if len(values) != size:
        raise UsageError(f"--{label} has {len(values)} entries; this model needs {size}")
    return np.array(values)


def _inputs(args, model, chart, p) -> tuple[np.ndarray, np.ndarray]:
    """(u, tau_p): the actuator inputs and the generalized force in the chart, from ``--u`` or ``--tau``."""
    if args.u is not None and args.tau is not None:
        raise UsageError("give either --u (actuator inputs) or --tau (generalized force in the chart), not both")
    if args.tau is None:
        u = _length(_vector(args.u, "u"), model.m, "u") if args.u is not None else np.zeros(model.m)
        return u, charts.force_to_chart(chart, p, model.input_map @ u)
    tau_p = _length(_vector(args.tau, "tau"), model.n, "tau")
    tau_q = charts.force_from_chart(chart, p, tau_p)
    u, *_ = np.linalg.lstsq(model.input_map, tau_q, rcond=None)
    off = float(np.abs(model.input_map @ u - tau_q).max())
    if off > 1e-9 * (1.0 + float(np.abs(tau_q).max())):
        raise UsageError(f"--tau is not a force the inputs can produce: in joint coordinates it is {tau_q.tolist()}, "
                         f"and the nearest B u misses it by {off:.3g} (the model has {model.m} inputs for "
                         f"{model.n} joints)")
    return u, tau_p


def _chart_split(backend, model, chart, p, pd, u, tau_p) -> tuple[str, object]:
    """(how it was evaluated, split in the chart). A joint-chart answer is mapped into the chart."""
    q = chart.q_of(p)
    qd = chart.jacobian(p) @ pd
    if chart.name == "identity":
        return "joint chart", backend.split(model, q, qd, u)
    if backend.split_chart is not None:
        return f"in chart {chart.name}", backend.split_chart(model, chart, p, pd, tau_p)
    split = backend.split(model, q, qd, u)
    mapped = {name: charts.acceleration_to_chart(chart, p, pd, getattr(split, name), with_rate=name != "ctrl")
              for name in ("drift", "ctrl", "total")}
    return "joint chart, mapped by Dpsi^-1", dataclasses.replace(split, **mapped)


def _non_finite(split) -> list[str]:
    """The fields of ``split`` holding NaN or inf at a finite state: the backend failed, unless a condition it
    reports in BREAKDOWN covers the field (a task singularity's Lambda is inf; ``tolerance.left_out``)."""
    broken = tolerance.breakdown(split)
    if tolerance.whole(broken):
        return []
    excused = tolerance.left_out(broken) | {"conditions"}
    return [key for key in split.__dataclass_fields__ if key not in excused
            and isinstance(value := getattr(split, key), (float, np.ndarray)) and not np.all(np.isfinite(value))]


def _chart_splits(model, chart, p, pd, u, tau_p, chosen):
    """Per backend: (how it was evaluated, split in the chart); the backends written for other models
    (``ModelNotSupported``): name -> their reason; and the backends that failed at this valid state (raised, or
    answered NaN or inf): name -> what happened, as the gate reports a backend error."""
    out, unsupported, errors = {}, {}, {}
    for backend in chosen:
        try:
            out[backend.name] = _chart_split(backend, model, chart, p, pd, u, tau_p)
        except ModelNotSupported as exc:
            unsupported[backend.name] = str(exc)
            continue
        except Exception as exc:  # a backend that raises on a valid state has failed: report it, exit 1
            errors[backend.name] = f"{type(exc).__name__}: {_one_line(exc)}"
            continue
        bad = _non_finite(out[backend.name][1])
        if bad:
            errors[backend.name] = f"non-finite values (NaN or inf) in {', '.join(bad)}"
    return out, unsupported, errors


#: eval accepts a constrained state when |phi| and |Jc qd| are below this times the model's length scale squared
#: (times 1 + |qd|_1 for the velocity): loose enough for states pasted from a report, tight against a wrong one.
ADMISSIBLE = 1e-9


def _constraint_rows(model) -> list[str]:
    return [c.name if c.size == 1 else f"{c.name}[{i}]" for c in model.constraints for i in range(c.size)]


def _admissible(model, chart, p, pd, project: bool) -> tuple[np.ndarray, np.ndarray]:
    """(p, pd) when the state satisfies the constraints (article 5.1: phi(q) = 0 and Jc qd = 0); with ``project``
    the state moved onto the manifold and its tangent space; otherwise a UsageError saying how far off it is."""
    q, qd = chart.q_of(p), chart.jacobian(p) @ pd
    phi, Jc, _ = constraint_kinematics(model, q, qd)
    vel = Jc @ qd
    scale = model.length_scale ** 2
    tol_q, tol_v = ADMISSIBLE * scale, ADMISSIBLE * scale * (1.0 + float(np.abs(qd).sum()))
    if np.abs(phi).max() <= tol_q and np.abs(vel).max() <= tol_v:
        return p, pd
    if not project:
        rows = _constraint_rows(model)
        worst_q, worst_v = rows[int(np.abs(phi).argmax())], rows[int(np.abs(vel).argmax())]
        raise UsageError(f"the state is not admissible for model '{model.name}' (article 5.1): |phi(q)|_inf = "
                         f"{np.abs(phi).max():.3g} (row {worst_q}; allowed {tol_q:.1g}), |Jc qd|_inf = "
                         f"{np.abs(vel).max():.3g} (row {worst_v}; allowed {tol_v:.1g}); give a state on the "
                         "constraint manifold or pass --project to move it there (q by Gauss–Newton, qd onto the "
                         "tangent space)")
    q = sampling.project_configuration(model, q)
    qd = sampling.project_velocity(model, q, qd)
    p = chart.p_of(q)
    pd = charts.velocity_to_chart(chart, p, qd)
    print(f"projected onto the constraint manifold: q = {p.tolist()}, qd = {pd.tolist()}", file=sys.stderr)
    return p, pd


def cmd_eval(args) -> int:
    if args.case and args.model:
        raise UsageError("give either --case or --model, not both")
    if not args.case and not args.model:
        raise UsageError("eval needs --case NAME or --model PATH")
    spec = _specs(argparse.Namespace(case=[args.case] if args.case else [], model=[args.model] if args.model else [],
                                     base=args.base, actuated=args.actuated, armature=args.armature,
                                     task_point=args.task_point, param=args.param))[0]
    model = spec.build()
    preflight.check_model(model)
    if args.frame is not None:
        model = frames.move_scene(model, _frame(args.frame, args.seed, spec.name))
    chart = charts.get(args.chart or "identity", model, args.seed, spec.name)
    on_q = chart.name == "identity" or isinstance(chart, charts.VelocityRepresentation)   # p is q itself (nq)
    p = _length(_vector(args.q, "q"), model.nq if on_q else model.n, "q")
    pd = _length(_vector(args.qd, "qd"), model.nv, "qd") if args.qd is not None else np.zeros(model.nv)
    if on_q:
        p = _unit_quaternions(model, p, args.normalize)
    _in_chart_domain(chart, p, pd)
    if model.constraints:
        p, pd = _admissible(model, chart, p, pd, args.project)
    for problem in sampling.outside_limits(model, p) if on_q else ():
        print(f"crosscheck: warning: {problem}; evaluated there all the same", file=sys.stderr)
    u, tau_p = _inputs(args, model, chart, p)
    chosen = _backends(args.formalism)
    closed = None if args.formalism else spec.closed_form()       # the case's closed form votes in the gate too
    splits, unsupported, errors = _chart_splits(model, chart, p, pd, u, tau_p, chosen + ([closed] if closed else []))
    out = {name: {key: _jsonable(getattr(split, key)) for key in split.__dataclass_fields__}
           for name, (_, split) in splits.items()}
    verdict = _eval_verdict(model, chart, p, pd, u, splits, errors, chosen)
    linear = _eval_linearize(model, chart, p, pd, u, splits, chosen, verdict) if args.linearize else None
    if args.json:
        print(json.dumps({"case": spec.name, "params": dict(spec.params), "chart": chart.name,
                          "frame": args.frame, "q": p.tolist(), "qd": pd.tolist(), "u": u.tolist(),
                          "tau": tau_p.tolist(), "formalisms": {name: _nulled(v) for name, v in out.items()},
                          "unsupported_quantities": {name: _unsupported_keys(v) for name, v in out.items()
                                                     if _unsupported_keys(v)},
                          "not_supported": unsupported, "errors": errors, "verdict": verdict,
                          **({"linearization": linear} if linear is not None else {})}, indent=1))
        return 1 if errors or verdict["agree"] is False else 0
    where = f" in chart {chart.name} (q = psi(p))" if chart.name != "identity" else ""
    if isinstance(chart, charts.VelocityRepresentation):
        where = f" in velocity representation {chart.name} (q as given, qd = w with v = T(q) w)"
    print(f"case {model.name}{where}: q = {p.tolist()}, qd = {pd.tolist()}, u = {u.tolist()}, "
          f"generalized force = {tau_p.tolist()}")
    for name, values in out.items():
        how, split = splits[name]
        broken = tolerance.breakdown(split)
        print(f"{name} ({how}):" + (" BREAKDOWN (" + ", ".join(
            f"cond {k} = {v:.3g} > {tolerance.BREAKDOWN_LIMITS[k]:.3g}" for k, v in broken.items()) + ")"
            if broken else ""))
        keys = ("drift", "ctrl", "total", "task_drift", "power_ctrl", "kinetic_energy", "task_inertia",
                "joint_wrenches", "joint_wrenches_drift", "cond_M", "conditions")
        if model.constraints:
            keys += ("lam", "lam_drift", "constraint_force", "power_constr", "power_constr_per_coord",
                     "constraint_rank")
        if model.loads:                   # the external loads' generalized force tau_ext and its power
            keys += ("external_force", "power_ext")
        for key in keys:
            print(f"  {key:22s} {values[key]}")
    for name, reason in unsupported.items():
        print(f"{name}: NOT COMPARED ({reason})")
    for name, error in errors.items():
        print(f"{name}: ERROR at this state: {error}")
    if linear is not None:
        _print_linearization(linear)
    print(f"verdict: {verdict['text']}")
    return 1 if errors or verdict["agree"] is False else 0


def _eval_linearize(model, chart, p, pd, u, splits: dict, chosen: list, verdict: dict) -> dict:
    """``eval --linearize``: each backend's A, B (eq. 11, ``crosscheck.checks.linearization``) and the eigenvalues of
    A, the reference's, and the gate's comparison of their blocks; a DISAGREE turns the verdict (joint chart only)."""
    if chart.name != "identity":
        raise UsageError("--linearize evaluates in the joint chart (the convention of formalisms.interface."
                         "Linearization); leave out --chart")
    state = sampling.State(0, tuple(p), tuple(pd), tuple(u))
    found, errors, unsupported = linearization.linearizations(model, state, chosen)
    trusted = [split for _, split in splits.values()]
    out = {"convention": "x = (dq, v), q (+) dq on Lie groups; A (2nv x 2nv), B (2nv x m)",
           "backends": {name: {"A": lin.A.tolist(), "B": lin.B.tolist(),
                               "eigenvalues": [[float(w.real), float(w.imag)] for w in lin.eigenvalues]}
                        for name, lin in found.items()},
           "not_supported": unsupported, "errors": errors, "checks": {}}
    if trusted:
        at = tolerance.scales(trusted, model, p, pd, u=u)
        comparisons = linearization.compared(model, state, found, unsupported, at)
        out["checks"] = {name: {"verdict": c.verdict, "worst_ratio": c.worst_ratio, "outlier": c.outlier}
                         for name, c in comparisons.items()}
        failing = [name for name, c in comparisons.items() if c.verdict == DISAGREE]
        if failing or errors:
            verdict.update(agree=False, text=verdict["text"] + f"; linearization DISAGREE: "
                           f"{', '.join(failing) or 'errors from ' + ', '.join(errors)}")
    return out


def _print_linearization(linear: dict) -> None:
    print(f"linearization ({linear['convention']}):")
    with np.printoptions(precision=6, suppress=False, linewidth=160):
        for name, lin in linear["backends"].items():
            print(f"{name}:\n  A =\n{np.array(lin['A'])}\n  B =\n{np.array(lin['B'])}")
            print("  eigenvalues of A: " + ", ".join(f"{re:.6g}{im:+.6g}i" for re, im in lin["eigenvalues"]))
    for name in linear["not_supported"]:
        print(f"{name}: linearization NOT COMPARED (no linearize)")
    for name, error in linear["errors"].items():
        print(f"{name}: ERROR in linearize: {error}")
    for name, c in linear["checks"].items():
        print(f"{name}: {c['verdict']} (worst ratio {c['worst_ratio']:.3g})"
              + (f", outlier {c['outlier']}" if c["outlier"] else ""))


def _unsupported_keys(values: dict) -> list[str]:
    return [key for key, value in values.items() if value == repr(UNSUPPORTED)]


def _nulled(values: dict) -> dict:
    """A backend's JSON fields with null for a quantity it does not supply (listed in ``unsupported_quantities``)."""
    return {key: None if value == repr(UNSUPPORTED) else value for key, value in values.items()}


def _eval_verdict(model, chart, p, pd, u, splits: dict, errors: dict, chosen: list) -> dict:
    """The gate's comparison of the backends at this state (``crosscheck.engine.evaluation.judge``: the tolerance
    table, the conditioning audit, the vote for an outlier) in the joint chart; in another chart or velocity
    representation the gate judges through the chart checks instead, so no verdict is given here. ``agree`` is None
    then, or when fewer than two answers can be compared."""
    if chart.name != "identity":
        return {"agree": None, "text": f"not judged in chart {chart.name} (the gate compares charts through its chart "
                                       "checks: run crosscheck gate)"}
    found = {name: (split, None) for name, (_, split) in splits.items()} | {n: (None, e) for n, e in errors.items()}
    outcome = evaluation.outcome_of(sampling.State(0, tuple(p), tuple(pd), tuple(u)), found)
    evaluation.judge(model, outcome, chosen)
    verdicts = [*outcome.comparisons.values(), *outcome.checks.values()]
    compared = [c for c in verdicts if len(c.voters) >= 2]
    failing = [c for c in verdicts if c.verdict == DISAGREE]
    worst = max((c.worst_ratio for c in compared), default=0.0)
    outliers = sorted({c.outlier for c in failing if c.outlier})
    if errors or failing:
        named = ", ".join(c.quantity for c in failing[:6]) + (", ..." if len(failing) > 6 else "")
        text = (f"DISAGREE: {named or 'errors'} (worst ratio {worst:.3g} of the tolerance"
                + (f"; outlier {', '.join(outliers)}" if outliers else "; no single outlier") + ")"
                + (f"; errors from {', '.join(errors)}" if errors else ""))
        return {"agree": False, "worst_ratio": worst, "outliers": outliers, "failing": [c.quantity for c in failing],
                "text": text}
    if not compared:
        return {"agree": None, "text": "nothing to compare (fewer than two backends answered)"}
    return {"agree": True, "worst_ratio": worst, "outliers": [], "failing": [],
            "text": f"agree (worst ratio {worst:.3g} of the tolerance, {len(compared)} quantities compared)"}


def _unit_quaternions(model, q: np.ndarray, normalize: bool) -> np.ndarray:
    """``q`` when its quaternions (spherical and free joints, ``(x, y, z, w)``) are unit; with ``normalize`` each
    divided by its norm; otherwise a UsageError naming each one that is not."""
    if normalize:
        try:
            return configuration.normalized(model, q)
        except ValueError as exc:
            raise UsageError(str(exc)) from None
    problems = configuration.quaternion_problems(model, q)
    if problems:
        raise UsageError("; ".join(problems) + " (or pass --normalize)")
    return q


def _in_chart_domain(chart, p, pd) -> None:
    """The chart maps (p, pd) to a finite joint state below the state limit, or a UsageError says it does not."""
    with np.errstate(all="ignore"):
        q, qd = chart.q_of(p), chart.jacobian(p) @ pd
        cond = float(np.linalg.cond(chart.jacobian(p))) if np.all(np.isfinite(p)) else 0.0
    if cond > charts.GIMBAL_LIMIT:
        raise UsageError(f"chart {chart.name} has lost a direction at this p (cond(Dpsi) = {cond:.3g}; for zyx: pitch "
                         "at +-pi/2, gimbal lock), so no coordinates of it can express the motion; evaluate in the "
                         "joint chart (leave out --chart) or at another p")
    if getattr(chart, "at_centre", None) is not None and np.all(np.isfinite(p)) and chart.at_centre(p):
        raise UsageError(f"chart {chart.name}: an orientation block of p is within {charts.EXP_CENTRE_LIMIT:g} of the "
                         "chart's centre (p = 0), where the chart-native backends' derivatives of psi are 0/0 "
                         "(sin(t/2)/t); evaluate at another p or in the joint chart (leave out --chart)")
    try:
        preflight.check_vector("q (mapped to joint coordinates)", q)
        preflight.check_vector("qd (mapped to joint coordinates)", qd)
    except preflight.PreflightError as exc:
        raise UsageError(f"chart {chart.name}: {exc}") from None


def _frame(name: str, seed: int, case: str) -> frames.Frame:
    if not (name.startswith("g") and name[1:].isdigit() and int(name[1:]) < MAX_FRAMES):
        raise UsageError(f"--frame takes a sampled frame name g0 ... g{MAX_FRAMES - 1} (as in the gate report), "
                         f"got '{name}'")
    return frames.sampled(seed, case, int(name[1:]) + 1)[-1]


def add_parser(sub) -> None:
    """The ``eval`` subcommand on ``sub``."""
    ev = sub.add_parser("eval", help="evaluate the backends at one state")
    ev.add_argument("--case", help="a built-in case")
    ev.add_argument("--param", action="append", default=[], metavar="K=V", help="case parameter (repeatable)")
    ev.add_argument("--model", metavar="PATH", help="a URDF (.urdf) or MJCF (.xml) file instead of --case")
    ev.add_argument("--base", choices=("fixed", "free"),
                    help="a URDF's base: welded to the world, or on a free joint (default: as the file says)")
    ev.add_argument("--actuated", metavar="JOINTS", help="a URDF's actuated joints, comma-separated, in the order "
                    "of u (default: every joint but a free base's; \"\": none, a passive model)")
    ev.add_argument("--armature", metavar="JOINT=VALUE[,...]",
                    help="a URDF's joints' armature (rotor inertia on M's diagonal; kg m^2, kg for a slide), e.g. shoulder=0.01,elbow=0.005 (an MJCF file declares its own)")
    ev.add_argument("--q", required=True, help="positions in the chart (joint positions by default; q itself with "
                    "--chart world or mixed), comma-separated")
    ev.add_argument("--qd", help="velocities in the chart (default zeros; with --chart world or mixed the base "
                    "velocity w in that representation, v = T(q) w)")
    ev.add_argument("--u", help="actuator inputs, one per column of B (default zeros)")
    ev.add_argument("--tau", help="instead of --u: the generalized force in the chart (a covector, n entries)")
    ev.add_argument("--chart", choices=charts.names(),
                    help="evaluate in this chart q = psi(p) (default identity; zyx and exp: the charts of spherical "
                         "and free joints, p with one entry per velocity)")
    ev.add_argument("--frame", help="move the scene by the gate's sampled frame g0, g1, ... (with --seed)")
    ev.add_argument("--seed", type=_seed, default=0,
                    help="seed of the gate run (the affine chart, the exp chart's centres, the frames)")
    ev.add_argument("--formalism", action="append", help="restrict to these backends (repeatable)")
    ev.add_argument("--project", action="store_true",
                    help="constrained case: move the state onto the constraint manifold first (else it is refused)")
    ev.add_argument("--normalize", action="store_true",
                    help="divide each quaternion of --q (spherical and free joints) by its norm (else a quaternion "
                         "that is not unit is refused)")
    ev.add_argument("--linearize", action="store_true",
                    help="also print each backend's linearization A, B (eq. 11) and the eigenvalues of A, compared")
    ev.add_argument("--json", action="store_true", help="print JSON")
    add_task_point_option(ev)
    add_plugin_option(ev)
    ev.set_defaults(run=cmd_eval)
