"""Plugin isolation (``crosscheck.isolation``): a plugin loaded by spec runs in a child process, so a crash of its
native code (here ``ctypes.string_at(0)``, a segfault) is an error of that plugin at that state, the run completes
and writes its report with the other backends compared, in this process and with ``--workers``; after
``CRASHES_IN_A_ROW`` crashes the plugin is not called again in the case; a plugin that fails at every state is one
report line per message, with its count of states."""

from __future__ import annotations

import sys
from pathlib import Path

import numpy as np
import pytest

import cases
from crosscheck import backends, cli
from crosscheck.needs import given
from crosscheck.reports import gate_summary
from formalisms.interface import ModelNotSupported

SEGFAULT = '''
import ctypes
from pathlib import Path


class Crashes:
    name = "crashes"

    def split(self, model, q, qd, u):
        with open(Path(__file__).with_suffix(".calls"), "a") as calls:   # one line per call that reached the plugin
            calls.write(model.name + "\\n")
        ctypes.string_at(0)            # reads address 0: SIGSEGV in native code, no Python exception


CRASHES = Crashes()
'''

#: A plugin whose own model building fails at every state (what a wrapper's URDF parser failing looks like).
NO_MODEL = '''
class NoModel:
    name = "no_model"

    def split(self, model, q, qd, u):
        raise ValueError(f"my parser cannot read {model.name}: unknown tag <transmission>")


NO_MODEL = NoModel()
'''


@pytest.fixture(autouse=True)
def fresh(monkeypatch):
    """Run from the repository root (examples/ by its path); no plugin before or after."""
    monkeypatch.chdir(Path(__file__).resolve().parents[2])
    for module in ("segfault_plugin", "no_model_plugin"):      # each test writes its own file of that name
        monkeypatch.delitem(sys.modules, module, raising=False)
    backends.reset()
    yield
    backends.reset()


@pytest.fixture
def plugin_files(tmp_path):
    (tmp_path / "segfault_plugin.py").write_text(SEGFAULT)
    (tmp_path / "no_model_plugin.py").write_text(NO_MODEL)
    return tmp_path


def _gate(tmp_path, *args) -> tuple[int, str]:
    report = tmp_path / "gate.md"
    code = cli.main(["gate", *args, "--report", str(report), "--quiet", "--no-self-test", "--no-linearization"])
    return code, gate_summary.read(report)


def _drift_row(report: str, case: str, n: int) -> dict[str, str]:
    """The per-quantity summary row of ``drift`` in ``case`` (``n`` coordinates): column header -> cell."""
    lines = report.splitlines()
    header = next(x for x in lines if x.startswith("| case | n | quantity |"))
    row = next(x for x in lines if x.startswith(f"| {case} | {n} | drift |"))
    return dict(zip(*([c.strip() for c in x.strip().strip("|").split("|")] for x in (header, row))))


def test_a_segfaulting_plugin_fails_the_gate_by_name_and_the_report_is_written(plugin_files):
    code, report = _gate(plugin_files, "--plugin", f"{plugin_files / 'segfault_plugin.py'}:CRASHES",
                         "--case", "double_pendulum", "--samples", "6")
    assert code == 1 and "**FAIL**" in report and "has not finished" not in report
    errors = [line for line in report.splitlines() if line.startswith("- **crashes raised**")]
    # state #0 crashes in the case's scene and in its moved scene, state #1 a third time: then no more calls
    assert errors == [
        "- **crashes raised** `PluginCrashed: plugin 'crashes' crashed (signal SIGSEGV) in split on model "
        "'double_pendulum'; its process is started again for the next call` (double_pendulum: 1 of 6 states, first #0)",
        "- **crashes raised** `PluginCrashed: plugin 'crashes' crashed (signal SIGSEGV) in split on model "
        "'double_pendulum@g0'; its process is started again for the next call` (double_pendulum: 1 of 6 states, "
        "first #0 as crashes@g0)",
        "- **crashes raised** `PluginCrashed: plugin 'crashes' crashed 3 times in a row (last: signal SIGSEGV in split "
        "on model 'double_pendulum'): not called again in this case (run it alone, e.g. crosscheck eval, to see "
        "where)` (double_pendulum: 5 of 6 states, first #1)"]
    drift = _drift_row(report, "double_pendulum", 2)          # the other six still compared at every state
    assert (drift["agree"], drift["DISAGREE"]) == ("6", "0")
    calls = (plugin_files / "segfault_plugin.calls").read_text().splitlines()
    assert calls == ["double_pendulum", "double_pendulum@g0", "double_pendulum"]   # CRASHES_IN_A_ROW, then no more


def test_a_segfaulting_plugin_in_worker_processes(plugin_files):
    code, report = _gate(plugin_files, "--plugin", f"{plugin_files / 'segfault_plugin.py'}:CRASHES",
                         "--case", "double_pendulum", "--case", "acrobot", "--samples", "3", "--workers", "2")
    assert code == 1 and "has not finished" not in report
    for case in ("double_pendulum", "acrobot"):
        assert f"crashed (signal SIGSEGV) in split on model '{case}'" in report
        assert _drift_row(report, case, 2)["agree"] == "3"
    calls = (plugin_files / "segfault_plugin.calls").read_text().splitlines()
    assert sorted(calls) == ["acrobot", "acrobot", "acrobot@g0", "double_pendulum", "double_pendulum",
                             "double_pendulum@g0"]          # each case tries it afresh: 3 crashes (#0, #0 moved, #1)


def test_a_plugin_failing_at_every_state_is_one_line_with_its_count(plugin_files):
    code, report = _gate(plugin_files, "--plugin", f"{plugin_files / 'no_model_plugin.py'}:NO_MODEL",
                         "--case", "double_pendulum", "--samples", "8", "--frames", "0", "--no-charts")
    assert code == 1
    lines = [line for line in report.splitlines() if "my parser cannot read" in line]
    assert lines == ["- **no_model raised** `ValueError: my parser cannot read double_pendulum: unknown tag "
                     "<transmission>` (double_pendulum: 8 of 8 states, first #0)"]
    assert "## Disagreements" not in report                  # no state disagrees: none is listed for its error alone


def test_the_child_answers_like_the_plugin_and_keeps_its_exceptions():
    """The split from the child is the plugin's, bit for bit; ModelNotSupported crosses back as it is."""

    formalism = backends.load_plugin("examples/my_dynamics.py:MY_DYNAMICS")
    model = cases.from_urdf("examples/arm.urdf", base="fixed")
    state = (np.array([0.3, -0.2, 0.1]), np.array([1.0, 0.5, -0.3]), np.zeros(model.m))
    isolated = formalism.split(model, *state)
    direct = formalism.split.function(given("pinocchio", model, "my_dynamics"), *state)
    for field in ("drift", "ctrl", "total", "accel_scale", "cond_M", "kinetic_energy"):
        np.testing.assert_array_equal(getattr(isolated, field), getattr(direct, field))
    assert not isolated.drift.flags.writeable
    four_bar = cases.load("four_bar")
    with pytest.raises(ModelNotSupported, match="unconstrained models only"):
        formalism.split(four_bar, np.zeros(four_bar.nq), np.zeros(four_bar.nv), np.zeros(four_bar.m))



def test_a_plugin_file_imports_the_modules_beside_it(tmp_path, monkeypatch):
    """``--plugin path/to/file.py:OBJ``: the file's folder is on sys.path here, in the workers of ``--workers`` and
    in the plugin's child process, so a helper module beside it imports."""
    monkeypatch.setattr(sys, "path", list(sys.path))
    folder = tmp_path / "my_wrapper"
    folder.mkdir()
    (folder / "sibling_helper_xyz.py").write_text("from crosscheck import backends\n\n"
                                                  "def split(model, q, qd, u):\n"
                                                  "    return backends.get('newton_euler').split(model, q, qd, u)\n")
    (folder / "sibling_plugin.py").write_text("import sibling_helper_xyz\n\n"
                                              "class Sibling:\n    name = 'sibling'\n\n"
                                              "    def split(self, model, q, qd, u):\n"
                                              "        return sibling_helper_xyz.split(model, q, qd, u)\n\n"
                                              "SIBLING = Sibling()\n")
    monkeypatch.delitem(sys.modules, "sibling_plugin", raising=False)
    monkeypatch.delitem(sys.modules, "sibling_helper_xyz", raising=False)
    for workers in ("0", "2"):
        code, report = _gate(tmp_path, "--plugin", f"{folder / 'sibling_plugin.py'}:SIBLING", "--case",
                             "double_pendulum", "--case", "acrobot", "--samples", "2", "--workers", workers)
        assert code == 0 and "pinocchio, sibling)" in report and "## Backend errors" not in report, report[:3000]
        assert _drift_row(report, "acrobot", 2)["agree"] == "2"
