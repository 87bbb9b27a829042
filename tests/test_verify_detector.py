"""``lesmc verify FRAMES --detector FILE.toml`` (issue 60, round 3, item 1).

The paper's experiment on the shipped heatmap detector, through the real entry point:
the detector file perceives and prices the video (no WAMI front end), the bundled
properties are checked on the paper's designs, a violation replays ``confirmed``
through the detector file and the tracker, and the results' ``perception.detections``
holds recall and precision equal to a matching written here from onnxruntime's
output and the truth; the payoffs the checked models read are priced, the others not.
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
scipy_opt = pytest.importorskip("scipy.optimize")

TOML = ROOT / "examples" / "detectors" / "heatmap.toml"
NET = ROOT / "examples" / "detectors" / "heatmap.onnx"
FRAMES = 10


def _decode(img: np.ndarray, sess: Any) -> np.ndarray:
    """(n, 2) detections: sigmoid cells >= 0.5 that are the maximum of their 5x5 square
    (the shipped file: stride 4, nms_radius 2; ties do not occur on these frames)."""
    x = (img.astype(np.float32) / np.float32(255.0))[None, None]
    raw = sess.run(None, {sess.get_inputs()[0].name: x})[0][0, 0].astype(np.float64)
    s = 1.0 / (1.0 + np.exp(-raw))
    out = [
        ((j + 0.5) * 4, (i + 0.5) * 4)
        for i in range(s.shape[0])
        for j in range(s.shape[1])
        if s[i, j] >= 0.5 and s[i, j] == s[max(0, i - 2) : i + 3, max(0, j - 2) : j + 3].max()
    ]
    return np.array(out, np.float64).reshape(-1, 2)


def _matched(det: np.ndarray, truth: np.ndarray, r: float = 4.0) -> int:
    """Pairs of a one-to-one matching within r px that has the most pairs (a maximum
    matching: the assignment of cost 0 within r, 1 beyond)."""
    if not len(det) or not len(truth):
        return 0
    d = np.hypot(det[:, None, 0] - truth[None, :, 0], det[:, None, 1] - truth[None, :, 1])
    rows, cols = scipy_opt.linear_sum_assignment((d > r).astype(float))
    return int(sum(d[a, b] <= r for a, b in zip(rows, cols, strict=True)))


@pytest.fixture(scope="module")
def run(tmp_path_factory: pytest.TempPathFactory) -> dict[str, Any]:
    d = tmp_path_factory.mktemp("verifydet")
    frames = d / "frames"
    r = lesmc("synth", str(frames), "--frames", str(FRAMES), "--size", "384x384", "--seed", "301")
    assert r.returncode == 0, r.stderr
    truth = json.loads((frames / "truth.json").read_text())["frames"]
    sess = ort.InferenceSession(str(NET))
    dets = [_decode(cv2.imread(str(frames / f["file"]), cv2.IMREAD_GRAYSCALE), sess) for f in truth]
    target = _target(truth, dets)
    out = d / "out"
    r = lesmc(
        "verify", str(frames), "--truth", str(frames / "truth.json"), "--detector", str(TOML),
        "--target", f"{target[0]:.1f},{target[1]:.1f}@0", "--out", str(out),
    )  # fmt: skip
    return {"dir": d, "frames": frames, "truth": truth, "dets": dets, "r": r, "out": out}


def _target(truth: list[dict[str, Any]], dets: list[np.ndarray]) -> tuple[float, float]:
    """A moving vehicle with a detection within 3 px in every frame: its first position."""
    by_id: dict[int, list[tuple[float, float]]] = {}
    for f in truth:
        for v in f["vehicles"]:
            if not v["occluded"] and v["speed_mps"] > 5:
                by_id.setdefault(v["id"], []).append((v["x"], v["y"]))
    for track in by_id.values():
        if len(track) == FRAMES and all(
            len(dt) and float(np.hypot(*(dt - np.asarray(p)).T).min()) <= 3.0
            for p, dt in zip(track, dets, strict=True)
        ):
            return track[0]
    pytest.fail("no vehicle detected in every frame")


def test_verify_runs_end_to_end(run: dict[str, Any]) -> None:
    r = run["r"]
    assert "Traceback" not in r.stderr and "internal error" not in r.stderr, r.stderr
    assert r.returncode == 1, r.stdout + r.stderr  # the bundled resilience is violated
    assert "report:" in r.stdout and "resilience" in r.stdout
    assert (run["out"] / "report.html").is_file() and (run["out"] / "scene.json").is_file()
    assert "detector file:" in r.stderr  # the detections' line (count, recall, precision)


def test_violations_replay_confirmed(run: dict[str, Any]) -> None:
    doc = json.loads((run["out"] / "results.json").read_text())
    violated = [x for rr in doc["runs"] for x in rr["results"] if x.get("replay") is not None]
    assert violated, "no counterexample was replayed"
    assert all(x["replay"]["status"] == "confirmed" for x in violated), [
        x["replay"] for x in violated
    ]
    assert any(x["verdict"] == "violated" for x in violated)


def test_recall_precision_match_onnxruntime(run: dict[str, Any]) -> None:
    """The results' recall and precision equal a matching of onnxruntime's detections
    with the visible vehicles computed here."""
    doc = json.loads((run["out"] / "results.json").read_text())
    facts = doc["perception"]["detections"]
    tp = n_det = n_veh = 0
    for f, dt in zip(run["truth"], run["dets"], strict=True):
        vis = np.array(
            [(v["x"], v["y"]) for v in f["vehicles"] if not v["occluded"]], np.float64
        ).reshape(-1, 2)
        tp += _matched(dt, vis)
        n_det += len(dt)
        n_veh += len(vis)
    assert facts["detections"] == n_det and facts["vehicles"] == n_veh
    assert facts["true_positives"] == tp
    assert facts["recall"] == pytest.approx(tp / n_veh)
    assert facts["precision"] == pytest.approx(tp / n_det)
    assert doc["perception"]["detector_file"]["kind"] == "heatmap"
    jsonschema = pytest.importorskip("jsonschema")
    from lesmc.schemas import schema  # the file with the registries' enums filled in

    jsonschema.validate(doc, schema("results"))
    scene = json.loads((run["out"] / "scene.json").read_text())
    pays = [d["payoff"] for fr in scene["frames"] for d in fr["detections"]]
    assert len(pays) == n_det  # priced when a model reads them: the others are unpriced
    priced = [p for p in pays if p != "unpriced"]
    assert priced and facts["priced"] == len(priced) == scene["meta"]["priced"]["detections"]
    assert facts["attackable"] == sum(p != "unattackable" for p in priced)


def test_campaign_refuses_window_networks_with_a_detector_file(tmp_path: Path) -> None:
    """A campaign perceives through a detector file (tests/test_campaign_detector.py); the
    window pipeline's networks beside it are an error before any work."""
    r = lesmc("campaign", str(tmp_path), "--detector", str(TOML), "--nets", str(tmp_path),
              "--out", str(tmp_path / "o"))  # fmt: skip
    assert r.returncode == 2, r.stdout + r.stderr
    assert "Traceback" not in r.stderr
    assert "--nets" in r.stderr and "detector file" in r.stderr
    assert not (tmp_path / "o").exists()


def test_verify_refuses_window_networks_with_a_detector_file(tmp_path: Path) -> None:
    r = lesmc("verify", str(tmp_path), "--detector", str(TOML), "--locator", str(NET),
              "--target", "10,10@0", "--out", str(tmp_path / "o"))  # fmt: skip
    assert r.returncode == 2, r.stdout + r.stderr
    assert "Traceback" not in r.stderr and "--locator" in r.stderr


def test_verify_scene_replays_through_the_detector_file(run: dict[str, Any]) -> None:
    """``verify --scene S --frames F --detector FILE.toml`` checks the detector file's scene
    and replays its violations through the file, as verify on the video did."""
    out = run["dir"] / "again"
    r = lesmc("verify", "--scene", str(run["out"] / "scene.json"), "--frames",
              str(run["frames"]), "--detector", str(TOML), "--out", str(out))  # fmt: skip
    assert "Traceback" not in r.stderr and r.returncode == 1, r.stdout + r.stderr
    doc = json.loads((out / "results.json").read_text())
    replays = [x["replay"] for rr in doc["runs"] for x in rr["results"] if x.get("replay")]
    assert replays and all(rp["status"] == "confirmed" for rp in replays), replays
