"""Hints from the shape of an error: where a disagreement sits and how it scales say which terms are wrong.

At a failing state the drift/control split is re-evaluated at the same q with the velocity scaled (qd x 0 and
qd x 2; still admissible for a constrained state, since ``Jc qd = 0`` is linear), with the inputs off (u = 0) and
on the scene without gravity. The error is the max-norm distance of the suspect (the backend the vote names) from
the median of the others, or the spread of all voters when none is named. Per article eq. (9),
``drift = -M^-1 (C qd + g)`` and ``ctrl = M^-1 B u``, so:

- an error that grows like ``|qd|^2`` and vanishes at qd = 0 is in the velocity-product terms (``C qd``: Coriolis,
  centrifugal, gyroscopic; ``Jcdot qd`` with constraints);
- one that doubles with qd and vanishes at qd = 0 is a force linear in qd, ``-c qd``: damping or viscous friction,
  which is no term of the rigid-body equation (a simulator's joint damping left on, a friction model in the
  dynamics code), not the mass matrix;
- one independent of qd that vanishes without gravity is in ``g``; one that persists is in the inertia;
- one in ctrl while the drift agrees is in the input map (``B``, or the solve of ``M^-1 B u``); one in ctrl and in
  the drift or the kinetic energy is in what they share, M (and the constraint projection, eq. 17);
- a small error in M itself (an inertia rounded in a late digit) may leave the drift within its tolerance and show
  in ctrl, the kinetic energy or the total alone. For any M the ctrl ``a = M^-1 B u`` has ``a . M a = a . B u``, so
  at qd along the suspect's own ctrl twice its kinetic energy equals its own work ``a . B u`` while it differs from
  the others' when its energy and its dynamics share one M that is not theirs (:func:`own_mass_matrix`): that names
  M. An error in the energy bookkeeping alone misses its own work too; one in B alone leaves its energy with the
  others';
- one only in the constrained quantities is in the multipliers or the constraint kinematics (article 5); a value
  that is a constant multiple of the others' (-1: a sign) is a convention slip;
- one only in a chart or frame check is in the chart map or the frame transformation (9.1, 7.4);
- one only in the joint loads (``joint_wrenches``, article 6.1.5) while the accelerations agree is in the backward
  pass (the wrench recursion); one only in ``task_inertia`` is in J or the inverse of ``J M^-1 J^T`` (eq. 22).
  When an acceleration fails too, the loads and Lambda follow from it and the accelerations classify the error.
- the reference alone against every formalism on a model loaded from a file (the reference read the file itself,
  the formalisms our conversion of it: ``crosscheck.references.pinocchio.reference``) points at the conversion, not at
  the formalisms.
"""

from __future__ import annotations

from collections import Counter
from typing import Mapping, Sequence

import numpy as np

import cases
from cases.model import Model
from crosscheck.backends import REFERENCE_NAME
from crosscheck.core.compare import DISAGREE, Comparison, suspect
from crosscheck.core.tolerance import CONSTRAINED_QUANTITIES
from crosscheck.engine.internal import guarded
from crosscheck.engine.outcomes import GateResult, StateOutcome
from formalisms.interface import Formalism, Split, Unsupported

#: An error "vanishes" in a variant when it falls below the tolerance or this fraction of the error at the state.
VANISHED = 1e-3
#: Ratios read as "unchanged" (independent of qd) and as "grows like |qd|^2" when qd doubles.
UNCHANGED = (0.8, 1.25)
QUADRATIC = (3.0, 5.0)
#: Ratios read as "grows like |qd|" when qd doubles (a force linear in qd).
LINEAR = (1.6, 2.5)

VELOCITY = "velocity-product terms (Coriolis/centrifugal, gyroscopic, Jcdot qd)"
GRAVITY = "gravity"
INERTIA = "inertia / mass matrix"
DAMPING = ("a force linear in qd, -c qd (damping, viscous friction): no term of M qdd + C qd + g = B u; turn joint "
           "damping off in the backend's model")


def without_gravity(model: Model) -> Model:
    """The same model with gravity switched off (its external loads kept: only gravity differs); a file source is kept,
    marked gravity-free, so that the reference and a plugin that reads the file (``crosscheck.backends``, "What a
    plugin needs") see the same scene."""
    source = None if model.source is None else model.source.without_gravity()
    return cases.build_model(f"{model.name} without gravity", model.bodies, gravity=np.zeros(3),
                             input_map=model.input_map, task_points=model.task_points, constraints=model.constraints,
                             source=source, loads=model.loads)


def _value(split: Split, quantity: str) -> np.ndarray | None:
    value = split.quantity(quantity)
    return None if value is None or isinstance(value, Unsupported) else np.atleast_1d(np.asarray(value, float))


def error(splits: Mapping[str, Split], quantity: str, who: str | None) -> float:
    """Max-norm distance of ``who`` from the median of the others on ``quantity``, or (``who`` None or absent) the
    largest distance between any two of ``splits``."""
    values = {name: v for name, split in splits.items() if (v := _value(split, quantity)) is not None}
    if len(values) < 2:
        return float("nan")
    if who in values:
        others = np.median([v for name, v in values.items() if name != who], axis=0)
        return float(np.abs(values[who] - others).max())
    stacked = np.array(list(values.values()))
    return float((stacked.max(axis=0) - stacked.min(axis=0)).max())


class Probe:
    """The voters re-evaluated at variants of one state, each variant computed once."""

    def __init__(self, model: Model, outcome: StateOutcome, backends: Sequence[Formalism], who: str | None):
        self.model, self.outcome, self.who = model, outcome, who
        self.backends = [b for b in backends if b.name in outcome.trusted]
        self._cache: dict[tuple, dict[str, Split]] = {}
        self._bare: Model | None = None

    def splits(self, qd_scale: float = 1.0, u_scale: float = 1.0, gravity: bool = True,
               qd: tuple[float, ...] | None = None, u: tuple[float, ...] | None = None) -> dict[str, Split]:
        """Every voter at (q, qd_scale qd, u_scale u), the state's qd and u or the ones given, on the scene with or
        without gravity; a backend raising there is left out of the measurement (the state's own report shows its
        errors)."""
        key = (qd_scale, u_scale, gravity, qd, u)
        if key == (1.0, 1.0, True, None, None):
            return self.outcome.trusted
        if key not in self._cache:
            if not gravity and self._bare is None:
                self._bare = without_gravity(self.model)
            model = self.model if gravity else self._bare
            s = self.outcome.state
            q = np.array(s.q)
            qd = qd_scale * np.array(s.qd if qd is None else qd, dtype=float)
            u = u_scale * np.array(s.u if u is None else u, dtype=float)
            found = {}
            for backend in self.backends:
                try:
                    found[backend.name] = backend.split(model, q, qd, u)
                except Exception:  # a variant a backend cannot evaluate gives no number, not a crash
                    continue
            self._cache[key] = found
        return self._cache[key]

    def error(self, quantity: str, **variant) -> float:
        voters = self.outcome.voters(quantity)
        return error({n: s for n, s in self.splits(**variant).items() if n in voters}, quantity, self.who)


def proportion(splits: Mapping[str, Split], quantity: str, who: str | None, tol: float) -> float | None:
    """The factor k with ``who``'s value = k times the median of the others' to within ``tol`` (a sign or scale
    slip), or None when ``who`` is not named or the values are not proportional."""
    values = {name: v for name, split in splits.items() if (v := _value(split, quantity)) is not None}
    if who not in values or len(values) < 2:
        return None
    ref = np.median([v for name, v in values.items() if name != who], axis=0)
    size = float(ref @ ref)
    if size == 0.0:
        return None
    k = float(values[who] @ ref) / size
    return k if float(np.abs(values[who] - k * ref).max()) <= tol else None


def _vanished(value: float, at_state: float, tol: float) -> bool:
    return value <= max(tol, VANISHED * at_state)


def _times(value: float, at_state: float, tol: float) -> str:
    """``0`` when the error vanished, else its multiple of the error at the state (``x4``); "not measurable" when
    either is NaN or the error at the state is 0 or inf (an inf there would make every variant look vanished)."""
    if not (value == value and 0.0 < at_state < np.inf):
        return "not measurable"
    return "0" if _vanished(value, at_state, tol) else f"x{value / at_state:.3g}"


def _between(value: float, at_state: float, band: tuple[float, float]) -> bool:
    return band[0] * at_state <= value <= band[1] * at_state


def _shape(probe: Probe, quantity: str, tol: float) -> tuple[str, str]:
    """(measurements, cause) for a quantity whose error may come from velocity products or gravity: the drift
    family, which at qd = 0 without gravity is zero for every backend."""
    e1 = probe.error(quantity)
    e0, e2 = probe.error(quantity, qd_scale=0.0), probe.error(quantity, qd_scale=2.0)
    eg = probe.error(quantity, gravity=False)
    text = (f"error {_times(e2, e1, tol)} when qd doubles, {_times(e0, e1, tol)} at qd = 0, "
            f"{_times(eg, e1, tol)} without gravity")
    if _vanished(e0, e1, tol) and _between(e2, e1, QUADRATIC):
        return text, VELOCITY
    if _vanished(e0, e1, tol) and _between(e2, e1, LINEAR):
        return text, DAMPING
    if _between(e2, e1, UNCHANGED) and _between(e0, e1, UNCHANGED):
        if _vanished(eg, e1, tol):
            return text, GRAVITY
        return text, f"{INERTIA} (a qd-independent error that persists without gravity)"
    return text, ("both velocity-product and gravity parts, so a factor they share: the mass matrix solve"
                  + (" or the constraint solve" if probe.model.constraints else ""))


def _ctrl_shape(probe: Probe, tol: float, total_tol: float) -> str:
    e1 = probe.error("ctrl")
    e2, eg = probe.error("ctrl", qd_scale=2.0), probe.error("ctrl", gravity=False)
    at_rest = probe.error("total", u_scale=0.0)
    return (f"ctrl error {_times(e2, e1, tol)} when qd doubles, {_times(eg, e1, tol)} without gravity; "
            f"total error {_times(at_rest, probe.error('total'), total_tol)} at u = 0")


#: How many times farther the suspect's kinetic energy at its own ctrl must be from the others' than from the work of
#: the input along that ctrl (and than the others' spread) for :func:`own_mass_matrix` to name its M.
OWN_M = 10.0


def own_mass_matrix(probe: Probe) -> str:
    """The measured evidence that the suspect's mass matrix differs from the others', in words; "" when there is none.

    For any M, the ctrl ``a = M^-1 B u`` satisfies ``a . M a = a . B u``: twice the kinetic energy at velocity a is
    the input's work along it (with constraints too, since ``Jc a = 0``). So at qd = a' (the suspect's ctrl,
    rescaled to the state's speed) a suspect whose energy and ctrl come from one M' != M has ``2T' = a' . B u`` to
    rounding, while the others' ``2T`` differs by ``a' . (M' - M) a'``. A wrong input map or a wrong solve leaves its
    energy with the others'; a wrong energy bookkeeping (the body twists) leaves it off its own work too. Measured
    with the state's u and with ``u = B^T qd`` (the input that works along the state's own velocity, where the
    energy was compared: the state's u may barely move the body whose inertia is off); named when, for one of
    them, the distance to the others is :data:`OWN_M` times the residual of its own work and the others' spread."""
    if probe.who is None:
        return ""
    state = probe.outcome.state
    for u in (tuple(state.u), tuple((probe.model.input_map.T @ np.asarray(state.qd, dtype=float)).tolist())):
        found = _work_and_energy(probe, u)
        if found:
            return found
    return ""


def _work_and_energy(probe: Probe, u: tuple[float, ...]) -> str:
    """:func:`own_mass_matrix` with the input ``u``."""
    who, state = probe.who, probe.outcome.state
    split = probe.splits(u=u).get(who)
    a = _value(split, "ctrl") if split is not None else None
    if a is None or not np.all(np.isfinite(a)) or not a.any():
        return ""
    qd = np.asarray(state.qd, dtype=float)
    speed = float(np.linalg.norm(qd)) / float(np.linalg.norm(a)) if qd.any() else 1.0
    work = speed**2 * float(a @ (probe.model.input_map @ np.asarray(u, dtype=float)))     # 2T at speed * a
    voters = probe.outcome.voters("kinetic_energy")
    twice = {name: 2.0 * float(e[0]) for name, found in probe.splits(qd=tuple((speed * a).tolist()), u=u).items()
             if name in voters and (e := _value(found, "kinetic_energy")) is not None}
    others = [e for name, e in twice.items() if name != who]
    if who not in twice or len(others) < 2 or work == 0.0:
        return ""
    off, own = abs(twice[who] - float(np.median(others))), abs(twice[who] - work)
    if not off > OWN_M * max(own, max(others) - min(others)):
        return ""
    return (f"at qd along its own ctrl, {who}'s 2T equals its own work ctrl . B u to {own / abs(work):.2g} "
            f"but differs from the others' by {off / abs(work):.2g} (relative): its energy and its ctrl share one M "
            "that is not the others'")


CHART_MAP = "the chart map (Dpsi, its rate, the covector map Dpsi^T)"
FRAME_MOVE = "the frame transformation (the moved scene, Ad_g, Ad_g^-T)"


def _check_hint(failing: Mapping[str, Comparison]) -> str:
    """Only chart, frame or conservation checks fail: the maps, not the dynamics."""
    families = sorted({key.split(":")[0] for key in failing})
    shared = sorted({c.shared for c in failing.values() if c.shared is not None and c.outlier == c.shared})
    named = Counter(who for c in failing.values() if (who := suspect(c)) is not None and who not in shared)
    keys = ", ".join(sorted(failing)[:4]) + (", ..." if len(failing) > 4 else "")
    if shared and not named:     # the vote named code every backend shares (crosscheck.core.compare, shared code)
        return (f"only in a chart or frame check ({keys}); pointing at the {' and the '.join(shared)} (shared code) — "
                "every backend moves together: " + " or ".join(
                    ([CHART_MAP] if any(s.startswith("chart") for s in shared) else [])
                    + ([FRAME_MOVE] if any(s.startswith("frame") for s in shared) else [])) + ", not a backend")
    causes = []
    if any(f.startswith("chart") for f in families):
        causes.append(CHART_MAP if not named else "a chart-native evaluation")
    if any(f.startswith("frame") for f in families):
        causes.append(FRAME_MOVE)
    if "conservation" in families:
        causes.append("the energy bookkeeping or the Christoffel symbols")
    who = f"pointing at {', '.join([*shared, *named])}" if named else "no single backend named"
    where = "a chart or frame check" if "conservation" not in families else "invariance or conservation checks"
    return f"only in {where} ({keys}); {who}: {' or '.join(causes)}"


def _suspect(failing: Mapping[str, Comparison], voters: Mapping[str, Split]) -> str | None:
    """The backend most disagreements at the state point at, when it is one of the voters."""
    named = Counter(who for c in failing.values() if (who := suspect(c)) is not None and who in voters)
    return min(named, key=lambda name: (-named[name], name)) if named else None


def hint(model: Model, outcome: StateOutcome, backends: Sequence[Formalism]) -> str:
    """One sentence on what the shape of the error at a failing ``outcome`` suggests, with the measured numbers;
    empty when nothing disagrees (a backend error only)."""
    failing = {q: c for q, c in outcome.comparisons.items() if c.verdict == DISAGREE}
    if not failing:
        checks = {k: c for k, c in outcome.checks.items() if c.verdict == DISAGREE}
        return _check_hint(checks) if checks else ""
    if any(q in ACCELERATIONS for q in failing):
        failing = {q: c for q, c in failing.items() if q not in DERIVED}
    if all(c.outlier == "exact" for c in failing.values()):
        return (f"the backends agree with each other against the exact value in {', '.join(failing)}: the state "
                "(not admissible?) or the exact claim, not a backend")
    if all(c.outlier == "closed_form" for c in failing.values()):
        return (f"every backend and the reference agree with each other against the article's closed form in "
                f"{', '.join(failing)}: suspect code they all share (the model or its constraint declarations, the "
                "interface constants, the harness) or the closed form itself, not one backend")
    who = _suspect(failing, outcome.trusted)
    names = ", ".join(failing)
    if who == REFERENCE_NAME and model.source is not None:
        return (f"all formalisms agree against the reference built from the file {model.source.path} ({names}): "
                f"suspect the model conversion (cases/{model.source.kind}.py), not the formalisms")
    probe = Probe(model, outcome, backends, who)
    subject = f"{who}'s" if who else "the voters' spread in"
    tol = {q: c.tolerance for q, c in outcome.comparisons.items()}
    if set(failing) <= set(CONSTRAINED_QUANTITIES):
        first = next(q for q in CONSTRAINED_QUANTITIES if q in failing)
        where = f"only in constrained quantities ({names}): the multipliers or the constraint kinematics"
        k = proportion(outcome.voters(first), first, who, tol[first])
        if k is not None:
            return f"{where}; {who}'s {first} is {k:.3g} times the others': a sign or scale convention"
        text, cause = _shape(probe, first, tol[first])
        return f"{where} (phi, Jc, Jcdot qd); {subject} {first} {text}: {cause}"
    if "external_force" in failing:
        return (f"{subject} tau_ext itself is off ({names}): the external loads' mapping (cases.loads): the frame of "
                "a force or couple (world or body), its point or lever (the moment about the body origin), a spring's "
                "force")
    if "ctrl" in failing:
        k = proportion(outcome.voters("ctrl"), "ctrl", who, tol["ctrl"])
        scaled = f"; {who}'s ctrl is {k:.3g} times the others'" if k is not None else ""
        shape = f"{subject} {_ctrl_shape(probe, tol['ctrl'], tol['total'])}{scaled}"
        if "drift" in failing or "kinetic_energy" in failing:
            both = "drift" if "drift" in failing else "kinetic energy"
            shared = ", with the constraint projection" if model.constraints else ""
            return f"{both} and ctrl both off; {shape}: {INERTIA} (M is what {both} and ctrl share{shared})"
        own = own_mass_matrix(probe)
        if own:
            return f"only in ctrl ({names}; drift agrees); {shape}; {own}: {INERTIA}"
        return f"only in ctrl ({names}; drift agrees); {shape}: the input map B or M^-1 B u"
    if "drift" in failing:
        text, cause = _shape(probe, "drift", tol["drift"])
        return f"{subject} drift {text}: {cause}"
    if "total" in failing or "additivity" in failing:
        own = own_mass_matrix(probe)
        if own:
            return f"drift and ctrl agree but the total does not ({names}); {own}: {INERTIA}"
        return f"drift and ctrl agree but the total does not ({names}): the total solve (drift + ctrl != total)"
    if "task_drift" in failing:
        text, cause = _shape(probe, "task_drift", tol["task_drift"])
        return (f"only the task acceleration ({names}): the task-point kinematics (J, Jdot qd); {subject} {text}: "
                f"{cause}")
    own = own_mass_matrix(probe) if "kinetic_energy" in failing else ""
    if own:
        return f"only in {names} (the accelerations agree); {own}: {INERTIA}"
    causes = dict.fromkeys(ALONE.get(q, f"the {q} bookkeeping") for q in failing)
    return f"only in {names} (the accelerations agree): " + "; ".join(causes)


#: Accelerations (and multipliers): when one of them fails, it classifies the error.
ACCELERATIONS = ("drift", "ctrl", "total", "additivity", "task_drift", "lam", "lam_drift")
#: Quantities computed from the accelerations (the joint loads, article 6.1.5) or from J and M (Lambda, eq. 22):
#: left out of the classification when an acceleration fails too.
DERIVED = ("joint_wrenches", "joint_wrenches_drift", "task_inertia")

LOADS = "the joint load bookkeeping: the backward pass (the wrench recursion from the leaves to the root)"
#: What a quantity failing while every acceleration agrees points at.
ALONE = {"power_ctrl": "the input power u . B^T qd (the input map in the power)",
         "kinetic_energy": "the kinetic energy bookkeeping (M, or the body twists)",
         "joint_wrenches": LOADS,
         "joint_wrenches_drift": LOADS,
         "task_inertia": "the task-space inertia: J, or the inverse of J M^-1 J^T (eq. 22)",
         "power_ext": "the external loads' power tau_ext . qd"}


#: Failing states per run that get a hint (the report lists the same first ones in detail).
HINTED_STATES = 20


def annotate(result: GateResult, backends: Sequence[Formalism], limit: int = HINTED_STATES) -> int:
    """Set ``hint`` on the first ``limit`` failing states of ``result`` (run order); returns how many. The harness
    failing in a hint is that state's internal error ``diagnosis hint`` (``crosscheck.engine.internal``)."""
    failing = [(case, state) for case in result.cases for state in case.states if state.failed][:limit]
    for case, state in failing:
        with guarded(state.internal, "diagnosis hint"):
            state.hint = hint(case.model, state, backends)
    return len(failing)
