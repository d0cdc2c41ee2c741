"""The geometric backend's linearization (article 4.8, eq. 11; ``formalisms.interface.Linearization``) and the drift's
parts (``Split.zvcf``, ``Split.drift_velocity``; article 4.5-4.6).

References, none of them computed by the geometric backend:

* unconstrained models: Pinocchio's analytical ABA derivatives (``crosscheck.references.pinocchio.reference.linearize``, same tangent
  convention on Lie groups), on the named cases and on random models (``crosscheck.testing``);
* constrained models: central differences (in this test only) of the reference's KKT solution
  (``crosscheck.references.pinocchio.reference.split(...).total``) along ``integrate`` and in v and u; the panda (a joint coupling, so Jc
  is constant) exactly, from Pinocchio's RNEA derivatives projected onto the constraint distribution;
* charts: at an equilibrium (v = 0, drift = 0) the chart's linearization is the joint one conjugated by
  ``T = blockdiag(Dpsi, Dpsi)`` (the harness's chart maps, ``crosscheck.checks.charts``), with the same eigenvalues;
* the drift's parts: they add up to the drift, and zvcf is the reference's drift at ``qd = 0``
  (``-M^-1 g`` from Pinocchio's CRBA and gravity on an unconstrained model).
"""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

import cases
from cases.configuration import integrate, neutral, random_configuration
from crosscheck.checks import charts
from crosscheck.references.pinocchio import build
from crosscheck.references.pinocchio import kinematics
from crosscheck.references.pinocchio import reference
from crosscheck.core import sampling
from crosscheck import testing
from formalisms import geometric as geo
from formalisms.interface import Linearization, ModelNotSupported, StateError

UNCONSTRAINED = ["double_pendulum", "spatial_arm", "free_body", "solo12", "ball_double_pendulum", "satellite_arm"]
CONSTRAINED = ["four_bar", "slider_crank"]


def _relative(got: np.ndarray, want: np.ndarray, scale: float) -> float:
    """Max abs error over the largest entry of the block (at least ``scale``: a block that is exactly 0 in the
    reference, such as a free body's dvdot/dq, is measured against the dynamics rows)."""
    error = float(np.abs(got - want).max())
    return error and error / max(float(np.abs(want).max()), scale)


def _blocks(model, lin: Linearization) -> dict:
    nv = model.nv
    return {"A_qq and I": lin.A[:nv], "dvdot/dq": lin.A[nv:, :nv], "dvdot/dv": lin.A[nv:, nv:], "B": lin.B}


def _assert_agree(model, lin: Linearization, want: Linearization, tol: float, floor: float = 0.0):
    """Each block to ``tol`` relative (its largest entry, at least ``floor`` and a thousandth of the largest
    reference derivative), and vdot to 1e-10 of its size (at least ``floor``)."""
    assert lin.A.shape == want.A.shape and lin.B.shape == want.B.shape
    got, ref = _blocks(model, lin), _blocks(model, want)
    scale = max(1e-3 * max(np.abs(want.A[model.nv:]).max(), np.abs(want.B).max(initial=0.0)), floor)
    errors = {name: _relative(got[name], ref[name], scale) for name in got}
    assert max(errors.values()) <= tol, errors
    np.testing.assert_allclose(lin.vdot, want.vdot, rtol=1e-10, atol=1e-10 * max(np.abs(want.vdot).max(), floor))


def _difference_floor(model, q, v, u) -> float:
    """Central differences resolve derivatives only above their rounding, ``eps |vdot| / h`` with ``|vdot|`` up to the
    reference's ``accel_scale``: a hundredth of that scale is the smallest block size they measure to 1e-7."""
    return 1e-2 * reference.split(model, q, v, u).accel_scale


def _state(model, seed: int):
    rng = np.random.default_rng(seed)
    return random_configuration(model, rng, 1.0, 0.3), rng.normal(size=model.nv), rng.normal(size=model.m)


@pytest.mark.parametrize("name", UNCONSTRAINED)
def test_linearize_matches_pinocchio_aba_derivatives(name):
    """A and B against ``computeABADerivatives`` at two random states, to 1e-8 relative per block (measured: 2e-14)."""
    model = cases.load(name)
    for seed in (0, 1):
        q, v, u = _state(model, seed)
        _assert_agree(model, geo.linearize(model, q, v, u), reference.linearize(model, q, v, u), 1e-8)


def _central_differences(model, q, v, u, h=1e-6) -> Linearization:
    """The reference KKT solution's derivatives by central differences, along ``q (+) s e_j``, in v and in u."""
    f = lambda q, v, u: reference.split(model, q, v, u).total  # noqa: E731
    cols = [(f(integrate(model, q, h * e), v, u) - f(integrate(model, q, -h * e), v, u)) / (2 * h)
            for e in np.eye(model.nv)]
    cols += [(f(q, v + h * e, u) - f(q, v - h * e, u)) / (2 * h) for e in np.eye(model.nv)]
    du = [(f(q, v, u + h * e) - f(q, v, u - h * e)) / (2 * h) for e in np.eye(model.m)]
    nv = model.nv
    lin = geo.linearize(model, q, v, u)    # only for its kinematic rows, compared separately from the dynamics
    return Linearization(A=np.vstack([lin.A[:nv], np.column_stack(cols)]),
                         B=np.vstack([np.zeros((nv, model.m)), np.column_stack(du)]), vdot=f(q, v, u))


@pytest.mark.parametrize("name", CONSTRAINED)
def test_constrained_linearize_matches_central_differences_of_the_reference(name):
    """The KKT system differentiated (the split's null-space solve) against central differences (h = 1e-6) of the
    reference's KKT solution, to 1e-7 relative per block, at an admissible random state."""
    model = cases.load(name)
    s = sampling.sample_states(model, 3, 5, name)[2]
    q, v, u = (np.array(x) for x in (s.q, s.qd, s.u))
    lin = geo.linearize(model, q, v, u)
    _assert_agree(model, lin, _central_differences(model, q, v, u), 1e-7, _difference_floor(model, q, v, u))
    np.testing.assert_array_equal(lin.A[:model.nv, :model.nv], 0.0)
    np.testing.assert_array_equal(lin.A[:model.nv, model.nv:], np.eye(model.nv))


def test_panda_with_its_finger_mimic_matches_pinocchio_rnea_derivatives():
    """The panda's constraint is a joint coupling (the finger mimic): Jc is constant and Jcdot qd = 0, so the KKT system
    differentiated is ``dvdot = P (dtau - d(M a + h))`` with ``P = Z (Z^T M Z)^-1 Z^T`` (Z spanning ker Jc) and
    ``d(M a + h)`` Pinocchio's exact RNEA derivatives at the reference's constrained acceleration a: an exact
    reference for the constrained linearization (measured: 1e-14), at 1e-8 relative per block."""
    import pinocchio as pin
    from scipy.linalg import null_space
    model = cases.load("panda")
    s = sampling.sample_states(model, 4, 0, "panda")[3]
    q, v, u = (np.array(x) for x in (s.q, s.qd, s.u))
    ref = reference.split(model, q, v, u)
    c = build.reference_model(model)
    data = c.model.createData()
    pin.computeRNEADerivatives(c.model, data, c.configuration(q), v[c.order], ref.total[c.order])
    dtau_dq, dtau_dv = (build.ours_matrix(c.order, np.array(d)) for d in (data.dtau_dq, data.dtau_dv))
    Z = null_space(ref.constraint_jacobian)
    P = Z @ np.linalg.solve(Z.T @ kinematics.mass_matrix(model, q) @ Z, Z.T)
    lin = geo.linearize(model, q, v, u)
    nv = model.nv
    want = Linearization(A=np.vstack([lin.A[:nv], np.hstack([-P @ dtau_dq, -P @ dtau_dv])]),
                         B=np.vstack([np.zeros((nv, model.m)), P @ model.input_map]), vdot=ref.total)
    _assert_agree(model, lin, want, 1e-8)
    np.testing.assert_array_equal(lin.A[:nv], np.hstack([np.zeros((nv, nv)), np.eye(nv)]))


@settings(max_examples=8, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(st.data())
def test_random_models_match_pinocchio(data):
    """Random kinematic trees (revolute, prismatic, spherical and free joints) at random states."""
    model = data.draw(testing.models(max_bodies=4, group=data.draw(st.booleans())))
    s = data.draw(testing.states(model))
    q, v, u = (np.array(x) for x in (s.q, s.qd, s.u))
    _assert_agree(model, geo.linearize(model, q, v, u), reference.linearize(model, q, v, u), 1e-8)


@settings(max_examples=5, deadline=None, suppress_health_check=[HealthCheck.too_slow, HealthCheck.filter_too_much])
@given(st.data())
def test_random_constrained_models_match_central_differences(data):
    """Random constrained trees at admissible states, against central differences of the reference (1e-7); states
    where S is near singular (a rank change within the difference step) are not linearizable and are skipped."""
    model = data.draw(testing.models(max_bodies=4, constraints=True))
    s = data.draw(testing.states(model))
    q, v, u = (np.array(x) for x in (s.q, s.qd, s.u))
    split = geo.split(model, q, v, u)
    if split.conditions["constraint"] > 1e6:
        return
    _assert_agree(model, geo.linearize(model, q, v, u), _central_differences(model, q, v, u), 1e-7,
                  _difference_floor(model, q, v, u))


@pytest.mark.parametrize("name, chart_name", [("double_pendulum", "nonlinear"), ("double_pendulum", "affine"),
                                               ("ball_pendulum", "zyx"), ("satellite_arm", "zyx")])
def test_chart_linearization_at_an_equilibrium_is_the_joint_one_conjugated(name, chart_name):
    """At an equilibrium (v = 0, drift = 0: a hanging chain, a free-floating body at rest without gravity's torque)
    ``A_p = T^-1 A_q T``, ``T = blockdiag(Dpsi, Dpsi)``, and ``B_p = [0; Dpsi^-1 M^-1 Dpsi^-T]`` (the chart's input is
    the covector ``tau_p``), with A_q and M from the reference; the eigenvalues are the same."""
    model = cases.load(name)
    chart = charts.get(chart_name, model)
    q, zero = _equilibrium(model), np.zeros(model.nv)
    p = chart.p_of(q)
    D = chart.jacobian(p)
    lin_p = geo.linearize_chart(model, chart, p, zero, np.zeros(model.n))
    A_q = reference.linearize(model, q, zero, np.zeros(model.m)).A
    T = np.kron(np.eye(2), D)
    want_A = np.linalg.solve(T, A_q @ T)
    want_B = np.vstack([np.zeros((model.nv, model.nv)),
                        np.linalg.solve(D, np.linalg.solve(kinematics.mass_matrix(model, q), np.linalg.inv(D).T))])
    assert np.abs(lin_p.A - want_A).max() <= 1e-10 * np.abs(want_A).max()
    assert np.abs(lin_p.B - want_B).max() <= 1e-10 * np.abs(want_B).max()
    np.testing.assert_array_equal(lin_p.A[:model.nv], np.hstack([np.zeros((model.nv, model.nv)), np.eye(model.nv)]))
    w_p, w_q = (_by_frequency(np.linalg.eigvals(A)) for A in (lin_p.A, A_q))
    np.testing.assert_allclose(w_p, w_q, rtol=0, atol=1e-8 * np.abs(w_q).max())


def _by_frequency(w: np.ndarray) -> np.ndarray:
    """Eigenvalues sorted by imaginary then real part, each rounded to 1e-9 for the sort (the real parts of an
    undamped equilibrium's pairs are rounding, whose sign would otherwise decide the order)."""
    return w[np.lexsort((np.round(w.real, 9), np.round(w.imag, 9)))]


def _equilibrium(model) -> np.ndarray:
    """A configuration where the drift at rest is 0 (checked against the reference): home for the hanging chains and
    for a satellite without gravity; a ball pendulum turned so that its centre of mass hangs below the joint (the
    quaternion ``(a x b, 1 + a . b)``, normalized, turns the unit COM direction a onto gravity's b)."""
    q = neutral(model)
    if model.name == "ball_pendulum":
        a, b = (x / np.linalg.norm(x) for x in (model.bodies[0].com, model.gravity))
        quat = np.append(np.cross(a, b), 1.0 + a @ b)
        q[:4] = quat / np.linalg.norm(quat)
    assert np.abs(reference.split(model, q, np.zeros(model.nv), np.zeros(model.m)).drift).max() < 1e-12
    return q


@pytest.mark.parametrize("name, chart_name", [("spatial_arm", "nonlinear"), ("ball_double_pendulum", "zyx")])
def test_chart_linearization_away_from_equilibrium_matches_the_mapped_reference(name, chart_name):
    """Anywhere: the chart's accelerations are ``pdd = Dpsi^-1 (vdot(psi(p), Dpsi pd, u) - (d/dt Dpsi) pd)`` with
    ``B u = Dpsi^-T tau_p`` (the harness's chart maps, the reference's vdot); its derivatives in (p, pd, tau_p) by
    central differences (h = 1e-6) against linearize_chart, to 1e-7 relative per block."""
    model = cases.load(name)
    chart = charts.get(chart_name, model)
    rng = np.random.default_rng(4)
    p = chart.p_of(random_configuration(model, rng, 1.0, 0.3))
    pd, tau_p = rng.normal(size=model.nv), rng.normal(size=model.nv)

    def pdd(p, pd, tau_p):
        D = chart.jacobian(p)
        u = np.linalg.solve(model.input_map, np.linalg.solve(D.T, tau_p))
        vdot = reference.split(model, chart.q_of(p), D @ pd, u).total
        return np.linalg.solve(D, vdot - chart.jacobian_rate(p, pd))

    h, x = 1e-6, [p, pd, tau_p]
    columns = []
    for slot in range(3):
        for e in np.eye(model.nv):
            ahead, behind = list(x), list(x)
            ahead[slot], behind[slot] = x[slot] + h * e, x[slot] - h * e
            columns.append((pdd(*ahead) - pdd(*behind)) / (2 * h))
    fd = np.column_stack(columns)
    nv = model.nv
    want = Linearization(A=np.block([[np.zeros((nv, nv)), np.eye(nv)], [fd[:, :2 * nv]]]),
                         B=np.vstack([np.zeros((nv, nv)), fd[:, 2 * nv:]]), vdot=pdd(p, pd, tau_p))
    lin = geo.linearize_chart(model, chart, p, pd, tau_p)
    _assert_agree(model, lin, want, 1e-7, _difference_floor(model, chart.q_of(p), chart.jacobian(p) @ pd,
                                                            np.zeros(model.m)))


@pytest.mark.parametrize("name", UNCONSTRAINED[:4] + CONSTRAINED)
def test_the_drift_parts_add_up_and_match_the_reference(name):
    """``zvcf + drift_velocity = drift`` to rounding (1e-13 of the drift's scale); zvcf is the reference's drift at
    ``qd = 0`` (with constraints: the KKT solve with f = -g and no bias) and drift_velocity the rest of the reference's
    drift; on an unconstrained model zvcf is also ``-M^-1 g`` from Pinocchio's CRBA and gravity."""
    model = cases.load(name)
    for s in sampling.sample_states(model, 3, 2, name)[1:]:
        q, v, u = (np.array(x) for x in (s.q, s.qd, s.u))
        split = geo.split(model, q, v, u)
        scale = np.abs(split.zvcf).max() + np.abs(split.drift_velocity).max()
        assert np.abs(split.drift_parts).max() <= 1e-13 * scale
        at_rest = reference.split(model, q, np.zeros(model.nv), np.zeros(model.m)).drift
        drift = reference.split(model, q, v, u).drift
        np.testing.assert_allclose(split.zvcf, at_rest, rtol=0, atol=1e-10 * scale)
        np.testing.assert_allclose(split.drift_velocity, drift - at_rest, rtol=0, atol=1e-10 * scale)
        if not model.constraints:
            _, g = kinematics.bias_forces(model, q, v)
            np.testing.assert_allclose(split.zvcf, -np.linalg.solve(kinematics.mass_matrix(model, q), g), rtol=0,
                                       atol=1e-10 * scale)


def test_the_drift_parts_in_a_chart_add_up():
    """``split_chart`` fills the parts too (the same solve in the chart): they add up to its drift, and at rest the
    drift is the zvcf."""
    model = cases.load("double_pendulum")
    chart = charts.get("nonlinear", model)
    p, pd = np.array([0.4, -0.7]), np.array([1.3, 0.2])
    s = geo.split_chart(model, chart, p, pd, np.zeros(2))
    assert np.abs(s.drift_parts).max() <= 1e-13 * np.abs(s.drift).max()
    at_rest = geo.split_chart(model, chart, p, np.zeros(2), np.zeros(2))
    np.testing.assert_array_equal(at_rest.drift_velocity, 0.0)
    np.testing.assert_allclose(s.zvcf, at_rest.drift, rtol=1e-14)


def test_the_derivative_function_is_built_on_the_first_linearize_only():
    """split never builds it; the first linearize of a model does, and it is cached."""
    model = cases.load("double_pendulum")
    q, v, u = _state(model, 3)
    geo.split(model, q, v, u)
    compiled = geo._compiled(model, None)
    compiled._linearization = None            # as built by split alone
    geo.split(model, q, v, u)
    assert compiled._linearization is None
    geo.linearize(model, q, v, u)
    built = compiled._linearization
    assert built is not None
    geo.linearize(model, q, v, u)
    assert compiled._linearization is built


def test_bad_input_is_a_state_error_and_representations_are_refused():
    model = cases.load("double_pendulum")
    with pytest.raises(StateError, match="qd has 3 entries"):
        geo.linearize(model, np.zeros(2), np.zeros(3), np.zeros(model.m))
    with pytest.raises(StateError, match="non-finite"):
        geo.linearize(model, np.array([0.0, np.nan]), np.zeros(2), np.zeros(model.m))
    with pytest.raises(StateError, match="not 1"):
        geo.linearize(cases.load("free_body"), np.zeros(7), np.zeros(6), np.zeros(cases.load("free_body").m))
    free = cases.load("free_body")
    with pytest.raises(ModelNotSupported):
        geo.linearize_chart(free, charts.get("world", free), neutral(free), np.zeros(6), np.zeros(6))
    with pytest.raises(ModelNotSupported):
        geo.linearize_chart(free, None, np.zeros(6), np.zeros(6), np.zeros(6))


def test_registered_on_the_formalism():
    assert geo.FORMALISM.linearize is geo.linearize
    assert geo.FORMALISM.linearize_chart is geo.linearize_chart
