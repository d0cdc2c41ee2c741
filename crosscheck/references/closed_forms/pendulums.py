"""Planar pendulums: the article's double pendulum (section 3, eqs. 4-9), chains in absolute angles mapped to
relative ones (section 6.4.6), the acrobot, and the double pendulum's external loads (``tau_ext = J^T f``)."""

from __future__ import annotations

import mpmath
import numpy as np
import scipy.linalg

from crosscheck.references.closed_forms.algebra import FLOAT, MPMATH


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


def mp(*values):
    """The arguments as mpmath numbers at the working precision, each float taken as its exact binary value."""
    return [mpmath.mpf(float(x)) for x in values]


def pendulum_terms_mp(t, td, m1=1.0, m2=1.0, l1=1.0, l2=1.0, g=9.81):
    """Eqs. (6), (7), (8) (:func:`pendulum_terms`) in mpmath at its working precision, every argument taken as its
    exact binary value: (M, C qd, g) as mpmath matrices (2 x 2, 2 x 1, 2 x 1)."""
    t1, t2, t1d, t2d, m1, m2, l1, l2, g = mp(*t, *td, m1, m2, l1, l2, g)
    return pendulum_terms((t1, t2), (t1d, t2d), m1, m2, l1, l2, g, MPMATH)


def disk_inertia(I1=0.0, I2=0.0):  # noqa: N803
    """What rotational inertias I1, I2 of the masses about z (``cases.double_pendulum(I1=.., I2=..)``, planar disks)
    add to eq. (6): T gains 1/2 I1 t1d^2 + 1/2 I2 (t1d + t2d)^2, so M gains [[I1 + I2, I2], [I2, I2]] (C qd and g
    are unchanged)."""
    return np.array([[I1 + I2, I2], [I2, I2]])


def rotor_inertia(*armature) -> np.ndarray:
    """What the joints' rotors (armature a_i, ``Body.armature``) add to M in the joint coordinates: each rotor turns at
    its own joint's (relative) rate, T gains ``1/2 sum a_i qd_i^2``, so M gains ``diag(a_1, ..., a_n)`` (C qd and g are
    unchanged: the rotor's energy does not depend on q)."""
    return np.diag(np.array(armature, dtype=float))


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
