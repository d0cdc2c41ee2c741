"""Coordinate charts ``q = psi(p)`` and the maps that carry a state and its answers into them (article 6.4.6,
9.1; docs/design.md, charts).

A chart is a named diffeomorphism with its Jacobian ``Dpsi`` and the term ``(d/dt Dpsi) pd``. Under it

    qd  = Dpsi pd                          velocities are vectors,
    tau_p = Dpsi^T tau_q                   generalized forces are covectors,
    pdd = Dpsi^-1 (qdd - (d/dt Dpsi) pd)   accelerations pick up the chart's own velocity-product term.

The physics is the same in every chart; a formalism that evaluates in p (``Formalism.split_chart``) receives the
chart object and evaluates ``psi`` in its own symbolic language, so its Jacobians are its own. The harness uses
the analytic Jacobians written here to map every joint-chart answer into p and compare.

Built-in charts: ``identity``; ``absolute`` (planar serial chains: ``phi_i = theta_1 + ... + theta_i``, 6.4.6);
``affine`` (``q = A p + b``, a random well-conditioned A, seeded per case); ``nonlinear``
(``q_i = p_i + a sin(p_{i+1})``, last coordinate unchanged: ``Dpsi`` is unit upper triangular, so the chart is
a global diffeomorphism for every a, inverted by back substitution). For models with spherical or free joints:
``zyx`` (ZYX Euler angles of every orientation, :class:`EulerZYX`), ``exp`` (exponential coordinates about a
seeded centre orientation, :class:`ExponentialCoordinates`) and the base-velocity representations ``world`` and
``mixed`` (:class:`VelocityRepresentation`: ``p = q``, ``v = T(q) w``, ``Dpsi := T``).
"""

from __future__ import annotations

import hashlib
import math
from dataclasses import dataclass, field
from typing import Callable, Sequence

import numpy as np

from cases import configuration
from cases.model import Model
from crosscheck.core.sampling import case_rng


class ChartError(ValueError):
    """A chart that does not apply to a model, or an unknown chart name."""


@dataclass(frozen=True)
class Chart:
    """Base of the built-in charts: the generic ``psi`` and its numeric inverse, Jacobian and Jacobian rate."""

    name: str

    @property
    def key(self) -> str:
        """A stable digest of the definition (name and parameters), for caches keyed by chart."""
        return hashlib.sha256(repr((type(self).__name__, self._params())).encode()).hexdigest()[:16]

    def _params(self) -> tuple:
        return ()

    def psi(self, p: Sequence, sin: Callable = math.sin, cos: Callable = math.cos) -> list:
        raise NotImplementedError

    def q_of(self, p) -> np.ndarray:
        """``q = psi(p)`` in floating point."""
        return np.array(self.psi(list(np.asarray(p, dtype=float)), math.sin, math.cos), dtype=float)

    def p_of(self, q) -> np.ndarray:
        """The inverse ``p = psi^-1(q)``."""
        raise NotImplementedError

    def jacobian(self, p) -> np.ndarray:
        """``Dpsi(p) = dq/dp`` (n x n)."""
        raise NotImplementedError

    def jacobian_rate(self, p, pd) -> np.ndarray:
        """``(d/dt Dpsi) pd``: the acceleration ``q`` has when ``pdd = 0`` (n)."""
        raise NotImplementedError


def _number(x: float) -> float | int:
    """Integral coefficients as ints, so a symbolic library keeps them exact (1*p stays p, -1*p stays -p)."""
    return int(x) if float(x).is_integer() else float(x)


@dataclass(frozen=True)
class AffineChart(Chart):
    """``q = A p + b``: constant Jacobian, no rate term. ``identity`` and ``absolute`` are instances."""

    A: np.ndarray = field(default_factory=lambda: np.eye(1))
    b: np.ndarray = field(default_factory=lambda: np.zeros(1))

    def _params(self) -> tuple:
        return (np.asarray(self.A).tolist(), np.asarray(self.b).tolist())

    def psi(self, p, sin=math.sin, cos=math.cos) -> list:
        n, out = len(p), []
        for i in range(n):
            terms = [p[j] if self.A[i, j] == 1.0 else _number(self.A[i, j]) * p[j]
                     for j in range(n) if self.A[i, j] != 0.0]
            if self.b[i] != 0.0:
                terms.append(_number(self.b[i]))
            q_i = terms[0]
            for t in terms[1:]:
                q_i = q_i + t
            out.append(q_i)
        return out

    def p_of(self, q) -> np.ndarray:
        return np.linalg.solve(self.A, np.asarray(q, dtype=float) - self.b)

    def jacobian(self, p) -> np.ndarray:
        return np.array(self.A, dtype=float)

    def jacobian_rate(self, p, pd) -> np.ndarray:
        return np.zeros(len(pd))


@dataclass(frozen=True)
class NonlinearChart(Chart):
    """``q_i = p_i + a sin(p_{i+1})`` for i < n-1, ``q_{n-1} = p_{n-1}``."""

    a: float = 0.5

    def _params(self) -> tuple:
        return (float(self.a),)

    def psi(self, p, sin=math.sin, cos=math.cos) -> list:
        n = len(p)
        return [p[i] + self.a * sin(p[i + 1]) if i + 1 < n else p[i] for i in range(n)]

    def p_of(self, q) -> np.ndarray:
        q = np.asarray(q, dtype=float)
        p = q.copy()
        for i in range(len(q) - 2, -1, -1):
            p[i] = q[i] - self.a * math.sin(p[i + 1])
        return p

    def jacobian(self, p) -> np.ndarray:
        p = np.asarray(p, dtype=float)
        return np.eye(len(p)) + np.diag(self.a * np.cos(p[1:]), 1)

    def jacobian_rate(self, p, pd) -> np.ndarray:
        p, pd = np.asarray(p, dtype=float), np.asarray(pd, dtype=float)
        return np.append(-self.a * np.sin(p[1:]) * pd[1:] ** 2, 0.0)


def identity(n: int) -> AffineChart:
    return AffineChart("identity", np.eye(n), np.zeros(n))


@dataclass(frozen=True)
class GroupIdentity(Chart):
    """The joint coordinates of a model with spherical or free joints, as the identity chart: ``p`` is q itself
    (``nq`` entries, quaternions included) and ``pd`` the velocity v (``nv``), so ``Dpsi`` is the nv x nv identity
    between velocities. Only evaluation uses it (``crosscheck eval``); the gate samples no chart for such models."""

    nv: int = 0

    def _params(self) -> tuple:
        return (self.nv,)

    def q_of(self, p) -> np.ndarray:
        return np.array(p, dtype=float)

    def p_of(self, q) -> np.ndarray:
        return np.array(q, dtype=float)

    def jacobian(self, p) -> np.ndarray:
        return np.eye(self.nv)

    def jacobian_rate(self, p, pd) -> np.ndarray:
        return np.zeros(self.nv)


def is_planar_serial(model: Model) -> bool:
    """A single chain of revolute joints whose axes are all parallel in the world (the chain is planar)."""
    if any(model.parent_index[i] != i - 1 for i in range(model.n)):
        return False
    if any(b.joint != "revolute" for b in model.bodies):
        return False
    R, axes = np.eye(3), []
    for body in model.bodies:  # joint rotations are about the axis itself, so the axis direction needs the
        R = R @ body.rotation  # fixed placements only
        axes.append(R @ body.axis)
    return all(np.linalg.norm(np.cross(axes[0], a)) < 1e-12 for a in axes)


def absolute(model: Model) -> AffineChart:
    """Absolute angles ``phi_i = theta_1 + ... + theta_i`` (article 6.4.6): ``q = psi(phi)`` with
    ``theta_1 = phi_1``, ``theta_i = phi_i - phi_{i-1}``."""
    if not is_planar_serial(model):
        raise ChartError(f"chart 'absolute' needs a planar serial chain of revolute joints with parallel axes; "
                         f"model '{model.name}' is not one")
    n = model.n
    return AffineChart("absolute", np.eye(n) - np.eye(n, k=-1), np.zeros(n))


#: The largest model whose affine chart is dense; beyond it each joint coordinate mixes the chart coordinates within
#: :data:`AFFINE_BAND` of it (:func:`random_affine`).
AFFINE_DENSE_LIMIT = 12
AFFINE_BAND = 2
#: Draws of A before the last one is shrunk to cond(A) <= max_cond: a random banded A meets the bound one time in 6
#: at 13 coordinates, one in 140 at 30 and almost never past 50 (tiago_dual's chart drew for ever, issue 34).
AFFINE_DRAWS = 1000


def random_affine(model: Model, seed: int, case: str, max_cond: float = 10.0) -> AffineChart:
    """``q = A p + b`` with ``A = I + G / sqrt(k)`` (G standard normal on k entries per row) redrawn until
    cond(A) <= max_cond (after :data:`AFFINE_DRAWS` draws, the last one's ``G`` shrunk to spectral norm
    ``(max_cond - 1) / (max_cond + 1)``, which bounds cond(A) by max_cond), and b uniform in +-1; seeded by (seed,
    case), so a gate run always uses the same chart.

    Up to :data:`AFFINE_DENSE_LIMIT` coordinates G is dense (every joint coordinate mixes all the chart coordinates,
    k = n); beyond, G is banded, ``|i - j| <= AFFINE_BAND``: a dense chart makes every body's pose a function of all
    n chart coordinates, so a derivation in it (Euler–Lagrange's) has O(n^3) terms in M alone (2 million operations
    per state for a 48-joint robot, against 2 thousand in its joint chart), while a band keeps the pose of a body at
    depth d a function of d + 2 AFFINE_BAND coordinates and still mixes neighbouring joints (across branches of a
    tree, whose coordinates follow one another in v's order) with an unsymmetric A."""
    rng = case_rng(seed, case + "/affine")
    n = model.n
    dense = n <= AFFINE_DENSE_LIMIT
    mask = np.ones((n, n)) if dense else (np.abs(np.subtract.outer(np.arange(n), np.arange(n))) <= AFFINE_BAND)
    per_row = n if dense else 2 * AFFINE_BAND + 1
    for _ in range(AFFINE_DRAWS):
        G = rng.standard_normal((n, n)) * mask / np.sqrt(per_row)
        A = np.eye(n) + G
        if np.linalg.cond(A) <= max_cond:
            return AffineChart("affine", A, rng.uniform(-1.0, 1.0, n))
    r = (max_cond - 1.0) / (max_cond + 1.0)          # |G| <= r bounds cond(I + G) by (1 + r) / (1 - r) = max_cond
    A = np.eye(n) + G * min(1.0, r / np.linalg.norm(G, 2))
    return AffineChart("affine", A, rng.uniform(-1.0, 1.0, n))


def _joint_blocks(joints: Sequence[str]):
    """(joint type, start in v (and in a chart's p), start in q) per body, in body order."""
    k = j = 0
    for joint in joints:
        yield joint, k, j
        k += {"spherical": 3, "free": 6}.get(joint, 1)
        j += {"spherical": 4, "free": 7}.get(joint, 1)


@dataclass(frozen=True)
class EulerZYX(Chart):
    """ZYX Euler angles for every spherical and free joint's orientation (article 6.4, 9.1: a map of the globe).

    ``p`` has one entry per velocity coordinate (``nv``): a revolute or prismatic joint keeps its coordinate; a
    spherical joint's block is ``(yaw, pitch, roll)`` with ``R = Rz(yaw) Ry(pitch) Rx(roll)``; a free joint's block is
    its position (as in q) then those three angles. ``psi(p)`` is the whole q (``nq`` entries), the quaternion
    ``qz(yaw) qy(pitch) qx(roll)`` from the half angles' sines and cosines, so a formalism can derive in p
    (``split_chart``). ``Dpsi`` maps ``pd`` to the velocity v: per spherical block the body angular velocity
    ``w = E(pitch, roll) (yaw, pitch, roll)dot`` with ``E = [[-s_p, 0, 1], [c_p s_r, c_r, 0], [c_p c_r, -s_r, 0]]``, per
    free block also ``v_lin = R^T pdot``. ``E`` is singular at pitch = +-pi/2 (gimbal lock): the chart then has no
    coordinates for the motion, and the gate leaves its chart check out there (:data:`GIMBAL_LIMIT`)."""

    joints: tuple = ()

    def _params(self) -> tuple:
        return self.joints

    def _blocks(self):
        """(joint type, start in p, start in q) per body."""
        return _joint_blocks(self.joints)

    @staticmethod
    def _quaternion(yaw, pitch, roll, sin, cos) -> list:
        cy, sy, cp, sp = cos(yaw / 2), sin(yaw / 2), cos(pitch / 2), sin(pitch / 2)
        cr, sr = cos(roll / 2), sin(roll / 2)
        return [sr * cp * cy - cr * sp * sy, cr * sp * cy + sr * cp * sy, cr * cp * sy - sr * sp * cy,
                cr * cp * cy + sr * sp * sy]

    def psi(self, p, sin=math.sin, cos=math.cos) -> list:
        out = []
        for joint, k, _ in self._blocks():
            if joint == "spherical":
                out += self._quaternion(p[k], p[k + 1], p[k + 2], sin, cos)
            elif joint == "free":
                out += [p[k], p[k + 1], p[k + 2]] + self._quaternion(p[k + 3], p[k + 4], p[k + 5], sin, cos)
            else:
                out.append(p[k])
        return out

    @staticmethod
    def _angles(quat) -> list[float]:
        x, y, z, w = quat
        R = np.eye(3) + 2.0 * w * _skew((x, y, z)) + 2.0 * _skew((x, y, z)) @ _skew((x, y, z))
        return [math.atan2(R[1, 0], R[0, 0]), math.asin(max(-1.0, min(1.0, -R[2, 0]))), math.atan2(R[2, 1], R[2, 2])]

    def p_of(self, q) -> np.ndarray:
        q, out = np.asarray(q, dtype=float), []
        for joint, _, j in self._blocks():
            if joint == "spherical":
                out += self._angles(q[j:j + 4])
            elif joint == "free":
                out += list(q[j:j + 3]) + self._angles(q[j + 3:j + 7])
            else:
                out.append(q[j])
        return np.array(out)

    @staticmethod
    def rate_rows(pitch, roll, sin: Callable = math.sin, cos: Callable = math.cos) -> tuple[list, list, list]:
        """E (pd of (yaw, pitch, roll) -> body angular velocity) and its derivatives by pitch and by roll, as nested
        lists in the number type of ``sin`` and ``cos`` (mpmath's for the exact reference,
        ``crosscheck.references.precise``)."""
        sp, cp, sr, cr = sin(pitch), cos(pitch), sin(roll), cos(roll)
        E = [[-sp, 0.0, 1.0], [cp * sr, cr, 0.0], [cp * cr, -sr, 0.0]]
        dE_pitch = [[-cp, 0.0, 0.0], [-sp * sr, 0.0, 0.0], [-sp * cr, 0.0, 0.0]]
        dE_roll = [[0.0, 0.0, 0.0], [cp * cr, -sr, 0.0], [-cp * sr, -cr, 0.0]]
        return E, dE_pitch, dE_roll

    @staticmethod
    def _rates(pitch: float, roll: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """:meth:`rate_rows` in floating point, as arrays."""
        E, dE_pitch, dE_roll = EulerZYX.rate_rows(pitch, roll)
        return np.array(E, dtype=float), np.array(dE_pitch, dtype=float), np.array(dE_roll, dtype=float)

    def _rotation(self, angles) -> np.ndarray:
        quat = self._quaternion(*angles, math.sin, math.cos)
        return configuration.rotation(np.asarray(quat, dtype=float))

    def jacobian(self, p) -> np.ndarray:
        p = np.asarray(p, dtype=float)
        D = np.eye(len(p))
        for joint, k, _ in self._blocks():
            if joint in ("spherical", "free"):
                a = k + (3 if joint == "free" else 0)
                D[a:a + 3, a:a + 3] = self._rates(p[a + 1], p[a + 2])[0]
                if joint == "free":
                    D[k:k + 3, k:k + 3] = self._rotation(p[a:a + 3]).T
        return D

    def jacobian_rate(self, p, pd) -> np.ndarray:
        p, pd = np.asarray(p, dtype=float), np.asarray(pd, dtype=float)
        out = np.zeros(len(p))
        for joint, k, _ in self._blocks():
            if joint in ("spherical", "free"):
                a = k + (3 if joint == "free" else 0)
                E, dE_pitch, dE_roll = self._rates(p[a + 1], p[a + 2])
                out[a:a + 3] = (pd[a + 1] * dE_pitch + pd[a + 2] * dE_roll) @ pd[a:a + 3]
                if joint == "free":       # d/dt (R^T pdot) at pdd = 0: -w x (R^T pdot), w = E adot (body frame)
                    w = E @ pd[a:a + 3]
                    out[k:k + 3] = -np.cross(w, self._rotation(p[a:a + 3]).T @ pd[k:k + 3])
        return out


def _skew(v) -> np.ndarray:
    return np.array([[0.0, -v[2], v[1]], [v[2], 0.0, -v[0]], [-v[1], v[0], 0.0]])


#: Below this rotation angle |p| the float methods of :class:`ExponentialCoordinates` use the Taylor series of the
#: coefficients of ``J_r`` and of its rate: their closed forms lose digits to cancellation as |p| -> 0 (``B`` of
#: :func:`_exp_coefficients` relatively eps / |p|^4: 1.4e-12 at |p| = 0.25, 2e-16 at 1). The series kept (through
#: |p|^20, :data:`_EXP_SERIES_TERMS`) are exact to rounding below it (the first term left out is below 1e-18).
EXP_SERIES_BELOW = 1.0
_EXP_SERIES_TERMS = 11


#: |p| of an orientation block below which :meth:`ExponentialCoordinates.at_centre` holds: the chart-native backends'
#: derivatives of psi lose digits there (measured on the ball pendulum, the chart check's error/tolerance was 0.014 at
#: |p| = 1e-3, 0.11 at 1e-4, 3.6 at 1e-5 and 20 at 3e-6).
EXP_CENTRE_LIMIT = 1e-3


def _series(coefficient: Callable[[int], float]) -> tuple[float, ...]:
    return tuple(coefficient(k) for k in range(_EXP_SERIES_TERMS))


#: Taylor coefficients in s = t^2 (class docstring of :class:`ExponentialCoordinates`): ``a = sum (-s)^k/(2k+2)!``,
#: ``b = sum (-s)^k/(2k+3)!``, and ``A = a'/t``, ``B = b'/t`` term by term (``d/dt t^2k = 2k t^(2k-1)``).
_EXP_SERIES = (_series(lambda k: (-1) ** k / math.factorial(2 * k + 2)),
               _series(lambda k: (-1) ** k / math.factorial(2 * k + 3)),
               _series(lambda k: (-1) ** (k + 1) * (2 * k + 2) / math.factorial(2 * k + 4)),
               _series(lambda k: (-1) ** (k + 1) * (2 * k + 2) / math.factorial(2 * k + 5)))


def _horner(coefficients: Sequence[float], s: float) -> float:
    out = 0.0
    for c in reversed(coefficients):
        out = out * s + c
    return out


def _exp_coefficients(t: float) -> tuple[float, float, float, float]:
    """``(a, b, A, B)`` at the angle t: ``J_r = I - a [p]x + b [p]x^2`` with ``a = (1 - cos t)/t^2``,
    ``b = (t - sin t)/t^3``, and their derivatives divided by t, ``A = a'(t)/t``, ``B = b'(t)/t`` (so that
    ``d/dt a = A (p . pd)``), each from its Taylor series below :data:`EXP_SERIES_BELOW`."""
    if t < EXP_SERIES_BELOW:
        s = t * t
        a, b, A, B = (_horner(c, s) for c in _EXP_SERIES)
        return a, b, A, B
    half = math.sin(t / 2)
    one_minus_cos, sin = 2.0 * half * half, math.sin(t)
    a, b = one_minus_cos / t**2, (t - sin) / t**3
    return a, b, (t * sin - 2.0 * one_minus_cos) / t**4, (t * one_minus_cos - 3.0 * (t - sin)) / t**5


def _quaternion_product(a: Sequence, b: Sequence) -> list:
    """Hamilton product of quaternions ``(x, y, z, w)`` (the rotation ``R(a) R(b)``), in generic scalar operations."""
    ax, ay, az, aw = a
    bx, by, bz, bw = b
    return [aw * bx + bw * ax + ay * bz - az * by, aw * by + bw * ay + az * bx - ax * bz,
            aw * bz + bw * az + ax * by - ay * bx, aw * bw - ax * bx - ay * by - az * bz]


@dataclass(frozen=True)
class ExponentialCoordinates(Chart):
    """Exponential coordinates of the first kind for every spherical and free joint's orientation, about a centre
    (article 6.2 the exponential map, 6.4 a map of the globe, 9.1).

    ``p`` has one entry per velocity coordinate (``nv``): a revolute or prismatic joint keeps its coordinate; a
    spherical joint's block is ``p`` in ``R = R_c exp([p]x)``, with ``R_c`` the joint's CENTRE orientation (a unit
    quaternion ``(x, y, z, w)`` in :attr:`centers`, one per group joint in body order, part of the chart's
    parameters and of its key); a free joint's block is its position (as in q) then the same for its orientation.
    ``psi(p)`` is the whole q (``nq`` entries): per group joint the quaternion ``q_c (x) (sin(t/2) p/t, cos(t/2))``,
    ``t = (p . p) ** 0.5``, written with generic operations (``** 0.5``, ``sin``, ``cos``, ``/``) so that a formalism
    can derive in p (``split_chart``); with Python floats at ``t = 0`` exactly it returns the limit ``q_c``.

    ``Dpsi`` maps ``pd`` to the velocity v: per rotation block SO(3)'s right Jacobian, ``w_body = J_r(p) pd`` with
    ``J_r = I - (1 - cos t)/t^2 [p]x + (t - sin t)/t^3 [p]x^2``; per free block also ``v_lin = R^T pdot`` (as in
    :class:`EulerZYX`). The rate ``(d/dt J_r) pd`` at ``pdd = 0`` is, with ``[pd]x pd = 0``,
    ``-A (p . pd) (p x pd) + B (p . pd) p x (p x pd) + b pd x (p x pd)`` (``a``, ``b``, ``A = a'/t``, ``B = b'/t`` of
    :func:`_exp_coefficients`); a free block's position rate is ``-w x (R^T pdot)``. The float methods use Taylor
    series below ``t =`` :data:`EXP_SERIES_BELOW`, so they are accurate as ``p -> 0``.

    Domain. :meth:`p_of` takes the shortest rotation, ``|p| <= pi``. There ``J_r`` has the singular value 1 along p
    and ``2 sin(t/2) / t >= 2/pi`` across it (twice, one per direction), so ``cond(J_r) <= pi/2``: the chart has no
    singularity on its domain (``exp`` is singular first at ``t = 2 pi``), and the gimbal-lock limit of the chart
    check (:data:`GIMBAL_LIMIT`) is never reached.

    Why a centre. About the identity (``R_c = I``) a state at the identity orientation (the gate's state 0, and any
    model's neutral configuration) would sit at ``p = 0``, where every formula above is the removable 0/0 of
    ``sin(t/2)/t``: the symbolic and automatic derivatives the chart-native backends take of psi are NaN there, and the
    closed forms lose digits nearby. :func:`get` draws the centres per case, Haar-uniformly on SO(3) from
    ``case_rng(seed, case + "/exp")`` (as :func:`random_affine` draws A and b), so a sampled state is at ``p = 0``
    with probability 0 (and within angle t of it with probability of order ``t^3``), and the same seed and case
    always give the same chart."""

    joints: tuple = ()
    centers: tuple = ()

    def _params(self) -> tuple:
        return (self.joints, self.centers)

    def at_centre(self, p) -> bool:
        """Whether some orientation block of p is within :data:`EXP_CENTRE_LIMIT` of the centre (``p = 0``), where
        psi's symbolic and automatic derivatives in the chart-native backends are the removable 0/0 of
        ``sin(t/2)/t``: their second derivatives cancel, so the backends' answers lose digits as t -> 0 (faster than
        eps / t: :data:`EXP_CENTRE_LIMIT`), and at ``p = 0`` exactly they divide by zero. The rotation angle of a
        Haar-uniform rotation relative to the centre has density ``(1 - cos t) / pi``, so a gate's state is within t of
        it with probability about ``t^3 / (6 pi)`` per joint (5e-11 at the limit; the centre is drawn, class
        docstring); the chart check and ``eval`` leave such a p out (a BREAKDOWN of the chart's formulas)."""
        p = np.asarray(p, dtype=float)
        for joint, k, _, _ in self._blocks():
            if joint in ("spherical", "free"):
                a = k + (3 if joint == "free" else 0)
                if float(np.linalg.norm(p[a:a + 3])) < EXP_CENTRE_LIMIT:
                    return True
        return False

    def _blocks(self):
        """(joint type, start in p, start in q, centre or None) per body."""
        g = 0
        for joint, k, j in _joint_blocks(self.joints):
            center = None
            if joint in ("spherical", "free"):
                center, g = self.centers[g], g + 1
            yield joint, k, j, center

    @staticmethod
    def _quaternion(w: Sequence, center: Sequence, sin: Callable, cos: Callable) -> list:
        """``q_c (x) exp(w)``: the quaternion of ``R_c exp([w]x)``, generic in the scalars of w."""
        x, y, z = w
        t = (x * x + y * y + z * z) ** 0.5
        if isinstance(t, float) and t == 0.0:  # floats at p = 0 exactly: the limit (symbolic inputs never get here)
            return [float(c) for c in center]
        s = sin(t / 2) / t
        return _quaternion_product(center, [s * x, s * y, s * z, cos(t / 2)])

    def psi(self, p, sin=math.sin, cos=math.cos) -> list:
        out = []
        for joint, k, _, center in self._blocks():
            if joint == "spherical":
                out += self._quaternion(p[k:k + 3], center, sin, cos)
            elif joint == "free":
                out += [p[k], p[k + 1], p[k + 2]] + self._quaternion(p[k + 3:k + 6], center, sin, cos)
            else:
                out.append(p[k])
        return out

    @staticmethod
    def _log(quat, center) -> list[float]:
        """The shortest ``p`` (``|p| <= pi``) with ``exp([p]x) = R_c^T R(quat)``."""
        c = np.asarray(center, dtype=float)
        r = np.array(_quaternion_product([-c[0], -c[1], -c[2], c[3]], [float(v) for v in quat]))
        r = r / np.linalg.norm(r)
        if r[3] < 0.0:
            r = -r
        n = float(np.linalg.norm(r[:3]))
        if n < 1e-8:       # 2 atan(n / w) / n to rounding: 2 / w (1 - (n / w)^2 / 3)
            scale = 2.0 / r[3] * (1.0 - (n / r[3]) ** 2 / 3.0)
        else:
            scale = 2.0 * math.atan2(n, r[3]) / n
        return list(scale * r[:3])

    def p_of(self, q) -> np.ndarray:
        q, out = np.asarray(q, dtype=float), []
        for joint, _, j, center in self._blocks():
            if joint == "spherical":
                out += self._log(q[j:j + 4], center)
            elif joint == "free":
                out += list(q[j:j + 3]) + self._log(q[j + 3:j + 7], center)
            else:
                out.append(q[j])
        return np.array(out)

    @staticmethod
    def right_jacobian(w) -> np.ndarray:
        """``J_r(w) = I - a [w]x + b [w]x^2`` (series near 0)."""
        w = np.asarray(w, dtype=float)
        a, b, _, _ = _exp_coefficients(float(np.linalg.norm(w)))
        K = _skew(w)
        return np.eye(3) - a * K + b * K @ K

    @staticmethod
    def right_jacobian_rate(w, wd) -> np.ndarray:
        """``(d/dt J_r(w)) wd`` at ``wdd = 0`` (class docstring; series near 0)."""
        w, wd = np.asarray(w, dtype=float), np.asarray(wd, dtype=float)
        _, b, A, B = _exp_coefficients(float(np.linalg.norm(w)))
        along, across = float(w @ wd), np.cross(w, wd)
        return -A * along * across + B * along * np.cross(w, across) + b * np.cross(wd, across)

    def _rotation(self, w, center) -> np.ndarray:
        return configuration.rotation(np.asarray(self._quaternion(list(np.asarray(w, dtype=float)), center, math.sin,
                                                                   math.cos), dtype=float))

    def jacobian(self, p) -> np.ndarray:
        p = np.asarray(p, dtype=float)
        D = np.eye(len(p))
        for joint, k, _, center in self._blocks():
            if joint in ("spherical", "free"):
                a = k + (3 if joint == "free" else 0)
                D[a:a + 3, a:a + 3] = self.right_jacobian(p[a:a + 3])
                if joint == "free":
                    D[k:k + 3, k:k + 3] = self._rotation(p[a:a + 3], center).T
        return D

    def jacobian_rate(self, p, pd) -> np.ndarray:
        p, pd = np.asarray(p, dtype=float), np.asarray(pd, dtype=float)
        out = np.zeros(len(p))
        for joint, k, _, center in self._blocks():
            if joint in ("spherical", "free"):
                a = k + (3 if joint == "free" else 0)
                out[a:a + 3] = self.right_jacobian_rate(p[a:a + 3], pd[a:a + 3])
                if joint == "free":       # d/dt (R^T pdot) at pdd = 0: -w x (R^T pdot), w = J_r pd (body frame)
                    w = self.right_jacobian(p[a:a + 3]) @ pd[a:a + 3]
                    out[k:k + 3] = -np.cross(w, self._rotation(p[a:a + 3], center).T @ pd[k:k + 3])
        return out


def exponential(model: Model, seed: int, case: str) -> ExponentialCoordinates:
    """The exp chart of ``model``: one centre per spherical or free joint, in body order, uniform on SO(3) (Haar) from
    ``case_rng(seed, case + "/exp")`` (:class:`ExponentialCoordinates`, "Why a centre")."""
    rng = case_rng(seed, case + "/exp")
    centers = tuple(tuple(float(c) for c in configuration.random_quaternion(rng)) for _ in model.group_joints)
    return ExponentialCoordinates("exp", tuple(b.joint for b in model.bodies), centers)


# ---------------------------------------------------------------------------------------- velocity representations

#: The base-velocity representations other than Pinocchio's body-frame one (:class:`VelocityRepresentation`).
REPRESENTATIONS = ("world", "mixed")


@dataclass(frozen=True)
class VelocityRepresentation(Chart):
    """A chart of the velocities only (docs/design.md, "Configuration on Lie groups": world and mixed base velocity).
    The configuration stays q (``p = q``, nq entries, quaternions included: :meth:`p_of` and :meth:`q_of` are the
    identity) and the velocity is w with ``v = T(q) w``; the chart maps of this module hold with ``Dpsi := T``:
    ``vdot = T wdot + Tdot w`` (:meth:`jacobian_rate` is ``Tdot w``) and ``tau_w = T^T tau_v``.

    Everything is in the joint's REFERENCE frame: the frame its q is measured in, the parent body's frame moved by
    the body's fixed placement (for a floating base at the identity placement, the world). With ``R``, ``p`` the
    joint's rotation and position from q and ``w_b``, ``v_b`` its body angular and linear velocity (v's blocks):

    * ``world`` (the spatial twist, Featherstone's and Murray's space frame): a free joint's block is
      ``V_s = (v_s, omega_s)``, ``omega_s = R w_b``, ``v_s = pdot - omega_s x p`` (the velocity of the body-fixed
      point at the reference origin), and ``v = Ad_{X^-1} V_s``: ``T = [[R^T, -R^T [p]x], [0, R^T]]`` in
      (linear, angular) order; ``Tdot w = 0`` (``d/dt Ad_{X^-1} = -ad_{V_b} Ad_{X^-1}`` and ``ad_V V = 0``).
    * ``mixed`` (Pinocchio's LOCAL_WORLD_ALIGNED: the body origin's velocity in the reference axes): a free joint's
      block is ``(pdot, omega_s)``, ``T = blockdiag(R^T, R^T)``, ``Tdot w = (-w_b x v_b, 0)``.
    * A spherical joint in both: ``omega_s = R w_b``, ``T = R^T``, ``Tdot w = 0``. Revolute and prismatic: identity.

    There is no ``psi``: a backend reads :attr:`representation` (duck-typed) and derives the dynamics in the
    matching LEFT exponential chart at the state itself (``formalisms.euler_lagrange``, ``formalisms.geometric``).
    ``mixed`` equals ``world`` on a model without a free joint, so the gate samples it only with one (:func:`sampled`).
    """

    representation: str = "world"
    joints: tuple = ()

    def _params(self) -> tuple:
        return (self.representation, self.joints)

    def _blocks(self):
        """(joint type, start in v, start in q) per body."""
        return _joint_blocks(self.joints)

    @property
    def nv(self) -> int:
        return sum({"spherical": 3, "free": 6}.get(joint, 1) for joint in self.joints)

    def q_of(self, p) -> np.ndarray:
        return np.array(p, dtype=float)

    def p_of(self, q) -> np.ndarray:
        return np.array(q, dtype=float)

    def jacobian(self, p) -> np.ndarray:
        """``T(q)`` (nv x nv): ``v = T w``."""
        q = np.asarray(p, dtype=float)
        D = np.eye(self.nv)
        for joint, k, j in self._blocks():
            if joint == "spherical":
                D[k:k + 3, k:k + 3] = configuration.rotation(q[j:j + 4]).T
            elif joint == "free":
                Rt = configuration.rotation(q[j + 3:j + 7]).T
                D[k:k + 3, k:k + 3] = D[k + 3:k + 6, k + 3:k + 6] = Rt
                if self.representation == "world":
                    D[k:k + 3, k + 3:k + 6] = -Rt @ _skew(q[j:j + 3])
        return D

    def jacobian_rate(self, p, pd) -> np.ndarray:
        """``Tdot w``: 0 but for a free joint in ``mixed``, ``(-w_b x v_b, 0)`` with ``v = T w``."""
        out = np.zeros(self.nv)
        if self.representation != "mixed":
            return out
        v = self.jacobian(p) @ np.asarray(pd, dtype=float)
        for joint, k, _ in self._blocks():
            if joint == "free":
                out[k:k + 3] = -np.cross(v[k + 3:k + 6], v[k:k + 3])
        return out


def velocity_representation(model: Model, name: str) -> VelocityRepresentation:
    """The representation ``name`` (``world`` or ``mixed``) of a model with spherical or free joints."""
    if not model.group_joints:
        raise ChartError(f"chart '{name}' (a base-velocity representation) does not apply to model '{model.name}', "
                         "which has no spherical or free joint")
    return VelocityRepresentation(name, name, tuple(b.joint for b in model.bodies))


def representations_sampled(model: Model) -> list[VelocityRepresentation]:
    """The representations the gate checks for a model with group joints: ``world``, and ``mixed`` when it has a
    free joint (with spherical joints only, mixed is world)."""
    free = any(model.bodies[i].joint == "free" for i in model.group_joints)
    return [velocity_representation(model, name) for name in REPRESENTATIONS if name == "world" or free]


#: cond(Dpsi) above which a chart of the orientation has lost a direction (gimbal lock, :class:`EulerZYX`): its
#: coordinates cannot express the motion, so the chart check is left out at that state (a BREAKDOWN of the chart).
GIMBAL_LIMIT = 1e4


def nonlinear(model: Model, a: float = 0.5) -> NonlinearChart:
    return NonlinearChart("nonlinear", a)


def names() -> list[str]:
    return ["identity", "absolute", "affine", "nonlinear", "zyx", "exp"] + list(REPRESENTATIONS)


#: The charts of the orientations of spherical and free joints (models with group joints have only these, the
#: velocity representations and identity).
GROUP_CHARTS = ("zyx", "exp")


def get(name: str, model: Model, seed: int = 0, case: str | None = None) -> Chart:
    """The built-in chart ``name`` for ``model`` (``affine`` and the centres of ``exp`` are drawn from ``seed`` and the
    case name, ``model.name`` when not given)."""
    case = model.name if case is None else case
    if name in REPRESENTATIONS:
        return velocity_representation(model, name)
    if not applies(model):
        if name == "identity":
            return GroupIdentity("identity", model.nv)
        if name == "zyx":
            return EulerZYX("zyx", tuple(b.joint for b in model.bodies))
        if name == "exp":
            return exponential(model, seed, case)
        raise ChartError(f"chart '{name}' does not apply to model '{model.name}': its spherical or free joints have "
                         "quaternion coordinates, which a joint-coordinate chart cannot map (its charts: zyx, exp, "
                         "and the velocity representations world, mixed)")
    if name == "zyx":
        raise ChartError(f"chart 'zyx' (Euler angles of spherical and free joints) does not apply to model "
                         f"'{model.name}', which has none")
    if name == "exp":
        raise ChartError(f"chart 'exp' (exponential coordinates of spherical and free joints) does not apply to model "
                         f"'{model.name}', which has none")
    makers = {"identity": lambda: identity(model.n), "absolute": lambda: absolute(model),
              "affine": lambda: random_affine(model, seed, case), "nonlinear": lambda: nonlinear(model)}
    if name not in makers:
        raise ChartError(f"unknown chart '{name}'; valid charts: {', '.join(makers)}")
    return makers[name]()


def applies(model: Model) -> bool:
    """Whether the joint-coordinate charts apply: a chart ``q = psi(p)`` maps real coordinates to real coordinates,
    and a spherical or free joint's coordinates are a unit quaternion (a point of the group, not of R^4), so a model
    with one has none of these charts."""
    return not model.group_joints


def sampled(model: Model, seed: int, case: str) -> list[Chart]:
    """The charts the gate checks for a model: every built-in one but identity (the joint chart itself), with
    ``absolute`` only for a planar serial chain; for a model with spherical or free joints (:func:`applies`) the charts
    of their orientations, :data:`GROUP_CHARTS` (Euler angles and exponential coordinates), and the velocity
    representations (:func:`representations_sampled`)."""
    if not applies(model):
        return [get(name, model, seed, case) for name in GROUP_CHARTS] + representations_sampled(model)
    return [get(name, model, seed, case) for name in names() if name not in GROUP_CHARTS + REPRESENTATIONS
            if name != "identity" and (name != "absolute" or is_planar_serial(model))]


def velocity_to_chart(chart: Chart, p, qd) -> np.ndarray:
    """``pd = Dpsi^-1 qd``."""
    return np.linalg.solve(chart.jacobian(p), np.asarray(qd, dtype=float))


def acceleration_to_chart(chart: Chart, p, pd, qdd, with_rate: bool = True) -> np.ndarray:
    """``pdd = Dpsi^-1 (qdd - (d/dt Dpsi) pd)``; ``with_rate=False`` for a part of the acceleration that is
    linear in the input (the control contribution), which carries no velocity term."""
    qdd = np.asarray(qdd, dtype=float)
    if with_rate:
        qdd = qdd - chart.jacobian_rate(p, pd)
    return np.linalg.solve(chart.jacobian(p), qdd)


def force_to_chart(chart: Chart, p, tau_q) -> np.ndarray:
    """``tau_p = Dpsi^T tau_q``: a generalized force is a covector."""
    return chart.jacobian(p).T @ np.asarray(tau_q, dtype=float)


def force_from_chart(chart: Chart, p, tau_p) -> np.ndarray:
    """``tau_q = Dpsi^-T tau_p``."""
    return np.linalg.solve(chart.jacobian(p).T, np.asarray(tau_p, dtype=float))
