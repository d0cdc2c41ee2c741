"""The per-backend closeness table (``crosscheck.reports.gate_closeness``): each backend's own error/tolerance
(``crosscheck.core.compare.Comparison.closeness``), per family, in every gate report; a backend with an injected
small error stands out in its own row, the others keep their own (smaller) figures."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from crosscheck import backends
from crosscheck.core.compare import compare
from crosscheck.engine.run import run_gate
from crosscheck.engine.specs import CaseSpec, Checks
from crosscheck.faults.injection import patched
from crosscheck.reports import gate_closeness
from crosscheck.reports.gate_summary import render, summary

ARM = str(Path(__file__).resolve().parents[2] / "examples" / "arm.urdf")
ALL = [backends.get(name) for name in backends.builtin_names()]
QUICK = Checks(charts=False, frames=0, conservation=False, closed_forms=False, self_test=False, linearization=False)


def _rows(report: str) -> dict[str, dict[str, str]]:
    """The summary's closeness table as {backend: {column: cell}}."""
    section = report.split("## How close each backend came\n", 1)[1]
    table = section.split("\n\n")[1].splitlines()
    header = [c.strip() for c in table[0].strip("|").split("|")]
    rows = [[c.strip() for c in line.strip("|").split("|")] for line in table[2:]]
    return {row[0]: dict(zip(header[1:], row[1:])) for row in rows}


def _figure(cell: str) -> float:
    return float(cell.strip("*"))


def test_closeness_is_each_voters_lower_median_distance_from_the_others_or_its_distance_from_the_exact_value():
    comp = compare("drift", {"a": [1.0, 2.0], "b": [1.0, 2.0 + 3e-9], "c": [1.0, 2.0], "d": [1.0 - 1e-9, 2.0],
                             "e": [1.0, 2.0]}, 1e-9)
    # pairs: b is 3 from a, c, d and e; d is 1 from a, c, e; a, c, e agree exactly
    assert comp.closeness() == pytest.approx({"a": 0.0, "b": 3.0, "c": 0.0, "d": 1.0, "e": 0.0})
    exact = compare("power_constr", {"a": 2e-9, "b": 0.0, "exact": 0.0}, 1e-9)
    assert exact.closeness() == pytest.approx({"a": 2.0, "b": 0.0})        # against the exact value, not the others
    nan = compare("drift", {"a": [1.0], "b": [np.nan], "c": [1.0 + 1e-9]}, 1e-9)
    assert nan.closeness()["a"] == pytest.approx(1.0) and np.isnan(nan.closeness()["b"])


def test_every_gate_report_has_the_table_with_a_row_per_backend():
    result = run_gate([CaseSpec("arm", path=ARM)], ALL, 50, 0, checks=Checks(self_test=False))
    assert result.passed
    report = summary(result, "test")
    rows = _rows(report)
    assert list(rows) == [b.name for b in ALL]
    assert {"drift, ctrl, total", "energy, power", "charts", "frames", "conservation", "linearization"} <= set(
        rows["pinocchio"])
    assert rows["euler_lagrange"]["task"] == "not supplied"                  # declares the task quantities unsupported
    assert rows["operational_space"]["left out"] == "BREAKDOWN at 1 state"   # near the arm's singular configurations
    for backend, row in rows.items():
        assert all(_figure(cell) < 1.0 for cell in row.values() if cell[0].isdigit() or cell[:3] == "**0"), backend
    assert "## How close each backend came, per case" not in render(result, "test")   # one case: the summary's


def test_a_backend_with_a_small_error_has_the_largest_figures_and_the_others_keep_their_own():
    """Newton–Euler's mass matrix off by a relative 1e-11 (the fault-injection hook): its accelerations and energy are
    out of tolerance, the table says so in its row alone; the other backends' figures are their own, not the pair's
    they share with it."""
    with patched("ne-mass-matrix-rounded", "formalisms.newton_euler:_mass_matrix",
                 lambda original: lambda model, kin, units: (1 + 1e-11) * original(model, kin, units)):
        result = run_gate([CaseSpec("double_pendulum"), CaseSpec("arm", path=ARM)], ALL, 10, 0, checks=QUICK)
    assert not result.passed
    rows = _rows(summary(result, "test"))
    column = {backend: _figure(row["drift, ctrl, total"]) for backend, row in rows.items()}
    assert max(column, key=column.get) == "newton_euler" and column["newton_euler"] > 1.0
    assert all(figure < 1.0 for backend, figure in column.items() if backend != "newton_euler"), column
    assert rows["newton_euler"]["worst at"].split()[0] in ("double_pendulum", "arm")
    details = render(result, "test")
    assert "### double_pendulum" in details.split("## How close each backend came, per case")[1]


def test_a_family_column_appears_only_where_it_was_compared():
    result = run_gate([CaseSpec("double_pendulum")], ALL, 3, 0, checks=QUICK)
    columns = set(_rows(summary(result, "test"))["pinocchio"])
    assert "charts" not in columns and "lam" not in columns and "drift, ctrl, total" in columns
    assert gate_closeness.family_of("chart affine: drift") == "charts"
    assert gate_closeness.family_of("frame law: screw wrenches_space") == "frames"
    assert gate_closeness.family_of("equilibrium hanging: eigenvalues of A") == "linearization"
