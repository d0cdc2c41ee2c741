"""The backends the harness evaluates: every registered formalism plus the Pinocchio reference."""

from __future__ import annotations

import formalisms
from formalisms.interface import Formalism

REFERENCE_NAME = "pinocchio"


def names() -> list[str]:
    """Every formalism, then the reference."""
    return formalisms.names() + [REFERENCE_NAME]


def get(name: str) -> Formalism:
    """A formalism or the reference by name; an unknown name lists the valid ones."""
    if name == REFERENCE_NAME:
        from crosscheck.reference import REFERENCE
        return REFERENCE
    if name not in formalisms.names():
        raise formalisms.UnknownFormalism(f"unknown formalism '{name}'; valid: {', '.join(names())}")
    return formalisms.get(name)
