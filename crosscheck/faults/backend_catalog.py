"""The fault catalog: realistic bugs in each backend's own computation, the kind dynamics code gets wrong, each
injected by replacing one function or method (``crosscheck.faults.injection``).

Every entry changes its backend's output at some state of the default gate, and the gate catches it, except the
entries with a ``gap`` note: realistic faults the gate misses, kept to document its blind spots (the note says
why, and which check would catch them; none at present: the last two, joint reactions at the wrong acceleration and
an uninverted task-space inertia, are caught since the gate compares ``joint_wrenches`` and ``task_inertia``);
``tests/faults/test_faults.py`` checks all of this. A replacement is built from the original: most wrap it and alter an
argument or the result, so the fault is exactly the bug described.
"""

from __future__ import annotations

import dataclasses

import numpy as np

from crosscheck.faults.injection import Fault, FaultError

EL, NE, SCREW, OSC, GEO = "euler_lagrange", "newton_euler", "screw", "operational_space", "geometric"


# ------------------------------------------------------------------------------------------- Euler–Lagrange


def _kinetic_energy_doubled(energies):
    def faulty(model, st, poses, motions=None):
        T, V = energies(model, st, poses, motions)
        return 2 * T, V
    return faulty


def _lagrange_dT_dq_sign(velocity_product):
    """Lagrange's equation with the sign of ``dT/dq`` flipped: ``C qd = d/dt (dT/dqd) + dT/dq``."""
    return lambda st, T, momentum, i: st.dt(momentum) + st.diff(T, i)


def _com_unrotated(com):
    import symengine

    return lambda R, p, offset: com(symengine.eye(3), p, offset)


def _chart_jacobian_constant(rate_of):
    """``_Staged._rate_of`` returning 0 for the time derivative of the joint rates ``qd_k = Dpsi_k pd`` (the named
    rates of the named ``q_k = psi_k(p)``), as if Dpsi were constant along the motion."""
    import symengine

    def faulty(self, s):
        rates = self.__dict__.setdefault("fault_joint_rates", set())  # this derivation's qd_k, as they appear
        if s in rates:
            return symengine.Integer(0)
        rate = rate_of(self, s)
        if s in self.joint and not rate.is_Number:
            rates.add(rate)
        return rate
    return faulty


EULER_LAGRANGE = [
    Fault("el-kinetic-energy-missing-half", EL,
          "The kinetic energy is written without its 1/2 (T = m |c_dot|^2 + w^T I w), which doubles M and C qd "
          "but not gravity.",
          "formalisms.euler_lagrange:_energies", _kinetic_energy_doubled, derived=True),
    Fault("el-rotational-energy-com-inertia", EL,
          "The rotational energy 1/2 tr(R_dot J R_dot^T) uses the COM inertia I in place of the pseudo-inertia "
          "J = 1/2 tr(I) 1 - I.",
          "formalisms.euler_lagrange:_pseudo_inertia", lambda f: lambda inertia: np.array(inertia, dtype=float),
          derived=True),
    Fault("el-lagrange-dtdq-sign", EL,
          "Lagrange's equation with the sign of dT/dq flipped: C qd = d/dt (dT/dqd) + dT/dq instead of "
          "d/dt (dT/dqd) - dT/dq.",
          "formalisms.euler_lagrange:_velocity_product", _lagrange_dT_dq_sign, derived=True),
    Fault("el-com-offset-unrotated", EL,
          "The COM offset is added in the world frame (c = p + com) instead of being rotated with the body "
          "(c = p + R com).",
          "formalisms.euler_lagrange:_com", _com_unrotated, derived=True),
    Fault("el-chart-jacobian-constant", EL,
          "In a chart q = psi(p) the time derivative of the joint rates qd = Dpsi pd treats Dpsi as constant, so the "
          "(d/dt Dpsi) pd terms drop out of the chart's C_p pd (and of Jcdot pd).",
          "formalisms.euler_lagrange:_Staged._rate_of", _chart_jacobian_constant, derived=True),
    Fault("el-constrained-drift-with-input", EL,
          "The constrained drift (ZTCF) and lam_drift are solved with the input applied: the u = 0 right-hand "
          "side of the KKT system is B u - h.",
          "formalisms.euler_lagrange:_kkt", lambda f: lambda sc, forces, bias: f(sc, forces[:, [0, 0]], bias)),
    Fault("el-input-map-unprojected", EL,
          "The constrained ctrl uses the free input map M^-1 B u: the projector I - Jc^T S^+ Jc M^-1 of eq. (17) "
          "is dropped.",
          "formalisms.euler_lagrange:_constrained_input_map",
          lambda f: lambda sc: f(sc._replace(V=sc.V[:, :0], w=sc.w[:0]))),
]


# ------------------------------------------------------------------------------------------- Newton–Euler


def _prismatic_axis_in_parent_frame(placements):
    def faulty(model, q):
        P, r, W = placements(model, q)
        for i, body in enumerate(model.bodies):
            if body.joint == "prismatic":
                r[i] = body.translation + q[model.q_index[i]] * body.axis
        return P, r, W
    return faulty


def _armature_dropped(mass_matrix):
    """``M`` of the backward passes alone: the joints' rotors (``Body.armature``) left off its diagonal."""
    def faulty(model, kin, units):
        bare = tuple(dataclasses.replace(b, armature=0.0) for b in model.bodies)
        return mass_matrix(dataclasses.replace(model, bodies=bare), kin, units)
    return faulty


def _negated_multipliers(solve):
    def faulty(self, force):
        qdd, lam = solve(self, force)
        return qdd, -lam
    return faulty


def _without_bias(rows):
    def faulty(*args):
        return [dataclasses.replace(r, bias=np.zeros_like(r.bias)) for r in rows(*args)]
    return faulty


def _cross3(a, b):
    """``a x b`` of 3-vectors (component-first, as the Newton–Euler backend's arrays)."""
    return np.array([a[1] * b[2] - a[2] * b[1], a[2] * b[0] - a[0] * b[2], a[0] * b[1] - a[1] * b[0]])


def _pfaffian_bias_dropped(terms):
    """The screw backend's constraint terms with ``Adot qd`` zeroed on the Pfaffian rows (``A qdd = 0``)."""
    def faulty(kin, q, qd):
        t = terms(kin, q, qd)
        return dataclasses.replace(t, bias=np.where(kin.model.pfaffian_rows, 0.0, t.bias))
    return faulty


def _loads_with_transposed_rotation(loads):
    return lambda model, kin, rows, lam: loads(model, (kin[0], kin[1], [W.T for W in kin[2]]), rows, lam)


def _world_loads_as_body(external_loads):
    """The external loads' world-frame forces and couples read as body-frame vectors (not turned by W^T)."""
    def faulty(model, kin):
        as_body = tuple(dataclasses.replace(x, frame="body") if hasattr(x, "frame") else x for x in model.loads)
        return external_loads(dataclasses.replace(model, loads=as_body), kin)
    return faulty


def _moment_shift_reversed(moment_about_origin):
    from formalisms.newton_euler import _cross

    return lambda offset, f, couple: couple + _cross(f, offset)


def _rolling_direction_fixed(turn):
    """``_rolling_turn`` with ``tdot = 0``: the rolling direction as if it did not turn with the axle. At an admissible
    state of the differential drive the contact's material point is at rest (v_pc = 0), so the split is unchanged;
    the linearization is not (``d(tdot . v_pc)/dqd = tdot^T J_pc``, with ``tdot = hd e2``)."""
    def faulty(b, b_dot):
        t, size, t_dot = turn(b, b_dot)
        return t, size, np.zeros_like(t_dot)
    return faulty


NEWTON_EULER = [
    Fault("ne-gyroscopic-dropped", NE,
          "Euler's equation (19) misses the gyroscopic moment w x (I w).",
          "formalisms.newton_euler:_gyroscopic", lambda f: lambda inertia, w: np.zeros(3)),
    Fault("ne-gravity-transposed-rotation", NE,
          "Gravity is brought into the body frame with W instead of W^T (the world <- body rotation not "
          "transposed).",
          "formalisms.newton_euler:_body_gravity", lambda f: lambda W, gravity: W @ gravity),
    Fault("ne-com-centripetal-dropped", NE,
          "The COM acceleration misses the centripetal term: a_c = a + wd x c without w x (w x c).",
          "formalisms.newton_euler:_com_acceleration",
          lambda f: lambda a, wd, w, com: f(a, wd, np.zeros(3), com)),
    Fault("ne-prismatic-axis-parent-frame", NE,
          "A prismatic joint slides along its axis taken in the parent's frame (q axis) instead of the joint "
          "frame (q rotation axis), in the placements only.",
          "formalisms.newton_euler:_placements", _prismatic_axis_in_parent_frame),
    Fault("ne-multiplier-sign", NE,
          "The multipliers are returned with the opposite sign convention (M qdd + h = B u - Jc^T lam).",
          "formalisms.newton_euler:_RangeSpace.solve", _negated_multipliers),
    Fault("ne-constraint-bias-dropped", NE,
          "Jcdot qd is dropped from the constraint acceleration equation (Jc qdd = 0 instead of -Jcdot qd).",
          "formalisms.newton_euler:_constraint_rows", _without_bias),
    Fault("ne-reactions-at-drift-acceleration", NE,
          "The joint reactions reported at the total acceleration are computed from the drift's forward pass (the "
          "motion at u = 0 reused).",
          "formalisms.newton_euler:_extras",
          lambda f: lambda model, kin, qd, total, drift, loads=None, loads_drift=None: f(
              model, kin, qd, drift, drift, loads, loads_drift)),
    Fault("ne-rolling-contact-body-fixed", NE,
          "The rolling contact point is taken as fixed in the disk in Adot qd (udot = w x u): the bias is T times "
          "the classical acceleration of a body-fixed point, not of the point that follows the contact.",
          "formalisms.newton_euler:_contact_rate",
          lambda f: lambda w, a, n, u, length: _cross3(w, u)),
    Fault("ne-rolling-direction-fixed", NE,
          "A rolling-direction row (RollingContact lateral=False) takes its direction t as fixed along the motion: "
          "tdot = 0, so Adot qd lacks tdot . v_pc.",
          "formalisms.newton_euler:_rolling_turn", _rolling_direction_fixed),
    Fault("ne-constraint-force-wrong-frame", NE,
          "The constraint forces are rotated into the body frames with W instead of W^T before the backward pass "
          "(the joint reactions carry them in the wrong frame).",
          "formalisms.newton_euler:_constraint_loads", _loads_with_transposed_rotation),
    Fault("ne-external-force-world-as-body", NE,
          "A world-frame external force (or couple) is applied in the backward pass as if it were given in the body "
          "frame: the rotation W^T into body frame i is left out.",
          "formalisms.newton_euler:_external_loads", _world_loads_as_body),
    Fault("ne-armature-dropped", NE,
          "M is built from the links alone: each joint's armature (a rotor's inertia, MuJoCo's <joint armature>) is "
          "left off its diagonal, so the rotor's torque a qdd is missing.",
          "formalisms.newton_euler:_mass_matrix", _armature_dropped),
    Fault("ne-external-moment-shift-sign", NE,
          "The moment about the body origin of an external force at a body point is taken as f x offset, the lever "
          "crossed the wrong way round.",
          "formalisms.newton_euler:_moment_about_origin", _moment_shift_reversed),
]


# ------------------------------------------------------------------------------------------- screw


def _com_inertia_at_origin(spatial_inertias):
    from formalisms.screw import lie

    def faulty(model):
        G = spatial_inertias(model)
        mass = np.array([b.mass for b in model.bodies])[:, None, None]
        C = lie.hat3(np.array([b.com for b in model.bodies]))
        G[:, :3, :3] += mass * (C @ C)                      # back to I_c: the -m [c][c] term removed
        return G
    return faulty


def _point_jacobian_from_body_jacobian(point_jacobian):
    from formalisms.screw import kinematics, lie

    def faulty(kin, body, p):
        Jb = kinematics.body_jacobian(kin, body)
        return Jb[3:] - lie.hat3(p) @ Jb[:3]
    return faulty


def _moment_not_shifted(about_origin):
    return lambda offset, f, couple: about_origin(np.zeros_like(offset), f, couple)


SCREW = [
    Fault("screw-pfaffian-bias-dropped", SCREW,
          "Adot qd is dropped for the Pfaffian rows (A qdd = 0 instead of -Adot qd: a knife edge's or a rolling "
          "contact's rows differentiated as if A were constant).",
          "formalisms.screw.constraints:terms", _pfaffian_bias_dropped),
    Fault("screw-coadjoint-dropped", SCREW,
          "The wrench balance (27) misses the coadjoint term ad_V^T (G V) (gyroscopic and velocity-product "
          "wrenches).",
          "formalisms.screw.lie:coad", lambda f: lambda V, F: np.zeros(np.broadcast_shapes(V.shape, F.shape))),
    Fault("screw-coadjoint-sign", SCREW,
          "ad*_V = -ad_V^T is confused with ad_V^T: the coadjoint term enters eq. (27) with the wrong sign.",
          "formalisms.screw.lie:coad", lambda f: lambda V, F: -f(V, F)),
    Fault("screw-wrench-mapped-as-twist", SCREW,
          "A child's wrench is carried to the parent by Ad (the twist map) instead of Ad^-T.",
          "formalisms.screw.dynamics:_wrench_to_parent", lambda f: lambda Ad, F: (Ad @ F[..., None])[..., 0]),
    Fault("screw-parallel-axis-dropped", SCREW,
          "The spatial inertia about the body origin keeps the COM inertia in its rotational block (the "
          "parallel-axis term -m [c][c] is missing).",
          "formalisms.screw.dynamics:spatial_inertias", _com_inertia_at_origin),
    Fault("screw-spatial-point-acceleration", SCREW,
          "A point's acceleration is taken from the spatial acceleration vd + wd x p, without w x pdot "
          "(spatial, not classical: task drift and Jcdot qd).",
          "formalisms.screw.kinematics:classical_acceleration",
          lambda f: lambda V, Vdot, p: f(np.zeros_like(V), Vdot, p)),
    Fault("screw-gravity-sign", SCREW,
          "The gravity wrench has the wrong sign (the weight pulls up).",
          "formalisms.screw.dynamics:gravity_wrenches", lambda f: lambda model, kin: -f(model, kin)),
    Fault("screw-point-jacobian-body-frame", SCREW,
          "A constrained point's Jacobian is built from the body Jacobian J_b with the point's world position "
          "(body and space frames mixed).",
          "formalisms.screw.kinematics:point_jacobian", _point_jacobian_from_body_jacobian),
    Fault("screw-external-moment-not-shifted", SCREW,
          "An external force at a body point enters eq. (27) as the body wrench (0, f): its moment offset x f about "
          "the body origin is left out (the wrench taken about the point of application).",
          "formalisms.screw.dynamics:about_origin", _moment_not_shifted),
]


# ------------------------------------------------------------------------------------------- operational space


def _task_bias_dropped(task_kinematics):
    def faulty(model, kin, point):
        J, bias = task_kinematics(model, kin, point)
        return J, np.zeros_like(bias)
    return faulty


def _lambda_reported_uninverted(task_space):
    def faulty(*args):
        principal, reported = task_space(*args)
        return principal, dataclasses.replace(reported, Lambda=reported.A)
    return faulty


OPERATIONAL_SPACE = [
    Fault("osc-gyroscopic-dropped", OSC,
          "The projected C qd misses the gyroscopic moments w x (I w).",
          "formalisms.operational_space:_gyroscopic", lambda f: lambda inertia, w: np.zeros_like(w)),
    Fault("osc-inertia-transposed-rotation", OSC,
          "The COM inertias are rotated to the world as R^T I R instead of R I R^T.",
          "formalisms.operational_space:_world_inertia", lambda f: lambda R, inertia: f(R.transpose(0, 2, 1), inertia)),
    Fault("osc-inertia-axes-swapped", OSC,
          "The body inertia tensors are read with their x and z axes swapped.",
          "formalisms.operational_space:_world_inertia", lambda f: lambda R, inertia: f(R, inertia[:, ::-1, ::-1])),
    Fault("osc-spatial-point-bias", OSC,
          "Point bias accelerations Jdot qd hold the point fixed in the world (its velocity dropped): spatial, "
          "not classical accelerations, for the COMs and the task point.",
          "formalisms.operational_space:point_bias",
          lambda f: lambda kin, body, points, velocities: f(kin, body, points, np.zeros_like(velocities))),
    Fault("osc-task-bias-dropped", OSC,
          "The task acceleration misses Jdot qd: the task drift is taken as J qdd_drift.",
          "formalisms.operational_space:_task_kinematics", _task_bias_dropped),
    Fault("osc-null-space-untransposed", OSC,
          "The null-space part of the recomposition uses N instead of N^T (M^-1 N (tau - h)).",
          "formalisms.operational_space:_recompose",
          lambda f: lambda ts, Minv, h, tau, tau_c: f(dataclasses.replace(ts, N=ts.N.T), Minv, h, tau, tau_c)),
    Fault("osc-lever-arm-from-world-origin", OSC,
          "Revolute Jacobian columns take the lever arm from the world origin (z_j x p) instead of from the joint "
          "origin (z_j x (p - o_j)).",
          "formalisms.operational_space:_linear_columns",
          lambda f: lambda z, o, revolute, moves, points: f(z, np.zeros_like(o), revolute, moves, points)),
    Fault("osc-support-transposed", OSC,
          "The support mask is transposed: body i's Jacobian gets the columns of its descendants instead of its "
          "ancestors.",
          "formalisms.operational_space:_moves", lambda f: lambda model: f(model).T),
    Fault("osc-lambda-reported-uninverted", OSC,
          "The reported task-space inertia is A = J M^-1 J^T instead of Lambda = A^-1 (extras['task'], "
          "task_space()).",
          "formalisms.operational_space:_task_space", _lambda_reported_uninverted),
    Fault("osc-constraint-inertia-with-m", OSC,
          "The constraint-space inertia is formed with M in place of M^-1: Lambda_c = (Jc M Jc^T)^+.",
          "formalisms.operational_space:_constraint_inertia",
          lambda f: lambda model, Jc, Minv: f(model, Jc, np.linalg.inv(Minv))),
]


# ------------------------------------------------------------------------------------------- geometric


def _christoffel_first_kind_sign_on_wrong_term(first_kind):
    # correct: 1/2 (d_j M_lk + d_k M_lj - d_l M_jk); faulty: 1/2 (d_k M_lj + d_l M_jk - d_j M_lk)
    return lambda dM: 0.5 * (dM.transpose(1, 2, 0) + dM - dM.transpose(1, 0, 2))


def _point_offset_unrotated(point):
    import casadi

    return lambda model, R, o, body, offset: point(model, [casadi.DM.eye(3)] * len(R), o, body, offset)


def _knife_edge_world_fixed(rates):
    """The geometric backend's knife edge with its body-frame direction used as a world direction (not turned by R)."""
    def faulty(model, c, R, o, p, pd, world):
        if type(c).__name__ != "KnifeEdge":
            return rates(model, c, R, o, p, pd, world)
        import casadi

        from formalisms import geometric

        return casadi.dot(casadi.DM(c.direction), casadi.jtimes(geometric._point(model, R, o, c.body, c.offset), p, pd))
    return faulty


def _task_bias_dropped_geometric(evaluate):
    def faulty(model, chart, p, pd):
        point = evaluate(model, chart, p, pd)
        return dataclasses.replace(point, Jdot_pd=np.zeros_like(point.Jdot_pd))
    return faulty


def _ctrl_unprojected(constrained_split):
    def faulty(model, chart, pt, p, pd, tau):
        split = constrained_split(model, chart, pt, p, pd, tau)
        return dataclasses.replace(split, ctrl=np.linalg.solve(pt.M, tau))
    return faulty


def _casadi_vector(v):
    import casadi

    return casadi.DM(v)


GEOMETRIC = [
    Fault("geo-christoffel-index-order", GEO,
          "The Christoffel symbols of the first kind have the minus sign on the wrong term: "
          "Gamma_l,jk = 1/2 (d_k M_lj + d_l M_jk - d_j M_lk).",
          "formalisms.geometric:christoffel_first_kind", _christoffel_first_kind_sign_on_wrong_term),
    Fault("geo-point-offset-unrotated", GEO,
          "A body point (the task point, a constrained point) is placed at o_b + offset, its offset not rotated "
          "with the body.",
          "formalisms.geometric:_point", _point_offset_unrotated, derived=True),
    Fault("geo-knife-edge-direction-world-fixed", GEO,
          "A knife edge's direction, fixed in the body, is used as a world direction (not turned by the body's "
          "rotation): the Pfaffian row (R d) . v becomes d . v.",
          "formalisms.geometric:_pfaffian_rates", _knife_edge_world_fixed, derived=True),
    Fault("geo-task-bias-dropped", GEO,
          "The task drift misses Jdot pd (taken as J pdd_drift).",
          "formalisms.geometric:_evaluate", _task_bias_dropped_geometric),
    Fault("geo-ctrl-unprojected", GEO,
          "The constrained ctrl is the free M^-1 tau, not projected onto the constraint distribution "
          "(eq. 17 ignored).",
          "formalisms.geometric:_constrained_split", _ctrl_unprojected),
    Fault("geo-multiplier-sign", GEO,
          "The multipliers are solved from Jc^T lam = f - M pdd (eq. 12's sign convention reversed).",
          "formalisms.geometric:_Distribution.solve_transposed", lambda f: lambda self, c: -f(self, c)),
    Fault("geo-euclidean-projection", GEO,
          "The free motion is projected onto H_t in the Euclidean metric (Z^T Z) instead of the kinetic-energy "
          "metric (Z^T M Z).",
          "formalisms.geometric:_reduced_metric_factor",
          lambda f: lambda model, chart, M, Z, p: f(model, chart, np.eye(len(M)), Z, p)),
    Fault("geo-external-body-force-unturned", GEO,
          "A body-frame external force (or couple) enters the virtual power as a world vector: the body's rotation R "
          "is left out.",
          "formalisms.geometric:_in_world",
          lambda f: lambda load, R, world, field: f(load, R, world, field) if load.frame == "world"
          else _casadi_vector(getattr(load, field)), derived=True),
]


# ------------------------------------------------------------------------ Lie groups: spherical and free joints


def _quaternion_read_as_wxyz(axis: int):
    """A rotation-from-quaternion function fed a stored ``(x, y, z, w)`` read as ``(w, x, y, z)``: the function then
    sees ``(x, y, z, w) = (y, z, w, x)`` of the stored components."""
    return lambda f: lambda quat, *rest: f(np.roll(quat, -1, axis=axis), *rest)


def _twist_rate_as_position_acceleration(group_motion):
    """Newton–Euler's free-joint step with ``d/dt v_lin`` taken as the body-frame second derivative of the position,
    without the ``(w_in + w) x v_lin`` of a turning frame."""
    def faulty(joint, w_in, wd_in, a_origin, v, vd):
        w, wd, a = group_motion(joint, w_in, wd_in, a_origin, v, vd)
        if joint == "free":
            a = a - np.array([(w_in + w)[1] * v[2] - (w_in + w)[2] * v[1], (w_in + w)[2] * v[0] - (w_in + w)[0] * v[2],
                              (w_in + w)[0] * v[1] - (w_in + w)[1] * v[0]])
        return w, wd, a
    return faulty


def _free_twist_order_swapped(screws):
    """The screw description with each free joint's unit twists for its velocity block read as (angular, linear)
    instead of (linear, angular)."""
    def faulty(model):
        sc = screws(model)
        twists = np.array(sc.unit_twists)
        for i in model.group_joints:
            if model.bodies[i].joint == "free":
                block = slice(model.v_index[i], model.v_index[i] + 6)
                twists[block] = np.roll(twists[block], 3, axis=0)
        return dataclasses.replace(sc, unit_twists=twists)
    return faulty


GROUP = [
    Fault("ne-quaternion-read-wxyz", NE,
          "The quaternion of a spherical or free joint is read in the (w, x, y, z) order of some libraries (Eigen's "
          "constructor, MuJoCo) instead of the stored (x, y, z, w).",
          "formalisms.newton_euler:_quaternion_rotation", _quaternion_read_as_wxyz(0)),
    Fault("ne-free-twist-rate-as-position-acceleration", NE,
          "A free joint's acceleration is used as the body-frame second derivative of its position: d/dt of the "
          "body twist misses (w_in + w) x v_lin (world and body base velocity confused).",
          "formalisms.newton_euler:_group_motion", _twist_rate_as_position_acceleration),
    Fault("screw-quaternion-conjugated", "screw",   # (SCREW is the list of screw faults by now)
          "The rotation of a quaternion is built as its inverse R^T (the passive, frame-rotation convention mixed "
          "with the active one).",
          "formalisms.screw.lie:quaternion_rotation", lambda f: lambda quat: np.swapaxes(f(quat), -1, -2)),
    Fault("screw-free-twist-order-swapped", "screw",
          "A free joint's velocity block is taken as (angular, linear), the order of the (w, v) twists, instead of "
          "Pinocchio's (linear, angular).",
          "formalisms.screw.kinematics:screws", _free_twist_order_swapped),
    Fault("osc-quaternion-read-wxyz", OSC,
          "The quaternion of a spherical or free joint is read in the (w, x, y, z) order instead of (x, y, z, w).",
          "formalisms.operational_space:_quaternion_rotations", _quaternion_read_as_wxyz(-1)),
    Fault("el-exponential-first-order", EL,
          "The local exponential chart around the state is cut to exp(X) = I + X, so dexp is taken as the identity "
          "near the state and the velocity products of the group joints lose their 1/2 ad term.",
          "formalisms.euler_lagrange:_exp_series", lambda f: lambda X, order: f(X, 1), derived=True),
    Fault("el-quaternion-transposed", EL,
          "The rotation of a quaternion is its transpose (the passive convention).",
          "formalisms.euler_lagrange:_quaternion_rotation", lambda f: lambda st, quat: f(st, quat).T, derived=True),
    Fault("geo-coadjoint-term-dropped", GEO,
          "The group chart's exponential is cut to first order, which drops the Euler–Poincaré coadjoint term "
          "(-ad*_v M v, the gyroscopic wrench) from the metric's Christoffel symbols.",
          "formalisms.geometric:_exp_series", lambda f: lambda X, order: f(X, 1), derived=True),
]


# ------------------------------------------------------------------ derivatives: the linearization (eq. 11)
# Each changes only what ``linearize`` returns (A, B): the splits stay right, so only the gate's linearization checks
# (``crosscheck.checks.linearization``, the first states of every case) can see them.


def _mass_derivative_dropped(terms):
    """Operational space's forward mode with the tangents of M dropped: ``dM/dq vdot`` left out of ``dvdot/dq``."""
    def faulty(model, kin):
        from formalisms.operational_space import _Dual
        M, Cqd, g = terms(model, kin)
        return (_Dual(M.val, np.zeros_like(M.tan)) if isinstance(M, _Dual) else M), Cqd, g
    return faulty


def _product_rule_sign(bilinear):
    """The dual numbers' product rule with a wrong sign on its second term: ``d(ab) = da b - a db``."""
    def faulty(f, a, b):
        from formalisms.operational_space import _Dual
        out = bilinear(f, a, b)
        if isinstance(a, _Dual) and isinstance(b, _Dual):
            second = bilinear(f, a.val, b)
            return _Dual(out.val, out.tan - 2.0 * second.tan)
        return out
    return faulty


def _velocity_block_transposed(derivatives):
    """casadi's column-major ``vec`` of ``dr/dpd`` read back row-major: the velocity block of A transposed."""
    def faulty(*args):
        dq, dv, dtau, split = derivatives(*args)
        return dq, dv.T, dtau, split
    return faulty


def _input_map_dropped(derivatives):
    """``dvdot/du`` formed as ``M^-1`` (the generalized force's derivative) without the input map B."""
    def faulty(model, chart, point, pd, tau, inputs):
        return derivatives(model, chart, point, pd, tau, np.eye(model.n))
    return faulty


DERIVATIVES = [
    Fault("el-linearize-local-chart-as-tangent", EL,
          "The derivative in the local exponential chart of a ball or free joint is used as the derivative along "
          "q exp(dq): the dexp correction (-ad_e vdot / 2 and the velocity terms) is left out of dvdot/dq.",
          "formalisms.euler_lagrange:_tangent", lambda f: lambda model, F_x, F_xd, vdot, v: F_x.copy()),
    Fault("screw-linearize-gravity-tangent-sign", "screw",   # (SCREW is the list of screw faults by now)
          "The derivative of the body-frame gravity R^T g along a body rotation eta has the wrong sign: "
          "+omega x g instead of -omega x g.",
          "formalisms.screw.derivatives:_weight_tangents", lambda f: lambda kin, G, eta: -f(kin, G, eta)),
    Fault("screw-linearize-bias-derivative-dropped", "screw",
          "The differentiated KKT system leaves out the derivative of Jcdot qd (the constraint rows' bias "
          "treated as constant).",
          "formalisms.screw.derivatives:constraint_tangents",
          lambda f: lambda kin, qd, d: (lambda dJc, dbias: (dJc, np.zeros_like(dbias)))(*f(kin, qd, d))),
    Fault("ne-linearize-at-zero-acceleration", NE,
          "The derivative recursion runs at qdd = 0 instead of at qdd = vdot, so d(M vdot)/dq is left out of A: "
          "the derivative of h alone.",
          "formalisms.newton_euler:_forward_tangents",
          lambda f: lambda model, kin, qd, qdd: f(model, kin, qd, np.zeros_like(qdd))),
    Fault("osc-linearize-mass-derivative-dropped", OSC,
          "The linearization leaves dM/dq vdot out of dvdot/dq (only the derivatives of h and of the constraint "
          "terms are kept).",
          "formalisms.operational_space:_terms", _mass_derivative_dropped),
    Fault("osc-dual-product-rule-sign", OSC,
          "The dual numbers' product rule has the wrong sign on its second term: d(ab) = da b - a db.",
          "formalisms.operational_space:_bilinear", _product_rule_sign),
    Fault("geo-linearize-velocity-block-transposed", GEO,
          "The Jacobian dr/dpd of casadi's column-major vec is read back row-major, so dvdot/dv (the Coriolis "
          "derivative) comes out transposed.",
          "formalisms.geometric:_derivatives", _velocity_block_transposed),
    Fault("geo-linearize-input-map-dropped", GEO,
          "B is formed as M^-1 (the derivative with respect to the generalized force) without the input map: "
          "dvdot/du = M^-1 instead of M^-1 B.",
          "formalisms.geometric:_derivatives", _input_map_dropped),
]


CATALOG: list[Fault] = EULER_LAGRANGE + NEWTON_EULER + SCREW + OPERATIONAL_SPACE + GEOMETRIC + GROUP + DERIVATIVES


def names() -> list[str]:
    return [f.name for f in CATALOG]


def get(name: str) -> Fault:
    """The fault called ``name``; an unknown name lists the valid ones."""
    for fault in CATALOG:
        if fault.name == name:
            return fault
    raise FaultError(f"unknown fault '{name}'; valid faults: {', '.join(names())}")
