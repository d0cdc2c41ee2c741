"""Bad input of every kind is refused at the boundary (exit 2, one line that says what is wrong and what is valid)
before any work starts; a plugin's malformed output is that plugin's error (exit 1, named); no traceback ever.

Each case here was a traceback, a wrong verdict or a silent misreading before ``crosscheck.guards.preflight`` (issue 16).
"""

from __future__ import annotations

import warnings

import numpy as np
import pytest

import cases
from cases.model import Body
from cases.build import build_model
from crosscheck import backends, cli
from crosscheck.reports import diagnosis
from crosscheck.guards import preflight

DP = ["--case", "double_pendulum"]
QUICK_GATE = ["gate", *DP, "--samples", "1", "--workers", "0", "--frames", "0", "--no-self-test"]

BAD_PLUGINS = '''
import numpy as np
from crosscheck.assemble import unconstrained_split


def _split(model, n, drift):
    z = np.zeros(n)
    return unconstrained_split(model, M=np.eye(n), Cqd=z, g=z, tau_ctrl=z, qd=z, drift=drift, ctrl=z, total=z)


class _Plugin:
    summary, split_chart = "malformed on purpose", None

    def __init__(self, name, answer):
        self.name, self.answer = name, answer

    def split(self, model, q, qd, u):
        return self.answer(model)


WRONG_SHAPE = _Plugin("wrong_shape", lambda model: _split(model, model.n + 1, np.zeros(model.n + 1)))
SCALAR_DRIFT = _Plugin("scalar_drift", lambda model: _split(model, model.n, 0.0))
NAN_DRIFT = _Plugin("nan_drift", lambda model: _split(model, model.n, np.full(model.n, np.nan)))
'''


@pytest.fixture
def bad_plugins(monkeypatch, tmp_path):
    """The malformed plugins importable; no plugin registered before or after."""
    (tmp_path / "bad_plugins.py").write_text(BAD_PLUGINS)
    monkeypatch.syspath_prepend(str(tmp_path))
    backends.reset()
    yield
    backends.reset()


def _refused(argv, capsys) -> str:
    assert cli.main(argv) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and err.startswith("crosscheck: error: "), err
    return err


@pytest.mark.parametrize("argv, fragment", [
    # a mass matrix singular everywhere: a point mass on a joint axis, a mass 1e-300 times the other
    (["eval", *DP, "--param", "I2=0", "--param", "l2=1e-200", "--q=0.1,0.2"], "velocity (link2 +1) moves no mass"),
    (["eval", *DP, "--param", "m2=1e-300", "--q=0.1,0.2"], "bodies 'link2' (1e-300 kg) are lighter than 1e-12 kg"),
    (["gate", "--case", "n_link_pendulum", "--param", "l=1e-100"], "longest placement or COM offset is 1e-100 m"),
    (["gate", "--case", "cartesian_pendulum", "--param", "L=1e300"], "constraint 'rod' radius has magnitude 1e+300"),
    (["gate", "--case", "geared_pendulums", "--param", "ratio=1e300"], "'gear' coefficients has magnitude 1e+300"),
    # magnitudes beyond the double-precision range of the tolerance policy
    (["gate", *DP, "--param", "m1=1e300"], "body 'link1' mass has magnitude 1e+300, above the mass limit"),
    (["gate", *DP, "--param", "g=1e308"], "gravity has magnitude 1e+308"),
    (["eval", *DP, "--q=1e308,0"], "--q has an entry of magnitude 1e+308"),
    (["eval", *DP, "--q=0.1,0", "--qd=1e308,1"], "--qd has an entry of magnitude 1e+308"),
    (["eval", *DP, "--q=0.1,0.2", "--u=1e308,1e308"], "--u has an entry of magnitude 1e+308"),
    (["eval", *DP, "--q=0.1,1e309"], "--q has non-finite entries"),
    # parameters outside a case's domain, unbounded work
    (["eval", *DP, "--param", "l2=0", "--q=0.1,0.2"], "double_pendulum: l2 must be positive, got 0.0"),
    (["eval", *DP, "--param", "l2=-1", "--q=0.1,0.2"], "double_pendulum: l2 must be positive, got -1.0"),
    (["gate", "--case", "n_link_pendulum", "--param", "n=100000"], "must be from 1 to"),
    # vectors read silently as something else
    (["eval", *DP, "--q=1,,2"], "--q has an empty entry (position 2)"),
    (["eval", *DP, "--q=1,2,"], "--q has an empty entry (position 3)"),
    # seeds and frames
    (["gate", *DP, "--seed", "-1"], "--seed: takes an integer from 0 to"),
    (["eval", *DP, "--q=0,0", "--seed=-1", "--frame", "g0"], "--seed: takes an integer from 0 to"),
    (["faults", "--seed", "-1"], "--seed: takes an integer from 0 to"),
    (["fuzz", "--seed", "-1"], "--seed: takes an integer from 0 to"),
    (["eval", *DP, "--q=0,0", "--frame", "g99"], "--frame takes a sampled frame name g0 ... g15"),
    (["gate", *DP, "--frames", "17"], "--frames takes 0 (off) to 16"),
    # unbounded or misdirected work
    (["fuzz", "--minutes", "inf"], "--minutes takes a positive, finite number of minutes, got inf"),
    (["fuzz", "--workers", "1000"], "--workers takes 0 to"),
    (["gate", *DP, "--workers", "1000"], "--workers takes 0 to"),
    (["gate", *DP, "--workers", "-1"], "--workers takes 0 to"),
])
def test_bad_input_is_refused_in_one_line(argv, fragment, capsys):
    assert fragment in _refused(argv, capsys)


def test_a_point_mass_on_its_joint_axis_is_refused_naming_the_joint():
    """Not a case parameter: a model built from bodies, as a URDF or a user's code gives it."""
    bodies = [Body("upper", None, "revolute", (0, 0, 1), 1.0, com=(0, -1, 0)),
              Body("wheel", "upper", "revolute", (0, 0, 1), 2.0, com=(0, 0, 0), translation=(0, -1, 0))]
    with pytest.raises(preflight.PreflightError, match=r"joint velocity \(wheel \+1\) moves no mass"):
        preflight.check_model(build_model("point_on_axis", bodies))


def test_every_built_in_case_passes_the_preflight():
    for name in cases.names():
        preflight.check_model(cases.load(name))


@pytest.mark.parametrize("where", ["directory", "parent is a file"])
def test_an_unwritable_report_is_refused_before_the_run(tmp_path, capsys, where):
    report = tmp_path if where == "directory" else tmp_path / "file" / "gate.md"
    (tmp_path / "file").write_text("not a directory")
    err = _refused([*QUICK_GATE, "--report", str(report)], capsys)
    assert ("is a directory" if where == "directory" else "is a file, not a directory") in err
    assert "states evaluated" not in err   # refused before any work


def test_an_unwritable_junit_path_fails_first_and_leaves_no_stale_pass(tmp_path, capsys):
    report = tmp_path / "gate.md"
    report.write_text("**PASS**: an earlier run")
    (tmp_path / "file").write_text("")
    _refused([*QUICK_GATE, "--report", str(report), "--junit", str(tmp_path / "file" / "j.xml")], capsys)
    assert "PASS" not in report.read_text()


@pytest.mark.parametrize("plugin, fragment", [
    ("WRONG_SHAPE", "returned drift of shape (3,) for model 'double_pendulum', which has 2 joints"),
    ("SCALAR_DRIFT", "drift of shape ()"),
    ("NAN_DRIFT", "non-finite values (NaN or inf) in drift"),
])
def test_a_malformed_plugin_answer_is_that_plugins_error(bad_plugins, capsys, plugin, fragment):
    argv = ["eval", *DP, "--q=0.1,0.2", "--plugin", f"bad_plugins:{plugin}"]
    assert cli.main(argv) == 1
    out = capsys.readouterr().out
    name = plugin.lower()
    assert f"{name}: ERROR at this state:" in out and fragment in out


def test_a_wrong_shape_plugin_fails_the_gate_named(bad_plugins, tmp_path, capsys):
    argv = [*QUICK_GATE, "--report", str(tmp_path / "r.md"), "--plugin", "bad_plugins:WRONG_SHAPE"]
    assert cli.main(argv) == 1
    err = capsys.readouterr().err
    assert "backend wrong_shape took part in no comparison (it raised at 1 states" in err
    assert "returned drift of shape (3,)" in err


def test_a_task_singularity_is_breakdown_not_an_error(capsys):
    """Lambda is inf at the stretched-out double pendulum: a BREAKDOWN the backend reports, exit 0."""
    assert cli.main(["eval", *DP, "--q=0.1,0"]) == 0
    assert "ERROR" not in capsys.readouterr().out


def test_an_infinite_error_is_not_measurable_never_zero():
    assert diagnosis._times(1.0, np.inf, 1e-12) == "not measurable"
    assert diagnosis._times(np.nan, 1.0, 1e-12) == "not measurable"
    assert diagnosis._times(4.0, 1.0, 1e-12) == "x4"


@pytest.mark.parametrize("command", [["bench", "--quick", "--no-stability"], ["stability", "--quick"]])
def test_a_report_directory_that_is_a_file_is_refused_before_the_run(tmp_path, capsys, command):
    (tmp_path / "file").write_text("")
    err = _refused([*command, "--out", str(tmp_path / "file")], capsys)
    assert "is a file" in err


def test_an_unwritable_derivation_cache_costs_time_not_the_backend(tmp_path, monkeypatch, capsys):
    (tmp_path / "file").write_text("")
    monkeypatch.setenv("CROSSCHECK_CACHE", str(tmp_path / "file"))
    argv = ["eval", *DP, "--param", "m1=1.2345", "--q=0.1,0.2", "--formalism", "euler_lagrange"]
    assert cli.main(argv) == 0
    assert "ERROR" not in capsys.readouterr().out


LINK = ('<link name="{0}"><inertial><mass value="1"/><inertia ixx="0.1" ixy="0" ixz="0" iyy="0.1" iyz="0" izz="0.1"/>'
        '</inertial></link>')


def _urdf(tmp_path, name: str, links: list[str], joints: list[str]) -> str:
    path = tmp_path / f"{name}.urdf"
    path.write_text(f'<?xml version="1.0"?><robot name="{name}">' + "".join(LINK.format(link) for link in links)
                    + "".join(joints) + "</robot>")
    return str(path)


def _joint(name: str, kind: str, parent: str, child: str) -> str:
    return (f'<joint name="{name}" type="{kind}"><parent link="{parent}"/><child link="{child}"/>'
            '<axis xyz="0 0 1"/></joint>')


def test_a_model_error_counts_its_problems_and_names_its_file_once(tmp_path, capsys):
    """Two unsupported joints are two problems; the file is where the model came from, not a third problem."""
    path = _urdf(tmp_path, "two_planar", ["base", "a", "b"],
                 [_joint("j1", "planar", "base", "a"), _joint("j2", "planar", "a", "b")])
    assert cli.main(["gate", "--model", path, "--samples", "1"]) == 2
    err = capsys.readouterr().err
    assert err.startswith(f"crosscheck: error: model 'two_planar' from URDF file '{path}' is invalid (2 problem(s)): "
                          "joint 'j1' has Pinocchio type JointModelPlanar"), err
    assert "; joint 'j2'" in err and ":;" not in err and err.count(path) == 1 and len(err.splitlines()) == 1


def test_a_urdf_whose_root_link_has_no_joint_is_told_to_float_it(tmp_path, capsys):
    """A quadrotor's URDF is one link: welded to the world nothing moves; the error says --base free."""
    path = _urdf(tmp_path, "quadrotor", ["base_link"], [])
    assert cli.main(["gate", "--model", path, "--samples", "1"]) == 2
    err = capsys.readouterr().err
    assert "(1 problem(s)): no movable joint: with a fixed base its root link is welded to the world" in err
    assert "floats with --base free" in err


def test_a_root_link_named_world_is_the_world_frame_and_loads_fixed_without_a_notice(tmp_path):
    """By the ROS convention a root link named world is the world frame: the file fixes its base itself."""
    fixed_to_world = _urdf(tmp_path, "bolted", ["world", "base", "arm"],
                           [_joint("bolt", "fixed", "world", "base"), _joint("shoulder", "continuous", "base", "arm")])
    loose = _urdf(tmp_path, "loose", ["base", "arm"], [_joint("shoulder", "continuous", "base", "arm")])
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        model = cases.from_urdf(fixed_to_world)
        assert not [w for w in caught if issubclass(w.category, cases.urdf.BaseNotice)]
        cases.from_urdf(loose)
    assert model.n == 1 and model.source.root == "fixed"
    assert [str(w.message) for w in caught if issubclass(w.category, cases.urdf.BaseNotice)] == [
        f"'{loose}' has no joint between its root link 'base' and the world: loaded with a fixed base (to float it: "
        "--base free, or cases.from_urdf(path, base='free'))"]
