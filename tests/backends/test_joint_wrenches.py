"""The compared joint loads ``joint_wrenches`` / ``joint_wrenches_drift`` (Split; article 6.1.4-6.1.5, 7.2): row i the
force and moment the parent exerts on body i through joint i, about body i's origin, in body frame i. Supplied by
Newton–Euler (its reactions), screw (its body wrenches reordered) and Pinocchio (``data.f`` after RNEA); checked
against Newton's second law on the article's double pendulum, against each other on every built-in case and on a
geared model, and shown to catch a load computed at the wrong acceleration and a 1e-6 change of one mass."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given
from hypothesis import strategies as st

import cases
from cases.constraints import JointCoupling
from closed_forms import (article_Cqd, article_g, article_M, endpoint_jacobian, heaviest_body_heavier, inv2, tip_bias,
                          tip_position)
from crosscheck import backends
from crosscheck.faults import backend_catalog
from crosscheck.core import tolerance
from crosscheck.core.compare import AGREE, DISAGREE, NOT_COMPARED, compare
from crosscheck.faults.injection import default_specs, injected
from crosscheck.engine.evaluation import CaseSetup, evaluate
from crosscheck.engine.specs import CaseSpec
from crosscheck.core.sampling import State, sample_states
from formalisms.interface import UNSUPPORTED

LOADS = ("joint_wrenches", "joint_wrenches_drift")
SUPPLIERS = ("newton_euler", "screw", "pinocchio")
ALL = [backends.get(n) for n in backends.names()]
G = 9.81

angle = st.floats(-np.pi, np.pi)
rate = st.floats(-3.0, 3.0)
torque = st.floats(-10.0, 10.0)


def _rz(angle_z: float) -> np.ndarray:
    c, s = np.cos(angle_z), np.sin(angle_z)
    return np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])


def _cross_z(r: np.ndarray, f: np.ndarray) -> float:
    """The z moment ``r x f`` of an in-plane force."""
    return float(r[0] * f[1] - r[1] * f[0])


def pendulum_loads(t, td, u, m1=1.0, m2=1.0):
    """Newton's second law on the article's double pendulum (section 3, unit links), written here from eqs. (4)-(8):
    qdd = M^-1 (u - C qd - g); each point mass k at p_k with classical acceleration a_k needs the net force
    m_k (a_k - gravity); the joint of body i carries that of every mass it holds up, and its moment about the body's
    origin o_i (the world origin for link 1, the elbow for link 2). Rows [force, moment] in body frame i (Rz(t1),
    Rz(t1 + t2)), as ``Split.joint_wrenches``."""
    t, td, u = (np.asarray(x, dtype=float) for x in (t, td, u))
    M = article_M(t[1], m1, m2)
    tdd = inv2(M) @ (u - article_Cqd(t[1], td[0], td[1], m2) - article_g(t[0], t[1], m1, m2, g=G))
    elbow = np.array([np.sin(t[0]), -np.cos(t[0])])
    a_elbow = np.array([np.cos(t[0]) * tdd[0] - np.sin(t[0]) * td[0] ** 2,
                        np.sin(t[0]) * tdd[0] + np.cos(t[0]) * td[0] ** 2])
    a_tip = endpoint_jacobian(t) @ tdd + tip_bias(t, td)
    gravity = np.array([0.0, -G])
    net = [m1 * (a_elbow - gravity), m2 * (a_tip - gravity)]
    points = [elbow, tip_position(t)]
    origins, held, frames_ = [np.zeros(2), elbow], [(0, 1), (1,)], [_rz(t[0]), _rz(t[0] + t[1])]
    rows = []
    for origin, masses, R in zip(origins, held, frames_):
        force = sum(net[k] for k in masses)
        moment = sum(_cross_z(points[k] - origin, net[k]) for k in masses)
        rows.append(np.concatenate([R.T @ np.array([*force, 0.0]), R.T @ np.array([0.0, 0.0, moment])]))
    return np.array(rows)


@given(st.tuples(angle, angle), st.tuples(rate, rate), st.tuples(torque, torque))
def test_the_double_pendulums_loads_are_newtons_second_law(t, td, u):
    model = cases.load("double_pendulum")
    total, drift = pendulum_loads(t, td, u), pendulum_loads(t, td, (0.0, 0.0))
    assert np.allclose(total[:, 5], u, atol=1e-10)       # the axis moments are the inputs B u (6.1.5)
    assert np.allclose(drift[:, 5], 0.0, atol=1e-10)     # and zero at the ZTCF (6.1.4): passive loads only
    scale = 1e-12 * (1.0 + np.abs(total).max() + np.abs(drift).max())
    for name in SUPPLIERS:
        split = backends.get(name).split(model, t, td, u)
        np.testing.assert_allclose(split.joint_wrenches, total, rtol=0, atol=scale, err_msg=name)
        np.testing.assert_allclose(split.joint_wrenches_drift, drift, rtol=0, atol=scale, err_msg=name)


def test_newton_euler_reports_its_reactions_and_screw_its_body_wrenches():
    model = cases.load("spatial_arm")
    state = sample_states(model, 2, 0, "spatial_arm")[1]
    ne = backends.get("newton_euler").split(model, state.q, state.qd, state.u)
    assert np.array_equal(ne.joint_wrenches, ne.extras["joint_reactions"])
    assert np.array_equal(ne.joint_wrenches_drift, ne.extras["joint_reactions_drift"])
    sc = backends.get("screw").split(model, state.q, state.qd, state.u)
    assert np.array_equal(sc.joint_wrenches, sc.extras["wrenches_body"][:, [3, 4, 5, 0, 1, 2]])
    for name in ("euler_lagrange", "operational_space", "geometric"):
        split = backends.get(name).split(model, state.q, state.qd, state.u)
        assert split.joint_wrenches is UNSUPPORTED and split.joint_wrenches_drift is UNSUPPORTED


@pytest.mark.parametrize("case", [spec.name for spec in default_specs()])
def test_the_three_suppliers_agree_on_every_built_in_case(case):
    model = cases.load(case)
    for state in sample_states(model, 3, 5, case)[1:]:
        outcome = evaluate(model, state, ALL)
        # redundant rows (rank below k) would leave the multipliers, so the joint loads, not unique: the rank rule
        # puts them in BREAKDOWN, not compared (differential_drive's three rows are independent since lateral=False)
        unique = all(s.constraint_rank in (None, model.k) for s in outcome.trusted.values())
        for quantity in LOADS:
            comparison = outcome.comparisons[quantity]
            if not unique:
                assert comparison.verdict == NOT_COMPARED, (case, state.index, quantity, comparison.verdict)
                continue
            assert comparison.verdict == AGREE, (case, state.index, quantity, comparison.worst_ratio)
            assert set(comparison.voters) == set(SUPPLIERS)
            assert set(comparison.not_compared) == {"euler_lagrange", "operational_space", "geometric"}


def _geared_double_pendulum():
    """The double pendulum with a gear q2 = -0.5 q1 + 0.2 (a JointCoupling: no point force, a torque on the joints)."""
    base = cases.load("double_pendulum")
    gear = JointCoupling("gear", ("link1", "link2"), (0.5, 1.0), 0.2)
    return cases.build_model("geared_pendulum", base.bodies, gravity=base.gravity, task_points=base.task_points,
                             constraints=[gear])


def test_a_gears_torque_is_carried_by_its_joints_in_every_supplier():
    """The coupling's generalized force ``c_j lam`` is part of the coupled joints' loads (Split.joint_wrenches): the
    axis moments are ``B u + c lam`` in all three suppliers (screw adds back what it applied as a constraint wrench,
    RNEA keeps it in the joint)."""
    model = _geared_double_pendulum()
    q1 = 0.7
    q, qd, u = np.array([q1, 0.2 - 0.5 * q1]), np.array([1.2, -0.6]), np.array([3.0, -2.0])
    splits = {name: backends.get(name).split(model, q, qd, u) for name in SUPPLIERS}
    c = np.array([0.5, 1.0])
    for name, split in splits.items():
        np.testing.assert_allclose(split.joint_wrenches[:, 5], u + c * split.lam[0], rtol=0, atol=1e-11, err_msg=name)
        np.testing.assert_allclose(split.joint_wrenches_drift[:, 5], c * split.lam_drift[0], rtol=0, atol=1e-11,
                                   err_msg=name)
    outcome = evaluate(model, State(0, tuple(q), tuple(qd), tuple(u)), ALL)
    assert all(outcome.comparisons[k].verdict == AGREE for k in LOADS)


def test_non_unique_multipliers_leave_the_loads_out_of_the_vote():
    """At the four-bar's change point S = Jc M^-1 Jc^T is singular: lam is not unique, nor are the loads its point
    forces make (BREAKDOWN_SCOPE), while the accelerations are still compared."""
    assert set(LOADS) <= set(tolerance.BREAKDOWN_SCOPE["constraint"])
    model = cases.load("four_bar")
    outcome = evaluate(model, State(0, (np.pi / 2, 0.0, np.pi / 2), (1.0, -1.0, 1.0), (1.0, 0.5, -1.0)), ALL)
    assert all("constraint" in b for b in outcome.breakdowns.values())
    assert outcome.comparisons["total"].verdict == AGREE
    assert all(outcome.comparisons[k].verdict == NOT_COMPARED for k in LOADS + ("lam",))


def test_loads_are_frame_checked_and_not_chart_checked():
    """Body-frame loads do not change with the world frame: every supplier on the moved scene votes with the
    unmoved ones. No chart-native backend supplies them, so no chart check repeats the joint-chart comparison."""
    setup = CaseSetup.build(CaseSpec("acrobot"), 0)
    state = sample_states(setup.model, 2, 0, "acrobot")[1]
    outcome = setup.evaluate(state, ALL)
    frame = setup.scene(state)[0].name
    for quantity in LOADS:
        check = outcome.checks[f"frame: {quantity}"]
        assert check.verdict == AGREE
        assert set(check.voters) == {*SUPPLIERS, *(f"{n}@{frame}" for n in SUPPLIERS)}
        assert not any(key.startswith("chart") and key.endswith(quantity) for key in outcome.checks)
    assert any(key.startswith("chart") for key in outcome.checks)


def test_loads_at_the_drift_acceleration_are_caught_and_newton_euler_named():
    model = cases.load("double_pendulum")
    state = State(0, (0.4, 1.1), (1.0, -2.0), (3.0, 1.0))
    with injected(backend_catalog.get("ne-reactions-at-drift-acceleration")):
        outcome = evaluate(model, state, ALL)
    comparison = outcome.comparisons["joint_wrenches"]
    assert comparison.verdict == DISAGREE and comparison.outlier == "newton_euler"
    assert outcome.comparisons["joint_wrenches_drift"].verdict == AGREE
    assert outcome.comparisons["total"].verdict == AGREE      # only the loads show it


@pytest.mark.parametrize("case", ["double_pendulum", "acrobot", "four_bar", "double_pendulum_circle"])
def test_a_one_in_a_million_mass_error_exceeds_the_load_tolerance(case):
    """The tolerance is tight: Pinocchio on the model with its heaviest body 1e-6 heavier is told apart from the
    correct suppliers at every sampled state (the default gate's seed)."""
    model = cases.load(case)
    wrong = heaviest_body_heavier(model, 1e-6)
    for state in sample_states(model, 6, 0, case)[1:]:
        outcome = evaluate(model, state, ALL)
        bad = backends.get("pinocchio").split(wrong, state.q, state.qd, state.u)
        for quantity in LOADS:
            good = outcome.comparisons[quantity]
            values = {n: outcome.splits[n].quantity(quantity) for n in ("newton_euler", "screw")}
            verdict = compare(quantity, {**values, "wrong": bad.quantity(quantity)}, good.tolerance)
            assert verdict.verdict == DISAGREE and verdict.outlier == "wrong", (state.index, quantity)


def test_the_load_scale_is_the_sum_of_the_magnitudes_times_cond_m():
    """Scales.load (module doc of crosscheck.core.tolerance) by hand for the double pendulum: reach 4 (1 + the elbow
    placement 1 + two COM offsets 1), m_total = 2, no inertia; lever 2 * 16."""
    model = cases.load("double_pendulum")
    q, qd, u = np.array([0.4, 1.1]), np.array([1.0, -2.0]), np.array([3.0, 1.0])
    splits = [backends.get(n).split(model, q, qd, u) for n in SUPPLIERS]
    at = tolerance.scales(splits, model, q, qd)
    total = np.median([np.abs(s.total).sum() for s in splits])
    load = np.median([np.abs(s.joint_wrenches).max() for s in splits])
    expected = 32.0 * (total + 9.0) + 5.0 * 2.0 * G + load
    assert at.load == pytest.approx(expected, rel=1e-12)
    assert tolerance.tolerance("joint_wrenches", at) == pytest.approx(100 * tolerance.EPS * at.cond_M * expected,
                                                                       rel=1e-12)



def test_loads_near_a_vacuous_constraint_row_carry_the_multipliers_rounding():
    """A fuzz finding, shrunk: a circle constraint whose row nearly vanishes at q2 = 2e-8 (S tiny, lam = 5.6 but
    lam_scale = 5e10). lam rounds at eps cond(M) lam_scale, not at eps |lam|: the loads (and the screw wrenches' frame
    law) on the scene moved by t = (0, 0, 1) once disagreed with the unmoved ones at 1.3 and 2.6 times the tolerance."""
    from cases import Body, PointOnCircle
    from crosscheck.checks import frames, invariance

    model = cases.build_model("nearly_vacuous_circle", [
        Body("b0", None, "revolute", (0, 0, 1), 28.973065541411664, inertia=np.diag([7.2432664, 3.4678422, 7.2432664])),
        Body("b1", None, "revolute", (1, 0, 0), 1.0, com=(0, 0, 0.477742911577675),
             translation=(0, 0.5043645627353799, 0)),
        Body("b2", "b1", "revolute", (0, 0, 1), 1.0, inertia=np.diag([0.03724997, 0.07449994, 0.03724997]))],
        constraints=[PointOnCircle("c0", "b1", (0, 0.5, 0), (-0.5403023058681398, 0.16289357792748338, 0.0), 1.0)])
    state = State(0, (0.0, 2.281272145616934e-08, 0.0), (0.0, 0.0, 0.0), (0.0, 0.0, 0.0))
    frame = frames.Frame("g", np.eye(3), np.array([0.0, 0.0, 1.0]))
    here, there = evaluate(model, state, ALL), evaluate(frames.move_scene(model, frame), state, ALL)
    assert max(s.lam_scale for s in here.trusted.values()) > 1e9 * np.abs(here.splits["pinocchio"].lam).max()
    checks = invariance.frame_checks(model, frame, state, here.trusted, there.trusted)
    assert all(c.verdict != DISAGREE for c in checks.values()), {k: c.worst_ratio for k, c in checks.items()}
    assert all(checks[key].verdict == AGREE for key in ("frame: joint_wrenches", "frame law: screw wrenches_space"))


def test_loads_near_a_tangent_circle_row_carry_the_rounding_of_its_short_row():
    """A fuzz finding, shrunk: a slider whose point moves tangentially to its circle at q = 0.375 (Jc = 2.5e-8, a
    difference of O(1) coordinates, lam = -6e7). lam inherits Jc's relative rounding eps / 2.5e-8, and so do the
    loads: on the scene moved by t = (0, 1, 0) they once disagreed with the unmoved ones at 22 times the tolerance."""
    from cases import Body, PointOnCircle
    from crosscheck.checks import frames, invariance

    model = cases.build_model("tangent_circle", [
        Body("b0", None, "prismatic", (0, 1, 0), 1.0),
        Body("b1", "b0", "revolute", (0, 0, 1), 1.0, inertia=np.diag([0.25, 0.04075453917271098, 0.209245460827289]))],
        input_map=[[1.0], [0.0]], constraints=[PointOnCircle("c0", "b0", (0, 0, 0), (-0.75, 0.375, 0.0), 0.75)])
    state = State(0, (0.3749999875823657, 0.0), (0.0, 0.0), (1.0,))
    frame = frames.Frame("g", np.eye(3), np.array([0.0, 1.0, 0.0]))
    here, there = evaluate(model, state, ALL), evaluate(frames.move_scene(model, frame), state, ALL)
    assert np.abs(here.splits["pinocchio"].lam).max() > 1e7 and not here.failed
    checks = invariance.frame_checks(model, frame, state, here.trusted, there.trusted)
    assert all(c.verdict != DISAGREE for c in checks.values()), {k: c.worst_ratio for k, c in checks.items()}
