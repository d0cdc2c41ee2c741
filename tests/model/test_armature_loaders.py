"""Armature in the model language (``cases.model.Body.armature``: a rotor's inertia added to each of the joint's
diagonal entries of M): validation, the digest, serialization, the loaders (MJCF reads it, a URDF takes it from the
user), the command line's ``--armature``, and MuJoCo's own M on the shipped file."""

from __future__ import annotations

import dataclasses
import json
import shlex
from pathlib import Path

import numpy as np
import pytest

import cases
import cases.mjcf
import cases.urdf
from cases.build import build_model
from cases.file_cases import FILES
from cases.model import ModelError, ModelSource
from cases.serialize import SerializeError, model_from_dict, model_to_dict
from crosscheck import cli
from crosscheck.checks import frames
from crosscheck.cli.options import UsageError, _armature
from crosscheck.engine.specs import CaseSpec
from crosscheck.references.pinocchio import kinematics

ROOT = Path(__file__).resolve().parents[2]
ARM = str(ROOT / "examples" / "arm.urdf")


def _body(**kw):
    return cases.Body(**{"name": "b", "parent": None, "joint": "revolute", "axis": (0, 0, 1), "mass": 1.0,
                         "com": (0.2, 0, 0), **kw})


# ---------------------------------------------------------------------------------------------- the field


def test_armature_defaults_to_zero_and_repeats_over_a_joints_velocities():
    assert _body().armature == 0.0
    model = build_model("m", [_body(armature=0.25), _body(name="c", parent="b", joint="spherical", axis=(0, 0, 0),
                                                            inertia=np.eye(3) * 0.01, armature=0.5)])
    assert model.armature_vector.tolist() == [0.25, 0.5, 0.5, 0.5] and model.has_armature
    assert not model.armature_vector.flags.writeable


@pytest.mark.parametrize("value, fragment", [(-0.1, "must be finite and >= 0"), (float("nan"), "must be finite"),
                                             (float("inf"), "must be finite"), ("heavy", "is not a number"),
                                             (True, "is not a number"), (None, "is not a number")])
def test_a_bad_armature_is_refused_with_the_body_named(value, fragment):
    with pytest.raises(ModelError, match=f"body 'b' armature .*{fragment}"):
        build_model("m", [_body(armature=value)])


def test_a_free_joints_armature_is_refused_saying_why():
    with pytest.raises(ModelError, match="body 'b' has a free joint with armature 0.2.*gyroscopic.*give it armature 0"):
        build_model("m", [_body(joint="free", axis=(0, 0, 0), inertia=np.eye(3) * 0.01, armature=0.2)])


def test_armature_is_physics_in_the_digest_and_a_model_without_it_keeps_its_digest():
    plain = build_model("m", [_body()])
    armed = build_model("m", [_body(armature=0.1)])
    assert plain.digest() != armed.digest() != build_model("m", [_body(armature=0.2)]).digest()
    assert build_model("m", [_body(armature=-0.0)]).digest() == plain.digest()
    assert cases.load("double_pendulum").digest() == "0276abca903a" + cases.load("double_pendulum").digest()[12:]


def test_armature_adds_to_the_inertia_scale():
    plain, armed = build_model("m", [_body()]), build_model("m", [_body(armature=0.1)])
    assert armed.inertia_scale == pytest.approx(plain.inertia_scale + 0.1)


# ------------------------------------------------------------------------------------------ serialization


def test_armature_round_trips_exactly_and_an_old_dict_reads_as_zero():
    model = cases.load("double_pendulum", a1=0.1 + 0.2, a2=1e-300)
    d = json.loads(json.dumps(model_to_dict(model)))
    back = model_from_dict(d)
    assert [b.armature for b in back.bodies] == [0.1 + 0.2, 1e-300] and back.digest() == model.digest()
    assert "armature" not in model_to_dict(cases.load("double_pendulum"))["bodies"][0]   # written only when set
    old = model_to_dict(cases.load("double_pendulum"))
    assert model_from_dict(old).armature_vector.tolist() == [0.0, 0.0]
    d["bodies"][0]["armature"] = -1.0
    with pytest.raises(ModelError, match="body 'link1' armature -1.0 must be finite and >= 0"):
        model_from_dict(d)
    d["bodies"][0]["armature"] = "x"
    with pytest.raises(SerializeError, match=r"bodies\[0\].armature"):
        model_from_dict(d)


def test_a_sources_declared_armature_round_trips_and_moves_with_the_scene():
    model = cases.from_urdf(ARM, base="fixed", armature={"elbow": 0.3})
    back = model_from_dict(json.loads(json.dumps(model_to_dict(model))))
    assert back.source.armature == (("elbow", 0.3),) and back.source == model.source
    moved = frames.move_scene(model, frames.sampled(0, "arm", 1)[0])
    assert moved.source.armature == (("elbow", 0.3),) and moved.source.without_gravity().armature == (("elbow", 0.3),)
    assert model.source.key() != cases.from_urdf(ARM, base="fixed").source.key()
    with pytest.raises(ModelError, match="source armature"):
        build_model("m", [_body()], source=ModelSource("urdf", ARM, armature=(("elbow", -1.0),)))


# ------------------------------------------------------------------------------------------------- loaders


def test_the_mjcf_loader_reads_armature_on_the_joint_from_a_default_class_and_on_a_slide():
    model = cases.load("mjcf_armature")
    assert [(b.name, b.joint, b.armature) for b in model.bodies] == [
        ("base_link", "revolute", 0.12), ("upper_arm", "revolute", 0.045), ("forearm", "revolute", 0.02),
        ("tool", "prismatic", 0.3)]
    assert model.source.armature == () and model.findings == ()


def _mjcf(tmp_path, joint: str) -> Path:
    path = tmp_path / "m.xml"
    path.write_text(f"""<mujoco model="m"><worldbody><body name="b" pos="0 0 1">{joint}
        <inertial pos="0.1 0 0" mass="1" diaginertia="0.01 0.02 0.025"/></body></worldbody></mujoco>""")
    return path


def test_an_mjcf_ball_joints_armature_is_on_its_three_velocities_and_a_free_joints_is_refused(tmp_path):
    ball = cases.mjcf.from_mjcf(_mjcf(tmp_path, '<joint name="j" type="ball" armature="0.05"/>'))
    assert ball.armature_vector.tolist() == [0.05] * 3
    with pytest.raises(ModelError, match="(?s)MJCF file .*body 'b' has a free joint with armature 0.05"):
        cases.mjcf.from_mjcf(_mjcf(tmp_path, '<joint name="j" type="free" armature="0.05"/>'))


def test_a_joint_with_unequal_armature_over_its_velocities_is_refused_naming_it(tmp_path):
    import pinocchio as pin

    pm = pin.buildModelFromMJCF(str(_mjcf(tmp_path, '<joint name="j" type="ball" armature="0.05"/>')))
    pm.armature = np.array([0.05, 0.05, 0.07])
    with pytest.raises(ModelError, match=r"joint 'j' has armature \[0.05, 0.05, 0.07\] over its 3 velocities"):
        cases.urdf.convert(pin, pm, "m", ModelSource("mjcf", str(tmp_path / "m.xml")))


def test_a_urdf_takes_armature_by_joint_name_and_refuses_what_is_no_movable_joint():
    model = cases.from_urdf(ARM, base="fixed", armature={"shoulder_pitch": 0.02})
    assert model.armature_vector.tolist() == [0.0, 0.02, 0.0]
    with pytest.raises(ModelError, match=r"armature names joint 'wrist', which is not a joint of the file; movable "
                                         r"joints: \['elbow', 'shoulder_pitch', 'shoulder_yaw'\]"):
        cases.from_urdf(ARM, base="fixed", armature={"wrist": 0.02})
    with pytest.raises(ModelError, match="armature names joint 'tool_mount', which is fixed"):
        cases.from_urdf(ARM, base="fixed", armature={"tool_mount": 0.02})
    with pytest.raises(ModelError, match="armature of joint 'elbow' is -1"):
        cases.from_urdf(ARM, base="fixed", armature={"elbow": -1})
    with pytest.raises(cases.urdf.UrdfError, match="declares its joints' armature itself"):
        cases.from_file(str(FILES / "armature_arm.xml"), armature={"upper": 0.1})


# --------------------------------------------------------------------------------------------- command line


def test_the_armature_option_parses_pairs_and_refuses_anything_else():
    assert _armature("shoulder_yaw=0.01, elbow=2e-3") == (("shoulder_yaw", 0.01), ("elbow", 0.002))
    for bad in ("elbow", "=0.1", "elbow=heavy", "", "a=1,a=2"):
        with pytest.raises(UsageError):
            _armature(bad)


def test_the_armature_option_reaches_the_model_and_the_reproduce_command(capsys):
    spec = CaseSpec("arm", path=ARM, base="fixed", armature=(("elbow", 0.1 + 0.2),))
    assert spec.build().armature_vector.tolist() == [0.0, 0.0, 0.1 + 0.2]
    args = shlex.split(spec.cli_args())
    assert args[args.index("--armature") + 1] == "elbow=0.30000000000000004"
    assert cli.main(["eval", "--model", ARM, "--base", "fixed", "--armature", "elbow=0.3", "--q=0.1,0.2,0.3",
                     "--formalism", "newton_euler"]) == 0
    assert cli.main(["gate", "--case", "double_pendulum", "--armature", "elbow=0.3"]) == 2
    assert "--armature applies to a --model URDF file" in capsys.readouterr().err


# ---------------------------------------------------------------------------------------------- MuJoCo's M


def test_mujocos_mass_matrix_on_the_shipped_file_is_ours_with_the_armature():
    """MuJoCo reads cases/files/armature_arm.xml itself (its own parser, its own CRBA, its dof_armature): its full M
    equals the harness's (Pinocchio on our model data, armature from our bodies) at a few configurations, and without
    the armature it would not."""
    mujoco = pytest.importorskip("mujoco")
    model = cases.load("mjcf_armature")
    mj = mujoco.MjModel.from_xml_path(str(FILES / "armature_arm.xml"))
    data = mujoco.MjData(mj)
    assert mj.dof_armature.tolist() == [0.12, 0.045, 0.02, 0.3]
    dof = [int(mj.jnt_dofadr[mj.body_jntadr[mj.body(b.name).id]]) for b in model.bodies]
    rng = np.random.default_rng(0)
    for _ in range(3):
        q = rng.uniform(-1.0, 1.0, model.nq) * np.array([3.0, 2.0, 3.0, 0.05])
        data.qpos[dof] = q
        mujoco.mj_forward(mj, data)
        M_mj = np.zeros((mj.nv, mj.nv))
        mujoco.mj_fullM(mj, data, M_mj)
        M = kinematics.mass_matrix(model, q)
        np.testing.assert_allclose(M_mj[np.ix_(dof, dof)], M, rtol=1e-10, atol=1e-12)
        bare = kinematics.mass_matrix(dataclasses.replace(model, bodies=tuple(
            dataclasses.replace(b, armature=0.0) for b in model.bodies)), q)
        np.testing.assert_allclose(np.diag(M - bare), [0.12, 0.045, 0.02, 0.3], atol=1e-14)
