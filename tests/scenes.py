"""Scenes the tests share that are not built-in cases."""

from __future__ import annotations

import cases
from cases.build import build_model


def panda_arm():
    """The Panda of the built-in case without its finger coupling (the URDF's ``<mimic>``, a ``JointCoupling``) and
    without its file source: the 9-joint 3-D tree for tests of a backend's unconstrained algorithms (inverse
    dynamics round trips, joint reactions, the energy rate, the task-space projector), which a constraint would
    change. The reference then builds it from these bodies, as for any model built in code."""
    panda = cases.load("panda")
    return build_model("panda_arm", panda.bodies, panda.gravity, input_map=panda.input_map,
                       task_points=panda.task_points)
