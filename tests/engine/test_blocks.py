"""The harness's block path (``crosscheck.engine``): a case's states evaluated in blocks give the outcomes of one state
at a time, and a backend's block form (``formalisms.interface.with_block_form``) returns ``split``'s numbers."""

from __future__ import annotations

import dataclasses
from collections.abc import Mapping

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

import cases
import formalisms.newton_euler as ne
import formalisms.operational_space as ops
from crosscheck import backends, testing
from crosscheck.checks import charts, frames
from crosscheck.campaigns.fuzz import chunk
from crosscheck.engine import evaluation
from crosscheck.engine import run
from crosscheck.engine.specs import CaseSpec, Checks
from crosscheck.engine.run import run_gate
from crosscheck.reports.gate_summary import render
from crosscheck.core.sampling import sample_states
from formalisms.interface import Formalism, block_form, with_block_form


def differences(a, b, path: str = "split") -> list[str]:
    """Where two splits (or any of their parts) are not the same bits: arrays equal entry by entry with the signs of
    zeros (NaN equal to NaN), floats likewise, dataclasses, mappings and tuples part by part, the types equal."""
    if type(a) is not type(b):
        return [f"{path}: {type(a).__name__} against {type(b).__name__}"]
    if dataclasses.is_dataclass(a):
        return [d for f in dataclasses.fields(a) for d in differences(getattr(a, f.name), getattr(b, f.name),
                                                                      f"{path}.{f.name}")]
    if isinstance(a, Mapping):
        if list(a) != list(b):
            return [f"{path}: keys {list(a)} against {list(b)}"]
        return [d for key in a for d in differences(a[key], b[key], f"{path}[{key}]")]
    if isinstance(a, tuple):
        return [d for k, (x, y) in enumerate(zip(a, b, strict=True)) for d in differences(x, y, f"{path}[{k}]")]
    if isinstance(a, (np.ndarray, float, np.floating)):
        x, y = np.asarray(a), np.asarray(b)
        same = (x.shape == y.shape and x.dtype == y.dtype and np.array_equal(x, y, equal_nan=True)
                and np.array_equal(np.signbit(x) | np.isnan(x), np.signbit(y) | np.isnan(y)))
        return [] if same else [f"{path}: {x!r} against {y!r}"]
    return [] if a is b or a == b else [f"{path}: {a!r} against {b!r}"]


def _rows(model, states):
    return [np.array([getattr(s, name) for s in states], dtype=float).reshape(len(states), width)
            for name, width in (("q", model.nq), ("qd", model.nv), ("u", model.m))]


BLOCKWISE = ["operational_space", "screw"]


#: Sub-blocks of a sequence of states (slices): the whole, without its first, every other, a short one in the middle,
#: so that a state is checked first, last and inside blocks of several lengths (a stack's rounding can depend on both).
SUB_BLOCKS = (slice(None), slice(1, None), slice(None, None, 2), slice(2, 5))


def _check_blocks(backend, model, states) -> None:
    """Every state of every sub-block: the block form's element is ``split``'s, bit for bit."""
    alone = [backend.split(model, state.q, state.qd, state.u) for state in states]
    for part in SUB_BLOCKS:
        rows = block_form(backend)(model, *_rows(model, states[part]))
        assert len(rows) == len(states[part])
        for row, single in zip(rows, alone[part]):
            assert differences(row, single) == [], part


@pytest.mark.parametrize("name", BLOCKWISE)
@pytest.mark.parametrize("case", cases.names())
def test_a_block_form_gives_split_bit_for_bit(name, case):
    """Every field and extra of every state, in the case's own scene (with the gate's seeded states) and moved."""
    backend, model = backends.get(name), cases.load(case)
    states = sample_states(model, 8, 1, case)
    for scene in (model, evaluation.CaseSetup.build(CaseSpec(case), 1).scenes[0][1]):
        _check_blocks(backend, scene, states)


@pytest.mark.parametrize("name", BLOCKWISE)
@settings(max_examples=15, deadline=None, database=None, suppress_health_check=list(HealthCheck))
@given(data=st.data())
def test_a_block_form_gives_split_bit_for_bit_on_drawn_models(name, data):
    """Random mechanisms (group joints, constraints, any input map) as the fuzzer draws them."""
    model = data.draw(testing.models(4, None, group=True), label="model")
    _check_blocks(backends.get(name), model, [data.draw(testing.states(model, i), label=f"state {i}")
                                               for i in range(6)])


def test_a_wrapped_split_has_no_block_form():
    """The block form is the split function's own: a backend whose split is replaced (a plugin's check, a test's
    altered backend) is evaluated state by state, so its block cannot bypass the replacement."""
    backend = backends.get("operational_space")
    assert block_form(backend) is ops.split_many
    assert block_form(dataclasses.replace(backend, split=lambda *args: backend.split(*args))) is None
    assert block_form(backends.get("newton_euler")) is None


def _report(specs, chosen, samples: int = 7, seed: int = 2) -> str:
    """The gate's report on ``specs`` without the self-test and the timings."""
    result = run_gate(specs, chosen, samples, seed, checks=Checks(self_test=False))
    return render(result, "crosscheck gate").split("## Timing")[0]


def _raising_split(model, q, qd, u):
    """Operational space, except that it raises where the first coordinate is positive."""
    if q[0] > 0.0:
        raise ValueError(f"refused q[0] = {q[0]}")
    return ops.split(model, q, qd, u)


def _raising_many(model, Q, QD, U):  # noqa: N803
    return [_raising_split(model, q, qd, u) for q, qd, u in zip(Q, QD, U)]


RAISING = Formalism("operational_space", "raises where q[0] > 0", with_block_form(_raising_many)(_raising_split))
PLUGIN = Formalism("plugin", "Newton–Euler behind a plugin's split alone", lambda *args: ne.split(*args))


@pytest.mark.parametrize("specs", [
    [CaseSpec("double_pendulum"), CaseSpec("four_bar")],            # closed forms, charts; a loop
    [CaseSpec("geared_pendulums"), CaseSpec("ball_pendulum")],      # a coupling; a ball joint (group charts)
])
def test_blocks_give_the_report_of_one_state_at_a_time(specs, monkeypatch):
    """Blocks of three states (the moved scenes' states grouped by frame) against one state per block: the same
    report, a backend raising at some states of a block, a plugin without a block form and Pinocchio included."""
    chosen = [backends.get(name) for name in ("euler_lagrange", "screw", "geometric", "pinocchio")] + [RAISING, PLUGIN]
    monkeypatch.setattr(run, "BLOCK", 3)
    blocks = _report(specs, chosen)
    monkeypatch.setattr(run, "BLOCK", 1)
    assert _report(specs, chosen) == blocks
    assert "ValueError: refused q[0]" in blocks


def test_a_block_form_is_used_and_states_complete_in_order(monkeypatch):
    """The gate calls a block form once per block of several states (in the joint chart and per moved scene), never
    for a lone state; ``progress`` is told each state as it completes (:class:`gate.Step`)."""
    calls = []

    def many(model, Q, QD, U):  # noqa: N803
        calls.append((model.name, len(Q)))
        return ops.split_many(model, Q, QD, U)

    def split(model, q, qd, u):
        return ops.split(model, q, qd, u)

    counted = Formalism("operational_space", "counted", with_block_form(many)(split))
    done = []
    monkeypatch.setattr(run, "BLOCK", 4)
    run.run_case(CaseSpec("acrobot"), [counted, backends.get("pinocchio")], samples=9, seed=0,
                  progress=lambda step: done.append((step.case, step.done)), checks=Checks(charts=False))
    assert done == sorted(done) and set(done) == {("acrobot", k) for k in range(10)}
    assert sorted(calls) == sorted([("acrobot", 4), ("acrobot", 4), ("acrobot@g0", 2), ("acrobot@g1", 2),
                                    ("acrobot@g0", 2), ("acrobot@g1", 2)])


def _seen(outcome) -> tuple:
    """Everything a state's outcome says: its comparisons and checks (every ratio, as repr), errors and breakdowns."""
    return repr(outcome.comparisons), repr(outcome.checks), outcome.errors, outcome.breakdowns


def test_the_fuzzers_block_gives_the_outcomes_of_one_state_at_a_time():
    """A fuzzing example's states as one block (joint chart and moved scene) against one state at a time, with a
    backend that raises at some of them."""
    model = cases.load("four_bar")
    states = sample_states(model, 5, 4, "four_bar")
    chart, frame = charts.get("affine", model, 4), frames.sampled(4, "four_bar", 1)[0]
    chosen = [backends.get("euler_lagrange"), backends.get("pinocchio"), RAISING, PLUGIN]
    every = {"charts": True, "frames": True, "conservation": True}
    block = list(chunk.evaluate_block(model, states, chart, frame, chosen, every))
    alone = [chunk.evaluate(model, state, chart, frame, chosen, every) for state in states]
    assert [_seen(o) for o in block] == [_seen(o) for o in alone]
    assert any("operational_space" in o.errors for o in block)
