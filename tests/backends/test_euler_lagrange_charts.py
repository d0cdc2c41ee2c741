"""The Euler–Lagrange backend re-derived in a chart ``q = psi(p)`` (article 6.4.6, 9.1; docs/design.md, charts).

``split_chart`` derives M_p, C_p pd and g_p from the Lagrangian with q = psi(p) substituted; nothing is mapped from
the joint chart. The references here are independent of that derivation:

* the identity chart is the joint derivation itself (same compiled code, bit for bit), and a disguised identity
  (``q = 1.0 p + 0.0``, which goes through the chart path) agrees with it to rounding;
* the double pendulum in absolute angles against the closed forms written in absolute angles (``absolute_terms``,
  from the Lagrangian in phi) and against the relative-angle closed form mapped by ``phi_dd = (t1_dd, t1_dd + t2_dd)``;
* random affine and the nonlinear chart against the joint-chart split mapped by the harness's analytic chart maps
  (``crosscheck.checks.charts``: ``pdd = Dpsi^-1 (qdd - (d/dt Dpsi) pd)``, ``tau_p = Dpsi^T B u``), plus the covariance of
  the metric and of the gravity covector (``M_p = Dpsi^T M Dpsi``, ``g_p = Dpsi^T g``) and the invariance of the
  kinetic energy and of the control power;
* the caches: one entry per (model, chart), never one chart's code for another.

Panda (9 joints) is not derived in a chart here: it takes seconds per chart, measured separately.
"""

from __future__ import annotations

import math

import numpy as np
import pytest
from hypothesis import given
from hypothesis import strategies as st

import cases
from closed_forms import absolute_terms, inv2, pendulum_terms
from crosscheck.checks import charts
from formalisms import euler_lagrange as el
from formalisms.interface import StateError

EPS = np.finfo(float).eps
PI = math.pi


pytestmark = pytest.mark.usefixtures("fresh_derivation_cache")  # conftest.py: derive afresh, into a scratch cache


def assert_close(got, expected, atol, what=""):
    atol = max(atol, 1e-300)
    err = np.abs(np.asarray(got, dtype=float) - np.asarray(expected, dtype=float)).max()
    assert err <= atol, f"{what}: max error {err:.3e} > tolerance {atol:.3e}\n got      {got}\n expected {expected}"


def state_strategy(model):
    """(q, qd, u) for ``model``: angles in [-pi, pi], prismatic offsets in [-0.5, 0.5] m."""
    coord = [st.floats(-PI, PI) if b.joint == "revolute" else st.floats(-0.5, 0.5) for b in model.bodies]
    vec = lambda k, lo, hi: st.lists(st.floats(lo, hi), min_size=k, max_size=k).map(np.array)  # noqa: E731
    return st.tuples(st.tuples(*coord).map(np.array), vec(model.n, -5.0, 5.0), vec(model.m, -20.0, 20.0))


MODELS = {name: cases.load(name) for name in ("double_pendulum", "acrobot", "spatial_arm")}


# ----------------------------------------------------------------------------------------------------------
# The identity chart is the joint derivation
# ----------------------------------------------------------------------------------------------------------

@pytest.mark.parametrize("name", ["double_pendulum", "spatial_arm"])
@given(data=st.data())
def test_identity_chart_is_the_joint_split(name, data):
    model = MODELS[name]
    q, qd, u = data.draw(state_strategy(model))
    chart = charts.identity(model.n)
    s, ref = el.split_chart(model, chart, q, qd, model.input_map @ u), el.split(model, q, qd, u)
    for key in ("drift", "ctrl", "total", "power_ctrl_per_coord"):
        np.testing.assert_array_equal(getattr(s, key), getattr(ref, key), err_msg=key)
    for key in ("power_ctrl", "kinetic_energy", "cond_M", "accel_scale"):
        assert getattr(s, key) == getattr(ref, key), key


def test_identity_chart_shares_the_joint_derivation():
    model = MODELS["spatial_arm"]
    assert el.chart_key(model, charts.identity(model.n)) == el.chart_key(model, None) == "identity"
    assert el.cache_key(model, charts.identity(model.n)) == el.cache_key(model)
    assert el.FORMALISM.split_chart is el.split_chart


class ScaledIdentity:
    """``q = 1.0 p + 0.0``: the identity, but not literally, so it is derived through the chart path."""

    name, key = "disguised_identity", "disguised-identity-v1"

    def psi(self, p, sin, cos):
        return [1.0 * x + 0.0 for x in p]


@given(data=st.data())
def test_a_disguised_identity_goes_through_the_chart_path_and_agrees(data):
    model = MODELS["spatial_arm"]
    chart = ScaledIdentity()
    assert el.chart_key(model, chart) == chart.key  # not recognized as the joint chart ...
    assert "def evaluate(p, pd):" in el.cached_source(model, chart)  # ... so derived in p
    q, qd, u = data.draw(state_strategy(model))
    s, ref = el.split_chart(model, chart, q, qd, model.input_map @ u), el.split(model, q, qd, u)
    for key in ("drift", "ctrl", "total"):
        tol = 64 * EPS * ref.cond_M * ref.accel_scale
        assert_close(getattr(s, key), getattr(ref, key), tol, key)
    assert s.kinetic_energy == pytest.approx(ref.kinetic_energy, rel=1e-13, abs=1e-300)
    assert s.power_ctrl == pytest.approx(ref.power_ctrl, rel=1e-13, abs=1e-13)


# ----------------------------------------------------------------------------------------------------------
# The double pendulum in absolute angles (article 6.4.6): closed forms written in phi
# ----------------------------------------------------------------------------------------------------------

angle = st.floats(-PI, PI)
rate = st.floats(-10.0, 10.0)
force = st.floats(-50.0, 50.0)
params = st.fixed_dictionaries({
    "m1": st.floats(0.1, 10.0), "m2": st.floats(0.1, 10.0),
    "l1": st.floats(0.1, 3.0), "l2": st.floats(0.1, 3.0), "g": st.floats(0.5, 30.0)})


def pendulum_scale(p, qd, tau):
    """A bound on the summed terms' magnitudes (cf. summand_size in test_euler_lagrange): M qd^2, gravity, tau."""
    m_size = (p["m1"] + p["m2"]) * (p["l1"] + p["l2"]) ** 2
    return m_size * np.abs(qd).sum() ** 2 + (p["m1"] + p["m2"]) * p["g"] * (p["l1"] + p["l2"]) + np.abs(tau).sum()


@given(p=params, t=st.tuples(angle, angle), td=st.tuples(rate, rate), tau=st.tuples(force, force))
def test_double_pendulum_in_absolute_angles_matches_the_closed_forms(p, t, td, tau):
    model = cases.load("double_pendulum", **p)
    chart = charts.get("absolute", model)
    t, td, tau = np.array(t), np.array(td), np.array(tau)
    phi, phid = np.array([t[0], t[0] + t[1]]), np.array([td[0], td[0] + td[1]])
    tau_p = np.array([tau[0] - tau[1], tau[1]])  # Dpsi^T tau with theta = (phi1, phi2 - phi1)
    s = el.split_chart(model, chart, phi, phid, tau_p)

    # the chart's own terms are the absolute-angle ones (different entries from eqs. 6-8, article 6.4.6)
    M_a, C_a, g_a = absolute_terms(phi, phid, **p)
    M, Cqd, g, T = el.evaluate_terms(model, phi, phid, chart)[:4]
    scale = pendulum_scale(p, phid, tau_p)
    m_size = (p["m1"] + p["m2"]) * (p["l1"] + p["l2"]) ** 2
    assert_close(M, M_a, 64 * EPS * m_size, "M in absolute angles")
    assert_close(Cqd, C_a, 64 * EPS * scale, "C pd in absolute angles")
    assert_close(g, g_a, 64 * EPS * scale, "g in absolute angles")
    assert T == pytest.approx(0.5 * phid @ M_a @ phid, rel=1e-13, abs=1e-300)

    # accelerations: the absolute-angle closed form, and the relative-angle one mapped (phi_dd = (t1dd, t1dd+t2dd))
    Minv_a = inv2(M_a)
    tol = 64 * EPS * np.linalg.cond(M_a) * np.linalg.norm(Minv_a, 2) * scale
    assert_close(s.drift, -Minv_a @ (C_a + g_a), tol, "drift vs absolute closed form")
    assert_close(s.ctrl, Minv_a @ tau_p, tol, "ctrl vs absolute closed form")
    assert_close(s.total, Minv_a @ (tau_p - C_a - g_a), tol, "total vs absolute closed form")
    M_r, C_r, g_r = pendulum_terms(t, td, **p)
    Minv_r = inv2(M_r)
    tol_r = tol + 64 * EPS * np.linalg.cond(M_r) * np.linalg.norm(Minv_r, 2) * pendulum_scale(p, td, tau)
    relative = lambda tdd: np.array([tdd[0], tdd[0] + tdd[1]])  # noqa: E731
    assert_close(s.drift, relative(-Minv_r @ (C_r + g_r)), 2 * tol_r, "drift vs relative closed form mapped")
    assert_close(s.ctrl, relative(Minv_r @ tau), 2 * tol_r, "ctrl vs relative closed form mapped")
    assert_close(s.total, relative(Minv_r @ (tau - C_r - g_r)), 2 * tol_r, "total vs relative closed form mapped")
    assert s.power_ctrl == pytest.approx(tau @ td, rel=1e-12, abs=1e-12 * np.abs(tau).sum() * np.abs(td).sum())


# ----------------------------------------------------------------------------------------------------------
# Affine and nonlinear charts: the joint-chart split mapped by the harness's analytic chart maps
# ----------------------------------------------------------------------------------------------------------

def make_chart(kind, model, seed=0):
    return charts.random_affine(model, seed, "x") if kind == "affine" else charts.get("nonlinear", model)


def check_against_mapped_joint_split(model, chart, q, qd, u):
    p = chart.p_of(q)
    pd = charts.velocity_to_chart(chart, p, qd)
    tau_p = charts.force_to_chart(chart, p, model.input_map @ u)
    s, ref = el.split_chart(model, chart, p, pd, tau_p), el.split(model, q, qd, u)
    D = chart.jacobian(p)
    Dinv = np.linalg.norm(np.linalg.inv(D), 2)
    expected = {"drift": charts.acceleration_to_chart(chart, p, pd, ref.drift),
                "ctrl": charts.acceleration_to_chart(chart, p, pd, ref.ctrl, with_rate=False),
                "total": charts.acceleration_to_chart(chart, p, pd, ref.total)}
    # rounding of the chart's own solve, of the joint solve carried through Dpsi^-1, and of the mapping itself
    tol = 64 * EPS * (s.cond_M * s.accel_scale + Dinv * ref.cond_M * ref.accel_scale
                      + np.linalg.cond(D) * max(np.abs(v).max() for v in expected.values())
                      + Dinv * np.abs(chart.jacobian_rate(p, pd)).max())
    for key, value in expected.items():
        assert_close(getattr(s, key), value, tol, f"{chart.name} {key}")
    # energy and power are chart-invariant (article 9.1)
    assert s.kinetic_energy == pytest.approx(ref.kinetic_energy, rel=1e-12, abs=1e-300)
    p_size = np.abs(tau_p * pd).sum() + np.abs(ref.power_ctrl_per_coord).sum()
    assert s.power_ctrl == pytest.approx(ref.power_ctrl, rel=0, abs=64 * EPS * np.linalg.cond(D) * p_size + 1e-300)
    # the metric and the gravity covector are tensors: M_p = Dpsi^T M Dpsi, g_p = Dpsi^T g
    M_q, _, g_q, _ = el.evaluate_terms(model, q, qd)[:4]
    M_p, _, g_p, _ = el.evaluate_terms(model, p, pd, chart)[:4]
    size = np.abs(D).sum(axis=0).max() ** 2
    assert_close(M_p, D.T @ M_q @ D, 64 * EPS * size * np.abs(M_q).max(), f"{chart.name} M_p = Dpsi^T M Dpsi")
    assert_close(g_p, D.T @ g_q, 64 * EPS * size * (np.abs(g_q).max() + s.accel_scale * np.abs(M_q).max()),
                 f"{chart.name} g_p = Dpsi^T g")
    return s


@pytest.mark.parametrize("kind", ["affine", "nonlinear"])
@pytest.mark.parametrize("name", ["double_pendulum", "acrobot", "spatial_arm"])
@given(data=st.data())
def test_chart_split_is_the_joint_split_mapped(name, kind, data):
    model = MODELS[name]
    q, qd, u = data.draw(state_strategy(model))
    check_against_mapped_joint_split(model, make_chart(kind, model), q, qd, u)


@given(seed=st.integers(0, 2**31 - 1), data=st.data())
def test_drawn_affine_charts_of_the_acrobot(seed, data):
    """A new affine chart per example (a new derivation each: cheap for two joints)."""
    model = MODELS["acrobot"]
    q, qd, u = data.draw(state_strategy(model))
    check_against_mapped_joint_split(model, charts.random_affine(model, seed, "acrobot"), q, qd, u)


def test_the_chart_terms_are_not_the_joint_terms():
    """The check above would pass vacuously if split_chart ignored the chart: it does not."""
    model = MODELS["double_pendulum"]
    q, qd = np.array([0.4, -1.1]), np.array([1.3, 0.7])
    for kind in ("affine", "nonlinear"):
        chart = make_chart(kind, model)
        p, pd = chart.p_of(q), charts.velocity_to_chart(chart, chart.p_of(q), qd)
        M_p = el.evaluate_terms(model, p, pd, chart).M
        assert np.abs(M_p - el.evaluate_terms(model, q, qd).M).max() > 1e-3
        assert np.abs(M_p - el.evaluate_terms(model, p, pd).M).max() > 1e-3


# ----------------------------------------------------------------------------------------------------------
# Kinetic energy from the generated code
# ----------------------------------------------------------------------------------------------------------

@given(p=params, t=st.tuples(angle, angle), td=st.tuples(rate, rate))
def test_kinetic_energy_is_the_article_T(p, t, td):
    model = cases.load("double_pendulum", **p)
    td = np.array(td)
    s = el.split(model, t, td, np.zeros(2))
    M, _, _ = pendulum_terms(np.array(t), td, **p)
    assert s.kinetic_energy == pytest.approx(0.5 * td @ M @ td, rel=1e-13, abs=1e-300)


@pytest.mark.parametrize("name", ["acrobot", "spatial_arm", "n_link_pendulum"])
def test_kinetic_energy_is_half_qd_M_qd(name):
    model = cases.load(name)
    rng = np.random.default_rng(31)
    for _ in range(20):
        q, qd = rng.uniform(-PI, PI, model.n), rng.uniform(-5, 5, model.n)
        M, _, _, T = el.evaluate_terms(model, q, qd)[:4]
        assert T == pytest.approx(0.5 * qd @ M @ qd, rel=1e-13)
        assert el.split(model, q, qd, np.zeros(model.m)).kinetic_energy == T


# ----------------------------------------------------------------------------------------------------------
# Caches: keyed by (model digest, chart key, module hash)
# ----------------------------------------------------------------------------------------------------------

def test_each_chart_has_its_own_cache_entry_and_is_never_served_for_another(isolated_cache, monkeypatch):
    model = cases.load("double_pendulum", m2=1.7)
    chart_list = [charts.random_affine(model, 0, "x"), charts.random_affine(model, 1, "x"),
                  charts.nonlinear(model), charts.nonlinear(model, a=0.3), charts.get("absolute", model)]
    keys = [el.cache_key(model, c) for c in chart_list] + [el.cache_key(model)]
    assert len(set(keys)) == len(keys), f"cache keys collide: {keys}"

    q, qd = np.array([0.3, -1.1]), np.array([0.7, 2.0])
    points = [(c.p_of(q), charts.velocity_to_chart(c, c.p_of(q), qd)) for c in chart_list]
    first = [el.evaluate_terms(model, p, pd, c) for c, (p, pd) in zip(chart_list, points)]
    assert len(list(isolated_cache.rglob("*.py"))) == len(chart_list)
    M_q = el.evaluate_terms(model, q, qd).M  # and the joint chart's own entry
    files = sorted(isolated_cache.rglob("*.py"))
    assert len(files) == len(chart_list) + 1, files
    for c in chart_list:
        text = (isolated_cache / "euler_lagrange" / f"{el.cache_key(model, c)}.py").read_text()
        assert f"chart '{c.name}' ({c.key})" in text and model.digest() in text
    # every chart's answer is its own: the metric is the joint one pulled back by that chart's Jacobian
    for c, (p, _), terms in zip(chart_list, points, first):
        D = c.jacobian(p)
        assert_close(terms.M, D.T @ M_q @ D, 1e-12, f"M_p of chart {c.name} ({c.key})")
    # a fresh "process": deriving is forbidden, every chart's code is read from its own file
    el._compiled.cache_clear()

    def no_derivation(*args):
        raise AssertionError("derived although the code is cached on disk")

    monkeypatch.setattr(el, "derivation", no_derivation)
    for c, (p, pd), before in zip(chart_list, points, first):
        after = el.evaluate_terms(model, p, pd, c)
        for a, b in zip(before, after):
            np.testing.assert_array_equal(a, b)
    assert sorted(isolated_cache.rglob("*.py")) == files


def test_in_process_cache_is_keyed_by_chart(isolated_cache):
    model = MODELS["acrobot"]
    a, b = charts.random_affine(model, 0, "x"), charts.random_affine(model, 1, "x")
    assert el._compiled(model, el._ref(model, a)) is not el._compiled(model, el._ref(model, b))
    assert el._compiled(model, el._ref(model, a)) is el._compiled(model, el._ref(model, a))
    assert el._ref(model, charts.identity(2)) is None and el._ref(model, None) is None


# ----------------------------------------------------------------------------------------------------------
# Validation
# ----------------------------------------------------------------------------------------------------------

@pytest.mark.parametrize("bad, label", [
    (dict(p=[0.1]), "p"), (dict(pd=[0.0, 0.0, 0.0]), "pd"), (dict(tau_p=[1.0, np.nan]), "tau_p"),
    (dict(p=[[0.1, 0.2]]), "p"), (dict(pd=["a", "b"]), "pd"), (dict(tau_p=[np.inf, 0.0]), "tau_p"),
    (dict(p=None), "p")])
def test_chart_state_is_validated(bad, label):
    model = MODELS["double_pendulum"]
    chart = charts.nonlinear(model)
    args = dict(p=[0.1, 0.2], pd=[0.0, 1.0], tau_p=[1.0, 0.0]) | bad
    with pytest.raises(StateError, match=rf"^{label} (has|is)"):
        el.split_chart(model, chart, args["p"], args["pd"], args["tau_p"])


def test_a_chart_that_does_not_fit_is_refused():
    model = MODELS["double_pendulum"]

    class Short:
        name, key = "short", "short-v1"

        def psi(self, p, sin, cos):
            return [p[0]]

    with pytest.raises(ValueError, match="chart 'short' returns 1 joint coordinates but model 'double_pendulum' has 2"):
        el.split_chart(model, Short(), [0.0, 0.0], [0.0, 0.0], [0.0, 0.0])
    with pytest.raises(TypeError, match="not a chart"):
        el.split_chart(model, object(), [0.0, 0.0], [0.0, 0.0], [0.0, 0.0])


def test_a_singular_chart_is_reported_with_the_chart():
    """``q = (p0, 2 p0)`` is no chart (its Jacobian is singular), so M_p is singular: the error names the chart."""
    model = MODELS["double_pendulum"]

    class Collapsed:
        name, key = "collapsed", "collapsed-v1"

        def psi(self, p, sin, cos):
            return [p[0], 2 * p[0]]

    with pytest.raises(ValueError, match="chart 'collapsed'.*singular"):
        el.split_chart(model, Collapsed(), [0.3, 0.1], [0.0, 0.0], [0.0, 0.0])
