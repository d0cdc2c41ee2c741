"""Stability maps: true errors and condition numbers along paths into trouble.

Each path (:func:`paths`) walks one model or family of models towards a place where some method degrades: the
double pendulum's task singularity theta2 -> 0 (article 6.3.4), the parallelogram four-bar's change point (5.6),
extreme mass ratios, long chains, large velocities. At every point every backend's split is measured against the
exact split of :mod:`crosscheck.references.precise` (its true error in drift, ctrl, total and, with constraints, lam),
next to the condition numbers that matter (cond M; cond(J M^-1 J^T) of the operational-space task; cond S of the
constraints) and the gate's own verdict at that state: :meth:`crosscheck.engine.evaluation.CaseSetup.evaluate`, the same
comparisons, tolerances, BREAKDOWN rule and checks as ``crosscheck gate``.

Per point and backend a true error above the gate's tolerance for that quantity is

* ``flagged`` when the backend does not vote on the quantity there (BREAKDOWN: the gate said not to trust it);
* ``caught`` when the gate's comparison of the quantity is a DISAGREE naming a pair the backend is in;
* ``silent`` otherwise: the tolerance policy let a real error through (a finding).

A DISAGREE (or a failing check, or a backend error) while every true error is within its tolerance is a false
alarm. :func:`write_report` writes ``stability.md`` and one ``stability_<path>.png`` per path.
"""

from __future__ import annotations

import dataclasses
import statistics
from dataclasses import dataclass
from typing import Sequence

import numpy as np

import cases
from crosscheck import backends as backend_registry
from crosscheck.checks import charts, invariance
from crosscheck.checks.invariance import mapped
from crosscheck.core import tolerance
from crosscheck.core.compare import DISAGREE, backend_of
from crosscheck.core.sampling import project_configuration, project_velocity, State
from crosscheck.engine import evaluation, outcomes, specs
from crosscheck.references import precise
from formalisms.interface import Formalism, Unsupported

#: The quantities measured against the exact split (lam on constrained models only).
QUANTITIES = ("drift", "ctrl", "total", "lam")
#: Seed of the gate's sampled charts and frames at every point.
SEED = 0
#: Chain length above which a backend is left out of the long-chain path: its one-off preparation grows too fast
#: (cold, on the 2-core development machine: Euler–Lagrange derivation 16 s at n = 20, 40 s at 25, 89 s at 30;
#: the geometric backend's casadi graph 4 s, 8 s, 25 s, rebuilt in every process).
PREPARATION_CAP = {"euler_lagrange": 20, "geometric": 20}
#: The double pendulum's state on its paths (besides the coordinate a path moves).
DP_Q, DP_QD, DP_U = (0.7, 0.5), (1.5, -2.0), (3.0, -1.0)

FULL_CHECKS = specs.Checks()
CHAIN_CHECKS = specs.Checks(charts=False, frames=0)      # re-deriving a long chain per chart or frame costs minutes
COMPARISONS_ONLY = specs.Checks(charts=False, frames=0, conservation=False)  # conservation builds geometric's graph


@dataclass(frozen=True)
class Point:
    """One state on a path: the path parameter ``x``, the case, the state, the backends evaluated and the gate's
    checks."""

    x: float
    spec: specs.CaseSpec
    state: State
    backends: tuple[str, ...]
    checks: specs.Checks = FULL_CHECKS
    chart: str | None = None        # also measure the answers in this chart (:class:`ChartMeasurement`)


@dataclass(frozen=True)
class Path:
    """A sequence of points into trouble; ``conditions`` are the condition names shown besides cond M."""

    name: str
    title: str
    parameter: str
    conditions: tuple[str, ...]
    points: tuple[Point, ...]
    note: str = ""


def _points(spec_of, state_of, xs, names, checks=FULL_CHECKS) -> tuple[Point, ...]:
    return tuple(Point(float(x), spec_of(x), State(i, *state_of(x)), tuple(names), checks) for i, x in enumerate(xs))


def theta2_path(count: int, names: Sequence[str]) -> Path:
    """Double pendulum at q = (0.7, theta2), theta2 from 1 down to 1e-12: the task Jacobian of the tip goes
    singular (the stretched pendulum, article 6.3.4)."""
    xs = np.logspace(0, -12, count)
    return Path("theta2", "Task singularity: double pendulum, theta2 -> 0", "theta2 (rad)", ("task",),
                _points(lambda x: specs.CaseSpec("double_pendulum"), lambda x: ((DP_Q[0], x), DP_QD, DP_U), xs, names))


def four_bar_state(delta: float) -> tuple[tuple, tuple, tuple]:
    """The parallelogram four-bar (the default 1-2-1-2) on its parallelogram branch q = (a, pi/2 - a, a), crank
    angle a = pi/2 - delta, ``delta`` from the change point q = (pi/2, 0, pi/2) where the loop Jacobian loses rank;
    q polished onto phi = 0 and qd = 1.3 (1, -1, 1) projected onto Jc qd = 0 (``crosscheck.core.sampling``)."""
    model = cases.load("four_bar")
    a = np.pi / 2 - delta
    q = project_configuration(model, (a, np.pi / 2 - a, a))
    qd = project_velocity(model, q, 1.3 * np.array([1.0, -1.0, 1.0]))
    return tuple(q.tolist()), tuple(qd.tolist()), (2.0, -1.0, 0.5)


def four_bar_path(count: int, names: Sequence[str]) -> Path:
    """The parallelogram four-bar approaching its change point, delta from 1 down to 1e-10 rad."""
    xs = np.logspace(0, -10, count)
    return Path("four_bar", "Change point: parallelogram four-bar", "delta = pi/2 - crank angle (rad)",
                ("constraint", "task"), _points(lambda x: specs.CaseSpec("four_bar"), four_bar_state, xs, names))


def mass_ratio_path(count: int, names: Sequence[str]) -> Path:
    """Double pendulum with m1 = 1 and m2 from 1e-6 to 1e6 kg."""
    xs = np.logspace(-6, 6, count)
    return Path("mass_ratio", "Mass ratio: double pendulum, m2/m1 from 1e-6 to 1e6", "m2 / m1", ("task",),
                _points(lambda x: specs.CaseSpec("double_pendulum", (("m2", repr(float(x))),)),
                        lambda x: (DP_Q, DP_QD, DP_U), xs, names))


def chain_state(n: int) -> tuple[tuple, tuple, tuple]:
    """The first n entries of one seeded draw: q uniform in +-pi, qd in +-1 rad/s, u in +-10 (one input per joint)."""
    rng = np.random.default_rng(SEED)
    q, qd, u = rng.uniform(-np.pi, np.pi, 60), rng.uniform(-1.0, 1.0, 60), rng.uniform(-10.0, 10.0, 60)
    return tuple(q[:n].tolist()), tuple(qd[:n].tolist()), tuple(u[:n].tolist())


def chain_path(ns: Sequence[int], names: Sequence[str]) -> Path:
    """n_link_pendulum for the given chain lengths (at most 60); a backend of :data:`PREPARATION_CAP` only up to its
    cap, the energy checks only while the geometric backend is evaluated."""
    if max(ns) > 60:
        raise ValueError(f"chain_path: chain lengths up to 60 are supported, got {max(ns)}")
    points = []
    for i, n in enumerate(ns):
        kept = tuple(b for b in names if n <= PREPARATION_CAP.get(b, n))
        checks = CHAIN_CHECKS if "geometric" in kept else COMPARISONS_ONLY
        points.append(Point(float(n), specs.CaseSpec("n_link_pendulum", (("n", str(n)),)), State(i, *chain_state(n)),
                            kept, checks))
    capped = ", ".join(f"{b} up to n = {cap}" for b, cap in PREPARATION_CAP.items() if b in names)
    note = (f"Chart and frame checks are off on this path (each re-derives the chain); {capped} (their one-off "
            "preparation grows too fast: cold, Euler–Lagrange's symbolic derivation took 16 s at n = 20, 40 s at 25 "
            "and 89 s at 30; the geometric backend's casadi graph 4 s, 8 s and 25 s); beyond that the energy "
            "checks are off too (they use the geometric backend's energy).")
    return Path("chain", "Long chains: n_link_pendulum", "n (links)", ("task",), tuple(points), note)


def velocity_path(count: int, names: Sequence[str]) -> Path:
    """Double pendulum with qd = s (1.5, -2.0), s from 1 to 1e6."""
    xs = np.logspace(0, 6, count)
    return Path("velocity", "Large velocities: double pendulum, qd scaled by s", "s (qd = s qd0)", ("task",),
                _points(lambda x: specs.CaseSpec("double_pendulum"),
                        lambda x: (DP_Q, tuple(x * v for v in DP_QD), DP_U), xs, names))


#: The ball pendulum's chart state on the gimbal path (besides the pitch): yaw, roll, the chart rates pd and u.
GIMBAL_YAW, GIMBAL_ROLL, GIMBAL_PD, GIMBAL_U = 0.4, -0.7, (0.9, -1.3, 0.6), (0.5, -0.8, 0.3)


def gimbal_state(delta: float) -> tuple[tuple, tuple, tuple]:
    """The ball pendulum at zyx angles (yaw, pi/2 - delta, roll) with chart rates pd: q = psi(p) and qd = Dpsi pd
    rounded to floats (the joint-chart state the gate is given), u fixed."""
    chart = charts.get("zyx", cases.load("ball_pendulum"))
    p = np.array([GIMBAL_YAW, np.pi / 2 - delta, GIMBAL_ROLL])
    return (tuple(chart.q_of(p).tolist()), tuple((chart.jacobian(p) @ np.array(GIMBAL_PD)).tolist()), GIMBAL_U)


def gimbal_path(xs: Sequence[float], names: Sequence[str]) -> Path:
    """The ball pendulum walking into gimbal lock of its zyx chart: pitch = pi/2 - delta (article 6.4, 9.1)."""
    note = ("The joint chart (quaternion, body angular velocity) is benign all along; the trouble is the zyx chart. "
            "The chart table below measures the chart's accelerations pdd: natively (Euler–Lagrange and geometric "
            "`split_chart`, `@zyx`) and every joint-chart answer mapped as the gate maps it "
            "(`invariance.mapped`), against the exact split carried into the chart in mpmath "
            "(`precise.chart_split`).")
    return Path("gimbal", "Gimbal lock: ball pendulum in zyx Euler angles, pitch -> pi/2",
                "delta = pi/2 - pitch (rad)", (),
                tuple(dataclasses.replace(p, chart="zyx") for p in _points(
                    lambda x: specs.CaseSpec("ball_pendulum"), gimbal_state, xs, names)), note)


def paths(quick: bool, names: Sequence[str]) -> list[Path]:
    """The six paths: a handful of points each when ``quick`` (CI), else 10 to 30."""
    ns = (2, 4, 8) if quick else (2, 3, 4, 6, 8, 10, 12, 16, 20, 25, 30, 40, 50, 60)
    deltas = (1e-1, 1e-3, 1e-4, 1e-6, 1e-8, 1e-10) if quick else np.logspace(-1, -10, 19)
    return [theta2_path(5 if quick else 25, names), four_bar_path(5 if quick else 21, names),
            mass_ratio_path(5 if quick else 25, names), chain_path(ns, names), velocity_path(4 if quick else 16, names),
            gimbal_path(deltas, names)]


@dataclass(frozen=True)
class Measurement:
    """One point: conditions (``"M"``: cond M, and each condition a backend reports, the median over reporters),
    per backend and quantity the relative true error and the absolute true error over the gate's tolerance (NaN
    where the gate compared nothing), the gate's tolerance per quantity, the verdict per backend (agree, DISAGREE,
    BREAKDOWN, ERROR) with the broken conditions, the (backend, quantity) pairs above tolerance by kind
    (``flagged``, ``caught``, ``silent``: module doc), the gate's alarms and its worst error/tolerance ratio."""

    point: Point
    conditions: dict[str, float]
    errors: dict[str, dict[str, float]]
    ratios: dict[str, dict[str, float]]
    tolerances: dict[str, float]
    verdicts: dict[str, str]
    breakdowns: dict[str, dict[str, float]]
    over: dict[str, tuple[tuple[str, str], ...]]
    alarms: tuple[str, ...]
    worst_ratio: float
    chart: "ChartMeasurement | None" = None

    @property
    def false_alarm(self) -> bool:
        return bool(self.alarms) and not any(self.over.values())

    def voting_ratio(self) -> float:
        """The largest true error / tolerance of a backend on a quantity it votes on (0 when none)."""
        return max((r for b, rs in self.ratios.items() for q, r in rs.items()
                    if q not in self.left_out(b) and r == r), default=0.0)

    def left_out(self, backend: str) -> set[str]:
        """The quantities ``backend`` does not vote on here (all when wholly in BREAKDOWN or in error)."""
        if self.verdicts.get(backend) == "ERROR":
            return set(QUANTITIES)
        broken = self.breakdowns.get(backend, {})
        return set(QUANTITIES) if tolerance.whole(broken) else tolerance.left_out(broken) & set(QUANTITIES)


def _conditions(outcome: outcomes.StateOutcome) -> dict[str, float]:
    out = {"M": statistics.median(s.cond_M for s in outcome.splits.values())} if outcome.splits else {}
    reported: dict[str, list[float]] = {}
    for split in outcome.splits.values():
        for name, value in split.conditions.items():
            reported.setdefault(name, []).append(float(value))
    out.update({name: float(statistics.median(values)) for name, values in reported.items()})
    return out


def _in_disagreement(outcome: outcomes.StateOutcome, backend: str, quantities=None) -> bool:
    """Whether ``backend`` is in a disagreeing pair of a comparison (of ``quantities``, default all and the checks)."""
    comps = ([outcome.comparisons[q] for q in quantities if q in outcome.comparisons] if quantities is not None
             else [*outcome.comparisons.values(), *outcome.checks.values()])
    return any(backend in (backend_of(a), backend_of(b)) for c in comps if c.verdict == DISAGREE
               for a, b in c.disagreeing_pairs)


def _verdict(outcome: outcomes.StateOutcome, backend: str) -> str:
    if backend in outcome.errors:
        return "ERROR"
    if backend in outcome.breakdowns:
        return "BREAKDOWN"
    return DISAGREE if _in_disagreement(outcome, backend) else "agree"


def _true_errors(splits, exact: precise.PreciseSplit, scales) -> dict[str, dict[str, tuple[float, float]]]:
    """Per backend and quantity: (relative error against the exact split, the largest error over the gate's tolerance
    entry by entry; NaN where the gate had no scales)."""
    out: dict[str, dict[str, tuple[float, float]]] = {}
    for name, split in splits.items():
        for quantity in QUANTITIES:
            value, truth = split.quantity(quantity), getattr(exact, quantity)
            if truth is None or value is None or isinstance(value, Unsupported):
                continue
            relative = precise.relative_error(value, truth)
            if scales is None:
                out.setdefault(name, {})[quantity] = (relative, float("nan"))
                continue
            error = np.abs(np.asarray(value, dtype=float) - exact.floats(quantity))
            with np.errstate(divide="ignore", invalid="ignore"):
                over = np.where(error == 0.0, 0.0, error / tolerance.tolerance(quantity, scales))
            out.setdefault(name, {})[quantity] = (relative, float(np.max(over)) if np.all(np.isfinite(value))
                                                  else float("inf"))
    return out


def measure(point: Point, setup: evaluation.CaseSetup, formalisms: Sequence[Formalism]) -> Measurement:
    """Everything at one point: the gate's evaluation at the state, the exact split, and their comparison."""
    state, model = point.state, setup.model
    outcome = setup.evaluate(state, formalisms)
    exact = precise.split(model, state.q, state.qd, state.u)
    true = _true_errors({name: split for name, split in outcome.splits.items() if name in point.backends}, exact,
                        outcome.scales)
    tolerances = {q: c.tolerance for q, c in outcome.comparisons.items() if q in QUANTITIES}
    ratios = {b: {q: (over if q in tolerances else float("nan")) for q, (_, over) in qs.items()}
              for b, qs in true.items()}
    verdicts = {b.name: _verdict(outcome, b.name) for b in formalisms}
    alarms = tuple([f"{name}: {c.worst_ratio:.3g}" for name, c in [*outcome.comparisons.items(),
                                                                     *outcome.checks.items()]
                    if c.verdict == DISAGREE] + [f"{b} raised {m}" for b, m in outcome.errors.items()])
    m = Measurement(point, _conditions(outcome), {b: {q: rel for q, (rel, _) in qs.items()} for b, qs in true.items()},
                    ratios, tolerances, verdicts, dict(outcome.breakdowns), {}, alarms, outcome.worst_ratio)
    chart = measure_chart(point, setup, formalisms, outcome) if point.chart else None
    return dataclasses.replace(m, over=_over(m, outcome), chart=chart)


#: The chart accelerations measured on a chart path.
CHART_QUANTITIES = ("drift", "ctrl", "total")


@dataclass(frozen=True)
class ChartMeasurement:
    """The answers in a chart at one point (the zyx chart of a model with ball joints: ``precise.chart_split``).

    ``cond_D``: cond(Dpsi) at the chart point the gate computes (``p = psi^-1(q)`` in floats; inf where Dpsi came out
    exactly singular), ``cond_D_exact`` at the exact one, ``cond_Mp`` the exact cond of the chart's mass matrix
    ``Dpsi^T M Dpsi``; ``compared``: whether the gate's chart check ran (cond_D <= ``charts.GIMBAL_LIMIT``; else it
    leaves the chart out, a BREAKDOWN of the chart). Per voter (``<backend>@<chart>``: evaluated natively,
    ``split_chart``; ``<backend>``: its joint-chart answer mapped as the gate maps it) and quantity: ``errors`` the
    relative error against the exact split at the state carried into the chart in mpmath; ``ratios`` the absolute
    error over the chart comparison's tolerance (the gate's where it compared; past the limit the tolerance the check
    would use with the limit lifted: ``would_be`` is then True). ``own``: per native voter, its relative error
    against the exact answer for the float chart inputs it was given (its own error, without the harness's rounding
    of the state into the chart); ``state_map``: the relative change of the exact total between those inputs and the
    state (the rounding of ``p = psi^-1(q)``, ``pd = Dpsi^-1 qd``). ``raised``: voter -> error message. ``verdicts``:
    per quantity the chart comparison's verdict (``left out`` past the limit); ``over`` the (voter, quantity) pairs
    above tolerance by kind, as :attr:`Measurement.over` (past the limit every one is ``flagged``)."""

    chart: str
    cond_D: float
    cond_D_exact: float
    cond_Mp: float
    compared: bool
    would_be: bool
    errors: dict[str, dict[str, float]]
    ratios: dict[str, dict[str, float]]
    own: dict[str, dict[str, float]]
    state_map: float
    raised: dict[str, str]
    verdicts: dict[str, str]
    over: dict[str, tuple[tuple[str, str], ...]]

    @property
    def voters(self) -> tuple[str, ...]:
        return tuple(dict.fromkeys([*self.errors, *self.raised]))

    def worst(self, voter: str) -> float:
        """The voter's largest relative error over the chart quantities (inf when it raised, NaN when absent)."""
        if voter in self.raised:
            return float("inf")
        return max(self.errors.get(voter, {}).values(), default=float("nan"))

    def ratio(self, voter: str) -> float:
        return max((r for r in self.ratios.get(voter, {}).values() if r == r), default=float("nan"))


def _abs_ratio(value, exact: np.ndarray, tol) -> float:
    value = np.asarray(value, dtype=float)
    if not np.all(np.isfinite(value)):
        return float("inf")
    error = np.abs(value - exact)
    with np.errstate(divide="ignore", invalid="ignore"):
        return float(np.max(np.where(error == 0.0, 0.0, error / np.asarray(tol, dtype=float))))


def measure_chart(point: Point, setup: evaluation.CaseSetup, formalisms: Sequence[Formalism],
                  outcome: outcomes.StateOutcome) -> ChartMeasurement:
    """The chart part of :func:`measure`: the gate's chart check at the state re-run with a record of what it used
    (``invariance.chart_checks``, deterministic: the same comparisons as in ``outcome``), and past the limit the same
    check with the limit lifted, for the tolerance and verdict it would have had."""

    model, state = setup.model, point.state
    chart = next((c for c in setup.charts if c.name == point.chart), None) or charts.get(point.chart, model)
    supported = [b for b in formalisms if b.name in outcome.splits or b.name in outcome.errors]
    record: dict = {}
    comps = invariance.chart_checks(model, state, chart, outcome.trusted, supported, {}, outcome.scales, record)
    compared = record["cond"] <= charts.GIMBAL_LIMIT
    raised: dict[str, str] = {}
    if not compared:
        record = {}
        with np.errstate(all="ignore"):
            try:
                comps = invariance.chart_checks(model, state, chart, outcome.trusted, supported, raised,
                                                outcome.scales, record, limit=float("inf"))
            except np.linalg.LinAlgError as exc:     # Dpsi exactly singular at the rounded chart point
                raised["harness map"] = f"LinAlgError: {exc}"
    exact = precise.chart_split(model, chart, state.q, state.qd, state.u)
    errors: dict[str, dict[str, float]] = {}
    ratios: dict[str, dict[str, float]] = {}
    own: dict[str, dict[str, float]] = {}
    state_map = float("nan")
    tolerances = record.get("tolerances", {})
    if "pd" in record:
        p, pd = record["p"], record["pd"]
        at = precise.chart_split_at(model, chart, p, pd, record["tau_p"])
        state_map = precise.relative_error(at.floats("total"), exact.total)
        values = {label: {q: split.quantity(q) for q in CHART_QUANTITIES} for label, split in record["native"].items()}
        for label, split in record["native"].items():
            own[label] = {q: precise.relative_error(split.quantity(q), getattr(at, q)) for q in CHART_QUANTITIES}
        with np.errstate(all="ignore"):
            for name, split in outcome.splits.items():
                if name in point.backends:
                    done: dict = {}
                    values[name] = {q: mapped(chart, p, pd, split, q, done) for q in CHART_QUANTITIES}
        for label, qs in values.items():
            errors[label] = {q: precise.relative_error(v, getattr(exact, q)) for q, v in qs.items()}
            ratios[label] = {q: (_abs_ratio(v, exact.floats(q), tolerances[q]) if q in tolerances else float("nan"))
                             for q, v in qs.items()}
    verdicts = {q: (comps[key].verdict if (key := f"chart {chart.name}: {q}") in comps else "not compared")
                if compared else "left out" for q in CHART_QUANTITIES}
    kinds: dict[str, list[tuple[str, str]]] = {"flagged": [], "caught": [], "silent": []}
    for label, rs in ratios.items():
        for q, r in rs.items():
            if not r > 1.0:
                continue
            key = f"chart {chart.name}: {q}"
            caught = compared and key in comps and comps[key].verdict == DISAGREE and any(
                label in (a, b) for a, b in comps[key].disagreeing_pairs)
            kinds["flagged" if not compared else "caught" if caught else "silent"].append((label, q))
    return ChartMeasurement(chart.name, record.get("cond", float("inf")), float(exact.cond_D), float(exact.cond_Mp),
                            compared, not compared and bool(tolerances), errors, ratios, own, state_map, raised,
                            verdicts, {k: tuple(v) for k, v in kinds.items()})


def _over(m: Measurement, outcome: outcomes.StateOutcome) -> dict[str, tuple[tuple[str, str], ...]]:
    """The (backend, quantity) pairs whose true error is above the gate's tolerance (or not finite), by kind."""
    kinds: dict[str, list[tuple[str, str]]] = {"flagged": [], "caught": [], "silent": []}
    for backend, rs in m.ratios.items():
        for quantity, ratio in rs.items():
            if not ratio > 1.0:     # NaN: no tolerance, the gate compared nothing there
                continue
            kind = ("flagged" if quantity in m.left_out(backend) else
                    "caught" if _in_disagreement(outcome, backend, [quantity]) else "silent")
            kinds[kind].append((backend, quantity))
    return {kind: tuple(pairs) for kind, pairs in kinds.items()}


@dataclass(frozen=True)
class PathResult:
    path: Path
    measurements: tuple[Measurement, ...]

    @property
    def backends(self) -> tuple[str, ...]:
        return tuple(dict.fromkeys(b for p in self.path.points for b in p.backends))


def run_path(path: Path, progress=None) -> PathResult:
    """Measure every point of ``path`` (one :class:`~crosscheck.engine.evaluation.CaseSetup` per case and checks)."""
    setups: dict[tuple, evaluation.CaseSetup] = {}
    out = []
    for point in path.points:
        key = (point.spec, point.checks)
        if key not in setups:
            setups[key] = evaluation.CaseSetup.build(point.spec, SEED, point.checks)
        out.append(measure(point, setups[key], [backend_registry.get(b) for b in point.backends]))
        if progress:
            progress(path.name, len(out), len(path.points))
    return PathResult(path, tuple(out))
