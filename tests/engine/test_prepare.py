"""Deriving ahead (``crosscheck.engine.prepare``): a helper process derives a case's charts while the evaluating
process starts, and an entry being derived is locked, so no process derives it twice
(``formalisms.euler_lagrange._cached_text``)."""

from __future__ import annotations

import threading
import time


import formalisms.euler_lagrange as el
from crosscheck import backends
from crosscheck.engine import prepare, run
from crosscheck.engine.evaluation import CaseSetup
from crosscheck.engine.specs import CaseSpec, Checks


def test_a_process_needing_an_entry_being_derived_waits_and_reads_it(isolated_cache):
    path = el._cache_dir() / "entry.py"
    made, inside = [], threading.Event()

    def holder():
        with el._deriving(path):
            inside.set()
            time.sleep(0.3)
            path.write_text("derived once")

    thread = threading.Thread(target=holder)
    thread.start()
    inside.wait()
    assert el._cached_text(path, lambda: made.append(1) or "derived twice") == "derived once"
    thread.join()
    assert made == []


def test_the_helper_derives_the_charts_and_the_outcomes_do_not_change(isolated_cache, monkeypatch):
    """With a CPU to spare and enough to derive, a helper process prepares every chart of the case (their entries are
    in the cache afterwards, derived by it or by the evaluating process, once each); the outcomes are those of a run
    without it."""
    monkeypatch.setattr(prepare, "AHEAD_S", 0.0)
    monkeypatch.setattr(prepare.os, "cpu_count", lambda: 2)
    spec, checks = CaseSpec("n_link_pendulum", (("n", "5"),)), Checks(frames=0, conservation=False)
    chosen = [backends.get("euler_lagrange"), backends.get("pinocchio")]
    setup = CaseSetup.build(spec, 0, checks)
    started = []
    monkeypatch.setattr(prepare, "ahead", lambda *a, _f=prepare.ahead: started.append(_f(*a)) or started[-1])
    ahead = run.run_case(spec, chosen, 3, 0, checks=checks, derive_ahead=True)
    assert started and started[0] is not None and not started[0].is_alive()
    for chart in setup.charts:
        assert (el._cache_dir() / f"{el.cache_key(setup.model, chart)}.py").exists()
    el._compiled.cache_clear()
    alone = run.run_case(spec, chosen, 3, 0, checks=checks)
    for a, b in zip(ahead.states, alone.states):
        assert {k: c.worst_ratio for k, c in a.checks.items()} == {k: c.worst_ratio for k, c in b.checks.items()}
        assert {k: c.worst_ratio for k, c in a.comparisons.items()} == {k: c.worst_ratio
                                                                       for k, c in b.comparisons.items()}


def test_no_helper_for_a_small_preparation_or_a_single_cpu(monkeypatch):
    setup = CaseSetup.build(CaseSpec("double_pendulum"), 0, Checks())
    chosen = [backends.get("euler_lagrange")]
    assert prepare.ahead(setup, chosen, prepare.AHEAD_S / 2, Checks(), 0) is None
    monkeypatch.setattr(prepare.os, "cpu_count", lambda: 1)
    assert prepare.ahead(setup, chosen, 10 * prepare.AHEAD_S, Checks(), 0) is None
