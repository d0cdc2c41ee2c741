"""Common-mode faults (crosscheck.faults.common_mode): bugs in code every backend shares are caught by the gate itself,
each by the guard outside the vote that exists for it, and the patches are fully removed afterwards."""

from __future__ import annotations

import dataclasses

import pytest

from crosscheck.faults import common_mode
from crosscheck.faults import injection

#: The rounds of states (state i of every case) the cheap first search evaluates: every shared fault is caught within
#: them by the default gate (reports/faults.md, "Common-mode faults": state #0 or #1 of some case, or before any state).
PROBE_ROUNDS = 2


def test_the_catalog_has_at_least_ten_faults_over_every_shared_area():
    names = common_mode.names()
    assert len(names) >= 10 and len(set(names)) == len(names)
    assert {f.area for f in common_mode.CATALOG} >= {"URDF conversion", "URDF parsing", "case factories",
                                                    "constraint declarations", "sampling", "charts", "frames",
                                                    "comparison", "tolerance", "load declarations", "conservation"}
    for fault in common_mode.CATALOG:
        for target in fault.targets:
            injection.resolve(fault.name, target)                   # every target exists
        assert fault.bug.endswith(".") and fault.guard


#: How each guard's catch shows in SharedHunt.by and .detail: (a fragment of by, a fragment of detail).
GUARDS = {"the reference built from the file": ("#", "outlier pinocchio"),
          "the second reading of the file": ("loader", "loader finding: link "),
          "the closed forms": ("#", "outlier closed_form"),
          "the sampling coverage": ("coverage", ""),
          "the internal errors of the harness": ("#", "internal error in "),
          "the self-test canaries": ("self-test", ""),
          "the chart checks": ("#", "chart"),
          "the frame checks": ("#", "frame"),
          "the exact values": ("#", "outlier exact"),
          "the conditions audit": ("#", "conditions"),
          "the Pinocchio reference's own kinematic rows": ("#", "linearization: kinematic rows"),
          "the energy-rate conservation checks": ("#", "conservation: energy rate")}


@pytest.mark.parametrize("fault", common_mode.CATALOG, ids=common_mode.names())
def test_the_gate_catches_the_shared_fault_by_its_guard(fault):
    before = [injection.resolve(fault.name, target)[2] for target in fault.targets]
    expected = [catch for guard, catch in GUARDS.items() if guard in fault.guard]

    def by_its_guard(found) -> bool:
        return found.caught and any(by in found.by and mark in found.detail for by, mark in expected)
    # first without the linearizations (cheap; a catch there is the default gate's at the same state, a check only
    # adding failures) and without the self-test (whose canaries, run first by a hunt, catch many of these too: here
    # the guard named must catch it on its own), in the states the default gate reaches first; then everything the
    # default gate does
    if "self-test" in fault.guard:         # the hunt runs the self-test first
        found = common_mode.hunt(fault)
    else:
        found = common_mode.hunt(fault, checks=dataclasses.replace(injection.WITHOUT_LINEARIZATION, self_test=False),
                                 rounds=PROBE_ROUNDS)
        found = found if by_its_guard(found) else common_mode.hunt(fault)
    assert found.caught, f"the gate misses {fault.name}: {found.detail}"
    assert expected and by_its_guard(found), (fault.guard, found.by, found.detail)
    assert [injection.resolve(fault.name, target)[2] for target in fault.targets] == before   # restored
