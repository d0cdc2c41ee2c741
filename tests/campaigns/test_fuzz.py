"""Fuzzing campaigns (crosscheck.campaigns.fuzz and the fuzz / replay / merge commands): reproducible, shardable, interruptible,
and able to find, shrink, save and replay an injected fault."""

from __future__ import annotations

import json
import re
import shutil
from pathlib import Path

import pytest

from cases.serialize import model_from_dict
from crosscheck import cli
from crosscheck.campaigns.fuzz import runs
from crosscheck.campaigns.fuzz import chunk
from crosscheck.campaigns.fuzz import settings
from crosscheck.campaigns.fuzz import storage
from crosscheck.reports import fuzz_report

#: A small campaign: two chunks of three examples, models of at most two bodies, two states each.
SMALL = dict(seed=0, examples=6, chunk_examples=3, max_bodies=2, max_states=2, workers=0)

#: Report rows that depend on the machine (and the run's directory, in the replay commands).
TIMING = re.compile(r"^\| (compute time|wall time|throughput) \|.*$", re.M)


def campaign(out: Path, **kwargs) -> storage.CampaignResult:
    return runs.run_campaign(settings.config(**{**SMALL, "out": str(out), **kwargs}))


def stable(result: storage.CampaignResult) -> str:
    """The report without its timing rows and with the campaign directory replaced."""
    return TIMING.sub("", (result.out / "report.md").read_text()).replace(str(result.out), "DIR")


def records(result: storage.CampaignResult) -> list[dict]:
    return [{k: v for k, v in r.items() if k != "seconds"} for r in result.chunks]


@pytest.fixture(scope="module")
def reference_run(tmp_path_factory):
    return campaign(tmp_path_factory.mktemp("fuzz") / "whole")


def test_campaign_logs_every_chunk_and_writes_a_report(reference_run):
    assert [r["chunk"] for r in reference_run.chunks] == [0, 1]
    assert all(r["examples"] + r["shrink_calls"] >= 1 and r["states"] >= 1 for r in reference_run.chunks)
    report = (reference_run.out / "report.md").read_text()
    summary, _, findings = report.partition("## Findings")
    assert "## Summary" in summary and "| examples |" in summary and "| throughput |" in summary
    for f in reference_run.findings:
        assert f"crosscheck replay {f['id']} --dir {reference_run.out}" in findings
        assert (reference_run.out / "findings" / f"{f['id']}.json").exists()


def test_same_seed_same_findings_and_report(reference_run, tmp_path):
    again = campaign(tmp_path / "again")
    assert [f["id"] for f in again.findings] == [f["id"] for f in reference_run.findings]
    assert records(again) == records(reference_run)
    assert stable(again) == stable(reference_run)


def test_shards_merged_equal_the_unsharded_run(reference_run, tmp_path):
    shards = [campaign(tmp_path / f"shard{i}", shard=(i, 2)) for i in range(2)]
    assert [[r["chunk"] for r in s.chunks] for s in shards] == [[0], [1]]
    merged = runs.merge([s.out for s in shards], tmp_path / "merged")
    assert [f["id"] for f in merged.findings] == [f["id"] for f in reference_run.findings]
    assert records(merged) == records(reference_run)
    strip = lambda text: re.sub(r"\(shards run: [^)]*\)", "", text)  # noqa: E731
    assert strip(stable(merged)) == strip(stable(reference_run))


def test_cli_fuzz_in_a_worker_process_matches_the_in_process_run(reference_run, tmp_path, capsys):
    out = tmp_path / "cli"
    code = cli.main(["fuzz", "--examples", "6", "--chunk-examples", "3", "--seed", "0", "--max-bodies", "2",
                     "--max-states", "2", "--workers", "1", "--out", str(out)])
    assert code == (1 if reference_run.findings else 0)
    assert sorted(p.name for p in (out / "findings").glob("*.json")) == sorted(
        p.name for p in (reference_run.out / "findings").glob("*.json"))
    logged = [json.loads(line) for line in (out / "chunks.jsonl").read_text().splitlines()]
    assert sorted(({k: v for k, v in r.items() if k != "seconds"} for r in logged), key=lambda r: r["chunk"]) \
        == records(reference_run)
    printed = capsys.readouterr().out
    assert f"report written to {out / 'report.md'}" in printed


def test_a_campaign_directory_resumes_and_refuses_another_campaign(reference_run, tmp_path, capsys):
    copy = tmp_path / "copy"
    shutil.copytree(reference_run.out, copy)
    resumed = campaign(copy)
    assert records(resumed) == records(reference_run)   # every chunk was logged: nothing ran again
    assert [f["id"] for f in resumed.findings] == [f["id"] for f in reference_run.findings]
    code = cli.main(["fuzz", "--examples", "6", "--seed", "1", "--max-bodies", "2", "--max-states", "2",
                     "--workers", "0", "--out", str(copy)])
    assert code == 2 and "seed 0 there, 1 here" in capsys.readouterr().err


@pytest.mark.parametrize("argv, message", [
    (["fuzz", "--shard", "2/2"], "shard 2/2"),
    (["fuzz", "--shard", "a"], "--shard takes i/N"),
    (["fuzz", "--examples", "5", "--minutes", "1"], "either --examples or --minutes"),
    (["fuzz", "--formalism", "nope"], "unknown formalism 'nope'"),
])
def test_bad_fuzz_input_exits_2(argv, message, tmp_path, capsys):
    assert cli.main(argv + ["--out", str(tmp_path / "x")]) == 2
    assert message in capsys.readouterr().err


def test_replay_of_an_unknown_id_lists_the_valid_ones(reference_run, capsys):
    assert cli.main(["replay", "nope", "--dir", str(reference_run.out)]) == 2
    err = capsys.readouterr().err
    assert "'nope' is not a finding" in err
    assert all(f["id"] in err for f in reference_run.findings)


#: Seed 2's six examples include a moving mechanism of two or more bodies (seeds 0, 4 and 5 draw none in six).
#: The linearization checks are off: a Coriolis term dropped from the dynamics is what this campaign finds and
#: shrinks, and linearizing every backend at each shrink step cost a quarter of its time (56 s against 42 s).
FAULT = dict(seed=2, examples=6, chunk_examples=3, max_bodies=3, max_states=2, constraints=False,
             conservation=False, linearization=False)


def interrupt_when_shrinking(patch: pytest.MonkeyPatch) -> None:
    """Ctrl-C at the first example after a failure: Hypothesis has started shrinking it."""
    original = chunk._Recorder.example

    def interrupted(self, model):
        if self.last_failure is not None:
            raise KeyboardInterrupt
        original(self, model)

    patch.setattr(chunk._Recorder, "example", interrupted)


@pytest.fixture(scope="module")
def fault_run(drop_coriolis, tmp_path_factory) -> storage.CampaignResult:
    """The FAULT campaign on Euler–Lagrange without its Coriolis term (the longest campaign here: its failure is
    shrunk), run once for the tests that read it."""
    with pytest.MonkeyPatch.context() as patch:
        drop_coriolis(patch)
        return campaign(tmp_path_factory.mktemp("fuzz") / "fault", **FAULT)


@pytest.fixture(scope="module")
def interrupted_fault_run(drop_coriolis, tmp_path_factory) -> storage.CampaignResult:
    """The FAULT campaign interrupted (Ctrl-C) as it starts shrinking its failure."""
    with pytest.MonkeyPatch.context() as patch:
        drop_coriolis(patch)
        interrupt_when_shrinking(patch)
        return campaign(tmp_path_factory.mktemp("fuzz") / "interrupted", **FAULT)


def test_an_injected_fault_is_found_shrunk_saved_and_replayed(fault_run, dropped_coriolis, monkeypatch, capsys):
    """Euler–Lagrange without its Coriolis term: the campaign finds it, shrinks it to the smallest mechanism that has
    a Coriolis term (two bodies), names the outlier, saves it; replay fails with the fault and passes without it.
    (Conservation checks are off: the energy-rate check has a zero tolerance at rest, a finding of its own.)"""
    result = fault_run
    assert result.findings, "the campaign missed Euler–Lagrange without its Coriolis term"
    finding = result.findings[0]
    drift = next(c for c in finding["failing"] if c["key"] == "drift")
    assert drift["outlier"] == "euler_lagrange" and drift["worst_ratio"] > 1e3
    assert finding["shrunk"] and len(finding["model"]["bodies"]) == 2
    for body in finding["model"]["bodies"]:       # shrunk toward revolute joints about z, unit masses
        assert body["joint"] == "revolute" and body["axis"] == [0.0, 0.0, 1.0] and body["mass"] == 1.0
    assert finding["chart"]["name"] == "identity" and not any(finding["frame"]["translation"])
    assert any(finding["state"]["qd"]), "a Coriolis term needs a velocity"
    saved = json.loads((result.out / "findings" / f"{finding['id']}.json").read_text())
    assert model_from_dict(saved["model"]).digest() == model_from_dict(finding["model"]).digest()

    assert cli.main(["replay", finding["id"], "--dir", str(result.out)]) == 1
    assert "drift: DISAGREE" in capsys.readouterr().out
    monkeypatch.undo()
    assert cli.main(["replay", finding["id"][:6], "--dir", str(result.out)]) == 0
    assert "passes now" in capsys.readouterr().out


def test_ctrl_c_while_shrinking_keeps_the_failure_in_hand(interrupted_fault_run):
    result = interrupted_fault_run
    assert result.interrupted
    assert len(result.findings) == 1 and not result.findings[0]["shrunk"]
    assert result.chunks[-1]["interrupted"] and result.chunks[-1]["findings"] == [result.findings[0]["id"]]
    assert result.findings[0]["id"] in (result.out / "report.md").read_text()
    chunk = result.chunks[-1]["chunk"]
    assert chunk == max(r["chunk"] for r in result.chunks), "the campaign went on after Ctrl-C"


def test_ctrl_c_after_a_finding_is_saved_leaves_it_on_disk(dropped_coriolis, monkeypatch, tmp_path):
    save = storage.save_finding

    def save_then_interrupt(out, finding):
        save(out, finding)
        raise KeyboardInterrupt

    monkeypatch.setattr(chunk, "save_finding", save_then_interrupt)
    result = campaign(tmp_path / "int2", **{**FAULT, "shrink_calls": 0})   # saved as soon as it fails
    assert result.interrupted and len(result.findings) == 1
    assert (result.out / "findings" / f"{result.findings[0]['id']}.json").exists()
    assert result.findings[0]["id"] in (result.out / "report.md").read_text()


def test_resuming_after_ctrl_c_while_shrinking_gives_the_uninterrupted_findings(fault_run, interrupted_fault_run,
                                                                              dropped_coriolis, tmp_path):
    """The failure saved when a chunk was interrupted mid-shrink is replaced by its chunk's run to the end: one failure
    is not counted twice (the same finding files as an uninterrupted run, the same report)."""
    whole, partial = fault_run, interrupted_fault_run
    assert partial.interrupted and not partial.findings[0]["shrunk"]
    assert partial.findings[0]["id"] not in {f["id"] for f in whole.findings}
    shutil.copytree(partial.out, tmp_path / "resumed")
    resumed = campaign(tmp_path / "resumed", **FAULT)
    assert resumed.findings == whole.findings
    assert records(resumed) == records(whole)
    assert stable(resumed) == stable(whole)


def test_the_report_and_the_summary_account_for_every_example_and_group_the_findings(fault_run):
    """Each chunk of the FAULT campaign stops generating at its first failure: the report and the summary say how many
    of the 6 examples asked were generated, and put every one not generated down to a chunk that ended at its failure;
    the findings are grouped by signature."""
    result = fault_run
    got = fuzz_report.account(storage.load_campaign(result.out), result.chunks)
    generated = sum(r["examples"] for r in result.chunks)
    short = [r for r in result.chunks if r["examples"] < r["planned"]]
    assert (got.asked, got.generated) == (6, generated) and short and all(r["findings"] for r in short)
    assert got.missing == ((fuzz_report.FAILED, len(short), 6 - generated),)
    report = (result.out / "report.md").read_text()
    assert f"| examples | {generated} of 6 asked generated; not generated: {6 - generated} in chunks that ended at " \
           "their first failure" in report
    assert "## Findings by signature" in report
    lines = fuzz_report.summary(result).splitlines()
    assert lines[0].startswith(f"2 chunks, examples: {got.text()}; ")
    (signature, members), *_ = fuzz_report.group(result.findings)
    assert lines[1].startswith(f"  {len(members)} x failing {signature[0]}; outlier euler_lagrange; 2 revolute: ")
