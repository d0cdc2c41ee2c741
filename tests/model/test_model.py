"""The model language: validation reports every problem at once; models are immutable; the digest is stable."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from cases import Body, ModelError, TaskPoint, build_model
from crosscheck.references.pinocchio import kinematics

Z = (0.0, 0.0, 1.0)


def _good_bodies():
    return [
        Body("a", None, "revolute", Z, 1.0, com=(0.0, -0.5, 0.0), inertia=np.diag([0.1, 0.02, 0.1])),
        Body("b", "a", "prismatic", (1.0, 0.0, 0.0), 2.0, com=(0.1, 0.0, 0.0), translation=(0.0, -1.0, 0.0)),
    ]


def test_valid_model_builds_with_defaults():
    m = build_model("ok", _good_bodies())
    assert m.n == 2 and m.m == 2
    np.testing.assert_array_equal(m.input_map, np.eye(2))
    assert m.parent_index == (-1, 0)
    assert m.topological_order == (0, 1)
    assert m.task_point().name == "tip" and m.task_point().body == "b"


def test_every_problem_is_reported_in_one_error():
    nan = float("nan")
    bodies = [
        Body("neg_mass", None, "revolute", Z, -1.0),
        Body("unsym", None, "revolute", Z, 1.0, inertia=[[1.0, 0.3, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, 1.0]]),
        Body("not_psd", None, "revolute", Z, 1.0, inertia=np.diag([1.0, 1.0, -0.5])),
        Body("zero_axis", None, "revolute", (0.0, 0.0, 0.0), 1.0),
        Body("long_axis", None, "prismatic", (0.0, 0.0, 2.0), 1.0),
        Body("orphan", "nobody", "revolute", Z, 1.0),
        Body("cyc1", "cyc2", "revolute", Z, 1.0),
        Body("cyc2", "cyc1", "revolute", Z, 1.0),
        Body("bad_shape", None, "revolute", Z, 1.0, com=(1.0, 2.0)),
        Body("has_nan", None, "revolute", Z, 1.0, translation=(0.0, nan, 0.0)),
        Body("bad_joint", None, "helical", Z, 1.0),
        Body("bad_rot", None, "revolute", Z, 1.0, rotation=np.diag([1.0, 1.0, -1.0])),
    ]
    with pytest.raises(ModelError) as info:
        build_model("broken", bodies, gravity=(0.0, -9.81), input_map=np.ones((3, 1)),
                    task_points=[TaskPoint("p", "ghost", (0.0, 0.0, 0.0))])
    err = info.value
    text = str(err)
    expected = {
        "neg_mass": "negative mass",
        "unsym": "not symmetric",
        "not_psd": "not positive semi-definite",
        "zero_axis": "zero joint axis",
        "long_axis": "has norm 2",
        "orphan": "unknown parent 'nobody'",
        "bad_shape": "shape (2,)",
        "has_nan": "non-finite",
        "bad_joint": "'helical'",
        "bad_rot": "not a proper rotation",
    }
    for body, phrase in expected.items():
        hits = [p for p in err.problems if f"'{body}'" in p and phrase in p]
        assert hits, f"problem of body {body!r} ({phrase!r}) missing from:\n{text}"
    assert any("cycle" in p and "cyc1" in p and "cyc2" in p for p in err.problems), text
    assert any(p.startswith("gravity") and "shape (2,)" in p for p in err.problems), text
    assert any("input map" in p and "(3, 1)" in p for p in err.problems), text
    assert any("task point 'p'" in p and "ghost" in p for p in err.problems), text
    # one line per problem in the message, and the count in the header
    assert f"({len(err.problems)} problem(s))" in text
    assert len(err.problems) >= len(expected) + 4
    for p in err.problems:
        assert p in text


def test_duplicate_names_and_empty_model_are_rejected():
    with pytest.raises(ModelError, match="more than once"):
        build_model("dup", [Body("a", None, "revolute", Z, 1.0), Body("a", None, "revolute", Z, 1.0)])
    with pytest.raises(ModelError, match="at least one body"):
        build_model("empty", [])


def test_model_is_immutable():
    m = build_model("ok", _good_bodies())
    arrays = [m.gravity, m.input_map]
    for b in m.bodies:
        arrays += [b.axis, b.com, b.inertia, b.rotation, b.translation]
    for tp in m.task_points:
        arrays.append(tp.offset)
    for arr in arrays:
        assert not arr.flags.writeable
        with pytest.raises(ValueError):
            arr[...] = 0.0
    with pytest.raises(dataclasses.FrozenInstanceError):
        m.name = "other"  # type: ignore[misc]
    with pytest.raises(dataclasses.FrozenInstanceError):
        m.bodies[0].mass = 5.0  # type: ignore[misc]
    assert isinstance(m.bodies, tuple) and isinstance(m.task_points, tuple)


def test_model_does_not_alias_caller_arrays():
    inertia = np.diag([0.1, 0.02, 0.1])
    gravity = np.array([0.0, -9.81, 0.0])
    m = build_model("ok", [Body("a", None, "revolute", Z, 1.0, inertia=inertia)], gravity=gravity)
    digest = m.digest()
    inertia[0, 0] = 7.0
    gravity[1] = 0.0
    assert m.bodies[0].inertia[0, 0] == 0.1 and m.gravity[1] == -9.81
    assert m.digest() == digest


def test_digest_is_stable_and_tracks_the_physics():
    d1 = build_model("ok", _good_bodies()).digest()
    d2 = build_model("ok", _good_bodies()).digest()
    assert d1 == d2 and len(d1) == 64
    heavier = _good_bodies()
    heavier[1] = dataclasses.replace(heavier[1], mass=2.0 + 1e-9)
    assert build_model("ok", heavier).digest() != d1
    moved = _good_bodies()
    moved[0] = dataclasses.replace(moved[0], com=(0.0, -0.5, 1e-12))
    assert build_model("ok", moved).digest() != d1
    assert build_model("ok", _good_bodies(), gravity=(0.0, 0.0, -9.8)).digest() != d1
    assert build_model("ok", _good_bodies(), input_map=[[1.0], [0.0]]).digest() != d1


def test_task_directions_default_to_all_three_and_are_validated():
    m = build_model("ok", _good_bodies(), task_points=[TaskPoint("tip", "b", (0.1, 0.0, 0.0))])
    np.testing.assert_array_equal(m.task_point().directions, np.eye(3))
    # left out, the default task point gets the directions it moves in: this chain moves in the x-y plane (a z axis
    # and a prismatic joint along the x axis of the rotating body), so a third row would be singular everywhere
    default = build_model("ok", _good_bodies()).task_point()
    np.testing.assert_array_equal(default.directions, [[1.0, 0.0, 0.0], [0.0, 1.0, 0.0]])
    planar = build_model("ok", _good_bodies(),
                         task_points=[TaskPoint("tip", "b", (0.0, 0.0, 0.0), ((1.0, 0.0, 0.0), (0.0, 1.0, 0.0)))])
    assert planar.task_point().directions.shape == (2, 3)
    assert planar.digest() != build_model("ok", _good_bodies(),
                                          task_points=[TaskPoint("tip", "b", (0.0, 0.0, 0.0))]).digest()
    with pytest.raises(ModelError) as info:
        build_model("bad", _good_bodies(), task_points=[
            TaskPoint("skew", "b", (0.0, 0.0, 0.0), ((1.0, 0.0, 0.0), (1.0, 1.0, 0.0))),
            TaskPoint("flat", "b", (0.0, 0.0, 0.0), (1.0, 0.0, 0.0)),
            TaskPoint("many", "b", (0.0, 0.0, 0.0), np.eye(4)[:, :3])])
    text = str(info.value)
    assert "task point 'skew' directions are not orthonormal rows" in text
    assert "task point 'flat' directions have shape (3,)" in text
    assert "task point 'many' directions have shape (4, 3)" in text
    with pytest.raises(ModelError, match="a model needs at least one task point"):
        build_model("none", _good_bodies(), task_points=[])


def test_a_unit_axis_is_kept_bit_for_bit_so_rebuilding_a_model_keeps_its_digest():
    """Dividing a unit vector by its computed norm can move its last bit; rebuilding a model from its own (already
    normalized) axes must not change it, or a saved model would come back with another digest."""
    rng = np.random.default_rng(0)
    for _ in range(300):
        axis = rng.normal(size=3)
        axis /= np.linalg.norm(axis)
        model = build_model("one", [Body("b", None, "revolute", axis, 1.0, com=(0.1, 0, 0))])
        again = build_model("one", list(model.bodies))
        assert np.array_equal(again.bodies[0].axis, model.bodies[0].axis) and again.digest() == model.digest()
    scaled = build_model("one", [Body("b", None, "revolute", (0, 0, 1 + 1e-9), 1.0, com=(0.1, 0, 0))])
    assert np.array_equal(scaled.bodies[0].axis, [0.0, 0.0, 1.0])       # a nearly-unit axis is still normalized


def test_an_impossible_inertia_is_a_finding_and_rounding_is_not():
    """A principal moment above the sum of the others is a finding (the model still builds: M stays positive
    definite); residues at the rounding of the body's inertia about its joint frame are neither (iCub's -2^-64 on a
    0.526 kg body 3 cm from its joint)."""
    triangle = build_model("t", [Body("a", None, "revolute", Z, 1.0, inertia=np.diag([1.0, 1.0, 3.0]))])
    assert len(triangle.findings) == 1 and "triangle inequality" in triangle.findings[0]
    assert "'a'" in triangle.findings[0]
    residue = np.diag([-2.0 ** -64, -2.0 ** -64, 0.0])
    icub = build_model("i", [Body("hip", None, "revolute", (1.0, 0.0, 0.0), 0.526, com=(0.0, 0.0, 0.03045),
                                  inertia=residue)])
    assert icub.findings == ()
    assert np.linalg.eigvalsh(kinematics.mass_matrix(icub, [0.4]))[0] > 0.0   # the reference builds it as given
    with pytest.raises(ModelError, match="not positive semi-definite"):    # the same residue without the lever
        build_model("p", [Body("hip", None, "revolute", Z, 0.526, com=(0.0, 0.0, 0.0), inertia=residue)])
    assert build_model("ok", _good_bodies()).findings == ()
