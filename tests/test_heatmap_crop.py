"""Heatmap detectors on crops (issue 60, second slice): the attack runs on the detection's
crop, and certified lower bounds come from the peak cell's crop.

* the crop's cells equal the whole frame's, computed by the torch network itself;
* ``payoff_lower <= payoff`` for every detection, and a 200-step PGD on the whole
  frame inside 0.99 x ``payoff_lower`` never hides a detection (about 30 of them);
* a network the crop cannot express is refused for --certify naming its node (exit 2),
  while its payoffs still come from attacks on the whole frame.
"""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any

import numpy as np
import pytest
import torch
from cli_run import lesmc
from torch import nn

pytest.importorskip("onnx")
pytest.importorskip("onnxscript")

import cv2
from test_detector_file import (
    H,
    W,
    _nets,
    export,
    onnx_input,
    reference_peaks,
    write_toml,
)


@pytest.fixture(scope="module")
def made(tmp_path_factory: pytest.TempPathFactory) -> dict[str, Any]:
    """Grey frames (4) and the test_detector_file networks, exported to ONNX and .pt2."""
    d = tmp_path_factory.mktemp("heatcrop")
    rng = np.random.default_rng(61)
    frames = d / "frames"
    frames.mkdir()
    imgs = []
    for k in range(4):
        img = cv2.GaussianBlur(rng.integers(0, 256, (H, W)).astype(np.uint8), (5, 5), 1.5)
        cv2.imwrite(str(frames / f"f{k}.png"), img)
        imgs.append(img)
    nets = []
    for name, net, keys in _nets():
        c = 3 if keys["channels"] == "rgb" else 1
        nets.append((name, net, keys, export(net, c, d / f"{name}.onnx"),
                     export(net, c, d / f"{name}.pt2")))  # fmt: skip
    return {"dir": d, "frames": frames, "imgs": imgs, "nets": nets}


def _raw(net: nn.Module, x: np.ndarray) -> np.ndarray:
    """The torch network's own raw heatmap (rows, cols) of one input."""
    with torch.no_grad():
        y = net(torch.from_numpy(x))
    return y.reshape(y.shape[-2], y.shape[-1]).double().numpy()


def _threshold(raw: np.ndarray, keep: int, r: int) -> float:
    """A raw threshold leaving about ``keep`` local peaks, halfway between two peak values."""
    cells = reference_peaks(raw, -np.inf, r)
    v = np.sort([raw[i, j] for i, j in cells])[::-1]
    n = min(keep, len(v) - 1)
    return float((v[n - 1] + v[n]) / 2)


@pytest.mark.parametrize("which", [0, 1])
@pytest.mark.parametrize("fmt", ["onnx", "pt2"])
def test_crop_cells_equal_the_whole_frames(made: dict[str, Any], which: int, fmt: str) -> None:
    """For random ranges of cells, the crop ConvNet.crop names computes exactly the cells
    the torch network computes on the whole frame (edges included)."""
    from lesmc.perception.detector_file import load_detector
    from lesmc.perception.heatmap_crop import conv_net

    name, net, keys, onnx_path, pt2_path = made["nets"][which]
    path = onnx_path if fmt == "onnx" else pt2_path
    toml = write_toml(
        made["dir"] / f"crop_{name}_{fmt}.toml",
        {"kind": "heatmap", "network": path.name, **keys, "threshold": 0.0},
    )
    det = load_detector(toml)
    conv = conv_net(det)
    assert conv.stride == keys["stride"]
    lo, hi = keys["scale"]
    x = onnx_input(made["imgs"][0], lo, hi)
    want = _raw(net, x)
    rows, cols = want.shape
    rng = np.random.default_rng(which)
    for _ in range(12):
        a = int(rng.integers(0, rows))
        b = int(rng.integers(a, min(rows, a + 3)))
        c = int(rng.integers(0, cols))
        e = int(rng.integers(c, min(cols, c + 3)))
        y0, y1 = conv.crop(a, b, H)
        x0, x1 = conv.crop(c, e, W)
        s = conv.stride
        with torch.no_grad():
            got = conv(torch.from_numpy(x[:, :, y0:y1, x0:x1]))[0].double().numpy()
        part = got[a - y0 // s : b - y0 // s + 1, c - x0 // s : e - x0 // s + 1]
        np.testing.assert_allclose(part, want[a : b + 1, c : e + 1], rtol=1e-5, atol=1e-5)
        assert (y1 - y0) * (x1 - x0) < H * W  # a crop, not the frame


def _pgd_keeps(net: nn.Module, x: np.ndarray, i: int, j: int, r: int, t: float, eps: float) -> bool:
    """A 200-step L2 PGD on the whole frame (no clipping: the certified ball) pushing the
    peak cell (i, j) down: True when after every step the peak cell, and so its square
    (the detection is hidden only when every cell of it is), stays at or above ``t``."""
    x0 = torch.from_numpy(x)
    rows, cols = _raw(net, x).shape
    g = torch.Generator().manual_seed(i * 1000 + j)
    delta = torch.randn(x0.shape, generator=g)
    delta *= 0.5 * eps / delta.norm()
    step = 2.5 * eps / 200
    for _ in range(200):
        delta.requires_grad_(True)
        y = net(x0 + delta).reshape(rows, cols)
        if float(y[i, j].detach()) < t:
            return False
        (grad,) = torch.autograd.grad(y[i, j], delta)
        with torch.no_grad():
            delta = delta - step * grad / (grad.norm() + 1e-12)
            n = delta.norm()
            if n > eps:
                delta = delta * (eps / n)
    return float(_raw(net, (x0 + delta).numpy())[i, j]) >= t


def test_certified_lower_bounds_hold(made: dict[str, Any]) -> None:
    """``payoff_lower <= payoff`` for every detection the CLI writes (perceive --certify), and
    PGD inside 0.99 x payoff_lower never hides one (30 detections, two networks)."""
    checked = 0
    for which in (0, 1):
        name, net, keys, onnx_path, _ = made["nets"][which]
        lo, hi = keys["scale"]
        xs = [onnx_input(img, lo, hi) for img in made["imgs"]]
        raw_t = _threshold(_raw(net, xs[0]), 8, keys["nms_radius"])
        thr = raw_t if keys["score"] == "raw" else float(1 / (1 + np.exp(-raw_t)))
        toml = write_toml(
            made["dir"] / f"cert_{name}.toml",
            {"kind": "heatmap", "network": onnx_path.name, **keys, "threshold": thr},
        )
        out = made["dir"] / f"cert_{name}.json"
        r = lesmc("perceive", str(made["frames"]), "--detector", str(toml), "-o", str(out),
                  "--certify")  # fmt: skip
        assert r.returncode == 0, r.stderr
        scene = json.loads(out.read_text())
        assert scene["meta"]["certify"]["method"] == "CROWN, L2 ball"
        s = keys["stride"]
        for k, fr in enumerate(scene["frames"]):
            for dd in fr["detections"]:
                low = dd["payoff_lower"]
                assert isinstance(low, float) and low >= 0.0
                if dd["payoff"] != "unattackable":
                    assert low <= dd["payoff"]
                if low <= 0.0 or checked == 30:
                    continue
                i, j = int(dd["y"] // s), int(dd["x"] // s)
                assert _pgd_keeps(net, xs[k], i, j, keys["nms_radius"], raw_t, 0.99 * low), dd
                checked += 1
    assert checked == 30


def test_certify_refuses_a_network_it_cannot_express(made: dict[str, Any]) -> None:
    """The max-pooling network: --certify is a located error naming the node (exit 2);
    without it, its detections are still priced (by attacks on the whole frame)."""
    _, _, keys, onnx_path, _ = made["nets"][2]
    d: Path = made["dir"]
    rgb = d / "frames_rgb"
    rgb.mkdir(exist_ok=True)
    for k, img in enumerate(made["imgs"][:2]):
        cv2.imwrite(str(rgb / f"f{k}.png"), np.repeat(img[:, :, None], 3, axis=2))
    toml = write_toml(
        d / "pool.toml", {"kind": "heatmap", "network": onnx_path.name, **keys, "threshold": 0.5}
    )
    r = lesmc("perceive", str(rgb), "--detector", str(toml), "-o", str(d / "pool.json"),
              "--certify")  # fmt: skip
    assert r.returncode == 2, r.stderr
    assert "Traceback" not in r.stderr
    assert str(onnx_path) in r.stderr and "MaxPool" in r.stderr and "node '" in r.stderr
    assert not (d / "pool.json").exists()
    r = lesmc("perceive", str(rgb), "--detector", str(toml), "-o", str(d / "pool.json"))
    assert r.returncode == 0, r.stderr
