"""Constrained dynamics in the screw backend (article 5, eq. 12-17; 6.2; 7.2: constraint wrenches, eq. 27): what only
this backend has. The references every backend shares (the cartesian pendulum's multiplier, the circle's KKT solve,
the absolute loop's accelerations, a gear, the split identities, a duplicated constraint, the four-bar at its change
point) are in ``test_constrained_backends.py``.

* the constraint wrenches: the cartesian pendulum's rod pull, a gear's couples, a duplicated circle's (the single
  one's), ``sum_i J_s,i^T W_i = Jc^T lam``, their power, their frame law (``Ad_g^-T``), and the joint wrenches with
  them applied (axis components = ``B u``);
* the absolute-coordinate double pendulum's multipliers are the joint forces of the joint model's wrench recursion;
* across formalisms, on spatial models with every declaration: the Newton–Euler backend (same ``phi``, ``Jc``,
  ``Jcdot qd``, accelerations, multipliers, and world-frame joint loads), and finite differences of ``phi``;
* the conditioning of S, computed here by another algorithm than Newton–Euler's, agrees with it (also at the
  four-bar's change point, where S is singular and ``H_t`` may be empty).
"""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

import cases
from cases.model import Body
from cases.build import build_model
from closed_forms import absolute_loop_state, circle_state
from crosscheck.checks import frames
from crosscheck.core.sampling import sample_states
from formalisms import newton_euler as ne
from formalisms import screw
from formalisms.screw import kinematics

CONSTRAINED_CASES = ("double_pendulum_circle", "four_bar", "slider_crank", "cartesian_pendulum",
                     "double_pendulum_absolute_loop")


def assert_small(value, scale, rel=1e-12, what=""):
    assert np.abs(value).max() <= rel * max(scale, 1.0), f"{what}: {np.abs(value).max():.3e} (scale {scale:.3e})"


def joint_screw_loads(model, s):
    """``B_i^T F_b,i``: the component of each joint wrench along its joint screw (the joint torque / force)."""
    axes = np.array([np.r_[b.axis, 0.0, 0.0, 0.0] if b.joint == "revolute" else np.r_[0.0, 0.0, 0.0, b.axis]
                     for b in model.bodies])
    return (np.einsum("ia,ia->i", axes, s.extras["wrenches_body"]),
            np.einsum("ia,ia->i", axes, s.extras["wrenches_body_drift"]))


def wrench_generalized_force(model, q, W):
    """``sum_i J_s,i^T W_i``: the generalized force of the space wrenches ``W`` (n, 6) on the bodies."""
    kin = kinematics.forward_kinematics(model, q)
    return sum(kinematics.space_jacobian(kin, i).T @ W[i] for i in range(model.n))


# ----------------------------------------------------------------------------------------------------------
# The constraint wrenches of the cartesian pendulum, a gear, a duplicated circle; the absolute loop's multipliers
# ----------------------------------------------------------------------------------------------------------

@pytest.mark.parametrize("m, L, angle, rate, u", [
    (1.0, 1.0, 0.3, 0.0, (0.0, 0.0)),
    (1.0, 1.0, -1.2, 2.5, (3.0, -1.0)),
    (2.5, 0.7, 2.8, -1.7, (-4.0, 6.0)),
])
def test_cartesian_pendulum_rod_pulls_on_the_bob(m, L, angle, rate, u):  # noqa: N803
    """The rod's pull on the bob, at the bob: moment p x f about the world origin, force f = 2 lam p; none on the
    massless carriage."""
    model = cases.load("cartesian_pendulum", m=m, L=L)
    p = L * np.array([np.sin(angle), -np.cos(angle)])
    v = rate * L * np.array([np.cos(angle), np.sin(angle)])
    s = screw.split(model, p, v, np.array(u))
    f = 2.0 * s.lam[0] * np.r_[p, 0.0]
    np.testing.assert_allclose(s.extras["constraint_wrenches_space"][1], np.r_[np.cross(np.r_[p, 0.0], f), f],
                               rtol=0, atol=1e-12)
    np.testing.assert_array_equal(s.extras["constraint_wrenches_space"][0], np.zeros(6))   # the carriage


@pytest.mark.parametrize("t, td, tau", [((0.3, 0.5), (0.7, -1.1), (1.0, -0.5)),
                                        ((-2.0, 1.2), (-2.5, 3.0), (0.0, 4.0))])
def test_absolute_loop_multipliers_are_the_joint_models_joint_forces(t, td, tau):
    """The multipliers are the joint forces of the joint model, in the world: shoulder, then elbow."""
    params = dict(m1=0.7, m2=1.4, l1=1.1, l2=0.6, I1=0.3, I2=0.02)
    loop = cases.load("double_pendulum_absolute_loop", **params)
    joint = cases.load("double_pendulum", **params)
    t, td, tau = (np.array(x) for x in (t, td, tau))
    q, qd = absolute_loop_state(t, td, params["l1"])
    s, ref = screw.split(loop, q, qd, tau), screw.split(joint, t, td, tau)
    np.testing.assert_allclose(s.lam, ref.extras["wrenches_space"][:, 3:5].reshape(-1), rtol=0,
                               atol=1e-12 * np.abs(s.lam).max())
    drift_forces = np.einsum("iab,ib->ia", ref.extras["poses"][:, :3, :3], ref.extras["wrenches_body_drift"][:, 3:])
    np.testing.assert_allclose(s.lam_drift, drift_forces[:, :2].reshape(-1), rtol=0,
                               atol=1e-12 * np.abs(s.lam_drift).max())


def test_joint_coupling_acts_as_a_wrench_pair():
    """The gear's torques act as a couple on each link and its opposite on the parent: the joint wrenches along
    their axes carry only the actuation, and the wrenches add up to Jc^T lam."""
    base = cases.load("double_pendulum")
    model = build_model("geared", base.bodies, gravity=base.gravity, task_points=base.task_points,
                        constraints=[cases.JointCoupling("gear", ("link1", "link2"), (1.0, -2.0), 0.1)])
    t, td, tau = np.array([0.7, 0.3]), np.array([1.4, 0.7]), np.array([2.0, -3.0])
    Jc = np.array([1.0, -2.0])
    s = screw.split(model, t, td, tau)
    lam = s.lam
    W = s.extras["constraint_wrenches_space"]
    np.testing.assert_allclose(W[:, 3:], 0.0, atol=0)                              # couples, no force
    np.testing.assert_allclose(W[:, 2], [lam[0] * (1.0 + 2.0), -2.0 * lam[0]], rtol=1e-14)
    np.testing.assert_allclose(wrench_generalized_force(model, t, W), Jc * lam[0], rtol=0, atol=1e-12)
    np.testing.assert_allclose(joint_screw_loads(model, s)[0], tau, rtol=0, atol=1e-12 * np.abs(lam).max())


def test_a_duplicated_constraint_has_the_single_ones_wrenches():
    single = cases.load("double_pendulum_circle")
    (circle,) = single.constraints
    double = build_model("circle_twice", single.bodies, gravity=single.gravity, task_points=single.task_points,
                         constraints=[circle, dataclasses.replace(circle, name="again")])
    t, td = circle_state(-0.7, -1.0, 2.0)
    tau = np.array([-1.0, 2.5])
    one, two = screw.split(single, t, td, tau), screw.split(double, t, td, tau)
    np.testing.assert_allclose(two.extras["constraint_wrenches_space"], one.extras["constraint_wrenches_space"],
                               rtol=0, atol=1e-12 * np.abs(one.extras["constraint_wrenches_space"]).max())


# ----------------------------------------------------------------------------------------------------------
# Constraint wrenches on the registered cases
# ----------------------------------------------------------------------------------------------------------

@pytest.mark.parametrize("case", CONSTRAINED_CASES)
def test_constraint_wrenches_are_the_generalized_constraint_force(case):
    """``sum_i J_s,i^T W_i = Jc^T lam`` (and at the drift), ``sum_i W_i . V_s,i = power_constr`` (0 on the
    manifold), and the joint wrenches with them applied carry ``B u`` along their screws (0 at the drift)."""
    model = cases.load(case)
    for state in sample_states(model, 3, 5, case):
        q, qd, u = (np.array(x) for x in (state.q, state.qd, state.u))
        s = screw.split(model, q, qd, u)
        scale = max(1.0, np.abs(s.constraint_force).max(), np.abs(s.constraint_force_drift).max())
        for key, force in (("constraint_wrenches_space", s.constraint_force),
                           ("constraint_wrenches_space_drift", s.constraint_force_drift)):
            np.testing.assert_allclose(wrench_generalized_force(model, q, s.extras[key]), force, rtol=0,
                                       atol=1e-12 * scale)
        power = np.einsum("ia,ia->", s.extras["constraint_wrenches_space"], s.extras["twists_space"])
        assert power == pytest.approx(s.power_constr, abs=1e-12 * scale * max(1.0, np.abs(qd).max()))
        assert_small(np.array([s.power_constr]), scale * np.abs(qd).max(), 1e-10, "power on the manifold")
        loads, loads_drift = joint_screw_loads(model, s)
        np.testing.assert_allclose(loads, model.input_map @ u, rtol=0, atol=1e-12 * scale)
        np.testing.assert_allclose(loads_drift, 0.0, rtol=0, atol=1e-12 * scale)


def test_constraint_wrenches_follow_the_frame_law():
    """Moving the scene by g: multipliers unchanged, constraint wrenches mapped by ``Ad_g^-T``."""
    model = cases.load("slider_crank")
    state = sample_states(model, 1, 2, "slider_crank")[0]
    q, qd, u = (np.array(x) for x in (state.q, state.qd, state.u))
    for frame in frames.sampled(4, "slider_crank"):
        before, after = screw.split(model, q, qd, u), screw.split(frames.move_scene(model, frame), q, qd, u)
        np.testing.assert_allclose(after.lam, before.lam, rtol=1e-11, atol=1e-11)
        for key in ("constraint_wrenches_space", "constraint_wrenches_space_drift", "wrenches_space"):
            W = before.extras[key]
            np.testing.assert_allclose(after.extras[key], W @ frames.wrench_map(frame).T, rtol=0,
                                       atol=1e-11 * np.abs(W).max(), err_msg=key)


# ----------------------------------------------------------------------------------------------------------
# Spatial models: the screw backend against Newton–Euler and finite differences
# ----------------------------------------------------------------------------------------------------------

def _unit(v):
    v = np.asarray(v, dtype=float)
    return v / np.linalg.norm(v)


def _body(name, parent, joint, axis, mass, com, translation=(0.0, 0.0, 0.0), rotation=np.eye(3)):
    return Body(name, parent, joint, _unit(axis), mass, com=com, inertia=mass * np.diag([0.05, 0.03, 0.04]),
                rotation=rotation, translation=translation)


TILT = np.array([[np.cos(0.5), 0.0, np.sin(0.5)], [0.0, 1.0, 0.0], [-np.sin(0.5), 0.0, np.cos(0.5)]])
BODIES = [
    _body("a1", None, "revolute", (0, 1, 0), 1.0, (0.2, 0.0, 0.0), (0.0, 0.0, 0.3)),
    _body("a2", "a1", "revolute", (0, 0, 1), 0.7, (0.25, 0.0, 0.0), (0.5, 0.0, 0.0), TILT),
    _body("a3", "a2", "revolute", (1, 1, 1), 0.4, (0.1, 0.0, 0.05), (0.4, 0.0, 0.0)),
    _body("b1", None, "prismatic", (0, 0, 1), 1.5, (0.0, 0.0, 0.0), (1.0, 0.3, 0.0)),
    _body("b2", "b1", "revolute", (1, 0, 0), 0.5, (0.0, 0.15, 0.0), (0.0, 0.0, 0.1), TILT.T),
]
Q0 = np.array([0.3, 0.8, -0.4, 0.2, 1.1])
B_3D = np.eye(5)[:, [0, 2, 3]] - 0.4 * np.eye(5)[:, [1, 4, 4]]


def spatial_model(kind: str):
    """``loop``: chain a's tip joined to chain b in 3 directions, b's point placed where a's point is at Q0
    (2 degrees of freedom); ``every``: all four declarations, a world pin among them (4 rows, 1 degree of
    freedom; Q0 is not on its manifold)."""
    tip_a = np.array([0.3, 0.0, 0.0])
    if kind == "loop":
        kin = kinematics.forward_kinematics(build_model("probe", BODIES), Q0)
        p = kinematics.point_position(kin, 2, tip_a)
        T = kin.poses[4]
        constraints = [cases.PointsCoincide("tips", "a3", tip_a, "b2", T[:3, :3].T @ (p - T[:3, 3]))]
    else:
        constraints = [
            cases.PointOnCircle("circle", "a3", tip_a, (0.9, 0.2, 0.1), 0.3, TILT[:2]),
            cases.PointOnLine("line", "b2", (0.0, 0.2, 0.0), (1.0, 0.0, 0.5), [_unit((0, 1, -1))]),
            cases.JointCoupling("gear", ("a1", "b2"), (0.5, 1.0), -0.3),
            cases.PointsCoincide("pin", "a2", (0.2, 0.0, 0.0), None, (0.6, 0.0, 0.2), [[1.0, 0.0, 0.0]]),
        ]
    return build_model(f"spatial_{kind}", BODIES, gravity=(0.3, -9.0, 1.0), input_map=B_3D, constraints=constraints)


def spatial_states(model, count=4, seed=0):
    rng = np.random.default_rng(seed)
    for _ in range(count):
        if model.name == "spatial_loop":               # on the manifold, a velocity in the null space of Jc
            Jc = screw.split(model, Q0, np.zeros(5), np.zeros(3)).constraint_jacobian
            yield Q0, rng.standard_normal(2) @ np.linalg.svd(Jc)[2][3:] * 2.0, rng.uniform(-4, 4, 3)
        else:                                          # anywhere: the backends must agree off the manifold too
            yield Q0 + 0.5 * rng.standard_normal(5), 2.0 * rng.standard_normal(5), rng.uniform(-4, 4, 3)


@pytest.mark.parametrize("kind", ["loop", "every"])
def test_spatial_screw_agrees_with_newton_euler(kind):
    """Two solves (Gauss's principle here, the Schur complement there) of the same rows: they agree to rounding
    amplified by cond(S)."""
    model = spatial_model(kind)
    for q, qd, u in spatial_states(model):
        a, b = screw.split(model, q, qd, u), ne.split(model, q, qd, u)
        gain = 1e-14 * max(1.0, b.conditions["constraint_kept"])
        scale = max(1.0, np.abs(b.total).max(), np.abs(b.drift).max())
        for name in ("constraint_value", "constraint_jacobian", "constraint_bias"):
            np.testing.assert_allclose(getattr(a, name), getattr(b, name), rtol=0,
                                       atol=1e-13 * max(1.0, np.abs(getattr(b, name)).max()), err_msg=name)
        for name in ("total", "drift", "ctrl", "task_drift"):
            np.testing.assert_allclose(getattr(a, name), getattr(b, name), rtol=0, atol=gain * scale, err_msg=name)
        for name in ("lam", "lam_drift", "constraint_force"):
            np.testing.assert_allclose(getattr(a, name), getattr(b, name), rtol=0,
                                       atol=gain * max(1.0, np.abs(getattr(b, name)).max()), err_msg=name)
        assert a.kinetic_energy == pytest.approx(b.kinetic_energy, rel=1e-12)
        assert_same_conditioning(a, b, model.name)
        if kind == "loop":   # both apply the loop force at the points: the same joint loads, (moment, force) order
            world = b.extras["joint_reactions_world"]
            np.testing.assert_allclose(a.extras["wrenches_space"], np.hstack([world[:, 3:], world[:, :3]]), rtol=0,
                                       atol=1e-11 * np.abs(world).max())
            assert a.constraint_rank == 3
            assert_small(a.admissibility_total, scale, 1e-12, "H_t residual")


def assert_same_conditioning(a, b, what):
    """The conditions and scales of two splits of one state, equal to rounding; cond S only where S is not singular
    (there it is the rounding of a zero eigenvalue, inf or 1e30)."""
    assert a.constraint_rank == b.constraint_rank, what
    for key in ("constraint", "constraint_kept"):
        if b.conditions[key] < 1e12:
            assert a.conditions[key] == pytest.approx(b.conditions[key], rel=1e-9), f"{what}: {key}"
        else:
            assert a.conditions[key] > 1e12, f"{what}: {key}"
    assert a.conditions["constraint_consistency"] == pytest.approx(b.conditions["constraint_consistency"], abs=1e-12)
    for key in ("cond_M", "accel_scale", "lam_scale"):
        assert getattr(a, key) == pytest.approx(getattr(b, key), rel=1e-9), f"{what}: {key}"


@pytest.mark.parametrize("case", CONSTRAINED_CASES)
def test_conditioning_agrees_with_newton_euler(case):
    """cond S, its kept part, the rank, the consistency, lam_scale and accel_scale from the eigendecomposition of
    ``S = A A^T`` here (Gauss's ``A = Jc L^-T``, ``scipy.linalg.eigh``), from the singular values of ``L^-1 Jc^T``
    there, each from its own M and rows: equal to rounding."""
    model = cases.load(case)
    for state in sample_states(model, 4, 0, case):
        a, b = (be.split(model, state.q, state.qd, state.u) for be in (screw, ne))
        assert_same_conditioning(a, b, f"{case} state {state.index}")


def test_conditioning_at_the_four_bars_change_point_agrees_with_newton_euler():
    """q = (pi/2, 0, pi/2): the loop's x row vanishes (rank 1). Along a branch H_t is not empty (consistency 0), off
    both branches it is (0.5 and more): both backends see the same."""
    model = cases.load("four_bar")
    q = np.array([np.pi / 2, 0.0, np.pi / 2])
    for qd, empty in (((1.0, -1.0, 1.0), False), ((0.0, 1.0, 2.0), True), ((1.0, 0.3, -0.2), True)):
        a, b = (be.split(model, q, np.array(qd), np.array([0.5, -1.0, 2.0])) for be in (screw, ne))
        assert_same_conditioning(a, b, f"qd = {qd}")
        assert a.constraint_rank == 1 and (a.conditions["constraint_consistency"] > 0.1) == empty


def test_spatial_constraint_kinematics_by_finite_differences():
    model = spatial_model("every")
    step = 1e-6
    rows = lambda x, v: screw.split(model, x, v, np.zeros(3))  # noqa: E731
    for q, qd, _ in spatial_states(model, 2, seed=1):
        s = rows(q, qd)
        Jc = np.column_stack([(rows(q + step * e, qd).constraint_value - rows(q - step * e, qd).constraint_value)
                              / (2 * step) for e in np.eye(5)])
        bias = ((rows(q + step * qd, qd).constraint_jacobian - rows(q - step * qd, qd).constraint_jacobian) @ qd
                / (2 * step))
        np.testing.assert_allclose(s.constraint_jacobian, Jc, rtol=0, atol=1e-8)
        np.testing.assert_allclose(s.constraint_bias, bias, rtol=0, atol=1e-7 * max(1.0, np.abs(bias).max()))
