"""The gate on constrained cases (article 5): every backend agrees at admissible states, degenerate states are
BREAKDOWN rather than failures, the report shows the power audit, and injected constraint faults are caught and
named."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

import cases
import formalisms.euler_lagrange as el
import formalisms.operational_space as osc
from cases import Body, PointOnLine, PointsCoincide, build_model
from crosscheck import backends
from crosscheck.core import sampling
from crosscheck.core.compare import AGREE, DISAGREE
from crosscheck.engine.specs import CaseSpec, Checks
from crosscheck.engine.evaluation import evaluate
from crosscheck.engine.run import run_case, run_gate
from crosscheck.reports.gate_summary import render
from crosscheck.core.sampling import State
from crosscheck.core.tolerance import CONSTRAINED_QUANTITIES

CONSTRAINED = ["double_pendulum_circle", "four_bar", "slider_crank", "cartesian_pendulum",
               "double_pendulum_absolute_loop"]
ALL = [backends.get(name) for name in backends.names()]


def _failures(outcome) -> list[str]:
    """One line per disagreement or error of a case outcome, for assertion messages."""
    lines = []
    for state in outcome.states:
        lines += [f"#{state.state.index} {name} raised {message}" for name, message in state.errors.items()]
        lines += [f"#{state.state.index} {key}: {c.worst_ratio:.3g} outlier {c.outlier}"
                  for key, c in {**state.comparisons, **state.checks}.items() if c.verdict == DISAGREE]
    return lines


def _verdicts(outcome, quantity: str) -> list[str]:
    return [s.comparisons[quantity].verdict for s in outcome.states if quantity in s.comparisons]


@pytest.mark.parametrize("case", CONSTRAINED)
def test_every_backend_agrees_on_every_constrained_quantity_and_check(case):
    outcome = run_case(CaseSpec(case), ALL, 12, 0)
    assert not outcome.failed, "\n".join(_failures(outcome)[:20])
    for quantity in CONSTRAINED_QUANTITIES:
        assert _verdicts(outcome, quantity).count(AGREE) >= 11, quantity     # compared, not skipped
    for state in outcome.states:
        assert set(state.trusted) - {"closed_form"} == {b.name for b in ALL}   # and the case's closed form, if any


def test_the_report_shows_the_constraint_power_audit():
    result = run_gate([CaseSpec("double_pendulum_circle")], ALL, 6, 0, checks=Checks(charts=False, frames=0))
    text = render(result, "crosscheck gate --case double_pendulum_circle")
    assert "## Constraint power audit (article 5.5)" in text
    row = next(line for line in text.splitlines() if line.startswith("| double_pendulum_circle | 6 |"))
    cells = [c.strip() for c in row.split("|")]
    assert float(cells[3]) < 1e-9 and float(cells[4]) > 0.0       # no net work, but energy moved between joints
    assert "| double_pendulum_circle | 2 | lam |" in text


# ------------------------------------------------------------------------------------- degenerate constraints


def _duplicated(case: str):
    model = cases.load(case)
    again = [dataclasses.replace(c, name=c.name + "_again") for c in model.constraints]
    return build_model(case + "_twice", model.bodies, gravity=model.gravity, input_map=model.input_map,
                       task_points=model.task_points, constraints=list(model.constraints) + again)


@pytest.mark.parametrize("case", ["double_pendulum_circle", "slider_crank"])
def test_a_duplicated_constraint_is_a_multiplier_breakdown_not_a_failure(case):
    model = _duplicated(case)
    for state in sampling.sample_states(model, 5, 2, case):
        outcome = evaluate(model, state, ALL)
        assert not outcome.failed, _failures(type("o", (), {"states": [outcome]})())
        assert set(outcome.breakdowns) == {b.name for b in ALL}
        assert all(set(b) == {"constraint"} for b in outcome.breakdowns.values())
        assert outcome.comparisons["lam"].verdict != AGREE              # non-unique: not compared
        for quantity in ("total", "drift", "ctrl", "constraint_force", "constraint_force_drift", "power_constr"):
            assert outcome.comparisons[quantity].verdict == AGREE, quantity
            assert len(outcome.comparisons[quantity].pairs) >= 15, quantity   # all six backends voted


def test_the_four_bar_at_its_change_point_is_breakdown_on_either_velocity_never_a_crash():
    model = cases.load("four_bar")
    q = (np.pi / 2, 0.0, np.pi / 2)                     # all links collinear: the loop Jacobian has rank 1
    consistent = State(0, q, (1.0, -1.0, 1.0), (0.5, -0.3, 0.2))     # along the parallelogram branch
    off_branch = State(1, q, (0.0, 1.0, 2.0), (0.5, -0.3, 0.2))      # admissible, but H_t is empty
    a = evaluate(model, consistent, ALL)
    assert not a.errors and not a.failed
    assert all("constraint" in b for b in a.breakdowns.values())
    assert a.comparisons["total"].verdict == AGREE and a.comparisons["constraint_force"].verdict == AGREE
    b = evaluate(model, off_branch, ALL)
    assert not b.errors and not b.failed
    assert all(b.breakdowns[name].get("constraint_consistency", 0.0) > 1e-8 for name in b.breakdowns)
    assert not b.trusted                                 # every backend's whole answer is untrusted there


@pytest.mark.parametrize("offset", [1e-3, 3e-5, 1e-6])
def test_the_four_bar_near_its_change_point_agrees_or_is_flagged_before_it_goes_wrong(offset):
    """Nearly redundant rows: every backend keeps the direction S keeps (the same convention, also in the geometric
    backend's tangent-space method and in the reference), so the answers agree; past cond 1e8 the state is flagged."""
    model = cases.load("four_bar")
    q = sampling.project_configuration(model, [np.pi / 2 + offset, 0.0, np.pi / 2 + offset])
    qd = sampling.project_velocity(model, q, [0.3, 1.0, 2.0])
    outcome = evaluate(model, State(0, tuple(q), tuple(qd), (0.5, -0.3, 0.2)), ALL)
    assert not outcome.errors and not outcome.failed
    totals = np.array([split.total for split in outcome.splits.values()])
    assert np.ptp(totals, axis=0).max() < 1e-8 * (1.0 + np.abs(totals).max())
    whole = {"constraint_kept", "constraint_consistency"}
    flagged = {name for name, b in outcome.breakdowns.items() if b.keys() & whole}
    assert flagged == (set(outcome.splits) if offset < 1e-4 else set())   # near: nearly redundant, or H_t empty


# -------------------------------------------------------------------------------------------- injected faults


def _caught(case: str, quantity: str, samples: int = 6) -> dict[str, object]:
    """Run the gate on ``case`` and return, for the states where ``quantity`` disagreed, its outliers."""
    outcome = run_case(CaseSpec(case), ALL, samples, 0, checks=Checks(charts=False, frames=0, conservation=False))
    return {s.state.index: s.comparisons[quantity].outlier for s in outcome.states
            if s.comparisons[quantity].verdict == DISAGREE}


def test_fault_multiplier_sign_flipped_in_one_backend_is_caught_and_named(monkeypatch):
    correct = osc.constrained_split

    def flipped(model, *, lam, lam_drift, **rest):     # the backend's convention: M qdd + h = B u - Jc^T lam
        return correct(model, lam=-np.asarray(lam), lam_drift=-np.asarray(lam_drift), **rest)

    monkeypatch.setattr(osc, "constrained_split", flipped)
    found = _caught("double_pendulum_circle", "lam")
    assert len(found) == 6 and set(found.values()) == {"operational_space"}


def test_fault_dropped_jcdot_qd_is_caught_and_named(monkeypatch):
    correct = el.evaluate

    def dropped(model, x, xd, chart=None):
        terms, cons = correct(model, x, xd, chart)
        return terms, cons._replace(bias=np.zeros_like(cons.bias))

    monkeypatch.setattr(el, "evaluate", dropped)
    for quantity in ("drift", "total", "constraint_bias"):
        found = _caught("double_pendulum_circle", quantity)
        assert len(found) >= 5 and set(found.values()) == {"euler_lagrange"}, quantity


def test_fault_constraint_input_map_with_m_instead_of_its_inverse_is_caught_and_named(monkeypatch):
    def with_m(sc):                                     # B_c = M [I - Jc^T (Jc M Jc^T)^+ Jc M]
        M, Jc = sc.U.T @ sc.U, sc.A @ sc.U
        return M - M @ Jc.T @ np.linalg.pinv(Jc @ M @ Jc.T) @ Jc @ M

    monkeypatch.setattr(el, "_constrained_input_map", with_m)
    found = _caught("slider_crank", "ctrl")
    assert len(found) == 6 and set(found.values()) == {"euler_lagrange"}
    assert len(_caught("slider_crank", "additivity")) == 6


def test_fault_inadmissible_sampled_velocity_is_caught_by_the_admissibility_and_power_checks(monkeypatch):
    monkeypatch.setattr(sampling, "project_velocity", lambda model, q, qd: np.asarray(qd, dtype=float))
    for quantity in ("constraint_velocity", "power_constr"):
        found = _caught("double_pendulum_circle", quantity)
        assert len(found) >= 5 and set(found.values()) == {"exact"}, quantity


def test_a_constraint_row_that_vanishes_identically_is_dropped_by_every_backend():
    """A point on the joint axes held on a line through it: phi = 0 and Jc = 0 at every configuration. Some
    kinematics give exact zeros, others rounding (1e-17); relative to itself a lone rounding row once looked like a
    direction, and Newton–Euler applied a 19.6 N constraint force (a fuzz finding). Below the degenerate floor
    (``interface.DEGENERATE_ROW``) every backend drops it: unconstrained motion, lam = 0."""
    z = (0.0, 0.0, 1.0)
    inertia = np.diag([0.25, 0.25, 0.025])
    model = build_model("vacuous_line", [
        Body("b0", None, "revolute", z, 1.0, inertia=inertia),
        Body("b1", "b0", "prismatic", z, 1.0, com=(0.3, 0, 0)),
        Body("b2", "b1", "revolute", (1.0, 0.0, 0.0), 1.0, inertia=inertia,
             rotation=[[0, -1, 0], [1, 0, 0], [0, 0, 1]]),
    ], gravity=(0, 0, -9.81), constraints=[PointOnLine("line", "b2", (0, 0, 0), (0, 0, 0), [[1.0, 0.0, 0.0]])])
    chosen = [backends.get(name) for name in backends.names()]
    for q in ([0.0, 0.0, 1.0], [0.4, -0.2, 2.0]):
        outcome = evaluate(model, State(0, tuple(q), (0.5, 1.0, -2.0), (1.0, 2.0, 3.0)), chosen)
        assert not outcome.failed, {k: c.worst_ratio for k, c in outcome.comparisons.items()}
        trusted = outcome.trusted           # the five backends and Pinocchio: the default task point is off the axes
        assert len(trusted) == 6 and all(s.constraint_rank == 0 and np.all(s.lam == 0.0) for s in trusted.values())


def test_multipliers_of_a_short_constraint_row_carry_its_rounding():
    """A fuzz finding: a point 5.3e-5 m off a joint axis pinned in x. Its Jc row is a difference of lever-sized terms,
    so it rounds at eps L however short it is, and lam = -1.4e5 inherits that relative error (2000 eps); a tolerance
    from lam_scale alone put correct backends 1.6 times over (``tolerance._lam_rounding``)."""
    model = build_model("short_row", [
        Body("b0", None, "revolute", (0, 1, 0), 1.0, inertia=np.diag([0.00625, 0.0625, 0.06875]),
             translation=(0, 0, 1)),
        Body("b1", "b0", "revolute", (0, 0, 1), 1.0, com=(0, 0, 0.5), inertia=np.diag([0.25, 0.0625, 0.1875]))],
        constraints=[PointsCoincide("c0", "b0", (0, 0, 5.319490610664871e-05), None,
                                    (4.476197002832528e-05, 0, 1.0000287413304298), [[1.0, 0.0, 0.0]])])
    outcome = evaluate(model, State(0, (1.0, 0.0), (0.0, 0.0), (0.0, 0.0)), [backends.get(n) for n in backends.names()])
    assert abs(outcome.splits["pinocchio"].lam[0]) > 1e5
    assert outcome.comparisons["lam"].verdict == AGREE and not outcome.failed



def test_chart_accelerations_near_a_tangent_circle_row_carry_the_multipliers_rounding():
    """A fuzz finding: a slider tangent to its circle (Jc = 1.8e-8 at q1 = 0.27496420006). The multipliers inherit the
    short row's relative rounding, and through Jc^T lam so do the accelerations; in the nonlinear chart the
    chart-native backends (their own phi(psi(p))) once differed from the mapped joint answers at 3.6 times the
    tolerance."""
    from cases import PointOnCircle
    from crosscheck.checks import charts, invariance

    model = build_model("tangent_slider", [
        Body("b0", None, "prismatic", (1, 0, 0), 1.0, rotation=[[0, 0, 1], [0, 1, 0], [-1, 0, 0]],
             translation=(1, 0, 0)),
        Body("b1", "b0", "revolute", (0, 0, 1), 10.0,
             inertia=np.diag([1.8977951719320398, 0.647241581311425, 1.250553590620615]))],
        input_map=[[1.0], [0.0]],
        constraints=[PointOnCircle("c0", "b0", (0, 0, 0), (0, 0, -0.27496420908501107), 1.0, [[1, 0, 0], [0, 0, -1]])])
    chosen = [backends.get(n) for n in backends.names()]
    state = State(0, (0.2749642000557799, 1.0), (0.0, 2.0), (0.0,))
    outcome = evaluate(model, state, chosen)
    checks = invariance.chart_checks(model, state, charts.get("nonlinear", model), outcome.trusted, chosen, {})
    assert not outcome.failed and all(c.verdict != DISAGREE for c in checks.values())
    assert checks["chart nonlinear: drift"].verdict == AGREE
