"""Benchmark: the report's figures: savefig's tight box, the box found once, two processes.

    python benchmarks/bench_figures.py [RESULTS] [--frames DIR] [--rounds 3]

Draws every figure of a report (default: ``lesmc-verify/results.json`` with the frames
of ``lesmc-verify/video``, what the README's ``lesmc verify`` wrote) alternately three
ways, nothing cached (issue 31):

- the reference: ``savefig(bbox_inches="tight")``, which lays the figure out in a
  drawing pass of its own before drawing it, in one process;
- lesmc in one process: ``figures.png``, which finds the same box without that pass
  (what ``lesmc verify`` does);
- lesmc in two processes: every second figure drawn by a forked copy
  (lesmc/report/drawing.py; ``lesmc report``, ``lesmc check --report``).

Prints the seconds each way took for the page and all its figures, per round, and
whether every PNG is the same bytes. Figures: docs/performance.md.
"""

from __future__ import annotations

import argparse
import io
import json
import os
import time
from pathlib import Path
from typing import Any
from unittest import mock

from rich.console import Console
from rich.table import Table

from lesmc.report import figures
from lesmc.report.html import render
from lesmc.report.publish import frames_reader


def reference(fig: Any) -> bytes:
    """What figures.png did before: savefig's own tight box."""
    buf = io.BytesIO()
    fig.savefig(
        buf, format="png", dpi=figures.DPI, bbox_inches="tight", pil_kwargs={"compress_level": 1}
    )
    figures.pyplot().close(fig)
    return buf.getvalue()


def draw_all(
    doc: dict[str, Any], frames_dir: Path | None, processes: int
) -> tuple[float, dict[str, bytes]]:
    """Seconds to render the report (the page and every figure), and the figures, by one
    process or two (``LESMC_DRAW_PROCESSES``, lesmc/report/drawing.py)."""
    image_for = frames_reader(None if frames_dir is None else str(frames_dir))
    with mock.patch.dict(os.environ, {"LESMC_DRAW_PROCESSES": str(processes)}):
        t0 = time.perf_counter()
        _, pngs = render(doc, image_for, None)
        return time.perf_counter() - t0, pngs


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("results", nargs="?", default="lesmc-verify/results.json")
    ap.add_argument("--frames", default="lesmc-verify/video")
    ap.add_argument("--rounds", type=int, default=3)
    args = ap.parse_args()
    doc = json.loads(Path(args.results).read_text())
    frames_dir = Path(args.frames) if Path(args.frames).is_dir() else None
    own = figures.png
    figures.pyplot()  # imported once, outside the timings
    table = Table(title=f"the report's figures of {args.results}")
    for col in ("round", "figures", "tight, 1 process s", "lesmc, 1 s", "lesmc, 2 s", "2 / tight"):
        table.add_column(col, justify="right")
    same = True
    for i in range(args.rounds):
        figures.png = reference
        tight, want = draw_all(doc, frames_dir, 1)
        figures.png = own
        one, got = draw_all(doc, frames_dir, 1)
        two, got2 = draw_all(doc, frames_dir, 2)
        same &= got == want == got2
        table.add_row(
            str(i + 1),
            str(len(got)),
            f"{tight:.2f}",
            f"{one:.2f}",
            f"{two:.2f}",
            f"{two / tight:.2f}",
        )
    Console().print(table)
    print("the same bytes" if same else "THE FIGURES DIFFER")


if __name__ == "__main__":
    main()
