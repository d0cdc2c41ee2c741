"""Pinocchio as the external reference (DESIGN.md: kept apart from the five formalisms).

:func:`to_pinocchio` builds a ``pinocchio.Model`` from OUR model data (never from a URDF), so the reference
checks the same physics the formalisms see. :func:`split` is the shared ``split`` contract on top of
Pinocchio's ABA / CRBA / RNEA; :data:`REFERENCE` wraps it as a :class:`~formalisms.interface.Formalism`.

Joint order: Pinocchio needs parents before children, so joints are added in ``model.topological_order``;
states and results are permuted in and out, so callers always use our coordinate order.
"""

from __future__ import annotations

import threading
from dataclasses import dataclass

import numpy as np
import pinocchio as pin

from cases.model import Model
from formalisms.interface import Formalism, Split, check_state, conditioning, unconstrained_split

_ALIGNED = {
    ("revolute", 0): pin.JointModelRX, ("revolute", 1): pin.JointModelRY, ("revolute", 2): pin.JointModelRZ,
    ("prismatic", 0): pin.JointModelPX, ("prismatic", 1): pin.JointModelPY, ("prismatic", 2): pin.JointModelPZ,
}
_UNALIGNED = {"revolute": pin.JointModelRevoluteUnaligned, "prismatic": pin.JointModelPrismaticUnaligned}


@dataclass(frozen=True)
class _Compiled:
    model: pin.Model
    order: np.ndarray  # order[k] = our coordinate index of Pinocchio's k-th velocity
    task_frame: int    # frame id of the model's default task point


_CACHE: dict[str, _Compiled] = {}
_LOCK = threading.Lock()


def _joint_model(joint: str, axis: np.ndarray):
    for k in range(3):
        unit = np.zeros(3)
        unit[k] = 1.0
        if np.array_equal(axis, unit):
            return _ALIGNED[(joint, k)]()
    return _UNALIGNED[joint](np.array(axis, dtype=float))


def _build(model: Model) -> _Compiled:
    pm = pin.Model()
    pm.name = model.name
    joint_id = {}
    for i in model.topological_order:
        b = model.bodies[i]
        parent = 0 if model.parent_index[i] < 0 else joint_id[model.parent_index[i]]
        placement = pin.SE3(np.array(b.rotation), np.array(b.translation))
        jid = pm.addJoint(parent, _joint_model(b.joint, b.axis), placement, b.name)
        pm.appendBodyToJoint(jid, pin.Inertia(float(b.mass), np.array(b.com), np.array(b.inertia)), pin.SE3.Identity())
        joint_id[i] = jid
    pm.gravity = pin.Motion(np.array(model.gravity), np.zeros(3))
    order = np.empty(model.n, dtype=int)
    for i, jid in joint_id.items():
        order[pm.joints[jid].idx_v] = i
    tp = model.task_point()
    task_frame = pm.addFrame(pin.Frame(f"task:{tp.name}", joint_id[model.body_index(tp.body)],
                                       pin.SE3(np.eye(3), np.array(tp.offset)), pin.FrameType.OP_FRAME))
    return _Compiled(pm, order, task_frame)


def _compiled(model: Model) -> _Compiled:
    key = model.digest()
    with _LOCK:
        hit = _CACHE.get(key)
        if hit is None:
            hit = _CACHE[key] = _build(model)
    return hit


def to_pinocchio(model: Model) -> pin.Model:
    """A ``pinocchio.Model`` of ``model`` (cached by ``model.digest()``; joint k = ``model.topological_order[k]``).

    Treat it as read-only: it is shared between calls.
    """
    return _compiled(model).model


def _sym(upper: np.ndarray) -> np.ndarray:
    """Pinocchio fills only the upper triangle of M (crba) and M^-1 (computeMinverse)."""
    return np.triu(upper) + np.triu(upper, 1).T


def split(model: Model, q, qd, u) -> Split:
    """Drift / control / total accelerations from Pinocchio (ABA twice, ``M^-1 B u`` from computeMinverse);
    task drift from the classical acceleration of a frame at the default task point (getFrameClassicalAcceleration)."""
    q, qd, u = check_state(model, q, qd, u)
    if model.constraints:
        raise NotImplementedError("the Pinocchio reference handles unconstrained models only (no KKT solve yet)")
    c = _compiled(model)
    pm, order = c.model, c.order
    data = pm.createData()  # fresh Data: the result cannot depend on call history
    tau_ctrl = model.input_map @ u
    qp, vp, tp = q[order], qd[order], tau_ctrl[order]
    zero = np.zeros(model.n)

    total_p = np.array(pin.aba(pm, data, qp, vp, tp))
    drift_p = np.array(pin.aba(pm, data, qp, vp, zero))
    pin.forwardKinematics(pm, data, qp, vp, drift_p)
    task_accel = pin.getFrameClassicalAcceleration(pm, data, c.task_frame, pin.LOCAL_WORLD_ALIGNED).linear
    Minv_p = _sym(np.array(pin.computeMinverse(pm, data, qp)))
    M_p = _sym(np.array(pin.crba(pm, data, qp)))
    g_p = np.array(pin.computeGeneralizedGravity(pm, data, qp))
    Cqd_p = np.array(pin.rnea(pm, data, qp, vp, zero)) - g_p

    def ours(vec_p):
        out = np.empty(model.n)
        out[order] = vec_p
        return out

    Minv = np.empty((model.n, model.n))
    Minv[np.ix_(order, order)] = Minv_p
    M = np.empty((model.n, model.n))
    M[np.ix_(order, order)] = M_p
    ctrl = Minv @ tau_ctrl
    Cqd, g = ours(Cqd_p), ours(g_p)
    cond_M, accel_scale = conditioning(model, M, Cqd, g, tau_ctrl, qd)
    return unconstrained_split(drift=ours(drift_p), ctrl=ctrl, total=ours(total_p), tau_ctrl=tau_ctrl, qd=qd,
                               cond_M=cond_M, accel_scale=accel_scale,
                               extras={"M": M, "Cqd": Cqd, "g": g},
                               task_drift=model.task_point().directions @ np.array(task_accel),
                               kinetic_energy=float(pin.computeKineticEnergy(pm, data, qp, vp)))


REFERENCE = Formalism(
    name="pinocchio",
    summary="External reference: Pinocchio's ABA (total, drift), computeMinverse (ctrl), CRBA/RNEA (conditioning), "
            "built from our model data",
    split=split,
)

__all__ = ["REFERENCE", "split", "to_pinocchio"]
