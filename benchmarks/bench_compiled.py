"""Benchmark: the `levels` engine's transitions/s against a bare compiled loop over the same
arrays (issue 62: is a compiled inner loop worth it?).

``python benchmarks/bench_compiled.py [--n 80] [--range 1000000] [--costs strong]
[--seed 1] [--max-transitions 200000000]`` (needs numba, which lesmc does not depend on:
``pip install -c constraints.txt numba``). On one knapsack reduction (bench_knapsack.py's
``instance``), side by side in one process:

1. ``levels`` (``check_bound``, the default engine) with its numpy passes only
   (``levels.COMPILED_AFTER`` out of reach): its optimum, transitions and seconds; then
   ``levels`` as shipped, which hands the optimum to lesmc/engines/compiled.py after
   ``COMPILED_AFTER`` labels (numba imported in this process by then: see below);
2. a depth-first branch and bound compiled by numba over the same arrays: the explicit
   space's CSR successors, contributions and leaves, and the same bounds the engine built
   (``level_bounds.LevelBounds``: suffix minima/maxima, the Lagrangian table ``h`` and each state's
   two λ per grid point), starting from the engine's optimum + the grain so that it must
   find the optimum and prove it; no dominance (a DFS has no level to compare in). It
   stops after ``--max-transitions``.

It prints numba's own costs too, each in a fresh process: ``import numba``, the first
call (compiling and writing the on-disk cache, ``cache=True``), and a later run's first
call (loading it). Figures: docs/performance.md, "Issue 62, second round".
"""

from __future__ import annotations

import argparse
import math
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))
sys.path.insert(0, str(Path(__file__).resolve().parent))

from bench_knapsack import instance

from lesmc.common.budget import Budget
from lesmc.engines import levels
from lesmc.engines.check import check_bound
from lesmc.engines.level_bounds import LAMBDA_GRID, LevelBounds
from lesmc.engines.space import Space, build_space
from lesmc.language.parser import parse_spec
from lesmc.language.semantics import BoundProperty, bind
from lesmc.model.arrays import ArrayModel
from lesmc.model.knapsack import Item, knapsack_lts, knapsack_spec

KERNEL = '''
import numpy as np
from numba import njit


@njit(cache=True)
def dfs(adj_ptr, adj, dst, c_obj, c_con, leaf, omin, cmax, alive, h, lam, best_k,
        bound, grid, root, o0, c0, upper, grain, max_transitions):
    """Cheapest path with constraint > bound below upper; (best, transitions)."""
    depth = 1
    cap = 1 << 16
    sq = np.empty(cap, np.int64)
    so = np.empty(cap)
    sc = np.empty(cap)
    sq[0], so[0], sc[0] = root, o0, c0
    best = upper
    cut = best - grain * (1 - 1e-9)
    transitions = 0
    while depth > 0 and transitions < max_transitions:
        depth -= 1
        q, o, c = sq[depth], so[depth], sc[depth]
        if leaf[q]:
            if c > bound and o < best:
                best = o
                cut = best - grain * (1 - 1e-9)
            continue
        for i in range(adj_ptr[q + 1] - 1, adj_ptr[q] - 1, -1):
            t = adj[i]
            d = dst[t]
            o2 = o + c_obj[t]
            c2 = c + c_con[t]
            transitions += 1
            if not alive[d] or not c2 + cmax[d] > bound:
                continue
            lb = o2 + omin[d]
            x = bound - min(c2, bound)
            j = min(int(x * ((grid - 1) / bound)), grid - 2)
            k1 = best_k[d * grid + j]
            k2 = best_k[d * grid + j + 1]
            lg = max(h[d, k1] + lam[k1] * x, h[d, k2] + lam[k2] * x)
            lb = max(lb, o2 + lg)
            lb -= 1e-9 * min(max(abs(lb), 1.0), 1e300)  # levels._lo: rounding slack
            if lb < cut:
                sq[depth], so[depth], sc[depth] = d, o2, c2
                depth += 1
    return best, transitions
'''


def arrays(n: int, r: int, costs: str, seed: int) -> tuple[BoundProperty, ArrayModel, Space, float]:
    """(the bound property, the model, the space, the demand) of one instance."""
    cost, cap, demand = instance(n, r, costs, seed)
    model = knapsack_lts([Item(float(c), float(g)) for c, g in zip(cost, cap, strict=True)])
    spec = parse_spec(knapsack_spec(len(cost), demand, 0.0), "<knapsack>")
    bp = bind(spec, spec.properties[0], model.end, model.components, model.has_covariance)
    return bp, model, build_space(model, bp), float(demand)


def numba_costs(cache_dir: str) -> tuple[float, float, float]:
    """Seconds of ``import numba``, a first call that compiles (and caches) the kernel, and
    a later process's first call (loading the cache): each in a fresh process."""
    mod = Path(cache_dir) / "kernel_mod.py"
    mod.write_text(KERNEL)
    probe = (
        "import time, sys; t = time.perf_counter(); import numba; a = time.perf_counter() - t;"
        f"sys.path.insert(0, {cache_dir!r}); import numpy as np; from kernel_mod import dfs;"
        "z = np.zeros(2, np.int64); f = np.zeros(2); b = np.zeros(2, bool);"
        "t = time.perf_counter(); dfs(z, z, z, f, f, b, f, f, b, np.zeros((2, 2)), f, z,"
        " 1.0, 2, 0, 0.0, 0.0, 1.0, 1.0, 0); print(a, time.perf_counter() - t)"
    )
    runs = []
    for _ in range(2):
        out = subprocess.run(
            [sys.executable, "-c", probe], capture_output=True, text=True, check=True
        ).stdout.split()
        runs.append((float(out[0]), float(out[1])))
    return runs[0][0], runs[0][1], runs[1][1]


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--n", type=int, default=80)
    ap.add_argument("--range", type=int, default=1_000_000)
    ap.add_argument("--costs", choices=("uncorrelated", "strong"), default="strong")
    ap.add_argument("--seed", type=int, default=1)
    ap.add_argument("--timeout", type=float, default=300.0)
    ap.add_argument("--max-transitions", type=int, default=200_000_000)
    args = ap.parse_args()
    with tempfile.TemporaryDirectory() as tmp:
        imp, first, later = numba_costs(tmp)
        print(
            f"numba: import {imp:.3f} s; first call (compiles, writes the cache) {first:.3f} s;"
            f" a later process's first call (loads it) {later:.3f} s",
            flush=True,
        )
        sys.path.insert(0, tmp)
        from kernel_mod import dfs  # type: ignore[import-not-found]

        bp, model, space, demand = arrays(args.n, args.range, args.costs, args.seed)
        default = levels.COMPILED_AFTER
        levels.COMPILED_AFTER = sys.maxsize  # numpy passes only
        r = check_bound(model, bp, "levels", Budget(timeout=args.timeout))
        levels.COMPILED_AFTER = default
        st = r.stats
        rate = st.transitions / st.seconds
        print(
            f"levels, numpy passes only: optimum {r.optimum}, θ* {r.witness_value}, "
            f"{st.stopped}, {st.states_expanded:,} labels, {st.transitions:,} transitions "
            f"in {st.seconds:.2f} s: {rate / 1e6:.2f} M/s",
            flush=True,
        )
        r2 = check_bound(model, bp, "levels", Budget(timeout=args.timeout))
        s2 = r2.stats
        print(
            f"levels as shipped (compiled pass after {default:,} labels, numba imported then):"
            f" optimum {r2.optimum}, θ* {r2.witness_value}, {s2.stopped}, "
            f"{s2.states_expanded:,} labels ({s2.extra.get('compiled_states', 0):,} of them"
            f" compiled), {s2.transitions:,} transitions in {s2.seconds:.2f} s; "
            f"{st.seconds / s2.seconds:.1f}x less time",
            flush=True,
        )
        b = LevelBounds(space)
        assert b.h is not None and b.lam is not None and b.best_k is not None
        assert b.grain is not None and r.optimum is not None and math.isfinite(r.optimum)
        sp = space
        args_ = (
            sp.adj_ptr,
            sp.adj,
            sp.cm.dst,
            np.asarray(sp.c_obj, dtype=float),
            np.asarray(sp.c_con, dtype=float),
            sp.leaves(),
            b.omin,
            b.cmax,
            b.alive,
            b.h,
            b.lam,
            b.best_k,
            demand,
            LAMBDA_GRID,
            sp.root,
            sp.root_obj,
            sp.root_con,
        )
        dfs(*args_, r.optimum + b.grain, b.grain, 10)  # compiled already: loads the cache
        dive = st.extra.get("dive_upper")
        starts = {"the optimum + grain": r.optimum + b.grain}
        if dive is not None and dive > r.optimum:
            starts["levels' dive incumbent"] = dive
        for name, upper in starts.items():
            t0 = time.perf_counter()
            best, transitions = dfs(*args_, upper, b.grain, args.max_transitions)
            secs = time.perf_counter() - t0
            done = transitions < args.max_transitions
            print(
                f"compiled DFS from {name} ({upper}): best {best} "
                f"({'finished' if done else 'stopped at the cap'}), {transitions:,} transitions"
                f" in {secs:.2f} s: {transitions / secs / 1e6:.2f} M/s, "
                f"{transitions / secs / rate:.0f}x levels' rate; "
                f"levels' seconds / these: {st.seconds / secs:.1f}x",
                flush=True,
            )
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
