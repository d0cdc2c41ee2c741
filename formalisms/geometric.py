"""Coordinate-free geometric mechanics (article 6.4, eqs. 24-25, 29): the kinetic-energy metric, its Levi-Civita
connection and the intrinsic drift field, evaluated in any chart ``q = psi(p)``.

The configuration manifold ``Q`` carries the Riemannian metric of the kinetic energy (6.4.3). In a chart ``p`` (the
joint chart ``p = q``, or any ``q = psi(p)`` from the harness) this backend builds everything itself, in casadi SX:

* Kinematics from ``cases.model``: ``X_body = X_parent * (rotation, translation) * motion(q_i)``, a revolute
  motion the Rodrigues rotation by ``q_i`` about the unit ``axis``, a prismatic one the translation ``q_i axis``;
  ``q = psi(p)`` is substituted, so the body rotations ``R_i``, origins ``o_i`` and centres of mass
  ``c_i = o_i + R_i com_i`` are expressions of ``p``.
* Energies: ``T(p, pd) = sum_i 1/2 m_i |c_i'|^2 + 1/2 w_i^T I_i w_i`` with ``c_i' = Jc_i pd`` (``Jc_i = dc_i/dp``,
  i.e. ``jtimes(c_i, p, pd)``) and the body angular velocity ``w_i = vee(R_i^T R_i')``, ``R_i' = (dR_i/dp) pd``
  (``I_i`` about the COM, body frame); ``V(p) = -sum_i m_i gravity . c_i``. A joint with armature a (a rotor geared
  to it) adds ``1/2 a (|w_m|^2 + |p_m'|^2)`` of the joint's own motion, the body frame relative to its joint frame
  (:func:`_rotor`): ``1/2 a qd_i^2`` for a revolute or prismatic joint, ``1/2 a |v_i|^2`` over a ball's or a free
  joint's velocities, in any chart.
* The metric (6.4.3) ``M_p = d^2 T / dpd^2``: since ``c_i'`` and ``w_i = Jw_i pd`` are linear in pd, the Hessian is
  ``sum_i m_i Jc_i^T Jc_i + Jw_i^T I_i Jw_i`` (plus the rotors' ``a (Jw_m^T Jw_m + Jp_m^T Jp_m)``: in the joint chart
  the constant diagonal ``diag(a)``, so the Christoffel symbols of the first kind are unchanged and those of the
  second kind change through ``M^-1``) exactly, and it is formed that way (``casadi.hessian`` of T gives the
  same matrix with 50 % more operations once dM is differentiated from it; the tests check ``M pd = dT/dpd`` and
  ``T = 1/2 pd^T M pd`` against the automatic differentiation of T). Its partial derivatives
  ``dM[k] = d M_p / dp_k`` (of the upper triangle; M is symmetric) and the differential ``dV/dp`` by automatic
  differentiation.

The connection is computed numerically at the point, by one formula shared with the generic-metric tools
(:func:`christoffel_of`, :func:`curvature_of`):

    Gamma_{l,jk} = 1/2 (d_j M_lk + d_k M_lj - d_l M_jk)        (first kind)
    Gamma^i_jk   = M^{il} Gamma_{l,jk}                          (second kind: a Cholesky solve, no inverse)

and eq. (25), the intrinsic drift field on TQ, with ``grad V = M^-1 dV/dp`` (the index raised by the metric):

    f_drift(p, pd) = (pd, -Gamma(pd, pd) - grad V),     Gamma(pd, pd)^i = Gamma^i_jk pd^j pd^k.

Eq. (24) with the control covector ``tau_p`` (``B u`` in the joint chart, ``Dpsi^T B u`` in a chart) raised by the
metric, ``G u = M^-1 tau_p``, gives the split (eq. 9): ``drift`` as above, ``ctrl = M^-1 tau_p``, and ``total``
solved on its own, ``M^-1 (tau_p - dV/dp) - Gamma(pd, pd)``, never as a sum of the other two.
``M Gamma(pd, pd)`` is the first-kind contraction, the chart's ``C qd`` of eq. (7); ``dV/dp`` is its ``g``.

Because nothing is transformed from another chart, :func:`split_chart` is a genuine check of chart invariance
(6.4.6, 9.1): the accelerations it returns are ``pdd``, which the harness compares with the joint answer mapped by
``pdd = Dpsi^-1 (qdd - (d/dt Dpsi) pd)``. Kinetic energy, power and the task acceleration (physical) are the same
in every chart.

External loads (``cases.loads``; article 2.3, eq. 12) as a covector by virtual power, in the same Function: the
power of the non-conservative loads along the rates, ``P(p, pd) = sum f . (dx/dp pd) + m . w`` (``x`` the load's
point ``o_b + R_b offset``, ``w`` the body's world angular velocity ``R_b vee(R_b^T R_b')``; body-frame vectors turned
by ``R_b``), is linear in pd and ``tau_ext = dP/dpd``; a spring is a potential of its own, ``V_s = 1/2 k (|x - a| -
L0)^2``, and contributes ``-dV_s/dp`` (kept apart from V, so the energy ``T + V`` stays the gravitational one and the
harness counts the spring's power as external). In any chart this is the chart's covector (``Dpsi^T tau_ext``). It
joins the potential's differential, ``dV/dp - tau_ext``, wherever that enters (the drift at rest ``grad V`` raised by
the metric, the linearization's residual).

Task drift (eq. 23): for ``model.task_point()`` with directions ``D``, ``x(p) = D (o_b + R_b offset)``; the classical
acceleration at the drift is ``J drift + Jdot pd`` with ``J = dx/dp`` and ``Jdot pd = jtimes(jtimes(x, p, pd), p, pd)``.

Task-space inertia (eq. 22): ``task_inertia = (J M_p^-1 J^T)^-1`` from the same ``J`` and the metric, in any chart
(``J_p = J_q Dpsi`` and ``M_p = Dpsi^T M Dpsi`` give the same matrix, so it is chart-invariant); with constraints
still the unconstrained metric's (eq. 22 puts them in ``F_constr``).

Constraints (article 5, eqs. 12-17; 6.4.5 "constraints restrict motion to submanifolds of Q"; 7.2 reaction
covectors). ``phi(p)`` is each declaration's function (``cases.constraints``) of this backend's own point positions
``o_b + R_b offset`` through the chart, so ``phi(psi(p))`` is the same function in every chart and the multipliers
are chart-invariant. ``Jc = dphi/dp`` and ``Jcdot pd = (d(Jc pd)/dp) pd`` by automatic differentiation, in the same
Function. Eq. (24) with the reaction covector ``Jc^T lam`` reads, as covectors (index lowered):

    M (pdd + Gamma(pd, pd)) + dV/dp = tau + Jc^T lam,        Jc pdd = -Jcdot pd   (eqs. 12, 13)

with ``M Gamma(pd, pd)`` the first-kind contraction. It is solved by the null-space (tangent-space) method, not a
KKT block solve: the admissible accelerations ``H_t`` (eq. 16) are ``pdd_p + D`` with the constraint distribution
``D = ker Jc`` and ``pdd_p = Jc^+ (-Jcdot pd)``; with ``Z`` an orthonormal basis of ``D`` (the right singular
vectors of ``Jc`` beyond its rank) and ``f = tau - M Gamma(pd, pd) - dV/dp``,

    pdd = pdd_p + Z (Z^T M Z)^-1 Z^T (f - M pdd_p),      lam = (Jc^T)^+ (M pdd - f)   (minimum norm),

i.e. the metric-orthogonal projection of the free motion onto ``H_t``: ``Z^T`` of eq. (12) removes ``Jc^T lam``.
``total``/``lam`` use ``tau``, ``drift``/``lam_drift`` ``tau = 0`` (eq. 14), each its own solve. ``ctrl`` is
``Z (Z^T M Z)^-1 Z^T tau``, which is the constraint-consistent input map of eq. (17) applied to ``tau``:
``P = Z (Z^T M Z)^-1 Z^T M`` and ``I - M^-1 Jc^T S^+ Jc`` (``S = Jc M^-1 Jc^T``) are both the M-orthogonal
projector onto ``D`` (each is idempotent, fixes ``D`` and has an M-orthogonal kernel: ``range M^-1 Jc^T``), so
``B_c = (I - M^-1 Jc^T S^+ Jc) M^-1 = P M^-1 = Z (Z^T M Z)^-1 Z^T``.

Rank: the interface's convention. The eigen-directions ``U_r`` of the constraint-space inverse inertia
``S = Jc M^-1 Jc^T`` above ``CONSTRAINT_RCOND`` times its largest eigenvalue (and above the degenerate floor
``(DEGENERATE_ROW L)^2 / inertia_scale``) are the independent constraints; the distribution is ``ker U_r^T Jc`` and
the multipliers lie in ``range U_r``. S is decomposed from the constraint covectors whitened by the metric,
``X = L^-1 Jc^T`` (``M = L L^T``): the triangle R of ``X = Q R`` has ``R^T R = S`` (eigh of that). (Deciding the rank
from Jc's own singular values instead would drop a nearly redundant direction that the metric does not, at a
four-bar near its change point, and move the accelerations far from the other backends'.) Redundant rows (a
duplicated constraint) and a rank drop (a four-bar at its change point) never raise: the pseudo-inverses give the
minimum-norm multipliers, unique ``pdd`` and ``Jc^T lam`` when ``H_t`` is not empty, and finite least-squares numbers
when it is (the harness flags BREAKDOWN from the conditions below).

Reported numbers, all computed here (the interface supplies only types and validators): cond(M) and ``||M^-1||``
from the eigenvalues of the metric's operator in the frame of its Cholesky factor (``L^T L``, similar to M); the
powers as covectors paired with the velocity in the chart (``tau(pd)``, ``(Jc^T lam)(pd)``); cond S, the kept cond,
the rank and the consistency of ``S lam = r`` (its share in S's redundant directions) from the decomposition above;
the task inertia ``Lambda = (J M^-1 J^T)^-1`` from the QR of the whitened task covectors ``L^-1 J^T``, whose triangle
is the Cholesky factor of ``J M^-1 J^T`` (``Lambda = R^-1 R^-T``, its condition from R's singular values).

Spherical and free joints: the group chart (article 2.1-2.2 configurations on SO(3) and SE(3) and body twists,
6.2 the exponential map, 6.4 "the globe, not the map"). Such a joint's configuration lives on a Lie group, which no
single chart covers (its four quaternion numbers are not coordinates). The backend therefore does what 6.4 asks and
works on the manifold itself, in the chart centred at the current configuration that the group's left-invariant
(body-frame) structure provides: the exponential chart with the exponential on the right,

    spherical   R(xi) = R0 exp([xi]x)                 (xi in R^3)
    free        X(xi) = X0 exp6(xi),  exp6(xi) = exp([[ [w]x, rho ], [0, 0]]),  xi = (rho, w) (linear, angular)

with ``R0 = R(quat) = I + 2 w [x y z]x + 2 [x y z]x^2`` and ``X0 = (R0, position)`` read from q (``cases.model``);
revolute and prismatic joints keep their own coordinate. Along a motion through the chart's origin the body velocity
is ``X^-1 Xdot = dexp_{-xi}(xid) = xid - 1/2 ad_xi xid + O(|xi|^2 |xid|)``, so at ``xi = 0``

    v = xid,      d/dt v = xidd - 1/2 ad_xid xid = xidd        (ad_x x = [x, x] = 0):

the chart's ``(pd, pdd)`` at the origin are the model's velocity v (the body angular velocity, the body twist:
Pinocchio's convention) and acceleration ``vdot``, so eqs. (24)-(25) in this chart at ``xi = 0`` are the equations of
motion in v-space with nothing transformed (the tests check both identities, through this chart and with the exact
exponential). The chart's metric is ``M_xi = A(xi)^T M(q (+) xi) A(xi)`` with ``A = dexp_{-xi}``: at 0 it is the
v-space mass matrix, and its derivatives ``d_k M_xi = D_k M - 1/2 (ad_k^T M + M ad_k)`` (``D_k`` along the curve
``q (+) h e_k``, ``ad_k`` the bracket with the k-th unit velocity in its joint's block) carry the group's structure
into the connection: for one free body (M constant in v-space) the first-kind contraction is
``M Gamma(v, v) = -ad_v^T M v``, and eq. (25) becomes Euler–Poincaré's ``M vdot = ad_v^* (M v)`` (Euler's equations
``I wd + w x I w = 0``, tested in closed form).

The exponential is written as its Taylor polynomial of degree :data:`EXP_ORDER` = 2 (:func:`_exp_series`), because
casadi differentiates expressions and the closed forms (``sin|w| / |w|``, ...) are not differentiable as written at
the one point used, ``xi = 0``. This is exact, not an approximation: every output of the compiled Function is a
derivative of order at most 2 in the chart coordinates at ``xi = 0`` (M and dV first, dM, ``Jdot pd``, ``Jcdot pd``
and ``dE/dp`` second), and there the polynomial of degree 2 has exactly the exponential's derivatives up to order 2
(the tests: degrees 2, 3 and 6 give the same numbers, degree 1 does not). The expressions are built and
differentiated in the chart coordinates p (nv of them) and then evaluated at the origin (``casadi.substitute``:
a revolute or prismatic coordinate at its value in q, ``xi = 0``), so the Functions take the configuration q (nq
numbers, unit quaternions) and the velocity v. Everything downstream (the connection, the split, the constrained
null-space method, the batches) is unchanged and reads v-space numbers: M is nv x nv, Jc and J are taken along v.

For such a model the public geometric objects (:func:`metric`, :func:`metric_derivatives`, :func:`christoffel`,
:func:`energy`, :func:`drift_field`, :func:`energy_rate`) take q (nq) and rates of nv and are those of this chart at
``xi = 0``: ``metric`` the v-space mass matrix, ``metric_derivatives`` the chart's ``d_k M_xi`` above (with the ``ad``
terms, not the derivative of the v-space matrix alone), ``christoffel`` its connection (``M Gamma(v, v)`` is the
v-space velocity-product vector ``C(q, v) v``), ``energy_rate`` exact because ``pd = v`` and ``pdd = vdot`` there.
The conservation checks (``crosscheck.checks.conservation``) compare these with the Euler–Lagrange backend's and
Pinocchio's terms in the same chart (v-space). Joint couplings relate revolute and prismatic coordinates only.

Charts of the group (article 6.4 "a map of the globe", 6.4.6, 9.1). A chart whose ``psi`` returns the whole q (nq
entries) from nv coordinates p, such as the harness's ZYX Euler-angle chart (``crosscheck.checks.charts.EulerZYX``: a
spherical block ``(yaw, pitch, roll)``, a free block ``(position, yaw, pitch, roll)``, revolute and prismatic
coordinates as they are, each quaternion written with sines and cosines of the half angles), is evaluated natively,
exactly as a chart of a model with revolute and prismatic joints only: ``q = psi(p)`` is substituted into the
kinematics (:func:`_chart_group_frames`), each joint at its own ``motion(q_i)``, ``(R(quat), 0)`` for a spherical
joint and ``(R(quat), position)`` for a free one, ``R(quat) = I + 2 w [x y z]x + 2 [x y z]x^2`` the polynomial of psi's
quaternion (a rotation for every p, since that quaternion is unit as a function of p), and everything is derived in p
by automatic differentiation: the body velocities ``w_i = vee(R_i^T R_i')`` and ``c_i' = Jc_i pd`` with
``' = (d/dp) pd``, so ``M_p = sum_i m_i Jc_i^T Jc_i + Jw_i^T I_i Jw_i`` (which is ``Dpsi^T M Dpsi`` with the
chart's own ``Dpsi``, never formed), its derivatives, eq. (25) and the rest unchanged. No exponential and no group
chart is involved (the Euler angles are ordinary coordinates on an open set of the group, away from gimbal lock), and
the chart's velocity-product terms (the Euler-angle rates' ``(d/dt Dpsi) pd``) come out of the Christoffel symbols of
``M_p``. :func:`split_chart` then returns ``pdd``
(nv), ``tau_p = Dpsi^T B u`` as given, ``Jc = dphi(psi(p))/dp``, ``Jcdot pd`` in p, ``Jc^T lam`` as a covector in p, the
chart-invariant multipliers, kinetic energy, power, task drift and task inertia, and cond of ``M_p``; the public
geometric objects take ``chart=`` with p and rates of nv. At gimbal lock (pitch = +-pi/2) ``M_p`` is singular (the
chart has no coordinates for the motion): the split raises the not-positive-definite ValueError there, or reports
cond(M_p) of order 1/eps when rounding leaves the factor positive, and the harness skips such states. Any other
chart (one whose psi fails on nv coordinates, such as the group's identity chart ``p = q``, or returns another number
of entries, or quaternions that are not unit at seeded test points), and ``chart=None`` in :func:`split_chart` (the
group chart itself: :func:`split`), raise ModelNotSupported with the reason.

Velocity representations (docs/design.md "Configuration on Lie groups"; a chart whose ``representation`` is ``"world"``
or ``"mixed"``, read duck-typed). The configuration stays q and the velocity is w with ``v = T(q) w``, in each joint's
REFERENCE frame (the frame its q is measured in: the parent's frame moved by the body's fixed placement; the world for
a floating base at the identity placement): world, a free joint's spatial twist ``(pdot - omega_s x p, omega_s)`` and
a ball joint's ``omega_s = R w_b``; mixed, a free joint's ``(pdot, omega_s)``. This backend does not map anything: it
builds the group chart with the exponential on the LEFT (:func:`_group_frames` with ``side``),

    spherical   R(xi) = exp([xi]x) R0
    free world  X(xi) = exp6(xi) X0                free mixed   R(xi) = exp([xi_ang]x) R0,  position(xi) = p0 + xi_lin

where the right-trivialized velocity ``Xdot X^-1 = dexp_xi(xid) = xid + 1/2 ad_xi xid + O(|xi|^2 |xid|)`` gives at
``xi = 0`` ``xid = w`` (the spatial twist, ``omega_s``; mixed: ``pdot``, ``omega_s``) and
``d/dt w = xidd + 1/2 ad_xid xid = xidd`` (``ad_x x = 0``; mixed: the position is affine in xi). The same Functions
as for the right chart (the metric ``M_xi`` at 0 is ``T^T M T``, its derivatives carry the left structure, the
control covector is ``T^T B u``, passed in as ``tau_p``) then give ``wdot`` from eqs. (24)-(25) directly. A
representation chart of a model without group joints is ModelNotSupported.

The drift's parts (article 4.5-4.6): ``zvcf = -grad V = -M^-1 dV/dp`` (the drift at rest) and ``drift_velocity =
-Gamma(pd, pd)``, each raised by the metric on its own; with constraints each is its own null-space solve, zvcf with the
forces ``-dV/dp`` and no bias, drift_velocity with ``-M Gamma(pd, pd)`` and the bias ``Jcdot pd``, so they add up to the
drift to rounding (the system is linear in forces and bias). In every Split, joint chart and chart alike.

World data. Gravity, each root body's placement, the task point's directions, the world points and directions of
the constraints and the world-frame data of the loads are parameters of the SX graph (``cases.world``,
:class:`_World`), read by every Function after the point (:func:`_arguments`): the Functions are built once per model
shape (``cases.world.shape_digest``), and a moved scene or a gravity-free copy evaluates them with its own numbers.

Linearization (article 4.8, eq. 11; :func:`linearize`, :func:`linearize_chart`). The accelerations ``a`` (and
multipliers) solve ``r(p, pd, a, lam) = (tau, 0)``, eqs. (12)-(13) written with this backend's own expressions,
``r = [M a + M Gamma(pd, pd) + dV/dp - Jc^T lam; Jc a + Jcdot pd] = [r_dyn; r_con]`` (M, the first-kind contraction
from the dM of the Function, dV, Jc and Jcdot pd read out of the Function's own SX expression). casadi differentiates r
in forward mode along a direction of the point and pd (``jtimes``: a second Function, built on the first linearize of
a (model, chart) and cached with the first; never by split), evaluated at the split's own ``(total, lam)`` along every
coordinate in one batched call, and the implicit function theorem gives
the derivatives: per direction ``M dvdot - Jc^T dlam = dtau - dr_dyn``, ``Jc dvdot = -dr_con``, solved as the split
is (the metric's Cholesky factor; with constraints the same null-space solve with the same independent rows, which
is eq. (17)'s ``B_c`` for the inputs). This is the KKT system differentiated, exact to rounding: no finite
differences, and no symbolic solve (casadi SX has no Cholesky with the backend's rank rule, and its symbolic QR solve
of an n x n system would be differentiated through n^3 operations). With spherical or free joints the point is the
configuration q itself (the group chart's values at its origin are functions of q): ``dvdot/dq`` along ``q (+) dq``
is the ambient derivative times the derivative of ``integrate`` (:func:`_tangent_map`), and the top rows are the
interface's ``[-ad_v, I]``; in a chart they are ``[0, I]``.

Performance: per (model, chart) one casadi SX Function evaluates M, every dM/dp_k, dV/dp, T, J, Jdot pd and (with
constraints) phi, Jc, Jcdot pd in a single call through casadi's buffer interface (built once and cached by the model
digest and the chart key: 0.1 s for the 9-joint panda, 65k SX instructions; built without casadi's common
subexpression elimination, which takes 8-13 times as long and is left to the compiled code, :func:`_eliminated`); the
rest is one Cholesky factor, one
LAPACK solve with all right-hand sides and small numpy contractions (with constraints: one SVD of Jc, and the factor
is that of ``Z^T M Z``). The small LAPACK calls (``potrs``, ``trtrs``, ``geqrf``, ``trtri``) are made directly: scipy's
wrappers check their arguments for longer than the calls take.

Batches (:func:`split_batch`): the same Function mapped over a block of states (``Function.map``, through a buffer on
the numpy arrays), then the connection, the metric solves and (with constraints) the null-space method for the whole
stack in numpy: ``Gamma(pd, pd)`` as ``M^-1`` of the first-kind symbols contracted with the rates (the same
connection, raised after contracting), batched Cholesky solves, the constrained states grouped by the rank of S.

Compiled evaluation. casadi's interpreter spends most of a panda state's time on the Function (its SX virtual machine
runs the 65k instructions at several ns each). Once a Function has evaluated :data:`COMPILE_AFTER` states in this
process and spent as long interpreted as its compilation is estimated to take (:data:`COMPILE_SECONDS_PER_INSTRUCTION`:
the total cost is then at most twice that of the better choice made in hindsight) it is rebuilt with common
subexpressions eliminated (the panda's 40k instructions; the same numbers bit for bit) and compiled to C by the system
compiler (``cc`` or ``gcc``, :data:`C_FLAGS`) and evaluated natively from then on, one C call per state or per block of
states. The C is written here from the Function's own instruction list (:func:`_c_source`): one statement per SX
instruction on casadi's work vector, in casadi's order, with the products and sums never fused (``-ffp-contract=off``),
so the compiled code does the interpreter's arithmetic operation for operation; it is cut into functions of
:data:`C_PART` statements, because the compiler's time grows faster than the size of one function (measured at -O1 on
the panda's 40k instructions: 43 s of CPU as one function, 14 s in parts of 1000, 8 s in parts of 100 to 250; casadi's
own ``Function.generate``, one function, 16 s), while the code runs as fast. The shared library is cached
on disk (``$CROSSCHECK_CACHE/geometric``, else ``~/.cache/crosscheck/geometric``) under a digest of the C and the
compiler command, so code derived differently (a fault injected, another chart) is never served for it, and with a
digest of its bytes beside it: a file that does not match, or does not load, is compiled again; a cache that cannot
be written only costs the compilation next time. Without a compiler, with ``CROSSCHECK_COMPILE=0``, or when
compiling fails (a RuntimeWarning with the compiler's message), the Function stays interpreted; :func:`evaluation`
says which applies. The few states of a gate never pay a compilation.

Public API: :func:`split`, :func:`split_chart`, :func:`split_batch`, :func:`linearize`, :func:`linearize_chart` (the
:class:`Formalism` contract); the geometric
objects of a mechanism :func:`metric`, :func:`metric_derivatives`, :func:`christoffel`, :func:`energy`,
:func:`drift_field`, :func:`energy_rate` (all in the joint chart or any ``chart``; with spherical or free joints in
the group chart at ``xi = 0`` when ``chart`` is None, or in a chart whose psi returns the whole q); the same machinery
for any metric,
:func:`christoffel_of` and :func:`curvature_of`; the shared formula :func:`christoffel_symbols`.
"""

from __future__ import annotations

import ctypes
import hashlib
import math
import os
import shutil
import subprocess
import tempfile
import threading
import time
import warnings
import weakref
from dataclasses import dataclass
from pathlib import Path
from typing import Callable, NamedTuple

import casadi as ca
import numpy as np
import scipy.linalg

from cases.constraints import (JointCoupling, KnifeEdge, PointOnCircle, PointOnLine, PointsCoincide, PointVelocity,
                               RollingContact)
from cases.loads import ExternalWrench, PointSpring
from cases.model import Model
from cases.world import label_of, shape_digest, world_data
from formalisms.interface import (CONSTRAINT_RCOND, DEGENERATE_ROW, Formalism, Linearization, ModelNotSupported,
                                  Split, SplitBatch, StateError, cache_dir, check_batch, chart_vectors, check_state,
                                  joint_vectors, state_space, used_cache_file, write_cache_file)

JOINT_CHART = "joint"  # cache key of the joint chart q = p (chart=None)



# ------------------------------------------------------------------------------------------------ the connection


def christoffel_first_kind(dM: np.ndarray) -> np.ndarray:
    """``Gamma_{l,jk} = 1/2 (d_j M_lk + d_k M_lj - d_l M_jk)`` as an (n, n, n) array indexed ``[l, j, k]``, from the
    metric derivatives ``dM[k, i, j] = d M_ij / dx_k``. Linear in ``dM``: applied to ``d_m dM`` it gives
    ``d_m Gamma_{l,jk}`` (used by :func:`curvature_of`). A stack (..., n, n, n) gives each point's."""
    return 0.5 * (dM.swapaxes(-3, -2) + dM.swapaxes(-3, -2).swapaxes(-2, -1) - dM)


def christoffel_symbols(M: np.ndarray, dM: np.ndarray, factor=None, covectors=()) -> tuple:
    """The Levi-Civita connection of the metric ``M`` at a point: ``(Gamma, first, raised)`` with
    ``Gamma[i, j, k] = Gamma^i_jk`` (second kind, the index raised by a Cholesky solve with ``factor`` =
    ``cho_factor(M)``, computed when not given), ``first[l, j, k] = Gamma_{l,jk}`` (:func:`christoffel_first_kind`)
    and ``raised`` the list ``M^-1 c`` of the given ``covectors`` (solved with the same factor, in the same LAPACK
    call: separate right-hand sides, so each is its own solve). The one formula behind both the mechanism path and
    :func:`christoffel_of`."""
    n = M.shape[0]
    first = christoffel_first_kind(dM)
    if factor is None:
        factor = _cholesky(M)
    rhs = np.empty((n, n * n + len(covectors)), order="F")
    rhs[:, :n * n] = first.reshape(n, n * n)
    for j, c in enumerate(covectors):
        rhs[:, n * n + j] = c
    x = _cho_solve(factor, rhs)
    return x[:, :n * n].reshape(n, n, n), first, [x[:, n * n + j] for j in range(len(covectors))]


def _cho_solve(factor, rhs: np.ndarray) -> np.ndarray:
    """``M^-1 rhs`` from ``factor = cho_factor(M)``: LAPACK potrs directly (scipy's cho_solve wrapper costs ~30 us
    of argument checking per call, more than the solve)."""
    c, lower = factor
    x, info = _POTRS(c, rhs, lower=int(bool(lower)))
    _checked("potrs", info)
    return x


_POTRS, _TRTRS, _GEQRF, _TRTRI = scipy.linalg.lapack.get_lapack_funcs(("potrs", "trtrs", "geqrf", "trtri"),
                                                                      (np.zeros(1),))


def _checked(routine: str, info: int) -> None:
    """A LAPACK call made directly (module docstring, performance) failed: a ValueError naming it."""
    if info != 0:
        raise ValueError(f"LAPACK {routine} failed (info = {info})")


def _cholesky(M: np.ndarray):
    try:
        return scipy.linalg.cho_factor(M)
    except np.linalg.LinAlgError:
        raise ValueError(f"the metric is not positive definite (Cholesky failed); eigenvalues "
                         f"{np.linalg.eigvalsh(M).tolist()}") from None


# ------------------------------------------------------------------------------------- generic metric machinery


def _metric_derivatives(metric_fn: Callable, x, order: int) -> list[np.ndarray]:
    """``[G, dG, d2G]`` (up to ``order``) of ``metric_fn`` at the numeric point ``x``: ``dG[k, i, j] = d_k G_ij``,
    ``d2G[m, k, i, j] = d_m d_k G_ij``, by casadi AD of the symbolic metric."""
    x = np.asarray(x, dtype=float).reshape(-1)
    n = x.size
    if n == 0 or not np.all(np.isfinite(x)):
        raise ValueError(f"the point must be a non-empty finite vector, got {x.tolist()}")
    X = ca.SX.sym("x", n)
    G = ca.SX(metric_fn(X))
    if G.shape != (n, n):
        raise ValueError(f"metric_fn returned a {G.shape[0]}x{G.shape[1]} matrix at a point of {n} coordinates; "
                         f"expected {n}x{n}")
    outs = [G]
    dG = ca.jacobian(ca.vec(G), X)  # (n^2, n); column k is vec(d_k G)
    if order >= 1:
        outs += [ca.reshape(dG[:, k], n, n) for k in range(n)]
    if order >= 2:
        for m in range(n):
            outs += [ca.reshape(ca.jacobian(dG[:, k], X)[:, m], n, n) for k in range(n)]
    values = [np.array(v.full()) for v in ca.Function("metric", [X], outs).call([ca.DM(x)])]
    result = [values[0]]
    if order >= 1:
        result.append(np.stack(values[1:1 + n]))
    if order >= 2:
        result.append(np.stack(values[1 + n:]).reshape(n, n, n, n))
    G_num = result[0]
    if not np.allclose(G_num, G_num.T, rtol=1e-12, atol=1e-12 * np.abs(G_num).max()):
        raise ValueError(f"metric_fn is not symmetric at x = {x.tolist()}: {G_num.tolist()}")
    return result


def christoffel_of(metric_fn: Callable, x) -> np.ndarray:
    """Christoffel symbols of the second kind of a Riemannian metric at the point ``x``: ``Gamma[i, j, k] =
    Gamma^i_jk`` (symmetric in j, k), with the same formula as the mechanism path (:func:`christoffel_symbols`).

    ``metric_fn`` maps a casadi SX column of n coordinates to an n x n SX matrix (symmetric, positive definite at
    ``x``); ``x`` is numeric. Example: polar coordinates on the plane, ``lambda x: ca.diag(ca.vertcat(1, x[0]**2))``.
    """
    G, dG = _metric_derivatives(metric_fn, x, 1)
    return christoffel_symbols(G, dG)[0]


def curvature_of(metric_fn: Callable, x) -> np.ndarray:
    """The Riemann curvature tensor ``R[i, j, k, l] = R^i_jkl`` of the metric at ``x`` (n, n, n, n), in the
    convention ``R(d_k, d_l) d_j = R^i_jkl d_i``:

        R^i_jkl = d_k Gamma^i_lj - d_l Gamma^i_kj + Gamma^i_km Gamma^m_lj - Gamma^i_lm Gamma^m_kj,

    so the sectional curvature of the coordinate plane (k, l) is ``g_ki R^i_lkl / (g_kk g_ll - g_kl^2)``: the unit
    sphere ``diag(1, sin^2 theta)`` in (theta, phi) has ``R^theta_{phi theta phi} = sin^2 theta``, curvature 1.

    Numeric at the point from the metric's first and second derivatives (casadi AD): ``d_m Gamma^i_jk =
    M^-1 (d_m Gamma_{.,jk} - (d_m M) Gamma^._jk)``, the first-kind part by :func:`christoffel_first_kind` (linear in
    dM) applied to ``d_m dM``. A test tool for small metrics (it builds n^2 second-derivative blocks).
    """
    G, dG, d2G = _metric_derivatives(metric_fn, x, 2)
    n = G.shape[0]
    factor = _cholesky(G)
    Gamma = christoffel_symbols(G, dG, factor)[0]
    dGamma = np.empty((n, n, n, n))  # dGamma[m, i, j, k] = d_m Gamma^i_jk
    for m in range(n):
        rhs = christoffel_first_kind(d2G[m]) - np.einsum("il,ljk->ijk", dG[m], Gamma)
        dGamma[m] = _cho_solve(factor, rhs.reshape(n, n * n)).reshape(n, n, n)
    return (np.einsum("kilj->ijkl", dGamma) - np.einsum("likj->ijkl", dGamma)
            + np.einsum("ikm,mlj->ijkl", Gamma, Gamma) - np.einsum("ilm,mkj->ijkl", Gamma, Gamma))


# ------------------------------------------------------------------------------------ the mechanism, symbolically


def _rodrigues(axis: np.ndarray, s, c):
    """Rotation by the angle with sine ``s`` and cosine ``c`` about the unit ``axis`` (SX 3x3)."""
    x, y, z = axis
    K = np.array([[0.0, -z, y], [z, 0.0, -x], [-y, x, 0.0]])
    return ca.DM(np.eye(3)) + s * ca.DM(K) + (1 - c) * ca.DM(K @ K)


def _joint_coordinates(model: Model, chart, p: ca.SX) -> list:
    """``q = psi(p)`` as SX scalars (``p`` itself in the joint chart)."""
    n = model.n
    ps = [p[i] for i in range(n)]
    if chart is None:
        return ps
    q = list(chart.psi(ps, ca.sin, ca.cos))
    if len(q) != n:
        raise ValueError(f"chart '{getattr(chart, 'name', chart)}' maps {n} coordinates to {len(q)} joint values; "
                         f"model '{model.name}' has {n} joints")
    return [ca.SX(qi) for qi in q]


def _world_values(model: Model) -> np.ndarray:
    """The numbers of the model's world data (``cases.world.world_data`` with the task directions), each matrix column
    by column (casadi's order), in order: what the Functions read after the point."""
    return np.concatenate([np.asarray(a, dtype=float).ravel(order="F") for _, a in world_data(model, task=True)])


def _arguments(model: Model, point: np.ndarray) -> np.ndarray:
    """A Function's first argument: the point (or the rows of a stack of points) and the model's world data."""
    world = _world_values(model)
    point = np.asarray(point, dtype=float)
    return np.concatenate([point, np.broadcast_to(world, point.shape[:-1] + world.shape)], axis=-1)


class _World:
    """The world data (``cases.world.world_data`` with the task directions) as SX symbols (``symbolic``, a compiled
    Function's parameters, read after the point) or as the model's own numbers; :meth:`matrix` gives a datum in its
    shape (a vector as a column), :meth:`of` a constraint's or a load's."""

    def __init__(self, model: Model, symbolic: bool = True):
        self.model, self._data, symbols = model, {}, []
        for label, value in world_data(model, task=True):
            value = np.asarray(value, dtype=float)
            rows, cols = (value.shape + (1,))[:2]
            if symbolic:
                symbols.append(ca.SX.sym(label.replace(".", "_"), value.size))
                self._data[label] = ca.reshape(symbols[-1], rows, cols)
            else:
                self._data[label] = ca.SX(ca.DM(value.reshape(rows, cols)))
        self.symbols = ca.vertcat(*symbols) if symbols else ca.SX(0, 1)

    def matrix(self, label: str) -> ca.SX:
        return self._data[label]

    def of(self, declaration, field: str) -> ca.SX:
        return self._data[label_of(self.model, declaration, field)]


def _walk(model: Model, motion, world: _World | None = None) -> tuple[list, list, list]:
    """``(R, o, values)``: the world rotations and origins of every body frame (SX, parents first) and the joints'
    values, ``motion(i, Rj, oj) = (R_i, o_i, value_i)`` body ``i``'s from the world rotation ``Rj`` and origin ``oj`` of
    its joint frame (``X_body = X_parent * (rotation, translation) * motion(q_i)``, ``cases.model``); a root's joint
    frame is its placement in the world, from ``world`` (:class:`_World`; the model's numbers when None)."""
    world = _World(model, symbolic=False) if world is None else world
    nb = len(model.bodies)
    R: list = [None] * nb
    o: list = [None] * nb
    values: list = [None] * nb
    for i in model.topological_order:
        body, parent = model.bodies[i], model.parent_index[i]
        if parent < 0:
            Rj, oj = world.matrix(f"root{i}.rotation"), world.matrix(f"root{i}.translation")
        else:
            Rj = ca.mtimes(R[parent], ca.DM(body.rotation))
            oj = o[parent] + ca.mtimes(R[parent], ca.DM(body.translation))
        R[i], o[i], values[i] = motion(i, Rj, oj)
    return R, o, values


def _scalar_motion(body, x, Rj: ca.SX, oj: ca.SX) -> tuple:
    """``(R, o, x)`` of a revolute (a turn by ``x`` about the axis) or prismatic joint (a slide by ``x``) whose joint
    frame is at ``(Rj, oj)``."""
    if body.joint == "revolute":
        return ca.mtimes(Rj, _rodrigues(body.axis, ca.sin(x), ca.cos(x))), oj, x
    return Rj, oj + ca.mtimes(Rj, ca.DM(body.axis)) * x, x


def _frames(model: Model, q: list, world: _World | None = None) -> tuple[list, list]:
    """World rotations ``R_i`` and origins ``o_i`` of every body frame (SX), parents first."""
    R, o, _ = _walk(model, lambda i, Rj, oj: _scalar_motion(model.bodies[i], q[i], Rj, oj), world)
    return R, o


# ------------------------------------------------------------------- spherical and free joints: the group chart

#: Degree of the truncated exponential series of the group chart (module docstring, "Spherical and free joints").
#: Every output of the compiled Function is a derivative of order at most 2 in the chart coordinates, taken at
#: xi = 0, where the series of degree 2 has exactly the derivatives of exp up to order 2.
EXP_ORDER = 2


def _hat(w) -> ca.SX:
    """``[w]x``, the skew matrix of the 3-vector ``w`` (so3)."""
    return ca.vertcat(ca.horzcat(0, -w[2], w[1]), ca.horzcat(w[2], 0, -w[0]), ca.horzcat(-w[1], w[0], 0))


def _quaternion_rotation(quat) -> ca.SX:
    """``R(quat) = I + 2 w [x y z]x + 2 [x y z]x^2`` of the unit quaternion ``(x, y, z, w)`` (cases.model)."""
    K = _hat(quat[0:3])
    return ca.DM.eye(3) + 2 * quat[3] * K + 2 * ca.mtimes(K, K)


def _exp_series(X: ca.SX, order: int) -> ca.SX:
    """``sum_{k <= order} X^k / k!``: the group exponential (of SO(3) for ``X = [w]x``, of SE(3) for the 4x4
    ``[[w]x, rho; 0, 0]``) truncated to its Taylor polynomial of degree ``order`` at 0. It is not a group element
    away from 0, but its partial derivatives at ``X = 0`` up to order ``order`` are exactly those of exp (they are
    the Taylor coefficients), and the chart is only ever differentiated at 0 (:data:`EXP_ORDER`). Written as a
    polynomial, casadi differentiates it at 0 where the closed form's ``sin|w| / |w|`` has no derivative."""
    E, term = ca.SX.eye(X.shape[0]), ca.SX.eye(X.shape[0])
    for k in range(1, order + 1):
        term = ca.mtimes(term, X) / k
        E = E + term
    return E


def _group_frames(model: Model, q: ca.SX, p: ca.SX, exp_order: int, side: str | None = None,
                  world: _World | None = None) -> tuple[list, list, list]:
    """``(R, o, values)``: the world rotations and origins of every body frame (SX, parents first) in the group chart
    of the configuration ``q`` (SX, nq): revolute and prismatic joints in their own coordinate ``p[v_index[i]]``
    (their joint values, ``values[i]``), a spherical joint at ``R0 exp([xi]x)`` and a free joint at ``X0 exp6(xi)``
    (``xi = p[v_index[i]:]``, twist order (linear, angular); ``R0 = R(quat)``, ``X0 = (R(quat), position)`` read
    from ``q``; ``values[i]`` None: a group has no joint value). With ``side`` a velocity representation (module
    docstring, "Velocity representations") the exponential is on the LEFT, in the joint's reference frame: a spherical
    joint at ``exp([xi]x) R0``, a free joint at ``exp6(xi) X0`` (``world``) or at ``(exp([xi_ang]x) R0,
    position + xi_lin)`` (``mixed``)."""
    def motion(i: int, Rj: ca.SX, oj: ca.SX) -> tuple:
        body, a, v = model.bodies[i], model.q_index[i], model.v_index[i]
        if body.joint in ("revolute", "prismatic"):
            return _scalar_motion(body, p[v], Rj, oj)
        if body.joint == "spherical":
            E, R0 = _exp_series(_hat(p[v:v + 3]), exp_order), _quaternion_rotation(q[a:a + 4])
            return ca.mtimes(Rj, ca.mtimes(R0, E) if side is None else ca.mtimes(E, R0)), oj, None
        R0, position = _quaternion_rotation(q[a + 3:a + 7]), q[a:a + 3]
        if side == "mixed":        # (exp([xi_ang]x) R0, position + xi_lin)
            E = _exp_series(_hat(p[v + 3:v + 6]), exp_order)
            return ca.mtimes(Rj, ca.mtimes(E, R0)), oj + ca.mtimes(Rj, position + p[v:v + 3]), None
        twist = ca.vertcat(ca.horzcat(_hat(p[v + 3:v + 6]), p[v:v + 3]), ca.SX.zeros(1, 4))
        E = _exp_series(twist, exp_order)
        if side is None:           # X0 exp6(xi), xi = (rho, w): the motion (R0 E_R, position + R0 E_p)
            return (ca.mtimes(ca.mtimes(Rj, R0), E[:3, :3]),
                    oj + ca.mtimes(Rj, position + ca.mtimes(R0, E[:3, 3])), None)
        # world: exp6(xi) X0 = (E_R R0, E_R position + E_p)
        return (ca.mtimes(Rj, ca.mtimes(E[:3, :3], R0)),
                oj + ca.mtimes(Rj, ca.mtimes(E[:3, :3], position) + E[:3, 3]), None)
    return _walk(model, motion, world)


#: The base-velocity representations this backend evaluates natively (module docstring, "Velocity representations").
REPRESENTATIONS = ("world", "mixed")


def _representation(model: Model, chart) -> str | None:
    """The velocity representation ``chart`` asks for (its ``representation``, read duck-typed), or None for any other
    chart; ModelNotSupported for an unknown one or a model without spherical or free joints."""
    side = None if chart is None else getattr(chart, "representation", None)
    if side is None:
        return None
    if side not in REPRESENTATIONS:
        raise _refuse_chart(model, chart, f"asks for the velocity representation {side!r} (known: "
                                          f"{', '.join(REPRESENTATIONS)})")
    if not model.group_joints:
        raise ModelNotSupported(f"geometric: chart '{_chart_name(chart)}' is a velocity representation ({side}); "
                                f"model '{model.name}' has no spherical or free joint to represent")
    return side


def _chart_origin(model: Model, q: ca.SX) -> ca.SX:
    """The group chart's coordinates of the configuration ``q`` itself (nv): a revolute or prismatic joint's value,
    ``xi = 0`` for a spherical or free joint."""
    parts = []
    for i, body in enumerate(model.bodies):
        parts.append(q[model.q_index[i]] if body.joint in ("revolute", "prismatic") else
                     ca.SX.zeros(3 if body.joint == "spherical" else 6))
    return ca.vertcat(*parts)


_NO_CHARTS = ("model '{model}' has spherical or free joints: its configuration lives on a Lie group, so a chart "
              "q = psi(p) applies only when psi returns the whole q ({nq} entries, each quaternion unit for every p, "
              "as the zyx chart does: crosscheck.checks.charts.EulerZYX); chart '{chart}' {reason}")

#: Chart points at which :func:`_group_chart_coordinates` checks that psi's quaternions are unit (seeded, so a
#: chart is accepted or refused the same way every time).
UNIT_CHECK_POINTS = 3


def _refuse_chart(model: Model, chart, reason: str) -> ModelNotSupported:
    return ModelNotSupported(_NO_CHARTS.format(model=model.name, nq=model.nq, chart=_chart_name(chart), reason=reason))


def _check_group_chart(model: Model, chart) -> None:
    """A chart given for a model with spherical or free joints must at least be a chart object (``psi`` and ``key``);
    whether its psi returns the whole q is decided when it is compiled (:func:`_group_chart_coordinates`)."""
    if _representation(model, chart) is not None:
        return
    if chart is not None and model.group_joints and not (callable(getattr(chart, "psi", None))
                                                         and hasattr(chart, "key")):
        raise _refuse_chart(model, chart, "is not a chart q = psi(p) (no psi or no key)")


def _group_chart_coordinates(model: Model, chart, p: ca.SX) -> list:
    """``q = psi(p)`` (nq SX scalars) of a model with spherical or free joints in ``chart``, whose ``p`` has nv entries
    (the Euler-angle chart: a revolute or prismatic coordinate as it is, a spherical block (yaw, pitch, roll), a free
    block (position, yaw, pitch, roll)). Refused (ModelNotSupported) unless psi, evaluated in casadi's sin and cos,
    returns nq entries whose quaternion blocks are unit at :data:`UNIT_CHECK_POINTS` seeded points (the rotation
    ``R(quat)`` of :func:`_quaternion_rotation` is then a rotation for every p: an identity of psi, not a number of the
    state)."""
    ps = [p[i] for i in range(model.nv)]
    try:
        q = list(chart.psi(ps, ca.sin, ca.cos))
    except Exception as exc:  # the group's identity chart (p = q) has no psi of nv coordinates
        raise _refuse_chart(model, chart, f"gives no psi of the {model.nv} velocity coordinates "
                                          f"({type(exc).__name__}: {exc})") from None
    if len(q) != model.nq:
        raise _refuse_chart(model, chart, f"returns {len(q)} entries")
    q = [ca.SX(qi) for qi in q]
    blocks = [model.q_index[i] + (3 if model.bodies[i].joint == "free" else 0) for i in model.group_joints]
    norms = ca.Function("unit", [p], [ca.vertcat(*[ca.sumsqr(ca.vertcat(*q[a:a + 4])) for a in blocks])])
    rng = np.random.default_rng(17)
    for _ in range(UNIT_CHECK_POINTS):
        off = np.abs(np.array(norms(rng.uniform(-math.pi, math.pi, model.nv))).ravel() - 1.0)
        if not np.all(off <= 1e-12):
            raise _refuse_chart(model, chart, f"has quaternions that are not unit (|quat|^2 - 1 up to {off.max():.3g})")
    return q


def _chart_group_frames(model: Model, q: list, world: _World | None = None) -> tuple[list, list, list]:
    """``(R, o, values)`` of a model with spherical or free joints at ``q = psi(p)`` (nq SX expressions of the chart
    coordinates, :func:`_group_chart_coordinates`): each joint's own ``motion(q_i)`` (``cases.model``), nothing else.
    A revolute or prismatic joint by its value ``q[q_index[i]]`` (``values[i]``), a spherical joint at
    ``(R(quat), 0)``, a free joint at ``(R(quat), position)``, ``R(quat) = I + 2 w [x y z]x + 2 [x y z]x^2`` the
    polynomial of psi's quaternion (a rotation for every p), so the body rotations and origins are functions of p
    and every velocity and derivative is taken in p by automatic differentiation (``values[i]`` None for a group
    joint)."""
    def motion(i: int, Rj: ca.SX, oj: ca.SX) -> tuple:
        body, a = model.bodies[i], model.q_index[i]
        if body.joint in ("revolute", "prismatic"):
            return _scalar_motion(body, q[a], Rj, oj)
        if body.joint == "spherical":
            return ca.mtimes(Rj, _quaternion_rotation(ca.vertcat(*q[a:a + 4]))), oj, None
        # free: (R(quat), position), the position in the joint frame
        R = ca.mtimes(Rj, _quaternion_rotation(ca.vertcat(*q[a + 3:a + 7])))
        return R, oj + ca.mtimes(Rj, ca.vertcat(*q[a:a + 3])), None
    return _walk(model, motion, world)


def _rotor(model: Model, i: int, R: list, o: list, p: ca.SX, pd: ca.SX, world: _World) -> tuple[ca.SX, ca.SX]:
    """``(T, M)`` of body ``i``'s joint rotor (``Body.armature`` a; module docstring, "Armature"): the rotor turns or
    slides with the joint's own motion, the body frame relative to its joint frame, ``(R_m, p_m) = (R_j^T R_i,
    R_j^T (o_i - o_j))`` with the joint frame ``(R_j, o_j)`` the parent's frame moved by the placement (a root's: the
    world data), so ``T = 1/2 a (|w_m|^2 + |p_m'|^2)``, ``[w_m]x = R_m^T R_m'`` (a revolute joint: ``qd^2``; a prismatic
    one: ``qd^2``; a ball: ``|v|^2``; a free joint: ``|v|^2`` over its six) in any chart. Both are linear in pd, so its
    metric is ``a (Jw^T Jw + Jp^T Jp)`` exactly (``Jw = dw_m/dpd``, ``Jp = dp_m/dp``): in the joint chart of revolute
    and prismatic joints the constant ``a`` on the joint's diagonal entry."""
    body, parent = model.bodies[i], model.parent_index[i]
    if parent < 0:
        Rj, oj = world.matrix(f"root{i}.rotation"), world.matrix(f"root{i}.translation")
    else:
        Rj = ca.mtimes(R[parent], ca.DM(body.rotation))
        oj = o[parent] + ca.mtimes(R[parent], ca.DM(body.translation))
    R_m, p_m = ca.mtimes(Rj.T, R[i]), ca.mtimes(Rj.T, o[i] - oj)
    R_m_dot = ca.reshape(ca.mtimes(ca.jacobian(ca.vec(R_m), p), pd), 3, 3)
    W = ca.mtimes(R_m.T, R_m_dot)
    w = ca.vertcat(W[2, 1], W[0, 2], W[1, 0])
    Jw, Jp = ca.jacobian(w, pd), ca.jacobian(p_m, p)
    p_m_dot = ca.mtimes(Jp, pd)
    a = float(body.armature)
    return (0.5 * a * (ca.dot(w, w) + ca.dot(p_m_dot, p_m_dot)),
            a * (ca.mtimes(Jw.T, Jw) + ca.mtimes(Jp.T, Jp)))


def _point(model: Model, R: list, o: list, body: str, offset) -> ca.SX:
    """World position ``o_b + R_b offset`` of the point ``offset`` (body frame) of ``body`` (SX 3-vector)."""
    b = model.body_index(body)
    return o[b] + ca.mtimes(R[b], ca.DM(offset))


def _constraint_rows(model: Model, c, q: list, R: list, o: list, world: _World) -> ca.SX:
    """``phi`` of one declaration, exactly as tabled in ``cases.constraints``, its world data from ``world``."""
    if isinstance(c, PointOnCircle):
        d = ca.mtimes(world.of(c, "plane"), _point(model, R, o, c.body, c.offset) - world.of(c, "center"))
        return ca.dot(d, d) - c.radius ** 2
    if isinstance(c, PointsCoincide):
        other = world.of(c, "offset_b") if c.body_b is None else _point(model, R, o, c.body_b, c.offset_b)
        return ca.mtimes(world.of(c, "directions"), _point(model, R, o, c.body_a, c.offset_a) - other)
    if isinstance(c, PointOnLine):
        return ca.mtimes(world.of(c, "normals"), _point(model, R, o, c.body, c.offset) - world.of(c, "origin"))
    if isinstance(c, JointCoupling):
        terms = [coefficient * q[model.body_index(j)] for j, coefficient in zip(c.joints, c.coefficients)]
        return ca.sum1(ca.vertcat(*terms)) - c.offset
    raise ValueError(f"model '{model.name}': constraint '{c.name}' is a {type(c).__name__}, which the geometric "
                     "backend does not know")


def _pfaffian_rates(model: Model, c, R: list, o: list, p: ca.SX, pd: ca.SX, world: _World) -> ca.SX:
    """The velocity rows ``A(p) pd`` of a Pfaffian declaration, exactly as :mod:`cases.constraints` fixes them: a
    point's velocity ``jtimes(x, p, pd)``, the body's world angular velocity from ``Rdot R^T``; for a rolling contact
    the material point at the contact ``p_c = c - r u`` moves with ``cdot + w x (p_c - c)`` (its rows along the ground's
    tangents T, or with ``lateral=False`` along the rolling direction ``t = (a x n) / |a x n|`` alone)."""
    b = model.body_index(c.body)
    if isinstance(c, PointVelocity):
        return ca.mtimes(world.of(c, "directions"), ca.jtimes(_point(model, R, o, c.body, c.offset), p, pd))
    if isinstance(c, KnifeEdge):
        e = ca.mtimes(R[b], ca.DM(c.direction))
        return ca.dot(e, ca.jtimes(_point(model, R, o, c.body, c.offset), p, pd))
    if isinstance(c, RollingContact):
        plane = world.of(c, "plane")
        n = ca.cross(plane[0, :].T, plane[1, :].T)
        a = ca.mtimes(R[b], ca.DM(c.axis))
        raw = n - ca.dot(n, a) * a
        e = -c.radius * raw / ca.norm_2(raw)
        W = ca.mtimes(ca.reshape(ca.jtimes(ca.vec(R[b]), p, pd), 3, 3), R[b].T)   # hat(w), world frame
        w = ca.vertcat(W[2, 1], W[0, 2], W[1, 0])
        velocity = ca.jtimes(_point(model, R, o, c.body, c.center), p, pd) + ca.cross(w, e)
        if not c.lateral:   # the rolling direction t = (a x n) / |a x n| only; (da/dp) pd turns t with the axle
            b = ca.cross(a, n)
            return ca.dot(b / ca.norm_2(b), velocity)
        return ca.mtimes(plane, velocity)
    raise ValueError(f"model '{model.name}': constraint '{c.name}' is a {type(c).__name__}, which the geometric "
                     "backend does not know")


def _rate_rows(model: Model, q: list, R: list, o: list, p: ca.SX, pd: ca.SX,
               world: _World) -> tuple[ca.SX, ca.SX, ca.SX]:
    """``phi``, ``Jc`` and ``Jcdot pd`` of a model with Pfaffian rows: every row as a rate ``a(p, pd)`` (a holonomic
    row's ``jtimes(phi, p, pd)``, a Pfaffian row's :func:`_pfaffian_rates`), ``Jc = da/dpd`` and ``Jcdot pd = (da/dp)
    pd``; ``phi`` is the holonomic rows' function and 0 on the Pfaffian rows."""
    values, rates = [], []
    for c in model.constraints:
        if c.holonomic:
            value = _constraint_rows(model, c, q, R, o, world)
            values.append(value)
            rates.append(ca.jtimes(value, p, pd))
        else:
            rate = _pfaffian_rates(model, c, R, o, p, pd, world)
            values.append(ca.SX.zeros(rate.shape[0], 1))
            rates.append(rate)
    a = ca.vertcat(*rates)
    return ca.vertcat(*values), ca.jacobian(a, pd), ca.mtimes(ca.jacobian(a, p), pd)


def _constraint_function(model: Model, q: list, R: list, o: list, world: _World) -> ca.SX:
    """``phi(p)`` (k,): the rows of every declaration in order, of the joint values ``q = psi(p)`` and the frames."""
    return ca.vertcat(*[_constraint_rows(model, c, q, R, o, world) for c in model.constraints])


# ------------------------------------------------------------------------------------------ compiled evaluation

#: States a Function evaluates interpreted before it may be compiled to C (module docstring, "Compiled evaluation").
COMPILE_AFTER = 1000
#: CPU seconds of compiling a Function, per SX instruction of it as built (before :func:`_eliminated`): the panda's 65k
#: (40k after elimination) took 8 s, tiago's (1.0M after elimination) 225 s (-O1, parts of :data:`C_PART`). A Function
#: is compiled once the seconds it has spent interpreted reach this estimate of its compilation (and it has had
#: :data:`COMPILE_AFTER` states): a model evaluated long enough to pay for it, and never a large model in a gate's few
#: states, whose compilation would cost more than all its interpreted evaluations (tiago's 225 s against about 10 ms a
#: state).
COMPILE_SECONDS_PER_INSTRUCTION = 1.2e-4
#: ``CROSSCHECK_COMPILE=0`` keeps every Function interpreted (casadi's SX virtual machine).
COMPILE_ENV = "CROSSCHECK_COMPILE"
#: The compilers looked for on the PATH, in order.
COMPILERS = ("cc", "gcc")
#: Compiler flags. -O1: the panda's Function runs 20 times faster than in the interpreter; -O2 takes half as long
#: again to compile and runs no faster, -O0 runs no faster than the interpreter. No fused multiply-adds
#: (``-ffp-contract=off``): the compiled code rounds exactly as the interpreter does.
C_FLAGS = ("-O1", "-ffp-contract=off", "-fPIC", "-shared")
#: SX instructions per C function of the generated code (module docstring: the compiler's time grows faster than a
#: function's size, so the code is cut into parts).
C_PART = 200

#: C of each casadi operation the Functions are made of (``{0}``, ``{1}`` the operands); any other operation leaves the
#: Function interpreted. ``2.*x`` and ``x*x`` are what casadi's virtual machine computes for ``OP_TWICE`` and ``OP_SQ``.
_C_OPERATIONS = {ca.OP_ASSIGN: "{0}", ca.OP_ADD: "{0}+{1}", ca.OP_SUB: "{0}-{1}", ca.OP_MUL: "{0}*{1}",
                 ca.OP_DIV: "{0}/{1}", ca.OP_NEG: "-{0}", ca.OP_TWICE: "2.*{0}", ca.OP_SQ: "{0}*{0}",
                 ca.OP_INV: "1./{0}", ca.OP_SQRT: "sqrt({0})", ca.OP_SIN: "sin({0})", ca.OP_COS: "cos({0})",
                 ca.OP_POW: "pow({0},{1})", ca.OP_CONSTPOW: "pow({0},{1})"}
_OPERATION_NAMES = {getattr(ca, name): name for name in dir(ca) if name.startswith("OP_")}
_ENTRY = "crosscheck_geometric"
_C_HEADER = """#include <math.h>
#include <stdlib.h>
#if defined(__GNUC__)
#define PART static __attribute__((noinline)) void
#else
#define PART static void
#endif
"""


class _NoCForm(Exception):
    """The Function uses a casadi operation :data:`_C_OPERATIONS` has no C for."""


def _c_number(value: float) -> str:
    """``value`` as an exact C literal (hexadecimal floating point)."""
    if math.isfinite(value):
        return value.hex()
    return "NAN" if math.isnan(value) else ("INFINITY" if value > 0 else "-INFINITY")


def _c_statement(function: ca.Function, k: int) -> str:
    """SX instruction ``k`` of ``function`` as a C statement on the work vector ``w`` (inputs ``p``, ``pd``, output
    ``r``)."""
    op, args, res = function.instruction_id(k), function.instruction_input(k), function.instruction_output(k)
    if op == ca.OP_INPUT:
        return f"w[{res[0]}]={('p', 'pd')[args[0]]}[{args[1]}];"
    if op == ca.OP_OUTPUT:
        return f"r[{res[1]}]=w[{args[0]}];"
    if op == ca.OP_CONST:
        return f"w[{res[0]}]={_c_number(function.instruction_constant(k))};"
    if op not in _C_OPERATIONS:
        raise _NoCForm(f"casadi operation {_OPERATION_NAMES.get(op, op)} has no C form here")
    return f"w[{res[0]}]=" + _C_OPERATIONS[op].format(*(f"w[{a}]" for a in args)) + ";"


def _c_source(function: ca.Function) -> str:
    """C of ``function`` (inputs ``p``, ``pd``, one dense output): its SX instructions in casadi's order, one statement
    each (:func:`_c_statement`), in parts of :data:`C_PART`, and the entry point
    ``int crosscheck_geometric(p, pd, r, states)`` that runs them for ``states`` row-major states (0, or 1 when the
    work vector cannot be allocated)."""
    count = function.n_instructions()
    parts = []
    for start in range(0, count, C_PART):
        body = "\n".join(f"  {_c_statement(function, k)}" for k in range(start, min(start + C_PART, count)))
        parts.append(f"PART part{len(parts)}(const double* restrict p, const double* restrict pd, double* restrict r, "
                     f"double* restrict w) {{\n{body}\n}}\n")
    calls = "\n".join(f"    part{i}(p, pd, r, w);" for i in range(len(parts)))
    sizes = function.nnz_in(0), function.nnz_in(1), function.nnz_out(0)
    return (_C_HEADER + "".join(parts)
            + f"int {_ENTRY}(const double* p, const double* pd, double* r, long states) {{\n"
            + f"  double* w = malloc({function.sz_w() + 1} * sizeof(double));\n  if (!w) return 1;\n"
            + f"  for (long s = 0; s < states; ++s, p += {sizes[0]}, pd += {sizes[1]}, r += {sizes[2]}) {{\n"
            + f"{calls}\n  }}\n  free(w);\n  return 0;\n}}\n")


class _Library:
    """A compiled Function: ``(P, PD) -> (N, outputs)`` for N row-major states, one call of its C entry point (which
    releases the GIL and allocates its own work vector, so calls need no lock)."""

    def __init__(self, path: Path, outputs: int):
        self._entry = getattr(ctypes.CDLL(str(path)), _ENTRY)   # OSError, AttributeError: not a library of ours
        self._entry.argtypes = [ctypes.c_void_p] * 3 + [ctypes.c_long]
        self._entry.restype = ctypes.c_int
        self._outputs = outputs

    def __call__(self, P: np.ndarray, PD: np.ndarray) -> np.ndarray:
        P, PD = np.ascontiguousarray(P, dtype=float), np.ascontiguousarray(PD, dtype=float)
        out = np.empty((len(P), self._outputs))
        if self._entry(P.ctypes.data, PD.ctypes.data, out.ctypes.data, len(P)):
            raise MemoryError("the compiled geometric Function could not allocate its work vector")
        return out


def _compiler() -> str | None:
    """The first of :data:`COMPILERS` on the PATH (its full path), or None."""
    return next((found for found in map(shutil.which, COMPILERS) if found), None)


def _interpreted_reason() -> str | None:
    """Why Functions stay interpreted in this process (compilation turned off, no compiler), or None."""
    if os.environ.get(COMPILE_ENV) == "0":
        return f"{COMPILE_ENV}=0"
    if _compiler() is None:
        return f"no C compiler found: none of {', '.join(COMPILERS)} on the PATH"
    return None


def evaluation() -> str:
    """How this backend evaluates its casadi Functions in this process, for ``crosscheck formalisms``."""
    reason = _interpreted_reason()
    if reason is not None:
        return f"interpreted casadi SX ({reason})"
    return (f"compiled C ({Path(_compiler()).name} {C_FLAGS[0]}) once a model has had {COMPILE_AFTER} states and "
            "as long interpreted as its compilation takes, interpreted casadi SX before")


def _cache_dir() -> Path:
    return cache_dir("geometric")


def _cached(path: Path, outputs: int) -> _Library | None:
    """The library cached at ``path`` when its bytes match the digest stored beside it and it loads, else None."""
    try:
        data, digest = path.read_bytes(), path.with_suffix(".sha256").read_text()
    except OSError:
        return None
    if hashlib.sha256(data).hexdigest() != digest:
        return None
    try:
        library = _Library(path, outputs)
    except (OSError, AttributeError):
        return None
    used_cache_file(path)
    used_cache_file(path.with_suffix(".sha256"))
    return library


def _build(source: str, command: list[str], path: Path, outputs: int) -> _Library:
    """Compile ``source`` with ``command`` in a scratch directory, load it, and cache it at ``path`` with the digest of
    its bytes (the loaded library outlives the scratch file). CalledProcessError, OSError or AttributeError (no entry
    point) when it fails."""
    with tempfile.TemporaryDirectory(prefix="crosscheck-geometric-") as scratch:
        c_file, library_file = Path(scratch) / "geometric.c", Path(scratch) / "geometric.so"
        c_file.write_text(source)
        subprocess.run([*command, str(c_file), "-o", str(library_file), "-lm"], check=True, capture_output=True,
                       text=True)
        library, data = _Library(library_file, outputs), library_file.read_bytes()
    write_cache_file(path, data)
    write_cache_file(path.with_suffix(".sha256"), hashlib.sha256(data).hexdigest().encode())
    return library


def _native(function: ca.Function) -> tuple[_Library | None, str]:
    """``function`` compiled to C (from the disk cache, or compiled now) and how it is evaluated; ``(None, why)`` when
    it stays interpreted (module docstring, "Compiled evaluation"). A failed compilation also warns."""
    reason = _interpreted_reason()
    if reason is not None:
        return None, f"interpreted casadi SX ({reason})"
    try:
        source = _c_source(function)
    except _NoCForm as exc:
        return None, f"interpreted casadi SX ({exc})"
    command = [_compiler(), *C_FLAGS]
    key = hashlib.sha256("\0".join([*command, source]).encode()).hexdigest()[:32]
    path, outputs = _cache_dir() / f"{key}.so", function.nnz_out(0)
    described = f"compiled C ({Path(command[0]).name} {C_FLAGS[0]})"
    library = _cached(path, outputs)
    if library is not None:
        return library, described
    try:
        return _build(source, command, path, outputs), described
    except subprocess.CalledProcessError as exc:
        why = f"{' '.join(command)} failed with exit status {exc.returncode}: {(exc.stderr or '').strip()[-500:]}"
    except (OSError, AttributeError) as exc:
        why = f"compiling with {' '.join(command)} failed: {exc}"
    warnings.warn(f"geometric: {why}; the Function '{function.name()}' stays interpreted", RuntimeWarning,
                  stacklevel=2)
    return None, f"interpreted casadi SX ({why})"


def _eliminated(function: ca.Function) -> ca.Function:
    """``function`` rebuilt with casadi's common subexpression elimination, for compiling (:class:`_Evaluator`): the
    same values from fewer instructions (the panda's 65k become 40k; a 24-link chain's 495k, already shared as built,
    490k). Building a Function with it takes 8-13 times as long (the panda 0.9 s instead of 0.1 s, in an affine chart
    5.1 s instead of 0.5 s; a 24-link chain 6.7 s instead of 0.6 s), which only a compiled Function pays back."""
    arguments = function.sx_in()
    return ca.Function(function.name(), arguments, function.call(arguments), {"cse": True})


class _Evaluator:
    """A casadi Function ``(p, pd) -> one dense column``: interpreted through casadi's buffer interface (the arguments
    copied into fixed numpy buffers and the result out of one, so a call costs microseconds instead of the ~80 us of a
    regular Function call with its conversions; one buffer per Function, so these calls are serialized), and compiled
    to C once it has evaluated :data:`COMPILE_AFTER` states (module docstring, "Compiled evaluation").
    ``evaluation`` says which, and why."""

    def __init__(self, name: str, p: ca.SX, pd: ca.SX, out: ca.SX):
        self.function = ca.Function(name, [p, pd], [ca.densify(out)], {"cse": False})
        self._p, self._pd, self._out = np.zeros(p.numel()), np.zeros(pd.numel()), np.zeros(out.numel())
        self._buffer, self._trigger = self.function.buffer()
        self._buffer.set_arg(0, memoryview(self._p))
        self._buffer.set_arg(1, memoryview(self._pd))
        self._buffer.set_res(0, memoryview(self._out))
        self._lock = threading.Lock()
        self._mapped: dict[int, ca.Function] = {}
        self.size = self._out.size  # outputs per state
        self._states, self._seconds, self._decided, self._library = 0, 0.0, False, None
        self.compile_estimate = COMPILE_SECONDS_PER_INSTRUCTION * self.function.n_instructions()
        self.evaluation = "interpreted casadi SX (not yet compiled)"

    def _native_when_due(self, states: int) -> _Library | None:
        """Count ``states`` (called under the lock) and return the compiled Function, compiling it (once) when it has
        had :data:`COMPILE_AFTER` states and its interpreted seconds have reached its estimated compilation
        (:data:`COMPILE_SECONDS_PER_INSTRUCTION`); None while it is interpreted."""
        if not self._decided:
            self._states += states
            if self._states >= COMPILE_AFTER and self._seconds >= self.compile_estimate:
                self._decided = True
                self._library, self.evaluation = _native(_eliminated(self.function))
        return self._library

    def __call__(self, p: np.ndarray, pd: np.ndarray) -> np.ndarray:
        with self._lock:
            library = self._native_when_due(1)
            if library is None:
                self._p[:] = p
                self._pd[:] = pd
                start = time.perf_counter()
                self._trigger()
                self._seconds += time.perf_counter() - start
                return self._out.copy()
        return library(p[None], pd[None])[0]

    def batch(self, P: np.ndarray, PD: np.ndarray) -> np.ndarray:
        """The Function at N states at once (rows of ``P``, ``PD``), as an (N, outputs) array: compiled, one C call;
        interpreted, the Function mapped over N (``Function.map``), called through a buffer on the arrays themselves
        (a row-major (N, n) array is the column-major (n, N) argument of the map, one state per column)."""
        N = len(P)
        out = np.empty((N, self._out.size))
        if N == 0:
            return out
        with self._lock:
            library = self._native_when_due(N)
            if library is None:
                if N not in self._mapped:
                    if len(self._mapped) >= 4:  # the map of a block size, and of the last partial blocks
                        self._mapped.clear()
                    self._mapped[N] = self.function.map(N)
                mapped = self._mapped[N]
        if library is not None:
            return library(P, PD)
        P, PD = (np.ascontiguousarray(a, dtype=float).reshape(-1) for a in (P, PD))
        buffer, trigger = mapped.buffer()
        buffer.set_arg(0, memoryview(P))
        buffer.set_arg(1, memoryview(PD))
        buffer.set_res(0, memoryview(out.reshape(-1)))
        start = time.perf_counter()
        trigger()
        with self._lock:
            self._seconds += time.perf_counter() - start
        return out


class _Compiled:
    """The casadi pieces of one (model, chart). ``evaluate(p, pd)`` returns one flat vector
    ``[M_upper, dM_upper (column k = d/dp_k of M_upper), dV/dp, T, vec J, Jdot pd, phi, vec Jc, Jcdot pd]``
    (``M_upper``: the upper triangle of M, row by row; vec column-major; ``k`` task rows, ``kc`` constraint rows)
    from a single SX Function call; the index arrays below read M, dM (``[k, i, j]``), dV, T, J, Jdot pd, phi, Jc and
    Jcdot pd out of it. ``energy`` (``[T, V, dE/dp, dE/dpd]``) is built on first use. For a model with spherical or
    free joints both take ``(q, v)``: the configuration (nq) in place of p, every derivative in p taken at the group
    chart's origin (module docstring, "Spherical and free joints")."""

    def __init__(self, n: int, k: int, kc: int, p: ca.SX, pd: ca.SX, T: ca.SX, V: ca.SX, out: ca.SX,
                 point: ca.SX | None = None, origin: ca.SX | None = None, external: bool = False,
                 world: ca.SX | None = None):
        self.n, self.k, self.p, self.pd, self.T, self.V = n, k, p, pd, T, V
        # a model with group joints: the Functions take the configuration ``point`` (nq) and evaluate every
        # derivative in p at the group chart's origin ``p = origin(point)`` (module docstring); otherwise point = p
        self.point, self.origin = (p, None) if point is None else (point, origin)
        # what every Function reads first: the point, then the model's world data (:func:`_arguments`)
        self.arguments = self.point if world is None else ca.vertcat(self.point, world)
        rows, cols = np.triu_indices(n)
        nu = rows.size
        upper = np.empty((n, n), dtype=np.intp)  # position of M[i, j] in M_upper
        upper[rows, cols] = upper[cols, rows] = np.arange(nu)
        self.M_index = upper                                                  # flat[M_index] = M
        self.dM_index = nu + nu * np.arange(n)[:, None, None] + upper[None]   # flat[dM_index] = dM, [k, i, j]
        self.dM_upper_slice = slice(nu, nu + n * nu)                          # reshaped (n, nu): d_k M_upper
        self.upper_pairs = rows, cols                                         # M_upper[u] = M[rows[u], cols[u]]
        at = nu + n * nu
        self.dV_slice, self.T_index = slice(at, at + n), at + n
        self.J_index = at + n + 1 + np.arange(k * n).reshape(n, k).T          # vec(J) is column-major
        self.Jdot_slice = slice(at + n + 1 + k * n, at + n + 1 + k * n + k)
        at = self.Jdot_slice.stop
        self.phi_slice = slice(at, at + kc)
        self.Jc_index = at + kc + np.arange(kc * n).reshape(n, kc).T
        self.Jc_bias_slice = slice(at + kc + kc * n, at + 2 * kc + kc * n)
        at = self.Jc_bias_slice.stop      # then tau_ext (n) for a model with external loads
        self.ext_slice = slice(at, at + n) if external else None
        self.kc, self.out = kc, self._at_origin(out)   # the Function's expression, of (point, pd)
        self.evaluate = _Evaluator("geometric", self.arguments, pd, self.out)
        self._energy: _Evaluator | None = None
        self._linearization: _Evaluator | None = None

    def _at_origin(self, expression: ca.SX) -> ca.SX:
        """``expression`` (of p, pd) at the chart's origin: p replaced by ``origin(point)`` for a group model."""
        return expression if self.origin is None else ca.substitute(expression, self.p, self.origin)

    def _terms(self) -> tuple:
        """``(M, Cqd, dV, Jc, Jcdot pd)`` as SX expressions of ``(point, pd)``, read out of the Function's own
        expression :attr:`out` with its index arrays; ``Cqd = M Gamma(pd, pd)`` the first-kind symbols contracted with
        the rates as in :func:`_first_kind_contracted`, ``(Mdot pd)_l - 1/2 pd^T (d_l M) pd``."""
        n, kc, flat = self.n, self.kc, self.out
        rows, cols = self.upper_pairs
        M = ca.reshape(flat[[int(i) for i in self.M_index.ravel(order="F")]], n, n)
        dM_upper = ca.reshape(flat[self.dM_upper_slice], rows.size, n)           # [upper entry, k]
        Mdot_upper = ca.mtimes(dM_upper, self.pd)                                 # d_k M_upper pd^k
        Mdot = ca.reshape(Mdot_upper[[int(i) for i in self.M_index.ravel(order="F")]], n, n)
        pairs = ca.vertcat(*[self.pd[int(r)] * self.pd[int(c)] * (1.0 if r == c else 2.0) for r, c in zip(rows, cols)])
        Cqd = ca.mtimes(Mdot, self.pd) - 0.5 * ca.mtimes(dM_upper.T, pairs)
        at = self.phi_slice.stop
        Jc = ca.reshape(flat[at:at + kc * n], kc, n)
        dV = flat[self.dV_slice] if self.ext_slice is None else flat[self.dV_slice] - flat[self.ext_slice]
        return M, Cqd, dV, Jc, flat[self.Jc_bias_slice]

    @property
    def linearization(self) -> _Evaluator:
        """``(point, [pd, a, lam, dpoint, dpd]) -> dr``: the derivative of the residual of eqs. (12)-(13) at the
        acceleration ``a`` and multipliers ``lam``,

            r = [M a + M Gamma(pd, pd) + dV/dp - Jc^T lam;  Jc a + Jcdot pd]        ((n + kc) rows),

        along the direction ``(dpoint, dpd)``: casadi's forward-mode AD of the same graph (``jtimes``, built on first
        use; about three times r's instructions, where the whole Jacobian's graph is 16 times r's and took a 29-joint
        humanoid 10 s to build). Its zero is the split's total (and lam): the implicit function theorem turns the
        derivatives along every coordinate of the point and of pd, one batched call, into A and B
        (:func:`_derivatives`). ``dpoint`` has one entry per coordinate of the Function's point (q, nq, for a model
        with spherical or free joints: the derivative of the group chart's origin values, not of the chart)."""
        if self._linearization is None:
            a, lam = ca.SX.sym("a", self.n), ca.SX.sym("lam", self.kc)
            dpoint, dpd = ca.SX.sym("dpoint", self.point.numel()), ca.SX.sym("dpd", self.n)
            M, Cqd, dV, Jc, Jc_bias = self._terms()
            r = ca.vertcat(ca.mtimes(M, a) + Cqd + dV - ca.mtimes(Jc.T, lam), ca.mtimes(Jc, a) + Jc_bias)
            self._linearization = _Evaluator("geometric_linearize", self.arguments,
                                             ca.vertcat(self.pd, a, lam, dpoint, dpd),
                                             ca.jtimes(r, ca.vertcat(self.point, self.pd), ca.vertcat(dpoint, dpd)))
        return self._linearization

    @property
    def energy(self) -> _Evaluator:
        """``(p, pd) -> [T, V, dE/dp, dE/dpd]`` with ``E = T + V`` (automatic differentiation of the energies)."""
        if self._energy is None:
            E = self.T + self.V
            self._energy = _Evaluator("geometric_energy", self.arguments, self.pd, self._at_origin(
                ca.vertcat(self.T, self.V, ca.gradient(E, self.p), ca.gradient(E, self.pd))))
        return self._energy


def _compile(model: Model, chart, exp_order: int = EXP_ORDER) -> _Compiled:
    """Kinematics, energies, metric, task map and constraints of ``model`` in ``chart`` as one SX Function (module
    docstring). A model with spherical or free joints is built in its group chart (:func:`_group_frames`, the
    exponential truncated to degree ``exp_order``) and its Functions take the configuration q (nq), every derivative
    taken at the chart's origin; in a ``chart`` whose psi returns the whole q (:func:`_group_chart_coordinates`,
    ModelNotSupported otherwise) it is built from ``q = psi(p)`` (:func:`_chart_group_frames`) and its Functions take
    p (nv), as for a model with revolute and prismatic joints only (module docstring, "Charts of the group").

    The metric is the Hessian of T in pd, taken in closed form: ``c_i' = Jc_i pd`` and ``w_i = Jw_i pd`` are linear in
    pd (``Jc_i = dc_i/dp``, ``Jw_i = dw_i/dpd``), so ``d^2 T / dpd^2 = sum_i m_i Jc_i^T Jc_i + Jw_i^T I_i Jw_i``
    exactly; AD of that sum gives the same matrix as ``casadi.hessian(T, pd)`` (the tests check ``M pd = dT/dpd`` and
    ``T = 1/2 pd^T M pd`` against the AD of T) with a third fewer operations once ``dM`` is differentiated from it.
    ``dM`` is taken of the upper triangle only (M is symmetric).
    """
    n = model.n
    p, pd = ca.SX.sym("p", n), ca.SX.sym("pd", n)
    point = None
    side = _representation(model, chart)
    world = _World(model)
    if model.group_joints and (chart is None or side):
        point = ca.SX.sym("q", model.nq)
        R, o, q = _group_frames(model, point, p, exp_order, side, world)
    elif model.group_joints:        # a chart whose psi returns the whole q (module docstring, "Charts of the group")
        R, o, q = _chart_group_frames(model, _group_chart_coordinates(model, chart, p), world)
    else:
        q = _joint_coordinates(model, chart, p)
        R, o = _frames(model, q, world)
    T, V, M = ca.SX(0), ca.SX(0), ca.SX.zeros(n, n)
    gravity = world.matrix("gravity")
    spins = []                                        # body-frame angular velocities, for the external loads' power
    for i, body in enumerate(model.bodies):
        c = o[i] + ca.mtimes(R[i], ca.DM(body.com))
        # c' and R' are jtimes(., p, pd) = (d./dp) pd, written as the Jacobian times pd so that pd enters linearly
        # at the end and the Jacobians are reused by the metric
        Jc = ca.jacobian(c, p)
        c_dot = ca.mtimes(Jc, pd)
        R_dot = ca.reshape(ca.mtimes(ca.jacobian(ca.vec(R[i]), p), pd), 3, 3)
        W = ca.mtimes(R[i].T, R_dot)  # skew: hat(w) of the body-frame angular velocity
        w = ca.vertcat(W[2, 1], W[0, 2], W[1, 0])
        spins.append(w)
        T += 0.5 * body.mass * ca.dot(c_dot, c_dot)
        M += body.mass * ca.mtimes(Jc.T, Jc)
        if np.any(body.inertia):
            inertia = ca.DM(body.inertia)
            T += 0.5 * ca.dot(w, ca.mtimes(inertia, w))
            Jw = ca.jacobian(w, pd)
            M += ca.mtimes(Jw.T, ca.mtimes(inertia, Jw))
        V -= body.mass * ca.dot(gravity, c)
    for i, body in enumerate(model.bodies):
        if body.armature:
            T_rotor, M_rotor = _rotor(model, i, R, o, p, pd, world)
            T, M = T + T_rotor, M + M_rotor
    rows, cols = np.triu_indices(n)
    M_upper = ca.vertcat(*[M[int(r), int(c)] for r, c in zip(rows, cols)])
    dM_upper = ca.jacobian(M_upper, p)  # column k = d M_upper / dp_k (so vec(dM_upper) is [k, upper entry])
    dV = ca.gradient(V, p)
    tp = model.task_point()
    x = ca.mtimes(world.matrix("task.directions"), _point(model, R, o, tp.body, tp.offset))
    J = ca.jacobian(x, p)
    Jdot_pd = ca.jtimes(ca.jtimes(x, p, pd), p, pd)
    if model.pfaffian_rows.any():
        phi, Jc, Jc_bias = _rate_rows(model, q, R, o, p, pd, world)
    else:
        phi = _constraint_function(model, q, R, o, world) if model.constraints else ca.SX(0, 1)
        Jc = ca.jacobian(phi, p)
        Jc_bias = ca.mtimes(ca.jacobian(ca.mtimes(Jc, pd), p), pd)  # Jcdot pd = (d(Jc pd)/dp) pd
    out = ca.vertcat(M_upper, ca.vec(dM_upper), dV, T, ca.vec(J), Jdot_pd, phi, ca.vec(Jc), Jc_bias)
    if model.loads:                  # appended: a model without loads keeps its Function as it was
        out = ca.vertcat(out, _external_covector(model, R, o, p, pd, spins, world))
    return _Compiled(n=n, k=x.shape[0], kc=phi.shape[0], p=p, pd=pd, T=T, V=V, out=out, point=point,
                     origin=None if point is None else _chart_origin(model, point), external=bool(model.loads),
                     world=world.symbols)


def _external_covector(model: Model, R: list, o: list, p: ca.SX, pd: ca.SX, spins: list, world: _World) -> ca.SX:
    """``tau_ext`` (n) of the model's external loads in the chart p (module docstring, "External loads"): ``dP/dpd``
    of the loads' virtual power ``P = sum f . xdot + m . w`` (``xdot = (dx/dp) pd``, ``w = R_b w_body``), minus
    ``dV_s/dp`` of the springs' potential ``1/2 k (|x - anchor| - L0)^2``."""
    power, springs = ca.SX(0), ca.SX(0)
    for load in model.loads:
        b = model.body_index(load.body)
        x = _point(model, R, o, load.body, load.offset)
        if isinstance(load, PointSpring):
            d = x - world.of(load, "anchor")
            stretch = ca.sqrt(ca.dot(d, d)) - load.rest_length if load.rest_length else None
            springs += 0.5 * load.stiffness * (stretch * stretch if load.rest_length else ca.dot(d, d))
            continue
        power += ca.dot(_in_world(load, R[b], world, "force"), ca.jtimes(x, p, pd))
        if isinstance(load, ExternalWrench):
            power += ca.dot(_in_world(load, R[b], world, "moment"), ca.mtimes(R[b], spins[b]))
    return ca.gradient(power, pd) - ca.gradient(springs, p)


def _in_world(load, R: ca.SX, world: _World, field: str) -> ca.SX:
    """A load's vector ``field`` (its force or couple) in the world: the world datum for ``frame = "world"``, ``R v``
    for ``"body"`` (R the body's orientation, world <- body)."""
    return world.of(load, field) if load.frame == "world" else ca.mtimes(R, ca.DM(getattr(load, field)))


_LOCK = threading.Lock()
_COMPILED: dict[tuple[str, str], _Compiled] = {}
_DIGESTS: dict[int, tuple[weakref.ref, str]] = {}  # id(model) -> (the model, its digest): digest() costs ~70 us


def _model_digest(model: Model) -> str:
    entry = _DIGESTS.get(id(model))
    if entry is not None and entry[0]() is model:
        return entry[1]
    digest = shape_digest(model)  # the model's arrays are read-only, so its digest never changes
    key = id(model)
    _DIGESTS[key] = (weakref.ref(model, lambda _, key=key: _DIGESTS.pop(key, None)), digest)
    return digest


def _compiled(model: Model, chart) -> _Compiled:
    """The cached casadi Functions of ``(model, chart)``, keyed by the model's digest without its world data
    (``cases.world.shape_digest``: a moved scene and a gravity-free copy share them) and ``chart.key``."""
    key = (_model_digest(model), JOINT_CHART if chart is None else str(chart.key))
    found = _COMPILED.get(key)
    if found is None:
        with _LOCK:
            found = _COMPILED.get(key)
            if found is None:
                found = _COMPILED[key] = _compile(model, chart)
    return found


# --------------------------------------------------------------------------------------------- evaluation


@dataclass(frozen=True)
class _Point:
    """The numeric pieces at one state ``(p, pd)`` in one chart."""

    M: np.ndarray
    dM: np.ndarray  # dM[k, i, j] = d M_ij / dp_k
    dV: np.ndarray
    T: float
    J: np.ndarray
    Jdot_pd: np.ndarray
    phi: np.ndarray      # (k,) constraint values; empty when unconstrained
    Jc: np.ndarray       # (k, n) dphi/dp
    Jc_bias: np.ndarray  # (k,) Jcdot pd
    tau_ext: np.ndarray | None = None  # (n,) the external loads' covector; dV is then dV/dp - tau_ext


def _evaluate(model: Model, chart, p: np.ndarray, pd: np.ndarray) -> _Point:
    c = _compiled(model, chart)
    flat = c.evaluate(_arguments(model, p), pd)
    tau_ext = None if c.ext_slice is None else flat[c.ext_slice]
    return _Point(M=flat[c.M_index], dM=flat[c.dM_index],
                  dV=flat[c.dV_slice] if tau_ext is None else flat[c.dV_slice] - tau_ext, T=float(flat[c.T_index]),
                  J=flat[c.J_index], Jdot_pd=flat[c.Jdot_slice], phi=flat[c.phi_slice], Jc=flat[c.Jc_index],
                  Jc_bias=flat[c.Jc_bias_slice], tau_ext=tau_ext)


def _external_fields(pt: _Point, pd: np.ndarray) -> dict:
    """``external_force`` (the covector ``tau_ext``) and ``power_ext`` (paired with pd) at a point; none without
    loads."""
    if pt.tau_ext is None:
        return {}
    return {"external_force": pt.tau_ext, "power_ext": _pairing(pt.tau_ext, pd)[0]}


def _applied(tau: np.ndarray, pt: _Point) -> np.ndarray:
    """The sizes of the applied covectors, ``|tau| + |tau_ext|``, for the acceleration scale."""
    return tau if pt.tau_ext is None else np.abs(tau) + np.abs(pt.tau_ext)


def _chart_name(chart) -> str:
    return JOINT_CHART if chart is None else getattr(chart, "name", "chart")


def _metric_factor(model: Model, chart, M: np.ndarray, p: np.ndarray):
    """The Cholesky factor of the metric ``M_p`` (``cho_factor``); a metric that is not positive definite (a point
    mass on its own joint axis; in a chart, wherever ``Dpsi`` is singular) is a ValueError naming the model, the
    point and the eigenvalues."""
    try:
        return scipy.linalg.cho_factor(M)
    except np.linalg.LinAlgError:
        where = f"q = {p.tolist()}" if chart is None else (
            f"p = {p.tolist()} in chart '{_chart_name(chart)}' (M_p = Dpsi^T M Dpsi is singular wherever Dpsi is)")
        raise ValueError(f"model '{model.name}': the mass matrix is not positive definite at {where} (Cholesky "
                         f"failed); eigenvalues {np.linalg.eigvalsh(M).tolist()}") from None


def _whitened(factor, covectors: np.ndarray) -> np.ndarray:
    """Covectors (the columns of ``covectors``) in the orthonormal coframe of the metric: ``L^-1 c`` with ``M = L L^T``
    (``factor`` from :func:`_metric_factor`), so that ``c^T M^-1 c' = (L^-1 c) . (L^-1 c')``."""
    c, lower = factor
    x, info = _TRTRS(c, covectors, lower=int(bool(lower)), trans=0 if lower else 1)
    _checked("trtrs", info)
    return x


def _metric_spectrum(factor) -> tuple[float, float]:
    """``(lambda_min, lambda_max)`` of the metric from its Cholesky factor: with ``M = L L^T``, the metric's operator in
    the frame of its factor, ``L^T L = L^-1 M L``, is similar to M, and its eigenvalues (eigvalsh) are M's."""
    c, lower = factor
    L = np.tril(c) if lower else np.triu(c).T
    eig = np.linalg.eigvalsh(L.T @ L)
    return float(eig[0]), float(eig[-1])


def _conditioning(model: Model, factor, Cqd: np.ndarray, dV: np.ndarray, tau: np.ndarray,
                  pd: np.ndarray) -> tuple[float, float, float]:
    """``(cond(M), ||M^-1||, accel_scale)`` of the metric in this chart (:func:`_metric_spectrum`; inf where its
    smallest eigenvalue is not positive), with ``accel_scale = ||M^-1||_2 H``: H the size of the covectors summed in
    ``tau - M Gamma(pd, pd) - dV/dp``, plus configuration-robust magnitudes of the terms that can cancel,
    ``||M|| |pd|^2`` (velocity products) and ``|gravity| sqrt(m_total ||M||)`` (a mass times a lever arm: gravity).
    1-norms, so tiny vectors do not underflow."""
    low, high = _metric_spectrum(factor)
    m_total = sum(b.mass for b in model.bodies)
    H = (np.abs(Cqd).sum() + np.abs(dV).sum() + np.abs(tau).sum() + high * float(pd @ pd)
         + np.abs(model.gravity).sum() * np.sqrt(m_total * high))
    if not low > 0.0:
        return np.inf, np.inf, np.inf
    return high / low, 1.0 / low, float(H / low)


def _pairing(covector: np.ndarray, velocity: np.ndarray) -> tuple[float, np.ndarray]:
    """The power of a generalized force: the covector paired with the velocity in this chart, ``tau(pd) = tau_i pd^i``
    (chart-invariant), and its terms per coordinate."""
    return float(np.dot(covector, velocity)), covector * velocity


def _degenerate_floor(model: Model) -> float:
    """The smallest eigenvalue of ``J M^-1 J^T`` (J constraint or task rows) that is a direction and not rounding: a
    row of ``DEGENERATE_ROW`` times the model's length scale L in the metric, ``(DEGENERATE_ROW L)^2 /
    inertia_scale``."""
    return (DEGENERATE_ROW * model.length_scale) ** 2 / model.inertia_scale


def _split(model: Model, chart, p: np.ndarray, pd: np.ndarray, tau: np.ndarray) -> Split:
    return _split_at(model, chart, _evaluate(model, chart, p, pd), p, pd, tau)


def _split_at(model: Model, chart, pt: _Point, p: np.ndarray, pd: np.ndarray, tau: np.ndarray) -> Split:
    """The split at ``(p, pd)`` from the Function's numbers ``pt`` there: eqs. (24)-(25), or with constraints
    :func:`_constrained_split`."""
    if model.constraints:
        return _constrained_split(model, chart, pt, p, pd, tau)
    factor = _metric_factor(model, chart, pt.M, p)
    # grad V (dV raised by the metric), G u (the control covector raised) and M^-1 (tau - dV), each its own solve
    Gamma, first, (grad_V, ctrl, forced) = christoffel_symbols(pt.M, pt.dM, factor, (pt.dV, tau, tau - pt.dV))
    gamma_pdpd = (Gamma @ pd) @ pd                           # Gamma(pd, pd)^i = Gamma^i_jk pd^j pd^k
    Cqd = (first @ pd) @ pd                                  # M Gamma(pd, pd): the chart's C qd (eq. 7)
    drift = -gamma_pdpd - grad_V                             # eq. (25)
    total = forced - gamma_pdpd                              # eq. (24) solved on its own, not drift + ctrl
    cond_M, _, accel_scale = _conditioning(model, factor, Cqd, pt.dV, _applied(tau, pt), pd)
    power, per = _pairing(tau, pd)
    Lambda, task_cond = _task_inertia(model, pt, factor)
    return Split(drift=drift, ctrl=ctrl, total=total, lam=None, lam_drift=None, power_ctrl=power,
                 power_ctrl_per_coord=per, power_constr=None, power_constr_per_coord=None, cond_M=cond_M,
                 accel_scale=accel_scale, extras={"chart": _chart_name(chart)}, task_drift=pt.J @ drift + pt.Jdot_pd,
                 conditions={"task_inertia": task_cond}, kinetic_energy=pt.T, task_inertia=Lambda,
                 zvcf=-grad_V, drift_velocity=-gamma_pdpd,     # the drift's parts (4.5-4.6), each its own term
                 **_external_fields(pt, pd))


def _task_inertia(model: Model, pt: _Point, factor) -> tuple[np.ndarray, float]:
    """``(Lambda, cond)``: the task-space inertia ``Lambda = (J M_p^-1 J^T)^-1`` (eq. 22) from the chart's task
    Jacobian ``J = dx/dp`` and metric ``M_p`` (the same matrix in every chart: ``J_p M_p^-1 J_p^T = J M^-1 J^T``), and
    ``cond_2(J M^-1 J^T)``.

    The task covectors whitened by the metric (:func:`_whitened`), ``X = L^-1 J^T``, have ``X^T X = J M^-1 J^T``; the
    triangle of their QR factorization ``X = Q R`` is its Cholesky factor, got without forming it: its eigenvalues
    are R's squared singular values and ``Lambda = R^-1 R^-T``. Numerically singular (the smallest eigenvalue not
    above k eps times the largest, eigvalsh's absolute accuracy, nor above :func:`_degenerate_floor`; or not
    finite): cond inf and Lambda NaN, never a plausible-looking number."""
    k = pt.J.shape[0]
    qr, _, _, info = _GEQRF(_whitened(factor, pt.J.T))
    _checked("geqrf", info)
    R = np.triu(qr[:k])                                      # (min(n, k), k)
    w = np.zeros(k)
    w[k - len(R):] = np.linalg.svd(R, compute_uv=False)[::-1] ** 2
    if not max(k * np.finfo(float).eps * w[-1], _degenerate_floor(model)) < w[0]:
        return np.full((k, k), np.nan), np.inf
    R_inv, info = _TRTRI(R)
    _checked("trtri", info)
    Lambda = R_inv @ R_inv.T
    return 0.5 * (Lambda + Lambda.T), float(w[-1] / w[0])


# ------------------------------------------------------------------------------------------------ constraints


@dataclass(frozen=True)
class _Distribution:
    """The constraint distribution ``D = ker (rows^T Jc)`` at a point: ``rows`` (k x r) the independent constraint
    directions (module docstring, "Rank"), the SVD ``rows^T Jc = U diag(s) V^T`` (full row rank r) and ``Z``, an
    orthonormal basis of ``D`` (the other right singular vectors). For one point, or a stack of points of the same
    rank r (a leading axis on every field, and on the vectors the methods take and return)."""

    rows: np.ndarray  # (k, r)
    U: np.ndarray     # (r, r)
    s: np.ndarray     # (r,)
    V: np.ndarray     # (n, r)
    Z: np.ndarray     # (n, n - r)

    def solve(self, b: np.ndarray) -> np.ndarray:
        """The minimum-norm solution of the independent rows of ``Jc x = b``."""
        return _mv(self.V, _mv(_t(self.U), _mv(_t(self.rows), b)) / self.s)

    def solve_transposed(self, c: np.ndarray) -> np.ndarray:
        """The minimum-norm least-squares solution of ``Jc^T lam = c`` with lam in the independent directions."""
        return _mv(self.rows, _mv(self.U, _mv(_t(self.V), c) / self.s))


def _t(a: np.ndarray) -> np.ndarray:
    """The transpose of the last two axes (of every matrix in a stack)."""
    return np.swapaxes(a, -1, -2)


def _mv(A: np.ndarray, x: np.ndarray) -> np.ndarray:
    """Matrix times vector, for one matrix and vector or for stacks of both."""
    return (A @ x[..., None])[..., 0]


def _constraint_spectrum(X: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Eigenvalues (ascending) and eigen-directions (columns) of ``S = Jc M^-1 Jc^T`` from the whitened constraint
    covectors ``X = L^-1 Jc^T`` (:func:`_whitened`; one state or a stack): the triangle of the QR factorization
    ``X = Q R`` has ``R^T R = X^T X = S``, decomposed by eigh in the constraint coordinates."""
    R = np.linalg.qr(X, mode="r")
    return np.linalg.eigh(_t(R) @ R)


def _independent(model: Model, w: np.ndarray) -> np.ndarray:
    """The independent constraint directions (module docstring, "Rank") among S's eigenvalues ``w`` (ascending; one
    state or a stack): above ``CONSTRAINT_RCOND`` times the largest and above :func:`_degenerate_floor`; the others,
    at or below, are redundant."""
    return w > np.maximum(CONSTRAINT_RCOND * w[..., -1:], _degenerate_floor(model))


def _distribution(Jc: np.ndarray, rows: np.ndarray) -> _Distribution:
    """The constraint distribution of the independent directions ``rows`` (columns, from :func:`_independent`): the
    SVD of ``rows^T Jc`` (module docstring, "Rank"); for one state or a stack of states of the same rank."""
    U, s, Vt = np.linalg.svd(_t(rows) @ Jc)
    r = rows.shape[-1]
    return _Distribution(rows=rows, U=U, s=s[..., :r], V=_t(Vt[..., :r, :]), Z=_t(Vt[..., r:, :]))


def _reduced_metric_factor(model: Model, chart, M: np.ndarray, Z: np.ndarray, p: np.ndarray):
    """Cholesky factor of ``Z^T M Z``, the metric restricted to the constraint distribution; not positive definite
    means the constraints leave a motion without kinetic energy free (a ValueError naming it)."""
    Mz = Z.T @ M @ Z
    try:
        return scipy.linalg.cho_factor(Mz), Mz
    except np.linalg.LinAlgError:
        raise ValueError(f"model '{model.name}': the metric restricted to the constraint distribution, Z^T M Z, is not "
                         f"positive definite at p = {p.tolist()} in chart '{_chart_name(chart)}' (a free motion "
                         f"without kinetic energy); eigenvalues {np.linalg.eigvalsh(Mz).tolist()}") from None


def _condition(Mz: np.ndarray) -> float:
    """2-norm condition number of the (symmetric positive definite) reduced metric ``Z^T M Z``; 1 when D = {0}."""
    if not Mz.size:
        return 1.0
    eig = np.linalg.eigvalsh(Mz)
    return float(eig[-1] / eig[0])


def _inconsistency(model: Model, pt: _Point, factor, X: np.ndarray, redundant: np.ndarray, forces: np.ndarray,
                   accel_scale: float) -> float:
    """The relative size of the right-hand sides ``r = -Jcdot pd - Jc M^-1 f`` of ``S lam = r`` in S's ``redundant``
    directions (columns), ``max |redundant^T r| / |r|`` over the covectors ``f`` (columns of ``forces``: with and
    without the input); ``Jc M^-1 f = X^T (L^-1 f)``, both whitened (:func:`_whitened`). 0 when S is regular;
    non-zero means ``H_t`` is empty (eq. 16: the constraints cannot all hold, e.g. a four-bar at its change point
    moving off both branches). |r| is taken at least ``1e-6 L accel_scale``: where every row is degenerate, r itself
    is rounding, and its share means nothing."""
    if not redundant.shape[1]:
        return 0.0
    r = -pt.Jc_bias[:, None] - X.T @ _whitened(factor, forces)
    size = np.maximum(np.linalg.norm(r, axis=0), 1e-6 * model.length_scale * accel_scale)
    return float(np.max(np.linalg.norm(redundant.T @ r, axis=0) / np.where(size > 0.0, size, 1.0)))


class _ConstraintConditioning(NamedTuple):
    """The conditioning of the constrained problem at one point (:func:`_constraint_conditioning`)."""

    conditions: dict     # "constraint", "constraint_consistency", "constraint_kept"
    rank: int
    lam_scale: float
    force_scale: float   # ||M^-1|| ||Jc|| lam_scale: the accelerations the constraint force can produce


def _constraint_conditioning(model: Model, pt: _Point, w: np.ndarray, independent: np.ndarray, inconsistency: float,
                             accel_scale: float, inverse_norm: float) -> _ConstraintConditioning:
    """From S's eigenvalues ``w`` (ascending, :func:`_constraint_spectrum`; the largest, ``w_max``, taken at least
    :func:`_degenerate_floor`) and its ``independent`` directions: ``"constraint"`` = cond S = ``w_max / w_min`` (inf
    when ``w_min`` is not positive: the multipliers are not unique), ``"constraint_kept"`` = ``w_max`` over the
    smallest independent eigenvalue (what the solve amplifies; 1 when none), the ``inconsistency``
    (:func:`_inconsistency`), the rank, and ``lam_scale = ||S^+|| (|Jcdot pd|_1 + ||Jc|| accel_scale)``, the size of the
    multipliers the summed terms could produce (``||S^+||`` one over the smallest independent eigenvalue; 0 when
    none), ``||Jc||`` the square root of ``Jc Jc^T``'s largest eigenvalue."""
    w_max = max(float(w[-1]), _degenerate_floor(model))
    kept = w[independent]
    jc_norm = math.sqrt(max(float(np.linalg.eigvalsh(pt.Jc @ pt.Jc.T)[-1]), 0.0))
    lam_scale = float((np.abs(pt.Jc_bias).sum() + jc_norm * accel_scale) / kept[0]) if kept.size else 0.0
    conditions = {"constraint": w_max / w[0] if w[0] > 0.0 else math.inf,
                  "constraint_consistency": inconsistency,
                  "constraint_kept": w_max / kept[0] if kept.size else 1.0}
    return _ConstraintConditioning(conditions, int(kept.size), lam_scale, inverse_norm * jc_norm * lam_scale)


def _constraint_distribution(model: Model, chart, pt: _Point, p: np.ndarray) -> tuple:
    """``(metric_factor, X, w, E, independent, dist)`` at a point (module docstring, "Rank"): the metric's Cholesky
    factor, the whitened constraint covectors ``X = L^-1 Jc^T``, S's eigenvalues ``w`` and directions ``E``
    (:func:`_constraint_spectrum`), the ``independent`` ones (:func:`_independent`) and their distribution."""
    metric_factor = _metric_factor(model, chart, pt.M, p)
    X = _whitened(metric_factor, pt.Jc.T)                    # the constraint covectors, whitened by the metric
    w, E = _constraint_spectrum(X)
    independent = _independent(model, w)
    return metric_factor, X, w, E, independent, _distribution(pt.Jc, E[:, independent])


def _constrained_split(model: Model, chart, pt: _Point, p: np.ndarray, pd: np.ndarray, tau: np.ndarray) -> Split:
    """Eqs. (12)-(17) by the null-space method (module docstring, "Constraints"): one particular admissible
    acceleration ``pdd_p = Jc^+ (-Jcdot pd)``, then in one LAPACK call the projections onto ``D`` (:func:`_projected`):
    ``total`` (forces ``f = tau - M Gamma(pd, pd) - dV/dp``), ``drift`` (``f0 = f - tau``, eq. 14) and ``ctrl =
    Z (Z^T M Z)^-1 Z^T tau`` (eq. 17, ``B_c tau`` directly), and the drift's parts (4.5-4.6) ``zvcf`` (forces
    ``-dV/dp``, bias 0) and ``drift_velocity`` (``-M Gamma(pd, pd)``, bias ``Jcdot pd``), each its own solve, which add
    up to the drift because the system is linear in (forces, bias); the multipliers from ``Jc^T lam = M pdd - f``. The
    reaction covector ``Jc^T lam`` (and at the drift) paired with pd is the constraint power (5.5); ``Jc pd`` the
    constraint covectors paired with the velocity; the conditioning from :func:`_constraint_conditioning`."""
    metric_factor, X, w, E, independent, dist = _constraint_distribution(model, chart, pt, p)
    factor, Mz = _reduced_metric_factor(model, chart, pt.M, dist.Z, p)
    Cqd = (christoffel_first_kind(pt.dM) @ pd) @ pd          # M Gamma(pd, pd), the chart's C qd (eq. 7)
    f0 = -Cqd - pt.dV                                        # eq. (24) as a covector, tau = 0
    f = tau + f0
    # total, drift (eq. 14), ctrl (eq. 17), zvcf (f = -dV, bias 0) and drift_velocity (f = -Cqd, bias Jcdot pd), each
    # its own right-hand side of one solve
    no_bias = np.zeros_like(pt.Jc_bias)
    total, drift, ctrl, zvcf, drift_velocity = _projected(
        dist, factor, pt.M, np.column_stack([f, f0, tau, -pt.dV, -Cqd]),
        np.column_stack([-pt.Jc_bias, -pt.Jc_bias, no_bias, no_bias, -pt.Jc_bias])).T
    lam = dist.solve_transposed(pt.M @ total - f)            # eq. (12): M pdd + h = tau + Jc^T lam
    lam_drift = dist.solve_transposed(pt.M @ drift - f0)     # eq. (14)
    cond_M, inverse_norm, accel_scale = _conditioning(model, metric_factor, Cqd, pt.dV, _applied(tau, pt), pd)
    inconsistency = _inconsistency(model, pt, metric_factor, X, E[:, ~independent], np.column_stack([f, f0]),
                                   accel_scale)
    cc = _constraint_conditioning(model, pt, w, independent, inconsistency, accel_scale, inverse_norm)
    Lambda, task_cond = _task_inertia(model, pt, metric_factor)   # eq. (22): the unconstrained metric's
    power, per = _pairing(tau, pd)
    reaction, reaction_drift = lam @ pt.Jc, lam_drift @ pt.Jc     # the reaction covectors Jc^T lam
    power_constr, per_constr = _pairing(reaction, pd)
    return Split(drift=drift, ctrl=ctrl, total=total, lam=lam, lam_drift=lam_drift, power_ctrl=power,
                 power_ctrl_per_coord=per, power_constr=power_constr, power_constr_per_coord=per_constr,
                 cond_M=cond_M, accel_scale=accel_scale + cc.force_scale, extras={"chart": _chart_name(chart)},
                 task_drift=pt.J @ drift + pt.Jdot_pd,
                 conditions={"reduced_metric": _condition(Mz), "task_inertia": task_cond, **cc.conditions},
                 kinetic_energy=pt.T, task_inertia=Lambda, constraint_value=pt.phi, constraint_jacobian=pt.Jc,
                 constraint_bias=pt.Jc_bias, constraint_velocity=pt.Jc @ pd, constraint_force=reaction,
                 constraint_force_drift=reaction_drift, constraint_rank=cc.rank, lam_scale=cc.lam_scale,
                 zvcf=zvcf, drift_velocity=drift_velocity, **_external_fields(pt, pd))


def _projected(dist: _Distribution, factor, M: np.ndarray, forces: np.ndarray, biases: np.ndarray) -> np.ndarray:
    """The null-space solution (module docstring, "Constraints") of ``M x = f + Jc^T lam``, ``Jc x = b`` for each
    column ``f`` of ``forces`` (n, c) and ``b`` of ``biases`` (k, c): ``x = x_p + Z (Z^T M Z)^-1 Z^T (f - M x_p)`` with
    ``x_p = Jc^+ b`` on the independent rows (a point of ``H_t``, eq. 16, for ``b = -Jcdot pd``; 0 for ``b = 0``),
    ``factor`` that of ``Z^T M Z``; separate right-hand sides of one LAPACK call, no step when ``D = {0}``."""
    x_p = dist.solve(biases.T).T
    if not dist.Z.shape[1]:
        return x_p
    return x_p + dist.Z @ _cho_solve(factor, dist.Z.T @ (forces - M @ x_p))


# ------------------------------------------------------------------------------------------------- public API


def split(model: Model, q, qd, u) -> Split:
    """The drift-control split (eq. 9) in the joint chart from eqs. (24)-(25): ``drift = -Gamma(qd, qd) - grad V``,
    ``ctrl = M^-1 B u``, ``total = M^-1 (B u - dV/dq) - Gamma(qd, qd)``; with constraints the same equations
    projected onto the constraint distribution (eqs. 12-17, module docstring). With spherical or free joints, q has
    nq entries (unit quaternions), qd is v (nv) and the accelerations are ``vdot``: the same equations in the group
    chart at ``xi = 0`` (module docstring, "Spherical and free joints")."""
    q, qd, u = check_state(model, q, qd, u)
    return _split(model, None, q, qd, model.input_map @ u)


def split_chart(model: Model, chart, p, pd, tau_p) -> Split:
    """The same split evaluated directly in the chart ``q = psi(p)``: the metric and potential are pulled back
    through ``psi`` symbolically and the connection computed in p (nothing is transformed from another chart).

    ``tau_p`` is the generalized force in the chart (a covector, ``Dpsi^T B u``); the accelerations returned are
    ``pdd``; ``power_ctrl = tau_p . pd`` (per coordinate ``tau_p_i pd_i``). ``chart=None`` is the joint chart.
    With constraints, ``phi(psi(p))`` is differentiated in p, so ``Jc`` is the chart's ``Jc_q Dpsi`` and ``lam`` is
    the joint chart's. A model with spherical or free joints is evaluated in a chart whose psi returns the whole q
    from nv coordinates (the ZYX Euler-angle chart; module docstring, "Charts of the group"): p, pd, tau_p have nv
    entries and the accelerations are ``pdd``, not ``vdot``. In a base-velocity representation (a chart with
    ``representation`` ``"world"`` or ``"mixed"``; module docstring, "Velocity representations") p is q itself (nq),
    pd the representation's w, tau_p its covector ``T^T f`` and the accelerations ``wdot``. Any other chart, and
    ``chart=None`` (use :func:`split` for the group chart), is ModelNotSupported.
    """
    if model.group_joints and chart is None:
        raise _refuse_chart(model, chart, "is the group chart itself: use split (q of nq entries, v)")
    if _representation(model, chart) is not None:       # p is q itself (nq), pd the representation's w (nv)
        q, w, _ = check_state(model, p, pd, np.zeros(model.m))
        (tau_p,) = chart_vectors(model, tau_p=tau_p)
        return _split(model, chart, q, w, tau_p)
    _check_group_chart(model, chart)
    p, pd, tau_p = chart_vectors(model, p=p, pd=pd, tau_p=tau_p)
    return _split(model, chart, p, pd, tau_p)


def linearize(model: Model, q, qd, u) -> Linearization:
    """A and B of eq. (11) (:class:`~formalisms.interface.Linearization`) at ``(q, qd, u)`` in the joint chart, from
    the exact derivatives of this backend's own equations (:func:`_derivatives`): ``vdot`` is the split's total, and
    ``dvdot/dq``, ``dvdot/dv`` and ``dvdot/du = M^-1 B`` (with constraints ``B_c B``, eq. 17) come from casadi's AD of
    the residual of eqs. (12)-(13) and the implicit function theorem. With spherical or free joints, ``dvdot/dq`` is
    along ``q (+) dq`` (the perturbation on the right): the derivative in the ambient q chained with the derivative
    of the group's ``integrate`` (:func:`_tangent_map`)."""
    q, qd, u = check_state(model, q, qd, u)
    dq, dv, dtau, s = _derivatives(model, None, q, qd, model.input_map @ u, model.input_map)
    return state_space(model, qd, dq @ _tangent_map(model, q), dv, dtau, s.total)


def linearize_chart(model: Model, chart, p, pd, tau_p) -> Linearization:
    """A and B of eq. (11) in the chart ``q = psi(p)`` with state ``x = (p, pd)`` and input ``tau_p`` (a covector in
    the chart): ``A = [[0, I], [dpdd/dp, dpdd/dpd]]``, ``B = [[0], [dpdd/dtau_p]]`` (``M_p^-1``, with constraints the
    chart's ``B_c``), from the chart's own evaluation (:func:`split_chart`'s Function, the same :func:`_derivatives`).
    A chart whose ``representation`` is a base velocity (``"world"``, ``"mixed"``) is ModelNotSupported (x would be
    q and w, not coordinates of one chart)."""
    if _representation(model, chart) is not None:
        raise ModelNotSupported(f"geometric: linearize_chart in the velocity representation of chart "
                                f"'{_chart_name(chart)}' is not supported (use a chart q = psi(p))")
    if model.group_joints and chart is None:
        raise _refuse_chart(model, chart, "is the group chart itself: use linearize (q of nq entries, v)")
    _check_group_chart(model, chart)
    p, pd, tau_p = chart_vectors(model, p=p, pd=pd, tau_p=tau_p)
    dp, dpd, dtau, s = _derivatives(model, chart, p, pd, tau_p, np.eye(model.n))
    n = model.n
    return Linearization(A=np.block([[np.zeros((n, n)), np.eye(n)], [dp, dpd]]),
                         B=np.vstack([np.zeros((n, n)), dtau]), vdot=s.total)


def _derivatives(model: Model, chart, point: np.ndarray, pd: np.ndarray, tau: np.ndarray,
                 inputs: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray, Split]:
    """``(dvdot/dpoint, dvdot/dpd, dvdot/du, split)`` at ``(point, pd)`` with the generalized force ``tau`` and the
    input map ``inputs`` (n x m; ``tau = inputs u``): the implicit function theorem on the residual ``r`` of
    eqs. (12)-(13) (:attr:`_Compiled.linearization`), which is zero at the split's ``(total, lam)``. For each
    direction ``x`` (a coordinate of the point, of pd, an input) the derivative ``(dvdot, dlam)`` solves the same
    system differentiated,

        M dvdot - Jc^T dlam = dtau/dx - d/dx (M a + M Gamma(pd, pd) + dV/dp - Jc^T lam)   at a = total,
        Jc dvdot = -d/dx (Jc a + Jcdot pd),

    i.e. ``dvdot = M^-1 (...)`` (the metric's Cholesky factor) or, with constraints, the split's own null-space solve
    (:func:`_projected`, the same independent rows): exact, from casadi's forward-mode AD of the backend's own
    expressions (M, its derivatives, dV/dp, Jc, Jcdot pd) in every direction at once, never finite differences.
    ``dvdot/dpoint`` has a column per coordinate of the point (nq for a model with spherical or free joints: the ambient
    derivative at the group chart's origin)."""
    c = _compiled(model, chart)
    pt = _evaluate(model, chart, point, pd)
    s = _split_at(model, chart, pt, point, pd, tau)
    n, kc, width = model.n, c.kc, point.size
    lam = np.asarray(s.lam, dtype=float) if model.constraints else np.zeros(0)
    directions = np.eye(width + n)                       # every coordinate of the point, then of pd
    at = np.hstack([np.tile(np.concatenate([pd, s.total, lam]), (width + n, 1)), directions])
    dr = c.linearization.batch(np.tile(_arguments(model, point), (width + n, 1)), at)   # row j: along direction j
    dr_dpoint, dr_dpd = dr[:width].T, dr[width:].T
    forces = np.hstack([-dr_dpoint[:n], -dr_dpd[:n], inputs])
    if model.constraints:
        metric_factor, _, _, _, _, dist = _constraint_distribution(model, chart, pt, point)
        factor, _ = _reduced_metric_factor(model, chart, pt.M, dist.Z, point)
        biases = np.hstack([-dr_dpoint[n:], -dr_dpd[n:], np.zeros((kc, inputs.shape[1]))])
        d = _projected(dist, factor, pt.M, forces, biases)
    else:
        d = _cho_solve(_metric_factor(model, chart, pt.M, point), forces)
    return d[:, :width], d[:, width:width + n], d[:, width + n:], s


def _tangent_map(model: Model, q: np.ndarray) -> np.ndarray:
    """``d/ds q (+) s e_j`` at ``s = 0`` (nq x nv, column j), the group's ``integrate`` with the perturbation on the
    right (Pinocchio's): 1 for a revolute or prismatic coordinate; for a quaternion block ``d quat = 1/2 quat (x)
    (e, 0)`` (quaternion product, x y z w order: ``(w e + [x y z] x e, -[x y z] . e)``), and for a free joint also
    ``d position = R(quat) e_linear`` (the body-frame linear velocity moves the origin along the body axes).
    The identity for a model without spherical or free joints."""
    T = np.zeros((model.nq, model.nv))
    for i, body in enumerate(model.bodies):
        a, v = model.q_index[i], model.v_index[i]
        if body.joint in ("revolute", "prismatic"):
            T[a, v] = 1.0
            continue
        if body.joint == "free":
            quat = q[a + 3:a + 7]
            K = _skew(quat[:3])
            T[a:a + 3, v:v + 3] = np.eye(3) + 2.0 * quat[3] * K + 2.0 * K @ K     # R(quat)
            a, v = a + 3, v + 3
        quat = q[a:a + 4]
        T[a:a + 3, v:v + 3] = 0.5 * (quat[3] * np.eye(3) + _skew(quat[:3]))
        T[a + 3, v:v + 3] = -0.5 * quat[:3]
    return T


def _skew(w: np.ndarray) -> np.ndarray:
    """``[w]x`` (numbers), so that ``[w]x e = w x e``."""
    return np.array([[0.0, -w[2], w[1]], [w[2], 0.0, -w[0]], [-w[1], w[0], 0.0]])


def _vectors(model: Model, chart, p, **rates) -> list[np.ndarray]:
    """The point ``p`` and the ``rates`` (velocity-like vectors) of the public geometric objects as float vectors:
    :func:`chart_vectors` (n each) for a model with revolute and prismatic joints only; for one with spherical or
    free joints, the configuration q (nq, unit quaternions) and rates of nv (StateError otherwise) in the group chart
    when ``chart`` is None, else the chart's p and rates (nv each; ModelNotSupported for a chart whose psi does not
    return the whole q, :func:`_check_group_chart` here and :func:`_group_chart_coordinates` when compiled)."""
    if not model.group_joints or (chart is not None and _representation(model, chart) is None):
        _check_group_chart(model, chart)
        return chart_vectors(model, p=p, **rates)
    out = joint_vectors(model, p, *rates.values())
    for label, value in zip(("q", *rates), out):
        if not np.all(np.isfinite(value)):
            raise StateError(f"{label} has non-finite entries: {value.tolist()}")
    check_state(model, out[0], np.zeros(model.nv), np.zeros(model.m))   # the quaternions are unit
    return out


def metric(model: Model, p, chart=None) -> np.ndarray:
    """The kinetic-energy metric ``M_p = d^2 T / dpd^2`` (n x n) at ``p`` in ``chart`` (joint chart when None)."""
    (p,) = _vectors(model, chart, p)
    return _evaluate(model, chart, p, np.zeros(model.n)).M


def metric_derivatives(model: Model, p, chart=None) -> np.ndarray:
    """The partial derivatives of the metric, ``dM[k, i, j] = d M_ij / dp_k`` (n, n, n), by automatic
    differentiation (so ``Mdot = sum_k dM[k] pd_k``). With spherical or free joints those of the group chart's metric
    at ``xi = 0``: ``D_k M - 1/2 (ad_k^T M + M ad_k)`` (module docstring)."""
    (p,) = _vectors(model, chart, p)
    return _evaluate(model, chart, p, np.zeros(model.n)).dM


def christoffel(model: Model, p, chart=None) -> np.ndarray:
    """The Levi-Civita connection of the kinetic-energy metric at ``p``: ``Gamma[i, j, k] = Gamma^i_jk`` (n, n, n),
    symmetric in (j, k); ``Gamma(pd, pd)^i = Gamma^i_jk pd^j pd^k`` is the drift's velocity-product term."""
    (p,) = _vectors(model, chart, p)
    pt = _evaluate(model, chart, p, np.zeros(model.n))
    return christoffel_symbols(pt.M, pt.dM, _metric_factor(model, chart, pt.M, p))[0]


def energy(model: Model, p, pd, chart=None) -> tuple[float, float]:
    """``(T, V)``: kinetic and potential energy at ``(p, pd)`` in ``chart``."""
    p, pd = _vectors(model, chart, p, pd=pd)
    values = _compiled(model, chart).energy(_arguments(model, p), pd)
    return float(values[0]), float(values[1])


def drift_field(model: Model, p, pd, chart=None) -> np.ndarray:
    """The intrinsic drift field of eq. (25) on TQ in ``chart``: ``(pd, -Gamma(pd, pd) - grad V)``, shape (2n,); with
    constraints the constrained drift of eq. (14) (the free one projected onto ``H_t``)."""
    p, pd = _vectors(model, chart, p, pd=pd)
    s = _split(model, chart, p, pd, np.zeros(model.n))
    return np.concatenate([pd, s.drift])


@dataclass(frozen=True)
class EnergyRate:
    """The time derivative of the total energy ``E = T + V`` along ``(p, pd, pdd)`` (article section 9).

    rate       ``dE/dt = dE/dp . pd + dE/dpd . pdd`` (automatic differentiation); zero under the drift, ``tau . pd``
               under the total.
    magnitude  ``sum_i |dE/dp_i pd_i| + sum_i |dE/dpd_i pdd_i|``: the size of the summed terms, to scale a tolerance.
    momentum   ``dT/dpd = M pd`` (the generalized momentum, a covector).
    """

    rate: float
    magnitude: float
    momentum: np.ndarray


def energy_rate(model: Model, p, pd, pdd, chart=None) -> EnergyRate:
    """:class:`EnergyRate` of ``E = T + V`` at ``(p, pd)`` with acceleration ``pdd``, in ``chart``."""
    (rate,) = energy_rates(model, p, pd, [pdd], chart)
    return rate


def energy_rates(model: Model, p, pd, accelerations, chart=None) -> list[EnergyRate]:
    """:func:`energy_rate` at ``(p, pd)`` for each acceleration of ``accelerations``: E's gradient is evaluated once."""
    if not len(accelerations):
        return []
    labels = ["pdd"] if len(accelerations) == 1 else [f"pdd[{i}]" for i in range(len(accelerations))]
    p, pd, *accelerations = _vectors(model, chart, p, pd=pd, **dict(zip(labels, accelerations)))
    n = model.n
    values = _compiled(model, chart).energy(_arguments(model, p), pd)
    dE_dp, dE_dpd = values[2:2 + n], values[2 + n:]
    momentum = np.array(dE_dpd)
    momentum.setflags(write=False)
    rates = []
    for pdd in accelerations:
        terms = np.concatenate([dE_dp * pd, dE_dpd * pdd])
        rates.append(EnergyRate(rate=float(terms.sum()), magnitude=float(np.abs(terms).sum()), momentum=momentum))
    return rates


# ------------------------------------------------------------------------------------------------------- batches

#: States per block of :func:`split_batch`, at most; a block's Function output (its largest array: the metric
#: derivatives' upper triangles, ``n^2 (n + 1) / 2`` numbers a state) has at most ``BATCH_ENTRIES`` numbers (16 MB), so
#: the memory stays bounded for long chains too.
BATCH_BLOCK = 2048
BATCH_ENTRIES = 2 ** 21


def _stack_cholesky(M: np.ndarray, explain: Callable[[int], object]) -> np.ndarray:
    """Lower Cholesky factors ``L`` (``M = L L^T``) of a stack of symmetric matrices; when one is not positive
    definite, ``explain(row)`` of the state with the smallest eigenvalue raises the single-state ValueError, which is
    re-raised naming that row."""
    try:
        return np.linalg.cholesky(M)
    except np.linalg.LinAlgError:
        worst = int(np.argmin(np.linalg.eigvalsh(M)[:, 0]))
        try:
            explain(worst)
        except ValueError as err:
            raise ValueError(f"state {worst} of the batch: {err}") from None
        raise ValueError(f"state {worst} of the batch: a matrix to factor is not positive definite (Cholesky failed; "
                         f"eigenvalues {np.linalg.eigvalsh(M[worst]).tolist()})") from None


def _forward(L: np.ndarray, b: np.ndarray) -> np.ndarray:
    """``L^-1 b`` for stacks of lower-triangular ``L`` (N, n, n) and ``b`` (N, n, columns): forward substitution, one
    row at a time for the whole stack."""
    y = np.empty(b.shape)
    for i in range(L.shape[-1]):
        y[:, i] = (b[:, i] - (L[:, i, None, :i] @ y[:, :i])[:, 0]) / L[:, i, i, None]
    return y


def _stack_cho_solve(L: np.ndarray, b: np.ndarray) -> np.ndarray:
    """``M^-1 b`` with ``M = L L^T`` for stacks (each column of ``b`` its own solve): forward, then back substitution
    with ``L^T``."""
    y, n = _forward(L, b), L.shape[-1]
    x = np.empty(b.shape)
    for i in range(n - 1, -1, -1):
        x[:, i] = (y[:, i] - (_t(L)[:, i, None, i + 1:] @ x[:, i + 1:])[:, 0]) / L[:, i, i, None]
    return x


def _constrained_block(model: Model, Jc: np.ndarray, bias: np.ndarray, M: np.ndarray, L: np.ndarray, Cqd, dV, P,
                       tau) -> tuple[np.ndarray, ...]:
    """``(drift, ctrl, total, lam, lam_drift)`` of a stack of constrained states by the null-space method of
    :func:`_constrained_split` (eqs. 12-17), the states grouped by the rank of ``S = Jc M^-1 Jc^T`` (its spectrum and
    independent directions as there: :func:`_constraint_spectrum`, :func:`_independent`), each group's
    :class:`_Distribution` a stack."""
    N, n = M.shape[:2]
    w, E = _constraint_spectrum(_forward(L, _t(Jc)))         # from L^-1 Jc^T, M = L L^T
    k = w.shape[-1]
    rank = _independent(model, w).sum(axis=1)
    f0 = -Cqd - dV                                           # eq. (24) as a covector, tau = 0
    f = tau + f0
    out = [np.empty((N, n)) for _ in range(3)] + [np.empty((N, k)) for _ in range(2)]
    for r in np.unique(rank):
        i = np.flatnonzero(rank == r)
        dist = _distribution(Jc[i], E[i][..., k - r:])
        Mi = M[i]
        pdd_p = dist.solve(-bias[i])                         # a point of H_t (eq. 16)
        rhs = _t(dist.Z) @ np.stack([f[i] - _mv(Mi, pdd_p), f0[i] - _mv(Mi, pdd_p), tau[i]], axis=-1)
        steps = np.zeros((len(i), n, 3))
        if n > r:
            Lz = _stack_cholesky(_t(dist.Z) @ Mi @ dist.Z,
                                 lambda j: _reduced_metric_factor(model, None, Mi[j], dist.Z[j], P[i[j]]))
            steps = dist.Z @ _stack_cho_solve(Lz, rhs)
        total, drift = pdd_p + steps[..., 0], pdd_p + steps[..., 1]
        lam = dist.solve_transposed(_mv(Mi, total) - f[i])                 # eq. (12)
        lam_drift = dist.solve_transposed(_mv(Mi, drift) - f0[i])          # eq. (14)
        for o, part in zip(out, (drift, steps[..., 2], total, lam, lam_drift)):
            o[i] = part
    return tuple(out)


def _first_kind_contracted(c: _Compiled, flat: np.ndarray, PD: np.ndarray) -> np.ndarray:
    """``Gamma_{l,jk} pd^j pd^k`` (= ``M Gamma(pd, pd)``, the chart's ``C qd`` of eq. 7) of a stack of states, from the
    upper triangles of the metric derivatives in the Function's output ``flat``, without forming the (n, n, n) symbols:
    the first-kind formula of :func:`christoffel_first_kind` contracted with the rates, whose two first terms are equal
    once contracted, ``(Mdot pd)_l - 1/2 pd^T (d_l M) pd`` with ``Mdot = d_k M pd^k``."""
    rows, cols = c.upper_pairs
    dM_upper = flat[:, c.dM_upper_slice].reshape(len(flat), PD.shape[1], rows.size)   # [state, k, upper entry]
    Mdot = (PD[:, None, :] @ dM_upper)[:, 0, c.M_index]                     # d_k M pd^k, (N, n, n)
    pairs = PD[:, rows] * PD[:, cols] * np.where(rows == cols, 1.0, 2.0)    # pd^i pd^j over the triangle
    return _mv(Mdot, PD) - 0.5 * _mv(dM_upper, pairs)


def _split_block(model: Model, P: np.ndarray, PD: np.ndarray, tau: np.ndarray) -> tuple:
    """``(drift, ctrl, total, lam, lam_drift)`` of a block of joint-chart states: the compiled Function mapped over the
    block, then eqs. (24)-(25) for the whole stack. ``Gamma(pd, pd) = M^-1 (Gamma_{.,jk} pd^j pd^k)``: the first-kind
    symbols contracted with the rates (:func:`_first_kind_contracted`), then raised by the metric (the same connection
    as :func:`_split`, which raises every symbol first); with constraints :func:`_constrained_block`."""
    c = _compiled(model, None)
    flat = c.evaluate.batch(_arguments(model, P), PD)
    M, dV = flat[:, c.M_index], flat[:, c.dV_slice]
    if c.ext_slice is not None:
        dV = dV - flat[:, c.ext_slice]                                       # dV/dp - tau_ext
    L = _stack_cholesky(M, lambda j: _metric_factor(model, None, M[j], P[j]))
    Cqd = _first_kind_contracted(c, flat, PD)                                # M Gamma(pd, pd) (eq. 7)
    if model.constraints:
        return _constrained_block(model, flat[:, c.Jc_index], flat[:, c.Jc_bias_slice], M, L, Cqd, dV, P, tau)
    gamma_pdpd, grad_V, ctrl, forced = np.moveaxis(_stack_cho_solve(L, np.stack([Cqd, dV, tau, tau - dV], -1)), -1, 0)
    return -gamma_pdpd - grad_V, ctrl, forced - gamma_pdpd, None, None    # eq. (25); total solved on its own


def split_batch(model: Model, Q, QD, U) -> SplitBatch:
    """:func:`split` of N states at once (rows of ``Q``, ``QD``, ``U``), in blocks of at most :data:`BATCH_BLOCK` states
    (fewer for a long chain: :data:`BATCH_ENTRIES`), each by :func:`_split_block`."""
    Q, QD, U = check_batch(model, Q, QD, U)
    tau = U @ model.input_map.T
    size = max(1, min(BATCH_BLOCK, BATCH_ENTRIES // _compiled(model, None).evaluate.size))
    blocks = [slice(i, i + size) for i in range(0, max(len(Q), 1), size)]
    parts = [_split_block(model, Q[b], QD[b], tau[b]) for b in blocks]
    drift, ctrl, total, lam, lam_drift = (None if p[0] is None else np.concatenate(p) for p in zip(*parts))
    return SplitBatch(drift=drift, ctrl=ctrl, total=total, lam=lam, lam_drift=lam_drift)


FORMALISM = Formalism(
    name="geometric",
    summary="Geometric mechanics: kinetic-energy metric, Levi-Civita connection, intrinsic drift field "
            "(article 6.4, eqs. 24-25), any chart",
    split=split,
    split_chart=split_chart,
    split_batch=split_batch,
    evaluation=evaluation,
    linearize=linearize,
    linearize_chart=linearize_chart,
)
