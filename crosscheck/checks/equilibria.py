"""Equilibria with closed-form eigenvalues: the linearization's check against physics (article 4.8, eq. 11).

At an equilibrium (v = 0, drift = 0) of a conservative model, ``A = [[0, I], [-M0^-1 K, 0]]`` with ``M0`` the mass
matrix and ``K`` the Hessian of the potential there, so the eigenvalues are ``+-sqrt(-mu)`` for the roots ``mu`` of
``det(K - mu M0) = 0``: a pair ``+-i omega`` per stable mode (``mu = omega^2 > 0``), a real pair ``+-sqrt(|mu|)`` per
unstable one. M0 and K are written here from the cases' typed parameters (their docstrings), not from any backend:

* the double pendulum (``cases.factories.double_pendulum``, point masses plus optional rotational inertias, relative
  angles from hanging down): ``V = -g ((m1 + m2) l1 cos t1 + m2 l2 cos(t1 + t2))``; at ``(t1, t2) = (s, 0)`` with
  ``c = cos s = +-1`` (hanging: s = 0, inverted: s = pi) ``K = c g [[(m1 + m2) l1 + m2 l2, m2 l2], [m2 l2, m2 l2]]``
  and ``M0 = [[m1 l1^2 + m2 (l1^2 + l2^2 + 2 l1 l2) + I1 + I2 + a1, m2 (l2^2 + l1 l2) + I2], [., m2 l2^2 + I2 +
  a2]]`` (a1, a2 the joints' armature, a rotor's inertia on M's diagonal);
* the spherical pendulum hanging (``spherical_pendulum`` at q = 0): the axes decouple, ``omega_k^2 = m g l / (m l^2 +
  I_k)`` about x (k = x) and y;
* the parallelogram four-bar at rest (``four_bar`` with crank = rocker = a, coupler = ground, uniform rods of mass m:
  crank and rocker hanging, the coupler level, q = (0, pi/2, 0)): one degree of freedom, the crank angle t, with the
  coupler translating, ``T = 1/2 (2 m a^2 / 3 + m a^2) tdot^2`` and ``V = -2 m g a cos t``, so ``omega^2 = 6 g / (5
  a)``. A constrained model's A (the KKT dynamics, also off the constraint manifold) has besides ``+-i omega`` 2k
  eigenvalues at 0 (``d^2 phi / dt^2 = 0`` along every constraint row; a Jordan structure, so rounding moves them by
  about ``sqrt(eps)``): the check compares the ``2 (n - k)`` eigenvalues of the motion, largest in modulus.

Under a chart ``q = psi(p)`` the equilibrium is one too, and there ``A_p = T^-1 A_q T`` with ``T = diag(Dpsi, Dpsi)``
(the chart's velocity-product term vanishes at rest): a similarity, so the eigenvalues do not change.

Tolerance. A simple eigenvalue moves by ``|d lambda| <= kappa ||dA||`` with ``kappa = |x| |y| / |y^H x|`` (x, y its
right and left eigenvectors; the largest over the compared eigenvalues, median over the voters) and ``||dA||``
bounded by the linearization check's tolerance of the ``dvdot/dq`` block (``crosscheck.checks.linearization``) summed
over a row, so an eigenvalue is held to exactly what the compared blocks are.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Callable, Sequence

import numpy as np
import scipy.linalg

import cases
from cases.model import Model
from crosscheck.checks import linearization
from crosscheck.core import tolerance
from crosscheck.core.compare import compare, Comparison
from crosscheck.core.sampling import State
from crosscheck.references import precise
from formalisms.interface import Formalism, Linearization, ModelNotSupported


@dataclass(frozen=True)
class Equilibrium:
    """A named equilibrium of a case: its configuration (v = 0, u = 0) and the closed-form ``(M0, K)`` (module doc)."""

    name: str
    case: str
    q: Callable[[Model], np.ndarray]
    stiffness: Callable[[dict], tuple[np.ndarray, np.ndarray]]
    applies: Callable[[dict], bool] = lambda params: True
    #: The joints' armature its M0 adds (``Body.armature``, per velocity) from the parameters; None: M0 has none, and a
    #: model with armature is refused (:func:`checks`), never checked against an M0 that drops it.
    armature: Callable[[dict], np.ndarray] | None = None

    def eigenvalues(self, params: dict) -> np.ndarray:
        """The closed-form eigenvalues of A: ``+-sqrt(-mu)``, mu the roots of ``det(K - mu M0)`` (module doc)."""
        M0, K = self.stiffness(params)
        mu = np.linalg.eigvals(np.linalg.solve(M0, K)).real
        return sort(np.concatenate([np.sqrt(-mu + 0j), -np.sqrt(-mu + 0j)]))


def sort(w: np.ndarray) -> np.ndarray:
    """Eigenvalues in a canonical order: by real part, then imaginary part (rounded, so a pair of conjugates and
    of opposites pairs up between backends)."""
    w = np.asarray(w, dtype=complex)
    return w[np.lexsort((np.round(w.imag, 9), np.round(w.real, 9)))]


def _double_pendulum(c: float) -> Callable[[dict], tuple[np.ndarray, np.ndarray]]:
    def stiffness(p: dict) -> tuple[np.ndarray, np.ndarray]:
        m1, m2, l1, l2, g, I1, I2, a1, a2 = (p[k] for k in ("m1", "m2", "l1", "l2", "g", "I1", "I2", "a1", "a2"))
        M0 = np.array([[m1 * l1**2 + m2 * (l1**2 + l2**2 + 2 * l1 * l2) + I1 + I2 + a1, m2 * (l2**2 + l1 * l2) + I2],
                       [m2 * (l2**2 + l1 * l2) + I2, m2 * l2**2 + I2 + a2]])
        K = c * g * np.array([[(m1 + m2) * l1 + m2 * l2, m2 * l2], [m2 * l2, m2 * l2]])
        return M0, K
    return stiffness


def _spherical_pendulum(p: dict) -> tuple[np.ndarray, np.ndarray]:
    m, l, g = p["m"], p["l"], p["g"]
    return np.diag([m * l**2 + p["Ix"], m * l**2 + p["Iy"]]), np.diag([m * g * l, m * g * l])


def _parallelogram(p: dict) -> tuple[np.ndarray, np.ndarray]:
    a, m, g = p["crank"], p["m"], p["g"]
    return np.array([[5.0 * m * a**2 / 3.0]]), np.array([[2.0 * m * g * a]])


EQUILIBRIA: tuple[Equilibrium, ...] = (
    Equilibrium("hanging", "double_pendulum", lambda model: np.zeros(2), _double_pendulum(1.0),
                armature=lambda p: np.array([p["a1"], p["a2"]], dtype=float)),
    Equilibrium("inverted", "double_pendulum", lambda model: np.array([np.pi, 0.0]), _double_pendulum(-1.0),
                armature=lambda p: np.array([p["a1"], p["a2"]], dtype=float)),
    Equilibrium("hanging", "spherical_pendulum", lambda model: np.zeros(2), _spherical_pendulum),
    Equilibrium("at rest", "four_bar", lambda model: np.array([0.0, np.pi / 2, 0.0]), _parallelogram,
                lambda p: p["crank"] == p["rocker"] and p["coupler"] == p["ground"]),
)


def of_case(case: str, params: dict | None = None) -> tuple[Equilibrium, ...]:
    """The equilibria with closed forms of the case ``case`` (with ``params``, those that apply to them)."""
    return tuple(e for e in EQUILIBRIA if e.case == case and (params is None or e.applies(params)))


def motion(A: np.ndarray, count: int) -> np.ndarray:
    """The ``count`` eigenvalues of A largest in modulus (the motion's; module doc), in canonical order."""
    w = np.linalg.eigvals(A)
    return sort(w[np.argsort(-np.abs(w), kind="stable")[:count]])


def _kappa(A: np.ndarray, count: int) -> float:
    """The largest condition number ``|x| |y| / |y^H x|`` of the ``count`` eigenvalues of A largest in modulus."""
    w, left, right = scipy.linalg.eig(A, left=True, right=True)
    chosen = np.argsort(-np.abs(w), kind="stable")[:count]
    dots = np.abs(np.sum(left[:, chosen].conj() * right[:, chosen], axis=0))
    return float(np.max(1.0 / np.maximum(dots, np.finfo(float).tiny)))


def _bound(model: Model, state: State, values: dict[str, Linearization], at: tolerance.Scales, count: int) -> float:
    """``kappa ||dA||`` (module doc) with ``||dA||`` the ``dvdot/dq`` block's tolerance summed along a row."""
    blocks = {name: linearization.blocks(model, lin)["dvdot/dq"] for name, lin in values.items()}
    tol = linearization.tolerances(model, state, blocks, "dvdot/dq", at).reshape(model.nv, model.nv)
    kappa = float(np.median([_kappa(lin.A, count) for lin in values.values()]))
    return kappa * float(tol.sum(axis=1).max())


def checks(equilibrium: Equilibrium, params: dict, model: Model, backends: Sequence[Formalism],
           case_charts: Sequence = ()) -> tuple[dict[str, Comparison], dict[str, str]]:
    """Every backend's eigenvalues of A at the equilibrium against the closed form (voter ``closed_form``), and for
    each chart and backend with ``linearize_chart`` the eigenvalues in the chart and the similarity
    ``A_p = T^-1 A_q T`` (module doc); and the errors the backends raised, by name."""
    expected = np.zeros(model.nv) if equilibrium.armature is None else equilibrium.armature(params)
    if not np.array_equal(np.asarray(expected, dtype=float), model.armature_vector):
        return {}, {f"closed_form (equilibrium {equilibrium.name})": (
            f"ClosedFormMismatch: the model's armature is {model.armature_vector.tolist()}, the closed-form M0's "
            f"{np.asarray(expected, dtype=float).tolist()}: the equilibrium's eigenvalues are not checked")}
    q = equilibrium.q(model)
    zero_v, zero_u = np.zeros(model.nv), np.zeros(model.m)
    state = State(index=0, q=tuple(q), qd=tuple(zero_v), u=tuple(zero_u))
    found, splits, errors = {}, {}, {}
    for backend in backends:
        if backend.linearize is None:
            continue
        try:
            found[backend.name] = backend.linearize(model, q, zero_v, zero_u)
            splits[backend.name] = backend.split(model, q, zero_v, zero_u)
        except ModelNotSupported:
            found.pop(backend.name, None)
        except Exception as exc:  # noqa: BLE001 - a backend's failure is a finding, reported by name
            found.pop(backend.name, None)
            errors[f"{backend.name} (equilibrium {equilibrium.name})"] = f"{type(exc).__name__}: {exc}"
    if not found:
        return {}, errors
    if model.constraints:                        # the 50-digit reference votes where Pinocchio's derivatives do not
        found["exact"] = precise.linearize(model, q, zero_v, zero_u)
    at = tolerance.scales(splits.values(), model, q, zero_v, u=zero_u)
    exact = equilibrium.eigenvalues(params)
    count = len(exact)
    tol = _bound(model, state, found, at, count)
    title = f"equilibrium {equilibrium.name}"
    out = {f"{title}: eigenvalues of A": compare(
        "eigenvalues", {**{n: _pairs(motion(lin.A, count)) for n, lin in found.items()},
                        "closed_form": _pairs(exact)}, tol)}
    for chart in case_charts:
        p = chart.p_of(q)
        D = chart.jacobian(p)
        T = np.kron(np.eye(2), D)
        moved = {}
        for backend in backends:
            if backend.linearize_chart is None or backend.name not in found:
                continue
            try:
                lin_p = backend.linearize_chart(model, chart, p, np.zeros(model.nv), np.zeros(model.nv))
            except Exception as exc:  # noqa: BLE001
                errors[f"{backend.name} (equilibrium {equilibrium.name}, chart {chart.name})"] = \
                    f"{type(exc).__name__}: {exc}"
                continue
            moved[backend.name] = (lin_p, np.linalg.solve(T, found[backend.name].A @ T))
        if not moved:
            continue
        out[f"{title} in chart {chart.name}: eigenvalues of A_p"] = compare(
            "eigenvalues", {**{n: _pairs(motion(lin.A, count)) for n, (lin, _) in moved.items()},
                            "closed_form": _pairs(exact)}, tol * np.linalg.cond(D))
        out[f"{title} in chart {chart.name}: A_p - T^-1 A T"] = compare(
            "A_p - T^-1 A T", {**{n: (lin.A - similar).ravel() for n, (lin, similar) in moved.items()},
                               "exact": 0.0}, tol * np.linalg.cond(D))
    return out, errors


def _pairs(w: np.ndarray) -> np.ndarray:
    """Eigenvalues as real numbers for the comparison: real and imaginary parts of the canonical order."""
    w = sort(w)
    return np.concatenate([w.real, w.imag])


def case_params(case: str, overrides: dict | None = None) -> dict:
    """The case's parameters (defaults updated by ``overrides``), as the closed forms read them."""
    params = {k: v for k, v in cases.parameters(case).items()}
    params.update(overrides or {})
    return params


__all__ = ["EQUILIBRIA", "Equilibrium", "case_params", "checks", "of_case", "sort"]
