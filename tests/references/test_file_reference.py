"""The reference of a loaded model reads the file itself (issue 15, item 1).

* provenance: ``Model.source`` (set by the URDF loader, left out of the digest, carried and composed by a frame
  change, round-tripped by ``cases.serialize``);
* the file-built reference agrees with the reference built from our converted data to rounding (panda and small
  URDFs written here: revolute, continuous about a non-axis direction, prismatic, fixed joints merged, unaligned
  axes, a branched tree), at several states, in a moved scene, with our coordinates listed in another order and
  with constraints declared on the loaded bodies;
* the joint map (by link name, sign +1) and its errors;
* conversion bugs injected into ``cases/urdf.py`` make the gate DISAGREE with the reference named as the outlier,
  and the hint says to suspect the conversion.
"""

from __future__ import annotations

import dataclasses
import json

import numpy as np
import pinocchio as pin
import pytest

import cases
import cases.urdf
from cases import build_model, from_urdf
from cases.model import Body, ModelError, ModelSource
from cases.serialize import SerializeError, model_from_dict, model_to_dict
from crosscheck.reports import diagnosis
from crosscheck.checks import frames
from crosscheck.engine import evaluation
from crosscheck.engine import run
from crosscheck.engine import specs
from crosscheck.references.pinocchio import build
from crosscheck.references.pinocchio import kinematics
from crosscheck.references.pinocchio import reference
from crosscheck.backends import get, names
from crosscheck.core.compare import DISAGREE, suspect
from crosscheck.core.sampling import sample_states

PANDA_LINKS = [f"panda_link{i}" for i in range(1, 8)] + ["panda_leftfinger", "panda_rightfinger"]
PANDA_JOINTS = [f"panda_joint{i}" for i in range(1, 8)] + ["panda_finger_joint1", "panda_finger_joint2"]

LIMIT = '<limit lower="-3" upper="3" effort="10" velocity="5"/>'


def _link(name: str, mass: float, com: str, inertia: tuple) -> str:
    ixx, ixy, ixz, iyy, iyz, izz = inertia
    return (f'<link name="{name}"><inertial><origin xyz="{com}" rpy="0.1 -0.2 0.3"/><mass value="{mass}"/>'
            f'<inertia ixx="{ixx}" ixy="{ixy}" ixz="{ixz}" iyy="{iyy}" iyz="{iyz}" izz="{izz}"/></inertial></link>')


def _joint(name: str, kind: str, parent: str, child: str, xyz: str, rpy: str, axis: str | None = None) -> str:
    axis_xml = f'<axis xyz="{axis}"/>' if axis else ""
    limit = LIMIT if kind in ("revolute", "prismatic") else ""
    return (f'<joint name="{name}" type="{kind}"><parent link="{parent}"/><child link="{child}"/>'
            f'<origin xyz="{xyz}" rpy="{rpy}"/>{axis_xml}{limit}</joint>')


I1 = (0.02, 0.001, -0.002, 0.03, 0.0015, 0.025)
I2 = (0.004, 0.0, 0.0005, 0.005, -0.0003, 0.006)

#: A branched tree: trunk (revolute z, placed with rpy) carries a rotor (continuous about (0, 0.6, 0.8)) with a
#: welded cap (fixed: merged), whose forearm turns about an unaligned axis and ends in a welded tool centre point;
#: and a slider (prismatic y) with a carriage (prismatic about (0.6, 0, 0.8)) and a hand (revolute x).
BRANCHED = "\n".join([
    '<?xml version="1.0"?>', '<robot name="branched">',
    _link("base", 5.0, "0 0 0.05", I1),
    _joint("j_root", "revolute", "base", "trunk", "0.1 -0.2 0.3", "0.2 -0.1 0.4", "0 0 1"),
    _link("trunk", 2.0, "0.05 0.01 0.2", I1),
    _joint("j_spin", "continuous", "trunk", "rotor", "0 0.1 0.4", "0 0.3 0", "0 0.6 0.8"),
    _link("rotor", 0.7, "0.02 0 0.01", I2),
    _joint("j_weld", "fixed", "rotor", "rotor_cap", "0.1 0 0", "0.1 0 0"),
    _link("rotor_cap", 0.3, "0.01 0.02 0", I2),
    _joint("j_arm", "revolute", "rotor_cap", "forearm", "0.2 0 0.05", "0 0 0.7", "0.36 0.48 0.8"),
    _link("forearm", 0.9, "0.15 0 0", I2),
    _joint("j_tool", "fixed", "forearm", "tool_tcp", "0.3 0 0", "0 0 0"),
    '<link name="tool_tcp"/>',
    _joint("j_slide", "prismatic", "trunk", "slider", "0.2 0 0.1", "0.5 0 0", "0 1 0"),
    _link("slider", 0.8, "0 0.05 0", I2),
    _joint("j_side", "prismatic", "slider", "carriage", "0 0.1 0", "0 0 0.2", "0.6 0 0.8"),
    _link("carriage", 0.5, "0.02 0 0.02", I2),
    _joint("j_wrist", "revolute", "carriage", "hand", "0 0 0.1", "0.3 0.2 0.1", "1 0 0"),
    _link("hand", 0.4, "0.05 0 0", I2),
    "</robot>", ""])

#: A revolute-continuous-prismatic chain (the same as test_urdf_and_reference's tiny URDF in kind).
CHAIN = "\n".join([
    '<?xml version="1.0"?>', '<robot name="chain">',
    _link("base", 3.0, "0 0 0", I2),
    _joint("j_a", "revolute", "base", "a", "0 0 0.1", "0.1 0.2 0.3", "0 0 1"),
    _link("a", 1.5, "0.1 0 0", I1),
    _joint("j_fix", "fixed", "a", "a_fixed", "0.3 0 0", "0 0 0.5"),
    _link("a_fixed", 0.5, "0.05 0.02 0", I2),
    _joint("j_b", "continuous", "a_fixed", "b", "0.1 0 0", "0.3 0 0", "1 0 0"),
    _link("b", 0.8, "0 0.1 0.02", I1),
    _joint("j_c", "prismatic", "b", "c", "0 0.2 0", "0 0.4 0", "0.6 0.8 0"),
    _link("c", 0.4, "0.02 0 0.03", I2),
    _joint("j_tool", "fixed", "c", "tool", "0.05 0 0.1", "0 0 0"),
    '<link name="tool"/>',
    "</robot>", ""])


def _write(tmp_path, text: str, name: str) -> str:
    path = tmp_path / f"{name}.urdf"
    path.write_text(text)
    return str(path)


@pytest.fixture(scope="module")
def panda_path() -> str:
    from cases.factories import panda_urdf_path

    return str(panda_urdf_path())


@pytest.fixture
def branched_path(tmp_path) -> str:
    return _write(tmp_path, BRANCHED, "branched")


@pytest.fixture
def chain_path(tmp_path) -> str:
    return _write(tmp_path, CHAIN, "chain")


def _rebuilt(model, bodies=None, source="same", constraints=None, name=None):
    """``model`` rebuilt with other bodies, source (None: from our data) or constraints."""
    return build_model(name or model.name, model.bodies if bodies is None else bodies, gravity=model.gravity,
                       input_map=model.input_map, task_points=model.task_points,
                       constraints=model.constraints if constraints is None else constraints,
                       source=model.source if source == "same" else source)


FIELDS = ("drift", "ctrl", "total", "task_drift", "joint_wrenches", "joint_wrenches_drift", "power_ctrl",
          "power_ctrl_per_coord", "kinetic_energy", "lam", "lam_drift", "constraint_value", "constraint_jacobian",
          "constraint_bias", "constraint_force", "power_constr_per_coord")


def _assert_same_split(a, b, rtol=1e-11):
    """Every field of two splits equal to rounding: each relative to its own size (accelerations to accel_scale);
    conditions within rtol times the condition itself."""
    accel = max(a.accel_scale, b.accel_scale)
    for name in FIELDS:
        x, y = getattr(a, name), getattr(b, name)
        if y is None:
            assert x is None, name
            continue
        x, y = np.asarray(x, float), np.asarray(y, float)
        scale = accel if name in ("drift", "ctrl", "total", "task_drift") else max(1.0, np.abs(y).max())
        assert np.abs(x - y).max() <= rtol * scale, (name, x, y)
    for name in ("cond_M", "accel_scale", "lam_scale"):
        assert getattr(a, name) == pytest.approx(getattr(b, name), rel=1e-9, abs=1e-300), name
    assert set(a.conditions) == set(b.conditions)
    for key, value in b.conditions.items():
        assert a.conditions[key] == pytest.approx(value, rel=max(1e-9, 1e-13 * value), abs=1e-12), key
    if np.all(np.isfinite(b.task_inertia)):
        Lambda = np.asarray(b.task_inertia)
        cond = b.conditions.get("task_inertia", 1.0)
        assert np.abs(a.task_inertia - Lambda).max() <= 1e-13 * cond * np.abs(Lambda).max()


def _file_and_data(model, count=4, seed=3):
    """(file-built split, data-built split) at ``count`` sampled states of ``model`` (which has a source)."""
    data = _rebuilt(model, source=None)
    assert model.source is not None and data.source is None and data.digest() == model.digest()
    for s in sample_states(model, count, seed, model.name):
        yield reference.split(model, s.q, s.qd, s.u), reference.split(data, s.q, s.qd, s.u)


# --------------------------------------------------------------------------------------------------- provenance


def test_loader_sets_the_source_outside_the_digest(chain_path):
    model = from_urdf(chain_path)
    assert model.source == ModelSource("urdf", chain_path)
    assert model.source.is_identity
    np.testing.assert_array_equal(model.source.rotation, np.eye(3))
    assert _rebuilt(model, source=None).digest() == model.digest()       # provenance, not physics
    assert build.joint_map(_rebuilt(model, source=None)) is None
    assert build.provenance(_rebuilt(model, source=None)) is None


def test_bad_source_is_a_model_error(chain_path):
    model = from_urdf(chain_path)
    with pytest.raises(ModelError) as info:
        _rebuilt(model, source=ModelSource("sdf", "", rotation=2 * np.eye(3)))
    msg = str(info.value)
    assert "source kind 'sdf'" in msg and "source path" in msg and "not a proper rotation" in msg


def test_move_scene_composes_the_source_placement(chain_path):
    model = from_urdf(chain_path)
    g1, g2 = frames.sampled(5, "chain", 2)
    once = frames.move_scene(model, g1)
    np.testing.assert_array_equal(once.source.rotation, g1.rotation)
    np.testing.assert_array_equal(once.source.translation, g1.translation)
    twice = frames.move_scene(once, g2)
    np.testing.assert_allclose(twice.source.rotation, g2.rotation @ g1.rotation, atol=1e-15)
    np.testing.assert_allclose(twice.source.translation, g2.rotation @ g1.translation + g2.translation, atol=1e-15)
    assert not twice.source.is_identity and twice.source.path == chain_path
    assert frames.move_scene(cases.load("double_pendulum"), g1).source is None
    assert "placed by the scene's rigid transform" in build.provenance(once)


def test_serialize_round_trips_the_source_and_reads_old_dicts(chain_path):
    model = frames.move_scene(from_urdf(chain_path), frames.sampled(1, "chain", 1)[0])
    d = json.loads(json.dumps(model_to_dict(model)))
    back = model_from_dict(d)
    assert back.source == model.source and back.digest() == model.digest()
    np.testing.assert_array_equal(back.source.rotation, model.source.rotation)
    old = {k: v for k, v in d.items() if k != "source"}                 # written before sources existed
    assert model_from_dict(old).source is None
    assert "source" not in model_to_dict(cases.load("four_bar"))      # a model built in code: as before
    with pytest.raises(SerializeError, match="source.path"):
        model_from_dict({**d, "source": {**d["source"], "path": 3}})
    with pytest.raises(SerializeError, match="source"):
        model_from_dict({**d, "source": [1, 2]})


# ------------------------------------------------------------------------------- file-built vs converted data


@pytest.mark.parametrize("which", ["panda", "branched", "chain"])
def test_file_built_reference_agrees_with_the_converted_one(which, panda_path, tmp_path):
    path = {"panda": panda_path, "branched": _write(tmp_path, BRANCHED, "branched"),
            "chain": _write(tmp_path, CHAIN, "chain")}[which]
    model = from_urdf(path)
    for a, b in _file_and_data(model):
        _assert_same_split(a, b)
    for frame in frames.sampled(11, which, 2):                         # moved scenes: g * the file's world
        moved = frames.move_scene(model, frame)
        for a, b in _file_and_data(moved, count=2):
            _assert_same_split(a, b)


def test_file_built_batch_agrees_with_split(branched_path):
    model = from_urdf(branched_path)
    states = sample_states(model, 5, 2, "branched")
    Q, QD, U = (np.array([getattr(s, x) for s in states]) for x in ("q", "qd", "u"))
    batch = reference.split_batch(model, Q, QD, U)
    for k, s in enumerate(states):
        one = reference.split(model, s.q, s.qd, s.u)
        for name in ("drift", "ctrl", "total"):
            assert np.abs(getattr(batch, name)[k] - getattr(one, name)).max() <= 1e-12 * one.accel_scale


def test_our_coordinate_order_is_mapped_by_name(branched_path):
    """The same bodies listed in another order: the map follows the names, so the answers permute with them."""
    model = from_urdf(branched_path)
    perm = [4, 0, 5, 2, 1, 3]
    listed = _rebuilt(model, bodies=[model.bodies[i] for i in perm], name="listed")
    assert [r.coordinate for r in build.joint_map(listed)] == list(range(6))
    assert [r.body for r in build.joint_map(listed)] == [model.bodies[i].name for i in perm]
    for s in sample_states(model, 3, 4, "branched"):
        q, qd, u = (np.array(x) for x in (s.q, s.qd, s.u))
        a, b = reference.split(model, q, qd, u), reference.split(listed, q[perm], qd[perm], u[perm])
        for name in ("drift", "ctrl", "total"):
            assert np.abs(getattr(a, name)[perm] - getattr(b, name)).max() <= 1e-12 * a.accel_scale


def _circle_and_coupling(model):
    """A point of 'forearm' on a circle through its position at q0 and a coupling of the two prismatic joints."""
    pm = build.to_pinocchio(model)                                  # joints named after our bodies
    data = pm.createData()
    pin.forwardKinematics(pm, data, np.full(model.n, 0.2))              # q0: every coordinate 0.2
    offset = np.array([0.1, 0.05, 0.0])
    p = data.oMi[pm.getJointId("forearm")].act(offset)
    center = p + np.array([0.3, -0.1, 0.0])
    circle = cases.PointOnCircle("ring", "forearm", offset, center, float(np.linalg.norm((p - center)[:2])))
    gear = cases.JointCoupling("gear", ("slider", "carriage"), (1.0, -2.0), 0.2 - 2.0 * 0.2)
    return [circle, gear]


def test_constraints_on_a_loaded_model_use_frames_of_the_file(branched_path):
    model = from_urdf(branched_path)
    constrained = _rebuilt(model, constraints=_circle_and_coupling(model), name="branched_constrained")
    moved = frames.move_scene(constrained, frames.sampled(2, "branched", 1)[0])  # the circle's centre moves by g
    for scene in (constrained, moved):
        for a, b in _file_and_data(scene, count=3):
            assert a.constraint_rank == b.constraint_rank == 2
            _assert_same_split(a, b, rtol=1e-10)


# ------------------------------------------------------------------------------------------------ the joint map


def test_joint_map_on_panda(panda_path):
    model = cases.load("panda")
    rows = build.joint_map(model)
    assert len(rows) == 9
    assert [r.coordinate for r in rows] == list(range(9))
    assert [r.body for r in rows] == PANDA_LINKS and [r.joint for r in rows] == PANDA_JOINTS
    assert [(r.idx_q, r.idx_v, r.nq, r.sign) for r in rows] == [(i, i, 1, 1) for i in range(9)]
    assert build.provenance(model) == f"built from the file {panda_path} (9 joints mapped by link name, sign +1)"


def test_joint_map_of_a_continuous_joint_is_cos_sin(branched_path):
    model = from_urdf(branched_path)
    np.testing.assert_allclose(model.bodies[model.body_index("rotor")].axis, [0.0, 0.6, 0.8], atol=1e-15)
    rows = {r.body: r for r in build.joint_map(model)}
    assert rows["rotor"].joint == "j_spin" and rows["rotor"].nq == 2 and rows["rotor"].sign == 1
    assert sum(r.nq for r in rows.values()) == 7 and sorted(r.idx_v for r in rows.values()) == list(range(6))
    q = np.linspace(-2.0, 4.0, 6)                                      # the rotor angle beyond pi maps too
    a = reference.split(model, q, np.ones(6), np.zeros(6))
    b = reference.split(_rebuilt(model, source=None), q, np.ones(6), np.zeros(6))
    _assert_same_split(a, b)


def _renamed(model, old: str, new: str):
    bodies = [dataclasses.replace(b, name=new if b.name == old else b.name,
                                  parent=new if b.parent == old else b.parent) for b in model.bodies]
    task_points = [dataclasses.replace(tp, body=new) if tp.body == old else tp for tp in model.task_points]
    return build_model(model.name, bodies, gravity=model.gravity, task_points=task_points, source=model.source)


def test_a_link_not_in_the_file_is_named(chain_path):
    model = _renamed(from_urdf(chain_path), "b", "b_renamed")
    with pytest.raises(ValueError) as info:
        reference.split(model, np.zeros(3), np.zeros(3), np.zeros(3))
    msg = str(info.value)
    assert "coordinate 1 (body 'b_renamed')" in msg and chain_path in msg and "no link 'b_renamed'" in msg


def test_a_welded_link_is_not_a_joint_coordinate(chain_path):
    model = _renamed(from_urdf(chain_path), "a", "a_fixed")
    with pytest.raises(ValueError, match="welded by the fixed joint 'j_fix'.*the link it moves directly"):
        build.joint_map(model)


def test_a_joint_without_a_coordinate_is_named(chain_path):
    model = from_urdf(chain_path)
    short = build_model("short", model.bodies[:2], gravity=model.gravity, source=model.source)
    with pytest.raises(ValueError, match=r"URDF joint\(s\) \['j_c'\] move no body"):
        build.joint_map(short)


def test_a_joint_with_more_than_one_velocity_is_named(chain_path, tmp_path):
    model = from_urdf(chain_path)
    planar = _write(tmp_path, CHAIN.replace('name="j_b" type="continuous"', 'name="j_b" type="planar"'), "planar")
    moved_to = _rebuilt(model, source=ModelSource("urdf", planar))
    with pytest.raises(ValueError, match="joint 'j_b' of .* is a JointModelPlanar with nq 4, nv 3") as info:
        build.joint_map(moved_to)
    assert planar in str(info.value) and "body 'b'" in str(info.value)


def test_a_missing_file_is_named(chain_path, tmp_path):
    gone = _rebuilt(from_urdf(chain_path), source=ModelSource("urdf", str(tmp_path / "gone.urdf")))
    with pytest.raises(ValueError, match="the reference cannot read .*gone.urdf"):
        reference.split(gone, np.zeros(3), np.zeros(3), np.zeros(3))


def test_harness_kinematics_use_our_data(chain_path, monkeypatch):
    """mass_matrix (tolerance scales) describes the problem the formalisms are given: our conversion."""
    monkeypatch.setattr(cases.urdf, "Body", _transposed)
    model = from_urdf(chain_path)
    q = np.array([0.3, -0.5, 0.1])
    M_data = reference.split(_rebuilt(model, source=None), q, np.zeros(3), np.zeros(3)).extras["M"]
    np.testing.assert_array_equal(kinematics.mass_matrix(model, q), M_data)
    assert np.abs(reference.split(model, q, np.zeros(3), np.zeros(3)).extras["M"] - M_data).max() > 1e-3


# ------------------------------------------------------------------------------------ injected conversion bugs


def _transposed(**kw):
    """Bug: the joint placement rotation transposed."""
    return Body(**{**kw, "rotation": np.array(kw["rotation"]).T})


def _about_joint_origin(**kw):
    """Bug: the inertia taken about the joint origin instead of the COM (parallel axis: + m (|c|^2 I - c c^T))."""
    c, m = np.array(kw["com"]), float(kw["mass"])
    return Body(**{**kw, "inertia": np.array(kw["inertia"]) + m * (c @ c * np.eye(3) - np.outer(c, c))})


def _axis_negated(**kw):
    """Bug: the joint axis of the second coordinate ('panda_link2', 'rotor', 'b') negated."""
    second = kw["name"] in ("panda_link2", "rotor", "b")
    return Body(**{**kw, "axis": -np.array(kw["axis"]) if second else kw["axis"]})


BUGS = {"rotation transposed": _transposed, "inertia about the joint origin": _about_joint_origin,
        "axis negated": _axis_negated}


def _converted_with(monkeypatch, bug, path: str, name: str | None = None):
    """The model from_urdf converts with ``bug`` in place of the loader's Body, after checking that the bug changes
    the converted model: its mass matrix (``mass_matrix`` reads our data), not only its digest."""
    clean = from_urdf(path, name=name)
    monkeypatch.setattr(cases.urdf, "Body", bug)
    model = from_urdf(path, name=name)
    monkeypatch.undo()
    assert model.digest() != clean.digest() and model.source == clean.source
    q = np.linspace(-1.0, 1.0, model.n)
    M, M_clean = (kinematics.mass_matrix(m, q) for m in (model, clean))
    assert np.abs(M - M_clean).max() > 1e-3 * np.abs(M_clean).max()
    return model


def _assert_reference_is_the_outlier(model, count: int):
    """At ``count`` sampled states the default backends DISAGREE, each disagreement points at the reference, and the
    hint says to suspect the conversion; returns the worst ratio seen."""
    backends = [get(n) for n in names()]
    worst = 0.0
    for s in sample_states(model, count, 0, model.name):
        outcome = evaluation.evaluate(model, s, backends)
        failing = [c for c in outcome.comparisons.values() if c.verdict == DISAGREE]
        assert failing, f"state {s.index}: the conversion bug was not caught"
        assert {suspect(c) for c in failing} == {"pinocchio"}, [(c.quantity, c.outlier) for c in failing]
        assert {"drift", "total", "kinetic_energy"} <= {c.quantity for c in failing}
        assert all(c.outlier == "pinocchio" for c in failing if c.quantity in ("drift", "ctrl", "total"))
        hint = diagnosis.hint(model, outcome, backends)
        assert hint.startswith("all formalisms agree against the reference built from the file "
                               f"{model.source.path}"), hint
        assert hint.endswith("suspect the model conversion (cases/urdf.py), not the formalisms"), hint
        worst = max(worst, max(c.worst_ratio for c in failing))
    return worst


@pytest.mark.parametrize("bug", list(BUGS))
def test_conversion_bug_makes_the_reference_the_outlier_on_panda(bug, panda_path, monkeypatch):
    model = _converted_with(monkeypatch, BUGS[bug], panda_path, name="panda")
    assert _assert_reference_is_the_outlier(model, 3) > 1e6


@pytest.mark.parametrize("bug", list(BUGS))
def test_conversion_bug_makes_the_reference_the_outlier_on_a_branched_urdf(bug, branched_path, monkeypatch):
    model = _converted_with(monkeypatch, BUGS[bug], branched_path)
    assert _assert_reference_is_the_outlier(model, 3) > 1e6


def test_gate_on_a_clean_loaded_urdf_passes_with_moved_scenes(branched_path):
    """The whole gate (charts, two moved scenes whose reference is built from the file, conservation) on the
    branched URDF: no disagreement, so the file-built reference is consistent with itself in every scene."""
    spec = specs.CaseSpec("branched", path=branched_path)
    result = run.run_gate([spec], [get(n) for n in names()], samples=4, seed=1)
    assert result.passed, [(s.index, s.errors, {k: c.worst_ratio for k, c in {**s.comparisons, **s.checks}.items()
                                                 if c.verdict == DISAGREE}) for s in result.cases[0].states]
    assert result.cases[0].model.source.path == branched_path
