"""The shipped heatmap detector example (issue 60, item 5).

examples/detectors/heatmap.toml (made by ``lesmc train --kind heatmap``) runs on a
synthetic video of a seed it was neither trained nor validated on: its detections,
decoded here from onnxruntime's output with a peak finder written in the test, find
the video's vehicles; ``lesmc perceive`` reports those detections; a property on a
tracked vehicle is violated by hiding it, and the counterexample replays
``confirmed`` through the detector file and the tracker. ``lesmc train --kind
heatmap`` on a tiny budget writes a detector file that ``lesmc perceive`` reads.
"""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any

import cv2
import numpy as np
import pytest
from cli_run import ROOT, lesmc

ort = pytest.importorskip("onnxruntime")

TOML = ROOT / "examples" / "detectors" / "heatmap.toml"
NET = ROOT / "examples" / "detectors" / "heatmap.onnx"
SEED = 301  # training used videos 101, 102 and validation 103
FRAMES = 10
SPEC = """property hide_cheap {
    attack window 5..7
    minimize payoff
    subject to dist.max(0..end) > 5
    holds if optimum > 10
    on x, y
}
"""


def _decode(img: np.ndarray, sess: Any) -> np.ndarray:
    """(n, 2) detections: sigmoid cells >= 0.5 that are the maximum of their 5x5 square."""
    x = (img.astype(np.float32) / np.float32(255.0))[None, None]
    raw = sess.run(None, {sess.get_inputs()[0].name: x})[0][0, 0].astype(np.float64)
    s = 1.0 / (1.0 + np.exp(-raw))
    out = []
    for i in range(s.shape[0]):
        for j in range(s.shape[1]):
            sq = s[max(0, i - 2) : i + 3, max(0, j - 2) : j + 3]
            if s[i, j] >= 0.5 and s[i, j] == sq.max():
                out.append(((j + 0.5) * 4, (i + 0.5) * 4))
    return np.array(out).reshape(-1, 2)


@pytest.fixture(scope="module")
def video(tmp_path_factory: pytest.TempPathFactory) -> dict[str, Any]:
    d = tmp_path_factory.mktemp("heatex")
    frames = d / "frames"
    r = lesmc("synth", str(frames), "--frames", str(FRAMES), "--size", "384x384",
              "--seed", str(SEED))  # fmt: skip
    assert r.returncode == 0, r.stderr
    truth = json.loads((frames / "truth.json").read_text())["frames"]
    sess = ort.InferenceSession(str(NET))
    dets = [_decode(cv2.imread(str(frames / f["file"]), cv2.IMREAD_GRAYSCALE), sess)
            for f in truth]  # fmt: skip
    return {"dir": d, "frames": frames, "truth": truth, "dets": dets}


def _near(p: tuple[float, float], dets: np.ndarray, r: float = 4.0) -> bool:
    return bool(len(dets)) and float(np.hypot(*(dets - np.asarray(p)).T).min()) <= r


def test_shipped_file_is_small() -> None:
    assert TOML.is_file() and NET.is_file()
    assert TOML.stat().st_size + NET.stat().st_size < 200_000


def test_detector_finds_the_vehicles(video: dict[str, Any]) -> None:
    """Most visible vehicles have a detection within 4 px, and most detections a vehicle."""
    found = seen = hits = n_det = 0
    for f, dets in zip(video["truth"], video["dets"], strict=True):
        pts = [(v["x"], v["y"]) for v in f["vehicles"] if not v["occluded"]]
        seen += len(pts)
        found += sum(_near(p, dets) for p in pts)
        n_det += len(dets)
        hits += sum(any(np.hypot(d[0] - p[0], d[1] - p[1]) <= 4.0 for p in pts) for d in dets)
    assert seen > 50 and found / seen > 0.5, (found, seen)
    assert hits / n_det > 0.6, (found, seen, hits, n_det)


def _target(video: dict[str, Any]) -> tuple[float, float]:
    """A moving vehicle detected (within 3 px) in every frame: its position in frame 0."""
    by_id: dict[int, list[tuple[float, float]]] = {}
    for f in video["truth"]:
        for v in f["vehicles"]:
            if not v["occluded"] and v["speed_mps"] > 5:
                by_id.setdefault(v["id"], []).append((v["x"], v["y"]))
    for track in by_id.values():
        if len(track) == FRAMES and all(
            _near(p, d, 3.0) for p, d in zip(track, video["dets"], strict=True)
        ):
            return track[0]
    pytest.fail("no vehicle detected in every frame")


@pytest.fixture(scope="module")
def scene(video: dict[str, Any]) -> Path:
    """``lesmc perceive`` with the shipped file, targeting a vehicle seen in every frame."""
    x, y = _target(video)
    out = video["dir"] / "scene.json"
    r = lesmc("perceive", str(video["frames"]), "--detector", str(TOML), "-o", str(out),
              "--target", f"{x:.1f},{y:.1f}@0")  # fmt: skip
    assert r.returncode == 0, r.stderr
    assert "Traceback" not in r.stderr
    return out


def test_perceive_check_replay_confirmed(video: dict[str, Any], scene: Path) -> None:
    d, frames = video["dir"], video["frames"]
    (d / "p.spec").write_text(SPEC)
    r = lesmc("check", str(scene), str(d / "p.spec"), "--report", str(d / "rep"))
    assert r.returncode == 1, r.stdout + r.stderr  # hiding the vehicle a few steps moves it
    r = lesmc("replay", str(d / "rep" / "results.json"), "--frames", str(frames),
              "--detector", str(TOML), "--json")  # fmt: skip
    assert r.returncode == 1, r.stderr
    assert "Traceback" not in r.stderr
    (row,) = json.loads(r.stdout)["replays"]
    assert row["verdict"] == "violated" and row["replay"]["status"] == "confirmed"


def test_perceive_reports_the_decoded_detections(video: dict[str, Any], scene: Path) -> None:
    """The scene's detections are those decoded here from onnxruntime's output."""
    doc = json.loads(scene.read_text())
    assert len(doc["frames"]) == FRAMES
    for fr, dets in zip(doc["frames"], video["dets"], strict=True):
        got = sorted((d["x"], d["y"]) for d in fr["detections"])
        want = sorted(map(tuple, dets.tolist()))
        assert np.allclose(np.array(got).reshape(-1, 2), np.array(want).reshape(-1, 2))


def test_train_heatmap_tiny_budget_is_read_by_perceive(tmp_path: Path) -> None:
    out = tmp_path / "det"
    r = lesmc("train", "--kind", "heatmap", "--out", str(out), "--frames", "6",
              "--size", "96x64", "--videos", "1", "--epochs", "1")  # fmt: skip
    assert r.returncode == 0, r.stderr
    assert "Traceback" not in r.stderr
    assert (out / "heatmap.toml").is_file() and (out / "heatmap.onnx").is_file()
    frames = tmp_path / "frames"
    assert lesmc("synth", str(frames), "--frames", "3", "--size", "96x64").returncode == 0
    r = lesmc("perceive", str(frames), "--detector", str(out / "heatmap.toml"))
    assert r.returncode == 0, r.stderr
    assert "Traceback" not in r.stderr


@pytest.mark.parametrize(
    ("args", "named"),
    [(["--size", "98x64"], "--size"), (["--json"], "--json")],
)
def test_train_heatmap_refusals_are_exit_2(args: list[str], named: str, tmp_path: Path) -> None:
    r = lesmc("train", "--kind", "heatmap", "--out", str(tmp_path / "n"), "--frames", "6", *args)
    assert r.returncode == 2, r.stderr
    assert "Traceback" not in r.stderr and named in r.stderr
    assert not (tmp_path / "n").exists()
