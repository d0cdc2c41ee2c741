"""A user's own backend for crosscheck: the planar double pendulum in closed form (article section 3).

The equations are typed in from the article, not derived by a program: the mass matrix (eq. 6), the velocity
products C qd (eq. 7), the gravity terms (eq. 8), the 2x2 inverse of section 4.7.2 and the drift/control split of
eq. (9). They hold for one mechanism: two revolute joints about parallel axes, point masses m1 at the end of link 1
(where link 2 is pinned) and m2 at the end of link 2, theta1 measured from hanging down along gravity and theta2
relative to link 1. :func:`parameters` reads m1, m2, l1, l2 and g off a crosscheck model and raises
``ModelNotSupported`` with the reason for any other model; the gate then reports this backend as NOT COMPARED on
that case. The geometry and gravity are read in link 1's joint frame, so the gate's moved scenes (frame checks)
are the same pendulum.

Supplied: drift, ctrl, total, the control power and the kinetic energy 1/2 qd^T M qd. Not supplied: the task-point
acceleration (``task_drift`` is UNSUPPORTED; the gate lists this backend as "not supplied by" there).

    pip install ./examples/closed_form_plugin          # the entry point: every crosscheck command includes it
    crosscheck gate --case double_pendulum

or, without installing, from this directory: ``crosscheck gate --plugin closed_form_pendulum:CLOSED_FORM``.

``SIGN_ERROR`` is the same backend with one deliberate bug, the sign of the centrifugal term ``c theta1d^2`` in the
second row of eq. (7) flipped; ``crosscheck gate --plugin closed_form_pendulum:SIGN_ERROR --case double_pendulum``
fails and names it as the outlier.
"""

from __future__ import annotations

from dataclasses import dataclass
from functools import partial

import numpy as np

from crosscheck.assemble import unconstrained_split
from formalisms.interface import Formalism, ModelNotSupported, Split, check_state

#: Relative tolerance on the geometry read off a model (a moved scene rounds it at 1e-16).
GEOMETRY_TOL = 1e-9


@dataclass(frozen=True)
class Pendulum:
    """The article's parameters: point masses (kg), link lengths (m), gravity (m/s^2)."""

    m1: float
    m2: float
    l1: float
    l2: float
    g: float


def _close(a, b) -> bool:
    a, b = np.asarray(a, dtype=float), np.asarray(b, dtype=float)
    return float(np.abs(a - b).max()) <= GEOMETRY_TOL * (1.0 + float(np.abs(b).max()))


def parameters(model) -> Pendulum:
    """m1, m2, l1, l2 and g of ``model``, or ModelNotSupported saying why it is not the mechanism of section 3."""
    def require(ok: bool, why: str) -> None:
        if not ok:
            raise ModelNotSupported(f"model '{model.name}' is not the point-mass double pendulum of article section "
                                    f"3 this closed form was derived for: {why}")

    require(model.n == 2 and not model.constraints,
            f"it has {model.n} joints and {model.k} constraint rows (2 and 0 needed)")
    link1, link2 = model.bodies
    require(link1.parent is None and link2.parent == link1.name, "its bodies are not a chain world - link 1 - link 2")
    require(link1.joint == link2.joint == "revolute", "a joint is not revolute")
    require(not np.any(link1.inertia) and not np.any(link2.inertia),
            "a body has rotational inertia (eq. 6 is for point masses)")
    l1, l2 = float(np.linalg.norm(link1.com)), float(np.linalg.norm(link2.com))
    require(l1 > 0.0 and l2 > 0.0, "a mass sits on its joint axis")
    down = np.asarray(link1.com) / l1                        # link 1's direction at theta1 = 0, in its joint frame
    require(_close(link2.translation, link1.com), "mass 1 is not where link 2 is pinned (the end of link 1)")
    require(_close(link2.rotation @ link2.axis, link1.axis), "the joint axes are not parallel (same sense)")
    require(abs(float(down @ link1.axis)) <= GEOMETRY_TOL, "link 1 does not lie in the plane normal to its axis")
    require(_close(link2.rotation @ link2.com / l2, down), "link 2 does not continue link 1 at theta2 = 0")
    gravity = link1.rotation.T @ model.gravity                # in link 1's joint frame: unchanged by a moved scene
    g = float(np.linalg.norm(gravity))
    require(_close(gravity, g * down), "at q = 0 the links do not hang along gravity (eq. 3 measures from there)")
    return Pendulum(link1.mass, link2.mass, l1, l2, g)


def mass_matrix(p: Pendulum, q) -> np.ndarray:
    """Eq. (6)."""
    c2 = np.cos(q[1])
    m12 = p.m2 * p.l2**2 + p.m2 * p.l1 * p.l2 * c2
    return np.array([[(p.m1 + p.m2) * p.l1**2 + p.m2 * p.l2**2 + 2.0 * p.m2 * p.l1 * p.l2 * c2, m12],
                     [m12, p.m2 * p.l2**2]])


def velocity_terms(p: Pendulum, q, qd) -> np.ndarray:
    """Eq. (7): C qd = [-2 c t1d t2d - c t2d^2, c t1d^2], c = m2 l1 l2 sin t2."""
    c = p.m2 * p.l1 * p.l2 * np.sin(q[1])
    return np.array([-2.0 * c * qd[0] * qd[1] - c * qd[1] ** 2, c * qd[0] ** 2])


def velocity_terms_sign_error(p: Pendulum, q, qd) -> np.ndarray:
    """Eq. (7) mistyped, deliberately: the centrifugal term of row 2 with the wrong sign (``-c t1d^2``)."""
    c = p.m2 * p.l1 * p.l2 * np.sin(q[1])
    return np.array([-2.0 * c * qd[0] * qd[1] - c * qd[1] ** 2, -c * qd[0] ** 2])


def gravity_terms(p: Pendulum, q) -> np.ndarray:
    """Eq. (8)."""
    s12 = np.sin(q[0] + q[1])
    return np.array([(p.m1 + p.m2) * p.g * p.l1 * np.sin(q[0]) + p.m2 * p.g * p.l2 * s12, p.m2 * p.g * p.l2 * s12])


def inverse(M: np.ndarray) -> np.ndarray:
    """The 2x2 inverse of section 4.7.2: (1 / det M) [[M22, -M12], [-M21, M11]]."""
    det = M[0, 0] * M[1, 1] - M[0, 1] * M[1, 0]
    return np.array([[M[1, 1], -M[0, 1]], [-M[1, 0], M[0, 0]]]) / det


def split(model, q, qd, u, velocity_terms=velocity_terms) -> Split:
    """Eq. (9): drift ``-M^-1 (C qd + g)``, ctrl ``M^-1 B u``, total ``M^-1 (B u - C qd - g)``, each directly."""
    p = parameters(model)
    q, qd, u = check_state(model, q, qd, u)
    M, Cqd, g = mass_matrix(p, q), velocity_terms(p, q, qd), gravity_terms(p, q)
    tau = model.input_map @ u
    Minv = inverse(M)
    return unconstrained_split(model, M=M, Cqd=Cqd, g=g, tau_ctrl=tau, qd=qd, drift=-Minv @ (Cqd + g),
                               ctrl=Minv @ tau, total=Minv @ (tau - Cqd - g), kinetic_energy=0.5 * qd @ M @ qd)


CLOSED_FORM = Formalism("closed_form_pendulum",
                        "the article's double pendulum in closed form (eqs. 6-9); that mechanism only", split)

SIGN_ERROR = Formalism("closed_form_pendulum_sign_error",
                       "CLOSED_FORM with a deliberate bug: the centrifugal term of eq. (7) with the wrong sign",
                       partial(split, velocity_terms=velocity_terms_sign_error))
