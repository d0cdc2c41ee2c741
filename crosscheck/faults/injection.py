"""Injected faults: how strong the gate is, measured (docs/design.md, "a check that cannot fail is a defect").

A :class:`Fault` is a realistic bug in one backend's own computation (a dropped Coriolis term, a transposed
rotation, a multiplier with the wrong sign, ...), injected by replacing one module attribute, a function or a
method, by a faulty version built from the original (``crosscheck.faults.backend_catalog`` holds the catalog). Sources
are never edited: :func:`injected` patches the attribute and restores it on exit, also on error. A fault in code whose
results a backend caches (``derived``: the Euler–Lagrange derivation, cached in an lru_cache and on disk under
``CROSSCHECK_CACHE``; the geometric backend's compiled casadi functions) runs on empty caches: a fresh temporary
``CROSSCHECK_CACHE`` directory, an empty lru_cache in place of the Euler–Lagrange one, the geometric one set aside.
On exit the temporary ones are discarded with every faulty result and the originals, which never saw the fault,
come back: no result from before the fault is served under it, and none from under it survives it.

:func:`hunt` evaluates the default gate's states (``crosscheck.engine``: every built-in case, the seeded states of
``sample_states``, the comparisons of ``evaluate`` and the chart, frame and conservation checks of ``add_checks``,
exactly as ``run_case``) round robin over the cases, state 0 of every case, then state 1, ..., under the fault,
and stops at the first failing state. It reports which comparisons and checks caught the fault, the outlier the
vote named, and the proof that the fault is real: the faulty backend's output at that state (in the joint chart,
in the gate's charts and on the state's moved scene) against its output once the fault is removed.
"""

from __future__ import annotations

import dataclasses
import functools
import importlib
import inspect
import os
import re
import statistics
import tempfile
import time
from collections import Counter
from contextlib import ExitStack, contextmanager
from dataclasses import dataclass, field
from typing import Any, Callable, Iterator, Mapping, Sequence

import numpy as np

import cases
from crosscheck import backends as backend_registry
from crosscheck.checks import charts, linearization
from crosscheck.core.compare import DISAGREE, backend_of, suspect
from crosscheck.core.sampling import sample_states, State
from crosscheck.engine import divergences
from crosscheck.engine.evaluation import CaseSetup
from crosscheck.engine.outcomes import StateOutcome
from crosscheck.engine.specs import DEFAULT_SAMPLES, CaseSpec, Checks
import formalisms
from formalisms.interface import Formalism, Unsupported

_KEBAB = re.compile(r"^[a-z0-9]+(-[a-z0-9]+)+$")


class FaultError(ValueError):
    """A fault that cannot be injected: a bad name, an unknown backend or target."""


@dataclass(frozen=True)
class Fault:
    """A named bug in one backend, injected by replacing ``target`` (``"module:attribute"``; the attribute may be a
    dotted path such as ``"Class.method"``) by ``replace(original)``.

    ``bug`` says in one sentence what is wrong, as a reviewer would describe it. ``derived`` marks a target that
    runs while a backend derives code it caches (module docstring). ``gap``, when not empty, records a known blind
    spot: why the default gate misses this fault and which check would catch it.
    """

    name: str
    backend: str
    bug: str
    target: str
    replace: Callable[[Any], Any] = field(repr=False, compare=False)
    derived: bool = False
    gap: str = ""

    def __post_init__(self):
        if not _KEBAB.match(self.name):
            raise FaultError(f"fault name '{self.name}' is not kebab-case (e.g. 'el-dropped-coriolis')")
        if self.backend not in formalisms.names():
            raise FaultError(f"fault '{self.name}': unknown backend '{self.backend}'; valid: "
                             f"{', '.join(formalisms.names())}")
        module, sep, attribute = self.target.partition(":")
        if not sep or not module or not attribute:
            raise FaultError(f"fault '{self.name}': target '{self.target}' is not 'module:attribute'")
        if self.derived and module not in _DERIVATION_CACHES:
            raise FaultError(f"fault '{self.name}' is marked derived, but '{module}' has no derivation cache; "
                             f"known: {', '.join(_DERIVATION_CACHES)}")

    @property
    def module(self) -> str:
        return self.target.partition(":")[0]


def _resolve(fault: Fault) -> tuple[Any, str, Any]:
    """``(owner, attribute name, original)`` of the fault's target (:func:`resolve`)."""
    return resolve(fault.name, fault.target)


def resolve(fault: str, target: str) -> tuple[Any, str, Any]:
    """``(owner, attribute name, original)`` of ``target`` (``"module:attribute"``, the attribute possibly dotted);
    a class attribute is read from the class's own dictionary, so the very object there is restored."""
    module, _, path = target.partition(":")
    owner: Any = importlib.import_module(module)
    *parents, name = path.split(".")
    try:
        for part in parents:
            owner = getattr(owner, part)
        original = owner.__dict__[name] if isinstance(owner, type) else getattr(owner, name)
    except (AttributeError, KeyError):
        raise FaultError(f"fault '{fault}': target '{target}' does not exist (has the code been refactored? update "
                         "the catalog)") from None
    return owner, name, original


@contextmanager
def patched(fault: str, target: str, replace: Callable[[Any], Any]) -> Iterator[Any]:
    """Within the block ``target`` is ``replace(original)`` (yielded); on exit, also on error, the original is back."""
    owner, name, original = resolve(fault, target)
    faulty = replace(original)
    _same_call(fault, target, original, faulty)
    setattr(owner, name, faulty)
    try:
        yield faulty
    finally:
        setattr(owner, name, original)


def _same_call(fault: str, target: str, original: Any, faulty: Any) -> None:
    """A FaultError when the faulty function cannot be called as the original is (its required positional
    parameters): a replacement written for an older signature would raise TypeError at every call, which the gate
    reports as a backend error, so the fault would look caught without the bug it describes ever running."""
    if not (inspect.isfunction(original) and callable(faulty)):
        return
    parameters = inspect.signature(original).parameters.values()
    required = [p for p in parameters
                if p.default is p.empty and p.kind in (p.POSITIONAL_ONLY, p.POSITIONAL_OR_KEYWORD)]
    optional = {p.name: p.default for p in parameters
                if p.default is not p.empty and p.kind in (p.POSITIONAL_OR_KEYWORD, p.KEYWORD_ONLY)}
    signature = inspect.signature(faulty)
    try:
        try:
            signature.bind(*required, **optional)      # the optional parameters by name ...
        except TypeError:
            signature.bind(*required, *optional)       # ... or in order (a replacement forwarding *args)
    except TypeError as exc:
        raise FaultError(f"fault '{fault}': the replacement of '{target}' cannot be called as {target}"
                         f"{inspect.signature(original)} is ({exc}); update the catalog") from None


#: The Euler–Lagrange lru_caches of code derived from the model (a fault in the derivation must not outlive itself in
#: any of them: a faulty linearization of the double pendulum once did, and named the next fault's backend wrongly).
_EULER_LAGRANGE_CACHES = ("_compiled", "_linear_code", "_derived")


@contextmanager
def _fresh_euler_lagrange() -> Iterator[None]:
    """The Euler–Lagrange caches empty for the fault: a temporary ``CROSSCHECK_CACHE`` directory (deleted on exit),
    and in place of each lru_cache of derived code (the dynamics', the linearization's) an empty one of the same size,
    discarded on exit with every faulty entry; the originals, which never see the fault, are put back with their
    entries."""
    from formalisms import euler_lagrange

    before = os.environ.get("CROSSCHECK_CACHE")
    originals = {name: getattr(euler_lagrange, name) for name in _EULER_LAGRANGE_CACHES}
    with tempfile.TemporaryDirectory(prefix="crosscheck-fault-") as tmp:
        os.environ["CROSSCHECK_CACHE"] = tmp
        for name, cached in originals.items():
            setattr(euler_lagrange, name, functools.lru_cache(maxsize=cached.cache_info().maxsize)(cached.__wrapped__))
        try:
            yield
        finally:
            for name, cached in originals.items():
                setattr(euler_lagrange, name, cached)
            if before is None:
                os.environ.pop("CROSSCHECK_CACHE", None)
            else:
                os.environ["CROSSCHECK_CACHE"] = before


@contextmanager
def _fresh_geometric() -> Iterator[None]:
    """The geometric backend's compiled functions set aside on entry (so every model and chart is compiled under the
    fault) and put back on exit, the faulty ones dropped."""
    from formalisms import geometric

    saved = dict(geometric._COMPILED)
    geometric._COMPILED.clear()
    try:
        yield
    finally:
        geometric._COMPILED.clear()
        geometric._COMPILED.update(saved)


#: module -> the context that isolates the results it derives and caches.
_DERIVATION_CACHES: dict[str, Callable[[], Any]] = {
    "formalisms.euler_lagrange": _fresh_euler_lagrange,
    "formalisms.geometric": _fresh_geometric,
}


@contextmanager
def injected(fault: Fault) -> Iterator[Any]:
    """Within the block the fault's target is ``fault.replace(original)`` (yielded) and, for a ``derived`` fault, the
    backend's derivation caches are empty; on exit, also on error, the original object and caches are put back."""
    with ExitStack() as stack:
        if fault.derived:
            stack.enter_context(_DERIVATION_CACHES[fault.module]())
        yield stack.enter_context(patched(fault.name, fault.target, fault.replace))


# ------------------------------------------------------------------------------------------------ outputs


def _flatten(prefix: str, value, out: dict[str, object]) -> None:
    """Every number a split holds, by a dotted name: arrays and scalars as float arrays, strings as they are;
    dataclasses and mappings (extras) recursively; None and UNSUPPORTED left out."""
    if value is None or isinstance(value, Unsupported):
        return
    if dataclasses.is_dataclass(value) and not isinstance(value, type):
        for f in dataclasses.fields(value):
            _flatten(f"{prefix}.{f.name}", getattr(value, f.name), out)
    elif isinstance(value, Mapping):
        for key, item in value.items():
            _flatten(f"{prefix}.{key}", item, out)
    elif isinstance(value, str):
        out[prefix] = value
    else:
        out[prefix] = np.asarray(value, dtype=float)


def outputs(backend: Formalism, setup: CaseSetup, state: State) -> dict[str, object]:
    """Everything ``backend`` returns at ``state`` where the gate evaluates it: in the joint chart, in each of the
    case's charts (``split_chart``, when the backend has it; the state carried over as the chart checks do), on
    the state's moved scene and, at the states the gate linearizes at, its linearization (A, B, vdot). Keys ``"<where>:
    <field>"``; a raising evaluation gives ``"<where>: error"``."""
    model = setup.model
    q, qd, u = (np.array(v) for v in (state.q, state.qd, state.u))
    calls: list[tuple[str, Callable[[], object]]] = [("joint", lambda: backend.split(model, q, qd, u))]
    if backend.split_chart is not None:
        for chart in setup.charts:
            p = chart.p_of(q)
            pd = charts.velocity_to_chart(chart, p, qd)
            tau_p = charts.force_to_chart(chart, p, model.input_map @ u)
            calls.append((f"chart {chart.name}",
                          functools.partial(backend.split_chart, model, chart, p, pd, tau_p)))
    scene = setup.scene(state)
    if scene is not None:
        frame, moved = scene
        calls.append((f"frame {frame.name}", functools.partial(backend.split, moved, q, qd, u)))
    if backend.linearize is not None and setup.linearization and state.index < linearization.STATES:
        calls.append(("linearization", functools.partial(backend.linearize, model, q, qd, u)))
    out: dict[str, object] = {}
    for where, call in calls:
        try:
            split = call()
        except Exception as exc:  # a fault may make a backend raise: that is an output too
            out[f"{where}: error"] = f"{type(exc).__name__}: {exc}"
            continue
        for f in dataclasses.fields(split):
            _flatten(f"{where}: {f.name}", getattr(split, f.name), out)
    return out


def _bits(value) -> tuple:
    return (value,) if isinstance(value, str) else (value.shape, value.dtype.str, value.tobytes())


def differing(a: Mapping[str, object], b: Mapping[str, object]) -> list[str]:
    """The keys whose values are not identical bit for bit (or present on one side only)."""
    return sorted(k for k in set(a) | set(b) if k not in a or k not in b or _bits(a[k]) != _bits(b[k]))


def _difference(a, b) -> tuple[float, float]:
    """(max absolute difference, the size of ``b``) of two outputs; inf when they cannot be compared (an error on
    one side, different shapes, NaN in different places)."""
    if isinstance(a, str) or isinstance(b, str) or a.shape != b.shape or not np.array_equal(
            np.isnan(a), np.isnan(b)):
        return float("inf"), 0.0
    finite = ~np.isnan(a)
    if not finite.any():
        return 0.0, 0.0
    return float(np.abs(a[finite] - b[finite]).max()), float(np.abs(b[finite]).max())


#: The split fields a proof names first, in this order (the answers the gate compares), before any other output.
ANSWERS = ("drift", "total", "ctrl", "lam", "lam_drift", "task_drift", "kinetic_energy", "constraint_force",
           "constraint_force_drift", "power_ctrl", "power_constr", "constraint_value", "constraint_jacobian",
           "constraint_bias", "constraint_velocity", "joint_wrenches", "joint_wrenches_drift", "task_inertia",
           "zvcf", "drift_velocity", "A", "B", "vdot")

#: A change smaller than this, relative to the largest answer in its place, is not shown as the proof when a larger
#: one exists (rounding where an answer is zero).
VISIBLE = 1e-8


@dataclass(frozen=True)
class Proof:
    """The fault is real: the faulty backend's outputs at the catching state against its outputs there with the fault
    removed. ``changed`` counts the outputs that differ; ``key`` names the one shown: an error if the fault made the
    backend raise, else the first answer (:data:`ANSWERS`, joint chart first, then the charts, then the moved scene)
    that changed by more than :data:`VISIBLE` times the largest answer in its place, else the output that changed
    most relative to its size; ``difference`` is its change (inf: an error or a changed shape) and ``size`` its
    largest entry with the fault removed."""

    changed: int
    key: str
    difference: float
    size: float

    @property
    def real(self) -> bool:
        return self.changed > 0


def _relative(difference: float, size: float) -> float:
    return difference / size if size > 0.0 else (float("inf") if difference > 0.0 else 0.0)


def proof(faulty: Mapping[str, object], restored: Mapping[str, object]) -> Proof:
    changed = set(differing(faulty, restored))
    if not changed:
        return Proof(0, "", 0.0, 0.0)
    odd = [k for k in list(faulty) + list(restored) if k in changed and (
        k.endswith(": error") or k not in faulty or k not in restored)]
    if odd:
        return Proof(len(changed), odd[0], float("inf"), 0.0)
    scored = {k: _difference(faulty[k], restored[k]) for k in faulty if k in changed}
    rank = {name: i for i, name in enumerate(ANSWERS)}
    answers = sorted((k for k in scored if _field(k) in rank), key=lambda k: rank[_field(k)])
    scale: dict[str, float] = {}                 # per place: the largest answer there, faulty or not
    for k in restored:
        if _field(k) in rank:
            place = k.split(": ", 1)[0]
            scale[place] = max(scale.get(place, 0.0), _size(restored[k]), _size(faulty[k]))
    visible = [k for k in answers if scored[k][0] > VISIBLE * scale[k.split(": ", 1)[0]]]
    key = visible[0] if visible else max(scored, key=lambda k: (_relative(*scored[k]), scored[k][0]))
    return Proof(len(changed), key, *scored[key])


def _field(key: str) -> str:
    return key.split(": ", 1)[1]


def _size(value) -> float:
    finite = value[~np.isnan(value)]
    return float(np.abs(finite).max()) if finite.size else 0.0


# ------------------------------------------------------------------------------------------------ the hunt


@dataclass(frozen=True)
class Catch:
    """A failing comparison or check (its key in the gate's outcome), its worst error/tolerance ratio and the backend
    it names (``compare.suspect``: the outlier of its vote, or the one backend behind it, e.g. a frame law, which
    checks one backend against itself on the moved scene). An error is ``"error <where>"`` with ratio inf, naming
    the backend that raised."""

    key: str
    ratio: float
    outlier: str | None


@dataclass(frozen=True)
class Hunt:
    """One fault against the gate. ``states`` is the number of states evaluated (up to and including the catching
    one); ``case`` and ``state`` locate the catch (None when not caught); ``catches`` are sorted by ratio, worst
    first; ``outlier`` is the backend most of them named (ties: the larger ratio), None when no vote named one."""

    fault: Fault
    caught: bool
    states: int
    seconds: float
    case: str | None = None
    state: int | None = None
    catches: tuple[Catch, ...] = ()
    outlier: str | None = None
    proof: Proof | None = None

    @property
    def named_faulty(self) -> bool:
        return self.outlier == self.fault.backend


def catches(outcome: StateOutcome) -> tuple[Catch, ...]:
    """Every failing comparison, check and error at a state, worst first."""
    found = [Catch(f"error {where}", float("inf"), backend_of(where)) for where in outcome.errors]
    found += [Catch(f"internal error in {check}: {error}", float("inf"), None)
              for check, error in getattr(outcome, "internal", {}).items()]
    for key, comparison in {**outcome.comparisons, **outcome.checks}.items():
        if comparison.verdict == DISAGREE:
            found.append(Catch(key, comparison.worst_ratio, suspect(comparison)))
    return tuple(sorted(found, key=lambda c: (-np.nan_to_num(c.ratio, nan=np.inf), c.key)))


def named_outlier(found: Sequence[Catch]) -> str | None:
    """The backend named most often as the outlier (ties: the one with the largest ratio)."""
    votes = Counter(c.outlier for c in found if c.outlier is not None)
    if not votes:
        return None
    worst = {name: max(np.nan_to_num(c.ratio, nan=np.inf) for c in found if c.outlier == name) for name in votes}
    return max(votes, key=lambda name: (votes[name], worst[name]))


class _Case:
    """A case as the gate sets it up, with its states sampled on demand: ``sample_states`` draws state i from the
    same generator after states 0..i-1, so the first k of N states are the k states, and the list grows by
    doubling."""

    def __init__(self, spec: CaseSpec, seed: int, checks: Checks):
        self.setup = CaseSetup.build(spec, seed, checks)
        self.seed = seed
        self._states: list[State] = []

    def state(self, index: int, samples: int) -> State:
        if index >= len(self._states):
            count = min(samples, max(2 * len(self._states), index + 1, 4))
            self._states = sample_states(self.setup.model, count, self.seed, self.setup.spec.name)
        return self._states[index]


@functools.lru_cache(maxsize=None)
def _case(spec: CaseSpec, seed: int, checks: Checks) -> _Case:
    """Cases are set up once per process: the faults never touch models, charts, frames or sampling, and the
    backends' caches are keyed by the model objects."""
    return _Case(spec, seed, checks)


def _round_robin(setups: Sequence[_Case], samples: int) -> Iterator[tuple[_Case, State]]:
    """State 0 of every case, then state 1 of every case, ..., up to state ``samples - 1``."""
    for index in range(samples):
        for case in setups:
            yield case, case.state(index, samples)


def default_specs() -> list[CaseSpec]:
    """The default gate's cases: every built-in case with its default parameters."""
    return [CaseSpec(name) for name in cases.names()]


def default_backends() -> list[Formalism]:
    """The default gate's backends: every formalism and the reference."""
    return [backend_registry.get(name) for name in backend_registry.names()]


def hunt(fault: Fault, specs: Sequence[CaseSpec] | None = None, backends: Sequence[Formalism] | None = None,
         samples: int = DEFAULT_SAMPLES, seed: int = 0, checks: Checks = Checks(), known: divergences.Registry | None = None,
         progress: Callable[[str, int], None] | None = None) -> Hunt:
    """Run the gate's states round robin under ``fault`` (module docstring) until one fails, at most ``samples``
    per case; ``specs`` and ``backends`` default to the default gate's. With ``known`` (a divergence registry, as
    ``crosscheck gate`` applies it) a disagreement it explains does not count as a catch. ``progress(case, index)``
    is called before each state is evaluated."""
    specs = default_specs() if specs is None else list(specs)
    backends = default_backends() if backends is None else list(backends)
    if fault.backend not in [b.name for b in backends]:
        raise FaultError(f"fault '{fault.name}' is in backend '{fault.backend}', which is not among the backends "
                         f"evaluated: {', '.join(b.name for b in backends)}")
    if samples < 1 or not specs:
        raise FaultError("a hunt needs at least one case and one sample per case")
    faulty_backend = next(b for b in backends if b.name == fault.backend)
    setups = [_case(spec, seed, checks) for spec in specs]
    start, count = time.perf_counter(), 0
    with injected(fault):
        for case, state in _round_robin(setups, samples):
            if progress:
                progress(case.setup.spec.name, state.index)
            outcome = case.setup.evaluate(state, backends)
            if known is not None:
                divergences.apply_to_state(known, (case.setup.spec.name, case.setup.model.name), outcome)
            count += 1
            if outcome.failed:
                faulty = outputs(faulty_backend, case.setup, state)
                break
        else:
            return Hunt(fault, False, count, time.perf_counter() - start)
    restored = outputs(faulty_backend, case.setup, state)
    found = catches(outcome)
    return Hunt(fault, True, count, time.perf_counter() - start, case.setup.spec.name, state.index, found,
                named_outlier(found), proof(faulty, restored))


#: The checks of a cheap first search (:func:`caught_within`): the default gate's without the linearizations, the
#: costliest per state (a cold Euler–Lagrange derivation of A and B, the 50-digit reference's central differences).
WITHOUT_LINEARIZATION = dataclasses.replace(Checks(), linearization=False)


def caught_within(fault: Fault, rounds: int) -> Hunt:
    """Whether the default gate catches ``fault`` within its first ``rounds`` states of every case, searched
    cheaply: first with :data:`WITHOUT_LINEARIZATION`, then, if that catches nothing, with every check. A catch of
    the first search is a catch of the default gate at the same state, by a check it runs: a check only adds
    failures to a state, never takes one away. (Its first catch may come earlier, by a linearization check;
    :func:`hunt` with every check, as ``crosscheck faults`` runs it, finds the first.)"""
    found = hunt(fault, samples=rounds, checks=WITHOUT_LINEARIZATION)
    return found if found.caught else hunt(fault, samples=rounds)


# ------------------------------------------------------------------------------------------------ the report


def _cell(text: str) -> str:
    """Text for a markdown table cell (a literal ``|`` escaped)."""
    return text.replace("|", r"\|")


def _ratio(x: float) -> str:
    return "inf" if x == float("inf") else f"{x:.3g}"


def line(h: Hunt) -> str:
    """One line per fault for the terminal."""
    if not h.caught:
        return (f"MISSED {h.fault.name} ({h.fault.backend}): not caught in {h.states} states"
                f"{' (a known gap of the gate)' if h.fault.gap else ''}")
    top = h.catches[0]
    return (f"caught {h.fault.name} ({h.fault.backend}): {h.case} #{h.state}, {h.states} states, by '{top.key}' "
            f"(ratio {_ratio(top.ratio)}; {len(h.catches)} failing), outlier {h.outlier or '-'}"
            f"{' (not the faulty backend)' if h.outlier and not h.named_faulty else ''}")


@dataclass(frozen=True)
class Summary:
    faults: int
    caught: int
    median_states: float
    max_states: int
    named_faulty: int
    named_other: int

    @property
    def rate(self) -> float:
        return self.caught / self.faults if self.faults else 0.0


def summarize(hunts: Sequence[Hunt]) -> Summary:
    caught = [h for h in hunts if h.caught]
    states = [h.states for h in caught]
    return Summary(len(hunts), len(caught), statistics.median(states) if states else 0.0, max(states, default=0),
                   sum(h.named_faulty for h in caught), sum(h.outlier is not None and not h.named_faulty
                                                           for h in caught))


def render(hunts: Sequence[Hunt], command: str, seconds: float, samples: int, seed: int, interrupted: str = "") -> str:
    """The markdown report: the summary, one row per fault, then each fault's description and injection point;
    ``interrupted``, for a run ended by Ctrl-C, says where (the report then holds the faults hunted until then)."""
    s = summarize(hunts)
    partial = [f"**PARTIAL**: the run was interrupted {interrupted}; only the faults hunted until then are below.",
               ""] if interrupted else []
    lines = [
        "# Fault catalog against the default gate", "", *partial,
        f"Command: `{command}` (seed {seed}, at most {samples} states per case, round robin over the cases; "
        f"{seconds:.1f} s in all).", "",
        "| catch rate | states needed (median / max) | outlier named = faulty backend | named another | none named |",
        "|---|---|---|---|---|",
        f"| {s.caught}/{s.faults} ({100 * s.rate:.0f} %) | {s.median_states:g} / {s.max_states} | {s.named_faulty} | "
        f"{s.named_other} | {s.caught - s.named_faulty - s.named_other} |", "",
        "## Faults", "",
        "| fault | backend | caught | where | states | caught by (worst ratio) | failing | outlier named | "
        "proof: changed output (difference) |",
        "|---|---|---|---|---|---|---|---|---|",
    ]
    for h in hunts:
        if not h.caught:
            lines.append(f"| `{h.fault.name}` | {h.fault.backend} | **NO** | - | {h.states} | - | - | - | - |")
            continue
        top, p = h.catches[0], h.proof
        lines.append(f"| `{h.fault.name}` | {h.fault.backend} | yes | {h.case} #{h.state} | {h.states} | "
                     f"`{top.key}` ({_ratio(top.ratio)}) | {len(h.catches)} | {h.outlier or '-'} | "
                     f"`{p.key}` ({_ratio(p.difference)} of {p.size:.3g}; {p.changed} outputs) |")
    missed = [h.fault for h in hunts if not h.caught]
    if missed:
        lines += ["", "## Not caught", ""]
        lines += [f"- `{f.name}` ({f.backend}): {f.bug} {f.gap or 'Not a known gap: a new blind spot of the gate.'}"
                  for f in missed]
    lines += ["", "## The catalog", "", "| fault | backend | bug | injected at |", "|---|---|---|---|"]
    lines += [f"| `{h.fault.name}` | {h.fault.backend} | {_cell(h.fault.bug)} | `{h.fault.target}`"
              f"{' (derivation)' if h.fault.derived else ''} |" for h in hunts]
    return "\n".join(lines) + "\n"
