"""MJCF loader: a MuJoCo XML file -> our :class:`~cases.model.Model`, through Pinocchio's MJCF parser.

``pinocchio.buildModelFromMJCF(path)`` parses the file; each Pinocchio joint then becomes one of our bodies in
Pinocchio's joint order, converted as the URDF loader converts (``cases.urdf``, module docstring): an MJCF ``hinge``
is a revolute joint, ``slide`` a prismatic one, ``ball`` a spherical one and ``free`` (``<freejoint/>``) a free joint,
with Pinocchio's conventions, which are ours (``cases.model``: quaternion ``(x, y, z, w)``, body-frame velocities).
The source is ``ModelSource("mjcf", <absolute path>)``, so the reference reads the file itself.

Joint ``armature`` (rotor inertia, MuJoCo's ``dof_armature``: added to each of the joint's diagonal entries of M) is
read: Pinocchio's parser puts it in ``model.armature`` per velocity (a ``<default>`` class's value included), and
each body takes its joint's (``Body.armature``; ``M = M_bodies + diag(a)``, docs/concepts.md, "Armature"). The
reference reads it from the file itself. A joint whose velocities have different values there is refused, naming it
(the model language holds one value per joint; an MJCF joint has one).

What the model language has no word for is refused, naming it (:class:`~cases.model.ModelError`), never dropped:
a body with several joints (Pinocchio makes one composite joint of them) and ``<equality>`` constraints. Contacts,
actuators, damping and friction loss do not enter the dynamics the harness checks (``M qdd + h = B u``, fully
actuated by default) and are not read.

Joint limits do not enter the dynamics either; they bound the states the gate samples (``Body.limits``,
``crosscheck.core.sampling``). A hinge or slide joint's ``range`` is read as MuJoCo reads it (:func:`_limits`): in
radians or degrees as ``<compiler angle>`` says for a hinge, in metres for a slide (Pinocchio's parser, 4.1, converts
a slide's range from degrees too), and only where the joint is limited (``limited="false"``, on the joint or its
default class, leaves it free; so does ``<compiler autolimits="false">`` without ``limited="true"``).
"""

from __future__ import annotations

import xml.etree.ElementTree as ET
from pathlib import Path

import numpy as np

from cases.model import Model, ModelError, ModelSource
from cases.urdf import _fd2_captured, convert, read_file, UrdfError


class MjcfError(UrdfError):
    """An MJCF file cannot be read or parsed (the message names the path)."""


def _read(path: Path) -> ET.Element:
    if path.is_dir():
        raise MjcfError(f"MJCF path '{path}' is a directory, not a file")
    if not path.exists():
        raise FileNotFoundError(f"MJCF file not found: '{path}'")
    try:
        root = ET.fromstring(path.read_bytes())
    except (OSError, ET.ParseError) as exc:
        raise MjcfError(f"cannot read MJCF file '{path}': {exc}") from None
    if root.tag != "mujoco":
        raise MjcfError(f"MJCF file '{path}' is XML whose root element is <{root.tag}>, not <mujoco>")
    return root


def _unsupported(root: ET.Element) -> list[str]:
    """What the file says that the model language cannot hold (module docstring)."""
    return [f"<equality> constraint <{e.tag}> '{e.get('name', '')}' is not read; declare it with "
            "cases.constraints instead" for eq in root.iter("equality") for e in eq]


def from_mjcf(path, name: str | None = None) -> Model:
    """Load the MJCF file at ``path`` as a :class:`Model` (module docstring). FileNotFoundError for a missing path,
    :class:`MjcfError` for a file that cannot be read or parsed, ModelError for what cannot be converted."""
    path = Path(path)
    root = _read(path)
    model_name = name if name is not None else root.get("model") or path.stem
    try:
        import pinocchio as pin
    except ImportError as exc:  # pragma: no cover - pin is a declared dependency
        raise ImportError("reading MJCF files needs Pinocchio: install the 'pin' package (pip install pin)") from exc
    with _fd2_captured():
        try:
            pm = read_file(pin, "mjcf", str(path))
        except Exception as exc:  # noqa: BLE001 - Pinocchio raises ValueError/RuntimeError/... for bad files
            raise MjcfError(f"could not parse MJCF file '{path}': {' '.join(str(exc).split())}") from None
    problems = _unsupported(root)
    if problems:
        raise ModelError(model_name, problems, f"MJCF file '{path}'")
    _limits(root, pin, pm)
    return convert(pin, pm, model_name, ModelSource("mjcf", str(path.resolve())))


def _joint_defaults(root: ET.Element) -> tuple[dict[str, dict[str, str]], dict[str, str | None]]:
    """The ``<joint>`` attributes each ``<default>`` class sets (its own only) and each class's parent class; the
    top-level default is class ``main``."""
    own: dict[str, dict[str, str]] = {}
    parent: dict[str, str | None] = {}

    def visit(element: ET.Element, above: str | None) -> None:
        name = element.get("class", "main" if above is None else None)
        if name is None:
            return
        joint = element.find("joint")
        own[name], parent[name] = {} if joint is None else dict(joint.attrib), above
        for child in element.findall("default"):
            visit(child, name)

    for top in root.findall("default"):
        visit(top, None)
    return own, parent


def _limits(root: ET.Element, pin, pm) -> None:
    """Set ``pm``'s position limits of every hinge and slide joint to what MuJoCo reads in the file (module doc):
    unlimited (infinite) where the joint is not limited, a slide's range in metres. The other joints keep Pinocchio's
    reading (a joint without a range is unlimited there already)."""
    compiler = {k: v for c in root.findall("compiler") for k, v in c.attrib.items()}
    degrees, auto = compiler.get("angle", "degree") == "degree", compiler.get("autolimits", "true") == "true"
    own, parent = _joint_defaults(root)
    lower, upper = np.array(pm.lowerPositionLimit, dtype=float), np.array(pm.upperPositionLimit, dtype=float)

    def attribute(joint: ET.Element, cls: str | None, key: str) -> str | None:
        if key in joint.attrib:
            return joint.get(key)
        while cls is not None:
            if key in own.get(cls, {}):
                return own[cls][key]
            cls = parent.get(cls)
        return None

    def joints(body: ET.Element, childclass: str):
        """(element, class) of every joint in document order: a body's own, then its children's (Pinocchio's
        order)."""
        childclass = body.get("childclass", childclass)
        for joint in body:
            if joint.tag in ("joint", "freejoint"):
                yield joint, joint.get("class", childclass)
        for child in body.findall("body"):
            yield from joints(child, childclass)

    found = [j for world in root.findall("worldbody") for body in world.findall("body") for j in joints(body, "main")]
    in_order = len(found) == pm.njoints - 1          # an unnamed joint is matched by its place, when all are parsed
    for k, (joint, cls) in enumerate(found):
        kind, name = "free" if joint.tag == "freejoint" else attribute(joint, cls, "type") or "hinge", joint.get("name")
        if kind not in ("hinge", "slide"):
            continue
        if name is not None and pm.existJointName(name):
            iq = pm.joints[pm.getJointId(name)].idx_q
        elif in_order:
            iq = pm.joints[k + 1].idx_q
        else:
            continue
        limited = attribute(joint, cls, "limited") or "auto"
        if limited == "false" or (limited == "auto" and not auto):
            lower[iq], upper[iq] = -np.inf, np.inf
        elif kind == "slide" and degrees:
            lower[iq], upper[iq] = np.degrees(lower[iq]), np.degrees(upper[iq])
    pm.lowerPositionLimit, pm.upperPositionLimit = lower, upper

