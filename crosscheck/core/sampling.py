"""Seeded random states for the gate: same seed and case, same states, on every machine.

A constrained model's states are admissible (docs/design.md; article 5.1): q is projected onto the constraint manifold
``phi(q) = 0`` of the holonomic rows by Gauss–Newton (Pfaffian rows ``A(q) qd = 0`` leave q free) and qd onto the
null space of every row, ``Jc qd = 0`` and ``A qd = 0``, both with the Pinocchio reference's
constraint kinematics (``crosscheck.references.pinocchio.kinematics.constraint_kinematics``), so admissibility is
decided outside the five formalisms under test.
"""

from __future__ import annotations

import zlib
from dataclasses import dataclass

import numpy as np

from cases import configuration
from cases.model import Model
from crosscheck.references.pinocchio.kinematics import constraint_kinematics

#: Sampling ranges: revolute angles (rad), prismatic displacements (m), joint rates (rad/s or m/s), inputs.
ANGLE_RANGE = np.pi
DISPLACEMENT_RANGE = 0.5
RATE_RANGE = 3.0
INPUT_RANGE = 10.0
#: Projection onto the constraint manifold: |phi|_inf below PHI_TOL (times the model's length scale squared).
PHI_TOL = 1e-13
NEWTON_STEPS = 60
#: Singular values of Jc kept by the velocity projection: all but rounding noise, so that qd satisfies every row,
#: however nearly redundant (removing one direction too many still leaves an admissible velocity).
VELOCITY_RCOND = 1e-13
#: Random restarts before a constrained case is declared unsampleable.
RESTARTS = 20


class ProjectionError(ValueError):
    """A configuration could not be brought onto the constraint manifold."""


@dataclass(frozen=True)
class State:
    """One sampled state (q, qd) and input u, with its index in the case's sample sequence."""

    index: int
    q: tuple[float, ...]
    qd: tuple[float, ...]
    u: tuple[float, ...]


def case_rng(seed: int, case: str) -> np.random.Generator:
    """A generator seeded by (seed, case name), so adding a case does not change another's states."""
    return np.random.default_rng([seed, zlib.crc32(case.encode())])


def _configuration(model: Model, rng: np.random.Generator) -> np.ndarray:
    """A random configuration: angles over one turn, displacements (and free-base positions) +-0.5 m, orientations
    uniform on SO(3) (``cases.configuration.random_configuration``)."""
    return configuration.random_configuration(model, rng, ANGLE_RANGE, DISPLACEMENT_RANGE)


def sample_states(model: Model, count: int, seed: int, case: str, limits: bool = True) -> list[State]:
    """``count`` states: q uniform over one turn (revolute) or +-0.5 m (prismatic; a free base's position),
    orientations of spherical and free joints uniform on SO(3), qd and u uniform.

    State 0 has the home configuration (``q = 0``, identity orientations; qd and u still random): serial chains are
    often singular there (the stretched double pendulum of article 6.3.4), so every gate run visits one such boundary
    state. A constrained model's q and qd are then made admissible (module doc); state 0 starts its projection at
    home. With ``limits`` (the default) a joint with limits (``Body.limits``, from a URDF or MJCF file) is drawn
    uniformly within them instead (:func:`within_limits`), the same draws mapped, so the other joints' values do
    not change; a constrained model's projection may then leave them.
    """
    rng = case_rng(seed, case)
    states = []
    for i in range(count):
        q = _configuration(model, rng)
        if i == 0:
            q = configuration.neutral(model)
        if limits:
            q = within_limits(model, q, home=i == 0)
        qd = rng.uniform(-RATE_RANGE, RATE_RANGE, model.nv)
        u = rng.uniform(-INPUT_RANGE, INPUT_RANGE, model.m)
        if model.constraints:
            q, qd = admissible(model, q, qd, rng)
        states.append(State(i, tuple(q.tolist()), tuple(qd.tolist()), tuple(u.tolist())))
    return states


def limited_joints(model: Model) -> list[int]:
    """The bodies whose joint has limits (``Body.limits``)."""
    return [i for i, b in enumerate(model.bodies) if b.limits is not None]


def within_limits(model: Model, q: np.ndarray, home: bool = False) -> np.ndarray:
    """``q`` with each limited joint's value mapped linearly from its free range (``+-ANGLE_RANGE`` for a revolute,
    ``+-DISPLACEMENT_RANGE`` for a prismatic joint) onto its limits, so a uniform draw stays uniform; for the
    ``home`` configuration the value 0 is clipped into the limits instead (the stretched configuration where the
    limits allow it)."""
    q = np.array(q, dtype=float)
    for i in limited_joints(model):
        body, iq = model.bodies[i], model.q_index[i]
        lower, upper = body.limits
        if home:
            q[iq] = min(max(q[iq], lower), upper)
        else:
            span = ANGLE_RANGE if body.joint == "revolute" else DISPLACEMENT_RANGE
            q[iq] = min(max(lower + (q[iq] + span) / (2.0 * span) * (upper - lower), lower), upper)
    return q


def outside_limits(model: Model, q) -> list[str]:
    """One sentence per limited joint (``Body.limits``) whose coordinate in ``q`` lies outside its limits (``eval``
    takes any q it is given and says so: the gate samples within the limits unless told ``--ignore-limits``)."""
    q = np.asarray(q, dtype=float)
    out = []
    for i in limited_joints(model):
        body, value = model.bodies[i], float(q[model.q_index[i]])
        lower, upper = body.limits
        if not lower <= value <= upper:
            out.append(f"q[{model.q_index[i]}] = {value:g} ({body.name}, {body.joint}) is outside its joint limits "
                       f"[{lower:g}, {upper:g}]")
    return out


def project_configuration(model: Model, q) -> np.ndarray:
    """``q`` moved onto ``phi(q) = 0`` by Gauss–Newton with minimum-norm steps in velocity space (``Jc`` is
    ``dphi`` along the velocities; a step moves q by ``cases.configuration.integrate``, on the group for spherical
    and free joints), halved until |phi| shrinks, iterated down to rounding; :class:`ProjectionError` saying how far it
    got when it ends above ``PHI_TOL``. Only the holonomic rows take part (``Model.holonomic_rows``): a Pfaffian row
    ``A(q) qd = 0`` has no ``phi`` and leaves every configuration admissible."""
    q = np.array(q, dtype=float)
    holonomic = model.holonomic_rows
    if not holonomic.any():       # Pfaffian rows only: they do not restrict the configuration
        return q
    zero, tol = np.zeros(model.nv), PHI_TOL * model.length_scale ** 2

    def holonomic_kinematics(model, q, qd):
        phi, Jc, bias = constraint_kinematics(model, q, qd)
        return phi[holonomic], Jc[holonomic], bias[holonomic]

    phi, Jc, _ = holonomic_kinematics(model, q, zero)
    for _ in range(NEWTON_STEPS):
        step, t = -np.linalg.pinv(Jc, rcond=1e-10) @ phi, 1.0
        while t > 1e-6:
            trial = configuration.integrate(model, q, t * step)
            if trial.tobytes() != q.tobytes():   # a step lost to rounding leaves q, and so phi, as they are
                phi_new, Jc_new, _ = holonomic_kinematics(model, trial, zero)
                if np.abs(phi_new).max() < np.abs(phi).max():
                    break
            t *= 0.5
        else:               # no step reduces |phi| any more: converged to rounding, or stuck
            break
        q, phi, Jc = configuration.integrate(model, q, t * step), phi_new, Jc_new
    if np.abs(phi).max() <= tol:
        return q
    raise ProjectionError(f"model '{model.name}': Gauss–Newton did not reach the constraint manifold from the start "
                          f"configuration in {NEWTON_STEPS} steps: |phi|_inf = {np.abs(phi).max():.3e} > {tol:.1e} "
                          f"at q = {q.tolist()}; check that the constraints can hold together")


def project_velocity(model: Model, q, qd) -> np.ndarray:
    """``qd`` projected onto the tangent space ``Jc qd = 0`` (every row: holonomic ``Jc`` and Pfaffian ``A``): ``N N^T
    qd`` with N an orthonormal basis of null(Jc) (Jc's right singular vectors beyond its rank; singular values above
    ``VELOCITY_RCOND`` count). Built from the kept part rather than by subtracting the removed one (``(I - Jc^+ Jc)
    qd``), the residual ``Jc qd`` is rounding of the result, not of the removed part, which can dwarf a small remaining
    qd."""
    _, Jc, _ = constraint_kinematics(model, q, np.zeros(model.nv))
    if not np.all(np.isfinite(Jc)):
        bad = int(np.argwhere(~np.isfinite(Jc))[0][0])
        raise ProjectionError(f"model '{model.name}': constraint row {bad} is not finite at q = {np.asarray(q).tolist()} "
                              "(a rolling disk lying flat on its ground plane has no contact point); no velocity "
                              "can be made admissible there")
    _, sigma, Vt = np.linalg.svd(Jc)
    rank = int(np.sum(sigma > VELOCITY_RCOND * sigma.max())) if sigma.size and sigma.max() > 0.0 else 0
    N = Vt[rank:].T
    return N @ (N.T @ np.asarray(qd, dtype=float))


def admissible(model: Model, q, qd, rng: np.random.Generator) -> tuple[np.ndarray, np.ndarray]:
    """An admissible state from a sampled one: q projected (restarting from fresh random configurations when the
    projection fails), then qd projected onto the tangent space."""
    error = None
    for _ in range(RESTARTS):
        try:
            q = project_configuration(model, q)
            return q, project_velocity(model, q, qd)
        except ProjectionError as exc:
            error, q = exc, _configuration(model, rng)
    raise ProjectionError(f"{error} (and {RESTARTS - 1} random restarts failed as well)")
