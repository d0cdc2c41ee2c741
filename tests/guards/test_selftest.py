"""Self-test canaries (crosscheck.guards.selftest): every canary is caught and named at a calibrated ratio, and the harness
faults they exist for (a loosened tolerance, a signed difference, NaN as agreement, a broken vote) make them fail."""

from __future__ import annotations

import numpy as np
import pytest

from crosscheck.core import compare, tolerance
from crosscheck.guards import selftest


@pytest.fixture(scope="module")
def clean() -> selftest.SelfTest:
    return selftest.run()


def test_every_canary_is_caught_and_named(clean):
    assert clean.passed, clean.failures()
    assert {r.canary.kind for r in clean.results} == {"mass matrix", "velocity products", "gravity", "one entry",
                                                     "multiplier sign", "not a number"}


def test_sized_canaries_are_caught_within_their_calibration(clean):
    """Caught with a margin (ratio >= 2: rounding, below 0.1 on these states, cannot fake a catch) and at most
    CALIBRATED times the tolerance, so that a tolerance loosened that much misses them."""
    for r in clean.results:
        if r.canary.size:
            assert 2.0 <= r.ratio <= selftest.CALIBRATED, (r.canary.describe(), r.ratio)


def test_the_3d_canaries_are_the_issues_claim(clean):
    """On the 3-D spatial arm a relative 1e-10 error in C qd and in g, and a smaller one in M, are caught."""
    sizes = {r.canary.kind: r.canary.size for r in clean.results if r.canary.case == "spatial_arm"}
    assert sizes["velocity products"] <= 1e-10 and sizes["gravity"] <= 1e-10 and sizes["mass matrix"] <= 1e-10


def test_a_tolerance_loosened_tenfold_is_caught(monkeypatch):
    loose = {q: (kind, 10.0 * factor) for q, (kind, factor) in tolerance.TOLERANCES.items()}
    monkeypatch.setattr(tolerance, "TOLERANCES", loose)
    result = selftest.run()
    assert not result.passed
    assert any("lost sensitivity" in line for line in result.failures())


def test_a_signed_difference_in_the_comparison_is_caught(monkeypatch):
    real = compare._pairwise

    def signed(vectors):
        i, j = compare._pair_indices(len(vectors))
        size = real(vectors).shape[1]
        V = np.array([v.ravel() if v.size == size else np.full(size, v.flat[0]) for v in vectors])
        return V[i] - V[j]

    monkeypatch.setattr(compare, "_pairwise", signed)
    assert not selftest.run().passed


def test_nan_counted_as_agreement_is_caught(monkeypatch):
    real = compare._ratios
    monkeypatch.setattr(compare, "_ratios", lambda d, t: np.nan_to_num(real(d, t), nan=0.0))
    result = selftest.run()
    assert [r.canary.kind for r in result.results if not r.passed] == ["not a number"]


def test_a_vote_that_names_the_wrong_backend_is_caught(monkeypatch):
    monkeypatch.setattr(compare, "_outlier", lambda names, pairs: names[0] if len(names) >= 3 else None)
    result = selftest.run()
    assert not result.passed and any("not named" in line for line in result.failures())
