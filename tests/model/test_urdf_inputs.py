"""A URDF model's input map (``cases.from_urdf(..., actuated=[...])``, ``--actuated j1,j3``): B is the identity's
columns of the named joints in the order given, every backend's ctrl is ``M^-1 B u`` with it, and a name that is not a
movable joint of the file is refused with the list of the movable ones."""

from __future__ import annotations

import json

import numpy as np
import pytest

import cases
from cases.model import ModelError
from crosscheck import cli
from crosscheck.references.pinocchio import kinematics
from crosscheck.engine.specs import CaseSpec

#: revolute j_a, continuous j_b (unaligned axis), prismatic j_c, and a fixed joint to a tool link.
CHAIN = "\n".join([
    '<?xml version="1.0"?>', '<robot name="inputs">', '<link name="base"/>',
    *[f'<link name="{name}"><inertial><origin xyz="{com}"/><mass value="{mass}"/>'
      '<inertia ixx="0.02" ixy="0" ixz="0" iyy="0.03" iyz="0" izz="0.025"/></inertial></link>'
      for name, mass, com in (("a", 1.5, "0.1 0 0"), ("b", 0.8, "0 0.1 0.02"), ("c", 0.4, "0.02 0 0.03"))],
    '<link name="tool"/>',
    '<joint name="j_a" type="revolute"><parent link="base"/><child link="a"/><axis xyz="0 0 1"/>'
    '<limit lower="-3" upper="3" effort="1" velocity="1"/></joint>',
    '<joint name="j_b" type="continuous"><parent link="a"/><child link="b"/><origin xyz="0.3 0 0"/>'
    '<axis xyz="0.6 0 0.8"/></joint>',
    '<joint name="j_c" type="prismatic"><parent link="b"/><child link="c"/><origin xyz="0 0.2 0"/>'
    '<axis xyz="0 1 0"/><limit lower="-1" upper="1" effort="1" velocity="1"/></joint>',
    '<joint name="j_tool" type="fixed"><parent link="c"/><child link="tool"/></joint>',
    "</robot>", ""])


@pytest.fixture
def path(tmp_path) -> str:
    p = tmp_path / "inputs.urdf"
    p.write_text(CHAIN)
    return str(p)


def test_actuated_joints_are_the_columns_of_b_in_the_order_given(path):
    model = cases.from_urdf(path, base="fixed", actuated=["j_c", "j_a"])
    np.testing.assert_array_equal(model.input_map, [[0.0, 1.0], [0.0, 0.0], [1.0, 0.0]])
    np.testing.assert_array_equal(cases.from_urdf(path, base="fixed").input_map, np.eye(3))
    assert CaseSpec("inputs", path=path, base="fixed", actuated=("j_c", "j_a")).cli_args() == \
        f"--model {path} --base fixed --actuated j_c,j_a"


@pytest.mark.parametrize("actuated, message", [
    (["j_x"], "actuated joint 'j_x' is not a joint of the file; movable joints: ['j_a', 'j_b', 'j_c']"),
    (["j_tool"], "actuated joint 'j_tool' is fixed, which no motor drives here"),
    (["j_a", "j_a"], "actuated names joint 'j_a' 2 times; name each joint once"),
    ("j_a", "actuated must be a list of URDF joint names, got 'j_a'"),
])
def test_a_bad_actuated_joint_is_refused_with_the_movable_ones(path, actuated, message):
    with pytest.raises(ModelError, match="inputs.urdf") as info:
        cases.from_urdf(path, base="fixed", actuated=actuated)
    assert message in str(info.value)


def test_ctrl_of_every_backend_uses_the_input_map(path, capsys):
    """eval with --actuated j_c,j_a and u = (2, -3): tau = (-3, 0, 2), ctrl = M^-1 tau for every backend."""
    q, qd, u = [0.3, -0.7, 0.05], [1.0, -2.0, 0.3], [2.0, -3.0]
    assert cli.main(["eval", "--model", path, "--base", "fixed", "--actuated", "j_c,j_a", "--q=0.3,-0.7,0.05",
                     "--qd=1,-2,0.3", "--u=2,-3", "--json"]) == 0
    data = json.loads(capsys.readouterr().out)
    model = cases.from_urdf(path, base="fixed")
    want = np.linalg.solve(kinematics.mass_matrix(model, q), [-3.0, 0.0, 2.0])
    assert len(data["formalisms"]) >= 6
    for name, values in data["formalisms"].items():
        np.testing.assert_allclose(values["ctrl"], want, rtol=1e-9, atol=1e-12, err_msg=name)
        np.testing.assert_allclose(values["power_ctrl"], -3.0 * qd[0] + 2.0 * qd[2], rtol=1e-12, err_msg=name)
    assert cli.main(["eval", "--model", path, "--base", "fixed", "--actuated", "j_c,j_a", "--q=0.3,-0.7,0.05",
                     "--u=1,2,3"]) == 2
    assert "--u has 3 entries; this model needs 2" in capsys.readouterr().err


def test_actuated_applies_to_a_urdf_only(capsys):
    assert cli.main(["eval", "--case", "double_pendulum", "--actuated", "j1", "--q=0,0"]) == 2
    assert "--actuated applies to a --model URDF file" in capsys.readouterr().err


def test_no_actuated_joint_is_a_passive_model_and_the_gate_runs_every_check(path, tmp_path):
    """``actuated=[]`` (``--actuated ""``): B has no columns; every check runs, the linearization's empty B
    included (issue 34: a zero-size B crashed the comparison)."""
    model = cases.from_urdf(path, base="fixed", actuated=[])
    assert model.input_map.shape == (3, 0)
    spec = CaseSpec("inputs", path=path, base="fixed", actuated=())
    assert spec.cli_args() == f"--model {path} --base fixed --actuated ''"
    report = tmp_path / "gate.md"
    assert cli.main(["gate", "--model", path, "--base", "fixed", "--actuated", "", "--samples", "3",
                     "--workers", "0", "--report", str(report)]) == 0
    text = report.read_text()
    assert "linearization: 2 states in 1 case(s), 10 comparisons, 0 DISAGREE" in (   # 5 blocks, dvdot/du empty
        tmp_path / "gate-details.md").read_text()
    assert "PASS" in text
