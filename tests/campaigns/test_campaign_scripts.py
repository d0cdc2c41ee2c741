"""The files that run a campaign on many machines (docs/campaigns.md, "on many machines"): the GitHub Actions workflow
``.github/workflows/fuzz-campaign.yml`` and the Slurm job scripts ``examples/slurm/fuzz.sh`` (the array of shards)
and ``examples/slurm/merge.sh``.

Their own shell scripts run here, as written, for two shards of one example each and then their merge; the merged
report must be that of the unsharded run with the same seed (``tests/campaigns/test_fuzz.py`` proves the same of
``crosscheck.campaigns.fuzz.runs.merge`` itself). ``crosscheck`` is this checkout's command line, put on PATH as the workflow's install step
and the Slurm scripts' virtual environment put it. The shards run in-process (WORKERS=0; worker processes give the
same chunks, ``test_fuzz.py``), and OPTIONS keeps the drawn models small. The workflow is read without a YAML
library (none is a dependency): its steps are written ``- name: NAME`` followed by ``env:``, ``with:`` and
``run: |`` blocks, and the ``${{ ... }}`` expressions of a step's env are looked up in a context the test gives (an
expression it does not know fails the test)."""

from __future__ import annotations

import json
import os
import re
import shutil
import subprocess
import sys
import textwrap
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[2]
WORKFLOW = ROOT / ".github" / "workflows" / "fuzz-campaign.yml"
SLURM_FUZZ = ROOT / "examples" / "slurm" / "fuzz.sh"
SLURM_MERGE = ROOT / "examples" / "slurm" / "merge.sh"

SEED = 5
#: Two examples in chunks of one: shard i/2 runs chunk i. The same options for every run compared.
EXAMPLES = "2"
OPTIONS = "--chunk-examples 1 --max-bodies 2 --max-states 2"
#: Seconds any one script may take before the test gives up on it.
PATIENCE = 120
#: Lines of a report that differ between a merge and a run, or from run to run: the command, the machine's timings,
#: the shards run; and the campaign directory, in the replay commands.
VARYING = re.compile(r"^(Command: .*|\| (compute time|wall time|throughput) \|.*)$|\(shards run: [^)]*\)", re.M)


def report(out: Path) -> str:
    return VARYING.sub("", (out / "report.md").read_text()).replace(str(out), "DIR")


def chunks(out: Path) -> list[dict]:
    """The chunk log without the chunks' times."""
    lines = (out / "chunks.jsonl").read_text().splitlines()
    return sorted(({k: v for k, v in json.loads(line).items() if k != "seconds"} for line in lines),
                  key=lambda r: r["chunk"])


def findings(out: Path) -> list[str]:
    return sorted(p.name for p in (out / "findings").glob("*.json"))


def same_campaign(merged: Path, whole: Path) -> None:
    assert findings(merged) == findings(whole)
    assert chunks(merged) == chunks(whole) and [r["chunk"] for r in chunks(whole)] == [0, 1]
    assert report(merged) == report(whole)


@pytest.fixture(scope="module")
def venv(tmp_path_factory) -> Path:
    """A stand-in for the virtual environment: ``bin/crosscheck`` runs this checkout's command line, and
    ``bin/activate`` puts ``bin`` first on PATH."""
    root = tmp_path_factory.mktemp("venv")
    (root / "bin").mkdir()
    path = os.pathsep.join([str(ROOT), os.environ.get("PYTHONPATH", "")]).rstrip(os.pathsep)
    script = root / "bin" / "crosscheck"
    script.write_text(f'#!/bin/sh\nPYTHONPATH="{path}" exec "{sys.executable}" -m crosscheck.cli "$@"\n')
    script.chmod(0o755)
    (root / "bin" / "activate").write_text(f'PATH="{root / "bin"}:$PATH"\n')
    return root


@pytest.fixture(scope="module")
def whole(venv, tmp_path_factory) -> Path:
    """The unsharded campaign, run by the command line."""
    out = tmp_path_factory.mktemp("whole") / "campaign"
    done = subprocess.run([str(venv / "bin" / "crosscheck"), "fuzz", "--seed", str(SEED), "--examples", EXAMPLES,
                           *OPTIONS.split(), "--workers", "0", "--out", str(out)],
                          capture_output=True, text=True, timeout=PATIENCE)
    assert done.returncode in (0, 1), done.stderr
    return out


def bash(script: str | Path, cwd: Path, env: dict, args: tuple[str, ...] = ()) -> subprocess.Popen:
    """``script`` (a file, or the text of a workflow step) run as GitHub Actions runs ``shell: bash``."""
    source = ["-c", script] if isinstance(script, str) else [str(script)]
    inherited = {k: v for k, v in os.environ.items() if not k.startswith("SLURM_")}   # the test may run in a job
    return subprocess.Popen(["bash", "--noprofile", "--norc", "-eo", "pipefail", *source, *args], cwd=cwd,
                            env={**inherited, **env}, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)


def finish(proc: subprocess.Popen) -> tuple[int, str]:
    stdout, stderr = proc.communicate(timeout=PATIENCE)
    return proc.returncode, stdout + stderr


# ------------------------------------------------------------------------------------------------ the workflow


def workflow_step(name: str) -> dict:
    """The step ``- name: NAME`` of the workflow: its ``env`` and ``with`` mappings and its ``run`` script."""
    lines = WORKFLOW.read_text().splitlines()
    start = [line.strip() for line in lines].index(f"- name: {name}")
    indent = len(lines[start]) - len(lines[start].lstrip()) + 2   # the step's keys
    step, key = {"env": {}, "with": {}, "run": []}, None
    for line in lines[start + 1:]:
        depth = len(line) - len(line.lstrip())
        if line.strip() and depth < indent:
            break
        if line.strip() and depth == indent:
            key = line.strip().split(":")[0]
        elif key in ("env", "with") and line.strip():
            field, _, value = line.strip().partition(":")
            step[key][field] = value.split(" #")[0].strip()
        elif key == "run":
            step["run"].append(line[indent + 2:])
    step["run"] = textwrap.dedent("\n".join(step["run"]))
    return step


def step_env(step: dict, context: dict[str, str]) -> dict[str, str]:
    """The step's environment, its ``${{ expression }}`` values looked up in ``context``."""
    return {name: re.sub(r"\$\{\{ (\S+) \}\}", lambda m: context[m.group(1)], value)
            for name, value in step["env"].items()}


def plan(tmp_path: Path, inputs: dict[str, str]) -> tuple[int, str, dict[str, str]]:
    """The plan job's script, dispatched with ``inputs`` (a scheduled run has none): exit code, output and the job's
    outputs."""
    out = tmp_path / "github_output"
    out.write_text("")
    context = {f"inputs.{k}": inputs.get(k, "") for k in ("seed", "shards", "minutes", "examples")}
    env = {**step_env(workflow_step("plan"), {**context, "github.run_number": "41"}), "GITHUB_OUTPUT": str(out)}
    code, output = finish(bash(workflow_step("plan")["run"], tmp_path, env))
    return code, output, dict(line.split("=", 1) for line in out.read_text().splitlines())


def test_the_workflow_plans_the_shards_and_refuses_bad_inputs(tmp_path):
    assert plan(tmp_path, {})[2] == {"seed": "41", "shards": "4", "matrix": "[0,1,2,3]", "minutes": "30",
                                     "examples": "", "timeout": "60"}
    assert plan(tmp_path, {"seed": "0", "shards": "1", "examples": "500"})[2] == {
        "seed": "0", "shards": "1", "matrix": "[0]", "minutes": "30", "examples": "500", "timeout": "360"}
    for bad, message in [({"shards": "0"}, "shards: 1 to 256"), ({"seed": "-1"}, "seed: a non-negative integer"),
                         ({"minutes": "301"}, "minutes: 1 to 300"), ({"examples": "x"}, "examples: a positive")]:
        code, output, outputs = plan(tmp_path, bad)
        assert code == 1 and f"::error::{message}" in output and not outputs


def test_the_workflows_shards_merged_are_the_unsharded_campaign(venv, whole, tmp_path):
    code, output, planned = plan(tmp_path, {"seed": str(SEED), "shards": "2", "examples": EXAMPLES})
    assert code == 0, output
    context = {**{f"needs.plan.outputs.{k}": v for k, v in planned.items()}, "inputs.options": OPTIONS}
    shard = workflow_step("shard")
    runners = {i: tmp_path / f"runner-{i}" for i in json.loads(planned["matrix"])}
    procs = []
    for i, runner in runners.items():    # one machine each: the install step puts crosscheck on PATH
        runner.mkdir()
        env = {**step_env(shard, {**context, "matrix.shard": str(i)}), "WORKERS": "0",
               "PATH": f"{venv / 'bin'}{os.pathsep}{os.environ['PATH']}"}
        procs.append(bash(shard["run"], runner, env))
    for proc in procs:
        code, output = finish(proc)
        assert code == 0, output
    # each shard uploads its shards/ directory; the merge job downloads them all into one shards/ directory
    upload, download = workflow_step("upload the shard"), workflow_step("download the shards")
    assert upload["with"]["path"] == "shards/" and download["with"]["path"] == "shards"
    assert download["with"]["merge-multiple"] == "true"
    machine = tmp_path / "merge"
    for runner in runners.values():
        shutil.copytree(runner / "shards", machine / "shards", dirs_exist_ok=True)
    code, output = finish(bash(workflow_step("merge")["run"], machine,
                               {"PATH": f"{venv / 'bin'}{os.pathsep}{os.environ['PATH']}"}))
    assert code == (1 if findings(whole) else 0), output
    same_campaign(machine / "campaign", whole)


# ------------------------------------------------------------------------------------------------ Slurm


def slurm_env(venv: Path, campaign: Path) -> dict[str, str]:
    return {"SEED": str(SEED), "SHARDS": "2", "EXAMPLES": EXAMPLES, "OPTIONS": OPTIONS, "CAMPAIGN": str(campaign),
            "VENV": str(venv), "WORKERS": "0"}


def test_the_slurm_array_runs_the_shards_and_the_merge_job_merges_them(venv, whole, tmp_path):
    env = slurm_env(venv, tmp_path / "campaign")
    procs = [bash(SLURM_FUZZ, tmp_path, {**env, "SLURM_ARRAY_TASK_ID": str(i)}) for i in range(2)]
    for proc in procs:
        code, output = finish(proc)
        assert code == 0, output
    code, output = finish(bash(SLURM_MERGE, tmp_path, env))
    assert code == (1 if findings(whole) else 0), output
    same_campaign(tmp_path / "campaign" / "merged", whole)


def test_the_slurm_scripts_refuse_an_array_that_does_not_match_the_shards(venv, tmp_path):
    header = re.search(r"^#SBATCH --array=0-(\d+)$", SLURM_FUZZ.read_text(), re.M)
    defaults = [re.search(r"SHARDS=\$\{SHARDS:-(\d+)\}", p.read_text()) for p in (SLURM_FUZZ, SLURM_MERGE)]
    assert header and all(d and int(d.group(1)) == int(header.group(1)) + 1 for d in defaults)
    env = slurm_env(venv, tmp_path / "campaign")
    code, output = finish(bash(SLURM_FUZZ, tmp_path, {**env, "SLURM_ARRAY_TASK_ID": "2"}))
    assert code == 2 and "task 2 of an array beyond SHARDS=2: give --array=0-1" in output
    code, output = finish(bash(SLURM_FUZZ, tmp_path, env))
    assert code != 0 and "not a task of a job array" in output
    (tmp_path / "campaign" / "shard-0").mkdir(parents=True)
    code, output = finish(bash(SLURM_MERGE, tmp_path, env))
    assert code == 2 and "no " + str(tmp_path / "campaign" / "shard-1") in output
