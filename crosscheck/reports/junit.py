"""JUnit XML for a gate run, for CI dashboards: one testsuite per case, one testcase per quantity and per check
family (``chart affine``, ``frame``, ``frame law``, each conservation check).

A testcase fails when one of its comparisons is DISAGREE at some state: the ``<failure>`` message gives the count
and the worst state (error/tolerance, severity, vote), its text one line per failing state with the reproduce
command. KNOWN comparisons (``crosscheck.engine.divergences``) pass, with the registry's reason in ``<system-out>``; a
testcase whose every comparison is NOT COMPARED is ``<skipped>``. Backend errors are an ``<error>`` testcase;
states with a backend in BREAKDOWN are listed in the testsuite's ``<system-out>``. Each case also has a ``sampling
coverage`` testcase (failing on a degenerate sample, ``crosscheck.guards.coverage``), for a model loaded from a file
a ``model file read apart from the loader`` one (failing on a loader finding, ``crosscheck.guards.loader``), and a
``backends compared`` one
(failing when a backend sat out most states in BREAKDOWN: ``GateResult.broken``), and the run a ``self-test`` suite
(one testcase per canary, ``crosscheck.guards.selftest``) and a ``backends`` suite (a required backend that took part in
no comparison fails), so that every reason the gate fails shows on a dashboard. The harness's own failures
(``crosscheck.engine.internal``) are a failing ``internal errors of the harness`` testcase in their case's suite, and
the run's own (the self-test, the report) a ``harness`` suite with one failing testcase per check.
"""

from __future__ import annotations

import xml.etree.ElementTree as ET
from pathlib import Path

from crosscheck.core.compare import DISAGREE, KNOWN, NOT_COMPARED, Comparison, vote
from crosscheck.core.tolerance import quantities
from crosscheck.engine import internal
from crosscheck.engine.outcomes import CaseOutcome, GateResult, StateOutcome
from crosscheck.reports.gate_lines import check_family, check_reproduce_command, reproduce_command

#: Failing states listed per testcase, as in the markdown report (the count is always complete).
MAX_LISTED = 20


def _ratio(comp: Comparison) -> float:
    return comp.worst_ratio if comp.worst_ratio == comp.worst_ratio else float("inf")


def _command(case: CaseOutcome, state: StateOutcome, key: str, seed: int) -> str:
    if key in state.comparisons:
        return reproduce_command(case, state)
    return check_reproduce_command(case, state, check_family(key), seed)


def _line(case: CaseOutcome, state: StateOutcome, key: str, comp: Comparison, seed: int) -> str:
    hint = f"; hint: {state.hint}" if state.hint else ""
    return (f"#{state.state.index} {key}: error/tolerance {comp.worst_ratio:.3g} ({comp.severity}), {vote(comp)}"
            f"{hint}; reproduce: {_command(case, state, key, seed)}")


def _groups(case: CaseOutcome) -> dict[str, list[tuple[StateOutcome, str, Comparison]]]:
    """testcase name -> every (state, key, comparison) it covers, quantities first, in run order."""
    groups: dict[str, list] = {q: [] for q in quantities(case.model)}
    for state in case.states:
        for key, comp in state.comparisons.items():
            groups.setdefault(key, []).append((state, key, comp))
    for state in case.states:
        for key, comp in state.checks.items():
            groups.setdefault(check_family(key), []).append((state, key, comp))
    return groups


def _testcase(suite: ET.Element, case: CaseOutcome, name: str, found: list, seed: int) -> str:
    """Add one testcase; returns its outcome: passed, failure or skipped."""
    element = ET.SubElement(suite, "testcase", classname=f"crosscheck.{case.spec.name}", name=name)
    bad = [f for f in found if f[2].verdict == DISAGREE]
    known = [f for f in found if f[2].verdict == KNOWN]
    if bad:
        state, key, worst = max(bad, key=lambda f: _ratio(f[2]))
        states = len({s.state.index for s, _, _ in bad})
        failure = ET.SubElement(element, "failure", type=DISAGREE, message=(
            f"{len(bad)} DISAGREE at {states} of {len(case.states)} states; worst #{state.state.index} {key}: "
            f"error/tolerance {worst.worst_ratio:.3g} ({worst.severity}), {vote(worst)}; reproduce: "
            f"{_command(case, state, key, seed)}"))
        lines = [_line(case, s, k, c, seed) for s, k, c in bad[:MAX_LISTED]]
        if len(bad) > MAX_LISTED:
            lines.append(f"... and {len(bad) - MAX_LISTED} more")
        failure.text = "\n".join(lines)
    if known:
        reasons = dict.fromkeys(c.reason for _, _, c in known)
        ET.SubElement(element, "system-out").text = "\n".join(
            f"KNOWN at {sum(c.reason == r for _, _, c in known)} comparison(s): {r}" for r in reasons)
    if bad:
        return "failure"
    if all(c.verdict == NOT_COMPARED for _, _, c in found):
        unsupported = sorted({n for _, _, c in found for n in c.not_compared})
        ET.SubElement(element, "skipped", message="NOT COMPARED: fewer than two values"
                      + (f" (not supplied by {', '.join(unsupported)})" if unsupported else ""))
        return "skipped"
    return "passed"


def _breakdowns(case: CaseOutcome) -> str:
    return "\n".join(f"BREAKDOWN #{s.state.index} {name}: " + ", ".join(f"cond {k} = {v:.3g}" for k, v in c.items())
                     + f"; reproduce: {reproduce_command(case, s)}"
                     for s in case.states for name, c in s.breakdowns.items())


def _suite(root: ET.Element, case: CaseOutcome, result: GateResult) -> dict[str, int]:
    suite = ET.SubElement(root, "testsuite", name=case.spec.name)
    properties = ET.SubElement(suite, "properties")
    for name, value in (("seed", result.seed), ("samples", result.samples), ("backends", ",".join(result.backends)),
                        ("case", case.spec.cli_args())):
        ET.SubElement(properties, "property", name=name, value=str(value))
    outcomes = [_testcase(suite, case, name, found, result.seed) for name, found in _groups(case).items()]
    if case.loader is not None:
        outcomes.append(_simple(suite, f"crosscheck.{case.spec.name}", "model file read apart from the loader",
                                "; ".join(map(str, case.loader.findings))))
    if case.coverage is not None:
        outcomes.append(_simple(suite, f"crosscheck.{case.spec.name}", "sampling coverage",
                                "; ".join(case.coverage.problems)))
    broken = result.broken.get(case.spec.name, {})
    outcomes.append(_simple(suite, f"crosscheck.{case.spec.name}", "backends compared", "; ".join(
        f"{name} was in BREAKDOWN (out of the vote) at {k} of {len(case.states)} states; --allow-breakdown {name} "
        "if that is expected" for name, k in broken.items())))
    errors = [s for s in case.states if s.errors]
    if errors:
        element = ET.SubElement(suite, "testcase", classname=f"crosscheck.{case.spec.name}", name="backend errors")
        error = ET.SubElement(element, "error", type="BackendError",
                              message=f"a backend raised at {len(errors)} states")
        error.text = "\n".join(f"#{s.state.index} {name}: {message}; reproduce: {reproduce_command(case, s)}"
                               for s in errors for name, message in s.errors.items())
    harness = [o for o in internal.occurrences(result) if o.case == case.spec.name]
    if harness:
        outcomes.append(_simple(suite, f"crosscheck.{case.spec.name}", "internal errors of the harness",
                                f"{len(harness)} internal error(s) of the harness (crosscheck's own code raised; "
                                f"the checks named were left out where they raised): {harness[0].describe()}",
                                "\n".join(o.describe() for o in harness), "InternalError"))
    if any(s.breakdowns for s in case.states):
        ET.SubElement(suite, "system-out").text = _breakdowns(case)
    counts = {"tests": len(outcomes) + bool(errors), "failures": outcomes.count("failure"),
              "errors": int(bool(errors)), "skipped": outcomes.count("skipped")}
    suite.attrib.update({k: str(v) for k, v in counts.items()})
    return counts


def _simple(suite: ET.Element, classname: str, name: str, failure: str, text: str = "", kind: str = "FAIL") -> str:
    """A testcase that fails with ``failure`` (passes when it is empty; ``text`` the failure's body, ``kind`` its
    type); returns its outcome."""
    element = ET.SubElement(suite, "testcase", classname=classname, name=name)
    if failure:
        ET.SubElement(element, "failure", type=kind, message=failure).text = text or None
        return "failure"
    return "passed"


def _run_suite(root: ET.Element, name: str, cases: list[tuple[str, str]]) -> dict[str, int]:
    """A suite of the run as a whole: (testcase name, failure message or "") each."""
    suite = ET.SubElement(root, "testsuite", name=name)
    outcomes = [_simple(suite, f"crosscheck.{name}", case, failure) for case, failure in cases]
    counts = {"tests": len(outcomes), "failures": outcomes.count("failure"), "errors": 0, "skipped": 0}
    suite.attrib.update({k: str(v) for k, v in counts.items()})
    return counts


def _self_test_cases(result: GateResult) -> list[tuple[str, str]]:
    test = result.self_test
    out = [(f"unusable state {where}", "the backends disagree there without any fault") for where in test.unusable]
    return out + [(f"{r.canary.check}: {r.canary.describe()}", "" if r.passed else (
        f"internal error {r.error}" if r.error else ("not caught" if not r.caught else "not named")
        + f" (error/tolerance {r.ratio:.3g})")) for r in test.results]


def to_xml(result: GateResult) -> ET.ElementTree:
    """The JUnit document of a gate run."""
    root = ET.Element("testsuites", name="crosscheck gate")
    totals = {"tests": 0, "failures": 0, "errors": 0, "skipped": 0}
    counts = [_suite(root, case, result) for case in result.cases]
    if result.self_test is not None:
        counts.append(_run_suite(root, "self-test", _self_test_cases(result)))
    if result.internal:
        counts.append(_run_suite(root, "harness", [(f"internal error in {check}", str(error))
                                                   for check, error in result.internal.items()]))
    if result.required:
        absent = set(result.absent)
        counts.append(_run_suite(root, "backends", [
            (f"{name} takes part", "took part in no comparison (name it with --optional if expected)"
             if name in absent else "") for name in result.required]))
    for count in counts:
        for k, v in count.items():
            totals[k] += v
    root.attrib.update({k: str(v) for k, v in totals.items()})
    tree = ET.ElementTree(root)
    ET.indent(tree)
    return tree


def write(result: GateResult, path: str | Path) -> None:
    """Write the JUnit XML of ``result`` to ``path`` (UTF-8, with an XML declaration)."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    to_xml(result).write(path, encoding="utf-8", xml_declaration=True)
