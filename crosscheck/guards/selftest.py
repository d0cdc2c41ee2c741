"""Self-test canaries: every gate run proves that each of its checks can still see a small error (docs/design.md, "a
check that cannot fail").

The code every backend shares (the model language, sampling, tolerances, the comparison, the vote, and the checks
themselves: charts, frames, conservation, linearization, equilibria, the conditions audit, coverage, the closed forms,
the second reading of a model file) is outside the vote: a check that silently stops comparing (compares a scene with itself, drops a term, returns ratio
0) or a tolerance loosened tenfold leaves every run green. So the gate injects a tiny known fault per check at fixed
states of fixed built-in cases, runs that check as the gate runs it (``crosscheck.engine.evaluation.CaseSetup``, with
the check switched on), and demands that the check itself catches the fault (a DISAGREE among its own comparisons,
:data:`FAMILIES`) and names the faulty voter; a canary that is not caught names the check that lost its power.

A canary (:class:`Canary`) is a fault of known size in one place:

* in one backend's joint-chart answer (``split``; checks ``comparisons``, ``multipliers``, ``conditions``,
  ``conservation``), by ``kind``:

  - ``mass matrix``: M off by a relative ``size``, ``(1 + size) M``: every acceleration divided by ``1 + size``;
  - ``velocity products`` / ``gravity``: ``C qd`` / ``g`` off by a relative ``size``: drift and total move by
    ``-size M^-1 C qd`` / ``-size M^-1 g`` (M, C qd and g from the Pinocchio reference at the state);
  - ``one entry``: the first entry of the drift raised by ``size`` times the drift's largest (one-signed: a comparison
    taking a signed difference sees it from one side of each pair only);
  - ``entry``: entry ``index`` of ``quantity`` raised by ``size`` times its scale (the largest entry; for the
    constraint power, the sum of its terms ``|Jc^T lam|_i |qd_i|``, since the power itself is 0);
  - ``multiplier sign``: lam and lam_drift negated; ``not a number``: a NaN in the drift;
  - ``condition``: the reported condition ``quantity`` off by a relative ``size``;
  - ``extra``: the extra ``quantity`` (Pinocchio's ``C qd``, which the Christoffel identity reads) off by ``size``;

* in a backend's chart-native answer (``split_chart``; check ``charts``) or its answer in the moved scene (``split``
  on the moved model; check ``frames``): ``mass matrix`` or ``extra`` there; or ``gravity unrotated``: the backend
  evaluates the moved scene with its gravity turned back towards the unmoved scene's by the share ``size`` (a frame
  check that compares a scene with itself, unmoved, cannot see it);
* in a backend's linearization (``linearize``; checks ``linearization``, ``equilibria``): ``stiffness``, the block
  ``dvdot/dq`` off by a relative ``size`` (the equilibria's eigenvalues move by about ``size / 2``);
* in the model every backend reads (checks ``closed forms`` and ``file reference``): ``mass``, body ``index``'s mass
  off by a relative ``size``; the backends agree with each other on the wrong model, and the closed form, bound to
  the case's parameters, or the Pinocchio reference, built from a file case's own file, must disagree with all of
  them;
* in the sample (check ``coverage``): ``sliver``, coordinate ``index`` squeezed to :data:`SLIVER_WIDTH` of its span;
  ``band``, four states of five squeezed so (the others keep the full range); ``at the limits``, one state of eight with a
  limited coordinate at one of the file's limits (read apart from the loader, as the coverage reads them);
  ``repeated``, every state a copy of one; ``rates never sampled``, qd = 0 everywhere. Each must be caught by its own
  rule of the coverage (``key``: a part of the problem's text);
* in the model converted from a file (check ``file reading``: the model against its file read apart from the loader,
  ``crosscheck.guards.loader``), as a parser's misreading every backend and the reference would share:
  ``inertia turned``, body ``index``'s inertia about its COM turned by ``size`` rad (about a fixed oblique axis);
  ``placement turned``, its joint placement's rotation turned so; ``limits misread``, its limits converted from
  degrees once more (a loader's slip). Each must be a loader finding naming that body's link and the field (``key``).

Sizes are calibrated (:data:`CANARIES`; ``tests/guards/test_selftest.py`` re-measures every ratio): each sized canary
is caught with an error/tolerance ratio between 2 and :data:`CALIBRATED`, so that a check loosened tenfold misses it,
while rounding (ratios below 0.1 on these states; below 6e-4 for the file reading over every URDF of
example-robot-data) cannot fake a catch. A coverage canary's margin is its construction: a coordinate spread over
:data:`SLIVER_WIDTH` of its span is a third of the sliver bound.
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass
from typing import Callable, Iterable, Sequence

import numpy as np

import cases
from crosscheck import backends as backend_registry
from crosscheck.core.compare import DISAGREE, backend_of, suspect
from crosscheck.core.sampling import State, sample_states
from crosscheck.engine import internal
from crosscheck.engine.evaluation import CaseSetup
from crosscheck.engine.specs import CaseSpec, Checks
from crosscheck.guards import coverage, file_limits, loader
from formalisms.interface import Formalism, Linearization

#: The seed of the canaries' states (fixed: the canaries are calibrated on these states, whatever the run's seed).
SEED = 0
#: A coverage canary's squeezed coordinate spans this share of its span: a third of the sliver bound and of the band
#: rule's window (0.1 each). Written here, not read from ``crosscheck.guards.coverage``, so that a bound loosened
#: tenfold misses it.
SLIVER_WIDTH = 0.03
#: The band canary keeps every BAND_SPREAD-th state as drawn (its coordinate still spans the full range) and squeezes
#: the others: 40 of 50 states in a window a third of the band rule's (0.1 of the span), where 30 is the most uniform
#: draws hold (``crosscheck.guards.coverage``); the rule with a window ten times wider, the whole span, holds them all.
BAND_SPREAD = 5
#: The at-the-limits canary puts every AT_LIMITS_EVERY-th state at a limit: 7 of 50, three times the 2 that uniform
#: draws (and home) may put there (``crosscheck.guards.coverage.limit_allowance``).
AT_LIMITS_EVERY = 8


@dataclass(frozen=True)
class Canary:
    """A known fault for the check ``check``: ``kind`` (module doc) of relative ``size`` (``quantity`` and ``index``
    where the kind needs them) in ``backend``'s answer at state ``state`` of the built-in case ``case``
    (``sample_states(model, state + 1, SEED, case)[state]``: the draws are sequential, so a state is the same
    however many are drawn); ``key``, when given, a part of the name of the comparison of the
    check that must catch it (``"momentum"``: the momentum rows of the conservation checks)."""

    check: str
    case: str
    state: int
    backend: str
    kind: str
    size: float = 0.0
    quantity: str = ""
    index: int = 0
    key: str = ""

    def describe(self) -> str:
        what = {"mass matrix": "M", "velocity products": "C qd", "gravity": "g", "one entry": "one drift entry",
                "entry": f"{self.quantity}[{self.index}]", "condition": f"the condition {self.quantity}",
                "extra": f"its {self.quantity}", "stiffness": "dvdot/dq",
                "mass": f"the mass of body {self.index} of the model",
                "gravity unrotated": "the moved scene's gravity (turned back)"}.get(self.kind)
        fault = f"a relative {self.size:.2g} error in {what}" if what else self.kind
        place = {"charts": " in a chart", "frames": " in a moved scene"}.get(self.check, "")
        if self.check == "coverage":
            return f"{fault} in the sample of {self.case}"
        if self.check == "file reading":
            turned = f" by {self.size:.2g} rad" if self.size else ""
            return f"{self.kind}{turned} (body {self.index}) in the model converted from the file of {self.case}"
        if not self.backend:                            # a fault in the model every backend reads
            return f"{fault} at {self.case} #{self.state}"
        return f"{fault}{place} of {self.backend} at {self.case} #{self.state}"


#: The canaries of every gate run, by the check each proves. Sizes calibrated on these states (each caught at an
#: error/tolerance ratio of about 3 to 7; ``tests/guards/test_selftest.py`` re-measures them); on the 3-D spatial arm
#: the 1e-10 claim (``crosscheck.faults.sensitivity``). The one-entry canary's backend is neither the first voter nor
#: the last, so that a signed difference misses it. The multipliers' canaries sit on cases with several constraint
#: rows (four_bar: 2, the absolute loop: 4), where cond(S) is 4 to 40.
CANARIES: tuple[Canary, ...] = (
    Canary("comparisons", "double_pendulum", 3, "newton_euler", "mass matrix", 1e-11),
    Canary("comparisons", "double_pendulum", 4, "screw", "velocity products", 1e-10),
    Canary("comparisons", "double_pendulum", 3, "euler_lagrange", "gravity", 2e-11),
    Canary("comparisons", "double_pendulum", 3, "geometric", "one entry", 2e-11),
    Canary("comparisons", "spatial_arm", 27, "geometric", "mass matrix", 3e-11),
    Canary("comparisons", "spatial_arm", 27, "operational_space", "velocity products", 1e-10),
    Canary("comparisons", "spatial_arm", 27, "pinocchio", "gravity", 1e-10),
    Canary("comparisons", "double_pendulum_circle", 2, "geometric", "multiplier sign"),
    Canary("comparisons", "double_pendulum_circle", 2, "newton_euler", "not a number"),
    Canary("multipliers", "four_bar", 3, "newton_euler", "entry", 2e-10, "lam", 1),
    Canary("multipliers", "four_bar", 3, "screw", "entry", 4e-10, "constraint_force", 2),
    Canary("multipliers", "four_bar", 3, "geometric", "entry", 2.5e-9, "power_constr"),
    Canary("multipliers", "double_pendulum_absolute_loop", 3, "operational_space", "entry", 3e-9, "lam", 3),
    Canary("multipliers", "double_pendulum_absolute_loop", 3, "newton_euler", "entry", 6e-9, "lam_drift", 2),
    Canary("charts", "double_pendulum", 3, "geometric", "mass matrix", 1.5e-11),
    Canary("charts", "spatial_arm", 27, "euler_lagrange", "mass matrix", 6e-10),
    Canary("charts", "ball_pendulum", 3, "geometric", "mass matrix", 8e-12),
    Canary("frames", "double_pendulum", 3, "screw", "mass matrix", 5e-11),
    Canary("frames", "spatial_arm", 27, "newton_euler", "mass matrix", 1e-10),
    Canary("frames", "spatial_arm", 27, "newton_euler", "gravity unrotated", 3e-10),
    Canary("frames", "spatial_arm", 27, "screw", "extra", 2e-6, "wrenches_space", key="frame law"),
    Canary("conservation", "double_pendulum", 3, "newton_euler", "gravity", 8e-11, key="energy"),
    Canary("conservation", "double_pendulum", 3, "pinocchio", "extra", 1e-9, "Cqd", key="C qd"),
    Canary("conservation", "free_body", 3, "screw", "velocity products", 1.5e-10, key="momentum"),
    Canary("linearization", "double_pendulum", 1, "newton_euler", "stiffness", 2e-11),
    Canary("linearization", "spatial_arm", 1, "screw", "stiffness", 4e-8),
    Canary("equilibria", "double_pendulum", 0, "euler_lagrange", "stiffness", 1.5e-9),
    Canary("conditions", "spatial_arm", 27, "screw", "condition", 4.5e-9, "task_inertia"),
    Canary("conditions", "four_bar", 3, "newton_euler", "condition", 4.5e-9, "constraint"),
    Canary("closed forms", "double_pendulum", 3, "", "mass", 8e-13, index=1),
    Canary("closed forms", "double_pendulum_circle", 2, "", "mass", 8e-12, index=0),
    Canary("file reference", "urdf_gripper", 3, "", "mass", 1.1e-12, index=1),
    Canary("coverage", "double_pendulum", 0, "", "sliver", index=1, key="sliver"),
    Canary("coverage", "spatial_arm", 0, "", "band", index=2, key="band"),
    Canary("coverage", "spatial_arm", 0, "", "repeated", key="repeat"),
    Canary("coverage", "panda", 0, "", "at the limits", index=3, key="limits"),
    Canary("coverage", "double_pendulum_circle", 0, "", "rates never sampled", key="rate"),
    Canary("file reading", "urdf_gripper", 0, "", "inertia turned", 1e-10, index=1, key="inertia"),
    Canary("file reading", "urdf_gripper", 0, "", "placement turned", 6e-12, index=2, key="placement rotation"),
    Canary("file reading", "urdf_gripper", 0, "", "limits misread", index=2, key="limits"),
)

#: Which comparisons of a state each check owns: a predicate on the key of ``outcome.comparisons`` (the quantities)
#: or ``outcome.checks`` (``"chart zyx: drift"``, ``"frame: total"``, ...), and which dictionary.
FAMILIES: dict[str, tuple[str, Callable[[str, Canary], bool]]] = {
    "comparisons": ("comparisons", lambda key, c: True),
    "multipliers": ("comparisons", lambda key, c: key == c.quantity),
    "closed forms": ("comparisons", lambda key, c: True),
    "file reference": ("comparisons", lambda key, c: True),
    "conditions": ("checks", lambda key, c: key.startswith("conditions: ")),
    "charts": ("checks", lambda key, c: key.startswith("chart ")),
    "frames": ("checks", lambda key, c: key.startswith(("frame: ", "frame law: "))),
    "conservation": ("checks", lambda key, c: key.startswith("conservation: ")),
    "linearization": ("checks", lambda key, c: key.startswith("linearization: ")),
    "equilibria": ("checks", lambda key, c: key.startswith("equilibrium ")),
}
CHECKS = (*FAMILIES, "coverage", "file reading")

#: A caught canary's error/tolerance ratio must stay below this: a check loosened by this factor misses it.
CALIBRATED = 10.0


def switched_on(check: str, checks: Checks) -> bool:
    """Whether the run ``checks`` runs the check ``check`` (a canary of a check switched off is not run)."""
    return {"charts": checks.charts, "frames": checks.frames > 0, "conservation": checks.conservation,
            "linearization": checks.linearization, "equilibria": checks.linearization,
            "closed forms": checks.closed_forms}.get(check, True)


@dataclass(frozen=True)
class CanaryResult:
    """A canary against its check: ``caught`` (a comparison of the check DISAGREEs), ``named`` (the vote points at the
    faulty voter, :func:`_points_at`: the canary's backend, or the closed form against a wrong model), the worst
    error/tolerance ratio of the check and ``where``, the comparison that had it. ``skipped`` says why a canary was
    not judged (its check is off in this run, or its backend already disagrees at the state without any fault: a real
    bug there, which the gate reports on its own cases); ``error``, the internal error that stopped it."""

    canary: Canary
    caught: bool
    named: bool
    ratio: float
    where: str
    skipped: str = ""
    error: str = ""

    @property
    def passed(self) -> bool:
        return not self.error and (bool(self.skipped) or (self.caught and self.named))


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
            check = r.canary.check
            if r.error:
                out.append(f"the {check} canary could not run ({r.canary.describe()}): internal error {r.error}")
            elif r.skipped:
                continue
            elif not r.caught:
                worst = "" if check == "coverage" else f" (worst error/tolerance {r.ratio:.3g})"
                out.append(f"the {check} check has lost its power: {r.canary.describe()} was not caught{worst}; a "
                           "check switched off, compared with itself, or loosened")
            elif not r.named:
                out.append(f"the vote failed in the {check} check: {r.canary.describe()} was caught ({r.where}, ratio "
                           f"{r.ratio:.3g}) but {_faulty_voter(r.canary)} was not named as its outlier")
        return out


def _faulty_voter(canary: Canary) -> str:
    return {"closed forms": "closed_form", "file reference": "pinocchio"}.get(canary.check, canary.backend)


# ------------------------------------------------------------------------------------------------- the faults


def _scale(split, quantity: str, qd: np.ndarray) -> float:
    """The size an ``entry`` fault of ``quantity`` is relative to (module doc)."""
    if quantity == "power_constr":
        return float(np.abs(np.asarray(split.constraint_force) * qd).sum())
    return float(np.abs(np.asarray(split.quantity(quantity), dtype=float)).max())


def inject(canary: Canary, split, reference=None, qd=None):
    """``split`` with the canary's fault; ``reference`` is the Pinocchio split at the same state (its ``extras`` M,
    C qd and g; for the ``velocity products`` and ``gravity`` kinds), ``qd`` the state's rates (``entry``)."""
    size, kind = canary.size, canary.kind
    if kind == "mass matrix":
        return dataclasses.replace(split, drift=split.drift / (1.0 + size), ctrl=split.ctrl / (1.0 + size),
                                   total=split.total / (1.0 + size))
    if kind in ("velocity products", "gravity"):
        force = reference.extras["Cqd" if kind == "velocity products" else "g"]
        shift = -size * np.linalg.solve(reference.extras["M"], force)
        return dataclasses.replace(split, drift=split.drift + shift, total=split.total + shift)
    if kind == "one entry":
        drift = np.array(split.drift)
        drift[0] += size * float(np.abs(drift).max())
        return dataclasses.replace(split, drift=drift)
    if kind == "entry":
        value = np.array(split.quantity(canary.quantity), dtype=float)
        value.flat[canary.index] += size * _scale(split, canary.quantity, np.asarray(qd, dtype=float))
        return dataclasses.replace(split, **{canary.quantity: value if value.ndim else float(value)})
    if kind == "multiplier sign":
        return dataclasses.replace(split, lam=-split.lam, lam_drift=-split.lam_drift)
    if kind == "not a number":
        drift = np.array(split.drift)
        drift[0] = np.nan
        return dataclasses.replace(split, drift=drift)
    if kind == "condition":
        return dataclasses.replace(split, conditions={**split.conditions, canary.quantity: (
            split.conditions[canary.quantity] * (1.0 + size))})
    if kind == "extra":
        return dataclasses.replace(split, extras={**split.extras, canary.quantity: (
            (1.0 + size) * np.asarray(split.extras[canary.quantity]))})
    raise ValueError(f"unknown canary kind '{kind}'")


def _unrotated(canary: Canary, moved, model):
    """The moved scene with its gravity turned back towards the unmoved scene's by the share ``size``."""
    gravity = np.asarray(moved.gravity, dtype=float)
    return dataclasses.replace(moved, gravity=gravity + canary.size * (np.asarray(model.gravity) - gravity))


def _stiffer(canary: Canary, lin: Linearization, nv: int) -> Linearization:
    A = np.array(lin.A)
    A[nv:, :nv] *= 1.0 + canary.size
    return dataclasses.replace(lin, A=A)


def faulty(canary: Canary, backend: Formalism, model) -> Formalism:
    """``backend`` with the canary's fault where its check looks (module doc); ``model`` is the case's (unmoved)
    model (the canary's state is evaluated alone: no block form is used)."""
    reference = backend_registry.get("pinocchio")

    def split(m, q, qd, u):
        if canary.check == "frames" and m is model:
            return backend.split(m, q, qd, u)
        if canary.kind == "gravity unrotated":
            return backend.split(_unrotated(canary, m, model), q, qd, u)
        answer = backend.split(m, q, qd, u)
        needs = canary.kind in ("velocity products", "gravity")
        return inject(canary, answer, reference.split(m, q, qd, u) if needs else None, qd)

    if canary.check == "charts":
        return dataclasses.replace(backend, split_chart=lambda *args: inject(
            canary, backend.split_chart(*args)))
    if canary.check in ("linearization", "equilibria"):
        return dataclasses.replace(backend, linearize=lambda m, q, v, u: _stiffer(
            canary, backend.linearize(m, q, v, u), m.nv))
    return dataclasses.replace(backend, split=split)


# ------------------------------------------------------------------------------------------------- judging


def _family(canary: Canary, outcome) -> dict:
    where, owns = FAMILIES[canary.check]
    return {key: c for key, c in getattr(outcome, where).items() if owns(key, canary) and canary.key in key}


def _points_at(comparison, voter: str) -> bool:
    """Whether the vote names ``voter``: its outlier, or the one voter behind a comparison of its own answers (a frame
    law: its prediction against its moved answer)."""
    if comparison.outlier is not None:
        return backend_of(comparison.outlier) == voter
    return {backend_of(v) for v in comparison.voters} == {voter}


def _judge(canary: Canary, outcome) -> CanaryResult:
    """Whether the canary's check caught it at ``outcome`` (the state evaluated with the fault) and named its
    voter."""
    found = _family(canary, outcome)
    failing = {key: c for key, c in found.items() if c.verdict == DISAGREE}
    pool = failing or found
    where = max(pool, key=lambda k: np.nan_to_num(pool[k].worst_ratio, nan=np.inf), default="-")
    ratio = pool[where].worst_ratio if pool else 0.0
    voter = _faulty_voter(canary)
    named = any(_points_at(c, voter) for c in failing.values())
    return CanaryResult(canary, bool(failing), named, float(ratio), where)


def _setup(canary: Canary) -> CaseSetup:
    """The canary's case set up with its check switched on (and the others off, as far as they can be)."""
    check = canary.check
    return CaseSetup.build(CaseSpec(canary.case), SEED, Checks(
        charts=check == "charts", frames=1 if check == "frames" else 0, conservation=check == "conservation",
        closed_forms=True, self_test=False, linearization=check in ("linearization", "equilibria")))


def _clean(canary: Canary, setup: CaseSetup, state: State, chosen: Sequence[Formalism]):
    """The backends the canary can be judged among: ``chosen`` without the one backend that disagrees in the canary's
    check at the state without any fault (named by the vote: a real bug, which the gate reports on its own cases); None
    when the state disagrees there and no single backend explains it, or the vote blames the closed form or the exact
    values (shared code every backend moves with: a model, a check)."""
    outcome = setup.evaluate(state, chosen)
    blamed = {suspect(c) for c in _family(canary, outcome).values() if c.verdict == DISAGREE}
    blamed |= {backend_of(name) for name in outcome.errors}
    if None in blamed or len(blamed) > 1 or not blamed <= {b.name for b in chosen}:
        return None
    return [b for b in chosen if b.name not in blamed]


def _model_canary(canary: Canary, setup: CaseSetup, state: State, chosen: Sequence[Formalism]) -> CanaryResult:
    """A closed-forms or file-reference canary: the model every backend reads with body ``index``'s mass off (module
    doc); the backends evaluated are those that prepare nothing for a new model (no symbolic derivation), with the
    case's closed form."""
    bodies = list(setup.model.bodies)
    body = bodies[canary.index]
    bodies[canary.index] = dataclasses.replace(body, mass=body.mass * (1.0 + canary.size))
    wrong = dataclasses.replace(setup.model, bodies=tuple(bodies))
    numeric = [b for b in chosen if b.preparation is None and b.prepare is None]
    outcome = dataclasses.replace(setup, model=wrong).evaluate(state, numeric)
    return _judge(canary, outcome)


def _coverage_canary(canary: Canary) -> CanaryResult:
    """A coverage canary: the case's gate sample (``crosscheck.engine.specs.DEFAULT_SAMPLES`` states) made degenerate
    by the canary's kind; caught when coverage names a problem."""
    from crosscheck.engine.specs import DEFAULT_SAMPLES

    model = cases.load(canary.case)
    states = _degenerate(canary, model, sample_states(model, DEFAULT_SAMPLES, SEED, canary.case))
    problems = [p for p in coverage.measure(model, states).problems if canary.key in p]
    return CanaryResult(canary, bool(problems), bool(problems), 0.0, problems[0] if problems else "-")


#: The axis a ``file reading`` canary turns an inertia or a placement about (oblique: every entry moves).
TURN_AXIS = np.array([1.0, 2.0, 3.0]) / np.sqrt(14.0)


def _turn(angle: float) -> np.ndarray:
    """The rotation by ``angle`` about :data:`TURN_AXIS` (Rodrigues' formula)."""
    K = np.array([[0.0, -TURN_AXIS[2], TURN_AXIS[1]], [TURN_AXIS[2], 0.0, -TURN_AXIS[0]],
                  [-TURN_AXIS[1], TURN_AXIS[0], 0.0]])
    return np.eye(3) + np.sin(angle) * K + (1.0 - np.cos(angle)) * K @ K


def _misread(canary: Canary, body):
    """``body`` as a loader that misreads it by the canary's kind would convert it (module doc)."""
    if canary.kind == "inertia turned":
        Q = _turn(canary.size)
        return dataclasses.replace(body, inertia=Q @ body.inertia @ Q.T)
    if canary.kind == "placement turned":
        return dataclasses.replace(body, rotation=_turn(canary.size) @ body.rotation)
    if canary.kind == "limits misread":
        return dataclasses.replace(body, limits=tuple(np.degrees(body.limits)))
    raise ValueError(f"unknown file reading canary kind '{canary.kind}'")


def _file_reading_canary(canary: Canary) -> CanaryResult:
    """A file reading canary: the case's model with body ``index`` misread (:func:`_misread`), checked against its
    file read apart from the loader as the gate checks it (``crosscheck.guards.loader``); caught when a loader finding
    concerns the field ``key``, named when it names the body's link."""
    model = cases.load(canary.case)
    bodies = list(model.bodies)
    body = bodies[canary.index]
    bodies[canary.index] = _misread(canary, body)
    checked = loader.check(dataclasses.replace(model, bodies=tuple(bodies)))
    found = [f for f in (checked.findings if checked else ()) if canary.key in f.field]
    named = [f for f in found if f.link == body.name]
    ratio = max((f.ratio for f in named or found), default=0.0)
    where = str((named or found)[0]) if found else "-"
    return CanaryResult(canary, bool(found), bool(named), ratio, where)


def _degenerate(canary: Canary, model, states: Sequence[State]) -> list[State]:
    """``states`` made degenerate by the canary's kind (module doc)."""
    k = canary.index
    if canary.kind == "repeated":
        return [dataclasses.replace(states[1], index=s.index) for s in states]
    if canary.kind == "rates never sampled":
        return [dataclasses.replace(s, qd=(0.0,) * len(s.qd)) for s in states]
    if canary.kind == "at the limits":
        read = file_limits.read(model)            # the limits the coverage judges against: the file's, read apart
        lower, upper = read.limits[k] if read and read.limits else model.bodies[k].limits
        iq = model.q_index[k]
        return [dataclasses.replace(s, q=s.q[:iq] + (lower if s.index % 2 else upper,) + s.q[iq + 1:])
                if s.index % AT_LIMITS_EVERY == 1 else s for s in states]
    if canary.kind in ("sliver", "band"):
        centre = states[0].q[k]
        shrink = SLIVER_WIDTH * coverage.REVOLUTE_SPAN / max(np.ptp([s.q[k] for s in states]), 1e-300)
        kept = (lambda s: s.index % BAND_SPREAD == 0) if canary.kind == "band" else (lambda s: False)
        return [s if kept(s) else dataclasses.replace(s, q=s.q[:k] + (centre + (s.q[k] - centre) * shrink,)
                                                      + s.q[k + 1:]) for s in states]
    raise ValueError(f"unknown coverage canary kind '{canary.kind}'")


def _one(canary: Canary, chosen: Sequence[Formalism], evaluated: dict) -> CanaryResult | str:
    """The canary's result, or the name of its state when the state is unusable."""
    if canary.check == "coverage":
        return _coverage_canary(canary)
    if canary.check == "file reading":
        return _file_reading_canary(canary)
    setup = _setup(canary)
    state = sample_states(setup.model, canary.state + 1, SEED, canary.case)[canary.state]
    if canary.check in ("closed forms", "file reference"):
        return _model_canary(canary, setup, state, chosen)
    key = (canary.case, canary.state, canary.check)
    if key not in evaluated:
        evaluated[key] = _clean(canary, setup, state, chosen)
    kept = evaluated[key]
    if kept is None:
        return f"{canary.case} #{canary.state} ({canary.check})"
    if canary.backend not in [b.name for b in kept]:
        return CanaryResult(canary, False, False, 0.0, "-", f"{canary.backend} disagrees at this state without a "
                            "fault")
    backends = [faulty(canary, b, setup.model) if b.name == canary.backend else b for b in kept]
    return _judge(canary, setup.evaluate(state, backends))


def run(canaries: Iterable[Canary] | None = None, backends=None, checks: Checks = Checks()) -> SelfTest:
    """Judge each canary (:data:`CANARIES` by default) whose check ``checks`` switches on (the others are listed as
    skipped) among ``backends`` (default: every built-in backend, whatever the run's): its state evaluated once clean
    (a backend that disagrees there without a fault is left out, :func:`_clean`), then with the fault. An exception
    of the harness while a canary runs is that canary's internal error, never the run's end."""
    chosen = ([backend_registry.get(name) for name in backend_registry.builtin_names()] if backends is None
              else list(backends))
    results, evaluated, unusable = [], {}, []
    for canary in CANARIES if canaries is None else canaries:
        if not switched_on(canary.check, checks):
            results.append(CanaryResult(canary, False, False, 0.0, "-", f"the {canary.check} check is off"))
            continue
        try:
            found = _one(canary, chosen, evaluated)
        except Exception as exc:  # noqa: BLE001 - the harness failing in a canary is reported, by check
            found = CanaryResult(canary, False, False, 0.0, "-", error=str(internal.of(exc)))
        if isinstance(found, str):
            unusable += [found] if found not in unusable else []
        else:
            results.append(found)
    return SelfTest(tuple(results), tuple(unusable))
