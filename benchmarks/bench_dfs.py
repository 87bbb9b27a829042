"""Benchmark: dense-scene resilience against a plain depth-first branch and bound (issue 31).

Side by side in one run, alternately, best of ``--repeat``: lesmc's default engine
(``levels``, through ``lesmc.api.check``: the scene's model unfolded on demand) and
a plain Python depth-first branch and bound over the same model, unfolded on demand
by lesmc's own expander (the same successor states, so the search is what differs).
The reference keeps the running dist.max over the window and cuts a branch once it
reaches the best optimum found (a max never decreases); a path counts when
dist.at(end) > EPS, a halted track deviating +inf after its halt
(docs/semantics.md). Both answers must agree.

Run ``python benchmarks/bench_dfs.py [--windows 4..10,4..12] [--repeat 3]``; the scene
is the dense one of bench_search.py (a target in a 6-vehicle platoon among 40
vehicles, 24 frames). Figures: docs/performance.md.
"""

from __future__ import annotations

import argparse
import math
import sys
import time
from pathlib import Path

import numpy as np
from rich.console import Console
from rich.table import Table

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))
sys.path.insert(0, str(Path(__file__).resolve().parent))

from bench_unfold import dense_scene

from lesmc.api import check
from lesmc.language.parser import parse_spec
from lesmc.scene import Scene
from lesmc.unfold.unfold import lazy_model

EPS = 1.0  #: resilience's constraint: dist.at(end) > EPS


def spec(l: int, u: int) -> str:
    return (
        f"property resilience {{ attack window {l}..{u} minimize dist.max({l}..{u}) "
        f"subject to dist.at(end) > {EPS} holds if optimum > 30 on x, y }}"
    )


def dfs_reference(scene: Scene, l: int, u: int) -> tuple[float, int]:
    """The optimum by depth-first branch and bound, and the states it visited."""
    model = lazy_model(scene, (l, u))
    orig = [int(q) for q in model.original]
    end = len(orig) - 1
    comps = [model.components.index(c) for c in ("x", "y")]
    ref = model.S[orig][:, comps].copy()
    best = math.inf
    visited = 0

    def dev(q: int) -> float:
        d = model.S[q][comps] - ref[int(model.step[q])]
        return float(math.sqrt(float(d @ d)))

    def visit(q: int, acc: float) -> None:
        nonlocal best, visited
        visited += 1
        k = int(model.step[q])
        if k == end:
            if dev(q) > EPS and acc < best:
                best = acc
            return
        if model.halted[q]:  # +inf from k+1 on: dist.at(end) > EPS holds
            obj = acc if k >= u else math.inf
            best = min(best, obj)
            return
        if not model.expanded(q):
            model.expand(np.array([q]), k)
        lo, hi = int(model.out_lo[q]), int(model.out_hi[q])
        ts = range(lo, hi)
        if not l <= k + 1 <= u:  # outside the window: the unattacked transition only
            first = lo + int(np.argmin(model.rank[lo:hi]))
            ts = range(first, first + 1)
        for t in ts:
            q2 = int(model.dst[t])
            a2 = max(acc, dev(q2)) if l <= k + 1 <= u else acc
            if a2 < best:
                visit(q2, a2)

    sys.setrecursionlimit(10_000)
    visit(int(orig[0]), 0.0)
    return best, visited


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--windows", default="4..10,4..12")
    ap.add_argument("--repeat", type=int, default=3)
    args = ap.parse_args()
    scene = dense_scene(40, 24, 0, "single")
    table = Table(title="dense resilience: levels against a depth-first branch and bound")
    for col in ("window", "optimum", "levels s", "DFS s", "DFS states", "DFS / levels"):
        table.add_column(col, justify="right")
    for w in args.windows.split(","):
        l, u = (int(x) for x in w.split(".."))
        ours = ref = math.inf
        for _ in range(args.repeat):
            t0 = time.perf_counter()
            r = check(scene, [parse_spec(spec(l, u), "<bench>")])[0]
            ours = min(ours, time.perf_counter() - t0)
            t0 = time.perf_counter()
            best, visited = dfs_reference(scene, l, u)
            ref = min(ref, time.perf_counter() - t0)
        got = math.inf if r.optimum is None else r.optimum
        assert math.isclose(got, best, rel_tol=1e-9) or got == best, (w, got, best)
        table.add_row(w, f"{got:.6g}", f"{ours:.3f}", f"{ref:.3f}", str(visited),
                      f"{ref / ours:.1f}x")  # fmt: skip
    Console(width=120).print(table)
    return 0


if __name__ == "__main__":
    sys.exit(main())
