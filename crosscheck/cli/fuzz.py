"""``crosscheck fuzz``, ``replay`` and ``merge``: run a fuzzing campaign (``crosscheck.campaigns.fuzz``), evaluate
one of its findings again, combine the directories of its shards."""

from __future__ import annotations

import math
import shlex
from pathlib import Path

import numpy as np

from crosscheck import backends
from crosscheck.campaigns.fuzz import replay, runs, settings
from crosscheck.cli.options import (OUTPUT_DIR, _interrupted, _seed, add_plugin_option, add_quiet_option,
                                    add_workers_option, UsageError, workers)
from crosscheck.reports import fuzz_report
from crosscheck.testing import describe_failure

#: ``fuzz --out`` and ``replay --dir`` (``crosscheck.campaigns.fuzz.settings.DEFAULT_DIR`` for the Python API).
DEFAULT_FUZZ_DIR = f"{OUTPUT_DIR}/fuzz"


def _shard(text: str) -> tuple[int, int]:
    index, sep, count = text.partition("/")
    if not (sep and index.isdigit() and count.isdigit()):
        raise UsageError(f"--shard takes i/N (e.g. 0/4), got '{text}'")
    return int(index), int(count)


def _fuzz_chunks(args) -> float:
    """The chunks this shard of the campaign runs (the units its ``--workers`` share out); inf for ``--minutes``."""
    if args.minutes is not None:
        return float("inf")
    index, count = _shard(args.shard)
    chunks = math.ceil((args.examples or settings.DEFAULT_EXAMPLES)
                       / max(args.chunk_examples or settings.CHUNK_EXAMPLES, 1))
    return len(range(index, chunks, count)) if count else 0   # a bad shard or count: settings.config says what is wrong


def cmd_fuzz(args) -> int:
    if args.examples is not None and args.minutes is not None:
        raise UsageError("give either --examples or --minutes, not both")
    if args.minutes is not None and not 0.0 < args.minutes < np.inf:
        raise UsageError(f"--minutes takes a positive, finite number of minutes, got {args.minutes}")
    bound = {"examples": args.examples, "minutes": args.minutes}
    if args.examples is None and args.minutes is None:
        bound["examples"] = settings.DEFAULT_EXAMPLES
    if args.chunk_examples is not None:
        bound["chunk_examples"] = args.chunk_examples
    try:
        cfg = settings.config(seed=args.seed, workers=workers(args.workers, _fuzz_chunks(args)),
                              shard=_shard(args.shard), out=args.out,
                              backends=tuple(args.formalism or ()), plugins=backends.plugin_specs(),
                              max_bodies=args.max_bodies, max_states=args.max_states,
                              constraints=settings.CONSTRAINT_CHOICES[args.constraints],
                              loads=settings.CONSTRAINT_CHOICES[args.loads],
                              group_joints=args.joints == "all", charts=not args.no_charts,
                              frames=not args.no_frames, conservation=not args.no_conservation,
                              linearization=not args.no_linearization, pfaffian=args.pfaffian, **bound)
        result = runs.run_campaign(cfg, "crosscheck " + " ".join(shlex.quote(a) for a in args.argv), args.quiet)
    except settings.FuzzError as exc:
        raise UsageError(str(exc)) from None
    print(fuzz_report.summary(result))
    if result.interrupted:
        return _interrupted("(the chunks in flight saved what they held); report written to "
                            f"{result.out / 'report.md'}; the same command again resumes the campaign")
    return 1 if result.findings else 0


def cmd_replay(args) -> int:
    try:
        finding = replay.find(Path(args.dir), args.id)
    except settings.FuzzError as exc:
        raise UsageError(str(exc)) from None
    missing = [name for name in (args.formalism or finding["backends"]) if name not in backends.names()]
    if missing:
        command = fuzz_report.replay_command(finding["id"], Path(args.dir),
                                             fuzz_report.campaign_plugins(Path(args.dir)))
        raise UsageError(f"finding {finding['id']} was evaluated with backend(s) {', '.join(missing)}, not loaded "
                         f"here; run `{command}`")
    outcome = replay.replay(finding, args.formalism)
    print(f"finding {finding['id']} (chunk {finding['campaign']['chunk']} of the campaign with seed "
          f"{finding['campaign']['seed']}), chart {finding['chart']['name']}, frame {finding['frame']['name']}:")
    if outcome.failed:
        print("FAILS " + describe_failure(outcome))
        return 1
    worst = max((c.worst_ratio for c in [*outcome.comparisons.values(), *outcome.checks.values()]), default=0.0)
    print(f"passes now: {len(outcome.comparisons) + len(outcome.checks)} comparisons and checks agree, worst "
          f"error/tolerance {worst:.3g}")
    return 0


def cmd_merge(args) -> int:
    try:
        result = runs.merge([Path(d) for d in args.dirs], Path(args.out),
                            "crosscheck " + " ".join(shlex.quote(a) for a in args.argv))
    except settings.FuzzError as exc:
        raise UsageError(str(exc)) from None
    print(fuzz_report.summary(result))
    return 1 if result.findings else 0


def add_parser(sub) -> None:
    """The ``fuzz``, ``replay`` and ``merge`` subcommands on ``sub``."""
    fz = sub.add_parser("fuzz", help="fuzzing campaign: random models and states, failures shrunk and saved")
    fz.add_argument("--examples", type=int, help="examples to generate over all shards (default 100 when --minutes "
                    "is not given)")
    fz.add_argument("--minutes", type=float, help="run for this long instead (the chunks in flight then finish)")
    fz.add_argument("--seed", type=_seed, default=0, help="campaign seed (default 0)")
    add_workers_option(fz, "chunk")   # a worker is replaced every few chunks: that bounds a campaign's memory
    fz.add_argument("--shard", default="0/1", metavar="i/N", help="run the chunks k with k %% N == i (default 0/1)")
    fz.add_argument("--out", default=DEFAULT_FUZZ_DIR, metavar="DIR",
                    help=f"campaign directory: findings, chunk log, report.md (default {DEFAULT_FUZZ_DIR})")
    fz.add_argument("--formalism", action="append", help="restrict to these backends (repeatable)")
    fz.add_argument("--max-bodies", type=int, default=4, help="largest drawn model (default 4 bodies)")
    fz.add_argument("--chunk-examples", type=int, default=None, metavar="N",
                    help="examples per chunk (part of the campaign's identity; default 10)")
    fz.add_argument("--max-states", type=int, default=settings.MAX_STATES,
                    help=f"states per drawn model, at most (default {settings.MAX_STATES}: 1 to that many)")
    fz.add_argument("--constraints", choices=["never", "sometimes", "always"], default="sometimes",
                    help="constrained models (default sometimes)")
    fz.add_argument("--pfaffian", action="store_true",
                    help="the drawn constraints may also be Pfaffian: knife edges, point velocities, rolling contacts")
    fz.add_argument("--loads", choices=["never", "sometimes", "always"], default="sometimes",
                    help="models with external loads: forces, wrenches, springs (default sometimes)")
    fz.add_argument("--joints", choices=["all", "scalar"], default="all",
                    help="joint types drawn: all (revolute, prismatic, spherical, free; default) or scalar (revolute "
                         "and prismatic only)")
    fz.add_argument("--no-charts", action="store_true", help="skip the chart invariance checks")
    fz.add_argument("--no-frames", action="store_true", help="skip the frame invariance checks")
    fz.add_argument("--no-conservation", action="store_true", help="skip the energy and Christoffel checks")
    fz.add_argument("--no-linearization", action="store_true",
                    help="skip the comparison of the linearizations A, B (eq. 11) at each example's first state")
    add_plugin_option(fz)
    add_quiet_option(fz)
    fz.set_defaults(run=cmd_fuzz)

    rp = sub.add_parser("replay", help="evaluate a saved fuzzing finding again")
    rp.add_argument("id", help="the finding's ID (or a unique prefix), as in the campaign report")
    rp.add_argument("--dir", default=DEFAULT_FUZZ_DIR, help=f"campaign directory (default {DEFAULT_FUZZ_DIR})")
    rp.add_argument("--formalism", action="append", help="evaluate these backends instead of the finding's")
    add_plugin_option(rp)
    rp.set_defaults(run=cmd_replay)

    mg = sub.add_parser("merge", help="combine the directories of fuzzing shards into one, with its report")
    mg.add_argument("dirs", nargs="+", metavar="DIR", help="campaign directories (shards of one campaign)")
    mg.add_argument("--out", required=True, metavar="DIR", help="the merged campaign directory")
    mg.set_defaults(run=cmd_merge)
