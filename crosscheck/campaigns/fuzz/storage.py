"""A campaign directory (``crosscheck.campaigns.fuzz``): ``campaign.json``, the append-only ``chunks.jsonl``, the
findings written atomically, the lock held by the one run at a time, and what a run returns
(:class:`CampaignResult`)."""

from __future__ import annotations

import contextlib
import fcntl
import json
import os
import secrets
from dataclasses import dataclass
from pathlib import Path
from typing import Iterable, Iterator, Sequence

from crosscheck.campaigns.fuzz.settings import FuzzConfig, FuzzError


# ------------------------------------------------------------------------------------------------ storage


def write_atomic(path: Path, text: str) -> None:
    """Replace ``path`` by a file holding ``text`` in one step (a reader sees the old file or the new one, a crash
    leaves at worst a ``.tmp`` file beside it); created with mode 0o666 less the umask, like any file."""
    path.parent.mkdir(parents=True, exist_ok=True)
    tmp = path.with_name(f".{path.name}.{os.getpid()}.{secrets.token_hex(4)}.tmp")
    try:
        with open(os.open(tmp, os.O_WRONLY | os.O_CREAT | os.O_EXCL, 0o666), "w") as fh:
            fh.write(text)
        os.replace(tmp, path)
    except BaseException:
        tmp.unlink(missing_ok=True)
        raise


@contextlib.contextmanager
def locked(out: Path) -> Iterator[None]:
    """The campaign directory ``out``, created if need be, locked for this run while in the block (``DIR/.lock``,
    ``fcntl.flock``, holding the pid of the run; the OS releases the lock when the process ends however it ends)."""
    _campaign_dir(out)
    try:
        fd = os.open(out / ".lock", os.O_RDWR | os.O_CREAT, 0o666)
    except OSError as exc:
        raise FuzzError(f"cannot write in campaign directory {out}: {exc.strerror or exc}") from None
    try:
        try:
            fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
        except BlockingIOError:
            holder = os.pread(fd, 32, 0).decode(errors="replace").strip() or "unknown"
            raise FuzzError(f"campaign directory {out} is in use by another run (pid {holder}); wait for it or give "
                            "another --out") from None
        os.ftruncate(fd, 0)
        os.pwrite(fd, f"{os.getpid()}\n".encode(), 0)
        yield
    finally:
        os.close(fd)


def _campaign_dir(out: Path) -> None:
    """Create ``out`` (and its parents); :class:`FuzzError` if it is a file or cannot be created."""
    if out.exists() and not out.is_dir():
        raise FuzzError(f"--out {out} is a file, not a directory")
    try:
        out.mkdir(parents=True, exist_ok=True)
    except OSError as exc:
        raise FuzzError(f"cannot create campaign directory {out}: {exc.strerror or exc}") from None


#: The keys of a chunk's log record and of a saved finding (:func:`run_chunk`).
CHUNK_KEYS = ("chunk", "examples", "shrink_calls", "states", "models", "worst_ratio", "worst_key", "worst_agreeing",
              "worst_agreeing_key", "seconds", "findings", "interrupted")
FINDING_KEYS = ("id", "model", "state", "chart", "frame", "checks", "backends", "failing", "errors", "worst_ratio",
                "campaign", "shrunk")


def _parsed(text: str | bytes, keys: Sequence[str]) -> dict:
    """The JSON object ``text`` with every one of ``keys``; ValueError saying what is wrong otherwise."""
    value = json.loads(text)
    if not isinstance(value, dict):
        raise ValueError(f"a JSON {type(value).__name__}, not an object")
    missing = [key for key in keys if key not in value]
    if missing:
        raise ValueError(f"no {', '.join(missing)}")
    return value


def read_finding(path: Path) -> dict:
    """The finding saved in ``path``; :class:`FuzzError` naming the file if it is not one."""
    try:
        finding = _parsed(path.read_bytes(), FINDING_KEYS)
        if not isinstance(finding["campaign"], dict) or "chunk" not in finding["campaign"]:
            raise ValueError("no campaign chunk")
    except ValueError as exc:
        raise FuzzError(f"{path} is not a finding file ({exc}); delete it (to find it again, delete as well the lines "
                        f"of chunks.jsonl that list {path.stem}, then resume)") from None
    return finding


def _precedence(finding: dict) -> tuple[bool, int]:
    """Which saved copy of a finding is kept, lowest first: one from a chunk that ran to its end before one from an
    interrupted chunk (perhaps not shrunk), then the one of the lowest chunk."""
    return bool(finding["campaign"].get("interrupted", False)), finding["campaign"]["chunk"]


def save_finding(out: Path, finding: dict) -> bool:
    """Write ``findings/ID.json`` atomically unless the copy there takes precedence (:func:`_precedence`: so the
    stored copy does not depend on which shard or worker finished first, nor on interruptions; a chunk run again
    replaces its earlier copy). Returns whether it was written."""
    path = out / "findings" / f"{finding['id']}.json"
    if path.exists() and _precedence(read_finding(path)) < _precedence(finding):
        return False
    write_atomic(path, json.dumps(finding, indent=1))
    return True


def load_findings(out: Path) -> list[dict]:
    """The saved findings, ordered by chunk then ID."""
    found = [read_finding(p) for p in sorted((out / "findings").glob("*.json"))]
    return sorted(found, key=lambda f: (f["campaign"]["chunk"], f["id"]))


def prune(out: Path) -> None:
    """Delete what an interruption or a crash left behind: temporary files, and the findings saved by interrupted
    chunks that no chunk of the log lists any more (their chunk ran again to its end without reproducing them)."""
    for tmp in [*out.glob("*.tmp"), *(out / "findings").glob("*.tmp")]:
        tmp.unlink(missing_ok=True)
    listed = {i for r in load_chunks(out) for i in r["findings"]}
    for path in sorted((out / "findings").glob("*.json")):
        finding = read_finding(path)
        if finding["campaign"].get("interrupted") and finding["id"] not in listed:
            path.unlink()


def final_records(records: Iterable[dict]) -> list[dict]:
    """One record per chunk, ordered by chunk: the last one that ran to its end, else the last one."""
    final: dict[int, dict] = {}
    for r in records:
        kept = final.get(r["chunk"])
        if kept is None or kept["interrupted"] or not r["interrupted"]:
            final[r["chunk"]] = r
    return sorted(final.values(), key=lambda r: r["chunk"])


def load_chunks(out: Path) -> list[dict]:
    """The chunk log, one record per chunk (:func:`final_records`), ordered by chunk. A torn last line (a crash while it
    was appended) is skipped; any other line that is not a record is corruption: :class:`FuzzError` naming it."""
    path = out / "chunks.jsonl"
    lines = path.read_bytes().split(b"\n") if path.exists() else []
    records = []
    for number, line in enumerate(lines, 1):
        if not line.strip():
            continue
        try:
            records.append(_parsed(line, CHUNK_KEYS))
        except ValueError as exc:
            if number == len(lines):   # no newline after it: torn; the next append drops it
                continue
            raise FuzzError(f"{path} line {number} is not a chunk record ({exc}): the log is corrupt; delete that "
                            "line (its chunk runs again on resume)") from None
    return final_records(records)


def append_chunk(out: Path, record: dict) -> None:
    """Append ``record`` to the chunk log, after dropping a torn last line (or ending a whole one)."""
    with open(out / "chunks.jsonl", "a+b") as fh:
        size = fh.seek(0, os.SEEK_END)
        if size and os.pread(fh.fileno(), 1, size - 1) != b"\n":
            fh.seek(0)
            text = fh.read()
            head = text[:text.rfind(b"\n") + 1]
            try:
                _parsed(text[len(head):], CHUNK_KEYS)
                fh.write(b"\n")
            except ValueError:
                fh.truncate(len(head))
        fh.write((json.dumps(record) + "\n").encode())


def load_campaign(out: Path) -> dict | None:
    """``campaign.json`` of ``out`` (None if there is none); :class:`FuzzError` if it is not a campaign file."""
    path = out / "campaign.json"
    if not path.exists():
        return None
    try:
        campaign = _parsed(path.read_bytes(), ("identity", "runs"))
        if not isinstance(campaign["identity"], dict) or not isinstance(campaign["runs"], list):
            raise ValueError("identity is not an object or runs not a list")
    except ValueError as exc:
        raise FuzzError(f"{path} is not a campaign file: {exc}; remove it or give another --out") from None
    return campaign


def prepare(cfg: FuzzConfig) -> dict:
    """Create or resume the campaign directory (locked by the caller): ``campaign.json`` must hold the same
    parameters."""
    out = Path(cfg.out)
    found = load_campaign(out)
    if found is not None and found["identity"] != cfg.identity():
        diff = {k: (found["identity"].get(k), v) for k, v in cfg.identity().items() if found["identity"].get(k) != v}
        raise FuzzError(f"{out} holds another campaign (parameters differ: "
                        + ", ".join(f"{k} {a!r} there, {b!r} here" for k, (a, b) in diff.items())
                        + "); give another --out or remove it")
    campaign = found or {"identity": cfg.identity(), "runs": []}
    write_atomic(out / "campaign.json", json.dumps(campaign, indent=1))
    return campaign


def record_run(cfg: FuzzConfig, campaign: dict, wall: float, interrupted: bool) -> None:
    run = {"shard": f"{cfg.shard[0]}/{cfg.shard[1]}", "workers": cfg.workers, "examples": cfg.examples,
           "minutes": cfg.minutes, "wall_seconds": round(wall, 3), "interrupted": interrupted}
    campaign["runs"].append(run)
    write_atomic(Path(cfg.out) / "campaign.json", json.dumps(campaign, indent=1))


@dataclass
class CampaignResult:
    out: Path
    chunks: list[dict]
    findings: list[dict]
    interrupted: bool
