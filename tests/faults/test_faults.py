"""The fault catalog is itself tested (crosscheck.faults.injection, crosscheck.faults.backend_catalog): every fault is real (its backend's
output changes), the default gate catches it and names its backend, and the patch is fully removed afterwards (the
backend's output bit for bit what it was before any fault was injected)."""

from __future__ import annotations

import dataclasses
import os

import pytest

import formalisms
from crosscheck import backends, cli
from crosscheck.faults import common_mode
from crosscheck.faults import backend_catalog
from crosscheck.faults import injection
from crosscheck.faults.injection import Fault, FaultError, Hunt, injected
from crosscheck.engine.specs import CaseSpec, Checks
from crosscheck.core.sampling import sample_states

#: The gate rounds (state i of every case) probed before any fault: every fault must be caught within them, so its
#: catching state has a pristine output to compare with after the fault is removed. Two: state 0 is the home
#: configuration, where every orientation is the identity and a quaternion conjugated changes nothing
#: (screw-quaternion-conjugated is caught at free_body #1).
PROBE_ROUNDS = 2


def _setup(case: str) -> injection._Case:
    return injection._case(CaseSpec(case), 0, Checks())


class Pristine:
    """The outputs of a backend at the probed states of every default case, computed on first use, which for each
    backend comes before any of its faults is injected."""

    def __init__(self):
        self._outputs: dict[str, dict[tuple[str, int], dict]] = {}

    def __call__(self, backend: str) -> dict[tuple[str, int], dict]:
        if backend not in self._outputs:
            formalism = backends.get(backend)
            self._outputs[backend] = {
                (spec.name, i): injection.outputs(formalism, _setup(spec.name).setup, _setup(spec.name).state(i, 100))
                for spec in injection.default_specs() for i in range(PROBE_ROUNDS)}
        return self._outputs[backend]


@pytest.fixture(scope="module")
def pristine() -> Pristine:
    return Pristine()


def test_the_catalog_has_at_least_25_uniquely_named_faults_in_every_backend():
    names = backend_catalog.names()
    assert len(names) >= 25
    assert len(set(names)) == len(names)
    assert {f.backend for f in backend_catalog.CATALOG} == set(formalisms.names())
    for fault in backend_catalog.CATALOG:
        owner, name, original = injection._resolve(fault)      # every target exists
        assert callable(original), fault.target
        assert fault.bug.endswith(".") and len(fault.bug) < 240, fault.name


def test_a_fault_must_be_well_formed():
    keep = dict(backend="screw", bug="b.", target="formalisms.screw.lie:coad", replace=lambda f: f)
    with pytest.raises(FaultError, match="kebab-case"):
        Fault("Screw_Bad", **keep)
    with pytest.raises(FaultError, match="unknown backend 'pinocchio'"):
        Fault("screw-bad", **{**keep, "backend": "pinocchio"})
    with pytest.raises(FaultError, match="not 'module:attribute'"):
        Fault("screw-bad", **{**keep, "target": "formalisms.screw.lie.coad"})
    with pytest.raises(FaultError, match="no derivation cache"):
        Fault("screw-bad", **keep, derived=True)
    with pytest.raises(FaultError, match="does not exist"):
        with injected(Fault("screw-bad", **{**keep, "target": "formalisms.screw.lie:no_such_function"})):
            pass
    with pytest.raises(FaultError, match="unknown fault 'nope'; valid faults: el-"):
        backend_catalog.get("nope")


def test_injected_patches_and_restores_the_very_object_also_on_error():
    fault = backend_catalog.get("ne-multiplier-sign")               # a method, patched on its class
    owner, name, original = injection._resolve(fault)
    with pytest.raises(RuntimeError, match="boom"):
        with injected(fault) as faulty:
            assert owner.__dict__[name] is faulty and faulty is not original
            raise RuntimeError("boom")
    assert owner.__dict__[name] is original


def test_a_derivation_fault_runs_on_empty_caches_and_leaves_the_originals():
    from formalisms import euler_lagrange, geometric

    before_env, compiled = os.environ.get("CROSSCHECK_CACHE"), euler_lagrange._compiled
    with injected(backend_catalog.get("el-kinetic-energy-missing-half")):
        assert os.environ["CROSSCHECK_CACHE"] != before_env and os.listdir(os.environ["CROSSCHECK_CACHE"]) == []
        assert euler_lagrange._compiled is not compiled and euler_lagrange._compiled.cache_info().currsize == 0
        temporary = os.environ["CROSSCHECK_CACHE"]
    assert os.environ.get("CROSSCHECK_CACHE") == before_env and not os.path.exists(temporary)
    assert euler_lagrange._compiled is compiled
    geometric.split(_setup("double_pendulum").setup.model, [0.1, 0.2], [0.3, 0.4], [0.0, 0.0])
    entries = dict(geometric._COMPILED)
    with injected(backend_catalog.get("geo-point-offset-unrotated")):
        assert geometric._COMPILED == {}
        geometric.split(_setup("double_pendulum").setup.model, [0.1, 0.2], [0.3, 0.4], [0.0, 0.0])
    assert geometric._COMPILED == entries


@pytest.mark.parametrize("fault", backend_catalog.CATALOG + common_mode.CATALOG,
                         ids=[f.name for f in backend_catalog.CATALOG + common_mode.CATALOG])
def test_every_replacement_can_be_called_as_its_target(fault):
    """A replacement written for an older signature of its target raises TypeError at every call, which the gate
    reports as a backend error: the fault would look caught without its bug ever running (this happened to
    el-kinetic-energy-missing-half when Euler–Lagrange's ``_energies`` lost an argument)."""
    for target in (fault.targets if isinstance(fault, common_mode.SharedFault) else (fault.target,)):
        owner, name, original = injection.resolve(fault.name, target)
        injection._same_call(fault.name, target, original, fault.replace(original))


def test_a_replacement_for_an_older_signature_is_refused():
    stale = Fault("el-stale-signature", "euler_lagrange", "written for _energies(model, st, poses, pd, world)",
                  "formalisms.euler_lagrange:_energies", lambda energies: lambda model, st, poses, pd, world: None)
    with pytest.raises(FaultError, match="el-stale-signature.*cannot be called as formalisms.euler_lagrange:_energies"):
        with injected(stale):
            pass


def test_the_hunt_visits_the_gates_states():
    for name in ("double_pendulum", "four_bar"):
        case = _setup(name)
        lazily = [case.state(i, 9) for i in range(9)]
        assert lazily == sample_states(case.setup.model, 9, 0, name)


@pytest.mark.parametrize("fault", backend_catalog.CATALOG, ids=[f.name for f in backend_catalog.CATALOG])
def test_the_gate_catches_the_fault_and_the_patch_is_removed(fault, pristine):
    before = pristine(fault.backend)
    found = injection.caught_within(fault, PROBE_ROUNDS)
    assert found.caught, f"the default gate misses {fault.name} in {found.states} states"
    assert found.state < PROBE_ROUNDS, f"{fault.name} is caught only at state {found.state}: raise PROBE_ROUNDS"
    assert found.catches and all(not c.ratio <= 1.0 for c in found.catches)
    assert found.outlier == fault.backend, f"the vote named {found.outlier}, not {fault.backend}"
    assert found.proof.real, f"{fault.name} does not change {fault.backend}'s output where it was caught"
    owner, name, original = injection._resolve(fault)
    assert (owner.__dict__[name] if isinstance(owner, type) else getattr(owner, name)) is original
    case = _setup(found.case)
    after = injection.outputs(backends.get(fault.backend), case.setup, case.state(found.state, 100))
    assert injection.differing(after, before[found.case, found.state]) == []


def test_the_catalog_has_no_known_gap():
    """Every catalog fault is caught (the test above): none may keep a gap note saying the gate misses it."""
    assert [f.name for f in backend_catalog.CATALOG if f.gap] == []


def test_a_fault_only_in_the_joint_loads_is_proven_on_the_loads():
    """Reactions computed at the drift acceleration leave every acceleration as it is: the proof is the loads."""
    found = injection.hunt(backend_catalog.get("ne-reactions-at-drift-acceleration"))
    assert found.caught and found.proof.key.endswith(": joint_wrenches")


def test_the_report_leads_with_the_catch_rate_and_marks_a_miss():
    caught = injection.hunt(backend_catalog.get("geo-task-bias-dropped"), samples=1)
    missed = Hunt(backend_catalog.get("osc-task-bias-dropped"), False, 10, 0.5)
    summary = injection.summarize([caught, missed])
    assert (summary.faults, summary.caught, summary.rate, summary.named_faulty) == (2, 1, 0.5, 1)
    text = injection.render([caught, missed], "crosscheck faults", 1.0, 1, 0)
    assert text.index("1/2 (50 %)") < text.index("## Faults")
    assert "| `osc-task-bias-dropped` | operational_space | **NO** |" in text
    assert "- `osc-task-bias-dropped` (operational_space): " in text and "a new blind spot" in text
    assert injection.line(missed).startswith("MISSED osc-task-bias-dropped")
    noted = dataclasses.replace(backend_catalog.get("osc-task-bias-dropped"), gap="A synthetic gap note.")
    gap = Hunt(noted, False, 10, 0.5)
    assert "(operational_space): " in injection.render([gap], "crosscheck faults", 1.0, 1, 0)
    assert "A synthetic gap note." in injection.render([gap], "crosscheck faults", 1.0, 1, 0)
    assert injection.line(gap).endswith("(a known gap of the gate)") and not injection.line(missed).endswith("gate)")


def test_the_faults_command_exits_0_only_when_every_fault_is_caught(tmp_path, capsys, monkeypatch):
    report = tmp_path / "faults.md"
    assert cli.main(["faults", "--fault", "geo-task-bias-dropped", "--samples", "2", "--report", str(report)]) == 0
    out = capsys.readouterr().out
    assert "caught geo-task-bias-dropped (geometric): double_pendulum #0" in out and "caught 1/1 (100 %)" in out
    assert "| 1/1 (100 %) |" in report.read_text()
    monkeypatch.setattr(injection, "hunt", lambda fault, **kw: Hunt(fault, False, 3, 0.1))
    assert cli.main(["faults", "--fault", "geo-task-bias-dropped", "--report", str(report)]) == 1
    assert "MISSED geo-task-bias-dropped" in capsys.readouterr().out
    assert cli.main(["faults", "--list"]) == 0
    listing = capsys.readouterr().out
    assert all(f"{f.name} " in listing and f.bug in listing for f in backend_catalog.CATALOG)
    assert cli.main(["faults", "--fault", "nope"]) == 2
    assert "unknown fault 'nope'" in capsys.readouterr().err


def test_a_derivation_fault_does_not_outlive_itself_in_the_linearization():
    """A faulty Euler–Lagrange derivation reaches the linearization's code too (derived from the same energies); that
    code is cached apart, and must be discarded with the fault: once it was not, and the next fault's hunt blamed
    euler_lagrange for the double pendulum's dvdot/dq."""
    import numpy as np

    import cases
    from formalisms import euler_lagrange
    model, q, v, u = cases.load("double_pendulum"), [0.3, 0.2], [1.0, -1.0], [0.0, 0.0]
    euler_lagrange._linear_code.cache_clear()                 # the first derivation of the model under the fault
    with injected(backend_catalog.get("el-kinetic-energy-missing-half")):
        faulty = euler_lagrange.linearize(model, q, v, u).A
    after = euler_lagrange.linearize(model, q, v, u).A
    euler_lagrange._linear_code.cache_clear()
    clean = euler_lagrange.linearize(model, q, v, u).A
    assert not np.allclose(faulty, clean)
    np.testing.assert_array_equal(after, clean)
