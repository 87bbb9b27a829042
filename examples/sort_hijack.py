"""Hijacking a SORT track on TUD-Campus (docs/results.md): for each pedestrian of the
ground truth, the cheapest attack that switches its identity within a 5-frame window, and
the fewest frames. Prints a Markdown table; every number comes from ``lesmc check``.

    python examples/sort_hijack.py [--radius R] [--tracks 1,2,...] [--out DIR]

The scene is motmetrics' bundled TUD-Campus: its ``test.txt`` boxes are the detections
(every payoff 1, so the cheapest attack counts the detections hidden) and its ``gt.txt``
the truth, imported with ``lesmc import mot --gt gt.txt --track ID``: the target's reference
is its ground-truth track. The attack window is the 5 steps after the first step at which
the unattacked SORT has a track of the pedestrian (IoU >= 0.5 with its gt box), and the
run ends 4 steps later (the time a new track takes to be output) or at the pedestrian's
last frame. The property asks for one switch more than the unattacked run makes in
0..end (SORT alone relabels some pedestrians: an attack is needed only beyond that). A
pedestrian SORT never tracks has no row of optima.
"""

from __future__ import annotations

import argparse
import json
import subprocess
import sys
import time
from pathlib import Path

from lesmc.model.identity import switches

SPEC = """property cheapest {{
  attack window {l}..{u}{within}
  end {end}
  minimize payoff
  subject to switches(0..end) > {n0}
  holds if optimum > 1
}}
property fewest_frames {{
  attack window {l}..{u}{within}
  end {end}
  minimize count.frames
  subject to switches(0..end) > {n0}
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


def window_of(tracked: list[int | None], last: int) -> tuple[int, int, int] | None:
    """The attack window l..u and the end for a pedestrian whose target's track id on the
    unattacked run is ``tracked[k]`` at step k and whose last frame is step ``last``: the
    5 steps after the first step with a track, the end 4 steps later (the time a new
    track takes to be output) or at its last frame; None: never tracked."""
    first = next((k for k, i in enumerate(tracked) if i is not None), None)
    if first is None:
        return None
    l = max(1, first + 1)
    u = min(l + 4, len(tracked) - 1)
    end = max(u, min(u + 4, last, len(tracked) - 1))
    return l, u, end


def run(track: int, radius: float | None, out: Path) -> dict[str, object]:
    """One pedestrian's row: its frames, the steps of the unattacked run where the
    target has a track (``tracked``), window, end, the optima (None: no attack switches
    it), the cheapest attack's hidden detections and the target's ids on it, states,
    seconds (of the check, the process included)."""
    d = tud_campus()
    scene = out / f"tud_{track}.json"
    lesmc("import", "mot", str(d / "test.txt"), "--gt", str(d / "gt.txt"),
          "--track", str(track), "-o", str(scene))  # fmt: skip
    first, last = gt_spans(d / "gt.txt")[track]
    tr = lesmc("track", str(scene), "--design", "sort", "--json")
    tracked = [s["target_id"] for s in json.loads(tr.stdout)["track"]]
    row: dict[str, object] = {"track": track, "frames": f"{first}..{last}"}
    row["tracked"] = sum(i is not None for i in tracked)
    w = window_of(tracked, last - 1)  # step k is frame k + 1
    if w is None:
        return row
    l, u, end = w
    spec = out / f"tud_{track}.spec"
    within = "" if radius is None else f" within {radius:g}"
    n0 = switches(tracked[: end + 1], 0, end)  # the unattacked run's own switches
    spec.write_text(SPEC.format(l=l, u=u, end=end, within=within, n0=n0))
    t0 = time.perf_counter()
    r = lesmc("check", str(scene), str(spec), "--design", "sort", "--json")
    seconds = time.perf_counter() - t0
    res = {x["property"]: x for x in json.loads(r.stdout)["results"]}
    cheap = res["cheapest"]
    hidden = [h for s in cheap["counterexample"] or [] for h in s["hidden"]]
    ids = [s["target_id"] for s in cheap["counterexample"] or []]
    row.update(
        window=f"{l}..{u}",
        end=end,
        unattacked=n0,
        cheapest=cheap["optimum"],
        fewest_frames=res["fewest_frames"]["optimum"],
        hidden=", ".join(hidden) or "-",
        ids=" → ".join(str(i) for k, i in enumerate(ids) if i is not None and i not in ids[:k]),
        states=f"{cheap['states']:,}",
        seconds=f"{seconds:.1f}",
    )
    return row


COLUMNS = ("track", "frames", "tracked", "window", "end", "unattacked", "cheapest", "fewest_frames",
           "hidden", "ids", "states", "seconds")  # fmt: skip


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
    print("| gt id | frames | steps tracked | window (steps) | end | unattacked switches "
          "| cheapest (detections) | fewest frames | hidden (cheapest) | target's ids | states "
          "| seconds |")  # fmt: skip
    print("|---|---|---|---|---|---|---|---|---|---|---|---|")
    for t in tracks:
        row = run(t, a.radius, out)
        cells = [row.get(c, "") for c in COLUMNS]
        shown = ["none" if v is None else f"{v:g}" if isinstance(v, float) else str(v)
                 for v in cells]  # fmt: skip
        if "window" not in row:
            shown[3] = "never tracked"
        print("| " + " | ".join(shown) + " |", flush=True)


if __name__ == "__main__":
    main()
