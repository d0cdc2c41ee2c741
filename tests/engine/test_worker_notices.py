"""Notices raised in a gate's worker processes (``crosscheck.engine.pool``) are shown as the command shows them in its
own process: one line each, without Python's file path and source line (``crosscheck.engine.workers``)."""

from __future__ import annotations

import multiprocessing
import warnings
from pathlib import Path

from cases.urdf import BaseNotice
from crosscheck import cli
from crosscheck.engine import pool, workers
from crosscheck.engine.run import PreparationNotice

ARM = str(Path(__file__).resolve().parents[2] / "examples" / "arm.urdf")


def _warn_preparation() -> None:
    warnings.warn(PreparationNotice("geometric: preparing case 'big' takes about 90 s of CPU"), stacklevel=1)


def test_a_notice_in_a_worker_is_one_line(capfd):
    with warnings.catch_warnings():
        warnings.showwarning = cli._notice
        show = workers.warning_display()
    assert show is cli._notice
    ctx = multiprocessing.get_context("spawn")
    with ctx.Pool(1, initializer=pool._init_worker, initargs=([], (), show)) as workers_pool:
        workers_pool.apply(_warn_preparation)
    err = capfd.readouterr().err
    assert "crosscheck: notice: geometric: preparing case 'big' takes about 90 s of CPU\n" in err
    assert "PreparationNotice" not in err and ".py:" not in err


def test_a_display_no_worker_can_take_leaves_python_s():
    with warnings.catch_warnings():
        warnings.showwarning = lambda *args, **kwargs: None
        assert workers.warning_display() is None


def test_a_gate_in_worker_processes_shows_a_loader_notice_once_in_one_line(tmp_path, capfd):
    """The parent builds every model (to check it, to order the cases) and shows its notice; the worker that builds
    it again does not repeat it."""
    with warnings.catch_warnings():
        warnings.simplefilter("default", BaseNotice)        # as outside pytest, which records warnings instead
        code = cli.main(["gate", "--model", ARM, "--case", "double_pendulum", "--workers", "2", "--samples", "2",
                         "--no-self-test", "--no-charts", "--frames", "0", "--report", str(tmp_path / "gate.md")])
    err = capfd.readouterr().err
    assert code == 0
    assert err.count("crosscheck: notice:") == 1 and "BaseNotice" not in err, err
