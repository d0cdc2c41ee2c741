"""How close each backend came, per family of quantities and checks: the gate report's per-backend table.

A cell is the backend's worst figure (``crosscheck.core.compare.Comparison.closeness``: its error/tolerance against the
exact value where there is one, else the lower median of its error/tolerance against each other voter) over every
comparison of the family at every state of the cases, the voters of a backend in charts and moved scenes
(``screw@affine``, ``screw@g1``) counting as the backend. Where it has no figure the cell says why: the backend declared
the quantities unsupported, was in BREAKDOWN or raised wherever they were compared. The summary has one table over the
run (:func:`closeness_section`), the details one per case when there are several (:func:`case_closeness_section`).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Sequence

from crosscheck.core.compare import NOT_COMPARED, Comparison, backend_of
from crosscheck.engine.outcomes import CaseOutcome, GateResult, StateOutcome

#: The table's columns: (family, the compared quantities in it). Checks go by the start of their key
#: (:func:`family_of`).
QUANTITY_FAMILIES: tuple[tuple[str, tuple[str, ...]], ...] = (
    ("drift, ctrl, total", ("drift", "ctrl", "total", "additivity", "zvcf", "drift_velocity", "drift_parts")),
    ("energy, power", ("kinetic_energy", "power_ctrl", "power_ext", "power_constr", "power_constr_per_coord")),
    ("task", ("task_drift", "task_inertia")),
    ("joint loads", ("joint_wrenches", "joint_wrenches_drift", "external_force")),
    ("lam", ("lam", "lam_drift", "constraint_force", "constraint_force_drift")),
    ("constraint rows", ("admissibility_drift", "admissibility_total", "constraint_value", "constraint_velocity",
                         "constraint_jacobian", "constraint_bias")),
)
#: The check families, in column order after the quantities': (family, the start of the check's key).
CHECK_FAMILIES: tuple[tuple[str, tuple[str, ...]], ...] = (
    ("linearization", ("linearization", "equilibrium")),
    ("charts", ("chart ",)),
    ("frames", ("frame",)),
    ("conservation", ("conservation",)),
    ("conditions", ("conditions",)),
)
COLUMNS = tuple(name for name, _ in (*QUANTITY_FAMILIES, *CHECK_FAMILIES))
_OF_QUANTITY = {quantity: name for name, quantities in QUANTITY_FAMILIES for quantity in quantities}


def family_of(key: str) -> str:
    """The column of a comparison (its quantity) or of a check (its key); "other" for one no family holds."""
    if key in _OF_QUANTITY:
        return _OF_QUANTITY[key]
    return next((name for name, starts in CHECK_FAMILIES if key.startswith(starts)), "other")


class _Cell:
    """One backend in one family: its worst ratio and where, and the states where it was left out and why."""

    def __init__(self):
        self.worst, self.where = None, ("", "")
        self.not_supplied: set[tuple[str, int]] = set()
        self.breakdown: set[tuple[str, int]] = set()
        self.raised: set[tuple[str, int]] = set()

    def add(self, ratio: float, where: tuple[str, str]) -> None:
        nan_now, nan_before = ratio != ratio, self.worst is not None and self.worst != self.worst
        if self.worst is None or (nan_now and not nan_before) or (not nan_before and ratio > self.worst):
            self.worst, self.where = ratio, where

    def text(self) -> str:
        """The figure (bold above 1); without one, why: not supplied, else BREAKDOWN or raised; "-" when the backend
        took no part."""
        if self.worst is not None:
            figure = "NaN" if self.worst != self.worst else f"{self.worst:.3g}"
            return f"**{figure}**" if not self.worst <= 1.0 else figure
        if self.not_supplied:
            return "not supplied"
        return ", ".join(label for label, found in (("BREAKDOWN", self.breakdown), ("raised", self.raised))
                         if found) or "-"


def _left_out(cell: _Cell, backend: str, case: CaseOutcome, state: StateOutcome, key: str,
              comp: Comparison) -> None:
    """Note why ``backend`` has no figure in the comparison or check ``key``: declared unsupported, in BREAKDOWN
    (for the quantity, or wholly for a check), raised (in the joint chart, a chart, a moved scene, its
    linearization)."""
    at = (case.spec.name, state.state.index)
    trusted = state.voters(key) if key in state.comparisons else state.trusted
    if backend in comp.not_compared:
        cell.not_supplied.add(at)
    elif backend in state.splits and backend not in trusted:
        cell.breakdown.add(at)
    elif any(backend_of(name.split(" (")[0]) == backend for name in state.errors):
        cell.raised.add(at)


def _case_cells(case: CaseOutcome, rows: Sequence[str]) -> dict[tuple[str, str], _Cell]:
    """(backend, family) -> its cell over the case. A backend's figure in a comparison is at most the comparison's
    worst ratio, so the figures (``Comparison.closeness``) are computed only where one could raise a cell."""
    cells: dict[tuple[str, str], _Cell] = {}
    for state in case.states:
        for key, comp in (*state.comparisons.items(), *state.checks.items()):
            if comp.verdict == NOT_COMPARED and not comp.not_compared:
                continue
            family = family_of(key)
            row = [cells.setdefault((backend, family), _Cell()) for backend in rows]
            voted = {backend_of(voter) for voter in comp.voters}
            mine: dict[str, float] = {}
            if any(not (cell.worst is not None and cell.worst >= comp.worst_ratio)
                   for backend, cell in zip(rows, row) if backend in voted):
                for voter, ratio in comp.closeness().items():
                    backend = backend_of(voter)
                    best = mine.get(backend)
                    if best is None or ratio != ratio or (best == best and ratio > best):
                        mine[backend] = ratio
            for backend, cell in zip(rows, row):
                if backend in mine:
                    cell.add(mine[backend], (case.spec.name, f"{key} #{state.state.index}"))
                elif backend not in voted and (voted or comp.not_compared):
                    _left_out(cell, backend, case, state, key, comp)
    return cells


def _merged(per_case: Sequence[dict[tuple[str, str], _Cell]]) -> dict[tuple[str, str], _Cell]:
    """The cells of several cases as one: the worst figure and where, the union of the states left out."""
    out: dict[tuple[str, str], _Cell] = {}
    for cells in per_case:
        for key, cell in cells.items():
            merged = out.setdefault(key, _Cell())
            if cell.worst is not None:
                merged.add(cell.worst, cell.where)
            merged.not_supplied |= cell.not_supplied
            merged.breakdown |= cell.breakdown
            merged.raised |= cell.raised
    return out


@dataclass(frozen=True)
class Closeness:
    """The table's cells for a run: the rows (backends) and each case's cells, computed once for the summary and the
    details (:func:`of`)."""

    rows: tuple[str, ...]
    per_case: tuple[dict[tuple[str, str], _Cell], ...]


def of(result: GateResult) -> Closeness:
    """The cells of every case of ``result``."""
    rows = tuple(_rows(result.cases, result.backends))
    return Closeness(rows, tuple(_case_cells(case, rows) for case in result.cases))


def _rows(cases: Sequence[CaseOutcome], backends: Sequence[str]) -> list[str]:
    """The run's backends, then the case's closed form where it votes (on the quantities, at every state)."""
    voting = any("closed_form" in pair for case in cases for state in case.states[:1]
                 for comp in state.comparisons.values() for pair in comp.pairs)
    return [*backends, *(["closed_form"] if voting else [])]


def closeness_table(rows: Sequence[str], cells: dict[tuple[str, str], _Cell], where_case: bool = True) -> list[str]:
    """The markdown table: a row per backend, a column per family with a figure (:data:`COLUMNS`), and the place of
    the row's worst figure (case if ``where_case``, quantity or check, state); [] when nothing was compared."""
    columns = [c for c in (*COLUMNS, "other") if any(cells.get((b, c)) and cells[(b, c)].worst is not None
                                                    for b in rows)]
    if not columns:
        return []
    lines = ["| backend | " + " | ".join(columns) + " | worst at | left out |", "|---" * (len(columns) + 3) + "|"]
    for backend in rows:
        row = [cells.get((backend, c), _Cell()) for c in columns]
        figures = [cell for cell in row if cell.worst is not None]
        worst = max(figures, key=lambda cell: float("inf") if cell.worst != cell.worst else cell.worst, default=None)
        where = "-" if worst is None else (" ".join(worst.where) if where_case else worst.where[1])
        lines.append(f"| {backend} | " + " | ".join(cell.text() for cell in row) + f" | {where} | "
                     f"{_left_out_text(row)} |")
    return lines


def _left_out_text(row: Sequence[_Cell]) -> str:
    """The states where a backend was left out of some comparison by a BREAKDOWN, or raised."""
    broken = set().union(*(cell.breakdown for cell in row))
    raised = set().union(*(cell.raised for cell in row))
    parts = [f"{label} at {len(found)} state{'s' if len(found) > 1 else ''}"
             for label, found in (("BREAKDOWN", broken), ("raised", raised)) if found]
    return "; ".join(parts) or "-"


EXPLAINED = ("Each backend's error/tolerance against the exact value where there is one, else the lower median of "
             "its error/tolerance against each other voter (so one outlier does not move the others' figures), the "
             "worst over every state; below 1 is within tolerance, **bold** above. Without a figure, why: not supplied "
             "(declared unsupported), BREAKDOWN (ill-conditioned there, so left out) or raised wherever that column "
             "was compared; - where it took no part. Left out: the states where a BREAKDOWN or an error kept it out "
             "of some comparison.")


def closeness_section(result: GateResult, found: Closeness | None = None) -> list[str]:
    """The summary's table over every case of the run (``found``: :func:`of` the result, computed here if None)."""
    found = found or of(result)
    table = closeness_table(found.rows, _merged(found.per_case))
    return ["## How close each backend came", "", EXPLAINED, "", *table, ""] if table else []


def case_closeness_section(result: GateResult, found: Closeness | None = None) -> list[str]:
    """The details' tables, one per case, for a run of two or more (the summary's table is the one case's)."""
    if len(result.cases) < 2:
        return []
    found = found or of(result)
    lines = []
    for case, cells in zip(result.cases, found.per_case):
        table = closeness_table(found.rows, cells, where_case=False)
        if table:
            lines += [f"### {case.spec.name}", "", *table, ""]
    if not lines:
        return []
    return ["## How close each backend came, per case", "", EXPLAINED, "", *lines]
