"""What a gate run is asked to check: the cases (:class:`CaseSpec`, a built-in factory or a model file) and the
checks besides the cross-backend comparison (:class:`Checks`)."""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass
from functools import partial
from typing import Callable

import cases
from cases import build
from cases.model import Model
from crosscheck.references import closed_forms
from formalisms.interface import UNSUPPORTED, Split


#: States per case of a default run (``--samples``). Every check runs at every state, so the run's time is linear in
#: it: 50 states of the 29 built-in cases keep the default gate near a minute on 2 cores. The fault catalog's every
#: fault is caught within the first two states of some case (docs/faults.md), and a fault that shows at a share p of
#: a case's states is missed with probability (1 - p)^50; longer runs: ``--samples``, ``crosscheck fuzz``.
DEFAULT_SAMPLES = 50


@dataclass(frozen=True)
class Checks:
    """Which checks the gate runs besides the cross-backend comparison: invariance and conservation, the closed
    forms of the cases that have them (``crosscheck.references.closed_forms``) and the self-test canaries
    (``crosscheck.guards.selftest``)."""

    charts: bool = True
    frames: int = 2
    conservation: bool = True
    closed_forms: bool = True
    self_test: bool = True
    linearization: bool = True
    joint_limits: bool = True   # sample within the joint limits a model declares (``--ignore-limits``: freely)


@dataclass(frozen=True)
class CaseSpec:
    """How to build one case: a built-in factory with parameters, or a model file (URDF or MJCF, ``path``) with the
    URDF ``base`` ("fixed", "free", or None: the file's own), ``actuated`` joints (None: every joint but a free
    base's) and ``armature`` (URDF joint name, rotor inertia) pairs (None: none declared; ``cases.from_file``);
    ``task_point``, when given, the default task point as ``BODY[:x,y,z]``
    (``cases.build.with_task_point``; a ``cases.build.TaskPointError`` for an unknown body or bad numbers)."""

    name: str
    params: tuple[tuple[str, str], ...] = ()
    path: str | None = None
    base: str | None = None
    actuated: tuple[str, ...] | None = None
    task_point: str | None = None
    armature: tuple[tuple[str, float], ...] | None = None

    def build(self) -> Model:
        if self.path is not None:
            model = cases.from_file(self.path, name=self.name, base=self.base, actuated=self.actuated,
                                    armature=None if self.armature is None else dict(self.armature))
        else:
            model = cases.load(self.name, **dict(self.params))
        return model if self.task_point is None else build.with_task_point(model, *build.parse(
            self.task_point))

    def closed_form(self):
        """The ``closed_form`` voter bound to this built-in case and its parameters
        (``crosscheck.references.closed_forms``), None when the case has none (a model file never has one). With a
        ``task_point`` given, it votes on everything but the task quantities, which its equations have for the case's
        own task point."""
        if self.path is not None:
            return None

        voter = closed_forms.voter(self.name, dict(self.params))
        if voter is None or self.task_point is None:
            return voter
        return dataclasses.replace(voter, split=partial(_without_task, voter.split),
                                   summary=f"{voter.summary} (not the task quantities: --task-point given)")

    def cli_args(self) -> str:
        """The command-line arguments that select this case."""
        point = f" --task-point {self.task_point}" if self.task_point is not None else ""
        if self.path is not None:
            return (f"--model {self.path}" + (f" --base {self.base}" if self.base else "")
                    + (f" --actuated {','.join(self.actuated) or chr(39) * 2}" if self.actuated is not None else "")
                    + (f" --armature {','.join(f'{j}={v!r}' for j, v in self.armature)}" if self.armature else "")
                    + point)
        return " ".join([f"--case {self.name}"] + [f"--param {k}={v}" for k, v in self.params]) + point


def _without_task(split: Callable[..., Split], model: Model, q, qd, u) -> Split:
    """``split``'s answer with the task drift, the task inertia and its condition declared unsupported."""
    s = split(model, q, qd, u)
    return dataclasses.replace(s, task_drift=UNSUPPORTED, task_inertia=UNSUPPORTED,
                               conditions={k: v for k, v in s.conditions.items() if k != "task_inertia"})
