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

and the constrained references of section 5 that every backend's constrained tests share:

* ``tip_position``, ``tip_bias``          eq. (4) and its second derivative at tdd = 0 (``Jdot qd``)
* ``circle_terms``, ``circle_state``      the tip on a circle (5.6): phi, Jc, Jcdot qd by hand; an admissible state
                                          by inverse kinematics of eq. (4)
* ``kkt_solve``                           the KKT system of 5.6 (eqs. 12, 13)
* ``constrained_input_map``               B_c of eq. (17)
* ``min_norm_solve``                      the range-space solve with S's pseudo-inverse (redundant rows)
* ``cartesian_lam``                       the cartesian pendulum's multiplier in closed form
* ``disk_inertia``                        what rotational inertias of the masses add to eq. (6)
* ``pendulum_terms_mp``, ``cartesian_lam_mp``
                                          eqs. (6)-(8) and the cartesian pendulum's multiplier in mpmath, for
                                          references beyond double precision
* ``absolute_loop_state``, ``loop_to_joint``, ``pin_forces``
                                          the absolute-coordinate double pendulum: a joint state in its coordinates,
                                          its accelerations back, and its pins' forces by Newton's second law

Not a test module (no ``test_`` prefix): the test files import it as ``from closed_forms import ...``, which works
because pytest's default ("prepend") import mode puts this directory on ``sys.path`` (there is no
``tests/__init__.py``).
"""

from __future__ import annotations

import dataclasses

import mpmath
import numpy as np

import cases


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


def tip_position(t, l1=1.0, l2=1.0):
    """Article eq. (4): the tip (mass 2) at x2 = l1 sin t1 + l2 sin(t1 + t2), y2 = -l1 cos t1 - l2 cos(t1 + t2)."""
    return np.array([l1 * np.sin(t[0]) + l2 * np.sin(t[0] + t[1]), -l1 * np.cos(t[0]) - l2 * np.cos(t[0] + t[1])])


def tip_bias(t, td, l1=1.0, l2=1.0):
    """``Jdot qd`` of the tip: eq. (4) differentiated twice at tdd = 0, with w = t1d + t2d,
    (-l1 sin t1 t1d^2 - l2 sin(t1 + t2) w^2, l1 cos t1 t1d^2 + l2 cos(t1 + t2) w^2); the tip's classical
    acceleration is ``endpoint_jacobian(t) @ tdd + tip_bias(t, td)`` (eq. 23)."""
    w = td[0] + td[1]
    return np.array([-l1 * np.sin(t[0]) * td[0]**2 - l2 * np.sin(t[0] + t[1]) * w**2,
                     l1 * np.cos(t[0]) * td[0]**2 + l2 * np.cos(t[0] + t[1]) * w**2])


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


def kkt_solve(M, Jc, f, bias):
    """Article 5.6: ``[[M, -Jc^T], [Jc, 0]] [qdd; lam] = [f; -Jcdot qd]`` with ``f = B u - C qd - g`` (eqs. 12, 13;
    ``f = -C qd - g`` gives the drift and lam_drift of eq. 14). ``Jc`` a row (one constraint) or k x n, ``bias``
    = ``Jcdot qd`` a scalar or (k,). Returns ``(qdd, lam)``."""
    Jc, bias = np.atleast_2d(Jc), np.atleast_1d(bias)
    n, k = len(M), len(Jc)
    K = np.block([[M, -Jc.T], [Jc, np.zeros((k, k))]])
    x = np.linalg.solve(K, np.concatenate([f, -bias]))
    return x[:n], x[n:]


def constrained_input_map(M, Jc):
    """Article eq. (17): ``B_c = M^-1 [I - Jc^T (Jc M^-1 Jc^T)^-1 Jc M^-1]`` (full-rank ``Jc``, a row or k x n), so
    that ``qdd_ctrl = B_c B u``."""
    Jc = np.atleast_2d(Jc)
    Minv = inv2(M) if np.shape(M) == (2, 2) else np.linalg.inv(M)
    return Minv @ (np.eye(len(M)) - Jc.T @ np.linalg.solve(Jc @ Minv @ Jc.T, Jc @ Minv))


def min_norm_solve(M, Jc, f, bias, rcond):
    """Article 5.6 with redundant rows, by the range-space method: ``lam = S^+ (-Jcdot qd - Jc M^-1 f)`` with
    ``S = Jc M^-1 Jc^T`` and its pseudo-inverse cut at ``rcond`` (eigenvalues below rcond times the largest are
    redundant directions), ``qdd = M^-1 (f + Jc^T lam)``: the minimum-norm multipliers; with full rank the KKT
    solution. Returns ``(qdd, lam)``."""
    Jc, bias = np.atleast_2d(Jc), np.atleast_1d(bias)
    Minv = np.linalg.inv(M)
    S = Jc @ Minv @ Jc.T
    lam = np.linalg.pinv(S, rcond=rcond, hermitian=True) @ (-bias - Jc @ Minv @ f)
    return Minv @ (f + Jc.T @ lam), lam


def cartesian_lam(q, qd, u, m=1.0, L=1.0, g=9.81):  # noqa: N803
    """The cartesian pendulum's multiplier (``cases.cartesian_pendulum``: q = p = (x, y), M = m I, B = I,
    ``phi = |p|^2 - L^2`` so ``Jc = 2 p^T`` and ``Jcdot qd = 2 |v|^2``), eqs. (12)-(13) solved by hand:
    ``lam = -m (|v|^2 + p . (gravity + u / m)) / (2 L^2)`` with gravity (0, -g); u = 0 gives lam_drift (eq. 14)."""
    q, qd, u = (np.asarray(x, dtype=float) for x in (q, qd, u))
    return -m * (qd @ qd + q @ (np.array([0.0, -g]) + u / m)) / (2.0 * L**2)


def disk_inertia(I1=0.0, I2=0.0):  # noqa: N803
    """What rotational inertias I1, I2 of the masses about z (``cases.double_pendulum(I1=.., I2=..)``) add to eq. (6):
    T gains 1/2 I1 t1d^2 + 1/2 I2 (t1d + t2d)^2, so M gains [[I1 + I2, I2], [I2, I2]] (C qd and g are unchanged)."""
    return np.array([[I1 + I2, I2], [I2, I2]])


def absolute_loop_state(t, td, l1=1.0):
    """The joint state (t, td) in the coordinates of ``cases.double_pendulum_absolute_loop``,
    ``q = (x1, y1, phi1, x2, y2, phi2)``: link 1's pivot at the origin, link 2's at link 1's end
    ``l1 (sin phi1, -cos phi1)``, absolute angles ``phi = (t1, t1 + t2)`` (6.4.6). Returns (q, qd)."""
    p1, p1d = t[0], td[0]
    q = np.array([0.0, 0.0, p1, l1 * np.sin(p1), -l1 * np.cos(p1), t[0] + t[1]])
    qd = np.array([0.0, 0.0, p1d, l1 * np.cos(p1) * p1d, l1 * np.sin(p1) * p1d, td[0] + td[1]])
    return q, qd


def loop_to_joint(a):
    """Absolute-loop accelerations (6,) back to the joint coordinates: (phi1dd, phi2dd - phi1dd)."""
    return np.array([a[2], a[5] - a[2]])


def pin_forces(t, td, tdd, m1=1.0, m2=1.0, l1=1.0, l2=1.0, g=9.81):
    """The pins' forces on the double pendulum at accelerations tdd, by Newton's second law for the masses of
    eq. (4) (the joint torques are couples): the elbow's on link 2, ``m2 (a2 - gravity)``, and the shoulder's on the
    whole chain, ``m1 a1 + m2 a2 - (m1 + m2) gravity``, with a_i eq. (4) differentiated twice and gravity (0, -g).
    Returns (shoulder, elbow), each (2,)."""
    gravity = np.array([0.0, -g])
    a1 = endpoint_jacobian(t, l1, 0.0) @ tdd + tip_bias(t, td, l1, 0.0)
    a2 = endpoint_jacobian(t, l1, l2) @ tdd + tip_bias(t, td, l1, l2)
    return m1 * a1 + m2 * a2 - (m1 + m2) * gravity, m2 * (a2 - gravity)


def heaviest_body_heavier(model, relative: float):
    """``model`` with its heaviest body's mass scaled by ``1 + relative``: a small modelling error a tolerance must
    resolve."""
    heavy = int(np.argmax([b.mass for b in model.bodies]))
    bodies = [dataclasses.replace(b, mass=b.mass * (1.0 + relative)) if i == heavy else b
              for i, b in enumerate(model.bodies)]
    return cases.build_model(f"{model.name}_heavier", bodies, gravity=model.gravity, input_map=model.input_map,
                             task_points=model.task_points, constraints=model.constraints)


def _mp(*values):
    """The arguments as mpmath numbers at the working precision, each float taken as its exact binary value."""
    return [mpmath.mpf(float(x)) for x in values]


def pendulum_terms_mp(t, td, m1=1.0, m2=1.0, l1=1.0, l2=1.0, g=9.81):
    """Eqs. (6), (7), (8) as in ``pendulum_terms``, evaluated in mpmath at its working precision (every argument taken
    as its exact binary value): (M, C qd, g) as mpmath matrices (2 x 2, 2 x 1, 2 x 1)."""
    t1, t2, t1d, t2d, m1, m2, l1, l2, g = _mp(*t, *td, m1, m2, l1, l2, g)
    c2, s12 = mpmath.cos(t2), mpmath.sin(t1 + t2)
    M12 = m2 * l2**2 + m2 * l1 * l2 * c2
    M = mpmath.matrix([[(m1 + m2) * l1**2 + m2 * l2**2 + 2 * m2 * l1 * l2 * c2, M12], [M12, m2 * l2**2]])
    c = m2 * l1 * l2 * mpmath.sin(t2)
    Cqd = mpmath.matrix([-2 * c * t1d * t2d - c * t2d**2, c * t1d**2])
    grav = mpmath.matrix([(m1 + m2) * g * l1 * mpmath.sin(t1) + m2 * g * l2 * s12, m2 * g * l2 * s12])
    return M, Cqd, grav


def cartesian_lam_mp(q, qd, u, m=1.0, L=1.0, g=9.81):  # noqa: N803
    """``cartesian_lam`` in mpmath at its working precision (arguments exact binary values):
    ``lam = -m (|v|^2 + p . (gravity + u / m)) / (2 L^2)``; exact at a state exactly on the circle, |p| = L."""
    x, y, xd, yd, ux, uy, m, L, g = _mp(*q, *qd, *u, m, L, g)
    return -m * (xd**2 + yd**2 + x * ux / m + y * (uy / m - g)) / (2 * L**2)
