"""The public strategies and assertions (crosscheck.testing) and exact model serialization (cases.serialize)."""

from __future__ import annotations

import json

import numpy as np
import pytest
from hypothesis import Phase, find, given, settings
from hypothesis import strategies as st

import cases
import formalisms
from cases.serialize import SerializeError, model_from_dict, model_to_dict
from crosscheck.checks import charts, frames
from crosscheck import cli, testing
from crosscheck.references.pinocchio import kinematics
from crosscheck.references.pinocchio import reference
from crosscheck.core import sampling
from crosscheck.core.sampling import State

NEWTON_EULER = formalisms.get("newton_euler")
QUIET = settings(max_examples=15, database=None, deadline=None)


def round_trip(model):
    return model_from_dict(json.loads(json.dumps(model_to_dict(model))))


def gear_model():
    """A three-link pendulum with its first joints geared 2:1 and its tip on a vertical line: the two declarations
    no built-in case uses (JointCoupling, PointOnLine), and a point of the last link with no vertical velocity (the
    Pfaffian PointVelocity, which no built-in case uses either)."""
    base = cases.load("n_link_pendulum", n=3)
    return cases.build_model("geared", base.bodies, gravity=base.gravity, task_points=base.task_points,
                             constraints=[cases.JointCoupling("gear", ("link1", "link2"), (2.0, -1.0), 0.25),
                                          cases.PointOnLine("slot", "link3", [0.0, -1.0, 0.0], [0.3, 0.0, 0.0],
                                                            [[1.0, 0.0, 0.0]]),
                                          cases.constraints.PointVelocity("brake", "link3", [0.0, -0.5, 0.0],
                                                                          [[0.0, 1.0, 0.0]])])


@pytest.mark.parametrize("name", cases.names())
def test_built_in_cases_round_trip_exactly(name):
    model = cases.load(name)
    assert round_trip(model).digest() == model.digest()


def test_every_constraint_type_round_trips():
    models = [cases.load(name) for name in cases.names()] + [gear_model()]
    kinds = {type(c).__name__ for m in models for c in m.constraints}
    assert kinds == {cls.__name__ for cls in cases.constraints.CONSTRAINT_TYPES}
    for model in models:
        back = round_trip(model)
        assert back.digest() == model.digest()
        assert [type(c) for c in back.constraints] == [type(c) for c in model.constraints]


@QUIET
@given(st.data())
def test_drawn_models_round_trip_with_the_same_split(data):
    model = data.draw(testing.models(max_bodies=4, constraints=None))
    back = round_trip(model)
    assert back.digest() == model.digest()
    state = data.draw(testing.states(model))
    a, b = (NEWTON_EULER.split(m, state.q, state.qd, state.u) for m in (model, back))
    for name in ("drift", "ctrl", "total", "lam"):
        assert np.array_equal(getattr(a, name), getattr(b, name)), name


@pytest.mark.parametrize("mutate, field", [
    (lambda d: d["bodies"][1].pop("mass"), "'bodies[1].mass' is missing"),
    (lambda d: d["bodies"][0].__setitem__("com", "up"), "'bodies[0].com' must be numbers"),
    (lambda d: d["bodies"][0].__setitem__("parent", 3), "'bodies[0].parent' must be a string or null"),
    (lambda d: d["constraints"][0].__setitem__("type", "Weld"), "'constraints[0].type' is 'Weld'"),
    (lambda d: d["constraints"][0].__setitem__("joints", ["link1", 2]), "'constraints[0].joints[1]'"),
    (lambda d: d.__setitem__("bodies", {}), "'bodies' must be a list"),
    (lambda d: d.__setitem__("format", "urdf"), "field 'format'"),
])
def test_a_bad_dict_names_the_field(mutate, field):
    d = json.loads(json.dumps(model_to_dict(gear_model())))
    mutate(d)
    with pytest.raises(SerializeError, match=field.replace("[", r"\[").replace("]", r"\]")):
        model_from_dict(d)


def test_a_bad_value_is_reported_by_model_validation():
    d = model_to_dict(gear_model())
    d["bodies"][0]["mass"] = -1.0
    with pytest.raises(cases.ModelError, match="negative mass"):
        model_from_dict(d)


@QUIET
@given(st.data())
def test_drawn_models_are_valid_trees_with_a_positive_definite_mass_matrix(data):
    model = data.draw(testing.models(max_bodies=5, constraints=None))
    assert 1 <= model.n <= 5 and model.k < model.n
    assert all(p < i for i, p in enumerate(model.parent_index))           # parents among earlier bodies
    assert np.all(np.abs(model.input_map) <= 2.0) and 1 <= model.m <= model.n
    state = data.draw(testing.states(model))
    M = reference.split(model, state.q, state.qd, state.u).extras["M"]
    assert np.linalg.eigvalsh(M)[0] > 0.0


@QUIET
@given(st.data())
def test_constrained_drawn_states_are_admissible(data):
    model = data.draw(testing.models(max_bodies=4, constraints=True))
    assert 1 <= model.k < model.n
    state = data.draw(testing.states(model))
    phi, Jc, _ = kinematics.constraint_kinematics(model, state.q, state.qd)
    scale = model.length_scale ** 2
    assert np.abs(phi).max() <= sampling.PHI_TOL * scale
    assert np.abs(Jc @ np.array(state.qd)).max() <= cli.eval.ADMISSIBLE * scale * (1.0 + np.abs(state.qd).sum())


def test_constraints_of_every_type_are_drawn():
    """Every declaration type (and a point pinned to the world) is among the drawn models: searched for, type by type,
    rather than counted in a fixed sample, whose make-up moves with Hypothesis's seed."""
    models = testing.models(max_bodies=3, constraints=True, pfaffian=True)
    search = settings(max_examples=500, database=None, deadline=None, phases=[Phase.generate])
    for cls in cases.constraints.CONSTRAINT_TYPES:
        find(models, lambda m, cls=cls: any(isinstance(c, cls) for c in m.constraints), settings=search)
    find(models, lambda m: any(isinstance(c, cases.PointsCoincide) and c.body_b is None for c in m.constraints),
         settings=search)


def test_the_pieces_shrink_to_round_values():
    quick = settings(database=None, max_examples=20)
    assert np.array_equal(find(testing.axes(), lambda a: True, settings=quick), [0.0, 0.0, 1.0])
    assert np.array_equal(find(testing.rotations(), lambda R: True, settings=quick), np.eye(3))
    assert np.array_equal(find(testing.vectors(1.0), lambda v: True, settings=quick), np.zeros(3))
    turned = find(testing.rotations(), lambda R: not np.array_equal(R, np.eye(3)), settings=quick)
    assert set(np.unique(turned)) <= {-1.0, 0.0, 1.0}                       # a quarter turn, exact entries
    assert np.array_equal(find(testing.vectors(1.0), lambda v: v[0] > 0.3, settings=quick), [1.0, 0.0, 0.0])


@QUIET
@given(st.data())
def test_drawn_charts_and_frames_are_valid(data):
    model = data.draw(testing.models(max_bodies=3))
    chart = data.draw(testing.charts(model))
    assert chart.name in charts.names() and (chart.name != "absolute" or charts.is_planar_serial(model))
    q = np.array(data.draw(testing.states(model)).q)
    assert np.allclose(chart.q_of(chart.p_of(q)), q, atol=1e-12)
    frame = data.draw(testing.frames())
    R = frame.rotation
    assert np.allclose(R.T @ R, np.eye(3), atol=1e-12) and np.linalg.det(R) > 0
    assert np.all(np.abs(frame.translation) <= 1.0)


PENDULUM = cases.load("double_pendulum")
MOVING = State(0, (0.3, -0.7), (1.5, -2.0), (2.0, -1.0))


def test_assert_backends_agree_passes_on_the_correct_backends():
    outcome = testing.assert_backends_agree(PENDULUM, MOVING, chart=charts.get("absolute", PENDULUM),
                                            frame=frames.sampled(0, "double_pendulum", 1)[0])
    assert not outcome.failed and outcome.comparisons
    assert {key.split(":")[0] for key in outcome.checks} >= {"chart absolute", "frame", "conservation"}


def test_assert_backends_agree_names_a_faulty_backend(dropped_coriolis):
    with pytest.raises(AssertionError) as caught:
        testing.assert_backends_agree(PENDULUM, MOVING, backends=["euler_lagrange", "newton_euler", "pinocchio"])
    message = str(caught.value)
    assert "drift: DISAGREE" in message and "outlier euler_lagrange" in message
    assert "    euler_lagrange: [" in message and "    pinocchio: [" in message


def test_assert_split_close_passes_and_fails_with_the_tolerance_policy(dropped_coriolis):
    q, qd, u = MOVING.q, MOVING.qd, MOVING.u
    ne, pin_split = NEWTON_EULER.split(PENDULUM, q, qd, u), reference.split(PENDULUM, q, qd, u)
    testing.assert_split_close(ne, pin_split, PENDULUM, q, qd, names=("newton_euler", "pinocchio"))
    broken = formalisms.get("euler_lagrange").split(PENDULUM, q, qd, u)
    with pytest.raises(AssertionError, match=r"drift: DISAGREE, error/tolerance \d"):
        testing.assert_split_close(broken, ne, PENDULUM, q, qd, names=("euler_lagrange", "newton_euler"))
