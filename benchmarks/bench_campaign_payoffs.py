"""Benchmark: what `lesmc campaign --payoffs interval` costs beside the attack's payoffs.

Side by side in one run, on the same K automatic targets of the embedded default
video (the paper's 36 windows, 3 designs, 2 properties): the attack-mode groups,
then the interval mode's three stages (finding the detections the units' models
can hide, certifying them, the groups with both payoff sets), each timed, with
the certified count and how the verdicts move. Use a fresh ``--out``: a scene
already there keeps the bounds of the last run, and only what is new is
certified (a reused scene is perceived again for its N_dr windows, which
counts in certifying).

Run ``python benchmarks/bench_campaign_payoffs.py [--out DIR] [--targets K] [--workers N]``
(docs/campaign.md, "Sound verdicts"; docs/performance.md).
"""

from __future__ import annotations

import argparse
import sys
import time
from collections import Counter
from pathlib import Path
from typing import Any

from rich.console import Console
from rich.table import Table

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from lesmc.campaign import run as campaign_run
from lesmc.campaign.plan import DEFAULT_WINDOWS, parse_windows
from lesmc.campaign.run import Video, auto_targets, certify_scenes, execute, make_groups, prepare
from lesmc.designs import registry
from lesmc.experiment.default_video import default_video_ready, write_default_video
from lesmc.experiment.experiment import bundled_specs, load_specs


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__)
    ap.add_argument("--out", type=Path, default=Path("/tmp/lesmc-bench-campaign-payoffs"))
    ap.add_argument("--targets", type=int, default=3, help="targets timed (K)")
    ap.add_argument("--workers", type=int, default=0, help="0: in this process, no Dask")
    ap.add_argument("--timeout", type=float, default=60.0)
    args = ap.parse_args()
    video = args.out / "video"
    if not default_video_ready(video):
        write_default_video(video)
    p = prepare(Video("default", video, video / "truth.json", "embedded default"), args.out)
    windows = parse_windows(DEFAULT_WINDOWS)
    p.targets = [a.spec for a in auto_targets(p, windows, True)[: args.targets]]
    specs = load_specs(bundled_specs(), None)
    designs = registry.expand("paper")

    attack_groups, total = make_groups([p], specs, windows, designs, set(), args.timeout, None)
    attack: list[dict[str, Any]] = []
    t0 = time.perf_counter()
    execute(attack_groups, {p.doc_key: p.doc}, attack.extend, args.workers, None)
    t_attack = time.perf_counter() - t0

    groups, _ = make_groups([p], specs, windows, designs, set(), args.timeout, None, "interval")
    probing = campaign_run.probe
    probe_seconds = [0.0]

    def timed_probe(*a: Any) -> Any:
        t = time.perf_counter()
        try:
            return probing(*a)
        finally:
            probe_seconds[0] += time.perf_counter() - t

    campaign_run.probe = timed_probe  # type: ignore[assignment]
    t0 = time.perf_counter()
    groups = certify_scenes([p], groups, (None, None, None))
    t_certify = time.perf_counter() - t0
    campaign_run.probe = probing
    interval: list[dict[str, Any]] = []
    t0 = time.perf_counter()
    execute(groups, {p.doc_key: p.doc}, interval.extend, args.workers, None)
    t_interval = time.perf_counter() - t0
    assert len(attack) == len(interval) == total

    cert = p.footage.meta["certified"]
    table = Table(
        title=f"lesmc campaign, {len(p.targets)} targets x 36 windows x 3 designs x 2 properties"
        f" = {total} rows, workers {args.workers}",
        title_justify="left",
    )
    for c in ("measure", "attack", "interval"):
        table.add_column(c, justify="left" if c == "measure" else "right")
    table.add_row("finding what the models can hide s", "", f"{probe_seconds[0]:.1f}")
    table.add_row(
        "certifying s (detections)",
        "",
        f"{t_certify - probe_seconds[0]:.1f} ({cert['detections']} of {cert['of']})",
    )
    table.add_row("checking s", f"{t_attack:.1f}", f"{t_interval:.1f}")
    table.add_row(
        "all s (ratio)", f"{t_attack:.1f}", f"{t_certify + t_interval:.1f} "
        f"({(t_certify + t_interval) / t_attack:.2f}x)",
    )  # fmt: skip
    for name, rows in (("attack", attack), ("interval", interval)):
        c = Counter(r["verdict"] for r in rows)
        table.add_row(
            f"holds / violated / unknown ({name})",
            *(
                [f"{c['holds']} / {c['violated']} / {c['unknown']}", ""]
                if name == "attack"
                else ["", f"{c['holds']} / {c['violated']} / {c['unknown']}"]
            ),
        )
    Console().print(table)


if __name__ == "__main__":
    main()
