"""Task points: where a model's task point can move and the default choice (article 6.3).

The operational-space quantities of a task point ``x_task = D p`` (eq. 22, 23) need a task Jacobian
``J = D dp/dv`` of full row rank: ``Lambda = (J M^-1 J^T)^-1`` exists only then. Two things make ``J`` rank-deficient
at every state, whatever the configuration, and so make the operational-space backend a BREAKDOWN everywhere:

* the point lies on the axis of a revolute joint of its chain (or at the centre of a spherical one): that joint
  moves it not at all, so its column of ``dp/dv`` is zero (a URDF leaf link's origin is its joint's origin);
* a task direction the point can never move in (a planar chain's normal): the rows of ``D`` must lie in the span of
  the point's velocities.

This module is the model language's own point kinematics (from :func:`cases.configuration.poses`), for choosing and
explaining task points; no formalism imports it, each computes its task Jacobian itself.

* :func:`point_jacobian`: ``dp/dv`` (3 x nv, world frame) of a body point at ``q``.
* :func:`axes_through`: the joints whose axis (or centre) the point lies on at every probed configuration.
* :func:`motion_directions`: orthonormal world rows spanning the point's velocities over the probed configurations.
* :func:`choose`: the first candidate point that lies on no axis, with the directions it moves in.
* :func:`default_task_point`: the default of :func:`cases.build.build_model`: the last body's COM, else an offset.
* a model with a task point given as ``BODY[:x,y,z]`` (CLI ``--task-point``): ``cases.build.with_task_point``.
* :func:`rank_deficiency`: why a model's task Jacobian is rank-deficient at ``q``, in words, or None.
"""

from __future__ import annotations

import dataclasses
import math
from typing import Sequence

import numpy as np

from cases import configuration
from cases.model import Model, TaskPoint

#: A column of ``dp/dv`` shorter than this times the model's length scale is zero (the point is on that axis): far
#: above rounding (1e-16 L) and far below any lever of physical size.
ON_AXIS = 1e-9
#: Configurations probed: the neutral one and this many drawn with a fixed seed (angles in +-pi, displacements in
#: +-half the length scale), so that a point on an axis at one configuration only (a singularity) is not flagged.
PROBES = 3
_SEED = 20
#: Offsets tried, in this order, after the declared candidates: the body's COM and its origin moved along each body
#: axis by this fraction of the model's length scale.
OFFSET_FRACTION = 0.1


def _chain(model: Model, body: int) -> list[int]:
    """The bodies from ``body`` up to the root (``body`` first)."""
    out = []
    while body >= 0:
        out.append(body)
        body = model.parent_index[body]
    return out


def point_jacobian(model: Model, q, body: str, offset) -> np.ndarray:
    """``dp/dv`` (3 x nv) of the point ``offset`` (body frame) of ``body`` at ``q``, in the world frame: ``pdot = J v``.

    Column of joint ``j`` with world rotation ``R_j`` and origin ``o_j`` of its body, ``r = p - o_j``: revolute
    ``(R_j a) x r``, prismatic ``R_j a`` (``a`` the axis), spherical ``R_j e_k x r`` (body-frame angular velocity),
    free ``R_j e_k`` (body-frame linear velocity) then ``R_j e_k x r``.
    """
    poses = configuration.poses(model, q)
    i = model.body_index(body)
    R_b, o_b = poses[i]
    p = o_b + R_b @ np.asarray(offset, dtype=float)
    J = np.zeros((3, model.nv))
    for j in _chain(model, i):
        b, (R, o), iv = model.bodies[j], poses[j], model.v_index[j]
        r = p - o
        if b.joint == "revolute":
            J[:, iv] = np.cross(R @ b.axis, r)
        elif b.joint == "prismatic":
            J[:, iv] = R @ b.axis
        elif b.joint == "spherical":
            J[:, iv:iv + 3] = np.cross(R.T, r).T
        else:
            J[:, iv:iv + 3] = R
            J[:, iv + 3:iv + 6] = np.cross(R.T, r).T
    return J


def probes(model: Model) -> list[np.ndarray]:
    """The configurations :func:`axes_through` and :func:`motion_directions` look at (:data:`PROBES`)."""
    rng = np.random.default_rng(_SEED)
    drawn = [configuration.random_configuration(model, rng, math.pi, 0.5 * model.length_scale) for _ in range(PROBES)]
    return [configuration.neutral(model)] + drawn


def _columns_on_axis(model: Model, J: np.ndarray, body: int) -> list[str]:
    """The joints of ``body``'s chain whose every rotational column of ``J`` is zero (module docstring)."""
    floor = ON_AXIS * model.length_scale
    out = []
    for j in _chain(model, body):
        b, iv = model.bodies[j], model.v_index[j]
        if b.joint == "revolute" and np.linalg.norm(J[:, iv]) <= floor:
            out.append(f"the axis of joint '{b.name}'")
        elif b.joint == "spherical" and np.linalg.norm(J[:, iv:iv + 3]) <= floor:
            out.append(f"the centre of the ball joint '{b.name}'")
    return out


def axes_through(model: Model, body: str, offset, qs: Sequence[np.ndarray] | None = None) -> list[str]:
    """The joints of the point's chain whose axis (revolute) or centre (spherical) the point lies on at every
    configuration of ``qs`` (default :func:`probes`), as phrases ("the axis of joint 'link2'"), root-most last."""
    qs = probes(model) if qs is None else qs
    i = model.body_index(body)
    found = [_columns_on_axis(model, point_jacobian(model, q, body, offset), i) for q in qs]
    return [phrase for phrase in found[0] if all(phrase in other for other in found[1:])] if found else []


def _canonical(basis: np.ndarray) -> np.ndarray:
    """Orthonormal rows spanning the same subspace as the orthonormal rows ``basis``, built from the coordinate axes'
    projections onto it (largest first, Gram-Schmidt), so that a plane of two coordinate axes is given by those axes
    exactly (stable digests, readable reports), in axis order."""
    P = basis.T @ basis
    order = sorted(range(3), key=lambda k: -np.linalg.norm(P[:, k]))
    rows: list[tuple[int, np.ndarray]] = []
    for k in order:
        v = P[:, k] - sum((P[:, k] @ r) * r for _, r in rows)
        if len(rows) < len(basis) and np.linalg.norm(v) > 1e-6:
            v = v / np.linalg.norm(v)
            m = int(np.argmax(np.abs(v)))
            v = -v if v[m] < 0 else v
            axis = np.eye(3)[m]
            rows.append((k, axis if np.abs(v - axis).max() <= 1e-12 else v))
    return np.array([r for _, r in sorted(rows, key=lambda kr: kr[0])])


def motion_directions(model: Model, body: str, offset, qs: Sequence[np.ndarray] | None = None,
                      at_once: bool = False) -> np.ndarray:
    """Orthonormal world rows (r x 3, r <= 3) along which the point moves over ``qs`` (default :func:`probes`): the
    left singular vectors of ``[J(q_1) ... J(q_K)]`` above ``ON_AXIS`` times its largest singular value, rewritten
    from the coordinate axes (:func:`_canonical`). All three axes for a point that moves in space; the plane of a
    planar chain; none (0 x 3) for a point that never moves. ``at_once``: no more rows than the point moves in at
    any one configuration (the leading singular directions), for a point whose velocities span more directions
    over the configurations than at any one of them (two joints moving a point in space: a plane that turns), so
    that its task Jacobian ``D J`` can have full row rank."""
    qs = probes(model) if qs is None else qs
    jacobians = [point_jacobian(model, q, body, offset) for q in qs]
    U, s, _ = np.linalg.svd(np.hstack(jacobians))
    if s.size == 0 or s[0] <= ON_AXIS * model.length_scale:
        return np.zeros((0, 3))
    r = int(np.sum(s > ON_AXIS * s[0]))
    if at_once:
        r = min(r, max(_rank(model, J) for J in jacobians))
    return np.eye(3) if r == 3 else _canonical(U[:, :r].T)


def _rank(model: Model, J: np.ndarray) -> int:
    """The rank of a task Jacobian, singular values above ``ON_AXIS`` times the model's length scale."""
    s = np.linalg.svd(J, compute_uv=False)
    return int(np.sum(s > ON_AXIS * model.length_scale)) if s.size else 0


def full_rank(model: Model, body: str, offset, directions: np.ndarray, qs: Sequence[np.ndarray] | None = None) -> bool:
    """Whether ``directions @ dp/dv`` has full row rank at some configuration of ``qs`` (default :func:`probes`): not
    rank-deficient at every state (a singular configuration, such as a stretched chain, is one where it is)."""
    qs = probes(model) if qs is None else qs
    D = np.asarray(directions, dtype=float)
    return any(_rank(model, D @ point_jacobian(model, q, body, offset)) == len(D) for q in qs)


def _candidates(model: Model, body: str) -> list[tuple[np.ndarray, str]]:
    """(offset, how it was chosen) for ``body``: its COM, then its origin moved along each of its axes."""
    b = model.bodies[model.body_index(body)]
    step = OFFSET_FRACTION * model.length_scale
    out = [(np.array(b.com, dtype=float), f"the centre of mass of body '{body}'")]
    for k, axis in enumerate("xyz"):
        offset = np.zeros(3)
        offset[k] = step
        out.append((np.array(b.com) + offset, f"the centre of mass of body '{body}' moved {step:.3g} m along its "
                                              f"{axis} axis"))
    return out


def choose(model: Model, candidates: Sequence[TaskPoint], reasons: Sequence[str] = (),
           name: str | None = None) -> TaskPoint:
    """The first of ``candidates`` (then the COM and offsets of each candidate's body, :func:`_candidates`) whose task
    Jacobian has full row rank at a generic configuration (:func:`full_rank`) in the task directions it moves in
    (:func:`motion_directions`), with a ``choice`` saying how it was chosen and what was passed over and why (the
    joint axes it lies on, :func:`axes_through`). A point on a joint axis whose other joints still move it in every
    direction (a tool centre point on a wrist's axis) is kept: its task-space inertia exists. ``reasons[k]``
    describes candidate ``k`` ("the URDF leaf link 'tool'"). Without such a point, the candidate that moves in the
    most directions. A point with no such directions, moving in fewer at once than over its configurations (two
    joints in space), gets the directions it moves in at once (``motion_directions(at_once=True)``) when they give
    full rank. The point is named ``name``, else as its candidate (``BODY:com``, ``BODY:offset`` for the
    points added)."""
    qs = probes(model)
    tried: list[str] = []
    fallback, turning = None, None
    pool = [(tp, reasons[k] if k < len(reasons) else f"task point '{tp.name}'") for k, tp in enumerate(candidates)]
    for tp in candidates:
        pool += [(TaskPoint(f"{tp.body}:com" if k == 0 else f"{tp.body}:offset", tp.body, offset), how)
                 for k, (offset, how) in enumerate(_candidates(model, tp.body))]
    seen: list[tuple[str, np.ndarray]] = []
    for tp, how in pool:
        if any(body == tp.body and np.array_equal(offset, tp.offset) for body, offset in seen):
            continue
        seen.append((tp.body, np.asarray(tp.offset)))
        tp = tp if name is None else TaskPoint(name, tp.body, tp.offset)
        D = motion_directions(model, tp.body, tp.offset, qs)
        if len(D) and full_rank(model, tp.body, tp.offset, D, qs):
            note = f"; passed over: {'; '.join(tried)}" if tried else ""
            return TaskPoint(tp.name, tp.body, tp.offset, D, choice=f"default: {how}{note}")
        on = axes_through(model, tp.body, tp.offset, qs)
        tried.append(f"{how} (on {' and '.join(on)})" if on else f"{how} (its task Jacobian is rank-deficient "
                     "everywhere)" if len(D) else f"{how} (it does not move)")
        once = motion_directions(model, tp.body, tp.offset, qs, at_once=True)
        if len(once) and len(once) < len(D) and full_rank(model, tp.body, tp.offset, once, qs) and (
                turning is None or len(once) > len(turning[0].directions)):
            turning = TaskPoint(tp.name, tp.body, tp.offset, once), how
        if fallback is None or len(D) > len(fallback.directions):
            fallback = TaskPoint(tp.name, tp.body, tp.offset, D if len(D) else np.eye(3),
                                 choice=f"default: {how}, although every candidate is degenerate: {'; '.join(tried)}")
    if turning is not None:
        point, how = turning
        return dataclasses.replace(point, choice=f"default: {how}, in the {len(point.directions)} directions it moves "
                                                 f"in at once (its chain turns them: more over its configurations); "
                                                 f"in all the directions they move in: {'; '.join(tried)}")
    return fallback


def default_task_point(model: Model) -> TaskPoint:
    """The default task point ``tip`` of a model built without one: the COM of the last body, unless it lies on a
    joint axis, then an offset point of that body (:func:`choose`)."""
    last = model.bodies[-1]
    return choose(model, [TaskPoint("tip", last.name, np.array(last.com))],
                  [f"the centre of mass of the last body '{last.name}'"], name="tip")


def rank_deficiency(model: Model, q) -> str | None:
    """Why the default task point's Jacobian ``D dp/dv`` has rank below its number of rows at ``q``, in words ("task
    Jacobian rank 1 < 2: the point lies on the axis of joint 'link2'"), or None when it has full row rank."""
    tp = model.task_point()
    J = tp.directions @ point_jacobian(model, q, tp.body, tp.offset)
    d = J.shape[0]
    rank = _rank(model, J)
    if rank >= d:
        return None
    causes = [f"the point lies on {p}" for p in axes_through(model, tp.body, tp.offset, [np.asarray(q, float)])]
    moves = motion_directions(model, tp.body, tp.offset)
    if len(moves) < d:
        causes.append(f"the point moves in {len(moves)} direction(s) only, the task has {d} (directions "
                      f"{np.round(tp.directions, 6).tolist()})")
    if not causes:
        causes.append("a singular configuration (the chain stretched or folded)")
    return f"task Jacobian rank {rank} < {d}: {'; '.join(causes)}"
