"""Drake as a backend: ``pydrake.multibody.parsing.Parser`` reads the URDF or MJCF file itself into a continuous
``MultibodyPlant(time_step=0.0)``; ``CalcMassMatrix``, ``CalcInverseDynamics``, ``CalcGravityGeneralizedForces``,
the plant's own forward dynamics (``get_generalized_acceleration_output_port``) and ``CalcKineticEnergy`` evaluate it.

    crosscheck gate --simulator drake --model robot.urdf          # or --plugin crosscheck.adapters.drake

Conventions (docs/simulators.md has the matrix of every adapter):

* quaternion ``(w, x, y, z)`` (ours ``(x, y, z, w)``), first in a free joint's coordinates ``(qw, qx, qy, qz, x, y,
  z)`` (ours ``(x, y, z, qx, qy, qz, qw)``); a free joint's (``QuaternionFloatingJoint``) velocity is ``(w_FM, v_FM)``:
  the angular velocity, **then** the linear velocity of the body origin, both in the joint's **parent** frame F (ours:
  linear then angular, both in the body frame). Every free joint here is one Drake holds between a frame F and the
  body: the free joint ``--base free`` adds is added explicitly, F the file's world placed by the scene, so its
  coordinates are ours relative to F, as are an MJCF ``<freejoint>``'s (F the body's pose in the file, moved by the
  scene; Drake would otherwise float the body from the world);
* an MJCF ``ball`` joint is a ``BallRpyJoint``: coordinates roll-pitch-yaw ``R_FM = Rz Ry Rx`` (ours a quaternion),
  velocity the angular velocity ``w_FM`` in the parent frame F (ours: in the body frame);
* joints are found by the file's joint name (``scene.joint_names``; a URDF ``continuous`` joint is a Drake
  ``revolute``), the free joints by their body; each one's ``position_start`` and ``velocity_start`` place it;
* the file's world: a URDF root link is welded to the world at the scene's placement (``WeldFrames``) or floated from
  it; a root link named ``world``, which Drake's URDF parser takes for its own world body, is renamed first so that
  it too can be placed (the joints hanging from it keep their offsets); a URDF ``floating`` joint, which Drake's
  parser does not hold (it warns and leaves the child body free), is made a ``QuaternionFloatingJoint`` from its
  ``<origin>`` in its parent link; an MJCF's joints to the world (its top bodies' hinges, slides, balls and welds) are
  made again from a frame at the scene's placement;
* fixed URDF joints are welds (``WeldJoint``), their links kept as bodies: nothing is merged; a link without
  ``<inertial>`` is massless; an MJCF body without ``<inertial>`` gets the inertia of its geoms (as MuJoCo's and
  Pinocchio's readings do on boxes, capsules and spheres); inertias are used as the file gives them, also one that
  fails Drake's physical-validity test (default ``repaired_inertia`` below);
* limits are not enforced by a continuous plant (only a discrete one), so ``<limit>`` changes nothing here; URDF
  ``<dynamics friction>``, ``<mechanicalReduction>`` and ``<safety_controller>`` are not supported by Drake (it warns
  and ignores them); contact needs geometry registered with a SceneGraph, and none is (URDF ``<visual>``,
  ``<collision>`` are dropped before Drake reads the file); the inputs enter as the plant's applied generalized force
  ``tau_L`` (the actuation port is held at zero, so actuator effort limits, gears and PD gains never act);
* two things Drake's URDF parser refuses (the whole file) are dropped from the text it is given, since no other reader
  uses them and they change no dynamics: a ``<mimic>`` tag on a fixed joint (crosscheck ignores it, as Pinocchio
  does: TALOS's grippers) and a ``<transmission>`` naming a joint the file does not have (TALOS's arm file).

Off unless named (:attr:`Drake.DEFAULTS`):

* ``damping``: joint damping (``Joint.default_damping``: URDF ``<dynamics damping>``, MJCF joint ``damping``); it
  enters through ``CalcForceElementsContribution``, so Drake's forward dynamics and ``h`` here (inverse dynamics with
  the force elements' forces), not ``M`` or ``CalcBiasTerm``;
* ``reflected_inertia``: an actuator's reflected rotor inertia ``rho G^2`` added to ``M``'s diagonal (a URDF
  ``<transmission>``'s ``<actuator>`` with ``<drake:rotor_inertia>`` and ``<drake:gear_ratio>``; an MJCF joint's
  ``armature`` when an actuator drives it, read as ``rho = armature / gear^2``); it is in ``M`` and the kinetic
  energy;
* ``repaired_inertia``: a URDF ``<inertia>`` that fails Drake's physical-validity test (the triangle inequality; e.g.
  ANYmal's ``base`` link, all six entries 1e-6) is replaced by the parser with a solid sphere's of the same mass
  (with a warning); off, the file's inertia is put back in each context (``SetSpatialInertiaInBodyFrame``).

NOT COMPARED: a model with constraint rows (a URDF ``<mimic>`` on a moving joint: Drake's parser makes a coupler
constraint, which Drake enforces in a discrete SAP plant only); a file Drake refuses (ModelNotSupported with Drake's
reason); a joint Drake reads as another type than crosscheck.
"""

from __future__ import annotations

import xml.etree.ElementTree as ET
from dataclasses import dataclass
from importlib import metadata

import numpy as np
from pydrake.math import RigidTransform, RollPitchYaw, RotationMatrix
from pydrake.multibody.parsing import Parser
from pydrake.multibody.plant import MultibodyPlant
from pydrake.multibody.tree import (BallRpyJoint, BodyIndex, FixedOffsetFrame, MultibodyForces, PrismaticJoint,
                                    QuaternionFloatingJoint, RevoluteJoint, SpatialInertia, UnitInertia, WeldJoint)

from cases.configuration import rotation
from crosscheck.adapters.base import (Adapter, FreeVelocity, Terms, accel_in_ours, in_ours,
                                      scene_gravity, urdf_without_geometry, velocity_map)
from formalisms.interface import ModelNotSupported

#: Drake's free-joint velocity (module docstring): angular then linear, both in the joint's parent frame F, which
#: :func:`velocity_map` calls "world" (the rotation passed to it is ``R_FM``).
FREE = FreeVelocity("world", "world", angular_first=True)
#: crosscheck's joint types (``scene.joints``) -> Drake's ``type_name()``.
_JOINT_TYPES = {"revolute": "revolute", "prismatic": "prismatic", "spherical": "ball_rpy",
                "free": "quaternion_floating"}
#: The name a URDF root link called ``world`` is given, so that Drake does not take it for its world body.
RENAMED_WORLD = "crosscheck_file_world"


def _transform(R, t) -> RigidTransform:
    return RigidTransform(RotationMatrix(np.asarray(R, dtype=float)), np.asarray(t, dtype=float))


def _urdf_text(scene) -> str:
    """The URDF as Drake is given it: without geometry, its root link renamed from ``world`` if so named, and without
    two things Drake refuses and no other reader uses, which change no dynamics: the ``<mimic>`` tags of fixed joints
    (crosscheck, as Pinocchio, ignores them: a fixed joint has no coordinate to couple) and the ``<transmission>``s
    that name a joint the file does not have (a partial robot's file, e.g. TALOS's arm)."""
    robot = ET.fromstring(urdf_without_geometry(scene.path))
    for joint in robot.findall("joint"):
        if joint.get("type") == "fixed":
            for mimic in joint.findall("mimic"):
                joint.remove(mimic)
    joints = {joint.get("name") for joint in robot.findall("joint")}
    for transmission in robot.findall("transmission"):
        if any(j.get("name") not in joints for j in transmission.findall("joint")):
            robot.remove(transmission)
    if scene.root_link == "world":
        for link in robot.iter("link"):
            if link.get("name") == "world":
                link.set("name", RENAMED_WORLD)
        for joint in robot.findall("joint"):
            for end in ("parent", "child"):
                element = joint.find(end)
                if element is not None and element.get("link") == "world":
                    element.set("link", RENAMED_WORLD)
    return ET.tostring(robot, encoding="unicode")


def _numbers(element, attribute: str, default: str) -> np.ndarray:
    return np.array([float(x) for x in (element.get(attribute) or default).split()]) if element is not None \
        else np.array([float(x) for x in default.split()])


def _file_inertias(text: str) -> dict[str, SpatialInertia]:
    """Each URDF link's spatial inertia about its origin as the file gives it (``<inertial>``: mass, the COM frame's
    ``<origin xyz rpy>`` and the inertia about the COM in that frame), built without Drake's validity check."""
    out = {}
    for link in ET.fromstring(text).iter("link"):
        inertial = link.find("inertial")
        if inertial is None or inertial.find("mass") is None:
            continue
        mass = float(inertial.find("mass").get("value"))
        if mass <= 0.0:
            tensor = inertial.find("inertia")
            if tensor is not None and any(float(tensor.get(k, 0.0)) for k in ("ixx", "iyy", "izz")):
                raise ModelNotSupported(f"link '{link.get('name')}' has mass 0 and a rotational inertia, which "
                                        "Drake's spatial inertia cannot hold (its parser makes it a 1 kg sphere: "
                                        "--simulator drake:repaired_inertia)")
            continue
        origin, tensor = inertial.find("origin"), inertial.find("inertia")
        c, rpy = _numbers(origin, "xyz", "0 0 0"), _numbers(origin, "rpy", "0 0 0")
        moments = {k: float(tensor.get(k, 0.0)) if tensor is not None else 0.0
                   for k in ("ixx", "iyy", "izz", "ixy", "ixz", "iyz")}
        I = np.array([[moments["ixx"], moments["ixy"], moments["ixz"]],
                      [moments["ixy"], moments["iyy"], moments["iyz"]],
                      [moments["ixz"], moments["iyz"], moments["izz"]]])
        R = RollPitchYaw(rpy).ToRotationMatrix().matrix()
        I_o = R @ I @ R.T + mass * (c @ c * np.eye(3) - np.outer(c, c))       # about the link origin
        G = I_o / mass
        out[link.get("name")] = SpatialInertia(mass, c, UnitInertia(G[0, 0], G[1, 1], G[2, 2], G[0, 1], G[0, 2],
                                                                      G[1, 2]), skip_validity_check=True)
    return out


def _remake(plant: MultibodyPlant, joint, parent_frame):
    """``joint`` made again with ``parent_frame`` as its frame on the parent (its type, child frame and damping kept;
    the actuators on it moved to the new joint)."""
    kind, name, child = joint.type_name(), joint.name(), joint.frame_on_child()
    damping = np.array(joint.default_damping_vector()) if joint.num_velocities() else None   # copies: the joint goes
    X_FM = RigidTransform(joint.X_FM()) if kind == "weld" else None
    axis = np.array(joint.revolute_axis() if kind == "revolute" else joint.translation_axis()) \
        if kind in ("revolute", "prismatic") else None
    actuators = []
    for index in plant.GetJointActuatorIndices():
        actuator = plant.get_joint_actuator(index)
        if actuator.joint().index() == joint.index():
            actuators.append((actuator.name(), actuator.effort_limit(), actuator.default_rotor_inertia(),
                              actuator.default_gear_ratio()))
            plant.RemoveJointActuator(actuator)
    if kind == "weld":
        new = WeldJoint(name, parent_frame, child, X_FM)
    elif kind == "revolute":
        new = RevoluteJoint(name, parent_frame, child, axis)
    elif kind == "prismatic":
        new = PrismaticJoint(name, parent_frame, child, axis)
    elif kind == "ball_rpy":
        new = BallRpyJoint(name, parent_frame, child)
    elif kind == "quaternion_floating":
        new = QuaternionFloatingJoint(name, parent_frame, child)
    else:
        raise ModelNotSupported(f"Drake's {kind} joint '{name}' hangs from the world; only weld, revolute, prismatic, "
                                "ball and free joints are placed here")
    plant.RemoveJoint(joint)
    added = plant.AddJoint(new)
    if damping is not None:
        added.set_default_damping_vector(damping)
    for actuator_name, limit, rotor, gear in actuators:
        actuator = plant.AddJointActuator(actuator_name, added, limit)
        actuator.set_default_rotor_inertia(rotor)
        actuator.set_default_gear_ratio(gear)
    return added


@dataclass(frozen=True)
class _Built:
    """One scene's finalized plant and where each of crosscheck's bodies' joints sits in its state."""

    plant: MultibodyPlant
    qpos: tuple[int, ...]        # position_start of each body's joint
    dof: tuple[int, ...]         # velocity_start of each body's joint
    mass: float                  # the moving bodies' mass
    inertias: tuple = ()         # (body index, the file's spatial inertia) of each body whose inertia Drake replaced


def _declared_armature(plant: MultibodyPlant, scene) -> None:
    """The armature the user declared for a URDF's joints (``scene.armature``) as Drake holds a rotor inertia: an
    actuator's reflected inertia ``rho G^2`` with ``rho`` the armature and ``G = 1`` (the joint's own actuator, or one
    added for it). An MJCF file's armature Drake keeps only on a joint an actuator drives: such a file is NOT
    COMPARED (MuJoCo reads it)."""
    if scene.kind == "mjcf" and any(e.get("armature") not in (None, "0") for e in ET.parse(scene.path).iter()):
        raise ModelNotSupported(f"'{scene.path}' declares armature: Drake's MJCF parser keeps it only as the reflected "
                                "rotor inertia of an actuated joint and drops it elsewhere (compare it with MuJoCo)")
    driven = {plant.get_joint_actuator(i).joint().name(): plant.get_joint_actuator(i)
              for i in plant.GetJointActuatorIndices()}
    for name, value in scene.armature:
        actuator = driven.get(name) or plant.AddJointActuator(f"crosscheck_rotor_{name}", plant.GetJointByName(name))
        actuator.set_default_rotor_inertia(float(value))
        actuator.set_default_gear_ratio(1.0)


class Drake(Adapter):
    """The Drake adapter (module docstring)."""

    simulator = "drake"
    KINDS = ("urdf", "mjcf")
    ARMATURE = True
    DEFAULTS = {
        "damping": "joint damping, a force -d qd (Joint.default_damping: URDF <dynamics damping>, MJCF damping)",
        "reflected_inertia": "an actuator's reflected rotor inertia rho G^2 on M's diagonal (a URDF <transmission> "
                             "actuator's <drake:rotor_inertia>, <drake:gear_ratio>; an MJCF actuated joint's armature)",
        "repaired_inertia": "a URDF <inertia> that fails Drake's physical-validity test (the triangle inequality) "
                            "replaced by a solid sphere's of the same mass, with a warning",
    }

    @staticmethod
    def library() -> str:
        return f"Drake {metadata.version('drake')}"

    def _parse(self, plant: MultibodyPlant, scene):
        """The file's model instances (URDF without geometry); ModelNotSupported with Drake's reason if it refuses."""
        try:
            if scene.kind == "urdf":
                return Parser(plant).AddModelsFromString(_urdf_text(scene), "urdf")
            return Parser(plant).AddModels(scene.path)
        except RuntimeError as error:
            raise ModelNotSupported(f"{self.library()} refuses '{scene.path}': {error}") from None

    @staticmethod
    def _place(plant: MultibodyPlant, scene) -> None:
        """The file's world put at the scene's placement X (module docstring): a URDF root link welded there or floated
        from there, a URDF ``floating`` joint (which Drake's parser does not hold: it warns and leaves the child body
        free) made a free joint from its ``<origin>`` in its parent link; an MJCF's joints to the world made again from
        X times their frame, each free body (an MJCF ``<freejoint>``) given a free joint from X times its pose in the
        file."""
        X = _transform(scene.rotation, scene.translation)
        world = plant.world_frame()
        if scene.kind == "urdf":
            root = plant.GetBodyByName(RENAMED_WORLD if scene.root_link == "world" else scene.root_link)
            if scene.root == "free":
                placed = plant.AddFrame(FixedOffsetFrame("crosscheck_placement", world, X))
                plant.AddJoint(QuaternionFloatingJoint("crosscheck_free_base", placed, root.body_frame()))
            else:
                plant.WeldFrames(world, root.body_frame(), X)
            for joint in ET.fromstring(_urdf_text(scene)).findall("joint"):    # Drake leaves these bodies free
                if joint.get("type") == "floating":
                    origin = joint.find("origin")
                    X_PF = RigidTransform(RollPitchYaw(_numbers(origin, "rpy", "0 0 0")),
                                          _numbers(origin, "xyz", "0 0 0"))
                    parent = plant.GetBodyByName(joint.find("parent").get("link"))
                    child = plant.GetBodyByName(joint.find("child").get("link"))
                    frame = plant.AddFrame(FixedOffsetFrame(f"crosscheck_{joint.get('name')}_frame",
                                                            parent.body_frame(), X_PF))
                    plant.AddJoint(QuaternionFloatingJoint(joint.get("name"), frame, child.body_frame()))
            return
        for index in list(plant.GetJointIndices()):
            joint = plant.get_joint(index)
            if joint.parent_body().index() == plant.world_body().index():
                X_WF = joint.frame_on_parent().GetFixedPoseInBodyFrame()
                placed = plant.AddFrame(FixedOffsetFrame(f"crosscheck_placement_{joint.name()}", world, X @ X_WF))
                _remake(plant, joint, placed)
        jointed = {int(plant.get_joint(j).child_body().index()) for j in plant.GetJointIndices()}
        for index in range(1, plant.num_bodies()):
            body = plant.get_body(BodyIndex(index))
            if index not in jointed:
                X_WB = plant.GetDefaultFloatingBaseBodyPose(body)
                placed = plant.AddFrame(FixedOffsetFrame(f"crosscheck_placement_{body.name()}", world, X @ X_WB))
                plant.AddJoint(QuaternionFloatingJoint(body.name(), placed, body.body_frame()))

    def _rigid_body_only(self, plant: MultibodyPlant) -> None:
        """Turn off in the plant every default not named (module docstring)."""
        if "damping" not in self.on:
            for index in plant.GetJointIndices():
                joint = plant.get_joint(index)
                if joint.num_velocities():
                    joint.set_default_damping_vector(np.zeros(joint.num_velocities()))
        if "reflected_inertia" not in self.on:
            for index in plant.GetJointActuatorIndices():
                plant.get_joint_actuator(index).set_default_rotor_inertia(0.0)

    def build(self, scene) -> _Built:
        """The scene's finalized plant: the file placed (:meth:`_place`), gravity turned with it (or zero), every
        default not named off; crosscheck's joints found by name (free ones by their body), their types checked."""
        plant = MultibodyPlant(time_step=0.0)
        models = self._parse(plant, scene)
        self._place(plant, scene)
        self._rigid_body_only(plant)
        _declared_armature(plant, scene)
        plant.mutable_gravity_field().set_gravity_vector(scene_gravity(scene))
        plant.Finalize()
        inertias = () if scene.kind != "urdf" or "repaired_inertia" in self.on else self._replaced(plant, scene)
        qpos, dof = [], []
        for name, joint_name, kind in zip(scene.bodies, scene.joint_names, scene.joints):
            joint = self._joint(plant, models, scene, name, joint_name, kind)
            if joint.type_name() != _JOINT_TYPES[kind] or joint.child_body().name() != name:
                raise ModelNotSupported(f"Drake reads the joint of body '{name}' in '{scene.path}' as a "
                                        f"{joint.type_name()} joint moving '{joint.child_body().name()}', crosscheck "
                                        f"as {kind}")
            qpos.append(joint.position_start())
            dof.append(joint.velocity_start())
        if plant.num_velocities() != scene.nv:
            raise ModelNotSupported(f"Drake's model of '{scene.path}' has {plant.num_velocities()} velocities, the "
                                    f"scene {scene.nv}")
        welded = {int(b.index()) for b in plant.GetBodiesWeldedTo(plant.world_body())}
        mass = sum(plant.get_body(BodyIndex(i)).default_mass() for i in range(plant.num_bodies())
                   if i not in welded)
        return _Built(plant, tuple(qpos), tuple(dof), float(mass), inertias)

    @staticmethod
    def _replaced(plant: MultibodyPlant, scene) -> tuple:
        """The bodies whose inertia Drake's parser replaced (one that fails its physical-validity test becomes a
        solid sphere's of the same mass, with a warning), each with the file's inertia to put back in a context."""
        out = []
        for name, M_file in _file_inertias(_urdf_text(scene)).items():
            if not plant.HasBodyNamed(name):
                continue
            body = plant.GetBodyByName(name)
            M, want = body.default_spatial_inertia().CopyToFullMatrix6(), M_file.CopyToFullMatrix6()
            if np.abs(M - want).max() > 1e-12 * max(1.0, np.abs(want).max()):
                out.append((body.index(), M_file))
        return tuple(out)

    @staticmethod
    def _joint(plant, models, scene, body: str, joint_name, kind: str):
        """Drake's joint of crosscheck's body ``body``: by the file's joint name, a free joint by its body."""
        if kind == "free" and (joint_name is None or scene.kind == "mjcf"):
            for index in plant.GetJointIndices():
                joint = plant.get_joint(index)
                if joint.child_body().name() == body and joint.type_name() == "quaternion_floating":
                    return joint
            raise ModelNotSupported(f"Drake's model of '{scene.path}' has no free joint moving '{body}'")
        for model in models:
            if plant.HasJointNamed(joint_name, model):
                return plant.GetJointByName(joint_name, model)
        raise ModelNotSupported(f"Drake's model of '{scene.path}' has no joint '{joint_name}'")

    @staticmethod
    def _state(b: _Built, scene, q):
        """Drake's positions of the scene's ``q`` and each free or ball joint's rotation ``R_FM``."""
        plant = b.plant
        q_L, rotations = np.zeros(plant.num_positions()), {}
        for i, kind in enumerate(scene.joints):
            a, iq = b.qpos[i], scene.q_index[i]
            if kind in ("revolute", "prismatic"):
                q_L[a] = q[iq]
            elif kind == "spherical":
                rotations[i] = rotation(q[iq:iq + 4])
                q_L[a:a + 3] = RollPitchYaw(RotationMatrix(rotations[i])).vector()
            else:                                 # free: (p, x, y, z, w) -> (w, x, y, z, p)
                rotations[i] = rotation(q[iq + 3:iq + 7])
                q_L[a:a + 4] = (q[iq + 6], *q[iq + 3:iq + 6])
                q_L[a + 4:a + 7] = q[iq:iq + 3]
        return q_L, rotations

    def velocity_map(self, b: _Built, scene, q, qd):
        """``T`` and ``c`` (``crosscheck.adapters.base``) at the state, with the rotations of :meth:`_state`."""
        q_L, rotations = self._state(b, scene, q)
        T, c = velocity_map(scene, q, qd, list(b.dof), FREE, rotations)
        for i, kind in enumerate(scene.joints):   # a ball joint's w_FM = R_FM w_M; d/dt: R_FM wdot_M (w x w = 0)
            if kind == "spherical":
                d, iv = b.dof[i], scene.v_index[i]
                T[d:d + 3, iv:iv + 3] = rotations[i]
        return q_L, T, c

    def terms(self, b: _Built, scene, q, qd, tau) -> Terms:
        """``M`` (``CalcMassMatrix``), ``h`` (``CalcInverseDynamics`` at zero acceleration with the force elements'
        forces: gravity and, left on, damping), ``g`` (``-CalcGravityGeneralizedForces``), Drake's own forward
        dynamics (the acceleration output port with the applied generalized force 0 and ``tau_L``) and kinetic
        energy."""
        plant = b.plant
        q_L, T, c = self.velocity_map(b, scene, q, qd)
        tau_L = np.linalg.solve(T.T, tau)
        context = plant.CreateDefaultContext()
        for index, inertia in b.inertias:           # the file's inertias where Drake's parser replaced them
            plant.get_body(index).SetSpatialInertiaInBodyFrame(context, inertia)
        plant.SetPositions(context, q_L)
        plant.SetVelocities(context, T @ qd)
        M_L = plant.CalcMassMatrix(context)
        forces = MultibodyForces(plant)
        plant.CalcForceElementsContribution(context, forces)
        h_L = plant.CalcInverseDynamics(context, np.zeros(plant.num_velocities()), forces)
        g_L = -plant.CalcGravityGeneralizedForces(context)
        if plant.get_actuation_input_port().size():
            plant.get_actuation_input_port().FixValue(context, np.zeros(plant.get_actuation_input_port().size()))
        applied = plant.get_applied_generalized_force_input_port()
        accel = plant.get_generalized_acceleration_output_port()
        applied.FixValue(context, np.zeros(plant.num_velocities()))
        drift_L = accel.Eval(context).copy()
        applied.FixValue(context, tau_L)
        total_L = accel.Eval(context).copy()
        M, h, g = in_ours(T, c, M_L, h_L, g_L)
        return Terms(M, h, g, b.mass, drift=accel_in_ours(T, c, drift_L), total=accel_in_ours(T, c, total_L),
                     kinetic_energy=float(plant.CalcKineticEnergy(context)))


BACKEND = Drake()
