"""Sampling coverage (crosscheck.guards.coverage): the ranges a case's states span, and a degenerate sample fails the gate."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

import cases
from crosscheck.guards import coverage
from crosscheck.core import sampling
from crosscheck.engine.specs import CaseSpec, Checks
from crosscheck.engine.run import run_case


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
