"""SE(3) and se(3) for the screw backend (article 6.2, Lynch & Park ch. 3): its own helpers, shared with nobody.

Conventions: a twist is ``V = (omega, v)`` (angular part first), a wrench ``F = (m, f)`` (moment first), and
the power of a wrench on a twist is ``F . V``. Transforms are 4x4 homogeneous matrices ``T = [[R, p], [0, 1]]``.

Every function takes a single object or a stack of them (leading axes broadcast: ``(..., 3)``, ``(..., 6)``,
``(..., 4, 4)``), so the kinematics can work on all bodies at once.
"""

from __future__ import annotations

import numpy as np

#: Below this angle (rad) the trigonometric coefficients are evaluated by their Taylor series, where the closed
#: forms lose digits to cancellation; the series are kept to the order that makes them exact to rounding here.
_SMALL = 0.2

#: Cyclic index shifts of a 3-vector's components, for :func:`cross`.
_NEXT, _PREV = np.array([1, 2, 0]), np.array([2, 0, 1])


def hat3(w: np.ndarray) -> np.ndarray:
    """``[w]``: the skew-symmetric 3x3 matrix with ``[w] x = w x x`` (so(3))."""
    w = np.asarray(w, dtype=float)
    W = np.zeros(w.shape + (3,))
    W[..., 0, 1], W[..., 0, 2], W[..., 1, 2] = -w[..., 2], w[..., 1], -w[..., 0]
    W[..., 1, 0], W[..., 2, 0], W[..., 2, 1] = w[..., 2], -w[..., 1], w[..., 0]
    return W


def vee3(W: np.ndarray) -> np.ndarray:
    """The inverse of :func:`hat3` (reads the lower triangle)."""
    W = np.asarray(W, dtype=float)
    return np.stack([W[..., 2, 1], W[..., 0, 2], W[..., 1, 0]], axis=-1)


def hat6(V: np.ndarray) -> np.ndarray:
    """``[V] = [[[omega], v], [0, 0]]``: the 4x4 se(3) matrix of the twist ``V = (omega, v)``."""
    V = np.asarray(V, dtype=float)
    X = np.zeros(V.shape[:-1] + (4, 4))
    X[..., :3, :3] = hat3(V[..., :3])
    X[..., :3, 3] = V[..., 3:]
    return X


def vee6(X: np.ndarray) -> np.ndarray:
    """The inverse of :func:`hat6`: ``(omega, v)`` from a 4x4 se(3) matrix."""
    X = np.asarray(X, dtype=float)
    return np.concatenate([vee3(X[..., :3, :3]), X[..., :3, 3]], axis=-1)


def _rotation_coefficients(x: np.ndarray):
    """``A = sin x / x``, ``B = (1 - cos x) / x^2``, ``C = (x - sin x) / x^3`` for angles ``x >= 0``."""
    small = x < _SMALL
    s = np.where(small, 1.0, x)                     # a safe divisor; the series take over below _SMALL
    x2 = x * x
    A = np.where(small, 1 - x2 / 6 * (1 - x2 / 20 * (1 - x2 / 42 * (1 - x2 / 72))), np.sin(s) / s)
    B = np.where(small, 0.5 - x2 / 24 * (1 - x2 / 30 * (1 - x2 / 56 * (1 - x2 / 90))),
                 2.0 * np.sin(0.5 * s) ** 2 / (s * s))
    C = np.where(small, 1 / 6 - x2 / 120 * (1 - x2 / 42 * (1 - x2 / 72 * (1 - x2 / 110))),
                 (s - np.sin(s)) / (s * s * s))
    return A, B, C


def exp3(phi: np.ndarray) -> np.ndarray:
    """Rodrigues: ``exp([phi]) = I + (sin x / x) [phi] + ((1 - cos x) / x^2) [phi]^2`` with ``x = |phi|``.

    ``phi = omega theta`` is a rotation vector (unit axis ``omega`` times the angle ``theta``).
    """
    phi = np.asarray(phi, dtype=float)
    A, B, _ = _rotation_coefficients(np.linalg.norm(phi, axis=-1))
    K = hat3(phi)
    return np.eye(3) + A[..., None, None] * K + B[..., None, None] * (K @ K)


def exp6(S: np.ndarray, theta=1.0) -> np.ndarray:
    """The exact SE(3) exponential ``exp([S] theta)`` (Lynch & Park eq. 3.88, article eq. 20's factors).

    With ``(phi, rho) = S theta`` and ``x = |phi|``::

        exp([S] theta) = [[exp3(phi), G rho], [0, 1]],   G = I + ((1 - cos x) / x^2) [phi] + ((x - sin x) / x^3) [phi]^2

    For a unit revolute screw (``|omega| = 1``) this is the rotation by ``theta`` about the screw axis; for a
    prismatic one (``omega = 0``) ``G = I`` and it is the translation ``v theta``; any other twist works too.
    ``theta`` broadcasts against the leading axes of ``S``.
    """
    V = np.asarray(S, dtype=float) * np.asarray(theta, dtype=float)[..., None]
    phi, rho = V[..., :3], V[..., 3:]
    A, B, C = _rotation_coefficients(np.linalg.norm(phi, axis=-1))
    K = hat3(phi)
    K2 = K @ K
    T = np.zeros(V.shape[:-1] + (4, 4))
    T[..., :3, :3] = np.eye(3) + A[..., None, None] * K + B[..., None, None] * K2
    G = np.eye(3) + B[..., None, None] * K + C[..., None, None] * K2
    T[..., :3, 3] = (G @ rho[..., None])[..., 0]
    T[..., 3, 3] = 1.0
    return T


def log3(R: np.ndarray) -> np.ndarray:
    """The rotation vector ``phi`` with ``exp3(phi) = R`` and ``|phi| = x`` in ``[0, pi]``.

    ``x = atan2(|vee(R - R^T)| / 2, (tr R - 1) / 2)``. For ``x <= pi/2`` the axis comes from the skew part,
    ``phi = vee(R - R^T) / (2 A(x))`` with ``A = sin x / x`` (a series near 0). Near ``pi`` the skew part vanishes,
    so the axis comes from the symmetric part ``omega omega^T = ((R + R^T)/2 - cos x I) / (1 - cos x)`` (the
    column of its largest diagonal entry), with the sign of the skew part.
    """
    R = np.asarray(R, dtype=float)
    skew = vee3(R - np.swapaxes(R, -1, -2))            # 2 sin x omega
    cos_x = np.clip((np.trace(R, axis1=-2, axis2=-1) - 1.0) / 2.0, -1.0, 1.0)
    x = np.arctan2(0.5 * np.linalg.norm(skew, axis=-1), cos_x)
    A, _, _ = _rotation_coefficients(x)
    near_zero = 0.5 * skew / A[..., None]
    sym = 0.5 * (R + np.swapaxes(R, -1, -2)) - cos_x[..., None, None] * np.eye(3)
    k = np.argmax(np.diagonal(sym, axis1=-2, axis2=-1), axis=-1)
    column = np.take_along_axis(sym, k[..., None, None], axis=-1)[..., 0]
    axis = column / np.linalg.norm(column, axis=-1, keepdims=True).clip(min=1e-300)
    axis = np.where(np.sum(axis * skew, axis=-1, keepdims=True) < 0.0, -axis, axis)
    return np.where((x <= 0.5 * np.pi)[..., None], near_zero, x[..., None] * axis)


def log6(T: np.ndarray) -> np.ndarray:
    """The twist ``V = (phi, rho)`` with ``exp6(V) = T`` and ``|phi|`` in ``[0, pi]`` (Lynch & Park eq. 3.92).

    ``phi = log3(R)``; ``rho = G^-1 p`` with ``G^-1 = I - [phi]/2 + D [phi]^2`` and
    ``D = 1/x^2 - cot(x/2) / (2x)``, which stays finite at ``x = pi`` (``1/pi^2``) and is a series near 0.
    """
    T = np.asarray(T, dtype=float)
    phi = log3(T[..., :3, :3])
    x = np.linalg.norm(phi, axis=-1)
    small = x < _SMALL
    s = np.where(small, 1.0, x)
    x2 = x * x
    D = np.where(small, 1 / 12 + x2 / 720 + x2 ** 2 / 30240 + x2 ** 3 / 1209600 + x2 ** 4 / 47900160,
                 1.0 / (s * s) - np.cos(0.5 * s) / np.sin(0.5 * s) / (2.0 * s))
    K = hat3(phi)
    G_inv = np.eye(3) - 0.5 * K + D[..., None, None] * (K @ K)
    rho = (G_inv @ T[..., :3, 3, None])[..., 0]
    return np.concatenate([phi, rho], axis=-1)


def inv(T: np.ndarray) -> np.ndarray:
    """``T^-1 = [[R^T, -R^T p], [0, 1]]``."""
    T = np.asarray(T, dtype=float)
    Rt = np.swapaxes(T[..., :3, :3], -1, -2)
    out = np.zeros(T.shape)
    out[..., :3, :3] = Rt
    out[..., :3, 3] = -(Rt @ T[..., :3, 3, None])[..., 0]
    out[..., 3, 3] = 1.0
    return out


def Ad(T: np.ndarray) -> np.ndarray:  # noqa: N802 (the article's name)
    """The adjoint ``Ad_T = [[R, 0], [[p] R, R]]`` (6x6): ``[Ad_T V] = T [V] T^-1`` maps twists by ``T``.

    Wrenches map by ``Ad_T^-T = Ad_{T^-1}^T`` (article 7.4), so that ``F . V`` is invariant.
    """
    T = np.asarray(T, dtype=float)
    R = T[..., :3, :3]
    X = np.zeros(T.shape[:-2] + (6, 6))
    X[..., :3, :3] = R
    X[..., 3:, 3:] = R
    X[..., 3:, :3] = hat3(T[..., :3, 3]) @ R
    return X


def ad(V: np.ndarray) -> np.ndarray:
    """The small adjoint ``ad_V = [[[omega], 0], [[v], [omega]]]`` (6x6): ``ad_V W = [V, W]``, the Lie bracket,
    which is ``d/dt Ad_{exp(t V)} W`` at ``t = 0``."""
    V = np.asarray(V, dtype=float)
    X = np.zeros(V.shape[:-1] + (6, 6))
    W = hat3(V[..., :3])
    X[..., :3, :3] = W
    X[..., 3:, 3:] = W
    X[..., 3:, :3] = hat3(V[..., 3:])
    return X


def cross(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """``a x b`` over the last axis of stacks of 3-vectors: ``(a x b)_k = a_{k+1} b_{k+2} - a_{k+2} b_{k+1}``
    (``np.cross`` is several times slower on small stacks)."""
    return a[..., _NEXT] * b[..., _PREV] - a[..., _PREV] * b[..., _NEXT]


def bracket(V: np.ndarray, W: np.ndarray) -> np.ndarray:
    """``ad_V W = [V, W] = (w x w', w x v' + v x w')`` for ``V = (w, v)``, ``W = (w', v')``, without building
    the matrix (stacks broadcast)."""
    w, v, w2, v2 = V[..., :3], V[..., 3:], W[..., :3], W[..., 3:]
    return np.concatenate([cross(w, w2), cross(w, v2) + cross(v, w2)], axis=-1)


def coad(V: np.ndarray, F: np.ndarray) -> np.ndarray:
    """``ad_V^T F = (-(w x m) - v x f, -(w x f))`` for ``V = (w, v)`` and a wrench ``F = (m, f)``, without
    building the matrix: the pairing ``(ad_V^T F) . W = F . [V, W]``."""
    w, v, m, f = V[..., :3], V[..., 3:], F[..., :3], F[..., 3:]
    return -np.concatenate([cross(w, m) + cross(v, f), cross(w, f)], axis=-1)
