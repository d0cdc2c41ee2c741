"""The backends the harness evaluates: the built-in formalisms, the Pinocchio reference, and plugins.

A plugin is a user's own backend behind the formalisms' contract (:class:`formalisms.interface.Formalism`): an
object with a ``name`` (letters, digits, ``_`` and ``-``), a callable ``split(X, q, qd, u)`` returning a
:class:`~formalisms.interface.Split`, and optionally a one-line ``summary``, a ``split_chart(X, chart, p, pd,
tau_p)`` and ``needs``, what ``X`` is. It joins in one of two ways:

* an entry point in the group ``crosscheck.formalisms`` of an installed distribution, named like the backend
  (``closed_form_pendulum = "closed_form_pendulum:CLOSED_FORM"``), discovered on first use, in name order;
* :func:`load_plugin` (the command line's ``--plugin``): ``"module:object"`` (a module on ``sys.path`` or in the
  current directory) or ``"path/to/file.py:object"`` (a file, no installation or environment variable needed; its
  folder joins ``sys.path``, so it imports the modules beside it); or :func:`register` (the object).

What a plugin needs
-------------------
``needs`` (a string attribute; default ``"model"``) declares what ``X`` is (:mod:`crosscheck.needs`):

* ``"model"``: crosscheck's :class:`cases.model.Model` (bodies, inertias, gravity, B, constraints);
* ``"source"``: a :class:`crosscheck.needs.SourceScene`, the file the model was loaded from (URDF or MJCF) and where
  the scene places it (rigid placement, gravity on or off), with the layout of a state: for code that reads the
  file itself (``examples/mujoco_plugin.py``);
* ``"pinocchio"``: a :class:`crosscheck.needs.PinocchioScene`, a Pinocchio model and data built from the same source
  (the file for a loaded model, else our data) and the maps between our coordinate order and Pinocchio's.

``split`` is called on the case's scene and also on **moved scenes** (the frame checks: the file's world placed by
a rigid transform, gravity turned with it) and on **gravity-free copies** (the hints at a failing state): ``X``
always describes the scene of that call, never the case as loaded. A value of ``needs`` not in
:data:`crosscheck.needs.NEEDS` is a PluginError at load. What an input cannot describe raises
``ModelNotSupported``: a ``"source"`` plugin on a model built in code (a built-in case, a fuzz model) has no file,
and is NOT COMPARED there.

Order (:func:`names`): the five formalisms, the reference, then the plugins (entry points first). Plugins come
last so that adding one never moves a built-in backend: with and without plugins the built-ins keep their places
in every report table, and the first backend (whose cond(M) a report prints per state) stays a built-in.

Isolation
---------
A plugin loaded by spec (``--plugin``, :func:`load_plugin`) or from an entry point is evaluated in a child process
of its own (:mod:`crosscheck.isolation`): a crash of its native code (a segfault) is a ``PluginCrashed`` error of that plugin at
that state, which fails the gate naming it (like any exception other than ``ModelNotSupported``, ``--optional`` or
not), and the run goes on and writes its report. A plugin given by object (:func:`register`) has no spec to be
loaded by in another process and runs in the evaluating process.

Every problem with a plugin is a :class:`PluginError` naming the plugin and what to fix. A plugin that raises
``formalisms.interface.ModelNotSupported`` for a model is NOT COMPARED on it
(``crosscheck.engine.evaluation.evaluate``).
"""

from __future__ import annotations

import importlib
import importlib.metadata
import importlib.util
import os
import re
import sys
from dataclasses import dataclass, replace
from pathlib import Path
from typing import Any, Callable, Sequence

import numpy as np

from crosscheck import isolation
from crosscheck.needs import NEEDS, given
from crosscheck.references.pinocchio.reference import REFERENCE
import formalisms
from formalisms.interface import Formalism, Split, Unsupported

REFERENCE_NAME = "pinocchio"

#: The entry-point group an installed distribution declares its backends in.
ENTRY_POINT_GROUP = "crosscheck.formalisms"

#: A backend name appears in reports, in ``--formalism`` and in labels such as ``name@g0`` (a moved scene).
_NAME = re.compile(r"[A-Za-z0-9_][A-Za-z0-9_-]*\Z")

#: Names the comparisons use for voters that are not backends (``crosscheck.core.compare``: the exact value).
RESERVED = ("exact", "independent", "closed_form")


class PluginError(Exception):
    """A plugin cannot be used: not importable, not found, not a backend, a name taken, an entry point that fails."""


@dataclass(frozen=True)
class _Checked:
    """A plugin's ``split`` (or ``split_chart``), given what the plugin ``need``s for the model of each call
    (:func:`crosscheck.needs.given`), whose result must be a Split; anything else is a TypeError, which the gate
    reports as that backend's error at that state. A plugin loaded by spec is sent to a worker process as its spec
    (:meth:`__reduce__`), so a plugin loaded from a file path needs no importable module there, and is evaluated in
    a child process of its own (:mod:`crosscheck.isolation`: a crash of its native code is an error of this plugin
    at that state, not the end of the run)."""

    name: str
    function: Callable[..., Any]
    need: str = "model"
    spec: str | None = None
    attribute: str = "split"

    def __reduce__(self):
        if self.spec is None:
            return super().__reduce__()
        return _reloaded, (self.spec, self.name, self.attribute)

    def __call__(self, model, *args) -> Split:
        if self.spec is not None and isolation.isolated():
            return replace(isolation.call(self.spec, self.name, self.attribute, self, model, args))  # arrays frozen
        out = self.function(given(self.need, model, self.name), *args)
        if not isinstance(out, Split):
            raise TypeError(f"plugin '{self.name}' returned {type(out).__name__}, not a formalisms.interface.Split "
                            "(build one with crosscheck.assemble.unconstrained_split or constrained_split)")
        sizes = {"drift": model.n, "lam": model.k if model.constraints else None}
        for key, size in sizes.items():
            value = getattr(out, key)
            shape = None if value is None or isinstance(value, Unsupported) else np.shape(value)
            if shape != (None if size is None else (size,)):
                raise TypeError(f"plugin '{self.name}' returned {key} of shape {shape} for model '{model.name}', "
                                f"which has {model.n} joints and {model.k} constraint rows (expected "
                                f"{None if size is None else (size,)})")
        return out


@dataclass(frozen=True)
class _Plugin:
    obj: Any              # what was loaded or registered (loading the same object again is a no-op)
    formalism: Formalism
    source: str           # where it came from, for messages and ``crosscheck formalisms``
    spec: str | None      # the ``module:object`` that loads it again (worker processes); None otherwise


_plugins: dict[str, _Plugin] = {}
_discovered = False


def _reloaded(spec: str, name: str, attribute: str) -> _Checked:
    """A plugin's checked ``split`` or ``split_chart`` in another process: the plugin loaded there by its spec."""
    return getattr(load_plugin(spec), attribute)


def _problems(obj) -> list[str]:
    """What keeps ``obj`` from being a backend (empty when nothing)."""
    name, split = getattr(obj, "name", None), getattr(obj, "split", None)
    chart, summary = getattr(obj, "split_chart", None), getattr(obj, "summary", "")
    out = []
    if not isinstance(name, str):
        out.append(f"no 'name' string (got {type(name).__name__})")
    elif not _NAME.match(name) or name in RESERVED:
        out.append(f"the name '{name}' is not usable: take letters, digits, '_' and '-' (not {', '.join(RESERVED)})")
    if not callable(split):
        out.append("no callable 'split(model, q, qd, u) -> Split'")
    if chart is not None and not callable(chart):
        out.append("a 'split_chart' that is not callable (leave it None when the backend works in joint "
                   "coordinates only)")
    if not isinstance(summary, str):
        out.append(f"a 'summary' that is not a string (got {type(summary).__name__})")
    need = getattr(obj, "needs", NEEDS[0])
    if not isinstance(need, str) or need not in NEEDS:
        out.append(f"needs = {need!r}: declare one of 'model' (crosscheck's Model, the default), 'source' (the file "
                   "the model was loaded from and the scene's placement) or 'pinocchio' (a Pinocchio model and data "
                   "of the same source)")
    return out


def _add(obj, source: str, spec: str | None, loads: str | None = None) -> Formalism:
    """Validate ``obj`` and register it under its name; the same object again is a no-op. ``spec`` is what a worker
    process loads it by (:func:`plugin_specs`); ``loads``, when there is no spec, the ``module:object`` that loads it
    in its child process (an entry point's value: a worker discovers the entry points itself)."""
    problems = _problems(obj)
    if problems:
        raise PluginError(f"{source} is not a backend (formalisms.interface.Formalism): it has "
                          + "; ".join(problems))
    name = obj.name
    if name in formalisms.names() or name == REFERENCE_NAME:
        raise PluginError(f"{source} is named '{name}', the name of a built-in backend; give it another name")
    if name in _plugins:
        if _plugins[name].obj is obj:
            return _plugins[name].formalism
        raise PluginError(f"{source} is named '{name}', a name already taken by {_plugins[name].source}; "
                          "give one of them another name")
    chart, need = getattr(obj, "split_chart", None), getattr(obj, "needs", NEEDS[0])
    loads = spec or loads
    formalism = Formalism(name, getattr(obj, "summary", ""), _Checked(name, obj.split, need, loads),
                          None if chart is None else _Checked(name, chart, need, loads, "split_chart"))
    _plugins[name] = _Plugin(obj, formalism, source, spec)
    if loads is not None:
        isolation.start(loads)
    return formalism


def _distribution(ep) -> str:
    dist = getattr(ep, "dist", None)
    return "(unknown)" if dist is None else f"'{dist.metadata['Name']} {dist.version}'"


def _discover() -> None:
    """Register the backends of the installed distributions' entry points (once; in name order)."""
    global _discovered
    if _discovered:
        return
    for ep in sorted(importlib.metadata.entry_points(group=ENTRY_POINT_GROUP), key=lambda e: e.name):
        source = f"entry point '{ep.name} = {ep.value}' (group {ENTRY_POINT_GROUP}) of distribution {_distribution(ep)}"
        try:
            obj = ep.load()
        except Exception as exc:  # user code: any failure is reported, with where it came from
            raise PluginError(f"{source} failed to load: {type(exc).__name__}: {exc}") from exc
        if getattr(obj, "name", None) != ep.name and not _problems(obj):
            raise PluginError(f"{source} loads a backend named '{obj.name}'; name the entry point like the backend "
                              f"('{obj.name} = {ep.value}')")
        _add(obj, source, None, ep.value)
    _discovered = True


def _import_file(path_text: str, spec: str):
    """Import the plugin's module from a ``.py`` file (relative to the current directory), as a module named after
    the file, with the file's folder on ``sys.path`` (after the installed packages) so that it can import the modules
    beside it; a worker or child process loading the plugin by its spec does the same."""
    path = Path(path_text).resolve()
    if not path.is_file():
        raise PluginError(f"plugin '{spec}': file '{path_text}' not found (from {os.getcwd()})")
    name = path.stem
    loaded = sys.modules.get(name)
    if loaded is not None:
        if getattr(loaded, "__file__", None) and Path(loaded.__file__).resolve() == path:
            return loaded
        raise PluginError(f"plugin '{spec}': a module named '{name}' is already imported (from "
                          f"{getattr(loaded, '__file__', None) or 'built in'}); rename the file")
    if str(path.parent) not in sys.path:        # its sibling modules import, as a script's do (after the installed)
        sys.path.append(str(path.parent))
    found = importlib.util.spec_from_file_location(name, path)
    module = importlib.util.module_from_spec(found)
    sys.modules[name] = module
    try:
        found.loader.exec_module(module)
    except Exception as exc:  # user code: any failure at import is reported as such
        del sys.modules[name]
        raise PluginError(f"plugin '{spec}': importing file '{path_text}' failed: {type(exc).__name__}: "
                          f"{exc}") from exc
    return module


def _import(module_name: str, spec: str):
    """Import the plugin's module; the current directory is searched too (after the installed packages)."""
    if module_name.endswith(".py"):
        return _import_file(module_name, spec)
    if os.getcwd() not in sys.path:
        sys.path.append(os.getcwd())
    try:
        return importlib.import_module(module_name)
    except ModuleNotFoundError as exc:
        if exc.name is not None and (module_name + ".").startswith(exc.name + "."):
            raise PluginError(f"plugin '{spec}': module '{module_name}' not found (install the package that "
                              f"provides it, or run from the directory that contains it)") from exc
        raise PluginError(f"plugin '{spec}': importing module '{module_name}' failed: ModuleNotFoundError: "
                          f"{exc}") from exc
    except Exception as exc:  # user code: any failure at import is reported as such
        raise PluginError(f"plugin '{spec}': importing module '{module_name}' failed: {type(exc).__name__}: "
                          f"{exc}") from exc


def _defaults_named(spec: str, attr: str) -> tuple[str, tuple[str, ...]]:
    """The object's path and the defaults named in brackets after it (``BACKEND[damping,springs]``)."""
    if not attr.endswith("]"):
        return attr, ()
    path, bracket, names = attr[:-1].partition("[")
    if not bracket or not path:
        raise PluginError(f"plugin '{spec}': defaults are named in brackets after the object, as in "
                          "crosscheck.adapters.mujoco:BACKEND[damping]")
    return path, tuple(n.strip() for n in names.split(",") if n.strip())


def load_plugin(spec: str) -> Formalism:
    """Load and register the backend ``"module:object"`` or ``"path/to/file.py:object"`` (``object`` may be dotted);
    a module alone loads its ``BACKEND``; ``object[a,b]`` is ``object.with_defaults("a", "b")`` (an adapter with
    those defaults of its library left on, ``crosscheck.adapters``). Loading it again is a no-op."""
    module_name, sep, attr = spec.rpartition(":")
    if not sep and spec and not spec.endswith(".py"):
        module_name, attr = spec, "BACKEND"
    if not module_name or not attr:
        raise PluginError(f"a plugin is given as MODULE:OBJECT or FILE.py:OBJECT (e.g. mypkg.dynamics:BACKEND, "
                          f"crosscheck.adapters.mujoco:BACKEND), got '{spec}'")
    _discover()
    obj = _import(module_name, spec)
    attr, defaults = _defaults_named(spec, attr)
    for part in attr.split("."):
        if not hasattr(obj, part):
            candidates = sorted(k for k, v in vars(obj).items() if not _problems(v)) if hasattr(obj, "__dict__") else []
            raise PluginError(f"plugin '{spec}': '{module_name}' has no attribute '{attr}' (backends defined there: "
                              f"{', '.join(candidates) or 'none'})")
        obj = getattr(obj, part)
    if defaults:
        obj = _with_defaults(spec, obj, defaults)
    return _add(obj, f"plugin '{spec}'", spec)


_CONFIGURED: dict[str, Any] = {}


def _with_defaults(spec: str, obj, defaults: tuple[str, ...]):
    """``obj.with_defaults(*defaults)``, one object per spec (loading it again is a no-op)."""
    if spec not in _CONFIGURED:
        if not callable(getattr(obj, "with_defaults", None)):
            raise PluginError(f"plugin '{spec}': {type(obj).__name__} has no defaults to leave on (no with_defaults)")
        try:
            _CONFIGURED[spec] = obj.with_defaults(*defaults)
        except ValueError as exc:
            raise PluginError(f"plugin '{spec}': {exc}") from exc
    return _CONFIGURED[spec]


def load_plugins(specs: Sequence[str]) -> None:
    """:func:`load_plugin` each spec, in order (the command line; a worker process's initializer with
    :func:`plugin_specs` of its parent)."""
    for spec in specs:
        load_plugin(spec)


def register(obj) -> Formalism:
    """Register a backend object (a :class:`~formalisms.interface.Formalism` or anything with ``name``, ``split``
    and optionally ``summary`` and ``split_chart``); returns it as a Formalism. Not passed on to worker
    processes (use :func:`load_plugin` for that)."""
    _discover()
    return _add(obj, f"the {type(obj).__name__} object passed to register()", None)


def plugin_specs() -> tuple[str, ...]:
    """The ``module:object`` specs of the plugins loaded so far, in order: what a worker process needs to load the
    same plugins (it discovers the entry points itself)."""
    return tuple(p.spec for p in _plugins.values() if p.spec is not None)


def plugin_object(name: str):
    """The object a plugin was loaded or registered as (an adapter's ``DEFAULTS`` and ``library()`` are read off it)."""
    _discover()
    if name not in _plugins:
        raise formalisms.UnknownFormalism(f"no plugin '{name}'; plugins: {', '.join(_plugins) or 'none'}")
    return _plugins[name].obj


def plugin_sources() -> dict[str, str]:
    """Plugin name -> where it came from (entry point, ``--plugin`` spec or register())."""
    _discover()
    return {name: p.source for name, p in _plugins.items()}


def reset() -> None:
    """Forget every plugin (and end their child processes); the entry points are discovered again on next use."""
    global _discovered
    _plugins.clear()
    isolation.stop_all()
    _discovered = False


def builtin_names() -> list[str]:
    """The five formalisms and the reference, without plugins."""
    return formalisms.names() + [REFERENCE_NAME]


def names() -> list[str]:
    """Every formalism, the reference, then the plugins (module docstring: why in that order)."""
    _discover()
    return builtin_names() + list(_plugins)


def get(name: str) -> Formalism:
    """A formalism, the reference or a plugin by name; an unknown name lists the valid ones."""
    if name == REFERENCE_NAME:
        return REFERENCE
    if name in formalisms.names():
        return formalisms.get(name)
    _discover()
    if name not in _plugins:
        raise formalisms.UnknownFormalism(f"unknown formalism '{name}'; valid: {', '.join(names())}")
    return _plugins[name].formalism
