"""The pybullet adapter (``crosscheck.adapters.pybullet``): pybullet reads the URDF itself and passes the gate on a
chain with every ``<inertial>``; what the gate finds in pybullet 3.2.7 as its users run it, each on a small file that
isolates it (a free base tilted about x and y: its inverse dynamics turns the base quaternion into Z-Y-X angles and
applies them as X-Y-Z; a fixed base turned relative to gravity: its inverse dynamics puts the base at the identity;
a link without ``<inertial>``: 1 kg and unit inertia); its one default left on; a deliberately broken copy named.
"""

from __future__ import annotations

import dataclasses

from pathlib import Path

import numpy as np
import pytest

import cases
from adapter_files import hints, outliers, quick_gate
from crosscheck.adapters.base import free_pose
from crosscheck.adapters.pybullet import BACKEND, PyBullet
from crosscheck.needs import pinocchio_scene, source_scene
from formalisms.interface import ModelNotSupported

ROOT = Path(__file__).resolve().parents[2]

#: A principal inertia (pybullet keeps it as it is) and a general one (pybullet diagonalizes it, to about 1e-10).
INERTIA = 'ixx="0.02" ixy="0" ixz="0" iyy="0.03" iyz="0" izz="0.025"'
GENERAL_INERTIA = 'ixx="0.02" ixy="0.001" ixz="-0.002" iyy="0.03" iyz="0.0015" izz="0.025"'
BOX = '<collision><geometry><box size="0.4 0.1 0.1"/></geometry></collision>'


def _link(name: str, mass: float, com: str, rpy: str = "0.1 -0.2 0.3", inertial: bool = True) -> str:
    body = (f'<inertial><origin xyz="{com}" rpy="{rpy}"/><mass value="{mass}"/><inertia {INERTIA}/></inertial>'
            if inertial else "")
    return f'<link name="{name}">{body}{BOX}</link>'


def _urdf(name: str, links: list[str], joints: list[str]) -> str:
    return "\n".join(['<?xml version="1.0"?>', f'<robot name="{name}">', *links, *joints, "</robot>", ""])


#: Three joints (revolute about an unaligned axis, continuous, prismatic), every link's <inertial> turned and off
#: its origin, its tensor on its principal axes, collision boxes (dropped: the inertias are the file's) and joint
#: damping (not in pybullet's dynamics).
CHAIN_JOINTS = [
    '<joint name="j_a" type="revolute"><parent link="base"/><child link="a"/><origin xyz="0 0 0.1" rpy="0.1 0.2 0.3"/>'
    '<axis xyz="0.6 0 0.8"/><limit lower="-2" upper="2" effort="10" velocity="5"/><dynamics damping="0.7"/></joint>',
    '<joint name="j_b" type="continuous"><parent link="a"/><child link="b"/><origin xyz="0.3 0 0" rpy="0.3 0 0"/>'
    '<axis xyz="0 1 0"/><dynamics damping="0.4"/></joint>',
    '<joint name="j_c" type="prismatic"><parent link="b"/><child link="c"/><origin xyz="0 0.2 0" rpy="0 0.4 0"/>'
    '<axis xyz="1 0 0"/><limit lower="-0.1" upper="0.1" effort="10" velocity="5"/></joint>',
]
CHAIN = _urdf("chain", ['<link name="base"/>', _link("a", 1.5, "0.1 0 0"), _link("b", 0.8, "0 0.1 0.02"),
                        _link("c", 0.4, "0.02 0 0.03")], CHAIN_JOINTS)
#: The chain with general inertia tensors, which pybullet diagonalizes (threshold 1e-6).
GENERAL = CHAIN.replace(INERTIA, GENERAL_INERTIA)
#: The chain with its root link's <inertial> turned: pybullet's fixed base is that inertial frame, put at the identity.
TURNED_ROOT = CHAIN.replace('<link name="base"/>', _link("base", 2.0, "0.05 0 0", rpy="0.4 0.3 0"))
#: The chain ending in a tool frame without <inertial>: massless to the file, 1 kg with unit inertia to pybullet.
TOOL = CHAIN.replace("</robot>", '<link name="tool"/><joint name="tool_mount" type="fixed"><parent link="c"/>'
                                 '<child link="tool"/><origin xyz="0.3 0 0"/></joint></robot>')
#: A torso (its <inertial> off its origin and turned) with two legs, for a free base.
TORSO = _urdf("torso", [_link("torso", 3.0, "0.05 -0.02 0.03", rpy="0.2 0.1 -0.3"), _link("l1", 0.5, "0 0 -0.1"),
                        _link("l2", 0.3, "0 0 -0.1")], [
    '<joint name="hip" type="revolute"><parent link="torso"/><child link="l1"/><origin xyz="0.2 0.1 0" rpy="0 0.3 0"/>'
    '<axis xyz="1 0 0"/><limit lower="-2" upper="2" effort="10" velocity="5"/></joint>',
    '<joint name="knee" type="revolute"><parent link="l1"/><child link="l2"/><origin xyz="0 0 -0.2"/>'
    '<axis xyz="0 1 0"/><limit lower="-2" upper="2" effort="10" velocity="5"/></joint>'])


def _file(tmp_path, text: str, name: str = "robot.urdf") -> str:
    path = tmp_path / name
    path.write_text(text)
    return str(path)


def _reference(model, q, qd):
    """Pinocchio's M, h and g (crba, rnea, generalized gravity) of the model's file, in our coordinates."""
    import pinocchio as pin

    s = pinocchio_scene(model, "test")
    qp, vp = s.configuration(q), s.velocity(qd)
    M = np.array(pin.crba(s.model, s.data, qp))
    M = np.triu(M) + np.triu(M, 1).T
    return (s.ours_matrix(M), s.ours(pin.rnea(s.model, s.data, qp, vp, 0 * vp)),
            s.ours(pin.computeGeneralizedGravity(s.model, s.data, qp)))


def test_pybullet_passes_on_a_chain_with_every_inertial(tmp_path):
    """Turned, off-origin inertias (diagonalized by pybullet), an unaligned axis, a prismatic joint, damping in the
    file and collision boxes: pybullet agrees with the five formalisms and Pinocchio on the unmoved scene."""
    code, text = quick_gate(tmp_path, _file(tmp_path, CHAIN), "--simulator", "pybullet", "--frames", "0", isolated=True)
    assert code == 0 and "**PASS**" in text and "pinocchio, pybullet)" in text, text


def test_diagonalized_inertias_move_m_past_the_tolerance_and_pybullet_is_named(tmp_path):
    """pybullet turns each <inertial> onto its principal axes by Jacobi sweeps to a threshold of 1e-6: M moves by
    about 1e-10 relative, some ten times the tolerance on a small chain (1.67 times on z1)."""
    path = _file(tmp_path, GENERAL)
    model = cases.from_urdf(path, base="fixed")
    scene, q, qd = source_scene(model, "test"), np.array([0.3, -0.7, 0.05]), np.array([1.0, -2.0, 0.3])
    t = BACKEND.terms(BACKEND.built(scene), scene, q, qd, np.zeros(3))
    M = _reference(model, q, qd)[0]
    assert 1e-13 < np.linalg.norm(t.M - M) / np.linalg.norm(M) < 1e-8
    code, text = quick_gate(tmp_path, path, "--simulator", "pybullet", "--frames", "0")
    assert code == 1 and outliers(text) == {"pybullet"}, text
    assert any("mass matrix" in h or "M^-1 B u" in h for h in hints(text)), hints(text)


def test_a_fixed_base_turned_relative_to_gravity_is_caught_and_pybullet_named(tmp_path):
    """pybullet's inverse dynamics puts a fixed base at the identity and sets gravity in the world frame: the moved
    scenes (frame checks) and a root link with a turned <inertial> put gravity in a wrong frame; M agrees."""
    code, text = quick_gate(tmp_path, _file(tmp_path, CHAIN), "--simulator", "pybullet", "--frames", "1")
    assert code == 1 and outliers(text) == {"pybullet@g0"}, text
    assert all("the moved scene" in h for h in hints(text))

    path = _file(tmp_path, TURNED_ROOT, "turned_root.urdf")
    code, text = quick_gate(tmp_path, path, "--simulator", "pybullet", "--frames", "0")
    assert code == 1 and outliers(text) == {"pybullet"}, text
    assert any(h.endswith(": gravity") for h in hints(text)), hints(text)
    model = cases.from_urdf(path, base="fixed")
    scene, q, qd = source_scene(model, "test"), np.array([0.3, -0.7, 0.05]), np.array([1.0, -2.0, 0.3])
    t = BACKEND.terms(BACKEND.built(scene), scene, q, qd, np.zeros(3))
    M, h, g = _reference(model, q, qd)
    np.testing.assert_allclose(t.M, M, rtol=1e-9, atol=1e-12)
    np.testing.assert_allclose(t.h - t.g, h - g, rtol=1e-9, atol=1e-11)
    assert np.linalg.norm(t.g - g) > 0.05 * np.linalg.norm(g)


def _free_state(model, rotation: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    from crosscheck.adapters.pybullet import _quaternion

    q = np.array([0.1, -0.2, 0.3, *_quaternion(rotation), 0.4, -0.6])
    return q, np.array([0.3, -0.5, 0.2, 1.1, -0.7, 0.9, 1.5, -2.0])


def _rotation(axis: str, angle: float) -> np.ndarray:
    c, s = np.cos(angle), np.sin(angle)
    return {"x": np.array([[1, 0, 0], [0, c, -s], [0, s, c]]), "y": np.array([[c, 0, s], [0, 1, 0], [-s, 0, c]]),
            "z": np.array([[c, -s, 0], [s, c, 0], [0, 0, 1]])}[axis]


def test_a_free_base_tilted_about_x_and_y_has_gravity_wrong_and_pybullet_named(tmp_path):
    """A free base: pybullet's velocity (angular first, at the centre of mass, the classical acceleration) mapped in,
    M, h and g are Pinocchio's with the base's inertial frame turned about z alone; tilted about x and y, g is
    Pinocchio's at Rx(roll) Ry(pitch) Rz(yaw) of that frame's Z-Y-X angles (the quaternion's angles applied in the
    wrong order), M and C qd still agree; the gate fails with pybullet named and the hint at gravity."""
    path = _file(tmp_path, TORSO)
    model = cases.from_urdf(path, base="free")
    scene = source_scene(model, "test")
    built = BACKEND.built(scene)
    R_c = built.inertial[1]       # pybullet's base frame is the root link's inertial frame, turned by R_c
    q, qd = _free_state(model, _rotation("z", 0.7) @ R_c.T)          # that frame turned about z alone
    t = BACKEND.terms(built, scene, q, qd, np.zeros(8))
    for got, want in zip((t.M, t.h, t.g), _reference(model, q, qd)):
        np.testing.assert_allclose(got, want, rtol=1e-9, atol=1e-10)

    R = _rotation("x", 0.6) @ _rotation("y", -0.5) @ _rotation("z", 0.4)
    q, qd = _free_state(model, R)
    t = BACKEND.terms(built, scene, q, qd, np.zeros(8))
    M, h, g = _reference(model, q, qd)
    np.testing.assert_allclose(t.M, M, rtol=1e-9, atol=1e-10)
    np.testing.assert_allclose(t.h - t.g, h - g, rtol=1e-9, atol=1e-10)
    assert np.linalg.norm(t.g - g) > 0.1 * np.linalg.norm(g)
    yaw, pitch, roll = _zyx_angles(free_pose(scene, q, 0)[0] @ R_c)
    applied = _rotation("x", roll) @ _rotation("y", pitch) @ _rotation("z", yaw)
    q_applied, _ = _free_state(model, applied @ R_c.T)
    np.testing.assert_allclose(t.g, _reference(model, q_applied, qd)[2], rtol=1e-9, atol=1e-10)

    code, text = quick_gate(tmp_path, path, "--base", "free", "--simulator", "pybullet", "--frames", "0")
    assert code == 1 and outliers(text) == {"pybullet"}, text
    assert any(h.endswith(": gravity") for h in hints(text)), hints(text)


def _zyx_angles(R: np.ndarray) -> tuple[float, float, float]:
    """(yaw, pitch, roll) with ``R = Rz(yaw) Ry(pitch) Rx(roll)`` (Bullet's ``getEulerZYX``)."""
    return (float(np.arctan2(R[1, 0], R[0, 0])), float(np.arcsin(-np.clip(R[2, 0], -1, 1))),
            float(np.arctan2(R[2, 1], R[2, 2])))


def test_a_link_without_inertial_weighs_one_kg_and_pybullet_is_named(tmp_path):
    """The tool frame has no <inertial>: massless in the file, 1 kg with unit inertia in pybullet (its URDF parser's,
    no flag turns it off); the gate fails with pybullet named and the hint at the mass matrix."""
    path = _file(tmp_path, TOOL)
    scene = source_scene(cases.from_urdf(path, base="fixed"), "test")
    assert BACKEND.built(scene).mass == pytest.approx(1.5 + 0.8 + 0.4 + 1.0)
    code, text = quick_gate(tmp_path, path, "--simulator", "pybullet", "--frames", "0")
    assert code == 1 and outliers(text) == {"pybullet"}, text
    assert any("inertia / mass matrix" in h for h in hints(text)), hints(text)


def test_inertia_from_collision_left_on_is_named(tmp_path):
    """Without URDF_USE_INERTIA_FROM_FILE pybullet computes each inertia from the collision boxes: with the default
    named, the adapter keeps them and the gate names pybullet_with_inertia_from_collision."""
    code, text = quick_gate(tmp_path, _file(tmp_path, CHAIN), "--simulator", "pybullet:inertia_from_collision",
                       "--frames", "0")
    assert code == 1 and outliers(text) == {"pybullet_with_inertia_from_collision"}, text
    with pytest.raises(ValueError, match="no default 'damping'"):
        PyBullet(["damping"])


BROKEN = '''
import dataclasses
from crosscheck.adapters.pybullet import PyBullet


class Broken(PyBullet):
    """pybullet with its velocity terms dropped: h = g (a deliberate bug)."""

    simulator = "pybullet_broken"

    def terms(self, b, scene, q, qd, tau):
        t = super().terms(b, scene, q, qd, tau)
        return dataclasses.replace(t, h=t.g)


BACKEND = Broken()
'''


def test_a_broken_copy_is_caught_and_named(tmp_path):
    plugin = _file(tmp_path, BROKEN, "broken_pybullet.py")
    code, text = quick_gate(tmp_path, _file(tmp_path, CHAIN), "--plugin", f"{plugin}:BACKEND", "--frames", "0")
    assert code == 1 and outliers(text) == {"pybullet_broken"}, text
    assert any("velocity" in h for h in hints(text)), hints(text)


def test_mjcf_and_spherical_joints_are_not_compared(tmp_path):
    scene = source_scene(cases.from_urdf(_file(tmp_path, CHAIN), base="fixed"), "test")
    state = (np.zeros(3), np.zeros(3), np.zeros(3))
    with pytest.raises(ModelNotSupported, match="loadMJCF reads a subset of MJCF"):
        BACKEND.split(dataclasses.replace(scene, kind="mjcf"), *state)
    with pytest.raises(ModelNotSupported, match="spherical"):
        BACKEND.build(dataclasses.replace(scene, joints=("spherical", "revolute", "prismatic")))
