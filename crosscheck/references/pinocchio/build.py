"""The Pinocchio model the reference evaluates (docs/design.md: kept apart from the five formalisms), and how our
coordinates map onto it.

Which Pinocchio model
---------------------
* A model loaded from a file (``model.source``, a :class:`cases.model.ModelSource`: URDF or MJCF) is checked
  against a ``pinocchio.Model`` the reference builds **from the file itself** (``cases.urdf.read_file``, the loader's
  call: ``pinocchio.buildModelFromUrdf(path)``, with a free-flyer root joint for a source whose root is "free", or
  ``pinocchio.buildModelFromMJCF(path)``), with the source's world placement ``g = (R, t)`` applied to the joints
  hanging from the universe (``g * placement``) and to gravity (``R @`` the file's gravity). Nothing of our
  conversion's bodies is read: not their placements, axes, masses, centres of mass or inertias, nor our gravity. From
  our model it takes only what a state means and what is asked: the coordinate order (by body name, the explicit
  joint map below), the input map B, the task point (by name; see :func:`_task_frame`) and its directions, and
  the constraint declarations. Armature (rotor inertia on M's diagonal) is the file's as Pinocchio's parser reads it
  (an MJCF ``<joint armature>``), and for the joints the user declared it for when loading (``ModelSource.armature``:
  a URDF has no tag for it) that value, set by joint name after reading the file (:func:`_declared_armature`); never
  our bodies' ``armature``. A bug in our URDF or MJCF conversion then moves the five formalisms and not the
  reference, and the vote names the reference as the outlier. The file's ``<mimic>`` tags (Pinocchio is asked to
  ignore them) are read from the XML here too: each must be declared on the model as the loader's coupling
  ``mimic:<joint>`` of the two joints the joint map gives, else the reference refuses the model
  (:func:`_check_mimics`), so a mimic the conversion drops, invents or attaches to another joint is not voted on.
  The joint limits, which bound the states the gate samples and enter no equation, are read from the file apart
  from the loader by ``crosscheck.guards.file_limits`` (through this joint map), and the coverage judges the sample
  against them: a limit the conversion misreads is a loader finding there.
* A model without a source (factories, fuzz, a moved copy built in code) is checked against a ``pinocchio.Model``
  built from OUR model data (:func:`to_pinocchio`): joints added in a depth-first order of ``model.bodies``,
  each with its placement, axis and inertia, and ``model.armature`` from each body's ``armature``.
The joint map (file-built reference)
------------------------------------
Our coordinate ``i`` belongs to body ``model.bodies[i].name``, which the loader names after the URDF link the joint
moves. :func:`joint_map` finds that link's BODY frame in the file-built model, checks that it hangs directly from
a joint's JOINT frame (not welded to another link by a fixed joint), and maps the coordinate to that joint: its
``idx_q``, ``idx_v`` and ``nq`` (2 for a URDF ``continuous`` joint, which Pinocchio stores as ``(cos q, sin q)``),
sign +1 (our ``q_i`` is the URDF joint position). A link that is not in the file, a joint with ``nv != 1``, two
coordinates on one joint or a joint left without a coordinate is a ValueError naming the body and the file, never
a guess.

States and results are permuted (and continuous joints mapped to ``(cos q, sin q)``) in and out by :func:`ours` and
:func:`ours_matrix`, so callers always use our coordinate order.
"""

from __future__ import annotations

import threading
import xml.etree.ElementTree as ET
from dataclasses import dataclass
from typing import NamedTuple

import numpy as np
import pinocchio as pin

from cases.constraints import JointCoupling, PointOnCircle, PointOnLine, PointsCoincide
from cases.model import GROUP_JOINTS, JOINT_DOF, Model, ModelSource
from cases.urdf import read_file
from formalisms.interface import DEGENERATE_ROW


_ALIGNED = {
    ("revolute", 0): pin.JointModelRX, ("revolute", 1): pin.JointModelRY, ("revolute", 2): pin.JointModelRZ,
    ("prismatic", 0): pin.JointModelPX, ("prismatic", 1): pin.JointModelPY, ("prismatic", 2): pin.JointModelPZ,
}
_UNALIGNED = {"revolute": pin.JointModelRevoluteUnaligned, "prismatic": pin.JointModelPrismaticUnaligned}
#: Pinocchio joint types stored as ``(cos q, sin q)`` (URDF ``continuous``), by short name.
_UNBOUNDED = ("JointModelRUBX", "JointModelRUBY", "JointModelRUBZ", "JointModelRevoluteUnboundedUnaligned")


class JointMapRow(NamedTuple):
    """Our body ``coordinate`` (its index; with revolute and prismatic joints only, the index of its coordinate),
    named ``body``, moves by the file's joint ``joint``: Pinocchio's configuration entries ``idx_q .. idx_q + nq - 1``
    (``nq`` 2 for a one-coordinate joint: ``(cos q, sin q)``; 4 and 7 for a spherical and a free joint, their
    quaternion blocks as ours) and velocities from ``idx_v``. ``sign`` is +1 for
    every row: the loader keeps each URDF joint's direction, so our ``q_i`` is the joint's position as it is."""

    coordinate: int
    body: str
    joint: str
    idx_q: int
    idx_v: int
    nq: int
    sign: int


@dataclass(frozen=True)
class _Scales:
    """The model sizes the definitions of the conditions use, read from the model the reference was built from:
    total mass, length scale ``1 + sum |placement translation| + |COM|``, inertia scale ``sum m L^2 + tr I`` (as
    ``cases.model.Model.length_scale`` / ``inertia_scale`` define them) and gravity."""

    mass: float
    length: float
    inertia: float
    gravity: np.ndarray

    @property
    def degenerate_floor(self) -> float:
        """The smallest eigenvalue of ``J M^-1 J^T`` that is a direction and not rounding: ``(DEGENERATE_ROW L)^2 /
        inertia scale`` (``formalisms.interface.DEGENERATE_ROW``)."""
        return (DEGENERATE_ROW * self.length) ** 2 / self.inertia


@dataclass(frozen=True)
class Compiled:
    """A Pinocchio model the reference evaluates (from the file or from our data) and how our coordinates, bodies,
    task point and constrained points map onto it."""

    model: pin.Model
    order: np.ndarray   # order[k] = our index of Pinocchio's k-th velocity
    plain: tuple        # (idx_q, our coordinate) arrays of the one-number configurations
    circle: tuple       # (idx_q, our coordinate) arrays of the (cos q, sin q) configurations
    joint_of: dict      # our body name -> Pinocchio joint id
    task_frame: int     # frame id of the model's default task point
    points: dict        # (body name, offset tuple) -> frame id of each constrained body point
    scales: _Scales
    joint_map: tuple[JointMapRow, ...] | None  # the file-built reference's map; None when built from our data
    body_of_joint: dict  # Pinocchio joint id -> our body index

    def configuration(self, q: np.ndarray) -> np.ndarray:
        """Pinocchio's configuration(s) of our ``q`` (n,) or (N, n): (nq,) or (N, nq)."""
        out = np.empty(q.shape[:-1] + (self.model.nq,))
        out[..., self.plain[0]] = q[..., self.plain[1]]
        out[..., self.circle[0]] = np.cos(q[..., self.circle[1]])
        out[..., self.circle[0] + 1] = np.sin(q[..., self.circle[1]])
        return out


_CACHE: dict[tuple, Compiled] = {}
LOCK = threading.Lock()


# ------------------------------------------------------------------------------------ built from our data


def _joint_model(joint: str, axis: np.ndarray):
    if joint == "spherical":
        return pin.JointModelSpherical()
    if joint == "free":
        return pin.JointModelFreeFlyer()
    for k in range(3):
        unit = np.zeros(3)
        unit[k] = 1.0
        if np.array_equal(axis, unit):
            return _ALIGNED[(joint, k)]()
    return _UNALIGNED[joint](np.array(axis, dtype=float))


def _depth_first(model: Model) -> list[int]:
    """The bodies in depth-first pre-order (each subtree contiguous, children in the model's order). Pinocchio's
    algorithms that walk subtree ranges (computeMinverse, CRBA) need joints added in this order; a merely
    parents-first order gave a wrong M^-1 on branched trees."""
    children: dict[int, list[int]] = {}
    for i in model.topological_order:
        children.setdefault(int(model.parent_index[i]), []).append(i)
    order, stack = [], list(reversed(children.get(-1, [])))
    while stack:
        i = stack.pop()
        order.append(i)
        stack.extend(reversed(children.get(i, [])))
    return order


def _inertia(body) -> "pin.Inertia":
    """The body's spatial inertia as given, as Pinocchio's URDF parser keeps a file's (its checked constructor refuses
    a principal moment of -1e-20, rounding that ``cases.build`` accepts: ``INERTIA_ROUNDING``)."""
    inertia = pin.Inertia.Zero()
    inertia.mass, inertia.lever, inertia.inertia = float(body.mass), np.array(body.com), np.array(body.inertia)
    return inertia


def _build_from_data(model: Model) -> Compiled:
    """The reference of a model without a file source: a Pinocchio model of our bodies (module docstring)."""
    pm = pin.Model()
    pm.name = model.name
    joint_id = {}
    for i in _depth_first(model):
        b = model.bodies[i]
        parent = 0 if model.parent_index[i] < 0 else joint_id[model.parent_index[i]]
        placement = pin.SE3(np.array(b.rotation), np.array(b.translation))
        jid = pm.addJoint(parent, _joint_model(b.joint, b.axis), placement, b.name)
        pm.appendBodyToJoint(jid, _inertia(b), pin.SE3.Identity())
        joint_id[i] = jid
    armature = np.zeros(pm.nv)      # Pinocchio's own armature: crba, rnea, aba, computeMinverse, the kinetic energy
    for i, jid in joint_id.items():  # and the ABA derivatives honour it (4.1, checked in tests/references)
        armature[pm.joints[jid].idx_v:pm.joints[jid].idx_v + pm.joints[jid].nv] = model.bodies[i].armature
    pm.armature = armature
    pm.gravity = pin.Motion(np.array(model.gravity), np.zeros(3))
    order, q_pin, q_ours = np.empty(model.nv, dtype=int), np.empty(model.nq, dtype=int), np.empty(model.nq, dtype=int)
    for i, jid in joint_id.items():     # joint blocks map as wholes: same conventions (cases.model)
        joint = pm.joints[jid]
        order[joint.idx_v:joint.idx_v + joint.nv] = model.v_index[i] + np.arange(joint.nv)
        q_pin[joint.idx_q:joint.idx_q + joint.nq] = np.arange(joint.idx_q, joint.idx_q + joint.nq)
        q_ours[joint.idx_q:joint.idx_q + joint.nq] = model.q_index[i] + np.arange(joint.nq)
    joint_of = {model.bodies[i].name: jid for i, jid in joint_id.items()}
    tp = model.task_point()
    task_frame = _add_point_frame(pm, f"task:{tp.name}", joint_of[tp.body], tp.offset)
    scales = _Scales(float(sum(b.mass for b in model.bodies)), model.length_scale, model.inertia_scale,
                     np.array(model.gravity))
    return Compiled(pm, order, (q_pin, q_ours), (np.zeros(0, int), np.zeros(0, int)), joint_of,
                     task_frame, _constraint_frames(pm, model, joint_of), scales, None,
                     {jid: i for i, jid in joint_id.items()})


def _add_point_frame(pm: pin.Model, name: str, joint: int, offset) -> int:
    """A frame on joint ``joint`` at ``offset`` in its frame (no rotation); returns its id."""
    return pm.addFrame(pin.Frame(name, joint, pin.SE3(np.eye(3), np.array(offset, dtype=float)),
                                 pin.FrameType.OP_FRAME))


def _constraint_frames(pm: pin.Model, model: Model, joint_of: dict) -> dict:
    """A frame for each constrained body point of the declarations, on the body's joint: (body, offset) -> id."""
    points = {}
    for c in model.constraints:
        for body, offset in _constrained_points(c):
            if body is not None and (body, tuple(offset)) not in points:
                points[(body, tuple(offset))] = _add_point_frame(pm, f"constraint:{c.name}:{len(points)}",
                                                                 joint_of[body], offset)
    return points


def _constrained_points(c) -> list:
    """The (body, offset) points a declaration constrains; body None is a world point."""
    if isinstance(c, PointsCoincide):
        return [(c.body_a, c.offset_a), (c.body_b, c.offset_b)]
    if isinstance(c, (PointOnCircle, PointOnLine)):
        return [(c.body, c.offset)]
    return []


# ----------------------------------------------------------------------------------------- built from the file


def _parent_joint(frame) -> int:
    """The joint a frame is attached to (Pinocchio >= 3.1: ``parentJoint``; older: ``parent``)."""
    return int(frame.parentJoint if hasattr(frame, "parentJoint") else frame.parent)


def _parent_frame(frame) -> int:
    """The frame this one hangs from (Pinocchio >= 3.1: ``parentFrame``; older: ``previousFrame``)."""
    return int(frame.parentFrame if hasattr(frame, "parentFrame") else frame.previousFrame)


def _read_file(source: ModelSource) -> pin.Model:
    """The file's Pinocchio model (``cases.urdf.read_file``: ``buildModelFromUrdf``, with a free-flyer root joint when
    the source's root is "free", or ``buildModelFromMJCF``) placed in the model's world by the source's ``g = (R,
    t)``: root joint placements and the frames on the universe ``g * X``, gravity ``R g_file`` (zero for a source
    without gravity, ``ModelSource.without_gravity``)."""
    try:
        pm = read_file(pin, source.kind, source.path, source.root)
    except Exception as exc:  # noqa: BLE001 - Pinocchio raises ValueError/RuntimeError/... for bad files
        raise ValueError(f"the reference cannot read '{source.path}', the {source.kind.upper()} file the model was "
                         f"loaded from: {exc}") from exc
    R, t = np.array(source.rotation), np.array(source.translation)
    for j in range(1, pm.njoints):
        if pm.parents[j] == 0:
            X = pm.jointPlacements[j]
            pm.jointPlacements[j] = pin.SE3(R @ X.rotation, R @ X.translation + t)
    for k in range(len(pm.frames)):
        frame = pm.frames[k]
        if _parent_joint(frame) == 0:
            frame.placement = pin.SE3(R @ frame.placement.rotation, R @ frame.placement.translation + t)
            pm.frames[k] = frame
    pm.gravity = pin.Motion(R @ np.array(pm.gravity.linear) if source.gravity else np.zeros(3), np.zeros(3))
    _declared_armature(pm, source)
    return pm


def _declared_armature(pm: pin.Model, source: ModelSource) -> None:
    """Set the armature the user declared for the file's joints (``ModelSource.armature``: a URDF cannot say it) on
    each named joint's velocities, by the joint's name in the file; the file's own (an MJCF ``<joint armature>``) is
    what Pinocchio's parser read. A name that is no joint of the file is a ValueError."""
    if not source.armature:
        return
    armature = np.array(pm.armature, dtype=float)
    for name, value in source.armature:
        if not pm.existJointName(name):
            raise ValueError(f"the reference cannot set the armature of joint '{name}': '{source.path}' has no such "
                             f"joint (its joints: {list(pm.names)[1:]})")
        joint = pm.joints[pm.getJointId(name)]
        armature[joint.idx_v:joint.idx_v + joint.nv] = float(value)
    pm.armature = armature


def _moving_joint(pm: pin.Model, model: Model, i: int, path: str) -> int:
    """The Pinocchio joint that moves the URDF link of our coordinate ``i`` (its body's name): the parent joint of
    the link's BODY frame, which must hang directly from that joint's JOINT frame."""
    link = model.bodies[i].name
    where = f"the reference cannot map coordinate {i} (body '{link}') of model '{model.name}' to a joint of '{path}'"
    if not pm.existFrame(link, pin.FrameType.BODY):
        links = [f.name for f in pm.frames if f.type == pin.FrameType.BODY]
        raise ValueError(f"{where}: the file has no link '{link}' (its links: {links}); the loader names each body "
                         "after the link its joint moves, so the conversion (cases/urdf.py) or the file changed")
    frame = pm.frames[pm.getFrameId(link, pin.FrameType.BODY)]
    jid = _parent_joint(frame)
    if jid == 0:
        raise ValueError(f"{where}: link '{link}' is welded to the world in the file; no joint moves it, so it has "
                         "no coordinate (check the conversion, cases/urdf.py)")
    above = pm.frames[_parent_frame(frame)]
    if above.type != pin.FrameType.JOINT or _parent_joint(above) != jid:
        raise ValueError(f"{where}: link '{link}' is welded by the fixed joint '{above.name}' to a link that joint "
                         f"'{pm.names[jid]}' moves; the coordinate of a joint belongs to the link it moves directly")
    return jid


def _map_joints(pm: pin.Model, model: Model, path: str) -> tuple[JointMapRow, ...]:
    """The joint map of the module docstring: one row per coordinate, every Pinocchio joint used exactly once."""
    rows, owner = [], {}
    for i, body in enumerate(model.bodies):
        jid = _moving_joint(pm, model, i, path)
        joint, name = pm.joints[jid], pm.names[jid]
        if jid in owner:
            raise ValueError(f"the reference cannot map model '{model.name}' to '{path}': bodies "
                             f"'{model.bodies[owner[jid]].name}' and '{body.name}' both belong to joint '{name}'")
        nq, nv = JOINT_DOF[body.joint]
        kind = {"JointModelFreeFlyer": "free", "JointModelSpherical": "spherical"}.get(joint.shortname(), "scalar")
        ours = body.joint if body.joint in GROUP_JOINTS else "scalar"
        if kind != ours or joint.nv != nv or joint.nq != (2 if joint.shortname() in _UNBOUNDED else nq):
            raise ValueError(f"the reference cannot map body '{body.name}' ({body.joint} joint, nq {nq}, nv {nv}) of "
                             f"model '{model.name}': joint '{name}' of '{path}' is a {joint.shortname()} with nq "
                             f"{joint.nq}, nv {joint.nv}")
        owner[jid] = i
        rows.append(JointMapRow(i, body.name, name, joint.idx_q, joint.idx_v, joint.nq, 1))
    unmapped = [pm.names[j] for j in range(1, pm.njoints) if j not in owner]
    if unmapped:
        raise ValueError(f"the reference cannot map model '{model.name}' to '{path}': URDF joint(s) {unmapped} move "
                         f"no body of the model (bodies: {[b.name for b in model.bodies]}); the model must have one "
                         "coordinate per movable joint of the file")
    return tuple(rows)


def _file_mimics(path: str) -> list[tuple[str, str, float, float]]:
    """The file's ``<mimic>`` tags, read from the XML (Pinocchio is asked to ignore them, as the loader does), but
    those of fixed joints, which have no coordinate to couple, and those naming no joint of the file: (joint, the
    joint it mimics, multiplier (default 1), offset (default 0))."""
    try:
        joints = ET.parse(path).getroot().findall("joint")
        names = {j.get("name") for j in joints}
        return [(j.get("name"), j.find("mimic").get("joint"), float(j.find("mimic").get("multiplier", 1.0)),
                 float(j.find("mimic").get("offset", 0.0))) for j in joints
                if j.find("mimic") is not None and j.get("type") != "fixed" and j.find("mimic").get("joint") in names]
    except (OSError, ET.ParseError, ValueError) as exc:
        raise ValueError(f"the reference cannot read the <mimic> tags of '{path}': {exc}") from exc


def coupling_row(model: Model, c, index: str = "v_index") -> np.ndarray:
    """A joint coupling's row over our velocities (``Jc``; ``index="q_index"``: over our coordinates, for phi)."""
    row = np.zeros(model.nv if index == "v_index" else model.nq)
    for name, coeff in zip(c.joints, c.coefficients):
        row[getattr(model, index)[model.body_index(name)]] += coeff
    return row


def _check_mimics(model: Model, rows: tuple[JointMapRow, ...], path: str) -> None:
    """Every ``<mimic>`` of the file (joint A mimics J: ``q_A = m q_J + o``) is declared on the model as the
    constraint ``mimic:A``, a joint coupling whose row is a multiple ``s (e_A - m e_J)`` with offset ``s o``, A and J
    mapped to our coordinates by the joint map; and every declaration named ``mimic:...`` is a mimic of the file.
    The loader declares them (cases/urdf.py); a ValueError names the mimic and the file."""
    coordinate = {r.joint: model.v_index[r.coordinate] for r in rows}     # a mimic joint has one velocity
    declared = {c.name: c for c in model.constraints if c.name.startswith("mimic:")}
    where = f"the reference cannot check model '{model.name}' against '{path}'"
    for joint, mimicked, m, o in _file_mimics(path):
        if joint not in coordinate or mimicked not in coordinate:
            raise ValueError(f"{where}: joint '{joint}' mimics '{mimicked}', and the joint map gives one of them no "
                             f"coordinate (mapped: {sorted(coordinate)})")
        c = declared.pop(f"mimic:{joint}", None)
        expected = np.zeros(model.nv)
        expected[coordinate[joint]], expected[coordinate[mimicked]] = 1.0, -m
        row = coupling_row(model, c) if isinstance(c, JointCoupling) else np.zeros(model.nv)
        s = row[coordinate[joint]]
        if s == 0.0 or np.abs(row - s * expected).max() > 1e-12 * abs(s) or abs(c.offset - s * o) > 1e-12 * abs(s):
            raise ValueError(f"{where}: joint '{joint}' mimics '{mimicked}' (q = {m!r} q + {o!r}), and the model "
                             f"declares {'no joint coupling' if c is None else repr(c)} 'mimic:{joint}' with that "
                             f"row (coordinates {coordinate[joint]}, {coordinate[mimicked]}); check the loader's "
                             "mimic couplings (cases/urdf.py)")
    if declared:
        raise ValueError(f"{where}: the model declares {sorted(declared)}, but the file has no such <mimic> tag")


def _file_scales(pm: pin.Model, rows: tuple[JointMapRow, ...]) -> _Scales:
    """:class:`_Scales` of the file's joints, summed in our coordinate order (the same numbers as our model's when
    the conversion is right)."""
    joints = [pm.getJointId(r.joint) for r in rows]
    mass = float(sum(pm.inertias[j].mass for j in joints))
    length = 1.0 + float(sum(np.linalg.norm(pm.jointPlacements[j].translation) + np.linalg.norm(pm.inertias[j].lever)
                             for j in joints))
    inertia = float(sum(pm.inertias[j].mass * length**2 + np.trace(pm.inertias[j].inertia) for j in joints)
                    + sum(float(np.sum(pm.armature[pm.joints[j].idx_v:pm.joints[j].idx_v + pm.joints[j].nv]))
                          for j in joints))
    return _Scales(mass, length, inertia, np.array(pm.gravity.linear))


def _task_frame(pm: pin.Model, model: Model, joint_of: dict) -> int:
    """The default task point's frame in the file-built model: the file's frame of the same name (a BODY frame
    first: the loader's task points are leaf links), else, for a task point that is not a frame of the file, one
    added at our body and offset (then read from our model: the only place the reference uses a placement of ours)."""
    tp = model.task_point()
    if pm.existFrame(tp.name, pin.FrameType.BODY):
        return pm.getFrameId(tp.name, pin.FrameType.BODY)
    if pm.existFrame(tp.name):
        return pm.getFrameId(tp.name)
    return _add_point_frame(pm, f"task:{tp.name}", joint_of[tp.body], tp.offset)


def _build_from_file(model: Model) -> Compiled:
    """The reference of a model with a file source (module docstring)."""
    pm = _read_file(model.source)
    rows = _map_joints(pm, model, model.source.path)
    _check_mimics(model, rows, model.source.path)
    joint_of = {r.body: pm.getJointId(r.joint) for r in rows}
    order = np.empty(model.nv, dtype=int)
    for r in rows:
        nv = JOINT_DOF[model.bodies[r.coordinate].joint][1]
        order[r.idx_v:r.idx_v + nv] = model.v_index[r.coordinate] + np.arange(nv)
    circle = [r for r in rows if r.nq == 2]           # a continuous joint: (cos q, sin q) of our one coordinate
    plain = [(r.idx_q + k, model.q_index[r.coordinate] + k) for r in rows if r.nq != 2 for k in range(r.nq)]
    pairs = (np.array([p[0] for p in plain], dtype=int), np.array([p[1] for p in plain], dtype=int))
    circles = (np.array([r.idx_q for r in circle], dtype=int),
               np.array([model.q_index[r.coordinate] for r in circle], dtype=int))
    return Compiled(pm, order, pairs, circles, joint_of, _task_frame(pm, model, joint_of),
                     _constraint_frames(pm, model, joint_of), _file_scales(pm, rows), rows,
                     {joint_of[r.body]: model.body_index(r.body) for r in rows})


# -------------------------------------------------------------------------------------------------- caches


def _cached(key: tuple, build, model: Model) -> Compiled:
    with LOCK:
        hit = _CACHE.get(key)
        if hit is None:
            hit = _CACHE[key] = build(model)
    return hit


def from_data(model: Model) -> Compiled:
    """The Pinocchio model of our data (cached by ``model.digest()``)."""
    return _cached(("data", model.digest()), _build_from_data, model)


def reference_key(model: Model) -> tuple:
    return ("data", model.digest()) if model.source is None else ("file", model.digest(), model.source.key())


def to_pinocchio(model: Model) -> pin.Model:
    """A ``pinocchio.Model`` of OUR data for ``model`` (cached by ``model.digest()``; joints in a depth-first order
    of the bodies), whatever its source: the speed anchor and the harness's view. Treat it as read-only: it is
    shared between calls."""
    return from_data(model).model


def reference_model(model: Model) -> Compiled:
    """The Pinocchio model :func:`split` evaluates for ``model`` (built from the file for a model with a source, with
    the scene's placement and gravity, else from our data) and how our coordinates map onto it: ``order`` (our index
    of each Pinocchio velocity) and ``configuration(q)``. Shared and cached: read-only (``crosscheck.needs`` copies
    it for a plugin)."""
    if model.source is None:
        return from_data(model)
    return _cached(reference_key(model), _build_from_file, model)


def joint_map(model: Model) -> tuple[JointMapRow, ...] | None:
    """How the file-built reference maps our coordinates to the file's joints (module docstring), one row per
    coordinate; None for a model without a file source. A ValueError names what does not map."""
    return None if model.source is None else reference_model(model).joint_map


def provenance(model: Model) -> str | None:
    """One line for reports on what the reference was built from: "built from the file <path> (9 joints mapped by
    link name, sign +1)", and whether the scene moved the file's world; None for a model without a file source."""
    rows = joint_map(model)
    if rows is None:
        return None
    signs = ", ".join(f"{s:+d}" for s in sorted({r.sign for r in rows}))
    moved = "" if model.source.is_identity else "; the file's world placed by the scene's rigid transform"
    return f"built from the file {model.source.path} ({len(rows)} joints mapped by link name, sign {signs}{moved})"


# ------------------------------------------------------------------------------- the harness's kinematics


def symmetric(upper: np.ndarray) -> np.ndarray:
    """Pinocchio fills only the upper triangle of M (crba)."""
    return np.triu(upper) + np.triu(upper, 1).T


def ours(order: np.ndarray, vec_p: np.ndarray) -> np.ndarray:
    """A vector in Pinocchio's velocity order back in our coordinate order."""
    out = np.empty(len(order))
    out[order] = vec_p
    return out


def ours_matrix(order: np.ndarray, M_p: np.ndarray) -> np.ndarray:
    """A matrix in Pinocchio's velocity order (rows and columns) back in our coordinate order."""
    M = np.empty_like(M_p)
    M[np.ix_(order, order)] = M_p
    return M
