"""``split_batch(model, Q, QD, U)`` equals ``split`` state by state, for every backend (issue 7).

Each row of a batch must be what ``split`` returns for that state, to rounding: the accelerations within
``100 eps cond(M)`` of the state's ``accel_scale`` (the size of the terms summed,
``Split.accel_scale``) and the multipliers within as much of ``lam_scale``: the harness's own
bound on two correct solves of one problem. Measured on the built-in cases the largest difference is 4e-15 of
``accel_scale`` (Pinocchio's batched ABA against its Cholesky solve), 1e-16 for the five formalisms; a row off by
1e-8 of its size fails.
"""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

import cases
from crosscheck import backends, testing
from crosscheck.core import sampling
from formalisms.interface import StateError

BATCHED = [name for name in backends.names() if backends.get(name).split_batch is not None]
SAMPLES = 12
#: Rounding allowed between a batch row and ``split``, in units of ``cond(M)`` times the state's scale.
RTOL = 100 * np.finfo(float).eps


def _states(model, case: str, count: int = SAMPLES):
    states = sampling.sample_states(model, count, seed=3, case=case)
    return tuple(np.array([getattr(s, f) for s in states]) for f in ("q", "qd", "u"))


def _difference(row: np.ndarray, value: np.ndarray) -> float:
    """Largest difference of a batch row from ``split``'s value; NaN must sit in the same places (a backend returns
    NaN where its method breaks down, e.g. operational space at a task singularity)."""
    assert np.array_equal(np.isnan(row), np.isnan(value)), f"NaN pattern differs: {row} against {value}"
    return float(np.max(np.abs(np.where(np.isnan(value), 0.0, row - value)), initial=0.0))


def assert_rows_equal_split(formalism, model, Q, QD, U) -> None:
    batch = formalism.split_batch(model, Q, QD, U)
    assert batch.drift.shape == batch.ctrl.shape == batch.total.shape == (len(Q), model.n)
    for i in range(len(Q)):
        s = formalism.split(model, Q[i], QD[i], U[i])
        tol = RTOL * s.cond_M * s.accel_scale
        for name in ("drift", "ctrl", "total"):
            err = _difference(getattr(batch, name)[i], getattr(s, name))
            assert err <= tol, f"{formalism.name} {model.name} state {i}: {name} differs by {err:.3g} (tol {tol:.3g})"
        if model.k:
            assert batch.lam.shape == batch.lam_drift.shape == (len(Q), model.k)
            for name in ("lam", "lam_drift"):
                err = _difference(getattr(batch, name)[i], getattr(s, name))
                tol = RTOL * s.cond_M * s.lam_scale
                assert err <= tol, f"{formalism.name} {model.name} state {i}: {name} off by {err:.3g} (tol {tol:.3g})"
        else:
            assert batch.lam is None and batch.lam_drift is None


@pytest.mark.parametrize("case", cases.names())
@pytest.mark.parametrize("name", BATCHED)
def test_split_batch_rows_equal_split(name, case):
    model = cases.load(case)
    assert_rows_equal_split(backends.get(name), model, *_states(model, case))


@pytest.mark.parametrize("name", BATCHED)
def test_split_batch_mixing_ranks_of_S(name):
    """Four-bar states at rank 1 (d = 1e-6 off the change point q = (pi/2 + d, -d, pi/2 + d): the rows of S nearly
    redundant, one dropped) and rank 2, interleaved in one batch: a backend that groups states by rank (or solves
    them together) must still give each row what ``split`` gives for that state."""
    model = cases.load("four_bar")
    near = [np.array([np.pi / 2 + d, -d, np.pi / 2 + d]) for d in (1e-6, 3e-5, 1e-6)]
    Q = np.array([near[0], [1.2, -0.4, 1.9], near[1], near[2]])
    QD = np.array([[0.0, 0.0, 0.0], [0.3, 0.1, -0.2], [0.5, -0.5, 0.5], [0.5, -0.5, 0.5]])
    U = np.array([[0.5, -1.0, 2.0], [1.0, 0.0, -1.0], [0.5, -1.0, 2.0], [-2.0, 1.0, 0.5]])
    formalism = backends.get(name)
    assert [formalism.split(model, *s).constraint_rank for s in zip(Q, QD, U)] == [1, 2, 2, 1]
    assert_rows_equal_split(formalism, model, Q, QD, U)


@pytest.mark.parametrize("name", BATCHED)
@settings(max_examples=6)
@given(data=st.data())
def test_split_batch_on_drawn_models(name, data):
    model = data.draw(testing.models(max_bodies=4, constraints=None))
    states = [data.draw(testing.states(model, index=i)) for i in range(3)]
    Q, QD, U = (np.array([getattr(s, f) for s in states]) for f in ("q", "qd", "u"))
    assert_rows_equal_split(backends.get(name), model, Q, QD, U)


@pytest.mark.parametrize("name", BATCHED)
def test_split_batch_of_one_and_of_none(name):
    model = cases.load("double_pendulum")
    Q, QD, U = _states(model, "double_pendulum", 1)
    assert len(backends.get(name).split_batch(model, Q, QD, U)) == 1
    empty = backends.get(name).split_batch(model, Q[:0], QD[:0], U[:0])
    assert empty.total.shape == (0, model.n)


@pytest.mark.parametrize("name", [n for n in BATCHED if n != backends.REFERENCE_NAME])
def test_split_batch_names_a_state_whose_mass_matrix_is_singular(name):
    """The second link a point mass on its own joint axis: M is singular wherever the first joint is. The batch
    raises its ValueError for the first such state (model, q, eigenvalues), as ``split`` does.
    (Pinocchio's ABA does not factor M and is not asked to.)"""
    base = cases.load("double_pendulum")
    first, second = base.bodies
    model = cases.build_model("point_on_axis", [first, dataclasses.replace(second, com=np.zeros(3),
                                                                         inertia=np.zeros((3, 3)))],
                              gravity=base.gravity, task_points=base.task_points)
    Q = np.array([[0.3, 0.0], [0.0, 0.0]])
    with pytest.raises(ValueError, match=r"point_on_axis.*not positive definite.*q = \[0\.3, 0\.0\].*eigenvalues"):
        backends.get(name).split_batch(model, Q, Q, Q)


@pytest.mark.parametrize("name", BATCHED)
def test_split_batch_rejects_bad_shapes(name):
    model = cases.load("double_pendulum")
    Q, QD, U = _states(model, "double_pendulum", 2)
    with pytest.raises(StateError, match=r"QD must have shape \(N, 2\)"):
        backends.get(name).split_batch(model, Q, QD[:, :1], U)
    with pytest.raises(StateError, match="same number of rows"):
        backends.get(name).split_batch(model, Q, QD[:1], U)
