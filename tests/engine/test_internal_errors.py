"""The harness's own failures (``crosscheck.engine.internal``): an exception raised by crosscheck's code in a check is an
internal error of that check, the run goes on, the report is written with a section on them, and ``crosscheck gate``
exits 3; a backend raising stays that backend's error, bad input is still refused (exit 2), Ctrl-C still interrupts."""

from __future__ import annotations

import multiprocessing.pool
import xml.etree.ElementTree as ET

import numpy as np
import pytest

from crosscheck import backends, cli
from crosscheck.checks import charts
from crosscheck.core import tolerance
from crosscheck.core.compare import ToleranceError, compare
from crosscheck.engine import internal, pool, run
from crosscheck.engine.run import run_gate
from crosscheck.engine.specs import CaseSpec, Checks
from crosscheck.reports import gate_details, gate_summary

ALL = [backends.get(name) for name in backends.names()]
QUICK = Checks(self_test=False)


def _raising(*args, **kwargs):
    raise TypeError("injected into the tolerance")


#: Where ``_raising`` raises: this file is the project's code, so the last frame there is its own.
HERE, RAISES = "tests/engine/test_internal_errors.py", _raising.__code__.co_firstlineno + 1


def test_a_tolerance_raising_is_an_internal_error_of_each_check_and_the_run_goes_on(monkeypatch):
    monkeypatch.setattr(tolerance, "tolerance", _raising)
    result = run_gate([CaseSpec("double_pendulum")], ALL, samples=2, seed=0, checks=QUICK)
    assert not result.passed and result.has_internal_errors
    (case,) = result.cases
    assert len(case.states) == 2 and case.failed and not case.internal
    first = case.states[0]
    assert {"comparisons", "conservation", "chart affine", "frame g0"} <= set(first.internal), first.internal
    error = first.internal["comparisons"]      # the last frame in the project's code: here the injected function's
    assert str(error) == f"TypeError: injected into the tolerance ({HERE}:{RAISES} in _raising)"
    assert error.trace[-2:] == (error.trace[-2], error.where) and "in compare_all" in error.trace[-2]
    assert not first.errors                                          # no backend is blamed for the harness
    assert any(key.startswith("conditions: ") for key in first.checks)   # the checks that did not raise ran
    found = internal.occurrences(result)
    assert ("comparisons", "double_pendulum", 0, 2) in {(o.check, o.case, o.first, o.states) for o in found}


def test_a_nan_tolerance_is_the_harness_failing_where_it_was_computed(monkeypatch):
    with pytest.raises(ToleranceError, match="the tolerance for drift is nan"):
        compare("drift", {"a": [1.0], "b": [1.0]}, np.nan)
    with pytest.raises(ToleranceError, match="is -1"):
        compare("drift", {"a": [1.0], "b": [1.0]}, [1e-9, -1.0])
    real = tolerance.tolerance
    monkeypatch.setattr(tolerance, "tolerance", lambda quantity, at: real(quantity, at) * np.nan)
    result = run_gate([CaseSpec("double_pendulum")], ALL, samples=1, seed=0, checks=QUICK)
    error = result.cases[0].states[0].internal["comparisons"]
    assert error.kind == "ToleranceError" and error.where.startswith("crosscheck/engine/evaluation.py:")
    assert error.where.endswith("in compare_all")


def test_a_case_whose_setup_fails_is_reported_and_the_others_run(monkeypatch):
    sampled = charts.sampled

    def broken(model, seed, case, *args, **kwargs):
        if case == "acrobot":
            raise KeyError("a chart sampler bug")
        return sampled(model, seed, case, *args, **kwargs)

    monkeypatch.setattr(charts, "sampled", broken)
    result = run_gate([CaseSpec("acrobot"), CaseSpec("double_pendulum")], ALL, samples=2, seed=0, checks=QUICK)
    acrobot, pendulum = result.cases
    assert acrobot.internal["case setup"].error == "KeyError: 'a chart sampler bug'" and acrobot.states == []
    assert acrobot.failed and not result.passed
    assert len(pendulum.states) == 2 and not pendulum.failed and not pendulum.internal
    text = gate_summary.render(result, "cmd")
    assert "- **internal error in case setup** (acrobot, none of its states was evaluated): `KeyError: 'a chart " \
           f"sampler bug'` at `{HERE}:" in text


def test_bad_input_is_still_raised_and_ctrl_c_still_interrupts(monkeypatch):
    with pytest.raises(run.INPUT_ERRORS):
        run_gate([CaseSpec("double_pendulum", (("l1", "-1"),))], ALL, samples=1, seed=0, checks=QUICK)

    def interrupted(*args, **kwargs):
        raise KeyboardInterrupt

    monkeypatch.setattr(tolerance, "tolerance", interrupted)
    with pytest.raises(run.Interrupted):
        run_gate([CaseSpec("double_pendulum")], ALL, samples=1, seed=0, checks=QUICK)


def test_a_case_raising_anywhere_else_is_its_internal_error_also_from_a_worker_process(monkeypatch):
    def boom(*args, **kwargs):
        raise RuntimeError("outside every check")

    monkeypatch.setattr(run, "run_case", boom)
    outcome = run.run_case_guarded(CaseSpec("acrobot"), ALL, 1, 0, checks=QUICK)
    assert outcome.internal["case"].error == "RuntimeError: outside every check" and outcome.failed

    class Pending:          # a worker's result whose process raised: its traceback comes back as text
        def get(self):
            try:
                raise ValueError("in the worker") from multiprocessing.pool.RemoteTraceback(
                    'Traceback (most recent call last):\n  File "'
                    f'{internal.ROOT}/crosscheck/checks/frames.py", line 42, in move_scene\n    x\nValueError: x')
            except ValueError as exc:
                raise exc

    found = pool._outcome(Pending(), CaseSpec("acrobot"), run.failed_case, run.INPUT_ERRORS)
    assert str(found.internal["case"]) == "ValueError: in the worker (crosscheck/checks/frames.py:42 in move_scene)"


def _gate(tmp_path, *args):
    report = tmp_path / "gate.md"
    code = cli.main(["gate", "--case", "double_pendulum", "--samples", "2", "--workers", "0", "--no-self-test",
                     "--report", str(report), "--junit", str(tmp_path / "gate.xml"), *args])
    return code, gate_summary.read(report) if report.exists() else ""


def test_the_gate_reports_the_internal_error_and_exits_3(tmp_path, monkeypatch, capsys):
    monkeypatch.setattr(tolerance, "tolerance", _raising)
    code, report = _gate(tmp_path)
    out, err = capsys.readouterr()
    assert code == 3
    assert "Traceback" not in err and "Traceback" not in out
    assert "FAIL internal error in comparisons (double_pendulum, 2 states, first #0): TypeError: injected into the " \
           f"tolerance ({HERE}:{RAISES} in _raising)" in out
    assert "**The harness itself failed**" in report and "**FAIL**" in report
    summary = report.split("# crosscheck gate report: details")[0]
    assert summary.count("## Internal errors of the harness") == 1
    assert "- **internal error in comparisons** (double_pendulum, 2 of 2 states, first #0): `TypeError: injected " \
           f"into the tolerance` at `{HERE}:{RAISES} in _raising`" in summary
    assert "traceback in the project (innermost first" in report.split("# crosscheck gate report: details")[1]
    suite = ET.parse(tmp_path / "gate.xml").getroot().find("testsuite")
    failing = [t.get("name") for t in suite.iter("testcase") if t.find("failure") is not None]
    assert "internal errors of the harness" in failing


def test_a_report_section_the_harness_fails_to_write_is_named_and_the_rest_is_written(tmp_path, monkeypatch, capsys):
    monkeypatch.setattr(gate_details, "_power_audit", _raising)
    code, report = _gate(tmp_path)
    out = capsys.readouterr().out
    assert code == 3 and "FAIL internal error in report: power audit: TypeError" in out
    assert "(The section 'power audit' could not be written: the harness failed there: `TypeError: injected" in report
    summary = report.split("# crosscheck gate report: details")[0]
    assert "- **internal error in report: power audit** (the run): `TypeError: injected into the tolerance`" in summary
    assert "## Timing" in report                                     # the sections after it were written


def test_a_report_that_cannot_be_written_at_all_leaves_the_least_report(tmp_path, monkeypatch, capsys):
    monkeypatch.setattr(gate_summary, "summary", _raising)
    code, report = _gate(tmp_path)
    assert code == 3
    assert report.startswith("# crosscheck gate report\n\n**FAIL**: the harness failed while writing this report")
    assert "- **internal error in report** (the run): `TypeError: injected into the tolerance`" in report
