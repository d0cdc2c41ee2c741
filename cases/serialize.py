"""Models as plain JSON-safe dicts and back, exactly: every float survives the round trip bit for bit, so the
rebuilt model has the same ``digest()`` and every backend gives it the same split.

    >>> d = model_to_dict(cases.load("four_bar"))
    >>> json.dumps(d)                                   # plain lists, floats, strings, None
    >>> model_from_dict(json.loads(json.dumps(d))).digest() == cases.load("four_bar").digest()
    True

The dict holds the bodies (joint, axis, placement, mass, centre of mass, inertia; ``limits`` and ``armature`` written
only when set, so a dict without them reads as unlimited and armature 0), gravity, the input map, the task
points, the constraint declarations of every type in :mod:`cases.constraints`, the external loads of every type in
:mod:`cases.loads` (a field written only when there are loads; a RollingContact's ``lateral`` is written only when
False, so an older dict reads as the two-row default) and, for a model loaded from a file,
its ``source`` (kind, path, world placement; :class:`cases.model.ModelSource`). A dict without ``source`` (written
before it existed, or of a model built in code) loads as a model without one. :func:`model_from_dict` rebuilds
through :func:`cases.build_model`, so a dict edited by hand is validated like any model; a missing or mistyped field
raises :class:`SerializeError` naming the field (``bodies[1].mass``).
"""

from __future__ import annotations

import dataclasses

import numpy as np

from cases import constraints as constraint_decl, loads as load_decl
from cases.build import build_model
from cases.model import Body, Model, ModelSource, TaskPoint

FORMAT = "crosscheck.model"
VERSION = 1

#: Body fields in the dict, in order (all but ``name``, ``parent`` and ``joint`` are float arrays).
_BODY_ARRAYS = ("axis", "com", "inertia", "rotation", "translation")

_CONSTRAINT_TYPES = {cls.__name__: cls for cls in constraint_decl.CONSTRAINT_TYPES}
_LOAD_TYPES = {cls.__name__: cls for cls in load_decl.LOAD_TYPES}


class SerializeError(ValueError):
    """A dict that is not a serialized model: says which field is missing or of the wrong kind."""


def _plain(value):
    """Arrays and tuples as (nested) lists of Python floats; strings, None and floats as they are."""
    if isinstance(value, np.ndarray):
        return value.tolist()
    if isinstance(value, tuple):
        return [_plain(v) for v in value]
    if isinstance(value, (np.floating, np.integer)):
        return value.item()
    return value


def _written(c, field: str) -> bool:
    """Whether a declaration's field is written: a RollingContact's ``lateral`` only when False (the default two rows
    are written as before the field existed, and a dict without it reads as the default)."""
    return not (field == "lateral" and getattr(c, field) is True)


def model_to_dict(model: Model) -> dict:
    """``model`` as a JSON-safe dict (module doc); :func:`model_from_dict` inverts it exactly. The ``source`` field
    is there only when the model has one, so the dict of a model built in code is what it was before sources."""
    d = {
        "format": FORMAT,
        "version": VERSION,
        "name": model.name,
        "bodies": [{"name": b.name, "parent": b.parent, "joint": b.joint, "mass": float(b.mass),
                    **{key: _plain(getattr(b, key)) for key in _BODY_ARRAYS},
                    **({} if b.limits is None else {"limits": list(b.limits)}),
                    **({"armature": float(b.armature)} if b.armature else {})} for b in model.bodies],
        "gravity": _plain(model.gravity),
        "input_map": _plain(model.input_map),
        "task_points": [{"name": tp.name, "body": tp.body, "offset": _plain(tp.offset),
                         "directions": _plain(tp.directions), **({"choice": tp.choice} if tp.choice else {})}
                        for tp in model.task_points],
        "constraints": [{"type": type(c).__name__, **{f.name: _plain(getattr(c, f.name))
                                                      for f in dataclasses.fields(c) if _written(c, f.name)}}
                        for c in model.constraints],
    }
    if model.loads:                           # written only when there are loads, so older dicts read the same
        d["loads"] = [{"type": type(x).__name__, **{f.name: _plain(getattr(x, f.name)) for f in dataclasses.fields(x)}}
                      for x in model.loads]
    if model.source is not None:
        d["source"] = {"kind": model.source.kind, "path": model.source.path,
                       "rotation": _plain(model.source.rotation), "translation": _plain(model.source.translation)}
        if model.source.root != "fixed":      # written only when not the default, so older dicts read the same
            d["source"]["root"] = model.source.root
        if not model.source.gravity:          # likewise: a gravity-free copy (ModelSource.without_gravity)
            d["source"]["gravity"] = False
        if model.source.armature:             # likewise: the armature the user declared for the file's joints
            d["source"]["armature"] = [[name, float(value)] for name, value in model.source.armature]
    return d


def _get(d, key, where: str):
    if not isinstance(d, dict):
        raise SerializeError(f"serialized model: {where or 'the top level'} is a {type(d).__name__}, expected an "
                             "object (dict)")
    if key not in d:
        raise SerializeError(f"serialized model: field '{_path(where, key)}' is missing")
    return d[key]


def _path(where: str, key) -> str:
    if isinstance(key, int):
        return f"{where}[{key}]"
    return f"{where}.{key}" if where else key


def _text(d, key, where: str, optional: bool = False) -> str | None:
    value = _get(d, key, where)
    if value is None and optional:
        return None
    if not isinstance(value, str):
        kind = "a string or null" if optional else "a string"
        raise SerializeError(f"serialized model: field '{_path(where, key)}' must be {kind}, got {value!r}")
    return value


def _numbers(d, key: str, where: str):
    """A number or a (nested) list of numbers, as floats; the shape is checked by ``build_model``."""
    value = _get(d, key, where)
    try:
        arr = np.array(value, dtype=float)
    except (TypeError, ValueError):
        raise SerializeError(f"serialized model: field '{_path(where, key)}' must be numbers, got {value!r}") from None
    if isinstance(value, (bool, str)) or arr.dtype == object:
        raise SerializeError(f"serialized model: field '{_path(where, key)}' must be numbers, got {value!r}")
    return float(arr) if arr.ndim == 0 else arr


def _items(d, key: str, where: str) -> list:
    value = _get(d, key, where)
    if not isinstance(value, list):
        raise SerializeError(f"serialized model: field '{_path(where, key)}' must be a list, got {value!r}")
    return value


def _body(d, where: str) -> Body:
    limits = _numbers(d, "limits", where) if isinstance(d, dict) and d.get("limits") is not None else None
    armature = _numbers(d, "armature", where) if isinstance(d, dict) and "armature" in d else 0.0
    return Body(name=_text(d, "name", where), parent=_text(d, "parent", where, optional=True),
                joint=_text(d, "joint", where), mass=_numbers(d, "mass", where),
                **{key: _numbers(d, key, where) for key in _BODY_ARRAYS},
                limits=None if limits is None else tuple(np.atleast_1d(limits).tolist()), armature=armature)


def _task_point(d, where: str) -> TaskPoint:
    directions = _get(d, "directions", where)
    return TaskPoint(_text(d, "name", where), _text(d, "body", where), _numbers(d, "offset", where),
                     None if directions is None else _numbers(d, "directions", where),
                     (_text(d, "choice", where) if "choice" in d else ""))


def _constraint(d, where: str):
    kind = _text(d, "type", where)
    cls = _CONSTRAINT_TYPES.get(kind)
    if cls is None:
        raise SerializeError(f"serialized model: field '{where}.type' is {kind!r}; valid types: "
                             f"{', '.join(_CONSTRAINT_TYPES)}")
    kwargs = {}
    for f in dataclasses.fields(cls):
        if f.name in ("name", "body", "body_a", "body_b"):
            kwargs[f.name] = _text(d, f.name, where, optional=f.name == "body_b")
        elif f.name == "joints":
            kwargs[f.name] = tuple(_text(dict(enumerate(_items(d, f.name, where))), i, f"{where}.joints")
                                   for i in range(len(d[f.name])))
        elif f.name == "coefficients":
            kwargs[f.name] = tuple(float(x) for x in np.atleast_1d(_numbers(d, f.name, where)))
        elif f.name == "lateral":           # absent in files written before the field: the two-row default
            if f.name in d and not isinstance(d[f.name], bool):
                raise SerializeError(f"serialized model: field '{where}.lateral' is {d[f.name]!r}; give true or false")
            kwargs[f.name] = d.get(f.name, True)
        else:
            kwargs[f.name] = _numbers(d, f.name, where)
    return cls(**kwargs)


def _load(d, where: str):
    """One load declaration (:mod:`cases.loads`) from its dict; the values are checked by ``build_model``."""
    kind = _text(d, "type", where)
    cls = _LOAD_TYPES.get(kind)
    if cls is None:
        raise SerializeError(f"serialized model: field '{where}.type' is {kind!r}; valid types: {', '.join(_LOAD_TYPES)}")
    kwargs = {}
    for f in dataclasses.fields(cls):
        kwargs[f.name] = (_text(d, f.name, where) if f.name in ("name", "body", "frame")
                          else _numbers(d, f.name, where))
    return cls(**kwargs)


def _source(d: dict) -> ModelSource | None:
    """The optional ``source`` field as a :class:`ModelSource` (absent or null: None); its placement is checked by
    ``build_model``."""
    value = d.get("source")
    if value is None:
        return None
    armature = _items(value, "armature", "source") if "armature" in value else []
    pairs = []
    for k, pair in enumerate(armature):
        if not isinstance(pair, list) or len(pair) != 2:
            raise SerializeError(f"serialized model: field 'source.armature[{k}]' must be [joint name, value], got "
                                 f"{pair!r}")
        pairs.append((_text(dict(enumerate(pair)), 0, f"source.armature[{k}]"),
                      _numbers(dict(enumerate(pair)), 1, f"source.armature[{k}]")))
    return ModelSource(_text(value, "kind", "source"), _text(value, "path", "source"),
                       _numbers(value, "rotation", "source"), _numbers(value, "translation", "source"),
                       _text(value, "root", "source") if "root" in value else "fixed", value.get("gravity", True),
                       tuple(pairs))


def model_from_dict(d: dict) -> Model:
    """The model a :func:`model_to_dict` dict describes, built (and so validated) by :func:`cases.build_model`.

    A missing or mistyped field raises :class:`SerializeError` naming it; a description that is not a valid model
    raises :class:`cases.ModelError` listing every problem.
    """
    if _get(d, "format", "") != FORMAT:
        raise SerializeError(f"serialized model: field 'format' is {d['format']!r}, expected {FORMAT!r}")
    if _get(d, "version", "") != VERSION:
        raise SerializeError(f"serialized model: version {d['version']!r} is not supported (this reads {VERSION})")
    bodies = [_body(b, f"bodies[{i}]") for i, b in enumerate(_items(d, "bodies", ""))]
    return build_model(
        _text(d, "name", ""), bodies, gravity=_numbers(d, "gravity", ""), input_map=_numbers(d, "input_map", ""),
        task_points=[_task_point(t, f"task_points[{i}]") for i, t in enumerate(_items(d, "task_points", ""))],
        constraints=[_constraint(c, f"constraints[{i}]") for i, c in enumerate(_items(d, "constraints", ""))],
        source=_source(d),
        loads=[_load(x, f"loads[{i}]") for i, x in enumerate(_items(d, "loads", "") if "loads" in d else [])])
