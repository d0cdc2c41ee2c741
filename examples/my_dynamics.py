"""Your own dynamics code as a crosscheck backend (the README's second example): M, C qd and g of the scene's
Pinocchio model, then the drift/control split of eq. (9), drift = -M^-1 (C qd + g), ctrl = M^-1 B u. Replace the
three lines marked "your code" with your own implementation; crosscheck then checks it state by state against
the five formalisms and Pinocchio."""

import numpy as np
import pinocchio as pin

from crosscheck.assemble import Sizes, unconstrained_split
from formalisms.interface import ModelNotSupported


class MyDynamics:
    name = "my_dynamics"
    needs = "pinocchio"                    # split gets a PinocchioScene built from the same URDF (crosscheck.needs)

    def split(self, scene, q, qd, u):
        if scene.constraints:
            raise ModelNotSupported("my_dynamics handles unconstrained models only")
        model, data = scene.model, scene.data
        q_p, v_p = scene.configuration(q), scene.velocity(qd)
        M = scene.ours_matrix(pin.crba(model, data, q_p))                            # your code: M(q)
        M = np.triu(M) + np.triu(M, 1).T                                              # crba fills the upper triangle
        g = scene.ours(pin.computeGeneralizedGravity(model, data, q_p))              # your code: g(q)
        Cqd = scene.ours(pin.nonLinearEffects(model, data, q_p, v_p)) - g            # your code: C(q, qd) qd
        qd, tau = np.asarray(qd, dtype=float), scene.input_map @ np.asarray(u, dtype=float)
        drift, ctrl = np.linalg.solve(M, -(Cqd + g)), np.linalg.solve(M, tau)
        sizes = Sizes(mass=sum(inertia.mass for inertia in model.inertias[1:]), gravity=model.gravity.linear)
        return unconstrained_split(sizes, M=M, Cqd=Cqd, g=g, tau_ctrl=tau, qd=qd,
                                   drift=drift, ctrl=ctrl, total=drift + ctrl, kinetic_energy=0.5 * qd @ M @ qd)


MY_DYNAMICS = MyDynamics()
