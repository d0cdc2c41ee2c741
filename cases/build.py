"""Building a model: a description validated into an immutable :class:`cases.model.Model` (:func:`build_model`:
every violated precondition reported together), with the default task point when none is given
(``cases.task.default_task_point``), and a model given another task point (:func:`with_task_point`, the command
line's ``--task-point BODY[:x,y,z]``, read by :func:`parse`)."""

from __future__ import annotations

import dataclasses
from typing import Iterable, Sequence

import numpy as np

from cases import constraints as constraint_decl, loads as load_decl
from cases.model import (GROUP_JOINTS, JOINT_DOF, JOINT_TYPES, SOURCE_KINDS, SOURCE_ROOTS, Body, Model, ModelError,
                         ModelSource, TaskPoint)
from cases.task import axes_through, choose, default_task_point, full_rank, motion_directions
from cases.validation import as_array, finite, frozen, orthonormal_rows


class TaskPointError(ValueError):
    """A task point given by the user (``--task-point``, :func:`with_task_point`) is not valid: the message says what
    is wrong and what is valid."""


#: Rounding allowed in an inertia's symmetry, definiteness and triangle inequality, relative to the body's inertia
#: about its joint frame, ``max|I_c| + m |c|^2`` (where it enters M): a file's inertia computed as that frame's
#: inertia minus the parallel-axis term keeps residues of this size (iCub's ``-5.42101e-20 = -2^-64`` on a 0.5 kg
#: body 3 cm from its joint), and 1e-9 of the inertia's own size for values printed to few digits.
INERTIA_ROUNDING = (16 * float(np.finfo(float).eps), 1e-9)


def inertia_tolerance(mass: float, com: np.ndarray, inertia: np.ndarray) -> float:
    """What :data:`INERTIA_ROUNDING` allows for an inertia about the COM of a body of ``mass`` at ``com``."""
    own = float(np.abs(inertia).max())
    return INERTIA_ROUNDING[0] * (own + mass * float(com @ com)) + INERTIA_ROUNDING[1] * own


def _check_inertia(problems: list[str], findings: list[str], where: str, inertia: np.ndarray, tol: float) -> None:
    """An asymmetric inertia or a negative principal moment beyond ``tol`` is a problem (no rigid body has it, and
    Pinocchio refuses it); a principal moment above the sum of the other two, beyond ``tol``, is a finding (no rigid
    body has it either, but M stays positive definite: every backend can still be compared)."""
    if np.abs(inertia - inertia.T).max() > tol:
        problems.append(f"{where} inertia about its COM is not symmetric: {inertia.tolist()}")
        return
    eig = np.linalg.eigvalsh(0.5 * (inertia + inertia.T))
    if eig[0] < -tol:
        problems.append(f"{where} inertia about its COM is not positive semi-definite: eigenvalues {eig.tolist()} "
                        f"(rounding allows {tol:.2g}); fix it in the file (a point mass uses the zero matrix)")
    elif eig[2] > eig[0] + eig[1] + tol:
        findings.append(f"{where} inertia about its COM violates the triangle inequality: principal moments "
                        f"{eig.tolist()}, the largest exceeds the sum of the other two by "
                        f"{eig[2] - eig[0] - eig[1]:.3g} (rounding allows {tol:.2g})")


def _validate_body(problems: list[str], findings: list[str], body: Body) -> Body | None:
    where = f"body '{body.name}'"
    n_before = len(problems)
    if body.joint not in JOINT_TYPES:
        problems.append(f"{where} has joint type {body.joint!r}; valid types: {list(JOINT_TYPES)}")
    axis = as_array(problems, f"{where} joint axis", body.axis, (3,))
    if axis is not None and body.joint in GROUP_JOINTS:
        if np.any(axis):
            problems.append(f"{where} has a {body.joint} joint, which has no axis, but axis {axis.tolist()}; "
                            "give axis=(0, 0, 0)")
    elif axis is not None:
        norm = np.linalg.norm(axis)
        if norm < 1e-12:
            problems.append(f"{where} has a zero joint axis {axis.tolist()}")
        elif abs(norm - 1.0) > 1e-6:
            problems.append(f"{where} joint axis {axis.tolist()} has norm {norm:.6g}; give a unit vector "
                            "(for a prismatic joint the axis length would rescale q)")
        elif abs(norm - 1.0) > 4 * np.finfo(float).eps:  # a unit vector to rounding stays bit for bit: dividing
            axis = axis / norm                            # by its computed norm can move a last bit (not idempotent)
    try:
        mass = float(body.mass)
    except (TypeError, ValueError):
        problems.append(f"{where} mass is not a number: {body.mass!r}")
        mass = float("nan")
    if not np.isfinite(mass):
        problems.append(f"{where} has a non-finite mass {mass}")
    elif mass < 0.0:
        problems.append(f"{where} has a negative mass {mass}")
    com = as_array(problems, f"{where} centre of mass", body.com, (3,))
    inertia = as_array(problems, f"{where} inertia", body.inertia, (3, 3))
    if inertia is not None and com is not None and np.isfinite(mass):
        _check_inertia(problems, findings, where, inertia, inertia_tolerance(abs(mass), com, inertia))
        if mass == 0.0 and np.abs(inertia).max() > 0.0:
            findings.append(f"{where} has zero mass but a non-zero inertia {inertia.tolist()}; a massless body "
                            "(a carriage) has zero inertia")
    rotation = as_array(problems, f"{where} joint placement rotation", body.rotation, (3, 3))
    if rotation is not None:
        err = np.abs(rotation.T @ rotation - np.eye(3)).max()
        if err > 1e-9 or np.linalg.det(rotation) < 0:
            problems.append(f"{where} joint placement rotation is not a proper rotation "
                            f"(|R^T R - I| = {err:.2e}, det = {np.linalg.det(rotation):.6f})")
    translation = as_array(problems, f"{where} joint placement translation", body.translation, (3,))
    limits = _limits(problems, where, body)
    armature = _armature(problems, where, body)
    if len(problems) > n_before:
        return None
    return Body(name=body.name, parent=body.parent, joint=body.joint, axis=frozen(axis, 3), mass=mass,
                com=frozen(com, 3), inertia=frozen(0.5 * (inertia + inertia.T), (3, 3)),
                rotation=frozen(rotation, (3, 3)), translation=frozen(translation, 3), limits=limits,
                armature=armature)


def _armature(problems: list[str], where: str, body: Body) -> float:
    """The body's joint armature as a float (``cases.model.Body.armature``); a problem for one that is not a finite
    number >= 0."""
    value = body.armature
    if isinstance(value, (bool, np.bool_)):
        problems.append(f"{where} armature {value!r} is not a number; give the rotor inertia (kg m^2 for a revolute "
                        "joint, kg for a prismatic one), >= 0")
        return 0.0
    try:
        armature = float(value)
    except (TypeError, ValueError):
        problems.append(f"{where} armature {value!r} is not a number; give the rotor inertia (kg m^2 for a revolute "
                        "joint, kg for a prismatic one), >= 0")
        return 0.0
    if not np.isfinite(armature) or armature < 0.0:
        problems.append(f"{where} armature {armature} must be finite and >= 0 (the rotor inertia added to the "
                        "joint's diagonal entries of M; 0 for none)")
        return 0.0
    if armature and body.joint == "free":
        problems.append(f"{where} has a free joint with armature {armature}; armature on a free joint is not "
                        "supported: MuJoCo's and Pinocchio's (a I added to the 6x6 block of M, no velocity term) is "
                        "the kinetic energy of no rotor (1/2 a |v|^2 over the body twist brings the gyroscopic force "
                        "a w x v), so the energy-based formalisms cannot state it; a floating base has no motor to the "
                        "world: give it armature 0")
        return 0.0
    return armature + 0.0                           # -0.0 becomes 0.0: the same model, the same digest


def _limits(problems: list[str], where: str, body: Body) -> tuple[float, float] | None:
    """The body's joint limits as two floats, or None; a problem for limits on a joint without one coordinate, or
    limits that are not two finite numbers with lower <= upper."""
    if body.limits is None:
        return None
    if body.joint not in ("revolute", "prismatic"):
        problems.append(f"{where} has a {body.joint} joint with limits {body.limits!r}; only revolute and prismatic "
                        "joints take limits (lower, upper)")
        return None
    try:
        lower, upper = (float(x) for x in body.limits)
    except (TypeError, ValueError):
        problems.append(f"{where} joint limits {body.limits!r} are not two numbers (lower, upper)")
        return None
    if not (np.isfinite(lower) and np.isfinite(upper) and lower <= upper):
        problems.append(f"{where} joint limits ({lower}, {upper}) are not finite with lower <= upper; leave them out "
                        "(None) for an unlimited joint")
        return None
    return lower, upper


def _topology(problems: list[str], bodies: Sequence[Body]) -> tuple[tuple[int, ...], tuple[int, ...]]:
    """Parent indices (-1 for the world) and a parents-first order; reports unknown parents and cycles."""
    index: dict[str, int] = {}
    for i, b in enumerate(bodies):
        if b.name in index:
            problems.append(f"body name '{b.name}' is used more than once")
        index.setdefault(b.name, i)
    parent = []
    for b in bodies:
        if b.parent is None:
            parent.append(-1)
        elif b.parent not in index:
            problems.append(f"body '{b.name}' names an unknown parent '{b.parent}'; "
                            f"bodies: {[x.name for x in bodies]} (None means the world)")
            parent.append(-1)
        else:
            parent.append(index[b.parent])
    order: list[int] = []
    placed = [False] * len(bodies)
    for _ in range(len(bodies)):
        for i, p in enumerate(parent):
            if not placed[i] and (p < 0 or placed[p]):
                placed[i] = True
                order.append(i)
    stuck = [bodies[i].name for i in range(len(bodies)) if not placed[i]]
    if stuck:
        problems.append(f"the parent links form a cycle through bodies {stuck}; a kinematic tree needs every "
                        "chain of parents to end at the world")
    return tuple(parent), tuple(order)


def _input_map(problems: list[str], input_map, n: int) -> np.ndarray:
    """B as an (n, m) float array (a length-n vector is one input); problems are appended, not raised."""
    if input_map is None:
        return np.eye(n)
    try:
        B = np.array(input_map, dtype=float)
    except (TypeError, ValueError):
        problems.append(f"input map B is not a numeric (n, m) array: {input_map!r}")
        return np.zeros((n, 0))
    if B.ndim == 1 and B.shape[0] == n:
        B = B.reshape(n, 1)
    if B.ndim != 2 or B.shape[0] != n:
        problems.append(f"input map B has shape {B.shape}, expected ({n}, m) for {n} degrees of freedom")
    else:
        finite(problems, "input map B", B)
    return B


def _validate_task_point(problems: list[str], tp: TaskPoint, body_names: set[str]) -> TaskPoint | None:
    where = f"task point '{tp.name}'"
    n_before = len(problems)
    offset = as_array(problems, f"{where} offset", tp.offset, (3,))
    if tp.body not in body_names:
        problems.append(f"{where} is on an unknown body '{tp.body}'")
    D = orthonormal_rows(problems, f"{where} directions", np.eye(3) if tp.directions is None else tp.directions,
                         (1, 2, 3))
    if len(problems) > n_before:
        return None
    return TaskPoint(tp.name, tp.body, frozen(offset, 3), D, str(tp.choice))


def _moving_mass(problems: list[str], bodies: Sequence[Body], parent: Sequence[int]) -> None:
    """Every joint must move some mass, or its row of M is zero (a massless carriage at the tip); a joint that turns
    may move a rotational inertia instead (a massless body with one is a finding, ``_check_inertia``)."""
    subtree = [(b.mass, b.mass + float(np.abs(b.inertia).max())) for b in bodies]
    for i in sorted(range(len(bodies)), key=lambda j: -_depth(parent, j)):
        if parent[i] >= 0:
            subtree[parent[i]] = tuple(a + b for a, b in zip(subtree[parent[i]], subtree[i]))
    for b, (mass, anything) in zip(bodies, subtree):
        if (mass if b.joint in ("prismatic", "free") else anything) == 0.0:      # a slide needs a mass
            problems.append(f"joint of body '{b.name}' moves no mass (the body and all its descendants are "
                            "massless), so the mass matrix is singular; give the body or a descendant a mass, or "
                            "make the joint fixed (a massless finger of a hand model)")


def _depth(parent: Sequence[int], i: int) -> int:
    depth = 0
    while parent[i] >= 0:
        i, depth = parent[i], depth + 1
    return depth


def _validate_source(problems: list[str], source) -> ModelSource | None:
    """``source`` with its placement as read-only arrays, or None (appending what is wrong)."""
    if source is None:
        return None
    if not isinstance(source, ModelSource):
        problems.append(f"source must be a cases.model.ModelSource or None, got {source!r}")
        return None
    n_before = len(problems)
    if source.kind not in SOURCE_KINDS:
        problems.append(f"source kind {source.kind!r} is not one of {list(SOURCE_KINDS)}")
    if not isinstance(source.path, str) or not source.path:
        problems.append(f"source path must be a non-empty string, got {source.path!r}")
    if source.root not in SOURCE_ROOTS:
        problems.append(f"source root {source.root!r} is not one of {list(SOURCE_ROOTS)}")
    rotation = as_array(problems, "source rotation", source.rotation, (3, 3))
    if rotation is not None and (np.abs(rotation.T @ rotation - np.eye(3)).max() > 1e-9
                                 or np.linalg.det(rotation) < 0):
        problems.append(f"source rotation is not a proper rotation: {rotation.tolist()}")
    translation = as_array(problems, "source translation", source.translation, (3,))
    if not isinstance(source.gravity, bool):
        problems.append(f"source gravity must be True (the file's gravity acts) or False, got {source.gravity!r}")
    armature = _declared_armature(problems, source.armature)
    if len(problems) > n_before:
        return None
    return ModelSource(source.kind, source.path, frozen(rotation, (3, 3)), frozen(translation, 3), source.root,
                       source.gravity, armature)


def _declared_armature(problems: list[str], declared) -> tuple[tuple[str, float], ...]:
    """A source's declared armature (``ModelSource.armature``) as ``(joint name, float)`` pairs; a problem for
    anything but pairs of a name (once each) and a finite value >= 0."""
    try:
        pairs = [(name, value) for name, value in declared]
    except (TypeError, ValueError):
        problems.append(f"source armature must be (joint name, value) pairs, got {declared!r}")
        return ()
    out = []
    for name, value in pairs:
        try:
            number = float(value)
        except (TypeError, ValueError):
            number = float("nan")
        if not isinstance(name, str) or not name or isinstance(value, bool) or not (np.isfinite(number)
                                                                                     and number >= 0.0):
            problems.append(f"source armature ({name!r}, {value!r}) must be a joint name and a finite value >= 0")
        else:
            out.append((name, number + 0.0))
    names = [name for name, _ in out]
    if len(set(names)) < len(names):
        problems.append(f"source armature names a joint more than once: {names}")
    return tuple(out)


def build_model(name: str, bodies: Iterable[Body], gravity=(0.0, 0.0, -9.81), input_map=None,
                task_points: Iterable[TaskPoint] | None = None, constraints: Iterable = (),
                source: ModelSource | None = None, loads: Iterable = (), findings: Iterable[str] = ()) -> Model:
    """Validate the description and return an immutable :class:`Model`.

    Every violated precondition is collected and reported together in one :class:`ModelError`.
    Default input map: identity (fully actuated). Default task point ``tip``: the COM of the last body, or, when that
    lies on a joint axis, an offset point of it, with the task directions it moves in (``cases.task.choose``: a planar
    chain's plane), so that its task Jacobian has full row rank away from singular configurations.
    ``source``: the file the description was converted from (:class:`ModelSource`; loaders set it).
    ``loads``: external load declarations (:mod:`cases.loads`), validated like the constraints. ``findings``: what a
    loader found wrong in the file and worked around (``Model.findings``, after the bodies' own).
    """
    bodies = list(bodies)
    problems: list[str] = []
    if not bodies:
        problems.append("a model needs at least one body")
    found: list[str] = []
    valid = [_validate_body(problems, found, b) for b in bodies]
    parent, order = _topology(problems, bodies)
    g = as_array(problems, "gravity", gravity, (3,))
    n = sum(JOINT_DOF.get(b.joint, (1, 1))[1] for b in bodies)
    B = _input_map(problems, input_map, n)
    names = {b.name for b in bodies}
    default = task_points is None
    task_points = [] if default else list(task_points)
    if not task_points and not default:
        problems.append("a model needs at least one task point (the task drift and the operational-space backend "
                        "use the first); leave task_points out for the default, the COM of the last body")
    tps = [tp for tp in (_validate_task_point(problems, tp, names) for tp in task_points) if tp is not None]
    if not problems:
        _moving_mass(problems, valid, parent)
    constraints = tuple(constraint_decl.validate(problems, c, names) for c in constraints)
    joint_of = {b.name: b.joint for b in bodies}
    for c in constraints:
        for j in getattr(c, "joints", ()) if isinstance(c, constraint_decl.JointCoupling) else ():
            if joint_of.get(j) in GROUP_JOINTS:
                problems.append(f"constraint '{c.name}' couples the {joint_of[j]} joint of body '{j}'; a joint "
                                "coupling relates joint values (revolute or prismatic joints), and a quaternion is "
                                "not one: constrain a point of the body instead")
    declared = [c.name for c in constraints if c is not None]
    if len(set(declared)) < len(declared):
        problems.append(f"constraint names repeat: {declared}; give each constraint its own name")
    source = _validate_source(problems, source)
    loads = tuple(load_decl.validate(problems, load, names) for load in loads)
    load_names = [load.name for load in loads if load is not None]
    if len(set(load_names)) < len(load_names):
        problems.append(f"load names repeat: {load_names}; give each load its own name")
    if problems:
        raise ModelError(name, problems)
    B = B.copy()
    B.setflags(write=False)
    model = Model(name=name, bodies=tuple(valid), gravity=frozen(g, 3), input_map=B,
                  task_points=tuple(tps), constraints=constraints, parent_index=parent, topological_order=order,
                  source=source, loads=loads, findings=tuple(dict.fromkeys([*found, *findings])))
    if default:
        tp = _validate_task_point(problems, default_task_point(model), names)
        model = dataclasses.replace(model, task_points=(tp,))
    return model


def parse(text: str) -> tuple[str, np.ndarray | None]:
    """``BODY`` or ``BODY:x,y,z`` (the CLI's ``--task-point``) as (body, offset or None); a ValueError saying what is
    wrong for anything else (:class:`TaskPointError`)."""
    body, sep, rest = text.partition(":")
    if not body:
        raise TaskPointError(f"--task-point takes BODY or BODY:x,y,z (an offset in the body's frame, in m), got "
                             f"'{text}'")
    if not sep:
        return body, None
    parts = rest.split(",")
    try:
        offset = np.array([float(p) for p in parts])
    except ValueError:
        raise TaskPointError(f"--task-point '{text}': the offset '{rest}' is not three numbers x,y,z (in m, in the "
                             "body's frame)") from None
    if offset.shape != (3,) or not np.all(np.isfinite(offset)):
        raise TaskPointError(f"--task-point '{text}': the offset needs three finite numbers x,y,z (in m, in the "
                             f"body's frame), got {len(parts)} entr{'y' if len(parts) == 1 else 'ies'}")
    return body, offset


def with_task_point(model: Model, body: str, offset=None, directions=None) -> Model:
    """``model`` with its default task point replaced by a point of ``body``: at ``offset`` (body frame, m) when
    given, else at the body's COM (or an offset point of the body if the COM lies on a joint axis: :func:`choose`).
    ``directions`` (orthonormal world rows) default to the directions the point moves in. The model's other task
    points follow. An unknown body is a :class:`TaskPointError` listing the bodies; a point on a joint axis is
    accepted (it is asked for) but its ``choice`` says so."""
    names = [b.name for b in model.bodies]
    if body not in names:
        raise TaskPointError(f"--task-point: model '{model.name}' has no body '{body}'; bodies: {', '.join(names)}")
    if offset is None:
        tp = choose(model, [TaskPoint(f"task_point:{body}", body, np.array(model.bodies[names.index(body)].com))],
                    [f"the centre of mass of body '{body}' (given: --task-point {body})"], name=f"task_point:{body}")
        tp = dataclasses.replace(tp, choice=tp.choice.replace("default: ", "given body; ", 1))
    else:
        offset = np.asarray(offset, dtype=float)
        D = motion_directions(model, body, offset) if directions is None else np.asarray(directions, dtype=float)
        on = axes_through(model, body, offset)
        warning = "" if len(D) and full_rank(model, body, offset, D) else (
            f" (it lies on {' and '.join(on)}: its task Jacobian is rank-deficient everywhere)" if on else
            " (its task Jacobian is rank-deficient everywhere)")
        tp = TaskPoint(f"task_point:{body}", body, offset, D if len(D) else np.eye(3),
                       choice=f"given: body '{body}', offset {offset.tolist()}{warning}")
    if directions is not None:
        tp = dataclasses.replace(tp, directions=np.asarray(directions, dtype=float))
    others = [t for t in model.task_points if t.name != tp.name]
    try:
        return build_model(model.name, model.bodies, gravity=model.gravity, input_map=model.input_map,
                           task_points=[tp, *others], constraints=model.constraints, source=model.source,
                           loads=model.loads, findings=model.findings)
    except ModelError as exc:
        raise TaskPointError(f"--task-point {body}: {'; '.join(exc.problems)}") from None
