"""One chunk of a campaign: a seeded Hypothesis run of the property "every drawn model and state passes the gate's
comparison and checks", its first failure shrunk and kept as a finding (``crosscheck.campaigns.fuzz``)."""

from __future__ import annotations

import contextlib
import hashlib
import json
import math
import time
import traceback
from dataclasses import dataclass, field
from pathlib import Path
from typing import Callable, Iterator, Sequence

import numpy as np
from hypothesis import HealthCheck, Phase, Verbosity, given, settings, target
from hypothesis import seed as hypothesis_seed
from hypothesis import strategies as st

from cases.model import Model
from cases.serialize import model_to_dict
from crosscheck import backends, isolation, testing
from crosscheck.campaigns.fuzz.interrupts import INTERRUPTS
from crosscheck.campaigns.fuzz.settings import chunk_seed, chunk_size, FuzzConfig
from crosscheck.campaigns.fuzz.storage import save_finding
from crosscheck.checks import charts, frames
from crosscheck.core.sampling import State
from crosscheck.engine import evaluation
from crosscheck.engine.outcomes import StateOutcome


# ------------------------------------------------------------------------------------------------ one chunk


class _ShrinkBudget(BaseException):
    """Raised inside the property when a chunk has spent its shrinking calls (escapes Hypothesis, which only
    shrinks on Exception)."""


def _worst(outcome: StateOutcome) -> tuple[float, str]:
    """The worst error/tolerance ratio of every comparison and check at a state (NaN counts as inf), and its key."""
    everything = {**outcome.comparisons, **outcome.checks}
    ratios = {key: (c.worst_ratio if c.worst_ratio == c.worst_ratio else math.inf) for key, c in everything.items()}
    if not ratios:
        return 0.0, ""
    key = max(ratios, key=ratios.get)
    return ratios[key], key


def _comparison_record(key: str, c) -> dict:
    return {"key": key, "verdict": c.verdict, "worst_ratio": c.worst_ratio, "tolerance": c.tolerance,
            "outlier": c.outlier, "values": {voter: np.atleast_1d(np.asarray(v, dtype=float)).tolist()
                                             for voter, v in c.values.items()}}


def finding_id(digest: str, state: dict, keys: Sequence[str]) -> str:
    """A stable ID: a hash of the model digest, the state and the failing check keys (sorted)."""
    text = json.dumps([digest, state["q"], state["qd"], state["u"], sorted(keys)])
    return hashlib.sha256(text.encode()).hexdigest()[:12]


def make_finding(model: Model, state: State, chart_spec: tuple[str, int], frame: frames.Frame, checks: dict,
                 chosen: Sequence[str], outcome: StateOutcome | None, harness_error: str | None = None) -> dict:
    """A finding (module doc): the serialized model, the state, the chart and frame, every failing comparison with
    each voter's value, the backend errors; without ID, campaign and shrinking marks (added when it is saved)."""
    failing = [] if outcome is None else [_comparison_record(k, c) for k, c in testing.failing(outcome).items()]
    errors = {} if outcome is None else dict(outcome.errors)
    if harness_error is not None:
        errors["harness"] = harness_error
    state_dict = {"q": list(state.q), "qd": list(state.qd), "u": list(state.u)}
    keys = [c["key"] for c in failing] + [f"error {name}" for name in errors]
    return {"id": finding_id(model.digest(), state_dict, keys), "model": model_to_dict(model), "state": state_dict,
            "chart": {"name": chart_spec[0], "seed": chart_spec[1]},
            "frame": {"name": frame.name, "rotation": frame.rotation.tolist(),
                      "translation": frame.translation.tolist()},
            "checks": checks, "backends": list(chosen), "failing": failing, "errors": errors,
            "worst_ratio": max([c["worst_ratio"] for c in failing], default=math.inf if errors else 0.0)}


@dataclass
class _Recorder:
    """What one chunk's property calls saw: counts, the worst ratio and where, the last failing call."""

    shrink_calls: int
    progress: Callable[[int, int, float], None] | None = None
    examples: int = 0
    shrinking: int = 0
    states: int = 0
    models: set = field(default_factory=set)
    worst: float = 0.0
    worst_key: str = ""
    agreeing: float = 0.0
    agreeing_key: str = ""
    last_failure: dict | None = None

    def example(self, model: Model) -> None:
        """A call that drew a model: a generated example, or (after a failure) a shrinking call."""
        if self.last_failure is None:
            self.examples += 1
        else:
            self.shrinking += 1
            if self.shrinking > self.shrink_calls:
                raise _ShrinkBudget()
        self.models.add(model.digest())

    def state(self, ratio: float, key: str, failed: bool) -> None:
        self.states += 1
        if ratio > self.worst or not self.worst_key:
            self.worst, self.worst_key = ratio, key
        if not failed and (ratio > self.agreeing or not self.agreeing_key):
            self.agreeing, self.agreeing_key = ratio, key

    def done(self, states: int, ratio: float) -> None:
        if self.progress is not None:
            self.progress(int(self.last_failure is None), states, ratio)


def evaluate(model: Model, state: State, chart: charts.Chart, frame: frames.Frame, chosen, checks: dict
             ) -> StateOutcome:
    """One state as the gate checks it: every backend compared, then (as ``checks`` says) the chart check in
    ``chart``, the frame check on the scene moved by ``frame`` and the conservation checks."""
    (outcome,) = evaluate_block(model, [state], chart, frame, chosen, checks)
    return outcome


def evaluate_block(model: Model, states: Sequence[State], chart: charts.Chart, frame: frames.Frame, chosen,
                   checks: dict) -> Iterator[StateOutcome]:
    """:func:`evaluate` at each of ``states``, yielded as each is done: the backends run over the block at once in the
    joint chart and on the moved scene (``gate.run_block``, which gives every state the splits and errors it gets
    alone), then state by state come the comparisons and checks. Should running the backends over the block fail in
    the harness itself, the states go one by one, so that the failure is met at the state that causes it."""
    scene = (frame, frames.move_scene(model, frame)) if checks["frames"] else None
    # the identity of a model with group joints is q itself, which no backend evaluates "in a chart"
    in_chart = [chart] if checks["charts"] and (charts.applies(model) or chart.name != "identity") else []
    try:
        joint = evaluation.run_block(model, states, chosen)
        moved = evaluation.run_block(scene[1], states, chosen) if scene else [None] * len(states)
    except Exception:  # the harness, not a backend (whose errors run_block records): one state at a time
        joint = moved = None
    for k, state in enumerate(states):
        outcome = evaluation.run_backends(model, state, chosen) if joint is None else joint[k]
        evaluation.judge(model, outcome, chosen)
        evaluation.add_checks(model, outcome, chosen, in_chart, scene, checks["conservation"],
                        None if moved is None else moved[k])
        if checks.get("linearization") and state.index == 0:   # a finding saved before the check has none
            evaluation.add_linearization_checks(model, outcome, chosen)
        yield outcome


def _evaluate(model: Model, states: Sequence[State], chart_spec: tuple[str, int], frame: frames.Frame,
              chosen, checks: dict, rec: _Recorder) -> tuple[float, dict | None]:
    """Every state (:func:`evaluate_block`); (worst ratio, finding of the first failing state or None). An exception
    of the harness itself is a finding too. A plugin that crashed too often on an earlier model is tried again
    (``crosscheck.isolation.new_case``)."""
    isolation.new_case()
    worst, names = 0.0, [b.name for b in chosen]
    chart = charts.get(chart_spec[0], model, chart_spec[1])
    outcomes = evaluate_block(model, states, chart, frame, chosen, checks)
    for state in states:
        try:
            outcome = next(outcomes)
        except Exception as exc:  # the harness failing on a valid model and state is a finding, not a crash
            where = "".join(traceback.format_exception(exc, limit=-3)).strip()
            return math.inf, make_finding(model, state, chart_spec, frame, checks, names, None, where)
        ratio, key = _worst(outcome)
        rec.state(ratio, key, outcome.failed)
        worst = max(worst, ratio)
        if outcome.failed:
            return worst, make_finding(model, state, chart_spec, frame, checks, names, outcome)
    return worst, None


def _property(cfg: FuzzConfig, chosen, rec: _Recorder):
    """The property one chunk runs (module doc)."""

    @given(st.data())
    def backends_agree(data):
        INTERRUPTS.poll()
        model = data.draw(testing.models(cfg.max_bodies, cfg.constraints, group=cfg.group_joints, loads=cfg.loads,
                                         pfaffian=cfg.pfaffian), label="model")
        count = data.draw(st.integers(1, cfg.max_states), label="number of states")
        states = [data.draw(testing.states(model, i), label=f"state {i}") for i in range(count)]
        chart_spec = data.draw(testing.chart_specs(model), label="chart (name, seed)")
        frame = data.draw(testing.frames(), label="frame")
        rec.example(model)
        worst, finding = _evaluate(model, states, chart_spec, frame, chosen, cfg.checks(), rec)
        rec.done(len(states), worst)
        target(min(worst, 1e300), label="worst error/tolerance")
        if finding is not None:
            rec.last_failure = finding
            raise AssertionError(f"finding {finding['id']}: "
                                 + ", ".join([c["key"] for c in finding["failing"]] + list(finding["errors"])))

    return backends_agree


@contextlib.contextmanager
def _no_local_constants():
    """Hypothesis (6.13x and later) sometimes draws a literal constant found in the source of the local modules in
    ``sys.modules``, so what a chunk drew depended on which modules the process had imported (and on its
    ``__main__``): a spawned worker and a test process that had imported ``crosscheck.campaigns.stability`` drew
    different examples from one seed. A campaign's draws must depend on its seed alone, so during a chunk that pool is
    empty, and so is the cache of constants Hypothesis drew from it before (filled by any earlier property test in the
    process: a test of the closed forms before the worker test drew different examples). This replaces a private
    Hypothesis function and clears a private cache (no public setting exists); without them the chunk still runs."""
    try:
        from hypothesis.internal.conjecture import providers
        original, cache = providers._get_local_constants, providers.CONSTANTS_CACHE.cache
    except (ImportError, AttributeError):
        yield
        return
    providers._get_local_constants = providers.Constants
    cache.clear()
    try:
        yield
    finally:
        providers._get_local_constants = original
        cache.clear()


def run_chunk(cfg: FuzzConfig, k: int, progress: Callable[[int, int, float], None] | None = None) -> dict:
    """Run chunk ``k`` (module doc); save its finding, if any, in ``cfg.out``; return its log record.

    An interrupt (Ctrl-C, SIGINT or SIGTERM, the campaign's stop flag) ends the chunk: a failure in hand (shrunk or
    not) is saved marked ``interrupted``, and so is the record.
    """
    with INTERRUPTS.chunk():
        chosen = [backends.get(name) for name in cfg.backends]
        rec = _Recorder(cfg.shrink_calls, progress)
        test = settings(max_examples=chunk_size(cfg, k), database=None, deadline=None, derandomize=False,
                        phases=(Phase.generate, Phase.target, Phase.shrink), report_multiple_bugs=False,
                        suppress_health_check=list(HealthCheck), verbosity=Verbosity.quiet)(_property(cfg, chosen, rec))
        test = hypothesis_seed(chunk_seed(cfg.seed, k))(test)
        start, interrupted, shrunk = time.perf_counter(), False, True
        try:
            with np.errstate(all="ignore"), _no_local_constants(), INTERRUPTS.during("test"):  # NaN, inf reported
                test()
        except KeyboardInterrupt:
            interrupted, shrunk = True, False
        except _ShrinkBudget:
            shrunk = False
        except Exception as exc:
            if rec.last_failure is None:   # not a failing example: a bug of the campaign itself
                raise
            shrunk = isinstance(exc, AssertionError)   # else Hypothesis could not replay it (flaky): as found
        findings = []
        if rec.last_failure is not None:
            campaign = {"seed": cfg.seed, "chunk": k, "chunk_seed": chunk_seed(cfg.seed, k), "interrupted": interrupted}
            finding = {**rec.last_failure, "campaign": campaign, "shrunk": shrunk}
            save_finding(Path(cfg.out), finding)
            findings.append(finding["id"])
        return {"chunk": k, "planned": chunk_size(cfg, k), "examples": rec.examples, "shrink_calls": rec.shrinking,
                "states": rec.states,
                "models": len(rec.models), "worst_ratio": rec.worst, "worst_key": rec.worst_key,
                "worst_agreeing": rec.agreeing, "worst_agreeing_key": rec.agreeing_key,
                "seconds": round(time.perf_counter() - start, 3), "findings": findings, "interrupted": interrupted}
