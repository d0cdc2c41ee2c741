"""The closed forms the tests use as independent references: a re-export of ``crosscheck.references.closed_forms``, where they
are typed in once from the article (section 3: eqs. 4-9; 5.6) or derived by hand, and where the gate's voter
``closed_form`` uses them too. See that module for each formula's equations; the names the tests import:

* ``endpoint_jacobian``, ``tip_position``, ``tip_bias``   eqs. (4), (5) and the tip's ``Jdot qd``
* ``article_M``, ``article_Cqd``, ``article_g``, ``pendulum_terms``
                                                            eqs. (6), (7), (8); ``pendulum_terms_mp`` the same in mpmath
* ``inv2``                                                  the 2x2 inverse of section 4.7.2
* ``absolute_terms``                                        (M, C qd, g) in absolute angles (section 6.4.6)
* ``disk_inertia``                                          what rotational inertias of the masses add to eq. (6)
* ``circle_terms``, ``circle_state``                        the tip on a circle (5.6): phi, Jc, Jcdot qd; an
                                                            admissible state by inverse kinematics of eq. (4)
* ``constrained_input_map``                                 B_c of eq. (17)
* ``cartesian_lam``, ``cartesian_lam_mp``                   the cartesian pendulum's multiplier (double, mpmath)
* ``absolute_loop_state``, ``loop_to_joint``, ``pin_forces``
                                                            the absolute-coordinate double pendulum: a joint state in
                                                            its coordinates, its accelerations back, its pins' forces

and three test utilities that are numerics, not closed forms: ``kkt_solve`` (the KKT system of 5.6 by one dense
solve), ``min_norm_solve`` (the range-space solve with S's pseudo-inverse, for redundant rows) and
``heaviest_body_heavier`` (a model with one mass perturbed).

Not a test module (no ``test_`` prefix): the test files import it as ``from closed_forms import ...``, which works
because pytest's default ("prepend") import mode puts this directory on ``sys.path`` (there is no
``tests/__init__.py``).
"""

from __future__ import annotations

import dataclasses

import numpy as np

import cases
from crosscheck.references.closed_forms.algebra import inv2  # noqa: F401 (re-exported)
from crosscheck.references.closed_forms.constrained import (  # noqa: F401 (re-exported)
    absolute_loop_state, cartesian_lam, cartesian_lam_mp, circle_state, circle_terms, constrained_input_map,
    loop_to_joint, pin_forces)
from crosscheck.references.closed_forms.pendulums import (  # noqa: F401 (re-exported)
    absolute_terms, article_Cqd, article_g, article_M, disk_inertia, endpoint_jacobian, pendulum_terms,
    pendulum_terms_mp, tip_bias, tip_position)


def kkt_solve(M, Jc, f, bias):
    """Article 5.6: ``[[M, -Jc^T], [Jc, 0]] [qdd; lam] = [f; -Jcdot qd]`` with ``f = B u - C qd - g`` (eqs. 12, 13;
    ``f = -C qd - g`` gives the drift and lam_drift of eq. 14). ``Jc`` a row (one constraint) or k x n, ``bias``
    = ``Jcdot qd`` a scalar or (k,). Returns ``(qdd, lam)``."""
    Jc, bias = np.atleast_2d(Jc), np.atleast_1d(bias)
    n, k = len(M), len(Jc)
    K = np.block([[M, -Jc.T], [Jc, np.zeros((k, k))]])
    x = np.linalg.solve(K, np.concatenate([f, -bias]))
    return x[:n], x[n:]


def min_norm_solve(M, Jc, f, bias, rcond):
    """Article 5.6 with redundant rows, by the range-space method: ``lam = S^+ (-Jcdot qd - Jc M^-1 f)`` with
    ``S = Jc M^-1 Jc^T`` and its pseudo-inverse cut at ``rcond`` (eigenvalues below rcond times the largest are
    redundant directions), ``qdd = M^-1 (f + Jc^T lam)``: the minimum-norm multipliers; with full rank the KKT
    solution. Returns ``(qdd, lam)``."""
    Jc, bias = np.atleast_2d(Jc), np.atleast_1d(bias)
    Minv = np.linalg.inv(M)
    S = Jc @ Minv @ Jc.T
    lam = np.linalg.pinv(S, rcond=rcond, hermitian=True) @ (-bias - Jc @ Minv @ f)
    return Minv @ (f + Jc.T @ lam), lam


def heaviest_body_heavier(model, relative: float):
    """``model`` with its heaviest body's mass scaled by ``1 + relative``: a small modelling error a tolerance must
    resolve."""
    heavy = int(np.argmax([b.mass for b in model.bodies]))
    bodies = [dataclasses.replace(b, mass=b.mass * (1.0 + relative)) if i == heavy else b
              for i, b in enumerate(model.bodies)]
    return cases.build_model(f"{model.name}_heavier", bodies, gravity=model.gravity, input_map=model.input_map,
                             task_points=model.task_points, constraints=model.constraints)
