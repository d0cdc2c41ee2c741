"""External load declarations in model terms (article 2.3, 5.1-5.5 eq. 12-17, 6.1; docs/design.md, conventions).

The equation of motion carries the external load ``tau_ext`` (eq. 12): ``M qdd + h = B u + Jc^T lam + tau_ext``.
A declaration says what acts on which body, in the words of the scene; it does not say how to compute
``tau_ext``: every formalism maps it with its own kinematics (virtual work through its own Jacobians, a body load
in a backward pass, a body wrench through its own adjoint). The definitions below fix exactly what each one means,
so that ``tau_ext`` is the same generalized force in every backend and in other tools.

``p`` is the world position of the point ``offset`` (body frame) of ``body``, ``R`` the body's orientation (world <-
body), ``v_p`` the point's velocity and ``w`` the body's angular velocity (world frame). A vector given in
``frame = "body"`` is ``R x`` in the world; in ``frame = "world"`` it is itself.

================  ======================================================================  =====================
declaration       load on the body (world frame)                                          power
================  ======================================================================  =====================
ExternalForce     the force ``f`` at ``p``                                                 ``f . v_p``
ExternalWrench    the force ``f`` at ``p`` and the couple ``m`` (a free moment):           ``f . v_p + m . w``
                  about the body origin ``o`` the moment is ``m + (p - o) x f``
PointSpring       the force ``f = -k (|d| - L0) d / |d|`` at ``p``, ``d = p - anchor``      ``-dV/dt``
                  (``anchor`` a world point): conservative, ``V = 1/2 k (|d| - L0)^2``
================  ======================================================================  =====================

So ``tau_ext = J_p^T f + J_w^T m`` with ``J_p`` the point's and ``J_w`` the body's angular velocity Jacobian
(world frame), and its power is ``tau_ext . qd``. Every load here is velocity-independent: it belongs with gravity
in the drift at rest (``zvcf``, article 4.5-4.6). A spring with ``rest_length > 0`` has no direction at ``d = 0``
(its force is undefined there); with ``rest_length = 0`` it is ``-k d``, smooth everywhere.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from cases.validation import as_array, frozen

#: The frames a force or a moment can be given in.
FRAMES = ("world", "body")


@dataclass(frozen=True)
class ExternalForce:
    """A force ``force`` (N) at the body point ``offset`` (body frame), its components in ``frame`` (world or body:
    a body-frame force turns with the body)."""

    name: str
    body: str
    offset: np.ndarray
    force: np.ndarray
    frame: str = "world"


@dataclass(frozen=True)
class ExternalWrench:
    """A force ``force`` at the body point ``offset`` and a couple ``moment`` (N m, a free moment), both with their
    components in ``frame``. About the body origin the moment is ``moment + offset x force`` (body frame)."""

    name: str
    body: str
    offset: np.ndarray
    force: np.ndarray
    moment: np.ndarray
    frame: str = "world"


@dataclass(frozen=True)
class PointSpring:
    """A linear spring from the body point ``offset`` to the world point ``anchor``: stiffness ``k`` (N/m, >= 0) and
    rest length ``L0`` (m, >= 0). Force on the point ``-k (|d| - L0) d / |d|`` with ``d = p - anchor``; potential
    energy :meth:`potential`."""

    name: str
    body: str
    offset: np.ndarray
    anchor: np.ndarray
    stiffness: float
    rest_length: float = 0.0

    def potential(self, distance: float) -> float:
        """``V = 1/2 k (|d| - L0)^2`` (J) at the spring's length ``|d|``."""
        return 0.5 * self.stiffness * (float(distance) - self.rest_length) ** 2


LOAD_TYPES = (ExternalForce, ExternalWrench, PointSpring)


def _vector(problems: list[str], where: str, value) -> np.ndarray | None:
    arr = as_array(problems, where, value, (3,))
    return None if arr is None else frozen(arr, 3)


def _number(problems: list[str], where: str, value) -> float:
    try:
        x = float(value)
    except (TypeError, ValueError):
        problems.append(f"{where} is not a number: {value!r}")
        return float("nan")
    if not np.isfinite(x):
        problems.append(f"{where} is not finite: {value!r}")
    return x


def validate(problems: list[str], load, bodies: set[str]):
    """The declaration with frozen float arrays, or None after appending what is wrong to ``problems``."""
    if not isinstance(load, LOAD_TYPES):
        problems.append(f"load {load!r} is not a load declaration; use one of "
                        f"{[t.__name__ for t in LOAD_TYPES]} (cases.loads)")
        return None
    where = f"load '{load.name}' ({type(load).__name__})"
    before = len(problems)
    if not isinstance(load.name, str) or not load.name:
        problems.append(f"{where} needs a non-empty name")
    if load.body not in bodies:
        problems.append(f"{where} names an unknown body {load.body!r}; bodies: {sorted(bodies)}")
    offset = _vector(problems, f"{where} offset", load.offset)
    if isinstance(load, PointSpring):
        anchor = _vector(problems, f"{where} anchor", load.anchor)
        k = _number(problems, f"{where} stiffness", load.stiffness)
        rest = _number(problems, f"{where} rest_length", load.rest_length)
        if k < 0.0:
            problems.append(f"{where} has a negative stiffness {k!r}; a spring's stiffness is >= 0 N/m")
        if rest < 0.0:
            problems.append(f"{where} has a negative rest length {rest!r}; give a length >= 0 m")
        out = PointSpring(load.name, load.body, offset, anchor, k, rest)
    else:
        if load.frame not in FRAMES:
            problems.append(f"{where} has frame {load.frame!r}; valid frames: {list(FRAMES)}")
        force = _vector(problems, f"{where} force", load.force)
        if isinstance(load, ExternalWrench):
            out = ExternalWrench(load.name, load.body, offset, force,
                                 _vector(problems, f"{where} moment", load.moment), load.frame)
        else:
            out = ExternalForce(load.name, load.body, offset, force, load.frame)
    return out if len(problems) == before else None


def digest_bytes(load) -> bytes:
    """Every field of the declaration at full precision, for model digests."""
    parts = [type(load).__name__.encode()]
    for f in load.__dataclass_fields__:
        value = getattr(load, f)
        if isinstance(value, np.ndarray) or isinstance(value, float):
            parts.append(np.ascontiguousarray(value, dtype="<f8").tobytes())
        else:
            parts.append(repr(value).encode())
    return b"|".join(parts)

