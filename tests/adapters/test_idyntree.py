"""The iDynTree adapter (``crosscheck.adapters.idyntree``): iDynTree reads the URDF itself and agrees with the vote
(the gate PASSes) on a fixed and a free base, on moved scenes and gravity-free copies too; it has no model-changing
default to leave on; a deliberately broken copy of the adapter makes the gate FAIL naming it as the outlier; what it
cannot read is NOT COMPARED.
"""

from __future__ import annotations

import idyntree.swig as idt
import numpy as np
import pytest
from adapter_files import outliers, closeness_row, ARM, FLOATING, IN_WORLD, MJCF_ARM, WALKER, write

import cases
from crosscheck import backends, cli
from crosscheck.adapters.base import Terms
from crosscheck.adapters.idyntree import IDynTree
from crosscheck.checks import frames
from crosscheck.core.sampling import sample_states
from crosscheck.needs import source_scene
from crosscheck.reports import diagnosis
from formalisms.interface import ModelNotSupported

#: The gate's fast settings for a failing run: the comparisons of the states only.
FAST = ["--samples", "2", "--quiet", "--no-linearization", "--no-self-test", "--frames", "0", "--no-charts",
        "--no-conservation"]


class MixedRepresentation(IDynTree):
    """A broken copy: the base velocity in iDynTree's default ``MIXED_REPRESENTATION`` (linear velocity in the world
    frame) while the adapter hands it our body twist."""

    simulator = "idyntree_mixed_representation"

    def build(self, scene):
        built = super().build(scene)
        built.kd.setFrameVelocityRepresentation(idt.MIXED_REPRESENTATION)
        return built


class NoVelocityBias(IDynTree):
    """A broken copy: the bias forces without their velocity part (``h = g``)."""

    simulator = "idyntree_no_velocity_bias"

    def terms(self, b, scene, q, qd, tau) -> Terms:
        t = super().terms(b, scene, q, qd, tau)
        return Terms(t.M, t.g, t.g, t.mass)


MIXED_REPRESENTATION, NO_VELOCITY_BIAS = MixedRepresentation(), NoVelocityBias()


@pytest.fixture
def walker(tmp_path) -> str:
    return write(tmp_path, "walker.urdf", WALKER)


@pytest.mark.parametrize("path, base", [(ARM, "fixed"), ("walker", "free")])
def test_idyntree_agrees_on_a_fixed_and_a_free_base_and_on_moved_scenes(path, base, walker, tmp_path):
    report = tmp_path / "gate.md"
    code = cli.main(["gate", "--simulator", "idyntree", "--model", walker if path == "walker" else path, "--base",
                     base, "--samples", "3", "--report", str(report), "--quiet", "--no-linearization",
                     "--no-self-test"])
    text = report.read_text()
    assert code == 0 and "**PASS**" in text and "took part in no comparison" not in text
    row = closeness_row(text, "idyntree")
    assert float(row["drift, ctrl, total"]) < 0.05 and float(row["frames"]) < 0.05, row


def test_moved_scenes_and_gravity_free_copies_are_the_references(tmp_path):
    """iDynTree's answer on a scene, on the scene moved by two frames and on a gravity-free copy is Pinocchio's on the
    same scene: a free base, a root link named ``world`` (a frame of the base link in iDynTree), and a URDF
    ``floating`` joint (which iDynTree's parser does not hold: the adapter floats the base from its origin)."""
    adapter, reference = IDynTree(), backends.get("pinocchio")
    for name, text, base in (("walker", WALKER, "free"), ("in_world", IN_WORLD, "fixed"),
                             ("floating", FLOATING, None)):
        model = cases.from_file(write(tmp_path, f"{name}.urdf", text), base=base)
        scenes = [model] + [frames.move_scene(model, f) for f in frames.sampled(5, model.name)]
        scenes.append(diagnosis.without_gravity(scenes[-1]))
        for state in sample_states(model, 3, 1, model.name):
            for scene in scenes:
                got = adapter.split(source_scene(scene, "idyntree"), state.q, state.qd, state.u)
                want = reference.split(scene, state.q, state.qd, state.u)
                for quantity in ("drift", "ctrl", "total"):
                    np.testing.assert_allclose(getattr(got, quantity), getattr(want, quantity), rtol=1e-9, atol=1e-9,
                                               err_msg=f"{name} {scene.name} {quantity}")


def test_idyntree_has_no_default_and_reads_no_mjcf(tmp_path):
    assert IDynTree.DEFAULTS == {}
    with pytest.raises(ValueError, match="idyntree has no default 'damping'; its defaults: none"):
        IDynTree(["damping"])
    model = cases.from_file(write(tmp_path, "arm.xml", MJCF_ARM))
    state = sample_states(model, 1, 0, "arm")[0]
    with pytest.raises(ModelNotSupported, match="does not read MJCF files"):
        IDynTree().split(source_scene(model, "idyntree"), state.q, state.qd, state.u)


@pytest.mark.parametrize("broken", ["MIXED_REPRESENTATION", "NO_VELOCITY_BIAS"])
def test_a_broken_copy_of_the_adapter_fails_the_gate_named(broken, walker, tmp_path):
    report = tmp_path / "gate.md"
    code = cli.main(["gate", "--plugin", f"{__file__}:{broken}", "--model", walker, "--base", "free",
                     "--report", str(report), *FAST])
    text = report.read_text()
    assert code == 1 and "**FAIL**" in text
    assert outliers(text) == {globals()[broken].name}
