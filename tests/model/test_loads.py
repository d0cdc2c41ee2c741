"""External loads (issue 21 item 1; article 2.3, eq. 12-14): the declarations, their validation, digest, serialization
and the moved scene."""

import json

import numpy as np
import pytest

import cases
from cases import loads as load_decl
from cases.model import ModelError
from cases.build import build_model
from cases.serialize import model_from_dict, model_to_dict
from crosscheck.checks import frames


def _pendulum(loads):
    base = cases.load("double_pendulum")
    return build_model("loaded", base.bodies, base.gravity, base.input_map, base.task_points, loads=loads)


LOADS = [cases.ExternalForce("push", "link2", (1.0, 0.0, 0.0), (0.5, -2.0, 0.0)),
         cases.ExternalWrench("wind", "link1", (0.3, 0.1, 0.0), (1.0, 0.5, 0.0), (0.0, 0.0, 0.7), "body"),
         cases.PointSpring("spring", "link2", (0.5, 0.0, 0.0), (1.0, -1.0, 0.0), 12.0, 0.4)]


def test_a_model_without_loads_keeps_its_digest_and_its_dict():
    plain = cases.load("double_pendulum")
    assert plain.loads == ()
    assert _pendulum(()).digest() == plain.digest()
    assert "loads" not in model_to_dict(plain)


def test_loads_are_in_the_digest_and_survive_serialization_bit_for_bit():
    model = _pendulum(LOADS)
    assert model.digest() != cases.load("double_pendulum").digest()
    again = model_from_dict(json.loads(json.dumps(model_to_dict(model))))
    assert again.digest() == model.digest()
    assert [type(x).__name__ for x in again.loads] == ["ExternalForce", "ExternalWrench", "PointSpring"]
    assert again.loads[1].frame == "body" and again.loads[2].rest_length == 0.4
    tweaked = _pendulum(LOADS[:2] + [cases.PointSpring("spring", "link2", (0.5, 0.0, 0.0), (1.0, -1.0, 0.0),
                                                       12.0 * (1 + 2e-16), 0.4)])
    assert tweaked.digest() != model.digest()


@pytest.mark.parametrize("load, words", [
    (cases.ExternalForce("f", "link9", (0, 0, 0), (1, 0, 0)), "unknown body 'link9'"),
    (cases.ExternalForce("f", "link1", (0, 0, 0), (np.nan, 0, 0)), "non-finite"),
    (cases.ExternalForce("f", "link1", (0, 0, 0), (1, 0, 0), "tool"), "frame 'tool'; valid frames"),
    (cases.ExternalWrench("w", "link1", (0, 0, 0), (1, 0, 0), (0, 0)), "moment has shape (2,)"),
    (cases.PointSpring("s", "link1", (0, 0, 0), (0, 0, 0), -3.0), "negative stiffness"),
    (cases.PointSpring("s", "link1", (0, 0, 0), (0, 0, 0), 3.0, -0.1), "negative rest length"),
    ("a force", "is not a load declaration"),
])
def test_bad_loads_are_refused_with_the_reason(load, words):
    with pytest.raises(ModelError) as err:
        _pendulum([load])
    assert words in str(err.value)


def test_repeated_load_names_are_refused():
    with pytest.raises(ModelError, match="load names repeat"):
        _pendulum([LOADS[0], LOADS[0]])


def test_the_moved_scene_moves_world_loads_and_keeps_body_loads():
    frame = frames.Frame("g", frames.random_rotation(np.random.default_rng(3)), np.array([0.2, -0.4, 0.9]))
    moved = frames.move_scene(_pendulum(LOADS), frame).loads
    R, t = frame.rotation, frame.translation
    np.testing.assert_array_equal(moved[0].force, R @ LOADS[0].force)
    np.testing.assert_array_equal(moved[0].offset, LOADS[0].offset)
    assert load_decl.digest_bytes(moved[1]) == load_decl.digest_bytes(_pendulum(LOADS).loads[1])   # body frame
    np.testing.assert_allclose(moved[2].anchor, R @ np.array(LOADS[2].anchor) + t, rtol=0, atol=1e-15)


def test_the_spring_potential():
    spring = LOADS[2]
    assert spring.potential(1.4) == pytest.approx(0.5 * 12.0 * 1.0**2)
    assert spring.potential(0.4) == 0.0


# ------------------------------------------------------------------------------------------ the backends

from cases import configuration  # noqa: E402
from crosscheck.engine import evaluation
from crosscheck.references import precise
from crosscheck.references.pinocchio import reference
from crosscheck import testing
from crosscheck.faults.injection import default_backends  # noqa: E402
from crosscheck.core.sampling import sample_states  # noqa: E402


def _loaded(name: str) -> cases.Model:
    """A built-in model with one load of each kind and frame on its first and last bodies (3-D offsets and vectors)."""
    base = cases.load(name)
    first, last = base.bodies[0].name, base.bodies[-1].name
    loads = [cases.ExternalForce("push", last, (0.3, 0.1, 0.05), (0.5, -2.0, 0.3)),
             cases.ExternalForce("carried", last, (0.2, 0.0, 0.1), (0.5, 1.0, 0.3), "body"),
             cases.ExternalWrench("wind", first, (0.3, 0.1, 0.0), (1.0, 0.5, 0.2), (0.1, -0.2, 0.7), "body"),
             cases.ExternalWrench("gust", last, (0.1, -0.2, 0.0), (0.3, 0.5, -0.2), (0.4, 0.2, -0.1), "world"),
             cases.PointSpring("spring", last, (0.5, 0.0, 0.0), (1.0, -1.0, 0.2), 12.0, 0.4)]
    return build_model(f"{name}_loaded", base.bodies, base.gravity, base.input_map, base.task_points,
                       base.constraints, loads=loads)


def _virtual_work(model, q, step=1e-6) -> np.ndarray:
    """``tau_ext_j = sum f . dx/dq_j + m . w_j`` by central differences of the poses (``cases.configuration``) along
    ``q (+) h e_j``, the loads' definitions (``cases.loads``) typed in here: no backend's code."""
    def at(qq):
        poses = configuration.poses(model, qq)
        out = []
        for load in model.loads:
            R, o = poses[model.body_index(load.body)]
            out.append((R, o + R @ load.offset))
        return out
    base = at(q)
    tau = np.zeros(model.nv)
    for j in range(model.nv):
        e = np.zeros(model.nv)
        e[j] = step
        plus, minus = at(configuration.integrate(model, q, e)), at(configuration.integrate(model, q, -e))
        for load, (R, x), (Rp, xp), (Rm, xm) in zip(model.loads, base, plus, minus):
            dx = (xp - xm) / (2 * step)
            if isinstance(load, cases.PointSpring):
                d = x - load.anchor
                f = -load.stiffness * (np.linalg.norm(d) - load.rest_length) * d / np.linalg.norm(d)
            else:
                f = load.force if load.frame == "world" else R @ load.force
            tau[j] += f @ dx
            if isinstance(load, cases.ExternalWrench):
                S = (Rp - Rm) / (2 * step) @ R.T                    # [w_j]x: the turn per unit q_j
                m = load.moment if load.frame == "world" else R @ load.moment
                tau[j] += m @ np.array([S[2, 1], S[0, 2], S[1, 0]])
    return tau


@pytest.mark.parametrize("name", ["spatial_arm", "ball_double_pendulum"])
def test_the_reference_tau_ext_is_the_virtual_work_of_the_loads(name):
    model = _loaded(name)
    for state in sample_states(model, 3, 0, name):
        expected = _virtual_work(model, np.array(state.q))
        got = reference.split(model, state.q, state.qd, state.u).external_force
        np.testing.assert_allclose(got, expected, rtol=0, atol=1e-7 * np.abs(expected).max())


@pytest.mark.parametrize("name", ["spatial_arm", "ball_double_pendulum", "four_bar"])
def test_every_backend_maps_every_load_and_the_gate_agrees(name):
    """All five backends and Pinocchio, with every kind of load on a 3-D arm, a ball chain and a closed loop: the gate's
    comparisons (tau_ext, its power, the drift and its part at rest, the joint loads ...) agree at each state, and so
    do the frame checks in a moved scene (world loads moved with it) and the energy balance with P_ext."""
    from crosscheck.checks import frames as frame_tools

    model = _loaded(name)
    backends = default_backends()
    frame = frame_tools.sampled(0, name, 1)[0]
    scene = (frame, frame_tools.move_scene(model, frame))
    for state in sample_states(model, 2, 1, name):
        outcome = evaluation.evaluate(model, state, backends)
        evaluation.add_checks(model, outcome, backends, [], scene, True)
        assert not outcome.errors and not outcome.failed, testing.describe_failure(outcome)
        assert "frame: external_force" in outcome.checks and "conservation: energy rate at drift" in outcome.checks
        assert {"external_force", "power_ext"} <= set(outcome.comparisons)
        compared = outcome.comparisons["external_force"]
        assert compared.verdict == "agree" and len(compared.voters) == 6, compared
        assert [q for q, c in outcome.comparisons.items() if c.verdict != "agree" and c.verdict != "NOT COMPARED"] == []


def test_the_drift_at_rest_carries_the_loads_and_the_50_digit_reference_agrees():
    """zvcf is the drift at qd = 0 (the loads are velocity-independent: eq. 14 at rest), and the drift of the exact
    reference (crosscheck.references.precise) equals Pinocchio's with the loads."""
    model = _loaded("spatial_arm")
    state = sample_states(model, 1, 2, "x")[0]
    at_rest = reference.split(model, state.q, np.zeros(model.nv), np.zeros(model.m))
    moving = reference.split(model, state.q, state.qd, state.u)
    np.testing.assert_allclose(moving.zvcf, at_rest.drift, rtol=1e-12, atol=1e-12)
    exact = precise.split(model, state.q, state.qd, state.u)
    np.testing.assert_allclose(moving.drift, exact.floats("drift"), rtol=1e-10, atol=1e-10)
    without = reference.split(cases.load("spatial_arm"), state.q, state.qd, state.u)
    assert np.abs(moving.external_force).max() > 1.0 and np.abs(moving.drift - without.drift).max() > 1e-3


@pytest.mark.parametrize("name", ["double_pendulum", "four_bar"])
def test_every_linearization_differentiates_the_loads(name):
    """A and B of eq. (11) with every kind of load (world vectors turning in the body frames, a spring following its
    point): each backend's exact derivative against the 50-digit central differences (the reference Pinocchio's fext
    derivatives cannot give for world-frame loads), with the gate's tolerance."""
    from crosscheck.checks import linearization
    from crosscheck.core import tolerance

    model = _loaded(name)
    state = sample_states(model, 1, 3, name)[0]
    backends = default_backends()
    found, errors, unsupported = linearization.linearizations(model, state, backends)
    assert not errors and not unsupported and "exact" in found and len(found) == 6
    at = tolerance.scales([b.split(model, state.q, state.qd, state.u) for b in backends], model, state.q, state.qd,
                          u=state.u)
    compared = linearization.compared(model, state, found, unsupported, at)
    assert {key: c.verdict for key, c in compared.items()} == dict.fromkeys(compared, "agree")


def test_pinocchio_linearizes_body_frame_loads_and_declines_world_ones():
    """Pinocchio's ABA derivatives hold fext fixed in the joint frames: right for body-frame forces and wrenches, which
    it then linearizes (and agrees with the 50-digit reference); a world-frame force is ModelNotSupported."""
    from formalisms.interface import ModelNotSupported

    base = cases.load("spatial_arm")
    body_only = build_model("carried", base.bodies, base.gravity, base.input_map, base.task_points, loads=[
        cases.ExternalWrench("tool", base.bodies[-1].name, (0.1, 0.2, 0.0), (1.0, -2.0, 0.5), (0.3, 0.0, 0.2), "body")])
    state = sample_states(body_only, 1, 4, "x")[0]
    ours, exact = (f.linearize(body_only, state.q, state.qd, state.u) for f in (reference, precise))
    np.testing.assert_allclose(ours.A, exact.A, rtol=0, atol=1e-9 * np.abs(exact.A).max())
    with pytest.raises(ModelNotSupported, match="world-frame"):
        reference.linearize(_loaded("spatial_arm"), state.q, state.qd, state.u)


@pytest.mark.parametrize("name", ["ball_double_pendulum", "four_bar"])
def test_block_forms_and_batches_carry_the_loads(name):
    """A backend's block form gives its split bit for bit with loads too (``formalisms.interface.with_block_form``),
    and its batch the split's accelerations."""
    import formalisms
    from formalisms.interface import block_form

    model = _loaded(name)
    states = sample_states(model, 4, 5, name)
    Q, QD, U = (np.array([getattr(s, key) for s in states]) for key in ("q", "qd", "u"))
    for backend in formalisms.names():
        f = formalisms.get(backend)
        alone = [f.split(model, s.q, s.qd, s.u) for s in states]
        many = block_form(f)
        if many is not None:
            for one, blocked in zip(alone, many(model, Q, QD, U)):
                for field in ("drift", "total", "zvcf", "external_force", "joint_wrenches"):
                    assert np.asarray(getattr(one, field)).tobytes() == np.asarray(getattr(blocked, field)).tobytes()
        batch = f.split_batch(model, Q, QD, U)
        for i, one in enumerate(alone):
            np.testing.assert_allclose(batch.drift[i], one.drift, rtol=1e-12, atol=1e-12 * np.abs(one.drift).max())


def test_a_wrong_load_mapping_is_named_and_hinted():
    """A backend whose tau_ext is wrong (its moment about the body origin with the lever crossed the wrong way round)
    is the outlier on external_force, and the hint points at the loads' mapping."""
    from crosscheck.reports import diagnosis
    from crosscheck.faults import backend_catalog
    from crosscheck.faults import injection

    model = cases.load("double_pendulum_tip_force")
    backends = default_backends()
    with injection.injected(backend_catalog.get("ne-external-moment-shift-sign")):
        outcome = evaluation.evaluate(model, sample_states(model, 1, 0, "double_pendulum_tip_force")[0], backends)
        assert outcome.comparisons["external_force"].outlier == "newton_euler"
        assert "external loads' mapping" in diagnosis.hint(model, outcome, backends)
