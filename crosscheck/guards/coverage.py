"""Sampling coverage: what a case's sampled states actually span, and whether that sample can test anything.

A gate whose states never move checks nothing: joint rates never sampled leave every velocity-product term
(Coriolis, centrifugal, gyroscopic, ``Jcdot qd``) at zero, inputs never sampled leave the control path unchecked, and
configurations in a sliver of the joint range test one posture. :func:`measure` records, per case, the range of every
coordinate of q, qd and u over the sampled states (and for a constrained model the rank of ``Jc`` over them, from the
harness's own constraint kinematics), and names what makes the sample degenerate. It judges the sample against what
the gate promises, never against the sampler's own inputs:

* **The limits, from the file.** A model loaded from a URDF or MJCF file (``model.source``) is measured against the
  joint limits its file declares, read apart from the loaders (``crosscheck.guards.file_limits``: the XML by the
  format's rules, paired with our coordinates by the Pinocchio reference's joint map), not against ``Body.limits``,
  which the sampler draws from. Converted limits that differ from the file's (a degree/radian slip, swapped or
  dropped limits, limits invented) are a **loader finding**, found when the case is set up, before its states are
  drawn (``crosscheck.guards.loader``), and fail the case there; the states, drawn within the model's limits, are
  still measured against the file's. A model without a file, or whose file cannot be read apart from the loaders
  (the report says why), is measured against ``Body.limits``.
* **The span** the gate promises for a coordinate: the width of the joint's limits where it has limits, else one
  turn of a revolute joint (:data:`REVOLUTE_SPAN`), a metre of a prismatic one or of a free base's position
  (:data:`PRISMATIC_SPAN`), 2 for a quaternion component. Written here, not read from the sampler.
* every joint rate zero (at two or more states), unless the constraints leave no motion (``rank Jc = n``);
* every input zero (at two or more states) for a model with inputs;
* **repeated states**: two states whose ``(q, qd, u)`` agree to :data:`REPEAT` (relative, in the largest entry) are one
  state tested twice, for every model; the problem counts the states that repeat an earlier one and names the most
  repeated one;
* from :data:`SLIVER_STATES` states on, the configurations (rules below). A coordinate is **judged freely** when
  nothing but the sampler decides it: every coordinate of an unconstrained model or of one with Pfaffian rows only
  (``A(q) qd = 0`` leaves q free), and a revolute or prismatic coordinate of a model with holonomic rows whose column
  in those rows of ``Jc`` is zero at every state (no constraint involves it, so the projection never moves it).

  - **Sliver**: a coordinate judged freely whose sampled range is below :data:`SLIVER` of its span; for a model
    with holonomic rows also every coordinate so (the constraints may confine some, not all).
  - **Pinned**: a coordinate of a model with holonomic rows whose sampled range is below :data:`PINNED` of its span
    is a sliver unless the constraints pin it: at every state where the holonomic rows of ``Jc`` have their largest
    rank over the sample (a rank drop is a singular configuration, with local motions the manifold does not have),
    the coordinate's rate along the null space of those rows is below :data:`NULL_TOL` (``||e_i^T G(q) N||``, N an
    orthonormal basis of the null space, G the map from velocities to coordinate rates: the identity for a revolute
    or prismatic joint, a quaternion's derivative for the others).
  - **Piled into a band**: a revolute or prismatic coordinate (or a free base's position) judged freely, and not a
    sliver, with more than ``K(N)`` of its N states in one window of width :data:`BAND` of its span.
  - **Piled at the limits**: a coordinate with limits, not a sliver (nor pinned: that is thinner), within
    :data:`AT_LIMIT` of its span of its lower or upper limit at more than ``L(N)`` states (which allows for the home
    state, clipped to a limit by design: ``crosscheck.core.sampling.within_limits(home=True)``).

  A coordinate whose span is zero (limits ``lower = upper`` declared in code: a joint held fixed) is not judged.

Why these thresholds (the false-alarm risk per coordinate and rule is at most :data:`RISK`, 1e-8, when the N - 1
non-home states are drawn uniformly over an interval of the span's width or wider, as the gate promises):

* Sliver: all N states within a window of width ``w`` (a fraction of the span) with one of them (home) fixed has
  probability at most ``N w^(N-1)``: 1e-8 at N = 10, w = 0.1, and far less beyond.
* Band: any window of width ``W = BAND * span`` lies inside one of the ``1/BAND + 1`` windows of width ``2 W``
  starting at ``lower + (j - 1) W``, each of probability at most ``2 BAND`` per draw; so the N - 1 draws put ``k`` or
  more in one ``W`` window with probability at most ``(1/BAND + 1) P(Binomial(N - 1, 2 BAND) >= k)``. ``K(N)`` is
  the smallest ``k`` that makes this at most :data:`RISK`; home adds at most one state, so more than ``K(N)`` of the
  N states in one window has probability at most :data:`RISK`. At N = 50 more than 30 states in a tenth of the span
  fail (uniform draws put about 5 there), at N = 20 more than 17; below N = 14 the rule cannot fire (the sliver rule
  speaks there). It looks at the whole distribution, not the extremes: a sample that reaches both ends but piles the
  rest into a narrow band fails. (The standard deviation, bounded by concentration inequalities, was weaker at these
  N; the band count has an exact binomial tail.)
* At the limits: a uniform draw lands within ``AT_LIMIT * span`` of a limit with probability at most ``2 AT_LIMIT``;
  ``L(N)`` is the smallest ``k`` with ``P(Binomial(N - 1, 2 AT_LIMIT) >= k) <= RISK`` (2 for N up to tens of
  thousands), and home adds at most one: more than ``L(N)`` states at the limits fail. A sample piled onto the two
  limits, which the other rules do not see (its range and spread are the largest possible), fails.
* Repeated: two states drawn independently agree to :data:`REPEAT` in every entry of ``(q, qd, u)`` with
  probability of order ``REPEAT`` per entry, multiplied over the entries.
* Pinned: a coordinate the constraints do not pin moves to first order along their manifold, so a range below
  :data:`PINNED` of its span over N >= 10 admissible states is no chance; :data:`NULL_TOL` and the rank cut
  :data:`RANK_RCOND` are far above rounding (4e-16 in the two coordinates the built-in absolute-coordinate loop pins)
  and far below a real motion.

These are per coordinate; a case's risk is the sum over its coordinates and rules (below 1e-6 for 19 coordinates).

A degenerate sample fails the gate (``crosscheck.engine``): the report says what was not sampled.
"""

from __future__ import annotations

import functools
import math
from dataclasses import dataclass
from typing import Sequence

import numpy as np

from cases import configuration
from cases.model import Model
from crosscheck.core import sampling
from crosscheck.guards import file_limits
from crosscheck.references.pinocchio.kinematics import constraint_kinematics

#: The span the gate promises to sample (docs/faults.md, coverage): one turn of a revolute joint, a metre of a
#: prismatic one. Written here, not read from ``crosscheck.core.sampling``, so that a sampler drawing from a narrower
#: range is measured against the promise, not against itself.
REVOLUTE_SPAN = 2.0 * np.pi
PRISMATIC_SPAN = 1.0
#: The spans of each joint's coordinates: a quaternion's components range over [-1, 1] (span 2), a free base's
#: position over the prismatic span.
_SPANS = {"revolute": (REVOLUTE_SPAN,), "prismatic": (PRISMATIC_SPAN,), "spherical": (2.0,) * 4,
          "free": (PRISMATIC_SPAN,) * 3 + (2.0,) * 4}
#: What each coordinate of a joint is: "scalar" (revolute, prismatic), "position" (a free base's), "quaternion".
_KINDS = {"revolute": ("scalar",), "prismatic": ("scalar",), "spherical": ("quaternion",) * 4,
          "free": ("position",) * 3 + ("quaternion",) * 4}
#: A coordinate's sampled range below this fraction of its promised span is a sliver.
SLIVER = 0.1
#: The configuration rules need this many states (fewer uniform draws may cluster by chance).
SLIVER_STATES = 10
#: The false-alarm risk each configuration rule allows per coordinate under uniform draws (module doc).
RISK = 1e-8
#: The window of the band rule, as a fraction of the span.
BAND = 0.1
#: "At a limit": within this fraction of the span of it.
AT_LIMIT = 1e-9
#: A sampled range below this fraction of the span is a pinned coordinate.
PINNED = 1e-6
#: A coordinate rate along the constraints' null space below this (per unit of velocity) is none: the constraints pin it.
NULL_TOL = 1e-6
#: Singular values of the holonomic ``Jc`` below this fraction of the largest are rank drops, not directions.
RANK_RCOND = 1e-9
#: Two states agreeing to this (relative to their largest entry) are one state.
REPEAT = 1e-12


@dataclass(frozen=True)
class Coverage:
    """The ranges sampled in one case: ``q``, ``qd`` (n, 2) and ``u`` (m, 2) rows ``[min, max]``, the sampling span
    promised for each coordinate, the range of ``rank Jc`` over the states (None without constraints), and
    ``problems``: what makes the sample degenerate (empty when it is not). ``limits``: the joint limits per body the
    sample was measured against (None: none), and ``limits_source``: where they were read (the file apart from the
    loader, or the model's ``Body.limits`` and why)."""

    states: int
    q: np.ndarray
    qd: np.ndarray
    u: np.ndarray
    span: np.ndarray
    constraint_rank: tuple[int, int] | None
    problems: tuple[str, ...]
    limits: tuple[tuple[float, float] | None, ...] = ()
    limits_source: str = ""

    @property
    def degenerate(self) -> bool:
        return bool(self.problems)


def _ranges(rows: np.ndarray, width: int) -> np.ndarray:
    return np.stack([rows.min(axis=0), rows.max(axis=0)], axis=1) if len(rows) else np.zeros((width, 2))


@functools.lru_cache(maxsize=None)
def binomial_allowance(n: int, p: float, windows: int = 1) -> int:
    """The smallest ``k`` with ``windows * P(Binomial(n, p) >= k) <= RISK`` (``n + 1`` if none is: then no count of
    ``n`` draws is improbable enough)."""
    if p <= 0.0:
        return 0
    if p >= 1.0:
        return n + 1
    logs = [math.lgamma(n + 1) - math.lgamma(j + 1) - math.lgamma(n - j + 1) + j * math.log(p)
            + (n - j) * math.log1p(-p) for j in range(n + 1)]
    tail = 0.0
    for k in range(n, -1, -1):
        tail += math.exp(logs[k])
        if windows * tail > RISK:
            return k + 1
    return 0


def band_allowance(states: int) -> int:
    """``K(N)``: the most states one window of width ``BAND`` of the span may hold (module doc)."""
    windows = math.ceil(1.0 / BAND - 1e-9) + 1
    return binomial_allowance(states - 1, 2.0 * BAND, windows)


def limit_allowance(states: int) -> int:
    """``L(N)``: the most states that may sit at a joint's limits (module doc)."""
    return binomial_allowance(states - 1, 2.0 * AT_LIMIT)


# ------------------------------------------------------------------------------------------------- the limits


def _limits(model: Model) -> tuple[tuple, str]:
    """The limits per body the sample is measured against, and where they come from."""
    ours = tuple(b.limits for b in model.bodies)
    read = file_limits.read(model)
    if read is None:
        return ours, "the model's joint limits (built in code: no file)"
    where = f"the {read.kind.upper()} file {read.path}"
    if read.limits is None:
        return ours, (f"the model's joint limits: {where} could not be read apart from the loader ({read.reason})")
    return read.limits, f"{where}, read apart from the loader"


def _promised(body, limits) -> tuple[float, ...]:
    """The spans promised for the body's coordinates: its joint limits' width where it has limits (the gate draws
    within them unless told otherwise; drawn freely, the sample only spans more), else :data:`_SPANS`."""
    return (limits[1] - limits[0],) if limits is not None else _SPANS[body.joint]


# ------------------------------------------------------------------------------------------------ repetition


def _repeated(X: np.ndarray) -> str | None:
    """The repeated-states problem of the rows of ``X`` (state-major ``(q, qd, u)``), or None. Candidates are found by
    sorting a fixed projection (two rows within ``REPEAT`` of each other project within ``REPEAT |w|_1`` times
    their size), so this is ``N log N`` plus the near pairs."""
    N = len(X)
    if N < 2:
        return None
    size = np.abs(X).max(axis=1) if X.shape[1] else np.zeros(N)
    w = np.sqrt(np.arange(X.shape[1]) + 2.0)
    p = X @ w
    order = np.argsort(p, kind="stable")
    reach = REPEAT * (float(size.max()) if N else 0.0) * float(w.sum())
    first = list(range(N))

    def root(i: int) -> int:
        while first[i] != i:
            first[i] = first[first[i]]
            i = first[i]
        return i

    for a in range(N):
        i = order[a]
        for b in range(a + 1, N):
            j = order[b]
            if p[j] - p[i] > reach:
                break
            if np.abs(X[i] - X[j]).max(initial=0.0) <= REPEAT * max(size[i], size[j]):
                ri, rj = root(i), root(j)
                first[max(ri, rj)] = min(ri, rj)
    groups: dict[int, list[int]] = {}
    for i in range(N):
        groups.setdefault(root(i), []).append(i)
    repeats = N - len(groups)
    if not repeats:
        return None
    top, members = max(groups.items(), key=lambda g: (len(g[1]), -g[0]))
    others = members[1:]
    shown = ", ".join(f"#{k}" for k in others[:5]) + (f" and {len(others) - 5} more" if len(others) > 5 else "")
    rest = sum(len(m) > 1 for m in groups.values()) - 1
    return (f"{repeats} of {N} states repeat an earlier state's (q, qd, u) (to {REPEAT:g} relative): state #{top} "
            f"recurs as {shown}" + (f"; {rest} other state(s) recur too" if rest else "") +
            " (a repeated state tests nothing new)")


# --------------------------------------------------------------------------------------------- constraints


@dataclass(frozen=True)
class _Constraints:
    """What the constraints do to the configurations at the sampled states (None fields: no holonomic rows)."""

    ranks: tuple[int, int] | None
    holonomic: bool
    free_columns: np.ndarray | None     # velocity columns zero in the holonomic rows at every state
    nulls: list | None                  # per state at the largest holonomic rank: (q, N) with N a null-space basis


def _constraints(model: Model, Q: np.ndarray) -> _Constraints:
    if not model.constraints or not len(Q):
        return _Constraints(None, False, None, None)
    holonomic = model.holonomic_rows
    ranks, free, nulls = [], np.ones(model.nv, dtype=bool), []
    for q in Q:
        Jc = constraint_kinematics(model, q, np.zeros(model.nv))[1]
        ranks.append(int(np.linalg.matrix_rank(Jc)))
        if holonomic.any():
            H = Jc[holonomic]
            free &= np.all(np.abs(H) <= 1e-12 * max(1.0, float(np.abs(H).max())), axis=0)
            _, sigma, Vt = np.linalg.svd(H)
            rank = int(np.sum(sigma > RANK_RCOND * sigma.max())) if sigma.size and sigma.max() > 0.0 else 0
            nulls.append((rank, q, Vt[rank:].T))
    if not holonomic.any():
        return _Constraints((min(ranks), max(ranks)), False, None, None)
    top = max(r for r, _, _ in nulls)
    return _Constraints((min(ranks), max(ranks)), True, free, [(q, N) for r, q, N in nulls if r == top])


def _coordinate_rates(model: Model, q: np.ndarray) -> np.ndarray:
    """``G(q)`` (nq, nv): the coordinate rates of unit velocities, ``d/dt q = G(q) v`` (central differences of
    ``cases.configuration.integrate``; exact for the scalar joints)."""
    h = 1e-7
    G = np.empty((model.nq, model.nv))
    for k in range(model.nv):
        step = np.zeros(model.nv)
        step[k] = h
        G[:, k] = (configuration.integrate(model, q, step) - configuration.integrate(model, q, -step)) / (2.0 * h)
    return G


def _pinned_by_constraints(model: Model, info: _Constraints, coordinates: list[int]) -> dict[int, float]:
    """For each coordinate, the largest rate along the holonomic rows' null space over the states at their largest
    rank (module doc): below :data:`NULL_TOL`, the constraints pin it."""
    worst = {i: 0.0 for i in coordinates}
    for q, N in info.nulls:
        G = _coordinate_rates(model, q)
        for i in coordinates:
            worst[i] = max(worst[i], float(np.linalg.norm(G[i] @ N)) if N.size else 0.0)
    return worst


# -------------------------------------------------------------------------------------------------- measure


def measure(model: Model, states: Sequence[sampling.State]) -> Coverage:
    """The coverage of ``states`` of ``model`` and its problems (module doc)."""
    Q, QD, U = (np.array([getattr(s, name) for s in states], dtype=float).reshape(len(states), size)
                for name, size in (("q", model.nq), ("qd", model.nv), ("u", model.m)))
    limits, source = _limits(model)
    problems: list[str] = []
    span = np.array([span for b, lim in zip(model.bodies, limits) for span in _promised(b, lim)])
    kinds = [kind for b in model.bodies for kind in _KINDS[b.joint]]
    owner = [b.name for b in model.bodies for _ in _KINDS[b.joint]]
    info = _constraints(model, Q)
    ranks = info.ranks
    repeated = _repeated(np.hstack([Q, QD, U]))
    if repeated:
        problems.append(repeated)
    if len(states) >= 2 and not np.any(QD) and not (ranks is not None and ranks[0] == model.n):
        problems.append(f"every joint rate is 0 at all {len(states)} states: the velocity-product terms (Coriolis, "
                        "centrifugal, gyroscopic, Jcdot qd) were never exercised")
    if len(states) >= 2 and model.m and not np.any(U):
        problems.append(f"every input is 0 at all {len(states)} states: the control path (B u, ctrl) was never "
                        "exercised")
    if len(states) >= SLIVER_STATES:
        problems += _configuration_problems(model, Q, span, kinds, owner, limits, info)
    return Coverage(len(states), _ranges(Q, model.nq), _ranges(QD, model.nv), _ranges(U, model.m), span, ranks,
                    tuple(problems), tuple(limits), source)


def _configuration_problems(model: Model, Q: np.ndarray, span: np.ndarray, kinds: list[str], owner: list[str],
                            limits: tuple, info: _Constraints) -> list[str]:
    """The sliver, pinned, band and at-limit rules (module doc)."""
    N, problems = len(Q), []
    width = np.ptp(Q, axis=0)
    thin = width < SLIVER * span
    judged = span > 0.0
    if info.holonomic:
        column = {model.q_index[i]: model.v_index[i] for i, b in enumerate(model.bodies) if b.joint in
                  ("revolute", "prismatic")}
        free = np.array([i in column and bool(info.free_columns[column[i]]) for i in range(model.nq)], dtype=bool)
    else:
        free = np.ones(model.nq, dtype=bool)
    pinned = (width < PINNED * span) & ~free & judged
    held = _pinned_by_constraints(model, info, list(np.flatnonzero(pinned))) if pinned.any() else {}
    loose = [i for i in np.flatnonzero(pinned) if held[i] > NULL_TOL]
    sliver = sorted(set(np.flatnonzero(thin & free)) | set(loose))
    if info.holonomic and thin.all() and judged.any():
        sliver = list(range(model.nq))
    if sliver:
        def say(i: int) -> str:
            text = f"q{i} ({owner[i]}) spans {width[i]:.3g} of {span[i]:.3g}"
            if i in held:
                text += (f" (pinned at {Q[0, i]:.6g}, and the constraints do not hold it there: it moves at "
                         f"{held[i]:.3g} per unit velocity along their null space)")
            return text

        problems.append(f"the configurations lie in a sliver of the joint ranges: {', '.join(map(say, sliver))} "
                        f"(below {SLIVER:g} of the sampling span" + (f"; pinned: below {PINNED:g} of it" if loose
                                                                     else "") + ")")
    # The band rule: coordinates judged freely that move along a line (not quaternion components), not slivers.
    allowed = band_allowance(N)
    piled = []
    for i in np.flatnonzero(free & ~thin & judged):
        if kinds[i] == "quaternion":
            continue
        x = np.sort(Q[:, i])
        counts = np.searchsorted(x, x + BAND * span[i], side="right") - np.arange(N)
        k = int(counts.max())
        if k > allowed:
            at = float(x[int(counts.argmax())])
            piled.append(f"q{i} ({owner[i]}) has {k} of {N} states in [{at:.4g}, {at + BAND * span[i]:.4g}]")
    if piled:
        problems.append(f"the configurations pile into a band: {', '.join(piled)} (a window of {BAND:g} of the "
                        f"sampling span may hold at most {allowed} of {N} uniform draws, module doc)")
    # The at-limit rule: every coordinate with limits that is not a sliver and not pinned by the constraints.
    at_limit, allowed = [], limit_allowance(N)
    for b, body in enumerate(model.bodies):
        i = model.q_index[b]
        if limits[b] is None or thin[i] or not judged[i]:
            continue
        lower, upper = limits[b]
        tol = AT_LIMIT * (upper - lower)
        low, high = int(np.sum(np.abs(Q[:, i] - lower) <= tol)), int(np.sum(np.abs(Q[:, i] - upper) <= tol))
        if low + high > allowed:
            at_limit.append(f"q{i} ({owner[i]}) at {low} states at its lower limit {lower:.6g} and {high} at its "
                            f"upper limit {upper:.6g}")
    if at_limit:
        problems.append(f"the configurations pile at the joint limits: {', '.join(at_limit)} (uniform draws within "
                        f"the limits sit there almost never; home may, once: at most {allowed} of {N})")
    return problems
