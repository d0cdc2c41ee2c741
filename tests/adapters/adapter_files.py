"""Model files for the adapter tests (tests/adapters): small URDFs with what a simulator's defaults change."""

from __future__ import annotations

import re

import pytest

from pathlib import Path

ROOT = Path(__file__).resolve().parents[2]
ARM = str(ROOT / "examples" / "arm.urdf")


def _inertial(mass: float, xyz: str, rpy: str, moments: tuple) -> str:
    """An ``<inertial>``: ``moments`` are ixx, ixy, ixz, iyy, iyz, izz."""
    named = " ".join(f'{k}="{v}"' for k, v in zip(("ixx", "ixy", "ixz", "iyy", "iyz", "izz"), moments))
    return f'<inertial><origin xyz="{xyz}" rpy="{rpy}"/><mass value="{mass}"/><inertia {named}/></inertial>'


#: A torso on a free base (``--base free``) with a branch of three joints (revolute about an unaligned axis,
#: continuous, prismatic) and a tool frame: joint damping, a transmission whose motor has a rotor inertia and a gear
#: ratio (Drake's reflected inertia), limits, friction, collision geometry, and a foot whose inertia fails the
#: triangle inequality (izz > ixx + iyy: Drake's parser replaces it). Every rigid-body backend must ignore all but
#: the inertia as given.
WALKER = "\n".join([
    '<?xml version="1.0"?>',
    '<robot name="walker" xmlns:drake="http://drake.mit.edu">',
    f'<link name="torso">{_inertial(4.0, "0.02 -0.01 0.05", "0.1 0.2 -0.1", (0.08, 0.004, -0.003, 0.06, 0.002, 0.05))}'
    '<collision><geometry><box size="0.3 0.2 0.2"/></geometry></collision></link>',
    f'<link name="thigh">{_inertial(1.2, "0 0.01 -0.15", "0 0 0", (0.01, 0, 0.001, 0.012, 0, 0.003))}</link>',
    f'<link name="shin">{_inertial(0.7, "0.01 0 -0.12", "0.2 0 0", (0.005, 0.0002, 0, 0.006, 0, 0.0015))}</link>',
    f'<link name="foot">{_inertial(0.4, "0.03 0 0", "0 0 0", (0.001, 0, 0, 0.0012, 0, 0.004))}</link>',
    '<link name="tool"/>',
    '<joint name="hip" type="revolute"><parent link="torso"/><child link="thigh"/>'
    '<origin xyz="0.1 0.05 -0.1" rpy="0.2 0 0.1"/><axis xyz="0.6 0.8 0"/>'
    '<limit lower="-1.2" upper="1.2" effort="40" velocity="6"/><dynamics damping="0.8" friction="0.2"/></joint>',
    '<joint name="knee" type="continuous"><parent link="thigh"/><child link="shin"/>'
    '<origin xyz="0 0 -0.3" rpy="0 0.3 0"/><axis xyz="0 1 0"/><dynamics damping="0.4"/></joint>',
    '<joint name="ankle" type="prismatic"><parent link="shin"/><child link="foot"/>'
    '<origin xyz="0 0 -0.25"/><axis xyz="0 0 1"/><limit lower="-0.05" upper="0.05" effort="40" velocity="1"/></joint>',
    '<joint name="tool_mount" type="fixed"><parent link="foot"/><child link="tool"/><origin xyz="0.1 0 0"/></joint>',
    '<transmission name="knee_transmission"><type>transmission_interface/SimpleTransmission</type>'
    '<joint name="knee"><hardwareInterface>EffortJointInterface</hardwareInterface></joint>'
    '<actuator name="knee_motor"><drake:rotor_inertia value="0.002"/><drake:gear_ratio value="8"/></actuator>'
    '</transmission>',
    "</robot>", ""])

#: A two-joint arm bolted to a link named ``world`` (as ur5's and z1's files are): Drake's parser takes a link so
#: named for its own world, iDynTree turns it into a frame of the base link.
IN_WORLD = "\n".join([
    '<?xml version="1.0"?>',
    '<robot name="in_world">',
    '<link name="world"/>',
    f'<link name="base_link">{_inertial(2.0, "0 0 0.05", "0 0 0", (0.01, 0, 0, 0.01, 0, 0.01))}</link>',
    f'<link name="upper">{_inertial(1.0, "0.1 0 0.02", "0 0.1 0", (0.002, 0.0001, 0, 0.008, 0, 0.008))}</link>',
    f'<link name="lower">{_inertial(0.5, "0.12 0 0", "0 0 0", (0.001, 0, 0, 0.004, 0, 0.004))}</link>',
    '<joint name="world_joint" type="fixed"><parent link="world"/><child link="base_link"/>'
    '<origin xyz="0.2 -0.1 0.3" rpy="0 0 0.5"/></joint>',
    '<joint name="shoulder" type="revolute"><parent link="base_link"/><child link="upper"/>'
    '<origin xyz="0 0 0.1" rpy="0.3 0 0"/><axis xyz="0 1 0"/><limit lower="-2" upper="2" effort="10" velocity="5"/>'
    '</joint>',
    '<joint name="elbow" type="continuous"><parent link="upper"/><child link="lower"/>'
    '<origin xyz="0.25 0 0"/><axis xyz="0 0.6 0.8"/></joint>',
    "</robot>", ""])


def write(tmp_path, name: str, text: str) -> str:
    path = tmp_path / name
    path.write_text(text)
    return str(path)

#: An MJCF arm: a hinge on a body hanging from the world (placed in the file) and a slider.
MJCF_ARM = """<mujoco model="mjcf_arm">
  <worldbody>
    <body name="upper" pos="0.3 0 0.5" euler="0 0.4 0.2">
      <joint name="shoulder" type="hinge" axis="1 0 0"/>
      <geom type="capsule" fromto="0 0 0 0 0 -0.3" size="0.03" mass="0.7"/>
      <body name="tip" pos="0 0 -0.3">
        <joint name="slide" type="slide" axis="0 0 1"/>
        <geom type="sphere" size="0.05" mass="0.2"/>
      </body>
    </body>
  </worldbody>
</mujoco>
"""

#: An MJCF torso on a ``<freejoint>`` (placed in the file), a ball shoulder (turned in the file), a hinge elbow and
#: a slider. (Not the torso turned: Pinocchio 4.1's MJCF parser drops a free body's rotation, which MuJoCo and Drake
#: both read.)
MJCF_LIMB = """<mujoco model="mjcf_limb">
  <worldbody>
    <body name="torso" pos="0.1 0 1">
      <freejoint name="root"/>
      <geom type="box" size="0.2 0.1 0.05" mass="3"/>
      <body name="upper" pos="0.2 0 0" euler="30 0 20">
        <joint name="shoulder" type="ball"/>
        <geom type="capsule" fromto="0 0 0 0 0 -0.3" size="0.03" mass="0.5"/>
        <body name="lower" pos="0 0 -0.3">
          <joint name="elbow" type="hinge" axis="0 1 0"/>
          <geom type="capsule" fromto="0 0 0 0 0 -0.25" size="0.025" mass="0.3"/>
          <body name="slider" pos="0 0 -0.25">
            <joint name="s" type="slide" axis="1 0 0"/>
            <geom type="sphere" size="0.02" mass="0.1"/>
          </body>
        </body>
      </body>
    </body>
  </worldbody>
</mujoco>
"""

#: The walker's torso on a URDF ``floating`` joint from a ``world`` link, placed by the joint's origin (Drake's and
#: iDynTree's parsers hold no floating joint: the adapters make it).
FLOATING = WALKER.replace('<link name="torso">', '<link name="world"/><joint name="float" type="floating">'
                          '<parent link="world"/><child link="torso"/><origin xyz="0.1 0.2 0.8" rpy="0.3 0.2 0.1"/>'
                          '</joint><link name="torso">')


def outliers(text: str) -> set[str]:
    """Every outlier a gate report names."""
    return set(re.findall(r"outlier \*\*([^*]+)\*\*", text))


def closeness_row(text: str, backend: str) -> dict[str, str]:
    """The report's "How close each backend came" row of ``backend``, by column."""
    lines = text.splitlines()
    header = next(line for line in lines if line.startswith("| backend |"))
    row = next(line for line in lines if line.startswith(f"| {backend} |"))
    return dict(zip([c.strip() for c in header.split("|")[1:-1]], [c.strip() for c in row.split("|")[1:-1]]))


#: The gate as a user runs it, a few states, the linearization and the charts left out (time).
QUICK = ["--samples", "3", "--quiet", "--no-linearization", "--no-charts", "--no-self-test"]


def quick_gate(tmp_path, path: str, *args: str, isolated: bool = False) -> tuple[int, str]:
    """The :data:`QUICK` gate's exit code and report; the adapter in the gate's process unless ``isolated`` (its own
    child process, as a user runs it: a second import of the library, some seconds)."""
    from crosscheck import cli, isolation
    from crosscheck.reports import gate_summary

    report = tmp_path / "gate.md"
    with pytest.MonkeyPatch.context() as patch:
        patch.setenv(isolation.ENV, "1" if isolated else "0")
        code = cli.main(["gate", "--model", path, *QUICK, "--report", str(report), *args])
    return code, gate_summary.read(report)


def hints(text: str) -> list[str]:
    """The hint lines of a gate report."""
    return [line for line in text.splitlines() if line.startswith("- hint:")]
