"""Benchmark and results: the fewest frames to hijack a pedestrian with SORT, hiding only
against hiding and injecting (issue 61; docs/results.md, "Attacks that inject").

The pedestrians are drawn at run time from ``--seed-base`` (printed; by default from the
clock, so that nobody tunes on them): ``--instances`` ground-truth tracks of motmetrics'
TUD-Campus and TUD-Stadtmitte ``gt.txt`` (the sequence, then the track). For each one
long enough for the window, ``examples/shifted_candidates.py`` makes the injection
candidates (the target's
detection of ``test.txt`` shifted right by 0.3 and 0.6 of its width, price 1; the
target's detection payoff 1, every other detection unattackable: a modelling device),
``lesmc import mot`` makes the scene, and ``lesmc check --design sort`` minimises
``count.frames subject to switches(0..end) > 0`` in a window of ``--steps`` steps that
starts ``--after`` steps into the longest run of frames in which the pedestrian is
detected (the target: its detection at the run's first frame), ``end`` ``--tail``
steps after the window or at the run's end, once with ``attack window L..U`` (hide)
and once with ``allow hide, inject``, under SORT's defaults (max_age 1, min_hits 3)
and the hijacking paper's setting (max_age 60, min_hits 6; a tracker file). Every
number is read from the real command's JSON; states and seconds side by side.

At the end: the median and the worst seconds and states of each column.

Run ``python benchmarks/bench_inject_tud.py [--seed-base N] [--instances 7] [--steps 4]
[--after 7] [--tail 8] [--out DIR]``; ``--tracks 1,2`` runs those TUD-Campus pedestrians
instead (docs/results.md's tables).
"""

from __future__ import annotations

import argparse
import itertools
import json
import statistics
import subprocess
import sys
import time
from pathlib import Path

import motmetrics
import numpy as np

ROOT = Path(__file__).resolve().parents[1]
DATA = Path(motmetrics.__file__).parent / "data"
SEQUENCES = ("TUD-Campus", "TUD-Stadtmitte")
SETTINGS = {"sort": {}, "paper": {"max_age": 60, "min_hits": 6}}
SPEC = """property hijack {{ attack window {l}..{u}{allow} minimize count.frames
  subject to switches(0..end) > 0 holds if optimum > 1000 end {end} }}
"""


def _run(*args: str) -> subprocess.CompletedProcess[str]:
    env = {"PYTHONPATH": str(ROOT)}
    return subprocess.run(
        [sys.executable, *args], capture_output=True, text=True, cwd=ROOT, env=env, check=False
    )


def seed_base(given: int | None) -> int:
    """The seed base: ``given``, else one from the clock (printed by the caller)."""
    return given if given is not None else int(time.time()) % 1_000_000


def draw_tracks(base: int, n: int) -> list[tuple[str, int]]:
    """``n`` distinct (sequence, gt track) pairs drawn from seed ``base``: a sequence of
    :data:`SEQUENCES`, then one of its tracks."""
    rng = np.random.default_rng(base)
    ids = {
        q: sorted({int(r[1]) for r in np.loadtxt(DATA / q / "gt.txt", delimiter=",", ndmin=2)})
        for q in SEQUENCES
    }
    n = min(n, sum(len(v) for v in ids.values()))
    out: list[tuple[str, int]] = []
    while len(out) < n:
        q = SEQUENCES[int(rng.integers(len(SEQUENCES)))]
        pick = (q, ids[q][int(rng.integers(len(ids[q])))])
        if pick not in out:
            out.append(pick)
    return out


def chosen(tracks: str | None, base: int, n: int) -> list[tuple[str, int]]:
    """TUD-Campus's ``tracks`` (a comma-separated list: the runs docs/results.md shows),
    else :func:`draw_tracks`."""
    if tracks:
        return [("TUD-Campus", int(t)) for t in tracks.split(",")]
    return draw_tracks(base, n)


def summary(label: str, values: list[float]) -> str:
    """``label``: the median and the worst (largest) of ``values``."""
    if not values:
        return f"{label}: none"
    return f"{label}: median {statistics.median(values):g}, worst {max(values):g}"


def _scene(seq: str, track: int, out: Path) -> tuple[Path, tuple[str, int, int]] | None:
    """The scene of ``track`` of sequence ``seq`` with its candidates, and its target
    (:func:`_target`); None: no detection overlaps the track."""
    det = out / f"det_{seq}_{track}.txt"
    r = _run(
        "examples/shifted_candidates.py",
        str(DATA / seq / "test.txt"),
        str(DATA / seq / "gt.txt"),
        str(track),
        str(det),
    )
    if r.returncode:
        return None
    scene = out / f"scene_{seq}_{track}.json"
    r = _run(
        "-m", "lesmc", "import", "mot", str(det), "-o", str(scene),
        "--payoff-column", "9", "--inject-column", "8", "--threshold", "0.5",
    )  # fmt: skip
    if r.returncode:
        raise SystemExit(r.stderr)
    return scene, _target(det)


def _target(det: Path) -> tuple[str, int, int]:
    """The target's detection (payoff 1 in column 9) at the first frame of its longest run
    of consecutive frames, as X,Y@FRAME, and that run's first and last frames."""
    rows = [c for c in (line.split(",") for line in det.read_text().splitlines()) if c[8] == "1"]
    if not rows:
        raise SystemExit(f"{det}: no target detection")
    frames = [int(c[0]) for c in rows]
    best, start = (frames[0], frames[0]), frames[0]
    for a, b in itertools.pairwise(frames):
        if b != a + 1:
            start = b
        if b - start > best[1] - best[0]:
            best = (start, b)
    c = rows[frames.index(best[0])]
    x, y = float(c[2]) + float(c[4]) / 2, float(c[3]) + float(c[5]) / 2
    return f"{x!r},{y!r}@{c[0]}", best[0], best[1]


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--seed-base", type=int, default=None)
    ap.add_argument("--instances", type=int, default=7)
    ap.add_argument("--tracks", help="TUD-Campus gt tracks (1,2,...) instead of drawn ones")
    ap.add_argument("--steps", type=int, default=4)
    ap.add_argument("--after", type=int, default=7)
    ap.add_argument("--tail", type=int, default=8)
    ap.add_argument("--out", default="/tmp/lesmc-inject-tud")
    args = ap.parse_args()
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    for name, keys in SETTINGS.items():
        (out / f"{name}.json").write_text(json.dumps({"design": "sort", **keys}))
    base = seed_base(args.seed_base)
    print(f"seed base {base}")
    print("seq track setting window end | hide: frames states s | hide+inject: frames states s")
    cols: dict[str, list[float]] = {}
    for seq, track in chosen(args.tracks, base, args.instances):
        made = _scene(seq, track, out)
        if made is None:
            print(f"{seq} {track}: no detection overlaps the track", flush=True)
            continue
        scene, (target, first, last) = made
        l = first - 1 + args.after  # steps count from frame 1
        u = l + args.steps - 1
        end = min(u + args.tail, last - 1)
        if end <= u:
            print(f"{seq} {track}: frames {first}..{last} are too few for the window", flush=True)
            continue
        for name in SETTINGS:
            row = [f"{seq} {track} {name} {l}..{u} {end}"]
            for allow in ("", " allow hide, inject"):
                spec = out / "p.spec"
                spec.write_text(SPEC.format(l=l, u=u, end=end, allow=allow))
                t0 = time.perf_counter()
                r = _run(
                    "-m", "lesmc", "check", str(scene), str(spec), "--design", "sort",
                    "--target", target, "--tracker", str(out / f"{name}.json"), "--json",
                )  # fmt: skip
                secs = time.perf_counter() - t0
                if r.returncode == 2 and "no reference track" in r.stderr:
                    row.append("no reference (its unattacked track is never output)")
                    continue
                if r.returncode not in (0, 1):
                    raise SystemExit(r.stderr)
                res = json.loads(r.stdout)["results"][0]
                opt = "inf" if res["optimum"] is None else f"{res['optimum']:g}"
                row.append(f"{opt} {res['states']} {secs:.1f}")
                key = f"{name} {'hide+inject' if allow else 'hide'}"
                cols.setdefault(f"{key} seconds", []).append(secs)
                cols.setdefault(f"{key} states", []).append(res["states"])
            print(" | ".join(row), flush=True)
    for label, values in cols.items():
        print(summary(label, values))


if __name__ == "__main__":
    main()
