"""numba's first use (issue 62): verbs that do not search never import it; the compiled
pass's kernel is cached on disk where numba is told (``NUMBA_CACHE_DIR``); without a
writable place for that cache the numpy passes decide (no compilation paid again and
again). benchmarks/bench_numba_cache.py measures the cold and the warm cache.

The cold-then-warm cache run (a compilation of several seconds) is behind
``LESMC_NUMBA_FULL=1``.
"""

from __future__ import annotations

import json
import os
import subprocess
import sys
import types
from pathlib import Path

import pytest
from test_engine_compiled import brute_knapsack, knapsack, solve
from test_startup import ROOT, TINY, modules_after

from lesmc.engines import compiled, levels

COMPILED = ("numba", "llvmlite")
"""The compiler's packages: seconds to import, never wanted by a verb that does not search."""

SCENE = ROOT / "tests" / "scenes" / "rq4_merge.json"


def compiler_in(modules: set[str]) -> list[str]:
    return sorted(m for m in modules if m.split(".")[0] in COMPILED)


@pytest.mark.parametrize(
    "args",
    [
        ["--help"],
        ["check", "--help"],
        ["reduce", "knapsack", "--help"],
        ["check", str(TINY / "model.lts"), str(TINY / "properties.spec"), "--engine", "auto"],
    ],
    ids=lambda a: " ".join(Path(x).name for x in a),
)
def test_help_and_a_small_check_never_import_numba(tmp_path: Path, args: list[str]) -> None:
    """--help, and a check whose search ends long before ``levels.COMPILED_AFTER`` labels."""
    status, modules = modules_after(tmp_path, *args)
    assert status in (0, 1)  # the tiny model violates some properties (exit 1)
    assert compiler_in(modules) == []


def test_build_check_report_never_import_numba(tmp_path: Path) -> None:
    """``lesmc build``, ``lesmc check --report`` and ``lesmc report`` on what they wrote."""
    model = tmp_path / "m.lts"
    status, modules = modules_after(
        tmp_path, "build", str(SCENE), "--window", "6..8", "-o", str(model)
    )
    assert status == 0 and model.is_file()
    assert compiler_in(modules) == []
    out = tmp_path / "a"
    spec = str(TINY / "properties.spec")
    status, modules = modules_after(
        tmp_path, "check", str(TINY / "model.lts"), spec, "--report", str(out)
    )
    assert status == 1 and (out / "results.json").is_file()
    assert "lesmc.engines.levels" in modules  # the searches ran
    assert compiler_in(modules) == []
    status, modules = modules_after(
        tmp_path, "report", str(out / "results.json"), "--out", str(tmp_path / "b")
    )
    assert status == 0 and (tmp_path / "b" / "report.html").is_file()
    assert compiler_in(modules) == []


_CACHE_PROBE = """
import json, sys
sys.path.insert(0, sys.argv[1])
from lesmc.engines import compiled
k = compiled.kernel()
print(json.dumps([type(k._cache).__name__, k._cache._cache_path]))
"""


def test_the_kernel_is_cached_where_numba_cache_dir_says(tmp_path: Path) -> None:
    """``njit(cache=True)``: a disk cache (not numba's NullCache), in NUMBA_CACHE_DIR."""
    pytest.importorskip("numba")
    env = {**os.environ, "NUMBA_CACHE_DIR": str(tmp_path)}
    r = subprocess.run(
        [sys.executable, "-c", _CACHE_PROBE, str(ROOT)],
        capture_output=True,
        text=True,
        env=env,
        timeout=300,
    )
    assert r.returncode == 0, r.stderr
    kind, path = json.loads(r.stdout)
    assert kind != "NullCache"
    assert Path(path).resolve().is_relative_to(tmp_path.resolve())


def test_no_writable_cache_leaves_the_numpy_passes_to_decide(
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    """numba raises RuntimeError when no cache directory is writable: no kernel, and the
    exact pass decides the optimum uncapped (the brute force's)."""

    def njit(**kw: object) -> object:
        assert kw == {"cache": True}
        raise RuntimeError("cannot cache function 'dfs_chunk': no locator available")

    monkeypatch.setitem(sys.modules, "numba", types.SimpleNamespace(njit=njit))
    monkeypatch.setattr(compiled, "_kernel", None)
    monkeypatch.setattr(compiled, "_tried", False)
    assert compiled.kernel() is None
    assert not compiled.available()
    monkeypatch.setattr(compiled, "_tried", False)
    monkeypatch.setattr(compiled, "_found", True)  # numba "installed": the cap applies
    monkeypatch.setattr(levels, "COMPILED_AFTER", 3)
    monkeypatch.setattr(levels, "VALUE_CELLS", -1)  # the label passes, not the value table
    monkeypatch.setattr(levels, "BEAM", 0)  # dives that drop labels: the exact pass runs
    items, demand = knapsack(7, 14, real=False)
    opt, extra, _ = solve(items, demand)
    assert "compiled" not in extra
    assert opt == brute_knapsack(items, demand)


_FIRST_USE = """
import json, sys
sys.path.insert(0, sys.argv[1])
import numpy as np
from lesmc.engines import compiled
k = compiled.kernel()
z = np.zeros(1, np.int64)
model = (np.array([0, 0]), z, z, np.zeros(1), np.zeros(1), np.ones(1, bool), np.zeros(1),
         np.zeros(1))
bounds = (np.zeros(1), np.zeros(1), np.ones(1, bool), np.zeros((1, 2)), np.zeros(2),
          np.zeros(2, np.int64))
stack, stack_f = np.zeros((2, 3), np.int64), np.zeros((2, 3))
state = np.array([0.0, 1.0, 0.0, 0.0, 0.0])
k(model, bounds, (2, 1.0, True, 0.0), stack, stack_f, z, z, state, 10)
print(json.dumps([sum(k.stats.cache_hits.values()), sum(k.stats.cache_misses.values())]))
"""


@pytest.mark.skipif(
    os.environ.get("LESMC_NUMBA_FULL") != "1", reason="compiles (seconds): LESMC_NUMBA_FULL=1"
)
def test_a_later_process_loads_what_the_first_compiled(tmp_path: Path) -> None:
    """Two fresh processes, one cache directory: the first compiles and writes the cache
    (a miss), the second loads it (a hit, no miss)."""
    pytest.importorskip("numba")
    env = {**os.environ, "NUMBA_CACHE_DIR": str(tmp_path)}
    runs = []
    for _ in range(2):
        r = subprocess.run(
            [sys.executable, "-c", _FIRST_USE, str(ROOT)],
            capture_output=True,
            text=True,
            env=env,
            timeout=600,
        )
        assert r.returncode == 0, r.stderr
        runs.append(tuple(json.loads(r.stdout)))
    assert runs[0][1] >= 1
    assert runs[1] == (1, 0)
    assert {p.suffix for p in tmp_path.rglob("*") if p.is_file()} == {".nbi", ".nbc"}
