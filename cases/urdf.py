"""URDF loader: a URDF file -> our :class:`~cases.model.Model`, through Pinocchio's parser.

Pinocchio does the parsing (``pinocchio.buildModelFromUrdf``), which also merges every fixed joint's child link
into its parent's inertia. Each Pinocchio joint then becomes one of our bodies, **in Pinocchio's joint order**,
so a state vector means the same thing to both (one coordinate per joint; a URDF ``continuous`` joint, which
Pinocchio stores as ``(cos q, sin q)``, is one angle ``q`` here):

* body name: the URDF link the joint moves (Pinocchio's BODY frame right after the joint frame);
* parent: the body of Pinocchio's parent joint (the universe -> ``None``; whatever is welded to the universe,
  e.g. Panda's ``panda_link0``, does not move and is left out);
* placement ``(rotation, translation)``: ``model.jointPlacements[j]``, in the parent joint's frame, which is
  our parent body frame;
* axis: from the joint type (RX/RY/RZ, RUBX/RUBY/RUBZ = continuous, PX/PY/PZ -> unit axes;
  RevoluteUnaligned, RevoluteUnboundedUnaligned, PrismaticUnaligned -> their motion subspace's axis);
* mass, com, inertia about the COM: ``model.inertias[j]`` (joint frame = our body frame);
* gravity: ``model.gravity.linear``;
* source: ``ModelSource("urdf", <absolute path>)`` with the identity placement, so the external reference
  (``crosscheck.reference``) builds its own model from the file and never from this conversion.

Task points: one per leaf link (a URDF link no joint hangs from), at that link's origin expressed in its
parent joint's frame. Leaves whose name contains ``tcp`` (a tool centre point, e.g. ``panda_hand_tcp``) come
first, so they are the default; the rest keep Pinocchio's frame order. Leaves welded to the universe are
skipped. Pinocchio 4 ignores ``<mimic>`` by default, so a mimicked joint is an independent coordinate here
(Panda: 7 arm joints + 2 finger joints = 9).

Pinocchio is imported inside :func:`from_urdf`, so importing :mod:`cases` does not import it.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from cases.model import Body, Model, ModelError, ModelSource, TaskPoint, build_model


class UrdfError(ValueError):
    """A URDF file cannot be read or parsed (the message names the path)."""


_UNIT = {"X": (1.0, 0.0, 0.0), "Y": (0.0, 1.0, 0.0), "Z": (0.0, 0.0, 1.0)}


def _joint_kind(jm) -> tuple[str, np.ndarray] | None:
    """(our joint type, axis) for a supported Pinocchio joint model, else None."""
    short = jm.shortname()
    kind = short[len("JointModel"):] if short.startswith("JointModel") else short
    if kind in ("RX", "RY", "RZ"):
        return "revolute", np.array(_UNIT[kind[1]])
    if kind in ("RUBX", "RUBY", "RUBZ"):
        return "revolute", np.array(_UNIT[kind[3]])
    if kind in ("PX", "PY", "PZ"):
        return "prismatic", np.array(_UNIT[kind[1]])
    if kind in ("RevoluteUnaligned", "RevoluteUnboundedUnaligned"):
        return "revolute", _subspace(jm)[3:]
    if kind == "PrismaticUnaligned":
        return "prismatic", _subspace(jm)[:3]
    return None


def _subspace(jm) -> np.ndarray:
    """The joint's constant motion subspace ``S = (linear, angular)`` (6,) of a one-velocity joint: its axis is the
    angular part (revolute) or the linear part (prismatic). Read from the joint data, since Pinocchio's Python
    bindings expose no ``axis`` of a RevoluteUnboundedUnaligned joint (a URDF continuous joint about a non-axis
    direction)."""
    data = jm.createData()
    jm.calc(data, np.array([1.0, 0.0]) if jm.nq == 2 else np.zeros(jm.nq))
    return np.array(data.S, dtype=float).reshape(6)


def _frame_parent_joint(frame) -> int:
    """The joint a frame is attached to (Pinocchio >= 3.1: ``parentJoint``; older: ``parent``)."""
    return int(frame.parentJoint if hasattr(frame, "parentJoint") else frame.parent)


def _frame_previous(frame) -> int:
    """The frame this one hangs from (Pinocchio >= 3.1: ``parentFrame``; older: ``previousFrame``)."""
    return int(frame.parentFrame if hasattr(frame, "parentFrame") else frame.previousFrame)


def from_urdf(path, name: str | None = None) -> Model:
    """Load the URDF at ``path`` as a :class:`Model` (joint order = Pinocchio's; see the module docstring).

    Raises :class:`FileNotFoundError` if the file does not exist, :class:`UrdfError` if Pinocchio cannot parse
    it, and :class:`~cases.model.ModelError` naming every joint whose type has no one-coordinate equivalent
    here (floating, planar, spherical, mimic, helical, ...), or if the converted model is invalid.
    """
    path = Path(path)
    if not path.is_file():
        raise FileNotFoundError(f"URDF file not found: '{path}'")
    try:
        import pinocchio as pin
    except ImportError as exc:  # pragma: no cover - pin is a declared dependency
        raise ImportError("reading URDF files needs Pinocchio: install the 'pin' package "
                          "(pip install pin)") from exc
    try:
        pm = pin.buildModelFromUrdf(str(path))
    except Exception as exc:  # noqa: BLE001 - Pinocchio raises ValueError/RuntimeError/... for bad files
        raise UrdfError(f"could not parse URDF file '{path}': {exc}") from exc
    model_name = name if name is not None else pm.name or path.stem

    frames = list(pm.frames)
    body_type, joint_types = pin.FrameType.BODY, (pin.FrameType.JOINT, pin.FrameType.FIXED_JOINT)

    # The link each joint moves: the BODY frame hanging right after that joint's JOINT frame.
    joint_frame = {}
    for k, f in enumerate(frames):
        if f.type == pin.FrameType.JOINT:
            joint_frame[_frame_parent_joint(f)] = k
    link_of = {0: None}
    for j in range(1, pm.njoints):
        link = pm.names[j]
        jf = joint_frame.get(j)
        for f in frames:
            if f.type == body_type and _frame_parent_joint(f) == j and jf is not None and _frame_previous(f) == jf:
                link = f.name
                break
        link_of[j] = link

    problems: list[str] = []
    bodies: list[Body] = []
    for j in range(1, pm.njoints):
        jm = pm.joints[j]
        kind = _joint_kind(jm)
        if kind is None:
            problems.append(f"joint '{pm.names[j]}' has Pinocchio type {jm.shortname()}, which has no "
                            "one-coordinate revolute/prismatic equivalent (supported: revolute, continuous, "
                            "prismatic, fixed)")
            continue
        if jm.nv != 1:  # pragma: no cover - every supported kind has one velocity
            problems.append(f"joint '{pm.names[j]}' has {jm.nv} velocities, expected 1")
            continue
        joint, axis = kind
        placement = pm.jointPlacements[j]
        inertia = pm.inertias[j]
        bodies.append(Body(name=link_of[j], parent=link_of[pm.parents[j]], joint=joint, axis=axis,
                           mass=float(inertia.mass), com=np.array(inertia.lever),
                           inertia=np.array(inertia.inertia), rotation=np.array(placement.rotation),
                           translation=np.array(placement.translation)))
    if problems:
        raise ModelError(model_name, problems + [f"(from URDF file '{path}')"])
    if not bodies:
        raise ModelError(model_name, [f"URDF file '{path}' has no movable joint"])

    # Leaf links: BODY frames no joint (moving or fixed) hangs from.
    has_child = {_frame_previous(f) for f in frames if f.type in joint_types}
    leaves = []
    for k, f in enumerate(frames):
        if f.type != body_type or k in has_child:
            continue
        parent = _frame_parent_joint(f)
        if parent == 0:
            continue  # welded to the universe: it never moves
        leaves.append(TaskPoint(f.name, link_of[parent], np.array(f.placement.translation)))
    leaves.sort(key=lambda tp: 0 if "tcp" in tp.name.lower() else 1)  # stable: tool centre points first

    try:
        return build_model(model_name, bodies, gravity=np.array(pm.gravity.linear),
                           task_points=leaves if leaves else None, source=ModelSource("urdf", str(path.resolve())))
    except ModelError as exc:  # e.g. a massless link on a moving joint: say which file it came from
        raise ModelError(model_name, list(exc.problems) + [f"(from URDF file '{path}')"]) from None
