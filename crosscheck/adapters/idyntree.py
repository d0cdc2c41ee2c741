"""iDynTree as a backend: ``idyntree.swig.ModelLoader`` reads the URDF itself; ``KinDynComputations`` in the
body-fixed representation evaluates its free-floating ``M`` (``getFreeFloatingMassMatrix``), bias forces
(``generalizedBiasForces``) and gravity forces (``generalizedGravityForces``).

    crosscheck gate --simulator idyntree --model robot.urdf          # or --plugin crosscheck.adapters.idyntree

Conventions (docs/simulators.md has the matrix of every adapter):

* no quaternion: the base pose is given as a transform ``world_H_base`` (a rotation matrix and a position); in the
  ``BODY_FIXED_REPRESENTATION`` the base velocity is the body twist of the base link, linear then angular, both in
  the base frame, and the base acceleration its time derivative: ours exactly. iDynTree's model is always free
  floating (6 base velocities, then the joints'): on a fixed base the base pose is the root link's placement in the
  scene, its velocity zero, and the joint block of ``M``, ``h``, ``g`` is the fixed-base dynamics. A URDF
  ``floating`` joint, which iDynTree's parser does not hold (it reports two root links and loads an empty model), is
  taken when it hangs alone from the root link: that link and joint are removed, and the base floats from the joint's
  ``<origin>`` placed by the scene;
* joints are found by the file's joint name (``getJointIndex``), their velocity at ``6 + getDOFsOffset()``; a URDF
  ``continuous`` joint is a ``RevoluteJoint``;
* fixed joints are kept as ``FixedJoint`` between links (no link is merged); a massless link that hangs by a fixed
  joint and carries nothing (e.g. a ``tool`` or ``world`` frame) is turned into an additional frame of its neighbour
  link (iDynTree's fake-link removal: no dynamic effect, but for a link with mass 0 and a rotational inertia, whose
  inertia is dropped: a model finding, ``cases.urdf``; bolt's feet), so the base is the link that carries the file's root link
  frame (a ``world`` root link is a frame of ``base_link`` then), placed so that this frame is where the scene puts
  the file's world;
* inertias are used as the file gives them; a link without ``<inertial>`` is massless;
* the inputs enter as joint torques ``tau``; gravity is the scene's, given with each state (``setRobotState``).

Defaults: none. ``KinDynComputations`` computes rigid-body dynamics only: the joints' ``<dynamics damping
friction>`` and ``<limit>`` are read into the model but enter none of these terms; the parser's option
``convertThreeRevoluteJointsToSphericalJoint`` is off by default (it would change the coordinates) and is left off;
the fake-link removal above changes no dynamics of a possible body; an inertia is taken as the file gives it, even one that fails the
triangle inequality. So :attr:`IDynTree.DEFAULTS` is empty. ``KinDynComputations`` has no forward dynamics (the
library's ``ArticulatedBodyAlgorithm`` is a free-floating one with gravity as link wrenches, not used) and no kinetic
energy: the drift, ctrl and total are solves of its own ``M`` and ``h`` (eq. 9), the kinetic energy is not supplied.
NOT COMPARED: MJCF files (iDynTree's ``ModelLoader`` reads URDF only); a model with constraint rows
(a URDF ``<mimic>``: iDynTree ignores the tag); a URDF ``floating`` joint elsewhere than alone below the root link;
a joint iDynTree reads as another type.
"""

from __future__ import annotations

import xml.etree.ElementTree as ET
from collections import deque
from dataclasses import dataclass
from importlib import metadata

import idyntree.swig as idt
import numpy as np

from cases.configuration import rotation
from crosscheck.adapters.base import (BODY_TWIST, Adapter, Terms, in_ours, scene_gravity,
                                      urdf_without_geometry, velocity_map)
from formalisms.interface import ModelNotSupported


def _homogeneous(R, p) -> np.ndarray:
    H = np.eye(4)
    H[:3, :3], H[:3, 3] = R, p
    return H


def _transform(H: np.ndarray):
    """iDynTree's Transform of a homogeneous matrix."""
    return idt.Transform(idt.Rotation.FromPython(np.ascontiguousarray(H[:3, :3])),
                         idt.Position.FromPython(np.ascontiguousarray(H[:3, 3])))


@dataclass(frozen=True)
class _Built:
    """One scene's KinDynComputations and where each of crosscheck's bodies' velocities sits in iDynTree's."""

    kd: object
    model: object
    base_H_root: np.ndarray      # the root link's frame in the base link (identity unless the root link is a frame)
    world_H_F: np.ndarray        # a free base's joint frame in the file's world (a URDF floating joint's origin)
    dof: tuple[int, ...]         # iDynTree's velocity index of each body's joint (the base's is 0)
    mass: float
    free: bool                   # body 0 is on a free joint (--base free, or the file's floating joint)


class IDynTree(Adapter):
    """The iDynTree adapter (module docstring)."""

    simulator = "idyntree"
    KINDS = ("urdf",)
    DEFAULTS: dict[str, str] = {}

    @staticmethod
    def library() -> str:
        return f"iDynTree {metadata.version('idyntree')}"

    def build(self, scene) -> _Built:
        """The scene's KinDynComputations: the file's full model (fixed joints kept), the base the link that carries
        the root link's frame, the body-fixed representation; crosscheck's joints found by name, types checked."""
        text, root_name, world_H_F = urdf_without_geometry(scene.path), scene.root_link, np.eye(4)
        if any(kind == "free" and name is not None for kind, name in zip(scene.joints, scene.joint_names)):
            text, world_H_F = self._unfloated(text, scene)
            root_name = scene.bodies[0]
        loader = idt.ModelLoader()
        if not loader.loadModelFromString(text) or loader.model().getNrOfLinks() == 0:
            raise ModelNotSupported(f"{self.library()} does not load '{scene.path}' (its parser's messages are on "
                                    "stderr)")
        model = loader.model().copy()
        root = model.getFrameIndex(root_name)
        if root < 0:
            raise ModelNotSupported(f"iDynTree's model of '{scene.path}' has no frame '{root_name}'")
        base = model.getFrameLink(root)
        base_H_root = model.getFrameTransform(root).asHomogeneousTransform().toNumPy()
        kd = idt.KinDynComputations()
        if not kd.loadRobotModel(model):
            raise ModelNotSupported(f"iDynTree's KinDynComputations does not take its model of '{scene.path}'")
        kd.setFrameVelocityRepresentation(idt.BODY_FIXED_REPRESENTATION)
        kd.setFloatingBase(model.getLinkName(base))
        dof = []
        for body, kind, name in zip(scene.bodies, scene.joints, scene.joint_names):
            if kind == "free":
                dof.append(0)
                continue
            index = model.getJointIndex(name)
            if index < 0:
                raise ModelNotSupported(f"iDynTree's model of '{scene.path}' has no joint '{name}'")
            joint = model.getJoint(index)
            links = {model.getLinkName(joint.getFirstAttachedLink()), model.getLinkName(joint.getSecondAttachedLink())}
            kinds = {"revolute": joint.isRevoluteJoint(), "prismatic": joint.isPrismaticJoint()}
            if not kinds.get(kind, False) or body not in links:
                raise ModelNotSupported(f"iDynTree reads joint '{name}' of '{scene.path}' as another type than "
                                        f"crosscheck's {kind} moving '{body}'")
            dof.append(6 + joint.getDOFsOffset())
        if model.getNrOfDOFs() + (6 if "free" in scene.joints else 0) != scene.nv:
            raise ModelNotSupported(f"iDynTree's model of '{scene.path}' has {model.getNrOfDOFs()} joint velocities, "
                                    f"the scene {scene.nv}")
        free = bool(scene.joints) and scene.joints[0] == "free"
        mass = model.getTotalMass() - (0.0 if free else self._welded_mass(model, base))
        return _Built(kd, model, base_H_root, world_H_F, tuple(dof), float(mass), free)

    @staticmethod
    def _unfloated(text: str, scene) -> tuple[str, np.ndarray]:
        """A URDF whose root link hangs the base by a ``floating`` joint (iDynTree's parser does not hold one) without
        that root link and joint, and the joint's frame F in the file's world (its ``<origin>``): the base then floats
        from F. Only a floating joint from a root link with no other joint is taken so (else ModelNotSupported)."""
        robot = ET.fromstring(text)
        joints = robot.findall("joint")
        floating = [j for j in joints if j.get("type") == "floating"]
        hanging = [j for j in joints if j.find("parent").get("link") == scene.root_link]
        if scene.joints[0] != "free" or len(floating) != 1 or hanging != floating \
                or floating[0].get("name") != scene.joint_names[0]:
            raise ModelNotSupported(f"'{scene.path}' has a floating joint, which iDynTree's URDF parser does not hold, "
                                    "elsewhere than alone below its root link")
        origin = floating[0].find("origin")
        xyz = [float(x) for x in (origin.get("xyz") if origin is not None and origin.get("xyz") else "0 0 0").split()]
        rpy = [float(x) for x in (origin.get("rpy") if origin is not None and origin.get("rpy") else "0 0 0").split()]
        robot.remove(floating[0])
        for link in robot.findall("link"):
            if link.get("name") == scene.root_link:
                robot.remove(link)
        R = idt.Rotation.RPY(*rpy).toNumPy()
        return ET.tostring(robot, encoding="unicode"), _homogeneous(R, np.array(xyz))

    @staticmethod
    def _welded_mass(model, base: int) -> float:
        """The mass of the base link and of every link welded to it by fixed joints (they do not move)."""
        seen, todo = {base}, deque([base])
        while todo:
            link = todo.popleft()
            for k in range(model.getNrOfNeighbors(link)):
                neighbor = model.getNeighbor(link, k)
                if neighbor.neighborLink not in seen and model.getJoint(neighbor.neighborJoint).getNrOfDOFs() == 0:
                    seen.add(neighbor.neighborLink)
                    todo.append(neighbor.neighborLink)
        return sum(model.getLink(link).getInertia().getMass() for link in seen)

    def terms(self, b: _Built, scene, q, qd, tau) -> Terms:
        """``M``, ``h``, ``g`` of the free-floating model at the state (the joint block on a fixed base)."""
        free, n = b.free, b.model.getNrOfDOFs()
        offset = 0 if free else 6                       # a fixed base's joints without the base's 6 velocities
        T, c = velocity_map(scene, q, qd, [d - offset for d in b.dof], BODY_TWIST)
        s = np.zeros(n)
        for i, kind in enumerate(scene.joints):
            if kind != "free":
                s[b.dof[i] - 6] = q[scene.q_index[i]]
        if free:
            iv = scene.v_index[0]
            T[0:6, iv:iv + 6] = self._adjoint(b.base_H_root)
            iq = scene.q_index[0]
            world_H_root = _homogeneous(scene.rotation, scene.translation) @ b.world_H_F @ \
                _homogeneous(rotation(q[iq + 3:iq + 7]), q[iq:iq + 3])
        else:
            world_H_root = _homogeneous(scene.rotation, scene.translation)
        v_L = np.concatenate([np.zeros(offset), T @ qd])            # (base twist, joint velocities)
        b.kd.setRobotState(_transform(world_H_root @ np.linalg.inv(b.base_H_root)), idt.VectorDynSize.FromPython(s),
                           idt.Twist.FromPython(v_L[:6]), idt.VectorDynSize.FromPython(v_L[6:]),
                           idt.Vector3.FromPython(scene_gravity(scene)))
        M_L = idt.MatrixDynSize(6 + n, 6 + n)
        b.kd.getFreeFloatingMassMatrix(M_L)
        bias, gravity = idt.FreeFloatingGeneralizedTorques(b.model), idt.FreeFloatingGeneralizedTorques(b.model)
        b.kd.generalizedBiasForces(bias)
        b.kd.generalizedGravityForces(gravity)
        M_L, h_L, g_L = M_L.toNumPy(), self._stacked(bias), self._stacked(gravity)
        M, h, g = in_ours(T, c, M_L[offset:, offset:], h_L[offset:], g_L[offset:])
        return Terms(M, h, g, b.mass)

    @staticmethod
    def _stacked(forces) -> np.ndarray:
        """The base wrench (force, then torque) and the joint torques of a FreeFloatingGeneralizedTorques."""
        return np.concatenate([forces.baseWrench().toNumPy(), forces.jointTorques().toNumPy()])

    @staticmethod
    def _adjoint(base_H_root: np.ndarray) -> np.ndarray:
        """The body twist (linear, angular) of the base link of the root frame's body twist, rigidly attached."""
        R, p = base_H_root[:3, :3], base_H_root[:3, 3]
        A = np.zeros((6, 6))
        A[:3, :3], A[3:, 3:] = R, R
        A[:3, 3:] = np.array([[0.0, -p[2], p[1]], [p[2], 0.0, -p[0]], [-p[1], p[0], 0.0]]) @ R
        return A


BACKEND = IDynTree()
