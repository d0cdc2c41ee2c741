"""The geometric backend on spherical and free joints (issue 17; article 2.1-2.2, 6.2, 6.4 "the globe, not the map").

The backend works in the group chart at the current configuration, ``q (+) xi`` with the group exponential on the
right (``R0 exp([xi]x)`` on SO(3), ``X0 exp6(xi)`` on SE(3), twist order (linear, angular)), truncated to its Taylor
polynomial of degree 2 (``formalisms.geometric.EXP_ORDER``), every derivative taken at ``xi = 0``. Tested here:

* the four Lie-group cases and three constrained variants built here (a ball-jointed double pendulum whose hand runs
  on a ring, a satellite whose gripper is docked to a world point, a free body on a rail) at sampled states against
  the Pinocchio reference (``crosscheck.references.pinocchio.reference.split``), field by field, to ``RTOL`` of the field's scale, and
  through the gate's own comparison and conservation checks (``crosscheck.testing.assert_backends_agree``);
* a Hypothesis property over random trees with spherical and free joints (``crosscheck.testing.models(group=True)``),
  unconstrained or constrained;
* ``split_batch`` rows equal ``split``;
* the torque-free body obeys Euler's equations (closed form written here);
* the chart: the velocity in it is v and ``d/dt v = xi_ddot`` at ``xi = 0`` (symbolically through the backend's own
  chart, and numerically with the exact exponential ``scipy.linalg.expm``), and the truncation is exact: degrees 2,
  3 and 6 give the same numbers, degree 1 does not (the outputs are second derivatives at 0, no higher);
* the public helpers (``metric``, ``metric_derivatives``, ``christoffel``, ``energy_rate``) on a group model: M and
  ``C qd`` against the reference, ``dM`` against finite differences of the reference's M along ``q (+) h e_k``, the
  energy rate; no joint-coordinate charts (ModelNotSupported); a quaternion that is not unit is a StateError;
* the ZYX Euler-angle chart (``crosscheck.checks.charts.EulerZYX``, psi returns the whole q), evaluated natively by
  ``split_chart`` and the helpers' ``chart=``: every field against the reference mapped into the chart (``pdd`` by
  ``Dpsi^-1 (vdot - (d/dt Dpsi) pd)``, covectors by ``Dpsi^T``, ``dphi/dp = Jc Dpsi``, invariants equal), the gate's
  chart check (cases, constrained variants, solo12_standing, random trees), ``M_p = Dpsi^T M Dpsi`` and the chart's
  velocity products, Euler's equations in the chart (closed form), the refusal of other charts, and a chart whose
  psi is not the one its Jacobian describes being caught.
"""

from __future__ import annotations

import functools
import math

import casadi as ca
import numpy as np
import pytest
import scipy.linalg
from hypothesis import given, settings
from hypothesis import strategies as st

import cases
from cases import PointOnCircle, PointOnLine, PointsCoincide, build_model
from cases.configuration import integrate
from crosscheck.checks import charts
from crosscheck.references.pinocchio import reference
from crosscheck.core import sampling
from crosscheck import testing
from formalisms import geometric
from formalisms.interface import ModelNotSupported, StateError, Unsupported

CASES = ("free_body", "ball_pendulum", "ball_double_pendulum", "satellite_arm")
CONSTRAINED = ("ball_loop", "docked_satellite", "free_body_rail")
STATES = 6
#: Relative agreement with the reference, of each field's scale (measured: 1e-13 at worst here, 4e-11 on random trees).
RTOL = 1e-9


def _with_constraints(base, name: str, constraints):
    return build_model(name, base.bodies, gravity=base.gravity, input_map=base.input_map,
                       task_points=base.task_points, constraints=constraints)


@functools.lru_cache(maxsize=None)
def model_of(name: str):
    if name == "ball_loop":      # 2 ball joints, the hand on a horizontal ring: 1 row
        return _with_constraints(cases.load("ball_double_pendulum"), name,
                                 [PointOnCircle("ring", "lower", (0.0, 0.0, -0.5), (0.0, 0.0, -0.7), 0.4)])
    if name == "docked_satellite":  # free base + arm, the gripper held at a world point: 3 rows, with gravity
        return _with_constraints(cases.load("satellite_arm", g=1.0), name,
                                 [PointsCoincide("dock", "extension", (0.25, 0.0, 0.0), None, (0.9, 0.2, 0.4))])
    if name == "free_body_rail":    # a free body whose marker runs on the z axis: 2 rows, with gravity
        return _with_constraints(cases.load("free_body", g=9.81), name,
                                 [PointOnLine("rail", "body", (0.2, 0.1, -0.05), (0.0, 0.0, 0.0),
                                              np.array([[1.0, 0.0, 0.0], [0.0, 1.0, 0.0]]))])
    return cases.load(name)


def states_of(name: str, count: int = STATES, seed: int = 17):
    return [tuple(np.array(x) for x in (s.q, s.qd, s.u))
            for s in sampling.sample_states(model_of(name), count, seed, name)]


def field_errors(model, q, qd, u, skip=()) -> dict[str, float]:
    """Every field of the geometric split (but those in ``skip``) against the reference's, as the largest difference
    over the field's scale: its largest entry, at least a floor where the value can be an exact 0 that rounding
    misses (``phi`` against L^2; ``Jc qd``, the constraint power and the task drift against the terms they sum;
    accelerations, multipliers and forces against 1e-6 of the size the summed terms could produce)."""
    ours, ref = geometric.split(model, q, qd, u), reference.split(model, q, qd, u)
    errors = {}

    def rel(name, a, b, floor=0.0):
        if name in skip:
            return
        a, b = np.asarray(a, dtype=float), np.asarray(b, dtype=float)
        assert a.shape == b.shape, f"{name}: shape {a.shape} against the reference's {b.shape}"
        # NaN (a singular task space) and inf (its condition number) must sit where the reference has them
        assert np.array_equal(np.isfinite(a), np.isfinite(b)) and np.array_equal(a[~np.isfinite(a)],
                                                                                  b[~np.isfinite(b)], equal_nan=True), (
            f"{name}: {a.tolist()} against the reference's {b.tolist()}")
        a, b = np.where(np.isfinite(b), a, 0.0), np.where(np.isfinite(b), b, 0.0)
        scale = max(float(np.abs(b).max(initial=0.0)), floor, np.finfo(float).tiny)
        errors[name] = float(np.abs(a - b).max(initial=0.0)) / scale

    tau = model.input_map @ u
    for name in ("drift", "ctrl", "total"):
        rel(name, getattr(ours, name), getattr(ref, name), 1e-6 * ref.accel_scale)
    for name in ("task_inertia", "kinetic_energy", "cond_M", "accel_scale"):
        rel(name, getattr(ours, name), getattr(ref, name))
    # a task point the constraints hold still has task_drift 0 (J drift and Jdot qd cancel): the terms' size
    rel("task_drift", ours.task_drift, ref.task_drift, model.length_scale * (ref.accel_scale + np.abs(qd).sum() ** 2))
    rel("power_ctrl", ours.power_ctrl, ref.power_ctrl, float(np.abs(tau * qd).sum()))
    rel("power_ctrl_per_coord", ours.power_ctrl_per_coord, ref.power_ctrl_per_coord, float(np.abs(tau * qd).max()))
    rel("additivity", ours.additivity, np.zeros(model.nv), float(np.abs(ref.total).max() + 1e-6 * ref.accel_scale))
    for key in ref.conditions:
        rel(f"conditions[{key}]", ours.conditions[key], ref.conditions[key], 1.0)
    if "constraint_rank" not in skip:
        assert ours.constraint_rank == ref.constraint_rank
    assert isinstance(ours.joint_wrenches, Unsupported)   # the geometric backend has no body-level loads
    if not model.constraints:
        assert ours.lam is None and ours.power_constr is None and ours.constraint_jacobian is None
        return errors
    Jc = np.asarray(ref.constraint_jacobian)
    forces = 1e-6 * np.abs(Jc).max() * ref.lam_scale
    reaction = float((np.abs(Jc).T @ np.abs(ref.lam) + forces) @ np.abs(qd))   # the terms Jc^T lam . qd sums
    for name, floor in (("lam", 1e-6 * ref.lam_scale), ("lam_drift", 1e-6 * ref.lam_scale), ("lam_scale", 0.0),
                        ("constraint_jacobian", 0.0), ("constraint_bias", 1e-6 * np.abs(Jc).max() * ref.accel_scale),
                        ("constraint_force", forces), ("constraint_force_drift", forces)):
        rel(name, getattr(ours, name), getattr(ref, name), floor)
    rel("constraint_value", ours.constraint_value, ref.constraint_value, model.length_scale ** 2)
    rel("constraint_velocity", ours.constraint_velocity, ref.constraint_velocity,
        float(np.abs(Jc).max() * np.abs(qd).sum()))
    rel("power_constr", ours.power_constr, ref.power_constr, reaction)
    rel("power_constr_per_coord", ours.power_constr_per_coord, ref.power_constr_per_coord, reaction)
    for name in ("admissibility_drift", "admissibility_total"):
        rel(name, getattr(ours, name), 0.0 * getattr(ref, name), float(np.abs(ref.constraint_bias).max(initial=0.0)
                                                                        + np.abs(Jc).max() * np.abs(ref.total).max()))
    return errors


# ---------------------------------------------------------------------------------------- against the reference


@pytest.mark.parametrize("name", CASES + CONSTRAINED)
def test_every_field_agrees_with_the_reference(name):
    model = model_of(name)
    for q, qd, u in states_of(name):
        errors = field_errors(model, q, qd, u)
        bad = {k: v for k, v in errors.items() if not v <= RTOL}
        assert not bad, f"{name} at q = {q.tolist()}: relative errors above {RTOL:g}: {bad}"


@pytest.mark.parametrize("name", CASES + CONSTRAINED)
def test_the_gate_finds_agreement_and_conservation(name):
    """The gate's comparison (its tolerance policy) and its conservation checks, which read this backend's
    ``metric``, ``christoffel``, ``metric_derivatives`` and ``energy_rate`` in the group chart."""
    model = model_of(name)
    for state in sampling.sample_states(model, 3, 5, name):
        outcome = testing.assert_backends_agree(model, state, backends=["geometric", "pinocchio"])
        assert any(key.startswith("conservation: energy rate") for key in outcome.checks)


@settings(max_examples=25)
@given(data=st.data())
def test_random_group_trees_agree_with_the_reference(data):
    model = data.draw(testing.models(max_bodies=4, group=True, constraints=None))
    state = data.draw(testing.states(model))
    testing.assert_backends_agree(model, state, backends=["geometric", "pinocchio"])
    q = np.array(state.q)
    M, M_ref = geometric.metric(model, q), reference.split(model, q, state.qd, state.u).extras["M"]
    assert np.abs(M - M_ref).max() <= 1e-12 * np.abs(M_ref).max()


@settings(max_examples=10)
@given(data=st.data())
def test_random_constrained_group_trees_agree_with_the_reference(data):
    model = data.draw(testing.models(max_bodies=4, group=True, constraints=True))
    testing.assert_backends_agree(model, data.draw(testing.states(model)), backends=["geometric", "pinocchio"])


# ------------------------------------------------------------------------------------------------------ batches


@pytest.mark.parametrize("name", CASES + CONSTRAINED)
def test_split_batch_rows_equal_split(name):
    model = model_of(name)
    Q, QD, U = (np.array(column) for column in zip(*states_of(name, 8, seed=3)))
    batch = geometric.split_batch(model, Q, QD, U)
    assert batch.drift.shape == (len(Q), model.nv)
    for i in range(len(Q)):
        s = geometric.split(model, Q[i], QD[i], U[i])
        tol = 100 * np.finfo(float).eps * s.cond_M
        for field in ("drift", "ctrl", "total"):
            assert np.abs(getattr(batch, field)[i] - getattr(s, field)).max() <= tol * s.accel_scale, (name, i, field)
        if model.k:
            for field in ("lam", "lam_drift"):
                assert np.abs(getattr(batch, field)[i] - getattr(s, field)).max() <= tol * s.lam_scale, (name, i, field)
        else:
            assert batch.lam is None


# ------------------------------------------------------------------------------------------ Euler's equations


def test_the_free_body_obeys_eulers_equations():
    """Torque-free, zero gravity: ``I wd + w x I w = 0`` about the COM, and the COM does not accelerate. With the
    body twist ``(v, w)`` at the body origin and the COM at ``c`` (body frame), the COM's body-frame velocity is
    ``u = v + w x c`` and its world acceleration ``R (u' + w x u) = 0``, so ``vd = -wd x c - w x u``."""
    model = cases.load("free_body")
    body = model.bodies[0]
    inertia, c = np.asarray(body.inertia), np.asarray(body.com)
    assert not np.any(model.gravity)
    for q, qd, u in states_of("free_body"):
        v, w = qd[:3], qd[3:]
        wd = -np.linalg.solve(inertia, np.cross(w, inertia @ w))
        vd = -np.cross(wd, c) - np.cross(w, v + np.cross(w, c))
        drift = geometric.split(model, q, qd, u).drift
        want = np.concatenate([vd, wd])
        assert np.abs(drift - want).max() <= 1e-12 * np.abs(want).max(), (drift, want)


# ----------------------------------------------------------------------------------------------------- the chart


def _hat(w):
    return np.array([[0.0, -w[2], w[1]], [w[2], 0.0, -w[0]], [-w[1], w[0], 0.0]])


def _vee(W):
    return np.array([W[2, 1], W[0, 2], W[1, 0]])


def _twist_matrix(xi):
    X = np.zeros((4, 4), dtype=complex if np.iscomplexobj(xi) else float)
    X[:3, :3], X[:3, 3] = _hat(xi[3:]), xi[:3]
    return X


@pytest.mark.parametrize("name", ["free_body", "ball_pendulum"])
def test_the_chart_velocity_is_v_and_its_acceleration_is_vdot(name):
    """Along ``xi(t) = t v + t^2/2 a`` through the chart's origin the body velocity ``v(t)`` (free: the twist
    ``(R^T pdot, vee(R^T Rdot))``; spherical: ``vee(R^T Rdot)``) has ``v(0) = v`` and ``vdot(0) = a``: the chart's
    first and second derivatives at 0 are the state's velocity and acceleration (``d/dt dexp_{-xi} xid = xidd -
    1/2 ad_xid xid = xidd`` at 0). Symbolically through the backend's own (truncated) chart: exact to rounding."""
    model = cases.load(name)
    free = model.bodies[0].joint == "free"
    t = ca.SX.sym("t")
    rng = np.random.default_rng(0)
    for q, v, _ in states_of(name, 3):
        a = rng.normal(size=model.nv)
        xi = t * ca.DM(v) + t ** 2 / 2 * ca.DM(a)
        R, o, _ = geometric._group_frames(model, ca.SX(ca.DM(q)), xi, geometric.EXP_ORDER)
        W = ca.mtimes(R[0].T, ca.jacobian(ca.vec(R[0]), t).reshape((3, 3)))
        twist = ca.vertcat(ca.mtimes(R[0].T, ca.jacobian(o[0], t)), W[2, 1], W[0, 2], W[1, 0])
        if not free:
            twist = twist[3:]
        f = ca.Function("twist", [t], [twist, ca.jacobian(twist, t)])
        velocity, acceleration = (np.array(x).ravel() for x in f(0.0))
        assert np.abs(velocity - v).max() <= 1e-14 * np.abs(v).max()
        assert np.abs(acceleration - a).max() <= 1e-13 * (np.abs(a).max() + np.abs(v).max() ** 2)


def test_the_exact_exponential_gives_the_same_velocity_and_acceleration():
    """The same property with the exact exponential of SE(3) (``scipy.linalg.expm``), independently of the backend:
    ``Xdot`` by a complex step, ``vdot`` by a central difference; and the contrast, a chart centred elsewhere
    (``xi(0) != 0``), where ``xid`` is not the body velocity."""
    rng = np.random.default_rng(1)
    X0 = scipy.linalg.expm(_twist_matrix(rng.normal(size=6)))
    v, a = rng.normal(size=6), rng.normal(size=6)

    def body_velocity(t, start):
        X = X0 @ scipy.linalg.expm(_twist_matrix(start + t * v + t ** 2 / 2 * a))
        h = 1e-30
        Xdot = (X0 @ scipy.linalg.expm(_twist_matrix(start + (t + 1j * h) * v + (t + 1j * h) ** 2 / 2 * a))).imag / h
        V = np.linalg.solve(X, Xdot)
        return np.concatenate([V[:3, 3], _vee(V[:3, :3])])

    zero, d = np.zeros(6), 1e-4
    assert np.abs(body_velocity(0.0, zero) - v).max() <= 1e-12
    vdot = (body_velocity(d, zero) - body_velocity(-d, zero)) / (2 * d)
    assert np.abs(vdot - a).max() <= 1e-6
    away = rng.normal(size=6)
    assert np.abs(body_velocity(0.0, away) - v).max() > 1e-2


@pytest.mark.parametrize("name", CASES + ("docked_satellite",))
def test_the_truncated_exponential_is_exact(name):
    """Every output of the compiled Function (M, dM, dV/dp, T, J, Jdot pd, phi, Jc, Jcdot pd) is a derivative of
    order at most 2 in the chart coordinates at ``xi = 0``, where the exponential's Taylor polynomial of degree
    K >= 2 has exactly its derivatives: degrees 2, 3 and 6 give the same numbers (to rounding), and degree 1 does
    not (the second-order term reaches dM, Jdot pd and Jcdot pd), so the degree used is the least that is exact."""
    model = model_of(name)
    compiled = {K: geometric._compile(model, None, exp_order=K) for K in (1, 2, 3, 6)}
    assert geometric.EXP_ORDER == 2
    for q, qd, _ in states_of(name, 3):
        x = geometric._arguments(model, q)              # the point, then the world data the Functions read
        out = {K: c.evaluate(x, qd) for K, c in compiled.items()}
        scale = np.abs(out[6]).max()
        assert np.abs(out[2] - out[6]).max() <= 1e-14 * scale
        assert np.abs(out[3] - out[6]).max() <= 1e-14 * scale
        assert np.array_equal(out[2], geometric._compiled(model, None).evaluate(x, qd))
        assert np.abs(out[1] - out[6]).max() > 1e-6 * scale


# ------------------------------------------------------------------------------------------- the public helpers


def _ad(model, k: int) -> np.ndarray:
    """``ad`` of the k-th unit velocity (nv x nv): the Lie bracket ``[e_k, .]`` in the block of the group joint that
    owns velocity k (zero for a revolute or prismatic joint: a vector space)."""
    ad = np.zeros((model.nv, model.nv))
    for i, body in enumerate(model.bodies):
        start, size = model.v_index[i], {"spherical": 3, "free": 6}.get(body.joint, 1)
        if start <= k < start + size and size > 1:
            e = np.zeros(size)
            e[k - start] = 1.0
            block = _hat(e) if size == 3 else np.block([[_hat(e[3:]), _hat(e[:3])], [np.zeros((3, 3)), _hat(e[3:])]])
            ad[start:start + size, start:start + size] = block
    return ad


@pytest.mark.parametrize("name", CASES)
def test_the_geometric_objects_in_the_group_chart(name):
    """``metric`` is the reference's M (in v-space). ``metric_derivatives[k]`` is the derivative of the chart's metric
    ``M_xi = A(xi)^T M(q (+) xi) A(xi)``, where ``v = A(xi) xid`` with ``A(xi) = dexp_{-xi} = I - 1/2 ad_xi + ...``
    (block by block: ``ad`` of so(3) ``[w]x``, of se(3) ``[[w]x, [v]x], [0, [w]x]]``), so at 0 ``d_k M_xi =
    d/dh M(q (+) h e_k) - 1/2 (ad_k^T M + M ad_k)``: the first term by central differences of the reference's M
    along the chart's coordinate curves. (It is not the derivative of the v-space matrix alone: a free body's M is
    constant in v-space, its chart's metric is not.) ``M Gamma(v, v)`` (from ``christoffel``) is the reference's
    ``C qd``; ``energy_rate`` is 0 at the drift and ``tau . v`` at the total, with momentum M v."""
    model, h = model_of(name), 1e-5
    for q, qd, u in states_of(name, 3):
        ref = reference.split(model, q, qd, u)
        M = geometric.metric(model, q)
        assert np.abs(M - ref.extras["M"]).max() <= 1e-13 * np.abs(M).max()
        dM = geometric.metric_derivatives(model, q)
        for k in range(model.nv):
            step = np.zeros(model.nv)
            step[k] = h
            forward, backward = (reference.split(model, integrate(model, q, s), qd, u).extras["M"]
                                 for s in (step, -step))
            ad = _ad(model, k)
            want = (forward - backward) / (2 * h) - 0.5 * (ad.T @ M + M @ ad)
            assert np.abs(dM[k] - want).max() <= 1e-7 * np.abs(M).max(), (name, k)
        Gamma = geometric.christoffel(model, q)
        Cqd = M @ ((Gamma @ qd) @ qd)
        assert np.abs(Cqd - ref.extras["Cqd"]).max() <= 1e-12 * (np.abs(M).max() * np.abs(qd).sum() ** 2)
        first = geometric.christoffel_first_kind(dM)
        assert np.abs((first @ qd) @ qd - Cqd).max() <= 1e-12 * (np.abs(M).max() * np.abs(qd).sum() ** 2)
        s = geometric.split(model, q, qd, u)
        at_drift, at_total = (geometric.energy_rate(model, q, qd, x) for x in (s.drift, s.total))
        assert abs(at_drift.rate) <= 1e-12 * at_drift.magnitude
        assert abs(at_total.rate - s.power_ctrl) <= 1e-12 * (at_total.magnitude + abs(s.power_ctrl))
        assert np.abs(at_drift.momentum - M @ qd).max() <= 1e-13 * np.abs(M).max() * np.abs(qd).max()
        T, V = geometric.energy(model, q, qd)
        assert abs(T - ref.kinetic_energy) <= 1e-13 * T


def test_group_models_have_no_joint_coordinate_charts():
    model, chart = model_of("ball_pendulum"), object()
    q, qd, u = states_of("ball_pendulum", 1)[0]
    with pytest.raises(ModelNotSupported, match="Lie group"):
        geometric.split_chart(model, chart, qd, qd, qd)
    with pytest.raises(ModelNotSupported, match="Lie group"):
        geometric.metric(model, q, chart=chart)


def test_group_configurations_are_checked():
    model = model_of("satellite_arm")
    q, qd, u = states_of("satellite_arm", 1)[0]
    with pytest.raises(StateError, match="not 1"):
        geometric.metric(model, np.concatenate([q[:3], 2 * q[3:7], q[7:]]))
    with pytest.raises(StateError, match="needs 10 coordinates"):
        geometric.energy_rate(model, qd, qd, qd)
    with pytest.raises(StateError, match="non-finite"):
        geometric.energy(model, q, np.full(model.nv, np.nan))


def test_a_chart_truncated_too_early_is_caught(monkeypatch):
    """The comparison can fail: with the exponential truncated to degree 1 (its second-order term lost, so dM,
    Jdot pd and the connection are wrong) the drift and the task drift disagree with the reference."""
    monkeypatch.setattr(geometric, "_COMPILED", {})
    monkeypatch.setattr(geometric, "_compile", functools.partial(geometric._compile, exp_order=1))
    q, qd, u = states_of("ball_double_pendulum", 2)[1]
    errors = field_errors(model_of("ball_double_pendulum"), q, qd, u)
    assert errors["drift"] > 1e-3 and errors["task_drift"] > 1e3 * RTOL


# ---------------------------------------------------------------------------------- the Euler-angle chart (zyx)
#
# split_chart and the public helpers in ``crosscheck.checks.charts.EulerZYX``: q = psi(p) (the whole q, quaternions from the
# half angles) substituted into the backend's kinematics, everything derived in p by casadi. The references below
# are the Pinocchio split in v-space mapped into the chart with the harness's Dpsi (test side only; the backend never
# reads it): pdd = Dpsi^-1 (vdot - (d/dt Dpsi) pd), M_p = Dpsi^T M Dpsi, covectors by Dpsi^T.

#: cond(Dpsi) of the states the chart comparisons use (away from gimbal lock, pitch = +-pi/2).
GIMBAL_COND = 1e3


def chart_states(name: str, count: int = STATES, seed: int = 17, chart_name: str = "zyx"):
    """``(q, qd, u, chart, p, pd, D)`` at the sampled states where the chart (zyx by default) is well conditioned."""
    model = model_of(name)
    chart = charts.get(chart_name, model)
    out = []
    for q, qd, u in states_of(name, count, seed):
        p = chart.p_of(q)
        D = chart.jacobian(p)
        if np.linalg.cond(D) < GIMBAL_COND:
            out.append((q, qd, u, chart, p, np.linalg.solve(D, qd), D))
    assert len(out) >= count // 2, f"{name}: too few states away from gimbal lock"
    return out


def chart_errors(model, q, qd, u, chart, p, pd, D) -> dict[str, float]:
    """Every field of ``split_chart`` in the zyx chart against the reference mapped into the chart, as the largest
    difference over the field's scale (floors as in :func:`field_errors`)."""
    ref = reference.split(model, q, qd, u)
    tau_p = D.T @ (model.input_map @ u)
    ours = geometric.split_chart(model, chart, p, pd, tau_p)
    assert ours.extras["chart"] == chart.name
    gain = np.abs(np.linalg.inv(D)).max() * model.nv          # what Dpsi^-1 may amplify the reference's rounding by
    errors = {}

    def rel(name, a, b, floor=0.0):
        a, b = np.asarray(a, dtype=float), np.asarray(b, dtype=float)
        assert a.shape == b.shape, f"{name}: shape {a.shape} against {b.shape}"
        scale = max(float(np.abs(b).max(initial=0.0)), floor, np.finfo(float).tiny)
        errors[name] = float(np.abs(a - b).max(initial=0.0)) / scale

    rate = chart.jacobian_rate(p, pd)
    for name in ("drift", "total"):
        rel(name, ours.quantity(name), charts.acceleration_to_chart(chart, p, pd, getattr(ref, name)),
            1e-6 * gain * ref.accel_scale)
    rel("ctrl", ours.ctrl, charts.acceleration_to_chart(chart, p, pd, ref.ctrl, with_rate=False),
        1e-6 * gain * ref.accel_scale)
    M_p = D.T @ ref.extras["M"] @ D
    rel("cond_M", ours.cond_M, np.linalg.cond(M_p))
    rel("kinetic_energy", ours.kinetic_energy, ref.kinetic_energy)
    rel("task_inertia", ours.task_inertia, ref.task_inertia)
    rel("task_drift", ours.task_drift, ref.task_drift, model.length_scale * (ref.accel_scale + np.abs(qd).sum() ** 2))
    rel("power_ctrl", ours.power_ctrl, ref.power_ctrl, float(np.abs(model.input_map @ u * qd).sum()))
    rel("power_ctrl_per_coord", ours.power_ctrl_per_coord, tau_p * pd, float(np.abs(tau_p * pd).max()))
    if not model.constraints:
        assert ours.lam is None and ours.constraint_jacobian is None
        return errors
    Jc = np.asarray(ref.constraint_jacobian)
    forces = 1e-6 * np.abs(Jc).max() * ref.lam_scale
    for name in ("lam", "lam_drift"):
        rel(name, getattr(ours, name), getattr(ref, name), 1e-6 * ref.lam_scale)
    rel("constraint_value", ours.constraint_value, ref.constraint_value, model.length_scale ** 2)
    rel("constraint_jacobian", ours.constraint_jacobian, Jc @ D)                      # dphi/dp = Jc_v Dpsi
    # d^2 phi/dt^2 = Jc_v vdot + Jcdot_v v with vdot = Dpsi pdd + (d/dt Dpsi) pd: the chart's bias adds Jc_v of the rate
    rel("constraint_bias", ours.constraint_bias, ref.constraint_bias + Jc @ rate,
        1e-6 * np.abs(Jc).max() * ref.accel_scale)
    rel("constraint_velocity", ours.constraint_velocity, ref.constraint_velocity,
        float(np.abs(Jc).max() * np.abs(qd).sum()))
    for name in ("constraint_force", "constraint_force_drift"):                     # covectors: Dpsi^T
        rel(name, getattr(ours, name), D.T @ getattr(ref, name), gain * forces)
    reaction = float((np.abs(Jc).T @ np.abs(ref.lam) + forces) @ np.abs(qd))
    rel("power_constr", ours.power_constr, ref.power_constr, reaction)
    assert ours.constraint_rank == ref.constraint_rank
    return errors


@pytest.mark.parametrize("chart_name", ("zyx", "exp"))
@pytest.mark.parametrize("name", CASES + CONSTRAINED)
def test_split_chart_in_euler_angles_agrees_with_the_mapped_reference(name, chart_name):
    model = model_of(name)
    for q, qd, u, chart, p, pd, D in chart_states(name, chart_name=chart_name):
        errors = chart_errors(model, q, qd, u, chart, p, pd, D)
        bad = {k: v for k, v in errors.items() if not v <= RTOL}
        assert not bad, f"{name} at p = {p.tolist()}: relative errors above {RTOL:g}: {bad}"


@pytest.mark.parametrize("chart_name", ("zyx", "exp"))
@pytest.mark.parametrize("name", CASES + CONSTRAINED + ("solo12_standing",))
def test_the_gate_chart_check_in_euler_angles(name, chart_name):
    """The gate's chart check (``crosscheck.checks.invariance.chart_checks`` through ``assert_backends_agree(chart=...)``):
    this backend's split_chart against every joint-chart answer mapped into the chart, with the gate's tolerances; in
    Euler angles (zyx) and in exponential coordinates about the centre drawn for the case (exp)."""
    model = cases.load(name) if name == "solo12_standing" else model_of(name)
    chart = charts.get(chart_name, model, 0, name)
    checked = 0
    for state in sampling.sample_states(model, 2 if name == "solo12_standing" else 3, 5, name):
        outcome = testing.assert_backends_agree(model, state, backends=["geometric", "pinocchio"], chart=chart,
                                                conservation=False)
        keys = [key for key in outcome.checks if key.startswith(f"chart {chart_name}:")]
        checked += bool(keys)
        assert all(f"geometric@{chart_name}" in outcome.checks[key].voters for key in keys)
    assert checked


@settings(max_examples=10)
@given(data=st.data())
def test_random_group_trees_in_euler_angles(data):
    model = data.draw(testing.models(max_bodies=3, group=True, constraints=None).filter(lambda m: m.group_joints))
    testing.assert_backends_agree(model, data.draw(testing.states(model)), backends=["geometric", "pinocchio"],
                                  chart=charts.get("zyx", model), conservation=False)


@pytest.mark.parametrize("name", CASES + ("ball_loop",))
def test_the_geometric_objects_in_euler_angles(name):
    """The public helpers with ``chart=``: ``metric`` is ``Dpsi^T M Dpsi``; the first-kind contraction of
    ``christoffel``/``metric_derivatives`` is the chart's velocity-product covector ``Dpsi^T (C v + M (d/dt Dpsi) pd)``
    (eq. 7 pulled back: ``M vdot + C v`` with ``vdot = Dpsi pdd + (d/dt Dpsi) pd``); ``energy`` is the reference's
    T; ``energy_rate`` vanishes along the drift; ``drift_field`` is ``(pd, drift)``."""
    model = model_of(name)
    for q, qd, u, chart, p, pd, D in chart_states(name, 4):
        ref = reference.split(model, q, qd, u)
        M = ref.extras["M"]
        M_p = geometric.metric(model, p, chart=chart)
        assert np.abs(M_p - D.T @ M @ D).max() <= 1e-12 * np.abs(M_p).max()
        want = D.T @ (ref.extras["Cqd"] + M @ chart.jacobian_rate(p, pd))
        size = np.abs(D).max() ** 2 * np.abs(M).max() * np.abs(pd).sum() ** 2
        first = geometric.christoffel_first_kind(geometric.metric_derivatives(model, p, chart=chart))
        assert np.abs((first @ pd) @ pd - want).max() <= 1e-12 * size
        Gamma = geometric.christoffel(model, p, chart=chart)
        assert np.abs(M_p @ ((Gamma @ pd) @ pd) - want).max() <= 1e-11 * size
        T, V = geometric.energy(model, p, pd, chart=chart)
        assert abs(T - ref.kinetic_energy) <= 1e-13 * T
        assert abs(V - geometric.energy(model, q, qd)[1]) <= 1e-13 * (abs(V) + 1.0)
        field = geometric.drift_field(model, p, pd, chart=chart)
        at_drift = geometric.energy_rate(model, p, pd, field[model.nv:], chart=chart)
        assert abs(at_drift.rate) <= 1e-12 * at_drift.magnitude
        assert np.abs(at_drift.momentum - M_p @ pd).max() <= 1e-12 * np.abs(M_p).max() * np.abs(pd).max()


def test_the_euler_chart_of_the_free_body_obeys_eulers_equations():
    """Closed form in the chart: the free body's drift in (position, yaw, pitch, roll) mapped to the body twist
    (``w = E adot``, ``v = R^T pdot``, E and R written here) satisfies Euler's equations about the COM."""
    model = model_of("free_body")
    body = model.bodies[0]
    inertia, c = np.asarray(body.inertia), np.asarray(body.com)
    for q, qd, u, chart, p, pd, D in chart_states("free_body"):
        (sy, sp, sr), (cy, cp, cr) = np.sin(p[3:]), np.cos(p[3:])
        E = np.array([[-sp, 0.0, 1.0], [cp * sr, cr, 0.0], [cp * cr, -sr, 0.0]])
        Rz = np.array([[cy, -sy, 0.0], [sy, cy, 0.0], [0.0, 0.0, 1.0]])
        Ry = np.array([[cp, 0.0, sp], [0.0, 1.0, 0.0], [-sp, 0.0, cp]])
        Rx = np.array([[1.0, 0.0, 0.0], [0.0, cr, -sr], [0.0, sr, cr]])
        R = Rz @ Ry @ Rx
        drift = geometric.split_chart(model, chart, p, pd, np.zeros(6)).drift
        w = E @ pd[3:]
        dE = np.array([[-cp * pd[4], 0.0, 0.0], [-sp * sr * pd[4] + cp * cr * pd[5], -sr * pd[5], 0.0],
                       [-sp * cr * pd[4] - cp * sr * pd[5], -cr * pd[5], 0.0]])
        wd = E @ drift[3:] + dE @ pd[3:]
        assert np.abs(inertia @ wd + np.cross(w, inertia @ w)).max() <= 1e-12 * np.abs(inertia).max() * (w @ w)
        # the COM does not accelerate: c_world = x + R c, so its second derivative R (wd x c + w x (w x c)) + xdd = 0
        com = drift[:3] + R @ (np.cross(wd, c) + np.cross(w, np.cross(w, c)))
        assert np.abs(com).max() <= 1e-12 * (np.abs(drift).max() + (w @ w) * np.abs(c).max())


class _NotUnit(charts.EulerZYX):
    """psi with quaternions scaled by 1.01: not a map into the group."""

    def psi(self, p, sin=math.sin, cos=math.cos):
        q = super().psi(p, sin, cos)
        for joint, _, j in self._blocks():
            if joint in ("spherical", "free"):
                a = j + (3 if joint == "free" else 0)
                q[a:a + 4] = [1.01 * x for x in q[a:a + 4]]
        return q


class _XYZ(charts.EulerZYX):
    """A chart that is not the one its Jacobian describes: psi in the order (roll, pitch, yaw), Dpsi still ZYX."""

    def psi(self, p, sin=math.sin, cos=math.cos):
        p = list(p)
        for joint, k, _ in self._blocks():
            if joint in ("spherical", "free"):
                a = k + (3 if joint == "free" else 0)
                p[a], p[a + 2] = p[a + 2], p[a]
        return super().psi(p, sin, cos)


def test_charts_that_do_not_return_the_whole_q_are_refused():
    model = model_of("satellite_arm")
    q, qd, u = states_of("satellite_arm", 1)[0]
    zyx = charts.get("zyx", model)
    p = zyx.p_of(q)
    for chart, reason in ((charts.get("identity", model), "no psi of the 9 velocity"),
                          (charts.EulerZYX("short", zyx.joints[:-1]), "returns 9 entries"),
                          (_NotUnit("scaled", zyx.joints), "not unit"),
                          (object(), "not a chart")):
        with pytest.raises(ModelNotSupported, match=reason):
            geometric.split_chart(model, chart, p, qd, qd)
        with pytest.raises(ModelNotSupported, match="Lie group"):
            geometric.metric(model, p, chart=chart)
    with pytest.raises(ModelNotSupported, match="use split"):
        geometric.split_chart(model, None, q, qd, qd)
    with pytest.raises(StateError, match="one per coordinate"):
        geometric.split_chart(model, zyx, q, qd, qd)          # q has nq entries, the chart's p nv


def test_the_chart_check_catches_a_chart_its_jacobian_does_not_describe():
    """The comparison can fail: evaluated natively in a chart whose psi is not the one the harness maps with, the
    accelerations disagree with the mapped reference far beyond the tolerance."""
    name = "ball_double_pendulum"
    model = model_of(name)
    q, qd, u, zyx, p, pd, D = chart_states(name)[1]
    errors = chart_errors(model, q, qd, u, _XYZ("zyx", zyx.joints), p, pd, D)
    assert errors["drift"] > 1e-3 and errors["kinetic_energy"] > 1e-3


def test_compiling_the_euler_chart_leaves_the_joint_chart_unchanged():
    """The group chart's Functions and answers are bit-identical before and after the zyx chart is compiled."""
    model = model_of("docked_satellite")
    q, qd, u = states_of("docked_satellite", 2)[1]
    before = geometric.split(model, q, qd, u)
    geometric.split_chart(model, charts.get("zyx", model), charts.get("zyx", model).p_of(q), qd, qd)
    after = geometric.split(model, q, qd, u)
    for field in ("drift", "ctrl", "total", "lam", "constraint_jacobian"):
        assert np.array_equal(getattr(before, field), getattr(after, field))
