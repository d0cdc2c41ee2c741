"""A second, independent reading of a URDF file, compared with the model the loader converted from it.

Every model the gate checks from a URDF is read by one parser, Pinocchio's urdfdom (``cases.urdf``), for the five
formalisms and for the Pinocchio reference alike: a misreading there (an inertial frame's rotation ignored, a fixed
joint's placement dropped, an axis's sign lost) moves every voter together, and the vote passes a wrong model. This
module reads the file again with :mod:`xml.etree`, by the URDF rules, without Pinocchio and without the loader
(nothing of ``cases.urdf`` is used), builds what each body of the converted model must be, and compares the two body
by body. A difference beyond rounding is a **loader finding** (:class:`Finding`), naming the link and the field; the
gate fails the case at its preparation, before any dynamics runs (``crosscheck.guards.loader``).

The reading (the URDF specification; urdfdom reads it so):

* A link's ``<inertial>``: ``<mass value>``, ``<inertia ixx ixy ixz iyy iyz izz>`` (about the COM, in the inertial
  frame) and ``<origin xyz rpy>`` (the inertial frame in the link frame; absent: the identity). In the link frame
  the COM is ``xyz`` and the inertia about it ``R I R^T``, ``R = R(rpy)``. A link without ``<inertial>`` is massless.
  A mass without ``<inertia>`` (or an entry left out) reads as a point mass (zeros), as Pinocchio's model of such a
  file has it; urdfdom reports the file as an error, and the loader refuses it.
* A joint's ``<origin xyz rpy>``: the joint frame in the parent link's frame, ``(R(rpy), xyz)``; the child link's
  frame is the joint frame moved by the joint. ``rpy`` are fixed-axis roll, pitch, yaw: ``R = Rz(y) Ry(p) Rx(r)``.
  (``quat_xyzw``, which recent urdfdom reads in place of ``rpy``, is read too.)
* ``<axis xyz>`` (default ``1 0 0``), normalized, in the joint frame: the loader keeps a joint frame as the file
  gives it and a URDF axis off x, y and z as the axis of a ``RevoluteUnaligned`` (``PrismaticUnaligned``) joint in that
  frame, so the axis is compared in the joint frame as it is.
* Types: ``revolute`` and ``continuous`` -> ``revolute`` (a continuous joint has no limits), ``prismatic`` ->
  ``prismatic``, ``floating`` -> ``free``; ``fixed`` welds (below). ``planar`` (and any other type) has no
  equivalent in the model language: the loader refuses such a file, and a body on one would be a finding.
* Limits: a ``revolute`` or ``prismatic`` joint's ``<limit lower upper>``, by the rule of
  :func:`limit` (shared with ``crosscheck.guards.file_limits``): an absent bound reads 0, and a range that is empty,
  reversed, or beyond :data:`UNLIMITED` is no limit.
* ``<mimic joint multiplier offset>`` (defaults 1, 0) on a movable joint ``A`` following an existing joint ``J``: the
  coupling ``mimic:A`` of the bodies of ``A`` and ``J`` with coefficients ``(1, -multiplier)`` and the offset. A tag
  on a fixed joint, or naming no joint of the file, couples nothing (the loader ignores both and says so).
* The fixed-joint merge: a link attached by a ``fixed`` joint is welded into the body of its parent link (the body
  whose movable joint is nearest above it). Its placement in that body's frame is the composition of the fixed joints'
  origins down from the body's link; its mass, COM and inertia are moved into the body frame and summed with the
  parallel-axis theorem: ``M = sum m_i``, ``C = sum m_i c_i / M``, ``I_C = sum (R_i I_i R_i^T + m_i (|d_i|^2 1 -
  d_i d_i^T))`` with ``d_i = c_i - C``. A movable joint below a welded link is placed in the body frame by the same
  composition. A massless body has no centre of mass (``C`` is not compared there: no equation reads it).
* The root: for ``ModelSource.root == "fixed"`` the root link is the world (it and everything welded to it do not
  move: no body); a ``floating`` joint from it (a ``world`` link) moves its child as a ``free`` body. For
  ``root == "free"`` the root link is itself a body on a ``free`` joint at the identity placement, with everything
  welded to it. The bodies are named by the link each joint moves, as the loader names them.
* A model whose source places the file's world elsewhere (``ModelSource.rotation``, ``translation``, a moved scene)
  has that placement composed onto the placements of the bodies on the world.

Geometry (``<visual>``, ``<collision>``, meshes, ``package://`` paths), ``<transmission>``, ``<gazebo>`` and
``<dynamics>`` are no part of the model and are not read.

Tolerance: rounding only
------------------------
Both readings evaluate the same closed-form expressions of the same decimal numbers of the file, in different
orders: the loader through urdfdom (rpy -> a quaternion -> a matrix, ``SE3`` products, ``Inertia +=``), this module
through numpy (rpy -> a matrix, matrix products, sums). Each reading parses each number to the nearest double (error
``u = 2^-53`` relative) and computes each quantity with a few tens of floating-point operations per fixed joint it
composes; the classical bound for such an evaluation is ``|computed - exact| <= gamma_k S``, ``gamma_k = k u / (1 -
k u)``, where ``k`` is the length of the longest chain of operations and ``S`` the same expression evaluated on the
absolute values of its terms (the field's *scale*). Two readings within ``gamma_k S`` of the exact value are within
``2 gamma_k S`` of each other. :data:`ROUNDING` = 1e-12 = ``2 gamma_k`` for ``k`` about 2250: a rotation from rpy is
about 30 operations (the sines and cosines, the quaternion and its normalization, the matrix), each composed
placement about 15 more per entry, each welded link's inertia about 40, so 1e-12 covers any chain of fixed joints
and welded links up to about 100 deep, far beyond real files (TALOS: 3). A physical misreading is far above it: the
smallest change a file can express in a 6-digit number is 1e-6 relative, and a dropped rpy, a sign, a unit or a
swapped axis is of order 1. The scales, per field (so the tolerance is ``ROUNDING * S`` and tracks cancellation):

* mass: ``sum m_i`` over the welded links (a sum of positive terms: its own size);
* COM: ``sum m_i (|c_i| + L_i) / M`` with ``c_i`` the COM in the link's inertial origin and ``L_i`` the summed
  lengths of the translations composed from the body's link to link ``i`` (what rounding in ``R c + t`` scales with);
* inertia about the COM: ``sum_i (sum_ab |I_i,ab| + m_i (|c_i| + L_i + |C|)^2)``: each rotated inertia's entries
  are bounded by the sum of its entries' sizes (``|R| <= 1``), each parallel-axis term by ``m |d|^2``, ``|d| <= |c_i|
  + L_i + |C|``, and the result (about the COM) may be much smaller than these terms (cancellation);
* placement rotation: 1 (entries of rotation matrices); placement translation: ``sum |t_k|`` over the composed
  origins (at least the translation's own size);
* axis: 1, plus :data:`AXIS_SNAP`: Pinocchio takes an axis within ``1e-12 |a|`` of x, y or z (Eigen's ``isApprox``
  at its dummy precision) to be exactly that axis, a documented rounding of the loader, not a misreading;
* limits, mimic multipliers and offsets: the number's own size (both read the same decimal; no arithmetic but a sign).

The joint type, the parent body, the presence of a body, a limit or a coupling are compared exactly. A finding's
``ratio`` is its difference over its tolerance (infinite for what is compared exactly), so that the self-test can
prove the comparison is no looser than this (``crosscheck.guards.selftest``).

The measured cost, reading and comparing, is a few milliseconds per file (a UR5: 1.6 ms, TALOS and iCub: 8 to 11 ms,
TIAGo dual's 101 bodies: 22 ms; docs/design.md, "The second reading of a model file").
"""

from __future__ import annotations

import math
import xml.etree.ElementTree as ET
from dataclasses import dataclass, field

import numpy as np

from cases.constraints import JointCoupling
from cases.model import Model

#: Two readings of one field within this much of its scale agree (module doc, "Tolerance: rounding only").
ROUNDING = 1e-12
#: How far from x, y or z an axis may be that Pinocchio takes to be exactly x, y or z (``Eigen::isApprox`` at the
#: dummy precision of a double): the loader's own documented rounding of an axis (module doc).
AXIS_SNAP = 1e-12
#: A bound this large or larger is "no limit" (a file's way of writing none; Pinocchio fills the largest double).
UNLIMITED = 1e10

Limits = tuple[float, float] | None

#: URDF joint types -> the model's joint type (``fixed`` welds; anything else has no equivalent).
JOINT_TYPES = {"revolute": "revolute", "continuous": "revolute", "prismatic": "prismatic", "floating": "free"}


class FileReadingError(ValueError):
    """The file cannot be read by the URDF rules (the message says where)."""


# ------------------------------------------------------------------------------------------------- the rules


def limit(lower: float, upper: float) -> Limits:
    """``(lower, upper)`` if that is a joint limit, else None: both finite, below :data:`UNLIMITED` in size, and
    ``lower < upper`` (an empty or reversed range, or one a file writes as "huge", is no limit; the loaders drop those
    by the same rule, docs/faults.md, "Joint limits")."""
    if not (math.isfinite(lower) and math.isfinite(upper)) or max(abs(lower), abs(upper)) >= UNLIMITED:
        return None
    return (float(lower), float(upper)) if lower < upper else None


def number(text: str | None, default: float = 0.0) -> float:
    """A number attribute (``default`` when absent or blank, as urdfdom reads it)."""
    return default if text is None or not text.strip() else float(text)


def _vector(text: str | None, default=(0.0, 0.0, 0.0), size: int = 3) -> np.ndarray:
    if text is None or not text.strip():
        return np.array(default, dtype=float)
    values = [float(x) for x in text.split()]
    if len(values) != size:
        raise FileReadingError(f"'{text}' has {len(values)} numbers, not {size}")
    return np.array(values, dtype=float)


def rpy_matrix(rpy) -> np.ndarray:
    """URDF's fixed-axis roll, pitch, yaw: ``R = Rz(yaw) Ry(pitch) Rx(roll)``."""
    r, p, y = (float(a) for a in rpy)
    cr, sr, cp, sp, cy, sy = math.cos(r), math.sin(r), math.cos(p), math.sin(p), math.cos(y), math.sin(y)
    return np.array([[cy * cp, cy * sp * sr - sy * cr, cy * sp * cr + sy * sr],
                     [sy * cp, sy * sp * sr + cy * cr, sy * sp * cr - cy * sr],
                     [-sp, cp * sr, cp * cr]])


def _quaternion_matrix(xyzw: np.ndarray) -> np.ndarray:
    norm = float(np.linalg.norm(xyzw))
    if norm == 0.0:
        raise FileReadingError("quat_xyzw is zero")
    x, y, z, w = xyzw / norm
    return np.array([[1 - 2 * (y * y + z * z), 2 * (x * y - z * w), 2 * (x * z + y * w)],
                     [2 * (x * y + z * w), 1 - 2 * (x * x + z * z), 2 * (y * z - x * w)],
                     [2 * (x * z - y * w), 2 * (y * z + x * w), 1 - 2 * (x * x + y * y)]])


def _origin(element: ET.Element | None) -> tuple[np.ndarray, np.ndarray]:
    """``(R, xyz)`` of an element's first ``<origin>`` (the identity when there is none)."""
    origin = None if element is None else element.find("origin")
    if origin is None:
        return np.eye(3), np.zeros(3)
    if origin.get("quat_xyzw") is not None:
        rotation = _quaternion_matrix(_vector(origin.get("quat_xyzw"), size=4))
    else:
        rotation = rpy_matrix(_vector(origin.get("rpy")))
    return rotation, _vector(origin.get("xyz"))


# ----------------------------------------------------------------------------------------------- the reading


@dataclass(frozen=True)
class _Link:
    """A link's mass properties in its own frame (COM, inertia about the COM) and the sizes of what they came from:
    ``com_size`` |xyz| of the inertial origin, ``inertia_size`` the sum of the sizes of the file's six entries (twice
    the products: the full matrix)."""

    mass: float
    com: np.ndarray
    inertia: np.ndarray
    com_size: float
    inertia_size: float


_MASSLESS = _Link(0.0, np.zeros(3), np.zeros((3, 3)), 0.0, 0.0)


def _inertial(link: ET.Element) -> _Link:
    inertial = link.find("inertial")
    if inertial is None:
        return _MASSLESS
    where = f"link '{link.get('name')}' <inertial>"
    mass_tag, tensor = inertial.find("mass"), inertial.find("inertia")
    if mass_tag is None or mass_tag.get("value") is None:
        raise FileReadingError(f"{where} has no <mass value>")
    try:
        xx, xy, xz, yy, yz, zz = (number(None if tensor is None else tensor.get(k))
                                  for k in ("ixx", "ixy", "ixz", "iyy", "iyz", "izz"))
        rotation, com = _origin(inertial)
        mass = float(mass_tag.get("value"))
    except ValueError as exc:
        raise FileReadingError(f"{where}: {exc}") from None
    own = np.array([[xx, xy, xz], [xy, yy, yz], [xz, yz, zz]])
    return _Link(mass, com, rotation @ own @ rotation.T, float(np.linalg.norm(com)), float(np.abs(own).sum()))


@dataclass(frozen=True)
class FileBody:
    """What the file says one body of the model must be (module doc): the ``link`` its joint moves (the body's name),
    the file's ``joint`` (None for the free joint a free base adds) of URDF type ``urdf_type`` and model joint type
    ``kind`` (:data:`JOINT_TYPES`; None: no equivalent), the ``parent`` body's link (None: the world), the joint
    placement ``(rotation, translation)`` in the parent body frame and ``length`` (the summed translations composed into it), the unit
    ``axis`` (zeros for a free joint), the ``limits``, the mass, COM and inertia about the COM in the body frame with
    their scales (module doc), and the links ``welded`` into it by fixed joints."""

    link: str
    joint: str | None
    urdf_type: str
    kind: str | None
    parent: str | None
    rotation: np.ndarray
    translation: np.ndarray
    length: float
    axis: np.ndarray
    limits: Limits
    mass: float = 0.0
    com: np.ndarray = field(default_factory=lambda: np.zeros(3))
    inertia: np.ndarray = field(default_factory=lambda: np.zeros((3, 3)))
    mass_scale: float = 0.0
    com_scale: float = 0.0
    inertia_scale: float = 0.0
    welded: tuple[str, ...] = ()


@dataclass(frozen=True)
class FileMimic:
    """A ``<mimic>`` tag that couples: joint ``joint`` (moving link ``link``) follows ``mimicked`` (moving
    ``mimicked_link``) as ``q = multiplier q_mimicked + offset``."""

    joint: str
    link: str
    mimicked: str
    mimicked_link: str
    multiplier: float
    offset: float


@dataclass(frozen=True)
class FileReading:
    """The file as this module reads it: its ``bodies`` by link name, in the order the file's tree reaches them, and
    its coupling ``mimics``; ``root_link`` and ``root`` ("fixed" or "free") as read."""

    path: str
    root: str
    root_link: str
    bodies: dict[str, FileBody]
    mimics: tuple[FileMimic, ...]


@dataclass
class _Frame:
    """Where a link sits: its body's link (None: the world) and its placement in that body's frame."""

    body: str | None
    rotation: np.ndarray
    translation: np.ndarray
    length: float


def read_urdf(path: str, root: str = "fixed") -> FileReading:
    """The bodies the URDF at ``path`` describes with its root link ``root`` ("fixed": welded to the world, "free": on
    a free joint), by the rules of the module doc; FileReadingError when the file is not a URDF tree by them, OSError
    when it cannot be read."""
    try:
        robot = ET.parse(path).getroot()
    except ET.ParseError as exc:
        raise FileReadingError(f"not XML ({exc})") from None
    if robot.tag != "robot":
        raise FileReadingError(f"the root element is <{robot.tag}>, not <robot>")
    links = {link.get("name"): link for link in robot.findall("link")}
    joints = robot.findall("joint")
    below: dict[str, list[ET.Element]] = {}
    child_of: dict[str, ET.Element] = {}
    for joint in joints:
        parent, child = joint.find("parent"), joint.find("child")
        if parent is None or child is None or parent.get("link") not in links or child.get("link") not in links:
            raise FileReadingError(f"joint '{joint.get('name')}' does not join two links of the file")
        if child.get("link") in child_of:
            raise FileReadingError(f"link '{child.get('link')}' is the child of two joints")
        below.setdefault(parent.get("link"), []).append(joint)
        child_of[child.get("link")] = joint
    roots = [name for name in links if name not in child_of]
    if len(roots) != 1:
        raise FileReadingError(f"{len(roots)} root links {roots[:5]}; a URDF tree has one")
    root_link = roots[0]
    bodies: dict[str, dict] = {}
    frames: dict[str, _Frame] = {}
    if root == "free":
        bodies[root_link] = dict(link=root_link, joint=None, urdf_type="free (added above the root link)",
                                 kind="free", parent=None, rotation=np.eye(3), translation=np.zeros(3), length=0.0,
                                 axis=np.zeros(3), limits=None)
        frames[root_link] = _Frame(root_link, np.eye(3), np.zeros(3), 0.0)
    else:
        frames[root_link] = _Frame(None, np.eye(3), np.zeros(3), 0.0)
    stack = [root_link]
    while stack:                                   # the tree, depth first (each link reached once: one parent each)
        name = stack.pop()
        here = frames[name]
        for joint in reversed(below.get(name, [])):
            child = joint.find("child").get("link")
            kind = joint.get("type")
            rotation, xyz = _origin(joint)
            R, t = here.rotation @ rotation, here.rotation @ xyz + here.translation
            length = here.length + float(np.linalg.norm(xyz))
            if kind == "fixed":
                frames[child] = _Frame(here.body, R, t, length)
            else:
                bodies[child] = dict(link=child, joint=joint.get("name"), urdf_type=kind, kind=JOINT_TYPES.get(kind),
                                     parent=here.body, rotation=R, translation=t, length=length,
                                     axis=_axis(joint), limits=joint_limits(joint))
                frames[child] = _Frame(child, np.eye(3), np.zeros(3), 0.0)
            stack.append(child)
    if len(frames) != len(links):
        raise FileReadingError(f"links {sorted(set(links) - set(frames))[:5]} are not reached from the root link")
    welded: dict[str, list[tuple[_Link, _Frame, str]]] = {}
    for name, where in frames.items():
        if where.body is not None:
            welded.setdefault(where.body, []).append((_inertial(links[name]), where, name))
    out = {}
    for name, fields in bodies.items():
        out[name] = FileBody(**fields, **_merged(welded.get(name, [])))
    return FileReading(str(path), root, root_link, out, _file_mimics(joints, child_of))


def _axis(joint: ET.Element) -> np.ndarray:
    if joint.get("type") not in ("revolute", "continuous", "prismatic"):
        return np.zeros(3)
    tag = joint.find("axis")
    axis = _vector(None if tag is None else tag.get("xyz"), default=(1.0, 0.0, 0.0))
    norm = float(np.linalg.norm(axis))
    if norm == 0.0:
        raise FileReadingError(f"joint '{joint.get('name')}' has a zero axis")
    return axis / norm


def joint_limits(joint: ET.Element) -> Limits:
    """A URDF ``<joint>``'s limits by :func:`limit`: a ``revolute`` or ``prismatic`` joint's ``<limit lower upper>``
    (an absent bound reads 0, as urdfdom reads it); none for the other types."""
    tag = joint.find("limit")
    if joint.get("type") not in ("revolute", "prismatic") or tag is None:
        return None
    return limit(number(tag.get("lower")), number(tag.get("upper")))


def _merged(parts: list[tuple[_Link, _Frame, str]]) -> dict:
    """The mass properties of the links welded into one body, in its frame, with their scales (module doc)."""
    if not parts:
        return {}
    masses = np.array([p.mass for p, _, _ in parts])
    coms = [f.rotation @ p.com + f.translation for p, f, _ in parts]
    total = float(masses.sum())
    centre = sum(m * c for m, c in zip(masses, coms)) / total if total > 0.0 else np.zeros(3)
    inertia = np.zeros((3, 3))
    for (p, f, _), m, c in zip(parts, masses, coms):
        d = c - centre
        inertia += f.rotation @ p.inertia @ f.rotation.T + m * (float(d @ d) * np.eye(3) - np.outer(d, d))
    sizes = [p.com_size + f.length for p, f, _ in parts]
    com_scale = float(sum(abs(m) * s for m, s in zip(masses, sizes)) / total) if total > 0.0 else 0.0
    inertia_scale = sum(p.inertia_size + abs(m) * (s + float(np.linalg.norm(centre))) ** 2
                        for (p, _, _), m, s in zip(parts, masses, sizes))
    return dict(mass=total, com=centre, inertia=inertia, mass_scale=float(np.abs(masses).sum()),
                com_scale=com_scale, inertia_scale=float(inertia_scale), welded=tuple(name for _, _, name in parts))


def _file_mimics(joints: list[ET.Element], child_of: dict[str, ET.Element]) -> tuple[FileMimic, ...]:
    """The tags that couple (module doc): on a movable joint, naming a joint of the file."""
    by_name = {j.get("name"): j for j in joints}
    out = []
    for joint in joints:
        tag = joint.find("mimic")
        if tag is None or joint.get("type") == "fixed" or tag.get("joint") not in by_name:
            continue
        target = by_name[tag.get("joint")]
        out.append(FileMimic(joint.get("name"), joint.find("child").get("link"), target.get("name"),
                             target.find("child").get("link"), number(tag.get("multiplier"), 1.0),
                             number(tag.get("offset"), 0.0)))
    return tuple(out)


# ------------------------------------------------------------------------------------------------ comparing


@dataclass(frozen=True)
class Finding:
    """A difference between the file and the loaded model: the ``link`` (the body) and the ``field`` concerned, the
    file's value and the model's in words (``file``, ``model``), the largest difference and its tolerance (0 for what
    is compared exactly) and ``ratio`` = difference / tolerance (infinite when compared exactly)."""

    link: str
    field: str
    file: str
    model: str
    difference: float = math.inf
    tolerance: float = 0.0

    @property
    def ratio(self) -> float:
        if self.tolerance > 0.0:
            return self.difference / self.tolerance
        return math.inf if self.difference > 0.0 else 0.0

    def __str__(self) -> str:
        size = ("" if not math.isfinite(self.difference) else
                f" (max difference {self.difference:.3g}, tolerance {self.tolerance:.3g})")
        return (f"loader finding: link '{self.link}' {self.field}: the file says {self.file}, the loaded model has "
                f"{self.model}{size}")


def _text(value) -> str:
    if value is None:
        return "none"
    if isinstance(value, str):
        return value
    array = np.asarray(value, dtype=float)
    if array.ndim == 0:
        return f"{float(array):.12g}"
    return np.array2string(array, separator=", ", formatter={"float_kind": lambda x: f"{x:.12g}"},
                           max_line_width=10_000).replace("\n", "")


def _numbers(found: list[Finding], link: str, name: str, theirs, ours, scale: float, extra: float = 0.0,
             said: str = "") -> None:
    """A finding when ``ours`` differs from ``theirs`` by more than ``ROUNDING * scale + extra`` (entrywise; ``said``
    goes before the file's value)."""
    a, b = np.asarray(theirs, dtype=float), np.asarray(ours, dtype=float)
    if a.shape != b.shape:
        found.append(Finding(link, name, said + _text(a), _text(b)))
        return
    difference = float(np.abs(a - b).max(initial=0.0)) if a.size else 0.0
    if not np.all(np.isfinite(b)):
        difference = math.inf
    tolerance = ROUNDING * scale + extra
    if difference > tolerance:
        found.append(Finding(link, name, said + _text(a), _text(b), difference, tolerance))


def _body_findings(body, theirs: FileBody, placement: tuple[np.ndarray, np.ndarray]) -> list[Finding]:
    """The fields of one body (module doc), ``placement`` the source's world placement (applied to a root body)."""
    found: list[Finding] = []
    link = body.name
    joint = f"joint '{theirs.joint}' ({theirs.urdf_type})" if theirs.joint else theirs.urdf_type
    if theirs.kind is None or body.joint != theirs.kind:
        found.append(Finding(link, "joint type", f"{joint}, a {theirs.kind or 'type with no equivalent'} joint",
                             f"a {body.joint} joint"))
        return found
    if body.parent != theirs.parent:
        found.append(Finding(link, "parent", f"it hangs from {_link(theirs.parent)}",
                             f"it hangs from {_link(body.parent)}"))
    _numbers(found, link, "mass", theirs.mass, body.mass, theirs.mass_scale)
    if theirs.mass > 0.0:
        _numbers(found, link, "com", theirs.com, body.com, theirs.com_scale + float(np.linalg.norm(theirs.com)))
    _numbers(found, link, "inertia", theirs.inertia, body.inertia, theirs.inertia_scale)
    rotation, translation = theirs.rotation, theirs.translation
    if theirs.parent is None:
        g_rotation, g_translation = placement
        rotation, translation = g_rotation @ rotation, g_rotation @ translation + g_translation
        length = theirs.length + float(np.linalg.norm(g_translation))
    else:
        length = theirs.length
    _numbers(found, link, f"placement rotation ({joint})", rotation, body.rotation, 1.0)
    _numbers(found, link, f"placement translation ({joint})", translation, body.translation,
             max(length, float(np.linalg.norm(translation))))
    if body.joint in ("revolute", "prismatic"):
        _numbers(found, link, f"axis ({joint})", theirs.axis, body.axis, 1.0, AXIS_SNAP)
        if (body.limits is None) != (theirs.limits is None):
            found.append(Finding(link, f"limits ({joint})", _limits_text(theirs.limits), _limits_text(body.limits)))
        elif theirs.limits is not None:
            _numbers(found, link, f"limits ({joint})", theirs.limits, body.limits,
                     float(np.abs(theirs.limits).max()))
    return found


def _link(name: str | None) -> str:
    return "the world" if name is None else f"link '{name}'"


def _limits_text(limits: Limits) -> str:
    return "no limits" if limits is None else f"[{limits[0]:.12g}, {limits[1]:.12g}]"


def _mimic_findings(model: Model, mimics: tuple[FileMimic, ...]) -> list[Finding]:
    """The model's ``mimic:`` couplings against the file's tags (module doc)."""
    found: list[Finding] = []
    ours = {c.name: c for c in model.constraints
            if isinstance(c, JointCoupling) and c.name.startswith("mimic:")}
    for tag in mimics:
        name = f"mimic:{tag.joint}"
        said = (f"joint '{tag.joint}' mimics '{tag.mimicked}' (q = {tag.multiplier:.12g} q_{tag.mimicked} + "
                f"{tag.offset:.12g})")
        c = ours.pop(name, None)
        if c is None:
            found.append(Finding(tag.link, "mimic", said, "no coupling"))
            continue
        got = (f"the coupling {tuple(c.joints)} with coefficients {_text(c.coefficients)} and offset "
               f"{float(c.offset):.12g}")
        if tuple(c.joints) != (tag.link, tag.mimicked_link) or len(c.coefficients) != 2:
            found.append(Finding(tag.link, "mimic", f"{said}, coupling the bodies {(tag.link, tag.mimicked_link)}",
                                 got))
            continue
        _numbers(found, tag.link, "mimic multiplier", [1.0, -tag.multiplier], c.coefficients,
                 max(abs(tag.multiplier), 1.0), said=f"{said}: coefficients ")
        _numbers(found, tag.link, "mimic offset", tag.offset, c.offset, abs(tag.offset), said=f"{said}: offset ")
    for name, c in ours.items():
        found.append(Finding(c.joints[0], "mimic", "no <mimic> tag that couples it",
                             f"the coupling '{name}' {tuple(c.joints)}"))
    return found


def compare(model: Model, reading: FileReading) -> list[Finding]:
    """Every difference between ``model``'s bodies and couplings and the file as read (module doc), body by body in
    the model's order, then the bodies the file moves that the model lacks, then the couplings."""
    source = model.source
    placement = (np.asarray(source.rotation, dtype=float), np.asarray(source.translation, dtype=float))
    found: list[Finding] = []
    for body in model.bodies:
        theirs = reading.bodies.get(body.name)
        if theirs is None:
            found.append(Finding(body.name, "body", "no movable joint moves it (it is welded, or no link of the file)",
                                 f"a body on a {body.joint} joint"))
            continue
        found += _body_findings(body, theirs, placement)
    names = {b.name for b in model.bodies}
    for name, theirs in reading.bodies.items():
        if name not in names:
            joint = f"joint '{theirs.joint}' ({theirs.urdf_type})" if theirs.joint else theirs.urdf_type
            found.append(Finding(name, "body", f"{joint} moves it", "no body for it"))
    found += _mimic_findings(model, reading.mimics)
    return found
