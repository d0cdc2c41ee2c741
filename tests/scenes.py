"""Scenes the tests share that are not built-in cases."""

from __future__ import annotations

import cases
from cases.build import build_model


def panda_arm():
    """The Panda of the built-in case without its finger coupling (the URDF's ``<mimic>``, a ``JointCoupling``) and
    without its file source: the 9-joint 3-D tree for tests of a backend's unconstrained algorithms (inverse
    dynamics round trips, joint reactions, the energy rate, the task-space projector), which a constraint would
    change. The reference then builds it from these bodies, as for any model built in code."""
    panda = cases.load("panda")
    return build_model("panda_arm", panda.bodies, panda.gravity, input_map=panda.input_map,
                       task_points=panda.task_points)


def chain_urdf(path, joints) -> str:
    """Write a URDF chain to ``path`` and return it as a string: a base link and one link per joint (mass 1, COM 0.3 m
    along x, inertia 0.01 I), each joint ``(name, parent, child, type, limit XML)`` about y, 0.6 m along x."""
    links = "".join(f'<link name="{child}"><inertial><mass value="1"/><origin xyz="0.3 0 0"/><inertia ixx="0.01" '
                    'iyy="0.01" izz="0.01" ixy="0" ixz="0" iyz="0"/></inertial></link>' for _, _, child, _, _ in joints)
    text = '<robot name="r"><link name="base"/>' + links + "".join(
        f'<joint name="{n}" type="{t}"><parent link="{p}"/><child link="{c}"/><origin xyz="0.6 0 0"/>'
        f'<axis xyz="0 1 0"/>{limit}</joint>' for n, p, c, t, limit in joints) + "</robot>"
    path.write_text(text)
    return str(path)


DAMPED_INERTIA = 'ixx="0.02" ixy="0.001" ixz="-0.002" iyy="0.03" iyz="0.0015" izz="0.025"'
#: Three joints (revolute, continuous about an unaligned axis, prismatic) with limits, damping and friction in
#: <dynamics>, and collision geometry: everything a rigid-body backend must ignore and MuJoCo reads.
DAMPED_CHAIN = "\n".join([
    '<?xml version="1.0"?>', '<robot name="damped_chain">',
    '<link name="base"/>',
    *[f'<link name="{name}"><inertial><origin xyz="{com}" rpy="0.1 -0.2 0.3"/><mass value="{mass}"/>'
      f'<inertia {DAMPED_INERTIA}/></inertial><collision><geometry><box size="0.1 0.1 0.1"/></geometry></collision></link>'
      for name, mass, com in (("a", 1.5, "0.1 0 0"), ("b", 0.8, "0 0.1 0.02"), ("c", 0.4, "0.02 0 0.03"))],
    '<joint name="j_a" type="revolute"><parent link="base"/><child link="a"/><origin xyz="0 0 0.1" rpy="0.1 0.2 0.3"/>'
    '<axis xyz="0 0 1"/><limit lower="-0.5" upper="0.5" effort="10" velocity="5"/>'
    '<dynamics damping="0.7" friction="0.3"/></joint>',
    '<joint name="j_b" type="continuous"><parent link="a"/><child link="b"/><origin xyz="0.3 0 0" rpy="0.3 0 0"/>'
    '<axis xyz="0.6 0 0.8"/><dynamics damping="0.4"/></joint>',
    '<joint name="j_c" type="prismatic"><parent link="b"/><child link="c"/><origin xyz="0 0.2 0" rpy="0 0.4 0"/>'
    '<axis xyz="0 1 0"/><limit lower="-0.1" upper="0.1" effort="10" velocity="5"/><dynamics damping="0.2"/></joint>',
    "</robot>", ""])


#: An MJCF torso on a free joint placed above the world, a ball shoulder, a hinge and a slider.
LIMB_MJCF = """<mujoco model="limb">
  <worldbody>
    <body name="torso" pos="0 0 1">
      <freejoint name="root"/>
      <geom type="box" size="0.2 0.1 0.05" mass="3"/>
      <body name="upper" pos="0.2 0 0">
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
