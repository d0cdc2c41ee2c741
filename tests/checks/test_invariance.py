"""Charts, frames and the gate's chart, frame and conservation checks, including the faults they must catch."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given
from hypothesis import strategies as st

import cases
from crosscheck import backends
from crosscheck.checks import charts, frames
from crosscheck.core.compare import DISAGREE
from crosscheck.engine.specs import CaseSpec, Checks
from crosscheck.engine.run import run_gate
from crosscheck.reports.gate_summary import render

PANDA = cases.load("panda")
DP = cases.load("double_pendulum")
ARM = cases.load("spatial_arm")

vectors = st.lists(st.floats(-3.0, 3.0), min_size=6, max_size=6).map(np.array)


def _all_charts(model):
    return [charts.get(name, model, 0, model.name) for name in charts.names()
            if (name != "absolute" or charts.is_planar_serial(model))
            and name not in charts.GROUP_CHARTS + charts.REPRESENTATIONS]   # group joints only (test_group_charts.py)


def _central(f, x, h=1e-6):
    return (f(x + h) - f(x - h)) / (2 * h)


@given(vectors, vectors)
def test_each_chart_inverts_and_its_jacobian_and_rate_are_the_derivatives_of_psi(p, pd):
    for chart in _all_charts(ARM):
        np.testing.assert_allclose(chart.p_of(chart.q_of(p)), p, rtol=0, atol=1e-12)
        D = chart.jacobian(p)
        for j in range(ARM.n):
            e = np.eye(ARM.n)[j]
            np.testing.assert_allclose(D[:, j], _central(lambda s: chart.q_of(p + s * e), 0.0), atol=1e-8)
        rate = _central(lambda s: chart.jacobian(p + s * pd) @ pd, 0.0)
        np.testing.assert_allclose(chart.jacobian_rate(p, pd), rate, atol=1e-7)


def test_the_affine_chart_of_a_large_model_is_drawn_in_bounded_time_within_its_condition():
    """tiago_dual (101 coordinates): a random banded A almost never has cond <= 10 past 50 coordinates, and the draw
    looped for ever (issue 34); after AFFINE_DRAWS draws the last one is shrunk to meet the bound."""
    model = cases.load("n_link_pendulum", n=60)
    chart = charts.random_affine(model, 0, "n_link_pendulum")
    assert np.linalg.cond(chart.A) <= 10.0 and np.count_nonzero(np.triu(chart.A, 3)) == 0       # still banded
    np.testing.assert_array_equal(charts.random_affine(model, 0, "n_link_pendulum").A, chart.A)  # still seeded


def test_absolute_chart_is_the_articles_and_only_for_planar_serial_chains():
    chart = charts.get("absolute", DP)
    theta = chart.q_of(np.array([0.3, 1.0]))         # phi = (theta1, theta1 + theta2)
    np.testing.assert_allclose(theta, [0.3, 0.7], rtol=0, atol=1e-15)
    with pytest.raises(charts.ChartError, match="planar serial chain"):
        charts.get("absolute", ARM)
    with pytest.raises(charts.ChartError, match="valid charts"):
        charts.get("polar", DP)


@given(vectors, vectors)
def test_forces_map_as_covectors_so_power_is_chart_invariant(p, pd):
    tau_q = np.linspace(-2.0, 3.0, ARM.n)
    for chart in _all_charts(ARM):
        qd = chart.jacobian(p) @ pd
        assert charts.force_to_chart(chart, p, tau_q) @ pd == pytest.approx(tau_q @ qd, abs=1e-10)
        np.testing.assert_allclose(charts.force_from_chart(chart, p, charts.force_to_chart(chart, p, tau_q)), tau_q,
                                   atol=1e-12)


def test_twists_and_wrenches_keep_their_pairing_under_a_frame_change():
    rng = np.random.default_rng(5)
    for frame in frames.sampled(0, "x", 4):
        V, F = rng.standard_normal(6), rng.standard_normal(6)
        assert (frames.wrench_map(frame) @ F) @ (frames.twist_map(frame) @ V) == pytest.approx(F @ V, abs=1e-12)
        np.testing.assert_allclose(frame.rotation @ frame.rotation.T, np.eye(3), atol=1e-14)
        assert np.linalg.det(frame.rotation) == pytest.approx(1.0)


def test_a_moved_scene_keeps_the_task_and_turns_gravity():
    frame = frames.sampled(0, "arm", 1)[0]
    moved = frames.move_scene(ARM, frame)
    np.testing.assert_allclose(moved.gravity, frame.rotation @ ARM.gravity)
    np.testing.assert_allclose(moved.task_point().directions, ARM.task_point().directions @ frame.rotation.T)
    assert moved.digest() != ARM.digest()


def _run(case, samples=6, **checks):
    result = run_gate([CaseSpec(case)], [backends.get(n) for n in backends.names()], samples, 0,
                      checks=Checks(**checks))
    bad = {key for s in result.cases[0].states for key, c in s.checks.items() if c.verdict == DISAGREE}
    return result, bad


@pytest.mark.parametrize("case", ["double_pendulum", "acrobot", "spatial_arm"])
def test_the_correct_backends_pass_every_chart_frame_and_conservation_check(case):
    result, bad = _run(case)
    assert result.passed and not bad, bad
    families = {key.split(":")[0] for s in result.cases[0].states for key in s.checks}
    expected = {"chart affine", "chart nonlinear", "frame", "frame law", "conservation"}
    assert expected <= families
    assert ("chart absolute" in families) == (case != "spatial_arm")
    report = render(result, "test")
    assert "## Invariance and conservation checks" in report and "chart nonlinear" in report


def test_fault_chart_without_its_rate_term_is_caught(monkeypatch):
    monkeypatch.setattr(charts.NonlinearChart, "jacobian_rate", lambda self, p, pd: np.zeros(len(pd)))
    result, bad = _run("double_pendulum", frames=0, conservation=False)
    assert not result.passed
    assert {key.split(":")[0] for key in bad} == {"chart nonlinear"}
    assert any(key.endswith(": drift") for key in bad)


def test_fault_forces_mapped_by_the_jacobian_instead_of_its_transpose_is_caught(monkeypatch):
    monkeypatch.setattr(charts, "force_to_chart", lambda chart, p, tau: chart.jacobian(p) @ np.asarray(tau))
    result, bad = _run("spatial_arm", frames=0, conservation=False)
    assert not result.passed
    assert any(key.startswith("chart affine") and key.endswith("ctrl") for key in bad)
    assert any(key.startswith("chart nonlinear") and key.endswith("power_ctrl") for key in bad)


def test_fault_gravity_not_rotated_with_the_frame_is_caught(monkeypatch):
    monkeypatch.setattr(frames, "rotate_gravity", lambda frame, gravity: gravity)
    result, bad = _run("spatial_arm", charts=False, conservation=False)
    assert not result.passed
    assert {"frame: drift", "frame: total"} <= bad


def test_fault_wrench_mapped_by_Ad_instead_of_its_inverse_transpose_is_caught(monkeypatch):  # noqa: N802
    monkeypatch.setattr(frames, "wrench_map", frames.twist_map)
    result, bad = _run("spatial_arm", charts=False, conservation=False)
    assert not result.passed
    assert bad == {"frame law: screw wrenches_space", "frame law: newton_euler joint_reactions_world"}
    report = render(result, "test")
    assert "--frame g" in report


def test_a_failing_chart_check_reports_a_command_that_reproduces_it_in_the_chart(monkeypatch, capsys):
    from crosscheck import cli
    monkeypatch.setattr(charts.NonlinearChart, "jacobian_rate", lambda self, p, pd: np.zeros(len(pd)))
    result, _ = _run("double_pendulum", samples=3, frames=0, conservation=False)
    report = render(result, "test")
    line = next(x for x in report.splitlines() if "--chart nonlinear" in x)
    command = line.split("`")[1]
    assert command.startswith("crosscheck eval --case double_pendulum --chart nonlinear --seed 0 --q=")
    monkeypatch.undo()
    assert cli.main(command.split()[1:]) == 0
    out = capsys.readouterr().out
    assert "in chart nonlinear" in out and "geometric (in chart nonlinear)" in out


def test_eval_in_a_chart_takes_the_generalized_force_there_and_refuses_one_the_inputs_cannot_make(capsys):
    from crosscheck import cli
    # absolute angles of the double pendulum; tau_p = Dpsi^T tau_q = (tau1 - tau2, tau2) for tau_q = (5, -2)
    assert cli.main(["eval", "--case", "double_pendulum", "--chart", "absolute", "--q=0.785,1.309", "--qd=2,1",
                     "--tau=7,-2", "--json"]) == 0
    import json
    out = json.loads(capsys.readouterr().out)
    assert out["u"] == pytest.approx([5.0, -2.0])
    geo, ne = out["formalisms"]["geometric"], out["formalisms"]["newton_euler"]
    np.testing.assert_allclose(geo["total"], ne["total"], rtol=1e-12)
    # the acrobot has one input, at the elbow: a shoulder torque is not a force its input can produce
    assert cli.main(["eval", "--case", "acrobot", "--chart", "absolute", "--q=0.1,0.2", "--tau=1,0"]) == 2
    assert "is not a force the inputs can produce" in capsys.readouterr().err


def test_fault_a_drift_that_does_work_is_caught_by_the_energy_rate_and_named(dropped_coriolis):
    """Euler–Lagrange with its velocity-product term dropped (conftest.py): its drift changes the energy."""
    result, bad = _run("spatial_arm", charts=False, frames=0)
    assert "conservation: energy rate at drift" in bad
    outliers = {s.checks["conservation: energy rate at drift"].outlier for s in result.cases[0].states}
    assert outliers == {"euler_lagrange"}


def test_fault_a_christoffel_symbol_with_the_wrong_sign_breaks_the_skew_identity(monkeypatch):
    from formalisms import geometric
    monkeypatch.setattr(geometric, "christoffel_first_kind",
                        lambda dM: 0.5 * (dM.transpose(1, 0, 2) + dM.transpose(1, 2, 0) + dM))
    result, bad = _run("spatial_arm", charts=False, frames=0)
    assert {"conservation: Mdot - 2C skew-symmetric", "conservation: C qd = M Gamma(qd, qd)"} <= bad


def test_a_task_point_on_the_joint_axes_is_compared_on_the_moved_scene_with_the_frames_lever():
    """A fuzz finding: the task point on two coaxial joints' axis accelerates at exactly 0 (task lever 0, tolerance
    0), but on the scene moved by t = (0, 1, 0) the screw backend's world-frame kinematics round on |t| (2.5e-16)."""
    from crosscheck.checks import invariance
    from crosscheck.engine.evaluation import evaluate
    from crosscheck.core.sampling import State

    inertia = np.diag([0.25, 0.25, 0.025])
    model = cases.build_model("on_axis", [cases.Body("b0", None, "revolute", (0, 0, 1), 1.0, inertia=inertia),
                                          cases.Body("b1", "b0", "revolute", (0, 0, 1), 1.0, inertia=inertia)],
                              task_points=[cases.TaskPoint("tip", "b1", (0, 0, 0), directions=[[1.0, 0.0, 0.0]])])
    chosen = [backends.get(name) for name in backends.names()]
    state = State(0, (0.0, 0.1875), (0.0, 1.0), (0.0, 0.0))
    frame = frames.Frame("g", np.eye(3), np.array([0.0, 1.0, 0.0]))
    here, there = evaluate(model, state, chosen), evaluate(frames.move_scene(model, frame), state, chosen)
    assert np.all(here.splits["pinocchio"].task_drift == 0.0)
    checks = invariance.frame_checks(model, frame, state, here.trusted, there.trusted)
    assert checks["frame: task_drift"].verdict != DISAGREE and checks["frame: task_drift"].tolerance > 0.0


def _tilted_coaxial():
    """A fuzz finding: three coaxial bodies, the first tilted by 7e-3 rad, a task direction nearly normal to the tip's
    motion (|J| ~ 3e-3 of its lever)."""
    tilt = [[0.9999761996640864, 1.2643928454141578e-05, 0.0068992713747435324],
            [1.2643928454141578e-05, 0.9999932829130087, -0.003665237917832502],
            [-0.0068992713747435324, 0.003665237917832502, 0.9999694825770951]]
    outer, inner = np.diag([0.25, 0.25, 0.025]), np.diag([0.0546875, 0.0625, 0.0078125])
    model = cases.build_model("tilted_coaxial", [
        cases.Body("b0", None, "revolute", (0, 0, 1), 1.0, inertia=outer, rotation=tilt),
        cases.Body("b1", "b0", "revolute", (0, 0, 1), 1.0, inertia=inner),
        cases.Body("b2", "b1", "revolute", (0, 0, 1), 1.0, inertia=outer)],
        task_points=[cases.TaskPoint("tip", "b2", (0.5, 0, 0), directions=[[1.0, 0.0, 0.0]])])
    return model, (0.0, 0.0, 0.0), (1.0, 0.0, 0.0)


def _oblique_task():
    """A fuzz finding: a one-row task direction 9e-7 off the normal of the point's motion (cond(A) = 1, Lambda
    8e12)."""
    model = cases.build_model("oblique_task", [
        cases.Body("b0", None, "revolute", (0, 0, 1), 1.0, inertia=np.diag([0.12910281416703115] * 2 + [0.0129102814]),
                   rotation=[[0, -1, 0], [1, 0, 0], [0, 0, 1]]),
        cases.Body("b1", "b0", "revolute", (0, 0, 1), 1.0, com=(0, 0.016, 0), translation=(-0.9297101705889657, 0, 0),
                   inertia=np.diag([0.01272449651405012, 0.11724536167239735, 0.10452086515834723])),
        cases.Body("b2", "b1", "revolute", (1, 0, 0), 1.0,
                   inertia=np.diag([0.021369577729806265, 0.0641087331894188, 0.042739155459612536]))],
        task_points=[cases.TaskPoint("tip", "b0", (0, -0.5, 0),
                                     directions=[[-0.7936945575169088, 9.064622042047122e-07, 0.6083164878311427]])])
    return model, (0.0, 0.0, 0.0), (2.754561810972139, 0.0, 0.0)


@pytest.mark.parametrize("example", [_tilted_coaxial, _oblique_task])
def test_a_task_jacobian_short_in_every_direction_is_an_operational_space_breakdown(example):
    """Two fuzz findings where the operational-space recomposition lost accuracy with cond(J M^-1 J^T) = 1: its error,
    eps L / |J| relative, is 2.3 and 280 times the componentwise drift tolerance (it once inflated the energy-rate
    tolerance instead). The backend reports how much its recomposition amplifies the task bias's rounding
    (``task_jacobian``, 7.9e4 and 1.6e6 here):
    a BREAKDOWN, and nothing else fails; the energy rate holds for the voters."""
    from crosscheck.checks import conservation
    from crosscheck.engine.evaluation import evaluate
    from crosscheck.core.sampling import State

    model, q, qd = example()
    state = State(0, q, qd, (0.0, 0.0, 0.0))
    outcome = evaluate(model, state, [backends.get(name) for name in backends.names()])
    assert set(outcome.breakdowns) == {"operational_space"}
    assert outcome.breakdowns["operational_space"]["task_jacobian"] > 5e4
    assert not outcome.failed
    rate = conservation.checks(model, state, outcome.trusted)["conservation: energy rate at drift"]
    assert rate.verdict != DISAGREE and "operational_space" not in rate.voters


def test_the_skew_symmetry_check_has_a_floor_where_mdot_cancels_to_zero():
    """A fuzz finding: a body on a perpendicular axis, q = (2, 0), qd = (1, 0): Mdot = 0 exactly, and the geometric
    backend's N + N^T = 1e-16 (rounding of terms of size ||M|| |qd|) failed a tolerance of 8e-30."""
    from crosscheck.checks import conservation
    from crosscheck.engine.evaluation import evaluate
    from crosscheck.core.sampling import State

    inertia = np.diag([0.25, 0.25, 0.025])
    model = cases.build_model("perpendicular", [
        cases.Body("b0", None, "revolute", (1, 0, 0), 1.0, inertia=inertia),
        cases.Body("b1", "b0", "revolute", (0, 1, 0), 1.0, com=(0.5, 0, 0), inertia=inertia,
                   rotation=[[0, 0, 1], [0, 1, 0], [-1, 0, 0]], translation=(0, 1, 0))])
    state = State(0, (2.0, 0.0), (1.0, 0.0), (0.0, 0.0))
    outcome = evaluate(model, state, [backends.get(name) for name in backends.names()])
    skew = conservation.checks(model, state, outcome.trusted)["conservation: Mdot - 2C skew-symmetric"]
    assert skew.verdict != DISAGREE and skew.tolerance > 1e-16
