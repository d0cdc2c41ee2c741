"""The tolerance policy: a tolerance is a claim about floating-point error, scaled by the problem.

For joint accelerations, solving ``M x = b`` in floating point gives ``|dx| <~ eps ||M^-1|| (H + cond(M) ||b||)``
with H the size of the summed terms; both parts are bounded by ``eps * cond(M) * accel_scale`` where
``accel_scale = ||M^-1|| H`` (formalisms.interface.conditioning defines H). Power is a sum of products, so
its error is a multiple of ``eps * sum_i |(B u)_i qd_i|``. A task acceleration ``J qdd + Jdot qd`` (eq. 23) maps
the joint error through J, whose columns are at most a lever arm L long (1 for a prismatic joint), and adds
the rounding of ``Jdot qd``, of size ``L |qd|^2``: its scale is ``L (cond(M) accel_scale + |qd|_1^2)``.
The kinetic energy ``1/2 qd^T M qd`` carries the error of M's entries, ``eps ||M|| |qd|^2 <= 2 eps cond(M) T``.

The scales are the median over the backends' own reports, so one backend misreporting its conditioning
cannot loosen the tolerance for the others. The factors below are data: each is a safety margin over the
largest error/scale ratio measured on correct backends (README, "Tolerances"), kept far below the O(1)
relative errors a modelling bug produces.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

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
}

#: The quantities the gate compares, in report order.
QUANTITIES = tuple(TOLERANCES)

#: Quantities with a value known exactly, which joins the vote as the voter ``exact``.
EXACT = {"additivity": 0.0}


#: condition name (``Split.conditions``) -> limit. Above it the formalism reporting the condition number is in
#: BREAKDOWN at that state: its method is ill-conditioned there, which is reported, not counted as a bug.
#: Calibrated by measurement (README, "Breakdown"): on paths into the task singularities of the planar chains
#: and the Panda, the largest error/tolerance of unflagged operational-space states is 0.064 at 1e3, 0.24 at
#: 1e4 and 4.5 at 1e6 (the recomposition's floor grows like eps |Jdot qd| sqrt(cond)).
BREAKDOWN_LIMITS: dict[str, float] = {
    "task": 1e3,   # cond(J M^-1 J^T), operational space (article 6.3.4)
}


def breakdown(split) -> dict[str, float]:
    """The conditions of ``split`` above their limits (NaN or inf included), by name; empty when none."""
    return {name: value for name, value in split.conditions.items()
            if not value <= BREAKDOWN_LIMITS.get(name, np.inf)}


@dataclass(frozen=True)
class Scales:
    """Problem scales at one state: the median of what the backends report."""

    cond_M: float
    accel_scale: float
    power_scale: float
    lever: float = 0.0
    rate_sq: float = 0.0
    energy: float = 0.0

    def of(self, kind: str) -> float:
        if kind == "acceleration":
            return self.cond_M * self.accel_scale
        if kind == "power":
            return self.power_scale
        if kind == "task":
            return self.lever * (self.cond_M * self.accel_scale + self.rate_sq)
        if kind == "energy":
            return self.cond_M * self.energy
        raise KeyError(f"unknown tolerance scale kind '{kind}'")


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
    return Scales(cond_M=float(np.median([s.cond_M for s in splits])),
                  accel_scale=float(np.median([s.accel_scale for s in splits])),
                  power_scale=float(np.median([np.abs(s.power_ctrl_per_coord).sum() for s in splits])),
                  energy=float(np.median(energies)) if energies else 0.0, **task)


def tolerance(quantity: str, at: Scales) -> float:
    """Absolute tolerance for ``quantity`` (max-norm of a difference) at a state with these scales."""
    kind, factor = TOLERANCES[quantity]
    return factor * EPS * max(at.of(kind), np.finfo(float).tiny)
