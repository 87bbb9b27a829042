"""Benchmark (issues 58 and 62): the exact minimum-switch attack on SORT (``lesmc check
--design sort``) on instances drawn at run time, against the time of running the reference
SORT once per explored state.

Each instance is drawn from ``--seed-base`` + i (printed, so a run can be repeated; the
default seed base comes from the clock, so nobody tunes on it): a sequence (motmetrics'
bundled TUD-Campus or TUD-Stadtmitte), a pedestrian of its ground truth, and a start frame
where the pedestrian is present. The scene is the sequence's detections (``lesmc import mot
--gt --track ID``, every payoff 1; the reference is the gt track) from that frame on:
``--lead`` frames before a ``--window``-frame attack window, ``--after`` frames after it.
The property: ``attack window L..U within R; minimize payoff subject to switches(0..end) >
0``.

Per instance, side by side: the states and transitions the search explored, the engine's
seconds (``lesmc.pipeline.multi.multi_results`` in this process: unfolding and search;
wall and CPU), the user's wall time (the CLI ``lesmc check --design sort --json`` as a
subprocess, start-up included), the seconds of ONE run of the reference SORT (PyPI
``sort-tracker-py``, unchanged; tests/sort_reference.py) over the same frames (the median
of ``--sample`` runs), that time the number of explored states (the issue's yardstick), and
the ratio engine / yardstick (issue 62's bar: at most 10). Then the median and the worst.

Run ``PYTHONPATH=. python benchmarks/bench_multi_attack.py [--seed-base N] [--instances
10] [--window 5] [--radius 150] [--lead 3] [--after 4]``; ``--radius 0`` makes every
detection attackable (``--max-states`` bounds such runs: an instance past it is reported,
not dropped).
"""

from __future__ import annotations

import argparse
import json
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path
from typing import Any

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))
sys.path.insert(0, str(ROOT / "tests"))  # tests/sort_reference.py: the reference SORT

from lesmc.common.errors import BudgetError  # noqa: E402
from lesmc.language.parser import parse_spec  # noqa: E402
from lesmc.pipeline.multi import multi_results  # noqa: E402
from lesmc.scene import load_scene  # noqa: E402

SEQUENCES = ("TUD-Campus", "TUD-Stadtmitte")

SPEC = """property min_switch {{
  attack window {l}..{u}{within}
  end {end}
  minimize payoff
  subject to switches(0..end) > 0
  holds if optimum > 1
}}
"""


def mot_dir(name: str) -> Path:
    """motmetrics' bundled sequence ``name``."""
    import motmetrics

    return Path(motmetrics.__file__).parent / "data" / name


def draw(rng: np.random.Generator, frames: int) -> tuple[str, int, int]:
    """A sequence, a gt pedestrian and a first frame at which it is present and from which
    the sequence has ``frames`` frames."""
    name = str(rng.choice(SEQUENCES))
    gt = np.loadtxt(mot_dir(name) / "gt.txt", delimiter=",", ndmin=2)
    last = int(gt[:, 0].max())
    rows = gt[gt[:, 0] <= last - frames + 1]
    row = rows[rng.integers(len(rows))]
    return name, int(row[1]), int(row[0])


def scene_file(name: str, track: int, first: int, frames: int, out: Path) -> Path:
    """The sequence ``name`` imported with gt track ``track`` as the target, cut to
    ``frames`` frames from ``first`` on, the target at its gt box centre at ``first``."""
    d = mot_dir(name)
    full = out / f"{name}_{track}.json"
    if not full.exists():
        cmd = [sys.executable, "-m", "lesmc", "import", "mot", str(d / "test.txt"),
               "--gt", str(d / "gt.txt"), "--track", str(track), "-o", str(full)]  # fmt: skip
        subprocess.run(cmd, check=True, capture_output=True, cwd=ROOT)
    doc = json.loads(full.read_text())
    keep = range(first, first + frames)
    doc["frames"] = [f for f in doc["frames"] if f["step"] in keep]
    for t in doc["truth"]:
        t["positions"] = [p for p in t["positions"] if p[0] in keep]
    doc["truth"] = [t for t in doc["truth"] if t["positions"]]
    me = next(t for t in doc["truth"] if t["id"] == str(track))
    x, y = next((p[1], p[2]) for p in me["positions"] if p[0] == first)
    doc["target"] = {"step": first, "start": [x, y]}
    doc["tracker"] = {**doc["tracker"], "design": "sort"}
    path = out / f"{name}_{track}_{first}.json"
    path.write_text(json.dumps(doc))
    return path


def sort_seconds(path: Path, sample: int) -> float:
    """The median seconds of one reference-SORT run over the scene's frames."""
    import sort_reference

    frames = [f.boxes() for f in load_scene(str(path)).frames]
    sort_reference.reference_sort(frames)  # untimed: imports filterpy and SORT
    times = []
    for _ in range(sample):
        t0 = time.perf_counter()
        sort_reference.reference_sort(frames)
        times.append(time.perf_counter() - t0)
    return statistics.median(times)


def instance(path: Path, spec_text: str, sample: int, max_states: int) -> dict[str, Any]:
    """One instance's measurements (see the module's docstring)."""
    spec_path = path.with_suffix(".spec")
    spec_path.write_text(spec_text)
    spec = parse_spec(spec_text, str(spec_path))
    scene = load_scene(str(path))
    w0, c0 = time.perf_counter(), time.process_time()
    try:
        res = multi_results(scene, str(path), (spec,), max_states=max_states)[0]
    except BudgetError as e:
        return {"budget": str(e)}
    wall, cpu = time.perf_counter() - w0, time.process_time() - c0
    t0 = time.perf_counter()
    cmd = [sys.executable, "-m", "lesmc", "check", str(path), str(spec_path), "--design",
           "sort", "--json", "--max-states", str(max_states)]  # fmt: skip
    r = subprocess.run(cmd, capture_output=True, text=True, cwd=ROOT)
    user = time.perf_counter() - t0
    if r.returncode not in (0, 1):
        raise SystemExit(r.stderr)
    per = sort_seconds(path, sample)
    yard = per * res["states"]
    return {
        "states": res["states"],
        "transitions": res["transitions"],
        "optimum": res["optimum"],
        "wall": wall,
        "cpu": cpu,
        "user": user,
        "sort": per,
        "yard": yard,
        "ratio": wall / yard,
    }


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seed-base", type=int, default=None)
    ap.add_argument("--instances", type=int, default=10)
    ap.add_argument("--window", type=int, default=5, help="attack window length (frames)")
    ap.add_argument("--lead", type=int, default=3, help="frames before the window")
    ap.add_argument("--after", type=int, default=4, help="frames after the window")
    ap.add_argument("--radius", type=float, default=150.0, help="within R; 0: every detection")
    ap.add_argument("--sample", type=int, default=20, help="timed reference-SORT runs")
    ap.add_argument("--max-states", type=int, default=2_000_000)
    a = ap.parse_args()
    base = a.seed_base if a.seed_base is not None else int(time.time()) % 1_000_000
    l, u = a.lead, a.lead + a.window - 1
    end = u + a.after
    within = "" if a.radius <= 0 else f" within {a.radius:g}"
    spec_text = SPEC.format(l=l, u=u, end=end, within=within)
    out = Path(tempfile.mkdtemp(prefix="bench-multi-"))
    print(f"seed base {base}; attack window {l}..{u}{within}, end {end}; {a.instances} instances")
    print("| seed | sequence | gt track | first frame | states | transitions | optimum | "
          "engine s (wall) | engine s (CPU) | user wall s (CLI) | one SORT run s | "
          "SORT x states s | ratio |")  # fmt: skip
    print("|---|---|---|---|---|---|---|---|---|---|---|---|---|")
    ratios = []
    for i in range(a.instances):
        seed = base + i
        name, track, first = draw(np.random.default_rng(seed), end + 1)
        path = scene_file(name, track, first, end + 1, out)
        m = instance(path, spec_text, a.sample, a.max_states)
        head = f"| {seed} | {name} | {track} | {first} |"
        if "budget" in m:
            print(f"{head} over --max-states: {m['budget']} |", flush=True)
            continue
        ratios.append(m["ratio"])
        opt = "none" if m["optimum"] is None else f"{m['optimum']:g}"
        print(
            f"{head} {m['states']:,} | {m['transitions']:,} | {opt} | {m['wall']:.3f} | "
            f"{m['cpu']:.3f} | {m['user']:.2f} | {m['sort']:.5f} | {m['yard']:.3f} | "
            f"{m['ratio']:.2g} |",
            flush=True,
        )
    if ratios:
        print(
            f"ratio engine / (one SORT run x states) over {len(ratios)} instances: "
            f"median {statistics.median(ratios):.2g}, worst {max(ratios):.2g}"
        )


if __name__ == "__main__":
    main()
