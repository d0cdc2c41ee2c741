"""Operational-space formalism (article 6.3): the dynamics seen from a task point, in Jacobian language.

Kinematics (world frame, frames of ``cases.model``): ``X_body = X_parent * (rotation, translation) * motion(q_i)``
gives every body's rotation ``R_i`` and origin ``o_i``; joint ``j`` has the world axis ``z_j`` and, when
revolute, the origin ``o_j`` (a rotation about the axis leaves the body origin on it). Joint ``j`` moves body
``i`` when it is ``i``'s own joint or an ancestor's. A point ``p`` fixed in body ``i`` has the geometric Jacobian

    linear column j:   z_j x (p - o_j)  (revolute)   or   z_j  (prismatic)
    angular column j:  z_j              (revolute)   or   0

and the CLASSICAL bias ``Jdot qd`` (the point's acceleration at ``qdd = 0``, docs/design.md) is the sum of the
analytic column derivatives times ``qd_j``: with ``zdot_j = w_j x z_j`` (the axis is fixed in body ``j`` and, for
a revolute joint, in its parent too), a revolute column changes by ``zdot_j x (p - o_j) + z_j x (pdot - odot_j)``
and a prismatic one by ``zdot_j``. Velocities are Jacobian sums as well: ``w_i = sum_j z_j qd_j`` over the
revolute joints moving ``i``, ``odot_i = J_v(o_i) qd``.

Column offsets: a revolute linear column is ``z_j x p + c_j`` with ``c_j = o_j x z_j`` (a prismatic one is
``c_j = z_j``), so every column sum over the joints moving body ``i`` splits into a part of the point and a part of
the body: ``J_v qd = w_i x p + sum_j c_j qd_j`` and ``Jdot_v qd = (Jdot_w qd)_i x p + w_i x pdot + sum_j cdot_j
qd_j``, with ``cdot_j = odot_j x z_j + o_j x zdot_j`` (``zdot_j`` prismatic). The kinematics keeps the three body
sums, ``Jdot_w qd``, ``sum c_j qd_j`` and ``sum cdot_j qd_j``; a point's velocity and bias then cost O(1), not a
sum over the joints per point.

Spherical and free joints (article 2.1-2.2: a configuration on the Lie groups SO(3) and SE(3); conventions of
``cases.model``, Pinocchio's). The velocities ``qd`` (``nv`` of them) are not the derivatives of the coordinates ``q``
(``nq``, with unit quaternions ``(x, y, z, w)``), so the Jacobians are over the velocities: a "column" above is one
velocity, and a joint owns one column per velocity. The poses use ``motion(q_i) = (R(quat), 0)`` (spherical) or
``(R(quat), p)`` (free), ``R(quat) = I + 2 w [x y z]x + 2 [x y z]x^2`` formed here, so body ``i`` on such a joint
has ``R_i = R_joint R(quat)`` and ``o_i = o_joint`` (spherical) or ``o_joint + R_joint p`` (free), ``R_joint`` and
``o_joint`` its joint frame in the world. Its velocities are in the body frame: a spherical joint's ``v_i`` is the
body's angular velocity relative to its joint frame, a free joint's ``(R(quat)^T pdot, omega)`` the body twist
(article 6.2: linear velocity of the body origin, then angular velocity). Their world images are ``R_i v``, so
each velocity is a column along a body axis ``z = R_i e_a`` (a column of ``R_i``):

    angular velocity a (spherical, free):  a ROTATION column about ``z = R_i e_a`` through ``o_i``, exactly a
                                           revolute column (linear ``z x (p - o_i)``, angular ``z``)
    linear velocity a (free):              a TRANSLATION column along ``z = R_i e_a``, as a prismatic one
                                           (linear ``z``, angular 0): ``R_i (R(quat)^T pdot) = R_joint pdot``

(``R_i v_lin = R_joint pdot`` is the body origin's velocity relative to the joint frame; the rotation columns pass
through ``o_i``: the body twist's angular part turns the body about its origin.) So every formula above holds column by
column, with ``o_j`` the owning body's origin and ``zdot_k = w_j x z_k`` the rate of an axis fixed in body ``j``
(for a revolute or prismatic joint ``w_j x z_j`` is its parent's ``w x z_j``, the same vector). The classical bias is
the time derivative of the columns along the motion, times the velocities, which is what the accelerations of a
state need: they are ``d/dt`` of the velocities (``vdot``, not ``qdd``), and ``pddot = J vdot + Jdot v`` holds for
any velocities. Kane's projection below holds for such generalized speeds too (article 6.4: M is the kinetic-energy
metric in the frame of the velocities), so ``M`` is ``nv x nv``, ``C qd``, ``g``, ``B``, ``Jc`` have ``nv``
columns or entries, and nothing downstream of the kinematics changes. A joint coupling relates one-number
coordinates only (``cases.model``): its row uses ``q_index`` and ``v_index``. No chart is evaluated here
(``FORMALISM.split_chart`` is None), so joint-coordinate charts never reach this backend. The task point may sit on
any body (below a free base or a ball joint); a task with more rows than directions its point can move in is
singular at every state, e.g. three task directions on a body hanging from a fixed ball joint (the point cannot move
along its radius): a BREAKDOWN there (below), as the stretched double pendulum is at one configuration.

Batches: every function below takes one state or a batch (a leading axis ``...`` on each state-dependent array);
``split`` evaluates one state, ``split_batch`` blocks of states, through the same code, and ``split_many`` (the block
form of ``split``, ``formalisms.interface.with_block_form``) the whole split of each state of a block.

Joint-space terms by projection (Kane's form), from the COM Jacobians ``J_v,i`` and ``J_w,i``:

    M    = sum_i m_i J_v,i^T J_v,i + J_w,i^T I_i J_w,i + diag(a)               (I_i: COM inertia, world)
    C qd = sum_i m_i J_v,i^T (Jdot_v,i qd) + J_w,i^T (I_i Jdot_w,i qd + w_i x I_i w_i)
    g    = -sum_i m_i J_v,i^T gravity

Armature: ``a`` holds each joint's rotor inertia (``Body.armature``) on every one of its columns; a rotor geared to
the joint moves with that column's rate alone (a constant Jacobian, the unit column), so Kane's projection adds
``diag(a)`` to M and nothing to C qd or g. Everything below that uses M (its inverse, the task-space ``Lambda``,
``mu``, ``p``, the dynamically consistent inverse, the constraint space) uses this M.

External loads (``cases.loads``; article 2.3, eq. 12) by virtual work through the same point Jacobians:
``tau_ext = sum J_v(p)^T f + J_w^T m`` (:func:`_external_force`; ``f``, ``m`` in the world: a body-frame vector is
``R_i x``, a spring's force ``-k (|d| - L0) d / |d|`` from the point's world position). Being velocity-independent it
joins gravity, ``g - tau_ext``, wherever g enters below (the task-space ``p`` of eq. 22 included), so the drift, its
part at rest and the recomposition carry it; the linearization differentiates it with the rest (dual numbers).

Task space (eq. 22) for ``x_task = D p``: ``J = D J_v(p)``, ``A = J M^-1 J^T = Lambda^-1``,
``mu = Lambda (J M^-1 C qd - Jdot qd)``, ``p = Lambda J M^-1 g``, ``J_bar = M^-1 J^T Lambda`` (the dynamically
consistent inverse), ``N = 1 - J_bar J``, ``F_ctrl = J_bar^T B u``. Eq. (22) solved for the task acceleration:
``xdd = A (F - mu - p)``. With ``F = J_bar^T tau`` this is

    xdd = J M^-1 tau - J M^-1 C qd + Jdot qd - J M^-1 g = J M^-1 (tau - h) + Jdot qd,

so at ``tau = 0`` it is eq. (23): ``xdd_drift = J qdd_drift + Jdot qd``.

The joint answer is RECOMPOSED from task space plus the dynamically consistent null-space part:

    qdd = J_bar (xdd - Jdot qd) + M^-1 N^T (tau - h)
        = [M^-1 J^T Lambda J M^-1 + M^-1 - M^-1 J^T Lambda J M^-1] (tau - h) = M^-1 (tau - h),

(using ``xdd - Jdot qd = J M^-1 (tau - h)`` and ``N^T = 1 - J^T Lambda J M^-1``): drift at ``tau = 0``, total at
``tau = B u``, and ctrl, the control increment computed directly, ``J_bar xdd_ctrl + M^-1 N^T B u`` with
``xdd_ctrl = A F_ctrl = J M^-1 B u`` (no bias). For a square task Jacobian (the double pendulum's endpoint)
``J_bar = J^-1`` and ``N = 0``: the joint acceleration comes entirely from task space. The drift's parts (article
4.5-4.6) are recomposed the same way, each directly: the zero-velocity counterfactual ``zvcf = J_bar xdd_zvcf - M^-1
N^T g`` with ``xdd_zvcf = -A p`` (no ``Jdot qd`` at ``qd = 0``), and ``drift_velocity = J_bar (xdd_velocity - Jdot
qd) - M^-1 N^T C qd`` with ``xdd_velocity = -A mu``: ``-M^-1 g`` and ``-M^-1 C qd``, which add up to the drift.

Breakdown (6.3.4): the method inverts ``A``, so every result carries ``cond = cond_2(A)`` (``Split.conditions
["task"]``) and how much the recomposition amplifies the task bias's rounding (``"task_jacobian"``, numerics below); the
harness declares states above their limits a BREAKDOWN. Where ``A`` is numerically singular (its
smallest eigenvalue is not positive, not finite, or below ``k eps lambda_max``, eigvalsh's absolute accuracy for
a k x k matrix, so indistinguishable from zero) ``cond`` is ``inf`` and every task-space quantity and joint
acceleration is NaN: no crash, and no plausible-looking garbage.

Constraints (article 5, eqs. 12-17; in operational space they are the ``F_constr`` of eq. 22, article 7.2): ``phi``,
``Jc`` and ``Jcdot qd`` come from the same point kinematics as the task, the world position, ``J_v`` and classical
bias of each constrained point, combined row by row as ``cases.constraints`` fixes them (a circle:
``d = P (p - c)``, ``phi = d.d - R^2``, ``Jc = 2 d^T P J_v``, ``Jcdot qd = 2 |P J_v qd|^2 + 2 d^T P (Jdot_v qd)``).
The constraint is treated as a second operational space with its own inertia (Khatib's constraint space):
``Lambda_c = S^+`` with ``S = Jc M^-1 Jc^T``, the pseudo-inverse from S's eigendecomposition without the
eigen-directions below ``CONSTRAINT_RCOND`` times the largest eigenvalue (redundant or degenerate rows give the
minimum-norm multipliers). With ``a`` the free accelerations recomposed as above, eq. (13) gives

    lam = Lambda_c (-Jcdot qd - Jc a)    (total: a = M^-1 (B u - h); drift, eq. 14: a = -M^-1 h)
    lam_ctrl = -Lambda_c Jc M^-1 B u      (the reaction to the input alone, eq. 15's lam - lam_0)

and the generalized constraint forces ``Jc^T lam`` enter eq. (22) as ``F_constr = J_bar^T Jc^T lam`` beside
``F_ctrl``: the same recomposition with ``tau + Jc^T lam`` for ``tau`` returns ``qdd = a + M^-1 Jc^T lam``. For the
control part that is eq. (17), ``ctrl = B_c B u = M^-1 [I - Jc^T Lambda_c Jc M^-1] B u``, computed directly from
``M^-1 B u`` (never ``total - drift``). Degenerate but consistent rows still give a unique ``qdd`` and ``Jc^T lam``;
inconsistent ones (``H_t`` empty, eq. 16) finite least-squares numbers, which the harness flags from the conditions
:func:`constrained_split` adds. A singular task space keeps its meaning: every acceleration is NaN there, with or
without constraints.

Reported numbers, all computed here from this backend's own M, ``M^-1``, ``C qd``, g, Jc, ``Jcdot qd`` and task
Jacobian (the interface supplies only types and validators): ``cond_2(M) = ||M|| ||M^-1||`` with each norm the largest
eigenvalue of its own matrix, the projected M and the inverse every solve goes through; cond S, the kept cond, the
rank and the consistency of ``S lam = r`` from the eigendecomposition of S that ``Lambda_c`` inverts; the task
inertia and ``cond(A)`` from the eigendecomposition of ``A`` that eq. (22) is solved in; the control power in input
space ``u . (B^T qd)`` and the constraint power in constraint space ``lam . (Jc qd)``.

Numerics: near a singularity ``Lambda``, ``mu``, ``p`` and ``F_ctrl`` grow like ``1 / lambda_min(A)`` along the
lost direction. In the model's task coordinates their rounding lands in every component, ``A``'s large
eigenvalue turns it into an ``eps cond(A)`` error of ``xdd``, and ``J_bar`` (norm ~ ``sqrt(cond(A))``) amplifies it
again: ``eps cond(A)^1.5`` was measured. So eq. (22) is evaluated and solved in the principal axes of ``A``
(``x' = V^T x``, ``Lambda' = diag(1 / eig)``), where each component keeps its own relative precision, and the
results are rotated back. What remains is inherent to the recomposition: ``Jdot qd`` has an O(1) component along
the lost direction while ``J qdd`` there is O(sigma_min(J)), so ``xdd - Jdot qd`` cancels and ``J_bar`` amplifies
the rounding: a joint error of about ``eps |Jdot qd| sqrt(cond(A) / lambda_max(A))``, the error the breakdown
limit is calibrated against (tests/backends/test_operational_space.py).

Linearization (article 4.8, eq. 11; :func:`linearize`) by forward-mode differentiation of the passes above: ``q`` and
``qd`` enter as dual numbers (:class:`_Dual`: a value and its tangents along all ``2 nv`` state directions at once,
the configuration directions ``d/ds integrate(q, s e_j)`` of the interface's right-perturbation convention), and the
kinematics, the Kane projection and the constraint rows run on them unchanged: their primitives (``_cross``, ``_t``,
the stacks, ``_where``, the rotation builders) accept dual numbers, sums add tangents and every product is bilinear
(the product rule by broadcasting over the tangent axis). That gives ``dM``, ``d(C qd)``, ``dg``, ``dJc`` and
``d(Jcdot qd)`` exactly (no differences). The solve is differentiated in joint-space form, which the recomposition
equals: ``M dvdot + dM vdot + dh = Jc^T dlam + dJc^T lam`` and ``Jc dvdot + dJc vdot + d(Jcdot qd) = 0``, solved
through the constraint space like the multipliers (``dlam = Lambda_c (r - Jc M^-1 f)``, minimum norm over redundant
directions); ``dvdot/du = B_c B`` (eq. 17).
"""

from __future__ import annotations

from dataclasses import dataclass, fields

import numpy as np

from cases.constraints import (JointCoupling, KnifeEdge, PointOnCircle, PointOnLine, PointsCoincide, PointVelocity,
                               RollingContact)
from cases.loads import ExternalWrench, PointSpring
from cases.model import Model
from formalisms.interface import (CONSTRAINT_RCOND, DEGENERATE_ROW, Formalism, Linearization, Split, SplitBatch,
                                  check_batch, check_state, state_space, with_block_form)


@dataclass(frozen=True)
class Kinematics:
    """World-frame kinematics of every body at ``(q, qd)``, of one state or, with a leading batch axis ``...`` on
    every state-dependent field, of a batch of states. Rows ``b`` are bodies, rows ``n`` velocity columns (one per
    entry of ``qd``; with revolute and prismatic joints only, column ``i`` is body ``i``'s joint).

    R (..., b, 3, 3) world <- body rotations; o (..., b, 3) body origins; z (..., n, 3) column axes; revolute (n,)
    column kinds (a rotation column, module docstring: revolute, or an angular velocity of a spherical or free joint;
    else a translation); moves (b, n) ``moves[i, k]``: column ``k`` moves body ``i`` (its joint is ``i``'s own or an
    ancestor's); qd (..., n) velocities; w (..., b, 3) angular velocities; odot (..., b, 3) origin velocities;
    zdot (..., n, 3) axis rates ``w_j x z_k`` (``j`` the column's body); the sums over the columns moving each body
    (..., b, 3) (module docstring, column offsets): w_bias = ``Jdot_w qd`` = sum ``zdot_k qd_k`` (rotation columns),
    c_qd = sum ``c_k qd_k``, cdot_qd = sum ``cdot_k qd_k``; owner (n,) the body of each column and column_origin
    (..., n, 3) its origin ``o_j`` (the point a rotation column turns about).
    """

    R: np.ndarray
    o: np.ndarray
    z: np.ndarray
    revolute: np.ndarray
    moves: np.ndarray
    qd: np.ndarray
    w: np.ndarray
    odot: np.ndarray
    zdot: np.ndarray
    w_bias: np.ndarray
    c_qd: np.ndarray
    cdot_qd: np.ndarray
    owner: np.ndarray
    column_origin: np.ndarray


@dataclass(frozen=True)
class TaskSpace:
    """The task-space quantities of eq. (22) at one state (or a batch: a leading axis ``...`` on every field), for
    one task point (k task coordinates).

    J (k, n), Jdot_qd (k,) classical bias, A = J M^-1 J^T (k, k), Lambda = A^-1, mu, p (k,), J_bar (n, k),
    N (n, n), F_ctrl = J_bar^T B u (k,), F_constr and F_constr_drift = J_bar^T Jc^T lam (k,) with and without input
    (zero without constraints), xdd_drift = A (F_constr_drift - mu - p) (eq. 23), xdd_ctrl = A (F_ctrl + J_bar^T
    Jc^T lam_ctrl), xdd_total = A (F_ctrl + F_constr - mu - p) (k,), the drift's parts (article 4.5-4.6)
    xdd_zvcf = A (F_constr_zvcf - p) (gravity's, at qd = 0) and xdd_velocity = A (F_constr_velocity - mu) (the
    velocity products'), with ``F_constr_zvcf``, ``F_constr_velocity`` the images of their multipliers (not kept),
    cond = cond_2(A).
    Everything but J, Jdot_qd and A is NaN where ``cond`` is inf (A numerically singular).
    """

    J: np.ndarray
    Jdot_qd: np.ndarray
    A: np.ndarray
    Lambda: np.ndarray
    mu: np.ndarray
    p: np.ndarray
    J_bar: np.ndarray
    N: np.ndarray
    F_ctrl: np.ndarray
    F_constr: np.ndarray
    F_constr_drift: np.ndarray
    xdd_drift: np.ndarray
    xdd_ctrl: np.ndarray
    xdd_total: np.ndarray
    xdd_zvcf: np.ndarray
    xdd_velocity: np.ndarray
    cond: float | np.ndarray


class _Dual:
    """A dual number for the forward-mode derivatives of eq. (11) (:func:`linearize`): a value ``val`` (...) and its
    tangents ``tan`` (D, ...) along D directions at once. Sums add the tangents; the backend's products (elementwise,
    ``@``) are bilinear, ``f(a, b)`` with the tangent ``f(da, b) + f(a, db)`` (the product rule), which the stacked
    tangents get by broadcasting over their leading axis. Indexing must start with ``...`` (the tangent axis leads)."""

    __array_ufunc__ = None                                   # numpy defers ndarray (op) _Dual to the methods below
    __slots__ = ("val", "tan")

    def __init__(self, val, tan):
        self.val, self.tan = np.asarray(val), np.asarray(tan)

    @property
    def shape(self) -> tuple:
        return self.val.shape

    def lifted(self, ndim: int) -> np.ndarray:
        """The tangents with singleton axes after the leading one, so they broadcast like a value of ``ndim`` axes."""
        extra = ndim - self.val.ndim
        return self.tan.reshape(self.tan.shape[:1] + (1,) * extra + self.val.shape) if extra > 0 else self.tan

    def __getitem__(self, key):
        if not (key is Ellipsis or (isinstance(key, tuple) and key and key[0] is Ellipsis)):
            raise IndexError(f"a dual number is indexed from the right (key starting with ...), got {key!r}")
        return _Dual(self.val[key], self.tan[key])

    def reshape(self, shape) -> "_Dual":
        val = self.val.reshape(shape)
        return _Dual(val, self.tan.reshape(self.tan.shape[:1] + val.shape))

    def __neg__(self):
        return _Dual(-self.val, -self.tan)

    def __add__(self, other):
        return _sum_of(self, other, 1.0)

    def __radd__(self, other):
        return _sum_of(other, self, 1.0)

    def __sub__(self, other):
        return _sum_of(self, other, -1.0)

    def __rsub__(self, other):
        return _sum_of(other, self, -1.0)

    def __mul__(self, other):
        return _bilinear(np.multiply, self, other)

    def __rmul__(self, other):
        return _bilinear(np.multiply, other, self)

    def __matmul__(self, other):
        return _bilinear(np.matmul, self, other)

    def __rmatmul__(self, other):
        return _bilinear(np.matmul, other, self)


def _value(x):
    """The value of a dual number, or ``x`` itself."""
    return x.val if isinstance(x, _Dual) else x


def _tangents(x, shape: tuple, count: int) -> np.ndarray:
    """The tangents of ``x`` broadcast to a value of ``shape`` (``count`` directions; zero for a constant)."""
    if not isinstance(x, _Dual):
        return np.zeros((count,) + shape)
    return x.tan if x.val.shape == shape else np.broadcast_to(x.lifted(len(shape)), (count,) + shape)


def _count(xs) -> int | None:
    """The number of tangent directions of the dual numbers among ``xs``, None when all are constants."""
    return next((x.tan.shape[0] for x in xs if isinstance(x, _Dual)), None)


def _sum_of(a, b, sign: float):
    """``a + sign b`` (sign 1 or -1) with the tangents added."""
    val = _value(a) + _value(b) if sign > 0 else _value(a) - _value(b)
    count = _count((a, b))
    ta, tb = _tangents(a, val.shape, count), _tangents(b, val.shape, count)
    return _Dual(val, ta + tb if sign > 0 else ta - tb)


def _bilinear(f, a, b):
    """``f(a, b)`` of a bilinear ``f`` (elementwise product, matmul) with the tangent ``f(da, b) + f(a, db)``."""
    av, bv = _value(a), _value(b)
    val = f(av, bv)
    tan = 0.0
    if isinstance(a, _Dual):
        tan = f(a.lifted(val.ndim), bv)
    if isinstance(b, _Dual):
        tan = tan + f(av, b.lifted(val.ndim))
    return _Dual(val, tan)


def _linear(f, x):
    """``f(x)`` of an axis-wise linear map ``f`` (a transpose, a sum over negative axes), tangents mapped alike."""
    return _Dual(f(x.val), f(x.tan)) if isinstance(x, _Dual) else f(x)


def _stack(xs, axis: int, shape: tuple | None = None):
    """``np.stack`` over a negative ``axis`` of arrays and dual numbers, each broadcast to ``shape`` (default: their
    common shape) first; arrays alone are written into one allocation (the stack's cost in the split)."""
    shape = np.broadcast_shapes(*(np.shape(_value(x)) for x in xs)) if shape is None else shape
    count = _count(xs)
    if count is None:
        cut = len(shape) + axis + 1
        out = np.empty(shape[:cut] + (len(xs),) + shape[cut:])
        for k, x in enumerate(xs):
            out[(Ellipsis, k) + (slice(None),) * (-axis - 1)] = x
        return out
    vals = [np.broadcast_to(_value(x), shape) for x in xs]
    return _Dual(np.stack(vals, axis=axis), np.stack([_tangents(x, shape, count) for x in xs], axis=axis))


def _concatenate(xs, axis: int):
    """``np.concatenate`` over a negative ``axis`` of arrays and dual numbers."""
    count = _count(xs)
    if count is None:
        return np.concatenate(xs, axis=axis)
    return _Dual(np.concatenate([_value(x) for x in xs], axis=axis),
                 np.concatenate([_tangents(x, np.shape(_value(x)), count) for x in xs], axis=axis))


def _where(mask: np.ndarray, a, b):
    """``np.where`` with a constant ``mask`` over arrays and dual numbers."""
    val = np.where(mask, _value(a), _value(b))
    count = _count((a, b))
    if count is None:
        return val
    return _Dual(val, np.where(mask, _tangents(a, val.shape, count), _tangents(b, val.shape, count)))


def _sin_cos(x) -> tuple:
    """``(sin x, cos x)`` of an array or a dual number (``d sin = cos dx``, ``d cos = -sin dx``)."""
    if not isinstance(x, _Dual):
        return np.sin(x), np.cos(x)
    s, c = np.sin(x.val), np.cos(x.val)
    return _Dual(s, c * x.tan), _Dual(c, -s * x.tan)


def _cross(a, b):
    """``a x b`` over the last axis of stacked 3-vectors (or dual numbers), broadcasting (np.cross pays for axis
    handling)."""
    return _stack([a[..., i] * b[..., j] - a[..., j] * b[..., i] for i, j in ((1, 2), (2, 0), (0, 1))], -1)


def _t(A):
    """The transposes of stacked matrices (..., r, c) -> (..., c, r)."""
    return _linear(lambda x: np.swapaxes(x, -1, -2), A)


def _mv(A, x):
    """``A x`` for stacked matrices (..., r, c) and vectors (..., c), broadcasting."""
    return (A @ x[..., None])[..., 0]


def _vm(x: np.ndarray, A: np.ndarray) -> np.ndarray:
    """``x^T A`` for stacked vectors (..., r) and matrices (..., r, c), broadcasting: each state's vector-matrix
    product on its own, the very product of one state (``x @ A`` on a stack of rows is one matrix product, whose
    rounding may differ from the single state's)."""
    return (x[..., None, :] @ A)[..., 0, :]


def _diag(x: np.ndarray) -> np.ndarray:
    """Stacked diagonal matrices (..., k, k) with the diagonals ``x`` (..., k)."""
    out = np.zeros(x.shape + x.shape[-1:])
    out[..., np.arange(x.shape[-1]), np.arange(x.shape[-1])] = x
    return out


def _flat(columns: np.ndarray) -> np.ndarray:
    """Stacked per-body Jacobians (..., b, 3, n) as one (..., 3 b, n) matrix."""
    *batch, b, rows, n = columns.shape
    return columns.reshape((*batch, b * rows, n))


def _axis_rotations(axes: np.ndarray, angles: np.ndarray) -> np.ndarray:
    """Rotations by ``angles`` (..., n) about the unit ``axes`` (n, 3) (Rodrigues), stacked (..., n, 3, 3)."""
    x, y, z = axes.T
    zero = np.zeros_like(x)
    K = np.stack([np.stack([zero, -z, y], -1), np.stack([z, zero, -x], -1), np.stack([-y, x, zero], -1)], -2)
    sin, cos = _sin_cos(angles)
    return np.eye(3) + sin[..., None, None] * K + (1.0 - cos)[..., None, None] * (K @ K)


def _quaternion_rotations(quat: np.ndarray) -> np.ndarray:
    """``R(quat) = I + 2 w [v]x + 2 [v]x^2`` (stacked (..., 3, 3)) of unit quaternions ``(x, y, z, w) = (v, w)``
    (..., 4) (``cases.model``; article 2.1: a spherical joint's configuration on SO(3))."""
    x, y, z, w = (quat[..., a] for a in range(4))
    zero = np.zeros(np.shape(_value(x)))
    K = _stack([_stack([zero, -z, y], -1), _stack([z, zero, -x], -1), _stack([-y, x, zero], -1)], -2)
    return np.eye(3) + 2.0 * w[..., None, None] * K + 2.0 * (K @ K)


def _columns(model: Model) -> tuple[np.ndarray, np.ndarray]:
    """``(owner, rotation)``: the body of each velocity column (n,) and whether it is a rotation column (module
    docstring, group joints): a revolute joint's, and the angular velocities of spherical and free joints; the
    prismatic and the free joints' linear velocities are translation columns."""
    owner, rotation = [], []
    for i, body in enumerate(model.bodies):
        kinds = {"revolute": (True,), "prismatic": (False,), "spherical": (True,) * 3,
                 "free": (False,) * 3 + (True,) * 3}[body.joint]
        owner += [i] * len(kinds)
        rotation += kinds
    return np.array(owner, dtype=int), np.array(rotation, dtype=bool)


def _moves(model: Model) -> np.ndarray:
    """``moves[i, k]`` (bodies x velocity columns): column ``k`` belongs to body ``i``'s own joint or to one of its
    ancestors' joints."""
    owner, _ = _columns(model)
    moves = np.zeros((len(model.bodies), model.n), dtype=bool)
    for i in model.topological_order:
        p = model.parent_index[i]
        if p >= 0:
            moves[i] = moves[p]
        moves[i, owner == i] = True
    return moves


def _column_offsets(z: np.ndarray, o: np.ndarray, revolute: np.ndarray) -> np.ndarray:
    """The constant parts ``c_j`` (..., n, 3) of the linear Jacobian columns ``z_j x p + c_j``: ``o_j x z_j``
    (revolute: ``z_j x (p - o_j)``) or ``z_j`` (prismatic, whose columns have no ``z_j x p`` part)."""
    return _where(revolute[:, None], _cross(o, z), z)


def _linear_columns(z, o, revolute, moves_rows, points) -> np.ndarray:
    """Linear Jacobians (..., k, 3, n) of world points (..., k, 3): column ``z_j x (p - o_j) = z_j x p + o_j x z_j``
    (revolute) or ``z_j`` (prismatic) for the joints in ``moves_rows`` (k, n), zero elsewhere; ``z``, ``o``
    (..., n, 3). Built row by row (x, y, z) from the axes and the points, one (..., k, n) product per term."""
    zr = (z * revolute[:, None])[..., None, :, :]
    c = _column_offsets(z, o, revolute)[..., None, :, :]
    p = points[..., :, None, :]
    return _stack([(zr[..., a] * p[..., b] - zr[..., b] * p[..., a] + c[..., axis]) * moves_rows
                   for axis, (a, b) in enumerate(((1, 2), (2, 0), (0, 1)))], -2)


def _angular_columns(kin: Kinematics, body: np.ndarray) -> np.ndarray:
    """Angular Jacobians (..., k, 3, n) of bodies ``body`` (k,): column ``z_j`` for the revolute joints moving
    them, zero elsewhere."""
    axes = _t(kin.z * kin.revolute[:, None])
    axes = axes if isinstance(axes, _Dual) else np.ascontiguousarray(axes)
    return axes[..., None, :, :] * kin.moves[body][:, None, :]


def kinematics(model: Model, q, qd) -> Kinematics:
    """World poses from ``X_body = X_parent * (rotation, translation) * motion(q_i)`` (``q`` of ``nq`` entries, the
    quaternions of spherical and free joints turned into rotations here); angular velocities, origin velocities and
    axis rates as sums over the velocity columns (``qd`` of ``nv`` entries; module docstring)."""
    q, qd, _ = check_state(model, q, qd, np.zeros(model.m))
    return _kinematics(model, q, qd)


def _kinematics(model: Model, q: np.ndarray, qd: np.ndarray) -> Kinematics:
    n, batch, count = model.n, q.shape[:-1], len(model.bodies)
    owner, revolute = _columns(model)
    turns = np.array([b.joint == "revolute" for b in model.bodies])
    axes = np.array([b.axis for b in model.bodies])
    local = np.array([b.rotation for b in model.bodies])
    plain = not model.group_joints                    # one column per body: column rows are body rows
    motion = _axis_rotations(axes, _where(turns, q if plain else q[..., list(model.q_index)], 0.0))
    R, o, z = [None] * count, [None] * count, [None] * n           # per body and column, stacked below
    for i in model.topological_order:
        b, p, k, j = model.bodies[i], model.parent_index[i], model.v_index[i], model.q_index[i]
        if p < 0:
            joint_frame, o_joint = local[i], b.translation
        else:
            joint_frame, o_joint = R[p] @ local[i], o[p] + R[p] @ b.translation
        if b.joint == "spherical" or b.joint == "free":       # module docstring, group joints
            free = b.joint == "free"
            R[i] = joint_frame @ _quaternion_rotations(q[..., j + 3 * free:j + 3 * free + 4])
            o[i] = (o_joint + _mv(joint_frame, q[..., j:j + 3])) if free else o_joint
            z[k:k + 3 + 3 * free] = [R[i][..., :, a % 3] for a in range(3 + 3 * free)]
            continue
        z[k] = joint_frame @ axes[i]
        R[i] = joint_frame @ motion[..., i, :, :]
        o[i] = o_joint if turns[i] else o_joint + q[..., j, None] * z[k]
    R, o, z = _stack(R, -3, batch + (3, 3)), _stack(o, -2, batch + (3,)), _stack(z, -2, batch + (3,))
    moves = _moves(model)
    of_columns = (lambda rows: rows) if plain else (lambda rows: rows[..., owner, :])   # body rows -> column rows
    origin = of_columns(o)
    rates, revolute_rates = moves * qd[..., None, :], moves * _where(revolute, qd, 0.0)[..., None, :]
    w = revolute_rates @ z
    c_qd = rates @ _column_offsets(z, origin, revolute)
    odot = _cross(w, o) + c_qd
    zdot = _cross(of_columns(w), z)
    cdot = _where(revolute[:, None], _cross(of_columns(odot), z) + _cross(origin, zdot), zdot)
    return Kinematics(R, o, z, revolute, moves, qd, w, odot, zdot, revolute_rates @ zdot, c_qd, rates @ cdot,
                      owner, origin)


def point_jacobian(kin: Kinematics, body: np.ndarray, points: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Geometric Jacobians ``(J_v, J_w)``, each (..., k, 3, n), of the world points ``points`` (..., k, 3) fixed in
    bodies ``body`` (k,): linear column ``z_j x (p - o_j)`` (revolute) or ``z_j`` (prismatic), angular column
    ``z_j`` (revolute) or 0, for every joint ``j`` moving the body; zero columns elsewhere."""
    return (_linear_columns(kin.z, kin.column_origin, kin.revolute, kin.moves[body], points),
            _angular_columns(kin, body))


def point_velocity(kin: Kinematics, body: np.ndarray, points: np.ndarray) -> np.ndarray:
    """``J_v qd`` (..., k, 3) of world points fixed in bodies ``body``: the column sum ``sum_j (z_j x p + c_j) qd_j
    = w x p + sum_j c_j qd_j`` (module docstring, column offsets)."""
    return _cross(kin.w[..., body, :], points) + kin.c_qd[..., body, :]


def point_bias(kin: Kinematics, body: np.ndarray, points: np.ndarray, velocities: np.ndarray) -> np.ndarray:
    """The CLASSICAL bias ``Jdot qd`` (..., k, 3) of world points fixed in bodies ``body`` moving with
    ``velocities``: the second time derivative of each point's position at ``qdd = 0``, the sum of the column
    derivatives ``(zdot_j x p + z_j x pdot + cdot_j) qd_j`` (revolute; ``zdot_j qd_j`` prismatic), that is
    ``Jdot_w qd x p + w x pdot + sum_j cdot_j qd_j`` (module docstring, column offsets)."""
    return (_cross(kin.w_bias[..., body, :], points) + _cross(kin.w[..., body, :], velocities)
            + kin.cdot_qd[..., body, :])


def _world_inertia(R: np.ndarray, inertia: np.ndarray) -> np.ndarray:  # noqa: N803
    """The COM inertias (..., n, 3, 3) rotated from the body frames to the world: ``R I R^T``."""
    return R @ inertia @ _t(R)


def _gyroscopic(inertia: np.ndarray, w: np.ndarray) -> np.ndarray:
    """The gyroscopic moments ``w x (I w)`` (..., n, 3) of bodies with world inertias ``I`` and angular velocities
    ``w``."""
    return _cross(w, _mv(inertia, w))


def _terms(model: Model, kin: Kinematics) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """``M``, ``C qd``, ``g`` projected from the COM Jacobians (Kane's form, module docstring), the linear terms
    through ``sqrt(m_i) J_v,i``. Bodies without mass skip the linear terms, bodies without rotational inertia (point
    masses) the angular ones."""
    mass = np.array([b.mass for b in model.bodies])
    inertia = np.array([b.inertia for b in model.bodies])
    heavy, spinning = np.flatnonzero(mass > 0.0), np.flatnonzero(np.abs(inertia).sum(axis=(1, 2)) > 0.0)
    com = kin.o[..., heavy, :] + _mv(kin.R[..., heavy, :, :], np.array([model.bodies[i].com for i in heavy]))
    root_m = np.sqrt(mass[heavy])[:, None]
    Jv = _flat(_linear_columns(kin.z, kin.column_origin, kin.revolute, kin.moves[heavy], com) * root_m[..., None])
    a_bias = root_m * point_bias(kin, heavy, com, point_velocity(kin, heavy, com))
    I_world = _world_inertia(kin.R[..., spinning, :, :], inertia[spinning])
    Jw = _angular_columns(kin, spinning)
    torque = _mv(I_world, kin.w_bias[..., spinning, :]) + _gyroscopic(I_world, kin.w[..., spinning, :])
    Jw_flat, JvT = _flat(Jw), _t(Jv)
    M = JvT @ Jv + _t(Jw_flat) @ _flat(I_world @ Jw)
    Cqd = _mv(JvT, _flat(a_bias[..., None])[..., 0]) + _mv(_t(Jw_flat), _flat(torque[..., None])[..., 0])
    g = -(root_m * model.gravity).reshape(-1) @ Jv
    return 0.5 * (M + _t(M)) + np.diag(_rotor_inertias(model)), Cqd, g


def _rotor_inertias(model: Model) -> np.ndarray:
    """The joints' rotors (module docstring, "Armature"): each body's ``armature`` on every column of its joint
    (one for a revolute or prismatic joint, three for a ball, six for a free joint), in the velocities' order."""
    columns = {"revolute": 1, "prismatic": 1, "spherical": 3, "free": 6}
    return np.repeat([b.armature for b in model.bodies], [columns[b.joint] for b in model.bodies]).astype(float)


def _sqrt(x):
    """``sqrt(x)`` of an array or a dual number (``d sqrt(x) = dx / (2 sqrt(x))``)."""
    if not isinstance(x, _Dual):
        return np.sqrt(x)
    root = np.sqrt(x.val)
    return _Dual(root, x.tan / (2.0 * root))


def _spring_force(load, p):
    """The world force ``-k (|d| - L0) d / |d|`` of a :class:`~cases.loads.PointSpring` at its point ``p`` (..., 3)
    (an array or a dual number), ``d = p - anchor``; ``-k d`` when ``L0 = 0``."""
    d = p - np.asarray(load.anchor, dtype=float)
    if not load.rest_length:
        return -load.stiffness * d
    length = _sqrt(_linear(lambda x: x.sum(axis=-1, keepdims=True), d * d))
    return -load.stiffness * (d - load.rest_length * (d * _reciprocal(length)))


def _external_force(model: Model, kin: Kinematics):
    """``tau_ext = sum J_v(p)^T f + J_w^T m`` (..., n) over the model's external loads (module docstring), from the
    geometric Jacobians of each load's point (:func:`point_jacobian`), with ``f`` and ``m`` in the world; None without
    loads. Arrays or dual numbers alike (:func:`linearize`)."""
    if not model.loads:
        return None
    total = 0.0
    for load in model.loads:
        i = np.array([model.body_index(load.body)])
        R = kin.R[..., i, :, :]
        p = kin.o[..., i, :] + _mv(R, np.asarray(load.offset, dtype=float))
        Jv, Jw = point_jacobian(kin, i, p)
        if isinstance(load, PointSpring):
            f = _spring_force(load, p)
        else:
            f = np.asarray(load.force, dtype=float)
            f = f if load.frame == "world" else _mv(R, f)
        total = total + _mv(_t(Jv), f)[..., 0, :]
        if isinstance(load, ExternalWrench):
            m = np.asarray(load.moment, dtype=float)
            total = total + _mv(_t(Jw), m if load.frame == "world" else _mv(R, m))[..., 0, :]
    return total


def joint_space_terms(model: Model, q, qd) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """``(M, C qd, g)`` of eq. (2), projected through the COM Jacobians (Kane's form, module docstring)."""
    q, qd, _ = check_state(model, q, qd, np.zeros(model.m))
    return _terms(model, _kinematics(model, q, qd))


def _point_kinematics(model: Model, kin: Kinematics, body: str | None,
                      offset: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """World position ``p`` (..., 3), linear Jacobian ``J_v`` (..., 3, n) and classical bias ``Jdot_v qd`` (..., 3)
    of the point ``offset`` fixed in ``body``; with ``body = None`` the fixed world point ``offset`` (zero Jacobian
    and bias)."""
    batch = kin.qd.shape[:-1]
    if body is None:
        return (np.broadcast_to(np.asarray(offset, dtype=float), batch + (3,)), np.zeros(batch + (3, model.n)),
                np.zeros(batch + (3,)))
    i = np.array([model.body_index(body)])
    p = kin.o[..., i, :] + _mv(kin.R[..., i, :, :], offset)
    Jv = _linear_columns(kin.z, kin.column_origin, kin.revolute, kin.moves[i], p)
    return p[..., 0, :], Jv[..., 0, :, :], point_bias(kin, i, p, point_velocity(kin, i, p))[..., 0, :]


def _task_kinematics(model: Model, kin: Kinematics, point: str | None) -> tuple[np.ndarray, np.ndarray]:
    """``J = D J_v(p)`` (..., k, n) and the classical ``Jdot qd = D (point bias)`` (..., k) of a task point."""
    tp = model.task_point(point)
    _, Jv, bias = _point_kinematics(model, kin, tp.body, tp.offset)
    return tp.directions @ Jv, _vm(bias, tp.directions.T)


def _cond(model: Model, eig: np.ndarray) -> float | np.ndarray:
    """``cond_2`` of ``A = J M^-1 J^T`` from its ascending eigenvalues (..., k); ``inf`` where it is numerically
    singular: its smallest eigenvalue not above ``k eps`` times the largest (eigvalsh's absolute accuracy) nor above
    the degenerate floor (:func:`_degenerate_floor`), or not finite (a task Jacobian of rounding size, 1e-135, once
    passed as cond 1)."""
    regular = np.maximum(eig.shape[-1] * np.finfo(float).eps * eig[..., -1], _degenerate_floor(model)) < eig[..., 0]
    return np.where(regular, eig[..., -1] / np.where(regular, eig[..., 0], 1.0), np.inf)[()]


def _task_lever(model: Model, q: np.ndarray) -> float:
    """An upper bound on the length of the task Jacobian's columns: the placements along the task point's chain, the
    point's offset, and for a prismatic joint its travel plus 1 (its unit column), for a free joint its position's
    length plus 1 (its unit linear columns; a spherical joint's rotation columns add no length)."""
    tp = model.task_point()
    lever, i = float(np.linalg.norm(tp.offset)), model.body_index(tp.body)
    while i >= 0:
        body, j = model.bodies[i], model.q_index[i]
        travel = 0.0
        if body.joint == "prismatic":
            travel = abs(float(q[j])) + 1.0
        elif body.joint == "free":
            travel = float(np.linalg.norm(q[j:j + 3])) + 1.0
        lever += float(np.linalg.norm(body.translation)) + travel
        i = model.parent_index[i]
    return lever


def _jacobian_condition(model: Model, q: np.ndarray, J_bar: np.ndarray) -> float:
    """``L ||J_bar||_2``, ``J_bar = M^-1 J^T Lambda``, L the task lever: how much the recomposition ``qdd = J_bar (xdd
    - Jdot qd) + ...`` amplifies the rounding of the task bias, ``eps |Jdot qd|``, a sum of lever-sized terms (module
    docstring, numerics). cond(A) misses it where every direction is short alike (a one-row task nearly normal to
    the point's motion: cond 1, Lambda 8e12, a relative error of 4e-10, a fuzz finding). Its bound ``L sqrt(||M^-1|| /
    lambda_min(A))`` is reached only by a task that moves the lightest direction of M: a 4e-6 kg m^2 wrist roll about
    the tool's own axis made it 30 times too large on tiago (issue 34). inf where A is singular (J_bar NaN)."""
    if not np.all(np.isfinite(J_bar)):
        return float("inf")
    return _task_lever(model, q) * float(np.sqrt(np.linalg.eigvalsh(J_bar.T @ J_bar)[-1]))


def _principal_task_space(model, J, Jdot_qd, Minv, Cqd, g, tau_ctrl,
                          tau_constr) -> tuple[TaskSpace, np.ndarray, np.ndarray]:
    """Eq. (22) and ``xdd = A (F - mu - p)`` (eq. 23 at ``F = 0``), evaluated in the principal axes of ``A``
    (``x' = V^T x`` with ``A = V diag(eig) V^T``, where ``Lambda = diag(1 / eig)``; module docstring, numerics).
    ``tau_constr`` (..., 5, n) holds the generalized constraint forces ``Jc^T lam`` at the drift, of the input alone,
    at the total, of the zero-velocity counterfactual and of the velocity products (zero without constraints); their
    images ``J_bar^T Jc^T lam`` are the ``F_constr`` of eq. (22).
    Returns the :class:`TaskSpace` in those axes, ``A`` as assembled and ``V``. All NaN, ``cond`` inf, where ``A`` is
    numerically singular."""
    n = Minv.shape[-1]
    A = J @ Minv @ _t(J)
    A = 0.5 * (A + _t(A))
    eig, V = np.linalg.eigh(A)
    cond = _cond(model, eig)
    eig = np.where(np.isinf(cond)[..., None], np.nan, eig)
    Jp, bias = _t(V) @ J, _mv(_t(V), Jdot_qd)
    Minv_JT = Minv @ _t(Jp)
    mu = (_mv(_t(Minv_JT), Cqd) - bias) / eig               # Lambda (J M^-1 C qd - Jdot qd)
    p = _mv(_t(Minv_JT), g) / eig                            # Lambda J M^-1 g
    J_bar = Minv_JT / eig[..., None, :]                      # M^-1 J^T Lambda
    F_ctrl = _mv(_t(J_bar), tau_ctrl)
    F_constr_drift, F_constr_ctrl, F_constr, F_constr_zvcf, F_constr_velocity = np.moveaxis(tau_constr @ J_bar, -2, 0)
    principal = TaskSpace(J=Jp, Jdot_qd=bias, A=_diag(eig), Lambda=_diag(1.0 / eig), mu=mu, p=p, J_bar=J_bar,
                          N=np.eye(n) - J_bar @ Jp, F_ctrl=F_ctrl, F_constr=F_constr, F_constr_drift=F_constr_drift,
                          xdd_drift=eig * (F_constr_drift - mu - p), xdd_ctrl=eig * (F_ctrl + F_constr_ctrl),
                          xdd_total=eig * (F_ctrl + F_constr - mu - p), xdd_zvcf=eig * (F_constr_zvcf - p),
                          xdd_velocity=eig * (F_constr_velocity - mu), cond=cond)
    return principal, A, V


def _task_space(model, J, Jdot_qd, Minv, Cqd, g, tau_ctrl, tau_constr) -> tuple[TaskSpace, TaskSpace]:
    """The :class:`TaskSpace` of :func:`_principal_task_space` in the principal axes and rotated back to the task
    coordinates (``J``, ``Jdot qd`` and ``A`` there as assembled)."""
    principal, A, V = _principal_task_space(model, J, Jdot_qd, Minv, Cqd, g, tau_ctrl, tau_constr)
    Lambda = V @ principal.Lambda @ _t(V)
    reported = TaskSpace(J=J, Jdot_qd=Jdot_qd, A=A, Lambda=0.5 * (Lambda + _t(Lambda)), mu=_mv(V, principal.mu),
                         p=_mv(V, principal.p), J_bar=principal.J_bar @ _t(V), N=principal.N,
                         F_ctrl=_mv(V, principal.F_ctrl), F_constr=_mv(V, principal.F_constr),
                         F_constr_drift=_mv(V, principal.F_constr_drift), xdd_drift=_mv(V, principal.xdd_drift),
                         xdd_ctrl=_mv(V, principal.xdd_ctrl), xdd_total=_mv(V, principal.xdd_total),
                         xdd_zvcf=_mv(V, principal.xdd_zvcf), xdd_velocity=_mv(V, principal.xdd_velocity),
                         cond=principal.cond)
    return principal, reported


def _recompose(ts: TaskSpace, Minv: np.ndarray, h: tuple[np.ndarray, np.ndarray], tau_ctrl: np.ndarray,
               tau_constr: np.ndarray) -> tuple[np.ndarray, ...]:
    """The joint accelerations from the principal-axes task space plus the dynamically consistent null space
    (module docstring), ``h = C qd + g`` given by its terms ``(C qd, g)``: ``drift = J_bar (xdd_drift - Jdot qd) +
    M^-1 N^T (Jc^T lam_0 - h)``, ``ctrl = J_bar xdd_ctrl + M^-1 N^T (B u + Jc^T lam_ctrl)`` (directly), ``total =
    J_bar (xdd_total - Jdot qd) + M^-1 N^T (B u + Jc^T lam - h)``, and the drift's parts, each directly: ``zvcf =
    J_bar xdd_zvcf + M^-1 N^T (Jc^T lam_zvcf - g)`` (at qd = 0 there is no ``Jdot qd``), ``drift_velocity = J_bar
    (xdd_velocity - Jdot qd) + M^-1 N^T (Jc^T lam_velocity - C qd)``; the constraint forces ``tau_constr`` of
    :func:`_task_space`."""
    f_drift, f_ctrl, f_total, f_zvcf, f_velocity = np.moveaxis(tau_constr, -2, 0)
    Cqd, g = h
    h = Cqd + g
    task = np.stack([ts.xdd_drift - ts.Jdot_qd, ts.xdd_ctrl, ts.xdd_total - ts.Jdot_qd, ts.xdd_zvcf,
                     ts.xdd_velocity - ts.Jdot_qd], axis=-1)
    forces = np.stack([f_drift - h, tau_ctrl + f_ctrl, tau_ctrl + f_total - h, f_zvcf - g, f_velocity - Cqd], axis=-1)
    return tuple(np.moveaxis(ts.J_bar @ task + Minv @ (_t(ts.N) @ forces), -1, 0))   # (..., n, 5) columns


def _circle(model: Model, kin: Kinematics, q: np.ndarray, c) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """PointOnCircle: ``d = P (p - c)``, ``phi = d.d - R^2``, ``Jc = 2 d^T P J_v``,
    ``Jcdot qd = 2 |P J_v qd|^2 + 2 d^T P (Jdot_v qd)``."""
    p, Jv, bias = _point_kinematics(model, kin, c.body, c.offset)
    d, PJ = _vm(p - c.center, c.plane.T), c.plane @ Jv
    v = _mv(PJ, kin.qd)
    dot = (lambda a, b: _linear(lambda x: np.sum(x, axis=-1, keepdims=True), a * b))  # noqa: E731
    return dot(d, d) - c.radius**2, 2.0 * d[..., None, :] @ PJ, 2.0 * dot(v, v) + 2.0 * dot(d, _vm(bias, c.plane.T))


def _coincide(model: Model, kin: Kinematics, q: np.ndarray, c) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """PointsCoincide: ``D (p_a - p_b)``, ``D (J_a - J_b)``, ``D (Jdot_a qd - Jdot_b qd)`` (body_b None: a world
    point, zero Jacobian and bias)."""
    pa, Ja, ba = _point_kinematics(model, kin, c.body_a, c.offset_a)
    pb, Jb, bb = _point_kinematics(model, kin, c.body_b, c.offset_b)
    D = c.directions
    return _vm(pa - pb, D.T), D @ (Ja - Jb), _vm(ba - bb, D.T)


def _line(model: Model, kin: Kinematics, q: np.ndarray, c) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """PointOnLine: ``N (p - origin)``, ``N J_v``, ``N Jdot_v qd``."""
    p, Jv, bias = _point_kinematics(model, kin, c.body, c.offset)
    return _vm(p - c.origin, c.normals.T), c.normals @ Jv, _vm(bias, c.normals.T)


def _coupling(model: Model, kin: Kinematics, q: np.ndarray, c) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """JointCoupling: ``sum_j c_j q_j - offset``, a constant row, zero bias (the coupled joints are revolute or
    prismatic: their coordinate ``q_j`` and velocity are one entry each, at ``q_index`` and ``v_index``)."""
    bodies = [model.body_index(name) for name in c.joints]
    row, position = np.zeros(model.n), np.zeros(model.nq)
    row[[model.v_index[i] for i in bodies]] = c.coefficients
    position[[model.q_index[i] for i in bodies]] = c.coefficients
    batch = q.shape[:-1]
    return _vm(q, position[:, None]) - c.offset, np.broadcast_to(row, batch + (1, model.n)), np.zeros(batch + (1,))


def _row_sum(x):
    """``sum`` over the last axis, kept (of an array or a dual number)."""
    return _linear(lambda v: np.sum(v, axis=-1, keepdims=True), x)


def _reciprocal(x):
    """``1 / x`` elementwise of an array or a dual number (tangent ``-dx / x^2``)."""
    return _Dual(1.0 / x.val, -x.tan / x.val**2) if isinstance(x, _Dual) else 1.0 / x


def _root(x):
    """``sqrt(x)`` elementwise of an array or a dual number (tangent ``dx / (2 sqrt(x))``)."""
    if not isinstance(x, _Dual):
        return np.sqrt(x)
    val = np.sqrt(x.val)
    return _Dual(val, x.tan / (2.0 * val))


def _pfaffian_point(model: Model, kin: Kinematics, body: str, p: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """``J_v`` (..., 3, n) and the classical bias (..., 3) of the material point of ``body`` at world ``p`` (..., 3)."""
    i = np.array([model.body_index(body)])
    p = p[..., None, :]
    Jv = _linear_columns(kin.z, kin.column_origin, kin.revolute, kin.moves[i], p)
    return Jv[..., 0, :, :], point_bias(kin, i, p, point_velocity(kin, i, p))[..., 0, :]


def _point_velocity(model: Model, kin: Kinematics, q: np.ndarray, c) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """PointVelocity (Pfaffian, phi reported 0): ``A = D J_v``, ``Adot qd = D Jdot_v qd``."""
    _, Jv, bias = _point_kinematics(model, kin, c.body, c.offset)
    D = c.directions
    return np.zeros(q.shape[:-1] + (len(D),)), D @ Jv, _vm(bias, D.T)


def _knife_edge(model: Model, kin: Kinematics, q: np.ndarray, c) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """KnifeEdge (Pfaffian, phi 0): ``e = R d``, ``A = e^T J_v``, ``Adot qd = (w x e) . (J_v qd) + e . Jdot_v qd``."""
    i = model.body_index(c.body)
    _, Jv, bias = _point_kinematics(model, kin, c.body, c.offset)
    e = _mv(kin.R[..., i, :, :], c.direction)
    pdot = _mv(Jv, kin.qd)
    rate = _row_sum(_cross(kin.w[..., i, :], e) * pdot + e * bias)
    return np.zeros(q.shape[:-1] + (1,)), e[..., None, :] @ Jv, rate


def _rolling(model: Model, kin: Kinematics, q: np.ndarray, c) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """RollingContact (Pfaffian, phi 0): the contact ``p_c = c - r u`` (``cases.constraints``), ``e = p_c - c``;
    ``A = T J_v(p_c)`` (the material point there) and ``Adot qd = T (a_c + w_bias x e + w x edot)`` from the centre's
    classical bias ``a_c``, the body's ``Jdot_w qd`` and ``edot = -r udot`` (``udot`` from ``adot = w x a``): the
    contact point slides over the disk. With ``lateral=False`` the one row along the rolling direction ``t = b / |b|``,
    ``b = a x n``: ``A = t^T J_v(p_c)``, ``Adot qd = t . rate + tdot . (J_v(p_c) qd)``, ``tdot = (bdot - t (t . bdot))
    / |b|``, ``bdot = adot x n``."""
    i = model.body_index(c.body)
    center, _, a_center = _point_kinematics(model, kin, c.body, c.center)
    w = kin.w[..., i, :]
    a = _mv(kin.R[..., i, :, :], c.axis)
    n = np.cross(c.plane[0], c.plane[1])
    dot = (lambda x, y: _row_sum(x * y))  # noqa: E731
    raw = n - dot(n, a) * a
    inverse_length = _reciprocal(_root(dot(raw, raw)))
    u = raw * inverse_length
    e = -c.radius * u
    a_dot = _cross(w, a)
    raw_dot = -dot(n, a_dot) * a - dot(n, a) * a_dot
    e_dot = -c.radius * ((raw_dot - dot(u, raw_dot) * u) * inverse_length)
    Jv, _ = _pfaffian_point(model, kin, c.body, center + e)
    rate = a_center + _cross(kin.w_bias[..., i, :], e) + _cross(w, e_dot)
    if not c.lateral:       # the rolling direction t = b / |b|, b = a x n, alone; t turns with the axle
        b = _cross(a, n)
        inverse_size = _reciprocal(_root(dot(b, b)))
        t = b * inverse_size
        b_dot = _cross(a_dot, n)
        t_dot = (b_dot - dot(t, b_dot) * t) * inverse_size
        pdot = _mv(Jv, kin.qd)
        return np.zeros(q.shape[:-1] + (1,)), t[..., None, :] @ Jv, dot(t, rate) + dot(t_dot, pdot)
    return np.zeros(q.shape[:-1] + (2,)), c.plane @ Jv, _vm(rate, c.plane.T)


#: The rows of each declaration of ``cases.constraints``, by its type.
_DECLARATIONS = {PointOnCircle: _circle, PointsCoincide: _coincide, PointOnLine: _line, JointCoupling: _coupling,
                 PointVelocity: _point_velocity, KnifeEdge: _knife_edge, RollingContact: _rolling}


def _constraint_rows(model: Model, kin: Kinematics, q: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """``phi`` (..., k), ``Jc`` (..., k, n) and ``Jcdot qd`` (..., k) of every declaration, in model order, from the
    point kinematics (module docstring, constraints)."""
    rows = []
    for c in model.constraints:
        if type(c) not in _DECLARATIONS:
            raise TypeError(f"model '{model.name}': the operational-space backend does not know the constraint "
                            f"{type(c).__name__} ({c.name!r}); known: {[t.__name__ for t in _DECLARATIONS]}")
        rows.append(_DECLARATIONS[type(c)](model, kin, q, c))
    phi, Jc, bias = zip(*rows)
    return _concatenate(phi, -1), _concatenate(Jc, -2), _concatenate(bias, -1)


def _degenerate_floor(model: Model) -> float:
    """The smallest eigenvalue of ``J M^-1 J^T`` (J task or constraint rows) that is a direction and not rounding: a
    row of ``DEGENERATE_ROW`` times the model's length scale L in the metric of M, ``(DEGENERATE_ROW L)^2 /
    inertia_scale`` (a row that vanishes at a configuration comes out of some kinematics as exact zeros, of others
    as rounding)."""
    return (DEGENERATE_ROW * model.length_scale) ** 2 / model.inertia_scale


def _independent(model: Model, w: np.ndarray) -> np.ndarray:
    """The constraint-space directions kept, among the ascending eigenvalues ``w`` (..., k) of ``S = Jc M^-1 Jc^T``:
    those above ``CONSTRAINT_RCOND`` times the largest and above :func:`_degenerate_floor`; the others are
    redundant (redundant or degenerate rows)."""
    return w > np.maximum(CONSTRAINT_RCOND * w[..., -1:], _degenerate_floor(model))


def _constraint_inertia(model: Model, Jc: np.ndarray, Minv: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """``(Lambda_c, w, U)``: the constraint-space inertia ``Lambda_c = S^+``, ``S = Jc M^-1 Jc^T = U diag(w) U^T``
    (eigh, w ascending), from S's eigendecomposition without the redundant eigen-directions (:func:`_independent`):
    minimum-norm multipliers."""
    S = Jc @ Minv @ _t(Jc)
    w, U = np.linalg.eigh(0.5 * (S + _t(S)))
    keep = _independent(model, w)
    return (U * np.where(keep, 1.0 / np.where(keep, w, 1.0), 0.0)[..., None, :]) @ _t(U), w, U


@dataclass(frozen=True)
class ConstraintSpace:
    """The constraint space at one state or a batch (eqs. 12-17; k constraint rows, module docstring).

    phi (..., k), Jc (..., k, n), bias = Jcdot qd (..., k), Lambda = S^+ (..., k, k) the constraint-space inertia,
    with S's eigenvalues (..., k; ascending) and eigen-directions (..., k, k; columns);
    the multipliers lam_drift (eq. 14, u = 0), lam_ctrl (the input's share ``lam - lam_0`` of eq. 15, solved
    directly) and lam (eq. 12), and the drift's parts (4.5-4.6), lam_zvcf (force ``-g``, bias 0) and lam_velocity
    (force ``-C qd``, bias ``Jcdot qd``), each (..., k).
    """

    phi: np.ndarray
    Jc: np.ndarray
    bias: np.ndarray
    Lambda: np.ndarray
    eigenvalues: np.ndarray
    directions: np.ndarray
    lam_drift: np.ndarray
    lam_ctrl: np.ndarray
    lam: np.ndarray
    lam_zvcf: np.ndarray
    lam_velocity: np.ndarray

    @property
    def forces(self) -> np.ndarray:
        """The generalized constraint forces ``Jc^T lam`` (..., 5, n): at the drift, of the input alone, at the
        total, of the zero-velocity counterfactual and of the velocity products."""
        return np.stack([self.lam_drift, self.lam_ctrl, self.lam, self.lam_zvcf, self.lam_velocity], axis=-2) @ self.Jc


def _constraint_space(model: Model, kin: Kinematics, q: np.ndarray, Minv: np.ndarray, free) -> ConstraintSpace:
    """Eq. (13) solved for the multipliers in constraint space, ``lam = Lambda_c (-Jcdot qd - Jc a)``, from the free
    accelerations ``free = (a_drift, a_ctrl, a_total, a_zvcf, a_velocity)`` (``M^-1 (-h)``, ``M^-1 B u``, ``M^-1 (B u
    - h)``, ``M^-1 (-g)``, ``M^-1 (-C qd)``); the zero-velocity counterfactual has no bias (``qd = 0``)."""
    phi, Jc, bias = _constraint_rows(model, kin, q)
    Lambda, w, U = _constraint_inertia(model, Jc, Minv)
    a_drift, a_ctrl, a_total, a_zvcf, a_velocity = free
    return ConstraintSpace(phi=phi, Jc=Jc, bias=bias, Lambda=Lambda, eigenvalues=w, directions=U,
                           lam_drift=_mv(Lambda, -bias - _mv(Jc, a_drift)), lam_ctrl=-_mv(Lambda, _mv(Jc, a_ctrl)),
                           lam=_mv(Lambda, -bias - _mv(Jc, a_total)), lam_zvcf=-_mv(Lambda, _mv(Jc, a_zvcf)),
                           lam_velocity=_mv(Lambda, -bias - _mv(Jc, a_velocity)))


def _cholesky(model: Model, M: np.ndarray, q: np.ndarray) -> np.ndarray:
    """The Cholesky factor of one mass matrix; one that is not positive definite (e.g. a point mass on its own joint
    axis) is a ValueError naming the model, the configuration and the eigenvalues."""
    try:
        return np.linalg.cholesky(M)
    except np.linalg.LinAlgError:
        raise ValueError(f"model '{model.name}': the mass matrix is not positive definite at q = {q.tolist()} "
                         f"(Cholesky failed); eigenvalues {np.linalg.eigvalsh(M).tolist()}") from None


def _inverse_mass_matrix(model: Model, M: np.ndarray, q: np.ndarray) -> np.ndarray:
    """``M^-1 = L^-T L^-1`` from the Cholesky factor ``L`` (symmetrized), of one state or a batch; a mass matrix
    that is not positive definite is the ValueError of :func:`_cholesky` for the first such state."""
    try:
        L_inv = np.linalg.inv(np.linalg.cholesky(M))
    except np.linalg.LinAlgError:
        for state in np.ndindex(M.shape[:-2]):               # the error path: name the first failing state
            _cholesky(model, M[state], q[state])
        raise
    Minv = _t(L_inv) @ L_inv
    return 0.5 * (Minv + _t(Minv))


@dataclass(frozen=True)
class _Solution:
    """One state or a batch solved: the joint-space terms and the inverse mass matrix, the reported task space (None
    when not asked for), the accelerations (drift, ctrl, total, zvcf, drift_velocity) of :func:`_recompose`, the
    constraint space (None without constraints), ``tau_ext`` (None without external loads; ``g`` is then ``g -
    tau_ext``)."""

    M: np.ndarray
    Minv: np.ndarray
    Cqd: np.ndarray
    g: np.ndarray
    tau_ctrl: np.ndarray
    task: TaskSpace | None
    accelerations: tuple[np.ndarray, ...]
    constraint: ConstraintSpace | None
    tau_ext: np.ndarray | None = None


def _solve(model: Model, q: np.ndarray, qd: np.ndarray, u: np.ndarray, point: str | None,
           report: bool = True) -> _Solution:
    """The free split through the task space of ``point``; with constraints, their multipliers from it and the split
    again with the constraint forces as ``F_constr`` (module docstring, constraints). One state (q, qd (n,), u (m,))
    or a batch (a leading axis on each). ``report``: also rotate the task space back to the task coordinates."""
    kin = _kinematics(model, q, qd)
    M, Cqd, g = _terms(model, kin)
    tau_ext = _external_force(model, kin)
    if tau_ext is not None:
        g = g - tau_ext                                   # velocity-independent: with gravity (module docstring)
    Minv, tau_ctrl = _inverse_mass_matrix(model, M, q), _vm(u, model.input_map.T)
    J, Jdot_qd = _task_kinematics(model, kin, point)

    def through_task_space(tau_constr):
        args = (model, J, Jdot_qd, Minv, Cqd, g, tau_ctrl, tau_constr)
        ts, reported = _task_space(*args) if report else (_principal_task_space(*args)[0], None)
        return reported, _recompose(ts, Minv, (Cqd, g), tau_ctrl, tau_constr)

    task, accelerations = through_task_space(np.zeros(q.shape[:-1] + (5, model.n)))
    constraint = None
    if model.constraints:
        constraint = _constraint_space(model, kin, q, Minv, accelerations)
        task, accelerations = through_task_space(constraint.forces)
    return _Solution(M, Minv, Cqd, g, tau_ctrl, task, accelerations, constraint, tau_ext)


def task_space(model: Model, q, qd, u, point: str | None = None) -> TaskSpace:
    """The :class:`TaskSpace` of eq. (22) for the task point named ``point`` (default: ``model.task_point()``),
    in its task coordinates ``x_task = D p``; with constraints, ``F_constr`` included."""
    q, qd, u = check_state(model, q, qd, u)
    return _solve(model, q, qd, u, point).task


def _mass_conditioning(model: Model, s: _Solution, qd: np.ndarray) -> tuple[float, float, float]:
    """``(cond(M), ||M^-1||, accel_scale)`` of a solved state: ``cond_2(M) = ||M||_2 ||M^-1||_2``, each norm the
    largest eigenvalue of its own matrix, the M this backend projected and the inverse it solved with (eigvalsh).

    ``accel_scale = ||M^-1||_2 H``, H the size of the generalized forces summed in ``B u - C qd - g``, plus
    configuration-robust magnitudes of the terms that can cancel: ``||M|| |qd|^2`` for the velocity products and
    ``|gravity| sqrt(m_total ||M||)`` (a mass times a lever arm) for gravity. 1-norms, so tiny vectors do not
    underflow."""
    norm, inverse_norm = float(np.linalg.eigvalsh(s.M)[-1]), float(np.linalg.eigvalsh(s.Minv)[-1])
    m_total = sum(b.mass for b in model.bodies)
    H = (np.abs(s.Cqd).sum() + np.abs(s.g).sum() + np.abs(s.tau_ctrl).sum() + norm * float(qd @ qd)
         + np.abs(model.gravity).sum() * np.sqrt(m_total * norm) + (0.0 if s.tau_ext is None else np.abs(s.tau_ext).sum()))
    return norm * inverse_norm, inverse_norm, float(H) * inverse_norm


def _inconsistency(model: Model, c: ConstraintSpace, redundant: np.ndarray, Minv: np.ndarray, forces: np.ndarray,
                   accel_scale: float) -> float:
    """The relative size of the constraint-space right-hand sides ``r = -Jcdot qd - Jc M^-1 f`` (the multipliers
    solve ``S lam = r``) in S's ``redundant`` eigen-directions (a mask): ``max |U_0^T r| / |r|`` over the columns
    ``f`` of ``forces`` (``B u - h`` and ``-h``); 0 when S is regular. Non-zero means ``H_t`` is empty (eq. 16: the
    constraints cannot all hold, e.g. a four-bar at its change point moving off both branches). |r| is taken at least
    ``1e-6 L accel_scale``: where every row is degenerate, r itself is rounding, and its share means nothing."""
    if not redundant.any():
        return 0.0
    r = -c.bias[:, None] - c.Jc @ (Minv @ forces)
    size = np.maximum(np.linalg.norm(r, axis=0), 1e-6 * model.length_scale * accel_scale)
    share = np.linalg.norm(c.directions[:, redundant].T @ r, axis=0) / np.where(size > 0.0, size, 1.0)
    return float(np.max(share))


def _constraint_conditioning(model: Model, c: ConstraintSpace, Minv: np.ndarray, free_forces: np.ndarray,
                             accel_scale: float, inverse_norm: float) -> tuple[dict, int, float, float]:
    """``(conditions, rank, lam_scale, force_scale)`` of one state's constraint space, from the eigendecomposition of
    ``S = Lambda_c^+`` it inverted (:func:`_constraint_inertia`; the largest eigenvalue ``w_max`` taken at least
    :func:`_degenerate_floor`): ``"constraint"`` = cond S = ``w_max / w_min`` (inf when ``w_min`` is not positive:
    the multipliers are not unique), ``"constraint_consistency"`` (:func:`_inconsistency` of ``free_forces``, the
    columns ``B u - h`` and ``-h``), ``"constraint_kept"`` = ``w_max`` over the smallest kept eigenvalue (what
    ``Lambda_c`` amplifies; 1 when none). ``lam_scale = ||Lambda_c|| (|Jcdot qd|_1 + ||Jc|| accel_scale)`` is the
    size of the multipliers the summed terms could produce (0 when no direction is kept); ``force_scale = ||M^-1||
    ||Jc|| lam_scale`` the accelerations their force can."""
    w = c.eigenvalues
    kept = _independent(model, w)
    w_max, rank = max(float(w[-1]), _degenerate_floor(model)), int(kept.sum())
    jc_norm = float(np.linalg.norm(c.Jc, 2))
    lam_scale = float((np.abs(c.bias).sum() + jc_norm * accel_scale) / w[kept][0]) if rank else 0.0
    conditions = {"constraint": w_max / w[0] if w[0] > 0.0 else np.inf,
                  "constraint_consistency": _inconsistency(model, c, ~kept, Minv, free_forces, accel_scale),
                  "constraint_kept": w_max / w[kept][0] if rank else 1.0}
    return conditions, rank, lam_scale, inverse_norm * jc_norm * lam_scale


def constrained_split(model: Model, *, constraint: ConstraintSpace, Minv: np.ndarray, free_forces: np.ndarray,
                      qd: np.ndarray, lam: np.ndarray, lam_drift: np.ndarray, accel_scale: float, inverse_norm: float,
                      conditions: dict, **free) -> Split:
    """The :class:`Split` of a constrained state from the fields of the free one (``free``, ``conditions``) and its
    constraint space: the multipliers ``lam``, ``lam_drift`` (eqs. 12, 14), the generalized constraint forces
    ``Jc^T lam`` (and at the drift), the constraint power in constraint space, ``lam . (Jc qd) = (Jc^T lam) . qd``
    (5.5; per coordinate ``(Jc^T lam)_i qd_i``), ``Jc qd``, and the conditioning of :func:`_constraint_conditioning`
    (``free_forces``: the columns ``B u - h`` and ``-h``), whose force scale the acceleration scale includes."""
    c = constraint
    cond, rank, lam_scale, force_scale = _constraint_conditioning(model, c, Minv, free_forces, accel_scale,
                                                                  inverse_norm)
    force, force_drift, velocity = lam @ c.Jc, lam_drift @ c.Jc, c.Jc @ qd
    return Split(lam=lam, lam_drift=lam_drift, power_constr=float(lam @ velocity), power_constr_per_coord=force * qd,
                 accel_scale=accel_scale + force_scale, conditions={**conditions, **cond}, constraint_value=c.phi,
                 constraint_jacobian=c.Jc, constraint_bias=c.bias, constraint_velocity=velocity,
                 constraint_force=force, constraint_force_drift=force_drift, constraint_rank=rank,
                 lam_scale=lam_scale, **free)


def _split_of(model: Model, s: _Solution, q: np.ndarray, qd: np.ndarray, u: np.ndarray) -> Split:
    """The :class:`Split` of one solved state ``s`` (:func:`_solve`) at ``(q, qd, u)`` (:func:`split`)."""
    drift, ctrl, total, zvcf, drift_velocity = s.accelerations
    cond_M, inverse_norm, accel_scale = _mass_conditioning(model, s, qd)
    free = dict(drift=drift, ctrl=ctrl, total=total, zvcf=zvcf, drift_velocity=drift_velocity,
                power_ctrl=float(u @ (model.input_map.T @ qd)), power_ctrl_per_coord=s.tau_ctrl * qd, cond_M=cond_M,
                task_drift=s.task.xdd_drift,
                conditions={"task": s.task.cond,
                            "task_jacobian": _jacobian_condition(model, q, s.task.J_bar)},
                kinetic_energy=0.5 * qd @ s.M @ qd, task_inertia=s.task.Lambda)
    if s.tau_ext is not None:
        free.update(external_force=s.tau_ext, power_ext=float(s.tau_ext @ qd))
    c = s.constraint
    if c is None:
        return Split(lam=None, lam_drift=None, power_constr=None, power_constr_per_coord=None, accel_scale=accel_scale,
                     extras={"task": s.task}, **free)
    h = s.Cqd + s.g
    return constrained_split(model, constraint=c, Minv=s.Minv, free_forces=np.stack([s.tau_ctrl - h, -h], axis=-1),
                             qd=qd, lam=c.lam, lam_drift=c.lam_drift, accel_scale=accel_scale,
                             inverse_norm=inverse_norm, extras={"task": s.task, "constraint_inertia": c.Lambda}, **free)


def _state(solved, i: int):
    """State ``i`` of a block solved at once (:func:`_solve` on rows of states): row ``i`` of every array of the
    :class:`_Solution` and of the task and constraint spaces it holds."""
    if solved is None:
        return None
    if isinstance(solved, tuple):
        return tuple(_state(part, i) for part in solved)
    if isinstance(solved, (_Solution, TaskSpace, ConstraintSpace)):
        return type(solved)(*(_state(getattr(solved, f.name), i) for f in fields(solved)))
    return solved[i]


#: Bound on the body-pair entries of the largest temporaries (N states x n bodies x n joints) that
#: :func:`split_batch` and :func:`split_many` let one block of states hold: about 0.4 MB each, so a block stays near
#: the caches.
BLOCK_ENTRIES = 50_000


def split_many(model: Model, Q, QD, U) -> list[Split]:
    """:func:`split` of N states (rows of ``Q``, ``QD``, ``U``), each a whole :class:`Split` equal to ``split``'s bit
    for bit: the kinematics, Kane projection, task space and recomposition of :func:`_solve` with a leading batch axis
    on blocks of states (the stacked products and LAPACK calls are the single state's, state by state), then each
    state's conditioning and reported numbers by the very functions ``split`` uses."""
    Q, QD, U = check_batch(model, Q, QD, U)
    size = max(1, BLOCK_ENTRIES // model.n**2)
    out = []
    for start in range(0, len(Q), size):
        rows = slice(start, start + size)
        solved = _solve(model, Q[rows], QD[rows], U[rows], None)
        out += [_split_of(model, _state(solved, i), q, qd, u) for i, (q, qd, u) in
                enumerate(zip(Q[rows], QD[rows], U[rows]))]
    return out


@with_block_form(split_many)
def split(model: Model, q, qd, u) -> Split:
    """The drift–control split (eq. 9) recomposed from task space (module docstring), in the principal axes:
    ``drift = J_bar (xdd_drift - Jdot qd) - M^-1 N^T h``, ``ctrl = J_bar xdd_ctrl + M^-1 N^T B u`` (directly),
    ``total = J_bar (xdd_total - Jdot qd) + M^-1 N^T (B u - h)``. With constraints the same with the constraint
    forces added (eqs. 12-17: lam, lam_drift; ctrl = B_c B u): :func:`constrained_split`.

    ``task_drift`` is eq. (23) for ``model.task_point()``; ``task_inertia`` its ``Lambda`` (eq. 22, the reported one
    of ``extras["task"]``; with constraints still ``(J M^-1 J^T)^-1`` of the unconstrained M, the constraints
    entering eq. 22 as ``F_constr``); ``conditions = {"task": cond_2(A), "task_jacobian":`` :func:`_jacobian_condition`
    ``}``;
    ``extras = {"task": TaskSpace}`` in the task coordinates, and with constraints ``"constraint_inertia"``
    (``Lambda_c``). NaN accelerations where A is numerically singular. The control power in input space,
    ``u . (B^T qd)`` (per coordinate ``(B u)_i qd_i``); cond(M) and the scales from :func:`_mass_conditioning`.
    The drift's parts (4.5-4.6), each recomposed directly (:func:`_recompose`): ``zvcf`` (``-M^-1 g``; with
    constraints the KKT solve with ``-g`` and no bias) and ``drift_velocity`` (``-M^-1 C qd``; with ``-C qd`` and
    the bias ``Jcdot qd``). Its block form is :func:`split_many`.
    """
    q, qd, u = check_state(model, q, qd, u)
    return _split_of(model, _solve(model, q, qd, u, None), q, qd, u)


def split_batch(model: Model, Q, QD, U) -> SplitBatch:
    """:func:`split` of N states at once (Q, QD (N, n), U (N, m)): the same kinematics, Kane projection, task space
    and null-space recomposition (eq. 22) and, with constraints, constraint space (eqs. 12-17), evaluated with a
    leading batch axis on blocks of states. Rows are ``split``'s drift, ctrl, total and lam, lam_drift."""
    Q, QD, U = check_batch(model, Q, QD, U)
    size = max(1, BLOCK_ENTRIES // model.n**2)
    blocks = [_solve(model, Q[s:s + size], QD[s:s + size], U[s:s + size], None, report=False)
              for s in range(0, max(len(Q), 1), size)]                  # an empty batch is one empty block
    drift, ctrl, total = (np.concatenate([b.accelerations[i] for b in blocks]) for i in range(3))
    if not model.constraints:
        return SplitBatch(drift, ctrl, total)
    lam, lam_drift = (np.concatenate([getattr(b.constraint, name) for b in blocks]) for name in ("lam", "lam_drift"))
    return SplitBatch(drift, ctrl, total, lam, lam_drift)


def _configuration_tangents(model: Model, q: np.ndarray) -> np.ndarray:
    """``d/ds integrate(q, s e_j)`` at ``s = 0`` (nv, nq), the ambient image of each tangent direction (interface,
    :class:`Linearization`): 1 at a revolute or prismatic coordinate; on a quaternion block ``0.5 quat (x) (e, 0)``
    (Hamilton product, x y z w: ``(w e + v x e, -v . e) / 2`` with ``quat = (v, w)``); a free joint's linear
    direction moves its position by ``R(quat) e``."""
    T = np.zeros((model.nv, model.nq))
    for i, body in enumerate(model.bodies):
        k, j = model.v_index[i], model.q_index[i]
        if body.joint not in ("spherical", "free"):
            T[k, j] = 1.0
            continue
        free = body.joint == "free"
        quat = q[j + 3 * free:j + 3 * free + 4]
        v, w = quat[:3], quat[3]
        for a, e in enumerate(np.eye(3)):
            T[k + 3 * free + a, j + 3 * free:j + 3 * free + 4] = 0.5 * np.append(w * e + np.cross(v, e), -v @ e)
        if free:
            T[k:k + 3, j:j + 3] = _quaternion_rotations(quat).T
    return T


def _kkt_derivative(Minv: np.ndarray, Jc: np.ndarray | None, Lambda: np.ndarray | None, force: np.ndarray,
                    rows: np.ndarray | None) -> np.ndarray:
    """The solution ``dvdot`` (nv, c) of ``[[M, Jc^T], [Jc, 0]] [dvdot; dlam] = [force; rows]`` for c right-hand
    sides (columns): ``dlam = Lambda_c (rows - Jc M^-1 force)`` in constraint space (the backend's ``Lambda_c = S^+``,
    minimum norm over redundant directions), ``dvdot = M^-1 (force + Jc^T dlam)``; unconstrained ``M^-1 force``."""
    free = Minv @ force
    if Jc is None:
        return free
    return free + Minv @ (Jc.T @ (Lambda @ (rows - Jc @ free)))


def linearize(model: Model, q, qd, u) -> Linearization:
    """A and B of eq. (11) (:class:`~formalisms.interface.Linearization`) by forward-mode differentiation of this
    backend's own passes: ``q`` and ``qd`` become dual numbers (:class:`_Dual`) with the 2 nv tangent directions
    ``(d/ds integrate(q, s e_j), 0)`` (:func:`_configuration_tangents`) and ``(0, e_j)``, carried through the
    kinematics, the Kane projection (``dM``, ``d(C qd)``, ``dg``) and the constraint rows (``dJc``,
    ``d(Jcdot qd)``). Then the solve, in joint-space form (the task-space recomposition returns the same ``vdot``,
    module docstring): ``a = M^-1 (B u - h)``, ``lam = Lambda_c (-Jcdot qd - Jc a)``, ``vdot = a + M^-1 Jc^T lam``,
    and the differentiated KKT system per direction, ``[[M, Jc^T], [Jc, 0]] [dvdot; dlam] = [-dh - dM vdot + dJc^T
    lam; -dJc vdot - d(Jcdot qd)]``; ``dvdot/du = B_c B`` (eq. 17; ``M^-1 B`` unconstrained)."""
    q, qd, u = check_state(model, q, qd, u)
    nv = model.nv
    q_dual = _Dual(q, np.vstack([_configuration_tangents(model, q), np.zeros((nv, model.nq))]))
    kin = _kinematics(model, q_dual, _Dual(qd, np.vstack([np.zeros((nv, nv)), np.eye(nv)])))
    M, Cqd, g = _terms(model, kin)
    tau_ext = _external_force(model, kin)
    h = Cqd + g if tau_ext is None else Cqd + g - tau_ext
    Minv = _inverse_mass_matrix(model, M.val, q)
    Jc = Lambda = rows = None
    vdot = Minv @ (model.input_map @ u - h.val)
    force = -h.tan.T
    if model.constraints:
        _, Jc, bias = _constraint_rows(model, kin, q_dual)       # constant rows (a joint coupling): no tangents
        (Jc, dJc), (bias, dbias) = ((_value(x), _tangents(x, np.shape(_value(x)), 2 * nv)) for x in (Jc, bias))
        Lambda = _constraint_inertia(model, Jc, Minv)[0]
        lam = Lambda @ (-bias - Jc @ vdot)
        vdot = vdot + Minv @ (Jc.T @ lam)
        force = force + (lam @ dJc).T
        rows = -(dJc @ vdot).T - dbias.T
    dvdot = _kkt_derivative(Minv, Jc, Lambda, force - (M.tan @ vdot).T, rows)
    dvdot_du = _kkt_derivative(Minv, Jc, Lambda, model.input_map, None if Jc is None else np.zeros((len(Jc), model.m)))
    return state_space(model, qd, dvdot[:, :nv], dvdot[:, nv:], dvdot_du, vdot)


FORMALISM = Formalism(
    name="operational_space",
    summary="Operational space (article 6.3, eqs. 22-23): Kane-projected M, C qd, g; task-space Lambda, mu, p; "
            "joint answer recomposed from task space plus the dynamically consistent null space; constraints as a "
            "constraint space (Lambda_c = S^+, eqs. 12-17) whose forces enter eq. 22 as F_constr",
    split=split,
    split_batch=split_batch,
    linearize=linearize,
)
