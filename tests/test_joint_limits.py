"""Joint limits: read from URDF and MJCF files, validated, serialized, and the sampler draws within them (issue 20,
item 6); ``--ignore-limits`` draws freely, and the gate report says which."""

from __future__ import annotations

import json

import numpy as np
import pytest

import cases
from cases.model import Body, ModelError, build_model
from cases.serialize import model_from_dict, model_to_dict
from crosscheck import cli, sampling

Z = (0.0, 0.0, 1.0)


def _arm(limits=((-0.5, 0.25), (0.1, 0.3))) -> cases.Model:
    return build_model("limited_arm", [
        Body("a", None, "revolute", Z, 1.0, com=(0.3, 0.0, 0.0), inertia=np.eye(3) * 0.01, limits=limits[0]),
        Body("b", "a", "prismatic", (1.0, 0.0, 0.0), 1.0, com=(0.1, 0.0, 0.0), inertia=np.eye(3) * 0.01,
             translation=(0.6, 0.0, 0.0), limits=limits[1])])


def test_the_panda_urdf_limits_are_read():
    panda = cases.load("panda")
    assert panda.bodies[3].limits == (-3.0718, -0.0698)   # the elbow never straightens: 0 is outside
    assert all(b.limits is not None for b in panda.bodies)


def test_sampled_states_lie_within_the_limits_and_home_is_clipped_into_them():
    model = _arm()
    states = sampling.sample_states(model, 200, 3, "limited_arm")
    q = np.array([s.q for s in states])
    assert np.all(q[:, 0] >= -0.5) and np.all(q[:, 0] <= 0.25)
    assert np.all(q[:, 1] >= 0.1) and np.all(q[:, 1] <= 0.3)
    assert q[0].tolist() == [0.0, 0.1]                       # home: 0 where allowed, else the nearest limit
    assert q[1:, 0].min() < -0.45 and q[1:, 0].max() > 0.2  # the whole range is drawn
    free = np.array([s.q for s in sampling.sample_states(model, 200, 3, "limited_arm", limits=False)])
    assert free[1:, 0].min() < -3.0 and free[0].tolist() == [0.0, 0.0]
    assert np.array_equal(sampling.within_limits(model, free[7]), q[7])   # the same draws, mapped


def test_a_model_without_limits_samples_as_before():
    model = cases.load("double_pendulum")
    assert sampling.sample_states(model, 5, 0, "x") == sampling.sample_states(model, 5, 0, "x", limits=False)


@pytest.mark.parametrize("limits, fragment", [
    ((1.0, 0.5), "are not finite with lower <= upper"),
    ((0.0, np.inf), "are not finite with lower <= upper"),
    (("a", 1.0), "are not two numbers"),
])
def test_bad_limits_are_refused_naming_the_body(limits, fragment):
    with pytest.raises(ModelError, match=f"body 'a' joint limits .*{fragment[:20]}"):
        _arm(limits=(limits, None))


def test_limits_on_a_ball_joint_are_refused():
    with pytest.raises(ModelError, match="has a spherical joint with limits"):
        build_model("ball", [Body("a", None, "spherical", (0.0, 0.0, 0.0), 1.0, com=(0.0, 0.0, -1.0),
                                  inertia=np.eye(3) * 0.01, limits=(0.0, 1.0))])


def test_limits_survive_serialization_and_stay_out_of_the_digest():
    model = _arm()
    back = model_from_dict(json.loads(json.dumps(model_to_dict(model))))
    assert [b.limits for b in back.bodies] == [(-0.5, 0.25), (0.1, 0.3)]
    assert back.digest() == model.digest() == _arm(limits=(None, None)).digest()


def test_the_gate_report_says_how_the_states_were_drawn(tmp_path):
    report = tmp_path / "gate.md"
    argv = ["gate", "--case", "panda", "--samples", "2", "--no-charts", "--frames", "0", "--no-conservation",
            "--no-self-test", "--workers", "0", "--quiet", "--report", str(report)]
    assert cli.main(argv) == 0
    assert "- states drawn within the joint limits the models declare (panda 9 of 9 joints)" in report.read_text()
    assert cli.main(argv + ["--ignore-limits"]) == 0
    assert "- joint limits ignored (`--ignore-limits`)" in report.read_text()


def test_coverage_measures_a_limited_joint_against_its_limits():
    """A joint drawn within narrow limits (the Panda's fingers: 4 cm) is not a sliver of its promised range, and a
    sample that stays in a sliver of the limits still is."""
    from crosscheck import coverage

    model = _arm(limits=((-0.5, 0.25), (0.0, 0.04)))
    assert not coverage.measure(model, sampling.sample_states(model, 30, 0, "arm")).degenerate
    stuck = [sampling.State(i, (0.01 * i / 30, 0.02), (1.0, 1.0), (1.0, 1.0)) for i in range(30)]
    assert "q0 (a) spans 0.00967 of 0.75" in coverage.measure(model, stuck).problems[0]
