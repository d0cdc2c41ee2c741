"""Assembling a :class:`~formalisms.interface.Split` for a plugin backend: the scales and conditions a backend must
report, computed from its own M, C qd, g (and Jc, Jcdot qd) by the harness's definitions.

A user's backend (docs/plugins.md) usually has M, C qd and g and solves for the accelerations; what
it does not want to write is the bookkeeping the harness reads: the control power, ``cond(M)`` and ``accel_scale``
(:func:`crosscheck.guards.conditioning.normwise_scales`), and with constraints ``Jc^T lam``, the constraint power, ``Jc
qd`` and the conditioning of ``S = Jc M^-1 Jc^T`` (:func:`crosscheck.guards.conditioning.constraint_conditions`). These
helpers add it. The five formalisms do not use them (``tests/backends/test_independence.py``): each computes every number it
reports itself, so that a bug here cannot move them together.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from cases.model import Model
from crosscheck.guards.conditioning import constraint_conditions, normwise_scales, scales_of
from formalisms.interface import UNSUPPORTED, Split


@dataclass(frozen=True)
class Sizes:
    """What the definition of ``accel_scale`` reads off a model, for a plugin given no crosscheck Model (``needs =
    "source"`` or ``"pinocchio"``, :mod:`crosscheck.needs`): the total mass (kg) and the gravity vector (world, m/s^2)
    of the plugin's own model of the scene. Pass it to :func:`unconstrained_split` in place of the model."""

    mass: float
    gravity: np.ndarray


def unconstrained_split(model: Model | Sizes, *, M, Cqd, g, tau_ctrl, qd, drift, ctrl, total, extras=None,
                        task_drift=UNSUPPORTED, conditions=None, kinetic_energy=UNSUPPORTED,
                        joint_wrenches=UNSUPPORTED, joint_wrenches_drift=UNSUPPORTED,
                        task_inertia=UNSUPPORTED, zvcf=UNSUPPORTED, drift_velocity=UNSUPPORTED,
                        external_force=None) -> Split:
    """The :class:`Split` of an unconstrained model from a backend's drift, ctrl and total and its own M, ``C qd``,
    ``g`` and applied force ``tau_ctrl = B u``: adds the control power ``tau_ctrl . qd`` (per coordinate too),
    ``cond(M)`` and ``accel_scale`` (from the model, or from :class:`Sizes`). The drift's parts ``zvcf`` (``M^-1
    (tau_ext - g)``) and ``drift_velocity`` (``-M^-1 C qd``), each the backend's own solve, and the external loads'
    generalized force ``external_force`` (``tau_ext``, for a model with ``cases.loads``; its power ``tau_ext . qd`` is
    added) are passed through; the fields of :class:`~formalisms.interface.Split` say what each is."""
    M = np.asarray(M, dtype=float)
    if isinstance(model, Sizes):
        cond_M, accel_scale = scales_of(M, Cqd, g, tau_ctrl, qd, model.mass, model.gravity)
    else:
        cond_M, accel_scale = normwise_scales(model, M, Cqd, g, tau_ctrl, qd)
    qd = np.asarray(qd, dtype=float)
    per = np.asarray(tau_ctrl, dtype=float) * qd
    power_ext = None if external_force is None else float(np.asarray(external_force, dtype=float) @ qd)
    return Split(drift=drift, ctrl=ctrl, total=total, lam=None, lam_drift=None, power_ctrl=float(per.sum()),
                 power_ctrl_per_coord=per, power_constr=None, power_constr_per_coord=None, cond_M=cond_M,
                 accel_scale=accel_scale, extras=extras or {}, task_drift=task_drift, conditions=conditions or {},
                 kinetic_energy=kinetic_energy, joint_wrenches=joint_wrenches,
                 joint_wrenches_drift=joint_wrenches_drift, task_inertia=task_inertia, zvcf=zvcf,
                 drift_velocity=drift_velocity, external_force=external_force, power_ext=power_ext)


def constrained_split(model: Model, *, M, Cqd, g, tau_ctrl, qd, phi, Jc, bias, lam, lam_drift, **free) -> Split:
    """The :class:`Split` of a constrained model (eqs. 12-17) from a backend's solve and its own M, ``C qd``, ``g``,
    ``phi``, ``Jc``, ``Jcdot qd``: :func:`unconstrained_split`'s fields, plus ``Jc^T lam`` (and at the drift), the
    constraint power ``(Jc^T lam) . qd`` (per coordinate too, 5.5), ``Jc qd``, and the conditions ``constraint``,
    ``constraint_kept``, ``constraint_consistency``, the rank and ``lam_scale``; ``accel_scale`` includes the
    accelerations the constraint force can produce. ``zvcf`` and ``drift_velocity`` (keywords of
    :func:`unconstrained_split`) are then the KKT solves with ``f = tau_ext - g`` and no bias, and with ``f = -C qd``
    and the bias ``Jcdot qd``."""
    if isinstance(model, Sizes):
        raise TypeError("constrained_split needs crosscheck's Model (its length and inertia scales define the "
                        "constraint conditions): declare needs = 'model', or build the Split's fields yourself")
    Jc, bias = np.asarray(Jc, dtype=float), np.asarray(bias, dtype=float)
    lam, lam_drift = np.asarray(lam, dtype=float).reshape(-1), np.asarray(lam_drift, dtype=float).reshape(-1)
    free_split = unconstrained_split(model, M=M, Cqd=Cqd, g=g, tau_ctrl=tau_ctrl, qd=qd, **free)
    cc = constraint_conditions(model, np.asarray(M, dtype=float), Jc, bias,
                               (tau_ctrl - Cqd - g, -Cqd - g), free_split.accel_scale)
    force = Jc.T @ lam
    return Split(**{**{f: getattr(free_split, f) for f in free_split.__dataclass_fields__},
                    "lam": lam, "lam_drift": lam_drift, "power_constr": float(force @ qd),
                    "power_constr_per_coord": force * qd, "accel_scale": free_split.accel_scale + cc.force_scale,
                    "conditions": {**free_split.conditions, "constraint": cc.cond_S,
                                   "constraint_kept": cc.cond_kept, "constraint_consistency": cc.inconsistency},
                    "constraint_value": phi, "constraint_jacobian": Jc, "constraint_bias": bias,
                    "constraint_velocity": Jc @ qd, "constraint_force": force,
                    "constraint_force_drift": Jc.T @ lam_drift, "constraint_rank": cc.rank,
                    "lam_scale": cc.lam_scale})
