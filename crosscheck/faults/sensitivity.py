"""How small an error the default gate catches: per backend and term, the smallest relative error in its ``M``,
``C qd`` or ``g`` that makes a state of the gate fail, per case family (the claim: on the 3-D cases as sharp as on the
planar ones).

A term fault scales one term where each backend forms it, before its solve, by ``1 + size``
(:data:`TERM_HOOKS`): Euler–Lagrange's generated ``M``, ``C qd``, ``g`` (``evaluate``, in every chart), Newton–Euler's
``M`` and ``h = C qd + g`` of its recursion (the gravity part from its own pass at rest), the screw backend's ``M``
and eq. (27)'s ``h``, the operational-space projections, and the geometric backend's metric, its derivatives (the
Christoffel symbols, so ``C qd``) and ``dV``. Everything the gate does then follows from the backend's own code: its
accelerations, task acceleration, kinetic energy, the chart-native answers and the conservation checks see the
error where they use the term.

The errors the gate sees are linear in ``size`` while it is small: :func:`measure` evaluates every state of a case
(every comparison and check of ``crosscheck gate``) with the term off by :data:`PROBE` and takes the largest
error/tolerance ratio r over the states; the smallest relative error caught is ``PROBE / r``, confirmed by
evaluating the best state again at twice that (caught) . The other backends' answers do not change with the fault
and are computed once (:class:`_Cached`).
"""

from __future__ import annotations

import dataclasses
from contextlib import ExitStack
from dataclasses import dataclass
from typing import Callable, Sequence

import numpy as np

from crosscheck.core.sampling import sample_states
from crosscheck.engine.evaluation import CaseSetup
from crosscheck.engine.outcomes import StateOutcome
from crosscheck.engine.specs import CaseSpec, Checks
from crosscheck.faults import injection
from formalisms.interface import Formalism

TERMS = ("M", "C qd", "g")
#: The relative size of the probing fault: far above rounding (the clean ratios are below 0.1), far below where the
#: answers stop being linear in it.
PROBE = 1e-8
#: Case families of the table (the default gate's cases).
FAMILIES = {"planar": ("double_pendulum", "n_link_pendulum", "acrobot"),
            "3-D": ("spatial_arm", "panda", "rotor", "inclined_slider", "spherical_pendulum"),
            "constrained": ("double_pendulum_circle", "four_bar", "slider_crank", "cartesian_pendulum",
                            "double_pendulum_absolute_loop", "double_pendulum_rail", "geared_pendulums"),
            "Lie groups": ("free_body", "ball_pendulum", "ball_double_pendulum", "satellite_arm", "solo12",
                           "solo12_standing"),
            "external loads": ("double_pendulum_tip_force", "double_pendulum_spring"),
            "nonholonomic": ("knife_edge", "rolling_disk", "differential_drive"),
            "model files": ("urdf_gripper", "mjcf_floating", "mjcf_ball_slide", "mjcf_armature")}
#: The 3-D cases of the claim (a relative 1e-10 error in any backend's M, C qd or g is caught).
CLAIMED = ("spatial_arm", "panda")
CLAIM = 1e-10
#: The multipliers' term: every backend's lam and lam_drift scaled by ``1 + size`` in its answer (as a multiplier solve
#: off by that much), measured on the default gate's cases with several constraint rows, where the multipliers'
#: tolerance carries cond(S) (4 to 40 there) and a loosened one would hide the most.
MULTIPLIERS = "lam"
MULTI_ROW = ("four_bar", "slider_crank", "double_pendulum_absolute_loop", "solo12_standing", "rolling_disk",
             "differential_drive")


def _scaled(term: str, size: float, M, Cqd, g):
    """``(M, C qd, g)`` with ``term`` off by the relative ``size``."""
    k = 1.0 + size
    return (k * M, Cqd, g) if term == "M" else (M, k * Cqd, g) if term == "C qd" else (M, Cqd, k * g)


def _euler_lagrange(term: str, size: float):
    def wrap(evaluate):
        def faulty(model, x, xd, chart=None):
            terms, constraint_terms = evaluate(model, x, xd, chart)
            M, Cqd, g = _scaled(term, size, terms.M, terms.Cqd, terms.g)
            return terms._replace(M=M, Cqd=Cqd, g=g), constraint_terms
        return faulty
    return wrap


def _newton_euler(term: str, size: float):
    def wrap(dynamics):
        def faulty(model, q, qd):
            from formalisms import newton_euler

            kin, units, bias_motion, h, M = dynamics(model, q, qd)
            rest = np.zeros((model.nv,) + np.shape(q)[1:])         # velocities: nv (q has nq with group joints)
            g = newton_euler.inverse_dynamics(model, q, rest, rest)
            M, Cqd, g = _scaled(term, size, M, h - g, g)
            return kin, units, bias_motion, Cqd + g, M
        return faulty
    return wrap


def _screw(term: str, size: float):
    def wrap(terms):
        def faulty(kin, G, qd):
            M, _, Cqd, g = terms(kin, G, qd)
            M, Cqd, g = _scaled(term, size, M, Cqd, g)
            return M, Cqd + g, Cqd, g
        return faulty
    return wrap


def _operational_space(term: str, size: float):
    def wrap(terms):
        return lambda model, kin: _scaled(term, size, *terms(model, kin))
    return wrap


def _geometric(term: str, size: float):
    def wrap(evaluate):
        def faulty(model, chart, p, pd):
            point = evaluate(model, chart, p, pd)
            k = 1.0 + size
            change = {"M": {"M": k * point.M}, "C qd": {"dM": k * point.dM}, "g": {"dV": k * point.dV}}[term]
            return dataclasses.replace(point, **change)
        return faulty
    return wrap


#: backend -> (the function that forms its terms, the fault that scales one of them).
TERM_HOOKS: dict[str, tuple[str, Callable]] = {
    "euler_lagrange": ("formalisms.euler_lagrange:evaluate", _euler_lagrange),
    "newton_euler": ("formalisms.newton_euler:_dynamics", _newton_euler),
    "screw": ("formalisms.screw.dynamics:terms", _screw),
    "operational_space": ("formalisms.operational_space:_terms", _operational_space),
    "geometric": ("formalisms.geometric:_evaluate", _geometric),
}


class _Cached:
    """A backend whose answers are kept by their arguments (the other backends' answers do not change while one
    backend is faulty)."""

    def __init__(self, backend: Formalism):
        self.backend, self.memo = backend, {}

    @staticmethod
    def _key(arg):
        if isinstance(arg, (np.ndarray, tuple, list)):
            return np.asarray(arg, dtype=float).tobytes()
        return id(arg)                    # a model or a chart: the session keeps every one alive

    def _call(self, function, *args):
        key = (function.__name__,) + tuple(self._key(a) for a in args)
        if key not in self.memo:
            try:
                self.memo[key] = (function(*args), None)
            except Exception as exc:  # noqa: BLE001 - an answer like any other, replayed
                self.memo[key] = (None, exc)
        value, exc = self.memo[key]
        if exc is not None:
            raise exc
        return value

    def formalism(self) -> Formalism:
        b = self.backend
        chart = None if b.split_chart is None else (lambda *args: self._call(b.split_chart, *args))
        return Formalism(b.name, b.summary, lambda *args: self._call(b.split, *args), chart)


def _multipliers_scaled(split: Callable, size: float) -> Callable:
    """``split`` with its lam and lam_drift scaled by ``1 + size``."""
    def faulty(*args):
        s = split(*args)
        return dataclasses.replace(s, lam=(1.0 + size) * np.asarray(s.lam), lam_drift=(1.0 + size) * np.asarray(
            s.lam_drift))
    return faulty


def _worst(outcome: StateOutcome) -> tuple[float, str]:
    """The largest error/tolerance ratio of every comparison and check at a state (NaN and an error count as inf),
    and where."""
    if outcome.errors:
        return float("inf"), "error " + next(iter(outcome.errors))
    found = [(np.nan_to_num(c.worst_ratio, nan=np.inf), key)
             for key, c in [*outcome.comparisons.items(), *outcome.checks.items()]]
    return max(found, default=(0.0, "-"))


@dataclass(frozen=True)
class Measurement:
    """One backend, term and case: the largest error/tolerance ratio at :data:`PROBE` over the states and where,
    the smallest relative error caught (``PROBE / ratio``; inf when the term never shows), and whether twice that,
    injected at the best state, is caught."""

    backend: str
    term: str
    case: str
    states: int
    ratio: float
    state: int
    key: str
    caught: float
    confirmed: bool


class Session:
    """The default gate's cases and states, set up once, with every backend's clean answers cached."""

    def __init__(self, backends: Sequence[Formalism], states: int = 30, seed: int = 0, checks: Checks = Checks(),
                 cases: Sequence[str] | None = None):
        names = list(dict.fromkeys([c for family in FAMILIES.values() for c in family] if cases is None else cases))
        self.setups = {name: CaseSetup.build(CaseSpec(name), seed, dataclasses.replace(checks, self_test=False))
                       for name in names}
        self.states = {name: sample_states(s.model, states, seed, name) for name, s in self.setups.items()}
        self.cached = {b.name: _Cached(b) for b in backends}

    def _backends(self, faulty: str, backend: Formalism) -> list[Formalism]:
        return [backend if name == faulty else c.formalism() for name, c in self.cached.items()]

    def measure(self, backend: str, term: str, case: str, count: int | None = None) -> Measurement:
        """:class:`Measurement` of ``term`` in ``backend`` on ``case`` (module doc; :data:`MULTIPLIERS`: its
        multipliers), over the case's first ``count`` states (all the session drew by default)."""
        setup, states = self.setups[case], self.states[case][:count]
        original = self.cached[backend].backend

        def worst_at(size: float, among) -> tuple[float, str, int]:
            with ExitStack() as stack:
                faulty = original
                if term == MULTIPLIERS:
                    faulty = dataclasses.replace(original, split=_multipliers_scaled(original.split, size))
                else:
                    target, hook = TERM_HOOKS[backend]
                    stack.enter_context(injection.patched(f"sensitivity-{backend}", target, hook(term, size)))
                found = [(*_worst(setup.evaluate(s, self._backends(backend, faulty))), s.index) for s in among]
            return max(found, default=(0.0, "-", -1))

        ratio, key, best = worst_at(PROBE, states)
        if not ratio > 0.0:
            return Measurement(backend, term, case, len(states), ratio, best, key, float("inf"), False)
        caught = PROBE / ratio
        confirm = worst_at(2.0 * caught, [s for s in states if s.index == best])[0]
        return Measurement(backend, term, case, len(states), ratio, best, key, caught, confirm > 1.0)


@dataclass(frozen=True)
class Table:
    """The sensitivity table: per backend and term, per family the smallest relative error caught on any of its
    cases (and the case), with every :class:`Measurement`."""

    measurements: tuple[Measurement, ...]
    states: int

    def smallest(self, backend: str, term: str, cases: Sequence[str]) -> Measurement | None:
        found = [m for m in self.measurements if m.backend == backend and m.term == term and m.case in cases]
        return min(found, key=lambda m: m.caught, default=None)

    def claim_met(self) -> bool:
        """Whether on each :data:`CLAIMED` case every backend's every term is caught at :data:`CLAIM`."""
        pairs = {(m.backend, m.term) for m in self.measurements if m.term in TERMS}
        return all((m := self.smallest(b, t, (case,))) is not None and m.caught <= CLAIM and m.confirmed
                   for b, t in pairs for case in CLAIMED)


def run(backends: Sequence[Formalism], states: int = 30, seed: int = 0,
        progress: Callable[[str], None] | None = None) -> Table:
    """Measure every backend with a term hook, every term and every case of :data:`FAMILIES`; and every backend's
    multipliers on the cases of :data:`MULTI_ROW`."""
    session = Session(backends, states, seed)
    out = []
    for backend in [b.name for b in backends if b.name in TERM_HOOKS]:
        for term in TERMS:
            for case in session.setups:
                out.append(session.measure(backend, term, case))
            if progress:
                progress(f"sensitivity {backend} {term}: done")
    for backend in [b.name for b in backends]:
        out += [session.measure(backend, MULTIPLIERS, case) for case in MULTI_ROW]
        if progress:
            progress(f"sensitivity {backend} multipliers: done")
    return Table(tuple(out), states)


def _size(m: Measurement | None) -> str:
    if m is None:
        return "-"
    if m.caught == float("inf"):
        return "never"
    return f"{m.caught:.1g}" + ("" if m.confirmed else " (unconfirmed)")


def render(table: Table) -> list[str]:
    """Markdown lines of the table: per backend and term, the smallest relative error caught per family, and on
    the claimed 3-D cases with the claim's verdict."""
    backends = list(dict.fromkeys(m.backend for m in table.measurements if m.term in TERMS))
    lines = ["## Sensitivity: the smallest relative error the default gate catches", "",
             f"Each backend's M, C qd or g scaled by 1 + e where it forms it (`crosscheck.faults.sensitivity`); e is the "
             f"smallest that fails a state of the gate (every comparison and check), measured on the first "
             f"{table.states} states of each case (the default gate evaluates 100, so it catches at least this). "
             f"The claim: {CLAIM:.0e} on the 3-D cases {', '.join(CLAIMED)}.", "",
             "| backend | term | " + " | ".join(FAMILIES) + " | " + " | ".join(CLAIMED) + " | claim |",
             "|---|---|" + "---|" * (len(FAMILIES) + len(CLAIMED) + 1)]
    for backend in backends:
        for term in TERMS:
            family = [table.smallest(backend, term, cases) for cases in FAMILIES.values()]
            claimed = [table.smallest(backend, term, (case,)) for case in CLAIMED]
            ok = all(m is not None and m.caught <= CLAIM and m.confirmed for m in claimed)
            cells = [f"{_size(m)} ({m.case})" if m is not None and m.caught != float("inf") else _size(m)
                     for m in family]
            lines.append(f"| {backend} | {term} | " + " | ".join(cells) + " | "
                         + " | ".join(_size(m) for m in claimed) + f" | {'met' if ok else '**not met**'} |")
    return lines + [""] + _multiplier_lines(table)


def _multiplier_lines(table: Table) -> list[str]:
    """The multipliers' table: per backend and case with several constraint rows, the smallest relative error in
    its lam caught (empty when none was measured)."""
    found = [m for m in table.measurements if m.term == MULTIPLIERS]
    if not found:
        return []
    rows = list(dict.fromkeys(m.case for m in found))
    lines = ["### The multipliers on cases with several constraint rows", "",
             "Each backend's lam and lam_drift scaled by 1 + e in its answer; e is the smallest that fails a state of "
             f"the gate, on the first {table.states} states of each case.", "",
             "| backend | " + " | ".join(rows) + " |", "|---|" + "---|" * len(rows)]
    for backend in dict.fromkeys(m.backend for m in found):
        lines.append(f"| {backend} | " + " | ".join(_size(table.smallest(backend, MULTIPLIERS, (case,)))
                                                   for case in rows) + " |")
    return lines + [""]
