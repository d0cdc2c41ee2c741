"""Sampling coverage (crosscheck.guards.coverage): the ranges a case's states span, and a degenerate sample fails the gate."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

import cases
from cases import configuration
from crosscheck.guards import coverage
from crosscheck.core import sampling
from crosscheck.engine.specs import CaseSpec, Checks
from crosscheck.engine.run import run_case
from scenes import chain_urdf


def _states(model, count=20, seed=0, name="x"):
    return sampling.sample_states(model, count, seed, name)


@pytest.mark.parametrize("name", ["double_pendulum", "spatial_arm", "four_bar", "cartesian_pendulum"])
def test_the_gate_sample_of_every_kind_of_case_is_not_degenerate(name):
    model = cases.load(name)
    cov = coverage.measure(model, _states(model, 20, 0, name))
    assert not cov.problems, cov.problems
    assert cov.q.shape == (model.n, 2) and cov.qd.shape == (model.n, 2) and cov.u.shape == (model.m, 2)
    assert np.all(cov.q[:, 0] <= cov.q[:, 1]) and (cov.constraint_rank is None) == (not model.constraints)


def test_rates_never_sampled_are_degenerate():
    model = cases.load("spatial_arm")
    still = [dataclasses.replace(s, qd=(0.0,) * model.n) for s in _states(model)]
    (problem,) = coverage.measure(model, still).problems
    assert "every joint rate is 0" in problem


def test_inputs_never_sampled_are_degenerate():
    model = cases.load("acrobot")
    idle = [dataclasses.replace(s, u=(0.0,) * model.m) for s in _states(model)]
    (problem,) = coverage.measure(model, idle).problems
    assert "every input is 0" in problem


def test_configurations_in_a_sliver_are_degenerate_but_few_states_are_not_judged():
    model = cases.load("n_link_pendulum", n=3)
    states = _states(model, 20)
    narrow = [dataclasses.replace(s, q=tuple(1e-3 * np.array(s.q))) for s in states]
    (problem,) = coverage.measure(model, narrow).problems
    assert "sliver" in problem and "q0 (link1)" in problem
    assert not coverage.measure(model, narrow[: coverage.SLIVER_STATES - 1]).problems


def test_the_span_is_the_promised_one_not_the_samplers(monkeypatch):
    """A sampler drawing angles from a narrow range is measured against one turn, not against itself."""
    model = cases.load("double_pendulum")
    monkeypatch.setattr(sampling, "ANGLE_RANGE", 1e-3)
    assert any("sliver" in p for p in coverage.measure(model, _states(model, 20)).problems)


def test_a_degenerate_sample_fails_the_case(monkeypatch):
    real = sampling.sample_states

    def still(model, count, seed, case, **options):
        return [dataclasses.replace(s, qd=(0.0,) * model.n) for s in real(model, count, seed, case, **options)]

    monkeypatch.setattr("crosscheck.engine.run.sample_states", still)
    outcome = run_case(CaseSpec("double_pendulum"), [], 4, 0, checks=Checks(charts=False, frames=0,
                                                                            conservation=False))
    assert outcome.failed and outcome.coverage.degenerate


# ------------------------------------------------------------------------- issue 35: judged independently


def _replaced(states, **columns):
    """``states`` with whole columns replaced: ``q={i: values}`` etc. (one value per state)."""
    out = []
    for k, s in enumerate(states):
        fields = {}
        for name, changes in columns.items():
            row = list(getattr(s, name))
            for i, values in changes.items():
                row[i] = float(values[k])
            fields[name] = tuple(row)
        out.append(dataclasses.replace(s, **fields))
    return out


@pytest.mark.parametrize("seed", [0, 1, 2])
@pytest.mark.parametrize("name", cases.names())
def test_every_built_in_case_sampled_by_the_gate_is_not_degenerate(name, seed):
    """No false alarm: the default sampler's 50 states of every built-in case, constrained ones included (a
    coordinate their constraints pin, as the absolute-coordinate loop's, is no sliver), at several seeds."""
    model = cases.load(name)
    cov = coverage.measure(model, sampling.sample_states(model, 50, seed, name))
    assert not cov.problems, cov.problems
    assert len(cov.limits) == len(model.bodies) and cov.limits_source


def test_the_allowances_are_the_binomial_tails_the_docstring_states():
    from scipy.stats import binom

    for states in (10, 20, 50, 200):
        k = coverage.band_allowance(states)
        windows = round(1 / coverage.BAND) + 1
        assert windows * binom.sf(k - 1, states - 1, 2 * coverage.BAND) <= coverage.RISK
        assert k == states or windows * binom.sf(k - 2, states - 1, 2 * coverage.BAND) > coverage.RISK
        assert coverage.limit_allowance(states) == 2
    assert coverage.band_allowance(50) == 30 and coverage.band_allowance(10) == 10


# -- the limits, read from the file

def _urdf(tmp_path):
    """A chain of a continuous, a revolute (limits -1, 0.5 rad) and a prismatic joint (limits 0.1, 0.3 m)."""
    joints = [("spin", "base", "l1", "continuous", ""),
              ("elbow", "l1", "l2", "revolute", '<limit lower="-1" upper="0.5" effort="1" velocity="1"/>'),
              ("slide", "l2", "l3", "prismatic", '<limit lower="0.1" upper="0.3" effort="1" velocity="1"/>')]
    return cases.from_file(chain_urdf(tmp_path / "r.urdf", joints), base="fixed")


def _with_limits(model, body, limits):
    bodies = list(model.bodies)
    bodies[body] = dataclasses.replace(bodies[body], limits=limits)
    return dataclasses.replace(model, bodies=tuple(bodies))


def test_a_urdf_with_continuous_revolute_and_prismatic_joints_is_measured_against_its_file(tmp_path):
    model = _urdf(tmp_path)
    assert [b.limits for b in model.bodies] == [None, (-1.0, 0.5), (0.1, 0.3)]
    for seed in range(5):
        cov = coverage.measure(model, sampling.sample_states(model, 50, seed, "r"))
        assert not cov.problems, cov.problems
    assert cov.limits == (None, (-1.0, 0.5), (0.1, 0.3))
    assert "URDF file" in cov.limits_source and "r.urdf" in cov.limits_source and "apart from" in cov.limits_source
    assert np.allclose(cov.span, [coverage.REVOLUTE_SPAN, 1.5, 0.2])


def test_converted_limits_that_differ_from_the_file_are_measured_against_the_files(tmp_path):
    """A loader bug emulated on Body.limits: the sampler draws within the wrong limits, and the coverage measures the
    sample against the file's own (the difference itself is a loader finding at the case's setup:
    tests/guards/test_file_reading.py), not as a problem of the sample."""
    good = _urdf(tmp_path)
    model = _with_limits(good, 1, (-180 / np.pi, 90 / np.pi))      # radians taken for degrees and converted again
    cov = coverage.measure(model, sampling.sample_states(model, 50, 0, "r"))
    assert not any("loader finding" in p for p in cov.problems), cov.problems
    assert cov.limits == coverage.measure(good, sampling.sample_states(good, 50, 0, "r")).limits == (
        None, (-1.0, 0.5), (0.1, 0.3))


def test_a_file_that_cannot_be_read_apart_from_the_loader_falls_back_on_the_model_and_says_why(tmp_path):
    model = _urdf(tmp_path)
    coverage.measure(model, sampling.sample_states(model, 12, 0, "r"))      # the reference caches the file's model
    (tmp_path / "r.urdf").write_text("<robot")
    cov = coverage.measure(model, sampling.sample_states(model, 50, 0, "r"))
    assert not cov.problems and "could not be read" in cov.limits_source
    assert cov.limits == (None, (-1.0, 0.5), (0.1, 0.3))


MJCF = """<mujoco model="m">{compiler}
 <default><default class="loose"><joint limited="false"/></default><default class="wide"><joint range="-20 40"/>
 </default></default>
 <worldbody>
  <body name="b1"><joint name="h1" type="hinge" axis="0 0 1" range="-90 45"/><geom size="0.1" pos="0.3 0 0" mass="1"/>
   <body name="b2" pos="0.6 0 0"><joint name="s2" type="slide" axis="1 0 0" range="-0.1 0.2"/>
    <geom size="0.1" pos="0.3 0 0" mass="1"/>
    <body name="b3" pos="0.6 0 0"><joint name="h3" class="loose" axis="0 1 0" range="-1 1"/>
     <geom size="0.1" pos="0.3 0 0" mass="1"/>
     <body name="b4" pos="0.6 0 0" childclass="wide"><joint name="h4" axis="0 1 0"/>
      <geom size="0.1" pos="0.3 0 0" mass="1"/>
      <body name="b5" pos="0.6 0 0"><joint name="h5" axis="0 1 0"/>
       <geom size="0.1" pos="0.3 0 0" mass="1"/></body>
 </body></body></body></body>
 </worldbody>
</mujoco>"""


@pytest.mark.parametrize("compiler, expected", [
    ("", [(-np.pi / 2, np.pi / 4), (-0.1, 0.2), None, (-np.pi / 9, 2 * np.pi / 9), (-np.pi / 9, 2 * np.pi / 9)]),
    ('<compiler angle="radian"/>', [(-90.0, 45.0), (-0.1, 0.2), None, (-20.0, 40.0), (-20.0, 40.0)]),
    ('<compiler angle="radian" autolimits="false"/>', [None, None, None, None, None]),
])
def test_an_mjcf_file_is_read_as_mujoco_reads_it_and_its_correct_conversion_is_no_finding(tmp_path, compiler,
                                                                                           expected):
    """A hinge's range in degrees (MJCF's default unit) is compared in radians with the converted limits; a joint not
    limited has none, on both sides; a default class's range reaches a joint through ``childclass``. Where MuJoCo is
    installed, its own reading of the file agrees."""
    from crosscheck.guards import file_limits

    path = tmp_path / "m.xml"
    path.write_text(MJCF.format(compiler=compiler))
    model = cases.from_file(str(path))
    read = file_limits.read(model)
    assert read.limits is not None and read.joints == ("h1", "s2", "h3", "h4", "h5")
    for got, want in zip(read.limits, expected):
        assert (got is None and want is None) or np.allclose(got, want, rtol=1e-12)
    cov = coverage.measure(model, sampling.sample_states(model, 50, 0, "m"))
    assert not cov.problems, cov.problems
    assert "MJCF file" in cov.limits_source
    mujoco = pytest.importorskip("mujoco")
    if "autolimits" in compiler:
        return      # MuJoCo refuses a range without `limited` under autolimits="false"; the loaders read no limit
    mj = mujoco.MjModel.from_xml_path(str(path))
    for k, got in enumerate(read.limits):
        assert (got is None) == (not mj.jnt_limited[k]) and (got is None or np.allclose(got, mj.jnt_range[k]))


# -- the distribution, not only the extremes

def test_states_piled_onto_the_two_limits_are_degenerate(tmp_path):
    """Half the states at each limit: the widest range and spread there is, and no uniform sample."""
    model = _urdf(tmp_path)
    states = sampling.sample_states(model, 50, 0, "r")
    piled = _replaced(states, q={1: [-1.0 if k % 2 else 0.5 for k in range(50)]})
    (problem,) = coverage.measure(model, piled).problems
    assert "pile at the joint limits" in problem and "q1 (l2) at 25 states at its lower limit -1" in problem
    assert not coverage.measure(model, _replaced(states, q={1: [0.5] + [s.q[1] for s in states[1:]]})).problems


def test_states_piled_into_a_band_are_degenerate_though_they_reach_both_ends():
    model = cases.load("double_pendulum")
    states = _states(model, 50, 0, "double_pendulum")
    rng = np.random.default_rng(5)
    values = np.r_[rng.uniform(-np.pi, np.pi, 15), rng.uniform(0.2, 0.4, 35)]
    (problem,) = coverage.measure(model, _replaced(states, q={0: values})).problems
    assert "pile into a band" in problem and "q0 (link1) has 3" in problem
    assert np.ptp(values) > 0.9 * coverage.REVOLUTE_SPAN           # the extremes alone saw nothing wrong


@pytest.mark.parametrize("name", ["double_pendulum", "spatial_arm", "satellite_arm", "knife_edge"])
def test_one_pinned_coordinate_of_an_unconstrained_model_is_a_sliver(name):
    model = cases.load(name)
    states = _states(model, 50, 0, name)
    i = model.q_index[-1]
    (problem,) = coverage.measure(model, _replaced(states, q={i: [0.25] * 50})).problems
    assert "sliver" in problem and f"q{i} ({model.bodies[-1].name}) spans 0 of" in problem


def test_a_pinned_coordinate_of_a_constrained_model_is_a_sliver_unless_the_constraints_pin_it():
    """The gear holds q1 = r q0 but pins neither: q1 pinned with q0 moving is a sampler's failure, though q0 keeps
    the sample from being "every coordinate thin". The absolute-coordinate loop's constraints pin its first two
    coordinates (no problem); its last one is free of every constraint, and pinned it is a sliver."""
    model = cases.load("geared_pendulums")
    states = _states(model, 50, 0, "geared_pendulums")
    (problem,) = coverage.measure(model, _replaced(states, q={1: [0.4] * 50})).problems
    assert "q1 (" in problem and "the constraints do not hold it there" in problem
    loop = cases.load("double_pendulum_absolute_loop")
    states = _states(loop, 50, 0, "double_pendulum_absolute_loop")
    assert np.ptp([s.q[0] for s in states]) < 1e-15 and not coverage.measure(loop, states).problems
    (problem,) = coverage.measure(loop, _replaced(states, q={5: [0.1] * 50})).problems
    assert "sliver" in problem and "q5 (" in problem


# -- repeated states

@pytest.mark.parametrize("name", ["double_pendulum", "four_bar", "free_body", "knife_edge", "panda"])
def test_repeated_states_are_degenerate_for_every_model(name):
    model = cases.load(name)
    states = _states(model, 50, 0, name)
    copies = states[:10] + [dataclasses.replace(states[3], index=k) for k in range(10, 40)] + states[40:]
    problem = coverage.measure(model, copies).problems[0]     # 31 equal configurations may pile into a band too
    assert problem.startswith("30 of 50 states repeat") and "state #3 recurs as #10, #11" in problem
    assert "25 more" in problem


def test_states_equal_to_rounding_repeat_and_distinct_ones_do_not():
    model = cases.load("double_pendulum")
    states = _states(model, 20)
    near = dataclasses.replace(states[7], index=20, q=tuple(np.array(states[7].q) * (1 + 1e-13)))
    (problem,) = coverage.measure(model, states + [near]).problems
    assert "1 of 21 states repeat" in problem and "state #7 recurs as #20" in problem
    apart = dataclasses.replace(near, q=tuple(np.array(states[7].q) * (1 + 1e-9)))
    assert not coverage.measure(model, states + [apart]).problems
    pairs = states + [dataclasses.replace(states[k], index=20 + k) for k in (2, 5)]
    (problem,) = coverage.measure(model, pairs).problems
    assert "2 of 22 states repeat" in problem and "1 other state(s) recur too" in problem


# -- uniform draws over the promised span pass

@settings(max_examples=40)
@given(seed=st.integers(0, 2**32 - 1), count=st.integers(coverage.SLIVER_STATES, 120),
       name=st.sampled_from(["double_pendulum", "spatial_arm", "satellite_arm", "limited"]))
def test_uniform_draws_over_the_promised_span_pass(seed, count, name):
    """Home (state 0) plus uniform draws: revolute angles over one turn, prismatic displacements and a free base's
    position over a metre, limited joints within their limits, orientations uniform: no problem."""
    model = _limited() if name == "limited" else cases.load(name)
    rng = np.random.default_rng(seed)
    states = []
    for k in range(count):
        q = configuration.random_configuration(model, rng, np.pi, 0.5) if k else configuration.neutral(model)
        for i, b in enumerate(model.bodies):
            if b.limits is not None:
                q[model.q_index[i]] = rng.uniform(*b.limits) if k else np.clip(0.0, *b.limits)
        states.append(sampling.State(k, tuple(q), tuple(rng.uniform(-3, 3, model.nv)),
                                     tuple(rng.uniform(-10, 10, model.m))))
    assert not coverage.measure(model, states).problems


def _limited():
    from cases.build import build_model
    from cases.model import Body

    return build_model("limited", [
        Body("a", None, "revolute", (0.0, 0.0, 1.0), 1.0, com=(0.3, 0.0, 0.0), inertia=np.eye(3) * 0.01,
             limits=(0.2, 1.0)),
        Body("b", "a", "prismatic", (1.0, 0.0, 0.0), 1.0, com=(0.1, 0.0, 0.0), inertia=np.eye(3) * 0.01,
             translation=(0.6, 0.0, 0.0), limits=(-0.04, 0.0))])


def test_the_details_report_says_which_limits_a_file_model_was_measured_against():
    from types import SimpleNamespace

    from crosscheck.reports.gate_details import _coverage_section

    outcome = run_case(CaseSpec("panda"), [], 12, 0, checks=Checks(charts=False, frames=0, conservation=False))
    assert not outcome.coverage.problems and "URDF file" in outcome.coverage.limits_source
    section = "\n".join(_coverage_section(SimpleNamespace(cases=[outcome])))
    assert "- panda: joint limits measured against the URDF file " in section and "panda.urdf" in section
