"""Hijacking a SORT track on TUD-Campus (docs/results.md): for each pedestrian of the
ground truth, the cheapest attack that switches its identity within a 5-frame window, and
the fewest frames. Prints a Markdown table; every number comes from ``lesmc check``.

    python examples/sort_hijack.py [--radius R] [--tracks 1,2,...] [--out DIR]

The scene is motmetrics' bundled TUD-Campus: its ``test.txt`` boxes are the detections
(every payoff 1, so the cheapest attack counts the detections hidden) and its ``gt.txt``
the truth, imported with ``lesmc import mot --gt gt.txt --track ID``: the target's reference
is its ground-truth track. For a pedestrian first seen at step s the attack window is
steps s+3..s+7 (its track confirmed by SORT's three hits first) and the run ends 4 steps
later (the time a new track takes to be output), or at the pedestrian's last frame.
"""

from __future__ import annotations

import argparse
import json
import subprocess
import sys
import time
from pathlib import Path

SPEC = """property cheapest {{
  attack window {l}..{u}{within}
  end {end}
  minimize payoff
  subject to switches(0..end) > 0
  holds if optimum > 1
}}
property fewest_frames {{
  attack window {l}..{u}{within}
  end {end}
  minimize count.frames
  subject to switches(0..end) > 0
  holds if optimum > 1
}}
"""


def tud_campus() -> Path:
    """motmetrics' bundled TUD-Campus folder (test.txt, gt.txt)."""
    import motmetrics

    return Path(motmetrics.__file__).parent / "data" / "TUD-Campus"


def lesmc(*args: str) -> subprocess.CompletedProcess[str]:
    """``python -m lesmc ARGS``; a failure stops the script with its message."""
    r = subprocess.run([sys.executable, "-m", "lesmc", *args], capture_output=True, text=True)
    if r.returncode not in (0, 1):
        sys.exit(f"lesmc {' '.join(args)}: exit {r.returncode}\n{r.stderr}")
    return r


def gt_spans(gt: Path) -> dict[int, tuple[int, int]]:
    """Each gt track's first and last frame."""
    spans: dict[int, tuple[int, int]] = {}
    for line in gt.read_text().splitlines():
        if line.strip():
            f, i = (int(float(v)) for v in line.split(",")[:2])
            a, b = spans.get(i, (f, f))
            spans[i] = (min(a, f), max(b, f))
    return spans


def window_of(first: int, last: int, first_frame: int, last_frame: int) -> tuple[int, int, int]:
    """The attack window l..u and the end for a pedestrian seen in frames first..last."""
    s = first - first_frame
    l, u = s + 3, s + 7
    end = min(u + 4, last - first_frame, last_frame - first_frame)
    return l, u, max(end, u)


def run(track: int, radius: float | None, out: Path) -> dict[str, object]:
    """One pedestrian's row: the steps 0..end where the unattacked SORT has a target's
    track (``tracked``), window, end, optima (None: no attack switches it), hidden
    detections of the cheapest attack, states, seconds."""
    d = tud_campus()
    scene = out / f"tud_{track}.json"
    lesmc("import", "mot", str(d / "test.txt"), "--gt", str(d / "gt.txt"),
          "--track", str(track), "-o", str(scene))  # fmt: skip
    first, last = gt_spans(d / "gt.txt")[track]
    l, u, end = window_of(first, last, 1, 71)
    spec = out / f"tud_{track}.spec"
    within = "" if radius is None else f" within {radius:g}"
    spec.write_text(SPEC.format(l=l, u=u, end=end, within=within))
    tr = lesmc("track", str(scene), "--design", "sort", "--json")
    unattacked = [s["target_id"] for s in json.loads(tr.stdout)["track"]][: end + 1]
    t0 = time.perf_counter()
    r = lesmc("check", str(scene), str(spec), "--design", "sort", "--json")
    seconds = time.perf_counter() - t0
    res = {x["property"]: x for x in json.loads(r.stdout)["results"]}
    cheap = res["cheapest"]
    hidden = [h for s in cheap["counterexample"] or [] for h in s["hidden"]]
    ids = [s["target_id"] for s in cheap["counterexample"] or []]
    return {
        "track": track,
        "frames": f"{first}..{last}",
        "window": f"{l}..{u}",
        "end": end,
        "tracked": sum(i is not None for i in unattacked),
        "cheapest": cheap["optimum"],
        "fewest_frames": res["fewest_frames"]["optimum"],
        "hidden": hidden,
        "ids": [i for k, i in enumerate(ids) if i is not None and i not in ids[:k]],
        "states": cheap["states"],
        "seconds": seconds,
    }


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--radius", type=float, default=None, help="attack window ... within R")
    ap.add_argument("--tracks", default=None, help="gt ids, comma-separated [default: all]")
    ap.add_argument("--out", default="/tmp/lesmc-sort-hijack", help="scenes and specs")
    a = ap.parse_args()
    out = Path(a.out)
    out.mkdir(parents=True, exist_ok=True)
    spans = gt_spans(tud_campus() / "gt.txt")
    tracks = sorted(spans) if a.tracks is None else [int(t) for t in a.tracks.split(",")]
    print("| gt id | frames | tracked | window (steps) | end | cheapest (detections) "
          "| fewest frames | hidden (cheapest) | target's ids | states | seconds |")  # fmt: skip
    print("|---|---|---|---|---|---|---|---|---|---|---|")
    for t in tracks:
        row = run(t, a.radius, out)

        def show(v: object) -> str:
            return "none" if v is None else f"{v:g}" if isinstance(v, float) else str(v)

        print(
            f"| {t} | {row['frames']} | {row['tracked']} | {row['window']} | {row['end']} | "
            f"{show(row['cheapest'])} | {show(row['fewest_frames'])} | "
            f"{', '.join(row['hidden']) or '-'} | {' → '.join(map(str, row['ids']))} | "  # type: ignore[call-overload]
            f"{row['states']:,} | {row['seconds']:.1f} |",
            flush=True,
        )


if __name__ == "__main__":
    main()
