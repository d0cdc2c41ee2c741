"""Shared test configuration: Hypothesis profiles.

* ``ci`` (the default): derandomized, so a CI run is reproducible; 25 examples per property; no deadline
  (the first Euler–Lagrange evaluation of a model derives and compiles it, which takes seconds); failing
  examples are printed with their reproduction blob.
* ``fuzz``: 2000 fresh random examples per property, for long local or nightly campaigns::

      HYPOTHESIS_PROFILE=fuzz .venv/bin/pytest tests

Compilation to C is off (``CROSSCHECK_COMPILE=0``) unless the environment says otherwise.

Tests that pin their own ``@settings(max_examples=...)`` keep that count under either profile.
The shared Euler–Lagrange disk cache is keyed by the model digest, the chart and a hash of the derivation's
source, so sharing it between runs cannot change an answer; the Euler–Lagrange test modules still derive afresh
(fixture ``fresh_derivation_cache``).
"""

from __future__ import annotations

import os
import signal

import pytest
from hypothesis import HealthCheck, settings

settings.register_profile(
    "ci",
    derandomize=True,
    deadline=None,
    max_examples=25,
    print_blob=True,
    suppress_health_check=[HealthCheck.too_slow],
)
settings.register_profile(
    "fuzz",
    derandomize=False,
    deadline=None,
    max_examples=2000,
    print_blob=True,
    suppress_health_check=[HealthCheck.too_slow],
)
settings.load_profile(os.environ.get("HYPOTHESIS_PROFILE", "ci"))

# The suite evaluates the backends' casadi Functions interpreted: compiling them to C (formalisms/geometric.py,
# "Compiled evaluation") costs seconds per model, and the tests that check the compiled code against the interpreter
# turn it on themselves. ``CROSSCHECK_COMPILE=1 pytest`` runs the whole suite compiled.
os.environ.setdefault("CROSSCHECK_COMPILE", "0")

# Ctrl-C as Python has it by default, whatever this process inherited: a shell without job control starts a
# background command (``pytest ... &``, a nohup'd or scheduled run) with SIGINT ignored, and an ignored signal stays
# ignored in every child, so the tests that send SIGINT to a crosscheck command would see it run to the end.
signal.signal(signal.SIGINT, signal.default_int_handler)


@pytest.fixture(scope="session", autouse=True)
def single_threaded_blas():
    """One BLAS thread, as the command line runs (``crosscheck.cli.options.BLAS_THREADS``): the matrices are tiny."""
    from threadpoolctl import threadpool_limits

    with threadpool_limits(limits=1, user_api="blas"):
        yield


def _drop_coriolis(patch: pytest.MonkeyPatch) -> None:
    """Euler–Lagrange with its velocity-product term silently dropped, as a real bug would (undone with ``patch``)."""
    import formalisms.euler_lagrange as el
    correct = el.evaluate

    def broken(model, x, xd, chart=None):
        terms, constraint_terms = correct(model, x, xd, chart)
        return terms._replace(Cqd=terms.Cqd * 0.0), constraint_terms

    patch.setattr(el, "evaluate", broken)


@pytest.fixture
def dropped_coriolis(monkeypatch):
    """Euler–Lagrange with its velocity-product term silently dropped, for the test."""
    _drop_coriolis(monkeypatch)


@pytest.fixture(scope="session")
def drop_coriolis():
    """The same fault for a module-scoped fixture that computes something under it once: called with the fixture's
    own ``pytest.MonkeyPatch.context()``, which undoes it."""
    return _drop_coriolis


@pytest.fixture(scope="module")
def fresh_derivation_cache(tmp_path_factory):
    """Euler–Lagrange derivations of one test module go to a scratch disk cache: (1) the module tests the current
    derivation, never code a stale cache entry serves; (2) drawn parameters make a new model (a new entry) per
    example, and a fuzzing run must not leave thousands of files in the user's cache."""
    import formalisms.euler_lagrange as el
    with pytest.MonkeyPatch.context() as mp:
        mp.setenv("CROSSCHECK_CACHE", str(tmp_path_factory.mktemp("el_cache")))
        el._compiled.cache_clear()
        yield
    el._compiled.cache_clear()


@pytest.fixture
def isolated_cache(tmp_path, monkeypatch):
    """One test's own scratch disk cache (``CROSSCHECK_CACHE``), no Euler–Lagrange program loaded before it and none
    compiled from it (or from a patched generator) outliving it."""
    import formalisms.euler_lagrange as el
    monkeypatch.setenv("CROSSCHECK_CACHE", str(tmp_path))
    el._compiled.cache_clear()
    yield tmp_path
    el._compiled.cache_clear()
