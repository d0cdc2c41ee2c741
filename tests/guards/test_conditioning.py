"""BREAKDOWN is a claim, and claims are checked (crosscheck.guards.conditioning): the harness's own conditions agree with every
backend's on every kind of state, and a backend that escapes the vote by claiming BREAKDOWN fails the gate."""

from __future__ import annotations

import numpy as np
import pytest

import cases
import formalisms.interface as interface
import formalisms.operational_space as osc
from crosscheck import backends
from crosscheck.guards import conditioning
from crosscheck.core import tolerance as policy
from crosscheck.core.compare import DISAGREE, suspect
from crosscheck.engine.specs import CaseSpec, Checks
from crosscheck.engine.evaluation import evaluate
from crosscheck.engine.run import run_gate
from crosscheck.core.sampling import State, sample_states

ALL = [backends.get(name) for name in backends.builtin_names()]
QUICK = Checks(charts=False, frames=0, conservation=False, self_test=False)


def test_the_harness_states_the_backends_rule_with_the_same_numbers():
    assert (conditioning.CONSTRAINT_RCOND, conditioning.DEGENERATE_ROW) == (interface.CONSTRAINT_RCOND,
                                                                            interface.DEGENERATE_ROW)


@pytest.mark.parametrize("case", ["double_pendulum", "spatial_arm", "panda", "four_bar", "double_pendulum_circle",
                                  "double_pendulum_absolute_loop", "slider_crank"])
def test_every_reported_condition_agrees_with_the_harnesss_own(case):
    model = cases.load(case)
    for state in sample_states(model, 12, 0, case):
        outcome = evaluate(model, state, ALL)
        audited = {k: c for k, c in outcome.checks.items() if k.startswith("conditions: ")}
        assert audited and all(c.verdict != DISAGREE for c in audited.values()), {
            k: (c.worst_ratio, c.values) for k, c in audited.items() if c.verdict == DISAGREE}


def test_at_the_four_bars_change_point_the_breakdowns_are_confirmed():
    """q = (pi/2, 0, pi/2): S is singular, every backend claims ``constraint`` BREAKDOWN, and the harness agrees."""
    model = cases.load("four_bar")
    state = State(0, (np.pi / 2, 0.0, np.pi / 2), (0.0, 0.0, 0.0), (1.0, 0.5, -0.5))
    truth = conditioning.independent(model, state.q, state.qd, state.u)
    assert truth["constraint"] > policy.BREAKDOWN_LIMITS["constraint"]
    outcome = evaluate(model, state, ALL)
    assert all("constraint" in outcome.breakdowns.get(b.name, {}) for b in ALL)
    assert outcome.checks["conditions: constraint"].verdict != DISAGREE


def test_an_operational_space_backend_with_a_garbage_inverse_cannot_hide_behind_breakdown(monkeypatch):
    """Issue 15's red-team mutant: an inverse mass matrix of garbage makes J M^-1 J^T indefinite, cond(task) = inf
    at every state; before the audit it was BREAKDOWN at all 20 states and the gate said PASS. Now every state
    fails, the conditions check names it, and its answers are compared."""
    monkeypatch.setattr(osc, "_inverse_mass_matrix", lambda model, M, q: -np.eye(M.shape[-1]) * np.ones(M.shape))
    result = run_gate([CaseSpec("double_pendulum")], ALL, 20, 0, checks=QUICK)
    model, checked = result.cases[0].model, 0
    assert not result.passed
    for s in result.cases[0].states:
        truth = conditioning.independent(model, s.state.q, s.state.qd, s.state.u)
        if max(truth["task"], truth["task_jacobian"]) > policy.BREAKDOWN_LIMITS["task"] / 2:
            continue                                # the task is truly (nearly) singular: the claim may stand
        checked += 1
        assert s.failed and "operational_space" not in s.breakdowns
        assert suspect(s.checks["conditions: task"]) == "operational_space"
    assert checked >= 15


def test_a_missed_breakdown_is_flagged():
    """A backend that reports a well-conditioned task where the harness finds it ill-conditioned (the double pendulum
    nearly stretched, theta2 = 1e-4: cond 1e8) disagrees in the conditions check. (Exactly stretched, J's shortest
    row is rounding and no condition is determined; the backend's garbage is then compared.)"""
    import dataclasses

    correct = osc.split
    model = cases.load("double_pendulum")
    state = State(0, (0.3, 1e-4), (1.0, 2.0), (1.0, 1.0))
    fake = interface.Formalism("operational_space", "", lambda m, q, qd, u: dataclasses.replace(
        correct(m, q, qd, u), conditions={"task": 10.0, "task_jacobian": 10.0}))
    outcome = evaluate(model, state, [b for b in ALL if b.name != "operational_space"] + [fake])
    check = outcome.checks["conditions: task"]
    assert check.verdict == DISAGREE and suspect(check) == "operational_space"


def test_a_row_a_few_nanometres_long_rounds_its_condition_numbers():
    """A fuzz finding: a point 2.35e-9 m off its line (a degenerate row below the floor, dropped by every backend);
    cond S, 1.4, is made of that row's eigenvalue, which rounds at eps L / |row| relative (4e-7), and the backends'
    values differed by 8e-8 against a tolerance of 1e-9. The rounding of short rows is in the audit's tolerance."""
    from cases import PointOnLine

    spinner = np.diag([0.25, 0.25, 0.025])
    model = cases.build_model("short_row", [
        cases.Body("b0", None, "revolute", (0, 0, 1), 1.0, inertia=spinner),
        cases.Body("b1", "b0", "revolute", (0, 0, 1), 1.0, inertia=spinner),
        cases.Body("b2", None, "revolute", (0, 0, 1), 1.0, com=(0, 0.5, 0), translation=(0, 1, 0))],
        task_points=[cases.TaskPoint("tip", "b2", (0, 0, 0), directions=[[1, 0, 0]])],
        constraints=[PointOnLine("c0", "b2", (0.5, 0, 0), (0.5, 1, 0), [[1, 0, 0]])])
    outcome = evaluate(model, State(0, (0.0, 0.0, 4.706175195600791e-09), (0.0, 0.0, 0.0), (0.0, 0.0, 0.0)), ALL)
    assert outcome.checks["conditions: constraint"].verdict != DISAGREE and not outcome.failed
