"""Shared test configuration: Hypothesis profiles.

* ``ci`` (the default): derandomized, so a CI run is reproducible; 25 examples per property; no deadline
  (the first Euler–Lagrange evaluation of a model derives and compiles it, which takes seconds); failing
  examples are printed with their reproduction blob.
* ``fuzz``: 2000 fresh random examples per property, for long local or nightly campaigns::

      HYPOTHESIS_PROFILE=fuzz .venv/bin/pytest tests

Tests that pin their own ``@settings(max_examples=...)`` keep that count under either profile.
The Euler–Lagrange disk cache is deliberately left alone: it is keyed by the model digest and the codegen
version, so sharing it between runs cannot change an answer (the cache test points it at a tmp dir itself).
"""

from __future__ import annotations

import os

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
