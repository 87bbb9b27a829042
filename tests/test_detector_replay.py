"""Replaying a counterexample through a detector file (issue 60, item 4).

A bright spot moves past a static one; a hand-set two-layer heatmap network finds
both. A cheap hiding attack at steps 6..8 violates a property on the model;
``lesmc replay RESULTS --frames DIR --detector det.toml`` re-runs the attack on
the frames, applies the perturbation, re-runs the detector and the tracker, and
confirms it. The replayed perturbation, added to the frame, leaves no detection
in the hidden detection's square when onnxruntime decodes it. Frames that are not
the results' are a located error (exit 2).
"""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any

import cv2
import numpy as np
import pytest
from cli_run import lesmc
from spot_detector import SPEC, H, W, write_spot_detector

from lesmc.schemas import schema

pytest.importorskip("onnx")
ort = pytest.importorskip("onnxruntime")
pytest.importorskip("onnxscript")
jsonschema = pytest.importorskip("jsonschema")


def _frames(d: Path, dy: float = 0.0) -> Path:
    """12 frames: a spot accelerating to the right past a static one (shifted ``dy``)."""
    fr = d / f"frames{dy:g}"
    fr.mkdir()
    for k in range(12):
        img = np.full((H, W), 20, np.uint8)
        x, y = 10 + 6 * k + 0.15 * k * k, 30 + 0.1 * k * k + dy
        cv2.circle(img, (round(x), round(y)), 3, 230, -1)
        cv2.circle(img, (60, 44), 3, 230, -1)
        cv2.imwrite(str(fr / f"f{k:02d}.png"), cv2.GaussianBlur(img, (5, 5), 1.0))
    return fr


@pytest.fixture(scope="module")
def checked(tmp_path_factory: pytest.TempPathFactory) -> dict[str, Any]:
    d = tmp_path_factory.mktemp("detreplay")
    frames, toml = _frames(d), write_spot_detector(d)
    scene = d / "scene.json"
    r = lesmc("perceive", str(frames), "--detector", str(toml), "-o", str(scene),
              "--target", "10,30@0")  # fmt: skip
    assert r.returncode == 0, r.stderr
    (d / "p.spec").write_text(SPEC)
    r = lesmc("check", str(scene), str(d / "p.spec"), "--report", str(d / "rep"))
    assert r.returncode == 1, r.stdout + r.stderr
    return {"dir": d, "frames": frames, "toml": toml, "results": d / "rep" / "results.json",
            "check_out": " ".join((r.stdout + r.stderr).split())}  # fmt: skip


def test_check_offers_the_replay_through_the_file(checked: dict[str, Any]) -> None:
    assert (
        f"lesmc replay RESULTS.json --frames {checked['frames']} --detector "
        f"{checked['toml']}" in checked["check_out"]
    )


def test_counterexample_replays_confirmed(checked: dict[str, Any]) -> None:
    r = lesmc("replay", str(checked["results"]), "--frames", str(checked["frames"]),
              "--detector", str(checked["toml"]), "--json")  # fmt: skip
    assert r.returncode == 1, r.stderr  # a violation confirmed
    assert "Traceback" not in r.stderr
    out = json.loads(r.stdout)
    jsonschema.validate(out, schema("replay"))  # the registries' enums filled in
    (row,) = out["replays"]
    assert row["verdict"] == "violated" and row["replay"]["status"] == "confirmed"
    perts = row["replay"]["perturbations"]
    assert perts
    sess = ort.InferenceSession(str(checked["dir"] / "spot.onnx"))
    for p in perts:
        frame = int(p["frame"])
        img = cv2.imread(str(sorted(checked["frames"].iterdir())[frame]), cv2.IMREAD_GRAYSCALE)
        x = (img.astype(np.float32) / np.float32(255.0))[None, None]
        delta = np.asarray(p["delta"], np.float32)
        x0, y0 = p["window_origin"]
        x[0, :, y0 : y0 + delta.shape[1], x0 : x0 + delta.shape[2]] += delta
        assert abs(float(np.sqrt((delta.astype(np.float64) ** 2).sum())) - p["payoff"]) < 1e-3
        y = sess.run(None, {sess.get_inputs()[0].name: x})[0][0, 0]
        i, j = int(p["y"] // 4), int(p["x"] // 4)
        square = y[max(0, i - 2) : i + 3, max(0, j - 2) : j + 3]
        assert float(square.max()) < 0.0  # every cell of the square below the threshold


def test_other_frames_are_a_located_error(checked: dict[str, Any]) -> None:
    other = _frames(checked["dir"], dy=6.0)
    r = lesmc("replay", str(checked["results"]), "--frames", str(other),
              "--detector", str(checked["toml"]))  # fmt: skip
    assert r.returncode == 2, r.stderr
    assert "Traceback" not in r.stderr
    assert "--frames:" in r.stderr and "not the frames" in r.stderr
