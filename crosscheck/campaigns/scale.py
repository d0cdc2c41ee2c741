"""Scale (``crosscheck bench --scale``): what large robots and long campaigns cost, each as a whole process.

* **gate**: ``crosscheck gate`` with every check at 100 states on the robots of the speed targets (the g1 humanoid, 29
  joints on a free base; tiago, 48 joints; pr2; simple_humanoid on a free base; baxter) and solo12, each from an empty
  cache, and on the built-in cases cold and warm (the same cache again);
* **Euler–Lagrange preparation** against the number of joints: its first ``split`` minus a steady one, cold (empty
  cache: the symbolic derivation) and cached, on planar chains of 2 to 48 links
  (:func:`crosscheck.campaigns.bench.preparation`);
* **fuzz**: states and models per second of a campaign with every check on, on 2 workers (``crosscheck fuzz``), as
  a whole process.

Each run is a child process measured by the kernel (``os.wait4``, whose figures on Linux cover the child and the
descendants it waited for): wall seconds, CPU seconds (user + system) and the peak resident memory of the largest
single process. A gate on one model evaluates it in one process; the built-in cases run in parallel workers, each
holding up to that peak. :func:`render` writes the markdown report.
"""

from __future__ import annotations

import json
import os
import subprocess
import sys
import tempfile
import time
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import Sequence

from cases.factories import robot_data_path
from crosscheck.campaigns import bench
from crosscheck.engine import progress

#: The robots of the gate's scale measurement: label, example-robot-data path, base.
ROBOTS = (("g1 humanoid (29 joints, free base)", "g1_description/urdf/g1_29dof_rev_1_0.urdf", "free"),
          ("tiago (48 joints)", "tiago_description/robots/tiago.urdf", "fixed"),
          ("pr2", "pr2_description/urdf/pr2.urdf", "fixed"),
          ("simple_humanoid (free base)", "simple_humanoid_description/urdf/simple_humanoid.urdf", "free"),
          ("baxter", "baxter_description/urdf/baxter.urdf", "fixed"),
          ("solo12 (12 joints, free base)", "solo_description/robots/solo12.urdf", "free"))
_ROBOT_DATA = "cmeel.prefix/share/example-robot-data/robots"


@dataclass(frozen=True)
class ScalePlan:
    robots: tuple[tuple[str, str, str], ...]
    samples: int                 # states per gate case
    links: tuple[int, ...]       # chain lengths of the Euler–Lagrange preparation
    fuzz_examples: int
    builtin_gate: bool


FULL = ScalePlan(ROBOTS, 100, (2, 4, 8, 16, 24, 32, 48), 100, True)
QUICK = ScalePlan((), 3, (2, 4), 4, False)


@dataclass
class Run:
    """One child process: what ran, its exit status, wall and CPU seconds, peak resident memory in MiB."""

    what: str
    command: list[str]
    status: int
    wall_s: float
    cpu_s: float
    peak_mib: float
    detail: dict = field(default_factory=dict)


@dataclass
class ScaleResults:
    plan: str
    machine: dict
    gates: list[Run] = field(default_factory=list)
    preparations: list[bench.Preparation] = field(default_factory=list)
    fuzz: list[Run] = field(default_factory=list)

    def to_json(self) -> str:
        return json.dumps(asdict(self), indent=1, sort_keys=True)


#: The small process that starts each measured command and reads its rusage (:func:`measured`): a process forked from
#: a large one inherits its peak resident memory in ``ru_maxrss`` (Linux keeps the high-water mark across fork and
#: exec), so the command is forked from this one, which has imported nothing, and its figures are those of the
#: command and its descendants alone. It writes ``[status, CPU seconds, peak KiB]`` to the file named first.
_LAUNCHER = ("import json, os, subprocess, sys; child = subprocess.Popen(sys.argv[2:]); "
             "_, status, usage = os.wait4(child.pid, 0); code = os.waitstatus_to_exitcode(status); "
             "open(sys.argv[1], 'w').write(json.dumps([code, usage.ru_utime + usage.ru_stime, usage.ru_maxrss]))")


def measured(what: str, arguments: Sequence[str], cache: str) -> Run:
    """``crosscheck ARGUMENTS`` in a child process with the Euler–Lagrange and geometric caches in ``cache``, measured
    by the kernel (module doc) through :data:`_LAUNCHER`. Its output is kept only for a failure (the last lines, in
    ``detail``)."""
    command = [sys.executable, "-c", "from crosscheck.cli import main; raise SystemExit(main())", *arguments]
    env = {**os.environ, "CROSSCHECK_CACHE": cache}
    with tempfile.TemporaryFile() as log, tempfile.TemporaryDirectory() as tmp:
        figures = os.path.join(tmp, "rusage.json")
        start = time.perf_counter()
        subprocess.run([sys.executable, "-S", "-c", _LAUNCHER, figures, *command], env=env, stdout=log,
                       stderr=subprocess.STDOUT)
        wall = time.perf_counter() - start
        status, cpu, peak_kib = json.loads(Path(figures).read_text())
        log.seek(0)
        tail = log.read().decode(errors="replace").strip().splitlines()[-5:]
    run = Run(what, list(arguments), status, wall, cpu, peak_kib / 1024)
    if status not in (0, 1):  # 1: the gate or campaign found something, still a measurement
        run.detail["output"] = tail
    return run


def robot_path(relative: str) -> str:
    return str(robot_data_path(f"{_ROBOT_DATA}/{relative}", relative.split("/")[-1]))


def gate_runs(plan: ScalePlan, display: progress.Display) -> list[Run]:
    """The default gate on each robot (an empty cache each), and on the built-in cases cold then warm."""
    runs = []
    with tempfile.TemporaryDirectory(prefix="crosscheck-scale-") as tmp:
        for label, relative, base in plan.robots:
            display.doing(f"gate on {label}")
            cache = tempfile.mkdtemp(dir=tmp)
            runs.append(measured(f"gate {label}", ["gate", "--quiet", "--model", robot_path(relative), "--base", base,
                                                   "--samples", str(plan.samples), "--report",
                                                   os.path.join(tmp, "gate.md")], cache))
            display.advance()
        if plan.builtin_gate:
            cache = tempfile.mkdtemp(dir=tmp)
            for state in ("cold", "warm"):
                display.doing(f"gate on the built-in cases, {state}")
                runs.append(measured(f"gate built-in cases, {state}", ["gate", "--quiet", "--samples",
                                                                        str(plan.samples), "--report",
                                                                        os.path.join(tmp, "gate.md")], cache))
                display.advance()
    return runs


def fuzz_run(plan: ScalePlan, display: progress.Display) -> Run:
    """A campaign of ``plan.fuzz_examples`` examples with every check on, on 2 workers; its states and models from the
    chunk log."""
    display.doing(f"fuzz campaign of {plan.fuzz_examples} examples")
    with tempfile.TemporaryDirectory(prefix="crosscheck-scale-") as tmp:
        out = os.path.join(tmp, "campaign")
        run = measured("fuzz", ["fuzz", "--quiet", "--examples", str(plan.fuzz_examples), "--workers", "2",
                                "--out", out], tempfile.mkdtemp(dir=tmp))
        chunks = [json.loads(line) for line in Path(out, "chunks.jsonl").read_text().splitlines() if line.strip()]
    run.detail.update(examples=sum(c["examples"] for c in chunks), states=sum(c["states"] for c in chunks),
                      models=sum(c["models"] for c in chunks), chunk_s=sum(c["seconds"] for c in chunks))
    display.advance()
    return run


def steps(plan: ScalePlan) -> int:
    return len(plan.robots) + 2 * plan.builtin_gate + len(plan.links) + 1


def run(plan: ScalePlan, display: progress.Display | None = None) -> ScaleResults:
    display = display or progress.silent()
    results = ScaleResults("quick" if plan is QUICK else "full", bench.machine())
    results.gates = gate_runs(plan, display)
    for n in plan.links:
        display.doing(f"preparing euler_lagrange on a chain of {n} links in fresh processes")
        results.preparations.append(bench.preparation("euler_lagrange", bench.chain_scene(n)))
        display.advance()
    results.fuzz = [fuzz_run(plan, display)]
    return results


def render(results: ScaleResults) -> str:
    """The markdown report of :func:`run`."""
    lines = ["# Scale: large robots and long campaigns", "",
             f"Plan `{results.plan}`; machine: " + ", ".join(f"{k} {v}" for k, v in results.machine.items()) + ".",
             "Each figure is one run of a whole process (`crosscheck.campaigns.scale`): wall and CPU seconds, peak resident "
             "memory of its largest process.", "", "## The default gate", "",
             "| gate on | exit | wall s | CPU s | peak MiB |", "|---|---:|---:|---:|---:|"]
    lines += [f"| {r.what.removeprefix('gate ')} | {r.status} | {r.wall_s:.1f} | {r.cpu_s:.1f} | {r.peak_mib:.0f} |"
              for r in results.gates]
    lines += ["", "## Euler–Lagrange preparation against the number of joints", "",
              "First `split` of a fresh process minus a steady one: cold (empty cache: the symbolic derivation) and "
              "cached (the code the cold run wrote).", "", "| chain | cold s | cached s |", "|---|---:|---:|"]
    lines += [f"| {p.scene} | {p.cold_s:.2f} | {p.cached_s:.3f} |" for p in results.preparations]
    lines += ["", "## Fuzz throughput", "",
              "States and models per second of the whole process (2 workers, start-up and the report included), and "
              "the chunks' own seconds summed over the workers; every drawn model is new, so its symbolic derivations "
              "and casadi Functions are built for it, once for all its states.", "",
              "| examples | models | states | exit | wall s | CPU s | states/s | models/s | in chunks: s | peak MiB |",
              "|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|"]
    for r in results.fuzz:
        d = r.detail
        lines.append(f"| {d['examples']} | {d['models']} | {d['states']} | {r.status} | {r.wall_s:.1f} | "
                     f"{r.cpu_s:.1f} | {d['states'] / r.wall_s:.1f} | {d['models'] / r.wall_s:.2f} | "
                     f"{d['chunk_s']:.1f} | {r.peak_mib:.0f} |")
    failed = [r for r in results.gates + results.fuzz if "output" in r.detail]
    for r in failed:
        lines += ["", f"`{r.what}` ended with status {r.status}:", "", "```", *r.detail["output"], "```"]
    return "\n".join(lines) + "\n"


def write(results: ScaleResults, out: Path) -> Path:
    """``out/scale.md`` and ``out/scale.json``; the markdown's path."""
    out.mkdir(parents=True, exist_ok=True)
    (out / "scale.json").write_text(results.to_json())
    path = out / "scale.md"
    path.write_text(render(results))
    return path
