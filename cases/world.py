"""A model's world data: what places it in the world and nothing else (gravity, each root body's placement, the task
point's directions, the world points and directions of the constraints, the world-frame data of the loads). A moved
scene (``crosscheck.checks.frames.move_scene``) and a gravity-free copy change exactly these, so a backend that takes
them as parameters of its derivation reuses the model's derivation for such scenes (``formalisms/euler_lagrange.py``,
``formalisms/geometric.py``), keyed by :func:`shape_digest`."""

from __future__ import annotations

import dataclasses

import numpy as np

from cases.constraints import PointOnCircle, PointOnLine, PointsCoincide, PointVelocity, RollingContact
from cases.loads import ExternalWrench, PointSpring
from cases.model import Model

#: The world data of each constraint type: its fields a moved scene changes (a body-fixed declaration has none).
CONSTRAINT_FIELDS = {PointOnCircle: ("center", "plane"), PointsCoincide: ("offset_b", "directions"),
                     PointOnLine: ("origin", "normals"), PointVelocity: ("directions",), RollingContact: ("plane",)}


def _constraint_fields(c) -> tuple[str, ...]:
    """A constraint's world fields (a coincidence's second point is world data only when it is on the ground)."""
    return tuple(f for f in CONSTRAINT_FIELDS.get(type(c), ()) if not (f == "offset_b" and c.body_b is not None))


def _load_fields(load) -> tuple[str, ...]:
    """A load's world fields: a spring's anchor; a world-frame force (and couple); none for a body-frame load."""
    if isinstance(load, PointSpring):
        return ("anchor",)
    if load.frame == "body":
        return ()
    return ("force", "moment") if isinstance(load, ExternalWrench) else ("force",)


def world_data(model: Model, task: bool = False) -> list[tuple[str, np.ndarray]]:
    """The model's world data as ``(label, array)`` in a fixed order: ``gravity``, with ``task`` the chosen task
    point's ``task.directions``, ``root<i>.rotation`` and ``root<i>.translation`` of each root body,
    ``constraint<r>.<field>`` and ``load<r>.<field>``."""
    out = [("gravity", model.gravity)]
    if task:
        out.append(("task.directions", model.task_point().directions))
    for i, body in enumerate(model.bodies):
        if body.parent is None:
            out += [(f"root{i}.rotation", body.rotation), (f"root{i}.translation", body.translation)]
    for r, c in enumerate(model.constraints):
        out += [(f"constraint{r}.{f}", getattr(c, f)) for f in _constraint_fields(c)]
    for r, load in enumerate(model.loads):
        out += [(f"load{r}.{f}", getattr(load, f)) for f in _load_fields(load)]
    return out


def label_of(model: Model, declaration, field: str) -> str:
    """The :func:`world_data` label of a constraint's or a load's world field (the declaration found by identity)."""
    for kind, declarations in (("constraint", model.constraints), ("load", model.loads)):
        for r, d in enumerate(declarations):
            if d is declaration:
                return f"{kind}{r}.{field}"
    raise KeyError(f"{declaration!r} is not a declaration of model '{model.name}'")


def shape_digest(model: Model) -> str:
    """The model's digest with every world datum (the task directions included) set to zero: what a derivation that
    takes the world data as parameters depends on."""
    def zero(x, fields):
        return dataclasses.replace(x, **{f: np.zeros(np.shape(getattr(x, f))) for f in fields})
    return dataclasses.replace(
        model, gravity=np.zeros(3),
        bodies=tuple(zero(b, ("rotation", "translation")) if b.parent is None else b for b in model.bodies),
        constraints=tuple(zero(c, _constraint_fields(c)) for c in model.constraints),
        loads=tuple(zero(load, _load_fields(load)) for load in model.loads),
        task_points=tuple(zero(tp, ("directions",)) for tp in model.task_points)).digest()
