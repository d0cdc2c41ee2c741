"""The plugin contract beyond drift, ctrl and total: the drift's parts (``zvcf``, ``drift_velocity``) and the
external loads' force given through ``crosscheck.assemble`` and compared like the built-in backends' (a wrong part
caught and the plugin named), and the file's joint names and root link in a ``SourceScene``."""

from __future__ import annotations

import xml.etree.ElementTree as ET
from pathlib import Path

import numpy as np
import pytest

import cases
from crosscheck import backends
from crosscheck.assemble import Sizes, unconstrained_split
from crosscheck.checks import frames
from crosscheck.core.compare import AGREE, DISAGREE, suspect
from crosscheck.engine.run import run_gate
from crosscheck.engine.specs import CaseSpec, Checks
from crosscheck.needs import source_scene

ROOT = Path(__file__).resolve().parents[2]
ARM = str(ROOT / "examples" / "arm.urdf")


class Parts:
    """M, C qd and g of the scene's Pinocchio model, the drift and its parts each solved on its own; ``wrong``: the
    velocity part taken as the whole drift (gravity counted in it twice over the parts)."""

    needs = "pinocchio"

    def __init__(self, name: str, wrong: bool = False):
        self.name, self.wrong = name, wrong

    def split(self, scene, q, qd, u):
        import pinocchio as pin

        pm, data = scene.model, scene.data
        qp, vp = scene.configuration(q), scene.velocity(qd)
        M_p = np.array(pin.crba(pm, data, qp))
        M = scene.ours_matrix(np.triu(M_p) + np.triu(M_p, 1).T)
        g = scene.ours(pin.computeGeneralizedGravity(pm, data, qp))
        Cqd = scene.ours(pin.nonLinearEffects(pm, data, qp, vp)) - g
        qd, tau = np.asarray(qd, dtype=float), scene.input_map @ np.asarray(u, dtype=float)
        drift, ctrl = np.linalg.solve(M, -(Cqd + g)), np.linalg.solve(M, tau)
        velocity = drift if self.wrong else np.linalg.solve(M, -Cqd)
        sizes = Sizes(float(sum(i.mass for i in pm.inertias)), np.array(pm.gravity.linear))
        return unconstrained_split(sizes, M=M, Cqd=Cqd, g=g, tau_ctrl=tau, qd=qd, drift=drift, ctrl=ctrl,
                                   total=drift + ctrl, zvcf=np.linalg.solve(M, -g), drift_velocity=velocity)


@pytest.fixture(autouse=True)
def fresh():
    backends.reset()
    yield
    backends.reset()


def _run(plugin: str):
    chosen = [backends.get(name) for name in ("pinocchio", "newton_euler", "screw", plugin)]
    return run_gate([CaseSpec("arm", path=ARM, base="fixed")], chosen, samples=4, seed=2,
                    checks=Checks(charts=False, linearization=False, self_test=False))


def test_a_plugin_supplying_the_drift_parts_is_compared_on_them():
    backends.register(Parts("parts"))
    result = _run("parts")
    assert result.passed
    for state in result.cases[0].states:
        for quantity in ("zvcf", "drift_velocity", "drift_parts"):
            comp = state.comparisons[quantity]
            assert comp.verdict == AGREE and "parts" not in comp.not_compared
            assert any("parts" in pair for pair in comp.pairs)


def test_a_wrong_drift_part_is_caught_and_the_plugin_named():
    backends.register(Parts("wrong_parts", wrong=True))
    result = _run("wrong_parts")
    assert not result.passed
    for state in result.cases[0].states:
        assert state.comparisons["drift"].verdict == AGREE            # the drift itself is right
        for quantity in ("drift_velocity", "drift_parts"):
            comp = state.comparisons[quantity]
            assert comp.verdict == DISAGREE and suspect(comp) == "wrong_parts", quantity


def test_external_force_through_the_helper_adds_its_power():
    split = unconstrained_split(Sizes(1.0, np.array([0.0, 0.0, -9.81])), M=np.eye(2), Cqd=np.zeros(2),
                                g=np.zeros(2), tau_ctrl=np.zeros(2), qd=np.array([2.0, -1.0]), drift=np.zeros(2),
                                ctrl=np.zeros(2), total=np.zeros(2), external_force=np.array([0.5, 3.0]))
    np.testing.assert_array_equal(split.external_force, [0.5, 3.0])
    assert split.power_ext == 0.5 * 2.0 - 3.0


def _file_joints(path: str) -> dict[str, str]:
    """The URDF's joints: child link -> joint name, read from the XML here."""
    robot = ET.parse(path).getroot()
    return {j.find("child").get("link"): j.get("name") for j in robot.findall("joint")}


@pytest.mark.parametrize("base", ["fixed", "free"])
def test_a_source_scene_names_the_files_joints_and_root_link(base):
    model = cases.from_urdf(ARM, base=base)
    by_link = _file_joints(ARM)
    moved = frames.move_scene(model, frames.sampled(1, "arm", 1)[0])
    for scene in (source_scene(model, "probe"), source_scene(moved, "probe")):
        assert scene.root_link == "base"                       # the link no joint of arm.urdf has as child
        expected = tuple(None if base == "free" and i == 0 else by_link[link] for i, link in enumerate(scene.bodies))
        assert scene.joint_names == expected
        assert scene.joint_names[-3:] == ("shoulder_yaw", "shoulder_pitch", "elbow")
    if base == "free":
        assert scene.bodies[0] == "base" and scene.joints[0] == "free" and scene.joint_names[0] is None
