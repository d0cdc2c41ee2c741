"""Verdicts that explain: severity bands, the vote and the suspects, and hints from the shape of the error
(``crosscheck.core.compare``, ``crosscheck.reports.diagnosis``), each hint checked against an injected fault of known kind."""

from __future__ import annotations

import numpy as np
import pytest

import cases
import formalisms.newton_euler as ne
import formalisms.operational_space as osc
from crosscheck import backends
from crosscheck.checks import charts
from crosscheck.reports import diagnosis
from crosscheck.core.compare import AGREE, DISAGREE, SEVERITY, compare, severity, suspect, suspects, vote
from crosscheck.engine.specs import CaseSpec, Checks
from crosscheck.engine.run import run_gate
from crosscheck.reports.gate_summary import render
from formalisms.interface import Formalism

ALL = [backends.get(name) for name in backends.names()]
QUICK = Checks(charts=False, frames=0, conservation=False, closed_forms=False, self_test=False, linearization=False)


# ----------------------------------------------------------------------------------------------- severity


@pytest.mark.parametrize("multiple", [1.5, 9.0, 11.0, 9e3, 2e4, 1e12])
def test_severity_is_the_band_of_the_error_in_tolerances(multiple):
    comp = compare("drift", {"a": [0.0, 0.0], "b": [0.0, multiple * 1e-9]}, 1e-9)
    band = next(name for bound, name in SEVERITY if multiple <= bound)
    assert comp.verdict == DISAGREE and comp.severity == band
    assert comp.worst_ratio == pytest.approx(multiple)


def test_bands_are_ordered_and_nan_is_gross():
    bounds = [bound for bound, _ in SEVERITY]
    assert bounds == sorted(bounds) and bounds[-1] == np.inf
    comp = compare("drift", {"a": [1.0], "b": [np.nan], "c": [1.0]}, 1e-9)
    assert comp.verdict == DISAGREE and comp.severity == "gross" and np.isnan(comp.worst_ratio)
    assert severity(float("nan")) == "gross"


def test_an_agreement_has_no_severity():
    comp = compare("drift", {"a": [1.0], "b": [1.0 + 1e-12]}, 1e-9)
    assert comp.verdict == AGREE and comp.severity is None


# ------------------------------------------------------------------------------------------ vote, suspects


def test_the_vote_names_an_outlier_or_says_why_not():
    outlier = compare("drift", {"a": [1.0], "b": [1.0], "c": [2.0]}, 1e-9)
    assert outlier.outlier == "c" and suspect(outlier) == "c" and vote(outlier) == "outlier c"

    two = compare("drift", {"a": [1.0], "b": [2.0]}, 1e-9)
    assert two.outlier is None and suspect(two) is None
    assert vote(two).startswith("only two voters (a, b)")

    split = compare("drift", {"a": [1.0], "b": [1.0], "c": [2.0], "d": [2.0]}, 1e-9)
    assert split.outlier is None and suspect(split) is None
    assert vote(split).startswith("split vote: no single backend explains it among 4 voters")
    assert "a/c" in vote(split) and "a/b" not in vote(split)

    law = compare("wrenches_space", {"screw (Ad-mapped)": [1.0], "screw@g1": [2.0]}, 1e-9)
    assert suspect(law) == "screw" and vote(law).startswith("one backend only (screw)")

    exact = compare("power_constr", {"a": [1.0], "b": [1.0], "exact": 0.0}, 1e-9)
    assert exact.outlier == "exact" and "against the exact value" in vote(exact)


def test_suspects_tally_the_disagreements():
    comps = [compare("x", {"a": [1.0], "b": [1.0], "c": [2.0]}, 1e-9),
             compare("y", {"a": [1.0], "b": [1.0], "c": [3.0]}, 1e-9),
             compare("z", {"a": [1.0], "b": [2.0]}, 1e-9),
             compare("w", {"a": [1.0], "b": [1.0], "c": [2.0], "d": [2.0]}, 1e-9),
             compare("v", {"a": [1.0], "b": [1.0]}, 1e-9)]
    found = suspects(comps)
    assert found.by_backend == {"c": 2} and found.undecided == 1 and found.split == 1


# -------------------------------------------------------------------------------------------- the hints


def _rebuilt(model, **change):
    parts = dict(gravity=model.gravity, input_map=model.input_map, task_points=model.task_points,
                 constraints=model.constraints)
    return cases.build_model(model.name, model.bodies, **{**parts, **change})


def _with_newton_euler(split):
    return [b if b.name != "newton_euler" else Formalism("newton_euler", "faulty", split) for b in ALL]


def _hints(chosen, case="double_pendulum", samples=4, checks=QUICK):
    result = run_gate([CaseSpec(case)], chosen, samples, 0, checks=checks)
    assert diagnosis.annotate(result, chosen) == sum(s.failed for s in result.cases[0].states)
    return result, [s.hint for s in result.cases[0].states if s.failed]


def test_dropped_coriolis_hints_velocity_products(dropped_coriolis):
    result, hints = _hints(ALL)
    assert len(hints) == 3           # state #0 is home (theta2 = 0), where C qd = 0 and the fault hides
    for hint in hints:
        assert hint.startswith("euler_lagrange's drift error x4 when qd doubles, 0 at qd = 0")
        assert hint.endswith(diagnosis.VELOCITY)
    report = render(result, "test")
    assert f"- hint: {hints[0]}" in report and "- suspects: euler_lagrange in 3 quantities and 0 checks" in report


def _flipped_gravity(model, q, qd, u):
    return ne.split(_rebuilt(model, gravity=-model.gravity), q, qd, u)


def _failing(state):
    return {q for q, c in state.comparisons.items() if c.verdict == DISAGREE}


def test_flipped_gravity_hints_gravity():
    """Where the drift fails, the joint loads that follow from it fail too, and the accelerations classify."""
    result = _hints(_with_newton_euler(_flipped_gravity))[0]
    moving = [s for s in result.cases[0].states if "drift" in _failing(s)]
    assert len(moving) == 3          # state #0 is home (q = 0, hanging): gravity has no joint torque there
    for state in moving:
        assert "joint_wrenches" in _failing(state)
        assert state.hint == ("newton_euler's drift error x1 when qd doubles, x1 at qd = 0, 0 without gravity: "
                              f"{diagnosis.GRAVITY}")


def test_a_fault_seen_only_in_the_joint_loads_hints_the_load_bookkeeping():
    """At home (q = 0, hanging) gravity exerts no joint torque, so flipping it leaves the drift as it is, but it
    flips the weight each joint carries (article 6.1.5)."""
    result = _hints(_with_newton_euler(_flipped_gravity))[0]
    home = result.cases[0].states[0]
    assert home.failed and _failing(home) == {"joint_wrenches", "joint_wrenches_drift"}
    assert home.hint == ("only in joint_wrenches, joint_wrenches_drift (the accelerations agree): "
                         f"{diagnosis.LOADS}")


def test_scaled_mass_matrix_hints_inertia(monkeypatch):
    correct = ne._mass_matrix
    monkeypatch.setattr(ne, "_mass_matrix", lambda model, kin, units: 1.5 * correct(model, kin, units))
    hints = _hints(ALL)[1]
    assert len(hints) == 4
    for hint in hints:
        assert "and ctrl both off; newton_euler's ctrl error x1 when qd doubles, x1 without gravity" in hint
        assert f"newton_euler's ctrl is {1 / 1.5:.3g} times the others'" in hint
        assert hint.endswith("(M is what drift and ctrl share)") or hint.endswith(
            "(M is what kinetic energy and ctrl share)")   # home: drift = 0 for everyone, the energy shows M
        assert diagnosis.INERTIA in hint


def test_scaled_input_map_hints_the_input_map():
    result, hints = _hints(_with_newton_euler(lambda model, q, qd, u: ne.split(
        _rebuilt(model, input_map=2 * model.input_map), q, qd, u)))
    assert len(hints) == 4
    assert all("joint_wrenches" in _failing(s) for s in result.cases[0].states)   # the loads follow from the ctrl
    for hint in hints:
        assert hint.startswith("only in ctrl (ctrl, total, power_ctrl; drift agrees)")
        assert "total error 0 at u = 0" in hint and "newton_euler's ctrl is 2 times the others'" in hint
        assert hint.endswith("the input map B or M^-1 B u")


def test_multiplier_sign_slip_hints_a_constrained_convention(monkeypatch):
    correct = osc.constrained_split

    def flipped(model, *, lam, lam_drift, **rest):
        return correct(model, lam=-np.asarray(lam), lam_drift=-np.asarray(lam_drift), **rest)

    monkeypatch.setattr(osc, "constrained_split", flipped)
    hints = _hints(ALL, "double_pendulum_circle", samples=3)[1]
    assert len(hints) == 3
    for hint in hints:
        assert hint.startswith("only in constrained quantities (lam, lam_drift")
        assert "operational_space's lam is -1 times the others'" in hint


def test_a_chart_map_fault_hints_the_chart_map(monkeypatch):
    monkeypatch.setattr(charts.NonlinearChart, "jacobian_rate", lambda self, p, pd: np.zeros(len(pd)))
    hints = _hints(ALL, samples=3, checks=Checks(frames=0, conservation=False))[1]
    assert hints and all(h.startswith("only in a chart or frame check (chart nonlinear: ") for h in hints)
    assert all("pointing at the chart map nonlinear (shared code) — every backend moves together: " in h
               and h.endswith("the chart map (Dpsi, its rate, the covector map Dpsi^T), not a backend") for h in hints)


def test_without_gravity_removes_exactly_the_gravity_part_of_the_drift():
    """drift = -M^-1 (C qd + g) (eq. 10): without gravity it loses -M^-1 g, the drift at qd = 0; ctrl is unchanged."""
    model = cases.load("double_pendulum")
    bare = diagnosis.without_gravity(model)
    assert not bare.gravity.any() and bare.n == model.n
    reference = backends.get("pinocchio")
    q, qd, u = [0.4, -1.1], [1.5, -0.7], [2.0, 1.0]
    full, at_rest, without = (reference.split(model, q, qd, u), reference.split(model, q, [0.0, 0.0], u),
                              reference.split(bare, q, qd, u))
    np.testing.assert_allclose(without.drift, full.drift - at_rest.drift, atol=1e-12)
    np.testing.assert_allclose(without.ctrl, full.ctrl, rtol=1e-12)
    assert np.abs(at_rest.drift).max() > 1.0


def test_the_report_says_when_two_voters_leave_no_vote(dropped_coriolis):
    chosen = [backends.get("euler_lagrange"), backends.get("pinocchio")]
    result = run_gate([CaseSpec("double_pendulum")], chosen, 3, 0, checks=QUICK)
    diagnosis.annotate(result, chosen)
    report = render(result, "test")
    assert "| double_pendulum | no vote (two voters only) | 6 | 0 | 2 |" in report   # drift, total, drift_velocity
    assert "; only two voters (euler_lagrange, pinocchio): no vote, either may be wrong" in report
    assert "- hint: the voters' spread in drift error x4 when qd doubles, 0 at qd = 0" in report


def test_an_exact_match_agrees_even_when_the_tolerance_underflows_to_zero():
    """At a state at rest (qd = 0) a tolerance made of velocity terms can be exactly 0: 0 / 0 must not be a NaN
    DISAGREE (fuzz finding: one revolute body at q = qd = u = 0), while any difference still fails."""
    assert compare("dE/dt", {"a": 0.0, "b": 0.0, "exact": 0.0}, 0.0).verdict == AGREE
    off = compare("dE/dt", {"a": 0.0, "b": 5e-324, "exact": 0.0}, 0.0)
    assert off.verdict == DISAGREE and off.worst_ratio == np.inf


def test_an_overflowed_answer_fails_the_conservation_checks_instead_of_crashing_them():
    """A trusted split with inf accelerations (the operational-space backend on a task Jacobian of size 1e-135 was
    one) must give a failing comparison; the energy rate of a non-finite acceleration is not computable."""
    import dataclasses
    from crosscheck.checks import conservation
    from crosscheck.core.sampling import State

    model = cases.load("double_pendulum")
    state = State(0, (0.3, 0.2), (1.0, -1.0), (0.5, 0.5))
    good = backends.get("newton_euler").split(model, state.q, state.qd, state.u)
    broken = dataclasses.replace(good, drift=np.array([np.inf, 0.0]), total=np.array([np.inf, 0.0]))
    out = conservation.checks(model, state, {"newton_euler": good, "screw": broken})
    rate = out["conservation: energy rate at drift"]
    assert rate.verdict == DISAGREE and rate.outlier == "screw" and np.isnan(rate.values["screw"]).all()
