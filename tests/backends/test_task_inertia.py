"""The compared task-space inertia ``task_inertia`` (Split; article eq. 22): ``Lambda = (J M^-1 J^T)^-1`` of the model's
default task point in its task coordinates. Supplied by the operational-space backend (its own Lambda), screw (PoE
point Jacobian), geometric (casadi point kinematics, in any chart) and Pinocchio (frame Jacobian, computeMinverse);
checked against the article's closed form (eqs. 5, 6), against each other with and without constraints, under chart
and frame changes, at and near task singularities, and shown to catch an uninverted Lambda and a 1e-6 mass error."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import assume, given
from hypothesis import strategies as st

import cases
from closed_forms import article_M, endpoint_jacobian, heaviest_body_heavier
from crosscheck import backends
from crosscheck.checks import charts, frames
from crosscheck.faults import backend_catalog
from crosscheck.core import tolerance
from crosscheck.core.compare import AGREE, DISAGREE, NOT_COMPARED, compare
from crosscheck.faults.injection import default_specs, injected
from crosscheck.engine.evaluation import CaseSetup, evaluate
from crosscheck.engine.specs import CaseSpec
from crosscheck.core.sampling import State, sample_states
from formalisms import geometric
from formalisms.interface import UNSUPPORTED

SUPPLIERS = ("screw", "operational_space", "geometric", "pinocchio")
ALL = [backends.get(n) for n in backends.names()]

angle = st.floats(-np.pi, np.pi)


def article_task_matrix(t, m1, m2, l1, l2):
    """``A = J M^-1 J^T`` with the article's M (eq. 6) and endpoint Jacobian (eq. 5); Lambda = A^-1 (eq. 22)."""
    J = endpoint_jacobian(t, l1, l2)
    return J @ np.linalg.solve(article_M(t[1], m1, m2, l1, l2), J.T)


@given(st.tuples(angle, angle), st.sampled_from([(1.0, 1.0, 1.0, 1.0), (2.0, 0.5, 0.8, 1.3)]))
def test_every_supplier_gives_the_articles_tip_inertia(t, params):
    m1, m2, l1, l2 = params
    A = article_task_matrix(t, m1, m2, l1, l2)
    cond = np.linalg.cond(A)
    assume(cond < 1e6)
    expected = np.linalg.inv(A)
    model = cases.load("double_pendulum", m1=m1, m2=m2, l1=l1, l2=l2)
    for name in SUPPLIERS:
        split = backends.get(name).split(model, t, (0.5, -1.0), (1.0, 2.0))
        if name == "operational_space" and tolerance.breakdown(split):
            continue                                     # above cond 1e3 the method itself is not trusted
        np.testing.assert_allclose(split.task_inertia, expected, rtol=0,
                                   atol=1e-13 * cond * np.abs(expected).max(), err_msg=name)


def test_with_constraints_lambda_is_the_unconstrained_ms():
    """The cartesian pendulum (a unit point mass on x and y slides, held on a circle): M = 1 and J = 1, so eq. (22)'s
    Lambda is the identity, although the rod leaves the bob free to move along the circle only."""
    model = cases.load("cartesian_pendulum")
    for state in sample_states(model, 4, 0, "cartesian_pendulum"):
        for name in SUPPLIERS:
            split = backends.get(name).split(model, state.q, state.qd, state.u)
            np.testing.assert_allclose(split.task_inertia, np.eye(2), rtol=0, atol=1e-14, err_msg=name)


def test_the_other_backends_do_not_supply_it():
    model = cases.load("spatial_arm")
    for name in ("euler_lagrange", "newton_euler"):
        assert backends.get(name).split(model, np.zeros(model.n), np.zeros(model.n),
                                        np.zeros(model.m)).task_inertia is UNSUPPORTED


@pytest.mark.parametrize("case", [spec.name for spec in default_specs()])
def test_the_suppliers_agree_on_every_built_in_case_and_in_every_chart_and_frame(case):
    """The gate's comparison and its chart and frame checks (geometric evaluates in each chart; Euler–Lagrange,
    which supplies no Lambda, is left out to spare its derivations in the charts)."""
    setup = CaseSetup.build(CaseSpec(case), 2)
    evaluated = [b for b in ALL if b.name != "euler_lagrange"]
    for state in sample_states(setup.model, 3, 2, case)[1:]:
        outcome = setup.evaluate(state, evaluated)
        comparison = outcome.comparisons["task_inertia"]
        assert comparison.verdict == AGREE, (case, state.index, comparison.worst_ratio)
        assert len(comparison.voters) >= 3 and set(comparison.voters) <= {*SUPPLIERS, "closed_form"}
        checks = {k: c for k, c in outcome.checks.items() if k.endswith(": task_inertia")}
        assert "frame: task_inertia" in checks
        assert any(k.startswith("chart") for k in checks)
        assert all(c.verdict == AGREE for c in checks.values()), {k: c.worst_ratio for k, c in checks.items()}


def test_it_is_the_same_matrix_in_a_chart_and_on_a_moved_scene():
    """J_p M_p^-1 J_p^T = J M^-1 J^T in any chart q = psi(p); the moved scene turns the task directions with it."""
    model = cases.load("acrobot")
    q, qd, u = np.array([0.3, -0.8]), np.array([1.5, 0.5]), np.array([2.0])
    joint = geometric.split(model, q, qd, u).task_inertia
    chart = charts.get("nonlinear", model)
    p = chart.p_of(q)
    in_chart = geometric.split_chart(model, chart, p, charts.velocity_to_chart(chart, p, qd),
                                     charts.force_to_chart(chart, p, model.input_map @ u)).task_inertia
    np.testing.assert_allclose(in_chart, joint, rtol=1e-12)
    moved = frames.move_scene(model, frames.sampled(4, "acrobot", 1)[0])
    for name in SUPPLIERS:
        np.testing.assert_allclose(backends.get(name).split(moved, q, qd, u).task_inertia, joint, rtol=1e-12,
                                   err_msg=name)


def test_at_a_task_singularity_it_is_left_out_not_failed():
    """Stretched arm (theta2 = 0): A = J M^-1 J^T is singular, Lambda does not exist: NaN, cond inf, and only
    task_inertia leaves the vote of the backends that merely report it (the operational-space one leaves wholly)."""
    model = cases.load("double_pendulum")
    outcome = evaluate(model, State(0, (0.4, 0.0), (1.0, -2.0), (3.0, 1.0)), ALL)
    for name in ("screw", "geometric", "pinocchio"):
        assert outcome.breakdowns[name] == {"task_inertia": np.inf}
        assert np.all(np.isnan(outcome.splits[name].task_inertia))
        assert name in outcome.comparisons["drift"].voters
    assert set(outcome.breakdowns["operational_space"]) == {"task", "task_jacobian"}
    assert outcome.breakdowns["operational_space"]["task"] == np.inf
    assert outcome.comparisons["task_inertia"].verdict == NOT_COMPARED
    assert not outcome.failed


@pytest.mark.parametrize("theta2", [1e-2, 1e-3, 3e-4, np.pi - 1e-3])
def test_near_a_singularity_the_tolerance_grows_with_cond_a_and_the_rest_agree(theta2):
    """cond(A) from 1e4 to 1e8: the operational-space backend is in BREAKDOWN, the other three still compare Lambda,
    with a tolerance of 100 eps cond(M) |Lambda| (cond(A) + L sqrt(|Lambda| ||M^-1||)) (crosscheck.core.tolerance), and
    agree; the cond(A) term dominates."""
    model = cases.load("double_pendulum")
    outcome = evaluate(model, State(0, (0.4, theta2), (1.0, -2.0), (3.0, 1.0)), ALL)
    comparison = outcome.comparisons["task_inertia"]
    assert "operational_space" in outcome.breakdowns and comparison.verdict == AGREE
    assert set(comparison.voters) == {"screw", "geometric", "pinocchio"}
    voters = [outcome.splits[name] for name in ("screw", "geometric", "pinocchio")]
    for split in voters:                                 # the condition each reports is its Lambda's
        eig = np.linalg.eigvalsh(split.task_inertia)
        assert split.conditions["task_inertia"] == pytest.approx(eig[-1] / eig[0], rel=1e-6)
    cond = np.median([split.conditions["task_inertia"] for split in voters])
    size = np.median([np.abs(split.task_inertia).max() for split in voters])
    at = tolerance.scales(outcome.trusted.values(), model, (0.4, theta2), (1.0, -2.0))
    assert at.task_cond == cond and at.task_size == size and cond > 1e3
    rounding_of_J = at.lever * np.sqrt(size * at.minv)
    assert comparison.tolerance == pytest.approx(100 * tolerance.EPS * at.cond_M * size * (cond + rounding_of_J),
                                                 rel=1e-12)
    assert cond > 10 * rounding_of_J


def test_an_uninverted_lambda_is_caught_and_the_operational_space_backend_named():
    model = cases.load("spatial_arm")
    state = sample_states(model, 2, 0, "spatial_arm")[1]
    with injected(backend_catalog.get("osc-lambda-reported-uninverted")):
        outcome = evaluate(model, state, ALL)
    comparison = outcome.comparisons["task_inertia"]
    assert comparison.verdict == DISAGREE and comparison.outlier == "operational_space"
    assert outcome.comparisons["total"].verdict == AGREE      # only Lambda shows it


@pytest.mark.parametrize("case", ["double_pendulum", "acrobot", "four_bar", "slider_crank"])
def test_a_one_in_a_million_mass_error_exceeds_the_tolerance_where_the_task_is_well_conditioned(case):
    """Pinocchio on the model with its heaviest body 1e-6 heavier is told apart from the correct suppliers at the
    sampled states with cond(A) below 100 (near a singularity the tolerance grows with cond(A), and with it the
    smallest mass error it resolves)."""
    model = cases.load(case)
    wrong = heaviest_body_heavier(model, 1e-6)
    checked = 0
    for state in sample_states(model, 8, 0, case)[1:]:
        outcome = evaluate(model, state, ALL)
        if outcome.splits["pinocchio"].conditions["task_inertia"] > 100:
            continue
        bad = backends.get("pinocchio").split(wrong, state.q, state.qd, state.u).task_inertia
        values = {n: outcome.splits[n].task_inertia for n in ("screw", "geometric")}
        verdict = compare("task_inertia", {**values, "wrong": bad}, outcome.comparisons["task_inertia"].tolerance)
        assert verdict.verdict == DISAGREE and verdict.outlier == "wrong", state.index
        checked += 1
    assert checked >= 3


def test_a_task_direction_the_point_barely_moves_in_is_compared_with_the_rounding_of_j():
    """A fuzz finding: one body whose task point moves slowly along x (|J| = 0.03 m from lever arms of 0.5 m, Lambda =
    1042 kg). J is a difference of lever-sized terms, so its relative rounding is eps L / |J|; the tolerance once left
    that out and the correct backends disagreed at 18 times it."""
    model = cases.build_model("slow_direction", [cases.Body(
        "b0", None, "revolute", (-0.8879017563584892, 0.0, 0.46003311952022563), 0.06497361354610663,
        inertia=np.diag([0.005117345745310789, 0.0034339736977065448, 0.002923730525059905]),
        translation=(-0.6983458712816262, 0.9115339385022554, -0.9106528656194295))],
        task_points=[cases.TaskPoint("tip", "b0", (0.2344030797423785, -0.11975812992046675, 0.4103923480359646),
                                     directions=[[1.0, 0.0, 0.0]])])
    outcome = evaluate(model, State(0, (-2.883795229812476,), (-3.0,), (-5.294065575208716,)), ALL)
    comparison = outcome.comparisons["task_inertia"]
    assert comparison.verdict == AGREE and len(comparison.voters) == 4
    assert np.abs(outcome.splits["pinocchio"].task_inertia).max() > 1000.0
