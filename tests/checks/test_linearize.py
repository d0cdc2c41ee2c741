"""The linearization's convention (``formalisms.interface.Linearization``, article eq. 11): its kinematic rows against
the group flow, and the reference (Pinocchio's ABA derivatives) against central differences of its own split."""

from __future__ import annotations

import numpy as np
import pytest

import cases
from cases.configuration import integrate, random_configuration
from crosscheck.references.pinocchio import reference
from formalisms.interface import Linearization, tangent_kinematics


def _flow(model, q, v, t):
    """The configuration after time t at the constant velocity v: ``q exp(t v)``."""
    return integrate(model, q, t * v)


def _log(model, q0, q1, h=1e-7):
    """The tangent vector dq with ``q1 = q0 (+) dq`` for a small dq, by Newton on ``integrate`` (a test's tool)."""
    dq = np.zeros(model.nv)
    for _ in range(4):
        r = integrate(model, q0, dq) - q1
        J = np.column_stack([(integrate(model, q0, dq + h * e) -
                              integrate(model, q0, dq - h * e)) / (2 * h) for e in np.eye(model.nv)])
        dq = dq - np.linalg.lstsq(J, r, rcond=None)[0]
    return dq


@pytest.mark.parametrize("name", ["free_body", "ball_double_pendulum", "double_pendulum"])
def test_tangent_kinematics_is_the_flow_of_a_right_perturbation(name):
    """``d/dt dq = dv + A_qq dq`` for ``q(t) = qbar(t) exp(dq(t))``: two trajectories at constant velocities v and
    v + dv, from qbar and qbar exp(dq0); the perturbation after a short time t matches the linear flow."""
    model = cases.load(name)
    rng = np.random.default_rng(3)
    q0 = random_configuration(model, rng, 1.0, 0.3)
    v = rng.normal(size=model.nv)
    dq0, dv = 1e-5 * rng.normal(size=model.nv), 1e-5 * rng.normal(size=model.nv)
    t = 1e-3
    dq_t = _log(model, _flow(model, q0, v, t), _flow(model, integrate(model, q0, dq0), v + dv, t))
    A_qq = tangent_kinematics(model, v)
    error = np.abs(dq_t - (dq0 + t * (dv + A_qq @ dq0))).max()
    # the first-order term t A_qq dq0 is predicted; what remains is O(t^2 |v|^2 |dq0|) and O(|dq0|^2) (1e-11 here)
    assert error < 1e-2 * t * np.abs(v).max() * np.abs(dq0).max()
    if model.group_joints:
        assert np.abs(dq_t - (dq0 + t * dv)).max() > 100 * error  # the check sees A_qq


def _central_differences(model, q, v, u, h=1e-6):
    f = lambda q, v, u: reference.split(model, q, v, u).total  # noqa: E731
    cols = []
    for e in np.eye(model.nv):
        cols.append((f(integrate(model, q, h * e), v, u) - f(integrate(model, q, -h * e), v, u)) / (2 * h))
    for e in np.eye(model.nv):
        cols.append((f(q, v + h * e, u) - f(q, v - h * e, u)) / (2 * h))
    for e in np.eye(model.m):
        cols.append((f(q, v, u + h * e) - f(q, v, u - h * e)) / (2 * h))
    return np.column_stack(cols)


@pytest.mark.parametrize("name", ["double_pendulum", "spatial_arm", "free_body", "solo12", "ball_double_pendulum"])
def test_the_reference_derivatives_match_central_differences(name):
    """Pinocchio's analytical ABA derivatives, in our order and convention, against central differences (h = 1e-6:
    truncation and rounding near 1e-10 relative) of the reference's own split."""
    model = cases.load(name)
    rng = np.random.default_rng(1)
    q, v, u = random_configuration(model, rng, 1.0, 0.3), rng.normal(size=model.nv), rng.normal(size=model.m)
    lin = reference.linearize(model, q, v, u)
    assert isinstance(lin, Linearization)
    A, B = lin
    fd = _central_differences(model, q, v, u)
    got = np.hstack([A[model.nv:], B[model.nv:]])
    assert np.abs(got - fd).max() <= 1e-8 * np.abs(fd).max()
    np.testing.assert_array_equal(A[:model.nv, model.nv:], np.eye(model.nv))
    np.testing.assert_array_equal(B[:model.nv], 0.0)
    np.testing.assert_allclose(lin.vdot, reference.split(model, q, v, u).total, rtol=1e-12, atol=1e-12)


@pytest.mark.parametrize("name", ["double_pendulum", "free_body", "ball_double_pendulum"])
def test_the_50_digit_reference_agrees_with_pinocchio(name):
    """Two references by different methods (Pinocchio's analytical derivatives, central differences of the exact
    dynamics at 50 digits) agree to Pinocchio's rounding."""
    from crosscheck.references import precise
    model = cases.load(name)
    rng = np.random.default_rng(2)
    q, v, u = random_configuration(model, rng, 1.0, 0.3), rng.normal(size=model.nv), rng.normal(size=model.m)
    exact, pin_lin = precise.linearize(model, q, v, u), reference.linearize(model, q, v, u)
    for got, want in ((pin_lin.A, exact.A), (pin_lin.B, exact.B)):
        assert np.abs(got - want).max() <= 1e-12 * np.abs(want).max()


def test_the_50_digit_reference_differentiates_the_kkt_solution():
    """On a constrained model (four-bar) the 50-digit A matches central differences of Pinocchio's KKT solve."""
    from crosscheck.references import precise
    from crosscheck.core.sampling import sample_states
    model = cases.load("four_bar")
    state = sample_states(model, 2, 0, "four_bar")[1]
    q, v, u = (np.array(x) for x in (state.q, state.qd, state.u))
    exact = precise.linearize(model, q, v, u)
    fd = _central_differences(model, q, v, u)
    got = np.hstack([exact.A[model.nv:], exact.B[model.nv:]])
    assert np.abs(got - fd).max() <= 1e-7 * np.abs(fd).max()


def test_equilibrium_eigenvalues_closed_form_against_pinocchio():
    """The hanging double pendulum: omega^2 = g (2 -+ sqrt 2) for unit masses and lengths (the textbook result), and
    Pinocchio's A has those eigenvalues; inverted, they are real."""
    import dataclasses

    from crosscheck.checks import equilibria
    params = equilibria.case_params("double_pendulum")
    hanging, inverted = equilibria.of_case("double_pendulum")
    omega = np.sqrt(9.81 * np.array([2 - np.sqrt(2), 2 + np.sqrt(2)]))
    np.testing.assert_allclose(np.sort(hanging.eigenvalues(params).imag[2:]), omega, rtol=1e-13)
    np.testing.assert_allclose(np.abs(hanging.eigenvalues(params).real), 0.0, atol=1e-15)
    np.testing.assert_allclose(np.sort(inverted.eigenvalues(params).real[2:]), omega, rtol=1e-13)
    model = cases.load("double_pendulum")
    ref = dataclasses.replace(reference.REFERENCE, name="pin")
    found, errors = equilibria.checks(hanging, params, model, [ref])
    assert not errors and all(c.verdict == "agree" for c in found.values())


def _perturbed(backend, block: str, factor: float):
    """A backend whose linearization is wrong in one block by a relative ``factor`` (a test's fault)."""
    import dataclasses

    def linearize(model, q, v, u):
        lin = backend.linearize(model, q, v, u)
        A, B = lin.A.copy(), lin.B.copy()
        nv = model.nv
        if block == "dvdot/dq":
            A[nv:, :nv] *= 1 + factor
        elif block == "dvdot/dv":
            A[nv:, nv:] = A[nv:, nv:].T
        else:
            B[nv:] *= 1 + factor
        return Linearization(A=A, B=B, vdot=lin.vdot)
    return dataclasses.replace(backend, name="faulty", linearize=linearize)


@pytest.mark.parametrize("block", ["dvdot/dq", "dvdot/dv", "dvdot/du"])
def test_the_linearization_check_catches_a_wrong_block(block):
    """The gate's linearization check names a backend whose A or B is wrong: a 1e-8 relative error in dvdot/dq or
    dvdot/du, dvdot/dv transposed (two correct voters, Pinocchio twice under two names, outvote it)."""
    import dataclasses

    from crosscheck.checks import linearization
    from crosscheck.core import tolerance as policy
    from crosscheck.core.sampling import sample_states
    model = cases.load("spatial_arm")
    state = sample_states(model, 2, 0, "spatial_arm")[1]
    good = dataclasses.replace(reference.REFERENCE, name="copy")
    bad = _perturbed(reference.REFERENCE, block, 1e-8)
    split = reference.split(model, state.q, state.qd, state.u)
    at = policy.scales([split], model, np.array(state.q), np.array(state.qd), u=np.array(state.u))
    found, errors = linearization.checks(model, state, [good, bad], at)
    assert not errors
    comparison = found[f"linearization: {block}"]
    assert comparison.verdict == "DISAGREE" and comparison.outlier == "faulty"
    clean, _ = linearization.checks(model, state, [good], at)
    assert all(c.verdict == "agree" for c in clean.values())


def test_eval_linearize_prints_a_b_and_eigenvalues(capsys):
    """``crosscheck eval --linearize --json``: every backend's A, B, eigenvalues and the compared blocks."""
    import json

    from crosscheck.cli import main
    code = main(["eval", "--case", "double_pendulum", "--q", "0.3,0.2", "--qd", "1,-1", "--linearize", "--json"])
    out = json.loads(capsys.readouterr().out)
    lin = out["linearization"]
    assert code == 0 and out["verdict"]["agree"] is True
    A = np.array(lin["backends"]["pinocchio"]["A"])
    assert A.shape == (4, 4) and np.array(lin["backends"]["pinocchio"]["B"]).shape == (4, 2)
    assert set(lin["checks"]) == {"linearization: dvdot/dq", "linearization: dvdot/dv", "linearization: dvdot/du",
                                  "linearization: vdot", "linearization: kinematic rows"}
    assert len(lin["backends"]["pinocchio"]["eigenvalues"]) == 4


def test_eval_linearize_refuses_a_chart(capsys):
    from crosscheck.cli import main
    assert main(["eval", "--case", "double_pendulum", "--q", "0.3,0.2", "--chart", "absolute", "--linearize"]) == 2
    assert "joint chart" in capsys.readouterr().err


def test_the_parallelogram_four_bar_at_rest_oscillates_at_its_closed_form():
    """The four-bar (1-2-1-2) at rest, q = (0, pi/2, 0): omega^2 = 6 g / (5 a) from its one degree of freedom, the
    50-digit reference's A has +-i omega and four eigenvalues at 0 (the constraint rows' d^2 phi/dt^2 = 0)."""
    from crosscheck.checks import equilibria
    from crosscheck.references import precise
    (rest,) = equilibria.of_case("four_bar", equilibria.case_params("four_bar"))
    model = cases.load("four_bar")
    A = precise.linearize(model, rest.q(model), np.zeros(3), np.zeros(model.m)).A
    omega = np.sqrt(6 * 9.81 / 5)
    np.testing.assert_allclose(equilibria.motion(A, 2), [-1j * omega, 1j * omega], atol=1e-12)
    assert np.sort(np.abs(np.linalg.eigvals(A)))[:4].max() < 1e-6
    assert not equilibria.of_case("four_bar", equilibria.case_params("four_bar", {"coupler": 2.5}))
