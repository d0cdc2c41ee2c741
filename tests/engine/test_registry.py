"""The divergence registry (``crosscheck.engine.divergences``, ``divergences.toml``): validation with specific errors, KNOWN
verdicts that do not fail the gate, unmatched disagreements that do, stale entries, and the command line."""

from __future__ import annotations

from pathlib import Path

import pytest

from crosscheck import backends, cli
from crosscheck.engine import divergences
from crosscheck.core.compare import DISAGREE, KNOWN
from crosscheck.engine.specs import CaseSpec, Checks
from crosscheck.engine.evaluation import evaluate
from crosscheck.engine.run import run_gate
from crosscheck.reports.gate_summary import render
from crosscheck.core.sampling import sample_states

ROOT = Path(__file__).resolve().parents[2]
ALL = [backends.get(name) for name in backends.names()]
QUICK = Checks(charts=False, frames=0, conservation=False, linearization=False)
REASON = "Christoffel term dropped on purpose in this test"


def _entry(backend="euler_lagrange", case="double_pendulum", quantity="drift", reason=REASON, extra=""):
    return (f'[[divergence]]\nbackend = "{backend}"\ncase = "{case}"\nquantity = "{quantity}"\n'
            f'reason = "{reason}"\n{extra}')


# ------------------------------------------------------------------------------------------------ loading


def test_the_checked_in_registry_is_valid_and_lists_no_invented_divergence():
    loaded = divergences.load(ROOT / "divergences.toml")
    assert loaded.entries == ()
    assert "[[divergence]]" in (ROOT / "divergences.toml").read_text()      # the header documents the format


def test_entries_are_read_with_their_fields():
    text = _entry() + "\n" + _entry(backend="screw", case="n_link_*", quantity="frame law: screw *",
                                     extra="max_ratio = 50\n")
    entries = divergences.parse(text, "test.toml").entries
    assert [(e.backend, e.case, e.quantity, e.number) for e in entries] == [
        ("euler_lagrange", "double_pendulum", "drift", 1), ("screw", "n_link_*", "frame law: screw *", 2)]
    assert entries[0].max_ratio is None and entries[1].max_ratio == 50.0 and entries[0].reason == REASON


@pytest.mark.parametrize("text, fragment", [
    (_entry(reason=""), "entry 1: 'reason' is empty; every known divergence must say why"),
    ('[[divergence]]\nbackend = "screw"\ncase = "*"\nquantity = "drift"\n', "entry 1: missing reason"),
    (_entry(backend="hamilton"), "unknown backend 'hamilton'; valid: euler_lagrange"),
    (_entry(quantity="dirft"), "quantity 'dirft' matches no quantity or check key"),
    (_entry(case="double_[pendulum"), "'case' = 'double_[pendulum' has an unclosed '['"),
    (_entry(case=""), "'case' must be a non-empty string"),
    (_entry(extra="max_ratio = 0.5\n"), "'max_ratio' must be a finite number above 1"),
    (_entry(extra="max_ratio = true\n"), "'max_ratio' must be a finite number above 1"),
    (_entry(extra='severity = "gross"\n'), "unknown key(s) severity; valid keys: backend, case, quantity"),
    (_entry() + _entry(), "entry 2 repeats entry 1"),
    ('[[divergence]]\nbackend = "screw\n', "not valid TOML"),
    ('known = 1\n', "unknown top-level key(s) known"),
    ('divergence = "drift"\n', "'divergence' must be an array of tables"),
])
def test_a_bad_registry_is_refused_with_a_specific_error(text, fragment):
    with pytest.raises(divergences.RegistryError) as info:
        divergences.parse(text, "bad.toml")
    assert str(info.value).startswith("bad.toml") and fragment in str(info.value)


def test_quantity_globs_reach_check_keys():
    for glob in ("chart affine: ctrl", "frame: *", "frame law: newton_euler joint_reactions_world",
                 "conservation: energy rate at drift", "lam*"):
        assert divergences.parse(_entry(quantity=glob)).entries[0].quantity == glob


# ----------------------------------------------------------------------------------------------- applying


def _coriolis_gate(samples=4):
    return run_gate([CaseSpec("double_pendulum")], ALL, samples, 0, checks=QUICK)


def _verdicts(result, key):
    return [s.comparisons[key].verdict for s in result.cases[0].states]


def test_an_explained_divergence_is_known_and_anything_unlisted_still_fails(dropped_coriolis):
    result = _coriolis_gate()
    applied = divergences.apply(divergences.parse(_entry()), result)
    assert _verdicts(result, "drift").count(KNOWN) == 3 and DISAGREE not in _verdicts(result, "drift")
    assert _verdicts(result, "total").count(DISAGREE) == 3           # not listed: still fails
    assert not result.passed and applied.known == 3 and not applied.stale
    known = result.cases[0].states[1].comparisons["drift"]
    assert known.reason == REASON and known.severity == "gross" and known.outlier == "euler_lagrange"


def test_a_fully_explained_run_passes_and_the_report_says_why(dropped_coriolis):
    result = _coriolis_gate()
    applied = divergences.apply(divergences.parse(_entry(quantity="drift") + _entry(quantity="total")
                                            + _entry(quantity="drift_velocity")), result)
    assert result.passed and applied.known == 9                   # drift, total and drift's velocity part, 3 states
    report = render(result, "test", applied)
    assert "**PASS**" in report and "9 known divergence(s)" in report
    section = report.split("## Known divergences")[1].split("\n## ")[0]
    assert "| double_pendulum | drift | euler_lagrange | 3 |" in section and REASON in section
    assert "## Disagreements" not in report


def test_an_entry_for_another_backend_or_a_larger_error_explains_nothing_and_is_stale(dropped_coriolis):
    text = _entry(backend="newton_euler") + _entry(quantity="total", extra="max_ratio = 1000\n")
    result = _coriolis_gate()
    applied = divergences.apply(divergences.parse(text, "reg.toml"), result)
    assert applied.known == 0 and not result.passed
    assert [e.number for e in applied.stale] == [1, 2]
    report = render(result, "test", applied)
    assert "**stale**: entry 1 (backend newton_euler, case double_pendulum, quantity drift) in `reg.toml`" in report


def test_an_entry_outside_the_run_is_not_exercised_rather_than_stale():
    result = run_gate([CaseSpec("acrobot")], ALL, 2, 0, checks=QUICK)
    applied = divergences.apply(divergences.parse(_entry(case="panda")), result)
    assert not applied.stale and [e.number for e in applied.unexercised] == [1]
    assert "- not exercised: entry 1" in render(result, "test", applied)


def test_two_voters_without_a_vote_are_explained_by_either_backend(dropped_coriolis):
    chosen = [backends.get("euler_lagrange"), backends.get("pinocchio")]
    model = CaseSpec("double_pendulum").build()
    state = sample_states(model, 2, 0, "double_pendulum")[1]
    for backend in ("euler_lagrange", "pinocchio"):
        outcome = evaluate(model, state, chosen)
        assert outcome.comparisons["drift"].outlier is None and outcome.failed
        usage = divergences.apply_to_state(divergences.parse(_entry(backend=backend, quantity="*")),
                                        ("double_pendulum",), outcome)
        assert usage.matched[1] == 3 and not outcome.failed          # drift, total and the drift's velocity part


def test_apply_to_state_turns_checks_known_too(monkeypatch):
    from crosscheck.checks import frames
    monkeypatch.setattr(frames, "wrench_map", frames.twist_map)
    result = run_gate([CaseSpec("spatial_arm")], ALL, 2, 0, checks=Checks(charts=False, conservation=False))
    text = _entry(backend="screw", case="spatial_*", quantity="frame law: screw wrenches_space")
    applied = divergences.apply(divergences.parse(text), result)
    checks = [c for s in result.cases[0].states for k, c in s.checks.items() if k.startswith("frame law: screw ")]
    assert applied.known == sum(c.verdict == KNOWN for c in checks) >= 1
    assert not result.passed                                      # the Newton–Euler reactions are not listed


# ------------------------------------------------------------------------------------------- command line


def _gate(tmp_path, *args):
    return cli.main(["gate", "--case", "double_pendulum", "--samples", "4", "--frames", "0", "--no-charts",
                     "--no-conservation", "--no-linearization", "--report", str(tmp_path / "gate.md"), *args])


def test_the_gate_reads_a_registry_and_warns_about_stale_entries(tmp_path, dropped_coriolis, capsys):
    path = tmp_path / "known.toml"
    path.write_text(_entry(quantity="drift") + _entry(quantity="total") + _entry(quantity="ctrl")
                    + _entry(quantity="drift_velocity"))
    assert _gate(tmp_path, "--registry", str(path)) == 0
    captured = capsys.readouterr()
    assert "PASS" in captured.out and "4 states, 0 failing, 9 known" in captured.out
    assert f"crosscheck: warning: stale entry 3 (backend euler_lagrange, case double_pendulum, quantity ctrl) in " \
           f"{path}" in captured.err
    assert _gate(tmp_path, "--no-registry") == 1


def test_the_gate_uses_divergences_toml_in_the_current_directory(tmp_path, dropped_coriolis, monkeypatch):
    monkeypatch.chdir(tmp_path)
    assert _gate(tmp_path) == 1
    (tmp_path / divergences.DEFAULT_PATH).write_text(_entry(quantity="drift") + _entry(quantity="total")
                                                  + _entry(quantity="drift_velocity"))
    assert _gate(tmp_path) == 0
    assert "divergence registry: `divergences.toml`, 3 entries; 9 comparison(s) KNOWN" in \
        (tmp_path / "gate.md").read_text()


@pytest.mark.parametrize("args, fragment", [
    (["--registry", "/no/such/known.toml"], "registry file /no/such/known.toml not found"),
    (["--registry", "x.toml", "--no-registry"], "give either --registry PATH or --no-registry"),
])
def test_registry_usage_errors_exit_2_with_one_line(tmp_path, args, fragment, capsys):
    assert _gate(tmp_path, *args) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and fragment in err


def test_an_invalid_registry_file_exits_2_naming_the_entry(tmp_path, capsys):
    path = tmp_path / "known.toml"
    path.write_text(_entry() + _entry(backend="hamilton", quantity="total"))
    assert _gate(tmp_path, "--registry", str(path)) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and f"{path}: [[divergence]] entry 2: unknown backend 'hamilton'" in err
