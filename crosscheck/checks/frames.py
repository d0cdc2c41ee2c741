"""Frame changes (article 7.4; docs/design.md, frames): the whole scene moved by a rigid transform g.

Moving the scene by ``g = (R, t)`` (world points ``x -> R x + t``) changes nothing physical: the root bodies'
placements become ``g * placement``, gravity rotates with the scene (``R gravity``), and the task directions
rotate too (``D R^T``), so the task is the same task on the moved scene. The constraints' world data move with it
(centres, line origins and ground points by g, planes, directions and normals by ``D R^T``), so every ``phi`` is
the same function of q. A model loaded from a file keeps its ``source`` with the file's world placement composed
with g, so the reference built from the file sees the same moved scene. Under it

    joint accelerations, inputs, multipliers, power, kinetic energy   are invariant,
    twists (w, v) in the world frame                                  map by Ad_g,
    wrenches (moment, force) in the world frame                       map by Ad_g^-T,
    world-frame task accelerations                                    rotate by R,

while quantities in body frames do not change. The adjoints here are the harness's own, written from their
block form, so a frame check never uses the code it checks.
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass

import numpy as np

import cases
from cases.model import Model
from crosscheck.core.sampling import case_rng


@dataclass(frozen=True)
class Frame:
    """A rigid transform ``g``: rotation R (3x3) and translation t (3), with a label for reports."""

    name: str
    rotation: np.ndarray
    translation: np.ndarray

    @property
    def matrix(self) -> np.ndarray:
        g = np.eye(4)
        g[:3, :3], g[:3, 3] = self.rotation, self.translation
        return g


def _hat(v: np.ndarray) -> np.ndarray:
    return np.array([[0.0, -v[2], v[1]], [v[2], 0.0, -v[0]], [-v[1], v[0], 0.0]])


def random_rotation(rng: np.random.Generator) -> np.ndarray:
    """A uniformly distributed rotation (a normalized Gaussian quaternion)."""
    w, x, y, z = (quat := rng.standard_normal(4)) / np.linalg.norm(quat)
    return np.array([[1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y)],
                     [2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x)],
                     [2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)]])


def sampled(seed: int, case: str, count: int = 2, reach: float = 1.0) -> list[Frame]:
    """``count`` rigid transforms, uniform rotations and translations in +-``reach`` m, seeded by (seed, case)."""
    rng = case_rng(seed, case + "/frames")
    return [Frame(f"g{k}", random_rotation(rng), rng.uniform(-reach, reach, 3)) for k in range(count)]


def rotate_gravity(frame: Frame, gravity: np.ndarray) -> np.ndarray:
    """Gravity is a world vector: it turns with the scene."""
    return frame.rotation @ gravity


def move_scene(model: Model, frame: Frame) -> Model:
    """The same scene moved by ``frame``: root placements ``g * placement``, gravity and task directions rotated, the
    external loads' world data moved (:func:`move_load`), and a file source's world placement ``g * placement``
    (``ModelSource.moved``)."""
    R, t = frame.rotation, frame.translation
    bodies = [dataclasses.replace(b, rotation=R @ b.rotation, translation=R @ b.translation + t)
              if b.parent is None else b for b in model.bodies]
    task_points = [dataclasses.replace(tp, directions=tp.directions @ R.T) for tp in model.task_points]
    constraints = [move_constraint(c, frame) for c in model.constraints]
    source = None if model.source is None else model.source.moved(R, t)
    return cases.build_model(f"{model.name}@{frame.name}", bodies, gravity=rotate_gravity(frame, model.gravity),
                             input_map=model.input_map, task_points=task_points, constraints=constraints,
                             source=source, loads=[move_load(load, frame) for load in model.loads])


def move_load(load, frame: Frame):
    """An external load declaration (``cases.loads``) on the moved scene: a world-frame force and couple turn by R, a
    spring's world anchor moves by g; body-frame data (offsets, body-frame forces) do not change."""
    R, t = frame.rotation, frame.translation
    if isinstance(load, cases.PointSpring):
        return dataclasses.replace(load, anchor=R @ load.anchor + t)
    if load.frame == "body":
        return load
    if isinstance(load, cases.ExternalWrench):
        return dataclasses.replace(load, force=R @ load.force, moment=R @ load.moment)
    return dataclasses.replace(load, force=R @ load.force)


def move_constraint(c, frame: Frame):
    """A constraint declaration on the moved scene: world points by g, world direction rows (a PointVelocity's
    directions, a RollingContact's ground plane) by ``D R^T``."""
    R, t = frame.rotation, frame.translation
    if isinstance(c, cases.PointOnCircle):
        return dataclasses.replace(c, center=R @ c.center + t, plane=c.plane @ R.T)
    if isinstance(c, cases.PointsCoincide):
        ground = c.offset_b if c.body_b is not None else R @ c.offset_b + t
        return dataclasses.replace(c, offset_b=ground, directions=c.directions @ R.T)
    if isinstance(c, cases.PointOnLine):
        return dataclasses.replace(c, origin=R @ c.origin + t, normals=c.normals @ R.T)
    if isinstance(c, cases.PointVelocity):
        return dataclasses.replace(c, directions=c.directions @ R.T)
    if isinstance(c, cases.RollingContact):    # the ground plane's tangents turn; its centre and axis are body data
        # (a lateral=False contact's direction t = (a x n) / |a x n| turns with them: its lam is frame-invariant)
        return dataclasses.replace(c, plane=c.plane @ R.T)
    return c                                   # a joint coupling or a knife edge (body-fixed) involves no world data


def twist_map(frame: Frame) -> np.ndarray:
    """``Ad_g`` for twists ``(w, v)``: ``w' = R w``, ``v' = t x (R w) + R v``."""
    R, T = frame.rotation, _hat(frame.translation)
    return np.block([[R, np.zeros((3, 3))], [T @ R, R]])


def wrench_map(frame: Frame) -> np.ndarray:
    """``Ad_g^-T`` for wrenches ``(moment, force)``: ``f' = R f``, ``n' = R n + t x (R f)`` (the moment about the
    moved origin), so that the power ``F' . V' = F . V`` is unchanged."""
    R, T = frame.rotation, _hat(frame.translation)
    return np.block([[R, T @ R], [np.zeros((3, 3)), R]])


def force_moment_map(frame: Frame) -> np.ndarray:
    """:func:`wrench_map` for rows ordered ``(force, moment)`` (the Newton–Euler joint reactions)."""
    swap = np.block([[np.zeros((3, 3)), np.eye(3)], [np.eye(3), np.zeros((3, 3))]])
    return swap @ wrench_map(frame) @ swap
