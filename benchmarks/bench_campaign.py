"""Benchmark: a campaign on the embedded default video, 1 worker against 2.

Rows of docs/performance.md (issue 12): the default video's campaign of at
least 50 automatic targets x the paper's 36 windows x 3 designs x 2
properties should take at most 15 minutes on 2 cores, and 2 Dask workers
should be at least 1.7x faster than 1. The script perceives the video once
(or reuses OUT/scenes/default.json), chooses the targets from the truth, then
runs the same K targets' groups on a LocalCluster of 1 worker and of 2
workers, side by side in one run (cluster start-up included), and projects
the full campaign from the 2-worker time per target.

Run ``python benchmarks/bench_campaign.py [--video DIR] [--out DIR] [--targets K]``
(``--video``: frames of the default video, e.g. an earlier ``lesmc verify``'s
OUT/video; generated into OUT/video when absent).
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

from rich.console import Console
from rich.table import Table

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from lesmc.campaign.plan import DEFAULT_WINDOWS, parse_windows
from lesmc.campaign.run import Video, auto_targets, execute, make_groups, prepare
from lesmc.designs import registry
from lesmc.experiment.default_video import default_video_ready, write_default_video
from lesmc.experiment.experiment import bundled_specs, load_specs


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__)
    ap.add_argument("--video", type=Path, default=None)
    ap.add_argument("--out", type=Path, default=Path("/tmp/lesmc-bench-campaign"))
    ap.add_argument("--targets", type=int, default=4, help="targets timed (K)")
    ap.add_argument("--full", type=int, default=50, help="targets of the projected campaign")
    ap.add_argument("--timeout", type=float, default=60.0)
    ap.add_argument(
        "--workers", default="1,2", help="worker counts to time (0: in this process, no Dask)"
    )
    args = ap.parse_args()
    video = args.video or args.out / "video"
    if not default_video_ready(video):
        write_default_video(video)
    t0 = time.perf_counter()
    p = prepare(Video("default", video, video / "truth.json", "embedded default"), args.out)
    t_scene = time.perf_counter() - t0
    windows = parse_windows(DEFAULT_WINDOWS)
    t0 = time.perf_counter()
    found = auto_targets(p, windows, True)
    t_targets = time.perf_counter() - t0
    p.targets = [a.spec for a in found[: args.targets]]
    specs = load_specs(bundled_specs(), None)
    groups, total = make_groups(
        [p], specs, windows, registry.expand("paper"), set(), args.timeout, None
    )
    seconds: dict[int, float] = {}
    unknown: dict[int, int] = {}
    counts = [int(w) for w in args.workers.split(",")]
    for workers in counts:
        rows: list[dict[str, object]] = []
        t0 = time.perf_counter()
        execute(groups, {p.doc_key: p.doc}, rows.extend, workers, None)
        seconds[workers] = time.perf_counter() - t0
        unknown[workers] = sum(r["verdict"] == "unknown" for r in rows)
        assert len(rows) == total
    best = max(counts)
    per_target = seconds[best] / len(p.targets)
    table = Table(title="lesmc campaign on the default video", title_justify="left")
    for c in ("measure", "value"):
        table.add_column(c, justify="left" if c == "measure" else "right")
    table.add_row("scene (perceived or reused) s", f"{t_scene:.1f}")
    table.add_row("automatic targets found (truth)", str(len(found)))
    table.add_row("choosing them s", f"{t_targets:.1f}")
    table.add_row(
        "timed: targets x windows x designs x properties",
        f"{len(p.targets)} x 36 x 3 x 2 = {total}",
    )
    for w in counts:
        table.add_row(f"{w} workers s" if w else "in this process s", f"{seconds[w]:.1f}")
    if 1 in seconds and 2 in seconds:
        table.add_row("speed-up 2 vs 1 (target >= 1.7x)", f"{seconds[1] / seconds[2]:.2f}x")
    table.add_row("unknown rows", " / ".join(str(unknown[w]) for w in counts))
    table.add_row(
        f"projected {args.full} targets, {best} workers (target <= 15 min on 2)",
        f"{per_target * args.full / 60:.1f} min (+ scene and targets)",
    )
    Console().print(table)


if __name__ == "__main__":
    main()
