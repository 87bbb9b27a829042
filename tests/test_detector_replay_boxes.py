"""Replaying a counterexample through a box-list detector file (issue 60, round 3, item 5).

test_detector_replay.py's video (a spot moving past a static one) and its hand-set
score network, given a box head: each stride-4 cell answers a 12x12 box around its
centre with the cell's score (``kind = "boxes"``). Hiding the moving spot at steps
6..8 violates the property; ``lesmc replay --detector`` re-runs the attack through the
real detector and tracker and confirms it. With the replayed perturbation added,
onnxruntime's rows hold no box overlapping the hidden one by IoU >= 0.5 with a score
>= the threshold; with it removed, they do (the perturbation is what hides it).
"""

from __future__ import annotations

import json
import warnings
from typing import Any

import cv2
import numpy as np
import pytest
import torch
from cli_run import lesmc
from spot_detector import SPEC, H, W
from test_detector_replay import _frames
from torch import nn

pytest.importorskip("onnx")
ort = pytest.importorskip("onnxruntime")
pytest.importorskip("onnxscript")

HALF = 6.0  # each cell's box is 12 x 12 pixels


class SpotBoxes(nn.Module):
    """(B, 1, 64, 96) -> (B, 384, 5): per stride-4 cell [x1, y1, x2, y2, raw score]."""

    def __init__(self) -> None:
        super().__init__()
        self.body = nn.Sequential(
            nn.Conv2d(1, 2, 5, stride=2, padding=2), nn.ReLU(),
            nn.Conv2d(2, 1, 3, stride=2, padding=1),
        )  # fmt: skip
        with torch.no_grad():  # brightness above a level, blurred (test_detector_replay)
            g = torch.ones(5, 5) / 25
            self.body[0].weight[:] = torch.stack([g, -g])[:, None]
            self.body[0].bias[:] = torch.tensor([-0.2, 0.3])
            self.body[2].weight.zero_()
            self.body[2].weight[0, 0] = torch.tensor([[1.0, 2, 1], [2, 4, 2], [1, 2, 1]]) / 4
            self.body[2].bias[:] = torch.tensor([-0.3])
        ys, xs = torch.meshgrid(torch.arange(H // 4), torch.arange(W // 4), indexing="ij")
        self.register_buffer("cx", ((xs + 0.5) * 4).float().reshape(1, 1, -1))
        self.register_buffer("cy", ((ys + 0.5) * 4).float().reshape(1, 1, -1))

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        s = self.body(x).flatten(2)  # (B, 1, N)
        cx, cy = self.cx + 0.0 * s, self.cy + 0.0 * s
        rows = torch.cat([cx - HALF, cy - HALF, cx + HALF, cy + HALF, s], dim=1)
        return rows.transpose(1, 2)


def _iou(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    w = np.clip(np.minimum(a[2], b[:, 2]) - np.maximum(a[0], b[:, 0]), 0, None)
    h = np.clip(np.minimum(a[3], b[:, 3]) - np.maximum(a[1], b[:, 1]), 0, None)
    union = (a[2] - a[0]) * (a[3] - a[1]) + (b[:, 2] - b[:, 0]) * (b[:, 3] - b[:, 1]) - w * h
    return np.asarray(w * h / union)


@pytest.fixture(scope="module")
def checked(tmp_path_factory: pytest.TempPathFactory) -> dict[str, Any]:
    d = tmp_path_factory.mktemp("boxreplay")
    frames = _frames(d)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        torch.onnx.export(
            SpotBoxes().eval(), (torch.rand(2, 1, H, W),), d / "spot.onnx", dynamo=True,
            dynamic_shapes=({0: torch.export.Dim("batch")},), external_data=False,
        )  # fmt: skip
    toml = d / "boxes.toml"
    toml.write_text(
        'kind = "boxes"\nnetwork = "spot.onnx"\nthreshold = 0.0\nscore = "raw"\niou_nms = 0.1\n'
    )
    scene = d / "scene.json"
    r = lesmc("perceive", str(frames), "--detector", str(toml), "-o", str(scene),
              "--target", "10,30@0")  # fmt: skip
    assert r.returncode == 0, r.stderr
    (d / "p.spec").write_text(SPEC)
    r = lesmc("check", str(scene), str(d / "p.spec"), "--report", str(d / "rep"))
    assert r.returncode == 1, r.stdout + r.stderr
    return {"dir": d, "frames": frames, "toml": toml, "results": d / "rep" / "results.json"}


def test_box_counterexample_replays_confirmed(checked: dict[str, Any]) -> None:
    r = lesmc("replay", str(checked["results"]), "--frames", str(checked["frames"]),
              "--detector", str(checked["toml"]), "--json")  # fmt: skip
    assert r.returncode == 1, r.stderr  # a violation confirmed
    assert "Traceback" not in r.stderr
    (row,) = json.loads(r.stdout)["replays"]
    assert row["verdict"] == "violated" and row["replay"]["status"] == "confirmed", row
    perts = row["replay"]["perturbations"]
    assert perts
    sess = ort.InferenceSession(str(checked["dir"] / "spot.onnx"))
    paths = sorted(checked["frames"].iterdir())
    for p in perts:
        img = cv2.imread(str(paths[int(p["frame"])]), cv2.IMREAD_GRAYSCALE)
        x = (img.astype(np.float32) / np.float32(255.0))[None, None]
        box = np.array([p["x"] - HALF, p["y"] - HALF, p["x"] + HALF, p["y"] + HALF])
        clean = sess.run(None, {sess.get_inputs()[0].name: x})[0][0].astype(np.float64)
        assert bool(((_iou(box, clean[:, :4]) >= 0.5) & (clean[:, 4] >= 0.0)).any())
        delta = np.asarray(p["delta"], np.float32)
        x0, y0 = p["window_origin"]
        x[0, :, y0 : y0 + delta.shape[1], x0 : x0 + delta.shape[2]] += delta
        rows = sess.run(None, {sess.get_inputs()[0].name: x})[0][0].astype(np.float64)
        assert not bool(((_iou(box, rows[:, :4]) >= 0.5) & (rows[:, 4] >= 0.0)).any())
        assert abs(float(np.sqrt((delta.astype(np.float64) ** 2).sum())) - p["payoff"]) < 1e-3
