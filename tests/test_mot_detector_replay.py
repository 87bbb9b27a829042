"""A scene imported by ``lesmc import mot --frames DIR --detector FILE`` replays through
the detector file (the review of round 20): MOT frame f is the directory's frame f - 1,
so the replay must decode the frame the payoff was priced on, and the replay command the
check prints names the frames directory, not the det.txt.

The det.txt is made here from the shipped heatmap example's own detections on a small
synthetic video (each box 12 x 8 px around a detection), so every box is priced; the
robustness property is violated at a finite payoff, and the replay must be confirmed.
"""

from __future__ import annotations

import json
import math
from pathlib import Path

import pytest
from cli_run import lesmc

pytest.importorskip("onnx")

ROOT = Path(__file__).resolve().parent.parent
DETECTOR = ROOT / "examples" / "detectors" / "heatmap.toml"
SPEC = """property robustness {
    attack window 1..3
    minimize payoff
    subject to dist.sum(0..end) > 3
    holds if optimum > 100.0
    on x, y
}
"""


def test_an_imported_mot_scene_replays_through_the_detector_file(tmp_path: Path) -> None:
    video = tmp_path / "video"
    r = lesmc("synth", str(video), "--frames", "8", "--size", "384x384", "--seed", "301")
    assert r.returncode == 0, r.stderr
    seen = tmp_path / "seen.json"
    r = lesmc("perceive", str(video), "--detector", str(DETECTOR), "-o", str(seen))
    assert r.returncode == 0, r.stderr
    frames = json.loads(seen.read_text())["frames"]
    lines = [
        f"{f['step'] + 1},-1,{d['x'] - 6},{d['y'] - 4},12,8,0.9,-1,-1,-1"
        for f in frames
        for d in f["detections"]
    ]  # MOT frames count from 1
    det = tmp_path / "det.txt"
    det.write_text("\n".join(lines) + "\n")
    scene = tmp_path / "ms.json"
    r = lesmc(
        "import", "mot", str(det), "--frames", str(video), "--detector", str(DETECTOR),
        "-o", str(scene),
    )  # fmt: skip
    assert r.returncode == 0, r.stderr
    doc = json.loads(scene.read_text())
    assert doc["meta"].get("unmatched") is None  # every box sits on a detection
    step4 = next(f for f in doc["frames"] if f["step"] == 4)
    t = min(step4["detections"], key=lambda d: math.hypot(d["x"] - 192, d["y"] - 192))
    spec = tmp_path / "h.spec"
    spec.write_text(SPEC)
    r = lesmc(
        "check", str(scene), str(spec), "--design", "single", "--target",
        f"{t['x']},{t['y']}@4", "--json", "--report", str(tmp_path / "r"),
    )  # fmt: skip
    assert "Traceback" not in r.stderr
    assert r.returncode == 1, r.stderr
    res = json.loads(r.stdout)["results"][0]
    assert res["replay"]["status"] == "not replayed"
    assert f"--frames {video}" in res["replay"]["command"]  # the frames, not the det.txt
    r = lesmc(
        "replay", str(tmp_path / "r" / "results.json"), "--frames", str(video),
        "--detector", str(DETECTOR), "--json",
    )  # fmt: skip
    assert "Traceback" not in r.stderr
    assert r.returncode == 1, r.stderr
    rep = json.loads(r.stdout)["replays"][0]
    assert rep["replay"]["status"] == "confirmed", rep["replay"].get("reason")
