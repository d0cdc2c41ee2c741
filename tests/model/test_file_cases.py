"""The built-in cases loaded from the model files shipped in ``cases/files`` (``cases.file_cases``, issue 35).

* they are registered (last), in the default gate and the fault hunt's cases, load through the loaders (the model's
  source is the shipped file) and are shipped as package data;
* each loader path is really exercised: a mimic with multiplier -0.8 and offset 0.05, a continuous joint, limits of
  every kind, a fixed joint merged, rotated inertial frames; a free joint, a ball joint, a hinge range in degrees, a
  slide range in metres, bodies turned by ``quat`` and ``euler``, ``fullinertia`` and ``diaginertia`` + ``quat``,
  a welded MJCF body; checked here against numbers computed by hand from the files, and against MuJoCo itself;
* each passes the gate against the reference built from its file, and ``crosscheck eval --case NAME`` reproduces
  one of its states;
* a loader fault injected into each path (the loader reading a misread copy of the file, or one of its functions
  patched) makes the gate on the case FAIL: the reference, which reads the real file, is the outlier, or refuses the
  model (a mimic or a limit that is not the file's, a joint of another kind).
"""

from __future__ import annotations

import re
import shlex
import tomllib
from pathlib import Path

import numpy as np
import pytest

import cases
import cases.mjcf
import cases.urdf
from cases import JointCoupling
from cases.file_cases import FILES
from crosscheck import backends, cli
from crosscheck.core.compare import DISAGREE, suspect
from crosscheck.engine import run
from crosscheck.engine.specs import CaseSpec, Checks
from crosscheck.faults import injection
from crosscheck.references.pinocchio import build
from crosscheck.reports import gate_lines, gate_summary

ROOT = Path(__file__).resolve().parents[2]
#: The loaders' and the reference's reader of a file (``cases.urdf.read_file``), before any test patches the loaders'.
READ_FILE = cases.urdf.read_file
FILE_CASES = {"urdf_gripper": "gripper.urdf", "mjcf_floating": "floating.xml", "mjcf_ball_slide": "ball_slide.xml",
              "mjcf_armature": "armature_arm.xml"}
ALL = [backends.get(name) for name in backends.builtin_names()]
NUMERIC = [b for b in ALL if b.name not in ("euler_lagrange", "geometric")]


def _rpy(r: float, p: float, y: float) -> np.ndarray:
    """URDF's rpy: ``Rz(y) Ry(p) Rx(r)``."""
    return _rot(2, y) @ _rot(1, p) @ _rot(0, r)


def _rot(axis: int, angle: float) -> np.ndarray:
    c, s = np.cos(angle), np.sin(angle)
    i, j = (axis + 1) % 3, (axis + 2) % 3
    R = np.eye(3)
    R[i, i], R[i, j], R[j, i], R[j, j] = c, -s, s, c
    return R


def _quat(w: float, x: float, y: float, z: float) -> np.ndarray:
    """MJCF's ``quat`` (w first, normalized) as a rotation matrix."""
    w, x, y, z = np.array([w, x, y, z]) / np.linalg.norm([w, x, y, z])
    return np.array([[1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y)],
                     [2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x)],
                     [2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)]])


def _euler_degrees(a: float, b: float, c: float) -> np.ndarray:
    """MJCF's ``euler`` with the default ``eulerseq="xyz"`` (rotating axes) in degrees: ``Rx(a) Ry(b) Rz(c)``."""
    return _rot(0, np.radians(a)) @ _rot(1, np.radians(b)) @ _rot(2, np.radians(c))


def _merged(parts) -> tuple[float, np.ndarray, np.ndarray]:
    """Mass, COM and COM inertia of rigidly joined parts, each (mass, com, inertia about its com) in one frame."""
    mass = sum(m for m, _, _ in parts)
    com = sum(m * c for m, c, _ in parts) / mass
    inertia = sum(I + m * ((c - com) @ (c - com) * np.eye(3) - np.outer(c - com, c - com)) for m, c, I in parts)
    return mass, com, inertia


def _off_diagonal(inertia) -> float:
    return float(np.abs(np.asarray(inertia) - np.diag(np.diag(inertia))).max())


# ---------------------------------------------------------------------------------------------- registration


def test_the_file_cases_are_registered_last_and_load_from_the_shipped_files():
    assert cases.names()[-len(FILE_CASES):] == list(FILE_CASES)
    catalog = {c.name: c for c in cases.catalog()}
    for name, file in FILE_CASES.items():
        model = cases.load(name)
        assert model.name == name and catalog[name].parameters == {} and catalog[name].summary
        assert model.source.kind == ("urdf" if file.endswith(".urdf") else "mjcf")
        assert Path(model.source.path) == FILES / file and (FILES / file).is_file()
        assert cases.model_file(name) == f"cases/files/{file}, shipped with crosscheck"
        assert build.provenance(model).startswith(f"built from the file {FILES / file} (")
        assert model.findings == ()                  # physical masses and inertias: no model finding
    assert cases.model_file("double_pendulum") is None


def test_the_files_are_package_data():
    """A non-editable install ships them (``pip wheel .`` was checked to hold cases/files/*): pyproject names them."""
    config = tomllib.loads((ROOT / "pyproject.toml").read_text())["tool"]["setuptools"]
    patterns = config["package-data"]["cases"]
    for file in FILE_CASES.values():
        assert any(Path("files", file).match(pattern) for pattern in patterns), file
    assert "cases*" in config["packages"]["find"]["include"]


def test_the_default_gate_and_the_fault_hunt_run_them_as_built_in_cases():
    """A file case is a built-in case: ``CaseSpec(name)`` without a path (``--case NAME`` reproduces it wherever the
    package is installed), no closed form, and a coverage line saying the reference is built from the file."""
    specs = {spec.name: spec for spec in injection.default_specs()}
    for name, file in FILE_CASES.items():
        spec = specs[name]
        assert spec.path is None and spec.cli_args() == f"--case {name}" and spec.closed_form() is None
        assert run._closed_form_coverage(spec, Checks()) == (
            f"none (loaded from the model file cases/files/{file}, shipped with crosscheck; its reference is built "
            "from the file)")
        assert spec.build().source.path == str(FILES / file)


# ------------------------------------------------------------------------------------ the paths are exercised


def test_urdf_gripper_exercises_mimic_continuous_limits_fixed_merge_and_rotated_inertials():
    model = cases.load("urdf_gripper")
    by_name = {b.name: b for b in model.bodies}
    assert [(b.name, b.joint) for b in model.bodies] == [("wrist", "revolute"), ("carriage", "prismatic"),
                                                         ("finger_left", "revolute"), ("finger_right", "revolute")]
    # the mimic: q_right = -0.8 q_left + 0.05, i.e. phi = q_right + 0.8 q_left - 0.05
    (coupling,) = model.constraints
    assert coupling == JointCoupling("mimic:finger_right", ("finger_right", "finger_left"), (1.0, 0.8), 0.05)
    assert -coupling.coefficients[1] != 1.0 and coupling.offset != 0.0
    # the continuous joint: one angle here, (cos q, sin q) in the file-built reference; no limits
    rows = {r.body: r for r in build.joint_map(model)}
    assert rows["wrist"].nq == 2 and rows["wrist"].joint == "wrist_roll" and by_name["wrist"].limits is None
    np.testing.assert_array_equal(by_name["wrist"].axis, [1.0, 0.0, 0.0])
    # limits of each kind: revolute, prismatic, the mimic joint's
    assert by_name["finger_left"].limits == (-0.3, 0.9) and by_name["carriage"].limits == (-0.02, 0.06)
    assert by_name["finger_right"].limits == (-0.8, 0.4)
    # the fixed joint palm_mount merged: the carriage carries the palm's mass, COM and rotated inertia, and the
    # fingers hang from the carriage through the mount's rotated, offset origin (computed here from the file)
    mount_R, mount_t = _rpy(0.1, 0.3, -0.2), np.array([0.05, 0.01, -0.02])
    carriage = (0.4, np.array([0.03, -0.01, 0.015]),
                _rpy(0.2, -0.4, 0.5) @ np.diag([0.0004, 0.0007, 0.0009]) @ _rpy(0.2, -0.4, 0.5).T)
    palm_I = mount_R @ _rpy(0.0, 0.5, 0.3) @ np.diag([0.0006, 0.0005, 0.0008]) @ (mount_R @ _rpy(0.0, 0.5, 0.3)).T
    palm = (0.5, mount_t + mount_R @ np.array([0.02, 0.0, 0.01]), palm_I)
    mass, com, inertia = _merged([carriage, palm])
    body = by_name["carriage"]
    assert body.mass == pytest.approx(mass, rel=1e-14)
    np.testing.assert_allclose(body.com, com, rtol=0, atol=1e-15)
    np.testing.assert_allclose(body.inertia, inertia, rtol=0, atol=1e-15)
    np.testing.assert_allclose(by_name["finger_left"].rotation, mount_R, atol=1e-15)
    np.testing.assert_allclose(by_name["finger_left"].translation, mount_t + mount_R @ [0.04, 0.03, 0.0], atol=1e-15)
    # every inertial frame is rotated: off-diagonal inertias
    assert min(_off_diagonal(b.inertia) for b in model.bodies) > 1e-7
    wrist_R = _rpy(0.3, 0.0, 0.2)
    np.testing.assert_allclose(by_name["wrist"].inertia, wrist_R @ np.diag([0.0009, 0.0012, 0.0010]) @ wrist_R.T,
                               atol=1e-16)


def test_mjcf_floating_exercises_free_joint_degrees_euler_fullinertia_and_a_welded_body():
    model = cases.load("mjcf_floating")
    torso, arm = model.bodies
    assert (torso.joint, arm.joint, model.nq, model.nv, model.input_map.shape) == ("free", "revolute", 8, 7, (7, 1))
    np.testing.assert_array_equal(model.input_map[:, 0], [0, 0, 0, 0, 0, 0, 1])   # the free joint is not driven
    # range="-90 45" read in degrees (the default <compiler angle="degree">)
    np.testing.assert_allclose(arm.limits, (-np.pi / 2, np.pi / 4), rtol=1e-15)
    assert torso.limits is None
    # euler="20 -30 45" in degrees, rotating axes xyz
    np.testing.assert_allclose(arm.rotation, _euler_degrees(20, -30, 45), atol=1e-15)
    # fullinertia="ixx iyy izz ixy ixz iyz"
    np.testing.assert_allclose(torso.inertia, [[0.030, 0.004, -0.003], [0.004, 0.040, 0.002],
                                               [-0.003, 0.002, 0.050]], atol=1e-16)
    # the arm's diaginertia turned by its quat, merged with the welded hand (turned by euler, at pos)
    R_in = _quat(0.9, 0.1, 0.3, 0.2)
    hand_R, hand_t = _euler_degrees(0, 40, 0), np.array([0.02, 0.01, -0.25])
    mass, com, inertia = _merged([
        (0.8, np.array([0.01, 0.0, -0.12]), R_in @ np.diag([0.004, 0.0045, 0.0008]) @ R_in.T),
        (0.3, hand_t + hand_R @ [0.0, 0.0, -0.03], hand_R @ np.diag([0.0004, 0.0003, 0.0002]) @ hand_R.T)])
    assert arm.mass == pytest.approx(mass, rel=1e-14)
    np.testing.assert_allclose(arm.com, com, atol=1e-15)
    np.testing.assert_allclose(arm.inertia, inertia, atol=1e-15)
    assert model.task_point().name == "hand"


def test_mjcf_ball_slide_exercises_ball_joint_quat_and_slide_range_in_metres():
    model = cases.load("mjcf_ball_slide")
    rod, bob = model.bodies
    assert (rod.joint, bob.joint, model.nq, model.nv) == ("spherical", "prismatic", 5, 4)
    np.testing.assert_allclose(rod.rotation, _quat(0.9, 0.3, 0.1, -0.2), atol=1e-15)
    np.testing.assert_allclose(bob.rotation, _euler_degrees(0, 0, 30), atol=1e-15)
    assert rod.limits is None and bob.limits == pytest.approx((-0.05, 0.1), rel=1e-15)   # metres, not degrees
    R_in = _quat(0.8, 0.2, -0.3, 0.1)
    np.testing.assert_allclose(rod.inertia, R_in @ np.diag([0.016, 0.017, 0.002]) @ R_in.T, atol=1e-16)
    assert _off_diagonal(bob.inertia) == pytest.approx(1e-4)


def test_mujoco_reads_the_mjcf_files_as_the_loader_does(monkeypatch, tmp_path):
    """The one reading of the MJCF files independent of Pinocchio's parser (which the loader and the file-built
    reference share): MuJoCo's limits, masses and body orientations, and the gate with the MuJoCo plugin voting."""
    mujoco = pytest.importorskip("mujoco")
    for name, file in FILE_CASES.items():
        if not file.endswith(".xml"):
            continue
        model, mj = cases.load(name), mujoco.MjModel.from_xml_path(str(FILES / file))
        for b in model.bodies:
            joint = mj.body_jntadr[mj.body(b.name).id]
            expected = tuple(mj.jnt_range[joint]) if b.joint in ("revolute", "prismatic") and mj.jnt_limited[joint] \
                else None
            assert (b.limits is None) == (expected is None) and np.allclose(b.limits or 0, expected or 0, rtol=1e-12)
        assert sum(b.mass for b in model.bodies) == pytest.approx(float(mj.body_mass.sum()), rel=1e-14)
        assert [b.armature for b in model.bodies] == [float(mj.dof_armature[mj.jnt_dofadr[mj.body_jntadr[
            mj.body(b.name).id]]]) for b in model.bodies]
    monkeypatch.chdir(ROOT)
    backends.reset()
    try:
        code = cli.main(["gate", "--plugin", "crosscheck.adapters.mujoco:BACKEND", "--case", "mjcf_floating", "--case",
                         "mjcf_ball_slide", "--case", "mjcf_armature", "--samples", "4", "--workers", "0", "--report",
                         str(tmp_path / "g.md")])
    finally:
        backends.reset()
    report = gate_summary.read(tmp_path / "g.md")
    assert code == 0 and "Compared: every backend in every case (7)." in report, report


# -------------------------------------------------------------------------------------------------- the gate


@pytest.mark.parametrize("case", list(FILE_CASES))
def test_each_file_case_passes_the_gate_against_the_reference_built_from_its_file(case, tmp_path):
    report = tmp_path / "gate.md"
    code = cli.main(["gate", "--case", case, "--samples", "10", "--workers", "0", "--report", str(report)])
    text, details = gate_summary.read(report), (tmp_path / "gate-details.md").read_text()
    assert code == 0 and "**PASS**" in text and "Compared: every backend in every case (6)." in text, text
    assert f"- no closed form: {case}" in text
    assert (f"- {case}: closed form: none (loaded from the model file cases/files/{FILE_CASES[case]}, shipped with "
            "crosscheck; its reference is built from the file)") in details
    assert f"- {case}: the reference (pinocchio) is built from the file {FILES / FILE_CASES[case]} (" in details


def test_eval_reproduces_a_state_of_a_file_case(capsys):
    result = run.run_gate([CaseSpec("urdf_gripper")], ALL, samples=2, seed=0, checks=Checks(self_test=False))
    case = result.cases[0]
    command = gate_lines.reproduce_command(case, case.states[1])
    assert command.startswith("crosscheck eval --case urdf_gripper --q=")
    capsys.readouterr()
    assert cli.main(shlex.split(command)[1:]) == 0
    out = capsys.readouterr().out
    assert "verdict: agree" in out and "pinocchio" in out


# ------------------------------------------------------------------------------------------ faults per path


def _misread(module, edit):
    """Inject: the loader's ``read_file`` (in ``module``: cases.urdf or cases.mjcf) parses a copy of the file, in the
    folder ``tmp``, changed by ``edit`` (which must change it); the reference keeps its own ``read_file`` and reads
    the real file."""
    def inject(patch, tmp: Path) -> None:
        def read(pin, kind, path, root="fixed"):
            text = Path(path).read_text()
            changed = edit(text)
            assert changed != text, "the emulated fault does not change the file"
            copy = tmp / Path(path).name
            copy.write_text(changed)
            return READ_FILE(pin, kind, str(copy), root)

        patch.setattr(module, "read_file", read)
    return inject


def _patched(module, name, wrap):
    """Inject: the loader's function ``module.name`` replaced by ``wrap(the real one)``."""
    return lambda patch, tmp: patch.setattr(module, name, wrap(getattr(module, name)))


def _mimic_number(attribute):
    """Bug: the mimic tag's ``attribute`` (multiplier, offset) not read: its default (1, 0) instead."""
    return lambda real: lambda problems, where, tag, key, default: (
        default if key == attribute else real(problems, where, tag, key, default))


def _limits_of(kind, change):
    """Bug: the limits of the one-coordinate joints of Pinocchio type ending in ``kind`` changed by ``change``."""
    return lambda real: lambda pm, j, jm: change(real(pm, j, jm)) if jm.shortname().endswith(kind) else real(pm, j, jm)


def _joint_kind(pinocchio_kind, ours):
    """Bug: Pinocchio joints whose type contains ``pinocchio_kind`` converted as ``ours`` (type, axis)."""
    return lambda real: lambda jm: ours if pinocchio_kind in jm.shortname() else real(jm)


def _mjcf_limits(change):
    """Bug in the MJCF loader's limits (``cases.mjcf._limits``): ``change(root, pm, lower, upper, real)`` sets them."""
    def wrap(real):
        def limits(root, pin, pm):
            lower, upper = np.array(pm.lowerPositionLimit), np.array(pm.upperPositionLimit)
            change(root, pm, lower, upper, lambda: real(root, pin, pm))
        return limits
    return wrap


def _hinge_in_radians(root, pm, lower, upper, real):
    """Pinocchio's degrees-to-radians conversion of the hinge's range undone: ``range="-90 45"`` read as radians."""
    real()
    lo, hi = np.array(pm.lowerPositionLimit), np.array(pm.upperPositionLimit)
    iq = pm.joints[pm.getJointId("shoulder")].idx_q
    lo[iq], hi[iq] = np.degrees(lo[iq]), np.degrees(hi[iq])
    pm.lowerPositionLimit, pm.upperPositionLimit = lo, hi


def _slide_in_degrees(root, pm, lower, upper, real):
    """The loader's correction of Pinocchio's slide range (converted from degrees) left out."""
    pm.lowerPositionLimit, pm.upperPositionLimit = lower, upper


#: fault -> (case, how it is injected, "outlier" (the vote names the reference), "loader JOINT" (a loader finding names
#: the limits of that joint of the file: ``crosscheck.guards.loader``) or a fragment of the refusal)
FAULTS = {
    "mimic multiplier read as 1": ("urdf_gripper", _patched(cases.urdf, "_mimic_number", _mimic_number("multiplier")),
                                   r"joint 'finger_right' mimics 'finger_left' \(q = -0.8 q \+ 0.05\)"),
    "mimic offset dropped": ("urdf_gripper", _patched(cases.urdf, "_mimic_number", _mimic_number("offset")),
                             r"joint 'finger_right' mimics 'finger_left' \(q = -0.8 q \+ 0.05\)"),
    "inertial rpy ignored": ("urdf_gripper", _misread(cases.urdf, lambda s: re.sub(
        r'(<inertial>\s*<origin xyz="[^"]*") rpy="[^"]*"', r"\1", s)), "outlier"),
    "fixed child's inertia not merged": ("urdf_gripper", _misread(cases.urdf, lambda s: re.sub(
        r'(<link name="palm">)\s*<inertial>.*?</inertial>', r"\1", s, flags=re.S)), "outlier"),
    "fixed joint's origin ignored": ("urdf_gripper", _misread(cases.urdf, lambda s: s.replace(
        '<origin xyz="0.05 0.01 -0.02" rpy="0.1 0.3 -0.2"/>', '<origin xyz="0 0 0" rpy="0 0 0"/>')), "outlier"),
    "continuous joint's axis read as z": ("urdf_gripper", _patched(cases.urdf, "_joint_kind", _joint_kind(
        "RUB", ("revolute", np.array([0.0, 0.0, 1.0])))), "outlier"),
    "continuous joint given limits": ("urdf_gripper", _patched(cases.urdf, "_position_limits", lambda real: (
        lambda pm, j, jm: (-np.pi, np.pi) if "RUB" in jm.shortname() else real(pm, j, jm))),
        "loader wrist_roll"),
    "revolute limits read in degrees": ("urdf_gripper", _patched(cases.urdf, "_position_limits", _limits_of(
        "RZ", lambda limits: tuple(np.degrees(limits)))), "loader finger_left"),
    "prismatic limits dropped": ("urdf_gripper", _patched(cases.urdf, "_position_limits", _limits_of(
        "PX", lambda limits: None)), "loader extend"),
    "hinge range in degrees read as radians": ("mjcf_floating", _patched(cases.mjcf, "_limits", _mjcf_limits(
        _hinge_in_radians)), "loader shoulder"),
    "body euler ignored": ("mjcf_floating", _misread(cases.mjcf, lambda s: s.replace(' euler="20 -30 45"', "")),
                           "outlier"),
    "inertial quat ignored": ("mjcf_floating", _misread(cases.mjcf, lambda s: s.replace(' quat="0.9 0.1 0.3 0.2"', "")),
                              "outlier"),
    "fullinertia products dropped": ("mjcf_floating", _misread(cases.mjcf, lambda s: s.replace(
        'fullinertia="0.030 0.040 0.050 0.004 -0.003 0.002"', 'diaginertia="0.030 0.040 0.050"')), "outlier"),
    "welded body not merged": ("mjcf_floating", _misread(cases.mjcf, lambda s: re.sub(
        r'(<body name="hand"[^>]*>)\s*<inertial[^>]*/>', r"\1", s)), "outlier"),
    "free joint read as a ball": ("mjcf_floating", _patched(cases.urdf, "_joint_kind", _joint_kind(
        "FreeFlyer", ("spherical", np.zeros(3)))), r"joint 'root' of .* is a JointModelFreeFlyer"),
    "slide range left in Pinocchio's degrees": ("mjcf_ball_slide", _patched(cases.mjcf, "_limits", _mjcf_limits(
        _slide_in_degrees)), "loader slide"),
    "body quat ignored": ("mjcf_ball_slide", _misread(cases.mjcf, lambda s: s.replace(' quat="0.9 0.3 0.1 -0.2"', "")),
                          "outlier"),
    "ball joint read as free": ("mjcf_ball_slide", _patched(cases.urdf, "_joint_kind", _joint_kind(
        "Spherical", ("free", np.zeros(3)))), r"joint 'pivot' of .* is a JointModelSpherical"),
}


@pytest.mark.parametrize("fault", list(FAULTS))
def test_a_loader_fault_fails_the_gate_on_its_file_case(fault, monkeypatch, isolated_cache):
    """The loader reads the file wrong, the reference reads it right: the gate FAILS, the reference the outlier of
    every disagreement on drift (the formalisms all read the faulty conversion), or the reference refuses the model
    at every state, naming the path. Two states, every check of the default gate but the self-test, among the backends that derive
    nothing symbolically for a new model (:data:`NUMERIC`: three formalisms and the reference; the faulty conversion
    is a new model, whose derivation would dominate the test)."""
    case, inject, expected = FAULTS[fault]
    clean = cases.load(case)
    inject(monkeypatch, isolated_cache)
    assert build.read_file is READ_FILE                            # the reference reads the real file
    result = run.run_gate([CaseSpec(case)], NUMERIC, samples=2, seed=0, checks=Checks(self_test=False))
    model = result.cases[0].model
    assert model.source == clean.source and model.source.path == str(FILES / FILE_CASES[case])
    assert not result.passed
    states = result.cases[0].states
    assert len(states) == 2
    for state in states:
        if expected == "outlier":
            failing = [c for c in state.comparisons.values() if c.verdict == DISAGREE]
            assert "drift" in {c.quantity for c in failing}, (fault, state.index, state.errors)
            assert all(c.outlier == "pinocchio" for c in failing if c.quantity in ("drift", "total"))
            assert {suspect(c) for c in failing} == {"pinocchio"}
        elif expected.startswith("loader "):           # a limit: a loader finding names the joint's limits
            found = [str(f) for f in result.cases[0].loader_findings]
            assert any(f"limits (joint '{expected.split()[1]}'" in f for f in found), found
        else:
            assert re.search(expected, state.errors["pinocchio"]), state.errors["pinocchio"]
