"""Running a campaign: its chunks in this process or in a pool of spawned workers (each replaced after
``CHUNKS_PER_PROCESS`` chunks), logged as they end, the report written at the end (also after an interruption); merging
the directories of shards into one (``crosscheck.campaigns.fuzz``)."""

from __future__ import annotations

import contextlib
import itertools
import json
import multiprocessing
import os
import queue as queues
import shutil
import signal
import tempfile
import threading
import time
from pathlib import Path
from typing import Iterable, Iterator, Sequence

from crosscheck import backends
from crosscheck.campaigns.fuzz.chunk import run_chunk
from crosscheck.campaigns.fuzz.interrupts import INTERRUPTS, signals_handled, watch
from crosscheck.campaigns.fuzz.settings import (CHUNKS_PER_PROCESS, INTERRUPT_GRACE, LOST_AFTER, POLL, chunk_size,
                                                FuzzConfig, FuzzError, planned_chunks)
from crosscheck.campaigns.fuzz.storage import (append_chunk, CampaignResult, final_records, load_campaign, load_chunks,
                                               load_findings, locked, prepare, prune, record_run, save_finding,
                                               write_atomic)
from crosscheck.engine import progress, workers
from crosscheck.reports.fuzz_report import write_report


# ------------------------------------------------------------------------------------------------ a campaign


class _Tally:
    """The campaign's counts on its progress display (``crosscheck.engine.progress``): examples (of the planned total),
    examples/s, the worst ratio, the findings, and whether examples are being generated or a failure shrunk."""

    def __init__(self, display: progress.Display):
        self.display = display
        self.start = time.perf_counter()
        self.examples, self.worst, self.findings = 0, 0.0, 0

    def example(self, examples: int, states: int, ratio: float) -> None:
        """A property call: a generated example (``examples`` 1) or a shrinking call (0)."""
        self.examples += examples
        self.worst = max(self.worst, ratio)
        rate = self.examples / max(time.perf_counter() - self.start, 1e-9)
        self.display.advance(examples, rate=rate, worst=self.worst)
        self.display.doing("generating examples" if examples else "shrinking a failure")

    def chunk(self, record: dict) -> None:
        self.findings += len(record["findings"])
        self.display.update(findings=self.findings)


def _display(total: int | None, quiet: bool) -> progress.Display:
    """The campaign's progress display: examples of ``total``, examples/s, worst ratio, findings."""
    return progress.Display("fuzz", "examples", total, quiet=quiet,
                            extra=("{task.fields[rate]:.2f}/s", "worst {task.fields[worst]:.3g}",
                                   "{task.fields[findings]} findings"), rate=0.0, worst=0.0, findings=0)


def _until(deadline: float | None, ks: Iterable[int]) -> Iterator[int]:
    for k in ks:
        if deadline is not None and time.monotonic() > deadline:
            return
        yield k


def _in_process(cfg: FuzzConfig, plan: Iterator[int], cache: str, tally: _Tally) -> Iterator[dict]:
    """Chunks one after another in this process (the derivation cache pointed at ``cache`` meanwhile), until one is
    interrupted or an interrupt is requested."""
    before = os.environ.get("CROSSCHECK_CACHE")
    os.environ["CROSSCHECK_CACHE"] = cache
    try:
        for k in plan:
            if INTERRUPTS.requested:
                return
            record = run_chunk(cfg, k, tally.example)
            yield record
            if record["interrupted"]:
                return
    finally:
        if before is None:
            os.environ.pop("CROSSCHECK_CACHE", None)
        else:
            os.environ["CROSSCHECK_CACHE"] = before


_QUEUE = None
_LIMITS = None


def _init_worker(plugins: Sequence[str], cache: str, queue, stop, parent: int) -> None:
    """A worker process: its interrupts (module doc: SIGINT and, during a chunk, SIGTERM handled as in the campaign;
    the stop flag and the parent watched), the campaign's derivation cache, one BLAS thread, the plugins, the
    progress queue."""
    global _QUEUE, _LIMITS
    from threadpoolctl import threadpool_limits

    INTERRUPTS.worker, INTERRUPTS.stop, INTERRUPTS.requested = True, stop, bool(stop.value)
    signal.signal(signal.SIGINT, INTERRUPTS.on_signal)   # SIGTERM: see _Interrupts.chunk
    threading.Thread(target=watch, args=(stop, parent, threading.get_ident()), daemon=True).start()
    queue.cancel_join_thread()   # exiting never waits on the queue (whose lock a killed worker may hold)
    os.environ["CROSSCHECK_CACHE"] = cache
    _LIMITS = threadpool_limits(limits=1, user_api="blas")
    backends.load_plugins(plugins)
    _QUEUE = queue


def _worker_chunk(cfg: FuzzConfig, k: int) -> dict:
    """Chunk ``k`` in a worker: the worker's pid to the queue first (the pool loop watches that it lives), then the
    chunk's progress."""
    _QUEUE.put(("start", k, os.getpid()))
    return run_chunk(cfg, k, lambda examples, states, ratio: _QUEUE.put(("example", examples, states, ratio)))


class _Flight:
    """The chunks in flight in a worker pool: their pending results, the process running each (from the workers'
    ``start`` messages), their progress counted by ``tally``."""

    def __init__(self, cfg: FuzzConfig, pool, queue, tally: _Tally):
        self.cfg, self.pool, self.queue, self.tally = cfg, pool, queue, tally
        self.pending: dict = {}
        self.pids: dict[int, int] = {}

    def start(self, ks: Iterable[int]) -> None:
        for k in ks:
            self.pending[k] = self.pool.apply_async(_worker_chunk, (self.cfg, k))

    def _drain(self) -> None:
        while True:
            try:
                kind, *message = self.queue.get_nowait()
            except queues.Empty:
                return
            if kind == "start":
                self.pids[message[0]] = message[1]
            else:
                self.tally.example(*message)

    def ended(self) -> list[dict]:
        """The records of the chunks that ended since the last call."""
        self._drain()
        ready = [k for k, result in self.pending.items() if result.ready()]
        for k in ready:
            self.pids.pop(k, None)
        return [self.pending.pop(k).get() for k in ready]

    def lost(self) -> tuple[int, int] | None:
        """(chunk, pid) of a chunk whose worker process is gone without returning it (killed), else None; the chunk
        is no longer waited for."""
        alive = {p.pid for p in multiprocessing.active_children()}
        for k, pid in self.pids.items():
            if pid not in alive:
                self.pending[k].wait(LOST_AFTER)   # its result may still be on its way
                if not self.pending[k].ready():
                    del self.pending[k], self.pids[k]
                    return k, pid
        return None

    def wait(self) -> tuple[list[dict], tuple[int, int] | None]:
        """Until a chunk ends, an interrupt is requested or a worker is lost: the records of the chunks that ended
        and the lost (chunk, pid)."""
        while True:
            done, lost = self.ended(), self.lost()
            if done or lost or INTERRUPTS.requested:
                return done, lost
            time.sleep(POLL)

    def grace(self) -> Iterator[dict]:
        """The records of the chunks in flight that end within ``INTERRUPT_GRACE`` seconds."""
        deadline = time.monotonic() + INTERRUPT_GRACE
        while self.pending and time.monotonic() < deadline:
            yield from self.ended()
            time.sleep(POLL / 2)


def _in_pool(cfg: FuzzConfig, plan: Iterator[int], cache: str, tally: _Tally) -> Iterator[dict]:
    """Chunks in ``cfg.workers`` spawned processes, at most one in flight per worker, records in completion order.
    On an interrupt (of this process, or a chunk reporting one) or a lost worker, no chunk starts any more and the
    stop flag interrupts the chunks in flight, which get ``INTERRUPT_GRACE`` seconds to save what they hold and
    report; a lost worker then raises :class:`FuzzError`."""
    ctx = multiprocessing.get_context("spawn")
    queue, stop = ctx.Queue(), ctx.RawValue("b", 0)
    with workers.spawning():   # its workers ignore Ctrl-C until their initializer handles it
        pool = ctx.Pool(cfg.workers, initializer=_init_worker,
                        initargs=(cfg.plugins, cache, queue, stop, os.getpid()), maxtasksperchild=CHUNKS_PER_PROCESS)
        flight = _Flight(cfg, pool, queue, tally)
        try:
            flight.start(itertools.islice(plan, cfg.workers))
            while flight.pending:
                done, lost = flight.wait()
                yield from done
                if lost or INTERRUPTS.requested or any(record["interrupted"] for record in done):
                    stop.value = 1
                    yield from flight.grace()
                    if lost:
                        raise FuzzError(f"the worker process running chunk {lost[0]} (pid {lost[1]}) died; the "
                                        "chunks in flight were stopped and the report written: run the same command "
                                        f"again to resume (chunk {lost[0]} runs again)")
                    return
                flight.start(itertools.islice(plan, len(done)))
        finally:
            stop.value = 1   # first: a worker takes the pool's SIGTERM after it as the end (_Interrupts.on_signal)
            pool.terminate()
            pool.join()


def run_campaign(cfg: FuzzConfig, command: str = "", quiet: bool = False) -> CampaignResult:
    """Run the campaign ``cfg`` (from :func:`config`) in its directory, locked for the run: chunks logged as they
    end, findings saved as they are found, the report written at the end, also after an interruption (SIGINT or
    SIGTERM: ``interrupted`` is then set) or an error (re-raised after). Module doc: what survives what. The
    progress display shows on a terminal's stderr, unless ``quiet``."""
    out = Path(cfg.out)
    with locked(out), signals_handled():
        campaign = prepare(cfg)
        prune(out)
        logged = {r["chunk"] for r in load_chunks(out) if not r["interrupted"]}   # an interrupted chunk runs again
        deadline = None if cfg.minutes is None else time.monotonic() + 60.0 * cfg.minutes
        plan = _until(deadline, (k for k in planned_chunks(cfg) if k not in logged))
        total = None if cfg.examples is None else sum(chunk_size(cfg, k) for k in planned_chunks(cfg)
                                                      if k not in logged)
        cache = tempfile.mkdtemp(prefix="crosscheck-fuzz-cache-")
        start, interrupted, ended = time.perf_counter(), False, False
        runner = _in_process if cfg.workers == 0 else _in_pool
        try:
            with _display(total, quiet) as display:
                tally = _Tally(display)
                with contextlib.closing(runner(cfg, plan, cache, tally)) as records:
                    for record in records:
                        append_chunk(out, record)
                        tally.chunk(record)
                        interrupted |= record["interrupted"]
            ended = True
        except KeyboardInterrupt:
            pass
        finally:
            interrupted = interrupted or not ended or INTERRUPTS.requested
            shutil.rmtree(cache, ignore_errors=True)
            prune(out)
            record_run(cfg, campaign, time.perf_counter() - start, interrupted)
            write_report(out, command)
        return CampaignResult(out, load_chunks(out), load_findings(out), interrupted)


def merge(dirs: Sequence[Path], out: Path, command: str = "") -> CampaignResult:
    """Combine campaign directories (shards) into ``out`` (locked meanwhile, like a run's): the same parameters
    required, findings de-duplicated by ID, chunk logs combined (a chunk in several keeps one record,
    :func:`final_records`), runs listed; the report written."""
    campaigns = []
    for d in dirs:
        found = load_campaign(Path(d))
        if found is None:
            raise FuzzError(f"{d} is not a campaign directory (no campaign.json)")
        campaigns.append(found)
    for d, c in zip(dirs[1:], campaigns[1:]):
        if c["identity"] != campaigns[0]["identity"]:
            raise FuzzError(f"cannot merge {d} with {dirs[0]}: the campaigns' parameters differ "
                            f"({c['identity']} vs {campaigns[0]['identity']})")
    with locked(out):
        existing = load_campaign(out)
        if existing is not None and existing["identity"] != campaigns[0]["identity"]:
            raise FuzzError(f"{out} holds another campaign; give another --out")
        runs = (existing or {"runs": []})["runs"] + [r for c in campaigns for r in c["runs"]]
        write_atomic(out / "campaign.json", json.dumps({"identity": campaigns[0]["identity"], "runs": runs}, indent=1))
        records = final_records(r for d in [out, *map(Path, dirs)] for r in load_chunks(d))
        write_atomic(out / "chunks.jsonl", "".join(json.dumps(r) + "\n" for r in records))
        for d in dirs:
            for finding in load_findings(Path(d)):
                save_finding(out, finding)
        prune(out)
        write_report(out, command)
        return CampaignResult(out, load_chunks(out), load_findings(out), False)
