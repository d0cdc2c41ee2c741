"""The gate and the command line: exit codes, reports, reproduce commands, and a gate that can fail."""

from __future__ import annotations

import dataclasses
import json
import shlex

import numpy as np
import pytest

import cases
import formalisms.newton_euler as ne
from closed_forms import pendulum_terms
from crosscheck import backends, cli
from crosscheck.engine import pool
from crosscheck.core.compare import DISAGREE, suspect
from crosscheck.engine.specs import CaseSpec, Checks
from crosscheck.engine.run import run_gate
from crosscheck.reports import gate_summary
from crosscheck.reports.gate_summary import render
from crosscheck.core.sampling import sample_states
from crosscheck.core.tolerance import BREAKDOWN_LIMITS
from formalisms import euler_lagrange
from formalisms.interface import Formalism

DP_STATE = ["--q=0.7853981633974483,0.5235987755982988", "--qd=2,-1", "--u=5,-2"]


def _gate(tmp_path, *args):
    report = tmp_path / "gate.md"
    code = cli.main(["gate", *args, "--report", str(report)])
    return code, gate_summary.read(report) if report.exists() else ""


def _without_timing(report: str) -> str:
    return report.split("## Timing")[0]


def test_gate_passes_and_is_reproducible(tmp_path):
    code, first = _gate(tmp_path, "--case", "double_pendulum", "--case", "acrobot", "--samples", "15", "--seed", "3")
    assert code == 0
    assert "**PASS**" in first and "| acrobot | 2 | total | 15 | 0 |" in first
    _, second = _gate(tmp_path, "--case", "double_pendulum", "--case", "acrobot", "--samples", "15", "--seed", "3")
    assert _without_timing(first) == _without_timing(second)
    _, other_seed = _gate(tmp_path, "--case", "double_pendulum", "--case", "acrobot", "--samples", "15", "--seed", "4")
    assert _without_timing(first) != _without_timing(other_seed)


def test_workers_give_the_same_report_with_the_cases_in_order(tmp_path, monkeypatch):
    """Cases in two spawned processes (the larger model, n_link_pendulum, starts first): the report of one process,
    timings apart, cases in the order given. ``--workers`` means what it means in every command: 0 runs in this
    process, N in N worker processes (``tests/reports/test_outputs.py``)."""
    pooled, real = [], pool.in_pool
    monkeypatch.setattr(pool, "in_pool", lambda *args: pooled.append(args[7]) or real(*args))
    args = ("--case", "double_pendulum", "--case", "n_link_pendulum", "--samples", "4", "--seed", "2")
    code, alone = _gate(tmp_path, *args, "--workers", "0")
    assert code == 0 and not pooled
    code, together = _gate(tmp_path, *args, "--workers", "2")
    assert code == 0 and pooled == [2]
    assert _without_timing(together).replace("--workers 2", "--workers 0") == _without_timing(alone)
    timing = together.split("## Timing")[1]
    assert 0 < timing.index("| double_pendulum |") < timing.index("| n_link_pendulum |")


def test_backends_another_process_cannot_take_run_in_this_one(monkeypatch):
    """A backend that cannot be pickled (a lambda) keeps every case in this process, whatever ``workers`` says."""
    pooled, real = [], pool.in_pool
    monkeypatch.setattr(pool, "in_pool", lambda *args: pooled.append(args[1]) or real(*args))
    local = Formalism("newton_euler", "a lambda", lambda model, q, qd, u: ne.split(model, q, qd, u))
    chosen = [backends.get("euler_lagrange"), local, backends.get("pinocchio")]
    result = run_gate([CaseSpec("acrobot"), CaseSpec("double_pendulum")], chosen, samples=2, seed=0, workers=2)
    assert not pooled and result.passed
    assert [c.spec.name for c in result.cases] == ["acrobot", "double_pendulum"]
    assert all("newton_euler" in s.splits for c in result.cases for s in c.states)


def test_dropped_coriolis_fails_the_gate_and_is_named(tmp_path, dropped_coriolis, capsys):
    code, report = _gate(tmp_path, "--case", "double_pendulum", "--samples", "10")
    assert code == 1
    assert "**FAIL**" in report and "## Disagreements" in report
    assert "outlier **euler_lagrange**" in report
    # ctrl does not involve C qd: it must still agree, so the report localizes the bug to drift and total.
    # State #0 is the home configuration theta2 = 0, where C qd = 0 (eq. 7), so the fault hides there.
    assert "| double_pendulum | 2 | ctrl | 10 | 0 |" in report
    assert "| double_pendulum | 2 | drift | 1 | 9 |" in report
    # every listed disagreement has a reproduce command that runs and shows the discrepancy
    disagreements = report.split("## Disagreements")[1]
    command = next(line for line in disagreements.splitlines() if "reproduce: `" in line).split("`")[1]
    argv = shlex.split(command)[1:] + ["--json"]
    assert f"     reproduce state #1: {command}\n" in capsys.readouterr().out   # printed too, the first failing state
    assert cli.main(argv) == 1   # the backends disagree there: eval's verdict says so
    data = json.loads(capsys.readouterr().out)
    assert data["verdict"]["agree"] is False and data["verdict"]["outliers"] == ["euler_lagrange"]
    out = data["formalisms"]
    assert not np.allclose(out["euler_lagrange"]["drift"], out["pinocchio"]["drift"])
    np.testing.assert_allclose(out["newton_euler"]["drift"], out["pinocchio"]["drift"], rtol=1e-12)


def test_a_failing_report_is_reproducible_and_puts_the_failures_first(tmp_path, dropped_coriolis):
    """The summary file leads with the disagreements (before what was run and the case table); the details file
    (read after it) holds the counts, suspects, per-quantity table and the rest."""
    args = ("--case", "double_pendulum", "--samples", "6", "--frames", "1", "--no-registry")
    code, first = _gate(tmp_path, *args)
    assert code == 1
    _, second = _gate(tmp_path, *args)
    assert _without_timing(first) == _without_timing(second)      # hints and suspects included
    sections = ["## Disagreements", "- command: ", "## Cases", "## Summary", "## Breakdowns",
                "## Invariance and conservation checks", "## Worst state per case", "## Timing"]
    assert [first.index(h) for h in sections] == sorted(first.index(h) for h in sections)
    assert "| double_pendulum | 2 | 6 | 5 |" in first.split("## Cases")[1]      # n, states, failing states
    summary = first.split("## Summary")[1]
    assert "| double_pendulum | 6 | 5 |" in summary                  # states, failing states
    assert "| double_pendulum | euler_lagrange | 15 |" in summary     # suspect: drift, total, drift_velocity at 5
    assert "| double_pendulum | 2 | drift | 1 | 5 | 0 | 0 |" in summary and "| gross |" in summary
    detail = first.split("## Disagreements")[1].split("\n## ")[0]
    assert detail.count("- hint: euler_lagrange's drift error x4 when qd doubles, 0 at qd = 0") == 5
    assert "- **drift**: DISAGREE (gross), worst error/tolerance" in detail


def test_two_backends_disagree_without_a_vote(dropped_coriolis):
    chosen = [backends.get("euler_lagrange"), backends.get("pinocchio")]
    result = run_gate([CaseSpec("double_pendulum")], chosen, samples=5, seed=0, checks=Checks(closed_forms=False))
    assert not result.passed
    comp = result.cases[0].states[1].comparisons["drift"]  # state #0 is home, where C qd = 0
    assert comp.verdict == DISAGREE and comp.outlier is None


def test_eval_json_matches_article_closed_form(capsys):
    assert cli.main(["eval", "--case", "double_pendulum", *DP_STATE, "--json"]) == 0
    data = json.loads(capsys.readouterr().out)
    assert data["case"] == "double_pendulum"
    assert set(data["formalisms"]) == set(backends.names()) | {"closed_form"}
    q, qd, tau = (np.pi / 4, np.pi / 6), (2.0, -1.0), np.array([5.0, -2.0])
    M, Cqd, g = pendulum_terms(q, qd)  # eqs. (6), (7), (8) at m1 = m2 = 1, l1 = l2 = 1, g = 9.81
    h = Cqd + g
    for name, values in data["formalisms"].items():
        assert values["lam"] is None and values["lam_drift"] is None
        np.testing.assert_allclose(values["total"], np.linalg.solve(M, tau - h), rtol=1e-12, err_msg=name)
        np.testing.assert_allclose(values["ctrl"], np.linalg.solve(M, tau), rtol=1e-12, err_msg=name)


def test_eval_ends_with_a_verdict_and_its_json_uses_null_for_what_a_backend_does_not_supply(capsys):
    assert cli.main(["eval", "--case", "double_pendulum", *DP_STATE]) == 0
    assert capsys.readouterr().out.splitlines()[-1].startswith("verdict: agree (worst ratio ")
    assert cli.main(["eval", "--case", "double_pendulum", *DP_STATE, "--json"]) == 0
    data = json.loads(capsys.readouterr().out)
    assert data["verdict"]["agree"] is True and data["verdict"]["worst_ratio"] < 1.0
    assert "task_inertia" in data["unsupported_quantities"]["euler_lagrange"]
    assert data["formalisms"]["euler_lagrange"]["task_inertia"] is None
    assert "UNSUPPORTED" not in json.dumps(data["formalisms"])


def test_eval_names_the_disagreement_and_its_outlier(dropped_coriolis, capsys):
    assert cli.main(["eval", "--case", "double_pendulum", *DP_STATE]) == 1
    last = capsys.readouterr().out.splitlines()[-1]
    assert last.startswith("verdict: DISAGREE: ") and "outlier euler_lagrange" in last, last


@pytest.mark.parametrize("argv, fragment", [
    (["gate", "--case", "no_such_case"], "unknown case 'no_such_case'; valid cases: double_pendulum"),
    (["eval", "--case", "double_pendulum", "--q=0.1"], "--q has 1 entries; this model needs 2"),
    (["eval", "--case", "double_pendulum", "--q=0.1,nan"], "q has non-finite entries"),
    (["eval", "--case", "double_pendulum", "--q=0.1,abc"], "--q takes comma-separated numbers"),
    (["eval", "--case", "double_pendulum", "--param", "m1=-1", "--q=0,0"], "m1 must be positive, got -1.0"),
    (["eval", "--case", "double_pendulum", "--param", "mass=2", "--q=0,0"],
     "has no parameter(s) 'mass'; valid parameters"),
    (["eval", "--case", "double_pendulum", "--q=0,0", "--formalism", "hamilton"], "valid: euler_lagrange"),
    (["eval", "--model", "/no/such/robot.urdf", "--q=0"], "/no/such/robot.urdf"),
    (["gate", "--samples", "0"], "--samples must be at least 1"),
    (["gate", "--workers", "-1"], "--workers takes 0 to"),
    (["frobnicate"], "invalid choice"),
])
def test_bad_input_exits_2_with_one_line(argv, fragment, capsys):
    assert cli.main(argv) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and err.startswith("crosscheck: error: ")
    assert fragment in err
    assert "Traceback" not in err


def test_listing_commands(capsys):
    assert cli.main(["cases"]) == 0
    listing = capsys.readouterr().out
    for name in ("double_pendulum", "n_link_pendulum", "acrobot", "spatial_arm", "panda"):
        assert name in listing
    assert cli.main(["formalisms"]) == 0
    listing = capsys.readouterr().out
    assert all(name in listing for name in
               ("euler_lagrange", "newton_euler", "screw", "operational_space", "pinocchio"))
    assert f"evaluation: {euler_lagrange.evaluation()}\n" in listing  # compiled C, or interpreted Python and why


def test_eval_marks_a_backend_in_breakdown(capsys):
    """The stretched double pendulum (theta2 = 0) is a task singularity (article 6.3.4)."""
    assert cli.main(["eval", "--case", "double_pendulum", "--q=0.3,0", "--qd=1,2", "--u=1,1"]) == 0
    out = capsys.readouterr().out
    assert "operational_space (joint chart): BREAKDOWN (cond task = inf > 1e+03, cond task_jacobian = " in out
    assert "newton_euler (joint chart):\n" in out and "newton_euler (joint chart): BREAKDOWN" not in out


def test_unparsable_urdf_exits_2(tmp_path, capsys):
    path = tmp_path / "broken.urdf"
    path.write_text("<robot name='x'><link name='a'></robot>")
    assert cli.main(["gate", "--model", str(path), "--samples", "1", "--report", str(tmp_path / "r.md")]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and str(path) in err


def test_a_split_that_does_not_add_up_is_named():
    """total solved with the wrong sign of the input: drift and ctrl are right, the total is not, and the
    additivity check (drift + ctrl - total = 0, exact) names the backend along with the total comparison."""
    correct = ne.split

    def broken(model, q, qd, u):
        s = correct(model, q, qd, u)
        wrong_total = s.drift - s.ctrl
        return dataclasses.replace(s, total=wrong_total)

    backend = Formalism(name="newton_euler", summary="total with the input's sign flipped", split=broken)
    chosen = [backends.get("euler_lagrange"), backend, backends.get("pinocchio")]
    result = run_gate([CaseSpec("acrobot")], chosen, samples=5, seed=0)
    comps = [s.comparisons for s in result.cases[0].states]
    assert all(c["additivity"].verdict == DISAGREE and c["additivity"].outlier == "newton_euler" for c in comps)
    assert all(c["drift"].verdict != DISAGREE and c["ctrl"].verdict != DISAGREE for c in comps)


@pytest.mark.parametrize("condition", [1e30, float("inf"), float("nan")])
def test_a_false_breakdown_claim_fails_and_the_backend_votes(condition):
    """Issue 15, BREAKDOWN is a claim: a backend reporting its method ill-conditioned (a condition above its limit, or
    NaN) where the harness's own condition is well below the limit does not escape the vote: the ``conditions`` check
    names it, and its garbage answers are compared and fail."""
    correct = ne.split

    def ill_conditioned(model, q, qd, u):
        s = correct(model, q, qd, u)
        nan = np.full(model.n, np.nan)
        return dataclasses.replace(s, drift=nan, total=nan, conditions={"task": condition})

    backend = Formalism(name="newton_euler", summary="claims a singular task at every state", split=ill_conditioned)
    chosen = [backends.get("euler_lagrange"), backend, backends.get("pinocchio")]
    result = run_gate([CaseSpec("acrobot")], chosen, samples=3, seed=0, checks=Checks(self_test=False))
    assert not result.passed
    for state in result.cases[0].states[1:]:                    # #0 is the home configuration, singular for Lambda
        check = state.checks["conditions: task"]
        assert check.verdict == DISAGREE and suspect(check) == "newton_euler"
        assert "newton_euler" not in state.breakdowns and state.comparisons["drift"].verdict == DISAGREE
    assert "conditions: task" in render(result, "cmd")


def test_a_genuine_breakdown_is_reported_not_compared():
    """The operational-space backend at the stretched acrobot (a task singularity, article 6.3.4): in BREAKDOWN, left
    out of the comparisons, the claim confirmed by the harness's own condition, the state listed with a reproduce
    command, and the run passes where the backend may be in BREAKDOWN (``--allow-breakdown``): at one state, it is
    out at every state, which otherwise fails the run (issue 34)."""
    chosen = [backends.get(name) for name in ("euler_lagrange", "operational_space", "pinocchio")]
    result = run_gate([CaseSpec("acrobot")], chosen, samples=1, seed=0, checks=Checks(self_test=False))
    assert not result.passed and result.broken == {"acrobot": {"operational_space": 1}}   # out at 1 of 1 states
    result = run_gate([CaseSpec("acrobot")], chosen, samples=1, seed=0, checks=Checks(self_test=False),
                      allow_breakdown=["operational_space"])
    state = result.cases[0].states[0]                           # the home configuration: links aligned
    assert result.passed and "task" in state.breakdowns["operational_space"]
    assert all("operational_space" not in pair for c in state.comparisons.values() for pair in c.pairs)
    assert state.checks["conditions: task"].verdict != DISAGREE
    report = render(result, "cmd")
    assert "| acrobot | operational_space | cond task |" in report
    assert "reproduce: `crosscheck eval --case acrobot" in report


def test_a_condition_below_its_limit_is_compared():
    def conditioned(model, q, qd, u):
        return dataclasses.replace(ne.split(model, q, qd, u), conditions={"task": BREAKDOWN_LIMITS["task"] / 2})

    chosen = [backends.get("euler_lagrange"), Formalism("newton_euler", "", conditioned), backends.get("pinocchio")]
    state = run_gate([CaseSpec("acrobot")], chosen, samples=1, seed=0).cases[0].states[0]
    assert "newton_euler" not in state.breakdowns
    assert ("euler_lagrange", "newton_euler") in state.comparisons["drift"].pairs
    assert all(set(b) == {"task_inertia"} for b in state.breakdowns.values())   # acrobot #0 is task-singular


def test_state_zero_is_the_home_configuration():
    model = cases.load("spatial_arm")
    states = sample_states(model, 3, seed=5, case="spatial_arm")
    assert states[0].q == (0.0,) * model.n and any(states[0].qd) and any(states[1].q)
    assert sample_states(model, 3, seed=5, case="spatial_arm") == states


def test_version(capsys):
    import importlib.metadata

    with pytest.raises(SystemExit) as stop:
        cli.main(["--version"])
    assert stop.value.code == 0
    assert capsys.readouterr().out == f"crosscheck {importlib.metadata.version('crosscheck')}\n"
