"""Tests of the Euler–Lagrange backend (article 4.7.1) against references written independently here.

* The double pendulum's closed forms, article eqs. (6), (7), (8), and the 2x2 inverse of 4.7.2, typed in from
  the article in ``closed_forms.py`` (not read from any project code): the 4.7.3 sanity check, ``terms()`` at
  drawn parameters and states, the chapter's gravity-compensation and inverse/forward round-trip experiments,
  and the symbolic output of ``derive``.
* Spong's acrobot mass matrix (closed form, angles from hanging down).
* For the 3-D ``spatial_arm``: a mass matrix and gravity vector assembled here from geometric Jacobians of this
  file's own forward kinematics (scipy rotation vectors, not the backend's Rodrigues / symbolic chain rule):
  ``M = sum m Jv^T Jv + Jw^T (R I R^T) Jw`` and ``g = -sum m Jv^T gravity``; the Jacobians and the potential
  are cross-checked against each other by finite differences, so the reference is checked too.
* The disk cache of the generated source: one file per model digest, reused without re-deriving (the compiled C:
  ``test_euler_lagrange_compiled.py``).

All tests here derive into a scratch cache (fixture ``fresh_derivation_cache``), so they test the current code.
"""

from __future__ import annotations

import math

import numpy as np
import pytest
import symengine
import sympy
from hypothesis import given
from hypothesis import strategies as st
from scipy.spatial.transform import Rotation

import cases
from closed_forms import article_Cqd, article_g, article_M, inv2, pendulum_terms
from formalisms import euler_lagrange as el

EPS = np.finfo(float).eps
PI = math.pi


# ----------------------------------------------------------------------------------------------------------
# Helpers on top of the article's closed forms (eqs. (6), (7), (8) and the 4.7.2 inverse: closed_forms.py)
# ----------------------------------------------------------------------------------------------------------

def summand_size(qd, tau, qdd=(0.0, 0.0), m1=1.0, m2=1.0, l1=1.0, l2=1.0, g=9.81):
    """A bound on the magnitudes of the terms summed into M qdd + C qd + g and tau: what rounding scales with.

    Not |C qd| itself: C qd is a difference of Christoffel terms of M's size times qd^2 that cancel (exactly
    at theta2 = 0 or pi), so rounding leaves ~eps * M * qd^2 where the closed form gives ~0.
    """
    m_size = (m1 + m2) * (l1 + l2) ** 2
    qd1, qdd1 = np.abs(qd).sum(), np.abs(qdd).sum()
    return m_size * (qd1**2 + qdd1) + (m1 + m2) * g * (l1 + l2) + np.abs(tau).sum()


def article_split(q, qd, tau, **p):
    """drift, ctrl, total of article 4.7.2 and the scale ||M^-1|| * summand_size (cf. interface accel_scale)."""
    M, Cqd, g = pendulum_terms(q, qd, **p)
    Minv = inv2(M)
    scale = np.linalg.norm(Minv, 2) * summand_size(qd, tau, **p)
    return -Minv @ (Cqd + g), Minv @ tau, Minv @ (np.asarray(tau) - Cqd - g), scale


def assert_close(got, expected, atol, what=""):
    """max |got - expected| <= atol; below 1e-300 a difference is underflow (subnormals), never physics."""
    atol = max(atol, 1e-300)
    err = np.abs(np.asarray(got) - np.asarray(expected)).max()
    assert err <= atol, f"{what}: max error {err:.3e} > tolerance {atol:.3e}\n got      {got}\n expected {expected}"


# ----------------------------------------------------------------------------------------------------------
# Article 4.7.3: the sanity check
# ----------------------------------------------------------------------------------------------------------

Q473, QD473, TAU473 = np.array([PI / 4, PI / 6]), np.array([2.0, -1.0]), np.array([5.0, -2.0])


def test_article_4_7_3_sanity_check():
    model = cases.load("double_pendulum")  # m1 = m2 = 1 kg, l1 = l2 = 1 m, g = 9.81 m/s^2
    s = el.split(model, Q473, QD473, TAU473)

    # drift + ctrl == total: three independent solves, so equal up to rounding (a few ulp of the magnitudes)
    ulp_scale = np.abs(s.drift) + np.abs(s.ctrl) + np.abs(s.total)
    resid = np.abs(s.drift + s.ctrl - s.total)
    assert np.all(resid <= 8 * EPS * ulp_scale), f"drift + ctrl - total = {s.drift + s.ctrl - s.total}"

    drift, ctrl, total, scale = article_split(Q473, QD473, TAU473)
    tol = 1e-14 * scale
    assert_close(s.drift, drift, tol, "drift vs eq. (9)/(10) closed form")
    assert_close(s.ctrl, ctrl, tol, "ctrl vs M^-1 tau closed form")
    assert_close(s.total, total, tol, "total vs full-equation closed form")
    # the closed form itself obeys the article's claim (a check that the reference above is typed in right)
    assert_close(drift + ctrl, total, 8 * EPS * np.abs(total).max() + 8 * EPS * np.abs(drift).max(), "closed form")
    # a hand-evaluated anchor: at 4.7.3, M = [[3 + sqrt 3, 1 + sqrt 3 / 2], [1 + sqrt 3 / 2, 1]]
    r3 = math.sqrt(3.0)
    assert_close(article_M(PI / 6), [[3 + r3, 1 + r3 / 2], [1 + r3 / 2, 1]], 1e-15, "eq. (6) typed in")
    assert s.power_ctrl == pytest.approx(TAU473 @ QD473, rel=1e-15)


def test_terms_at_the_article_state():
    model = cases.load("double_pendulum")
    M, Cqd, g = el.terms(model, Q473, QD473)
    assert_close(M, article_M(Q473[1]), 1e-14, "M eq. (6)")
    assert_close(Cqd, article_Cqd(Q473[1], *QD473), 1e-14, "C qd eq. (7)")
    assert_close(g, article_g(*Q473), 1e-13, "g eq. (8)")


pytestmark = pytest.mark.usefixtures("fresh_derivation_cache")  # conftest.py: derive afresh, into a scratch cache


angle = st.floats(-PI, PI)
rate = st.floats(-10.0, 10.0)
params = st.fixed_dictionaries({
    "m1": st.floats(0.1, 10.0), "m2": st.floats(0.1, 10.0),
    "l1": st.floats(0.1, 3.0), "l2": st.floats(0.1, 3.0), "g": st.floats(0.5, 30.0)})


@given(p=params, q=st.tuples(angle, angle), qd=st.tuples(rate, rate))
def test_terms_match_closed_forms_at_drawn_parameters_and_states(p, q, qd):
    model = cases.load("double_pendulum", **p)
    q, qd = np.array(q), np.array(qd)
    M, Cqd, g = el.terms(model, q, qd)
    M_ref, Cqd_ref, g_ref = pendulum_terms(q, qd, **p)
    # rounding: each entry is a short sum of products of magnitude at most the bounds below; C qd is built
    # from derivatives of M entries (each up to m_scale per radian) times qd^2, and they cancel, e.g. at t2 = 0
    m_scale = (p["m1"] + p["m2"]) * (p["l1"] + p["l2"]) ** 2
    c_scale = m_scale * (abs(qd[0]) + abs(qd[1])) ** 2  # cf. summand_size
    g_scale = (p["m1"] + p["m2"]) * p["g"] * (p["l1"] + p["l2"])
    assert_close(M, M_ref, 64 * EPS * m_scale, "M eq. (6)")
    assert_close(Cqd, Cqd_ref, 64 * EPS * c_scale, "C qd eq. (7)")
    assert_close(g, g_ref, 64 * EPS * g_scale, "g eq. (8)")


@given(p=params, q=st.tuples(angle, angle), qd=st.tuples(rate, rate),
       tau=st.tuples(st.floats(-50.0, 50.0), st.floats(-50.0, 50.0)))
def test_split_matches_closed_forms_at_drawn_parameters_and_states(p, q, qd, tau):
    model = cases.load("double_pendulum", **p)
    s = el.split(model, q, qd, tau)
    drift, ctrl, total, scale = article_split(np.array(q), np.array(qd), np.array(tau), **p)
    # forward error of a 2x2 solve: cond(M) eps times the scale; cond(M) <= ||M|| ||M^-1||
    cond = np.linalg.cond(article_M(q[1], **{k: p[k] for k in ("m1", "m2", "l1", "l2")}))
    tol = 64 * EPS * cond * scale
    assert_close(s.drift, drift, tol, "drift")
    assert_close(s.ctrl, ctrl, tol, "ctrl")
    assert_close(s.total, total, tol, "total")


# ----------------------------------------------------------------------------------------------------------
# Chapter experiment 2: the mass matrix is symmetric positive definite across the workspace
# ----------------------------------------------------------------------------------------------------------

def test_double_pendulum_mass_matrix_spd_over_elbow_sweep():
    model = cases.load("double_pendulum", m1=0.7, m2=1.9, l1=1.3, l2=0.6)
    m1, m2, l1, l2 = 0.7, 1.9, 1.3, 0.6
    rng = np.random.default_rng(5)
    for t2 in np.linspace(-PI, PI, 361):
        q = np.array([rng.uniform(-PI, PI), t2])
        M, _, _ = el.terms(model, q, np.zeros(2))
        assert np.array_equal(M, M.T), f"M not symmetric at {q}"
        eig = np.linalg.eigvalsh(M)
        assert eig[0] > 0, f"M not positive definite at {q}: eigenvalues {eig}"
        # det M = M11 M22 - M12^2 = m2 l1^2 l2^2 (m1 + m2 sin^2 t2): bounded away from zero by m1 m2 l1^2 l2^2
        det_ref = m2 * l1**2 * l2**2 * (m1 + m2 * math.sin(t2) ** 2)
        assert np.linalg.det(M) == pytest.approx(det_ref, rel=1e-12)
        assert_close(M, article_M(t2, m1, m2, l1, l2), 1e-14, "M eq. (6)")


def acrobot_M(q2, m1=1.0, m2=1.0, l1=1.0, lc1=0.5, lc2=1.0, I1=0.083, I2=0.33):  # noqa: N803
    """Spong's acrobot mass matrix (I1, I2 about the COMs)."""
    c2 = math.cos(q2)
    d11 = m1 * lc1**2 + m2 * (l1**2 + lc2**2 + 2 * l1 * lc2 * c2) + I1 + I2
    d12 = m2 * (lc2**2 + l1 * lc2 * c2) + I2
    d22 = m2 * lc2**2 + I2
    return np.array([[d11, d12], [d12, d22]])


def test_acrobot_mass_matrix_spd_and_spong_closed_form():
    model = cases.load("acrobot")
    rng = np.random.default_rng(7)
    for t2 in np.linspace(-PI, PI, 181):
        q = np.array([rng.uniform(-PI, PI), t2])
        M, _, _ = el.terms(model, q, np.zeros(2))
        assert np.array_equal(M, M.T)
        assert np.linalg.eigvalsh(M)[0] > 0, f"M not positive definite at {q}"
        assert_close(M, acrobot_M(t2), 1e-13, "acrobot M (Spong)")
    # only the elbow is actuated: ctrl = M^-1 B u with B = [0, 1]^T (not M^-1 u)
    q, qd, u = np.array([0.4, -1.2]), np.array([1.5, -0.5]), np.array([3.0])
    s = el.split(model, q, qd, u)
    assert_close(s.ctrl, inv2(acrobot_M(q[1])) @ np.array([0.0, 3.0]), 1e-13, "acrobot ctrl = M^-1 B u")
    assert s.power_ctrl == pytest.approx(3.0 * qd[1], rel=1e-15)


# --- an independent 3-D reference: forward kinematics and geometric Jacobians -------------------------------

def forward_kinematics(model, q):
    """World rotation R and origin o of every body frame, world joint axes a, and COM positions c."""
    n = model.n
    R, o, a = [None] * n, [None] * n, [None] * n
    for i in model.topological_order:
        b, p = model.bodies[i], model.parent_index[i]
        R_p, o_p = (np.eye(3), np.zeros(3)) if p < 0 else (R[p], o[p])
        R_joint, o_joint = R_p @ b.rotation, o_p + R_p @ b.translation
        a[i] = R_joint @ b.axis
        if b.joint == "revolute":
            R[i], o[i] = R_joint @ Rotation.from_rotvec(q[i] * np.asarray(b.axis)).as_matrix(), o_joint
        else:
            R[i], o[i] = R_joint, o_joint + q[i] * a[i]
    c = [o[i] + R[i] @ b.com for i, b in enumerate(model.bodies)]
    return R, o, a, c


def com_jacobians(model, q):
    """Per body: R, COM position c, linear Jv = dc/dq and angular Jw (3 x n) from the joint axes."""
    R, o, a, c = forward_kinematics(model, q)
    out = []
    for i in range(model.n):
        Jv, Jw = np.zeros((3, model.n)), np.zeros((3, model.n))
        k = i
        while k >= 0:
            if model.bodies[k].joint == "revolute":
                Jv[:, k], Jw[:, k] = np.cross(a[k], c[i] - o[k]), a[k]
            else:
                Jv[:, k] = a[k]
            k = model.parent_index[k]
        out.append((R[i], c[i], Jv, Jw))
    return out


def reference_M_g(model, q):
    """M = sum m Jv^T Jv + Jw^T R I R^T Jw and g = dV/dq = -sum m Jv^T gravity."""
    M, g = np.zeros((model.n, model.n)), np.zeros(model.n)
    for b, (R, _, Jv, Jw) in zip(model.bodies, com_jacobians(model, q)):
        M += b.mass * Jv.T @ Jv + Jw.T @ (R @ b.inertia @ R.T) @ Jw
        g -= b.mass * Jv.T @ model.gravity
    return M, g


def potential(model, q):
    return -sum(b.mass * model.gravity @ c for b, c in zip(model.bodies, forward_kinematics(model, q)[3]))


def random_configuration(model, rng):
    return np.array([rng.uniform(-PI, PI) if b.joint == "revolute" else rng.uniform(-0.5, 0.5)
                     for b in model.bodies])


def test_reference_jacobians_are_consistent_with_finite_differences():
    """The 3-D reference itself: Jv and g against central differences of the COM positions and the potential."""
    model = cases.load("spatial_arm")
    rng = np.random.default_rng(11)
    h = 1e-6
    for _ in range(3):
        q = random_configuration(model, rng)
        E = np.eye(model.n)
        fd_c = [[(forward_kinematics(model, q + h * e)[3][i] - forward_kinematics(model, q - h * e)[3][i]) / (2 * h)
                 for e in E] for i in range(model.n)]
        for i, (_, _, Jv, _) in enumerate(com_jacobians(model, q)):
            np.testing.assert_allclose(Jv, np.array(fd_c[i]).T, atol=1e-8)
        fd_g = np.array([(potential(model, q + h * e) - potential(model, q - h * e)) / (2 * h) for e in E])
        np.testing.assert_allclose(reference_M_g(model, q)[1], fd_g, atol=1e-7)


@pytest.mark.parametrize("name", ["acrobot", "spatial_arm", "n_link_pendulum"])
def test_mass_matrix_spd_at_random_configurations(name):
    model = cases.load(name)
    rng = np.random.default_rng(3)
    for _ in range(30):
        q = random_configuration(model, rng)
        M, _, _ = el.terms(model, q, np.zeros(model.n))
        assert np.array_equal(M, M.T), f"{name}: M not symmetric at {q}"
        eig = np.linalg.eigvalsh(M)
        assert eig[0] > 1e-9 * eig[-1], f"{name}: M not positive definite at {q}: eigenvalues {eig}"
        if name == "spatial_arm":
            M_ref, _ = reference_M_g(model, q)
            assert_close(M, M_ref, 1e-13 * np.abs(M_ref).max(), "spatial_arm M vs geometric Jacobians")


# ----------------------------------------------------------------------------------------------------------
# Chapter experiment 3: gravity compensation, tau = g(q) at rest gives zero acceleration
# ----------------------------------------------------------------------------------------------------------

def test_double_pendulum_gravity_compensation():
    model = cases.load("double_pendulum")
    rng = np.random.default_rng(13)
    for t1 in np.linspace(-PI, PI, 73):
        q = np.array([t1, rng.uniform(-PI, PI)])
        s = el.split(model, q, np.zeros(2), article_g(*q))
        assert np.abs(s.total).max() < 1e-12, f"not held at q = {q}: total = {s.total}"
        # and without the compensation it falls: drift is -M^-1 g, not zero (the check above can fail)
        np.testing.assert_allclose(s.drift, -inv2(article_M(q[1])) @ article_g(*q), atol=1e-12)


def test_spatial_arm_gravity_compensation():
    """u = g(q) from this file's geometric Jacobians; the limit is the rounding of g scaled by ||M^-1||
    (about 1e3 for the wrist), so the chapter's 1e-12 is scaled by ||M^-1|| ||g|| here."""
    model = cases.load("spatial_arm")
    rng = np.random.default_rng(17)
    for _ in range(20):
        q = random_configuration(model, rng)
        M_ref, g_ref = reference_M_g(model, q)
        s = el.split(model, q, np.zeros(model.n), g_ref)
        tol = max(1e-12, 16 * EPS * np.linalg.norm(np.linalg.inv(M_ref), 2) * np.linalg.norm(g_ref))
        assert np.abs(s.total).max() < tol, f"not held at q = {q}: total = {s.total} (tol {tol:.1e})"
        assert np.abs(s.drift).max() > 1.0  # gravity really acts


# ----------------------------------------------------------------------------------------------------------
# Chapter: inverse dynamics (closed form) -> forward dynamics (Euler–Lagrange) round trip
# ----------------------------------------------------------------------------------------------------------

@given(p=params, q=st.tuples(angle, angle), qd=st.tuples(rate, rate),
       qdd=st.tuples(st.floats(-20.0, 20.0), st.floats(-20.0, 20.0)))
def test_inverse_forward_round_trip(p, q, qd, qdd):
    q, qd, qdd = np.array(q), np.array(qd), np.array(qdd)
    M, Cqd, g = pendulum_terms(q, qd, **p)
    tau = M @ qdd + Cqd + g
    s = el.split(cases.load("double_pendulum", **p), q, qd, tau)
    # relative to the accelerations the summed terms could produce (interface accel_scale, computed here)
    scale = np.linalg.norm(inv2(M), 2) * summand_size(qd, tau, qdd, **p)
    tol = 16 * EPS * np.linalg.cond(M) * scale
    assert_close(s.total, qdd, tol, "recovered qdd")


def test_inverse_forward_round_trip_at_unit_parameters_is_at_machine_precision():
    """The chapter's claim (error below ~1e-15 relative) at well-conditioned states of the default pendulum."""
    model = cases.load("double_pendulum")
    rng = np.random.default_rng(19)
    worst = 0.0
    for _ in range(200):
        q, qd, qdd = rng.uniform(-PI, PI, 2), rng.uniform(-3, 3, 2), rng.uniform(-3, 3, 2)
        tau = article_M(q[1]) @ qdd + article_Cqd(q[1], *qd) + article_g(*q)
        s = el.split(model, q, qd, tau)
        scale = np.linalg.norm(inv2(article_M(q[1])), 2) * summand_size(qd, tau, qdd)
        worst = max(worst, np.abs(s.total - qdd).max() / scale)
    assert worst < 1e-15, f"worst relative round-trip error {worst:.2e}"


# ----------------------------------------------------------------------------------------------------------
# The symbolic derivation
# ----------------------------------------------------------------------------------------------------------

@pytest.fixture(scope="module")
def derived():
    """The double pendulum's derivation with its world data (gravity, the root's placement: parameters of the
    derivation) substituted by the model's own numbers, exactly (the placement is the identity)."""
    model = cases.load("double_pendulum")
    d = el.derivation(model)
    world = {s: symengine.Integer(int(v)) if v == int(v) else symengine.Float(v)
             for s, v in zip(d.world, el._world_values(model))}
    for s, e in d.staged.definitions.items():
        d.staged.definitions[s] = e.subs(world)
    M, Cqd, g = (m.subs(world) for m in (d.M, d.Cqd, d.g))
    return M, Cqd, g, d.coordinates, d.rates, d.staged


def _numeric(exprs, staged, values):
    """Evaluate expressions that use staged intermediates: substitute the definitions in evaluation order."""
    env = dict(values)
    for s, e in staged.needed(exprs):
        env[s] = float(e.subs(env))
    return [float(e.subs(env)) for e in exprs]


def test_derived_mass_matrix_is_eq_6_at_random_points(derived):
    M, Cqd, g, q, qd, staged = derived
    rng = np.random.default_rng(23)
    for _ in range(10):
        qv, qdv = rng.uniform(-PI, PI, 2), rng.uniform(-5, 5, 2)
        values = {q[0]: qv[0], q[1]: qv[1], qd[0]: qdv[0], qd[1]: qdv[1]}
        Mv = np.array(_numeric([M[i, j] for i in range(2) for j in range(2)], staged, values)).reshape(2, 2)
        assert_close(Mv, article_M(qv[1]), 1e-13, "derived M eq. (6)")
        assert_close(_numeric(list(Cqd), staged, values), article_Cqd(qv[1], *qdv), 1e-12, "derived C qd eq. (7)")
        assert_close(_numeric(list(g), staged, values), article_g(*qv), 1e-12, "derived g eq. (8)")


def test_derived_mass_matrix_is_eq_6_symbolically(derived):
    M, _, _, q, _, staged = derived
    t2 = sympy.Symbol("q1")
    m1 = m2 = l1 = l2 = 1
    eq6 = sympy.Matrix([[(m1 + m2) * l1**2 + m2 * l2**2 + 2 * m2 * l1 * l2 * sympy.cos(t2),
                         m2 * l2**2 + m2 * l1 * l2 * sympy.cos(t2)],
                        [m2 * l2**2 + m2 * l1 * l2 * sympy.cos(t2), m2 * l2**2]])
    exprs = [M[i, j] for i in range(2) for j in range(2)]
    defs = staged.needed(exprs)
    for k, e in enumerate(exprs):
        for s, d in reversed(defs):          # expand the staged intermediates back into functions of q
            e = e.subs({s: d})
        diff = sympy.trigsimp(sympy.expand(sympy.sympify(e) - eq6[k // 2, k % 2]))
        assert diff == 0, f"M[{k // 2},{k % 2}] - eq. (6) = {diff}"


def test_derived_cqd_is_quadratic_in_qd(derived):
    _, Cqd, _, q, qd, staged = derived
    s = symengine.Symbol("s")
    for i, e in enumerate(Cqd):
        for name, d in reversed(staged.needed([e])):  # the staged intermediates (velocities among them) expanded
            e = e.subs({name: d})
        assert e.free_symbols <= set(q) | set(qd), f"C qd[{i}] has symbols other than q, qd: {e.free_symbols}"
        scaled = e.subs({v: s * v for v in qd})
        assert symengine.expand(scaled - s**2 * e) == 0, f"C qd[{i}] is not homogeneous of degree 2 in qd"
        assert symengine.expand(e.subs({v: 0 for v in qd})) == 0, f"C qd[{i}] is not zero at qd = 0"
    # numerically too, through the compiled code: scaling qd by s scales C qd by s^2, zero at qd = 0
    model = cases.load("double_pendulum")
    rng = np.random.default_rng(29)
    for _ in range(20):
        qv, qdv, sv = rng.uniform(-PI, PI, 2), rng.uniform(-5, 5, 2), rng.uniform(-4, 4)
        _, c1, _ = el.terms(model, qv, qdv)
        _, cs, _ = el.terms(model, qv, sv * qdv)
        _, c0, _ = el.terms(model, qv, np.zeros(2))
        assert_close(cs, sv**2 * c1, 1e-12 * max(1.0, sv**2 * np.abs(c1).max()), "C(q, s qd) = s^2 C(q, qd)")
        assert np.array_equal(c0, np.zeros(2))
        assert np.abs(c1).max() > 0 or abs(math.sin(qv[1])) < 1e-12  # not trivially zero


# ----------------------------------------------------------------------------------------------------------
# The disk cache of the generated source
# ----------------------------------------------------------------------------------------------------------

def test_disk_cache_writes_once_and_reloads_without_deriving(isolated_cache, monkeypatch):
    model = cases.load("double_pendulum", m1=1.25)
    q, qd = np.array([0.3, -1.1]), np.array([0.7, 2.0])
    first = el.terms(model, q, qd)
    files = sorted(isolated_cache.rglob("*.py"))
    assert len(files) == 1, f"expected one cached source, found {files}"
    assert not list(isolated_cache.rglob("*.tmp")), "a temporary file was left behind"
    text = files[0].read_text()
    assert model.digest() in text and "def evaluate(q, qd):" in text

    # a fresh "process": the in-memory cache is gone, deriving is forbidden, the file must be read
    el._compiled.cache_clear()

    def no_derivation(m, *args):
        raise AssertionError(f"'{m.name}' derived although its code is cached on disk")

    with monkeypatch.context() as mp:
        mp.setattr(el, "derivation", no_derivation)
        second = el.terms(model, q, qd)
        # a renamed copy of the same physics shares the entry (the digest ignores the name)
        renamed = cases.build_model("renamed", model.bodies, gravity=model.gravity,
                                    task_points=model.task_points)
        np.testing.assert_array_equal(el.terms(renamed, q, qd)[0], first[0])
    for a, b in zip(first, second):
        np.testing.assert_array_equal(a, b)
    assert sorted(isolated_cache.rglob("*.py")) == files

    # different physics, different file (and different numbers)
    heavier = cases.load("double_pendulum", m1=2.5)
    third = el.terms(heavier, q, qd)
    files2 = sorted(isolated_cache.rglob("*.py"))
    assert len(files2) == 2 and files[0] in files2, f"expected a second cache file, found {files2}"
    assert not np.array_equal(third[0], first[0])
    assert_close(third[0], article_M(q[1], m1=2.5), 1e-14, "M of the heavier model")


def test_disk_cache_entry_is_what_the_generator_produces(isolated_cache):
    model = cases.load("acrobot", I2=0.4)
    el.terms(model, np.zeros(2), np.zeros(2))
    (path,) = isolated_cache.rglob("*.py")
    assert path.read_text() == el.generate_source(model)


def test_compiled_code_is_cached_beside_the_source(isolated_cache, monkeypatch):
    """The interpreted evaluation: a fresh process loads the compiled code object (marshal) instead of compiling the
    source again (most of a second for a 9-joint arm); a damaged entry is compiled again and rewritten."""
    monkeypatch.setenv(el.COMPILE_VARIABLE, "0")
    model = cases.load("double_pendulum", m1=1.5)
    q, qd = np.array([0.3, -1.1]), np.array([0.7, 2.0])
    first = el.terms(model, q, qd)
    (code_file,) = isolated_cache.rglob("*.code")
    el._compiled.cache_clear()

    def no_source(*args):
        raise AssertionError("the source was read although its compiled code is cached")

    with monkeypatch.context() as mp:
        mp.setattr(el, "cached_source", no_source)
        second = el.terms(model, q, qd)
    for damage in (b"damaged", b"N"):  # not marshal data; marshal data that is not code
        code_file.write_bytes(damage)
        el._compiled.cache_clear()
        third = el.terms(model, q, qd)
        for a, b, c in zip(first, second, third):
            np.testing.assert_array_equal(a, b)
            np.testing.assert_array_equal(a, c)
        assert code_file.read_bytes() != damage


def test_batch_over_several_blocks_equals_split(monkeypatch):
    """Blocks of 4 states: a batch of 10 crosses two block boundaries and ends on a partial block; every row is
    what ``split`` gives (1e-9 of the state's accel_scale), and the numpy evaluation of the derived source gives
    the same M, C qd, g as the scalar one."""
    monkeypatch.setattr(el, "BATCH_BLOCK", 4)
    model = cases.load("spatial_arm")
    rng = np.random.default_rng(5)
    Q, QD, U = (rng.uniform(-2.0, 2.0, (10, size)) for size in (model.n, model.n, model.m))
    batch = el.split_batch(model, Q, QD, U)
    terms, _ = el.evaluate_batch(model, Q, QD)
    for i in range(len(Q)):
        s = el.split(model, Q[i], QD[i], U[i])
        for name in ("drift", "ctrl", "total"):
            err = np.abs(getattr(batch, name)[i] - getattr(s, name)).max()
            assert err <= 1e-9 * s.accel_scale, f"state {i}: {name} differs by {err:.3g}"
        single = el.evaluate_terms(model, Q[i], QD[i])
        for name in ("M", "Cqd", "g", "T"):
            np.testing.assert_allclose(getattr(terms, name)[i], getattr(single, name), rtol=1e-12, atol=1e-12)


