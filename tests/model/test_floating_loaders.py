"""Issue 17, the harness side: the model language's group joints, their configuration space, the loaders (URDF with
a fixed or free base, MJCF), quaternion validation, the momentum (Noether) checks and the free body's closed form."""

from __future__ import annotations

import dataclasses
import warnings

import numpy as np
import pinocchio as pin
import pytest

import cases
from cases import configuration
from cases.model import Body, ModelError
from cases.build import build_model
from cases.mjcf import from_mjcf
from cases.urdf import BaseNotice, from_urdf
from crosscheck import cli
from crosscheck.references import closed_forms
from crosscheck.references.pinocchio import build
from crosscheck.references.pinocchio import kinematics
from crosscheck.references.pinocchio import reference
from crosscheck.checks import conservation
from crosscheck.core import sampling
from crosscheck.core.compare import AGREE, DISAGREE
from formalisms.interface import StateError, check_state

from scenes import LIMB_MJCF as MJCF

ROBOTS = "cmeel.prefix/share/example-robot-data/robots"

FLOATING = """<robot name="floating">
  <link name="world"/>
  <joint name="root" type="floating"><parent link="world"/><child link="base"/></joint>
  <link name="base"><inertial><mass value="2"/><origin xyz="0.1 0 0"/>
    <inertia ixx="0.1" iyy="0.2" izz="0.25" ixy="0" ixz="0" iyz="0"/></inertial></link>
  <joint name="j1" type="revolute"><parent link="base"/><child link="arm"/><axis xyz="0 0 1"/><origin xyz="0.3 0 0"/>
    <limit lower="-1" upper="1" effort="1" velocity="1"/></joint>
  <link name="arm"><inertial><mass value="1"/><origin xyz="0.2 0 0"/>
    <inertia ixx="0.01" iyy="0.02" izz="0.02" ixy="0" ixz="0" iyz="0"/></inertial></link>
</robot>
"""




def _robot(name: str) -> str:
    import site

    for root in site.getsitepackages():
        path = f"{root}/{ROBOTS}/{name}"
        try:
            open(path).close()
            return path
        except OSError:
            continue
    pytest.skip(f"example-robot-data has no {name}")


def _write(tmp_path, name: str, text: str) -> str:
    path = tmp_path / name
    path.write_text(text)
    return str(path)


# ------------------------------------------------------------------------------------------ configuration space


def test_integrate_is_pinocchios():
    """q (+) v on SO(3) and SE(3) (right multiplication by the exponential) as Pinocchio integrates."""
    model = cases.load("satellite_arm")
    pm = build.to_pinocchio(model)
    rng = np.random.default_rng(3)
    for _ in range(10):
        q = configuration.random_configuration(model, rng, np.pi, 0.5)
        v = rng.uniform(-2.0, 2.0, model.nv) * rng.choice([1.0, 1e-6])
        np.testing.assert_allclose(configuration.integrate(model, q, v), pin.integrate(pm, q, v), atol=1e-14)


def test_orientations_are_uniform_on_so3():
    """Haar-uniform rotations have E[R] = 0 (every entry): 4000 draws put each mean within 5 standard errors."""
    rng = np.random.default_rng(0)
    R = np.array([configuration.rotation(configuration.random_quaternion(rng)) for _ in range(4000)])
    assert np.abs(R.mean(axis=0)).max() < 5 * np.sqrt(1.0 / 3.0 / 4000)


def test_scalar_models_sample_the_states_they_always_did():
    """Group joints changed the sampler's code, not the states of a model without them (the gate's reports)."""
    model = cases.load("spatial_arm")
    rng = sampling.case_rng(7, "spatial_arm")
    span = np.array([sampling.ANGLE_RANGE if b.joint == "revolute" else sampling.DISPLACEMENT_RANGE
                     for b in model.bodies])
    rng.uniform(-span, span)                                    # state 0's draw, replaced by the home configuration
    rng.uniform(-sampling.RATE_RANGE, sampling.RATE_RANGE, model.n)
    rng.uniform(-sampling.INPUT_RANGE, sampling.INPUT_RANGE, model.m)
    expected = rng.uniform(-span, span)
    assert np.array_equal(sampling.sample_states(model, 2, 7, "spatial_arm")[1].q, expected)


def test_sampled_group_states_are_unit_and_admissible():
    body = Body("base", None, "free", (0, 0, 0), 2.0, com=(0.1, 0, 0), inertia=np.diag([0.1, 0.2, 0.25]))
    arm = Body("arm", "base", "spherical", (0, 0, 0), 1.0, com=(0, 0, -0.3), inertia=np.diag([0.02, 0.02, 0.01]),
               translation=(0.2, 0.0, 0.0))
    pin_arm = cases.PointsCoincide("hand", "arm", (0.0, 0.0, -0.5), None, (0.2, 0.0, -0.5))
    model = build_model("pinned", [body, arm], constraints=[pin_arm])
    for s in sampling.sample_states(model, 6, 1, "pinned"):
        q = np.array(s.q)
        assert not configuration.quaternion_problems(model, q)
        phi, Jc, _ = kinematics.constraint_kinematics(model, q, np.array(s.qd))
        assert np.abs(phi).max() < 1e-12 and np.abs(Jc @ np.array(s.qd)).max() < 1e-12


# -------------------------------------------------------------------------------------------- quaternions


def test_a_non_unit_quaternion_is_refused_with_the_reason():
    model = cases.load("ball_pendulum")
    with pytest.raises(StateError, match=r"q\[0:4\], the quaternion \(x, y, z, w\) of body 'bob', has norm 1.004"):
        check_state(model, [0.1, 0.0, 0.0, 1.0], np.zeros(3), np.zeros(3))
    check_state(model, configuration.normalized(model, [0.1, 0.0, 0.0, 1.0]), np.zeros(3), np.zeros(3))


def test_eval_refuses_or_normalizes_a_quaternion(capsys):
    assert cli.main(["eval", "--case", "free_body", "--q=0,0,0,0.1,0,0,1", "--formalism", "pinocchio"]) == 2
    err = capsys.readouterr().err
    assert len(err.splitlines()) == 1 and "has norm 1.00498" in err and "--normalize" in err
    assert cli.main(["eval", "--case", "free_body", "--q=0,0,0,0.1,0,0,1", "--normalize", "--qd=0,0,0,1,2,3",
                     "--formalism", "pinocchio", "--json"]) == 0


def test_a_joint_coupling_on_a_ball_joint_is_refused():
    bob = Body("bob", None, "spherical", (0, 0, 0), 1.0, com=(0, 0, -1), inertia=0.01 * np.eye(3))
    with pytest.raises(ModelError, match="couples the spherical joint of body 'bob'"):
        build_model("bad", [bob], constraints=[cases.JointCoupling("c", ("bob",), (1.0,), 0.0)])


def test_a_group_joint_has_no_axis():
    with pytest.raises(ModelError, match="has a free joint, which has no axis"):
        build_model("bad", [Body("b", None, "free", (0, 0, 1), 1.0, inertia=np.eye(3))])


# ------------------------------------------------------------------------------------------------ loaders


def test_urdf_without_base_loads_fixed_with_one_notice(tmp_path, capsys):
    path = _robot("solo_description/robots/solo12.urdf")
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        fixed = from_urdf(path)
    assert [type(w.message) for w in caught] == [BaseNotice] and "--base free" in str(caught[0].message)
    assert fixed.nq == fixed.nv == 12 and fixed.source.root == "fixed"
    with warnings.catch_warnings():
        warnings.simplefilter("always", BaseNotice)
        code = cli.main(["eval", "--model", path, "--q=" + ",".join(["0"] * 12), "--formalism", "pinocchio"])
    err = capsys.readouterr().err
    assert code == 0 and err.count("crosscheck: notice:") == 1 and len(err.splitlines()) == 1


def test_urdf_with_a_free_base_is_pinocchios_free_flyer():
    """solo12 with base="free" means what Pinocchio's ``buildModelFromUrdf(path, JointModelFreeFlyer())`` means: the
    same q and v, the same ABA (the reference built from the file) and the same from our conversion's data."""
    path = _robot("solo_description/robots/solo12.urdf")
    model = from_urdf(path, base="free")
    assert (model.nq, model.nv, model.bodies[0].joint, model.source.root) == (19, 18, "free", "free")
    pm = pin.buildModelFromUrdf(path, pin.JointModelFreeFlyer())
    data = pm.createData()
    unsourced = build_model("solo12", model.bodies, model.gravity, model.input_map, model.task_points)
    for s in sampling.sample_states(model, 4, 2, "solo12"):
        q, v, u = (np.array(x) for x in (s.q, s.qd, s.u))
        truth = pin.aba(pm, data, q, v, model.input_map @ u)
        for m in (model, unsourced):
            np.testing.assert_allclose(reference.split(m, q, v, u).total, truth, rtol=1e-12, atol=1e-9)


def test_a_floating_root_joint_floats_and_refuses_a_fixed_base(tmp_path):
    path = _write(tmp_path, "floating.urdf", FLOATING)
    model = from_urdf(path)
    assert [b.joint for b in model.bodies] == ["free", "revolute"] and model.source.root == "fixed"
    with pytest.raises(ModelError, match="root joint 'root' .* is floating"):
        from_urdf(path, base="fixed")
    with pytest.raises(ModelError, match="base must be one of"):
        from_urdf(path, base="floating")


def test_mjcf_hinge_slide_ball_free(tmp_path):
    path = _write(tmp_path, "limb.xml", MJCF)
    model = cases.from_file(path)
    assert [(b.name, b.joint) for b in model.bodies] == [("torso", "free"), ("upper", "spherical"),
                                                         ("lower", "revolute"), ("slider", "prismatic")]
    assert (model.nq, model.nv, model.source.kind) == (13, 11, "mjcf")
    pm = pin.buildModelFromMJCF(path)
    for s in sampling.sample_states(model, 3, 0, "limb"):
        q, v, u = (np.array(x) for x in (s.q, s.qd, s.u))
        truth = pin.aba(pm, pm.createData(), q, v, model.input_map @ u)
        np.testing.assert_allclose(reference.split(model, q, v, u).total, truth, rtol=1e-12, atol=1e-9)
    with pytest.raises(cases.UrdfError, match="MJCF file, whose free joints are declared in it"):
        cases.from_file(path, base="free")


@pytest.mark.parametrize("change, reason", [
    (('<joint name="elbow" type="hinge" axis="0 1 0"/>',
      '<joint name="elbow" type="hinge" axis="0 1 0"/><joint name="twist" type="hinge" axis="0 0 1"/>'),
     "Composite"),
    (("</worldbody>", '</worldbody><equality><joint joint1="elbow" joint2="s"/></equality>'), "<equality>"),
    (('<freejoint name="root"/>', '<joint name="root" type="free" armature="0.1"/>'), "free joint with armature 0.1"),
])
def test_mjcf_what_the_model_language_cannot_hold_is_refused(tmp_path, change, reason):
    path = _write(tmp_path, "bad.xml", MJCF.replace(*change))
    with pytest.raises(ModelError, match=reason):
        from_mjcf(path)


# ------------------------------------------------------------------------------------ momentum and closed form


@pytest.mark.parametrize("case", ["free_body", "satellite_arm", "ball_pendulum", "ball_double_pendulum", "rotor",
                                  "inclined_slider", "double_pendulum"])
def test_momentum_laws_hold_for_the_reference_and_catch_a_wrong_drift(case):
    model = cases.load(case)
    for s in sampling.sample_states(model, 4, 5, case):
        split = reference.split(model, s.q, s.qd, s.u)
        check = conservation.momentum_checks(model, s, {"pinocchio": split})
        (comparison,) = check.values()
        assert comparison.verdict == AGREE, comparison
        bad = dataclasses.replace(split, drift=split.drift + 1e-6 * (1.0 + np.abs(split.drift).max()))
        (caught,) = conservation.momentum_checks(model, s, {"pinocchio": split, "bad": bad}).values()
        assert caught.verdict == DISAGREE and caught.outlier == "bad"


def test_no_momentum_law_for_a_constrained_model():
    model = cases.load("four_bar")
    s = sampling.sample_states(model, 2, 0, "four_bar")[1]
    assert conservation.momentum_checks(model, s, {"pinocchio": reference.split(model, s.q, s.qd, s.u)}) == {}


def test_free_body_closed_form_is_eulers_equations():
    """Zero gravity: Euler's ``I1 w1' = (I2 - I3) w2 w3`` (and cyclic) at the centre of mass, typed in here."""
    I1, I2, I3 = 0.02, 0.05, 0.06
    model = cases.load("free_body")
    voter = closed_forms.voter("free_body", {})
    for s in sampling.sample_states(model, 5, 4, "free_body"):
        w = np.array(s.qd[3:])
        euler = np.array([(I2 - I3) * w[1] * w[2] / I1, (I3 - I1) * w[2] * w[0] / I2, (I1 - I2) * w[0] * w[1] / I3])
        drift = voter.split(model, s.q, s.qd, s.u).drift
        np.testing.assert_allclose(drift[3:], euler, rtol=1e-12, atol=1e-12)
        np.testing.assert_allclose(drift, reference.split(model, s.q, s.qd, s.u).drift, rtol=1e-12, atol=1e-12)
