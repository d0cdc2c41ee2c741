"""``crosscheck stability``: true errors and condition numbers along paths into trouble (stability.md)."""

from __future__ import annotations

import sys
from pathlib import Path

from crosscheck.cli.options import OUTPUT_DIR
from crosscheck.guards import preflight
from crosscheck.reports import stability_report


def cmd_stability(args) -> int:
    """``crosscheck stability``: true errors, condition numbers and the gate's verdicts along paths into trouble
    (``crosscheck.campaigns.stability``), written to DIR/stability.md and its charts. Exit 0: it measures."""
    preflight.claim_directory(args.out, "out")
    report = stability_report.write_report(Path(args.out), quick=args.quick,
                                           progress=lambda path, i, n: print(f"{path}: {i}/{n}", file=sys.stderr,
                                                                             flush=True))
    print(f"stability: {report}")
    return 0


def add_parser(sub) -> None:
    """The ``stability`` subcommand on ``sub``."""
    st = sub.add_parser("stability", help="true errors and condition numbers along paths into trouble "
                        "(stability.md)")
    st.add_argument("--quick", action="store_true", help="a few points per path (CI; well under a minute)")
    st.add_argument("--out", default=OUTPUT_DIR, metavar="DIR", help=f"report directory (default {OUTPUT_DIR})")
    st.set_defaults(run=cmd_stability)
