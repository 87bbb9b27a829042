"""The layering holds: each package imports only the packages below it.

``LAYERS`` is the table of docs/architecture.md: a package may import the
packages it lists (and ``common``), nothing else. Imports under
``if TYPE_CHECKING:`` are annotations only and do not count. The table itself
must have no cycle, and the engines are checked once more in a fresh
interpreter, so that a module reaching a higher layer through another one is
caught too.
"""

from __future__ import annotations

import ast
import subprocess
import sys
from pathlib import Path

import networkx as nx
import pytest

ROOT = Path(__file__).resolve().parents[1]
PACKAGE = ROOT / "lesmc"

LAYERS: dict[str, set[str]] = {
    "common": set(),
    "language": set(),
    "video": set(),
    "schemas": {"designs"},
    "designs": set(),
    "model": {"language"},
    "scene": {"designs", "language"},
    "engines": {"language", "model"},
    "export": {"engines", "language", "model"},
    "perception": {"scene", "video"},
    "tracking": {"model", "scene"},
    "build": {"designs", "model", "scene", "tracking"},
    "results": {"designs", "engines", "language", "model", "scene", "schemas"},
    "pipeline": {"build", "designs", "engines", "language", "model", "results", "scene"},
    "report": {"engines", "language", "results", "video"},
    "replay": {
        "designs", "engines", "model", "perception", "results", "scene", "tracking", "video",
    },
    "verify": {
        "build", "designs", "language", "model", "perception", "pipeline", "replay",
        "report", "results", "scene", "tracking", "video",
    },
    "campaign": {
        "build", "designs", "engines", "language", "perception", "pipeline", "report",
        "results", "scene", "tracking", "verify", "video",
    },
    "api": {
        "build", "designs", "engines", "export", "language", "model", "pipeline", "results",
        "scene", "tracking", "verify",
    },
    "cli": {
        "api", "build", "campaign", "designs", "engines", "export", "language", "model",
        "perception",
        "pipeline", "replay", "report", "results", "scene", "tracking", "verify", "video",
    },
    "__main__": {"cli"},
}  # fmt: skip


def _package_of(path: Path) -> str:
    parts = path.relative_to(PACKAGE).parts
    return parts[0][:-3] if len(parts) == 1 else parts[0]


def _runtime_imports(tree: ast.Module) -> list[tuple[int, str]]:
    """(line, module) of every absolute ``lesmc.`` import outside ``if TYPE_CHECKING:``."""
    skipped: set[int] = set()
    for node in ast.walk(tree):
        if isinstance(node, ast.If) and "TYPE_CHECKING" in ast.unparse(node.test):
            skipped.update(id(n) for stmt in node.body for n in ast.walk(stmt))
    found = []
    for node in ast.walk(tree):
        if id(node) in skipped:
            continue
        if isinstance(node, ast.ImportFrom) and node.module and node.level == 0:
            found.append((node.lineno, node.module))
        elif isinstance(node, ast.Import):
            found.extend((node.lineno, a.name) for a in node.names)
    return [(line, name) for line, name in found if name.startswith("lesmc.")]


MODULES = sorted(p for p in PACKAGE.rglob("*.py") if _package_of(p) != "__init__")


def test_every_package_has_a_row() -> None:
    assert {_package_of(p) for p in MODULES} <= set(LAYERS)


def test_the_layers_have_no_cycle() -> None:
    graph = nx.DiGraph([(a, b) for a, below in LAYERS.items() for b in below])
    assert nx.is_directed_acyclic_graph(graph), nx.find_cycle(graph)


@pytest.mark.parametrize("path", MODULES, ids=lambda p: str(p.relative_to(PACKAGE)))
def test_module_imports_only_lower_layers(path: Path) -> None:
    package = _package_of(path)
    allowed = LAYERS[package] | {package, "common"}
    for line, name in _runtime_imports(ast.parse(path.read_text())):
        target = name.split(".")[1]
        assert target in allowed, f"{path.relative_to(ROOT)}:{line}: {package} imports {name}"


def test_a_layering_violation_is_caught() -> None:
    """The checker itself: an engine importing the tracker fails it."""
    tree = ast.parse("import lesmc.tracking.kalman\nif TYPE_CHECKING:\n    import lesmc.cli\n")
    assert _runtime_imports(tree) == [(1, "lesmc.tracking.kalman")]


def test_importing_the_engines_loads_no_higher_layer() -> None:
    code = (
        "import sys, lesmc.engines.check, lesmc.engines.bnb, lesmc.engines.enumerate, "
        "lesmc.engines.lazy; print('\\n'.join(sys.modules))"
    )
    out = subprocess.run(
        [sys.executable, "-c", code], capture_output=True, text=True, check=True, cwd=ROOT
    ).stdout.split()
    allowed = ("lesmc.engines", "lesmc.language", "lesmc.model", "lesmc.common")
    loaded = [m for m in out if m.startswith("lesmc.") and not m.startswith(allowed)]
    assert not loaded, loaded


MAX_FUNCTION_LINES = 60


def _long_functions(tree: ast.AST) -> list[tuple[int, str, int]]:
    """(line, name, length) of every function longer than :data:`MAX_FUNCTION_LINES`."""
    found = []
    for node in ast.walk(tree):
        if isinstance(node, (ast.FunctionDef, ast.AsyncFunctionDef)):
            length = (node.end_lineno or node.lineno) - node.lineno + 1
            if length > MAX_FUNCTION_LINES:
                found.append((node.lineno, node.name, length))
    return found


def test_no_function_is_longer_than_60_lines() -> None:
    """Issue 28's rule: small functions (click verbs are option tables plus a call)."""
    long = [
        f"{p.relative_to(ROOT)}:{line}: {name} has {n} lines"
        for p in MODULES
        for line, name, n in _long_functions(ast.parse(p.read_text()))
    ]
    assert not long, "\n".join(long)


def test_a_long_function_is_caught() -> None:
    body = "\n".join(f"    x{i} = {i}" for i in range(MAX_FUNCTION_LINES))
    assert _long_functions(ast.parse(f"def f():\n{body}\n")) == [(1, "f", 61)]
    assert _long_functions(ast.parse("def g():\n    return 1\n")) == []
