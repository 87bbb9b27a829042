"""Front-end speed and memory: time per stage on a 2048x2048 frame, peak RSS on a large video.

    python benchmarks/bench_perception.py                 # 2048x2048, 8 frames
    python benchmarks/bench_perception.py --size 12000x10000 --frames 6

Generation and perception run in separate processes so each peak RSS is its own.
Figures are recorded in docs/performance.md.
"""

from __future__ import annotations

import argparse
import subprocess
import sys
import tempfile
import time
from pathlib import Path

# runs lesmc in a child that reports its own peak resident memory (KiB) on exit
_WRAP = (
    "import atexit, resource, sys\n"
    "atexit.register(lambda: print('PEAK_KIB', resource.getrusage(resource.RUSAGE_SELF)"
    ".ru_maxrss, file=sys.stderr))\n"
    "sys.argv = ['lesmc', *sys.argv[1:]]\n"
    "from lesmc.cli.main import main\n"
    "main()\n"
)


def peak_rss_gib(args: list[str]) -> tuple[float, float]:
    """Run ``lesmc ARGS``; return (seconds, that process's own peak resident memory in GiB)."""
    t = time.perf_counter()
    r = subprocess.run(
        [sys.executable, "-c", _WRAP, *args],
        check=True,
        stdout=subprocess.DEVNULL,
        stderr=subprocess.PIPE,
        text=True,
    )
    wall = time.perf_counter() - t
    kib = max(int(line.split()[1]) for line in r.stderr.splitlines() if line.startswith("PEAK_KIB"))
    return wall, kib / 2**20


def stage_times(frames_dir: Path, history: int) -> dict[str, float]:
    """Mean seconds per frame of each front-end stage (after the history is full)."""
    import numpy as np

    from lesmc.perception.background import FrameHistory, background
    from lesmc.perception.blobs import BlobConfig, blobs, foreground
    from lesmc.perception.registration import RegistrationConfig, describe, register
    from lesmc.video.reader import open_frames

    fs = open_frames(frames_dir, history + 1)
    rc, bc = RegistrationConfig(), BlobConfig()
    hist = FrameHistory(history)
    times: dict[str, list[float]] = {
        k: [] for k in ("describe", "register", "align", "median", "blobs", "total")
    }
    prev_f = None
    for img in fs:
        t0 = time.perf_counter()
        f = describe(img, rc)
        t1 = time.perf_counter()
        if prev_f is not None:
            reg = register(prev_f, f, rc, hist.frames[-1], img)
            t2 = time.perf_counter()
            hist.advance(reg.homography)
            if hist.full():
                al = hist.aligned((img.shape[1], img.shape[0]))
                t3 = time.perf_counter()
                bg = background(al, img)
                t4 = time.perf_counter()
                diff, mask = foreground(img, bg, al.valid, bc)
                blobs(mask, diff, bc)
                t5 = time.perf_counter()
                for k, v in zip(
                    times, (t1 - t0, t2 - t1, t3 - t2, t4 - t3, t5 - t4, t5 - t0), strict=True
                ):
                    times[k].append(v)
        hist.push(img)
        prev_f = f
    return {k: float(np.mean(v)) for k, v in times.items() if v}


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--size", default="2048x2048")
    ap.add_argument("--frames", type=int, default=8)
    ap.add_argument("--history", type=int, default=4)
    args = ap.parse_args()
    with tempfile.TemporaryDirectory() as tmp:
        d = Path(tmp) / "video"
        wall, rss = peak_rss_gib(
            ["synth", str(d), "--frames", str(args.frames), "--size", args.size]
        )
        print(f"synth {args.size} x {args.frames}: {wall:.1f} s, peak RSS {rss:.2f} GiB")
        for extra, what in (
            (["--no-cnn"], "perceive --no-cnn (front end)"),
            ([], "perceive (front end + CNNs)"),
        ):
            wall, rss2 = peak_rss_gib(
                ["perceive", str(d), "--history", str(args.history), "--json", *extra]
            )
            print(f"{what}: {wall:.1f} s, peak RSS {rss2:.2f} GiB")
        for k, v in stage_times(d, args.history).items():
            print(f"  {k:<9} {v * 1000:8.1f} ms/frame")


if __name__ == "__main__":
    main()
