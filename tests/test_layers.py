"""The layering holds: each package imports only the packages below it.

``LAYERS`` is the table of docs/architecture.md: a package may import the
packages it lists (and ``common``), nothing else. Every import counts: at the
top of a module, inside a function (a lazy import is still a dependency) and
under ``if TYPE_CHECKING:`` (an annotation names a type of that layer), and so do
the modules the registries declare as ``module:name`` strings (trackers, export
writers). The table
must have no cycle, the modules' own import graph must have none either (a cycle
hidden by a function-local import is still a cycle), and the engines are checked
once more in a fresh interpreter, so that a module reaching a higher layer through
another one is caught too.
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
    "schemas": {"designs", "engines", "exporters", "language"},
    "designs": set(),
    "model": {"language"},
    "scene": {"designs", "language"},
    "engines": {"language", "model"},
    "exporters": {"engines", "language", "model"},
    "perception": {"scene", "video"},
    "tracking": {"designs", "model", "scene"},
    "unfold": {"designs", "model", "scene", "tracking"},
    "results": {"designs", "engines", "language", "model", "scene", "schemas"},
    "pipeline": {"unfold", "designs", "engines", "language", "model", "results", "scene"},
    "report": {"engines", "language", "results", "video"},
    "replay": {
        "designs", "engines", "model", "perception", "results", "scene", "tracking", "video",
    },
    "experiment": {
        "unfold", "designs", "language", "model", "perception", "pipeline", "replay",
        "report", "results", "scene", "tracking", "video",
    },
    "campaign": {
        "unfold", "designs", "engines", "language", "perception", "pipeline", "report",
        "results", "scene", "tracking", "experiment", "video",
    },
    "api_checks": {"designs", "engines", "exporters", "language", "model"},
    "api": {
        "api_checks", "unfold", "designs", "engines", "exporters", "language", "model",
        "pipeline", "results", "scene", "tracking", "experiment",
    },
    "cli": {
        "api", "api_checks", "unfold", "campaign", "designs", "engines", "exporters", "language",
        "model", "perception",
        "pipeline", "replay", "report", "results", "scene", "tracking", "experiment", "video",
    },
    "__main__": {"cli"},
}  # fmt: skip


def _package_of(path: Path) -> str:
    parts = path.relative_to(PACKAGE).parts
    return parts[0][:-3] if len(parts) == 1 else parts[0]


def _module_name(path: Path) -> str:
    name = ".".join(path.relative_to(ROOT).with_suffix("").parts)
    return name.removesuffix(".__init__")


MODULES = sorted(p for p in PACKAGE.rglob("*.py") if _package_of(p) != "__init__")
MODULE_NAMES = {_module_name(p) for p in PACKAGE.rglob("*.py")}


def _imports(tree: ast.Module) -> list[tuple[int, str]]:
    """(line, module) of every absolute ``lesmc.`` import, wherever it stands (top level,
    inside a function, under ``if TYPE_CHECKING:``). ``from lesmc.pkg import mod`` names
    the module ``lesmc.pkg.mod`` where that is a module of the package."""
    found: list[tuple[int, str]] = []
    for node in ast.walk(tree):
        if isinstance(node, ast.ImportFrom) and node.module and node.level == 0:
            subs = [f"{node.module}.{a.name}" for a in node.names]
            if all(m in MODULE_NAMES for m in subs):
                found.extend((node.lineno, m) for m in subs)
            else:
                found.append((node.lineno, node.module))
        elif isinstance(node, ast.Import):
            found.extend((node.lineno, a.name) for a in node.names)
    return [(line, name) for line, name in found if name.startswith("lesmc.")]


def _declared_imports() -> list[tuple[Path, int, str]]:
    """The modules the registries name as ``module:name`` strings, as imports of the module
    that imports them when they are used: the design registry's trackers (imported by
    lesmc/tracking/trackers.py when a scene is unfolded) and the export formats' writers
    (imported by lesmc/exporters/formats.py when a model is written)."""
    from lesmc.designs import registry
    from lesmc.exporters import formats

    trackers = PACKAGE / "tracking" / "trackers.py"
    writers = PACKAGE / "exporters" / "formats.py"
    return [
        *[(trackers, 0, impl.partition(":")[0]) for impl in registry.implementations()],
        *[(writers, 0, formats.get(f).writer.partition(":")[0]) for f in formats.names()],
    ]


def _import_graph() -> nx.DiGraph:
    """Module -> module, every edge with the line of its import."""
    graph = nx.DiGraph()
    edges = [(p, line, m) for p in MODULES for line, m in _imports(ast.parse(p.read_text()))]
    for path, line, target in [*edges, *_declared_imports()]:
        source = _module_name(path)
        if target in MODULE_NAMES and target != source:
            graph.add_edge(source, target, line=line)
    return graph


def test_every_package_has_a_row() -> None:
    assert {_package_of(p) for p in MODULES} <= set(LAYERS)


def test_the_layers_have_no_cycle() -> None:
    graph = nx.DiGraph([(a, b) for a, below in LAYERS.items() for b in below])
    assert nx.is_directed_acyclic_graph(graph), nx.find_cycle(graph)


@pytest.mark.parametrize("path", MODULES, ids=lambda p: str(p.relative_to(PACKAGE)))
def test_module_imports_only_lower_layers(path: Path) -> None:
    package = _package_of(path)
    allowed = LAYERS[package] | {package, "common"}
    for line, name in _imports(ast.parse(path.read_text())):
        target = name.split(".")[1]
        assert target in allowed, f"{path.relative_to(ROOT)}:{line}: {package} imports {name}"


def test_a_layering_violation_is_caught() -> None:
    """The checker itself: an engine importing the tracker fails it, lazily or not."""
    tree = ast.parse(
        "import lesmc.tracking.kalman\nif TYPE_CHECKING:\n    import lesmc.cli\n"
        "def f():\n    from lesmc.scene import io\n"
    )
    assert _imports(tree) == [
        (1, "lesmc.tracking.kalman"),
        (3, "lesmc.cli"),
        (5, "lesmc.scene.io"),
    ]


def _cycles(graph: nx.DiGraph) -> list[str]:
    """Each cycle of the module graph as ``a:LINE -> b:LINE -> ...``."""
    return [
        " -> ".join(
            f"{a}:{graph.edges[a, b]['line']}" for a, b in zip(c, [*c[1:], c[0]], strict=True)
        )
        for c in nx.simple_cycles(graph)
    ]


def test_the_modules_import_no_cycle() -> None:
    """Issue 57: no cycle between modules, even one closed by a function-local import or a
    ``TYPE_CHECKING`` one (the shared types move down instead: perception/chain.py)."""
    assert not _cycles(_import_graph()), "\n".join(_cycles(_import_graph())[:10])


def test_a_hidden_cycle_is_caught() -> None:
    """The cycle check itself: two modules that import each other, one of them inside a
    function, are a cycle; the real graph with that edge added has one."""
    graph = _import_graph()
    graph.add_edge("lesmc.perception.chain", "lesmc.perception.graphs", line=99)
    assert any("lesmc.perception.chain:99" in c for c in _cycles(graph))
    tree = ast.parse("def f():\n    from lesmc.perception import graphs\n")
    assert _imports(tree) == [(2, "lesmc.perception.graphs")]


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
