"""Forward ZTCF trajectories (crosscheck/campaigns/trajectory.py): integrator orders, the 50-digit reference, the envelope
judgment (it must fail on a 1e-10 drift fault and pass on correct backends), the CLI's errors and the report command."""

from __future__ import annotations

import dataclasses

import mpmath
import numpy as np
import pytest

import cases
from crosscheck import cli
from crosscheck.campaigns import trajectory as T
from crosscheck.reports import trajectory_report as R


def _oscillator(q, v, t):
    return -q


def _pendulum_batch(Q, V, ts):
    return -np.sin(Q)


def _rk4_end(h, T_end=1.0):
    q, v = np.array([1.0]), np.array([0.0])
    for k in range(int(round(T_end / h))):
        q, v = T.rk4_step(_oscillator, q, v, k * h, h)
    return abs(q[0] - np.cos(T_end)) + abs(v[0] + np.sin(T_end))


def _gauss_end(h, T_end=1.0):
    q, v = np.array([1.0]), np.array([0.0])
    for k in range(int(round(T_end / h))):
        q, v, _ = T.gauss_step(lambda Q, V, ts: -Q, q, v, k * h, h)
    return abs(q[0] - np.cos(T_end)) + abs(v[0] + np.sin(T_end))


def test_rk4_order_four():
    ratio = _rk4_end(0.05) / _rk4_end(0.025)
    assert 14.0 < ratio < 18.0, ratio


def test_gauss_order_four_and_energy_bounded_on_the_pendulum():
    ratio = _gauss_end(0.1) / _gauss_end(0.05)
    assert 14.0 < ratio < 18.0, ratio
    q, v, h = np.array([2.0]), np.array([0.0]), 0.2
    energies = []
    for k in range(2000):                      # 400 s, about 60 periods
        q, v, _ = T.gauss_step(_pendulum_batch, q, v, k * h, h)
        energies.append(0.5 * v[0] ** 2 - np.cos(q[0]))
    dE = np.abs(np.array(energies) - (-np.cos(2.0)))
    assert dE.max() < 1e-2                     # bounded, no secular growth:
    assert dE[1000:].max() < 2 * dE[:1000].max()
    q, v = np.array([2.0]), np.array([0.0])    # RK4 at the same step drifts (it damps)
    for k in range(2000):
        q, v = T.rk4_step(lambda q, v, t: -np.sin(q), q, v, k * h, h)
    assert abs(0.5 * v[0] ** 2 - np.cos(q[0]) + np.cos(2.0)) > 10 * dE.max()


def test_closed_form_field_matches_the_generic_precise_split():
    model = cases.load("double_pendulum")
    f = T._PendulumField({})
    rng = np.random.default_rng(1)
    with mpmath.workdps(50):
        for _ in range(3):
            x = [mpmath.mpf(float(a)) for a in rng.uniform(-3, 3, 4)]
            a = f(0, x)
            b = T._mp_acceleration(model, x[:2], x[2:], [mpmath.mpf(0)] * 2)
            assert max(abs(a[2] - b[0]), abs(a[3] - b[1])) < mpmath.mpf(10) ** -44


def test_reference_conserves_energy_to_1e30_and_estimates_its_error():
    model = cases.load("double_pendulum")
    ref = T.reference_trajectory(model, [2.0, 1.0], [0.0, 0.0], 0.2, 0.05, closed_form={})
    with mpmath.workdps(50):
        drift = max(abs(e - ref.energy[0]) for e in ref.energy)
    assert drift < mpmath.mpf(10) ** -30
    assert ref.error_estimate < 1e-22
    # and the small-oscillation closed form: theta(t) ~ linear normal modes; check the reference against the float
    # RK4 at a tiny step instead (both exact to ~1e-12 there)
    run = T.simulate(model, "pinocchio", [2.0, 1.0], [0.0, 0.0], 0.2, 0.001, "rk4", every=50)
    assert np.abs(run.x - ref.x).max() < 1e-10


def test_group_joints_are_refused():
    with pytest.raises(T.TrajectoryError, match="revolute and prismatic"):
        T.check_model(cases.load("free_body"))


@pytest.fixture(scope="module")
def pendulum_runs():
    model = cases.load("double_pendulum")
    q0, v0, horizon, dt, interval = [2.0, 1.0], [0.0, 0.0], 0.6, 0.01, 0.02
    ref = T.reference_trajectory(model, q0, v0, horizon, interval, closed_form={}, halving=False)
    lyap = T.lyapunov(model, ref)
    runs = {b: T.simulate(model, b, q0, v0, horizon, dt, "rk4", every=2)
            for b in ("euler_lagrange", "geometric", "pinocchio")}
    runs["fault"] = T.simulate(model, T.FaultyBackend("euler_lagrange", 1e-10), q0, v0, horizon, dt, "rk4", every=2)
    sigma = T.rounding_rate(model, ref, dt, "rk4")
    return ref, lyap, runs, sigma


def test_envelope_passes_correct_backends(pendulum_runs):
    ref, lyap, runs, sigma = pendulum_runs
    j = T.judge([runs["euler_lagrange"], runs["geometric"], runs["pinocchio"]], ref, lyap, sigma)
    assert j.outside == []
    assert max(j.ratio.values()) < 1.0
    assert j.judged_until == pytest.approx(0.6)


def test_envelope_names_a_1e10_drift_fault(pendulum_runs):
    ref, lyap, runs, sigma = pendulum_runs
    fault = runs["fault"]
    assert fault.backend == "euler_lagrange+1e-10"
    j = T.judge([runs["euler_lagrange"], runs["geometric"], runs["pinocchio"], fault], ref, lyap, sigma)
    assert j.outside == ["euler_lagrange+1e-10"]
    two = T.judge([runs["pinocchio"], fault], ref, lyap, sigma)   # two voters: both named, cannot tell which
    assert set(two.outside) == {"pinocchio", "euler_lagrange+1e-10"}


def test_growth_summary_of_a_pure_exponential():
    t = np.linspace(0, 4, 201)
    ly = T.growth_summary(t, np.exp(1.5 * t))
    assert ly.ftle == pytest.approx(1.5)
    assert ly.exponent == pytest.approx(1.5)
    E = T.envelope(t, np.ones_like(t), 1.0, ly)
    assert E[-1] == pytest.approx(np.expm1(1.5 * 4) / 1.5, rel=0.05)


def test_projection_keeps_the_four_bar_on_its_manifold():
    model = cases.load("four_bar", coupler=2.5, rocker=2.0)
    q, v = R._start_state("four_bar", (("coupler", 2.5), ("rocker", 2.0)))
    free = T.simulate(model, "pinocchio", q, v, 0.4, 0.04, "rk4", "none")
    kept = T.simulate(model, "pinocchio", q, v, 0.4, 0.04, "rk4", "project")
    assert T.constraint_drift(model, kept).max() < 1e-12 < T.constraint_drift(model, free).max()


@pytest.mark.parametrize("argv, message", [
    (["--case", "nope", "--horizon", "1"], "unknown case 'nope'"),
    (["--case", "double_pendulum", "--horizon", "0"], "--horizon must be a positive"),
    (["--case", "double_pendulum", "--horizon", "-1"], "--horizon must be a positive"),
    (["--case", "double_pendulum", "--horizon", "1", "--q", "1,2,3"], "--q has 3 entries; the case needs 2"),
    (["--case", "double_pendulum", "--horizon", "1", "--v", "1,x"], "--v must be comma-separated numbers"),
    (["--case", "free_body", "--horizon", "1"], "revolute and prismatic joints only"),
    (["--case", "double_pendulum", "--horizon", "1", "--integrator", "euler"], "unknown integrator 'euler'"),
    (["--case", "double_pendulum", "--horizon", "1", "--formalism", "bogus"], "unknown formalism 'bogus'"),
])
def test_cli_bad_input_is_one_line_exit_2(capsys, argv, message):
    assert cli.main(["trajectory", *argv]) == 2
    err = capsys.readouterr().err.strip()
    assert message in err and "\n" not in err


def test_cli_table_and_json(capsys):
    argv = ["trajectory", "--case", "double_pendulum", "--horizon", "0.1", "--formalism", "euler_lagrange",
            "--formalism", "pinocchio", "--json"]
    assert cli.main(argv) == 0
    import json
    out = json.loads(capsys.readouterr().out)
    assert [b["backend"] for b in out["backends"]] == ["euler_lagrange", "pinocchio"]
    assert out["outside"] == [] and out["reference_error_estimate"] < 1e-20


def test_report_command_writes_the_files(tmp_path, monkeypatch):
    tiny = dataclasses.replace(R.quick(), horizon=0.1, c_horizon=0.1, drift_horizon=0.2, energy_horizon=1.0,
                               periods=2.0)
    monkeypatch.setattr(R, "Settings", lambda: tiny)
    assert cli.main(["trajectory", "--report", str(tmp_path)]) == 0
    text = (tmp_path / "trajectories.md").read_text()
    assert "# Forward ZTCF trajectories" in text and "OUTSIDE" in text     # the fault row is flagged
    for png in ("trajectories_double_pendulum.png", "trajectories_lyapunov.png", "trajectories_four_bar.png",
                "trajectories_maps.png"):
        assert (tmp_path / png).stat().st_size > 1000


def test_input_schedule_reaches_backends_and_reference():
    model = cases.load("double_pendulum")

    def schedule(t):           # mpmath functions: exact at the reference's precision, float for the backends
        return [mpmath.cos(3 * t), -0.5]
    ref = T.reference_trajectory(model, [0.5, 0.2], [0.0, 0.0], 0.2, 0.05, schedule=schedule, closed_form={},
                                 halving=False)
    generic = T.reference_trajectory(model, [0.5, 0.2], [0.0, 0.0], 0.2, 0.05, schedule=schedule, halving=False)
    assert np.abs(ref.x - generic.x).max() < 1e-15
    run = T.simulate(model, "pinocchio", [0.5, 0.2], [0.0, 0.0], 0.2, 0.001, "rk4", every=50, schedule=schedule)
    drift = T.simulate(model, "pinocchio", [0.5, 0.2], [0.0, 0.0], 0.2, 0.001, "rk4", every=50)
    assert np.abs(run.x - ref.x).max() < 1e-11 < np.abs(drift.x - ref.x).max()


@pytest.mark.parametrize("coefficients", [((0.25, 0.25 - T._S3 / 6), (0.25 - T._S3 / 6, 0.25)),   # A21's sign
                                          ((0.25, 0.25 - T._S3 / 6), (0.25 + T._S3 / 6, 0.5))])   # a stage weight off
def test_a_wrong_gauss_coefficient_fails_the_order_check(monkeypatch, coefficients):
    """The integrators are shared by every backend, so the backends' vote cannot see a fault in them; the order
    check against the exact solution does: a Gauss–Legendre tableau with a wrong coefficient is no longer order 4."""
    monkeypatch.setattr(T, "GAUSS_A", coefficients)
    ratio = _gauss_end(0.1) / _gauss_end(0.05)
    assert not 14.0 < ratio < 18.0, ratio
