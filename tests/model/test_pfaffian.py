"""Pfaffian constraints A(q) qd = 0: the declarations, every backend's rows and solve against the
others and the 50-digit reference, the closed forms of the knife edge, the rolling disk and the differential drive,
the rolling disk (backends and closed form) against an independent derivation with the literature's rolling
constraint, the rolling-direction row (``RollingContact(lateral=False)``) against its own symbolic derivation, and the
sampler's handling of velocity-only rows."""

import json

import numpy as np
import pytest
import sympy as sy

import cases
from cases.constraints import KnifeEdge, RollingContact
from cases.serialize import SerializeError, model_from_dict, model_to_dict
from crosscheck.references import closed_forms
from crosscheck.references.closed_forms import nonholonomic
from crosscheck.references import precise
from crosscheck.references.pinocchio import kinematics
from crosscheck.references.pinocchio import reference
from crosscheck.core import sampling
from formalisms import euler_lagrange, geometric, newton_euler, operational_space, screw

BACKENDS = (euler_lagrange, newton_euler, screw, operational_space, geometric)
NONHOLONOMIC = ("knife_edge", "rolling_disk", "differential_drive")


def _state(model, seed):
    rng = np.random.default_rng(seed)
    q = rng.uniform(-1.0, 1.0, model.nq)
    qd = sampling.project_velocity(model, q, rng.uniform(-2.0, 2.0, model.nv))
    return q, qd, rng.uniform(-3.0, 3.0, model.m)


def test_declarations_are_validated_serialized_and_marked_pfaffian():
    model = cases.load("rolling_disk")
    assert model.pfaffian_rows.tolist() == [True, True] and not model.holonomic_rows.any()
    again = model_from_dict(json.loads(json.dumps(model_to_dict(model))))
    assert again.digest() == model.digest() and isinstance(again.constraints[0], RollingContact)
    bodies = list(cases.load("knife_edge").bodies)
    with pytest.raises(cases.ModelError, match="direction .*length"):
        cases.build_model("bad", bodies, constraints=[KnifeEdge("blade", "sleigh", (0, 0, 0), (0, 2, 0))])
    with pytest.raises(cases.ModelError, match="positive finite radius"):
        cases.build_model("bad", bodies, constraints=[RollingContact("wheel", "sleigh", (0, 0, 0), (0, 1, 0), -1.0)])


@pytest.mark.parametrize("case", NONHOLONOMIC)
def test_backends_and_references_agree_on_rows_accelerations_and_multipliers(case):
    model = cases.load(case)
    q, qd, u = _state(model, 1)
    exact = precise.split(model, q, qd, u)
    for backend in (*BACKENDS, reference):
        s = backend.FORMALISM.split(model, q, qd, u) if backend is not reference else reference.split(model, q, qd, u)
        np.testing.assert_array_equal(s.constraint_value, 0.0)
        np.testing.assert_allclose(s.total, np.asarray(exact.total, dtype=float), atol=1e-11)
        np.testing.assert_allclose(s.drift, np.asarray(exact.drift, dtype=float), atol=1e-11)
        np.testing.assert_allclose(s.constraint_jacobian @ s.total + s.constraint_bias, 0.0, atol=1e-11)
        assert abs(s.power_constr) < 1e-11                  # ideal rows do no work: lam . A qd = 0
        assert s.constraint_rank == model.k                 # independent rows: lam is unique
        np.testing.assert_allclose(s.lam, np.asarray(exact.lam, dtype=float), atol=1e-11)


def test_knife_edge_closed_form_matches_the_backends():
    model = cases.load("knife_edge")
    voter = closed_forms.voter("knife_edge")
    for seed in (2, 3):
        q, qd, u = _state(model, seed)
        cf, ne = voter.split(model, q, qd, u), newton_euler.split(model, q, qd, u)
        for name in ("total", "drift", "ctrl", "lam", "lam_drift", "constraint_jacobian", "constraint_bias"):
            np.testing.assert_allclose(getattr(cf, name), getattr(ne, name), atol=1e-12, err_msg=name)


def _literature_rolling_disk_terms(m, r, g, q, qd):
    """The rolling disk by Lagrange-d'Alembert, derived here with sympy: the disk's kinetic energy from its centre and
    angular velocity in (x, y, yaw, lean, spin) with x, y the contact point, and the classical rolling constraint of a
    disk with contact-point coordinates (e.g. Bloch, Nonholonomic Mechanics, 1.4): the contact moves along the heading
    at the rolling rate, ``xd = r spind cos(yaw)``, ``yd = r spind sin(yaw)`` (spin positive rolling forward).
    Returns (M, h = C qd + g, A, Adot qd) as float arrays (5 x 5, 5, 2 x 5, 2)."""
    x, y, psi, phi, th = sy.symbols("x y psi phi theta")
    coords = [x, y, psi, phi, th]
    rates = sy.symbols("xd yd psid phid thetad")
    Rz = sy.Matrix([[sy.cos(psi), -sy.sin(psi), 0], [sy.sin(psi), sy.cos(psi), 0], [0, 0, 1]])
    Rx = sy.Matrix([[1, 0, 0], [0, sy.cos(phi), -sy.sin(phi)], [0, sy.sin(phi), sy.cos(phi)]])
    Ry = sy.Matrix([[sy.cos(th), 0, sy.sin(th)], [0, 1, 0], [-sy.sin(th), 0, sy.cos(th)]])
    center = sy.Matrix([x, y, 0]) + Rz * Rx * sy.Matrix([0, 0, r])
    heading, axle = Rz * sy.Matrix([1, 0, 0]), Rz * Rx * sy.Matrix([0, 1, 0])
    omega = rates[2] * sy.Matrix([0, 0, 1]) + rates[3] * heading + rates[4] * axle
    R = Rz * Rx * Ry
    body_omega = R.T * omega
    vc = center.jacobian(coords) * sy.Matrix(rates)
    T = (m * (vc.T * vc)[0] + (body_omega.T * sy.diag(m * r**2 / 4, m * r**2 / 2, m * r**2 / 4) * body_omega)[0]) / 2
    V = m * g * center[2]
    dT = sy.Matrix([T]).jacobian(rates).T
    M = dT.jacobian(rates)
    h = dT.jacobian(coords) * sy.Matrix(rates) - sy.Matrix([T]).jacobian(coords).T + sy.Matrix([V]).jacobian(coords).T
    A = sy.Matrix([[1, 0, 0, 0, -r * sy.cos(psi)], [0, 1, 0, 0, -r * sy.sin(psi)]])
    bias = (A * sy.Matrix(rates)).jacobian(coords) * sy.Matrix(rates)
    evaluate = sy.lambdify([coords, rates], [M, h, A, bias], "numpy")
    M, h, A, bias = (np.array(e, dtype=float) for e in evaluate(list(q), list(qd)))
    return M, h.ravel(), A, bias.ravel()


def _literature_rolling_disk(m, r, g, q, qd, u):
    """The total accelerations of :func:`_literature_rolling_disk_terms` by the KKT system (eqs. 12, 13)."""
    M, h, A, bias = _literature_rolling_disk_terms(m, r, g, q, qd)
    kkt = np.block([[M, -A.T], [A, np.zeros((2, 2))]])
    return np.linalg.solve(kkt, np.concatenate([u - h, -bias]))[:5]


def test_rolling_disk_matches_the_literature_rolling_constraint():
    m, r, g = 1.3, 0.4, 9.81
    model = cases.load("rolling_disk", m=m, r=r, g=g)
    rng = np.random.default_rng(4)
    q = np.array([0.3, -0.2, 0.7, 0.4, 1.1])
    spin, yaw_rate, lean_rate = 2.0, -0.8, 0.5          # admissible by the literature's constraint
    qd = np.array([r * spin * np.cos(q[2]), r * spin * np.sin(q[2]), yaw_rate, lean_rate, spin])
    u = rng.uniform(-1.0, 1.0, 5)
    expected = _literature_rolling_disk(m, r, g, q, qd, u)
    for backend in BACKENDS:
        np.testing.assert_allclose(backend.FORMALISM.split(model, q, qd, u).total, expected, atol=1e-10,
                                   err_msg=backend.__name__)
    # Newton for the disk at u = 0: the ground's friction (lam, along x and y) is the only horizontal force on it, so it
    # is m times the horizontal acceleration of the centre (the task point "center", at the drift)
    drift = newton_euler.split(model, q, qd, np.zeros(5))
    np.testing.assert_allclose(drift.lam_drift, m * drift.task_drift[:2], atol=1e-12)


def test_rolling_disk_closed_form_terms_are_the_literature_derivations():
    """``closed_forms.disk_terms`` (by hand, the classical form) against the sympy derivation above, term by term, for
    |lean| < pi/2 (the literature's disk stands on its contact): M, h = C qd + g, the rows and ``Adot qd``. The case's
    rows (the world x, y velocity of the contact's material point) ARE the literature's rows there, the row transform
    the identity, so lam means the same force in both."""
    rng = np.random.default_rng(11)
    for m, r, g in ((1.0, 0.5, 9.81), (1.7, 0.3, 9.81), (0.4, 1.2, 3.7)):
        for _ in range(3):
            q = np.concatenate([rng.uniform(-2.0, 2.0, 3), rng.uniform(-1.4, 1.4, 1), rng.uniform(-3.0, 3.0, 1)])
            qd = rng.uniform(-2.0, 2.0, 5)          # the terms hold at any qd, admissible or not
            M, h, A, bias = _literature_rolling_disk_terms(m, r, g, q, qd)
            M_cf, Cqd, grav, A_cf, bias_cf = nonholonomic.disk_terms(q, qd, m, r, g)
            scale = m * (1.0 + r) ** 2 * (1.0 + qd @ qd) + m * g * r
            np.testing.assert_allclose(M_cf, M, rtol=0, atol=1e-14 * m * (1.0 + r) ** 2)
            np.testing.assert_allclose(Cqd + grav, h, rtol=0, atol=1e-14 * scale)
            np.testing.assert_allclose(A_cf, A, rtol=0, atol=1e-15 * (1.0 + r))
            np.testing.assert_allclose(bias_cf, bias, rtol=0, atol=1e-15 * r * (1.0 + qd @ qd))


def test_rolling_disk_closed_form_matches_newton_euler():
    """The closed form's split against Newton-Euler's at admissible states, lean drawn on (-3, 3): beyond pi/2 the
    chain puts the centre below the ground and the case's contact, the disk's lowest point, is the chain's far point
    (``disk_terms``' sigma = -1), where the rows are not the literature's. Near |lean| = pi/2 the disk lies almost
    flat, its yaw and spin turn it about nearly the same axis, and cond(M) grows (to 2.5e4 at lean 1.51 here, the
    accelerations to 3e3): both sides then round by about eps cond(M) |value| (each is within 1.4e-10 of the 50-digit
    reference there), so the tolerance is 1e-11 plus 4 eps cond(M) |value|_max (measured: at most 0.04 of the
    tolerance, at lean -1.45 where Newton-Euler is 3e-11 off the reference)."""
    rng = np.random.default_rng(12)
    checked_flipped = 0
    for params in ({}, {"m": 1.7, "r": 0.3}):
        model = cases.load("rolling_disk", **params)
        voter = closed_forms.voter("rolling_disk", params)
        for _ in range(6):
            q = rng.uniform(-3.0, 3.0, 5)
            qd = sampling.project_velocity(model, q, rng.uniform(-2.0, 2.0, 5))
            u = rng.uniform(-3.0, 3.0, 5)
            checked_flipped += np.cos(q[3]) < 0.0
            cf, ne = voter.split(model, q, qd, u), newton_euler.split(model, q, qd, u)
            np.testing.assert_allclose(cf.constraint_jacobian @ qd, 0.0, atol=1e-13)
            for name in ("total", "drift", "ctrl", "lam", "lam_drift", "constraint_jacobian", "constraint_bias",
                         "task_drift", "kinetic_energy"):
                expected = np.asarray(getattr(ne, name), dtype=float)
                atol = 1e-11 + 4.0 * np.finfo(float).eps * ne.cond_M * np.abs(expected).max()
                np.testing.assert_allclose(getattr(cf, name), expected, rtol=0, atol=atol, err_msg=name)
    assert checked_flipped >= 2


def test_sampler_leaves_configurations_free_and_velocities_admissible():
    model = cases.load("knife_edge")
    states = sampling.sample_states(model, 4, seed=7, case="knife_edge")
    for s in states:
        _, A, _ = kinematics.constraint_kinematics(model, np.array(s.q), np.zeros(3))
        assert abs(A @ np.array(s.qd)).max() < 1e-13
    assert sampling.project_configuration(model, np.array([0.3, -0.4, 2.0])).tolist() == [0.3, -0.4, 2.0]


@pytest.mark.parametrize("case", NONHOLONOMIC)
def test_linearizations_with_pfaffian_rows(case):
    """Euler–Lagrange and geometric differentiate the KKT system with A(q) and Adot qd (q, qd) as they do holonomic
    rows, Newton–Euler, screw and operational space their own tangents (the rolling contact's point moving over the
    disk), and all match the 50-digit reference's central differences."""
    model = cases.load(case)
    q, qd, u = _state(model, 6)
    exact = precise.linearize(model, q, qd, u)
    for backend in BACKENDS:
        lin = backend.FORMALISM.linearize(model, q, qd, u)
        np.testing.assert_allclose(lin.A, exact.A, atol=1e-11, err_msg=backend.__name__)
        np.testing.assert_allclose(lin.B, exact.B, atol=1e-11, err_msg=backend.__name__)


def test_fuzzed_models_carry_pfaffian_rows_and_their_states_are_admissible():
    """Each Pfaffian kind is among the fuzzer's models (searched for, not counted in a fixed sample, whose make-up moves
    with Hypothesis's seed), and the states drawn for such a model satisfy its rows."""
    from hypothesis import HealthCheck, Phase, find, given, settings

    from crosscheck import testing

    search = settings(max_examples=500, database=None, deadline=None, phases=[Phase.generate],
                      suppress_health_check=list(HealthCheck))
    for kind in ("KnifeEdge", "PointVelocity", "RollingContact"):
        model = find(testing.models(3, True, pfaffian=True),
                     lambda m, kind=kind: any(type(c).__name__ == kind for c in m.constraints), settings=search)

        @settings(max_examples=10, database=None, deadline=None, derandomize=True,
                  suppress_health_check=list(HealthCheck))
        @given(testing.states(model))
        def admissible(s):
            Jc = kinematics.constraint_kinematics(model, np.array(s.q), np.zeros(model.nv))[1]
            assert np.abs(Jc @ np.array(s.qd)).max() <= 1e-12 * (1.0 + np.abs(s.qd).max())
        admissible()


def test_drawn_rolling_contacts_come_both_ways():
    """``crosscheck.testing`` draws a rolling contact's ``lateral`` both ways (two rows or the rolling direction)."""
    from hypothesis import HealthCheck, given, settings, strategies as st

    from crosscheck import testing

    seen = set()

    @settings(max_examples=20, database=None, deadline=None, derandomize=True,
              suppress_health_check=list(HealthCheck))
    @given(st.data())
    def drawn(data):
        c = testing._pfaffian_declaration(data.draw, "RollingContact", "c", "disk", np.zeros(3), np.eye(3), 2)
        assert c.size == (2 if c.lateral else 1)
        seen.add(c.lateral)
    drawn()
    assert seen == {True, False}


def test_the_tolerance_grows_as_the_rolling_disk_lies_flat():
    """The contact direction is a unit vector divided by |n x a| = |cos(lean)| for the rolling disk's chain, and its
    rate by its square: the constraint kinematics' scale carries 1 / cos(lean)^2."""
    from crosscheck.core import tolerance

    model = cases.load("rolling_disk")
    for lean in (0.3, 1.55, -1.5703):
        q = np.array([0.1, 0.2, 0.7, lean, 0.4])
        assert tolerance._contact_gain(model, q) == pytest.approx(1.0 / np.cos(lean) ** 2, rel=1e-9)
    assert tolerance._contact_gain(cases.load("knife_edge"), np.zeros(3)) == 1.0


def test_the_differential_drives_payload_load_by_hand():
    """The crate on the robot's tray (``cases.nonholonomic.differential_drive``): a body-frame force f_b and couple
    m_z at r_b = (-0.15, 0.05) from the axle's midpoint. In q = (x, y, heading, wheels) by virtual work:
    tau_ext = (R f_b (x, y), r_b x f_b + m_z, 0, 0), R the heading's rotation; the weight does no work. Every backend
    and the reference give it, and the drift at rest is the KKT solve with it on the right-hand side."""
    drag, heading = 3.0, 0.7
    model = cases.load("differential_drive")
    c, s = np.cos(heading), np.sin(heading)
    f_b = np.array([-drag, -0.4 * drag])
    expected = np.array([c * f_b[0] - s * f_b[1], s * f_b[0] + c * f_b[1],
                         -0.15 * f_b[1] - 0.05 * f_b[0] + 0.1 * drag, 0.0, 0.0])
    q = np.array([0.3, -0.2, heading, 1.1, -0.4])
    qd = sampling.project_velocity(model, q, np.array([0.5, -0.3, 0.8, 2.0, 1.0]))
    for backend in (*BACKENDS, reference):
        out = backend.split(model, q, qd, np.zeros(2))
        assert np.abs(out.external_force - expected).max() <= 1e-14 * 10, backend.__name__
        assert out.power_ext == pytest.approx(expected @ qd, rel=1e-12, abs=1e-14)


# ------------------------------------------------------------------ the rolling-direction row (lateral=False)


def _leaning_disk(lateral: bool = False, m: float = 1.3, r: float = 0.4, g: float = 9.81):
    """``cases.rolling_disk``'s chain (x, y, yaw, lean, spin; the contact point at (x, y, 0)) with its contact declared
    ``RollingContact(..., lateral=lateral)``: with False one row, the disk may slide sideways."""
    base = cases.load("rolling_disk", m=m, r=r, g=g)
    contact = RollingContact("rolling", "disk", (0, 0, 0), (0, 1, 0), r, ((1, 0, 0), (0, 1, 0)), lateral=lateral)
    return cases.build_model("leaning_disk", base.bodies, gravity=base.gravity, task_points=base.task_points,
                             constraints=[contact])


def _rolling_direction_row(r):
    """The row ``t . v_pc`` of the leaning disk derived here with sympy, from the module docstring's definition and
    the chain's geometry alone: the centre ``c = (x, y, 0) + Rz Rx (0, 0, r)``, the axle ``a = Rz Rx e_y``, ``w = yawd
    e_z + leand (Rz e_x) + spind a``, the contact ``p_c = c - r u`` with ``u = (n - (n.a) a) / |.|``, ``n = e_z``, its
    material point's velocity ``cdot + w x (p_c - c)`` and ``t = (a x n) / |a x n|``. Returns functions of (q, qd):
    A = d(row)/dqd and the bias ``(d(row)/dq) qd`` (the rates held: qdd = 0)."""
    x, y, psi, phi, th = coords = sy.symbols("x y psi phi theta", real=True)
    rates = sy.Matrix(sy.symbols("xd yd psid phid thetad", real=True))
    Rz = sy.Matrix([[sy.cos(psi), -sy.sin(psi), 0], [sy.sin(psi), sy.cos(psi), 0], [0, 0, 1]])
    Rx = sy.Matrix([[1, 0, 0], [0, sy.cos(phi), -sy.sin(phi)], [0, sy.sin(phi), sy.cos(phi)]])
    n = sy.Matrix([0, 0, 1])
    center = sy.Matrix([x, y, 0]) + Rz * Rx * sy.Matrix([0, 0, r])
    a = Rz * Rx * sy.Matrix([0, 1, 0])
    w = rates[2] * n + rates[3] * (Rz * sy.Matrix([1, 0, 0])) + rates[4] * a
    raw = n - (n.T * a)[0] * a
    e = -r * raw / sy.sqrt((raw.T * raw)[0])
    v_pc = center.jacobian(coords) * rates + w.cross(e)
    b = a.cross(n)
    row = (b.T * v_pc)[0] / sy.sqrt((b.T * b)[0])
    A = sy.Matrix([row]).jacobian(rates)
    bias = sy.Matrix([row]).jacobian(coords) * rates
    return sy.lambdify([coords, list(rates)], [A, bias], "numpy")


def test_the_rolling_direction_row_matches_its_own_derivation_where_the_disk_slides_sideways():
    """A and Adot qd of ``lateral=False`` in every backend and both references against the sympy derivation of ``t .
    v_pc`` (:func:`_rolling_direction_row`) on a leaning disk that slides sideways (so ``tdot . v_pc`` is not 0)."""
    r = 0.4
    model = _leaning_disk(r=r)
    evaluate = _rolling_direction_row(r)
    for seed in (11, 12, 13):
        q, qd, u = _state(model, seed)
        A, bias = (np.array(e, dtype=float).ravel() for e in evaluate(list(q), list(qd)))
        lateral = -np.sin(q[2]) * qd[0] + np.cos(q[2]) * qd[1]                  # the contact's sideways rate
        assert abs(lateral) > 0.05, lateral
        for backend in (*BACKENDS, reference):
            s = backend.split(model, q, qd, u)
            np.testing.assert_allclose(s.constraint_jacobian.ravel(), A, atol=1e-13, err_msg=backend.__name__)
            np.testing.assert_allclose(s.constraint_bias, bias, atol=1e-12, err_msg=backend.__name__)


def test_every_backend_matches_the_50_digit_reference_on_a_leaning_disk_with_the_rolling_row_only():
    model = _leaning_disk()
    for seed in (21, 22):
        q, qd, u = _state(model, seed)
        exact = precise.split(model, q, qd, u)
        for backend in (*BACKENDS, reference):
            s = backend.split(model, q, qd, u)
            assert s.constraint_rank == 1 and s.lam.shape == (1,)
            for name in ("total", "drift", "lam", "lam_drift"):
                np.testing.assert_allclose(getattr(s, name), exact.floats(name), atol=1e-11,
                                           err_msg=f"{backend.__name__} {name}")
    q, qd, u = _state(model, 23)
    exact = precise.linearize(model, q, qd, u)
    for backend in BACKENDS:
        lin = backend.FORMALISM.linearize(model, q, qd, u)
        np.testing.assert_allclose(lin.A, exact.A, atol=1e-11, err_msg=backend.__name__)
        np.testing.assert_allclose(lin.B, exact.B, atol=1e-11, err_msg=backend.__name__)


def test_the_rolling_row_multiplier_is_the_traction_along_t():
    """Newton for the disk at u = 0, no slip along t: the ground's only horizontal force on the disk is ``lam t``
    (t = the heading on this chain), so ``m (horizontal acceleration of the centre) = lam t``: nothing across t."""
    m = 1.3
    model = _leaning_disk(m=m)
    q, qd, _ = _state(model, 31)
    drift = newton_euler.split(model, q, qd, np.zeros(5))
    heading = np.array([np.cos(q[2]), np.sin(q[2])])
    np.testing.assert_allclose(m * drift.task_drift[:2], drift.lam_drift[0] * heading, atol=1e-12)


def test_the_lateral_flag_is_validated_serialized_and_digested():
    bodies = list(cases.load("rolling_disk").bodies)
    plane = ((1, 0, 0), (0, 1, 0))
    with pytest.raises(cases.ModelError, match=r"lateral='no'; give True .* or False"):
        cases.build_model("bad", bodies, constraints=[RollingContact("c", "disk", (0, 0, 0), (0, 1, 0), 0.5, plane,
                                                                     "no")])
    one_row, two_rows = _leaning_disk(), _leaning_disk(lateral=True)
    assert (one_row.k, two_rows.k) == (1, 2) and one_row.digest() != two_rows.digest()
    d = model_to_dict(one_row)
    assert d["constraints"][0]["lateral"] is False
    again = model_from_dict(json.loads(json.dumps(d)))
    assert again.digest() == one_row.digest() and again.constraints[0].lateral is False
    old = model_to_dict(two_rows)                       # the default is not written: a dict from before the field
    assert "lateral" not in old["constraints"][0]
    assert model_from_dict(old).constraints[0].lateral is True and model_from_dict(old).k == 2
    d["constraints"][0]["lateral"] = 0
    with pytest.raises(SerializeError, match=r"constraints\[0\]\.lateral' is 0; give true or false"):
        model_from_dict(d)


def test_the_differential_drive_has_three_independent_rows_in_every_backend():
    """Two rolling-direction rows and the axle's knife edge: rank 3 at every sampled state, S well conditioned (no
    BREAKDOWN of "constraint"), and the rows are those of its docstring."""
    model = cases.load("differential_drive")
    assert model.k == 3
    r, b = 0.1, 0.2
    for state in sampling.sample_states(model, 6, seed=0, case="differential_drive"):
        q, qd, u = (np.array(x) for x in (state.q, state.qd, state.u))
        c, s = np.cos(q[2]), np.sin(q[2])
        rows = np.array([[c, s, -b, -r, 0.0], [c, s, b, 0.0, -r], [-s, c, 0.0, 0.0, 0.0]])
        for backend in (*BACKENDS, reference):
            out = backend.split(model, q, qd, u)
            assert out.constraint_rank == 3, backend.__name__
            assert out.conditions["constraint"] < 1e3, (backend.__name__, out.conditions["constraint"])
            np.testing.assert_allclose(out.constraint_jacobian, rows, atol=1e-15, err_msg=backend.__name__)


def test_the_differential_drive_closed_form_matches_the_backends():
    model = cases.load("differential_drive")
    voter = closed_forms.voter("differential_drive")
    for seed in (2, 3, 4, 5):
        q, qd, _ = _state(model, seed)
        u = np.random.default_rng(seed).uniform(-3.0, 3.0, 2)
        cf = voter.split(model, q, qd, u)
        for backend, extra in ((newton_euler, ("task_drift",)), (euler_lagrange, ())):   # EL has no task point
            other = backend.split(model, q, qd, u)
            for name in ("total", "drift", "ctrl", "lam", "lam_drift", "constraint_jacobian", "constraint_bias",
                         "external_force", "kinetic_energy", "zvcf", "drift_velocity") + extra:
                np.testing.assert_allclose(getattr(cf, name), getattr(other, name), atol=1e-11,
                                           err_msg=f"{backend.__name__} {name}")


def test_the_differential_drive_closed_form_by_hand_at_one_state():
    """:func:`crosscheck.references.closed_forms.nonholonomic.drive_motion` against numbers worked here: at rest heading 0 with equal torques
    u the robot drives straight, ``vdot = (2 u / r + F_along) / (m + 2 I_a / r^2)``, the tractions ``(u - I_a vdot /
    r) / r`` each, and the axle carries the load's lateral force (``lam_a = -F_lat``, nothing turns it at rest apart
    from the load's yaw moment, which the heading row takes)."""
    m_body, m_wheel, r, track, d = 4.0, 0.5, 0.1, 0.4, 0.1
    Ia = m_wheel * r * r / 2.0
    tau_ext = np.array([-3.0, -1.2, 0.0, 0.0, 0.0])          # a pure force at P, along -x and -y, no moment
    qdd, lam = nonholonomic.drive_motion(np.zeros(5), np.zeros(5), np.array([0.5, 0.5]), tau_ext, m_body, m_wheel, r,
                                         track, d)
    vdot = (2 * 0.5 / r - 3.0) / (m_body + 2 * m_wheel + 2 * Ia / r**2)
    np.testing.assert_allclose(qdd, [vdot, 0.0, 0.0, vdot / r, vdot / r], atol=1e-15)
    np.testing.assert_allclose(lam, [(0.5 - Ia * vdot / r) / r] * 2 + [1.2], atol=1e-14)
