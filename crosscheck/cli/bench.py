"""``crosscheck bench``: speed against accuracy of every backend and the stability maps, or (``--scale``) the gate
and campaigns on large robots, each a whole process."""

from __future__ import annotations

from pathlib import Path

from crosscheck import backends
from crosscheck.campaigns import bench, scale, stability
from crosscheck.cli.options import OUTPUT_DIR, _interrupted, add_plugin_option, add_quiet_option
from crosscheck.engine.progress import Display
from crosscheck.guards import preflight
from crosscheck.reports import bench_report, stability_report


def cmd_bench(args) -> int:
    """``crosscheck bench``: time and error of every backend (DIR/speed_accuracy.md and its charts), then the
    stability maps (DIR/stability.md), so one command regenerates both reports. Exit 0: it measures."""
    preflight.claim_directory(args.out, "out")
    if args.scale:
        return _bench_scale(args)
    plan = bench.QUICK if args.quick else bench.FULL
    names = args.formalism or None
    for name in names or []:
        backends.get(name)
    with Display("bench", "steps", bench.steps(plan, names or backends.names()), quiet=args.quiet) as display:
        try:
            results = bench.run(plan, names, getattr(args, "plugin", []), display)
        except bench.Interrupted as stop:
            path = bench_report.write(stop.results, Path(args.out), stop.where)
            return _interrupted(f"while {stop.where}; partial report written to {path}")
        speed = bench_report.write(results, Path(args.out))
        print(f"speed and accuracy: {speed}")
        if not args.no_stability:
            try:
                print(f"stability: {_stability_maps(args.out, args.quick, display)}")
            except KeyboardInterrupt:
                return _interrupted(f"during the stability maps; {speed} is complete, stability.md not updated")
    return 0


def _bench_scale(args) -> int:
    """``crosscheck bench --scale``: large robots and campaigns as whole processes (DIR/scale.md)."""
    plan = scale.QUICK if args.quick else scale.FULL
    with Display("bench --scale", "steps", scale.steps(plan), quiet=args.quiet) as display:
        try:
            results = scale.run(plan, display)
        except KeyboardInterrupt:
            return _interrupted("scale measurements not written")
    print(f"scale: {scale.write(results, Path(args.out))}")
    return 0


def _stability_maps(out: str, quick: bool, display: Display) -> Path:
    """The stability maps (``crosscheck.campaigns.stability``), a step on ``display`` per point; the report's path."""
    display.stage("stability points", sum(len(p.points) for p in stability.paths(quick, backends.names())))

    def measured(path: str, done: int, count: int) -> None:
        display.advance()
        display.doing(f"stability: {path} {done}/{count}")

    return stability_report.write_report(Path(out), quick=quick, progress=measured)


def add_parser(sub) -> None:
    """The ``bench`` subcommand on ``sub``."""
    bn = sub.add_parser("bench", help="speed against accuracy of every backend, stability maps (speed_accuracy.md, "
                        "stability.md and their charts)", description="Runs in this process, no --workers: the "
                        "timings need the machine as quiet as it gets.")
    bn.add_argument("--quick", action="store_true", help="few scenes, states and repeats (CI; about a minute)")
    bn.add_argument("--out", default=OUTPUT_DIR, metavar="DIR", help=f"report directory (default {OUTPUT_DIR})")
    bn.add_argument("--formalism", action="append", help="restrict to these backends (repeatable)")
    bn.add_argument("--no-stability", action="store_true", help="skip the stability maps (DIR/stability.md)")
    bn.add_argument("--scale", action="store_true", help="instead: the gate on tiago, g1 and solo12, Euler–Lagrange "
                    "preparation against joints, fuzz throughput, each a whole process (DIR/scale.md)")
    add_plugin_option(bn)
    add_quiet_option(bn)
    bn.set_defaults(run=cmd_bench)
