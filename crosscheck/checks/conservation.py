"""Conservation checks at one state (article section 9; 4.7.1 step 3).

Energy. With ``E = T + V`` the energy rate along an acceleration is ``dE/dt = dE/dq . qd + dE/dqd . qdd``
(= ``qd^T M qdd + 1/2 qd^T Mdot qd + g . qd``). Under the drift only the external loads (``cases.loads``) do work, so
``dE/dt = tau_ext . qd`` (0 without loads); under the total acceleration the input's work joins it, so ``dE/dt = u .
B^T qd + tau_ext . qd``. V is gravity's: a spring's energy is counted as the work of its force (its power is in
``power_ext``), so the check needs no potential of the loads. Each backend's accelerations are
put through one energy bookkeeping, the geometric formalism's ``energy_rate`` (automatic differentiation of
``T + V``), and the exact values vote with them, so a backend whose drift does work is named.

Christoffel identities. For the Christoffel-consistent ``C`` (``C_ij = sum_k Gamma_ijk qd_k``, first kind)
``Mdot - 2C`` is skew-symmetric, and ``C qd = M Gamma(qd, qd)`` equals the velocity-product vector that the
Euler–Lagrange derivation (Christoffel symbols of the first kind, symbolically) and Pinocchio (RNEA) compute,
when those backends are among the ones evaluated.

Momentum (Noether, article 9.2). Under the drift of an unconstrained model the only external loads are gravity and
the reactions of the joints that hold the tree to the world, and those do no work along the joints' own freedoms:
the momentum conjugate to each freedom changes only by gravity's share. With ``m`` the total mass, ``c`` the centre
of mass, ``P`` the linear momentum and ``L_G`` the angular momentum about c (world axes):

* every root on a free joint (a floating system): ``dP/dt = m g`` and ``dL_G/dt = 0``; with zero gravity both are
  conserved;
* one root, on a revolute joint with world axis ``a`` through ``O``: ``d/dt a . L_O = a . ((c - O) x m g)``
  (``L_O = L_G + (c - O) x P``), conserved when ``a`` is parallel to gravity; on a spherical joint centred at O, the
  whole ``dL_O/dt = (c - O) x m g``; on a prismatic joint along ``a``: ``d/dt a . P = m a . g``.

Armature (``Body.armature`` a: a rotor geared to the joint, outside the bodies). A rotor on a joint below the root
turns with that joint's rate alone, so it adds nothing to the root's law; the root's own rotor is held by the world
(its stator) and spins with the root's freedom, so its momentum ``a v_root`` joins the conserved quantity: ``d/dt (a .
L_O) + a_root qdd_root`` (revolute), ``d/dt (a . P) + a_root qdd_root`` (prismatic), ``dL_O/dt + a_root R wdot``
(spherical: the rotor's angular momentum ``a R w`` in the world, ``R`` the ball's world rotation; ``d/dt (R w) = R
wdot`` since ``w x w = 0``). A free joint has no armature (``cases.build``).

Each backend's drift is put through one momentum bookkeeping, the harness's ``dh_G/dt = A_G qdd + b`` (Pinocchio's
centroidal map on the model's data, ``crosscheck.references.pinocchio.kinematics.centroidal_momentum_map``), and the
exact rates vote with them. A drift the comparison accepts moves the rate by up to ``|A_G|`` times its tolerance, and
the rate's own rounding is eps times the terms it sums; the tolerance is their sum.
"""

from __future__ import annotations

from typing import Mapping

import numpy as np

from cases.model import Model
from crosscheck.core import tolerance
from crosscheck.core.compare import compare, Comparison
from crosscheck.core.sampling import State
from crosscheck.references.pinocchio.kinematics import centroidal_momentum_map
from formalisms import euler_lagrange, geometric
from formalisms.interface import Split

EPS = tolerance.EPS
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
    external = {name: _external_power(model, s) for name, s in splits.items()}
    finite = {name: bool(np.all(np.isfinite(s.drift)) and np.all(np.isfinite(s.total))) for name, s in splits.items()}
    rates = iter(geometric.energy_rates(model, q, qd, [a for name, s in splits.items() if finite[name]
                                                       for a in (s.drift, s.total)]))
    for name, split in splits.items():
        if not finite[name]:
            at_drift[name] = at_total[name] = np.nan   # an overflowed answer fails here too, it does not crash
            continue
        drift, total = next(rates), next(rates)
        at_drift[name], at_total[name] = drift.rate - external[name], total.rate - split.power_ctrl - external[name]
        for rate in (drift, total):
            tol = max(tol, FACTOR * EPS * (rate.magnitude + abs(split.power_ctrl) + abs(external[name])
                                           + np.abs(qd).sum() * force * cond_M))
    return at_drift, at_total, tol


def _external_power(model: Model, split: Split) -> float:
    """The external loads' power ``tau_ext . qd`` the split reports (``power_ext``), 0 for a model without loads; NaN
    when a backend does not report it for a loaded model (its energy balance cannot be closed)."""
    if not model.loads:
        return 0.0
    power = split.power_ext
    return float(power) if isinstance(power, (int, float)) else float("nan")


def checks(model: Model, state: State, splits: Mapping[str, Split],
           at: tolerance.Scales | None = None) -> dict[str, Comparison]:
    """Energy-rate, Christoffel and momentum checks at ``state`` for the (trusted) ``splits``; ``at``: their
    ``tolerance.scales`` at the state when the caller has them (computed here otherwise)."""
    q, qd = np.array(state.q), np.array(state.qd)
    if at is None:
        at = tolerance.scales(splits.values(), model, q, qd, u=state.u)
    M = geometric.metric(model, q)
    force = at.accel_scale * np.linalg.norm(M, 2) / at.cond_M       # H = accel_scale * lambda_min(M)
    at_drift, at_total, tol = _energy_rates(model, q, qd, splits, force, at.cond_M)
    # an acceleration the comparison accepts (within the drift tolerance) changes dE/dt = qd . (M qdd + ...) by up
    # to |M qd| . (that tolerance): the operational-space recomposition uses that room (a fuzz finding, 8x)
    tol = max(tol, float(np.sum(np.abs(M @ qd) * tolerance.tolerance("drift", at))))
    out = {"conservation: energy rate at drift": compare("dE/dt", {**at_drift, "exact": 0.0}, tol),
           "conservation: energy rate at total - power": compare("dE/dt - P", {**at_total, "exact": 0.0}, tol)}
    out.update(_christoffel(model, q, qd, splits, at, M, force))
    out.update(momentum_checks(model, state, splits, at))
    return out


def _christoffel(model: Model, q, qd, splits: Mapping[str, Split], at: tolerance.Scales, M: np.ndarray,
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


def _momentum_rows(model: Model, c: np.ndarray) -> tuple[np.ndarray, np.ndarray] | None:
    """``(R, exact)``: the checked rates are ``R (dh_G/dt)`` with R (r x 6) picking momentum components (about the
    root's point) and ``exact`` (r,) their value under the drift (module doc); None
    when no momentum law applies (constrained, external loads, several roots not all free, or no law for the root's
    joint)."""
    roots = [i for i, p in enumerate(model.parent_index) if p < 0]
    if model.constraints or model.loads:      # external loads change the momentum by their own wrench
        return None
    m, g = sum(b.mass for b in model.bodies), np.asarray(model.gravity, dtype=float)
    if all(model.bodies[i].joint == "free" for i in roots):
        return np.eye(6), np.concatenate([m * g, np.zeros(3)])
    if len(roots) != 1:
        return None
    root = model.bodies[roots[0]]
    lever = c - np.asarray(root.translation, dtype=float)            # c - O, O the root joint's origin (world)
    about_O = np.zeros((3, 6))                                        # L_O = L_G + (c - O) x P
    about_O[:, 3:] = np.eye(3)
    about_O[:, :3] = np.array([[0.0, -lever[2], lever[1]], [lever[2], 0.0, -lever[0]], [-lever[1], lever[0], 0.0]])
    moment = np.cross(lever, m * g)
    axis = np.asarray(root.rotation, dtype=float) @ np.asarray(root.axis, dtype=float)
    if root.joint == "spherical":
        return about_O, moment
    if root.joint == "revolute":
        return axis @ about_O[None], np.array([axis @ moment])
    if root.joint == "prismatic":
        row = np.concatenate([axis, np.zeros(3)])[None]
        return row, np.array([m * axis @ g])
    return None


def _root_rotor(model: Model, q: np.ndarray, rows: int) -> np.ndarray:
    """The rate of the root joint's rotor momentum as rows over the accelerations (module doc, "Armature"): zero
    without armature on the (single) root; ``a_root`` at the root's velocity for a revolute or prismatic root, ``a_root
    R`` over a spherical root's three, ``R = rotation @ R(quat)`` its world rotation."""
    out = np.zeros((rows, model.nv))
    roots = [i for i, p in enumerate(model.parent_index) if p < 0]
    if len(roots) != 1 or not model.bodies[roots[0]].armature:
        return out
    i = roots[0]
    root, k = model.bodies[i], model.v_index[roots[0]]
    if root.joint == "spherical":
        x, y, z, w = (float(v) for v in q[model.q_index[i]:model.q_index[i] + 4])
        K = np.array([[0.0, -z, y], [z, 0.0, -x], [-y, x, 0.0]])
        out[:, k:k + 3] = root.armature * (np.asarray(root.rotation, dtype=float) @ (np.eye(3) + 2 * w * K + 2 * K @ K))
    else:
        out[:, k] = root.armature
    return out


def momentum_checks(model: Model, state: State, splits: Mapping[str, Split],
                    at: tolerance.Scales | None = None) -> dict[str, Comparison]:
    """The momentum law of the model's roots under each backend's drift (module doc, "Momentum"); empty when no
    law applies."""
    q, qd = np.array(state.q), np.array(state.qd)
    A, b, c = centroidal_momentum_map(model, q, qd)
    rows = _momentum_rows(model, c)
    if rows is None or not splits:
        return {}
    R, exact = rows
    if at is None:
        at = tolerance.scales(splits.values(), model, q, qd, u=state.u)
    Q, bias = R @ A, R @ b
    Q = Q + _root_rotor(model, q, len(exact))
    rates = {name: Q @ s.drift + bias if np.all(np.isfinite(s.drift)) else np.full(len(exact), np.nan)
             for name, s in splits.items()}
    size = np.max([np.abs(Q) @ np.abs(s.drift) for s in splits.values() if np.all(np.isfinite(s.drift))]
                  + [np.zeros(len(exact))], axis=0)
    tol = (np.abs(Q) @ np.broadcast_to(tolerance.tolerance("drift", at), (model.nv,))
           + FACTOR * EPS * (size + np.abs(bias) + np.abs(exact) + np.abs(R) @ np.abs(b)))
    return {"conservation: momentum rate at drift (Noether)": compare("dh/dt", {**rates, "exact": exact}, tol)}
