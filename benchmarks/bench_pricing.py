"""Benchmark: ``lesmc verify`` with payoffs priced on demand against every detection
priced up front (issue 31).

    python benchmarks/bench_pricing.py [--rounds 3] [--video DIR]

The reference is ``lesmc verify --price-all`` (what verify did before: DeepFool on
every Q_dr blob while perceiving); lesmc's default attacks a detection when a model
first reads its payoff (lesmc/experiment/pricing.py). Both run alternately, each a fresh
process in a fresh output directory, on the default video (rendered once into a
temporary directory and copied into each output directory, so neither renders) or
on ``--video``'s frames with their truth.json. Prints per round the wall and CPU
seconds (the process and its children), the peak resident memory of the largest
process, how many detections carry a payoff, and whether the two runs gave the same
verdicts and paths with optima equal to 1e-5 (float32 attacks batched differently).
Figures: docs/performance.md.
"""

from __future__ import annotations

import argparse
import json
import os
import shutil
import subprocess
import sys
import tempfile
import time
from pathlib import Path
from typing import Any

from rich.console import Console
from rich.table import Table


def verify(out: Path, video: Path | None, seed_video: Path | None, *extra: str) -> dict[str, Any]:
    """One fresh ``lesmc verify``: wall, CPU, peak RSS, the results and the scene."""
    shutil.rmtree(out, ignore_errors=True)
    out.mkdir(parents=True)
    args = ["--out", str(out), *extra]
    if video is not None:
        args = [str(video), "--truth", str(video / "truth.json"), *args]
    else:  # the default video, already rendered: verify reuses OUT/video
        assert seed_video is not None
        shutil.copytree(seed_video, out / "video")
    log = out / "stderr.log"
    t0 = time.perf_counter()
    with log.open("w") as err:
        p = subprocess.Popen(
            [sys.executable, "-m", "lesmc", "verify", *args],
            stdout=subprocess.DEVNULL,
            stderr=err,
        )
        _, status, ru = os.wait4(p.pid, 0)  # this run's usage, its reaped children's too
    wall = time.perf_counter() - t0
    code = os.waitstatus_to_exitcode(status)
    if code not in (0, 1):
        raise SystemExit(f"lesmc verify exited {code}:\n{log.read_text()}")
    scene = json.loads((out / "scene.json").read_text())
    payoffs = [d["payoff"] for f in scene["frames"] for d in f["detections"]]
    return {
        "wall": wall,
        "cpu": ru.ru_utime + ru.ru_stime,
        "rss_mb": ru.ru_maxrss / 1024,
        "doc": json.loads((out / "results.json").read_text()),
        "priced": sum(p != "unpriced" for p in payoffs),
        "of": len(payoffs),
    }


def same(a: dict[str, Any], b: dict[str, Any]) -> bool:
    """The same verdicts, paths and counterexample states; optima equal to 1e-5."""

    def key(doc: dict[str, Any]) -> list[Any]:
        return [
            (run["design"], r["property"], r["verdict"], len(run.get("paths", [])))
            for run in doc["runs"]
            for r in run["results"]
        ]

    def optima(doc: dict[str, Any]) -> list[Any]:
        return [r["optimum"] for run in doc["runs"] for r in run["results"]]

    if key(a) != key(b):
        return False
    for x, y in zip(optima(a), optima(b), strict=True):
        if isinstance(x, float) and isinstance(y, float):
            if abs(x - y) > 1e-5 * max(abs(x), abs(y), 1e-9):
                return False
        elif x != y:
            return False
    return True


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--rounds", type=int, default=3)
    ap.add_argument("--video", type=Path, help="frames with truth.json [default: the default]")
    args = ap.parse_args()
    table = Table(title="lesmc verify: payoffs on demand against --price-all")
    for col in ("round", "all s", "demand s", "demand / all", "CPU all", "CPU demand",
                "MB all", "MB demand", "priced", "same"):  # fmt: skip
        table.add_column(col, justify="right")
    with tempfile.TemporaryDirectory() as tmp:
        seed = None
        if args.video is None:  # render once; each run copies it
            seed = Path(tmp) / "seed"
            subprocess.run(
                [sys.executable, "-c",
                 "import sys; from pathlib import Path; "
                 "from lesmc.experiment.default_video import write_default_video as w; "
                 "w(Path(sys.argv[1]))", str(seed)],
                check=True,
            )  # fmt: skip
        for i in range(args.rounds):
            full = verify(Path(tmp) / "all", args.video, seed, "--price-all")
            lazy = verify(Path(tmp) / "demand", args.video, seed)
            table.add_row(
                str(i + 1),
                f"{full['wall']:.1f}",
                f"{lazy['wall']:.1f}",
                f"{lazy['wall'] / full['wall']:.2f}",
                f"{full['cpu']:.1f}",
                f"{lazy['cpu']:.1f}",
                f"{full['rss_mb']:.0f}",
                f"{lazy['rss_mb']:.0f}",
                f"{lazy['priced']}/{full['priced']}",
                "yes" if same(full["doc"], lazy["doc"]) else "NO",
            )
    Console(width=120).print(table)
    print(f"priced: detections with a payoff, on demand / up front, of {lazy['of']}")


if __name__ == "__main__":
    main()
