"""Holonomic constraints (article section 5, eqs. 12-17): the tip on a circle or a rail, the cartesian pendulum, the
double pendulum as a closed loop in absolute coordinates, the four-bar, the slider-crank and geared pendulums, and
the rule for redundant rows (:class:`Rule`: the minimum-norm multipliers where S = Jc M^-1 Jc^T is singular)."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from crosscheck.references.closed_forms.algebra import eigenvalues, inv2
from crosscheck.references.closed_forms.pendulums import (CHAIN_AND_ONE, chain_position, chain_tip, endpoint_jacobian,
                                                          mp, rod_chain_terms, stack_terms, tip_bias, tip_position,
                                                          to_joint)
from formalisms.interface import CONSTRAINT_RCOND, DEGENERATE_ROW


# ------------------------------------------------------------------------------ constrained (article section 5)


def circle_terms(t, td, l1=1.0, l2=1.0, xc=1.0, yc=-1.0, R=0.5):  # noqa: N803
    """Article 5.6, the tip on the circle of centre c = (xc, yc) and radius R (``cases.double_pendulum_circle``):
    ``phi = |x2 - c|^2 - R^2``, ``Jc = 2 (x2 - c)^T J`` with J of eq. (5), and
    ``Jcdot qd = 2 |J qd|^2 + 2 (x2 - c) . (Jdot qd)`` (phi differentiated twice at qdd = 0), all by hand from eq. (4).
    Returns ``(phi, Jc, Jcdot qd)``: a scalar, the row (2,), a scalar."""
    d = tip_position(t, l1, l2) - np.array([xc, yc])
    J = endpoint_jacobian(t, l1, l2)
    v = J @ td
    return d @ d - R**2, 2.0 * d @ J, 2.0 * v @ v + 2.0 * d @ tip_bias(t, td, l1, l2)


def circle_state(beta, elbow=1.0, rate=0.0, l1=1.0, l2=1.0, xc=1.0, yc=-1.0, R=0.5):  # noqa: N803
    """An admissible state of article 5.6, by hand: the tip at ``c + R (cos beta, sin beta)`` by the inverse
    kinematics of eq. (4) (cosine rule; ``elbow`` = +-1 picks the sign of t2, i.e. the branch), and the velocity
    ``rate`` times the unit null vector ``(Jc2, -Jc1) / |Jc|`` of ``Jc`` (5.1: ``Jc qd = 0``). Returns (t, td)."""
    x, y = xc + R * np.cos(beta), yc + R * np.sin(beta)
    t2 = elbow * np.arccos((x * x + y * y - l1**2 - l2**2) / (2.0 * l1 * l2))
    t1 = np.arctan2(x, -y) - np.arctan2(l2 * np.sin(t2), l1 + l2 * np.cos(t2))
    t = np.array([t1, t2])
    _, Jc, _ = circle_terms(t, np.zeros(2), l1, l2, xc, yc, R)
    return t, rate * np.array([Jc[1], -Jc[0]]) / np.linalg.norm(Jc)


def one_row_kkt(Minv, Jc, bias, f):
    """Article 5.6's KKT system ``[[M, -Jc^T], [Jc, 0]] [qdd; lam] = [f; -Jcdot qd]`` (eqs. 12, 13) for one row, by
    hand: with ``y = M^-1 Jc^T`` and ``S = Jc y``, ``lam = -(Jcdot qd + y . f) / S`` and ``qdd = M^-1 f + y lam``.
    ``f = B u - C qd - g`` gives total and lam, ``f = -C qd - g`` the drift and lam_drift (eq. 14). Returns
    ``(qdd, lam)``, lam a scalar."""
    y = Minv @ Jc
    lam = -(bias + y @ f) / (Jc @ y)
    return Minv @ f + y * lam, lam


def constrained_input_map(M, Jc, Spinv=None):  # noqa: N803
    """Article eq. (17): ``B_c = M^-1 [I - Jc^T S^+ Jc M^-1]`` with ``S = Jc M^-1 Jc^T`` (``Jc`` a row or k x n), so
    that ``qdd_ctrl = B_c B u``: ``S^+ = S^-1`` for a full-rank ``Jc``, else ``Spinv``, the pseudo-inverse over S's
    kept eigen-directions (:meth:`Spectrum.pinv`)."""
    Jc = np.atleast_2d(Jc)
    Minv = inv2(M) if np.shape(M) == (2, 2) else np.linalg.inv(M)
    projected = np.linalg.solve(Jc @ Minv @ Jc.T, Jc @ Minv) if Spinv is None else Spinv @ Jc @ Minv
    return Minv @ (np.eye(len(M)) - Jc.T @ projected)


@dataclass(frozen=True)
class Spectrum:
    """``S = Jc M^-1 Jc^T`` split by the backends' rule (:class:`Rule`): its eigenvalues ``w`` ascending
    (:func:`eigenvalues`), their eigen-directions ``V`` (columns), which are ``kept`` (the others are redundant
    directions) and ``w_max``, the largest eigenvalue taken at least the degenerate floor."""

    w: np.ndarray
    V: np.ndarray
    kept: np.ndarray
    w_max: float

    @property
    def rank(self) -> int:
        return int(self.kept.sum())

    def pinv(self) -> np.ndarray:
        """``S^+ = V_k diag(1 / w_k) V_k^T`` over the kept directions: ``S^-1`` at full rank; otherwise the
        minimum-norm multipliers ``S^+ r`` (the accelerations and ``Jc^T lam`` stay unique)."""
        V = self.V[:, self.kept]
        return (V / self.w[self.kept]) @ V.T

    def conditions(self) -> dict[str, float]:
        """``"constraint"`` = ``w_max / w_min`` (inf when ``w_min <= 0``) and ``"constraint_kept"`` = ``w_max`` over
        the smallest kept eigenvalue (1 when none is kept): the definitions in ``Split``'s docstring."""
        return {"constraint": self.w_max / self.w[0] if self.w[0] > 0.0 else float("inf"),
                "constraint_kept": self.w_max / self.w[self.kept][0] if self.rank else 1.0}

    def inconsistency(self, residuals, least: float) -> float:
        """``"constraint_consistency"``: the largest share ``|V_0^T r| / max(|r|, least)`` of the KKT right-hand
        sides ``r = -Jcdot qd - Jc M^-1 f`` in the redundant directions V_0 (0 when there are none, or r = 0):
        non-zero means ``H_t`` is empty (eq. 16)."""
        V0 = self.V[:, ~self.kept]
        shares = [np.linalg.norm(V0.T @ r) / size for r in residuals if (size := max(np.linalg.norm(r), least)) > 0]
        return float(max(shares, default=0.0)) if V0.shape[1] else 0.0


@dataclass(frozen=True)
class Rule:
    """The backends' rule for redundant and degenerate constraint rows (``formalisms.interface``): an eigenvalue of
    S at or below ``max(CONSTRAINT_RCOND w[-1], floor)`` is a redundant direction, ``floor = (DEGENERATE_ROW L)^2 /
    inertia``. The model's scales are written here from the case's parameters, not read off the model: ``length``
    L is ``Model.length_scale`` (1 m plus every body's placement and COM offsets, |translation| + |com|), ``inertia``
    is ``Model.inertia_scale`` (``sum_k m_k L^2 + tr I_k``); L also sets the consistency share's least |r|,
    ``1e-6 L accel_scale``."""

    length: float
    inertia: float

    @classmethod
    def of(cls, *bodies: tuple[float, float, float]) -> Rule:
        """From each massive body's (mass, |translation| + |com|, tr I), typed in from its case factory (massless
        bodies at the origin add nothing)."""
        length = 1.0 + sum(offset for _, offset, _ in bodies)
        return cls(length, sum(mass * length**2 + trace for mass, _, trace in bodies))

    @property
    def floor(self) -> float:
        return (DEGENERATE_ROW * self.length) ** 2 / self.inertia

    def spectrum(self, S) -> Spectrum:
        """S's :class:`Spectrum` under this rule."""
        w = eigenvalues(S)
        return Spectrum(w, np.linalg.eigh(np.atleast_2d(S))[1], w > max(CONSTRAINT_RCOND * w[-1], self.floor),
                        max(float(w[-1]), self.floor))


def rod_body(mass, length, placed=0.0) -> tuple[float, float, float]:
    """A uniform rod's entry of :meth:`Rule.of` (``cases.constrained._rod``): its COM l/2 beyond its joint, placed
    ``placed`` from its parent's frame, ``tr diag(m l^2/12, 0, m l^2/12) = m l^2/6``."""
    return mass, placed + length / 2.0, mass * length**2 / 6.0


def cartesian_lam(q, qd, u, m=1.0, L=1.0, g=9.81):  # noqa: N803
    """The cartesian pendulum's multiplier (``cases.cartesian_pendulum``: q = p = (x, y), M = m I, B = I,
    ``phi = |p|^2 - L^2`` so ``Jc = 2 p^T`` and ``Jcdot qd = 2 |v|^2``), eqs. (12)-(13) solved by hand:
    ``lam = -m (|v|^2 + p . (gravity + u / m)) / (2 L^2)`` with gravity (0, -g); u = 0 gives lam_drift (eq. 14).
    Plain arithmetic on the entries, so that it evaluates in mpmath too (:func:`cartesian_lam_mp`)."""
    (x, y), (xd, yd), (ux, uy) = q, qd, u
    return -m * (xd * xd + yd * yd + x * (ux / m) + y * (uy / m - g)) / (2 * L * L)


def cartesian_lam_mp(q, qd, u, m=1.0, L=1.0, g=9.81):  # noqa: N803
    """:func:`cartesian_lam` in mpmath at its working precision (arguments exact binary values); exact at a state
    exactly on the circle, |p| = L."""
    x, y, xd, yd, ux, uy, m, L, g = mp(*q, *qd, *u, m, L, g)
    return cartesian_lam((x, y), (xd, yd), (ux, uy), m, L, g)


def absolute_loop_state(t, td, l1=1.0):
    """The joint state (t, td) in the coordinates of ``cases.double_pendulum_absolute_loop``,
    ``q = (x1, y1, phi1, x2, y2, phi2)``: link 1's pivot at the origin, link 2's at link 1's end
    ``l1 (sin phi1, -cos phi1)``, absolute angles ``phi = (t1, t1 + t2)`` (6.4.6). Returns (q, qd)."""
    p1, p1d = t[0], td[0]
    q = np.array([0.0, 0.0, p1, l1 * np.sin(p1), -l1 * np.cos(p1), t[0] + t[1]])
    qd = np.array([0.0, 0.0, p1d, l1 * np.cos(p1) * p1d, l1 * np.sin(p1) * p1d, td[0] + td[1]])
    return q, qd


def loop_to_joint(a):
    """Absolute-loop accelerations (6,) (or rates) back to the joint coordinates: (phi1dd, phi2dd - phi1dd)."""
    return np.array([a[2], a[5] - a[2]])


def joint_to_loop(t, td, tdd, l1=1.0):
    """Joint accelerations tdd at (t, td) in the absolute loop's coordinates: the shoulder pivot fixed, link 2's
    pivot at mass 1's place, eq. (4) with l2 = 0 differentiated twice, angles ``phi = (t1, t1 + t2)``; td = 0 gives the
    linear part alone (what maps ctrl)."""
    a1 = endpoint_jacobian(t, l1, 0.0) @ tdd + tip_bias(t, td, l1, 0.0)
    return np.array([0.0, 0.0, tdd[0], a1[0], a1[1], tdd[0] + tdd[1]])


def pin_forces(t, td, tdd, m1=1.0, m2=1.0, l1=1.0, l2=1.0, g=9.81):
    """The pins' forces on the double pendulum at accelerations tdd, by Newton's second law for the masses of
    eq. (4) (the joint torques are couples): the elbow's on link 2, ``m2 (a2 - gravity)``, and the shoulder's on the
    whole chain, ``m1 a1 + m2 a2 - (m1 + m2) gravity``, with a_i eq. (4) differentiated twice and gravity (0, -g).
    Returns (shoulder, elbow), each (2,)."""
    gravity = np.array([0.0, -g])
    a1 = endpoint_jacobian(t, l1, 0.0) @ tdd + tip_bias(t, td, l1, 0.0)
    a2 = endpoint_jacobian(t, l1, l2) @ tdd + tip_bias(t, td, l1, l2)
    return m1 * a1 + m2 * a2 - (m1 + m2) * gravity, m2 * (a2 - gravity)


def loop_terms(q, qd, m1, m2, l1, l2, g, I1, I2):  # noqa: N803
    """(M, C qd, g) of the two free planar bodies of the absolute loop, q = (x1, y1, phi1, x2, y2, phi2), before the
    pins. Body b (pivot (x, y), angle phi, mass m at l (sin phi, -cos phi) from it, I about z):
        T = 1/2 m (xd^2 + yd^2) + m l phid (cos phi xd + sin phi yd) + 1/2 (m l^2 + I) phid^2,  V = m g (y - l cos phi),
    so its block is M = [[m, 0, m l cos phi], [0, m, m l sin phi], [m l cos phi, m l sin phi, m l^2 + I]],
    C qd = (-m l sin phi phid^2, m l cos phi phid^2, 0), g = (0, m g, m g l sin phi); the bodies do not couple."""
    M, Cqd, grav = np.zeros((6, 6)), np.zeros(6), np.zeros(6)
    for b, (m, l, inertia) in enumerate(((m1, l1, I1), (m2, l2, I2))):
        k = slice(3 * b, 3 * b + 3)
        phi, phid = q[3 * b + 2], qd[3 * b + 2]
        c, s = np.cos(phi), np.sin(phi)
        M[k, k] = [[m, 0.0, m * l * c], [0.0, m, m * l * s], [m * l * c, m * l * s, m * l * l + inertia]]
        Cqd[k] = (-m * l * s * phid**2, m * l * c * phid**2, 0.0)
        grav[k] = (0.0, m * g, m * g * l * s)
    return M, Cqd, grav


def loop_constraint(q, qd, l1):
    """The absolute loop's pins (``PointsCoincide`` rows along x, y): the shoulder, link 1's pivot at the origin,
    phi = (x1, y1); the elbow, link 2's pivot at link 1's end, phi = (x2 - x1 - l1 sin phi1, y2 - y1 + l1 cos phi1).
    Jc = [[1, 0, 0, 0, 0, 0], [0, 1, 0, 0, 0, 0], [-1, 0, -l1 cos phi1, 1, 0, 0], [0, -1, -l1 sin phi1, 0, 1, 0]] and
    Jcdot qd = (0, 0, l1 sin phi1 phi1d^2, -l1 cos phi1 phi1d^2). Returns (phi (4,), Jc (4, 6), Jcdot qd (4,))."""
    c, s, w2 = np.cos(q[2]), np.sin(q[2]), qd[2]**2
    phi = np.array([q[0], q[1], q[3] - q[0] - l1 * s, q[4] - q[1] + l1 * c])
    Jc = np.array([[1.0, 0.0, 0.0, 0.0, 0.0, 0.0], [0.0, 1.0, 0.0, 0.0, 0.0, 0.0],
                   [-1.0, 0.0, -l1 * c, 1.0, 0.0, 0.0], [0.0, -1.0, -l1 * s, 0.0, 1.0, 0.0]])
    return phi, Jc, np.array([0.0, 0.0, l1 * s * w2, -l1 * c * w2])


# --------------------------------------------------------------- closed loops of rods, a rail and a gear


def four_bar_terms(q, qd, crank, coupler, rocker, m, g):
    """(M, C qd, g) of ``cases.four_bar``'s open tree (before the loop closes): crank and coupler a chain of uniform
    rods from the origin, the rocker a rod on its own pivot (where the pivot is does not enter its dynamics), each of
    mass m. In absolute angles ``phi = T q = (q1, q1 + q2, q3)`` (:data:`CHAIN_AND_ONE`) the chain and the rocker
    are :func:`rod_chain_terms` side by side (:func:`stack_terms`: they do not couple), mapped to q by
    :func:`to_joint`. With a, b, c the crank, coupler and rocker lengths and d = phi1 - phi2:
        M_phi = [[4/3 m a^2, m a b/2 cos d, 0], [m a b/2 cos d, m b^2/3, 0], [0, 0, m c^2/3]],
        C_phi qd = m a b/2 sin(d) (phi2d^2, -phi1d^2, 0),  g_phi = m g (3/2 a sin phi1, b/2 sin phi2, c/2 sin phi3)."""
    T = CHAIN_AND_ONE
    phi, phid = T @ q, T @ qd
    return to_joint(T, *stack_terms(rod_chain_terms(phi[:2], phid[:2], (m, m), (crank, coupler), g),
                                    rod_chain_terms(phi[2:], phid[2:], (m,), (rocker,), g)))


def four_bar_loop(q, qd, crank, coupler, rocker, ground):
    """The four-bar's loop (``PointsCoincide`` rows x, y): ``phi = p_coupler_end - p_rocker_end``, with e(phi) =
    (sin phi, -cos phi), ``phi = a e(phi1) + b e(phi2) - c e(phi3) - (ground, 0)``: the chain crank, coupler, rocker
    walked back (length -c) from the origin, less the rocker's pivot (:func:`chain_position`). Its Jacobian and
    ``Jcdot qd`` in absolute angles are :func:`chain_tip`'s with lengths (a, b, -c), so with w = q1d + q2d
        Jc = [[a c1 + b c12, b c12, -c c3], [a s1 + b s12, b s12, -c s3]],
        Jcdot qd = (-a s1 q1d^2 - b s12 w^2 + c s3 q3d^2, a c1 q1d^2 + b c12 w^2 - c c3 q3d^2).
    Jc loses rank where the four links are collinear (a change point, possible only when a +- b = +-c + ground).
    Returns (phi (2,), Jc (2, 3), Jcdot qd (2,))."""
    phi, phid, lengths = CHAIN_AND_ONE @ q, CHAIN_AND_ONE @ qd, (crank, coupler, -rocker)
    J, bias = chain_tip(phi, phid, lengths)
    return chain_position(phi, lengths) - np.array([ground, 0.0]), J @ CHAIN_AND_ONE, bias


def link_point(q, qd, crank, along):
    """A point ``along`` the second link of a two-link chain in relative angles, as the first two coordinates of
    ``q`` (``four_bar``'s ``coupler_mid``, along = coupler / 2): its Jacobian (2 x n) and ``Jdot qd``, by
    :func:`chain_tip` with lengths (crank, along) and ``J_q = J_phi T`` (:data:`CHAIN_AND_ONE`'s first rows)."""
    T = CHAIN_AND_ONE[:2, :len(q)]
    J, bias = chain_tip(T @ q, T @ qd, (crank, along))
    return J @ T, bias


def slider_crank_terms(q, qd, crank, rod, m_crank, m_rod, m_slider, g):
    """(M, C qd, g) of ``cases.slider_crank``'s open tree: crank and connecting rod a chain of uniform rods
    (:func:`rod_chain_terms` in absolute angles, mapped to q by :func:`to_joint` with :data:`CHAIN_AND_ONE`) and the
    slider, a point mass on a prismatic joint along x: ``T = 1/2 m_slider xd^2`` and a constant V (its height is the
    offset), so its block is ``M = m_slider``, ``C qd = g = 0``. With a, r the crank and rod lengths, d = phi1 - phi2:
        M_phi = [[(m_crank/3 + m_rod) a^2, m_rod a r/2 cos d, 0], [m_rod a r/2 cos d, m_rod r^2/3, 0],
                 [0, 0, m_slider]],  C_phi qd = m_rod a r/2 sin(d) (phi2d^2, -phi1d^2, 0),
        g_phi = g ((m_crank/2 + m_rod) a sin phi1, m_rod r/2 sin phi2, 0)."""
    T = CHAIN_AND_ONE
    phi, phid = T @ q, T @ qd
    slider = (np.array([[m_slider]]), np.zeros(1), np.zeros(1))
    return to_joint(T, *stack_terms(rod_chain_terms(phi[:2], phid[:2], (m_crank, m_rod), (crank, rod), g), slider))


def wrist_pin(q, qd, crank, rod, offset):
    """The slider-crank's wrist pin (``PointsCoincide`` rows x, y): ``phi = p_rod_end - p_slider = a e(phi1) +
    r e(phi2) - (x, offset)`` (:func:`chain_position`, e(phi) = (sin phi, -cos phi)); ``Jc`` is the chain's
    Jacobian (:func:`chain_tip`, :func:`link_point` with along = r) with the column (-1, 0) of x, ``Jcdot qd`` the
    chain's (x enters linearly):
        Jc = [[a c1 + r c12, r c12, -1], [a s1 + r s12, r s12, 0]],
        Jcdot qd = (-a s1 q1d^2 - r s12 w^2, a c1 q1d^2 + r c12 w^2), w = q1d + q2d.
    Full rank everywhere: the second row vanishes only with crank and rod both vertical, their end at height
    +-a +-r, which cannot meet the slider's line since r > a + |offset|. Returns (phi, Jc, Jcdot qd)."""
    J, bias = link_point(q, qd, crank, rod)
    J[0, 2] = -1.0
    return chain_position(CHAIN_AND_ONE[:2] @ q, (crank, rod)) - np.array([q[2], offset]), J, bias


def rail_normal(incline):
    """The normal of a rail at ``incline`` rad from the x axis, ``n = (-sin incline, cos incline)``: the one row of
    ``cases.double_pendulum_rail``'s ``PointOnLine``."""
    return np.array([-np.sin(incline), np.cos(incline)])


def rail_terms(t, td, l1=1.0, l2=1.0, x0=0.0, y0=-1.2, incline=0.3):
    """The double pendulum's tip on the straight rail through o = (x0, y0) with normal n (:func:`rail_normal`),
    ``cases.double_pendulum_rail``'s ``PointOnLine``: ``phi = n . (x2 - o)`` with x2 of eq. (4), ``Jc = n^T J``
    (eq. 5) and ``Jcdot qd = n . (Jdot qd)`` (:func:`tip_bias`; a straight line has no curvature term, compare
    :func:`circle_terms`). Returns (phi (1,), Jc (1, 2), Jcdot qd (1,))."""
    n = rail_normal(incline)
    return (np.array([n @ (tip_position(t, l1, l2) - np.array([x0, y0]))]), (n @ endpoint_jacobian(t, l1, l2))[None],
            np.array([n @ tip_bias(t, td, l1, l2)]))


def gear_terms(q, qd, m1, l1, m2, l2, g):
    """(M, C qd, g) of ``cases.geared_pendulums`` before the gear couples them: two uniform rods on their own pivots,
    :func:`rod_chain_terms` of one rod each side by side: ``M = diag(m1 l1^2/3, m2 l2^2/3)``, ``C qd = 0``,
    ``g = g (m1 l1/2 sin q1, m2 l2/2 sin q2)``."""
    return stack_terms(rod_chain_terms(q[:1], qd[:1], (m1,), (l1,), g), rod_chain_terms(q[1:], qd[1:], (m2,), (l2,), g))


def gear_constraint(q, ratio, offset):
    """The gear (``JointCoupling`` with coefficients (1, -ratio)): ``phi = q1 - ratio q2 - offset``, the constant
    row ``Jc = (1, -ratio)``, ``Jcdot qd = 0``; so ``Jc^T lam = (lam, -ratio lam)``: lam is the gear's torque on
    the pinion (joint 1), ``-ratio lam`` the torque on the wheel. Returns (phi (1,), Jc (1, 2), Jcdot qd (1,))."""
    return np.array([q[0] - ratio * q[1] - offset]), np.array([[1.0, -ratio]]), np.zeros(1)
