"""BREAKDOWN is a claim, and claims are checked: the conditions of a state computed independently of the backends.

A backend that reports its method ill-conditioned at a state (``Split.conditions`` above ``tolerance
.BREAKDOWN_LIMITS``) leaves the vote there. A backend could escape every comparison that way: an operational-space
backend whose inverse mass matrix is garbage reports cond(task) = inf everywhere, is BREAKDOWN at every state, and
the gate would say PASS. So the harness computes every condition the backends report from Pinocchio's M, ``C qd``,
``g``, task Jacobian and constraint kinematics (``crosscheck.references.pinocchio.reference``), with its own code
(:func:`independent`), and :func:`audit` compares each backend's report with it:

* ``conditions: <name>`` (a check, voted like any comparison, the independent value voting as ``independent``):
  condition numbers agree when their logarithms differ by less than their rounding, ``100 eps (kappa cond(M) +
  L (n + 1) / sigma_min)`` relative (the smallest eigenvalue of ``J M^-1 J^T`` carries an absolute error of eps
  ``||A|| cond(M)``, and a row of J as short as sigma_min is relatively imprecise by eps L / sigma_min), values
  above twice the limit counting as equal (broken is broken); the consistency share is not compared (it is rounding
  wherever S has redundant directions and ``H_t`` is not empty, and methods round it differently by decades);
* a BREAKDOWN where the independent condition is below half its limit (for ``constraint_consistency``, a share of
  the right-hand side, below 1e-4 of it: :data:`MARGIN`) is a false claim: the backend is put back into the vote at
  that state, where its answers are compared like any other (and for a condition number the check fails).

The definitions are the backends' (``formalisms.interface`` documents them): ``task`` and ``task_inertia`` =
cond(J M^-1 J^T) of the model's default task point (inf where it is numerically singular), ``task_jacobian`` = ``L
||M^-1 J^T (J M^-1 J^T)^-1||_2`` with L the task lever (operational space); ``constraint`` = cond(S),
``S = Jc M^-1 Jc^T``, its largest eigenvalue taken at least the degenerate floor; ``constraint_kept`` the same over
the eigenvalues kept above :func:`redundant_below`; ``constraint_consistency`` the largest share of the KKT
right-hand sides ``-Jcdot qd - Jc M^-1 f`` (``f = B u - h`` and ``-h``) in S's redundant directions.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Mapping

import numpy as np
import scipy.linalg

from cases.model import Model
from crosscheck.core import tolerance
from crosscheck.core.compare import compare, Comparison
from crosscheck.references.pinocchio.kinematics import bias_forces, constraint_kinematics, mass_matrix, task_jacobian

EPS = float(np.finfo(float).eps)
#: The backends' rule for redundant and degenerate rows (docs/tolerances.md), stated again by the harness: the same
#: numbers as ``formalisms.interface.CONSTRAINT_RCOND`` and ``DEGENERATE_ROW`` (a test holds them equal), written
#: here so that a threshold changed there, which every backend would follow, is audited against the documented rule
#: and not against itself.
CONSTRAINT_RCOND = 1e-10
DEGENERATE_ROW = 1e-8
#: A BREAKDOWN claim is false when the independent condition is below its limit divided by this (condition numbers
#: by the default). The consistency share is rounding wherever S has redundant directions and H_t is not empty, and
#: with |r| at its floor that rounding reaches the limit itself (a campaign saw 1e-12 against 4e-11): a claim is
#: refused only where the harness's share is at most 1e-14 (at a regular state it is exactly 0).
MARGIN = {"constraint_consistency": 1e4}
DEFAULT_MARGIN = 2.0


def degenerate_floor(model: Model) -> float:
    """The smallest eigenvalue of ``J M^-1 J^T`` that is a direction and not rounding (interface docs):
    ``(DEGENERATE_ROW L)^2 / inertia_scale``."""
    return (DEGENERATE_ROW * model.length_scale) ** 2 / model.inertia_scale


def redundant_below(model: Model, w_max):
    """Eigenvalues of S at or below this are redundant directions: ``CONSTRAINT_RCOND`` times the largest, never less
    than :func:`degenerate_floor` (the harness's statement of the backends' rule, for
    :mod:`crosscheck.references.precise` and :func:`independent`; ``w_max`` may be an array)."""
    return np.maximum(CONSTRAINT_RCOND * np.asarray(w_max, dtype=float), degenerate_floor(model))


def _task_conditions(model: Model, q, M_factor, J: np.ndarray) -> tuple[float, float]:
    """cond(A), ``A = J M^-1 J^T`` (inf where numerically singular), and ``L ||M^-1 J^T A^-1||_2``, L the task lever
    (``tolerance.task_lever``; inf where A is numerically singular, as the backend's ``J_bar`` is NaN there)."""
    Minv_JT = scipy.linalg.cho_solve(M_factor, J.T)
    A = 0.5 * (J @ Minv_JT + (J @ Minv_JT).T)
    w = np.linalg.eigvalsh(A)
    floor = max(len(w) * EPS * w[-1], degenerate_floor(model))
    cond = float(w[-1] / w[0]) if np.all(np.isfinite(w)) and w[0] > floor else float("inf")
    if cond == float("inf"):
        return cond, cond
    J_bar = Minv_JT @ np.linalg.inv(A)
    return cond, tolerance.task_lever(model, q) * float(np.linalg.norm(J_bar, 2))


def normwise_scales(model: Model, M: np.ndarray, Cqd, g, tau, qd) -> tuple[float, float]:
    """``(cond(M), accel_scale)`` with ``accel_scale = ||M^-1|| H`` (the definition every backend reports in
    ``Split.accel_scale``): H the size of the forces summed in ``B u - C qd - g``, plus configuration-robust
    magnitudes of the terms that can cancel, ``||M|| |qd|^2`` for the velocity products and ``|gravity|_1
    sqrt(m_total ||M||)`` for gravity; 1-norms, so tiny vectors do not underflow."""
    return scales_of(M, Cqd, g, tau, qd, sum(b.mass for b in model.bodies), model.gravity)


def scales_of(M: np.ndarray, Cqd, g, tau, qd, mass: float, gravity) -> tuple[float, float]:
    """:func:`normwise_scales` with the model's total ``mass`` and ``gravity`` given (a plugin's own model of the
    scene: ``crosscheck.assemble.Sizes``)."""
    eig = np.linalg.eigvalsh(M)
    qd = np.asarray(qd, dtype=float)
    H = (np.abs(Cqd).sum() + np.abs(g).sum() + np.abs(tau).sum() + eig[-1] * float(qd @ qd)
         + np.abs(np.asarray(gravity, dtype=float)).sum() * np.sqrt(mass * eig[-1]))
    return float(eig[-1] / eig[0]), float(H / eig[0])


@dataclass(frozen=True)
class ConstraintConditions:
    """The conditioning of ``S = Jc M^-1 Jc^T`` at one state (module doc): cond S, over the kept directions, the
    rank, the inconsistency share, ``lam_scale = ||S^+|| (|Jcdot qd|_1 + ||Jc|| accel_scale)`` (the multipliers'
    size from the magnitudes summed into their right-hand side) and ``force_scale = ||M^-1|| ||Jc|| lam_scale``."""

    cond_S: float
    cond_kept: float
    rank: int
    inconsistency: float
    lam_scale: float
    force_scale: float


def constraint_conditions(model: Model, M: np.ndarray, Jc: np.ndarray, bias: np.ndarray, forces,
                          accel_scale: float) -> ConstraintConditions:
    """:class:`ConstraintConditions` from M, Jc and ``Jcdot qd``, with ``forces`` the right-hand sides ``B u - h``
    (total) and ``-h`` (drift); ``|r|`` taken at least ``1e-6 L accel_scale`` in the inconsistency share (where every
    row is degenerate, r itself is rounding)."""
    factor = scipy.linalg.cho_factor(M)
    X = scipy.linalg.cho_solve(factor, Jc.T)
    w, U = np.linalg.eigh(0.5 * (Jc @ X + (Jc @ X).T))
    kept = w > redundant_below(model, w[-1])
    w_max, rank = max(float(w[-1]), degenerate_floor(model)), int(kept.sum())
    jc_norm = float(np.linalg.norm(Jc, 2))
    lam_scale = float((np.abs(bias).sum() + jc_norm * accel_scale) / w[kept][0]) if rank else 0.0
    inconsistency = 0.0
    if rank < len(w):
        floor = 1e-6 * model.length_scale * accel_scale
        for f in forces:
            r = -bias - Jc @ scipy.linalg.cho_solve(factor, f)
            norm = max(float(np.linalg.norm(r)), floor)
            if norm > 0.0:
                inconsistency = max(inconsistency, float(np.linalg.norm(U[:, ~kept].T @ r)) / norm)
    return ConstraintConditions(w_max / float(w[0]) if w[0] > 0.0 else float("inf"),
                                w_max / float(w[kept][0]) if rank else 1.0, rank, inconsistency, lam_scale,
                                float(jc_norm * lam_scale / np.linalg.eigvalsh(M)[0]))


def _short(model: Model, J: np.ndarray) -> float:
    """``L (n + 1) / sigma``, sigma the smallest non-zero singular value of the rows J: a row is a sum of lever-sized
    terms and rounds at ``eps L`` however short it comes out, so a short row is relatively imprecise by this much
    times eps, and so is every eigenvalue of ``J M^-1 J^T`` it makes (a degenerate row below the floor too: its
    eigenvalue still sets cond S; a fuzz finding, a point 2e-9 m off its line, cond S 1.4 differing by 8e-8)."""
    sigma = np.linalg.svd(J, compute_uv=False) if J.size else np.zeros(0)
    sigma = sigma[sigma > 0.0]
    return model.length_scale * (model.n + 1) / float(sigma.min()) if sigma.size else 1.0


def independent(model: Model, q, qd, u) -> dict[str, float]:
    """Every condition a backend may report at the state, from Pinocchio's M, ``C qd``, ``g``, task Jacobian and
    constraint kinematics, by this module's own code (module doc), ``"M"``: cond(M), and the relative rounding of the
    rows the conditions are made of (:func:`_short`), ``"rows task"`` and ``"rows constraint"``."""
    q, qd, u = (np.asarray(x, dtype=float) for x in (q, qd, u))
    M = mass_matrix(model, q)
    factor = scipy.linalg.cho_factor(M)
    eig = np.linalg.eigvalsh(M)
    J = task_jacobian(model, q)
    task, short = _task_conditions(model, q, factor, J)
    out = {"M": float(eig[-1] / eig[0]), "task": task, "task_inertia": task, "task_jacobian": short,
           "rows task": _short(model, J), "rows constraint": 1.0}
    if model.constraints:
        Cqd, g = bias_forces(model, q, qd)
        tau = model.input_map @ u
        _, Jc, bias = constraint_kinematics(model, q, qd)
        cc = constraint_conditions(model, M, Jc, bias, (tau - Cqd - g, -Cqd - g),
                                   normwise_scales(model, M, Cqd, g, tau, qd)[1])
        out.update({"constraint": cc.cond_S, "constraint_kept": cc.cond_kept,
                    "constraint_consistency": cc.inconsistency, "rows constraint": _short(model, Jc)})
    return out


def _margin(name: str) -> float:
    return MARGIN.get(name, DEFAULT_MARGIN)


def _saturated(name: str, value: float) -> float:
    """A condition number as compared, on a log scale from 1 (its rounding is relative): above twice its limit all
    values are one (broken is broken)."""
    limit = tolerance.BREAKDOWN_LIMITS[name]
    value = min(value, 2.0 * limit) if value == value else value
    return float(np.log(max(value, 1.0)))


def audit(model: Model, state, splits: Mapping, breakdowns: dict[str, dict[str, float]]) -> dict[str, Comparison]:
    """Check every backend's reported conditions at ``state`` against :func:`independent` (module doc). Returns the
    ``conditions: <name>`` checks; removes from ``breakdowns`` (backend -> broken conditions) every false claim, so
    that backend votes at this state. Nothing is checked where the independent computation itself fails (a mass
    matrix that is not positive definite: every backend fails there on its own)."""
    try:
        truth = independent(model, state.q, state.qd, state.u)
    except (np.linalg.LinAlgError, ValueError):
        return {}
    out = {}
    for name in tolerance.BREAKDOWN_LIMITS:
        reported = {backend: s.conditions[name] for backend, s in splits.items() if name in s.conditions}
        if not reported or name not in truth:
            continue
        limit, margin, kappa = tolerance.BREAKDOWN_LIMITS[name], _margin(name), truth[name]
        for backend, value in reported.items():
            if not value <= limit and kappa <= limit / margin:
                breakdowns.get(backend, {}).pop(name, None)
        if name in MARGIN:
            continue     # a share of rounding: a refused claim is enough, the backend's answers then decide
        values = {backend: _saturated(name, v) for backend, v in reported.items()}
        values["independent"] = _saturated(name, kappa)
        rows = truth["rows constraint" if name.startswith("constraint") else "rows task"]
        tol = float(np.log(1.0 + max(1e-9, 100.0 * EPS * (min(kappa, 2.0 * limit) * truth["M"] + rows))))
        out[f"conditions: {name}"] = compare(name, values, tol)
    for backend in [b for b, broken in breakdowns.items() if not broken]:
        del breakdowns[backend]
    return out
