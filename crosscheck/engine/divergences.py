"""The divergence registry: known, explained divergences, checked in as ``divergences.toml`` (docs/design.md, verdicts).

Each entry names a backend, a glob on the case (or model) name, a glob on the quantity or check key (``drift``,
``chart affine: ctrl``, ``frame law: screw wrenches_space``, ``conservation: ...``), the reason (required) and
optionally ``max_ratio``, the largest error/tolerance the explanation covers::

    [[divergence]]
    backend = "operational_space"
    case = "panda*"
    quantity = "task_drift"
    reason = "why this divergence is understood and accepted"
    max_ratio = 50.0

A DISAGREE is explained by an entry when its case and key match the globs, every pair of voters further apart than
the tolerance involves the entry's backend (it is the outlier, or one of only two voters, or alone behind a frame
law) and its worst ratio is within ``max_ratio``. It becomes KNOWN: reported with the reason, not a failure.
Anything not listed still fails. An entry whose backend, case and key were compared in a run but that explained
nothing there is stale: reported as a warning, not a failure.
"""

from __future__ import annotations

import dataclasses
import fnmatch
import math
import re
import tomllib
from collections import Counter
from dataclasses import dataclass, field
from pathlib import Path
from typing import Iterable, Sequence

from crosscheck import backends
from crosscheck.checks import charts
from crosscheck.checks.invariance import CONSTRAINED_INVARIANT, FRAME_LAWS, INVARIANT
from crosscheck.core.compare import DISAGREE, KNOWN, NOT_COMPARED, backend_of, Comparison
from crosscheck.core.tolerance import TOLERANCES
from crosscheck.engine.outcomes import GateResult, StateOutcome

DEFAULT_PATH = "divergences.toml"
REQUIRED = ("backend", "case", "quantity", "reason")
OPTIONAL = ("max_ratio",)


class RegistryError(ValueError):
    """A registry file that cannot be used: says which file, which entry and what to fix."""


@dataclass(frozen=True)
class Entry:
    """One known divergence (module doc); ``number`` is its position in the file, from 1."""

    backend: str
    case: str
    quantity: str
    reason: str
    max_ratio: float | None = None
    number: int = 0

    def describe(self) -> str:
        bound = f", max_ratio {self.max_ratio:g}" if self.max_ratio is not None else ""
        return f"entry {self.number} (backend {self.backend}, case {self.case}, quantity {self.quantity}{bound})"

    def covers(self, case_names: Sequence[str], key: str) -> bool:
        """Whether the globs match this case (any of its names) and this quantity or check key."""
        return fnmatch.fnmatchcase(key, self.quantity) and any(fnmatch.fnmatchcase(n, self.case) for n in case_names)

    def explains(self, case_names: Sequence[str], key: str, comp: Comparison) -> bool:
        """Whether this entry explains the disagreement ``comp`` on ``key`` (module doc)."""
        if comp.verdict != DISAGREE or not self.covers(case_names, key):
            return False
        if self.max_ratio is not None and not comp.worst_ratio <= self.max_ratio:
            return False
        pairs = comp.disagreeing_pairs
        return bool(pairs) and all(self.backend in (backend_of(a), backend_of(b)) for a, b in pairs)

    def exercised(self, case_names: Sequence[str], key: str, comp: Comparison) -> bool:
        """Whether ``comp`` compared this entry's backend on a key and case it covers (whatever the verdict)."""
        return (comp.verdict != NOT_COMPARED and self.covers(case_names, key)
                and self.backend in {backend_of(v) for v in comp.voters})


@dataclass(frozen=True)
class Registry:
    entries: tuple[Entry, ...]
    source: str = DEFAULT_PATH


@dataclass
class Usage:
    """What a registry did in a run: comparisons made KNOWN per entry number, and the entries exercised."""

    matched: Counter = field(default_factory=Counter)
    exercised: set[int] = field(default_factory=set)

    def add(self, other: "Usage") -> "Usage":
        self.matched.update(other.matched)
        self.exercised |= other.exercised
        return self


@dataclass(frozen=True)
class Applied:
    """A registry applied to a gate run: the KNOWN count, the stale entries (exercised, explained nothing) and
    the entries the run never exercised (their backend, case or key was not compared)."""

    registry: Registry
    usage: Usage

    @property
    def known(self) -> int:
        return sum(self.usage.matched.values())

    @property
    def stale(self) -> tuple[Entry, ...]:
        return tuple(e for e in self.registry.entries
                     if e.number in self.usage.exercised and not self.usage.matched[e.number])

    @property
    def unexercised(self) -> tuple[Entry, ...]:
        return tuple(e for e in self.registry.entries if e.number not in self.usage.exercised)


# ----------------------------------------------------------------------------------------------- loading


def known_keys() -> tuple[str, ...]:
    """Every quantity and check key a gate run can produce, except the conservation checks (any key starting
    ``conservation`` is accepted)."""
    invariant = INVARIANT + CONSTRAINED_INVARIANT
    keys = list(TOLERANCES)
    keys += [f"chart {chart}: {q}" for chart in charts.names() for q in invariant]
    keys += [f"frame: {q}" for q in invariant]
    keys += [f"frame law: {b} {extra}" for b in backends.names() for extra in FRAME_LAWS]
    return tuple(keys)


def _glob(entry: str, name: str, value) -> str:
    if not isinstance(value, str) or not value.strip():
        raise RegistryError(f"{entry}: '{name}' must be a non-empty string (a glob: * ? [..]), got {value!r}")
    if re.search(r"\[[^\]]*$", value):
        raise RegistryError(f"{entry}: '{name}' = {value!r} has an unclosed '[' (a glob character class)")
    return value


def _entry(raw, number: int, source: str) -> Entry:
    where = f"{source}: [[divergence]] entry {number}"
    if not isinstance(raw, dict):
        raise RegistryError(f"{where}: expected a table with keys {', '.join(REQUIRED + OPTIONAL)}, got {raw!r}")
    unknown = sorted(set(raw) - set(REQUIRED + OPTIONAL))
    if unknown:
        raise RegistryError(f"{where}: unknown key(s) {', '.join(unknown)}; valid keys: "
                            f"{', '.join(REQUIRED + OPTIONAL)}")
    missing = [k for k in REQUIRED if k not in raw]
    if missing:
        raise RegistryError(f"{where}: missing {', '.join(missing)}"
                            + ("; every known divergence must say why it is explained" if "reason" in missing else ""))
    reason = raw["reason"]
    if not isinstance(reason, str) or not reason.strip():
        raise RegistryError(f"{where}: 'reason' is empty; every known divergence must say why it is explained")
    backend = raw["backend"]
    if backend not in backends.names():
        raise RegistryError(f"{where}: unknown backend {backend!r}; valid: {', '.join(backends.names())} (a plugin "
                            "backend must be loaded, e.g. with --plugin, before the registry is read)")
    quantity = _glob(where, "quantity", raw["quantity"])
    if not quantity.startswith("conservation") and not fnmatch.filter(known_keys(), quantity):
        raise RegistryError(f"{where}: quantity {quantity!r} matches no quantity or check key; quantities: "
                            f"{', '.join(TOLERANCES)}; checks: 'chart NAME: QUANTITY', 'frame: QUANTITY', "
                            "'frame law: BACKEND EXTRA', 'conservation: ...'")
    bound = raw.get("max_ratio")
    if bound is not None and (isinstance(bound, bool) or not isinstance(bound, (int, float))
                              or not math.isfinite(bound) or bound <= 1.0):
        raise RegistryError(f"{where}: 'max_ratio' must be a finite number above 1 (an error/tolerance ratio; "
                            f"ratios up to 1 agree), got {bound!r}")
    return Entry(backend, _glob(where, "case", raw["case"]), quantity, reason.strip(),
                 None if bound is None else float(bound), number)


def parse(text: str, source: str = DEFAULT_PATH) -> Registry:
    """Validate a registry's TOML text; a :class:`RegistryError` names the file, the entry and the problem."""
    try:
        data = tomllib.loads(text)
    except tomllib.TOMLDecodeError as exc:
        raise RegistryError(f"{source}: not valid TOML: {exc}") from None
    unknown = sorted(set(data) - {"divergence"})
    if unknown:
        raise RegistryError(f"{source}: unknown top-level key(s) {', '.join(unknown)}; the file holds "
                            "[[divergence]] tables only")
    raw = data.get("divergence", [])
    if not isinstance(raw, list):
        raise RegistryError(f"{source}: 'divergence' must be an array of tables ([[divergence]]), got {raw!r}")
    entries = tuple(_entry(item, number, source) for number, item in enumerate(raw, 1))
    seen: dict[tuple[str, str, str], int] = {}
    for e in entries:
        first = seen.setdefault((e.backend, e.case, e.quantity), e.number)
        if first != e.number:
            raise RegistryError(f"{source}: entry {e.number} repeats entry {first} (backend {e.backend}, case "
                                f"{e.case}, quantity {e.quantity}); merge them")
    return Registry(entries, source)


def load(path: str | Path) -> Registry:
    """Read and validate the registry file at ``path``."""
    path = Path(path)
    if not path.is_file():
        raise RegistryError(f"registry file {path} not found (pass --no-registry to run without one)")
    return parse(path.read_text(encoding="utf-8"), str(path))


# ---------------------------------------------------------------------------------------------- applying


def _apply(entries: Iterable[Entry], case_names: Sequence[str], found: dict[str, Comparison], usage: Usage) -> None:
    for key, comp in found.items():
        usage.exercised |= {e.number for e in entries if e.exercised(case_names, key, comp)}
        entry = next((e for e in entries if e.explains(case_names, key, comp)), None)
        if entry is not None:
            found[key] = dataclasses.replace(comp, verdict=KNOWN, reason=entry.reason)
            usage.matched[entry.number] += 1


def apply_to_state(registry: Registry, case_names: Sequence[str], outcome: StateOutcome) -> Usage:
    """Turn the disagreements at one state that an entry explains into KNOWN (in place, in its comparisons and
    checks); ``case_names`` are the names the case globs are matched against (case and model name)."""
    usage = Usage()
    _apply(registry.entries, case_names, outcome.comparisons, usage)
    _apply(registry.entries, case_names, outcome.checks, usage)
    return usage


def apply(registry: Registry, result: GateResult) -> Applied:
    """Apply the registry to every state of a gate run (in place)."""
    usage = Usage()
    for case in result.cases:
        names = (case.spec.name, case.model.name)
        for state in case.states:
            usage.add(apply_to_state(registry, names, state))
    return Applied(registry, usage)
