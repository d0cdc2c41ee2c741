"""Forward ZTCF trajectories (article 4.5, 4.6, 10.3).

A pointwise ZTCF sample (eq. 10) is the drift at one instant; a forward ZTCF trajectory integrates the drift (u = 0,
or a given input schedule ``u(t)``) from a state. Here every backend's dynamics is integrated through the SAME
integrators, and the results are compared with a 50-digit reference trajectory and with each other.

State ``x = (q, v)``, ``qdot = v``, ``vdot`` = the backend's acceleration (drift for u = 0, else total). The
integrators are written once, on a function ``vdot(q, v, t)``:

* :func:`rk4` classical fixed-step Runge–Kutta of order 4;
* :func:`gauss` the 2-stage Gauss–Legendre collocation (order 4, symplectic, A-stable); the stage equations are
  solved by fixed-point iteration, stopped when the update of the stage slopes times the step is at most
  :data:`GAUSS_TOL` times ``max(1, |x|)`` (at rounding), or when it stalls at rounding level; a step whose iteration
  does not converge within :data:`GAUSS_ITERATIONS` ends the run with a failure message (the iteration converges
  only for ``h L`` below about 1, L the Lipschitz constant of the field: the step-size limit of the stability map);
* :func:`adaptive` scipy's ``solve_ivp`` (DOP853) with ``rtol = atol =`` :data:`ADAPTIVE_TOL`, sampled by its dense
  output.

Joints. The built-in trajectories are restricted to vector joints (revolute, prismatic), where ``q (+) v`` is
``q + v`` and every method keeps its classical order; a model with spherical or free joints is refused with a
one-line error (:class:`TrajectoryError`), rather than integrated at an order not measured.

The reference (:func:`reference_trajectory`) integrates the exact acceleration at :data:`DIGITS` digits with
Gragg–Bulirsch–Stoer extrapolation: the modified midpoint rule with ``n = 2, 4, ..., 2K`` substeps per step,
extrapolated in ``h^2`` (order 2K, :data:`GBS_LEVELS` = K = 8), the step size controlled so that the last
extrapolation's correction stays below :data:`REFERENCE_TOL` ``max(1, |x|)`` (a step is rejected and retried smaller
otherwise; steps never cross an output time). The acceleration is ``crosscheck.references.precise``'s KKT solve in
mpmath, or, for the double pendulum, the article's eqs. (6)-(8) in mpmath (:class:`_PendulumField`, about 25 times
cheaper; checked against the generic split to 1e-44 in the tests). Its own error is estimated by a verification run with
the local tolerance :data:`VERIFY_TOL` = ``REFERENCE_TOL 2^-(2K+1)`` (what halving every step gives at order 2K): the
largest difference of the two runs over the horizon (:attr:`Reference.error_estimate`); the finer run is kept.

Lyapunov exponent and envelope (:func:`lyapunov`, :func:`envelope`). A third reference run starts
:data:`LYAPUNOV_EPS` away along a fixed (seeded) direction, in the tangent space of the constraints for both q and
v; ``G(t) = |delta x(t)|_inf / |delta x(0)|_inf`` is the measured growth and the finite-time Lyapunov exponent
(FTLE) is ``ln G(T) / T``. The perturbation aligns with the most unstable direction, so ``G(t) / G(s)`` is the growth
over the window ``[s, t]``; ``Ghat(tau) = max_s G(s + tau) / G(s)`` (at least 1, non-decreasing) is the worst growth
measured over any window of length tau, and ``lambda_env = max_{tau >= WINDOW} ln Ghat(tau) / tau`` summarizes it.

Two correct backends integrated with the same integrator and step differ by a perturbation injected at every step
and carried by the linearized flow: ``d' = A(t) d + r(t)``, ``|r| <= sigma``, so ``|d(t)| <= sigma integral_0^t
Ghat(t - s) ds`` (``<= sigma (exp(lambda_env t) - 1) / lambda_env`` when the growth is exponential: the form
``c eps exp(lambda t)``, ``c = sigma / (eps lambda)``). ``sigma`` is derived, not fitted: each backend's
acceleration is within ``eps * acceleration_bound`` of the exact one (the gate's tolerance claim,
``crosscheck.core.tolerance.acceleration_bound``, evaluated on the reference trajectory; maximum over time), and each
step's update of x rounds at ``eps |x|`` per step, i.e. ``eps |x| / dt`` per unit time; a pair doubles both:
``sigma = 2 eps (max_t |bound(t)|_inf + max_t |x(t)|_inf / dt)``. The envelope adds the rounding of the states
themselves: ``E(t) = sigma integral_0^t Ghat(t - s) ds + 2 eps |x(t)|`` (:func:`envelope`; the integral by the
right-endpoint sum on the output grid, which overestimates a non-decreasing Ghat). The judgment (:func:`judge`)
holds each pair of backends to it while all of them are still near the reference (error below
:data:`JUDGED_UNTIL` times the state's size: beyond that the linearization about the reference flow, hence Ghat, no
longer describes their difference); a backend outside the envelope against more than half of the others is named;
with two backends a pair outside it names both. For the adaptive integrator the step sequences of two backends can
differ (an accepted or rejected step decided differently), which injects a difference of the local error's size:
its sigma adds ``2 ADAPTIVE_TOL max(1, |x|) / dt``, dt the output interval.

Constrained models: ``project='none'`` integrates the KKT drift as it is (phi drifts by the truncation error);
``'project'`` moves q back onto ``phi = 0`` and v onto ``Jc v = 0`` after every step (``crosscheck.core.sampling``'s
Gauss–Newton and tangent projections; not with the adaptive integrator, whose steps are internal);
``'baumgarte'`` adds ``-M^-1 Jc^T S^+ (2 alpha Jc v + alpha^2 phi)`` (``S = Jc M^-1 Jc^T``, M and the constraint
kinematics from Pinocchio, the harness's view) so that the constraint error obeys ``phi'' + 2 alpha phi' +
alpha^2 phi = 0``.
"""

from __future__ import annotations

import math
import time
from dataclasses import dataclass, field
from typing import Callable, Sequence

import mpmath
import numpy as np
from mpmath import mpf

import formalisms
from cases import configuration
from cases.model import GROUP_JOINTS, Model
from crosscheck.core.sampling import project_configuration, project_velocity
from crosscheck.core.tolerance import acceleration_bound
from crosscheck.references import precise
from crosscheck.references.pinocchio import reference
from crosscheck.references.pinocchio.kinematics import constraint_kinematics, mass_matrix
from crosscheck.references.precise import (algebra as precise_algebra, dynamics as precise_dynamics,
                                           kinematics as precise_kinematics)
from formalisms.interface import SplitBatch

EPS = float(np.finfo(float).eps)
INTEGRATORS = ("rk4", "gauss", "adaptive")
PROJECTIONS = ("none", "project", "baumgarte")
GAUSS_TOL = 4 * EPS
GAUSS_ITERATIONS = 60
ADAPTIVE_TOL = 1e-12
DIGITS = 50
GBS_LEVELS = 8
REFERENCE_TOL = 1e-26
#: The verification run's (and the Lyapunov run's) local tolerance: what halving every step gives at order 2K.
VERIFY_TOL = REFERENCE_TOL * 2.0 ** -(2 * GBS_LEVELS + 1)
LYAPUNOV_EPS = 1e-20
WINDOW = 1.0
JUDGED_UNTIL = 1e-3
BAUMGARTE_ALPHA = 10.0
PINOCCHIO = "pinocchio"


class TrajectoryError(ValueError):
    """Bad input for a trajectory (one line, specific)."""


# ----------------------------------------------------------------------------------------------- dynamics


def check_model(model: Model) -> None:
    group = [b.name for b in model.bodies if b.joint in GROUP_JOINTS]
    if group:
        raise TrajectoryError(f"model '{model.name}': trajectories support revolute and prismatic joints only; "
                              f"joints on a group: {', '.join(group)}")


def _split_functions(backend):
    """(split, split_batch or None) of a backend name, or of an object with ``split`` (a wrapped backend)."""
    if isinstance(backend, str):
        mod = reference if backend == PINOCCHIO else formalisms.get(backend)
        return mod.split, getattr(mod, "split_batch", None)
    return backend.split, getattr(backend, "split_batch", None)


class Dynamics:
    """``vdot(q, v, t)`` of one backend: its drift with ``u = 0`` or its total with ``u = schedule(t)``, plus the
    Baumgarte term when asked; counts its evaluations."""

    def __init__(self, model: Model, backend, schedule: Callable[[float], np.ndarray] | None = None,
                 baumgarte: float | None = None):
        self.model, self.schedule, self.alpha = model, schedule, baumgarte
        self.split, self.split_batch = _split_functions(backend)
        self.evals = 0

    def _u(self, t: float) -> np.ndarray:
        return np.zeros(self.model.m) if self.schedule is None else np.asarray(self.schedule(t), dtype=float)

    def batch(self, Q: np.ndarray, V: np.ndarray, ts: Sequence[float]) -> np.ndarray:
        U = np.array([self._u(t) for t in ts]).reshape(len(ts), self.model.m)
        self.evals += len(Q)
        if self.split_batch is not None:
            out = self.split_batch(self.model, Q, V, U)
            A = np.array(out.drift if self.schedule is None else out.total, dtype=float)
        else:
            A = np.array([getattr(self.split(self.model, q, v, u), "drift" if self.schedule is None else "total")
                          for q, v, u in zip(Q, V, U)], dtype=float)
        if self.alpha:
            A = A + np.array([baumgarte_term(self.model, q, v, self.alpha) for q, v in zip(Q, V)])
        return A

    def __call__(self, q, v, t: float) -> np.ndarray:
        return self.batch(np.asarray(q, dtype=float)[None], np.asarray(v, dtype=float)[None], [t])[0]


def baumgarte_term(model: Model, q, v, alpha: float) -> np.ndarray:
    phi, Jc, _ = constraint_kinematics(model, q, v)
    Minv = np.linalg.inv(mass_matrix(model, q))
    X = Minv @ Jc.T
    S = Jc @ X
    return -X @ (np.linalg.pinv(S, rcond=1e-12) @ (2 * alpha * (Jc @ v) + alpha ** 2 * phi))


# ----------------------------------------------------------------------------------------------- integrators


@dataclass
class Run:
    """A float trajectory: times t (N,), q (N, n), v (N, nv) at the output grid; ``failure`` says why it ended early
    (then t ends there)."""

    backend: str
    integrator: str
    dt: float
    project: str
    t: np.ndarray
    q: np.ndarray
    v: np.ndarray
    evals: int = 0
    seconds: float = 0.0
    failure: str | None = None
    iterations: float = 0.0     # gauss: mean fixed-point iterations per step

    @property
    def x(self) -> np.ndarray:
        return np.hstack([self.q, self.v])


def _post(model: Model, project: str):
    if project != "project" or not model.constraints:
        return None

    def post(q, v):
        q = project_configuration(model, q)
        return q, project_velocity(model, q, v)
    return post


def _finite(q, v) -> bool:
    return bool(np.all(np.isfinite(q)) and np.all(np.isfinite(v)) and np.abs(q).max(initial=0) < 1e12
                and np.abs(v).max(initial=0) < 1e12)


def rk4_step(f, q, v, t, h):
    a1 = f(q, v, t)
    q2, v2 = q + h / 2 * v, v + h / 2 * a1
    a2 = f(q2, v2, t + h / 2)
    q3, v3 = q + h / 2 * v2, v + h / 2 * a2
    a3 = f(q3, v3, t + h / 2)
    q4, v4 = q + h * v3, v + h * a3
    a4 = f(q4, v4, t + h)
    return q + h / 6 * (v + 2 * v2 + 2 * v3 + v4), v + h / 6 * (a1 + 2 * a2 + 2 * a3 + a4)


_S3 = math.sqrt(3.0)
GAUSS_C = (0.5 - _S3 / 6, 0.5 + _S3 / 6)
GAUSS_A = ((0.25, 0.25 - _S3 / 6), (0.25 + _S3 / 6, 0.25))


def gauss_step(fb, q, v, t, h):
    """One 2-stage Gauss–Legendre step; returns (q, v, iterations) or raises ArithmeticError when the fixed-point
    iteration does not converge. ``fb(Q, V, ts)`` evaluates both stages at once."""
    a0 = fb(q[None], v[None], [t])[0]
    KV = np.array([v, v])            # stage slopes of q (velocities) and of v (accelerations)
    KA = np.array([a0, a0])
    scale = max(1.0, float(np.abs(np.concatenate([q, v])).max()))
    last = np.inf
    A = np.array(GAUSS_A)
    for it in range(1, GAUSS_ITERATIONS + 1):
        Q = q + h * (A @ KV)
        V = v + h * (A @ KA)
        new_KA = fb(Q, V, [t + c * h for c in GAUSS_C])
        new_KV = V
        change = h * max(float(np.abs(new_KA - KA).max()), float(np.abs(new_KV - KV).max()))
        KV, KA = new_KV, new_KA
        if not np.isfinite(change):
            break
        if change <= GAUSS_TOL * scale or (it > 3 and change >= 0.5 * last and change <= 1e3 * GAUSS_TOL * scale):
            return q + h * 0.5 * (KV[0] + KV[1]), v + h * 0.5 * (KA[0] + KA[1]), it
        last = change
    raise ArithmeticError(f"Gauss–Legendre fixed-point iteration did not converge at t = {t:.6g} (h = {h:g})")


def _fixed(step_name: str, model: Model, dyn: Dynamics, q0, v0, dt: float, steps: int, every: int, project: str,
           backend: str) -> Run:
    post = _post(model, project)
    q, v = np.array(q0, dtype=float), np.array(v0, dtype=float)
    ts, Qs, Vs, iters = [0.0], [q.copy()], [v.copy()], []
    start, failure = time.perf_counter(), None
    for k in range(1, steps + 1):
        t = (k - 1) * dt
        try:
            if step_name == "rk4":
                q, v = rk4_step(dyn, q, v, t, dt)
            else:
                q, v, it = gauss_step(dyn.batch, q, v, t, dt)
                iters.append(it)
        except ArithmeticError as exc:
            failure = str(exc)
            break
        except Exception as exc:          # a backend that raises (a singular matrix on a blown-up state)
            failure = f"{type(exc).__name__} at t = {t:.6g}: {exc}"
            break
        if not _finite(q, v):
            failure = f"state left the finite range at t = {k * dt:.6g}"
            break
        if post is not None:
            q, v = post(q, v)
        if k % every == 0:
            ts.append(k * dt)
            Qs.append(q.copy())
            Vs.append(v.copy())
    return Run(backend, step_name, dt, project, np.array(ts), np.array(Qs), np.array(Vs), dyn.evals,
               time.perf_counter() - start, failure, float(np.mean(iters)) if iters else 0.0)


def adaptive_run(model: Model, dyn: Dynamics, q0, v0, t_out: np.ndarray, project: str, backend: str,
                 tol: float = ADAPTIVE_TOL) -> Run:
    from scipy.integrate import solve_ivp

    n = model.n
    start = time.perf_counter()

    def rhs(t, x):
        return np.concatenate([x[n:], dyn(x[:n], x[n:], t)])
    try:
        sol = solve_ivp(rhs, (0.0, float(t_out[-1])), np.concatenate([q0, v0]), method="DOP853", rtol=tol, atol=tol,
                        t_eval=t_out)
        failure = None if sol.status == 0 else sol.message
        X = sol.y.T
        t = sol.t
    except Exception as exc:
        failure, X, t = f"{type(exc).__name__}: {exc}", np.concatenate([q0, v0])[None], t_out[:1]
    return Run(backend, "adaptive", float("nan"), project, np.asarray(t), X[:, :n], X[:, n:], dyn.evals,
               time.perf_counter() - start, failure)


def simulate(model: Model, backend, q0, v0, horizon: float, dt: float, integrator: str = "rk4",
             project: str = "none", every: int = 1, schedule=None, name: str | None = None) -> Run:
    """Integrate one backend's dynamics from ``(q0, v0)`` for ``horizon`` seconds; output every ``every`` steps
    (the adaptive integrator: at the same times ``k every dt``)."""
    check_model(model)
    if integrator not in INTEGRATORS:
        raise TrajectoryError(f"unknown integrator '{integrator}'; valid: {', '.join(INTEGRATORS)}")
    if project not in PROJECTIONS:
        raise TrajectoryError(f"unknown projection '{project}'; valid: {', '.join(PROJECTIONS)}")
    if integrator == "adaptive" and project == "project":
        raise TrajectoryError("projection after each step needs a fixed-step integrator (rk4, gauss); "
                              "use --project baumgarte or none with adaptive")
    dyn = Dynamics(model, backend, schedule, BAUMGARTE_ALPHA if (project == "baumgarte" and model.constraints)
                   else None)
    label = name or (backend if isinstance(backend, str) else getattr(backend, "name", "custom"))
    steps = int(round(horizon / dt))
    if integrator == "adaptive":
        t_out = np.arange(0, steps // every + 1) * (every * dt)
        return adaptive_run(model, dyn, np.asarray(q0, float), np.asarray(v0, float), t_out, project, label)
    return _fixed(integrator, model, dyn, q0, v0, dt, steps, every, project, label)


# ----------------------------------------------------------------------------------------------- 50-digit reference


def _mp_acceleration(model: Model, q, v, tau):
    """The exact acceleration (eq. 12-13 with u; the drift for tau = 0) at mpf q, v inside ``workdps``."""
    data, kin, M, h = precise._terms(model, q, v)
    L = precise_algebra.cholesky(model, M, q)
    force = [t - x for t, x in zip(tau, h)]
    if not data.rows:
        return precise_algebra.cho_solve(L, force)
    _, Jc, bias = precise_dynamics.constraint_terms(data, kin, q)
    return precise_algebra.RangeSpace(model, L, Jc, bias).solve(force)[0]


def mp_energy(model: Model, q, v):
    """Total energy ``1/2 v^T M v - sum m_i gravity . p_com_i`` at mpf q, v inside ``workdps``."""
    data, kin, M, _ = precise._terms(model, q, v)
    T = sum(v[i] * mpmath.fdot(M[i], v) for i in range(len(v))) / 2
    V = mpf(0)
    for i, b in enumerate(data.bodies):
        com = precise_algebra.add3(kin.p[i], precise_algebra.matvec3(kin.R[i], b.com))
        V -= b.mass * precise_algebra.dot3(data.gravity, com)
    return T + V


def energy(model: Model, q, v) -> float:
    """Total energy in float (harness: Pinocchio's M, the model's poses)."""
    q, v = np.asarray(q, float), np.asarray(v, float)
    T = 0.5 * v @ mass_matrix(model, q) @ v
    V = 0.0
    for (R, p), b in zip(configuration.poses(model, q), model.bodies):
        V -= b.mass * float(np.asarray(model.gravity) @ (p + R @ np.asarray(b.com)))
    return float(T + V)


def _mp_input(schedule, t) -> list:
    """``u(t)`` for the reference: the schedule is called with the mpf time and its values taken at the working
    precision. A schedule written with mpmath functions (or piecewise constant) keeps the reference exact; one that
    rounds to float (numpy) makes the field non-smooth at 1e-16 and the step-size control gives up
    (:class:`TrajectoryError`)."""
    return [a if isinstance(a, mpf) else mpf(float(a)) for a in schedule(t)]


class _PendulumField:
    """The double pendulum's exact acceleration from the article's eqs. (6)-(8) (as
    ``crosscheck.references.closed_forms`` types them), in scalar mpmath arithmetic with the case's parameters ``m1, m2,
    l1, l2, g`` (point masses; the case's input map is the identity, so ``tau = u``), solved by hand (2 x 2): about 25
    times cheaper than the generic multiprecision split, which it is checked against (tests)."""

    def __init__(self, params: dict, schedule=None):
        self.p = {k: mpf(float(params.get(k, d))) for k, d in (("m1", 1.0), ("m2", 1.0), ("l1", 1.0), ("l2", 1.0),
                                                            ("g", 9.81))}
        self.schedule, self.evals = schedule, 0

    def __call__(self, t, x):
        # eq. (6): M; eq. (7): C qd with c = m2 l1 l2 sin t2; eq. (8): g. Scalar mpf arithmetic (no matrices).
        p = self.p
        m1, m2, l1, l2, g = p["m1"], p["m2"], p["l1"], p["l2"], p["g"]
        t1, t2, w1, w2 = x
        c2, s2 = mpmath.cos(t2), mpmath.sin(t2)
        s1, s12 = mpmath.sin(t1), mpmath.sin(t1 + t2)
        M12 = m2 * l2 * l2 + m2 * l1 * l2 * c2
        M11 = (m1 + m2) * l1 * l1 + m2 * l2 * l2 + 2 * m2 * l1 * l2 * c2
        M22 = m2 * l2 * l2
        c = m2 * l1 * l2 * s2
        f0 = 2 * c * w1 * w2 + c * w2 * w2 - ((m1 + m2) * g * l1 * s1 + m2 * g * l2 * s12)
        f1 = -c * w1 * w1 - m2 * g * l2 * s12
        if self.schedule is not None:
            u = _mp_input(self.schedule, t)
            f0, f1 = f0 + u[0], f1 + u[1]
        det = M11 * M22 - M12 * M12
        self.evals += 1
        return [w1, w2, (M22 * f0 - M12 * f1) / det, (M11 * f1 - M12 * f0) / det]


class _MpField:
    def __init__(self, model: Model, schedule):
        self.model, self.schedule, self.n = model, schedule, model.n
        self.B = precise_kinematics.prepare(model, mpmath.mp.prec).B
        self.evals = 0

    def __call__(self, t, x):
        n = self.n
        q, v = x[:n], x[n:]
        if self.schedule is None:
            tau = [mpf(0)] * n
        else:
            tau = [mpmath.fdot(row, _mp_input(self.schedule, t)) for row in self.B]
        self.evals += 1
        return list(v) + list(_mp_acceleration(self.model, q, v, tau))


def gbs_step(f, t, x, H, levels: int = GBS_LEVELS):
    """One Gragg–Bulirsch–Stoer step (modified midpoint with n = 2, 4, ..., 2 levels substeps, Aitken–Neville
    extrapolation in h^2) at the current mpmath precision; returns (x_new, the last correction's size)."""
    f0 = f(t, x)
    table: list[list] = []
    ns = [2 * (j + 1) for j in range(levels)]
    for j, n in enumerate(ns):
        h = H / n
        z0 = list(x)
        z1 = [a + h * b for a, b in zip(x, f0)]
        for m in range(1, n):
            fm = f(t + m * h, z1)
            z0, z1 = z1, [a + 2 * h * b for a, b in zip(z0, fm)]
        row = [z1]
        for k in range(1, j + 1):
            ratio = (mpf(ns[j]) / ns[j - k]) ** 2 - 1
            prev, lower = row[k - 1], table[j - 1][k - 1]
            row.append([a + (a - b) / ratio for a, b in zip(prev, lower)])
        table.append(row)
    best = table[-1][-1]
    corr = max(abs(a - b) for a, b in zip(best, table[-1][-2]))
    return best, corr


@dataclass
class Reference:
    """The 50-digit reference trajectory on the output grid: t (N,), x as float (N, 2n) and as mpf lists, energy
    (mpf), the step-halving error estimate per time (float), its step H and cost."""

    t: np.ndarray
    x: np.ndarray
    x_mp: list
    energy: list
    error: np.ndarray
    H: float
    evals: int
    seconds: float
    digits: int = DIGITS
    closed_form: dict | None = None

    @property
    def error_estimate(self) -> float:
        return float(np.max(self.error))


def _field(model: Model, schedule, closed_form: dict | None):
    return _MpField(model, schedule) if closed_form is None else _PendulumField(closed_form, schedule)


def _mp_run(model: Model, x0_mp: list, interval: float, intervals: int, tol, schedule, digits: int,
            closed_form: dict | None = None):
    """Outputs at ``k interval``; inside each interval GBS steps whose size is controlled so that the last
    extrapolation's correction is at most ``tol max(1, |x|)`` (rejected and retried smaller otherwise)."""
    f = _field(model, schedule, closed_form)
    out = [list(x0_mp)]
    x = list(x0_mp)
    tol = mpf(tol)
    h = mpf(interval)
    order = 2 * GBS_LEVELS - 1
    for k in range(intervals):
        t, end = k * mpf(interval), (k + 1) * mpf(interval)
        while end - t > mpf(interval) * mpf(2) ** -40:
            step = min(h, end - t)
            new, corr = gbs_step(f, t, x, step)
            size = max(1, max(abs(a) for a in x))
            ratio = corr / (tol * size)
            if ratio <= 1:
                x, t = new, t + step
                h = step * min(mpf(2), mpf("0.9") * (1 / max(ratio, mpf(10) ** -30)) ** (mpf(1) / order))
            else:
                h = step * max(mpf("0.2"), mpf("0.9") * (1 / ratio) ** (mpf(1) / order))
                if h < mpf(interval) * mpf(2) ** -30:
                    raise TrajectoryError(f"reference: the step size control failed at t = {float(t):.6g} (local "
                                          f"error {float(corr):.1e} > {float(tol):.0e}); is the field smooth at "
                                          "the working precision (an input schedule rounded to float is not)?")
        out.append(list(x))
    return out, f.evals


def reference_run(model: Model, x0: Sequence[float], interval: float, intervals: int, tol: float, schedule=None,
                  digits: int = DIGITS, closed_form: dict | None = None, perturb: Sequence[float] | None = None):
    """One multiprecision run from the float state ``x0`` (plus ``LYAPUNOV_EPS * perturb``, exactly, in mpmath):
    the states at ``k interval`` as mpf lists and the number of evaluations (a unit of work for a process pool)."""
    check_model(model)
    with mpmath.workdps(digits):
        x0_mp = [mpf(float(a)) for a in x0]
        if perturb is not None:
            x0_mp = [a + mpf(LYAPUNOV_EPS) * mpf(float(b)) for a, b in zip(x0_mp, perturb)]
        return _mp_run(model, x0_mp, interval, intervals, tol, schedule, digits, closed_form)


def assemble_reference(model: Model, main: list, fine: list | None, interval: float, evals: int, seconds: float,
                       digits: int = DIGITS, closed_form: dict | None = None) -> Reference:
    """The :class:`Reference` from a run and its verification run (the finer one is kept; the difference of the two
    per output time is the error estimate)."""
    with mpmath.workdps(digits):
        if fine is not None:
            err = np.array([float(max(abs(a - b) for a, b in zip(x, y))) for x, y in zip(main, fine)])
            xs = fine
        else:
            err, xs = np.full(len(main), np.nan), main
        n = model.n
        E = [mp_energy(model, x[:n], x[n:]) for x in xs]
    X = np.array([[float(a) for a in x] for x in xs])
    return Reference(np.arange(len(xs)) * interval, X, xs, E, err, interval, evals, seconds, digits, closed_form)


def reference_trajectory(model: Model, q0, v0, horizon: float, H: float, schedule=None, digits: int = DIGITS,
                         halving: bool = True, closed_form: dict | None = None) -> Reference:
    """The reference on the output grid ``k H``, k = 0..round(horizon / H) (GBS steps inside each interval, their
    size controlled to :data:`REFERENCE_TOL`); with ``halving`` a verification run at :data:`VERIFY_TOL` (what halving
    every step gives at order 2K) provides the error estimate. ``closed_form``: the double pendulum's parameters, to
    use the article's equations (:class:`_PendulumField`) instead of the generic multiprecision split."""
    if closed_form is not None and (model.name != "double_pendulum" or model.n != 2):
        raise TrajectoryError(f"the closed-form reference is the double pendulum's, not model '{model.name}'")
    if closed_form is not None and model.has_armature:
        raise TrajectoryError(f"the closed-form reference (eqs. 6-8, point masses) has no armature; model "
                              f"'{model.name}' has {model.armature_vector.tolist()}: use the generic reference")
    start = time.perf_counter()
    steps = int(round(horizon / H))
    x0 = np.concatenate([np.asarray(q0, float), np.asarray(v0, float)])
    main, evals = reference_run(model, x0, H, steps, REFERENCE_TOL, schedule, digits, closed_form)
    fine = None
    if halving:
        fine, e2 = reference_run(model, x0, H, steps, VERIFY_TOL, schedule, digits, closed_form)
        evals += e2
    return assemble_reference(model, main, fine, H, evals, time.perf_counter() - start, digits, closed_form)


# ----------------------------------------------------------------------------------------------- Lyapunov


@dataclass
class Lyapunov:
    t: np.ndarray
    growth: np.ndarray     # G(t) = |delta x(t)| / |delta x(0)|
    worst: np.ndarray      # Ghat(tau) = max_s G(s + tau) / G(s) on the grid's lags (module doc)
    ftle: float            # ln G(T) / T
    exponent: float        # lambda_env = max over lags tau >= WINDOW of ln Ghat(tau) / tau


def perturbation_direction(model: Model, q0, seed: int = 0) -> np.ndarray:
    """A unit direction in x = (q, v), in the tangent space of the constraints at q0 for both parts."""
    rng = np.random.default_rng(seed)
    d = rng.standard_normal(2 * model.n)
    if model.constraints:
        _, Jc, _ = constraint_kinematics(model, q0, np.zeros(model.n))
        _, s, Vt = np.linalg.svd(Jc)
        N = Vt[int(np.sum(s > 1e-10 * s.max())):].T
        d = np.concatenate([N @ (N.T @ d[:model.n]), N @ (N.T @ d[model.n:])])
    return d / np.abs(d).max()


def lyapunov(model: Model, ref: Reference, schedule=None, seed: int = 0, perturbed: list | None = None) -> Lyapunov:
    """The growth of a :data:`LYAPUNOV_EPS` perturbation along the reference (module doc), integrated like the
    reference's verification run (``perturbed``: that run, when a pool already made it)."""
    if perturbed is None:
        d = perturbation_direction(model, ref.x[0, :model.n], seed)
        perturbed, _ = reference_run(model, ref.x[0], ref.H, len(ref.t) - 1, VERIFY_TOL, schedule, ref.digits,
                                     ref.closed_form, d)
    with mpmath.workdps(ref.digits):
        G = np.array([float(max(abs(a - b) for a, b in zip(x, y)) / mpf(LYAPUNOV_EPS))
                      for x, y in zip(perturbed, ref.x_mp)])
    return growth_summary(ref.t, G)


def growth_summary(t: np.ndarray, G: np.ndarray, window: float = WINDOW) -> Lyapunov:
    """FTLE, the worst growth per lag ``Ghat`` and ``lambda_env`` from a measured growth G on a uniform grid."""
    G = np.maximum(np.asarray(G, float), 1e-300)
    N = len(G)
    worst = np.array([1.0] + [float(np.max(G[k:] / G[:N - k])) for k in range(1, N)])
    worst = np.maximum.accumulate(np.maximum(worst, 1.0))      # a perturbation may also sit still: Ghat >= 1, monotone
    T = float(t[-1])
    lags = t - t[0]
    long = lags >= min(window, T / 2)
    exponent = float(np.max(np.log(worst[long]) / lags[long])) if long.any() else 0.0
    return Lyapunov(np.asarray(t), G, worst, float(np.log(G[-1]) / T), exponent)


# ----------------------------------------------------------------------------------------------- envelope, judgment


def rounding_rate(model: Model, ref: Reference, dt: float, integrator: str, samples: int = 25) -> float:
    """``sigma`` of the module doc: a pair's perturbation injected per unit time."""
    n = model.n
    idx = np.unique(np.linspace(0, len(ref.t) - 1, min(samples, len(ref.t))).astype(int))
    bound = 0.0
    for i in idx:
        q, v = ref.x[i, :n], ref.x[i, n:]
        with mpmath.workdps(ref.digits):
            a = np.array([float(c) for c in _mp_acceleration(model, ref.x_mp[i][:n], ref.x_mp[i][n:], [mpf(0)] * n)])
        bound = max(bound, float(np.abs(acceleration_bound(model, q, v, a)).max()))
    size = float(np.abs(ref.x).max())
    sigma = 2 * EPS * (bound + size / dt)
    if integrator == "adaptive":
        sigma += 2 * ADAPTIVE_TOL * max(1.0, size) / dt
    return sigma


def envelope(t: np.ndarray, size: np.ndarray, sigma: float, lyap: Lyapunov) -> np.ndarray:
    """``E(t_j) = sigma sum_{i<j} Ghat(t_j - t_i) dt + 2 eps |x(t_j)|`` (module doc): each interval's injected
    perturbation carried by the worst growth measured over that lag."""
    t = np.asarray(t, float)
    N = len(t)
    dt = t[1] - t[0] if N > 1 else 0.0
    cum = np.concatenate([[0.0], np.cumsum(lyap.worst[1:N])])     # cum[j] = sum_{k=1}^{j} Ghat(k dt)
    return sigma * dt * cum + 2 * EPS * np.asarray(size, float)


@dataclass
class Judgment:
    ratio: dict            # (a, b) -> max over the judged window of |x_a - x_b| / E
    outside: list          # backends named
    judged_until: float    # end of the judged window (s)
    envelope: np.ndarray
    sigma: float
    exponent: float


def errors(run: Run, ref: Reference) -> np.ndarray:
    """|x_run(t) - x_ref(t)|_inf on the run's output times (the reference's grid)."""
    k = len(run.t)
    return np.abs(run.x - ref.x[:k]).max(axis=1)


def digits_gone(run: Run, ref: Reference) -> float:
    """First time where the error against the reference reaches the size of the state (|x_ref(t)|_inf); inf when it
    never does within the run, the run's end when it failed."""
    e = errors(run, ref)
    size = np.abs(ref.x[:len(run.t)]).max(axis=1)
    hit = np.nonzero(e >= size)[0]
    if hit.size:
        return float(run.t[hit[0]])
    return float(run.t[-1]) if run.failure else float("inf")


def judge(runs: Sequence[Run], ref: Reference, lyap: Lyapunov, sigma: float) -> Judgment:
    """Hold each pair of runs (same integrator and step) to the envelope (module doc)."""
    k = min(len(r.t) for r in runs)
    t = ref.t[:k]
    size = np.abs(ref.x[:k]).max(axis=1)
    near = np.ones(k, bool)
    for r in runs:
        near &= errors(r, ref)[:k] <= JUDGED_UNTIL * size
    stop = int(np.argmin(near)) if not near.all() else k
    E = envelope(t, size, sigma, lyap)
    ratio = {}
    for i, a in enumerate(runs):
        for b in runs[i + 1:]:
            d = np.abs(a.x[:stop] - b.x[:stop]).max(axis=1) if stop else np.zeros(0)
            ratio[(a.backend, b.backend)] = float(np.max(d / E[:stop])) if stop else 0.0
    names = [r.backend for r in runs]
    outside = []
    for name in names:
        bad = sum(1 for (a, b), r in ratio.items() if name in (a, b) and r > 1.0)
        if len(names) == 2 and bad:
            outside.append(name)
        elif len(names) > 2 and bad > (len(names) - 1) / 2:
            outside.append(name)
    return Judgment(ratio, outside, float(t[stop - 1]) if stop else 0.0, E, sigma, lyap.exponent)


def constraint_drift(model: Model, run: Run) -> np.ndarray:
    """max(|phi|_inf, |Jc v|_inf) along the run (0 for an unconstrained model)."""
    if not model.constraints:
        return np.zeros(len(run.t))

    out = []
    for q, v in zip(run.q, run.v):
        phi, Jc, _ = constraint_kinematics(model, q, v)
        out.append(max(float(np.abs(phi).max()), float(np.abs(Jc @ v).max())))
    return np.array(out)


def energy_error(model: Model, run: Run, ref: Reference) -> np.ndarray:
    """|E(t) - E_ref(0)| along the run (J), E from :func:`energy` (drift only: u = 0 conserves energy)."""
    E0 = float(ref.energy[0])
    return np.array([abs(energy(model, q, v) - E0) for q, v in zip(run.q, run.v)])


# ----------------------------------------------------------------------------------------------- faults for the tests


@dataclass
class FaultyBackend:
    """A backend whose drift (and total) carries a relative error ``rel`` (every component scaled by 1 + rel)."""

    backend: str
    rel: float = 1e-10
    name: str = field(default="")

    def __post_init__(self):
        self.name = self.name or f"{self.backend}+{self.rel:g}"
        self._split, self._batch = _split_functions(self.backend)

    def split_batch(self, model, Q, QD, U):
        out = self._batch(model, Q, QD, U) if self._batch else None
        if out is None:
            ss = [self._split(model, q, v, u) for q, v, u in zip(Q, QD, U)]
            return SplitBatch(np.array([s.drift for s in ss]) * (1 + self.rel),
                              np.array([s.ctrl for s in ss]), np.array([s.total for s in ss]) * (1 + self.rel))
        from dataclasses import replace
        return replace(out, drift=np.asarray(out.drift) * (1 + self.rel), total=np.asarray(out.total) * (1 + self.rel))

    def split(self, model, q, qd, u):
        from dataclasses import replace
        s = self._split(model, q, qd, u)
        return replace(s, drift=np.asarray(s.drift) * (1 + self.rel), total=np.asarray(s.total) * (1 + self.rel))
