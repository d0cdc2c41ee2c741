"""MuJoCo as a backend: ``mujoco.MjSpec`` reads the URDF or MJCF file itself; ``mj_forward``, ``mj_fullM`` and
``mj_solveM`` evaluate it.

    crosscheck gate --simulator mujoco --model robot.urdf          # or --plugin crosscheck.adapters.mujoco

Conventions (docs/simulators.md has the matrix of every adapter):

* quaternion ``(w, x, y, z)`` (ours ``(x, y, z, w)``); a free joint's velocity is the linear velocity of the body
  origin in the **world** frame, then the angular velocity in the **body** frame (ours: both in the body frame);
  its pose is relative to the world, so the joint's frame (MuJoCo's ``qpos0``: the body's pose in the file, moved
  by the scene) is composed in;
* joints are found by the body they move (``scene.bodies``: the URDF link or MJCF body), the type checked;
* fixed URDF links are merged into their parent by MuJoCo's URDF compiler (``fusestatic``); a link without
  ``<inertial>`` is massless (its geoms are dropped here, so ``inertiafromgeom`` adds nothing), and a link with mass
  0 and a rotational inertia (a model finding, ``cases.urdf``) loses the inertia when it is merged;
* inertias are used as the file gives them (``balanceinertia``, ``boundmass``, ``boundinertia`` stay off);
* ``armature`` (rotor inertia, added to M's diagonal) is part of the model (``cases.model.Body.armature``): an
  MJCF's is kept as MuJoCo reads it, a URDF's (which the file cannot say) is set on the joints the user declared it
  for (``scene.armature``, from ``--armature``).

Off unless named (:attr:`MuJoCo.DEFAULTS`): the constraint solver (``mjDSBL_CONSTRAINT``: contacts, joint limits,
equality constraints, friction loss), joint damping and springs (``mjDSBL_DAMPER``, ``mjDSBL_SPRING``; a URDF
``<dynamics damping>`` becomes MuJoCo damping), gravity compensation (``gravcomp``), the fluid model (``density``,
``viscosity``, ``wind``) and actuators (``mjDSBL_ACTUATION``: the inputs enter as ``qfrc_applied = B u``).
URDF ``<visual>`` and ``<collision>`` are dropped before MuJoCo reads the file. A model with constraint rows (a URDF
``<mimic>``) is NOT COMPARED: MuJoCo's equality constraints are soft.
"""

from __future__ import annotations

from dataclasses import dataclass

import mujoco
import numpy as np

from crosscheck.adapters.base import (Adapter, FreeVelocity, Terms, accel_in_ours, in_ours, scene_gravity,
                                      urdf_without_geometry, velocity_map)
from formalisms.interface import ModelNotSupported

_FREE, _BALL = mujoco.mjtJoint.mjJNT_FREE, mujoco.mjtJoint.mjJNT_BALL
#: crosscheck's joint types (``scene.joints``) -> MuJoCo's.
_JOINT_TYPES = {"revolute": mujoco.mjtJoint.mjJNT_HINGE, "prismatic": mujoco.mjtJoint.mjJNT_SLIDE,
                "spherical": _BALL, "free": _FREE}
#: MuJoCo's free-joint velocity (module docstring).
FREE = FreeVelocity("world", "body", angular_first=False)
_D = mujoco.mjtDisableBit


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


def _compiled(spec: mujoco.MjSpec, scene) -> mujoco.MjModel:
    """``spec`` compiled; a file MuJoCo's compiler refuses (an inertia it finds invalid, say) is NOT COMPARED with
    MuJoCo's reason: its users could not load it either (``balanceinertia`` would change the file's inertias)."""
    try:
        return spec.compile()
    except ValueError as exc:
        raise ModelNotSupported(f"MuJoCo's compiler refuses '{scene.path}': {exc}") from None


@dataclass(frozen=True)
class _Compiled:
    """One scene's MjModel and where each of crosscheck's bodies sits in it."""

    model: mujoco.MjModel
    qpos: tuple[int, ...]       # qpos address of each body's joint
    dof: tuple[int, ...]        # dof address of each body's joint


class MuJoCo(Adapter):
    """The MuJoCo adapter (module docstring)."""

    simulator = "mujoco"
    KINDS = ("urdf", "mjcf")
    ARMATURE = True
    DEFAULTS = {
        "constraint_solver": "contacts, joint limits, equality constraints and friction loss (mjDSBL_CONSTRAINT)",
        "damping": "joint damping, a force -c qd (mjDSBL_DAMPER; URDF <dynamics damping>)",
        "springs": "joint springs, a force -k (q - q_ref) (mjDSBL_SPRING; joint stiffness)",
        "gravcomp": "gravity compensation of bodies (body gravcomp)",
        "fluid": "the fluid model (option density, viscosity, wind)",
        "actuators": "actuator forces, their gains and biases at zero control (mjDSBL_ACTUATION)",
    }

    @staticmethod
    def library() -> str:
        return f"MuJoCo {mujoco.__version__}"

    def _rigid_body_only(self, spec: mujoco.MjSpec) -> None:
        """Turn off in ``spec`` every default not named (module docstring)."""
        flags = {"constraint_solver": _D.mjDSBL_CONSTRAINT, "damping": _D.mjDSBL_DAMPER,
                 "springs": _D.mjDSBL_SPRING, "actuators": _D.mjDSBL_ACTUATION}
        for default, flag in flags.items():
            if default not in self.on:
                spec.option.disableflags |= int(flag)
        if "fluid" not in self.on:
            spec.option.density, spec.option.viscosity, spec.option.wind = 0.0, 0.0, [0.0, 0.0, 0.0]
        spec.option.enableflags |= mujoco.mjtEnableBit.mjENBL_ENERGY          # kinetic energy in data.energy[1]
        for joint in spec.joints:   # damping and stiffness are polynomial coefficients (arrays) in MuJoCo 4
            if "springs" not in self.on:
                joint.stiffness, joint.springdamper = np.zeros_like(joint.stiffness), np.zeros_like(joint.springdamper)
            if "damping" not in self.on:
                joint.damping = np.zeros_like(joint.damping)
            if "constraint_solver" not in self.on:
                joint.frictionloss = 0.0
        if "gravcomp" not in self.on:
            for body in spec.bodies:
                body.gravcomp = 0.0

    @staticmethod
    def _spec(scene) -> mujoco.MjSpec:
        """The file as MuJoCo reads it (URDF without geometry; MJCF as it is), with a free joint on the root body
        when the scene floats the file's base, armature as the scene declares it for a URDF."""
        if scene.kind == "urdf":
            spec = mujoco.MjSpec.from_string(urdf_without_geometry(scene.path))
        else:
            spec = mujoco.MjSpec.from_file(scene.path)
        for name, value in scene.armature:          # a URDF cannot say it: the user declared it (--armature)
            joint = spec.joint(name)
            if joint is None:
                raise ModelNotSupported(f"MuJoCo's model of '{scene.path}' has no joint '{name}' to set its "
                                        "armature on")
            joint.armature = float(value)
        if scene.root == "free":
            roots = list(spec.worldbody.bodies)
            if len(roots) != 1:
                raise ModelNotSupported(f"'{scene.path}' has {len(roots)} root bodies; a free base needs one")
            roots[0].add_freejoint()
        return spec

    def in_file(self, scene) -> dict[str, str]:
        """The defaults the file sets, read off MuJoCo's model of it compiled with every default as MuJoCo has it."""
        m = _compiled(self._spec(scene), scene)
        counts = {"damping": int(np.count_nonzero(m.dof_damping)), "springs": int(np.count_nonzero(m.jnt_stiffness)),
                  "gravcomp": int(np.count_nonzero(m.body_gravcomp))}
        found = {name: f"on {k} {'joints' if name != 'gravcomp' else 'bodies'}" for name, k in counts.items() if k}
        solver = [f"{k} {what}" for k, what in ((int(m.jnt_limited.sum()), "limited joints"),
                                                 (int(np.count_nonzero(m.dof_frictionloss)), "joints with friction loss"),
                                                 (m.ngeom, "geoms (contacts)"), (m.neq, "equality constraints")) if k]
        if solver:
            found["constraint_solver"] = ", ".join(solver)
        if m.opt.density or m.opt.viscosity or np.any(m.opt.wind):
            found["fluid"] = "density, viscosity or wind set"
        if m.nu:
            found["actuators"] = f"{m.nu} actuators"
        return found

    def build(self, scene) -> _Compiled:
        """The scene's MjModel: the file's bodies in a frame at the scene's placement, gravity turned with it (or
        zero), every default not named off; crosscheck's bodies found by name, their joint types checked."""
        spec = self._spec(scene)
        R, t = np.asarray(scene.rotation, dtype=float), np.asarray(scene.translation, dtype=float)
        frame = spec.worldbody.add_frame(pos=t, quat=_quat_of(R))
        for body in list(spec.worldbody.bodies):
            body.set_frame(frame)
        spec.option.gravity = scene_gravity(scene)
        self._rigid_body_only(spec)
        model = _compiled(spec, scene)
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

    @staticmethod
    def _state(c: _Compiled, scene, q, qd):
        """MuJoCo's qpos of the scene's ``q``, and each free body's world rotation."""
        qpos, rotations = c.model.qpos0.copy(), {}
        for i, joint in enumerate(scene.joints):
            a, iq = c.qpos[i], scene.q_index[i]
            if joint in ("revolute", "prismatic"):
                qpos[a] = q[iq]
            elif joint == "spherical":
                x, y, z, w = q[iq:iq + 4]
                qpos[a:a + 4] = (w, x, y, z)
            else:     # free: world pose X0 * (p, R), X0 the joint frame (qpos0: the file's pose moved by the scene)
                R0 = _matrix(c.model.qpos0[a + 3:a + 7])
                rotations[i] = R0 @ _matrix(np.array([q[iq + 6], *q[iq + 3:iq + 6]]))
                qpos[a:a + 3] = R0 @ q[iq:iq + 3] + c.model.qpos0[a:a + 3]
                qpos[a + 3:a + 7] = _quat_of(rotations[i])
        return qpos, rotations

    def terms(self, c: _Compiled, scene, q, qd, tau) -> Terms:
        """``M`` (``mj_fullM``), ``h`` (``qfrc_bias``), ``g`` (``qfrc_bias`` at rest), MuJoCo's own accelerations
        (``qacc`` at ``u = 0`` and with ``qfrc_applied = tau_L``; ``mj_solveM`` for ctrl) and kinetic energy."""
        m, data = c.model, mujoco.MjData(c.model)
        qpos, rotations = self._state(c, scene, q, qd)
        T, cv = velocity_map(scene, q, qd, list(c.dof), FREE, rotations)
        tau_L = np.linalg.solve(T.T, tau)
        data.qpos[:], data.qvel[:] = qpos, T @ qd
        mujoco.mj_forward(m, data)
        drift_L, h_L, kinetic = data.qacc.copy(), data.qfrc_bias.copy(), float(data.energy[1])
        M_L = np.empty((m.nv, m.nv))
        mujoco.mj_fullM(m, data, M_L)
        ctrl_L = np.empty((1, m.nv))
        mujoco.mj_solveM(m, data, ctrl_L, tau_L.reshape(1, -1))
        data.qfrc_applied[:] = tau_L
        mujoco.mj_forward(m, data)
        total_L = data.qacc.copy()
        data.qvel[:], data.qfrc_applied[:] = 0.0, 0.0
        mujoco.mj_forward(m, data)                    # at rest: qfrc_bias is the gravity term g alone
        M, h, g = in_ours(T, cv, M_L, h_L, data.qfrc_bias)
        zero = np.zeros_like(cv)
        return Terms(M, h, g, float(m.body_mass.sum()), drift=accel_in_ours(T, cv, drift_L),
                     ctrl=accel_in_ours(T, zero, ctrl_L[0]), total=accel_in_ours(T, cv, total_L),
                     kinetic_energy=kinetic)


BACKEND = MuJoCo()
