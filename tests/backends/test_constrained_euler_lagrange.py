"""The constrained Euler–Lagrange backend (article section 5: eqs. 12-17, the KKT system of 5.6): what only this
backend has. The references every backend shares (the cartesian pendulum's multiplier, the circle's KKT solve, the
absolute loop, a gear and a rail, the split identities, a duplicated constraint, the four-bar at its change point)
are in ``test_constrained_backends.py``.

* ``phi``, ``Jc`` and ``Jcdot qd`` of every declaration type against finite differences of ``phi``.
* The four-bar just off its change point against a range-space solve with the backend's own M and the pseudo-inverse
  of S cut at ``CONSTRAINT_RCOND`` (rank 1 below it, rank 2 just above).
* ``split_chart`` in the nonlinear and an affine chart against the joint-chart split mapped by the harness's maps
  (``crosscheck.checks.charts``): the same multipliers, ``pdd = Dpsi^-1 (qdd - (d/dt Dpsi) pd)``, ``Jc_p = Jc Dpsi``.

All tests derive into a scratch cache (fixture ``fresh_derivation_cache``), so they test the current code.
"""

from __future__ import annotations

import math

import numpy as np
import pytest

import cases
from cases import JointCoupling, PointOnLine
from closed_forms import circle_state, min_norm_solve
from crosscheck.checks import charts
from formalisms import euler_lagrange as el
from formalisms.interface import CONSTRAINT_RCOND

pytestmark = pytest.mark.usefixtures("fresh_derivation_cache")  # conftest.py: derive afresh, into a scratch cache

RTOL = 1e-11


def assert_close(got, expected, what="", rtol=RTOL, scale=None):
    """``|got - expected| <= rtol * scale`` elementwise-max, ``scale`` defaulting to ``max(1, |expected|)``."""
    got, expected = np.asarray(got, dtype=float), np.asarray(expected, dtype=float)
    scale = max(1.0, float(np.abs(expected).max(initial=0.0))) if scale is None else scale
    err = float(np.abs(got - expected).max(initial=0.0))
    assert err <= rtol * scale, (f"{what}: max error {err:.3e} > {rtol * scale:.3e}\n got      {got}\n"
                                 f" expected {expected}")


def check_split_identities(s, what=""):
    """Eq. (9) additivity, the H_t residuals of eq. (16) for drift and total, and P_constr = lam^T Jc qd (5.5)."""
    size = max(1.0, np.abs(s.total).max(), np.abs(s.drift).max())
    assert_close(s.drift + s.ctrl, s.total, f"{what} additivity", scale=size)
    jc = max(1.0, np.abs(s.constraint_jacobian).max())
    assert_close(s.admissibility_total, 0.0, f"{what} Jc qdd + Jcdot qd", scale=jc * size)
    assert_close(s.admissibility_drift, 0.0, f"{what} Jc qdd_drift + Jcdot qd", scale=jc * size)


# ----------------------------------------------------------------------------------------------------------
# phi, Jc, Jcdot qd of every declaration type against finite differences of phi
# ----------------------------------------------------------------------------------------------------------

def double_pendulum_with(constraint):
    base = cases.load("double_pendulum")
    return cases.build_model(f"double_pendulum_{constraint.name}", base.bodies, gravity=base.gravity,
                             task_points=base.task_points, constraints=[constraint])


GEAR = JointCoupling("gear", ("link1", "link2"), (1.0, -2.0), 0.1)          # t1 - 2 t2 - 0.1
RAIL = PointOnLine("rail", "link2", (0.0, -1.0, 0.0), (1.2, 0.0, 0.0), ((1.0, 0.0, 0.0),))  # x2 = 1.2


def small_models():
    return {"gear": double_pendulum_with(GEAR), "rail": double_pendulum_with(RAIL),
            **{name: cases.load(name) for name in ("double_pendulum_circle", "four_bar", "slider_crank",
                                                   "cartesian_pendulum", "double_pendulum_absolute_loop")}}


@pytest.mark.parametrize("name", ["gear", "rail", "double_pendulum_circle", "four_bar", "slider_crank",
                                  "cartesian_pendulum", "double_pendulum_absolute_loop"])
def test_jacobian_and_bias_are_the_derivatives_of_phi(name):
    """``Jc = dphi/dq`` by central differences; ``Jcdot qd = qd^T (d^2 phi/dq^2) qd`` = the second derivative of
    ``phi(q + s qd)`` at s = 0, by the five-point stencil (nothing of the derivation is used but phi)."""
    model = small_models()[name]
    rng = np.random.default_rng(3)
    q, qd = rng.uniform(-1.0, 1.0, model.n), rng.uniform(-1.0, 1.0, model.n)

    def phi(x):
        return el.evaluate(model, x, np.zeros(model.n))[1].phi

    cons = el.evaluate(model, q, qd)[1]
    h = 1e-5
    fd_jac = np.column_stack([(phi(q + h * e) - phi(q - h * e)) / (2 * h) for e in np.eye(model.n)])
    assert_close(cons.Jc, fd_jac, "Jc vs finite differences", rtol=1e-8)
    h = 1e-3
    f = [phi(q + i * h * qd) for i in (-2, -1, 0, 1, 2)]
    fd_bias = (-f[0] + 16 * f[1] - 30 * f[2] + 16 * f[3] - f[4]) / (12 * h**2)
    assert_close(cons.bias, fd_bias, "Jcdot qd vs finite differences", rtol=1e-7)


# ----------------------------------------------------------------------------------------------------------
# The four-bar just off its change point (at it: test_constrained_backends.py)
# ----------------------------------------------------------------------------------------------------------

def range_space_reference(model, q, qd, u):
    """The minimum-norm solution by the range-space method (``closed_forms.min_norm_solve``, the pseudo-inverse of S
    cut at CONSTRAINT_RCOND) with M, C qd + g, Jc and Jcdot qd from the backend."""
    terms, cons = el.evaluate(model, q, qd)
    return min_norm_solve(terms.M, cons.Jc, model.input_map @ u - terms.Cqd - terms.g, cons.bias, CONSTRAINT_RCOND)


@pytest.mark.parametrize("delta, rank", [(1e-6, 1), (3e-5, 2)])
def test_four_bar_near_its_change_point_gives_the_minimum_norm_solution(delta, rank):
    """On the parallelogram branch at q = (pi/2 + d, -d, pi/2 + d) the smaller eigenvalue of S over the larger is
    ~ 6e-13 (d / 1e-6)^2: at d = 1e-6 below CONSTRAINT_RCOND (that direction is redundant, rank 1), at d = 3e-5
    above it (kept, rank 2, large multipliers). Either way the backend is the range-space solve with S's
    pseudo-inverse cut at CONSTRAINT_RCOND, at rest and moving along the branch. (A dropped direction that is not
    exactly redundant leaves its O(d) residual in H_t, so admissibility is checked where nothing is dropped.)"""
    model = cases.load("four_bar")
    q, u = np.array([math.pi / 2 + delta, -delta, math.pi / 2 + delta]), np.array([0.5, -1.0, 2.0])
    for qd in (np.zeros(3), np.array([0.5, -0.5, 0.5])):
        s = el.split(model, q, qd, u)
        assert s.constraint_rank == rank
        qdd, lam = range_space_reference(model, q, qd, u)
        assert_close(s.total, qdd, "total")
        assert_close(s.lam, lam, "lam (minimum norm)")
        assert_close(s.drift + s.ctrl, s.total, "additivity", scale=np.abs(s.total).max())
        if rank == 2:
            check_split_identities(s, f"four_bar at d = {delta}")


# ----------------------------------------------------------------------------------------------------------
# split_chart: the same multipliers, the accelerations mapped
# ----------------------------------------------------------------------------------------------------------

@pytest.mark.parametrize("kind", ["nonlinear", "affine"])
def test_chart_split_with_a_constraint_is_the_joint_split_mapped(kind):
    model = cases.load("double_pendulum_circle")
    chart = charts.get(kind, model, seed=4)
    rng = np.random.default_rng(13)
    for admissible in (True, False):
        for _ in range(5):
            if admissible:
                q, qd = circle_state(rng.uniform(-math.pi, math.pi), rng.choice([-1.0, 1.0]), rng.uniform(-3.0, 3.0))
            else:
                q, qd = rng.uniform(-math.pi, math.pi, 2), rng.uniform(-3.0, 3.0, 2)
            u = rng.uniform(-10.0, 10.0, 2)
            joint = el.split(model, q, qd, u)
            p = chart.p_of(q)
            pd = charts.velocity_to_chart(chart, p, qd)
            s = el.split_chart(model, chart, p, pd, charts.force_to_chart(chart, p, model.input_map @ u))
            assert_close(s.lam, joint.lam, f"{kind}: lam", rtol=1e-10)
            assert_close(s.lam_drift, joint.lam_drift, f"{kind}: lam_drift", rtol=1e-10)
            for key in ("drift", "total"):
                assert_close(s.quantity(key), charts.acceleration_to_chart(chart, p, pd, joint.quantity(key)),
                             f"{kind}: {key}", rtol=1e-10)
            assert_close(s.ctrl, charts.acceleration_to_chart(chart, p, pd, joint.ctrl, with_rate=False),
                         f"{kind}: ctrl", rtol=1e-10)
            assert_close(s.constraint_value, joint.constraint_value, f"{kind}: phi")
            assert_close(s.constraint_jacobian, joint.constraint_jacobian @ chart.jacobian(p), f"{kind}: Jc Dpsi")
            assert_close(s.power_constr, joint.power_constr, f"{kind}: P_constr", rtol=1e-10)
            check_split_identities(s, f"chart {kind}")


# ----------------------------------------------------------------------------------------------------------
# split_batch: states of different ranks of S in one batch
# ----------------------------------------------------------------------------------------------------------
