"""JUnit XML reports (``crosscheck.reports.junit``, ``crosscheck gate --junit``): well-formed, one testsuite per case, one
testcase per quantity and per check family, failures with the failing states, KNOWN passed with its reason,
BREAKDOWN listed, NOT COMPARED skipped."""

from __future__ import annotations

import dataclasses
import json
import shlex
import xml.etree.ElementTree as ET

import numpy as np

from crosscheck import backends, cli
from crosscheck.reports import diagnosis, junit
from crosscheck.engine import divergences
from crosscheck.engine.specs import CaseSpec, Checks
from crosscheck.engine.run import run_gate
from crosscheck.reports.gate_lines import check_family
from crosscheck.core.tolerance import quantities
from formalisms.interface import Formalism

ALL = [backends.get(name) for name in backends.names()]
QUICK = Checks(charts=False, frames=0, conservation=False, closed_forms=False, self_test=False, linearization=False)


def _parsed(result, tmp_path):
    path = tmp_path / "out" / "gate.xml"
    junit.write(result, path)
    root = ET.parse(path).getroot()                 # well-formed, or this raises
    assert path.read_text().startswith("<?xml version='1.0' encoding='utf-8'?>")
    return root


def _cases(suite):
    return {tc.get("name"): tc for tc in suite.findall("testcase")}


def test_a_passing_gate_has_one_suite_per_case_and_one_testcase_per_quantity_and_check_family(tmp_path):
    result = run_gate([CaseSpec("double_pendulum"), CaseSpec("slider_crank")], ALL, 3, 0,
                      checks=Checks(charts=True, frames=1, conservation=True))
    root = _parsed(result, tmp_path)
    suites = root.findall("testsuite")
    assert [s.get("name") for s in suites] == ["double_pendulum", "slider_crank", "self-test"]
    canaries = _cases(suites[-1])
    assert len(canaries) == len(result.self_test.results) and all(tc.find("failure") is None
                                                                  for tc in canaries.values())
    for suite, case in zip(suites, result.cases):
        families = {check_family(k) for s in case.states for k in s.checks}
        assert set(_cases(suite)) == set(quantities(case.model)) | families | {"sampling coverage", "backends compared"}
        assert int(suite.get("tests")) == len(suite.findall("testcase"))
        assert suite.get("failures") == "0" and suite.get("errors") == "0"
        assert {p.get("name"): p.get("value") for p in suite.iter("property")}["case"] == f"--case {case.spec.name}"
    assert int(root.get("tests")) == sum(int(s.get("tests")) for s in suites)
    assert root.get("failures") == "0" and not root.findall(".//failure")


def test_a_failing_gate_lists_the_failing_states_with_ratio_severity_outlier_and_command(tmp_path, dropped_coriolis,
                                                                                        capsys):
    result = run_gate([CaseSpec("double_pendulum")], ALL, 4, 0, checks=QUICK)
    diagnosis.annotate(result, ALL)
    suite = _parsed(result, tmp_path).find("testsuite")
    testcases = _cases(suite)
    failed = {name for name, tc in testcases.items() if tc.find("failure") is not None}
    assert failed == {"drift", "total", "drift_velocity"} and suite.get("failures") == "3"
    failure = testcases["drift"].find("failure")
    assert failure.get("type") == "DISAGREE"
    message = failure.get("message")
    assert message.startswith("3 DISAGREE at 3 of 4 states; worst #")
    assert "(gross), outlier euler_lagrange; reproduce: crosscheck eval --case double_pendulum --q=" in message
    lines = failure.text.splitlines()
    assert [line.split()[0] for line in lines] == ["#1", "#2", "#3"]
    assert all("hint: euler_lagrange's drift error x4 when qd doubles" in line for line in lines)
    # the command in the message reproduces the failure
    argv = shlex.split(message.split("reproduce: ")[1])[1:] + ["--json"]
    capsys.readouterr()
    assert cli.main(argv) == 1   # eval's verdict: the backends disagree there
    assert json.loads(capsys.readouterr().out)["verdict"]["outliers"] == ["euler_lagrange"]


def test_known_passes_with_its_reason_and_breakdown_is_listed(tmp_path, dropped_coriolis):
    result = run_gate([CaseSpec("double_pendulum")], ALL, 3, 0, checks=QUICK)
    reason = "test: velocity products dropped"
    text = "".join(f'[[divergence]]\nbackend = "euler_lagrange"\ncase = "*"\nquantity = "{q}"\nreason = "{reason}"\n'
                   for q in ("drift", "total", "drift_velocity"))
    divergences.apply(divergences.parse(text), result)
    suite = _parsed(result, tmp_path).find("testsuite")
    drift = _cases(suite)["drift"]
    assert drift.find("failure") is None and drift.find("system-out").text == f"KNOWN at 2 comparison(s): {reason}"
    assert suite.get("failures") == "0"
    out = suite.find("system-out").text.splitlines()
    assert out and all(line.startswith("BREAKDOWN #") and "; reproduce: crosscheck eval" in line for line in out)
    assert any(line.startswith("BREAKDOWN #0") and "operational_space: cond task = inf" in line for line in out)


def test_not_compared_is_skipped_and_backend_errors_are_errors(tmp_path):
    def raising(model, q, qd, u):
        raise np.linalg.LinAlgError("injected")

    chosen = [backends.get("euler_lagrange"), backends.get("geometric"), Formalism("newton_euler", "", raising)]
    result = run_gate([CaseSpec("acrobot")], chosen, 4, 0, checks=QUICK)
    suite = _parsed(result, tmp_path).find("testsuite")
    testcases = _cases(suite)
    skipped = testcases["task_drift"].find("skipped")     # only geometric supplies it: never two values
    assert skipped is not None and skipped.get("message") == ("NOT COMPARED: fewer than two values (not supplied "
                                                              "by euler_lagrange)")
    errors = [s for s in result.cases[0].states if s.errors]
    assert errors and suite.get("errors") == "1"
    error = testcases["backend errors"].find("error")
    assert error.get("message") == f"a backend raised at {len(errors)} states"
    assert "newton_euler: LinAlgError: injected" in error.text
    assert int(suite.get("skipped")) == sum(tc.find("skipped") is not None for tc in testcases.values())


def test_a_degenerate_sample_a_missed_canary_and_an_absent_backend_fail_on_the_dashboard(tmp_path, monkeypatch):
    """Every reason the gate fails shows as a failing testcase, not only a DISAGREE."""
    from crosscheck.guards import coverage, selftest

    result = run_gate([CaseSpec("acrobot")], ALL, 3, 0, checks=QUICK)
    result.cases[0].coverage = dataclasses.replace(result.cases[0].coverage, problems=("every joint rate is 0",))
    r = result.self_test = selftest.SelfTest((selftest.CanaryResult(selftest.CANARIES[0], False, False, 0.3, "-"),))
    result.required = ("nobody",)
    root = _parsed(result, tmp_path)
    suites = {s.get("name"): s for s in root.findall("testsuite")}
    assert _cases(suites["acrobot"])["sampling coverage"].find("failure").get("message") == "every joint rate is 0"
    assert _cases(suites["self-test"])[f"{r.results[0].canary.check}: {r.results[0].canary.describe()}"].find("failure") is not None
    assert _cases(suites["backends"])["nobody takes part"].find("failure") is not None
    assert root.get("failures") == "3" and not result.passed and isinstance(result.cases[0].coverage,
                                                                            coverage.Coverage)


def test_the_gate_writes_junit_next_to_the_report(tmp_path):
    path = tmp_path / "ci" / "junit.xml"
    assert cli.main(["gate", "--case", "acrobot", "--samples", "2", "--frames", "0", "--no-charts", "--no-registry",
                     "--report", str(tmp_path / "gate.md"), "--junit", str(path)]) == 0
    root = ET.parse(path).getroot()
    assert [s.get("name") for s in root.findall("testsuite")] == ["acrobot", "self-test"]
    assert root.get("failures") == "0"
