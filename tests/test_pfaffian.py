"""Pfaffian constraints A(q) qd = 0 (issue 21, item 2): the declarations, every backend's rows and solve against the
others and the 50-digit reference, the knife edge's and the rolling disk's closed forms, the rolling disk (backends
and closed form) against an independent derivation with the literature's rolling constraint, and the sampler's
handling of velocity-only rows."""

import json

import numpy as np
import pytest
import sympy as sy

import cases
from cases.constraints import KnifeEdge, RollingContact
from cases.serialize import model_from_dict, model_to_dict
from crosscheck import closed_forms, precise, reference, sampling
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
        if case != "differential_drive":                    # its two lateral rows are one (rank 3 of 4)
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
            M_cf, Cqd, grav, A_cf, bias_cf = closed_forms.disk_terms(q, qd, m, r, g)
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
        _, A, _ = reference.constraint_kinematics(model, np.array(s.q), np.zeros(3))
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
    from hypothesis import HealthCheck, given, settings, strategies as st

    from crosscheck import testing

    seen = set()

    @settings(max_examples=25, database=None, deadline=None, derandomize=True,
              suppress_health_check=list(HealthCheck))
    @given(st.data())
    def admissible(data):
        model = data.draw(testing.models(3, True, pfaffian=True))
        seen.update(type(c).__name__ for c in model.constraints if not c.holonomic)
        s = data.draw(testing.states(model))
        Jc = reference.constraint_kinematics(model, np.array(s.q), np.zeros(model.nv))[1]
        assert np.abs(Jc @ np.array(s.qd)).max() <= 1e-12 * (1.0 + np.abs(s.qd).max())
    admissible()
    assert seen == {"KnifeEdge", "PointVelocity", "RollingContact"}, seen


def test_the_tolerance_grows_as_the_rolling_disk_lies_flat():
    """The contact direction is a unit vector divided by |n x a| = |cos(lean)| for the rolling disk's chain, and its
    rate by its square: the constraint kinematics' scale carries 1 / cos(lean)^2."""
    from crosscheck import tolerance

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
