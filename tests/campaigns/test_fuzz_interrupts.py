"""Fuzzing campaigns lose nothing on any interruption (``crosscheck.campaigns.fuzz`` module doc, "Interruptions and crashes").

SIGINT or SIGTERM to the campaign's process alone, SIGKILL of it or of a worker, sent while chunks are shrinking a
failure, then the same command again, give the findings (same IDs, same files) and the report of an uninterrupted run.
A torn or corrupt chunk log, corrupt campaign and finding files, a second run on one directory and an ``--out`` that
cannot be a campaign directory are handled or refused clearly; files follow the umask.

The signal tests run the command line in a subprocess with a plugin backend written to a scratch directory:
Newton–Euler with a velocity-dependent error in its drift, so every chunk fails and shrinks. The plugin marks the
moment to strike: at its FAULTY_AT-th wrong answer in a process (a failure in hand, shrinking under way) it writes its
pid to FAULTY_MARKER, and from then on each wrong answer takes FAULTY_DELAY seconds more, so shrinking lasts many
seconds after the marker however loaded the machine is (an interrupt breaks into the delay, so it costs an
interrupted run nothing). The uninterrupted and resumed runs go at full speed (no marker, no delay).
"""

from __future__ import annotations

import fcntl
import json
import os
import re
import signal
import subprocess
import sys
import time
import types
from pathlib import Path

import pytest

from crosscheck import cli
from crosscheck.campaigns.fuzz import runs
from crosscheck.campaigns.fuzz import interrupts
from crosscheck.campaigns.fuzz import settings
from crosscheck.campaigns.fuzz import storage

PLUGIN = '''
import dataclasses
import os
import time
from pathlib import Path

import numpy as np

from formalisms import newton_euler
from formalisms.interface import Formalism

wrong = 0


def split(model, q, qd, u):
    global wrong
    s = newton_euler.split(model, q, qd, u)
    error = 0.1 * np.asarray(qd, dtype=float) ** 2
    if np.any(error) and os.environ.get("FAULTY_MARKER"):
        wrong += 1
        if wrong == int(os.environ["FAULTY_AT"]):
            Path(os.environ["FAULTY_MARKER"]).write_text(str(os.getpid()))
        if wrong >= int(os.environ["FAULTY_AT"]):
            time.sleep(float(os.environ["FAULTY_DELAY"]))
    return dataclasses.replace(s, drift=s.drift + error, total=s.total + error)


BUGGY = Formalism("buggy", "Newton-Euler with a velocity-dependent drift error", split)
'''

#: Two chunks of three examples, run by two workers at once: both chunks fail, shrink, and are interrupted. One-body
#: models and three quick backends keep a chunk near two seconds.
FUZZ = ["fuzz", "--plugin", "faulty_backend:BUGGY", "--formalism", "newton_euler", "--formalism", "pinocchio",
        "--formalism", "buggy", "--examples", "6", "--chunk-examples", "3", "--seed", "2", "--max-bodies", "1",
        "--max-states", "2", "--constraints", "never", "--no-conservation", "--workers", "2"]
#: Report rows that depend on the machine or on the runs (an interrupted run adds one).
TIMING = re.compile(r"^\| (compute time|wall time|throughput) \|.*$", re.M)
#: Seconds any one step of a subprocess campaign may take before the test gives up on it.
PATIENCE = 120
#: Seconds a campaign hit by a signal may take to end, every process it started gone (its stdout closed). It takes
#: under a second (five at most, ``fuzz.INTERRUPT_GRACE``, if a chunk were stuck); a worker left to finish its chunk
#: would take a minute (the plugin's delay).
ENDS = 15


@pytest.fixture(scope="module")
def env(tmp_path_factory) -> dict:
    plugins = tmp_path_factory.mktemp("plugin")
    (plugins / "faulty_backend.py").write_text(PLUGIN)
    path = os.pathsep.join([str(plugins), os.environ.get("PYTHONPATH", "")]).rstrip(os.pathsep)
    clean = {k: v for k, v in os.environ.items() if not k.startswith("FAULTY_")}
    # the plugin runs in its worker (not in a child of its own, crosscheck.isolation), so the pid it writes is the
    # worker's: these tests strike the campaign's processes, not a plugin's
    return {**clean, "PYTHONPATH": path, "CROSSCHECK_ISOLATE": "0"}


def run(env: dict, out: Path) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, "-m", "crosscheck.cli", *FUZZ, "--out", str(out)], env=env,
                          capture_output=True, text=True, timeout=PATIENCE)


@pytest.fixture(scope="module")
def uninterrupted(env, tmp_path_factory) -> Path:
    out = tmp_path_factory.mktemp("fuzz") / "uninterrupted"
    done = run(env, out)
    assert done.returncode == 1, done.stderr
    return out


def findings(out: Path) -> dict[str, dict]:
    return {p.stem: json.loads(p.read_text()) for p in (out / "findings").glob("*.json")}


def records(out: Path) -> list[dict]:
    return [{k: v for k, v in r.items() if k != "seconds"} for r in storage.load_chunks(out)]


def report(out: Path) -> str:
    return TIMING.sub("", (out / "report.md").read_text()).replace(str(out), "DIR")


def wait_for(condition, what: str, seconds: float = PATIENCE) -> None:
    deadline = time.monotonic() + seconds
    while not condition():
        assert time.monotonic() < deadline, f"gave up waiting for {what}"
        time.sleep(0.02)


def interrupted_run(env: dict, out: Path, signum: int, target: str, marker: Path
                    ) -> tuple[subprocess.CompletedProcess, int, float]:
    """The campaign in ``out``, hit by ``signum`` (at its parent process alone, or at the worker that wrote the
    marker) once a chunk is shrinking; (the ended process, the worker's pid, the seconds from the signal until the
    campaign and the processes it started had all ended)."""
    slowed = {**env, "FAULTY_MARKER": str(marker), "FAULTY_AT": "5", "FAULTY_DELAY": "1"}
    proc = subprocess.Popen([sys.executable, "-m", "crosscheck.cli", *FUZZ, "--out", str(out)], env=slowed,
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    try:
        wait_for(lambda: proc.poll() is not None or marker.exists() and marker.read_text(), "a chunk to shrink")
        assert proc.poll() is None, f"the campaign ended before it shrank anything: {proc.communicate()}"
        worker = int(marker.read_text())
        os.kill(proc.pid if target == "parent" else worker, signum)
        sent = time.monotonic()
        stdout, stderr = proc.communicate(timeout=PATIENCE)   # until every process holding its pipes has ended
        ended = time.monotonic() - sent
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.communicate()
    return subprocess.CompletedProcess(proc.args, proc.returncode, stdout, stderr), worker, ended


@pytest.mark.parametrize("signame, target", [("SIGINT", "parent"), ("SIGTERM", "parent"), ("SIGKILL", "parent"),
                                             ("SIGKILL", "worker")])
def test_a_signal_mid_shrink_then_resume_gives_the_uninterrupted_findings(signame, target, env, uninterrupted,
                                                                          tmp_path):
    out = tmp_path / "campaign"
    proc, worker, ended = interrupted_run(env, out, getattr(signal, signame), target, tmp_path / "marker")
    assert ended < ENDS, f"the campaign's processes took {ended:.1f} s to end after {signame}"
    if signame != "SIGKILL":
        # an orderly stop: the workers were told, the failure in hand saved and logged, the report written
        assert proc.returncode == 130, proc.stderr
        assert "(interrupted)" in proc.stdout
        assert "Traceback" not in proc.stderr and proc.stderr.splitlines()[-1].startswith("crosscheck: interrupted ")
        interrupted = [r for r in storage.load_chunks(out) if r["interrupted"]]
        held = {i for r in interrupted for i in r["findings"]}
        assert held and held <= set(findings(out)), "the failure being shrunk was lost"
        assert all(i in (out / "report.md").read_text() for i in held)
        assert json.loads((out / "campaign.json").read_text())["runs"][-1]["interrupted"]
    elif target == "worker":
        assert proc.returncode == 2 and f"pid {worker}) died" in proc.stderr, proc.stderr
        assert (out / "report.md").exists()
    else:
        assert proc.returncode == -signal.SIGKILL
    resumed = run(env, out)
    assert resumed.returncode == 1, resumed.stderr
    assert findings(out) == findings(uninterrupted)    # the same IDs, each saved the same
    assert records(out) == records(uninterrupted)
    assert report(out) == report(uninterrupted)


# ------------------------------------------------------------------------------------------------ files, lock, --out

#: A campaign of two one-example chunks of a one-body model: a fraction of a second, in this process.
TINY = dict(seed=0, examples=2, chunk_examples=1, max_bodies=1, max_states=1, workers=0)


def tiny(out: Path) -> storage.CampaignResult:
    return runs.run_campaign(settings.config(**TINY, out=str(out)))


def test_a_torn_last_log_line_is_skipped_and_dropped_at_the_next_append(tmp_path):
    whole = tiny(tmp_path / "whole")
    log = tmp_path / "whole" / "chunks.jsonl"
    lines = log.read_text().splitlines(keepends=True)
    log.write_text(lines[0] + lines[1][:len(lines[1]) // 2])     # a crash while chunk 1 was logged
    assert [r["chunk"] for r in storage.load_chunks(log.parent)] == [0]
    resumed = tiny(tmp_path / "whole")                            # chunk 1 runs again
    assert [json.loads(line)["chunk"] for line in log.read_text().splitlines()] == [0, 1]
    assert [{k: v for k, v in r.items() if k != "seconds"} for r in resumed.chunks] \
        == [{k: v for k, v in r.items() if k != "seconds"} for r in whole.chunks]


def test_a_whole_last_record_without_its_newline_is_kept(tmp_path):
    tiny(tmp_path / "c")
    log = tmp_path / "c" / "chunks.jsonl"
    log.write_text(log.read_text().splitlines()[0])              # chunk 0's record, its newline lost
    tiny(tmp_path / "c")
    assert [json.loads(line)["chunk"] for line in log.read_text().splitlines()] == [0, 1]


def test_a_corrupt_line_inside_the_log_is_an_error_naming_it(tmp_path):
    tiny(tmp_path / "c")
    log = tmp_path / "c" / "chunks.jsonl"
    lines = log.read_text().splitlines(keepends=True)
    log.write_text(lines[0][:20] + "\n" + lines[1])
    with pytest.raises(settings.FuzzError, match=rf"{re.escape(str(log))} line 1 is not a chunk record"):
        tiny(tmp_path / "c")


@pytest.mark.parametrize("text, reason", [("{not json", "Expecting"), ('{"identity": {}}', "no runs"),
                                          ("[1, 2]", "not an object")])
def test_a_corrupt_campaign_file_is_an_error_naming_it(text, reason, tmp_path, capsys):
    out = tmp_path / "c"
    out.mkdir()
    (out / "campaign.json").write_text(text)
    argv = ["fuzz", "--examples", "1", "--max-bodies", "1", "--workers", "0", "--out", str(out)]
    assert cli.main(argv) == 2
    err = capsys.readouterr().err
    assert f"{out / 'campaign.json'} is not a campaign file: " in err and reason in err
    assert "remove it or give another --out" in err


def test_a_corrupt_finding_file_is_an_error_naming_it(tmp_path, capsys):
    tiny(tmp_path / "c")
    bad = tmp_path / "c" / "findings" / "0123456789ab.json"
    bad.parent.mkdir(exist_ok=True)
    bad.write_text('{"id": "0123456789ab"')
    with pytest.raises(settings.FuzzError, match=rf"{re.escape(str(bad))} is not a finding file"):
        tiny(tmp_path / "c")
    assert cli.main(["replay", "0123", "--dir", str(tmp_path / "c")]) == 2
    assert f"{bad} is not a finding file" in capsys.readouterr().err


def test_one_run_at_a_time_in_a_campaign_directory(tmp_path):
    out = tmp_path / "c"
    tiny(out)                                                    # a run releases its lock when it ends
    with open(out / ".lock", "r+") as other:                     # another run holds it
        fcntl.flock(other, fcntl.LOCK_EX | fcntl.LOCK_NB)
        other.write("4242\n")
        other.flush()
        for attempt in (lambda: tiny(out), lambda: runs.merge([out], out)):
            with pytest.raises(settings.FuzzError, match=rf"campaign directory {re.escape(str(out))} is in use by "
                                                     r"another run \(pid 4242\); wait for it or give another --out"):
                attempt()
    assert len(tiny(out).chunks) == 2


def test_files_follow_the_umask(tmp_path):
    before = os.umask(0o027)
    try:
        result = tiny(tmp_path / "c")
        storage.save_finding(result.out, {"id": "0123456789ab", "campaign": {"chunk": 0}})
    finally:
        os.umask(before)
    for name in ("campaign.json", "chunks.jsonl", "report.md", ".lock", "findings/0123456789ab.json"):
        assert (result.out / name).stat().st_mode & 0o777 == 0o640, name


@pytest.mark.parametrize("command", ["fuzz", "merge"])
def test_an_out_that_cannot_be_a_campaign_directory_is_refused(command, tmp_path, capsys):
    shard = tiny(tmp_path / "shard").out
    afile = tmp_path / "afile"
    afile.write_text("mine\n")
    argv = {"fuzz": ["fuzz", "--examples", "1", "--max-bodies", "1", "--workers", "0", "--out"],
            "merge": ["merge", str(shard), "--out"]}[command]
    assert cli.main(argv + [str(afile)]) == 2
    assert f"--out {afile} is a file, not a directory" in capsys.readouterr().err
    assert afile.read_text() == "mine\n"
    assert cli.main(argv + [str(afile / "sub")]) == 2
    assert f"cannot create campaign directory {afile / 'sub'}: " in capsys.readouterr().err


def test_an_interrupt_that_lands_where_it_cannot_raise_is_not_reported(monkeypatch):
    """A KeyboardInterrupt from the signal handler inside a garbage-collector callback is "unraisable": Python would
    print it with a traceback. During a chunk's run, once the interrupt is noted, that report is dropped (the next
    example stops the chunk); any other unraisable exception is still reported."""
    reported = []
    monkeypatch.setattr(sys, "unraisablehook", reported.append)
    monkeypatch.setattr(interrupts.INTERRUPTS, "requested", True)
    interrupt = types.SimpleNamespace(exc_type=KeyboardInterrupt)
    other = types.SimpleNamespace(exc_type=ValueError)
    with interrupts.INTERRUPTS.during("test"):
        sys.unraisablehook(interrupt)
        sys.unraisablehook(other)
    assert reported == [other]
    assert sys.unraisablehook == reported.append
