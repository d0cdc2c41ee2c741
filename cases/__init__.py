"""Scene descriptions: the model language, parameterized case factories, and the URDF loader.

    >>> import cases
    >>> cases.names()
    ['double_pendulum', 'double_pendulum_tip_force', 'double_pendulum_spring', 'n_link_pendulum', 'acrobot',
     'spatial_arm', 'panda', 'rotor', 'inclined_slider', 'spherical_pendulum', 'double_pendulum_circle', 'four_bar',
     'slider_crank', 'cartesian_pendulum', 'double_pendulum_absolute_loop', 'double_pendulum_rail', 'geared_pendulums',
     'free_body', 'ball_pendulum', 'ball_double_pendulum', 'satellite_arm', 'solo12', 'solo12_standing', 'knife_edge',
     'rolling_disk', 'differential_drive', 'urdf_gripper', 'mjcf_floating', 'mjcf_ball_slide']
    >>> model = cases.load("n_link_pendulum", n="3")     # strings (CLI --param n=3) convert by the default's type

``catalog()`` lists each case with a one-line summary and its parameters with their defaults. Importing this
package does not import Pinocchio (only ``from_urdf`` and the cases loaded from a file do, when called).
``model_file(name)`` names the model file a built-in case is loaded from (``panda``, ``solo12`` and the small files
shipped in ``cases/files/``, :mod:`cases.file_cases`), None for a case built in code.
"""

from __future__ import annotations

from cases import constrained, floating, nonholonomic  # noqa: F401 (register the constrained, Lie-group and
#                                                            nonholonomic cases)
from cases import file_cases  # noqa: F401 (register the cases loaded from the shipped model files, last)
from cases.factories import MODEL_FILES, REGISTRY, CaseError, CaseInfo
from cases.constraints import (JointCoupling, KnifeEdge, PointOnCircle, PointOnLine, PointsCoincide, PointVelocity,
                               RollingContact)
from cases.loads import ExternalForce, ExternalWrench, PointSpring
from cases.model import Body, Model, ModelError, TaskPoint
from cases.build import build_model
from cases.urdf import UrdfError, from_urdf


def from_file(path, name: str | None = None, base: str | None = None, actuated=None, armature=None) -> Model:
    """A model file by its extension: ``.urdf`` through :func:`from_urdf` (with ``base`` "fixed" or "free"; None: as
    the file says, with a notice when it is fixed; ``actuated``: the URDF joints driven by u, in order; None: every
    joint but a free base's; ``armature``: URDF joint name -> rotor inertia, which a URDF cannot say), ``.xml`` or
    ``.mjcf`` through ``cases.mjcf.from_mjcf`` (whose free joints and armature are in the file: ``base``, ``actuated``
    and ``armature`` must be None). Anything else is a UrdfError naming the extensions."""
    from pathlib import Path

    suffix = Path(path).suffix.lower()
    if suffix in (".xml", ".mjcf"):
        from cases.mjcf import from_mjcf

        if base is not None:
            raise UrdfError(f"'{path}' is an MJCF file, whose free joints are declared in it (<freejoint/>); a base "
                            "applies to URDF files only")
        if actuated is not None:
            raise UrdfError(f"'{path}' is an MJCF file; actuated joints apply to URDF files only (an MJCF file is "
                            "driven at every joint but a free one)")
        if armature is not None:
            raise UrdfError(f"'{path}' is an MJCF file, which declares its joints' armature itself (<joint "
                            "armature=\"...\">, read by the loader); armature applies to URDF files only")
        return from_mjcf(path, name=name)
    if suffix != ".urdf":
        raise UrdfError(f"'{path}' is not a model file this loads: give a .urdf (URDF) or a .xml / .mjcf (MJCF) file")
    return from_urdf(path, name=name, base=base, actuated=actuated, armature=armature)


def names() -> list[str]:
    """The registered case names, in registry order."""
    return list(REGISTRY)


def model_file(name: str) -> str | None:
    """The model file the built-in case ``name`` is loaded from, in words (its reference is built from that file), or
    None for a case built in code."""
    return MODEL_FILES.get(name)


def catalog() -> list[CaseInfo]:
    """One :class:`CaseInfo` per case (``name``, ``summary``, ``parameters`` = {name: default}), in registry order."""
    return [CaseInfo(c.name, c.summary, dict(c.parameters), c.factory) for c in REGISTRY.values()]


def _describe(params: dict) -> str:
    return ", ".join(f"{k}={v!r}" for k, v in params.items()) if params else "(none: this case takes no parameters)"


def _convert(case: str, key: str, value, default):
    """``value`` (a number or a CLI string) as the type of ``default``; an int must be integral; no bools."""
    kind = type(default)
    try:
        converted = kind(float(value)) if kind is int else kind(value)
        valid = not isinstance(value, bool) and (kind is not int or float(value) == converted)
    except (TypeError, ValueError, OverflowError):
        valid = False
    if not valid:
        raise CaseError(f"case '{case}': parameter {key}={value!r} is not a valid {kind.__name__} "
                        f"(default {default!r})")
    return converted


def _overrides(name: str, params: dict) -> tuple[CaseInfo, dict]:
    """The case ``name`` and ``params`` converted by the types of its defaults (:func:`_convert`), or a
    :class:`CaseError` naming an unknown case or parameter and listing what is valid."""
    info = REGISTRY.get(name)
    if info is None:
        raise CaseError(f"unknown case '{name}'; valid cases: {', '.join(REGISTRY)}")
    unknown = [k for k in params if k not in info.parameters]
    if unknown:
        raise CaseError(f"case '{name}' has no parameter(s) {', '.join(map(repr, unknown))}; valid parameters "
                        f"with defaults: {_describe(info.parameters)}")
    return info, {k: _convert(name, k, v, info.parameters[k]) for k, v in params.items()}


def load(name: str, **params) -> Model:
    """Build the case ``name`` with ``params`` overriding its defaults.

    Values may be strings (from a CLI ``--param k=v``); they are converted by the type of the parameter's default.
    An unknown case or parameter, or a value that does not convert, raises :class:`CaseError` listing what is valid.
    """
    info, kwargs = _overrides(name, params)
    return info.factory(**kwargs)


def parameters(name: str, **params) -> dict:
    """The typed parameters ``load(name, **params)`` builds the case with: every parameter of the case, its default
    overridden by ``params`` converted as :func:`load` converts them. Raises :class:`CaseError` as :func:`load` does.

        >>> cases.parameters("n_link_pendulum", n="3")
        {'n': 3, 'm': 1.0, 'l': 1.0, 'g': 9.81, 'a': 0.0}
    """
    info, kwargs = _overrides(name, params)
    return {**info.parameters, **kwargs}


__all__ = ["Body", "CaseError", "CaseInfo", "ExternalForce", "ExternalWrench", "JointCoupling", "KnifeEdge", "Model",
           "ModelError", "PointOnCircle", "PointOnLine", "PointSpring", "PointVelocity", "PointsCoincide",
           "RollingContact", "TaskPoint", "UrdfError", "build_model", "catalog", "constrained", "file_cases",
           "floating", "from_file", "from_urdf", "load", "model_file", "names", "nonholonomic", "parameters"]
