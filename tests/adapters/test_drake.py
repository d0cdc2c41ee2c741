"""The Drake adapter (``crosscheck.adapters.drake``): Drake reads the URDF itself and agrees with the vote (the gate
PASSes) on a fixed and a free base, on moved scenes and gravity-free copies too; each of its defaults left on, and a
deliberately broken copy of the adapter, makes the gate FAIL naming it as the outlier.
"""

from __future__ import annotations

import numpy as np
import pytest
from adapter_files import outliers, closeness_row, ARM, FLOATING, IN_WORLD, MJCF_ARM, MJCF_LIMB, WALKER, write

import cases
from crosscheck import backends, cli
from crosscheck.adapters.drake import Drake
from crosscheck.adapters.base import Terms
from crosscheck.checks import frames
from crosscheck.core.sampling import sample_states
from crosscheck.needs import source_scene
from crosscheck.reports import diagnosis

#: The gate's fast settings for a failing run: the comparisons of the states only.
FAST = ["--samples", "2", "--quiet", "--no-linearization", "--no-self-test", "--frames", "0", "--no-charts",
        "--no-conservation"]


class SwappedQuaternion(Drake):
    """A broken copy: a free joint's quaternion handed to Drake as ours is stored, ``(x, y, z, w)``, where Drake
    wants ``(w, x, y, z)``."""

    simulator = "drake_swapped_quaternion"

    @staticmethod
    def _state(b, scene, q):
        q_L, rotations = Drake._state(b, scene, q)
        for i, kind in enumerate(scene.joints):
            if kind == "free":
                a = b.qpos[i]
                q_L[a:a + 4] = np.roll(q_L[a:a + 4], -1)
        return q_L, rotations


class NoVelocityBias(Drake):
    """A broken copy: the bias forces without their velocity part (``h = g``, as if ``CalcBiasTerm`` were left
    out), and no solves of Drake's own."""

    simulator = "drake_no_velocity_bias"

    def terms(self, b, scene, q, qd, tau) -> Terms:
        t = super().terms(b, scene, q, qd, tau)
        return Terms(t.M, t.g, t.g, t.mass)


SWAPPED_QUATERNION, NO_VELOCITY_BIAS = SwappedQuaternion(), NoVelocityBias()


@pytest.fixture
def walker(tmp_path) -> str:
    return write(tmp_path, "walker.urdf", WALKER)


@pytest.mark.parametrize("path, base", [(ARM, "fixed"), ("walker", "free")])
def test_drake_agrees_on_a_fixed_and_a_free_base_and_on_moved_scenes(path, base, walker, tmp_path):
    """Every default off, Drake agrees with the vote, also on the frame checks' moved scenes (the walker's file has
    damping, a rotor inertia on a transmission, friction, limits, geometry and an inertia Drake's parser replaces)."""
    report = tmp_path / "gate.md"
    code = cli.main(["gate", "--simulator", "drake", "--model", walker if path == "walker" else path, "--base", base,
                     "--samples", "3", "--report", str(report), "--quiet", "--no-linearization", "--no-self-test"])
    text = report.read_text()
    assert code == 0 and "**PASS**" in text and "took part in no comparison" not in text
    row = closeness_row(text, "drake")
    assert float(row["drift, ctrl, total"]) < 0.05 and float(row["frames"]) < 0.05, row


def test_moved_scenes_and_gravity_free_copies_are_the_references(tmp_path):
    """Drake's answer on a scene, on the scene moved by two frames and on a gravity-free copy is Pinocchio's on the
    same scene: a free base (its pose composed with the placement), a root link named ``world``, a URDF ``floating``
    joint, and MJCF files: a hinge hanging from the world, a ``<freejoint>`` and a ball joint (Drake's roll-pitch-yaw
    ball)."""
    adapter, reference = Drake(), backends.get("pinocchio")
    for name, text, base in (("walker.urdf", WALKER, "free"), ("in_world.urdf", IN_WORLD, "fixed"),
                             ("floating.urdf", FLOATING, None), ("arm.xml", MJCF_ARM, None),
                             ("limb.xml", MJCF_LIMB, None)):
        path = write(tmp_path, name, text)
        model = cases.from_file(path, base=base)
        scenes = [model] + [frames.move_scene(model, f) for f in frames.sampled(5, model.name)]
        scenes.append(diagnosis.without_gravity(scenes[-1]))
        for state in sample_states(model, 3, 1, model.name):
            for scene in scenes:
                got = adapter.split(source_scene(scene, "drake"), state.q, state.qd, state.u)
                want = reference.split(scene, state.q, state.qd, state.u)
                for quantity in ("drift", "ctrl", "total", "kinetic_energy"):
                    np.testing.assert_allclose(getattr(got, quantity), getattr(want, quantity), rtol=1e-9, atol=1e-9,
                                               err_msg=f"{path} {scene.name} {quantity}")


def test_the_free_joint_is_drakes_quaternion_floating_joint(walker):
    """Drake's free joint as the adapter fills it: ``q = (qw, qx, qy, qz, x, y, z)`` puts the torso at the pose of our
    ``(x, y, z, qx, qy, qz, qw)`` (placed by the scene), and ``v = (w, v)`` is the torso's spatial velocity in the
    world (the joint's parent frame here), our body twist turned by the torso's rotation."""
    from crosscheck.adapters.base import free_pose

    model = cases.from_file(walker, base="free")
    scene = source_scene(frames.move_scene(model, frames.sampled(2, "x", 1)[0]), "drake")
    adapter = Drake()
    built = adapter.built(scene)
    state = sample_states(model, 2, 3, "walker")[1]
    q, qd = np.array(state.q), np.array(state.qd)
    q_L, T, _ = adapter.velocity_map(built, scene, q, qd)
    context = built.plant.CreateDefaultContext()
    built.plant.SetPositions(context, q_L)
    built.plant.SetVelocities(context, T @ qd)
    torso = built.plant.GetBodyByName("torso")
    R, p = free_pose(scene, q, 0)
    X = torso.EvalPoseInWorld(context)
    np.testing.assert_allclose(X.rotation().matrix(), R, atol=1e-12)
    np.testing.assert_allclose(X.translation(), p, atol=1e-12)
    V = torso.EvalSpatialVelocityInWorld(context)
    np.testing.assert_allclose(V.rotational(), R @ qd[3:6], atol=1e-12)
    np.testing.assert_allclose(V.translational(), R @ qd[0:3], atol=1e-12)
    assert built.plant.num_positions() == model.nq and q_L[0] == pytest.approx(q[6])          # qw first


@pytest.mark.parametrize("default", sorted(Drake.DEFAULTS))
def test_each_default_left_on_fails_the_gate_named(default, walker, tmp_path):
    """Joint damping, the transmission's reflected rotor inertia and Drake's replacement of the foot's inertia: each
    one left on makes Drake the outlier."""
    report = tmp_path / "gate.md"
    code = cli.main(["gate", "--simulator", f"drake:{default}", "--model", walker, "--base", "free",
                     "--report", str(report), *FAST])
    text = report.read_text()
    assert code == 1 and "**FAIL**" in text
    assert outliers(text) == {f"drake_with_{default}"}


@pytest.mark.parametrize("broken", ["SWAPPED_QUATERNION", "NO_VELOCITY_BIAS"])
def test_a_broken_copy_of_the_adapter_fails_the_gate_named(broken, walker, tmp_path):
    report = tmp_path / "gate.md"
    code = cli.main(["gate", "--plugin", f"{__file__}:{broken}", "--model", walker, "--base", "free",
                     "--report", str(report), *FAST])
    text = report.read_text()
    assert code == 1 and "**FAIL**" in text
    assert outliers(text) == {globals()[broken].name}
