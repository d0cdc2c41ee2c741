"""The harness's layers (docs/design.md, "Architecture"): no import cycle among the modules of ``cases`` and
``crosscheck``, and a module imports only its own layer or those below it, imports inside functions included. The
imports are read with ``ast``, nothing is imported; the checker is run on made-up graphs too, so that it can fail.
"""

from __future__ import annotations

import ast
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]

#: Each package or module of the harness and its layer, lowest first (the longest matching prefix counts).
LAYER = {
    "crosscheck": 0,                     # the package itself: the worker marker
    "crosscheck.references": 1, "crosscheck.backends": 1, "crosscheck.needs": 1,
    "crosscheck.isolation": 1,
    "crosscheck.core": 2,
    "crosscheck.checks": 3, "crosscheck.guards": 3,
    "crosscheck.engine": 4, "crosscheck.guards.selftest": 4, "crosscheck.assemble": 4,
    "crosscheck.gate": 5, "crosscheck.testing": 5, "crosscheck.adapters": 5,
    "crosscheck.faults": 6, "crosscheck.campaigns": 6, "crosscheck.reports": 6,
    "crosscheck.cli": 7, "crosscheck.bench_report": 7,
}
#: Imports from a layer above, each with its reason (docs/design.md, "Architecture").
UPWARD = {
    ("crosscheck.references.precise", "crosscheck.checks.charts"):
        "the 50-digit reference evaluates the ZYX chart exactly, to judge the chart checks",
    ("crosscheck.references.precise", "crosscheck.guards.conditioning"):
        "the 50-digit reference drops redundant rows by the harness's statement of the backends' rule",
}


def _module(path: Path) -> str:
    parts = list(path.relative_to(ROOT).with_suffix("").parts)
    return ".".join(parts[:-1] if parts[-1] == "__init__" else parts)


def _modules() -> dict[str, Path]:
    return {_module(p): p for top in ("cases", "crosscheck") for p in (ROOT / top).rglob("*.py")}


def _imports(path: Path, known: set[str]) -> set[str]:
    """The modules of ``known`` that ``path`` imports anywhere in it (``from pkg import module`` names the module)."""
    found = set()
    for node in ast.walk(ast.parse(path.read_text())):
        if isinstance(node, ast.Import):
            found |= {a.name for a in node.names if a.name in known}
        elif isinstance(node, ast.ImportFrom) and node.module and not node.level:
            for a in node.names:
                sub = f"{node.module}.{a.name}"
                found.add(sub if sub in known else node.module)
    return found & known


def _graph() -> dict[str, set[str]]:
    modules = _modules()
    return {name: _imports(path, set(modules)) - {name} for name, path in modules.items()}


def _cycles(graph: dict[str, set[str]]) -> list[list[str]]:
    """The strongly connected components of more than one module (Tarjan)."""
    index, low, stack, on, out = {}, {}, [], set(), []

    def visit(v):
        index[v] = low[v] = len(index)
        stack.append(v)
        on.add(v)
        for w in graph.get(v, ()):
            if w not in index:
                visit(w)
                low[v] = min(low[v], low[w])
            elif w in on:
                low[v] = min(low[v], index[w])
        if low[v] == index[v]:
            component = []
            while True:
                w = stack.pop()
                on.discard(w)
                component.append(w)
                if w == v:
                    break
            if len(component) > 1:
                out.append(sorted(component))

    for v in sorted(graph):
        if v not in index:
            visit(v)
    return out


def _layer(module: str) -> int | None:
    keys = [k for k in LAYER if module == k or module.startswith(k + ".")]
    return LAYER[max(keys, key=len)] if keys else None


def _upward(graph: dict[str, set[str]]) -> list[str]:
    """Every import of a module from a layer above its own, not listed in :data:`UPWARD`."""
    out = []
    for src, targets in graph.items():
        for tgt in targets:
            ls, lt = _layer(src), _layer(tgt)
            if ls is None or lt is None or lt <= ls:
                continue
            if not any(src.startswith(a) and tgt.startswith(b) for a, b in UPWARD):
                out.append(f"{src} (layer {ls}) imports {tgt} (layer {lt})")
    return sorted(out)


def test_no_import_cycle():
    assert _cycles(_graph()) == []


def test_every_module_of_the_harness_has_a_layer():
    assert [m for m in _graph() if m.startswith("crosscheck") and _layer(m) is None] == []


def test_no_module_imports_from_a_layer_above():
    assert _upward(_graph()) == []


def test_the_model_language_imports_no_harness():
    assert [(s, t) for s, ts in _graph().items() if s.startswith("cases") for t in ts if t.startswith("crosscheck")] == []


@pytest.mark.parametrize("graph,cycles", [
    ({"a": {"b"}, "b": {"a"}, "c": set()}, [["a", "b"]]),
    ({"a": {"b"}, "b": {"c"}, "c": {"a"}}, [["a", "b", "c"]]),
    ({"a": {"b"}, "b": set()}, []),
])
def test_the_cycle_finder_finds_cycles(graph, cycles):
    assert _cycles(graph) == cycles


def test_the_layer_rule_can_fail():
    assert _upward({"crosscheck.core.sampling": {"crosscheck.engine.run"}}) == [
        "crosscheck.core.sampling (layer 2) imports crosscheck.engine.run (layer 4)"]
    assert _upward({"crosscheck.engine.run": {"crosscheck.core.sampling"}}) == []
