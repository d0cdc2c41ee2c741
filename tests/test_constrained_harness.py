"""The harness side of constrained dynamics (article 5): declarations, admissible sampling, the Pinocchio
reference's KKT solve, frames moving the constraints, and eval refusing inadmissible states."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest
from hypothesis import given
from hypothesis import strategies as st

import cases
from cases import Body, JointCoupling, ModelError, PointOnCircle, PointOnLine, PointsCoincide, build_model
from crosscheck import frames, reference, sampling
from crosscheck.cli import main
from tests.closed_forms import article_Cqd, article_g, article_M

Z = (0.0, 0.0, 1.0)
CONSTRAINED = ["double_pendulum_circle", "four_bar", "slider_crank", "cartesian_pendulum",
               "double_pendulum_absolute_loop"]


def _cartesian_lam(q, qd, u, m=1.0, L=1.0, g=9.81):  # noqa: N803
    """Closed form of the cartesian pendulum's multiplier (cases.constrained.cartesian_pendulum)."""
    return -m * (qd @ qd + q @ (np.array([0.0, -g]) + u / m)) / (2.0 * L**2)


# ------------------------------------------------------------------------------------------- declarations


def test_every_violated_constraint_precondition_is_reported_together():
    bodies = [Body("a", None, "revolute", Z, 1.0, com=(0.0, -1.0, 0.0)),
              Body("b", "a", "revolute", Z, 1.0, com=(0.0, -1.0, 0.0), translation=(0.0, -1.0, 0.0))]
    bad = [PointOnCircle("circle", "ghost", (0, 0, 0), (0, 0, 0), -1.0),
           PointsCoincide("loop", "a", (0, 0, 0), "a", (0, 0, 0), ((1.0, 0.0, 0.0), (1.0, 0.0, 0.0))),
           PointOnLine("line", "b", (0, 0, 0), (0, 0, 0), ((0.0, 2.0, 0.0),)),
           JointCoupling("gear", ("a", "b"), (1.0,)),
           "not a declaration"]
    with pytest.raises(ModelError) as info:
        build_model("broken", bodies, constraints=bad)
    text = str(info.value)
    for expected in ("unknown body 'ghost'", "positive finite radius", "joins body 'a' to itself",
                     "directions are not orthonormal", "normals are not orthonormal", "one coefficient each",
                     "is not a declaration"):
        assert expected in text, expected


def test_a_massless_carriage_is_allowed_but_a_joint_that_moves_no_mass_is_not():
    carriage = Body("carriage", None, "prismatic", (1.0, 0.0, 0.0), 0.0)
    with pytest.raises(ModelError, match="joint of body 'carriage' moves no mass"):
        build_model("bare", [carriage])
    with pytest.raises(ModelError, match="zero mass but a non-zero inertia"):
        build_model("odd", [dataclasses.replace(carriage, inertia=np.eye(3))])
    assert cases.load("cartesian_pendulum").bodies[0].mass == 0.0


def test_the_digest_sees_every_constraint_number_at_full_precision():
    a = cases.load("double_pendulum_circle")
    b = cases.load("double_pendulum_circle", R=0.5 + 1e-15)
    assert a.digest() != b.digest() and a.k == 1 and cases.load("double_pendulum_absolute_loop").k == 4


def test_an_unreachable_circle_is_refused_by_the_case():
    with pytest.raises(cases.CaseError, match="misses the tip's reachable annulus"):
        cases.load("double_pendulum_circle", xc=5.0, yc=0.0, R=0.5)


# ------------------------------------------------------------------------------------------------ sampling


@pytest.mark.parametrize("case", CONSTRAINED)
def test_sampled_states_are_admissible_by_pinocchio_kinematics(case):
    model = cases.load(case)
    for state in sampling.sample_states(model, 20, 3, case):
        phi, Jc, _ = reference.constraint_kinematics(model, state.q, state.qd)
        assert np.abs(phi).max() < 1e-13 * sampling.length_scale(model) ** 2
        assert np.abs(Jc @ np.array(state.qd)).max() < 1e-13 * (1 + np.abs(state.qd).sum())
        assert np.abs(state.qd).max() > 0.0            # the tangent projection keeps a real velocity


def test_a_configuration_that_cannot_satisfy_the_constraints_is_reported_with_how_far_it_got():
    bodies = [Body("link", None, "revolute", Z, 1.0, com=(0.0, -1.0, 0.0))]
    far = PointOnCircle("far", "link", (0.0, -1.0, 0.0), (5.0, 0.0, 0.0), 0.5)   # out of reach of a 1 m link
    model = build_model("unreachable", bodies, gravity=(0.0, -9.81, 0.0), constraints=[far])
    with pytest.raises(sampling.ProjectionError, match=r"did not reach the constraint manifold.*\|phi\|_inf"):
        sampling.project_configuration(model, [0.3])


# ------------------------------------------------------------------------------- reference (Pinocchio KKT)


@given(st.floats(-3.0, 3.0), st.floats(-3.0, 3.0), st.lists(st.floats(-10.0, 10.0), min_size=2, max_size=2))
def test_reference_cartesian_pendulum_multiplier_is_the_closed_form(angle, rate, u):
    model = cases.load("cartesian_pendulum")
    q = np.array([np.sin(angle), -np.cos(angle)])
    qd = rate * np.array([np.cos(angle), np.sin(angle)])
    u = np.array(u)
    s = reference.split(model, q, qd, u)
    assert s.lam[0] == pytest.approx(_cartesian_lam(q, qd, u), abs=1e-12 * (1 + abs(s.lam[0])))
    assert s.lam_drift[0] == pytest.approx(_cartesian_lam(q, qd, 0 * u), abs=1e-12 * (1 + abs(s.lam_drift[0])))


def test_reference_double_pendulum_circle_matches_a_3x3_kkt_solve_written_here():
    model = cases.load("double_pendulum_circle")
    t = sampling.project_configuration(model, [0.3, 1.2])
    x2 = np.sin(t[0]) + np.sin(t[0] + t[1]) - 1.0
    y2 = -np.cos(t[0]) - np.cos(t[0] + t[1]) + 1.0
    J = np.array([[np.cos(t[0]) + np.cos(t[0] + t[1]), np.cos(t[0] + t[1])],
                  [np.sin(t[0]) + np.sin(t[0] + t[1]), np.sin(t[0] + t[1])]])
    Jc = 2.0 * np.array([x2, y2]) @ J
    td = np.array([-Jc[1], Jc[0]]) * 1.7 / np.linalg.norm(Jc)            # tangent: Jc td = 0
    v = J @ td
    a_bias = np.array([-np.sin(t[0]) * td[0]**2 - np.sin(t[0] + t[1]) * (td[0] + td[1])**2,
                       np.cos(t[0]) * td[0]**2 + np.cos(t[0] + t[1]) * (td[0] + td[1])**2])
    bias = 2.0 * v @ v + 2.0 * np.array([x2, y2]) @ a_bias
    u = np.array([3.0, -2.0])
    M, h = article_M(t[1]), article_Cqd(t[1], td[0], td[1]) + article_g(t[0], t[1])
    K = np.block([[M, -Jc[:, None]], [Jc[None, :], np.zeros((1, 1))]])
    total = np.linalg.solve(K, np.concatenate([u - h, [-bias]]))
    drift = np.linalg.solve(K, np.concatenate([-h, [-bias]]))
    Minv = np.linalg.inv(M)
    B_c = Minv - np.outer(Minv @ Jc, Jc @ Minv) / (Jc @ Minv @ Jc)
    s = reference.split(model, t, td, u)
    np.testing.assert_allclose(s.constraint_jacobian[0], Jc, atol=1e-13)
    np.testing.assert_allclose(s.constraint_bias, [bias], atol=1e-12)
    np.testing.assert_allclose(s.total, total[:2], atol=1e-11)
    np.testing.assert_allclose(s.lam, total[2:], atol=1e-11)
    np.testing.assert_allclose(s.drift, drift[:2], atol=1e-11)
    np.testing.assert_allclose(s.lam_drift, drift[2:], atol=1e-11)
    np.testing.assert_allclose(s.ctrl, B_c @ u, atol=1e-12)                 # ctrl = B_c u (eq. 17) ...
    np.testing.assert_allclose(s.additivity, 0.0, atol=1e-12)              # ... and drift + ctrl = total
    assert abs(s.power_constr) < 1e-12 and np.abs(s.admissibility_total).max() < 1e-11


def test_reference_absolute_loop_gives_the_joint_models_accelerations():
    loop, joint = cases.load("double_pendulum_absolute_loop"), cases.load("double_pendulum", I1=0.1, I2=0.1)
    t, td, u = np.array([0.4, -1.1]), np.array([1.2, -0.7]), np.array([1.5, -2.0])
    q = [0.0, 0.0, t[0], np.sin(t[0]), -np.cos(t[0]), t[0] + t[1]]
    qd = [0.0, 0.0, td[0], np.cos(t[0]) * td[0], np.sin(t[0]) * td[0], td[0] + td[1]]
    a, b = reference.split(loop, q, qd, u), reference.split(joint, t, td, u)
    for name in ("drift", "ctrl", "total"):
        got = getattr(a, name)
        np.testing.assert_allclose([got[2], got[5] - got[2]], getattr(b, name), atol=1e-12)


def test_reference_duplicated_constraint_is_rank_deficient_but_answers_with_min_norm_multipliers():
    single = cases.load("double_pendulum_circle")
    twice = dataclasses.replace(single.constraints[0], name="again")
    double = build_model("twice", single.bodies, gravity=single.gravity, task_points=single.task_points,
                         constraints=[single.constraints[0], twice])
    state = sampling.sample_states(single, 2, 0, "dup")[1]
    a, b = reference.split(single, state.q, state.qd, state.u), reference.split(double, state.q, state.qd, state.u)
    assert b.constraint_rank == 1 and b.conditions["constraint"] > 1e8
    np.testing.assert_allclose(b.total, a.total, atol=1e-9)
    np.testing.assert_allclose(b.constraint_force, a.constraint_force, atol=1e-9)
    np.testing.assert_allclose(b.lam, [a.lam[0] / 2, a.lam[0] / 2], atol=1e-9)


# ------------------------------------------------------------------------------------------------- frames


@pytest.mark.parametrize("case", CONSTRAINED)
def test_moving_the_scene_moves_the_constraints_so_phi_and_lam_do_not_change(case):
    model = cases.load(case)
    moved = frames.move_scene(model, frames.sampled(1, case, 1)[0])
    state = sampling.sample_states(model, 2, 1, case)[1]
    a, b = reference.split(model, state.q, state.qd, state.u), reference.split(moved, state.q, state.qd, state.u)
    assert np.abs(b.constraint_value).max() < 1e-12
    np.testing.assert_allclose(b.lam, a.lam, atol=1e-9 * (1 + np.abs(a.lam).max()))


# ---------------------------------------------------------------------------------------------------- eval


def test_eval_refuses_an_inadmissible_state_saying_how_far_off_and_projects_on_request(capsys):
    args = ["eval", "--case", "cartesian_pendulum", "--q=0.5,-0.5", "--qd=1,0", "--formalism", "pinocchio"]
    assert main(args) == 2
    err = capsys.readouterr().err
    assert "not admissible" in err and "|phi(q)|_inf = 0.5 (row rod" in err and "--project" in err
    assert main(args + ["--project"]) == 0
    captured = capsys.readouterr()
    assert "projected onto the constraint manifold" in captured.err and "lam" in captured.out
