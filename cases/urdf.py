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
  FreeFlyer (a URDF ``floating`` joint, or the one ``base="free"`` adds) -> a ``free`` joint, Spherical (an MJCF
  ball, :mod:`cases.mjcf`) -> a ``spherical`` one, both with Pinocchio's conventions, which are ours
  (``cases.model``);
* mass, com, inertia about the COM: ``model.inertias[j]`` (joint frame = our body frame);
* gravity: ``model.gravity.linear``;
* source: ``ModelSource("urdf", <absolute path>)`` with the identity placement, so the external reference
  (``crosscheck.references.pinocchio.build``) builds its own model from the file and never from this conversion.

The base. A URDF tree hangs from one root link. With ``base="fixed"`` the root link is welded to the world (its
mass does not move and is left out, Pinocchio's reading of the file); with ``base="free"`` the loader adds a free
joint above it (``pinocchio.buildModelFromUrdf(path, JointModelFreeFlyer())``), so the root link is a floating base
with its mass. A file whose root joint is already ``floating`` (from a ``world`` link) loads free either way, and
``base="fixed"`` is refused for it. Left out (``base=None``), a file without a floating root joint loads fixed with
one :class:`BaseNotice` warning saying so and how to float it; none when the root link is named ``world``
(:data:`WORLD_LINK`): that link is the world frame by the ROS convention, and the joints hanging from it (fixed for
an arm bolted down) are the file's own statement of its base. The source records the choice (``ModelSource.root``),
so the reference reads the file the same way.

Inputs: the identity's columns of every joint velocity but a free joint's, whose six velocities are unactuated
(a floating base has no motor to the world). ``actuated`` (URDF joint names, e.g. ``["joint1", "joint3"]``; the
command line's ``--actuated joint1,joint3``) makes B the identity's columns of those joints only, in the order given:
``u[k]`` is the force or torque of ``actuated[k]``; an empty list (``--actuated ""``) makes the model passive, B with
no columns. A name that is not a movable joint of the file (unknown, fixed, floating, or given twice) is a
:class:`~cases.model.ModelError` listing the movable joints.

Task points: one per leaf link (a URDF link no joint hangs from), at that link's origin expressed in its
parent joint's frame, ranked (:func:`_leaf_rank`): sensor frames last (a word of the name, split at anything but
letters and digits, in :data:`SENSOR_WORDS`: ``narrow_stereo_..._optical_frame``, ``LFsrCenter_frame``), tool and
end-effector frames first (:data:`TOOL_WORDS`: ``panda_hand_tcp``, ``ee_link``, ``l_gripper_tool_frame``), then the
longest chain (the most joints with a coordinate: a humanoid's arm before its legs), then Pinocchio's frame order.
Leaves welded to the universe are skipped. The default (first) task
point is the first leaf that lies on no joint axis of its chain, with the task directions it moves in
(``cases.task.choose``): a leaf link's origin is often its own joint's origin, on its axis, where the task Jacobian
is rank-deficient at every state; then the leaf's COM (or an offset point of it) is the default, named
``LINK:com`` (``LINK:offset``), and a planar chain's task directions are its plane.

Armature: a URDF has no standard tag for a joint's rotor inertia, so ``armature`` (URDF joint name -> value, kg m^2
for a revolute or continuous joint, kg for a prismatic one; the command line's ``--armature JOINT=VALUE,...``) declares
it: the loader sets Pinocchio's ``model.armature`` of those joints' velocities and each body takes its joint's
(``Body.armature``, added to M's diagonal), and the source records the declaration (``ModelSource.armature``), so
the reference, which reads the file itself, sets the same. A name that is not a movable joint of the file (unknown
or fixed) or a value that is not finite and >= 0 is a :class:`~cases.model.ModelError` listing the movable joints.
A joint whose velocities have different armature in Pinocchio's model (not one value) is refused, naming it.

Mimic joints: a joint ``A`` with ``<mimic joint="J" multiplier="m" offset="o"/>`` (defaults m = 1, o = 0) keeps its
own coordinate and gets the coupling ``q_A = m q_J + o`` as a constraint,
``JointCoupling("mimic:A", (body of A, body of J), (1, -m), o)`` (``cases.constraints``), in Pinocchio's joint
order of ``A``. The mimic joint keeps its column of the identity input map. Pinocchio is asked to ignore the tags
(``mimic=False``), so the tags are read from the XML here, and the reference reads them from the file again and
checks the declaration (``crosscheck.references.pinocchio.reference``). Panda: 9 coordinates, ``panda_finger_joint2``
mimics ``panda_finger_joint1``, one constraint row. A mimic tag on a fixed joint constrains nothing (the joint has no
coordinate) and is ignored with one :class:`MimicNotice`, as Pinocchio ignores it (TALOS's grippers). A mimic of a
joint that does not exist is ignored too, as a model finding (``Model.findings``; alex_psyonic_hands names
``index_q1`` for ``Left_index_q1``). Refused (:class:`~cases.model.ModelError`, naming the joint): a mimic of itself,
of a fixed joint or of a joint that is itself a mimic (a chain), a multiplier that is 0, not a number or not finite,
an offset that is not a finite number.

Before Pinocchio parses, the file is read here and checked to be a URDF tree: XML whose root is ``<robot>``, every
joint attaching two distinct links that exist, no link the child of two joints, no chain of joints that closes on
itself (a cycle Pinocchio would drop silently) and one root link. A URDF describes a tree; a closed loop belongs in
the model's constraint declarations (``cases.constraints.PointsCoincide``). What urdfdom (Pinocchio's parser) prints
while it rejects a file becomes part of the :class:`UrdfError`, one message.

Pinocchio is imported inside :func:`from_urdf`, so importing :mod:`cases` does not import it.
"""

from __future__ import annotations

import contextlib
import difflib
import math
import os
import re
import sys
import tempfile
import warnings
import xml.etree.ElementTree as ET
from pathlib import Path
from typing import NamedTuple, Sequence

import numpy as np

from cases import task
from cases.build import build_model
from cases.constraints import JointCoupling
from cases.model import JOINT_DOF, Body, Model, ModelError, ModelSource, TaskPoint


class UrdfError(ValueError):
    """A URDF file cannot be read or parsed (the message names the path)."""


#: The name of a root link that stands for the world frame (the ROS convention for a robot fixed to the world by its
#: own joint from it): a file with it says how its base is held, so loading it fixed needs no notice.
WORLD_LINK = "world"


class LoadNotice(UserWarning):
    """Something a loader did with a file that the user should know and may want to change (one line each)."""


class BaseNotice(LoadNotice):
    """A URDF file loaded with a fixed base because no base was asked for (module docstring, "The base")."""


class MimicNotice(LoadNotice):
    """``<mimic>`` tags on fixed joints, ignored: a fixed joint has no coordinate to couple (module docstring)."""


#: The ``base`` values of :func:`from_urdf`.
BASES = ("fixed", "free")


class Mimic(NamedTuple):
    """A URDF ``<mimic>`` tag of joint ``joint``: ``q_joint = multiplier * q_mimicked + offset``."""

    joint: str
    mimicked: str
    multiplier: float
    offset: float


_UNIT = {"X": (1.0, 0.0, 0.0), "Y": (0.0, 1.0, 0.0), "Z": (0.0, 0.0, 1.0)}
_LOOP_HINT = ("a URDF describes a tree; declare a closed loop as a constraint of the model "
              "(cases.constraints.PointsCoincide)")


# ------------------------------------------------------------------------------------------------ the XML


def _read_robot(path: Path) -> ET.Element:
    """The file's ``<robot>`` element. FileNotFoundError for a missing path; UrdfError for a directory, a file that
    cannot be read, text that is not XML and XML whose root is not ``<robot>``."""
    if path.is_dir():
        raise UrdfError(f"URDF path '{path}' is a directory, not a file")
    if not path.exists():
        raise FileNotFoundError(f"URDF file not found: '{path}'")
    try:
        text = path.read_bytes()
    except OSError as exc:
        raise UrdfError(f"cannot read URDF file '{path}': {exc.strerror or exc}") from None
    try:
        root = ET.fromstring(text)
    except ET.ParseError as exc:
        raise UrdfError(f"URDF file '{path}' is not XML ({exc})" if text.strip() else
                        f"URDF file '{path}' is empty") from None
    if root.tag != "robot":
        raise UrdfError(f"URDF file '{path}' is XML whose root element is <{root.tag}>, not <robot>")
    return root


def _joint_links(robot: ET.Element) -> dict[str, tuple[str | None, str | None]]:
    """URDF joint name -> (parent link, child link), None where the tag or its ``link`` is missing (urdfdom
    reports those)."""
    out = {}
    for joint in robot.findall("joint"):
        parent, child = joint.find("parent"), joint.find("child")
        out[joint.get("name")] = (None if parent is None else parent.get("link"),
                                  None if child is None else child.get("link"))
    return out


def _tree_problems(robot: ET.Element) -> list[str]:
    """What keeps the joints from forming one tree of links: a joint on an unknown link or on one link twice, a link
    that is the child of two joints, a chain of joints that closes on itself, more than one root link."""
    links = {link.get("name") for link in robot.findall("link")}
    joints = _joint_links(robot)
    names = [j.get("name") for j in robot.findall("joint")]
    problems = [f"joint name '{name}' is used by {names.count(name)} joints; each URDF joint needs its own name"
                for name in sorted(set(names) - {None}) if names.count(name) > 1]
    problems += [f"{names.count(None)} <joint> element(s) have no name attribute"] if None in names else []
    if problems:
        return problems
    parent_joint: dict[str, list[str]] = {}
    for name, (parent, child) in joints.items():
        if parent is None or child is None:
            problems.append(f"joint '{name}' has no <{'parent' if parent is None else 'child'} link=\"...\"/>")
            continue
        unknown = [link for link in (parent, child) if link not in links]
        if unknown:
            problems.append(f"joint '{name}' names link(s) {unknown} that the file does not define")
        elif parent == child:
            problems.append(f"joint '{name}' attaches link '{child}' to itself; {_LOOP_HINT}")
        else:
            parent_joint.setdefault(child, []).append(name)
    problems += [f"link '{child}' is the child of {len(owners)} joints {owners}; {_LOOP_HINT}"
                 for child, owners in parent_joint.items() if len(owners) > 1]
    if problems:
        return problems
    problems += _cycles(joints, parent_joint)
    roots = sorted(link for link in links if link not in parent_joint)
    if len(roots) > 1 and not problems:
        problems.append(f"links {roots} have no parent joint; a URDF tree has one root link")
    return problems


def _cycles(joints: dict, parent_joint: dict[str, list[str]]) -> list[str]:
    """One problem per chain of joints that closes on itself (each link has one parent joint here)."""
    found, problems = set(), []
    for start in parent_joint:
        seen, link = [], start
        while link in parent_joint and link not in seen:
            seen.append(link)
            link = joints[parent_joint[link][0]][0]
        if link in seen:
            cycle = [parent_joint[x][0] for x in seen[seen.index(link):]]
            if frozenset(cycle) not in found:
                found.add(frozenset(cycle))
                problems.append(f"joints {cycle} form a closed chain (each is the parent of the next one's link), so "
                                f"their links never reach the root; {_LOOP_HINT}")
    return problems


def _massless_inertias(robot: ET.Element) -> list[str]:
    """A model finding for each link welded by a fixed joint whose ``<inertial>`` has mass 0 and a rotational inertia:
    physically impossible, and read differently by different tools. Pinocchio (so the model) keeps the rotational
    inertia, adding it to the body the link is welded to; MuJoCo and iDynTree drop a massless link's; Drake's parser
    makes it a 1 kg sphere. (A moving body with it is the model's own finding, ``cases.build``.)"""
    welded = {j.find("child").get("link") for j in robot.iter("joint")
              if j.get("type") == "fixed" and j.find("child") is not None}
    out = []
    for link in (link for link in robot.iter("link") if link.get("name") in welded):
        inertial = link.find("inertial")
        mass = None if inertial is None else inertial.find("mass")
        tensor = None if inertial is None else inertial.find("inertia")
        if mass is None or tensor is None:
            continue
        try:
            moments = [float(tensor.get(k, 0.0)) for k in ("ixx", "iyy", "izz", "ixy", "ixz", "iyz")]
            massless = float(mass.get("value", "nan")) == 0.0
        except ValueError:
            continue
        if massless and any(moments):
            out.append(f"link '{link.get('name')}' has mass 0 and a rotational inertia (ixx, iyy, izz = "
                       f"{moments[0]:g}, {moments[1]:g}, {moments[2]:g}): no body has one without the other; the "
                       "model keeps the inertia (Pinocchio's reading), other tools drop it or replace it")
    return out


def _mimics(robot: ET.Element, problems: list[str], findings: list[str]) -> list[Mimic]:
    """The ``<mimic>`` tags (module docstring), appending to ``problems`` the ones that cannot be a coupling and to
    ``findings`` the ones that name no joint of the file (ignored)."""
    types = {j.get("name"): j.get("type") for j in robot.findall("joint")}
    tags = [(j.get("name"), j.find("mimic")) for j in robot.findall("joint") if j.find("mimic") is not None]
    fixed = [name for name, _ in tags if types[name] == "fixed"]
    if fixed:
        warnings.warn(MimicNotice(f"{len(fixed)} fixed joint(s) carry a <mimic> tag, ignored: a fixed joint has no "
                                  f"coordinate to couple ({', '.join(fixed)})"), stacklevel=3)
    for name, tag in tags:
        target = tag.get("joint")
        if target is not None and target not in types:
            near = difflib.get_close_matches(target, list(types), n=1)
            findings.append(f"joint '{name}' mimics joint '{target}', which does not exist: the tag is ignored, so "
                            f"'{name}' moves freely" + (f" (did the file mean '{near[0]}'?)" if near else ""))
    tags = [(name, tag) for name, tag in tags if types[name] != "fixed" and tag.get("joint") in (None, *types)]
    mimicking = {name for name, _ in tags}
    problems += [f"joint '{j.get('name')}' has {len(j.findall('mimic'))} <mimic> tags; a joint follows one joint"
                 for j in robot.findall("joint") if len(j.findall("mimic")) > 1]
    out = []
    for name, tag in tags:
        where = f"joint '{name}' mimics joint '{tag.get('joint')}'"
        n_before = len(problems)
        multiplier = _mimic_number(problems, where, tag, "multiplier", 1.0)
        offset = _mimic_number(problems, where, tag, "offset", 0.0)
        problems += _mimic_problems(where, name, tag.get("joint"), types, mimicking)
        if multiplier == 0.0:
            problems.append(f"{where} with multiplier 0, which would lock it at its offset; remove the mimic and "
                            "make the joint fixed")
        if len(problems) == n_before:
            out.append(Mimic(name, tag.get("joint"), multiplier, offset))
    return out


def _mimic_problems(where: str, name: str, target: str | None, types: dict, mimicking: set) -> list[str]:
    """Why joint ``name`` cannot follow joint ``target`` (``types``: joint name -> URDF type), if it cannot."""
    problems = []
    if target is None:
        problems.append(f"joint '{name}' has a <mimic> without a joint attribute; name the joint it follows")
    elif target == name:
        problems.append(f"{where}, itself")
    elif target in mimicking:
        problems.append(f"{where}, which itself mimics another joint; a mimic chain is not supported: let "
                        f"'{name}' mimic the joint at the start of the chain")
    elif types[target] == "fixed":
        problems.append(f"{where}, a fixed joint with no coordinate; remove the tag, or make '{name}' fixed too if "
                        "it does not move")
    return problems


def _mimic_number(problems: list[str], where: str, tag: ET.Element, attribute: str, default: float) -> float:
    """A finite number from the mimic tag's ``attribute`` (``default`` if absent), else NaN and a problem."""
    text = tag.get(attribute)
    if text is None:
        return default
    try:
        value = float(text)
    except ValueError:
        value = math.nan
    if not math.isfinite(value):
        problems.append(f"{where} with {attribute} {text!r}; give a finite number")
    return value


# ----------------------------------------------------------------------------------------------- Pinocchio


def _parse(pin, path: Path, root: str = "fixed"):
    """``pinocchio.buildModelFromUrdf(path)`` (:func:`read_file`), with urdfdom's printout (C++, on file
    descriptor 2) made part of the UrdfError instead of extra lines on the console. An error urdfdom reports is fatal
    even when Pinocchio returns a model: urdfdom skips what it cannot read (a link whose inertial has a NaN becomes
    massless), so that model is not the file's. Whatever else it printed is passed on."""
    with _fd2_captured() as printed:
        try:
            pm, error = read_file(pin, "urdf", str(path), root), None
        except Exception as exc:  # noqa: BLE001 - Pinocchio raises ValueError/RuntimeError/... for bad files
            pm, error = None, exc
    reasons = [line.split(":", 1)[1].strip() for line in printed[0].splitlines() if line.startswith("Error:")]
    if error is None and not reasons:
        sys.stderr.write(printed[0])
        return pm
    if error is not None:
        detail = " ".join(str(error).split()) + (f" (urdfdom: {'; '.join(reasons)})" if reasons else "")
    else:
        detail = f"urdfdom reported errors and skipped what it could not read: {'; '.join(reasons)}"
    raise UrdfError(f"could not parse URDF file '{path}': {detail}; Pinocchio's parser (urdfdom) reads the file for "
                    "the reference and for crosscheck alike, so fix what it names (check_urdf, from urdfdom, shows "
                    "the same)")


@contextlib.contextmanager
def _fd2_captured():
    """File descriptor 2 redirected to a temporary file; yields a one-item list that holds the text afterwards."""
    printed = [""]
    sys.stderr.flush()
    saved = os.dup(2)
    with tempfile.TemporaryFile() as tmp:
        os.dup2(tmp.fileno(), 2)
        try:
            yield printed
        finally:
            os.dup2(saved, 2)
            os.close(saved)
            tmp.seek(0)
            printed[0] = tmp.read().decode(errors="replace")


def _joint_kind(jm) -> tuple[str, np.ndarray] | None:
    """(our joint type, axis) for a supported Pinocchio joint model, else None."""
    short = jm.shortname()
    kind = short.removeprefix("JointModel")
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
    if kind in ("FreeFlyer", "Spherical"):
        return ("free" if kind == "FreeFlyer" else "spherical"), np.zeros(3)
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


def _links_of(pin, pm) -> dict[int, str | None]:
    """Pinocchio joint index -> the link it moves: the BODY frame hanging right after that joint's JOINT frame
    (the universe, 0 -> None)."""
    frames = list(pm.frames)
    joint_frame = {_frame_parent_joint(f): k for k, f in enumerate(frames) if f.type == pin.FrameType.JOINT}
    link_of: dict[int, str | None] = {0: None}
    for j in range(1, pm.njoints):
        link_of[j] = next((f.name for f in frames if f.type == pin.FrameType.BODY and _frame_parent_joint(f) == j
                           and j in joint_frame and _frame_previous(f) == joint_frame[j]), pm.names[j])
    return link_of


def _bodies(pm, link_of: dict, problems: list[str]) -> list[Body]:
    """One body per Pinocchio joint (module docstring); a joint type with no equivalent here is a problem."""
    bodies: list[Body] = []
    for j in range(1, pm.njoints):
        jm = pm.joints[j]
        kind = _joint_kind(jm)
        if kind is None:
            problems.append(f"joint '{pm.names[j]}' has Pinocchio type {jm.shortname()}, which has no equivalent "
                            "here (supported: revolute, continuous, prismatic, fixed, floating; MJCF hinge, slide, "
                            "ball, free, one joint per body)")
            continue
        joint, axis = kind
        placement, inertia = pm.jointPlacements[j], pm.inertias[j]
        bodies.append(Body(name=link_of[j], parent=link_of[pm.parents[j]], joint=joint, axis=axis,
                           mass=float(inertia.mass), com=np.array(inertia.lever),
                           inertia=np.array(inertia.inertia), rotation=np.array(placement.rotation),
                           translation=np.array(placement.translation), limits=_position_limits(pm, j, jm),
                           armature=_joint_armature(pm, j, jm, problems)))
    return bodies


def _joint_armature(pm, j: int, jm, problems: list[str]) -> float:
    """The armature of Pinocchio joint ``j`` (``pm.armature`` over its velocities: an MJCF file's ``<joint
    armature>``, or what :func:`apply_armature` declared), one value for the joint (``Body.armature``); a problem
    naming the joint when its velocities have different values, which the model language cannot hold."""
    values = np.asarray(pm.armature, dtype=float)[jm.idx_v:jm.idx_v + jm.nv]
    if values.size and np.any(values != values[0]):
        problems.append(f"joint '{pm.names[j]}' has armature {values.tolist()} over its {jm.nv} velocities; the model "
                        "language holds one armature per joint, added to each of its velocities")
        return 0.0
    return float(values[0]) if values.size else 0.0


def apply_armature(pm, armature: Sequence[tuple[str, float]]) -> None:
    """Set ``pm.armature`` of each named joint's velocities to its value (``ModelSource.armature``: what the user
    declared for a file that cannot say it)."""
    values = np.array(pm.armature, dtype=float)
    for name, value in armature:
        jm = pm.joints[pm.getJointId(name)]
        values[jm.idx_v:jm.idx_v + jm.nv] = value
    pm.armature = values


#: Beyond this a position limit is taken as none: Pinocchio fills a joint without limits with the largest double.
UNLIMITED = 1e10


def _position_limits(pm, j: int, jm) -> tuple[float, float] | None:
    """The file's position limits of a one-coordinate joint (revolute, prismatic; a continuous joint has nq 2 in
    Pinocchio and no limits), or None (then the joint is sampled freely) where there are none (a bound beyond
    :data:`UNLIMITED`), where the file gives lower > upper, or where the range is empty, lower = upper: URDF's
    ``<limit effort=".." velocity=".."/>`` without ``lower`` and ``upper`` reads as (0, 0), which would hold the joint
    at 0 in every sampled state and leave its dynamics unchecked."""
    if jm.nq != 1:
        return None
    lower, upper = float(pm.lowerPositionLimit[jm.idx_q]), float(pm.upperPositionLimit[jm.idx_q])
    if not (abs(lower) < UNLIMITED and abs(upper) < UNLIMITED and lower < upper):
        return None
    return lower, upper


def _actuated(bodies: list[Body]) -> np.ndarray:
    """B: the identity's columns of every joint velocity but a free joint's. A file's joints are driven; a free joint
    (a floating base) is not: no motor acts between it and the world (``B u`` has zero base rows)."""
    driven = [j == "driven" for b in bodies for j in (["free"] * 6 if b.joint == "free" else
                                                       ["driven"] * JOINT_DOF[b.joint][1])]
    return np.eye(len(driven))[:, driven]


def _named_inputs(robot: ET.Element, actuated, problems: list[str]) -> list[str]:
    """The child links of the ``actuated`` URDF joints (module docstring, "Inputs"), in the order given; a problem
    for each name that is not a movable joint of the file, or given twice."""
    if isinstance(actuated, str) or not all(isinstance(name, str) for name in actuated):
        problems.append(f"actuated must be a list of URDF joint names, got {actuated!r}")
        return []
    types = {j.get("name"): j.get("type") for j in robot.findall("joint")}
    movable = sorted(name for name, kind in types.items() if kind in ("revolute", "continuous", "prismatic"))
    n_before = len(problems)
    problems += [f"actuated names joint '{name}' {actuated.count(name)} times; name each joint once"
                 for name in sorted(set(actuated)) if actuated.count(name) > 1]
    for name in dict.fromkeys(actuated):
        if name not in types:
            problems.append(f"actuated joint '{name}' is not a joint of the file; movable joints: {movable}")
        elif name not in movable:
            problems.append(f"actuated joint '{name}' is {types[name]}, which no motor drives here; movable joints: "
                            f"{movable}")
    links = _joint_links(robot)
    return [] if len(problems) > n_before else [links[name][1] for name in actuated]


def _declared(robot: ET.Element, armature, problems: list[str]) -> tuple[tuple[str, float], ...]:
    """The ``armature`` argument of :func:`from_urdf` (URDF joint name -> rotor inertia; module docstring,
    "Armature") as ``(name, value)`` pairs in the file's joint order; a problem for a name that is not a movable joint
    of the file and for a value that is not a finite number >= 0."""
    if armature is None:
        return ()
    if not isinstance(armature, dict):
        problems.append(f"armature must be a dict of URDF joint name -> rotor inertia, got {armature!r}")
        return ()
    types = {j.get("name"): j.get("type") for j in robot.findall("joint")}
    movable = sorted(name for name, kind in types.items() if kind in ("revolute", "continuous", "prismatic",
                                                                      "floating"))
    n_before = len(problems)
    for name, value in armature.items():
        if name not in types:
            problems.append(f"armature names joint '{name}', which is not a joint of the file; movable joints: "
                            f"{movable}")
        elif name not in movable:
            problems.append(f"armature names joint '{name}', which is {types[name]} (it has no velocity to add a "
                            f"rotor inertia to); movable joints: {movable}")
        try:
            number = float(value)
        except (TypeError, ValueError):
            number = math.nan
        if isinstance(value, bool) or not (math.isfinite(number) and number >= 0.0):
            problems.append(f"armature of joint '{name}' is {value!r}; give a finite rotor inertia >= 0 (kg m^2 for "
                            "a revolute joint, kg for a prismatic one)")
    if len(problems) > n_before:
        return ()
    order = list(types)
    return tuple((name, float(armature[name]) + 0.0) for name in sorted(armature, key=order.index))


def _input_map(bodies: list[Body], driven_links: list[str] | None) -> np.ndarray:
    """B (module docstring, "Inputs"): :func:`_actuated`, or the identity's columns of the bodies ``driven_links``
    names (each a one-velocity joint), in that order."""
    if driven_links is None:
        return _actuated(bodies)
    index = {b.name: k for k, b in enumerate(bodies)}
    nv = sum(JOINT_DOF[b.joint][1] for b in bodies)
    starts = np.cumsum([0] + [JOINT_DOF[b.joint][1] for b in bodies[:-1]])
    return np.eye(nv)[:, [int(starts[index[link]]) for link in driven_links]]


def _couplings(pm, link_of: dict, mimics: list[Mimic]) -> list[JointCoupling]:
    """The mimic tags as joint couplings on the bodies the joints move, in Pinocchio's order of the mimic joints."""
    by_joint = sorted(mimics, key=lambda m: pm.getJointId(m.joint))
    return [JointCoupling(f"mimic:{m.joint}", (link_of[pm.getJointId(m.joint)], link_of[pm.getJointId(m.mimicked)]),
                          (1.0, -m.multiplier), m.offset) for m in by_joint]


#: Words of a link name (split at anything but letters and digits) that make a leaf a tool or end-effector frame,
#: and words that make it a sensor frame (unless it is also a tool: a force sensor's tool side, ``wrist_ft_tool_link``).
TOOL_WORDS = frozenset({"tcp", "tool", "ee", "eef", "effector", "flange", "grasping"})
SENSOR_WORDS = frozenset({"camera", "cam", "optical", "stereo", "kinect", "depth", "rgb", "sensor", "imu", "laser",
                          "lidar", "hokuyo", "sonar", "scan", "gazebo", "fsr", "accelerometer", "gyro", "itb", "led"})


def _words(tp: TaskPoint) -> set[str]:
    return set(re.split(r"[^a-z0-9]+", tp.name.lower()))


def _is_sensor(tp: TaskPoint) -> bool:
    return bool(_words(tp) & SENSOR_WORDS) and not _words(tp) & TOOL_WORDS


def _leaf_rank(tp: TaskPoint, chain: int) -> tuple[int, int, int]:
    """Sort key of a leaf as the default task point (module docstring, "Task points"): not a sensor frame, then a
    tool or end-effector frame, then the longest chain (``chain`` movable joints from the root)."""
    return int(_is_sensor(tp)), int(not _words(tp) & TOOL_WORDS), -chain


def _task_points(pin, pm, link_of: dict) -> list[TaskPoint]:
    """One task point per leaf link not welded to the universe, in the order of :func:`_leaf_rank` (stable)."""
    joint_types = (pin.FrameType.JOINT, pin.FrameType.FIXED_JOINT)
    has_child = {_frame_previous(f) for f in pm.frames if f.type in joint_types}
    ranked = []
    for k, f in enumerate(pm.frames):
        joint = _frame_parent_joint(f)
        if f.type == pin.FrameType.BODY and k not in has_child and joint != 0:
            tp = TaskPoint(f.name, link_of[joint], np.array(f.placement.translation))
            ranked.append((_leaf_rank(tp, _chain_length(pm, joint)), tp))
    return [tp for _, tp in sorted(ranked, key=lambda pair: pair[0])]


def _chain_length(pm, joint: int) -> int:
    """The number of joints with a coordinate from the universe down to ``joint``."""
    count = 0
    while joint != 0:
        count += pm.joints[joint].nv > 0
        joint = pm.parents[joint]
    return count


def _root(robot: ET.Element) -> tuple[str | None, str | None]:
    """(the root link, the name of its floating joint when the tree hangs from it by one, else None)."""
    joints = [j for j in robot.findall("joint")]
    children = {j.find("child").get("link") for j in joints if j.find("child") is not None}
    roots = [link.get("name") for link in robot.findall("link") if link.get("name") not in children]
    if len(roots) != 1:
        return None, None
    floating = [j.get("name") for j in joints if j.get("type") == "floating"
                and j.find("parent") is not None and j.find("parent").get("link") == roots[0]]
    return roots[0], (floating[0] if floating else None)


def _base(path: Path, robot: ET.Element, base: str | None, problems: list[str]) -> tuple[str, str | None]:
    """(the source root, "fixed" or "free", for ``base``; the notice to give once the file has loaded, or None)
    (module docstring, "The base"); a problem for an unknown ``base`` or a fixed base under a floating root joint."""
    root, floating = _root(robot)
    if base not in (None, *BASES):
        problems.append(f"base must be one of {list(BASES)} (or left out), got {base!r}")
        return "fixed", None
    if floating is not None:
        if base == "fixed":
            problems.append(f"the root joint '{floating}' of '{path}' is floating; the file floats its base, so it "
                            "cannot be loaded with base='fixed' (make that joint fixed in the file instead)")
        return "fixed", None    # Pinocchio reads the floating joint itself: no joint is added
    notice = None if base is not None or root == WORLD_LINK else (
        f"'{path}' has no joint between its root link '{root}' and the world: loaded with a fixed base (to float it: "
        "--base free, or cases.from_urdf(path, base='free'))")
    return base or "fixed", notice


def read_file(pin, kind: str, path: str, root: str = "fixed"):
    """The Pinocchio model of a file as the loaders read it: ``buildModelFromUrdf`` (with a ``JointModelFreeFlyer``
    root joint for ``root="free"``) or ``buildModelFromMJCF``. The reference
    (``crosscheck.references.pinocchio.reference``) reads the file with this call too, so both see the same joints."""
    if kind == "mjcf":
        return pin.buildModelFromMJCF(path)
    return pin.buildModelFromUrdf(path, pin.JointModelFreeFlyer()) if root == "free" else pin.buildModelFromUrdf(path)


def from_urdf(path, name: str | None = None, base: str | None = None, actuated=None, armature=None) -> Model:
    """Load the URDF at ``path`` as a :class:`Model` (joint order = Pinocchio's; see the module docstring), with a
    ``base`` "fixed" or "free" (module docstring, "The base"; left out: fixed, with a :class:`BaseNotice`), with
    ``actuated`` (URDF joint names) the input map of those joints only (module docstring, "Inputs") and with
    ``armature`` (URDF joint name -> rotor inertia) those joints' armature (module docstring, "Armature").

    Raises :class:`FileNotFoundError` if the path does not exist, :class:`UrdfError` if it cannot be read or
    parsed, and :class:`~cases.model.ModelError` naming every joint whose type has no equivalent here (planar,
    helical, ...), every mimic tag that is no coupling and every joint that keeps the links from forming a tree, or
    if the converted model is invalid.
    """
    path = Path(path)
    robot = _read_robot(path)
    model_name = name if name is not None else robot.get("name") or path.stem
    problems, findings = _tree_problems(robot), _massless_inertias(robot)
    mimics = _mimics(robot, problems, findings)
    driven = None if actuated is None or problems else _named_inputs(
        robot, actuated if isinstance(actuated, str) else list(actuated), problems)
    declared = _declared(robot, armature, problems) if not problems else ()
    root, notice = _base(path, robot, base, problems) if not problems else ("fixed", None)
    if problems:
        raise ModelError(model_name, problems, f"URDF file '{path}'")
    try:
        import pinocchio as pin
    except ImportError as exc:  # pragma: no cover - pin is a declared dependency
        raise ImportError("reading URDF files needs Pinocchio: install the 'pin' package "
                          "(pip install pin)") from exc
    source = ModelSource("urdf", str(path.resolve()), root=root, armature=declared)
    pm = _parse(pin, path, root)
    apply_armature(pm, declared)
    model = convert(pin, pm, model_name, source, mimics, driven, findings)
    if notice is not None:
        warnings.warn(BaseNotice(notice), stacklevel=2)
    return model


def convert(pin, pm, model_name: str, source: ModelSource, mimics: list[Mimic] = (),
            driven_links: list[str] | None = None, findings: Sequence[str] = ()) -> Model:
    """Our :class:`Model` of a parsed Pinocchio model (module docstring): bodies, gravity, task points, the mimic
    couplings, the input map (of the bodies ``driven_links`` names, else every joint but a free one), the file's
    ``source`` and the loader's ``findings`` (``Model.findings``); a ModelError naming the file for what cannot be
    converted."""
    problems: list[str] = []
    link_of = _links_of(pin, pm)
    bodies = _bodies(pm, link_of, problems)
    where = f"{source.kind.upper()} file '{source.path}'"
    if not bodies and not problems:
        problems.append(_nothing_moves(source))
    if problems:
        raise ModelError(model_name, problems, where)
    leaves = _task_points(pin, pm, link_of)
    try:
        model = build_model(model_name, bodies, gravity=np.array(pm.gravity.linear),
                            input_map=_input_map(bodies, driven_links),
                            task_points=leaves if leaves else None, constraints=_couplings(pm, link_of, mimics),
                            source=source, findings=findings)
    except ModelError as exc:  # e.g. a massless link on a moving joint: say which file it came from
        raise ModelError(model_name, exc.problems, where) from None
    return _with_default_task_point(model, leaves, source)


def _nothing_moves(source: ModelSource) -> str:
    """The problem of a file without a movable joint, with the way to make it move: a URDF loaded with a fixed base
    welds its root link to the world (a lone body, a quadrotor: ``--base free`` floats it); an MJCF body moves only on
    its own joints (a ``<freejoint/>`` floats it)."""
    if source.kind == "urdf" and source.root == "fixed":
        return ("no movable joint: with a fixed base its root link is welded to the world and nothing moves; a "
                "free-flying body (a quadrotor, a lone rigid body) floats with --base free (cases.from_urdf(path, "
                "base='free'))")
    if source.kind == "mjcf":
        return "no movable joint: a body without a joint is welded to the world; give it a <freejoint/> to float it"
    return "no movable joint"


def _with_default_task_point(model: Model, leaves: list[TaskPoint], source: ModelSource) -> Model:
    """``model`` with the first leaf that lies on no joint axis (or a point of a leaf body, ``cases.task.choose``) as
    its default task point, the other leaves after it (module docstring, "Task points")."""
    if not leaves:
        return model
    kind = source.kind.upper()
    tried = [tp for tp in leaves if not _is_sensor(tp)] or leaves           # a sensor frame only when all are
    chosen = task.choose(model, tried, [f"the {kind} leaf link '{tp.name}' (its origin)" for tp in tried])
    rest = [tp for tp in model.task_points if tp.name != chosen.name]
    return build_model(model.name, model.bodies, gravity=model.gravity, input_map=model.input_map,
                       task_points=[chosen, *rest], constraints=model.constraints, source=model.source,
                       findings=model.findings)
