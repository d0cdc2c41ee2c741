"""The same scene, modelled with general 3-D body frames (docs/performance.md, "Model no more than a scene needs").

The case factories build the smallest model of a scene: planar chains with joint axes along z, point masses where
the article uses them, placements along one axis. :func:`general_3d` rebuilds a model with every body frame turned
by a rotation ``R_i``: the joint axes become unaligned, the placements rotated, COM offsets and inertia tensors
dense. The joint coordinates and the physics are unchanged, so every backend must return the same drift, ctrl,
total and lam (to rounding); only the work the model lets a backend skip differs.

With the joint frame ``J' = J R_i`` and axis ``R_i^T a``, the body frame becomes ``B' = B R_i`` for any q (a rotation
about ``R_i^T a`` seen in ``J R_i`` is the rotation about ``a`` in ``J``); a child's placement, expressed in ``B'``,
is ``(R_p^T rotation R_i, R_p^T translation)``; body-fixed points (COM, task points, constrained points) turn by
``R_i^T`` (a knife edge's direction, a rolling disk's centre and axle too), inertias by ``R_i^T I R_i``, and so do
the external loads' offsets and body-frame vectors. World-fixed data (gravity, circle centres, lines, task directions,
a rolling contact's ground plane, world-frame loads, spring anchors) stay.

A body on a spherical or free joint keeps its frame (``R_i = I``): its coordinates are its orientation (and position)
in the joint frame and its velocities are body-frame components (``cases.model``), so turning the frame would change
what a state means. Its children's placements still turn with their own frames.
"""

from __future__ import annotations

import dataclasses

import numpy as np

from cases import constraints as decl
from cases.build import build_model
from cases.model import Model


def _rotation(rng: np.random.Generator) -> np.ndarray:
    """A uniformly random rotation (QR of a Gaussian matrix, signs fixed so that det = +1)."""
    Q, R = np.linalg.qr(rng.standard_normal((3, 3)))
    Q = Q * np.sign(np.diag(R))
    return Q if np.linalg.det(Q) > 0 else -Q


def _turn_constraint(c, turn: dict):
    """A constraint declaration with its body-fixed offsets turned into the new body frames."""
    if isinstance(c, (decl.PointOnCircle, decl.PointOnLine, decl.PointVelocity)):
        return dataclasses.replace(c, offset=turn[c.body].T @ c.offset)
    if isinstance(c, decl.KnifeEdge):            # its direction is body-fixed too
        return dataclasses.replace(c, offset=turn[c.body].T @ c.offset, direction=turn[c.body].T @ c.direction)
    if isinstance(c, decl.RollingContact):       # centre and axle are body-fixed; the ground plane is world data
        return dataclasses.replace(c, center=turn[c.body].T @ c.center, axis=turn[c.body].T @ c.axis)
    if isinstance(c, decl.PointsCoincide):
        offset_b = c.offset_b if c.body_b is None else turn[c.body_b].T @ c.offset_b
        return dataclasses.replace(c, offset_a=turn[c.body_a].T @ c.offset_a, offset_b=offset_b)
    return c


def _turn_load(load, turn: dict):
    """An external load (``cases.loads``) on the turned bodies: its offset, and a body-frame force or couple, by
    ``R^T``; world data stay."""
    R = turn[load.body]
    moved = {"offset": R.T @ load.offset}
    if getattr(load, "frame", "world") == "body":
        moved["force"] = R.T @ load.force
        if hasattr(load, "moment"):
            moved["moment"] = R.T @ load.moment
    return dataclasses.replace(load, **moved)


def general_3d(model: Model, seed: int = 0) -> Model:
    """``model`` with every body frame turned by a random rotation (module doc): the same physics in the same
    joint coordinates, written as general 3-D bodies. Deterministic for a given seed."""
    rng = np.random.default_rng(seed)
    turn = {b.name: _rotation(rng) for b in model.bodies}
    turn.update({model.bodies[i].name: np.eye(3) for i in model.group_joints})     # module doc: states keep meaning
    bodies = []
    for b in model.bodies:
        R, Rp = turn[b.name], (np.eye(3) if b.parent is None else turn[b.parent])
        bodies.append(dataclasses.replace(
            b, axis=R.T @ b.axis, com=R.T @ b.com, inertia=R.T @ b.inertia @ R,
            rotation=Rp.T @ b.rotation @ R, translation=Rp.T @ b.translation))
    tasks = [dataclasses.replace(tp, offset=turn[tp.body].T @ tp.offset) for tp in model.task_points]
    return build_model(f"{model.name} (general 3-D frames)", bodies, gravity=model.gravity,
                       input_map=model.input_map, task_points=tasks,
                       constraints=[_turn_constraint(c, turn) for c in model.constraints],
                       loads=[_turn_load(load, turn) for load in model.loads])
