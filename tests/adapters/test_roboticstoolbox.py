"""The roboticstoolbox-python adapter (``crosscheck.adapters.roboticstoolbox``): rtb reads the URDF itself and passes
the gate, moved scenes included, on a chain with every ``<inertial>``; what the gate finds in rtb 1.5.0 as its users
run it, each on a small file that isolates it (``Robot.rne`` drops the fixed transform of a static link before a
joint, and places static links side by side along the flat link list; the reader turns the child frame of a joint
whose axis is no coordinate axis, and reverses a negative axis in the transform only); its one default left on; a
free base and an MJCF not compared; a deliberately broken copy named.
"""

from __future__ import annotations

import dataclasses


import numpy as np
import pytest

import cases
from adapter_files import hints, outliers, quick_gate
from crosscheck.adapters.roboticstoolbox import BACKEND, RoboticsToolbox
from crosscheck.needs import source_scene
from formalisms.interface import ModelNotSupported


INERTIA = 'ixx="0.02" ixy="0.001" ixz="-0.002" iyy="0.03" iyz="0.0015" izz="0.025"'


def _link(name: str, mass: float, com: str) -> str:
    return (f'<link name="{name}"><inertial><origin xyz="{com}" rpy="0.1 -0.2 0.3"/><mass value="{mass}"/>'
            f'<inertia {INERTIA}/></inertial></link>')


def _joint(name: str, kind: str, parent: str, child: str, xyz: str, rpy: str = "0 0 0", axis: str = "0 0 1",
           extra: str = "") -> str:
    limit = '<limit lower="-2" upper="2" effort="10" velocity="5"/>' if kind in ("revolute", "prismatic") else ""
    axis = f'<axis xyz="{axis}"/>' if kind != "fixed" else ""
    return (f'<joint name="{name}" type="{kind}"><parent link="{parent}"/><child link="{child}"/>'
            f'<origin xyz="{xyz}" rpy="{rpy}"/>{axis}{limit}{extra}</joint>')


def _urdf(links: list[str], joints: list[str]) -> str:
    return "\n".join(['<?xml version="1.0"?>', '<robot name="robot">', '<link name="base"/>', *links, *joints,
                      "</robot>", ""])


#: Three joints on coordinate axes (revolute, continuous, prismatic) with turned origins, general inertias off their
#: links' origins, and <dynamics friction> (a viscous B to rtb, set to 0 by the adapter).
CHAIN = _urdf([_link("a", 1.5, "0.1 0 0"), _link("b", 0.8, "0 0.1 0.02"), _link("c", 0.4, "0.02 0 0.03")], [
    _joint("j_a", "revolute", "base", "a", "0 0 0.1", "0.1 0.2 0.3", extra='<dynamics friction="0.6"/>'),
    _joint("j_b", "continuous", "a", "b", "0.3 0 0", "0.3 0 0", "0 1 0", extra='<dynamics friction="0.4"/>'),
    _joint("j_c", "prismatic", "b", "c", "0 0.2 0", "0 0.4 0", "1 0 0")])
#: A static link with its own <origin> between two joints (z1's gripperStator before jointGripper).
STATIC_BEFORE_JOINT = _urdf([_link("a", 1.5, "0.1 0 0"), _link("s", 0.5, "0 0.05 0"), _link("b", 0.8, "0.1 0 0")], [
    _joint("j_a", "revolute", "base", "a", "0 0 0.1"),
    _joint("weld", "fixed", "a", "s", "0.3 0.1 0", "0.4 0 0.2"),
    _joint("j_b", "revolute", "s", "b", "0.1 0 0.05", axis="0 1 0")])
#: Two static links side by side under one joint (kinova's end effector and fingers under link_6).
SIDE_BY_SIDE = _urdf([_link("a", 1.5, "0.1 0 0"), _link("b", 0.8, "0.1 0 0"), _link("f1", 0.3, "0.02 0 0"),
                      _link("f2", 0.3, "0 0.02 0")], [
    _joint("j_a", "revolute", "base", "a", "0 0 0.1"),
    _joint("j_b", "revolute", "a", "b", "0.3 0 0", axis="0 1 0"),
    _joint("w1", "fixed", "b", "f1", "0.2 0.05 0", "0 0 0.5"),
    _joint("w2", "fixed", "b", "f2", "0.2 -0.05 0.1", "0.3 0 0")])
#: The chain with its second axis reversed, and with it not on a coordinate axis.
NEGATIVE_AXIS = CHAIN.replace('<axis xyz="0 1 0"/>', '<axis xyz="0 -1 0"/>')
OBLIQUE_AXIS = CHAIN.replace('<axis xyz="0 1 0"/>', '<axis xyz="0 0.6 0.8"/>')


def _file(tmp_path, text: str, name: str = "robot.urdf") -> str:
    path = tmp_path / name
    path.write_text(text)
    return str(path)


def test_roboticstoolbox_passes_on_a_chain_moved_scenes_included(tmp_path):
    """Turned origins, general inertias off the links' origins, a prismatic joint; the moved scenes (robot.base and
    gravity turned with it) and the file's <dynamics friction> (B, set to 0): rtb agrees."""
    code, text = quick_gate(tmp_path, _file(tmp_path, CHAIN), "--simulator", "roboticstoolbox", "--frames", "1",
                       isolated=True)
    assert code == 0 and "**PASS**" in text and "pinocchio, roboticstoolbox)" in text, text


@pytest.mark.parametrize("urdf", [STATIC_BEFORE_JOINT, SIDE_BY_SIDE], ids=["static_link_before_a_joint",
                                                                          "static_links_side_by_side"])
def test_rne_misplacing_static_links_is_caught_and_roboticstoolbox_named(tmp_path, urdf):
    """rtb's rne places a joint below a static link from the joint above it (the static link's origin dropped) and
    static links side by side one after the other: M is off, rtb is named, the hint at the mass matrix."""
    code, text = quick_gate(tmp_path, _file(tmp_path, urdf), "--simulator", "roboticstoolbox", "--frames", "0")
    assert code == 1 and outliers(text) == {"roboticstoolbox"}, text
    assert any("inertia / mass matrix" in h for h in hints(text)), hints(text)


@pytest.mark.parametrize("urdf", [NEGATIVE_AXIS, OBLIQUE_AXIS], ids=["negative_axis", "oblique_axis"])
def test_rtb_reading_of_joint_axes_is_caught_and_roboticstoolbox_named(tmp_path, urdf):
    """An axis -y: rtb reverses the joint's transform (ET.Ry(flip=True)) but not the motion subspace rne uses; an
    axis (0, 0.6, 0.8): rtb turns the child's frame by the axis-angle of that vector. Both are named."""
    code, text = quick_gate(tmp_path, _file(tmp_path, urdf), "--simulator", "roboticstoolbox", "--frames", "0")
    assert code == 1 and outliers(text) == {"roboticstoolbox"}, text


def test_friction_left_on_is_named_with_a_force_linear_in_qd(tmp_path):
    """rtb reads <dynamics friction> as the motor's viscous friction B: left on, rne adds B qd to h, the gate names
    roboticstoolbox_with_friction and hints at a force linear in qd."""
    code, text = quick_gate(tmp_path, _file(tmp_path, CHAIN), "--simulator", "roboticstoolbox:friction", "--frames", "0")
    assert code == 1 and outliers(text) == {"roboticstoolbox_with_friction"}, text
    assert any("a force linear in qd" in h for h in hints(text)), hints(text)
    with pytest.raises(ValueError, match="no default 'damping'"):
        RoboticsToolbox(["damping"])


BROKEN = '''
import dataclasses
from crosscheck.adapters.roboticstoolbox import RoboticsToolbox


class Broken(RoboticsToolbox):
    """roboticstoolbox with gravity's sign flipped: g -> -g in h and g (a deliberate bug)."""

    simulator = "roboticstoolbox_broken"

    def terms(self, b, scene, q, qd, tau):
        t = super().terms(b, scene, q, qd, tau)
        return dataclasses.replace(t, h=t.h - 2 * t.g, g=-t.g)


BACKEND = Broken()
'''


def test_a_broken_copy_is_caught_and_named(tmp_path):
    plugin = _file(tmp_path, BROKEN, "broken_roboticstoolbox.py")
    code, text = quick_gate(tmp_path, _file(tmp_path, CHAIN), "--plugin", f"{plugin}:BACKEND", "--frames", "0")
    assert code == 1 and outliers(text) == {"roboticstoolbox_broken"}, text
    assert any(h.endswith(": gravity") for h in hints(text)), hints(text)


def test_a_free_base_and_an_mjcf_are_not_compared(tmp_path):
    """rtb has no floating-base dynamics and reads no MJCF: NOT COMPARED, saying why; the gate with the adapter
    optional passes on a free base without it."""
    path = _file(tmp_path, CHAIN.replace('<link name="base"/>', _link("base", 2.0, "0 0 0.05")))
    scene = source_scene(cases.from_urdf(path, base="fixed"), "test")
    state = (np.zeros(3), np.zeros(3), np.zeros(3))
    with pytest.raises(ModelNotSupported, match="no floating-base dynamics"):
        BACKEND.split(dataclasses.replace(scene, root="free"), *state)
    with pytest.raises(ModelNotSupported, match="URDF \\(and xacro\\) files only"):
        BACKEND.split(dataclasses.replace(scene, kind="mjcf"), *state)
    code, text = quick_gate(tmp_path, path, "--base", "free", "--simulator", "roboticstoolbox", "--optional",
                       "roboticstoolbox", "--frames", "0")
    assert code == 0 and "roboticstoolbox not compared" in text, text
