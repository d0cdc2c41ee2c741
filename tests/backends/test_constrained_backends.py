"""Constrained dynamics (article section 5: eqs. 12-17, the KKT system of 5.6) in every backend, the five formalisms
and the Pinocchio reference (``crosscheck.backends``), against references written independently in ``closed_forms.py``
(the article's closed forms; ``phi``, ``Jc``, ``Jcdot qd`` differentiated by hand) and here:

* ``cartesian_pendulum``: the multiplier's closed form ``lam = -m (|v|^2 + p . (gravity + u / m)) / (2 L^2)``, the
  accelerations ``m a = m gravity + u + 2 lam p`` and ``ctrl = (I - p p^T / L^2) u / m``.
* ``double_pendulum_circle`` (default and other parameters) at admissible states found by hand: a 3x3 KKT solve of
  eqs. (6)-(8), ``B_c`` of eq. (17), the tip's drift acceleration (eq. 23), the kinetic energy; and ``ctrl`` solved
  directly (not ``total - drift``) where the drift dwarfs it.
* A gear (joint coupling) and a rail (point on a line) on the article's double pendulum: their KKT solves; the
  cartesian pendulum's bob also on a rail (no freedom left): at rest, multipliers by hand.
* ``double_pendulum_absolute_loop`` at the image of a joint state: eqs. (6)-(8) with the links' inertias and the
  joint model ``double_pendulum(I1=.., I2=..)``, and the pin multipliers are the pin forces of Newton's second law.
* Eqs. (12)-(17) as identities at sampled admissible states of every constrained case (``crosscheck.core.sampling``):
  ``drift + ctrl = total``, both on ``H_t`` (eq. 16), ``ctrl = B_c B u`` and eq. (15) with M from the reference,
  ``Jc^T lam``, zero constraint power (5.5).
* Redundant rows: a duplicated circle (the same motion and ``Jc^T lam``, half the multiplier each, rank 1), and the
  four-bar at its change point against the minimum-norm (range-space) solve with M from the reference and ``Jc``,
  ``Jcdot qd`` by hand, moving along a branch (consistent) and off both (``H_t`` empty: finite, flagged).

Bounds are the tightest of the former per-backend tests (``test_constrained_<backend>.py`` before they were merged
here). A few of those held only at their hand-picked states: the circle's and the absolute loop's keep those states
with those bounds (``former``), and states drawn from a seeded generator get the bounds that the worst of some
thousands of drawn states per backend needs, with a margin (``drawn``). Pinocchio regularizes its KKT solve where
``S`` is singular (``crosscheck.references.pinocchio.reference``: damping ``1e-12 |S|``), which moves its answer by ~1e-12 relative: at
redundant states it is held to ``DAMPED_RTOL`` (its former test: 1e-9 absolute). The operational-space backend's
default four-bar task point is singular at the change point (a task BREAKDOWN, tested in its own file): there it
tracks the coupler's midpoint along y only. Like the gate's tests, these use the shared Euler–Lagrange disk cache
(keyed by the model digest and a hash of the derivation's source, so it cannot change an answer; the parameter sets
here are fixed, so it stays small); ``test_constrained_euler_lagrange.py`` derives its models afresh.
"""

from __future__ import annotations

import dataclasses
import functools

import numpy as np
import pytest

import cases
from cases import JointCoupling, PointOnLine, TaskPoint, build_model
from closed_forms import (absolute_loop_state, cartesian_lam, circle_state, circle_terms, constrained_input_map,
                          disk_inertia, endpoint_jacobian, kkt_solve, loop_to_joint, min_norm_solve, pendulum_terms,
                          pin_forces, tip_bias)
from crosscheck import backends
from crosscheck.references.pinocchio import reference
from crosscheck.core import sampling
from crosscheck.core import tolerance as policy
from crosscheck.guards.conditioning import normwise_scales
from formalisms.interface import CONSTRAINT_RCOND, Unsupported

BACKENDS = backends.names()
CONSTRAINED = ("double_pendulum_circle", "four_bar", "slider_crank", "cartesian_pendulum",
               "double_pendulum_absolute_loop")
G = 9.81
#: Relative bound at redundant states (S singular): Pinocchio's damped KKT (module doc); the formalisms' 1e-12.
DAMPED_RTOL = {"pinocchio": 1e-10}


def damped_rtol(name):
    return DAMPED_RTOL.get(name, 1e-12)


@functools.lru_cache(maxsize=None)
def model_of(name, **params):
    return cases.load(name, **params)


def split(name, model, q, qd, u):
    return backends.get(name).split(model, *(np.asarray(x, dtype=float) for x in (q, qd, u)))


def check(got, want, tol, what):
    """``max |got - want| <= tol`` (NaN fails)."""
    got, want = np.asarray(got, dtype=float), np.asarray(want, dtype=float)
    err = float(np.abs(got - want).max(initial=0.0))
    assert err <= tol, f"{what}: error {err:.3e} > tolerance {tol:.3e}\n  got  {got.tolist()}\n  want {want.tolist()}"


def sup(x):
    return float(np.abs(x).max(initial=0.0))


def supported(value):
    return not isinstance(value, Unsupported)


# ----------------------------------------------------------------------------------------------------------
# cartesian_pendulum: the multiplier's closed form
# ----------------------------------------------------------------------------------------------------------

def cartesian_states():
    """((m, L), angle a, rate w, u): the former tests' hand-picked states, then seeded draws."""
    states = [((1.0, 1.0), 0.3, 0.0, (0.0, 0.0)), ((1.0, 1.0), -1.2, 2.5, (3.0, -1.0)),
              ((2.5, 0.7), 2.8, -1.7, (-4.0, 6.0)), ((0.3, 2.0), np.pi / 2, 0.9, (0.5, 0.5))]
    rng = np.random.default_rng(11)
    for params in ((1.0, 1.0), (2.5, 0.7), (0.3, 2.0), (1.0, 1.0)):
        states.append((params, rng.uniform(-np.pi, np.pi), rng.uniform(-5.0, 5.0), tuple(rng.uniform(-20, 20, 2))))
    return states


@pytest.mark.parametrize("name", BACKENDS)
def test_cartesian_pendulum_multiplier_is_the_closed_form(name):
    """At p = L (sin a, -cos a) with v = w L (cos a, sin a) tangent: lam and lam_drift in closed form, eq. (12) with
    M = m I, B = I, Jc = 2 p^T (``m a = m gravity + u + 2 lam p``), ctrl the input projected on the tangent,
    ``Jcdot qd = 2 |v|^2``, the split identities and zero constraint power, rank 1."""
    gravity = np.array([0.0, -G])
    for (m, L), a, w, u in cartesian_states():  # noqa: N806
        p, v, u = L * np.array([np.sin(a), -np.cos(a)]), w * L * np.array([np.cos(a), np.sin(a)]), np.array(u)
        s = split(name, model_of("cartesian_pendulum", m=m, L=L), p, v, u)
        lam, lam0 = cartesian_lam(p, v, u, m, L), cartesian_lam(p, v, np.zeros(2), m, L)
        scale = m * (v @ v + L * (G + np.abs(u).sum() / m)) / L**2           # the sizes summed into lam
        check(s.lam, [lam], 1e-13 * min(max(1.0, abs(lam)), scale), "lam")
        check(s.lam_drift, [lam0], 1e-13 * min(max(1.0, abs(lam0)), scale), "lam_drift")
        check(s.total, gravity + (u + 2.0 * lam * p) / m, 1e-12, "total: m a = m gravity + u + 2 lam p")
        check(s.drift, gravity + 2.0 * lam0 * p / m, 1e-12, "drift")
        check(s.ctrl, (np.eye(2) - np.outer(p, p) / L**2) @ u / m, 1e-14 * np.abs(u).sum() / m, "ctrl = B_c u")
        check(s.constraint_value, [0.0], 1e-12 * L**2, "phi")
        check(s.constraint_jacobian, [2.0 * p], 1e-15, "Jc = 2 p^T")
        check(s.constraint_bias, [2.0 * v @ v], max(1e-14 * 2.0 * v @ v, 1e-15), "Jcdot qd = 2 |v|^2")
        check(s.additivity, 0.0, 1e-13 * max(1.0, sup(s.total)), "drift + ctrl = total")
        check(s.admissibility_total, 0.0, 1e-13 * scale * L, "H_t residual (total)")
        check(s.admissibility_drift, 0.0, 1e-13 * scale * L, "H_t residual (drift)")
        check(s.constraint_force, s.constraint_jacobian.T @ s.lam, 1e-12 * (sup(s.lam) + sup(s.constraint_force)),
              "Jc^T lam")
        check(s.power_constr, 0.0, 1e-12 * min(scale * L * np.abs(v).sum(), sup(s.constraint_force)), "P_constr")
        assert s.constraint_rank == 1


# ----------------------------------------------------------------------------------------------------------
# double_pendulum_circle: a 3x3 KKT solve from the article's closed forms
# ----------------------------------------------------------------------------------------------------------

CIRCLES = {"default": dict(m1=1.0, m2=1.0, l1=1.0, l2=1.0, xc=1.0, yc=-1.0, R=0.5),
           "odd": dict(m1=0.7, m2=1.9, l1=1.2, l2=0.8, xc=0.4, yc=-1.3, R=0.6)}
#: (circle, beta, elbow, rate, u) of the former tests with bounds tighter than drawn states allow: the Newton–Euler
#: and screw ones (both elbow branches) and the reference's (the tip projected from q = (0.3, 1.2)).
FORMER_CIRCLE_STATES = [
    ("default", 0.4, 1.0, 0.0, (2.0, -1.0)), ("default", 2.0, 1.0, 1.5, (-3.0, 4.0)),
    ("default", -2.5, 1.0, -2.2, (0.5, 0.0)), ("default", np.pi, 1.0, 0.7, (0.0, 0.0)),
    ("default", 0.4, -1.0, 0.0, (2.0, -1.0)), ("default", 2.0, -1.0, 1.5, (-3.0, 4.0)),
    ("default", -2.5, -1.0, -2.2, (0.5, 0.0)), ("default", 0.4458322075611338, 1.0, -1.7, (3.0, -2.0))]


def drawn_circle_states(count=4):
    rng = np.random.default_rng(5)
    return [(circle, rng.uniform(-np.pi, np.pi), rng.choice([-1.0, 1.0]), rng.uniform(-4.0, 4.0),
             tuple(rng.uniform(-20.0, 20.0, 2))) for circle in ("default", "odd") * (count // 2)]


def circle_geometry(params):
    return {k: params[k] for k in ("l1", "l2", "xc", "yc", "R")}


def circle_reference(t, td, u, params):
    """total, lam, drift, lam_drift (KKT of 5.6), ctrl = B_c u (eq. 17), (phi, Jc, Jcdot qd) and M, all by hand."""
    M, Cqd, g = pendulum_terms(t, td, params["m1"], params["m2"], params["l1"], params["l2"], G)  # noqa: N806
    phi, Jc, bias = terms = circle_terms(t, td, **circle_geometry(params))
    total, lam = kkt_solve(M, Jc, u - Cqd - g, bias)
    drift, lam_drift = kkt_solve(M, Jc, -Cqd - g, bias)
    return total, lam, drift, lam_drift, constrained_input_map(M, Jc) @ u, terms, M


def check_circle(name, circle, beta, elbow, rate, u, drawn):
    """One state of ``test_double_pendulum_circle_against_the_kkt_solve``; ``drawn``: the additivity, H_t and
    per-coordinate power bounds that drawn states need (module doc), else the former tests' tighter ones."""
    params = CIRCLES[circle]
    t, td = circle_state(beta, elbow, rate, **circle_geometry(params))
    u = np.asarray(u, dtype=float)
    total, lam, drift, lam_drift, ctrl, (phi, Jc, bias), M = circle_reference(t, td, u, params)  # noqa: N806
    assert abs(phi) <= 1e-14 * params["R"] ** 2, "the hand-made state is on the circle"
    s = split(name, model_of("double_pendulum_circle", **params), t, td, u)
    sc, jc, rtol = max(1.0, sup(total), sup(drift)), sup(Jc), 1e-13 if drawn else 1e-14
    check(s.constraint_value, [0.0], 1e-14, "phi")
    check(s.constraint_jacobian, [Jc], 1e-14 * min(1.0, jc), "Jc")
    check(s.constraint_bias, [bias], 1e-13 * min(max(1.0, abs(bias)), abs(bias) + td @ td) + 1e-300, "Jcdot qd")
    check(s.total, total, 1e-13 * sc, "total vs KKT")
    check(s.drift, drift, 1e-13 * sc, "drift vs KKT (u = 0, eq. 14)")
    check(s.ctrl, ctrl, 1e-12, "ctrl = B_c u (eq. 17)")
    check(s.lam, lam, 1e-13 * (1.0 + sup(lam)), "lam vs KKT")
    check(s.lam_drift, lam_drift, 1e-13 * (1.0 + sup(lam_drift)), "lam_drift vs KKT")
    check(s.constraint_force, Jc * lam[0], 1e-13 * (1.0 + sup(lam)) * jc, "Jc^T lam")
    check(s.constraint_force_drift, Jc * lam_drift[0], 1e-13 * (1.0 + sup(lam_drift)) * jc, "Jc^T lam_drift")
    check(s.additivity, 0.0, rtol * sc, "drift + ctrl = total")
    check(s.admissibility_total, 0.0, rtol * jc * sc, "H_t residual (total)")
    check(s.admissibility_drift, 0.0, rtol * jc * sc, "H_t residual (drift)")
    check(Jc @ s.ctrl, 0.0, rtol * jc * sc, "Jc ctrl")
    check(s.power_constr, 0.0, 1e-13 * sup(Jc * lam[0]) * sup(td) + 1e-300, "P_constr")
    check(s.power_constr_per_coord, Jc * lam[0] * td,
          1e-12 * ((1.0 + sup(lam)) * jc * sup(td) if drawn else sup(lam)), "P_constr per coordinate")
    if supported(s.task_drift):
        l1, l2 = params["l1"], params["l2"]
        check(s.task_drift, endpoint_jacobian(t, l1, l2) @ drift + tip_bias(t, td, l1, l2), 1e-12 * sc,
              "tip drift acceleration (eq. 23)")
    T = 0.5 * td @ M @ td  # noqa: N806
    check(s.kinetic_energy, T, 1e-13 * T + 1e-300, "T = 1/2 qd^T M qd")
    assert s.constraint_rank == 1 and s.conditions["constraint_consistency"] == 0.0 and not policy.breakdown(s)


@pytest.mark.parametrize("name", BACKENDS)
def test_double_pendulum_circle_against_the_kkt_solve(name):
    """Article 5.6 at admissible states found by hand (the former tests' and drawn ones): phi, Jc, Jcdot qd as
    differentiated by hand; qdd and lam with and without u (eq. 14) from the 3x3 KKT system of eqs. (6)-(8);
    ctrl = B_c u (eq. 17); drift + ctrl = total, both on H_t (eq. 16), Jc ctrl = 0; Jc^T lam and its zero power (5.5,
    also per coordinate); the tip's drift acceleration (eq. 23); T = 1/2 qd^T M qd; rank 1, consistent, no
    BREAKDOWN."""
    for state in FORMER_CIRCLE_STATES:
        check_circle(name, *state, drawn=False)
    for state in drawn_circle_states():
        check_circle(name, *state, drawn=True)


@pytest.mark.parametrize("name", BACKENDS)
def test_ctrl_is_solved_directly_not_as_total_minus_drift(name):
    """Where the drift dwarfs the control, ``total - drift`` would lose every digit of ``ctrl = B_c u``."""
    t, _ = circle_state(0.4, 1.0)
    _, Jc, _ = circle_terms(t, np.zeros(2))
    td, u = 3e3 * np.array([Jc[1], -Jc[0]]), np.array([1e-6, -2e-6])
    ctrl = constrained_input_map(pendulum_terms(t, td)[0], Jc) @ u
    check(split(name, model_of("double_pendulum_circle"), t, td, u).ctrl, ctrl, 1e-12 * sup(ctrl), "ctrl")


# ----------------------------------------------------------------------------------------------------------
# A gear and a rail on the article's double pendulum; the cartesian pendulum locked by a rail
# ----------------------------------------------------------------------------------------------------------

GEAR = JointCoupling("gear", ("link1", "link2"), (1.0, -2.0), 0.1)                    # t1 - 2 t2 - 0.1
RAIL = PointOnLine("rail", "link2", (0.0, -1.0, 0.0), (1.2, 0.0, 0.0), ((1.0, 0.0, 0.0),))  # x2 = 1.2


@functools.lru_cache(maxsize=None)
def double_pendulum_with(kind):
    base, constraint = model_of("double_pendulum"), {"gear": GEAR, "rail": RAIL}[kind]
    return build_model(f"double_pendulum_{kind}", base.bodies, gravity=base.gravity, task_points=base.task_points,
                       constraints=[constraint])


def gear_and_rail_states():
    """Admissible states by hand: the gear's t1 = 2 t2 + 0.1 with qd along (2, 1); the rail's sin t1 + sin(t1 + t2)
    = 1.2 with qd along the null vector of J's first row (eq. 5)."""
    states = [("gear", (0.7, 0.3), (1.4, 0.7), (2.0, -3.0)), ("gear", (0.7, 0.3), (2.0, 1.0), (1.0, -1.0))]
    rng = np.random.default_rng(9)
    t2, rate, u = rng.uniform(-2.0, 2.0), rng.uniform(-3.0, 3.0), tuple(rng.uniform(-10.0, 10.0, 2))
    states.append(("gear", (2.0 * t2 + 0.1, t2), tuple(rate * np.array([2.0, 1.0])), u))
    t1 = rng.uniform(0.3, 1.5)
    t = np.array([t1, np.arcsin(1.2 - np.sin(t1)) - t1])
    J = endpoint_jacobian(t)[0]
    return states + [("rail", tuple(t), tuple(rate * np.array([J[1], -J[0]])), u)]


@pytest.mark.parametrize("name", BACKENDS)
def test_gear_and_rail_against_the_kkt_solve(name):
    """A JointCoupling (``Jc = (1, -2)``, ``Jcdot qd = 0``) and a PointOnLine (``x2 = 1.2``: ``Jc`` the first row of
    eq. (5), ``Jcdot qd`` the first of the tip's bias) on the article's double pendulum: phi, Jc, Jcdot qd, the KKT
    solution with and without u, ctrl = B_c u, H_t residuals and zero constraint power."""
    for kind, t, td, u in gear_and_rail_states():
        t, td, u = np.array(t), np.array(td), np.array(u)
        if kind == "gear":
            phi, Jc, bias = t[0] - 2.0 * t[1] - 0.1, np.array([1.0, -2.0]), 0.0
        else:
            phi, Jc, bias = np.sin(t[0]) + np.sin(t[0] + t[1]) - 1.2, endpoint_jacobian(t)[0], tip_bias(t, td)[0]
        M, Cqd, g = pendulum_terms(t, td)  # noqa: N806
        total, lam = kkt_solve(M, Jc, u - Cqd - g, bias)
        drift, lam_drift = kkt_solve(M, Jc, -Cqd - g, bias)
        s = split(name, double_pendulum_with(kind), t, td, u)
        sc, what = max(1.0, sup(total), sup(drift)), f"{kind} at {t.tolist()}"
        check(s.constraint_value, [phi], 1e-15, f"{what}: phi")
        check(s.constraint_jacobian, [Jc], 1e-15, f"{what}: Jc")
        check(s.constraint_bias, [bias], 0.0 if kind == "gear" else 1e-14 * max(1.0, td @ td), f"{what}: Jcdot qd")
        check(s.total, total, 1e-12 * sup(total), f"{what}: total")
        check(s.drift, drift, 1e-12 * sup(drift), f"{what}: drift")
        check(s.ctrl, constrained_input_map(M, Jc) @ u, 1e-12 * sc, f"{what}: ctrl = B_c u")
        check(s.lam, lam, 1e-12 * sup(lam), f"{what}: lam")
        check(s.lam_drift, lam_drift, 1e-12 * sup(lam_drift), f"{what}: lam_drift")
        check(s.additivity, 0.0, 1e-13 * sc, f"{what}: drift + ctrl = total")
        check(s.admissibility_total, 0.0, 1e-13 * s.accel_scale * min(1.0, sup(Jc)), f"{what}: H_t residual (total)")
        check(s.admissibility_drift, 0.0, 1e-13 * s.accel_scale * min(1.0, sup(Jc)), f"{what}: H_t residual (drift)")
        check(s.power_constr, 0.0, 1e-12 * sup(s.constraint_force) * np.abs(td).sum(), f"{what}: P_constr")


@pytest.mark.parametrize("name", BACKENDS)
def test_a_pendulum_locked_by_a_rail_rests_with_the_multipliers_by_hand(name):
    """The cartesian pendulum's bob also on the line x = 0.6 (no freedom left): at rest qdd = 0 and
    ``Jc^T lam = -(B u - dV/dq)`` with ``Jc = [[2x, 2y], [1, 0]]``, rank 2."""
    bob = model_of("cartesian_pendulum")
    line = PointOnLine("x", "bob", np.zeros(3), np.array([0.6, 0.0, 0.0]), np.array([[1.0, 0.0, 0.0]]))
    locked = build_model("locked", bob.bodies, gravity=bob.gravity, task_points=bob.task_points,
                         constraints=[*bob.constraints, line])
    x, u = np.array([0.6, -0.8]), np.array([1.0, 1.0])
    s = split(name, locked, x, np.zeros(2), u)
    Jc = np.array([[2 * x[0], 2 * x[1]], [1.0, 0.0]])
    check(s.constraint_value, 0.0, 1e-15, "phi")
    check(s.constraint_jacobian, Jc, 1e-15, "Jc")
    for key in ("total", "drift", "ctrl"):
        check(s.quantity(key), 0.0, 1e-14, key)
    check(s.lam, np.linalg.solve(Jc.T, -(u - [0.0, G])), 1e-13, "lam")
    assert s.constraint_rank == 2


# ----------------------------------------------------------------------------------------------------------
# The absolute loop is the double pendulum
# ----------------------------------------------------------------------------------------------------------

LOOPS = [dict(m1=1.0, m2=1.0, l1=1.0, l2=1.0, I1=0.1, I2=0.1),          # the loop's defaults
         dict(m1=1.3, m2=0.8, l1=0.9, l2=1.2, I1=0.05, I2=0.2)]
#: (parameter set, t, td, u) of the former tests with bounds tighter than drawn states allow: the Newton–Euler ones
#: (the screw one's were its first two, on other parameters) and the reference's.
FORMER_LOOP_STATES = [(1, (0.3, 0.5), (0.7, -1.1), (1.0, -0.5)), (1, (-2.0, 1.2), (-2.5, 3.0), (0.0, 4.0)),
                      (1, (3.0, -0.2), (0.0, 0.0), (-6.0, 2.0)), (0, (0.4, -1.1), (1.2, -0.7), (1.5, -2.0))]


def drawn_loop_states():
    rng = np.random.default_rng(7)
    return [(loop, rng.uniform(-np.pi, np.pi, 2), rng.uniform(-4.0, 4.0, 2), rng.uniform(-20.0, 20.0, 2))
            for loop in range(len(LOOPS))]


def check_absolute_loop(name, loop, t, td, u, drawn):
    """One state of ``test_absolute_loop_is_the_joint_coordinate_pendulum``; ``drawn``: the acceleration and H_t
    bounds that drawn states need (module doc), else the former tests' tighter ones."""
    params = LOOPS[loop]
    t, td, u = (np.asarray(x, dtype=float) for x in (t, td, u))
    q, qd = absolute_loop_state(t, td, params["l1"])
    s = split(name, model_of("double_pendulum_absolute_loop", **params), q, qd, u)
    joint_model = model_of("double_pendulum", **params)
    joint = split(name, joint_model, t, td, u)
    dynamics = {k: params[k] for k in ("m1", "m2", "l1", "l2")}
    M, Cqd, g = pendulum_terms(t, td, **dynamics)  # noqa: N806
    M = M + disk_inertia(params["I1"], params["I2"])  # noqa: N806
    expected = {"total": np.linalg.solve(M, u - Cqd - g), "drift": np.linalg.solve(M, -Cqd - g),
                "ctrl": np.linalg.solve(M, u)}
    sc, size = max(1.0, sup(expected["total"])), max(1.0, sup(s.total), sup(s.drift))
    # drawn states: 1e-12 of the accelerations the summed terms could produce; the former states: 1e-12 absolute
    bound = 1e-12 * normwise_scales(joint_model, M, Cqd, g, u, td)[1] if drawn else 1e-12
    check(s.constraint_value, np.zeros(4), 1e-15, "phi")
    for key, tdd in expected.items():
        check(loop_to_joint(s.quantity(key)), tdd, bound, f"{key}: loop vs eqs. (6)-(8)")
    T = 0.5 * td @ M @ td  # noqa: N806
    check(s.kinetic_energy, T, 1e-13 * T, "T")
    check(s.power_ctrl, u @ td, 1e-14 * np.abs(u).sum() * np.abs(td).sum() + 1e-300, "u . B^T qd")
    if not policy.breakdown(joint):          # (the operational-space joint model at its stretched arm is one)
        for key in expected:
            check(loop_to_joint(s.quantity(key)), joint.quantity(key), bound, f"{key}: loop vs the joint model")
        check(joint.kinetic_energy, T, 1e-13 * T, "T of the joint model")
        if supported(s.task_drift):
            check(s.task_drift, joint.task_drift, 1e-12 * sc, "tip drift acceleration")
    for lam, tdd in ((s.lam, expected["total"]), (s.lam_drift, expected["drift"])):
        shoulder, elbow = pin_forces(t, td, tdd, **dynamics, g=G)
        check(lam, np.concatenate([shoulder, elbow]), 1e-12 * s.lam_scale, "pin multipliers = pin forces")
    check(s.additivity, 0.0, 3e-12 * size, "drift + ctrl = total")
    check(s.admissibility_total, 0.0, 1e-12 * size if drawn else 1e-13 * sc, "H_t residual (total)")
    check(s.admissibility_drift, 0.0, 1e-12 * size if drawn else 1e-13 * sc, "H_t residual (drift)")
    check(s.power_constr, 0.0, 1e-13 * sup(s.constraint_force) * sup(qd) + 1e-300, "P_constr")
    assert s.constraint_rank == 4


@pytest.mark.parametrize("name", BACKENDS)
def test_absolute_loop_is_the_joint_coordinate_pendulum(name):
    """Two free bodies pinned together (4 rows, 6 coordinates) at the image of a joint state (the former tests' and
    drawn ones): theta1dd = phi1dd and theta2dd = phi2dd - phi1dd for total, drift and ctrl, equal to eqs. (6)-(8)
    with the links' inertias and to the same backend's ``double_pendulum`` with the same inertias; the same kinetic
    energy, control power and tip drift; the pin multipliers are the pin forces (Newton: the elbow's on link 2, the
    shoulder's on the chain); on H_t, no constraint work, rank 4."""
    for state in FORMER_LOOP_STATES:
        check_absolute_loop(name, *state, drawn=False)
    for state in drawn_loop_states():
        check_absolute_loop(name, *state, drawn=True)


# ----------------------------------------------------------------------------------------------------------
# Eqs. (12)-(17) as identities at sampled admissible states of every constrained case
# ----------------------------------------------------------------------------------------------------------

@functools.lru_cache(maxsize=None)
def sampled(case):
    """Three admissible states (``crosscheck.core.sampling``) with M from the reference (Pinocchio's CRBA)."""
    model = model_of(case)
    return [(np.array(x.q), np.array(x.qd), np.array(x.u), reference.split(model, x.q, x.qd, x.u).extras["M"])
            for x in sampling.sample_states(model, 3, 5, case)]


@pytest.mark.parametrize("case", CONSTRAINED)
@pytest.mark.parametrize("name", BACKENDS)
def test_split_identities_at_sampled_admissible_states(name, case):
    """drift + ctrl = total (eq. 9), both on H_t (eq. 16), ``ctrl = B_c B u`` (eq. 17) and eq. (15)
    ``M ctrl = B u + Jc^T (lam - lam_drift)``, ``Jc^T lam``, zero constraint power (5.5); phi = 0 and Jc qd = 0 in
    the backend's own kinematics; full rank, consistent."""
    model = model_of(case)
    for q, qd, u, M in sampled(case):  # noqa: N806
        s = split(name, model, q, qd, u)
        tau, jc = model.input_map @ u, sup(s.constraint_jacobian)
        sc = max(1.0, sup(s.total), sup(s.drift))
        check(s.constraint_value, 0.0, 1e-12 * model.length_scale ** 2, "phi")
        check(s.constraint_velocity, 0.0, 1e-12 * (1.0 + np.abs(qd).sum()), "Jc qd")
        check(s.additivity, 0.0, 1e-13 * s.accel_scale, "drift + ctrl = total")
        check(s.admissibility_total, 0.0, 1e-12 * sc * min(1.0, jc), "H_t residual (total)")
        check(s.admissibility_drift, 0.0, 1e-12 * sc * min(1.0, jc), "H_t residual (drift)")
        check(s.ctrl, constrained_input_map(M, s.constraint_jacobian) @ tau, 1e-12 * s.accel_scale, "ctrl = B_c B u")
        check(M @ s.ctrl, tau + s.constraint_force - s.constraint_force_drift, 1e-12 * s.accel_scale * sup(M),
              "eq. (15)")
        check(s.constraint_force, s.constraint_jacobian.T @ s.lam, 1e-12 * (sup(s.lam) + sup(s.constraint_force)),
              "Jc^T lam")
        check(s.power_constr, 0.0, 1e-11 * s.lam_scale * jc * np.abs(qd).sum(), "P_constr")
        assert s.constraint_rank == model.k and s.conditions["constraint_consistency"] <= 1e-10


# ----------------------------------------------------------------------------------------------------------
# Redundant rows: a duplicated circle, the four-bar at its change point
# ----------------------------------------------------------------------------------------------------------

@functools.lru_cache(maxsize=None)
def circle_twice():
    single = model_of("double_pendulum_circle")
    circle = single.constraints[0]
    return build_model("circle_twice", single.bodies, gravity=single.gravity, task_points=single.task_points,
                       constraints=[circle, dataclasses.replace(circle, name="tip_on_circle_again")])


@functools.lru_cache(maxsize=None)
def duplicate_states():
    """(t, td, u) of the former tests: the Newton–Euler and screw ones on both elbow branches, the reference's
    sampled one."""
    state = sampling.sample_states(model_of("double_pendulum_circle"), 2, 0, "dup")[1]
    return [(*circle_state(1.1, 1.0, 1.3), (1.5, -2.0)), (*circle_state(-0.7, -1.0, 2.0), (-1.0, 2.5)),
            (state.q, state.qd, state.u)]


@pytest.mark.parametrize("name", BACKENDS)
def test_a_duplicated_constraint_gives_the_same_motion_and_half_multipliers(name):
    """Two copies of the circle: S is singular (rank 1), consistent; the accelerations and ``Jc^T lam`` are the single
    constraint's and the minimum-norm multipliers split its multiplier in halves."""
    single, double = model_of("double_pendulum_circle"), circle_twice()
    assert double.k == 2
    rtol = damped_rtol(name)
    for t, td, u in duplicate_states():
        one, two = split(name, single, t, td, u), split(name, double, t, td, u)
        sc = max(1.0, sup(one.total))
        assert two.constraint_rank == 1 and one.constraint_rank == 1
        assert two.conditions["constraint"] > 1e12 and two.conditions["constraint_consistency"] < 1e-12
        for key in ("total", "drift", "ctrl"):
            check(two.quantity(key), one.quantity(key), rtol * sc, key)
        for key in ("constraint_force", "constraint_force_drift"):
            check(two.quantity(key), one.quantity(key), 0.1 * rtol * max(1.0, sup(one.quantity(key))), key)
        check(two.lam, np.repeat(one.lam / 2.0, 2), rtol * sup(one.lam) / 2.0, "lam = half each (minimum norm)")
        check(two.lam_drift, np.repeat(one.lam_drift / 2.0, 2), rtol * sup(one.lam_drift) / 2.0, "lam_drift: halves")


CHANGE_POINT = np.array([np.pi / 2, 0.0, np.pi / 2])


@functools.lru_cache(maxsize=None)
def four_bar_for(name):
    """The four-bar; for the operational-space backend with its task point moving along y only (module doc)."""
    model = model_of("four_bar")
    if name != "operational_space":
        return model
    tp = model.task_point()
    return build_model("four_bar_y", model.bodies, gravity=model.gravity, constraints=model.constraints,
                       task_points=[TaskPoint(tp.name, tp.body, tp.offset, [[0.0, 1.0, 0.0]])])


def change_point_rows(qd):
    """The four-bar's loop rows at q = (pi/2, 0, pi/2) by hand (``cases.four_bar``: crank 1, coupler 2, rocker 1,
    ground 2; phi = crank end + coupler end - rocker end, a link at absolute angle a pointing along (sin a, -cos a)):
    all three links point along +x, so ``Jc = [[0, 0, 0], [3, 2, -1]]`` (the x row vanishes: rank 1) and
    ``Jcdot qd = (q3d^2 - q1d^2 - 2 (q1d + q2d)^2, 0)``: zero in x along the parallelogram branch (1, -1, 1)."""
    Jc = np.array([[0.0, 0.0, 0.0], [3.0, 2.0, -1.0]])  # noqa: N806
    return Jc, np.array([qd[2]**2 - qd[0]**2 - 2.0 * (qd[0] + qd[1])**2, 0.0])


@functools.lru_cache(maxsize=None)
def change_point_reference(qd, u):
    """total, lam, drift, lam_drift, ctrl of the minimum-norm (range-space) solve: M, C qd + g from the reference
    (Pinocchio), Jc and Jcdot qd by hand (an inconsistent x row is dropped with the redundant direction)."""
    model, qd, u = model_of("four_bar"), np.array(qd), np.array(u)
    r = reference.split(model, CHANGE_POINT, qd, u)
    M, h, tau = r.extras["M"], r.extras["Cqd"] + r.extras["g"], model.input_map @ u  # noqa: N806
    Jc, bias = change_point_rows(qd)  # noqa: N806
    total, lam = min_norm_solve(M, Jc, tau - h, bias, CONSTRAINT_RCOND)
    drift, lam_drift = min_norm_solve(M, Jc, -h, bias, CONSTRAINT_RCOND)
    ctrl, _ = min_norm_solve(M, Jc, tau, np.zeros(2), CONSTRAINT_RCOND)
    return {"total": total, "lam": lam, "drift": drift, "lam_drift": lam_drift, "ctrl": ctrl}


def check_change_point(name, qd, u):
    """No exception; phi = 0, Jc and Jcdot qd by hand; finite; the minimum-norm solve; additivity; the y row holds;
    rank 1. Returns the split."""
    rtol = damped_rtol(name)
    s = split(name, four_bar_for(name), CHANGE_POINT, qd, u)
    Jc, bias = change_point_rows(qd)  # noqa: N806
    check(s.constraint_value, 0.0, 1e-15, "phi at the change point")
    check(s.constraint_jacobian, Jc, 1e-14, "Jc by hand")
    check(s.constraint_bias, bias, 1e-14 * max(1.0, qd @ qd), "Jcdot qd by hand")
    for key in ("drift", "ctrl", "total", "lam", "lam_drift", "task_drift"):
        if supported(s.quantity(key)):
            assert np.all(np.isfinite(s.quantity(key))), key
    for key, want in change_point_reference(tuple(qd), tuple(u)).items():
        check(s.quantity(key), want, rtol * sup(want), f"{key} vs the minimum-norm solve")
    check(s.additivity, 0.0, 0.01 * rtol * sup(s.total), "drift + ctrl = total")
    check(s.admissibility_total[1], 0.0, rtol * s.accel_scale, "the y row holds (total)")
    assert s.constraint_rank == 1
    return s


@pytest.mark.parametrize("name", BACKENDS)
def test_four_bar_at_its_change_point_moving_along_a_branch(name):
    """q = (pi/2, 0, pi/2): the loop Jacobian loses its x row (rank 1). At rest or along the parallelogram branch
    (1, -1, 1) the x row's bias vanishes too, so H_t is not empty: no exception, and the answer is the minimum-norm
    one (the unique accelerations; lam_x = 0), consistent, on H_t."""
    for qd in ((0.0, 0.0, 0.0), (1.0, -1.0, 1.0)):
        s = check_change_point(name, np.array(qd), np.array([1.0, -2.0, 0.5]))
        assert s.conditions["constraint_consistency"] < 1e-12
        check(s.admissibility_total, 0.0, damped_rtol(name) * s.accel_scale, "H_t residual (total)")
        check(s.admissibility_drift, 0.0, damped_rtol(name) * s.accel_scale, "H_t residual (drift)")


@pytest.mark.parametrize("name", BACKENDS)
def test_four_bar_at_its_change_point_moving_off_both_branches(name):
    """At the change point a velocity off both branches, e.g. (0, 1, 2) in null(Jc), makes the x row's bias non-zero
    while its Jacobian row is 0: H_t is empty. No exception: finite numbers, the minimum-norm solve with the
    redundant row dropped, and the inconsistency flagged in the conditions (a BREAKDOWN for the harness)."""
    for qd in ((0.0, 1.0, 2.0), (1.0, 0.3, -0.2)):
        s = check_change_point(name, np.array(qd), np.array([0.5, -1.0, 2.0]))
        assert s.conditions["constraint_consistency"] > 0.1
        assert "constraint_consistency" in policy.breakdown(s)
