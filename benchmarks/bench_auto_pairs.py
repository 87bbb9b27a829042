"""Benchmark: ``auto`` against one other engine on one instance, in alternating pairs.

``python benchmarks/bench_auto_pairs.py --only TEXT [--seed-base B] [--pairs N]
[--engine levels]``: the instance of bench_auto.py's set whose name contains TEXT (the
knapsacks of seed base B, n = 40 and 80, and bench_engines.py's models), checked N
times by each engine through ``check_bound``, the two alternating (the first of each
pair alternating too), after one run of each out of the figures. Prints the median,
fastest and mean CPU seconds of each and the medians' ratio: the check of
docs/performance.md, "Issue 62, sixth round", that a ratio above 1.2x in bench_auto.py
is the jitter between runs and not ``auto``'s own cost.
"""

from __future__ import annotations

import argparse
import statistics
import sys
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent))

from bench_auto import engines_set, knapsack_set, once


def main() -> int:
    """Measure the pairs; 2 when no instance's name contains ``--only``."""
    ap = argparse.ArgumentParser(description=(__doc__ or "").splitlines()[0])
    ap.add_argument("--only", required=True, help="the instance whose name contains this")
    ap.add_argument("--seed-base", type=int, default=1)
    ap.add_argument("--pairs", type=int, default=100)
    ap.add_argument("--engine", default="levels", help="the engine auto is paired with")
    ap.add_argument("--timeout", type=float, default=20.0)
    args = ap.parse_args()
    cases = knapsack_set(1, args.seed_base, False) + engines_set(False)
    cases = [c for c in cases if args.only in c[0]]
    if not cases:
        print(f"bench_auto_pairs.py: no instance's name contains {args.only!r}", file=sys.stderr)
        return 2
    name, cm, bp = cases[0]
    pair = ("auto", args.engine)
    secs: dict[str, list[float]] = {e: [] for e in pair}
    for e in pair:  # imports and first calls out of the figures
        once(cm, bp, e, args.timeout)
    for k in range(args.pairs):
        for e in pair if k % 2 == 0 else pair[::-1]:
            secs[e].append(once(cm, bp, e, args.timeout)[1])
    print(f"{name}: {args.pairs} pairs, CPU seconds")
    for e in pair:
        x = secs[e]
        med, mean = statistics.median(x), statistics.mean(x)
        print(f"  {e}: median {med:.5f}, fastest {min(x):.5f}, mean {mean:.5f}")
    ratio = statistics.median(secs["auto"]) / statistics.median(secs[args.engine])
    print(f"  auto / {args.engine} (medians): {ratio:.2f}x")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
