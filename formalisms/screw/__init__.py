"""Screw theory / product of exponentials formalism (article 6.2): twists and wrenches on SE(3).

Modules: :mod:`~formalisms.screw.lie` (SE(3) and se(3): exponentials, logarithms, adjoints),
:mod:`~formalisms.screw.kinematics` (eq. 20 on the tree, space and body Jacobians, twists, bias accelerations)
and :mod:`~formalisms.screw.dynamics` (the wrench recursion of eq. 27, ``M``, ``h``). This module holds the
forward dynamics and the drift–control split (article 6.2.3; eq. 9, 10).

``M``, ``h = C qd + g``, ``C qd`` and ``g`` come from one vectorized pass of the wrench recursion (eq. 27); one
Cholesky factor of ``M`` then gives ``drift = M^-1 (-h)`` (eq. 10, the ZTCF), ``ctrl = M^-1 B u`` and
``total = M^-1 (B u - h)``, each solved on its own.

extras (numpy arrays, row ``i`` = body ``i`` in model order; twists ``(w, v)``, wrenches ``(moment, force)``):

``poses``                  (n, 4, 4) ``T_i``, world <- body ``i`` (eq. 20).
``twists_space``           (n, 6) ``V_s,i = J_s,i qd``: ``[V_s] = Tdot T^-1``, world frame (``v`` is the velocity
                           of the body-fixed point at the world origin).
``twists_body``            (n, 6) ``V_b,i = Ad_{T_i^-1} V_s,i``: ``[V_b] = T^-1 Tdot``, body frame ``i`` (``v`` is
                           the velocity of the body-frame origin).
``accelerations_space``    (n, 6) ``Vdot_s,i = J_s,i qdd + Jdot_s,i qd`` at ``qdd = total``, world frame.
``wrenches_body``          (n, 6) at ``qdd = total``: the wrench the parent exerts on body ``i`` through joint ``i``
                           (gravity included), about body ``i``'s origin, in body frame ``i``.
``wrenches_body_drift``    (n, 6) the same at ``qdd = drift``.
``wrenches_space``         (n, 6) ``F_s,i = Ad_{T_i^-1}^T F_b,i``: ``wrenches_body`` expressed in the world frame
                           (moment about the world origin), so that ``F_s . V_s = F_b . V_b``.

Under a change of world frame by ``g`` (the scene moved rigidly, gravity rotated with it) the space twists and
accelerations map by ``Ad_g``, ``wrenches_space`` by ``Ad_g^-T``, ``poses`` by ``g T``; the body quantities do
not change (article 7.4).
"""

from __future__ import annotations

import numpy as np
import scipy.linalg

from cases.model import Model
from formalisms.interface import (Formalism, Split, check_state, conditioning, factor_mass_matrix,
                                  unconstrained_split)
from formalisms.screw import dynamics, kinematics
from formalisms.screw.kinematics import Kinematics


def _task_drift(kin: Kinematics, qd: np.ndarray, drift: np.ndarray):
    """``D a`` for the default task point at the drift (eq. 23, classical acceleration)."""
    model = kin.model
    tp = model.task_point()
    a = kinematics.point_acceleration(kin, model.body_index(tp.body), tp.offset, qd, drift)
    return tp.directions @ a


def _kinetic_energy(model: Model, twists_body: np.ndarray) -> float:
    """``T = sum_i 1/2 V_b,i^T G_i V_b,i`` with ``G_i`` the spatial inertia in body frame ``i``."""
    G = dynamics.spatial_inertias(model)
    return 0.5 * float(np.einsum("ia,iab,ib->", twists_body, G, twists_body))


def _extras(kin: Kinematics, qd: np.ndarray, total: np.ndarray, drift: np.ndarray) -> dict[str, np.ndarray]:
    """The twists, accelerations and wrenches listed in the module docstring."""
    V_s = kinematics.twists(kin, qd)
    F = dynamics.wrenches(kin, np.column_stack([qd, qd]), np.column_stack([total, drift]), np.ones(2))
    F_body = F[:, 0]
    return {
        "poses": kin.poses,
        "twists_space": V_s,
        "twists_body": (kin.to_body @ V_s[..., None])[..., 0],
        "accelerations_space": kinematics.spatial_accelerations(kin, qd, total),
        "wrenches_body": F_body,
        "wrenches_body_drift": F[:, 1],
        "wrenches_space": (np.swapaxes(kin.to_body, 1, 2) @ F_body[..., None])[..., 0],
    }


def split(model: Model, q, qd, u) -> Split:
    """The drift–control split of eq. (9) in screw coordinates: ``drift = -M^-1 h`` (eq. 10, ZTCF), ``ctrl =
    M^-1 B u`` solved directly, ``total = M^-1 (B u - h)`` solved on its own; ``M`` and ``h`` from eq. (27).

    ``task_drift`` is the classical acceleration of ``model.task_point()`` at the drift, from the body's space
    twist and spatial acceleration (eq. 23). extras: see the module docstring.
    """
    if model.constraints:
        raise NotImplementedError(f"model '{model.name}': the screw backend does not handle constraints yet; "
                                  "constraints arrive with the constraint issue")
    q, qd, u = check_state(model, q, qd, u)
    kin = kinematics.forward_kinematics(model, q)
    M, h, c_qd, g = dynamics.terms(kin, qd)
    factor = factor_mass_matrix(model, M, q)
    tau_ctrl = model.input_map @ u
    drift = scipy.linalg.cho_solve(factor, -h)
    ctrl = scipy.linalg.cho_solve(factor, tau_ctrl)
    total = scipy.linalg.cho_solve(factor, tau_ctrl - h)
    cond_M, accel_scale = conditioning(model, M, c_qd, g, tau_ctrl, qd)
    extras = _extras(kin, qd, total, drift)
    return unconstrained_split(drift=drift, ctrl=ctrl, total=total, tau_ctrl=tau_ctrl, qd=qd, cond_M=cond_M,
                               accel_scale=accel_scale, extras=extras, task_drift=_task_drift(kin, qd, drift),
                               kinetic_energy=_kinetic_energy(model, extras["twists_body"]))


FORMALISM = Formalism(
    name="screw",
    summary="Product of exponentials and screw theory (article 6.2, eqs. 20, 27): twists and wrenches on SE(3)",
    split=split,
)
