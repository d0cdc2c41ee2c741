"""Seeded random states for the gate: same seed and case, same states, on every machine."""

from __future__ import annotations

import zlib
from dataclasses import dataclass

import numpy as np

from cases.model import Model

#: Sampling ranges: revolute angles (rad), prismatic displacements (m), joint rates (rad/s or m/s), inputs.
ANGLE_RANGE = np.pi
DISPLACEMENT_RANGE = 0.5
RATE_RANGE = 3.0
INPUT_RANGE = 10.0


@dataclass(frozen=True)
class State:
    """One sampled state (q, qd) and input u, with its index in the case's sample sequence."""

    index: int
    q: tuple[float, ...]
    qd: tuple[float, ...]
    u: tuple[float, ...]


def case_rng(seed: int, case: str) -> np.random.Generator:
    """A generator seeded by (seed, case name), so adding a case does not change another's states."""
    return np.random.default_rng([seed, zlib.crc32(case.encode())])


def sample_states(model: Model, count: int, seed: int, case: str) -> list[State]:
    """``count`` states: q uniform over one turn (revolute) or +-0.5 m (prismatic), qd and u uniform.

    State 0 has the home configuration ``q = 0`` (qd and u still random): serial chains are often singular
    there (the stretched double pendulum of article 6.3.4), so every gate run visits one such boundary state.
    """
    rng = case_rng(seed, case)
    span = np.array([ANGLE_RANGE if b.joint == "revolute" else DISPLACEMENT_RANGE for b in model.bodies])
    states = []
    for i in range(count):
        q = rng.uniform(-span, span)
        if i == 0:
            q = np.zeros(model.n)
        qd = rng.uniform(-RATE_RANGE, RATE_RANGE, model.n)
        u = rng.uniform(-INPUT_RANGE, INPUT_RANGE, model.m)
        states.append(State(i, tuple(q.tolist()), tuple(qd.tolist()), tuple(u.tolist())))
    return states
