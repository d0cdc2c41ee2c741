"""The independent formalisms behind one interface (``formalisms.interface``).

Registry: ``names()`` lists them, ``get(name)`` returns the :class:`~formalisms.interface.Formalism`.
Modules are imported on first use, so listing names costs nothing.
"""

from __future__ import annotations

import importlib

from formalisms.interface import UNSUPPORTED, Formalism, Split, StateError

_MODULES = {
    "euler_lagrange": "formalisms.euler_lagrange",
    "newton_euler": "formalisms.newton_euler",
    "screw": "formalisms.screw",
    "operational_space": "formalisms.operational_space",
    "geometric": "formalisms.geometric",
}


class UnknownFormalism(KeyError):
    def __str__(self) -> str:
        return self.args[0]


def names() -> list[str]:
    """The registered formalisms, in registry order."""
    return list(_MODULES)


def get(name: str) -> Formalism:
    """The formalism called ``name``; an unknown name raises :class:`UnknownFormalism` listing the valid ones."""
    if name not in _MODULES:
        raise UnknownFormalism(f"unknown formalism '{name}'; valid formalisms: {', '.join(_MODULES)}")
    return importlib.import_module(_MODULES[name]).FORMALISM


__all__ = ["Formalism", "Split", "StateError", "UNSUPPORTED", "UnknownFormalism", "get", "names"]
