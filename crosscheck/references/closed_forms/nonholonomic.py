"""Pfaffian (non-holonomic) constraints ``A(q) qd = 0``: the Chaplygin sleigh (a knife edge), the classical rolling
disk (Neimark-Fufaev, Bloch 1.4) and the differential drive."""

from __future__ import annotations

import numpy as np


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
def drive_terms(q, qd, m_body, m_wheel, r, track, com_ahead):
    """The differential drive (``cases.differential_drive``) by hand: q = (x, y, h, left, right), P = (x, y) the axle's
    midpoint, ``e1 = (c, s)`` forward, ``e2 = (-s, c)`` along the axle, half track ``b = track / 2``, ``d = com_ahead``.
    The chassis' COM moves with ``Pdot + d hd e2``, the wheels' centres with ``Pdot -+ b hd e1``; the chassis turns at
    ``hd`` about z (its inertia ``m_body track^2 / 6`` about z), a thin wheel at ``hd z + spin_d axle`` (``m_w r^2 / 4``
    about a diameter, ``m_w r^2 / 2`` about the axle). So ``T = m/2 |Pdot|^2 + m_body d hd (e2 . Pdot) + J/2 hd^2 +
    I_a/2 (left_d^2 + right_d^2)`` with ``m = m_body + 2 m_w``, ``J = m_body track^2 / 6 + m_w r^2 / 2 + m_body d^2 + 2
    m_w b^2``, ``I_a = m_w r^2 / 2``: the sleigh's M (:func:`sleigh_terms`, ``m a`` -> ``m_body d``) and ``C qd =
    -m_body d hd^2 (c, s, 0, 0, 0)``; g = 0 (gravity along -z).

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
    origin P. The point moves with ``Pdot + hd z x (R r_b)``, so x and y take the horizontal force ``R f_b``, the
    heading the moment about z ``r_bx f_by - r_by f_bx + 0.1 drag``; the weight does no work (nothing moves vertically),
    the wheels take nothing."""
    s, c = np.sin(q[2]), np.cos(q[2])
    fx, fy = -drag, -0.4 * drag
    return np.array([c * fx - s * fy, s * fx + c * fy, -0.15 * fy - 0.05 * fx + 0.1 * drag, 0.0, 0.0])


def drive_motion(q, qd, u, tau_ext, m_body, m_wheel, r, track, com_ahead):
    """The differential drive's accelerations and multipliers by hand at an admissible state (``Pdot = v e1``, ``left_d
    = (v - b w) / r``, ``right_d = (v + b w) / r``, ``w = hd``) under the wheel torques u and the load's ``tau_ext =
    (F_x, F_y, tau, 0, 0)``: with ``F_along = c F_x + s F_y``, ``F_lat = -s F_x + c F_y`` and lam = (left traction,
    right traction, axle's lateral force), the forces the ground exerts along e1 at each contact and along e2 at P.

    Newton-Euler of chassis + wheels. The system's COM is ``d m_body / m`` ahead of P, so its momentum changes along
    e1 and e2 by ``m vdot - m_body d w^2`` and ``m v w + m_body d wdot`` (``Pddot = vdot e1 + v w e2``); its angular
    momentum about P by ``J wdot + m_body d v w`` (P moves, the COM is off it). Each wheel spins about its axle under
    its motor and its contact's traction, whose moment about the axle is ``-r lam``: ``I_a spin_dd = u - r lam``
    (the disk is symmetric, no gyroscopic term along the axle); the motors' reactions on the chassis are about the
    horizontal axle and do no planar work. So::

        m vdot - m_body d w^2 = F_along + lam_l + lam_r,     m v w + m_body d wdot = F_lat + lam_a,
        J wdot + m_body d v w = tau + b (lam_r - lam_l),    I_a (vdot -+ b wdot) / r = u_l,r - r lam_l,r

    and eliminating the tractions: ``(m + 2 I_a / r^2) vdot = F_along + m_body d w^2 + (u_l + u_r) / r``, ``(J + 2 b^2
    I_a / r^2) wdot = tau - m_body d v w + b (u_r - u_l) / r``; ``lam_a = m v w + m_body d wdot - F_lat``. Then ``xdd =
    c vdot - s v w``, ``ydd = s vdot + c v w``, ``hdd = wdot``, ``spin_dd = (vdot -+ b wdot) / r``. Returns (qdd,
    lam)."""
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
