"""The planar double pendulum's closed forms, typed in once from the article (not read from any project code).

Article section 3 (drift-control-article): point masses m1, m2 at the ends of links l1, l2; theta1 from the
downward vertical, theta2 relative to the first link; gravity g. The tests use these as independent references
for every backend, so they are written out from the article's equations only:

* ``endpoint_jacobian``  eq. (5)
* ``article_M``          eq. (6)  mass matrix
* ``article_Cqd``        eq. (7)  velocity-product terms C(q, qd) qd
* ``article_g``          eq. (8)  gravity terms
* ``pendulum_terms``     eqs. (6), (7), (8) together
* ``inv2``               the 2x2 inverse of section 4.7.2
* ``absolute_terms``     (M, C qd, g) in absolute angles ``phi = (theta1, theta1 + theta2)`` (section 6.4.6),
                         from the Lagrangian written directly in phi (derivation in its docstring)

Not a test module (no ``test_`` prefix): the test files import it as ``from closed_forms import ...``, which works
because pytest's default ("prepend") import mode puts this directory on ``sys.path`` (there is no
``tests/__init__.py``).
"""

from __future__ import annotations

import numpy as np


def endpoint_jacobian(t, l1=1.0, l2=1.0):
    """Article eq. (5): J(q) = [[l1 cos t1 + l2 cos(t1 + t2), l2 cos(t1 + t2)],
                                [l1 sin t1 + l2 sin(t1 + t2), l2 sin(t1 + t2)]]."""
    c1, s1, c12, s12 = np.cos(t[0]), np.sin(t[0]), np.cos(t[0] + t[1]), np.sin(t[0] + t[1])
    return np.array([[l1 * c1 + l2 * c12, l2 * c12], [l1 * s1 + l2 * s12, l2 * s12]])


def article_M(t2, m1=1.0, m2=1.0, l1=1.0, l2=1.0):
    """Article eq. (6): M11 = (m1 + m2) l1^2 + m2 l2^2 + 2 m2 l1 l2 cos t2, M12 = M21 = m2 l2^2 + m2 l1 l2 cos t2,
    M22 = m2 l2^2."""
    c2 = np.cos(t2)
    M11 = (m1 + m2) * l1**2 + m2 * l2**2 + 2 * m2 * l1 * l2 * c2
    M12 = m2 * l2**2 + m2 * l1 * l2 * c2
    M22 = m2 * l2**2
    return np.array([[M11, M12], [M12, M22]])


def article_Cqd(t2, t1d, t2d, m2=1.0, l1=1.0, l2=1.0):
    """Article eq. (7): C qd = [-2 c t1d t2d - c t2d^2, c t1d^2] with c = m2 l1 l2 sin t2 (m1 does not enter)."""
    c = m2 * l1 * l2 * np.sin(t2)
    return np.array([-2 * c * t1d * t2d - c * t2d**2, c * t1d**2])


def article_g(t1, t2, m1=1.0, m2=1.0, l1=1.0, l2=1.0, g=9.81):
    """Article eq. (8): g(q) = [(m1 + m2) g l1 sin t1 + m2 g l2 sin(t1 + t2), m2 g l2 sin(t1 + t2)]."""
    s12 = np.sin(t1 + t2)
    return np.array([(m1 + m2) * g * l1 * np.sin(t1) + m2 * g * l2 * s12, m2 * g * l2 * s12])


def pendulum_terms(t, td, m1=1.0, m2=1.0, l1=1.0, l2=1.0, g=9.81):
    """(M, C qd, g) of article eqs. (6), (7), (8) at angles ``t`` = (theta1, theta2) and rates ``td``."""
    return (article_M(t[1], m1, m2, l1, l2),
            article_Cqd(t[1], td[0], td[1], m2, l1, l2),
            article_g(t[0], t[1], m1, m2, l1, l2, g))


def inv2(M):
    """The 2x2 inverse of article 4.7.2: M^-1 = (1 / det M) [[M22, -M12], [-M21, M11]], det M = M11 M22 - M12 M21
    (the article writes M12^2: M is symmetric)."""
    det = M[0, 0] * M[1, 1] - M[0, 1] * M[1, 0]
    return np.array([[M[1, 1], -M[0, 1]], [-M[1, 0], M[0, 0]]]) / det


def absolute_terms(phi, phid, m1=1.0, m2=1.0, l1=1.0, l2=1.0, g=9.81):
    """(M, C qd, g) of the double pendulum in absolute angles phi = (theta1, theta1 + theta2) (article 6.4.6).

    Written from the Lagrangian in phi, not by transforming eqs. (6)-(8): the masses sit at
    (l1 sin phi1, -l1 cos phi1) and that plus (l2 sin phi2, -l2 cos phi2), so with d = phi1 - phi2
        T = 1/2 (m1 + m2) l1^2 phi1d^2 + 1/2 m2 l2^2 phi2d^2 + m2 l1 l2 cos(d) phi1d phi2d,
        V = -(m1 + m2) g l1 cos phi1 - m2 g l2 cos phi2,
    and Lagrange's equations give M = [[(m1 + m2) l1^2, m2 l1 l2 cos d], [m2 l1 l2 cos d, m2 l2^2]],
    C qd = m2 l1 l2 sin(d) [phi2d^2, -phi1d^2], g = [(m1 + m2) g l1 sin phi1, m2 g l2 sin phi2].
    """
    d = phi[0] - phi[1]
    k = m2 * l1 * l2
    M = np.array([[(m1 + m2) * l1**2, k * np.cos(d)], [k * np.cos(d), m2 * l2**2]])
    Cqd = k * np.sin(d) * np.array([phid[1] ** 2, -phid[0] ** 2])
    grav = np.array([(m1 + m2) * g * l1 * np.sin(phi[0]), m2 * g * l2 * np.sin(phi[1])])
    return M, Cqd, grav
