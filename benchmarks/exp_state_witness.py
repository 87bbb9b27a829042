"""Experiment: ``levels`` with and without θ* by states (engines/below.py) on drawn dense
scenes, side by side (issue 62; figures: docs/performance.md, "Issue 62, fourth round").

``python benchmarks/exp_state_witness.py --seed-base N [--scenes 20] [--window 4..12]
[--repeat 2]``: on each of bench_dense_random.py's dense scenes (seeds N, N + 1, ...) it
runs ``levels`` (``lesmc.api.check``, the model unfolded on demand) with
``levels.STATE_WITNESS`` off and on, alternately, ``--repeat`` times each, and prints the
engine's seconds (best of the repeats), its states expanded (labels) and the time ratio;
optimum and θ* must agree.
"""

from __future__ import annotations

import argparse
import statistics
import sys
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))
sys.path.insert(0, str(Path(__file__).resolve().parent))

from bench_dense_random import FAMILIES
from bench_dfs import spec

from lesmc.api import check
from lesmc.engines import levels
from lesmc.language.parser import parse_spec


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seed-base", type=int, required=True)
    ap.add_argument("--scenes", type=int, default=20)
    ap.add_argument("--window", default="4..12")
    ap.add_argument("--repeat", type=int, default=2)
    args = ap.parse_args()
    l, u = (int(x) for x in args.window.split(".."))
    prop = parse_spec(spec(l, u), "<exp>")
    check(FAMILIES["dense"](0), [parse_spec(spec(1, 2), "<warm-up>")])
    ratios, states = [], []
    for seed in range(args.seed_base, args.seed_base + args.scenes):
        scene = FAMILIES["dense"](seed)
        best = {False: float("inf"), True: float("inf")}
        got = {}
        for _ in range(args.repeat):
            for flag in (False, True):
                levels.STATE_WITNESS = flag
                r = check(scene, [prop])[0]
                best[flag] = min(best[flag], r.stats.seconds)
                got[flag] = (r.optimum, r.witness_value, r.stats.states_expanded)
        assert got[False][:2] == got[True][:2], (seed, got)
        ratios.append(best[False] / best[True])
        states.append(got[False][2] / got[True][2])
        print(f"seed {seed}: optimum {got[True][0]:.6g}, θ* {got[True][1]:.6g}; labels "
              f"{got[False][2]:,} -> {got[True][2]:,}; seconds {best[False]:.2f} -> "
              f"{best[True]:.2f} ({ratios[-1]:.2f}x)", flush=True)  # fmt: skip
    print(f"without / with: time median {statistics.median(ratios):.2f}x (from {min(ratios):.2f}x "
          f"to {max(ratios):.2f}x), labels median {statistics.median(states):.2f}x")  # fmt: skip
    return 0


if __name__ == "__main__":
    sys.exit(main())
