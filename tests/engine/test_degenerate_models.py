"""Models at the edges of the model language run every check (issue 34): a floating body with no joints in its file
(a quadrotor: B has zero columns, since the free joint is not actuated) and an empty comparison (a block with no
entries agrees, it does not crash)."""

from __future__ import annotations

import numpy as np

import cases
from crosscheck import cli
from crosscheck.core.compare import AGREE, compare

#: One link with an inertial and no joint: a quadrotor's body, as hector_description's quadrotor_base.urdf.
BODY = """<?xml version="1.0"?>
<robot name="quad"><link name="base_link"><inertial><origin xyz="0.01 0 -0.02"/><mass value="1.477"/>
<inertia ixx="0.01152" ixy="0" ixz="0" iyy="0.01152" iyz="0" izz="0.0218"/></inertial></link></robot>
"""


def test_an_empty_block_agrees():
    comp = compare("dvdot/du", {"a": np.zeros(0), "b": np.zeros(0), "c": np.zeros(0)}, np.zeros(0))
    assert comp.verdict == AGREE and comp.worst_ratio == 0.0 and set(comp.pairs.values()) == {0.0}


def test_a_floating_body_without_joints_runs_every_check(tmp_path):
    path = tmp_path / "quad.urdf"
    path.write_text(BODY)
    model = cases.from_urdf(str(path), base="free")
    assert (model.nv, model.input_map.shape) == (6, (6, 0))
    report = tmp_path / "gate.md"
    rc = cli.main(["gate", "--model", str(path), "--base", "free", "--samples", "4", "--workers", "0",
                   "--report", str(report)])
    details = (tmp_path / "gate-details.md").read_text()
    assert rc == 0, report.read_text()
    assert "linearization: 2 states in 1 case(s), 10 comparisons, 0 DISAGREE" in details
    for check in ("chart", "frame", "conservation"):
        assert check in details
