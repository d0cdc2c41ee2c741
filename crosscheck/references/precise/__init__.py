"""A high-precision reference: the exact split of a model's float data, in mpmath.

:func:`split` computes drift, ctrl, total (eq. 9, 10; eq. 12-17 with constraints) and the multipliers lam,
lam_drift with mpmath at ``digits`` significant digits (default :data:`DIGITS` = 50), so that every backend's true
error at a state can be measured against it. It is part of the harness, not a formalism: it never calls a backend or
Pinocchio, and is written from the model's definition (``cases.model``) in a classical, compact form (the model data
and kinematics in ``kinematics``, M, h and the constraint rows in ``dynamics``, the solves in ``algebra``; the
public API, the charts and the linearization here):

* kinematics in the world frame per body, parents first: rotation R, origin p, joint axis a and origin o, angular
  velocity w, origin velocity v, and at ``qdd = 0`` the angular acceleration and the origin's classical acceleration;
  each velocity column's unit twist at the world origin (angular part, velocity of the point at the world origin),
  ``S = (a, o x a)`` (revolute) or ``(0, a)`` (prismatic); spherical and free joints below;
* ``M`` from composite bodies (CRBA): the momentum ``(L, P)`` of body i's subtree moving with ``S_c`` (c a column of
  body i) paired with ``S_d`` for each column d of i and of its ancestors, ``M_cd = a_d . L + v_d . P``;
* each joint's armature (``Body.armature``) added exactly to its velocities' diagonal entries of ``M`` (the rotor
  has no velocity-product or gravity term);
* ``h = C qd + g`` by a recursive Newton–Euler pass at ``qdd = 0``: each body's ``m (a_com - gravity)`` and
  ``I alpha + w x I w``, summed over subtrees as wrenches about the world origin and paired with ``S_c``;
* each declaration's ``phi``, ``Jc`` and ``Jcdot qd`` row by row as ``cases.constraints`` defines them, from point
  Jacobians and the points' classical accelerations at ``qdd = 0`` (the rows, signs and scaling of every backend);
  a Pfaffian declaration's ``A`` and ``Adot qd`` (``phi`` 0) likewise, a rolling contact's from the material point at
  the contact plus the sliding of the contact over the disk (``dynamics._pfaffian_rows``);
* the external loads (``cases.loads``) as world wrenches about the world origin (``x x f + m`` with ``x`` the load's
  point, body-frame vectors turned by R, a spring's force ``-k (|d| - L0) d / |d|``) subtracted from each body's own
  in the Newton–Euler pass: ``h`` is then ``C qd + g - tau_ext`` (so :func:`bias_forces` of a loaded model includes
  ``-tau_ext``), and the drift (eq. 14) carries them;
* the constrained solve by the range-space method: ``lam = S^+ (-Jcdot qd - Jc M^-1 f)``, ``qdd = M^-1 (f + Jc^T
  lam)`` with ``S = Jc M^-1 Jc^T``, eigenvalues of S at or below ``crosscheck.guards.conditioning.redundant_below``
  dropped (the minimum-norm multipliers, the backends' rule); ``f = B u - h`` for total and lam, ``-h`` for drift and
  lam_drift (eq. 14), and ``ctrl = B_c B u`` (eq. 17) computed directly.

Group joints (``cases.model``; article 2.1-2.2, 6.2, 6.4). With the joint frame ``(Rj, o)`` (the parent's frame
times the placement) and the parent's ``w0, alpha0`` and origin ``p0, v0, acc0``, a body on a

* spherical joint, ``q_i = (x, y, z, w)``, ``v_i = omega`` (body frame): ``R = Rj R(quat)``, ``p = o``; its columns
  are the rotations about the body's own axes through its origin, ``S_k = (e_k, p x e_k)`` with ``e_k = R[:, k]``;
  ``w = w0 + R omega``, ``alpha = alpha0 + w0 x R omega`` (at ``omegadot = 0``, ``d/dt (R omega) = w x R omega``
  and ``w x R omega = w0 x R omega``); the origin moves with the parent: ``v = v0 + w0 x r``,
  ``acc = acc0 + alpha0 x r + w0 x (w0 x r)``, ``r = p - p0`` (as for a revolute joint);
* free joint, ``q_i = (p_q, x, y, z, w)``, ``v_i = (nu, omega)`` = ``(R(quat)^T pdot_q, omega)``, the body twist:
  ``R = Rj R(quat)``, ``p = o + Rj p_q``; its columns are the translations along the body's axes, then the rotations
  about them through its origin: ``S_k = (0, e_k)``, ``S_{3+k} = (e_k, p x e_k)``; ``w``, ``alpha`` as for the
  spherical joint; ``v = v0 + w0 x r + R nu`` and, at ``(nudot, omegadot) = 0``, ``acc = acc0 + alpha0 x r +
  w0 x (w0 x r) + (w0 + w) x R nu`` (the term ``w0 x R nu`` from the moving joint frame, ``w x R nu`` from
  ``d/dt (R nu)``: the acceleration is the derivative of the body twist, not ``R pdd_q``; for a free body hanging
  from the world, ``acc = w x v``).

Since each column's twist is fixed in the moving body (spherical, free) or in the parent (revolute, prismatic), the
world ``S`` changes with the motion; the Newton–Euler pass with these accelerations at zero ``vdot`` gives ``h``
in velocity space, and ``M`` and the point Jacobians use the same columns, so ``M vdot + h = B u + Jc^T lam`` with
``vdot`` the time derivative of ``v``. A joint coupling joins 1-DOF joints (``cases.constraints``): ``phi`` reads
their q entries (``q_index``), ``Jc`` their velocity columns.

Exactness. q, qd, u and the model's numbers are taken as their exact binary values (``mpf(float)``), so the result is
the exact answer for those inputs, to ``digits``. Two kinds of model data are unit or orthogonal only to rounding in
float, and are made exactly so first: joint axes are normalized, and placement rotations are replaced by the nearest
rotation (polar decomposition), so that the bodies are rigid; the change is at the level of the float data's own
rounding (``cases.model`` validates both to a few eps). Constraint directions are used as given. A quaternion
``(x, y, z, w)`` of q is taken exactly and normalized in mpmath before ``R(quat) = I + 2 w [u]x + 2 [u]x^2`` (u =
``(x, y, z)``) is formed: the float quaternion is unit only to about 1e-16 (``check_state`` accepts 1e-12), and
the rigid rotation of the normalized quaternion is the exact meaning taken here. Pinocchio does not normalize, so
float backends that follow it differ from this reference by about ``| |quat| - 1 |`` (1e-16 for a quaternion
normalized in float).

Cost: O(n^2) multiprecision operations per state plus Cholesky (n^3 / 6), n = nv; see ``reports/speed_accuracy.md`` for
timings (Solo12, nv 18: about 12 ms per split, 75 ms with its 12 contact rows, on gmpy).
"""

from __future__ import annotations

from dataclasses import dataclass

import mpmath
import numpy as np
from mpmath import mpf

from cases.model import Model
from crosscheck.checks.charts import EulerZYX
from crosscheck.references.precise.algebra import (add3, cho_solve, cholesky, cross3, matvec3, matvec_n, RangeSpace,
                                                   scale3, transpose3)
from crosscheck.references.precise.dynamics import bias_terms, composite_mass_matrix, constraint_terms
from crosscheck.references.precise.kinematics import body_kinematics, check_digits, prepare, quaternion_rotation
from formalisms.interface import check_state, Linearization, state_space


#: Default working precision (significant decimal digits).
DIGITS = 50


# ----------------------------------------------------------------------------------------------- public API


@dataclass(frozen=True)
class PreciseSplit:
    """The exact split at one state, to ``digits`` significant digits: ``drift``, ``ctrl``, ``total`` (n mpf each),
    ``lam``, ``lam_drift`` (k mpf each; None when the model has no constraints). n = nv: accelerations in velocity
    space (``cases.model``).

    The mpf values keep their digits, but mpmath rounds every new result to its context's precision (15 digits by
    default): do arithmetic on them inside ``mpmath.workdps(digits)``, or use :func:`relative_error`."""

    drift: tuple
    ctrl: tuple
    total: tuple
    lam: tuple | None
    lam_drift: tuple | None
    digits: int

    def floats(self, name: str) -> np.ndarray | None:
        """The quantity ``name`` rounded to the nearest float64 (None for the multipliers of an unconstrained
        model)."""
        if name not in ("drift", "ctrl", "total", "lam", "lam_drift"):
            raise ValueError(f"PreciseSplit has no quantity {name!r}; quantities: drift, ctrl, total, lam, lam_drift")
        value = getattr(self, name)
        return None if value is None else np.array([float(x) for x in value])


def _state(model: Model, q, qd, u):
    q, qd, u = check_state(model, q, qd, u)
    return [mpf(float(x)) for x in q], [mpf(float(x)) for x in qd], [mpf(float(x)) for x in u]


def _terms(model: Model, q, qd):
    data = prepare(model, mpmath.mp.prec)
    kin = body_kinematics(data, q, qd)
    return data, kin, composite_mass_matrix(data, kin), bias_terms(data, kin)


def split(model: Model, q, qd, u, digits: int = DIGITS) -> PreciseSplit:
    """The split of eq. (9) (eq. 12-17 with constraints) at ``(q, qd, u)``, exact for the float inputs to ``digits``
    significant digits (module doc). ``ctrl = B_c B u`` is computed directly, not as total - drift."""
    digits = check_digits(digits)
    with mpmath.workdps(digits):
        q, qd, u = _state(model, q, qd, u)
        return _split(model, q, qd, matvec_n(prepare(model, mpmath.mp.prec).B, u), digits)


def _split(model: Model, q, qd, tau, digits: int) -> PreciseSplit:
    """:func:`split` at mpf ``q``, ``qd`` and the generalized input force ``tau = B u`` (inside ``workdps``)."""
    data, kin, M, h = _terms(model, q, qd)
    L = cholesky(model, M, q)
    force = [t - x for t, x in zip(tau, h)]
    if not data.rows:
        out = cho_solve(L, [-x for x in h]), cho_solve(L, tau), cho_solve(L, force), None, None
    else:
        _, Jc, bias = constraint_terms(data, kin, q)
        rs = RangeSpace(model, L, Jc, bias)
        drift, lam_drift = rs.solve([-x for x in h])
        total, lam = rs.solve(force)
        out = drift, rs.input_map(tau), total, tuple(lam), tuple(lam_drift)
    return PreciseSplit(tuple(out[0]), tuple(out[1]), tuple(out[2]), out[3], out[4], digits)


# ----------------------------------------------------------------------------------------------- charts


@dataclass(frozen=True)
class PreciseChartSplit:
    """The exact split expressed in a chart of the orientation (``crosscheck.checks.charts.EulerZYX``): the chart point
    ``p``, its rates ``pd``, the chart's accelerations ``drift``, ``ctrl``, ``total`` (``pdd``, nv mpf each), the
    chart's mass matrix ``M_p = Dpsi^T M Dpsi`` and its 2-norm condition number, and cond(Dpsi) (mpf)."""

    p: tuple
    pd: tuple
    drift: tuple
    ctrl: tuple
    total: tuple
    cond_D: mpf
    cond_Mp: mpf
    digits: int

    def floats(self, name: str) -> np.ndarray:
        return np.array([float(x) for x in getattr(self, name)])


def _mp_trig():
    return mpmath.sin, mpmath.cos


def _zyx_angles(quat) -> list:
    """(yaw, pitch, roll) of the normalized quaternion, ``R = Rz Ry Rx`` (``charts.EulerZYX.p_of`` exactly)."""
    R = quaternion_rotation(*quat)
    return [mpmath.atan2(R[1][0], R[0][0]), mpmath.asin(-R[2][0]), mpmath.atan2(R[2][1], R[2][2])]


def _zyx_terms(chart, p, pd) -> tuple[list, list]:
    """``Dpsi(p)`` (nv x nv) and ``(d/dt Dpsi) pd`` (nv) of the zyx chart in mpmath (``charts.EulerZYX``: the same
    E and its derivatives through :meth:`~crosscheck.checks.charts.EulerZYX.rate_rows` with mpmath's sin and cos; a free
    block's ``R^T`` from the exact rotation of the angles)."""
    sin, cos = _mp_trig()
    n = len(p)
    D = [[mpf(1) if i == j else mpf(0) for j in range(n)] for i in range(n)]
    rate = [mpf(0)] * n
    for joint, k, _ in chart._blocks():
        if joint not in ("spherical", "free"):
            continue
        a = k + (3 if joint == "free" else 0)
        E, dEp, dEr = chart.rate_rows(p[a + 1], p[a + 2], sin, cos)
        a_rates = pd[a:a + 3]
        for r in range(3):
            for c in range(3):
                D[a + r][a + c] = mpf(E[r][c])
            rate[a + r] = mpmath.fdot([pd[a + 1] * dEp[r][c] + pd[a + 2] * dEr[r][c] for c in range(3)], a_rates)
        if joint == "free":
            RT = transpose3(quaternion_rotation(*chart._quaternion(p[a], p[a + 1], p[a + 2], sin, cos)))
            for r in range(3):
                for c in range(3):
                    D[k + r][k + c] = RT[r][c]
            w = matvec3(E, a_rates)
            lin = cross3(w, matvec3(RT, pd[k:k + 3]))
            for r in range(3):
                rate[k + r] = -lin[r]
    return D, rate


def _check_chart(chart) -> None:
    if not isinstance(chart, EulerZYX):
        raise ValueError(f"precise chart splits are written for the zyx chart (charts.EulerZYX), got {chart!r}")


def _in_chart(model: Model, chart, p, pd, exact: PreciseSplit, digits: int) -> PreciseChartSplit:
    """The joint-chart split ``exact`` at ``(psi(p), Dpsi pd)`` carried into the chart (inside ``workdps``):
    ``pdd = Dpsi^-1 (vdot - (d/dt Dpsi) pd)``, ctrl by ``Dpsi^-1`` alone."""
    D, rate = _zyx_terms(chart, p, pd)
    Dm = mpmath.matrix(D)

    def solve(b):
        return tuple(mpmath.lu_solve(Dm, mpmath.matrix(list(b))))

    drift = solve([x - r for x, r in zip(exact.drift, rate)])
    total = solve([x - r for x, r in zip(exact.total, rate)])
    M = mpmath.matrix(_terms(model, list(chart.psi(list(p), *_mp_trig())), [mpf(0)] * len(p))[2])
    Mp = Dm.T * M * Dm
    return PreciseChartSplit(tuple(p), tuple(pd), drift, solve(exact.ctrl), total, _cond(Dm), _cond(Mp), digits)


def _cond(A) -> mpf:
    s = mpmath.svd_r(A, compute_uv=False)
    values = [abs(s[i]) for i in range(len(s))]
    return max(values) / min(values) if min(values) > 0 else mpmath.inf


def chart_split(model: Model, chart, q, qd, u, digits: int = DIGITS) -> PreciseChartSplit:
    """The exact split at the joint-chart state ``(q, qd, u)`` (floats taken exactly) expressed in the zyx chart:
    ``p = psi^-1(q)`` of the normalized quaternions, ``pd = Dpsi^-1 qd``, and the accelerations mapped by
    ``pdd = Dpsi^-1 (vdot - (d/dt Dpsi) pd)`` (ctrl by ``Dpsi^-1``), all in mpmath at ``digits``: the answer every
    chart evaluation of this state should give, nothing rounded through floats."""
    digits = check_digits(digits)
    _check_chart(chart)
    with mpmath.workdps(digits):
        q, qd, u = _state(model, q, qd, u)
        p = []
        for joint, _, j in chart._blocks():
            if joint == "spherical":
                p += _zyx_angles(q[j:j + 4])
            elif joint == "free":
                p += list(q[j:j + 3]) + _zyx_angles(q[j + 3:j + 7])
            else:
                p.append(q[j])
        D, _ = _zyx_terms(chart, p, [mpf(0)] * len(p))
        pd = list(mpmath.lu_solve(mpmath.matrix(D), mpmath.matrix(qd)))
        exact = _split(model, q, qd, matvec_n(prepare(model, mpmath.mp.prec).B, u), digits)
        return _in_chart(model, chart, p, pd, exact, digits)


def chart_split_at(model: Model, chart, p, pd, tau_p, digits: int = DIGITS) -> PreciseChartSplit:
    """The exact split at the chart point ``(p, pd)`` with the chart's generalized force ``tau_p`` (floats taken
    exactly): what a chart-native evaluation (``Formalism.split_chart``) with these inputs should return.
    ``q = psi(p)`` and ``v = Dpsi pd`` in mpmath (the quaternions unit to the working precision), ``B u = Dpsi^-T
    tau_p``."""
    digits = check_digits(digits)
    _check_chart(chart)
    with mpmath.workdps(digits):
        p, pd, tau_p = ([mpf(float(x)) for x in np.asarray(v, dtype=float)] for v in (p, pd, tau_p))
        D, _ = _zyx_terms(chart, p, pd)
        q = list(chart.psi(p, *_mp_trig()))
        qd = matvec_n(D, pd)
        tau = list(mpmath.lu_solve(mpmath.matrix(D).T, mpmath.matrix(tau_p)))
        return _in_chart(model, chart, p, pd, _split(model, q, qd, tau, digits), digits)


def mass_matrix(model: Model, q, digits: int = DIGITS) -> mpmath.matrix:
    """``M(q)`` (nv x nv) to ``digits`` significant digits, e.g. for exact condition numbers."""
    digits = check_digits(digits)
    with mpmath.workdps(digits):
        q, qd, _ = _state(model, q, np.zeros(model.n), np.zeros(model.m))
        _, _, M, _ = _terms(model, q, qd)
        return mpmath.matrix(M)


def bias_forces(model: Model, q, qd, digits: int = DIGITS) -> tuple:
    """``h = C(q, qd) qd + g(q)`` (nv mpf) to ``digits`` significant digits (article eq. 7, 8 for the double
    pendulum)."""
    digits = check_digits(digits)
    with mpmath.workdps(digits):
        q, qd, _ = _state(model, q, qd, np.zeros(model.m))
        return tuple(_terms(model, q, qd)[3])


# ----------------------------------------------------------------------------------------------- linearization


def _quaternion_product(a, b) -> list:
    """``a b`` of quaternions in ``(x, y, z, w)`` order."""
    (ax, ay, az, aw), (bx, by, bz, bw) = a, b
    return [aw * bx + ax * bw + ay * bz - az * by, aw * by - ax * bz + ay * bw + az * bx,
            aw * bz + ax * by - ay * bx + az * bw, aw * bw - ax * bx - ay * by - az * bz]


def _quaternion_exp(w) -> list:
    """``exp`` of the rotation vector ``w`` as a unit quaternion ``(sin(t/2) w/t, cos(t/2))``, t = |w|."""
    t = mpmath.sqrt(mpmath.fsum(x * x for x in w))
    s = mpf(1) / 2 if t == 0 else mpmath.sin(t / 2) / t
    return [s * w[0], s * w[1], s * w[2], mpmath.cos(t / 2)]


def _se3_translation(w, v) -> tuple:
    """``V(w) v`` of SE(3)'s exponential (``cases.configuration``), the series below t = 1e-10 (error t^4)."""
    t = mpmath.sqrt(mpmath.fsum(x * x for x in w))
    if t < mpf("1e-10"):
        a, b = mpf(1) / 2 - t * t / 24, mpf(1) / 6 - t * t / 120
    else:
        a, b = (1 - mpmath.cos(t)) / t**2, (t - mpmath.sin(t)) / t**3
    wv = cross3(w, v)
    return add3(add3(v, scale3(a, wv)), scale3(b, cross3(w, wv)))


def _integrate(model: Model, q, dq) -> list:
    """``q (+) dq`` (``cases.configuration.integrate``) in mpmath: each group joint moved by ``exp(dq)`` on the right."""
    out = list(q)
    for i, b in enumerate(model.bodies):
        iq, iv = model.q_index[i], model.v_index[i]
        if b.joint == "spherical":
            out[iq:iq + 4] = _quaternion_product(q[iq:iq + 4], _quaternion_exp(dq[iv:iv + 3]))
        elif b.joint == "free":
            quat = q[iq + 3:iq + 7]
            shift = matvec3(quaternion_rotation(*quat), _se3_translation(dq[iv + 3:iv + 6], dq[iv:iv + 3]))
            out[iq:iq + 3] = [x + d for x, d in zip(q[iq:iq + 3], shift)]
            out[iq + 3:iq + 7] = _quaternion_product(quat, _quaternion_exp(dq[iv + 3:iv + 6]))
        else:
            out[iq] = q[iq] + dq[iv]
    return out


def linearize(model: Model, q, qd, u, digits: int = DIGITS) -> Linearization:
    """A and B of eq. (11) (:class:`~formalisms.interface.Linearization`, its tangent convention) of the exact
    dynamics, constrained ones included (the KKT solution as a function of the state): ``dvdot/dq`` and ``dvdot/dv``
    by central differences at ``digits`` digits with the step ``h = 10^-(digits/3)`` along ``q (+) h e_j`` and
    ``v + h e_j`` (truncation ``h^2`` times the third derivative over 6, rounding ``10^-digits / h``: both near
    ``10^(-2 digits/3)``, 1e-33 at 50 digits, far below double's rounding), and ``dvdot/du = B_c B`` exactly, the
    ``ctrl`` of each unit input (eq. 17). It is the harness's reference for a constrained model (Pinocchio's ABA
    derivatives are unconstrained); a central difference is this reference's method, never a backend's (those
    differentiate exactly)."""
    digits = check_digits(digits)
    qd_float = check_state(model, q, qd, u)[1]
    with mpmath.workdps(digits):
        q, qd, u = _state(model, q, qd, u)
        B = prepare(model, mpmath.mp.prec).B
        tau = matvec_n(B, u)
        step = mpf(10) ** (-(digits // 3))

        def vdot(q_, qd_) -> list:
            return list(_split(model, q_, qd_, tau, digits).total)

        def column(plus: list, minus: list) -> list:
            return [(a - b) / (2 * step) for a, b in zip(plus, minus)]
        units = [[step if i == j else mpf(0) for i in range(model.nv)] for j in range(model.nv)]
        dq = [column(vdot(_integrate(model, q, e), qd), vdot(_integrate(model, q, [-x for x in e]), qd))
              for e in units]
        dv = [column(vdot(q, [x + y for x, y in zip(qd, e)]), vdot(q, [x - y for x, y in zip(qd, e)]))
              for e in units]
        du = [list(_split(model, q, qd, [row[j] for row in B], digits).ctrl) for j in range(model.m)]
        center = vdot(q, qd)
    return state_space(model, qd_float, _columns(dq, model.nv), _columns(dv, model.nv), _columns(du, model.nv),
                       np.array([float(x) for x in center]))


def _columns(columns: list, rows: int) -> np.ndarray:
    """A float matrix (rows x len(columns)) of mpf columns."""
    return np.array([[float(x) for x in col] for col in columns], dtype=float).reshape(-1, rows).T


def relative_error(value, exact) -> float:
    """Norm-wise relative error ``max_i |value_i - exact_i| / max_i |exact_i|``, evaluated in mpmath (float or mpf
    entries, taken exactly, at :data:`DIGITS` digits) and returned as a float. When ``exact`` is all zero there is no
    scale: the absolute error ``max_i |value_i|`` is returned instead. A value that is not finite (NaN, inf) is
    infinitely wrong: inf."""
    value, exact = list(np.asarray(value, dtype=object).reshape(-1)), list(exact)
    if len(value) != len(exact):
        raise ValueError(f"relative_error: value has {len(value)} entries, exact has {len(exact)}")
    with mpmath.workdps(DIGITS):
        if not all(mpmath.isfinite(mpf(a)) for a in value):
            return float("inf")
        err = max((abs(mpf(a) - mpf(b)) for a, b in zip(value, exact)), default=mpf(0))
        size = max((abs(mpf(b)) for b in exact), default=mpf(0))
        return float(err / size) if size else float(err)


__all__ = ["DIGITS", "PreciseChartSplit", "PreciseSplit", "bias_forces", "chart_split", "chart_split_at",
           "linearize", "mass_matrix", "relative_error", "split"]
