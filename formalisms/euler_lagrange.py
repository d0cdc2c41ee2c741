"""Euler–Lagrange formalism (article 4.7.1): the dynamics from the energies, derived symbolically, in the joint
coordinates or in any chart ``q = psi(p)`` (article 6.4.6, 9.1; docs/design.md, charts).

Derivation (symbolic, from the model data and the chart alone), in coordinates ``p`` with rates ``pd``:
  0. The joint coordinates as functions of the chart's: ``q_k = psi_k(p)``, each a named intermediate, so the
     Jacobian entries ``Dpsi_kj = dq_k/dp_j`` are named intermediates of the chain rule too. In the joint chart
     (``chart=None``, or a chart whose ``psi`` is literally the identity) ``q_k`` *is* the coordinate ``p_k``,
     and every step below is the joint-coordinate derivation (same expressions, same code path).
  1. Body poses ``R_i``, ``p_i`` by composing the fixed joint placements and the joint motions; ``sin q_k`` and
     ``cos q_k`` are named intermediates with seeded derivatives ``d sin(q_k)/dp_j = cos(q_k) Dpsi_kj``.
  2. Kinetic energy ``T = sum_i 1/2 m_i |c_i_dot|^2 + 1/2 tr(R_i_dot J_i R_i_dot^T)`` with ``c_i`` the COM and the
     body velocities ``c_i_dot``, ``R_i_dot`` the time derivatives of the staged poses (:meth:`_Staged.dt`: each
     intermediate's rate is the product and chain rule applied to its definition, one named symbol per
     intermediate, so the joint rates enter as ``qd = Dpsi pd``: the Lagrangian with ``q = psi(p)`` substituted) and
     ``J_i = 1/2 tr(I_i) 1 - I_i`` (the rotational energy ``1/2 w^T I w`` written with the rotation matrix's rate,
     so no angular velocity is formed), plus each joint's rotor ``1/2 a_i |v_i|^2`` (``Body.armature``; the rate of
     the joint's coordinate, or of its motion for a group joint: :func:`_rotor_energy`), which puts ``a_i`` on M's
     diagonal. Potential energy ``V = -sum_i m_i gravity . c_i``. The armature is a number of the derivation (the
     cache key's model digest covers it).
  3. Lagrange's equation (lagrangian chapter, "Euler–Lagrange turns energy into motion";
     ``d/dt dL/dpd - dL/dp = tau``), with the momenta ``P = dT/dpd``: ``M = dP/dpd = d^2 T / d pd^2`` (section 4.7.1
     step 1, eq. 6), ``g = dV/dp`` (step 2, eq. 8) and the velocity-product vector ``C pd = d/dt P - dT/dp`` at
     ``pdd = 0`` (the rest of ``d/dt P`` is ``M pdd``; :func:`_velocity_product`). It equals step 3's Christoffel
     form ``(C pd)_i = sum_jk 1/2 (dM_ij/dp_k + dM_ik/dp_j - dM_jk/dp_i) pd_j pd_k`` (eq. 7), which costs n^3
     derivatives of M's entries (minutes and gigabytes for a 48-joint robot); Lagrange's equation costs one
     derivative of T per coordinate and one time derivative per momentum, and shares no formula with the
     geometric backend's Christoffel symbols.
  4. Constraints (article 5.1, 5.7 steps 1-2): ``phi(p)`` row by row as :mod:`cases.constraints` fixes it, from the
     same staged point positions ``p(body, offset) = p_i + R_i offset`` as the energies (a joint coupling from
     ``q = psi(p)``), ``Jc = dphi/dp`` and ``Jcdot pd = d^2 phi / dt^2`` at ``pdd = 0``, i.e.
     ``sum_jk d^2 phi/dp_j dp_k pd_j pd_k`` (eq. 13), by the same chain rule and time derivative. In a chart this is
     ``phi(psi(p))``, so its Jacobian is ``Jc Dpsi`` without forming either, and its multipliers are the joint
     chart's.
  5. External loads (``cases.loads``; article 2.3, eq. 12) by virtual work, from the same staged poses: a force ``f``
     at the point ``x = p_i + R_i offset`` contributes ``Q_j = f . dx/dp_j``, a couple ``m`` (world) ``m . vee(dR_i/dp_j
     R_i^T)`` (body-frame vectors turned by ``R_i``), and a spring its potential ``V_s = 1/2 k (|x - a| - L0)^2`` as
     ``-dV_s/dp_j`` (:func:`_external_forces`). Velocity-independent, ``tau_ext = Q`` joins ``g``: the derivation's
     ``g`` is ``dV/dp - Q`` (so the drift, its part at rest and the linearization carry it), and ``Q`` itself is a
     further output (``Qext``), reported as ``external_force``.
In a chart these are the chart's own M_p, C_p pd and g_p (different entries, article 6.4.6), never the joint
ones mapped; the accelerations they give are the chart's ``pdd``, equal to the joint ones mapped by
``qdd = Dpsi pdd + (d/dt Dpsi) pd`` (9.1), which is what the tests check.
Group joints (spherical and free; article 2.1-2.2, 6.2, 6.4). A quaternion is not a coordinate: its four entries are
tied by ``|quat| = 1`` and its velocity is not ``d quat / dt`` (``cases.model``: v is the body angular velocity,
the body twist for a free joint). Such a model is derived in LOCAL EXPONENTIAL COORDINATES around the state:
  * Chart. ``q(xi) = q (+) xi``, Pinocchio's ``integrate`` on the right: spherical ``R(xi) = R0 exp([xi]x)``; free
    ``(R, p)(xi) = (R0, p0) exp6(xi)`` on SE(3), ``xi = (rho, phi)`` a twist in the order (linear, angular),
    ``exp6`` the exponential of the 4x4 ``Xi = [[[phi]x, rho], [0, 0]]``. Revolute and prismatic coordinates stay
    themselves; the chart has nv coordinates, in v's order (:func:`_local_coordinates`, :func:`_local_motions`).
    The state's orientation ``R0 = R(quat)`` (formed here: ``I + 2 w [u]x + 2 [u]x^2``) and position ``p0`` are
    PARAMETERS of the derivation (symbols that are not differentiated), so a model is derived once, not per state;
    the code is evaluated at ``xi = 0`` with the state's q (:func:`_at_origin`).
  * Velocity. Write the joint's motion ``E(xi) = exp(X(xi))``, X linear in xi (``[xi]x``, or ``Xi``). The joint's
    relative velocity in the body frame is ``[v] = E^-1 Edot`` (the placement and R0 are constant). At ``xi = 0``:
    ``E = I``, ``Edot = X(xid)``, so ``v = xid`` (dexp(0) = I).
  * Acceleration: ``d/dt v = xidd`` exactly at ``xi = 0``. ``d/dt [v] = -E^-1 Edot E^-1 Edot + E^-1 Eddot``, at 0
    ``-X(xid)^2 + Eddot``. With ``E = I + X + X^2/2 + O(|xi|^3)``, ``Eddot = X(xidd) + d^2/dt^2 (X^2/2)`` and
    ``d^2/dt^2 (X(xi)^2 / 2) = X(xid)^2 + (X(xi) X(xidd) + X(xidd) X(xi)) / 2`` is ``X(xid)^2`` at 0 (the second-order
    term is symmetric in its two factors): the two squares cancel and ``d/dt [v] = X(xidd)``. Equivalently ``v =
    dexp_-xi xid = (I - ad_xi / 2 + O(|xi|^2)) xid``, so ``vdot = xidd - ad_xid xid / 2 = xidd`` at 0, since
    ``ad_a a = 0`` (``a x a = 0``; for a twist ``(w x v + v x w, w x w) = 0``). So the accelerations this chart
    gives ARE the v-space accelerations of the contract, with no correction term.
  * Forces. A v-space force f has power ``f . v = f . dexp_-xi xid``: its chart covector ``dexp_-xi^T f`` is f at 0,
    so ``B u`` and ``Jc^T lam`` enter unchanged; ``T = 1/2 v^T M v`` gives ``M_xi(0) = M``. The Euler–Lagrange
    equations at 0, ``M(0) xidd + C(0, xid) xid + g(0) = B u (+ Jc^T lam)``, hold for every xidd = vdot, so they
    ARE ``M vdot + nle(q, v) = tau``: ``g(0) = rnea(q, 0, 0)`` and ``C(0, v) v = rnea(q, v, 0) - g`` (what
    :func:`terms` returns for such a model). Constraints likewise: ``Jc = dphi/dxi (0)`` is the v-space Jacobian,
    and ``d^2/dt^2 phi = Jc xidd + xid^T (d^2 phi / dxi^2) xid`` gives ``Jcdot v = v^T (d^2 phi/dxi^2)(0) v``.
  * Truncation (:data:`EXP_ORDER` = 3; 2 would do for the dynamics). At ``xi = 0`` the equations use ``M``,
    ``dM/dxi``, ``dV/dxi``, ``phi``, ``dphi/dxi`` and ``d^2 phi/dxi^2``: T's coefficients (M is a quadratic form in
    the poses' first derivatives) to first order in xi, V to first and phi to second order, i.e. derivatives of the poses of order at most 2 in xi
    (any order in the other coordinates). ``E_2 = I + X + X^2/2`` agrees with ``exp(X)`` to ``O(|xi|^3)``, and
    its first and second derivatives at 0 with exp's (the 4x4 series is SE(3)'s: rotation ``sum [phi]x^k / k!``,
    translation ``sum [phi]x^(k-1) rho / k!``), so every number evaluated at 0 is exact, although ``E_2`` is not a
    rotation away from 0 (the T written with it differs from the true one by ``O(|xi|^2) |xid|^2``). The closed forms
    (Rodrigues, ``V(phi)``) would bring ``sin|xi| / |xi|`` and its removable 0/0 into symbolic differentiation.
    ``tests/backends/test_group_euler_lagrange.py`` shows orders 2, 3 and 4 give the same numbers and order 1 does
    not. The series is truncated at 3, not 2, because the linearization differentiates the same derivation once more
    in xi (module docstring, "Linearization"): one derivation then serves both (:func:`_derived`), where two cost a
    humanoid 4.8 s each, and at ``xi = 0`` the code is the same (the third-order terms vanish there).
  * Caches. The local chart (and its order) is part of the cache key (:data:`GROUP_CHART`).
Velocity representations (:func:`split_chart` with a chart whose ``representation`` is ``"world"`` or ``"mixed"``;
docs/design.md "Configuration on Lie groups", article 6.2, 6.4). The configuration stays q and the velocity is w with
``v = T(q) w``; everything is in each joint's REFERENCE frame (the frame its q is measured in: the parent's frame moved
by the body's fixed placement; the world for a floating base at the identity placement). World: a free joint's w is
its spatial twist ``V_s = (pdot - omega_s x p, omega_s)``, a spherical joint's ``omega_s = R w_b``; mixed: a free
joint's w is ``(pdot, omega_s)``, a spherical joint's ``omega_s``. The derivation is the "Group joints" one in the
local exponential chart with the exponential on the LEFT (:func:`_local_motions` with ``side``): spherical
``R(xi) = exp([xi]x) R0``; free world ``(R, p)(xi) = exp6(xi) (R0, p0)`` on SE(3); free mixed ``p = p0 + xi_lin``,
``R = exp([xi_ang]x) R0``. At ``xi = 0``:
  * Velocity. ``Xdot X^-1 = X(xid)`` (the right-trivialized velocity): the spatial twist (world), ``omega_s`` (ball
    joints), and for mixed ``pdot = xid_lin``, ``omega_s = xid_ang``. So ``xid = w``.
  * Acceleration. ``d/dt (Xdot X^-1) = Eddot - X(xid)^2`` at 0, and ``Eddot = X(xidd) + X(xid)^2`` by the same
    symmetric order-2 term as on the right (``ad_a a = 0``): ``xidd = wdot`` exactly (mixed: ``p`` is affine in xi and
    the rotation is SO(3)'s left chart). No rate term is added here; the harness's ``Tdot w`` is its own.
  * Forces. The power of a v-force f is ``f . T(q(xi)) A(xi) xid`` with ``A(0) = I``, so the chart's covector at 0 is
    ``T^T f`` (what the harness passes as ``tau_p``), and ``M_xi(0) = T^T M T`` comes out of ``T = 1/2 v^T M v``
    itself; Lagrange's velocity-product terms, g and the constraint terms are the chart's own, as for the right chart.
  * Truncation and caches: as for the right chart (:data:`EXP_ORDER`); the cache key holds the chart's key and the
    local chart's description (:data:`GROUP_CHART_LEFT`). A representation chart of a model without group joints is
    ModelNotSupported (:func:`_representation`).
Group joints in a chart ``q = psi(p)`` (:func:`split_chart`; article 6.4.6, 9.1; e.g.
``crosscheck.checks.charts.EulerZYX``, ZYX Euler angles per spherical or free joint). Such a chart has nv coordinates p
and its ``psi`` returns the WHOLE q (nq entries), each quaternion a function of p that is unit for every p; the
derivation is then the scalar charts' one, steps 0-4, with the poses of the group joints written through psi:
  * ``q = psi(p)`` is formed with the staged ``sin`` and ``cos`` (:meth:`_Staged.trig`: ``sin(e)``, ``cos(e)`` of a
    chart's half angle ``e`` are named symbols with seeded derivatives ``cos(e) de/dp_j``, ``-sin(e) de/dp_j``);
    a revolute or prismatic joint reads its coordinate at ``q_index`` (:attr:`_Staged.joint_index`).
  * A group joint's motion is ``R(quat(p)) = I + 2 w [u]x + 2 [u]x^2`` of psi's quaternion block (a rotation for
    every p, since the block is unit), and for a free joint the translation ``X_joint = (R, pos(p))`` with ``pos``
    psi's position block (:func:`_chart_motions`); the body poses compose as for any joint (:func:`_poses`).
  * Everything after the poses is unchanged and exact: T(p, pd) with the body velocities from differentiating
    the poses in p (``R_dot = sum_j dR/dp_j pd_j``, ``c_dot`` likewise), so the angular velocity enters through
    the rotational energy ``1/2 tr(R_dot J R_dot^T) = 1/2 w^T I w`` and the Euler-rate map ``w = E(p) pd`` is never
    formed; ``M_p = d^2 T/d pd^2``, Lagrange's velocity-product terms in p, ``g_p = dV/dp``, ``phi(psi(p))`` and its
    derivatives. The accelerations are the chart's ``pdd`` (no truncation, no local chart), the multipliers the
    joint chart's, ``Jc_p = Jc Dpsi`` with ``Dpsi`` the chart's map from pd to v, which this module never forms.
  * :func:`chart_key` validates such a chart (:func:`_group_chart_refusal`: psi evaluates on nv symbols, returns nq
    entries, and its quaternion blocks are unit to 1e-12 at a few fixed points); any other chart of a model with
    group joints (a chart of scalar coordinates, the harness's group identity) is ModelNotSupported. The cache key
    holds the chart's key and :data:`GROUP_IN_CHART`. At gimbal lock (``Dpsi`` singular) M_p is singular: there and
    within ~1e-8 rad of it the Cholesky factorization fails with a ValueError naming the chart (the harness leaves
    out states with cond(Dpsi) > 1e4); closer than that to the lock the answers lose accuracy as cond(M_p) grows.
The derivation is staged: every pose entry and every derivative of one is a named intermediate, and
derivatives go through a memoized chain rule (forward-mode differentiation done symbolically), so the
expressions never expand the kinematic chain. The symbolic engine is SymEngine, the C++ core of the sympy
project with sympy's API, because pure-Python sympy takes minutes on a 9-joint arm.
Compilation: the staged definitions in order, with repeated subexpressions computed once (tree-matching CSE, linear
time: :class:`_Source`), written by one emitter as C and as Python (:func:`generate_source`; the same operations in
the same order, so both round alike); one call returns M, C pd, g, the kinetic energy T and the constraint terms phi,
Jc, Jcdot pd at the state.
  * Compiled (:func:`_native`). The C is compiled by the system compiler (``cc``, else ``gcc``; :data:`C_FLAGS`:
    -O1, IEEE arithmetic as written, no fused multiply-add) into a shared library called through ctypes, with a
    batched entry that runs a block of states in one call. It runs two states at once, one per lane of a vector of
    two doubles (:func:`_c`), and is cut into functions of about :data:`C_PART` characters and its sums into partial
    sums (:data:`C_LONGEST`), because gcc's time on a function grows faster than the function: in one function the
    Panda's code took 63 s at -O1, and 166 s for tiago's cut only by statements. Measured cold on a loaded 2-core
    machine (CPU seconds of the compiler; the derivation apart): the Panda 3.3 s at -O1 (1.5 s at -O0, 4.3 s at -O2
    for code no faster), a 24-link chain 7 s (4 s at -O0, 13.5 s at -O2), tiago (48 joints, 24,600 statements) 24 s
    (16.5 s at -O0); -O1 code evaluates 2-3x as fast as -O0 code, so -O1 at every size. symengine's LLVM
    ``Lambdify`` is not used: it compiles expressions of its input symbols, so the staged intermediates would have to
    be substituted into them, expanding the kinematic chain the staging keeps apart.
  * Interpreted (:func:`_interpreted`), without a compiler, with ``CROSSCHECK_COMPILE=0``, or when the C does not
    compile (a RuntimeWarning): the Python source run with ``math`` for one state, and with numpy's ``sin``, ``cos``
    and ``sqrt`` on columns of states for a batch (each coordinate an array with one entry per state).
  Compiling costs about three derivations, so a model in a chart is compiled only once it has evaluated
  :data:`COMPILE_AFTER` states in the process (a campaign, a batch; the few states of a gate stay interpreted), or at
  once when its library is in the cache (:class:`_Deferred`). :func:`evaluation` says which is in use
  (``crosscheck formalisms``); ``split``, ``split_chart`` and ``split_batch`` all run the same one.
World as parameters. Whatever places the model in the world, and nothing else, is a parameter of the derivation, not
a number in it (``cases.world``, :class:`_World`): gravity, each root body's placement, the world points and
directions of the constraints (a circle's centre and plane, a ground point, a line's origin and normals, the
directions of a point's velocity rows, the ground plane of a rolling contact) and the world-frame data of the loads
(forces, couples, a spring's anchor). They are symbols the chain rule never differentiates; the generated code reads
their numbers after the coordinates (:func:`_world_values`), so a moved scene or a gravity-free copy of a model
evaluates the model's own derivation and compiled code with other numbers (the frame checks then compare that code's
answers in two placements). The code grows about 10 % (``R_root^T R_root`` no longer simplifies).
Caches: the sources (Python and C), the Python code object (``marshal``) and the library are cached on disk keyed by
the model digest without its world data (``cases.world.shape_digest``; it covers the constraints), the chart's key
(``"identity"`` for the joint chart), for a model with group joints the local chart with its order
(:data:`GROUP_CHART`), and a hash of this module, so a second process loads them instead of re-deriving or compiling
(:func:`cached_source`, :func:`cached_code`, :func:`_library`). Every file is written atomically (a temporary file
renamed into place: :func:`~formalisms.interface.write_cache_file`), and a library is compiled in
a private directory, so processes filling the same entry at once do not disturb each other; a library is sealed with
its SHA-256 and one that does not match (damaged, truncated) is compiled again, never loaded; a cache that cannot be
written only costs the work next time.
Batches (:func:`split_batch`): the generated code gives every state's M, C qd, g and constraint terms in one call;
the solves below are written for one state or a stack alike (batched Cholesky, substitution over the stack), with
constrained states grouped by the rank of S.
Solving: Cholesky factorization of M, never an explicit inverse. With constraints, the KKT system of article 5.6
as one block matrix, scaled by the Cholesky factor and the eigen-directions of ``S = Jc M^-1 Jc^T`` kept above
``CONSTRAINT_RCOND`` (rank-revealing: redundant constraints give the minimum-norm multipliers, :func:`_kkt`), and
the control part from the constraint-consistent input map of eq. (17) (:func:`_constrained_input_map`).
Drift's parts (article 4.5-4.6): every Split carries ``zvcf = -M^-1 g`` and ``drift_velocity = -M^-1 C xd``, each
solved directly (:func:`_free_parts`; with constraints the KKT solves with ``f = -g`` and no bias, and with ``f = -C
xd`` and the bias ``Jcdot xd``: :func:`_constrained_parts`), so that they add up to the drift to rounding.
Linearization (article 4.8, eq. 11; :func:`linearize`): the exact derivatives of this derivation's own equations.
  * Differentiated, not derived (forward mode through the dynamics' own code; :func:`linear_terms`). The rows
    ``force = M a + C xd + g - Jc^T lam`` and ``accel = Jc a + Jcdot xd`` at fixed ``a`` and ``lam`` need the first
    derivatives of M, C xd, g, Jc and Jcdot xd in every coordinate and rate. They come from the generated Python
    that ``split`` runs, run once on 2n complex columns, column j at ``x + i h e_j`` (then ``xd + i h e_j``) with
    h = :data:`STEP` = 2^-70: every operation of the code (``+``, ``*``, ``1/b``, ``sqrt``, ``sin``, ``cos``,
    integer powers) is analytic, so the imaginary part of each output is h times its directional derivative, carried
    operation by operation like a dual number's (the complex step). Nothing is subtracted, so the derivatives are as
    accurate as the values; h^2 ~ 1e-42 is below every rounding of the real parts. The cost is one batched
    evaluation of the dynamics' code over 2n columns (:func:`_derivatives`): the Panda 10 ms, solo12 16 ms, with no
    derivation (until 2026-11 the derivatives were derived symbolically: 5-11 s cold on those two, minutes for a
    humanoid). With group joints the joint chart's code is evaluated at ``xi = 0`` with xi gone, so the linearization
    has its own program, the dynamics in the local chart to order :data:`LINEAR_ORDER` with xi among the inputs
    (:func:`_local_program`), derived on the first ``linearize`` of the model (never during ``split``) and cached in
    memory and on disk (:func:`linearization_key`); in a chart and without group joints nothing is derived.
  * Numeric. ``vdot`` and ``lam`` by the split's own solve; then per direction the differentiated KKT system
    ``[[M, -Jc^T], [Jc, 0]] [dvdot; dlam] = [dtau - d force; -d accel]`` at ``a = vdot`` by the same scaled,
    rank-revealing :func:`_kkt` (minimum-norm multipliers, the same rank rule), ``dvdot/du = B_c B`` (eq. 17); without
    constraints ``dvdot = M^-1 (dtau - d force)``, ``dvdot/du = M^-1 B`` with the Cholesky factor.
  * Group joints. The derivation runs in the local exponential chart ``q exp(xi)`` at ``xi = 0`` with the series to
    order :data:`LINEAR_ORDER` = 3 (the xi-derivatives of ``C xd`` and ``Jcdot xd`` need the poses' third derivatives
    in xi, which ``E_3`` has exactly). That chart's ``xidd = F(xi, xid, u)`` is converted to the contract's convention
    (``vdot`` at ``q exp(s e)`` with v fixed) in closed form with the chart's own derivative, the right Jacobian
    ``v = J_r(xi) xid``, ``J_r = dexp_-xi = I - ad_xi / 2 + ad_xi^2 / 6 - ...``: a v-force ``tau`` is the chart
    covector ``J_r^T tau`` (``dtau = -ad_e^T tau / 2``, :func:`_chart_force`), ``xid = v + s ad_e v / 2`` and ``vdot =
    J_r xidd + (d/dt J_r) xid``, giving :func:`_tangent`'s columns. ``dvdot/dv = dF/dxid`` at 0 (``J_r(0) = I``).
  * In a chart ``q = psi(p)`` (:func:`linearize_chart`): the chart's own derivation differentiated the same way, x =
    (p, pd), ``A_qq = 0`` and the input ``tau_p`` (``B = [[0], [B_c]]``, n columns); no local chart, so no chain rule
    (a zyx chart of group joints is a chart like any other). Velocity representations are refused.
Everything a split reports is computed here (the interface supplies only types and validators), by methods of its
own: cond(M) and ``||M^-1||`` from M's extreme eigenvalues, each by Sturm-sequence bisection (:func:`_mass_spectrum`);
S's eigenvalues, rank and the consistency of the KKT right-hand sides from the SVD of the scaled constraint block
``Jc U^-1`` that the KKT solve itself uses (:func:`_spectrum`, :func:`_constraint_conditioning`); the powers with a
correctly rounded sum (:func:`_power`).
"""

from __future__ import annotations

import contextlib
import ctypes
import functools
import hashlib
import importlib.util
import marshal
import math
import os
import re
import shutil
import subprocess
import tempfile
import types
import warnings
from pathlib import Path
from typing import Callable, Iterator, NamedTuple, Sequence

try:
    import fcntl
except ImportError:                       # not POSIX: entries are not locked while derived (:func:`_deriving`)
    fcntl = None

import numpy as np
import scipy.linalg
import symengine as sp

from cases.constraints import KnifeEdge, PointOnCircle, PointOnLine, PointsCoincide, PointVelocity
from cases.loads import ExternalWrench, PointSpring
from cases.model import JOINT_DOF, Model
from cases.world import label_of, shape_digest, world_data
from formalisms.interface import (CONSTRAINT_RCOND, DEGENERATE_ROW, Chart, Formalism, Linearization, ModelNotSupported,
                                  Split, SplitBatch, cache_dir, chart_vectors, check_batch, check_state, state_space,
                                  used_cache_file, write_cache_file)

ZERO, ONE, HALF = sp.Integer(0), sp.Integer(1), sp.Rational(1, 2)
JOINT_CHART = "identity"  # the cache key of the joint chart q = p
_NO_CHARTS = ("Euler–Lagrange: a model with spherical or free joints is derived in a chart q = psi(p) only when psi "
              "returns its whole q ({nq} entries, every quaternion block unit for every p, e.g. the zyx chart); "
              "{reason}")


def _exact(x: float) -> sp.Expr:
    """A float as a symbolic number; exact zeros and ones stay integers so products with them vanish."""
    return sp.Integer(int(x)) if x in (0.0, 1.0, -1.0) else sp.RealDouble(float(x))


def _matrix(arr) -> sp.DenseMatrix:
    arr = np.asarray(arr, dtype=float)
    return sp.DenseMatrix(arr.shape[0], arr.shape[1] if arr.ndim == 2 else 1,
                          [_exact(v) for v in arr.reshape(-1)])


def _skew(a: sp.DenseMatrix) -> sp.DenseMatrix:
    return sp.DenseMatrix([[0, -a[2], a[1]], [a[2], 0, -a[0]], [-a[1], a[0], 0]])


def _world_values(model: Model) -> np.ndarray:
    """The numbers of the model's world data (``cases.world.world_data``), flat, in order: what the generated code reads
    after the coordinates."""
    return np.concatenate([np.ravel(np.asarray(a, dtype=float)) for _, a in world_data(model)])


class _World:
    """The world data (``cases.world.world_data``) as symbols of the derivation (parameters: never differentiated), one
    per number, named ``world0 ..`` in that order; :meth:`matrix` gives a datum's symbols in its shape (a vector as a
    column), :meth:`of` a constraint's or a load's."""

    def __init__(self, model: Model):
        self.model = model
        self.symbols: list = []
        self._data: dict = {}
        for label, value in world_data(model):
            shape = np.shape(value)
            flat = list(sp.symbols(f"world{len(self.symbols)}:{len(self.symbols) + int(np.prod(shape))}"))
            self.symbols += flat
            self._data[label] = sp.DenseMatrix(shape[0], shape[1] if len(shape) == 2 else 1, flat)

    def matrix(self, label: str) -> sp.DenseMatrix:
        return self._data[label]

    def of(self, declaration, field: str) -> sp.DenseMatrix:
        return self._data[label_of(self.model, declaration, field)]


class _Staged:
    """Named intermediate expressions with a memoized chain rule: forward-mode differentiation, symbolically.

    ``coordinates`` are the symbols the derivation differentiates by (the chart's ``p``); ``joint[k]`` is the
    joint coordinate ``q_k`` as a function of them (the coordinate itself in the joint chart, else a named
    intermediate ``psi_k(p)``, set by :meth:`set_joint`). Every pose entry, and every derivative of one, becomes
    a symbol whose definition uses only earlier symbols. ``diff(expr, j)`` is the total derivative of ``expr``
    by ``p_j`` through all of them, so differentiating T twice and M once never expands the kinematic chain
    (which grows exponentially), and the chart's Jacobian ``Dpsi_kj = diff(q_k, j)`` is a named intermediate.
    """

    def __init__(self, coordinates: list[sp.Symbol], rates: Sequence[sp.Symbol] = ()):
        self.coordinates = coordinates
        self.rates = list(rates)
        #: What :meth:`diff` differentiates by: the coordinates (indices ``0 .. n-1``), then the rates
        #: (``n .. 2n-1``), so that ``diff(T, n + i)`` is ``dT/dpd_i``.
        self.variables = list(coordinates) + self.rates
        self.joint: list[sp.Expr] = list(coordinates)
        #: Where body i's revolute or prismatic coordinate is in ``joint``: ``Model.v_index`` (None) when ``joint``
        #: has one entry per velocity, ``Model.q_index`` when it is a whole q of a model with group joints.
        self.joint_index: Sequence[int] | None = None
        self._trig: dict = {}
        self.definitions: dict[sp.Symbol, sp.Expr] = {}
        self._coordinate = {s: k for k, s in enumerate(self.variables)}
        self._depends: dict[sp.Symbol, frozenset[int]] = {}
        self._derivative: dict[tuple[sp.Symbol, int], sp.Expr] = {}
        #: ``sin(e)`` -> ``(cos(e), e)``, ``cos(e)`` -> ``(-sin(e), e)``: the seeded symbols' time derivatives are
        #: ``factor * de/dt`` (:meth:`_rate_of`), one product each whatever the number of coordinates e depends on.
        self._seeded: dict[sp.Symbol, tuple[sp.Expr, sp.Expr]] = {}
        self._rate: dict[sp.Symbol, sp.Expr] = {}
        self._count = 0
        #: The model's world data as parameters (:class:`_World`), set by :func:`derivation`.
        self.world: _World | None = None

    def name(self, expr) -> sp.Expr:
        """A symbol standing for ``expr`` (numbers and symbols are returned as they are)."""
        expr = sp.sympify(expr)
        if expr.is_Number or expr.is_Symbol:
            return expr
        s = sp.Symbol(f"w{self._count}")
        self._count += 1
        self.definitions[s] = expr
        self._depends[s] = self.dependencies(expr)
        return s

    def dependencies(self, expr) -> frozenset[int]:
        """The indices of the coordinates ``expr`` depends on, through the intermediates."""
        return frozenset().union(*(
            self._depends.get(f, frozenset({self._coordinate[f]}) if f in self._coordinate else frozenset())
            for f in sp.sympify(expr).free_symbols))

    def set_joint(self, psi: Sequence) -> None:
        """The joint coordinates ``q_k = psi_k(p)``, each named (a coordinate or a number stays itself)."""
        self.joint = [self.name(e) for e in psi]

    def angle(self, k: int) -> tuple[sp.Symbol, sp.Symbol]:
        """Symbols for ``sin(q_k)`` and ``cos(q_k)`` with their derivatives seeded: ``d sin(q_k)/dp_j =
        cos(q_k) dq_k/dp_j`` and ``d cos(q_k)/dp_j = -sin(q_k) dq_k/dp_j`` (in the joint chart ``dq_k/dp_k = 1``:
        ``cos(q_k)`` and ``-sin(q_k)``)."""
        q = self.joint[k]
        s, c = self.name(sp.sin(q)), self.name(sp.cos(q))
        for j in sorted(self.dependencies(q)):
            dq = self.diff(q, j)
            self._derivative[(s, j)], self._derivative[(c, j)] = c * dq, -s * dq
        self._seeded.update({s: (c, q), c: (-s, q)})
        return s, c

    def trig(self, e) -> tuple[sp.Expr, sp.Expr]:
        """Symbols for ``sin(e)`` and ``cos(e)`` of any expression in the coordinates (a chart's half angles), once
        per ``e``, with their derivatives seeded as in :meth:`angle`: ``d sin(e)/dp_j = cos(e) de/dp_j``."""
        e = sp.sympify(e)
        if e not in self._trig:
            s, c = self.name(sp.sin(e)), self.name(sp.cos(e))
            for j in sorted(self.dependencies(e)):
                de = self.diff(e, j)
                self._derivative[(s, j)], self._derivative[(c, j)] = c * de, -s * de
            self._seeded.update({s: (c, e), c: (-s, e)})
            self._trig[e] = (s, c)
        return self._trig[e]

    def sin(self, e) -> sp.Expr:
        return self.trig(e)[0]

    def cos(self, e) -> sp.Expr:
        return self.trig(e)[1]

    def diff(self, expr: sp.Expr, k: int) -> sp.Expr:
        """Total derivative ``d expr / d p_k`` (``d expr / d pd_(k-n)`` for ``k >= n``), chain rule at symbols."""
        pk = self.variables[k]
        return self._forward(expr, lambda e: ONE if e == pk else (
            self._derivative_of(e, k) if k in self._depends.get(e, ()) else ZERO), f"by {pk}")

    def _forward(self, expr, of_symbol: Callable, what: str) -> sp.Expr:
        """Forward-mode differentiation of ``expr`` in one memoized pass: sum and product rules, the chain rule through
        ``sin`` and ``cos`` (only in a chart's psi: those of a joint coordinate are seeded symbols), numeric powers,
        and ``of_symbol(s)`` the derivative of a symbol (:meth:`diff`, :meth:`dt`)."""
        memo: dict = {}

        def d(e):
            if e in memo:
                return memo[e]
            if e.is_Number:
                r = ZERO
            elif e.is_Symbol:
                r = of_symbol(e)
            elif e.is_Add:
                r = sp.Add(*[d(a) for a in e.args])
            elif e.is_Mul:
                a = e.args
                r = sp.Add(*[sp.Mul(*a[:i], da, *a[i + 1:]) for i in range(len(a)) if (da := d(a[i])) != 0])
            elif e.is_Pow and e.exp.is_Number:
                r = e.exp * e.base ** (e.exp - 1) * d(e.base)
            elif isinstance(e, sp.sin):
                r = sp.cos(e.args[0]) * d(e.args[0])
            elif isinstance(e, sp.cos):
                r = -sp.sin(e.args[0]) * d(e.args[0])
            else:
                raise TypeError(f"Euler–Lagrange: cannot differentiate {e!r} {what} (a chart's psi may use +, -, *, /, "
                                "integer powers, sin and cos)")
            memo[e] = r
            return r

        return d(sp.sympify(expr))

    def _derivative_of(self, s: sp.Symbol, k: int) -> sp.Expr:
        if (s, k) not in self._derivative:
            self._derivative[(s, k)] = self.name(self.diff(self.definitions[s], k))
        return self._derivative[(s, k)]

    def dt(self, expr) -> sp.Expr:
        """Time derivative along the motion at ``pdd = 0``: ``sum_j d(expr)/dp_j pd_j``, by the sum, product and chain
        rules through the intermediates (:meth:`_rate_of`), so it costs the size of the definitions, not n
        derivatives of each. A rate has time derivative 0 (``pdd = 0``), a parameter (a symbol that is neither a
        coordinate nor an intermediate depending on one) too."""
        return self._forward(expr, self._rate_of, "in time")

    def _rate_of(self, s: sp.Symbol) -> sp.Expr:
        """``d s / dt`` at ``pdd = 0`` of one symbol, named: ``pd_k`` for the coordinate ``p_k``; for ``sin`` and
        ``cos`` of a joint coordinate or a chart's angle ``e`` the factor of their seeded derivatives times
        ``de/dt``; for any other intermediate the time derivative of its definition (:meth:`dt`)."""
        k = self._coordinate.get(s)
        if k is not None:
            return self.rates[k] if k < len(self.coordinates) else ZERO
        depends = [j for j in self._depends.get(s, ()) if j < len(self.coordinates)]
        if not depends:
            return ZERO
        if s not in self._rate:
            if s in self._seeded:
                factor, argument = self._seeded[s]
                rate = factor * self.dt(argument)
            else:
                rate = self.dt(self.definitions[s])
            self._rate[s] = self.name(rate)
        return self._rate[s]

    def needed(self, exprs) -> list[tuple[sp.Symbol, sp.Expr]]:
        """The definitions the expressions use, transitively, in an order that evaluates (creation order)."""
        seen: set = set()
        stack = [f for e in exprs for f in e.free_symbols if f in self.definitions]
        while stack:
            s = stack.pop()
            if s not in seen:
                seen.add(s)
                stack.extend(f for f in self.definitions[s].free_symbols if f in self.definitions)
        return [(s, e) for s, e in self.definitions.items() if s in seen]


def _joint_rotation(axis: sp.DenseMatrix, s: sp.Symbol, c: sp.Symbol) -> sp.DenseMatrix:
    """Rodrigues' formula ``I + sin(q) [a]x + (1 - cos(q)) [a]x^2`` for a unit axis a."""
    K = _skew(axis)
    return sp.eye(3) + s * K + (1 - c) * (K * K)


def _poses(model: Model, st: _Staged, local: dict | None = None) -> list[tuple[sp.DenseMatrix, sp.DenseMatrix]]:
    """World rotation and origin of every body frame as staged functions of p (module docstring, step 1); a body
    on a spherical or free joint moves by its motion ``local[i] = (R_m, p_m)`` (:func:`_local_motions` in the local
    chart, :func:`_chart_motions` in a chart ``q = psi(p)``), a revolute or prismatic one by its coordinate
    (``joint[v_index[i]]``, or ``joint[q_index[i]]`` when ``joint`` is a whole q: ``_Staged.joint_index``; both are
    ``i`` without group joints)."""
    local = local or {}
    index = model.v_index if st.joint_index is None else st.joint_index
    poses: list = [None] * len(model.bodies)
    for i in model.topological_order:
        body = model.bodies[i]
        parent = model.parent_index[i]
        if parent < 0:       # a root body: its placement in the world is world data (module docstring)
            R_joint, p_joint = st.world.matrix(f"root{i}.rotation"), st.world.matrix(f"root{i}.translation")
        else:
            R_par, p_par = poses[parent]
            R_joint = R_par * _matrix(body.rotation)
            p_joint = p_par + R_par * _matrix(body.translation)
        axis = _matrix(body.axis)
        if i in local:
            R_m, p_m = local[i]
            R, p = R_joint * R_m, p_joint + R_joint * p_m
        elif body.joint == "revolute":
            R, p = R_joint * _joint_rotation(axis, *st.angle(index[i])), p_joint
        else:
            R, p = R_joint, p_joint + R_joint * axis * st.joint[index[i]]
        poses[i] = (R.applyfunc(st.name), p.applyfunc(st.name))
    return poses


# ----------------------------------------------------------------------------------------------------------
# Spherical and free joints: local exponential coordinates around the state (module docstring, "Group joints")
# ----------------------------------------------------------------------------------------------------------

#: The truncation order of the exponential series in the local chart: 2 is exact for everything the Euler–Lagrange
#: equations evaluate at ``xi = 0`` and 3 for their first derivatives in xi (the linearization), so 3, and one
#: derivation serves both (module docstring, "Group joints"); ``tests/backends/test_group_euler_lagrange.py``
#: compares orders 2, 3 and 4, and shows that order 1 is wrong.
EXP_ORDER = 3
#: The cache key of the chart of the group joints (part of what is derived, so part of :func:`cache_key`).
GROUP_CHART = "local-exponential:q(+)xi=q*exp(xi) on the right:twist(linear,angular):order{order}"
#: The local charts of a base-velocity representation (module docstring, "Velocity representations"): the exponential
#: on the LEFT, ``X = exp(xi) X0`` (world: on SE(3); mixed: position plus xi, rotation by SO(3)'s exp on the left).
GROUP_CHART_LEFT = {
    "world": "local-exponential:q(+)xi=exp(xi)*q on the left:spatial twist(linear,angular):order{order}",
    "mixed": "local-exponential:p=p0+xi_lin,R=exp(xi_ang)*R0 on the left:(pdot,omega_s):order{order}"}
#: The same for a chart ``q = psi(p)`` of a model with group joints (with the chart's own key).
GROUP_IN_CHART = "group joints through q=psi(p):R(quat)=I+2w[u]x+2[u]x^2,free position from q"


def _quaternion_rotation(st: _Staged, quat: Sequence) -> sp.DenseMatrix:
    """``R(quat) = I + 2 w [u]x + 2 [u]x^2`` of a unit quaternion ``(x, y, z, w) = (u, w)`` (cases.model), its
    entries named; the quaternion's entries are parameters of the derivation, not coordinates."""
    K = _skew(sp.DenseMatrix(list(quat[:3])))
    return (sp.eye(3) + 2 * quat[3] * K + 2 * (K * K)).applyfunc(st.name)


def _exp_series(X: sp.DenseMatrix, order: int) -> sp.DenseMatrix:
    """The matrix exponential's series truncated after ``X^order / order!``: ``sum_{k <= order} X^k / k!``."""
    term, total = sp.eye(X.rows), sp.eye(X.rows)
    for k in range(1, order + 1):
        term = (term * X).applyfunc(lambda e: sp.expand(e / k))
        total = total + term
    return total


def _local_coordinates(model: Model) -> tuple[list, list, list]:
    """The symbols of the local chart (module docstring, "Group joints"): ``coordinates`` (nv, in v's order: the
    joint value ``q{q_index}`` of a revolute or prismatic body, ``xi{v_index + a}`` for a group joint's local
    coordinates), ``configuration`` (nq: ``q0 ..``, the state's q; a group joint's entries are parameters) and
    ``local`` (the xi, set to 0 in the generated code)."""
    configuration = list(sp.symbols(f"q0:{model.nq}"))
    coordinates: list = [None] * model.nv
    local = []
    for i, body in enumerate(model.bodies):
        iq, iv = model.q_index[i], model.v_index[i]
        if i in model.group_joints:
            size = 3 if body.joint == "spherical" else 6
            xi = list(sp.symbols(f"xi{iv}:{iv + size}"))
            coordinates[iv:iv + size] = xi
            local += xi
        else:
            coordinates[iv] = configuration[iq]
    return coordinates, configuration, local


def _local_motions(model: Model, st: _Staged, configuration: list, order: int, side: str | None = None) -> dict:
    """``i -> (R_m, p_m)``, the motion of each group joint as a function of its local coordinates xi, with the
    state's orientation (and position) as parameters. ``side`` None (the joint chart, exponential on the right):
    spherical ``R_m = R0 exp([xi]x)``, ``p_m = 0``; free ``(R_m, p_m) = (R0, p0) exp6(xi)`` on SE(3) with
    ``xi = (rho, phi)`` (linear, angular), the 4x4 series of ``Xi = [[phi]x, rho; 0, 0]``: rotation
    ``sum [phi]x^k / k!``, translation ``sum [phi]x^(k-1) rho / k!``. ``side`` ``"world"`` or ``"mixed"`` (a velocity
    representation, exponential on the LEFT; module docstring, "Velocity representations"): spherical
    ``R_m = exp([xi]x) R0`` in both; free world ``(R_m, p_m) = exp6(xi) (R0, p0) = (E_R R0, E_R p0 + E_p)``, free
    mixed ``R_m = exp([phi]x) R0``, ``p_m = p0 + rho``. Every series truncated at ``order`` (:data:`EXP_ORDER`)."""
    out = {}
    for i in model.group_joints:
        iq, iv = model.q_index[i], model.v_index[i]
        if model.bodies[i].joint == "spherical":
            R0 = _quaternion_rotation(st, configuration[iq:iq + 4])
            E = _exp_series(_skew(sp.DenseMatrix(st.coordinates[iv:iv + 3])), order).applyfunc(st.name)
            out[i] = (R0 * E if side is None else E * R0, sp.zeros(3, 1))
            continue
        p0, R0 = sp.DenseMatrix(configuration[iq:iq + 3]), _quaternion_rotation(st, configuration[iq + 3:iq + 7])
        rho, phi = st.coordinates[iv:iv + 3], st.coordinates[iv + 3:iv + 6]
        if side == "mixed":
            E = _exp_series(_skew(sp.DenseMatrix(phi)), order).applyfunc(st.name)
            out[i] = (E * R0, p0 + sp.DenseMatrix(rho))
            continue
        Xi = sp.zeros(4, 4)
        Xi[:3, :3] = _skew(sp.DenseMatrix(phi))
        Xi[:3, 3] = sp.DenseMatrix(rho)
        E = _exp_series(Xi, order).applyfunc(st.name)
        if side is None:
            out[i] = (R0 * E[:3, :3], p0 + R0 * E[:3, 3])
        else:
            out[i] = (E[:3, :3] * R0, E[:3, :3] * p0 + E[:3, 3])
    return out


def _chart_motions(model: Model, st: _Staged) -> dict:
    """``i -> (R_m, p_m)``, the motion of each group joint in a chart whose ``psi`` returns the whole q (module
    docstring, "Group joints in a chart"): ``R_m = R(quat(p)) = I + 2 w [u]x + 2 [u]x^2`` of the quaternion block
    of ``q = psi(p)`` (named intermediates of p, so their derivatives go through the chain rule), ``p_m = 0`` for a
    spherical joint and the position block of q for a free one (``X_joint = (R(quat), p)``, cases.model)."""
    out = {}
    for i in model.group_joints:
        iq = model.q_index[i]
        if model.bodies[i].joint == "spherical":
            out[i] = (_quaternion_rotation(st, st.joint[iq:iq + 4]), sp.zeros(3, 1))
        else:
            out[i] = (_quaternion_rotation(st, st.joint[iq + 3:iq + 7]), sp.DenseMatrix(st.joint[iq:iq + 3]))
    return out


def _com(R: sp.DenseMatrix, p: sp.DenseMatrix, com) -> sp.DenseMatrix:  # noqa: N803
    """World position of a body's COM ``p + R com`` (``com`` in the body frame)."""
    return p + R * _matrix(com)


def _pseudo_inertia(inertia: np.ndarray) -> np.ndarray:
    """``J = 1/2 tr(I) 1 - I``, so that ``1/2 w^T I w = 1/2 tr(R_dot J R_dot^T)`` (module docstring, step 2)."""
    return 0.5 * np.trace(inertia) * np.eye(3) - inertia


def _energies(model: Model, st: _Staged, poses, motions: dict | None = None) -> tuple[sp.Expr, sp.Expr]:
    """Kinetic energy T(p, pd) and potential energy V(p) of the whole tree (module docstring, step 2); the body
    velocities ``c_dot`` and ``R_dot`` are the staged time derivatives of the poses (:meth:`_Staged.dt`). The joints'
    rotors add their own energy (:func:`_rotor_energy`)."""
    T, V = ZERO, ZERO
    gravity = st.world.matrix("gravity")
    for body, (R, p) in zip(model.bodies, poses):
        c = _com(R, p, body.com).applyfunc(st.name)
        c_dot = c.applyfunc(st.dt)
        T += HALF * _exact(body.mass) * (c_dot.T * c_dot)[0]
        if np.any(body.inertia):
            J = _matrix(_pseudo_inertia(body.inertia))
            R_dot = R.applyfunc(st.dt)
            RJR = R_dot * J * R_dot.T
            T += HALF * (RJR[0, 0] + RJR[1, 1] + RJR[2, 2])
        V -= _exact(body.mass) * (gravity.T * c)[0]
    return T + _rotor_energy(model, st, motions or {}), V


def _rotor_energy(model: Model, st: _Staged, motions: dict) -> sp.Expr:
    """The kinetic energy of the joints' rotors (``Body.armature`` a, module docstring, step 2): ``1/2 a qd_i^2`` of a
    revolute or prismatic joint, ``qd_i`` the time derivative of its coordinate (in a chart, of ``psi_i(p)``); for a
    spherical or free joint, ``1/2 a |v_i|^2`` of its whole velocity block, formed from the joint's own motion
    ``(R_m, p_m)`` (:func:`_local_motions`, :func:`_chart_motions`) as ``1/2 a (1/2 tr(R_m_dot R_m_dot^T) +
    |p_m_dot|^2)``: ``R_m_dot = R_m [w]x`` gives ``tr = 2 |w|^2`` and ``|R_m^T p_m_dot| = |p_m_dot|``, so it is the same
    energy in every chart and representation. With it in the Lagrangian, M gains ``a`` on the joint's diagonal and C qd
    and g nothing (the energy is a constant quadratic form in v)."""
    T = ZERO
    index = model.v_index if st.joint_index is None else st.joint_index
    for i, body in enumerate(model.bodies):
        if not body.armature:
            continue
        a = _exact(body.armature)
        if i in motions:
            R_m, p_m = motions[i]
            R_dot, p_dot = R_m.applyfunc(st.dt), p_m.applyfunc(st.dt)
            square = HALF * sum((R_dot[r, k] ** 2 for r in range(3) for k in range(3)), ZERO)
            square += sum((p_dot[r] ** 2 for r in range(3)), ZERO)
            T += HALF * a * st.name(square)
        else:
            rate = st.dt(st.joint[index[i]])
            T += HALF * a * rate * rate
    return T


def _point(model: Model, st: _Staged, poses, body: str, offset) -> sp.DenseMatrix:
    """World position ``p(body, offset) = p_i + R_i offset`` of a body point (cases.constraints), named."""
    R, p = poses[model.body_index(body)]
    return (p + R * _matrix(offset)).applyfunc(st.name)


def _constraint_rows(model: Model, st: _Staged, poses, declarations=None) -> list:
    """``phi(p)``, the rows of every (holonomic) declaration in order (``declarations``, default the model's), exactly
    as :mod:`cases.constraints` fixes them."""
    rows: list = []
    for c in (model.constraints if declarations is None else declarations):
        world = functools.partial(st.world.of, c)
        if isinstance(c, PointOnCircle):
            d = world("plane") * (_point(model, st, poses, c.body, c.offset) - world("center"))
            rows.append((d.T * d)[0] - _exact(c.radius**2))
        elif isinstance(c, PointsCoincide):
            b = world("offset_b") if c.body_b is None else _point(model, st, poses, c.body_b, c.offset_b)
            rows.extend(world("directions") * (_point(model, st, poses, c.body_a, c.offset_a) - b))
        elif isinstance(c, PointOnLine):
            rows.extend(world("normals") * (_point(model, st, poses, c.body, c.offset) - world("origin")))
        else:  # JointCoupling: sum_j c_j q_j - offset, with q = psi(p) (revolute and prismatic joints only)
            index = model.v_index if st.joint_index is None else st.joint_index
            rows.append(sp.Add(*[_exact(a) * st.joint[index[model.body_index(j)]]
                                 for j, a in zip(c.joints, c.coefficients)]) - _exact(c.offset))
    return rows


def _angular_velocity(st: _Staged, R: sp.DenseMatrix) -> sp.DenseMatrix:
    """The world angular velocity ``w`` of a body of world rotation ``R``: ``[w]x = Rdot R^T`` (staged ``dt``)."""
    W = R.applyfunc(st.dt) * R.T
    return sp.DenseMatrix([st.name(W[2, 1]), st.name(W[0, 2]), st.name(W[1, 0])])


def _pfaffian_rows(model: Model, st: _Staged, poses, c) -> list:
    """The velocity rows ``A(p) pd`` of a Pfaffian declaration exactly as :mod:`cases.constraints` fixes them, from the
    staged time derivatives of this backend's own poses: a point's velocity ``dt(p)``, a body's angular velocity from
    ``Rdot R^T``. For a rolling contact the material point at the contact ``p_c = c - r u`` moves with ``dt(c) + w x
    (p_c - c)``; with ``lateral=False`` only ``t . v`` along the rolling direction ``t = (a x n) / |a x n|``. ``Jc`` and
    ``Jcdot pd`` then follow by differentiating the rows (:func:`_constraints`): the turning of t is in ``dt``."""
    R, _ = poses[model.body_index(c.body)]
    if isinstance(c, PointVelocity):
        return list(st.world.of(c, "directions") * _point(model, st, poses, c.body, c.offset).applyfunc(st.dt))
    if isinstance(c, KnifeEdge):
        e = R * _matrix(c.direction)
        return [(e.T * _point(model, st, poses, c.body, c.offset).applyfunc(st.dt))[0]]
    # RollingContact
    plane = st.world.of(c, "plane")
    n = (_skew(plane[0, :].T) * plane[1, :].T).applyfunc(st.name)
    a = (R * _matrix(c.axis)).applyfunc(st.name)
    raw = (n - (n.T * a)[0] * a).applyfunc(st.name)
    length = st.name(sp.sqrt((raw.T * raw)[0]))
    e = (raw * (-_exact(c.radius) / length)).applyfunc(st.name)
    w = _angular_velocity(st, R)
    velocity = _point(model, st, poses, c.body, c.center).applyfunc(st.dt) + _skew(w) * e
    if not c.lateral:       # the rolling direction t = (a x n) / |a x n| only; dt turns t with the axle (tdot . v)
        b = (_skew(a) * n).applyfunc(st.name)
        t = (b * (ONE / st.name(sp.sqrt((b.T * b)[0])))).applyfunc(st.name)
        return [(t.T * velocity)[0]]
    return list(plane * velocity)


def _constraints(model: Model, st: _Staged, poses) -> tuple[list, list, list]:
    """``phi``, ``Jc = dphi/dp`` (rows) and ``Jcdot pd = d^2 phi / dt^2`` at ``pdd = 0`` (eqs. 13, 16; module
    docstring, step 4), the last as the staged second time derivative of each row (:meth:`_Staged.dt`). A Pfaffian
    declaration's rows are velocity rows ``a = A(p) pd`` (:func:`_pfaffian_rows`): ``phi = 0``, ``A = da/dpd`` and
    ``Adot pd = dt(a)`` (the rates held: ``pdd = 0``)."""
    n = model.n
    phi_rows = iter([st.name(e) for e in _constraint_rows(model, st, poses,
                                                          [c for c in model.constraints if c.holonomic])])
    rows = []                     # (phi, None) for a holonomic row, (0, a) for a Pfaffian one, in model order
    for c in model.constraints:
        rows += ([(next(phi_rows), None) for _ in range(c.size)] if c.holonomic
                 else [(ZERO, st.name(a)) for a in _pfaffian_rows(model, st, poses, c)])
    phi = [e for e, _ in rows]
    Jc = [[st.name(st.diff(e, j) if a is None else st.diff(a, n + j)) for j in range(n)] for e, a in rows]
    bias = [st.dt(st.dt(e)) if a is None else st.dt(a) for e, a in rows]
    return phi, Jc, bias


# ----------------------------------------------------------------------------------------------------------
# Charts
# ----------------------------------------------------------------------------------------------------------

def _psi(model: Model, chart: Chart, p: list, st: _Staged | None = None) -> list:
    """``chart.psi`` evaluated on SymEngine symbols (the chart is written against generic scalar operations); with
    ``st`` its ``sin`` and ``cos`` are the staged, seeded ones (:meth:`_Staged.trig`), whose symbols are
    intermediates of p. It must return the model's ``nq`` joint coordinates (``n`` without group joints)."""
    if not callable(getattr(chart, "psi", None)):
        raise TypeError(f"Euler–Lagrange: {chart!r} is not a chart (no psi(p, sin, cos))")
    q = list(chart.psi(list(p), sp.sin, sp.cos) if st is None else chart.psi(list(p), st.sin, st.cos))
    name = getattr(chart, "name", "?")
    if len(q) != model.nq:
        raise ValueError(f"chart '{name}' returns {len(q)} joint coordinates but model '{model.name}' has "
                         f"{model.nq}")
    q = [sp.sympify(e) for e in q]
    stray = set().union(*(e.free_symbols for e in q)) - set(p) - (set() if st is None else set(st.definitions))
    if stray:
        raise ValueError(f"chart '{name}': psi uses symbols {sorted(map(str, stray))} that are not coordinates")
    return q


_JOINT_CHART_MEMO: dict[tuple[int, str], bool] = {}
_GROUP_CHART_MEMO: dict[tuple, str | None] = {}
#: Points of p (as multiples of a fixed pattern) where a chart of a model with group joints must give unit quaternions.
_UNIT_PROBES = (0.0, 0.37, -1.21, 2.9)


def _group_chart_refusal(model: Model, chart: Chart) -> str | None:
    """Why ``chart`` cannot carry a model with spherical or free joints here, or None when it can: its ``psi`` must
    evaluate on ``nv`` coordinates, return the whole q (``nq`` entries) and give every quaternion block unit length
    (to 1e-12, at a few fixed points; then ``R(quat)`` is a rotation, module docstring "Group joints in a chart")."""
    name = getattr(chart, "name", "?")
    p = list(sp.symbols(f"p0:{model.nv}"))
    try:
        q = chart.psi(list(p), sp.sin, sp.cos)
        size = len(q)
    except Exception as exc:  # a chart written for other models (scalar coordinates, the group identity)
        return f"chart '{name}' does not evaluate on {model.nv} coordinates ({type(exc).__name__}: {exc})"
    if size != model.nq:
        return (f"chart '{name}' returns {size} coordinates, not the {model.nq} of q (a joint-coordinate chart of "
                f"the velocities is not a chart of the group)")
    pattern = np.cos(np.arange(model.nv) * 1.7 + 0.3)
    for scale in _UNIT_PROBES:
        q = np.array(chart.psi(list(scale * pattern), math.sin, math.cos), dtype=float)
        for i in model.group_joints:
            start = model.q_index[i] + (3 if model.bodies[i].joint == "free" else 0)
            norm = float(np.linalg.norm(q[start:start + 4]))
            if not abs(norm - 1.0) <= 1e-12:
                return (f"chart '{name}' gives body '{model.bodies[i].name}' a quaternion of norm {norm!r} at "
                        f"p = {(scale * pattern).tolist()}")
    return None


def _representation(model: Model, chart) -> str | None:
    """The base-velocity representation a chart asks for (its ``representation``, read duck-typed: ``"world"`` or
    ``"mixed"``; module docstring, "Velocity representations"), or None for any other chart. Such a chart applies
    only to a model with spherical or free joints (ModelNotSupported otherwise)."""
    side = getattr(chart, "representation", None)
    if side is None:
        return None
    if side not in GROUP_CHART_LEFT:
        raise ModelNotSupported(f"Euler–Lagrange: chart '{getattr(chart, 'name', '?')}' asks for the velocity "
                                f"representation {side!r}; known: {', '.join(GROUP_CHART_LEFT)}")
    if not model.group_joints:
        raise ModelNotSupported(f"Euler–Lagrange: chart '{getattr(chart, 'name', '?')}' is a velocity representation "
                                f"({side}), and model '{model.name}' has no spherical or free joint to represent")
    return side


def _group_chart_text(model: Model, chart, order: int) -> str:
    """The local chart's description (part of the cache key and the source's header): :data:`GROUP_CHART` (right) or,
    for a velocity representation, :data:`GROUP_CHART_LEFT`."""
    side = None if chart is None else _representation(model, chart)
    return (GROUP_CHART if side is None else GROUP_CHART_LEFT[side]).format(order=order)


def chart_key(model: Model, chart: Chart | None) -> str:
    """The cache key of a chart: ``"identity"`` for ``None`` and for a chart whose ``psi`` returns its
    coordinates unchanged (the joint chart, whatever it is called), else ``chart.key``. For a model with spherical
    or free joints any chart is validated first (:func:`_group_chart_refusal`: psi returns the whole q with unit
    quaternions), and one that is not such a chart is :class:`ModelNotSupported`."""
    if chart is None:
        return JOINT_CHART
    if _representation(model, chart) is not None:
        key = getattr(chart, "key", None)
        if not isinstance(key, str) or not key:
            raise TypeError(f"Euler–Lagrange: chart {chart!r} has no key (a stable digest of its definition)")
        return key
    if not callable(getattr(chart, "psi", None)):
        raise TypeError(f"Euler–Lagrange: {chart!r} is not a chart (no psi(p, sin, cos))")
    key = getattr(chart, "key", None)
    if not isinstance(key, str) or not key:
        raise TypeError(f"Euler–Lagrange: chart {chart!r} has no key (a stable digest of its definition)")
    if model.group_joints:  # a chart of the group: psi returns the whole q; never the joint (local) chart
        memo = (model.nq, tuple(b.joint for b in model.bodies), key)
        if memo not in _GROUP_CHART_MEMO:
            _GROUP_CHART_MEMO[memo] = _group_chart_refusal(model, chart)
        if _GROUP_CHART_MEMO[memo] is not None:
            raise ModelNotSupported(_NO_CHARTS.format(nq=model.nq, reason=_GROUP_CHART_MEMO[memo]))
        return key
    memo = (model.n, key)
    if memo not in _JOINT_CHART_MEMO:
        p = list(sp.symbols(f"p0:{model.n}"))
        _JOINT_CHART_MEMO[memo] = _psi(model, chart, p) == p
    return JOINT_CHART if _JOINT_CHART_MEMO[memo] else key


# ----------------------------------------------------------------------------------------------------------
# Derivation
# ----------------------------------------------------------------------------------------------------------

class Derivation(NamedTuple):
    """The symbolic dynamics in one chart. ``M``, ``Cqd`` (= C pd), ``g``, ``T``, ``V`` and the constraint terms
    ``phi`` (k), ``Jc`` (k rows of n) and ``bias`` (= Jcdot pd, k) use the staged intermediates
    (``staged.needed(...)`` lists their definitions in evaluation order); ``coordinates`` and ``rates`` are the
    symbols p, pd (named q, qd in the joint chart); ``joint`` is q = psi(p). With spherical or free joints
    (module docstring, "Group joints") ``coordinates`` are the local chart's (joint values and xi, nv of them),
    ``configuration`` the nq symbols of the state's q (the quaternions and free positions are parameters) and
    ``local`` the xi, which the generated code sets to 0; both are empty without group joints. ``world`` are the
    symbols of the world data (:class:`_World`), read by the generated code after the coordinates."""

    M: sp.DenseMatrix
    Cqd: sp.DenseMatrix
    g: sp.DenseMatrix
    T: sp.Expr
    V: sp.Expr
    phi: list
    Jc: list
    bias: list
    coordinates: list
    rates: list
    joint: list
    staged: _Staged
    configuration: tuple = ()
    local: tuple = ()
    Qext: tuple = ()
    world: tuple = ()


def _external_forces(model: Model, st: _Staged, poses) -> list:
    """``Q`` (n expressions): the generalized force of the model's external loads by virtual work (module docstring,
    step 5), each entry named."""
    n = model.n
    Q = [ZERO] * n
    for load in model.loads:
        R, _ = poses[model.body_index(load.body)]
        x = _point(model, st, poses, load.body, load.offset)
        if isinstance(load, PointSpring):
            d = x - st.world.of(load, "anchor")
            squared = st.name((d.T * d)[0])
            V = (HALF * _exact(load.stiffness) * (st.name(sp.sqrt(squared)) - _exact(load.rest_length)) ** 2
                 if load.rest_length else HALF * _exact(load.stiffness) * squared)
            Q = [Q[j] - st.diff(V, j) for j in range(n)]
            continue
        world = (lambda f: st.world.of(load, f)) if load.frame == "world" else \
            (lambda f, R=R: R * _matrix(getattr(load, f)))
        f = world("force")
        Q = [Q[j] + (f.T * x.applyfunc(lambda e, j=j: st.diff(e, j)))[0] for j in range(n)]
        if isinstance(load, ExternalWrench):
            m = world("moment")
            for j in range(n):
                S = R.applyfunc(lambda e, j=j: st.diff(e, j)) * R.T         # [dR/dp_j R^T]x: the turn rate per p_j
                Q[j] = Q[j] + m[0] * S[2, 1] + m[1] * S[0, 2] + m[2] * S[1, 0]
    return [st.name(e) for e in Q]


def _velocity_product(st: _Staged, T: sp.Expr, momentum: sp.Expr, i: int) -> sp.Expr:
    """``(C pd)_i = d/dt (dT/dpd_i) - dT/dp_i`` at ``pdd = 0``: Lagrange's equation (lagrangian chapter, "Euler–Lagrange
    turns energy into motion") with the ``M pdd`` part of ``d/dt (dT/dpd)`` left out; ``momentum`` is ``dT/dpd_i``."""
    return st.dt(momentum) - st.diff(T, i)


def derivation(model: Model, chart: Chart | None = None, order: int | None = None) -> Derivation:
    """Symbolic ``M``, ``C pd``, ``g`` (article 4.7.1, eqs. 6–8), the energies T, V and the constraint terms
    ``phi``, ``Jc``, ``Jcdot pd`` (article 5.7, eq. 13) in the chart ``q = psi(p)`` (article 6.4.6: the Lagrangian
    and phi with q = psi(p) substituted, then the same steps); ``chart=None`` (or an identity chart) is the joint
    chart, derived with the coordinates themselves as q (module docstring). A model with spherical or free joints
    is derived in the local exponential chart around the state (module docstring, "Group joints"; ``order`` is the
    truncation of its exponential series, :data:`EXP_ORDER` by default), or in a chart whose ``psi`` returns the
    whole q (the zyx chart; module docstring, "Group joints in a chart": the poses ``R(quat(psi(p)))``), any other
    chart being :class:`ModelNotSupported`."""
    n = model.n
    order = EXP_ORDER if order is None else order
    joint_chart = chart_key(model, chart) == JOINT_CHART
    side = _representation(model, chart)
    letter = "q" if joint_chart or side else "p"
    configuration, local = [], []
    if model.group_joints and (joint_chart or side):
        x, configuration, local = _local_coordinates(model)
    else:
        x = list(sp.symbols(f"{letter}0:{n}"))
    xd = list(sp.symbols(f"{letter}d0:{n}"))
    st = _Staged(x, xd)
    st.world = _World(model)
    motions = None
    if side:  # a velocity representation: the local chart with the exponential on the left
        motions = _local_motions(model, st, configuration, order, side)
    elif model.group_joints and not joint_chart:  # psi(p) is the whole q, its sin and cos staged (seeded)
        st.set_joint(_psi(model, chart, x, st))
        st.joint_index = model.q_index
        motions = _chart_motions(model, st)
    elif not joint_chart:
        st.set_joint(_psi(model, chart, x))
    elif local:
        motions = _local_motions(model, st, configuration, order)
    poses = _poses(model, st, motions)
    T, V = _energies(model, st, poses, motions)
    momenta = [st.diff(T, n + i) for i in range(n)]
    M = sp.zeros(n, n)
    for i in range(n):
        depends = st.dependencies(momenta[i])
        for j in range(i, n):
            M[i, j] = M[j, i] = st.diff(momenta[i], n + j) if n + j in depends else ZERO
    Cqd = sp.DenseMatrix([_velocity_product(st, T, momenta[i], i) for i in range(n)])
    g = sp.DenseMatrix([st.diff(V, i) for i in range(n)])
    Qext = _external_forces(model, st, poses) if model.loads else []
    if Qext:                                              # velocity-independent: with gravity (module doc, step 5)
        g = sp.DenseMatrix([g[i] - Qext[i] for i in range(n)])
    return Derivation(M, Cqd, g, T, V, *_constraints(model, st, poses), x, xd, list(st.joint), st,
                      tuple(configuration), tuple(local), tuple(Qext), tuple(st.world.symbols))


def derive(model: Model, chart: Chart | None = None):
    """``(M, Cqd, g, coordinates, rates, staged)`` of :func:`derivation` (the tuple this module always returned)."""
    d = derivation(model, chart)
    return d.M, d.Cqd, d.g, d.coordinates, d.rates, d.staged


def _is_atom(e) -> bool:
    return e.is_Symbol or e.is_Number


class _Python:
    """Python syntax for :class:`_Source`: floats print with ``repr`` so they round-trip exactly, integers as
    integers (Python's ``int * float`` is the float product, ``x**k`` C's ``pow``)."""

    longest = None  # a statement's length is not bounded
    prefix = ""     # of the names of sin, cos and sqrt

    @staticmethod
    def number(e) -> str:
        return str(int(e)) if e.is_Integer else repr(float(e))

    @staticmethod
    def pow(base: str, exponent: str) -> str:
        return f"({base}**{exponent})"


#: The longest statement of the generated C, in characters (about an operation per 10): gcc's time on one expression
#: grows faster than its size (tiago's sums of some 3,000 terms: 20 s each at -O1), so :class:`_Source` cuts a longer
#: sum or product into partial ones, computed in the same order.
C_LONGEST = 1000


class _C:
    """C syntax for :class:`_Source`, on pairs of states (:func:`_c`: a value is a ``vec`` of two doubles, one state
    per lane, and a number stands for itself in both): every number a double literal (``2.0``, ``1e-05``: ``repr`` of
    the float, which round-trips and always has a ``.`` or an exponent), so no integer arithmetic (division) happens
    anywhere; ``vsin``, ``vcos``, ``vsqrt``, ``vpow``: the C library's functions lane by lane."""

    longest = C_LONGEST
    prefix = "v"

    @staticmethod
    def number(e) -> str:
        value = float(e)
        if not math.isfinite(value):
            raise ValueError(f"Euler–Lagrange codegen: the number {e!r} has no C literal")
        return repr(value)

    @staticmethod
    def pow(base: str, exponent: str) -> str:
        return f"vpow({base}, {exponent})"


class _Source:
    """Assignments ``(name, expression text)`` for staged definitions in Python or C (``syntax``: :class:`_Python`,
    :class:`_C`), with common subexpression elimination by tree matching.

    A non-atomic subexpression that occurs more than once anywhere in the expressions (the same node, found by
    hash) is computed once into a temporary ``x<k>``, emitted just before its first use. This is linear in the
    size of the expressions; the staging has already named the chain's structure, so matching subsets of sums
    and products as well (SymEngine's ``cse``) shortens the code little, and is quadratic: 7 s of the 9 s of
    a cold 9-joint arm, and beyond 15 minutes for that arm in a chart that couples all coordinates. Both targets
    write the same operations in the same order (sums and products left to right), so they round alike.
    """

    def __init__(self, exprs, syntax):
        counts: dict = {}
        for e in exprs:
            stack = [e]
            while stack:
                x = stack.pop()
                if _is_atom(x):
                    continue
                seen = x in counts
                counts[x] = counts.get(x, 0) + 1
                if not seen:
                    stack.extend(x.args)
        self.syntax = syntax
        self._shared = {x for x, c in counts.items() if c > 1}
        self._names: dict = {}
        self._count = 0
        self.statements: list[tuple[str, str]] = []

    def ref(self, e) -> str:
        """Source for ``e`` as an operand: a temporary when it is shared (emitted on first use), else inline."""
        if _is_atom(e):
            return str(e) if e.is_Symbol else self.syntax.number(e)
        if e in self._names:
            return self._names[e]
        text = self._inline(e)
        return self._temporary(e, text) if e in self._shared else text

    def name(self, e) -> str:
        """Source for ``e`` as a name (a symbol, number or temporary), never an inline expression."""
        text = self.ref(e)
        return text if _is_atom(e) or e in self._names else self._temporary(e, text)

    def _temporary(self, e, text: str) -> str:
        self._names[e] = name = self._fresh(text)
        return name

    def _fresh(self, text: str) -> str:
        name = f"x{self._count}"
        self._count += 1
        self.statements.append((name, text))
        return name

    def assign(self, symbol, e) -> None:
        """``symbol = e``; a shared ``e`` is thereafter read from ``symbol``."""
        text = self.ref(e) if _is_atom(e) or e in self._names else self._inline(e)
        self.statements.append((str(symbol), text))
        if not _is_atom(e) and e in self._shared:
            self._names.setdefault(e, str(symbol))

    def _inline(self, e) -> str:
        if e.is_Add or e.is_Mul:
            return self._joined(e.args, " + " if e.is_Add else "*")
        if e.is_Pow and e.args[1].is_Number:
            return self._power(e.args[0], e.args[1])
        if isinstance(e, (sp.sin, sp.cos)):
            return f"{self.syntax.prefix}{type(e).__name__}({self.ref(e.args[0])})"
        raise TypeError(f"Euler–Lagrange codegen: unexpected expression {e!r}")

    def _power(self, base, exponent) -> str:
        """``b**e`` in both targets alike, the base named first: ``b*b`` for 2 and ``1.0/b`` for -1 (correctly rounded,
        where the C library's ``pow`` may be off by half an ulp), ``sqrt(b)`` for 1/2, else the library's ``pow``."""
        b = self.name(base)
        if exponent == 2:
            return f"({b}*{b})"
        if exponent == -1:
            return f"(1.0/{b})"
        if exponent == HALF:
            return f"{self.syntax.prefix}sqrt({b})"
        return self.syntax.pow(b, self.syntax.number(exponent))

    def _joined(self, args, separator: str) -> str:
        """``(a0 <separator> a1 <separator> ...)``, evaluated left to right. Where the syntax bounds a statement's
        length (``longest``), the operands so far are computed into a temporary whenever the text would grow past it:
        ``x = (a0 + a1)``, then ``(x + a2 + ...)``, the same operations in the same order."""
        text = ""
        for a in args:
            operand = self.ref(a)
            if text and self.syntax.longest and len(text) + len(operand) > self.syntax.longest:
                text = self._fresh(f"({text})")
            text = f"{text}{separator}{operand}" if text else operand
        return f"({text})"



def _at_origin(definitions: list, outputs: dict, local: Sequence) -> tuple[list, dict]:
    """The definitions and outputs evaluated at ``xi = 0`` (module docstring, "Group joints"), symbolically: each
    definition in order with the local coordinates set to 0 and every earlier definition that became a number or a
    symbol substituted (constant propagation), then only the definitions the outputs still use. Exact: every
    definition is a polynomial in the named intermediates, so this is the value of the derived expressions at 0."""
    value: dict = {s: ZERO for s in local}

    def at(e):
        sub = {f: value[f] for f in e.free_symbols if f in value}
        return e.subs(sub) if sub else e

    kept = {}
    for s, e in definitions:
        e = at(e)
        if _is_atom(e):
            value[s] = e
        else:
            kept[s] = e
    outputs = {label: [at(e) for e in exprs] for label, exprs in outputs.items()}
    used: set = set()
    stack = [f for e in [e for v in outputs.values() for e in v] for f in e.free_symbols if f in kept]
    while stack:
        s = stack.pop()
        if s not in used:
            used.add(s)
            stack.extend(f for f in kept[s].free_symbols if f in kept)
    return [(s, e) for s, e in kept.items() if s in used], outputs


class _Program(NamedTuple):
    """The straight-line program of one derivation, for either target (:func:`_program`): the staged definitions in
    creation order (each reads only earlier ones) and the outputs in the order of :data:`OUTPUTS`."""

    header: str                 # what was derived: model, digest, chart
    arguments: tuple[str, str]  # the argument names: q, qd in the joint chart (and the local one), p, pd in a chart
    inputs: list                # the symbols read from the first argument, in order (nq of them with group joints)
    rates: list                 # the symbols read from the second argument
    definitions: list           # (symbol, expression)
    outputs: dict               # label -> expressions (T: one)


#: The outputs of the generated code, in order: M's upper triangle row by row, C pd, g, the kinetic energy T, then
#: the constraint terms phi, Jc (row by row) and Jcdot pd (empty without constraints), then the external loads'
#: ``Q`` (empty without loads; ``g`` is then ``dV/dp - Q``).
OUTPUTS = ("M_upper", "Cqd", "g", "T", "phi", "Jc", "bias", "Qext")


@functools.lru_cache(maxsize=1)
def _derived(model: Model, order: int) -> Derivation:
    """The joint chart's derivation of a model with group joints, the last one kept: the dynamics' program (at
    ``xi = 0``) and the linearization's (xi as inputs, :func:`_local_program`) are both made from it."""
    return derivation(model, None, order)


def _program(model: Model, chart: Chart | None, order: int, at_origin: bool = True) -> _Program:
    """:func:`derivation`'s outputs and the definitions they use; with spherical or free joints at ``xi = 0``
    (:func:`_at_origin`; ``order`` of the exponential series, module docstring "Group joints"), or with the xi as
    inputs after the state's q (``at_origin`` False: the linearization's :func:`_local_program`)."""
    d = _derived(model, order) if _needs_local_program(model, chart) else derivation(model, chart, order)
    n = model.n
    outputs = {"M_upper": [d.M[i, j] for i in range(n) for j in range(i, n)], "Cqd": list(d.Cqd), "g": list(d.g),
               "T": [d.T], "phi": d.phi, "Jc": [e for row in d.Jc for e in row], "bias": d.bias}
    if d.Qext:                       # only with loads: a model without them keeps its code as it was
        outputs["Qext"] = list(d.Qext)
    definitions = d.staged.needed([e for v in outputs.values() for e in v])
    if d.local and at_origin:
        definitions, outputs = _at_origin(definitions, outputs, d.local)
    key = chart_key(model, chart)
    where = "joint coordinates" if key == JOINT_CHART else f"chart '{chart.name}' ({key})"
    if d.local:
        at = "at xi = 0" if at_origin else "xi (inputs after q), for the linearization"
        where = f"local exponential coordinates {at} ({_group_chart_text(model, chart, order)})"
    elif model.group_joints:
        where += f" ({GROUP_IN_CHART})"
    inputs = list(d.configuration or d.coordinates) + ([] if at_origin else list(d.local)) + list(d.world)
    return _Program(f"Euler-Lagrange dynamics of model '{model.name}' ({model.digest()}) in {where}, generated by "
                    "crosscheck", ("q", "qd") if key == JOINT_CHART or d.local else ("p", "pd"),
                    inputs, list(d.rates), definitions, outputs)


def _source(program: _Program, syntax) -> _Source:
    code = _Source([e for _, e in program.definitions] + [e for v in program.outputs.values() for e in v], syntax)
    for s, e in program.definitions:
        code.assign(s, e)
    return code


def _python(program: _Program) -> str:
    """Python source of ``evaluate(x, xd)`` returning the program's outputs in order, tuples but for the number T:
    ``(M_upper, Cqd, g, T, phi, Jc, bias)`` of the dynamics, :data:`LINEAR_OUTPUTS` of the linearization."""
    code = _source(program, _Python)
    for label, exprs in program.outputs.items():
        refs = [code.ref(e) for e in exprs]
        code.statements.append((label, refs[0] if label == "T" else f"({''.join(r + ', ' for r in refs)})"))
    x, xd = program.arguments
    return "\n".join([
        f"# {program.header}",
        f"def evaluate({x}, {xd}):",
        f"    {', '.join(map(str, program.inputs))}, = {x}",
        f"    {', '.join(map(str, program.rates))}, = {xd}",
        *(f"    {name} = {text}" for name, text in code.statements),
        f"    return {', '.join(program.outputs)}"]) + "\n"


#: The size of a function of the generated C, in characters of its statements (about an operation per 10). gcc's
#: optimizer takes time superlinear in the size of a function (the panda's 2,900 statements in one function: 63 s at
#: -O1), so the body is cut into functions of about this size, never inlined, which pass the values they share
#: through one array.
C_PART = 4000
_IDENTIFIER = re.compile(r"\b[A-Za-z_]\w*")


def _c_parts(program: _Program, statements: list[tuple[str, str]]) -> tuple[list[str], int]:
    """The C functions ``part<k>(x_, xd_, v_, out_)`` running ``statements`` (:data:`C_PART` long) and the length of
    the array ``v_`` they share (a slot per value that a later part reads, in order of definition). A part stores
    such values into ``v_`` as it defines them and reads the inputs and earlier parts' values where it uses them
    (``x_[i]``, ``xd_[i]``, ``v_[k]`` in place of the name): loaded at the top instead, the last parts' thousands of
    values would all be live at once, and gcc's register allocation takes seconds on each such part."""
    parts: list[list] = [[]]
    size = 0
    for statement in statements:
        if parts[-1] and size + len(statement[1]) > C_PART:
            parts.append([])
            size = 0
        parts[-1].append(statement)
        size += len(statement[1])
    home = {name: p for p, part in enumerate(parts) for name, _ in part}
    uses = [set(_IDENTIFIER.findall(" ".join(text for _, text in part))) for part in parts]
    later = {n for p, used in enumerate(uses) for n in used if home.get(n, p) < p}
    slot = {name: k for k, name in enumerate(name for name, _ in statements if name in later)}
    remote = {name: f"v_[{k}]" for name, k in slot.items()}
    remote.update({str(s): f"x_[{i}]" for i, s in enumerate(program.inputs)})
    remote.update({str(s): f"xd_[{i}]" for i, s in enumerate(program.rates)})
    functions = []
    for p, part in enumerate(parts):
        body = []
        for name, text in part:
            text = _IDENTIFIER.sub(lambda m: m[0] if home.get(m[0], -1) == p else remote.get(m[0], m[0]), text)
            if not _IDENTIFIER.search(text):  # a number: the same in both lanes
                text = f"(vec){{{text}, {text}}}"
            body.append(f"    {name} = {text};" if name.startswith("out_[") else f"    const vec {name} = {text};")
            if name in slot:
                body.append(f"    v_[{slot[name]}] = {name};")
        functions += [f"__attribute__((noinline)) static void part{p}(const vec *restrict x_, const vec *restrict xd_, "
                      "vec *restrict v_, vec *restrict out_) {", *body, "}"]
    return functions, len(slot)


#: The C library's functions lane by lane on a pair of states (:class:`_C`).
_C_HELPERS = (
    "typedef double vec __attribute__((vector_size(16)));  /* two states, one per lane */",
    "double sin(double); double cos(double); double sqrt(double); double pow(double, double);",
    "static vec vsin(vec a) { return (vec){sin(a[0]), sin(a[1])}; }",
    "static vec vcos(vec a) { return (vec){cos(a[0]), cos(a[1])}; }",
    "static vec vsqrt(vec a) { return (vec){sqrt(a[0]), sqrt(a[1])}; }",
    "static vec vpow(vec a, double e) { return (vec){pow(a[0], e), pow(a[1], e)}; }")


def _c(program: _Program) -> str:
    """C source of ``void evaluate(const double *x, const double *xd, double *out)`` writing the outputs of
    :data:`OUTPUTS` one after the other into ``out``, and of ``evaluate_batch(n_states, X, XD, OUT)``, which runs it on
    the rows of row-major arrays; ``crosscheck_layout`` holds the lengths of x, xd and out.

    The code runs on two states at once (``evaluate_pair``), one per lane of a ``vec`` (gcc's and clang's vector
    extension: two doubles, whatever the machine's vector instructions are; each lane's arithmetic is the scalar
    IEEE one): a batch is run in pairs, a single state in both lanes. The body is cut into functions
    (:func:`_c_parts`) called in order, which share values through ``v_`` (on the stack, 16 bytes a value: 300 KB
    for tiago's 48 joints). The library functions are declared, not included (``math.h`` declares names such as
    ``y0`` and ``j1``)."""
    code = _source(program, _C)
    outputs = [e for exprs in program.outputs.values() for e in exprs]
    for k, e in enumerate(outputs):
        code.statements.append((f"out_[{k}]", code.ref(e)))
    functions, shared = _c_parts(program, code.statements)
    nx, nv, size = len(program.inputs), len(program.rates), len(outputs)
    return "\n".join([
        f"/* {program.header.replace('*/', '* /')} */",
        *_C_HELPERS,
        f"const long crosscheck_layout[3] = {{{nx}, {nv}, {size}}};",
        *functions,
        "static void evaluate_pair(const double *xa, const double *xda, const double *xb, const double *xdb, "
        "double *outa, double *outb) {",
        f"    vec x_[{max(nx, 1)}], xd_[{max(nv, 1)}], v_[{max(shared, 1)}], out_[{size}];",
        f"    for (int i = 0; i < {nx}; ++i) x_[i] = (vec){{xa[i], xb[i]}};",
        f"    for (int i = 0; i < {nv}; ++i) xd_[i] = (vec){{xda[i], xdb[i]}};",
        *(f"    part{p}(x_, xd_, v_, out_);" for p in range(functions.count("}"))),
        f"    for (int i = 0; i < {size}; ++i) {{ outa[i] = out_[i][0]; outb[i] = out_[i][1]; }}",
        "}",
        "void evaluate(const double *x, const double *xd, double *out) {",
        f"    double copy[{size}];",
        "    evaluate_pair(x, xd, x, xd, out, copy);",
        "}",
        "void evaluate_batch(long n_states, const double *X, const double *XD, double *OUT) {",
        "    long i = 0;",
        f"    for (; i + 1 < n_states; i += 2) evaluate_pair(X + {nx} * i, XD + {nv} * i, X + {nx} * (i + 1), "
        f"XD + {nv} * (i + 1), OUT + {size} * i, OUT + {size} * (i + 1));",
        f"    if (i < n_states) evaluate(X + {nx} * i, XD + {nv} * i, OUT + {size} * i);",
        "}"]) + "\n"


#: The targets of :func:`generate_source`.
LANGUAGES = {"python": _python, "c": _c}


def generate_source(model: Model, chart: Chart | None = None, order: int | None = None,
                    language: str = "python") -> str:
    """Source of the dynamics at a state in the chart, in Python or C (``language``, :data:`LANGUAGES`): Python's
    ``evaluate(x, xd) -> (M_upper, Cqd, g, T, phi, Jc, bias)`` (:func:`_python`), C's ``evaluate`` writing the same
    numbers into one array (:func:`_c`); ``Jc`` row by row, the constraint terms empty without constraints. The
    staged definitions in creation order (each reads only earlier ones), shared subexpressions as temporaries, then
    the outputs (the arguments are named ``q, qd`` in the joint chart and ``p, pd`` in any other). With spherical or
    free joints ``x`` is the state's q (nq entries) and the code is the local chart's derivation at ``xi = 0``
    (:func:`_at_origin`; ``order`` of the exponential series, module docstring "Group joints")."""
    if language not in LANGUAGES:
        raise ValueError(f"Euler–Lagrange: no code generator for {language!r}; known: {', '.join(LANGUAGES)}")
    return LANGUAGES[language](_program(model, chart, EXP_ORDER if order is None else order))



# ----------------------------------------------------------------------------------------------------------
# Caches: on disk (generated source) and in process (compiled function), keyed by (model, chart, this module)
# ----------------------------------------------------------------------------------------------------------

_DERIVATION_HASH = hashlib.sha256(Path(__file__).read_bytes()).digest()


def _cache_dir() -> Path:
    return cache_dir("euler_lagrange")


def cache_key(model: Model, chart: Chart | None = None) -> str:
    """The disk-cache key: a digest of (the model's digest without its world data, ``cases.world.shape_digest``; the
    chart key or ``"identity"``; a hash of this module)."""
    parts = (shape_digest(model), chart_key(model, chart))
    if model.group_joints:  # how the group joints are derived is part of the key: the local chart, or psi's q
        parts += (GROUP_IN_CHART if parts[1] != JOINT_CHART and _representation(model, chart) is None
                  else _group_chart_text(model, chart, EXP_ORDER),)
    return hashlib.sha256("\0".join(parts).encode() + b"\0" + _DERIVATION_HASH).hexdigest()[:32]


#: The file suffix of each language's cached source.
_SUFFIX = {"python": ".py", "c": ".c"}


def cached_source(model: Model, chart: Chart | None = None, language: str = "python") -> str:
    """The generated source in ``language`` (:data:`LANGUAGES`), from the disk cache when present. Only that language
    is rendered: the C is needed only by a model that is compiled (:class:`_Deferred`), and rendering it costs as
    much again as the Python (a fifth of a fuzz campaign's time when both were written); compiling, three times the
    derivation, pays for deriving once more.

    Keyed by the model digest, the chart's key and a hash of this module's own source, so a change to the
    derivation can never be hidden by code generated before it, and one chart's code is never served for another.
    """
    path = (_cache_dir() / cache_key(model, chart)).with_suffix(_SUFFIX[language])
    return _cached_text(path, lambda: generate_source(model, chart, language=language))


def _cached_text(path: Path, make: Callable[[], str]) -> str:
    """The text cached at ``path``, else ``make()`` written there (:func:`~formalisms.interface.write_cache_file`).
    A miss holds an exclusive lock on ``<path>.lock`` while it derives (:func:`_deriving`), so a process that needs
    the same entry meanwhile (a helper deriving ahead, a second worker) waits and reads it instead of deriving it
    again."""
    if path.exists():
        used_cache_file(path)
        return path.read_text()
    with _deriving(path):
        if path.exists():                 # another process derived it while this one waited
            used_cache_file(path)
            return path.read_text()
        source = make()
        write_cache_file(path, source.encode())
    return source


@contextlib.contextmanager
def _deriving(path: Path) -> Iterator[None]:
    """An exclusive ``flock`` on ``<path>.lock`` (POSIX; nothing elsewhere, or where the cache cannot be written: the
    work is then only done twice). The kernel releases it when its process ends, killed or not."""
    try:
        path.parent.mkdir(parents=True, exist_ok=True)
        handle = open(path.with_name(path.name + ".lock"), "a")
    except OSError:
        yield
        return
    with handle:
        if fcntl is not None:
            fcntl.flock(handle, fcntl.LOCK_EX)
        yield


def cached_code(model: Model, chart: Chart | None = None) -> types.CodeType:
    """The code object of :func:`cached_source`, cached on disk beside it (marshal, keyed also by the interpreter's
    bytecode magic number): compiling the source of a 9-joint arm takes most of a second, loading its code a few
    milliseconds. An entry that does not load is compiled again."""
    return _cached_code(_cache_dir() / f"{cache_key(model, chart)}.py", lambda: cached_source(model, chart))


def _cached_code(path: Path, source: Callable[[], str]) -> types.CodeType:
    """The code object of the Python source cached at ``path`` (``source()`` gives it), from its marshalled copy beside
    it when that loads (:func:`cached_code`), else compiled and written there."""
    code_path = path.with_name(f"{path.stem}-{importlib.util.MAGIC_NUMBER.hex()}.code")
    if path.exists() and code_path.exists():
        try:
            code = marshal.loads(code_path.read_bytes())
        except (EOFError, ValueError, TypeError):
            code = None
        if isinstance(code, types.CodeType):
            used_cache_file(path)
            used_cache_file(code_path)
            return code
    code = compile(source(), str(path), "exec")
    write_cache_file(code_path, marshal.dumps(code))
    return code


# ----------------------------------------------------------------------------------------------------------
# Compiled C (module docstring, "Compilation"): a shared library per (model, chart), cached beside the source
# ----------------------------------------------------------------------------------------------------------

#: The compiler's options: IEEE arithmetic as written (no reassociation, no contraction of ``a*b + c`` into a fused
#: multiply-add, which aarch64 would do by default), so the compiled code rounds as the interpreted one does.
#: -O1 (measured; module docstring, "Compilation").
C_FLAGS = ("-O1", "-fno-fast-math", "-ffp-contract=off", "-fPIC", "-shared")
#: The environment variable that turns compilation off (``0``): the interpreted code is used.
COMPILE_VARIABLE = "CROSSCHECK_COMPILE"


class CompileError(RuntimeError):
    """The generated C did not compile, or its library does not load (the interpreted code is used instead)."""


def _compiler() -> str | None:
    """The system C compiler: ``cc``, else ``gcc``, from PATH (None when there is neither)."""
    return shutil.which("cc") or shutil.which("gcc")


def _no_compilation() -> str | None:
    """Why the generated code is not compiled in this process (:data:`COMPILE_VARIABLE` is 0, no compiler), or None."""
    if os.environ.get(COMPILE_VARIABLE, "").strip() == "0":
        return f"{COMPILE_VARIABLE}=0"
    if _compiler() is None:
        return "no C compiler found: neither cc nor gcc is on PATH"
    return None


def _compiler_text() -> str:
    """The compiler's name and the options that decide the arithmetic, e.g. ``cc -O1 -fno-fast-math ...``."""
    return f"{os.path.basename(_compiler())} {' '.join(C_FLAGS[:3])}"


def evaluation() -> str:
    """Which evaluation this backend uses in this process (``crosscheck formalisms``): compiled C with the compiler
    and its options, or interpreted Python and why. A model whose C fails to compile is evaluated interpreted, with
    a warning (:class:`_Deferred`)."""
    reason = _no_compilation()
    if reason is not None:
        return f"interpreted Python ({reason})"
    return (f"compiled C ({_compiler_text()}) once a model has had {COMPILE_AFTER} states or its library is cached, "
            "interpreted Python before")


_DIGEST = hashlib.sha256().digest_size


def _seal(library: bytes) -> bytes:
    """A cache entry: the library's bytes followed by their SHA-256 (the loader ignores bytes past the library)."""
    return library + hashlib.sha256(library).digest()


def _intact(path: Path) -> bool:
    """Whether the cache entry at ``path`` is whole (its digest matches): a damaged or truncated library is never
    loaded, since loading one can crash the process (its pages past the end of the file fault)."""
    try:
        data = path.read_bytes()
    except OSError:
        return False
    return len(data) > _DIGEST and hashlib.sha256(data[:-_DIGEST]).digest() == data[-_DIGEST:]


def _build(source: str) -> tuple[bytes, ctypes.CDLL]:
    """Compile C source into a shared library in a private temporary directory (so processes compiling the same
    entry at once never share a file): its bytes, and the library loaded from there."""
    compiler = _compiler()
    with tempfile.TemporaryDirectory(prefix="crosscheck-el-") as tmp:
        target = os.path.join(tmp, "evaluate.so")
        try:
            done = subprocess.run([compiler, *C_FLAGS, "-o", target, "-x", "c", "-", "-lm"], input=source.encode(),
                                  capture_output=True, check=False)
        except OSError as exc:
            raise CompileError(f"{compiler} did not run: {exc}") from None
        if done.returncode != 0:
            tail = done.stderr.decode(errors="replace").strip().splitlines()[-5:]
            raise CompileError(f"{compiler} exited with status {done.returncode}"
                               + "".join(f"; {line}" for line in tail))
        try:
            return Path(target).read_bytes(), ctypes.CDLL(target)
        except OSError as exc:
            raise CompileError(f"the library {compiler} built does not load: {exc}") from None


def _layout(library: ctypes.CDLL, model: Model) -> tuple[int, int, int]:
    """The lengths of x, xd and the outputs the library was generated for (``crosscheck_layout``), checked against
    the model's (n rates, :func:`_output_size` outputs); a ValueError names a mismatch."""
    layout = tuple((ctypes.c_long * 3).in_dll(library, "crosscheck_layout"))
    if layout[1:] != (model.n, _output_size(model)):
        raise ValueError(f"Euler–Lagrange: a library for {layout[1]} rates and {layout[2]} outputs, not the "
                         f"{model.n} and {_output_size(model)} of model '{model.name}'")
    return layout


def _library(model: Model, chart: Chart | None) -> tuple[ctypes.CDLL, tuple[int, int, int]]:
    """The compiled library of the model in the chart and its layout: the cached one (``<key>.so``) when it is
    intact and loads, else compiled from :func:`cached_source`'s C and written to the cache
    (:func:`~formalisms.interface.write_cache_file`)."""
    path = _cache_dir() / f"{cache_key(model, chart)}.so"
    if _intact(path):
        try:
            library = ctypes.CDLL(str(path))
            used_cache_file(path)
            return library, _layout(library, model)
        except (OSError, ValueError):  # whole, but not loadable here (another machine's) or not this model's
            pass
    data, library = _build(cached_source(model, chart, "c"))
    write_cache_file(path, _seal(data))
    return library, _layout(library, model)


#: CPU seconds of a cold derivation per (body, coordinate its pose depends on) pair: 21 ms in tiago's joint chart (48
#: joints, 461 pairs, 9.8 s), 27 ms in its banded affine chart (682 pairs, 18.4 s), 30 ms in spatial_arm's dense one,
#: 7-12 ms on planar chains of point masses (measured on the 2-core machine of docs/performance.md, CPU time).
SECONDS_PER_PAIR = 0.03


def preparation_estimate(model: Model, chart: Chart | None = None) -> float:
    """Estimated CPU seconds before the first answer in ``chart`` (None: the joint chart): 0 when the code is cached
    on disk, else the derivation's cost, :data:`SECONDS_PER_PAIR` times the number of (body,
    chart coordinate) pairs where the body's pose depends on the coordinate: the staged derivation names the
    derivatives of each pose entry by each coordinate it depends on (module docstring, steps 1-3). The dependence is
    read from psi's expressions (each joint coordinate's free symbols) and the tree (a body moves with its
    ancestors' joints)."""
    if (_cache_dir() / f"{cache_key(model, chart)}.py").exists():
        return 0.0
    return SECONDS_PER_PAIR * _dependence_pairs(model, chart)


def _dependence_pairs(model: Model, chart: Chart | None) -> int:
    """``sum_i |coordinates body i's pose depends on|`` (:func:`preparation_estimate`)."""
    if chart is None or chart_key(model, chart) == JOINT_CHART or _representation(model, chart):
        own = [frozenset(range(v, v + JOINT_DOF[b.joint][1])) for b, v in zip(model.bodies, model.v_index)]
    else:
        p = list(sp.symbols(f"p0:{model.n}"))
        index = {s: k for k, s in enumerate(p)}
        q = [frozenset(index[f] for f in e.free_symbols) for e in _psi(model, chart, p)]
        own = [frozenset().union(*q[i:i + JOINT_DOF[b.joint][0]]) for b, i in zip(model.bodies, model.q_index)]
    depends: list = [None] * len(model.bodies)
    for i in model.topological_order:
        parent = model.parent_index[i]
        depends[i] = own[i] | (depends[parent] if parent >= 0 else frozenset())
    return sum(len(d) for d in depends)


class _ChartRef:
    """A chart as an in-process cache key: equal and hashed by its key (chart objects may hold arrays, which
    do not hash)."""

    __slots__ = ("chart", "key")

    def __init__(self, chart: Chart, key: str):
        self.chart, self.key = chart, key

    def __eq__(self, other) -> bool:
        return isinstance(other, _ChartRef) and other.key == self.key

    def __hash__(self) -> int:
        return hash(self.key)


def _ref(model: Model, chart: Chart | None) -> _ChartRef | None:
    key = chart_key(model, chart)
    return None if key == JOINT_CHART else _ChartRef(chart, key)


def _output_size(model: Model) -> int:
    """The number of outputs of the generated code (:data:`OUTPUTS`): M's upper triangle, C pd, g, T, phi, Jc, bias,
    and Q with external loads."""
    n, k = model.n, model.k
    return n * (n + 1) // 2 + 2 * n + 1 + k * (n + 2) + (n if model.loads else 0)


class _Evaluator(NamedTuple):
    """How the generated code of one model in one chart runs: ``single(x, xd)`` gives the outputs of :data:`OUTPUTS`
    at one state as one array, ``batch(X, XD)`` those of the rows of X, XD as rows; ``entries`` is the numbers the
    batched call holds per state (what bounds a block of :func:`split_batch`), ``description`` which evaluation this
    is (for the interpreted one, why)."""

    single: Callable[[np.ndarray, np.ndarray], np.ndarray]
    batch: Callable[[np.ndarray, np.ndarray], np.ndarray]
    entries: int
    description: str


def _native(model: Model, chart: Chart | None) -> _Evaluator:
    """The compiled library (:func:`_library`) called through ctypes: one call per state, one per block of states
    (``evaluate_batch``, row-major arrays), the model's world data (:func:`_world_values`) after each state's
    coordinates. A ValueError names arguments of the wrong shape (the library reads exactly its layout's lengths)."""
    library, (nx, nv, size) = _library(model, chart)
    world = _world_values(model)
    nx -= len(world)
    one, many = library.evaluate, library.evaluate_batch
    one.argtypes, one.restype = [ctypes.c_void_p] * 3, None
    many.argtypes, many.restype = [ctypes.c_long] + [ctypes.c_void_p] * 3, None

    def arguments(x, xd, shape: tuple) -> tuple[np.ndarray, np.ndarray]:
        x, xd = np.asarray(x, dtype=float), np.ascontiguousarray(xd, dtype=float)
        if x.shape != shape + (nx,) or xd.shape != shape + (nv,):
            raise ValueError(f"Euler–Lagrange: the compiled code of model '{model.name}' takes x of shape "
                             f"{shape + (nx,)} and xd of {shape + (nv,)}, not {x.shape} and {xd.shape}")
        return np.ascontiguousarray(np.concatenate([x, np.broadcast_to(world, shape + world.shape)], axis=-1)), xd

    def single(x, xd) -> np.ndarray:
        x, xd = arguments(x, xd, ())
        out = np.empty(size)
        one(x.ctypes.data, xd.ctypes.data, out.ctypes.data)
        return out

    def batch(X, XD) -> np.ndarray:
        X, XD = arguments(X, XD, (len(X),))
        out = np.empty((len(X), size))
        many(len(X), X.ctypes.data, XD.ctypes.data, out.ctypes.data)
        return out

    return _Evaluator(single, batch, size, f"compiled C ({_compiler_text()})")


def _flat(outputs) -> list:
    """The generated Python's ``(M_upper, Cqd, g, T, phi, Jc, bias[, Qext])`` as one list in that order."""
    M_upper, Cqd, g, T, *rows = outputs
    return [*M_upper, *Cqd, *g, T, *(e for row in rows for e in row)]


def _rows(values, size: int) -> np.ndarray:
    """The outputs of the batched source (arrays with one entry per state, or numbers where an entry does not
    depend on the state) as one (len(values), size) array."""
    out = np.empty((len(values), size))
    for i, v in enumerate(values):
        out[i] = v
    return out


def _interpreted(model: Model, chart: Chart | None, reason: str) -> _Evaluator:
    """The cached Python code (:func:`cached_code`) run with ``math``'s ``sin`` and ``cos`` for one state, and with
    numpy's on columns of states (each coordinate an array with one entry per state) for a batch, the model's world
    data (:func:`_world_values`) after the coordinates; the batched call holds one array per local of the code."""
    code = cached_code(model, chart)
    scalar = {"sin": math.sin, "cos": math.cos, "sqrt": math.sqrt}
    columns = {"sin": np.sin, "cos": np.cos, "sqrt": np.sqrt}
    exec(code, scalar)
    exec(code, columns)
    one, many = scalar["evaluate"], columns["evaluate"]
    world = _world_values(model)

    def single(x, xd) -> np.ndarray:
        return np.array(_flat(one(np.asarray(x, dtype=float).tolist() + world.tolist(),
                                  np.asarray(xd, dtype=float).tolist())))

    def batch(X, XD) -> np.ndarray:
        X = np.asarray(X, dtype=float)
        X = np.concatenate([X, np.broadcast_to(world, (len(X), len(world)))], axis=1)
        outputs = many(np.ascontiguousarray(X.T), np.ascontiguousarray(XD.T, dtype=float))
        return _rows(_flat(outputs), len(X)).T

    return _Evaluator(single, batch, len(many.__code__.co_varnames), f"interpreted Python ({reason})")


#: States the generated code of one model in one chart evaluates interpreted in a process before it is compiled
#: (module docstring, "Compilation"): compiling costs about three derivations (the Panda's C 2.9 s of CPU, its
#: derivation 0.9 s), some thousands of interpreted states, so only a model evaluated this often (a batch, a campaign)
#: pays for it. A library already in the cache is loaded at once.
COMPILE_AFTER = 1000


class _Deferred:
    """The generated code of one model in one chart (:func:`_compiled`): the cached library when there is one, else
    the interpreted Python (:func:`_interpreted`) until it has evaluated :data:`COMPILE_AFTER` states, then the
    compiled C (:func:`_native`); without compilation (:func:`_no_compilation`), or when the C does not compile (a
    RuntimeWarning with the compiler's message), interpreted throughout. Both round alike (:class:`_Source`)."""

    def __init__(self, model: Model, chart: Chart | None):
        self.model, self.chart, self.states = model, chart, 0
        reason = _no_compilation()
        self.current = self._cached() if reason is None else None
        self.decided = reason is not None or self.current is not None
        if self.current is None:
            self.current = _interpreted(model, chart, reason or f"compiled after {COMPILE_AFTER} states")
        self._due(0)

    def _cached(self) -> _Evaluator | None:
        if not _intact(_cache_dir() / f"{cache_key(self.model, self.chart)}.so"):
            return None
        try:
            return _native(self.model, self.chart)
        except CompileError:
            return None

    def _due(self, states: int) -> _Evaluator:
        if not self.decided:
            self.states += states
            if self.states >= COMPILE_AFTER:
                self.decided = True
                try:
                    self.current = _native(self.model, self.chart)
                except CompileError as exc:
                    reason = f"the C did not compile: {exc}"
                    warnings.warn(f"Euler–Lagrange: model '{self.model.name}': {reason}; evaluating it interpreted",
                                  RuntimeWarning, stacklevel=3)
                    self.current = self.current._replace(description=f"interpreted Python ({reason})")
        return self.current

    def single(self, x, xd) -> np.ndarray:
        return self._due(1).single(x, xd)

    def batch(self, X, XD) -> np.ndarray:
        return self._due(len(X)).batch(X, XD)

    @property
    def entries(self) -> int:
        return self.current.entries

    @property
    def description(self) -> str:
        return self.current.description


@functools.lru_cache(maxsize=64)
def _compiled(model: Model, ref: _ChartRef | None) -> _Deferred:
    """The evaluation of the model's derivation in the chart (None: the joint chart), keyed by (model, chart key):
    :class:`_Deferred`."""
    return _Deferred(model, None if ref is None else ref.chart)


# ----------------------------------------------------------------------------------------------------------
# Numbers
# ----------------------------------------------------------------------------------------------------------

class Terms(NamedTuple):
    """The numeric dynamics at a state, in the chart it was evaluated in."""

    M: np.ndarray      # mass matrix (n x n)
    Cqd: np.ndarray    # velocity-product vector C pd
    g: np.ndarray      # dV/dp (minus Qext with external loads)
    T: float           # kinetic energy at the state (J)
    Qext: np.ndarray | None = None   # the external loads' generalized force, None without loads


class ConstraintTerms(NamedTuple):
    """The numeric constraint terms at a state, in the chart it was evaluated in (empty without constraints)."""

    phi: np.ndarray    # phi (k), the declarations' rows
    Jc: np.ndarray     # dphi/dp (k x n); in a chart Jc Dpsi
    bias: np.ndarray   # Jcdot pd (k), so that Jc pdd + bias = 0 (eq. 13)


@functools.lru_cache(maxsize=None)
def _symmetric(n: int) -> np.ndarray:
    """For each entry ``(i, j)`` of an n x n matrix, row by row, the index of ``(min, max)`` in its upper triangle
    listed row by row (the generated code's ``M_upper``)."""
    upper = np.zeros((n, n), dtype=int)
    upper[np.triu_indices(n)] = np.arange(n * (n + 1) // 2)
    return np.triu(upper).ravel() + np.triu(upper, 1).T.ravel()


def _unpack(model: Model, out: np.ndarray) -> tuple[Terms, ConstraintTerms]:
    """The outputs of :data:`OUTPUTS` of one state (``out`` of one dimension) or of a stack of states (rows) as
    :class:`Terms` and :class:`ConstraintTerms` (with a leading axis for a stack)."""
    n, k, lead = model.n, model.k, out.shape[:-1]
    upper, Cqd, g, T, phi, Jc, bias, Qext = np.split(out, np.cumsum([n * (n + 1) // 2, n, n, 1, k, k * n, k]), axis=-1)
    return (Terms(upper[..., _symmetric(n)].reshape(lead + (n, n)), Cqd, g, T[..., 0] if lead else float(T[0]),
                  Qext if model.loads else None),
            ConstraintTerms(phi, Jc.reshape(lead + (k, n)), bias))


def evaluate(model: Model, x: np.ndarray, xd: np.ndarray, chart: Chart | None = None) -> tuple[Terms, ConstraintTerms]:
    """The dynamics and the constraint terms at coordinates ``x`` with rates ``xd`` in ``chart`` (None: joint
    chart), from one call of the generated code (compiled or interpreted: :func:`_compiled`). With spherical or free
    joints ``x`` is the state's q (nq entries) and ``xd`` its v: the local chart at ``xi = 0`` (module docstring,
    "Group joints")."""
    return _unpack(model, _compiled(model, _ref(model, chart)).single(x, xd))


def evaluate_batch(model: Model, X: np.ndarray, XD: np.ndarray) -> tuple[Terms, ConstraintTerms]:
    """The dynamics and the constraint terms of N joint-chart states at once (rows of ``X``, ``XD``), from one call
    of the generated code (:func:`_compiled`): ``M`` (N, n, n), ``Cqd``, ``g`` (N, n), ``T`` (N,), ``phi``, ``bias``
    (N, k), ``Jc`` (N, k, n)."""
    return _unpack(model, _compiled(model, None).batch(X, XD))


def evaluate_terms(model: Model, x: np.ndarray, xd: np.ndarray, chart: Chart | None = None) -> Terms:
    """``M``, ``C xd``, ``g`` and ``T`` at coordinates ``x`` with rates ``xd`` in ``chart`` (None: joint chart)."""
    return evaluate(model, x, xd, chart)[0]


def terms(model: Model, q: np.ndarray, qd: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Numeric ``M(q)``, ``C(q, qd) qd`` and ``g(q)`` of eq. (2) from the compiled derivation. With spherical or
    free joints (q of nq entries, qd = v of nv) these are the local exponential chart's at ``xi = 0`` (module
    docstring, "Group joints"): M in v-space, ``C qd = rnea(q, v, 0) - g`` and ``g = rnea(q, 0, 0)``."""
    M, Cqd, g, *_ = evaluate_terms(model, q, qd)
    return M, Cqd, g


# The solves below take one state (2-D matrices) or a stack of states (a leading batch axis) alike.

def _t(a: np.ndarray) -> np.ndarray:
    """The transpose of the last two axes (of every matrix in a stack)."""
    return np.swapaxes(a, -1, -2)


def _not_positive_definite(model: Model, M: np.ndarray, x: np.ndarray, chart: str | None) -> ValueError:
    """The error for a mass matrix that is not positive definite (e.g. a point mass on its own joint axis), naming
    the model, the configuration and the eigenvalues; in a chart (its name) ``M`` and ``x`` are ``M_p`` and ``p``."""
    where = f"q = {x.tolist()}" if chart is None else (
        f"p = {x.tolist()} in chart '{chart}' (M_p = Dpsi^T M Dpsi is singular wherever Dpsi is)")
    return ValueError(f"model '{model.name}': the mass matrix is not positive definite at {where} (Cholesky "
                      f"failed); eigenvalues {np.linalg.eigvalsh(M).tolist()}")


def _upper_factor(model: Model, M: np.ndarray, x: np.ndarray, chart: str | None = None) -> np.ndarray:
    """The upper Cholesky factor ``U`` of ``M = U^T U`` (of each M in a stack, ``x`` then the stack of coordinates);
    a mass matrix that is not positive definite is :func:`_not_positive_definite`'s ValueError (for a stack, of the
    state with the smallest eigenvalue, named by its row)."""
    if M.ndim == 2:
        try:
            c, lower = scipy.linalg.cho_factor(M)
        except np.linalg.LinAlgError:
            raise _not_positive_definite(model, M, x, chart) from None
        return np.tril(c).T if lower else np.triu(c)
    try:
        return _t(np.linalg.cholesky(M))
    except np.linalg.LinAlgError:
        worst = int(np.argmin(np.linalg.eigvalsh(M)[:, 0]))
        try:
            _upper_factor(model, M[worst], x[worst], chart)
        except ValueError as err:
            raise ValueError(f"state {worst} of the batch: {err}") from None
        raise ValueError(f"model '{model.name}': a mass matrix of the batch is not positive definite (Cholesky "
                         f"failed; the smallest eigenvalue, {np.linalg.eigvalsh(M[worst])[0]:.3g}, is at state "
                         f"{worst})") from None


def _triangular(U: np.ndarray, b: np.ndarray, trans: bool = False) -> np.ndarray:
    """``U^-1 b`` (``U^-T b`` with ``trans``) for an upper-triangular ``U`` and ``b`` of shape (n, columns), or for
    stacks of both: LAPACK for one matrix, substitution row by row over the whole stack for many."""
    if U.ndim == 2:
        return scipy.linalg.solve_triangular(U, b, trans="T" if trans else "N")
    if len(U) == 1 == len(b):  # a stack of one (a single split's scaling)
        return _triangular(U[0], b[0], trans)[None]
    n = U.shape[-1]
    x = np.empty(np.broadcast_shapes(U.shape[:-1], b.shape[:-1]) + b.shape[-1:])
    for i in (range(n) if trans else range(n - 1, -1, -1)):
        done = slice(0, i) if trans else slice(i + 1, n)
        coefficients = U[:, done, i] if trans else U[:, i, done]
        x[:, i] = (b[:, i] - (coefficients[:, None, :] @ x[:, done])[:, 0]) / U[:, i, i, None]
    return x


def _free(U: np.ndarray, h: np.ndarray, tau: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """drift ``-M^-1 h`` (eq. 10, ``h = C xd + g``), ctrl ``M^-1 tau`` and total ``M^-1 (tau - h)``, each solved on
    its own (a separate right-hand side) with the Cholesky factor ``U`` of M, never an inverse."""
    x = _triangular(U, _triangular(U, np.stack([-h, tau, tau - h], axis=-1), trans=True))
    return x[..., 0], x[..., 1], x[..., 2]


def _free_parts(U: np.ndarray, Cqd: np.ndarray, g: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The drift's parts (article 4.5-4.6): the zero-velocity counterfactual ``zvcf = -M^-1 g`` and the velocity part
    ``drift_velocity = -M^-1 C xd``, each solved directly with the Cholesky factor ``U`` (their sum is the drift of
    :func:`_free` up to rounding, since the solve is linear)."""
    x = _triangular(U, _triangular(U, np.stack([-g, -Cqd], axis=-1), trans=True))
    return x[..., 0], x[..., 1]


#: LAPACK's symmetric eigensolver for selected eigenvalues (Sturm-sequence bisection), called directly: scipy's
#: ``eigh`` wrapper costs more than the two bisections.
_SYEVX = scipy.linalg.lapack.get_lapack_funcs("syevx", (np.zeros(1),))


def _eigenvalue(M: np.ndarray, i: int) -> float:
    """The ``i``-th smallest eigenvalue (1-based) of the symmetric ``M`` by bisection: the value where the Sturm count
    of M's tridiagonal form ``T`` (the number of negative pivots of ``T - sigma 1``, Sylvester's law of inertia)
    reaches i (LAPACK dsyevx with an index range: dstebz), not by the QR iteration of a full eigendecomposition."""
    w, _, _, _, info = _SYEVX(M, compute_v=0, range="I", il=i, iu=i)
    if info != 0:
        raise ValueError(f"LAPACK dsyevx failed (info = {info}) on a matrix with entries {M.tolist()}")
    return float(w[0])


def _mass_spectrum(M: np.ndarray) -> tuple[float, float]:
    """``(lambda_min, lambda_max)`` of a mass matrix, each by bisection (:func:`_eigenvalue`): the smallest and the
    largest kinetic energy per unit rate, ``2 T / |xd|^2``."""
    return _eigenvalue(M, 1), _eigenvalue(M, len(M))


def _conditioning(model: Model, M, Cqd, g, tau, xd) -> tuple[float, float, float]:
    """``(cond(M), ||M^-1||, accel_scale)`` from this derivation's M, C xd, g and the applied force ``tau``, with
    M's extreme eigenvalues from :func:`_mass_spectrum` (``cond = lambda_max / lambda_min``, ``||M^-1|| = 1 /
    lambda_min``; both inf where lambda_min is not positive).

    ``accel_scale = ||M^-1||_2 H``, H the size of the generalized forces summed in ``tau - C xd - g``. The computed
    ``C xd`` and ``g`` can cancel to zero while their terms do not (a folded arm, zero gravity), so H also carries
    configuration-robust magnitudes of those terms: ``||M|| |xd|^2`` for the velocity products and ``|gravity|
    sqrt(m_total ||M||)`` (a mass times a lever arm) for gravity. 1-norms, so tiny vectors do not underflow."""
    low, high = _mass_spectrum(M)
    m_total = sum(b.mass for b in model.bodies)
    H = (np.abs(Cqd).sum() + np.abs(g).sum() + np.abs(tau).sum() + high * float(xd @ xd)
         + np.abs(model.gravity).sum() * math.sqrt(m_total * high))
    inverse_norm = 1.0 / low if low > 0.0 else math.inf
    return high * inverse_norm, inverse_norm, float(H) * inverse_norm


def _power(force: np.ndarray, rate: np.ndarray) -> tuple[float, np.ndarray]:
    """The power of a generalized force (a covector) on the rates: per coordinate ``force_i rate_i``, and their sum
    correctly rounded (``math.fsum``)."""
    per = force * rate
    return math.fsum(per), per


def _external_fields(Qext: np.ndarray | None, xd: np.ndarray) -> dict:
    """``external_force`` (the derivation's Q) and its power ``Q . xd``; none without loads."""
    return {} if Qext is None else {"external_force": Qext, "power_ext": _power(Qext, xd)[0]}


def _applied(tau: np.ndarray, Qext: np.ndarray | None) -> np.ndarray:
    """The applied generalized forces' sizes for the acceleration scale: ``|tau| + |Q|``."""
    return tau if Qext is None else np.abs(tau) + np.abs(Qext)


def _solve(model: Model, M, Cqd, g, tau, x, xd, T, chart: str | None = None, Qext: np.ndarray | None = None) -> Split:
    """The split of eq. (9) from the terms: drift ``-M^-1 (C xd + g)`` (eq. 10), ctrl ``M^-1 tau``, total
    ``M^-1 (tau - C xd - g)`` (:func:`_free`); the power ``tau . xd`` and the conditioning of M. With external loads
    ``g`` is ``dV/dp - Qext``."""
    U = _upper_factor(model, M, x, chart)
    drift, ctrl, total = _free(U, Cqd + g, tau)
    zvcf, drift_velocity = _free_parts(U, Cqd, g)
    cond_M, _, accel_scale = _conditioning(model, M, Cqd, g, _applied(tau, Qext), xd)
    power, per = _power(tau, xd)
    return Split(drift=drift, ctrl=ctrl, total=total, lam=None, lam_drift=None, power_ctrl=power,
                 power_ctrl_per_coord=per, power_constr=None, power_constr_per_coord=None, cond_M=cond_M,
                 accel_scale=accel_scale, kinetic_energy=T, zvcf=zvcf, drift_velocity=drift_velocity,
                 **_external_fields(Qext, xd))


class _Scaled(NamedTuple):
    """The constrained problem in the Cholesky frame of ``M = U^T U``: ``A = Jc U^-1``, so ``S = Jc M^-1 Jc^T =
    A A^T``, and S's eigen-decomposition from the SVD of A (:func:`_spectrum`): the eigen-directions ``V`` (columns)
    and eigenvalues ``w`` (ascending) that are kept, above :func:`_redundant_below`, and the redundant ones ``V0``,
    ``w0``. For one state, or a stack of states of the same rank (leading axis)."""

    U: np.ndarray
    A: np.ndarray
    V: np.ndarray
    w: np.ndarray
    V0: np.ndarray
    w0: np.ndarray


def _degenerate_floor(model: Model) -> float:
    """The smallest eigenvalue of ``Jc M^-1 Jc^T`` that is a direction and not rounding: a row of ``DEGENERATE_ROW``
    times the model's length scale L, in the metric of M: ``(DEGENERATE_ROW L)^2 / inertia_scale``."""
    return (DEGENERATE_ROW * model.length_scale) ** 2 / model.inertia_scale


def _redundant_below(model: Model, w_max):
    """The redundancy rule: eigenvalues of S at or below ``CONSTRAINT_RCOND`` times the largest, ``w_max`` (one per
    state of a stack), or below :func:`_degenerate_floor`, are redundant directions."""
    return np.maximum(CONSTRAINT_RCOND * np.asarray(w_max, dtype=float), _degenerate_floor(model))


def _spectrum(A: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Eigen-directions (columns) and eigenvalues, ascending, of ``S = A A^T`` (of each in a stack) from the SVD of
    ``A = E diag(sigma) X^T``: ``S = E diag(sigma^2) E^T``, the eigenvalues beyond ``min(k, n)`` zero."""
    E, sigma, _ = np.linalg.svd(A)
    w = np.zeros(A.shape[:-1])
    w[..., :sigma.shape[-1]] = sigma ** 2
    return E[..., ::-1], w[..., ::-1]


def _scaled(model: Model, U: np.ndarray, Jc: np.ndarray) -> list[tuple[np.ndarray, _Scaled]]:
    """:class:`_Scaled` of a stack of states (``U`` (N, n, n) the Cholesky factors of M, ``Jc`` (N, k, n)), grouped
    by rank: ``(rows, scaled)`` per rank, the states' rows in the stack and their stacked :class:`_Scaled`. The kept
    eigenvalues of S are the largest ones, above :func:`_redundant_below` of each state."""
    A = _t(_triangular(U, _t(Jc), trans=True))
    E, w = _spectrum(A)
    k = w.shape[-1]
    rank = (w > _redundant_below(model, w[:, -1:])).sum(axis=1)
    groups = []
    for r in np.unique(rank):
        rows = np.flatnonzero(rank == r)
        E_r, w_r = E[rows], w[rows]
        groups.append((rows, _Scaled(U[rows], A[rows], E_r[..., k - r:], w_r[..., k - r:], E_r[..., :k - r],
                                     w_r[..., :k - r])))
    return groups


def _kkt(sc: _Scaled, forces: np.ndarray, bias: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Solve the KKT system of article 5.6, ``[[M, -Jc^T], [Jc, 0]] [qdd; lam] = [f; -Jcdot qd]`` (eq. 12:
    ``M qdd + h = B u + Jc^T lam``; eq. 13), for each column ``f`` of ``forces``; returns qdd (n x columns) and
    lam (k x columns) (for a stack of states: a leading axis on every argument and result). ``bias`` is one vector
    (k) for every column, or one column per column of ``forces`` (k x columns: the drift's parts, the linearization).

    Rank-revealing by scaling: in the unknowns ``y = U qdd`` and ``mu = s V^T lam`` (``s^2`` the largest
    eigenvalue of S) the block matrix becomes ``[[I, -Ah^T], [Ah, 0]]`` with ``Ah = V^T A / s``, whose rows are
    the kept eigen-directions of S (row norms ``sqrt(w_i) / s`` in ``[sqrt(CONSTRAINT_RCOND), 1]``), so it is
    regular and well scaled. The multipliers ``lam = V mu / s`` lie in the kept directions: for a consistent
    system the unique qdd and the minimum-norm multipliers (a duplicated row gets half each); for an inconsistent
    one (``H_t`` empty) the equations along the redundant directions are dropped: a finite answer, the
    least-squares one where those directions are exactly redundant.
    """
    n, r = sc.A.shape[-1], sc.V.shape[-1]
    s = (np.sqrt(sc.w[..., -1:]) if r else np.ones(sc.w.shape[:-1] + (1,)))[..., None]
    Ah = _t(sc.V) @ sc.A / s
    K = np.zeros(Ah.shape[:-2] + (n + r, n + r))
    K[..., :n, :n] = np.eye(n)
    K[..., :n, n:], K[..., n:, :n] = -_t(Ah), Ah
    columns = bias if bias.ndim == forces.ndim else bias[..., None]
    target = np.broadcast_to(-(_t(sc.V) @ columns) / s, Ah.shape[:-1] + forces.shape[-1:])
    sol = np.linalg.solve(K, np.concatenate([_triangular(sc.U, forces, trans=True), target], axis=-2))
    return _triangular(sc.U, sol[..., :n, :]), sc.V @ sol[..., n:, :] / s


def _constrained_input_map(sc: _Scaled) -> np.ndarray:
    """``B_c = M^-1 [I - Jc^T S^+ Jc M^-1]`` with ``S = Jc M^-1 Jc^T`` (article eq. 17), ``S^+`` the
    pseudo-inverse over its kept eigen-directions (``V diag(1/w) V^T``); in the Cholesky frame
    ``U^-1 (I - A^T S^+ A) U^-T`` (for a stack of states: each one's)."""
    AW = _t(sc.A) @ (sc.V / np.sqrt(sc.w)[..., None, :])
    P = np.eye(sc.U.shape[-1]) - AW @ _t(AW)
    return _triangular(sc.U, _t(_triangular(sc.U, P)))  # U^-1 (U^-1 P)^T, P = P^T


def _constrained(sc: _Scaled, h: np.ndarray, tau: np.ndarray, bias: np.ndarray) -> tuple[np.ndarray, ...]:
    """``(total, drift, ctrl, lam, lam_drift)`` of one state or a stack (article 5.3-5.6): total and lam from the KKT
    system with the input, drift and lam_drift with u = 0 (eq. 14), both by :func:`_kkt`; ctrl ``B_c tau``
    (eq. 17) directly, never total - drift."""
    qdd, lam = _kkt(sc, np.stack([tau - h, -h], axis=-1), bias)
    ctrl = (_constrained_input_map(sc) @ tau[..., None])[..., 0]
    return qdd[..., 0], qdd[..., 1], ctrl, lam[..., 0], lam[..., 1]


def _constrained_parts(sc: _Scaled, Cqd: np.ndarray, g: np.ndarray, bias: np.ndarray) -> tuple[np.ndarray, ...]:
    """The drift's parts with constraints (article 4.5-4.6, 5.3): ``zvcf`` the KKT solve (:func:`_kkt`) with ``f = -g``
    and no bias (``Jcdot qd = 0`` at ``qd = 0``), ``drift_velocity`` with ``f = -C qd`` and the bias ``Jcdot qd``;
    the KKT system is linear in (f, bias), so they add up to the drift."""
    qdd, _ = _kkt(sc, np.stack([-g, -Cqd], axis=-1), np.stack([np.zeros_like(bias), bias], axis=-1))
    return qdd[..., 0], qdd[..., 1]


class _ConstraintConditioning(NamedTuple):
    """The conditioning of the constrained problem at one state (:func:`_constraint_conditioning`)."""

    conditions: dict     # "constraint", "constraint_consistency", "constraint_kept"
    rank: int
    lam_scale: float
    force_scale: float   # ||M^-1|| ||Jc|| lam_scale: the accelerations the constraint force can produce


def _inconsistency(model: Model, sc: _Scaled, bias: np.ndarray, forces: np.ndarray, accel_scale: float) -> float:
    """The relative size of the KKT right-hand sides in S's redundant directions ``V0``: ``max |V0^T r| / |r|`` over
    the columns ``f`` of ``forces``, ``r = -Jcdot qd - Jc M^-1 f = -Jcdot qd - A U^-T f`` (the multipliers solve
    ``S lam = r``); 0 when S is regular. Non-zero means ``H_t`` is empty (eq. 16: the constraints cannot all hold,
    e.g. a four-bar at its change point moving off both branches). |r| is taken at least ``1e-6 L accel_scale``:
    where every row is degenerate, r itself is rounding, and its share means nothing."""
    if not sc.V0.shape[-1]:
        return 0.0
    r = -bias[:, None] - sc.A @ _triangular(sc.U, forces, trans=True)
    size = np.maximum(np.linalg.norm(r, axis=0), 1e-6 * model.length_scale * accel_scale)
    return float(np.max(np.linalg.norm(sc.V0.T @ r, axis=0) / np.where(size > 0.0, size, 1.0)))


def _constraint_conditioning(model: Model, sc: _Scaled, cons: ConstraintTerms, forces: np.ndarray,
                             accel_scale: float, inverse_norm: float) -> _ConstraintConditioning:
    """The conditioning of the constrained problem from the KKT's own scaled blocks (:class:`_Scaled`, one state):
    S's eigenvalues ``w0, w`` (ascending; the largest ``w_max`` taken at least :func:`_degenerate_floor`) give
    ``"constraint"`` = cond S = ``w_max / w_min`` (inf when ``w_min`` is not positive: the multipliers are not unique)
    and ``"constraint_kept"`` = ``w_max`` over the smallest kept eigenvalue (what the solve amplifies; 1 when none
    is kept); ``"constraint_consistency"`` is :func:`_inconsistency` of the right-hand sides ``forces`` (columns
    ``B u - h`` and ``-h``). ``lam_scale = ||S^+|| (|Jcdot qd|_1 + ||Jc|| accel_scale)`` bounds the multipliers by the
    magnitudes summed into ``r`` (``||S^+||`` one over the smallest kept eigenvalue; 0 when none is kept)."""
    w = np.concatenate([sc.w0, sc.w])
    w_max = max(float(w[-1]), _degenerate_floor(model))
    rank = len(sc.w)
    jc_norm = float(np.linalg.svd(cons.Jc, compute_uv=False)[0])
    lam_scale = float((np.abs(cons.bias).sum() + jc_norm * accel_scale) / sc.w[0]) if rank else 0.0
    conditions = {"constraint": w_max / w[0] if w[0] > 0.0 else math.inf,
                  "constraint_consistency": _inconsistency(model, sc, cons.bias, forces, accel_scale),
                  "constraint_kept": w_max / sc.w[0] if rank else 1.0}
    return _ConstraintConditioning(conditions, rank, lam_scale, inverse_norm * jc_norm * lam_scale)


def _solve_constrained(model: Model, dynamics: Terms, cons: ConstraintTerms, tau, x, xd,
                       chart: str | None = None) -> Split:
    """The constrained split (article 5.3-5.6) of one state by :func:`_constrained`, with the scaling of
    :func:`_scaled` (a stack of one); the constraint force ``Jc^T lam`` (and at the drift), its power
    ``(Jc^T lam) . xd`` (5.5), ``Jc xd``, and the conditioning of :func:`_constraint_conditioning`, whose
    ``force_scale`` the acceleration scale includes."""
    M, Cqd, g, T, Qext = dynamics
    ((_, stacked),) = _scaled(model, _upper_factor(model, M, x, chart)[None], cons.Jc[None])
    sc = _Scaled(*(a[0] for a in stacked))
    h = Cqd + g
    total, drift, ctrl, lam, lam_drift = _constrained(sc, h, tau, cons.bias)
    zvcf, drift_velocity = _constrained_parts(sc, Cqd, g, cons.bias)
    cond_M, inverse_norm, accel_scale = _conditioning(model, M, Cqd, g, _applied(tau, Qext), xd)
    cc = _constraint_conditioning(model, sc, cons, np.stack([tau - h, -h], axis=-1), accel_scale, inverse_norm)
    power, per = _power(tau, xd)
    force, force_drift = cons.Jc.T @ lam, cons.Jc.T @ lam_drift
    power_constr, per_constr = _power(force, xd)
    return Split(drift=drift, ctrl=ctrl, total=total, lam=lam, lam_drift=lam_drift, power_ctrl=power,
                 power_ctrl_per_coord=per, power_constr=power_constr, power_constr_per_coord=per_constr,
                 cond_M=cond_M, accel_scale=accel_scale + cc.force_scale, conditions=cc.conditions,
                 kinetic_energy=T, constraint_value=cons.phi, constraint_jacobian=cons.Jc,
                 constraint_bias=cons.bias, constraint_velocity=cons.Jc @ xd, constraint_force=force,
                 constraint_force_drift=force_drift, constraint_rank=cc.rank, lam_scale=cc.lam_scale,
                 zvcf=zvcf, drift_velocity=drift_velocity, **_external_fields(Qext, xd))


def split(model: Model, q, qd, u):
    """Drift ``-M^-1 (C qd + g)`` (eq. 10), control ``M^-1 B u`` and total ``M^-1 (B u - C qd - g)`` (eq. 9);
    power ``u . B^T qd`` and the kinetic energy ``T`` from the derived energy. With constraints, the KKT solves of
    article 5.6 with and without the input (eqs. 12-14) and ctrl ``B_c B u`` (eq. 17): :func:`_solve_constrained`."""
    q, qd, u = check_state(model, q, qd, u)
    if model.constraints:
        return _solve_constrained(model, *evaluate(model, q, qd), model.input_map @ u, q, qd)
    M, Cqd, g, T, Qext = evaluate_terms(model, q, qd)
    return _solve(model, M, Cqd, g, model.input_map @ u, q, qd, T, Qext=Qext)


def split_chart(model: Model, chart: Chart, p, pd, tau_p):
    """The split of eq. (9) evaluated in the chart ``q = psi(p)`` (article 6.4.6, 9.1), from the chart's own
    derivation (module docstring: the Lagrangian in p, eqs. 6–8 in p): drift ``M_p^-1 (-C_p pd - g_p)`` (eq. 10),
    ctrl ``M_p^-1 tau_p``, total ``M_p^-1 (tau_p - C_p pd - g_p)``, accelerations ``pdd`` in the chart. With
    constraints, the same KKT solves and ``B_c`` (eqs. 12-17) with the chart's ``phi(psi(p))``, its Jacobian
    ``Jc_p = Jc Dpsi`` and ``Jcdot_p pd``: the multipliers are the joint chart's.

    ``tau_p`` is the generalized force in the chart, a covector (``Dpsi^T B u`` for an input u); the control
    power is ``tau_p . pd`` (= ``u . B^T qd``, chart-invariant) and the kinetic energy T is the chart's own
    (chart-invariant, 9.1). The task acceleration is not computed here (UNSUPPORTED).
    A model with spherical or free joints is evaluated in a chart whose ``psi`` returns its whole q (the zyx chart:
    ``p``, ``pd``, ``tau_p`` have nv entries; module docstring, "Group joints in a chart"), or in a base-velocity
    representation (a chart with ``representation`` ``"world"`` or ``"mixed"``: ``p`` is q itself, nq entries,
    ``pd`` the representation's w and ``tau_p`` its covector ``T^T f``, nv each; the accelerations returned are
    ``wdot``; module docstring, "Velocity representations"); any other chart is :class:`ModelNotSupported`
    (:func:`chart_key`).
    """
    # validates the chart first: a wrong object is a TypeError, not a StateError
    if _representation(model, chart) is not None:      # p is q itself (nq), pd the representation's w (nv)
        chart_key(model, chart)
        q, w, _ = check_state(model, p, pd, np.zeros(model.m))
        (tau_p,) = chart_vectors(model, tau_p=tau_p)
        if model.constraints:
            return _solve_constrained(model, *evaluate(model, q, w, chart), tau_p, q, w, chart=chart.name)
        M, Cqd, g, T, Qext = evaluate_terms(model, q, w, chart)
        return _solve(model, M, Cqd, g, tau_p, q, w, T, chart=chart.name, Qext=Qext)
    if chart_key(model, chart) == JOINT_CHART and model.group_joints:
        raise ModelNotSupported(_NO_CHARTS.format(nq=model.nq, reason="no chart given: the joint chart (q of nq "
                                                  "entries, v of nv) is split's"))
    p, pd, tau_p = chart_vectors(model, p=p, pd=pd, tau_p=tau_p)
    if model.constraints:
        return _solve_constrained(model, *evaluate(model, p, pd, chart), tau_p, p, pd, chart=chart.name)
    M, Cqd, g, T, Qext = evaluate_terms(model, p, pd, chart)
    return _solve(model, M, Cqd, g, tau_p, p, pd, T, chart=chart.name, Qext=Qext)


#: States per block of :func:`split_batch`, at most; the batched code holds one array per local (some 4,000 for a
#: 9-joint arm, 90,000 for a 30-link chain) until it returns, so a block has at most ``BATCH_ENTRIES // locals``
#: states: at most 256 MB of intermediates (70 MB for panda), and blocks as long as that allows, since every
#: operation costs numpy's per-call overhead once per block.
BATCH_BLOCK = 2048
BATCH_ENTRIES = 2 ** 25


def _split_block(model: Model, Q: np.ndarray, QD: np.ndarray, tau: np.ndarray) -> tuple[np.ndarray, ...]:
    """``(drift, ctrl, total, lam, lam_drift)`` of a block of states (module docstring: the same derivation and
    solves as :func:`split`, every state at once; the constrained states grouped by the rank of S)."""
    (M, Cqd, g, *_), cons = evaluate_batch(model, Q, QD)
    U, h = _upper_factor(model, M, Q), Cqd + g
    if not model.constraints:
        return (*_free(U, h, tau), None, None)
    out = [np.empty((len(Q), model.n)) for _ in range(3)] + [np.empty((len(Q), model.k)) for _ in range(2)]
    for rows, sc in _scaled(model, U, cons.Jc):
        for o, part in zip(out, _constrained(sc, h[rows], tau[rows], cons.bias[rows])):
            o[rows] = part
    total, drift, ctrl, lam, lam_drift = out
    return drift, ctrl, total, lam, lam_drift


def split_batch(model: Model, Q, QD, U) -> SplitBatch:
    """:func:`split` of N states at once (rows of ``Q``, ``QD``, ``U``): the derivation's source evaluated with numpy
    on whole columns of states, M assembled and factored as a stack, and the same solves (:func:`_free`; with
    constraints :func:`_kkt` and :func:`_constrained_input_map` on the states of each rank of S), in blocks of
    at most :data:`BATCH_BLOCK` states (fewer for a long source: :data:`BATCH_ENTRIES`)."""
    Q, QD, U = check_batch(model, Q, QD, U)
    tau = U @ model.input_map.T
    size = max(1, min(BATCH_BLOCK, BATCH_ENTRIES // _compiled(model, None).entries))
    blocks = [slice(i, i + size) for i in range(0, max(len(Q), 1), size)]
    parts = [_split_block(model, Q[b], QD[b], tau[b]) for b in blocks]
    drift, ctrl, total, lam, lam_drift = (None if p[0] is None else np.concatenate(p) for p in zip(*parts))
    return SplitBatch(drift=drift, ctrl=ctrl, total=total, lam=lam, lam_drift=lam_drift)


# ----------------------------------------------------------------------------------------------------------
# Linearization (article 4.8, eq. 11): the derivation's inverse dynamics and constraint terms differentiated
# ----------------------------------------------------------------------------------------------------------

#: The truncation order of the local chart's exponential series in the linearization's program (module docstring,
#: "Group joints"): the first derivatives in xi at 0 of ``C xd`` and ``Jcdot xd`` use the poses' derivatives in xi up
#: to order 3, which ``E_3 = I + X + X^2/2 + X^3/6`` has exactly (order 2 gives wrong dvdot/dq).
LINEAR_ORDER = EXP_ORDER
#: What the linearization's own program computes (part of its cache key, :func:`linearization_key`): the dynamics'
#: outputs in the local exponential chart with xi among the inputs (group joints only).
LINEARIZATION = f"linearization:the dynamics' outputs with xi as inputs:exponential order {LINEAR_ORDER}"
#: The complex step of the forward-mode differentiation (module docstring, "Linearization"): a power of two, so the
#: imaginary part divides by it exactly; its square (1e-42) is below every rounding of the real parts.
STEP = 2.0 ** -70


def _needs_local_program(model: Model, chart: Chart | None) -> bool:
    """Whether the linearization needs its own program: the joint chart of a model with group joints, whose dynamics'
    code is evaluated at ``xi = 0`` with xi gone (:func:`_at_origin`), so it cannot be differentiated in xi."""
    return bool(model.group_joints) and chart_key(model, chart) == JOINT_CHART


def _local_program(model: Model) -> _Program:
    """The dynamics' straight-line program of a model with group joints in the local exponential chart with the xi kept
    as inputs after the state's q (:data:`LINEAR_ORDER`), for :func:`linear_terms` to differentiate at ``xi = 0``."""
    return _program(model, None, LINEAR_ORDER, at_origin=False)


def linearization_key(model: Model, chart: Chart | None = None) -> str:
    """The disk-cache key of the linearization's own program (group joints in the joint chart): :func:`cache_key`
    (model, chart, this module's hash) with :data:`LINEARIZATION`."""
    return hashlib.sha256(f"{cache_key(model, chart)}\0{LINEARIZATION}".encode()).hexdigest()[:32]


def _local_code(model: Model) -> types.CodeType:
    """The code of :func:`_local_program`, from the disk cache (:func:`linearization_key`) or derived into it."""
    path = _cache_dir() / f"{linearization_key(model, None)}.py"
    return _cached_code(path, lambda: _cached_text(path, lambda: _python(_local_program(model))))


def prepare(model: Model, chart: Chart | None = None, linearization: bool = False) -> None:
    """Derive the model's code in ``chart`` (None: the joint chart) into the disk cache now, and with
    ``linearization`` the linearization's own program where it has one (:func:`_needs_local_program`): what a
    process deriving ahead of the gate does (``Formalism.prepare``). Nothing when it is cached."""
    cached_code(model, chart)
    if linearization and _needs_local_program(model, chart):
        _local_code(model)


class _Directional(NamedTuple):
    """The code :func:`linear_terms` differentiates: its batched ``evaluate(x, xd)`` (columns of states, numpy's
    functions, so complex columns too), per coordinate of the chart the index of the input it moves, and the number of
    local coordinates xi that follow the state's q among the inputs (0 but for :func:`_local_program`)."""

    evaluate: Callable
    columns: tuple[int, ...]
    local: int = 0


@functools.lru_cache(maxsize=64)
def _linear_code(model: Model, ref: _ChartRef | None) -> _Directional:
    """The code of :func:`linear_terms`: the dynamics' own code (:func:`cached_code`, the code ``split`` runs) in a
    chart and in the joint chart without group joints; with group joints in the joint chart the local program
    (:func:`_local_program`), derived on the first ``linearize`` (never during ``split``) and cached in memory and on
    disk (:func:`linearization_key`)."""
    chart = None if ref is None else ref.chart
    local: list = []
    if _needs_local_program(model, chart):
        code = _local_code(model)
        coordinates, configuration, local = _local_coordinates(model)
        inputs = configuration + local                    # :func:`_local_program`'s, before the world data
        columns = tuple(inputs.index(s) for s in coordinates)
    else:
        code, columns = cached_code(model, chart), tuple(range(model.n))
    namespace = {"sin": np.sin, "cos": np.cos, "sqrt": np.sqrt}
    exec(code, namespace)
    return _Directional(namespace["evaluate"], columns, len(local))


class LinearTerms(NamedTuple):
    """The derivatives of the KKT rows at a state (:func:`linear_terms`), in the chart they were derived in."""

    force_x: np.ndarray    # d(M a + C xd + g - Jc^T lam)/dx (n x n)
    force_xd: np.ndarray   # the same by xd
    accel_x: np.ndarray    # d(Jc a + Jcdot xd)/dx (k x n)
    accel_xd: np.ndarray   # the same by xd


def _derivatives(model: Model, x, xd, chart: Chart | None) -> tuple[Terms, ConstraintTerms]:
    """The derivatives of the dynamics' outputs (:data:`OUTPUTS`) in the 2n directions of ``(x, xd)`` at a state, as
    :class:`Terms` and :class:`ConstraintTerms` with a leading axis of 2n directions (coordinates, then rates). Forward
    mode by the complex step: each direction is a column of the batched code with
    ``x + i h e_j`` (or ``xd + i h e_j``), whose imaginary parts are ``h`` times the derivatives (module docstring,
    "Linearization")."""
    n = model.n
    code = _linear_code(model, _ref(model, chart))
    x, xd = np.asarray(x, dtype=float), np.asarray(xd, dtype=float)
    inputs = np.concatenate([x, np.zeros(code.local), _world_values(model)])                    # xi = 0
    X = np.tile(inputs.astype(complex), (2 * n, 1))
    XD = np.tile(xd.astype(complex), (2 * n, 1))
    X[np.arange(n), code.columns] += 1j * STEP
    XD[np.arange(n, 2 * n), np.arange(n)] += 1j * STEP
    outputs = _flat(code.evaluate(X.T, XD.T))
    out = np.empty((2 * n, len(outputs)))
    for i, value in enumerate(outputs):
        out[:, i] = np.imag(value) / STEP
    return _unpack(model, out)


def linear_terms(model: Model, x, xd, a, lam, chart: Chart | None = None) -> LinearTerms:
    """:class:`LinearTerms` at coordinates ``x`` (q with group joints: the local chart at ``xi = 0``), rates ``xd``,
    accelerations ``a`` and multipliers ``lam`` (k): the rows ``force = M a + C xd + g - Jc^T lam`` (eq. 2, 12: the
    KKT system's first row) and ``accel = Jc a + Jcdot xd`` (eq. 13, its second) differentiated in every coordinate
    and rate from the derivatives of M, C xd, g, Jc and Jcdot xd (:func:`_derivatives`) at fixed ``a`` and ``lam``."""
    n = model.n
    (dM, dCqd, dg, *_), (_, dJc, dbias) = _derivatives(model, x, xd, chart)
    force = dM @ np.asarray(a, dtype=float) + dCqd + dg - np.einsum("drj,r->dj", dJc, np.asarray(lam, dtype=float))
    accel = dJc @ np.asarray(a, dtype=float) + dbias
    return LinearTerms(force[:n].T, force[n:].T, accel[:n].T, accel[n:].T)


def _ad(e: np.ndarray) -> np.ndarray:
    """``ad_e`` of a group joint's tangent vector: ``[e]x`` on SO(3) (3 entries), ``[[[phi]x, [rho]x], [0, [phi]x]]``
    on SE(3) for ``e = (rho, phi)`` (linear, angular: the interface's :func:`tangent_kinematics` order)."""
    def hat(w):
        return np.array([[0.0, -w[2], w[1]], [w[2], 0.0, -w[0]], [-w[1], w[0], 0.0]])
    if e.size == 3:
        return hat(e)
    out = np.zeros((6, 6))
    out[:3, :3] = out[3:, 3:] = hat(e[3:])
    out[:3, 3:] = hat(e[:3])
    return out


def _group_blocks(model: Model) -> list[slice]:
    """The v-slices of the spherical (3) and free (6) joints."""
    return [slice(model.v_index[i], model.v_index[i] + (3 if model.bodies[i].joint == "spherical" else 6))
            for i in model.group_joints]


def _chart_force(model: Model, tau: np.ndarray) -> np.ndarray:
    """``d/dxi (J_r(xi)^T tau)`` at 0 (n x n): a v-space force ``tau`` is the covector ``J_r(xi)^T tau`` of the local
    chart (its power ``tau . v``, ``v = J_r(xi) xid``), ``J_r = I - ad_xi / 2 + ad_xi^2 / 6 - ...`` (the right
    Jacobian, ``dexp_-xi``): column ``j`` of a group joint's block is ``-ad_(e_j)^T tau_b / 2``; 0 elsewhere."""
    out = np.zeros((model.n, model.n))
    for b in _group_blocks(model):
        size = b.stop - b.start
        for j, e in enumerate(np.eye(size)):
            out[b, b.start + j] = -_ad(e).T @ tau[b] / 2
    return out


def _tangent(model: Model, F_x: np.ndarray, F_xd: np.ndarray, vdot: np.ndarray, v: np.ndarray) -> np.ndarray:
    """``dvdot/dq`` in the contract's convention (``q (+) dq = q exp(dq)``) from the local chart's ``F_x = dxidd/dxi``
    and ``F_xd = dxidd/dxid`` at ``xi = 0`` (module docstring, "Linearization"). Along ``xi = s e`` at fixed v the
    chart's rates are ``xid = J_r(xi)^-1 v = v + s ad_e v / 2 + O(s^2)`` and ``vdot = J_r xidd + (d/dt J_r) xid``
    with ``(d/dt J_r) xid = ad_xid ad_xi xid / 6 + O(|xi|^2)`` (``ad_xid xid = 0``), so the column of ``e`` (a unit
    vector of a group joint's block b) is ``F_x e + F_xd[:, b] ad_e v_b / 2 - ad_e vdot_b / 2 + ad_v_b ad_e v_b / 6``
    (the last two in the rows of b); a revolute or prismatic column is ``F_x``'s."""
    out = F_x.copy()
    for b in _group_blocks(model):
        size = b.stop - b.start
        for j, e in enumerate(np.eye(size)):
            ad_e = _ad(e)
            column = out[:, b.start + j]
            column += F_xd[:, b] @ (ad_e @ v[b]) / 2
            column[b] += -ad_e @ vdot[b] / 2 + _ad(v[b]) @ (ad_e @ v[b]) / 6
    return out


def _differentiated(model: Model, x, xd, tau, inputs, chart: Chart | None = None) -> tuple[np.ndarray, ...]:
    """``(vdot, dF/dx, dF/dxd, dF/dinputs)`` of the chart's ``xdd = F(x, xd)`` under the generalized force ``tau`` (the
    KKT solution of eqs. 12-13 at ``a = vdot``; module docstring, "Linearization"): vdot and lam by the split's own
    solve, then the differentiated KKT system ``[[M, -Jc^T], [Jc, 0]] [dF; dlam] = [dtau - d force; -d accel]`` per
    direction, with :func:`linear_terms` (the dynamics' code differentiated) and the same scaled, rank-revealing
    :func:`_kkt`
    (unconstrained: ``dF = M^-1 (dtau - d force)`` by the Cholesky factor), and ``dF/dinputs = B_c inputs`` (eq. 17;
    ``M^-1 inputs`` unconstrained). ``dtau`` is the local chart's (:func:`_chart_force`) in the joint chart (None), 0
    in a chart ``q = psi(p)``, whose force ``tau_p`` is its own coordinate's."""
    n = model.n
    (M, Cqd, g, *_), cons = evaluate(model, x, xd, chart)
    U = _upper_factor(model, M, x, None if chart is None else chart.name)
    dtau = _chart_force(model, tau) if chart is None else np.zeros((n, n))
    if model.constraints:
        ((_, stacked),) = _scaled(model, U[None], cons.Jc[None])
        sc = _Scaled(*(a[0] for a in stacked))
        vdot, _, _, lam, _ = _constrained(sc, Cqd + g, tau, cons.bias)
        lt = linear_terms(model, x, xd, vdot, lam, chart)
        dF = _kkt(sc, np.hstack([dtau - lt.force_x, -lt.force_xd]), np.hstack([lt.accel_x, lt.accel_xd]))[0]
        return vdot, dF[:, :n], dF[:, n:], _constrained_input_map(sc) @ inputs
    _, _, vdot = _free(U, Cqd + g, tau)
    lt = linear_terms(model, x, xd, vdot, np.zeros(0), chart)
    dF = _triangular(U, _triangular(U, np.hstack([dtau - lt.force_x, -lt.force_xd, inputs]), trans=True))
    return vdot, dF[:, :n], dF[:, n:2 * n], dF[:, 2 * n:]


def linearize(model: Model, q, qd, u) -> Linearization:
    """A and B of eq. (11) (:class:`~formalisms.interface.Linearization`, x = (q, v) with the right perturbation on
    group joints) from this derivation's own exact derivatives (module docstring, "Linearization"): the differentiated
    KKT system of the joint chart (:func:`_differentiated`, input map B: ``dvdot/du = B_c B``, eq. 17) and, for
    spherical and free joints, the chain rule from the local chart to the contract's convention (:func:`_tangent`)."""
    q, qd, u = check_state(model, q, qd, u)
    vdot, F_x, F_xd, F_u = _differentiated(model, q, qd, model.input_map @ u, model.input_map)
    return state_space(model, qd, _tangent(model, F_x, F_xd, vdot, qd), F_xd, F_u, vdot)


def linearize_chart(model: Model, chart: Chart, p, pd, tau_p) -> Linearization:
    """A and B of eq. (11) in the chart ``q = psi(p)`` (article 6.4.6): x = (p, pd), ``A = [[0, I], [dpdd/dp,
    dpdd/dpd]]`` and ``B = [[0], [dpdd/dtau_p]]`` (2n x n: the input is the chart's generalized force ``tau_p``, so
    ``dpdd/dtau_p = M_p^-1``, with constraints ``B_c`` of eq. 17 in the chart), from the chart's own derivation
    differentiated (:func:`_differentiated`). The charts of :func:`split_chart` but the velocity representations
    (whose coordinates are q itself: use :func:`linearize` and the representation's map), which are
    :class:`ModelNotSupported`, as are charts of a model with group joints that do not return its whole q."""
    if _representation(model, chart) is not None:
        raise ModelNotSupported(f"Euler–Lagrange: chart '{getattr(chart, 'name', '?')}' is a velocity "
                                "representation; linearize_chart takes a chart q = psi(p) of coordinates p")
    if chart_key(model, chart) == JOINT_CHART and model.group_joints:
        raise ModelNotSupported(_NO_CHARTS.format(nq=model.nq, reason="no chart given: the joint chart (q of nq "
                                                  "entries, v of nv) is linearize's"))
    p, pd, tau_p = chart_vectors(model, p=p, pd=pd, tau_p=tau_p)
    n = model.n
    pdd, F_x, F_xd, F_u = _differentiated(model, p, pd, tau_p, np.eye(n), chart)
    return Linearization(A=np.block([[np.zeros((n, n)), np.eye(n)], [F_x, F_xd]]),
                         B=np.vstack([np.zeros((n, n)), F_u]), vdot=pdd)


FORMALISM = Formalism(
    name="euler_lagrange",
    summary="symbolic energies T, V; M = Hessian of T, C qd = d/dt dT/dqd - dT/dq (Lagrange's equation), g = dV/dq; "
            "re-derived in any chart q = psi(p) (6.4.6); ball and free joints in local exponential coordinates at "
            "xi = 0 (2.1-2.2), or through R(quat(psi(p))) in a chart of the group (zyx); constraints by a scaled, "
            "rank-revealing KKT solve (5.6)",
    split=split,
    split_chart=split_chart,
    split_batch=split_batch,
    evaluation=evaluation,
    preparation=preparation_estimate,
    prepare=prepare,
    linearize=linearize,
    linearize_chart=linearize_chart,
)
