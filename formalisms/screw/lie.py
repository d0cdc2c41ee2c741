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

    With ``S = (omega, v)``, ``K = [omega]`` and ``x = |omega theta|``::

        exp([S] theta) = [[I + A theta K + B theta^2 K^2, (theta I + B theta^2 K + C theta^3 K^2) v], [0, 1]]

    with ``A = sin x / x``, ``B = (1 - cos x) / x^2``, ``C = (x - sin x) / x^3``. For a unit revolute screw
    (``|omega| = 1``) this is the rotation by ``theta`` about the screw axis; for a prismatic one (``omega = 0``) it
    is the translation ``v theta``; any other twist works too. ``theta`` broadcasts against the leading axes of
    ``S``; ``K`` and ``K^2 = omega omega^T - |omega|^2 I`` are built from ``S`` alone, so a stack of states over
    the same screws costs elementwise products only.
    """
    S, theta = np.asarray(S, dtype=float), np.asarray(theta, dtype=float)
    w, v = S[..., :3], S[..., 3:]
    A, B, C = _rotation_coefficients(np.linalg.norm(w, axis=-1) * np.abs(theta))
    K = hat3(w)
    K2 = w[..., :, None] * w[..., None, :] - np.sum(w * w, axis=-1)[..., None, None] * np.eye(3)
    At, Bt, Ct = A * theta, B * theta**2, C * theta**3
    T = _to_back(np.zeros((4, 4) + np.broadcast_shapes(S.shape[:-1], theta.shape)), 2)
    T[..., :3, :3] = np.eye(3) + At[..., None, None] * K + Bt[..., None, None] * K2
    T[..., :3, 3] = theta[..., None] * v + Bt[..., None] * rotate(K, v) + Ct[..., None] * rotate(K2, v)
    T[..., 3, 3] = 1.0
    return T


def quaternion_rotation(quat: np.ndarray) -> np.ndarray:
    """The element of SO(3) a unit quaternion ``(x, y, z, w)`` stands for (article 2.1), as an exponential.

    A unit quaternion is ``(sin(x/2) n, cos(x/2))`` for the rotation by the angle ``x`` about the unit axis ``n``, and
    ``-quat`` is the same rotation; so with the sign chosen for ``w >= 0`` (half angle in ``[0, pi/2]``) the rotation
    vector is ``phi = 2 atan2(|u|, w) u / |u|`` (``u = (x, y, z)``; ``phi = 2 u / w`` at ``u = 0``) and ``R =
    exp([phi])`` (:func:`exp3`, Rodrigues). This is ``I + 2 w [u] + 2 [u]^2`` (``cases.model``) for a unit quaternion;
    a quaternion off unit length by ``d`` gives the rotation of its normalization (the polynomial would be off
    orthogonal by ``2 d``).
    """
    quat = np.asarray(quat, dtype=float)
    sign = np.where(quat[..., 3] < 0.0, -1.0, 1.0)
    u, w = sign[..., None] * quat[..., :3], sign * quat[..., 3]
    s = np.linalg.norm(u, axis=-1)
    some = s > 0.0
    scale = np.where(some, 2.0 * np.arctan2(s, w) / np.where(some, s, 1.0), 2.0 / np.where(some, 1.0, w))
    return exp3(scale[..., None] * u)


def transform(R: np.ndarray, p: np.ndarray | None = None) -> np.ndarray:  # noqa: N803
    """The SE(3) element ``[[R, p], [0, 1]]`` (4x4) of rotations (..., 3, 3) and translations (..., 3) (None: 0)."""
    R = np.asarray(R, dtype=float)
    T = np.zeros(R.shape[:-2] + (4, 4))
    T[..., :3, :3] = R
    if p is not None:
        T[..., :3, 3] = p
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


def _to_front(x: np.ndarray, k: int) -> np.ndarray:
    """The last ``k`` axes of ``x`` moved to the front (a view; ``np.moveaxis`` costs more per call)."""
    d = x.ndim
    return x.transpose(tuple(range(d - k, d)) + tuple(range(d - k)))


def _to_back(x: np.ndarray, k: int) -> np.ndarray:
    """The first ``k`` axes of ``x`` moved to the end: the inverse of :func:`_to_front`."""
    d = x.ndim
    return x.transpose(tuple(range(k, d)) + tuple(range(k)))


def _fronts(a: np.ndarray, ka: int, b: np.ndarray, kb: int) -> tuple[np.ndarray, np.ndarray]:
    """``a`` and ``b`` with their last ``ka``, ``kb`` (component) axes moved to the front, their leading (stack) axes
    padded to equal length so that they broadcast: with components stored part by part (:func:`components`) each
    component is a contiguous block, and sums over components are sums of blocks."""
    a, b = np.asarray(a, dtype=float), np.asarray(b, dtype=float)
    lead = max(a.ndim - ka, b.ndim - kb)
    a = a.reshape((1,) * (lead + ka - a.ndim) + a.shape)
    b = b.reshape((1,) * (lead + kb - b.ndim) + b.shape)
    return _to_front(a, ka), _to_front(b, kb)


def matmul(A: np.ndarray, B: np.ndarray) -> np.ndarray:  # noqa: N803
    """``A B`` for stacks of small matrices (..., i, k) and (..., k, j) (leading axes broadcast), as one product and
    one sum over blocks: ``np.matmul`` on a large stack of 3x3 or 4x4 matrices costs several times more than the
    arithmetic."""
    a, b = _fronts(A, 2, B, 2)
    return _to_back(np.sum(a[:, :, None] * b[None], axis=1), 2)


def rotate(R: np.ndarray, x: np.ndarray) -> np.ndarray:
    """``R x`` for stacks of 3x3 matrices and 3-vectors (broadcast), as in :func:`matmul`."""
    r, v = _fronts(R, 2, x, 1)
    return _to_back(np.sum(r * v[None], axis=1), 1)


def rotate_back(R: np.ndarray, x: np.ndarray) -> np.ndarray:
    """``R^T x`` for stacks (see :func:`rotate`)."""
    r, v = _fronts(R, 2, x, 1)
    return _to_back(np.sum(r * v[:, None], axis=0), 1)


def dot(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """``a . b`` over the last axis of stacks of vectors (broadcast), as a sum over blocks."""
    x, y = _fronts(a, 1, b, 1)
    return np.sum(x * y, axis=0)


def compose(T1: np.ndarray, T2: np.ndarray) -> np.ndarray:
    """``T1 T2`` for stacks of 4x4 transforms (broadcast)."""
    return matmul(T1, T2)


def adjoint(T: np.ndarray, V: np.ndarray) -> np.ndarray:
    """``Ad_T V = (R w, p x R w + R v)`` for a twist ``V = (w, v)``, without building the 6x6 matrix."""
    R, p = T[..., :3, :3], T[..., :3, 3]
    w = rotate(R, V[..., :3])
    return join(w, cross(p, w) + rotate(R, V[..., 3:]))


def wrench_to_body(T: np.ndarray, F: np.ndarray) -> np.ndarray:
    """``Ad_T^T F = (R^T (m - p x f), R^T f)``: a wrench ``F = (m, f)`` in the frame ``T`` maps from (the world,
    say) to its own frame (:func:`Ad`: wrenches map by ``Ad_T^-T``), without building the 6x6 matrix."""
    R, p = T[..., :3, :3], T[..., :3, 3]
    m, f = F[..., :3], F[..., 3:]
    return join(rotate_back(R, m - cross(p, f)), rotate_back(R, f))


def wrench_from_body(T: np.ndarray, F: np.ndarray) -> np.ndarray:
    """``Ad_{T^-1}^T F = (R m + p x R f, R f)``: a wrench ``F = (m, f)`` given in the frame ``T`` (moment about its
    origin) re-expressed in the frame ``T`` is placed in (the world, say; moment about the world origin): the inverse
    of :func:`wrench_to_body`."""
    R, p = T[..., :3, :3], T[..., :3, 3]
    f = rotate(R, F[..., 3:])
    return join(rotate(R, F[..., :3]) + cross(p, f), f)


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


def components(*parts: np.ndarray) -> np.ndarray:
    """The stack ``(..., k)`` of k arrays ``(...)`` of one shape, stored part by part: each component of a large
    stack (of states) is then one contiguous block, which elementwise operations run through several times faster
    than components interleaved state by state."""
    return _to_back(np.stack(parts), 1)


def join(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """``(a, b)`` joined along the last axis (e.g. a twist from its angular and linear parts), leading axes
    broadcast, stored component by component (:func:`components`)."""
    if a.shape[:-1] != b.shape[:-1]:
        lead = np.broadcast_shapes(a.shape[:-1], b.shape[:-1])
        a, b = np.broadcast_to(a, lead + a.shape[-1:]), np.broadcast_to(b, lead + b.shape[-1:])
    return _to_back(np.concatenate([_to_front(a, 1), _to_front(b, 1)]), 1)


def cross(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """``a x b`` over the last axis of stacks of 3-vectors: ``(a x b)_k = a_{k+1} b_{k+2} - a_{k+2} b_{k+1}``
    (``np.cross`` is several times slower on small stacks), component by component."""
    a0, a1, a2, b0, b1, b2 = a[..., 0], a[..., 1], a[..., 2], b[..., 0], b[..., 1], b[..., 2]
    return components(a1 * b2 - a2 * b1, a2 * b0 - a0 * b2, a0 * b1 - a1 * b0)


def bracket(V: np.ndarray, W: np.ndarray) -> np.ndarray:
    """``ad_V W = [V, W] = (w x w', w x v' + v x w')`` for ``V = (w, v)``, ``W = (w', v')``, without building
    the matrix (stacks broadcast)."""
    w, v, w2, v2 = V[..., :3], V[..., 3:], W[..., :3], W[..., 3:]
    return join(cross(w, w2), cross(w, v2) + cross(v, w2))


def coad(V: np.ndarray, F: np.ndarray) -> np.ndarray:
    """``ad_V^T F = (-(w x m) - v x f, -(w x f))`` for ``V = (w, v)`` and a wrench ``F = (m, f)``, without
    building the matrix: the pairing ``(ad_V^T F) . W = F . [V, W]``."""
    w, v, m, f = V[..., :3], V[..., 3:], F[..., :3], F[..., 3:]
    return -join(cross(w, m) + cross(v, f), cross(w, f))
