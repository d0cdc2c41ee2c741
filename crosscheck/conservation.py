"""Conservation checks at one state (article section 9; 4.7.1 step 3).

Energy. With ``E = T + V`` the energy rate along an acceleration is ``dE/dt = dE/dq . qd + dE/dqd . qdd``
(= ``qd^T M qdd + 1/2 qd^T Mdot qd + g . qd``). Under the drift nothing does work, so ``dE/dt = 0``; under the
total acceleration the only work is the input's, so ``dE/dt = u . B^T qd``. Each backend's accelerations are
put through one energy bookkeeping, the geometric formalism's ``energy_rate`` (automatic differentiation of
``T + V``), and the exact values vote with them, so a backend whose drift does work is named.

Christoffel identities. For the Christoffel-consistent ``C`` (``C_ij = sum_k Gamma_ijk qd_k``, first kind)
``Mdot - 2C`` is skew-symmetric, and ``C qd = M Gamma(qd, qd)`` equals the velocity-product vector that the
Euler–Lagrange derivation (Christoffel symbols of the first kind, symbolically) and Pinocchio (RNEA) compute,
when those backends are among the ones evaluated.
"""

from __future__ import annotations

from typing import Mapping

import numpy as np

from cases.model import Model
from crosscheck import tolerance as policy
from crosscheck.compare import Comparison, compare
from crosscheck.sampling import State
from formalisms import euler_lagrange, geometric
from formalisms.interface import Split

EPS = policy.EPS
FACTOR = 100.0


def _energy_rates(model: Model, q, qd, splits: Mapping[str, Split], force: float, cond_M: float):
    """Per backend: dE/dt at its drift and at its total minus its control power, and the tolerance.

    A backward-stable solve of ``M qdd = f`` leaves a residual of size ``eps (||M|| |qdd| + |f|)``, and the energy
    rate is ``qd . (M qdd - f)`` up to the terms it sums, so its rounding is ``eps (magnitude + |qd|_1 F)`` with F
    the size of the forces. Not every backend is backward stable: the operational-space recomposition (task part
    plus null-space part) has a forward error of ``eps cond(M)`` relative, and so a residual up to ``eps cond(M)
    |qd|_1 F`` (a fuzz finding: 7.5 times the backward-stable tolerance at cond(M) = 105), so F carries cond(M).
    """
    at_drift, at_total, tol = {}, {}, 0.0
    for name, split in splits.items():
        if not (np.all(np.isfinite(split.drift)) and np.all(np.isfinite(split.total))):
            at_drift[name] = at_total[name] = np.nan   # an overflowed answer fails here too, it does not crash
            continue
        drift = geometric.energy_rate(model, q, qd, split.drift)
        total = geometric.energy_rate(model, q, qd, split.total)
        at_drift[name], at_total[name] = drift.rate, total.rate - split.power_ctrl
        for rate in (drift, total):
            tol = max(tol, FACTOR * EPS * (rate.magnitude + abs(split.power_ctrl)
                                           + np.abs(qd).sum() * force * cond_M))
    return at_drift, at_total, tol


def checks(model: Model, state: State, splits: Mapping[str, Split],
           at: policy.Scales | None = None) -> dict[str, Comparison]:
    """Energy-rate and Christoffel checks at ``state`` for the (trusted) ``splits``; ``at``: their
    ``tolerance.scales`` at the state when the caller has them (computed here otherwise)."""
    q, qd = np.array(state.q), np.array(state.qd)
    if at is None:
        at = policy.scales(splits.values(), model, q, qd, u=state.u)
    M = geometric.metric(model, q)
    force = at.accel_scale * np.linalg.norm(M, 2) / at.cond_M       # H = accel_scale * lambda_min(M)
    at_drift, at_total, tol = _energy_rates(model, q, qd, splits, force, at.cond_M)
    # an acceleration the comparison accepts (within the drift tolerance) changes dE/dt = qd . (M qdd + ...) by up
    # to |M qd| . (that tolerance): the operational-space recomposition uses that room (a fuzz finding, 8x)
    tol = max(tol, float(np.sum(np.abs(M @ qd) * policy.tolerance("drift", at))))
    out = {"conservation: energy rate at drift": compare("dE/dt", {**at_drift, "exact": 0.0}, tol),
           "conservation: energy rate at total - power": compare("dE/dt - P", {**at_total, "exact": 0.0}, tol)}
    out.update(_christoffel(model, q, qd, splits, at, M, force))
    return out


def _christoffel(model: Model, q, qd, splits: Mapping[str, Split], at: policy.Scales, M: np.ndarray,
                 force: float) -> dict[str, Comparison]:
    """The skew-symmetry of ``Mdot - 2C`` and ``C qd`` three ways. Pinocchio's ``C qd`` is ``RNEA(q, qd, 0) - g``,
    so its rounding is that of the forces summed (``force`` = H, gravity included), times cond(M) for the
    geometric ``M (M^-1 Gamma_first)``."""
    Gamma = geometric.christoffel(model, q)                      # Gamma[i, j, k] = Gamma^i_jk
    first = np.einsum("il,ljk->ijk", M, Gamma)                   # Gamma_ijk, first kind
    C = first @ qd                                               # C_ij = sum_k Gamma_ijk qd_k
    Mdot = np.einsum("kij,k->ij", geometric.metric_derivatives(model, q), qd)
    N = Mdot - 2.0 * C
    # the entries of Mdot and C are sums of terms of size ||M|| |qd|_1 that can cancel to 0 (a fuzz finding: Mdot = 0
    # exactly, N + N^T = 1e-16 against a tolerance of 8e-30), so that is their floor
    terms = max(np.abs(Mdot).max() + np.abs(C).max(), np.linalg.norm(M, 2) * float(np.abs(qd).sum()))
    size = FACTOR * EPS * at.cond_M * (terms + np.finfo(float).tiny)
    Cqd = {"geometric": C @ qd}
    if "euler_lagrange" in splits:
        Cqd["euler_lagrange"] = euler_lagrange.terms(model, q, qd)[1]
    if "pinocchio" in splits and "Cqd" in splits["pinocchio"].extras:
        Cqd["pinocchio"] = splits["pinocchio"].extras["Cqd"]
    return {"conservation: Mdot - 2C skew-symmetric": compare("N + N^T", {"N + N^T": (N + N.T).ravel(),
                                                                          "exact": np.zeros(N.size)}, size),
            "conservation: C qd = M Gamma(qd, qd)": compare("C qd", Cqd, FACTOR * EPS * at.cond_M * force)}
