"""Case factories and the ``cases`` API: geometry against the article, input maps, errors, parameter parsing.

Forward kinematics here is the test's own, written from the frame convention of ``cases.model``
(``X_body = X_parent * (rotation, translation) * motion(q)``), not taken from any backend.
"""

from __future__ import annotations

import subprocess
import sys

import numpy as np
import pytest

import cases
from cases import CaseError, Model

ALL = ["double_pendulum", "double_pendulum_tip_force", "double_pendulum_spring", "n_link_pendulum", "acrobot",
       "spatial_arm", "panda", "rotor", "inclined_slider", "spherical_pendulum", "double_pendulum_circle", "four_bar",
       "slider_crank", "cartesian_pendulum", "double_pendulum_absolute_loop", "double_pendulum_rail",
       "geared_pendulums", "free_body", "ball_pendulum", "ball_double_pendulum", "satellite_arm", "solo12",
       "solo12_standing", "knife_edge", "rolling_disk", "differential_drive", "urdf_gripper", "mjcf_floating",
       "mjcf_ball_slide", "mjcf_armature"]


def _rodrigues(axis, angle):
    k = np.asarray(axis, float)
    K = np.array([[0, -k[2], k[1]], [k[2], 0, -k[0]], [-k[1], k[0], 0]])
    return np.eye(3) + np.sin(angle) * K + (1 - np.cos(angle)) * K @ K


def _body_poses(model: Model, q):
    """World (R, p) of every body frame, from the model data alone."""
    poses = {}
    todo = list(range(model.n))
    while todo:  # parents-first without relying on model.topological_order
        for i in list(todo):
            b = model.bodies[i]
            if b.parent is not None and b.parent not in poses:
                continue
            Rp, pp = (np.eye(3), np.zeros(3)) if b.parent is None else poses[b.parent]
            Rj, pj = Rp @ b.rotation, pp + Rp @ b.translation
            if b.joint == "revolute":
                R, p = Rj @ _rodrigues(b.axis, q[i]), pj
            else:
                R, p = Rj, pj + Rj @ (q[i] * np.asarray(b.axis))
            poses[b.name] = (R, p)
            todo.remove(i)
    return poses


def _point(model, q, body, offset):
    R, p = _body_poses(model, q)[body]
    return p + R @ np.asarray(offset)


# ------------------------------------------------------------------------------------------------ registry


def test_names_and_catalog():
    assert cases.names() == ALL
    cat = {c.name: c for c in cases.catalog()}
    assert list(cat) == ALL
    assert cat["double_pendulum"].parameters == {"m1": 1.0, "m2": 1.0, "l1": 1.0, "l2": 1.0, "g": 9.81, "I1": 0.0,
                                                 "I2": 0.0, "a1": 0.0, "a2": 0.0}
    assert cat["n_link_pendulum"].parameters == {"n": 5, "m": 1.0, "l": 1.0, "g": 9.81, "a": 0.0}
    assert set(cat["acrobot"].parameters) == {"m1", "m2", "l1", "l2", "lc1", "lc2", "I1", "I2", "g", "a1", "a2"}
    assert cat["spatial_arm"].parameters == {} and cat["panda"].parameters == {}
    for c in cat.values():
        assert c.summary and "\n" not in c.summary


@pytest.mark.parametrize("name", ALL)
def test_every_case_builds(name):
    m = cases.load(name)
    assert isinstance(m, Model) and m.n >= 1 and m.task_points
    assert m.input_map.shape[0] == m.n


def test_unknown_case_lists_valid_names():
    with pytest.raises(CaseError) as info:
        cases.load("tripple_pendulum")
    msg = str(info.value)
    assert "tripple_pendulum" in msg
    for name in ALL:
        assert name in msg
    assert isinstance(info.value, ValueError)


def test_unknown_parameter_lists_valid_parameters_with_defaults():
    with pytest.raises(CaseError) as info:
        cases.load("double_pendulum", m3=2.0)
    msg = str(info.value)
    assert "'m3'" in msg
    for text in ("m1=1.0", "m2=1.0", "l1=1.0", "l2=1.0", "g=9.81"):
        assert text in msg
    with pytest.raises(CaseError, match="no parameters"):
        cases.load("spatial_arm", n=3)


def test_string_parameters_convert_by_the_default_type():
    m = cases.load("n_link_pendulum", n="3", l="0.5", m="2")
    assert m.n == 3
    assert all(b.mass == 2.0 for b in m.bodies)
    assert m.bodies[-1].translation[1] == -0.5
    assert cases.load("n_link_pendulum", n=" 4 ").n == 4
    assert cases.load("n_link_pendulum", n="2.0").n == 2
    assert cases.load("double_pendulum", g="1e1").gravity[1] == -10.0
    with pytest.raises(CaseError, match="n='three'.*int"):
        cases.load("n_link_pendulum", n="three")
    with pytest.raises(CaseError, match="not a valid int"):
        cases.load("n_link_pendulum", n="2.5")
    with pytest.raises(CaseError, match="n=2.5 is not a valid int"):
        cases.load("n_link_pendulum", n=2.5)
    with pytest.raises(CaseError, match="n=True is not a valid int"):
        cases.load("n_link_pendulum", n=True)
    with pytest.raises(CaseError, match="l1='long'.*float"):
        cases.load("double_pendulum", l1="long")


def test_n_link_pendulum_takes_from_one_link_to_its_limit():
    from cases.factories import MAX_LINKS

    for n in (0, MAX_LINKS + 1):
        with pytest.raises(CaseError, match=f"must be from 1 to {MAX_LINKS}, got {n}"):
            cases.load("n_link_pendulum", n=n)
    assert cases.load("n_link_pendulum", n=1).n == 1


def test_importing_cases_does_not_import_pinocchio():
    code = "import sys, cases; cases.load('double_pendulum'); print('pinocchio' in sys.modules)"
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True)
    assert out.stdout.strip() == "False"


# ------------------------------------------------------------------------------------------------ geometry


def test_double_pendulum_matches_article_section_3():
    m1, m2, l1, l2, g = 1.3, 0.7, 0.9, 1.4, 9.7
    model = cases.load("double_pendulum", m1=m1, m2=m2, l1=l1, l2=l2, g=g)
    assert [b.mass for b in model.bodies] == [m1, m2]
    assert all(not b.inertia.any() for b in model.bodies)  # point masses
    np.testing.assert_array_equal(model.gravity, [0.0, -g, 0.0])
    np.testing.assert_array_equal(model.input_map, np.eye(2))
    rng = np.random.default_rng(1)
    for _ in range(20):
        t1, t2 = rng.uniform(-np.pi, np.pi, 2)
        q = np.array([t1, t2])
        # article: mass 1 at (l1 sin t1, -l1 cos t1); mass 2 at eq. (4)
        x1, y1 = l1 * np.sin(t1), -l1 * np.cos(t1)
        x2 = l1 * np.sin(t1) + l2 * np.sin(t1 + t2)
        y2 = -l1 * np.cos(t1) - l2 * np.cos(t1 + t2)
        b1, b2 = model.bodies
        np.testing.assert_allclose(_point(model, q, "link1", b1.com), [x1, y1, 0.0], atol=1e-12)
        np.testing.assert_allclose(_point(model, q, "link2", b2.com), [x2, y2, 0.0], atol=1e-12)
        tip = model.task_point()
        assert tip.name == "tip"
        np.testing.assert_allclose(_point(model, q, tip.body, tip.offset), [x2, y2, 0.0], atol=1e-12)


def test_n_link_pendulum_chain_geometry():
    n, length = 4, 0.6
    model = cases.load("n_link_pendulum", n=n, l=length)
    q = np.array([0.3, -0.7, 1.1, 0.25])
    phi = np.cumsum(q)
    expected = [length * np.sum(np.sin(phi)), -length * np.sum(np.cos(phi)), 0.0]
    tip = model.task_point()
    np.testing.assert_allclose(_point(model, q, tip.body, tip.offset), expected, atol=1e-12)
    np.testing.assert_allclose(_point(model, q, "link2", model.bodies[1].com),
                               [length * (np.sin(phi[0]) + np.sin(phi[1])),
                                -length * (np.cos(phi[0]) + np.cos(phi[1])), 0.0], atol=1e-12)


def test_acrobot_input_map_and_inertia():
    model = cases.load("acrobot", I1=0.1, I2=0.4, lc2=0.8)
    np.testing.assert_array_equal(model.input_map, [[0.0], [1.0]])
    assert model.m == 1
    assert model.bodies[0].inertia[2, 2] == 0.1 and model.bodies[1].inertia[2, 2] == 0.4
    q = np.array([0.4, -1.0])
    # COM of link 2 at lc2 along the link, link 2 starting at the end of link 1 (l1 = 1)
    expected = [np.sin(0.4) + 0.8 * np.sin(-0.6), -np.cos(0.4) - 0.8 * np.cos(-0.6), 0.0]
    np.testing.assert_allclose(_point(model, q, "link2", model.bodies[1].com), expected, atol=1e-12)
    tip = model.task_point()
    np.testing.assert_allclose(_point(model, q, tip.body, tip.offset),
                               [np.sin(0.4) + 2 * np.sin(-0.6), -np.cos(0.4) - 2 * np.cos(-0.6), 0.0], atol=1e-12)


def test_spatial_arm_is_genuinely_three_dimensional():
    model = cases.load("spatial_arm")
    assert model.n == 6
    assert [b.joint for b in model.bodies].count("prismatic") == 1
    np.testing.assert_array_equal(model.gravity, [0.0, 0.0, -9.81])
    coordinate_axes = [np.eye(3)[k] for k in range(3)]
    assert any(not any(np.allclose(abs(b.axis), e) for e in coordinate_axes) for b in model.bodies)
    assert sum(not np.allclose(b.rotation, np.eye(3)) for b in model.bodies) >= 4
    for b in model.bodies:
        assert 0.5 <= b.mass <= 5.0
        off = b.inertia - np.diag(np.diag(b.inertia))
        assert np.abs(off).max() > 1e-5, f"{b.name}: inertia has no off-diagonal terms"
        assert np.linalg.norm(b.com) > 0.0
        assert np.linalg.norm(b.translation) <= 0.5
    tip = model.task_point()
    assert tip.body == model.bodies[-1].name and np.linalg.norm(tip.offset) > 0.05
    # joint axes in the world at q = 0 (and at another pose) are pairwise non-parallel
    for q in (np.zeros(6), np.array([0.3, -0.5, 0.8, 0.1, -1.2, 0.4])):
        poses = _body_poses(model, q)
        axes = [poses[b.name][0] @ b.axis for b in model.bodies]
        for i in range(6):
            for j in range(i + 1, 6):
                assert np.linalg.norm(np.cross(axes[i], axes[j])) > 0.1, (i, j)


def test_panda_case():
    model = cases.load("panda")
    assert model.name == "panda" and model.n == 9
    assert model.task_point().name == "panda_hand_tcp"
