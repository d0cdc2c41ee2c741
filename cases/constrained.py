"""Constrained scenes (article section 5): closed loops, a circle, a slider, the non-minimal pendulum.

Same conventions as :mod:`cases.factories` (x-y plane, revolute axes z, links hanging along -y at q = 0, gravity
(0, -g, 0), relative angles). Constraints are declarations from :mod:`cases.constraints`; the planar loops close in
the x-y plane only (two rows), since a third row would be identically satisfied and so redundant.
Links with distributed mass are uniform rods along the link: COM at the middle, ``m l^2 / 12`` about z.
"""

from __future__ import annotations

import numpy as np

from cases.build import build_model
from cases.constraints import XY_PLANE, JointCoupling, PointOnCircle, PointOnLine, PointsCoincide
from cases.factories import _PLANE, _Z, _positive, _require, double_pendulum, planar_disk, register
from cases.model import Body, Model, TaskPoint

_X, _Y = (1.0, 0.0, 0.0), (0.0, 1.0, 0.0)
_ORIGIN = (0.0, 0.0, 0.0)


def _rod(name: str, parent: str | None, mass: float, length: float, at=_ORIGIN) -> Body:
    """A uniform planar rod on a revolute z joint at ``at`` (parent frame), hanging along -y at q = 0."""
    inertia = np.diag([mass * length**2 / 12.0, 0.0, mass * length**2 / 12.0])
    return Body(name, parent, "revolute", _Z, mass, com=(0.0, -length / 2.0, 0.0), inertia=inertia, translation=at)


@register
def double_pendulum_circle(m1: float = 1.0, m2: float = 1.0, l1: float = 1.0, l2: float = 1.0, g: float = 9.81,
                           xc: float = 1.0, yc: float = -1.0, R: float = 0.5) -> Model:  # noqa: N803
    """The double pendulum with its endpoint on a circle (article 5.6): phi = (x2 - xc)^2 + (y2 - yc)^2 - R^2.

    The article's double pendulum (``double_pendulum``: point masses, relative angles) plus one constraint. The
    default circle, centre (1, -1) radius 0.5, lies inside the reachable annulus |l1 - l2| < r < l1 + l2, so every
    point of it is a generic configuration (two elbow branches, no singular one).
    """
    _positive("double_pendulum_circle", m1=m1, m2=m2, l1=l1, l2=l2, R=R)
    near, far = np.hypot(xc, yc) - R, np.hypot(xc, yc) + R
    _require(far >= abs(l1 - l2) and near <= l1 + l2,
             f"double_pendulum_circle: the circle (centre ({xc}, {yc}), radius {R}) misses the tip's reachable "
             f"annulus {abs(l1 - l2)} <= r <= {l1 + l2}, so no configuration satisfies the constraint")
    bodies = [
        Body("link1", None, "revolute", _Z, m1, com=(0.0, -l1, 0.0)),
        Body("link2", "link1", "revolute", _Z, m2, com=(0.0, -l2, 0.0), translation=(0.0, -l1, 0.0)),
    ]
    circle = PointOnCircle("tip_on_circle", "link2", (0.0, -l2, 0.0), (xc, yc, 0.0), R)
    return build_model("double_pendulum_circle", bodies, gravity=(0.0, -g, 0.0),
                       task_points=[TaskPoint("tip", "link2", (0.0, -l2, 0.0), _PLANE)], constraints=[circle])


@register
def four_bar(crank: float = 1.0, coupler: float = 2.0, rocker: float = 1.0, ground: float = 2.0, m: float = 1.0,
             g: float = 9.81) -> Model:
    """A planar four-bar linkage (a closed loop); the default parallelogram has change points.

    Crank on a pivot at the origin, coupler on the crank's end, rocker on a pivot at (ground, 0); the loop closes
    where the coupler's end meets the rocker's end (2 rows, 1 degree of freedom). q = (crank angle, coupler angle
    relative to the crank, rocker angle), uniform rods of mass m. With crank + coupler = rocker + ground (Grashof
    equality, e.g. the default parallelogram 1-2-1-2) the links can be collinear: at q = (pi/2, 0, pi/2) and
    q = (-pi/2, pi, -pi/2) the loop Jacobian loses rank and the two assembly branches cross (the change point).
    """
    _positive("four_bar", crank=crank, coupler=coupler, rocker=rocker, ground=ground, m=m)
    lengths = sorted([crank, coupler, rocker, ground])
    _require(lengths[3] <= sum(lengths[:3]),
             f"four_bar: the longest link ({lengths[3]}) exceeds the sum of the others, so the loop cannot close")
    bodies = [_rod("crank", None, m, crank), _rod("coupler", "crank", m, coupler, (0.0, -crank, 0.0)),
              _rod("rocker", None, m, rocker, (ground, 0.0, 0.0))]
    loop = PointsCoincide("loop", "coupler", (0.0, -coupler, 0.0), "rocker", (0.0, -rocker, 0.0), XY_PLANE)
    return build_model("four_bar", bodies, gravity=(0.0, -g, 0.0), constraints=[loop],
                       task_points=[TaskPoint("coupler_mid", "coupler", (0.0, -coupler / 2.0, 0.0), _PLANE)])


@register
def slider_crank(crank: float = 0.5, rod: float = 1.5, offset: float = 0.1, m_crank: float = 1.0,
                 m_rod: float = 1.0, m_slider: float = 2.0, g: float = 9.81) -> Model:
    """A slider-crank: crank and connecting rod (uniform rods) and a slider block on a prismatic joint along x.

    The slider's line is y = offset; the rod's end is pinned to the slider (a 2-row loop closure), one degree of
    freedom. q = (crank angle, rod angle relative to the crank, slider x). The dead centres (crank and rod
    aligned) are input singularities, not constraint ones: the loop Jacobian keeps full rank there. Task point:
    the slider, along x (the only direction it moves in).
    """
    _positive("slider_crank", crank=crank, rod=rod, m_crank=m_crank, m_rod=m_rod, m_slider=m_slider)
    _require(rod > crank + abs(offset),
             f"slider_crank: the rod ({rod}) must be longer than crank + |offset| ({crank + abs(offset)}) for the "
             "crank to turn fully")
    bodies = [_rod("crank", None, m_crank, crank), _rod("rod", "crank", m_rod, rod, (0.0, -crank, 0.0)),
              Body("slider", None, "prismatic", _X, m_slider, translation=(0.0, offset, 0.0))]
    pin = PointsCoincide("wrist_pin", "rod", (0.0, -rod, 0.0), "slider", _ORIGIN, XY_PLANE)
    return build_model("slider_crank", bodies, gravity=(0.0, -g, 0.0), constraints=[pin],
                       task_points=[TaskPoint("slider", "slider", _ORIGIN, (_X,))])


@register
def cartesian_pendulum(m: float = 1.0, L: float = 1.0, g: float = 9.81) -> Model:  # noqa: N803
    """The non-minimal pendulum: a point mass on two prismatic joints x, y, held on a circle of radius L.

    A massless carriage slides along x and carries the bob on a y slide: q = (x, y), M = m I, B = I (forces
    along x and y), phi = x^2 + y^2 - L^2. Its multiplier has a closed form:
    ``lam = -m (|v|^2 + p . (gravity + u / m)) / (2 L^2)`` (tension = -2 L lam).
    """
    _positive("cartesian_pendulum", m=m, L=L)
    bodies = [Body("carriage", None, "prismatic", _X, 0.0), Body("bob", "carriage", "prismatic", _Y, m)]
    rod = PointOnCircle("rod", "bob", _ORIGIN, _ORIGIN, L)
    return build_model("cartesian_pendulum", bodies, gravity=(0.0, -g, 0.0), constraints=[rod],
                       task_points=[TaskPoint("bob", "bob", _ORIGIN, _PLANE)])


def _free_planar_body(name: str, mass: float, length: float, izz: float) -> list[Body]:
    """A free planar body as three joints: massless x and y carriages, then the link on a revolute z joint
    (absolute angle from hanging down), its mass at distance ``length`` along it with moment ``izz`` about z."""
    return [Body(f"{name}_x", None, "prismatic", _X, 0.0), Body(f"{name}_y", f"{name}_x", "prismatic", _Y, 0.0),
            Body(name, f"{name}_y", "revolute", _Z, mass, com=(0.0, -length, 0.0), inertia=planar_disk(izz))]


@register
def double_pendulum_absolute_loop(m1: float = 1.0, m2: float = 1.0, l1: float = 1.0, l2: float = 1.0,
                                  g: float = 9.81, I1: float = 0.1, I2: float = 0.1) -> Model:  # noqa: N803
    """The double pendulum built from two free planar bodies joined by loop constraints (4 rows).

    q = (x1, y1, phi1, x2, y2, phi2): each link's pivot position and absolute angle. Constraints: link 1's pivot
    is pinned to the origin, link 2's pivot to link 1's end. A free body needs a rotational inertia (a free point
    mass has no orientation, so its angle would have zero mass), hence ``I1``, ``I2`` about z; with the same values
    ``double_pendulum(I1=.., I2=..)`` is the same machine in joint coordinates. The inputs are its joint torques
    (tau1 at the shoulder, tau2 at the elbow), whose generalized forces on the absolute angles are
    (tau1 - tau2, tau2). At every admissible state the accelerations must match: theta1 = phi1,
    theta2 = phi2 - phi1.
    """
    _positive("double_pendulum_absolute_loop", m1=m1, m2=m2, l1=l1, l2=l2, I1=I1, I2=I2)
    bodies = _free_planar_body("link1", m1, l1, I1) + _free_planar_body("link2", m2, l2, I2)
    B = np.zeros((6, 2))
    B[2] = (1.0, -1.0)
    B[5] = (0.0, 1.0)
    constraints = [PointsCoincide("shoulder", "link1", _ORIGIN, None, _ORIGIN, XY_PLANE),
                   PointsCoincide("elbow", "link2", _ORIGIN, "link1", (0.0, -l1, 0.0), XY_PLANE)]
    return build_model("double_pendulum_absolute_loop", bodies, gravity=(0.0, -g, 0.0), input_map=B,
                       task_points=[TaskPoint("tip", "link2", (0.0, -l2, 0.0), _PLANE)], constraints=constraints)


@register
def double_pendulum_rail(m1: float = 1.0, m2: float = 1.0, l1: float = 1.0, l2: float = 1.0, g: float = 9.81,
                         x0: float = 0.0, y0: float = -1.2, incline: float = 0.3) -> Model:
    """The double pendulum with its tip in a straight rail: a ``PointOnLine`` row, phi = n . (p_tip - o).

    The article's double pendulum (``double_pendulum``: point masses, relative angles) with its tip held on the
    rail through o = (x0, y0) at ``incline`` rad from the x axis: one row, normal n = (-sin incline, cos incline),
    so lam is the rail's force on the tip along n; one degree of freedom. The rail must pass within the tip's reach
    (its distance from the shoulder below l1 + l2: at l1 + l2 it only touches the reach, stretched, where the row
    vanishes); a rail at distance |l1 - l2| touches the inner edge of the reach, and the row vanishes there too.
    Task point ``tip``.
    """
    _positive("double_pendulum_rail", m1=m1, m2=m2, l1=l1, l2=l2)
    normal = (-np.sin(incline), np.cos(incline), 0.0)
    distance = abs(normal[0] * x0 + normal[1] * y0)
    _require(distance < l1 + l2,
             f"double_pendulum_rail: the rail through ({x0}, {y0}) at incline {incline} passes {distance} from the "
             f"shoulder, beyond the tip's reach l1 + l2 = {l1 + l2}, so no configuration satisfies the constraint")
    bodies = double_pendulum(m1=m1, m2=m2, l1=l1, l2=l2, g=g).bodies
    rail = PointOnLine("tip_on_rail", "link2", (0.0, -l2, 0.0), (x0, y0, 0.0), (normal,))
    return build_model("double_pendulum_rail", bodies, gravity=(0.0, -g, 0.0), constraints=[rail],
                       task_points=[TaskPoint("tip", "link2", (0.0, -l2, 0.0), _PLANE)])


@register
def geared_pendulums(m1: float = 1.0, l1: float = 0.5, m2: float = 2.0, l2: float = 1.0, ratio: float = -2.0,
                     offset: float = 0.0, spacing: float = 1.5, g: float = 9.81) -> Model:
    """Two rod pendulums on parallel axes geared together: a ``JointCoupling`` row, phi = q1 - ratio q2 - offset.

    The pinion (a uniform rod, m1, l1) hangs from the origin, the wheel (m2, l2) from (spacing, 0); the gear holds
    q1 = ratio q2 + offset (one degree of freedom). Meshing gears turn opposite ways: ratio = -R_wheel / R_pinion
    (default -2, a pinion of half the wheel's radius). ``Jc^T lam = (lam, -ratio lam)``: lam is the gear's torque
    on the pinion, -ratio lam the torque on the wheel. ``spacing`` (the pitch radii's sum) places the wheel and
    enters no dynamics. Task point ``pinion_tip``, the pinion rod's end, along x (singular with the pinion level).
    """
    _positive("geared_pendulums", m1=m1, l1=l1, m2=m2, l2=l2, spacing=spacing)
    _require(np.isfinite(ratio) and ratio != 0.0,
             f"geared_pendulums: ratio must be finite and non-zero, got {ratio} (a zero ratio locks the pinion)")
    bodies = [_rod("pinion", None, m1, l1), _rod("wheel", None, m2, l2, (spacing, 0.0, 0.0))]
    gear = JointCoupling("gear", ("pinion", "wheel"), (1.0, -ratio), offset)
    return build_model("geared_pendulums", bodies, gravity=(0.0, -g, 0.0), constraints=[gear],
                       task_points=[TaskPoint("pinion_tip", "pinion", (0.0, -l1, 0.0), (_X,))])


__all__ = ["cartesian_pendulum", "double_pendulum_absolute_loop", "double_pendulum_circle", "double_pendulum_rail",
           "four_bar", "geared_pendulums", "slider_crank"]
