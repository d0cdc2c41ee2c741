"""Task points: the default avoids joint axes and moves in its task directions, ``--task-point`` sets one, bad input
is refused with what is valid, and the gate report says which point was used and why a backend broke down.

Expected values are by hand: a planar two-link chain of unit links about the world y axis, hanging along -z."""

from __future__ import annotations

import warnings

import numpy as np
import pytest

from cases import Body, TaskPoint, build_model
from cases import build
from cases import task
from cases.urdf import from_urdf
from crosscheck import cli
from crosscheck.reports import gate_summary

URDF = """<?xml version="1.0"?>
<robot name="double_pendulum_continuous">
  <link name="base"/>
  <link name="link1"><inertial><origin xyz="0 0 -0.5"/><mass value="1"/>
    <inertia ixx="0.01" ixy="0" ixz="0" iyy="0.01" iyz="0" izz="0.001"/></inertial></link>
  <link name="link2"><inertial><origin xyz="0 0 -0.5"/><mass value="1"/>
    <inertia ixx="0.01" ixy="0" ixz="0" iyy="0.01" iyz="0" izz="0.001"/></inertial></link>
  <joint name="j1" type="continuous"><parent link="base"/><child link="link1"/><axis xyz="0 1 0"/></joint>
  <joint name="j2" type="continuous"><parent link="link1"/><child link="link2"/><origin xyz="0 0 -1"/>
    <axis xyz="0 1 0"/></joint>
</robot>
"""


@pytest.fixture
def urdf_path(tmp_path):
    path = tmp_path / "double_pendulum_continuous.urdf"
    path.write_text(URDF)
    return path


def _chain(com2=(0.0, 0.0, -0.5)) -> list[Body]:
    inertia = np.diag([0.01, 0.01, 0.001])
    return [Body("link1", None, "revolute", (0.0, 1.0, 0.0), 1.0, com=(0.0, 0.0, -0.5), inertia=inertia),
            Body("link2", "link1", "revolute", (0.0, 1.0, 0.0), 1.0, com=com2, inertia=inertia,
                 translation=(0.0, 0.0, -1.0))]


def test_point_jacobian_of_a_planar_two_link_chain_is_the_closed_form():
    # tip at p = (-sin t1 - sin(t1 + t2), 0, -cos t1 - cos(t1 + t2)) for rotations about +y of the -z hanging links
    model = build_model("chain", _chain(), task_points=[TaskPoint("tip", "link2", (0.0, 0.0, -1.0))])
    t1, t2 = 0.4, -1.1
    J = task.point_jacobian(model, [t1, t2], "link2", [0.0, 0.0, -1.0])
    c1, c12 = np.cos(t1), np.cos(t1 + t2)
    s1, s12 = np.sin(t1), np.sin(t1 + t2)
    expected = np.array([[-c1 - c12, -c12], [0.0, 0.0], [s1 + s12, s12]])
    np.testing.assert_allclose(J, expected, atol=1e-14)


def test_a_point_on_a_joint_axis_is_found_and_the_default_moves_off_it():
    on_axis = build_model("chain", _chain(com2=(0.0, 0.3, 0.0)))  # the leaf's COM on its own joint's axis
    assert task.axes_through(on_axis, "link2", [0.0, 0.3, 0.0]) == ["the axis of joint 'link2'"]
    tp = on_axis.task_point()
    assert tp.name == "tip" and task.axes_through(on_axis, tp.body, tp.offset) == []
    assert "passed over: the centre of mass of the last body 'link2' (on the axis of joint 'link2')" in tp.choice
    np.testing.assert_array_equal(tp.directions, [[1.0, 0.0, 0.0], [0.0, 0.0, 1.0]])  # the x-z plane it moves in
    assert task.rank_deficiency(on_axis, [0.4, -1.1]) is None


def test_the_urdf_default_is_not_on_the_leaf_joint_axis(urdf_path):
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        model = from_urdf(urdf_path)
    tp = model.task_point()
    assert (tp.name, tp.body) == ("link2:com", "link2")
    np.testing.assert_allclose(tp.offset, [0.0, 0.0, -0.5])
    np.testing.assert_array_equal(tp.directions, [[1.0, 0.0, 0.0], [0.0, 0.0, 1.0]])
    assert "passed over: the URDF leaf link 'link2' (its origin) (on the axis of joint 'link2')" in tp.choice
    assert [t.name for t in model.task_points] == ["link2:com", "link2"]


def test_with_task_point_sets_validates_and_explains(urdf_path):
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        model = from_urdf(urdf_path)
    moved = build.with_task_point(model, "link2", [0.1, 0.0, -1.0])
    tp = moved.task_point()
    assert tp.body == "link2" and tp.choice == "given: body 'link2', offset [0.1, 0.0, -1.0]"
    assert moved.digest() != model.digest()
    # one joint moves a point of link1: a circle, one direction at a time in a plane of two
    assert build.with_task_point(model, "link1", [0.1, 0.0, -1.0]).task_point().choice.endswith(
        "(its task Jacobian is rank-deficient everywhere)")
    on_axis = build.with_task_point(model, "link2", [0.0, 0.0, 0.0])
    assert "it lies on the axis of joint 'link2'" in on_axis.task_point().choice
    assert task.rank_deficiency(on_axis, [0.4, -1.1]) == (
        "task Jacobian rank 1 < 2: the point lies on the axis of joint 'link2'")
    with pytest.raises(build.TaskPointError, match="has no body 'hand'; bodies: link1, link2"):
        build.with_task_point(model, "hand")
    assert build.parse("link2") == ("link2", None)
    with pytest.raises(build.TaskPointError, match="three finite numbers"):
        build.parse("link2:1,2")
    with pytest.raises(build.TaskPointError, match="not three numbers"):
        build.parse("link2:1,x,2")


def test_cli_refuses_a_bad_task_point_and_the_report_names_the_point(urdf_path, tmp_path, capsys):
    report = tmp_path / "gate.md"
    base = ["gate", "--model", str(urdf_path), "--samples", "2", "--report", str(report), "--quiet", "--workers",
            "0", "--no-self-test", "--frames", "0", "--no-charts", "--no-conservation", "--no-linearization"]
    assert cli.main(base + ["--task-point", "hand"]) == 2
    assert "has no body 'hand'; bodies: link1, link2" in capsys.readouterr().err
    junit = tmp_path / "gate.xml"
    assert cli.main(base + ["--task-point", "link2:0,0,0", "--junit", str(junit)]) == 1   # out at most states: FAIL
    assert ("--allow-breakdown operational_space if that is expected" in capsys.readouterr().err)
    assert ('name="backends compared">\n      <failure type="FAIL" message="operational_space was in BREAKDOWN (out '
            'of the vote) at 2 of 2 states' in junit.read_text())
    assert cli.main(base + ["--task-point", "link2:0,0,0", "--allow-breakdown", "operational_space"]) == 0
    captured = capsys.readouterr()
    assert "note double_pendulum_continuous: a task condition was in BREAKDOWN at 2 of 2 states" in captured.err
    assert ("Compared: every backend but double_pendulum_continuous: operational_space in BREAKDOWN at 2 of 2 states "
            "(allowed).") in captured.out
    text = report.read_text()                       # the summary: the point, why it broke down, the picture
    assert "- double_pendulum_continuous: task point `task_point:link2` on body `link2` at [0, 0, 0] m" in text
    assert ("a task condition was in BREAKDOWN at 2 of 2 states (worst inf); at state #1: task Jacobian rank 1 < 2: "
            "the point lies on the axis of joint 'link2'") in text     # state #0 is the home configuration
    picture = "gate_double_pendulum_continuous_state1.png"       # the mechanism there, next to the report
    assert f"- double_pendulum_continuous: ![double_pendulum_continuous]({picture})" in text
    assert (tmp_path / picture).read_bytes()[:4] == b"\x89PNG"
    assert "--task-point link2:0,0,0" in gate_summary.read(report)     # the reproduce commands (details) carry it


def test_every_built_in_task_point_has_a_full_rank_task_jacobian():
    # only Panda's tool centre point lies on a joint axis (the flange's, joint 7's), and its other six joints still
    # move it in every direction: its task-space inertia exists, so it stays the default
    import cases

    on_axis = {}
    for name in cases.names():
        model = cases.load(name)
        tp = model.task_point()
        assert task.full_rank(model, tp.body, tp.offset, tp.directions), name
        axes = task.axes_through(model, tp.body, tp.offset)
        if axes:
            on_axis[name] = axes
    # the rolling disk's task point is its centre, on its spin axis; lean, yaw and the contact's slides move it
    assert on_axis == {"panda": ["the axis of joint 'panda_link7'"], "rolling_disk": ["the axis of joint 'disk'"]}


def test_a_given_task_point_leaves_the_closed_forms_task_quantities_out():
    from crosscheck.engine.specs import CaseSpec
    from formalisms.interface import UNSUPPORTED

    given = CaseSpec("double_pendulum", task_point="link2:0.1,-0.5,0")
    model = given.build()
    assert model.task_point().body == "link2" and given.cli_args().endswith("--task-point link2:0.1,-0.5,0")
    state = (np.array([0.3, -0.7]), np.array([1.0, 0.5]), np.array([0.2, -0.1]))
    split, plain = given.closed_form().split(model, *state), CaseSpec("double_pendulum").closed_form().split(
        CaseSpec("double_pendulum").build(), *state)
    assert split.task_drift is UNSUPPORTED and split.task_inertia is UNSUPPORTED
    assert "task_inertia" not in split.conditions
    np.testing.assert_array_equal(split.total, plain.total)


def test_two_joints_in_space_get_the_two_directions_their_point_moves_in_at_once():
    """A yaw joint and a pitch joint move the arm's point over a sphere: its velocities span space over the
    configurations but a plane at each one, so three task directions are rank-deficient everywhere and operational
    space would be in BREAKDOWN at every state; the default takes the two it moves in at once."""
    inertia = np.diag([0.01, 0.01, 0.005])
    model = build_model("yaw_pitch", [
        Body("l1", None, "revolute", (0.0, 0.0, 1.0), 1.0, com=(0.0, 0.0, 0.2), inertia=inertia),
        Body("l2", "l1", "revolute", (0.0, 1.0, 0.0), 0.5, com=(0.15, 0.0, 0.0), inertia=inertia,
             translation=(0.0, 0.0, 0.4))])
    tp = model.task_point()
    assert len(task.motion_directions(model, tp.body, tp.offset)) == 3
    assert tp.directions.shape == (2, 3) and "the 2 directions it moves in at once" in tp.choice
    np.testing.assert_allclose(tp.directions @ tp.directions.T, np.eye(2), atol=1e-12)
    ranks = [np.linalg.matrix_rank(tp.directions @ task.point_jacobian(model, q, tp.body, tp.offset))
             for q in np.random.default_rng(3).uniform(-3.0, 3.0, (20, 2))]
    assert ranks.count(2) >= 18, ranks


def test_the_default_task_point_is_a_tool_frame_never_a_sensor_and_else_the_longest_chain(tmp_path):
    """Issue 34: pr2's default was a head camera's optical frame. Sensor frames come last, tool and end-effector
    frames first, then the longest chain (a humanoid's arm before its legs)."""
    def link(name):
        return (f'<link name="{name}"><inertial><origin xyz="0.05 0 0.02"/><mass value="1"/>'
                '<inertia ixx="0.01" ixy="0" ixz="0" iyy="0.01" iyz="0" izz="0.01"/></inertial></link>')

    def joint(name, parent, child, kind="revolute", axis="0 0 1"):
        return (f'<joint name="{name}" type="{kind}"><parent link="{parent}"/><child link="{child}"/>'
                f'<origin xyz="0.1 0.03 0.2"/><axis xyz="{axis}"/>'
                + ('<limit lower="-2" upper="2" effort="1" velocity="1"/>' if kind == "revolute" else "") + "</joint>")

    def robot(leaves):
        links = ["base", "a1", "a2", "a3", "a4", "l1", "l2", "l3", *(leaf for _, leaf in leaves)]
        joints = [joint("s1", "base", "a1"), joint("s2", "a1", "a2", axis="0 1 0"), joint("s3", "a2", "a3"),
                  joint("s4", "a3", "a4", axis="0 1 0"), joint("hip", "base", "l1", axis="1 0 0"),
                  joint("knee", "l1", "l2", axis="0 1 0"), joint("ankle", "l2", "l3", axis="1 0 0")]
        joints += [joint(f"j_{leaf}", parent, leaf, kind="fixed") for parent, leaf in leaves]
        path = tmp_path / "r.urdf"
        path.write_text('<?xml version="1.0"?><robot name="r">' + "".join(map(link, links)) + "".join(joints)
                        + "</robot>")
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            return from_urdf(str(path), base="fixed").task_point().name

    camera = "narrow_stereo_l_stereo_camera_optical_frame"
    assert robot([("l3", "foot"), ("a4", "hand")]) == "hand"                              # the longest chain
    assert robot([("a4", camera), ("l3", "foot")]) == "foot"                              # never a sensor frame
    assert robot([("a4", "hand"), ("l3", "l_gripper_tool_frame")]) == "l_gripper_tool_frame"  # a tool first
    assert robot([("a4", camera), ("l3", "imu_link")]) == camera                          # sensors only: longest
