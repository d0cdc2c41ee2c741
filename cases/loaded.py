"""Cases with external loads (``cases.loads``; article 2.3, eq. 12-14: ``M qdd + h = B u + tau_ext``).

Both are the double pendulum of article section 3 (:func:`cases.factories.double_pendulum`: point masses at the link
ends, relative angles from hanging down, the tip ``x2 = (l1 sin t1 + l2 sin(t1 + t2), -l1 cos t1 - l2 cos(t1 + t2))``
of eq. 4 with the Jacobian J of eq. 5) with loads at the tip, so that ``tau_ext = J^T f`` by hand
(``crosscheck.closed_forms``).
"""

from __future__ import annotations

from cases.factories import double_pendulum, register
from cases.loads import ExternalForce, ExternalWrench, PointSpring
from cases.model import Model, build_model


def _loaded(name: str, base: Model, loads: list) -> Model:
    return build_model(name, base.bodies, gravity=base.gravity, task_points=base.task_points, loads=loads)


@register
def double_pendulum_tip_force(m1: float = 1.0, m2: float = 1.0, l1: float = 1.0, l2: float = 1.0, g: float = 9.81,
                              fx: float = 4.0, fy: float = 1.5) -> Model:
    """The double pendulum with a constant world-frame force (fx, fy) at its tip (mass 2): tau_ext = J^T f.

    The force acts at link 2's point (0, -l2, 0), the tip of eq. (4); ``tau_ext = J(q)^T (fx, fy)`` with J of eq. (5).
    """
    base = double_pendulum(m1=m1, m2=m2, l1=l1, l2=l2, g=g)
    return _loaded("double_pendulum_tip_force", base,
                   [ExternalForce("tip_force", "link2", (0.0, -l2, 0.0), (fx, fy, 0.0), "world")])


@register
def double_pendulum_spring(m1: float = 1.0, m2: float = 1.0, l1: float = 1.0, l2: float = 1.0, g: float = 9.81,
                           k: float = 20.0, rest: float = 0.3, ax: float = 1.2, ay: float = -0.6, bfx: float = 0.5,
                           bfy: float = 1.0, couple: float = 0.7) -> Model:
    """The double pendulum with its tip on a spring to the world point (ax, ay) and a body-frame wrench on link 2.

    The spring (stiffness k, rest length ``rest``) pulls the tip with ``-k (|d| - rest) d / |d|``, ``d = x2 - (ax, ay)``;
    the wrench is a force (bfx, bfy) in link 2's frame at the tip and a couple ``couple`` about z: ``tau_ext = J^T
    (f_spring + R(t1 + t2) (bfx, bfy)) + couple (1, 1)``.
    """
    base = double_pendulum(m1=m1, m2=m2, l1=l1, l2=l2, g=g)
    tip = (0.0, -l2, 0.0)
    return _loaded("double_pendulum_spring", base,
                   [PointSpring("tip_spring", "link2", tip, (ax, ay, 0.0), k, rest),
                    ExternalWrench("motor_reaction", "link2", tip, (bfx, bfy, 0.0), (0.0, 0.0, couple), "body")])


__all__ = ["double_pendulum_spring", "double_pendulum_tip_force"]
