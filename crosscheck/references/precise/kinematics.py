"""The 50-digit reference's model data (every number of the model, decimal-exact in mpmath) and its kinematics:
each body's pose, velocity and classical acceleration by the recursion over the tree."""

from __future__ import annotations

import functools
from dataclasses import dataclass

import mpmath
import numpy as np
from mpmath import mpf

from cases.constraints import JointCoupling, KnifeEdge, PointOnLine, PointsCoincide, PointVelocity, RollingContact
from cases.loads import ExternalWrench, PointSpring
from cases.model import GROUP_JOINTS, JOINT_DOF, Model
from crosscheck.references.precise.algebra import ZERO3, add3, cross3, dot3, matmul3, matvec3, scale3, sub3, transpose3


#: The least precision :func:`split` accepts: well above double's 16 digits, so its answer is exact to double.
MIN_DIGITS = 40


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
    armature: mpf = mpf(0)   # the joint's rotor inertia, on each of its velocities' diagonal entries of M


@dataclass(frozen=True)
class Data:
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
    return scale3(1 / mpmath.sqrt(dot3(v, v)), v)


def _nearest_rotation(R) -> tuple:
    """The rotation nearest to ``R`` (its polar factor) by Newton's iteration ``R <- (R + R^-T) / 2``, which converges
    quadratically from a matrix orthogonal to rounding."""
    tol = mpf(2) ** (-mpmath.mp.prec)
    for _ in range(20):
        cof = tuple(cross3(R[(i + 1) % 3], R[(i + 2) % 3]) for i in range(3))   # rows of det(R) R^-T
        det = dot3(R[0], cof[0])
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
    moment = _vec(load.moment) if isinstance(load, ExternalWrench) else ZERO3
    return ("wrench", i, offset, _vec(load.force), moment, load.frame == "world")


@functools.lru_cache(maxsize=32)
def prepare(model: Model, prec: int) -> Data:
    """The model's data at binary precision ``prec`` (the mpmath context must be at that precision)."""
    bodies = tuple(_Body(int(model.parent_index[i]), b.joint == "revolute",
                         ZERO3 if b.joint in GROUP_JOINTS else _unit(b.axis), mpf(b.mass), _vec(b.com),
                         _mat(b.inertia), _nearest_rotation(_mat(b.rotation)), _vec(b.translation), b.joint,
                         mpf(b.armature))
                   for i, b in enumerate(model.bodies))
    cols = tuple(tuple(range(v, v + JOINT_DOF[b.joint][1])) for v, b in zip(model.v_index, model.bodies))
    return Data(bodies, tuple(model.topological_order), _vec(model.gravity), _mat(model.input_map),
                 tuple(_constraint_data(model, c) for c in model.constraints), tuple(model.q_index), cols,
                 tuple(_load_data(model, load) for load in model.loads))


def check_digits(digits) -> int:
    if not isinstance(digits, (int, np.integer)) or isinstance(digits, bool) or digits < MIN_DIGITS:
        raise ValueError(f"digits must be an integer of at least {MIN_DIGITS} (significant decimal digits of the "
                         f"reference), got {digits!r}")
    return int(digits)


# ----------------------------------------------------------------------------------------------- kinematics


@dataclass(frozen=True)
class Kin:
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
    K2 = matmul3(K, K)
    return tuple(tuple((1 if i == j else 0) + s * K[i][j] + (1 - c) * K2[i][j] for j in range(3)) for i in range(3))


def quaternion_rotation(x, y, z, w):
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
    R = matmul3(Rj, quaternion_rotation(*quat))
    axes = transpose3(R)                                    # the body's axes in the world: R e_k
    w_rel = matvec3(R, qd[vi + 3:vi + 6] if free else qd[vi:vi + 3])
    w = add3(w0, w_rel)
    alpha = add3(al0, cross3(w0, w_rel))                    # d/dt (R omega_b) = w x R omega_b = w0 x R omega_b
    p = add3(o, matvec3(Rj, q[qi:qi + 3])) if free else o
    r = sub3(p, p0)
    v = add3(v0, cross3(w0, r))
    acc = add3(add3(ac0, cross3(al0, r)), cross3(w0, cross3(w0, r)))
    if free:
        v_rel = matvec3(R, qd[vi:vi + 3])                   # R nu: the body-frame linear velocity in the world
        v = add3(v, v_rel)
        acc = add3(acc, cross3(add3(w0, w), v_rel))         # w0 x R nu + d/dt (R nu) at nudot = 0
        S = [(ZERO3, e) for e in axes] + [(e, cross3(p, e)) for e in axes]
    else:
        S = [(e, cross3(p, e)) for e in axes]
    return R, p, w, v, alpha, acc, S


def body_kinematics(data: Data, q, qd) -> Kin:
    """One pass parents first: ``X_body = X_parent * placement * motion(q_i)`` (``cases.model``), velocities and the
    accelerations at qdd = 0 (a prismatic joint adds its Coriolis term ``2 w_parent x a qd_i``; group joints:
    :func:`_group_joint`)."""
    n = len(data.bodies)
    kin = Kin(*([None] * n for _ in range(6)), [None] * len(qd), [None] * n)
    identity = ((mpf(1), 0, 0), (0, mpf(1), 0), (0, 0, mpf(1)))
    for i in data.order:
        b = data.bodies[i]
        if b.parent < 0:
            R0, p0, w0, v0, al0, ac0 = identity, ZERO3, ZERO3, ZERO3, ZERO3, ZERO3
        else:
            j = b.parent
            R0, p0, w0, v0, al0, ac0 = kin.R[j], kin.p[j], kin.w[j], kin.v[j], kin.alpha[j], kin.acc[j]
        Rj = matmul3(R0, b.rotation)                       # joint frame
        o = add3(p0, matvec3(R0, b.translation))           # joint origin
        if b.joint in GROUP_JOINTS:
            R, p, w, v, alpha, acc, S = _group_joint(b, q, qd, data.q_index[i], data.cols[i][0],
                                                     (R0, p0, w0, v0, al0, ac0), Rj, o)
            kin.R[i], kin.p[i], kin.w[i], kin.v[i], kin.alpha[i], kin.acc[i] = R, p, w, v, alpha, acc
            for c, twist in zip(data.cols[i], S):
                kin.S[c] = twist
            if any(x for row in b.inertia for x in row):
                kin.inertia[i] = matmul3(matmul3(R, b.inertia), transpose3(R))
            continue
        qi = data.cols[i][0]                                # the 1-DOF joint's velocity column
        a = matvec3(Rj, b.axis)                            # joint axis (world)
        if b.revolute:
            R, p = matmul3(Rj, _axis_rotation(b.axis, q[data.q_index[i]])), o
            w, alpha = add3(w0, scale3(qd[qi], a)), add3(al0, scale3(qd[qi], cross3(w0, a)))
            S = (a, cross3(o, a))
        else:
            R, p = Rj, add3(o, scale3(q[data.q_index[i]], a))
            w, alpha = w0, al0
            S = (ZERO3, a)
        r = sub3(p, p0)
        v = add3(v0, cross3(w0, r))
        acc = add3(add3(ac0, cross3(al0, r)), cross3(w0, cross3(w0, r)))
        if not b.revolute:
            v = add3(v, scale3(qd[qi], a))
            acc = add3(acc, scale3(2 * qd[qi], cross3(w0, a)))
        kin.R[i], kin.p[i], kin.w[i], kin.v[i], kin.alpha[i], kin.acc[i], kin.S[qi] = R, p, w, v, alpha, acc, S
        if any(x for row in b.inertia for x in row):
            kin.inertia[i] = matmul3(matmul3(R, b.inertia), transpose3(R))
    return kin


def ancestors(data: Data, i: int):
    """Body ``i`` and its ancestors up to the root."""
    while i >= 0:
        yield i
        i = data.bodies[i].parent
