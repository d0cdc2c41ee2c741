"""Progress and Ctrl-C (``crosscheck.engine.progress``, ``crosscheck.engine.run.Interrupted``): the display is a live bar on a
terminal only, plain notes elsewhere, nothing with ``--quiet``; Ctrl-C ends gate, faults and bench with exit code 130,
one line on stderr, no traceback, and a partial report that says so and never says PASS, also when the gate's cases
run in worker processes and the signal reaches the whole process group.
"""

from __future__ import annotations

import io
import os
import signal
import subprocess
import sys
import time

import pytest
from rich.console import Console

import formalisms.newton_euler as ne
import crosscheck
from crosscheck import backends, cli
from crosscheck.campaigns import bench
from crosscheck.faults import injection
from crosscheck.engine import run
from crosscheck.engine import phases
from crosscheck.reports import gate_summary
from crosscheck.faults.injection import Hunt
from crosscheck.engine.specs import CaseSpec, Checks
from crosscheck.engine import progress
from crosscheck.engine.progress import Display
from formalisms.interface import Formalism

#: A gate as small as it gets: no charts, frames, conservation or self-test.
BARE = ["--no-charts", "--frames", "0", "--no-conservation", "--no-self-test", "--workers", "0"]


@pytest.fixture(autouse=True)
def not_forced_to_a_terminal(monkeypatch):
    """Captured stderr is not a terminal, whatever a CI environment tells rich (``FORCE_COLOR``, ...)."""
    for name in ("FORCE_COLOR", "TTY_COMPATIBLE", "TTY_INTERACTIVE"):
        monkeypatch.delenv(name, raising=False)


def _shown(terminal: bool, quiet: bool = False) -> str:
    """Everything a display writes on its console through a short run."""
    out = io.StringIO()
    console = Console(file=out, force_terminal=terminal, width=120)
    with Display("gate", "states", 4, quiet=quiet, console=console) as display:
        display.doing("panda: preparing euler_lagrange")
        display.advance(2)
        display.note("  panda: 2 states evaluated")
    return out.getvalue()


def test_the_display_is_a_bar_on_a_terminal_plain_notes_elsewhere_and_nothing_when_quiet():
    live = _shown(terminal=True)
    assert "2/4" in live and "states" in live and "ETA" in live and "panda: 2 states evaluated" in live
    assert _shown(terminal=False) == "  panda: 2 states evaluated\n"
    assert _shown(terminal=True, quiet=True) == ""


def _gate(tmp_path, *args) -> tuple[int, str]:
    return cli.main(["gate", "--case", "double_pendulum", "--case", "acrobot", "--samples", "3", *BARE,
                     "--report", str(tmp_path / "gate.md"), *args]), str(tmp_path / "gate.md")


def test_quiet_silences_the_gates_progress(tmp_path, capsys):
    assert _gate(tmp_path)[0] == 0
    assert capsys.readouterr().err == "  double_pendulum: 3 states evaluated\n  acrobot: 3 states evaluated\n"
    assert _gate(tmp_path, "--quiet")[0] == 0
    captured = capsys.readouterr()
    assert captured.err == "" and "PASS: report written to" in captured.out


@pytest.fixture
def interrupt_at(monkeypatch):
    """Ctrl-C at the progress step of a case about to evaluate state k + 1 (after k states)."""
    def arm(case: str, k: int) -> None:
        real = cli.gate._gate_progress

        def interrupting(display):
            inner = real(display)

            def progress(step: phases.Step) -> None:
                inner(step)
                if (step.case, step.phase, step.done) == (case, phases.EVALUATING, k):
                    raise KeyboardInterrupt

            return progress

        monkeypatch.setattr(cli.gate, "_gate_progress", interrupting)
    return arm


@pytest.mark.parametrize("quiet", [True, False])
def test_ctrl_c_in_a_case_ends_with_one_line_and_a_partial_report(quiet, tmp_path, capsys, interrupt_at):
    interrupt_at("acrobot", 2)
    code, path = _gate(tmp_path, *(["--quiet"] if quiet else []))
    captured = capsys.readouterr()
    assert code == 130 and captured.out == ""
    message = f"crosscheck: interrupted after 2/3 states of case 'acrobot'; partial report written to {path}"
    assert captured.err.splitlines() == ([] if quiet else ["  double_pendulum: 3 states evaluated"]) + [message]
    assert "Traceback" not in captured.err
    text = gate_summary.read(path)
    assert "**PARTIAL REPORT: the run was interrupted after 2/3 states of case 'acrobot'.**" in text
    assert "**PARTIAL**: 0 of 5 states" in text and "PASS" not in text
    assert "| double_pendulum | 2 | total | 3 | 0 |" in text and "| acrobot | 2 | total | 2 | 0 |" in text


def test_ctrl_c_in_a_backend_gives_the_partial_result_which_never_passes():
    """A KeyboardInterrupt raised inside a backend's split is not taken for a backend error. The states are evaluated
    in blocks (the first alone, then the rest together: ``gate._blocks``), so the third call (the second state of the
    second block) leaves one state complete."""
    calls = []

    def split(model, q, qd, u):
        calls.append(1)
        if len(calls) == 3:
            raise KeyboardInterrupt
        return ne.split(model, q, qd, u)

    chosen = [backends.get("pinocchio"), Formalism("newton_euler", "interrupted at its third call", split)]
    with pytest.raises(run.Interrupted) as stop:
        run.run_gate([CaseSpec("acrobot")], chosen, 5, 0, checks=Checks(charts=False, frames=0))
    result = stop.value.result
    assert result.interrupted == "after 1/5 states of case 'acrobot'" and not result.passed
    assert [len(c.states) for c in result.cases] == [1] and result.self_test is None
    assert not any(s.errors for s in result.cases[0].states)


def test_the_gate_tells_each_step_and_the_first_call_of_each_backend():
    steps = []
    chosen = [backends.get("pinocchio"), backends.get("newton_euler")]
    run.run_gate([CaseSpec("acrobot")], chosen, 2, 0, steps.append, Checks(charts=False, frames=0,
                                                                           closed_forms=False))
    assert [s.text for s in steps] == [
        f"acrobot: {phases.SETTING_UP}", "acrobot: evaluating state 1/2", "acrobot: preparing pinocchio",
        "acrobot: evaluating state 1/2", "acrobot: preparing newton_euler", "acrobot: evaluating state 1/2",
        "acrobot: evaluating state 2/2", "acrobot: 2 states evaluated", phases.SELF_TEST]


def test_ctrl_c_in_faults_keeps_the_faults_hunted(tmp_path, capsys, monkeypatch):
    calls = []

    def hunt(fault, **kw):
        calls.append(fault.name)
        if len(calls) == 2:
            raise KeyboardInterrupt
        return Hunt(fault, False, 3, 0.1)

    monkeypatch.setattr(injection, "hunt", hunt)
    report = tmp_path / "faults.md"
    code = cli.main(["faults", "--fault", "geo-task-bias-dropped", "--fault", "osc-task-bias-dropped", "--quiet",
                     "--workers", "0", "--report", str(report)])
    captured = capsys.readouterr()
    assert code == 130 and "Traceback" not in captured.err
    assert captured.err.splitlines() == [f"crosscheck: interrupted after 1/2 faults; partial report written to "
                                         f"{report}"]
    text = report.read_text()
    assert "**PARTIAL**: the run was interrupted after 1/2 faults" in text
    assert "| `geo-task-bias-dropped` |" in text and "`osc-task-bias-dropped`" not in text


def test_ctrl_c_in_bench_writes_what_was_measured(tmp_path, capsys, monkeypatch):
    measured = bench.Measurement("newton_euler", "double_pendulum", 2, None, 1e-5, 1e-6, 10, True, 1e-6,
                                 {"drift": 1e-16, "ctrl": 0.0, "total": 1e-16},
                                 {"drift": 2e-16, "ctrl": 0.0, "total": 2e-16}, 0, 2)

    def interrupted(plan, scene, names, display):
        yield measured
        display.doing(f"measuring pinocchio on {scene.label}")
        raise KeyboardInterrupt

    monkeypatch.setattr(bench, "measure_scene", interrupted)
    code = cli.main(["bench", "--quick", "--no-stability", "--quiet", "--out", str(tmp_path)])
    captured = capsys.readouterr()
    report = tmp_path / "speed_accuracy.md"
    assert code == 130 and "Traceback" not in captured.err
    assert captured.err.splitlines() == ["crosscheck: interrupted while measuring pinocchio on double_pendulum; "
                                         f"partial report written to {report}"]
    text = report.read_text()
    assert "**PARTIAL**: the run was interrupted while measuring pinocchio on double_pendulum" in text
    assert "| double_pendulum | 2 | newton_euler |" in text


SLOW_PLUGIN = '''
import os
import time
from pathlib import Path

from formalisms import newton_euler
from formalisms.interface import Formalism


def split(model, q, qd, u):
    Path(os.environ["SLOW_MARKER"]).write_text(str(os.getpid()))
    time.sleep(0.05)
    return newton_euler.split(model, q, qd, u)


SLOW = Formalism("slow", "Newton-Euler, 50 ms a call, marking that a worker evaluates", split)
'''


def test_ctrl_c_to_the_process_group_stops_the_gates_workers_without_a_traceback(tmp_path):
    """SIGINT to the whole process group, as Ctrl-C at a terminal sends it, while the cases run in two worker
    processes: the command ends with exit code 130 and its one line, the workers print nothing."""
    (tmp_path / "slow_backend.py").write_text(SLOW_PLUGIN)
    marker, report = tmp_path / "marker", tmp_path / "gate.md"
    env = {**os.environ, "SLOW_MARKER": str(marker),
           "PYTHONPATH": os.pathsep.join([str(tmp_path), os.environ.get("PYTHONPATH", "")]).rstrip(os.pathsep)}
    argv = ["gate", "--case", "double_pendulum", "--case", "acrobot", "--samples", "50", *BARE[:-2],
            "--formalism", "pinocchio", "--formalism", "slow", "--plugin", "slow_backend:SLOW", "--workers", "2",
            "--quiet", "--report", str(report)]
    proc = subprocess.Popen([sys.executable, "-m", "crosscheck.cli", *argv], env=env, stdout=subprocess.PIPE,
                            stderr=subprocess.PIPE, text=True, start_new_session=True)
    try:
        deadline = time.monotonic() + 120
        while not marker.exists() and proc.poll() is None and time.monotonic() < deadline:
            time.sleep(0.02)
        assert marker.exists(), f"no worker evaluated a state: {proc.communicate()}"
        os.killpg(proc.pid, signal.SIGINT)
        stdout, stderr = proc.communicate(timeout=60)
    finally:
        if proc.poll() is None:
            os.killpg(proc.pid, signal.SIGKILL)
            proc.communicate()
    assert proc.returncode == 130 and stdout == "" and "Traceback" not in stderr, stderr
    assert stderr.splitlines() == [f"crosscheck: interrupted after 0/2 cases (run in worker processes: the cases in "
                                   f"flight are not in the report); partial report written to {report}"]
    text = gate_summary.read(report)
    assert "**PARTIAL**" in text and "PASS" not in text


def test_only_a_spawned_pool_worker_ignores_ctrl_c():
    """A process that inherits the worker mark from its parent but is not a pool worker multiprocessing spawned (a
    ``crosscheck`` command a test or a script starts while its own pool is open) keeps its Ctrl-C."""
    probe = "import signal, crosscheck; print(signal.getsignal(signal.SIGINT) is signal.default_int_handler)"
    env = {**os.environ, crosscheck.WORKER: str(os.getpid())}
    done = subprocess.run([sys.executable, "-c", probe], env=env, capture_output=True, text=True, check=True)
    assert done.stdout.strip() == "True", done.stderr


def test_without_a_terminal_a_heartbeat_line_comes_at_least_every_interval(monkeypatch):
    """A CI log gets a line every ``HEARTBEAT_S`` while the command runs, even while nothing advances (a long
    derivation): what runs now, the count, the elapsed time and an ETA once something is done."""
    monkeypatch.setattr(progress, "HEARTBEAT_S", 0.05)
    out = io.StringIO()
    with Display("gate", "states", 4, console=Console(file=out, force_terminal=False, width=200)) as display:
        display.doing("g1: preparing euler_lagrange")
        time.sleep(0.3)
        display.advance(2)
        time.sleep(0.3)
    lines = out.getvalue().splitlines()
    assert len(lines) >= 4, lines
    assert lines[0].startswith("crosscheck gate: 0/4 states, 0:00 elapsed; g1: preparing euler_lagrange"), lines
    assert any(line.startswith("crosscheck gate: 2/4 states, ") and ", ETA 0:0" in line for line in lines), lines
    quiet = io.StringIO()
    with Display("gate", "states", 4, quiet=True, console=Console(file=quiet, force_terminal=False)):
        time.sleep(0.2)
    assert quiet.getvalue() == ""


def test_sigterm_ends_the_gate_like_ctrl_c_with_a_partial_report(tmp_path):
    """SIGTERM (``timeout``, a CI job's limit) to the gate's process alone: exit 143, one line that says so, and the
    partial report, as at Ctrl-C."""
    (tmp_path / "slow_backend.py").write_text(SLOW_PLUGIN)
    marker, report = tmp_path / "marker", tmp_path / "gate.md"
    env = {**os.environ, "SLOW_MARKER": str(marker),
           "PYTHONPATH": os.pathsep.join([str(tmp_path), os.environ.get("PYTHONPATH", "")]).rstrip(os.pathsep)}
    argv = ["gate", "--case", "double_pendulum", "--samples", "200", *BARE[:-2], "--formalism", "pinocchio",
            "--formalism", "slow", "--plugin", "slow_backend:SLOW", "--workers", "0", "--quiet", "--report",
            str(report)]
    proc = subprocess.Popen([sys.executable, "-m", "crosscheck.cli", *argv], env=env, stdout=subprocess.PIPE,
                            stderr=subprocess.PIPE, text=True)
    try:
        deadline = time.monotonic() + 120
        while not marker.exists() and proc.poll() is None and time.monotonic() < deadline:
            time.sleep(0.02)
        assert marker.exists(), f"no state was evaluated: {proc.communicate()}"
        proc.terminate()
        stdout, stderr = proc.communicate(timeout=60)
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.communicate()
    assert proc.returncode == 143 and "Traceback" not in stderr, stderr
    (line,) = stderr.splitlines()
    assert line.startswith("crosscheck: terminated by SIGTERM after ") and f"partial report written to {report}" in line
    text = gate_summary.read(report)
    assert "**PARTIAL**" in text and "PASS" not in text
