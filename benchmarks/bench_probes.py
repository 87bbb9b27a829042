"""Benchmark: would a campaign gain by pricing payoffs on demand? Probes against pricing all.

``lesmc verify`` prices a payoff when a model first reads it (docs/cnn.md, "Payoffs on
demand"). A campaign's checks run in Dask workers without the networks, so on demand
there would mean a probe in the client first: per group (target, tracker) and widest
window, the model built once with every payoff finite, noting which payoffs it reads
(``lesmc.unfold.probe.priced_detections``, what ``--payoffs interval`` campaigns do
before certifying). This script times, side by side in one run on the default video:

- the reference: DeepFool on every Q_dr blob, what a campaign does today;
- per number of targets K: the probes of the first K automatic targets (the paper's
  designs' trackers, the widest windows of ``--windows``), and DeepFool on the blobs
  of the detections they found.

On demand pays when the probes and their pricing take less than the reference.

Run ``python benchmarks/bench_probes.py [--targets 2,10] [--windows 4..12:1..4]``
(the video is perceived in this process, for its N_dr windows, into a new directory
under ``--out``; a scene already there is left alone).
Figures: docs/performance.md.
"""

from __future__ import annotations

import argparse
import sys
import tempfile
import time
from pathlib import Path

import numpy as np
from rich.console import Console
from rich.table import Table

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from lesmc.campaign.plan import DEFAULT_WINDOWS, parse_windows
from lesmc.campaign.run import Video, auto_targets, place_target, prepare
from lesmc.designs import registry
from lesmc.experiment.default_video import default_video_ready, write_default_video
from lesmc.perception.attack_settings import AttackConfig
from lesmc.perception.cnn import load_nets
from lesmc.perception.run import price_detections
from lesmc.pipeline.certify import widest
from lesmc.unfold.probe import merged_detections, priced_detections


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--video", type=Path, default=None)
    ap.add_argument("--out", type=Path, default=Path("/tmp/lesmc-bench-probes"))
    ap.add_argument("--targets", default="2,10", help="numbers of targets K to probe")
    ap.add_argument("--windows", default=DEFAULT_WINDOWS)
    args = ap.parse_args()
    video = args.video or args.out / "video"
    if not default_video_ready(video):
        write_default_video(video)
    args.out.mkdir(parents=True, exist_ok=True)
    fresh = Path(tempfile.mkdtemp(prefix="perceived-", dir=args.out))  # no scene to reuse
    p = prepare(Video("default", video, video / "truth.json", "embedded default"), fresh)
    assert p.run is not None
    nets = load_nets()
    run = p.run
    every = {fd.index: np.arange(len(fd.source)) for fd in run.detections}
    n_dets = sum(len(v) for v in every.values())
    t0 = time.perf_counter()
    price_detections(nets, run, every, AttackConfig())
    t_all = time.perf_counter() - t0

    windows = parse_windows(args.windows)
    wide = widest(set(windows))
    trackers = sorted({registry.get(d).tracker for d in registry.expand("paper")})
    found = auto_targets(p, windows, True)
    table = Table(title=f"pricing on demand in a campaign: windows {args.windows}")
    for col in ("K targets", "probes", "probe s", "ms / probe", "detections read", "pricing s",
                "on demand s", "price all s", "on demand / all"):  # fmt: skip
        table.add_column(col, justify="right")
    for k in (int(x) for x in args.targets.split(",")):
        reads = []
        t0 = time.perf_counter()
        for t in found[:k]:
            for tracker in trackers:
                scene = place_target(p.footage, t.spec).with_tracker(design=tracker)
                reads.extend(priced_detections(scene, w) for w in wide)
        t_probe = time.perf_counter() - t0
        union = merged_detections(reads)
        t0 = time.perf_counter()
        price_detections(nets, run, union, AttackConfig())
        t_price = time.perf_counter() - t0
        n = len(reads)
        on_demand = t_probe + t_price
        read = sum(map(len, union.values()))
        table.add_row(str(min(k, len(found))), str(n), f"{t_probe:.2f}",
                      f"{1000 * t_probe / n:.1f}", f"{read} of {n_dets}", f"{t_price:.2f}",
                      f"{on_demand:.2f}", f"{t_all:.2f}", f"{on_demand / t_all:.2f}x")  # fmt: skip
    Console(width=140).print(table)


if __name__ == "__main__":
    main()
