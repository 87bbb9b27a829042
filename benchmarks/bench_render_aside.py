"""Benchmark: the default video rendered aside while torch is imported (issue 31).

    python benchmarks/bench_render_aside.py [--rounds 3] [--frames 24]

What the first ``lesmc verify`` does before perceiving, two ways, alternately, each in
a fresh process (an import happens once per process), timed from outside:

- in turn (the reference, what verify did before): ``write_video`` renders the default
  video in this process, then ``lesmc.perception.cnn`` (torch) is imported;
- aside (lesmc now): ``write_video(..., meanwhile=import)``: a child process renders
  while this one imports.

Prints the wall and CPU seconds (children included) of each round and whether the
two videos are the same bytes (SHA-256 of every file). Figures: docs/performance.md.
"""

from __future__ import annotations

import argparse
import hashlib
import resource
import shutil
import subprocess
import sys
import tempfile
import time
from pathlib import Path

from rich.console import Console
from rich.table import Table

SCRIPT = """
import sys
from pathlib import Path
from lesmc.video.synth import SynthConfig
from lesmc.video.write import write_video
def networks():
    import lesmc.perception.cnn
cfg = SynthConfig(frames={frames}, width=2048, height=2048, seed=1)
if sys.argv[1] == "aside":
    write_video(cfg, Path(sys.argv[2]), meanwhile=networks)
else:
    write_video(cfg, Path(sys.argv[2]))
    networks()
"""


def digest(video: Path) -> str:
    h = hashlib.sha256()
    for p in sorted(video.iterdir()):
        h.update(p.name.encode() + p.read_bytes())
    return h.hexdigest()


def run(way: str, out: Path, frames: int) -> tuple[float, float, str]:
    """Wall and CPU seconds (this child and its own children) of one way; the video's hash."""
    shutil.rmtree(out, ignore_errors=True)
    before = resource.getrusage(resource.RUSAGE_CHILDREN)
    t0 = time.perf_counter()
    code = SCRIPT.format(frames=frames)
    subprocess.run([sys.executable, "-c", code, way, str(out)], check=True)
    wall = time.perf_counter() - t0
    after = resource.getrusage(resource.RUSAGE_CHILDREN)
    cpu = (after.ru_utime - before.ru_utime) + (after.ru_stime - before.ru_stime)
    return wall, cpu, digest(out)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--rounds", type=int, default=3)
    ap.add_argument("--frames", type=int, default=24)
    args = ap.parse_args()
    table = Table(title="render the default video, then import torch")
    for col in ("round", "in turn s", "aside s", "aside / in turn", "CPU in turn", "CPU aside"):
        table.add_column(col, justify="right")
    hashes = set()
    with tempfile.TemporaryDirectory() as tmp:
        for i in range(args.rounds):
            turn = run("turn", Path(tmp) / "turn", args.frames)
            aside = run("aside", Path(tmp) / "aside", args.frames)
            hashes |= {turn[2], aside[2]}
            table.add_row(
                str(i + 1),
                f"{turn[0]:.2f}",
                f"{aside[0]:.2f}",
                f"{aside[0] / turn[0]:.2f}",
                f"{turn[1]:.1f}",
                f"{aside[1]:.1f}",
            )
    Console().print(table)
    print("the same bytes" if len(hashes) == 1 else "THE VIDEOS DIFFER")


if __name__ == "__main__":
    main()
