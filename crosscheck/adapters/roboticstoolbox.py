"""roboticstoolbox-python (Peter Corke's Robotics Toolbox) as a backend: its URDF reader (``URDF_file``, what
``rtb.Robot.URDF`` calls) builds a ``Robot`` of ETS links; ``inertia``, ``rne`` and ``gravload`` evaluate it.

    crosscheck gate --simulator roboticstoolbox --model robot.urdf   # or --plugin crosscheck.adapters.roboticstoolbox

Conventions (docs/simulators.md has the matrix of every adapter):

* no quaternions and no free base: rtb's dynamics (``Robot.rne``, ``inertia``, ``gravload``) are those of a fixed
  base, its velocities the joint rates; the scene's placement is ``robot.base = SE3(R, t)`` (``rne`` turns the
  world gravity it is given into the base frame, ``base.R.T @ gravity``) and the gravity passed is the scene's;
* joints are found by the link they move (rtb's link of the URDF's child link, ``isjoint``, its ``jindex``), the
  type checked; fixed URDF joints become static links (``isjoint`` False) that ``rne`` folds into the inertia of
  the nearest joint above them;
* inertias: the ``<inertial>`` tensor is turned into the link frame about the centre of mass (``Link.I``, ``r``); a
  link without ``<inertial>`` has no mass;
* ``rne`` is the Python recursion ``Robot.rne`` (the C ``frne`` is DHRobot's only), ``symbolic=False``, as users
  get it; ``inertia(q)`` is ``rne`` with unit accelerations, ``gravload`` ``rne`` at rest. ``rne`` also adds the
  motor's reflected inertia ``G^2 Jm qdd`` and subtracts its friction ``G^2 B qd + |G| Tc``: ``Jm`` and ``Tc`` are 0
  unless set in code and ``G`` (a ``<transmission>``'s ``mechanicalReduction``) only scales them, but ``B`` is read
  from the file.

Off unless named (:attr:`RoboticsToolbox.DEFAULTS`): ``friction`` (rtb reads a URDF joint's ``<dynamics
friction>``, a Coulomb friction, as the motor's viscous friction ``B``: ``rne`` then adds ``G^2 B qd`` to ``h``; the
adapter sets ``B = 0``). URDF ``<visual>`` and ``<collision>`` are dropped before rtb reads the file (it loads
every mesh, and ``package://`` ones are often not found).

NOT COMPARED (ModelNotSupported): a free base (``--base free``: rtb has no floating-base dynamics), an MJCF file (rtb
reads URDF and xacro only) and a model with constraint rows (a URDF ``<mimic>``: rtb ignores it).

What the gate finds (roboticstoolbox-python 1.5.0, the library as its users run it): ``Robot.rne`` groups each static
link with the joint above it, but

* drops the fixed transform between a static link and the next joint: a joint whose parent is a static link is
  placed from the joint above, as if the static link's own ``<origin>`` were the identity (z1's ``gripperStator``
  before ``jointGripper``: ``M`` off by up to 6 %, relative in the Frobenius norm over the gate's 20 states)::

      crosscheck gate --simulator roboticstoolbox --model z1.urdf --samples 20

* composes the static links of one group along the flat link list, not their own parent chain: static links side by
  side under one joint are placed one after the other (kinova's end effector and fingers under ``link_6``: ``M`` off
  by up to 3.6 %)::

      crosscheck gate --simulator roboticstoolbox --model kinova.urdf --samples 20

* reads a joint axis that is not a coordinate axis by turning the child's frame by the axis-angle of the axis
  vector (``angvec2r(|a|, a/|a|)``) and the joint about the new z, which moves the child's inertia and every origin
  below it;
* reverses a joint whose axis is a negative coordinate axis in its transform only (``ET.Rz(flip=True)`` for -z), not
  in the motion subspace ``rne`` uses: the gravity and velocity terms are off where ``M`` may still agree.

It agrees on ur5 and examples/arm.urdf.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import roboticstoolbox as rtb
from roboticstoolbox.models.URDF.URDFRobot import URDF_file
from spatialmath import SE3

from crosscheck.adapters.base import (Adapter, Terms, in_ours, scene_gravity, urdf_file_without_geometry,
                                      velocity_map)
from formalisms.interface import ModelNotSupported


@dataclass(frozen=True)
class _Built:
    """One scene's Robot and where each of crosscheck's bodies' joints sits in it."""

    robot: object
    jindex: tuple[int, ...]     # rtb's joint index of each body's joint
    mass: float                 # the mass the joints move


class RoboticsToolbox(Adapter):
    """The roboticstoolbox-python adapter (module docstring)."""

    simulator = "roboticstoolbox"
    KINDS = ("urdf",)
    DEFAULTS = {
        "friction": "a URDF joint's <dynamics friction> read as the motor's viscous friction B, a force -G^2 B qd "
                    "in rne",
    }

    @staticmethod
    def library() -> str:
        return f"roboticstoolbox-python {rtb.__version__}"

    def unsupported(self, scene) -> str:
        if scene.root == "free":
            return (f"{self.library()} has no floating-base dynamics (Robot.rne, inertia and gravload are a fixed "
                    "base's): a free base is not compared")
        if scene.kind == "mjcf":
            return f"{self.library()} reads URDF (and xacro) files only, not the MJCF file '{scene.path}'"
        return super().unsupported(scene)

    def build(self, scene) -> _Built:
        """The scene's Robot: the file read by rtb's URDF reader, placed by ``robot.base``, ``B = 0`` unless
        ``friction`` is named; crosscheck's joints found by the link they move, their types checked."""
        try:
            links, name, _ = URDF_file(urdf_file_without_geometry(scene.path))
            robot = rtb.Robot(links, name=name)
        except Exception as exc:            # rtb's reader raises URDFError, ValueError, RuntimeError...
            raise ModelNotSupported(f"roboticstoolbox-python cannot read '{scene.path}': {exc}") from None
        robot.base = SE3.Rt(np.asarray(scene.rotation, dtype=float), np.asarray(scene.translation, dtype=float))
        if "friction" not in self.on:
            for link in robot.links:
                link.B = 0.0
        by_name = {link.name: link for link in robot.links}
        jindex = []
        for body, joint in zip(scene.bodies, scene.joints):
            link = by_name.get(body)
            if link is None or not link.isjoint:
                raise ModelNotSupported(f"roboticstoolbox-python's model of '{scene.path}' has no link '{body}' "
                                        "moved by a joint")
            kind = "revolute" if link.isrevolute else "prismatic" if link.isprismatic else "?"
            if kind != joint:
                raise ModelNotSupported(f"roboticstoolbox-python reads the joint of link '{body}' in '{scene.path}' "
                                        f"as {kind}, crosscheck as {joint}")
            jindex.append(int(link.jindex))
        if robot.n != scene.nv:
            raise ModelNotSupported(f"roboticstoolbox-python's model of '{scene.path}' has {robot.n} joints, the "
                                    f"scene {scene.nv}")
        return _Built(robot, tuple(jindex), self._moved_mass(robot))

    @staticmethod
    def _moved_mass(robot) -> float:
        """The mass of the links a joint moves (a static link counts below a joint, not welded to the base)."""
        def moved(link) -> bool:
            while link is not None:
                if link.isjoint:
                    return True
                link = link.parent
            return False

        return float(sum(link.m or 0.0 for link in robot.links if moved(link)))

    def terms(self, b: _Built, scene, q, qd, tau) -> Terms:
        """``M`` (``inertia``), ``h`` (``rne`` at zero acceleration) and ``g`` (``gravload``), in rtb's joint order
        and back."""
        T, c = velocity_map(scene, q, qd, list(b.jindex))
        q_L, qd_L = T @ q, T @ qd                  # revolute and prismatic joints only: one coordinate each
        gravity = scene_gravity(scene)
        with self._lock:                            # one Robot per scene, shared by the threads of a process
            M_L = b.robot.inertia(q_L)
            h_L = b.robot.rne(q_L, qd_L, np.zeros_like(q_L), gravity=gravity)
            g_L = b.robot.gravload(q_L, gravity=gravity)
        M, h, g = in_ours(T, c, M_L, h_L, g_L)
        return Terms(M, h, g, b.mass)


BACKEND = RoboticsToolbox()
