"""Cases on Lie groups: free bodies, ball joints and a free-floating base (article 2.1-2.2, 6.2, 6.4, 9.2).

Conventions are those of :mod:`cases.model` (Pinocchio's): a spherical joint's coordinates are a unit quaternion
``(x, y, z, w)`` and its velocity the body angular velocity; a free joint's coordinates are ``(p, x, y, z, w)``
and its velocity the body twist ``(v, w)``.
"""

from __future__ import annotations

import numpy as np

from cases.build import build_model
from cases.constraints import PointsCoincide
from cases.factories import _PLANE, _inertia, _positive, _require, _rot, loaded_from, register
from cases.model import Body, Model, TaskPoint

_ZERO = (0.0, 0.0, 0.0)


@register
def free_body(m: float = 2.0, I1: float = 0.02, I2: float = 0.05, I3: float = 0.06, g: float = 0.0) -> Model:  # noqa: N803
    """A torque-free rigid body on a free joint (SE(3)) with three different principal moments (Euler's equations).

    Mass ``m``, principal inertia diag(I1, I2, I3) about its centre of mass, which is the body-frame origin offset
    by (0.05, -0.03, 0.02) so that the body twist couples linear and angular motion; gravity (0, 0, -g), zero by
    default (the torque-free body of Euler's equations, a closed form). Task point ``marker``: a point on the body.
    """
    _positive("free_body", m=m, I1=I1, I2=I2, I3=I3)
    _require(max(I1, I2, I3) <= I1 + I2 + I3 - max(I1, I2, I3),
             f"free_body: principal moments {I1}, {I2}, {I3} violate the triangle inequality")
    body = Body("body", None, "free", _ZERO, m, com=(0.05, -0.03, 0.02), inertia=np.diag([I1, I2, I3]))
    return build_model("free_body", [body], gravity=(0.0, 0.0, -g),
                       task_points=[TaskPoint("marker", "body", (0.2, 0.1, -0.05))])


@register
def ball_pendulum(m: float = 1.0, l: float = 0.8, Ix: float = 0.03, Iy: float = 0.05, Iz: float = 0.02,
                  g: float = 9.81) -> Model:  # noqa: E741, N803
    """A rigid body hanging from a ball joint (SO(3)): the 3-degree-of-freedom spherical pendulum.

    The ball joint is at the world origin; the body's centre of mass (mass m, principal inertia diag(Ix, Iy, Iz) in a
    tilted frame) is at (0.05, 0.02, -l) in its body frame. Gravity (0, 0, -g). Task point ``bob``: the centre of
    mass along world x and y (it moves on a sphere about the joint, so a third direction, along the rod, would make
    the task inertia singular everywhere). (The gimbal model ``spherical_pendulum`` is the same point on two
    revolute joints: 2 degrees of freedom.)
    """
    _positive("ball_pendulum", m=m, l=l, Ix=Ix, Iy=Iy, Iz=Iz)
    com = (0.05, 0.02, -l)
    body = Body("bob", None, "spherical", _ZERO, m, com=com,
                inertia=_inertia((Ix, Iy, Iz), _rot((1.0, 2.0, 0.5), 0.6)))
    return build_model("ball_pendulum", [body], gravity=(0.0, 0.0, -g),
                       task_points=[TaskPoint("bob", "bob", com, _PLANE)])


@register
def ball_double_pendulum(m1: float = 1.2, m2: float = 0.8, l1: float = 0.6, l2: float = 0.5,
                         g: float = 9.81) -> Model:
    """A 3-D double pendulum on two ball joints (a limb: shoulder and elbow as ball joints), 6 degrees of freedom.

    The shoulder is at the world origin, the elbow at (0, 0, -l1) in the upper link's frame, placed with a small
    rotation; the links' centres of mass are at mid-length, with full inertia tensors. Gravity (0, 0, -g). Task
    point ``hand``: the lower link's end.
    """
    _positive("ball_double_pendulum", m1=m1, m2=m2, l1=l1, l2=l2)
    bodies = [Body("upper", None, "spherical", _ZERO, m1, com=(0.01, 0.0, -l1 / 2),
                   inertia=_inertia((m1 * l1**2 / 12, m1 * l1**2 / 12 * 1.1, 0.004), _rot((1.0, 0.0, 0.3), 0.2))),
              Body("lower", "upper", "spherical", _ZERO, m2, com=(0.0, -0.01, -l2 / 2),
                   inertia=_inertia((m2 * l2**2 / 12 * 0.9, m2 * l2**2 / 12, 0.003), _rot((0.2, 1.0, 0.0), 0.5)),
                   rotation=_rot((0.0, 1.0, 1.0), 0.3), translation=(0.0, 0.0, -l1))]
    return build_model("ball_double_pendulum", bodies, gravity=(0.0, 0.0, -g),
                       task_points=[TaskPoint("hand", "lower", (0.0, 0.0, -l2))])


@register
def satellite_arm(m_base: float = 40.0, m_link: float = 3.0, l: float = 0.5, g: float = 0.0) -> Model:
    """A free-floating spacecraft (free joint) carrying a 3-joint arm (revolute, revolute, prismatic), zero gravity.

    The base (mass m_base, a box's inertia) carries the arm at (0.4, 0.1, 0.3); the arm's axes are skewed and its
    links of length l have full inertia tensors. The inputs are the arm's three joints (the base is unactuated:
    B is the 9 x 3 selection of the arm's velocities). Gravity (0, 0, -g), zero by default. Task point ``gripper``.
    """
    _positive("satellite_arm", m_base=m_base, m_link=m_link, l=l)
    box = m_base / 12 * np.array([0.8**2 + 0.6**2, 1.0**2 + 0.6**2, 1.0**2 + 0.8**2])
    rod = m_link * l**2 / 12
    bodies = [Body("base", None, "free", _ZERO, m_base, com=(0.02, -0.01, 0.03),
                   inertia=_inertia(box, _rot((1.0, 1.0, 0.0), 0.1))),
              Body("shoulder", "base", "revolute", (0.0, 0.0, 1.0), m_link, com=(l / 2, 0.0, 0.0),
                   inertia=_inertia((0.002, rod, rod), _rot((0.0, 0.0, 1.0), 0.2)), translation=(0.4, 0.1, 0.3)),
              Body("elbow", "shoulder", "revolute", (0.0, 1.0, 0.0), m_link, com=(l / 2, 0.01, 0.0),
                   inertia=_inertia((0.002, rod, rod), _rot((1.0, 0.0, 0.0), 0.4)),
                   rotation=_rot((1.0, 0.0, 0.0), 0.3), translation=(l, 0.0, 0.0)),
              Body("extension", "elbow", "prismatic", (1.0, 0.0, 0.0), m_link / 2, com=(l / 4, 0.0, 0.0),
                   inertia=_inertia((0.001, rod / 4, rod / 4), _rot((0.0, 1.0, 0.0), 0.1)),
                   translation=(l, 0.0, 0.0))]
    B = np.zeros((9, 3))
    B[6:, :] = np.eye(3)
    return build_model("satellite_arm", bodies, gravity=(0.0, 0.0, -g), input_map=B,
                       task_points=[TaskPoint("gripper", "extension", (l / 2, 0.0, 0.0))])


# ------------------------------------------------------------------------------ robots from example-robot-data

SOLO12_URDF = "cmeel.prefix/share/example-robot-data/robots/solo_description/robots/solo12.urdf"
#: Solo12 standing (example-robot-data's SRDF "standing" posture): base 0.235 m up, each leg (HAA, HFE, KFE).
SOLO12_STANDING = (0.0, 0.0, 0.235, 0.0, 0.0, 0.0, 1.0) + (0.1, 0.8, -1.6, -0.1, 0.8, -1.6, 0.1, -0.8, 1.6,
                                                            -0.1, -0.8, 1.6)
SOLO12_FEET = ("FL_FOOT", "FR_FOOT", "HL_FOOT", "HR_FOOT")


@register
@loaded_from("example-robot-data's solo_description/robots/solo12.urdf")
def solo12() -> Model:
    """Solo12, a 12-joint quadruped (example-robot-data's URDF via Pinocchio), on a free base: nq 19, nv 18.

    The base is unactuated (B selects the 12 leg joints); the default task point is the front-left foot.
    """
    from cases.factories import robot_data_path
    from cases.urdf import from_urdf

    return from_urdf(robot_data_path(SOLO12_URDF, "solo12"), name="solo12", base="free")


@register
@loaded_from("example-robot-data's solo_description/robots/solo12.urdf (its feet pinned by constraints declared "
             "in code)")
def solo12_standing() -> Model:
    """Solo12 (``solo12``) standing on four point contacts: each foot pinned to the ground point under it in the
    standing posture (``PointsCoincide`` with the world, 3 rows each: 12 rows on 18 velocities).

    The feet are the URDF's foot frames (the task points); their world points are those of the standing
    configuration :data:`SOLO12_STANDING` (forward kinematics, ``cases.configuration.poses``).
    """
    from cases import configuration

    free = solo12()
    at = configuration.poses(free, SOLO12_STANDING)
    feet = [free.task_point(name) for name in SOLO12_FEET]
    pins = []
    for tp in feet:
        R, p = at[free.body_index(tp.body)]
        pins.append(PointsCoincide(f"contact:{tp.name}", tp.body, tp.offset, None, R @ tp.offset + p))
    return build_model("solo12_standing", free.bodies, free.gravity, input_map=free.input_map,
                       task_points=free.task_points, constraints=pins, source=free.source)


__all__ = ["ball_double_pendulum", "ball_pendulum", "free_body", "satellite_arm", "solo12", "solo12_standing"]
