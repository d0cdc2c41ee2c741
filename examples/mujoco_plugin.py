"""MuJoCo as a crosscheck backend: a complete wrapper to copy for your own simulator.

    crosscheck gate --plugin examples/mujoco_plugin.py:MUJOCO --model path/to/robot.urdf --samples 50

(``--plugin FILE.py:OBJECT`` loads this file directly: no installation, no environment variable.) MuJoCo reads the
URDF or MJCF file itself (``mujoco.MjSpec.from_file``), so it is an implementation independent of crosscheck's
conversion of the file and of Pinocchio's parser: the plugin declares ``needs = "source"`` and receives a
:class:`crosscheck.needs.SourceScene` (the file, where the scene places it, whether gravity acts, and the layout of a
state), never crosscheck's Model. On a built-in case (no file) it is NOT COMPARED.

What must be off for rigid-body dynamics
----------------------------------------
The gate compares the rigid-body equation of motion ``M(q) qdd + C(q, qd) qd + g(q) = B u`` (article eq. 9). A
simulator adds much to it, and everything extra makes it disagree with the formalisms (rightly: it is another
equation). :func:`rigid_body_only` turns off, before compiling:

* the whole constraint solver (``mjDSBL_CONSTRAINT``): contacts, joint limits (a URDF ``<limit>`` becomes a MuJoCo
  limit), equality constraints, friction loss (a URDF ``<dynamics friction=...>`` becomes ``frictionloss``);
* passive forces: joint damping (a URDF ``<dynamics damping=...>`` becomes MuJoCo damping: a force ``-c qd``
  linear in the velocity, which the gate's hint names as such) and joint springs (``stiffness``), by the flags
  ``mjDSBL_DAMPER`` and ``mjDSBL_SPRING`` and by zeroing ``damping`` and ``stiffness`` of every joint; gravity
  compensation (``gravcomp``); the fluid model (``density``, ``viscosity``, ``wind``);
* actuators (``mjDSBL_ACTUATION``): their gains, biases, activation dynamics and control clamping are MuJoCo's
  actuator model, not ``B u``; the inputs enter as ``qfrc_applied = B u`` instead;
* geometry (URDF ``<visual>`` and ``<collision>`` are dropped before MuJoCo reads the file: meshes need not be
  found, and with the inertias given in the file they add nothing to the dynamics).

The rotor inertia ``armature``, which MuJoCo adds to M's diagonal, is part of the equation (crosscheck's
``Body.armature``): an MJCF file's is kept as MuJoCo reads it, and a URDF's, which the file cannot say, is set on the
joints the user declared it for (``scene.armature``, from ``--armature``; :func:`_declared_armature`).

Left as the file says, and they must stay so: ``balanceinertia``, ``boundmass``, ``boundinertia``,
``settotalmass`` (each would change the file's inertias), and ``inertiafromgeom`` (MuJoCo fills in a body without
``<inertial>`` from its geoms; a URDF's are dropped here, so such a link is massless, as Pinocchio reads it).
``DAMPING_LEFT_ON`` is the same backend with joint damping left on: on a file whose joints declare damping, the
gate names it as the outlier, with the hint "a force linear in qd".

Which scenes ``split`` is called on
-----------------------------------
Not only the file as loaded: the gate's frame checks call it on **moved scenes** (the file's world placed by a
rigid transform ``(scene.rotation, scene.translation)``, gravity turned with it) and its hints on **gravity-free
copies** (``scene.gravity`` False). This wrapper places the file's bodies in a frame at that transform, turns the
file's gravity (MuJoCo's ``<option gravity>``, default ``0 0 -9.81``) by the rotation or sets it to zero, and keeps
one compiled MjModel per scene.

Conventions (``cases.model``): ``q`` per body in the scene's coordinate order (``scene.bodies``: the link or body
each joint moves, which is MuJoCo's body name too); a quaternion is ``(x, y, z, w)`` (MuJoCo: ``(w, x, y, z)``); a
free joint's velocity is the body twist, linear velocity then angular velocity, both in the body frame (MuJoCo: the
linear velocity in the world frame), and its acceleration is the time derivative of that twist. MuJoCo's free joint
is always relative to the world, so its pose is composed here with the joint's frame (MuJoCo's ``qpos0``: the
body's pose in the file, moved by the scene's transform). A model with constraint
declarations (a URDF ``<mimic>``) is not supported: MuJoCo's equality constraints are soft (``solref``,
``solimp``), not the ideal constraints of article section 5.

Supplied: drift, ctrl (``M^-1 B u`` by MuJoCo's own factorization, ``mj_solveM``), total, the control power and the
kinetic energy. Not supplied: the task-point acceleration (``task_drift``), joint loads, the task inertia.
"""

from __future__ import annotations

import threading
import xml.etree.ElementTree as ET
from dataclasses import dataclass

import mujoco
import numpy as np

from crosscheck.assemble import Sizes, unconstrained_split
from formalisms.interface import ModelNotSupported, Split

_FREE, _BALL = mujoco.mjtJoint.mjJNT_FREE, mujoco.mjtJoint.mjJNT_BALL
#: crosscheck's joint types (``scene.joints``) -> MuJoCo's.
_JOINT_TYPES = {"revolute": mujoco.mjtJoint.mjJNT_HINGE, "prismatic": mujoco.mjtJoint.mjJNT_SLIDE,
                "spherical": _BALL, "free": _FREE}
_OFF = int(mujoco.mjtDisableBit.mjDSBL_CONSTRAINT | mujoco.mjtDisableBit.mjDSBL_DAMPER
           | mujoco.mjtDisableBit.mjDSBL_SPRING | mujoco.mjtDisableBit.mjDSBL_ACTUATION)


def _quat_of(R: np.ndarray) -> np.ndarray:
    """MuJoCo's quaternion ``(w, x, y, z)`` of a rotation matrix."""
    quat = np.empty(4)
    mujoco.mju_mat2Quat(quat, np.ascontiguousarray(R, dtype=float).reshape(9))
    return quat


def _matrix(quat: np.ndarray) -> np.ndarray:
    """The rotation matrix of MuJoCo's quaternion ``(w, x, y, z)``."""
    R = np.empty(9)
    mujoco.mju_quat2Mat(R, np.asarray(quat, dtype=float))
    return R.reshape(3, 3)


def _without_geometry(path: str) -> str:
    """The URDF's text with every ``<visual>`` and ``<collision>`` removed (module docstring)."""
    robot = ET.parse(path).getroot()
    for link in robot.iter("link"):
        for tag in ("visual", "collision"):
            for element in link.findall(tag):
                link.remove(element)
    return ET.tostring(robot, encoding="unicode")


def rigid_body_only(spec: mujoco.MjSpec, damping: bool = False) -> None:
    """Turn off in ``spec`` everything that is not rigid-body dynamics (module docstring); ``damping`` True leaves
    joint damping on (the deliberately broken copy)."""
    off = _OFF if not damping else _OFF & ~int(mujoco.mjtDisableBit.mjDSBL_DAMPER)
    spec.option.disableflags |= off
    spec.option.density, spec.option.viscosity, spec.option.wind = 0.0, 0.0, [0.0, 0.0, 0.0]
    spec.option.enableflags |= mujoco.mjtEnableBit.mjENBL_ENERGY          # kinetic energy in data.energy[1]
    for joint in spec.joints:      # damping and stiffness are polynomial coefficients (arrays) in MuJoCo 4
        joint.stiffness, joint.springdamper = np.zeros_like(joint.stiffness), np.zeros_like(joint.springdamper)
        joint.frictionloss = 0.0
        if not damping:
            joint.damping = np.zeros_like(joint.damping)
    for body in spec.bodies:
        body.gravcomp = 0.0


def _declared_armature(spec: mujoco.MjSpec, scene) -> None:
    """Set the armature the user declared for the file's joints (``scene.armature``: joint name, value; a URDF has no
    tag for it) on those joints, by name (module docstring)."""
    for name, value in scene.armature:
        joint = spec.joint(name)
        if joint is None:
            raise ModelNotSupported(f"MuJoCo's model of '{scene.path}' has no joint '{name}' to set its armature on")
        joint.armature = float(value)


def _spec(scene) -> mujoco.MjSpec:
    """The file as MuJoCo reads it (URDF without geometry; MJCF as it is), with a free joint on the root link when
    the scene floats the file's base (``scene.root == "free"``)."""
    if scene.kind == "urdf":
        spec = mujoco.MjSpec.from_string(_without_geometry(scene.path))
    else:
        spec = mujoco.MjSpec.from_file(scene.path)
    if scene.root == "free":
        roots = list(spec.worldbody.bodies)
        if len(roots) != 1:
            raise ModelNotSupported(f"'{scene.path}' has {len(roots)} root bodies; a free base needs one")
        roots[0].add_freejoint()
    return spec


@dataclass(frozen=True)
class _Compiled:
    """One scene's MjModel and where each of crosscheck's bodies sits in it."""

    model: mujoco.MjModel
    qpos: tuple[int, ...]       # qpos address of each body's joint
    dof: tuple[int, ...]        # dof address of each body's joint


class MuJoCo:
    """The MuJoCo backend (module docstring). ``damping`` True leaves joint damping on (a deliberate bug)."""

    needs = "source"

    def __init__(self, name: str = "mujoco", damping: bool = False):
        self.name, self.damping = name, damping
        self.summary = (f"MuJoCo {mujoco.__version__} reading the URDF or MJCF file itself (mj_forward, mj_solveM)"
                        + ("; joint damping LEFT ON (a deliberate bug)" if damping else ""))
        self._compiled: dict[tuple, _Compiled] = {}
        self._lock = threading.Lock()

    # ------------------------------------------------------------------------------------------- the scene
    def _compile(self, scene) -> _Compiled:
        """The scene's MjModel (module docstring, "Which scenes"): the file's bodies in a frame at ``g``, gravity
        ``R g_file`` or zero, everything but rigid-body dynamics off; crosscheck's bodies found by name."""
        spec = _spec(scene)
        R, t = np.asarray(scene.rotation, dtype=float), np.asarray(scene.translation, dtype=float)
        frame = spec.worldbody.add_frame(pos=t, quat=_quat_of(R))
        for body in list(spec.worldbody.bodies):
            body.set_frame(frame)
        spec.option.gravity = R @ np.asarray(spec.option.gravity) if scene.gravity else np.zeros(3)
        rigid_body_only(spec, self.damping)
        _declared_armature(spec, scene)
        model = spec.compile()
        qpos, dof = [], []
        for name, joint in zip(scene.bodies, scene.joints):
            body = mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_BODY, name)
            if body < 0 or model.body_jntnum[body] != 1:
                raise ModelNotSupported(f"MuJoCo's model of '{scene.path}' has no body '{name}' moved by one joint")
            j = model.body_jntadr[body]
            if model.jnt_type[j] != _JOINT_TYPES[joint]:
                raise ModelNotSupported(f"MuJoCo reads the joint of body '{name}' in '{scene.path}' as "
                                        f"{mujoco.mjtJoint(model.jnt_type[j]).name}, crosscheck as {joint}")
            qpos.append(int(model.jnt_qposadr[j]))
            dof.append(int(model.jnt_dofadr[j]))
        if model.nv != scene.nv:
            raise ModelNotSupported(f"MuJoCo's model of '{scene.path}' has {model.nv} velocities, the scene "
                                    f"{scene.nv}")
        return _Compiled(model, tuple(qpos), tuple(dof))

    def compiled(self, scene) -> _Compiled:
        key = (scene.kind, scene.path, scene.root, scene.gravity, np.asarray(scene.rotation).tobytes(),
               np.asarray(scene.translation).tobytes())
        with self._lock:
            if key not in self._compiled:
                self._compiled[key] = self._compile(scene)
            return self._compiled[key]

    # ------------------------------------------------------------------------------------------ the state
    @staticmethod
    def _to_mujoco(c: _Compiled, scene, q, qd):
        """MuJoCo's qpos and qvel of the scene's ``q``, ``qd``, and the map T of velocities (``qvel = T qd``)."""
        qpos, qvel, T = c.model.qpos0.copy(), np.zeros(c.model.nv), np.eye(c.model.nv)
        for i, joint in enumerate(scene.joints):
            a, d, iq, iv = c.qpos[i], c.dof[i], scene.q_index[i], scene.v_index[i]
            if joint in ("revolute", "prismatic"):
                qpos[a], qvel[d] = q[iq], qd[iv]
            elif joint == "spherical":
                x, y, z, w = q[iq:iq + 4]
                qpos[a:a + 4], qvel[d:d + 3] = (w, x, y, z), qd[iv:iv + 3]
            else:     # free: world pose X0 * (p, R), X0 the joint frame (qpos0: the file's pose moved by g)
                R0, R = _matrix(c.model.qpos0[a + 3:a + 7]), _matrix(np.array([q[iq + 6], *q[iq + 3:iq + 6]]))
                R_world = R0 @ R
                qpos[a:a + 3] = R0 @ q[iq:iq + 3] + c.model.qpos0[a:a + 3]
                qpos[a + 3:a + 7] = _quat_of(R_world)
                T[d:d + 3, d:d + 3] = R_world
                qvel[d:d + 3], qvel[d + 3:d + 6] = R_world @ qd[iv:iv + 3], qd[iv + 3:iv + 6]
        return qpos, qvel, T

    @staticmethod
    def _ours(c: _Compiled, scene, acc_mj, T, qd, velocity_terms: bool) -> np.ndarray:
        """An acceleration (or a solve ``M^-1 tau``) from MuJoCo's dof order to the scene's: a free joint's linear
        part in the body frame, with ``- w x v`` for the rotating frame when ``velocity_terms``."""
        out = np.empty(scene.nv)
        for i, joint in enumerate(scene.joints):
            d, iv, size = c.dof[i], scene.v_index[i], {"free": 6, "spherical": 3}.get(joint, 1)
            out[iv:iv + size] = acc_mj[d:d + size]
            if joint == "free":
                out[iv:iv + 3] = T[d:d + 3, d:d + 3].T @ acc_mj[d:d + 3]
                if velocity_terms:
                    out[iv:iv + 3] -= np.cross(qd[iv + 3:iv + 6], qd[iv:iv + 3])
        return out

    # -------------------------------------------------------------------------------------------- split
    def split(self, scene, q, qd, u) -> Split:
        """drift ``-M^-1 (C qd + g)`` and total (``mj_forward`` at ``u = 0`` and with ``qfrc_applied = B u``),
        ctrl ``M^-1 B u`` (``mj_solveM`` on MuJoCo's factorization of M), the kinetic energy (``energy[1]``)."""
        if scene.constraints:
            raise ModelNotSupported(f"model '{scene.name}' has constraint rows ({[c.name for c in scene.constraints]}"
                                    "); MuJoCo's equality constraints are soft, not the ideal constraints compared")
        q, qd, u = (np.asarray(x, dtype=float) for x in (q, qd, u))
        c = self.compiled(scene)
        m, data = c.model, mujoco.MjData(c.model)
        qpos, qvel, T = self._to_mujoco(c, scene, q, qd)
        P = np.zeros((scene.nv, m.nv))               # qvel = T P^T qd: P permutes, T turns free joints' velocities
        P[np.arange(scene.nv), self._dofs(c, scene)] = 1.0
        tau = np.asarray(scene.input_map) @ u
        tau_mj = T @ P.T @ tau                        # the same power: tau . qd = tau_mj . qvel (T is orthogonal)

        data.qpos[:], data.qvel[:] = qpos, qvel
        mujoco.mj_forward(m, data)
        drift_mj, kinetic = data.qacc.copy(), float(data.energy[1])
        M_mj = np.empty((m.nv, m.nv))
        mujoco.mj_fullM(m, data, M_mj)
        ctrl_mj = np.empty((1, m.nv))
        mujoco.mj_solveM(m, data, ctrl_mj, tau_mj.reshape(1, -1))
        data.qfrc_applied[:] = tau_mj
        mujoco.mj_forward(m, data)
        total_mj = data.qacc.copy()
        data.qvel[:], data.qfrc_applied[:] = 0.0, 0.0
        mujoco.mj_forward(m, data)                    # at rest: qfrc_bias is the gravity term g alone

        M = P @ T.T @ M_mj @ T @ P.T
        g = P @ T.T @ data.qfrc_bias
        drift = self._ours(c, scene, drift_mj, T, qd, True)
        sizes = Sizes(float(m.body_mass.sum()), np.array(m.opt.gravity))
        return unconstrained_split(sizes, M=M, Cqd=-(M @ drift) - g, g=g, tau_ctrl=tau, qd=qd, drift=drift,
                                   ctrl=self._ours(c, scene, ctrl_mj[0], T, qd, False),
                                   total=self._ours(c, scene, total_mj, T, qd, True), kinetic_energy=kinetic)

    @staticmethod
    def _dofs(c: _Compiled, scene) -> np.ndarray:
        """MuJoCo's dof of each of the scene's velocities."""
        out = np.empty(scene.nv, dtype=int)
        for i, joint in enumerate(scene.joints):
            size = {"free": 6, "spherical": 3}.get(joint, 1)
            out[scene.v_index[i]:scene.v_index[i] + size] = c.dof[i] + np.arange(size)
        return out


MUJOCO = MuJoCo()
DAMPING_LEFT_ON = MuJoCo("mujoco_damping_left_on", damping=True)
