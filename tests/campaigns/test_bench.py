"""``crosscheck bench`` (issue 7): the quick bench runs and writes its reports; its error statistics measure what
they claim; the general 3-D rewrite of a scene keeps its physics."""

from __future__ import annotations

import dataclasses
import json

import numpy as np
import pytest

import cases
from cases.representation import general_3d
from crosscheck import backends
from crosscheck.campaigns import bench
from crosscheck.references import precise
from crosscheck.references.pinocchio import reference
from crosscheck.core import sampling
from crosscheck.cli import main
from formalisms.interface import Formalism

PNG = b"\x89PNG\r\n\x1a\n"


@pytest.fixture(scope="module")
def quick_reports(tmp_path_factory):
    out = tmp_path_factory.mktemp("bench")
    assert main(["bench", "--quick", "--out", str(out)]) == 0
    return out


def test_quick_bench_writes_both_reports_and_charts(quick_reports):
    for name in ("speed_accuracy.png", "speed_scaling.png"):
        assert (quick_reports / name).read_bytes()[:8] == PNG
    text = (quick_reports / "speed_accuracy.md").read_text()
    assert "## Targets" in text and "batched time per state, panda" in text
    for name in backends.names():
        assert f"| panda | 9 | {name} |" in text
    assert (quick_reports / "stability.md").exists()


def test_quick_bench_measures_every_backend_on_every_scene(quick_reports):
    results = json.loads((quick_reports / "speed_accuracy.json").read_text())
    rows = results["measurements"]
    assert {(r["backend"], r["scene"]) for r in rows} == {
        (n, s.label) for n in backends.names() for s in bench.QUICK.scenes}
    for r in rows:
        assert 0 < r["aba_s"] and 0 < r["batch_s"] and 0 < r["single_s"]
        assert r["own_batch"], f"{r['backend']} has no split_batch of its own"
        # every backend is accurate at the quick states it does not flag (double precision, far from singularities)
        for quantity, worst in r["error_max"].items():
            assert worst == worst and worst < 1e-11, (r["backend"], r["scene"], quantity, worst)
    # the general 3-D rewrite of a scene gives every backend the same answers (NaN only where both are NaN)
    assert {r["backend"] for r in results["representations"]} == set(backends.names())
    for r in results["representations"]:
        assert r["difference"] < 1e-12, r


def _shifted(formalism: Formalism, relative: float) -> Formalism:
    """``formalism`` with its drift and total off by ``relative`` of their size (an injected error)."""
    def split(model, q, qd, u):
        s = formalism.split(model, q, qd, u)
        return dataclasses.replace(s, drift=s.drift * (1 + relative), total=s.total * (1 + relative))
    return Formalism(f"{formalism.name}-shifted", "", split)


def test_errors_measure_an_injected_error():
    model = cases.load("double_pendulum")
    Q, QD, U = bench.states(model, 3, "double_pendulum")
    exact = [precise.split(model, *s) for s in zip(Q, QD, U)]
    median, worst, flagged = bench.errors(_shifted(backends.get("pinocchio"), 1e-7), model, Q, QD, U, exact)
    assert 0.5e-7 < median["drift"] <= worst["drift"] < 2e-7
    assert median["ctrl"] < 1e-14 and flagged == 0


def test_errors_leave_out_breakdown_states():
    """Operational space is singular at the stretched double pendulum (state 0, q = 0): not counted, but reported."""
    model = cases.load("double_pendulum")
    Q, QD, U = bench.states(model, 3, "double_pendulum")
    assert np.all(Q[0] == 0.0)
    exact = [precise.split(model, *s) for s in zip(Q, QD, U)]
    median, worst, flagged = bench.errors(backends.get("operational_space"), model, Q, QD, U, exact)
    assert flagged == 1
    assert np.isfinite(worst["total"]) and worst["total"] < 1e-12


def test_per_call_runs_at_least_min_time():
    calls = []
    seconds = bench.per_call(lambda x: calls.append(x), [(1,), (2,)], min_time=0.01, repeats=2)
    assert seconds > 0 and len(calls) >= 4 and len(calls) % 2 == 0


@pytest.mark.parametrize("case", cases.names())
def test_general_3d_is_the_same_scene(case):
    """Turning every body frame changes the model's numbers, not its physics: equal drift, ctrl, total, lam."""
    minimal = cases.load(case)
    general = general_3d(minimal, seed=1)
    assert general.digest() != minimal.digest() or len(minimal.bodies) == len(minimal.group_joints)
    assert not any(np.array_equal(a.axis, b.axis) for a, b in zip(minimal.bodies, general.bodies)
                   if a.joint in ("revolute", "prismatic"))
    for s in sampling.sample_states(minimal, 3, 1, case):
        a, b = reference.split(minimal, s.q, s.qd, s.u), reference.split(general, s.q, s.qd, s.u)
        for name in ("drift", "ctrl", "total"):
            assert np.max(np.abs(getattr(a, name) - getattr(b, name))) <= 1e-12 * a.accel_scale
        if minimal.k:
            assert np.max(np.abs(a.lam - b.lam)) <= 1e-12 * a.lam_scale


def test_bench_rejects_an_unknown_backend(capsys):
    assert main(["bench", "--quick", "--formalism", "nope", "--out", "/nonexistent"]) == 2
    assert "unknown formalism 'nope'" in capsys.readouterr().err
