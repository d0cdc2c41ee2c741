"""What every simulator adapter shares: the defaults it turns off, the scene it builds, and its terms in our coordinates.

An adapter (:class:`Adapter`) is a plugin backend (``needs = "source"``, docs/plugins.md) that gives the model file
to a simulator or dynamics library as its users give it, reads that library's own ``M``, bias forces ``h = C qd +
g`` and gravity forces ``g`` (and its own forward dynamics where it has them), and brings them into crosscheck's
coordinates. Everything the library adds to rigid-body dynamics by default (damping, armature, friction, limits,
contacts, gravity compensation, made-up inertias) is turned off and listed in :attr:`Adapter.DEFAULTS`; naming a
default (``Adapter.with_defaults``, the command line's ``--simulator NAME:DEFAULT,...``) leaves it on, as the
library's users get it, and the adapter is then named ``NAME_with_DEFAULT``.

Coordinates. A library orders its velocities its own way and may represent a free base's velocity in other frames:
its velocity is ``v_L = T v`` with ``v`` ours (the scene's order; a free joint's body twist, ``cases.model``) and
``T`` (:func:`velocity_map`) a permutation with one 6x6 block per free joint. Its accelerations are ``a_L = T a +
c`` with ``c = Tdot v``. By the power ``tau_L . v_L = tau . v`` its equation ``M_L a_L + h_L = tau_L`` is ours with
(:func:`in_ours`)

    M = T^T M_L T,   h = T^T (h_L + M_L c),   g = T^T g_L,   tau_L = T^-T tau.
"""

from __future__ import annotations

import functools
import os
import tempfile
import threading
import xml.etree.ElementTree as ET
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from cases.configuration import rotation
from crosscheck.assemble import Sizes, unconstrained_split
from formalisms.interface import UNSUPPORTED, ModelNotSupported, Split

#: The file's gravity when the file does not say (a URDF never does): what every library here and Pinocchio assume.
STANDARD_GRAVITY = np.array([0.0, 0.0, -9.81])


@dataclass(frozen=True)
class FreeVelocity:
    """How a library represents a free joint's velocity: each of the linear velocity of the joint's origin and the
    angular velocity in the ``"world"`` or the ``"body"`` frame, angular first or linear first."""

    linear: str
    angular: str
    angular_first: bool


#: crosscheck's (and Pinocchio's) free-joint velocity: the body twist, linear then angular, in the body frame.
BODY_TWIST = FreeVelocity("body", "body", False)


def free_pose(scene, q: np.ndarray, body: int) -> tuple[np.ndarray, np.ndarray]:
    """The world pose ``(R, p)`` of free body ``body``: the scene's placement of the file's world composed with the
    joint's ``(p, quat)`` (a free base's joint frame is the file's world frame)."""
    iq = scene.q_index[body]
    R0, t0 = np.asarray(scene.rotation, dtype=float), np.asarray(scene.translation, dtype=float)
    return R0 @ rotation(q[iq + 3:iq + 7]), R0 @ q[iq:iq + 3] + t0


def _free_block(R: np.ndarray, v_b: np.ndarray, w_b: np.ndarray, rep: FreeVelocity):
    """``T`` (6x6, our body twist into ``rep``) and ``c = Tdot v`` of one free joint at world rotation ``R``: a
    world-frame linear velocity ``R v_b`` has ``d/dt = R (w_b x v_b + vdot_b)``, a world angular one ``R w_b`` has
    ``R wdot_b`` (``w_b x w_b = 0``); body-frame ones are ours."""
    lin_T = R if rep.linear == "world" else np.eye(3)
    ang_T = R if rep.angular == "world" else np.eye(3)
    lin_c = R @ np.cross(w_b, v_b) if rep.linear == "world" else np.zeros(3)
    T, c = np.zeros((6, 6)), np.zeros(6)
    lin, ang = (slice(3, 6), slice(0, 3)) if rep.angular_first else (slice(0, 3), slice(3, 6))
    T[lin, 0:3], T[ang, 3:6], c[lin] = lin_T, ang_T, lin_c
    return T, c


def velocity_map(scene, q, qd, dofs: list[int], free: FreeVelocity = BODY_TWIST, rotations=None):
    """``T`` (library velocities from ours, ``v_L = T v``) and ``c = Tdot v`` (module docstring). ``dofs[i]`` is the
    library's first velocity index of body ``i``'s joint; revolute and prismatic joints have one velocity there,
    free joints six (``free``: the library's representation), spherical joints three (an angular velocity in the
    body frame, as ours). ``rotations[i]``, when given, is free body ``i``'s world rotation (else
    :func:`free_pose`'s)."""
    q, qd = np.asarray(q, dtype=float), np.asarray(qd, dtype=float)
    T, c = np.zeros((scene.nv, scene.nv)), np.zeros(scene.nv)
    for i, joint in enumerate(scene.joints):
        iv, d = scene.v_index[i], dofs[i]
        if joint == "free":
            R = free_pose(scene, q, i)[0] if rotations is None else rotations[i]
            block, cb = _free_block(R, qd[iv:iv + 3], qd[iv + 3:iv + 6], free)
            T[d:d + 6, iv:iv + 6], c[d:d + 6] = block, cb
        else:
            size = 3 if joint == "spherical" else 1
            T[d:d + size, iv:iv + size] = np.eye(size)
    return T, c


def in_ours(T: np.ndarray, c: np.ndarray, M_L, h_L, g_L):
    """``(M, h, g)`` in our coordinates from the library's (module docstring)."""
    M_L, h_L, g_L = (np.asarray(x, dtype=float) for x in (M_L, h_L, g_L))
    return T.T @ M_L @ T, T.T @ (h_L + M_L @ c), T.T @ g_L


def accel_in_ours(T: np.ndarray, c: np.ndarray, a_L) -> np.ndarray:
    """Our acceleration of the library's ``a_L = T a + c`` (a solve ``M_L^-1 tau_L`` with ``c = 0``)."""
    return np.linalg.solve(T, np.asarray(a_L, dtype=float) - c)


def file_gravity(scene) -> np.ndarray:
    """The file's gravity vector: MJCF's ``<option gravity>`` (default ``0 0 -9.81``); a URDF's is standard."""
    if scene.kind == "mjcf":
        for option in ET.parse(scene.path).getroot().iter("option"):
            if option.get("gravity") is not None:
                return np.array([float(x) for x in option.get("gravity").split()])
    return STANDARD_GRAVITY.copy()


def scene_gravity(scene) -> np.ndarray:
    """Gravity in the scene's world: the file's turned by the scene's rotation, or zero on a gravity-free copy."""
    return np.asarray(scene.rotation, dtype=float) @ file_gravity(scene) if scene.gravity else np.zeros(3)


def _keep_prefixes(path: str) -> None:
    """Have ElementTree write the file's namespace prefixes as the file declares them (``xmlns:drake``), not as
    ``ns0``, ``ns1``: a reader that matches prefixed tags (Drake's ``<drake:rotor_inertia>``) would miss them."""
    for _, (prefix, uri) in ET.iterparse(path, events=("start-ns",)):
        try:
            ET.register_namespace(prefix, uri)
        except ValueError:            # a prefix ElementTree reserves (ns0, ...): written as ElementTree names it
            pass


def urdf_without_geometry(path: str) -> str:
    """The URDF's text with every ``<visual>`` and ``<collision>`` removed: their meshes need not be found, and with
    the inertias given in ``<inertial>`` they add nothing to the dynamics. Namespace prefixes are kept."""
    _keep_prefixes(path)
    robot = ET.parse(path).getroot()
    for link in robot.iter("link"):
        for tag in ("visual", "collision"):
            for element in link.findall(tag):
                link.remove(element)
    return ET.tostring(robot, encoding="unicode")


def file_version(path: str) -> tuple[int, int]:
    """What tells a file rewritten in place from its earlier text: its modification time and size."""
    stat = os.stat(path)
    return stat.st_mtime_ns, stat.st_size


def urdf_file_without_geometry(path: str) -> str:
    """:func:`urdf_without_geometry` written to a file of its own (for a library that reads a path only), beside no
    mesh: one per version of the file and process."""
    return _written_without_geometry(path, file_version(path))


@functools.lru_cache(maxsize=64)
def _written_without_geometry(path: str, version: tuple[int, int]) -> str:
    folder = Path(tempfile.mkdtemp(prefix="crosscheck-adapter-"))
    out = folder / Path(path).name
    out.write_text(urdf_without_geometry(path))
    return str(out)


def scene_key(scene) -> tuple:
    """What tells one scene of a file from another (the library model is built once per key); the file's version
    too, so a file rewritten in place is read again."""
    return (scene.kind, scene.path, file_version(scene.path), scene.root, scene.gravity,
            np.asarray(scene.rotation, dtype=float).tobytes(), np.asarray(scene.translation, dtype=float).tobytes(),
            scene.joint_names)


@dataclass(frozen=True)
class Terms:
    """A library's answer at one state, in our coordinates: ``M``, ``h = C qd + g``, ``g``, the total mass its model
    has, and where the library has them its own solves (``drift``, ``ctrl``, ``total``) and kinetic energy."""

    M: np.ndarray
    h: np.ndarray
    g: np.ndarray
    mass: float
    drift: np.ndarray | None = None
    ctrl: np.ndarray | None = None
    total: np.ndarray | None = None
    kinetic_energy: float | None = None


class Adapter:
    """A simulator or dynamics library as a backend (module docstring). A subclass sets :attr:`simulator`,
    :attr:`DEFAULTS` and :attr:`KINDS`, builds its model of a scene (:meth:`build`) and evaluates it
    (:meth:`terms`)."""

    needs = "source"
    #: The registry's name (``crosscheck.adapters.SIMULATORS``).
    simulator = ""
    #: Each model-changing default of the library -> what it adds when left on. All are off unless named.
    DEFAULTS: dict[str, str] = {}
    #: The file formats the library reads.
    KINDS: tuple[str, ...] = ("urdf",)
    #: Whether the adapter gives the library the armature (rotor inertia) the user declared for a URDF's joints
    #: (``SourceScene.armature``); one that cannot is NOT COMPARED on such a scene.
    ARMATURE = False

    def __init__(self, on=()):
        on = tuple(on)
        unknown = sorted(set(on) - set(self.DEFAULTS))
        if unknown:
            raise ValueError(f"{self.simulator} has no default {', '.join(map(repr, unknown))}; its defaults: "
                             f"{', '.join(self.DEFAULTS) or 'none'}")
        self.on = frozenset(on)
        self.name = self.simulator + ("_with_" + "_".join(sorted(self.on)) if self.on else "")
        left = "; LEFT ON: " + ", ".join(sorted(self.on)) if self.on else "; every model-changing default off"
        self.summary = f"{self.library()} reading the file itself{left}"
        self._built: dict[tuple, object] = {}
        self._lock = threading.Lock()

    def with_defaults(self, *names: str) -> "Adapter":
        """The same adapter with the named defaults left on (the library as its users get it)."""
        return type(self)(names)

    @staticmethod
    def library() -> str:
        """The library and its version."""
        raise NotImplementedError

    def in_file(self, scene) -> dict[str, str]:
        """Which of :attr:`DEFAULTS` the file itself sets (default -> where, e.g. "damping on 3 joints"): those that
        had to be off for this model. Empty when the adapter cannot tell."""
        return {}

    def build(self, scene):
        """The library's model of ``scene`` (any object :meth:`terms` reads); ModelNotSupported for what the library
        cannot hold."""
        raise NotImplementedError

    def terms(self, built, scene, q: np.ndarray, qd: np.ndarray, tau: np.ndarray) -> Terms:
        """The library's :class:`Terms` at ``(q, qd)`` with the applied force ``tau = B u`` (ours)."""
        raise NotImplementedError

    def built(self, scene):
        key = scene_key(scene)
        with self._lock:
            if key not in self._built:
                self._built[key] = self.build(scene)
            return self._built[key]

    def unsupported(self, scene) -> str:
        """Why the library cannot be compared on ``scene`` (NOT COMPARED), or "": a file format it does not read,
        constraint rows, armature it is not given. An adapter adds its own reasons before these."""
        if scene.kind not in self.KINDS:
            return (f"{self.library()} does not read {scene.kind.upper()} files here (it reads "
                    f"{', '.join(k.upper() for k in self.KINDS)})")
        if scene.constraints:
            return (f"model '{scene.name}' has constraint rows ({', '.join(c.name for c in scene.constraints)}); "
                    f"{self.simulator} is compared on unconstrained models only")
        if scene.armature and not self.ARMATURE:
            return (f"{self.library()} is not given the armature (rotor inertia) declared for "
                    f"{', '.join(name for name, _ in scene.armature)} here: it has no such term")
        return ""

    def split(self, scene, q, qd, u) -> Split:
        """drift ``-M^-1 h``, ctrl ``M^-1 B u``, total: the library's own solves where it has them, else of its own
        ``M`` and ``h`` (eq. 9); NOT COMPARED on what it cannot read."""
        why = self.unsupported(scene)
        if why:
            raise ModelNotSupported(why)
        q, qd, u = (np.asarray(x, dtype=float) for x in (q, qd, u))
        tau = np.asarray(scene.input_map, dtype=float) @ u
        t = self.terms(self.built(scene), scene, q, qd, tau)
        drift = t.drift if t.drift is not None else np.linalg.solve(t.M, -t.h)
        ctrl = t.ctrl if t.ctrl is not None else np.linalg.solve(t.M, tau)
        total = t.total if t.total is not None else np.linalg.solve(t.M, tau - t.h)
        return unconstrained_split(Sizes(t.mass, scene_gravity(scene)), M=t.M, Cqd=t.h - t.g, g=t.g, tau_ctrl=tau,
                                   qd=qd, drift=drift, ctrl=ctrl, total=total,
                                   kinetic_energy=UNSUPPORTED if t.kinetic_energy is None else t.kinetic_energy)
