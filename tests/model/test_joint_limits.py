"""Joint limits: read from URDF and MJCF files, validated, serialized, and the sampler draws within them (issue 20,
item 6); ``--ignore-limits`` draws freely, and the gate report says which. The coverage reads the limits from the
file's XML apart from the loader and names a model whose limits are not the file's (issue 35)."""

from __future__ import annotations

import json

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

import cases
import dataclasses

from cases.model import Body, ModelError
from cases.build import build_model
from cases.serialize import model_from_dict, model_to_dict
from crosscheck import cli
from crosscheck.core import sampling
from crosscheck.references.pinocchio import build
from scenes import chain_urdf

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
    from crosscheck.guards import coverage

    model = _arm(limits=((-0.5, 0.25), (0.0, 0.04)))
    assert not coverage.measure(model, sampling.sample_states(model, 30, 0, "arm")).degenerate
    stuck = [sampling.State(i, (0.01 * i / 30, 0.02), (1.0, 1.0), (1.0, 1.0)) for i in range(30)]
    assert "q0 (a) spans 0.00967 of 0.75" in coverage.measure(model, stuck).problems[0]


def test_a_urdf_limit_without_lower_and_upper_is_no_limit(tmp_path):
    """URDF reads ``<limit effort velocity/>`` without lower and upper as (0, 0): taken as the joint held at 0 it
    would never move in a sampled state, so it is no limit (drawn freely); a file's lower > upper is none either."""
    joints = [("j1", "base", "l1", "revolute", '<limit effort="1" velocity="1"/>'),
              ("j2", "l1", "l2", "revolute", '<limit lower="-1" upper="0.5" effort="1" velocity="1"/>'),
              ("j3", "l2", "l3", "prismatic", '<limit lower="0.2" upper="0.1" effort="1" velocity="1"/>')]
    model = cases.from_urdf(chain_urdf(tmp_path / "r.urdf", joints), base="fixed")
    assert [b.limits for b in model.bodies] == [None, (-1.0, 0.5), None]
    assert len(build.joint_map(model)) == 3          # the reference reads the file's limits the same way


MJCF = """<mujoco model="m">{compiler}
 <default><joint limited="auto"/><default class="free"><joint limited="false"/></default></default>
 <worldbody>
  <body name="b1"><joint name="h1" type="hinge" axis="0 0 1" range="-90 45"/><geom size="0.1" pos="0.3 0 0" mass="1"/>
   <body name="b2" pos="0.6 0 0"><joint name="s2" type="slide" axis="1 0 0" range="-0.1 0.2"/>
    <geom size="0.1" pos="0.3 0 0" mass="1"/>
    <body name="b3" pos="0.6 0 0"><joint name="h3" class="free" axis="0 1 0" range="-1 1"/>
     <geom size="0.1" pos="0.3 0 0" mass="1"/>
     <body name="b4" pos="0.6 0 0"><joint name="h4" axis="0 1 0" range="-1 1" limited="true"/>
      <geom size="0.1" pos="0.3 0 0" mass="1"/>
      <body name="b5" pos="0.6 0 0"><joint name="h5" axis="0 1 0"/><geom size="0.1" pos="0.3 0 0" mass="1"/></body>
 </body></body></body></body>
 </worldbody>
</mujoco>"""


@pytest.mark.parametrize("compiler, expected", [
    ("", [(-np.pi / 2, np.pi / 4), (-0.1, 0.2), None, (-np.pi / 180, np.pi / 180), None]),
    ('<compiler angle="radian"/>', [(-90.0, 45.0), (-0.1, 0.2), None, (-1.0, 1.0), None]),
    ('<compiler angle="radian" autolimits="false"/>', [None, None, None, (-1.0, 1.0), None]),
])
def test_mjcf_ranges_are_read_as_mujoco_reads_them(tmp_path, compiler, expected):
    """A hinge's range in the compiler's angle unit, a slide's in metres whatever that unit (Pinocchio 4.1 converts
    it from degrees too), no limits where the joint or its default class says ``limited="false"``, nor where
    autolimits is off and the joint does not say ``limited="true"``, nor where there is no range."""
    from cases.mjcf import from_mjcf

    path = tmp_path / "m.xml"
    path.write_text(MJCF.format(compiler=compiler))
    model = from_mjcf(path)
    found = [b.limits for b in model.bodies]
    assert [f is None for f in found] == [e is None for e in expected]
    for f, e in zip(found, expected):
        if e is not None:
            np.testing.assert_allclose(f, e, rtol=1e-15)
    assert len(build.joint_map(model)) == 5          # the reference reads the file's ranges the same way


def _with_limits(model: cases.Model, body: str, limits) -> cases.Model:
    bodies = [dataclasses.replace(b, limits=limits) if b.name == body else b for b in model.bodies]
    return build_model(model.name, bodies, model.gravity, input_map=model.input_map, task_points=model.task_points,
                       constraints=model.constraints, source=model.source)


@pytest.mark.parametrize("compiler, body, limits", [
    ("", "b1", (-90.0, 45.0)),                                     # a hinge's range in degrees taken as radians
    ("", "b2", (np.radians(-0.1), np.radians(0.2))),               # a slide's range in metres converted as degrees
    ("", "b3", (-1.0, 1.0)),                                       # its class says limited="false"
    ("", "b5", (-1.0, 1.0)),                                       # no range
    ('<compiler angle="radian" autolimits="false"/>', "b1", (-90.0, 45.0)),
    ("", "b4", None),                                              # a limit dropped
])
def test_limits_that_are_not_the_mjcf_files_are_a_loader_finding(tmp_path, compiler, body, limits):
    """The limits bound the states the gate samples and enter no equation, so the vote cannot see a misread one: the
    loader check reads them from the XML apart from the loader (``crosscheck.guards.loader``, through
    ``crosscheck.guards.file_limits``) and names the body and the joint."""
    from cases.mjcf import from_mjcf
    from crosscheck.guards import loader

    path = tmp_path / "m.xml"
    path.write_text(MJCF.format(compiler=compiler))
    model = from_mjcf(path)
    changed = _with_limits(model, body, limits)
    assert not loader.check(model).findings
    found = [str(f) for f in loader.check(changed).findings]
    assert len(found) == 1 and f"link '{body}' limits" in found[0] and found[0].startswith("loader finding"), found


def test_limits_that_are_not_the_urdf_files_are_a_loader_finding():
    from crosscheck.guards import loader

    model = cases.load("panda")
    changed = _with_limits(model, "panda_link4", (-3.0718, 0.0698))
    found = [str(f) for f in loader.check(changed).findings]
    assert len(found) == 1 and "panda_link4" in found[0] and "panda_joint4" in found[0], found
    rounding = _with_limits(model, "panda_link4", (-3.0718, -0.0698 + 1e-14))
    assert not loader.check(rounding).findings


def test_eval_warns_of_a_q_outside_the_limits_and_evaluates_it(capsys):
    """``eval`` takes the q it is given: the Panda's stretched elbow (0, outside [-3.0718, -0.0698]) is named on stderr,
    and the state is evaluated all the same."""
    model = _arm()
    assert sampling.outside_limits(model, [0.0, 0.2]) == []
    assert sampling.outside_limits(model, [0.3, 0.05]) == [
        "q[0] = 0.3 (a, revolute) is outside its joint limits [-0.5, 0.25]",
        "q[1] = 0.05 (b, prismatic) is outside its joint limits [0.1, 0.3]"]
    for elbow, warned in (("0", True), ("-1", False)):
        argv = ["eval", "--case", "panda", f"--q=0,0,0,{elbow},0,1,0,0.01,0.01", "--qd=1,0,0,0,0,0,0,0,0",
                "--formalism", "newton_euler", "--formalism", "pinocchio"]
        assert cli.main(argv) == 0
        out, err = capsys.readouterr()
        assert err.splitlines() == (["crosscheck: warning: q[3] = 0 (panda_link4, revolute) is outside its joint "
                                     "limits [-3.0718, -0.0698]; evaluated there all the same"] if warned else [])
        assert "verdict: agree" in out


@settings(max_examples=30, deadline=None)
@given(st.data())
def test_property_tests_draw_within_the_limits_too(data):
    """``crosscheck.testing.states`` (the fuzz campaigns' and property tests' states) draws a limited joint within its
    limits, as the gate does; random models (``testing.models``) declare none."""
    from crosscheck import testing

    state = data.draw(testing.states(_arm()))
    assert -0.5 <= state.q[0] <= 0.25 and 0.1 <= state.q[1] <= 0.3
    assert all(b.limits is None for b in data.draw(testing.models(max_bodies=3)).bodies)


def test_an_unnamed_joint_gets_its_range_as_mujoco_reads_it(tmp_path):
    """A joint without a name is matched to Pinocchio's by its place in the document: an unnamed slide's range is in
    metres (Pinocchio converts it as degrees), an unnamed hinge's in degrees; the coverage, reading the file apart from
    the loader, finds no difference (before, the slide kept (-0.0087, 0.0044))."""
    from cases.mjcf import from_mjcf
    from crosscheck.guards import coverage

    path = tmp_path / "u.xml"
    path.write_text('<mujoco model="u"><worldbody><body name="b1"><joint type="hinge" axis="0 0 1" range="-90 45"/>'
                    '<geom size="0.1" pos="0.3 0 0" mass="1"/><body name="b2" pos="0.6 0 0"><joint type="slide" '
                    'axis="1 0 0" range="-0.5 0.25"/><geom size="0.1" pos="0.3 0 0" mass="1"/></body></body>'
                    '</worldbody></mujoco>')
    model = from_mjcf(path)
    np.testing.assert_allclose(model.bodies[0].limits, np.radians([-90.0, 45.0]), rtol=1e-15)
    assert model.bodies[1].limits == (-0.5, 0.25)
    assert not coverage.measure(model, sampling.sample_states(model, 20, 0, "u")).problems
