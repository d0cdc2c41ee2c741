"""The screw backend's linearization (article 4.8, eq. 11; ``formalisms.screw.derivatives``) and the drift's parts
(article 4.5-4.6: ``zvcf``, ``drift_velocity``), against references outside the backend:

* unconstrained models (named and drawn, with spherical and free joints): Pinocchio's ABA derivatives
  (``crosscheck.references.pinocchio.reference.linearize``, same right-perturbation convention), to 1e-9 relative per block;
* constrained models (panda's finger mimic, the four-bar, the slider-crank, circles, closed loops, drawn ones): central
  differences of the reference's KKT solution (``crosscheck.references.pinocchio.reference.split(...).total``) along
  ``cases.configuration.integrate``, Richardson-extrapolated in q (truncation far below the tolerance); in v and u the
  accelerations are exactly quadratic and linear, so one central difference of unit step is exact up to rounding;
* the drift's parts add up to the drift, ``zvcf`` is ``-M^-1 g`` and ``drift_velocity`` ``-M^-1 C qd`` from the
  reference's M, C qd and g, and with constraints ``zvcf`` is the reference's drift at ``qd = 0``.
"""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest
from hypothesis import HealthCheck, assume, given, settings
from hypothesis import strategies as st

import cases
from cases.configuration import integrate, random_configuration
from cases.build import build_model
from crosscheck.references.pinocchio import kinematics
from crosscheck.references.pinocchio import reference
from crosscheck import testing
from crosscheck.core.sampling import sample_states
from formalisms import screw
from formalisms.interface import Linearization, StateError

UNCONSTRAINED = ("double_pendulum", "spatial_arm", "free_body", "solo12", "ball_double_pendulum", "satellite_arm")
CONSTRAINED = ("panda", "four_bar", "slider_crank", "double_pendulum_circle", "cartesian_pendulum",
               "double_pendulum_absolute_loop")


def relative(got, want) -> float:
    """Max abs error over max abs entry of the reference block (0 when both vanish)."""
    scale = np.abs(want).max()
    error = np.abs(got - want).max()
    return float(error / scale) if scale > 0.0 else float(error)


def assert_blocks(lin: Linearization, ref_rows: np.ndarray, nv: int, rel: float, noise: float = 0.0) -> None:
    """The rows ``[dvdot/dq, dvdot/dv, dvdot/du]`` of ``lin`` against the reference's, block by block: max abs error
    over max abs entry of the reference's block, or over 1e-4 of the largest block's when the block is that small (a
    block that is zero in exact arithmetic, dvdot/dv without velocities say, is rounding noise in both); ``noise``
    the reference's own absolute error (of differences), allowed on top."""
    got = np.hstack([lin.A[nv:], lin.B[nv:]])
    floor = 1e-4 * np.abs(ref_rows).max()
    for name, cols in (("dq", slice(0, nv)), ("dv", slice(nv, 2 * nv)), ("du", slice(2 * nv, None))):
        error = np.abs(got[:, cols] - ref_rows[:, cols]).max(initial=0.0)
        scale = max(np.abs(ref_rows[:, cols]).max(initial=0.0), floor)
        assert error <= rel * scale + noise, (name, error, scale, noise)


def assert_matches_differences(lin: Linearization, model, q, v, u, rel: float = 1e-8) -> None:
    """:func:`assert_blocks` against :func:`differences` at steps h and h/2, allowing ten times their disagreement
    (the differences' own rounding, amplified by 1/h) and 1e-12 of the terms summed (the accelerations, their
    derivatives and the unconstrained input response ``M^-1 B`` from the reference's M: a block that vanishes in exact
    arithmetic, ``B_c B`` with every input locked by the constraints, is their rounding)."""
    coarse, fine = differences(model, q, v, u), differences(model, q, v, u, h=5e-3)
    free_response = np.linalg.solve(kinematics.mass_matrix(model, q), model.input_map)
    summed = np.abs(lin.vdot).max() + np.abs(coarse).max() + np.abs(free_response).max(initial=0.0)
    assert_blocks(lin, coarse, model.nv, rel, noise=10 * np.abs(coarse - fine).max() + 1e-12 * summed)


def assert_matches_pinocchio(model, q, v, u, rel=1e-9) -> None:
    lin, ref = screw.linearize(model, q, v, u), reference.linearize(model, q, v, u)
    np.testing.assert_array_equal(lin.A[:model.nv], ref.A[:model.nv])         # the shared kinematic rows
    assert_blocks(lin, np.hstack([ref.A[model.nv:], ref.B[model.nv:]]), model.nv, rel)
    assert relative(lin.vdot, ref.vdot) <= 1e-10


def differences(model, q, v, u, h=1e-2) -> np.ndarray:
    """``[dvdot/dq, dvdot/dv, dvdot/du]`` of the reference's constrained total: in q central differences along
    ``integrate`` at h, h/2, h/4 combined by Richardson (error O(h^6): 1e-12 at h = 1e-2, where the rounding of the
    reference, amplified by 1/h, stays below 1e-10 on the drawn models; at 1e-3 it reached 3e-7); in v and u one
    central difference of unit step, exact for a quadratic and a linear function."""
    def f(q_, v_, u_):
        return reference.split(model, q_, v_, u_).total

    def along_q(step):
        return np.column_stack([(f(integrate(model, q, step * e), v, u) - f(integrate(model, q, -step * e), v, u))
                                / (2 * step) for e in np.eye(model.nv)])
    d1, d2, d4 = along_q(h), along_q(h / 2), along_q(h / 4)
    r1, r2 = (4 * d2 - d1) / 3, (4 * d4 - d2) / 3
    dv = np.column_stack([(f(q, v + e, u) - f(q, v - e, u)) / 2 for e in np.eye(model.nv)])
    du = np.column_stack([(f(q, v, u + e) - f(q, v, u - e)) / 2 for e in np.eye(model.m)])
    return np.hstack([(16 * r2 - r1) / 15, dv, du])


def _state(model, rng):
    return random_configuration(model, rng, 1.0, 0.3), rng.normal(size=model.nv), rng.normal(size=model.m)


@pytest.mark.parametrize("name", UNCONSTRAINED)
def test_named_models_match_pinocchios_aba_derivatives(name):
    model = cases.load(name)
    rng = np.random.default_rng(7)
    for _ in range(3):
        assert_matches_pinocchio(model, *_state(model, rng))


def test_a_state_at_rest_at_home_matches_pinocchio():
    """q at home (identity orientations, a stretched chain), qd = 0, u = 0: the velocity products vanish."""
    for name in ("solo12", "spatial_arm"):
        model = cases.load(name)
        q0 = sample_states(model, 1, 0, name)[0].q
        assert_matches_pinocchio(model, np.array(q0), np.zeros(model.nv), np.zeros(model.m))


@pytest.mark.parametrize("name", CONSTRAINED)
def test_constrained_models_match_differences_of_the_reference_kkt_solution(name):
    model = cases.load(name)
    for state in sample_states(model, 3, 5, name)[1:]:
        q, v, u = (np.array(x) for x in (state.q, state.qd, state.u))
        lin = screw.linearize(model, q, v, u)
        assert_matches_differences(lin, model, q, v, u)
        assert relative(lin.vdot, reference.split(model, q, v, u).total) <= 1e-10


_SETTINGS = dict(deadline=None, database=None, suppress_health_check=list(HealthCheck))


@settings(max_examples=25, **_SETTINGS)
@given(data=st.data())
def test_drawn_models_with_group_joints_match_pinocchio(data):
    model = data.draw(testing.models(5, False, group=True), label="model")
    state = data.draw(testing.states(model), label="state")
    assert_matches_pinocchio(model, *(np.array(x) for x in (state.q, state.qd, state.u)), rel=1e-8)


@settings(max_examples=10, **_SETTINGS)
@given(data=st.data())
def test_drawn_constrained_models_match_differences(data):
    """Independent rows only: a drawn mechanism whose rows are dependent on the manifold can have independent ones a
    step off it (the rank, and with it the function differentiated, changes inside the stencil); the redundant case
    with a constant rank is the duplicated circle below."""
    model = data.draw(testing.models(4, True, group=data.draw(st.booleans(), label="group")), label="model")
    state = data.draw(testing.states(model), label="state")
    q, v, u = (np.array(x) for x in (state.q, state.qd, state.u))
    assume(screw.split(model, q, v, u).constraint_rank == model.k)
    assert_matches_differences(screw.linearize(model, q, v, u), model, q, v, u)


def test_a_duplicated_circle_has_the_single_circles_linearization():
    """Redundant rows (rank 1 of 2 everywhere): the minimum-norm solve of the differentiated KKT system gives the
    unique derivative, the reference's differences and the single circle's."""
    single = cases.load("double_pendulum_circle")
    circle = single.constraints[0]
    twice = build_model("circle_twice", single.bodies, gravity=single.gravity, task_points=single.task_points,
                        constraints=[circle, dataclasses.replace(circle, name="again")])
    for state in sample_states(single, 3, 4, "twice")[1:]:
        q, v, u = (np.array(x) for x in (state.q, state.qd, state.u))
        lin = screw.linearize(twice, q, v, u)
        assert screw.split(twice, q, v, u).constraint_rank == 1
        assert_matches_differences(lin, twice, q, v, u)
        assert_blocks(lin, np.hstack([x[single.nv:] for x in screw.linearize(single, q, v, u)]), single.nv, 1e-12)


def test_linearize_is_registered_and_validates_the_state():
    from formalisms import get

    model = cases.load("double_pendulum")
    assert get("screw").linearize is screw.linearize
    with pytest.raises(StateError, match="qd has 3 entries"):
        screw.linearize(model, np.zeros(2), np.zeros(3), np.zeros(model.m))
    with pytest.raises(StateError, match="non-finite"):
        screw.linearize(model, [np.nan, 0.0], np.zeros(2), np.zeros(model.m))


@pytest.mark.parametrize("name", UNCONSTRAINED + CONSTRAINED)
def test_the_drift_parts_add_up_and_match_the_reference(name):
    model = cases.load(name)
    for state in sample_states(model, 4, 3, name):
        q, v, u = (np.array(x) for x in (state.q, state.qd, state.u))
        s = screw.split(model, q, v, u)
        scale = max(np.abs(s.zvcf).max(), np.abs(s.drift_velocity).max(), 1e-300)
        assert np.abs(s.drift_parts).max() <= 1e-13 * scale
        if model.constraints:
            at_rest = reference.split(model, q, np.zeros(model.nv), u).drift
            assert relative(s.zvcf, at_rest) <= 1e-11
            drift = reference.split(model, q, v, u).drift       # the difference is good to eps |drift| only
            assert np.abs(s.drift_velocity - (drift - at_rest)).max() <= 1e-11 * np.abs(drift).max()
        else:
            M = kinematics.mass_matrix(model, q)
            c_qd, g = kinematics.bias_forces(model, q, v)
            assert relative(s.zvcf, np.linalg.solve(M, -g)) <= 1e-12
            assert relative(s.drift_velocity, np.linalg.solve(M, -c_qd)) <= 1e-12
