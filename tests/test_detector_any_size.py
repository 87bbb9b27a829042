"""Detector networks that read frames of any size (issue 60, round 3, item 2).

The shipped example's ONNX has dynamic height and width, so ``lesmc perceive
--detector examples/detectors/heatmap.toml`` reads a 256x192 video (not only
384x384) and finds what onnxruntime's output decoded here finds; a frame size the
stride does not divide is a located error (exit 2), and so is a network exported with
one fixed size run on frames of another.
"""

from __future__ import annotations

import json
from pathlib import Path

import cv2
import numpy as np
import pytest
from cli_run import ROOT, lesmc
from test_verify_detector import _decode

ort = pytest.importorskip("onnxruntime")
onnx = pytest.importorskip("onnx")
torch = pytest.importorskip("torch")

TOML = ROOT / "examples" / "detectors" / "heatmap.toml"
NET = ROOT / "examples" / "detectors" / "heatmap.onnx"


def _video(d: Path, size: str, frames: int = 2) -> Path:
    r = lesmc("synth", str(d), "--frames", str(frames), "--size", size, "--seed", "7")
    assert r.returncode == 0, r.stderr
    return d


def test_shipped_onnx_has_dynamic_height_and_width() -> None:
    dims = onnx.load(str(NET)).graph.input[0].type.tensor_type.shape.dim
    assert [d.HasField("dim_param") for d in dims] == [True, False, True, True]


def test_shipped_example_reads_another_size(tmp_path: Path) -> None:
    frames = _video(tmp_path / "v", "256x192", 3)
    out = tmp_path / "s.json"
    r = lesmc("perceive", str(frames), "--detector", str(TOML), "-o", str(out), "--max-iter", "5")
    assert r.returncode == 0, r.stderr
    assert "Traceback" not in r.stderr
    sess = ort.InferenceSession(str(NET))
    scene = json.loads(out.read_text())
    names = sorted(p.name for p in frames.glob("*.png"))
    assert len(scene["frames"]) == len(names) == 3
    n = 0
    for fr, name in zip(scene["frames"], names, strict=True):
        want = _decode(cv2.imread(str(frames / name), cv2.IMREAD_GRAYSCALE), sess)
        got = np.array([(d["x"], d["y"]) for d in fr["detections"]], float).reshape(-1, 2)
        assert np.array_equal(np.sort(got, axis=0), np.sort(want, axis=0)), (name, got, want)
        n += len(got)
    assert n > 0


def test_stride_not_dividing_the_frames_is_located(tmp_path: Path) -> None:
    frames = _video(tmp_path / "v", "250x192")
    r = lesmc("perceive", str(frames), "--detector", str(TOML))
    assert r.returncode == 2, r.stdout + r.stderr
    assert "Traceback" not in r.stderr
    line = next(i for i, t in enumerate(TOML.read_text().splitlines(), 1) if t.startswith("stride"))
    assert f"{TOML}:{line}" in r.stderr and "does not divide" in r.stderr, r.stderr
    assert str(frames) in r.stderr


def test_fixed_size_network_on_other_frames_is_located(tmp_path: Path) -> None:
    torch.manual_seed(0)
    net = torch.nn.Sequential(
        torch.nn.Conv2d(1, 4, 3, stride=2, padding=1),
        torch.nn.ReLU(),
        torch.nn.Conv2d(4, 1, 3, stride=2, padding=1),
    ).eval()
    onnx_path = tmp_path / "fixed.onnx"
    torch.onnx.export(
        net, (torch.zeros(2, 1, 64, 64),), str(onnx_path), dynamo=True, external_data=False,
        dynamic_shapes=({0: torch.export.Dim("batch")},),
    )  # fmt: skip
    toml = tmp_path / "det.toml"
    toml.write_text('kind = "heatmap"\nnetwork = "fixed.onnx"\nstride = 4\nthreshold = 0.5\n')
    frames = _video(tmp_path / "v", "96x64")
    r = lesmc("perceive", str(frames), "--detector", str(toml))
    assert r.returncode == 2, r.stdout + r.stderr
    assert "Traceback" not in r.stderr
    assert "takes 64x64 inputs" in r.stderr and "dynamic height and width" in r.stderr
