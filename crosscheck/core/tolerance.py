"""The tolerance policy: a tolerance is a claim about floating-point error, scaled by the problem.

Joint accelerations (drift, ctrl, total, additivity) get one tolerance per coordinate, a componentwise bound
(:func:`acceleration_bound`). Solving ``M x = b`` where M and b were formed with errors ``dM`` and ``db`` gives, to
first order, ``|dx| <= |M^-1| (|db| + |dM| |x|)`` (absolute values entrywise). The sizes of ``db`` and ``dM`` are
eps times the magnitudes of the terms each entry sums, which the model's geometry bounds body by body: a body k a
joint i moves contributes to the force on joint i its weight and velocity-product forces times a lever no longer than
P_k (the path length from the world origin to its COM: world-frame kinematics round on world distances), and to
``M_ij`` a product ``m_k (P_k l_jk + l_ik P_k)`` of one world distance and one lever ``l`` about the joint (the
differences of world positions that make a lever round on the positions). The Cholesky solve adds a backward error
bounded by ``sqrt(M_ii M_jj)``. Summed over the subtrees this is far sharper than the normwise ``eps cond(M)
||M^-1|| H`` it replaces: on a 3-D arm the small inertias of the wrist make cond(M) large, but the wrist's rows of
``M^-1`` meet only the wrist's small forces (the normwise bound was 1e5 times the spread of correct backends on the
Panda and spatial_arm; this one is within 1e2 to 1e4 of the true errors measured against the 50-digit reference).
With constraints the multipliers add ``M^-1 Jc^T dlam``: per joint the smaller of the normwise ``cond(M) ||M^-1||
||Jc|| lam_scale`` and a componentwise first-order bound through ``S = Jc M^-1 Jc^T``
(:func:`_constrained_bound`; the Panda's finger coupling leaves the arm's tolerance as tight as without it),
with the short-row rounding below.
Power is a sum of products, so its error is a multiple of ``eps * sum_i |(B u)_i qd_i|``. A task
acceleration ``J qdd + Jdot qd`` (eq. 23) maps the joint error through J, whose columns are at most a lever arm L
long (1 for a prismatic joint), and adds the rounding of ``Jdot qd``, of size ``L |qd|^2``: its scale is
``L (sum_i acceleration_i + |qd|_1^2)``.
The kinetic energy ``1/2 qd^T M qd`` carries the error of M's entries: ``|qd|^T (M-term bound) |qd|`` (the same
per-entry magnitudes as the accelerations').

Constrained models (article 5.2-5.5). The multipliers solve ``S lam = r`` with ``S = Jc M^-1 Jc^T``; their scale is
``lam_scale = ||S^+|| (|Jcdot qd| + ||Jc|| accel_scale)`` (``formalisms.interface.constraint_conditioning``), which
already carries S's amplification (``||S^+||``, over the directions kept above ``CONSTRAINT_RCOND``); the
acceleration scale adds what the constraint force can produce, ``||M^-1|| ||Jc|| lam_scale``. ``Jc^T lam`` and its
power add ``||Jc^T||`` and ``|qd|_1``. The constraint kinematics (``phi``, ``Jc``, ``Jcdot qd``, ``Jc qd``) are sums of
products of lengths: their scale is ``L^2 (n + 1) + max|Jc| (1 + |q|_1)`` with L the model's length scale, times
``|qd|_1`` per time derivative, and times ``1 / s^2`` for a rolling contact whose axle makes the angle with sine s with
the ground normal (its contact direction is a unit vector divided by s).

External loads (``cases.loads``; ``external_force`` = ``tau_ext``, ``power_ext``). ``tau_ext = sum J_p^T f + J_w^T m``
sums, per coordinate, the loads' forces times world lever arms (at most the reach R plus the point's offset) and their
couples (:func:`external_terms`); those terms join the right-hand side of the acceleration bound like gravity's, the
joint loads' scale (the forces over lever arms up to R), and the scales of ``tau_ext`` itself (the terms' sum plus the
voters' ``|tau_ext|_1``) and of its power (times ``|qd|``).

Joint loads (``joint_wrenches``, ``joint_wrenches_drift``: body-frame force and moment per joint, article 6.1.5)
are sums over a subtree of masses times accelerations, weights and the point forces of the multipliers, with
moments over lever arms no longer than the model's reach R (its length scale plus the travel of its prismatic
joints). Their rounding is eps times those magnitudes: ``(m_total R^2 + sum |I_k|) (|qdd|_1 + |qd|_1^2)`` for the
inertial and velocity-product terms (forces ``m R``, moments ``m R^2 + |I|`` per unit acceleration; ``|I_k|``
bounded by its trace),
``(1 + R) m_total |gravity|`` for the weights, ``(1 + R) G cond(S) |lam|_1`` for the constraint forces (G the largest
force or coupling torque per unit multiplier of a declaration: 1 for the orthonormal rows of a loop or a line,
``2 radius`` for a circle, ``max |c_j|`` for a coupling; ``cond(S)`` over the directions kept, what the multipliers'
solve amplifies), plus the loads' own size. The accelerations and multipliers they are built from were solved with
M, so the sum is multiplied by cond(M): scale ``cond(M) [(m_total R^2 + sum |I_k|) (|qdd|_1 + |qd|_1^2) + (1 + R)
(m_total |gravity| + G cond(S) |lam|_1) + max |load|]``, with ``qdd, lam`` the total's (``lam_drift`` and the drift's
for the drift loads), each size the median over the voters.

The task-space inertia ``Lambda = A^-1``, ``A = J M^-1 J^T`` (``task_inertia``, eq. 22): a backward-stable solve
with M gives ``|dA| <~ eps cond(M) |A|``, and the inverse amplifies it to ``|dLambda| <~ |Lambda|^2 |dA| = eps
cond(M) cond(A) |Lambda|``. J itself rounds at ``eps L`` (L the task point's lever arm) however small it comes out:
a task direction the point barely moves in (``|J|`` small, Lambda large) is a difference of lever-arm-sized terms,
relative error ``eps L / |J|``, with ``1 / |J| <= sqrt(max|Lambda| ||M^-1||)`` (a fuzz finding: one body, Lambda = 1042
kg, 18 times the tolerance without this). Scale: ``cond(M) max|Lambda_ij| (cond(A) + L sqrt(max|Lambda_ij|
||M^-1||))``, cond(A) (as the voters report it) and the largest entry the medians over the voters, ``||M^-1||``
from Pinocchio's M. Where A is
numerically singular (a task singularity) Lambda does not exist; each voter reports ``cond(A)`` as the condition
``task_inertia`` and is left out of the vote on ``task_inertia`` alone above its limit (``BREAKDOWN_LIMITS``).

Quantities with an exact value (``EXACT``) vote against it: a drift off ``H_t``, constraint power at an admissible
state, an inadmissible sampled state.

The scales are the median over the backends' own reports, so one backend misreporting its conditioning
cannot loosen the tolerance for the others. The factors below are data: each is a safety margin over the
largest error/scale ratio measured on correct backends (docs/tolerances.md), kept far below the O(1)
relative errors a modelling bug produces.
"""

from __future__ import annotations

import statistics
import weakref
from dataclasses import dataclass

import numpy as np

from cases.constraints import JointCoupling, PointOnCircle, RollingContact
from cases.loads import ExternalWrench, PointSpring
from cases.model import JOINT_DOF
from crosscheck.references.pinocchio.kinematics import contact_sines, mass_matrix
from formalisms.interface import CONSTRAINT_RCOND, Unsupported

EPS = float(np.finfo(float).eps)
#: The smallest positive normal float: a scale is never taken below it.
TINY = np.finfo(float).tiny

#: quantity -> (scale kind, factor). tol = factor * eps * scale.
TOLERANCES: dict[str, tuple[str, float]] = {
    "drift": ("acceleration", 100.0),
    "ctrl": ("acceleration", 100.0),
    "total": ("acceleration", 100.0),
    "additivity": ("acceleration", 100.0),
    "zvcf": ("acceleration", 100.0),
    "drift_velocity": ("acceleration", 100.0),
    "drift_parts": ("acceleration", 100.0),
    "power_ctrl": ("power", 100.0),
    "task_drift": ("task", 100.0),
    "kinetic_energy": ("energy", 100.0),
    "joint_wrenches": ("load", 100.0),
    "joint_wrenches_drift": ("load_drift", 100.0),
    "task_inertia": ("task_inertia", 100.0),
    "lam": ("multiplier", 100.0),
    "lam_drift": ("multiplier", 100.0),
    "constraint_force": ("constraint_force", 100.0),
    "constraint_force_drift": ("constraint_force", 100.0),
    "power_constr": ("constraint_power", 100.0),
    "power_constr_per_coord": ("constraint_power", 100.0),
    "admissibility_drift": ("admissibility", 100.0),
    "admissibility_total": ("admissibility", 100.0),
    "constraint_value": ("constraint_kinematics", 100.0),
    "constraint_velocity": ("constraint_velocity", 100.0),
    "constraint_jacobian": ("constraint_kinematics", 100.0),
    "constraint_bias": ("constraint_rate", 100.0),
    "external_force": ("external_force", 100.0),
    "power_ext": ("external_power", 100.0),
}

#: The quantities of a constrained model only (article 5), in report order.
CONSTRAINED_QUANTITIES = ("lam", "lam_drift", "constraint_force", "constraint_force_drift", "power_constr",
                          "power_constr_per_coord", "admissibility_drift", "admissibility_total", "constraint_value",
                          "constraint_velocity", "constraint_jacobian", "constraint_bias")

#: The quantities of a model with external loads only (``cases.loads``): ``tau_ext`` and its power.
LOADED_QUANTITIES = ("external_force", "power_ext")

#: The quantities the gate compares on every model, in report order.
QUANTITIES = tuple(q for q in TOLERANCES if q not in CONSTRAINED_QUANTITIES and q not in LOADED_QUANTITIES)

#: Quantities with a value known exactly, which joins the vote as the voter ``exact``.
EXACT = {"additivity": 0.0, "drift_parts": 0.0, "power_constr": 0.0, "admissibility_drift": 0.0, "admissibility_total": 0.0,
         "constraint_value": 0.0, "constraint_velocity": 0.0}


def quantities(model) -> tuple[str, ...]:
    """The quantities compared on ``model``: the constrained ones join when it has constraints, the loaded ones when it
    has external loads."""
    return (QUANTITIES + (CONSTRAINED_QUANTITIES if model is not None and model.constraints else ())
            + (LOADED_QUANTITIES if model is not None and model.loads else ()))


#: condition name (``Split.conditions``) -> limit. Above it the formalism reporting the condition number is in
#: BREAKDOWN at that state: its method is ill-conditioned there, which is reported, not counted as a bug.
#: Calibrated by measurement (docs/tolerances.md, Breakdown): on paths into the task singularities of the planar chains
#: and the Panda, the largest error/tolerance of unflagged operational-space states is 0.064 at 1e3, 0.24 at
#: 1e4 and 4.5 at 1e6 (the recomposition's floor grows like eps |Jdot qd| sqrt(cond)).
BREAKDOWN_LIMITS: dict[str, float] = {
    "task": 1e3,                      # cond(J M^-1 J^T), operational space (article 6.3.4)
    "task_jacobian": 1e3,             # L ||M^-1 J^T Lambda||_2, operational space: the recomposition's amplification
                                      # of the task bias's rounding (a Jacobian short in every direction, cond 1);
                                      # 0.03-0.18 of the tolerance at 1e3 (docs/tolerances.md); 286 on the gate's cases
    "constraint": 1e8,                # cond(Jc M^-1 Jc^T): redundant or degenerate constraints (5.6)
    "constraint_kept": 1e8,           # the same over the directions kept: nearly (not exactly) redundant rows
    "constraint_consistency": 1e-10,  # share of the KKT right-hand side S cannot reach: H_t is empty (5.4); it is
                                      # left as H_t residual, so 1e-8 let tangent circle rows fail H_t (fuzz findings)
    "task_inertia": 1e8,              # cond(J M^-1 J^T) of a backend that reports Lambda (eq. 22) besides its split
}

#: condition name -> the quantities its BREAKDOWN leaves out; a condition not listed leaves out the whole backend.
#: Singular ``Jc M^-1 Jc^T`` makes only the multipliers non-unique: ``Jc^T lam`` and the accelerations stay unique,
#: while the joint loads carry the multipliers' point forces themselves. A singular task space leaves its Lambda
#: undefined, and nothing else of a backend that only reports it.
BREAKDOWN_SCOPE: dict[str, tuple[str, ...]] = {
    "constraint": ("lam", "lam_drift", "joint_wrenches", "joint_wrenches_drift"),
    "task_inertia": ("task_inertia",),
}


def breakdown(split) -> dict[str, float]:
    """The conditions of ``split`` above their limits (NaN or inf included), by name; empty when none."""
    return {name: value for name, value in split.conditions.items()
            if not value <= BREAKDOWN_LIMITS.get(name, np.inf)}


def whole(conditions: dict[str, float]) -> bool:
    """Whether these broken conditions leave the whole backend out (some condition has no narrower scope)."""
    return any(name not in BREAKDOWN_SCOPE for name in conditions)


def left_out(conditions: dict[str, float]) -> set[str]:
    """The quantities a backend with these broken conditions does not vote on (when not :func:`whole`)."""
    return {q for name in conditions for q in BREAKDOWN_SCOPE.get(name, ())}


@dataclass(frozen=True)
class Scales:
    """Problem scales at one state: the median of what the backends report, and ``accel`` the componentwise
    acceleration bound of :func:`acceleration_bound` (with constraints :func:`_constrained_bound`; module doc); without
    ``accel`` (a chart's own coordinates, where the model's joint geometry does not apply) accelerations fall back
    to the normwise ``cond(M) accel_scale``."""

    cond_M: float
    accel_scale: float
    power_scale: float
    lever: float = 0.0
    rate_sq: float = 0.0
    energy: float = 0.0
    cond_S: float = 1.0
    lam_scale: float = 0.0
    jc: float = 0.0
    kinematics: float = 0.0
    rate: float = 0.0
    load: float = 0.0
    load_drift: float = 0.0
    task_cond: float = 0.0
    task_size: float = 0.0
    minv: float = 0.0
    lam_rounding: float = 0.0
    accel: np.ndarray | None = None
    energy_terms: float | None = None
    external: float = 0.0
    external_power: float = 0.0

    def of(self, kind: str):
        """The scale of ``kind`` (:data:`TOLERANCES`): a float, or for ``acceleration`` with the componentwise bound
        one value per coordinate."""
        if kind not in _SCALE_OF:
            raise KeyError(f"unknown tolerance scale kind '{kind}'")
        return _SCALE_OF[kind](self)

    @property
    def normwise(self) -> float:
        """The normwise acceleration scale ``cond(M) accel_scale``, plus the multipliers' short-row rounding that the
        constraint force ``Jc^T lam`` carries into the accelerations (the componentwise bound has it in ``accel``)."""
        return self.cond_M * self.accel_scale + self.minv * self.jc * self.lam_rounding

    @property
    def acceleration(self):
        """The acceleration scale: ``accel`` (per coordinate) when there is one, else :attr:`normwise`."""
        return self.normwise if self.accel is None else self.accel

    @property
    def multiplier(self) -> float:
        """The multipliers' scale ``cond(M) lam_scale`` plus their short-row rounding."""
        return self.cond_M * self.lam_scale + self.lam_rounding


#: scale kind -> its value from the :class:`Scales` at a state (:meth:`Scales.of`).
_SCALE_OF = {
    "load": lambda s: s.cond_M * s.load,
    "load_drift": lambda s: s.cond_M * s.load_drift,
    "task_inertia": lambda s: s.cond_M * s.task_size * (s.task_cond + s.lever * np.sqrt(s.task_size * s.minv)),
    "acceleration": lambda s: s.acceleration,
    "power": lambda s: s.power_scale,
    "task": lambda s: s.lever * (float(np.sum(s.acceleration)) + s.rate_sq),
    "energy": lambda s: s.cond_M * s.energy if s.energy_terms is None else s.energy_terms,
    "multiplier": lambda s: s.multiplier,
    "constraint_force": lambda s: s.jc * s.multiplier,
    "constraint_power": lambda s: (s.jc * s.multiplier + s.lam_scale * s.kinematics) * s.rate,
    # Jc qdd: the error of the solve through Jc, plus Jc's own rounding (eps times the kinematics scale) times qdd,
    # which a row dropped as degenerate (rounding-size Jc, no multiplier) leaves whole
    "admissibility": lambda s: s.jc * s.normwise + s.kinematics * (s.accel_scale + s.rate**2),
    "constraint_kinematics": lambda s: s.kinematics,
    "constraint_velocity": lambda s: s.kinematics * s.rate,
    "constraint_rate": lambda s: s.kinematics * s.rate**2,
    "external_force": lambda s: s.external,
    "external_power": lambda s: s.external_power,
}


def task_lever(model, q) -> float:
    """An upper bound on the length of the task Jacobian's columns: the sum of the placements along the task
    point's chain (prismatic joints add their travel and 1 for their unit column) plus the point's offset."""
    tp = model.task_point()
    lever, i = float(np.linalg.norm(tp.offset)), model.body_index(tp.body)
    while i >= 0:
        lever += float(np.linalg.norm(model.bodies[i].translation)) + _travel(model, q, i)
        if model.bodies[i].joint in ("prismatic", "free"):
            lever += 1.0
        i = model.parent_index[i]
    return lever


def _travel(model, q, i: int) -> float:
    """How far body i's joint has carried its origin from the joint frame: ``|q_i|`` for a prismatic joint, the
    position's norm for a free one, 0 for a rotation (``cases.model``)."""
    joint, start = model.bodies[i].joint, model.q_index[i]
    if joint == "prismatic":
        return abs(float(q[start]))
    return float(np.linalg.norm(np.asarray(q, dtype=float)[start:start + 3])) if joint == "free" else 0.0


def load_gain(model) -> float:
    """The largest force (or coupling torque) a unit multiplier of one row applies: 1 for the orthonormal rows of a
    loop or a line, ``2 radius`` for a circle (``|grad phi| = 2 |P (p - c)|`` on it), ``max |c_j|`` for a coupling;
    0 without constraints."""
    def gain(c) -> float:
        if isinstance(c, PointOnCircle):
            return 2.0 * c.radius
        return float(np.abs(c.coefficients).max()) if isinstance(c, JointCoupling) else 1.0

    return max((gain(c) for c in model.constraints), default=0.0)


@dataclass(frozen=True)
class _Loads:
    """The model's constants in the load scale (module doc): its length scale, total mass, ``sum_k tr I_k`` (a bound
    on ``sum |I_k|_2``), weight ``m_total |gravity|``, the gain G and the indices in q of the travels of its prismatic
    joints and free bases' positions."""

    length: float
    mass: float
    inertia: float
    weight: float
    gain: float
    prismatic: np.ndarray

    @classmethod
    def of(cls, model) -> "_Loads":
        return cls(model.length_scale, sum(b.mass for b in model.bodies),
                   sum(float(np.trace(b.inertia)) for b in model.bodies),
                   sum(b.mass for b in model.bodies) * float(np.linalg.norm(model.gravity)), load_gain(model),
                   np.array([model.q_index[i] + k for i, b in enumerate(model.bodies)
                             for k in range({"prismatic": 1, "free": 3}.get(b.joint, 0))], dtype=int))


_CONSTANTS: dict[tuple[str, int], tuple[weakref.ref, object]] = {}   # (kind, id(model)) -> (the model, constants)


def _constants(model, kind: type):
    """``kind.of(model)`` (a model's constants), computed once per model: models are immutable."""
    key = (kind.__name__, id(model))
    entry = _CONSTANTS.get(key)
    if entry is None or entry[0]() is not model:
        entry = _CONSTANTS[key] = (weakref.ref(model, lambda _, key=key: _CONSTANTS.pop(key, None)), kind.of(model))
    return entry[1]


def _loads(model) -> _Loads:
    return _constants(model, _Loads)


def reach(model, q) -> float:
    """The model's reach R: its length scale (1 m plus every placement and COM offset) plus the travel of its
    prismatic joints and free bases; no lever arm within the tree is longer."""
    constants = _loads(model)
    return constants.length + float(np.abs(np.asarray(q, dtype=float)[constants.prismatic]).sum())


def _median(values) -> float:
    """The median of a short list of floats (``statistics``: the gate calls this per state, many times)."""
    return float(statistics.median(values)) if values else 0.0


def _nanmedian(arrays) -> np.ndarray:
    """``np.nanmedian(arrays, axis=0)`` (the voters' values entry by entry, NaN left out): by ``np.median``, the same
    numbers a tenth of the time on a few small arrays, when there is no NaN."""
    stacked = np.asarray(arrays, dtype=float)
    return np.nanmedian(stacked, axis=0) if np.isnan(stacked).any() else np.median(stacked, axis=0)


def _load_scales(model, splits, q, qd, rounding: dict[int, float]) -> dict[str, float]:
    """The sums of magnitudes in the joint loads at the total and at the drift (module doc), without cond(M), over
    the splits that supply the loads (none: no load scale, as in a chart, where no backend reports them);
    ``rounding``: :func:`_lam_rounding` of each constrained split, by ``id``."""
    splits = [s for s in splits if not isinstance(s.joint_wrenches, Unsupported)]
    if not splits:
        return {}
    constants, R = _loads(model), reach(model, q)
    lever = constants.mass * R**2 + constants.inertia
    rate_sq = float(np.abs(qd).sum()) ** 2
    cond_S = _median([s.conditions.get("constraint_kept", 1.0) for s in splits])
    out = {}
    for kind, acceleration, lam, load in (("load", "total", "lam", "joint_wrenches"),
                                          ("load_drift", "drift", "lam_drift", "joint_wrenches_drift")):
        constrained = [s for s in splits if s.constraint_jacobian is not None]
        multipliers = [float(np.abs(s.quantity(lam)).sum()) for s in constrained]
        # lam's own rounding (the multiplier tolerance, module doc), whatever |lam| is: a nearly vacuous row (S tiny)
        # gives lam = 5.6 with lam_scale = 5e10, a circle row near tangency lam = -6e7 with Jc = 2.5e-8 (fuzz findings)
        lam_error = _median([s.lam_scale + rounding[id(s)] for s in constrained])
        out[kind] = (lever * (_median([float(np.abs(s.quantity(acceleration)).sum()) for s in splits]) + rate_sq)
                     + (1.0 + R) * (constants.weight + constants.gain * (cond_S * _median(multipliers) + lam_error)
                                    + _external_size(model, R))
                     + _median([float(np.abs(s.quantity(load)).max()) for s in splits]))
    return out


def _external_size(model, R: float) -> float:
    """The external loads' forces and couples summed (:func:`size_bound`), 0 without loads: the joint
    loads carry them, their moments over lever arms up to the reach R."""
    return float(sum(sum(size_bound(load, R)) for load in model.loads))


def size_bound(load, reach: float) -> tuple[float, float]:
    """``(force, moment)``: bounds on the sizes of an external load's force and couple (``cases.loads``) for a model
    whose points lie within ``reach`` of the world origin, without kinematics: a spring's force is at most ``k (reach +
    |anchor| + L0)``."""
    if isinstance(load, PointSpring):
        return load.stiffness * (reach + float(np.linalg.norm(load.anchor)) + load.rest_length), 0.0
    moment = float(np.linalg.norm(load.moment)) if isinstance(load, ExternalWrench) else 0.0
    return float(np.linalg.norm(load.force)), moment


def _task_condition(split) -> float:
    """cond(J M^-1 J^T) as the split reports it (``task_inertia``, or the operational-space ``task``), else from its
    Lambda."""
    found = split.conditions.get("task_inertia", split.conditions.get("task"))
    if found is not None:
        return float(found)
    eig = np.linalg.eigvalsh(split.task_inertia)
    return float(eig[-1] / eig[0]) if eig[0] > 0.0 else float("inf")


@dataclass(frozen=True)
class _Mass:
    """The harness's view of M at one q (Pinocchio's CRBA, ``crosscheck.references.pinocchio.kinematics.mass_matrix``):
    ``M^-1``, ``|M^-1|`` entrywise, ``||M||_2``, ``||M^-1||_2`` and ``sqrt(diag M)``."""

    inverse: np.ndarray
    abs_inverse: np.ndarray
    norm: float
    inverse_norm: float
    root_diagonal: np.ndarray


_MASS: dict[int, tuple[weakref.ref, bytes, _Mass]] = {}   # id(model) -> (the model, q's bytes, M's data): last q


def _mass(model, q) -> _Mass:
    """:class:`_Mass` at q; the value at the model's last q is kept, since the gate asks for it several times per
    state (joint chart, charts, moved scene)."""
    key = np.asarray(q, dtype=float).tobytes()
    entry = _MASS.get(id(model))
    if entry is None or entry[0]() is not model or entry[1] != key:
        import scipy.linalg

        M = mass_matrix(model, q)
        inverse = scipy.linalg.cho_solve(scipy.linalg.cho_factor(M), np.eye(len(M)))
        eigenvalues = np.linalg.eigvalsh(M)
        value = _Mass(inverse, np.abs(inverse), float(eigenvalues[-1]), 1.0 / float(eigenvalues[0]),
                      np.sqrt(np.diag(M)))
        ident = id(model)
        entry = _MASS[ident] = (weakref.ref(model, lambda _, ident=ident: _MASS.pop(ident, None)), key, value)
    return entry[2]


@dataclass(frozen=True)
class _Geometry:
    """The model's constants in :func:`acceleration_bound`, per velocity coordinate (column) j and body k:
    ``moves[j, k]`` = 1 when column j moves body k (j's body on k's path from the world), ``body[j]`` the body whose
    joint owns column j, ``revolute[j]`` whether column j turns (a revolute joint, a spherical joint's three and a
    free joint's last three columns) rather than slides; per body the placement lengths ``|t_k|``, the COM offsets
    ``|c_k|``, masses, ``tr I_k``, ``ancestors[k, a]`` = 1 when body a is on k's path (k included), and ``travel``
    the q indices whose sizes carry a body's origin (a prismatic joint's value, a free base's position) with the
    body each belongs to. Revolute and prismatic joints only: one column per body, the matrices as before."""

    moves: np.ndarray
    body: np.ndarray
    placement: np.ndarray
    com: np.ndarray
    mass: np.ndarray
    inertia: np.ndarray
    revolute: np.ndarray
    ancestors: np.ndarray
    travel: tuple[np.ndarray, np.ndarray]

    @classmethod
    def of(cls, model) -> "_Geometry":
        count = len(model.bodies)
        ancestors = np.zeros((count, count))
        for k in range(count):
            a = k
            while a >= 0:
                ancestors[k, a] = 1.0
                a = model.parent_index[a]
        body = np.array([i for i, b in enumerate(model.bodies) for _ in range(JOINT_DOF[b.joint][1])], dtype=int)
        turns = {"revolute": [True], "prismatic": [False], "spherical": [True] * 3, "free": [False] * 3 + [True] * 3}
        revolute = np.array([t for b in model.bodies for t in turns[b.joint]])
        travel_q = [(model.q_index[i] + k, i) for i, b in enumerate(model.bodies)
                    for k in range({"prismatic": 1, "free": 3}.get(b.joint, 0))]
        return cls(ancestors.T[body], body, np.array([float(np.linalg.norm(b.translation)) for b in model.bodies]),
                   np.array([float(np.linalg.norm(b.com)) for b in model.bodies]),
                   np.array([b.mass for b in model.bodies]),
                   np.array([float(np.trace(b.inertia)) for b in model.bodies]), revolute, ancestors,
                   (np.array([t[0] for t in travel_q], dtype=int), np.array([t[1] for t in travel_q], dtype=int)))


def _entry_terms(model, q, qd) -> tuple[np.ndarray, np.ndarray]:
    """``(Mterm, f)``: the magnitudes of the terms each entry of M and of ``h = C qd + g`` sums (module doc).

    Path lengths from the world origin (each joint's placement, plus the travel of a prismatic joint): joint i's
    origin is at most ``O_i`` from the origin, body k's COM at most ``P_k``, and its lever about joint i at most
    ``l_ik = P_k - O_i``. A revolute joint i rounds body k's terms on ``rho_ik = P_k`` (world positions) and turns
    them by ``l_ik``; a prismatic one by 1 and 1. ``Mterm_ij = sum_k m_k (rho_ik l_jk + l_ik rho_jk) + tr I_k`` over
    the bodies both joints move, plus joint i's armature on the diagonal (``Body.armature``, a term of ``M_ii``);
    ``f_i = sum_k rho_ik m_k (2 W_k V_k + |gravity|) + tr I_k W_k^2`` over the bodies
    joint i moves, with ``W_k`` the angular rates and ``V_k = P_k W_k`` plus the sliding rates on k's path, and for a
    revolute joint also ``m_k V_k^2``: a moment of the momentum about its own velocity, ``v x (m v)``, is zero only
    up to ``eps m |v|^2`` (a fuzz finding: a body sliding at 1 m/s and not turning, drift 2e-16 from 0 in two
    backends against a tolerance that had no term for it)."""
    geo = _constants(model, _Geometry)
    q, rates = np.asarray(q, dtype=float), np.abs(np.asarray(qd, dtype=float))
    travel = np.bincount(geo.travel[1], np.abs(q[geo.travel[0]]), minlength=len(geo.mass))   # per body
    origin = geo.ancestors @ (geo.placement + travel) - travel        # O_k: body k's joint origin
    P = origin + travel + geo.com                                      # P_k: body k's COM
    lever = np.where(geo.revolute[:, None], P[None, :] - origin[geo.body][:, None], 1.0) * geo.moves   # l_jk
    rho = np.where(geo.revolute[:, None], P[None, :], 1.0) * geo.moves                                # rho_jk
    angular = geo.moves.T @ np.where(geo.revolute, rates, 0.0)
    speed = P * angular + geo.moves.T @ np.where(geo.revolute, 0.0, rates)
    spin = geo.moves * geo.inertia
    Mterm = (rho * geo.mass) @ lever.T + (lever * geo.mass) @ rho.T + spin @ geo.moves.T + np.diag(model.armature_vector)
    f = (rho @ (geo.mass * (2.0 * angular * speed + float(np.linalg.norm(model.gravity)))) + spin @ angular**2
         + np.where(geo.revolute, geo.moves @ (geo.mass * speed**2), 0.0))
    if model.loads:
        f = f + external_terms(model, q)
    return Mterm, f


def external_terms(model, q) -> np.ndarray:
    """The sizes of the terms each entry of ``tau_ext = sum J_p^T f + J_w^T m`` sums (``cases.loads``), eps aside, per
    velocity coordinate j: for each load on a body that column j moves, ``(R + |offset|) |f| + |m|`` where j turns
    (a world lever, at most the model's reach R plus the point's offset, times the force, and the couple) and ``|f|``
    where it slides; ``|f|`` and ``|m|`` the declarations' bounds (:func:`size_bound`: a spring's force at
    most ``k (R + |anchor| + L0)``). Zeros for a model without loads."""
    geo = _constants(model, _Geometry)
    R = reach(model, q)
    out = np.zeros(model.nv)
    for load in model.loads:
        k = model.body_index(load.body)
        force, moment = size_bound(load, R)
        lever = R + float(np.linalg.norm(load.offset))
        out += geo.moves[:, k] * np.where(geo.revolute, lever * force + moment, force)
    return out


def acceleration_bound(model, q, qd, accelerations, forces=None) -> np.ndarray:
    """The componentwise rounding bound of joint accelerations (module doc), without the factor eps: ``|M^-1| (f +
    |forces| + Mterm |x| + d (d . |x|))`` with ``x`` = ``accelerations`` (the sizes the solves produced, e.g. ``|drift|
    + |ctrl|``), ``forces`` any further generalized forces summed into the right-hand side (the constraint forces'
    sizes), ``d = sqrt(diag M)`` (Cholesky's backward error) and M from Pinocchio's CRBA."""
    mass = _mass(model, q)
    Mterm, f = _entry_terms(model, q, qd)
    x = np.abs(np.asarray(accelerations, dtype=float))
    d = mass.root_diagonal
    with np.errstate(over="ignore", invalid="ignore"):       # an overflowed answer has no finite bound: inf
        rhs = f + Mterm @ x + d * float(d @ x) + (0.0 if forces is None else np.abs(forces))
        return mass.abs_inverse @ rhs


def kinetic_energy_bound(model, q, qd) -> float:
    """The rounding bound of ``T = 1/2 qd^T M qd`` without the factor eps: ``|qd|^T (Mterm + d d^T) |qd|``."""
    Mterm, _ = _entry_terms(model, q, qd)
    rates, d = np.abs(np.asarray(qd, dtype=float)), _mass(model, q).root_diagonal
    return float(rates @ Mterm @ rates + (d @ rates) ** 2)


def _task_inertia_scales(splits) -> dict[str, float]:
    """Median cond(J M^-1 J^T) and largest entry of Lambda over the splits that vote on ``task_inertia`` (supplied,
    below the BREAKDOWN limit of the condition, finite)."""
    limit = BREAKDOWN_LIMITS["task_inertia"]
    voting = [(cond, s.task_inertia) for s in splits if not isinstance(s.task_inertia, Unsupported)
              and (cond := _task_condition(s)) <= limit and np.all(np.isfinite(s.task_inertia))]
    if not voting:
        return {}
    return {"task_cond": _median([cond for cond, _ in voting]),
            "task_size": _median([float(np.abs(Lambda).max()) for _, Lambda in voting])}


def scales(splits, model=None, q=None, qd=None, joint_chart: bool = True, u=None) -> Scales:
    """Median scales over the backends' splits (an iterable of Split); the task, load and componentwise acceleration
    scales need the model and the state (``q``, ``qd``). ``joint_chart=False`` for splits evaluated in a chart's own
    coordinates p, where the joint geometry of :func:`acceleration_bound` does not apply (normwise scales there).
    With the inputs ``u`` the power's scale is the size of its terms, ``|qd| . (|B| |u|)`` (:func:`power_scale`)."""
    splits = list(splits)
    constrained = [s for s in splits if s.constraint_jacobian is not None]
    rounding = {} if model is None else {id(s): _lam_rounding(model, s) for s in constrained}
    task = {} if model is None else {"lever": task_lever(model, q), "rate_sq": float(np.abs(qd).sum()) ** 2,
                                     "minv": _mass(model, q).inverse_norm,
                                     **_load_scales(model, splits, q, qd, rounding)}
    task.update(_task_inertia_scales(splits))
    energies = [s.kinetic_energy for s in splits if not isinstance(s.kinetic_energy, Unsupported)]
    if model is not None and constrained:
        task.update(_constraint_scales(model, constrained, q, qd, rounding))
    if model is not None and joint_chart and splits:
        task.update(_componentwise(model, splits, constrained, q, qd, task))
    elif model is not None and splits and not constrained:
        task["accel"] = _chart_bound(model, splits)
    power = _median([float(np.abs(s.power_ctrl_per_coord).sum()) for s in splits])
    if model is not None and u is not None:
        power = max(power, power_scale(model, qd, u))
    if model is not None and model.loads:
        task.update(_external_scales(model, splits, q, qd))
    return Scales(cond_M=_median([s.cond_M for s in splits]), accel_scale=_median([s.accel_scale for s in splits]),
                  power_scale=power, energy=_median(energies), **task)


def _external_scales(model, splits, q, qd) -> dict[str, float]:
    """``external`` (the size of the terms summed in ``tau_ext``, :func:`external_terms`, 1-norm, and the median size of
    the voters' ``|tau_ext|_1``) and ``external_power`` (those terms times ``|qd|``: ``tau_ext . qd`` sums them)."""
    terms = external_terms(model, q)
    supplied = [float(np.abs(s.external_force).sum()) for s in splits
                if s.external_force is not None and not isinstance(s.external_force, Unsupported)]
    size = float(terms.sum()) + _median(supplied)
    return {"external": size, "external_power": float(terms @ np.abs(np.asarray(qd, dtype=float))) + size * float(
        np.abs(np.asarray(qd, dtype=float)).sum())}


def power_scale(model, qd, u) -> float:
    """The size of the terms summed in ``u . (B^T qd)``, ``|qd| . (|B| |u|)``: a backend may sum them in any order
    (``(B u) . qd`` or ``u . (B^T qd)``), and ``B u`` can cancel to far less than its terms (a fuzz finding: B's row
    (1.17, -1.1) at u = (-9.4, -10) gives (B u)_i = 0.037 from terms of 11, and the powers differed by 1.2 times a
    tolerance built from ``|(B u)_i qd_i|``)."""
    return float(np.abs(np.asarray(qd, dtype=float)) @ (np.abs(model.input_map) @ np.abs(np.asarray(u, dtype=float))))


def _chart_bound(model, splits) -> np.ndarray:
    """The accelerations' rounding in a chart's own coordinates p (``split_chart``), where the joint geometry of
    :func:`acceleration_bound` does not apply: the normwise first-order bound of a backward-stable solve of
    ``M_p pdd = f`` whose M_p and f are computed to eps relative to their terms, ``eps (||M_p^-1|| H + cond(M_p)
    ||pdd||)`` (``accel_scale = ||M_p^-1|| H``, H the size of the terms summed in f), with ``||pdd||`` the median
    1-norm of the voters' drift, ctrl and total (a 1-norm bounds every entry of the 2-norm bound), in every coordinate.
    The bound ``cond(M_p) accel_scale`` used before multiplies the two terms: at the zyx chart's gimbal lock both grow
    like 1 / delta^2 (delta = pi/2 - pitch), so the check accepted 1e-7 relative errors at delta = 0.1 and 0.1 at
    delta = 1e-3, where the native answers were right to 8e-13 and 2e-9 (``crosscheck stability``, path gimbal).
    Unconstrained models only: a constrained solve in p adds the multipliers' error through ``M_p^-1 Jc_p^T``, whose
    ``||M_p^-1||`` no split reports, so those keep the normwise ``cond(M_p) accel_scale``."""
    size = _median([max(float(np.abs(s.drift).sum()), float(np.abs(s.ctrl).sum()), float(np.abs(s.total).sum()))
                    for s in splits])
    bound = _median([s.accel_scale for s in splits]) + _median([s.cond_M for s in splits]) * size
    return np.full(model.nv, bound)


def _componentwise(model, splits, constrained, q, qd, scales: dict) -> dict:
    """``accel`` (:func:`acceleration_bound` at the median sizes of the voters' drift + ctrl, with the median
    constraint forces ``|Jc|^T (|lam| + |lam_drift|)``; with constraints :func:`_constrained_bound`) and
    ``energy_terms`` (:func:`kinetic_energy_bound`)."""
    sizes = np.nan_to_num(_nanmedian([np.abs(s.drift) + np.abs(s.ctrl) for s in splits]))
    forces = None
    if constrained:
        forces = _nanmedian([np.abs(s.constraint_jacobian).T @ (np.abs(s.lam) + np.abs(s.lam_drift))
                             for s in constrained])
    accel = acceleration_bound(model, q, qd, sizes, forces)
    if constrained:
        accel = _constrained_bound(model, constrained, q, qd, sizes, accel, _median([s.cond_M for s in splits]),
                                   scales)
    return {"accel": accel, "energy_terms": kinetic_energy_bound(model, q, qd)}


def _constrained_bound(model, constrained, q, qd, sizes: np.ndarray, accel: np.ndarray, cond_M: float,
                       scales: dict) -> np.ndarray:
    """The joint accelerations' rounding with constraints: per joint the smaller of two bounds of it (so their
    minimum is one too).

    Normwise: ``accel`` (:func:`acceleration_bound` with the constraint forces) plus the multipliers' error through
    the constraint force ``M^-1 Jc^T dlam``, ``||M^-1|| (||Jc||_2 cond(M) lam_scale + ||Jc^T||_inf lam_rounding)``.
    Componentwise, to first order in the KKT system ``[[M, Jc^T], [Jc, 0]] (qdd, -lam) = (tau - h, -Jcdot qd)``: a
    backward error ``(r1, r2)`` moves qdd by ``G r1 + X S^+ r2`` with ``X = M^-1 Jc^T``, ``S = Jc X`` and ``G = M^-1 -
    X S^+ X^T`` (the constrained response). ``|r1|`` is the unconstrained solve's (:func:`acceleration_bound`'s
    right-hand side, at the sizes of the free accelerations ``|qdd| + |X| |lam|`` a range-space solve forms first
    and cancels: a fuzz finding, a coupling holding a joint driven at 2560 rad/s^2 left 1.5e-10 against 1.2e-10
    computed at the answer's 0, and with the constraint forces), plus ``||M|| ||qdd||`` (the normwise backward
    error of the orthogonal factorizations the backends' constrained solves use: SVD, QR, eigh mix heavy and light
    rows; a fuzz finding, a 100 kg base beside 1 g links, geometric's ctrl 4e-9 off at 1000 rad/s^2 against 5e-10),
    plus ``T |lam|_1`` in every joint, T the rounding
    size of Jc's entries (:func:`_row_rounding`; the rows round into their structural zeros: a fuzz finding, two
    couplings where the null-space basis of one leaked 5.7e-15 of the other's multiplier into joints an exact solve
    leaves at rest); ``|r2|`` is ``|Jc| |M^-1| |r1|`` (the free accelerations' error in ``Jc a``), the rounding of
    ``Jcdot qd`` (the kinematics scale times ``|qd|_1^2``), ``T`` times the free accelerations and the S solve's
    ``||S|| |lam|_1``; the short-row rounding ``lam_rounding`` enters through ``|X|``.
    The normwise bound carries ``||M^-1||`` and ``cond(M)`` into every joint: the Panda's finger mimic (15 g fingers,
    ``||M^-1||`` about their inverse mass) made the arm joints' drift tolerance 50 times looser than without the
    coupling, and the 1e-10 canaries in C qd went unseen. Jc is the median of the voters'; where S is not finite
    the normwise bound stands alone."""
    mass = _mass(model, q)
    lam_error, lam_rounding = scales.get("lam_scale", 0.0), scales.get("lam_rounding", 0.0)
    Jc = _nanmedian([s.constraint_jacobian for s in constrained])
    lam = _nanmedian([np.abs(s.lam) + np.abs(s.lam_drift) for s in constrained])
    norm2 = _median([float(np.linalg.norm(s.constraint_jacobian, 2)) for s in constrained])
    normwise = accel + mass.inverse_norm * (norm2 * cond_M * lam_error
                                            + float(np.abs(Jc).sum(axis=0).max()) * lam_rounding)
    with np.errstate(over="ignore", invalid="ignore"):
        X = mass.inverse @ Jc.T
        if not np.all(np.isfinite(Jc @ X)):
            return normwise
        w, V = np.linalg.eigh(Jc @ X)
        kept = w > CONSTRAINT_RCOND * max(float(w.max()), 0.0)
        S_plus = (V[:, kept] / w[kept]) @ V[:, kept].T
        Mterm, f = _entry_terms(model, q, qd)
        d, row, lam_1 = mass.root_diagonal, _row_rounding(model, Jc), float(lam.sum())
        free = sizes + np.abs(X) @ lam          # the unconstrained accelerations a range-space solve forms first
        r1 = (f + Mterm @ free + d * float(d @ free) + np.abs(Jc).T @ lam + row * lam_1
              + mass.norm * float(np.linalg.norm(free)))
        r2 = (np.abs(Jc) @ (mass.abs_inverse @ r1) + scales.get("kinematics", 0.0) * scales.get("rate", 0.0) ** 2
              + row * float(free.sum()) + float(w.max()) * lam_1)
        G = mass.inverse - X @ S_plus @ X.T
        componentwise = np.abs(G) @ r1 + np.abs(X @ S_plus) @ r2 + np.abs(X).sum(axis=1) * lam_rounding
        return np.fmin(componentwise, normwise)


def _row_rounding(model, Jc: np.ndarray) -> float:
    """The size at which an entry of Jc rounds, eps aside: a joint coupling's row is its coefficients (``max|Jc|``,
    exact, but a backend's basis of the rows mixes them at that size); a geometric row is a sum of lever-sized terms,
    ``L (n + 1)`` with L the model's length scale, however small it comes out (:func:`_lam_rounding`; a fuzz finding:
    a row 8.7e-4 long holding a multiplier of 1e4 put 3e-12 into a structural zero of a moved scene)."""
    geometric = any(not isinstance(c, JointCoupling) for c in model.constraints)
    return max(float(np.abs(Jc).max()), _loads(model).length * (model.n + 1) if geometric else 0.0)


def _constraint_scales(model, splits, q, qd, rounding: dict[int, float]) -> dict[str, float]:
    """The constraint part of :class:`Scales` (module doc), medians over the constrained splits (``rounding``:
    :func:`_lam_rounding` of each, by ``id``)."""
    length = _loads(model).length
    jc_max = _median([float(np.abs(s.constraint_jacobian).max()) for s in splits])
    return {"cond_S": _median([s.conditions.get("constraint_kept", 1.0) for s in splits]),
            "lam_scale": _median([s.lam_scale for s in splits]),
            "jc": _median([float(np.abs(s.constraint_jacobian).sum(axis=0).max()) for s in splits]),
            "kinematics": (length**2 * (model.n + 1) + jc_max * (1.0 + float(np.abs(q).sum())))
            * _contact_gain(model, q),
            "rate": float(np.abs(qd).sum()),
            "lam_rounding": _median([rounding[id(s)] for s in splits])}


#: The least sine of a rolling disk's axle against the ground normal the contact gain uses (a flat disk has none).
MIN_CONTACT_SINE = 1e-8


def _contact_gain(model, q) -> float:
    """``1 / s^2`` with s the smallest ``|n x a|`` of the model's rolling contacts at q (``reference.contact_sines``);
    1 without one. The contact direction ``u = (n - (n.a) a) / s`` rounds at ``eps / s`` and its rate ``udot``, which
    enters ``Adot qd``, at ``eps / s^2`` (a leaning disk nearly flat: lean 1.587 rad, s = 0.016, put the backends'
    rolling biases 0.3 tolerances apart with the plain kinematics scale). The rolling direction of a ``lateral=False``
    contact, ``t = (a x n) / s`` (``|a x n| = s``), and its rate ``tdot`` are divided by the same s and round alike."""
    if not any(isinstance(c, RollingContact) for c in model.constraints):
        return 1.0

    return 1.0 / max(float(contact_sines(model, q).min()), MIN_CONTACT_SINE) ** 2


def _lam_rounding(model, split) -> float:
    """``(|lam|_1 + lam_scale) (T / sigma_r(Jc))``: a row of Jc is a sum of terms of size T (the kinematics scale over
    the length scale) and rounds at ``eps T`` however small it comes out, so a short row (a point 5e-5 m off a joint
    axis) has a relative error ``eps T / sigma_r`` that lam, ``S^-1 r``, inherits (a fuzz finding: lam = -1.4e5 off by
    2000 eps, 1.6 times a tolerance built from lam_scale alone); and that rounding, times the free accelerations in
    ``r = -Jcdot qd - Jc a``, is up to ``eps T accel_scale ||S^+||``, at most ``eps T lam_scale / sigma_r``, however
    small lam (a fuzz finding: a slide 1.8e-8 rad off the level, a row 1.5e-8 long, a rounding entry 1e-16 in it
    times a free acceleration of 6.6 moved lam from -6.3 to -3.1). sigma_r is Jc's smallest kept singular value."""
    if all(isinstance(c, JointCoupling) for c in model.constraints):
        return 0.0                   # a coupling's row is its coefficients, exact: no kinematics rounds in it
    sigma = np.linalg.svd(split.constraint_jacobian, compute_uv=False)
    rank = split.constraint_rank or 0
    if rank == 0:
        return 0.0
    size = max(float(np.abs(split.lam).sum()), float(np.abs(split.lam_drift).sum())) + split.lam_scale
    if not (np.isfinite(size) and sigma[rank - 1] > 0.0):
        return 0.0                   # an answer that is not finite fails on its own; it must not blur the tolerance
    return size * _loads(model).length * (model.n + 1) / float(sigma[rank - 1])


def tolerance(quantity: str, at: Scales):
    """Absolute tolerance for ``quantity`` at a state with these scales: a float (for the max-norm of a difference),
    or for the joint accelerations one per coordinate (:func:`acceleration_bound`)."""
    kind, factor = TOLERANCES[quantity]
    scale = at.of(kind)
    if np.ndim(scale):
        return factor * EPS * np.maximum(scale, TINY)
    return factor * EPS * max(scale, TINY)
