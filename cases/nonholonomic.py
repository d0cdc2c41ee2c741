"""Nonholonomic scenes (article 1.5, 5.1: ideal Pfaffian constraints ``A(q) qd = 0``): a knife edge, a rolling disk, a
differential-drive robot.

Planar bodies move in the x-y plane (the ground), gravity along -z (``(0, 0, -g)``); a free planar body is built from
massless x and y carriages (prismatic joints) and a revolute z joint, so its coordinates are the position of the body
origin and its heading. The rows are declarations of :mod:`cases.constraints` (``KnifeEdge``, ``RollingContact``);
the contact's height is held by the coordinates (the holonomic part of rolling), never by a row.
"""

from __future__ import annotations

import numpy as np

from cases.build import build_model
from cases.constraints import XY_PLANE, KnifeEdge, RollingContact
from cases.factories import _positive, _require, register
from cases.loads import ExternalWrench
from cases.model import Body, Model, TaskPoint

_X, _Y, _Z = (1.0, 0.0, 0.0), (0.0, 1.0, 0.0), (0.0, 0.0, 1.0)
#: The rolling disk's lean joint limits (rad, 80 degrees): a disk leaning further is nearly flat, its contact direction
#: ill-defined (its tolerance grows as 1 / cos(lean)^2: 33 times at the limit).
LEAN_LIMIT = 1.4
_ORIGIN = (0.0, 0.0, 0.0)


def _thin_disk(mass: float, radius: float) -> np.ndarray:
    """COM inertia of a thin disk with its axle along the body y axis: ``m r^2 / 2`` about y, ``m r^2 / 4`` about x and
    z."""
    return np.diag([mass * radius**2 / 4.0, mass * radius**2 / 2.0, mass * radius**2 / 4.0])


def _planar_carriages(prefix: str) -> list[Body]:
    """The massless x and y carriages of a free planar body (its origin's position in the ground plane)."""
    return [Body(f"{prefix}_x", None, "prismatic", _X, 0.0), Body(f"{prefix}_y", f"{prefix}_x", "prismatic", _Y, 0.0)]


@register
def knife_edge(m: float = 1.0, a: float = 0.5, I: float = 0.2, g: float = 9.81) -> Model:  # noqa: E741, N803
    """The Chaplygin sleigh: a planar body on a knife edge (one Pfaffian row).

    q = (x, y, theta): the position of the contact point P (the body origin) in the ground plane and the heading of
    the runner (the body x axis). The centre of mass is ``a`` ahead of P on the runner, ``I`` the moment of inertia
    about it. ``KnifeEdge`` at P across the body y axis: ``-sin(theta) xd + cos(theta) yd = 0``; lam is the ground's
    lateral force on P along the body y axis. Inputs: the generalized forces on x, y, theta (B = I). Gravity is along
    -z, normal to every motion. Closed form: ``crosscheck.references.closed_forms`` (forward speed v and turning rate w
    obey ``m (vdot - a w^2) = F_along``, ``(I + m a^2) wdot = tau - m a v w``).
    """
    _positive("knife_edge", m=m, I=I)
    bodies = _planar_carriages("sleigh") + [
        Body("sleigh", "sleigh_y", "revolute", _Z, m, com=(a, 0.0, 0.0), inertia=np.diag([I / 2.0, I / 2.0, I]))]
    blade = KnifeEdge("runner", "sleigh", _ORIGIN, _Y)
    return build_model("knife_edge", bodies, gravity=(0.0, 0.0, -g), constraints=[blade],
                       task_points=[TaskPoint("com", "sleigh", (a, 0.0, 0.0), XY_PLANE)])


@register
def rolling_disk(m: float = 1.0, r: float = 0.5, g: float = 9.81) -> Model:
    """A thin disk (mass m, radius r) rolling without slipping on the ground plane z = 0 (two Pfaffian rows).

    q = (x, y, yaw, lean, spin): the contact point's position, the heading of the disk's rolling direction about z,
    the lean about that heading (0: upright) and the spin about the axle. A chain of massless frames: x and y
    carriages, a yaw frame (revolute z) and a lean frame (revolute x) at the contact point, then the disk on a
    revolute joint about its axle (body y) at height r along the leaned frame's z, so the lowest point of the disk is
    the contact point (x, y, 0) at every q (the holonomic part of rolling is in the coordinates). ``RollingContact``
    with the ground's x-y tangents: lam is the ground's friction force on the disk at the contact along x and y.
    Inputs: the generalized forces on every coordinate (B = I). The lean is meaningful in (-pi/2, pi/2): at
    +-pi/2 the disk lies flat and has no contact point, beyond it the chain puts the centre below the ground. The
    lean joint's limits (:data:`LEAN_LIMIT`) keep the sampled states upright enough to roll.
    """
    _positive("rolling_disk", m=m, r=r)
    bodies = _planar_carriages("contact") + [
        Body("heading", "contact_y", "revolute", _Z, 0.0),
        Body("lean", "heading", "revolute", _X, 0.0, limits=(-LEAN_LIMIT, LEAN_LIMIT)),
        Body("disk", "lean", "revolute", _Y, m, inertia=_thin_disk(m, r), translation=(0.0, 0.0, r))]
    rolling = RollingContact("rolling", "disk", _ORIGIN, _Y, r, XY_PLANE)
    return build_model("rolling_disk", bodies, gravity=(0.0, 0.0, -g), constraints=[rolling],
                       task_points=[TaskPoint("center", "disk", _ORIGIN)])


@register
def differential_drive(m_body: float = 4.0, m_wheel: float = 0.5, r: float = 0.1, track: float = 0.4,
                       com_ahead: float = 0.1, g: float = 9.81, payload: float = 2.0, drag: float = 3.0) -> Model:
    """A differential-drive robot: a chassis on the ground plane and two wheels of radius r on a common axle, the
    textbook three Pfaffian rows (Siciliano et al., Robotics, 11.2; Campion et al. 1996): each wheel rolls without
    slipping along its rolling direction (``RollingContact(..., lateral=False)``, one row each) and the axle does not
    slide sideways (one ``KnifeEdge`` at the axle's midpoint across the chassis' y axis). Rank 3, two degrees of
    freedom remain (drive and turn).

    q = (x, y, heading, left wheel, right wheel): the position of the axle's midpoint on the ground, the chassis'
    heading (body x forward, axle along body y) and the wheels' spin angles. The chassis (a box of mass ``m_body``,
    COM ``com_ahead`` in front of the axle at height r) carries the wheels at ``(0, +-track/2, r)``. Inputs: the
    two wheel torques. lam = (the left and the right wheel's traction: the ground's friction force at its contact
    along its rolling direction, the heading; the ground's lateral force on the axle along the chassis' y axis).
    Rows, with h the heading and s = track/2: ``cos h xd + sin h yd - s hd - r left_d = 0``, ``cos h xd + sin h yd + s
    hd - r right_d = 0``, ``-sin h xd + cos h yd = 0``. Closed form: ``crosscheck.references.closed_forms``.

    The payload (an external load, ``cases.loads``): a crate of ``payload`` kg on a tray behind and left of the axle,
    not part of the chassis' inertia, pressing with its weight and dragging with ``drag`` N backward and 0.4 ``drag``
    to the right (chassis frame), with a 0.1 ``drag`` N m yaw couple: an ``ExternalWrench`` in the body frame at
    ``(-0.15, 0.05, 2 r)``. Its vertical force does no work in these coordinates (tau_ext has none of it); the
    horizontal ones drive the drift at rest.
    """
    _positive("differential_drive", m_body=m_body, m_wheel=m_wheel, r=r, track=track)
    _require(payload >= 0.0 and drag >= 0.0 and np.isfinite(payload + drag),
             f"differential_drive: payload ({payload} kg) and drag ({drag} N) must be finite and >= 0")
    half = track / 2.0
    chassis_inertia = m_body / 12.0 * np.diag([track**2 + r**2, (2 * half) ** 2 + r**2, 2 * track**2])
    bodies = _planar_carriages("chassis") + [
        Body("chassis", "chassis_y", "revolute", _Z, m_body, com=(com_ahead, 0.0, r), inertia=chassis_inertia),
        Body("wheel_left", "chassis", "revolute", _Y, m_wheel, inertia=_thin_disk(m_wheel, r),
             translation=(0.0, half, r)),
        Body("wheel_right", "chassis", "revolute", _Y, m_wheel, inertia=_thin_disk(m_wheel, r),
             translation=(0.0, -half, r))]
    B = np.zeros((5, 2))
    B[3, 0] = B[4, 1] = 1.0
    rows = [RollingContact(f"{side}_rolling", f"wheel_{side}", _ORIGIN, _Y, r, XY_PLANE, lateral=False)
            for side in ("left", "right")] + [KnifeEdge("axle", "chassis", _ORIGIN, _Y)]
    crate = ExternalWrench("payload", "chassis", (-0.15, 0.05, 2.0 * r), (-drag, -0.4 * drag, -payload * g),
                           (0.0, 0.0, 0.1 * drag), "body")
    return build_model("differential_drive", bodies, gravity=(0.0, 0.0, -g), input_map=B, constraints=rows,
                       task_points=[TaskPoint("front", "chassis", (com_ahead + 0.1, 0.0, r), XY_PLANE)],
                       loads=[crate])


__all__ = ["differential_drive", "knife_edge", "rolling_disk"]
