"""Benchmark: ``levels``' transitions/s on a dense scene against a bare compiled loop over
the same arrays (issue 62: the limit of this machine on that instance).

``python benchmarks/bench_dense_loop.py --seed N [--window 4..12] [--family dense]``
(needs numba: ``pip install -c constraints.txt numba``). On one scene of
bench_dense_random.py's families (its hardest drawn one, say), in one process:

1. ``levels`` on the scene's model unfolded on demand (lesmc.engines.lazy, as ``lesmc
   check SCENE.json`` runs it): optimum, transitions, seconds, transitions/s, and the
   seconds spent unfolding (the tracker's steps: ``GrowingModel.expand``);
2. a depth-first branch and bound compiled by numba over the arrays that run built:
   successors (``out_lo``/``out_hi``), the property's allowed transitions, contributions,
   leaves and their tails; its cut is the running objective (a max or a sum never
   decreases) against the incumbent, which starts at the optimum plus a hair (every
   state a path below the optimum reaches was expanded by ``levels``), so it must find
   the optimum and prove it. The kernel's compilation is timed apart.

Figures: docs/performance.md ("Issue 62, fourth round").
"""

from __future__ import annotations

import argparse
import math
import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))
sys.path.insert(0, str(Path(__file__).resolve().parent))

from bench_dense_random import FAMILIES
from bench_dfs import spec

from lesmc.engines.lazy import LazySpace
from lesmc.engines.levels import level_search
from lesmc.language.parser import parse_spec
from lesmc.pipeline.check import bind_scene
from lesmc.unfold.unfold import lazy_model


def _kernel():  # type: ignore[no-untyped-def]
    """The compiled DFS: (lowest violating objective below ``upper``, transitions)."""
    from numba import njit

    @njit(cache=False)
    def dfs(lo, hi, allowed, dst, c_obj, c_con, leaf, t_obj, t_con, root, o0, c0,
            obj_max, con_max, bound, strict, upper):  # fmt: skip
        best = upper
        transitions = 0
        n = lo.size
        stack_q = np.empty(n, np.int64)
        stack_o = np.empty(n)
        stack_c = np.empty(n)
        top = 0
        stack_q[0], stack_o[0], stack_c[0] = root, o0, c0
        top = 1
        while top > 0:
            top -= 1
            q, o, c = stack_q[top], stack_o[top], stack_c[top]
            if o >= best:
                continue
            if leaf[q]:
                fo = max(o, t_obj[q]) if obj_max else o + t_obj[q]
                fc = max(c, t_con[q]) if con_max else c + t_con[q]
                if (fc > bound if strict else fc >= bound) and fo < best:
                    best = fo
                continue
            if lo[q] < 0:
                continue  # never built: no path below the optimum enters it
            for t in range(hi[q] - 1, lo[q] - 1, -1):
                if not allowed[t]:
                    continue
                transitions += 1
                o2 = max(o, c_obj[t]) if obj_max else o + c_obj[t]
                if o2 >= best:
                    continue
                c2 = max(c, c_con[t]) if con_max else c + c_con[t]
                if top >= n:
                    return -1.0, transitions
                stack_q[top], stack_o[top], stack_c[top] = dst[t], o2, c2
                top += 1
        return best, transitions

    return dfs


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seed", type=int, required=True)
    ap.add_argument("--window", default="4..12")
    ap.add_argument("--family", choices=sorted(FAMILIES), default="dense")
    args = ap.parse_args()
    l, u = (int(x) for x in args.window.split(".."))
    scene = FAMILIES[args.family](args.seed)
    bp = bind_scene(scene, [parse_spec(spec(l, u), "<bench>")])[0]
    assert bp.op in (">", ">=")
    model = lazy_model(scene, (bp.l, bp.u), bp.end)
    spent = [0.0]
    grow = model.expand

    def timed(states: np.ndarray, step: int) -> np.ndarray:
        t0 = time.perf_counter()
        try:
            return grow(states, step)
        finally:
            spent[0] += time.perf_counter() - t0

    model.expand = timed  # type: ignore[method-assign]
    space = LazySpace(model, bp)
    out = level_search(space)
    s = out.stats
    print(f"seed {args.seed}: levels optimum {out.optimum!r}, {s.states_expanded:,} labels, "
          f"{s.transitions:,} transitions in {s.seconds:.2f} s = "
          f"{s.transitions / s.seconds / 1e6:.3f} M/s; unfolding {spent[0]:.2f} s "
          f"({model.n_states:,} states built); search alone "
          f"{s.transitions / max(s.seconds - spent[0], 1e-9) / 1e6:.3f} M/s",
          flush=True)  # fmt: skip
    n = model.n_states
    leaf = space.leaves()[:n].copy()
    t_obj, t_con = np.zeros(n), np.zeros(n)
    ends = np.flatnonzero(leaf)
    t_obj[ends], t_con[ends] = space.tails(ends)
    m = model.n_transitions
    arrays = (
        np.ascontiguousarray(model.out_lo[:n]),
        np.ascontiguousarray(model.out_hi[:n]),
        np.ascontiguousarray(space.allowed_mask()[:m]),
        np.ascontiguousarray(model.dst[:m]),
        np.ascontiguousarray(space.c_obj[:m]),
        np.ascontiguousarray(space.c_con[:m]),
        leaf,
        t_obj,
        t_con,
    )
    t0 = time.perf_counter()
    dfs = _kernel()
    strict = bp.op == ">"
    upper = out.optimum * (1 + 1e-9) if math.isfinite(out.optimum) else math.inf
    args_ = (*arrays, space.root, space.root_obj, space.root_con, space.obj_max, space.con_max,
             bp.bound, strict)  # fmt: skip
    dfs(*args_, 0.0)  # compiles (a zero incumbent prunes everything)
    print(f"numba import and compile {time.perf_counter() - t0:.2f} s", flush=True)
    sec = math.inf
    for _ in range(3):  # best of 3 (a shared machine)
        t0 = time.perf_counter()
        best, trans = dfs(*args_, upper)
        sec = min(sec, time.perf_counter() - t0)
    assert math.isclose(best, out.optimum, rel_tol=1e-9), (best, out.optimum)
    print(f"bare compiled DFS over the same arrays: optimum {best!r}, {trans:,} transitions in "
          f"{sec:.3f} s = {trans / sec / 1e6:.1f} M/s; levels' rate is "
          f"{(s.transitions / s.seconds) / (trans / sec):.4f} of it", flush=True)  # fmt: skip
    return 0


if __name__ == "__main__":
    sys.exit(main())
