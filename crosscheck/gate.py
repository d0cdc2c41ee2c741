"""The equivalence gate's public interface: ``run_gate`` over :class:`CaseSpec` cases with the :class:`Checks` to run,
the progress protocol (:class:`Step`) and Ctrl-C's partial result (:class:`Interrupted`).

The gate itself lives in ``crosscheck.engine`` (docs/design.md, "Architecture"): ``specs`` (cases and checks),
``evaluation`` (a block of states), ``outcomes``, ``phases`` (progress), ``run`` (the run) and ``pool`` (worker
processes). This module is the stable import path the documentation gives users; the harness imports the engine's
modules directly.
"""

from crosscheck.engine.outcomes import CaseOutcome, GateResult, StateOutcome
from crosscheck.engine.phases import Step
from crosscheck.engine.run import Interrupted, run_gate
from crosscheck.engine.specs import DEFAULT_SAMPLES, CaseSpec, Checks

__all__ = ["CaseOutcome", "CaseSpec", "Checks", "DEFAULT_SAMPLES", "GateResult", "Interrupted", "StateOutcome", "Step",
           "run_gate"]
