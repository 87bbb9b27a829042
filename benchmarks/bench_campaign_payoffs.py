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

from lesmc.campaign.plan import DEFAULT_WINDOWS, parse_windows
from lesmc.campaign.run import Video, certify_scenes, execute, make_groups, prepare
from lesmc.campaign.targets import auto_targets
from lesmc.designs import registry
from lesmc.experiment.default_video import default_video_ready, write_default_video
from lesmc.experiment.experiment import bundled_specs, load_specs
from lesmc.pipeline import certify


def _args() -> argparse.Namespace:
    ap = argparse.ArgumentParser(description=__doc__)
    ap.add_argument("--out", type=Path, default=Path("/tmp/lesmc-bench-campaign-payoffs"))
    ap.add_argument("--targets", type=int, default=3, help="targets timed (K)")
    ap.add_argument("--workers", type=int, default=0, help="0: in this process, no Dask")
    ap.add_argument("--timeout", type=float, default=60.0)
    return ap.parse_args()


def _prepared(out: Path, targets: int, windows: Any) -> Any:
    """The default video (rendered into ``out``/video once), perceived, with its first
    ``targets`` automatic targets."""
    video = out / "video"
    if not default_video_ready(video):
        write_default_video(video)
    p = prepare(Video("default", video, video / "truth.json", "embedded default"), out)
    p.targets = [a.spec for a in auto_targets(p, windows, True)[:targets]]
    return p


def _execute(groups: Any, p: Any, workers: int) -> tuple[list[dict[str, Any]], float]:
    """The campaign's rows of ``groups`` and the seconds they took."""
    rows: list[dict[str, Any]] = []
    t0 = time.perf_counter()
    execute(groups, {p.doc_key: p.doc}, rows.extend, workers, None)
    return rows, time.perf_counter() - t0


def _certify(p: Any, groups: Any) -> tuple[Any, float, float]:
    """The interval mode's groups after certifying, the seconds certifying took in all,
    and those of them spent finding what the units' models can hide (``certify.probe``,
    which lesmc/campaign/run.py calls through its module)."""
    probing = certify.probe
    probe_seconds = [0.0]

    def timed_probe(*a: Any) -> Any:
        t = time.perf_counter()
        try:
            return probing(*a)
        finally:
            probe_seconds[0] += time.perf_counter() - t

    certify.probe = timed_probe  # type: ignore[assignment]
    t0 = time.perf_counter()
    try:
        groups = certify_scenes([p], groups, (None, None, None))
    finally:
        certify.probe = probing
    return groups, time.perf_counter() - t0, probe_seconds[0]


def _verdicts(rows: list[dict[str, Any]]) -> str:
    c = Counter(r["verdict"] for r in rows)
    return f"{c['holds']} / {c['violated']} / {c['unknown']}"


def _table(title: str, cert: dict[str, Any], seconds: dict[str, float], rows: Any) -> Table:
    """The side-by-side table: ``seconds`` of each stage (attack, probe, certify,
    interval), ``rows`` the two modes' campaign rows by name."""
    table = Table(title=title, title_justify="left")
    for c in ("measure", "attack", "interval"):
        table.add_column(c, justify="left" if c == "measure" else "right")
    t_attack, t_probe = seconds["attack"], seconds["probe"]
    t_certify, t_interval = seconds["certify"], seconds["interval"]
    table.add_row("finding what the models can hide s", "", f"{t_probe:.1f}")
    table.add_row(
        "certifying s (detections)",
        "",
        f"{t_certify - t_probe:.1f} ({cert['detections']} of {cert['of']})",
    )
    table.add_row("checking s", f"{t_attack:.1f}", f"{t_interval:.1f}")
    table.add_row(
        "all s (ratio)", f"{t_attack:.1f}", f"{t_certify + t_interval:.1f} "
        f"({(t_certify + t_interval) / t_attack:.2f}x)",
    )  # fmt: skip
    table.add_row("holds / violated / unknown (attack)", _verdicts(rows["attack"]), "")
    table.add_row("holds / violated / unknown (interval)", "", _verdicts(rows["interval"]))
    return table


def main() -> None:
    args = _args()
    windows = parse_windows(DEFAULT_WINDOWS)
    p = _prepared(args.out, args.targets, windows)
    specs = load_specs(bundled_specs(), None)
    designs = registry.expand("paper")
    attack_groups, total = make_groups([p], specs, windows, designs, set(), args.timeout, None)
    attack, t_attack = _execute(attack_groups, p, args.workers)
    groups, _ = make_groups([p], specs, windows, designs, set(), args.timeout, None, "interval")
    groups, t_certify, t_probe = _certify(p, groups)
    interval, t_interval = _execute(groups, p, args.workers)
    assert len(attack) == len(interval) == total
    title = (
        f"lesmc campaign, {len(p.targets)} targets x 36 windows x 3 designs x 2 properties"
        f" = {total} rows, workers {args.workers}"
    )
    seconds = {"attack": t_attack, "probe": t_probe, "certify": t_certify, "interval": t_interval}
    rows = {"attack": attack, "interval": interval}
    Console().print(_table(title, p.footage.meta["certified"], seconds, rows))


if __name__ == "__main__":
    main()
