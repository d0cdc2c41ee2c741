"""``crosscheck simulators``: every installed simulator adapter (``crosscheck.adapters``) against the five formalisms
and the reference on one model file, and the conformance report (``crosscheck.reports.conformance``).

The run is the gate's (every check, the self-test) with each simulator as an ``--optional`` plugin (a model it
cannot read is NOT COMPARED, with the reason); its report is written beside the conformance report
(``NAME-gate.md``). Exit 0 when every simulator conforms and the gate passes, 1 when a simulator has a finding or the
gate fails otherwise (then the built-in backends disagree: read the gate report), as ``gate`` for the rest.
"""

from __future__ import annotations

import argparse
import os
from pathlib import Path

from crosscheck import adapters, backends
from crosscheck.cli import gate
from crosscheck.cli.options import (OUTPUT_DIR, UsageError, _Parser, add_plugin_option, add_quiet_option,
                                    add_workers_option)
from crosscheck.engine.outcomes import GateResult
from crosscheck.guards import preflight
from crosscheck.needs import source_scene
from crosscheck.reports import conformance
from formalisms.interface import ModelNotSupported

DEFAULT_REPORT = f"{OUTPUT_DIR}/simulators.md"


def _gate_args(args, specs: list[str], names: list[str], gate_report: Path) -> argparse.Namespace:
    """The ``gate`` options of this run: the file, the simulators as optional plugins, the gate report's path."""
    argv = ["gate", "--model", args.model, "--samples", str(args.samples), "--seed", str(args.seed),
            "--report", str(gate_report)]
    for flag in ("base", "actuated", "armature", "workers"):
        if getattr(args, flag) is not None:
            argv += [f"--{flag}", str(getattr(args, flag))]
    argv += ["--quiet"] * args.quiet
    for spec, name in zip(specs, names):
        argv += ["--plugin", spec, "--optional", name]
    parser = _Parser(prog="crosscheck")
    gate.add_parser(parser.add_subparsers(dest="command", parser_class=_Parser))
    parsed = parser.parse_args(argv)
    parsed.argv = argv
    return parsed


def _reason(result: GateResult, name: str) -> str:
    """Why ``name`` is NOT COMPARED on the run's model (its ModelNotSupported), or "" when it voted somewhere."""
    case = result.cases[0] if result.cases else None
    if case is None or not case.states or name in case.voted():
        return ""
    first = case.states[0].state
    try:
        backends.get(name).split(case.model, first.q, first.qd, first.u)
    except ModelNotSupported as exc:
        return str(exc)
    except Exception as exc:  # noqa: BLE001 - the plugin's own failure, reported as its reason
        return f"{type(exc).__name__}: {exc}"
    return ""


def _info(result: GateResult, name: str) -> dict:
    """What the report says of a simulator besides its cells: the library, its defaults off and on, the reason."""
    obj = backends.plugin_object(name)
    defaults = getattr(obj, "DEFAULTS", {})
    on = sorted(getattr(obj, "on", ()))
    library = obj.library() if hasattr(obj, "library") else getattr(obj, "summary", "") or name
    reason = _reason(result, name)
    used = _in_file(obj, result, name) if not reason else {}
    return {"library": library, "on": on, "reason": reason,
            "off": [(d, what + (f" **(this file: {used[d]})**" if d in used else "")) for d, what in defaults.items()
                    if d not in on]}


def _in_file(obj, result: GateResult, name: str) -> dict[str, str]:
    """The defaults the run's file sets (``Adapter.in_file``), or none when the adapter cannot tell."""
    if not callable(getattr(obj, "in_file", None)) or not result.cases:
        return {}
    try:
        return obj.in_file(source_scene(result.cases[0].model, name))
    except Exception:  # noqa: BLE001 - a note of the report, never its failure
        return {}


def cmd_simulators(args) -> int:
    specs = list(args.plugin) or [adapters.plugin_spec(name) for name in adapters.installed()]
    if not specs:
        raise UsageError("no simulator is installed: pip install 'crosscheck[simulators]' (or one of "
                         f"{', '.join(adapters.SIMULATORS)}), or name your own with --plugin")
    names = [backends.load_plugin(spec).name for spec in specs]
    report = preflight.claim_output(args.report, "report", "# crosscheck simulators\n\nNot finished.\n")
    gate_report = report.with_name(f"{report.stem}-gate.md")
    code, result = gate.gated(_gate_args(args, specs, names, gate_report))
    info = {name: _info(result, name) for name in names}
    text, conforms, verdicts = conformance.render(result, args.model, info,
                                                  os.path.relpath(gate_report, report.parent))
    report.write_text(text)
    for name in names:
        print(f"simulator {name:24s} {verdicts.get(name, 'not run: see the gate report')}")
    verdict = "PASS" if code == 0 and conforms else "FAIL"
    print(f"{verdict}: conformance report written to {report}")
    return code if code not in (0, 1) else 0 if verdict == "PASS" else 1


def add_parser(sub) -> None:
    """The ``simulators`` subcommand on ``sub``."""
    p = sub.add_parser("simulators", help="every installed simulator against the formalisms on a model file: "
                       "a conformance report")
    p.add_argument("--model", required=True, metavar="PATH", help="a URDF (.urdf) or MJCF (.xml) file")
    p.add_argument("--base", choices=("fixed", "free"), help="a URDF's base (default: as the file says)")
    p.add_argument("--actuated", metavar="JOINTS", help="a URDF's actuated joints, comma-separated")
    p.add_argument("--armature", metavar="JOINT=VALUE[,...]", help="a URDF's joints' armature (rotor inertia on M's "
                   "diagonal), given to each simulator that can hold it (an MJCF file declares its own)")
    p.add_argument("--samples", type=int, default=20, help="states (default 20)")
    p.add_argument("--seed", type=int, default=0, help="random seed (default 0)")
    p.add_argument("--report", default=DEFAULT_REPORT, metavar="PATH",
                   help=f"the conformance report (default {DEFAULT_REPORT}); the gate's goes beside it, NAME-gate.md")
    add_workers_option(p, "case")
    add_plugin_option(p)
    add_quiet_option(p)
    p.set_defaults(run=cmd_simulators)
