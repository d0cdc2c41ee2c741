"""Parameterized case factories, registered by name (the registry behind :func:`cases.load`).

Every factory takes only keyword parameters with numeric defaults (the catalog reads them from the signature)
and returns a validated :class:`~cases.model.Model`. Conventions are those of :mod:`cases.model`.

Planar cases (``double_pendulum``, ``n_link_pendulum``, ``acrobot``) move in the x-y plane: revolute axes z,
links hanging along -y at q = 0, gravity (0, -g, 0), and every angle is relative to the previous link, measured
from hanging straight down (article section 3). A point at distance ``l`` along a link whose absolute angle is
``phi`` is at ``(l sin phi, -l cos phi)`` from the link's joint.
"""

from __future__ import annotations

import inspect
from dataclasses import dataclass
from typing import Callable

import numpy as np

from cases.build import build_model
from cases.loads import ExternalForce, ExternalWrench, PointSpring
from cases.model import Body, Model, TaskPoint


class CaseError(ValueError):
    """An unknown case, an unknown parameter, or a parameter value a case cannot use."""


@dataclass(frozen=True)
class CaseInfo:
    """One catalog entry: the case name, a one-line summary, and its parameters with their defaults."""

    name: str
    summary: str
    parameters: dict
    factory: Callable[..., Model]


REGISTRY: dict[str, CaseInfo] = {}


def register(func: Callable[..., Model]) -> Callable[..., Model]:
    """Register ``func`` under its own name; its keyword defaults become the case's parameters."""
    params = {}
    for p in inspect.signature(func).parameters.values():
        if p.default is inspect.Parameter.empty:
            raise TypeError(f"case factory {func.__name__}: parameter '{p.name}' needs a default")
        params[p.name] = p.default
    summary = (inspect.getdoc(func) or "").strip().splitlines()[0] if func.__doc__ else ""
    REGISTRY[func.__name__] = CaseInfo(func.__name__, summary, params, func)
    return func


#: The built-in cases whose model is loaded from a model file, by name: that file, in words (``cases.model_file``).
#: Their model carries the file as its ``source``, so the reference is built from the file itself
#: (``crosscheck.references.pinocchio.build``), and no closed form is bound to them.
MODEL_FILES: dict[str, str] = {}


def loaded_from(description: str) -> Callable[[Callable[..., Model]], Callable[..., Model]]:
    """Mark a case factory as loading its model from the file ``description`` names (:data:`MODEL_FILES`)."""
    def mark(func: Callable[..., Model]) -> Callable[..., Model]:
        MODEL_FILES[func.__name__] = description
        return func
    return mark


# ----------------------------------------------------------------------------------------------- helpers


def _rot(axis, angle: float) -> np.ndarray:
    """Rotation matrix of ``angle`` (rad) about ``axis`` (Rodrigues)."""
    k = np.asarray(axis, dtype=float)
    k = k / np.linalg.norm(k)
    K = np.array([[0.0, -k[2], k[1]], [k[2], 0.0, -k[0]], [-k[1], k[0], 0.0]])
    return np.eye(3) + np.sin(angle) * K + (1.0 - np.cos(angle)) * (K @ K)


def _inertia(principal, rotation) -> np.ndarray:
    """``R diag(principal) R^T``: a full (off-diagonal) inertia tensor about the COM."""
    R = np.asarray(rotation, dtype=float)
    return R @ np.diag(principal) @ R.T


_Z = (0.0, 0.0, 1.0)
#: Task directions of the planar cases: the x-y plane they move in (article 6.3.4, x_task = [x_2, y_2]).
_PLANE = ((1.0, 0.0, 0.0), (0.0, 1.0, 0.0))


def planar_disk(izz: float) -> np.ndarray:
    """COM inertia of a thin disk in the x-y plane with moment ``izz`` about z: diag(izz/2, izz/2, izz)."""
    return np.diag([izz / 2.0, izz / 2.0, izz])


def _require(cond: bool, message: str) -> None:
    if not cond:
        raise CaseError(message)


def _positive(case: str, **values: float) -> None:
    """Masses and lengths of a case: positive (a link's direction is the joint angle's job, not its length's sign;
    a zero mass or length is a different mechanism, usually one with a singular mass matrix)."""
    for key, value in values.items():
        _require(value > 0.0, f"{case}: {key} must be positive, got {value}")


#: Most links ``n_link_pendulum`` builds. One state of ``crosscheck gate --samples 1 --frames 0 --no-charts`` (the
#: symbolic Euler–Lagrange derivation dominates) took 34 s and 0.8 GB at n = 30, 74 s and 1.9 GB at n = 40, and had
#: not finished after 15 minutes at n = 50 (2-core machine, busy with a campaign); n = 100000 ran without end. The
#: stability maps chart chains up to 60 links (``crosscheck.campaigns.stability``, Euler–Lagrange capped below that).
MAX_LINKS = 60


# ---------------------------------------------------------------------------------------------- planar


@register
def double_pendulum(m1: float = 1.0, m2: float = 1.0, l1: float = 1.0, l2: float = 1.0,
                    g: float = 9.81, I1: float = 0.0, I2: float = 0.0, a1: float = 0.0,  # noqa: N803
                    a2: float = 0.0) -> Model:
    """Planar double pendulum of article section 3: point masses at the link ends, relative angles from hanging down.

    q = (theta1, theta2): theta1 of link 1 from the downward vertical, theta2 of link 2 relative to link 1.
    Mass 1 at (l1 sin t1, -l1 cos t1), mass 2 (task point ``tip``) at eq. (4). ``I1``, ``I2`` (default 0, the
    article's point masses) give each mass a rotational inertia about z (:func:`planar_disk`); ``a1``, ``a2``
    (default 0) give each joint an armature, a rotor's inertia on M's diagonal (``Body.armature``).
    """
    _positive("double_pendulum", m1=m1, m2=m2, l1=l1, l2=l2)
    bodies = [
        Body("link1", None, "revolute", _Z, m1, com=(0.0, -l1, 0.0), inertia=planar_disk(I1), armature=a1),
        Body("link2", "link1", "revolute", _Z, m2, com=(0.0, -l2, 0.0), inertia=planar_disk(I2),
             translation=(0.0, -l1, 0.0), armature=a2),
    ]
    return build_model("double_pendulum", bodies, gravity=(0.0, -g, 0.0),
                       task_points=[TaskPoint("tip", "link2", (0.0, -l2, 0.0), _PLANE)])


# ------------------------------------------------------------------- external loads (cases.loads; article 2.3)
# The double pendulum with loads at its tip, so that tau_ext = J^T f by hand (crosscheck.references.closed_forms).
# Registered right after it: a fault in the loads is then found in the first states of a round-robin hunt.


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

    The spring (stiffness k, rest length ``rest``) pulls the tip with ``-k (|d| - rest) d / |d|``, ``d = x2 - (ax,
    ay)``; the wrench is a force (bfx, bfy) in link 2's frame at the tip and a couple ``couple`` about z: ``tau_ext =
    J^T (f_spring + R(t1 + t2) (bfx, bfy)) + couple (1, 1)``.
    """
    base = double_pendulum(m1=m1, m2=m2, l1=l1, l2=l2, g=g)
    tip = (0.0, -l2, 0.0)
    return _loaded("double_pendulum_spring", base,
                   [PointSpring("tip_spring", "link2", tip, (ax, ay, 0.0), k, rest),
                    ExternalWrench("motor_reaction", "link2", tip, (bfx, bfy, 0.0), (0.0, 0.0, couple), "body")])


@register
def n_link_pendulum(n: int = 5, m: float = 1.0, l: float = 1.0, g: float = 9.81,  # noqa: E741
                    a: float = 0.0) -> Model:
    """Planar chain of n equal point masses at the link ends, relative angles from hanging down (n >= 1).

    Body ``link{i}`` (i = 1..n) is placed at the previous link's end; task point ``tip`` is the last mass. ``a``
    (default 0): every joint's armature, a rotor's inertia on M's diagonal (``Body.armature``).
    """
    _require(isinstance(n, (int, np.integer)) and not isinstance(n, bool),
             f"n_link_pendulum: n must be an integer, got {n!r}")
    _require(1 <= n <= MAX_LINKS, f"n_link_pendulum: n (the number of links) must be from 1 to {MAX_LINKS}, got {n}")
    _positive("n_link_pendulum", m=m, l=l)
    bodies = []
    for i in range(1, n + 1):
        bodies.append(Body(f"link{i}", None if i == 1 else f"link{i - 1}", "revolute", _Z, m,
                           com=(0.0, -l, 0.0), translation=(0.0, 0.0, 0.0) if i == 1 else (0.0, -l, 0.0),
                           armature=a))
    return build_model("n_link_pendulum", bodies, gravity=(0.0, -g, 0.0),
                       task_points=[TaskPoint("tip", f"link{n}", (0.0, -l, 0.0), _PLANE)])


@register
def acrobot(m1: float = 1.0, m2: float = 1.0, l1: float = 1.0, l2: float = 2.0, lc1: float = 0.5,
            lc2: float = 1.0, I1: float = 0.083, I2: float = 0.33, g: float = 9.81, a1: float = 0.0,  # noqa: N803
            a2: float = 0.0) -> Model:
    """Spong's acrobot: two links with distributed inertia, only the elbow actuated (B = [[0], [1]]).

    Link i has its COM at distance lci along the link and rotational inertia Ii about the COM and the joint
    axis z (defaults: Spong 1995, uniform rods). The COM inertia tensor is that of a slender rod along the link
    (y): diag(Ii, 0, Ii), which is positive semi-definite and satisfies the triangle inequality. ``a1``, ``a2``
    (default 0): the joints' armature, a rotor's inertia on M's diagonal (``Body.armature``).
    Task point ``tip``: the end of link 2.
    """
    _positive("acrobot", m1=m1, m2=m2, l1=l1, l2=l2)
    bodies = [
        Body("link1", None, "revolute", _Z, m1, com=(0.0, -lc1, 0.0), inertia=np.diag([I1, 0.0, I1]), armature=a1),
        Body("link2", "link1", "revolute", _Z, m2, com=(0.0, -lc2, 0.0), inertia=np.diag([I2, 0.0, I2]),
             translation=(0.0, -l1, 0.0), armature=a2),
    ]
    return build_model("acrobot", bodies, gravity=(0.0, -g, 0.0), input_map=[[0.0], [1.0]],
                       task_points=[TaskPoint("tip", "link2", (0.0, -l2, 0.0), _PLANE)])


# --------------------------------------------------------------------------------------------- spatial

_S2 = np.sqrt(0.5)


@register
def spatial_arm() -> Model:
    """A fixed 3-D 6-joint arm (5 revolute + 1 prismatic) with skewed axes, rotated placements and full inertias.

    Deterministic, hard-coded numbers (masses 0.6-4 kg, links 0.1-0.35 m). Joint axes are pairwise
    non-parallel at q = 0 (one of them is (1, 1, 0)/sqrt 2 in its joint frame), every placement but the first
    has a non-identity rotation, every COM inertia is ``R diag(principal) R^T`` with off-diagonal terms, and
    the task point ``tip`` is offset from the last body's origin. Gravity (0, 0, -9.81).
    """
    bodies = [
        Body("base", None, "revolute", (0.0, 0.0, 1.0), 4.0,
             com=(0.01, -0.02, 0.06),
             inertia=_inertia((0.020, 0.024, 0.016), _rot((1.0, 2.0, 3.0), 0.4)),
             rotation=np.eye(3), translation=(0.0, 0.0, 0.10)),
        Body("shoulder", "base", "revolute", (0.0, 0.0, 1.0), 3.0,
             com=(0.12, 0.01, -0.02),
             inertia=_inertia((0.006, 0.030, 0.028), _rot((0.0, 1.0, 1.0), 0.3)),
             rotation=_rot((1.0, 0.0, 0.0), -np.pi / 2), translation=(0.02, 0.0, 0.15)),
        Body("upper_arm", "shoulder", "revolute", (_S2, _S2, 0.0), 2.5,
             com=(0.15, -0.01, 0.02),
             inertia=_inertia((0.004, 0.021, 0.019), _rot((2.0, -1.0, 1.0), 0.7)),
             rotation=_rot((0.0, 0.0, 1.0), 0.3), translation=(0.30, 0.0, 0.03)),
        Body("slider", "upper_arm", "prismatic", (1.0, 0.0, 0.0), 1.5,
             com=(0.08, 0.015, -0.01),
             inertia=_inertia((0.002, 0.009, 0.008), _rot((1.0, 1.0, -1.0), 0.5)),
             rotation=_rot((0.0, 1.0, 0.0), 0.2), translation=(0.25, 0.05, 0.0)),
        Body("wrist1", "slider", "revolute", (0.0, 1.0, 0.0), 1.0,
             com=(0.0, 0.04, 0.03),
             inertia=_inertia((0.0015, 0.0012, 0.0020), _rot((3.0, 1.0, 2.0), 0.9)),
             rotation=_rot((1.0, 0.0, 1.0), 0.6), translation=(0.18, 0.0, -0.02)),
        Body("wrist2", "wrist1", "revolute", (0.0, 0.0, 1.0), 0.6,
             com=(0.02, -0.01, 0.05),
             inertia=_inertia((0.0008, 0.0010, 0.0006), _rot((-1.0, 2.0, 0.5), 1.1)),
             rotation=_rot((1.0, -1.0, 0.0), 0.8), translation=(0.0, 0.10, 0.04)),
    ]
    return build_model("spatial_arm", bodies, gravity=(0.0, 0.0, -9.81),
                       task_points=[TaskPoint("tip", "wrist2", (0.03, -0.02, 0.12))])


# ------------------------------------------------------------------------------------------------- URDF

PANDA_URDF = "cmeel.prefix/share/example-robot-data/robots/panda_description/urdf/panda.urdf"


def panda_urdf_path():
    """Path of the Franka Panda URDF shipped by the ``example-robot-data`` package (v6 has no python module)."""
    return robot_data_path(PANDA_URDF, "panda")


def robot_data_path(relative: str, case: str):
    """Path of a file the ``example-robot-data`` package ships (``relative`` to its distribution), for case
    ``case``; ImportError / FileNotFoundError saying how to install it."""
    import importlib.metadata

    try:
        dist = importlib.metadata.distribution("example-robot-data")
    except importlib.metadata.PackageNotFoundError as exc:
        raise ImportError(f"the '{case}' case needs a URDF from the 'example-robot-data' package: "
                          "pip install example-robot-data") from exc
    path = dist.locate_file(relative)
    if not path.exists():
        raise FileNotFoundError(f"the '{case}' case: example-robot-data {dist.version} is installed but has no "
                                f"'{path}'; reinstall it (pip install --force-reinstall example-robot-data)")
    return path


@register
@loaded_from("example-robot-data's panda_description/urdf/panda.urdf")
def panda() -> Model:
    """Franka Emika Panda from example-robot-data's URDF via Pinocchio: 7 arm joints + 2 finger joints, the second
    finger coupled to the first by the URDF's ``<mimic>`` (a ``JointCoupling``, ``mimic:panda_finger_joint2``).

    Joint order is Pinocchio's; the default task point is ``panda_hand_tcp``.
    """
    from cases.urdf import from_urdf

    return from_urdf(panda_urdf_path(), name="panda", base="fixed")


# ------------------------------------------------------------------------------- 3-D cases with closed forms
# Each is built with the helpers above (``_rot``, ``_inertia``), so that a bug in them moves every backend together
# and only the case's closed form (``crosscheck.references.closed_forms``, computed from the typed parameters) sees it.


@register
def rotor(m: float = 2.0, cx: float = 0.3, cy: float = -0.1, cz: float = 0.2, Ia: float = 0.04, Ib: float = 0.06,
          Ic: float = 0.08, spin: float = 0.7, tilt: float = 0.5, azimuth: float = 0.3,
          g: float = 9.81) -> Model:  # noqa: N803
    """A 3-D rotor: one rigid body (offset COM, full rotated inertia) on a revolute joint about a tilted axis.

    The joint sits at the world origin; its axis is z turned by ``tilt`` about y, then by ``azimuth`` about z:
    a = (sin tilt cos azimuth, sin tilt sin azimuth, cos tilt). The COM is at (cx, cy, cz) in the body frame, the
    COM inertia is ``R diag(Ia, Ib, Ic) R^T`` with R the rotation by ``spin`` about (1, 1, 1). Gravity (0, 0, -g).
    Task point ``rim``: the body point (0.4, 0.1, -0.2), along world x.
    """
    _require(m > 0.0, f"rotor: m must be positive, got {m}")
    axis = _rot(_Z, azimuth) @ _rot((0.0, 1.0, 0.0), tilt) @ np.array(_Z)
    body = Body("rotor", None, "revolute", axis, m, com=(cx, cy, cz),
                inertia=_inertia((Ia, Ib, Ic), _rot((1.0, 1.0, 1.0), spin)))
    return build_model("rotor", [body], gravity=(0.0, 0.0, -g),
                       task_points=[TaskPoint("rim", "rotor", (0.4, 0.1, -0.2), ((1.0, 0.0, 0.0),))])


@register
def inclined_slider(m: float = 1.5, incline: float = 0.4, azimuth: float = 0.8, g: float = 9.81) -> Model:
    """A point mass on a prismatic joint along a tilted unit axis, under gravity (0, 0, -g).

    The joint frame is turned by ``incline`` about -y, then by ``azimuth`` about z, and the mass slides along its x
    axis: a = (cos incline cos azimuth, cos incline sin azimuth, sin incline), climbing at ``incline`` above the
    horizontal. Task point ``mass``: the mass, along world z (its height).
    """
    _require(m > 0.0, f"inclined_slider: m must be positive, got {m}")
    placement = _rot(_Z, azimuth) @ _rot((0.0, -1.0, 0.0), incline)
    body = Body("slider", None, "prismatic", (1.0, 0.0, 0.0), m, rotation=placement)
    return build_model("inclined_slider", [body], gravity=(0.0, 0.0, -g),
                       task_points=[TaskPoint("mass", "slider", (0.0, 0.0, 0.0), (_Z,))])


@register
def spherical_pendulum(m: float = 1.0, l: float = 1.0, Ix: float = 0.04, Iy: float = 0.05, Iz: float = 0.03,
                       g: float = 9.81) -> Model:  # noqa: E741, N803
    """A spherical pendulum: a ball on two perpendicular revolute joints (x, then the gimbal's y), hanging along -z.

    A massless gimbal turns about world x (q1) and carries the ball's joint about its own y (q2); the ball (mass m,
    principal inertia diag(Ix, Iy, Iz) about its centre in its body frame; Iz > 0 keeps M regular where the ball
    passes the x axis) hangs at (0, 0, -l) in its body frame: at (-l sin q2, l sin q1 cos q2, -l cos q1 cos q2).
    Gravity (0, 0, -g). Task point ``ball``: its centre, along world x and y.
    """
    _require(m > 0.0 and l > 0.0 and Iz > 0.0, f"spherical_pendulum: m, l and Iz must be positive, got {m}, {l}, {Iz}")
    bodies = [Body("gimbal", None, "revolute", (1.0, 0.0, 0.0), 0.0),
              Body("ball", "gimbal", "revolute", (0.0, 1.0, 0.0), m, com=(0.0, 0.0, -l), inertia=np.diag([Ix, Iy, Iz]))]
    return build_model("spherical_pendulum", bodies, gravity=(0.0, 0.0, -g),
                       task_points=[TaskPoint("ball", "ball", (0.0, 0.0, -l), _PLANE)])
