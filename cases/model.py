"""The model language: an immutable kinematic tree of rigid bodies (docs/design.md, "The data flow").

A model is plain data. Every backend reads the same fields and derives its own kinematics from them.

Frames and conventions
----------------------
* Body ``i`` is attached to its parent (another body, or the fixed world when ``parent`` is None) by a joint.
  The joint frame sits at the fixed placement ``(rotation, translation)`` expressed in the parent's body frame;
  the body frame is the joint frame moved by the joint: ``X_body = X_parent * (rotation, translation) * motion(q_i)``
  with ``q_i`` the joint's block of coordinates and ``motion`` (article 2.1-2.2, 6.2):

  ===========  ===  ===  ======================================================================================
  joint        nq   nv   motion(q_i); velocity v_i
  ===========  ===  ===  ======================================================================================
  revolute     1    1    rotation by ``q_i`` about ``axis``; ``v_i = qd_i``
  prismatic    1    1    translation by ``q_i * axis``; ``v_i = qd_i``
  spherical    4    3    ``(R(quat), 0)``, ``q_i`` = quaternion ``(x, y, z, w)``; ``v_i`` = angular velocity of the
                         body relative to the joint frame, in the body frame (``R^T Rdot = [v_i]x``)
  free         7    6    ``(R(quat), p)``, ``q_i = (p, x, y, z, w)``; ``v_i = (R^T pdot, w)``: the body twist, linear
                         velocity of the body origin then angular velocity, both in the body frame
  ===========  ===  ===  ======================================================================================

  These are Pinocchio's conventions (``JointModelSpherical``, ``JointModelFreeFlyer``), so a state means the same
  to both tools. ``R(quat) = I + 2 w [x y z]x + 2 [x y z]x^2`` for a unit quaternion; a state's quaternions must be
  unit (``formalisms.interface.check_state``). The accelerations of a state are in velocity space: the time
  derivative of ``v`` (of the body twist for a free joint, not the second derivative of ``p``). ``axis`` is a unit
  vector in the joint frame for a revolute or prismatic joint, and the zero vector for a spherical or free joint
  (they have none). ``cases.configuration`` holds the group operations (neutral configuration, integration).
* ``com`` (centre of mass) and ``inertia`` (3x3 rotational inertia about the COM) are in the body frame.
  A point mass has ``inertia = 0``.
* The coordinates ``q`` (``nq`` of them) and the velocities ``v`` (``nv = n``, the degrees of freedom) are the
  bodies' joint blocks in the order the bodies are given: body ``i``'s are ``q[q_index[i] : q_index[i] + nq_i]``
  and ``v[v_index[i] : v_index[i] + nv_i]``. With revolute and prismatic joints only, ``nq = nv = n`` and body
  ``i`` owns coordinate ``i``. ``topological_order`` lists the bodies parents-first for the recursions.
* ``input_map`` is ``B`` of ``M vdot + h = B u`` (nv x m, docs/design.md conventions; default identity).
* Gravity is a vector in the world frame (m/s^2); the potential is ``V = -sum m_i gravity . p_com_i``.
* A body may be massless (mass 0, zero inertia): a carriage that only adds a joint, as in a free planar body built
  from two prismatic joints and a revolute one. Every joint must still move some mass.
* ``constraints`` are declarations from :mod:`cases.constraints`; ``Model.k`` counts their rows (``phi`` in R^k).
* ``loads`` are external load declarations from :mod:`cases.loads` (a force or a wrench on a body at a point, in the
  world or the body frame; a spring to a world point): the ``tau_ext`` of eq. (12), which every backend maps itself.
* ``source`` (optional, :class:`ModelSource`) records the file a loaded model was converted from and where the scene
  places that file's world, so that the external reference can read the file itself instead of our conversion of it.
  It is provenance, not physics: :meth:`Model.digest` leaves it out.
"""

from __future__ import annotations

import dataclasses
import functools
import hashlib
from dataclasses import dataclass, field
from typing import Iterable, Sequence

import numpy as np

from cases import constraints as constraint_decl
from cases import loads as load_decl
from cases.validation import as_array, finite, frozen, orthonormal_rows

#: Joint types with their numbers of coordinates and of velocities (nq, nv) (module docstring).
JOINT_DOF = {"revolute": (1, 1), "prismatic": (1, 1), "spherical": (4, 3), "free": (7, 6)}
JOINT_TYPES = tuple(JOINT_DOF)
#: The joints whose configuration is a Lie group (SO(3), SE(3)) and carries a unit quaternion.
GROUP_JOINTS = ("spherical", "free")
#: File formats a model can be loaded from (:attr:`ModelSource.kind`).
SOURCE_KINDS = ("urdf", "mjcf")
#: How a file's root is attached (:attr:`ModelSource.root`): welded to the world, or on a free joint added above it.
SOURCE_ROOTS = ("fixed", "free")


class ModelError(ValueError):
    """A model violates one or more preconditions; the message lists every violation, one per line."""

    def __init__(self, model_name: str, problems: Sequence[str]):
        self.problems = tuple(problems)
        lines = "\n".join(f"  - {p}" for p in self.problems)
        super().__init__(f"model '{model_name}' is invalid ({len(self.problems)} problem(s)):\n{lines}")


@dataclass(frozen=True)
class Body:
    """One rigid body and the joint that attaches it to its parent (see the module docstring for frames)."""

    name: str
    parent: str | None
    joint: str
    axis: np.ndarray
    mass: float
    com: np.ndarray = field(default_factory=lambda: np.zeros(3))
    inertia: np.ndarray = field(default_factory=lambda: np.zeros((3, 3)))
    rotation: np.ndarray = field(default_factory=lambda: np.eye(3))
    translation: np.ndarray = field(default_factory=lambda: np.zeros(3))
    #: ``(lower, upper)`` of a revolute (rad) or prismatic (m) joint's coordinate, as the source file declares them;
    #: None: unlimited. Not physics (left out of the digest): the sampler draws within them (``crosscheck.core.sampling``).
    limits: tuple[float, float] | None = None


@dataclass(frozen=True)
class TaskPoint:
    """A named point fixed in a body: ``offset`` is expressed in that body's frame.

    ``directions`` (k x 3, orthonormal rows, world frame) select the task coordinates ``x_task = D p`` of the
    point's world position ``p`` (article 6.3.2); the default is all three. A planar mechanism uses the rows of its
    plane (article 6.3.4: ``x_task = [x_2, y_2]``), since a direction the point can never move in makes the
    task-space inertia singular everywhere.

    ``choice`` says how the point was chosen, for reports: empty when declared with the model, else the default's
    rule or what was given (``cases.task``). It is provenance, not physics: :meth:`Model.digest` leaves it out.
    """

    name: str
    body: str
    offset: np.ndarray
    directions: np.ndarray | None = None
    choice: str = ""


@dataclass(frozen=True, eq=False)
class ModelSource:
    """Where a loaded model came from: the file (``kind`` one of :data:`SOURCE_KINDS`, ``path``: the URDF loader
    stores it absolute) and the rigid transform ``(rotation, translation)`` that places the file's world frame in
    the model's world (the identity for a model fresh from the loader; a moved scene composes it:
    ``crosscheck.checks.frames``). ``root`` says how the loader attached the file's root link: ``"fixed"`` as the file has
    it, or ``"free"``: on a free joint (``JointModelFreeFlyer``) the loader added above it.
    A point ``x`` of the file's world is at ``rotation @ x + translation`` in the model's world, and the file's
    gravity ``g`` is ``rotation @ g``; ``gravity`` False: the scene is the file's without gravity (a gravity-free
    copy, ``crosscheck.reports.diagnosis.without_gravity``), so whatever is built from the file sets gravity to zero."""

    kind: str
    path: str
    rotation: np.ndarray = field(default_factory=lambda: np.eye(3))
    translation: np.ndarray = field(default_factory=lambda: np.zeros(3))
    root: str = "fixed"
    gravity: bool = True

    def moved(self, rotation: np.ndarray, translation: np.ndarray) -> "ModelSource":
        """The source of the scene moved by ``g = (rotation, translation)``: placement ``g * (R, t)``."""
        R, t = np.asarray(rotation, dtype=float), np.asarray(translation, dtype=float)
        return ModelSource(self.kind, self.path, R @ self.rotation, R @ self.translation + t, self.root, self.gravity)

    def without_gravity(self) -> "ModelSource":
        """The same file and placement with gravity switched off."""
        return ModelSource(self.kind, self.path, self.rotation, self.translation, self.root, False)

    @property
    def is_identity(self) -> bool:
        """Whether the file's world is the model's world (a model as loaded, not moved)."""
        return bool(np.array_equal(self.rotation, np.eye(3)) and not np.any(self.translation))

    def key(self) -> str:
        """A stable text of every field (for caches of whatever is built from the file)."""
        placement = np.concatenate([np.ravel(self.rotation), np.ravel(self.translation)]).astype("<f8")
        weight = "" if self.gravity else ":no-gravity"
        return f"{self.kind}:{self.root}:{self.path}:{placement.tobytes().hex()}{weight}"

    def __eq__(self, other) -> bool:
        return isinstance(other, ModelSource) and self.key() == other.key()

    def __hash__(self) -> int:
        return hash(self.key())


@dataclass(frozen=True, eq=False)
class Model:
    """A validated, immutable multibody model. Build it with :func:`build_model`, never directly."""

    name: str
    bodies: tuple[Body, ...]
    gravity: np.ndarray
    input_map: np.ndarray
    task_points: tuple[TaskPoint, ...]
    constraints: tuple = ()
    parent_index: tuple[int, ...] = ()
    topological_order: tuple[int, ...] = ()
    source: ModelSource | None = None
    loads: tuple = ()

    @property
    def n(self) -> int:
        """Number of degrees of freedom: the size of v, of the accelerations and of M (``nv``)."""
        return self.nv

    @functools.cached_property
    def nv(self) -> int:
        """Number of velocity coordinates (module docstring: one per revolute or prismatic joint, 3 per spherical,
        6 per free joint)."""
        return sum(JOINT_DOF[b.joint][1] for b in self.bodies)

    @functools.cached_property
    def nq(self) -> int:
        """Number of configuration coordinates (4 per spherical and 7 per free joint: the quaternion)."""
        return sum(JOINT_DOF[b.joint][0] for b in self.bodies)

    @functools.cached_property
    def q_index(self) -> tuple[int, ...]:
        """Where each body's block of ``q`` starts."""
        return tuple(np.cumsum([0] + [JOINT_DOF[b.joint][0] for b in self.bodies[:-1]]).tolist())

    @functools.cached_property
    def v_index(self) -> tuple[int, ...]:
        """Where each body's block of ``v`` (and of the accelerations, and of M's rows) starts."""
        return tuple(np.cumsum([0] + [JOINT_DOF[b.joint][1] for b in self.bodies[:-1]]).tolist())

    @functools.cached_property
    def velocity_labels(self) -> tuple[str, ...]:
        """A name per velocity coordinate: the body's for a revolute or prismatic joint, ``body.wx``, ``body.wy``,
        ``body.wz`` for a spherical joint and ``body.vx`` ... ``body.wz`` for a free one (body-frame components)."""
        parts = {"spherical": ("wx", "wy", "wz"), "free": ("vx", "vy", "vz", "wx", "wy", "wz")}
        return tuple(label for b in self.bodies
                     for label in ([f"{b.name}.{p}" for p in parts[b.joint]] if b.joint in parts else [b.name]))

    @functools.cached_property
    def group_joints(self) -> tuple[int, ...]:
        """The bodies on a spherical or free joint (a configuration on a Lie group), in body order."""
        return tuple(i for i, b in enumerate(self.bodies) if b.joint in GROUP_JOINTS)

    @property
    def k(self) -> int:
        """Number of constraint rows (``phi(q)`` in R^k); 0 for an unconstrained model."""
        return sum(c.size for c in self.constraints)

    @functools.cached_property
    def pfaffian_rows(self) -> np.ndarray:
        """A read-only boolean mask over the k constraint rows: True for the rows of Pfaffian declarations
        (``A(q) qd = 0``, no ``phi``: ``cases.constraints.PFAFFIAN_TYPES``), False for holonomic ones."""
        mask = np.array([not c.holonomic for c in self.constraints for _ in range(c.size)], dtype=bool)
        mask.setflags(write=False)
        return mask

    @property
    def holonomic_rows(self) -> np.ndarray:
        """The complement of :attr:`pfaffian_rows`: the rows with a position-level ``phi(q) = 0``."""
        return ~self.pfaffian_rows

    @property
    def m(self) -> int:
        """Number of inputs (columns of the input map B)."""
        return self.input_map.shape[1]

    @functools.cached_property
    def length_scale(self) -> float:
        """A length for the model's residuals and floors: 1 m plus every placement and COM offset in it."""
        return 1.0 + float(sum(np.linalg.norm(b.translation) + np.linalg.norm(b.com) for b in self.bodies))

    @functools.cached_property
    def inertia_scale(self) -> float:
        """``sum_k (m_k L^2 + tr I_k)`` with L the length scale: the size of M's entries (about its largest
        eigenvalue, up to a factor of the number of joints)."""
        L = self.length_scale
        return float(sum(b.mass * L**2 + np.trace(b.inertia) for b in self.bodies))

    def body_index(self, name: str) -> int:
        for i, body in enumerate(self.bodies):
            if body.name == name:
                return i
        raise KeyError(f"model '{self.name}' has no body '{name}'; bodies: {[b.name for b in self.bodies]}")

    def task_point(self, name: str | None = None) -> TaskPoint:
        """The named task point, or the first (default) one."""
        if name is None:
            return self.task_points[0]
        for tp in self.task_points:
            if tp.name == name:
                return tp
        raise KeyError(f"model '{self.name}' has no task point '{name}'; "
                       f"task points: {[t.name for t in self.task_points]}")

    def digest(self) -> str:
        """A stable hash of everything that determines the physics and the task points (for caches keyed by
        model); the model's name and its ``source`` (provenance, not physics) are left out, so a renamed copy
        shares cache entries. Computed once per model."""
        return self._digest

    @functools.cached_property
    def _digest(self) -> str:
        h = hashlib.sha256()
        for b in self.bodies:
            h.update(repr((b.name, b.parent, b.joint)).encode())
            for arr in (b.axis, b.com, b.inertia, b.rotation, b.translation):
                h.update(np.ascontiguousarray(arr, dtype="<f8").tobytes())
            h.update(np.float64(b.mass).tobytes())
        for arr in (self.gravity, self.input_map):
            h.update(repr(arr.shape).encode())
            h.update(np.ascontiguousarray(arr, dtype="<f8").tobytes())
        for tp in self.task_points:
            h.update(repr((tp.name, tp.body)).encode())
            for arr in (tp.offset, tp.directions):
                h.update(repr(arr.shape).encode())
                h.update(np.ascontiguousarray(arr, dtype="<f8").tobytes())
        for c in self.constraints:
            h.update(constraint_decl.digest_bytes(c))
        for load in self.loads:       # nothing for a model without loads: its digest is what it was before loads
            h.update(b"load:" + load_decl.digest_bytes(load))
        return h.hexdigest()

    def __hash__(self) -> int:
        return hash(self.digest())

    def __eq__(self, other) -> bool:
        return isinstance(other, Model) and self.digest() == other.digest()


def _check_inertia(problems: list[str], where: str, inertia: np.ndarray) -> None:
    scale = max(np.abs(inertia).max(), 1e-300)
    tol = 1e-9 * scale
    if np.abs(inertia - inertia.T).max() > tol:
        problems.append(f"{where} inertia about its COM is not symmetric: {inertia.tolist()}")
        return
    eig = np.linalg.eigvalsh(inertia)
    if eig[0] < -tol:
        problems.append(f"{where} inertia about its COM is not positive semi-definite: eigenvalues {eig.tolist()} "
                        "(a point mass uses the zero matrix)")
        return
    a, b, c = eig
    if c > a + b + tol:
        problems.append(f"{where} inertia about its COM violates the triangle inequality: principal moments "
                        f"{eig.tolist()}, the largest exceeds the sum of the other two")


def _validate_body(problems: list[str], body: Body) -> Body | None:
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
    if inertia is not None:
        _check_inertia(problems, where, inertia)
        if mass == 0.0 and np.abs(inertia).max() > 0.0:
            problems.append(f"{where} has zero mass but a non-zero inertia {inertia.tolist()}; a massless body "
                            "(a carriage) has zero inertia")
    rotation = as_array(problems, f"{where} joint placement rotation", body.rotation, (3, 3))
    if rotation is not None:
        err = np.abs(rotation.T @ rotation - np.eye(3)).max()
        if err > 1e-9 or np.linalg.det(rotation) < 0:
            problems.append(f"{where} joint placement rotation is not a proper rotation "
                            f"(|R^T R - I| = {err:.2e}, det = {np.linalg.det(rotation):.6f})")
    translation = as_array(problems, f"{where} joint placement translation", body.translation, (3,))
    limits = _limits(problems, where, body)
    if len(problems) > n_before:
        return None
    return Body(name=body.name, parent=body.parent, joint=body.joint, axis=frozen(axis, 3), mass=mass,
                com=frozen(com, 3), inertia=frozen(0.5 * (inertia + inertia.T), (3, 3)),
                rotation=frozen(rotation, (3, 3)), translation=frozen(translation, 3), limits=limits)


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
    """Every joint must move some mass, or its row of M is zero (a massless carriage at the tip)."""
    subtree = [b.mass for b in bodies]
    for i in sorted(range(len(bodies)), key=lambda j: -_depth(parent, j)):
        if parent[i] >= 0:
            subtree[parent[i]] += subtree[i]
    for b, carried in zip(bodies, subtree):
        if carried == 0.0:
            problems.append(f"joint of body '{b.name}' moves no mass (the body and all its descendants are "
                            "massless), so the mass matrix is singular; give the body or a descendant a mass")


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
    if len(problems) > n_before:
        return None
    return ModelSource(source.kind, source.path, frozen(rotation, (3, 3)), frozen(translation, 3), source.root,
                       source.gravity)


def build_model(name: str, bodies: Iterable[Body], gravity=(0.0, 0.0, -9.81), input_map=None,
                task_points: Iterable[TaskPoint] | None = None, constraints: Iterable = (),
                source: ModelSource | None = None, loads: Iterable = ()) -> Model:
    """Validate the description and return an immutable :class:`Model`.

    Every violated precondition is collected and reported together in one :class:`ModelError`.
    Default input map: identity (fully actuated). Default task point ``tip``: the COM of the last body, or, when that
    lies on a joint axis, an offset point of it, with the task directions it moves in (``cases.task.choose``: a planar
    chain's plane), so that its task Jacobian has full row rank away from singular configurations.
    ``source``: the file the description was converted from (:class:`ModelSource`; loaders set it).
    ``loads``: external load declarations (:mod:`cases.loads`), validated like the constraints.
    """
    bodies = list(bodies)
    problems: list[str] = []
    if not bodies:
        problems.append("a model needs at least one body")
    valid = [_validate_body(problems, b) for b in bodies]
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
                  source=source, loads=loads)
    if default:
        from cases.task import default_task_point  # cases.task builds on this module

        tp = _validate_task_point(problems, default_task_point(model), names)
        model = dataclasses.replace(model, task_points=(tp,))
    return model
