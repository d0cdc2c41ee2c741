"""A fuzz campaign's accounting of its examples (asked, generated, and why fewer) and its findings grouped by
signature (issue 20, item 6), on hand-written chunk logs and findings; ``tests/campaigns/test_fuzz.py`` checks both on a real
campaign."""

from __future__ import annotations

from pathlib import Path

from crosscheck.campaigns.fuzz import storage
from crosscheck.reports import fuzz_report


def _chunk(k: int, examples: int, planned: int = 10, findings=(), interrupted: bool = False) -> dict:
    return {"chunk": k, "planned": planned, "examples": examples, "shrink_calls": 5, "states": examples,
            "models": examples, "worst_ratio": 1.0, "worst_key": "drift", "worst_agreeing": 0.5,
            "worst_agreeing_key": "drift", "seconds": 1.0, "findings": list(findings), "interrupted": interrupted}


def _campaign(examples=None, minutes=None, shards=("0/1",)) -> dict:
    return {"identity": {"chunk_examples": 10},
            "runs": [{"shard": s, "examples": examples, "minutes": minutes} for s in shards]}


def test_every_example_not_generated_is_accounted_for():
    """Asked 50 in chunks of 10: chunk 0 generated all; chunk 1 failed at its 3rd example (7 never drawn); chunk 2 was
    interrupted after 2; chunk 3 stopped at 9 without a failure; chunk 4 was never run."""
    chunks = [_chunk(0, 10), _chunk(1, 3, findings=["a"]), _chunk(2, 2, interrupted=True), _chunk(3, 9)]
    got = fuzz_report.account(_campaign(examples=50), chunks)
    assert (got.asked, got.generated) == (50, 24)
    assert got.missing == ((fuzz_report.FAILED, 1, 7), (fuzz_report.INTERRUPTED, 1, 8), (fuzz_report.NOT_RUN, 1, 10), (fuzz_report.EARLY, 1, 1))
    assert sum(n for _, _, n in got.missing) == got.asked - got.generated
    assert got.text().startswith("24 of 50 asked generated; not generated: 7 in chunks that ended at their first "
                                 "failure (Hypothesis shrinks it instead of generating the rest) (1 chunk); 8 in")


def test_a_shard_expects_only_its_chunks_and_a_timed_campaign_has_no_count_asked():
    """Shard 0/2 of 40 examples plans chunks 0 and 2: with both logged, nothing is missing (chunks 1 and 3 belong to
    the other shard). The last chunk of 25 examples plans 5."""
    assert fuzz_report.account(_campaign(examples=40, shards=("0/2",)), [_chunk(0, 10), _chunk(2, 10)]).missing == ()
    assert fuzz_report.account(_campaign(examples=25), [_chunk(0, 10), _chunk(1, 10)]).missing == ((fuzz_report.NOT_RUN, 1, 5),)
    timed = fuzz_report.account(_campaign(minutes=5.0), [_chunk(0, 10), _chunk(1, 4, findings=["a"])])
    assert timed.text() == "14 generated (asked: 5 minutes)" and timed.missing == ((fuzz_report.FAILED, 1, 6),)


def _finding(ident: str, chunk: int, keys=("drift", "total"), outlier="euler_lagrange", joints=("revolute",) * 2,
             constraints=(), errors=None) -> dict:
    return {"id": ident, "campaign": {"chunk": chunk},
            "model": {"bodies": [{"joint": j} for j in joints], "constraints": [{"type": c} for c in constraints]},
            "failing": [{"key": k, "outlier": outlier} for k in keys], "errors": errors or {}}


def test_findings_of_one_bug_group_by_signature_in_the_summary(tmp_path: Path):
    """Three findings of one bug (the same checks, outlier and shrunk mechanism, whatever the order of the checks) and
    two others (another mechanism; a backend error): three groups, the largest first, each with its count, its IDs and
    one replay command."""
    findings = [_finding("aaa", 0), _finding("bbb", 1, keys=("total", "drift")), _finding("ccc", 2),
                _finding("ddd", 3, joints=("revolute", "prismatic", "revolute"), constraints=("PointOnCircle",)),
                _finding("eee", 4, keys=(), outlier=None, errors={"screw": "ValueError: nan"})]
    groups = fuzz_report.group(findings)
    assert [[f["id"] for f in members] for _, members in groups] == [["aaa", "bbb", "ccc"], ["ddd"], ["eee"]]
    assert groups[1][0] == ("drift, total", "euler_lagrange", "-", "1 prismatic, 2 revolute; 1 PointOnCircle")
    assert groups[2][0] == ("-", "-", "screw", "2 revolute")
    text = fuzz_report.summary(storage.CampaignResult(tmp_path, [_chunk(k, 1, 1, [f["id"]]) for k, f in enumerate(findings)],
                                            findings, False))
    lines = text.splitlines()
    assert lines[0] == "5 chunks, examples: 5 generated; 5 states, 5 findings in 3 signature(s)"
    assert lines[1] == "  3 x failing drift, total; outlier euler_lagrange; 2 revolute: aaa, bbb, ccc"
    assert lines[2] == f"    crosscheck replay aaa --dir {tmp_path}"
    assert lines[5] == "  1 x errors in screw; 2 revolute: eee"
    assert sum("crosscheck replay" in line for line in lines) == 3
