"""The harness: everything that is not physics (DESIGN.md).

Sampling (``sampling``), the tolerance policy (``tolerance``), comparison and verdicts (``compare``),
the equivalence gate (``gate``), markdown reports (``report``) and the command line (``cli``).
The Pinocchio reference lives in ``reference``, apart from the formalisms it checks.
"""
