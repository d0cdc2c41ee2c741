"""The README and docs/ say only what runs: every ``crosscheck`` command in them is parsed by the command line's own
parser (a renamed or removed flag fails here), the cheap ones are run as written, the README's two examples are run
in full in a scratch directory (they must pass and write nothing but ``crosscheck-out/``), and every link to a local
file or heading resolves.

The README's two set-up commands (a fresh virtual environment, ``pip install``) are run by CI itself (``.ci/run``
runs the test command as written in the README); here only their ``crosscheck`` part is parsed.
"""

from __future__ import annotations

import argparse
import os
import re
import shlex
import subprocess
import sys
from pathlib import Path

import pytest

from crosscheck.cli import build_parser, main

ROOT = Path(__file__).resolve().parents[2]
PAGES = [ROOT / "README.md", *sorted((ROOT / "docs").glob("*.md"))]

#: The README's two examples: run in full (each ~10 s), as written, in a scratch copy of the files they read.
EXAMPLES = [
    "crosscheck gate --model examples/arm.urdf",
    "crosscheck gate --model examples/arm.urdf --plugin examples/my_dynamics.py:MY_DYNAMICS",
]
EXAMPLE_FILES = ["examples/arm.urdf", "examples/my_dynamics.py"]

#: Commands cheap enough to run as written here (in-process, in a scratch directory): at most a few seconds each.
RUN = [
    "crosscheck --version",
    "crosscheck cases",
    "crosscheck formalisms",
    "crosscheck faults --list",
    "crosscheck eval --case double_pendulum --q=0.785,0.524 --qd=2,-1 --u=5,-2",
    "crosscheck eval --case double_pendulum --q=0.785,0.524 --qd=2,-1 --u=5,-2 --json --formalism newton_euler",
    "crosscheck eval --case cartesian_pendulum --q=0.6,-0.8 --qd=0.8,0.6 --u=1,0",
    "crosscheck eval --case free_body --q=0,0,0,0,0,0,1 --qd=0,0,0,1,2,3",
    "crosscheck eval --case free_body --chart zyx --q=0,0,0,0.1,0.2,0.3 --qd=0,0,0,1,2,3",
    "crosscheck eval --case four_bar --q=1,0.5,1 --qd=1,0,0 --project",
    "crosscheck eval --case double_pendulum --q=0.3,0.2 --qd=1,-1 --linearize",
    "crosscheck eval --case double_pendulum --q=0,0 --linearize --json",
]

#: Every other command is only parsed; the first rule whose prefix matches says why it is not run here.
PARSE_ONLY = [
    ("crosscheck gate --plugin mypkg", "a placeholder plugin package (mypkg) the reader supplies"),
    ("crosscheck gate --plugin path/to", "a placeholder path the reader supplies"),
    ("crosscheck gate --plugin crosscheck.adapters", "a simulator on a robot file of the reader's"),
    ("crosscheck gate --simulator", "a simulator on a robot file of the reader's"),
    ("crosscheck simulators", "every installed simulator on a robot file: tens of seconds to minutes"),
    ("crosscheck gate --plugin closed_form_pendulum", "runs in examples/closed_form_plugin, where its module is found"),
    ("crosscheck gate --model path/to", "a placeholder path the reader supplies"),
    ("crosscheck gate --model robot.urdf", "a placeholder path the reader supplies"),
    ("crosscheck gate", "all built-in cases (about a minute on 2 cores), or Panda or a 12-link chain, 100-500 states"),
    ("crosscheck faults", "the whole catalog took 755 s (docs/faults.md); a named fault hunts the gate's states"),
    ("crosscheck fuzz", "a campaign: minutes to hours"),
    ("crosscheck replay", "needs a finding of a campaign (ID)"),
    ("crosscheck merge", "needs the directories of a sharded campaign"),
    ("crosscheck reports", "rewrites the committed reports/; the faults alone take about 13 minutes"),
    ("crosscheck bench", "measures speed: about 30 s (--quick), 5 minutes (full), 10 minutes (--scale)"),
    ("crosscheck stability", "six paths against a 50-digit reference: part of the full bench's minutes"),
    ("crosscheck trajectory", "a 50-digit reference trajectory: 20 s for a 2 s horizon, more for --report"),
]

def _strip_comments(text: str) -> str:
    """The page without HTML comments (notes for maintainers, not commands)."""
    return re.sub(r"<!--.*?-->", "", text, flags=re.S)


def _code_lines(text: str):
    """Lines of fenced blocks (``sh``, ``console`` or no language) and of indented code blocks."""
    fence, lang, prev_blank = None, "", True
    for line in text.splitlines():
        if fence is None and line.lstrip().startswith("```"):
            fence, lang, block = line.strip()[:3], line.strip()[3:].strip(), []
            continue
        if fence is not None:
            if line.strip().startswith(fence):
                fence = None
                yield from _yaml_runs(block) if lang == "yaml" else ()
            elif lang in ("", "sh", "bash", "console", "shell"):
                yield line.strip()
            block.append(line)
            continue
        if line.startswith("    ") and not line.lstrip().startswith(("-", "*", "|")) and prev_blank:
            yield line.strip()
            continue
        prev_blank = not line.strip()


def _yaml_runs(block: list[str]):
    """The shell lines of a CI workflow's ``run:`` steps, a folded ``run: >`` joined into one line."""
    i = 0
    while i < len(block):
        m = re.match(r"(\s*)(?:- )?run: (.*)$", block[i])
        i += 1
        if not m:
            continue
        if m.group(2).strip() not in (">", "|"):
            yield m.group(2).strip()
            continue
        folded = []
        while i < len(block) and len(block[i]) - len(block[i].lstrip()) > len(m.group(1)) and block[i].strip():
            folded.append(block[i].strip())
            i += 1
        yield from [" ".join(folded)] if m.group(2).strip() == ">" else folded


def _commands_in(line: str):
    """The ``crosscheck`` commands of a shell line (each part of ``a && b``), without trailing comments."""
    for part in line.split("&&"):
        if part.split()[:1] == ["crosscheck"]:
            yield " ".join(shlex.quote(w) for w in shlex.split(part, comments=True))


def documented() -> tuple[dict[str, str], dict[str, str]]:
    """Every command in the code blocks of the README and docs/, and every inline span naming one -> its page."""
    commands, spans = {}, {}
    for page in PAGES:
        text = _strip_comments(page.read_text())
        for line in _code_lines(text):
            for command in _commands_in(line):
                commands.setdefault(command, page.name)
        for span in re.findall(r"`(crosscheck(?: [^`]*)?)`", text):
            spans.setdefault(span, page.name)
    return commands, spans


COMMANDS, SPANS = documented()


def _subcommands(parser: argparse.ArgumentParser) -> dict:
    (sub,) = [a for a in parser._actions if isinstance(a, argparse._SubParsersAction)]
    return sub.choices


def strict_parser() -> argparse.ArgumentParser:
    """The command line's parser, refusing abbreviated options (``--example`` for ``--examples``), so that a
    documented option must be spelt as the parser spells it."""
    parser = build_parser()
    for p in (parser, *_subcommands(parser).values()):
        p.allow_abbrev = False
    return parser


@pytest.mark.parametrize("span", sorted(SPANS))
def test_every_command_named_in_prose_has_those_options(span):
    """Inline code spans name commands in prose, often as fragments (``crosscheck eval --chart NAME``): each option
    they name must exist in that subcommand's parser."""
    words = span.split()
    if len(words) == 1 or words[1].startswith("-"):
        assert all(w in build_parser()._option_string_actions for w in words[1:]), f"{SPANS[span]}: `{span}`"
        return
    subcommands = _subcommands(build_parser())
    assert words[1] in subcommands, f"{SPANS[span]}: `{span}`: no subcommand {words[1]!r}"
    options = subcommands[words[1]]._option_string_actions
    for word in words[2:]:
        if word.startswith("--"):
            assert word.split("=")[0] in options, f"{SPANS[span]}: `{span}`: {words[1]} has no option {word}"


def test_the_docs_have_commands_and_the_run_lists_are_documented():
    assert len(COMMANDS) > 40 and len(SPANS) > 20
    for command in EXAMPLES + RUN:
        assert command in COMMANDS, f"{command!r} is not in the README or docs/ any more"


@pytest.mark.parametrize("command", sorted(COMMANDS))
def test_every_documented_command_parses(command):
    words = shlex.split(command)[1:]
    if words == ["--version"]:
        return                  # argparse's version action prints and exits 0; it is run below
    try:
        args = strict_parser().parse_args(words)
    except SystemExit as exc:
        pytest.fail(f"{COMMANDS[command]}: `{command}` is refused by the command line's parser (exit {exc.code})")
    assert callable(args.run)
    if command not in EXAMPLES + RUN:
        assert any(command.startswith(prefix) for prefix, _ in PARSE_ONLY), f"{command}: neither run nor parse-only"


@pytest.mark.parametrize("command", RUN)
def test_cheap_commands_run_as_written(command, tmp_path, monkeypatch, capsys):
    monkeypatch.chdir(tmp_path)
    try:
        code = main(shlex.split(command)[1:])
    except SystemExit as exc:       # --version
        code = exc.code
    out = capsys.readouterr().out
    assert code == 0, out
    assert out.strip()
    if command.startswith("crosscheck eval"):
        assert ('"unsupported_quantities"' in out) if "--json" in command else ("verdict: " in out)
    assert not list(tmp_path.iterdir()), "a command that writes no report wrote files"


@pytest.mark.parametrize("command", EXAMPLES)
def test_readme_examples_pass_and_write_only_crosscheck_out(command, tmp_path):
    for name in EXAMPLE_FILES:
        (tmp_path / name).parent.mkdir(parents=True, exist_ok=True)
        (tmp_path / name).write_bytes((ROOT / name).read_bytes())
    before = {p for p in tmp_path.rglob("*")}
    env = {**os.environ, "PYTHONPATH": os.pathsep.join([str(ROOT), os.environ.get("PYTHONPATH", "")])}
    run = subprocess.run([sys.executable, "-m", "crosscheck.cli", *shlex.split(command)[1:]], cwd=tmp_path, env=env,
                         capture_output=True, text=True, timeout=300)
    assert run.returncode == 0, run.stdout + run.stderr
    assert "PASS" in run.stdout
    if "--plugin" in command:
        assert "my_dynamics" in (tmp_path / "crosscheck-out" / "gate.md").read_text()
    written = {p.relative_to(tmp_path) for p in set(tmp_path.rglob("*")) - before}
    outside = sorted(str(p) for p in written if p.parts[0] != "crosscheck-out")
    assert not outside, f"the example wrote outside crosscheck-out/: {outside}"
    assert Path("crosscheck-out/gate.md") in written


def _slug(heading: str) -> str:
    """GitHub's anchor of a heading: lower case, punctuation but '-' and '_' dropped, spaces as '-'."""
    text = re.sub(r"[`*]", "", heading.strip().lower())
    return re.sub(r"[^\w\- ]", "", text).replace(" ", "-")


def _anchors(page: Path) -> set[str]:
    return {_slug(m) for m in re.findall(r"^#+ (.+)$", page.read_text(), flags=re.M)}


@pytest.mark.parametrize("page", PAGES, ids=lambda p: p.name)
def test_local_links_resolve(page):
    text = _strip_comments(page.read_text())
    links = re.findall(r"\]\(([^)\s]+)\)", text)
    for link in links:
        if re.match(r"[a-z]+:", link):
            continue
        path, _, anchor = link.partition("#")
        target = (page.parent / path).resolve() if path else page
        assert target.exists(), f"{page.name}: link to {link}: no such file"
        if anchor:
            assert anchor in _anchors(target), f"{page.name}: link to {link}: no such heading in {target.name}"


def test_every_docs_page_is_linked_from_the_readme():
    readme = (ROOT / "README.md").read_text()
    for page in PAGES[1:]:
        assert f"](docs/{page.name})" in readme, f"docs/{page.name} is not linked from the README"


def test_docs_cite_no_path_outside_the_repository():
    for page in PAGES:
        assert "../shared" not in page.read_text(), page.name


def test_readme_plugin_excerpt_is_the_example_file():
    """The README shows the heart of ``examples/my_dynamics.py`` (elisions as ``...``): every line it shows is there."""
    readme = (ROOT / "README.md").read_text()
    (excerpt,) = re.findall(r"```python\n(.*?)```", readme, flags=re.S)
    source = (ROOT / "examples" / "my_dynamics.py").read_text().splitlines()
    shown = [line for line in excerpt.splitlines() if line.strip() and line.strip() != "..."]
    assert len(shown) > 10
    missing = [line for line in shown if line.rstrip() not in source]
    assert not missing, f"README lines not in examples/my_dynamics.py: {missing}"
