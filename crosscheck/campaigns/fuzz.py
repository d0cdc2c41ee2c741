"""Fuzzing campaigns: random mechanisms and states, every backend compared, each failure shrunk and saved.

A campaign is a deterministic sequence of chunks k = 0, 1, 2, ... Chunk k is one Hypothesis run (seeded from the
campaign seed and k, no example database, no deadline, ``chunk_examples`` examples) of a property that draws a model
(``crosscheck.testing.models``), up to ``max_states`` admissible states, a chart and a rigid frame, evaluates every
backend at each state with the gate's comparison, chart, frame and conservation checks (``crosscheck.engine``), tells
Hypothesis the worst error/tolerance ratio (``hypothesis.target``) and fails when a state fails (a disagreement or a
backend error). Hypothesis then shrinks the failure to a minimal model and state, and the last failing call, the
minimal example, is saved as a finding; the campaign goes on with the next chunk.

A chunk's result depends only on (seed, k) and the campaign parameters, so ``--shard i/N`` (the chunks with
k % N == i) run on N machines and merged give the findings of the unsharded run, and ``--workers W`` runs chunks in
W processes (spawned, each loading the plugins by their specs; a worker process is replaced every
``CHUNKS_PER_PROCESS`` chunks, which bounds the memory the backends' per-model caches take).

A chunk generates fewer examples than it was given when it fails: Hypothesis stops generating at a chunk's first
failing example and shrinks it instead, so the rest of that chunk's examples are never drawn (a campaign of 100
examples in chunks of 10 with a failure in 8 chunks generated 56). The report and the command's summary state the
examples generated against those asked and account for every one not generated (:func:`account`: a chunk that ended
at its failure, an interrupted chunk, a chunk not run yet). Findings are grouped by signature (:func:`signature`: the
failing checks, the outlier, the backends in error and the shrunk mechanism's joint types and constraint kinds), since
one bug is typically found again by many chunks.

The campaign directory holds ``campaign.json`` (the parameters; a run in a directory with the same parameters
resumes, skipping the chunks already logged and not interrupted), ``chunks.jsonl`` (one line per chunk, appended as
each ends), ``findings/ID.json`` (written atomically as soon as a chunk ends with a failure, or is interrupted with
one in hand) and ``report.md`` (written at the end, also after an interruption). A finding's ID hashes the model
digest, the state and the failing check keys, so the same failure found by a shard and by the unsharded run has the
same ID. Files are written like any other (their mode follows the umask).

Interruptions and crashes. Interrupting a campaign by any signal at any time and resuming it (the same command
again) gives the same findings as an uninterrupted run:

- SIGINT or SIGTERM, to the campaign's process alone or to its whole process group, is an orderly stop: no chunk
  starts any more, every chunk in flight is interrupted (the parent sets a flag each worker watches, so a signal
  to the parent alone reaches them), saves the failure it holds (shrunk or not, marked ``interrupted``) and is
  logged as interrupted; the chunks get ``INTERRUPT_GRACE`` seconds for that. The report is written, the run recorded
  as interrupted (the command exits 130). A signal never breaks a save or a log append: only a chunk's Hypothesis
  run is broken into, once; otherwise the signal is noted and acted on at the next example or chunk.
- SIGKILL of the campaign or of a worker loses nothing already logged or saved: files are replaced atomically,
  the chunk log is append-only and a torn last line (a crash mid-append) is ignored, and dropped at the next append;
  workers notice their parent is gone and exit at once. A worker that dies (SIGKILL, the OOM killer) stops the
  campaign in the same orderly way, with an error naming its chunk. Corrupt files give errors naming them.
- An interrupted chunk runs again on resume; its run to the end replaces the failure the interrupted run saved: a
  saved copy of a finding from a chunk that ended takes precedence over one from an interrupted chunk, and a finding
  of an interrupted chunk that no chunk of the log lists any more is deleted.
- One run at a time per campaign directory: a run (and ``merge`` into its ``--out``) holds a lock on ``DIR/.lock``,
  which the OS releases when the process ends however it ends; a second run is refused, naming the first's pid.
"""

from __future__ import annotations

import contextlib
import dataclasses
import fcntl
import hashlib
import itertools
import json
import math
import multiprocessing
import os
import queue as queues
import secrets
import shlex
import shutil
import signal
import sys
import tempfile
import threading
import time
import traceback
from dataclasses import dataclass, field
from pathlib import Path
from typing import Callable, Iterable, Iterator, Sequence

import numpy as np
from hypothesis import HealthCheck, Phase, Verbosity, given, settings, target
from hypothesis import seed as hypothesis_seed
from hypothesis import strategies as st

from cases.model import Model
from cases.serialize import model_from_dict, model_to_dict
from crosscheck import backends, testing
from crosscheck.checks import charts, frames
from crosscheck.engine import evaluation
from crosscheck.engine import progress
from crosscheck.engine import workers as worker_processes
from crosscheck.engine.outcomes import StateOutcome
from crosscheck.core.sampling import State

DEFAULT_DIR = "crosscheck-out/fuzz"
#: Examples of a campaign given neither a number of examples nor of minutes (the command line's default).
DEFAULT_EXAMPLES = 100
#: ``--constraints`` words -> ``FuzzConfig.constraints`` (``crosscheck.testing.models``).
CONSTRAINT_CHOICES = {"never": False, "sometimes": None, "always": True}
#: Examples per chunk: small enough that a chunk ends (and is logged) every few tens of seconds.
CHUNK_EXAMPLES = 10
#: Test calls a chunk may spend shrinking after its first failure; then the smallest failure so far is saved.
SHRINK_CALLS = 300
#: Chunks a worker process runs before it is replaced (the backends cache compiled code per model).
CHUNKS_PER_PROCESS = 4
#: Seconds the campaign waits, after an interruption, for the chunks in flight to save what they hold and report
#: (they stop within a fraction of a second unless a backend is stuck in compiled code).
INTERRUPT_GRACE = 5.0
#: Seconds between a worker's checks of the stop flag and of its parent; between the pool loop's checks.
POLL = 0.1
#: Seconds a chunk's result may take to arrive after its worker exited before the worker counts as lost.
LOST_AFTER = 2.0
#: The parameters that make two runs parts of one campaign (merge and resume require them equal).
IDENTITY = ("seed", "chunk_examples", "max_bodies", "max_states", "constraints", "loads", "group_joints", "backends",
            "plugins", "shrink_calls", "charts", "frames", "conservation", "linearization")


class FuzzError(ValueError):
    """A campaign that cannot run or go on: bad input (a directory of another campaign or in use, a corrupt file, an
    unknown finding, incompatible shards) or a worker process lost."""


@dataclass(frozen=True)
class FuzzConfig:
    """A campaign's parameters. ``examples`` bounds the run (examples generated over all shards, in chunks of
    ``chunk_examples``), else ``minutes`` does; ``workers`` 0 runs in this process (tests, debugging).
    ``backends`` are names (``crosscheck.backends``), ``plugins`` the specs that load the plugin ones.
    ``group_joints``: the drawn trees may have spherical joints, and free joints on bodies hung from the world
    (``crosscheck.testing.models(group=True)``); ``pfaffian``: the drawn constraints may be knife edges, point
    velocities and rolling contacts too (``testing.models(pfaffian=True)``). ``loads``: the drawn models carry external
    loads (``cases.loads``): False never, True always, None sometimes (``crosscheck.testing.models(loads=...)``).
    ``charts``,
    ``frames`` and ``conservation`` turn the gate's checks on or off (the chart and frame are drawn either way)."""

    seed: int = 0
    examples: int | None = None
    minutes: float | None = None
    workers: int = 1
    shard: tuple[int, int] = (0, 1)
    out: str = DEFAULT_DIR
    backends: tuple[str, ...] = ()
    plugins: tuple[str, ...] = ()
    chunk_examples: int = CHUNK_EXAMPLES
    max_bodies: int = 4
    max_states: int = 4
    constraints: bool | None = None
    loads: bool | None = None
    group_joints: bool = True
    shrink_calls: int = SHRINK_CALLS
    charts: bool = True
    frames: bool = True
    conservation: bool = True
    linearization: bool = True
    pfaffian: bool = False

    def checks(self) -> dict:
        return {"charts": self.charts, "frames": self.frames, "conservation": self.conservation,
                "linearization": self.linearization}

    def identity(self) -> dict:
        """The fields that make a campaign what it is; ``pfaffian`` only when set (so a campaign without Pfaffian rows
        keeps the identity it had before they existed)."""
        ident = {key: _jsonable(getattr(self, key)) for key in IDENTITY}
        return {**ident, "pfaffian": True} if self.pfaffian else ident


def config(**kwargs) -> FuzzConfig:
    """A checked :class:`FuzzConfig`; the backends default to every one in ``crosscheck.backends``."""
    cfg = FuzzConfig(**kwargs)
    problems = []
    if (cfg.examples is None) == (cfg.minutes is None):
        problems.append("give either a number of examples or of minutes")
    if cfg.examples is not None and cfg.examples < 1:
        problems.append(f"examples must be at least 1, got {cfg.examples}")
    if cfg.minutes is not None and not cfg.minutes > 0:
        problems.append(f"minutes must be positive, got {cfg.minutes}")
    index, count = cfg.shard
    if not (count >= 1 and 0 <= index < count):
        problems.append(f"shard {index}/{count}: give i/N with 0 <= i < N")
    for key in ("workers", "chunk_examples", "max_bodies", "max_states", "shrink_calls"):
        if getattr(cfg, key) < (0 if key in ("workers", "shrink_calls") else 1):
            problems.append(f"{key} is {getattr(cfg, key)}")
    if cfg.constraints is True and cfg.max_bodies < 2:
        problems.append("constrained models need max_bodies >= 2")
    if problems:
        raise FuzzError("fuzz campaign: " + "; ".join(problems))
    names = tuple(cfg.backends) or tuple(backends.names())
    for name in names:
        backends.get(name)  # an unknown name raises, listing the valid ones
    return dataclasses.replace(cfg, backends=names, plugins=tuple(cfg.plugins))


def _jsonable(value):
    return list(value) if isinstance(value, tuple) else value


def chunk_seed(seed: int, k: int) -> int:
    """The Hypothesis seed of chunk ``k`` of the campaign with ``seed``."""
    return int.from_bytes(hashlib.sha256(f"crosscheck-fuzz/{seed}/{k}".encode()).digest()[:8], "big")


def planned_chunks(cfg: FuzzConfig) -> Iterator[int]:
    """This shard's chunks in order (all of them for an examples-bounded campaign; endless for a timed one)."""
    index, count = cfg.shard
    ks = range(math.ceil(cfg.examples / cfg.chunk_examples)) if cfg.examples else itertools.count()
    return (k for k in ks if k % count == index)


def chunk_size(cfg: FuzzConfig, k: int) -> int:
    """Examples of chunk ``k``: ``chunk_examples``, or what is left of the campaign's examples."""
    if cfg.examples is None:
        return cfg.chunk_examples
    return min(cfg.chunk_examples, cfg.examples - k * cfg.chunk_examples)


# ------------------------------------------------------------------------------------------------ interrupts


@dataclass
class _Interrupts:
    """How this process takes SIGINT and SIGTERM (module doc): ``requested`` once one came; ``phase`` is ``"idle"``
    (no chunk running here), ``"chunk"`` (a chunk setting up or saving) or ``"test"`` (its Hypothesis run);
    ``worker`` in a pool worker process, ``stop`` there the campaign's stop flag (:func:`_watch`)."""

    requested: bool = False
    phase: str = "idle"
    worker: bool = False
    stop: object = None

    def on_signal(self, signum: int, frame) -> None:
        """The first signal during a chunk's Hypothesis run raises KeyboardInterrupt there (the chunk saves the
        failure in hand); any other only sets ``requested``, which the property and the loops poll. In a worker's
        chunk, SIGTERM once an interrupt is under way or once the campaign's ``stop`` flag is set ends the process:
        that is how the pool stops its workers, and a worker must not outlive it."""
        first, self.requested = not self.requested, True
        if self.worker and signum == signal.SIGTERM and (not first or self.stop.value):
            raise SystemExit(128 + signum)
        if self.phase == "test" and first:
            raise KeyboardInterrupt

    def poll(self) -> None:
        """Called at each example: an interrupt noted outside the Hypothesis run stops the chunk now."""
        if self.requested:
            raise KeyboardInterrupt

    @contextlib.contextmanager
    def during(self, phase: str) -> Iterator[None]:
        """In ``phase``. The KeyboardInterrupt :meth:`on_signal` raises can land in code that cannot raise (a garbage
        collector callback of Hypothesis's), which Python reports as "Exception ignored" with a traceback: that
        report is dropped here, since the interrupt is noted (``requested``) and the next example stops the chunk."""
        before, self.phase = self.phase, phase
        hook = sys.unraisablehook

        def quiet(unraisable) -> None:
            if not (self.requested and issubclass(unraisable.exc_type, KeyboardInterrupt)):
                hook(unraisable)

        sys.unraisablehook = quiet
        try:
            yield
        finally:
            self.phase = before
            sys.unraisablehook = hook

    @contextlib.contextmanager
    def chunk(self) -> Iterator[None]:
        """A chunk runs here. A worker takes SIGTERM by :meth:`on_signal` only meanwhile; idle, the default action
        ends it at once. (A Python handler runs in the main thread, and a signal the kernel hands to another thread
        does not wake the main thread from a blocking wait: an idle worker waiting for a task would outlive the
        pool's SIGTERM.)"""
        if self.worker:
            signal.signal(signal.SIGTERM, self.on_signal)
        try:
            with self.during("chunk"):
                yield
        finally:
            if self.worker:
                signal.signal(signal.SIGTERM, signal.SIG_DFL)


_INTERRUPTS = _Interrupts()
_SIGNALS = (signal.SIGINT, signal.SIGTERM)


@contextlib.contextmanager
def _signals_handled() -> Iterator[None]:
    """SIGINT and SIGTERM taken by :data:`_INTERRUPTS` while in the block (in the main thread; elsewhere Python
    cannot set handlers), the previous handlers restored after."""
    _INTERRUPTS.requested = False
    if threading.current_thread() is not threading.main_thread():
        yield
        return
    previous = {signum: signal.signal(signum, _INTERRUPTS.on_signal) for signum in _SIGNALS}
    try:
        yield
    finally:
        for signum, handler in previous.items():
            signal.signal(signum, handler)
        _INTERRUPTS.requested = False


def _watch(stop, parent: int, main_thread: int) -> None:
    """A worker's watcher thread: the campaign's stop flag interrupts the worker's main thread (as SIGINT would);
    the death of the parent ends the worker at once (a SIGKILLed campaign leaves no worker writing into its
    directory; the chunk runs again on resume). The flag is a lock-free shared byte: a worker killed while it held a
    lock (a multiprocessing Event's) would block every other process that takes it."""
    while not stop.value:
        if os.getppid() != parent:
            os._exit(1)
        time.sleep(POLL)
    signal.pthread_kill(main_thread, signal.SIGINT)
    while os.getppid() == parent:
        time.sleep(POLL)
    os._exit(1)


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
    of the harness itself is a finding too."""
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
        _INTERRUPTS.poll()
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
    ``__main__``): a spawned worker and a test process that had imported ``crosscheck.campaigns.stability`` drew different
    examples from one seed. A campaign's draws must depend on its seed alone, so during a chunk that pool is empty,
    and so is the cache of constants Hypothesis drew from it before (filled by any earlier property test in the
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
    with _INTERRUPTS.chunk():
        chosen = [backends.get(name) for name in cfg.backends]
        rec = _Recorder(cfg.shrink_calls, progress)
        test = settings(max_examples=chunk_size(cfg, k), database=None, deadline=None, derandomize=False,
                        phases=(Phase.generate, Phase.target, Phase.shrink), report_multiple_bugs=False,
                        suppress_health_check=list(HealthCheck), verbosity=Verbosity.quiet)(_property(cfg, chosen, rec))
        test = hypothesis_seed(chunk_seed(cfg.seed, k))(test)
        start, interrupted, shrunk = time.perf_counter(), False, True
        try:
            with np.errstate(all="ignore"), _no_local_constants(), _INTERRUPTS.during("test"):  # NaN, inf reported
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


# ------------------------------------------------------------------------------------------------ storage


def _write_atomic(path: Path, text: str) -> None:
    """Replace ``path`` by a file holding ``text`` in one step (a reader sees the old file or the new one, a crash
    leaves at worst a ``.tmp`` file beside it); created with mode 0o666 less the umask, like any file."""
    path.parent.mkdir(parents=True, exist_ok=True)
    tmp = path.with_name(f".{path.name}.{os.getpid()}.{secrets.token_hex(4)}.tmp")
    try:
        with open(os.open(tmp, os.O_WRONLY | os.O_CREAT | os.O_EXCL, 0o666), "w") as fh:
            fh.write(text)
        os.replace(tmp, path)
    except BaseException:
        tmp.unlink(missing_ok=True)
        raise


@contextlib.contextmanager
def _locked(out: Path) -> Iterator[None]:
    """The campaign directory ``out``, created if need be, locked for this run while in the block (``DIR/.lock``,
    ``fcntl.flock``, holding the pid of the run; the OS releases the lock when the process ends however it ends)."""
    _campaign_dir(out)
    try:
        fd = os.open(out / ".lock", os.O_RDWR | os.O_CREAT, 0o666)
    except OSError as exc:
        raise FuzzError(f"cannot write in campaign directory {out}: {exc.strerror or exc}") from None
    try:
        try:
            fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
        except BlockingIOError:
            holder = os.pread(fd, 32, 0).decode(errors="replace").strip() or "unknown"
            raise FuzzError(f"campaign directory {out} is in use by another run (pid {holder}); wait for it or give "
                            "another --out") from None
        os.ftruncate(fd, 0)
        os.pwrite(fd, f"{os.getpid()}\n".encode(), 0)
        yield
    finally:
        os.close(fd)


def _campaign_dir(out: Path) -> None:
    """Create ``out`` (and its parents); :class:`FuzzError` if it is a file or cannot be created."""
    if out.exists() and not out.is_dir():
        raise FuzzError(f"--out {out} is a file, not a directory")
    try:
        out.mkdir(parents=True, exist_ok=True)
    except OSError as exc:
        raise FuzzError(f"cannot create campaign directory {out}: {exc.strerror or exc}") from None


#: The keys of a chunk's log record and of a saved finding (:func:`run_chunk`).
CHUNK_KEYS = ("chunk", "examples", "shrink_calls", "states", "models", "worst_ratio", "worst_key", "worst_agreeing",
              "worst_agreeing_key", "seconds", "findings", "interrupted")
FINDING_KEYS = ("id", "model", "state", "chart", "frame", "checks", "backends", "failing", "errors", "worst_ratio",
                "campaign", "shrunk")


def _parsed(text: str | bytes, keys: Sequence[str]) -> dict:
    """The JSON object ``text`` with every one of ``keys``; ValueError saying what is wrong otherwise."""
    value = json.loads(text)
    if not isinstance(value, dict):
        raise ValueError(f"a JSON {type(value).__name__}, not an object")
    missing = [key for key in keys if key not in value]
    if missing:
        raise ValueError(f"no {', '.join(missing)}")
    return value


def _read_finding(path: Path) -> dict:
    """The finding saved in ``path``; :class:`FuzzError` naming the file if it is not one."""
    try:
        finding = _parsed(path.read_bytes(), FINDING_KEYS)
        if not isinstance(finding["campaign"], dict) or "chunk" not in finding["campaign"]:
            raise ValueError("no campaign chunk")
    except ValueError as exc:
        raise FuzzError(f"{path} is not a finding file ({exc}); delete it (to find it again, delete as well the lines "
                        f"of chunks.jsonl that list {path.stem}, then resume)") from None
    return finding


def _precedence(finding: dict) -> tuple[bool, int]:
    """Which saved copy of a finding is kept, lowest first: one from a chunk that ran to its end before one from an
    interrupted chunk (perhaps not shrunk), then the one of the lowest chunk."""
    return bool(finding["campaign"].get("interrupted", False)), finding["campaign"]["chunk"]


def save_finding(out: Path, finding: dict) -> bool:
    """Write ``findings/ID.json`` atomically unless the copy there takes precedence (:func:`_precedence`: so the
    stored copy does not depend on which shard or worker finished first, nor on interruptions; a chunk run again
    replaces its earlier copy). Returns whether it was written."""
    path = out / "findings" / f"{finding['id']}.json"
    if path.exists() and _precedence(_read_finding(path)) < _precedence(finding):
        return False
    _write_atomic(path, json.dumps(finding, indent=1))
    return True


def load_findings(out: Path) -> list[dict]:
    """The saved findings, ordered by chunk then ID."""
    found = [_read_finding(p) for p in sorted((out / "findings").glob("*.json"))]
    return sorted(found, key=lambda f: (f["campaign"]["chunk"], f["id"]))


def _prune(out: Path) -> None:
    """Delete what an interruption or a crash left behind: temporary files, and the findings saved by interrupted
    chunks that no chunk of the log lists any more (their chunk ran again to its end without reproducing them)."""
    for tmp in [*out.glob("*.tmp"), *(out / "findings").glob("*.tmp")]:
        tmp.unlink(missing_ok=True)
    listed = {i for r in load_chunks(out) for i in r["findings"]}
    for path in sorted((out / "findings").glob("*.json")):
        finding = _read_finding(path)
        if finding["campaign"].get("interrupted") and finding["id"] not in listed:
            path.unlink()


def _final(records: Iterable[dict]) -> list[dict]:
    """One record per chunk, ordered by chunk: the last one that ran to its end, else the last one."""
    final: dict[int, dict] = {}
    for r in records:
        kept = final.get(r["chunk"])
        if kept is None or kept["interrupted"] or not r["interrupted"]:
            final[r["chunk"]] = r
    return sorted(final.values(), key=lambda r: r["chunk"])


def load_chunks(out: Path) -> list[dict]:
    """The chunk log, one record per chunk (:func:`_final`), ordered by chunk. A torn last line (a crash while it
    was appended) is skipped; any other line that is not a record is corruption: :class:`FuzzError` naming it."""
    path = out / "chunks.jsonl"
    lines = path.read_bytes().split(b"\n") if path.exists() else []
    records = []
    for number, line in enumerate(lines, 1):
        if not line.strip():
            continue
        try:
            records.append(_parsed(line, CHUNK_KEYS))
        except ValueError as exc:
            if number == len(lines):   # no newline after it: torn; the next append drops it
                continue
            raise FuzzError(f"{path} line {number} is not a chunk record ({exc}): the log is corrupt; delete that "
                            "line (its chunk runs again on resume)") from None
    return _final(records)


def _append_chunk(out: Path, record: dict) -> None:
    """Append ``record`` to the chunk log, after dropping a torn last line (or ending a whole one)."""
    with open(out / "chunks.jsonl", "a+b") as fh:
        size = fh.seek(0, os.SEEK_END)
        if size and os.pread(fh.fileno(), 1, size - 1) != b"\n":
            fh.seek(0)
            text = fh.read()
            head = text[:text.rfind(b"\n") + 1]
            try:
                _parsed(text[len(head):], CHUNK_KEYS)
                fh.write(b"\n")
            except ValueError:
                fh.truncate(len(head))
        fh.write((json.dumps(record) + "\n").encode())


def load_campaign(out: Path) -> dict | None:
    """``campaign.json`` of ``out`` (None if there is none); :class:`FuzzError` if it is not a campaign file."""
    path = out / "campaign.json"
    if not path.exists():
        return None
    try:
        campaign = _parsed(path.read_bytes(), ("identity", "runs"))
        if not isinstance(campaign["identity"], dict) or not isinstance(campaign["runs"], list):
            raise ValueError("identity is not an object or runs not a list")
    except ValueError as exc:
        raise FuzzError(f"{path} is not a campaign file: {exc}; remove it or give another --out") from None
    return campaign


def _prepare(cfg: FuzzConfig) -> dict:
    """Create or resume the campaign directory (locked by the caller): ``campaign.json`` must hold the same
    parameters."""
    out = Path(cfg.out)
    found = load_campaign(out)
    if found is not None and found["identity"] != cfg.identity():
        diff = {k: (found["identity"].get(k), v) for k, v in cfg.identity().items() if found["identity"].get(k) != v}
        raise FuzzError(f"{out} holds another campaign (parameters differ: "
                        + ", ".join(f"{k} {a!r} there, {b!r} here" for k, (a, b) in diff.items())
                        + "); give another --out or remove it")
    campaign = found or {"identity": cfg.identity(), "runs": []}
    _write_atomic(out / "campaign.json", json.dumps(campaign, indent=1))
    return campaign


def _record_run(cfg: FuzzConfig, campaign: dict, wall: float, interrupted: bool) -> None:
    run = {"shard": f"{cfg.shard[0]}/{cfg.shard[1]}", "workers": cfg.workers, "examples": cfg.examples,
           "minutes": cfg.minutes, "wall_seconds": round(wall, 3), "interrupted": interrupted}
    campaign["runs"].append(run)
    _write_atomic(Path(cfg.out) / "campaign.json", json.dumps(campaign, indent=1))


# ------------------------------------------------------------------------------------------------ a campaign


class _Tally:
    """The campaign's counts on its progress display (``crosscheck.engine.progress``): examples (of the planned total),
    examples/s, the worst ratio, the findings, and whether examples are being generated or a failure shrunk."""

    def __init__(self, display: progress.Display):
        self.display = display
        self.start = time.perf_counter()
        self.examples, self.worst, self.findings = 0, 0.0, 0

    def example(self, examples: int, states: int, ratio: float) -> None:
        """A property call: a generated example (``examples`` 1) or a shrinking call (0)."""
        self.examples += examples
        self.worst = max(self.worst, ratio)
        rate = self.examples / max(time.perf_counter() - self.start, 1e-9)
        self.display.advance(examples, rate=rate, worst=self.worst)
        self.display.doing("generating examples" if examples else "shrinking a failure")

    def chunk(self, record: dict) -> None:
        self.findings += len(record["findings"])
        self.display.update(findings=self.findings)


def _display(total: int | None, quiet: bool) -> progress.Display:
    """The campaign's progress display: examples of ``total``, examples/s, worst ratio, findings."""
    return progress.Display("fuzz", "examples", total, quiet=quiet,
                            extra=("{task.fields[rate]:.2f}/s", "worst {task.fields[worst]:.3g}",
                                   "{task.fields[findings]} findings"), rate=0.0, worst=0.0, findings=0)


def _until(deadline: float | None, ks: Iterable[int]) -> Iterator[int]:
    for k in ks:
        if deadline is not None and time.monotonic() > deadline:
            return
        yield k


def _in_process(cfg: FuzzConfig, plan: Iterator[int], cache: str, tally: _Tally) -> Iterator[dict]:
    """Chunks one after another in this process (the derivation cache pointed at ``cache`` meanwhile), until one is
    interrupted or an interrupt is requested."""
    before = os.environ.get("CROSSCHECK_CACHE")
    os.environ["CROSSCHECK_CACHE"] = cache
    try:
        for k in plan:
            if _INTERRUPTS.requested:
                return
            record = run_chunk(cfg, k, tally.example)
            yield record
            if record["interrupted"]:
                return
    finally:
        if before is None:
            os.environ.pop("CROSSCHECK_CACHE", None)
        else:
            os.environ["CROSSCHECK_CACHE"] = before


_QUEUE = None
_LIMITS = None


def _init_worker(plugins: Sequence[str], cache: str, queue, stop, parent: int) -> None:
    """A worker process: its interrupts (module doc: SIGINT and, during a chunk, SIGTERM handled as in the campaign;
    the stop flag and the parent watched), the campaign's derivation cache, one BLAS thread, the plugins, the
    progress queue."""
    global _QUEUE, _LIMITS
    from threadpoolctl import threadpool_limits

    _INTERRUPTS.worker, _INTERRUPTS.stop, _INTERRUPTS.requested = True, stop, bool(stop.value)
    signal.signal(signal.SIGINT, _INTERRUPTS.on_signal)   # SIGTERM: see _Interrupts.chunk
    threading.Thread(target=_watch, args=(stop, parent, threading.get_ident()), daemon=True).start()
    queue.cancel_join_thread()   # exiting never waits on the queue (whose lock a killed worker may hold)
    os.environ["CROSSCHECK_CACHE"] = cache
    _LIMITS = threadpool_limits(limits=1, user_api="blas")
    backends.load_plugins(plugins)
    _QUEUE = queue


def _worker_chunk(cfg: FuzzConfig, k: int) -> dict:
    """Chunk ``k`` in a worker: the worker's pid to the queue first (the pool loop watches that it lives), then the
    chunk's progress."""
    _QUEUE.put(("start", k, os.getpid()))
    return run_chunk(cfg, k, lambda examples, states, ratio: _QUEUE.put(("example", examples, states, ratio)))


class _Flight:
    """The chunks in flight in a worker pool: their pending results, the process running each (from the workers'
    ``start`` messages), their progress counted by ``tally``."""

    def __init__(self, cfg: FuzzConfig, pool, queue, tally: _Tally):
        self.cfg, self.pool, self.queue, self.tally = cfg, pool, queue, tally
        self.pending: dict = {}
        self.pids: dict[int, int] = {}

    def start(self, ks: Iterable[int]) -> None:
        for k in ks:
            self.pending[k] = self.pool.apply_async(_worker_chunk, (self.cfg, k))

    def _drain(self) -> None:
        while True:
            try:
                kind, *message = self.queue.get_nowait()
            except queues.Empty:
                return
            if kind == "start":
                self.pids[message[0]] = message[1]
            else:
                self.tally.example(*message)

    def ended(self) -> list[dict]:
        """The records of the chunks that ended since the last call."""
        self._drain()
        ready = [k for k, result in self.pending.items() if result.ready()]
        for k in ready:
            self.pids.pop(k, None)
        return [self.pending.pop(k).get() for k in ready]

    def lost(self) -> tuple[int, int] | None:
        """(chunk, pid) of a chunk whose worker process is gone without returning it (killed), else None; the chunk
        is no longer waited for."""
        alive = {p.pid for p in multiprocessing.active_children()}
        for k, pid in self.pids.items():
            if pid not in alive:
                self.pending[k].wait(LOST_AFTER)   # its result may still be on its way
                if not self.pending[k].ready():
                    del self.pending[k], self.pids[k]
                    return k, pid
        return None

    def wait(self) -> tuple[list[dict], tuple[int, int] | None]:
        """Until a chunk ends, an interrupt is requested or a worker is lost: the records of the chunks that ended
        and the lost (chunk, pid)."""
        while True:
            done, lost = self.ended(), self.lost()
            if done or lost or _INTERRUPTS.requested:
                return done, lost
            time.sleep(POLL)

    def grace(self) -> Iterator[dict]:
        """The records of the chunks in flight that end within ``INTERRUPT_GRACE`` seconds."""
        deadline = time.monotonic() + INTERRUPT_GRACE
        while self.pending and time.monotonic() < deadline:
            yield from self.ended()
            time.sleep(POLL / 2)


def _in_pool(cfg: FuzzConfig, plan: Iterator[int], cache: str, tally: _Tally) -> Iterator[dict]:
    """Chunks in ``cfg.workers`` spawned processes, at most one in flight per worker, records in completion order.
    On an interrupt (of this process, or a chunk reporting one) or a lost worker, no chunk starts any more and the
    stop flag interrupts the chunks in flight, which get ``INTERRUPT_GRACE`` seconds to save what they hold and
    report; a lost worker then raises :class:`FuzzError`."""
    ctx = multiprocessing.get_context("spawn")
    queue, stop = ctx.Queue(), ctx.RawValue("b", 0)
    with worker_processes.spawning():   # its workers ignore Ctrl-C until their initializer handles it
        pool = ctx.Pool(cfg.workers, initializer=_init_worker,
                        initargs=(cfg.plugins, cache, queue, stop, os.getpid()), maxtasksperchild=CHUNKS_PER_PROCESS)
        flight = _Flight(cfg, pool, queue, tally)
        try:
            flight.start(itertools.islice(plan, cfg.workers))
            while flight.pending:
                done, lost = flight.wait()
                yield from done
                if lost or _INTERRUPTS.requested or any(record["interrupted"] for record in done):
                    stop.value = 1
                    yield from flight.grace()
                    if lost:
                        raise FuzzError(f"the worker process running chunk {lost[0]} (pid {lost[1]}) died; the "
                                        "chunks in flight were stopped and the report written: run the same command "
                                        f"again to resume (chunk {lost[0]} runs again)")
                    return
                flight.start(itertools.islice(plan, len(done)))
        finally:
            stop.value = 1   # first: a worker takes the pool's SIGTERM after it as the end (_Interrupts.on_signal)
            pool.terminate()
            pool.join()


@dataclass
class CampaignResult:
    out: Path
    chunks: list[dict]
    findings: list[dict]
    interrupted: bool


def run_campaign(cfg: FuzzConfig, command: str = "", quiet: bool = False) -> CampaignResult:
    """Run the campaign ``cfg`` (from :func:`config`) in its directory, locked for the run: chunks logged as they
    end, findings saved as they are found, the report written at the end, also after an interruption (SIGINT or
    SIGTERM: ``interrupted`` is then set) or an error (re-raised after). Module doc: what survives what. The
    progress display shows on a terminal's stderr, unless ``quiet``."""
    out = Path(cfg.out)
    with _locked(out), _signals_handled():
        campaign = _prepare(cfg)
        _prune(out)
        logged = {r["chunk"] for r in load_chunks(out) if not r["interrupted"]}   # an interrupted chunk runs again
        deadline = None if cfg.minutes is None else time.monotonic() + 60.0 * cfg.minutes
        plan = _until(deadline, (k for k in planned_chunks(cfg) if k not in logged))
        total = None if cfg.examples is None else sum(chunk_size(cfg, k) for k in planned_chunks(cfg)
                                                      if k not in logged)
        cache = tempfile.mkdtemp(prefix="crosscheck-fuzz-cache-")
        start, interrupted, ended = time.perf_counter(), False, False
        runner = _in_process if cfg.workers == 0 else _in_pool
        try:
            with _display(total, quiet) as display:
                tally = _Tally(display)
                with contextlib.closing(runner(cfg, plan, cache, tally)) as records:
                    for record in records:
                        _append_chunk(out, record)
                        tally.chunk(record)
                        interrupted |= record["interrupted"]
            ended = True
        except KeyboardInterrupt:
            pass
        finally:
            interrupted = interrupted or not ended or _INTERRUPTS.requested
            shutil.rmtree(cache, ignore_errors=True)
            _prune(out)
            _record_run(cfg, campaign, time.perf_counter() - start, interrupted)
            write_report(out, command)
        return CampaignResult(out, load_chunks(out), load_findings(out), interrupted)


# ------------------------------------------------------------------------------------------------ replay, merge


def find(out: Path, finding: str) -> dict:
    """The saved finding with this ID (or unique ID prefix); :class:`FuzzError` listing the valid IDs otherwise."""
    ids = sorted(p.stem for p in (out / "findings").glob("*.json"))
    matches = [i for i in ids if i.startswith(finding)] if finding else []
    if len(matches) != 1:
        what = "matches several findings" if matches else "is not a finding"
        raise FuzzError(f"'{finding}' {what} in {out}; valid IDs: {', '.join(ids) or 'none (no findings saved)'}")
    return _read_finding(out / "findings" / f"{matches[0]}.json")


def scene_of(finding: dict) -> tuple[Model, State, charts.Chart, frames.Frame]:
    """The model, state, chart and frame a finding was found at, rebuilt exactly."""
    model = model_from_dict(finding["model"])
    s = finding["state"]
    state = State(0, tuple(s["q"]), tuple(s["qd"]), tuple(s["u"]))
    chart = charts.get(finding["chart"]["name"], model, finding["chart"]["seed"])
    f = finding["frame"]
    frame = frames.Frame(f["name"], np.array(f["rotation"]), np.array(f["translation"]))
    return model, state, chart, frame


def replay(finding: dict, names: Sequence[str] | None = None) -> StateOutcome:
    """Evaluate the finding's state again, as the campaign did, with its backends (or ``names``)."""
    model, state, chart, frame = scene_of(finding)
    chosen = [backends.get(name) for name in (names or finding["backends"])]
    with np.errstate(all="ignore"):
        return evaluate(model, state, chart, frame, chosen, finding["checks"])


def merge(dirs: Sequence[Path], out: Path, command: str = "") -> CampaignResult:
    """Combine campaign directories (shards) into ``out`` (locked meanwhile, like a run's): the same parameters
    required, findings de-duplicated by ID, chunk logs combined (a chunk in several keeps one record,
    :func:`_final`), runs listed; the report written."""
    campaigns = []
    for d in dirs:
        found = load_campaign(Path(d))
        if found is None:
            raise FuzzError(f"{d} is not a campaign directory (no campaign.json)")
        campaigns.append(found)
    for d, c in zip(dirs[1:], campaigns[1:]):
        if c["identity"] != campaigns[0]["identity"]:
            raise FuzzError(f"cannot merge {d} with {dirs[0]}: the campaigns' parameters differ "
                            f"({c['identity']} vs {campaigns[0]['identity']})")
    with _locked(out):
        existing = load_campaign(out)
        if existing is not None and existing["identity"] != campaigns[0]["identity"]:
            raise FuzzError(f"{out} holds another campaign; give another --out")
        runs = (existing or {"runs": []})["runs"] + [r for c in campaigns for r in c["runs"]]
        _write_atomic(out / "campaign.json", json.dumps({"identity": campaigns[0]["identity"], "runs": runs}, indent=1))
        records = _final(r for d in [out, *map(Path, dirs)] for r in load_chunks(d))
        _write_atomic(out / "chunks.jsonl", "".join(json.dumps(r) + "\n" for r in records))
        for d in dirs:
            for finding in load_findings(Path(d)):
                save_finding(out, finding)
        _prune(out)
        write_report(out, command)
        return CampaignResult(out, load_chunks(out), load_findings(out), False)


# ------------------------------------------------------------------------------------------------ report


def _vec(values) -> str:
    """A vector (or a matrix, row after row) with 6 significant digits."""
    return "[" + ", ".join(f"{float(x):.6g}" for x in np.ravel(values)) + "]"


def describe_model(d: dict) -> list[str]:
    """A serialized model in a few lines: each body and joint, gravity, B, task point, constraints."""
    lines = []
    for b in d["bodies"]:
        inertia = "point mass" if not any(map(any, b["inertia"])) else f"inertia {b['inertia']}"
        lines.append(f"  - `{b['name']}`: {b['joint']} about {_vec(b['axis'])} on {b['parent'] or 'the world'} "
                     f"at {_vec(b['translation'])}, rotation {b['rotation']}; mass {b['mass']:.6g} kg, "
                     f"COM {_vec(b['com'])}, {inertia}")
    B = np.array(d["input_map"])
    lines.append(f"  - gravity {_vec(d['gravity'])}; B "
                 + ("identity" if B.shape[0] == B.shape[1] and np.array_equal(B, np.eye(len(B))) else str(B.tolist())))
    for tp in d["task_points"]:
        lines.append(f"  - task point `{tp['name']}` on `{tp['body']}` at {_vec(tp['offset'])}, "
                     f"directions {tp['directions']}")
    for c in d["constraints"]:
        fields = ", ".join(f"{k} {v}" for k, v in c.items() if k not in ("type", "name"))
        lines.append(f"  - constraint `{c['name']}`: {c['type']} ({fields})")
    return lines


def replay_command(finding_id: str, out: Path, plugins: Sequence[str]) -> str:
    """The command that evaluates a finding again: ``crosscheck replay ID --dir OUT`` with a ``--plugin`` flag for
    each plugin the campaign loaded by spec (its findings name those backends; entry points load themselves)."""
    return f"crosscheck replay {finding_id} --dir {out}" + "".join(f" --plugin {shlex.quote(p)}" for p in plugins)


def campaign_plugins(out: Path) -> list[str]:
    """The plugin specs of the campaign in ``out`` (its identity), none for a directory without one."""
    return list((load_campaign(out) or {"identity": {}})["identity"].get("plugins", []))


def _finding_section(f: dict, out: Path, plugins: Sequence[str] = ()) -> list[str]:
    s, chart, frame = f["state"], f["chart"], f["frame"]
    camp = f["campaign"]
    how = "shrunk" if f["shrunk"] else "NOT fully shrunk (" + (
        "interrupted: resuming the campaign runs its chunk again" if camp.get("interrupted")
        else "interrupted or shrinking budget spent") + ")"
    lines = [f"### Finding `{f['id']}`", "",
             f"Chunk {camp['chunk']} (campaign seed {camp['seed']}), {how}; worst error/tolerance "
             f"{f['worst_ratio']:.3g}.", "",
             f"- model ({len(f['model']['bodies'])} bodies, {len(f['model']['constraints'])} constraints):",
             *describe_model(f["model"]),
             f"- state: q = {s['q']}, qd = {s['qd']}, u = {s['u']}",
             f"- chart `{chart['name']}` (seed {chart['seed']}); frame `{frame['name']}`: rotation "
             f"{frame['rotation']}, translation {frame['translation']}",
             f"- backends: {', '.join(f['backends'])}; checks: "
             + ", ".join(["comparison"] + [name for name, on in f["checks"].items() if on]),
             f"- reproduce: `{replay_command(f['id'], out, plugins)}`", ""]
    if f["failing"]:
        lines += ["| check | error/tolerance | tolerance | outlier |", "|---|---|---|---|"]
        lines += [f"| {c['key']} | {c['worst_ratio']:.3g} | {c['tolerance']:.3g} | {c['outlier'] or '-'} |"
                  for c in f["failing"]]
        lines += ["", "Values:", "", "```"]
        for c in f["failing"]:
            lines.append(f"{c['key']}:")
            lines += [f"  {voter}: {_vec(v)}" for voter, v in c["values"].items()]
        lines += ["```", ""]
    if f["errors"]:
        lines += ["Errors:", "", "```"] + [f"{name}: {message}" for name, message in f["errors"].items()] + ["```", ""]
    return lines


#: Why examples of a campaign were not generated (:func:`account`), in report order.
FAILED = "in chunks that ended at their first failure (Hypothesis shrinks it instead of generating the rest)"
INTERRUPTED = "in interrupted chunks (they run again when the same command resumes the campaign)"
NOT_RUN = "in chunks not run yet (the run was stopped before them; the same command resumes the campaign)"
EARLY = "in chunks where Hypothesis stopped without a failure (it had nothing new to draw)"


@dataclass(frozen=True)
class Accounting:
    """The examples a campaign was asked for (``asked``; None when bounded by ``minutes``) and ``generated``, and the
    ones not generated, as ``(reason, chunks, examples)`` per reason (:data:`FAILED`, :data:`INTERRUPTED`,
    :data:`NOT_RUN`, :data:`EARLY`) with at least one example."""

    asked: int | None
    minutes: float | None
    generated: int
    missing: tuple[tuple[str, int, int], ...]

    def text(self) -> str:
        """``56 of 100 asked generated`` and what became of the rest, or ``56 generated (asked: 5 minutes)``."""
        if self.asked is None:
            return f"{self.generated} generated" + (f" (asked: {self.minutes:g} minutes)" if self.minutes else "")
        text = f"{self.generated} of {self.asked} asked generated"
        if self.missing:
            text += "; not generated: " + "; ".join(f"{n} {why} ({chunks} chunk{'s' * (chunks != 1)})"
                                                     for why, chunks, n in self.missing)
        return text


def _asked(campaign: dict) -> tuple[int | None, float | None, list[tuple[int, int]]]:
    """The latest run's bound (examples or minutes) and every shard (i, N) run in this directory."""
    runs = campaign.get("runs", [])
    last = runs[-1] if runs else {}
    shards = sorted({tuple(int(x) for x in r["shard"].split("/")) for r in runs if "shard" in r})
    return last.get("examples"), last.get("minutes"), shards


def account(campaign: dict, chunks: Sequence[dict]) -> Accounting:
    """The campaign's examples asked, generated and not generated, and why (:class:`Accounting`): a chunk's planned
    examples are its record's ``planned`` (else the campaign's ``chunk_examples``); the chunks an examples-bounded
    campaign plans for the shards run here and that are not in the log are not run yet."""
    asked, minutes, shards = _asked(campaign)
    size = campaign.get("identity", {}).get("chunk_examples") or CHUNK_EXAMPLES
    missing = {FAILED: [0, 0], INTERRUPTED: [0, 0], NOT_RUN: [0, 0], EARLY: [0, 0]}
    for r in chunks:
        short = r.get("planned", size) - r["examples"]
        if short > 0:
            why = INTERRUPTED if r["interrupted"] else FAILED if r["findings"] else EARLY
            missing[why][0] += 1
            missing[why][1] += short
    if asked is not None:
        logged = {r["chunk"] for r in chunks}
        for k in range(math.ceil(asked / size)):
            if k not in logged and any(k % count == index for index, count in shards):
                missing[NOT_RUN][0] += 1
                missing[NOT_RUN][1] += min(size, asked - k * size)
    return Accounting(asked, minutes, sum(r["examples"] for r in chunks),
                      tuple((why, c, n) for why, (c, n) in missing.items() if n > 0))


def mechanism(d: dict) -> str:
    """A serialized model's shape: how many joints of each type, and of each constraint kind (``2 revolute,
    1 prismatic; 1 PointOnCircle``)."""
    def counted(names) -> str:
        kinds = sorted(set(names))
        return ", ".join(f"{list(names).count(kind)} {kind}" for kind in kinds)

    text = counted([b["joint"] for b in d["bodies"]]) or "no joints"
    constraints = [c["type"] for c in d["constraints"]]
    return text + (f"; {counted(constraints)}" if constraints else "")


def signature(finding: dict) -> tuple[str, str, str, str]:
    """What one bug found many times has in common (module doc): the failing checks, the outliers the vote named,
    the backends in error and the mechanism (:func:`mechanism`), each as text (``-`` for none)."""
    failing = finding["failing"]
    return (", ".join(sorted(c["key"] for c in failing)) or "-",
            ", ".join(sorted({c["outlier"] for c in failing if c["outlier"]})) or "-",
            ", ".join(sorted(finding["errors"])) or "-",
            mechanism(finding["model"]))


def group(findings: Sequence[dict]) -> list[tuple[tuple[str, str, str, str], list[dict]]]:
    """The findings by :func:`signature`, the largest group first (then by their first finding's order)."""
    groups: dict[tuple[str, str, str, str], list[dict]] = {}
    for f in findings:
        groups.setdefault(signature(f), []).append(f)
    return sorted(groups.items(), key=lambda item: -len(item[1]))


def _signature_section(findings: Sequence[dict]) -> list[str]:
    """The findings grouped by signature: one row per group with its count and IDs."""
    if not findings:
        return []
    lines = ["## Findings by signature", "",
             "Findings with the same failing checks, outlier, backend errors and mechanism (joint types and constraint "
             "kinds, after shrinking) are most likely one bug found several times.", "",
             "| findings | failing checks | outlier | backend errors | mechanism | IDs |", "|---|---|---|---|---|---|"]
    for (checks, outliers, errors, shape), members in group(findings):
        ids = ", ".join(f"`{f['id']}`" for f in members)
        lines.append(f"| {len(members)} | {checks} | {outliers} | {errors} | {shape} | {ids} |")
    return lines + [""]


def render_report(out: Path, command: str = "") -> str:
    """The campaign report (markdown): summary first, then each finding. Only the rows ``compute time``, ``wall
    time`` and ``throughput`` depend on the machine; the rest is the same for the same campaign."""
    campaign = load_campaign(out) or {"identity": {}, "runs": []}
    chunks, findings = load_chunks(out), load_findings(out)
    ident = campaign["identity"]
    total = {key: sum(r[key] for r in chunks) for key in ("examples", "shrink_calls", "states", "models")}
    seconds = sum(r["seconds"] for r in chunks)
    wall = sum(r["wall_seconds"] for r in campaign["runs"])
    worst = max(chunks, key=lambda r: r["worst_ratio"], default=None)
    where = f" (chunk {worst['chunk']}, `{worst['worst_key']}`)" if worst and worst["worst_key"] else ""
    margin = max(chunks, key=lambda r: r["worst_agreeing"], default=None)
    margin_where = f" (chunk {margin['chunk']}, `{margin['worst_agreeing_key']}`)" if margin else ""
    shards = sorted({r["shard"] for r in campaign["runs"]})
    interrupted = [r for r in chunks if r["interrupted"]]
    rate = f"{len(findings) / total['states']:.3g} per state" if total["states"] else "-"
    lines = ["# Fuzzing campaign", ""]
    if command:
        lines += [f"Command: `{command}`", ""]
    lines += [
        "## Summary", "",
        "| | |", "|---|---|",
        f"| seed | {ident.get('seed')} |",
        f"| backends | {', '.join(ident.get('backends', []))} |",
        f"| drawn | up to {ident.get('max_bodies')} bodies, up to {ident.get('max_states')} states per model, "
        f"constraints {({True: 'always', False: 'never', None: 'sometimes'})[ident.get('constraints')]}, joints "
        f"{'revolute, prismatic, spherical, free' if ident.get('group_joints', True) else 'revolute, prismatic'}, "
        "without joint limits (each coordinate over its whole range) |",
        "| checks | every quantity compared; "
        + ", ".join(name for name in ("charts", "frames", "conservation", "linearization") if ident.get(name)) + " |",
        f"| chunks | {len(chunks)} of {ident.get('chunk_examples')} examples (shards run: {', '.join(shards)}"
        + (f"; {len(interrupted)} interrupted" if interrupted else "") + ") |",
        f"| examples | {account(campaign, chunks).text()}; {total['shrink_calls']} more calls while shrinking |",
        f"| models | {total['models']} |",
        f"| states | {total['states']} |",
        f"| worst error/tolerance | {worst['worst_ratio'] if worst else 0.0:.3g}{where} |",
        f"| worst error/tolerance at states that passed | {margin['worst_agreeing'] if margin else 0.0:.3g}"
        f"{margin_where} |",
        f"| findings (disagreements and backend errors) | {len(findings)}"
        + (f", {len(group(findings))} signature(s) (below)" if findings else "") + " |",
        f"| false alarms | {len(findings)} findings on {total['states']} states ({rate}): with correct backends each "
        "finding is a false alarm of the tolerance policy unless replaying it shows a backend bug |",
        f"| compute time | {seconds:.1f} s in chunks |",
        f"| wall time | {wall:.1f} s |",
        f"| throughput | {total['examples'] / seconds if seconds else 0.0:.2f} examples/s, "
        f"{total['states'] / seconds if seconds else 0.0:.2f} states/s (per process) |", ""]
    lines += _signature_section(findings)
    lines += ["## Findings", ""]
    if not findings:
        lines += ["None: every backend agreed at every state.", ""]
    for f in findings:
        lines += _finding_section(f, out, ident.get("plugins", []))
    return "\n".join(lines)


def summary(result: CampaignResult) -> str:
    """A few lines for the terminal: what ran (the examples generated of those asked, and why fewer), what was found
    (grouped by :func:`signature`, each group with its count, IDs and one replay command), the report."""
    chunks = result.chunks
    findings = result.findings
    examples = account(load_campaign(result.out) or {}, chunks).text()
    lines = [f"{len(chunks)} chunks, examples: {examples}; {sum(r['states'] for r in chunks)} states, "
             f"{len(findings)} findings" + (f" in {len(group(findings))} signature(s)" if findings else "")
             + (" (interrupted)" if result.interrupted else "")]
    plugins = campaign_plugins(result.out)
    for (checks, outliers, errors, shape), members in group(findings):
        what = "; ".join(part for part in (f"failing {checks}" if checks != "-" else "",
                                           f"outlier {outliers}" if outliers != "-" else "",
                                           f"errors in {errors}" if errors != "-" else "", shape) if part)
        lines.append(f"  {len(members)} x {what}: {', '.join(f['id'] for f in members)}")
        lines.append(f"    {replay_command(members[0]['id'], result.out, plugins)}")
    lines.append(f"report written to {result.out / 'report.md'}")
    return "\n".join(lines)


def write_report(out: Path, command: str = "") -> Path:
    path = out / "report.md"
    _write_atomic(path, render_report(out, command))
    return path
