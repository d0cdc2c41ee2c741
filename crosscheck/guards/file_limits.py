"""The joint limits a model file declares, read here from its XML, apart from the loaders.

The sampler draws within ``Body.limits``, which the loaders (``cases/urdf.py``, ``cases/mjcf.py``) convert from the
file; the sampling coverage (``crosscheck.guards.coverage``) measures the sample against the limits read here, and
compares both, so a degree/radian slip, swapped or dropped limits in the conversion is a finding, not a "covered"
sample. Nothing of the loaders is used: the file's XML is read with :mod:`xml.etree` by the rules of its format, and
our coordinates are paired with the file's joints by the Pinocchio reference's joint map
(``crosscheck.references.pinocchio.build.joint_map``: link names, built from the file itself).

* URDF: a ``revolute`` or ``prismatic`` joint's ``<limit lower=".." upper=".."/>`` (radians, metres; an absent
  attribute reads 0, as urdfdom reads it). A ``continuous`` joint has none; nor has a ``floating`` root (or the free
  root joint Pinocchio adds for a free base, which is not in the file).
* MJCF (MuJoCo's rules): a ``hinge`` or ``slide`` joint's ``range``, the joint's own attribute or its default class's
  (``<default class>``, nested, the top one ``main``; ``class`` on the joint, else the nearest ``childclass``), in
  the unit ``<compiler angle>`` says for a hinge (degrees unless ``angle="radian"``), in metres for a slide, where
  the joint is limited: ``limited="true"``, or ``"auto"`` (the default) with a range given and ``<compiler
  autolimits>`` not ``"false"``. A ``ball`` joint's range is a cone, no limit on a coordinate; a free joint has
  none. ``<include file>`` is spliced in. Pinocchio's joint ``k`` is paired with the file's ``k``-th joint in document
  order (Pinocchio's MJCF parser adds them so), checked by type and, where the file names the joint, by name.

A pair is a limit only when both bounds are finite and below ``file_reading.UNLIMITED`` in size, and ``lower < upper``: an
empty or reversed range, or one a file writes as "huge", is no limit (the loaders drop those too, by the same rule
stated in docs/faults.md, "Joint limits"). The rule, and the URDF reading of a joint's limits, are those of the second
reading of a URDF file (``crosscheck.guards.file_reading.limit``, ``joint_limits``), stated once. When the file cannot be read or paired, :func:`read` says why and the
coverage falls back on ``Body.limits`` (and says so in the report).
"""

from __future__ import annotations

import math
import os
import xml.etree.ElementTree as ET
from dataclasses import dataclass

from cases.model import Model
from crosscheck.guards.file_reading import joint_limits, limit
from crosscheck.references.pinocchio.build import reference_model

Limits = tuple[float, float] | None


@dataclass(frozen=True)
class FileLimits:
    """What :func:`read` found: ``limits`` per body of the model (None: the joint has none), or None with
    ``reason`` when the file could not be read or paired with the model; ``path`` and ``kind`` of the file, and the
    file's joint of each body (``joints``, the reference's joint map's names)."""

    kind: str
    path: str
    limits: tuple[Limits, ...] | None
    reason: str = ""
    joints: tuple[str, ...] = ()


# ------------------------------------------------------------------------------------------------------ URDF


def _urdf_joints(path: str) -> dict[str, Limits]:
    """URDF joint name -> its limits (module doc; the rule of ``file_reading.joint_limits``)."""
    return {joint.get("name"): joint_limits(joint)                     # not those <transmission> and <gazebo> name
            for joint in ET.parse(path).getroot().findall("joint")}


def _urdf(model: Model, rows) -> tuple[Limits, ...]:
    joints = _urdf_joints(model.source.path)
    limits: list[Limits] = [None] * len(model.bodies)
    for r in rows:
        if r.joint in joints:
            limits[r.coordinate] = joints[r.joint]
        elif not (model.source.root == "free" and model.bodies[r.coordinate].joint == "free"):
            raise ValueError(f"the file has no joint '{r.joint}' (body '{r.body}')")
    return tuple(limits)


# ------------------------------------------------------------------------------------------------------ MJCF


def _spliced(element: ET.Element, directory: str, depth: int = 0) -> ET.Element:
    """``element`` with each ``<include file>`` replaced by the children of the included file's root."""
    if depth > 20:
        raise ValueError("<include> nested more than 20 deep")
    for parent in list(element.iter()):
        for k, child in reversed(list(enumerate(parent))):
            if child.tag == "include":
                included = os.path.join(directory, child.get("file", ""))
                root = _spliced(ET.parse(included).getroot(), os.path.dirname(included), depth + 1)
                parent.remove(child)
                for n, grandchild in enumerate(list(root)):
                    parent.insert(k + n, grandchild)
    return element


def _mjcf_joints(path: str) -> list[tuple[str | None, str, Limits]]:
    """The file's joints in document order (depth first through ``<worldbody>``): (name, MuJoCo type, limits)."""
    root = _spliced(ET.parse(path).getroot(), os.path.dirname(os.path.abspath(path)))
    compiler = {k: v for c in root.iter("compiler") for k, v in c.attrib.items()}
    scale = math.pi / 180.0 if compiler.get("angle", "degree") == "degree" else 1.0
    auto = compiler.get("autolimits", "true") != "false"
    own: dict[str, dict[str, str]] = {}
    above: dict[str, str | None] = {}

    def defaults(element: ET.Element, parent: str | None) -> None:
        name = element.get("class") or ("main" if parent is None else None)
        if name is None:
            return
        joint = element.find("joint")
        own[name], above[name] = dict(joint.attrib) if joint is not None else {}, parent
        for child in element.findall("default"):
            defaults(child, name)

    for top in root.findall("default"):
        defaults(top, None)

    def attribute(joint: ET.Element, cls: str | None, key: str) -> str | None:
        if key in joint.attrib:
            return joint.get(key)
        seen = set()
        while cls is not None and cls not in seen:
            seen.add(cls)
            if key in own.get(cls, {}):
                return own[cls][key]
            cls = above.get(cls)
        return None

    out: list[tuple[str | None, str, Limits]] = []

    def visit(element: ET.Element, childclass: str) -> None:
        childclass = element.get("childclass", childclass)
        if element.tag == "body":
            for joint in element:
                if joint.tag == "freejoint":
                    out.append((joint.get("name"), "free", None))
                elif joint.tag == "joint":
                    cls = joint.get("class", childclass)
                    kind = attribute(joint, cls, "type") or "hinge"
                    given = attribute(joint, cls, "range")
                    limited = attribute(joint, cls, "limited") or "auto"
                    limits = None
                    if kind in ("hinge", "slide") and given is not None and (
                            limited == "true" or (limited == "auto" and auto)):
                        lower, upper = (float(x) for x in given.split())
                        factor = scale if kind == "hinge" else 1.0
                        limits = limit(lower * factor, upper * factor)
                    out.append((joint.get("name"), kind, limits))
        for child in element:
            if child.tag in ("body", "frame"):
                visit(child, childclass)

    for world in root.findall("worldbody"):
        for child in world:
            if child.tag in ("body", "frame"):
                visit(child, "main")
    return out


#: MuJoCo joint type -> the Pinocchio joint types it becomes (short names, by prefix).
_PINOCCHIO_KIND = {"hinge": ("JointModelR",), "slide": ("JointModelP",), "ball": ("JointModelSpherical",),
                   "free": ("JointModelFreeFlyer",)}


def _mjcf(model: Model, rows, pm) -> tuple[Limits, ...]:
    joints = _mjcf_joints(model.source.path)
    if len(joints) != pm.njoints - 1:
        raise ValueError(f"the file has {len(joints)} joints in document order, the reference's model of it "
                         f"{pm.njoints - 1}")
    limits: list[Limits] = [None] * len(model.bodies)
    for r in rows:
        jid = pm.getJointId(r.joint)
        name, kind, found = joints[jid - 1]
        shortname = pm.joints[jid].shortname()
        if (name is not None and name != r.joint) or not shortname.startswith(_PINOCCHIO_KIND.get(kind, ("?",))):
            raise ValueError(f"joint {jid} of the reference's model ('{r.joint}', {shortname}) is not the file's "
                             f"joint {jid} in document order ('{name}', {kind})")
        limits[r.coordinate] = found
    return tuple(limits)


# ----------------------------------------------------------------------------------------------------------


def read(model: Model) -> FileLimits | None:
    """The limits of ``model``'s file per body (module doc); None for a model without a file source. A file that
    cannot be read or paired gives ``limits`` None and the reason."""
    source = model.source
    if source is None:
        return None
    try:
        compiled = reference_model(model)
        rows = compiled.joint_map
        limits = _mjcf(model, rows, compiled.model) if source.kind == "mjcf" else _urdf(model, rows)
    except (OSError, ET.ParseError, ValueError, TypeError, RuntimeError) as exc:
        return FileLimits(source.kind, source.path, None, " ".join(str(exc).split()))
    joints = [""] * len(model.bodies)
    for r in rows:
        joints[r.coordinate] = r.joint
    return FileLimits(source.kind, source.path, limits, joints=tuple(joints))
