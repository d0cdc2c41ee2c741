"""Speed against accuracy: ``crosscheck bench`` measures every backend on a fixed set of scenes.

For each scene (double pendulum, planar chains of n links, Panda, a constrained four-bar) and backend (the five
formalisms, the Pinocchio reference, plugins):

* **single call**: seconds per ``split`` (one state a call, cycled over sampled states);
* **batch**: seconds per state of ``split_batch`` on N states (a backend without one is looped state by state);
* **anchor**: Pinocchio's ``aba`` called once per state from Python on the same model, timed in the same run, so
  every time is also reported as a ratio to it (ratios mean something on a noisy machine; absolute times do not);
* **error**: relative error of drift, ctrl, total (and lam, lam_drift) against the 50-digit reference
  (:mod:`crosscheck.references.precise`), median and max over sampled states;
* **preparation**: the first ``split`` of a fresh process minus a steady call (symbolic derivation, compilation),
  cold (empty Euler–Lagrange disk cache) and cached (the same cache again);
* **representation**: each backend on a scene modelled minimally and on the same scene written with general 3-D body
  frames (:func:`cases.representation.general_3d`): the cost of the model's structure, with equal answers.

Timings are the minimum over repeats of a loop that runs at least ``min_time`` seconds (the least disturbed
estimate on a shared machine). :mod:`crosscheck.reports.bench_report` renders the markdown report and the charts.
"""

from __future__ import annotations

import json
import os
import subprocess
import sys
import tempfile
import time
from dataclasses import asdict, dataclass, field
from typing import Callable, Iterator, Sequence

import numpy as np
import pinocchio as pin

import cases
from cases.model import Model
from cases.representation import general_3d
from crosscheck import backends
from crosscheck.core import sampling, tolerance
from crosscheck.engine import progress
from crosscheck.references import precise
from crosscheck.references.pinocchio import build
from formalisms.interface import split_batch_by_loop

SEED = 7
REPEATS = 3


@dataclass(frozen=True)
class Scene:
    """A benchmarked scene: a built-in case with parameters; ``links`` for the chains of the scaling chart."""

    label: str
    case: str
    params: tuple = ()
    links: int | None = None

    def model(self) -> Model:
        return cases.load(self.case, **dict(self.params))


def chain_scene(n: int) -> Scene:
    return Scene(f"n_link_pendulum n={n}", "n_link_pendulum", (("n", n),), links=n)


@dataclass(frozen=True)
class Plan:
    """What a bench run measures: the scenes, how many states for errors and timings, batch sizes, repeats."""

    scenes: tuple[Scene, ...]
    error_states: int
    timing_states: int
    batch: int                   # N for every scene but the target scene
    target_batch: int            # N on the target scene (the target: panda at N = 10,000)
    min_time: float              # seconds each timing loop runs at least
    prep: tuple[str, ...]        # scene labels whose preparation is measured in fresh processes
    representation: tuple[Scene, ...]
    gate: bool                   # also time the default gate (a subprocess)
    target: str = "panda"


_BASE = (Scene("double_pendulum", "double_pendulum"), Scene("panda", "panda"), Scene("four_bar", "four_bar"))

FULL = Plan(scenes=_BASE + tuple(chain_scene(n) for n in (2, 3, 5, 8, 12, 16, 20, 25, 30)), error_states=8,
            timing_states=16, batch=1000, target_batch=10_000, min_time=0.2, prep=("double_pendulum", "panda",
                                                                                   "four_bar"),
            representation=(Scene("double_pendulum", "double_pendulum"), chain_scene(8), Scene("four_bar", "four_bar")),
            gate=True)
QUICK = Plan(scenes=_BASE + tuple(chain_scene(n) for n in (2, 5)), error_states=2, timing_states=4, batch=100,
             target_batch=500, min_time=0.02, prep=("double_pendulum",),
             representation=(Scene("double_pendulum", "double_pendulum"),), gate=False)


@dataclass
class Measurement:
    """One backend on one scene."""

    backend: str
    scene: str
    n: int
    links: int | None
    single_s: float
    batch_s: float
    batch_n: int
    own_batch: bool              # the backend has its own split_batch (else it was looped)
    aba_s: float                 # Pinocchio aba per call on this scene, timed in the same run
    error_median: dict = field(default_factory=dict)
    error_max: dict = field(default_factory=dict)
    breakdowns: int = 0          # error states at which the backend flagged a BREAKDOWN (left out of the errors)
    error_states: int = 0


@dataclass
class Preparation:
    backend: str
    scene: str
    cold_s: float                # first split in a fresh process with an empty cache, minus a steady call
    cached_s: float              # the same with the cache the cold run wrote


@dataclass
class Representation:
    backend: str
    scene: str
    minimal_s: float
    general_s: float
    difference: float            # max |total_general - total_minimal| / accel_scale over the timing states (NaN in
                                 # both: not counted)


@dataclass
class Results:
    plan: str
    machine: dict
    measurements: list[Measurement]
    preparations: list[Preparation]
    representations: list[Representation]
    gate_s: float | None
    seconds: float

    def to_json(self) -> str:
        return json.dumps(asdict(self), indent=1, sort_keys=True)

    @classmethod
    def from_json(cls, text: str) -> "Results":
        """The results :meth:`to_json` wrote (``reports/speed_accuracy.json``), to render them again."""
        d = json.loads(text)
        return cls(d["plan"], d["machine"], [Measurement(**m) for m in d["measurements"]],
                   [Preparation(**p) for p in d["preparations"]], [Representation(**r) for r in d["representations"]],
                   d["gate_s"], d["seconds"])


class Interrupted(KeyboardInterrupt):
    """Ctrl-C during :func:`run`: ``results`` holds what was measured until then, ``where`` what was running."""

    def __init__(self, results: Results, where: str):
        super().__init__(f"bench interrupted while {where}")
        self.results, self.where = results, where


def per_call(fn: Callable, calls: Sequence[tuple], min_time: float, repeats: int = REPEATS) -> float:
    """Seconds per call of ``fn(*args)`` over ``calls``, cycled for at least ``min_time``; the minimum over
    ``repeats`` such loops (one loop when a single pass already takes ten times ``min_time``: a large batch)."""
    best = float("inf")
    for k in range(repeats):
        if k and best * len(calls) > 10 * min_time:
            break
        count, start = 0, time.perf_counter()
        while True:
            for args in calls:
                fn(*args)
            count += len(calls)
            elapsed = time.perf_counter() - start
            if elapsed >= min_time:
                break
        best = min(best, elapsed / count)
    return best


def states(model: Model, count: int, case: str) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """``count`` sampled states (admissible for a constrained model) as arrays Q, QD, U."""
    drawn = sampling.sample_states(model, count, SEED, case)
    return tuple(np.array([getattr(s, f) for s in drawn], dtype=float).reshape(count, -1) for f in ("q", "qd", "u"))


def aba_per_call(model: Model, Q: np.ndarray, QD: np.ndarray, min_time: float) -> float:
    """Seconds per ``pinocchio.aba`` call from Python on the model (the speed anchor; constraints ignored)."""
    pm = build.to_pinocchio(model)
    data = pm.createData()
    tau = np.ones(model.n)
    return per_call(lambda q, v: pin.aba(pm, data, q, v, tau), list(zip(Q, QD)), min_time)


def batch_function(formalism):
    """The backend's own ``split_batch``, or ``split`` looped state by state."""
    return formalism.split_batch or split_batch_by_loop(formalism.split)


def _quantities(model: Model) -> tuple[str, ...]:
    return ("drift", "ctrl", "total") + (("lam", "lam_drift") if model.k else ())


def errors(formalism, model: Model, Q, QD, U, exact: Sequence[precise.PreciseSplit]) -> tuple[dict, dict, int]:
    """Median and max relative error of each quantity against the high-precision reference, over the states the
    harness would compare: a quantity a BREAKDOWN leaves out at a state (``crosscheck.core.tolerance.breakdown``: the
    method is ill-conditioned there, e.g. operational space at a task singularity) is not counted. Also returns the
    number of states at which a BREAKDOWN left out any of these quantities. A quantity left out everywhere has no
    statistics (NaN)."""
    found: dict[str, list[float]] = {name: [] for name in _quantities(model)}
    flagged = 0
    for q, qd, u, ref in zip(Q, QD, U, exact):
        s = formalism.split(model, q, qd, u)
        broken = tolerance.breakdown(s)
        skip = set(found) if broken and tolerance.whole(broken) else tolerance.left_out(broken) & set(found)
        flagged += bool(skip)
        for name in set(found) - skip:
            found[name].append(precise.relative_error(getattr(s, name), getattr(ref, name)))
    stat = (lambda f, v: float(f(v)) if v else float("nan"))
    return ({k: stat(np.median, v) for k, v in found.items()}, {k: stat(np.max, v) for k, v in found.items()}, flagged)


def measure_scene(plan: Plan, scene: Scene, names: Sequence[str], display: progress.Display
                  ) -> Iterator[Measurement]:
    """Every backend on one scene (module doc), one after another, each a step on ``display``."""
    model = scene.model()
    display.doing(f"computing the 50-digit reference on {scene.label}")
    Qe, QDe, Ue = states(model, plan.error_states, scene.case)
    exact = [precise.split(model, q, qd, u) for q, qd, u in zip(Qe, QDe, Ue)]
    Qt, QDt, Ut = states(model, plan.timing_states, scene.case)
    N = plan.target_batch if scene.label == plan.target else plan.batch
    Qb, QDb, Ub = states(model, N, scene.case)
    for name in names:
        display.doing(f"measuring {name} on {scene.label}")
        formalism = backends.get(name)
        formalism.split(model, Qt[0], QDt[0], Ut[0])  # preparation is measured apart
        batch = batch_function(formalism)
        batch(model, Qb, QDb, Ub)  # so is a compilation a batch of N states sets off (formalisms/geometric.py)
        single = per_call(lambda q, qd, u: formalism.split(model, q, qd, u), list(zip(Qt, QDt, Ut)), plan.min_time)
        batched = per_call(lambda: batch(model, Qb, QDb, Ub), [()], plan.min_time) / N
        aba = aba_per_call(model, Qt, QDt, plan.min_time)
        median, worst, flagged = errors(formalism, model, Qe, QDe, Ue, exact)
        display.note(f"{scene.label:24s} {name:18s} single {single * 1e6:9.1f} us  batch {batched * 1e6:8.2f} "
                     f"us/state  aba {aba * 1e6:6.2f} us  total error {worst['total']:.1e}")
        display.advance()
        yield Measurement(name, scene.label, model.n, scene.links, single, batched, N,
                          formalism.split_batch is not None, aba, median, worst, flagged, len(Qe))


def first_calls(backend: str, case: str, params: dict, plugins: Sequence[str] = ()) -> dict:
    """In this process: seconds of the first ``split`` on the scene's first state, and of a second one."""
    for spec in plugins:
        backends.load_plugin(spec)
    model = cases.load(case, **params)
    Q, QD, U = states(model, 1, case)
    formalism = backends.get(backend)
    start = time.perf_counter()
    formalism.split(model, Q[0], QD[0], U[0])
    first = time.perf_counter() - start
    start = time.perf_counter()
    formalism.split(model, Q[0], QD[0], U[0])
    return {"first": first, "steady": time.perf_counter() - start}


_FIRST_CALLS = ("import json, sys; from crosscheck.campaigns import bench; "
                "print(json.dumps(bench.first_calls(*json.loads(sys.argv[1]))))")


def _fresh_process(args: list, cache: str) -> dict:
    env = {**os.environ, "CROSSCHECK_CACHE": cache, "OMP_NUM_THREADS": "1", "OPENBLAS_NUM_THREADS": "1"}
    done = subprocess.run([sys.executable, "-c", _FIRST_CALLS, json.dumps(args)], env=env, capture_output=True,
                          text=True, check=False)
    if done.returncode != 0:
        raise RuntimeError(f"preparation run {args} failed:\n{done.stderr[-2000:]}")
    return json.loads(done.stdout.strip().splitlines()[-1])


def preparation(backend: str, scene: Scene, plugins: Sequence[str] = ()) -> Preparation:
    """Cold and cached preparation of one backend on one scene, each in a fresh Python process (module doc)."""
    args = [backend, scene.case, dict(scene.params), list(plugins)]
    with tempfile.TemporaryDirectory(prefix="crosscheck-bench-") as cache:
        cold, cached = _fresh_process(args, cache), _fresh_process(args, cache)
    return Preparation(backend, scene.label, max(cold["first"] - cold["steady"], 0.0),
                       max(cached["first"] - cached["steady"], 0.0))


def _difference(a, b) -> float:
    """``max |total_b - total_a| / accel_scale``; 0 where both are NaN (the method breaks down at that state in
    both models, e.g. operational space at a task singularity), NaN where only one is."""
    both = np.isnan(a.total) & np.isnan(b.total)
    return float(np.max(np.abs(np.where(both, 0.0, b.total - a.total)))) / a.accel_scale


def representation(plan: Plan, scene: Scene, names: Sequence[str], display: progress.Display
                   ) -> Iterator[Representation]:
    """Each backend on the scene as modelled and written with general 3-D body frames: time per call and the
    largest difference of the answers; one after another, each a step on ``display``."""
    minimal = scene.model()
    general = general_3d(minimal, seed=SEED)
    Q, QD, U = states(minimal, plan.timing_states, scene.case)
    calls = list(zip(Q, QD, U))
    for name in names:
        display.doing(f"timing {name} on {scene.label} as modelled and in general 3-D frames")
        formalism = backends.get(name)
        times, answers = [], []
        for model in (minimal, general):
            answers.append([formalism.split(model, *c) for c in calls])
            times.append(per_call(lambda q, qd, u: formalism.split(model, q, qd, u), calls, plan.min_time))
        difference = max(_difference(a, b) for a, b in zip(*answers))
        display.advance()
        yield Representation(name, scene.label, times[0], times[1], difference)


def time_gate() -> float:
    """Wall seconds of the default ``crosscheck gate`` in a fresh process (report to a temporary file)."""
    with tempfile.TemporaryDirectory(prefix="crosscheck-bench-") as tmp:
        start = time.perf_counter()
        subprocess.run([sys.executable, "-c", "from crosscheck.cli import main; raise SystemExit(main())", "gate",
                        "--report", os.path.join(tmp, "gate.md")], capture_output=True, check=False)
        return time.perf_counter() - start


def machine() -> dict:
    import platform

    import casadi
    import scipy
    import sympy
    return {"python": platform.python_version(), "cpus": os.cpu_count(), "numpy": np.__version__,
            "scipy": scipy.__version__, "pinocchio": pin.__version__, "casadi": casadi.__version__,
            "sympy": sympy.__version__, "machine": platform.machine()}


def steps(plan: Plan, names: Sequence[str]) -> int:
    """The steps :func:`run` counts on its display: a backend on a scene, in fresh processes (preparation) and on a
    rewritten scene (representation), and the default gate's timing."""
    return len(names) * (len(plan.scenes) + len(plan.prep) + len(plan.representation)) + int(plan.gate)


def run(plan: Plan, names: Sequence[str] | None = None, plugins: Sequence[str] = (),
        display: progress.Display | None = None) -> Results:
    """The whole bench (module doc), its progress on ``display`` (a line per measurement). Ctrl-C raises
    :class:`Interrupted` with what was measured until then."""
    display = display or progress.silent()
    start = time.perf_counter()
    names = list(names or backends.names())
    results = Results("quick" if plan is QUICK else "full", machine(), [], [], [], None, 0.0)
    try:
        _measure(plan, names, plugins, display, results)
    except KeyboardInterrupt:
        results.seconds = time.perf_counter() - start
        raise Interrupted(results, display.current or "starting") from None
    results.seconds = time.perf_counter() - start
    return results


def _measure(plan: Plan, names: list[str], plugins: Sequence[str], display: progress.Display, results: Results
             ) -> None:
    """Fill ``results`` (module doc) measurement by measurement, so that an interrupted run keeps what it measured."""
    for scene in plan.scenes:
        for measurement in measure_scene(plan, scene, names, display):
            results.measurements.append(measurement)
    by_label = {s.label: s for s in plan.scenes}
    for label in plan.prep:
        for name in names:
            display.doing(f"preparing {name} on {label} in fresh processes")
            p = preparation(name, by_label[label], plugins)
            results.preparations.append(p)
            display.note(f"preparation {label:18s} {name:18s} cold {p.cold_s:7.2f} s  cached {p.cached_s:6.3f} s")
            display.advance()
    for scene in plan.representation:
        for rep in representation(plan, scene, names, display):
            results.representations.append(rep)
    if plan.gate:
        display.doing("timing the default gate in a fresh process")
        results.gate_s = time_gate()
        display.advance()
