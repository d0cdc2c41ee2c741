"""The linearization's convention (``formalisms.interface.Linearization``, article eq. 11): its kinematic rows against
the group flow, and the reference (Pinocchio's ABA derivatives) against central differences of its own split."""

from __future__ import annotations

import numpy as np
import pytest

import cases
from cases.configuration import integrate, random_configuration
from crosscheck import reference
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
