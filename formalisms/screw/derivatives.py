"""Exact first-order model of the screw backend's dynamics (article 4.8, eq. 11): the Lie-group derivative of the
product-of-exponentials recursions (Park, Bobrow & Ploen 1995, "A Lie group formulation of robot dynamics"), carried
forward as tangents through this backend's own passes with its own operations (``Ad``, ``ad``, ``ad^T``).

Directions. A direction is a pair ``(dq, dv)`` (nv each) of a configuration tangent and a velocity change; the
configuration moves on the right, ``q (+) s dq`` (``formalisms.interface.Linearization``), which here is the same
for every joint: body ``i``'s joint motion ``g_i`` becomes ``g_i exp(s [xi_i])`` with ``xi_i = E_i dq_i`` the joint's
own twist of ``dq`` (:func:`kinematics.joint_twists`; ``g_i = exp([B_i] q_i)`` for a screw joint). All ``2 nv``
coordinate directions ``(e_j, 0)``, ``(0, e_j)`` are carried at once on a leading axis (numpy).

Inverse dynamics (:mod:`~formalisms.screw.dynamics`, body frames). With ``X_i = Ad_{T_i,parent(i)}`` and
``dX_i = -ad_{xi_i} X_i`` (``T_i,parent(i) = g_i^-1 M_parent(i),i^-1``), ``Y_i = X_i V_parent``, ``Z_i = X_i
Vdot_parent``, the forward tangents are::

    dV_i    = X_i dV_parent - [xi_i, Y_i] + E_i dv_i
    dVdot_i = X_i dVdot_parent - [xi_i, Z_i] + [dV_i, E_i v_i] + [V_i, E_i dv_i]          (vdot = a held fixed)

and the backward ones, with ``eta_i = J_b,i dq`` (the body twist of the configuration tangent: ``dT_i = T_i
[eta_i]``, so the weight's body wrench ``W_g,i = Ad_{T_i}^T W_g`` moves by ``ad_{eta_i}^T W_g,i``)::

    dF_i = G_i dVdot_i - ad_{dV_i}^T G_i V_i - ad_{V_i}^T G_i dV_i - ad_{eta_i}^T W_g,i
           + sum_children X_c^T (dF_c - ad_{xi_c}^T F_c),        d tau_j = E_j^T dF_owner(j).

That is ``d ID(q, v, a)`` at ``a`` fixed, with ``ID = M a + h`` (eq. 2, 27). External loads (``cases.loads``) enter
the recursion as ``-W_ext,i`` (``ID = M a + h - tau_ext``) and their body wrenches move with the body: a world
vector's body components by ``x_b x omega_i`` (``omega_i`` the angular part of ``eta_i``), a spring's world force with
its point, ``dp = R_i (eta_v + eta_w x offset)`` (:func:`_external_tangents`); a body-frame vector is constant.

Constraint kinematics (:mod:`~formalisms.screw.constraints`, space frame). The space columns move as ``dS_k =
[sigma_owner(k), S_k]`` with ``sigma_i = J_s,i dq`` (the space twist of the configuration tangent), points as ``dp =
J_p dq``; the space twists and bias accelerations ``V_s,i = sum_k S_k v_k``, ``Jdot_s,i v = sum_k [V_s,owner(k), S_k
v_k]`` follow by the product rule, and the classical acceleration ``a_p = vd + wd x p + w x pdot`` likewise. The rows
of each declaration are differentiated from these (``d phi``, ``d Jc``, ``d (Jcdot v)``); a Pfaffian row's ``dA`` and
``d (Adot v)`` likewise, with a body-fixed direction turning by ``sigma_i x e`` (the angular part) and a rolling
contact's point moving over the disk (its ``dp`` the centre's plus that of ``e = -r u``).

Forward dynamics (eq. 2, 12-13). Unconstrained: ``dvdot/dx = -M^-1 dID/dx`` at ``a = vdot``, ``dvdot/du = M^-1 B``
on the Cholesky factor of ``M``. Constrained: the KKT system differentiated, ``M dvdot = -dID + dJc^T lam + Jc^T
dlam``, ``Jc dvdot = -(dJc vdot + d(Jcdot v))``, solved per direction by Gauss's principle on the split's own factor
and pseudo-inverse (same rank rule, minimum-norm multipliers), and ``dvdot/du = B_c B`` (eq. 17). With redundant
rows this is the derivative while the rank of ``S`` is locally constant (then ``dJc^T n`` of a null vector ``n`` of
``Jc^T`` lies in the range of ``Jc^T``, so the choice of ``lam`` does not matter); where the rank changes nearby (rows
dependent on the manifold, independent off it) the accelerations are not differentiable off the manifold and this is
the derivative within the constant-rank family.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Callable

import numpy as np

from cases.constraints import (JointCoupling, KnifeEdge, PointOnCircle, PointOnLine, PointsCoincide, PointVelocity,
                               RollingContact)
from cases.loads import ExternalWrench, PointSpring
from cases.model import Model
from formalisms.interface import Linearization, check_state, state_space
from formalisms.screw import constraints, dynamics, kinematics, lie
from formalisms.screw.kinematics import Kinematics
from formalisms.screw.linalg import Cholesky


@dataclass(frozen=True)
class Directions:
    """``dq``, ``dv`` (D, nv): the directions carried (module docstring), one per row."""

    dq: np.ndarray
    dv: np.ndarray

    @classmethod
    def coordinates(cls, nv: int) -> "Directions":
        """The ``2 nv`` coordinate directions: ``(e_j, 0)`` then ``(0, e_j)``."""
        eye, zero = np.eye(nv), np.zeros((nv, nv))
        return cls(np.vstack([eye, zero]), np.vstack([zero, eye]))


def _parents(kin: Kinematics, per_body: np.ndarray) -> np.ndarray:
    """``X_i x_parent(i)`` (..., nb, 6) for per-body twists ``x`` (..., nb, 6): each parent's twist seen in the child's
    frame, 0 at a root."""
    model = kin.model
    parent = np.array(model.parent_index)
    seen = (kin.from_parent_adjoint @ per_body[..., np.maximum(parent, 0), :, None])[..., 0]
    return np.where((parent >= 0)[:, None], seen, 0.0)


def _motion_tangents(kin: Kinematics, qd: np.ndarray, qdd: np.ndarray, d: Directions, V: np.ndarray,  # noqa: N803
                     Vdot: np.ndarray, xi: np.ndarray) -> tuple[np.ndarray, np.ndarray]:  # noqa: N803
    """``(dV, dVdot)`` (D, nb, 6) of the body twists and accelerations (module docstring), base to tip."""
    model, Ad = kin.model, kin.from_parent_adjoint
    ev, edv = kinematics.joint_twists(kin, qd), kinematics.joint_twists(kin, d.dv)
    dV = edv - lie.bracket(xi, _parents(kin, V))
    dVdot = lie.bracket(V, edv) - lie.bracket(xi, _parents(kin, Vdot))
    by_own = np.swapaxes(lie.ad(ev), -1, -2)                   # [dV_i, E_i v_i] = -ad_{E_i v_i} dV_i, as rows
    for i in model.topological_order:
        p = model.parent_index[i]
        if p >= 0:
            dV[:, i] += dV[:, p] @ Ad[i].T
            dVdot[:, i] += dVdot[:, p] @ Ad[i].T
        dVdot[:, i] -= dV[:, i] @ by_own[i]
    return np.ascontiguousarray(dV), np.ascontiguousarray(dVdot)


def _weight_tangents(kin: Kinematics, G: dynamics.Inertias, eta: np.ndarray) -> np.ndarray:  # noqa: N803
    """``dW_g,i`` (D, nb, 6): the weight's body wrench ``(m_i c_i x g_i, m_i g_i)`` (``g_i = R_i^T g``, acting at the
    COM, which is fixed in the body) when ``dT_i = T_i [eta_i]``: ``dg_i = -omega_i x g_i``, ``omega_i`` the angular
    part of ``eta_i`` (D, nb, 6)."""
    g = lie.rotate_back(kin.poses[:, :3, :3], np.asarray(kin.model.gravity, dtype=float))
    dg = -lie.cross(eta[..., :3], g)
    return lie.join(lie.cross(G.first_moment, dg), G.mass[:, None] * dg)


def _external_tangents(kin: Kinematics, eta: np.ndarray) -> np.ndarray:
    """``dW_ext,i`` (D, nb, 6): the external loads' body wrenches ``(offset x f_b + m_b, f_b)``
    (:func:`dynamics.external_wrenches`) when ``dT_i = T_i [eta_i]`` (module docstring)."""
    model = kin.model
    out = np.zeros(eta.shape)
    for load in model.loads:
        i = model.body_index(load.body)
        R, o = kin.poses[i, :3, :3], kin.poses[i, :3, 3]
        offset, omega = np.asarray(load.offset, dtype=float), eta[:, i, :3]
        dcouple = 0.0
        if isinstance(load, PointSpring):
            d = o + R @ offset - load.anchor
            dd = (eta[:, i, 3:] + lie.cross(omega, offset)) @ R.T                     # dp, (D, 3)
            length = float(np.sqrt(d @ d))
            if load.rest_length:
                scale = 1.0 - load.rest_length / length
                F = -load.stiffness * scale * d
                dF = -load.stiffness * (scale * dd + load.rest_length * np.outer(dd @ d, d) / length**3)
            else:
                F, dF = -load.stiffness * d, -load.stiffness * dd
            f = R.T @ F
            df = lie.cross(f, omega) + dF @ R                                          # R^T dF, row by row
        elif load.frame == "world":
            f = R.T @ load.force
            df = lie.cross(f, omega)
            if isinstance(load, ExternalWrench):
                dcouple = lie.cross(R.T @ load.moment, omega)
        else:
            df = np.zeros((len(eta), 3))
        out[:, i] += lie.join(lie.cross(offset, df) + dcouple, df)
    return out


def inverse_dynamics_tangents(kin: Kinematics, G: dynamics.Inertias, qd: np.ndarray, qdd: np.ndarray,  # noqa: N803
                              d: Directions) -> np.ndarray:
    """``d ID`` (D, nv): the derivative of ``ID(q, qd, qdd) = M qdd + h - tau_ext`` (eq. 2 by the wrench balance of eq.
    27, with gravity and the external loads) along each direction of ``d`` at ``qdd`` fixed (module docstring), at one
    state."""
    model = kin.model
    V, Vdot = kinematics.body_motion(kin, qd, qdd)
    xi = kinematics.joint_twists(kin, d.dq)
    dV, dVdot = _motion_tangents(kin, qd, qdd, d, V, Vdot, xi)
    F = dynamics.wrenches(kin, G, qd, qdd, 1.0, dynamics.external_wrenches(model, kin))
    GV = G.apply(V)
    eta = kinematics.body_twists(kin, d.dq)
    dF = (G.apply(dVdot) - lie.coad(dV, GV) - lie.coad(V, G.apply(dV)) - _weight_tangents(kin, G, eta))
    if model.loads:
        dF = dF - _external_tangents(kin, eta)
    moved = lie.coad(xi, F)                                    # ad_{xi_c}^T F_c: the child's wrench as its frame turns
    for i in reversed(model.topological_order):
        p = model.parent_index[i]
        if p >= 0:
            dF[:, p] += (dF[:, i] - moved[:, i]) @ kin.from_parent_adjoint[i]
    return dynamics.generalized_forces(kin, dF)


@dataclass(frozen=True)
class _PointTangent:
    """A point's ``dp`` (D, 3), ``dJ`` (D, 3, nv), ``dpdot`` (D, 3) and ``da`` (D, 3) (its classical acceleration at
    ``qdd = 0``, ``Jdot_p v``) along the directions, beside its kinematics ``x`` (``constraints._Point``) and velocity
    ``pdot`` (3,)."""

    x: constraints._Point
    pdot: np.ndarray
    dp: np.ndarray
    dJ: np.ndarray
    dpdot: np.ndarray
    da: np.ndarray


def _point_tangents(kin: Kinematics, qd: np.ndarray, d: Directions) -> Callable[[str | None, np.ndarray],
                                                                                _PointTangent]:
    """``point(body, offset)``: a body point's tangents (module docstring); a body of None is a fixed world point."""
    model, columns = kin.model, kin.columns
    rates = columns * qd[:, None]
    Vs = kinematics.twists(kin, qd)
    A = kinematics.bias_accelerations(kin, qd)
    sigma = kinematics.twists(kin, d.dq)                                  # J_s,i dq, (D, nb, 6)
    dcolumns = lie.bracket(kinematics.at_columns(kin, sigma), columns)    # dS_k = [sigma_owner(k), S_k]
    drates = dcolumns * qd[:, None] + columns * d.dv[..., None]
    dVs = kinematics._accumulate(kin, drates)
    dA = kinematics._accumulate(kin, lie.bracket(kinematics.at_columns(kin, dVs), rates)
                                + lie.bracket(kinematics.at_columns(kin, Vs), drates))
    base = constraints._point_kinematics(kin, qd)
    D = len(d.dq)

    def at(x: constraints._Point, dp: np.ndarray) -> _PointTangent:
        """The tangents of the material point of body ``x.body`` at world ``x.p``, the point moving by ``dp``."""
        i, p = x.body, x.p
        support = kin.screws.support[i][:, None]
        S, dS = columns * support, dcolumns * support
        dJ = np.swapaxes(dS[..., 3:] + lie.cross(dS[..., :3], p) + lie.cross(S[:, :3], dp[:, None, :]), -1, -2)
        w, v, wd = Vs[i, :3], Vs[i, 3:], A[i, :3]
        dw, dv, dwd, dvd = dVs[:, i, :3], dVs[:, i, 3:], dA[:, i, :3], dA[:, i, 3:]
        pdot = v + lie.cross(w, p)
        dpdot = dv + lie.cross(dw, p) + lie.cross(w, dp)
        da = dvd + lie.cross(dwd, p) + lie.cross(wd, dp) + lie.cross(dw, pdot) + lie.cross(w, dpdot)
        return _PointTangent(x, pdot, dp, dJ, dpdot, da)

    def point(body: str | None, offset: np.ndarray) -> _PointTangent:
        x = base(body, offset)
        if body is None:
            zero = np.zeros((D, 3))
            return _PointTangent(x, np.zeros(3), zero, np.zeros((D, 3, model.nv)), zero, zero)
        return at(x, d.dq @ x.J.T)

    def moving(body: str, p: np.ndarray, dp: np.ndarray) -> _PointTangent:
        """A point of ``body`` at world ``p`` that moves over the body, by ``dp`` (D, 3) along the directions."""
        i = model.body_index(body)
        J = kinematics.point_jacobian(kin, i, p)
        return at(constraints._Point(i, p, J, kinematics.classical_acceleration(Vs[i], A[i], p)), dp)

    def spin(body: str) -> _Spin:
        i = model.body_index(body)
        return _Spin(kin.poses[i, :3, :3], Vs[i, :3], dVs[:, i, :3], sigma[:, i, :3])

    point.moving, point.spin = moving, spin
    return point


@dataclass(frozen=True)
class _Spin:
    """A body's world rotation ``R``, angular velocity ``w`` and its tangents ``dw`` (D, 3), and the rotation of its
    frame ``sigma_w`` (D, 3) along the directions (the angular part of ``J_s,i dq``: ``dR = [sigma_w] R``)."""

    R: np.ndarray
    w: np.ndarray
    dw: np.ndarray
    sigma_w: np.ndarray


def _dot(x: np.ndarray, y: np.ndarray) -> np.ndarray:
    """``x . y`` over the last axis, broadcasting (a vector (3,) with tangents (D, 3): (D,))."""
    return np.sum(x * y, axis=-1)


def _point_velocity(c, point, D: int, nv: int):
    t = point(c.body, c.offset)
    return np.einsum("ra,Dan->Drn", c.directions, t.dJ), t.da @ c.directions.T


def _knife_edge(c, point, D: int, nv: int):
    """``A = e^T J``, ``Adot qd = (w x e) . pdot + e . a`` with ``e = R d`` turning by ``de = sigma_w x e``."""
    t, s = point(c.body, c.offset), point.spin(c.body)
    e = s.R @ c.direction
    de = lie.cross(s.sigma_w, e)
    dJc = de @ t.x.J + np.einsum("a,Dan->Dn", e, t.dJ)
    we = lie.cross(s.w, e)
    dbias = (_dot(lie.cross(s.dw, e) + lie.cross(s.w, de), t.pdot) + t.dpdot @ we + de @ t.x.a + t.da @ e)
    return dJc[:, None, :], dbias[:, None]


def _rolling(c, point, D: int, nv: int):
    """The rolling rows of ``constraints._rolling`` differentiated: the contact ``p_c = center + e`` moves by ``d center
    + de`` (the material point there: :func:`_point_tangents`' ``moving``), ``A = T J(p_c)`` and ``Adot qd = T (a(p_c)
    + w x (edot - w x e))``, with ``a = R axis`` turning by ``sigma_w x a`` and the contact terms by the chain rule;
    with ``lateral=False`` the one row along ``t = (a x n) / |a x n|``, its turning differentiated too."""
    s, center = point.spin(c.body), point(c.body, c.center)
    n, r = np.cross(c.plane[0], c.plane[1]), c.radius
    a = s.R @ c.axis
    da = lie.cross(s.sigma_w, a)
    raw, draw = n - (n @ a) * a, -(da @ n)[:, None] * a - (n @ a) * da
    length = float(np.sqrt(raw @ raw))
    u = raw / length
    du = (draw - (draw @ u)[:, None] * u) / length
    a_dot = lie.cross(s.w, a)
    da_dot = lie.cross(s.dw, a) + lie.cross(s.w, da)
    raw_dot = -(n @ a_dot) * a - (n @ a) * a_dot
    draw_dot = -(da_dot @ n)[:, None] * a - (n @ a_dot) * da - (da @ n)[:, None] * a_dot - (n @ a) * da_dot
    u_dot = (raw_dot - (u @ raw_dot) * u) / length
    du_dot = ((draw_dot - (du @ raw_dot)[:, None] * u - (u @ raw_dot) * du - (draw_dot @ u)[:, None] * u) / length
              - (draw @ u)[:, None] * u_dot / length)
    e, de, e_dot, de_dot = -r * u, -r * du, -r * u_dot, -r * du_dot
    t = point.moving(c.body, center.x.p + e, center.dp + de)
    dslide = (lie.cross(s.dw, e_dot - lie.cross(s.w, e))                 # d of w x (edot - w x e)
              + lie.cross(s.w, de_dot - lie.cross(s.dw, e) - lie.cross(s.w, de)))
    if not c.lateral:
        # the rolling direction (constraints._rolling): A = k^T J, Adot v = k . (a + slide) + kdot . pdot with k = b /
        # |b|, b = a x n, bdot = adot x n, kdot = (bdot - k (k . bdot)) / |b|; k turns by dk along the directions
        slide = lie.cross(s.w, e_dot - lie.cross(s.w, e))
        b, db = lie.cross(a, n), lie.cross(da, n)
        size = float(np.sqrt(b @ b))
        k = b / size
        dsize = db @ k
        dk = (db - dsize[:, None] * k) / size
        b_dot, db_dot = lie.cross(a_dot, n), lie.cross(da_dot, n)
        k_dot = (b_dot - (k @ b_dot) * k) / size
        dk_dot = ((db_dot - (k @ b_dot) * dk - ((dk @ b_dot) + (db_dot @ k))[:, None] * k) / size
                  - dsize[:, None] * k_dot / size)
        dJc = dk @ t.x.J + np.einsum("a,Dan->Dn", k, t.dJ)
        dbias = dk @ (t.x.a + slide) + (t.da + dslide) @ k + dk_dot @ t.pdot + t.dpdot @ k_dot
        return dJc[:, None, :], dbias[:, None]
    return np.einsum("ra,Dan->Drn", c.plane, t.dJ), (t.da + dslide) @ c.plane.T


def _circle(c, point, D: int, nv: int):
    t = point(c.body, c.offset)
    d, dd = (t.x.p - c.center) @ c.plane.T, t.dp @ c.plane.T
    grad, dgrad = 2.0 * d @ c.plane, 2.0 * dd @ c.plane
    v, dv = t.pdot @ c.plane.T, t.dpdot @ c.plane.T
    dJc = dgrad @ t.x.J + np.einsum("a,Dan->Dn", grad, t.dJ)
    dbias = 4.0 * dv @ v + dgrad @ t.x.a + t.da @ grad
    return dJc[:, None, :], dbias[:, None]


def _coincide(c, point, D: int, nv: int):
    a, b = point(c.body_a, c.offset_a), point(c.body_b, c.offset_b)
    return np.einsum("ra,Dan->Drn", c.directions, a.dJ - b.dJ), (a.da - b.da) @ c.directions.T


def _line(c, point, D: int, nv: int):
    t = point(c.body, c.offset)
    N = c.normals
    return np.einsum("ra,Dan->Drn", N, t.dJ), t.da @ N.T


def _coupling(c, point, D: int, nv: int):
    return np.zeros((D, 1, nv)), np.zeros((D, 1))


#: The rows' tangents of each declaration of ``cases.constraints`` (``constraints.terms``' rows), by its type.
_DECLARATIONS = {PointOnCircle: _circle, PointsCoincide: _coincide, PointOnLine: _line, JointCoupling: _coupling,
                 PointVelocity: _point_velocity, KnifeEdge: _knife_edge, RollingContact: _rolling}


def constraint_tangents(kin: Kinematics, qd: np.ndarray, d: Directions) -> tuple[np.ndarray, np.ndarray]:
    """``(dJc, dbias)`` (D, k, nv), (D, k): the derivatives of ``Jc`` and ``Jcdot qd`` along each direction of ``d``,
    every declaration of ``kin.model`` in model order (module docstring), at one state."""
    model = kin.model
    point = _point_tangents(kin, qd, d)
    parts = [_DECLARATIONS[type(c)](c, point, len(d.dq), model.nv) for c in model.constraints]
    return np.concatenate([p[0] for p in parts], axis=1), np.concatenate([p[1] for p in parts], axis=1)


def _kkt(gauss: constraints.Gauss | None, factor: Cholesky, f: np.ndarray, bias: np.ndarray | None) -> np.ndarray:
    """``x`` (n, r) with ``M x = f + Jc^T mu``, ``Jc x = -bias`` for right-hand sides ``f`` (n, r), ``bias`` (k, r), by
    Gauss's principle on the split's factor and pseudo-inverse (:class:`constraints.Gauss`); ``M^-1 f`` without
    constraints (``gauss`` None)."""
    a = factor.solve(f[None])[0]
    if gauss is None:
        return a
    y = gauss.A_pinv[0] @ (-bias - gauss.Jc[0] @ a)
    return a + factor.backward(y[None])[0]


def linearize(model: Model, q, qd, u) -> Linearization:
    """A and B of eq. (11) (:class:`~formalisms.interface.Linearization`) from the exact tangents of this backend's
    recursions (module docstring): ``dvdot/d(q, v) = -M^-1 dID`` (unconstrained) or the differentiated KKT system of
    eq. (12-13), and ``dvdot/du = B_c B`` (eq. 17; ``M^-1 B`` unconstrained). ``vdot`` is the split's total."""
    q, qd, u = check_state(model, q, qd, u)
    kin, G = kinematics.forward_kinematics(model, q), dynamics.Inertias.of(model)
    M, h, _, _ = dynamics.terms(kin, G, qd)
    external = dynamics.external_wrenches(model, kin)
    if external is not None:                                     # h - tau_ext: the loads act with gravity
        h = h - dynamics.external_forces(kin, external)
    factor = Cholesky.of(M[None])
    if not factor.positive.all():
        raise ValueError(f"model '{model.name}': the mass matrix is not positive definite at q = {q.tolist()} "
                         f"(Cholesky failed); eigenvalues {np.linalg.eigvalsh(M).tolist()}")
    tau = model.input_map @ u
    d = Directions.coordinates(model.nv)
    gauss, bias = None, None
    if model.constraints:
        rows = constraints.terms(kin, q, qd)
        gauss = constraints.Gauss.build(model, factor, rows.jacobian[None], rows.bias[None])
        vdot, lam = (x[0] for x in gauss.solve((tau - h)[None]))
        dJc, dbias = constraint_tangents(kin, qd, d)
        bias = (dJc @ vdot + dbias).T
    else:
        vdot = factor.solve((tau - h)[None, :, None])[0, :, 0]
    f = -inverse_dynamics_tangents(kin, G, qd, vdot, d).T
    if gauss is not None:
        f = f + np.einsum("Dkn,k->nD", dJc, lam)
    dvdot = _kkt(gauss, factor, f, bias)
    ctrl = _kkt(gauss, factor, model.input_map.astype(float), None if gauss is None else np.zeros((model.k, model.m)))
    nv = model.nv
    return state_space(model, qd, dvdot[:, :nv], dvdot[:, nv:], ctrl, vdot)
