"""Benchmark: a box-list detector's ``lesmc verify``, payoffs up front vs on demand (issue 60).

    python benchmarks/bench_boxes_lazy.py [--out DIR] [--frames 12] [--size 384]

Makes a synthetic video (``lesmc synth --size SIZExSIZE --seed 103``, the held-out seed
of the shipped heatmap example) and a box-list network from the shipped heatmap
network (examples/detectors/heatmap.onnx, its ONNX graph extended here: every heatmap
cell becomes a row [x1, y1, x2, y2, raw], a 16x16 box on the cell's centre; ``iou_nms
= 0.3``, so a detection suppresses boxes up to two cells away, as the example's
``nms_radius = 2``), then runs ``lesmc verify FRAMES --detector box.toml --truth
truth.json --target X,Y@0`` (the fastest vehicle of frame 0 that stays in view) twice
in fresh OUT directories: with ``--price-all`` (every detection
priced up front) and without (priced when a model reads it). Prints per run the wall
seconds, the CPU seconds of the lesmc process, the exit status, the detections and how
many were priced, and the verdicts. Figures: docs/performance.md, "Issue 60, round 22".
"""

from __future__ import annotations

import argparse
import json
import os
import resource
import subprocess
import sys
import time
from pathlib import Path
from typing import Any

ROOT = Path(__file__).resolve().parents[1]


def lesmc(*args: str) -> tuple[int, float, float, str]:
    """``python -m lesmc ARGS``: exit status, wall and CPU seconds, stderr."""
    before = resource.getrusage(resource.RUSAGE_CHILDREN)
    t0 = time.monotonic()
    r = subprocess.run(
        [sys.executable, "-m", "lesmc", *args], capture_output=True, text=True,
        env={**os.environ, "PYTHONPATH": str(ROOT)}, cwd=ROOT,
    )  # fmt: skip
    wall = time.monotonic() - t0
    after = resource.getrusage(resource.RUSAGE_CHILDREN)
    cpu = (after.ru_utime - before.ru_utime) + (after.ru_stime - before.ru_stime)
    return r.returncode, wall, cpu, r.stderr


def box_network(out: Path, size: int) -> Path:
    """examples/detectors/heatmap.onnx with a box head, for ``size`` x ``size`` frames, and
    its detector file."""
    import numpy as np
    import onnx
    from onnx import helper, numpy_helper

    m = onnx.load(str(ROOT / "examples" / "detectors" / "heatmap.onnx"))
    g = m.graph
    for d, v in zip(g.input[0].type.tensor_type.shape.dim[2:], (size, size), strict=True):
        d.ClearField("dim_param")
        d.dim_value = v
    heat = g.output[0].name
    n = (size // 4) ** 2
    ii, jj = np.meshgrid(np.arange(size // 4), np.arange(size // 4), indexing="ij")
    cx, cy = ((jj + 0.5) * 4).reshape(-1), ((ii + 0.5) * 4).reshape(-1)
    boxes = np.stack([cx - 8, cy - 8, cx + 8, cy + 8], axis=1)[None].astype(np.float32)
    g.initializer.extend([
        numpy_helper.from_array(np.array([-1, n, 1], np.int64), "box_shape"),
        numpy_helper.from_array(boxes, "box_corners"),
        numpy_helper.from_array(np.zeros((1, 1, 4), np.float32), "box_zeros"),
    ])  # fmt: skip
    g.node.extend([
        helper.make_node("Reshape", [heat, "box_shape"], ["box_raw"]),
        helper.make_node("Mul", ["box_raw", "box_zeros"], ["box_none"]),
        helper.make_node("Add", ["box_none", "box_corners"], ["box_xyxy"]),
        helper.make_node("Concat", ["box_xyxy", "box_raw"], ["boxes"], axis=2),
    ])  # fmt: skip
    del g.output[:]
    g.output.append(helper.make_tensor_value_info("boxes", onnx.TensorProto.FLOAT, None))
    onnx.save(m, str(out / "box.onnx"))
    toml = out / "box.toml"
    toml.write_text(
        'kind = "boxes"\nnetwork = "box.onnx"\nchannels = "gray"\nscale = [0.0, 1.0]\n'
        'threshold = 0.5\nscore = "sigmoid"\niou_nms = 0.3\n'
    )
    return toml


def target(truth: Path) -> str:
    """``X,Y@0``: the fastest vehicle of frame 0 that every frame shows unoccluded."""
    frames = json.loads(truth.read_text())["frames"]
    seen = [{v["id"] for v in f["vehicles"] if not v["occluded"]} for f in frames]
    always = set.intersection(*seen)
    best = max((v for v in frames[0]["vehicles"] if v["id"] in always),
               key=lambda v: v["speed_mps"])  # fmt: skip
    return f"{best['x']:.1f},{best['y']:.1f}@0"


def facts(out: Path) -> dict[str, Any]:
    """The run's detections, priced count and verdicts, from its results.json."""
    doc = json.loads((out / "results.json").read_text())
    det = doc["perception"]["detections"]
    verdicts = [
        f"{x['design']}/{x['property']}:{x['verdict']}@{x.get('optimum')}"
        for r in doc["runs"]
        for x in r["results"]
    ]
    return {"detections": det["detections"], "priced": det["priced"], "verdicts": verdicts}


def same_payoffs(a: Path, b: Path) -> str:
    """How the payoffs run ``b`` priced compare with run ``a``'s (its scene.json)."""
    pays = [
        [x["payoff"] for f in json.loads((r / "scene.json").read_text())["frames"]
         for x in f["detections"]]
        for r in (a, b)
    ]  # fmt: skip
    both = [(p, q) for p, q in zip(*pays, strict=True) if q != "unpriced"]
    nums = [abs(p - q) / max(abs(p), 1e-12) for p, q in both if not isinstance(p, str)]
    same = all(p == q for p, q in both if isinstance(p, str) or isinstance(q, str))
    worst = max(nums, default=0.0)
    return f"{len(both)} priced both ways, largest relative difference {worst:.2g}, same: {same}"


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--out", default="/tmp/bench_boxes_lazy")
    ap.add_argument("--frames", type=int, default=12)
    ap.add_argument("--size", type=int, default=384)
    args = ap.parse_args()
    out = Path(args.out)
    video = out / "video"
    if not video.exists():
        code, *_, err = lesmc("synth", str(video), "--frames", str(args.frames), "--size",
                              f"{args.size}x{args.size}", "--seed", "103")  # fmt: skip
        assert code == 0, err
    toml = box_network(out, args.size)
    at = target(video / "truth.json")
    print(f"target {at}", flush=True)
    for name, extra in (("up front", ["--price-all"]), ("on demand", [])):
        run = out / name.replace(" ", "_")
        subprocess.run(["rm", "-rf", str(run)], check=True)
        code, wall, cpu, err = lesmc(
            "verify", str(video), "--detector", str(toml), "--truth", str(video / "truth.json"),
            "--target", at, "--out", str(run), *extra,
        )  # fmt: skip
        got = facts(run) if (run / "results.json").exists() else {"error": err[-2000:]}
        print(f"{name}: exit {code}, {wall:.1f} s wall, {cpu:.1f} s CPU, {got}", flush=True)
    print(same_payoffs(out / "up_front", out / "on_demand"))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
