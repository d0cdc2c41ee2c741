"""Every Python name the README and docs/ tell a user to use resolves: each dotted name of ours in backticks
(``crosscheck.gate.Step``, ``cases.build.with_task_point``), each ``module:object`` (``crosscheck.cli:main``), each
``python -m MODULE`` and each ``from X import a, b`` of a code block. A module moved or a name renamed without the docs
following fails here, naming the page and the name.
"""

from __future__ import annotations

import importlib
import importlib.util
import re
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[2]
PAGES = [ROOT / "README.md", *sorted((ROOT / "docs").glob("*.md"))]
OURS = ("crosscheck", "cases", "formalisms")

#: Dotted names of ours that the docs use and that are not Python objects, with why.
NOT_OBJECTS = {
    "crosscheck.formalisms": "the entry-point group plugins register under (pyproject.toml), not a module",
}

DOTTED = re.compile(r"`(?:python -m )?((?:%s)(?:\.[A-Za-z_][A-Za-z_0-9]*)+)(?::([A-Za-z_][A-Za-z_0-9]*))?"
                    % "|".join(OURS))
FROM_IMPORT = re.compile(r"^\s*from ((?:%s)(?:\.[A-Za-z_0-9]+)*) import ([A-Za-z_0-9, ]+?)\s*(?:#.*)?$"
                         % "|".join(OURS))
PYTHON_M = re.compile(r"python3? -m ((?:%s)(?:\.[A-Za-z_0-9]+)*)" % "|".join(OURS))


def _resolve(dotted: str):
    """The object ``dotted`` names: the longest importable module prefix, then attributes."""
    parts = dotted.split(".")
    for k in range(len(parts), 0, -1):
        try:
            obj = importlib.import_module(".".join(parts[:k]))
        except ModuleNotFoundError:
            continue
        for attr in parts[k:]:
            obj = getattr(obj, attr)
        return obj
    raise ModuleNotFoundError(dotted)


def _documented() -> list[tuple[str, str]]:
    """(page, name) for every name of ours the pages use: ``module.attr``, ``module:object`` or ``from``-imports."""
    found = []
    for page in PAGES:
        for line in page.read_text().splitlines():
            for dotted, obj in DOTTED.findall(line):
                if dotted not in NOT_OBJECTS:
                    found.append((page.name, f"{dotted}.{obj}" if obj else dotted))
            if m := FROM_IMPORT.match(line):
                found += [(page.name, f"{m.group(1)}.{name.split(' as ')[0].strip()}") for name in m.group(2).split(",")]
    return sorted(set(found))


#: The import paths the README and docs/ promise to keep whatever moves inside the package (docs/design.md,
#: "Architecture"), besides those the pages name.
PROMISED = ["crosscheck.assemble.unconstrained_split", "crosscheck.assemble.Sizes", "crosscheck.needs.NEEDS",
            "crosscheck.backends.register", "crosscheck.backends.get", "crosscheck.testing.models",
            "crosscheck.gate.run_gate", "crosscheck.gate.CaseSpec", "crosscheck.gate.Checks", "crosscheck.gate.Step",
            "crosscheck.gate.Interrupted", "crosscheck.cli.main"]


def test_the_docs_name_python_objects():
    assert len(_documented()) > 30


@pytest.mark.parametrize("name", PROMISED)
def test_the_promised_import_paths_resolve(name):
    _resolve(name)


def test_the_console_script_and_the_plugin_group_are_declared():
    text = (ROOT / "pyproject.toml").read_text()
    assert 'crosscheck = "crosscheck.cli:main"' in text
    assert _resolve("crosscheck.backends.ENTRY_POINT_GROUP") == "crosscheck.formalisms"


@pytest.mark.parametrize("page,name", _documented())
def test_every_documented_name_resolves(page, name):
    try:
        _resolve(name)
    except (ImportError, AttributeError) as exc:
        pytest.fail(f"{page} names {name}, which does not resolve: {exc}")


@pytest.mark.parametrize("page,module", sorted({(p.name, m) for p in PAGES for m in PYTHON_M.findall(p.read_text())}))
def test_every_documented_python_m_module_runs_as_main(page, module):
    spec = importlib.util.find_spec(module)
    assert spec is not None, f"{page}: python -m {module}: no such module"
    if spec.submodule_search_locations is not None:        # a package runs its __main__
        assert importlib.util.find_spec(f"{module}.__main__") is not None, f"{page}: python -m {module}: no __main__"
    else:
        assert "__main__" in Path(spec.origin).read_text(), f"{page}: python -m {module} does nothing as a script"
