"""Large models: the banded affine chart, the Euler–Lagrange preparation estimate and the gate's notice before a long
preparation."""

import numpy as np
import pytest

import cases
from crosscheck.campaigns import bench, scale
from crosscheck.checks import charts
from crosscheck.engine import evaluation
from crosscheck.engine import run
from crosscheck.engine import specs
from formalisms import euler_lagrange as el


@pytest.mark.parametrize("n", [3, charts.AFFINE_DENSE_LIMIT])
def test_the_affine_chart_of_a_small_model_is_dense(n):
    A = charts.random_affine(cases.load("n_link_pendulum", n=n), 5, "x").A
    assert np.all(A != 0.0) and np.linalg.cond(A) <= 10.0


def test_the_affine_chart_of_a_large_model_is_banded_and_well_conditioned():
    n = charts.AFFINE_DENSE_LIMIT + 9
    A = charts.random_affine(cases.load("n_link_pendulum", n=n), 5, "x").A
    distance = np.abs(np.subtract.outer(np.arange(n), np.arange(n)))
    assert np.all(A[distance > charts.AFFINE_BAND] == 0.0)
    assert np.all(A[distance <= charts.AFFINE_BAND] != 0.0)
    assert np.linalg.cond(A) <= 10.0


def test_the_dependence_pairs_of_a_chain():
    """Body i of a chain moves with joints 0..i: n(n+1)/2 pairs in the joint chart; in a dense chart every body
    depends on all n coordinates; in the banded one body i on 0..min(i + band, n - 1)."""
    small = cases.load("n_link_pendulum", n=6)
    assert el._dependence_pairs(small, None) == 21
    assert el._dependence_pairs(small, charts.get("affine", small, 0, "x")) == 36
    large = cases.load("n_link_pendulum", n=20)
    band = charts.AFFINE_BAND
    assert el._dependence_pairs(large, charts.get("affine", large, 0, "x")) == sum(min(i + band, 19) + 1
                                                                                   for i in range(20))


def test_the_estimate_is_zero_once_the_derivation_is_cached(tmp_path, monkeypatch):
    monkeypatch.setenv("CROSSCHECK_CACHE", str(tmp_path))
    model = cases.load("double_pendulum", m1=1.25)
    assert el.preparation_estimate(model) == pytest.approx(el.SECONDS_PER_PAIR * 3)
    el.cached_source(model)
    assert el.preparation_estimate(model) == 0.0


def test_the_gate_announces_a_long_preparation_before_the_case(tmp_path, monkeypatch):
    monkeypatch.setenv("CROSSCHECK_CACHE", str(tmp_path))
    monkeypatch.setattr(run, "PREPARATION_NOTICE_S", 0.5)
    spec = specs.CaseSpec("n_link_pendulum", (("n", "14"),))
    with pytest.warns(run.PreparationNotice, match=r"euler_lagrange: preparing case 'n_link_pendulum' \(14 coordinates\)"
                      r" in the joint chart and 3 chart\(s\) takes about \d+ s"):
        run.announce_preparation(evaluation.CaseSetup.build(spec, 0), [el.FORMALISM])


def test_a_measured_child_reports_its_status_time_and_memory(tmp_path):
    """``crosscheck bench --scale`` measures whole processes through the kernel: a command that works, and one that
    fails with its last lines kept."""
    run = scale.measured("cases", ["cases"], str(tmp_path))
    assert run.status == 0 and run.wall_s > 0 and run.cpu_s > 0
    assert run.peak_mib > 20  # a Python process with numpy loaded
    assert "output" not in run.detail
    failed = scale.measured("an unknown case", ["gate", "--case", "no_such_case"], str(tmp_path))
    assert failed.status == 2 and any("no_such_case" in line for line in failed.detail["output"])


def test_a_measured_child_does_not_inherit_the_peak_memory_of_its_parent(tmp_path):
    """Linux carries a process's peak resident memory across fork and exec, so a command forked from a large process
    (``crosscheck reports`` after the faults and the bench) reported that process's peak as its own; the launcher in
    between gives the command's own."""
    import numpy as np

    ballast = np.ones(60_000_000)          # 480 MB resident in this process
    ballast[::512] = 2.0
    run = scale.measured("cases", ["cases"], str(tmp_path))
    assert run.status == 0 and run.peak_mib < 300, run.peak_mib
    assert ballast.sum() > 0


def test_the_scale_report_shows_every_measurement():
    gate_run = scale.Run("gate tiago (48 joints)", ["gate"], 0, 700.0, 690.0, 2600.0)
    fuzz_run = scale.Run("fuzz", ["fuzz"], 0, 60.0, 58.0, 300.0,
                         {"examples": 100, "models": 100, "states": 250, "chunk_s": 50.0})
    results = scale.ScaleResults("full", {"cpus": 2}, [gate_run], [bench.Preparation("euler_lagrange", "chain", 1.5,
                                                                                       0.01)], [fuzz_run])
    text = scale.render(results)
    assert "| tiago (48 joints) | 0 | 700.0 | 690.0 | 2600 |" in text
    assert "| chain | 1.50 | 0.010 |" in text
    assert "| 100 | 100 | 250 | 0 | 60.0 | 58.0 | 4.2 | 1.67 | 50.0 | 300 |" in text   # states/s, models/s
