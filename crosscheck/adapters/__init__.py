"""Simulators and dynamics libraries as backends: MuJoCo, Drake, pybullet, iDynTree and roboticstoolbox-python.

Each adapter (:class:`crosscheck.adapters.base.Adapter`) reads the model file itself, as the library's users load
it, with every model-changing default of the library turned off and listed (``DEFAULTS``), and joins the vote like
any plugin (docs/plugins.md, docs/simulators.md):

    crosscheck gate --simulator drake --model robot.urdf                   # every default off
    crosscheck gate --simulator mujoco:damping --model robot.urdf          # MuJoCo with joint damping left on
    crosscheck gate --plugin crosscheck.adapters.drake --model robot.urdf  # the same as --simulator drake
    crosscheck simulators --model robot.urdf                               # every installed adapter, one report

Each is an optional extra (``pip install crosscheck[drake]``; ``crosscheck[simulators]`` installs all). An adapter
whose library is not installed is named so when asked for, and left out of ``crosscheck simulators``.
"""

from __future__ import annotations

import importlib.util

#: Each adapter's name -> (its module, the distribution that provides the library, the module that imports it).
SIMULATORS = {
    "mujoco": ("crosscheck.adapters.mujoco", "mujoco", "mujoco"),
    "drake": ("crosscheck.adapters.drake", "drake", "pydrake"),
    "pybullet": ("crosscheck.adapters.pybullet", "pybullet", "pybullet"),
    "idyntree": ("crosscheck.adapters.idyntree", "idyntree", "idyntree"),
    "roboticstoolbox": ("crosscheck.adapters.roboticstoolbox", "roboticstoolbox-python", "roboticstoolbox"),
}


class SimulatorError(ValueError):
    """A ``--simulator`` that names no adapter, a default the adapter does not have, or a library not installed."""


def installed() -> list[str]:
    """The adapters whose library is installed here (found, not imported), in :data:`SIMULATORS` order."""
    return [name for name, (_, _, module) in SIMULATORS.items() if importlib.util.find_spec(module) is not None]


def plugin_spec(text: str) -> str:
    """The ``--plugin`` spec of ``--simulator NAME[:DEFAULT,...]``: ``crosscheck.adapters.NAME:BACKEND[DEFAULT,...]``
    (``crosscheck.backends.load_plugin`` leaves the named defaults on)."""
    name, _, defaults = text.partition(":")
    if name not in SIMULATORS:
        raise SimulatorError(f"--simulator '{text}': no adapter '{name}'; adapters: {', '.join(SIMULATORS)}")
    module, distribution, library = SIMULATORS[name]
    if importlib.util.find_spec(library) is None:
        raise SimulatorError(f"--simulator '{text}': {distribution} is not installed; pip install "
                             f"'crosscheck[{name}]' (or pip install {distribution})")
    on = [d.strip() for d in defaults.split(",") if d.strip()]
    return f"{module}:BACKEND" + (f"[{','.join(on)}]" if on else "")
