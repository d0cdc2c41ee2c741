"""The closed forms as the gate's voter ``closed_form`` (``crosscheck.references.closed_forms``, issue 15 item 2).

Each closed form agrees with Pinocchio and with the five formalisms at drawn parameters and states (and in moved
scenes); it is bound to its case by name and typed parameters, so a bug in a case factory or in the model language,
which moves the six others together, leaves it the outlier; and a model that is not its case is a failure of the
voter (ClosedFormMismatch), never a silent NOT COMPARED.
"""

from __future__ import annotations

import dataclasses
from itertools import product

import numpy as np
import pytest
from hypothesis import assume, given, settings
from hypothesis import strategies as st

import cases
import cases.constrained
import cases.constraints
import cases.factories
import cases.build
import cases.nonholonomic
from crosscheck import backends, cli, testing
from crosscheck.references import closed_forms
from crosscheck.references.closed_forms import constrained
from crosscheck.references.closed_forms import pendulums
from crosscheck.references.closed_forms import spatial
from crosscheck.references.pinocchio import kinematics
from crosscheck.reports import diagnosis
from crosscheck.checks import frames
from crosscheck.engine import evaluation
from crosscheck.core import sampling
from crosscheck.core import tolerance as policy
from crosscheck.core.compare import DISAGREE, suspect
from crosscheck.reports.gate_summary import read as read_report
from crosscheck.core.sampling import State

ALL = [backends.get(name) for name in backends.names()]
REFERENCE = backends.get(backends.REFERENCE_NAME)
CASES = list(closed_forms.CLOSED_FORMS)


def _floats(low: float, high: float, small: float = 0.0) -> st.SearchStrategy[float]:
    """Floats in [low, high], those below ``small`` in magnitude drawn as 0 (``crosscheck.testing``'s convention: a
    length below 1 micrometre or an angle below 1e-9 rad only probes underflow, e.g. a COM 2e-16 m off the axis)."""
    return st.floats(low, high, allow_nan=False, allow_infinity=False).map(lambda x: 0.0 if abs(x) < small else x)


MASS, LENGTH, INERTIA = _floats(0.1, 5.0), _floats(0.2, 2.0), _floats(0.01, 1.0)
GRAVITY, OFFSET = _floats(0.0, 20.0, testing.MIN_LENGTH), _floats(-0.5, 0.5, testing.MIN_LENGTH)
ANGLE = _floats(-np.pi, np.pi, testing.MIN_VALUE)


@st.composite
def _circle(draw) -> dict:
    """A circle well inside the tip's reachable annulus |l1 - l2| < r < l1 + l2, so that states can be projected."""
    l1, l2 = draw(LENGTH), draw(LENGTH)
    inner, outer = abs(l1 - l2), l1 + l2
    d = inner + (outer - inner) * draw(_floats(0.3, 0.7))
    R = min(d - inner, outer - d) * draw(_floats(0.2, 0.8))  # noqa: N806
    at = draw(ANGLE)
    return {"m1": draw(MASS), "m2": draw(MASS), "l1": l1, "l2": l2, "g": draw(GRAVITY), "xc": d * np.sin(at),
            "yc": -d * np.cos(at), "R": R}


@st.composite
def _principal(draw) -> tuple[float, float, float]:
    """Principal moments of a solid body: positive, the third between the other two's difference and sum."""
    a, b = draw(_floats(0.01, 0.1)), draw(_floats(0.01, 0.1))
    return a, b, abs(a - b) + (a + b - abs(a - b)) * draw(_floats(0.1, 0.9))


def _rotor(draw) -> dict:
    Ia, Ib, Ic = draw(_principal())  # noqa: N806
    return {"m": draw(MASS), "cx": draw(OFFSET), "cy": draw(OFFSET), "cz": draw(OFFSET), "Ia": Ia, "Ib": Ib, "Ic": Ic,
            "spin": draw(ANGLE), "tilt": draw(_floats(0.0, np.pi, testing.MIN_VALUE)), "azimuth": draw(ANGLE),
            "g": draw(GRAVITY)}


def _spherical(draw) -> dict:
    Ix, Iy, Iz = draw(_principal())  # noqa: N806
    return {"m": draw(MASS), "l": draw(LENGTH), "Ix": Ix, "Iy": Iy, "Iz": Iz, "g": draw(GRAVITY)}


def _collinear_gap(crank, coupler, rocker, ground) -> float:
    """How far the four-bar is from closing with all links collinear (a change point): the least
    |crank s1 + coupler s2 - rocker s3 - ground| over the signs; zero at the Grashof equality (e.g. 1-2-1-2). Where the
    longest link equals the sum of the others it is zero too (the loop closes only stretched)."""
    return min(abs(crank * s1 + coupler * s2 - rocker * s3 - ground) for s1, s2, s3 in product((1.0, -1.0), repeat=3))


def _four_bar(draw) -> dict:
    """Lengths whose loop closes with room to spare and never at a change point (``_collinear_gap`` above 0.1)."""
    crank, coupler, rocker, ground = lengths = [draw(LENGTH) for _ in range(4)]
    assume(2.0 * max(lengths) < sum(lengths) and _collinear_gap(*lengths) > 0.1)
    return {"crank": crank, "coupler": coupler, "rocker": rocker, "ground": ground, "m": draw(MASS),
            "g": draw(GRAVITY)}


def _slider_crank(draw) -> dict:
    """A crank that turns fully: rod > crank + |offset|."""
    crank, offset = draw(_floats(0.2, 1.0)), draw(OFFSET)
    return {"crank": crank, "rod": crank + abs(offset) + draw(_floats(0.2, 1.5)), "offset": offset,
            "m_crank": draw(MASS), "m_rod": draw(MASS), "m_slider": draw(MASS), "g": draw(GRAVITY)}


def _rail(draw) -> dict:
    """A rail crossing the tip's reachable annulus |l1 - l2| < r < l1 + l2 well inside it (tangent to neither of its
    circles): its distance from the shoulder 10-90 % of the way across, its point o anywhere along it."""
    l1, l2, incline = draw(LENGTH), draw(LENGTH), draw(ANGLE)
    distance = abs(l1 - l2) + 2.0 * min(l1, l2) * draw(_floats(0.1, 0.9))
    normal, along = constrained.rail_normal(incline), np.array([np.cos(incline), np.sin(incline)])
    x0, y0 = draw(st.sampled_from((1.0, -1.0))) * distance * normal + draw(_floats(-1.0, 1.0)) * along
    return {"m1": draw(MASS), "m2": draw(MASS), "l1": l1, "l2": l2, "g": draw(GRAVITY), "x0": float(x0),
            "y0": float(y0), "incline": incline}


def _free_body(draw) -> dict:
    """Principal moments on the triangle inequality's right side: the third between the others' difference and sum,
    10-90 % of the way (a flat body at the boundary is a different scene)."""
    I1, I2 = draw(INERTIA), draw(INERTIA)
    I3 = abs(I1 - I2) + (I1 + I2 - abs(I1 - I2)) * draw(_floats(0.1, 0.9))
    return {"m": draw(MASS), "I1": I1, "I2": I2, "I3": I3, "g": draw(st.one_of(st.just(0.0), GRAVITY))}


def _spring(draw) -> dict:
    """A tip spring anchored outside the tip's reach (at least 0.2 m beyond l1 + l2, so the spring never passes
    through its anchor, where its direction is undefined), and a body-frame wrench on link 2."""
    l1, l2, at = draw(LENGTH), draw(LENGTH), draw(ANGLE)
    distance = l1 + l2 + draw(_floats(0.2, 2.0))
    return {"m1": draw(MASS), "m2": draw(MASS), "l1": l1, "l2": l2, "g": draw(GRAVITY),
            "k": draw(_floats(0.1, 100.0)), "rest": draw(_floats(0.0, 1.0, testing.MIN_LENGTH)),
            "ax": distance * np.sin(at), "ay": -distance * np.cos(at), "bfx": draw(FORCE), "bfy": draw(FORCE),
            "couple": draw(_floats(-5.0, 5.0, testing.MIN_VALUE))}


FORCE = _floats(-20.0, 20.0, testing.MIN_VALUE)

#: Drawn typed parameters per case (within each factory's domain; see the module doc of crosscheck.references.closed_forms).
PARAMETERS = {
    "double_pendulum": st.fixed_dictionaries({"m1": MASS, "m2": MASS, "l1": LENGTH, "l2": LENGTH, "g": GRAVITY,
                                              "I1": st.one_of(st.just(0.0), INERTIA),
                                              "I2": st.one_of(st.just(0.0), INERTIA),
                                              "a1": st.one_of(st.just(0.0), INERTIA),
                                              "a2": st.one_of(st.just(0.0), INERTIA)}),
    "n_link_pendulum": st.fixed_dictionaries({"n": st.integers(1, 6), "m": MASS, "l": LENGTH, "g": GRAVITY,
                                              "a": st.one_of(st.just(0.0), INERTIA)}),
    "acrobot": st.fixed_dictionaries({"m1": MASS, "m2": MASS, "l1": LENGTH, "l2": LENGTH, "lc1": _floats(0.1, 1.5),
                                      "lc2": _floats(0.1, 1.5), "I1": INERTIA, "I2": INERTIA, "g": GRAVITY,
                                      "a1": st.one_of(st.just(0.0), INERTIA), "a2": st.one_of(st.just(0.0), INERTIA)}),
    "double_pendulum_circle": _circle(),
    "cartesian_pendulum": st.fixed_dictionaries({"m": MASS, "L": _floats(0.3, 2.0), "g": GRAVITY}),
    "double_pendulum_absolute_loop": st.fixed_dictionaries({"m1": MASS, "m2": MASS, "l1": LENGTH, "l2": LENGTH,
                                                            "g": GRAVITY, "I1": INERTIA, "I2": INERTIA}),
    "rotor": st.composite(_rotor)(),
    # (an incline of 1e-150 rad moves the mass 1e-150 m up per metre: below the backends' degenerate floor, their
    # task inertia is NaN while the closed form's, m / sin^2, is finite; it then votes alone, NOT COMPARED)
    "inclined_slider": st.fixed_dictionaries({"m": MASS, "incline": st.one_of(_floats(0.05, 1.5), _floats(-1.5, -0.05)),
                                              "azimuth": ANGLE, "g": GRAVITY}),
    "spherical_pendulum": st.composite(_spherical)(),
    "four_bar": st.composite(_four_bar)(),
    "slider_crank": st.composite(_slider_crank)(),
    "double_pendulum_rail": st.composite(_rail)(),
    "free_body": st.composite(_free_body)(),
    "knife_edge": st.fixed_dictionaries({"m": MASS, "a": st.one_of(st.just(0.0), _floats(-1.5, 1.5)), "I": INERTIA,
                                         "g": GRAVITY}),
    "rolling_disk": st.fixed_dictionaries({"m": MASS, "r": LENGTH, "g": GRAVITY}),
    "geared_pendulums": st.fixed_dictionaries({"m1": MASS, "l1": LENGTH, "m2": MASS, "l2": LENGTH,
                                               "ratio": st.one_of(_floats(-3.0, -0.3), _floats(0.3, 3.0)),
                                               "offset": ANGLE, "spacing": _floats(0.5, 3.0), "g": GRAVITY}),
    "double_pendulum_tip_force": st.fixed_dictionaries({"m1": MASS, "m2": MASS, "l1": LENGTH, "l2": LENGTH,
                                                        "g": GRAVITY, "fx": FORCE, "fy": FORCE}),
    "double_pendulum_spring": st.composite(_spring)(),
    "differential_drive": st.fixed_dictionaries({"m_body": MASS, "m_wheel": MASS, "r": _floats(0.05, 0.5),
                                                 "track": _floats(0.1, 1.0), "com_ahead": OFFSET, "g": GRAVITY,
                                                 "payload": _floats(0.0, 5.0), "drag": _floats(0.0, 10.0)}),
}


def test_every_closed_form_has_drawn_parameters():
    assert set(PARAMETERS) == set(CASES)


@pytest.mark.parametrize("case", CASES)
@settings(max_examples=10)   # each example is a new model (its own Euler–Lagrange derivation): 10 per case, 190 in all
@given(data=st.data())
def test_closed_form_agrees_with_pinocchio_and_the_formalisms(case, data):
    """At drawn parameters and admissible states: against Pinocchio alone (two voters, no vote to hide behind), then
    against the five formalisms and Pinocchio as the gate compares them, with the frame and conservation checks in a
    drawn moved scene (the voter accepts the moved model, ``case@frame``). It votes on every quantity it supplies."""
    params = data.draw(PARAMETERS[case], label="params")
    model = cases.load(case, **params)
    state = data.draw(testing.states(model), label="state")
    voter = closed_forms.voter(case, params)
    pair = evaluation.evaluate(model, state, [voter, REFERENCE])
    assert not pair.failed, testing.describe_failure(pair)
    chosen = [*ALL, voter]
    outcome = evaluation.evaluate(model, state, chosen)
    frame = data.draw(testing.frames(), label="frame")
    evaluation.add_checks(model, outcome, chosen, [], (frame, frames.move_scene(model, frame)), True)
    assert not outcome.failed, testing.describe_failure(outcome)
    broken = outcome.breakdowns.get("closed_form", {})
    assert not policy.whole(broken), broken
    for quantity in closed_forms.CLOSED_FORMS[case].supplies(cases.parameters(case, **params)):
        if quantity not in policy.left_out(broken):     # its task inertia at a task singularity, as everyone's
            assert "closed_form" in outcome.comparisons[quantity].voters, quantity


@pytest.mark.parametrize("case", CASES)
def test_closed_form_on_the_gate_states_of_the_default_case(case):
    """The default parameters at the gate's own sampled states (the home configuration q = 0 included): the closed
    form is never the outlier and never raises."""
    model = cases.load(case)
    voter = closed_forms.voter(case, {})
    for state in sampling.sample_states(model, 8, 0, case):
        outcome = evaluation.evaluate(model, state, [*ALL, voter])
        assert not outcome.failed, testing.describe_failure(outcome)


def test_the_voter_reads_parameters_not_the_model():
    """The split depends on the typed parameters alone: the model of other lengths (same name and shape) gives the
    same numbers, and CLI strings give the same split as numbers."""
    state = (np.array([0.4, -0.3]), np.array([1.0, 2.0]), np.array([0.5, -1.5]))
    bound = closed_forms.voter("double_pendulum", {"l2": "0.7", "I1": "0.1"})
    as_numbers = closed_forms.voter("double_pendulum", {"l2": 0.7, "I1": 0.1})
    right, other = cases.load("double_pendulum", l2=0.7, I1=0.1), cases.load("double_pendulum", l2=1.3)
    a, b, c = bound.split(right, *state), bound.split(other, *state), as_numbers.split(right, *state)
    for quantity in ("drift", "ctrl", "total", "task_drift", "task_inertia", "kinetic_energy"):
        assert np.array_equal(a.quantity(quantity), b.quantity(quantity)), quantity
        assert np.array_equal(a.quantity(quantity), c.quantity(quantity)), quantity


def test_double_pendulum_is_the_article_sanity_check():
    """Article 4.7.3: theta = (pi/4, pi/6), rates (2, -1), m = l = 1, g = 9.81, tau = (5, -2): drift + ctrl = total,
    and total solves eq. (2) with eqs. (6)-(8) by a dense solve."""
    q, qd, u = np.array([np.pi / 4, np.pi / 6]), np.array([2.0, -1.0]), np.array([5.0, -2.0])
    split = closed_forms.voter("double_pendulum", {}).split(cases.load("double_pendulum"), q, qd, u)
    M, Cqd, g = pendulums.pendulum_terms(q, qd)  # noqa: N806
    assert np.allclose(split.total, np.linalg.solve(M, u - Cqd - g), rtol=1e-14, atol=0)
    assert np.allclose(split.drift + split.ctrl, split.total, rtol=1e-14, atol=0)


def test_n_link_with_two_links_is_the_article_double_pendulum():
    """The absolute-angle Lagrangian (n = 2, equal masses) mapped to relative angles gives eqs. (6)-(8): two derivations
    of the same machine agree to rounding."""
    state = (np.array([0.9, -2.1]), np.array([1.5, -0.5]), np.array([2.0, 3.0]))
    chain = closed_forms.voter("n_link_pendulum", {"n": 2, "m": 1.3, "l": 0.8})
    article = closed_forms.voter("double_pendulum", {"m1": 1.3, "m2": 1.3, "l1": 0.8, "l2": 0.8})
    a = chain.split(cases.load("n_link_pendulum", n=2, m=1.3, l=0.8), *state)
    b = article.split(cases.load("double_pendulum", m1=1.3, m2=1.3, l1=0.8, l2=0.8), *state)
    for quantity in ("drift", "ctrl", "total", "task_drift", "task_inertia"):
        assert np.allclose(a.quantity(quantity), b.quantity(quantity), rtol=1e-13, atol=1e-13), quantity


# ---------------------------------------------------------------------------- closed loops, a rail and a gear


@given(m=MASS, l=LENGTH, phi=ANGLE, g=GRAVITY)
def test_one_rod_is_the_pendulum_about_its_end(m, l, phi, g):  # noqa: E741
    """The rod as three point masses (``rod_chain_terms``) has the textbook moment m l^2/3 about its end and its
    weight at mid-length: M = m l^2/3, C qd = 0, g = m g l/2 sin phi."""
    M, Cqd, grav = pendulums.rod_chain_terms([phi], [2.0], [m], [l], g)  # noqa: N806
    assert np.allclose(M, [[m * l * l / 3.0]], rtol=1e-14, atol=0)
    assert np.allclose(Cqd, 0.0, rtol=0, atol=1e-14 * m * l * l) and np.allclose(grav, [0.5 * m * g * l * np.sin(phi)],
                                                                                rtol=1e-14, atol=1e-300)


@pytest.mark.parametrize("case", [c for c in CASES if closed_forms.CLOSED_FORMS[c].rule is not None])
@given(data=st.data())
def test_the_rule_scales_typed_in_are_the_models(case, data):
    """The scales of the backends' redundancy rule, typed in from each factory, are the built model's
    ``length_scale`` and ``inertia_scale`` (what every backend's degenerate floor reads)."""
    params = data.draw(PARAMETERS[case], label="params")
    rule = closed_forms.CLOSED_FORMS[case].rule(cases.parameters(case, **params))
    model = cases.load(case, **params)
    assert rule.length == pytest.approx(model.length_scale, rel=1e-14)
    assert rule.inertia == pytest.approx(model.inertia_scale, rel=1e-14)


RATE, INPUT = _floats(-3.0, 3.0, testing.MIN_VALUE), _floats(-10.0, 10.0, testing.MIN_VALUE)


@pytest.mark.parametrize("q", [(np.pi / 2, 0.0, np.pi / 2), (-np.pi / 2, np.pi, -np.pi / 2)])
@given(rates=st.tuples(RATE, RATE, RATE), u=st.tuples(INPUT, INPUT, INPUT))
def test_four_bar_change_point_follows_the_backends_rule(q, rates, u):
    """At the default four-bar's change points (the loop Jacobian of rank 1, S singular) the closed form keeps the
    same eigen-direction of S as the backends, returns the same minimum-norm multipliers and reports the same
    conditions ("constraint" broken, "constraint_consistency" where the rates leave H_t empty): the gate, its
    conditions audit included, passes with it."""
    model = cases.load("four_bar")
    qd = sampling.project_velocity(model, q, rates)
    state = State(0, q, tuple(qd), u)
    outcome = evaluation.evaluate(model, state, [*ALL, closed_forms.voter("four_bar", {})])
    assert not outcome.failed, testing.describe_failure(outcome)
    closed, pinocchio = outcome.splits["closed_form"], outcome.splits[REFERENCE.name]
    assert closed.constraint_rank == pinocchio.constraint_rank == 1
    assert set(outcome.breakdowns["closed_form"]) == set(outcome.breakdowns[REFERENCE.name]) >= {"constraint"}
    for quantity in ("lam", "lam_drift"):          # left out of the vote here: compared directly
        assert np.allclose(closed.quantity(quantity), pinocchio.quantity(quantity), rtol=0,
                           atol=1e-12 * closed.lam_scale), quantity


def test_a_model_of_the_same_shape_is_a_mismatch_by_its_name():
    """The four-bar's voter given the slider-crank (both n = 3, m = 3, k = 2): the name alone tells them apart."""
    with pytest.raises(closed_forms.ClosedFormMismatch, match="named 'slider_crank', not 'four_bar'"):
        closed_forms.voter("four_bar", {}).split(cases.load("slider_crank"), np.zeros(3), np.zeros(3), np.zeros(3))


# ------------------------------------------------------------------------------------ injected factory bugs


def _transposed_inertia(principal, rotation):
    R = np.asarray(rotation, dtype=float)  # noqa: N806
    return R.T @ np.diag(principal) @ R


def _rotation_backwards(axis, angle):
    k = np.asarray(axis, dtype=float) / np.linalg.norm(axis)
    K = np.array([[0.0, -k[2], k[1]], [k[2], 0.0, -k[0]], [-k[1], k[0], 0.0]])  # noqa: N806
    return np.eye(3) - np.sin(angle) * K + (1.0 - np.cos(angle)) * (K @ K)


def _disk_halved(izz):
    return np.diag([izz / 2.0, izz / 2.0, izz / 2.0])


def _l2_read_from_l1(monkeypatch):
    info = cases.factories.REGISTRY["double_pendulum"]
    wrong = dataclasses.replace(info, factory=lambda **kw: info.factory(**{**kw, "l2": kw.get("l1", 1.0)}))
    monkeypatch.setitem(cases.factories.REGISTRY, "double_pendulum", wrong)


def _placement_rotation_dropped(monkeypatch):
    validate = cases.build._validate_body
    monkeypatch.setattr(cases.build, "_validate_body", lambda problems, findings, body: None if (b := validate(
        problems, findings, body)) is None else dataclasses.replace(b, rotation=np.eye(3)))


_ROD = cases.constrained._rod


def _rod_inertia_about_its_end(name, parent, mass, length, at=(0.0, 0.0, 0.0)):
    """``cases.constrained._rod`` with the moment about the rod's end, m l^2/3, for the one about its middle."""
    end = mass * length**2 / 3.0
    return dataclasses.replace(_ROD(name, parent, mass, length, at), inertia=np.diag([end, 0.0, end]))


def _validated(kind, change):
    """A bug in ``cases.constraints.validate`` (where every declaration is checked and stored): declarations of
    ``kind`` come out changed by ``change``."""
    def inject(monkeypatch):
        validate = cases.constraints.validate

        def faulty(problems, c, bodies):
            out = validate(problems, c, bodies)
            return change(out) if isinstance(out, kind) else out
        monkeypatch.setattr(cases.constraints, "validate", faulty)
    return inject


def _normal_xy_swapped(line):
    normals = line.normals[:, [1, 0, 2]]
    normals.setflags(write=False)
    return dataclasses.replace(line, normals=normals)


def _coefficients_reversed(coupling):
    return dataclasses.replace(coupling, coefficients=coupling.coefficients[::-1])


def _thin_disk_axle_on_x(mass, radius):
    """``cases.nonholonomic._thin_disk`` with the axle's moment m r^2/2 about body x, not the axle (body y)."""
    return np.diag([mass * radius**2 / 2.0, mass * radius**2 / 4.0, mass * radius**2 / 4.0])


def _radius_as_diameter(contact):
    return dataclasses.replace(contact, radius=2.0 * contact.radius)


#: name -> (how to inject it, case, parameters): each a realistic bug in shared code that all six others share.
FACTORY_BUGS = {
    "factory inertia R^T diag R": (lambda mp: mp.setattr(cases.factories, "_inertia", _transposed_inertia),
                                   "rotor", {}),
    "Rodrigues with the sine's sign flipped": (lambda mp: mp.setattr(cases.factories, "_rot", _rotation_backwards),
                                               "inclined_slider", {}),
    "planar disk with izz / 2 about z": (lambda mp: mp.setattr(cases.factories, "planar_disk", _disk_halved),
                                         "double_pendulum", {"I1": 0.2, "I2": 0.3}),
    "l2 read from l1": (_l2_read_from_l1, "double_pendulum", {"l1": 1.0, "l2": 0.6}),
    "model language drops placement rotations": (_placement_rotation_dropped, "inclined_slider", {}),
    "rod inertia m l^2/3 (four-bar)": (lambda mp: mp.setattr(cases.constrained, "_rod", _rod_inertia_about_its_end),
                                       "four_bar", {}),
    "rod inertia m l^2/3 (slider-crank)": (
        lambda mp: mp.setattr(cases.constrained, "_rod", _rod_inertia_about_its_end), "slider_crank", {}),
    "rod inertia m l^2/3 (gear)": (lambda mp: mp.setattr(cases.constrained, "_rod", _rod_inertia_about_its_end),
                                   "geared_pendulums", {}),
    "line normal stored with x and y swapped": (_validated(cases.PointOnLine, _normal_xy_swapped),
                                                "double_pendulum_rail", {}),
    "coupling coefficients stored reversed": (_validated(cases.JointCoupling, _coefficients_reversed),
                                              "geared_pendulums", {}),
    "thin disk with the axle's moment about x": (
        lambda mp: mp.setattr(cases.nonholonomic, "_thin_disk", _thin_disk_axle_on_x), "rolling_disk", {}),
    "rolling contact's radius stored as the diameter": (_validated(cases.RollingContact, _radius_as_diameter),
                                                        "rolling_disk", {"r": 0.3}),
}


@pytest.mark.parametrize("bug", FACTORY_BUGS)
def test_a_factory_bug_makes_the_closed_form_the_outlier(bug, monkeypatch):
    """With the bug injected every backend and Pinocchio agree on the wrong model; the closed form, computed from the
    typed parameters, disagrees, and every disagreement points at it (``compare.suspect``)."""
    inject, case, params = FACTORY_BUGS[bug]
    inject(monkeypatch)
    model = cases.load(case, **params)
    voter = closed_forms.voter(case, params)
    outcomes = [evaluation.evaluate(model, state, [*ALL, voter]) for state in sampling.sample_states(model, 3, 0, case)]
    disagreements = [c for o in outcomes for c in o.comparisons.values() if c.verdict == DISAGREE]
    assert {c.quantity for c in disagreements} >= {"drift", "total"}, bug
    assert all(c.outlier == "closed_form" and suspect(c) == "closed_form" for c in disagreements), bug
    failed = next(o for o in outcomes if o.failed)
    assert "suspect code they all share" in diagnosis.hint(model, failed, [*ALL, voter]), bug


def test_without_the_bug_the_same_states_agree():
    """The control for the test above: the same cases and parameters, no bug, no disagreement."""
    for _, case, params in FACTORY_BUGS.values():
        model = cases.load(case, **params)
        voter = closed_forms.voter(case, params)
        for state in sampling.sample_states(model, 3, 0, case):
            assert not evaluation.evaluate(model, state, [*ALL, voter]).failed


# ------------------------------------------------------------------------------------------------ mismatches

STATE = State(0, (0.3, -0.2), (1.0, 0.5), (2.0,))


def test_another_cases_model_is_a_mismatch():
    """The double pendulum's voter given the acrobot: the name and the number of inputs do not match."""
    voter = closed_forms.voter("double_pendulum", {})
    with pytest.raises(closed_forms.ClosedFormMismatch) as info:
        voter.split(cases.load("acrobot"), STATE.q, STATE.qd, STATE.u)
    message = str(info.value)
    assert "'double_pendulum'" in message and "named 'acrobot'" in message
    assert "the number of inputs m is 1, the closed form's is 2" in message
    assert "m1=1.0" in message                           # the parameters it was bound to


def test_parameters_that_do_not_give_the_models_shape_are_a_mismatch():
    voter = closed_forms.voter("n_link_pendulum", {"n": "3"})
    model = cases.load("n_link_pendulum", n=4)
    with pytest.raises(closed_forms.ClosedFormMismatch, match=r"n=3.*coordinates n is 4, the closed form's is 3"):
        voter.split(model, np.zeros(4), np.zeros(4), np.zeros(4))


def test_a_mismatch_fails_the_gate_as_an_error_of_the_voter():
    """In the gate a mismatch is the voter's error at the state: the state fails, it is not NOT COMPARED."""
    model = cases.load("double_pendulum_circle")
    state = sampling.sample_states(model, 2, 0, "double_pendulum_circle")[1]
    outcome = evaluation.evaluate(model, state, [*ALL, closed_forms.voter("double_pendulum", {})])
    assert outcome.failed and outcome.errors["closed_form"].startswith("ClosedFormMismatch: ")
    assert "constraint rows k is 1, the closed form's is 0" in outcome.errors["closed_form"]


def test_cases_without_a_closed_form_have_no_voter():
    assert closed_forms.voter("spatial_arm", {}) is None
    assert closed_forms.coverage("spatial_arm", {}).startswith("none (closed forms exist for double_pendulum, ")
    assert set(CASES) <= set(cases.names())


@pytest.mark.parametrize("case, file", [("panda", "example-robot-data's panda_description/urdf/panda.urdf"),
                                        ("urdf_gripper", "cases/files/gripper.urdf, shipped with crosscheck"),
                                        ("mjcf_floating", "cases/files/floating.xml, shipped with crosscheck"),
                                        ("mjcf_ball_slide", "cases/files/ball_slide.xml, shipped with crosscheck")])
def test_a_case_loaded_from_a_file_has_no_voter_and_says_its_reference_reads_the_file(case, file):
    assert closed_forms.voter(case, {}) is None and case not in CASES
    assert closed_forms.coverage(case, {}) == (f"none (loaded from the model file {file}; its reference is built "
                                               "from the file)")


def test_unknown_parameters_are_refused_when_binding():
    with pytest.raises(cases.CaseError, match="no parameter"):
        closed_forms.voter("rotor", {"mass": 2.0})


def test_coverage_names_the_source_the_parameters_and_the_quantities():
    line = closed_forms.coverage("double_pendulum_circle", {"R": "0.4"})
    assert line.startswith("article 5.6")
    assert "bound to m1=1.0, m2=1.0, l1=1.0, l2=1.0, g=9.81, xc=1.0, yc=-1.0, R=0.4;" in line
    assert "lam_drift" in line and "not the joint loads" in line
    assert "lam" not in closed_forms.coverage("rotor", {})


# ------------------------------------------------------------------------------------------------- new cases


@pytest.mark.parametrize("case", ["rotor", "inclined_slider", "spherical_pendulum", "double_pendulum_rail",
                                  "geared_pendulums"])
def test_new_cases_build_with_their_parameters(case):
    params = cases.parameters(case)
    model = cases.load(case, **params)
    assert (model.n, model.m, model.k) == closed_forms.CLOSED_FORMS[case].shape(params)
    assert case in {c.name for c in cases.catalog()}


def test_the_rail_and_gear_factories_refuse_what_cannot_hold():
    """A rail beyond the tip's reach has no admissible configuration; a gear of ratio 0 is no gear."""
    with pytest.raises(cases.CaseError, match="beyond the tip's reach"):
        cases.load("double_pendulum_rail", y0=-2.5, incline=0.0)
    with pytest.raises(cases.CaseError, match="ratio must be finite and non-zero"):
        cases.load("geared_pendulums", ratio=0.0)
    rail, gear = cases.load("double_pendulum_rail").constraints[0], cases.load("geared_pendulums").constraints[0]
    assert isinstance(rail, cases.PointOnLine) and np.allclose(rail.normals, [[-np.sin(0.3), np.cos(0.3), 0.0]])
    assert isinstance(gear, cases.JointCoupling) and gear.coefficients == (1.0, 2.0)


def test_rotor_is_three_dimensional():
    """The rotor's inertia has off-diagonal terms and its axis is tilted (what makes the injected bugs visible)."""
    body = cases.load("rotor").bodies[0]
    assert np.abs(body.inertia - np.diag(np.diag(body.inertia))).max() > 1e-3
    assert 0.1 < abs(body.axis[2]) < 0.99


def test_pinocchio_agrees_with_the_rotor_closed_form_mass_matrix():
    """M of the rotor by hand against Pinocchio's CRBA, at several parameter sets (the gate compares accelerations)."""
    for params in ({}, {"tilt": 1.2, "spin": -2.0, "cx": -0.4}, {"tilt": 0.0, "Ia": 0.09, "Ib": 0.02, "Ic": 0.1}):
        typed = cases.parameters("rotor", **params)
        M = spatial.rotor_terms([0.3], [0.0], *(typed[k] for k in ("m", "cx", "cy", "cz", "Ia", "Ib", "Ic", "spin",
                                                                      "tilt", "azimuth", "g")))[0]  # noqa: N806
        assert np.allclose(M, kinematics.mass_matrix(cases.load("rotor", **params), [0.3]), rtol=1e-14, atol=0)


def test_gate_on_the_new_cases_passes(tmp_path):
    report = tmp_path / "new.md"
    code = cli.main(["gate", "--case", "rotor", "--case", "inclined_slider", "--case", "spherical_pendulum",
                     "--samples", "10", "--report", str(report)])
    assert code == 0 and "**PASS**" in report.read_text()


def test_gate_with_the_loops_rail_and_gear_closed_forms_passes(tmp_path):
    """The closed forms of the constrained cases without one before (four_bar, slider_crank) and of the two cases that
    use ``PointOnLine`` and ``JointCoupling`` vote in the gate, which passes."""
    report = tmp_path / "loops.md"
    names = ("four_bar", "slider_crank", "double_pendulum_rail", "geared_pendulums")
    code = cli.main(["gate", *(a for case in names for a in ("--case", case)), "--samples", "10", "--no-self-test",
                     "--report", str(report)])
    text = read_report(report)      # the summary and its details file
    assert code == 0 and "**PASS**" in text
    assert all(f"- {case}: closed form: " in text for case in names)


def test_case_parameters_are_typed_with_the_defaults_merged():
    """``cases.parameters``, what the voter is bound to: CLI strings converted by the defaults' types, as ``load``."""
    assert cases.parameters("n_link_pendulum", n="3", l="0.5") == {"n": 3, "m": 1.0, "l": 0.5, "g": 9.81, "a": 0.0}
    assert cases.parameters("cartesian_pendulum") == {"m": 1.0, "L": 1.0, "g": 9.81}
    with pytest.raises(cases.CaseError, match="not a valid int"):
        cases.parameters("n_link_pendulum", n="2.5")
    with pytest.raises(cases.CaseError, match="unknown case"):
        cases.parameters("no_such_case")
