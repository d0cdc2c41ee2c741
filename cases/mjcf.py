"""MJCF loader: a MuJoCo XML file -> our :class:`~cases.model.Model`, through Pinocchio's MJCF parser.

``pinocchio.buildModelFromMJCF(path)`` parses the file; each Pinocchio joint then becomes one of our bodies in
Pinocchio's joint order, converted as the URDF loader converts (``cases.urdf``, module docstring): an MJCF ``hinge``
is a revolute joint, ``slide`` a prismatic one, ``ball`` a spherical one and ``free`` (``<freejoint/>``) a free joint,
with Pinocchio's conventions, which are ours (``cases.model``: quaternion ``(x, y, z, w)``, body-frame velocities).
The source is ``ModelSource("mjcf", <absolute path>)``, so the reference reads the file itself.

What the model language has no word for is refused, naming it (:class:`~cases.model.ModelError`), never dropped:
a body with several joints (Pinocchio makes one composite joint of them), ``<equality>`` constraints, and joint
``armature`` (rotor inertia added to M). Contacts, actuators, damping and limits do not enter the dynamics the
harness checks (``M qdd + h = B u``, fully actuated by default) and are not read.
"""

from __future__ import annotations

import xml.etree.ElementTree as ET
from pathlib import Path

import numpy as np

from cases.model import Model, ModelError, ModelSource
from cases.urdf import UrdfError, _fd2_captured, convert, read_file


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


def _unsupported(root: ET.Element, pm) -> list[str]:
    """What the file says that the model language cannot hold (module docstring)."""
    problems = [f"<equality> constraint <{e.tag}> '{e.get('name', '')}' is not read; declare it with "
                "cases.constraints instead" for eq in root.iter("equality") for e in eq]
    armature = np.asarray(getattr(pm, "armature", np.zeros(0)), dtype=float)
    problems += [f"velocity {k} has armature (rotor inertia) {a:g}, which the model language has no field for"
                 for k, a in enumerate(armature) if a != 0.0]
    return problems


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
    problems = _unsupported(root, pm)
    if problems:
        raise ModelError(model_name, problems + [f"(from MJCF file '{path}')"])
    return convert(pin, pm, model_name, ModelSource("mjcf", str(path.resolve())))
