"""Benchmark: the eager build's batches, sized by counted work (round 24) or by the wall
clock (before), side by side: benchmarks/bench_unfold.py's dense scenes (single, window
4..9; joint, window 4..7), the CPU seconds of a build (best of 3) and how many batches it
made (how often it looked at its budget).

Run it once per checkout, alternately, with that checkout first on the path::

    for i in 1 2 3; do for r in /work/main .; do
        PYTHONPATH=$r python benchmarks/bench_eager_batches.py $r; done; done

(docs/performance.md, "Round 24: the eager build's batches counted").
"""

from __future__ import annotations

import sys
import time
from pathlib import Path

root = Path(sys.argv[1] if len(sys.argv) > 1 else Path(__file__).resolve().parents[1])
sys.path.insert(0, str(root / "benchmarks"))

from bench_unfold import dense_scene  # noqa: E402

from lesmc.unfold.unfold import build_model  # noqa: E402


def _build(scene, win):  # type: ignore[no-untyped-def]
    """One build of ``scene``: (model, CPU seconds, batches)."""
    seen: list[int] = []
    t0 = time.process_time()
    model = build_model(scene, win, on_batch=lambda m: seen.append(m.n_states))
    return model, time.process_time() - t0, len(seen)


def main() -> int:
    build_model(dense_scene(10, 3, seed=0), (1, 1))  # imports and warm-up out of the figures
    for design, win in (("single", (4, 9)), ("joint", (4, 7))):
        scene = dense_scene(40, 20, seed=1, design=design)
        runs = [_build(scene, win) for _ in range(3)]
        model, batches = runs[0][0], runs[0][2]
        best = min(r[1] for r in runs)
        print(f"{root} {design} {win[0]}..{win[1]}: {model.n_states} states, "
              f"{batches} batches, {best:.3f} s CPU", flush=True)  # fmt: skip
    return 0


if __name__ == "__main__":
    sys.exit(main())
