"""Benchmark: numba's first-use cost for `levels`' compiled pass, cold and warm on-disk cache
(issue 62: "its compile cost is cached on disk, first run and later runs both measured").

``python benchmarks/bench_numba_cache.py [--n 24] [--range 1000000] [--costs strong]
[--seed 1] [--runs 3]``. Each run is a fresh interpreter with ``NUMBA_CACHE_DIR`` set to
one new temporary directory (the first run finds it empty: it compiles and writes the
cache; the later ones load it). In each: ``import lesmc.engines.levels`` (numba must not
be imported by it), then one knapsack reduction (bench_knapsack.py's ``instance``) checked
by ``levels`` four ways, each timed:

1. the numpy passes alone (``levels.COMPILED_AFTER`` out of reach);
2. ``levels`` as shipped: the compiled pass after ``COMPILED_AFTER`` labels of the exact
   pass, if the search gets that far (then this call pays numba's first use);
3. the compiled pass from the first label of the exact pass (``COMPILED_AFTER = 0``, no
   value table), first compiled call of the process unless 2. made it: numba's import,
   the kernel's compilation or its load from the cache, and the search;
4. the same again in the same process: the search alone.

It prints the seconds of each (wall and the process's CPU: the machine is shared) and
the cache's files. Figures: docs/performance.md, "Issue 62, fifth round".
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import tempfile
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]

_CHILD = """
import json, sys, time
sys.path[:0] = [{root!r}, {bench!r}]
t, c = time.perf_counter(), time.process_time()
from lesmc.engines import levels, compiled
from lesmc.engines.check import check_bound
from lesmc.language.parser import parse_spec
from lesmc.language.semantics import bind
from lesmc.model.knapsack import Item, knapsack_lts, knapsack_spec
from bench_knapsack import instance
imported = time.perf_counter() - t
imported_cpu = time.process_time() - c
numba_after_import = "numba" in sys.modules
cost, cap, demand = instance({n}, {r}, {costs!r}, {seed})
model = knapsack_lts([Item(float(c), float(g)) for c, g in zip(cost, cap)])
spec = parse_spec(knapsack_spec({n}, demand, 0.0), "<knapsack>")
bp = bind(spec, spec.properties[0], model.end, model.components, False)
shipped = (levels.COMPILED_AFTER, levels.VALUE_CELLS)
def run(after, cells):
    levels.COMPILED_AFTER, levels.VALUE_CELLS = after, cells
    t, c = time.perf_counter(), time.process_time()
    r = check_bound(model, bp, "levels")
    return (time.perf_counter() - t, r.optimum, r.stats.extra.get("compiled", False),
        time.process_time() - c, r.stats.states_expanded)
plain = run(10**15, shipped[1])
numba_after_plain = "numba" in sys.modules
default = run(*shipped)
first = run(0, -1)
again = run(0, -1)
print(json.dumps(dict(imported=imported, imported_cpu=imported_cpu,
    numba_after_import=numba_after_import, numba_after_plain=numba_after_plain,
    plain=plain, default=default, first=first, again=again)))
"""


def child(args: argparse.Namespace, cache: str) -> dict[str, object]:
    """One fresh interpreter's figures (``_CHILD``) with the cache in ``cache``."""
    code = _CHILD.format(
        root=str(ROOT),
        bench=str(ROOT / "benchmarks"),
        n=args.n,
        r=args.range,
        costs=args.costs,
        seed=args.seed,
    )
    env = {**os.environ, "NUMBA_CACHE_DIR": cache}
    out = subprocess.run(
        [sys.executable, "-c", code], capture_output=True, text=True, check=True, env=env
    )
    got: dict[str, object] = json.loads(out.stdout.strip().splitlines()[-1])
    return got


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--n", type=int, default=24)
    ap.add_argument("--range", type=int, default=1_000_000)
    ap.add_argument("--costs", choices=("uncorrelated", "strong"), default="strong")
    ap.add_argument("--seed", type=int, default=1)
    ap.add_argument("--runs", type=int, default=3)
    args = ap.parse_args()
    with tempfile.TemporaryDirectory() as cache:
        for k in range(args.runs):
            got = child(args, cache)
            plain, default, first, again = (got[k] for k in ("plain", "default", "first", "again"))
            assert isinstance(plain, list) and isinstance(default, list)
            assert isinstance(first, list) and isinstance(again, list)
            same = plain[1] == default[1] == first[1] == again[1]
            print(
                f"run {k + 1} ({'cold' if k == 0 else 'warm'} cache), seconds wall/CPU:"
                f" import lesmc.engines {got['imported']:.3f}/{got['imported_cpu']:.3f}"
                f" (numba imported: {got['numba_after_import']});"
                f" numpy passes {plain[0]:.3f}/{plain[3]:.3f} ({plain[4]:,} labels)"
                f" (numba imported: {got['numba_after_plain']});"
                f" as shipped {default[0]:.3f}/{default[3]:.3f} ({default[4]:,} labels,"
                f" compiled: {default[2]});"
                f" compiled, first call {first[0]:.3f}/{first[3]:.3f};"
                f" again {again[0]:.3f}/{again[3]:.3f};"
                f" compiled used: {first[2]}; equal optima: {same}",
                flush=True,
            )
        files = sorted(p.name for p in Path(cache).rglob("*") if p.is_file())
        print(f"NUMBA_CACHE_DIR held: {files}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
