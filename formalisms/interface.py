"""The one interface every formalism implements (DESIGN.md, "The data flow").

A formalism is a pure function ``split(model, q, qd, u) -> Split`` of an immutable model and a state.
The split is article eq. (9): ``qdd = qdd_drift + qdd_ctrl`` with ``qdd_drift`` the pointwise ZTCF sample
(eq. 10, u = 0) and ``qdd_ctrl`` the control contribution, computed directly (``M^-1 B u``), never as
``total - drift``.

With constraints (article 5.2-5.4) ``M qdd + h = B u + Jc^T lam`` and ``Jc qdd + Jcdot qd = 0`` (eq. 12, 13): total
and lam solve the KKT system, drift and lam_drift solve it with u = 0 (eq. 14), and ctrl is ``B_c B u`` with the
constraint-consistent input map ``B_c = M^-1 [I - Jc^T (Jc M^-1 Jc^T)^-1 Jc M^-1]`` (eq. 17), computed directly.
Redundant constraints make ``S = Jc M^-1 Jc^T`` singular: every backend then treats the eigen-directions of S
below ``CONSTRAINT_RCOND`` times its largest eigenvalue as redundant and returns the minimum-norm multipliers
(the generalized constraint force ``Jc^T lam`` and the accelerations stay unique).
"""

from __future__ import annotations

from dataclasses import dataclass, field, replace
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


#: Relative eigenvalue of ``S = Jc M^-1 Jc^T`` below which a constraint direction counts as redundant (module doc).
CONSTRAINT_RCOND = 1e-10
#: A constraint or task row shorter than this times the model's length scale (in the metric of M) is degenerate.
DEGENERATE_ROW = 1e-8


def degenerate_floor(model: Model) -> float:
    """The smallest eigenvalue of ``J M^-1 J^T`` (J the constraint rows Jc, or a task Jacobian) that is a direction
    and not rounding: ``(DEGENERATE_ROW L)^2 / inertia_scale``, L the model's length scale.

    A row that vanishes at a configuration (a constrained or task point on a joint axis, a direction the point cannot
    move in) comes out of some kinematics as exact zeros and of others as rounding (1e-17 L); relative to the largest
    eigenvalue, as a lone row, the rounding looks like a direction, and one backend enforced it (a fuzz finding).
    The floor is far above that rounding, ``(eps L)^2 ||M^-1||``, unless cond(M) exceeds 1e15, and far below a row of
    any physical size."""
    return (DEGENERATE_ROW * model.length_scale) ** 2 / model.inertia_scale


def redundant_below(model: Model, w_max):
    """Eigenvalues of ``S = Jc M^-1 Jc^T`` at or below this are redundant directions (module doc): ``CONSTRAINT_RCOND``
    times the largest, and never less than :func:`degenerate_floor`. ``w_max`` may be an array (one largest
    eigenvalue per state of a batch); the result then has its shape."""
    return np.maximum(CONSTRAINT_RCOND * np.asarray(w_max, dtype=float), degenerate_floor(model))


class StateError(ValueError):
    """A state (q, qd, u) does not fit the model: wrong length or non-finite entries."""


class ModelNotSupported(Exception):
    """Raised by ``split`` of a backend written for some mechanisms only (a closed form derived for one model, a
    plugin without constraint handling) on a model outside them, with the reason. The gate then reports that
    backend as NOT COMPARED on the whole case (listed as "not supplied by"): not a failure, not a silent skip.
    A backend that handles the model but not some quantity returns ``UNSUPPORTED`` for that quantity instead."""


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
    joint_wrenches       (n, 6) row ``i`` = ``[force(3), moment(3)]`` the parent exerts on body ``i`` through joint
                         ``i`` at ``qdd = total`` (article 6.1.5, 7.2), moment about body ``i``'s origin, both in body
                         frame ``i``; gravity and the constraint forces of ``lam`` included (point forces applied to the
                         bodies; a joint coupling's torque ``c_j lam`` is carried by its joints, like an actuator, so
                         the axis components are ``B u`` plus the coupling rows of ``Jc^T lam``). Body-frame loads:
                         invariant under a change of chart or of world frame. UNSUPPORTED from a formalism without
                         body-level forces.
    joint_wrenches_drift the same at ``qdd = drift`` with ``lam_drift`` (the passive loads of the ZTCF, article 6.1.4).
    task_inertia         (k, k) ``Lambda = (J M^-1 J^T)^-1`` (eq. 22) of ``model.task_point()`` in its task coordinates
                         ``x_task = D p`` (the point and directions of ``task_drift``), from this formalism's own J and
                         M. With constraints it is still the unconstrained M's (eq. 22 puts the constraints in
                         ``F_constr``). Invariant under a chart change (``J_p M_p^-1 J_p^T = J M^-1 J^T``) and a frame
                         change (the task directions turn with the scene). NaN where ``J M^-1 J^T`` is numerically
                         singular; a formalism that reports it also reports ``conditions["task_inertia"]`` (or, the
                         operational-space one, ``"task"``): cond(J M^-1 J^T). UNSUPPORTED from a formalism without
                         point kinematics.

    Constrained models only (None otherwise), each from the formalism's own kinematics:
    constraint_value     ``phi(q)`` (k,), the declarations' functions (``cases.constraints``).
    constraint_jacobian  ``Jc = dphi/dq`` (k x n).
    constraint_bias      ``Jcdot qd`` (k,), so that ``H_t = {qdd : Jc qdd = -Jcdot qd}`` (eq. 16).
    constraint_velocity  ``Jc qd`` (k,): zero at an admissible state (5.1).
    constraint_force     ``Jc^T lam`` (n,), the generalized constraint force; ``constraint_force_drift`` likewise.
    constraint_rank      rank of ``S = Jc M^-1 Jc^T`` (eigenvalues above ``CONSTRAINT_RCOND`` times the largest).
    lam_scale            the size of the multipliers the summed terms could produce (see :func:`constrained_split`).
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
    joint_wrenches: np.ndarray | Unsupported = UNSUPPORTED
    joint_wrenches_drift: np.ndarray | Unsupported = UNSUPPORTED
    task_inertia: np.ndarray | Unsupported = UNSUPPORTED
    constraint_value: np.ndarray | None = None
    constraint_jacobian: np.ndarray | None = None
    constraint_bias: np.ndarray | None = None
    constraint_velocity: np.ndarray | None = None
    constraint_force: np.ndarray | None = None
    constraint_force_drift: np.ndarray | None = None
    constraint_rank: int | None = None
    lam_scale: float = 0.0

    def __post_init__(self):
        """Validate and freeze: every array field becomes a read-only float array of the shape the contract gives it
        (n from ``drift``, k from ``lam``), scalars become floats; a field of the wrong shape is a ValueError naming
        it. A formalism builds its Split directly, from its own numbers; this checks only their form."""
        n = np.shape(self.drift)[0] if np.ndim(self.drift) == 1 else -1
        if n < 0:
            raise ValueError(f"a formalism returned drift of shape {np.shape(self.drift)}, expected (n,)")
        constrained = self.lam is not None and not isinstance(self.lam, Unsupported)
        k = int(np.size(self.lam)) if constrained else 0
        shapes = {"drift": (n,), "ctrl": (n,), "total": (n,), "power_ctrl_per_coord": (n,),
                  "joint_wrenches": (n, 6), "joint_wrenches_drift": (n, 6), "lam": (k,), "lam_drift": (k,),
                  "power_constr_per_coord": (n,), "constraint_value": (k,), "constraint_jacobian": (k, n),
                  "constraint_bias": (k,), "constraint_velocity": (k,), "constraint_force": (n,),
                  "constraint_force_drift": (n,)}
        for name, shape in shapes.items():
            value = getattr(self, name)
            if value is None or isinstance(value, Unsupported):
                continue
            arr = np.array(value, dtype=float).reshape(-1) if name in ("lam", "lam_drift") else np.array(
                value, dtype=float)
            if arr.shape != shape:
                raise ValueError(f"a formalism returned {name} of shape {arr.shape}, expected {shape}")
            arr.setflags(write=False)
            object.__setattr__(self, name, arr)
        for name in ("task_drift", "task_inertia"):
            value = getattr(self, name)
            if not isinstance(value, Unsupported):
                arr = np.array(value, dtype=float)
                arr.setflags(write=False)
                object.__setattr__(self, name, arr)
        for name in ("power_ctrl", "cond_M", "accel_scale", "lam_scale"):
            object.__setattr__(self, name, float(getattr(self, name)))
        for name in ("power_constr", "kinetic_energy"):
            value = getattr(self, name)
            if value is not None and not isinstance(value, Unsupported):
                object.__setattr__(self, name, float(value))
        object.__setattr__(self, "conditions", {key: float(v) for key, v in self.conditions.items()})
        object.__setattr__(self, "extras", dict(self.extras))

    @property
    def additivity(self) -> np.ndarray:
        """``drift + ctrl - total``: zero up to rounding, because the split of eq. (9) is exact (4.2, 5.3)."""
        return self.drift + self.ctrl - self.total

    @property
    def admissibility_drift(self) -> np.ndarray | None:
        """``Jc qdd_drift + Jcdot qd``: the drift's distance from ``H_t`` (eq. 16); zero up to rounding."""
        if self.constraint_jacobian is None:
            return None
        return self.constraint_jacobian @ self.drift + self.constraint_bias

    @property
    def admissibility_total(self) -> np.ndarray | None:
        """``Jc qdd + Jcdot qd`` for the total acceleration (eq. 13)."""
        if self.constraint_jacobian is None:
            return None
        return self.constraint_jacobian @ self.total + self.constraint_bias

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
class SplitBatch:
    """The split of N states at once (``split_batch(model, Q, QD, U)``), each row what ``split`` returns for that
    state: ``drift``, ``ctrl``, ``total`` (N, n) as in :class:`Split` (eq. 9, 10; ctrl ``B_c B u`` of eq. 17 computed
    directly), ``lam`` and ``lam_drift`` (N, k) the multipliers with and without input (eq. 12, 14; None when
    unconstrained; minimum-norm over redundant directions, the rule of :func:`redundant_below`)."""

    drift: np.ndarray
    ctrl: np.ndarray
    total: np.ndarray
    lam: np.ndarray | None = None
    lam_drift: np.ndarray | None = None

    def __len__(self) -> int:
        return len(self.drift)


def _numeric(label: str, value, kind: str) -> np.ndarray:
    """``value`` as a float array, or a :class:`StateError` saying that ``label`` is not a numeric ``kind``."""
    try:
        return np.array(value, dtype=float)
    except (TypeError, ValueError):
        raise StateError(f"{label} is not a numeric {kind}: {value!r}") from None


def check_batch(model: Model, Q, QD, U) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Return (Q, QD, U) as float arrays of shapes (N, n), (N, n), (N, m), or raise :class:`StateError` naming what
    does not fit."""
    out = []
    for label, value, size in (("Q", Q, model.n), ("QD", QD, model.n), ("U", U, model.m)):
        arr = _numeric(label, value, "array")
        if arr.ndim != 2 or arr.shape[1] != size:
            raise StateError(f"{label} must have shape (N, {size}) for model '{model.name}' (one row per state), "
                             f"got {arr.shape}")
        if not np.all(np.isfinite(arr)):
            bad = np.argwhere(~np.isfinite(arr))[0]
            raise StateError(f"{label} has non-finite entries (first at row {bad[0]}, column {bad[1]})")
        out.append(arr)
    if not len(out[0]) == len(out[1]) == len(out[2]):
        raise StateError(f"Q, QD and U must have the same number of rows (states), got {len(out[0])}, "
                         f"{len(out[1])} and {len(out[2])}")
    return out[0], out[1], out[2]


def split_batch_by_loop(split: Callable[[Model, np.ndarray, np.ndarray, np.ndarray], Split]):
    """A ``split_batch`` that calls ``split`` state by state: for a backend (a plugin) without its own."""
    def split_batch(model: Model, Q, QD, U) -> SplitBatch:
        Q, QD, U = check_batch(model, Q, QD, U)
        splits = [split(model, q, qd, u) for q, qd, u in zip(Q, QD, U)]

        def stack(name: str, width: int) -> np.ndarray:
            return np.array([getattr(s, name) for s in splits], dtype=float).reshape(len(Q), width)
        lam = (stack("lam", model.k), stack("lam_drift", model.k)) if model.k else (None, None)
        return SplitBatch(stack("drift", model.n), stack("ctrl", model.n), stack("total", model.n), *lam)
    return split_batch


@dataclass(frozen=True)
class Formalism:
    """A named formulation of rigid-body dynamics behind the shared ``split`` contract.

    ``split_chart(model, chart, p, pd, tau_p)``, when present, evaluates the same split directly in the chart
    ``q = psi(p)``: state ``(p, pd)``, the generalized force ``tau_p`` a covector in that chart, and the
    returned accelerations in that chart (``pdd``). None for a formalism that works only in the joint chart.
    ``split_batch(model, Q, QD, U)`` evaluates N states at once (:class:`SplitBatch`, rows equal to ``split``'s);
    None for a backend without one (the harness then loops over ``split``: :func:`split_batch_by_loop`).
    """

    name: str
    summary: str
    split: Callable[[Model, np.ndarray, np.ndarray, np.ndarray], Split]
    split_chart: Callable[[Model, Chart, np.ndarray, np.ndarray, np.ndarray], Split] | None = None
    split_batch: Callable[[Model, np.ndarray, np.ndarray, np.ndarray], SplitBatch] | None = None


def check_state(model: Model, q, qd, u) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Return (q, qd, u) as float arrays, or raise :class:`StateError` naming what does not fit."""
    out = []
    for label, value, size in (("q", q, model.n), ("qd", qd, model.n), ("u", u, model.m)):
        arr = _numeric(label, value, "vector")
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
        arr = _numeric(label, value, "vector")
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


def _optional(value):
    """A supplied optional quantity as a read-only float array; UNSUPPORTED stays UNSUPPORTED."""
    return value if isinstance(value, Unsupported) else _readonly(value)


def singular_below(model: Model, eig: np.ndarray):
    """A symmetric positive semi-definite ``J M^-1 J^T`` with ascending eigenvalues ``eig`` is numerically singular
    when its smallest is at or below this (NaN when any is not finite): ``k eps`` times the largest (eigvalsh's
    absolute accuracy) or :func:`degenerate_floor`, whichever is larger. ``eig`` may be stacked (..., k), one row
    per state of a batch; the result then has the leading shape."""
    eig = np.asarray(eig, dtype=float)
    floor = np.maximum(eig.shape[-1] * np.finfo(float).eps * eig[..., -1], degenerate_floor(model))
    return np.where(np.all(np.isfinite(eig), axis=-1), floor, np.nan)[()]


def task_space_inertia(model: Model, J: np.ndarray, factor) -> tuple[np.ndarray, float]:
    """``(Lambda, cond)``: the task-space inertia ``Lambda = (J M^-1 J^T)^-1`` of eq. (22) and ``cond_2(J M^-1 J^T)``
    from a formalism's own task Jacobian ``J`` (k x n) and the Cholesky factor of its own ``M``
    (:func:`factor_mass_matrix`). ``A = J M^-1 J^T`` is inverted in its eigen-axes; where it is numerically singular
    (its smallest eigenvalue not finite, not positive, below ``k eps`` times the largest or below
    :func:`degenerate_floor`: indistinguishable from zero) ``cond`` is inf and ``Lambda`` NaN, never a
    plausible-looking number."""
    A = J @ scipy.linalg.cho_solve(factor, J.T)
    w, V = np.linalg.eigh(0.5 * (A + A.T))
    if not singular_below(model, w) < w[0]:
        return np.full(A.shape, np.nan), float("inf")
    Lambda = (V / w) @ V.T
    return 0.5 * (Lambda + Lambda.T), float(w[-1] / w[0])


def unconstrained_split(*, drift, ctrl, total, tau_ctrl, qd, cond_M, accel_scale, extras=None,
                        task_drift=UNSUPPORTED, conditions=None, kinetic_energy=UNSUPPORTED,
                        joint_wrenches=UNSUPPORTED, joint_wrenches_drift=UNSUPPORTED,
                        task_inertia=UNSUPPORTED) -> Split:
    """Assemble the :class:`Split` of an unconstrained model (no multipliers, no constraint power)."""
    n = len(qd)
    for label, value in (("drift", drift), ("ctrl", ctrl), ("total", total)):
        if np.shape(value) != (n,):
            raise ValueError(f"a formalism returned {label} of shape {np.shape(value)}, expected ({n},)")
    for label, value in (("joint_wrenches", joint_wrenches), ("joint_wrenches_drift", joint_wrenches_drift)):
        if not isinstance(value, Unsupported) and np.shape(value) != (n, 6):
            raise ValueError(f"a formalism returned {label} of shape {np.shape(value)}, expected ({n}, 6)")
    p, per = joint_power(tau_ctrl, qd)
    return Split(drift=_readonly(drift), ctrl=_readonly(ctrl), total=_readonly(total), lam=None, lam_drift=None,
                 power_ctrl=p, power_ctrl_per_coord=_readonly(per), power_constr=None, power_constr_per_coord=None,
                 cond_M=float(cond_M), accel_scale=float(accel_scale), extras=dict(extras or {}),
                 task_drift=_optional(task_drift), conditions={k: float(v) for k, v in (conditions or {}).items()},
                 kinetic_energy=kinetic_energy if isinstance(kinetic_energy, Unsupported) else float(kinetic_energy),
                 joint_wrenches=_optional(joint_wrenches), joint_wrenches_drift=_optional(joint_wrenches_drift),
                 task_inertia=_optional(task_inertia))


@dataclass(frozen=True)
class ConstraintConditioning:
    """Conditioning of ``S = Jc M^-1 Jc^T`` at one state (see :func:`constraint_conditioning`)."""

    cond_S: float        # largest / smallest eigenvalue of S (inf when S is singular)
    cond_kept: float     # largest / smallest eigenvalue kept above CONSTRAINT_RCOND (what a solve amplifies)
    rank: int
    inconsistency: float  # relative size of the KKT right-hand sides in S's redundant directions (0 when none)
    lam_scale: float
    force_scale: float   # ||M^-1|| ||Jc|| lam_scale: the accelerations the constraint force can produce


def constraint_conditioning(model: Model, M: np.ndarray, Jc: np.ndarray, bias: np.ndarray,
                            forces: Sequence[np.ndarray], accel_scale: float) -> ConstraintConditioning:
    """Conditioning of the constrained problem from a formalism's own ``M``, ``Jc``, ``Jcdot qd``; ``forces`` are
    the right-hand sides ``B u - h`` (total) and ``-h`` (drift).

    The multipliers solve ``S lam = r`` with ``r = -Jcdot qd - Jc M^-1 f``. ``lam_scale = ||S^+|| (|Jcdot qd|_1 +
    ||Jc|| accel_scale)`` bounds their size from the magnitudes summed into r. When S is singular (redundant or
    degenerate constraints), ``inconsistency`` is ``max |U_0^T r| / |r|`` over the right-hand sides, with U_0 the
    redundant eigen-directions: non-zero means ``H_t`` is empty (the constraints cannot all hold, e.g. a four-bar
    at its change point moving off both branches) and no acceleration is the answer. |r| is taken at least
    ``1e-6 L accel_scale``: where every row is degenerate, r itself is rounding, and its share means nothing.
    """
    L = np.linalg.cholesky(M)
    X = np.linalg.solve(L, Jc.T)
    S = X.T @ X
    w, U = np.linalg.eigh(S)
    w_max = max(float(w[-1]), degenerate_floor(model))
    kept = w > redundant_below(model, w[-1])
    rank = int(kept.sum())
    Minv_norm = 1.0 / float(np.linalg.eigvalsh(M)[0])
    jc_norm = float(np.linalg.norm(Jc, 2))
    lam_scale = (np.abs(bias).sum() + jc_norm * accel_scale) / float(w[kept][0]) if rank else 0.0
    inconsistency = 0.0
    if rank < len(w):
        for f in forces:
            r = -bias - Jc @ np.linalg.solve(L.T, np.linalg.solve(L, f))
            size = max(float(np.linalg.norm(r)), 1e-6 * model.length_scale * accel_scale)
            if size > 0.0:
                inconsistency = max(inconsistency, float(np.linalg.norm(U[:, ~kept].T @ r) / size))
    return ConstraintConditioning(cond_S=float(w_max / w[0]) if w[0] > 0.0 else np.inf,
                                  cond_kept=float(w_max / w[kept][0]) if rank else 1.0, rank=rank,
                                  inconsistency=inconsistency, lam_scale=float(lam_scale),
                                  force_scale=Minv_norm * jc_norm * float(lam_scale))


def constrained_split(model: Model, *, M, Cqd, g, tau_ctrl, qd, phi, Jc, bias, drift, ctrl, total, lam, lam_drift,
                      extras=None, task_drift=UNSUPPORTED, conditions=None, kinetic_energy=UNSUPPORTED,
                      joint_wrenches=UNSUPPORTED, joint_wrenches_drift=UNSUPPORTED, task_inertia=UNSUPPORTED) -> Split:
    """Assemble the :class:`Split` of a constrained model from a formalism's own solve (eq. 12-17) and its own
    ``M``, ``C qd``, ``g``, ``phi``, ``Jc``, ``Jcdot qd``.

    Adds the constraint force ``Jc^T lam`` (and at the drift), the constraint power ``(Jc^T lam) . qd`` and per
    coordinate (5.5), and the conditions ``"constraint"`` (cond S: the multipliers are not unique above its limit)
    and ``"constraint_consistency"`` (non-zero when ``H_t`` is empty). ``accel_scale`` includes the accelerations
    the constraint force can produce.
    """
    n, k = len(qd), model.k
    Jc, bias, phi = (np.asarray(x, dtype=float) for x in (Jc, bias, phi))
    lam, lam_drift = np.asarray(lam, dtype=float).reshape(-1), np.asarray(lam_drift, dtype=float).reshape(-1)
    for label, value, shape in (("Jc", Jc, (k, n)), ("Jcdot qd", bias, (k,)), ("phi", phi, (k,)),
                                ("lam", lam, (k,)), ("lam_drift", lam_drift, (k,))):
        if value.shape != shape:
            raise ValueError(f"a formalism returned {label} of shape {value.shape}, expected {shape}")
    cond_M, accel_scale = conditioning(model, M, Cqd, g, tau_ctrl, qd)
    cc = constraint_conditioning(model, M, Jc, bias, (tau_ctrl - Cqd - g, -Cqd - g), accel_scale)
    base = unconstrained_split(drift=drift, ctrl=ctrl, total=total, tau_ctrl=tau_ctrl, qd=qd, cond_M=cond_M,
                               accel_scale=accel_scale + cc.force_scale, extras=extras, task_drift=task_drift,
                               conditions={**(conditions or {}), "constraint": cc.cond_S,
                                           "constraint_consistency": cc.inconsistency},
                               kinetic_energy=kinetic_energy, joint_wrenches=joint_wrenches,
                               joint_wrenches_drift=joint_wrenches_drift, task_inertia=task_inertia)
    force, force_drift = Jc.T @ lam, Jc.T @ lam_drift
    p_constr, per = joint_power(force, qd)
    return replace(base, lam=_readonly(lam), lam_drift=_readonly(lam_drift), power_constr=p_constr,
                   power_constr_per_coord=_readonly(per), constraint_value=_readonly(phi),
                   constraint_jacobian=_readonly(Jc), constraint_bias=_readonly(bias),
                   constraint_velocity=_readonly(Jc @ qd),
                   constraint_force=_readonly(force), constraint_force_drift=_readonly(force_drift),
                   constraint_rank=cc.rank, lam_scale=cc.lam_scale,
                   conditions={**base.conditions, "constraint_kept": cc.cond_kept})
