"""``crosscheck simulators`` and its conformance report: an adapter that agrees, one left with a default on that
changes the model (named, with the hint and the state), one that cannot read the model (NOT COMPARED, with the
reason), and ``--simulator`` errors."""

from __future__ import annotations

import re

import pytest

from crosscheck import adapters, backends, cli
from crosscheck.reports import conformance, diagnosis
from scenes import DAMPED_CHAIN


#: A plugin that reads nothing: NOT COMPARED on every model, with its reason.
DECLINING = '''
from formalisms.interface import ModelNotSupported

class Declining:
    name, needs = "declining_sim", "source"

    def split(self, scene, q, qd, u):
        raise ModelNotSupported("this simulator reads no " + scene.kind.upper() + " file")

BACKEND = Declining()
'''


@pytest.fixture
def damped(tmp_path) -> str:
    path = tmp_path / "damped_chain.urdf"
    path.write_text(DAMPED_CHAIN)
    return str(path)


def _run(tmp_path, *argv) -> tuple[int, str]:
    report = tmp_path / "sim.md"
    code = cli.main(["simulators", *argv, "--samples", "3", "--report", str(report), "--quiet"])
    return code, report.read_text()


def test_a_conforming_simulator_and_one_with_a_default_left_on(tmp_path, damped, capsys):
    """MuJoCo with every default off agrees in every family it supplies; with joint damping left on (the file
    declares it) it is the drift's outlier, with the damping hint, the state and the command to reproduce it; ctrl
    (M^-1 B u, no damping in it) still agrees."""
    code, text = _run(tmp_path, "--model", damped, "--simulator", "mujoco", "--simulator", "mujoco:damping")
    out = capsys.readouterr().out
    assert code == 1
    rows = {line.split(" | ")[0].strip("| "): line for line in text.splitlines() if line.startswith("| mujoco")}
    assert "FINDING" not in rows["mujoco"] and "agrees" in rows["mujoco"]
    cells = dict(zip(conformance.FAMILIES, rows["mujoco_with_damping"].split(" | ")[2:]))
    assert "**FINDING** (3 states)" in cells["drift"] and cells["ctrl"].startswith("agrees")
    section = text.split("## mujoco_with_damping")[1]
    assert "outlier **mujoco_with_damping** at 3 states" in section
    assert "hint: mujoco_with_damping" in section and diagnosis.DAMPING[:40] in section
    assert "reproduce: `crosscheck eval --model" in section and "Defaults left on: damping." in section
    assert "- `damping`" not in section and "- `damping`" in text.split("## mujoco_with_damping")[0]
    assert re.search(r"^simulator mujoco +agrees", out, re.M)
    assert re.search(r"^simulator mujoco_with_damping +FINDING in drift \(3 states\)", out, re.M)
    assert (tmp_path / "sim-gate.md").is_file()


def test_a_simulator_that_cannot_read_the_file_is_not_compared_with_its_reason(tmp_path, damped):
    plugin = tmp_path / "declining.py"
    plugin.write_text(DECLINING)
    code, text = _run(tmp_path, "--model", damped, "--simulator", "mujoco", "--plugin", f"{plugin}:BACKEND")
    assert code == 0, text
    assert "| declining_sim |" in text and "NOT COMPARED: this simulator reads no URDF file" in text


def test_simulator_errors_are_one_line_and_exit_2(tmp_path, damped, capsys):
    assert cli.main(["gate", "--simulator", "nope", "--model", damped]) == 2
    assert "no adapter 'nope'; adapters: mujoco, drake, pybullet, idyntree, roboticstoolbox" in capsys.readouterr().err
    assert cli.main(["gate", "--simulator", "mujoco:bogus", "--model", damped]) == 2
    assert "mujoco has no default 'bogus'; its defaults: constraint_solver, damping" in capsys.readouterr().err


def test_every_adapter_is_installed_here_and_states_its_defaults():
    """CI installs every library (the test extras): each adapter loads, and each default says what it adds."""
    assert adapters.installed() == list(adapters.SIMULATORS)
    for name in adapters.SIMULATORS:
        adapter = backends.load_plugin(adapters.plugin_spec(name))
        obj = backends.plugin_object(adapter.name)
        assert obj.name == name and obj.needs == "source" and obj.library()
        assert all(isinstance(what, str) and what for what in obj.DEFAULTS.values())
        every = obj.with_defaults(*obj.DEFAULTS)
        assert every.on == set(obj.DEFAULTS) and every.name == "_with_".join([name, *(
            ["_".join(sorted(obj.DEFAULTS))] if obj.DEFAULTS else [])])


def test_armature_is_given_to_the_simulators_that_hold_it_and_the_others_are_not_compared(tmp_path):
    """A URDF's declared armature reaches MuJoCo (joint armature) and Drake (an actuator's reflected rotor inertia),
    which agree; iDynTree, pybullet and roboticstoolbox have no such term and are NOT COMPARED, saying so. The shipped
    MJCF with armature is checked by MuJoCo; Drake, which keeps an MJCF's armature only on actuated joints, is NOT
    COMPARED with that reason."""
    code, text = _run(tmp_path, "--model", "examples/arm.urdf", "--armature", "shoulder_yaw=0.01,elbow=0.02",
                      "--simulator", "mujoco", "--simulator", "drake", "--simulator", "idyntree")
    assert code == 0, text
    rows = {line.split(" | ")[0].strip("| "): line for line in text.splitlines() if line.startswith("| ")}
    assert "agrees" in rows["mujoco"] and "agrees" in rows["drake"] and "NOT COMPARED" in rows["idyntree"]
    assert "is not given the armature (rotor inertia) declared for shoulder_yaw, elbow here" in text
    code, text = _run(tmp_path, "--model", "cases/files/armature_arm.xml", "--simulator", "mujoco",
                      "--simulator", "drake")
    assert code == 0, text
    assert "| mujoco | MuJoCo" in text and "agrees" in text.split("| mujoco |")[1].splitlines()[0]
    assert "declares armature: Drake's MJCF parser keeps it only as the reflected rotor inertia" in text


def test_two_simulators_wrong_at_once_are_each_found_against_the_builtin_backends(tmp_path, damped):
    """MuJoCo and Drake both with joint damping left on move together: the vote names no single outlier, and each is
    still a FINDING, as it disagrees with every built-in backend while those agree; iDynTree, which has no damping
    term, agrees."""
    code, text = _run(tmp_path, "--model", damped, "--simulator", "mujoco:damping", "--simulator", "drake:damping",
                      "--simulator", "idyntree")
    assert code == 1
    rows = {line.split(" | ")[0].strip("| "): line for line in text.splitlines() if line.startswith("| ")}
    for name in ("mujoco_with_damping", "drake_with_damping"):
        cells = dict(zip(conformance.FAMILIES, rows[name].split(" | ")[2:]))
        assert cells["drift"].startswith("**FINDING**") and cells["ctrl"].startswith("agrees"), rows[name]
    assert "FINDING" not in rows["idyntree"] and "not named" not in rows["idyntree"]


def test_a_massless_link_with_a_rotational_inertia_is_a_model_finding_and_drake_cannot_hold_it(tmp_path, damped):
    """A foot welded to the chain's last link with mass 0 and a rotational inertia (bolt's feet): a model finding at
    the top of the report; the model keeps the inertia (Pinocchio's reading), MuJoCo drops it (a finding against the
    built-in backends), Drake's spatial inertia cannot hold it (NOT COMPARED, saying why)."""
    foot = ('<link name="foot"><inertial><mass value="0"/><inertia ixx="0.004" iyy="0.006" izz="0.003" ixy="0" '
            'ixz="0" iyz="0"/></inertial></link><joint name="ankle" type="fixed"><parent link="c"/>'
            '<child link="foot"/><origin xyz="0 0 -0.2"/></joint></robot>')
    path = tmp_path / "footed.urdf"
    path.write_text(DAMPED_CHAIN.replace("</robot>", foot))
    code, text = _run(tmp_path, "--model", str(path), "--simulator", "mujoco", "--simulator", "drake")
    assert code == 1
    assert "- link 'foot' has mass 0 and a rotational inertia (ixx, iyy, izz = 0.004, 0.006, 0.003)" in text
    rows = {line.split(" | ")[0].strip("| "): line for line in text.splitlines() if line.startswith("| ")}
    assert "**FINDING**" in rows["mujoco"].split(" | ")[3]          # ctrl: M^-1 B u, M without the foot's inertia
    assert "NOT COMPARED: link 'foot' has mass 0 and a rotational inertia, which Drake's spatial inertia" in text
