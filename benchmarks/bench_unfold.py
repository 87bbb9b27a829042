"""Benchmark: unfolding a scene into its model, against a per-state filterpy loop.

Rows of docs/performance.md (issue "A fast core"): full unfolding of the dense
scene (a target inside a 6-vehicle platoon among 40 other vehicles, i.e. about
40 clutter detections per frame), single and joint designs, in states per
second, side by side in one run with a filterpy predict+update loop over as
many states; and memory per unfolded state (the model's arrays, and the peak
of the whole build as traced by tracemalloc).

Run ``python benchmarks/bench_unfold.py [--window 4..9] [--joint-window 4..7] [--repeat 5]``
(the joint window 4..7 unfolds about 49 k states: long enough for a rate). Each side
is timed ``--repeat`` times, alternately, and the best of each is compared.
"""

from __future__ import annotations

import argparse
import sys
import time
import tracemalloc
from pathlib import Path

import numpy as np
from filterpy.kalman import KalmanFilter
from rich.console import Console
from rich.table import Table

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from lesmc.scene.toy import Vehicle, vehicle_scene
from lesmc.tracking.kalman import matrices
from lesmc.unfold.unfold import build_model


def dense_scene(n: int, frames: int, seed: int, design: str = "single"):  # type: ignore[no-untyped-def]
    """A target among n random straight-line vehicles, some in a platoon around it."""
    rng = np.random.default_rng(seed)
    t = Vehicle("t", 500, 500, 10, 0, 3.0)
    platoon = [
        Vehicle(f"p{i}", 500 + float(dx), 500 + float(dy), 10, 0, float(rng.uniform(1, 5)))
        for i, (dx, dy) in enumerate(rng.uniform(-12, 12, size=(6, 2)))
    ]
    others = [
        Vehicle(
            f"v{i}",
            *map(float, rng.uniform(0, 1000, 2)),
            *map(float, rng.uniform(-10, 10, 2)),
            float(rng.uniform(1, 5)),
        )
        for i in range(n)
    ]
    return vehicle_scene([t, *platoon, *others], frames, t).with_tracker(design=design)


def filterpy_rate(scene, n: int) -> float:  # type: ignore[no-untyped-def]
    """States per second of a per-state filterpy predict+update loop (the reference)."""
    m = matrices(scene.tracker, scene.dt)
    kf = KalmanFilter(dim_x=4, dim_z=2)
    kf.F, kf.Q, kf.H, kf.R, kf.P = m.F, m.Q, m.H, m.R, m.P0.copy()
    z = np.array([500.0, 500.0])
    t0 = time.perf_counter()
    for _ in range(n):
        kf.x = np.array([[500.0], [500.0], [10.0], [0.0]])
        kf.P = m.P0.copy()
        kf.predict()
        kf.update(z)
    return n / (time.perf_counter() - t0)


def window(text: str) -> tuple[int, int]:
    a, b = text.split("..")
    return int(a), int(b)


def main() -> int:
    ap = argparse.ArgumentParser()
    ap.add_argument("--window", type=window, default=(4, 9))
    ap.add_argument("--joint-window", type=window, default=(4, 7))
    ap.add_argument("--frames", type=int, default=20)
    ap.add_argument("--repeat", type=int, default=5, help="timed runs of each (best taken)")
    args = ap.parse_args()
    build_model(dense_scene(10, 3, seed=0), (1, 1))  # imports and warm-up out of the figures
    table = Table(title="unfolding the dense scene (40 other vehicles + platoon of 6)")
    for c in (
        "design",
        "window",
        "states",
        "transitions",
        "build s",
        "states/s",
        "filterpy states/s",
        "ratio",
        "model B/state",
        "peak B/state",
    ):
        table.add_column(c, justify="right")
    for design, win in (("single", args.window), ("joint", args.joint_window)):
        scene = dense_scene(40, args.frames, seed=1, design=design)
        tracemalloc.start()
        t0 = time.perf_counter()
        model = build_model(scene, win)
        secs = time.perf_counter() - t0
        _, peak = tracemalloc.get_traced_memory()
        tracemalloc.stop()
        # timed again without tracemalloc's overhead, alternating with the reference:
        # the best of each (this VM's speed drifts by ±30 % within a minute)
        secs, ref = float("inf"), 0.0
        for _ in range(args.repeat):
            t0 = time.perf_counter()
            model = build_model(scene, win)
            secs = min(secs, time.perf_counter() - t0)
            ref = max(ref, filterpy_rate(scene, min(model.n_states, 50_000)))
        rate = model.n_states / secs
        table.add_row(
            design,
            f"{win[0]}..{win[1]}",
            f"{model.n_states:,}",
            f"{model.n_transitions:,}",
            f"{secs:.2f}",
            f"{rate:,.0f}",
            f"{ref:,.0f}",
            f"{rate / ref:.2f}x",
            f"{model.nbytes() / model.n_states:.0f}",
            f"{peak / model.n_states:.0f}",
        )
    Console(width=160).print(table)
    return 0


if __name__ == "__main__":
    sys.exit(main())
