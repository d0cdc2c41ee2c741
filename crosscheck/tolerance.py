"""The tolerance policy: a tolerance is a claim about floating-point error, scaled by the problem.

For accelerations, solving ``M x = b`` in floating point gives ``|dx| <~ eps ||M^-1|| (H + cond(M) ||b||)``
with H the size of the summed terms; both parts are bounded by ``eps * cond(M) * accel_scale`` where
``accel_scale = ||M^-1|| H`` (formalisms.interface.conditioning defines H). Power is a sum of products, so
its error is a multiple of ``eps * sum_i |(B u)_i qd_i|``.

The scales are the median over the backends' own reports, so one backend misreporting its conditioning
cannot loosen the tolerance for the others. The factors below are data: each is a safety margin over the
largest error/scale ratio measured on correct backends (README, "Tolerances"), kept far below the O(1)
relative errors a modelling bug produces.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

EPS = float(np.finfo(float).eps)

#: quantity -> (scale kind, factor). tol = factor * eps * scale.
TOLERANCES: dict[str, tuple[str, float]] = {
    "drift": ("acceleration", 100.0),
    "ctrl": ("acceleration", 100.0),
    "total": ("acceleration", 100.0),
    "additivity": ("acceleration", 100.0),
    "power_ctrl": ("power", 100.0),
}

#: The quantities the gate compares, in report order.
QUANTITIES = tuple(TOLERANCES)

#: Quantities with a value known exactly, which joins the vote as the voter ``exact``.
EXACT = {"additivity": 0.0}


@dataclass(frozen=True)
class Scales:
    """Problem scales at one state: the median of what the backends report."""

    cond_M: float
    accel_scale: float
    power_scale: float

    def of(self, kind: str) -> float:
        if kind == "acceleration":
            return self.cond_M * self.accel_scale
        if kind == "power":
            return self.power_scale
        raise KeyError(f"unknown tolerance scale kind '{kind}'")


def scales(splits) -> Scales:
    """Median scales over the backends' splits (an iterable of Split)."""
    splits = list(splits)
    return Scales(cond_M=float(np.median([s.cond_M for s in splits])),
                  accel_scale=float(np.median([s.accel_scale for s in splits])),
                  power_scale=float(np.median([np.abs(s.power_ctrl_per_coord).sum() for s in splits])))


def tolerance(quantity: str, at: Scales) -> float:
    """Absolute tolerance for ``quantity`` (max-norm of a difference) at a state with these scales."""
    kind, factor = TOLERANCES[quantity]
    return factor * EPS * max(at.of(kind), np.finfo(float).tiny)
