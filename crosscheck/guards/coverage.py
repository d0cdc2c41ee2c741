"""Sampling coverage: what a case's sampled states actually span, and whether that sample can test anything.

A gate whose states never move checks nothing: joint rates never sampled leave every velocity-product term
(Coriolis, centrifugal, gyroscopic, ``Jcdot qd``) at zero, inputs never sampled leave the control path unchecked, and
configurations in a sliver of the joint range test one posture. :func:`measure` records, per case, the range of every
coordinate of q, qd and u over the sampled states (and for a constrained model the rank of ``Jc`` over them, from the
harness's own constraint kinematics), and names what makes the sample degenerate:

* every joint rate zero (at two or more states), unless the constraints leave no motion (``rank Jc = n``);
* every input zero (at two or more states) for a model with inputs;
* from :data:`SLIVER_STATES` states on, configurations in a sliver: an unconstrained model with a coordinate whose
  sampled range is below :data:`SLIVER` of the span the gate promises (:data:`REVOLUTE_SPAN`,
  :data:`PRISMATIC_SPAN`, or the width of the joint limits a model declares) (uniform draws over the span leave that
  with probability below 1e-8), a constrained one with every coordinate so (the constraints may confine some, not all).

A degenerate sample fails the gate (``crosscheck.engine``): the report says what was not sampled.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Sequence

import numpy as np

from cases.model import Model
from crosscheck.core import sampling
from crosscheck.references.pinocchio.kinematics import constraint_kinematics

#: The span the gate promises to sample (docs/faults.md, coverage): one turn of a revolute joint, a metre of a
#: prismatic one. Written here, not read from ``crosscheck.core.sampling``, so that a sampler drawing from a narrower
#: range is measured against the promise, not against itself.
REVOLUTE_SPAN = 2.0 * np.pi
PRISMATIC_SPAN = 1.0
#: The spans of each joint's coordinates: a quaternion's components range over [-1, 1] (span 2), a free base's
#: position over the prismatic span.
_SPANS = {"revolute": (REVOLUTE_SPAN,), "prismatic": (PRISMATIC_SPAN,), "spherical": (2.0,) * 4,
          "free": (PRISMATIC_SPAN,) * 3 + (2.0,) * 4}
#: A coordinate's sampled range below this fraction of its promised span is a sliver.
SLIVER = 0.1
#: The sliver test needs this many states (fewer uniform draws may cluster by chance).
SLIVER_STATES = 10


@dataclass(frozen=True)
class Coverage:
    """The ranges sampled in one case: ``q``, ``qd`` (n, 2) and ``u`` (m, 2) rows ``[min, max]``, the sampling span
    promised for each coordinate, the range of ``rank Jc`` over the states (None without constraints), and
    ``problems``: what makes the sample degenerate (empty when it is not)."""

    states: int
    q: np.ndarray
    qd: np.ndarray
    u: np.ndarray
    span: np.ndarray
    constraint_rank: tuple[int, int] | None
    problems: tuple[str, ...]

    @property
    def degenerate(self) -> bool:
        return bool(self.problems)


def _ranges(rows: np.ndarray, width: int) -> np.ndarray:
    return np.stack([rows.min(axis=0), rows.max(axis=0)], axis=1) if len(rows) else np.zeros((width, 2))


def _ranks(model: Model, Q: np.ndarray) -> tuple[int, int] | None:
    if not model.constraints or not len(Q):
        return None

    ranks = [int(np.linalg.matrix_rank(constraint_kinematics(model, q, np.zeros(model.nv))[1])) for q in Q]
    return min(ranks), max(ranks)


def _promised(body) -> tuple[float, ...]:
    """The spans promised for the body's coordinates: its joint limits' width where the model declares limits (the
    gate draws within them unless told otherwise; drawn freely, the sample only spans more), else :data:`_SPANS`."""
    return (body.limits[1] - body.limits[0],) if body.limits is not None else _SPANS[body.joint]


def measure(model: Model, states: Sequence[sampling.State]) -> Coverage:
    """The coverage of ``states`` of ``model`` and its problems (module doc)."""
    Q, QD, U = (np.array([getattr(s, name) for s in states], dtype=float).reshape(len(states), size)
                for name, size in (("q", model.nq), ("qd", model.nv), ("u", model.m)))
    span = np.array([span for b in model.bodies for span in _promised(b)])
    ranks = _ranks(model, Q)
    problems = []
    if len(states) >= 2 and not np.any(QD) and not (ranks is not None and ranks[0] == model.n):
        problems.append(f"every joint rate is 0 at all {len(states)} states: the velocity-product terms (Coriolis, "
                        "centrifugal, gyroscopic, Jcdot qd) were never exercised")
    if len(states) >= 2 and model.m and not np.any(U):
        problems.append(f"every input is 0 at all {len(states)} states: the control path (B u, ctrl) was never "
                        "exercised")
    if len(states) >= SLIVER_STATES:
        width = np.ptp(Q, axis=0)
        thin = width < SLIVER * span
        if thin.all() if model.constraints else thin.any():
            owner = [b.name for b in model.bodies for _ in _SPANS[b.joint]]
            which = ", ".join(f"q{i} ({owner[i]}) spans {width[i]:.3g} of {span[i]:.3g}"
                              for i in np.flatnonzero(thin))
            problems.append(f"the configurations lie in a sliver of the joint ranges: {which} (below "
                            f"{SLIVER:g} of the sampling span)")
    return Coverage(len(states), _ranges(Q, model.nq), _ranges(QD, model.nv), _ranges(U, model.m), span, ranks,
                    tuple(problems))
