"""The constrained Euler–Lagrange backend (article section 5: eqs. 12-17, the KKT system of 5.6) against references
written independently here.

* ``cartesian_pendulum``: the multiplier's closed form ``lam = -m (|v|^2 + p . (gravity + u / m)) / (2 L^2)`` and
  ``m a = m gravity + u + 2 lam p`` at admissible states.
* ``double_pendulum_circle``: a 3x3 KKT solve written here from the article's closed forms (``closed_forms.py``:
  eqs. 6-8) with ``Jc`` and ``Jcdot qd`` by hand from the tip position of eq. (4), and ``B_c`` of eq. (17) from the
  2x2 inverse of 4.7.2; admissibility (eq. 16) and the zero constraint power (5.5).
* ``double_pendulum_absolute_loop`` against ``double_pendulum`` with the same inertias (theta1 = phi1,
  theta2 = phi2 - phi1).
* ``phi``, ``Jc`` and ``Jcdot qd`` of every declaration type against finite differences of ``phi``.
* Redundant constraints: a duplicated circle (half the multiplier each, the same accelerations and ``Jc^T lam``),
  and the four-bar at and near its change point against a range-space solve with the pseudo-inverse of S cut at
  ``CONSTRAINT_RCOND`` (rank 1 below it, rank 2 just above); an inconsistent system returns finite numbers.
* ``split_chart`` in the nonlinear and an affine chart against the joint-chart split mapped by the harness's maps
  (``crosscheck.charts``): the same multipliers, ``pdd = Dpsi^-1 (qdd - (d/dt Dpsi) pd)``, ``Jc_p = Jc Dpsi``.

All tests derive into a scratch cache (fixture ``fresh_derivation_cache``), so they test the current code.
"""

from __future__ import annotations

import dataclasses
import math

import numpy as np
import pytest

import cases
from cases import JointCoupling, PointOnLine
from closed_forms import endpoint_jacobian, inv2, pendulum_terms
from crosscheck import charts
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
# cartesian_pendulum: the multiplier's closed form
# ----------------------------------------------------------------------------------------------------------

@pytest.mark.parametrize("m, L", [(1.0, 1.0), (2.5, 0.7)])
def test_cartesian_pendulum_multiplier_is_the_closed_form(m, L):  # noqa: N803
    model = cases.load("cartesian_pendulum", m=m, L=L)
    rng = np.random.default_rng(11)
    for _ in range(10):
        a, w = rng.uniform(-math.pi, math.pi), rng.uniform(-4.0, 4.0)
        p = L * np.array([math.sin(a), -math.cos(a)])
        v = w * L * np.array([math.cos(a), math.sin(a)])       # tangent: p . v = 0
        u = rng.uniform(-10.0, 10.0, 2)
        s = el.split(model, p, v, u)
        gravity = model.gravity[:2]
        for lam, lam_ref_u, qdd in ((s.lam, u, s.total), (s.lam_drift, np.zeros(2), s.drift)):
            lam_ref = -m * (v @ v + p @ (gravity + lam_ref_u / m)) / (2.0 * L**2)
            assert_close(lam, [lam_ref], "lam", scale=m * (w**2 + 10.0 + np.abs(u).sum()))
            assert_close(qdd, gravity + (lam_ref_u + 2.0 * lam_ref * p) / m, "m a = m gravity + u + 2 lam p",
                         scale=w**2 * L + 10.0 + np.abs(u).sum() / m)
        assert_close(s.constraint_value, [0.0], "phi on the circle", scale=L**2)
        assert_close(s.power_constr, 0.0, "P_constr", scale=m * (w**2 + 10.0 + np.abs(u).sum()) * abs(w) * L**2)
        check_split_identities(s, "cartesian_pendulum")


# ----------------------------------------------------------------------------------------------------------
# double_pendulum_circle: a 3x3 KKT solve from the article's closed forms
# ----------------------------------------------------------------------------------------------------------

CENTER, RADIUS = np.array([1.0, -1.0]), 0.5


def tip(t):
    """Article eq. (4): x2 = l1 sin t1 + l2 sin(t1 + t2), y2 = -l1 cos t1 - l2 cos(t1 + t2) (l1 = l2 = 1)."""
    return np.array([math.sin(t[0]) + math.sin(t[0] + t[1]), -math.cos(t[0]) - math.cos(t[0] + t[1])])


def circle_constraint(t, td):
    """phi, Jc = 2 (x2 - c)^T J (eq. 5) and Jcdot qd = 2 |J qd|^2 + 2 (x2 - c) . (Jdot qd), by hand."""
    d = tip(t) - CENTER
    J = endpoint_jacobian(t)
    w = td[0] + td[1]
    Jdot_qd = np.array([-math.sin(t[0]) * td[0]**2 - math.sin(t[0] + t[1]) * w**2,
                        math.cos(t[0]) * td[0]**2 + math.cos(t[0] + t[1]) * w**2])
    v = J @ td
    return d @ d - RADIUS**2, 2.0 * d @ J, 2.0 * v @ v + 2.0 * d @ Jdot_qd


def circle_state(angle, elbow, rate):
    """Joint angles putting the tip at ``CENTER + R (cos angle, sin angle)`` on the ``elbow`` branch (+-1), and a
    velocity ``rate`` along the null space of Jc."""
    x, y = CENTER + RADIUS * np.array([math.cos(angle), math.sin(angle)])
    t2 = elbow * math.acos((x * x + y * y - 2.0) / 2.0)
    t1 = math.atan2(x, -y) - math.atan2(math.sin(t2), 1.0 + math.cos(t2))
    t = np.array([t1, t2])
    _, Jc, _ = circle_constraint(t, np.zeros(2))
    return t, rate * np.array([Jc[1], -Jc[0]]) / np.linalg.norm(Jc)


def kkt_reference(t, td, u):
    """total, lam (with u) and drift, lam_drift (u = 0) of article 5.6, and B_c u of eq. (17), by hand."""
    M, Cqd, g = pendulum_terms(t, td)
    _, Jc, bias = circle_constraint(t, td)
    K = np.block([[M, -Jc[:, None]], [Jc[None, :], np.zeros((1, 1))]])
    total = np.linalg.solve(K, np.append(u - Cqd - g, -bias))
    drift = np.linalg.solve(K, np.append(-Cqd - g, -bias))
    Minv = inv2(M)
    B_c = Minv @ (np.eye(2) - np.outer(Jc, Jc) @ Minv / (Jc @ Minv @ Jc))
    return total, drift, B_c @ u


def test_double_pendulum_circle_against_a_hand_written_kkt_solve():
    model = cases.load("double_pendulum_circle")
    rng = np.random.default_rng(5)
    for _ in range(12):
        t, td = circle_state(rng.uniform(-math.pi, math.pi), rng.choice([-1.0, 1.0]), rng.uniform(-3.0, 3.0))
        u = rng.uniform(-10.0, 10.0, 2)
        s = el.split(model, t, td, u)
        phi, Jc, bias = circle_constraint(t, td)
        assert abs(phi) < 1e-12, "the hand-made state is on the circle"
        assert_close(s.constraint_value, [0.0], "phi")
        assert_close(s.constraint_jacobian, [Jc], "Jc")
        assert_close(s.constraint_bias, [bias], "Jcdot qd")
        total, drift, ctrl = kkt_reference(t, td, u)
        assert_close(s.total, total[:2], "total")
        assert_close(s.lam, total[2:], "lam")
        assert_close(s.drift, drift[:2], "drift")
        assert_close(s.lam_drift, drift[2:], "lam_drift")
        assert_close(s.ctrl, ctrl, "ctrl = B_c u (eq. 17)")
        assert_close(s.constraint_force, Jc * total[2], "Jc^T lam")
        assert_close(s.power_constr, 0.0, "P_constr", scale=abs(total[2]) * np.abs(Jc).sum() * np.abs(td).sum())
        check_split_identities(s, "double_pendulum_circle")


# ----------------------------------------------------------------------------------------------------------
# The absolute loop is the double pendulum
# ----------------------------------------------------------------------------------------------------------

def test_absolute_loop_has_the_double_pendulum_accelerations():
    loop = cases.load("double_pendulum_absolute_loop", I1=0.1, I2=0.2, m2=1.5)
    joint = cases.load("double_pendulum", I1=0.1, I2=0.2, m2=1.5)
    rng = np.random.default_rng(7)
    for _ in range(10):
        (t1, t2), (a, b) = rng.uniform(-math.pi, math.pi, 2), rng.uniform(-3.0, 3.0, 2)
        u = rng.uniform(-10.0, 10.0, 2)
        q = np.array([0.0, 0.0, t1, math.sin(t1), -math.cos(t1), t1 + t2])
        qd = np.array([0.0, 0.0, a, math.cos(t1) * a, math.sin(t1) * a, a + b])
        s, ref = el.split(loop, q, qd, u), el.split(joint, np.array([t1, t2]), np.array([a, b]), u)
        assert_close(s.constraint_value, np.zeros(4), "phi")
        for key in ("total", "drift", "ctrl"):
            phidd = getattr(s, key)
            assert_close([phidd[2], phidd[5] - phidd[2]], getattr(ref, key), key, rtol=1e-10)
        assert_close(s.kinetic_energy, ref.kinetic_energy, "T")
        assert_close(s.power_ctrl, ref.power_ctrl, "u . B^T qd")
        assert_close(s.power_constr, 0.0, "P_constr", scale=np.abs(s.constraint_force).sum() * np.abs(qd).sum())
        check_split_identities(s, "absolute loop")


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


def test_gear_and_rail_stay_on_their_constraint():
    """A JointCoupling and a PointOnLine at admissible states: phi = 0, H_t residual 0, P_constr = 0."""
    models = small_models()
    rng = np.random.default_rng(9)
    for _ in range(8):
        t2, rate, u = rng.uniform(-2.0, 2.0), rng.uniform(-3.0, 3.0), rng.uniform(-10.0, 10.0, 2)
        gear_state = (np.array([2.0 * t2 + 0.1, t2]), rate * np.array([2.0, 1.0]))
        t1 = rng.uniform(0.3, 1.5)                             # sin t1 + sin(t1 + t2) = 1.2
        t = np.array([t1, math.asin(1.2 - math.sin(t1)) - t1])
        J = endpoint_jacobian(t)[0]
        rail_state = (t, rate * np.array([J[1], -J[0]]))
        for name, (q, qd) in (("gear", gear_state), ("rail", rail_state)):
            s = el.split(models[name], q, qd, u)
            assert_close(s.constraint_value, [0.0], f"{name} phi")
            assert_close(s.constraint_jacobian @ qd, [0.0], f"{name} Jc qd")
            assert_close(s.power_constr, 0.0, f"{name} P_constr",
                         scale=np.abs(s.constraint_force).sum() * np.abs(qd).sum())
            check_split_identities(s, name)


# ----------------------------------------------------------------------------------------------------------
# Redundant and inconsistent constraints
# ----------------------------------------------------------------------------------------------------------

def test_a_duplicated_constraint_splits_the_multiplier_in_half():
    single = cases.load("double_pendulum_circle")
    circle = single.constraints[0]
    double = cases.build_model("double_circle", single.bodies, gravity=single.gravity,
                               task_points=single.task_points,
                               constraints=[circle, dataclasses.replace(circle, name="tip_on_circle_again")])
    assert double.k == 2
    rng = np.random.default_rng(2)
    for _ in range(8):
        t, td = circle_state(rng.uniform(-math.pi, math.pi), rng.choice([-1.0, 1.0]), rng.uniform(-3.0, 3.0))
        u = rng.uniform(-10.0, 10.0, 2)
        one, two = el.split(single, t, td, u), el.split(double, t, td, u)
        assert two.constraint_rank == 1
        for key in ("total", "drift", "ctrl", "constraint_force", "constraint_force_drift"):
            assert_close(getattr(two, key), getattr(one, key), key)
        assert_close(two.lam, np.repeat(one.lam / 2.0, 2), "lam = half each (minimum norm)")
        assert_close(two.lam_drift, np.repeat(one.lam_drift / 2.0, 2), "lam_drift = half each")
        check_split_identities(two, "duplicated circle")


def range_space_reference(model, q, qd, u):
    """The minimum-norm solution by the range-space method: ``lam = S^+ (-Jcdot qd - Jc M^-1 f)`` with the
    pseudo-inverse cut at CONSTRAINT_RCOND, ``qdd = M^-1 (f + Jc^T lam)``; M, Jc, Jcdot qd from the backend."""
    terms, cons = el.evaluate(model, q, qd)
    Minv = np.linalg.inv(terms.M)
    S = cons.Jc @ Minv @ cons.Jc.T
    f = model.input_map @ u - terms.Cqd - terms.g
    lam = np.linalg.pinv(S, rcond=CONSTRAINT_RCOND, hermitian=True) @ (-cons.bias - cons.Jc @ Minv @ f)
    return Minv @ (f + cons.Jc.T @ lam), lam


@pytest.mark.parametrize("delta, rank", [(0.0, 1), (1e-6, 1), (3e-5, 2)])
def test_four_bar_near_its_change_point_gives_the_minimum_norm_solution(delta, rank):
    """On the parallelogram branch at q = (pi/2 + d, -d, pi/2 + d) the smaller eigenvalue of S over the larger is
    ~ 6e-13 (d / 1e-6)^2: at d = 0 and 1e-6 below CONSTRAINT_RCOND (that direction is redundant, rank 1), at d = 3e-5
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


def test_four_bar_moving_off_both_branches_is_finite():
    """At the change point a velocity off both branches makes the system inconsistent (H_t empty): the answer is
    finite, the range-space one with the redundant direction's equation dropped, and the harness sees the
    inconsistency in the conditions."""
    model = cases.load("four_bar")
    q, qd, u = np.array([math.pi / 2, 0.0, math.pi / 2]), np.array([1.0, 0.3, -0.2]), np.array([0.5, -1.0, 2.0])
    s = el.split(model, q, qd, u)
    assert s.constraint_rank == 1 and s.conditions["constraint_consistency"] > 1e-3
    for key in ("drift", "ctrl", "total", "lam", "lam_drift"):
        assert np.all(np.isfinite(getattr(s, key))), key
    qdd, lam = range_space_reference(model, q, qd, u)
    assert_close(s.total, qdd, "total (redundant equation dropped)")
    assert_close(s.lam, lam, "lam (redundant equation dropped)")
    assert_close(s.drift + s.ctrl, s.total, "additivity", scale=np.abs(s.total).max())


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
