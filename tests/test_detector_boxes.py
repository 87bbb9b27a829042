"""Box-list detectors in a detector file (issue 60, kind = "boxes").

A random network answering (B, N, 5) rows [x1, y1, x2, y2, score], exported to
ONNX and ``.pt2``: lesmc's detections equal a decode written here (greedy NMS)
from onnxruntime's outputs; every saved perturbation hides its detection (no row
with IoU >= 0.5 and a score >= threshold in onnxruntime's output) and its norm is
the payoff; --certify is refused (attack-only), and keys of the other kind are
located errors.
"""

from __future__ import annotations

import json
import warnings
from pathlib import Path
from typing import Any

import cv2
import numpy as np
import pytest
import torch
from cli_run import lesmc
from torch import nn

pytest.importorskip("onnx")
ort = pytest.importorskip("onnxruntime")
pytest.importorskip("onnxscript")

H, W = 48, 64


class BoxNet(nn.Module):
    """(B, 1, 48, 64) -> (B, 48, 5): one box per 8x8 cell, centre moved by tanh, half
    sizes 6..10 pixels, raw score."""

    def __init__(self, s: int = 8) -> None:
        super().__init__()
        self.body = nn.Sequential(
            nn.Conv2d(1, 8, 3, stride=2, padding=1), nn.ReLU(),
            nn.Conv2d(8, 8, 3, stride=2, padding=1), nn.ReLU(),
            nn.Conv2d(8, 5, 3, stride=2, padding=1),
        )  # fmt: skip
        ys, xs = torch.meshgrid(torch.arange(H // s), torch.arange(W // s), indexing="ij")
        self.register_buffer("cx", ((xs + 0.5) * s).float().reshape(1, 1, -1))
        self.register_buffer("cy", ((ys + 0.5) * s).float().reshape(1, 1, -1))

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        o = self.body(x).flatten(2)
        cx = self.cx + 4.0 * torch.tanh(o[:, 0:1])
        cy = self.cy + 4.0 * torch.tanh(o[:, 1:2])
        hw = 6.0 + 4.0 * torch.sigmoid(o[:, 2:3])
        hh = 6.0 + 4.0 * torch.sigmoid(o[:, 3:4])
        rows = torch.cat([cx - hw, cy - hh, cx + hw, cy + hh, o[:, 4:5]], dim=1)
        return rows.transpose(1, 2)


@pytest.fixture(scope="module")
def made(tmp_path_factory: pytest.TempPathFactory) -> dict[str, Any]:
    d = tmp_path_factory.mktemp("boxes")
    torch.manual_seed(62)
    net = BoxNet().eval()
    x = torch.rand(3, 1, H, W)
    dyn = ({0: torch.export.Dim("batch")},)
    torch.export.save(torch.export.export(net, (x,), dynamic_shapes=dyn), d / "box.pt2")
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        torch.onnx.export(
            net, (x,), d / "box.onnx", dynamic_shapes=dyn, dynamo=True, external_data=False
        )
    frames = d / "frames"
    frames.mkdir()
    rng = np.random.default_rng(62)
    xs = []
    for k in range(3):
        img = cv2.GaussianBlur(rng.integers(0, 256, (H, W)).astype(np.uint8), (5, 5), 1.5)
        cv2.imwrite(str(frames / f"f{k}.png"), img)
        xs.append((img.astype(np.float32) / np.float32(255.0))[None, None])
    rows = _ort(d / "box.onnx", xs[0])
    v = np.sort(rows[:, 4])[::-1]
    thr = float((v[3] + v[4]) / 2)  # about 4 boxes a frame
    return {"dir": d, "frames": frames, "xs": xs, "thr": thr}


def _ort(path: Path, x: np.ndarray) -> np.ndarray:
    sess = ort.InferenceSession(str(path), providers=["CPUExecutionProvider"])
    out: np.ndarray = sess.run(None, {sess.get_inputs()[0].name: x})[0][0].astype(np.float64)
    return out


def _iou(a: np.ndarray, b: np.ndarray) -> float:
    w = max(0.0, min(a[2], b[2]) - max(a[0], b[0]))
    h = max(0.0, min(a[3], b[3]) - max(a[1], b[1]))
    union = (a[2] - a[0]) * (a[3] - a[1]) + (b[2] - b[0]) * (b[3] - b[1]) - w * h
    return w * h / union if union > 0 else 0.0


def _reference(rows: np.ndarray, thr: float, iou_nms: float) -> list[np.ndarray]:
    """Greedy NMS, written plainly: by decreasing score (earlier row first on ties), a box
    is kept unless it overlaps a kept one by IoU > iou_nms; kept boxes in row order."""
    order = sorted(
        (r for r in range(len(rows)) if rows[r, 4] >= thr), key=lambda r: (-rows[r, 4], r)
    )
    kept: list[int] = []
    for r in order:
        if all(_iou(rows[r], rows[q]) <= iou_nms for q in kept):
            kept.append(r)
    return [rows[r, :4] for r in sorted(kept)]


def _toml(made: dict[str, Any], name: str, network: str, **extra: Any) -> Path:
    keys = {"kind": "boxes", "network": network, "threshold": made["thr"], "iou_nms": 0.3}
    keys |= extra
    path: Path = made["dir"] / name
    path.write_text("".join(f"{k} = {json.dumps(v)}\n" for k, v in keys.items()))
    return path


@pytest.mark.parametrize("fmt", ["onnx", "pt2"])
def test_box_detections_equal_onnxruntime_decode_and_attacks_hide_them(
    made: dict[str, Any], fmt: str
) -> None:
    d: Path = made["dir"]
    det = _toml(made, f"box_{fmt}.toml", f"box.{fmt}")
    out, saved = d / f"box_{fmt}.json", d / f"saved_{fmt}"
    r = lesmc("perceive", str(made["frames"]), "--detector", str(det), "-o", str(out),
              "--save-attacks", str(saved))  # fmt: skip
    assert r.returncode == 0, r.stderr
    assert "Traceback" not in r.stderr
    scene = json.loads(out.read_text())
    assert scene["meta"]["detector_file"]["kind"] == "boxes"
    priced = 0
    for k, fr in enumerate(scene["frames"]):
        rows = _ort(d / "box.onnx", made["xs"][k])
        want = _reference(rows, made["thr"], 0.3)
        got = fr["detections"]
        assert len(got) == len(want)
        for n, (dd, box) in enumerate(zip(got, want, strict=True)):
            assert dd["id"] == f"{k}:{n}"
            cx, cy, w, h = (
                (box[0] + box[2]) / 2,
                (box[1] + box[3]) / 2,
                box[2] - box[0],
                box[3] - box[1],
            )
            assert np.allclose([dd["x"], dd["y"], dd["w"], dd["h"]], [cx, cy, w, h], atol=1e-4)
            f = saved / f"{k}_{n}.npy"
            if dd["payoff"] == "unattackable":
                assert not f.exists()
                continue
            delta = np.load(f)
            assert delta.dtype == np.float32 and delta.shape == (1, 1, H, W)
            assert abs(float(np.sqrt((delta.astype(np.float64) ** 2).sum())) - dd["payoff"]) < 1e-5
            after = _ort(d / "box.onnx", made["xs"][k] + delta)
            left = [q for q in range(len(after))
                    if after[q, 4] >= made["thr"] and _iou(after[q], box) >= 0.5]  # fmt: skip
            assert left == [], (dd["id"], left)
            priced += 1
    assert priced >= 3


def test_box_detectors_are_attack_only(made: dict[str, Any]) -> None:
    det = _toml(made, "box_cert.toml", "box.onnx")
    out = made["dir"] / "box_cert.json"
    r = lesmc("perceive", str(made["frames"]), "--detector", str(det), "-o", str(out),
              "--certify")  # fmt: skip
    assert r.returncode == 2, r.stderr
    assert "Traceback" not in r.stderr
    assert f"{det}:1:1: kind: box-list detectors are attack-only" in r.stderr
    assert not out.exists()


@pytest.mark.parametrize(
    ("kind", "key", "value"), [("boxes", "stride", 4), ("boxes", "nms_radius", 1),
                               ("heatmap", "iou_nms", 0.5)]
)  # fmt: skip
def test_keys_of_the_other_kind_are_located_errors(
    made: dict[str, Any], kind: str, key: str, value: Any
) -> None:
    extra: dict[str, Any] = {"kind": kind, key: value}
    if kind == "heatmap":
        extra["stride"] = 8
    det = _toml(made, f"other_{key}.toml", "box.onnx", **extra)
    r = lesmc("perceive", str(made["frames"]), "--detector", str(det))
    assert r.returncode == 2, r.stderr
    line = det.read_text().splitlines().index(f"{key} = {json.dumps(value)}") + 1
    assert f'{det}:{line}:1: {key}: applies to kind = "' in r.stderr
