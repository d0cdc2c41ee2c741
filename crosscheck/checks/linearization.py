"""The linearization checks (article 4.8, eq. 11): every backend's A and B at a state, compared with each other and
with an external reference, with a tolerance derived like the others (docs/tolerances.md).

``xdot ~ f(x_t) + A (x - x_t) + B u`` with ``x = (q, v)`` in the tangent convention of
:class:`formalisms.interface.Linearization`. The kinematic rows ``[A_qq, I]`` and ``[0]`` are the convention's
(``tangent_kinematics``, shared by the backends; the Pinocchio reference forms them with its own Lie algebra, so the
comparison of the ``kinematic rows`` checks that shared code too), and the checks compare the three dynamic blocks
``dvdot/dq``, ``dvdot/dv`` and ``dvdot/du`` (each backend's own exact derivative) and ``vdot`` itself. The references
are Pinocchio's analytical ABA derivatives (``crosscheck.references.pinocchio.reference.linearize``) on an unconstrained
model and the 50-digit central differences of the exact KKT solution (``crosscheck.references.precise.linearize``, voter
``exact``) on a constrained one, and on a model with external loads Pinocchio declines (world-frame forces and springs
turn in its joint frames, which its fext derivatives hold fixed).

Tolerance. ``dvdot/dx = -M^-1 d(M vdot + h - B u)/dx`` (with constraints the KKT matrix in place of M), so a
column's rounding is that of the forces differentiated, times the solve's amplification, plus the solve's own
relative rounding of the column. Column ``j`` of a block gets

    tol_j = FACTOR eps cond (max over voters |column j|_inf + s_j),

``cond = cond(M)`` (times cond(S) of the kept constraint directions with constraints) and ``s_j`` the size of the
differentiated terms as accelerations: ``accel_scale / unit_j`` for ``dq_j`` (``accel_scale`` = ``||M^-1||`` times the
forces summed, :class:`formalisms.interface.Split`; ``unit_j`` = 1 for an angle, the model's length scale for a
translation: a force's derivative per metre is its size over the lever), ``accel_scale / max(|v|_2, sqrt(accel_scale /
L))`` for ``dv_j`` (the velocity-product accelerations are quadratic in v, so their derivative is at most twice their
size over |v|, bounded at rest by the model's own rate) and ``||M^-1|| |B e_j|`` for ``du_j`` (eq. 17's two terms
can cancel). FACTOR is data (:data:`FACTOR`), measured like the others' (docs/tolerances.md).
"""

from __future__ import annotations

from typing import Mapping, Sequence

import numpy as np

from cases.model import Model
from crosscheck.core import tolerance
from crosscheck.core.compare import compare, Comparison
from crosscheck.core.sampling import State
from crosscheck.references import precise
from crosscheck.references.pinocchio import reference
from formalisms.interface import UNSUPPORTED, Formalism, Linearization, ModelNotSupported

#: Safety factor of the linearization tolerance (module doc), as the others' (100 eps times the scale).
FACTOR = 100.0
#: States of a case (the first ones) at which the gate checks the linearizations: derivatives cost n times a split.
STATES = 2
#: The dynamic blocks of A and B compared, by name: (rows of A or B, columns).
BLOCKS = ("dvdot/dq", "dvdot/dv", "dvdot/du", "vdot", "kinematic rows")


def tangent_units(model: Model) -> np.ndarray:
    """The unit of each tangent coordinate: 1 for an angle (revolute, a group joint's rotation), the model's length
    scale for a translation (prismatic, a free joint's linear part)."""
    L = model.length_scale
    units = []
    for body in model.bodies:
        units += {"revolute": [1.0], "prismatic": [L], "spherical": [1.0] * 3,
                  "free": [L] * 3 + [1.0] * 3}[body.joint]
    return np.array(units)


def blocks(model: Model, lin: Linearization) -> dict[str, np.ndarray]:
    """The dynamic blocks of a linearization (module doc) by name."""
    nv = model.nv
    return {"dvdot/dq": lin.A[nv:, :nv], "dvdot/dv": lin.A[nv:, nv:], "dvdot/du": lin.B[nv:], "vdot": lin.vdot,
            "kinematic rows": np.hstack([lin.A[:nv], lin.B[:nv]])}


def linearizations(model: Model, state: State, backends: Sequence[Formalism]
                   ) -> tuple[dict[str, Linearization], dict[str, str], list[str]]:
    """Each backend's linearization at ``state`` and the reference's (``pinocchio`` unconstrained, ``exact`` with
    constraints or loads Pinocchio declines): (by name, errors by name, the backends without one or declining the
    model)."""
    q, qd, u = (np.asarray(x, dtype=float) for x in (state.q, state.qd, state.u))
    found, errors, unsupported = {}, {}, []
    for backend in backends:
        if backend.name == reference.REFERENCE.name:
            continue                                   # joins below, with the 50-digit reference where it has none
        if backend.linearize is None:
            unsupported.append(backend.name)
            continue
        try:
            found[backend.name] = backend.linearize(model, q, qd, u)
        except ModelNotSupported:
            unsupported.append(backend.name)
        except Exception as exc:  # noqa: BLE001 - a backend's failure is a finding, reported by name
            errors[backend.name] = f"linearize raised {type(exc).__name__}: {exc}"
    if not model.constraints:
        try:
            found["pinocchio"] = reference.linearize(model, q, qd, u)
            return found, errors, unsupported
        except ModelNotSupported:        # world-frame loads and springs: Pinocchio's fext is fixed in the joints
            pass
        except Exception as exc:  # noqa: BLE001 - e.g. a file-built reference refusing the model: a failure, named
            errors["pinocchio"] = f"linearize raised {type(exc).__name__}: {exc}"
            return found, errors, unsupported
    found["exact"] = precise.linearize(model, q, qd, u)
    return found, errors, unsupported


def tolerances(model: Model, state: State, values: Mapping[str, np.ndarray], block: str,
               at: tolerance.Scales) -> np.ndarray:
    """The per-entry tolerance of ``block`` (module doc) for the voters' ``values`` of it."""
    stacked = np.array(list(values.values()), dtype=float)
    cond = at.cond_M * (max(at.cond_S, 1.0) if model.constraints else 1.0)
    if block == "vdot":
        return np.broadcast_to(tolerance.tolerance("total", at), (model.nv,))
    if block == "kinematic rows":                    # entries of v and exact zeros and ones: rounding of |v| at most
        return np.full(model.nv * (2 * model.nv + model.m),
                       FACTOR * tolerance.EPS * (float(np.abs(state.qd).max()) + 1.0))
    size = np.abs(stacked).max(axis=(0, 1)) if stacked.size else np.zeros(stacked.shape[-1])
    if block == "dvdot/dq":
        terms = at.accel_scale / tangent_units(model)
    elif block == "dvdot/dv":
        rate = max(float(np.linalg.norm(state.qd)), np.sqrt(at.accel_scale / model.length_scale))
        terms = np.full(model.nv, at.accel_scale / max(rate, tolerance.TINY))
    else:
        terms = at.minv * np.abs(model.input_map).max(axis=0)
    column = FACTOR * tolerance.EPS * cond * np.maximum(size + terms, tolerance.TINY)
    return np.broadcast_to(column, stacked.shape[1:]).ravel()


def checks(model: Model, state: State, backends: Sequence[Formalism], at: tolerance.Scales
           ) -> tuple[dict[str, Comparison], dict[str, str]]:
    """The comparisons of the dynamic blocks of A and B (module doc) at ``state``, and the backends' errors."""
    found, errors, unsupported = linearizations(model, state, backends)
    return compared(model, state, found, unsupported, at), errors


def compared(model: Model, state: State, found: Mapping[str, Linearization], unsupported: Sequence[str],
             at: tolerance.Scales) -> dict[str, Comparison]:
    """The comparison of each block (:data:`BLOCKS`) among the linearizations ``found`` (the ``unsupported``
    backends joining as UNSUPPORTED), with the tolerance of :func:`tolerances`."""
    out = {}
    for block in BLOCKS:
        values = {name: blocks(model, lin)[block] for name, lin in found.items()}
        tol = tolerances(model, state, values, block, at)
        flat = {name: np.asarray(value, dtype=float).ravel() for name, value in values.items()}
        flat.update(dict.fromkeys(unsupported, UNSUPPORTED))
        out[f"linearization: {block}"] = compare(block, flat, tol)
    return out
