"""The second reading of a URDF file (crosscheck.guards.file_reading) and the loader findings
(crosscheck.guards.loader): closed forms of the reading on small files written here, the fixed-joint merge against the parallel-axis theorem done
by hand, every kind of misread in a converted model named with its link and field, no finding on real robots, and a
finding failing the gate's case before any dynamics runs."""

from __future__ import annotations

import dataclasses
import math
import re
import site
from fractions import Fraction
from pathlib import Path

import numpy as np
import pytest

import cases
from cases import urdf
from cases.constraints import JointCoupling
from crosscheck import cli
from crosscheck.checks import frames
from crosscheck.engine.run import run_case
from crosscheck.engine.specs import CaseSpec, Checks
from crosscheck.guards import file_reading, loader
from scenes import chain_urdf

INERTIA = '<inertia ixx="{0}" iyy="{1}" izz="{2}" ixy="0" ixz="0" iyz="0"/>'


def _link(name: str, mass: float = 1.0, xyz: str = "0 0 0", rpy: str = "0 0 0", diagonal=(0.01, 0.02, 0.03)) -> str:
    return (f'<link name="{name}"><inertial><origin xyz="{xyz}" rpy="{rpy}"/><mass value="{mass}"/>'
            f'{INERTIA.format(*diagonal)}</inertial></link>')


def _joint(name: str, parent: str, child: str, kind: str = "revolute", xyz: str = "0 0 0", rpy: str = "0 0 0",
           axis: str | None = "0 0 1", extra: str = "") -> str:
    limit = '<limit lower="-1" upper="1" effort="1" velocity="1"/>' if kind in ("revolute", "prismatic") else ""
    axis_tag = f'<axis xyz="{axis}"/>' if axis is not None else ""
    return (f'<joint name="{name}" type="{kind}"><parent link="{parent}"/><child link="{child}"/>'
            f'<origin xyz="{xyz}" rpy="{rpy}"/>{axis_tag}{limit}{extra}</joint>')


def _write(tmp_path: Path, *parts: str, name: str = "r.urdf") -> str:
    path = tmp_path / name
    path.write_text('<robot name="r">' + "".join(parts) + "</robot>")
    return str(path)


def _Rx(a):
    c, s = math.cos(a), math.sin(a)
    return np.array([[1, 0, 0], [0, c, -s], [0, s, c]])


def _Ry(a):
    c, s = math.cos(a), math.sin(a)
    return np.array([[c, 0, s], [0, 1, 0], [-s, 0, c]])


def _Rz(a):
    c, s = math.cos(a), math.sin(a)
    return np.array([[c, -s, 0], [s, c, 0], [0, 0, 1]])


def _findings(model) -> list[str]:
    return [str(f) for f in loader.check(model).findings]


# ------------------------------------------------------------------------------------------- the reading itself


def test_rpy_is_fixed_axis_roll_pitch_yaw():
    r, p, y = 0.3, -0.7, 1.1
    assert np.allclose(file_reading.rpy_matrix((r, p, y)), _Rz(y) @ _Ry(p) @ _Rx(r), atol=1e-15)
    assert np.allclose(file_reading.rpy_matrix((0, 0, math.pi / 2)), [[0, -1, 0], [1, 0, 0], [0, 0, 1]], atol=1e-15)


def test_an_inertial_rpy_rotates_a_diagonal_inertia_into_the_link_frame(tmp_path):
    """A diagonal inertia (a, b, c) in an inertial frame turned by theta about z: in the link frame
    Ixx = a cos^2 + b sin^2, Iyy = a sin^2 + b cos^2, Ixy = (a - b) sin cos, Izz = c (by hand); and a quarter turn
    about x swaps y and z. The converted model agrees: no finding."""
    theta, (a, b, c) = 0.4, (0.01, 0.02, 0.03)
    path = _write(tmp_path, '<link name="base"/>', _link("l1", 2.0, "0.1 0.2 0.3", f"0 0 {theta}"),
                  _link("l2", 1.0, "0 0 0", f"{math.pi / 2} 0 0"), _joint("j1", "base", "l1"),
                  _joint("j2", "l1", "l2"))
    reading = file_reading.read_urdf(path, "fixed")
    co, si = math.cos(theta), math.sin(theta)
    expected = np.array([[a * co**2 + b * si**2, (a - b) * si * co, 0], [(a - b) * si * co, a * si**2 + b * co**2, 0],
                         [0, 0, c]])
    assert np.allclose(reading.bodies["l1"].inertia, expected, rtol=0, atol=1e-17)
    assert np.allclose(reading.bodies["l1"].com, [0.1, 0.2, 0.3], rtol=0, atol=0)
    assert reading.bodies["l1"].mass == 2.0
    assert np.allclose(reading.bodies["l2"].inertia, np.diag([a, c, b]), rtol=0, atol=1e-17)
    assert not _findings(urdf.from_urdf(path, base="fixed"))


def test_the_fixed_joint_merge_is_the_parallel_axis_theorem(tmp_path):
    """Link a (2 kg, COM (0.1, 0, 0), diag(0.01, 0.01, 0.01)) on a revolute joint, link w welded to it by a fixed joint
    at (0.4, 0, 0) turned a quarter about z (1 kg, COM (0.1, 0, 0) in its frame, diag(0.001, 0.002, 0.003)), and a
    revolute joint below w at (0.2, 0, 0) in w's frame. By hand: M = 3, C = (0.2, 1/30, 0), the inertia about C the
    two inertias (w's turned: diag(0.002, 0.001, 0.003)) plus m (|d|^2 1 - d d^T) with d_a = (-0.1, -1/30, 0), d_w =
    (0.2, 1/15, 0); the joint below w at (0.4, 0.2, 0), turned a quarter about z, in a's frame."""
    path = _write(tmp_path, '<link name="base"/>', _link("a", 2.0, "0.1 0 0", diagonal=(0.01, 0.01, 0.01)),
                  _link("w", 1.0, "0.1 0 0", diagonal=(0.001, 0.002, 0.003)), _link("tip", 0.5),
                  _joint("ja", "base", "a", xyz="0 0 0.5"),
                  _joint("weld", "a", "w", "fixed", xyz="0.4 0 0", rpy=f"0 0 {math.pi / 2}", axis=None),
                  _joint("jt", "w", "tip", xyz="0.2 0 0"))
    F = Fraction
    M, C = F(3), (F(1, 5), F(1, 30), F(0))
    terms = [(F(2), (F(-1, 10), F(-1, 30), F(0)), (F(1, 100), F(1, 100), F(1, 100))),
             (F(1), (F(1, 5), F(1, 15), F(0)), (F(2, 1000), F(1, 1000), F(3, 1000)))]
    by_hand = [[F(0)] * 3 for _ in range(3)]
    for m, d, diagonal in terms:
        dd = sum(x * x for x in d)
        for i in range(3):
            for j in range(3):
                by_hand[i][j] += (diagonal[i] if i == j else 0) + m * ((dd if i == j else 0) - d[i] * d[j])
    assert by_hand[0][1] == F(-1, 50) and by_hand[1][1] == F(71, 1000)          # the numbers of the docstring
    body = file_reading.read_urdf(path, "fixed").bodies["a"]
    assert body.welded == ("a", "w") and body.mass == float(M)
    assert np.allclose(body.com, [float(x) for x in C], rtol=0, atol=1e-16)
    assert np.allclose(body.inertia, np.array(by_hand, dtype=float), rtol=0, atol=1e-16)
    tip = file_reading.read_urdf(path, "fixed").bodies["tip"]
    assert tip.parent == "a" and np.allclose(tip.translation, [0.4, 0.2, 0], rtol=0, atol=1e-16)
    assert np.allclose(tip.rotation, _Rz(math.pi / 2), rtol=0, atol=1e-16)
    model = urdf.from_urdf(path, base="fixed")
    assert [b.name for b in model.bodies] == ["a", "tip"] and not _findings(model)


def test_the_base_fixed_free_or_floating_in_the_file(tmp_path):
    """Fixed: the root link and what is welded to it are the world, no body. Free: the root link is a body on a free
    joint at the identity, with its welded links. A floating joint from a world link: its child is a free body placed
    by the joint's origin."""
    parts = [_link("base", 3.0, "0 0 0.1"), _link("plate", 1.0),
             _link("l1", 1.0, "0.3 0 0"), _joint("weld", "base", "plate", "fixed", xyz="0 0 0.2", axis=None),
             _joint("j1", "plate", "l1", xyz="0.1 0 0")]
    path = _write(tmp_path, *parts)
    fixed = file_reading.read_urdf(path, "fixed")
    assert list(fixed.bodies) == ["l1"] and fixed.bodies["l1"].parent is None
    assert np.allclose(fixed.bodies["l1"].translation, [0.1, 0, 0.2])
    free = file_reading.read_urdf(path, "free")
    assert list(free.bodies) == ["base", "l1"] and free.bodies["base"].kind == "free"
    assert free.bodies["base"].mass == 4.0 and free.bodies["l1"].parent == "base"
    for base in ("fixed", "free"):
        assert not _findings(urdf.from_urdf(path, base=base))
    floating = _write(tmp_path, '<link name="world"/>', _link("body", 2.0, "0 0.1 0"), _link("l1", 1.0),
                      _joint("float", "world", "body", "floating", xyz="1 2 3", rpy="0.1 0.2 0.3", axis=None),
                      _joint("j1", "body", "l1"), name="f.urdf")
    reading = file_reading.read_urdf(floating, "fixed")
    assert reading.bodies["body"].kind == "free" and np.allclose(reading.bodies["body"].translation, [1, 2, 3])
    model = urdf.from_urdf(floating)
    assert model.bodies[0].joint == "free" and not _findings(model)


@pytest.mark.parametrize("axis", ["0 0.6 0.8", "0 0 -1", "1 1 1", "0 -2 0"])
@pytest.mark.parametrize("kind", ["revolute", "continuous", "prismatic"])
def test_an_axis_off_x_y_z_is_compared_in_its_joint_frame(tmp_path, axis, kind):
    """Pinocchio keeps the joint frame as the file gives it and a RevoluteUnaligned (PrismaticUnaligned) joint's axis
    in it: the converted axis is the file's, normalized, and the placement is the origin's, not re-oriented."""
    path = _write(tmp_path, '<link name="base"/>', _link("l1"),
                  _joint("j1", "base", "l1", kind, xyz="0 0 0.1", rpy="0.2 0 0", axis=axis))
    model = urdf.from_urdf(path, base="fixed")
    given = np.array([float(x) for x in axis.split()])
    assert np.allclose(model.bodies[0].axis, given / np.linalg.norm(given), rtol=0, atol=1e-15)
    assert np.allclose(model.bodies[0].rotation, _Rx(0.2), rtol=0, atol=1e-15)
    assert not _findings(model)


def test_an_axis_within_pinocchios_snap_of_x_is_no_finding(tmp_path):
    """Pinocchio takes an axis within 1e-12 |a| of x to be x (Eigen's isApprox): the loader's own rounding."""
    path = _write(tmp_path, '<link name="base"/>', _link("l1"), _joint("j1", "base", "l1", axis="1 9e-13 0"))
    model = urdf.from_urdf(path, base="fixed")
    assert np.array_equal(model.bodies[0].axis, [1.0, 0.0, 0.0]) and not _findings(model)


def test_massless_links_and_a_link_without_inertial(tmp_path):
    """A link without <inertial> is massless; a massless body's COM is not compared (no equation reads it)."""
    path = _write(tmp_path, '<link name="base"/>', '<link name="carrier"/>', _link("l2", 1.0, "0.2 0 0"),
                  _joint("j1", "base", "carrier", axis="1 0 0"), _joint("j2", "carrier", "l2"))
    reading = file_reading.read_urdf(path, "fixed")
    assert reading.bodies["carrier"].mass == 0.0 and not reading.bodies["carrier"].inertia.any()
    assert not _findings(urdf.from_urdf(path, base="fixed"))


def test_a_moved_scene_is_compared_with_its_placement():
    """A moved scene (the frame checks) places the file's world elsewhere: the bodies on the world are compared with
    that placement composed onto the file's."""
    model = cases.load("urdf_gripper")
    moved = frames.move_scene(model, frames.sampled(0, "urdf_gripper", 1)[0])
    assert not moved.source.is_identity and not _findings(moved)
    unmoved_source = dataclasses.replace(moved, source=model.source)
    assert any("placement" in f for f in _findings(unmoved_source))


# -------------------------------------------------------------------------------------- misreads are findings


def _gripper():
    return cases.load("urdf_gripper")


def _body(model, link: str, **change):
    bodies = [dataclasses.replace(b, **change) if b.name == link else b for b in model.bodies]
    return dataclasses.replace(model, bodies=tuple(bodies))


def _coupling(model, **change):
    constraints = [dataclasses.replace(c, **change) if isinstance(c, JointCoupling) else c for c in model.constraints]
    return dataclasses.replace(model, constraints=tuple(constraints))


def _turn(angle):
    return _Rz(angle) @ _Rx(angle)


MISREADS = {     # name -> (a model misread as a parser's bug would, the link named, a fragment of the field)
    "mass": (lambda m: _body(m, "carriage", mass=m.bodies[1].mass * (1 + 1e-9)), "carriage", "mass"),
    "com": (lambda m: _body(m, "wrist", com=m.bodies[0].com + [0, 1e-9, 0]), "wrist", "com"),
    "inertia rotation": (lambda m: _body(m, "carriage", inertia=_turn(1e-8) @ m.bodies[1].inertia @ _turn(1e-8).T),
                         "carriage", "inertia"),
    "inertial rpy ignored (merged body)": (lambda m: _body(m, "carriage", inertia=np.diag(np.diag(
        m.bodies[1].inertia))), "carriage", "inertia"),
    "placement rotation": (lambda m: _body(m, "finger_left", rotation=_turn(1e-10) @ m.bodies[2].rotation),
                           "finger_left", "placement rotation (joint 'finger_left' (revolute))"),
    "placement translation": (lambda m: _body(m, "finger_right", translation=m.bodies[3].translation + [1e-9, 0, 0]),
                              "finger_right", "placement translation"),
    "fixed joint's origin dropped": (lambda m: _body(m, "finger_left", rotation=np.eye(3)), "finger_left",
                                     "placement rotation"),
    "axis sign": (lambda m: _body(m, "finger_left", axis=-m.bodies[2].axis), "finger_left", "axis"),
    "joint type": (lambda m: _body(m, "carriage", joint="revolute"), "carriage", "joint type"),
    "parent": (lambda m: _body(m, "finger_right", parent="wrist"), "finger_right", "parent"),
    "limits in degrees": (lambda m: _body(m, "carriage", limits=tuple(np.degrees(m.bodies[1].limits))), "carriage",
                          "limits (joint 'extend' (prismatic))"),
    "limits invented": (lambda m: _body(m, "wrist", limits=(-1.0, 1.0)), "wrist", "limits"),
    "limits dropped": (lambda m: _body(m, "finger_left", limits=None), "finger_left", "limits"),
    "mimic multiplier sign": (lambda m: _coupling(m, coefficients=(1.0, -0.8)), "finger_right", "mimic multiplier"),
    "mimic offset": (lambda m: _coupling(m, offset=0.0), "finger_right", "mimic offset"),
    "mimic dropped": (lambda m: dataclasses.replace(m, constraints=()), "finger_right", "mimic"),
    "mimic on the wrong joints": (lambda m: _coupling(m, joints=("finger_right", "wrist")), "finger_right", "mimic"),
}


@pytest.mark.parametrize("name", list(MISREADS))
def test_each_kind_of_misread_is_a_loader_finding_naming_the_link_and_field(name):
    misread, link, field = MISREADS[name]
    model = _gripper()
    assert not _findings(model)
    found = _findings(misread(model))
    assert len(found) == 1, found
    assert found[0].startswith(f"loader finding: link '{link}' {field}"), found[0]
    assert "the file says" in found[0] and "the loaded model has" in found[0]


def test_a_finding_gives_both_values_and_the_difference():
    (finding,) = loader.check(_body(_gripper(), "carriage", mass=1.0)).findings
    assert str(finding) == ("loader finding: link 'carriage' mass: the file says 0.9, the loaded model has 1 (max "
                            f"difference 0.1, tolerance {finding.tolerance:.3g})")
    assert finding.tolerance == pytest.approx(0.9e-12) and finding.ratio == pytest.approx(0.1 / 0.9e-12)


def test_a_missing_and_an_extra_body_are_findings():
    model = _gripper()
    missing = dataclasses.replace(model, bodies=model.bodies[:3], constraints=())
    assert _findings(missing)[0] == ("loader finding: link 'finger_right' body: the file says joint 'finger_right' "
                                     "(revolute) moves it, the loaded model has no body for it")
    renamed = [dataclasses.replace(b, name="palm") if b.name == "finger_right" else b for b in model.bodies]
    found = _findings(dataclasses.replace(model, bodies=tuple(renamed), constraints=()))
    assert any("link 'palm' body: the file says no movable joint moves it" in f for f in found), found
    assert any("link 'finger_right' body" in f for f in found), found


def test_rounding_is_no_finding_and_the_tolerance_is_the_scales():
    """A difference at the tolerance's scale (1e-13 relative, ten times below it) is rounding; the same difference
    on a quantity whose scale is smaller is not."""
    model = _gripper()
    body = model.bodies[1]
    assert not _findings(_body(model, "carriage", mass=body.mass * (1 + 1e-13),
                               inertia=body.inertia * (1 + 1e-13), com=body.com * (1 + 1e-13)))
    assert not _findings(_body(model, "carriage", limits=(-0.02 * (1 + 1e-13), 0.06)))
    assert _findings(_body(model, "carriage", mass=body.mass + 1e-11))


def test_a_file_the_second_reading_cannot_read_is_a_finding(tmp_path):
    path = chain_urdf(tmp_path / "r.urdf", [("j1", "base", "l1", "revolute",
                                             '<limit lower="-1" upper="1" effort="1" velocity="1"/>')])
    model = cases.from_file(path, base="fixed")
    Path(path).write_text("<robot")
    (finding,) = _findings(model)
    assert "link 'l1' file" in finding and "not XML" in finding


def test_a_model_without_a_file_has_nothing_to_check():
    assert loader.check(cases.load("double_pendulum")) is None


# ---------------------------------------------------------------------------------------------- real robots


def _robot(name: str) -> str:
    for root in site.getsitepackages():
        path = Path(root) / "cmeel.prefix/share/example-robot-data/robots" / name
        if path.exists():
            return str(path)
    pytest.skip(f"example-robot-data has no {name}")


@pytest.mark.parametrize("name, base", [
    ("ur_description/urdf/ur5_robot.urdf", "fixed"),          # fixed joints, a massless link
    ("baxter_description/urdf/baxter.urdf", "fixed"),         # inertials with rpy, 37 fixed joints, mimics
    ("icub_description/robots/icub.urdf", "free"),            # 29 axes off x, y, z; free base
    ("tiago_pro_description/robots/tiago_pro.urdf", "fixed"),  # an inertial rpy, negative axes, mimics, massless links
    ("talos_data/robots/talos_full_v2.urdf", "free"),         # a humanoid on a free base, mimics on fixed joints
])
def test_real_robots_have_no_finding(name, base):
    model = urdf.from_urdf(_robot(name), base=base)
    checked = loader.check(model)
    assert checked.bodies == len(model.bodies) and not checked.findings, [str(f) for f in checked.findings]


def test_rounding_on_real_robots_is_far_below_the_tolerance(monkeypatch):
    """With the tolerance a million times tighter, every field of two robots agrees within 1e-3 of the real one:
    the tolerance is no looser than rounding needs, by three orders of magnitude."""
    monkeypatch.setattr(file_reading, "ROUNDING", 1e-18)
    monkeypatch.setattr(file_reading, "AXIS_SNAP", 0.0)
    for name, base in (("baxter_description/urdf/baxter.urdf", "fixed"), ("icub_description/robots/icub.urdf",
                                                                           "free")):
        model = urdf.from_urdf(_robot(name), base=base)
        for f in loader.check(model).findings:
            assert f.difference <= 1e-3 * f.tolerance * 1e6, str(f)


# ----------------------------------------------------------------------------------------------- the gate


def _misparsed(monkeypatch, edit):
    """Pinocchio's reading of a URDF (shared by the loader and the reference) parses a copy changed by ``edit``."""
    real = urdf.read_file

    def read(pin, kind, path, root="fixed"):
        copy = Path(path).with_name("misparsed.urdf")
        copy.write_text(edit(Path(path).read_text()))
        return real(pin, kind, str(copy), root)

    monkeypatch.setattr(urdf, "read_file", read)
    from crosscheck.references.pinocchio import build
    monkeypatch.setattr(build, "read_file", read)
    monkeypatch.setattr(build, "_CACHE", {})


def test_a_misparse_every_voter_shares_fails_the_case_before_any_dynamics(tmp_path, monkeypatch):
    """The inertial rpy dropped by the parser, for the backends and the reference alike: the case's outcome carries
    the loader finding, found before its states, and fails."""
    path = _write(tmp_path, '<link name="base"/>', _link("l1", 1.0, "0.2 0 0", "0.3 0.2 0.1"),
                  _joint("j1", "base", "l1", axis="0 1 0"))
    _misparsed(monkeypatch, lambda text: re.sub(r' rpy="0.3 0.2 0.1"', "", text))
    spec = CaseSpec("r", path=path, base="fixed")
    outcome = run_case(spec, [], 2, 0, checks=Checks(charts=False, frames=0, conservation=False,
                                                     linearization=False, self_test=False))
    (finding,) = outcome.loader_findings
    assert str(finding).startswith("loader finding: link 'l1' inertia: the file says")
    assert outcome.failed and not outcome.internal


def test_the_gate_fails_and_reports_a_loader_finding(tmp_path, monkeypatch, capsys):
    path = _write(tmp_path, '<link name="base"/>', _link("l1", 1.0, "0.2 0 0"), _link("l2", 0.5, "0.1 0 0"),
                  _joint("j1", "base", "l1", axis="0 1 0"),
                  _joint("j2", "l1", "l2", xyz="0.4 0 0", rpy="0.5 0 0", axis="0 1 0"))
    _misparsed(monkeypatch, lambda text: text.replace('rpy="0.5 0 0"', 'rpy="0 0 0"'))
    report = tmp_path / "gate.md"
    code = cli.main(["gate", "--model", path, "--base", "fixed", "--samples", "2", "--workers", "0", "--no-charts",
                     "--frames", "0", "--no-conservation", "--no-linearization", "--no-self-test", "--formalism",
                     "newton_euler", "--report", str(report)])
    captured = capsys.readouterr()
    assert code == 1
    assert "FAIL r: loader finding: link 'l2' placement rotation (joint 'j2' (revolute))" in captured.err
    text = report.read_text()
    assert "## Loader findings" in text and "- **r**: loader finding: link 'l2' placement rotation" in text
    assert "read apart from the loader: every field" in text and "1 loader finding(s)" in text


def test_a_correct_file_reports_what_was_compared(tmp_path, capsys):
    path = _write(tmp_path, '<link name="base"/>', _link("l1", 1.0, "0.2 0 0"), _joint("j1", "base", "l1"))
    report = tmp_path / "gate.md"
    code = cli.main(["gate", "--model", path, "--base", "fixed", "--samples", "2", "--workers", "0", "--no-charts",
                     "--frames", "0", "--no-conservation", "--no-linearization", "--no-self-test", "--formalism",
                     "newton_euler", "--report", str(report)])
    assert code == 0, capsys.readouterr()
    assert (f"- r: read apart from the loader: every field (mass, COM, inertia, placement, axis, type, parent, "
            f"limits, mimic) of 1 bodies against the URDF file {Path(path).resolve()}: no finding"
            ) in report.read_text()


# ---------------------------------------------------------------------------------------------- MJCF limits

MJCF = """<mujoco model="m">
 <worldbody>
  <body name="b1"><joint name="h1" type="hinge" axis="0 0 1" range="-90 45"/><geom size="0.1" pos="0.3 0 0" mass="1"/>
   <body name="b2" pos="0.6 0 0"><joint name="s2" type="slide" axis="1 0 0" range="-0.1 0.2"/>
    <geom size="0.1" pos="0.3 0 0" mass="1"/></body>
 </body>
 </worldbody>
</mujoco>"""


def test_an_mjcf_hinge_range_left_in_degrees_is_a_loader_finding(tmp_path):
    """An MJCF model: only its limits are read apart from the loader (the place for a second reading of its bodies:
    crosscheck.guards.loader)."""
    path = tmp_path / "m.xml"
    path.write_text(MJCF)
    model = cases.from_file(str(path))
    checked = loader.check(model)
    assert checked.what == "the joint limits" and not checked.findings
    (finding,) = _findings(_body(model, "b1", limits=(-90.0, 45.0)))
    assert "link 'b1' limits (joint 'h1', revolute)" in finding
    assert "[-90, 45]" in finding and "[-1.570796327, 0.7853981634]" in finding
