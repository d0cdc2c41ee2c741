"""Self-test canaries (crosscheck.guards.selftest): every check of the gate has a canary, every canary is caught by
its own check and names its voter at a calibrated ratio, and each check switched off, loosened tenfold or failing
makes its canaries fail (the harness faults they exist for)."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from crosscheck.checks import conservation, equilibria, invariance, linearization
from crosscheck.core import compare, tolerance
from crosscheck.engine.specs import Checks
from crosscheck.guards import conditioning, coverage, file_reading, selftest
from crosscheck.references import closed_forms
from crosscheck.references.pinocchio import build


@pytest.fixture(scope="module")
def clean() -> selftest.SelfTest:
    return selftest.run()


def of(check: str) -> list[selftest.Canary]:
    return [c for c in selftest.CANARIES if c.check == check]


def test_every_canary_is_caught_by_its_check_and_named(clean):
    assert clean.passed, clean.failures()
    assert not any(r.skipped for r in clean.results)
    assert {r.canary.check for r in clean.results} == set(selftest.CHECKS)


def test_each_canary_is_caught_in_its_own_check(clean):
    """Where a canary was caught is a comparison its check owns (the momentum canary by the momentum rows)."""
    for r in clean.results:
        c = r.canary
        if c.check in ("comparisons", "closed forms", "coverage"):
            continue
        if c.check == "file reference":
            continue
        if c.check == "file reading":                 # a loader finding naming the field
            assert r.where.startswith("loader finding: link ") and c.key in r.where, (c, r.where)
            continue
        prefix = {"charts": "chart ", "frames": "frame", "conservation": "conservation: ", "conditions": "conditions: ",
                  "linearization": "linearization: ", "equilibria": "equilibrium ", "multipliers": c.quantity}[c.check]
        assert r.where.startswith(prefix) and c.key in r.where, (c, r.where)


def test_sized_canaries_are_caught_within_their_calibration(clean):
    """Caught with a margin (ratio >= 2: rounding, below 0.1 on these states, cannot fake a catch) and at most
    CALIBRATED times the tolerance, so that a check loosened that much misses them."""
    for r in clean.results:
        if r.canary.size:
            assert 2.0 <= r.ratio <= selftest.CALIBRATED, (r.canary.describe(), r.ratio)


def test_the_3d_canaries_are_the_issues_claim(clean):
    """On the 3-D spatial arm a relative 1e-10 error in C qd and in g, and a smaller one in M, are caught."""
    sizes = {r.canary.kind: r.canary.size for r in clean.results
             if r.canary.case == "spatial_arm" and r.canary.check == "comparisons"}
    assert sizes["velocity products"] <= 1e-10 and sizes["gravity"] <= 1e-10 and sizes["mass matrix"] <= 1e-10


def test_the_multipliers_canaries_sit_on_cases_with_several_rows():
    import cases

    assert all(cases.load(c.case).k >= 2 for c in of("multipliers"))
    assert {c.quantity for c in of("multipliers")} >= {"lam", "constraint_force", "power_constr"}


def _loosened(module):
    """``module``'s ``compare`` with every tolerance ten times larger."""
    real = module.compare
    return lambda quantity, values, tol, *args, **kw: real(quantity, values, 10.0 * np.asarray(tol), *args, **kw)


def _no_problems(measure):
    return lambda model, states: dataclasses.replace(measure(model, states), problems=())


#: check -> (what switches it off, what loosens it tenfold): (module, attribute, replacement of the original).
BREAKS = {
    "charts": ((invariance, "chart_checks", lambda f: lambda *a, **k: {}), (invariance, "compare", None)),
    "frames": ((invariance, "frame_checks", lambda f: lambda *a, **k: {}), (invariance, "compare", None)),
    "conservation": ((conservation, "checks", lambda f: lambda *a, **k: {}), (conservation, "compare", None)),
    "linearization": ((linearization, "checks", lambda f: lambda *a, **k: ({}, {})), (linearization, "compare", None)),
    "equilibria": ((equilibria, "checks", lambda f: lambda *a, **k: ({}, {})), (equilibria, "compare", None)),
    "conditions": ((conditioning, "audit", lambda f: lambda *a, **k: {}), (conditioning, "compare", None)),
    "closed forms": ((closed_forms, "voter", lambda f: lambda *a, **k: None),
                     (tolerance, "TOLERANCES", lambda t: {q: (kind, 10.0 * factor) for q, (kind, factor) in t.items()})),
    "file reference": ((build, "_build_from_file", lambda f: build._build_from_data),
                       (tolerance, "TOLERANCES", lambda t: {q: (kind, 10.0 * factor) for q, (kind, factor) in t.items()})),
    "multipliers": ((tolerance, "quantities", lambda f: lambda model: [q for q in f(model) if q not in (
        "lam", "lam_drift", "constraint_force", "power_constr")]),
                    (tolerance, "TOLERANCES", lambda t: {q: (kind, 10.0 * factor if q in (
                        "lam", "lam_drift", "constraint_force", "power_constr") else factor)
                        for q, (kind, factor) in t.items()})),
    "coverage": ((coverage, "measure", _no_problems), (coverage, "SLIVER", lambda value: value / 10.0),
                 (coverage, "BAND", lambda value: 10.0 * value),
                 (coverage, "limit_allowance", lambda f: lambda states: 10 * f(states))),
    "file reading": ((file_reading, "compare", lambda f: lambda *a, **k: []),
                     (file_reading, "ROUNDING", lambda value: 10.0 * value)),
}


def test_every_check_has_a_break_below():
    assert set(BREAKS) == set(selftest.CHECKS) - {"comparisons"}


@pytest.mark.parametrize("how", ["off", "loosened tenfold"])
@pytest.mark.parametrize("check", sorted(BREAKS))
def test_a_check_switched_off_or_loosened_fails_its_canaries(monkeypatch, check, how):
    patches = BREAKS[check][:1] if how == "off" else BREAKS[check][1:]
    if check == "coverage" and how != "off":
        canaries = [c for c in of(check) if c.kind in ("sliver", "band", "at the limits")]    # those with bounds
    elif check == "file reading" and how != "off":
        canaries = [c for c in of(check) if c.size]                  # those sized against the rounding tolerance
    else:
        canaries = of(check)
    monkeypatch.setattr(build, "_CACHE", {})              # no reference built before the break is reused
    for module, name, replace in patches:
        original = getattr(module, name)
        monkeypatch.setattr(module, name, _loosened(module) if replace is None else replace(original))
    result = selftest.run(canaries)
    assert not result.passed
    assert all(not r.passed for r in result.results), [(r.canary, r.ratio) for r in result.results if r.passed]
    assert all(check in line for line in result.failures())


def test_a_frame_check_comparing_a_scene_with_itself_is_caught(monkeypatch):
    """A moved scene that is a copy of the unmoved one: the canary whose backend leaves gravity unrotated in the moved
    scene is not caught, and where a frame law expects the extras turned every backend disagrees without a fault."""
    from crosscheck.checks import frames

    monkeypatch.setattr(frames, "move_scene", lambda model, frame: dataclasses.replace(model))
    monkeypatch.setattr(invariance, "FRAME_LAWS", {})
    result = selftest.run([c for c in of("frames") if c.key != "frame law"])
    assert [r.canary.kind for r in result.results if not r.passed] == ["gravity unrotated"]
    monkeypatch.undo()
    monkeypatch.setattr(frames, "move_scene", lambda model, frame: dataclasses.replace(model))
    assert not selftest.run(of("frames")).passed


def test_a_check_raising_is_its_canarys_internal_error(monkeypatch):
    def broken(*args, **kwargs):
        raise ZeroDivisionError("a fault in the energy bookkeeping")

    monkeypatch.setattr(conservation, "checks", broken)
    result = selftest.run(of("conservation"))
    assert not result.passed and all("conservation" in line for line in result.failures())


def test_a_check_switched_off_in_the_run_skips_its_canaries():
    result = selftest.run(of("charts") + of("frames"), checks=Checks(charts=False, frames=0))
    assert result.passed and all("off" in r.skipped for r in result.results)


def test_a_tolerance_loosened_tenfold_is_caught(monkeypatch):
    loose = {q: (kind, 10.0 * factor) for q, (kind, factor) in tolerance.TOLERANCES.items()}
    monkeypatch.setattr(tolerance, "TOLERANCES", loose)
    result = selftest.run(of("comparisons"))
    assert not result.passed
    assert any("lost its power" in line for line in result.failures())


def test_a_signed_difference_in_the_comparison_is_caught(monkeypatch):
    real = compare._pairwise

    def signed(vectors):
        i, j = compare._pair_indices(len(vectors))
        size = real(vectors).shape[1]
        V = np.array([v.ravel() if v.size == size else np.full(size, v.flat[0]) for v in vectors])
        return V[i] - V[j]

    monkeypatch.setattr(compare, "_pairwise", signed)
    assert not selftest.run(of("comparisons")).passed


def test_nan_counted_as_agreement_is_caught(monkeypatch):
    real = compare._ratios
    monkeypatch.setattr(compare, "_ratios", lambda d, t: np.nan_to_num(real(d, t), nan=0.0))
    result = selftest.run(of("comparisons"))
    assert [r.canary.kind for r in result.results if not r.passed] == ["not a number"]


def test_a_vote_that_names_the_wrong_backend_is_caught(monkeypatch):
    monkeypatch.setattr(compare, "_outlier", lambda names, pairs: names[0] if len(names) >= 3 else None)
    result = selftest.run(of("comparisons"))
    assert not result.passed and any("not named" in line for line in result.failures())
