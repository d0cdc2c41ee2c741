"""What a plugin needs (``crosscheck.needs``): crosscheck's Model, the source file and the scene's placement, or a
Pinocchio model of the same source; given for every scene ``split`` is called on (the case, moved scenes, gravity-free
copies). The MuJoCo adapter (``crosscheck.adapters.mujoco``, loaded by its spec) reads the URDF itself, passes
the gate, and its copy with joint damping left on fails it, named as the outlier.
"""

from __future__ import annotations

import multiprocessing
import operator
import pickle
import shlex
from pathlib import Path

import numpy as np
import pytest

import cases
from crosscheck import backends, cli
from crosscheck.reports import diagnosis
from crosscheck.checks import frames
from crosscheck.campaigns.fuzz import runs
from crosscheck.campaigns.fuzz import settings
from crosscheck.reports import fuzz_report
from crosscheck.assemble import Sizes, unconstrained_split
from crosscheck.core.compare import NOT_COMPARED, suspect
from crosscheck.engine.specs import CaseSpec, Checks
from crosscheck.engine.run import run_gate
from scenes import DAMPED_CHAIN, LIMB_MJCF
from crosscheck.needs import PinocchioScene, SourceScene

#: A state of the chain (revolute, continuous, prismatic): q, qd, u.
STATE = ([0.3, -0.7, 0.05], [1.0, -2.0, 0.3], [0.5, -0.2, 0.1])
ROOT = Path(__file__).resolve().parents[2]
MUJOCO, DAMPED = "crosscheck.adapters.mujoco:BACKEND", "crosscheck.adapters.mujoco:BACKEND[damping]"

@pytest.fixture(autouse=True)
def fresh(monkeypatch):
    """Run from the repository root (the plugin is given by its path there); no plugin before or after."""
    monkeypatch.chdir(ROOT)
    backends.reset()
    yield
    backends.reset()


@pytest.fixture
def chain_path(tmp_path) -> str:
    path = tmp_path / "damped_chain.urdf"
    path.write_text(DAMPED_CHAIN)
    return str(path)


class Recorder:
    """A backend that records what it is given and answers with Pinocchio's ABA on the Pinocchio model it gets
    (``needs = "pinocchio"``); with ``c`` > 0 it adds a viscous force ``-c qd`` (a deliberate bug)."""

    needs = "pinocchio"

    def __init__(self, name: str = "recorder", c: float = 0.0):
        self.name, self.c = name, c
        self.seen: list[PinocchioScene] = []

    def split(self, scene: PinocchioScene, q, qd, u):
        import pinocchio as pin

        self.seen.append(scene)
        pm, data = scene.model, scene.data
        qp, vp, tau = scene.configuration(q), scene.velocity(qd), scene.input_map @ np.asarray(u, dtype=float)
        drift = scene.ours(pin.aba(pm, data, qp, vp, -self.c * vp))
        total = scene.ours(pin.aba(pm, data, qp, vp, scene.velocity(tau) - self.c * vp))
        M_p = np.array(pin.crba(pm, data, qp))
        M = scene.ours_matrix(np.triu(M_p) + np.triu(M_p, 1).T)           # crba fills the upper triangle
        g = scene.ours(pin.computeGeneralizedGravity(pm, data, qp))
        sizes = Sizes(float(sum(i.mass for i in pm.inertias)), np.array(pm.gravity.linear))
        return unconstrained_split(sizes, M=M, Cqd=-(M @ drift) - g, g=g, tau_ctrl=tau, qd=qd, drift=drift,
                                   ctrl=np.linalg.solve(M, tau), total=total)


def test_mujoco_example_passes_on_a_urdf_with_damping_limits_and_geometry(chain_path):
    """MuJoCo reads the file with damping, friction, limits and collision boxes, and agrees once they are off."""
    report = Path(chain_path).with_suffix(".md")
    code = cli.main(["gate", "--plugin", MUJOCO, "--model", chain_path, "--samples", "3", "--report", str(report),
                     "--quiet", "--no-linearization"])
    text = report.read_text()
    assert code == 0 and "**PASS**" in text
    assert "pinocchio, mujoco)" in text and "took part in no comparison" not in text


def test_mujoco_example_passes_on_free_and_ball_joints_of_an_mjcf(tmp_path):
    """An MJCF torso on a free joint placed above the world, a ball shoulder, a hinge and a slider: MuJoCo's free
    joint is relative to the world and its linear velocity is in the world frame, converted to crosscheck's."""
    path, report = tmp_path / "limb.xml", tmp_path / "limb.md"
    path.write_text(LIMB_MJCF)
    code = cli.main(["gate", "--plugin", MUJOCO, "--model", str(path), "--samples", "2", "--report", str(report),
                     "--quiet", "--no-linearization"])
    text = report.read_text()
    assert code == 0 and "**PASS**" in text and "pinocchio, mujoco)" in text


def test_mujoco_with_damping_left_on_fails_and_is_named(chain_path):
    report = Path(chain_path).with_suffix(".md")
    code = cli.main(["gate", "--plugin", DAMPED, "--model", chain_path, "--samples", "3", "--report", str(report),
                     "--quiet", "--no-linearization", "--frames", "0", "--no-charts"])
    text = report.read_text()
    assert code == 1 and "**FAIL**" in text
    blamed = [line for line in text.splitlines() if "outlier **" in line]
    assert blamed and all("outlier **mujoco_with_damping**" in line for line in blamed)
    commands = [line for line in text.splitlines() if "reproduce: `crosscheck eval" in line]
    assert commands and all(f"--plugin {shlex.quote(DAMPED)}" in line for line in commands)
    hints = [line for line in text.splitlines() if "a force linear in qd" in line]
    assert hints and "mass matrix" not in " ".join(hints)


def test_source_scenes_follow_moved_scenes_and_gravity_free_copies(chain_path):
    """The frame checks' moved scenes reach the plugin as the file placed by each frame; a gravity-free copy as the
    file with gravity off; MuJoCo's answer there is the reference's on the same copy."""
    plugin = backends.load_plugin(MUJOCO)
    seen: list[SourceScene] = []
    recording = type("RecordingMuJoCo", (), {
        "needs": "source", "name": "recording_mujoco",
        "split": lambda self, scene, q, qd, u: (seen.append(scene), plugin.split.function(scene, q, qd, u))[1]})()
    backends.register(recording)
    model = cases.from_urdf(chain_path, base="fixed")
    result = run_gate([CaseSpec("damped_chain", path=chain_path, base="fixed")],
                      [backends.get("pinocchio"), backends.get("newton_euler"), backends.get("recording_mujoco")],
                      samples=2, seed=3, checks=Checks(charts=False, linearization=False))
    assert result.passed
    placements = {(s.rotation.tobytes(), s.translation.tobytes()) for s in seen}
    expected = {(np.eye(3).tobytes(), np.zeros(3).tobytes())} | {
        (f.rotation.tobytes(), f.translation.tobytes()) for f in frames.sampled(3, "damped_chain")}
    assert placements == expected and all(s.gravity and s.path == model.source.path for s in seen)
    assert seen[0].bodies == ("a", "b", "c") and seen[0].joints == ("revolute", "revolute", "prismatic")

    bare = diagnosis.without_gravity(model)
    got = backends.get("recording_mujoco").split(bare, *STATE)
    assert seen[-1].gravity is False
    want = backends.get("pinocchio").split(bare, *STATE)
    np.testing.assert_allclose(got.drift, want.drift, rtol=1e-10, atol=1e-12)
    held = backends.get("pinocchio").split(model, *STATE)
    assert np.abs(held.drift - want.drift).max() > 1e-3        # gravity did act on the loaded model


def test_pinocchio_scenes_are_built_from_the_file_or_the_data_for_each_scene(chain_path):
    recorder = Recorder()
    backends.register(recorder)
    model = cases.from_urdf(chain_path, base="fixed")
    moved = frames.move_scene(model, frames.sampled(1, "x", 1)[0])
    bare = diagnosis.without_gravity(moved)
    for m in (model, moved, bare):
        got = backends.get("recorder").split(m, *STATE)
        want = backends.get("pinocchio").split(m, *STATE)
        np.testing.assert_allclose(got.total, want.total, rtol=1e-12, atol=1e-12)
    file_gravity = np.array([0.0, 0.0, -9.81])
    gravities = [np.array(s.model.gravity.linear) for s in recorder.seen]
    np.testing.assert_allclose(gravities[0], file_gravity)
    np.testing.assert_allclose(gravities[1], frames.sampled(1, "x", 1)[0].rotation @ file_gravity)
    assert not np.any(gravities[2]) and all(s.from_file for s in recorder.seen)
    assert recorder.seen[0].model is not backends.get("pinocchio") and recorder.seen[0].data is not \
        recorder.seen[1].data
    result = run_gate([CaseSpec("double_pendulum")], [backends.get("pinocchio"), backends.get("newton_euler"),
                                                      backends.get("recorder")], samples=2, seed=0,
                      checks=Checks(linearization=False))
    assert result.passed and not recorder.seen[-1].from_file     # a built-in case: built from our data


def test_a_source_plugin_on_a_built_in_case_is_not_compared():
    backends.load_plugin(MUJOCO)
    model = cases.load("double_pendulum")
    with pytest.raises(Exception, match="needs the model's source file .* was built in code"):
        backends.get("mujoco").split(model, [0.1, 0.2], [0.0, 0.0], [0.0, 0.0])
    result = run_gate([CaseSpec("double_pendulum")], [backends.get("pinocchio"), backends.get("newton_euler"),
                                                      backends.get("mujoco")], samples=1, seed=0,
                      checks=Checks(linearization=False, charts=False, frames=0))
    state = result.cases[0].states[0]
    assert result.passed and "mujoco" not in state.splits and not state.errors
    assert all("mujoco" in c.not_compared for c in state.comparisons.values())
    assert state.comparisons["drift"].verdict != NOT_COMPARED


def test_bad_needs_is_one_line_and_exit_2(tmp_path, capsys):
    (tmp_path / "wants_urdf.py").write_text(
        "from crosscheck.needs import NEEDS\n"
        "class Wants:\n    name = 'wants'\n    needs = 'urdf'\n    def split(self, x, q, qd, u):\n        pass\n"
        "BACKEND = Wants()\n")
    assert cli.main(["formalisms", "--plugin", f"{tmp_path / 'wants_urdf.py'}:BACKEND"]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "needs = 'urdf': declare one of 'model'" in err
    assert cli.main(["formalisms", "--plugin", "examples/no_such_file.py:X"]) == 2
    assert "plugin 'examples/no_such_file.py:X': file 'examples/no_such_file.py' not found" in capsys.readouterr().err


def test_a_plugin_loaded_from_a_file_goes_to_worker_processes_by_its_spec():
    formalism = backends.load_plugin(MUJOCO)
    assert pickle.loads(pickle.dumps(formalism)).split is formalism.split     # here: the same, loaded once
    context = multiprocessing.get_context("spawn")
    with context.Pool(1) as pool:                 # there: nothing of the parent's plugins but the spec
        assert pool.apply(operator.attrgetter("name"), (formalism,)) == "mujoco"


def test_a_force_linear_in_qd_is_hinted_as_damping_not_the_mass_matrix():
    """A backend adding ``-c qd`` (joint damping left on): its drift and total are off, ctrl agrees, the error doubles
    with qd and vanishes at rest; the hint names a force linear in qd, not the mass matrix."""
    backends.register(Recorder("viscous", c=0.3))
    chosen = [backends.get(name) for name in ("pinocchio", "newton_euler", "screw", "viscous")]
    result = run_gate([CaseSpec("double_pendulum")], chosen, samples=3, seed=1,
                      checks=Checks(charts=False, frames=0, conservation=False, linearization=False))
    assert diagnosis.annotate(result, chosen) == 3
    for state in result.cases[0].states:
        assert {q for q, c in state.comparisons.items() if c.verdict == "DISAGREE"} >= {"drift", "total"}
        assert state.comparisons["ctrl"].verdict == "agree" and suspect(state.comparisons["drift"]) == "viscous"
        assert "error x2 when qd doubles, 0 at qd = 0" in state.hint, state.hint
        assert diagnosis.DAMPING in state.hint and diagnosis.INERTIA not in state.hint


def test_a_plugin_finding_prints_a_replay_command_that_runs_as_printed(tmp_path, capsys):
    """A fuzz campaign with a plugin loaded from a file: the finding's replay command carries ``--plugin`` and, run
    as printed (in a fresh registry), reproduces it; without the flag, replay says which command to run."""
    (tmp_path / "viscous_plugin.py").write_text("from test_plugin_needs import Recorder\n\n"
                                                "BACKEND = Recorder('viscous', c=0.3)\n")
    spec = f"{tmp_path / 'viscous_plugin.py'}:BACKEND"
    out = tmp_path / "campaign"
    backends.load_plugin(spec)
    # 8 examples: since the model strategy also draws armature (testing.models), seed 0's first 6 examples miss the
    # viscous force (measured: none of 4 or 6 fails, 8 do); a state at rest, the first drawn, cannot show it
    cfg = settings.config(seed=0, examples=8, workers=0, out=str(out), backends=("pinocchio", "newton_euler", "viscous"),
                      plugins=backends.plugin_specs(), constraints=False, group_joints=False, max_bodies=2,
                      max_states=1, shrink_calls=0, charts=False, frames=False, conservation=False,
                      linearization=False)
    result = runs.run_campaign(cfg, quiet=True)
    assert result.findings
    printed = fuzz_report.summary(result)
    command = next(line.strip() for line in printed.splitlines() if line.strip().startswith("crosscheck replay"))
    assert command.endswith(f"--plugin {spec}") and f"`{command}`" in (out / "report.md").read_text()
    backends.reset()
    assert cli.main(shlex.split(command)[1:]) == 1
    assert "FAILS" in capsys.readouterr().out
    backends.reset()
    assert cli.main(shlex.split(command.split(" --plugin")[0])[1:]) == 2
    assert f"backend(s) viscous, not loaded here; run `{command}`" in capsys.readouterr().err
