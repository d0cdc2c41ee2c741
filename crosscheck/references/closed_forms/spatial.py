"""Three-dimensional cases: a rotor on a tilted axis, a slider on a tilted rail, a spherical pendulum, and a free
body by Newton's and Euler's equations in its body frame."""

from __future__ import annotations

import numpy as np

from crosscheck.references.closed_forms.algebra import hat, turn


# ------------------------------------------------------------------------------------------------- 3-D cases

#: The rotor's task point in its body frame (``cases.rotor``: the point ``rim``, along world x).
ROTOR_RIM = (0.4, 0.1, -0.2)


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


#: The free body's centre of mass and task point ``marker`` in its body frame (``cases.free_body``).
FREE_BODY_COM = np.array([0.05, -0.03, 0.02])
FREE_BODY_MARKER = np.array([0.2, 0.1, -0.05])


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
    R = np.eye(3) + 2.0 * w4 * hat(e) + 2.0 * hat(e) @ hat(e)
    c, r = FREE_BODY_COM, FREE_BODY_MARKER
    C = hat(c)
    M = np.block([[m * np.eye(3), -m * C], [m * C, np.diag([I1, I2, I3]) - m * C @ C]])
    vo, w = np.asarray(v[:3], dtype=float), np.asarray(v[3:], dtype=float)
    lin, ang = np.split(M @ np.concatenate([vo, w]), 2)
    Cqd = np.concatenate([np.cross(w, lin), np.cross(w, ang) + np.cross(vo, lin)])
    weight = m * R.T @ np.array([0.0, 0.0, -g])
    grav = -np.concatenate([weight, np.cross(c, weight)])
    J = R @ np.hstack([np.eye(3), -hat(r)])
    bias = R @ np.cross(w, vo + np.cross(w, r))
    return M, Cqd, grav, J, bias
