"""The one interface every formalism implements (DESIGN.md, "The data flow").

A formalism is a pure function ``split(model, q, qd, u) -> Split`` of an immutable model and a state.
The split is article eq. (9): ``qdd = qdd_drift + qdd_ctrl`` with ``qdd_drift`` the pointwise ZTCF sample
(eq. 10, u = 0) and ``qdd_ctrl`` the control contribution, computed directly (``M^-1 B u``), never as
``total - drift``.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any, Callable, Mapping, Protocol, Sequence

import numpy as np
import scipy.linalg

from cases.model import Model


class Unsupported:
    """Marker for a quantity a formalism declares it cannot produce; the harness reports "not compared"."""

    _instance = None

    def __new__(cls):
        if cls._instance is None:
            cls._instance = super().__new__(cls)
        return cls._instance

    def __repr__(self) -> str:
        return "UNSUPPORTED"


UNSUPPORTED = Unsupported()


class StateError(ValueError):
    """A state (q, qd, u) does not fit the model: wrong length or non-finite entries."""


@dataclass(frozen=True)
class Split:
    """What every formalism returns for one state.

    drift, ctrl, total   joint accelerations (n,): eq. (10), ``M^-1 B u``, and the full solve of eq. (2).
    lam, lam_drift       constraint multipliers with and without input (eq. 12, 14); None when unconstrained.
    power_ctrl           ``u . (B^T qd)`` (W); ``power_ctrl_per_coord[i] = (B u)_i qd_i``.
    power_constr         ``(Jc^T lam) . qd``, None when unconstrained; per coordinate likewise.
    cond_M               2-norm condition number of the mass matrix this formalism solved with.
    accel_scale          the size of the accelerations the summed terms could produce (see
                         :func:`conditioning`); the harness scales tolerances by it (DESIGN.md, tolerances).
    task_drift           classical acceleration (second time derivative of position, not spatial) of the model's
                         default task point ``model.task_point()`` at the drift, in its task coordinates
                         ``x_task = D p`` (eq. 23); UNSUPPORTED from a formalism without point kinematics.
    kinetic_energy       ``T = 1/2 qd^T M qd`` (J) at the state, from this formalism's own bookkeeping; chart- and
                         frame-invariant (article 9.1); UNSUPPORTED when a formalism does not report it.
    conditions           condition numbers of the method-specific matrices this formalism inverted, by name
                         (operational space: ``"task"`` = cond(J M^-1 J^T)); the harness declares the state a
                         BREAKDOWN of this formalism above the limits in ``crosscheck.tolerance``.
    extras               formalism-specific outputs by name, e.g. Newton–Euler ``joint_reactions``: the force and
                         moment the parent exerts on each body, about the body-frame origin (for a revolute
                         joint the joint origin; for a prismatic one the point on the moving side).
    """

    drift: np.ndarray
    ctrl: np.ndarray
    total: np.ndarray
    lam: np.ndarray | None | Unsupported
    lam_drift: np.ndarray | None | Unsupported
    power_ctrl: float
    power_ctrl_per_coord: np.ndarray
    power_constr: float | None | Unsupported
    power_constr_per_coord: np.ndarray | None | Unsupported
    cond_M: float
    accel_scale: float
    extras: Mapping[str, Any] = field(default_factory=dict)
    task_drift: np.ndarray | Unsupported = UNSUPPORTED
    conditions: Mapping[str, float] = field(default_factory=dict)
    kinetic_energy: float | Unsupported = UNSUPPORTED

    @property
    def additivity(self) -> np.ndarray:
        """``drift + ctrl - total``: zero up to rounding, because the split of eq. (9) is exact (4.2)."""
        return self.drift + self.ctrl - self.total

    def quantity(self, name: str):
        """A compared quantity by name (``drift``, ``ctrl``, ``total``, ``additivity``, ``power_ctrl``, ...)."""
        return getattr(self, name)


class Chart(Protocol):
    """A coordinate chart ``q = psi(p)`` of the configuration manifold (article 6.4.6, 9.1; DESIGN.md, charts).

    ``psi`` is written once against the scalar operations every symbolic library shares, so a formalism
    evaluates it in its own language (numbers, casadi, SymEngine) and differentiates it itself: it takes the
    chart coordinates as a sequence of scalars and the library's ``sin`` and ``cos``, and returns the joint
    coordinates as a list. ``key`` is a stable digest of the chart's definition, for caches.
    """

    name: str
    key: str

    def psi(self, p: Sequence, sin: Callable, cos: Callable) -> list: ...


@dataclass(frozen=True)
class Formalism:
    """A named formulation of rigid-body dynamics behind the shared ``split`` contract.

    ``split_chart(model, chart, p, pd, tau_p)``, when present, evaluates the same split directly in the chart
    ``q = psi(p)``: state ``(p, pd)``, the generalized force ``tau_p`` a covector in that chart, and the
    returned accelerations in that chart (``pdd``). None for a formalism that works only in the joint chart.
    """

    name: str
    summary: str
    split: Callable[[Model, np.ndarray, np.ndarray, np.ndarray], Split]
    split_chart: Callable[[Model, Chart, np.ndarray, np.ndarray, np.ndarray], Split] | None = None


def check_state(model: Model, q, qd, u) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Return (q, qd, u) as float arrays, or raise :class:`StateError` naming what does not fit."""
    out = []
    for label, value, size in (("q", q, model.n), ("qd", qd, model.n), ("u", u, model.m)):
        try:
            arr = np.array(value, dtype=float)
        except (TypeError, ValueError):
            raise StateError(f"{label} is not a numeric vector: {value!r}") from None
        if arr.ndim != 1:
            raise StateError(f"{label} must be a 1-D vector of length {size}, got an array of shape {arr.shape}")
        if arr.size != size:
            raise StateError(f"{label} has {arr.size} entries but model '{model.name}' needs {size}")
        if not np.all(np.isfinite(arr)):
            raise StateError(f"{label} has non-finite entries: {arr.tolist()}")
        out.append(arr)
    return out[0], out[1], out[2]


def chart_vectors(model: Model, **vectors) -> list[np.ndarray]:
    """The named arguments (e.g. ``p``, ``pd``, ``tau_p`` of ``split_chart``) as finite float vectors with one entry
    per coordinate, or a :class:`StateError` naming the one that does not fit."""
    out = []
    for label, value in vectors.items():
        try:
            arr = np.array(value, dtype=float)
        except (TypeError, ValueError):
            raise StateError(f"{label} is not a numeric vector: {value!r}") from None
        if arr.ndim != 1 or arr.size != model.n:
            raise StateError(f"{label} has shape {arr.shape} ({arr.size} entries) but model '{model.name}' needs "
                             f"{model.n} values (one per coordinate)")
        if not np.all(np.isfinite(arr)):
            raise StateError(f"{label} has non-finite entries: {arr.tolist()}")
        out.append(arr)
    return out


def joint_vectors(model: Model, *vectors) -> list[np.ndarray]:
    """The arguments as float vectors of length n (e.g. ``q, qd, qdd`` of an inverse-dynamics call), or a
    :class:`StateError` naming the sizes."""
    out = [np.asarray(v, dtype=float).reshape(-1) for v in vectors]
    if any(v.size != model.n for v in out):
        raise StateError(f"model '{model.name}' needs {model.n} joint values per vector; got sizes "
                         f"{[v.size for v in out]}")
    return out


def factor_mass_matrix(model: Model, M: np.ndarray, q: np.ndarray, chart: str | None = None):
    """Cholesky factor of ``M`` (``scipy.linalg.cho_factor``); a mass matrix that is not positive definite (e.g. a
    point mass on its own joint axis) is a ValueError naming the model, the configuration and the eigenvalues.
    With ``chart`` (its name), ``M`` and ``q`` are the chart's ``M_p = Dpsi^T M Dpsi`` and ``p``."""
    try:
        return scipy.linalg.cho_factor(M)
    except np.linalg.LinAlgError:
        where = f"q = {q.tolist()}" if chart is None else (
            f"p = {q.tolist()} in chart '{chart}' (M_p = Dpsi^T M Dpsi is singular wherever Dpsi is)")
        raise ValueError(f"model '{model.name}': the mass matrix is not positive definite at {where} "
                         f"(Cholesky failed); eigenvalues {np.linalg.eigvalsh(M).tolist()}") from None


def conditioning(model: Model, M: np.ndarray, Cqd: np.ndarray, g: np.ndarray, tau: np.ndarray,
                 qd: np.ndarray) -> tuple[float, float]:
    """``(cond(M), accel_scale)`` from a formalism's own M, C qd, g and applied force ``tau``.

    ``accel_scale = ||M^-1||_2 * H`` with H the size of the generalized forces summed in ``B u - C qd - g``.
    The computed ``C qd`` and ``g`` can cancel to zero while their terms do not (a folded arm, zero
    gravity), so H also carries configuration-robust magnitudes of those terms: ``||M|| |qd|^2`` for the
    velocity products and ``|gravity| sqrt(m_total ||M||)`` (a mass times a lever arm) for gravity.
    1-norms, so tiny vectors do not underflow.
    """
    eig = np.linalg.eigvalsh(M)
    m_total = sum(b.mass for b in model.bodies)
    H = (np.abs(Cqd).sum() + np.abs(g).sum() + np.abs(tau).sum() + eig[-1] * float(qd @ qd)
         + np.abs(model.gravity).sum() * np.sqrt(m_total * eig[-1]))
    return float(eig[-1] / eig[0]), float(H / eig[0])


def joint_power(tau: np.ndarray, qd: np.ndarray) -> tuple[float, np.ndarray]:
    """Power of a generalized force on the joint velocities: total ``tau . qd`` and per coordinate."""
    per = tau * qd
    return float(per.sum()), per


def _readonly(arr: np.ndarray) -> np.ndarray:
    arr = np.array(arr, dtype=float)
    arr.setflags(write=False)
    return arr


def unconstrained_split(*, drift, ctrl, total, tau_ctrl, qd, cond_M, accel_scale, extras=None,
                        task_drift=UNSUPPORTED, conditions=None, kinetic_energy=UNSUPPORTED) -> Split:
    """Assemble the :class:`Split` of an unconstrained model (no multipliers, no constraint power)."""
    n = len(qd)
    for label, value in (("drift", drift), ("ctrl", ctrl), ("total", total)):
        if np.shape(value) != (n,):
            raise ValueError(f"a formalism returned {label} of shape {np.shape(value)}, expected ({n},)")
    p, per = joint_power(tau_ctrl, qd)
    return Split(drift=_readonly(drift), ctrl=_readonly(ctrl), total=_readonly(total), lam=None, lam_drift=None,
                 power_ctrl=p, power_ctrl_per_coord=_readonly(per), power_constr=None, power_constr_per_coord=None,
                 cond_M=float(cond_M), accel_scale=float(accel_scale), extras=dict(extras or {}),
                 task_drift=task_drift if isinstance(task_drift, Unsupported) else _readonly(task_drift),
                 conditions={k: float(v) for k, v in (conditions or {}).items()},
                 kinetic_energy=kinetic_energy if isinstance(kinetic_energy, Unsupported) else float(kinetic_energy))
