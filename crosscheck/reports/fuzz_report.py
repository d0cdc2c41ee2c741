"""A fuzzing campaign's report (``report.md`` in its directory) and the command's summary: every example asked
accounted for (:func:`account`), findings grouped by signature (:func:`signature`), each with its replay command."""

from __future__ import annotations

import math
import shlex
from dataclasses import dataclass
from pathlib import Path
from typing import Sequence

import numpy as np

from crosscheck.campaigns.fuzz.settings import CHUNK_EXAMPLES
from crosscheck.campaigns.fuzz.storage import CampaignResult, load_campaign, load_chunks, load_findings, write_atomic


# ------------------------------------------------------------------------------------------------ report


def _vec(values) -> str:
    """A vector (or a matrix, row after row) with 6 significant digits."""
    return "[" + ", ".join(f"{float(x):.6g}" for x in np.ravel(values)) + "]"


def describe_model(d: dict) -> list[str]:
    """A serialized model in a few lines: each body and joint, gravity, B, task point, constraints."""
    lines = []
    for b in d["bodies"]:
        inertia = "point mass" if not any(map(any, b["inertia"])) else f"inertia {b['inertia']}"
        lines.append(f"  - `{b['name']}`: {b['joint']} about {_vec(b['axis'])} on {b['parent'] or 'the world'} "
                     f"at {_vec(b['translation'])}, rotation {b['rotation']}; mass {b['mass']:.6g} kg, "
                     f"COM {_vec(b['com'])}, {inertia}")
    B = np.array(d["input_map"])
    lines.append(f"  - gravity {_vec(d['gravity'])}; B "
                 + ("identity" if B.shape[0] == B.shape[1] and np.array_equal(B, np.eye(len(B))) else str(B.tolist())))
    for tp in d["task_points"]:
        lines.append(f"  - task point `{tp['name']}` on `{tp['body']}` at {_vec(tp['offset'])}, "
                     f"directions {tp['directions']}")
    for c in d["constraints"]:
        fields = ", ".join(f"{k} {v}" for k, v in c.items() if k not in ("type", "name"))
        lines.append(f"  - constraint `{c['name']}`: {c['type']} ({fields})")
    return lines


def replay_command(finding_id: str, out: Path, plugins: Sequence[str]) -> str:
    """The command that evaluates a finding again: ``crosscheck replay ID --dir OUT`` with a ``--plugin`` flag for
    each plugin the campaign loaded by spec (its findings name those backends; entry points load themselves)."""
    return f"crosscheck replay {finding_id} --dir {out}" + "".join(f" --plugin {shlex.quote(p)}" for p in plugins)


def campaign_plugins(out: Path) -> list[str]:
    """The plugin specs of the campaign in ``out`` (its identity), none for a directory without one."""
    return list((load_campaign(out) or {"identity": {}})["identity"].get("plugins", []))


def _finding_section(f: dict, out: Path, plugins: Sequence[str] = ()) -> list[str]:
    s, chart, frame = f["state"], f["chart"], f["frame"]
    camp = f["campaign"]
    how = "shrunk" if f["shrunk"] else "NOT fully shrunk (" + (
        "interrupted: resuming the campaign runs its chunk again" if camp.get("interrupted")
        else "interrupted or shrinking budget spent") + ")"
    lines = [f"### Finding `{f['id']}`", "",
             f"Chunk {camp['chunk']} (campaign seed {camp['seed']}), {how}; worst error/tolerance "
             f"{f['worst_ratio']:.3g}.", "",
             f"- model ({len(f['model']['bodies'])} bodies, {len(f['model']['constraints'])} constraints):",
             *describe_model(f["model"]),
             f"- state: q = {s['q']}, qd = {s['qd']}, u = {s['u']}",
             f"- chart `{chart['name']}` (seed {chart['seed']}); frame `{frame['name']}`: rotation "
             f"{frame['rotation']}, translation {frame['translation']}",
             f"- backends: {', '.join(f['backends'])}; checks: "
             + ", ".join(["comparison"] + [name for name, on in f["checks"].items() if on]),
             f"- reproduce: `{replay_command(f['id'], out, plugins)}`", ""]
    if f["failing"]:
        lines += ["| check | error/tolerance | tolerance | outlier |", "|---|---|---|---|"]
        lines += [f"| {c['key']} | {c['worst_ratio']:.3g} | {c['tolerance']:.3g} | {c['outlier'] or '-'} |"
                  for c in f["failing"]]
        lines += ["", "Values:", "", "```"]
        for c in f["failing"]:
            lines.append(f"{c['key']}:")
            lines += [f"  {voter}: {_vec(v)}" for voter, v in c["values"].items()]
        lines += ["```", ""]
    if f["errors"]:
        lines += ["Errors:", "", "```"] + [f"{name}: {message}" for name, message in f["errors"].items()] + ["```", ""]
    return lines


#: Why examples of a campaign were not generated (:func:`account`), in report order.
FAILED = "in chunks that ended at their first failure (Hypothesis shrinks it instead of generating the rest)"
INTERRUPTED = "in interrupted chunks (they run again when the same command resumes the campaign)"
NOT_RUN = "in chunks not run yet (the run was stopped before them; the same command resumes the campaign)"
EARLY = "in chunks where Hypothesis stopped without a failure (it had nothing new to draw)"


@dataclass(frozen=True)
class Accounting:
    """The examples a campaign was asked for (``asked``; None when bounded by ``minutes``) and ``generated``, and the
    ones not generated, as ``(reason, chunks, examples)`` per reason (:data:`FAILED`, :data:`INTERRUPTED`,
    :data:`NOT_RUN`, :data:`EARLY`) with at least one example."""

    asked: int | None
    minutes: float | None
    generated: int
    missing: tuple[tuple[str, int, int], ...]

    def text(self) -> str:
        """``56 of 100 asked generated`` and what became of the rest, or ``56 generated (asked: 5 minutes)``."""
        if self.asked is None:
            return f"{self.generated} generated" + (f" (asked: {self.minutes:g} minutes)" if self.minutes else "")
        text = f"{self.generated} of {self.asked} asked generated"
        if self.missing:
            text += "; not generated: " + "; ".join(f"{n} {why} ({chunks} chunk{'s' * (chunks != 1)})"
                                                     for why, chunks, n in self.missing)
        return text


def _asked(campaign: dict) -> tuple[int | None, float | None, list[tuple[int, int]]]:
    """The latest run's bound (examples or minutes) and every shard (i, N) run in this directory."""
    runs = campaign.get("runs", [])
    last = runs[-1] if runs else {}
    shards = sorted({tuple(int(x) for x in r["shard"].split("/")) for r in runs if "shard" in r})
    return last.get("examples"), last.get("minutes"), shards


def account(campaign: dict, chunks: Sequence[dict]) -> Accounting:
    """The campaign's examples asked, generated and not generated, and why (:class:`Accounting`): a chunk's planned
    examples are its record's ``planned`` (else the campaign's ``chunk_examples``); the chunks an examples-bounded
    campaign plans for the shards run here and that are not in the log are not run yet."""
    asked, minutes, shards = _asked(campaign)
    size = campaign.get("identity", {}).get("chunk_examples") or CHUNK_EXAMPLES
    missing = {FAILED: [0, 0], INTERRUPTED: [0, 0], NOT_RUN: [0, 0], EARLY: [0, 0]}
    for r in chunks:
        short = r.get("planned", size) - r["examples"]
        if short > 0:
            why = INTERRUPTED if r["interrupted"] else FAILED if r["findings"] else EARLY
            missing[why][0] += 1
            missing[why][1] += short
    if asked is not None:
        logged = {r["chunk"] for r in chunks}
        for k in range(math.ceil(asked / size)):
            if k not in logged and any(k % count == index for index, count in shards):
                missing[NOT_RUN][0] += 1
                missing[NOT_RUN][1] += min(size, asked - k * size)
    return Accounting(asked, minutes, sum(r["examples"] for r in chunks),
                      tuple((why, c, n) for why, (c, n) in missing.items() if n > 0))


def mechanism(d: dict) -> str:
    """A serialized model's shape: how many joints of each type, and of each constraint kind (``2 revolute,
    1 prismatic; 1 PointOnCircle``)."""
    def counted(names) -> str:
        kinds = sorted(set(names))
        return ", ".join(f"{list(names).count(kind)} {kind}" for kind in kinds)

    text = counted([b["joint"] for b in d["bodies"]]) or "no joints"
    constraints = [c["type"] for c in d["constraints"]]
    return text + (f"; {counted(constraints)}" if constraints else "")


def signature(finding: dict) -> tuple[str, str, str, str]:
    """What one bug found many times has in common (module doc): the failing checks, the outliers the vote named,
    the backends in error and the mechanism (:func:`mechanism`), each as text (``-`` for none)."""
    failing = finding["failing"]
    return (", ".join(sorted(c["key"] for c in failing)) or "-",
            ", ".join(sorted({c["outlier"] for c in failing if c["outlier"]})) or "-",
            ", ".join(sorted(finding["errors"])) or "-",
            mechanism(finding["model"]))


def group(findings: Sequence[dict]) -> list[tuple[tuple[str, str, str, str], list[dict]]]:
    """The findings by :func:`signature`, the largest group first (then by their first finding's order)."""
    groups: dict[tuple[str, str, str, str], list[dict]] = {}
    for f in findings:
        groups.setdefault(signature(f), []).append(f)
    return sorted(groups.items(), key=lambda item: -len(item[1]))


def _signature_section(findings: Sequence[dict]) -> list[str]:
    """The findings grouped by signature: one row per group with its count and IDs."""
    if not findings:
        return []
    lines = ["## Findings by signature", "",
             "Findings with the same failing checks, outlier, backend errors and mechanism (joint types and constraint "
             "kinds, after shrinking) are most likely one bug found several times.", "",
             "| findings | failing checks | outlier | backend errors | mechanism | IDs |", "|---|---|---|---|---|---|"]
    for (checks, outliers, errors, shape), members in group(findings):
        ids = ", ".join(f"`{f['id']}`" for f in members)
        lines.append(f"| {len(members)} | {checks} | {outliers} | {errors} | {shape} | {ids} |")
    return lines + [""]


def render_report(out: Path, command: str = "") -> str:
    """The campaign report (markdown): summary first, then each finding. Only the rows ``compute time``, ``wall
    time`` and ``throughput`` depend on the machine; the rest is the same for the same campaign."""
    campaign = load_campaign(out) or {"identity": {}, "runs": []}
    chunks, findings = load_chunks(out), load_findings(out)
    ident = campaign["identity"]
    total = {key: sum(r[key] for r in chunks) for key in ("examples", "shrink_calls", "states", "models")}
    seconds = sum(r["seconds"] for r in chunks)
    wall = sum(r["wall_seconds"] for r in campaign["runs"])
    worst = max(chunks, key=lambda r: r["worst_ratio"], default=None)
    where = f" (chunk {worst['chunk']}, `{worst['worst_key']}`)" if worst and worst["worst_key"] else ""
    margin = max(chunks, key=lambda r: r["worst_agreeing"], default=None)
    margin_where = f" (chunk {margin['chunk']}, `{margin['worst_agreeing_key']}`)" if margin else ""
    shards = sorted({r["shard"] for r in campaign["runs"]})
    interrupted = [r for r in chunks if r["interrupted"]]
    rate = f"{len(findings) / total['states']:.3g} per state" if total["states"] else "-"
    lines = ["# Fuzzing campaign", ""]
    if command:
        lines += [f"Command: `{command}`", ""]
    lines += [
        "## Summary", "",
        "| | |", "|---|---|",
        f"| seed | {ident.get('seed')} |",
        f"| backends | {', '.join(ident.get('backends', []))} |",
        f"| drawn | up to {ident.get('max_bodies')} bodies, up to {ident.get('max_states')} states per model, "
        f"constraints {({True: 'always', False: 'never', None: 'sometimes'})[ident.get('constraints')]}, joints "
        f"{'revolute, prismatic, spherical, free' if ident.get('group_joints', True) else 'revolute, prismatic'}, "
        "without joint limits (each coordinate over its whole range) |",
        "| checks | every quantity compared; "
        + ", ".join(name for name in ("charts", "frames", "conservation", "linearization") if ident.get(name)) + " |",
        f"| chunks | {len(chunks)} of {ident.get('chunk_examples')} examples (shards run: {', '.join(shards)}"
        + (f"; {len(interrupted)} interrupted" if interrupted else "") + ") |",
        f"| examples | {account(campaign, chunks).text()}; {total['shrink_calls']} more calls while shrinking |",
        f"| models | {total['models']} |",
        f"| states | {total['states']} |",
        f"| worst error/tolerance | {worst['worst_ratio'] if worst else 0.0:.3g}{where} |",
        f"| worst error/tolerance at states that passed | {margin['worst_agreeing'] if margin else 0.0:.3g}"
        f"{margin_where} |",
        f"| findings (disagreements and backend errors) | {len(findings)}"
        + (f", {len(group(findings))} signature(s) (below)" if findings else "") + " |",
        f"| false alarms | {len(findings)} findings on {total['states']} states ({rate}): with correct backends each "
        "finding is a false alarm of the tolerance policy unless replaying it shows a backend bug |",
        f"| compute time | {seconds:.1f} s in chunks |",
        f"| wall time | {wall:.1f} s |",
        f"| throughput | {total['examples'] / seconds if seconds else 0.0:.2f} examples/s, "
        f"{total['states'] / seconds if seconds else 0.0:.2f} states/s (per process); over the wall time "
        f"{total['states'] / wall if wall else 0.0:.2f} states/s and {total['models'] / wall if wall else 0.0:.2f} "
        "models/s |", ""]
    lines += _signature_section(findings)
    lines += ["## Findings", ""]
    if not findings:
        lines += ["None: every backend agreed at every state.", ""]
    for f in findings:
        lines += _finding_section(f, out, ident.get("plugins", []))
    return "\n".join(lines)


def summary(result: CampaignResult) -> str:
    """A few lines for the terminal: what ran (the examples generated of those asked, and why fewer), what was found
    (grouped by :func:`signature`, each group with its count, IDs and one replay command), the report."""
    chunks = result.chunks
    findings = result.findings
    examples = account(load_campaign(result.out) or {}, chunks).text()
    lines = [f"{len(chunks)} chunks, examples: {examples}; {sum(r['states'] for r in chunks)} states, "
             f"{len(findings)} findings" + (f" in {len(group(findings))} signature(s)" if findings else "")
             + (" (interrupted)" if result.interrupted else "")]
    plugins = campaign_plugins(result.out)
    for (checks, outliers, errors, shape), members in group(findings):
        what = "; ".join(part for part in (f"failing {checks}" if checks != "-" else "",
                                           f"outlier {outliers}" if outliers != "-" else "",
                                           f"errors in {errors}" if errors != "-" else "", shape) if part)
        lines.append(f"  {len(members)} x {what}: {', '.join(f['id'] for f in members)}")
        lines.append(f"    {replay_command(members[0]['id'], result.out, plugins)}")
    lines.append(f"report written to {result.out / 'report.md'}")
    return "\n".join(lines)


def write_report(out: Path, command: str = "") -> Path:
    path = out / "report.md"
    write_atomic(path, render_report(out, command))
    return path
