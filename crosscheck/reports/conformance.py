"""The conformance report of ``crosscheck simulators``: per simulator and quantity family, agree or the finding.

A simulator's cell in a family says one of:

* ``agrees (r)``: it voted in every comparison of the family it supplies and was never the suspect of a
  disagreement; ``r`` is its worst closeness (its error/tolerance against the others, ``Comparison.closeness``);
* ``FINDING``: it is the suspect (``crosscheck.core.compare.suspect``: the outlier, or the one backend behind a
  one-backend check) of a disagreement at some states, or, where the vote names no one (two simulators wrong at
  once), it disagrees with every built-in voter while those agree with each other; the section below the table gives the size (error/tolerance),
  the state, the hint the error's shape suggests (``crosscheck.reports.diagnosis``) and the command that reproduces
  it;
* ``disagrees, not named``: a disagreement it voted in that neither rule blames on it or clears it of (read the gate
  report); one blamed on another voter, or where it agrees with every built-in voter, is not its own;
* ``not supplied``: it voted in no comparison of the family (the quantity is not computed by that library, or the
  model is NOT COMPARED: the reason is given).
"""

from __future__ import annotations

from dataclasses import dataclass, field

from crosscheck import backends
from crosscheck.core.compare import DISAGREE, NOT_BACKENDS, backend_of, Comparison, suspect, worst_of
from crosscheck.engine.outcomes import CaseOutcome, GateResult, StateOutcome
from crosscheck.reports.gate_lines import check_reproduce_command, reproduce_command

#: The report's columns: a family -> the state comparisons it holds; checks join by their key's prefix (:func:`family`).
FAMILIES = {
    "drift": ("drift", "total", "additivity", "zvcf", "drift_velocity", "drift_parts"),
    "ctrl": ("ctrl", "power_ctrl"),
    "energy": ("kinetic_energy",),
    "task space": ("task_drift", "task_inertia"),
    "joint loads": ("joint_wrenches", "joint_wrenches_drift"),
    "charts": (),
    "frames": (),
    "conservation": (),
    "linearization": (),
}
_CHECK_FAMILIES = (("chart", "charts"), ("frame", "frames"), ("conservation", "conservation"),
                   ("linearization", "linearization"))


def family(key: str, is_check: bool) -> str | None:
    """The family of a comparison key (a state comparison's quantity, or a check's key); None for what is no
    simulator's (the conditions audit)."""
    if not is_check:
        return next((name for name, keys in FAMILIES.items() if key in keys), None)
    return next((name for prefix, name in _CHECK_FAMILIES if key.startswith(prefix)), None)


@dataclass
class Finding:
    """A simulator blamed in one family: at how many states, the worst error/tolerance, where, what it suggests."""

    family: str
    states: int
    worst: float
    quantity: str
    state: StateOutcome
    hint: str
    reproduce: str


@dataclass
class Cell:
    voted: bool = False
    closeness: float = 0.0
    findings: list[tuple[StateOutcome, str, Comparison]] = field(default_factory=list)
    unnamed: list[tuple[StateOutcome, str, Comparison]] = field(default_factory=list)


def _comparisons(state: StateOutcome):
    for key, comp in state.comparisons.items():
        yield key, comp, False
    for key, comp in state.checks.items():
        yield key, comp, True


def cells(case: CaseOutcome, simulator: str) -> dict[str, Cell]:
    """The simulator's cell in each family over the case's states (module docstring)."""
    out = {name: Cell() for name in FAMILIES}
    for state in case.states:
        for key, comp, is_check in _comparisons(state):
            name = family(key, is_check)
            if name is None or simulator not in {backend_of(v) for v in comp.voters}:
                continue
            cell = out[name]
            cell.voted = True
            mine = [r for v, r in comp.closeness().items() if backend_of(v) == simulator]
            cell.closeness = worst_of([cell.closeness, *mine])
            if comp.verdict != DISAGREE:
                continue
            blamed = suspect(comp)
            if blamed is None:
                blamed = _against_builtins(comp, simulator)
            if blamed == simulator:
                cell.findings.append((state, key, comp))
            elif blamed is None:
                cell.unnamed.append((state, key, comp))
    return out


def _against_builtins(comp: Comparison, simulator: str) -> str | None:
    """Who a disagreement the vote names no one for is on, read against the built-in backends (the five formalisms,
    the reference, the exact values): the simulator when one of its voters (``pybullet@g0``: a moved scene) disagrees
    with every built-in voter it is paired with while those agree with each other (two simulators wrong at once leave
    the vote without an outlier); "" (no one of its concern) when each of its voters agrees with every built-in voter
    it is paired with; None otherwise."""
    builtin = set(backends.builtin_names()) | set(NOT_BACKENDS) | {"closed_form"}
    mine: dict[str, list[float]] = {}
    theirs = []
    for (a, b), ratio in comp.pairs.items():
        for own, other in ((a, b), (b, a)):
            if backend_of(own) == simulator and backend_of(other) in builtin:
                mine.setdefault(own, []).append(ratio)
        if backend_of(a) in builtin and backend_of(b) in builtin:
            theirs.append(ratio)
    if mine and all(r <= 1.0 for ratios in mine.values() for r in ratios):
        return ""
    if any(not any(r <= 1.0 for r in ratios) for ratios in mine.values()) and all(r <= 1.0 for r in theirs):
        return simulator
    return None


def finding(case: CaseOutcome, seed: int, name: str, cell: Cell, simulator: str) -> Finding:
    """The worst of a cell's blamed disagreements, with its reproduce command."""
    def size(found):
        ratio = found[2].worst_ratio
        return ratio if ratio == ratio else float("inf")

    worst = max(cell.findings, key=size)
    hinted = [f for f in cell.findings if simulator in f[0].hint]      # a hint on this simulator, not another's
    state, key, comp = max(hinted, key=size) if hinted else worst
    is_check = key in state.checks
    command = (check_reproduce_command(case, state, key.split(":")[0], seed) if is_check
               else reproduce_command(case, state))
    return Finding(name, len({id(s) for s, _, _ in cell.findings}), worst[2].worst_ratio, key, state,
                   state.hint if hinted else "", command)


def cell_text(cell: Cell, reason: str) -> str:
    if cell.findings:
        return f"**FINDING** ({len({id(s) for s, _, _ in cell.findings})} states)"
    if cell.unnamed:
        return f"disagrees, not named ({len(cell.unnamed)})"
    if cell.voted:
        return f"agrees ({cell.closeness:.2g})"
    return "NOT COMPARED" if reason else "not supplied"


def render(result: GateResult, model_path: str, simulators: dict[str, dict],
           gate_report: str) -> tuple[str, bool, dict[str, str]]:
    """The markdown report, whether every simulator conforms, and each simulator's verdict in one line (the
    terminal's). ``simulators``: name -> ``{"library": ..., "off": [(default, what it adds), ...], "on": [...],
    "reason": why NOT COMPARED or ""}``."""
    case = result.cases[0] if result.cases else None
    lines = [f"# Simulator conformance: `{model_path}`", ""]
    if case is None:
        return ("\n".join(lines + [f"The gate did not run a case; see [{gate_report}]({gate_report})."]) + "\n", False,
                {})
    base = case.model.source.root if case.model.source is not None else "fixed"
    lines += [f"{len(case.states)} states (seed {result.seed}), base {base}; every simulator against the five "
              "formalisms, the Pinocchio reference and each other: the gate's full report is "
              f"[{gate_report}]({gate_report}). Each cell: `agrees (worst error/tolerance)`, a **FINDING** (the "
              "simulator is the outlier: below), `not supplied` (the library does not compute it) or NOT COMPARED "
              "(the model is not supported: why, below).", ""]
    if case.model.findings:
        lines += ["Model findings: what the file says that no body can be, which tools may read differently (the "
                  "backends follow Pinocchio's reading; a simulator reading it another way disagrees here):", ""]
        lines += [f"- {finding}" for finding in case.model.findings] + [""]
    lines += ["| simulator | library | " + " | ".join(FAMILIES) + " |", "|---" * (len(FAMILIES) + 2) + "|"]
    conforms, details, verdicts = True, [], {}
    for name, info in simulators.items():
        got = cells(case, name)
        verdicts[name] = one_line(got)
        lines.append(f"| {name} | {info['library']} | "
                     + " | ".join(cell_text(c, info["reason"]) for c in got.values()) + " |")
        found = [finding(case, result.seed, fam, c, name) for fam, c in got.items() if c.findings]
        unnamed = sum(len(c.unnamed) for c in got.values())
        conforms &= not found and not unnamed
        details += _simulator_section(name, info, found, unnamed, got)
    return "\n".join(lines + [""] + details) + "\n", conforms, verdicts


def one_line(got: dict[str, Cell]) -> str:
    """A simulator's verdict in one line: its findings by family, or that it agrees."""
    blamed = [f"{fam} ({len({id(s) for s, _, _ in c.findings})} states)" for fam, c in got.items() if c.findings]
    if blamed:
        return "FINDING in " + ", ".join(blamed)
    if any(c.unnamed for c in got.values()):
        return "disagrees, not named (read the gate report)"
    if not any(c.voted for c in got.values()):
        return "NOT COMPARED"
    return f"agrees (worst error/tolerance {max(c.closeness for c in got.values() if c.voted):.3g})"


def _simulator_section(name: str, info: dict, found: list[Finding], unnamed: int, got: dict[str, Cell]) -> list[str]:
    verdict = ("NOT COMPARED: " + info["reason"] if info["reason"] else
               f"{len(found)} finding(s)" if found else
               f"disagreements not blamed on it at {unnamed} comparisons: read the gate report" if unnamed else
               "agrees wherever compared")
    out = [f"## {name}", "", f"{info['library']}: **{verdict}**.", ""]
    for f in found:
        out += [f"- **{f.family}**: outlier **{name}** at {f.states} states; worst error/tolerance {f.worst:.3g} "
                f"({f.quantity}, state #{f.state.state.index})."]
        if f.hint:
            out.append(f"  - hint: {f.hint}")
        out.append(f"  - reproduce: `{f.reproduce}`")
    supplied = [fam for fam, c in got.items() if c.voted]
    out += ["", f"Compared: {', '.join(supplied) or 'nothing'}."]
    if info["off"]:
        out += ["", "Defaults turned off (each changes the model; `--simulator "
                f"{name.split('_with_')[0]}:NAME` leaves one on):", ""]
        out += [f"- `{default}`: {what}" for default, what in info["off"]]
    if info["on"]:
        out += ["", f"Defaults left on: {', '.join(info['on'])}."]
    return out + [""]
