"""Chart and frame invariance checks at one state (article 6.4.6, 7.4, 9.1; docs/design.md, charts and frames).

Each check is a :class:`~crosscheck.core.compare.Comparison` keyed ``"<family> <name>: <quantity>"``, so the gate,
the outlier vote and the report treat it like any cross-backend comparison.

Chart invariance. The state ``(q, qd, u)`` is expressed in the chart: ``p = psi^-1(q)``, ``pd = Dpsi^-1 qd``
(for a model with spherical or free joints, ``Dpsi`` maps pd to the velocity v, ``crosscheck.checks.charts.EulerZYX``
and ``crosscheck.checks.charts.ExponentialCoordinates``; a state where ``cond(Dpsi)`` exceeds ``charts.GIMBAL_LIMIT``,
zyx's gimbal lock, has no chart check; exp's ``cond(Dpsi)`` is at most pi/2 on its domain; a base-velocity
representation, ``charts.VelocityRepresentation``, has ``p = q`` and ``Dpsi = T(q)``, ``v = T w``)
and the generalized force ``tau_p = Dpsi^T B u`` (a covector). Every backend with ``split_chart`` evaluates in p
directly; every joint-chart answer is mapped by ``pdd = Dpsi^-1 (qdd - (d/dt Dpsi) pd)`` (the control part,
linear in u, by ``Dpsi^-1`` alone). All must agree; power, kinetic energy and the task-space inertia must equal
the joint-chart ones. A quantity no chart-capable backend supplies in the chart is not checked there.

Frame invariance. Every backend evaluates the scene moved by g (``crosscheck.checks.frames``) at the same state. Joint
quantities (accelerations, power, kinetic energy, task accelerations and the task-space inertia in the rotated task
directions, body-frame joint loads) must equal the unmoved ones; extras transform by their law in
:data:`FRAME_LAWS` (world twists by ``Ad_g``, world wrenches by ``Ad_g^-T``, body-frame quantities unchanged).
"""

from __future__ import annotations

import dataclasses
from typing import Mapping, Sequence

import numpy as np

from cases.model import Model
from crosscheck.checks import charts, frames
from crosscheck.core import tolerance
from crosscheck.core.compare import compare, Comparison, DISAGREE
from crosscheck.core.sampling import State
from formalisms.interface import Formalism, Split, Unsupported

EPS = tolerance.EPS

#: Quantities checked for invariance under a chart change and under a frame change. The joint loads are body-frame
#: quantities and Lambda is in task coordinates (whose directions turn with a moved scene), so neither depends on
#: the chart or the world frame; a chart check runs only for a quantity some chart-native backend supplies (else
#: it would repeat the joint-chart comparison), so the loads are checked under frame changes only.
INVARIANT = ("drift", "ctrl", "total", "additivity", "power_ctrl", "kinetic_energy", "task_drift", "task_inertia",
             "joint_wrenches", "joint_wrenches_drift")

#: With constraints, also: the multipliers and phi are invariant (phi(psi(p)) and the moved declarations are the
#: same functions), the constraint force ``Jc^T lam`` is a covector (``Dpsi^T`` into a chart, invariant under a
#: frame change), and the constraint power is invariant (article 5.5: only the total is coordinate-free).
CONSTRAINED_INVARIANT = ("lam", "lam_drift", "constraint_force", "constraint_force_drift", "power_constr",
                         "constraint_value")


#: With external loads (``cases.loads``), also: ``tau_ext`` is a covector (``Dpsi^T`` into a chart, invariant under a
#: frame change: the moved scene moves the loads' world data with it) and its power is invariant.
LOADED_INVARIANT = ("external_force", "power_ext")


def _invariant(model: Model) -> tuple[str, ...]:
    return (INVARIANT + (CONSTRAINED_INVARIANT if model.constraints else ())
            + (LOADED_INVARIANT if model.loads else ()))


def _votes(split: Split, quantity: str) -> bool:
    """Whether ``split`` votes on ``quantity`` (not left out by a narrow BREAKDOWN, e.g. non-unique multipliers)."""
    return quantity not in tolerance.left_out(tolerance.breakdown(split))

#: extra name -> how its rows transform under a frame change: the name of the 6x6 map in ``crosscheck.checks.frames``
#: (looked up when used), or None for a quantity that does not change (body-frame rows).
FRAME_LAWS: dict[str, str | None] = {
    "twists_space": "twist_map",
    "accelerations_space": "twist_map",
    "wrenches_space": "wrench_map",
    "twists_body": None,
    "wrenches_body": None,
    "wrenches_body_drift": None,
    "joint_reactions": None,
    "joint_reactions_drift": None,
    "joint_reactions_world": "force_moment_map",
    "constraint_wrenches_space": "wrench_map",
    "constraint_wrenches_space_drift": "wrench_map",
}


def mapped(chart: charts.Chart, p, pd, split: Split, quantity: str, done: dict | None = None):
    """A joint-chart answer expressed in the chart; ``done`` keeps the maps already made for this split (the
    additivity is the mapped drift plus the mapped ctrl minus the mapped total, each mapped once)."""
    done = {} if done is None else done
    if quantity in done:
        return done[quantity]
    if quantity in ("drift", "total"):
        value = charts.acceleration_to_chart(chart, p, pd, split.quantity(quantity))
    elif quantity == "ctrl":
        value = charts.acceleration_to_chart(chart, p, pd, split.ctrl, with_rate=False)
    elif quantity == "additivity":
        value = (mapped(chart, p, pd, split, "drift", done) + mapped(chart, p, pd, split, "ctrl", done)
                 - mapped(chart, p, pd, split, "total", done))
    elif quantity in ("constraint_force", "constraint_force_drift", "external_force"):
        value = charts.force_to_chart(chart, p, split.quantity(quantity))
    else:
        value = split.quantity(quantity)     # power, energy, task accelerations, multipliers, phi: no map
    done[quantity] = value
    return value


class _AtPoint:
    """``chart`` for the maps of one chart check (``crosscheck.checks.charts``, in its place): ``Dpsi`` at ``p`` and
    ``(d/dt Dpsi) pd`` evaluated once, on first use, for the point and the rates of the check (the same objects),
    however many answers are mapped (the maps only read them); anything else is the chart's own."""

    def __init__(self, chart: charts.Chart, p: np.ndarray):
        self._chart, self._p, self._jacobian, self._rate = chart, p, None, None

    def jacobian(self, p) -> np.ndarray:
        if p is not self._p:
            return self._chart.jacobian(p)
        if self._jacobian is None:
            self._jacobian = self._chart.jacobian(p)
        return self._jacobian

    def jacobian_rate(self, p, pd) -> np.ndarray:
        if p is not self._p:
            return self._chart.jacobian_rate(p, pd)
        if self._rate is None or self._rate[0] is not pd:
            self._rate = (pd, self._chart.jacobian_rate(p, pd))
        return self._rate[1]

    def __getattr__(self, name: str):
        return getattr(self._chart, name)


def _tolerance(quantity: str, scales: Sequence[tolerance.Scales], gains: Sequence):
    """The largest of the tolerances the contributing scales give (entry by entry where they are per coordinate),
    each carried by its gain: a number, or a matrix (``|Dpsi^-1|``, the map that carried joint-chart accelerations
    into the chart) applied to a per-coordinate tolerance."""
    carried = [g @ t if np.ndim(g) == 2 else g * t
               for g, t in ((g, tolerance.tolerance(quantity, s)) for s, g in zip(scales, gains))]
    return np.maximum.reduce(np.broadcast_arrays(*carried)) if any(np.ndim(c) for c in carried) else max(carried)


def chart_checks(model: Model, state: State, chart: charts.Chart, joint: Mapping[str, Split],
                 backends: Sequence[Formalism], errors: dict[str, str],
                 joint_scales: tolerance.Scales | None = None, record: dict | None = None,
                 limit: float = charts.GIMBAL_LIMIT) -> dict[str, Comparison]:
    """Chart invariance at ``state``: the chart-capable ``backends`` evaluated in p against every trusted
    joint-chart split in ``joint`` mapped into p. A backend raising is recorded in ``errors``. ``joint_scales``:
    ``tolerance.scales`` of ``joint`` at the state when the caller has them (computed here otherwise). ``record``,
    when given, receives what the check used (``crosscheck.campaigns.stability`` measures it): ``p``, ``cond`` (of
    Dpsi), and where the chart is not left out ``pd``, ``tau_p``, ``native`` (label -> split) and ``tolerances``
    (quantity -> the tolerance compared with, per coordinate or one number). ``limit``: the cond(Dpsi) above which
    the chart is left out (the gate's :data:`~crosscheck.checks.charts.GIMBAL_LIMIT`; the stability map asks what the
    check would say beyond it)."""
    record = {} if record is None else record
    q, qd, u = (np.array(v) for v in (state.q, state.qd, state.u))
    p = chart.p_of(q)
    at_p = _AtPoint(chart, p)
    record.update(p=p, cond=float(np.linalg.cond(at_p.jacobian(p))))
    if record["cond"] > limit:
        return {}                  # the chart has lost a direction here (gimbal lock): a BREAKDOWN of the map
    if getattr(chart, "at_centre", None) is not None and chart.at_centre(p):
        return {}                  # exp at its centre: psi's derivatives are 0/0 there (charts.ExponentialCoordinates)
    pd = charts.velocity_to_chart(at_p, p, qd)
    tau_p = charts.force_to_chart(at_p, p, model.input_map @ u)
    record.update(pd=pd, tau_p=tau_p, native={}, tolerances={})
    native: dict[str, Split] = {}
    for backend in backends:
        if backend.split_chart is None:
            continue
        label = f"{backend.name}@{chart.name}"
        try:
            native[label] = backend.split_chart(model, chart, p, pd, tau_p)
        except Exception as exc:  # a backend failing in a valid chart is a failure, reported, never a crash
            errors[label] = f"{type(exc).__name__}: {exc}"
    record["native"] = native
    if not native or not joint:
        return {}
    inverse = np.linalg.inv(at_p.jacobian(p))
    gain = np.abs(inverse) if joint_scales is None or joint_scales.accel is not None else np.linalg.norm(inverse, 2)
    if joint_scales is None:
        joint_scales = tolerance.scales(joint.values(), model, q, qd, u=u)
    at = [tolerance.scales(native.values(), model, q, qd, joint_chart=False, u=u), joint_scales]
    out = {}
    done: dict[str, dict] = {name: {} for name in joint}
    left_out = {name: tolerance.left_out(tolerance.breakdown(split))
                for name, split in (*joint.items(), *native.items())}
    for quantity in _invariant(model):
        if all(isinstance(split.quantity(quantity), Unsupported) for split in native.values()):
            continue                        # no answer from the chart itself: nothing the joint chart has not
        values = {name: mapped(at_p, p, pd, split, quantity, done[name]) for name, split in joint.items()
                  if quantity not in left_out[name]}
        values.update({name: split.quantity(quantity) for name, split in native.items()
                       if quantity not in left_out[name]})
        gains = (1.0, gain) if quantity in ("drift", "ctrl", "total", "additivity") else (1.0, 1.0)
        if quantity == "external_force":     # a covector: Dpsi^T carries each joint-chart entry's rounding into p
            gains = (covector_gain := float(np.abs(at_p.jacobian(p)).sum(axis=0).max()), covector_gain)
        tol = _tolerance(quantity, at, gains)
        if quantity == "power_ctrl":
            tol = max(tol, tolerance.TOLERANCES[quantity][1] * EPS * _transfer(at_p, p, pd, tau_p))
        if quantity == "power_ext":          # as the input's power: pd carries the state's rounding into the chart
            tol = max(tol, tolerance.TOLERANCES[quantity][1] * EPS * _transfer(at_p, p, pd, _loads_in_chart(
                at_p, p, joint)))
        record["tolerances"][quantity] = tol
        out[f"chart {chart.name}: {quantity}"] = compare(quantity, values, tol, shared=f"chart map {chart.name}")
    return out


def _loads_in_chart(chart: charts.Chart, p: np.ndarray, joint: Mapping[str, Split]) -> np.ndarray:
    """The largest (entry by entry) of the joint-chart splits' ``tau_ext`` mapped into the chart, ``Dpsi^T tau_ext``."""
    forces = [np.abs(charts.force_to_chart(chart, p, s.external_force)) for s in joint.values()
              if s.external_force is not None and not isinstance(s.external_force, Unsupported)]
    return np.max(forces, axis=0) if forces else np.zeros(len(p))


def _transfer(chart: charts.Chart, p: np.ndarray, pd: np.ndarray, tau_p: np.ndarray) -> float:
    """The rounding the state carries into the chart, in the power ``tau_p . pd`` the chart evaluations report, eps
    aside: ``pd`` is a solve with ``Dpsi``, off by ``n cond_inf(Dpsi) |pd|_inf`` in any entry (LU's backward error
    ``|L| |U|`` fills entries that are zero in Dpsi), and ``tau_p = Dpsi^T B u`` by ``n |Dpsi|^T |B u|``. A fuzz
    finding: a ball joint turning about body x with the input about z does no work, the joint-chart power is exactly 0
    and its terms are 0, and the chart's pd had 4.5e-16 in yaw, a power of 7.6e-17 against a tolerance of 1.7e-30."""
    D = chart.jacobian(p)
    n = len(pd)
    cond = float(np.linalg.norm(D, np.inf) * np.linalg.norm(np.linalg.inv(D), np.inf))
    applied = np.linalg.solve(D.T, tau_p)                                    # B u, back in the joint chart
    return n * (float(np.abs(tau_p).sum()) * cond * float(np.abs(pd).max())
                + float((np.abs(D).T @ np.abs(applied)) @ np.abs(pd)))


def _extra_rows(value) -> np.ndarray | None:
    arr = np.asarray(value, dtype=float) if isinstance(value, np.ndarray) else None
    return arr if arr is not None and arr.ndim == 2 and arr.shape[1] == 6 else None


def _load_scale(model: Model, u: np.ndarray) -> float:
    """A floor for the size of joint loads: the weight (and its moment over the model's length scale) plus the
    inputs. Loads can be zero at a state (a joint the constraint forces unload), while their rounding is not."""
    weight = sum(b.mass for b in model.bodies) * float(np.linalg.norm(model.gravity))
    return weight * model.length_scale + float(np.abs(model.input_map @ u).sum())


#: Voters bound to their case rather than to the model they are given (``crosscheck.references.closed_forms``): their
#: answer in a moved scene is their answer in the original one, computed from the case's parameters, so it stands on
#: the original side of the frame move (``crosscheck.core.compare``, shared code).
CASE_BOUND = ("closed_form",)


def _moved_label(name: str, frame: frames.Frame) -> str:
    """A backend's label in the moved scene of ``frame``: ``newton_euler@g1``; a voter bound to its case
    (:data:`CASE_BOUND`) is not marked as moved: ``closed_form (case-bound, g1)``."""
    return f"{name} (case-bound, {frame.name})" if name in CASE_BOUND else f"{name}@{frame.name}"


def frame_checks(model: Model, frame: frames.Frame, state: State, original: Mapping[str, Split],
                 moved: Mapping[str, Split], original_scales: tolerance.Scales | None = None,
                 moved_model: Model | None = None) -> dict[str, Comparison]:
    """Frame invariance at ``state``: each backend's split of the moved scene (``moved``) against the unmoved
    splits (``original``), for the joint quantities (all backends vote together) and, per backend, for each
    extra with a law in :data:`FRAME_LAWS` (the prediction from the unmoved extra against the moved one).
    ``original_scales``: ``tolerance.scales`` of all of ``original`` when the caller has them (used when every
    original backend is also in ``moved``); ``moved_model``: the moved scene (``frames.move_scene(model, frame)``,
    made here when not given), whose geometry the moved answers' componentwise tolerance reads: its bodies sit up
    to |t| farther from the world origin."""
    moved_model = frames.move_scene(model, frame) if moved_model is None else moved_model
    q, qd = np.array(state.q), np.array(state.qd)
    both = [name for name in original if name in moved]
    if not both:
        return {}
    # the moved scene sits up to |t| farther from the origin: world-frame kinematics there round on lever arms
    # longer by that much (a body twist from space twists cancels ``t x w``), as in the frame laws below; the kinetic
    # energy multiplies two such velocities. A task point on the joint axes has lever 0 unmoved (its acceleration is
    # exactly 0) but rounds on |t| moved (a fuzz finding): the moved scene's task lever adds |t|.
    reach = 1.0 + float(np.linalg.norm(frame.translation))
    shared = f"frame move {frame.name}"
    u = np.array(state.u)
    there = tolerance.scales([moved[n] for n in both], moved_model, q, qd, u=u)
    if original_scales is None or len(both) < len(original):
        original_scales = tolerance.scales([original[n] for n in both], model, q, qd, u=u)
    at = [original_scales, dataclasses.replace(there, lever=there.lever + reach - 1.0)]
    out = {}
    for quantity in _invariant(model):
        values = {name: original[name].quantity(quantity) for name in both if _votes(original[name], quantity)}
        values.update({_moved_label(name, frame): moved[name].quantity(quantity) for name in both
                       if _votes(moved[name], quantity)})
        gain = reach**2 if quantity == "kinetic_energy" else reach
        out[f"frame: {quantity}"] = compare(quantity, values, _tolerance(quantity, at, (1.0, gain)), shared=shared)
    # the joint-load scale (crosscheck.core.tolerance) where some backend supplies loads: it carries the multipliers'
    # rounding, eps cond(M) lam_scale, which a nearly vacuous constraint row makes far larger than lam itself
    floor = max(_load_scale(model, np.array(state.u)), at[0].load)
    for name in both:
        for key, law in FRAME_LAWS.items():
            before, after = (_extra_rows(s.extras.get(key)) for s in (original[name], moved[name]))
            if before is None or after is None:
                continue
            predicted = before if law is None else before @ getattr(frames, law)(frame).T
            size = max(float(np.abs(before).max()), float(np.abs(after).max()), floor)
            tol = 100.0 * EPS * at[0].cond_M * at[0].cond_S * reach * size
            out[f"frame law: {name} {key}"] = compare(key, {f"{name} (Ad-mapped)" if law else name: predicted,
                                                        f"{name}@{frame.name}": after}, tol)
    return _laws_along(out, shared)


def _laws_along(out: dict[str, Comparison], shared: str) -> dict[str, Comparison]:
    """The frame laws' disagreements blamed on the frame move ``shared`` (``crosscheck.core.compare``, shared code) where
    every backend moved together: the joint quantities' frame checks at the state name it, or a law fails for every
    backend that supplies its extra (two or more). A frame law is one backend's check (its prediction against its own
    moved answer), which alone would name that backend."""
    laws = {key: c for key, c in out.items() if key.startswith("frame law: ")}
    failing = {key for key, c in laws.items() if c.verdict == DISAGREE}
    if not failing:
        return out
    moved_together = any(c.outlier == shared for key, c in out.items() if key.startswith("frame: "))
    by_extra: dict[str, list[str]] = {}
    for key, c in laws.items():
        by_extra.setdefault(c.quantity, []).append(key)
    every = {key for keys in by_extra.values() if len(keys) >= 2 and set(keys) <= failing for key in keys}
    return {key: dataclasses.replace(c, outlier=shared, shared=shared)
            if key in failing and (moved_together or key in every) else c for key, c in out.items()}
