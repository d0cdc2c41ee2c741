"""Pinocchio as the external reference voter (docs/design.md, "Independence is the product"): the ``split`` contract
on Pinocchio's ABA / CRBA / RNEA, on the model :mod:`crosscheck.references.pinocchio.build` builds.

What is computed
----------------
:func:`split` is the shared ``split`` contract on top of Pinocchio's ABA / CRBA / RNEA; :data:`REFERENCE` wraps it
as a :class:`~formalisms.interface.Formalism`. The numbers the reference reports besides the accelerations are its
own (no numerics from ``formalisms.interface``), with the definitions every backend uses:

* ``cond_M`` and ``accel_scale`` from the singular values of M (:func:`_conditioning`);
* the input power ``u . (B^T qd)``, the constraint force ``Jc^T lam``, the constraint power ``lam . (Jc qd)`` and
  ``Jc qd``;
* the constraint conditions (``"constraint"`` = cond S, ``"constraint_kept"``, ``"constraint_consistency"``,
  the rank, ``lam_scale`` and the accelerations the constraint force can produce, added to ``accel_scale``) from
  the SVD of ``L^-1 Jc^T`` (L the Cholesky factor of M), whose squared singular values are the eigenvalues of
  ``S = Jc M^-1 Jc^T`` (:class:`_Gram`);
* the task inertia ``(J M^-1 J^T)^-1`` and ``conditions["task_inertia"]`` likewise from the SVD of ``L^-1 J^T``;
* the kinetic energy from the bodies' spatial velocities and inertias plus the joints' armature (:func:`_kinetic_energy`:
  Pinocchio 4.1's ``computeKineticEnergy`` drops the armature of an unaligned revolute joint).

Armature (``model.armature``, from the model's bodies or the file, ``build``): Pinocchio's crba, rnea, aba,
computeMinverse, forwardDynamics (on crba's M) and the ABA derivatives add it to M's diagonal themselves.

The constrained split uses Pinocchio's own KKT solver (``pinocchio.forwardDynamics(q, v, tau, J, gamma)``) for
total / lam and drift / lam_drift. At a degenerate state (S singular up to ``CONSTRAINT_RCOND``) Pinocchio's
Cholesky-based KKT solve has no answer: the reference gives it the independent combinations of the rows (S's
eigen-directions above the threshold, as the formalisms keep them) and maps the multipliers back, which gives the
minimum-norm multipliers the formalisms return.

Joint loads (the compared ``joint_wrenches``): ``data.f[j]`` after ``pinocchio.rnea(q, v, a)`` is the spatial force
``(linear, angular)`` the parent transmits to body ``j`` through joint ``j``, in joint ``j``'s local frame (our body
frame: the loader takes each body's inertia in the joint frame, and the data build appends it there), moment about
its origin; RNEA's accelerating base (``a_gf = a - g``) puts the weight in it exactly, so ``data.f`` at ``a = total``
(``drift``) is ``joint_wrenches`` (``joint_wrenches_drift``), rows read back in our coordinate order. With
constraints the point forces of ``lam`` (``lam_drift``) are applied as RNEA's external forces ``fext`` (local
frame, moment about the joint origin); a joint coupling's ``c_j lam`` is not a point force, so RNEA leaves it in
the coupled joint's own load, the convention of ``Split.joint_wrenches``.

External loads (``cases.loads``): each declaration is a ``pinocchio.Force`` in its joint's local frame, moment
about the joint origin (:func:`_external_fext`, from ``data.oMi``: a world vector ``x`` is ``R^T x`` there, a spring's
force formed from ``oMi * offset``), passed as ABA's and RNEA's ``fext``: the accelerations, the drift at rest
(``aba(q, 0, 0, fext)``) and the joint loads carry them. ``tau_ext`` itself is ``-rnea(q, 0, 0, fext)`` of the
gravity-free model. The constrained solve (``forwardDynamics`` takes no fext) adds ``tau_ext`` to the applied force.
The linearization takes ``computeABADerivatives(..., fext)``, whose fext is constant in the joint frames: body-frame
forces and wrenches only (a world-frame force or a spring turns in the joint frame and has further q-derivatives;
:func:`linearize` declines those models).

States and results are permuted (and continuous joints mapped to ``(cos q, sin q)``) in and out, so callers always
use our coordinate order.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import pinocchio as pin
import scipy.linalg

from cases.constraints import KnifeEdge, PointOnCircle, PointOnLine, PointsCoincide, PointVelocity, RollingContact
from cases.loads import ExternalWrench, PointSpring
from cases.model import Model
from crosscheck.references.pinocchio.build import (LOCK, Compiled, ours, ours_matrix, reference_key, reference_model,
                                                   symmetric)
from crosscheck.references.pinocchio.kinematics import constraint_terms, contact, rolling_direction, task_rows
from formalisms.interface import (CONSTRAINT_RCOND, check_batch, check_state, Formalism, Linearization,
                                  ModelNotSupported, Split, split_batch_by_loop, SplitBatch)


# ------------------------------------------------------------------------------------ the reference's numerics


@dataclass(frozen=True)
class _Dynamics:
    """CRBA's M, its lower Cholesky factor L and its singular values (descending), RNEA's g and C qd at one state,
    in Pinocchio's order."""

    M: np.ndarray
    L: np.ndarray
    singular_values: np.ndarray
    g: np.ndarray
    Cqd: np.ndarray

    @classmethod
    def at(cls, c: Compiled, data, q_p: np.ndarray, v_p: np.ndarray) -> "_Dynamics":
        M = symmetric(np.array(pin.crba(c.model, data, q_p)))
        g = np.array(pin.computeGeneralizedGravity(c.model, data, q_p))
        Cqd = np.array(pin.rnea(c.model, data, q_p, v_p, np.zeros(len(v_p)))) - g
        return cls(M, scipy.linalg.cholesky(M, lower=True), np.linalg.svd(M, compute_uv=False), g, Cqd)


def _conditioning(c: Compiled, dyn: _Dynamics, tau: np.ndarray, qd: np.ndarray) -> tuple[float, float]:
    """``(cond(M), accel_scale)`` from the singular values of M (for a symmetric positive definite M its
    eigenvalues): ``accel_scale = ||M^-1||_2 H``, H the size of the generalized forces summed in ``B u - C qd - g``
    (1-norms), including the configuration-robust magnitudes ``||M|| |qd|^2`` of the velocity products and
    ``|gravity|_1 sqrt(m_total ||M||)`` of gravity (the definition the formalisms use; mass and gravity are the
    reference model's: the file's, for a loaded model). ``tau`` and ``qd`` in any one order."""
    s = dyn.singular_values
    H = (np.abs(dyn.Cqd).sum() + np.abs(dyn.g).sum() + np.abs(tau).sum() + s[0] * float(qd @ qd)
         + np.abs(c.scales.gravity).sum() * np.sqrt(c.scales.mass * s[0]))
    return float(s[0] / s[-1]), float(H / s[-1])


@dataclass(frozen=True)
class _Gram:
    """``G = X^T X`` (k x k) in its eigen-axes from the SVD of X (n x k): eigenvalues ``w`` (ascending, the squared
    singular values, zero beyond rank n) and eigenvectors ``axes`` (columns). With ``X = L^-1 J^T`` and L the
    Cholesky factor of M, ``G = J M^-1 J^T``: S for the constraint rows, A for the task Jacobian."""

    w: np.ndarray
    axes: np.ndarray

    @classmethod
    def of(cls, L: np.ndarray, J: np.ndarray) -> "_Gram":
        X = scipy.linalg.solve_triangular(L, J.T, lower=True)
        _, sigma, Vt = np.linalg.svd(X, full_matrices=True)
        w = np.zeros(X.shape[1])
        w[:len(sigma)] = sigma**2
        return cls(w[::-1].copy(), Vt[::-1].T.copy())


def _task_inertia(model: Model, c: Compiled, data, L: np.ndarray) -> dict:
    """``task_inertia`` (eq. 22) of the default task point, ``(J M^-1 J^T)^-1`` from the eigen-axes of
    ``A = J M^-1 J^T`` (:class:`_Gram`; J from :func:`task_rows`, needs computeJointJacobians), and
    ``conditions["task_inertia"]`` = cond(A). A is numerically singular (NaN and inf) when its smallest eigenvalue
    is at or below ``k eps`` times its largest or the degenerate floor, or any is not finite (the definition the
    formalisms use)."""
    A = _Gram.of(L, task_rows(model, c, data))                 # A does not depend on the coordinate order
    w = A.w
    floor = max(len(w) * np.finfo(float).eps * w[-1], c.scales.degenerate_floor)
    if not (np.all(np.isfinite(w)) and floor < w[0]):
        return {"task_inertia": np.full((len(w), len(w)), np.nan), "conditions": {"task_inertia": float("inf")}}
    Lambda = (A.axes / w) @ A.axes.T
    return {"task_inertia": 0.5 * (Lambda + Lambda.T), "conditions": {"task_inertia": float(w[-1] / w[0])}}


def _input_power(model: Model, u: np.ndarray, qd: np.ndarray) -> tuple[float, np.ndarray]:
    """``P_ctrl = u . (B^T qd)`` and per coordinate ``(B u)_i qd_i`` (docs/design.md, power)."""
    return float(u @ (model.input_map.T @ qd)), (model.input_map @ u) * qd


def _joint_wrenches(c: Compiled, data, q_p, v_p, a_p, fext=None) -> np.ndarray:
    """``data.f`` after ``rnea(q, v, a, fext)``: row ``i`` (our order) = ``[force, moment]`` the parent transmits to
    body ``i``, in its frame, about its origin (module docstring)."""
    if fext is None:
        pin.rnea(c.model, data, q_p, v_p, a_p)
    else:
        pin.rnea(c.model, data, q_p, v_p, a_p, fext)
    out = np.empty((len(c.body_of_joint), 6))
    for jid, body in c.body_of_joint.items():
        f = data.f[jid]
        out[body] = np.concatenate([f.linear, f.angular])
    return out


def _point_forces(c: Compiled, data, con, part: np.ndarray) -> list:
    """The point forces ``(body, offset, world force)`` the multipliers ``part`` of one declaration apply (none on
    the world, none for a coupling): a circle ``2 P^T P (p - c) lam``, a loop ``D^T lam`` on a and ``-D^T lam`` on
    b, a line ``N^T lam``. Needs the frame placements."""
    if isinstance(con, PointsCoincide):
        force = con.directions.T @ part
        return [(b, o, s * force) for b, o, s in ((con.body_a, con.offset_a, 1.0), (con.body_b, con.offset_b, -1.0))
                if b is not None]
    if isinstance(con, PointOnLine):
        return [(con.body, con.offset, con.normals.T @ part)]
    if isinstance(con, PointOnCircle):
        p = np.array(data.oMf[c.points[(con.body, tuple(con.offset))]].translation)
        return [(con.body, con.offset, 2.0 * con.plane.T @ (con.plane @ (p - con.center)) * part[0])]
    if isinstance(con, PointVelocity):
        return [(con.body, con.offset, con.directions.T @ part)]
    if isinstance(con, KnifeEdge):
        R = np.array(data.oMi[c.joint_of[con.body]].rotation)
        return [(con.body, con.offset, (R @ con.direction) * part[0])]
    if isinstance(con, RollingContact):   # at the contact point, its offset in the body (joint) frame
        R = np.array(data.oMi[c.joint_of[con.body]].rotation)
        direction = con.plane.T if con.lateral else rolling_direction(con, R @ con.axis)[0][:, None]
        return [(con.body, con.center - con.radius * (R.T @ contact(con, R)[0]), direction @ part)]
    return []


def _constraint_fext(model: Model, c: Compiled, data, lam: np.ndarray) -> list:
    """The constraint forces of ``lam`` as RNEA's external forces: per joint a ``pinocchio.Force`` in its local frame
    (``R^T f``, moment ``offset x R^T f`` about the joint origin). Needs the placements (``data.oMi``, ``oMf``)."""
    fext = [pin.Force.Zero() for _ in range(c.model.njoints)]
    start = 0
    for con in model.constraints:
        part, start = lam[start:start + con.size], start + con.size
        for body, offset, force in _point_forces(c, data, con, part):
            jid = c.joint_of[body]
            local = np.array(data.oMi[jid].rotation).T @ force
            fext[jid] = fext[jid] + pin.Force(local, np.cross(offset, local))
    return fext


def _external_fext(model: Model, c: Compiled, data) -> list | None:
    """The external loads (``cases.loads``) as ABA's and RNEA's ``fext``: per joint a ``pinocchio.Force`` in its local
    frame, moment about the joint origin (module docstring); None without loads. Needs the placements (``data.oMi``,
    after forwardKinematics)."""
    if not model.loads:
        return None
    fext = [pin.Force.Zero() for _ in range(c.model.njoints)]
    for load in model.loads:
        jid = c.joint_of[load.body]
        R, origin = np.array(data.oMi[jid].rotation), np.array(data.oMi[jid].translation)
        couple = np.zeros(3)
        if isinstance(load, PointSpring):
            d = origin + R @ load.offset - load.anchor
            length = float(np.linalg.norm(d))
            local = R.T @ (-load.stiffness * (length - load.rest_length) / length * d if load.rest_length
                           else -load.stiffness * d)
        else:
            to_local = R.T if load.frame == "world" else np.eye(3)
            local = to_local @ load.force
            if isinstance(load, ExternalWrench):
                couple = to_local @ load.moment
        fext[jid] = fext[jid] + pin.Force(local, np.cross(load.offset, local) + couple)
    return fext


def _external_force(model: Model, c: Compiled, q_p: np.ndarray, fext: list) -> np.ndarray:
    """``tau_ext`` in Pinocchio's order: ``-rnea(q, 0, 0, fext)`` of the gravity-free model (the joint torques that
    hold the external loads at rest, negated)."""
    still = _gravity_free(model)
    zero = np.zeros(model.nv)
    return -np.array(pin.rnea(still, still.createData(), q_p, zero, zero, fext))


def _kinetic_energy(pm: pin.Model, data, qp: np.ndarray, vp: np.ndarray) -> float:
    """``T = sum_j 1/2 v_j . (I_j v_j)`` over Pinocchio's bodies (their spatial velocities and inertias after
    ``forwardKinematics``) plus the joints' rotors ``1/2 sum a_k v_k^2`` (``model.armature``), added here: Pinocchio
    4.1's ``computeKineticEnergy`` leaves out the armature of a ``JointModelRevoluteUnaligned`` joint (a revolute joint
    about an axis that is not x, y or z), while crba, rnea, aba, computeMinverse and the ABA derivatives honour it on
    every joint (``tests/references/test_armature_pinocchio.py`` measures both). Moves ``data``'s kinematics."""
    pin.forwardKinematics(pm, data, qp, vp)
    bodies = sum(float(pm.inertias[j].vtiv(data.v[j])) for j in range(1, pm.njoints))
    return 0.5 * (bodies + float(np.asarray(pm.armature, dtype=float) @ (vp * vp)))


def split(model: Model, q, qd, u) -> Split:
    """Drift / control / total accelerations from Pinocchio (ABA twice; ``M^-1 B u`` by a Cholesky solve on CRBA's M:
    computeMinverse lost 256 eps on a single rotor, a fuzz finding); task drift from the classical acceleration of
    the task frame (getFrameClassicalAcceleration); the conditions, powers and task inertia by the reference's own
    numerics (module docstring). A constrained model goes through :func:`_constrained_split`."""
    q, qd, u = check_state(model, q, qd, u)
    if model.constraints:
        return _constrained_split(model, q, qd, u)
    c = reference_model(model)
    pm, order = c.model, c.order
    data = pm.createData()  # fresh Data: the result cannot depend on call history
    tau_ctrl = model.input_map @ u
    qp, vp, tp = c.configuration(q), qd[order], tau_ctrl[order]
    pin.forwardKinematics(pm, data, qp)
    fext = _external_fext(model, c, data)
    loads = () if fext is None else (fext,)

    total_p = np.array(pin.aba(pm, data, qp, vp, tp, *loads))
    drift_p = np.array(pin.aba(pm, data, qp, vp, np.zeros(model.n), *loads))
    zvcf_p = np.array(pin.aba(pm, data, qp, np.zeros(model.n), np.zeros(model.n), *loads))
    still = _gravity_free(model)
    velocity_p = np.array(pin.aba(still, still.createData(), qp, vp, np.zeros(model.n)))
    pin.forwardKinematics(pm, data, qp, vp, drift_p)
    task_accel = pin.getFrameClassicalAcceleration(pm, data, c.task_frame, pin.LOCAL_WORLD_ALIGNED).linear
    dyn = _Dynamics.at(c, data, qp, vp)
    M, Cqd, g = ours_matrix(order, dyn.M), ours(order, dyn.Cqd), ours(order, dyn.g)
    ctrl = scipy.linalg.cho_solve(scipy.linalg.cho_factor(M), tau_ctrl)
    tau_ext = None if fext is None else ours(order, _external_force(model, c, qp, fext))
    cond_M, accel_scale = _conditioning(c, dyn, tau_ctrl if tau_ext is None else np.abs(tau_ctrl) + np.abs(tau_ext), qd)
    power, power_per = _input_power(model, u, qd)
    pin.computeJointJacobians(pm, data, qp)
    inertia = _task_inertia(model, c, data, dyn.L)
    return Split(drift=ours(order, drift_p), ctrl=ctrl, total=ours(order, total_p), lam=None, lam_drift=None,
                 power_ctrl=power, power_ctrl_per_coord=power_per, power_constr=None, power_constr_per_coord=None,
                 cond_M=cond_M, accel_scale=accel_scale, extras={"M": M, "Cqd": Cqd, "g": g},
                 task_drift=model.task_point().directions @ np.array(task_accel), conditions=inertia["conditions"],
                 kinetic_energy=_kinetic_energy(pm, data, qp, vp),
                 joint_wrenches=_joint_wrenches(c, data, qp, vp, total_p, fext),
                 joint_wrenches_drift=_joint_wrenches(c, data, qp, vp, drift_p, fext), task_inertia=inertia["task_inertia"],
                 zvcf=ours(order, zvcf_p), drift_velocity=ours(order, velocity_p), external_force=tau_ext,
                 power_ext=None if tau_ext is None else float(tau_ext @ qd))


_STILL: dict[tuple, pin.Model] = {}


def _gravity_free(model: Model) -> pin.Model:
    """The reference model with gravity zero (cached with it): ABA there at ``(q, qd, 0)`` is ``-M^-1 C qd``, the
    drift's velocity-product part, computed directly."""
    key, pm = reference_key(model), reference_model(model).model
    with LOCK:
        if key not in _STILL:
            _STILL[key] = pin.Model(pm)
            _STILL[key].gravity = pin.Motion.Zero()
    return _STILL[key]


def linearize(model: Model, q, qd, u) -> Linearization:
    """A and B of eq. (11) (:class:`~formalisms.interface.Linearization`, its tangent-space convention) from
    Pinocchio's analytical derivatives of ABA (``computeABADerivatives``: ``dvdot/dq``, ``dvdot/dv`` and ``M^-1``, so
    ``dvdot/du = M^-1 B``), in our coordinate order. Unconstrained models only: a constrained model's reference is
    :func:`crosscheck.references.precise.linearize`."""
    q, qd, u = check_state(model, q, qd, u)
    if model.constraints:
        raise ModelNotSupported(f"model '{model.name}' has constraints: Pinocchio's ABA derivatives are unconstrained; "
                                "the reference linearization of a constrained model is crosscheck.references.precise.linearize")
    if any(isinstance(x, PointSpring) or x.frame == "world" for x in model.loads):
        raise ModelNotSupported(f"model '{model.name}' has world-frame external loads or springs: Pinocchio's ABA "
                                "derivatives hold fext constant in the joint frames (body-frame loads only)")
    c = reference_model(model)
    pm, order = c.model, c.order
    data = pm.createData()
    qp = c.configuration(q)
    pin.forwardKinematics(pm, data, qp)
    fext = _external_fext(model, c, data)
    pin.computeABADerivatives(pm, data, qp, qd[order], (model.input_map @ u)[order], *(() if fext is None else (fext,)))
    Minv = ours_matrix(order, symmetric(np.array(data.Minv)))
    nv = model.nv
    A = np.block([[_tangent_kinematics(model, qd), np.eye(nv)],
                  [ours_matrix(order, np.array(data.ddq_dq)), ours_matrix(order, np.array(data.ddq_dv))]])
    return Linearization(A=A, B=np.vstack([np.zeros((nv, model.m)), Minv @ model.input_map]),
                         vdot=ours(order, np.array(data.ddq)))


def _tangent_kinematics(model: Model, qd: np.ndarray) -> np.ndarray:
    """The kinematic rows' ``A_qq`` of the linearization's convention from Pinocchio's own Lie algebra, not from the
    interface's ``tangent_kinematics`` the backends use: ``-ad_v`` (``pin.Motion(v).action``) on a free joint,
    ``-[omega]x`` (``pin.skew``) on a spherical one, so the gate's reference checks that shared convention too."""
    out = np.zeros((model.nv, model.nv))
    for i, body in enumerate(model.bodies):
        j = model.v_index[i]
        if body.joint == "free":
            out[j:j + 6, j:j + 6] = -pin.Motion(qd[j:j + 6]).action
        elif body.joint == "spherical":
            out[j:j + 3, j:j + 3] = -pin.skew(qd[j:j + 3])
    return out


@dataclass(frozen=True)
class _ConstraintConditions:
    """Conditioning of the constrained problem at one state (the definitions the formalisms use): cond S
    (``constraint``), over the directions kept (``constraint_kept``), the share of the KKT right-hand sides in S's
    redundant directions (``constraint_consistency``), the rank, ``lam_scale`` and ``force_scale`` (the
    accelerations the constraint force can produce: ``||M^-1|| ||Jc|| lam_scale``)."""

    conditions: dict
    rank: int
    lam_scale: float
    force_scale: float


def _kept(c: Compiled, S: _Gram) -> np.ndarray:
    """The directions of S above ``max(CONSTRAINT_RCOND w_max, degenerate floor)``; the rest are redundant."""
    return S.w > max(CONSTRAINT_RCOND * S.w[-1], c.scales.degenerate_floor)


def _constraint_conditions(c: Compiled, dyn: _Dynamics, S: _Gram, Jc_p: np.ndarray, bias: np.ndarray,
                           forces: tuple, accel_scale: float) -> _ConstraintConditions:
    """:class:`_ConstraintConditions` from S's eigen-axes. ``lam_scale = (|Jcdot qd|_1 + ||Jc|| accel_scale) /
    w_kept_min``; the consistency is ``max |U_0^T r| / max(|r|, 1e-6 L accel_scale)`` over the right-hand sides
    ``r = -Jcdot qd - Jc M^-1 f`` of ``forces`` (``B u - h`` and ``-h``), U_0 the redundant directions."""
    kept = _kept(c, S)
    w, rank = S.w, int(kept.sum())
    w_max = max(float(w[-1]), c.scales.degenerate_floor)
    jc_norm = float(np.linalg.norm(Jc_p, 2))
    lam_scale = (np.abs(bias).sum() + jc_norm * accel_scale) / float(w[kept][0]) if rank else 0.0
    inconsistency = 0.0
    for f in forces if rank < len(w) else ():
        r = -bias - Jc_p @ scipy.linalg.cho_solve((dyn.L, True), f)
        size = max(float(np.linalg.norm(r)), 1e-6 * c.scales.length * accel_scale)
        if size > 0.0:
            inconsistency = max(inconsistency, float(np.linalg.norm(S.axes[:, ~kept].T @ r) / size))
    return _ConstraintConditions(
        {"constraint": float(w_max / w[0]) if w[0] > 0.0 else float("inf"), "constraint_consistency": inconsistency,
         "constraint_kept": float(w_max / w[kept][0]) if rank else 1.0},
        rank, float(lam_scale), jc_norm * float(lam_scale) / float(dyn.singular_values[-1]))


def _kkt(c: Compiled, data, q_p, v_p, tau_p, Jc_p, bias):
    """Pinocchio's constrained forward dynamics (KKT): ``M a + b = tau + J^T lambda_c``, ``J a + gamma = 0``."""
    a = np.array(pin.forwardDynamics(c.model, data, q_p, v_p, tau_p, Jc_p, bias, 0.0))
    return a, np.array(data.lambda_c)


def _constrained_split(model: Model, q, qd, u) -> Split:
    """Eq. (12)-(17) with Pinocchio: total / lam and drift / lam_drift from ``pinocchio.forwardDynamics`` with
    our ``Jc`` and ``gamma = Jcdot qd``; ctrl = B_c B u with ``M^-1`` by Cholesky on CRBA's M (eq. 17)."""
    c = reference_model(model)
    pm, order = c.model, c.order
    data = pm.createData()
    phi, Jc_p, bias = constraint_terms(model, c, data, q, qd)
    tau_ctrl = model.input_map @ u
    qp, vp, tp = c.configuration(q), qd[order], tau_ctrl[order]
    pin.forwardKinematics(pm, data, qp)
    fext = _external_fext(model, c, data)
    ext_p = np.zeros(model.n) if fext is None else _external_force(model, c, qp, fext)   # forwardDynamics: no fext
    dyn = _Dynamics.at(c, data, qp, vp)
    Minv_p = scipy.linalg.cho_solve((dyn.L, True), np.eye(model.n))
    S = _Gram.of(dyn.L, Jc_p)
    kept = _kept(c, S)
    rows = np.eye(len(S.w)) if kept.all() else S.axes[:, kept]   # regular: the rows as declared
    # singular S: Pinocchio's KKT on the independent combinations of the rows, the redundant directions dropped as
    # the formalisms drop them; lam = rows lam_r is then the minimum-norm multiplier
    J_r, bias_r = rows.T @ Jc_p, rows.T @ bias
    total_p, lam_r = _kkt(c, data, qp, vp, tp + ext_p, J_r, bias_r)
    drift_p, lam_drift_r = _kkt(c, data, qp, vp, ext_p, J_r, bias_r)
    zvcf_p, _ = _kkt(c, data, qp, np.zeros(model.n), ext_p, J_r, np.zeros(len(bias_r)))
    still = _gravity_free(model)
    velocity_p = np.array(pin.forwardDynamics(still, still.createData(), qp, vp, np.zeros(model.n), J_r, bias_r, 0.0))
    lam, lam_drift = rows @ lam_r, rows @ lam_drift_r
    S_pinv = (S.axes[:, kept] / S.w[kept]) @ S.axes[:, kept].T
    B_c = Minv_p - Minv_p @ Jc_p.T @ S_pinv @ Jc_p @ Minv_p
    pin.computeJointJacobians(pm, data, qp)                      # placements and Jacobians at q, afresh
    pin.updateFramePlacements(pm, data)
    inertia = _task_inertia(model, c, data, dyn.L)
    fext, fext_drift = _constraint_fext(model, c, data, lam), _constraint_fext(model, c, data, lam_drift)
    applied = _external_fext(model, c, data)
    if applied is not None:                                      # the external loads act in both
        fext, fext_drift = ([a + b for a, b in zip(f, applied)] for f in (fext, fext_drift))
    wrenches = _joint_wrenches(c, data, qp, vp, total_p, fext), _joint_wrenches(c, data, qp, vp, drift_p, fext_drift)
    pin.forwardKinematics(pm, data, qp, vp, drift_p)
    task_accel = pin.getFrameClassicalAcceleration(pm, data, c.task_frame, pin.LOCAL_WORLD_ALIGNED).linear

    cond_M, accel_scale = _conditioning(c, dyn, np.abs(tau_ctrl) + np.abs(ours(order, ext_p)), qd)
    cc = _constraint_conditions(c, dyn, S, Jc_p, bias, (tp + ext_p - dyn.Cqd - dyn.g, ext_p - dyn.Cqd - dyn.g),
                                accel_scale)
    Jc = np.empty_like(Jc_p)
    Jc[:, order] = Jc_p
    velocity = Jc @ qd
    power, power_per = _input_power(model, u, qd)
    force, force_drift = Jc.T @ lam, Jc.T @ lam_drift
    Cqd, g = ours(order, dyn.Cqd), ours(order, dyn.g)
    return Split(
        drift=ours(order, drift_p), ctrl=ours(order, B_c @ tp), total=ours(order, total_p), lam=lam,
        lam_drift=lam_drift, power_ctrl=power, power_ctrl_per_coord=power_per,
        power_constr=float(lam @ velocity), power_constr_per_coord=force * qd, cond_M=cond_M,
        accel_scale=accel_scale + cc.force_scale, extras={"M": ours_matrix(order, dyn.M), "Cqd": Cqd, "g": g},
        task_drift=model.task_point().directions @ np.array(task_accel),
        conditions={**inertia["conditions"], **cc.conditions},
        kinetic_energy=_kinetic_energy(pm, data, qp, vp), joint_wrenches=wrenches[0],
        joint_wrenches_drift=wrenches[1], task_inertia=inertia["task_inertia"], constraint_value=phi,
        constraint_jacobian=Jc, constraint_bias=bias, constraint_velocity=velocity, constraint_force=force,
        constraint_force_drift=force_drift, constraint_rank=cc.rank, lam_scale=cc.lam_scale,
        zvcf=ours(order, zvcf_p), drift_velocity=ours(order, velocity_p),
        external_force=ours(order, ext_p) if model.loads else None,
        power_ext=float(ours(order, ext_p) @ qd) if model.loads else None)


# ------------------------------------------------------------------------------------------------- batches


_POOLS: dict[tuple, tuple] = {}


def _pools(model: Model) -> tuple:
    """Pinocchio ModelPools of the reference model and of a gravity-free copy (for ``M^-1 tau = ABA(q, 0, tau)``),
    cached with the reference."""
    key, pm = reference_key(model), reference_model(model).model
    with LOCK:
        if key not in _POOLS:
            still = pin.Model(pm)
            still.gravity = pin.Motion.Zero()
            _POOLS[key] = (pin.ModelPool(pm, 1), pin.ModelPool(still, 1))
    return _POOLS[key]


def split_batch(model: Model, Q, QD, U) -> SplitBatch:
    """N states with Pinocchio's batched ABA (``abaInParallel`` on one thread) on the reference model of
    :func:`split`: total ``ABA(q, qd, B u)``, drift ``ABA(q, qd, 0)``, ctrl ``ABA(q, 0, B u)`` of the gravity-free
    model, which is ``M^-1 B u`` (eq. 9) computed directly. A constrained model goes state by state through
    :func:`split` (Pinocchio's KKT solve has no batched form in its Python API)."""
    Q, QD, U = check_batch(model, Q, QD, U)
    if model.constraints or model.loads or not len(Q):
        return split_batch_by_loop(split)(model, Q, QD, U)
    c = reference_model(model)
    order = c.order
    pool, still = _pools(model)
    qp, vp = np.asfortranarray(c.configuration(Q).T), np.asfortranarray(QD[:, order].T)
    tp = np.asfortranarray((U @ model.input_map.T)[:, order].T)
    rest = np.zeros_like(vp)
    out = {}
    for name, (p, v, t) in {"total": (pool, vp, tp), "drift": (pool, vp, rest), "ctrl": (still, rest, tp)}.items():
        a = np.empty_like(vp)
        a[order] = np.reshape(pin.abaInParallel(1, p, qp, v, t), vp.shape)
        out[name] = a.T
    return SplitBatch(**out)


REFERENCE = Formalism(
    name="pinocchio",
    summary="External reference: Pinocchio's ABA (total, drift), CRBA (ctrl by Cholesky), RNEA (conditioning), "
            "built from the model's file when it was loaded from one (URDF), else from our model data",
    split=split,
    split_batch=split_batch,
    linearize=linearize,
)

__all__ = ["REFERENCE", "linearize", "split", "split_batch"]
