"""The configuration space of a model as a product of groups (article 2.1-2.2, 6.4: the globe, not the map).

Revolute and prismatic coordinates are real numbers; a spherical joint's block is a unit quaternion
``(x, y, z, w)`` (SO(3)) and a free joint's ``(p, x, y, z, w)`` (SE(3)); ``cases.model`` gives the conventions,
Pinocchio's. This module is the model language's own geometry, for the harness (sampling, projection onto
constraints, charts of the orientation): no formalism imports it, each forms its rotations itself.

* :func:`neutral`: the home configuration (zero joint values, identity orientations, base at the origin).
* :func:`integrate`: ``q (+) v`` with the velocity applied for unit time in the body frame, Pinocchio's
  ``integrate``: ``R exp([w]x)`` for a spherical joint and ``X exp(twist)`` on SE(3) for a free joint.
* :func:`random_configuration`: joint values uniform in their ranges and orientations uniform on SO(3) (Haar
  measure: a normalized 4-D Gaussian).
* :func:`quaternion_problems`: which quaternions of a state are not unit, for the state validators.
* :func:`poses`: every body frame's world rotation and origin at q (forward kinematics, for placing scenes).
"""

from __future__ import annotations

import numpy as np

from cases.model import Model

#: A state's quaternion is unit when ``| |quat| - 1 |`` is at most this: a quaternion normalized in float has an
#: error of a few eps; a quaternion typed with 6 digits is refused (normalize it, or pass the explicit flag).
UNIT_TOL = 1e-12


def quaternion_slices(model: Model) -> list[tuple[int, slice]]:
    """(body index, slice of q) of every quaternion in the configuration."""
    out = []
    for i in model.group_joints:
        start = model.q_index[i] + (3 if model.bodies[i].joint == "free" else 0)
        out.append((i, slice(start, start + 4)))
    return out


def neutral(model: Model) -> np.ndarray:
    """The home configuration: zero joint values, identity quaternions ``(0, 0, 0, 1)``, free bases at the origin."""
    q = np.zeros(model.nq)
    for _, sl in quaternion_slices(model):
        q[sl.stop - 1] = 1.0
    return q


def quaternion_problems(model: Model, q: np.ndarray) -> list[str]:
    """One line per quaternion of ``q`` that is not unit to :data:`UNIT_TOL`, naming its body and norm."""
    problems = []
    for i, sl in quaternion_slices(model):
        norm = float(np.linalg.norm(q[sl]))
        if not abs(norm - 1.0) <= UNIT_TOL:
            problems.append(f"the quaternion (x, y, z, w) of body '{model.bodies[i].name}' (q[{sl.start}:{sl.stop}] "
                            f"= {q[sl].tolist()}) has norm {norm!r}, not 1 (to {UNIT_TOL:g}); a rotation needs a "
                            "unit quaternion: divide it by its norm")
    return problems


def normalized(model: Model, q) -> np.ndarray:
    """``q`` with every quaternion divided by its norm (the explicit normalization; a zero quaternion is an error)."""
    q = np.array(q, dtype=float)
    for i, sl in quaternion_slices(model):
        norm = np.linalg.norm(q[sl])
        if not norm > 0.0:
            raise ValueError(f"the quaternion of body '{model.bodies[i].name}' is zero and has no direction")
        q[sl] = q[sl] / norm
    return q


def hat(w: np.ndarray) -> np.ndarray:
    """The cross-product matrix: ``hat(w) @ x = w x x``."""
    return np.array([[0.0, -w[2], w[1]], [w[2], 0.0, -w[0]], [-w[1], w[0], 0.0]])


def quaternion_product(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Hamilton product of quaternions in ``(x, y, z, w)`` order: the rotation ``R(a) R(b)``."""
    va, wa, vb, wb = a[:3], a[3], b[:3], b[3]
    return np.concatenate([wa * vb + wb * va + np.cross(va, vb), [wa * wb - va @ vb]])


def quaternion_exp(w: np.ndarray) -> np.ndarray:
    """The unit quaternion of the rotation ``exp([w]x)`` (angle ``|w|`` about ``w / |w|``), series near 0."""
    theta = float(np.linalg.norm(w))
    half = 0.5 * theta
    if theta < 1e-4:
        s = 0.5 - theta**2 / 48.0
        return np.concatenate([s * w, [1.0 - half**2 / 2.0 + half**4 / 24.0]])
    return np.concatenate([np.sin(half) / theta * w, [np.cos(half)]])


def rotation(quat: np.ndarray) -> np.ndarray:
    """``R(quat)`` of a unit quaternion ``(x, y, z, w)``."""
    K = hat(quat[:3])
    return np.eye(3) + 2.0 * quat[3] * K + 2.0 * K @ K


def _se3_translation(w: np.ndarray, v: np.ndarray) -> np.ndarray:
    """The translation of ``exp`` of the twist ``(v, w)``: ``V(w) v`` with ``V = I + (1 - cos t)/t^2 [w]x + (t - sin
    t)/t^3 [w]x^2`` (Lynch & Park 3.88), series near 0."""
    theta = float(np.linalg.norm(w))
    K = hat(w)
    if theta < 1e-4:
        a, b = 0.5 - theta**2 / 24.0, 1.0 / 6.0 - theta**2 / 120.0
    else:
        a, b = (1.0 - np.cos(theta)) / theta**2, (theta - np.sin(theta)) / theta**3
    return (np.eye(3) + a * K + b * K @ K) @ v


def integrate(model: Model, q, v) -> np.ndarray:
    """``q (+) v``: each joint moved by its velocity block for unit time (module doc; Pinocchio's ``integrate``)."""
    q, v = np.array(q, dtype=float), np.asarray(v, dtype=float)
    out = q.copy()
    for i, b in enumerate(model.bodies):
        iq, iv = model.q_index[i], model.v_index[i]
        if b.joint == "spherical":
            out[iq:iq + 4] = quaternion_product(q[iq:iq + 4], quaternion_exp(v[iv:iv + 3]))
        elif b.joint == "free":
            quat = q[iq + 3:iq + 7]
            out[iq:iq + 3] = q[iq:iq + 3] + rotation(quat) @ _se3_translation(v[iv + 3:iv + 6], v[iv:iv + 3])
            out[iq + 3:iq + 7] = quaternion_product(quat, quaternion_exp(v[iv + 3:iv + 6]))
        else:
            out[iq] = q[iq] + v[iv]
    return out


def _axis_rotation(axis: np.ndarray, angle: float) -> np.ndarray:
    K = hat(axis)
    return np.eye(3) + np.sin(angle) * K + (1.0 - np.cos(angle)) * K @ K


def poses(model: Model, q) -> list[tuple[np.ndarray, np.ndarray]]:
    """World (rotation, origin) of every body frame at ``q``: ``X_body = X_parent * (rotation, translation) *
    motion(q_i)`` (``cases.model``), parents first. For scene factories that place world points (a foot's contact)
    at a configuration; the harness's kinematics for checks are Pinocchio's
    (``crosscheck.references.pinocchio.kinematics``)."""
    q = np.asarray(q, dtype=float)
    out: list = [None] * len(model.bodies)
    for i in model.topological_order:
        b, parent, iq = model.bodies[i], model.parent_index[i], model.q_index[i]
        R, p = (np.eye(3), np.zeros(3)) if parent < 0 else out[parent]
        R, p = R @ b.rotation, R @ b.translation + p
        if b.joint == "revolute":
            R = R @ _axis_rotation(b.axis, q[iq])
        elif b.joint == "prismatic":
            p = p + R @ (b.axis * q[iq])
        elif b.joint == "spherical":
            R = R @ rotation(q[iq:iq + 4])
        else:
            p, R = p + R @ q[iq:iq + 3], R @ rotation(q[iq + 3:iq + 7])
        out[i] = (R, p)
    return out


def random_quaternion(rng: np.random.Generator) -> np.ndarray:
    """A unit quaternion uniform on SO(3) (Haar measure), with ``w >= 0``."""
    g = rng.standard_normal(4)
    g = g / np.linalg.norm(g)
    return -g if g[3] < 0.0 else g


def random_configuration(model: Model, rng: np.random.Generator, angle: float, displacement: float) -> np.ndarray:
    """Revolute angles uniform in ``+-angle`` and prismatic displacements uniform in ``+-displacement``, drawn
    together (one draw of all of them, as before group joints existed, so that their states do not change), then per
    group joint, in body order: a free base's position uniform in ``+-displacement`` and an orientation uniform on
    SO(3)."""
    q = neutral(model)
    scalar = [i for i, b in enumerate(model.bodies) if b.joint not in ("spherical", "free")]
    span = np.array([angle if model.bodies[i].joint == "revolute" else displacement for i in scalar])
    q[[model.q_index[i] for i in scalar]] = rng.uniform(-span, span)
    for i in model.group_joints:
        iq = model.q_index[i]
        if model.bodies[i].joint == "free":
            q[iq:iq + 3] = rng.uniform(-displacement, displacement, 3)
            iq += 3
        q[iq:iq + 4] = random_quaternion(rng)
    return q
