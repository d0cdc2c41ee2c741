"""Constraint declarations in model terms (article 5.1; DESIGN.md, constraints).

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
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from cases.validation import as_array, frozen, orthonormal_rows

#: The x-y plane of the planar cases (rows), the default plane of a circle.
XY_PLANE = ((1.0, 0.0, 0.0), (0.0, 1.0, 0.0))


@dataclass(frozen=True)
class PointOnCircle:
    """A body point on a circle: ``phi = |P (p - center)|^2 - radius^2`` with ``P`` the 2 rows of the circle's
    plane (article 5.6). In a planar mechanism that moves in the plane this is the circle; in space it holds the
    point on the cylinder through the circle, perpendicular to the plane."""

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

    name: str
    joints: tuple[str, ...]
    coefficients: tuple[float, ...]
    offset: float = 0.0

    @property
    def size(self) -> int:
        return 1


CONSTRAINT_TYPES = (PointOnCircle, PointsCoincide, PointOnLine, JointCoupling)


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
    for f in c.__dataclass_fields__:
        value = getattr(c, f)
        if isinstance(value, np.ndarray) or (isinstance(value, tuple) and value and not isinstance(value[0], str)):
            parts.append(np.ascontiguousarray(value, dtype="<f8").tobytes())
        elif isinstance(value, float):
            parts.append(np.float64(value).tobytes())
        else:
            parts.append(repr(value).encode())
    return b"|".join(parts)
