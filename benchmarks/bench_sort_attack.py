"""Benchmark: the exact minimum-switch attack on SORT (``lesmc check --design sort``) on
TUD-Campus with a 5-frame window, against the brute force that would run the reference
SORT once per way to hide detections (issue 58, docs/performance.md).

Side by side in one run: lesmc's unfolding and search (seconds, states, transitions, the
optimum) and the brute force's size, the number of reference-SORT runs it needs (every
subset of the attackable detections of each window frame: the product of 2^k), with the
time of that many runs estimated from a timed sample of them (the reference SORT,
``sort-tracker-py`` run unchanged, on frames 0..end with a random subset hidden in the
window).

benchmarks/bench_multi_attack.py measures instances drawn at run time against one
reference-SORT run per explored state (issue 62's yardstick); this one, one pedestrian
against the brute force's count of runs.

Run ``python benchmarks/bench_sort_attack.py [--track 1] [--window 3..7] [--end 11]
[--radius 150 ...] [--full] [--sample 40]``: ``attack window ... within R`` for each R
(default 150), and with ``--full`` every detection attackable. The
scene is motmetrics' bundled TUD-Campus (``lesmc import mot test.txt --gt gt.txt --track
ID``: detections with boxes, every payoff 1; the reference is the gt track).
"""

from __future__ import annotations

import argparse
import math
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))
sys.path.insert(0, str(ROOT / "tests"))  # tests/sort_reference.py: the reference SORT

from lesmc.cli.multi_check import multi_results  # noqa: E402
from lesmc.language.parser import parse_spec  # noqa: E402
from lesmc.scene import load_scene  # noqa: E402
from lesmc.tracking.multi import SortDesign, reference_boxes  # noqa: E402
from lesmc.unfold.multi import attackable  # noqa: E402

SPEC = """property min_switch {{
  attack window {l}..{u}{within}
  end {end}
  minimize payoff
  subject to switches(0..end) > 0
  holds if optimum > 1
}}
"""


def scene_file(track: int, out: Path) -> Path:
    """TUD-Campus imported with gt track ``track`` as the target."""
    import motmetrics

    d = Path(motmetrics.__file__).parent / "data" / "TUD-Campus"
    path = out / f"tud_{track}.json"
    cmd = [sys.executable, "-m", "lesmc", "import", "mot", str(d / "test.txt"),
           "--gt", str(d / "gt.txt"), "--track", str(track), "-o", str(path)]  # fmt: skip
    subprocess.run(cmd, check=True, capture_output=True)
    return path


def brute_force(
    frames: list[np.ndarray], can: list[np.ndarray], l: int, u: int, sample: int, seed: int
) -> tuple[int, float]:
    """The reference-SORT runs a brute force needs (every subset of each window frame's
    attackable detections ``can``), and the seconds of one run, timed on ``sample`` runs
    with random subsets hidden."""
    import sort_reference

    runs = math.prod(2 ** int(can[k].sum()) for k in range(l, u + 1))
    rng = np.random.default_rng(seed)
    sort_reference.reference_sort(frames)  # untimed: imports filterpy and SORT
    t0 = time.perf_counter()
    for _ in range(sample):
        hidden = [f.copy() for f in frames]
        for k in range(l, u + 1):
            idx = np.nonzero(can[k])[0]
            drop = idx[rng.random(len(idx)) < 0.5]
            hidden[k] = np.delete(frames[k], drop, axis=0)
        sort_reference.reference_sort(hidden)
    return runs, (time.perf_counter() - t0) / sample


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--track", type=int, default=1)
    ap.add_argument("--window", default="3..7")
    ap.add_argument("--end", type=int, default=11)
    ap.add_argument("--radius", type=float, action="append", help="within R (repeatable)")
    ap.add_argument("--full", action="store_true", help="also every detection attackable")
    ap.add_argument("--sample", type=int, default=40)
    a = ap.parse_args()
    l, u = (int(x) for x in a.window.split(".."))
    out = Path(tempfile.mkdtemp(prefix="bench-sort-"))
    path = scene_file(a.track, out)
    scene = load_scene(str(path)).with_tracker(design="sort")  # as --design sort
    frames = [f.boxes() for f in scene.frames[: a.end + 1]]
    refs = reference_boxes(scene, [s.tracks for s in SortDesign(scene, str(path)).run(a.end)])
    radii: list[float | None] = [*(a.radius or [150.0]), *([None] if a.full else [])]
    print(f"TUD-Campus, gt track {a.track}, attack window {l}..{u}, end {a.end}")
    print("| attackable | lesmc: seconds | states | transitions | optimum | "
          "brute force: reference-SORT runs | s per run | estimated seconds | ratio |")  # fmt: skip
    print("|---|---|---|---|---|---|---|---|---|")
    for r in radii:
        within = "" if r is None else f" within {r:g}"
        spec = parse_spec(SPEC.format(l=l, u=u, end=a.end, within=within), "bench.spec")
        t0 = time.perf_counter()
        res = multi_results(scene, str(path), (spec,))[0]
        secs = time.perf_counter() - t0
        can = [attackable(f, refs[k], r) for k, f in enumerate(scene.frames[: a.end + 1])]
        runs, per = brute_force(frames, can, l, u, a.sample, seed=a.track)
        est = runs * per
        opt = "none" if res["optimum"] is None else f"{res['optimum']:g}"
        what = "all detections" if r is None else f"within {r:g} px"
        print(
            f"| {what} | {secs:.1f} | {res['states']:,} | {res['transitions']:,} | {opt} | "
            f"{runs:,} | {per:.4f} | {est:,.0f} | {est / secs:,.0f}x |",
            flush=True,
        )


if __name__ == "__main__":
    main()
