"""A fault in code every backend shares between the two sides of a chart or frame check (the chart map, the frame move)
is blamed on that code, not on a backend (``crosscheck.core.compare``, shared code); a fault in one backend's
chart-native evaluation is still blamed on that backend."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from crosscheck import backends
from crosscheck.core.compare import DISAGREE, compare, suspect, suspects, vote
from crosscheck.core.sampling import sample_states
from crosscheck.engine.evaluation import CaseSetup
from crosscheck.engine.specs import CaseSpec, Checks
from crosscheck.faults import common_mode

ALL = [backends.get(name) for name in backends.names()]


def _failing(backends_, checks: Checks, states: int = 2, case: str = "double_pendulum"):
    """Every failing check of the first ``states`` states of ``case``: (key, comparison)."""
    setup = CaseSetup.build(CaseSpec(case), 0, checks)
    found = []
    for state in sample_states(setup.model, states, 0, case):
        outcome = setup.evaluate(state, backends_)
        found += [(key, c) for key, c in outcome.checks.items() if c.verdict == DISAGREE]
    return found


# ------------------------------------------------------------------------------------------- the vote itself


def test_a_disagreement_along_the_shared_code_names_it():
    values = {"a": [1.0], "b": [1.0], "c": [1.0], "a@x": [2.0], "b@x": [2.0]}
    comp = compare("drift", values, 1e-9, shared="chart map x")
    assert comp.outlier == "chart map x" and comp.shared == "chart map x" and suspect(comp) == "chart map x"
    assert vote(comp).startswith("outlier chart map x (shared code) — every backend moves together: the 2 voters "
                                 "a@x, b@x agree with each other against the 3 others")
    assert suspects([comp]).by_backend == {"chart map x": 1}


def test_one_voter_alone_on_its_side_names_neither_it_nor_the_shared_code():
    comp = compare("drift", {"a": [1.0], "b": [1.0], "c": [1.0], "a@x": [2.0]}, 1e-9, shared="chart map x")
    assert comp.outlier is None and comp.shared == "chart map x" and suspect(comp) is None
    assert vote(comp).startswith("chart map x (shared code) or a@x, the only voter on its side")
    assert compare("drift", {"a": [1.0], "b": [1.0], "c": [1.0], "a@x": [2.0]}, 1e-9).outlier == "a@x"   # no shared


def test_one_backend_off_is_still_its_outlier():
    values = {"a": [1.0], "b": [1.0], "c": [1.0], "a@x": [1.0], "b@x": [2.0]}
    comp = compare("drift", values, 1e-9, shared="chart map x")
    assert comp.outlier == "b@x" and comp.shared is None and suspect(comp) == "b"
    spread = compare("drift", {"a": [1.0], "b": [3.0], "a@x": [2.0], "b@x": [2.0]}, 1e-9, shared="chart map x")
    assert spread.shared is None and spread.outlier is None       # the plain side disagrees within: not the map


# ------------------------------------------------------------------------------------------- in the gate's checks


def test_a_chart_map_fault_is_blamed_on_the_chart_map():
    """``charts-rate-term-dropped``: every joint-chart answer is mapped without its rate term, so the mapped answers
    agree with each other against the chart-native ones (Euler–Lagrange's and the geometric backend's)."""
    with common_mode.injected(common_mode.get("charts-rate-term-dropped")):
        failing = _failing(ALL, Checks(frames=0, conservation=False, linearization=False))
    assert failing and all(key.startswith("chart ") for key, _ in failing)
    for key, comp in failing:
        chart = key.split(":")[0].split(" ", 1)[1]
        assert comp.outlier == f"chart map {chart}" and suspect(comp) == f"chart map {chart}", (key, vote(comp))
        assert f"outlier chart map {chart} (shared code) — every backend moves together" in vote(comp)


def test_a_frame_move_fault_is_blamed_on_the_frame_move():
    """``frames-gravity-not-rotated``: every backend's answer in the moved scene agrees with the other moved ones
    against the original ones, and the frame laws (one backend's check each) follow the state's other frame checks.
    The closed form, bound to its case, answers the original scene's answer in the moved one: it stands on the
    original side."""
    with common_mode.injected(common_mode.get("frames-gravity-not-rotated")):
        failing = _failing([*ALL], Checks(charts=False, conservation=False, linearization=False, closed_forms=True))
    assert any(key.startswith("frame: ") for key, _ in failing) and any(key.startswith("frame law: ")
                                                                       for key, _ in failing)
    for key, comp in failing:
        assert suspect(comp) is not None and suspect(comp).startswith("frame move g"), (key, vote(comp))
        assert "(shared code) — every backend moves together" in vote(comp)


def test_one_backends_chart_native_fault_is_still_blamed_on_it():
    geometric = backends.get("geometric")

    def off(model, chart, p, pd, tau):
        split = geometric.split_chart(model, chart, p, pd, tau)
        return dataclasses.replace(split, drift=1.001 * np.asarray(split.drift))

    chosen = [dataclasses.replace(b, split_chart=off) if b.name == "geometric" else b for b in ALL]
    failing = _failing(chosen, Checks(frames=0, conservation=False, linearization=False))
    assert failing and {suspect(c) for _, c in failing} == {"geometric"}
    assert all(c.shared is None and c.outlier.startswith("geometric@") for _, c in failing)


@pytest.mark.parametrize("fault", ["charts-rate-term-dropped"])
def test_a_lone_chart_native_backend_is_not_blamed_for_the_map(fault):
    """With one chart-capable backend (the geometric one left out), a chart map fault leaves it alone against every
    mapped answer: the vote cannot tell its chart-native evaluation from the map and names neither (it named the
    backend before)."""
    chosen = [b for b in ALL if b.name != "geometric"]
    with common_mode.injected(common_mode.get(fault)):
        failing = _failing(chosen, Checks(frames=0, conservation=False, linearization=False))
    assert failing
    for key, comp in failing:
        assert comp.outlier is None and suspect(comp) is None, (key, vote(comp))
        assert "(shared code) or euler_lagrange@" in vote(comp)


def test_the_report_says_the_shared_map_moved_every_backend_together():
    from crosscheck.engine.run import run_gate
    from crosscheck.reports import diagnosis, gate_summary

    with common_mode.injected(common_mode.get("charts-rate-term-dropped")):
        result = run_gate([CaseSpec("double_pendulum")], ALL, samples=2, seed=0,
                          checks=Checks(frames=0, conservation=False, linearization=False, self_test=False))
        diagnosis.annotate(result, ALL)
    text = gate_summary.render(result, "cmd")
    assert "- **chart nonlinear: drift**: DISAGREE (gross)" in text
    assert "; outlier chart map nonlinear (shared code) — every backend moves together: the 2 voters " \
           "euler_lagrange@nonlinear, geometric@nonlinear agree with each other against the" in text
    assert "| double_pendulum | chart map nonlinear |" in text                  # the suspects table
    hint = next(s.hint for s in result.cases[0].states if s.failed)
    assert "pointing at the chart map nonlinear (shared code) — every backend moves together" in hint
