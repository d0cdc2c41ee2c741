"""Euler–Lagrange formalism (article 4.7.1): the dynamics from the energies, derived symbolically.

Derivation (symbolic, from the model data alone):
  1. Body poses ``R_i(q)``, ``p_i(q)`` by composing the fixed joint placements and the joint motions.
  2. Kinetic energy ``T = sum_i 1/2 m_i |c_i_dot|^2 + 1/2 tr(R_i_dot J_i R_i_dot^T)`` with ``c_i`` the COM,
     ``R_i_dot = sum_k dR_i/dq_k qd_k`` and ``J_i = 1/2 tr(I_i) 1 - I_i`` (the rotational energy
     ``1/2 w^T I w`` written with the rotation matrix's rate, so no angular velocity is formed).
     Potential energy ``V = -sum_i m_i gravity . c_i``.
  3. ``M = d^2 T / d qd^2`` (section 4.7.1 step 1), ``g = dV/dq`` (step 2, eq. 8) and the velocity-product
     vector from the Christoffel symbols of the first kind (step 3):
     ``(C qd)_i = sum_jk 1/2 (dM_ij/dq_k + dM_ik/dq_j - dM_jk/dq_i) qd_j qd_k``.
The derivation is staged: every pose entry and every derivative of one is a named intermediate, and
derivatives go through a memoized chain rule (forward-mode differentiation done symbolically), so the
expressions never expand the kinematic chain. The symbolic engine is SymEngine, the C++ core of the sympy
project with sympy's API, because pure-Python sympy takes minutes on a 9-joint arm.
Compilation: common-subexpression elimination, then plain Python source evaluated with ``math``. The source
is cached on disk keyed by the model digest and a hash of this module, so a second process loads it instead
of re-deriving. Solving: Cholesky factorization of M, never an explicit inverse.
"""

from __future__ import annotations

import functools
import hashlib
import math
import os
import tempfile
from pathlib import Path

import numpy as np
import scipy.linalg
import symengine as sp

from cases.model import Model
from formalisms.interface import Formalism, check_state, conditioning, factor_mass_matrix, unconstrained_split

ZERO, ONE, HALF = sp.Integer(0), sp.Integer(1), sp.Rational(1, 2)


def _exact(x: float) -> sp.Expr:
    """A float as a symbolic number; exact zeros and ones stay integers so products with them vanish."""
    return sp.Integer(int(x)) if x in (0.0, 1.0, -1.0) else sp.RealDouble(float(x))


def _matrix(arr) -> sp.DenseMatrix:
    arr = np.asarray(arr, dtype=float)
    return sp.DenseMatrix(arr.shape[0], arr.shape[1] if arr.ndim == 2 else 1,
                          [_exact(v) for v in arr.reshape(-1)])


def _skew(a: sp.DenseMatrix) -> sp.DenseMatrix:
    return sp.DenseMatrix([[0, -a[2], a[1]], [a[2], 0, -a[0]], [-a[1], a[0], 0]])


class _Staged:
    """Named intermediate expressions with a memoized chain rule: forward-mode differentiation, symbolically.

    Every pose entry, and every derivative of one, becomes a symbol whose definition uses only earlier
    symbols. ``diff(expr, k)`` is the total derivative of ``expr`` by ``q_k`` through all of them, so
    differentiating T twice and M once never expands the kinematic chain (which grows exponentially).
    """

    def __init__(self, q: list[sp.Symbol]):
        self.q = q
        self.definitions: dict[sp.Symbol, sp.Expr] = {}
        self._coordinate = {s: k for k, s in enumerate(q)}
        self._depends: dict[sp.Symbol, frozenset[int]] = {}
        self._derivative: dict[tuple[sp.Symbol, int], sp.Expr] = {}
        self._count = 0

    def name(self, expr) -> sp.Expr:
        """A symbol standing for ``expr`` (numbers and symbols are returned as they are)."""
        expr = sp.sympify(expr)
        if expr.is_Number or expr.is_Symbol:
            return expr
        s = sp.Symbol(f"w{self._count}")
        self._count += 1
        self.definitions[s] = expr
        self._depends[s] = frozenset().union(*(
            self._depends.get(f, frozenset({self._coordinate[f]}) if f in self._coordinate else frozenset())
            for f in expr.free_symbols))
        return s

    def angle(self, k: int) -> tuple[sp.Symbol, sp.Symbol]:
        """Symbols for ``sin(q_k)`` and ``cos(q_k)`` with their derivatives seeded."""
        s, c = self.name(sp.sin(self.q[k])), self.name(sp.cos(self.q[k]))
        self._derivative[(s, k)], self._derivative[(c, k)] = c, -s
        return s, c

    def diff(self, expr: sp.Expr, k: int) -> sp.Expr:
        """Total derivative ``d expr / d q_k``: sum and product rules in one pass, chain rule at symbols."""
        memo: dict = {}
        qk = self.q[k]

        def d(e):
            if e in memo:
                return memo[e]
            if e.is_Number:
                r = ZERO
            elif e.is_Symbol:
                r = ONE if e == qk else (
                    self._derivative_of(e, k) if k in self._depends.get(e, ()) else ZERO)
            elif e.is_Add:
                r = sp.Add(*[d(a) for a in e.args])
            elif e.is_Mul:
                a = e.args
                r = sp.Add(*[sp.Mul(*a[:i], da, *a[i + 1:]) for i in range(len(a)) if (da := d(a[i])) != 0])
            elif e.is_Pow and e.exp.is_Number:
                r = e.exp * e.base ** (e.exp - 1) * d(e.base)
            else:
                r = e.diff(qk)  # sin/cos of a coordinate only appear inside seeded definitions
            memo[e] = r
            return r

        return d(expr)

    def _derivative_of(self, s: sp.Symbol, k: int) -> sp.Expr:
        if (s, k) not in self._derivative:
            self._derivative[(s, k)] = self.name(self.diff(self.definitions[s], k))
        return self._derivative[(s, k)]

    def rate(self, m: sp.DenseMatrix, qd) -> sp.DenseMatrix:
        """Time derivative along the motion: ``sum_k d(m)/dq_k qd_k``."""
        return m.applyfunc(lambda e: sp.Add(*[self.diff(e, k) * qd[k] for k in range(len(qd))]))

    def needed(self, exprs) -> list[tuple[sp.Symbol, sp.Expr]]:
        """The definitions the expressions use, transitively, in an order that evaluates (creation order)."""
        seen: set = set()
        stack = [f for e in exprs for f in e.free_symbols if f in self.definitions]
        while stack:
            s = stack.pop()
            if s not in seen:
                seen.add(s)
                stack.extend(f for f in self.definitions[s].free_symbols if f in self.definitions)
        return [(s, e) for s, e in self.definitions.items() if s in seen]


def _joint_rotation(axis: sp.DenseMatrix, s: sp.Symbol, c: sp.Symbol) -> sp.DenseMatrix:
    """Rodrigues' formula ``I + sin(q) [a]x + (1 - cos(q)) [a]x^2`` for a unit axis a."""
    K = _skew(axis)
    return sp.eye(3) + s * K + (1 - c) * (K * K)


def _poses(model: Model, st: _Staged) -> list[tuple[sp.DenseMatrix, sp.DenseMatrix]]:
    """World rotation and origin of every body frame as staged functions of q (module docstring, step 1)."""
    poses: list = [None] * model.n
    for i in model.topological_order:
        body = model.bodies[i]
        parent = model.parent_index[i]
        R_par, p_par = (sp.eye(3), sp.zeros(3, 1)) if parent < 0 else poses[parent]
        R_joint = R_par * _matrix(body.rotation)
        p_joint = p_par + R_par * _matrix(body.translation)
        axis = _matrix(body.axis)
        if body.joint == "revolute":
            R, p = R_joint * _joint_rotation(axis, *st.angle(i)), p_joint
        else:
            R, p = R_joint, p_joint + R_joint * axis * st.q[i]
        poses[i] = (R.applyfunc(st.name), p.applyfunc(st.name))
    return poses


def _energies(model: Model, st: _Staged, qd) -> tuple[sp.Expr, sp.Expr]:
    """Kinetic energy T(q, qd) and potential energy V(q) of the whole tree (module docstring, step 2)."""
    T, V = ZERO, ZERO
    gravity = _matrix(model.gravity)
    for body, (R, p) in zip(model.bodies, _poses(model, st)):
        c = (p + R * _matrix(body.com)).applyfunc(st.name)
        c_dot = st.rate(c, qd)
        T += HALF * _exact(body.mass) * (c_dot.T * c_dot)[0]
        if np.any(body.inertia):
            J = _matrix(0.5 * np.trace(body.inertia) * np.eye(3) - body.inertia)
            R_dot = st.rate(R, qd)
            RJR = R_dot * J * R_dot.T
            T += HALF * (RJR[0, 0] + RJR[1, 1] + RJR[2, 2])
        V -= _exact(body.mass) * (gravity.T * c)[0]
    return T, V


def derive(model: Model):
    """Symbolic ``M(q)``, ``C(q, qd) qd`` and ``g(q)`` from the energies (article 4.7.1, eqs. 6–8).

    Returns (M, Cqd, g, q, qd, staged): the expressions use the staged intermediates, whose definitions
    ``staged.needed(...)`` lists in evaluation order.
    """
    n = model.n
    q = list(sp.symbols(f"q0:{n}"))
    qd = list(sp.symbols(f"qd0:{n}"))
    st = _Staged(q)
    T, V = _energies(model, st, qd)
    dT = [T.diff(v) for v in qd]
    M = sp.zeros(n, n)
    for i in range(n):
        for j in range(i, n):
            M[i, j] = M[j, i] = sp.expand(dT[i].diff(qd[j]))
    dM = {(i, j, k): st.name(st.diff(M[i, j], k)) for i in range(n) for j in range(i, n) for k in range(n)}

    def dm(i, j, k):
        return dM[(min(i, j), max(i, j), k)]

    Cqd = sp.DenseMatrix([
        sp.Add(*[HALF * (dm(i, j, k) + dm(i, k, j) - dm(j, k, i)) * qd[j] * qd[k]
                 for j in range(n) for k in range(n)])
        for i in range(n)])
    g = sp.DenseMatrix([st.diff(V, i) for i in range(n)])
    return M, Cqd, g, q, qd, st


def _py(e) -> str:
    """Python source for a symbolic expression; floats print with ``repr`` so they round-trip exactly."""
    if e.is_Symbol:
        return str(e)
    if e.is_Integer:
        return str(int(e))
    if e.is_Number:
        return repr(float(e))
    if e.is_Add:
        return "(" + " + ".join(_py(a) for a in e.args) + ")"
    if e.is_Mul:
        return "(" + "*".join(_py(a) for a in e.args) + ")"
    if e.is_Pow:
        return f"({_py(e.args[0])}**{_py(e.args[1])})"
    if isinstance(e, (sp.sin, sp.cos)):
        return f"{type(e).__name__}({_py(e.args[0])})"
    raise TypeError(f"Euler–Lagrange codegen: unexpected expression {e!r}")


def generate_source(model: Model) -> str:
    """Python source of ``evaluate(q, qd) -> (M_upper, Cqd, g)``: staged definitions, CSE, outputs."""
    M, Cqd, g, q, qd, st = derive(model)
    n = model.n
    upper = [M[i, j] for i in range(n) for j in range(i, n)]
    outputs = upper + list(Cqd) + list(g)
    definitions = st.needed(outputs)
    exprs = [e for _, e in definitions] + outputs
    replacements, reduced = sp.cse(exprs)
    named, reduced = reduced[: len(definitions)], reduced[len(definitions):]
    # cse hoists shared subexpressions of all definitions first; each definition then follows in order.
    lines = [f"# Euler-Lagrange dynamics of model '{model.name}' ({model.digest()}), generated by crosscheck",
             "def evaluate(q, qd):",
             f"    {', '.join(map(str, q))}, = q",
             f"    {', '.join(map(str, qd))}, = qd"]
    lines += _ordered_assignments(replacements, list(zip((s for s, _ in definitions), named)))
    m_up, rest = reduced[: len(upper)], reduced[len(upper):]
    lines.append(f"    M_upper = ({', '.join(_py(e) for e in m_up)},)")
    lines.append(f"    Cqd = ({', '.join(_py(e) for e in rest[:n])},)")
    lines.append(f"    g = ({', '.join(_py(e) for e in rest[n:])},)")
    lines.append("    return M_upper, Cqd, g")
    return "\n".join(lines) + "\n"


def _ordered_assignments(*groups) -> list[str]:
    """Assignment lines for all (symbol, expr) pairs, each after everything it reads (a topological sort)."""
    pending = {s: e for group in groups for s, e in group}
    done: set = set()
    lines: list[str] = []

    def emit(s):
        stack = [(s, False)]
        while stack:
            sym, expanded = stack.pop()
            if sym in done:
                continue
            if expanded:
                done.add(sym)
                lines.append(f"    {sym} = {_py(pending[sym])}")
                continue
            stack.append((sym, True))
            stack.extend((f, False) for f in pending[sym].free_symbols if f in pending and f not in done)

    for group in groups:
        for s, _ in group:
            emit(s)
    return lines


_DERIVATION_HASH = hashlib.sha256(Path(__file__).read_bytes()).digest()


def _cache_dir() -> Path:
    root = os.environ.get("CROSSCHECK_CACHE") or os.path.join(
        os.environ.get("XDG_CACHE_HOME") or os.path.expanduser("~/.cache"), "crosscheck")
    return Path(root) / "euler_lagrange"


def cached_source(model: Model) -> str:
    """The generated source, from the disk cache when present.

    Keyed by the model digest and a hash of this module's own source, so a change to the derivation can
    never be hidden by code generated before it.
    """
    key = hashlib.sha256(model.digest().encode() + _DERIVATION_HASH).hexdigest()[:32]
    path = _cache_dir() / f"{key}.py"
    if path.exists():
        return path.read_text()
    source = generate_source(model)
    path.parent.mkdir(parents=True, exist_ok=True)
    with tempfile.NamedTemporaryFile("w", dir=path.parent, delete=False, suffix=".tmp") as fh:
        fh.write(source)
    os.replace(fh.name, path)
    return source


@functools.lru_cache(maxsize=64)
def _compiled(model: Model):
    namespace = {"sin": math.sin, "cos": math.cos}
    exec(compile(cached_source(model), f"<euler_lagrange {model.name}>", "exec"), namespace)
    return namespace["evaluate"]


def terms(model: Model, q: np.ndarray, qd: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Numeric ``M(q)``, ``C(q, qd) qd`` and ``g(q)`` of eq. (2) from the compiled derivation."""
    n = model.n
    M_upper, Cqd, g = _compiled(model)(q.tolist(), qd.tolist())
    M = np.zeros((n, n))
    M[np.triu_indices(n)] = M_upper
    M = M + np.triu(M, 1).T
    return M, np.array(Cqd), np.array(g)


def split(model: Model, q, qd, u):
    """Drift ``-M^-1 (C qd + g)`` (eq. 10), control ``M^-1 B u`` and total ``M^-1 (B u - C qd - g)`` (eq. 9)."""
    if model.constraints:
        raise NotImplementedError("Euler–Lagrange: constraints arrive with the constraint issue")
    q, qd, u = check_state(model, q, qd, u)
    M, Cqd, g = terms(model, q, qd)
    factor = factor_mass_matrix(model, M, q)
    Bu = model.input_map @ u
    h = Cqd + g
    cond_M, accel_scale = conditioning(model, M, Cqd, g, Bu, qd)
    return unconstrained_split(
        drift=scipy.linalg.cho_solve(factor, -h),
        ctrl=scipy.linalg.cho_solve(factor, Bu),
        total=scipy.linalg.cho_solve(factor, Bu - h),
        tau_ctrl=Bu, qd=qd, cond_M=cond_M, accel_scale=accel_scale)


FORMALISM = Formalism(
    name="euler_lagrange",
    summary="symbolic energies T, V; M = Hessian of T, C qd from Christoffel symbols of the first kind, g = dV/dq",
    split=split,
)
