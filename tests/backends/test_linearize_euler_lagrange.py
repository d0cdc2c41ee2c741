"""Euler–Lagrange's linearization (article 4.8, eq. 11; ``formalisms.euler_lagrange.linearize``) and the drift's parts
(``Split.zvcf``, ``Split.drift_velocity``), against references outside the backend:

* unconstrained models (revolute, spherical, free joints, drawn models) against Pinocchio's analytical ABA
  derivatives (``crosscheck.references.pinocchio.reference.linearize``, same tangent convention), 1e-8 relative per block;
* constrained models (four-bar, slider-crank, drawn models) against central differences (Richardson-extrapolated, here
  in the test only) of the reference's KKT solve along ``integrate``, 1e-7 relative;
* the drift's parts against ``-M^-1 g`` and ``-M^-1 C qd`` from the reference's M, C qd and g, adding up to the drift;
* the derivation of the linearization is lazy (never during ``split``) and cached on disk under its own key.

Every derivation goes to a scratch cache (``fresh_derivation_cache``), so the tests test the current code; the
largest (solo12, free base) takes about a second cold since the linearization differentiates the dynamics' code.
"""

from __future__ import annotations


import numpy as np
import pytest
from hypothesis import Phase, assume, given, settings
from hypothesis import strategies as st

import cases
import formalisms
import formalisms.euler_lagrange as el
from cases.configuration import integrate, random_configuration
from crosscheck.checks import charts
from crosscheck.references.pinocchio import kinematics
from crosscheck.references.pinocchio import reference
from crosscheck.core import sampling
from crosscheck.testing import models, states
from formalisms.interface import Linearization, StateError

pytestmark = pytest.mark.usefixtures("fresh_derivation_cache")
EL = formalisms.get("euler_lagrange")
#: A drawn model's derivation takes a second or more, so a failure is reported as drawn, not shrunk for minutes.
NO_SHRINK = (Phase.explicit, Phase.reuse, Phase.generate)


@pytest.fixture(autouse=True, scope="module")
def fresh_linear_code():
    """The in-memory linearization code is derived afresh too (the disk cache is the scratch one)."""
    el._linear_code.cache_clear()
    yield
    el._linear_code.cache_clear()


def _relative(got: np.ndarray, want: np.ndarray, floor: float) -> float:
    """max |got - want| / max |want|, the block's scale at least ``floor`` (a block that is 0 but for rounding)."""
    return float(np.abs(got - want).max() / max(np.abs(want).max(), floor))


def _blocks(model, lin: Linearization, want: Linearization) -> dict:
    """The relative error of each block; a block's scale is at least 1e-6 of the largest entry of the dynamics'
    rows (``[dvdot/dq, dvdot/dv, dvdot/du]``), below which entries are rounding."""
    n = model.nv
    floor = 1e-6 * max(np.abs(want.A[n:]).max(), np.abs(want.B).max(), np.abs(want.A[:n]).max(), 1e-300)
    return {"kinematics": _relative(lin.A[:n], want.A[:n], floor),
            "dvdot/dq": _relative(lin.A[n:, :n], want.A[n:, :n], floor),
            "dvdot/dv": _relative(lin.A[n:, n:], want.A[n:, n:], floor), "dvdot/du": _relative(lin.B, want.B, floor)}


def _state(model, seed: int):
    rng = np.random.default_rng(seed)
    q, v, u = random_configuration(model, rng, 1.0, 0.3), rng.normal(size=model.nv), rng.normal(size=model.m)
    if model.constraints:
        q, v = sampling.admissible(model, q, v, rng)
    return q, v, u


def _against_pinocchio(model, q, v, u) -> None:
    lin, want = EL.linearize(model, q, v, u), reference.linearize(model, q, v, u)
    errors = _blocks(model, lin, want)
    assert max(errors.values()) <= 1e-8, f"{model.name}: relative errors {errors}"
    scale = max(np.abs(want.vdot).max(), np.linalg.norm(model.gravity), 1.0)
    assert np.abs(lin.vdot - want.vdot).max() <= 1e-10 * scale


def _central_differences(model, q, v, u, h=1e-6) -> np.ndarray:
    """``[dvdot/dq, dvdot/dv, dvdot/du]`` of the reference's constrained split, by central differences along
    ``integrate`` (the tangent convention)."""
    def f(q, v, u):
        return reference.split(model, q, v, u).total
    cols = [(f(integrate(model, q, h * e), v, u) - f(integrate(model, q, -h * e), v, u)) / (2 * h)
            for e in np.eye(model.nv)]
    cols += [(f(q, v + h * e, u) - f(q, v - h * e, u)) / (2 * h) for e in np.eye(model.nv)]
    cols += [(f(q, v, u + h * e) - f(q, v, u - h * e)) / (2 * h) for e in np.eye(model.m)]
    return np.column_stack(cols)


def _rank_is_locally_constant(model, q, h=1e-6) -> bool:
    """The rank of the reference's Jc is the same at q and along every ``integrate`` step of the differences: where a
    row degenerates at q only, vdot has no derivative (the contract's "while the rank is locally constant")."""
    def rank(q):
        sigma = np.linalg.svd(kinematics.constraint_kinematics(model, q, np.zeros(model.nv))[1], compute_uv=False)
        return int(np.sum(sigma > 1e-6 * model.length_scale))
    at = rank(q)
    return all(rank(integrate(model, q, s * e)) == at for e in np.eye(model.nv) for s in (h, -h))


def _against_differences(model, q, v, u) -> None:
    """Each block within 1e-7 of the differences' largest entry, with a floor of 1e-8 times the largest entry of all
    blocks (the differences' rounding where a block is exactly 0). The differences are Richardson's extrapolation of
    central ones (h = 1e-3 and 5e-4: truncation O(h^4), rounding ``eps |vdot| / h``); with h = 1e-6 alone the rounding
    of the reference's KKT solve reached 4e-8 of a block (a drawn model with a point on a line)."""
    lin, n = EL.linearize(model, q, v, u), model.nv
    fd = (4.0 * _central_differences(model, q, v, u, 5e-4) - _central_differences(model, q, v, u, 1e-3)) / 3.0
    got = np.hstack([lin.A[n:], lin.B[n:]])
    floor = 1e-8 * max(np.abs(fd).max(), np.abs(lin.vdot).max())
    for label, cols in (("dvdot/dq", slice(0, n)), ("dvdot/dv", slice(n, 2 * n)), ("dvdot/du", slice(2 * n, None))):
        error = np.abs(got[:, cols] - fd[:, cols]).max()
        assert error <= max(1e-7 * np.abs(fd[:, cols]).max(), floor), f"{model.name} {label}: {error:.3g}"
    np.testing.assert_array_equal(lin.A[:n, n:], np.eye(n))
    np.testing.assert_array_equal(lin.B[:n], 0.0)
    np.testing.assert_allclose(lin.vdot, reference.split(model, q, v, u).total, rtol=0,
                               atol=1e-10 * np.abs(lin.vdot).max())


@pytest.mark.parametrize("name", ["double_pendulum", "free_body", "ball_double_pendulum"])
def test_linearize_matches_pinocchio(name):
    """A, B against Pinocchio's ABA derivatives: revolute joints, a free body (``-ad_v`` kinematics, the chain rule
    of the local chart on SE(3)) and spherical joints (on SO(3)), at a state with an input."""
    model = cases.load(name)
    _against_pinocchio(model, *_state(model, 1))


def test_linearize_matches_pinocchio_at_a_second_state_and_without_input():
    """The same model, another state and u = 0 (the drift's linearization): the code derived once serves both."""
    model = cases.load("ball_double_pendulum")
    q, v, _ = _state(model, 7)
    _against_pinocchio(model, q, 3.0 * v, np.zeros(model.m))


@pytest.mark.parametrize("name", ["four_bar", "slider_crank"])
def test_constrained_linearize_matches_central_differences(name):
    """Closed loops: the differentiated KKT system against central differences of the reference's KKT solve."""
    model = cases.load(name)
    _against_differences(model, *_state(model, 2))


@settings(max_examples=4, phases=NO_SHRINK)
@given(data=st.data())
def test_drawn_models_match_pinocchio(data):
    """Drawn trees (revolute, prismatic, spherical and free joints, dense input maps, random gravity)."""
    model = data.draw(models(max_bodies=3, group=True))
    s = data.draw(states(model))
    _against_pinocchio(model, np.array(s.q), np.array(s.qd), np.array(s.u))


@settings(max_examples=6, phases=NO_SHRINK)
@given(data=st.data())
def test_drawn_constrained_models_match_central_differences(data):
    """Drawn trees with drawn constraints (couplings, coincident points, points on circles and lines)."""
    model = data.draw(models(max_bodies=3, constraints=True))
    s = data.draw(states(model))
    assume(_rank_is_locally_constant(model, np.array(s.q)))
    _against_differences(model, np.array(s.q), np.array(s.qd), np.array(s.u))


def test_panda_with_its_finger_coupling_matches_central_differences():
    """The issue's named robot, always (about 13 s of cold derivation); the larger models below are opt-in."""
    model = cases.load("panda")
    _against_differences(model, *_state(model, 3))


@pytest.mark.parametrize("name", ["solo12", "spatial_arm", "satellite_arm"])
def test_large_models_match_pinocchio(name):
    model = cases.load(name)
    _against_pinocchio(model, *_state(model, 4))


def test_the_linearization_differentiates_the_dynamics_own_code():
    """Without group joints the linearization derives nothing: it differentiates the code ``split`` runs (the
    dynamics' cache entry, no file of its own)."""
    model = cases.load("n_link_pendulum", n=3)  # no other test here derives it
    q, v, u = _state(model, 5)
    EL.split(model, q, v, u)
    files = set(el._cache_dir().iterdir())
    EL.linearize(model, q, v, u)
    assert set(el._cache_dir().iterdir()) == files
    assert not (el._cache_dir() / f"{el.linearization_key(model)}.py").exists()


def test_the_local_program_is_derived_lazily_and_cached_under_its_own_key():
    """With group joints the joint chart's code is evaluated at xi = 0, so the linearization has its own program (xi
    among the inputs): ``split`` never derives it; the first ``linearize`` does, once, into the disk cache under
    ``linearization_key`` (distinct from the dynamics' key); a second call is served from memory, and a process
    without the memory cache reads the disk and gives the same numbers."""
    model = cases.load("ball_pendulum")  # no other test here linearizes it
    q, v, u = _state(model, 5)
    path = el._cache_dir() / f"{el.linearization_key(model)}.py"
    before = el._linear_code.cache_info()
    EL.split(model, q, v, u)
    assert el._linear_code.cache_info() == before and not path.exists()
    first = EL.linearize(model, q, v, u)
    assert path.exists() and el.linearization_key(model) != el.cache_key(model)
    assert "for the linearization" in path.read_text().splitlines()[0]
    EL.linearize(model, q, v, u)
    assert el._linear_code.cache_info().misses == before.misses + 1
    el._linear_code.cache_clear()
    again = EL.linearize(model, q, v, u)
    np.testing.assert_array_equal(again.A, first.A)
    np.testing.assert_array_equal(again.B, first.B)


def test_linearize_rejects_bad_states():
    model = cases.load("double_pendulum")
    with pytest.raises(StateError, match="q has 3 entries"):
        EL.linearize(model, np.zeros(3), np.zeros(2), np.zeros(model.m))
    with pytest.raises(StateError, match="non-finite"):
        EL.linearize(model, np.zeros(2), np.array([0.0, np.nan]), np.zeros(model.m))


@pytest.mark.parametrize("name", ["double_pendulum", "free_body", "ball_double_pendulum"])
def test_drift_parts_are_the_references_gravity_and_velocity_parts(name):
    """``zvcf = -M^-1 g`` and ``drift_velocity = -M^-1 C qd`` with Pinocchio's M, g and C qd; they add up to the drift
    to rounding (``Split.drift_parts``)."""
    model = cases.load(name)
    q, v, u = _state(model, 6)
    s = EL.split(model, q, v, u)
    M = kinematics.mass_matrix(model, q)
    Cqd, g = kinematics.bias_forces(model, q, v)
    np.testing.assert_allclose(s.zvcf, -np.linalg.solve(M, g), rtol=0, atol=1e-10 * np.abs(s.zvcf).max())
    np.testing.assert_allclose(s.drift_velocity, -np.linalg.solve(M, Cqd), rtol=0,
                               atol=1e-10 * np.abs(s.drift_velocity).max())
    assert np.abs(s.drift_parts).max() <= 1e-13 * np.abs(s.drift).max()


@pytest.mark.parametrize("name", ["four_bar", "slider_crank"])
def test_constrained_drift_parts(name):
    """With constraints: ``zvcf`` is the reference's drift at ``qd = 0`` (the KKT solve with ``f = -g``, no bias), and
    the parts add up to the drift to rounding."""
    model = cases.load(name)
    q, v, u = _state(model, 8)
    s = EL.split(model, q, v, u)
    at_rest = reference.split(model, q, np.zeros(model.nv), np.zeros(model.m)).drift
    np.testing.assert_allclose(s.zvcf, at_rest, rtol=0, atol=1e-10 * np.abs(at_rest).max())
    assert np.abs(s.drift_parts).max() <= 1e-13 * max(np.abs(s.drift).max(), np.abs(s.zvcf).max())


def test_drift_parts_in_a_chart():
    """``split_chart`` fills the parts too: the chart's own ``-M_p^-1 g_p`` is the zero-velocity drift in the chart, and
    the parts add up to the chart's drift."""
    model = cases.load("double_pendulum")
    chart = charts.absolute(model)
    p, pd = np.array([0.3, -1.1]), np.array([0.8, 1.9])
    s = EL.split_chart(model, chart, p, pd, np.zeros(model.n))
    rest = EL.split_chart(model, chart, p, np.zeros(model.n), np.zeros(model.n))
    np.testing.assert_allclose(s.zvcf, rest.drift, rtol=0, atol=1e-13 * np.abs(rest.drift).max())
    assert np.abs(s.drift_parts).max() <= 1e-13 * np.abs(s.drift).max()


@pytest.mark.parametrize("name", ["double_pendulum"])  # spatial_arm in a dense chart: minutes to derive
def test_linearize_chart_in_an_affine_chart_is_the_references_mapped(name):
    """In ``q = A p + b``: ``pdd = A^-1 qdd`` with ``tau_q = A^-T tau_p``, so ``dpdd/dp = A^-1 (dvdot/dq) A``,
    ``dpdd/dpd = A^-1 (dvdot/dv) A`` and ``dpdd/dtau_p = A^-1 M^-1 A^-T``, from Pinocchio's derivatives and M; the
    chart's derivation is EL's own (M_p, C_p pd, g_p differentiated in p), nothing mapped."""
    model = cases.load(name)
    chart = charts.random_affine(model, 0, name)
    A, b = np.asarray(chart.A), np.asarray(chart.b)
    rng = np.random.default_rng(9)
    p, pd, tau_p = rng.normal(size=model.n), rng.normal(size=model.n), rng.normal(size=model.n)
    q, qd, tau_q = A @ p + b, A @ pd, np.linalg.solve(A.T, tau_p)
    u = np.linalg.lstsq(model.input_map, tau_q, rcond=None)[0]
    assert np.allclose(model.input_map @ u, tau_q)
    ref, n = reference.linearize(model, q, qd, u), model.n
    Ainv = np.linalg.inv(A)
    want_A = np.block([[np.zeros((n, n)), np.eye(n)], [Ainv @ ref.A[n:, :n] @ A, Ainv @ ref.A[n:, n:] @ A]])
    want_B = np.vstack([np.zeros((n, n)), Ainv @ np.linalg.inv(kinematics.mass_matrix(model, q)) @ Ainv.T])
    lin = EL.linearize_chart(model, chart, p, pd, tau_p)
    assert lin.A.shape == (2 * n, 2 * n) and lin.B.shape == (2 * n, n)
    assert _relative(lin.A[n:, :n], want_A[n:, :n], 1e-300) <= 1e-8
    assert _relative(lin.A[n:, n:], want_A[n:, n:], 1e-300) <= 1e-8
    assert _relative(lin.B, want_B, 1e-300) <= 1e-8
    np.testing.assert_array_equal(lin.A[:n], want_A[:n])
    np.testing.assert_allclose(lin.vdot, Ainv @ ref.vdot, rtol=0, atol=1e-10 * np.abs(ref.vdot).max())


def test_linearize_chart_refuses_a_velocity_representation():
    model = cases.load("free_body")
    with pytest.raises(formalisms.interface.ModelNotSupported, match="velocity representation"):
        EL.linearize_chart(model, charts.velocity_representation(model, "world"), np.zeros(model.nq),
                           np.zeros(model.nv), np.zeros(model.nv))
