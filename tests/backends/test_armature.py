"""Armature (``Body.armature``: a rotor's inertia on M's diagonal) in every backend, each in its own formulation:

* for random models with random armature (revolute, prismatic and ball joints), every backend's M, and the 50-digit
  reference's, is the M of the same model without armature plus ``diag(armature per velocity)``, and the backends
  agree on the drift, ctrl and the rest of the gate's comparison;
* the kinetic energy gains ``1/2 a qd^2``, the inverse dynamics ``a qdd``, the linearization's B is ``M^-1 B`` of
  that M;
* the pendulums' closed forms add it, checked against a hand formula typed here, and a closed form without armature
  refuses a model that has some;
* the Euler–Lagrange cache never serves code derived for another armature.
"""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest
from hypothesis import assume, given, strategies as st

import cases
import formalisms
from cases.build import build_model
from crosscheck import backends, testing
from crosscheck.checks import frames
from crosscheck.references import closed_forms, precise
from crosscheck.references.closed_forms import ClosedFormMismatch
from crosscheck.references.pinocchio import kinematics
from formalisms import euler_lagrange as el, geometric, newton_euler, operational_space
from formalisms.screw import dynamics as screw_dynamics

pytestmark = pytest.mark.usefixtures("fresh_derivation_cache")


def without_armature(model):
    """The same model with every joint's armature 0."""
    return dataclasses.replace(model, bodies=tuple(dataclasses.replace(b, armature=0.0) for b in model.bodies))


def with_armature(model, values):
    """``model`` rebuilt with body i's armature ``values[i]``."""
    bodies = [dataclasses.replace(b, armature=a) for b, a in zip(model.bodies, values)]
    return build_model(model.name, bodies, gravity=model.gravity, input_map=model.input_map,
                       task_points=model.task_points, constraints=model.constraints, loads=model.loads)


#: Each backend's M (and the references'), at a state (q, v).
MASS_MATRICES = {
    "euler_lagrange": lambda m, q, v: el.evaluate(m, q, v)[0].M,
    "newton_euler": lambda m, q, v: newton_euler.mass_matrix(m, q),
    "screw": lambda m, q, v: screw_dynamics.mass_matrix(m, q),
    "operational_space": lambda m, q, v: operational_space.joint_space_terms(m, q, v)[0],
    "geometric": lambda m, q, v: geometric.metric(m, q),
    "pinocchio": lambda m, q, v: kinematics.mass_matrix(m, q),
    "precise": lambda m, q, v: np.array(precise.mass_matrix(m, q).tolist(), dtype=float),
}


@given(st.data())
def test_every_backends_M_is_the_bodies_M_plus_the_armature_and_the_backends_agree(data):
    model = data.draw(testing.models(max_bodies=3, group=True, armature=True))
    state = data.draw(testing.states(model))
    q, v = np.array(state.q), np.array(state.qd)
    a = model.armature_vector
    assume(a.any())                 # a model of free joints only has no joint that can hold armature
    assert not without_armature(model).armature_vector.any()
    bare = without_armature(model)
    for name, mass_matrix in MASS_MATRICES.items():
        M, M0 = mass_matrix(model, q, v), mass_matrix(bare, q, v)
        scale = np.abs(M).max()
        np.testing.assert_allclose(M - M0, np.diag(a), rtol=0, atol=1e-12 * scale, err_msg=name)
    testing.assert_backends_agree(model, state)


def _ball_arm():
    """A ball joint, a revolute and a prismatic one, each with its own armature (0.07, 0.02, 0.4)."""
    bodies = [cases.Body("ball", None, "spherical", (0, 0, 0), 1.2, com=(0.1, 0.05, -0.3),
                         inertia=np.diag([0.01, 0.02, 0.025]), translation=(0, 0, 1), armature=0.07),
              cases.Body("hinge", "ball", "revolute", (0, 1, 0), 0.7, com=(0.1, 0, -0.1),
                         inertia=np.diag([0.01, 0.02, 0.025]), translation=(0.1, 0, -0.4), armature=0.02),
              cases.Body("slide", "hinge", "prismatic", (1, 0, 0), 0.3, com=(0.03, 0, 0),
                         inertia=np.diag([0.0002, 0.0004, 0.0004]), translation=(0.2, 0, 0), armature=0.4)]
    return build_model("ball_arm", bodies)


STATE = (np.array([0.1, -0.2, 0.3, np.sqrt(1 - 0.14), 0.4, 0.05]), np.array([0.7, -1.1, 0.4, 1.3, -0.6]),
         np.array([0.5, -0.2, 0.1, 0.3, 1.0]))


def test_the_armature_per_velocity_repeats_over_a_ball_joints_three():
    assert _ball_arm().armature_vector.tolist() == [0.07, 0.07, 0.07, 0.02, 0.4]


@pytest.mark.parametrize("name", formalisms.names() + ["pinocchio"])
def test_the_kinetic_energy_gains_half_a_qd_squared(name):
    model = _ball_arm()
    q, v, u = STATE
    backend = backends.get(name)
    T, T0 = backend.split(model, q, v, u).kinetic_energy, backend.split(without_armature(model), q, v, u).kinetic_energy
    assert T - T0 == pytest.approx(0.5 * float(model.armature_vector @ (v * v)), rel=1e-12)


@pytest.mark.parametrize("inverse_dynamics", [newton_euler.inverse_dynamics, screw_dynamics.inverse_dynamics],
                         ids=["newton_euler", "screw"])
def test_the_inverse_dynamics_gains_the_rotors_torque(inverse_dynamics):
    model = _ball_arm()
    q, v, qdd = STATE
    extra = inverse_dynamics(model, q, v, qdd) - inverse_dynamics(without_armature(model), q, v, qdd)
    np.testing.assert_allclose(extra, model.armature_vector * qdd, rtol=1e-12, atol=1e-14)


@pytest.mark.parametrize("name", formalisms.names())
def test_the_linearizations_input_matrix_is_the_inverse_of_M_with_armature(name):
    model = _ball_arm()
    q, v, u = STATE
    lin = formalisms.get(name).linearize(model, q, v, u)
    M = kinematics.mass_matrix(model, q)
    dvdot_du = lin.B[model.nv:]
    np.testing.assert_allclose(dvdot_du, np.linalg.solve(M, model.input_map), rtol=1e-10, atol=1e-12)
    assert not np.allclose(dvdot_du, np.linalg.solve(kinematics.mass_matrix(without_armature(model), q),
                                                     model.input_map), rtol=1e-3)


# --------------------------------------------------------------------------------------------- closed forms


def _hand_double_pendulum(t, td, u, m1, m2, l1, l2, g, a1, a2):
    """The double pendulum with rotors on its joints, by hand: T = 1/2 (m1 + m2) l1^2 t1d^2 + 1/2 m2 l2^2 (t1d +
    t2d)^2 + m2 l1 l2 cos t2 t1d (t1d + t2d) + 1/2 a1 t1d^2 + 1/2 a2 t2d^2 (the rotors turn at the relative rates),
    V = -g ((m1 + m2) l1 cos t1 + m2 l2 cos(t1 + t2)); Lagrange's equations solved for the accelerations."""
    c2, s2 = np.cos(t[1]), np.sin(t[1])
    M = np.array([[(m1 + m2) * l1**2 + m2 * l2**2 + 2 * m2 * l1 * l2 * c2 + a1, m2 * l2**2 + m2 * l1 * l2 * c2],
                  [m2 * l2**2 + m2 * l1 * l2 * c2, m2 * l2**2 + a2]])
    h = m2 * l1 * l2 * s2
    Cqd = np.array([-h * (2 * td[0] * td[1] + td[1] ** 2), h * td[0] ** 2])
    grav = g * np.array([(m1 + m2) * l1 * np.sin(t[0]) + m2 * l2 * np.sin(t[0] + t[1]), m2 * l2 * np.sin(t[0] + t[1])])
    return np.linalg.solve(M, -Cqd - grav), np.linalg.solve(M, u), M


def test_the_double_pendulums_closed_form_adds_the_armature_as_the_hand_formula_does():
    params = dict(m1=1.3, m2=0.7, l1=0.9, l2=1.1, g=9.81, a1=0.4, a2=0.15)
    model = cases.load("double_pendulum", **params)
    assert model.armature_vector.tolist() == [0.4, 0.15]
    t, td, u = np.array([0.6, -1.1]), np.array([1.4, -0.8]), np.array([0.5, -1.5])
    drift, ctrl, M = _hand_double_pendulum(t, td, u, **params)
    voter = closed_forms.voter("double_pendulum", params)
    s = voter.split(model, t, td, u)
    np.testing.assert_allclose(s.drift, drift, rtol=1e-13)
    np.testing.assert_allclose(s.ctrl, ctrl, rtol=1e-13)
    assert s.kinetic_energy == pytest.approx(0.5 * td @ M @ td, rel=1e-14)
    for name in formalisms.names():
        np.testing.assert_allclose(formalisms.get(name).split(model, t, td, u).drift, drift, rtol=1e-10, err_msg=name)
    bare = closed_forms.voter("double_pendulum", {**params, "a1": 0.0, "a2": 0.0}).split(
        cases.load("double_pendulum", **{**params, "a1": 0.0, "a2": 0.0}), t, td, u)
    assert np.abs(bare.drift - drift).max() > 0.05                  # the armature matters at this state


def test_the_one_link_pendulums_closed_form_with_armature():
    """n = 1: (m l^2 + a) tdd = -m g l sin t + u."""
    m, l, g, a = 0.8, 1.2, 9.81, 0.35
    model = cases.load("n_link_pendulum", n=1, m=m, l=l, g=g, a=a)
    s = closed_forms.voter("n_link_pendulum", dict(n=1, m=m, l=l, g=g, a=a)).split(model, [0.7], [1.1], [0.4])
    assert s.drift[0] == pytest.approx(-m * g * l * np.sin(0.7) / (m * l**2 + a), rel=1e-14)
    assert s.ctrl[0] == pytest.approx(0.4 / (m * l**2 + a), rel=1e-14)


def test_the_acrobots_closed_form_adds_its_armature():
    model = cases.load("acrobot", a1=0.2, a2=0.05)
    q, qd, u = np.array([0.3, -0.5]), np.array([0.9, 0.2]), np.array([1.0])
    s = closed_forms.voter("acrobot", {"a1": 0.2, "a2": 0.05}).split(model, q, qd, u)
    for name in formalisms.names():
        np.testing.assert_allclose(formalisms.get(name).split(model, q, qd, u).drift, s.drift, rtol=1e-10)


def test_a_closed_form_refuses_a_model_whose_armature_is_not_its_own():
    rotor = cases.load("rotor")
    armed = with_armature(rotor, [0.1])
    with pytest.raises(ClosedFormMismatch, match=r"armature \[0.1\].*does not add to M"):
        closed_forms.voter("rotor").split(armed, [0.2], [0.3], [0.0])
    model = cases.load("double_pendulum", a1=0.3)
    with pytest.raises(ClosedFormMismatch, match=r"armature is \[0.3, 0.0\], the closed form's .* \[0.0, 0.0\]"):
        closed_forms.voter("double_pendulum").split(model, [0.2, 0.1], [0.3, 0.0], [0.0, 0.0])
    moved = frames.move_scene(model, frames.sampled(3, "double_pendulum", 1)[0])
    closed_forms.voter("double_pendulum", {"a1": 0.3}).split(moved, [0.2, 0.1], [0.3, 0.0], [0.0, 0.0])


# ------------------------------------------------------------------------------------ the Euler–Lagrange cache


def test_the_euler_lagrange_cache_never_serves_another_armature(isolated_cache):
    """Code derived for one armature is keyed by the model's digest, which holds it: a model that differs only in its
    armature gets its own entry (and its own M) on disk and in memory, also in a fresh process's view; a moved scene
    of the same model shares it."""
    q, qd = np.array([0.4, -0.3]), np.array([0.2, 0.5])
    one, other = cases.load("double_pendulum", a1=0.1), cases.load("double_pendulum", a1=0.7)
    assert el.cache_key(one) != el.cache_key(other)
    M_one = el.evaluate(one, q, qd)[0].M
    assert (isolated_cache / "euler_lagrange" / f"{el.cache_key(one)}.py").exists()
    el._compiled.cache_clear()                     # a new process: only the disk cache, which holds `one`'s code
    M_other = el.evaluate(other, q, qd)[0].M
    np.testing.assert_allclose(M_other - M_one, np.diag([0.6, 0.0]), atol=1e-14)
    assert el.cached_source(other) != el.cached_source(one)
    moved = frames.move_scene(one, frames.sampled(1, "double_pendulum", 1)[0])
    assert el.cache_key(moved) == el.cache_key(one)
    np.testing.assert_allclose(el.evaluate(moved, q, qd)[0].M, M_one, atol=1e-14)
