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
* ``armature`` (rotor inertia, >= 0) is added to each of the joint's velocity entries on M's diagonal:
  ``M(q) = M_bodies(q) + diag(Model.armature_vector)``, ``T = 1/2 v^T M v`` (docs/concepts.md, "Armature"). It is
  no body: it moves with the joint velocity alone, so C and g are those of the bodies.
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

import functools
import hashlib
from dataclasses import dataclass, field
from typing import Sequence

import numpy as np

from cases import constraints as constraint_decl, loads as load_decl


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
    """A model violates one or more preconditions; the message lists every violation, one per line, after the file
    the model came from (``source``, e.g. "URDF file 'robot.urdf'"), which is no problem of its own."""

    def __init__(self, model_name: str, problems: Sequence[str], source: str = ""):
        self.problems, self.source = tuple(problems), source
        lines = "\n".join(f"  - {p}" for p in self.problems)
        origin = f" from {source}" if source else ""
        super().__init__(f"model '{model_name}'{origin} is invalid ({len(self.problems)} problem(s)):\n{lines}")


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
    #: None: unlimited. Not physics (left out of the digest): the sampler draws within them
    #: (``crosscheck.core.sampling``).
    limits: tuple[float, float] | None = None
    #: Armature (rotor inertia reflected through the joint's gearing; kg m^2 for a revolute joint, kg for a prismatic
    #: one), added to each of the joint's diagonal entries of M (each of a spherical joint's 3: MuJoCo's ``<joint
    #: armature>``, Pinocchio's ``model.armature``): ``M(q) = M_bodies(q) + diag(a)``, and the kinetic energy gains
    #: ``1/2 a |v_i|^2``. Physics (in the digest); finite and >= 0, and 0 on a free joint (``cases.build``: there
    #: MuJoCo's and Pinocchio's definition is no rotor's kinetic energy).
    armature: float = 0.0


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
    ``crosscheck.checks.frames``). ``root`` says how the loader attached the file's root link: ``"fixed"`` as the file
    has it, or ``"free"``: on a free joint (``JointModelFreeFlyer``) the loader added above it.
    A point ``x`` of the file's world is at ``rotation @ x + translation`` in the model's world, and the file's
    gravity ``g`` is ``rotation @ g``; ``gravity`` False: the scene is the file's without gravity (a gravity-free
    copy, ``crosscheck.reports.diagnosis.without_gravity``), so whatever is built from the file sets gravity to zero.
    ``armature``: ``(joint name, value)`` pairs the user declared when loading (``cases.from_urdf(...,
    armature={...})``, the command line's ``--armature``), which the file does not say (a URDF has no armature tag):
    whatever is built from the file sets each named joint's armature to its value after reading the file (an MJCF
    file's own ``<joint armature>`` is read from the file itself)."""

    kind: str
    path: str
    rotation: np.ndarray = field(default_factory=lambda: np.eye(3))
    translation: np.ndarray = field(default_factory=lambda: np.zeros(3))
    root: str = "fixed"
    gravity: bool = True
    armature: tuple[tuple[str, float], ...] = ()

    def moved(self, rotation: np.ndarray, translation: np.ndarray) -> "ModelSource":
        """The source of the scene moved by ``g = (rotation, translation)``: placement ``g * (R, t)``."""
        R, t = np.asarray(rotation, dtype=float), np.asarray(translation, dtype=float)
        return ModelSource(self.kind, self.path, R @ self.rotation, R @ self.translation + t, self.root, self.gravity,
                           self.armature)

    def without_gravity(self) -> "ModelSource":
        """The same file and placement with gravity switched off."""
        return ModelSource(self.kind, self.path, self.rotation, self.translation, self.root, False, self.armature)

    @property
    def is_identity(self) -> bool:
        """Whether the file's world is the model's world (a model as loaded, not moved)."""
        return bool(np.array_equal(self.rotation, np.eye(3)) and not np.any(self.translation))

    def key(self) -> str:
        """A stable text of every field (for caches of whatever is built from the file)."""
        placement = np.concatenate([np.ravel(self.rotation), np.ravel(self.translation)]).astype("<f8")
        weight = "" if self.gravity else ":no-gravity"
        declared = "".join(f":armature:{name}={np.float64(value).tobytes().hex()}" for name, value in self.armature)
        return f"{self.kind}:{self.root}:{self.path}:{placement.tobytes().hex()}{weight}{declared}"

    def __eq__(self, other) -> bool:
        return isinstance(other, ModelSource) and self.key() == other.key()

    def __hash__(self) -> int:
        return hash(self.key())


@dataclass(frozen=True, eq=False)
class Model:
    """A validated, immutable multibody model. Build it with :func:`cases.build.build_model`, never directly."""

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
    #: What is physically impossible in the data but still gives a positive-definite M (an inertia that violates the
    #: triangle inequality beyond rounding, a massless body with a rotational inertia): reported
    #: at the top of a gate report, the backends still compared (``--strict-model`` refuses such a model). Derived
    #: from the bodies by :func:`cases.build.build_model`, so left out of the digest.
    findings: tuple[str, ...] = ()

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
    def armature_vector(self) -> np.ndarray:
        """The armature per velocity coordinate (nv, read-only): each body's ``armature`` repeated over its joint's
        velocities (module docstring), so ``M = M_bodies + diag(armature_vector)``."""
        a = np.array([b.armature for b in self.bodies for _ in range(JOINT_DOF[b.joint][1])], dtype=float)
        a.setflags(write=False)
        return a

    @property
    def has_armature(self) -> bool:
        """Whether any joint has a non-zero armature."""
        return any(b.armature != 0.0 for b in self.bodies)

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
        """``sum_k (m_k L^2 + tr I_k)`` with L the length scale, plus the armature of every velocity: the size of M's
        entries (about its largest eigenvalue, up to a factor of the number of joints)."""
        L = self.length_scale
        return float(sum(b.mass * L**2 + np.trace(b.inertia) for b in self.bodies) + self.armature_vector.sum())

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
            if b.armature:            # nothing without armature: such a model's digest is what it was before it
                h.update(b"armature:" + np.float64(b.armature).tobytes())
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
