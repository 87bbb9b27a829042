"""Benchmark: the whole `lesmc campaign` command, 1 worker against 2, and what 2 cores allow.

    python benchmarks/bench_campaign_workers.py [--video DIR] [--targets 2] [--repeat 2]

Issue 31's target: a campaign of 2-4 targets x windows 4..5:1..2 x 2 designs
with 2 workers at least 1.6x faster than with 1. This runs the real command,
``lesmc campaign VIDEO --out FRESH --targets K --windows 4..5:1..2 --design both
--workers W``, W = 1 then 2, alternately, ``--repeat`` times, each in a fresh
process and a fresh output directory (the default video is rendered once
beforehand, into ``--video`` when absent). For each run it prints the wall
seconds a user waits, the CPU seconds of the command and every process it
waited for (the Dask nanny and workers included: ``RUSAGE_CHILDREN``), and the
phases read from the command's log lines (stdout is a pipe, so it logs).

The last column is the bound the cores set: a run that uses C CPU seconds on
2 cores takes at least C / 2 seconds, so the 2-worker run can be at most
2 x T1 / C2 times faster than the 1-worker run (T1 its wall time) unless it
does less work.
"""

from __future__ import annotations

import argparse
import re
import resource
import shutil
import subprocess
import sys
import tempfile
import time
from pathlib import Path

from rich.console import Console
from rich.table import Table

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from lesmc.experiment.default_video import default_video_ready, write_default_video

#: each phase and the log line that ends it, in order; the summary ends with the process
PHASES = (
    ("start-up", re.compile(r"perceiving .*: started")),
    ("perception", re.compile(r"perceiving .*: (\d+)/\1\b")),
    ("targets", re.compile(r"campaign: started")),
    ("checks", re.compile(r"campaign: (\d+)/\1\b")),
)
NAMES = [name for name, _ in PHASES] + ["summary"]


def _cpu() -> float:
    r = resource.getrusage(resource.RUSAGE_CHILDREN)
    return r.ru_utime + r.ru_stime


def run(video: Path, targets: int, workers: int) -> tuple[float, float, dict[str, float], int]:
    """Wall seconds, CPU seconds, seconds per phase and the exit status of one campaign."""
    out = Path(tempfile.mkdtemp(prefix="lesmc-bench-cw-"))
    cmd = ["lesmc", "campaign", str(video), "--out", str(out / "run"), "--targets"]
    cmd += [str(targets), "--windows", "4..5:1..2", "--design", "both", "--workers", str(workers)]
    cpu0, t0 = _cpu(), time.perf_counter()
    proc = subprocess.Popen(cmd, stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True)
    stamps: list[tuple[float, str]] = []
    assert proc.stdout is not None
    for line in proc.stdout:
        stamps.append((time.perf_counter() - t0, line))
    status = proc.wait()
    wall, cpu = time.perf_counter() - t0, _cpu() - cpu0
    shutil.rmtree(out)
    return wall, cpu, _phases(stamps, wall), status


def _phases(stamps: list[tuple[float, str]], wall: float) -> dict[str, float]:
    """Seconds per phase: a phase ends at the first log line after the previous end
    that matches its pattern (``PHASES``); the summary ends with the process."""
    spent: dict[str, float] = {}
    at, i = 0.0, 0
    for name, pattern in PHASES:
        while i < len(stamps) and not pattern.search(stamps[i][1]):
            i += 1
        end = stamps[i][0] if i < len(stamps) else wall
        spent[name], at = end - at, end
    spent["summary"] = wall - at
    return spent


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__)
    ap.add_argument("--video", type=Path, default=Path("/tmp/lesmc-bench-campaign/video"))
    ap.add_argument("--targets", type=int, default=2)
    ap.add_argument("--repeat", type=int, default=2)
    args = ap.parse_args()
    if not default_video_ready(args.video):
        write_default_video(args.video)
    table = Table(title="lesmc campaign, 1 worker against 2", title_justify="left")
    for c in ("workers", "wall s", "CPU s", *NAMES, "exit", "2 x T1 / C2"):
        table.add_column(c, justify="right")
    for _ in range(args.repeat):
        walls: dict[int, float] = {}
        for workers in (1, 2):
            wall, cpu, phases, status = run(args.video, args.targets, workers)
            walls[workers] = wall
            bound = f"{2 * walls[1] / cpu:.2f}x" if workers == 2 else ""
            cells = [f"{phases[n]:.2f}" for n in NAMES]
            table.add_row(str(workers), f"{wall:.2f}", f"{cpu:.2f}", *cells, str(status), bound)
        ratio = walls[1] / walls[2]
        table.add_row("", f"ratio {ratio:.2f}x", "", *[""] * len(NAMES), "", "")
    Console(width=140).print(table)


if __name__ == "__main__":
    main()
