"""pybullet as a backend: ``loadURDF`` reads the URDF file itself; ``calculateMassMatrix`` and
``calculateInverseDynamics`` evaluate it (pybullet has no forward dynamics of a multibody without stepping: the
drift and the total are solves of its own ``M`` and ``h``).

    crosscheck gate --simulator pybullet --model robot.urdf         # or --plugin crosscheck.adapters.pybullet

Conventions (docs/simulators.md has the matrix of every adapter):

* quaternion ``(x, y, z, w)``, as ours. One ``p.connect(p.DIRECT)`` client per adapter and process; the scene's
  placement is the base's ``basePosition``/``baseOrientation`` and gravity (``setGravity``) is the scene's, set
  before every call (pybullet's default gravity is zero);
* a multibody's base frame is the root link's **inertial** frame (its ``<inertial><origin>`` turned onto the
  principal axes), not the link frame. On a free base (``useFixedBase=False``), ``calculateInverseDynamics`` takes
  the base pose as ``objPositions[:7] = (position, quaternion)`` of that frame and ``calculateMassMatrix`` the joint
  positions only. Its base velocity is six numbers, **angular then linear**, both in the inertial frame, the linear
  one the velocity of the centre of mass; the base acceleration it takes is that frame's angular acceleration and the
  **classical** acceleration of the centre of mass (the tree's ``m_body_acc``), not the time derivative of that
  velocity, so ``a_L = T a + c`` with ``c`` the ``w x v + w x (w x r)`` terms (:func:`_free_block`). The base's
  generalized force is a moment then a force in ``calculateMassMatrix``'s rows; ``calculateInverseDynamics``
  returns it **force then moment** (pybullet swaps its output, not its inputs,
  ``PhysicsServerCommandProcessor::processInverseDynamicsCommand``), which is put back here;
* joints are found by name (``getJointInfo``: the movable ones, in the multibody's link order, ``uIndex``), the
  type checked; fixed links stay links of the multibody (``URDF_MERGE_FIXED_LINKS`` is not a default);
* inertias: pybullet diagonalizes each link's inertia tensor (``btMatrix3x3::diagonalize``, threshold 1e-6, 30
  sweeps) and turns the inertial frame onto the principal axes; a link without ``<inertial>`` gets **1 kg and unit
  inertia** (``UrdfParser``: "No inertial data for link, using mass=1", the parser's own, no flag turns it off; a
  link named ``world`` gets none); a tensor outside the triangle inequality is set to zero. These are pybullet's
  reading of the file, not defaults: the gate compares them.

Off unless named (:attr:`PyBullet.DEFAULTS`): ``inertia_from_collision`` (without the flag
``URDF_USE_INERTIA_FROM_FILE`` pybullet replaces each link's inertia tensor by a solid box's, the box bounding
its collision shapes (``btCompoundShape::calculateLocalInertia``), keeping the file's mass and centre of mass; the
adapter passes the flag and reads the file without ``<visual>`` and
``<collision>``; with the default named it reads the file itself, meshes found by pybullet's own search from the
file's folder, and a file it cannot load is NOT COMPARED). Not defaults, since they do not enter
``calculateMassMatrix`` or ``calculateInverseDynamics`` (the tree ``btInverseDynamics::MultiBodyTree`` has no such
terms; checked: a ``changeDynamics`` of them leaves both unchanged): joint damping and friction (URDF
``<dynamics>``, ``jointDamping``), the bodies' linear and angular damping (0.04), the default velocity motors,
joint limits and contacts, which act in ``stepSimulation`` only. ``flags=1`` of ``calculateInverseDynamics`` (the
stable-PD plugin's separate model) is not what users get by default and is not used.

NOT COMPARED (ModelNotSupported): an MJCF file (``loadMJCF`` reads a subset of MJCF: no ``euler``, ``xyaxes`` or
``zaxis`` frames, no ``fullinertia``, no ``armature``, no ``<option gravity>``: the model it builds is not the
file's), a model with constraint rows (a URDF ``<mimic>``: pybullet's inverse dynamics ignores it) and a spherical
joint (pybullet's ``calculateInverseDynamics`` does not handle them, bullet3 PR #1381).

What the gate finds (pybullet 3.2.7, the library as its users run it):

* a free base at a general tilt: ``processInverseDynamicsCommand`` turns the base quaternion into Z-Y-X Euler
  angles (``getEulerZYX``) and the tree applies them as X-Y-Z (``MultiBodyTreeImpl``, FLOATING joint: ``R =
  Rx(roll) Ry(pitch) Rz(yaw)``): gravity acts in a wrong base frame (exact about z alone, wrong by up to 2x at a
  general tilt), ``M`` and the velocity terms agree::

      crosscheck gate --simulator pybullet --model solo12.urdf --base free --samples 20

* a fixed base turned relative to gravity: ``btMultiBodyTreeCreator`` puts the base at the identity ("compute
  inverse dynamics in body-fixed frame") while gravity is set in the world frame, so gravity acts as if the base's
  inertial frame were the world's (bullet3 issue #2876, a wall-mounted arm): caught by the frame checks (the moved
  scenes) on every fixed base, ``M`` and the velocity terms agreeing, and on an unmoved scene whose root link has a
  turned ``<inertial>``::

      crosscheck gate --simulator pybullet --model ur5_robot.urdf --samples 20      # PASS with --frames 0

* a link without ``<inertial>`` weighs 1 kg with unit inertia (examples/arm.urdf's massless tool frame)::

      crosscheck gate --simulator pybullet --model examples/arm.urdf --samples 20

* the diagonalized inertias move ``M`` by about 1e-11 relative (z1; each link's tensor by up to 7e-10), at the
  tolerance: ``ctrl`` 1.67 times it at some states of z1, some ten times on a small chain of general tensors.
"""

from __future__ import annotations

import os
from dataclasses import dataclass

import numpy as np
import pybullet

from cases.configuration import hat
from crosscheck.adapters.base import (Adapter, Terms, free_pose, in_ours, scene_gravity,
                                      urdf_file_without_geometry, velocity_map)
from formalisms.interface import ModelNotSupported

#: crosscheck's joint types (``scene.joints``) -> pybullet's (``getJointInfo``).
_JOINT_TYPES = {"revolute": pybullet.JOINT_REVOLUTE, "prismatic": pybullet.JOINT_PRISMATIC}
_TYPE_NAMES = {pybullet.JOINT_REVOLUTE: "revolute", pybullet.JOINT_PRISMATIC: "prismatic",
               pybullet.JOINT_SPHERICAL: "spherical", pybullet.JOINT_PLANAR: "planar", pybullet.JOINT_FIXED: "fixed"}


def _quaternion(R: np.ndarray) -> np.ndarray:
    """The unit quaternion ``(x, y, z, w)`` of a rotation matrix (Shepperd's method)."""
    R = np.asarray(R, dtype=float)
    t = np.trace(R)
    if t > 0:
        s = 2.0 * np.sqrt(1.0 + t)
        quat = [(R[2, 1] - R[1, 2]) / s, (R[0, 2] - R[2, 0]) / s, (R[1, 0] - R[0, 1]) / s, 0.25 * s]
    else:
        i = int(np.argmax(np.diag(R)))
        j, k = (i + 1) % 3, (i + 2) % 3
        s = 2.0 * np.sqrt(1.0 + R[i, i] - R[j, j] - R[k, k])
        quat = [0.0] * 4
        quat[i], quat[j], quat[k] = 0.25 * s, (R[j, i] + R[i, j]) / s, (R[k, i] + R[i, k]) / s
        quat[3] = (R[k, j] - R[j, k]) / s
    quat = np.array(quat)
    return quat / np.linalg.norm(quat)


def _matrix(quat) -> np.ndarray:
    """The rotation matrix of pybullet's quaternion ``(x, y, z, w)``."""
    return np.array(pybullet.getMatrixFromQuaternion(list(quat)), dtype=float).reshape(3, 3)


def _free_block(R_c: np.ndarray, r: np.ndarray, v_b: np.ndarray, w_b: np.ndarray):
    """pybullet's base velocity from our body twist ``(v_b, w_b)`` at the root link's origin: ``T`` (6x6) and ``c``
    (module docstring). The inertial frame sits at ``r`` turned by ``R_c`` in the link frame; pybullet's velocity is
    ``(R_c^T w, R_c^T (v + w x r))`` (angular first, the centre of mass's velocity) and its linear acceleration the
    centre of mass's classical one, ``R_c^T (vdot + wdot x r + w x v + w x (w x r))``."""
    T = np.zeros((6, 6))
    T[0:3, 3:6] = R_c.T
    T[3:6, 0:3] = R_c.T
    T[3:6, 3:6] = -R_c.T @ hat(r)
    c = np.zeros(6)
    c[3:6] = R_c.T @ (np.cross(w_b, v_b) + np.cross(w_b, np.cross(w_b, r)))
    return T, c


@dataclass(frozen=True)
class _Loaded:
    """One scene's multibody in the adapter's client and where each of crosscheck's bodies sits in it."""

    body: int                   # pybullet's body unique id
    dof: tuple[int, ...]        # pybullet's first velocity index of each body's joint (the base's six first)
    n_joints: int               # pybullet's movable joints
    free: bool                  # a free base
    inertial: tuple             # (r, R_c): the base's inertial frame in its link frame
    mass: float                 # the mass the joints move


class PyBullet(Adapter):
    """The pybullet adapter (module docstring)."""

    simulator = "pybullet"
    KINDS = ("urdf",)
    DEFAULTS = {
        "inertia_from_collision": "each link's inertia tensor a solid box's, the box bounding its collision shapes, "
                                  "instead of the file's <inertial> (loadURDF without URDF_USE_INERTIA_FROM_FILE)",
    }

    def __init__(self, on=()):
        super().__init__(on)
        self._client: int | None = None
        self._pid: int | None = None

    @staticmethod
    def library() -> str:
        from importlib.metadata import version

        return f"pybullet {version('pybullet')}"

    def unsupported(self, scene) -> str:
        if scene.kind == "mjcf":
            return (f"{self.library()} reads URDF files here: its loadMJCF reads a subset of MJCF (no euler, xyaxes or "
                    "zaxis frames, no fullinertia, no armature, no <option gravity>), so the model it builds is not "
                    f"the file's '{scene.path}'")
        return super().unsupported(scene)

    def _connected(self) -> int:
        """This process's DIRECT client."""
        if self._client is None:
            self._client, self._pid = pybullet.connect(pybullet.DIRECT), os.getpid()
        return self._client

    def built(self, scene) -> "_Loaded":
        """The scene's multibody in this process's client: a forked copy connects anew and loads its own (a client
        and its bodies are not shared across processes)."""
        with self._lock:
            if self._pid is not None and self._pid != os.getpid():
                self._client, self._pid, self._built = None, None, {}
        return super().built(scene)

    def build(self, scene) -> _Loaded:
        """The scene's multibody: the file read by ``loadURDF`` at the scene's placement, the base fixed or free as
        the scene's; crosscheck's joints found by name, their types checked."""
        if "spherical" in scene.joints:
            raise ModelNotSupported(f"'{scene.path}' has a spherical joint: pybullet's calculateInverseDynamics "
                                    "does not handle spherical joints")
        cid = self._connected()
        flags = 0 if "inertia_from_collision" in self.on else pybullet.URDF_USE_INERTIA_FROM_FILE
        path = scene.path if "inertia_from_collision" in self.on else urdf_file_without_geometry(scene.path)
        free = scene.root == "free"
        R, t = np.asarray(scene.rotation, dtype=float), np.asarray(scene.translation, dtype=float)
        try:
            body = pybullet.loadURDF(path, basePosition=list(t), baseOrientation=list(_quaternion(R)),
                                     useFixedBase=not free, flags=flags, physicsClientId=cid)
        except pybullet.error as exc:
            raise ModelNotSupported(f"pybullet cannot load '{scene.path}': {exc}") from None
        infos = [pybullet.getJointInfo(body, j, physicsClientId=cid)
                 for j in range(pybullet.getNumJoints(body, physicsClientId=cid))]
        movable = sorted((i for i in infos if i[3] >= 0), key=lambda i: i[4])
        by_name = {i[1].decode(): k for k, i in enumerate(movable)}
        base = 6 if free else 0
        dof = []
        for body_name, joint, name in zip(scene.bodies, scene.joints, scene.joint_names):
            if joint == "free":
                dof.append(0)
                continue
            if name not in by_name:
                raise ModelNotSupported(f"pybullet's model of '{scene.path}' has no movable joint '{name}'")
            info = movable[by_name[name]]
            if info[2] != _JOINT_TYPES[joint]:
                raise ModelNotSupported(f"pybullet reads joint '{name}' of '{scene.path}' as "
                                        f"{_TYPE_NAMES.get(info[2], info[2])}, crosscheck as {joint}")
            dof.append(base + by_name[name])
        if base + len(movable) != scene.nv:
            raise ModelNotSupported(f"pybullet's model of '{scene.path}' has {base + len(movable)} velocities, the "
                                    f"scene {scene.nv}")
        dynamics = pybullet.getDynamicsInfo(body, -1, physicsClientId=cid)
        inertial = (np.array(dynamics[3], dtype=float), _matrix(dynamics[4]))
        return _Loaded(body, tuple(dof), len(movable), free, inertial, self._moved_mass(body, infos, free, cid))

    @staticmethod
    def _moved_mass(body: int, infos, free: bool, cid: int) -> float:
        """The mass of pybullet's links that a joint moves (the base's too on a free base; not links welded to a
        fixed base)."""
        moved = {-1: free}
        for j, info in enumerate(infos):            # a parent's index is below its child's
            moved[j] = moved[info[16]] or info[2] != pybullet.JOINT_FIXED
        return float(sum(pybullet.getDynamicsInfo(body, j, physicsClientId=cid)[0]
                         for j, m in moved.items() if m))

    def terms(self, b: _Loaded, scene, q, qd, tau) -> Terms:
        """``M`` (``calculateMassMatrix``), ``h`` (``calculateInverseDynamics`` at zero acceleration) and ``g`` (at
        rest), the base velocity and pose brought to pybullet's (module docstring)."""
        joints = np.zeros(b.n_joints)
        base = 6 if b.free else 0
        for i, joint in enumerate(scene.joints):
            if joint != "free":
                joints[b.dof[i] - base] = q[scene.q_index[i]]
        T, c = velocity_map(scene, q, qd, list(b.dof))
        position = list(joints)
        if b.free:
            iv = scene.v_index[0]
            r, R_c = b.inertial
            R, p = free_pose(scene, q, 0)
            T[0:6, iv:iv + 6], c[0:6] = _free_block(R_c, r, qd[iv:iv + 3], qd[iv + 3:iv + 6])
            position = [*(R @ r + p), *_quaternion(R @ R_c), *joints]
        v_L, zero = T @ qd, [0.0] * scene.nv
        with self._lock:
            cid = self._connected()
            pybullet.setGravity(*scene_gravity(scene), physicsClientId=cid)
            M_L = np.array(pybullet.calculateMassMatrix(b.body, list(joints), physicsClientId=cid))
            h_L = np.array(pybullet.calculateInverseDynamics(b.body, position, list(v_L), zero, physicsClientId=cid))
            g_L = np.array(pybullet.calculateInverseDynamics(b.body, position, zero, zero, physicsClientId=cid))
        if b.free:                                  # pybullet returns the base's force first: moment first, as M
            h_L[0:6], g_L[0:6] = np.r_[h_L[3:6], h_L[0:3]], np.r_[g_L[3:6], g_L[0:3]]
        M, h, g = in_ours(T, c, M_L, h_L, g_L)
        return Terms(M, h, g, b.mass)


BACKEND = PyBullet()
