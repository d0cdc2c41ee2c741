"""Hints on a small error in a plugin's mass matrix (``crosscheck.reports.diagnosis.own_mass_matrix``): inertias
rounded at 1e-10 relative leave drift and ctrl within or near their tolerances and show mostly in the kinetic energy
or in ctrl alone; the work identity ``a . M a = a . B u`` at the plugin's own ctrl names its M, while an error in the
energy bookkeeping alone or in the input map alone is not blamed on M."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from crosscheck import backends
from crosscheck.assemble import Sizes, unconstrained_split
from crosscheck.engine.run import run_gate
from crosscheck.engine.specs import CaseSpec, Checks
from crosscheck.reports import diagnosis

ARM = str(Path(__file__).resolve().parents[2] / "examples" / "arm.urdf")
QUICK = Checks(charts=False, frames=0, conservation=False, closed_forms=False, self_test=False, linearization=False)


class Rounded:
    """Pinocchio's M, C qd and g (as examples/my_dynamics.py) with one body's inertia (mass and rotational inertia)
    scaled by ``1 + dynamics`` in the M it solves with and by ``1 + energy`` in the M of its kinetic energy, and its
    input map scaled by ``1 + input_map``."""

    needs = "pinocchio"

    def __init__(self, name: str, body: int, dynamics: float = 0.0, energy: float = 0.0, input_map: float = 0.0):
        self.name, self.body = name, body
        self.dynamics, self.energy, self.input_map = dynamics, energy, input_map

    def _mass_matrix(self, scene, q_p, relative: float) -> np.ndarray:
        import pinocchio as pin

        model = scene.model.copy()
        inertia = model.inertias[self.body]
        model.inertias[self.body] = pin.Inertia(inertia.mass * (1 + relative), inertia.lever,
                                                inertia.inertia * (1 + relative))
        M = scene.ours_matrix(pin.crba(model, model.createData(), q_p))
        return np.triu(M) + np.triu(M, 1).T                                  # crba fills the upper triangle

    def split(self, scene, q, qd, u):
        import pinocchio as pin

        model, data = scene.model, scene.data
        q_p, v_p = scene.configuration(q), scene.velocity(qd)
        M, M_energy = self._mass_matrix(scene, q_p, self.dynamics), self._mass_matrix(scene, q_p, self.energy)
        g = scene.ours(pin.computeGeneralizedGravity(model, data, q_p))
        Cqd = scene.ours(pin.nonLinearEffects(model, data, q_p, v_p)) - g
        qd = np.asarray(qd, dtype=float)
        tau = (1 + self.input_map) * scene.input_map @ np.asarray(u, dtype=float)
        drift, ctrl = np.linalg.solve(M, -(Cqd + g)), np.linalg.solve(M, tau)
        sizes = Sizes(mass=sum(inertia.mass for inertia in model.inertias), gravity=model.gravity.linear)
        return unconstrained_split(sizes, M=M, Cqd=Cqd, g=g, tau_ctrl=tau, qd=qd, drift=drift, ctrl=ctrl,
                                   total=drift + ctrl, kinetic_energy=0.5 * qd @ M_energy @ qd)


@pytest.fixture(autouse=True)
def no_plugins():
    backends.reset()
    yield
    backends.reset()


def _hints(plugin: Rounded, samples: int = 10) -> list[str]:
    backends.register(plugin)
    chosen = [backends.get(name) for name in backends.names()]
    result = run_gate([CaseSpec("arm", path=ARM)], chosen, samples, 0, checks=QUICK)
    assert diagnosis.annotate(result, chosen) == sum(s.failed for s in result.cases[0].states)
    return [s.hint for s in result.cases[0].states if s.failed]


def test_inertias_rounded_at_1e_10_are_hinted_as_the_mass_matrix():
    """The shoulder link's inertia off by 1e-10: failing states show only ctrl, only the kinetic energy, or only the
    total (drift agrees everywhere); every hint names the mass matrix."""
    hints = _hints(Rounded("rounded", body=1, dynamics=1e-10, energy=1e-10))
    assert hints and all(h.endswith(diagnosis.INERTIA) or "(M is what" in h for h in hints), hints
    alone = [h for h in hints if h.startswith(("only in ctrl", "only in kinetic_energy", "drift and ctrl agree"))]
    assert alone, hints                        # the states the identity decides: no acceleration pair shows M
    assert all("its energy and its ctrl share one M that is not the others'" in h for h in alone)


def test_an_energy_bookkeeping_error_alone_is_not_hinted_as_the_mass_matrix():
    """Inertias rounded (1e-9) in the kinetic energy only (its dynamics use the right M): its energy at its own
    ctrl is off its own work as much as off the others', so the energy bookkeeping is named, not M."""
    hints = _hints(Rounded("energy_only", body=1, energy=1e-9))
    assert hints and all(h.startswith("only in kinetic_energy (the accelerations agree): the kinetic energy "
                                      "bookkeeping") for h in hints), hints


def test_an_input_map_error_alone_is_not_hinted_as_the_mass_matrix():
    """B off by 1e-9 with the right M: ctrl alone is off, its energy agrees with the others', the input map is
    named."""
    hints = _hints(Rounded("input_map", body=1, input_map=1e-9))
    assert hints and all(h.startswith("only in ctrl") and h.endswith("the input map B or M^-1 B u")
                         for h in hints), hints
