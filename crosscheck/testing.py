"""Hypothesis strategies and assertions for property tests of rigid-body dynamics code, yours or ours.

Draw random mechanisms and admissible states, and check that backends agree under the harness's tolerance policy::

    from hypothesis import given, settings, strategies as st
    from crosscheck import testing

    @settings(max_examples=50, deadline=None)
    @given(st.data())
    def test_my_backend_agrees(data):
        model = data.draw(testing.models(max_bodies=4))
        state = data.draw(testing.states(model))
        testing.assert_backends_agree(model, state, backends=["my_backend", "pinocchio"])

Strategies: :func:`models` (random kinematic trees, optionally constrained), :func:`states` (admissible
``crosscheck.core.sampling.State``), :func:`charts` (``crosscheck.checks.charts``), :func:`frames` (rigid transforms,
``crosscheck.checks.frames``), and the pieces they are built from (:func:`unit_vectors`, :func:`axes`,
:func:`rotations`, :func:`inertias`). Everything a failing example shrinks toward is the simplest mechanism of its kind:
fewer bodies, a serial chain, revolute joints about z, identity placements, point masses of 1 kg, round numbers, no
armature.

Assertions: :func:`assert_backends_agree` runs the gate's comparison at one state (and the chart, frame and
conservation checks); :func:`assert_split_close` compares two splits with the tolerance policy. Both raise
``AssertionError`` with every failing quantity, its error/tolerance ratio, the outlier and each backend's value.
"""

from __future__ import annotations

import dataclasses
import functools
from typing import Sequence

import numpy as np
import pinocchio as pin
from hypothesis import assume
from hypothesis import strategies as st

from cases import constraints as decl, loads as load_decl
from cases.build import build_model
from cases.model import JOINT_DOF, Body, Model, TaskPoint
from crosscheck import backends as backend_registry
from crosscheck.checks import charts as chart_catalog, frames as frame_tools
from crosscheck.core import sampling, tolerance
from crosscheck.core.compare import DISAGREE, compare, Comparison
from crosscheck.engine import evaluation
from crosscheck.engine.outcomes import StateOutcome
from crosscheck.references.pinocchio import build, kinematics
from formalisms.interface import Split

#: Drawn ranges. Lengths (placements, centres of mass, task offsets) within +-1 m and +-0.5 m; masses log-uniform
#: over four decades; radii of gyration 5-50 cm; gravity up to 20 m/s^2 per axis; constraint circles 0.1-1 m.
PLACEMENT_RANGE = 1.0
OFFSET_RANGE = 0.5
MASS_DECADES = (-2.0, 2.0)
GYRATION_RANGE = (0.05, 0.5)
GRAVITY_RANGE = 20.0
RADIUS_RANGE = (0.1, 1.0)
#: External loads (``cases.loads``) of drawn models: force and couple entries (N, N m), spring anchors (m), stiffness
#: decades (N/m) and rest lengths (m).
FORCE_RANGE = 20.0
COUPLE_RANGE = 5.0
ANCHOR_RANGE = 1.5
STIFFNESS_DECADES = (-1.0, 2.0)
REST_RANGE = (0.0, 0.5)
#: Drawn lengths below this (1 micrometre) are drawn as 0. Physically they are below any modelling precision, and
#: numerically a lever arm that small next to metre-scale placements is decided by rounding: a constraint point
#: 1e-38 m off a joint axis has a Jacobian row of 1e-38 in body-frame kinematics and exactly 0 in world-frame
#: kinematics, so the backends disagree on whether the constraint exists (see docs/campaigns.md).
MIN_LENGTH = 1e-6
#: Drawn direction components and state entries (angles, rates, inputs) below this in magnitude are drawn as 0:
#: below any sensor, actuator or machining resolution, they only probe floating-point underflow (a 1-row task
#: Jacobian of 1e-135 at q = 2e-135 rad overflows the operational-space backend's task inertia; see docs/campaigns.md).
MIN_VALUE = 1e-9
#: A projected state whose q moved more than this from the draw (in some coordinate) is rejected: Gauss–Newton left
#: the draw's neighbourhood (a revolute angle of -7.8e6 rad was seen), and the state is a far-off copy of one near it.
MAX_PROJECTION_STEP = 2.0 * np.pi
#: A point mass on a revolute joint sits at least this far from the joint axis; closer, the body gets a solid
#: inertia instead. Either way every joint moves some inertia along its own motion, so M is positive definite
#: (the shallowest moving joint always moves its own body), whatever the configuration.
MIN_ARM = 0.05
#: Principal moments of a solid body, in units of mass x gyration^2: the two first in [0.1, 1], the third between
#: their difference and their sum (the triangle inequality) and at least 0.1, so the inertia is positive definite.
MIN_MOMENT = 0.1

STANDARD_GRAVITY = (0.0, 0.0, -9.81)
_UNIT = {"z": (0.0, 0.0, 1.0), "x": (1.0, 0.0, 0.0), "y": (0.0, 1.0, 0.0)}


@functools.lru_cache(maxsize=None)
def _floats(low: float, high: float) -> st.SearchStrategy[float]:
    return st.floats(low, high, allow_nan=False, allow_infinity=False)


def _length(x: float) -> float:
    return 0.0 if abs(x) < MIN_LENGTH else x


def _value(x: float) -> float:
    return 0.0 if abs(x) < MIN_VALUE else x


@functools.lru_cache(maxsize=None)
def _values(low: float, high: float) -> st.SearchStrategy[float]:
    """Floats in ``[low, high]``, those below :data:`MIN_VALUE` in magnitude drawn as 0."""
    return _floats(low, high).map(_value)


@functools.lru_cache(maxsize=None)
def vectors(bound: float) -> st.SearchStrategy[np.ndarray]:
    """3-vectors with entries in ``[-bound, bound]`` (shrinking toward zero and round entries); entries below
    :data:`MIN_LENGTH` in magnitude are 0."""
    return st.tuples(*[_floats(-bound, bound).map(_length)] * 3).map(lambda v: np.array(v, dtype=float))


def _normalized(v) -> np.ndarray:
    v = np.array([_value(x) for x in v], dtype=float)
    norm = np.linalg.norm(v)
    return v / norm if norm > 1e-6 else np.array(_UNIT["z"])


@functools.lru_cache(maxsize=None)
def unit_vectors() -> st.SearchStrategy[np.ndarray]:
    """Random unit 3-vectors (a drawn vector, components below :data:`MIN_VALUE` zeroed, normalized; one too short
    to normalize stands for z)."""
    return st.tuples(*[_floats(-1.0, 1.0)] * 3).map(_normalized)


@functools.lru_cache(maxsize=None)
def axes() -> st.SearchStrategy[np.ndarray]:
    """Joint axes: z, x or y (shrinking toward z), or a random unit vector."""
    return st.one_of(st.sampled_from(list(_UNIT.values())).map(np.array), unit_vectors())


def _rodrigues(axis: np.ndarray, angle: float) -> np.ndarray:
    """Rotation by ``angle`` about the unit ``axis``: ``I + sin(a) K + (1 - cos(a)) K^2`` with ``K = [axis]x``."""
    K = np.array([[0.0, -axis[2], axis[1]], [axis[2], 0.0, -axis[0]], [-axis[1], axis[0], 0.0]])
    return np.eye(3) + np.sin(angle) * K + (1.0 - np.cos(angle)) * (K @ K)


@functools.lru_cache(maxsize=None)
def rotations() -> st.SearchStrategy[np.ndarray]:
    """Rotation matrices: the identity, a quarter turn about x, y or z (exact entries), or a random rotation
    (axis and angle in [-pi, pi]), in that shrinking order."""
    quarter = [np.rint(_rodrigues(np.array(a), s * np.pi / 2)) for a in _UNIT.values() for s in (1, -1)]
    return st.one_of(st.just(np.eye(3)), st.sampled_from(quarter),
                     st.builds(_rodrigues, unit_vectors(), _values(-np.pi, np.pi)))


def _unit_inertia(k: float, s1: float, s2: float, t: float, R: np.ndarray) -> np.ndarray:
    low, high = max(abs(s1 - s2), MIN_MOMENT), s1 + s2
    inertia = k * k * (R @ np.diag([s1, s2, low + t * (high - low)]) @ R.T)
    return 0.5 * (inertia + inertia.T)


@functools.lru_cache(maxsize=None)
def _unit_inertias() -> st.SearchStrategy[np.ndarray]:
    return st.builds(_unit_inertia, _floats(*GYRATION_RANGE), _floats(MIN_MOMENT, 1.0), _floats(MIN_MOMENT, 1.0),
                     _floats(0.0, 1.0), rotations())


def inertias(mass: float = 1.0) -> st.SearchStrategy[np.ndarray]:
    """Rotational inertias about the COM of a solid body of ``mass``: ``m k^2 R diag(s) R^T`` with the radius of
    gyration k in ``GYRATION_RANGE``, principal moments s satisfying the triangle inequality and each at least
    ``MIN_MOMENT`` (the third drawn between the bounds that leaves; positive definite), principal axes R a drawn
    rotation. Exactly symmetric."""
    return _unit_inertias().map(lambda inertia: mass * inertia)


def _arm(com: np.ndarray, axis: np.ndarray) -> float:
    """Distance of the COM from the joint axis through the body origin."""
    return float(np.linalg.norm(com - (com @ axis) * axis))


@functools.lru_cache(maxsize=None)
@st.composite
def _body(draw, i: int, group: bool = False) -> Body:
    """Body ``i``: parent the previous body (shrinking toward a serial chain), an earlier one, or the world. With
    ``group`` its joint may also be spherical, or free when it hangs from the world; a body on either is solid (a
    point mass at a ball joint's centre would not resist every rotation)."""
    back = draw(st.integers(0, i))
    parent = None if back == i else f"b{i - 1 - back}"
    kinds = ("revolute", "prismatic") + (("spherical", "free") if group and parent is None else
                                         ("spherical",) if group else ())
    joint = draw(st.sampled_from(kinds))
    axis = np.zeros(3) if joint in ("spherical", "free") else draw(axes())
    translation = draw(vectors(PLACEMENT_RANGE))
    rotation = draw(rotations())
    mass = float(10.0 ** draw(_floats(*MASS_DECADES)))
    com = draw(vectors(OFFSET_RANGE))
    solid = mass * draw(_unit_inertias())
    wants_solid = draw(st.booleans())
    point = not wants_solid and (joint == "prismatic" or joint == "revolute" and _arm(com, axis) >= MIN_ARM)
    return Body(f"b{i}", parent, joint, axis, mass, com=com, inertia=np.zeros((3, 3)) if point else solid,
                rotation=rotation, translation=translation)


@functools.lru_cache(maxsize=None)
def _input_maps(n: int) -> st.SearchStrategy:
    """B: identity (None), a selection of joints (possibly underactuated), or a dense n x m matrix."""
    selection = st.lists(st.integers(0, n - 1), min_size=1, max_size=n, unique=True).map(
        lambda cols: np.eye(n)[:, sorted(cols)])
    dense = st.integers(1, n).flatmap(
        lambda m: st.lists(st.lists(_values(-2.0, 2.0), min_size=m, max_size=m), min_size=n, max_size=n)).map(
        lambda rows: np.array(rows, dtype=float))
    return st.one_of(st.none(), selection, dense)


def _quaternion(x) -> list[float]:
    """A drawn 4-vector normalized (x, y, z, w); one too short to normalize stands for the identity."""
    v = np.array(x, dtype=float)
    norm = np.linalg.norm(v)
    return (v / norm).tolist() if norm > 1e-3 else [0.0, 0.0, 0.0, 1.0]


@functools.lru_cache(maxsize=None)
def quaternions() -> st.SearchStrategy[list[float]]:
    """Unit quaternions ``(x, y, z, w)``: a drawn 4-vector normalized (shrinking toward the identity)."""
    return st.tuples(*[_floats(-1.0, 1.0)] * 3, _floats(-1.0, 1.0).map(lambda w: 1.0 - w)).map(_quaternion)


def _joint_values(joint: str) -> st.SearchStrategy[list[float]]:
    """One joint's block of q over ``crosscheck.core.sampling``'s ranges (``cases.model`` conventions)."""
    d = sampling.DISPLACEMENT_RANGE
    if joint == "spherical":
        return quaternions()
    if joint == "free":
        return st.tuples(_values(-d, d), _values(-d, d), _values(-d, d), quaternions()).map(
            lambda x: [x[0], x[1], x[2], *x[3]])
    span = sampling.ANGLE_RANGE if joint == "revolute" else d
    return _values(-span, span).map(lambda x: [x])


def configurations(model: Model) -> st.SearchStrategy[np.ndarray]:
    """Configurations over ``crosscheck.core.sampling``'s ranges: one turn (revolute), +-0.5 m (prismatic, a free base's
    position), unit quaternions (spherical and free joints)."""
    return st.tuples(*[_joint_values(b.joint) for b in model.bodies]).map(
        lambda blocks: np.array([x for block in blocks for x in block], dtype=float))


def body_poses(model: Model, q) -> list[tuple[np.ndarray, np.ndarray]]:
    """World (rotation, origin) of every body frame at ``q``, from Pinocchio's forward kinematics (the reference,
    outside the backends under test)."""
    pm = build.to_pinocchio(model)
    data = pm.createData()
    ids = [pm.getJointId(b.name) for b in model.bodies]
    q_pin = np.zeros(pm.nq)
    for i, jid in enumerate(ids):
        nq = pm.joints[jid].nq
        q_pin[pm.joints[jid].idx_q:pm.joints[jid].idx_q + nq] = q[model.q_index[i]:model.q_index[i] + nq]
    pin.forwardKinematics(pm, data, q_pin)
    return [(np.array(data.oMi[jid].rotation), np.array(data.oMi[jid].translation)) for jid in ids]


@st.composite
def _task_point(draw, model: Model) -> TaskPoint:
    """A task point on a body (shrinking toward the last), with 1 to min(3, n) task directions."""
    count = len(model.bodies)
    body = model.bodies[count - 1 - draw(st.integers(0, count - 1))]
    offset = draw(vectors(OFFSET_RANGE))
    rows = draw(st.integers(1, min(3, model.n)))
    return TaskPoint("tip", body.name, offset, draw(rotations())[:rows])


def _point(poses, i: int, offset: np.ndarray) -> np.ndarray:
    R, origin = poses[i]
    return R @ offset + origin


@st.composite
def _constraint(draw, model: Model, q0: np.ndarray, poses, budget: int, name: str, pfaffian: bool = False):
    """One declaration that holds at ``q0`` (where the bodies have ``poses``), with at most ``budget`` rows; with
    ``pfaffian`` also velocity-only declarations (a knife edge, a point velocity, a rolling contact), which hold at
    every configuration."""
    scalar = [j for j, b in enumerate(model.bodies) if b.joint in ("revolute", "prismatic")]
    kinds = (["JointCoupling"] if scalar else []) + ["PointsCoincide", "PointOnCircle", "PointOnLine"]
    if pfaffian:
        kinds += ["KnifeEdge", "PointVelocity"] + (["RollingContact"] if budget >= 2 else [])
    kind = draw(st.sampled_from(kinds))
    names = [b.name for b in model.bodies]
    a = draw(st.integers(0, len(model.bodies) - 1))
    offset = draw(vectors(OFFSET_RANGE))
    p = _point(poses, a, offset)
    frame = draw(rotations())
    if kind in ("KnifeEdge", "PointVelocity", "RollingContact"):
        return _pfaffian_declaration(draw, kind, name, names[a], offset, frame, budget)
    if kind == "JointCoupling":   # couples joint values: revolute and prismatic joints only
        a = a if a in scalar else scalar[a % len(scalar)]       # no extra draw: scalar-only models draw as before
        others = [j for j in scalar if j != a]
        joints = [a] + (draw(st.lists(st.sampled_from(others), max_size=1)) if others else [])
        coefficients = [draw(st.sampled_from((1.0, -1.0, 2.0, 0.5))) for _ in joints]
        return decl.JointCoupling(name, tuple(names[j] for j in joints), tuple(coefficients),
                                  float(sum(c * q0[model.q_index[j]] for c, j in zip(coefficients, joints))))
    if kind == "PointsCoincide":
        other = draw(st.sampled_from([None] + [j for j in range(len(model.bodies)) if j != a]))
        rows = draw(st.integers(1, min(3, budget)))
        if other is None:
            return decl.PointsCoincide(name, names[a], offset, None, p, frame[:rows])
        R_b, origin_b = poses[other]
        return decl.PointsCoincide(name, names[a], offset, names[other], R_b.T @ (p - origin_b), frame[:rows])
    if kind == "PointOnCircle":
        radius, angle = draw(_floats(*RADIUS_RANGE)), draw(_values(-np.pi, np.pi))
        plane = frame[:2]
        center = p - radius * (np.cos(angle) * plane[0] + np.sin(angle) * plane[1])
        return decl.PointOnCircle(name, names[a], offset, center, radius, plane)
    rows = draw(st.integers(1, min(2, budget)))
    return decl.PointOnLine(name, names[a], offset, p, frame[:rows])


def _pfaffian_declaration(draw, kind: str, name: str, body: str, offset: np.ndarray, frame: np.ndarray, budget: int):
    """A Pfaffian declaration on ``body`` (``cases.constraints``): a knife edge at ``offset`` across a drawn body
    direction, a point velocity along 1 to 3 drawn world directions, or a disk of drawn radius centred at ``offset``
    with a drawn axle rolling on a drawn plane (its axle never along the plane's normal: the third row of ``frame``
    is the normal, the axle mixes the first and the normal), its rows drawn both ways: along both tangents or along
    the rolling direction only (``lateral``)."""
    if kind == "KnifeEdge":
        return decl.KnifeEdge(name, body, offset, frame[0])
    if kind == "PointVelocity":
        return decl.PointVelocity(name, body, offset, frame[:draw(st.integers(1, min(3, budget)))])
    tilt = draw(_values(-1.2, 1.2))
    axle = np.cos(tilt) * frame[0] + np.sin(tilt) * frame[2]
    return decl.RollingContact(name, body, offset, axle / np.linalg.norm(axle), draw(_floats(*RADIUS_RANGE)),
                               frame[:2], draw(st.booleans()))


@st.composite
def _constraints(draw, model: Model, required: bool, pfaffian: bool = False) -> list:
    """Declarations that hold at a drawn reference configuration q0 (placed with Pinocchio's forward kinematics
    there: the circle, line or pin through the point's position at q0), with fewer rows than joints."""
    q0 = draw(configurations(model))
    poses = body_poses(model, q0)
    out: list = []
    budget = model.n - 1
    while budget > 0 and (draw(st.booleans()) or (required and not out)):
        c = draw(_constraint(model, q0, poses, budget, f"c{len(out)}", pfaffian))
        out.append(c)
        budget -= c.size
    return out


@st.composite
def _load(draw, model: Model, name: str):
    """One external load on a drawn body at a drawn offset: a force or a wrench in the world or the body frame, or a
    spring to a drawn world anchor (stiffness log-uniform over :data:`STIFFNESS_DECADES`, rest length 0 or drawn)."""
    body = model.bodies[draw(st.integers(0, len(model.bodies) - 1))].name
    offset = draw(vectors(OFFSET_RANGE))
    kind = draw(st.sampled_from(["force", "wrench", "spring"]))
    if kind == "spring":
        rest = draw(st.one_of(st.just(0.0), _floats(*REST_RANGE)))
        stiffness = 10.0 ** draw(_floats(*STIFFNESS_DECADES))
        return load_decl.PointSpring(name, body, offset, draw(vectors(ANCHOR_RANGE)), stiffness, rest)
    frame = draw(st.sampled_from(load_decl.FRAMES))
    force = draw(vectors(FORCE_RANGE))
    if kind == "wrench":
        return load_decl.ExternalWrench(name, body, offset, force, draw(vectors(COUPLE_RANGE)), frame)
    return load_decl.ExternalForce(name, body, offset, force, frame)


@st.composite
def models(draw, max_bodies: int = 5, constraints: bool | None = False, min_bodies: int = 1,
           name: str = "drawn", group: bool = False, loads: bool | None = False, pfaffian: bool = False,
           armature: bool | None = None) -> Model:
    """Random valid models: kinematic trees of ``min_bodies`` to ``max_bodies`` bodies.

    Each body hangs from the previous one, an earlier one or the world, by a revolute or prismatic joint about an
    axis-aligned or random unit axis, at a drawn placement (translation, rotation); its mass is log-uniform over
    ``MASS_DECADES``, its COM offset drawn, its inertia a point mass or a random positive definite one (see
    :data:`MIN_ARM`: M is positive definite everywhere). Gravity is standard or random, B the identity, a selection
    of joints or a dense matrix (possibly underactuated), the task point on a drawn body with 1-3 task directions.

    ``group``: joints may also be spherical, and free where a body hangs from the world (configurations on SO(3) and
    SE(3): ``cases.model``).

    ``constraints``: False none, True at least one, None either. Declarations (joint couplings, points coinciding
    with another body's point or pinned to the world, points on circles and lines) are placed so that a drawn
    configuration satisfies them, with fewer rows than joints; ``states`` then finds admissible states.
    ``pfaffian``: the declarations may also be Pfaffian (knife edges, point velocities, rolling contacts; mixed with
    the holonomic ones), which leave the configuration free and restrict the velocities.

    ``loads``: external loads (``cases.loads``, :func:`_load`): False none, True one or two, None either (drawn
    last, so the rest of a model is drawn as without them).

    ``armature``: the joints' armature (``Body.armature``, a rotor's inertia on M's diagonal, :func:`_armature`):
    False none, True on some joints, None (the default) on some joints of one model in four; drawn after everything
    else, so the rest of a model is drawn as without it, and shrinking toward none.
    """
    if constraints and max_bodies < 2:
        raise ValueError("models(constraints=True) needs max_bodies >= 2 (a constraint leaves fewer rows than joints)")
    low = max(min_bodies, 2) if constraints else min_bodies
    n = draw(st.integers(low, max_bodies))
    bodies = [draw(_body(i, group)) for i in range(n)]
    gravity = draw(st.one_of(st.just(np.array(STANDARD_GRAVITY)), vectors(GRAVITY_RANGE)))
    input_map = draw(_input_maps(sum(JOINT_DOF[b.joint][1] for b in bodies)))
    base = build_model(name, bodies, gravity=gravity, input_map=input_map)
    task = draw(_task_point(base))
    wanted = draw(st.booleans()) if constraints is None else constraints
    declared = draw(_constraints(base, constraints is True, pfaffian)) if wanted and n >= 2 else []
    loaded = draw(st.booleans()) if loads is None else loads
    applied = [draw(_load(base, f"load{i}")) for i in range(draw(st.integers(1, 2)))] if loaded else []
    armed = draw(st.integers(0, 3)) == 3 if armature is None else armature
    if armed:
        bodies = draw(_armature(bodies, at_least_one=armature is True))
    return build_model(name, bodies, gravity=gravity, input_map=input_map, task_points=[task], constraints=declared,
                       loads=applied)


#: The armature :func:`models` draws, relative to the body's mass (kg m^2 per kg for a revolute or spherical joint, kg
#: per kg for a prismatic one): log-uniform over these decades, from a rotor far lighter than its link to one as heavy
#: (a geared motor's reflected inertia can exceed the link's own).
ARMATURE_DECADES = (-3.0, 0.5)


@st.composite
def _armature(draw, bodies: list[Body], at_least_one: bool = False) -> list[Body]:
    """``bodies`` with an armature drawn for each joint but a free one (which has none: ``cases.build``): 0 (shrinking
    toward it) or ``mass 10^e`` with e in :data:`ARMATURE_DECADES`; ``at_least_one``: a first joint that can have one
    always does."""
    out, first = [], at_least_one
    for b in bodies:
        if b.joint == "free":
            out.append(b)
            continue
        value = _floats(*ARMATURE_DECADES).map(lambda e, m=b.mass: m * 10.0 ** e)
        a = draw(value if first else st.one_of(st.just(0.0), value))
        first = False
        out.append(dataclasses.replace(b, armature=a))
    return out


#: A drawn state whose rolling disk is flatter than this (the sine of its axle against the ground normal) is rejected:
#: a disk lying flat has no contact point, and near it the rows are ill-conditioned by ``1 / sine^2``.
MIN_CONTACT_SINE = 1e-3


@st.composite
def states(draw, model: Model, index: int = 0) -> sampling.State:
    """Admissible states of ``model`` over ``crosscheck.core.sampling``'s ranges (positions one turn or +-0.5 m, rates,
    inputs), a joint with limits (``Body.limits``: a model from a file; :func:`models` draws none) within them as the
    gate draws it (``sampling.within_limits``). A constrained model's q is projected onto ``phi(q) = 0`` and qd onto
    ``Jc qd = 0`` (``sampling.project_configuration`` / ``project_velocity``); a draw the projection cannot bring onto
    the manifold, or moves more than :data:`MAX_PROJECTION_STEP` to get there, or leaves a rolling disk flatter than
    :data:`MIN_CONTACT_SINE`, is rejected (``hypothesis.assume``).
    Entries below :data:`MIN_VALUE` in magnitude are drawn as 0."""
    drawn = sampling.within_limits(model, draw(configurations(model)))
    qd = np.array(draw(st.tuples(*[_values(-sampling.RATE_RANGE, sampling.RATE_RANGE)] * model.n)), dtype=float)
    u = np.array(draw(st.tuples(*[_values(-sampling.INPUT_RANGE, sampling.INPUT_RANGE)] * model.m)), dtype=float)
    q = drawn
    if model.constraints:
        try:
            q = sampling.project_configuration(model, drawn)
        except sampling.ProjectionError:
            assume(False)
        assume(np.abs(q - drawn).max() <= MAX_PROJECTION_STEP)
        assume(not len(kinematics.contact_sines(model, q)) or kinematics.contact_sines(model, q).min() > MIN_CONTACT_SINE)
        qd = sampling.project_velocity(model, q, qd)
    return sampling.State(index, tuple(q.tolist()), tuple(qd.tolist()), tuple(u.tolist()))


def chart_names(model: Model) -> list[str]:
    """The built-in charts that apply to ``model``: identity, nonlinear, affine, and absolute for a planar chain; for a
    model with spherical or free joints identity (q itself), zyx (Euler angles: ``crosscheck.checks.charts.EulerZYX``),
    exp (exponential coordinates about a centre drawn from the seed:
    ``crosscheck.checks.charts.ExponentialCoordinates``) and the velocity representations world and mixed (mixed only
    with a free joint: ``charts.representations_sampled``)."""
    if not chart_catalog.applies(model):
        return ["identity", *chart_catalog.GROUP_CHARTS] + [c.name for c in chart_catalog.representations_sampled(model)]
    return [name for name in ("identity", "nonlinear", "affine", "absolute")
            if name != "absolute" or chart_catalog.is_planar_serial(model)]


def chart_specs(model: Model) -> st.SearchStrategy[tuple[str, int]]:
    """(chart name, seed) pairs; ``crosscheck.checks.charts.get(name, model, seed)`` makes the chart."""
    return st.tuples(st.sampled_from(chart_names(model)), st.integers(0, 2**31 - 1))


def charts(model: Model) -> st.SearchStrategy[chart_catalog.Chart]:
    """Built-in charts of ``model`` (shrinking toward the identity; the affine one drawn from a seed)."""
    return chart_specs(model).map(lambda spec: chart_catalog.get(spec[0], model, spec[1]))


def frames(name: str = "g", reach: float = 1.0) -> st.SearchStrategy[frame_tools.Frame]:
    """Rigid transforms: a drawn rotation and a translation within +-``reach`` m per axis."""
    return st.builds(frame_tools.Frame, st.just(name), rotations(), vectors(reach))


# ------------------------------------------------------------------------------------------------ assertions


def _format(value) -> str:
    arr = np.atleast_1d(np.asarray(value, dtype=float))
    return np.array2string(arr, precision=9, max_line_width=10_000, separator=", ")


def failing(outcome: StateOutcome) -> dict[str, Comparison]:
    """The comparisons and checks of ``outcome`` that DISAGREE, by key."""
    everything = {**outcome.comparisons, **outcome.checks}
    return {key: c for key, c in everything.items() if c.verdict == DISAGREE}


def describe_comparison(key: str, c: Comparison) -> list[str]:
    """A failing comparison as lines: key, ratio, tolerance, outlier, then each voter's value."""
    outlier = f", outlier {c.outlier}" if c.outlier else ", no single outlier"
    lines = [f"{key}: DISAGREE, error/tolerance {c.worst_ratio:.3g} (tolerance {c.tolerance:.3g}){outlier}"]
    lines += [f"    {voter}: {_format(value)}" for voter, value in c.values.items()]
    return lines


def describe_failure(outcome: StateOutcome) -> str:
    """Every failing comparison and backend error of ``outcome``, one block each."""
    s = outcome.state
    lines = [f"at q = {list(s.q)}, qd = {list(s.qd)}, u = {list(s.u)}:"]
    for key, c in failing(outcome).items():
        lines += describe_comparison(key, c)
    lines += [f"{name} raised {message}" for name, message in outcome.errors.items()]
    return "\n".join(lines)


def assert_backends_agree(model: Model, state: sampling.State, backends: Sequence[str] | None = None,
                          chart: chart_catalog.Chart | None = None, frame: frame_tools.Frame | None = None,
                          conservation: bool = True) -> StateOutcome:
    """Evaluate ``backends`` (names; default every one in ``crosscheck.backends``) at ``state`` as the gate does
    (``crosscheck.engine.evaluation.evaluate``), with the chart check in ``chart``, the frame check on the scene moved
    by ``frame`` and the conservation checks when asked (``gate.add_checks``). Returns the outcome; raises
    AssertionError listing each disagreement (quantity, error/tolerance ratio, tolerance, outlier, values) and each
    backend error.

        >>> model = cases.load("double_pendulum")
        >>> state = sampling.State(0, (0.3, -0.2), (1.0, 0.5), (2.0, -1.0))
        >>> testing.assert_backends_agree(model, state, chart=charts.get("absolute", model))
    """
    chosen = [backend_registry.get(name) for name in (backends or backend_registry.names())]
    outcome = evaluation.evaluate(model, state, chosen)
    scene = None if frame is None else (frame, frame_tools.move_scene(model, frame))
    evaluation.add_checks(model, outcome, chosen, [] if chart is None else [chart], scene, conservation)
    if outcome.failed:
        raise AssertionError(f"backends {[b.name for b in chosen]} disagree on model '{model.name}' "
                             + describe_failure(outcome))
    return outcome


def assert_split_close(a: Split, b: Split, model: Model, q, qd, names: tuple[str, str] = ("a", "b"), u=None) -> None:
    """Compare two splits of ``model`` at ``(q, qd)`` quantity by quantity (``crosscheck.core.tolerance.quantities``)
    with the harness's tolerance policy (scales from both splits, and from the inputs ``u`` when given; quantities
    with an exact value also against it).
    The splits are compared as given (a BREAKDOWN is not looked at). Raises AssertionError naming each quantity
    that differs, with the ratio, the tolerance and both values.

        >>> a = formalisms.get("newton_euler").split(model, q, qd, u)
        >>> testing.assert_split_close(a, my_split(model, q, qd, u), model, q, qd, names=("newton_euler", "mine"))
    """
    at = tolerance.scales([a, b], model, np.asarray(q, dtype=float), np.asarray(qd, dtype=float), u=u)
    bad = []
    for quantity in tolerance.quantities(model):
        values = {names[0]: a.quantity(quantity), names[1]: b.quantity(quantity)}
        if quantity in tolerance.EXACT:
            values["exact"] = tolerance.EXACT[quantity]
        c = compare(quantity, values, tolerance.tolerance(quantity, at))
        if c.verdict == DISAGREE:
            bad += describe_comparison(quantity, c)
    if bad:
        raise AssertionError(f"splits {names[0]} and {names[1]} of model '{model.name}' differ at q = {list(q)}, "
                             f"qd = {list(qd)}:\n" + "\n".join(bad))
