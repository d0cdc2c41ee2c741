"""Plugin backends: a user's own backend joins the gate (``--plugin``, entry points, register()), is compared like
the built-in ones, is named as the outlier when it is wrong, and is NOT COMPARED on a model it does not support.

The plugin is the worked example ``examples/closed_form_plugin/closed_form_pendulum.py`` (the article's closed form
of the double pendulum, and SIGN_ERROR: the same with the centrifugal term's sign flipped).
"""

from __future__ import annotations

import importlib
import importlib.metadata
import json
import multiprocessing
import subprocess
import sys
import tomllib
from pathlib import Path

import numpy as np
import pytest

import cases
from closed_forms import pendulum_terms
from crosscheck import backends, cli
from crosscheck.reports import gate_summary
from crosscheck.core.compare import NOT_COMPARED
from crosscheck.engine.specs import CaseSpec, Checks
from crosscheck.engine.run import run_gate
from formalisms.interface import Unsupported

ROOT = Path(__file__).resolve().parents[2]
EXAMPLE = ROOT / "examples" / "closed_form_plugin"
GOOD, BUGGY = "closed_form_pendulum:CLOSED_FORM", "closed_form_pendulum:SIGN_ERROR"
DP_STATE = ["--q=0.7853981633974483,0.5235987755982988", "--qd=2,-1", "--u=5,-2"]

PROBE_PLUGINS = '''
import types
from closed_form_pendulum import parameters, split
from formalisms.interface import Formalism

NO_SPLIT = types.SimpleNamespace(name="no_split", summary="has a name only")
NO_NAME = types.SimpleNamespace(split=split)
BAD_NAME = Formalism("two words", "", split)
RESERVED_NAME = Formalism("exact", "", split)
BUILTIN_NAME = Formalism("newton_euler", "", split)
TWIN_A = Formalism("twin", "", split)
TWIN_B = Formalism("twin", "", split)
RETURNS_DICT = Formalism("returns_dict", "", lambda model, q, qd, u: {"drift": q})


def split_chart(model, chart, p, pd, tau_p):
    parameters(model)       # ModelNotSupported off the double pendulum, as its split says
    raise NotImplementedError("only used on models it does not support")


CHART_CAPABLE = Formalism("chart_capable", "", split, split_chart)
'''


@pytest.fixture(autouse=True)
def plugin_path(monkeypatch, tmp_path):
    """The example's directory and a scratch module of broken plugins on sys.path; no plugin before or after."""
    (tmp_path / "probe_plugins.py").write_text(PROBE_PLUGINS)
    (tmp_path / "raises_on_import.py").write_text("import no_such_dependency_xyz  # noqa: F401\n")
    monkeypatch.syspath_prepend(str(EXAMPLE))
    monkeypatch.syspath_prepend(str(tmp_path))
    backends.reset()
    yield
    backends.reset()


def _gate(tmp_path, *args):
    report = tmp_path / "gate.md"
    code = cli.main(["gate", *args, "--report", str(report)])
    return code, gate_summary.read(report) if report.exists() else ""


def _cells(line: str) -> list[str]:
    return [cell.strip() for cell in line.strip().strip("|").split("|")]


def _summary_rows(report: str, case: str) -> dict[str, dict[str, str]]:
    """The report's per-quantity summary rows of ``case``: quantity -> column header -> cell."""
    lines = report.splitlines()
    header = _cells(next(line for line in lines if line.startswith("| case | n | quantity |")))
    rows = [dict(zip(header, _cells(line))) for line in lines if line.startswith(f"| {case} | 2 | ")]
    return {row["quantity"]: row for row in rows if len(row) == len(header)}


def test_plugin_passes_the_gate_and_votes(tmp_path):
    code, report = _gate(tmp_path, "--plugin", GOOD, "--case", "double_pendulum", "--samples", "6")
    assert code == 0 and "**PASS**" in report
    assert "7 backends (euler_lagrange, newton_euler, screw, operational_space, geometric, pinocchio, " \
           "closed_form_pendulum)" in report
    assert "| closed_form_pendulum | `[" in report          # its values are in the vote tables
    rows = _summary_rows(report, "double_pendulum")
    assert (rows["drift"]["agree"], rows["drift"]["DISAGREE"], rows["drift"]["not supplied by"]) == ("6", "0", "-")
    assert "closed_form_pendulum" in rows["task_drift"]["not supplied by"]  # declared UNSUPPORTED


def test_buggy_plugin_fails_and_is_named_as_outlier(tmp_path):
    code, report = _gate(tmp_path, "--plugin", BUGGY, "--case", "double_pendulum", "--samples", "6")
    assert code == 1 and "**FAIL**" in report
    rows = _summary_rows(report, "double_pendulum")
    # state #0 is the home configuration theta2 = 0, where c = m2 l1 l2 sin theta2 = 0 (eq. 7) hides the sign
    for quantity, expected in (("drift", ("1", "5")), ("total", ("1", "5")), ("ctrl", ("6", "0"))):
        assert (rows[quantity]["agree"], rows[quantity]["DISAGREE"]) == expected   # ctrl = M^-1 B u: no C qd
    blamed = [line for line in report.splitlines() if "outlier **" in line]
    assert blamed and all("outlier **closed_form_pendulum_sign_error**" in line for line in blamed)
    commands = [line for line in report.splitlines() if "reproduce: `crosscheck eval" in line]
    assert commands and all(f"--plugin {BUGGY}" in line for line in commands)   # the outlier runs again


def test_a_named_plugin_that_declines_every_case_fails_unless_optional(tmp_path, capsys):
    """Issue 15: a backend named on the command line that takes part in no comparison (here: written for the double
    pendulum only, run on the acrobot) checks nothing; that fails the run unless it is named with --optional."""
    code, report = _gate(tmp_path, "--plugin", GOOD, "--case", "acrobot", "--samples", "2")
    assert code == 1 and "**FAIL: closed_form_pendulum took part in no comparison**" in report
    assert "backend closed_form_pendulum took part in no comparison" in capsys.readouterr().err
    code, _ = _gate(tmp_path, "--plugin", GOOD, "--case", "acrobot", "--samples", "2", "--optional",
                    "closed_form_pendulum")
    assert code == 0


def test_unsupported_model_is_not_compared_not_failed(tmp_path):
    code, report = _gate(tmp_path, "--plugin", GOOD, "--case", "acrobot", "--samples", "4", "--optional",
                         "closed_form_pendulum")
    assert code == 0 and "**PASS**" in report and "## Backend errors" not in report
    rows = _summary_rows(report, "acrobot")
    assert rows and all("closed_form_pendulum" in row["not supplied by"] for row in rows.values())
    result = run_gate([CaseSpec("acrobot")], [backends.get("pinocchio"), backends.get("newton_euler"),
                                              backends.get("closed_form_pendulum")], samples=3, seed=0,
                        checks=Checks(closed_forms=False))
    for state in result.cases[0].states:
        assert "closed_form_pendulum" not in state.splits and not state.errors
        assert all("closed_form_pendulum" in c.not_compared for c in state.comparisons.values())
        for quantity, comp in state.comparisons.items():   # the others still compared wherever two supply it
            suppliers = [name for name, split in state.voters(quantity).items()
                         if not isinstance(split.quantity(quantity), Unsupported)]
            assert (comp.verdict == NOT_COMPARED) == (len(suppliers) < 2), quantity
        assert state.comparisons["drift"].verdict != NOT_COMPARED
        # newton_euler has no task-space inertia (eq. 22): pinocchio alone supplies it, nothing to compare it with
        assert state.comparisons["task_inertia"].verdict == NOT_COMPARED


def test_unsupported_model_is_not_evaluated_in_charts(tmp_path):
    """A chart-capable plugin is not asked for chart answers on a model its split does not support."""
    code, report = _gate(tmp_path, "--plugin", "probe_plugins:CHART_CAPABLE", "--case", "acrobot", "--samples", "2",
                         "--optional", "chart_capable")
    assert code == 0 and "## Backend errors" not in report


def test_plugin_that_raises_or_returns_garbage_fails(tmp_path):
    """Only ModelNotSupported means "not compared": any other exception or a wrong return is a failure."""
    code, report = _gate(tmp_path, "--plugin", "probe_plugins:RETURNS_DICT", "--case", "double_pendulum",
                         "--samples", "2", "--frames", "0", "--no-charts")
    assert code == 1
    assert "**returns_dict raised** `TypeError: plugin 'returns_dict' returned dict, not a formalisms.interface.Split" \
        in report


def test_eval_shows_the_plugin(capsys):
    assert cli.main(["eval", "--plugin", GOOD, "--case", "double_pendulum", *DP_STATE, "--json"]) == 0
    data = json.loads(capsys.readouterr().out)
    got = data["formalisms"]["closed_form_pendulum"]
    M, Cqd, g = pendulum_terms((np.pi / 4, np.pi / 6), (2.0, -1.0))      # eqs. (6)-(8), typed in separately
    np.testing.assert_allclose(got["drift"], np.linalg.solve(M, -(Cqd + g)), rtol=1e-13)
    np.testing.assert_allclose(got["ctrl"], np.linalg.solve(M, [5.0, -2.0]), rtol=1e-13)
    assert got["task_drift"] is None and "task_drift" in data["unsupported_quantities"]["closed_form_pendulum"]
    assert data["not_supported"] == {}
    assert cli.main(["eval", "--plugin", GOOD, "--case", "acrobot", "--q=0.1,0.2"]) == 0
    out = capsys.readouterr().out
    assert "closed_form_pendulum: NOT COMPARED (model 'acrobot' is not the point-mass double pendulum" in out
    assert "rotational inertia" in out and "pinocchio (joint chart):" in out


def test_moved_scene_and_two_link_chain_are_supported():
    """The frame checks' moved scenes and n_link_pendulum with n = 2 are the same mechanism; the gate compares the
    plugin there (no state leaves it out)."""
    backends.load_plugin(GOOD)
    result = run_gate([CaseSpec("n_link_pendulum", (("n", "2"),))],
                      [backends.get("pinocchio"), backends.get("newton_euler"), backends.get("closed_form_pendulum")],
                      samples=4, seed=1)
    assert result.passed
    for state in result.cases[0].states:
        assert "closed_form_pendulum" in state.splits
        frame_voters = {name for key, c in state.checks.items() if key.startswith("frame: ") for pair in c.pairs
                        for name in pair}
        assert any(name.startswith("closed_form_pendulum@g") for name in frame_voters)


@pytest.mark.parametrize("spec, message", [
    ("closed_form_pendulum", "plugin 'closed_form_pendulum': 'closed_form_pendulum' has no attribute 'BACKEND' "
                             "(backends defined there: CLOSED_FORM, SIGN_ERROR)"),
    (":X", "a plugin is given as MODULE:OBJECT or FILE.py:OBJECT (e.g. mypkg.dynamics:BACKEND, "
           "crosscheck.adapters.mujoco:BACKEND), got ':X'"),
    ("closed_form_pendulum:CLOSED_FORM[a]", "plugin 'closed_form_pendulum:CLOSED_FORM[a]': Formalism has no "
                                            "defaults to leave on (no with_defaults)"),
    ("no_such_module_abc:X", "plugin 'no_such_module_abc:X': module 'no_such_module_abc' not found"),
    ("raises_on_import:X", "plugin 'raises_on_import:X': importing module 'raises_on_import' failed: "
                           "ModuleNotFoundError: No module named 'no_such_dependency_xyz'"),
    ("closed_form_pendulum:NOPE", "plugin 'closed_form_pendulum:NOPE': 'closed_form_pendulum' has no attribute "
                                  "'NOPE' (backends defined there: CLOSED_FORM, SIGN_ERROR)"),
    ("probe_plugins:NO_SPLIT", "plugin 'probe_plugins:NO_SPLIT' is not a backend (formalisms.interface."
                               "Formalism): it has no callable 'split(model, q, qd, u) -> Split'"),
    ("probe_plugins:NO_NAME", "plugin 'probe_plugins:NO_NAME' is not a backend (formalisms.interface.Formalism): it "
                              "has no 'name' string (got NoneType)"),
    ("probe_plugins:BAD_NAME", "the name 'two words' is not usable"),
    ("probe_plugins:RESERVED_NAME", "the name 'exact' is not usable"),
    ("probe_plugins:BUILTIN_NAME", "plugin 'probe_plugins:BUILTIN_NAME' is named 'newton_euler', the name of a "
                                   "built-in backend; give it another name"),
])
def test_bad_plugin_is_one_specific_line_and_exit_2(capsys, spec, message):
    assert cli.main(["formalisms", "--plugin", spec]) == 2
    err = capsys.readouterr().err
    assert err.startswith("crosscheck: error: ") and err.count("\n") == 1
    assert message in err


def test_name_clash_between_plugins_and_reloading(capsys):
    assert cli.main(["gate", "--plugin", "probe_plugins:TWIN_A", "--plugin", "probe_plugins:TWIN_B",
                     "--case", "double_pendulum", "--samples", "1"]) == 2
    assert ("plugin 'probe_plugins:TWIN_B' is named 'twin', a name already taken by plugin 'probe_plugins:TWIN_A'; "
            "give one of them another name") in capsys.readouterr().err
    backends.reset()
    first = backends.load_plugin(GOOD)
    assert backends.load_plugin(GOOD) is first                   # the same object again: no clash
    assert backends.plugin_specs() == (GOOD,)


def _entry_points_file(tmp_path, dist: str, lines: list[str]) -> None:
    info = tmp_path / "site" / f"{dist.replace('-', '_')}-1.0.dist-info"
    info.mkdir(parents=True)
    (info / "METADATA").write_text(f"Metadata-Version: 2.1\nName: {dist}\nVersion: 1.0\n")
    (info / "entry_points.txt").write_text("[crosscheck.formalisms]\n" + "\n".join(lines) + "\n")


def test_entry_point_of_the_example_package_is_discovered(tmp_path, monkeypatch, capsys):
    """The example's pyproject.toml declares the entry point; an installed distribution with it (its .dist-info on
    sys.path, as pip leaves it) makes the backend part of every command without --plugin."""
    table = tomllib.loads((EXAMPLE / "pyproject.toml").read_text())["project"]["entry-points"]
    declared = table[backends.ENTRY_POINT_GROUP]
    assert declared == {"closed_form_pendulum": GOOD}
    _entry_points_file(tmp_path, "crosscheck-closed-form-pendulum", [f"{k} = {v}" for k, v in declared.items()])
    monkeypatch.syspath_prepend(str(tmp_path / "site"))
    importlib.invalidate_caches()
    assert backends.names()[-1] == "closed_form_pendulum" and backends.plugin_specs() == ()
    assert cli.main(["formalisms"]) == 0
    line = next(x for x in capsys.readouterr().out.splitlines() if x.startswith("closed_form_pendulum "))
    assert "of distribution 'crosscheck-closed-form-pendulum 1.0'" in line


def test_entry_point_that_fails_to_load_names_distribution_and_entry_point(tmp_path, monkeypatch, capsys):
    _entry_points_file(tmp_path, "broken-plugin", ["broken = no_such_module_xyz:BACKEND"])
    monkeypatch.syspath_prepend(str(tmp_path / "site"))
    importlib.invalidate_caches()
    assert cli.main(["gate", "--case", "double_pendulum", "--samples", "1"]) == 2
    err = capsys.readouterr().err
    assert ("entry point 'broken = no_such_module_xyz:BACKEND' (group crosscheck.formalisms) of distribution "
            "'broken-plugin 1.0' failed to load: ModuleNotFoundError: No module named 'no_such_module_xyz'") in err


def test_entry_point_must_be_named_like_its_backend(monkeypatch):
    wrong = importlib.metadata.EntryPoint(name="pendulum", value=GOOD, group=backends.ENTRY_POINT_GROUP)
    monkeypatch.setattr(importlib.metadata, "entry_points",
                        lambda group: [wrong] if group == backends.ENTRY_POINT_GROUP else [])
    with pytest.raises(backends.PluginError, match="loads a backend named 'closed_form_pendulum'; name the entry "
                                                   "point like the backend"):
        backends.names()


def test_register_from_python():
    import closed_form_pendulum as example
    formalism = backends.register(example.CLOSED_FORM)
    assert backends.get("closed_form_pendulum") is formalism and backends.names()[-1] == "closed_form_pendulum"
    model = cases.load("double_pendulum")
    np.testing.assert_array_equal(formalism.split(model, [0.3, 0.2], [1.0, 0.0], [0.0, 0.0]).drift,
                                  example.split(model, [0.3, 0.2], [1.0, 0.0], [0.0, 0.0]).drift)
    with pytest.raises(backends.PluginError, match="passed to register\\(\\) is not a backend"):
        backends.register(object())


def test_worker_process_loads_the_same_plugins():
    """A campaign passes ``plugin_specs()`` to its workers (spawned: nothing inherited but sys.path)."""
    backends.load_plugin(GOOD)
    context = multiprocessing.get_context("spawn")
    with context.Pool(1, initializer=backends.load_plugins, initargs=(backends.plugin_specs(),)) as pool:
        assert pool.apply(backends.names) == backends.names()


def test_console_script_imports_from_the_working_directory():
    """``crosscheck`` (a console script: its sys.path does not hold the working directory) finds a plugin module in
    the directory it runs from."""
    done = subprocess.run([str(Path(sys.executable).parent / "crosscheck"), "eval", "--plugin", GOOD,
                           "--case", "double_pendulum", *DP_STATE], cwd=EXAMPLE, capture_output=True, text=True,
                          timeout=120)
    assert done.returncode == 0, done.stderr
    assert "closed_form_pendulum (joint chart):" in done.stdout
