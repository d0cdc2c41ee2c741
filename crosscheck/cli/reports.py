"""``crosscheck reports``: regenerate the committed reports in reports/ by running each one's own command
(:data:`REPORTS`), parsed by the subparsers those commands' modules add (:data:`COMMANDS`)."""

from __future__ import annotations

from pathlib import Path

from crosscheck.cli import bench, faults, gate, stability, trajectory
from crosscheck.cli.options import INTERRUPTED, OUTPUT_DIR, REPORTS_DIR, _interrupted, _Parser, UsageError

#: The committed reports (in :data:`REPORTS_DIR`) and the command that writes each there: ``crosscheck reports``
#: runs these, so the reports carry the command that regenerates them.
REPORTS = {
    "gate": ["gate", "--report", f"{REPORTS_DIR}/gate.md"],
    "faults": ["faults", "--report", f"{REPORTS_DIR}/faults.md"],
    "bench": ["bench", "--no-stability", "--out", REPORTS_DIR],
    "stability": ["stability", "--out", REPORTS_DIR],
    "scale": ["bench", "--scale", "--out", REPORTS_DIR],
    "trajectories": ["trajectory", "--report", REPORTS_DIR],
}
#: The commands of :data:`REPORTS` that take ``--quiet``.
QUIET = ("gate", "faults", "bench", "scale")
#: The modules of the commands in :data:`REPORTS`: each adds its subparser to the one :func:`cmd_reports` parses
#: them with (``crosscheck.cli.build_parser`` holds every command, but it imports this module).
COMMANDS = (gate, faults, bench, stability, trajectory)


def _only(text: str) -> list[str]:
    """``--only a,b``: report names of :data:`REPORTS`, in the order given."""
    names = [name.strip() for name in text.split(",") if name.strip()]
    unknown = [name for name in names if name not in REPORTS]
    if unknown or not names:
        raise UsageError(f"--only takes report names separated by commas from {', '.join(REPORTS)}; got '{text}'")
    return list(dict.fromkeys(names))


def cmd_reports(args) -> int:
    """``crosscheck reports``: regenerate the committed reports in :data:`REPORTS_DIR` by running each report's own
    command (:data:`REPORTS`) in turn. Exit 0 when each command exits 0, 130 at Ctrl-C (the reports not yet run keep
    their old contents), else 1 (a failing gate or fault hunt still writes its report)."""
    chosen = _only(args.only) if args.only else list(REPORTS)
    if not Path(REPORTS_DIR).is_dir():
        raise UsageError(f"there is no {REPORTS_DIR}/ directory here ({Path.cwd()}): run crosscheck reports from the "
                         "repository's root, where the committed reports are")
    codes = {}
    for name in chosen:
        argv = REPORTS[name] + (["--quiet"] if args.quiet and name in QUIET else [])
        print(f"reports: {name}: crosscheck {' '.join(argv)}", flush=True)
        sub = _parser().parse_args(argv)
        sub.argv = argv
        codes[name] = sub.run(sub)
        if codes[name] == INTERRUPTED:
            return _interrupted(f"while regenerating {name}; not run: {', '.join(chosen[len(codes):]) or 'none'}")
    failed = [name for name, code in codes.items() if code]
    print(f"reports: {len(chosen)} regenerated in {REPORTS_DIR}/" + (f"; exit non-zero: {', '.join(failed)}"
                                                                     if failed else ""))
    return 1 if failed else 0


def _parser() -> _Parser:
    """The ``crosscheck`` parser with the subcommands of :data:`COMMANDS`, each as ``crosscheck`` parses it."""
    parser = _Parser(prog="crosscheck")
    sub = parser.add_subparsers(dest="command", required=True, parser_class=_Parser)
    for command in COMMANDS:
        command.add_parser(sub)
    return parser


def add_parser(sub) -> None:
    """The ``reports`` subcommand on ``sub``."""
    rep = sub.add_parser("reports", help=f"regenerate the committed reports in {REPORTS_DIR}/ (every other command "
                         f"writes to {OUTPUT_DIR}/ by default)")
    rep.add_argument("--only", metavar="NAMES", help=f"comma-separated, from {', '.join(REPORTS)} (default: all; "
                     "each a full run: the faults took about 17 minutes on 2 CPUs in one process)")
    rep.add_argument("--quiet", action="store_true", help="no progress on stderr")
    rep.set_defaults(run=cmd_reports)
