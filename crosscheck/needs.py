"""What a plugin backend is given in place of crosscheck's Model: the input it declares it ``needs``.

A plugin's ``split(X, q, qd, u)`` (and ``split_chart(X, chart, p, pd, tau_p)``) receives as ``X``, by its class
attribute ``needs`` (:data:`NEEDS`; default ``"model"``):

* ``"model"``: the :class:`cases.model.Model` itself (bodies, placements, inertias, gravity, B, constraints);
* ``"source"``: a :class:`SourceScene`: the file the model was loaded from (URDF or MJCF, absolute path, and how its
  root was attached), the rigid placement ``(rotation, translation)`` of the file's world in the scene's world,
  whether gravity acts, and the layout of a state (bodies and joint types in coordinate order, B, the constraint
  declarations). Nothing of our conversion's physics: the plugin reads masses, geometry and gravity from the file;
* ``"pinocchio"``: a :class:`PinocchioScene`: a private copy of the Pinocchio model the reference evaluates (built
  from the file for a loaded model, else from our data) with fresh data, and the maps between our coordinate order
  and Pinocchio's.

The gate calls ``split`` on more scenes than the case itself, and each input describes the scene of that call:

* on a **moved scene** (the frame checks, ``crosscheck.checks.frames.move_scene``), the file's world is placed by the
moved placement and gravity is turned with it (``SourceScene.rotation``, ``translation``; the Pinocchio model's root
  joints and gravity moved);
* on a **gravity-free copy** (the hints at a failing state, ``crosscheck.reports.diagnosis.without_gravity``),
  ``SourceScene.gravity`` is False and the Pinocchio model's gravity is zero.

What an input cannot describe is :class:`~formalisms.interface.ModelNotSupported` (the backend is then NOT
COMPARED on that model): a ``"source"`` plugin on a model built in code (a built-in case, a fuzz model) has no file.
"""

from __future__ import annotations

import threading
from dataclasses import dataclass
from typing import Callable

import numpy as np

from cases.model import Model
from crosscheck.references.pinocchio.build import reference_model
from formalisms.interface import ModelNotSupported

#: The inputs a plugin may declare (module docstring); the first is the default.
NEEDS = ("model", "source", "pinocchio")


@dataclass(frozen=True, eq=False)
class SourceScene:
    """The scene of one ``split`` call as a file and its placement (module docstring).

    ``kind`` "urdf" or "mjcf", ``path`` absolute; ``root`` "fixed" (the file's root link welded to the world, as the
    file has it) or "free" (a free joint added above the root link: ``--base free``). A point ``x`` of the file's
    world is at ``rotation @ x + translation`` in the scene's world; the file's gravity ``g`` acts as ``rotation @
    g`` when ``gravity`` is True and not at all when it is False. ``bodies[i]`` is the file's link (URDF) or body
    (MJCF) that body ``i``'s joint moves and ``joints[i]`` that joint's type ("revolute", "prismatic", "spherical",
    "free"); its coordinates are ``q[q_index[i]:...]``, its velocities ``qd[v_index[i]:...]`` (``cases.model``:
    Pinocchio's conventions, a free joint's linear velocity in the body frame). ``joint_names[i]`` is the file's name
    of that joint (URDF ``<joint name>``, MJCF ``<joint>``/``<freejoint>`` name as Pinocchio reads it), None for the
    free joint ``root = "free"`` adds (it is not in the file); ``root_link`` is the file's root link (URDF: the link
    no joint has as child) or root body (MJCF: the first body of ``<worldbody>``), the first body Pinocchio reads:
    welded to the world on a fixed base, moved by ``joints[0]`` on a free one. ``input_map`` is B of ``tau = B
    u``; ``constraints`` are the model's declarations (a URDF ``<mimic>``: ``cases.constraints.JointCoupling``).
    ``armature`` holds the ``(joint name, value)`` pairs the user declared for the file's joints when loading it
    (``ModelSource.armature``, ``--armature``: a URDF cannot say a joint's rotor inertia), which the plugin sets
    after reading the file; an MJCF file's own ``<joint armature>`` is in the file."""

    name: str
    kind: str
    path: str
    root: str
    rotation: np.ndarray
    translation: np.ndarray
    gravity: bool
    bodies: tuple[str, ...]
    joints: tuple[str, ...]
    q_index: tuple[int, ...]
    v_index: tuple[int, ...]
    nq: int
    nv: int
    input_map: np.ndarray
    constraints: tuple
    joint_names: tuple[str | None, ...]
    root_link: str
    armature: tuple[tuple[str, float], ...] = ()


@dataclass(frozen=True, eq=False)
class PinocchioScene:
    """The scene of one ``split`` call as a Pinocchio model (module docstring).

    ``model`` is this plugin's own copy (it may be modified; it is rebuilt for every other scene) and ``data`` fresh
    for the call. ``from_file`` says whether it was built from the model's file (else from our data: a built-in case
    or a fuzz model). Pinocchio orders the joints its own way and stores a URDF continuous joint as ``(cos q, sin
    q)``: :meth:`configuration` and :meth:`velocity` take our ``q`` and ``qd`` to Pinocchio's, :meth:`ours` and
    :meth:`ours_matrix` bring a velocity-space vector or matrix back. ``input_map`` is B (our order) and
    ``constraints`` the model's declarations."""

    name: str
    model: object
    data: object
    from_file: bool
    input_map: np.ndarray
    constraints: tuple
    order: np.ndarray
    _configuration: Callable[[np.ndarray], np.ndarray]

    def configuration(self, q) -> np.ndarray:
        """Pinocchio's configuration of our ``q``."""
        return self._configuration(np.asarray(q, dtype=float))

    def velocity(self, qd) -> np.ndarray:
        """Pinocchio's velocity (or acceleration, or generalized force) of our ``qd``: ``qd[order]``."""
        return np.asarray(qd, dtype=float)[self.order]

    def ours(self, vec_p) -> np.ndarray:
        """A vector in Pinocchio's velocity order back in ours."""
        out = np.empty(len(self.order))
        out[self.order] = np.asarray(vec_p, dtype=float)
        return out

    def ours_matrix(self, M_p) -> np.ndarray:
        """A matrix in Pinocchio's velocity order (rows and columns) back in ours."""
        M = np.empty((len(self.order), len(self.order)))
        M[np.ix_(self.order, self.order)] = np.asarray(M_p, dtype=float)
        return M


def _no_loads(model: Model, plugin: str, need: str) -> None:
    """ModelNotSupported for a model with external loads (``cases.loads``): a file or a Pinocchio model does not carry
    them, so a plugin that reads one would answer without them (NOT COMPARED, not a false DISAGREE)."""
    if model.loads:
        raise ModelNotSupported(f"plugin '{plugin}' needs {need} (needs = \"{need}\"), which does not carry model "
                                f"'{model.name}''s external loads ({', '.join(x.name for x in model.loads)}); "
                                "give the plugin needs = \"model\" to read them from crosscheck's Model.loads")


def source_scene(model: Model, plugin: str) -> SourceScene:
    """The :class:`SourceScene` of ``model``; ModelNotSupported for a model without a file. The joint names and the
    root link are read from the Pinocchio model the reference builds from the file (``joint_map``), the file's own."""
    _no_loads(model, plugin, "source")
    src = model.source
    if src is None:
        raise ModelNotSupported(f"plugin '{plugin}' needs the model's source file (needs = \"source\"), and model "
                                f"'{model.name}' was built in code (a built-in case or a fuzz model), not loaded from "
                                "a file; run it on a file (--model PATH)")
    import pinocchio as pin

    built = reference_model(model)                  # read from the file itself: the names are the file's
    names = tuple(None if src.root == "free" and i == 0 else row.joint for i, row in enumerate(built.joint_map))
    root_link = next(f.name for f in built.model.frames if f.type == pin.FrameType.BODY)
    return SourceScene(model.name, src.kind, src.path, src.root, np.array(src.rotation), np.array(src.translation),
                       src.gravity, tuple(b.name for b in model.bodies), tuple(b.joint for b in model.bodies),
                       model.q_index, model.v_index, model.nq, model.nv, np.array(model.input_map), model.constraints,
                       names, root_link, tuple(src.armature))


_COPIES: dict[tuple, object] = {}
_LOCK = threading.Lock()


def pinocchio_scene(model: Model, plugin: str) -> PinocchioScene:
    """The :class:`PinocchioScene` of ``model``: a copy of the reference's Pinocchio model (cached per plugin and
    scene, so a plugin that changes its copy never changes the reference's), fresh data."""
    import pinocchio as pin

    _no_loads(model, plugin, "pinocchio")
    c = reference_model(model)
    key = (plugin, model.digest(), None if model.source is None else model.source.key())
    with _LOCK:
        if key not in _COPIES:
            _COPIES[key] = pin.Model(c.model)
        pm = _COPIES[key]
    return PinocchioScene(model.name, pm, pm.createData(), model.source is not None, np.array(model.input_map),
                          model.constraints, np.array(c.order), c.configuration)


def given(need: str, model: Model, plugin: str):
    """What a plugin declaring ``need`` receives for ``model`` (module docstring)."""
    if need == "model":
        return model
    if need == "source":
        return source_scene(model, plugin)
    return pinocchio_scene(model, plugin)
