"""The 50-digit reference's dynamics terms: M and h = C qd + g by the composite-body and recursive sums, the
external loads' generalized forces, and each constraint declaration's rows (phi, Jc and Jcdot qd; a Pfaffian
declaration's A and Adot qd)."""

from __future__ import annotations

import mpmath
from mpmath import mpf

from crosscheck.references.precise.algebra import ZERO3, add3, cross3, dot3, matvec3, scale3, sub3, transpose3
from crosscheck.references.precise.kinematics import ancestors, Data, Kin


# ----------------------------------------------------------------------------------------------- M and h


def composite_mass_matrix(data: Data, kin: Kin) -> list:
    """CRBA: composite mass, first moment h = sum m c and inertia about the world origin per subtree; then
    ``M_ij = a_j . L + v_j . P`` with ``(L, P) = (I_o a_i + h x v_i, m v_i + a_i x h)`` the subtree's momentum at
    unit rate of velocity column i (``S_i = (a_i, v_i)``), for every column j of the body or of its ancestors; then
    each joint's armature (``Body.armature``, a rotor on the joint) added to its columns' diagonal entries."""
    n = len(data.bodies)
    mass, first, second = [None] * n, [None] * n, [None] * n
    for i, b in enumerate(data.bodies):
        c = add3(kin.p[i], matvec3(kin.R[i], b.com))
        cc = dot3(c, c)
        mass[i], first[i] = b.mass, scale3(b.mass, c)
        second[i] = tuple(tuple(b.mass * ((cc if r == s else 0) - c[r] * c[s]) for s in range(3)) for r in range(3))
        if kin.inertia[i] is not None:
            second[i] = tuple(add3(row, own) for row, own in zip(second[i], kin.inertia[i]))
    for i in reversed(data.order):
        j = data.bodies[i].parent
        if j >= 0:
            mass[j], first[j] = mass[j] + mass[i], add3(first[j], first[i])
            second[j] = tuple(add3(second[j][r], second[i][r]) for r in range(3))
    nv = len(kin.S)
    M = [[mpf(0)] * nv for _ in range(nv)]
    for i in range(n):
        for ci in data.cols[i]:
            wi, vi = kin.S[ci]
            L = add3(matvec3(second[i], wi), cross3(first[i], vi))
            P = add3(scale3(mass[i], vi), cross3(wi, first[i]))
            for j in ancestors(data, i):
                for cj in data.cols[j]:
                    wj, vj = kin.S[cj]
                    M[ci][cj] = M[cj][ci] = dot3(wj, L) + dot3(vj, P)
    for i, b in enumerate(data.bodies):         # the joint's rotor: its armature on each of its columns, exactly
        for c in data.cols[i]:
            M[c][c] += b.armature
    return M


def bias_terms(data: Data, kin: Kin) -> list:
    """``h = C qd + g``: Newton–Euler at qdd = 0, each body's wrench about the world origin summed over subtrees and
    paired with each of the body's velocity columns."""
    n = len(data.bodies)
    force, moment = [None] * n, [None] * n
    for i, b in enumerate(data.bodies):
        r = matvec3(kin.R[i], b.com)
        w = kin.w[i]
        a_com = add3(add3(kin.acc[i], cross3(kin.alpha[i], r)), cross3(w, cross3(w, r)))
        f = scale3(b.mass, sub3(a_com, data.gravity))
        moment[i], force[i] = cross3(add3(kin.p[i], r), f), f
        Iw = kin.inertia[i]
        if Iw is not None:
            moment[i] = add3(moment[i], add3(matvec3(Iw, kin.alpha[i]), cross3(w, matvec3(Iw, w))))
    for i, f, m in _external_wrenches(data, kin):         # the external loads act on the bodies: h - tau_ext
        force[i], moment[i] = sub3(force[i], f), sub3(moment[i], m)
    for i in reversed(data.order):
        j = data.bodies[i].parent
        if j >= 0:
            force[j], moment[j] = add3(force[j], force[i]), add3(moment[j], moment[i])
    return [dot3(kin.S[c][0], moment[i]) + dot3(kin.S[c][1], force[i]) for i in range(n) for c in data.cols[i]]


def _external_wrenches(data: Data, kin: Kin) -> list:
    """``(body, force, moment about the world origin)`` of each external load in the world frame (module doc)."""
    out = []
    for kind, i, offset, *numbers in data.loads:
        R = kin.R[i]
        x = add3(kin.p[i], matvec3(R, offset))
        couple = ZERO3
        if kind == "spring":
            anchor, k, rest = numbers
            d = sub3(x, anchor)
            f = scale3(-k * (1 - rest / mpmath.sqrt(dot3(d, d))) if rest else -k, d)
        else:
            force, moment, in_world = numbers
            f, couple = (force, moment) if in_world else (matvec3(R, force), matvec3(R, moment))
        out.append((i, f, add3(cross3(x, f), couple)))
    return out


# ----------------------------------------------------------------------------------------------- constraints


def _point(data: Data, kin: Kin, n: int, body, offset):
    """World position, velocity, linear Jacobian (3 rows of nv) and classical acceleration at qdd = 0 of the point
    ``offset`` of ``body``; a world point (body None) is fixed."""
    zero = [mpf(0)] * n
    if body is None:
        return offset, ZERO3, [list(zero) for _ in range(3)], ZERO3
    r = matvec3(kin.R[body], offset)
    x = add3(kin.p[body], r)
    w = kin.w[body]
    vel = add3(kin.v[body], cross3(w, r))
    acc = add3(add3(kin.acc[body], cross3(kin.alpha[body], r)), cross3(w, cross3(w, r)))
    J = [list(zero) for _ in range(3)]
    for j in ancestors(data, body):
        for c in data.cols[j]:
            col = add3(kin.S[c][1], cross3(kin.S[c][0], x))
            for r_ in range(3):
                J[r_][c] = col[r_]
    return x, vel, J, acc


def _project(D, x):
    return [dot3(row, x) for row in D]


def _project_jacobian(D, J):
    return [[dot3(row, col) for col in zip(*J)] for row in D]


def _rows(data: Data, kin: Kin, q, decl):
    """phi, Jc and Jcdot qd of one declaration (the formulas of ``cases.constraints``; a coupling joins 1-DOF joints,
    whose velocity is their coordinate's rate)."""
    n = len(kin.S)
    kind = decl[0]
    if kind == "coupling":
        _, joints, coefficients, offset = decl
        row, row_q = [mpf(0)] * n, [mpf(0)] * len(q)
        for j, c in zip(joints, coefficients):
            row[data.cols[j][0]] += c
            row_q[data.q_index[j]] += c
        return [mpmath.fdot(row_q, q) - offset], [row], [mpf(0)]
    if kind == "coincide":
        _, a, b, D = decl
        xa, _, Ja, aa = _point(data, kin, n, *a)
        xb, _, Jb, ab = _point(data, kin, n, *b)
        dJ = [[s - t for s, t in zip(ra, rb)] for ra, rb in zip(Ja, Jb)]
        return _project(D, sub3(xa, xb)), _project_jacobian(D, dJ), _project(D, sub3(aa, ab))
    if kind in PFAFFIAN_KINDS:
        return _pfaffian_rows(data, kin, decl)
    x, vel, J, acc = _point(data, kin, n, *decl[1])
    if kind == "line":
        _, _, origin, N = decl
        return _project(N, sub3(x, origin)), _project_jacobian(N, J), _project(N, acc)
    _, _, center, radius, P = decl
    d = _project(P, sub3(x, center))
    PJ, Pv, Pa = _project_jacobian(P, J), _project(P, vel), _project(P, acc)
    row = [2 * (d[0] * PJ[0][k] + d[1] * PJ[1][k]) for k in range(n)]
    return ([d[0] ** 2 + d[1] ** 2 - radius ** 2], [row],
            [2 * (Pv[0] ** 2 + Pv[1] ** 2) + 2 * (d[0] * Pa[0] + d[1] * Pa[1])])


#: The declaration kinds of :func:`_constraint_data` that are Pfaffian (velocity rows, phi reported 0).
PFAFFIAN_KINDS = ("velocity", "knife", "rolling")


def _pfaffian_rows(data: Data, kin: Kin, decl):
    """phi (0), A and Adot qd of a Pfaffian declaration (``cases.constraints``) from :func:`_point`: a point's
    ``D J``, ``D acc``; a knife edge's ``e = R d`` with ``(w x e) . vel + e . acc``; a rolling contact's material point
    at ``p_c = c - r u`` (its body-frame offset ``center + R^T e``, ``e = -r u``) with ``Adot qd = T (acc + w x (edot -
    w x e))``, ``edot = -r udot``, ``udot = (I - u u^T) rawdot / |raw|``, ``raw = n - (n.a) a``, ``adot = w x a``;
    with ``lateral=False`` the one row along ``t = b / |b|``, ``b = a x n``: ``A = t^T J``, ``Adot qd = t . (acc + w x
    (edot - w x e)) + tdot . vel``, ``tdot = (bdot - t (t.bdot)) / |b|``, ``bdot = adot x n``."""
    n = len(kin.S)
    kind, (body, offset) = decl[0], decl[1]
    if kind == "velocity":
        _, J, acc = _point(data, kin, n, body, offset)[1:]
        return [mpf(0)] * len(decl[2]), _project_jacobian(decl[2], J), _project(decl[2], acc)
    R, w = kin.R[body], kin.w[body]
    if kind == "knife":
        _, vel, J, acc = _point(data, kin, n, body, offset)
        e = matvec3(R, decl[2])
        return [mpf(0)], [_project_jacobian((e,), J)[0]], [dot3(cross3(w, e), vel) + dot3(e, acc)]
    _, _, axis, radius, T, lateral = decl
    normal = cross3(T[0], T[1])
    a = matvec3(R, axis)
    raw = sub3(normal, scale3(dot3(normal, a), a))
    length = mpmath.sqrt(dot3(raw, raw))
    u = scale3(1 / length, raw)
    e = scale3(-radius, u)
    a_dot = cross3(w, a)
    raw_dot = sub3(scale3(-dot3(normal, a_dot), a), scale3(dot3(normal, a), a_dot))
    e_dot = scale3(-radius / length, sub3(raw_dot, scale3(dot3(u, raw_dot), u)))
    _, vel, J, acc = _point(data, kin, n, body, add3(offset, matvec3(transpose3(R), e)))
    rate = add3(acc, cross3(w, sub3(e_dot, cross3(w, e))))
    if not lateral:     # the rolling direction t = b / |b|, b = a x n, alone: t . rate + tdot . vel
        b = cross3(a, normal)
        size = mpmath.sqrt(dot3(b, b))
        t = scale3(1 / size, b)
        b_dot = cross3(a_dot, normal)
        t_dot = scale3(1 / size, sub3(b_dot, scale3(dot3(t, b_dot), t)))
        return [mpf(0)], [_project_jacobian((t,), J)[0]], [dot3(t, rate) + dot3(t_dot, vel)]
    return [mpf(0), mpf(0)], _project_jacobian(T, J), _project(T, rate)


def constraint_terms(data: Data, kin: Kin, q):
    phi, Jc, bias = [], [], []
    for decl in data.rows:
        p, J, b = _rows(data, kin, q, decl)
        phi += p
        Jc += J
        bias += b
    return phi, Jc, bias
