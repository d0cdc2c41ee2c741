"""Constraint declarations in model terms (article 5.1; docs/design.md, constraints).

A declaration says what is constrained, in the words of the scene (a point of a body on a circle, two points
that coincide, a point on a line, a gear between two joints). It does not say how to compute ``phi``: every
formalism derives ``phi(q)``, ``Jc = dphi/dq`` and ``Jcdot qd`` with its own kinematics. The functions ``phi``
below are fixed exactly, row by row, so that the multipliers ``lam`` of eq. (12),
``M qdd + h = B u + Jc^T lam``, mean the same number in every backend and in other tools.

``p(body, offset)`` is the world position of the point ``offset`` (body frame) of ``body``; world-fixed data
(centres, origins, directions) are world-frame vectors. Direction sets are orthonormal rows (k x 3).

=================  ==========================================================  ====
declaration        phi (rows)                                                  rows
=================  ==========================================================  ====
PointOnCircle      ``|P (p - c)|^2 - R^2`` (article 5.6 with P the x-y plane)   1
PointsCoincide     ``D (p_a - p_b)``; ``body_b = None`` pins to the world      k
PointOnLine        ``N (p - origin)``; N spans the directions the point may    k
                   not move in (one in-plane normal for a planar slider, two
                   for a line in space)
JointCoupling      ``sum_j c_j q_j - offset`` (a gear: ``q_a - r q_b``)          1
=================  ==========================================================  ====

Pfaffian declarations (article 1.5, 5.1: ``A(q) qd = 0`` with no ``phi``; non-holonomic in general). Their rows
are velocity rows ``a(q, qd) = A(q) qd`` fixed exactly as below; each backend derives ``A = da/dqd`` and the bias
``Adot qd = d/dt a`` at ``qdd = 0`` itself, so that ``A qdd + Adot qd = 0`` along a motion (eq. 13 with ``A`` for
``Jc``). They have no position-level function: a backend reports ``phi = 0`` for their rows
(``Split.constraint_value``), and the harness projects configurations onto the holonomic rows only
(:attr:`cases.model.Model.pfaffian_rows`). ``v(body, offset)`` is the world velocity of the material point
``offset`` of ``body``; ``R`` the body's world rotation, ``w`` its world angular velocity.

=================  ==========================================================  ====
declaration        rows ``A(q) qd``                                            rows
=================  ==========================================================  ====
PointVelocity      ``D v(body, offset)``: the point has no velocity along the    k
                   world-fixed rows of D (1 to 3)
KnifeEdge          ``(R d) . v(body, offset)``: no velocity across the           1
                   body-fixed direction d (a blade, a sleigh's runner)
RollingContact     ``T (v_c + w x (p_c - c))``, ``c = p(body, center)``: the     2
                   material point at the contact ``p_c = c - r u`` has no
                   velocity along the plane's two tangent rows T (rolling
                   without slipping); ``u`` the unit vector in the disk plane
                   (normal ``R axis``) away from the ground plane
                   (normal ``n = T_0 x T_1``): ``u = (n - (n.a) a) / |..|``,
                   ``a = R axis``
RollingContact     ``t . (v_c + w x (p_c - c))`` with ``t = (a x n) / |a x n|``   1
(``lateral=       the disk's rolling direction (positive spin about the axle
False``)           rolls it along +t): no slip along t only; the contact may
                   slide sideways (another row, e.g. a KnifeEdge on a shared
                   axle, holds that)
=================  ==========================================================  ====

The contact point ``p_c`` moves over the disk as the disk turns, so ``Adot qd`` of a rolling row is not ``T`` times the
classical acceleration of a body-fixed point: with ``e = p_c - c = -r u``, ``d/dt (w x e) = wdot x e + w x edot`` and
``edot = -r udot`` (``udot`` from ``adot = w x a``), not ``w x e``. The ground plane's height enters no row: the contact
point's height (``n . p_c``) is holonomic and is left to the coordinates (or to a holonomic declaration).
A disk whose axis is along the ground normal (``n x a = 0``) has no contact point: a RollingContact is undefined
there (a backend reports NaN rows).

The rolling-direction row (``lateral=False``) is ``t . v_pc`` with ``v_pc = v_c + w x e`` as above and a direction
that turns with the axle: ``A = t^T J_pc`` and ``Adot qd = t . (d/dt v_pc at qdd = 0) + tdot . v_pc`` with ``b = a x
n``, ``bdot = (w x a) x n`` and ``tdot = (bdot - t (t . bdot)) / |b|``. The first term is the two-row bias projected on
t; the second vanishes only where the contact does not slide sideways. ``|b| = |a x n| = |n - (n.a) a|``, so the row
is undefined where the disk lies flat, like the two-row form.
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass, field
from typing import ClassVar

import numpy as np

from cases.validation import as_array, frozen, orthonormal_rows

#: The x-y plane of the planar cases (rows), the default plane of a circle.
XY_PLANE = ((1.0, 0.0, 0.0), (0.0, 1.0, 0.0))


@dataclass(frozen=True)
class PointOnCircle:
    """A body point on a circle: ``phi = |P (p - center)|^2 - radius^2`` with ``P`` the 2 rows of the circle's
    plane (article 5.6). In a planar mechanism that moves in the plane this is the circle; in space it holds the
    point on the cylinder through the circle, perpendicular to the plane."""

    holonomic: ClassVar[bool] = True

    name: str
    body: str
    offset: np.ndarray
    center: np.ndarray
    radius: float
    plane: np.ndarray = field(default_factory=lambda: np.array(XY_PLANE))

    @property
    def size(self) -> int:
        return 1


@dataclass(frozen=True)
class PointsCoincide:
    """Two points coincide along ``directions`` (loop closure): ``phi = D (p_a - p_b)``. ``body_b = None`` makes
    ``offset_b`` a fixed world point (a pin to the ground). Planar loops use the 2 rows of their plane."""

    holonomic: ClassVar[bool] = True

    name: str
    body_a: str
    offset_a: np.ndarray
    body_b: str | None
    offset_b: np.ndarray
    directions: np.ndarray = field(default_factory=lambda: np.eye(3))

    @property
    def size(self) -> int:
        return int(np.shape(self.directions)[0])


@dataclass(frozen=True)
class PointOnLine:
    """A body point on the line through ``origin`` (world) perpendicular to the rows of ``normals``:
    ``phi = N (p - origin)`` (a slider)."""

    holonomic: ClassVar[bool] = True

    name: str
    body: str
    offset: np.ndarray
    origin: np.ndarray
    normals: np.ndarray

    @property
    def size(self) -> int:
        return int(np.shape(self.normals)[0])


@dataclass(frozen=True)
class JointCoupling:
    """A linear coupling of joints (a gear, a belt): ``phi = sum_j coefficients[j] q[joints[j]] - offset``, the
    joints named by their bodies."""

    holonomic: ClassVar[bool] = True

    name: str
    joints: tuple[str, ...]
    coefficients: tuple[float, ...]
    offset: float = 0.0

    @property
    def size(self) -> int:
        return 1


@dataclass(frozen=True)
class PointVelocity:
    """A body point with no velocity along world-fixed directions: the Pfaffian rows ``D v(body, offset) = 0``
    (``directions`` D: 1 to 3 orthonormal world rows). The general linear-in-velocity row (module docstring)."""

    name: str
    body: str
    offset: np.ndarray
    directions: np.ndarray

    holonomic: ClassVar[bool] = False

    @property
    def size(self) -> int:
        return int(np.shape(self.directions)[0])


@dataclass(frozen=True)
class KnifeEdge:
    """A knife edge (the Chaplygin sleigh's runner): the body point ``offset`` has no velocity across the unit
    ``direction`` fixed in the body (body frame): the Pfaffian row ``(R direction) . v(body, offset) = 0``."""

    name: str
    body: str
    offset: np.ndarray
    direction: np.ndarray

    holonomic: ClassVar[bool] = False

    @property
    def size(self) -> int:
        return 1


@dataclass(frozen=True)
class RollingContact:
    """A disk or wheel of ``radius`` rolling without slipping on a plane: the disk's centre is ``center`` and its
    axle the unit ``axis``, both in the body frame; ``plane`` holds the ground plane's two orthonormal tangent rows
    (world), its normal ``n = plane[0] x plane[1]`` pointing to the side the disk is on. Rows: the material point at
    the contact has no velocity along either tangent (module docstring); ``lam`` are the tangential (friction) forces
    the ground exerts at the contact along the rows of ``plane``.

    ``lateral=False`` keeps only the rolling-direction row: the contact has no velocity along ``t = (a x n) / |a x
    n|`` (``a = R axis`` the world axle; positive spin about the axle rolls the disk along +t), and ``lam`` is the
    one friction force the ground exerts at the contact along t (a wheel's traction). Two wheels on one axle each
    forbid the same sideways motion, so a differential drive declares them with ``lateral=False`` and holds the
    axle's sideways motion once (a KnifeEdge)."""

    name: str
    body: str
    center: np.ndarray
    axis: np.ndarray
    radius: float
    plane: np.ndarray = field(default_factory=lambda: np.array(XY_PLANE))
    lateral: bool = True

    holonomic: ClassVar[bool] = False

    @property
    def size(self) -> int:
        return 2 if self.lateral else 1


CONSTRAINT_TYPES = (PointOnCircle, PointsCoincide, PointOnLine, JointCoupling, PointVelocity, KnifeEdge,
                    RollingContact)
#: The Pfaffian (velocity-level, ``A(q) qd = 0``) declarations; the others are holonomic (``phi(q) = 0``).
PFAFFIAN_TYPES = (PointVelocity, KnifeEdge, RollingContact)


def contact_normal(c: RollingContact) -> np.ndarray:
    """The ground plane's unit normal ``plane[0] x plane[1]`` of a rolling contact (module docstring)."""
    return np.cross(c.plane[0], c.plane[1])


def _array(problems: list[str], where: str, value, shape) -> np.ndarray | None:
    arr = as_array(problems, where, value, shape)
    return None if arr is None else frozen(arr, shape)


def _number(problems: list[str], where: str, value) -> float:
    """``value`` as a float; NaN (and a problem) when it is not a number."""
    try:
        return float(value)
    except (TypeError, ValueError):
        problems.append(f"{where} is not a number: {value!r}")
        return float("nan")


def _unit(problems: list[str], where: str, value) -> np.ndarray | None:
    """``value`` as a read-only unit 3-vector (to 1e-9), or None after saying what is wrong."""
    arr = as_array(problems, where, value, (3,))
    if arr is None:
        return None
    if abs(float(np.linalg.norm(arr)) - 1.0) > 1e-9:
        problems.append(f"{where} has length {float(np.linalg.norm(arr))!r}; give a unit vector")
        return None
    return frozen(arr, (3,))


def _body(problems: list[str], where: str, name, bodies: set[str]) -> None:
    if name not in bodies:
        problems.append(f"{where} names an unknown body {name!r}; bodies: {sorted(bodies)}")


def validate(problems: list[str], c, bodies: set[str]):
    """The declaration with frozen float arrays, or None after appending what is wrong to ``problems``."""
    if not isinstance(c, CONSTRAINT_TYPES):
        problems.append(f"constraint {c!r} is not a declaration; use one of "
                        f"{[t.__name__ for t in CONSTRAINT_TYPES]} (cases.constraints)")
        return None
    where = f"constraint '{c.name}' ({type(c).__name__})"
    before = len(problems)
    if isinstance(c, PointOnCircle):
        _body(problems, where, c.body, bodies)
        out = PointOnCircle(c.name, c.body, _array(problems, f"{where} offset", c.offset, (3,)),
                            _array(problems, f"{where} center", c.center, (3,)),
                            _number(problems, f"{where} radius", c.radius),
                            orthonormal_rows(problems, f"{where} plane rows", c.plane, (2,)))
        if not (np.isfinite(out.radius) and out.radius > 0.0):
            problems.append(f"{where} has radius {c.radius!r}; a circle needs a positive finite radius")
    elif isinstance(c, PointsCoincide):
        _body(problems, where, c.body_a, bodies)
        if c.body_b is not None:
            _body(problems, where, c.body_b, bodies)
        if c.body_b == c.body_a:
            problems.append(f"{where} joins body {c.body_a!r} to itself; a loop closure joins two bodies")
        out = PointsCoincide(c.name, c.body_a, _array(problems, f"{where} offset_a", c.offset_a, (3,)), c.body_b,
                             _array(problems, f"{where} offset_b", c.offset_b, (3,)),
                             orthonormal_rows(problems, f"{where} directions", c.directions, (1, 2, 3)))
    elif isinstance(c, PointOnLine):
        _body(problems, where, c.body, bodies)
        out = PointOnLine(c.name, c.body, _array(problems, f"{where} offset", c.offset, (3,)),
                          _array(problems, f"{where} origin", c.origin, (3,)),
                          orthonormal_rows(problems, f"{where} normals", c.normals, (1, 2)))
    elif isinstance(c, PointVelocity):
        _body(problems, where, c.body, bodies)
        out = PointVelocity(c.name, c.body, _array(problems, f"{where} offset", c.offset, (3,)),
                            orthonormal_rows(problems, f"{where} directions", c.directions, (1, 2, 3)))
    elif isinstance(c, KnifeEdge):
        _body(problems, where, c.body, bodies)
        out = KnifeEdge(c.name, c.body, _array(problems, f"{where} offset", c.offset, (3,)),
                        _unit(problems, f"{where} direction (body frame)", c.direction))
    elif isinstance(c, RollingContact):
        _body(problems, where, c.body, bodies)
        out = RollingContact(c.name, c.body, _array(problems, f"{where} center", c.center, (3,)),
                             _unit(problems, f"{where} axis (body frame)", c.axis),
                             _number(problems, f"{where} radius", c.radius),
                             orthonormal_rows(problems, f"{where} plane rows (the ground's two tangents)", c.plane,
                                              (2,)),
                             bool(c.lateral) if isinstance(c.lateral, (bool, np.bool_)) else True)
        if not isinstance(c.lateral, (bool, np.bool_)):
            problems.append(f"{where} has lateral={c.lateral!r}; give True (rows along both ground tangents) or "
                            "False (the rolling direction only)")
        if not (np.isfinite(out.radius) and out.radius > 0.0):
            problems.append(f"{where} has radius {c.radius!r}; a rolling disk needs a positive finite radius")
    else:
        joints = tuple(c.joints)
        coefficients = tuple(_number(problems, f"{where} coefficient", x) for x in c.coefficients)
        offset = _number(problems, f"{where} offset", c.offset)
        for j in joints:
            _body(problems, where, j, bodies)
        if not joints or len(joints) != len(coefficients) or len(set(joints)) != len(joints):
            problems.append(f"{where} needs distinct joints and one coefficient each; got joints {list(joints)} "
                            f"and coefficients {list(coefficients)}")
        elif not all(np.isfinite(coefficients)) or not any(coefficients) or not np.isfinite(offset):
            problems.append(f"{where} has coefficients {list(coefficients)} and offset {c.offset!r}; give finite "
                            "numbers, not all coefficients zero")
        out = JointCoupling(c.name, joints, coefficients, offset)
    return out if len(problems) == before else None


def digest_bytes(c) -> bytes:
    """Every number of the declaration at full precision (``repr`` of an array rounds), for model digests."""
    parts = [type(c).__name__.encode(), repr(c.name).encode()]
    for f in (f.name for f in dataclasses.fields(c)):
        value = getattr(c, f)
        if f == "lateral" and value:  # the default adds nothing: a two-row contact's digest is what it was before
            continue
        if isinstance(value, np.ndarray) or (isinstance(value, tuple) and value and not isinstance(value[0], str)):
            parts.append(np.ascontiguousarray(value, dtype="<f8").tobytes())
        elif isinstance(value, float):
            parts.append(np.float64(value).tobytes())
        else:
            parts.append(repr(value).encode())
    return b"|".join(parts)
