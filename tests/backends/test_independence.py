"""Independence is the product (docs/design.md): a formalism never imports Pinocchio, the harness, or another formalism,
and shares no numerics with the others.

Every module under ``formalisms/`` except the package ``__init__`` (the lazy registry) and ``interface.py`` is
read with ``ast`` (never imported, so nothing it would import is loaded) and every import is checked against an
allow-list: the standard library, the numeric libraries below, ``formalisms.interface``, the model language
(``cases.model``, ``cases.constraints``, ``cases.loads``: declarations each backend maps itself), and a formalism's own
sub-modules when it is a package. A new dependency must be added here, with a reason. From ``formalisms.interface`` a
formalism may use only the names in :data:`INTERFACE` (types, constants, validators, exceptions: imported, or read as
attributes of the module), and ``interface.py`` itself defines nothing else but ``split_batch_by_loop`` (a loop for
plugins) and ``block_form`` (the harness's look-up of a block form): a power, a constraint force, a factorization, a
rank decision, a conditioning or a task inertia computed there once for every backend would be compared bit-identically
and prove nothing. Dynamic imports (``importlib.import_module``, ``__import__``) are checked the same way when their
argument is a string literal, and refused when it is not (they could load anything).
"""

from __future__ import annotations

import ast
import subprocess
import sys
from pathlib import Path

import pytest

import formalisms

ROOT = Path(__file__).resolve().parents[2]
PACKAGE_DIR = ROOT / "formalisms"
SHARED = {"formalisms/__init__.py", "formalisms/interface.py", "formalisms/cache.py"}

# third-party libraries a formalism may use: numerics and symbolics only
THIRD_PARTY = {"numpy", "scipy", "sympy", "symengine", "casadi"}
# project modules a formalism may use: the model types and the shared interface
PROJECT = {"formalisms.interface", "cases.model", "cases.constraints", "cases.loads",
           "cases.world"}  # which data place a model in the world (model language, no numerics)
# what a formalism may take from formalisms.interface: types, constants, validators and exceptions, nothing numeric
INTERFACE = {"CONSTRAINT_RCOND", "DEGENERATE_ROW", "UNSUPPORTED", "Unsupported", "Chart", "Formalism",
             "ModelNotSupported", "Split", "SplitBatch", "StateError", "chart_vectors", "check_batch", "check_state",
             "joint_vectors", "with_block_form",
             # disk-cache plumbing: where a backend keeps its derivations, no numerics
             "cache_dir", "write_cache_file", "used_cache_file",
             # the linearization's type and its kinematic rows: the group convention (no dynamics), held against the
             # flow of cases.configuration.integrate by tests/checks/test_linearize.py, outside the vote
             "Linearization", "state_space", "tangent_kinematics"}
# roots that are never allowed (named for a clear message; the allow-list would refuse them anyway)
FORBIDDEN = {"pinocchio": "the external reference (Pinocchio) is kept apart from the five formalisms",
             "pin": "the external reference (Pinocchio) is kept apart from the five formalisms",
             "crosscheck": "a formalism must not depend on the harness"}
STDLIB = set(sys.stdlib_module_names)
PROJECT_ROOTS = {"formalisms", "cases", "crosscheck", "tests"}


def module_name(path: Path) -> tuple[str, bool]:
    """Dotted module name of a file under ROOT and whether it is a package ``__init__``."""
    parts = list(path.relative_to(ROOT).with_suffix("").parts)
    is_package = parts[-1] == "__init__"
    if is_package:
        parts = parts[:-1]
    return ".".join(parts), is_package


def _resolve_relative(module: str, is_package: bool, level: int, target: str | None) -> str | None:
    """Absolute name of ``from <level dots><target> import ...`` inside ``module`` (None if it leaves the tree)."""
    package = module.split(".") if is_package else module.split(".")[:-1]
    if level - 1 > len(package) - 1:
        return None
    base = package[: len(package) - (level - 1)]
    return ".".join(base + ([target] if target else []))


def _check_name(name: str, own_unit: str) -> str | None:
    """Why the absolute module ``name`` may not be imported by formalism ``own_unit`` (None when allowed)."""
    root = name.split(".")[0]
    if root in FORBIDDEN:
        return FORBIDDEN[root]
    if root == "formalisms":
        if name == "formalisms":
            return "the formalisms package itself is the registry, which imports every formalism"
        if any(name == p or name.startswith(p + ".") for p in PROJECT):
            return None
        unit = ".".join(name.split(".")[:2])
        if unit == own_unit:
            return None  # a formalism package's own sub-module
        return (f"{name} is another formalism or the registry: a cross-check between implementations that "
                "share code checks nothing")
    if root in PROJECT_ROOTS:
        if any(name == p or name.startswith(p + ".") for p in PROJECT):
            return None
        return f"project module {name} is not on the allow-list {sorted(PROJECT)}"
    if root in THIRD_PARTY or root in STDLIB:
        return None
    return f"'{root}' is not on the allow-list (stdlib, {sorted(THIRD_PARTY)}); add it here with a reason"


def _interface_name(name: str, lineno: int, module: str) -> list[str]:
    if name in INTERFACE:
        return []
    return [f"{module}:{lineno}: uses formalisms.interface.{name}, which is not on the allow-list {sorted(INTERFACE)}: "
            "a formalism computes every number it reports itself"]


def interface_violations(tree: ast.AST, module: str, is_package: bool) -> list[str]:
    """Names taken from ``formalisms.interface`` that are not in :data:`INTERFACE`: imported from it, or read as
    attributes of a name the module bound to it (``from formalisms import interface``, ``import formalisms.interface
    as fi``)."""
    problems, aliases = [], set()
    for node in ast.walk(tree):
        if isinstance(node, ast.ImportFrom):
            base = node.module if node.level == 0 else _resolve_relative(module, is_package, node.level, node.module)
            for alias in node.names:
                if base == "formalisms.interface":
                    problems += _interface_name(alias.name, node.lineno, module)
                elif base == "formalisms" and alias.name == "interface":
                    aliases.add(alias.asname or alias.name)
        elif isinstance(node, ast.Import):
            aliases.update(alias.asname for alias in node.names
                           if alias.name == "formalisms.interface" and alias.asname)
    for node in ast.walk(tree):
        if isinstance(node, ast.Attribute) and isinstance(node.value, ast.Name) and node.value.id in aliases:
            problems += _interface_name(node.attr, node.lineno, module)
    return problems


def import_violations(source: str, module: str, is_package: bool = False) -> list[str]:
    """Every disallowed import in ``source`` (the text of ``module``), one message each with its line, and every
    name it takes from ``formalisms.interface`` outside :data:`INTERFACE`."""
    tree = ast.parse(source)
    own_unit = ".".join(module.split(".")[:2])
    problems: list[str] = interface_violations(tree, module, is_package)

    def check(lineno: int, name: str | None, statement: str) -> None:
        why = "it reaches outside the project tree" if name is None else _check_name(name, own_unit)
        if why:
            problems.append(f"{module}:{lineno}: `{statement}` imports {name}: {why}")

    for node in ast.walk(tree):
        if isinstance(node, ast.Import):
            for alias in node.names:
                check(node.lineno, alias.name, f"import {alias.name}")
        elif isinstance(node, ast.ImportFrom):
            text = f"from {'.' * node.level}{node.module or ''} import {', '.join(a.name for a in node.names)}"
            base = node.module if node.level == 0 else _resolve_relative(module, is_package, node.level, node.module)
            if base == "__future__":
                continue
            if base is None or base.split(".")[0] not in PROJECT_ROOTS:
                check(node.lineno, base, text)
                continue
            # inside the project, `from pkg import x` binds the sub-module pkg.x or an attribute of pkg: judge
            # pkg.x (so `from formalisms import interface` passes and `from formalisms import get`, which is the
            # registry, does not); a star import takes all of pkg
            for alias in node.names:
                check(node.lineno, base if alias.name == "*" else f"{base}.{alias.name}", text)
        elif isinstance(node, ast.Call):
            func = node.func
            called = func.attr if isinstance(func, ast.Attribute) else func.id if isinstance(func, ast.Name) else None
            if called in {"import_module", "__import__"}:
                arg = node.args[0] if node.args else None
                anchor = node.args[1] if len(node.args) > 1 else None
                if isinstance(arg, ast.Constant) and isinstance(arg.value, str):
                    name = arg.value
                    if name.startswith("."):  # relative to the `package` argument: resolve it when literal
                        level = len(name) - len(name.lstrip("."))
                        if isinstance(anchor, ast.Constant) and isinstance(anchor.value, str):
                            name = _resolve_relative(anchor.value, True, level, name.lstrip(".") or None)
                        else:
                            name = None
                    check(node.lineno, name, f"{called}({arg.value!r})")
                else:
                    problems.append(f"{module}:{node.lineno}: `{called}(...)` with a computed name: a dynamic "
                                    "import cannot be checked; import statically")
    return problems


def formalism_files() -> list[Path]:
    return sorted(p for p in PACKAGE_DIR.rglob("*.py")
                  if p.relative_to(ROOT).as_posix() not in SHARED and "__pycache__" not in p.parts)


FILES = formalism_files()


def test_the_formalism_modules_are_found():
    """The check below runs over every registered formalism (an empty list would check nothing)."""
    checked = {module_name(p)[0] for p in FILES}
    for name in formalisms.names():
        module = formalisms.get(name).split.__module__
        assert module in checked, f"formalism '{name}' lives in {module}, which the independence test does not read"


@pytest.mark.parametrize("path", FILES, ids=lambda p: p.relative_to(ROOT).as_posix())
def test_formalism_imports_only_allowed_modules(path):
    module, is_package = module_name(path)
    problems = import_violations(path.read_text(), module, is_package)
    assert not problems, "\n".join(problems)


def test_importing_a_formalism_loads_no_reference_harness_or_sibling():
    """The runtime complement of the static check (transitive imports too, e.g. through ``cases``): import each
    registered formalism alone in a fresh interpreter and list what got loaded. The unit is
    ``formalisms.<name>``: a package formalism may load its own sub-modules, wherever ``split`` lives."""
    modules = sorted({".".join(formalisms.get(name).split.__module__.split(".")[:2]) for name in formalisms.names()})
    for module in modules:
        code = ("import importlib, sys; importlib.import_module(%r); "
                "print('\\n'.join(sorted(sys.modules)))" % module)
        out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True, cwd=ROOT)
        loaded = set(out.stdout.split())
        assert module in loaded
        bad = sorted(m for m in loaded if m.split(".")[0] in {"pinocchio", "crosscheck"}
                     or (m.startswith("formalisms.") and m not in ("formalisms.interface", "formalisms.cache")
                         and not (m == module or m.startswith(module + "."))))
        assert not bad, f"importing {module} loaded {bad}"


# ------------------------------------------------------------------------------- the checker can fail

BAD = [
    "import pinocchio",
    "import pinocchio as pin",
    "import pinocchio.utils",
    "from pinocchio import aba",
    "from pinocchio.utils import zero",
    "def f():\n    import pinocchio as pin\n    return pin",
    "try:\n    import pinocchio\nexcept ImportError:\n    pinocchio = None",
    "import crosscheck",
    "import crosscheck.references.pinocchio.reference",
    "from crosscheck import reference",
    "from crosscheck.references.pinocchio.reference import split",
    "from formalisms.newton_euler import split",
    "import formalisms.newton_euler",
    "import formalisms.newton_euler as ne",
    "from formalisms import newton_euler",
    "from formalisms import get",
    "from formalisms import *",
    "import formalisms",
    "from . import newton_euler",
    "from . import interface, newton_euler",
    "from .newton_euler import split",
    "from .newton_euler.kinematics import forward",
    "from .. import crosscheck",
    "from ..crosscheck import reference",
    "from ... import anything",
    "from cases import Body",
    "import cases",
    "from cases.urdf import from_urdf",
    "import requests",
    "import torch",
    "import importlib\nimportlib.import_module('pinocchio')",
    "from importlib import import_module\nimport_module('formalisms.newton_euler')",
    "import importlib\nimportlib.import_module('.newton_euler', 'formalisms')",
    "pin = __import__('pinocchio')",
    "from formalisms.interface import conditioning",
    "from formalisms.interface import Split, constrained_split",
    "from .interface import task_space_inertia",
    "from formalisms import interface\ninterface.redundant_below(1, 2)",
    "import formalisms.interface as fi\nfi.factor_mass_matrix(1)",
    "import importlib\nname = 'pin' + 'occhio'\nimportlib.import_module(name)",
]

def test_the_interface_defines_only_the_allowed_names():
    """``interface.py`` holds types, constants, validators and exceptions (and a loop for plugins), nothing numeric a
    backend could share: every public name it defines is on the allow-list."""
    tree = ast.parse((PACKAGE_DIR / "interface.py").read_text())
    defined = {node.name for node in tree.body if isinstance(node, (ast.FunctionDef, ast.ClassDef))}
    defined |= {t.id for node in tree.body if isinstance(node, ast.Assign) for t in node.targets
                if isinstance(t, ast.Name)}
    public = {name for name in defined if not name.startswith("_")} - {"__all__"}
    assert public <= INTERFACE | {"split_batch_by_loop", "block_form"}, sorted(public - INTERFACE)


GOOD = [
    "from __future__ import annotations",
    "import math",
    "import functools, hashlib, os, tempfile",
    "from pathlib import Path",
    "import numpy as np",
    "import scipy.linalg",
    "from scipy.spatial.transform import Rotation",
    "import sympy",
    "import symengine as sp",
    "import casadi as ca",
    "from formalisms.interface import Formalism, Split, check_state",
    "from formalisms.interface import CONSTRAINT_RCOND, DEGENERATE_ROW, SplitBatch, check_batch",
    "from formalisms import interface\ninterface.check_state(1, 2, 3, 4)",
    "import formalisms.interface",
    "from formalisms import interface",
    "from . import interface",
    "from .interface import UNSUPPORTED",
    "from cases.model import Model",
    "from cases import model",
    "import cases.model",
]


@pytest.mark.parametrize("source", BAD)
def test_checker_flags_forbidden_imports(source):
    problems = import_violations(source, "formalisms.synthetic")
    assert problems, f"the checker let this through:\n{source}"


@pytest.mark.parametrize("source", GOOD)
def test_checker_accepts_allowed_imports(source):
    assert import_violations(source, "formalisms.synthetic") == []


def test_a_formalism_package_may_import_its_own_submodules_only():
    # formalisms/screw/dynamics.py importing formalisms/screw/kinematics.py: same formalism, allowed
    assert import_violations("from . import kinematics", "formalisms.screw.dynamics") == []
    assert import_violations("from .kinematics import twist", "formalisms.screw.dynamics") == []
    assert import_violations("from formalisms.screw import kinematics", "formalisms.screw.dynamics") == []
    assert import_violations("from . import kinematics", "formalisms.screw", is_package=True) == []
    # ... but not a sibling formalism, however spelled
    assert import_violations("from .. import newton_euler", "formalisms.screw.dynamics")
    assert import_violations("from ..newton_euler import split", "formalisms.screw.dynamics")
    assert import_violations("from .. import interface", "formalisms.screw.dynamics") == []


def test_messages_name_the_module_line_and_reason():
    (msg,) = import_violations("import numpy\n\nimport pinocchio as pin\n", "formalisms.synthetic")
    assert msg.startswith("formalisms.synthetic:3:") and "pinocchio" in msg and "reference" in msg
