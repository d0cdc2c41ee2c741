"""A campaign's parameters (:class:`FuzzConfig`, from :func:`config`) and its plan of chunks: chunk ``k``'s seed and
size, the chunks of a shard (the campaign as a whole: ``crosscheck.campaigns.fuzz``)."""

from __future__ import annotations

import dataclasses
import hashlib
import itertools
import math
from dataclasses import dataclass
from typing import Iterator

from crosscheck import backends


DEFAULT_DIR = "crosscheck-out/fuzz"
#: Examples of a campaign given neither a number of examples nor of minutes (the command line's default).
DEFAULT_EXAMPLES = 100
#: ``--constraints`` words -> ``FuzzConfig.constraints`` (``crosscheck.testing.models``).
CONSTRAINT_CHOICES = {"never": False, "sometimes": None, "always": True}
#: Examples per chunk: small enough that a chunk ends (and is logged) every few tens of seconds.
CHUNK_EXAMPLES = 10
#: Test calls a chunk may spend shrinking after its first failure; then the smallest failure so far is saved.
SHRINK_CALLS = 300
#: Chunks a worker process runs before it is replaced (the backends cache compiled code per model).
CHUNKS_PER_PROCESS = 4
#: Seconds the campaign waits, after an interruption, for the chunks in flight to save what they hold and report
#: (they stop within a fraction of a second unless a backend is stuck in compiled code).
INTERRUPT_GRACE = 5.0
#: Seconds between a worker's checks of the stop flag and of its parent; between the pool loop's checks.
POLL = 0.1
#: Seconds a chunk's result may take to arrive after its worker exited before the worker counts as lost.
LOST_AFTER = 2.0
#: The parameters that make two runs parts of one campaign (merge and resume require them equal).
IDENTITY = ("seed", "chunk_examples", "max_bodies", "max_states", "constraints", "loads", "group_joints", "backends",
            "plugins", "shrink_calls", "charts", "frames", "conservation", "linearization")


class FuzzError(ValueError):
    """A campaign that cannot run or go on: bad input (a directory of another campaign or in use, a corrupt file, an
    unknown finding, incompatible shards) or a worker process lost."""


#: States drawn per model, at most (each example draws 1 to this many, about a third of it on average): a drawn model
#: costs its preparation (Euler–Lagrange's derivations, geometric's Functions) once for all its states, evaluated as
#: one block. At 4 a campaign checked 5 states/s in a process, at 100 about 50 (2 workers: 95 states/s, 3.1
#: models/s), so throughput and model diversity are both kept (docs/performance.md).
MAX_STATES = 100


@dataclass(frozen=True)
class FuzzConfig:
    """A campaign's parameters. ``examples`` bounds the run (examples generated over all shards, in chunks of
    ``chunk_examples``), else ``minutes`` does; ``workers`` 0 runs in this process (tests, debugging).
    ``backends`` are names (``crosscheck.backends``), ``plugins`` the specs that load the plugin ones.
    ``group_joints``: the drawn trees may have spherical joints, and free joints on bodies hung from the world
    (``crosscheck.testing.models(group=True)``); ``pfaffian``: the drawn constraints may be knife edges, point
    velocities and rolling contacts too (``testing.models(pfaffian=True)``). ``loads``: the drawn models carry external
    loads (``cases.loads``): False never, True always, None sometimes (``crosscheck.testing.models(loads=...)``).
    ``charts``,
    ``frames`` and ``conservation`` turn the gate's checks on or off (the chart and frame are drawn either way)."""

    seed: int = 0
    examples: int | None = None
    minutes: float | None = None
    workers: int = 1
    shard: tuple[int, int] = (0, 1)
    out: str = DEFAULT_DIR
    backends: tuple[str, ...] = ()
    plugins: tuple[str, ...] = ()
    chunk_examples: int = CHUNK_EXAMPLES
    max_bodies: int = 4
    max_states: int = MAX_STATES
    constraints: bool | None = None
    loads: bool | None = None
    group_joints: bool = True
    shrink_calls: int = SHRINK_CALLS
    charts: bool = True
    frames: bool = True
    conservation: bool = True
    linearization: bool = True
    pfaffian: bool = False

    def checks(self) -> dict:
        return {"charts": self.charts, "frames": self.frames, "conservation": self.conservation,
                "linearization": self.linearization}

    def identity(self) -> dict:
        """The fields that make a campaign what it is; ``pfaffian`` only when set (so a campaign without Pfaffian rows
        keeps the identity it had before they existed)."""
        ident = {key: _jsonable(getattr(self, key)) for key in IDENTITY}
        return {**ident, "pfaffian": True} if self.pfaffian else ident


def config(**kwargs) -> FuzzConfig:
    """A checked :class:`FuzzConfig`; the backends default to every one in ``crosscheck.backends``."""
    cfg = FuzzConfig(**kwargs)
    problems = []
    if (cfg.examples is None) == (cfg.minutes is None):
        problems.append("give either a number of examples or of minutes")
    if cfg.examples is not None and cfg.examples < 1:
        problems.append(f"examples must be at least 1, got {cfg.examples}")
    if cfg.minutes is not None and not cfg.minutes > 0:
        problems.append(f"minutes must be positive, got {cfg.minutes}")
    index, count = cfg.shard
    if not (count >= 1 and 0 <= index < count):
        problems.append(f"shard {index}/{count}: give i/N with 0 <= i < N")
    for key in ("workers", "chunk_examples", "max_bodies", "max_states", "shrink_calls"):
        if getattr(cfg, key) < (0 if key in ("workers", "shrink_calls") else 1):
            problems.append(f"{key} is {getattr(cfg, key)}")
    if cfg.constraints is True and cfg.max_bodies < 2:
        problems.append("constrained models need max_bodies >= 2")
    if problems:
        raise FuzzError("fuzz campaign: " + "; ".join(problems))
    names = tuple(cfg.backends) or tuple(backends.names())
    for name in names:
        backends.get(name)  # an unknown name raises, listing the valid ones
    return dataclasses.replace(cfg, backends=names, plugins=tuple(cfg.plugins))


def _jsonable(value):
    return list(value) if isinstance(value, tuple) else value


def chunk_seed(seed: int, k: int) -> int:
    """The Hypothesis seed of chunk ``k`` of the campaign with ``seed``."""
    return int.from_bytes(hashlib.sha256(f"crosscheck-fuzz/{seed}/{k}".encode()).digest()[:8], "big")


def planned_chunks(cfg: FuzzConfig) -> Iterator[int]:
    """This shard's chunks in order (all of them for an examples-bounded campaign; endless for a timed one)."""
    index, count = cfg.shard
    ks = range(math.ceil(cfg.examples / cfg.chunk_examples)) if cfg.examples else itertools.count()
    return (k for k in ks if k % count == index)


def chunk_size(cfg: FuzzConfig, k: int) -> int:
    """Examples of chunk ``k``: ``chunk_examples``, or what is left of the campaign's examples."""
    if cfg.examples is None:
        return cfg.chunk_examples
    return min(cfg.chunk_examples, cfg.examples - k * cfg.chunk_examples)
