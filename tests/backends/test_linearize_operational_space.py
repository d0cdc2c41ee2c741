"""The operational-space backend's linearization (article 4.8, eq. 11: forward-mode tangents through its own
kinematics, Kane projection and constraint rows, the KKT system differentiated) and its drift's parts (4.5-4.6:
``zvcf``, ``drift_velocity``), held against references outside the backend: Pinocchio's ABA derivatives
(``crosscheck.references.pinocchio.reference.linearize``) on unconstrained models; on constrained ones, central differences of the
60-digit KKT solution (``crosscheck.references.precise``), whose truncation (h^2 = 1e-40) and rounding (1e-60 / h) are far
below double precision, so the differences are exact to double."""

from __future__ import annotations

import mpmath
import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st
from mpmath import mpf

import cases
import formalisms
from cases.configuration import quaternion_product, random_configuration, rotation
from cases.constraints import PointsCoincide
from cases.build import build_model
from crosscheck.references import precise
from crosscheck.references.pinocchio import kinematics
from crosscheck.references.pinocchio import reference
from crosscheck.core import sampling
from crosscheck import testing
from formalisms import operational_space
from formalisms.interface import StateError, tangent_kinematics

#: The issue's "done when": A and B agree with the reference to this, relative to each block's largest entry.
RTOL = 1e-8


def _state(model, seed):
    """A random state (``random_configuration``, rates and inputs N(0, 1)); a constrained model's projected onto its
    manifold and tangent space (``crosscheck.core.sampling``), the states the harness evaluates."""
    rng = np.random.default_rng(seed)
    q, v, u = random_configuration(model, rng, 1.0, 0.3), rng.normal(size=model.nv), rng.normal(size=model.m)
    if model.constraints:
        q = sampling.project_configuration(model, q)
        v = sampling.project_velocity(model, q, v)
    return q, v, u


def _blocks(model, lin):
    """``(dvdot/dq, dvdot/dv, dvdot/du)`` from a :class:`Linearization`."""
    nv = model.nv
    return lin.A[nv:, :nv], lin.A[nv:, nv:], lin.B[nv:]


def _assert_blocks_close(model, got, want):
    """Each block within RTOL of its largest reference entry (a block that is zero in the reference, e.g. a free
    body's dvdot/dq, against the largest entry of all blocks)."""
    scale = max(np.abs(w).max(initial=0.0) for w in want)
    for label, g, w in zip(("dvdot/dq", "dvdot/dv", "dvdot/du"), got, want):
        error = np.abs(g - w).max(initial=0.0)
        assert error <= RTOL * max(np.abs(w).max(initial=0.0), 1e-3 * scale), (model.name, label, error)


def _ambient_directions(model, q):
    """``d/ds integrate(q, s e_j)`` at ``s = 0`` (nv, nq), from ``cases.configuration``: 1 at a one-number joint's
    coordinate; ``quat (x) (e, 0) / 2`` on a quaternion; ``R(quat) e`` on a free joint's position."""
    T = np.zeros((model.nv, model.nq))
    for i, body in enumerate(model.bodies):
        k, j = model.v_index[i], model.q_index[i]
        if body.joint not in ("spherical", "free"):
            T[k, j] = 1.0
            continue
        free = 3 if body.joint == "free" else 0
        quat = q[j + free:j + free + 4]
        for a, e in enumerate(np.eye(3)):
            T[k + free + a, j + free:j + free + 4] = 0.5 * quaternion_product(quat, np.append(e, 0.0))
            if free:
                T[k + a, j:j + 3] = rotation(quat) @ e
    return T


def _precise_derivatives(model, q, v, u, digits=60, h="1e-20"):
    """Central differences of the precise total acceleration (a test's tool) along the ``2 nv + m`` directions:
    configurations along :func:`_ambient_directions` (the precise split normalizes a
    quaternion before use, so the line ``q + s T_j`` has the derivative of ``integrate(q, s e_j)``), velocities,
    inputs. Returns (nv, len(columns))."""
    nv = model.nv
    T = _ambient_directions(model, q)
    with mpmath.workdps(digits):
        H = mpf(h)
        x = [[mpf(float(a)) for a in vec] for vec in (q, v, u)]
        B = [[mpf(float(b)) for b in row] for row in model.input_map]

        def total(qq, vv, uu):
            tau = [sum(b * a for b, a in zip(row, uu)) for row in B]
            return np.array(precise._split(model, qq, vv, tau, digits).total, dtype=object)

        def moved(sign, col):
            out = [list(a) for a in x]
            if col < nv:
                out[0] = [a + sign * H * mpf(float(t)) for a, t in zip(out[0], T[col])]
            else:
                part, k = (1, col - nv) if col < 2 * nv else (2, col - 2 * nv)
                out[part][k] += sign * H
            return out

        cols = [(total(*moved(1, col)) - total(*moved(-1, col))) / (2 * H) for col in range(2 * nv + model.m)]
        return np.array([[float(a) for a in c] for c in cols]).T


@pytest.mark.parametrize("name", ["spatial_arm", "double_pendulum", "free_body", "solo12", "ball_double_pendulum",
                                  "satellite_arm"])
def test_linearize_matches_pinocchio_aba_derivatives(name):
    model = cases.load(name)
    for seed in (1, 2):
        q, v, u = _state(model, seed)
        lin = operational_space.linearize(model, q, v, u)
        ref = reference.linearize(model, q, v, u)
        _assert_blocks_close(model, _blocks(model, lin), _blocks(model, ref))
        np.testing.assert_allclose(lin.vdot, ref.vdot, rtol=0, atol=1e-10 * np.abs(ref.vdot).max())
        np.testing.assert_array_equal(lin.A[:model.nv, :model.nv], tangent_kinematics(model, v))
        np.testing.assert_array_equal(lin.A[:model.nv, model.nv:], np.eye(model.nv))
        np.testing.assert_array_equal(lin.B[:model.nv], 0.0)


@pytest.mark.parametrize("name", ["four_bar", "slider_crank", "panda"])
def test_constrained_linearize_matches_the_differentiated_precise_kkt_solution(name):
    """With constraints (four_bar, slider_crank: loop closures; panda: the finger mimic coupling) against central
    differences of the 60-digit KKT solution."""
    model = cases.load(name)
    q, v, u = _state(model, 3)
    lin = operational_space.linearize(model, q, v, u)
    want = _precise_derivatives(model, q, v, u)
    nv = model.nv
    _assert_blocks_close(model, _blocks(model, lin), (want[:, :nv], want[:, nv:2 * nv], want[:, 2 * nv:]))
    total = reference.split(model, q, v, u).total
    np.testing.assert_allclose(lin.vdot, total, rtol=0, atol=1e-10 * np.abs(total).max())


@settings(max_examples=12, deadline=None, suppress_health_check=[HealthCheck.too_slow, HealthCheck.filter_too_much])
@given(st.data())
def test_linearize_on_drawn_models(data):
    """Random trees (revolute, prismatic, spherical, free joints) against Pinocchio's ABA derivatives."""
    model = data.draw(testing.models(max_bodies=4, group=True))
    state = data.draw(testing.states(model))
    q, v, u = (np.array(x) for x in (state.q, state.qd, state.u))
    lin = operational_space.linearize(model, q, v, u)
    _assert_blocks_close(model, _blocks(model, lin), _blocks(model, reference.linearize(model, q, v, u)))


@settings(max_examples=6, deadline=None, suppress_health_check=[HealthCheck.too_slow, HealthCheck.filter_too_much])
@given(st.data())
def test_linearize_on_drawn_constrained_models(data):
    """Random constrained trees (couplings, coinciding points, circles, lines; spherical and free joints too) against
    the precise KKT solution differentiated; a state where S is not regular (a redundant row: the derivative holds only where the rank is
    locally constant) is skipped by the condition it reports."""
    model = data.draw(testing.models(max_bodies=3, constraints=True, group=True))
    state = data.draw(testing.states(model))
    q, v, u = (np.array(x) for x in (state.q, state.qd, state.u))
    split = operational_space.split(model, q, v, u)
    if split.constraint_rank < model.k or split.conditions["constraint"] > 1e6:
        return
    got = _blocks(model, operational_space.linearize(model, q, v, u))
    want = _precise_derivatives(model, q, v, u)
    nv = model.nv
    _assert_blocks_close(model, got, (want[:, :nv], want[:, nv:2 * nv], want[:, 2 * nv:]))


def test_linearize_is_registered_and_checks_its_state():
    model = cases.load("double_pendulum")
    assert formalisms.get("operational_space").linearize is operational_space.linearize
    with pytest.raises(StateError, match="q has 3 entries"):
        operational_space.linearize(model, np.zeros(3), np.zeros(2), np.zeros(model.m))
    with pytest.raises(StateError, match="non-finite"):
        operational_space.linearize(model, np.zeros(2), np.array([0.0, np.nan]), np.zeros(model.m))


@pytest.mark.parametrize("name", ["spatial_arm", "solo12", "ball_double_pendulum", "satellite_arm"])
def test_drift_parts_match_the_reference_joint_space_terms(name):
    """``zvcf = -M^-1 g`` and ``drift_velocity = -M^-1 C qd`` against Pinocchio's M, C qd and g; they add up to
    the drift."""
    model = cases.load(name)
    q, v, u = _state(model, 4)
    s = operational_space.split(model, q, v, u)
    M = kinematics.mass_matrix(model, q)
    Cqd, g = kinematics.bias_forces(model, q, v)
    zvcf, velocity = -np.linalg.solve(M, g), -np.linalg.solve(M, Cqd)
    scale = np.abs(s.drift).max()
    np.testing.assert_allclose(s.zvcf, zvcf, rtol=0, atol=1e-11 * max(np.abs(zvcf).max(), scale))
    np.testing.assert_allclose(s.drift_velocity, velocity, rtol=0, atol=1e-11 * max(np.abs(velocity).max(), scale))
    assert np.abs(s.drift_parts).max() <= 1e-13 * scale


@pytest.mark.parametrize("name", ["panda", "four_bar", "slider_crank"])
def test_constrained_drift_parts_match_the_reference_kkt_solutions(name):
    """With constraints: ``zvcf`` is the reference's drift at ``qd = 0`` (the KKT solve with ``-g``, no bias);
    ``drift_velocity`` the reference's drift less it; the parts add up to the drift; the block form returns them
    bit for bit."""
    model = cases.load(name)
    q, v, u = _state(model, 5)
    s = operational_space.split(model, q, v, u)
    zvcf = reference.split(model, q, np.zeros(model.nv), u).drift
    velocity = reference.split(model, q, v, u).drift - zvcf
    scale = max(np.abs(s.drift).max(), np.abs(zvcf).max())
    np.testing.assert_allclose(s.zvcf, zvcf, rtol=0, atol=1e-10 * scale)
    np.testing.assert_allclose(s.drift_velocity, velocity, rtol=0, atol=1e-10 * scale)
    assert np.abs(s.drift_parts).max() <= 1e-13 * scale
    many = operational_space.split_many(model, np.array([q, q]), np.array([v, v]), np.array([u, u]))
    for other in many:
        np.testing.assert_array_equal(other.zvcf, s.zvcf)
        np.testing.assert_array_equal(other.drift_velocity, s.drift_velocity)


def test_constrained_linearize_with_redundant_rows():
    """The four-bar's loop closure declared again along z (a row that vanishes in the plane) and x (a duplicate):
    rank 2 of 4 rows, ``S`` singular. The accelerations and their derivatives stay unique (the rank is constant
    nearby) and agree with the precise KKT solution differentiated, whose multipliers follow the same minimum-norm
    rule."""
    base = cases.load("four_bar")
    loop = base.constraints[0]
    again = PointsCoincide(loop.name + "_again", loop.body_a, loop.offset_a, loop.body_b, loop.offset_b,
                           np.array([[0.0, 0.0, 1.0], [1.0, 0.0, 0.0]]))
    model = build_model("four_bar_redundant", base.bodies, gravity=base.gravity, input_map=base.input_map,
                        task_points=base.task_points, constraints=[*base.constraints, again])
    q, v, u = _state(model, 6)
    assert operational_space.split(model, q, v, u).constraint_rank == 2
    want = _precise_derivatives(model, q, v, u)
    nv = model.nv
    _assert_blocks_close(model, _blocks(model, operational_space.linearize(model, q, v, u)),
                         (want[:, :nv], want[:, nv:2 * nv], want[:, 2 * nv:]))
