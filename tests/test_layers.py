"""The layering holds: the checker sees only the language and the model.

Imports are checked in a fresh interpreter, so a module that reaches a higher
layer through another one is caught too.
"""

from __future__ import annotations

import ast
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
ENGINES = sorted((ROOT / "lesmc" / "engines").glob("*.py"))
FORBIDDEN = ("lesmc.tracking", "lesmc.perception", "lesmc.report", "lesmc.video", "lesmc.cli")


@pytest.mark.parametrize("path", ENGINES, ids=lambda p: p.name)
def test_engine_modules_import_only_language_and_model(path: Path) -> None:
    tree = ast.parse(path.read_text())
    for node in ast.walk(tree):
        names = []
        if isinstance(node, ast.ImportFrom) and node.module:
            names = [node.module]
        elif isinstance(node, ast.Import):
            names = [a.name for a in node.names]
        for name in names:
            if name.startswith("lesmc."):
                allowed = ("lesmc.engines", "lesmc.language", "lesmc.model", "lesmc.errors")
                assert name.startswith(allowed), f"{path.name} imports {name}"


def test_importing_the_engines_loads_no_higher_layer() -> None:
    code = (
        "import sys, lesmc.engines.check, lesmc.engines.bnb, lesmc.engines.enumerate, "
        "lesmc.engines.lazy; print('\\n'.join(sys.modules))"
    )
    out = subprocess.run(
        [sys.executable, "-c", code], capture_output=True, text=True, check=True, cwd=ROOT
    ).stdout.split()
    loaded = [m for m in out if m.startswith(FORBIDDEN)]
    assert not loaded, loaded
