"""External loads (issue 21 item 1; article 2.3, eq. 12-14): the declarations, their validation, digest, serialization
and the moved scene."""

import json

import numpy as np
import pytest

import cases
from cases import loads as load_decl
from cases.model import ModelError, build_model
from cases.serialize import model_from_dict, model_to_dict
from crosscheck import frames


def _pendulum(loads):
    base = cases.load("double_pendulum")
    return build_model("loaded", base.bodies, base.gravity, base.input_map, base.task_points, loads=loads)


LOADS = [cases.ExternalForce("push", "link2", (1.0, 0.0, 0.0), (0.5, -2.0, 0.0)),
         cases.ExternalWrench("wind", "link1", (0.3, 0.1, 0.0), (1.0, 0.5, 0.0), (0.0, 0.0, 0.7), "body"),
         cases.PointSpring("spring", "link2", (0.5, 0.0, 0.0), (1.0, -1.0, 0.0), 12.0, 0.4)]


def test_a_model_without_loads_keeps_its_digest_and_its_dict():
    plain = cases.load("double_pendulum")
    assert plain.loads == ()
    assert _pendulum(()).digest() == plain.digest()
    assert "loads" not in model_to_dict(plain)


def test_loads_are_in_the_digest_and_survive_serialization_bit_for_bit():
    model = _pendulum(LOADS)
    assert model.digest() != cases.load("double_pendulum").digest()
    again = model_from_dict(json.loads(json.dumps(model_to_dict(model))))
    assert again.digest() == model.digest()
    assert [type(x).__name__ for x in again.loads] == ["ExternalForce", "ExternalWrench", "PointSpring"]
    assert again.loads[1].frame == "body" and again.loads[2].rest_length == 0.4
    tweaked = _pendulum(LOADS[:2] + [cases.PointSpring("spring", "link2", (0.5, 0.0, 0.0), (1.0, -1.0, 0.0),
                                                       12.0 * (1 + 2e-16), 0.4)])
    assert tweaked.digest() != model.digest()


@pytest.mark.parametrize("load, words", [
    (cases.ExternalForce("f", "link9", (0, 0, 0), (1, 0, 0)), "unknown body 'link9'"),
    (cases.ExternalForce("f", "link1", (0, 0, 0), (np.nan, 0, 0)), "non-finite"),
    (cases.ExternalForce("f", "link1", (0, 0, 0), (1, 0, 0), "tool"), "frame 'tool'; valid frames"),
    (cases.ExternalWrench("w", "link1", (0, 0, 0), (1, 0, 0), (0, 0)), "moment has shape (2,)"),
    (cases.PointSpring("s", "link1", (0, 0, 0), (0, 0, 0), -3.0), "negative stiffness"),
    (cases.PointSpring("s", "link1", (0, 0, 0), (0, 0, 0), 3.0, -0.1), "negative rest length"),
    ("a force", "is not a load declaration"),
])
def test_bad_loads_are_refused_with_the_reason(load, words):
    with pytest.raises(ModelError) as err:
        _pendulum([load])
    assert words in str(err.value)


def test_repeated_load_names_are_refused():
    with pytest.raises(ModelError, match="load names repeat"):
        _pendulum([LOADS[0], LOADS[0]])


def test_the_moved_scene_moves_world_loads_and_keeps_body_loads():
    frame = frames.Frame("g", frames.random_rotation(np.random.default_rng(3)), np.array([0.2, -0.4, 0.9]))
    moved = frames.move_scene(_pendulum(LOADS), frame).loads
    R, t = frame.rotation, frame.translation
    np.testing.assert_array_equal(moved[0].force, R @ LOADS[0].force)
    np.testing.assert_array_equal(moved[0].offset, LOADS[0].offset)
    assert load_decl.digest_bytes(moved[1]) == load_decl.digest_bytes(_pendulum(LOADS).loads[1])   # body frame
    np.testing.assert_allclose(moved[2].anchor, R @ np.array(LOADS[2].anchor) + t, rtol=0, atol=1e-15)


def test_the_spring_potential():
    spring = LOADS[2]
    assert spring.potential(1.4) == pytest.approx(0.5 * 12.0 * 1.0**2)
    assert spring.potential(0.4) == 0.0
