"""The URDF loader on any input (issue 16): no traceback, and never a model of something else.

* ``<mimic>`` joints become ``JointCoupling`` constraints (checked against Pinocchio's own mimic model and through the
  gate), the reference refuses a model whose couplings are not the file's mimics, and bad mimic tags are refused;
* a URDF that is not a tree (a link that is its own parent, a closed chain, a link with two parent joints) is refused
  with the joints named, where Pinocchio drops the joints silently;
* unaligned revolute, continuous and prismatic axes load with their axis and pass the gate against Pinocchio;
* every bad file gives exit 2 and one line from ``crosscheck gate --model``.
"""

from __future__ import annotations

import pathlib
import re

import numpy as np
import pinocchio as pin
import pytest

import cases
from cases import JointCoupling, ModelError, UrdfError, build_model, from_urdf
from crosscheck import cli
from crosscheck.references.pinocchio import build
from crosscheck.references.pinocchio import reference
from crosscheck.reports import gate_summary

LIMIT = '<limit lower="-3" upper="3" effort="10" velocity="5"/>'


def _link(name: str, mass="1.0", ixx="0.01") -> str:
    return (f'<link name="{name}"><inertial><origin xyz="0.05 0 0.1"/><mass value="{mass}"/>'
            f'<inertia ixx="{ixx}" iyy="0.012" izz="0.008" ixy="0" ixz="0" iyz="0"/></inertial></link>')


def _joint(name: str, parent: str, child: str, kind="revolute", axis="0 0 1", xyz="0 0 0.2", extra="") -> str:
    limit = LIMIT if kind in ("revolute", "prismatic") else ""
    return (f'<joint name="{name}" type="{kind}"><parent link="{parent}"/><child link="{child}"/>'
            f'<origin xyz="{xyz}" rpy="0 0 0"/><axis xyz="{axis}"/>{limit}{extra}</joint>')


def _robot(links, joints, name="r") -> str:
    return "\n".join(['<?xml version="1.0"?>', f'<robot name="{name}">', *links, *joints, "</robot>"])


def _write(tmp_path, text: str, name: str = "r") -> str:
    path = tmp_path / f"{name}.urdf"
    path.write_text(text)
    return str(path)


def _chain(*joints) -> str:
    """base -> a -> b -> c with the given joints (each a ``_joint`` string)."""
    return _robot([_link("base"), _link("a"), _link("b"), _link("c")], list(joints))


def _mimic(joint: str, multiplier=None, offset=None) -> str:
    attrs = f'joint="{joint}"' + (f' multiplier="{multiplier}"' if multiplier is not None else "") + (
        f' offset="{offset}"' if offset is not None else "")
    return f"<mimic {attrs}/>"


#: j3 (on link c) follows j1 (on link a): q_j3 = -2 q_j1 + 0.3; j2 (prismatic, about y) is free.
MIMIC = _chain(_joint("j1", "base", "a"), _joint("j2", "a", "b", kind="prismatic", axis="0 1 0"),
               _joint("j3", "b", "c", axis="1 0 0", extra=_mimic("j1", -2.0, 0.3)))


def _gate(path: str, tmp_path, samples: int) -> tuple[int, str]:
    rc = cli.main(["gate", "--model", path, "--samples", str(samples), "--workers", "0",
                   "--report", str(tmp_path / "report.md")])
    return rc, gate_summary.read(tmp_path / "report.md") if rc in (0, 1) else ""


# ---------------------------------------------------------------------------------------------------- mimic


def test_a_mimic_joint_is_a_joint_coupling(tmp_path):
    model = from_urdf(_write(tmp_path, MIMIC))
    assert [b.name for b in model.bodies] == ["a", "b", "c"] and model.k == 1
    assert model.constraints == (JointCoupling("mimic:j3", ("c", "a"), (1.0, 2.0), 0.3),)


def test_mimic_defaults_are_multiplier_one_offset_zero(tmp_path):
    model = from_urdf(_write(tmp_path, _chain(_joint("j1", "base", "a"), _joint("j2", "a", "b", extra=_mimic("j1")),
                                              _joint("j3", "b", "c"))))
    assert model.constraints == (JointCoupling("mimic:j2", ("b", "a"), (1.0, -1.0), 0.0),)


def test_mimic_split_matches_pinocchios_own_mimic_model(tmp_path):
    """Pinocchio's ``mimic=True`` model has 2 coordinates (j1, j2) and q = G q_r + (0, 0, 0.3): the constrained
    reference split (built from the file, with our coupling) is G times its accelerations."""
    path = _write(tmp_path, MIMIC)
    model, direct = from_urdf(path), pin.buildModelFromUrdf(path, mimic=True)
    assert direct.nv == 2
    G = np.array([[1.0, 0.0], [0.0, 1.0], [-2.0, 0.0]])
    data, rng = direct.createData(), np.random.default_rng(5)
    for _ in range(3):
        q_r, v_r, u = rng.uniform(-1, 1, 2), rng.uniform(-1, 1, 2), rng.uniform(-2, 2, 3)
        s = reference.split(model, G @ q_r + [0.0, 0.0, 0.3], G @ v_r, u)
        M = pin.crba(direct, data, q_r)
        M = np.triu(M) + np.triu(M, 1).T
        h = pin.rnea(direct, data, q_r, v_r, np.zeros(2))
        np.testing.assert_allclose(s.total, G @ np.linalg.solve(M, G.T @ u - h), atol=1e-10)
        np.testing.assert_allclose(s.drift, G @ np.linalg.solve(M, -h), atol=1e-10)


def test_gate_passes_on_a_mimic_urdf(tmp_path):
    rc, report = _gate(_write(tmp_path, MIMIC), tmp_path, 4)
    assert rc == 0 and "| lam |" in report


def test_panda_fingers_are_coupled():
    model = cases.load("panda")
    assert model.n == 9 and model.k == 1
    assert model.constraints == (JointCoupling("mimic:panda_finger_joint2", ("panda_rightfinger", "panda_leftfinger"),
                                               (1.0, -1.0), 0.0),)


@pytest.mark.parametrize("declared, message", [
    ((), "declares no joint coupling 'mimic:j3'"),
    ((JointCoupling("mimic:j3", ("c", "a"), (1.0, -2.0), 0.3),), "mimics 'j1'"),   # the multiplier's sign lost
    ((JointCoupling("mimic:j3", ("c", "b"), (1.0, 2.0), 0.3),), "mimics 'j1'"),    # mapped to the wrong joint
    ((JointCoupling("mimic:j3", ("c", "a"), (1.0, 2.0), 0.0),), "mimics 'j1'"),    # the offset lost
    ((JointCoupling("mimic:j3", ("c", "a"), (-2.0, -4.0), -0.6),                   # the same row times -2 is fine,
      JointCoupling("mimic:j2", ("b", "a"), (1.0, -1.0), 0.0)), r"declares \['mimic:j2'\]"),  # an invented one not
])
def test_the_reference_checks_the_mimic_couplings_against_the_file(tmp_path, declared, message):
    loaded = from_urdf(_write(tmp_path, MIMIC))
    model = build_model(loaded.name, loaded.bodies, loaded.gravity, task_points=loaded.task_points,
                        constraints=declared, source=loaded.source)
    with pytest.raises(ValueError, match=message):
        build.joint_map(model)


def test_the_reference_accepts_a_scaled_coupling_row(tmp_path):
    loaded = from_urdf(_write(tmp_path, MIMIC))
    model = build_model(loaded.name, loaded.bodies, loaded.gravity, task_points=loaded.task_points,
                        constraints=[JointCoupling("mimic:j3", ("a", "c"), (-4.0, -2.0), -0.6)], source=loaded.source)
    assert len(build.joint_map(model)) == 3


@pytest.mark.parametrize("mimic, reason", [
    (_mimic("j3"), "joint 'j3' mimics joint 'j3', itself"),
    (_mimic("j2"), "joint 'j3' mimics joint 'j2', which itself mimics another joint"),
    (_mimic("j1", 0), "joint 'j3' mimics joint 'j1' with multiplier 0"),
    (_mimic("j1", "nan"), "joint 'j3' mimics joint 'j1' with multiplier 'nan'; give a finite number"),
    (_mimic("j1", "inf"), "with multiplier 'inf'"),
    (_mimic("j1", "two"), "with multiplier 'two'"),
    (_mimic("j1", 1, "nan"), "with offset 'nan'"),
    ("<mimic/>", "joint 'j3' has a <mimic> without a joint attribute"),
    (_mimic("j1") + _mimic("j1", 2), "joint 'j3' has 2 <mimic> tags"),
])
def test_a_bad_mimic_is_refused_with_the_joint_and_the_reason(tmp_path, mimic, reason):
    text = _chain(_joint("j1", "base", "a"), _joint("j2", "a", "b", extra=_mimic("j1")),
                  _joint("j3", "b", "c", extra=mimic))
    with pytest.raises(ModelError, match=reason):
        from_urdf(_write(tmp_path, text))


def test_a_mimic_of_a_fixed_joint_is_refused_and_one_on_a_fixed_joint_is_ignored(tmp_path):
    text = _chain(_joint("j1", "base", "a", kind="fixed"), _joint("j2", "a", "b", extra=_mimic("j1")),
                  _joint("j3", "b", "c"))
    with pytest.raises(ModelError) as info:
        from_urdf(_write(tmp_path, text))
    assert "joint 'j2' mimics joint 'j1', a fixed joint with no coordinate; remove the tag" in str(info.value)
    on_fixed = _chain(_joint("j1", "base", "a"), _joint("j2", "a", "b"),
                      _joint("j3", "b", "c", kind="fixed", extra=_mimic("j2")))     # TALOS's grippers
    with pytest.warns(cases.urdf.MimicNotice, match=r"1 fixed joint\(s\) carry a <mimic> tag, ignored.*\(j3\)"):
        model = from_urdf(_write(tmp_path, on_fixed), base="fixed")
    assert model.n == 2 and model.constraints == ()


# ----------------------------------------------------------------------------------------------- not a tree


@pytest.mark.parametrize("joints, reason", [
    ([_joint("j1", "base", "a"), _joint("j2", "a", "b"), _joint("j3", "c", "c")],
     "joint 'j3' attaches link 'c' to itself"),
    ([_joint("j1", "base", "a"), _joint("j2", "b", "c"), _joint("j3", "c", "b")],
     r"joints \['j2', 'j3'\] form a closed chain"),
    ([_joint("j1", "base", "a"), _joint("j2", "a", "b"), _joint("j3", "b", "c"), _joint("j4", "c", "a")],
     r"link 'a' is the child of 2 joints \['j1', 'j4'\]"),
    ([_joint("j1", "base", "a"), _joint("j2", "a", "b"), _joint("j3", "b", "zz")],
     r"joint 'j3' names link\(s\) \['zz'\]"),
])
def test_a_urdf_that_is_not_a_tree_is_refused_with_the_joints(tmp_path, joints, reason):
    with pytest.raises(ModelError, match=reason) as info:
        from_urdf(_write(tmp_path, _chain(*joints)))
    assert "a URDF describes a tree" in str(info.value) or "names link" in str(info.value)


# ------------------------------------------------------------------------------------------- unaligned axes


#: A continuous joint about (0.6, 0.8, 0), a revolute one about (0.6, 0, 0.8), a prismatic one along (0, 0.6, 0.8).
UNALIGNED = _chain(_joint("j1", "base", "a", kind="continuous", axis="0.6 0.8 0"),
                   _joint("j2", "a", "b", axis="0.6 0 0.8"), _joint("j3", "b", "c", kind="prismatic", axis="0 0.6 0.8"))


def test_unaligned_axes_load_with_their_axes(tmp_path):
    model = from_urdf(_write(tmp_path, UNALIGNED))
    assert [b.joint for b in model.bodies] == ["revolute", "revolute", "prismatic"]
    for body, axis in zip(model.bodies, [(0.6, 0.8, 0.0), (0.6, 0.0, 0.8), (0.0, 0.6, 0.8)]):
        np.testing.assert_allclose(body.axis, axis, atol=1e-15)


def test_gate_passes_on_unaligned_axes(tmp_path):
    rc, report = _gate(_write(tmp_path, UNALIGNED), tmp_path, 10)
    assert rc == 0, report


# ------------------------------------------------------------------------------------------- the command line


BAD = {
    "empty": ("", "is empty"),
    "not XML": ("hello <<< world", "is not XML"),
    "not a robot": ("<?xml version='1.0'?><foo><bar/></foo>", "root element is <foo>, not <robot>"),
    "negative mass": (_robot([_link("base"), _link("a", mass="-1")], [_joint("j1", "base", "a")]), "negative mass"),
    "inertia not PD": (_robot([_link("base"), _link("a", ixx="-0.5")], [_joint("j1", "base", "a")]),
                       "not positive semi-definite"),
    "NaN inertia": (_robot([_link("base"), _link("a", ixx="nan")], [_joint("j1", "base", "a")]),
                    "urdfdom reported errors"),
    "zero axis": (_robot([_link("base"), _link("a")], [_joint("j1", "base", "a", axis="0 0 0")]), "zero joint axis"),
    "NaN origin": (_robot([_link("base"), _link("a")], [_joint("j1", "base", "a", xyz="nan 0 0")]),
                   r"urdfdom: Unable to parse component \[nan\]"),
    "planar": (_robot([_link("base"), _link("a")], [_joint("j1", "base", "a", kind="planar")]), "JointModelPlanar"),
    "cycle": (_chain(_joint("j1", "base", "a"), _joint("j2", "b", "c"), _joint("j3", "c", "b")), "closed chain"),
    "duplicate joint": (_chain(_joint("j1", "base", "a"), _joint("j1", "a", "b"), _joint("j3", "b", "c")),
                        "joint name 'j1' is used by 2 joints"),
}


def _assert_one_line_exit_2(path: str, tmp_path, capfd, reason: str) -> None:
    rc = cli.main(["gate", "--model", path, "--samples", "1", "--workers", "0", "--report", str(tmp_path / "r.md")])
    out, err = capfd.readouterr()
    assert rc == 2, out + err
    assert len(err.splitlines()) == 1 and err.startswith("crosscheck: error: "), err
    assert re.search(reason, err), err


@pytest.mark.parametrize("which", list(BAD))
def test_a_bad_file_is_exit_2_with_one_line(tmp_path, capfd, which):
    text, reason = BAD[which]
    _assert_one_line_exit_2(_write(tmp_path, text, which.replace(" ", "_")), tmp_path, capfd, reason)


def test_a_directory_is_exit_2_with_one_line(tmp_path, capfd):
    (tmp_path / "d.urdf").mkdir()
    _assert_one_line_exit_2(str(tmp_path / "d.urdf"), tmp_path, capfd, "is a directory, not a file")


def test_an_unreadable_file_is_exit_2_with_one_line(tmp_path, capfd, monkeypatch):
    """The read fails as for a file without read permission (simulated: chmod does not stop root)."""
    path = _write(tmp_path, MIMIC)
    real = pathlib.Path.read_bytes

    def denied(self):
        if str(self) == path:
            raise PermissionError(13, "Permission denied", path)
        return real(self)

    monkeypatch.setattr(pathlib.Path, "read_bytes", denied)
    _assert_one_line_exit_2(path, tmp_path, capfd, "cannot read URDF file .*Permission denied")


def test_urdfdom_errors_on_a_file_pinocchio_accepts_are_an_error(tmp_path):
    """urdfdom skips an inertial it cannot read (the link becomes massless) and Pinocchio returns the model anyway."""
    text = _chain(_joint("j1", "base", "a"), _joint("j2", "a", "b"), _joint("j3", "b", "c"))
    with pytest.raises(UrdfError, match=r"mass \[nan\] is not a float"):
        from_urdf(_write(tmp_path, text.replace('<mass value="1.0"/>', '<mass value="nan"/>', 2)))


# ------------------------------------------------------------------------------------------ model findings


def test_an_impossible_inertia_is_a_finding_at_the_top_and_strict_model_refuses_it(tmp_path, capfd):
    """romeo_small's case: a principal moment above the sum of the others (0.05 > 0.012 + 0.008) is reported, and the
    backends are still compared; ``--strict-model`` refuses the file instead (exit 2, one line)."""
    path = _write(tmp_path, _robot([_link("base"), _link("a", ixx="0.05"), _link("b")],
                                   [_joint("j1", "base", "a"), _joint("j2", "a", "b", axis="0 1 0")]))
    rc, summary = _gate(path, tmp_path, 3)
    assert rc == 0
    top = summary.split("- command:")[0]
    assert "## Model findings" in top and "body 'a' inertia about its COM violates the triangle inequality" in top
    assert "model finding(s) at its top" in capfd.readouterr().out
    assert cli.main(["gate", "--model", path, "--samples", "1", "--strict-model", "--workers", "0",
                     "--report", str(tmp_path / "strict.md")]) == 2
    err = capfd.readouterr().err
    assert "triangle inequality" in err and "leave --strict-model out" in err and len(err.splitlines()) == 1


def test_a_mimic_of_a_joint_that_does_not_exist_is_a_finding_and_ignored(tmp_path):
    """alex_psyonic_hands: ``Left_index_q2`` mimics ``index_q1`` (the file means ``Left_index_q1``); Pinocchio loads
    the file, so the tag is ignored and reported, the joint moves freely, and the reference agrees (it skips the tag
    too)."""
    path = _write(tmp_path, _chain(_joint("j1", "base", "a"), _joint("j2", "a", "b", extra=_mimic("j_1")),
                                   _joint("j3", "b", "c")))
    model = from_urdf(path, base="fixed")
    assert model.constraints == () and model.n == 3
    assert model.findings == ("joint 'j2' mimics joint 'j_1', which does not exist: the tag is ignored, so 'j2' "
                              "moves freely (did the file mean 'j1'?)",)
    rc, summary = _gate(path, tmp_path, 2)
    assert rc == 0 and "which does not exist: the tag is ignored" in summary.split("- command:")[0]
