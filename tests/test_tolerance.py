"""The tolerance scale (interface.conditioning) and the policy built on it: tight, but no false alarms where
summed terms cancel or vectors are tiny."""

from __future__ import annotations

import numpy as np
import pytest

import cases
from crosscheck import backends, tolerance
from crosscheck.compare import AGREE, DISAGREE, NOT_COMPARED, compare
from crosscheck.gate import evaluate
from crosscheck.sampling import State
from formalisms.interface import Unsupported, conditioning

ALL = [backends.get(n) for n in backends.names()]


def test_conditioning_closed_form():
    model = cases.load("double_pendulum", m1=2.0, g=3.0)
    M = np.array([[4.0, 1.0], [1.0, 2.0]])
    Cqd, g, tau, qd = np.array([0.5, -1.0]), np.array([2.0, 0.0]), np.array([0.0, -3.0]), np.array([1.0, 2.0])
    lo, hi = (6 - np.sqrt(8)) / 2, (6 + np.sqrt(8)) / 2          # eigenvalues of M
    H = 1.5 + 2.0 + 3.0 + hi * 5.0 + 3.0 * np.sqrt(3.0 * hi)     # |Cqd|_1 + |g|_1 + |tau|_1 + ... (m_total = 3)
    cond, scale = conditioning(model, M, Cqd, g, tau, qd)
    assert cond == pytest.approx(hi / lo, rel=1e-14)
    assert scale == pytest.approx(H / lo, rel=1e-14)


def _verdicts_at_task_singularity(model, q, qd, u):
    """The verdicts at a state where the arm is straight or folded (the tip's task space singular): the task-space
    inertia does not exist there, so every backend that supplies it is in BREAKDOWN for it and it is NOT COMPARED;
    returned are the verdicts of all the other quantities."""
    outcome = evaluate(model, State(0, tuple(q), tuple(qd), tuple(u)), ALL)
    assert not outcome.errors
    suppliers = [name for name, split in outcome.splits.items() if not isinstance(split.task_inertia, Unsupported)]
    assert suppliers and all(tolerance.whole(outcome.breakdowns.get(name, {}))
                             or "task_inertia" in tolerance.left_out(outcome.breakdowns.get(name, {}))
                             for name in suppliers)
    assert outcome.comparisons["task_inertia"].verdict == NOT_COMPARED
    return {k: c.verdict for k, c in outcome.comparisons.items() if k != "task_inertia"}


@pytest.mark.parametrize("q", [(1.0, 0.0), (1.0, 1e-13), (0.3, np.pi)])
def test_no_false_alarm_when_velocity_terms_cancel(q):
    """Zero gravity with the arm straight or folded: C qd cancels to rounding noise in some backends and to an
    exact zero in others; the tolerance must still cover the rounding of the terms that were summed."""
    model = cases.load("double_pendulum", m1=3.0, m2=0.25, l1=2.0, l2=0.125, g=0.0)
    assert set(_verdicts_at_task_singularity(model, q, (1.0, 0.0), (0.0, 0.0)).values()) == {AGREE}


def test_no_false_alarm_on_tiny_inputs():
    model = cases.load("double_pendulum")
    assert set(_verdicts_at_task_singularity(model, (0.0, 0.0), (0.0, 0.0), (0.0, 1e-291)).values()) == {AGREE}


def test_tolerance_still_catches_a_small_modelling_error():
    """A 1e-6 relative change in one mass is far above the tolerance: the policy is tight, not just quiet."""
    model = cases.load("double_pendulum")
    perturbed = cases.load("double_pendulum", m2=1.0 + 1e-6)
    state = State(0, (0.4, 1.1), (1.0, -2.0), (3.0, 1.0))
    good = evaluate(model, state, ALL[:1]).splits[ALL[0].name]
    bad = ALL[0].split(perturbed, state.q, state.qd, state.u)
    tol = tolerance.tolerance("total", tolerance.scales([good, bad]))
    assert compare("total", {"good": good.total, "bad": bad.total}, tol).verdict == DISAGREE
