"""How many injection candidates the joint design offers each state on a perceived video
(issue 61): per attacked frame, the frame's candidates m, the states expanded, the most
and the mean number of candidates relevant to a state (lesmc/tracking/parts/
attacker_subsets.py ``relevant_candidates``: in a track's gate or in the birth region of
a position the primary can take; docs/semantics.md, "Pruning injection candidates") and
the (state, subset) rows built, against the states × 2^m an unpruned step would list.

Reads the scenes ``benchmarks/bench_inject_video.py`` caches (run it first, same
``--out``); builds the model of the bundled robustness window (6..8) under ``allow hide,
inject`` in process, counting through a wrapper of the design's ``pruned_subsets``.
``--max-states N`` stops the build past N states: the row then reads "≥ N" model states
and counts only what was expanded before.

Usage: PYTHONPATH=. python benchmarks/bench_inject_prune.py [--seeds 1,2,3]
       [--out /tmp/lesmc-inject-video] [--max-states N]
"""

from __future__ import annotations

import argparse
import time
from pathlib import Path

import numpy as np


class _Stopped(Exception):
    """The build passed ``--max-states``."""


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--seeds", default="1,2,3")
    ap.add_argument("--out", default="/tmp/lesmc-inject-video")
    ap.add_argument("--max-states", type=int, default=None)
    args = ap.parse_args()

    import lesmc.tracking.joint as joint
    import lesmc.unfold.unfold as unfold
    from lesmc.api import load_scene
    from lesmc.model.growing import GrowingModel

    seen: list[tuple[int, int, int, float, int]] = []
    inner = joint.pruned_subsets

    def counting(relevant: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray, list]:
        out = inner(relevant)
        k = relevant.sum(axis=1)
        seen.append(
            (relevant.shape[1], len(k), int(k.max(initial=0)), float(k.mean()), len(out[0]))
        )
        return out

    joint.pruned_subsets = counting  # type: ignore[assignment]

    def stop(model: GrowingModel) -> None:
        if args.max_states is not None and model.n_states > args.max_states:
            raise _Stopped

    print(
        "| seed | candidates a frame | states expanded | relevant a state: most | mean "
        "| rows built | model states | CPU s |"
    )
    print("|---|---|---|---|---|---|---|---|")
    for seed in (int(s) for s in args.seeds.split(",")):
        path = Path(args.out) / f"scene{seed}.json"
        scene = load_scene(path).with_tracker(design="joint")
        seen.clear()
        t0 = time.process_time()
        try:
            cm = unfold.build_model(
                scene, (6, 8), inject=True, max_states=args.max_states, on_batch=stop
            )
            built = f"{len(cm.ptr) - 1:,}"
        except _Stopped:
            built = f"≥ {args.max_states:,}"
        secs = time.process_time() - t0
        m = sorted({s[0] for s in seen}) or [0]
        n, rows = sum(s[1] for s in seen), sum(s[4] for s in seen)
        most = max((s[2] for s in seen), default=0)
        mean = sum(s[3] * s[1] for s in seen) / max(n, 1)
        print(
            f"| {seed} | {m[0]}-{m[-1]} | {n:,} | {most} | {mean:.2f} | {rows:,} "
            f"| {built} | {secs:.0f} |",
            flush=True,
        )


if __name__ == "__main__":
    main()
