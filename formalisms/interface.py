"""The one interface every formalism implements (docs/design.md, "The data flow").

A formalism is a pure function ``split(model, q, qd, u) -> Split`` of an immutable model and a state.
The split is article eq. (9): ``qdd = qdd_drift + qdd_ctrl`` with ``qdd_drift`` the pointwise ZTCF sample
(eq. 10, u = 0) and ``qdd_ctrl`` the control contribution, computed directly (``M^-1 B u``), never as
``total - drift``.

External loads (article 2.3, eq. 12, 14; ``cases.loads``): ``M qdd + h = B u + tau_ext``, each backend mapping the
model's declarations to ``tau_ext`` with its own kinematics. ``tau_ext`` enters the drift, ``drift = M^-1 (tau_ext -
h)``, and, being velocity-independent, the drift's part at rest: ``zvcf = M^-1 (tau_ext - g)``; ctrl is unchanged.
With constraints (article 5.2-5.4) ``M qdd + h = B u + Jc^T lam`` and ``Jc qdd + Jcdot qd = 0`` (eq. 12, 13): total
and lam solve the KKT system, drift and lam_drift solve it with u = 0 (eq. 14), and ctrl is ``B_c B u`` with the
constraint-consistent input map ``B_c = M^-1 [I - Jc^T (Jc M^-1 Jc^T)^-1 Jc M^-1]`` (eq. 17), computed directly.
Redundant constraints make ``S = Jc M^-1 Jc^T`` singular: every backend then treats the eigen-directions of S
below ``CONSTRAINT_RCOND`` times its largest eigenvalue as redundant and returns the minimum-norm multipliers
(the generalized constraint force ``Jc^T lam`` and the accelerations stay unique).

This module holds only what every backend must agree on to be compared at all: types (:class:`Split`,
:class:`SplitBatch`, :class:`Formalism`, :class:`Chart`), constants (the rule for redundant and degenerate rows),
validators of the state vectors and exceptions (docs/design.md, "Independence is the product"). Every number a backend
reports, its power, constraint forces, factorization, rank decision, conditioning and task inertia, it computes
itself, its own way; ``tests/backends/test_independence.py`` holds the formalisms to the names listed in :data:`__all__`.
The definitions those numbers follow are written out in :class:`Split`'s fields below.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any, Callable, Mapping, Protocol, Sequence

import numpy as np

from cases.configuration import UNIT_TOL, quaternion_slices
from cases.model import Model
from formalisms.cache import cache_dir, used_cache_file, write_cache_file  # the backends' cache plumbing


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


#: Relative eigenvalue of ``S = Jc M^-1 Jc^T`` below which a constraint direction counts as redundant (module doc):
#: an eigenvalue at or below ``max(CONSTRAINT_RCOND w_max, floor)`` is redundant, the floor below.
CONSTRAINT_RCOND = 1e-10
#: A constraint or task row shorter than this times the model's length scale (in the metric of M) is degenerate: the
#: floor ``(DEGENERATE_ROW L)^2 / inertia_scale`` (``Model.length_scale``, ``Model.inertia_scale``) is the smallest
#: eigenvalue of ``J M^-1 J^T`` that is a direction and not rounding (a row that vanishes at a configuration comes
#: out of some kinematics as exact zeros and of others as 1e-17 L). A task ``J M^-1 J^T`` is numerically singular
#: when its smallest eigenvalue is not above ``max(k eps w_max, floor)``.
DEGENERATE_ROW = 1e-8


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
                         ``||M^-1||_2 H``, H = ``|C qd|_1 + |g|_1 + |B u|_1 + ||M|| |qd|^2 + |gravity|_1
                         sqrt(m_total ||M||)``: the forces summed, with configuration-robust magnitudes of the terms
                         that can cancel); the harness scales tolerances by it (docs/design.md, tolerances). With
                         constraints it adds ``force_scale = ||M^-1|| ||Jc|| lam_scale``.
    task_drift           classical acceleration (second time derivative of position, not spatial) of the model's
                         default task point ``model.task_point()`` at the drift, in its task coordinates
                         ``x_task = D p`` (eq. 23); UNSUPPORTED from a formalism without point kinematics.
    kinetic_energy       ``T = 1/2 qd^T M qd`` (J) at the state, from this formalism's own bookkeeping; chart- and
                         frame-invariant (article 9.1); UNSUPPORTED when a formalism does not report it.
    conditions           condition numbers of the method-specific matrices this formalism inverted, by name
                         (operational space: ``"task"`` = cond(J M^-1 J^T)); the harness declares the state a
                         BREAKDOWN of this formalism above the limits in ``crosscheck.core.tolerance``.
    extras               formalism-specific outputs by name, e.g. Newton–Euler ``joint_reactions``: the force and
                         moment the parent exerts on each body, about the body-frame origin (for a revolute
                         joint the joint origin; for a prismatic one the point on the moving side).
    joint_wrenches       (bodies, 6) row ``i`` = ``[force(3), moment(3)]`` the parent exerts on body ``i`` through joint
                         ``i`` at ``qdd = total`` (article 6.1.5, 7.2), moment about body ``i``'s origin, both in body
                         frame ``i``; gravity and the constraint forces of ``lam`` included (point forces applied to the
                         bodies; a joint coupling's torque ``c_j lam`` is carried by its joints, like an actuator, so
                         the axis components are ``B u`` plus the coupling rows of ``Jc^T lam``). Body-frame loads:
                         invariant under a change of chart or of world frame. UNSUPPORTED from a formalism without
                         body-level forces.
    joint_wrenches_drift the same at ``qdd = drift`` with ``lam_drift`` (the passive loads of the ZTCF, article 6.1.4).
                         The external loads (``cases.loads``) are applied to their bodies in both.
    external_force       ``tau_ext`` (n,), the generalized force of the model's external loads (eq. 12; ``cases.loads``:
                         ``J_p^T f + J_w^T m`` summed over them), from this formalism's own kinematics; in a chart a
                         covector (``Dpsi^T tau_ext``). None for a model without loads.
    power_ext            ``tau_ext . qd`` (W), the external loads' power (beside ``power_ctrl``); None without loads.
    zvcf                 the zero-velocity counterfactual (article 4.5-4.6): the drift at the same ``q`` with ``qd =
    0``,
                         gravity's part of the drift, ``-M^-1 g`` (with constraints the KKT solve with ``f = -g`` and
                         ``Jcdot qd = 0``), computed directly; UNSUPPORTED when a formalism does not report it. With
                         external loads (all velocity-independent) ``M^-1 (tau_ext - g)``: the drift at rest.
    drift_velocity       the velocity-product part of the drift, ``-M^-1 C(q, qd) qd`` (with constraints the KKT solve
                         with ``f = -C qd`` and the bias ``Jcdot qd``), computed directly, not as ``drift - zvcf``:
                         ``zvcf + drift_velocity = drift`` up to rounding, because the KKT system is linear in
                         (f, bias).
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
    lam_scale            the size of the multipliers the summed terms could produce: ``(|Jcdot qd|_1 + ||Jc||
                         accel_scale) / w_kept``, ``w_kept`` the smallest kept eigenvalue of S (0 when none is kept).
    conditions (constrained) ``"constraint"`` = cond S (``max(w_max, floor) / w_min``, inf when ``w_min <= 0``),
                         ``"constraint_kept"`` the same over the kept eigenvalues (1 when none), and
                         ``"constraint_consistency"`` = ``max |U_0^T r| / max(|r|, 1e-6 L accel_scale)`` over the KKT
                         right-hand sides ``r = -Jcdot qd - Jc M^-1 f`` (``f = B u - h`` and ``-h``), U_0 S's
                         redundant eigen-directions (0 when none): non-zero means ``H_t`` is empty.
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
    zvcf: np.ndarray | Unsupported = UNSUPPORTED
    drift_velocity: np.ndarray | Unsupported = UNSUPPORTED
    constraint_value: np.ndarray | None = None
    constraint_jacobian: np.ndarray | None = None
    constraint_bias: np.ndarray | None = None
    constraint_velocity: np.ndarray | None = None
    constraint_force: np.ndarray | None = None
    constraint_force_drift: np.ndarray | None = None
    constraint_rank: int | None = None
    lam_scale: float = 0.0
    external_force: np.ndarray | None | Unsupported = None
    power_ext: float | None | Unsupported = None

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
                  "lam": (k,), "lam_drift": (k,),
                  "power_constr_per_coord": (n,), "constraint_value": (k,), "constraint_jacobian": (k, n),
                  "constraint_bias": (k,), "constraint_velocity": (k,), "constraint_force": (n,),
                  "constraint_force_drift": (n,), "zvcf": (n,), "drift_velocity": (n,), "external_force": (n,)}
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
        for name in ("joint_wrenches", "joint_wrenches_drift"):
            value = getattr(self, name)
            if not isinstance(value, Unsupported):
                arr = np.array(value, dtype=float)
                if arr.ndim != 2 or arr.shape[1] != 6:
                    raise ValueError(f"a formalism returned {name} of shape {arr.shape}, expected (bodies, 6)")
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
        for name in ("power_constr", "kinetic_energy", "power_ext"):
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
    def drift_parts(self) -> np.ndarray | Unsupported:
        """``zvcf + drift_velocity - drift``: zero up to rounding (the drift's parts add up, 4.5-4.6)."""
        if isinstance(self.zvcf, Unsupported) or isinstance(self.drift_velocity, Unsupported):
            return UNSUPPORTED
        return self.zvcf + self.drift_velocity - self.drift

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
    """A coordinate chart ``q = psi(p)`` of the configuration manifold (article 6.4.6, 9.1; docs/design.md, charts).

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
    unconstrained; minimum-norm over redundant directions, the rule of :data:`CONSTRAINT_RCOND`)."""

    drift: np.ndarray
    ctrl: np.ndarray
    total: np.ndarray
    lam: np.ndarray | None = None
    lam_drift: np.ndarray | None = None

    def __len__(self) -> int:
        return len(self.drift)


@dataclass(frozen=True)
class Linearization:
    """The first-order model of the state-space dynamics at a state and input (article 4.8, eq. 11):
    ``xdot ~ f(x_t, u_t) + A (x - x_t) + B (u - u_t)`` with ``x = (q, v)`` and ``f = (qdot, vdot)``.

    Convention on Lie groups (``cases.model``: spherical and free joints): a configuration near ``q`` is written
    ``q (+) dq`` (``cases.configuration.integrate``: ``q exp(dq)``, the perturbation on the right, in the joint's own
    tangent space, Pinocchio's), so ``x`` has ``2 nv`` coordinates ``(dq, v)``. Then

    * ``A = [[A_qq, I], [dvdot/dq, dvdot/dv]]`` (2nv x 2nv) and ``B = [[0], [dvdot/du]]`` (2nv x m);
    * ``A_qq`` (:func:`tangent_kinematics`) is 0 on revolute and prismatic joints and ``-ad_v`` on group joints
      (``d/dt dq = dv - ad_v dq`` for ``q(t) = q_t(t) exp(dq(t))``); ``dvdot/dq`` is the derivative along
      ``q (+) dq`` at ``dq = 0`` (Pinocchio's ``computeABADerivatives`` convention).

    With constraints, ``vdot`` is the KKT solution of eq. (12-13) (``M vdot + h = B u + Jc^T lam``, ``Jc vdot +
    Jcdot v = 0``) as a function of ``(q, v, u)`` wherever ``S = Jc M^-1 Jc^T`` is regular, also off the constraint
    manifold, and A and B are its derivatives (the KKT system differentiated). ``vdot`` is that solution at the state
    (the drift when ``u = 0``). Unpacks as ``A, B = linearize(...)``.
    """

    A: np.ndarray
    B: np.ndarray
    vdot: np.ndarray

    def __post_init__(self):
        A, B, vdot = (np.array(x, dtype=float) for x in (self.A, self.B, self.vdot))
        nv = vdot.shape[0] if vdot.ndim == 1 else -1
        if nv < 0 or A.shape != (2 * nv, 2 * nv) or B.ndim != 2 or B.shape[0] != 2 * nv:
            raise ValueError(f"a formalism returned a linearization of shapes A {A.shape}, B {B.shape}, vdot "
                             f"{vdot.shape}; expected (2nv, 2nv), (2nv, m), (nv,)")
        for name, arr in (("A", A), ("B", B), ("vdot", vdot)):
            arr.setflags(write=False)
            object.__setattr__(self, name, arr)

    def __iter__(self):
        return iter((self.A, self.B))

    @property
    def eigenvalues(self) -> np.ndarray:
        """The eigenvalues of A, sorted by real part then imaginary part."""
        w = np.linalg.eigvals(self.A)
        return w[np.lexsort((w.imag, w.real))]


def tangent_kinematics(model: Model, v) -> np.ndarray:
    """``A_qq`` of :class:`Linearization` (nv x nv): ``d/dt dq = dv + A_qq dq`` for ``q = q_t exp(dq)``. Zero on a
    revolute or prismatic joint; ``-[omega]x`` on a spherical joint (``v_i = omega``, body frame); ``-ad_V`` on a free
    joint with the body twist ``V = (nu, omega)`` (linear first): ``ad_V = [[ [omega]x, [nu]x ], [0, [omega]x]]``.
    It is the convention's definition (a group's kinematics, no dynamics), shared like the state validators."""
    v = np.asarray(v, dtype=float)
    out = np.zeros((model.nv, model.nv))

    def hat(w):
        return np.array([[0.0, -w[2], w[1]], [w[2], 0.0, -w[0]], [-w[1], w[0], 0.0]])
    for i, body in enumerate(model.bodies):
        j = model.v_index[i]
        if body.joint == "spherical":
            out[j:j + 3, j:j + 3] = -hat(v[j:j + 3])
        elif body.joint == "free":
            nu, omega = v[j:j + 3], v[j + 3:j + 6]
            out[j:j + 3, j:j + 3] = -hat(omega)
            out[j:j + 3, j + 3:j + 6] = -hat(nu)
            out[j + 3:j + 6, j + 3:j + 6] = -hat(omega)
    return out


def state_space(model: Model, v, dvdot_dq, dvdot_dv, dvdot_du, vdot) -> Linearization:
    """The :class:`Linearization` from a backend's derivatives of ``vdot`` (each nv x nv, nv x nv, nv x m) and
    ``vdot``: stacks the kinematic rows ``[tangent_kinematics(model, v), I]`` and ``[0]`` above them."""
    nv = model.nv
    A = np.block([[tangent_kinematics(model, v), np.eye(nv)], [np.asarray(dvdot_dq), np.asarray(dvdot_dv)]])
    B = np.vstack([np.zeros((nv, model.m)), np.asarray(dvdot_du).reshape(nv, model.m)])
    return Linearization(A=A, B=B, vdot=vdot)


def _numeric(label: str, value, kind: str) -> np.ndarray:
    """``value`` as a float array, or a :class:`StateError` saying that ``label`` is not a numeric ``kind``."""
    try:
        return np.array(value, dtype=float)
    except (TypeError, ValueError):
        raise StateError(f"{label} is not a numeric {kind}: {value!r}") from None


def check_batch(model: Model, Q, QD, U) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Return (Q, QD, U) as float arrays of shapes (N, nq), (N, nv), (N, m), or raise :class:`StateError` naming
    what does not fit (as :func:`check_state`)."""
    out = []
    for label, value, size in (("Q", Q, model.nq), ("QD", QD, model.nv), ("U", U, model.m)):
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
    _unit_quaternions(model, out[0], "Q")
    return out[0], out[1], out[2]


def split_batch_by_loop(split: Callable[[Model, np.ndarray, np.ndarray, np.ndarray], Split]):
    """A ``split_batch`` that calls ``split`` state by state: for a backend (a plugin) without its own."""
    def split_batch(model: Model, Q, QD, U) -> SplitBatch:
        Q, QD, U = check_batch(model, Q, QD, U)
        splits = [split(model, q, qd, u) for q, qd, u in zip(Q, QD, U)]

        def stack(name: str, width: int) -> np.ndarray:
            return np.array([getattr(s, name) for s in splits], dtype=float).reshape(len(Q), width)
        lam = (stack("lam", model.k), stack("lam_drift", model.k)) if model.k else (None, None)
        return SplitBatch(stack("drift", model.nv), stack("ctrl", model.nv), stack("total", model.nv), *lam)
    return split_batch


def with_block_form(split_many: Callable[[Model, np.ndarray, np.ndarray, np.ndarray], Sequence[Split]]):
    """Declare ``split_many(model, Q, QD, U)`` the block form of the decorated ``split``: the :class:`Split` of each of
    N states (rows of Q, QD, U) computed for the block at once, element ``i`` equal to ``split(model, Q[i], QD[i],
    U[i])`` bit for bit, every field and extra. The harness evaluates blocks of a model's states through it
    (:func:`block_form`). It is kept on the ``split`` function itself, so whatever wraps or replaces a backend's
    ``split`` (a plugin's check, a test's altered backend) has no block form and is evaluated state by state."""
    def declare(split):
        split.split_many = split_many
        return split
    return declare


def block_form(formalism: "Formalism") -> Callable[[Model, np.ndarray, np.ndarray, np.ndarray], Sequence[Split]] | None:
    """The block form of ``formalism.split`` (:func:`with_block_form`), None when it has none."""
    return getattr(formalism.split, "split_many", None)


@dataclass(frozen=True)
class Formalism:
    """A named formulation of rigid-body dynamics behind the shared ``split`` contract.

    ``split_chart(model, chart, p, pd, tau_p)``, when present, evaluates the same split directly in the chart
    ``q = psi(p)``: state ``(p, pd)``, the generalized force ``tau_p`` a covector in that chart, and the
    returned accelerations in that chart (``pdd``). None for a formalism that works only in the joint chart.
    ``split_batch(model, Q, QD, U)`` evaluates N states at once (:class:`SplitBatch`, rows equal to ``split``'s
    accelerations and multipliers); None for a backend without one (the harness then loops over ``split``:
    :func:`split_batch_by_loop`). ``split`` may carry a block form that returns whole splits (:func:`with_block_form`).
    ``evaluation()``, when present, says in a few words how the backend evaluates its expressions in this process,
    and why (``"compiled C (cc -O1)"``, ``"interpreted casadi SX (no C compiler found)"``); ``crosscheck formalisms``
    prints it. None for a backend with nothing to choose.
    ``preparation(model, chart)``, when present, estimates the CPU seconds of the one-off work before the first answer
    on ``model`` in ``chart`` (None: the joint chart), 0 when it is cached: a symbolic derivation, a compilation.
    ``prepare(model, chart, linearization)``, when present, does that work now and caches it on disk (with
    ``linearization``, what the backend's ``linearize`` needs too), so that another process can derive ahead of the
    one that evaluates (``crosscheck.engine.prepare``).
    ``linearize(model, q, v, u)`` returns the :class:`Linearization` (A, B of eq. 11) from the backend's own exact
    derivative of its own computation (no finite differences); ``linearize_chart(model, chart, p, pd, tau_p)`` the same
    in a chart's coordinates ``x = (p, pd)`` (A_qq = 0 there). None for a backend without them.
    """

    name: str
    summary: str
    split: Callable[[Model, np.ndarray, np.ndarray, np.ndarray], Split]
    split_chart: Callable[[Model, Chart, np.ndarray, np.ndarray, np.ndarray], Split] | None = None
    split_batch: Callable[[Model, np.ndarray, np.ndarray, np.ndarray], SplitBatch] | None = None
    evaluation: Callable[[], str] | None = None
    preparation: Callable[[Model, "Chart | None"], float] | None = None
    linearize: Callable[[Model, np.ndarray, np.ndarray, np.ndarray], Linearization] | None = None
    linearize_chart: Callable[[Model, Chart, np.ndarray, np.ndarray, np.ndarray], Linearization] | None = None
    prepare: Callable[[Model, "Chart | None", bool], None] | None = None


def _unit_quaternions(model: Model, q: np.ndarray, label: str) -> None:
    """A :class:`StateError` naming the first quaternion of ``q`` (a spherical or free joint's ``(x, y, z, w)``,
    ``cases.model``) whose norm is not 1 to ``UNIT_TOL``: a rotation is never built from a non-unit quaternion."""
    for i, block in quaternion_slices(model):
        start, quat = block.start, q[..., block]
        norm = np.sqrt(np.sum(quat * quat, axis=-1))
        bad = np.flatnonzero(~(np.abs(norm - 1.0) <= UNIT_TOL))
        if bad.size:
            where = f"{label}[{start}:{start + 4}]" if q.ndim == 1 else f"{label}[{bad[0]}, {start}:{start + 4}]"
            raise StateError(f"{where}, the quaternion (x, y, z, w) of body '{model.bodies[i].name}', has norm "
                             f"{float(np.ravel(norm)[bad[0]])!r}, not 1 (to {UNIT_TOL:g}): a rotation needs a unit "
                             "quaternion; divide it by its norm")


def check_state(model: Model, q, qd, u) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Return (q, qd, u) as float arrays (q of length ``nq``, qd of ``nv``, u of ``m``), or raise
    :class:`StateError` naming what does not fit (a length, a non-finite entry, a quaternion that is not unit)."""
    out = []
    for label, value, size in (("q", q, model.nq), ("qd", qd, model.nv), ("u", u, model.m)):
        arr = _numeric(label, value, "vector")
        if arr.ndim != 1:
            raise StateError(f"{label} must be a 1-D vector of length {size}, got an array of shape {arr.shape}")
        if arr.size != size:
            raise StateError(f"{label} has {arr.size} entries but model '{model.name}' needs {size}")
        if not np.all(np.isfinite(arr)):
            raise StateError(f"{label} has non-finite entries: {arr.tolist()}")
        out.append(arr)
    _unit_quaternions(model, out[0], "q")
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


def joint_vectors(model: Model, q, *rates) -> list[np.ndarray]:
    """``q`` (length ``nq``) and the ``rates`` (e.g. ``qd, qdd`` of an inverse-dynamics call, length ``nv``) as float
    vectors, or a :class:`StateError` naming the sizes."""
    out = [np.asarray(v, dtype=float).reshape(-1) for v in (q, *rates)]
    if out[0].size != model.nq or any(v.size != model.nv for v in out[1:]):
        raise StateError(f"model '{model.name}' needs {model.nq} coordinates and {model.nv} values per velocity-like "
                         f"vector; got sizes {[v.size for v in out]}")
    return out


__all__ = ["CONSTRAINT_RCOND", "DEGENERATE_ROW", "UNSUPPORTED", "Chart", "Formalism", "Linearization",
           "ModelNotSupported", "Split", "SplitBatch", "StateError", "Unsupported", "block_form", "chart_vectors",
           "check_batch", "check_state", "joint_vectors", "split_batch_by_loop", "state_space", "tangent_kinematics",
           "with_block_form", "cache_dir", "used_cache_file", "write_cache_file"]
