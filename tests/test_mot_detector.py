"""``lesmc import mot DET --frames DIR --detector FILE.toml`` (issue 60, round 3, item 3).

A det.txt whose boxes sit on the detections of a random heatmap network (and, second
test, of a random box-list network), decoded here from onnxruntime's output, plus one
box far from every detection: each matched box takes the payoff ``lesmc perceive
--detector -o`` gives the detection the test placed it on; the far box is "unpriced",
named in ``meta.unmatched`` and in a warning at its det.txt line; a check reading it
would stop, never price it silently. Bad combinations of options are exit 2.
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
from test_detector_boxes import _ort, _reference, _toml, made  # noqa: F401  (a fixture)

ort = pytest.importorskip("onnxruntime")
pytest.importorskip("onnxscript")

H, W, STRIDE, RADIUS = 48, 64, 4, 1


def _heat_net(d: Path) -> tuple[Path, list[np.ndarray], float]:
    """A random fully convolutional heatmap net (stride 4) in ONNX, 3 random frames, and a
    threshold that leaves a few peaks a frame."""
    torch.manual_seed(60)
    net = torch.nn.Sequential(
        torch.nn.Conv2d(1, 6, 5, stride=2, padding=2), torch.nn.ReLU(),
        torch.nn.Conv2d(6, 1, 3, stride=2, padding=1),
    ).eval()  # fmt: skip
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        torch.onnx.export(  # TorchScript: the dynamo exporter's operators, seconds faster
            net, (torch.rand(2, 1, H, W),), str(d / "heat.onnx"), dynamo=False,
            input_names=["x"], dynamic_axes={"x": {0: "batch"}},
        )  # fmt: skip
    frames = d / "frames"
    frames.mkdir()
    rng = np.random.default_rng(60)
    xs = []
    for k in range(3):
        img = cv2.GaussianBlur(rng.integers(0, 256, (H, W)).astype(np.uint8), (7, 7), 2.0)
        cv2.imwrite(str(frames / f"f{k}.png"), img)
        xs.append((img.astype(np.float32) / np.float32(255.0))[None, None])
    maps = np.stack([_raw(d / "heat.onnx", x) for x in xs])
    return frames, xs, float(np.quantile(maps, 0.93))


def _raw(path: Path, x: np.ndarray) -> np.ndarray:
    sess = ort.InferenceSession(str(path), providers=["CPUExecutionProvider"])
    out: np.ndarray = sess.run(None, {sess.get_inputs()[0].name: x})[0].astype(np.float64)
    return out.reshape(H // STRIDE, W // STRIDE)


def _peaks(raw: np.ndarray, thr: float) -> list[tuple[float, float]]:
    """Cells >= thr and >= every cell within RADIUS (raw score; no ties on these maps),
    row-major, at their cells' centres."""
    out = []
    for i in range(raw.shape[0]):
        for j in range(raw.shape[1]):
            sq = raw[max(0, i - RADIUS) : i + RADIUS + 1, max(0, j - RADIUS) : j + RADIUS + 1]
            if raw[i, j] >= thr and raw[i, j] == sq.max():
                out.append(((j + 0.5) * STRIDE, (i + 0.5) * STRIDE))
    return out


def _payoffs(scene_path: Path) -> dict[tuple[int, float, float], Any]:
    scene = json.loads(scene_path.read_text())
    return {
        (fr["step"], round(d["x"], 3), round(d["y"], 3)): d["payoff"]
        for fr in scene["frames"]
        for d in fr["detections"]
    }


def test_heatmap_boxes_priced_and_unmatched_reported(tmp_path: Path) -> None:
    frames, xs, thr = _heat_net(tmp_path)
    toml = tmp_path / "det.toml"
    toml.write_text(
        f'kind = "heatmap"\nnetwork = "heat.onnx"\nstride = {STRIDE}\nthreshold = {thr}\n'
        f"nms_radius = {RADIUS}\n"
    )
    r = lesmc("perceive", str(frames), "--detector", str(toml), "-o", str(tmp_path / "p.json"))
    assert r.returncode == 0, r.stderr
    priced = _payoffs(tmp_path / "p.json")
    lines, want = [], {}
    for k, x in enumerate(xs):
        for px, py in _peaks(_raw(tmp_path / "heat.onnx", x), thr):
            # a 6x6 box whose centre is 1 px off the peak: in the peak's cell
            lines.append(f"{k + 1},-1,{px - 2:g},{py - 2:g},6,6,1,-1,-1,-1")
            want[(k + 1, px + 1, py + 1)] = priced[(k, round(px, 3), round(py, 3))]
    assert len(want) >= 3
    far = len(lines) + 1  # its line number
    lines.append("3,-1,-500,-500,4,4,1,-1,-1,-1")
    det = tmp_path / "det.txt"
    det.write_text("\n".join(lines) + "\n")
    out = tmp_path / "s.json"
    r = lesmc("import", "mot", str(det), "--frames", str(frames), "--detector", str(toml),
              "-o", str(out))  # fmt: skip
    assert r.returncode == 0, r.stdout + r.stderr
    assert "Traceback" not in r.stderr
    scene = json.loads(out.read_text())
    got = {(fr["step"], d["x"], d["y"]): d for fr in scene["frames"] for d in fr["detections"]}
    for key, pay in want.items():
        assert got[key]["payoff"] == pay, key
    unpriced = [d["id"] for d in got.values() if d["payoff"] == "unpriced"]
    assert len(unpriced) == 1 and scene["meta"]["unmatched"] == unpriced
    assert f"warning: {det}:{far}:1: box {unpriced[0]}" in r.stdout + r.stderr
    assert scene["meta"]["detector_file"]["kind"] == "heatmap"


def test_box_detector_boxes_priced_by_iou(made: dict[str, Any], tmp_path: Path) -> None:  # noqa: F811
    toml = _toml(made, "mot_box.toml", "box.onnx")
    r = lesmc("perceive", str(made["frames"]), "--detector", str(toml), "-o",
              str(tmp_path / "p.json"))  # fmt: skip
    assert r.returncode == 0, r.stderr
    priced = _payoffs(tmp_path / "p.json")
    lines, want = [], {}
    for k, x in enumerate(made["xs"]):
        for b in _reference(_ort(made["dir"] / "box.onnx", x), made["thr"], 0.3):
            b = [float(v) for v in b]
            w, h = b[2] - b[0], b[3] - b[1]
            # the box shrunk by 5 % of its size on each side: IoU 0.81 with the detection
            lines.append(f"{k + 1},-1,{b[0] + 0.05 * w!r},{b[1] + 0.05 * h!r},"
                         f"{0.9 * w!r},{0.9 * h!r},1,-1,-1,-1")  # fmt: skip
            cx, cy = (b[0] + b[2]) / 2, (b[1] + b[3]) / 2
            want[(k + 1, round(cx, 3), round(cy, 3))] = priced[(k, round(cx, 3), round(cy, 3))]
    lines.append("3,-1,1000,1000,5,5,1,-1,-1,-1")
    det = tmp_path / "det.txt"
    det.write_text("\n".join(lines) + "\n")
    out = tmp_path / "s.json"
    r = lesmc("import", "mot", str(det), "--frames", str(made["frames"]), "--detector",
              str(toml), "-o", str(out))  # fmt: skip
    assert r.returncode == 0, r.stdout + r.stderr
    scene = json.loads(out.read_text())
    got = {
        (fr["step"], round(d["x"], 3), round(d["y"], 3)): d["payoff"]
        for fr in scene["frames"]
        for d in fr["detections"]
    }
    assert want and all(got[key] == pay for key, pay in want.items())
    assert list(got.values()).count("unpriced") == 1
    assert len(scene["meta"]["unmatched"]) == 1


@pytest.mark.parametrize(
    ("extra", "says"),
    [
        (["--detector", "d.toml"], "--frames and --detector go together"),
        (["--frames", ".", "--detector", "d.toml", "--payoff", "2"], "--payoff prices"),
        (["--frames", ".", "--detector", "n.onnx"], "give a detector file"),
    ],
)
def test_bad_combinations_exit_2(tmp_path: Path, extra: list[str], says: str) -> None:
    det = tmp_path / "det.txt"
    det.write_text("1,-1,5,5,4,4,1,-1,-1,-1\n")
    r = lesmc("import", "mot", str(det), "-o", str(tmp_path / "s.json"), *extra, cwd=tmp_path)
    assert r.returncode == 2, r.stdout + r.stderr
    assert "Traceback" not in r.stderr and says in r.stderr, r.stderr
    assert not (tmp_path / "s.json").exists()
