"""The tolerance policy: a tolerance is a claim about floating-point error, scaled by the problem.

For joint accelerations, solving ``M x = b`` in floating point gives ``|dx| <~ eps ||M^-1|| (H + cond(M) ||b||)``
with H the size of the summed terms; both parts are bounded by ``eps * cond(M) * accel_scale`` where
``accel_scale = ||M^-1|| H`` (formalisms.interface.conditioning defines H). Power is a sum of products, so
its error is a multiple of ``eps * sum_i |(B u)_i qd_i|``. A task acceleration ``J qdd + Jdot qd`` (eq. 23) maps
the joint error through J, whose columns are at most a lever arm L long (1 for a prismatic joint), and adds
the rounding of ``Jdot qd``, of size ``L |qd|^2``: its scale is ``L (cond(M) accel_scale + |qd|_1^2)``.
The kinetic energy ``1/2 qd^T M qd`` carries the error of M's entries, ``eps ||M|| |qd|^2 <= 2 eps cond(M) T``.

Constrained models (article 5.2-5.5). The multipliers solve ``S lam = r`` with ``S = Jc M^-1 Jc^T``; their scale is
``lam_scale = ||S^+|| (|Jcdot qd| + ||Jc|| accel_scale)`` (``formalisms.interface.constraint_conditioning``), which
already carries S's amplification (``||S^+||``, over the directions kept above ``CONSTRAINT_RCOND``); the
acceleration scale adds what the constraint force can produce, ``||M^-1|| ||Jc|| lam_scale``. ``Jc^T lam`` and its
power add ``||Jc^T||`` and ``|qd|_1``. The constraint kinematics (``phi``, ``Jc``, ``Jcdot qd``, ``Jc qd``) are sums of products of lengths: their
scale is ``L^2 (n + 1) + max|Jc| (1 + |q|_1)`` with L the model's length scale, times ``|qd|_1`` per time derivative.
Quantities with an exact value (``EXACT``) vote against it: a drift off ``H_t``, constraint power at an admissible
state, an inadmissible sampled state.

The scales are the median over the backends' own reports, so one backend misreporting its conditioning
cannot loosen the tolerance for the others. The factors below are data: each is a safety margin over the
largest error/scale ratio measured on correct backends (README, "Tolerances"), kept far below the O(1)
relative errors a modelling bug produces.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from crosscheck.sampling import length_scale
from formalisms.interface import Unsupported

EPS = float(np.finfo(float).eps)

#: quantity -> (scale kind, factor). tol = factor * eps * scale.
TOLERANCES: dict[str, tuple[str, float]] = {
    "drift": ("acceleration", 100.0),
    "ctrl": ("acceleration", 100.0),
    "total": ("acceleration", 100.0),
    "additivity": ("acceleration", 100.0),
    "power_ctrl": ("power", 100.0),
    "task_drift": ("task", 100.0),
    "kinetic_energy": ("energy", 100.0),
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
}

#: The quantities of a constrained model only (article 5), in report order.
CONSTRAINED_QUANTITIES = ("lam", "lam_drift", "constraint_force", "constraint_force_drift", "power_constr",
                          "power_constr_per_coord", "admissibility_drift", "admissibility_total", "constraint_value",
                          "constraint_velocity", "constraint_jacobian", "constraint_bias")

#: The quantities the gate compares on every model, in report order.
QUANTITIES = tuple(q for q in TOLERANCES if q not in CONSTRAINED_QUANTITIES)

#: Quantities with a value known exactly, which joins the vote as the voter ``exact``.
EXACT = {"additivity": 0.0, "power_constr": 0.0, "admissibility_drift": 0.0, "admissibility_total": 0.0,
         "constraint_value": 0.0, "constraint_velocity": 0.0}


def quantities(model) -> tuple[str, ...]:
    """The quantities compared on ``model``: the constrained ones join when it has constraints."""
    return QUANTITIES + (CONSTRAINED_QUANTITIES if model is not None and model.constraints else ())


#: condition name (``Split.conditions``) -> limit. Above it the formalism reporting the condition number is in
#: BREAKDOWN at that state: its method is ill-conditioned there, which is reported, not counted as a bug.
#: Calibrated by measurement (README, "Breakdown"): on paths into the task singularities of the planar chains
#: and the Panda, the largest error/tolerance of unflagged operational-space states is 0.064 at 1e3, 0.24 at
#: 1e4 and 4.5 at 1e6 (the recomposition's floor grows like eps |Jdot qd| sqrt(cond)).
BREAKDOWN_LIMITS: dict[str, float] = {
    "task": 1e3,                      # cond(J M^-1 J^T), operational space (article 6.3.4)
    "constraint": 1e8,                # cond(Jc M^-1 Jc^T): redundant or degenerate constraints (5.6)
    "constraint_kept": 1e8,           # the same over the directions kept: nearly (not exactly) redundant rows
    "constraint_consistency": 1e-8,   # share of the KKT right-hand side S cannot reach: H_t is empty (5.4)
}

#: condition name -> the quantities its BREAKDOWN leaves out; a condition not listed leaves out the whole backend.
#: Singular ``Jc M^-1 Jc^T`` makes only the multipliers non-unique: ``Jc^T lam`` and the accelerations stay unique.
BREAKDOWN_SCOPE: dict[str, tuple[str, ...]] = {
    "constraint": ("lam", "lam_drift"),
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
    """Problem scales at one state: the median of what the backends report."""

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

    def of(self, kind: str) -> float:
        acceleration = self.cond_M * self.accel_scale
        multiplier = self.cond_M * self.lam_scale
        scale = {
            "acceleration": acceleration,
            "power": self.power_scale,
            "task": self.lever * (acceleration + self.rate_sq),
            "energy": self.cond_M * self.energy,
            "multiplier": multiplier,
            "constraint_force": self.jc * multiplier,
            "constraint_power": (self.jc * multiplier + self.lam_scale * self.kinematics) * self.rate,
            "admissibility": self.jc * acceleration + self.kinematics * self.rate**2,
            "constraint_kinematics": self.kinematics,
            "constraint_velocity": self.kinematics * self.rate,
            "constraint_rate": self.kinematics * self.rate**2,
        }
        if kind not in scale:
            raise KeyError(f"unknown tolerance scale kind '{kind}'")
        return scale[kind]


def task_lever(model, q) -> float:
    """An upper bound on the length of the task Jacobian's columns: the sum of the placements along the task
    point's chain (prismatic joints add their travel and 1 for their unit column) plus the point's offset."""
    tp = model.task_point()
    lever, i = float(np.linalg.norm(tp.offset)), model.body_index(tp.body)
    while i >= 0:
        body = model.bodies[i]
        lever += float(np.linalg.norm(body.translation))
        if body.joint == "prismatic":
            lever += abs(float(q[i])) + 1.0
        i = model.parent_index[i]
    return lever


def scales(splits, model=None, q=None, qd=None) -> Scales:
    """Median scales over the backends' splits (an iterable of Split); the task scale needs the model and the
    state (``q``, ``qd``)."""
    splits = list(splits)
    task = {} if model is None else {"lever": task_lever(model, q), "rate_sq": float(np.abs(qd).sum()) ** 2}
    energies = [s.kinetic_energy for s in splits if not isinstance(s.kinetic_energy, Unsupported)]
    constrained = [s for s in splits if s.constraint_jacobian is not None]
    if model is not None and constrained:
        task.update(_constraint_scales(model, constrained, q, qd))
    return Scales(cond_M=float(np.median([s.cond_M for s in splits])),
                  accel_scale=float(np.median([s.accel_scale for s in splits])),
                  power_scale=float(np.median([np.abs(s.power_ctrl_per_coord).sum() for s in splits])),
                  energy=float(np.median(energies)) if energies else 0.0, **task)


def _constraint_scales(model, splits, q, qd) -> dict[str, float]:
    """The constraint part of :class:`Scales` (module doc), medians over the constrained splits."""
    length = length_scale(model)
    jc_max = float(np.median([np.abs(s.constraint_jacobian).max() for s in splits]))
    return {"cond_S": float(np.median([s.conditions.get("constraint_kept", 1.0) for s in splits])),
            "lam_scale": float(np.median([s.lam_scale for s in splits])),
            "jc": float(np.median([np.abs(s.constraint_jacobian).sum(axis=0).max() for s in splits])),
            "kinematics": length**2 * (model.n + 1) + jc_max * (1.0 + float(np.abs(q).sum())),
            "rate": float(np.abs(qd).sum())}


def tolerance(quantity: str, at: Scales) -> float:
    """Absolute tolerance for ``quantity`` (max-norm of a difference) at a state with these scales."""
    kind, factor = TOLERANCES[quantity]
    return factor * EPS * max(at.of(kind), np.finfo(float).tiny)
