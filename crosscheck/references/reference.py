"""Pinocchio as the external reference (DESIGN.md: kept apart from the five formalisms).

Which Pinocchio model
---------------------
* A model loaded from a file (``model.source``, a :class:`cases.model.ModelSource`: today URDF) is checked against
  a ``pinocchio.Model`` the reference builds **from the file itself** (``pinocchio.buildModelFromUrdf(path)``, the
  loader's call: no root joint), with the source's world placement ``g = (R, t)`` applied to the joints hanging
  from the universe (``g * placement``) and to gravity (``R @`` the file's gravity). Nothing of our conversion's
  bodies is read: not their placements, axes, masses, centres of mass or inertias, nor our gravity. From our
  model it takes only what a state means and what is asked: the coordinate order (by body name, the explicit
  joint map below), the input map B, the task point (by name; see :func:`_task_frame`) and its directions, and
  the constraint declarations. A bug in our URDF conversion then moves the five formalisms and not the
  reference, and the vote names the reference as the outlier. The file's ``<mimic>`` tags (Pinocchio is asked to
  ignore them) are read from the XML here too: each must be declared on the model as the loader's coupling
  ``mimic:<joint>`` of the two joints the joint map gives, else the reference refuses the model
  (:func:`_check_mimics`), so a mimic the conversion drops, invents or attaches to another joint is not voted on.
* A model without a source (factories, fuzz, a moved copy built in code) is checked against a ``pinocchio.Model``
  built from OUR model data (:func:`to_pinocchio`): joints added in a depth-first order of ``model.bodies``,
  each with its placement, axis and inertia.
* The harness's own helpers, :func:`mass_matrix` (tolerance scales), :func:`bias_forces` and
  :func:`task_jacobian` (the independent conditions a backend's BREAKDOWN claims are audited against) and
  :func:`constraint_kinematics` (admissible states, projection onto the constraint manifold), always use the model
  built from our data: they describe the problem the formalisms are given, not a vote.

The joint map (file-built reference)
------------------------------------
Our coordinate ``i`` belongs to body ``model.bodies[i].name``, which the loader names after the URDF link the joint
moves. :func:`joint_map` finds that link's BODY frame in the file-built model, checks that it hangs directly from
a joint's JOINT frame (not welded to another link by a fixed joint), and maps the coordinate to that joint: its
``idx_q``, ``idx_v`` and ``nq`` (2 for a URDF ``continuous`` joint, which Pinocchio stores as ``(cos q, sin q)``),
sign +1 (our ``q_i`` is the URDF joint position). A link that is not in the file, a joint with ``nv != 1``, two
coordinates on one joint or a joint left without a coordinate is a ValueError naming the body and the file, never
a guess.

What is computed
----------------
:func:`split` is the shared ``split`` contract on top of Pinocchio's ABA / CRBA / RNEA; :data:`REFERENCE` wraps it
as a :class:`~formalisms.interface.Formalism`. The numbers the reference reports besides the accelerations are its
own (no numerics from ``formalisms.interface``), with the definitions every backend uses:

* ``cond_M`` and ``accel_scale`` from the singular values of M (:func:`_conditioning`);
* the input power ``u . (B^T qd)``, the constraint force ``Jc^T lam``, the constraint power ``lam . (Jc qd)`` and
  ``Jc qd``;
* the constraint conditions (``"constraint"`` = cond S, ``"constraint_kept"``, ``"constraint_consistency"``,
  the rank, ``lam_scale`` and the accelerations the constraint force can produce, added to ``accel_scale``) from
  the SVD of ``L^-1 Jc^T`` (L the Cholesky factor of M), whose squared singular values are the eigenvalues of
  ``S = Jc M^-1 Jc^T`` (:class:`_Gram`);
* the task inertia ``(J M^-1 J^T)^-1`` and ``conditions["task_inertia"]`` likewise from the SVD of ``L^-1 J^T``.

Constraints: :func:`constraint_kinematics` forms ``phi``, ``Jc`` and ``Jcdot qd`` of the declarations
(``cases.constraints``) from Pinocchio's frame placements, frame Jacobians and classical frame accelerations (a
Pfaffian declaration's ``A`` and ``Adot qd``, ``phi`` 0, from the joint Jacobian, velocity and classical acceleration
of its body: :func:`_pfaffian_rows`), and
the constrained split uses Pinocchio's own KKT solver (``pinocchio.forwardDynamics(q, v, tau, J, gamma)``) for
total / lam and drift / lam_drift. At a degenerate state (S singular up to ``CONSTRAINT_RCOND``) Pinocchio's
Cholesky-based KKT solve has no answer: the reference gives it the independent combinations of the rows (S's
eigen-directions above the threshold, as the formalisms keep them) and maps the multipliers back, which gives the
minimum-norm multipliers the formalisms return.

Joint loads (the compared ``joint_wrenches``): ``data.f[j]`` after ``pinocchio.rnea(q, v, a)`` is the spatial force
``(linear, angular)`` the parent transmits to body ``j`` through joint ``j``, in joint ``j``'s local frame (our body
frame: the loader takes each body's inertia in the joint frame, and the data build appends it there), moment about
its origin; RNEA's accelerating base (``a_gf = a - g``) puts the weight in it exactly, so ``data.f`` at ``a = total``
(``drift``) is ``joint_wrenches`` (``joint_wrenches_drift``), rows read back in our coordinate order. With
constraints the point forces of ``lam`` (``lam_drift``) are applied as RNEA's external forces ``fext`` (local
frame, moment about the joint origin); a joint coupling's ``c_j lam`` is not a point force, so RNEA leaves it in
the coupled joint's own load, the convention of ``Split.joint_wrenches``.

External loads (``cases.loads``): each declaration is a ``pinocchio.Force`` in its joint's local frame, moment
about the joint origin (:func:`_external_fext`, from ``data.oMi``: a world vector ``x`` is ``R^T x`` there, a spring's
force formed from ``oMi * offset``), passed as ABA's and RNEA's ``fext``: the accelerations, the drift at rest
(``aba(q, 0, 0, fext)``) and the joint loads carry them. ``tau_ext`` itself is ``-rnea(q, 0, 0, fext)`` of the
gravity-free model. The constrained solve (``forwardDynamics`` takes no fext) adds ``tau_ext`` to the applied force.
The linearization takes ``computeABADerivatives(..., fext)``, whose fext is constant in the joint frames: body-frame
forces and wrenches only (a world-frame force or a spring turns in the joint frame and has further q-derivatives;
:func:`linearize` declines those models).

States and results are permuted (and continuous joints mapped to ``(cos q, sin q)``) in and out, so callers always
use our coordinate order.
"""

from __future__ import annotations

import threading
import xml.etree.ElementTree as ET
from dataclasses import dataclass
from typing import NamedTuple

import numpy as np
import pinocchio as pin
import scipy.linalg

from cases.constraints import (JointCoupling, KnifeEdge, PointOnCircle, PointOnLine, PointsCoincide, PointVelocity,
                               RollingContact)
from cases.loads import ExternalWrench, PointSpring
from cases.model import GROUP_JOINTS, JOINT_DOF, Model, ModelSource
from formalisms.interface import (CONSTRAINT_RCOND, DEGENERATE_ROW, Formalism, Linearization, Split, SplitBatch,
                                  check_batch, check_state, split_batch_by_loop, ModelNotSupported)

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
class _Compiled:
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


_CACHE: dict[tuple, _Compiled] = {}
_LOCK = threading.Lock()


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


def _build_from_data(model: Model) -> _Compiled:
    """The reference of a model without a file source: a Pinocchio model of our bodies (module docstring)."""
    pm = pin.Model()
    pm.name = model.name
    joint_id = {}
    for i in _depth_first(model):
        b = model.bodies[i]
        parent = 0 if model.parent_index[i] < 0 else joint_id[model.parent_index[i]]
        placement = pin.SE3(np.array(b.rotation), np.array(b.translation))
        jid = pm.addJoint(parent, _joint_model(b.joint, b.axis), placement, b.name)
        pm.appendBodyToJoint(jid, pin.Inertia(float(b.mass), np.array(b.com), np.array(b.inertia)), pin.SE3.Identity())
        joint_id[i] = jid
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
    return _Compiled(pm, order, (q_pin, q_ours), (np.zeros(0, int), np.zeros(0, int)), joint_of,
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
    from cases.urdf import read_file

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
    return pm


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
    """The file's ``<mimic>`` tags, read from the XML (Pinocchio is asked to ignore them, as the loader does):
    (joint, the joint it mimics, multiplier (default 1), offset (default 0))."""
    try:
        joints = ET.parse(path).getroot().findall("joint")
        return [(j.get("name"), j.find("mimic").get("joint"), float(j.find("mimic").get("multiplier", 1.0)),
                 float(j.find("mimic").get("offset", 0.0))) for j in joints if j.find("mimic") is not None]
    except (OSError, ET.ParseError, ValueError) as exc:
        raise ValueError(f"the reference cannot read the <mimic> tags of '{path}': {exc}") from exc


def _coupling_row(model: Model, c, index: str = "v_index") -> np.ndarray:
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
        row = _coupling_row(model, c) if isinstance(c, JointCoupling) else np.zeros(model.nv)
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
    inertia = float(sum(pm.inertias[j].mass * length**2 + np.trace(pm.inertias[j].inertia) for j in joints))
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


def _build_from_file(model: Model) -> _Compiled:
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
    return _Compiled(pm, order, pairs, circles, joint_of, _task_frame(pm, model, joint_of),
                     _constraint_frames(pm, model, joint_of), _file_scales(pm, rows), rows,
                     {joint_of[r.body]: model.body_index(r.body) for r in rows})


# -------------------------------------------------------------------------------------------------- caches


def _cached(key: tuple, build, model: Model) -> _Compiled:
    with _LOCK:
        hit = _CACHE.get(key)
        if hit is None:
            hit = _CACHE[key] = build(model)
    return hit


def _from_data(model: Model) -> _Compiled:
    """The Pinocchio model of our data (cached by ``model.digest()``)."""
    return _cached(("data", model.digest()), _build_from_data, model)


def _reference_key(model: Model) -> tuple:
    return ("data", model.digest()) if model.source is None else ("file", model.digest(), model.source.key())


def _reference(model: Model) -> _Compiled:
    """What :func:`split` checks against: the file-built model for a model with a source, else :func:`_from_data`'s
    (cached by the digest and the source)."""
    if model.source is None:
        return _from_data(model)
    return _cached(_reference_key(model), _build_from_file, model)


def to_pinocchio(model: Model) -> pin.Model:
    """A ``pinocchio.Model`` of OUR data for ``model`` (cached by ``model.digest()``; joints in a depth-first order
    of the bodies), whatever its source: the speed anchor and the harness's view. Treat it as read-only: it is
    shared between calls."""
    return _from_data(model).model


def reference_model(model: Model) -> _Compiled:
    """The Pinocchio model :func:`split` evaluates for ``model`` (built from the file for a model with a source, with
    the scene's placement and gravity, else from our data) and how our coordinates map onto it: ``order`` (our index
    of each Pinocchio velocity) and ``configuration(q)``. Shared and cached: read-only (``crosscheck.needs`` copies
    it for a plugin)."""
    return _reference(model)


def joint_map(model: Model) -> tuple[JointMapRow, ...] | None:
    """How the file-built reference maps our coordinates to the file's joints (module docstring), one row per
    coordinate; None for a model without a file source. A ValueError names what does not map."""
    return None if model.source is None else _reference(model).joint_map


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


def _sym(upper: np.ndarray) -> np.ndarray:
    """Pinocchio fills only the upper triangle of M (crba)."""
    return np.triu(upper) + np.triu(upper, 1).T


def _ours(order: np.ndarray, vec_p: np.ndarray) -> np.ndarray:
    """A vector in Pinocchio's velocity order back in our coordinate order."""
    out = np.empty(len(order))
    out[order] = vec_p
    return out


def _ours_matrix(order: np.ndarray, M_p: np.ndarray) -> np.ndarray:
    """A matrix in Pinocchio's velocity order (rows and columns) back in our coordinate order."""
    M = np.empty_like(M_p)
    M[np.ix_(order, order)] = M_p
    return M


def mass_matrix(model: Model, q) -> np.ndarray:
    """``M(q)`` from Pinocchio's CRBA on the model of our data (:func:`to_pinocchio`), in our coordinate order: the
    problem the formalisms are given, for the harness's tolerance scales."""
    c = _from_data(model)
    M_p = _sym(np.array(pin.crba(c.model, c.model.createData(), c.configuration(np.asarray(q, dtype=float)))))
    return _ours_matrix(c.order, M_p)


def bias_forces(model: Model, q, qd) -> tuple[np.ndarray, np.ndarray]:
    """``(C qd, g)`` from RNEA on the model of our data (:func:`to_pinocchio`), in our coordinate order: the problem
    the formalisms are given."""
    c = _from_data(model)
    q, qd = (np.asarray(x, dtype=float) for x in (q, qd))
    data = c.model.createData()
    q_p = c.configuration(q)
    g = np.array(pin.computeGeneralizedGravity(c.model, data, q_p))
    Cqd = np.array(pin.rnea(c.model, data, q_p, qd[c.order], np.zeros(model.n))) - g
    return _ours(c.order, Cqd), _ours(c.order, g)


def task_jacobian(model: Model, q) -> np.ndarray:
    """``J = D dp/dq`` (k x n, our coordinate order) of the default task point ``p`` in its task directions ``D``,
    from the model of our data (:func:`to_pinocchio`): the problem the formalisms are given."""
    c = _from_data(model)
    data = c.model.createData()
    pin.computeJointJacobians(c.model, data, c.configuration(np.asarray(q, dtype=float)))
    J_p = _task_rows(model, c, data)
    J = np.empty_like(J_p)
    J[:, c.order] = J_p
    return J


def body_origins(model: Model, q) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """World positions at ``q`` of every body frame's origin (its joint's origin) and centre of mass (bodies x 3
    each, in body order) and of the default task point, from the model of our data (:func:`to_pinocchio`): for
    pictures of the mechanism."""
    c = _from_data(model)
    data = c.model.createData()
    pin.forwardKinematics(c.model, data, c.configuration(np.asarray(q, dtype=float)))
    pin.updateFramePlacements(c.model, data)
    joints = [c.joint_of[b.name] for b in model.bodies]
    origins = np.array([data.oMi[j].translation for j in joints])
    coms = np.array([data.oMi[j].act(c.model.inertias[j].lever) for j in joints])
    return origins, coms, np.array(data.oMf[c.task_frame].translation)


def centroidal_momentum_map(model: Model, q, qd) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The rate of the centroidal momentum ``h_G = (P, L_G)`` (linear momentum, angular momentum about the centre of
    mass; world axes) as an affine function of the accelerations, ``dh_G/dt = A_G qdd + b``: ``(A_G, b, c)`` with
    ``A_G`` (6 x nv, our order) from Pinocchio's ``ccrba``, ``b = dh_G/dt`` at ``qdd = 0``
    (``computeCentroidalMomentumTimeVariation``) and c the centre of mass (world), from the model of our data
    (:func:`to_pinocchio`): the harness's view, for the momentum checks of ``crosscheck.checks.conservation``."""
    c = _from_data(model)
    data = c.model.createData()
    q_p, v_p = c.configuration(np.asarray(q, dtype=float)), np.asarray(qd, dtype=float)[c.order]
    A_p = np.array(pin.ccrba(c.model, data, q_p, v_p)).reshape(6, model.nv)
    A = np.empty_like(A_p)
    A[:, c.order] = A_p
    rate = pin.computeCentroidalMomentumTimeVariation(c.model, data, q_p, v_p, np.zeros(model.nv))
    b = np.concatenate([np.array(data.dhg.linear), np.array(data.dhg.angular)]) if rate is not None else None
    return A, b, np.array(data.com[0])


def constraint_kinematics(model: Model, q, qd) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """``phi(q)`` (k,), ``Jc = dphi/dq`` (k x n, our coordinate order) and ``Jcdot qd`` (k,) from Pinocchio's
    kinematics of the model of our data (:func:`to_pinocchio`): the harness's view of the constraints the
    formalisms are given (admissibility, projection onto the manifold)."""
    q, qd = (np.asarray(x, dtype=float) for x in (q, qd))
    c = _from_data(model)
    phi, Jc_p, bias = _constraint_terms(model, c, c.model.createData(), q, qd)
    Jc = np.empty_like(Jc_p)
    Jc[:, c.order] = Jc_p
    return phi, Jc, bias


def contact_sines(model: Model, q) -> np.ndarray:
    """For each RollingContact of the model (in order), ``|n x a|``: the sine of the angle between the disk's axle
    ``a = R axis`` and the ground's normal n at ``q``, from Pinocchio's placements of the model of our data (0 where
    the disk lies flat and has no contact point; the harness's tolerance scales grow as it shrinks)."""
    contacts = [con for con in model.constraints if isinstance(con, RollingContact)]
    if not contacts:
        return np.zeros(0)
    c = _from_data(model)
    data = c.model.createData()
    pin.framesForwardKinematics(c.model, data, c.configuration(np.asarray(q, dtype=float)))
    return np.array([np.linalg.norm(np.cross(np.cross(con.plane[0], con.plane[1]),
                                             np.array(data.oMi[c.joint_of[con.body]].rotation) @ con.axis))
                     for con in contacts])


def _point_kinematics(c: _Compiled, data, body, offset, n: int):
    """World position, linear Jacobian (3 x n, Pinocchio order) and classical acceleration at qdd = 0 of a
    body point; a world point (body None) is fixed. Needs forwardKinematics(q, v, 0) and computeJointJacobians."""
    if body is None:
        return np.array(offset, dtype=float), np.zeros((3, n)), np.zeros(3)
    fid = c.points[(body, tuple(offset))]
    pos = np.array(data.oMf[fid].translation)
    J = np.array(pin.getFrameJacobian(c.model, data, fid, pin.LOCAL_WORLD_ALIGNED)).reshape(6, n)[:3]
    acc = np.array(pin.getFrameClassicalAcceleration(c.model, data, fid, pin.LOCAL_WORLD_ALIGNED).linear)
    return pos, J, acc


class _Material(NamedTuple):
    """A body's joint placement (``R``, origin ``o``), angular velocity ``w`` (world), and the linear Jacobian ``J``
    (3 x n, Pinocchio order) and classical acceleration ``a`` at qdd = 0 of its material point at world ``p``."""

    R: np.ndarray
    o: np.ndarray
    w: np.ndarray
    J: np.ndarray
    a: np.ndarray


def _material_point(c: _Compiled, data, body: str, at, n: int) -> _Material:
    """:class:`_Material` of ``body`` at the world point ``at(R, o)`` from Pinocchio's joint Jacobian and the joint's
    velocity and classical acceleration (LOCAL_WORLD_ALIGNED): ``J = J_v - [r]x J_w``, ``a = a_o + wd x r + w x (w x
    r)`` with ``r = p - o``. Needs forwardKinematics(q, v, 0) and computeJointJacobians."""
    jid = c.joint_of[body]
    R, o = np.array(data.oMi[jid].rotation), np.array(data.oMi[jid].translation)
    J6 = np.array(pin.getJointJacobian(c.model, data, jid, pin.LOCAL_WORLD_ALIGNED)).reshape(6, n)
    velocity = pin.getVelocity(c.model, data, jid, pin.LOCAL_WORLD_ALIGNED)
    w = np.array(velocity.angular)
    a_o = np.array(pin.getClassicalAcceleration(c.model, data, jid, pin.LOCAL_WORLD_ALIGNED).linear)
    wd = np.array(pin.getAcceleration(c.model, data, jid, pin.LOCAL_WORLD_ALIGNED).angular)
    r = at(R, o) - o
    return _Material(R, o, w, J6[:3] - np.cross(r, J6[3:].T).T, a_o + np.cross(wd, r) + np.cross(w, np.cross(w, r)))


def _contact(con: RollingContact, R: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """A rolling contact's ``u`` (unit, in the disk plane, away from the ground), ``|n - (n.a) a|`` and the axis
    ``a = R axis`` (``cases.constraints``)."""
    n, a = np.cross(con.plane[0], con.plane[1]), R @ con.axis
    raw = n - (n @ a) * a
    return raw / np.linalg.norm(raw), np.linalg.norm(raw), a


def _rolling_direction(con: RollingContact, a: np.ndarray) -> tuple[np.ndarray, float]:
    """A rolling contact's rolling direction ``t = (a x n) / |a x n|`` and ``|a x n|`` (``cases.constraints``)."""
    b = np.cross(a, np.cross(con.plane[0], con.plane[1]))
    size = float(np.linalg.norm(b))
    return b / size, size


def _pfaffian_rows(model: Model, c: _Compiled, data, con, v_p: np.ndarray):
    """phi (0), A (Pinocchio order) and Adot qd of a Pfaffian declaration (``cases.constraints``), from
    :func:`_material_point`: a knife edge's ``e = R d`` turns with ``w``; a rolling contact's material point at the
    contact ``p_c = c - r u`` has ``A = T J`` and ``Adot qd = T (a + w x (edot - w x e))``, ``e = -r u``, ``edot = -r
    udot`` (the contact slides over the disk); with ``lateral=False`` the one row ``t^T J`` along the rolling direction
    ``t = (a x n) / |a x n|``, its bias ``t . (a + w x (edot - w x e)) + tdot . (J qd)``, ``tdot = (bdot - t (t.bdot))
    / |a x n|``, ``bdot = (w x a) x n``."""
    n = model.n
    if isinstance(con, PointVelocity):
        x = _material_point(c, data, con.body, lambda R, o: o + R @ con.offset, n)
        return np.zeros(con.size), con.directions @ x.J, con.directions @ x.a
    if isinstance(con, KnifeEdge):
        x = _material_point(c, data, con.body, lambda R, o: o + R @ con.offset, n)
        e = x.R @ con.direction
        return np.zeros(1), (e @ x.J)[None, :], np.array([np.cross(x.w, e) @ (x.J @ v_p) + e @ x.a])
    x = _material_point(c, data, con.body,
                        lambda R, o: o + R @ con.center - con.radius * _contact(con, R)[0], n)
    u, length, a = _contact(con, x.R)
    n_ground = np.cross(con.plane[0], con.plane[1])
    a_dot = np.cross(x.w, a)
    raw_dot = -(n_ground @ a_dot) * a - (n_ground @ a) * a_dot
    e, e_dot = -con.radius * u, -con.radius * (raw_dot - (u @ raw_dot) * u) / length
    rate = x.a + np.cross(x.w, e_dot - np.cross(x.w, e))
    if not con.lateral:     # the rolling direction t = b / |b|, b = a x n; tdot = (bdot - t (t.bdot)) / |b|
        t, size = _rolling_direction(con, a)
        b_dot = np.cross(a_dot, n_ground)
        t_dot = (b_dot - (t @ b_dot) * t) / size
        return np.zeros(1), (t @ x.J)[None, :], np.array([t @ rate + t_dot @ (x.J @ v_p)])
    return np.zeros(2), con.plane @ x.J, con.plane @ rate


def _rows(model: Model, c: _Compiled, data, con, q: np.ndarray, v_p: np.ndarray):
    """phi, Jc (Pinocchio order) and Jcdot qd of one declaration (the formulas of ``cases.constraints``)."""
    n = model.n
    if not con.holonomic:
        return _pfaffian_rows(model, c, data, con, v_p)
    if isinstance(con, JointCoupling):
        phi = _coupling_row(model, con, "q_index") @ q - con.offset
        return np.array([phi]), _coupling_row(model, con)[c.order][None, :], np.zeros(1)
    if isinstance(con, PointsCoincide):
        pa, Ja, aa = _point_kinematics(c, data, con.body_a, con.offset_a, n)
        pb, Jb, ab = _point_kinematics(c, data, con.body_b, con.offset_b, n)
        D = con.directions
        return D @ (pa - pb), D @ (Ja - Jb), D @ (aa - ab)
    p, J, a = _point_kinematics(c, data, con.body, con.offset, n)
    if isinstance(con, PointOnLine):
        return con.normals @ (p - con.origin), con.normals @ J, con.normals @ a
    P = con.plane
    d = P @ (p - con.center)
    return (np.array([d @ d - con.radius**2]), (2.0 * d @ P @ J)[None, :],
            np.array([2.0 * np.sum((P @ J @ v_p) ** 2) + 2.0 * d @ P @ a]))


def _constraint_terms(model: Model, c: _Compiled, data, q: np.ndarray, qd: np.ndarray):
    """phi, Jc (Pinocchio's coordinate order), Jcdot qd; leaves data with the kinematics at (q, qd, 0)."""
    qp, vp = c.configuration(q), qd[c.order]
    pin.forwardKinematics(c.model, data, qp, vp, np.zeros(model.n))
    pin.computeJointJacobians(c.model, data, qp)
    pin.updateFramePlacements(c.model, data)
    rows = [_rows(model, c, data, con, q, vp) for con in model.constraints]
    return (np.concatenate([r[0] for r in rows]), np.vstack([r[1] for r in rows]),
            np.concatenate([r[2] for r in rows]))


# ------------------------------------------------------------------------------------ the reference's numerics


@dataclass(frozen=True)
class _Dynamics:
    """CRBA's M, its lower Cholesky factor L and its singular values (descending), RNEA's g and C qd at one state,
    in Pinocchio's order."""

    M: np.ndarray
    L: np.ndarray
    singular_values: np.ndarray
    g: np.ndarray
    Cqd: np.ndarray

    @classmethod
    def at(cls, c: _Compiled, data, q_p: np.ndarray, v_p: np.ndarray) -> "_Dynamics":
        M = _sym(np.array(pin.crba(c.model, data, q_p)))
        g = np.array(pin.computeGeneralizedGravity(c.model, data, q_p))
        Cqd = np.array(pin.rnea(c.model, data, q_p, v_p, np.zeros(len(v_p)))) - g
        return cls(M, scipy.linalg.cholesky(M, lower=True), np.linalg.svd(M, compute_uv=False), g, Cqd)


def _conditioning(c: _Compiled, dyn: _Dynamics, tau: np.ndarray, qd: np.ndarray) -> tuple[float, float]:
    """``(cond(M), accel_scale)`` from the singular values of M (for a symmetric positive definite M its
    eigenvalues): ``accel_scale = ||M^-1||_2 H``, H the size of the generalized forces summed in ``B u - C qd - g``
    (1-norms), including the configuration-robust magnitudes ``||M|| |qd|^2`` of the velocity products and
    ``|gravity|_1 sqrt(m_total ||M||)`` of gravity (the definition the formalisms use; mass and gravity are the
    reference model's: the file's, for a loaded model). ``tau`` and ``qd`` in any one order."""
    s = dyn.singular_values
    H = (np.abs(dyn.Cqd).sum() + np.abs(dyn.g).sum() + np.abs(tau).sum() + s[0] * float(qd @ qd)
         + np.abs(c.scales.gravity).sum() * np.sqrt(c.scales.mass * s[0]))
    return float(s[0] / s[-1]), float(H / s[-1])


@dataclass(frozen=True)
class _Gram:
    """``G = X^T X`` (k x k) in its eigen-axes from the SVD of X (n x k): eigenvalues ``w`` (ascending, the squared
    singular values, zero beyond rank n) and eigenvectors ``axes`` (columns). With ``X = L^-1 J^T`` and L the
    Cholesky factor of M, ``G = J M^-1 J^T``: S for the constraint rows, A for the task Jacobian."""

    w: np.ndarray
    axes: np.ndarray

    @classmethod
    def of(cls, L: np.ndarray, J: np.ndarray) -> "_Gram":
        X = scipy.linalg.solve_triangular(L, J.T, lower=True)
        _, sigma, Vt = np.linalg.svd(X, full_matrices=True)
        w = np.zeros(X.shape[1])
        w[:len(sigma)] = sigma**2
        return cls(w[::-1].copy(), Vt[::-1].T.copy())


def _task_rows(model: Model, c: _Compiled, data) -> np.ndarray:
    """The task Jacobian ``D J`` (k x n, Pinocchio's order): the task frame's ``LOCAL_WORLD_ALIGNED`` linear
    Jacobian in the task directions. Needs computeJointJacobians."""
    J6 = np.array(pin.getFrameJacobian(c.model, data, c.task_frame, pin.LOCAL_WORLD_ALIGNED)).reshape(6, model.n)
    return model.task_point().directions @ J6[:3]


def _task_inertia(model: Model, c: _Compiled, data, L: np.ndarray) -> dict:
    """``task_inertia`` (eq. 22) of the default task point, ``(J M^-1 J^T)^-1`` from the eigen-axes of
    ``A = J M^-1 J^T`` (:class:`_Gram`; J from :func:`_task_rows`, needs computeJointJacobians), and
    ``conditions["task_inertia"]`` = cond(A). A is numerically singular (NaN and inf) when its smallest eigenvalue
    is at or below ``k eps`` times its largest or the degenerate floor, or any is not finite (the definition the
    formalisms use)."""
    A = _Gram.of(L, _task_rows(model, c, data))                 # A does not depend on the coordinate order
    w = A.w
    floor = max(len(w) * np.finfo(float).eps * w[-1], c.scales.degenerate_floor)
    if not (np.all(np.isfinite(w)) and floor < w[0]):
        return {"task_inertia": np.full((len(w), len(w)), np.nan), "conditions": {"task_inertia": float("inf")}}
    Lambda = (A.axes / w) @ A.axes.T
    return {"task_inertia": 0.5 * (Lambda + Lambda.T), "conditions": {"task_inertia": float(w[-1] / w[0])}}


def _input_power(model: Model, u: np.ndarray, qd: np.ndarray) -> tuple[float, np.ndarray]:
    """``P_ctrl = u . (B^T qd)`` and per coordinate ``(B u)_i qd_i`` (DESIGN.md, power)."""
    return float(u @ (model.input_map.T @ qd)), (model.input_map @ u) * qd


def _joint_wrenches(c: _Compiled, data, q_p, v_p, a_p, fext=None) -> np.ndarray:
    """``data.f`` after ``rnea(q, v, a, fext)``: row ``i`` (our order) = ``[force, moment]`` the parent transmits to
    body ``i``, in its frame, about its origin (module docstring)."""
    if fext is None:
        pin.rnea(c.model, data, q_p, v_p, a_p)
    else:
        pin.rnea(c.model, data, q_p, v_p, a_p, fext)
    out = np.empty((len(c.body_of_joint), 6))
    for jid, body in c.body_of_joint.items():
        f = data.f[jid]
        out[body] = np.concatenate([f.linear, f.angular])
    return out


def _point_forces(c: _Compiled, data, con, part: np.ndarray) -> list:
    """The point forces ``(body, offset, world force)`` the multipliers ``part`` of one declaration apply (none on
    the world, none for a coupling): a circle ``2 P^T P (p - c) lam``, a loop ``D^T lam`` on a and ``-D^T lam`` on
    b, a line ``N^T lam``. Needs the frame placements."""
    if isinstance(con, PointsCoincide):
        force = con.directions.T @ part
        return [(b, o, s * force) for b, o, s in ((con.body_a, con.offset_a, 1.0), (con.body_b, con.offset_b, -1.0))
                if b is not None]
    if isinstance(con, PointOnLine):
        return [(con.body, con.offset, con.normals.T @ part)]
    if isinstance(con, PointOnCircle):
        p = np.array(data.oMf[c.points[(con.body, tuple(con.offset))]].translation)
        return [(con.body, con.offset, 2.0 * con.plane.T @ (con.plane @ (p - con.center)) * part[0])]
    if isinstance(con, PointVelocity):
        return [(con.body, con.offset, con.directions.T @ part)]
    if isinstance(con, KnifeEdge):
        R = np.array(data.oMi[c.joint_of[con.body]].rotation)
        return [(con.body, con.offset, (R @ con.direction) * part[0])]
    if isinstance(con, RollingContact):   # at the contact point, its offset in the body (joint) frame
        R = np.array(data.oMi[c.joint_of[con.body]].rotation)
        direction = con.plane.T if con.lateral else _rolling_direction(con, R @ con.axis)[0][:, None]
        return [(con.body, con.center - con.radius * (R.T @ _contact(con, R)[0]), direction @ part)]
    return []


def _constraint_fext(model: Model, c: _Compiled, data, lam: np.ndarray) -> list:
    """The constraint forces of ``lam`` as RNEA's external forces: per joint a ``pinocchio.Force`` in its local frame
    (``R^T f``, moment ``offset x R^T f`` about the joint origin). Needs the placements (``data.oMi``, ``oMf``)."""
    fext = [pin.Force.Zero() for _ in range(c.model.njoints)]
    start = 0
    for con in model.constraints:
        part, start = lam[start:start + con.size], start + con.size
        for body, offset, force in _point_forces(c, data, con, part):
            jid = c.joint_of[body]
            local = np.array(data.oMi[jid].rotation).T @ force
            fext[jid] = fext[jid] + pin.Force(local, np.cross(offset, local))
    return fext


def _external_fext(model: Model, c: _Compiled, data) -> list | None:
    """The external loads (``cases.loads``) as ABA's and RNEA's ``fext``: per joint a ``pinocchio.Force`` in its local
    frame, moment about the joint origin (module docstring); None without loads. Needs the placements (``data.oMi``,
    after forwardKinematics)."""
    if not model.loads:
        return None
    fext = [pin.Force.Zero() for _ in range(c.model.njoints)]
    for load in model.loads:
        jid = c.joint_of[load.body]
        R, origin = np.array(data.oMi[jid].rotation), np.array(data.oMi[jid].translation)
        couple = np.zeros(3)
        if isinstance(load, PointSpring):
            d = origin + R @ load.offset - load.anchor
            length = float(np.linalg.norm(d))
            local = R.T @ (-load.stiffness * (length - load.rest_length) / length * d if load.rest_length
                           else -load.stiffness * d)
        else:
            to_local = R.T if load.frame == "world" else np.eye(3)
            local = to_local @ load.force
            if isinstance(load, ExternalWrench):
                couple = to_local @ load.moment
        fext[jid] = fext[jid] + pin.Force(local, np.cross(load.offset, local) + couple)
    return fext


def _external_force(model: Model, c: _Compiled, q_p: np.ndarray, fext: list) -> np.ndarray:
    """``tau_ext`` in Pinocchio's order: ``-rnea(q, 0, 0, fext)`` of the gravity-free model (the joint torques that
    hold the external loads at rest, negated)."""
    still = _gravity_free(model)
    zero = np.zeros(model.nv)
    return -np.array(pin.rnea(still, still.createData(), q_p, zero, zero, fext))


def split(model: Model, q, qd, u) -> Split:
    """Drift / control / total accelerations from Pinocchio (ABA twice; ``M^-1 B u`` by a Cholesky solve on CRBA's M:
    computeMinverse lost 256 eps on a single rotor, a fuzz finding); task drift from the classical acceleration of
    the task frame (getFrameClassicalAcceleration); the conditions, powers and task inertia by the reference's own
    numerics (module docstring). A constrained model goes through :func:`_constrained_split`."""
    q, qd, u = check_state(model, q, qd, u)
    if model.constraints:
        return _constrained_split(model, q, qd, u)
    c = _reference(model)
    pm, order = c.model, c.order
    data = pm.createData()  # fresh Data: the result cannot depend on call history
    tau_ctrl = model.input_map @ u
    qp, vp, tp = c.configuration(q), qd[order], tau_ctrl[order]
    pin.forwardKinematics(pm, data, qp)
    fext = _external_fext(model, c, data)
    loads = () if fext is None else (fext,)

    total_p = np.array(pin.aba(pm, data, qp, vp, tp, *loads))
    drift_p = np.array(pin.aba(pm, data, qp, vp, np.zeros(model.n), *loads))
    zvcf_p = np.array(pin.aba(pm, data, qp, np.zeros(model.n), np.zeros(model.n), *loads))
    still = _gravity_free(model)
    velocity_p = np.array(pin.aba(still, still.createData(), qp, vp, np.zeros(model.n)))
    pin.forwardKinematics(pm, data, qp, vp, drift_p)
    task_accel = pin.getFrameClassicalAcceleration(pm, data, c.task_frame, pin.LOCAL_WORLD_ALIGNED).linear
    dyn = _Dynamics.at(c, data, qp, vp)
    M, Cqd, g = _ours_matrix(order, dyn.M), _ours(order, dyn.Cqd), _ours(order, dyn.g)
    ctrl = scipy.linalg.cho_solve(scipy.linalg.cho_factor(M), tau_ctrl)
    tau_ext = None if fext is None else _ours(order, _external_force(model, c, qp, fext))
    cond_M, accel_scale = _conditioning(c, dyn, tau_ctrl if tau_ext is None else np.abs(tau_ctrl) + np.abs(tau_ext), qd)
    power, power_per = _input_power(model, u, qd)
    pin.computeJointJacobians(pm, data, qp)
    inertia = _task_inertia(model, c, data, dyn.L)
    return Split(drift=_ours(order, drift_p), ctrl=ctrl, total=_ours(order, total_p), lam=None, lam_drift=None,
                 power_ctrl=power, power_ctrl_per_coord=power_per, power_constr=None, power_constr_per_coord=None,
                 cond_M=cond_M, accel_scale=accel_scale, extras={"M": M, "Cqd": Cqd, "g": g},
                 task_drift=model.task_point().directions @ np.array(task_accel), conditions=inertia["conditions"],
                 kinetic_energy=float(pin.computeKineticEnergy(pm, data, qp, vp)),
                 joint_wrenches=_joint_wrenches(c, data, qp, vp, total_p, fext),
                 joint_wrenches_drift=_joint_wrenches(c, data, qp, vp, drift_p, fext), task_inertia=inertia["task_inertia"],
                 zvcf=_ours(order, zvcf_p), drift_velocity=_ours(order, velocity_p), external_force=tau_ext,
                 power_ext=None if tau_ext is None else float(tau_ext @ qd))


_STILL: dict[tuple, pin.Model] = {}


def _gravity_free(model: Model) -> pin.Model:
    """The reference model with gravity zero (cached with it): ABA there at ``(q, qd, 0)`` is ``-M^-1 C qd``, the
    drift's velocity-product part, computed directly."""
    key, pm = _reference_key(model), _reference(model).model
    with _LOCK:
        if key not in _STILL:
            _STILL[key] = pin.Model(pm)
            _STILL[key].gravity = pin.Motion.Zero()
    return _STILL[key]


def linearize(model: Model, q, qd, u) -> Linearization:
    """A and B of eq. (11) (:class:`~formalisms.interface.Linearization`, its tangent-space convention) from
    Pinocchio's analytical derivatives of ABA (``computeABADerivatives``: ``dvdot/dq``, ``dvdot/dv`` and ``M^-1``, so
    ``dvdot/du = M^-1 B``), in our coordinate order. Unconstrained models only: a constrained model's reference is
    :func:`crosscheck.references.precise.linearize`."""
    q, qd, u = check_state(model, q, qd, u)
    if model.constraints:
        raise ModelNotSupported(f"model '{model.name}' has constraints: Pinocchio's ABA derivatives are unconstrained; "
                                "the reference linearization of a constrained model is crosscheck.references.precise.linearize")
    if any(isinstance(x, PointSpring) or x.frame == "world" for x in model.loads):
        raise ModelNotSupported(f"model '{model.name}' has world-frame external loads or springs: Pinocchio's ABA "
                                "derivatives hold fext constant in the joint frames (body-frame loads only)")
    c = _reference(model)
    pm, order = c.model, c.order
    data = pm.createData()
    qp = c.configuration(q)
    pin.forwardKinematics(pm, data, qp)
    fext = _external_fext(model, c, data)
    pin.computeABADerivatives(pm, data, qp, qd[order], (model.input_map @ u)[order], *(() if fext is None else (fext,)))
    Minv = _ours_matrix(order, _sym(np.array(data.Minv)))
    nv = model.nv
    A = np.block([[_tangent_kinematics(model, qd), np.eye(nv)],
                  [_ours_matrix(order, np.array(data.ddq_dq)), _ours_matrix(order, np.array(data.ddq_dv))]])
    return Linearization(A=A, B=np.vstack([np.zeros((nv, model.m)), Minv @ model.input_map]),
                         vdot=_ours(order, np.array(data.ddq)))


def _tangent_kinematics(model: Model, qd: np.ndarray) -> np.ndarray:
    """The kinematic rows' ``A_qq`` of the linearization's convention from Pinocchio's own Lie algebra, not from the
    interface's ``tangent_kinematics`` the backends use: ``-ad_v`` (``pin.Motion(v).action``) on a free joint,
    ``-[omega]x`` (``pin.skew``) on a spherical one, so the gate's reference checks that shared convention too."""
    out = np.zeros((model.nv, model.nv))
    for i, body in enumerate(model.bodies):
        j = model.v_index[i]
        if body.joint == "free":
            out[j:j + 6, j:j + 6] = -pin.Motion(qd[j:j + 6]).action
        elif body.joint == "spherical":
            out[j:j + 3, j:j + 3] = -pin.skew(qd[j:j + 3])
    return out


@dataclass(frozen=True)
class _ConstraintConditions:
    """Conditioning of the constrained problem at one state (the definitions the formalisms use): cond S
    (``constraint``), over the directions kept (``constraint_kept``), the share of the KKT right-hand sides in S's
    redundant directions (``constraint_consistency``), the rank, ``lam_scale`` and ``force_scale`` (the
    accelerations the constraint force can produce: ``||M^-1|| ||Jc|| lam_scale``)."""

    conditions: dict
    rank: int
    lam_scale: float
    force_scale: float


def _kept(c: _Compiled, S: _Gram) -> np.ndarray:
    """The directions of S above ``max(CONSTRAINT_RCOND w_max, degenerate floor)``; the rest are redundant."""
    return S.w > max(CONSTRAINT_RCOND * S.w[-1], c.scales.degenerate_floor)


def _constraint_conditions(c: _Compiled, dyn: _Dynamics, S: _Gram, Jc_p: np.ndarray, bias: np.ndarray,
                           forces: tuple, accel_scale: float) -> _ConstraintConditions:
    """:class:`_ConstraintConditions` from S's eigen-axes. ``lam_scale = (|Jcdot qd|_1 + ||Jc|| accel_scale) /
    w_kept_min``; the consistency is ``max |U_0^T r| / max(|r|, 1e-6 L accel_scale)`` over the right-hand sides
    ``r = -Jcdot qd - Jc M^-1 f`` of ``forces`` (``B u - h`` and ``-h``), U_0 the redundant directions."""
    kept = _kept(c, S)
    w, rank = S.w, int(kept.sum())
    w_max = max(float(w[-1]), c.scales.degenerate_floor)
    jc_norm = float(np.linalg.norm(Jc_p, 2))
    lam_scale = (np.abs(bias).sum() + jc_norm * accel_scale) / float(w[kept][0]) if rank else 0.0
    inconsistency = 0.0
    for f in forces if rank < len(w) else ():
        r = -bias - Jc_p @ scipy.linalg.cho_solve((dyn.L, True), f)
        size = max(float(np.linalg.norm(r)), 1e-6 * c.scales.length * accel_scale)
        if size > 0.0:
            inconsistency = max(inconsistency, float(np.linalg.norm(S.axes[:, ~kept].T @ r) / size))
    return _ConstraintConditions(
        {"constraint": float(w_max / w[0]) if w[0] > 0.0 else float("inf"), "constraint_consistency": inconsistency,
         "constraint_kept": float(w_max / w[kept][0]) if rank else 1.0},
        rank, float(lam_scale), jc_norm * float(lam_scale) / float(dyn.singular_values[-1]))


def _kkt(c: _Compiled, data, q_p, v_p, tau_p, Jc_p, bias):
    """Pinocchio's constrained forward dynamics (KKT): ``M a + b = tau + J^T lambda_c``, ``J a + gamma = 0``."""
    a = np.array(pin.forwardDynamics(c.model, data, q_p, v_p, tau_p, Jc_p, bias, 0.0))
    return a, np.array(data.lambda_c)


def _constrained_split(model: Model, q, qd, u) -> Split:
    """Eq. (12)-(17) with Pinocchio: total / lam and drift / lam_drift from ``pinocchio.forwardDynamics`` with
    our ``Jc`` and ``gamma = Jcdot qd``; ctrl = B_c B u with ``M^-1`` by Cholesky on CRBA's M (eq. 17)."""
    c = _reference(model)
    pm, order = c.model, c.order
    data = pm.createData()
    phi, Jc_p, bias = _constraint_terms(model, c, data, q, qd)
    tau_ctrl = model.input_map @ u
    qp, vp, tp = c.configuration(q), qd[order], tau_ctrl[order]
    pin.forwardKinematics(pm, data, qp)
    fext = _external_fext(model, c, data)
    ext_p = np.zeros(model.n) if fext is None else _external_force(model, c, qp, fext)   # forwardDynamics: no fext
    dyn = _Dynamics.at(c, data, qp, vp)
    Minv_p = scipy.linalg.cho_solve((dyn.L, True), np.eye(model.n))
    S = _Gram.of(dyn.L, Jc_p)
    kept = _kept(c, S)
    rows = np.eye(len(S.w)) if kept.all() else S.axes[:, kept]   # regular: the rows as declared
    # singular S: Pinocchio's KKT on the independent combinations of the rows, the redundant directions dropped as
    # the formalisms drop them; lam = rows lam_r is then the minimum-norm multiplier
    J_r, bias_r = rows.T @ Jc_p, rows.T @ bias
    total_p, lam_r = _kkt(c, data, qp, vp, tp + ext_p, J_r, bias_r)
    drift_p, lam_drift_r = _kkt(c, data, qp, vp, ext_p, J_r, bias_r)
    zvcf_p, _ = _kkt(c, data, qp, np.zeros(model.n), ext_p, J_r, np.zeros(len(bias_r)))
    still = _gravity_free(model)
    velocity_p = np.array(pin.forwardDynamics(still, still.createData(), qp, vp, np.zeros(model.n), J_r, bias_r, 0.0))
    lam, lam_drift = rows @ lam_r, rows @ lam_drift_r
    S_pinv = (S.axes[:, kept] / S.w[kept]) @ S.axes[:, kept].T
    B_c = Minv_p - Minv_p @ Jc_p.T @ S_pinv @ Jc_p @ Minv_p
    pin.computeJointJacobians(pm, data, qp)                      # placements and Jacobians at q, afresh
    pin.updateFramePlacements(pm, data)
    inertia = _task_inertia(model, c, data, dyn.L)
    fext, fext_drift = _constraint_fext(model, c, data, lam), _constraint_fext(model, c, data, lam_drift)
    applied = _external_fext(model, c, data)
    if applied is not None:                                      # the external loads act in both
        fext, fext_drift = ([a + b for a, b in zip(f, applied)] for f in (fext, fext_drift))
    wrenches = _joint_wrenches(c, data, qp, vp, total_p, fext), _joint_wrenches(c, data, qp, vp, drift_p, fext_drift)
    pin.forwardKinematics(pm, data, qp, vp, drift_p)
    task_accel = pin.getFrameClassicalAcceleration(pm, data, c.task_frame, pin.LOCAL_WORLD_ALIGNED).linear

    cond_M, accel_scale = _conditioning(c, dyn, np.abs(tau_ctrl) + np.abs(_ours(order, ext_p)), qd)
    cc = _constraint_conditions(c, dyn, S, Jc_p, bias, (tp + ext_p - dyn.Cqd - dyn.g, ext_p - dyn.Cqd - dyn.g),
                                accel_scale)
    Jc = np.empty_like(Jc_p)
    Jc[:, order] = Jc_p
    velocity = Jc @ qd
    power, power_per = _input_power(model, u, qd)
    force, force_drift = Jc.T @ lam, Jc.T @ lam_drift
    Cqd, g = _ours(order, dyn.Cqd), _ours(order, dyn.g)
    return Split(
        drift=_ours(order, drift_p), ctrl=_ours(order, B_c @ tp), total=_ours(order, total_p), lam=lam,
        lam_drift=lam_drift, power_ctrl=power, power_ctrl_per_coord=power_per,
        power_constr=float(lam @ velocity), power_constr_per_coord=force * qd, cond_M=cond_M,
        accel_scale=accel_scale + cc.force_scale, extras={"M": _ours_matrix(order, dyn.M), "Cqd": Cqd, "g": g},
        task_drift=model.task_point().directions @ np.array(task_accel),
        conditions={**inertia["conditions"], **cc.conditions},
        kinetic_energy=float(pin.computeKineticEnergy(pm, data, qp, vp)), joint_wrenches=wrenches[0],
        joint_wrenches_drift=wrenches[1], task_inertia=inertia["task_inertia"], constraint_value=phi,
        constraint_jacobian=Jc, constraint_bias=bias, constraint_velocity=velocity, constraint_force=force,
        constraint_force_drift=force_drift, constraint_rank=cc.rank, lam_scale=cc.lam_scale,
        zvcf=_ours(order, zvcf_p), drift_velocity=_ours(order, velocity_p),
        external_force=_ours(order, ext_p) if model.loads else None,
        power_ext=float(_ours(order, ext_p) @ qd) if model.loads else None)


# ------------------------------------------------------------------------------------------------- batches


_POOLS: dict[tuple, tuple] = {}


def _pools(model: Model) -> tuple:
    """Pinocchio ModelPools of the reference model and of a gravity-free copy (for ``M^-1 tau = ABA(q, 0, tau)``),
    cached with the reference."""
    key, pm = _reference_key(model), _reference(model).model
    with _LOCK:
        if key not in _POOLS:
            still = pin.Model(pm)
            still.gravity = pin.Motion.Zero()
            _POOLS[key] = (pin.ModelPool(pm, 1), pin.ModelPool(still, 1))
    return _POOLS[key]


def split_batch(model: Model, Q, QD, U) -> SplitBatch:
    """N states with Pinocchio's batched ABA (``abaInParallel`` on one thread) on the reference model of
    :func:`split`: total ``ABA(q, qd, B u)``, drift ``ABA(q, qd, 0)``, ctrl ``ABA(q, 0, B u)`` of the gravity-free
    model, which is ``M^-1 B u`` (eq. 9) computed directly. A constrained model goes state by state through
    :func:`split` (Pinocchio's KKT solve has no batched form in its Python API)."""
    Q, QD, U = check_batch(model, Q, QD, U)
    if model.constraints or model.loads or not len(Q):
        return split_batch_by_loop(split)(model, Q, QD, U)
    c = _reference(model)
    order = c.order
    pool, still = _pools(model)
    qp, vp = np.asfortranarray(c.configuration(Q).T), np.asfortranarray(QD[:, order].T)
    tp = np.asfortranarray((U @ model.input_map.T)[:, order].T)
    rest = np.zeros_like(vp)
    out = {}
    for name, (p, v, t) in {"total": (pool, vp, tp), "drift": (pool, vp, rest), "ctrl": (still, rest, tp)}.items():
        a = np.empty_like(vp)
        a[order] = np.reshape(pin.abaInParallel(1, p, qp, v, t), vp.shape)
        out[name] = a.T
    return SplitBatch(**out)


REFERENCE = Formalism(
    name="pinocchio",
    summary="External reference: Pinocchio's ABA (total, drift), CRBA (ctrl by Cholesky), RNEA (conditioning), "
            "built from the model's file when it was loaded from one (URDF), else from our model data",
    split=split,
    split_batch=split_batch,
    linearize=linearize,
)

__all__ = ["REFERENCE", "JointMapRow", "bias_forces", "constraint_kinematics", "contact_sines", "joint_map", "mass_matrix",
           "provenance", "split", "split_batch", "task_jacobian", "to_pinocchio"]
