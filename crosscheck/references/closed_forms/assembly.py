"""A closed form's terms assembled into a :class:`~formalisms.interface.Split`: drift, ctrl (``B_c B u`` computed
directly) and total, with constraints the KKT solution and the multipliers, the powers, the task quantities, and
cond(M), ``accel_scale`` and the constraint conditions by their definitions."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from crosscheck.references.closed_forms.algebra import eigenvalues
from crosscheck.references.closed_forms.constrained import constrained_input_map, Rule
from formalisms.interface import Split


# ---------------------------------------------------------------------------------------- assembling a Split


@dataclass(frozen=True)
class Terms:
    """One state's ``M qdd + C qd + g = tau (+ Jc^T lam)`` in closed form (tau = B u), with M's inverse, the total
    mass and ``|gravity|_1`` (for accel_scale)."""

    M: np.ndarray
    Minv: np.ndarray
    Cqd: np.ndarray
    g: np.ndarray
    tau: np.ndarray
    mass: float
    gravity: float
    tau_ext: np.ndarray | None = None     # the external loads' generalized force; ``g`` is then ``dV/dq - tau_ext``

    def accelerations(self) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Eq. (9), each directly: drift ``-M^-1 (C qd + g)``, ctrl ``M^-1 B u``, total ``M^-1 (B u - C qd - g)``."""
        return (-self.Minv @ (self.Cqd + self.g), self.Minv @ self.tau, self.Minv @ (self.tau - self.Cqd - self.g))

    def forces(self) -> tuple[np.ndarray, np.ndarray]:
        """The right-hand sides ``f`` of eq. (12): ``B u - C qd - g`` (total) and ``-C qd - g`` (drift, eq. 14)."""
        return self.tau - self.Cqd - self.g, -self.Cqd - self.g

    def accel_scale(self, qd) -> float:
        """``accel_scale = ||M^-1|| H``, ``H = |C qd|_1 + |g|_1 + |B u|_1 + lambda_max(M) |qd|^2 + |gravity|_1
        sqrt(m_total lambda_max(M))`` (the definition of ``Split.accel_scale``, before the constraint force)."""
        w = eigenvalues(self.M)
        external = 0.0 if self.tau_ext is None else np.abs(self.tau_ext).sum()
        return (np.abs(self.Cqd).sum() + np.abs(self.g).sum() + np.abs(self.tau).sum() + w[-1] * float(qd @ qd)
                + self.gravity * np.sqrt(self.mass * w[-1]) + external) / w[0]


@dataclass(frozen=True)
class Kkt:
    """A constrained state's closed forms: phi, Jc, Jcdot qd, the multipliers with and without input, and the
    rule (with the case's scales) that decides S's redundant directions."""

    phi: np.ndarray
    Jc: np.ndarray
    bias: np.ndarray
    lam: np.ndarray
    lam_drift: np.ndarray
    rule: Rule


def _residuals(t: Terms, Jc, bias) -> list[np.ndarray]:
    """The KKT right-hand sides ``r = -Jcdot qd - Jc M^-1 f`` for total and drift (:meth:`Terms.forces`): eliminating
    qdd from eqs. (12), (13) leaves ``S lam = r``."""
    return [-bias - Jc @ t.Minv @ f for f in t.forces()]


def constrained_solution(t: Terms, phi, Jc, bias, rule: Rule) -> tuple[np.ndarray, np.ndarray, np.ndarray, Kkt]:
    """Eqs. (12)-(17) by the range-space method under the backends' rule (:class:`Rule`): with ``S^+`` the
    pseudo-inverse over S's kept eigen-directions (:meth:`Spectrum.pinv`), ``lam = S^+ r`` and ``qdd = M^-1 (f +
    Jc^T lam)`` (:func:`_residuals`: r; f = B u - h for total and lam, -h for the drift and lam_drift of eq. 14),
    and ``ctrl = B_c B u`` with eq. (17)'s B_c (:func:`constrained_input_map`), directly. At full rank the KKT
    solution of 5.6; at a change point the minimum-norm multipliers, with the equations along the redundant
    directions dropped where H_t is empty, as every backend does. Returns (drift, ctrl, total, :class:`Kkt`)."""
    Spinv = rule.spectrum(Jc @ t.Minv @ Jc.T).pinv()
    lam, lam_drift = (Spinv @ r for r in _residuals(t, Jc, bias))
    f_total, f_drift = t.forces()
    return (t.Minv @ (f_drift + Jc.T @ lam_drift), constrained_input_map(t.M, Jc, Spinv) @ t.tau,
            t.Minv @ (f_total + Jc.T @ lam), Kkt(phi, Jc, bias, lam, lam_drift, rule))


def assemble(t: Terms, qd, drift, ctrl, total, task, kkt: Kkt | None = None) -> Split:
    """The Split of one state from its closed forms; ``task`` = (task drift, Lambda, cond(J M^-1 J^T)).

    cond(M) and ``accel_scale`` (:meth:`Terms.accel_scale`). With constraints, by the definitions in ``Split``'s
    docstring and the backends' rule (:class:`Rule`, :class:`Spectrum` of ``S = Jc M^-1 Jc^T``): ``lam_scale =
    (|Jcdot qd|_1 + ||Jc|| accel_scale) / w_kept`` (w_kept the smallest kept eigenvalue of S; 0 when none is kept),
    ``accel_scale`` plus ``||M^-1|| ||Jc|| lam_scale``, the conditions ``constraint``, ``constraint_kept``
    (:meth:`Spectrum.conditions`) and ``constraint_consistency`` (:meth:`Spectrum.inconsistency` of the KKT
    right-hand sides, least |r| ``1e-6 L accel_scale``), the rank of S; the constraint force ``Jc^T lam`` and its
    power."""
    w = eigenvalues(t.M)
    accel_scale = t.accel_scale(qd)
    task_drift, Lambda, task_cond = task
    fields = dict(drift=drift, ctrl=ctrl, total=total, power_ctrl=float(t.tau @ qd), power_ctrl_per_coord=t.tau * qd,
                  cond_M=w[-1] / w[0], task_drift=task_drift, kinetic_energy=0.5 * qd @ t.M @ qd,
                  task_inertia=Lambda, **_drift_parts(t, kkt))
    if t.tau_ext is not None:
        fields.update(external_force=t.tau_ext, power_ext=float(t.tau_ext @ qd))
    if kkt is None:
        return Split(lam=None, lam_drift=None, power_constr=None, power_constr_per_coord=None,
                     accel_scale=accel_scale, conditions={"task_inertia": task_cond}, **fields)
    S = kkt.rule.spectrum(kkt.Jc @ t.Minv @ kkt.Jc.T)
    jc_norm = float(np.linalg.norm(kkt.Jc, 2))
    lam_scale = (np.abs(kkt.bias).sum() + jc_norm * accel_scale) / S.w[S.kept][0] if S.rank else 0.0
    consistency = S.inconsistency(_residuals(t, kkt.Jc, kkt.bias), 1e-6 * kkt.rule.length * accel_scale)
    force, force_drift = kkt.Jc.T @ kkt.lam, kkt.Jc.T @ kkt.lam_drift
    return Split(lam=kkt.lam, lam_drift=kkt.lam_drift, power_constr=float(force @ qd),
                 power_constr_per_coord=force * qd,
                 accel_scale=accel_scale + jc_norm * lam_scale / w[0],
                 conditions={"task_inertia": task_cond, **S.conditions(), "constraint_consistency": consistency},
                 constraint_value=kkt.phi, constraint_jacobian=kkt.Jc, constraint_bias=kkt.bias,
                 constraint_velocity=kkt.Jc @ qd, constraint_force=force, constraint_force_drift=force_drift,
                 constraint_rank=S.rank, lam_scale=lam_scale, **fields)


def _drift_parts(t: Terms, kkt: Kkt | None) -> dict:
    """The drift's parts (article 4.5-4.6), each solved directly: ``zvcf`` with ``f = -g`` (and, with constraints, the
    bias 0 of a state at rest) and ``drift_velocity`` with ``f = -C qd`` and the bias ``Jcdot qd``, by the range-space
    method of :func:`constrained` under the same rule."""
    if kkt is None:
        return {"zvcf": -t.Minv @ t.g, "drift_velocity": -t.Minv @ t.Cqd}
    Spinv = kkt.rule.spectrum(kkt.Jc @ t.Minv @ kkt.Jc.T).pinv()

    def solve(f, bias):
        return t.Minv @ (f + kkt.Jc.T @ (Spinv @ (-bias - kkt.Jc @ t.Minv @ f)))
    return {"zvcf": solve(-t.g, np.zeros_like(kkt.bias)), "drift_velocity": solve(-t.Cqd, kkt.bias)}


def task_terms(J, bias, drift, inertia) -> tuple:
    """(task drift ``J drift + Jdot qd`` (eq. 23), Lambda, cond) with ``inertia`` = (Lambda, cond)."""
    return (J @ drift + bias, *inertia)
