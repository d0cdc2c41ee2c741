"""A high-precision reference: the exact split of a model's float data, in mpmath.

:func:`split` computes drift, ctrl, total (eq. 9, 10; eq. 12-17 with constraints) and the multipliers lam,
lam_drift with mpmath at ``digits`` significant digits (default :data:`DIGITS` = 50), so that every backend's true
error at a state can be measured against it. It is part of the harness, not a formalism: it never calls a backend or
Pinocchio, and is written from the model's definition (``cases.model``) in a classical, compact form:

* kinematics in the world frame per body, parents first: rotation R, origin p, joint axis a and origin o, angular
  velocity w, origin velocity v, and at ``qdd = 0`` the angular acceleration and the origin's classical acceleration;
  each velocity column's unit twist at the world origin (angular part, velocity of the point at the world origin),
  ``S = (a, o x a)`` (revolute) or ``(0, a)`` (prismatic); spherical and free joints below;
* ``M`` from composite bodies (CRBA): the momentum ``(L, P)`` of body i's subtree moving with ``S_c`` (c a column of
  body i) paired with ``S_d`` for each column d of i and of its ancestors, ``M_cd = a_d . L + v_d . P``;
* ``h = C qd + g`` by a recursive Newton–Euler pass at ``qdd = 0``: each body's ``m (a_com - gravity)`` and
  ``I alpha + w x I w``, summed over subtrees as wrenches about the world origin and paired with ``S_c``;
* each declaration's ``phi``, ``Jc`` and ``Jcdot qd`` row by row as ``cases.constraints`` defines them, from point
  Jacobians and the points' classical accelerations at ``qdd = 0`` (the rows, signs and scaling of every backend);
  a Pfaffian declaration's ``A`` and ``Adot qd`` (``phi`` 0) likewise, a rolling contact's from the material point at
  the contact plus the sliding of the contact over the disk (:func:`_pfaffian_rows`);
* the external loads (``cases.loads``) as world wrenches about the world origin (``x x f + m`` with ``x`` the load's
  point, body-frame vectors turned by R, a spring's force ``-k (|d| - L0) d / |d|``) subtracted from each body's own
  in the Newton–Euler pass: ``h`` is then ``C qd + g - tau_ext`` (so :func:`bias_forces` of a loaded model includes
  ``-tau_ext``), and the drift (eq. 14) carries them;
* the constrained solve by the range-space method: ``lam = S^+ (-Jcdot qd - Jc M^-1 f)``, ``qdd = M^-1 (f + Jc^T
  lam)`` with ``S = Jc M^-1 Jc^T``, eigenvalues of S at or below ``crosscheck.guards.conditioning.redundant_below`` dropped
  (the minimum-norm multipliers, the backends' rule); ``f = B u - h`` for total and lam, ``-h`` for drift and
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

import functools
from dataclasses import dataclass
from typing import Callable

import mpmath
import numpy as np
from mpmath import mpf

from cases.constraints import JointCoupling, KnifeEdge, PointOnLine, PointsCoincide, PointVelocity, RollingContact
from cases.loads import ExternalWrench, PointSpring
from cases.model import GROUP_JOINTS, JOINT_DOF, Model
from crosscheck.checks.charts import EulerZYX
from crosscheck.guards.conditioning import redundant_below
from formalisms.interface import check_state, Linearization, state_space

#: Default working precision (significant decimal digits).
DIGITS = 50
#: The least precision :func:`split` accepts: well above double's 16 digits, so its answer is exact to double.
MIN_DIGITS = 40

_ZERO3 = (mpf(0), mpf(0), mpf(0))


# ----------------------------------------------------------------------------------------------- 3-vector algebra


def _add(a, b):
    return (a[0] + b[0], a[1] + b[1], a[2] + b[2])


def _sub(a, b):
    return (a[0] - b[0], a[1] - b[1], a[2] - b[2])


def _scale(s, a):
    return (s * a[0], s * a[1], s * a[2])


def _dot(a, b):
    return mpmath.fdot(a, b)


def _cross(a, b):
    return (a[1] * b[2] - a[2] * b[1], a[2] * b[0] - a[0] * b[2], a[0] * b[1] - a[1] * b[0])


def _matvec(A, x):
    return tuple(_dot(row, x) for row in A)


def _matmul(A, B):
    cols = tuple(zip(*B))
    return tuple(tuple(_dot(row, col) for col in cols) for row in A)


def _transpose(A):
    return tuple(zip(*A))


# ----------------------------------------------------------------------------------------------- model data


@dataclass(frozen=True)
class _Body:
    """One body's data as mpf (``cases.model.Body``); parent -1 is the world."""

    parent: int
    revolute: bool
    axis: tuple       # unit (revolute, prismatic); zero for a group joint, which has none
    mass: mpf
    com: tuple
    inertia: tuple
    rotation: tuple
    translation: tuple
    joint: str        # cases.model joint type (spherical and free: group joints)


@dataclass(frozen=True)
class _Data:
    """The model's numbers as mpf (axes unit and placements rotations exactly: module doc)."""

    bodies: tuple
    order: tuple
    gravity: tuple
    B: tuple
    rows: tuple       # per declaration, its numbers as mpf (see _constraint_data)
    q_index: tuple    # where body i's block of q starts
    cols: tuple       # body i's velocity columns (indices into v, M's rows): range(v_index[i], v_index[i] + nv_i)
    loads: tuple = ()  # per external load, its numbers as mpf (see _load_data)


def _vec(x) -> tuple:
    return tuple(mpf(float(v)) for v in np.asarray(x, dtype=float).reshape(-1))


def _mat(A) -> tuple:
    return tuple(_vec(row) for row in np.atleast_2d(np.asarray(A, dtype=float)))


def _unit(x) -> tuple:
    v = _vec(x)
    return _scale(1 / mpmath.sqrt(_dot(v, v)), v)


def _nearest_rotation(R) -> tuple:
    """The rotation nearest to ``R`` (its polar factor) by Newton's iteration ``R <- (R + R^-T) / 2``, which converges
    quadratically from a matrix orthogonal to rounding."""
    tol = mpf(2) ** (-mpmath.mp.prec)
    for _ in range(20):
        cof = tuple(_cross(R[(i + 1) % 3], R[(i + 2) % 3]) for i in range(3))   # rows of det(R) R^-T
        det = _dot(R[0], cof[0])
        new = tuple(tuple((R[i][j] + cof[i][j] / det) / 2 for j in range(3)) for i in range(3))
        change = max(abs(new[i][j] - R[i][j]) for i in range(3) for j in range(3))
        R = new
        if change <= tol:
            break
    return R


def _constraint_data(model: Model, c) -> tuple:
    """A declaration's kind, bodies (by index) and numbers as mpf; the fourth kind is PointOnCircle."""
    if isinstance(c, JointCoupling):
        return ("coupling", tuple(model.body_index(j) for j in c.joints), _vec(c.coefficients), mpf(c.offset))
    if isinstance(c, PointsCoincide):
        b = None if c.body_b is None else model.body_index(c.body_b)
        return ("coincide", (model.body_index(c.body_a), _vec(c.offset_a)), (b, _vec(c.offset_b)), _mat(c.directions))
    if isinstance(c, PointOnLine):
        return ("line", (model.body_index(c.body), _vec(c.offset)), _vec(c.origin), _mat(c.normals))
    if isinstance(c, PointVelocity):
        return ("velocity", (model.body_index(c.body), _vec(c.offset)), _mat(c.directions))
    if isinstance(c, KnifeEdge):
        return ("knife", (model.body_index(c.body), _vec(c.offset)), _vec(c.direction))
    if isinstance(c, RollingContact):
        return ("rolling", (model.body_index(c.body), _vec(c.center)), _vec(c.axis), mpf(c.radius), _mat(c.plane),
                bool(c.lateral))
    return ("circle", (model.body_index(c.body), _vec(c.offset)), _vec(c.center), mpf(c.radius),
            _mat(c.plane))


def _load_data(model: Model, load) -> tuple:
    """An external load's kind, body (index), offset and numbers as mpf: ``("spring", i, offset, anchor, k, L0)`` or
    ``(kind, i, offset, force, moment, in_world)`` (moment zero for a force)."""
    i, offset = model.body_index(load.body), _vec(load.offset)
    if isinstance(load, PointSpring):
        return ("spring", i, offset, _vec(load.anchor), mpf(load.stiffness), mpf(load.rest_length))
    moment = _vec(load.moment) if isinstance(load, ExternalWrench) else _ZERO3
    return ("wrench", i, offset, _vec(load.force), moment, load.frame == "world")


@functools.lru_cache(maxsize=32)
def _prepare(model: Model, prec: int) -> _Data:
    """The model's data at binary precision ``prec`` (the mpmath context must be at that precision)."""
    bodies = tuple(_Body(int(model.parent_index[i]), b.joint == "revolute",
                         _ZERO3 if b.joint in GROUP_JOINTS else _unit(b.axis), mpf(b.mass), _vec(b.com),
                         _mat(b.inertia), _nearest_rotation(_mat(b.rotation)), _vec(b.translation), b.joint)
                   for i, b in enumerate(model.bodies))
    cols = tuple(tuple(range(v, v + JOINT_DOF[b.joint][1])) for v, b in zip(model.v_index, model.bodies))
    return _Data(bodies, tuple(model.topological_order), _vec(model.gravity), _mat(model.input_map),
                 tuple(_constraint_data(model, c) for c in model.constraints), tuple(model.q_index), cols,
                 tuple(_load_data(model, load) for load in model.loads))


def _check_digits(digits) -> int:
    if not isinstance(digits, (int, np.integer)) or isinstance(digits, bool) or digits < MIN_DIGITS:
        raise ValueError(f"digits must be an integer of at least {MIN_DIGITS} (significant decimal digits of the "
                         f"reference), got {digits!r}")
    return int(digits)


# ----------------------------------------------------------------------------------------------- kinematics


@dataclass(frozen=True)
class _Kin:
    """World-frame kinematics of every body at (q, qd) and qdd = 0 (lists indexed by body, ``S`` by velocity
    column)."""

    R: list
    p: list        # body origin
    w: list        # angular velocity
    v: list        # origin velocity
    alpha: list    # angular acceleration at qdd = 0
    acc: list      # origin classical acceleration at qdd = 0
    S: list        # each velocity column's unit twist at the world origin: (angular, linear)
    inertia: list  # COM inertia in the world frame, R I R^T (None for a point mass)


def _axis_rotation(a, angle):
    """Rodrigues: the rotation by ``angle`` about the unit vector ``a``."""
    s, c = mpmath.sin(angle), mpmath.cos(angle)
    K = ((0, -a[2], a[1]), (a[2], 0, -a[0]), (-a[1], a[0], 0))
    K2 = _matmul(K, K)
    return tuple(tuple((1 if i == j else 0) + s * K[i][j] + (1 - c) * K2[i][j] for j in range(3)) for i in range(3))


def _quaternion_rotation(x, y, z, w):
    """``R = I + 2 w [u]x + 2 [u]x^2`` of the quaternion ``(u, w) = (x, y, z, w)`` normalized first (module doc)."""
    s = 1 / mpmath.sqrt(mpmath.fsum((x * x, y * y, z * z, w * w)))
    x, y, z, w = x * s, y * s, z * s, w * s
    return ((1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y)),
            (2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x)),
            (2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)))


def _group_joint(b: _Body, q, qd, qi: int, vi: int, parent: tuple, Rj, o) -> tuple:
    """``(R, p, w, v, alpha, acc, S)`` of a body on a spherical or free joint (module doc, group joints): ``parent``
    is ``(R0, p0, w0, v0, alpha0, acc0)``, ``Rj``, ``o`` the joint frame's rotation and origin."""
    R0, p0, w0, v0, al0, ac0 = parent
    free = b.joint == "free"
    quat = q[qi + 3:qi + 7] if free else q[qi:qi + 4]
    R = _matmul(Rj, _quaternion_rotation(*quat))
    axes = _transpose(R)                                    # the body's axes in the world: R e_k
    w_rel = _matvec(R, qd[vi + 3:vi + 6] if free else qd[vi:vi + 3])
    w = _add(w0, w_rel)
    alpha = _add(al0, _cross(w0, w_rel))                    # d/dt (R omega_b) = w x R omega_b = w0 x R omega_b
    p = _add(o, _matvec(Rj, q[qi:qi + 3])) if free else o
    r = _sub(p, p0)
    v = _add(v0, _cross(w0, r))
    acc = _add(_add(ac0, _cross(al0, r)), _cross(w0, _cross(w0, r)))
    if free:
        v_rel = _matvec(R, qd[vi:vi + 3])                   # R nu: the body-frame linear velocity in the world
        v = _add(v, v_rel)
        acc = _add(acc, _cross(_add(w0, w), v_rel))         # w0 x R nu + d/dt (R nu) at nudot = 0
        S = [(_ZERO3, e) for e in axes] + [(e, _cross(p, e)) for e in axes]
    else:
        S = [(e, _cross(p, e)) for e in axes]
    return R, p, w, v, alpha, acc, S


def _kinematics(data: _Data, q, qd) -> _Kin:
    """One pass parents first: ``X_body = X_parent * placement * motion(q_i)`` (``cases.model``), velocities and the
    accelerations at qdd = 0 (a prismatic joint adds its Coriolis term ``2 w_parent x a qd_i``; group joints:
    :func:`_group_joint`)."""
    n = len(data.bodies)
    kin = _Kin(*([None] * n for _ in range(6)), [None] * len(qd), [None] * n)
    identity = ((mpf(1), 0, 0), (0, mpf(1), 0), (0, 0, mpf(1)))
    for i in data.order:
        b = data.bodies[i]
        if b.parent < 0:
            R0, p0, w0, v0, al0, ac0 = identity, _ZERO3, _ZERO3, _ZERO3, _ZERO3, _ZERO3
        else:
            j = b.parent
            R0, p0, w0, v0, al0, ac0 = kin.R[j], kin.p[j], kin.w[j], kin.v[j], kin.alpha[j], kin.acc[j]
        Rj = _matmul(R0, b.rotation)                       # joint frame
        o = _add(p0, _matvec(R0, b.translation))           # joint origin
        if b.joint in GROUP_JOINTS:
            R, p, w, v, alpha, acc, S = _group_joint(b, q, qd, data.q_index[i], data.cols[i][0],
                                                     (R0, p0, w0, v0, al0, ac0), Rj, o)
            kin.R[i], kin.p[i], kin.w[i], kin.v[i], kin.alpha[i], kin.acc[i] = R, p, w, v, alpha, acc
            for c, twist in zip(data.cols[i], S):
                kin.S[c] = twist
            if any(x for row in b.inertia for x in row):
                kin.inertia[i] = _matmul(_matmul(R, b.inertia), _transpose(R))
            continue
        qi = data.cols[i][0]                                # the 1-DOF joint's velocity column
        a = _matvec(Rj, b.axis)                            # joint axis (world)
        if b.revolute:
            R, p = _matmul(Rj, _axis_rotation(b.axis, q[data.q_index[i]])), o
            w, alpha = _add(w0, _scale(qd[qi], a)), _add(al0, _scale(qd[qi], _cross(w0, a)))
            S = (a, _cross(o, a))
        else:
            R, p = Rj, _add(o, _scale(q[data.q_index[i]], a))
            w, alpha = w0, al0
            S = (_ZERO3, a)
        r = _sub(p, p0)
        v = _add(v0, _cross(w0, r))
        acc = _add(_add(ac0, _cross(al0, r)), _cross(w0, _cross(w0, r)))
        if not b.revolute:
            v = _add(v, _scale(qd[qi], a))
            acc = _add(acc, _scale(2 * qd[qi], _cross(w0, a)))
        kin.R[i], kin.p[i], kin.w[i], kin.v[i], kin.alpha[i], kin.acc[i], kin.S[qi] = R, p, w, v, alpha, acc, S
        if any(x for row in b.inertia for x in row):
            kin.inertia[i] = _matmul(_matmul(R, b.inertia), _transpose(R))
    return kin


def _ancestors(data: _Data, i: int):
    """Body ``i`` and its ancestors up to the root."""
    while i >= 0:
        yield i
        i = data.bodies[i].parent


# ----------------------------------------------------------------------------------------------- M and h


def _mass_matrix(data: _Data, kin: _Kin) -> list:
    """CRBA: composite mass, first moment h = sum m c and inertia about the world origin per subtree; then
    ``M_ij = a_j . L + v_j . P`` with ``(L, P) = (I_o a_i + h x v_i, m v_i + a_i x h)`` the subtree's momentum at
    unit rate of velocity column i (``S_i = (a_i, v_i)``), for every column j of the body or of its ancestors."""
    n = len(data.bodies)
    mass, first, second = [None] * n, [None] * n, [None] * n
    for i, b in enumerate(data.bodies):
        c = _add(kin.p[i], _matvec(kin.R[i], b.com))
        cc = _dot(c, c)
        mass[i], first[i] = b.mass, _scale(b.mass, c)
        second[i] = tuple(tuple(b.mass * ((cc if r == s else 0) - c[r] * c[s]) for s in range(3)) for r in range(3))
        if kin.inertia[i] is not None:
            second[i] = tuple(_add(row, own) for row, own in zip(second[i], kin.inertia[i]))
    for i in reversed(data.order):
        j = data.bodies[i].parent
        if j >= 0:
            mass[j], first[j] = mass[j] + mass[i], _add(first[j], first[i])
            second[j] = tuple(_add(second[j][r], second[i][r]) for r in range(3))
    nv = len(kin.S)
    M = [[mpf(0)] * nv for _ in range(nv)]
    for i in range(n):
        for ci in data.cols[i]:
            wi, vi = kin.S[ci]
            L = _add(_matvec(second[i], wi), _cross(first[i], vi))
            P = _add(_scale(mass[i], vi), _cross(wi, first[i]))
            for j in _ancestors(data, i):
                for cj in data.cols[j]:
                    wj, vj = kin.S[cj]
                    M[ci][cj] = M[cj][ci] = _dot(wj, L) + _dot(vj, P)
    return M


def _bias(data: _Data, kin: _Kin) -> list:
    """``h = C qd + g``: Newton–Euler at qdd = 0, each body's wrench about the world origin summed over subtrees and
    paired with each of the body's velocity columns."""
    n = len(data.bodies)
    force, moment = [None] * n, [None] * n
    for i, b in enumerate(data.bodies):
        r = _matvec(kin.R[i], b.com)
        w = kin.w[i]
        a_com = _add(_add(kin.acc[i], _cross(kin.alpha[i], r)), _cross(w, _cross(w, r)))
        f = _scale(b.mass, _sub(a_com, data.gravity))
        moment[i], force[i] = _cross(_add(kin.p[i], r), f), f
        Iw = kin.inertia[i]
        if Iw is not None:
            moment[i] = _add(moment[i], _add(_matvec(Iw, kin.alpha[i]), _cross(w, _matvec(Iw, w))))
    for i, f, m in _external_wrenches(data, kin):         # the external loads act on the bodies: h - tau_ext
        force[i], moment[i] = _sub(force[i], f), _sub(moment[i], m)
    for i in reversed(data.order):
        j = data.bodies[i].parent
        if j >= 0:
            force[j], moment[j] = _add(force[j], force[i]), _add(moment[j], moment[i])
    return [_dot(kin.S[c][0], moment[i]) + _dot(kin.S[c][1], force[i]) for i in range(n) for c in data.cols[i]]


def _external_wrenches(data: _Data, kin: _Kin) -> list:
    """``(body, force, moment about the world origin)`` of each external load in the world frame (module doc)."""
    out = []
    for kind, i, offset, *numbers in data.loads:
        R = kin.R[i]
        x = _add(kin.p[i], _matvec(R, offset))
        couple = _ZERO3
        if kind == "spring":
            anchor, k, rest = numbers
            d = _sub(x, anchor)
            f = _scale(-k * (1 - rest / mpmath.sqrt(_dot(d, d))) if rest else -k, d)
        else:
            force, moment, in_world = numbers
            f, couple = (force, moment) if in_world else (_matvec(R, force), _matvec(R, moment))
        out.append((i, f, _add(_cross(x, f), couple)))
    return out


# ----------------------------------------------------------------------------------------------- constraints


def _point(data: _Data, kin: _Kin, n: int, body, offset):
    """World position, velocity, linear Jacobian (3 rows of nv) and classical acceleration at qdd = 0 of the point
    ``offset`` of ``body``; a world point (body None) is fixed."""
    zero = [mpf(0)] * n
    if body is None:
        return offset, _ZERO3, [list(zero) for _ in range(3)], _ZERO3
    r = _matvec(kin.R[body], offset)
    x = _add(kin.p[body], r)
    w = kin.w[body]
    vel = _add(kin.v[body], _cross(w, r))
    acc = _add(_add(kin.acc[body], _cross(kin.alpha[body], r)), _cross(w, _cross(w, r)))
    J = [list(zero) for _ in range(3)]
    for j in _ancestors(data, body):
        for c in data.cols[j]:
            col = _add(kin.S[c][1], _cross(kin.S[c][0], x))
            for r_ in range(3):
                J[r_][c] = col[r_]
    return x, vel, J, acc


def _project(D, x):
    return [_dot(row, x) for row in D]


def _project_jacobian(D, J):
    return [[_dot(row, col) for col in zip(*J)] for row in D]


def _rows(data: _Data, kin: _Kin, q, decl):
    """phi, Jc and Jcdot qd of one declaration (the formulas of ``cases.constraints``; a coupling joins 1-DOF joints,
    whose velocity is their coordinate's rate)."""
    n = len(kin.S)
    kind = decl[0]
    if kind == "coupling":
        _, joints, coefficients, offset = decl
        row, row_q = [mpf(0)] * n, [mpf(0)] * len(q)
        for j, c in zip(joints, coefficients):
            row[data.cols[j][0]] += c
            row_q[data.q_index[j]] += c
        return [mpmath.fdot(row_q, q) - offset], [row], [mpf(0)]
    if kind == "coincide":
        _, a, b, D = decl
        xa, _, Ja, aa = _point(data, kin, n, *a)
        xb, _, Jb, ab = _point(data, kin, n, *b)
        dJ = [[s - t for s, t in zip(ra, rb)] for ra, rb in zip(Ja, Jb)]
        return _project(D, _sub(xa, xb)), _project_jacobian(D, dJ), _project(D, _sub(aa, ab))
    if kind in PFAFFIAN_KINDS:
        return _pfaffian_rows(data, kin, decl)
    x, vel, J, acc = _point(data, kin, n, *decl[1])
    if kind == "line":
        _, _, origin, N = decl
        return _project(N, _sub(x, origin)), _project_jacobian(N, J), _project(N, acc)
    _, _, center, radius, P = decl
    d = _project(P, _sub(x, center))
    PJ, Pv, Pa = _project_jacobian(P, J), _project(P, vel), _project(P, acc)
    row = [2 * (d[0] * PJ[0][k] + d[1] * PJ[1][k]) for k in range(n)]
    return ([d[0] ** 2 + d[1] ** 2 - radius ** 2], [row],
            [2 * (Pv[0] ** 2 + Pv[1] ** 2) + 2 * (d[0] * Pa[0] + d[1] * Pa[1])])


#: The declaration kinds of :func:`_constraint_data` that are Pfaffian (velocity rows, phi reported 0).
PFAFFIAN_KINDS = ("velocity", "knife", "rolling")


def _pfaffian_rows(data: _Data, kin: _Kin, decl):
    """phi (0), A and Adot qd of a Pfaffian declaration (``cases.constraints``) from :func:`_point`: a point's
    ``D J``, ``D acc``; a knife edge's ``e = R d`` with ``(w x e) . vel + e . acc``; a rolling contact's material point
    at ``p_c = c - r u`` (its body-frame offset ``center + R^T e``, ``e = -r u``) with ``Adot qd = T (acc + w x (edot -
    w x e))``, ``edot = -r udot``, ``udot = (I - u u^T) rawdot / |raw|``, ``raw = n - (n.a) a``, ``adot = w x a``;
    with ``lateral=False`` the one row along ``t = b / |b|``, ``b = a x n``: ``A = t^T J``, ``Adot qd = t . (acc + w x
    (edot - w x e)) + tdot . vel``, ``tdot = (bdot - t (t.bdot)) / |b|``, ``bdot = adot x n``."""
    n = len(kin.S)
    kind, (body, offset) = decl[0], decl[1]
    if kind == "velocity":
        _, J, acc = _point(data, kin, n, body, offset)[1:]
        return [mpf(0)] * len(decl[2]), _project_jacobian(decl[2], J), _project(decl[2], acc)
    R, w = kin.R[body], kin.w[body]
    if kind == "knife":
        _, vel, J, acc = _point(data, kin, n, body, offset)
        e = _matvec(R, decl[2])
        return [mpf(0)], [_project_jacobian((e,), J)[0]], [_dot(_cross(w, e), vel) + _dot(e, acc)]
    _, _, axis, radius, T, lateral = decl
    normal = _cross(T[0], T[1])
    a = _matvec(R, axis)
    raw = _sub(normal, _scale(_dot(normal, a), a))
    length = mpmath.sqrt(_dot(raw, raw))
    u = _scale(1 / length, raw)
    e = _scale(-radius, u)
    a_dot = _cross(w, a)
    raw_dot = _sub(_scale(-_dot(normal, a_dot), a), _scale(_dot(normal, a), a_dot))
    e_dot = _scale(-radius / length, _sub(raw_dot, _scale(_dot(u, raw_dot), u)))
    _, vel, J, acc = _point(data, kin, n, body, _add(offset, _matvec(_transpose(R), e)))
    rate = _add(acc, _cross(w, _sub(e_dot, _cross(w, e))))
    if not lateral:     # the rolling direction t = b / |b|, b = a x n, alone: t . rate + tdot . vel
        b = _cross(a, normal)
        size = mpmath.sqrt(_dot(b, b))
        t = _scale(1 / size, b)
        b_dot = _cross(a_dot, normal)
        t_dot = _scale(1 / size, _sub(b_dot, _scale(_dot(t, b_dot), t)))
        return [mpf(0)], [_project_jacobian((t,), J)[0]], [_dot(t, rate) + _dot(t_dot, vel)]
    return [mpf(0), mpf(0)], _project_jacobian(T, J), _project(T, rate)


def _constraint_terms(data: _Data, kin: _Kin, q):
    phi, Jc, bias = [], [], []
    for decl in data.rows:
        p, J, b = _rows(data, kin, q, decl)
        phi += p
        Jc += J
        bias += b
    return phi, Jc, bias


# ----------------------------------------------------------------------------------------------- linear algebra


def _cholesky(model: Model, M, q) -> list:
    L = _cholesky_factor(M)
    if L is None:
        raise ValueError(f"model '{model.name}': the mass matrix is not positive definite at q = {list(q)} "
                         "(multiprecision Cholesky failed)")
    return L


def _cholesky_factor(M) -> list | None:
    """The lower Cholesky factor of the symmetric matrix M (lists of mpf), None when M is not positive definite."""
    n = len(M)
    L = [[mpf(0)] * n for _ in range(n)]
    for j in range(n):
        d = M[j][j] - mpmath.fdot(L[j][:j], L[j][:j])
        if d <= 0:
            return None
        L[j][j] = mpmath.sqrt(d)
        for i in range(j + 1, n):
            L[i][j] = (M[i][j] - mpmath.fdot(L[i][:j], L[j][:j])) / L[j][j]
    return L


def _cho_solve(L, b) -> list:
    n = len(L)
    y = [mpf(0)] * n
    for i in range(n):
        y[i] = (b[i] - mpmath.fdot(L[i][:i], y[:i])) / L[i][i]
    x = [mpf(0)] * n
    for i in reversed(range(n)):
        x[i] = (y[i] - mpmath.fdot([L[k][i] for k in range(i + 1, n)], x[i + 1:])) / L[i][i]
    return x


def _matvec_n(A, x) -> list:
    return [mpmath.fdot(row, x) for row in A]


#: A float eigenvalue of S this much (times the largest) above the redundancy floor is above it in exact arithmetic
#: too: rounding S to floats moves its eigenvalues by at most ``k eps max|S_ij|``, below 1e-14 of the largest.
_CLEAR_OF_FLOOR = 1e-12


def _pseudo_solver(model: Model, S) -> Callable[[list], list]:
    """``r -> S^+ r`` for the symmetric k x k S (lists of mpf), eigenvalues at or below ``redundant_below`` dropped
    (the backends' rank rule). When every eigenvalue of S rounded to floats is clear of the floor
    (:data:`_CLEAR_OF_FLOOR`), none is dropped in exact arithmetic either and ``S^+ = S^-1`` by Cholesky; otherwise
    the multiprecision eigendecomposition decides, eigenvalue by eigenvalue (many times the cost)."""
    k = len(S)
    w = np.linalg.eigvalsh(np.array([[float(x) for x in row] for row in S]))
    if np.all(np.isfinite(w)) and w[0] - redundant_below(model, w[-1]) > _CLEAR_OF_FLOOR * abs(w[-1]):
        L = _cholesky_factor(S)
        if L is not None:
            return functools.partial(_cho_solve, L)
    w, U = mpmath.eigsy(mpmath.matrix(S))
    floor = redundant_below(model, float(max(w[i] for i in range(k))))
    kept = [i for i in range(k) if w[i] > floor]
    pinv = [[sum((U[r, i] * U[c, i] / w[i] for i in kept), mpf(0)) for c in range(k)] for r in range(k)]
    return functools.partial(_matvec_n, pinv)


class _RangeSpace:
    """``X = M^-1 Jc^T`` and ``r -> S^+ r`` (S = Jc X, eigenvalues at or below ``redundant_below`` dropped)."""

    def __init__(self, model: Model, L, Jc, bias):
        self.L, self.Jc, self.bias = L, Jc, bias
        cols = [_cho_solve(L, row) for row in Jc]                  # columns of X
        self.X = [list(r) for r in zip(*cols)]
        k = len(Jc)
        S = [[mpf(0)] * k for _ in range(k)]
        for r in range(k):
            for s in range(r, k):
                S[r][s] = S[s][r] = mpmath.fdot(Jc[r], cols[s])
        self.S_solve = _pseudo_solver(model, S)

    def solve(self, f) -> tuple[list, list]:
        """``(qdd, lam)`` of eq. (12, 13) for the generalized force ``f``."""
        a = _cho_solve(self.L, f)
        r = [-b - jc for b, jc in zip(self.bias, _matvec_n(self.Jc, a))]
        lam = self.S_solve(r)
        return [x + y for x, y in zip(a, _matvec_n(self.X, lam))], lam

    def input_map(self, tau) -> list:
        """``B_c tau`` of eq. (17): ``M^-1 tau - X S^+ Jc M^-1 tau``."""
        a = _cho_solve(self.L, tau)
        corr = _matvec_n(self.X, self.S_solve(_matvec_n(self.Jc, a)))
        return [x - y for x, y in zip(a, corr)]


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
    data = _prepare(model, mpmath.mp.prec)
    kin = _kinematics(data, q, qd)
    return data, kin, _mass_matrix(data, kin), _bias(data, kin)


def split(model: Model, q, qd, u, digits: int = DIGITS) -> PreciseSplit:
    """The split of eq. (9) (eq. 12-17 with constraints) at ``(q, qd, u)``, exact for the float inputs to ``digits``
    significant digits (module doc). ``ctrl = B_c B u`` is computed directly, not as total - drift."""
    digits = _check_digits(digits)
    with mpmath.workdps(digits):
        q, qd, u = _state(model, q, qd, u)
        return _split(model, q, qd, _matvec_n(_prepare(model, mpmath.mp.prec).B, u), digits)


def _split(model: Model, q, qd, tau, digits: int) -> PreciseSplit:
    """:func:`split` at mpf ``q``, ``qd`` and the generalized input force ``tau = B u`` (inside ``workdps``)."""
    data, kin, M, h = _terms(model, q, qd)
    L = _cholesky(model, M, q)
    force = [t - x for t, x in zip(tau, h)]
    if not data.rows:
        out = _cho_solve(L, [-x for x in h]), _cho_solve(L, tau), _cho_solve(L, force), None, None
    else:
        _, Jc, bias = _constraint_terms(data, kin, q)
        rs = _RangeSpace(model, L, Jc, bias)
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
    R = _quaternion_rotation(*quat)
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
            RT = _transpose(_quaternion_rotation(*chart._quaternion(p[a], p[a + 1], p[a + 2], sin, cos)))
            for r in range(3):
                for c in range(3):
                    D[k + r][k + c] = RT[r][c]
            w = _matvec(E, a_rates)
            lin = _cross(w, _matvec(RT, pd[k:k + 3]))
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
    digits = _check_digits(digits)
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
        exact = _split(model, q, qd, _matvec_n(_prepare(model, mpmath.mp.prec).B, u), digits)
        return _in_chart(model, chart, p, pd, exact, digits)


def chart_split_at(model: Model, chart, p, pd, tau_p, digits: int = DIGITS) -> PreciseChartSplit:
    """The exact split at the chart point ``(p, pd)`` with the chart's generalized force ``tau_p`` (floats taken
    exactly): what a chart-native evaluation (``Formalism.split_chart``) with these inputs should return.
    ``q = psi(p)`` and ``v = Dpsi pd`` in mpmath (the quaternions unit to the working precision), ``B u = Dpsi^-T
    tau_p``."""
    digits = _check_digits(digits)
    _check_chart(chart)
    with mpmath.workdps(digits):
        p, pd, tau_p = ([mpf(float(x)) for x in np.asarray(v, dtype=float)] for v in (p, pd, tau_p))
        D, _ = _zyx_terms(chart, p, pd)
        q = list(chart.psi(p, *_mp_trig()))
        qd = _matvec_n(D, pd)
        tau = list(mpmath.lu_solve(mpmath.matrix(D).T, mpmath.matrix(tau_p)))
        return _in_chart(model, chart, p, pd, _split(model, q, qd, tau, digits), digits)


def mass_matrix(model: Model, q, digits: int = DIGITS) -> mpmath.matrix:
    """``M(q)`` (nv x nv) to ``digits`` significant digits, e.g. for exact condition numbers."""
    digits = _check_digits(digits)
    with mpmath.workdps(digits):
        q, qd, _ = _state(model, q, np.zeros(model.n), np.zeros(model.m))
        _, _, M, _ = _terms(model, q, qd)
        return mpmath.matrix(M)


def bias_forces(model: Model, q, qd, digits: int = DIGITS) -> tuple:
    """``h = C(q, qd) qd + g(q)`` (nv mpf) to ``digits`` significant digits (article eq. 7, 8 for the double
    pendulum)."""
    digits = _check_digits(digits)
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
    wv = _cross(w, v)
    return _add(_add(v, _scale(a, wv)), _scale(b, _cross(w, wv)))


def _integrate(model: Model, q, dq) -> list:
    """``q (+) dq`` (``cases.configuration.integrate``) in mpmath: each group joint moved by ``exp(dq)`` on the right."""
    out = list(q)
    for i, b in enumerate(model.bodies):
        iq, iv = model.q_index[i], model.v_index[i]
        if b.joint == "spherical":
            out[iq:iq + 4] = _quaternion_product(q[iq:iq + 4], _quaternion_exp(dq[iv:iv + 3]))
        elif b.joint == "free":
            quat = q[iq + 3:iq + 7]
            shift = _matvec(_quaternion_rotation(*quat), _se3_translation(dq[iv + 3:iv + 6], dq[iv:iv + 3]))
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
    digits = _check_digits(digits)
    qd_float = check_state(model, q, qd, u)[1]
    with mpmath.workdps(digits):
        q, qd, u = _state(model, q, qd, u)
        B = _prepare(model, mpmath.mp.prec).B
        tau = _matvec_n(B, u)
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


__all__ = ["DIGITS", "MIN_DIGITS", "PreciseChartSplit", "PreciseSplit", "bias_forces", "chart_split", "chart_split_at",
           "linearize", "mass_matrix", "relative_error", "split"]
