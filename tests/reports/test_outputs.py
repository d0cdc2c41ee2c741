"""Where the commands write (issue 20, item 2) and what ``--workers`` means (item 5): every command writes under
``crosscheck-out/`` by default, the committed ``reports/`` only through ``crosscheck reports``, and ``--workers`` has
one meaning and one default rule in every command that takes it."""

from __future__ import annotations

import argparse
import math
import os
import re
from pathlib import Path

import pytest

from crosscheck import cli
from crosscheck.campaigns.fuzz import settings
from crosscheck.cli import options
from crosscheck.reports import gate_summary

ROOT = Path(__file__).resolve().parents[2]


def _subcommands() -> dict[str, argparse.ArgumentParser]:
    parser = cli.build_parser()
    sub = next(a for a in parser._actions if isinstance(a, argparse._SubParsersAction))
    return dict(sub.choices)


def _option(parser: argparse.ArgumentParser, dest: str) -> argparse.Action | None:
    return next((a for a in parser._actions if a.dest == dest), None)


def test_a_gate_writes_its_report_in_crosscheck_out_and_nothing_else(tmp_path, monkeypatch, capsys):
    monkeypatch.chdir(tmp_path)
    assert cli.main(["gate", "--case", "double_pendulum", "--samples", "3", "--no-self-test"]) == 0
    written = sorted(str(p.relative_to(tmp_path)) for p in tmp_path.rglob("*") if p.is_file())
    assert written == ["crosscheck-out/gate-details.md", "crosscheck-out/gate.md"]
    assert "report written to crosscheck-out/gate.md (details in crosscheck-out/gate-details.md)" in \
        capsys.readouterr().out
    summary = (tmp_path / "crosscheck-out" / "gate.md").read_text()
    assert "**PASS**" in summary and "[gate-details.md](gate-details.md)" in summary


def test_no_default_output_is_under_reports():
    """Every output option of every command (``--report``, ``--out``, ``--dir``, also ``trajectory --report``'s
    directory) defaults to a place under crosscheck-out/, which git ignores; reports/ is never a default."""
    defaults = {}
    for name, parser in _subcommands().items():
        for dest in ("report", "out", "dir"):
            action = _option(parser, dest)
            if action is not None and (action.default or action.const) not in (None, False):
                defaults[f"{name} --{dest}"] = action.const if action.nargs == "?" else action.default
    assert set(defaults) == {"gate --report", "faults --report", "fuzz --out", "replay --dir", "bench --out",
                             "stability --out", "trajectory --report", "simulators --report"}
    for option, default in defaults.items():
        assert Path(default).parts[0] == options.OUTPUT_DIR and options.REPORTS_DIR not in Path(default).parts, option
    assert settings.DEFAULT_DIR == cli.fuzz.DEFAULT_FUZZ_DIR == _option(_subcommands()["replay"], "dir").default
    assert f"{options.OUTPUT_DIR}/" in (ROOT / ".gitignore").read_text().splitlines()


@pytest.fixture
def in_a_checkout(tmp_path, monkeypatch):
    """A current directory with a reports/ directory, as the repository's root has."""
    (tmp_path / options.REPORTS_DIR).mkdir()
    monkeypatch.chdir(tmp_path)


def test_the_reports_command_runs_each_report_command_into_reports(in_a_checkout, monkeypatch, capsys):
    """``crosscheck reports`` runs the commands of ``cli.reports.REPORTS`` as they are (so a report names the command
    that regenerates it), each writing into reports/; ``--only`` picks some, in the order given."""
    ran = []

    def fake(args) -> int:
        target = getattr(args, "report", None) or getattr(args, "out", None)
        ran.append((args.command, str(target), getattr(args, "scale", False), " ".join(args.argv)))
        return 0

    for name in ("gate", "faults", "bench", "stability", "trajectory"):   # each module's parser reads its cmd_NAME
        monkeypatch.setattr(getattr(cli, name), f"cmd_{name}", fake)
    assert cli.main(["reports", "--quiet"]) == 0
    assert [r[0] for r in ran] == ["gate", "faults", "bench", "stability", "bench", "trajectory"]
    assert [r[1] for r in ran] == ["reports/gate.md", "reports/faults.md", "reports", "reports", "reports", "reports"]
    assert ran[4][2] and "--quiet" in ran[0][3] and "--no-stability" in ran[2][3]
    ran.clear()
    assert cli.main(["reports", "--only", "trajectories,gate"]) == 0
    assert [r[3] for r in ran] == ["trajectory --report reports", "gate --report reports/gate.md"]
    assert capsys.readouterr().out.splitlines()[-1] == "reports: 2 regenerated in reports/"


def test_the_reports_command_passes_failures_on_and_stops_at_ctrl_c(in_a_checkout, monkeypatch, capsys):
    codes = {"gate": 1, "faults": options.INTERRUPTED}
    monkeypatch.setattr(cli.gate, "cmd_gate", lambda args: codes[args.command])
    monkeypatch.setattr(cli.faults, "cmd_faults", lambda args: codes[args.command])
    monkeypatch.setattr(cli.stability, "cmd_stability", lambda args: pytest.fail("ran after Ctrl-C"))
    assert cli.main(["reports", "--only", "gate"]) == 1
    assert "exit non-zero: gate" in capsys.readouterr().out
    assert cli.main(["reports", "--only", "faults,stability"]) == options.INTERRUPTED
    assert "interrupted while regenerating faults; not run: stability" in capsys.readouterr().err


def test_the_reports_command_runs_where_the_reports_are(tmp_path, monkeypatch, capsys):
    monkeypatch.chdir(tmp_path)
    monkeypatch.setattr(cli.gate, "cmd_gate", lambda args: pytest.fail("ran outside a checkout"))
    assert cli.main(["reports", "--only", "gate"]) == 2
    assert "there is no reports/ directory here" in capsys.readouterr().err
    assert not (tmp_path / options.REPORTS_DIR).exists()


@pytest.mark.parametrize("only", ["gate,nope", ",", "reports"])
def test_reports_only_takes_known_names(only, capsys):
    assert cli.main(["reports", "--only", only]) == 2
    assert "--only takes report names separated by commas from gate, faults, bench" in capsys.readouterr().err


def _gate_files(tmp_path, *args) -> tuple[int, str, str]:
    report = tmp_path / "gate.md"
    code = cli.main(["gate", "--case", "double_pendulum", "--case", "acrobot", "--samples", "3", "--frames", "0",
                     "--no-self-test", "--workers", "0", *args, "--report", str(report)])
    return code, report.read_text(), gate_summary.details_path(report).read_text()


def test_a_passing_gate_report_is_short_and_its_details_sit_next_to_it(tmp_path):
    """The summary: the verdict, what was run and checked, one line per case; everything else in the details."""
    assert gate_summary.details_path(tmp_path / "gate.md") == tmp_path / "gate-details.md"
    assert gate_summary.details_path("/tmp/panda.md") == Path("/tmp/panda-details.md")
    code, summary, details = _gate_files(tmp_path)
    assert code == 0
    short, closeness = summary.split("## How close each backend came\n")
    lines = short.splitlines()
    assert lines[2].startswith("**PASS**: 0 of 6 states") and len(lines) < 30, len(lines)
    assert len(closeness.splitlines()) == 5 + 7 + 1   # blank, text, blank, header, rule; 6 backends, closed_form; blank
    assert "- worst error/tolerance: " in summary and "- checked: every quantity every backend supplies, chart " \
        "invariance, energy and Christoffel conservation, linearizations A, B (eq. 11), the article's closed " \
        "forms as a voter" in summary
    assert "- skipped by option: frame changes (--frames 0), self-test canaries (--no-self-test)" in summary
    assert [line.split(" |")[0] for line in lines if line.startswith("| double_pendulum |")
            or line.startswith("| acrobot |")] == ["| double_pendulum", "| acrobot"]
    for section in ("Per quantity:", "## Sampling coverage", "## Worst state per case", "## Timing",
                    "- tolerance per quantity: "):
        assert section in details and section not in summary, section
    assert details.startswith("# crosscheck gate report: details (summary: [gate.md](gate.md))")


def test_a_failing_gate_report_leads_with_the_failures(tmp_path, dropped_coriolis):
    code, summary, details = _gate_files(tmp_path)
    assert code == 1 and summary.splitlines()[2].startswith("**FAIL**")
    failures, rest = summary.split("- command: ")
    assert "## Disagreements" in failures and "reproduce: `crosscheck eval --case double_pendulum" in failures
    assert "outlier **euler_lagrange**" in failures and "## Cases" in rest and "## Disagreements" not in details


# -------------------------------------------------------------------------------------------------- --workers


def test_every_workers_option_has_one_meaning_and_one_default():
    """Each ``--workers`` (gate, simulators, fuzz, faults, trajectory --report) is ``options.add_workers_option``'s: default
    None, resolved by ``options.workers``, and the same help."""
    found = {name: _option(parser, "workers") for name, parser in _subcommands().items()}
    found = {name: action for name, action in found.items() if action is not None}
    assert set(found) == {"gate", "fuzz", "faults", "trajectory", "simulators"}
    for name, action in found.items():
        assert action.default is None and action.type is int, name
        assert action.help.startswith("0: run in this process; N >= 1: N worker processes, at most one per "), name
        assert "default: one per CPU, or this process when there is only one" in action.help, name


def test_workers_resolves_the_same_way_everywhere():
    cpus = os.cpu_count() or 1
    assert options.workers(None, 1) == 0                   # one case, one chunk: a pool would only add start-up
    assert options.workers(None, 21) == min(cpus, 21)
    assert options.workers(None, math.inf) == cpus
    assert options.workers(0, 21) == 0
    assert options.workers(1, 1) == 1                      # asked for a worker process: one, also for one case
    assert options.workers(2, 1) == 1                      # never more processes than units of work
    for bad in (-1, options.WORKERS_PER_CPU * cpus + 1):
        with pytest.raises(options.UsageError, match=r"--workers takes 0 to \d+ \(2 per CPU\) processes"):
            options.workers(bad, 5)


def test_gate_workers_1_is_one_worker_process(monkeypatch, tmp_path):
    """``gate --workers 1`` on one case runs it in a pool of one process (as ``fuzz --workers 1`` runs its chunks in
    one), ``--workers 0`` and the default for one case in this process. The pool is replaced by a recorder that
    runs the cases here, so the test spawns nothing."""
    from crosscheck.engine import pool

    pools = []

    def recorder(run_case, specs, backends, samples, seed, tell, checks, count, outcomes, *how_a_case_fails):
        pools.append(count)
        outcomes.extend(run_case(spec, backends, samples, seed, tell, checks) for spec in specs)

    monkeypatch.setattr(pool, "in_pool", recorder)
    argv = ["gate", "--case", "acrobot", "--samples", "1", "--frames", "0", "--no-charts", "--no-conservation",
            "--no-linearization", "--no-self-test", "--formalism", "newton_euler", "--formalism", "pinocchio",
            "--report", str(tmp_path / "gate.md")]
    for workers, expected in ((["--workers", "1"], [1]), (["--workers", "0"], []), ([], [])):
        pools.clear()
        assert cli.main([*argv, *workers]) == 0
        assert pools == expected, workers


def test_faults_in_worker_processes_give_the_same_report(tmp_path, capsys):
    """``faults --workers 1`` hunts the faults in one spawned process, each found there by name: the same hunts, lines
    and report as in this process, in catalog order (timings apart)."""
    argv = ["faults", "--fault", "osc-task-bias-dropped", "--fault", "geo-task-bias-dropped", "--samples", "3",
            "--sensitivity-states", "0", "--quiet"]
    texts, lines = [], []
    for workers in ("0", "1"):
        assert cli.main([*argv, "--workers", workers, "--report", str(tmp_path / "f.md")]) == 0
        lines.append(capsys.readouterr().out.splitlines()[:2])
        texts.append(re.sub(r"[0-9.]+ s\b", "T s", (tmp_path / "f.md").read_text()).replace(f"--workers {workers} ", ""))
    assert lines[0] == lines[1] and lines[0][0].startswith("caught osc-task-bias-dropped")
    assert texts[0] == texts[1] and "| `geo-task-bias-dropped` | geometric | yes |" in texts[1]


def test_fuzz_workers_share_out_the_chunks_of_its_shard():
    parse = cli.build_parser().parse_args
    assert cli.fuzz._fuzz_chunks(parse(["fuzz"])) == 10                  # 100 examples in chunks of 10
    assert cli.fuzz._fuzz_chunks(parse(["fuzz", "--examples", "25", "--shard", "1/2"])) == 1  # chunks 0, 1, 2: only 1
    assert cli.fuzz._fuzz_chunks(parse(["fuzz", "--examples", "5"])) == 1
    assert cli.fuzz._fuzz_chunks(parse(["fuzz", "--minutes", "1"])) == math.inf


def test_trajectory_workers_apply_to_the_report(capsys):
    assert cli.main(["trajectory", "--case", "double_pendulum", "--horizon", "0.1", "--workers", "0"]) == 2
    assert "--workers applies to --report" in capsys.readouterr().err
