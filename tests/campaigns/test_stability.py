"""Stability maps (``crosscheck.campaigns.stability``): the quick paths, the tolerance policy against the exact split, the
BREAKDOWN of the operational-space backend at the task singularity, and an injected wrong answer."""

from __future__ import annotations

import dataclasses
import math

import pytest

from crosscheck import backends
from crosscheck.checks import charts
from crosscheck.engine import evaluation
from crosscheck.campaigns import stability
from crosscheck.reports import stability_report
from crosscheck.cli import build_parser
from crosscheck.cli.stability import cmd_stability


@pytest.fixture(scope="module")
def results() -> dict[str, stability.PathResult]:
    return {p.name: stability.run_path(p) for p in stability.paths(quick=True, names=backends.names())}


def _voting(m: stability.Measurement):
    """(backend, quantity, ratio) for every quantity a backend votes on at this point."""
    return [(b, q, r) for b, rs in m.ratios.items() for q, r in rs.items() if q not in m.left_out(b)]


def test_paths_cover_every_backend_with_finite_errors(results):
    assert set(results) == {"theta2", "four_bar", "mass_ratio", "chain", "velocity", "gimbal"}
    for result in results.values():
        assert len(result.measurements) >= 3
        for m in result.measurements:
            assert set(m.errors) == set(m.point.backends) == set(m.verdicts)
            for backend, errors in m.errors.items():
                assert {"drift", "ctrl", "total"} <= set(errors)
                if not m.left_out(backend):
                    assert all(math.isfinite(e) for e in errors.values()), (result.path.name, m.point.x, backend)


def test_true_error_within_tolerance_wherever_the_gate_votes(results):
    for result in results.values():
        for m in result.measurements:
            assert not m.alarms, (result.path.name, m.point.x, m.alarms)
            voting = _voting(m)
            assert all(not math.isnan(r) for _, _, r in voting) or not m.tolerances
            over = [(b, q, r) for b, q, r in voting if r > 1.0]
            assert not over, (result.path.name, m.point.x, over)
            assert not m.over["silent"] and not m.over["caught"]


def test_operational_space_breakdown_comes_before_its_error_exceeds_the_tolerance(results):
    ms = results["theta2"].measurements
    broken = [i for i, m in enumerate(ms) if m.left_out("operational_space")]
    wrong = [i for i, m in enumerate(ms) if max(m.ratios["operational_space"].values()) > 1.0]
    assert broken and wrong
    assert broken[0] < wrong[0]
    assert all(i in broken for i in wrong)                        # every wrong answer is flagged
    assert ms[broken[0]].conditions["task"] > 1e3                  # flagged by the task condition
    assert all(("operational_space", q) in ms[i].over["flagged"] for i in wrong
               for q, r in ms[i].ratios["operational_space"].items() if r > 1.0)


def test_an_injected_error_is_recorded_above_tolerance_and_caught():
    honest = backends.get("newton_euler")

    def wrong(model, q, qd, u):
        split = honest.split(model, q, qd, u)
        return dataclasses.replace(split, drift=split.drift * (1.0 + 1e-6))

    formalisms = [dataclasses.replace(honest, split=wrong) if b.name == honest.name else b
                  for b in map(backends.get, backends.names())]
    point = stability.theta2_path(3, backends.names()).points[0]
    m = stability.measure(point, evaluation.CaseSetup.build(point.spec, stability.SEED, point.checks), formalisms)
    assert 0.5e-6 < m.errors["newton_euler"]["drift"] < 2e-6
    assert m.ratios["newton_euler"]["drift"] > 1.0
    assert all(r <= 1.0 for b, q, r in _voting(m) if b != "newton_euler")
    assert ("newton_euler", "drift") in m.over["caught"]
    assert m.verdicts["newton_euler"] == "DISAGREE" and m.alarms and not m.false_alarm


def test_report_and_charts_are_written(results, tmp_path):
    report = stability_report.write(list(results.values()), tmp_path, quick=True, seconds=1.0)
    text = report.read_text()
    for name in results:
        assert f"## {name}" in text and f"(stability_{name}.png)" in text
        assert (tmp_path / f"stability_{name}.png").stat().st_size > 1000
    assert "### gimbal: the answers in the chart" in text and (tmp_path / "stability_gimbal_chart.png").stat().st_size > 1000
    assert "silent" in text and "**silent:" not in text


def test_cli_has_the_stability_command():
    args = build_parser().parse_args(["stability", "--quick", "--out", "somewhere"])
    assert args.run is cmd_stability and args.quick and args.out == "somewhere"


def test_gimbal_path_measures_the_zyx_chart(results):
    ms = results["gimbal"].measurements
    assert len(ms) >= 4 and all(m.chart is not None for m in ms)
    deltas = [m.point.x for m in ms]
    assert deltas == sorted(deltas, reverse=True) and deltas[0] >= 1e-1 and deltas[-1] <= 1e-9
    natives = {"euler_lagrange@zyx", "geometric@zyx"}
    first = ms[0].chart
    assert first.compared and natives <= set(first.errors)
    # the exact reference is right: at a benign pitch every answer in the chart agrees with it to ~1e-12
    assert all(e < 1e-11 for v in first.voters for e in first.errors[v].values()), first.errors
    # the gate compares where cond(Dpsi) <= GIMBAL_LIMIT and leaves the chart out past it
    for m in ms:
        c = m.chart
        assert c.compared == (c.cond_D <= charts.GIMBAL_LIMIT)
        assert c.compared == all(v != "left out" for v in c.verdicts.values())
        assert not c.compared or all(v == "agree" for v in c.verdicts.values())
    assert not ms[-1].chart.compared and any(m.chart.compared for m in ms)
    # errors grow towards the lock: the natives' own error like eps cond(M_p), the map's like eps cond(Dpsi)^2
    for v in natives:
        own = [max(m.chart.own[v].values()) for m in ms if v in m.chart.own]
        assert own[0] < 1e-11 and max(own) > 1e-4
        finite = [(max(m.chart.own[v].values()), m.chart.cond_Mp) for m in ms if v in m.chart.own]
        assert all(e < 1e3 * 2.2e-16 * c for e, c in finite if e < 0.1)
    mapped = [m.chart.worst("newton_euler") for m in ms]
    assert mapped[0] < 1e-13 and max(mapped) > 1e-6
    # near the lock a native either fails (Cholesky of M_p: recorded as raised, not a crash) or its answer is recorded
    # with its error (Euler–Lagrange's M_p from Lagrange's equation still factors at delta = 1e-10)
    assert all(v in ms[-1].chart.raised or v in ms[-1].chart.own for v in natives)
    assert "geometric@zyx" in ms[-1].chart.raised
    # the joint chart itself is benign all along
    assert all(e < 1e-14 for m in ms for es in m.errors.values() for e in es.values())


def test_exact_chart_split_agrees_with_the_float_map_at_a_benign_pitch():
    import cases
    import numpy as np

    from crosscheck.references import precise
    from crosscheck.checks.invariance import mapped

    model = cases.load("ball_pendulum")
    chart = charts.get("zyx", model)
    q, qd, u = stability.gimbal_state(0.8)
    exact = precise.chart_split(model, chart, q, qd, u)
    p = chart.p_of(np.array(q))
    assert np.allclose(p, [stability.GIMBAL_YAW, np.pi / 2 - 0.8, stability.GIMBAL_ROLL], atol=1e-14)
    assert np.allclose([float(x) for x in exact.pd], stability.GIMBAL_PD, atol=1e-14)
    pd = charts.velocity_to_chart(chart, p, qd)
    split = backends.get("newton_euler").split(model, q, qd, u)
    for quantity in stability.CHART_QUANTITIES:
        assert precise.relative_error(mapped(chart, p, pd, split, quantity), getattr(exact, quantity)) < 1e-12
    tau_p = charts.force_to_chart(chart, p, model.input_map @ np.array(u))
    native = backends.get("geometric").split_chart(model, chart, p, pd, tau_p)
    at = precise.chart_split_at(model, chart, p, pd, tau_p)
    assert precise.relative_error(native.total, at.total) < 1e-12
    assert precise.relative_error(at.floats("total"), exact.total) < 1e-14
