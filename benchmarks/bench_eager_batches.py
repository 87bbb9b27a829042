"""Benchmark: the eager build's batches, sized by counted work (round 24) or by the wall
clock (before), side by side: dense scenes of benchmarks/bench_unfold.py drawn at run time
(single, window 4..9; joint, window 4..7), per scene the CPU seconds of one build and how
many batches it made (how often it looked at its budget), then the median and the worst
over the scenes.

Run it once per checkout, alternately, each with that checkout first on the path and the
same ``--seed-base`` (the first run prints the one it drew)::

    B=$(python -c 'import secrets; print(secrets.randbelow(10**6))')
    for i in 1 2; do for r in OLD_CHECKOUT .; do
        PYTHONPATH=$r python benchmarks/bench_eager_batches.py $r --seed-base $B; done; done

(docs/performance.md, "Round 24: the eager build's batches counted").
"""

from __future__ import annotations

import argparse
import secrets
import statistics
import sys
import time
from pathlib import Path


def _build(scene, win):  # type: ignore[no-untyped-def]
    """One build of ``scene``: (model, CPU seconds, batches)."""
    from lesmc.unfold.unfold import build_model

    seen: list[int] = []
    t0 = time.process_time()
    model = build_model(scene, win, on_batch=lambda m: seen.append(m.n_states))
    return model, time.process_time() - t0, len(seen)


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("root", nargs="?", default=str(Path(__file__).resolve().parents[1]))
    ap.add_argument("--seeds", type=int, default=3, help="scenes drawn per design")
    ap.add_argument("--seed-base", type=int, default=None, help="[default: drawn]")
    args = ap.parse_args()
    base = secrets.randbelow(10**6) if args.seed_base is None else args.seed_base
    sys.path.insert(0, str(Path(args.root) / "benchmarks"))
    from bench_unfold import dense_scene

    print(f"{args.root}: --seed-base {base} --seeds {args.seeds}", flush=True)
    _build(dense_scene(10, 3, seed=base), (1, 1))  # imports and warm-up out of the figures
    for design, win in (("single", (4, 9)), ("joint", (4, 7))):
        cpu, batches = [], []
        for seed in range(base, base + args.seeds):
            model, s, b = _build(dense_scene(40, 20, seed=seed, design=design), win)
            cpu.append(s)
            batches.append(b)
            print(f"  {design} seed {seed}: {model.n_states} states, {b} batches, "
                  f"{s:.3f} s CPU", flush=True)  # fmt: skip
        print(f"{design} {win[0]}..{win[1]}: CPU s median {statistics.median(cpu):.3f}, "
              f"worst {max(cpu):.3f}; batches median {statistics.median(batches)}, "
              f"most {max(batches)}", flush=True)  # fmt: skip
    return 0


if __name__ == "__main__":
    sys.exit(main())
