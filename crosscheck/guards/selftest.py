"""Self-test canaries: every gate run proves it can still see small errors (docs/design.md, "a check that cannot fail").

The code every backend shares (the model language, sampling, tolerances, the comparison, the vote) is outside the
vote: a tolerance loosened tenfold, a comparison that takes a signed difference or lets NaN agree, a vote that names
the wrong backend would leave every run green. So the gate injects a few tiny, known faults into one backend's
answer at fixed states of fixed built-in cases and checks that its own comparisons catch each one and name that
backend (:func:`run`); a canary that is not caught fails the run: the gate has lost sensitivity.

A canary is a fault of known size in one backend's answer, made from exact relations between the answers:

* ``mass matrix``: M off by a relative ``size``, ``(1 + size) M``: every acceleration (drift, ctrl, total) divided
  by ``1 + size``;
* ``velocity products``: ``C qd`` off by a relative ``size``: drift and total move by ``-size M^-1 C qd``;
* ``gravity``: ``g`` off by a relative ``size``: drift and total move by ``-size M^-1 g``;
* ``one entry``: the first entry of the drift raised by ``size`` times the drift's largest (a one-signed error in one
  place: a comparison that takes a signed difference sees it from one side of each pair only);
* ``multiplier sign``: the multipliers reported with the opposite sign convention (lam and lam_drift negated);
* ``not a number``: a NaN in one entry of the drift (a NaN must never count as agreement).

``M``, ``C qd`` and ``g`` come from the Pinocchio reference's split at the state. The sizes are calibrated: each
canary is caught with an error/tolerance ratio between 2 and 10 (see :data:`CANARIES`), so a tolerance loosened
tenfold misses it, while rounding (ratios below 0.1 on these states) cannot fake a catch.
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass
from typing import Sequence

import numpy as np

from crosscheck import backends as backend_registry
from crosscheck.core import tolerance
from crosscheck.core.compare import DISAGREE, suspect
from crosscheck.core.sampling import sample_states
from crosscheck.engine.evaluation import CaseSetup, compare_all
from crosscheck.engine.outcomes import StateOutcome
from crosscheck.engine.specs import CaseSpec, Checks

#: The seed of the canaries' states (fixed: the canaries are calibrated on these states, whatever the run's seed).
SEED = 0
#: States drawn per canary case (the canaries use some of them).
STATES = 30


@dataclass(frozen=True)
class Canary:
    """A known fault: ``kind`` (module doc) of relative ``size`` in ``backend``'s answer at state ``state`` of the
    built-in case ``case`` (``sample_states(model, STATES, SEED, case)``)."""

    case: str
    state: int
    backend: str
    kind: str
    size: float = 0.0

    def describe(self) -> str:
        what = {"mass matrix": "M", "velocity products": "C qd", "gravity": "g", "one entry": "one drift entry"}.get(
            self.kind)
        fault = f"a relative {self.size:.0e} error in {what}" if what else self.kind
        return f"{fault} of {self.backend} at {self.case} #{self.state}"


#: The canaries of every gate run: the article's double pendulum (planar), the 3-D spatial arm, a constrained case.
#: Sizes calibrated on these states (``tests/guards/test_selftest.py`` re-measures every ratio): double pendulum #3
#: M 3.1, g 4.0, one entry 4.4, #4 C qd 6.9; spatial arm #27 M 3.3, C qd 2.1, g 3.9. The 3-D claim is 1e-10
#: (sensitivity). The one-entry canary's backend is neither the first voter nor the last, so that a signed difference
#: misses it.
CANARIES: tuple[Canary, ...] = (
    Canary("double_pendulum", 3, "newton_euler", "mass matrix", 1e-11),
    Canary("double_pendulum", 4, "screw", "velocity products", 1e-10),
    Canary("double_pendulum", 3, "euler_lagrange", "gravity", 2e-11),
    Canary("double_pendulum", 3, "geometric", "one entry", 2e-11),
    Canary("spatial_arm", 27, "geometric", "mass matrix", 3e-11),
    Canary("spatial_arm", 27, "operational_space", "velocity products", 1e-10),
    Canary("spatial_arm", 27, "pinocchio", "gravity", 1e-10),
    Canary("double_pendulum_circle", 2, "geometric", "multiplier sign"),
    Canary("double_pendulum_circle", 2, "newton_euler", "not a number"),
)

#: A caught canary's error/tolerance ratio must stay below this: a tolerance loosened by this factor misses it.
CALIBRATED = 10.0


@dataclass(frozen=True)
class CanaryResult:
    """A canary against the gate: ``caught`` (some comparison DISAGREEs), ``named`` (the vote names the canary's
    backend its outlier: it disagrees with every other voter, which agree), the worst error/tolerance ratio and the
    comparison that had it. ``skipped`` says why a canary was not
    judged: its backend already disagrees at the state without any fault (a real bug there, which the gate reports
    on its own cases, or one the divergence registry explains)."""

    canary: Canary
    caught: bool
    named: bool
    ratio: float
    quantity: str
    skipped: str = ""

    @property
    def passed(self) -> bool:
        return bool(self.skipped) or (self.caught and self.named)


@dataclass(frozen=True)
class SelfTest:
    """The canaries' results; ``unusable`` names the canary states where the backends disagree without a fault and
    no single backend explains it (a broken comparison or tolerance: nothing can be judged there)."""

    results: tuple[CanaryResult, ...]
    unusable: tuple[str, ...] = ()

    @property
    def passed(self) -> bool:
        return not self.unusable and all(r.passed for r in self.results)

    def failures(self) -> list[str]:
        """One sentence per canary that was not caught or not named, and per unusable state."""
        out = [f"the gate disagrees with itself without any fault at {where}; no canary can be judged there (a "
               "broken comparison or tolerance)" for where in self.unusable]
        for r in self.results:
            if r.skipped:
                continue
            if not r.caught:
                out.append(f"the gate has lost sensitivity: {r.canary.describe()} was not caught (worst "
                           f"error/tolerance {r.ratio:.3g}); a loosened tolerance, a broken comparison or degenerate "
                           "sampling")
            elif not r.named:
                out.append(f"the vote failed: {r.canary.describe()} was caught ({r.quantity}, ratio {r.ratio:.3g}) "
                           f"but {r.canary.backend} was not named as its outlier")
        return out


def inject(canary: Canary, split, reference):
    """``split`` (the canary backend's answer) with the canary's fault; ``reference`` is the Pinocchio split at the
    same state (its ``extras`` M, C qd and g)."""
    size = canary.size
    if canary.kind == "mass matrix":
        return dataclasses.replace(split, drift=split.drift / (1.0 + size), ctrl=split.ctrl / (1.0 + size),
                                   total=split.total / (1.0 + size))
    if canary.kind in ("velocity products", "gravity"):
        force = reference.extras["Cqd" if canary.kind == "velocity products" else "g"]
        shift = -size * np.linalg.solve(reference.extras["M"], force)
        return dataclasses.replace(split, drift=split.drift + shift, total=split.total + shift)
    if canary.kind == "one entry":
        drift = np.array(split.drift)
        drift[0] += size * float(np.abs(drift).max())
        return dataclasses.replace(split, drift=drift)
    if canary.kind == "multiplier sign":
        return dataclasses.replace(split, lam=-split.lam, lam_drift=-split.lam_drift)
    if canary.kind == "not a number":
        drift = np.array(split.drift)
        drift[0] = np.nan
        return dataclasses.replace(split, drift=drift)
    raise ValueError(f"unknown canary kind '{canary.kind}'")


def _judge(canary: Canary, model, outcome) -> CanaryResult:
    """Compare again at ``outcome``'s state (clean, :func:`_clean`) with the canary's backend faulty, as the gate
    compares."""
    if canary.backend not in outcome.splits:
        return CanaryResult(canary, False, False, 0.0, "-", f"{canary.backend} disagrees at this state without a fault")
    splits = dict(outcome.splits)
    splits[canary.backend] = inject(canary, splits[canary.backend], outcome.splits["pinocchio"])
    faulty = StateOutcome(outcome.state, splits, {}, {}, {name: b for name, split in splits.items()
                                                          if (b := tolerance.breakdown(split))})
    compare_all(model, faulty)
    failing = [(key, c) for key, c in faulty.comparisons.items() if c.verdict == DISAGREE]
    worst_key, worst = max(failing, key=lambda kc: np.nan_to_num(kc[1].worst_ratio, nan=np.inf),
                           default=("-", None))
    ratio = max((c.worst_ratio for c in faulty.comparisons.values()),
                key=lambda r: np.nan_to_num(r, nan=np.inf), default=0.0) if worst is None else worst.worst_ratio
    return CanaryResult(canary, bool(failing), any(c.outlier == canary.backend for _, c in failing), ratio,
                        worst_key)


def _clean(model, outcome):
    """``outcome`` without the backends that disagree at it without any fault (each named by the vote), compared
    again; None when the state disagrees and no single backend explains it."""
    failing = [c for c in outcome.comparisons.values() if c.verdict == DISAGREE]
    if not failing:
        return outcome
    blamed = {suspect(c) for c in failing}
    if None in blamed:
        return None
    kept = {name: split for name, split in outcome.splits.items() if name not in blamed}
    clean = StateOutcome(outcome.state, kept, {}, {}, {k: v for k, v in outcome.breakdowns.items() if k in kept})
    compare_all(model, clean)
    return None if any(c.verdict == DISAGREE for c in clean.comparisons.values()) else clean


def run(canaries: Sequence[Canary] = CANARIES, backends=None) -> SelfTest:
    """Evaluate each canary's state once with every backend (the default gate's backends and the case's closed form,
    without charts, frames or conservation), leave out any backend that disagrees there without a fault
    (:func:`_clean`), and judge each canary there."""
    chosen = ([backend_registry.get(name) for name in backend_registry.builtin_names()] if backends is None
              else list(backends))
    results, evaluated, unusable = [], {}, []
    for canary in canaries:
        key = (canary.case, canary.state)
        if key not in evaluated:
            setup = CaseSetup.build(CaseSpec(canary.case), SEED, Checks(charts=False, frames=0, conservation=False,
                                                                        self_test=False, linearization=False))
            state = sample_states(setup.model, STATES, SEED, canary.case)[canary.state]
            evaluated[key] = (setup.model, _clean(setup.model, setup.evaluate(state, chosen)))
            if evaluated[key][1] is None:
                unusable.append(f"{canary.case} #{canary.state}")
        model, outcome = evaluated[key]
        if outcome is not None:
            results.append(_judge(canary, model, outcome))
    return SelfTest(tuple(results), tuple(unusable))
