"""Closed forms of the built-in cases, and the gate's voter ``closed_form``.

The five formalisms and the Pinocchio reference all read the same :class:`~cases.model.Model`: a bug in a case
factory or in the model language (an inertia rotated the wrong way, a length read from the wrong parameter) moves all
six together, and their vote cannot see it. A closed form does not read the model: it is bound to the case BY NAME
and computes every quantity from the case's TYPED PARAMETERS (``cases.parameters``) and the state alone, from
equations typed in from the article or derived by hand in the docstrings below. The only things it reads off the
model are its shape (coordinates n, inputs m, constraint rows k) and its name, to refuse a model that is not the case
it was written for (:class:`ClosedFormMismatch`, an error of the voter: a failure of the gate, never a silent NOT
COMPARED).

    >>> from crosscheck.engine import evaluation
    >>> from crosscheck.references import closed_forms
    >>> voter = closed_forms.voter("double_pendulum", {"l2": "0.7"})     # None where no closed form exists
    >>> outcome = evaluation.evaluate(cases.load("double_pendulum", l2="0.7"), state, [*backends, voter])

Cases and their equations (:func:`coverage` says the same for one case):

=============================  =====================================================================================
double_pendulum                article section 3: eqs. (4)-(9), point masses plus planar disk inertias I1, I2
n_link_pendulum                the Lagrangian in absolute angles (:func:`chain_terms`) mapped to relative angles
acrobot                        Spong's equations, angles from hanging down (:func:`acrobot_terms`)
double_pendulum_circle         article 5.6: eqs. (12)-(17) with one circle row (:func:`circle_terms`)
cartesian_pendulum             the multiplier of eqs. (12)-(13) solved by hand (:func:`cartesian_lam`)
double_pendulum_absolute_loop  the double pendulum's accelerations in the loop's coordinates, its multipliers the pins'
                               forces by Newton's second law (:func:`pin_forces`)
rotor                          one body on a tilted revolute joint (:func:`rotor_terms`)
inclined_slider                a point mass on a tilted prismatic joint (:func:`slider_terms`)
spherical_pendulum             a ball on two perpendicular revolute joints (:func:`spherical_terms`)
four_bar                       three uniform rods (:func:`rod_chain_terms`: a rod is three point masses) in absolute
                               angles mapped to relative (:func:`four_bar_terms`), the loop's two rows
                               (:func:`four_bar_loop`); minimum-norm multipliers at the change points
slider_crank                   two rods and a point-mass slider (:func:`slider_crank_terms`), the wrist pin's two rows
                               (:func:`wrist_pin`)
double_pendulum_rail           eqs. (4)-(8) with the tip on a straight rail, a ``PointOnLine`` row (:func:`rail_terms`)
geared_pendulums               two rods coupled by a gear, a ``JointCoupling`` row (:func:`gear_terms`,
                               :func:`gear_constraint`)
free_body                      Newton's and Euler's equations in the body frame (:func:`free_body_terms`)
knife_edge                     the Chaplygin sleigh: Newton and Euler along and across the runner, a ``KnifeEdge``
                               (Pfaffian) row (:func:`sleigh_terms`, :func:`sleigh_motion`)
rolling_disk                   the classical rolling disk (Neimark-Fufaev, Bloch 1.4): the centre's velocity and the
                               angular velocity in the heading frame, the contact's two ``RollingContact`` rows
                               (:func:`disk_terms`, :func:`disk_center`)
double_pendulum_tip_force      eqs. (4)-(9) with ``tau_ext = J^T f`` of a world force at the tip (:func:`tip_force`)
double_pendulum_spring         eqs. (4)-(9) with a tip spring and a body-frame wrench on link 2 (:func:`tip_spring`)
differential_drive             Newton-Euler of chassis and wheels in the forward speed and the turning rate, the two
                               rolling-direction rows and the axle's row, the payload's ``tau_ext = J^T F``
                               (:func:`drive_terms`, :func:`drive_motion`, :func:`drive_load`)
=============================  =====================================================================================

Each supplies drift, ctrl and total (eq. 9; eqs. 14, 15, 17 with constraints; ctrl ``B_c B u`` computed directly),
the control power, the kinetic energy, the task drift and the task inertia (eq. 22, with ``conditions
["task_inertia"]``), and on the constrained cases lam, lam_drift, the constraint kinematics, forces and power. The
joint loads are not supplied (UNSUPPORTED: "not supplied by" in a report). cond(M), ``accel_scale`` and the
constraint conditions are computed here, from these closed forms, by the definitions of ``Split.accel_scale``,
``lam_scale`` and the conditions (no numeric helper of the harness is used). Where S = Jc M^-1 Jc^T is singular (the
four-bar's change points) a closed form follows the backends' rule for redundant rows (:class:`Rule`, with the
model's length and inertia scales typed in from the factory): the minimum-norm multipliers and the same
``constraint``, ``constraint_kept`` and ``constraint_consistency`` conditions (:func:`_constrained`).

The double-pendulum formulas (:func:`article_M`, :func:`article_Cqd`, :func:`article_g`, :func:`pendulum_terms`)
evaluate in double precision or, with ``lib=MPMATH``, in mpmath (:func:`pendulum_terms_mp`): one typing of eqs.
(6)-(8) for both. The tests' ``tests/closed_forms.py`` re-exports this module.
"""

from __future__ import annotations

from dataclasses import dataclass
from functools import partial
from typing import Callable, Mapping

import mpmath
import numpy as np
import scipy.linalg

import cases
from formalisms.interface import CONSTRAINT_RCOND, DEGENERATE_ROW, Formalism, Split, check_state

EPS = float(np.finfo(float).eps)


class ClosedFormMismatch(ValueError):
    """The model given to a closed form is not the case and parameters it was bound to (another case's model, or a
    shape that the parameters do not give): the message names the case, its parameters and what does not match."""


@dataclass(frozen=True)
class Arithmetic:
    """What a closed form needs from a number system: ``sin``, ``cos`` and ``array`` (rows to a matrix, a list to a
    vector): double precision (:data:`FLOAT`, numpy arrays) or mpmath (:data:`MPMATH`, mpmath matrices)."""

    sin: Callable
    cos: Callable
    array: Callable


FLOAT = Arithmetic(np.sin, np.cos, lambda rows: np.array(rows, dtype=float))
MPMATH = Arithmetic(mpmath.sin, mpmath.cos, mpmath.matrix)


# ------------------------------------------------------------------------------------- small linear algebra


def inv2(M):
    """The 2x2 inverse of article 4.7.2: M^-1 = (1 / det M) [[M22, -M12], [-M21, M11]], det M = M11 M22 - M12 M21
    (the article writes M12^2: M is symmetric)."""
    det = M[0, 0] * M[1, 1] - M[0, 1] * M[1, 0]
    return np.array([[M[1, 1], -M[0, 1]], [-M[1, 0], M[0, 0]]]) / det


def eigenvalues(A) -> np.ndarray:
    """Ascending eigenvalues of a symmetric matrix: in closed form for 1x1 and 2x2 ``[[a, b], [b, c]]`` (the larger
    ``(a + c) / 2 + hypot((a - c) / 2, b)``, the smaller ``det / larger``, which keeps the smaller one's relative
    accuracy when it is tiny), numpy's ``eigvalsh`` beyond."""
    A = np.atleast_2d(np.asarray(A, dtype=float))
    if A.shape == (1, 1):
        return A[0].copy()
    if A.shape == (2, 2):
        a, b, c = A[0, 0], 0.5 * (A[0, 1] + A[1, 0]), A[1, 1]
        high = 0.5 * (a + c) + np.hypot(0.5 * (a - c), b)
        low = (a * c - b * b) / high if high > 0.0 else 0.5 * (a + c) - np.hypot(0.5 * (a - c), b)
        return np.array([low, high])
    return np.linalg.eigvalsh(A)


def condition(A) -> float:
    """cond(A) of a symmetric positive (semi-)definite A (:func:`eigenvalues`), inf where A is numerically singular:
    its smallest eigenvalue not above ``k eps`` times its largest (an eigensolver's absolute accuracy), or not
    finite."""
    w = eigenvalues(A)
    return float(w[-1] / w[0]) if np.all(np.isfinite(w)) and w[0] > len(w) * EPS * w[-1] else float("inf")


def task_inertia_square(J, M) -> tuple[np.ndarray, float]:
    """Eq. (22) for a square task Jacobian: ``Lambda = (J M^-1 J^T)^-1 = J^-T M J^-1`` and ``cond(J M^-1 J^T) =
    cond(Lambda)``, with J's 2x2 inverse (4.7.2); ``(NaN, inf)`` where J or Lambda is numerically singular."""
    if J[0, 0] * J[1, 1] - J[0, 1] * J[1, 0] == 0.0:
        return np.full((2, 2), np.nan), float("inf")
    Jinv = inv2(J)
    Lambda = Jinv.T @ M @ Jinv
    cond = condition(Lambda)
    return (Lambda if np.isfinite(cond) else np.full((2, 2), np.nan)), cond


def task_inertia(J, Minv) -> tuple[np.ndarray, float]:
    """Eq. (22): ``Lambda = (J M^-1 J^T)^-1`` and ``cond(J M^-1 J^T)`` for a k x n J (1 x 1 and 2 x 2 by hand, 4.7.2;
    numpy's inverse beyond); ``(NaN, inf)`` where ``J M^-1 J^T`` is numerically singular, and always when k > n (more
    task directions than joints)."""
    J = np.atleast_2d(J)
    A = J @ Minv @ J.T
    cond = condition(A) if J.shape[0] <= J.shape[1] else float("inf")
    if not np.isfinite(cond):
        return np.full(A.shape, np.nan), cond
    return (1.0 / A if A.shape == (1, 1) else inv2(A) if A.shape == (2, 2) else np.linalg.inv(A)), cond


# --------------------------------------------------------------------- the double pendulum (article section 3)


def endpoint_jacobian(t, l1=1.0, l2=1.0):
    """Article eq. (5): J(q) = [[l1 cos t1 + l2 cos(t1 + t2), l2 cos(t1 + t2)],
                                [l1 sin t1 + l2 sin(t1 + t2), l2 sin(t1 + t2)]]."""
    c1, s1, c12, s12 = np.cos(t[0]), np.sin(t[0]), np.cos(t[0] + t[1]), np.sin(t[0] + t[1])
    return np.array([[l1 * c1 + l2 * c12, l2 * c12], [l1 * s1 + l2 * s12, l2 * s12]])


def tip_position(t, l1=1.0, l2=1.0):
    """Article eq. (4): the tip (mass 2) at x2 = l1 sin t1 + l2 sin(t1 + t2), y2 = -l1 cos t1 - l2 cos(t1 + t2)."""
    return np.array([l1 * np.sin(t[0]) + l2 * np.sin(t[0] + t[1]), -l1 * np.cos(t[0]) - l2 * np.cos(t[0] + t[1])])


def tip_bias(t, td, l1=1.0, l2=1.0):
    """``Jdot qd`` of the tip: eq. (4) differentiated twice at tdd = 0, with w = t1d + t2d,
    (-l1 sin t1 t1d^2 - l2 sin(t1 + t2) w^2, l1 cos t1 t1d^2 + l2 cos(t1 + t2) w^2); the tip's classical
    acceleration is ``endpoint_jacobian(t) @ tdd + tip_bias(t, td)`` (eq. 23). With l2 = 0 it is mass 1's."""
    w = td[0] + td[1]
    return np.array([-l1 * np.sin(t[0]) * td[0]**2 - l2 * np.sin(t[0] + t[1]) * w**2,
                     l1 * np.cos(t[0]) * td[0]**2 + l2 * np.cos(t[0] + t[1]) * w**2])


def article_M(t2, m1=1.0, m2=1.0, l1=1.0, l2=1.0, lib=FLOAT):
    """Article eq. (6): M11 = (m1 + m2) l1^2 + m2 l2^2 + 2 m2 l1 l2 cos t2, M12 = M21 = m2 l2^2 + m2 l1 l2 cos t2,
    M22 = m2 l2^2."""
    c2 = lib.cos(t2)
    M12 = m2 * l2**2 + m2 * l1 * l2 * c2
    return lib.array([[(m1 + m2) * l1**2 + m2 * l2**2 + 2 * m2 * l1 * l2 * c2, M12], [M12, m2 * l2**2]])


def article_Cqd(t2, t1d, t2d, m2=1.0, l1=1.0, l2=1.0, lib=FLOAT):
    """Article eq. (7): C qd = [-2 c t1d t2d - c t2d^2, c t1d^2] with c = m2 l1 l2 sin t2 (m1 does not enter)."""
    c = m2 * l1 * l2 * lib.sin(t2)
    return lib.array([-2 * c * t1d * t2d - c * t2d**2, c * t1d**2])


def article_g(t1, t2, m1=1.0, m2=1.0, l1=1.0, l2=1.0, g=9.81, lib=FLOAT):
    """Article eq. (8): g(q) = [(m1 + m2) g l1 sin t1 + m2 g l2 sin(t1 + t2), m2 g l2 sin(t1 + t2)]."""
    s12 = lib.sin(t1 + t2)
    return lib.array([(m1 + m2) * g * l1 * lib.sin(t1) + m2 * g * l2 * s12, m2 * g * l2 * s12])


def pendulum_terms(t, td, m1=1.0, m2=1.0, l1=1.0, l2=1.0, g=9.81, lib=FLOAT):
    """(M, C qd, g) of article eqs. (6), (7), (8) at angles ``t`` = (theta1, theta2) and rates ``td``."""
    return (article_M(t[1], m1, m2, l1, l2, lib), article_Cqd(t[1], td[0], td[1], m2, l1, l2, lib),
            article_g(t[0], t[1], m1, m2, l1, l2, g, lib))


def _mp(*values):
    """The arguments as mpmath numbers at the working precision, each float taken as its exact binary value."""
    return [mpmath.mpf(float(x)) for x in values]


def pendulum_terms_mp(t, td, m1=1.0, m2=1.0, l1=1.0, l2=1.0, g=9.81):
    """Eqs. (6), (7), (8) (:func:`pendulum_terms`) in mpmath at its working precision, every argument taken as its
    exact binary value: (M, C qd, g) as mpmath matrices (2 x 2, 2 x 1, 2 x 1)."""
    t1, t2, t1d, t2d, m1, m2, l1, l2, g = _mp(*t, *td, m1, m2, l1, l2, g)
    return pendulum_terms((t1, t2), (t1d, t2d), m1, m2, l1, l2, g, MPMATH)


def disk_inertia(I1=0.0, I2=0.0):  # noqa: N803
    """What rotational inertias I1, I2 of the masses about z (``cases.double_pendulum(I1=.., I2=..)``, planar disks)
    add to eq. (6): T gains 1/2 I1 t1d^2 + 1/2 I2 (t1d + t2d)^2, so M gains [[I1 + I2, I2], [I2, I2]] (C qd and g
    are unchanged)."""
    return np.array([[I1 + I2, I2], [I2, I2]])


# ------------------------------------------------------------------------ planar chains in absolute angles


def chain_terms(phi, phid, masses, lengths, g=9.81):
    """(M, C qd, g) of a planar chain of point masses m_k at the ends of links l_k, hanging from a fixed pivot, in
    the links' absolute angles phi (from hanging down; article 6.4.6 for two links).

    Mass k sits at sum_{i<=k} l_i (sin phi_i, -cos phi_i). With mu_ij = sum_{k >= max(i, j)} m_k (the masses outboard
    of both links) the Lagrangian is
        T = 1/2 sum_ij mu_ij l_i l_j cos(phi_i - phi_j) phid_i phid_j,   V = -g sum_i mu_ii l_i cos phi_i,
    and Lagrange's equations give M_ij = mu_ij l_i l_j cos(phi_i - phi_j),
    (C qd)_i = sum_j mu_ij l_i l_j sin(phi_i - phi_j) phid_j^2, g_i = g mu_ii l_i sin phi_i.
    Equal masses m and lengths l (``n_link_pendulum``): M_ij = m l^2 (n - max(i, j) + 1) cos(phi_i - phi_j)
    (1-based i, j)."""
    phi, phid, l = (np.asarray(x, dtype=float) for x in (phi, phid, lengths))
    outboard = np.cumsum(np.asarray(masses, dtype=float)[::-1])[::-1]
    idx = np.arange(len(phi))
    mu = outboard[np.maximum.outer(idx, idx)]
    d = np.subtract.outer(phi, phi)
    M = mu * np.outer(l, l) * np.cos(d)
    Cqd = (mu * np.outer(l, l) * np.sin(d)) @ phid**2
    return M, Cqd, g * outboard * l * np.sin(phi)


def absolute_terms(phi, phid, m1=1.0, m2=1.0, l1=1.0, l2=1.0, g=9.81):
    """(M, C qd, g) of the double pendulum in absolute angles phi = (theta1, theta1 + theta2) (article 6.4.6):
    :func:`chain_terms` of two links, M = [[(m1 + m2) l1^2, m2 l1 l2 cos d], [m2 l1 l2 cos d, m2 l2^2]],
    C qd = m2 l1 l2 sin(d) [phi2d^2, -phi1d^2], g = [(m1 + m2) g l1 sin phi1, m2 g l2 sin phi2], d = phi1 - phi2."""
    return chain_terms(phi, phid, (m1, m2), (l1, l2), g)


def chain_tip(phi, phid, lengths):
    """The chain's last mass in absolute angles: its Jacobian ``dp/dphi`` (2 x n, columns l_i (cos phi_i,
    sin phi_i)) and ``Jdot phid = sum_i l_i (-sin phi_i, cos phi_i) phid_i^2``."""
    phi, phid, l = (np.asarray(x, dtype=float) for x in (phi, phid, lengths))
    return (np.array([l * np.cos(phi), l * np.sin(phi)]),
            np.array([-(l * np.sin(phi)) @ phid**2, (l * np.cos(phi)) @ phid**2]))


def chain_position(phi, lengths):
    """The chain's last point in absolute angles: ``sum_i l_i (sin phi_i, -cos phi_i)`` from the pivot (eq. 4 for two
    links); :func:`chain_tip` is its Jacobian and ``Jdot phid``. A negative l_i walks link i back from its end."""
    phi, l = np.asarray(phi, dtype=float), np.asarray(lengths, dtype=float)
    return np.array([l @ np.sin(phi), -(l @ np.cos(phi))])


def relative_to_absolute(n: int) -> np.ndarray:
    """T with ``phi = T q``: lower-triangular ones (each absolute angle is the sum of the relative ones up to it).
    T is constant, so ``M_q = T^T M_phi T``, ``h_q = T^T h_phi`` (:func:`to_joint`) and ``J_q = J_phi T``."""
    return np.tril(np.ones((n, n)))


#: T of a two-link chain in relative angles plus one more coordinate (``four_bar``: the rocker's angle;
#: ``slider_crank``: the slider's x): ``phi = T q = (q1, q1 + q2, q3)``.
CHAIN_AND_ONE = scipy.linalg.block_diag(relative_to_absolute(2), np.eye(1))


def to_joint(T, M, Cqd, g):
    """(M, C qd, g) in coordinates phi mapped to q, where ``phi = T q`` with T constant: the Lagrangian in q is the
    one in phi at ``T q``, so Lagrange's equations give ``(T^T M T, T^T C qd, T^T g)``."""
    return T.T @ M @ T, T.T @ Cqd, T.T @ g


def stack_terms(*terms):
    """(M, C qd, g) of independent subsystems (no shared coordinate, no coupling) side by side: M block-diagonal,
    C qd and g concatenated."""
    return (scipy.linalg.block_diag(*(t[0] for t in terms)), np.concatenate([t[1] for t in terms]),
            np.concatenate([t[2] for t in terms]))


def rod_chain_terms(phi, phid, masses, lengths, g=9.81):
    """(M, C qd, g) of a planar chain of uniform rods hanging from a fixed pivot, in the rods' absolute angles phi
    (from hanging down): rod k of mass m_k and length l_k, its COM at mid-length and ``m_k l_k^2 / 12`` about it
    (``cases.constrained._rod``).

    In the plane a rigid body's T and V depend only on its mass, its COM and its moment about the COM, so a uniform
    rod is the three point masses m/6 at its pivot, 2m/3 at its middle and m/6 at its end (mass m, COM at l/2,
    moment 2 (m/6) (l/2)^2 = m l^2/12). The chain of rods is then :func:`chain_terms`'s chain of point masses on
    half-links l_k/2, two per rod at the rod's angle, with 2 m_k/3 at the middle of rod k and m_k/6 + m_{k+1}/6 at
    its end (the first rod's pivot mass does not move); with E the constant matrix repeating each angle
    (half-link angles E phi), ``M = E^T M_half E``, ``C qd = E^T (C qd)_half``, ``g = E^T g_half`` (:func:`to_joint`).
    Two rods, d = phi1 - phi2:
        M = [[(m1/3 + m2) l1^2, m2 l1 l2/2 cos d], [m2 l1 l2/2 cos d, m2 l2^2/3]],
        C qd = m2 l1 l2/2 sin(d) (phi2d^2, -phi1d^2),  g = g ((m1/2 + m2) l1 sin phi1, m2 l2/2 sin phi2);
    one rod: M = m l^2/3, C qd = 0, g = m g l/2 sin phi."""
    m, l = np.asarray(masses, dtype=float), np.asarray(lengths, dtype=float)
    E = np.repeat(np.eye(len(m)), 2, axis=0)
    half_masses = np.column_stack([2.0 * m / 3.0, (m + np.append(m[1:], 0.0)) / 6.0]).ravel()
    terms = chain_terms(E @ phi, E @ phid, half_masses, np.repeat(l / 2.0, 2), g)
    return to_joint(E, *terms)


# ---------------------------------------------------------------------------------------------------- acrobot


def acrobot_terms(q, qd, m1, m2, l1, lc1, lc2, I1, I2, g):  # noqa: N803
    """(M, C qd, g) of Spong's acrobot (Spong 1995), with angles from hanging down (``cases.acrobot``; Spong's q1 is
    from the horizontal, so his cos q1 is sin q1 here) and q2 relative; link i's COM at lci along it, Ii about it:
        M11 = m1 lc1^2 + m2 (l1^2 + lc2^2 + 2 l1 lc2 cos q2) + I1 + I2,  M12 = m2 (lc2^2 + l1 lc2 cos q2) + I2,
        M22 = m2 lc2^2 + I2;  C qd = [-2 h q1d q2d - h q2d^2, h q1d^2], h = m2 l1 lc2 sin q2;
        g = [(m1 lc1 + m2 l1) g sin q1 + m2 lc2 g sin(q1 + q2), m2 lc2 g sin(q1 + q2)]."""
    c2, h, s12 = np.cos(q[1]), m2 * l1 * lc2 * np.sin(q[1]), np.sin(q[0] + q[1])
    M12 = m2 * (lc2**2 + l1 * lc2 * c2) + I2
    M = np.array([[m1 * lc1**2 + m2 * (l1**2 + lc2**2 + 2.0 * l1 * lc2 * c2) + I1 + I2, M12],
                  [M12, m2 * lc2**2 + I2]])
    Cqd = np.array([-2.0 * h * qd[0] * qd[1] - h * qd[1]**2, h * qd[0]**2])
    grav = np.array([(m1 * lc1 + m2 * l1) * g * np.sin(q[0]) + m2 * lc2 * g * s12, m2 * lc2 * g * s12])
    return M, Cqd, grav


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
    x, y, xd, yd, ux, uy, m, L, g = _mp(*q, *qd, *u, m, L, g)
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


# ------------------------------------------------------------------------------------------------- 3-D cases

#: The rotor's task point in its body frame (``cases.rotor``: the point ``rim``, along world x).
ROTOR_RIM = (0.4, 0.1, -0.2)


def turn(a, v, angle):
    """``v`` turned by ``angle`` about the unit axis ``a`` (Rodrigues): v cos + (a x v) sin + a (a . v)(1 - cos).
    Its derivative in the angle is ``a x turn(a, v, angle)``."""
    a, v = np.asarray(a, dtype=float), np.asarray(v, dtype=float)
    return v * np.cos(angle) + np.cross(a, v) * np.sin(angle) + a * (a @ v) * (1.0 - np.cos(angle))


def rotor_terms(q, qd, m, cx, cy, cz, Ia, Ib, Ic, spin, tilt, azimuth, g):  # noqa: N803
    """``cases.rotor`` by hand: M (1x1), C qd, g and the task point's Jacobian and ``Jdot qd``.

    Axis a = (sin tilt cos azimuth, sin tilt sin azimuth, cos tilt); principal axes P = cos(spin) 1 + sin(spin) K +
    (1 - cos(spin)) k k^T with k = (1, 1, 1) / sqrt 3 and K = [k]x; COM c = (cx, cy, cz) (body frame, which is the
    joint frame turned by q about a). The inertia about the joint axis is constant:
        M = a . (P diag(Ia, Ib, Ic) P^T + m (|c|^2 1 - c c^T)) a = a . P diag P^T a + m |a x c|^2,
    so C qd = 0; the COM's height is e_z . turn(a, c, q), V = m g e_z . turn(a, c, q), g(q) = m g (a x turn(a, c, q))_z.
    The task point r = ROTOR_RIM at p = turn(a, r, q): J = (a x p)_x, Jdot qd = (a x (a x p))_x qd^2.
    Returns (M, C qd, g, J, Jdot qd) as arrays (1, 1), (1,), (1,), (1, 1), (1,)."""
    a = np.array([np.sin(tilt) * np.cos(azimuth), np.sin(tilt) * np.sin(azimuth), np.cos(tilt)])
    cs, ss = np.cos(spin), np.sin(spin)
    K = np.array([[0.0, -1.0, 1.0], [1.0, 0.0, -1.0], [-1.0, 1.0, 0.0]]) / np.sqrt(3.0)
    P = cs * np.eye(3) + ss * K + (1.0 - cs) * np.full((3, 3), 1.0 / 3.0)
    c = np.array([cx, cy, cz])
    pa = P.T @ a
    M = pa @ (np.array([Ia, Ib, Ic]) * pa) + m * np.cross(a, c) @ np.cross(a, c)
    grav = m * g * np.cross(a, turn(a, c, q[0]))[2]
    p = turn(a, ROTOR_RIM, q[0])
    J = np.cross(a, p)[0]
    return (np.array([[M]]), np.zeros(1), np.array([grav]), np.array([[J]]),
            np.array([np.cross(a, np.cross(a, p))[0] * qd[0]**2]))


def slider_terms(m, incline, g):
    """``cases.inclined_slider`` by hand: the slide a = (cos incline cos azimuth, cos incline sin azimuth,
    sin incline), the mass at its origin + q a, so T = 1/2 m qd^2: M = m, C qd = 0, V = m g q sin(incline),
    g = m g sin(incline); the task (the height) z = q sin(incline): J = sin(incline), Jdot qd = 0 (the azimuth does
    not enter). Returns (M, C qd, g, J, Jdot qd) as arrays (1, 1), (1,), (1,), (1, 1), (1,)."""
    s = np.sin(incline)
    return np.array([[m]]), np.zeros(1), np.array([m * g * s]), np.array([[s]]), np.zeros(1)


def spherical_terms(q, qd, m, l, Ix, Iy, Iz, g):  # noqa: E741, N803
    """``cases.spherical_pendulum`` by hand: the ball at p = R_x(q1) R_y(q2) (0, 0, -l) =
    (-l sin q2, l sin q1 cos q2, -l cos q1 cos q2), so |v|^2 = l^2 (cos^2 q2 q1d^2 + q2d^2); its angular velocity in
    its own frame is R_y(q2)^T q1d e_x + q2d e_y = (cos q2 q1d, q2d, sin q2 q1d). Hence
        M = diag((m l^2 + Ix) cos^2 q2 + Iz sin^2 q2, m l^2 + Iy),
        C qd = (M11' q1d q2d, -1/2 M11' q1d^2) with M11' = dM11/dq2 = 2 (Iz - Ix - m l^2) sin q2 cos q2,
        g = (m g l sin q1 cos q2, m g l cos q1 sin q2) from V = -m g l cos q1 cos q2;
    the task (x, y) of the ball: J = [[0, -l c2], [l c1 c2, -l s1 s2]],
    Jdot qd = (l s2 q2d^2, -l s1 c2 (q1d^2 + q2d^2) - 2 l c1 s2 q1d q2d). Returns (M, C qd, g, J, Jdot qd)."""
    c1, s1, c2, s2 = np.cos(q[0]), np.sin(q[0]), np.cos(q[1]), np.sin(q[1])
    dM11 = 2.0 * (Iz - Ix - m * l * l) * s2 * c2
    M = np.diag([(m * l * l + Ix) * c2 * c2 + Iz * s2 * s2, m * l * l + Iy])
    Cqd = np.array([dM11 * qd[0] * qd[1], -0.5 * dM11 * qd[0]**2])
    grav = m * g * l * np.array([s1 * c2, c1 * s2])
    J = np.array([[0.0, -l * c2], [l * c1 * c2, -l * s1 * s2]])
    bias = np.array([l * s2 * qd[1]**2, -l * s1 * c2 * (qd[0]**2 + qd[1]**2) - 2.0 * l * c1 * s2 * qd[0] * qd[1]])
    return M, Cqd, grav, J, bias


# ---------------------------------------------------------------------------------------- assembling a Split


@dataclass(frozen=True)
class _Terms:
    """One state's ``M qdd + C qd + g = tau (+ Jc^T lam)`` in closed form (tau = B u), with M's inverse, the total
    mass and ``|gravity|_1`` (for accel_scale)."""

    M: np.ndarray
    Minv: np.ndarray
    Cqd: np.ndarray
    g: np.ndarray
    tau: np.ndarray
    mass: float
    gravity: float
    tau_ext: np.ndarray | None = None     # the external loads' generalized force; ``g`` is then ``dV/dq - tau_ext``

    def accelerations(self) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Eq. (9), each directly: drift ``-M^-1 (C qd + g)``, ctrl ``M^-1 B u``, total ``M^-1 (B u - C qd - g)``."""
        return (-self.Minv @ (self.Cqd + self.g), self.Minv @ self.tau, self.Minv @ (self.tau - self.Cqd - self.g))

    def forces(self) -> tuple[np.ndarray, np.ndarray]:
        """The right-hand sides ``f`` of eq. (12): ``B u - C qd - g`` (total) and ``-C qd - g`` (drift, eq. 14)."""
        return self.tau - self.Cqd - self.g, -self.Cqd - self.g

    def accel_scale(self, qd) -> float:
        """``accel_scale = ||M^-1|| H``, ``H = |C qd|_1 + |g|_1 + |B u|_1 + lambda_max(M) |qd|^2 + |gravity|_1
        sqrt(m_total lambda_max(M))`` (the definition of ``Split.accel_scale``, before the constraint force)."""
        w = eigenvalues(self.M)
        external = 0.0 if self.tau_ext is None else np.abs(self.tau_ext).sum()
        return (np.abs(self.Cqd).sum() + np.abs(self.g).sum() + np.abs(self.tau).sum() + w[-1] * float(qd @ qd)
                + self.gravity * np.sqrt(self.mass * w[-1]) + external) / w[0]


@dataclass(frozen=True)
class _Kkt:
    """A constrained state's closed forms: phi, Jc, Jcdot qd, the multipliers with and without input, and the
    rule (with the case's scales) that decides S's redundant directions."""

    phi: np.ndarray
    Jc: np.ndarray
    bias: np.ndarray
    lam: np.ndarray
    lam_drift: np.ndarray
    rule: Rule


def _residuals(t: _Terms, Jc, bias) -> list[np.ndarray]:
    """The KKT right-hand sides ``r = -Jcdot qd - Jc M^-1 f`` for total and drift (:meth:`_Terms.forces`): eliminating
    qdd from eqs. (12), (13) leaves ``S lam = r``."""
    return [-bias - Jc @ t.Minv @ f for f in t.forces()]


def _constrained(t: _Terms, phi, Jc, bias, rule: Rule) -> tuple[np.ndarray, np.ndarray, np.ndarray, _Kkt]:
    """Eqs. (12)-(17) by the range-space method under the backends' rule (:class:`Rule`): with ``S^+`` the
    pseudo-inverse over S's kept eigen-directions (:meth:`Spectrum.pinv`), ``lam = S^+ r`` and ``qdd = M^-1 (f +
    Jc^T lam)`` (:func:`_residuals`: r; f = B u - h for total and lam, -h for the drift and lam_drift of eq. 14),
    and ``ctrl = B_c B u`` with eq. (17)'s B_c (:func:`constrained_input_map`), directly. At full rank the KKT
    solution of 5.6; at a change point the minimum-norm multipliers, with the equations along the redundant
    directions dropped where H_t is empty, as every backend does. Returns (drift, ctrl, total, :class:`_Kkt`)."""
    Spinv = rule.spectrum(Jc @ t.Minv @ Jc.T).pinv()
    lam, lam_drift = (Spinv @ r for r in _residuals(t, Jc, bias))
    f_total, f_drift = t.forces()
    return (t.Minv @ (f_drift + Jc.T @ lam_drift), constrained_input_map(t.M, Jc, Spinv) @ t.tau,
            t.Minv @ (f_total + Jc.T @ lam), _Kkt(phi, Jc, bias, lam, lam_drift, rule))


def _assemble(t: _Terms, qd, drift, ctrl, total, task, kkt: _Kkt | None = None) -> Split:
    """The Split of one state from its closed forms; ``task`` = (task drift, Lambda, cond(J M^-1 J^T)).

    cond(M) and ``accel_scale`` (:meth:`_Terms.accel_scale`). With constraints, by the definitions in ``Split``'s
    docstring and the backends' rule (:class:`Rule`, :class:`Spectrum` of ``S = Jc M^-1 Jc^T``): ``lam_scale =
    (|Jcdot qd|_1 + ||Jc|| accel_scale) / w_kept`` (w_kept the smallest kept eigenvalue of S; 0 when none is kept),
    ``accel_scale`` plus ``||M^-1|| ||Jc|| lam_scale``, the conditions ``constraint``, ``constraint_kept``
    (:meth:`Spectrum.conditions`) and ``constraint_consistency`` (:meth:`Spectrum.inconsistency` of the KKT
    right-hand sides, least |r| ``1e-6 L accel_scale``), the rank of S; the constraint force ``Jc^T lam`` and its
    power."""
    w = eigenvalues(t.M)
    accel_scale = t.accel_scale(qd)
    task_drift, Lambda, task_cond = task
    fields = dict(drift=drift, ctrl=ctrl, total=total, power_ctrl=float(t.tau @ qd), power_ctrl_per_coord=t.tau * qd,
                  cond_M=w[-1] / w[0], task_drift=task_drift, kinetic_energy=0.5 * qd @ t.M @ qd,
                  task_inertia=Lambda, **_drift_parts(t, kkt))
    if t.tau_ext is not None:
        fields.update(external_force=t.tau_ext, power_ext=float(t.tau_ext @ qd))
    if kkt is None:
        return Split(lam=None, lam_drift=None, power_constr=None, power_constr_per_coord=None,
                     accel_scale=accel_scale, conditions={"task_inertia": task_cond}, **fields)
    S = kkt.rule.spectrum(kkt.Jc @ t.Minv @ kkt.Jc.T)
    jc_norm = float(np.linalg.norm(kkt.Jc, 2))
    lam_scale = (np.abs(kkt.bias).sum() + jc_norm * accel_scale) / S.w[S.kept][0] if S.rank else 0.0
    consistency = S.inconsistency(_residuals(t, kkt.Jc, kkt.bias), 1e-6 * kkt.rule.length * accel_scale)
    force, force_drift = kkt.Jc.T @ kkt.lam, kkt.Jc.T @ kkt.lam_drift
    return Split(lam=kkt.lam, lam_drift=kkt.lam_drift, power_constr=float(force @ qd),
                 power_constr_per_coord=force * qd,
                 accel_scale=accel_scale + jc_norm * lam_scale / w[0],
                 conditions={"task_inertia": task_cond, **S.conditions(), "constraint_consistency": consistency},
                 constraint_value=kkt.phi, constraint_jacobian=kkt.Jc, constraint_bias=kkt.bias,
                 constraint_velocity=kkt.Jc @ qd, constraint_force=force, constraint_force_drift=force_drift,
                 constraint_rank=S.rank, lam_scale=lam_scale, **fields)


def _drift_parts(t: _Terms, kkt: _Kkt | None) -> dict:
    """The drift's parts (article 4.5-4.6), each solved directly: ``zvcf`` with ``f = -g`` (and, with constraints, the
    bias 0 of a state at rest) and ``drift_velocity`` with ``f = -C qd`` and the bias ``Jcdot qd``, by the range-space
    method of :func:`_constrained` under the same rule."""
    if kkt is None:
        return {"zvcf": -t.Minv @ t.g, "drift_velocity": -t.Minv @ t.Cqd}
    Spinv = kkt.rule.spectrum(kkt.Jc @ t.Minv @ kkt.Jc.T).pinv()

    def solve(f, bias):
        return t.Minv @ (f + kkt.Jc.T @ (Spinv @ (-bias - kkt.Jc @ t.Minv @ f)))
    return {"zvcf": solve(-t.g, np.zeros_like(kkt.bias)), "drift_velocity": solve(-t.Cqd, kkt.bias)}


def _task(J, bias, drift, inertia) -> tuple:
    """(task drift ``J drift + Jdot qd`` (eq. 23), Lambda, cond) with ``inertia`` = (Lambda, cond)."""
    return (J @ drift + bias, *inertia)


# ------------------------------------------------------------------------------------ the closed forms by case


def _double_pendulum(p, q, qd, u) -> Split:
    """Article section 3: M (eq. 6, plus :func:`disk_inertia`), C qd (7), g (8), the split (9), the tip (4, 5)."""
    l1, l2 = p["l1"], p["l2"]
    M, Cqd, grav = pendulum_terms(q, qd, p["m1"], p["m2"], l1, l2, p["g"])
    M = M + disk_inertia(p["I1"], p["I2"])
    t = _Terms(M, inv2(M), Cqd, grav, u, p["m1"] + p["m2"], abs(p["g"]))
    drift, ctrl, total = t.accelerations()
    J = endpoint_jacobian(q, l1, l2)
    return _assemble(t, qd, drift, ctrl, total, _task(J, tip_bias(q, qd, l1, l2), drift, task_inertia_square(J, M)))


def tip_force(q, l1, l2, fx, fy) -> np.ndarray:
    """``tau_ext = J(q)^T (fx, fy)``: the virtual work of a world force at the tip, J of eq. (5), i.e.
    ``tau_1 = fx (l1 cos t1 + l2 cos(t1 + t2)) + fy (l1 sin t1 + l2 sin(t1 + t2))``, ``tau_2 = fx l2 cos(t1 + t2) + fy
    l2 sin(t1 + t2)``."""
    return endpoint_jacobian(q, l1, l2).T @ np.array([fx, fy])


def tip_spring(q, l1, l2, k, rest, ax, ay, bfx, bfy, couple) -> np.ndarray:
    """``tau_ext`` of ``cases.double_pendulum_spring`` by hand: the spring's force ``-k (|d| - rest) d / |d|`` at the
    tip, ``d = x2 - (ax, ay)`` (x2 of eq. 4), and link 2's body-frame force ``(bfx, bfy)`` turned by the link's
    absolute angle ``t1 + t2`` (``R = [[cos, -sin], [sin, cos]]``), both through ``J^T`` (eq. 5); the couple about z
    does ``couple (t1d + t2d)`` of work (link 2 turns at ``t1d + t2d``): ``(couple, couple)``."""
    x, y = tip_position(q, l1, l2)
    d = np.array([x - ax, y - ay])
    length = float(np.hypot(*d))
    spring = -k * (length - rest) / length * d
    c, s = np.cos(q[0] + q[1]), np.sin(q[0] + q[1])
    body = np.array([c * bfx - s * bfy, s * bfx + c * bfy])
    return endpoint_jacobian(q, l1, l2).T @ (spring + body) + np.array([couple, couple])


def _loaded_pendulum(p, q, qd, u, tau_ext) -> Split:
    """The double pendulum (eqs. 4-9) with the external generalized force ``tau_ext`` beside gravity (eq. 12, 14):
    ``M qdd + C qd + g = B u + tau_ext``."""
    l1, l2 = p["l1"], p["l2"]
    M, Cqd, grav = pendulum_terms(q, qd, p["m1"], p["m2"], l1, l2, p["g"])
    t = _Terms(M, inv2(M), Cqd, grav - tau_ext, u, p["m1"] + p["m2"], abs(p["g"]), tau_ext)
    drift, ctrl, total = t.accelerations()
    J = endpoint_jacobian(q, l1, l2)
    return _assemble(t, qd, drift, ctrl, total, _task(J, tip_bias(q, qd, l1, l2), drift, task_inertia_square(J, M)))


def _double_pendulum_tip_force(p, q, qd, u) -> Split:
    """Eqs. (4)-(9) with :func:`tip_force`."""
    return _loaded_pendulum(p, q, qd, u, tip_force(q, p["l1"], p["l2"], p["fx"], p["fy"]))


def _double_pendulum_spring(p, q, qd, u) -> Split:
    """Eqs. (4)-(9) with :func:`tip_spring`."""
    return _loaded_pendulum(p, q, qd, u, tip_spring(q, p["l1"], p["l2"], p["k"], p["rest"], p["ax"], p["ay"],
                                                     p["bfx"], p["bfy"], p["couple"]))


def _n_link_pendulum(p, q, qd, u) -> Split:
    """:func:`chain_terms` of n equal masses in absolute angles phi = T q (:func:`relative_to_absolute`), mapped to
    the relative angles: M = T^T M_phi T, h = T^T h_phi; the tip :func:`chain_tip` with J_q = J_phi T."""
    n, m, l = p["n"], p["m"], p["l"]
    T = relative_to_absolute(n)
    phi, phid = T @ q, T @ qd
    M, Cqd, grav = to_joint(T, *chain_terms(phi, phid, [m] * n, [l] * n, p["g"]))
    t = _Terms(M, np.linalg.inv(M), Cqd, grav, u, n * m, abs(p["g"]))
    drift, ctrl, total = t.accelerations()
    J_phi, bias = chain_tip(phi, phid, [l] * n)
    J = J_phi @ T
    return _assemble(t, qd, drift, ctrl, total, _task(J, bias, drift, task_inertia(J, t.Minv)))


def _acrobot(p, q, qd, u) -> Split:
    """Spong's equations (:func:`acrobot_terms`), B = [[0], [1]], the tip of link 2 by eqs. (4), (5)."""
    M, Cqd, grav = acrobot_terms(q, qd, p["m1"], p["m2"], p["l1"], p["lc1"], p["lc2"], p["I1"], p["I2"], p["g"])
    t = _Terms(M, inv2(M), Cqd, grav, np.array([0.0, u[0]]), p["m1"] + p["m2"], abs(p["g"]))
    drift, ctrl, total = t.accelerations()
    J = endpoint_jacobian(q, p["l1"], p["l2"])
    return _assemble(t, qd, drift, ctrl, total,
                     _task(J, tip_bias(q, qd, p["l1"], p["l2"]), drift, task_inertia_square(J, M)))


# The scales of each constrained case's rule (:meth:`Rule.of`: mass, |translation| + |com|, tr I per massive body),
# typed in from its factory.


def _double_pendulum_rule(p) -> Rule:
    """The point-mass double pendulum (``cases.double_pendulum``'s bodies, the circle's and the rail's): mass 1 at l1
    from the shoulder, link 2 placed l1 down with its mass l2 beyond, no rotational inertia."""
    return Rule.of((p["m1"], p["l1"], 0.0), (p["m2"], p["l1"] + p["l2"], 0.0))


def _cartesian_rule(p) -> Rule:
    """The bob at the origin of its slides (the carriage is massless)."""
    return Rule.of((p["m"], 0.0, 0.0))


def _absolute_loop_rule(p) -> Rule:
    """Each link's mass l_i from its massless carriages, ``planar_disk(I_i)`` of trace 2 I_i."""
    return Rule.of((p["m1"], p["l1"], 2.0 * p["I1"]), (p["m2"], p["l2"], 2.0 * p["I2"]))


def _four_bar_rule(p) -> Rule:
    """Three rods (:func:`rod_body`): the crank at the origin, the coupler placed ``crank`` down the crank, the rocker
    at (ground, 0)."""
    return Rule.of(rod_body(p["m"], p["crank"]), rod_body(p["m"], p["coupler"], p["crank"]),
                   rod_body(p["m"], p["rocker"], p["ground"]))


def _slider_crank_rule(p) -> Rule:
    """Two rods (:func:`rod_body`) and the slider placed |offset| from the origin, a point mass."""
    return Rule.of(rod_body(p["m_crank"], p["crank"]), rod_body(p["m_rod"], p["rod"], p["crank"]),
                   (p["m_slider"], abs(p["offset"]), 0.0))


def _gear_rule(p) -> Rule:
    """Two rods (:func:`rod_body`), the wheel's placed ``spacing`` from the origin."""
    return Rule.of(rod_body(p["m1"], p["l1"]), rod_body(p["m2"], p["l2"], p["spacing"]))


def _double_pendulum_circle(p, q, qd, u) -> Split:
    """Article 5.6: eqs. (6)-(8), the circle row (:func:`circle_terms`), the KKT system by hand
    (:func:`one_row_kkt`: eqs. 12-14) and ctrl = B_c u (eq. 17, :func:`constrained_input_map`)."""
    l1, l2 = p["l1"], p["l2"]
    M, Cqd, grav = pendulum_terms(q, qd, p["m1"], p["m2"], l1, l2, p["g"])
    t = _Terms(M, inv2(M), Cqd, grav, u, p["m1"] + p["m2"], abs(p["g"]))
    phi, Jc, bias = circle_terms(q, qd, l1, l2, p["xc"], p["yc"], p["R"])
    drift, lam_drift = one_row_kkt(t.Minv, Jc, bias, -Cqd - grav)
    total, lam = one_row_kkt(t.Minv, Jc, bias, u - Cqd - grav)
    ctrl = constrained_input_map(M, Jc) @ u
    J = endpoint_jacobian(q, l1, l2)
    return _assemble(t, qd, drift, ctrl, total, _task(J, tip_bias(q, qd, l1, l2), drift, task_inertia_square(J, M)),
                     _Kkt(np.array([phi]), Jc.reshape(1, 2), np.array([bias]), np.array([lam]),
                          np.array([lam_drift]), _double_pendulum_rule(p)))


def _cartesian_pendulum(p, q, qd, u) -> Split:
    """M = m I, h = (0, m g), B = I; lam by :func:`cartesian_lam`, so ``m qdd = m gravity + u + 2 lam p`` (eq. 12)
    for total (and lam_drift, u = 0, for the drift); ctrl = B_c u (eq. 17); the task point is the bob (J = I)."""
    m, L, g = p["m"], p["L"], p["g"]
    M, gravity = m * np.eye(2), np.array([0.0, -g])
    t = _Terms(M, np.eye(2) / m, np.zeros(2), np.array([0.0, m * g]), u, m, abs(g))
    lam, lam_drift = cartesian_lam(q, qd, u, m, L, g), cartesian_lam(q, qd, np.zeros(2), m, L, g)
    total, drift = gravity + (u + 2.0 * lam * q) / m, gravity + 2.0 * lam_drift * q / m
    ctrl = constrained_input_map(M, 2.0 * q) @ u
    return _assemble(t, qd, drift, ctrl, total, _task(np.eye(2), np.zeros(2), drift, task_inertia_square(np.eye(2), M)),
                     _Kkt(np.array([q @ q - L * L]), 2.0 * q.reshape(1, 2), np.array([2.0 * qd @ qd]),
                          np.array([lam]), np.array([lam_drift]), _cartesian_rule(p)))


def _double_pendulum_absolute_loop(p, q, qd, u) -> Split:
    """The double pendulum with disk inertias (eqs. 6-9 and :func:`disk_inertia`) at the joint state t = (phi1,
    phi2 - phi1) (:func:`loop_to_joint`), its accelerations mapped to the loop (:func:`joint_to_loop`; ctrl by the
    linear part), lam and lam_drift the pins' forces (:func:`pin_forces`) at total and drift; the loop's own M, C qd,
    g (:func:`loop_terms`) for cond(M) and accel_scale, its pins (:func:`loop_constraint`). The tip is link 2's COM,
    a free body's centre of mass: a force there only translates it, so Lambda = m2 I (cond 1)."""
    m1, m2, l1, l2, g = p["m1"], p["m2"], p["l1"], p["l2"], p["g"]
    th, thd = loop_to_joint(q), loop_to_joint(qd)
    Mj, Cj, gj = pendulum_terms(th, thd, m1, m2, l1, l2, g)
    Mj = Mj + disk_inertia(p["I1"], p["I2"])
    joint = _Terms(Mj, inv2(Mj), Cj, gj, u, m1 + m2, abs(g))
    drift_j, ctrl_j, total_j = joint.accelerations()
    M, Cqd, grav = loop_terms(q, qd, m1, m2, l1, l2, g, p["I1"], p["I2"])
    t = _Terms(M, np.linalg.inv(M), Cqd, grav, np.array([0.0, 0.0, u[0] - u[1], 0.0, 0.0, u[1]]), m1 + m2, abs(g))
    phi, Jc, bias = loop_constraint(q, qd, l1)
    lam, lam_drift = (np.concatenate(pin_forces(th, thd, a, m1, m2, l1, l2, g)) for a in (total_j, drift_j))
    tip = endpoint_jacobian(th, l1, l2) @ drift_j + tip_bias(th, thd, l1, l2)
    return _assemble(t, qd, joint_to_loop(th, thd, drift_j, l1), joint_to_loop(th, np.zeros(2), ctrl_j, l1),
                     joint_to_loop(th, thd, total_j, l1), (tip, m2 * np.eye(2), 1.0),
                     _Kkt(phi, Jc, bias, lam, lam_drift, _absolute_loop_rule(p)))


def _four_bar(p, q, qd, u) -> Split:
    """The open tree's M, C qd, g (:func:`four_bar_terms`), the loop (:func:`four_bar_loop`), eqs. (12)-(17) under
    the backends' rule (:func:`_constrained`: minimum-norm multipliers at the change points), the task point
    ``coupler_mid`` by :func:`link_point` (eqs. 23, 22 with the open tree's M)."""
    a, b, c, m, g = p["crank"], p["coupler"], p["rocker"], p["m"], p["g"]
    M, Cqd, grav = four_bar_terms(q, qd, a, b, c, m, g)
    t = _Terms(M, np.linalg.inv(M), Cqd, grav, u, 3.0 * m, abs(g))
    drift, ctrl, total, kkt = _constrained(t, *four_bar_loop(q, qd, a, b, c, p["ground"]), _four_bar_rule(p))
    J, bias = link_point(q, qd, a, b / 2.0)
    return _assemble(t, qd, drift, ctrl, total, _task(J, bias, drift, task_inertia(J, t.Minv)), kkt)


def _slider_crank(p, q, qd, u) -> Split:
    """The open tree's M, C qd, g (:func:`slider_crank_terms`), the wrist pin (:func:`wrist_pin`), eqs. (12)-(17)
    (:func:`_constrained`); the task is the slider's x: J = (0, 0, 1), Jdot qd = 0, Lambda = 1 / (M^-1)_33 =
    m_slider (M is block-diagonal), cond 1."""
    a, r, e = p["crank"], p["rod"], p["offset"]
    ms = p["m_slider"]
    M, Cqd, grav = slider_crank_terms(q, qd, a, r, p["m_crank"], p["m_rod"], ms, p["g"])
    t = _Terms(M, np.linalg.inv(M), Cqd, grav, u, p["m_crank"] + p["m_rod"] + ms, abs(p["g"]))
    drift, ctrl, total, kkt = _constrained(t, *wrist_pin(q, qd, a, r, e), _slider_crank_rule(p))
    J = np.array([[0.0, 0.0, 1.0]])
    return _assemble(t, qd, drift, ctrl, total, _task(J, np.zeros(1), drift, task_inertia(J, t.Minv)), kkt)


def _double_pendulum_rail(p, q, qd, u) -> Split:
    """Eqs. (6)-(8), the rail row (:func:`rail_terms`), eqs. (12)-(17) (:func:`_constrained`), the tip by
    eqs. (4), (5)."""
    l1, l2 = p["l1"], p["l2"]
    M, Cqd, grav = pendulum_terms(q, qd, p["m1"], p["m2"], l1, l2, p["g"])
    t = _Terms(M, inv2(M), Cqd, grav, u, p["m1"] + p["m2"], abs(p["g"]))
    drift, ctrl, total, kkt = _constrained(t, *rail_terms(q, qd, l1, l2, p["x0"], p["y0"], p["incline"]),
                                           _double_pendulum_rule(p))
    J = endpoint_jacobian(q, l1, l2)
    return _assemble(t, qd, drift, ctrl, total, _task(J, tip_bias(q, qd, l1, l2), drift, task_inertia_square(J, M)),
                     kkt)


def _geared_pendulums(p, q, qd, u) -> Split:
    """Two rods (:func:`gear_terms`, M diagonal) coupled by the gear (:func:`gear_constraint`), eqs. (12)-(17)
    (:func:`_constrained`: with ``S = 1 / M11 + ratio^2 / M22`` the gear's torque is ``lam = (ratio (M^-1 f)_2 -
    (M^-1 f)_1) / S``); the task is the pinion rod's end along x: ``J = (l1 cos q1, 0)``, ``Jdot qd = -l1 sin q1
    q1d^2`` (:func:`chain_tip` of one link)."""
    m1, l1, m2, l2 = p["m1"], p["l1"], p["m2"], p["l2"]
    M, Cqd, grav = gear_terms(q, qd, m1, l1, m2, l2, p["g"])
    t = _Terms(M, np.diag(1.0 / np.diag(M)), Cqd, grav, u, m1 + m2, abs(p["g"]))
    drift, ctrl, total, kkt = _constrained(t, *gear_constraint(q, p["ratio"], p["offset"]), _gear_rule(p))
    J, bias = chain_tip(q[:1], qd[:1], (l1,))
    J = np.array([[J[0, 0], 0.0]])
    return _assemble(t, qd, drift, ctrl, total, _task(J, bias[:1], drift, task_inertia(J, t.Minv)), kkt)


#: The free body's centre of mass and task point ``marker`` in its body frame (``cases.free_body``).
FREE_BODY_COM = np.array([0.05, -0.03, 0.02])
FREE_BODY_MARKER = np.array([0.2, 0.1, -0.05])


def _hat(a) -> np.ndarray:
    return np.array([[0.0, -a[2], a[1]], [a[2], 0.0, -a[0]], [-a[1], a[0], 0.0]])


def free_body_terms(q, v, m, I1, I2, I3, g):  # noqa: N803
    """``cases.free_body`` by hand, in the body frame (the free joint's conventions, ``cases.model``): q = (p, x, y,
    z, w), R = I + 2 w [e]x + 2 [e]x^2 with e = (x, y, z); v = (v_o, w) the body twist (velocity of the body origin,
    angular velocity, both in the body frame). With the centre of mass c = FREE_BODY_COM and I_c = diag(I1, I2, I3)
    about it, the momentum about the origin is ``(p_lin, L) = M v`` with
        M = [[m 1, -m [c]x], [m [c]x, I_c - m [c]x^2]],
    and Newton's and Euler's equations in a frame turning with the body (Euler's equations with the COM off the
    origin) are ``d/dt p_lin + w x p_lin = f`` and ``d/dt L + w x L + v_o x p_lin = n_o``, so
        C qd = (w x p_lin, w x L + v_o x p_lin),   g = -(m R^T gravity, c x m R^T gravity)   (gravity (0, 0, -g)),
    and ``B u`` is the body wrench (force, moment about the origin). At ``c = 0`` the angular rows are Euler's
    ``I w' + w x I w = n``. The marker r = FREE_BODY_MARKER is at ``p + R r``: its velocity ``R (v_o + w x r)``, so
    ``J = R [1, -[r]x]`` and ``Jdot qd = R (w x (v_o + w x r))``. Returns (M, C qd, g, J, Jdot qd)."""
    e, w4 = np.asarray(q[3:6], dtype=float), float(q[6])
    R = np.eye(3) + 2.0 * w4 * _hat(e) + 2.0 * _hat(e) @ _hat(e)
    c, r = FREE_BODY_COM, FREE_BODY_MARKER
    C = _hat(c)
    M = np.block([[m * np.eye(3), -m * C], [m * C, np.diag([I1, I2, I3]) - m * C @ C]])
    vo, w = np.asarray(v[:3], dtype=float), np.asarray(v[3:], dtype=float)
    lin, ang = np.split(M @ np.concatenate([vo, w]), 2)
    Cqd = np.concatenate([np.cross(w, lin), np.cross(w, ang) + np.cross(vo, lin)])
    weight = m * R.T @ np.array([0.0, 0.0, -g])
    grav = -np.concatenate([weight, np.cross(c, weight)])
    J = R @ np.hstack([np.eye(3), -_hat(r)])
    bias = R @ np.cross(w, vo + np.cross(w, r))
    return M, Cqd, grav, J, bias


def _one_joint(M, Cqd, grav, J, bias, u, qd, mass, g) -> Split:
    """A 1-degree-of-freedom case from its (1x1) terms: eq. (9) with M^-1 = 1 / M, the task of eq. (23) and (22)."""
    t = _Terms(M, 1.0 / M, Cqd, grav, u, mass, abs(g))
    drift, ctrl, total = t.accelerations()
    return _assemble(t, qd, drift, ctrl, total, _task(J, bias, drift, task_inertia(J, t.Minv)))


def _rotor(p, q, qd, u) -> Split:
    """:func:`rotor_terms`."""
    keys = ("m", "cx", "cy", "cz", "Ia", "Ib", "Ic", "spin", "tilt", "azimuth", "g")
    return _one_joint(*rotor_terms(q, qd, *(p[k] for k in keys)), u, qd, p["m"], p["g"])


def _inclined_slider(p, q, qd, u) -> Split:
    """:func:`slider_terms`."""
    return _one_joint(*slider_terms(p["m"], p["incline"], p["g"]), u, qd, p["m"], p["g"])


def _spherical_pendulum(p, q, qd, u) -> Split:
    """:func:`spherical_terms`, eq. (9) with the diagonal M's inverse, the ball's task by eqs. (23), (22)."""
    M, Cqd, grav, J, bias = spherical_terms(q, qd, p["m"], p["l"], p["Ix"], p["Iy"], p["Iz"], p["g"])
    t = _Terms(M, np.diag(1.0 / np.diag(M)), Cqd, grav, u, p["m"], abs(p["g"]))
    drift, ctrl, total = t.accelerations()
    return _assemble(t, qd, drift, ctrl, total, _task(J, bias, drift, task_inertia_square(J, M)))


def _free_body(p, q, qd, u) -> Split:
    """:func:`free_body_terms`; eq. (9) with M^-1 from numpy (6 x 6), the marker's task by eqs. (23), (22)."""
    M, Cqd, grav, J, bias = free_body_terms(q, qd, p["m"], p["I1"], p["I2"], p["I3"], p["g"])
    t = _Terms(M, np.linalg.inv(M), Cqd, grav, u, p["m"], abs(p["g"]))
    drift, ctrl, total = t.accelerations()
    A = J @ t.Minv @ J.T
    cond = condition(A)
    Lambda = np.linalg.inv(A) if np.isfinite(cond) else np.full((3, 3), np.nan)
    return _assemble(t, qd, drift, ctrl, total, _task(J, bias, drift, (Lambda, cond)))


def sleigh_terms(q, qd, m, a, I):  # noqa: E741, N803
    """The Chaplygin sleigh (``cases.knife_edge``) by hand: q = (x, y, theta), P = (x, y) the runner's contact, the
    COM at ``P + a e1`` with ``e1 = (c, s)``, ``e2 = (-s, c)``. ``T = m/2 |Pdot + a thd e2|^2 + I/2 thd^2`` gives
    ``M = [[m, 0, -m a s], [0, m, m a c], [-m a s, m a c, I + m a^2]]`` and ``C qd = -m a thd^2 (c, s, 0)`` (the theta
    row cancels: ``Mdot qd`` and ``dT/dtheta`` are both ``-m a thd (c xd + s yd)``); g = 0 (gravity along -z). The
    knife edge: ``A = e2^T`` on (x, y), ``Adot qd = -thd (c xd + s yd)``."""
    s, c = np.sin(q[2]), np.cos(q[2])
    M = np.array([[m, 0.0, -m * a * s], [0.0, m, m * a * c], [-m * a * s, m * a * c, I + m * a * a]])
    Cqd = -m * a * qd[2] ** 2 * np.array([c, s, 0.0])
    return M, Cqd, np.array([[-s, c, 0.0]]), np.array([-qd[2] * (c * qd[0] + s * qd[1])])


def sleigh_motion(q, qd, force, m, a, I):  # noqa: E741, N803
    """The sleigh's accelerations and the blade's multiplier by hand, at an admissible state (``xd = c v``, ``yd = s
    v``) under the generalized force ``force = (Fx, Fy, tau)`` (B u, or 0 for the drift). With the forward speed ``v =
    c xd + s yd``, ``w = thd``, ``F_along = c Fx + s Fy`` and ``F_lat = -s Fx + c Fy`` (at P), Newton along e1 and e2
    and Euler about the COM (the COM accelerates by ``(vdot - a w^2) e1 + (v w + a wdot) e2``; ``lam e2`` acts at P,
    ``a`` behind the COM):

        m (vdot - a w^2) = F_along,   m (v w + a wdot) = F_lat + lam,   I wdot = tau - a (F_lat + lam)

    so ``wdot = (tau - m a v w) / (I + m a^2)``, ``vdot = a w^2 + F_along / m``, ``lam = m (v w + a wdot) - F_lat``,
    and ``xdd = c vdot - s v w``, ``ydd = s vdot + c v w``. Returns (qdd, lam)."""
    s, c = np.sin(q[2]), np.cos(q[2])
    v, w = c * qd[0] + s * qd[1], qd[2]
    along, lateral = c * force[0] + s * force[1], -s * force[0] + c * force[1]
    wdot = (force[2] - m * a * v * w) / (I + m * a * a)
    vdot = a * w * w + along / m
    return np.array([c * vdot - s * v * w, s * vdot + c * v * w, wdot]), m * (v * w + a * wdot) - lateral


def _sleigh_rule(p) -> Rule:
    """The sleigh: its COM ``a`` from the origin, inertia diag(I/2, I/2, I) of trace 2 I; the carriages massless."""
    return Rule.of((p["m"], abs(p["a"]), 2.0 * p["I"]))


def _knife_edge(p, q, qd, u) -> Split:
    """:func:`sleigh_terms` and :func:`sleigh_motion` (total with ``B u = u``, drift with 0; ctrl = B_c u, eq. 17, by
    :func:`constrained_input_map`); the task point ``com`` at ``P + a e1``: ``J = [[1, 0, -a s], [0, 1, a c]]``,
    ``Jdot qd = -a thd^2 e1``."""
    m, a, I = p["m"], p["a"], p["I"]  # noqa: E741
    M, Cqd, Jc, bias = sleigh_terms(q, qd, m, a, I)
    t = _Terms(M, np.linalg.inv(M), Cqd, np.zeros(3), u, m, abs(p["g"]))
    total, lam = sleigh_motion(q, qd, u, m, a, I)
    drift, lam_drift = sleigh_motion(q, qd, np.zeros(3), m, a, I)
    s, c = np.sin(q[2]), np.cos(q[2])
    J = np.array([[1.0, 0.0, -a * s], [0.0, 1.0, a * c]])
    task_bias = -a * qd[2] ** 2 * np.array([c, s])
    return _assemble(t, qd, drift, constrained_input_map(M, Jc) @ u, total,
                     _task(J, task_bias, drift, task_inertia(J, t.Minv)),
                     _Kkt(np.zeros(1), Jc, bias, np.array([lam]), np.array([lam_drift]), _sleigh_rule(p)))


def disk_terms(q, qd, m, r, g):
    """The rolling disk (``cases.rolling_disk``) by hand, in the classical form (Neimark and Fufaev, Dynamics of
    Nonholonomic Systems; Bloch, Nonholonomic Mechanics and Control, 1.4; O'Reilly, Nonlinear Dynamics 10, 1996):
    q = (x, y, psi, phi, theta) the contact point, yaw, lean and spin. The heading frame (e1, e2, e3) = ((c_psi,
    s_psi, 0), (-s_psi, c_psi, 0), (0, 0, 1)); the leaned frame (e1, a, n) with the axle a = c_phi e2 + s_phi e3
    and n = -s_phi e2 + c_phi e3 (the contact-to-centre direction). The centre is at (x, y, 0) + r n; with the
    contact's forward and lateral rates u = c_psi xd + s_psi yd, w = -s_psi xd + c_psi yd, its velocity in the
    heading frame and the disk's angular velocity ``psid e3 + phid e1 + thetad a`` in the leaned frame are

        v = (u + r s_phi psid, w - r c_phi phid, -r s_phi phid) = Jv qd,
        omega = (phid, thetad + s_phi psid, c_phi psid) = Jw qd,

    and T = m/2 |v|^2 + 1/2 omega . I omega with I = m r^2/4 diag(1, 2, 1) (a thin disk; axisymmetric, so constant in
    the leaned frame), V = m g r c_phi. Lagrange's equations are the Newton-Euler equations projected by the Jacobians
    (virtual power), with the accelerations taken in the turning frames (heading frame turning at psid e3, leaned
    frame at phid e1 + psid e3, i.e. omega less the spin):

        M = m Jv^T Jv + Jw^T I Jw,   C qd = m Jv^T a_b + Jw^T (I alpha_b + omega x I omega),
        a_b = (2 r c_phi phid psid, r s_phi (phid^2 + psid^2), -r c_phi phid^2)   (the centre, heading frame),
        alpha_b = (-c_phi psid thetad, c_phi phid psid, phid (thetad - s_phi psid))   (leaned frame),
        omega x I omega = m r^2/4 (thetad + s_phi psid) (-c_phi psid, 0, phid),
        g = (0, 0, 0, -m g r s_phi, 0).

    The rows (``RollingContact``: the world x and y velocity of the disk's material point at the contact, the disk's
    lowest point ``p_c = c - r sigma n`` with ``sigma = sign(c_phi)``: for |phi| > pi/2 the chain puts the centre below
    the ground and the lowest point is the far end of n; at c_phi = 0 the disk is flat and has none, NaN rows). With
    ``omega x n = (thetad + s_phi psid) e1 - phid a`` and ``k = 1 - sigma`` (0 or 2),

        v_P = v - r sigma omega x n = (u + k r s_phi psid - sigma r thetad) e1 + (w - k r c_phi phid) e2 + (..) e3,

    for |phi| < pi/2 the contact rate less the rolling rate, ``(u - r thetad) e1 + w e2``. In world x, y (``R_psi``
    the heading's rotation): ``A = R_psi [[c_psi, s_psi, k r s_phi, 0, -sigma r], [-s_psi, c_psi, 0, -k r c_phi, 0]]``,
    for |phi| < pi/2 ``[[1, 0, 0, 0, -r c_psi], [0, 1, 0, 0, -r s_psi]]``: the literature's rows (``xd = r thetad
    c_psi``, ``yd = r thetad s_psi``) as they stand, the row transform the identity with this chain's coordinates.
    ``Adot qd = R_psi b`` with b the heading-frame rows differentiated at qdd = 0 plus ``psid e3 x``:
    ``b = (2 k r c_phi phid psid, k r s_phi (phid^2 + psid^2) - sigma r psid thetad)``, for |phi| < pi/2
    ``Adot qd = r psid thetad (s_psi, -c_psi)``. Returns (M, C qd, g, A, Adot qd)."""
    psi, phi = q[2], q[3]
    psid, phid, thetad = qd[2], qd[3], qd[4]
    cs, ss, cp, sp = np.cos(psi), np.sin(psi), np.cos(phi), np.sin(phi)
    Jv = np.array([[cs, ss, r * sp, 0.0, 0.0], [-ss, cs, 0.0, -r * cp, 0.0], [0.0, 0.0, 0.0, -r * sp, 0.0]])
    Jw = np.array([[0.0, 0.0, 0.0, 1.0, 0.0], [0.0, 0.0, sp, 0.0, 1.0], [0.0, 0.0, cp, 0.0, 0.0]])
    inertia = m * r * r / 4.0 * np.array([1.0, 2.0, 1.0])
    M = m * Jv.T @ Jv + Jw.T @ (inertia[:, None] * Jw)
    omega = Jw @ qd
    a_b = r * np.array([2.0 * cp * phid * psid, sp * (phid**2 + psid**2), -cp * phid**2])
    alpha_b = np.array([-cp * psid * thetad, cp * phid * psid, phid * (thetad - sp * psid)])
    gyro = m * r * r / 4.0 * omega[1] * np.array([-omega[2], 0.0, omega[0]])
    Cqd = m * Jv.T @ a_b + Jw.T @ (inertia * alpha_b + gyro)
    grav = np.array([0.0, 0.0, 0.0, -m * g * r * sp, 0.0])
    sigma = np.sign(cp) if cp != 0.0 else np.nan
    k = 1.0 - sigma
    R = np.array([[cs, -ss], [ss, cs]])
    A = R @ np.array([[cs, ss, k * r * sp, 0.0, -sigma * r], [-ss, cs, 0.0, -k * r * cp, 0.0]])
    b = r * np.array([2.0 * k * cp * phid * psid, k * sp * (phid**2 + psid**2) - sigma * psid * thetad])
    return M, Cqd, grav, A, R @ b


def disk_center(q, qd, r):
    """The disk's centre (``cases.rolling_disk``'s task point ``center``) in the world: ``(x, y, 0) + r n`` =
    ``(x + r s_phi s_psi, y - r s_phi c_psi, r c_phi)`` (:func:`disk_terms`); its Jacobian is the heading frame's
    ``R_psi Jv`` and ``Jdot qd = R_psi a_b`` (the centre's acceleration at qdd = 0, heading frame to world):
        J = [[1, 0, r s_phi c_psi, r c_phi s_psi, 0], [0, 1, r s_phi s_psi, -r c_phi c_psi, 0],
             [0, 0, 0, -r s_phi, 0]],
        Jdot qd = r (2 c_phi c_psi phid psid - s_phi s_psi (phid^2 + psid^2),
                     2 c_phi s_psi phid psid + s_phi c_psi (phid^2 + psid^2), -c_phi phid^2).
    Returns (J (3, 5), Jdot qd (3,))."""
    psi, phi = q[2], q[3]
    psid, phid = qd[2], qd[3]
    cs, ss, cp, sp = np.cos(psi), np.sin(psi), np.cos(phi), np.sin(phi)
    J = np.array([[1.0, 0.0, r * sp * cs, r * cp * ss, 0.0], [0.0, 1.0, r * sp * ss, -r * cp * cs, 0.0],
                  [0.0, 0.0, 0.0, -r * sp, 0.0]])
    both = phid**2 + psid**2
    bias = r * np.array([2.0 * cp * cs * phid * psid - sp * ss * both, 2.0 * cp * ss * phid * psid + sp * cs * both,
                         -cp * phid**2])
    return J, bias


def _disk_rule(p) -> Rule:
    """The disk: its centre r from the lean frame (translation (0, 0, r), COM at its origin), inertia
    ``m r^2 diag(1/4, 1/2, 1/4)`` of trace ``m r^2``; the carriages, heading and lean frames massless."""
    return Rule.of((p["m"], p["r"], p["m"] * p["r"] ** 2))


def _rolling_disk(p, q, qd, u) -> Split:
    """:func:`disk_terms` (B = I), eqs. (12)-(17) under the backends' rule (:func:`_constrained`; S = A M^-1 A^T has
    full rank: A's two rows are independent everywhere), the task point ``center`` by :func:`disk_center` (eqs. 23, 22
    with the unconstrained M, a 3 x 3 task: singular where the disk stands upright, phi = 0, since the centre's height
    is then stationary)."""
    m, r = p["m"], p["r"]
    M, Cqd, grav, A, bias = disk_terms(q, qd, m, r, p["g"])
    t = _Terms(M, np.linalg.inv(M), Cqd, grav, u, m, abs(p["g"]))
    drift, ctrl, total, kkt = _constrained(t, np.zeros(2), A, bias, _disk_rule(p))
    J, task_bias = disk_center(q, qd, r)
    return _assemble(t, qd, drift, ctrl, total, _task(J, task_bias, drift, task_inertia(J, t.Minv)), kkt)
def drive_terms(q, qd, m_body, m_wheel, r, track, com_ahead):
    """The differential drive (``cases.differential_drive``) by hand: q = (x, y, h, left, right), P = (x, y) the axle's
    midpoint, ``e1 = (c, s)`` forward, ``e2 = (-s, c)`` along the axle, half track ``b = track / 2``, ``d = com_ahead``.
    The chassis' COM moves with ``Pdot + d hd e2``, the wheels' centres with ``Pdot -+ b hd e1``; the chassis turns at
    ``hd`` about z (its inertia ``m_body track^2 / 6`` about z), a thin wheel at ``hd z + spin_d axle`` (``m_w r^2 / 4``
    about a diameter, ``m_w r^2 / 2`` about the axle). So ``T = m/2 |Pdot|^2 + m_body d hd (e2 . Pdot) + J/2 hd^2 +
    I_a/2 (left_d^2 + right_d^2)`` with ``m = m_body + 2 m_w``, ``J = m_body track^2 / 6 + m_w r^2 / 2 + m_body d^2 + 2
    m_w b^2``, ``I_a = m_w r^2 / 2``: the sleigh's M (:func:`sleigh_terms`, ``m a`` -> ``m_body d``) and ``C qd = -m_body
    d hd^2 (c, s, 0, 0, 0)``; g = 0 (gravity along -z).

    The rows (``cases.differential_drive``), each wheel's contact along its rolling direction e1 and the axle across
    e2: ``A = [[c, s, -b, -r, 0], [c, s, b, 0, -r], [-s, c, 0, 0, 0]]``; only the heading enters A, so ``Adot qd = hd
    (v_lat, v_lat, -v)`` with ``v = c xd + s yd``, ``v_lat = -s xd + c yd``. Returns (M, C qd, A, Adot qd)."""
    s, c = np.sin(q[2]), np.cos(q[2])
    b, d = track / 2.0, com_ahead
    m, md = m_body + 2.0 * m_wheel, m_body * com_ahead
    J = m_body * track**2 / 6.0 + m_wheel * r**2 / 2.0 + m_body * d**2 + 2.0 * m_wheel * b**2
    M = np.zeros((5, 5))
    M[:3, :3] = [[m, 0.0, -md * s], [0.0, m, md * c], [-md * s, md * c, J]]
    M[3, 3] = M[4, 4] = m_wheel * r**2 / 2.0
    Cqd = -md * qd[2] ** 2 * np.array([c, s, 0.0, 0.0, 0.0])
    A = np.array([[c, s, -b, -r, 0.0], [c, s, b, 0.0, -r], [-s, c, 0.0, 0.0, 0.0]])
    v, v_lat = c * qd[0] + s * qd[1], -s * qd[0] + c * qd[1]
    return M, Cqd, A, qd[2] * np.array([v_lat, v_lat, -v])


def drive_load(q, drag, g, payload) -> np.ndarray:
    """``tau_ext = J^T F`` of the crate on the tray by hand (``cases.differential_drive``): the body-frame force ``f_b =
    (-drag, -0.4 drag, -payload g)`` and couple ``(0, 0, 0.1 drag)`` at ``r_b = (-0.15, 0.05, 2 r)`` from the chassis
    origin P. The point moves with ``Pdot + hd z x (R r_b)``, so x and y take the horizontal force ``R f_b``, the heading
    the moment about z ``r_bx f_by - r_by f_bx + 0.1 drag``; the weight does no work (nothing moves vertically), the
    wheels take nothing."""
    s, c = np.sin(q[2]), np.cos(q[2])
    fx, fy = -drag, -0.4 * drag
    return np.array([c * fx - s * fy, s * fx + c * fy, -0.15 * fy - 0.05 * fx + 0.1 * drag, 0.0, 0.0])


def drive_motion(q, qd, u, tau_ext, m_body, m_wheel, r, track, com_ahead):
    """The differential drive's accelerations and multipliers by hand at an admissible state (``Pdot = v e1``, ``left_d
    = (v - b w) / r``, ``right_d = (v + b w) / r``, ``w = hd``) under the wheel torques u and the load's ``tau_ext = (F_x,
    F_y, tau, 0, 0)``: with ``F_along = c F_x + s F_y``, ``F_lat = -s F_x + c F_y`` and lam = (left traction, right
    traction, axle's lateral force), the forces the ground exerts along e1 at each contact and along e2 at P.

    Newton-Euler of chassis + wheels. The system's COM is ``d m_body / m`` ahead of P, so its momentum changes along
    e1 and e2 by ``m vdot - m_body d w^2`` and ``m v w + m_body d wdot`` (``Pddot = vdot e1 + v w e2``); its angular
    momentum about P by ``J wdot + m_body d v w`` (P moves, the COM is off it). Each wheel spins about its axle under
    its motor and its contact's traction, whose moment about the axle is ``-r lam``: ``I_a spin_dd = u - r lam``
    (the disk is symmetric, no gyroscopic term along the axle); the motors' reactions on the chassis are about the
    horizontal axle and do no planar work. So::

        m vdot - m_body d w^2 = F_along + lam_l + lam_r,     m v w + m_body d wdot = F_lat + lam_a,
        J wdot + m_body d v w = tau + b (lam_r - lam_l),    I_a (vdot -+ b wdot) / r = u_l,r - r lam_l,r

    and eliminating the tractions: ``(m + 2 I_a / r^2) vdot = F_along + m_body d w^2 + (u_l + u_r) / r``, ``(J + 2 b^2
    I_a / r^2) wdot = tau - m_body d v w + b (u_r - u_l) / r``; ``lam_a = m v w + m_body d wdot - F_lat``. Then ``xdd = c
    vdot - s v w``, ``ydd = s vdot + c v w``, ``hdd = wdot``, ``spin_dd = (vdot -+ b wdot) / r``. Returns (qdd, lam)."""
    s, c = np.sin(q[2]), np.cos(q[2])
    b, d = track / 2.0, com_ahead
    m, md, Ia = m_body + 2.0 * m_wheel, m_body * com_ahead, m_wheel * r**2 / 2.0
    J = m_body * track**2 / 6.0 + m_wheel * r**2 / 2.0 + m_body * d**2 + 2.0 * m_wheel * b**2
    v, w = c * qd[0] + s * qd[1], qd[2]
    along, lateral = c * tau_ext[0] + s * tau_ext[1], -s * tau_ext[0] + c * tau_ext[1]
    vdot = (along + md * w * w + (u[0] + u[1]) / r) / (m + 2.0 * Ia / r**2)
    wdot = (tau_ext[2] - md * v * w + b * (u[1] - u[0]) / r) / (J + 2.0 * b * b * Ia / r**2)
    left, right = (vdot - b * wdot) / r, (vdot + b * wdot) / r
    lam = np.array([(u[0] - Ia * left) / r, (u[1] - Ia * right) / r, m * v * w + md * wdot - lateral])
    return np.array([c * vdot - s * v * w, s * vdot + c * v * w, wdot, left, right]), lam


def _drive_rule(p) -> Rule:
    """The drive: the chassis (COM at ``(com_ahead, 0, r)``, trace ``m_body (4 track^2 + 2 r^2) / 12``), two wheels at
    ``(0, +-track/2, r)`` of trace ``m_w r^2``; the carriages massless."""
    r, half = p["r"], p["track"] / 2.0
    return Rule.of((p["m_body"], float(np.hypot(p["com_ahead"], r)), p["m_body"] * (4.0 * p["track"] ** 2 + 2.0 * r * r)
                    / 12.0), *[(p["m_wheel"], float(np.hypot(half, r)), p["m_wheel"] * r * r)] * 2)


def _differential_drive(p, q, qd, u) -> Split:
    """:func:`drive_terms`, :func:`drive_load` and :func:`drive_motion` (total with u, drift with 0, the load in both;
    ctrl = B_c B u, eq. 17, by :func:`constrained_input_map`); the task point ``front`` at ``P + f e1``, ``f =
    com_ahead + 0.1``: ``J = [[1, 0, -f s, 0, 0], [0, 1, f c, 0, 0]]``, ``Jdot qd = -f hd^2 e1``."""
    shape = (p["m_body"], p["m_wheel"], p["r"], p["track"], p["com_ahead"])
    M, Cqd, Jc, bias = drive_terms(q, qd, *shape)
    tau_ext = drive_load(q, p["drag"], p["g"], p["payload"])
    B = np.zeros((5, 2))
    B[3, 0] = B[4, 1] = 1.0
    t = _Terms(M, np.linalg.inv(M), Cqd, -tau_ext, B @ u, p["m_body"] + 2.0 * p["m_wheel"], abs(p["g"]), tau_ext)
    total, lam = drive_motion(q, qd, u, tau_ext, *shape)
    drift, lam_drift = drive_motion(q, qd, np.zeros(2), tau_ext, *shape)
    s, c = np.sin(q[2]), np.cos(q[2])
    f = p["com_ahead"] + 0.1
    J = np.array([[1.0, 0.0, -f * s, 0.0, 0.0], [0.0, 1.0, f * c, 0.0, 0.0]])
    return _assemble(t, qd, drift, constrained_input_map(M, Jc) @ (B @ u), total,
                     _task(J, -f * qd[2] ** 2 * np.array([c, s]), drift, task_inertia(J, t.Minv)),
                     _Kkt(np.zeros(3), Jc, bias, lam, lam_drift, _drive_rule(p)))


# ------------------------------------------------------------------------------------------------- the voter

UNCONSTRAINED = ("drift", "ctrl", "total", "additivity", "power_ctrl", "task_drift", "kinetic_energy", "task_inertia")
CONSTRAINED = ("lam", "lam_drift", "constraint_force", "constraint_force_drift", "power_constr",
               "power_constr_per_coord", "admissibility_drift", "admissibility_total", "constraint_value",
               "constraint_velocity", "constraint_jacobian", "constraint_bias")
LOADED = ("external_force", "power_ext")


@dataclass(frozen=True)
class ClosedForm:
    """One case's closed form: where its equations come from, the shape (n, m, k) its parameters give, its split
    from the typed parameters and a state, and (constrained cases) the scales of the backends' rule for redundant
    rows from the typed parameters (:class:`Rule`; equal to the model's ``length_scale`` and ``inertia_scale``)."""

    source: str
    shape: Callable[[dict], tuple[int, int, int]]
    split: Callable[[dict, np.ndarray, np.ndarray, np.ndarray], Split]
    rule: Callable[[dict], Rule] | None = None
    loaded: bool = False

    def supplies(self, params: dict) -> tuple[str, ...]:
        """The compared quantities it supplies (the joint loads are not among them)."""
        return UNCONSTRAINED + (CONSTRAINED if self.shape(params)[2] else ()) + (LOADED if self.loaded else ())


CLOSED_FORMS: dict[str, ClosedForm] = {
    "double_pendulum": ClosedForm("article section 3, eqs. (4)-(9), with planar disk inertias I1, I2",
                                  lambda p: (2, 2, 0), _double_pendulum),
    "n_link_pendulum": ClosedForm("the Lagrangian of n point masses in absolute angles, mapped to relative angles",
                                  lambda p: (p["n"], p["n"], 0), _n_link_pendulum),
    "acrobot": ClosedForm("Spong's acrobot equations, angles from hanging down", lambda p: (2, 1, 0), _acrobot),
    "double_pendulum_circle": ClosedForm("article 5.6, eqs. (4)-(8), (12)-(17), one circle row",
                                         lambda p: (2, 2, 1), _double_pendulum_circle, _double_pendulum_rule),
    "cartesian_pendulum": ClosedForm("the multiplier of eqs. (12)-(13) by hand, M = m I",
                                     lambda p: (2, 2, 1), _cartesian_pendulum, _cartesian_rule),
    "double_pendulum_absolute_loop": ClosedForm(
        "the double pendulum's eqs. (4)-(9) mapped to the loop, multipliers the pins' forces (Newton)",
        lambda p: (6, 2, 4), _double_pendulum_absolute_loop, _absolute_loop_rule),
    "rotor": ClosedForm("one rigid body on a tilted revolute joint, by hand", lambda p: (1, 1, 0), _rotor),
    "inclined_slider": ClosedForm("a point mass on a tilted prismatic joint, by hand", lambda p: (1, 1, 0),
                                  _inclined_slider),
    "spherical_pendulum": ClosedForm("a ball on two perpendicular revolute joints, by hand", lambda p: (2, 2, 0),
                                     _spherical_pendulum),
    "four_bar": ClosedForm("three uniform rods by hand (absolute angles mapped to relative), the loop's two rows, "
                           "eqs. (12)-(17) with minimum-norm multipliers at the change points",
                           lambda p: (3, 3, 2), _four_bar, _four_bar_rule),
    "slider_crank": ClosedForm("two uniform rods and a point-mass slider by hand, the wrist pin's two rows, "
                               "eqs. (12)-(17)", lambda p: (3, 3, 2), _slider_crank, _slider_crank_rule),
    "double_pendulum_rail": ClosedForm("article section 3, eqs. (4)-(8), with the tip's PointOnLine row, "
                                       "eqs. (12)-(17)", lambda p: (2, 2, 1), _double_pendulum_rail,
                                       _double_pendulum_rule),
    "free_body": ClosedForm("Newton's and Euler's equations of a free rigid body in its own frame, by hand",
                            lambda p: (6, 6, 0), _free_body),
    "knife_edge": ClosedForm("the Chaplygin sleigh by hand: Newton and Euler along and across the runner, the knife "
                             "edge's Pfaffian row, eqs. (12)-(17)", lambda p: (3, 3, 1), _knife_edge, _sleigh_rule),
    "rolling_disk": ClosedForm("the rolling disk by hand (Neimark-Fufaev, Bloch 1.4): the centre's velocity and the "
                               "angular velocity in the heading frame, the contact's two Pfaffian rows, eqs. (12)-(17)",
                               lambda p: (5, 5, 2), _rolling_disk, _disk_rule),
    "geared_pendulums": ClosedForm("two uniform rods by hand coupled by a JointCoupling gear, eqs. (12)-(17)",
                                   lambda p: (2, 2, 1), _geared_pendulums, _gear_rule),
    "double_pendulum_tip_force": ClosedForm("article section 3, eqs. (4)-(9), with tau_ext = J^T f of the tip force "
                                            "(eq. 12, 14)", lambda p: (2, 2, 0), _double_pendulum_tip_force,
                                            loaded=True),
    "double_pendulum_spring": ClosedForm("article section 3, eqs. (4)-(9), with tau_ext of the tip spring and the "
                                         "body-frame wrench by hand (eq. 12, 14)", lambda p: (2, 2, 0),
                                         _double_pendulum_spring, loaded=True),
    "differential_drive": ClosedForm("Newton-Euler of chassis and wheels by hand in the forward speed and the turning "
                                     "rate (the wheels' spin inertia), the rolling-direction and axle rows, tau_ext = "
                                     "J^T F of the payload, eqs. (12)-(17)", lambda p: (5, 2, 3), _differential_drive,
                                     _drive_rule, loaded=True),
}


def _describe(params: dict) -> str:
    return ", ".join(f"{k}={v!r}" for k, v in params.items())


def _checked_split(case: str, form: ClosedForm, params: dict, model, q, qd, u) -> Split:
    """The closed form's split at (q, qd, u) after checking that ``model`` is the case it is bound to: its name (a
    moved scene's ``case@frame`` included) and its shape (n, m, k) from the parameters; else ClosedFormMismatch."""
    n, m, k = form.shape(params)
    shapes = (("the number of coordinates n", model.n, n), ("the number of inputs m", model.m, m),
              ("the number of constraint rows k", model.k, k))
    problems = [f"{label} is {got}, the closed form's is {want}" for label, got, want in shapes if got != want]
    if model.name.split("@")[0] != case:
        problems.insert(0, f"the model is named '{model.name}', not '{case}'")
    if problems:
        raise ClosedFormMismatch(f"the closed form of case '{case}' ({_describe(params)}) does not match the model it "
                                 f"was given: {'; '.join(problems)}")
    q, qd, u = check_state(model, q, qd, u)
    return form.split(params, q, qd, u)


def voter(case: str, params: Mapping[str, object] | None = None) -> Formalism | None:
    """The gate's voter ``closed_form`` for case ``case`` built with ``params`` (numbers or CLI strings, converted as
    ``cases.load`` converts them; CaseError for an unknown parameter), or None when the case has no closed form. Its
    ``split(model, q, qd, u)`` computes from the typed parameters alone and raises :class:`ClosedFormMismatch` for a
    model that is not that case with those parameters."""
    form = CLOSED_FORMS.get(case)
    if form is None:
        return None
    typed = cases.parameters(case, **dict(params or {}))
    return Formalism("closed_form", f"closed form of {case}: {form.source}", partial(_checked_split, case, form, typed))


def coverage(case: str, params: Mapping[str, object] | None = None) -> str:
    """For a report's line on ``case`` (the caller names the case): the closed form that votes on it with ``params``,
    the typed parameters it is bound to and the quantities it supplies, or "none" and the cases that have one."""
    form = CLOSED_FORMS.get(case)
    if form is None:
        return f"none (closed forms exist for {', '.join(CLOSED_FORMS)})"
    typed = cases.parameters(case, **dict(params or {}))
    return (f"{form.source}; bound to {_describe(typed)}; supplies {', '.join(form.supplies(typed))} (not the joint "
            "loads)")
