"""Screw theory / product of exponentials formalism (article 6.2): twists and wrenches on SE(3).

Modules: :mod:`~formalisms.screw.lie` (SE(3) and se(3): exponentials, logarithms, adjoints),
:mod:`~formalisms.screw.kinematics` (eq. 20 on the tree, space and body Jacobians, twists, bias accelerations,
point kinematics), :mod:`~formalisms.screw.dynamics` (the wrench recursion of eq. 27, ``M``, ``h``) and
:mod:`~formalisms.screw.constraints` (``phi``, ``Jc``, ``Jcdot qd``, constraint wrenches and Gauss's principle,
article 5), :mod:`~formalisms.screw.conditioning` (its own cond(M), conditioning of S, scales and task-space
inertia), :mod:`~formalisms.screw.derivatives` (the exact linearization of eq. 11: tangents of the PoE recursions and
the differentiated KKT system, :func:`linearize`). This module holds the forward dynamics and the drift–control split
(article 6.2.3; eq. 9, 10, 14-17), with the drift's parts ``zvcf = M^-1 (-g)`` and ``drift_velocity = M^-1 (-C qd)``
(article 4.5-4.6; with constraints the KKT solves with the bias 0 and ``Jcdot qd``), each solved on its own.

``M = sum_i J_b,i^T G_i J_b,i`` and ``h = C qd + g`` from the wrench recursion of eq. (27), both in body frames
(:mod:`~formalisms.screw.dynamics`: no moment about the world origin, so M and h round on the levers about the
joints); one Cholesky factor of ``M`` then gives ``drift = M^-1 (-h)`` (eq. 10, the ZTCF), ``ctrl = M^-1 B u`` and
``total = M^-1 (B u - h)``, each solved on its own. With constraints, total / lam and drift / lam_drift (eq. 14) come
from Gauss's principle in the Udwadia–Kalaba form on the same factor, and ``ctrl = B_c B u`` (eq. 17) directly.

Spherical and free joints (article 2.1-2.2: the configuration on SO(3) and SE(3), not in a chart; 6.2; 6.4.2: the
configuration manifold itself): a joint's quaternion (and position) block is turned into its group element ``g_i``
here (:func:`lie.quaternion_rotation`, the exponential of the rotation vector), its velocity block is the body twist
of ``g_i`` on constant unit-twist columns, ``(linear, angular)`` for a free joint, and the recursions are the screw
ones (:mod:`~formalisms.screw.kinematics`, :mod:`~formalisms.screw.dynamics`): ``V_i = Ad_{g_i^-1 M^-1} V_parent +
E_i v_i``, the accelerations with ``ad``, the wrenches back with ``ad*``. ``q`` has ``nq`` entries and everything
velocity-like (``qd``, the accelerations, the rows of ``M``, the columns of ``B`` and ``Jc``) ``nv``; the per-body
arrays below have one row per body. This backend has no ``split_chart``, so no chart of the group is ever needed.

``split_batch`` evaluates N states in one pass of the same functions (kinematics, inertias, recursion, rows and
solves all take a leading state axis; :mod:`~formalisms.screw.linalg` factors the N mass matrices at once), in
blocks of :data:`BLOCK` states; ``split`` is that pass for one state, plus the extras below. ``split_many``, the block
form of ``split`` (``formalisms.interface.with_block_form``), returns each state's whole split, extras included, with
``split``'s very numbers.

extras (numpy arrays, row ``i`` = body ``i`` in model order; twists ``(w, v)``, wrenches ``(moment, force)``):

``poses``                  (nb, 4, 4) ``T_i``, world <- body ``i`` (eq. 20).
``twists_space``           (nb, 6) ``V_s,i = J_s,i qd``: ``[V_s] = Tdot T^-1``, world frame (``v`` is the velocity
                           of the body-fixed point at the world origin).
``twists_body``            (nb, 6) ``V_b,i = Ad_{T_i^-1} V_s,i``: ``[V_b] = T^-1 Tdot``, body frame ``i`` (``v`` is
                           the velocity of the body-frame origin).
``accelerations_space``    (nb, 6) ``Vdot_s,i = J_s,i qdd + Jdot_s,i qd`` at ``qdd = total``, world frame.
``wrenches_body``          (nb, 6) at ``qdd = total``: the wrench the parent exerts on body ``i`` through joint ``i``
                           (gravity and the constraint wrenches included), about body ``i``'s origin, in body
                           frame ``i``.
``wrenches_body_drift``    (nb, 6) the same at ``qdd = drift`` (with the drift's constraint wrenches).
``wrenches_space``         (nb, 6) ``F_s,i = Ad_{T_i^-1}^T F_b,i``: ``wrenches_body`` expressed in the world frame
                           (moment about the world origin), so that ``F_s . V_s = F_b . V_b``.

Constrained models also report (article 7.2, "constraint wrenches"; eq. 27's ``W_constr``):

``constraint_wrenches_space``        (nb, 6) the wrench all constraint forces of ``lam`` exert on body ``i``, world
                                     frame, moment about the world origin (:mod:`~formalisms.screw.constraints`);
                                     ``sum_i J_s,i^T W_i = Jc^T lam``.
``constraint_wrenches_space_drift``  (nb, 6) the same for ``lam_drift``.

The split also carries the compared joint loads ``joint_wrenches`` (``joint_wrenches_drift``): ``wrenches_body``
(``wrenches_body_drift``) in ``[force, moment]`` order, with the torques ``c_j lam`` of any joint coupling added back
on the coupled joints' axes (they are applied to the bodies as constraint wrenches, so the wrench recursion leaves
them out of the joint's own load; the harness's convention counts them in, like an actuator's ``B u``), and the
task-space inertia ``task_inertia`` ``Lambda = (J M^-1 J^T)^-1`` (eq. 22) of the default task point, with ``J`` the
point Jacobian ``[-[p] | I] J_s`` from the space Jacobian (``conditions["task_inertia"]`` = cond(J M^-1 J^T)).

Under a change of world frame by ``g`` (the scene moved rigidly, gravity rotated with it) the space twists and
accelerations map by ``Ad_g``, ``wrenches_space`` and the constraint wrenches by ``Ad_g^-T``, ``poses`` by
``g T``; the body quantities do not change (article 7.4).
"""

from __future__ import annotations

import numpy as np

from cases.model import Model
from formalisms.interface import Formalism, Split, SplitBatch, check_batch, check_state, with_block_form
from formalisms.screw import conditioning, constraints, dynamics, kinematics, lie
from formalisms.screw.derivatives import linearize
from formalisms.screw.kinematics import Kinematics
from formalisms.screw.linalg import Cholesky

#: States per pass of :func:`split_batch`: large enough that numpy's per-call cost is spread over many states,
#: small enough that the per-body arrays stay in cache and N = 10,000 states need a few tens of MB.
BLOCK = 1024


def _task_drift(kin: Kinematics, qd: np.ndarray, drift: np.ndarray):
    """``D a`` for the default task point at the drift (eq. 23, classical acceleration), (..., k)."""
    model = kin.model
    tp = model.task_point()
    a = kinematics.point_acceleration(kin, model.body_index(tp.body), tp.offset, qd, drift)
    return (tp.directions @ a[..., None])[..., 0]


def _task_jacobian(kin: Kinematics) -> np.ndarray:
    """The default task point's Jacobian ``D [-[p] | I] J_s`` (..., k, nv)."""
    model = kin.model
    tp = model.task_point()
    body = model.body_index(tp.body)
    return tp.directions @ kinematics.point_jacobian(kin, body, kinematics.point_position(kin, body, tp.offset))


def _task_inertia(kin: Kinematics, factor: Cholesky) -> tuple[np.ndarray, float]:
    """``task_inertia`` (eq. 22) of the default task point from its point Jacobian and the factor of M, with its
    condition ``cond(J M^-1 J^T)`` (:func:`conditioning.task_inertia`)."""
    return conditioning.task_inertia(kin.model, _task_jacobian(kin), factor)


def _joint_wrenches(kin: Kinematics, F_body: np.ndarray, torques: np.ndarray | None = None) -> np.ndarray:  # noqa: N803
    """Body wrenches ``(moment, force)`` as the compared joint loads ``[force, moment]``, each joint's coupling
    torque ``torques[j]`` (per velocity column; None: no coupling) added along its body screw axis ``B_j``."""
    if torques is not None:
        F_body = F_body + kinematics.joint_twists(kin, torques)
    return np.concatenate([F_body[..., 3:], F_body[..., :3]], axis=-1)


def _kinetic_energy(G: dynamics.Inertias, twists_body: np.ndarray, qd: np.ndarray) -> float:  # noqa: N803
    """``T = sum_i 1/2 V_b,i^T G_i V_b,i + sum_j 1/2 a_j qd_j^2`` with ``G_i`` the spatial inertia in body frame ``i``
    and ``a_j`` the rotors' armature (:mod:`~formalisms.screw.dynamics`, "Armature")."""
    return 0.5 * float(np.sum(twists_body * G.apply(twists_body))) + 0.5 * float(G.rotors @ (qd * qd))


def _extras(kin: Kinematics, G: dynamics.Inertias, qd: np.ndarray, total: np.ndarray, drift: np.ndarray,  # noqa: N803
            constraint_wrenches: tuple[np.ndarray, np.ndarray] | None = None,
            loads: np.ndarray | None = None) -> dict[str, np.ndarray]:
    """The twists, accelerations and wrenches listed in the module docstring; ``constraint_wrenches`` (space frame,
    at the total and at the drift) and the external loads' body wrenches ``loads`` (:func:`dynamics.external_wrenches`)
    are applied to the bodies in the wrench recursion, the former also reported."""
    V_s = kinematics.twists(kin, qd)
    external = None
    if constraint_wrenches is not None:                       # F_b = Ad_{T_i}^T F_s
        external = lie.wrench_to_body(kin.poses, np.stack(constraint_wrenches))
    if loads is not None:
        external = loads if external is None else external + loads
    F = dynamics.wrenches(kin, G, qd, np.stack([total, drift]), np.ones((2,) + (1,) * (np.ndim(qd) - 1)), external)
    extras = {
        "poses": kin.poses,
        "twists_space": V_s,
        "twists_body": kinematics.body_twists(kin, qd),
        "accelerations_space": kinematics.spatial_accelerations(kin, qd, total),
        "wrenches_body": F[0],
        "wrenches_body_drift": F[1],
        "wrenches_space": lie.wrench_from_body(kin.poses, F[0]),
    }
    if constraint_wrenches is not None:
        extras["constraint_wrenches_space"], extras["constraint_wrenches_space_drift"] = constraint_wrenches
    return extras


def _unconstrained(factor: Cholesky, h: np.ndarray, tau_ctrl: np.ndarray) -> tuple[np.ndarray, ...]:
    """``(drift, ctrl, total) = M^-1 (-h), M^-1 B u, M^-1 (B u - h)`` (N, n) each (eq. 9, 10), solved on their own."""
    x = factor.solve(np.stack([-h, tau_ctrl, tau_ctrl - h], axis=-1))   # (N, n, 3)
    return tuple(x[..., c] for c in range(3))


def _drift_parts(factor: Cholesky, g: np.ndarray, c_qd: np.ndarray) -> dict[str, np.ndarray]:
    """``zvcf = M^-1 (-g)`` and ``drift_velocity = M^-1 (-C qd)`` (N, n) each (article 4.5-4.6), solved on their own:
    the drift's parts, ``zvcf + drift_velocity = drift`` to rounding."""
    x = factor.solve(np.stack([-g, -c_qd], axis=-1))
    return {"zvcf": x[..., 0], "drift_velocity": x[..., 1]}


def _constrained_drift_parts(gauss: constraints.Gauss, g: np.ndarray, c_qd: np.ndarray) -> dict[str, np.ndarray]:
    """The drift's parts with constraints (eq. 14 split by linearity in ``(f, Jcdot qd)``): ``zvcf`` the KKT solve with
    ``f = -g`` and the bias 0 (at ``qd = 0`` the rows' ``Jcdot qd`` vanishes), ``drift_velocity`` with ``f = -C qd``
    and the bias ``Jcdot qd`` (N, n) each."""
    return {"zvcf": gauss.solve(-g, np.zeros_like(gauss.bias))[0], "drift_velocity": gauss.solve(-c_qd)[0]}


def _constrained(gauss: constraints.Gauss, h: np.ndarray, tau_ctrl: np.ndarray) -> tuple[np.ndarray, ...]:
    """``(drift, ctrl, total, lam, lam_drift)`` (eq. 12-17) by Gauss's principle: total / lam with the input,
    drift / lam_drift without it (eq. 14), ``ctrl = B_c B u`` (eq. 17) directly."""
    (total, lam), (drift, lam_drift) = gauss.solve(tau_ctrl - h), gauss.solve(-h)
    return drift, gauss.input_map(tau_ctrl), total, lam, lam_drift


def _reported(kin: Kinematics, G: dynamics.Inertias, qd: np.ndarray, drift: np.ndarray, extras: dict,  # noqa: N803
              torques=(None, None)) -> dict:
    """The Split fields read off the extras: ``task_drift``, the kinetic energy and the joint wrenches (with the
    coupling ``torques`` at the total and at the drift, :func:`_joint_wrenches`)."""
    return dict(extras=extras, task_drift=_task_drift(kin, qd, drift),
                kinetic_energy=_kinetic_energy(G, extras["twists_body"], qd),
                joint_wrenches=_joint_wrenches(kin, extras["wrenches_body"], torques[0]),
                joint_wrenches_drift=_joint_wrenches(kin, extras["wrenches_body_drift"], torques[1]))


def _power(model: Model, u: np.ndarray, qd: np.ndarray) -> dict:
    """``power_ctrl = u . (B^T qd)`` (W) and ``power_ctrl_per_coord = (B u)_i qd_i``."""
    return {"power_ctrl": float(u @ (model.input_map.T @ qd)), "power_ctrl_per_coord": (model.input_map @ u) * qd}


def _external(kin: Kinematics, forces: tuple) -> tuple[np.ndarray | None, np.ndarray | None, tuple]:
    """The external loads (``cases.loads``): their body wrenches, ``tau_ext`` through the body Jacobians
    (:func:`dynamics.external_forces`) and ``forces = (h, C qd, g)`` with ``tau_ext`` taken off ``h`` and ``g`` (it is
    velocity-independent: the drift at rest carries it, eq. 14); ``(None, None, forces)`` without loads."""
    W = dynamics.external_wrenches(kin.model, kin)
    if W is None:
        return None, None, forces
    tau_ext = dynamics.external_forces(kin, W)
    h, c_qd, g = forces
    return W, tau_ext, (h - tau_ext, c_qd, g - tau_ext)


def _external_fields(tau_ext: np.ndarray | None, qd: np.ndarray) -> dict:
    """``external_force`` and ``power_ext = tau_ext . qd`` of one state (None without loads)."""
    if tau_ext is None:
        return {}
    return {"external_force": tau_ext, "power_ext": float(tau_ext @ qd)}


def _factor(model: Model, M: np.ndarray, Q: np.ndarray, first: int | None = None) -> Cholesky:  # noqa: N803
    """The Cholesky factors of a stack of mass matrices (N, n, n) at the configurations ``Q`` (N, nq); a ValueError
    naming the model, the first state whose M is not positive definite (``first``: the stack's offset in a batch; None
    for one state) and its eigenvalues."""
    factor = Cholesky.of(M)
    if not factor.positive.all():
        i = int(np.flatnonzero(~factor.positive)[0])
        where = f"q = {Q[i].tolist()}" if first is None else f"state {first + i} of the batch, q = {Q[i].tolist()}"
        raise ValueError(f"model '{model.name}': the mass matrix is not positive definite at {where} (Cholesky "
                         f"failed); eigenvalues {np.linalg.eigvalsh(M[i]).tolist()}")
    return factor


def _unconstrained_splits(model: Model, Q: np.ndarray, QD: np.ndarray, U: np.ndarray,  # noqa: N803
                          first: int) -> list[Split]:
    """:func:`split` of a block of states of an unconstrained model: the kinematics, ``M``, ``h``, the solves, the
    extras and the task quantities of the whole block in one pass of the same functions (a leading state axis, every
    state summed as alone: ``B u`` and ``D a`` are products state by state), then each state's conditioning."""
    kin, G = kinematics.forward_kinematics(model, Q), dynamics.Inertias.of(model)
    M, *forces = dynamics.terms(kin, G, QD)
    loads, tau_ext, (h, c_qd, g) = _external(kin, tuple(forces))
    factor, tau_ctrl = _factor(model, M, Q, first), (model.input_map @ U[..., None])[..., 0]
    drift, ctrl, total = _unconstrained(factor, h, tau_ctrl)
    parts = _drift_parts(factor, g, c_qd)
    extras, task_drift, J = (_extras(kin, G, QD, total, drift, loads=loads), _task_drift(kin, QD, drift),
                             _task_jacobian(kin))
    wrenches = (_joint_wrenches(kin, extras["wrenches_body"]), _joint_wrenches(kin, extras["wrenches_body_drift"]))
    out = []
    for i, (qd, u) in enumerate(zip(QD, U)):
        applied = tau_ctrl[i] if tau_ext is None else np.abs(tau_ctrl[i]) + np.abs(tau_ext[i])
        mass = conditioning.of_mass(model, M[i], c_qd[i], forces[2][i], applied, qd)   # gravity's g: tau_ext is in applied
        Lambda, task_cond = conditioning.task_inertia(model, J[i], factor.state(i))
        own = {key: value[i] for key, value in extras.items()}
        out.append(Split(drift=drift[i], ctrl=ctrl[i], total=total[i], lam=None, lam_drift=None, power_constr=None,
                         power_constr_per_coord=None, accel_scale=mass.accel_scale,
                         conditions={"task_inertia": task_cond}, extras=own, task_drift=task_drift[i],
                         kinetic_energy=_kinetic_energy(G, own["twists_body"], qd), joint_wrenches=wrenches[0][i],
                         joint_wrenches_drift=wrenches[1][i], cond_M=mass.cond, task_inertia=Lambda,
                         **{key: value[i] for key, value in parts.items()}, **_power(model, u, qd),
                         **_external_fields(None if tau_ext is None else tau_ext[i], qd)))
    return out


def split_many(model: Model, Q, QD, U) -> list[Split]:  # noqa: N803
    """:func:`split` of N states (rows of ``Q``, ``QD``, ``U``), each a whole :class:`Split` equal to ``split``'s bit
    for bit, :data:`BLOCK` states per pass (:func:`_unconstrained_splits`). A constrained model's states go through
    ``split`` one by one: Gauss's principle (``np.einsum``, whose loops depend on the length of the stack) and the
    rows' products with their direction matrices round differently on a stack than on one state."""
    Q, QD, U = check_batch(model, Q, QD, U)
    if model.constraints:
        return [split(model, q, qd, u) for q, qd, u in zip(Q, QD, U)]
    return [s for i in range(0, len(Q), BLOCK)
            for s in _unconstrained_splits(model, Q[i:i + BLOCK], QD[i:i + BLOCK], U[i:i + BLOCK], i)]


@with_block_form(split_many)
def split(model: Model, q, qd, u) -> Split:
    """The drift–control split of eq. (9) in screw coordinates: ``drift = -M^-1 h`` (eq. 10, ZTCF), ``ctrl =
    M^-1 B u`` solved directly, ``total = M^-1 (B u - h)`` solved on its own; ``M`` and ``h`` from eq. (27). A
    constrained model goes through :func:`_constrained_split`. The conditioning is this backend's own
    (:mod:`~formalisms.screw.conditioning`).

    ``task_drift`` is the classical acceleration of ``model.task_point()`` at the drift, from the body's space
    twist and spatial acceleration (eq. 23). extras: see the module docstring.
    """
    q, qd, u = check_state(model, q, qd, u)
    kin, G = kinematics.forward_kinematics(model, q), dynamics.Inertias.of(model)
    M, *forces = dynamics.terms(kin, G, qd)
    loads, tau_ext, (h, c_qd, g) = _external(kin, tuple(forces))
    factor = _factor(model, M[None], q[None])
    tau_ctrl = model.input_map @ u
    mass = conditioning.of_mass(model, M, c_qd, forces[2], tau_ctrl if tau_ext is None  # gravity's g: tau_ext is
                                else np.abs(tau_ctrl) + np.abs(tau_ext), qd)           # counted in the applied forces
    Lambda, task_cond = _task_inertia(kin, factor)
    common = dict(cond_M=mass.cond, task_inertia=Lambda, **_power(model, u, qd), **_external_fields(tau_ext, qd))
    if model.constraints:
        return _constrained_split(kin, G, qd, factor, (h, c_qd, g), tau_ctrl, mass, common,
                                  {"task_inertia": task_cond}, loads)
    drift, ctrl, total = (x[0] for x in _unconstrained(factor, h[None], tau_ctrl[None]))
    common.update({key: value[0] for key, value in _drift_parts(factor, g[None], c_qd[None]).items()})
    return Split(drift=drift, ctrl=ctrl, total=total, lam=None, lam_drift=None, power_constr=None,
                 power_constr_per_coord=None, accel_scale=mass.accel_scale, conditions={"task_inertia": task_cond},
                 **_reported(kin, G, qd, drift, _extras(kin, G, qd, total, drift, loads=loads)), **common)


def _constrained_split(kin: Kinematics, G: dynamics.Inertias, qd, factor: Cholesky, forces, tau_ctrl,  # noqa: N803
                       mass: conditioning.MassConditioning, common: dict, conditions: dict,
                       loads: np.ndarray | None = None) -> Split:
    """Eq. (12)-(17) by Gauss's principle (:func:`_constrained`, a stack of one state) with ``forces = (h, C qd, g)``,
    the drift's parts, the constraint wrenches of both multipliers, and the constraint's own quantities (article
    5.5): ``Jc^T lam`` and its power, ``Jc qd`` and the conditioning of ``S`` (``accel_scale`` adds what the
    constraint force can produce). ``h`` and ``g`` carry ``-tau_ext``; ``loads``, the external body wrenches, are
    applied in the wrench recursion of the extras."""
    model = kin.model
    h, c_qd, g = forces
    rows = constraints.terms(kin, kin.q, qd)
    Jc, bias = rows.jacobian, rows.bias
    gauss = constraints.Gauss.build(model, factor, Jc[None], bias[None])
    drift, ctrl, total, lam, lam_drift = (x[0] for x in _constrained(gauss, h[None], tau_ctrl[None]))
    parts = _constrained_drift_parts(gauss, g[None], c_qd[None])
    common = {**common, **{key: value[0] for key, value in parts.items()}}
    extras = _extras(kin, G, qd, total, drift, (rows.wrenches(lam), rows.wrenches(lam_drift)), loads)
    cc = conditioning.of_constraints(model, factor, gauss.A[0], Jc, bias, (tau_ctrl - h, -h), mass)
    force = Jc.T @ lam
    return Split(drift=drift, ctrl=ctrl, total=total, lam=lam, lam_drift=lam_drift,
                 power_constr=float(force @ qd), power_constr_per_coord=force * qd,
                 accel_scale=mass.accel_scale + cc.force_scale,
                 conditions={**conditions, "constraint": cc.cond_S, "constraint_consistency": cc.inconsistency,
                             "constraint_kept": cc.cond_kept},
                 constraint_value=rows.phi, constraint_jacobian=Jc, constraint_bias=bias, constraint_velocity=Jc @ qd,
                 constraint_force=force, constraint_force_drift=Jc.T @ lam_drift, constraint_rank=cc.rank,
                 lam_scale=cc.lam_scale,
                 **_reported(kin, G, qd, drift, extras,
                             (rows.coupling_torques(lam), rows.coupling_torques(lam_drift))),
                 **common)


def _split_block(model: Model, Q: np.ndarray, QD: np.ndarray, U: np.ndarray, first: int) -> tuple:  # noqa: N803
    """``(drift, ctrl, total, lam, lam_drift)`` of a block of states (lam None when unconstrained): the pass of
    ``split`` over a leading state axis."""
    kin = kinematics.forward_kinematics(model, Q)
    G = dynamics.Inertias.of(model)
    M = dynamics.mass_matrix_of(kin, G)
    loads = dynamics.external_wrenches(model, kin)
    h = dynamics.generalized_forces(kin, dynamics.wrenches(kin, G, QD, None, 1.0))
    if loads is not None:
        h = h - dynamics.external_forces(kin, loads)
    factor, tau_ctrl = _factor(model, M, Q, first), U @ model.input_map.T
    if not model.constraints:
        return (*_unconstrained(factor, h, tau_ctrl), None, None)
    rows = constraints.terms(kin, Q, QD)
    return _constrained(constraints.Gauss.build(model, factor, rows.jacobian, rows.bias), h, tau_ctrl)


def split_batch(model: Model, Q, QD, U) -> SplitBatch:  # noqa: N803
    """The split of N states at once (:class:`SplitBatch`): row ``i`` is ``split(model, Q[i], QD[i], U[i])``'s
    drift, ctrl, total (and lam, lam_drift), by the same functions over a leading state axis, :data:`BLOCK` states
    per pass."""
    Q, QD, U = check_batch(model, Q, QD, U)
    starts = range(0, len(Q), BLOCK)
    blocks = [_split_block(model, Q[i:i + BLOCK], QD[i:i + BLOCK], U[i:i + BLOCK], i) for i in starts]
    if not blocks:
        empty = np.zeros((0, model.n))
        lam = (np.zeros((0, model.k)),) * 2 if model.constraints else (None, None)
        return SplitBatch(empty, empty, empty, *lam)
    drift, ctrl, total, lam, lam_drift = (None if parts[0] is None else np.concatenate(parts) for parts in zip(*blocks))
    return SplitBatch(drift, ctrl, total, lam, lam_drift)


FORMALISM = Formalism(
    name="screw",
    summary="Product of exponentials and screw theory (article 6.2, eqs. 20, 27): twists and wrenches on SE(3)",
    split=split,
    split_batch=split_batch,
    linearize=linearize,
)
