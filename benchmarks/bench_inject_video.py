"""Benchmark and results: the default video's robustness with hide + inject against hide
only (issue 61), the injection candidates coming from the WAMI pipeline itself.

Per video (``lesmc synth --seed S --frames 24``, 2048x2048; seed 1 is the default
video): perception with ``--inject-within W`` (the candidates N_dr rejects within W px of
a detection, priced by DeepFool towards "vehicle"; its extra time measured apart), the
target ``lesmc verify`` chooses (experiment/targets.py ``auto_target`` with the bundled
specs), then per design ``lesmc check`` of the bundled robustness property (window
6..8, ``dist.sum(0..end) > 120``) as ``minimize payoff`` and as ``minimize
count.frames`` (the fewest frames to move the track beyond epsilon), once hide only and
once ``allow hide, inject``, for every design (``joint`` and ``improved`` take inject as
``single`` does). Prints the optima, the states built and the check's wall-clock seconds
side by side. A check stopped by ``--max-states`` or ``--timeout`` prints its verdict
``unknown`` and the bounds found (``unknown [lo, hi]``), never a guessed optimum; a
check that stops with exit status 3 before any verdict (the joint design refuses to
build 2^m subsets of a frame's m candidates past its limit: a BudgetError) prints
``budget`` and its message goes to stderr.

``--near all`` (the default) offers every perceived candidate: the joint design builds,
per state, the subsets of only the candidates that can change its successor (those in
a track's gate or in the birth region of a position its primary can take;
docs/semantics.md, "Pruning injection candidates"). ``--near K`` (a modelling
restriction, named as such in the results): each frame keeps only the K injection
candidates nearest the target's unattacked track (the scene's single tracker) at that
frame, for every design. The perceived scene is cached in ``--out`` (sceneS.json and
its facts): a second run with other designs or ``--near`` does not perceive again.

Usage: PYTHONPATH=. python benchmarks/bench_inject_video.py [--seeds 1,2,3] [--within 30] [--cap N]
       [--designs single,joint,improved] [--max-states N] [--timeout S] [--near all|K]
       [--out /tmp/lesmc-inject-video]
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]

SPEC = """property rob {{ attack window 6..8{allow} minimize payoff
  subject to dist.sum(0..end) > 120 holds if optimum > 3.0 on x, y }}
property frames {{ attack window 6..8{allow} minimize count.frames
  subject to dist.sum(0..end) > 120 holds if optimum > 3 on x, y }}
"""


def _run(*args: str) -> subprocess.CompletedProcess[str]:
    env = {**os.environ, "PYTHONPATH": str(ROOT)}
    return subprocess.run(
        [sys.executable, *args], capture_output=True, text=True, env=env, check=False
    )


def _scene(seed: int, within: float, cap: int, out: Path) -> tuple[Path, dict[str, float]]:
    """The video of ``seed`` perceived with injection candidates, its target placed as
    verify places it; and what perception cost."""
    from lesmc.api import load_spec, save_scene
    from lesmc.experiment.perceive import PerceiveRequest, open_inputs, perceive_frames
    from lesmc.experiment.targets import auto_target
    from lesmc.scene import Scene

    path, facts_path = out / f"scene{seed}.json", out / f"scene{seed}.facts.json"
    if path.exists() and facts_path.exists():
        facts: dict[str, float] = json.loads(facts_path.read_text())
        return path, facts
    video = out / f"v{seed}"
    if not (video / "truth.json").exists():
        r = _run("-m", "lesmc", "synth", str(video), "--seed", str(seed), "--frames", "24")
        if r.returncode:
            raise SystemExit(r.stderr)
    req = PerceiveRequest(
        str(video), truth=str(video / "truth.json"), inject_within=within, inject_cap=cap
    )
    inputs = open_inputs(req)
    t0 = time.perf_counter()
    got = perceive_frames(req, inputs)
    secs = time.perf_counter() - t0
    assert got.scene is not None and not isinstance(got.scene, Scene)
    specs = [load_spec(ROOT / "specs" / f"{n}.spec") for n in ("robustness", "resilience")]
    assert inputs.truth is not None
    scene = auto_target(got.scene, inputs.frames, inputs.truth, specs)
    save_scene(scene, path)
    facts = {
        "perceive_s": secs,
        "inject_s": got.run.inject_seconds,
        "detections": sum(len(f.detections) for f in scene.frames),
        "candidates": sum(len(f.candidates) for f in scene.frames),
    }
    facts_path.write_text(json.dumps(facts))
    return path, facts


def _near(scene_path: Path, k: int) -> Path:
    """The scene with each frame's injection candidates cut to the ``k`` nearest the
    target's unattacked track (single tracker) at that frame (ties: the lower index)."""
    import dataclasses

    import numpy as np

    from lesmc.api import load_scene, save_scene
    from lesmc.tracking.monitor import track
    from lesmc.tracking.trackers import make_tracker

    scene = load_scene(scene_path)
    single = scene.with_tracker(design="single")
    at = {p.frame: p.x[:2] for p in track(make_tracker(single))}
    frames = []
    for f in scene.frames:
        c = f.candidates
        if f.step in at and len(c) > k:
            d = np.hypot(*(np.array([[x.x, x.y] for x in c]) - at[f.step]).T)
            keep = sorted(np.argsort(d, kind="stable")[:k].tolist())
            c = tuple(c[i] for i in keep)
        elif f.step not in at:
            c = ()
        frames.append(dataclasses.replace(f, candidates=c))
    out = scene_path.with_name(f"{scene_path.stem}.near{k}.json")
    save_scene(dataclasses.replace(scene, frames=tuple(frames)), out)
    return out


def _check(scene: Path, design: str, allow: str, out: Path, budget: list[str]) -> dict[str, object]:
    """One ``lesmc check`` of both properties on ``scene``: the optima (or, for a
    property the budget stopped, ``unknown [lo, hi]``), the states built and seconds."""
    spec = out / "p.spec"
    spec.write_text(SPEC.format(allow=allow))
    t0 = time.perf_counter()
    cmd = ["-m", "lesmc", "check", str(scene), str(spec), "--design", design, "--json"]
    r = _run(*cmd, *budget)
    secs = time.perf_counter() - t0
    if r.returncode not in (0, 1, 3):
        raise SystemExit(r.stderr)
    doc = json.loads(r.stdout) if r.stdout.strip() else {}
    if "results" not in doc:  # exit 3 before any verdict: a BudgetError (its error document)
        print(f"seed {scene.stem} {design}{allow}: {r.stderr.strip()}", file=sys.stderr)
        return {"payoff": "budget", "frames": "", "states": 0, "seconds": round(secs, 1)}
    res = {x["property"]: x for x in doc["results"]}
    return {
        "payoff": _optimum(res["rob"]),
        "frames": _optimum(res["frames"]),
        "states": max(res[p]["stats"].get("states_built", 0) for p in res),
        "seconds": round(secs, 1),
    }


def _optimum(res: dict[str, object]) -> str:
    """The optimum as printed, or ``unknown [lo, hi]`` when the budget stopped the check."""
    if res["verdict"] == "unknown":
        b = res.get("bounds")
        lo, hi = (b["lower"], b["upper"]) if isinstance(b, dict) else (None, None)
        return f"unknown [{_num(lo)}, {_num(hi)}]"
    return _num(res["optimum"])


def _num(v: object) -> str:
    return f"{v:.4g}" if isinstance(v, float) else str(v)


def _near_arg(v: str) -> str:
    """``--near``: ``all`` or a positive count."""
    if v != "all" and not (v.isdigit() and int(v) > 0):
        raise argparse.ArgumentTypeError(f"expected 'all' or a positive count, got {v!r}")
    return v


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--seeds", default="1,2,3")
    ap.add_argument("--within", type=float, default=30.0)
    ap.add_argument("--cap", type=int, default=100000, help="candidates a frame at most")
    ap.add_argument("--designs", default="single,joint,improved")
    ap.add_argument("--max-states", type=int, default=None, help="lesmc check's budget")
    ap.add_argument("--timeout", type=float, default=None, help="lesmc check's seconds")
    ap.add_argument(
        "--near",
        type=_near_arg,
        default="all",
        help="candidates a frame near the target: all (default) or K",
    )
    ap.add_argument("--out", default="/tmp/lesmc-inject-video")
    args = ap.parse_args()
    budget = [] if args.max_states is None else ["--max-states", str(args.max_states)]
    budget += [] if args.timeout is None else ["--timeout", str(args.timeout)]
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    print(
        "| seed | design | hide: payoff | frames | states | s "
        "| hide + inject: payoff | frames | states | s |"
    )
    for seed in (int(s) for s in args.seeds.split(",")):
        scene, facts = _scene(seed, args.within, args.cap, out)
        print(f"seed {seed}: {json.dumps(facts)}", file=sys.stderr)
        if args.near != "all":
            scene = _near(scene, int(args.near))
        for design in args.designs.split(","):
            row = [str(seed), design]
            for allow in ("", " allow hide, inject"):
                got = _check(scene, design, allow, out, budget)
                row += [
                    str(got["payoff"]),
                    str(got["frames"]),
                    f"{got['states']:,}" if got["states"] else "",
                    str(got["seconds"]),
                ]
            print("| " + " | ".join(row) + " |", flush=True)


if __name__ == "__main__":
    main()
