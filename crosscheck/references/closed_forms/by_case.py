"""The closed form of each built-in case: its typed parameters (``cases.parameters``) and the state to the terms of
its mechanism family, assembled into a Split (the table :data:`crosscheck.references.closed_forms.CLOSED_FORMS`)."""

from __future__ import annotations

import numpy as np

from crosscheck.references.closed_forms.algebra import condition, inv2, task_inertia, task_inertia_square
from crosscheck.references.closed_forms.assembly import assemble, constrained_solution, Kkt, task_terms, Terms
from crosscheck.references.closed_forms.constrained import (cartesian_lam, circle_terms, constrained_input_map,
                                                            four_bar_loop, four_bar_terms, gear_constraint, gear_terms,
                                                            joint_to_loop, link_point, loop_constraint, loop_terms,
                                                            loop_to_joint, one_row_kkt, pin_forces, rail_terms,
                                                            rod_body, Rule, slider_crank_terms, wrist_pin)
from crosscheck.references.closed_forms.nonholonomic import (disk_center, disk_terms, drive_load, drive_motion,
                                                             drive_terms, sleigh_motion, sleigh_terms)
from crosscheck.references.closed_forms.pendulums import (acrobot_terms, chain_terms, chain_tip, disk_inertia,
                                                          endpoint_jacobian, pendulum_terms, relative_to_absolute,
                                                          rotor_inertia, tip_bias, tip_force, tip_spring, to_joint)
from crosscheck.references.closed_forms.spatial import free_body_terms, rotor_terms, slider_terms, spherical_terms
from formalisms.interface import Split


# ------------------------------------------------------------------------------------ the closed forms by case


def double_pendulum(p, q, qd, u) -> Split:
    """Article section 3: M (eq. 6, plus :func:`disk_inertia` and the joints' :func:`rotor_inertia`), C qd (7),
    g (8), the split (9), the tip (4, 5)."""
    l1, l2 = p["l1"], p["l2"]
    M, Cqd, grav = pendulum_terms(q, qd, p["m1"], p["m2"], l1, l2, p["g"])
    M = M + disk_inertia(p["I1"], p["I2"]) + rotor_inertia(p["a1"], p["a2"])
    t = Terms(M, inv2(M), Cqd, grav, u, p["m1"] + p["m2"], abs(p["g"]))
    drift, ctrl, total = t.accelerations()
    J = endpoint_jacobian(q, l1, l2)
    return assemble(t, qd, drift, ctrl, total, task_terms(J, tip_bias(q, qd, l1, l2), drift, task_inertia_square(J, M)))


def _loaded_pendulum(p, q, qd, u, tau_ext) -> Split:
    """The double pendulum (eqs. 4-9) with the external generalized force ``tau_ext`` beside gravity (eq. 12, 14):
    ``M qdd + C qd + g = B u + tau_ext``."""
    l1, l2 = p["l1"], p["l2"]
    M, Cqd, grav = pendulum_terms(q, qd, p["m1"], p["m2"], l1, l2, p["g"])
    t = Terms(M, inv2(M), Cqd, grav - tau_ext, u, p["m1"] + p["m2"], abs(p["g"]), tau_ext)
    drift, ctrl, total = t.accelerations()
    J = endpoint_jacobian(q, l1, l2)
    return assemble(t, qd, drift, ctrl, total, task_terms(J, tip_bias(q, qd, l1, l2), drift, task_inertia_square(J, M)))


def double_pendulum_tip_force(p, q, qd, u) -> Split:
    """Eqs. (4)-(9) with :func:`tip_force`."""
    return _loaded_pendulum(p, q, qd, u, tip_force(q, p["l1"], p["l2"], p["fx"], p["fy"]))


def double_pendulum_spring(p, q, qd, u) -> Split:
    """Eqs. (4)-(9) with :func:`tip_spring`."""
    return _loaded_pendulum(p, q, qd, u, tip_spring(q, p["l1"], p["l2"], p["k"], p["rest"], p["ax"], p["ay"],
                                                     p["bfx"], p["bfy"], p["couple"]))


def n_link_pendulum(p, q, qd, u) -> Split:
    """:func:`chain_terms` of n equal masses in absolute angles phi = T q (:func:`relative_to_absolute`), mapped to
    the relative angles: M = T^T M_phi T, h = T^T h_phi; the tip :func:`chain_tip` with J_q = J_phi T."""
    n, m, l = p["n"], p["m"], p["l"]
    T = relative_to_absolute(n)
    phi, phid = T @ q, T @ qd
    M, Cqd, grav = to_joint(T, *chain_terms(phi, phid, [m] * n, [l] * n, p["g"]))
    M = M + rotor_inertia(*[p["a"]] * n)              # the rotors turn at the RELATIVE rates: diagonal in q
    t = Terms(M, np.linalg.inv(M), Cqd, grav, u, n * m, abs(p["g"]))
    drift, ctrl, total = t.accelerations()
    J_phi, bias = chain_tip(phi, phid, [l] * n)
    J = J_phi @ T
    return assemble(t, qd, drift, ctrl, total, task_terms(J, bias, drift, task_inertia(J, t.Minv)))


def acrobot(p, q, qd, u) -> Split:
    """Spong's equations (:func:`acrobot_terms`), B = [[0], [1]], the tip of link 2 by eqs. (4), (5)."""
    M, Cqd, grav = acrobot_terms(q, qd, p["m1"], p["m2"], p["l1"], p["lc1"], p["lc2"], p["I1"], p["I2"], p["g"])
    M = M + rotor_inertia(p["a1"], p["a2"])
    t = Terms(M, inv2(M), Cqd, grav, np.array([0.0, u[0]]), p["m1"] + p["m2"], abs(p["g"]))
    drift, ctrl, total = t.accelerations()
    J = endpoint_jacobian(q, p["l1"], p["l2"])
    return assemble(t, qd, drift, ctrl, total,
                     task_terms(J, tip_bias(q, qd, p["l1"], p["l2"]), drift, task_inertia_square(J, M)))


# The scales of each constrained case's rule (:meth:`Rule.of`: mass, |translation| + |com|, tr I per massive body),
# typed in from its factory.


def double_pendulum_rule(p) -> Rule:
    """The point-mass double pendulum (``cases.double_pendulum``'s bodies, the circle's and the rail's): mass 1 at l1
    from the shoulder, link 2 placed l1 down with its mass l2 beyond, no rotational inertia."""
    return Rule.of((p["m1"], p["l1"], 0.0), (p["m2"], p["l1"] + p["l2"], 0.0))


def cartesian_rule(p) -> Rule:
    """The bob at the origin of its slides (the carriage is massless)."""
    return Rule.of((p["m"], 0.0, 0.0))


def absolute_loop_rule(p) -> Rule:
    """Each link's mass l_i from its massless carriages, ``planar_disk(I_i)`` of trace 2 I_i."""
    return Rule.of((p["m1"], p["l1"], 2.0 * p["I1"]), (p["m2"], p["l2"], 2.0 * p["I2"]))


def four_bar_rule(p) -> Rule:
    """Three rods (:func:`rod_body`): the crank at the origin, the coupler placed ``crank`` down the crank, the rocker
    at (ground, 0)."""
    return Rule.of(rod_body(p["m"], p["crank"]), rod_body(p["m"], p["coupler"], p["crank"]),
                   rod_body(p["m"], p["rocker"], p["ground"]))


def slider_crank_rule(p) -> Rule:
    """Two rods (:func:`rod_body`) and the slider placed |offset| from the origin, a point mass."""
    return Rule.of(rod_body(p["m_crank"], p["crank"]), rod_body(p["m_rod"], p["rod"], p["crank"]),
                   (p["m_slider"], abs(p["offset"]), 0.0))


def gear_rule(p) -> Rule:
    """Two rods (:func:`rod_body`), the wheel's placed ``spacing`` from the origin."""
    return Rule.of(rod_body(p["m1"], p["l1"]), rod_body(p["m2"], p["l2"], p["spacing"]))


def double_pendulum_circle(p, q, qd, u) -> Split:
    """Article 5.6: eqs. (6)-(8), the circle row (:func:`circle_terms`), the KKT system by hand
    (:func:`one_row_kkt`: eqs. 12-14) and ctrl = B_c u (eq. 17, :func:`constrained_input_map`)."""
    l1, l2 = p["l1"], p["l2"]
    M, Cqd, grav = pendulum_terms(q, qd, p["m1"], p["m2"], l1, l2, p["g"])
    t = Terms(M, inv2(M), Cqd, grav, u, p["m1"] + p["m2"], abs(p["g"]))
    phi, Jc, bias = circle_terms(q, qd, l1, l2, p["xc"], p["yc"], p["R"])
    drift, lam_drift = one_row_kkt(t.Minv, Jc, bias, -Cqd - grav)
    total, lam = one_row_kkt(t.Minv, Jc, bias, u - Cqd - grav)
    ctrl = constrained_input_map(M, Jc) @ u
    J = endpoint_jacobian(q, l1, l2)
    return assemble(t, qd, drift, ctrl, total, task_terms(J, tip_bias(q, qd, l1, l2), drift, task_inertia_square(J, M)),
                     Kkt(np.array([phi]), Jc.reshape(1, 2), np.array([bias]), np.array([lam]),
                          np.array([lam_drift]), double_pendulum_rule(p)))


def cartesian_pendulum(p, q, qd, u) -> Split:
    """M = m I, h = (0, m g), B = I; lam by :func:`cartesian_lam`, so ``m qdd = m gravity + u + 2 lam p`` (eq. 12)
    for total (and lam_drift, u = 0, for the drift); ctrl = B_c u (eq. 17); the task point is the bob (J = I)."""
    m, L, g = p["m"], p["L"], p["g"]
    M, gravity = m * np.eye(2), np.array([0.0, -g])
    t = Terms(M, np.eye(2) / m, np.zeros(2), np.array([0.0, m * g]), u, m, abs(g))
    lam, lam_drift = cartesian_lam(q, qd, u, m, L, g), cartesian_lam(q, qd, np.zeros(2), m, L, g)
    total, drift = gravity + (u + 2.0 * lam * q) / m, gravity + 2.0 * lam_drift * q / m
    ctrl = constrained_input_map(M, 2.0 * q) @ u
    return assemble(t, qd, drift, ctrl, total, task_terms(np.eye(2), np.zeros(2), drift, task_inertia_square(np.eye(2), M)),
                     Kkt(np.array([q @ q - L * L]), 2.0 * q.reshape(1, 2), np.array([2.0 * qd @ qd]),
                          np.array([lam]), np.array([lam_drift]), cartesian_rule(p)))


def double_pendulum_absolute_loop(p, q, qd, u) -> Split:
    """The double pendulum with disk inertias (eqs. 6-9 and :func:`disk_inertia`) at the joint state t = (phi1,
    phi2 - phi1) (:func:`loop_to_joint`), its accelerations mapped to the loop (:func:`joint_to_loop`; ctrl by the
    linear part), lam and lam_drift the pins' forces (:func:`pin_forces`) at total and drift; the loop's own M, C qd,
    g (:func:`loop_terms`) for cond(M) and accel_scale, its pins (:func:`loop_constraint`). The tip is link 2's COM,
    a free body's centre of mass: a force there only translates it, so Lambda = m2 I (cond 1)."""
    m1, m2, l1, l2, g = p["m1"], p["m2"], p["l1"], p["l2"], p["g"]
    th, thd = loop_to_joint(q), loop_to_joint(qd)
    Mj, Cj, gj = pendulum_terms(th, thd, m1, m2, l1, l2, g)
    Mj = Mj + disk_inertia(p["I1"], p["I2"])
    joint = Terms(Mj, inv2(Mj), Cj, gj, u, m1 + m2, abs(g))
    drift_j, ctrl_j, total_j = joint.accelerations()
    M, Cqd, grav = loop_terms(q, qd, m1, m2, l1, l2, g, p["I1"], p["I2"])
    t = Terms(M, np.linalg.inv(M), Cqd, grav, np.array([0.0, 0.0, u[0] - u[1], 0.0, 0.0, u[1]]), m1 + m2, abs(g))
    phi, Jc, bias = loop_constraint(q, qd, l1)
    lam, lam_drift = (np.concatenate(pin_forces(th, thd, a, m1, m2, l1, l2, g)) for a in (total_j, drift_j))
    tip = endpoint_jacobian(th, l1, l2) @ drift_j + tip_bias(th, thd, l1, l2)
    return assemble(t, qd, joint_to_loop(th, thd, drift_j, l1), joint_to_loop(th, np.zeros(2), ctrl_j, l1),
                     joint_to_loop(th, thd, total_j, l1), (tip, m2 * np.eye(2), 1.0),
                     Kkt(phi, Jc, bias, lam, lam_drift, absolute_loop_rule(p)))


def four_bar(p, q, qd, u) -> Split:
    """The open tree's M, C qd, g (:func:`four_bar_terms`), the loop (:func:`four_bar_loop`), eqs. (12)-(17) under
    the backends' rule (:func:`~crosscheck.references.closed_forms.assembly.constrained_solution`: minimum-norm
    multipliers at the change points), the task point ``coupler_mid`` by :func:`link_point` (eqs. 23, 22 with the open
    tree's M)."""
    a, b, c, m, g = p["crank"], p["coupler"], p["rocker"], p["m"], p["g"]
    M, Cqd, grav = four_bar_terms(q, qd, a, b, c, m, g)
    t = Terms(M, np.linalg.inv(M), Cqd, grav, u, 3.0 * m, abs(g))
    drift, ctrl, total, kkt = constrained_solution(t, *four_bar_loop(q, qd, a, b, c, p["ground"]), four_bar_rule(p))
    J, bias = link_point(q, qd, a, b / 2.0)
    return assemble(t, qd, drift, ctrl, total, task_terms(J, bias, drift, task_inertia(J, t.Minv)), kkt)


def slider_crank(p, q, qd, u) -> Split:
    """The open tree's M, C qd, g (:func:`slider_crank_terms`), the wrist pin (:func:`wrist_pin`), eqs. (12)-(17)
    (:func:`~crosscheck.references.closed_forms.assembly.constrained_solution`); the task is the slider's x: J = (0, 0,
    1), Jdot qd = 0, Lambda = 1 / (M^-1)_33 =
    m_slider (M is block-diagonal), cond 1."""
    a, r, e = p["crank"], p["rod"], p["offset"]
    ms = p["m_slider"]
    M, Cqd, grav = slider_crank_terms(q, qd, a, r, p["m_crank"], p["m_rod"], ms, p["g"])
    t = Terms(M, np.linalg.inv(M), Cqd, grav, u, p["m_crank"] + p["m_rod"] + ms, abs(p["g"]))
    drift, ctrl, total, kkt = constrained_solution(t, *wrist_pin(q, qd, a, r, e), slider_crank_rule(p))
    J = np.array([[0.0, 0.0, 1.0]])
    return assemble(t, qd, drift, ctrl, total, task_terms(J, np.zeros(1), drift, task_inertia(J, t.Minv)), kkt)


def double_pendulum_rail(p, q, qd, u) -> Split:
    """Eqs. (6)-(8), the rail row (:func:`rail_terms`), eqs. (12)-(17) (:func:`~crosscheck.references.closed_forms.assembly.constrained_solution`), the tip by
    eqs. (4), (5)."""
    l1, l2 = p["l1"], p["l2"]
    M, Cqd, grav = pendulum_terms(q, qd, p["m1"], p["m2"], l1, l2, p["g"])
    t = Terms(M, inv2(M), Cqd, grav, u, p["m1"] + p["m2"], abs(p["g"]))
    drift, ctrl, total, kkt = constrained_solution(t, *rail_terms(q, qd, l1, l2, p["x0"], p["y0"], p["incline"]),
                                           double_pendulum_rule(p))
    J = endpoint_jacobian(q, l1, l2)
    return assemble(t, qd, drift, ctrl, total, task_terms(J, tip_bias(q, qd, l1, l2), drift, task_inertia_square(J, M)),
                     kkt)


def geared_pendulums(p, q, qd, u) -> Split:
    """Two rods (:func:`gear_terms`, M diagonal) coupled by the gear (:func:`gear_constraint`), eqs. (12)-(17)
    (:func:`~crosscheck.references.closed_forms.assembly.constrained_solution`: with ``S = 1 / M11 + ratio^2 / M22`` the
    gear's torque is ``lam = (ratio (M^-1 f)_2 -
    (M^-1 f)_1) / S``); the task is the pinion rod's end along x: ``J = (l1 cos q1, 0)``, ``Jdot qd = -l1 sin q1
    q1d^2`` (:func:`chain_tip` of one link)."""
    m1, l1, m2, l2 = p["m1"], p["l1"], p["m2"], p["l2"]
    M, Cqd, grav = gear_terms(q, qd, m1, l1, m2, l2, p["g"])
    t = Terms(M, np.diag(1.0 / np.diag(M)), Cqd, grav, u, m1 + m2, abs(p["g"]))
    drift, ctrl, total, kkt = constrained_solution(t, *gear_constraint(q, p["ratio"], p["offset"]), gear_rule(p))
    J, bias = chain_tip(q[:1], qd[:1], (l1,))
    J = np.array([[J[0, 0], 0.0]])
    return assemble(t, qd, drift, ctrl, total, task_terms(J, bias[:1], drift, task_inertia(J, t.Minv)), kkt)


def _one_joint(M, Cqd, grav, J, bias, u, qd, mass, g) -> Split:
    """A 1-degree-of-freedom case from its (1x1) terms: eq. (9) with M^-1 = 1 / M, the task of eq. (23) and (22)."""
    t = Terms(M, 1.0 / M, Cqd, grav, u, mass, abs(g))
    drift, ctrl, total = t.accelerations()
    return assemble(t, qd, drift, ctrl, total, task_terms(J, bias, drift, task_inertia(J, t.Minv)))


def rotor(p, q, qd, u) -> Split:
    """:func:`rotor_terms`."""
    keys = ("m", "cx", "cy", "cz", "Ia", "Ib", "Ic", "spin", "tilt", "azimuth", "g")
    return _one_joint(*rotor_terms(q, qd, *(p[k] for k in keys)), u, qd, p["m"], p["g"])


def inclined_slider(p, q, qd, u) -> Split:
    """:func:`slider_terms`."""
    return _one_joint(*slider_terms(p["m"], p["incline"], p["g"]), u, qd, p["m"], p["g"])


def spherical_pendulum(p, q, qd, u) -> Split:
    """:func:`spherical_terms`, eq. (9) with the diagonal M's inverse, the ball's task by eqs. (23), (22)."""
    M, Cqd, grav, J, bias = spherical_terms(q, qd, p["m"], p["l"], p["Ix"], p["Iy"], p["Iz"], p["g"])
    t = Terms(M, np.diag(1.0 / np.diag(M)), Cqd, grav, u, p["m"], abs(p["g"]))
    drift, ctrl, total = t.accelerations()
    return assemble(t, qd, drift, ctrl, total, task_terms(J, bias, drift, task_inertia_square(J, M)))


def free_body(p, q, qd, u) -> Split:
    """:func:`free_body_terms`; eq. (9) with M^-1 from numpy (6 x 6), the marker's task by eqs. (23), (22)."""
    M, Cqd, grav, J, bias = free_body_terms(q, qd, p["m"], p["I1"], p["I2"], p["I3"], p["g"])
    t = Terms(M, np.linalg.inv(M), Cqd, grav, u, p["m"], abs(p["g"]))
    drift, ctrl, total = t.accelerations()
    A = J @ t.Minv @ J.T
    cond = condition(A)
    Lambda = np.linalg.inv(A) if np.isfinite(cond) else np.full((3, 3), np.nan)
    return assemble(t, qd, drift, ctrl, total, task_terms(J, bias, drift, (Lambda, cond)))


def sleigh_rule(p) -> Rule:
    """The sleigh: its COM ``a`` from the origin, inertia diag(I/2, I/2, I) of trace 2 I; the carriages massless."""
    return Rule.of((p["m"], abs(p["a"]), 2.0 * p["I"]))


def knife_edge(p, q, qd, u) -> Split:
    """:func:`sleigh_terms` and :func:`sleigh_motion` (total with ``B u = u``, drift with 0; ctrl = B_c u, eq. 17, by
    :func:`constrained_input_map`); the task point ``com`` at ``P + a e1``: ``J = [[1, 0, -a s], [0, 1, a c]]``,
    ``Jdot qd = -a thd^2 e1``."""
    m, a, I = p["m"], p["a"], p["I"]  # noqa: E741
    M, Cqd, Jc, bias = sleigh_terms(q, qd, m, a, I)
    t = Terms(M, np.linalg.inv(M), Cqd, np.zeros(3), u, m, abs(p["g"]))
    total, lam = sleigh_motion(q, qd, u, m, a, I)
    drift, lam_drift = sleigh_motion(q, qd, np.zeros(3), m, a, I)
    s, c = np.sin(q[2]), np.cos(q[2])
    J = np.array([[1.0, 0.0, -a * s], [0.0, 1.0, a * c]])
    task_bias = -a * qd[2] ** 2 * np.array([c, s])
    return assemble(t, qd, drift, constrained_input_map(M, Jc) @ u, total,
                     task_terms(J, task_bias, drift, task_inertia(J, t.Minv)),
                     Kkt(np.zeros(1), Jc, bias, np.array([lam]), np.array([lam_drift]), sleigh_rule(p)))


def disk_rule(p) -> Rule:
    """The disk: its centre r from the lean frame (translation (0, 0, r), COM at its origin), inertia
    ``m r^2 diag(1/4, 1/2, 1/4)`` of trace ``m r^2``; the carriages, heading and lean frames massless."""
    return Rule.of((p["m"], p["r"], p["m"] * p["r"] ** 2))


def rolling_disk(p, q, qd, u) -> Split:
    """:func:`disk_terms` (B = I), eqs. (12)-(17) under the backends' rule
    (:func:`~crosscheck.references.closed_forms.assembly.constrained_solution`; S = A M^-1 A^T has
    full rank: A's two rows are independent everywhere), the task point ``center`` by :func:`disk_center` (eqs. 23, 22
    with the unconstrained M, a 3 x 3 task: singular where the disk stands upright, phi = 0, since the centre's height
    is then stationary)."""
    m, r = p["m"], p["r"]
    M, Cqd, grav, A, bias = disk_terms(q, qd, m, r, p["g"])
    t = Terms(M, np.linalg.inv(M), Cqd, grav, u, m, abs(p["g"]))
    drift, ctrl, total, kkt = constrained_solution(t, np.zeros(2), A, bias, disk_rule(p))
    J, task_bias = disk_center(q, qd, r)
    return assemble(t, qd, drift, ctrl, total, task_terms(J, task_bias, drift, task_inertia(J, t.Minv)), kkt)


def drive_rule(p) -> Rule:
    """The drive: the chassis (COM at ``(com_ahead, 0, r)``, trace ``m_body (4 track^2 + 2 r^2) / 12``), two wheels at
    ``(0, +-track/2, r)`` of trace ``m_w r^2``; the carriages massless."""
    r, half = p["r"], p["track"] / 2.0
    return Rule.of((p["m_body"], float(np.hypot(p["com_ahead"], r)), p["m_body"] * (4.0 * p["track"] ** 2 + 2.0 * r * r)
                    / 12.0), *[(p["m_wheel"], float(np.hypot(half, r)), p["m_wheel"] * r * r)] * 2)


def differential_drive(p, q, qd, u) -> Split:
    """:func:`drive_terms`, :func:`drive_load` and :func:`drive_motion` (total with u, drift with 0, the load in both;
    ctrl = B_c B u, eq. 17, by :func:`constrained_input_map`); the task point ``front`` at ``P + f e1``, ``f =
    com_ahead + 0.1``: ``J = [[1, 0, -f s, 0, 0], [0, 1, f c, 0, 0]]``, ``Jdot qd = -f hd^2 e1``."""
    shape = (p["m_body"], p["m_wheel"], p["r"], p["track"], p["com_ahead"])
    M, Cqd, Jc, bias = drive_terms(q, qd, *shape)
    tau_ext = drive_load(q, p["drag"], p["g"], p["payload"])
    B = np.zeros((5, 2))
    B[3, 0] = B[4, 1] = 1.0
    t = Terms(M, np.linalg.inv(M), Cqd, -tau_ext, B @ u, p["m_body"] + 2.0 * p["m_wheel"], abs(p["g"]), tau_ext)
    total, lam = drive_motion(q, qd, u, tau_ext, *shape)
    drift, lam_drift = drive_motion(q, qd, np.zeros(2), tau_ext, *shape)
    s, c = np.sin(q[2]), np.cos(q[2])
    f = p["com_ahead"] + 0.1
    J = np.array([[1.0, 0.0, -f * s, 0.0, 0.0], [0.0, 1.0, f * c, 0.0, 0.0]])
    return assemble(t, qd, drift, constrained_input_map(M, Jc) @ (B @ u), total,
                     task_terms(J, -f * qd[2] ** 2 * np.array([c, s]), drift, task_inertia(J, t.Minv)),
                     Kkt(np.zeros(3), Jc, bias, lam, lam_drift, drive_rule(p)))
