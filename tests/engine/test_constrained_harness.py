"""The harness side of constrained dynamics (article 5): declarations, admissible sampling, frames moving the
constraints, and eval refusing inadmissible states. The Pinocchio reference's KKT solve is tested with the formalisms
against the shared references in ``test_constrained_backends.py``."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

import cases
from cases import Body, JointCoupling, ModelError, PointOnCircle, PointOnLine, PointsCoincide, build_model
from crosscheck.checks import frames
from crosscheck.references.pinocchio import kinematics
from crosscheck.references.pinocchio import reference
from crosscheck.core import sampling
from crosscheck.cli import main

Z = (0.0, 0.0, 1.0)
CONSTRAINED = ["double_pendulum_circle", "four_bar", "slider_crank", "cartesian_pendulum",
               "double_pendulum_absolute_loop"]


# ------------------------------------------------------------------------------------------- declarations


def test_every_violated_constraint_precondition_is_reported_together():
    bodies = [Body("a", None, "revolute", Z, 1.0, com=(0.0, -1.0, 0.0)),
              Body("b", "a", "revolute", Z, 1.0, com=(0.0, -1.0, 0.0), translation=(0.0, -1.0, 0.0))]
    bad = [PointOnCircle("circle", "ghost", (0, 0, 0), (0, 0, 0), -1.0),
           PointsCoincide("loop", "a", (0, 0, 0), "a", (0, 0, 0), ((1.0, 0.0, 0.0), (1.0, 0.0, 0.0))),
           PointOnLine("line", "b", (0, 0, 0), (0, 0, 0), ((0.0, 2.0, 0.0),)),
           JointCoupling("gear", ("a", "b"), (1.0,)),
           JointCoupling("belt", ("a",), ("two",)),
           PointOnCircle("dup", "a", (0, 0, 0), (0, 0, 0), 1.0), PointOnCircle("dup", "b", (0, 0, 0), (0, 0, 0), 1.0),
           "not a declaration"]
    with pytest.raises(ModelError) as info:
        build_model("broken", bodies, constraints=bad)
    text = str(info.value)
    for expected in ("unknown body 'ghost'", "positive finite radius", "joins body 'a' to itself",
                     "directions are not orthonormal", "normals are not orthonormal", "one coefficient each",
                     "coefficient is not a number: 'two'", "constraint names repeat: ['dup', 'dup']",
                     "is not a declaration"):
        assert expected in text, expected


def test_a_massless_carriage_is_allowed_but_a_joint_that_moves_no_mass_is_not():
    carriage = Body("carriage", None, "prismatic", (1.0, 0.0, 0.0), 0.0)
    with pytest.raises(ModelError, match="joint of body 'carriage' moves no mass"):
        build_model("bare", [carriage])
    with pytest.raises(ModelError, match="joint of body 'carriage' moves no mass"):    # an inertia moves no slide
        build_model("odd", [dataclasses.replace(carriage, inertia=np.eye(3))])
    spinner = build_model("spinner", [Body("disk", None, "revolute", (0.0, 0.0, 1.0), 0.0, inertia=np.eye(3))])
    assert spinner.findings == ("body 'disk' has zero mass but a non-zero inertia [[1.0, 0.0, 0.0], [0.0, 1.0, 0.0], "
                                "[0.0, 0.0, 1.0]]; a massless body (a carriage) has zero inertia",)
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
        phi, Jc, _ = kinematics.constraint_kinematics(model, state.q, state.qd)
        assert np.abs(phi).max() < 1e-13 * model.length_scale ** 2
        assert np.abs(Jc @ np.array(state.qd)).max() < 1e-13 * (1 + np.abs(state.qd).sum())
        assert np.abs(state.qd).max() > 0.0            # the tangent projection keeps a real velocity


def test_a_configuration_that_cannot_satisfy_the_constraints_is_reported_with_how_far_it_got():
    bodies = [Body("link", None, "revolute", Z, 1.0, com=(0.0, -1.0, 0.0))]
    far = PointOnCircle("far", "link", (0.0, -1.0, 0.0), (5.0, 0.0, 0.0), 0.5)   # out of reach of a 1 m link
    model = build_model("unreachable", bodies, gravity=(0.0, -9.81, 0.0), constraints=[far])
    with pytest.raises(sampling.ProjectionError, match=r"did not reach the constraint manifold.*\|phi\|_inf"):
        sampling.project_configuration(model, [0.3])


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


def test_a_projected_velocity_satisfies_the_constraints_to_rounding_of_itself_however_small():
    """qd almost entirely off the tangent space: the projection keeps a tiny admissible part, and ``Jc qd`` is rounding
    of that part (eps |qd_projected|), not of the part removed (a residual once 1e12 times the tolerance)."""
    model = cases.load("double_pendulum_circle")
    q = sampling.project_configuration(model, np.array([0.3, 1.2]))
    _, Jc, _ = kinematics.constraint_kinematics(model, q, np.zeros(2))
    tangent = np.linalg.svd(Jc)[2][-1]
    for tiny in (1e-3, 1e-9, 1e-15, 0.0):
        qd = sampling.project_velocity(model, q, 7.0 * Jc[0] + tiny * tangent)
        assert np.abs(Jc @ qd).max() <= 4 * np.finfo(float).eps * np.linalg.norm(Jc) * max(np.abs(qd).max(), 1e-300)
        np.testing.assert_allclose(qd, tiny * tangent, rtol=1e-12, atol=1e-14)
