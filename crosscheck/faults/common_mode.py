"""Common-mode faults: realistic bugs in code every backend shares, which the vote cannot see (docs/design.md, "Shared
code that cannot be avoided ... is guarded by something outside the vote").

A bug in the model language, a URDF conversion, a case factory, a constraint declaration, the sampler, the charts,
the frames, the comparison or the tolerance moves all voters together: they agree on the wrong answer, or the check
that should have failed cannot. The gate guards each of these places with something outside the vote: the reference
built from the model file (``crosscheck.references.pinocchio.reference``), the second reading of a model file apart
from the loader and its parser (``crosscheck.guards.loader``), the closed forms bound to a case's parameters
(``crosscheck.references.closed_forms``), the exact values (``H_t``, phi, constraint power), the chart and frame
invariance checks, the conditions audit (``crosscheck.guards.conditioning``), the sampling coverage
(``crosscheck.guards.coverage``) and the self-test canaries (``crosscheck.guards.selftest``). :data:`CATALOG` lists such
bugs, each with the guard expected to catch it; :func:`hunt` runs everything ``crosscheck gate`` runs under the bug,
cheapest first (the self-test, building the cases, their files read apart from the loader, their coverage, then the
states round robin, as ``crosscheck.faults.injection.hunt`` does), and says what caught it. ``tests/faults/test_common_mode.py`` checks that
every entry is caught, and by its guard.

A fault is injected as in ``crosscheck.faults.injection`` (one attribute replaced, restored on exit), possibly at
several targets (a constant imported by every backend is one bug at every import); a fault in code a cached derivation
reads runs on fresh derivation caches, discarded afterwards (:data:`DERIVATION_INPUTS`), so that it cannot outlive the
hunt.

A bug in Pinocchio's parser of a model file (``cases.urdf.read_file``, which the URDF loader and the reference share)
moves the reference with the backends: the reference cannot catch it. It is injected at both places the parser is
looked up (:data:`_PARSERS`), on a copy of the file changed as the bug would read it, and only the second reading of
the file catches it (``crosscheck.guards.loader``), when the cases are built, before any state.
"""

from __future__ import annotations

import dataclasses
import os
import tempfile
import time
import xml.etree.ElementTree as ET
from contextlib import ExitStack, contextmanager
from dataclasses import dataclass, field
from typing import Any, Callable, Iterator, Sequence

import numpy as np

from crosscheck.core import sampling
from crosscheck.core.sampling import sample_states
from crosscheck.engine import divergences
from crosscheck.engine.specs import DEFAULT_SAMPLES, CaseSpec, Checks
from crosscheck.faults import injection
from crosscheck.guards import coverage, loader, selftest
from crosscheck.references.pinocchio.kinematics import constraint_kinematics


@dataclass(frozen=True)
class SharedFault:
    """A named bug in shared code (``area``), injected by replacing each of ``targets`` (``"module:attribute"``) by
    ``replace(original)``; ``guard`` names what is expected to catch it."""

    name: str
    area: str
    bug: str
    targets: tuple[str, ...]
    replace: Callable[[Any], Any] = field(repr=False, compare=False)
    guard: str = ""


#: Shared modules whose code the backends' cached derivations read without it entering the cache keys (a chart's
#: ``psi`` is keyed by the chart's definition, not by the code that evaluates it): a fault there runs on fresh caches.
#: Elsewhere a shared fault either changes the model, and so the digest every cache is keyed by, or no derivation.
DERIVATION_INPUTS = ("crosscheck.checks.charts",)


@contextmanager
def injected(fault: SharedFault) -> Iterator[None]:
    """Within the block every target is replaced (and, for a fault in :data:`DERIVATION_INPUTS`, both derivation
    caches are fresh); all restored on exit."""
    with ExitStack() as stack:
        if any(target.startswith(DERIVATION_INPUTS) for target in fault.targets):
            stack.enter_context(injection._fresh_euler_lagrange())
            stack.enter_context(injection._fresh_geometric())
        for target in fault.targets:
            stack.enter_context(injection.patched(fault.name, target, fault.replace))
        yield


@dataclass(frozen=True)
class SharedHunt:
    """A shared fault against the gate: ``caught``, ``by`` (what failed: the self-test, the model build, a case's
    coverage or a state's comparisons and checks), ``detail`` (the first failure in words), ``states`` evaluated."""

    fault: SharedFault
    caught: bool
    by: str
    detail: str
    states: int
    seconds: float


def _first_failure(outcome) -> str:
    found = injection.catches(outcome)
    return ", ".join(f"{c.key} ({injection._ratio(c.ratio)}, outlier {c.outlier or '-'})" for c in found[:3])


def hunt(fault: SharedFault, specs: Sequence[CaseSpec] | None = None, backends=None, samples: int = DEFAULT_SAMPLES,
         seed: int = 0, checks: Checks = Checks(), known: divergences.Registry | None = None,
         progress: Callable[[str, int], None] | None = None, rounds: int | None = None) -> SharedHunt:
    """Everything the default gate does, under ``fault``, until something fails (module doc); ``progress(case,
    index)`` is called before each state is evaluated. ``rounds``: evaluate only the first ``rounds`` of the
    ``samples`` states of every case (the coverage check still sees all ``samples``)."""
    specs = injection.default_specs() if specs is None else list(specs)
    backends = injection.default_backends() if backends is None else list(backends)
    start, count = time.perf_counter(), 0

    def done(by: str, detail: str) -> SharedHunt:
        return SharedHunt(fault, bool(by), by, detail, count, time.perf_counter() - start)

    with injected(fault):
        if checks.self_test and not (test := selftest.run(checks=checks)).passed:
            return done("self-test", test.failures()[0])
        try:
            setups = [injection._Case(spec, seed, checks) for spec in specs]
        except Exception as exc:  # the gate refuses bad input: it does not pass
            return done("model build", f"{type(exc).__name__}: {exc}")
        for case in setups:
            checked = loader.check(case.setup.model)
            if checked is not None and checked.findings:
                return done(f"loader {case.setup.spec.name}", str(checked.findings[0]))
        for case in setups:
            problems = coverage.measure(case.setup.model, sample_states(case.setup.model, samples, seed,
                                                                           case.setup.spec.name)).problems
            if problems:
                return done(f"coverage {case.setup.spec.name}", problems[0])
        for case, state in injection._round_robin(setups, min(samples, rounds or samples)):
            if progress:
                progress(case.setup.spec.name, state.index)
            outcome = case.setup.evaluate(state, backends, guard=True)
            if known is not None:
                divergences.apply_to_state(known, (case.setup.spec.name, case.setup.model.name), outcome)
            count += 1
            if outcome.failed:
                return done(f"{case.setup.spec.name} #{state.index}", _first_failure(outcome))
    return done("", "not caught")


def line(h: SharedHunt) -> str:
    """One line per fault for the terminal."""
    if not h.caught:
        return f"MISSED {h.fault.name} (shared: {h.fault.area}): not caught in {h.states} states"
    return f"caught {h.fault.name} (shared: {h.fault.area}): by {h.by} after {h.states} states: {h.detail}"


def render(hunts: Sequence[SharedHunt]) -> str:
    """The report's section on the common-mode faults (empty when none was hunted)."""
    if not hunts:
        return ""
    caught = sum(h.caught for h in hunts)
    lines = ["", "## Common-mode faults in shared code", "",
             f"Caught {caught}/{len(hunts)} by `crosscheck gate` itself (the self-test, the model build, the model "
             "files read apart from the loader, the sampling coverage, then the states round robin). The vote cannot see these: each is caught by the guard outside "
             "it.", "",
             "| fault | shared code | caught | by | states | first failure | guard | bug |",
             "|---|---|---|---|---|---|---|---|"]
    for h in hunts:
        detail = injection._cell(h.detail if len(h.detail) < 160 else h.detail[:157] + "...")
        lines.append(f"| `{h.fault.name}` | {h.fault.area} | {'yes' if h.caught else '**NO**'} | {h.by or '-'} | "
                     f"{h.states} | {detail} | {h.fault.guard} | {injection._cell(h.fault.bug)} |")
    return "\n".join(lines) + "\n\n"


# ------------------------------------------------------------------------------------------------ the catalog


def _body_with(change):
    """A replacement for a loader's ``Body`` constructor that alters its keyword arguments."""
    def replace(body):
        return lambda *args, **kw: body(*args, **change(kw))
    return replace


def _transposed_rotation(kw):
    return {**kw, "rotation": np.asarray(kw["rotation"]).T}


def _inertia_about_origin(kw):
    c = np.asarray(kw["com"], dtype=float)
    return {**kw, "inertia": np.asarray(kw["inertia"]) + kw["mass"] * (c @ c * np.eye(3) - np.outer(c, c))}


def _rates_never_sampled(sample):
    def faulty(model, count, seed, case, **options):
        return [dataclasses.replace(s, qd=(0.0,) * model.n) for s in sample(model, count, seed, case, **options)]
    return faulty


def _signed_pairwise(pairwise):
    def faulty(vectors):
        size = max(v.size for v in vectors)
        V = np.array([v.ravel() if v.size == size else np.full(size, v.flat[0]) for v in vectors])
        i, j = np.triu_indices(len(vectors), 1)
        return V[i] - V[j]
    return faulty


def _rod_inertia_about_end(rod):
    def faulty(name, parent, mass, length, *args):
        body = rod(name, parent, mass, length, *args)
        return dataclasses.replace(body, inertia=4.0 * np.asarray(body.inertia))
    return faulty


def _declaration_changed(kind_name: str, change):
    """A replacement for ``cases.constraints.validate`` that alters the validated declarations of one kind."""
    def replace(validate):
        def faulty(problems, c, bodies):
            out = validate(problems, c, bodies)
            return change(out) if type(out).__name__ == kind_name else out
        return faulty
    return replace


_circle_radius_squared = _declaration_changed("PointOnCircle", lambda c: dataclasses.replace(c, radius=c.radius**2))
_line_normal_swapped = _declaration_changed(
    "PointOnLine", lambda c: dataclasses.replace(c, normals=np.asarray(c.normals)[:, [1, 0, 2]]))
_coupling_reversed = _declaration_changed(
    "JointCoupling", lambda c: dataclasses.replace(c, coefficients=np.asarray(c.coefficients)[::-1]))


def _pfaffian_as_holonomic(project_velocity):
    """``sampling.project_velocity`` with the Pfaffian rows treated as holonomic: taken to hold once q is projected,
    so qd is projected onto the null space of the holonomic rows only."""
    def faulty(model, q, qd):
        if not model.pfaffian_rows.any():
            return project_velocity(model, q, qd)

        Jc = constraint_kinematics(model, q, np.zeros(model.nv))[1][model.holonomic_rows]
        if not len(Jc):
            return np.asarray(qd, dtype=float)
        _, sigma, Vt = np.linalg.svd(Jc)
        N = Vt[int(np.sum(sigma > 1e-13 * sigma.max())):].T
        return N @ (N.T @ np.asarray(qd, dtype=float))
    return faulty


def _about_z(quat: np.ndarray) -> np.ndarray:
    """A quaternion's rotation about z alone: its x and y components dropped, renormalized."""
    kept = np.array([0.0, 0.0, quat[2], quat[3]])
    return kept / np.linalg.norm(kept)


def _scaled(factor: float):
    return lambda f: lambda *args, **kw: factor * f(*args, **kw)


def _world_loads_validated_as_body(validate):
    """``cases.loads.validate`` returning a world-frame force or wrench as a body-frame one."""
    def faulty(problems, load, bodies):
        out = validate(problems, load, bodies)
        return dataclasses.replace(out, frame="body") if out is not None and getattr(out, "frame", "") == "world" else out
    return faulty


_SAMPLERS = ("crosscheck.core.sampling:sample_states", "crosscheck.engine.run:sample_states",
             "crosscheck.faults.injection:sample_states", "crosscheck.faults.common_mode:sample_states",
             "crosscheck.guards.selftest:sample_states")


def _sample_changed(change):
    """A replacement for ``sample_states`` (at each of :data:`_SAMPLERS`) that alters the drawn states."""
    def replace(sample):
        def faulty(model, count, seed, case, **options):
            return change(model, sample(model, count, seed, case, **options))
        return faulty
    return replace


def _pinned(model, states):
    """The last coordinate of q left at its home value (state 0's) in every state."""
    k = model.nq - 1
    return [dataclasses.replace(s, q=s.q[:k] + (states[0].q[k],) + s.q[k + 1:]) for s in states]


def _repeated(model, states):
    """Every state after the second a copy of the second."""
    return states[:2] + [dataclasses.replace(states[1], index=s.index) for s in states[2:]]


def _limits_in_degrees(position_limits):
    """The URDF loader's ``_position_limits`` with the file's radians read as degrees (converted once more)."""
    def faulty(pm, j, jm):
        limits = position_limits(pm, j, jm)
        return None if limits is None else tuple(np.degrees(limits))
    return faulty


def _parsed_edited(edit):
    """A replacement for ``read_file`` (Pinocchio's reading of a model file, which the URDF loader and the reference
    share: ``cases.urdf.read_file``) that parses a copy of a URDF file changed by ``edit(robot element)``: a bug of
    the parser, which every voter reads the same way."""
    def replace(read_file):
        def faulty(pin, kind, path, root="fixed"):
            if kind != "urdf":
                return read_file(pin, kind, path, root)
            tree = ET.parse(path)
            edit(tree.getroot())
            with tempfile.TemporaryDirectory() as folder:
                copy = os.path.join(folder, os.path.basename(path))
                tree.write(copy)
                return read_file(pin, kind, copy, root)
        return faulty
    return replace


def _inertial_rpy_dropped(robot: ET.Element) -> None:
    for origin in robot.iterfind("link/inertial/origin"):
        origin.attrib.pop("rpy", None)


def _fixed_origins_dropped(robot: ET.Element) -> None:
    for joint in robot.iterfind("joint"):
        origin = joint.find("origin")
        if joint.get("type") == "fixed" and origin is not None:
            joint.remove(origin)


#: Where Pinocchio's reading of a model file is looked up: by the URDF loader and by the reference.
_PARSERS = ("cases.urdf:read_file", "crosscheck.references.pinocchio.build:read_file")


def _to_the_ends(within_limits):
    """``sampling.within_limits`` sending each limited coordinate to the nearer of its limits."""
    def faulty(model, q, home=False):
        q = within_limits(model, q, home)
        for i in sampling.limited_joints(model):
            lower, upper = model.bodies[i].limits
            iq = model.q_index[i]
            q[iq] = lower if q[iq] - lower < upper - q[iq] else upper
        return q
    return faulty


MULTIPLIER_QUANTITIES = ("lam", "lam_drift", "constraint_force", "constraint_force_drift", "power_constr")


def _input_power_scale_divides_by_zero(power_scale):
    """``tolerance.power_scale`` divided by the number of inputs a passive model would have: a ZeroDivisionError."""
    return lambda model, qd, u: power_scale(model, qd, u) / (len(u) - model.m)


def _times_cond_S(tolerance_of):
    """``tolerance.tolerance`` with the multipliers' quantities multiplied by cond(S) once more."""
    return lambda quantity, at: tolerance_of(quantity, at) * (at.cond_S if quantity in MULTIPLIER_QUANTITIES else 1.0)


CATALOG: list[SharedFault] = [
    SharedFault("urdf-joint-rotation-transposed", "URDF conversion",
                "The URDF loader stores each joint placement's rotation transposed (parent <- child read as child "
                "<- parent).",
                ("cases.urdf:Body",), _body_with(_transposed_rotation),
                "the second reading of the file (before any state; then the reference built from the file, at every "
                "state)"),
    SharedFault("urdf-inertia-about-joint-origin", "URDF conversion",
                "The URDF loader takes the link inertia about the joint origin for the inertia about the COM (the "
                "parallel-axis term m [c]^T [c] added twice).",
                ("cases.urdf:Body",), _body_with(_inertia_about_origin),
                "the second reading of the file (before any state; then the reference built from the file, at every "
                "state)"),
    SharedFault("factory-inertia-transposed-rotation", "case factories",
                "The case factories rotate a principal inertia as R^T diag(I) R instead of R diag(I) R^T.",
                ("cases.factories:_inertia",), lambda f: lambda principal, rotation: f(principal,
                                                                                     np.asarray(rotation).T),
                "the closed forms (rotor)"),
    SharedFault("factory-rod-inertia-about-its-end", "case factories",
                "The constrained cases' uniform rods get the inertia m l^2 / 3 (about an end) for m l^2 / 12 (about "
                "the COM).",
                ("cases.constrained:_rod",), _rod_inertia_about_end, "the closed forms (four_bar, slider_crank)"),
    SharedFault("sampling-rates-never-sampled", "sampling",
                "The sampler leaves every joint rate at 0 (qd drawn but never stored).",
                ("crosscheck.core.sampling:sample_states", "crosscheck.engine.run:sample_states",
                 "crosscheck.faults.injection:sample_states", "crosscheck.faults.common_mode:sample_states"),
                _rates_never_sampled,
                "the self-test canaries (their states are sampled) or the sampling coverage"),
    SharedFault("sampling-angles-in-a-sliver", "sampling",
                "The sampler draws joint angles from +-1e-4 rad instead of one turn (degrees taken for radians "
                "twice).",
                ("crosscheck.core.sampling:ANGLE_RANGE",), lambda value: 1e-4,
                "the self-test canaries (their states are sampled) or the sampling coverage"),
    SharedFault("sampling-projection-skipped", "sampling",
                "Constrained states are not projected onto the constraint manifold (q and qd used as drawn).",
                ("crosscheck.core.sampling:admissible",), lambda f: lambda model, q, qd, rng: (q, qd),
                "the self-test canaries (their states are sampled) or the exact values (phi, Jc qd)"),
    SharedFault("sampling-pfaffian-row-as-holonomic", "sampling",
                "The sampler treats Pfaffian rows as holonomic: it takes them to hold once the configuration is "
                "projected, and projects qd onto the null space of the holonomic rows only (A qd != 0).",
                ("crosscheck.core.sampling:project_velocity",), _pfaffian_as_holonomic,
                "the exact values (A qd = 0) and the power audit (lam . A qd = 0)"),
    SharedFault("sampling-orientations-about-z-only", "sampling",
                "The sampler's orientations of spherical and free joints are rotations about z only (the x and y "
                "components of a drawn quaternion dropped), not uniform on SO(3).",
                ("cases.configuration:random_quaternion",), lambda f: lambda rng: _about_z(f(rng)),
                "the sampling coverage"),
    SharedFault("factory-floating-com-negated", "case factories",
                "The Lie-group case factories place each body's centre of mass at -c in the body frame.",
                ("cases.floating:Body",), _body_with(lambda kw: {**kw, "com": -np.asarray(kw["com"], dtype=float)}),
                "the closed forms (free_body)"),
    SharedFault("charts-rate-term-dropped", "charts",
                "Joint accelerations are mapped into a chart by Dpsi^-1 qdd alone, without the (d/dt Dpsi) pd term.",
                ("crosscheck.checks.charts:acceleration_to_chart",),
                lambda f: lambda chart, p, pd, qdd, with_rate=True: f(chart, p, pd, qdd, with_rate=False),
                "the chart checks"),
    SharedFault("charts-mixed-rate-term-dropped", "charts",
                "The mixed base-velocity representation loses its rate term: Tdot w = (-w_b x v_b, 0) is taken as 0, "
                "so joint accelerations are mapped into mixed by T^-1 vdot alone.",
                ("crosscheck.checks.charts:VelocityRepresentation.jacobian_rate",),
                lambda f: lambda self, p, pd: np.zeros(len(pd)) if self.representation == "mixed" else f(self, p, pd),
                "the chart checks (Euler-Lagrange and geometric evaluate mixed natively)"),
    SharedFault("frames-gravity-not-rotated", "frames",
                "A moved scene keeps gravity as it was instead of rotating it with the scene.",
                ("crosscheck.checks.frames:rotate_gravity",), lambda f: lambda frame, gravity: np.asarray(gravity),
                "the frame checks"),
    SharedFault("compare-signed-difference", "comparison",
                "The comparison takes the signed difference a - b of each pair instead of |a - b|.",
                ("crosscheck.core.compare:_pairwise",), _signed_pairwise, "the self-test canaries"),
    SharedFault("compare-nan-agrees", "comparison",
                "A NaN difference counts as agreement (NaN replaced by 0 before the tolerance test).",
                ("crosscheck.core.compare:_ratios",), lambda f: lambda d, t: np.nan_to_num(f(d, t), nan=0.0),
                "the self-test canaries"),
    SharedFault("tolerance-factor-tenfold", "tolerance",
                "Every tolerance factor is 1000 eps instead of 100 eps.",
                ("crosscheck.core.tolerance:TOLERANCES",),
                lambda table: {q: (kind, 10.0 * factor) for q, (kind, factor) in table.items()},
                "the self-test canaries"),
    SharedFault("tolerance-acceleration-scale-tenfold", "tolerance",
                "The componentwise acceleration bound is ten times too large.",
                ("crosscheck.core.tolerance:acceleration_bound",), _scaled(10.0), "the self-test canaries"),
    SharedFault("constraint-circle-radius-squared", "constraint declarations",
                "A point-on-circle declaration is validated into a circle of radius R^2 (phi = |d|^2 - R^4).",
                ("cases.constraints:validate",), _circle_radius_squared,
                "the closed forms (double_pendulum_circle, cartesian_pendulum)"),
    SharedFault("constraint-line-normal-swapped", "constraint declarations",
                "A point-on-line declaration is validated with its normal's x and y components swapped.",
                ("cases.constraints:validate",), _line_normal_swapped, "the closed forms (double_pendulum_rail)"),
    SharedFault("constraint-coupling-coefficients-reversed", "constraint declarations",
                "A joint coupling is validated with its coefficients in reverse order (the gear ratio applied to the "
                "wrong joint).",
                ("cases.constraints:validate",), _coupling_reversed,
                "the closed forms (geared_pendulums) and the frame checks (the Panda's finger mimic: a moved scene is "
                "validated again, reversed twice, and its multiplier changes sign)"),
    SharedFault("interface-redundancy-threshold-too-high", "interface constants",
                "The relative eigenvalue below which a constraint direction counts as redundant is 1e-2, not 1e-10 "
                "(every backend imports it).",
                ("formalisms.interface:CONSTRAINT_RCOND", "formalisms.euler_lagrange:CONSTRAINT_RCOND",
                 "formalisms.newton_euler:CONSTRAINT_RCOND", "formalisms.screw.constraints:CONSTRAINT_RCOND",
                 "formalisms.screw.conditioning:CONSTRAINT_RCOND",
                 "formalisms.operational_space:CONSTRAINT_RCOND", "formalisms.geometric:CONSTRAINT_RCOND",
                 "crosscheck.references.pinocchio.reference:CONSTRAINT_RCOND"), lambda value: 1e-2,
                "the closed forms, the conditions audit and the exact H_t residual"),
    SharedFault("loads-world-force-validated-as-body", "load declarations",
                "An external force or wrench declared in the world frame is validated into a body-frame one (its "
                "vector then turns with the body).",
                ("cases.loads:validate",), _world_loads_validated_as_body,
                "the closed forms (double_pendulum_tip_force)"),
    SharedFault("frames-loads-not-moved", "frames",
                "A moved scene keeps the external loads' world data (force directions, spring anchors) as they were "
                "instead of moving them with the scene.",
                ("crosscheck.checks.frames:move_load",), lambda f: lambda load, frame: load, "the frame checks"),
    SharedFault("conservation-external-power-dropped", "conservation",
                "The energy balance leaves the external loads' power out: dE/dt is checked against P_ctrl alone "
                "(against 0 under the drift), as if only gravity and the inputs acted.",
                ("crosscheck.checks.conservation:_external_power",), lambda f: lambda model, split: 0.0,
                "the energy-rate conservation checks"),
    SharedFault("tolerance-multipliers-times-cond-S", "tolerance",
                "The multipliers' tolerance counts cond(S) twice: lam, lam_drift, the constraint forces and the "
                "constraint power are held to cond(S) times their bound (4 to 40 on the built-in cases with several "
                "rows).",
                ("crosscheck.core.tolerance:tolerance",), _times_cond_S,
                "the self-test canaries (the multipliers on cases with several rows)"),
    SharedFault("charts-every-chart-left-out", "charts",
                "The chart check's gimbal-lock test leaves out every chart (the limit on cond(Dpsi) taken as 0), so "
                "no chart is ever compared.",
                ("crosscheck.checks.invariance:chart_checks",),
                lambda f: lambda *args, **kw: f(*args, **{**kw, "limit": 0.0}), "the self-test canaries (charts)"),
    SharedFault("frames-scene-not-moved", "frames",
                "The moved scene is a copy of the unmoved one (the frame's rotation and translation dropped), so the "
                "frame checks compare each scene with itself.",
                ("crosscheck.checks.frames:move_scene",), lambda f: lambda model, frame: dataclasses.replace(model),
                "the self-test canaries (frames)"),
    SharedFault("conservation-tolerance-tenfold", "conservation",
                "The conservation checks' safety factor is 1000, not 100 (energy rate, Christoffel identities, "
                "momentum).",
                ("crosscheck.checks.conservation:FACTOR",), lambda value: 10.0 * value,
                "the self-test canaries (conservation)"),
    SharedFault("linearization-tolerance-tenfold", "linearization",
                "The linearization checks' safety factor is 1000, not 100 (and so the equilibria's bound).",
                ("crosscheck.checks.linearization:FACTOR",), lambda value: 10.0 * value,
                "the self-test canaries (linearization, equilibria)"),
    SharedFault("equilibria-none-found", "linearization",
                "The equilibria table is looked up under the wrong key, so no case has an equilibrium and the "
                "eigenvalues of A are never checked against physics.",
                ("crosscheck.checks.equilibria:of_case",), lambda f: lambda case, params=None: (),
                "the self-test canaries (equilibria)"),
    SharedFault("conditions-audit-saturated", "conditions audit",
                "The conditions audit saturates every condition at 1 before comparing (the limit taken as 0), so a "
                "backend's reported condition is never compared with the harness's own.",
                ("crosscheck.guards.conditioning:_saturated",), lambda f: lambda name, value: 0.0,
                "the self-test canaries (conditions)"),
    SharedFault("closed-forms-never-found", "closed forms",
                "The closed forms are looked up under a wrong name, so no case gets its closed-form voter.",
                ("crosscheck.references.closed_forms:voter",), lambda f: lambda case, params=None: None,
                "the self-test canaries (closed forms)"),
    SharedFault("coverage-sliver-bound-tenfold", "coverage",
                "The sampling coverage's sliver bound is 0.01 of a coordinate's span, not 0.1.",
                ("crosscheck.guards.coverage:SLIVER",), lambda value: value / 10.0,
                "the self-test canaries (coverage)"),
    SharedFault("sampling-last-coordinate-pinned", "sampling",
                "The sampler never draws the last coordinate of q: it stays at its home value in every state.",
                _SAMPLERS, _sample_changed(_pinned), "the sampling coverage"),
    SharedFault("sampling-states-repeated", "sampling",
                "The sampler's generator is re-seeded after the second state, so every later state repeats it.",
                _SAMPLERS, _sample_changed(_repeated), "the sampling coverage"),
    SharedFault("tolerance-power-scale-raises", "tolerance",
                "The input power's tolerance scale divides by the number of inputs less the model's (0): every state "
                "raises ZeroDivisionError in the harness's own code.",
                ("crosscheck.core.tolerance:power_scale",), _input_power_scale_divides_by_zero,
                "the internal errors of the harness (each check named)"),
    SharedFault("urdf-limits-read-as-degrees", "URDF conversion",
                "The URDF loader converts the joint limits from degrees to radians, though a URDF's are in radians "
                "already (a limit of 2.9 becomes 166).",
                ("cases.urdf:_position_limits",), _limits_in_degrees,
                "the second reading of the file (a loader finding: the limits)"),
    SharedFault("urdf-inertial-rpy-ignored", "URDF parsing",
                "Pinocchio's URDF parser ignores the rotation (rpy) of each link's inertial frame, taking every "
                "inertia tensor as given in the link frame: the loader and the reference read the same wrong model.",
                _PARSERS, _parsed_edited(_inertial_rpy_dropped),
                "the second reading of the file (a loader finding: an inertia)"),
    SharedFault("urdf-fixed-joint-placement-dropped", "URDF parsing",
                "Pinocchio's URDF parser drops the origin of every fixed joint when it welds the child link into its "
                "parent: the welded masses and the joints below sit at the parent's origin, for the loader and the "
                "reference alike.",
                _PARSERS, _parsed_edited(_fixed_origins_dropped),
                "the second reading of the file (a loader finding: a COM, an inertia, a placement)"),
    SharedFault("sampling-limited-joints-at-their-ends", "sampling",
                "The sampler maps each limited joint's draw onto the nearer of its limits instead of into the range "
                "between them.",
                ("crosscheck.core.sampling:within_limits",), _to_the_ends, "the sampling coverage"),
    SharedFault("interface-tangent-kinematics-sign", "interface (linearization)",
                "The kinematic rows of every backend's linearization take d/dt dq = dv + ad_v dq (the perturbation "
                "on the left) instead of dv - ad_v dq, on ball and free joints.",
                ("formalisms.interface:tangent_kinematics",), lambda f: lambda model, v: -f(model, v),
                "the Pinocchio reference's own kinematic rows (linearization check)"),
]


def names() -> list[str]:
    return [f.name for f in CATALOG]


def get(name: str) -> SharedFault:
    for fault in CATALOG:
        if fault.name == name:
            return fault
    raise injection.FaultError(f"unknown common-mode fault '{name}'; valid: {', '.join(names())}")
