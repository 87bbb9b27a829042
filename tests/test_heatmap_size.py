"""Heatmap size channels (issue 60 item 1): ``size = "wh"`` in a detector file.

Three random fully convolutional networks with 3 output channels are made here and
exported to ONNX: channel 0 the score map, channels 1, 2 each cell's width and height.
lesmc's detections (positions and boxes) must equal a decode written here from
onnxruntime's outputs; the injection candidates carry the box at their cell; the
saved perturbations hide their detections when onnxruntime decodes channel 0; SORT
tracks the perceived scene; ``import mot --detector`` matches by IoU with each
detection's own box; bad input is a located error with exit 2.
"""

from __future__ import annotations

import json
import re
import warnings
from pathlib import Path
from typing import Any

import cv2
import numpy as np
import pytest
import torch
from cli_run import lesmc
from torch import nn

ort = pytest.importorskip("onnxruntime")
pytest.importorskip("onnx")
pytest.importorskip("onnxscript")

from test_heatmap_candidates import _maxima  # noqa: E402

H, W = 48, 64
WITHIN, CAP = 16.0, 3


class SigmoidSizes(nn.Module):
    """A body, a score conv and a size conv whose (w, h) = 4 + 20 · sigmoid(conv): not one
    chain of convolutions (attacks run on the whole frame; no certificate)."""

    def __init__(self, body: nn.Module, score: nn.Module, size: nn.Module) -> None:
        super().__init__()
        self.body, self.score, self.size = body, score, size

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        h = self.body(x)
        return torch.cat([self.score(h), 4.0 + 20.0 * torch.sigmoid(self.size(h))], dim=1)


def _nets() -> list[tuple[str, nn.Module, dict[str, Any]]]:
    """Three random networks with 3 output channels and their detector files' keys; the
    size channels of ``a`` and ``c`` are plain convolutions whose biases keep them > 0."""
    torch.manual_seed(6060)
    a = nn.Sequential(
        nn.Conv2d(1, 4, 3, padding=1), nn.ReLU(),
        nn.Conv2d(4, 4, 3, stride=2, padding=1), nn.ReLU(),
        nn.Conv2d(4, 3, 1),
    )  # fmt: skip
    b = SigmoidSizes(
        nn.Sequential(nn.Conv2d(1, 6, 5, stride=2, padding=2), nn.ReLU(),
                      nn.Conv2d(6, 6, 3, stride=2, padding=1), nn.ReLU()),
        nn.Conv2d(6, 1, 3, padding=1), nn.Conv2d(6, 2, 1),
    )  # fmt: skip
    c = nn.Sequential(
        nn.Conv2d(3, 4, 3, stride=2, padding=1), nn.ReLU(),
        nn.Conv2d(4, 5, 3, stride=2, padding=1),
    )  # fmt: skip
    with torch.no_grad():
        for last, (w0, h0) in ((a[-1], (9.0, 6.0)), (c[-1], (14.0, 11.0))):
            last.weight[1:3] *= 0.2  # sizes near the biases: > 0 everywhere on these frames
            last.bias[1:3] = torch.tensor([w0, h0])
    return [
        ("a", a.eval(), {"channels": "gray", "scale": [0.0, 1.0], "stride": 2, "score": "raw",
                         "nms_radius": 1}),
        ("b", b.eval(), {"channels": "gray", "scale": [-1.0, 1.0], "stride": 4,
                         "score": "sigmoid", "nms_radius": 1}),
        ("c", c.eval(), {"channels": "rgb", "scale": [0.0, 1.0], "stride": 4,
                         "score": "sigmoid", "nms_radius": 0}),
    ]  # fmt: skip


def _export(net: nn.Module, channels: int, path: Path) -> Path:
    """``net`` as ONNX with a dynamic batch, by torch's TorchScript exporter: the same
    operators and the same outputs, bit for bit, as the dynamo exporter's (checked on
    a, b, c), seconds faster per network (tests/spot_detector.py does the same)."""
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        torch.onnx.export(
            net, (torch.rand(2, channels, H, W),), str(path), dynamo=False,
            input_names=["x"], dynamic_axes={"x": {0: "batch"}},
        )  # fmt: skip
    return path


def _toml(path: Path, keys: dict[str, Any]) -> Path:
    path.write_text("".join(f"{k} = {json.dumps(v)}\n" for k, v in keys.items()))
    return path


def _input(img: np.ndarray, lo: float, hi: float) -> np.ndarray:
    """A frame as the network's (1, C, H, W) input (RGB from OpenCV's BGR)."""
    chw = img[None] if img.ndim == 2 else img[:, :, ::-1].transpose(2, 0, 1)
    return np.ascontiguousarray((lo + (hi - lo) * (chw.astype(np.float32) / 255.0))[None])


def _ort(path: Path, x: np.ndarray) -> np.ndarray:
    """onnxruntime's (K, rows, cols) output for the (1, C, H, W) input ``x``."""
    sess = ort.InferenceSession(str(path), providers=["CPUExecutionProvider"])
    y = sess.run(None, {sess.get_inputs()[0].name: x.astype(np.float32)})[0]
    return np.asarray(y, np.float64)[0]


def _score(raw: np.ndarray, how: str) -> np.ndarray:
    return 1.0 / (1.0 + np.exp(-raw)) if how == "sigmoid" else raw


def _decode(y: np.ndarray, keys: dict[str, Any], thr: float) -> list[tuple[float, ...]]:
    """The reference decode: (x, y, w, h) of each detection, row-major: a local maximum of
    channel 0's score >= ``thr`` at its cell's centre, its box channels 1, 2 there."""
    s, st = _score(y[0], keys["score"]), keys["stride"]
    return [
        ((j + 0.5) * st, (i + 0.5) * st, y[1, i, j], y[2, i, j])
        for i, j in _maxima(s, keys["nms_radius"])
        if s[i, j] >= thr
    ]


def _threshold(s: np.ndarray, r: int) -> float:
    """A threshold between two local maxima of ``s`` 1e-3 apart, below the 3rd highest."""
    v = np.sort([s[c] for c in _maxima(s, r)])[::-1]
    k = 2 + int(np.argmax(np.diff(-v[2:]) > 1e-3))
    return float((v[k] + v[k + 1]) / 2)


@pytest.fixture(scope="module")
def made(tmp_path_factory: pytest.TempPathFactory) -> dict[str, Any]:
    """Two grey and two colour frames; the three networks as ONNX with their detector files
    (size = "wh"); ``lesmc perceive -o --inject-within --save-attacks`` on each (``a``:
    with --certify)."""
    d = tmp_path_factory.mktemp("heatsize")
    rng = np.random.default_rng(60)
    imgs: dict[str, list[np.ndarray]] = {}
    for kind, shape in (("gray", (H, W)), ("rgb", (H, W, 3))):
        (d / kind).mkdir()
        imgs[kind] = []
        for k in range(2):
            img = cv2.GaussianBlur(rng.integers(0, 256, shape).astype(np.uint8), (5, 5), 1.5)
            cv2.imwrite(str(d / kind / f"f{k}.png"), img)
            imgs[kind].append(img)
    runs = {}
    for name, net, keys in _nets():
        c = 3 if keys["channels"] == "rgb" else 1
        onnx = _export(net, c, d / f"{name}.onnx")
        lo, hi = keys["scale"]
        ys = [_ort(onnx, _input(img, lo, hi)) for img in imgs[keys["channels"]]]
        thr = _threshold(_score(ys[0][0], keys["score"]), keys["nms_radius"])
        base = {"kind": "heatmap", "network": onnx.name, **keys, "threshold": thr}
        toml = _toml(d / f"{name}.toml", {**base, "size": "wh"})
        out, saved = d / f"{name}.json", d / f"saved_{name}"
        more = ["--certify"] if name == "a" else []  # a is one chain of convolutions
        r = lesmc("perceive", str(d / keys["channels"]), "--detector", str(toml), "-o",
                  str(out), "--inject-within", str(WITHIN), "--inject-cap", str(CAP),
                  "--save-attacks", str(saved), *more)  # fmt: skip
        assert r.returncode == 0, r.stderr
        assert "Traceback" not in r.stderr
        runs[name] = {"keys": keys, "ys": ys, "thr": thr, "toml": toml, "base": base,
                      "scene": json.loads(out.read_text()), "out": out, "saved": saved,
                      "xs": [_input(img, lo, hi) for img in imgs[keys["channels"]]]}  # fmt: skip
    return {"dir": d, "runs": runs}


@pytest.mark.parametrize("name", ["a", "b", "c"])
def test_detections_and_boxes_equal_onnxruntime_decode(made: dict[str, Any], name: str) -> None:
    """Each frame's detections: ids, positions (exactly) and boxes w, h (to float32
    rounding between runtimes) of the reference decode; the meta records the size."""
    run = made["runs"][name]
    total = 0
    for k, (fr, y) in enumerate(zip(run["scene"]["frames"], run["ys"], strict=True)):
        want = _decode(y, run["keys"], run["thr"])
        got = fr["detections"]
        assert [d["id"] for d in got] == [f"{k}:{n}" for n in range(len(want))]
        assert [(d["x"], d["y"]) for d in got] == [(x, yy) for x, yy, _, _ in want]
        for d, (_, _, w, h) in zip(got, want, strict=True):
            assert (d["w"], d["h"]) == pytest.approx((w, h), rel=1e-5, abs=1e-5)
        total += len(want)
    assert total >= 4
    assert run["scene"]["meta"]["detector_file"]["size"] == "wh"
    assert "box" not in run["scene"]["meta"]["detector_file"]


@pytest.mark.parametrize("name", ["a", "b"])
def test_candidates_carry_the_box_at_their_cell(made: dict[str, Any], name: str) -> None:
    """Each injection candidate ``FRAME:cK`` sits at the K-th (row-major) sub-threshold
    local maximum of onnxruntime's score map, with channels 1, 2 there as its box."""
    run = made["runs"][name]
    keys, st = run["keys"], run["keys"]["stride"]
    n = 0
    for fr, y in zip(run["scene"]["frames"], run["ys"], strict=True):
        s = _score(y[0], keys["score"])
        subs = [(i, j) for i, j in _maxima(s, keys["nms_radius"]) if s[i, j] < run["thr"]]
        for c in fr.get("candidates", []):
            i, j = subs[int(c["id"].split(":c")[1])]
            assert (c["x"], c["y"]) == ((j + 0.5) * st, (i + 0.5) * st)
            assert (c["w"], c["h"]) == pytest.approx((y[1, i, j], y[2, i, j]), rel=1e-5)
            n += 1
    assert n  # some candidate was priced


@pytest.mark.parametrize("name", ["a", "b"])
def test_saved_attacks_hide_their_detections(made: dict[str, Any], name: str) -> None:
    """Pricing reads channel 0 only: each saved perturbation, added to the frame, leaves no
    detection of onnxruntime's decode in its square, and its norm is the payoff."""
    run = made["runs"][name]
    keys, st, r = run["keys"], run["keys"]["stride"], run["keys"]["nms_radius"]
    path = made["dir"] / f"{name}.onnx"
    checked = 0
    for k, fr in enumerate(run["scene"]["frames"]):
        for n, d in enumerate(fr["detections"]):
            f = run["saved"] / f"{k}_{n}.npy"
            if d["payoff"] == "unattackable":
                assert not f.exists()
                continue
            delta = np.load(f)
            assert float(np.sqrt((delta.astype(np.float64) ** 2).sum())) == pytest.approx(
                d["payoff"], rel=1e-5
            )
            after = _decode(_ort(path, run["xs"][k] + delta), keys, run["thr"])
            i, j = int(d["y"] / st - 0.5), int(d["x"] / st - 0.5)
            assert not any(
                abs(yy / st - 0.5 - i) <= r and abs(x / st - 0.5 - j) <= r for x, yy, _, _ in after
            )
            checked += 1
    assert checked


def test_sort_tracks_the_perceived_scene(made: dict[str, Any]) -> None:
    """``lesmc track SCENE --design sort`` runs on the scene (its IoU reads every
    detection's own box), and verify's refusal of point detectors lets size = "wh" pass."""
    from lesmc.experiment.multi_verify import refuse_points_for_boxes

    r = lesmc("track", str(made["runs"]["c"]["out"]), "--design", "sort", "--json")
    assert r.returncode == 0, r.stderr
    assert "Traceback" not in r.stderr
    assert json.loads(r.stdout)
    refuse_points_for_boxes(str(made["runs"]["a"]["toml"]), "sort")


def test_certified_bounds_read_the_score_channel(made: dict[str, Any]) -> None:
    """Network ``a`` is one chain of convolutions with 3 output channels: certified bounds
    run on its score channel, and each is at most its payoff."""
    lows = 0
    for fr in made["runs"]["a"]["scene"]["frames"]:
        for det in fr["detections"]:
            if det["payoff"] != "unattackable":
                assert 0 <= det["payoff_lower"] <= det["payoff"]
                lows += det["payoff_lower"] > 0
    assert lows


def test_import_mot_matches_by_iou_of_each_box(made: dict[str, Any]) -> None:
    """det.txt boxes: one on each detection of frame 0 of network ``a`` with its own box
    (IoU 1), one at a detection's centre but 4 times its size (IoU 1/16 < 0.5: unmatched,
    though its centre is the detection's cell), one far away. Matched boxes take the
    detection's payoff; the others are unpriced, with a warning at their line."""
    run = made["runs"]["a"]
    d = made["dir"]
    dets = run["scene"]["frames"][0]["detections"]
    lines = [f"1,-1,{q['x'] - q['w'] / 2},{q['y'] - q['h'] / 2},{q['w']},{q['h']},1,-1,-1,-1"
             for q in dets]  # fmt: skip
    q = dets[0]
    lines.append(f"1,-1,{q['x'] - 2 * q['w']},{q['y'] - 2 * q['h']},{4 * q['w']},{4 * q['h']},1")
    lines.append("1,-1,-500,-500,4,4,1,-1,-1,-1")
    det_txt = d / "det.txt"
    det_txt.write_text("\n".join(lines) + "\n")
    out = d / "mot.json"
    r = lesmc("import", "mot", str(det_txt), "--frames", str(d / "gray"), "--detector",
              str(run["toml"]), "-o", str(out))  # fmt: skip
    assert r.returncode == 0, r.stderr
    assert "Traceback" not in r.stderr
    scene = json.loads(out.read_text())
    got = scene["frames"][0]["detections"]
    for g, want in zip(got, dets, strict=False):
        assert g["payoff"] == want["payoff"]
    n = len(dets)
    assert [g["payoff"] for g in got[n:]] == ["unpriced", "unpriced"]
    assert scene["meta"]["unmatched"] == [f"1:{n}", f"1:{n + 1}"]
    for line in (n + 1, n + 2):
        assert re.search(
            rf"det\.txt:{line}:1: box 1:{line - 1} .* is unpriced", r.stdout + r.stderr
        )


# ---------------------------------------------------------------- bad input


def _bad(made: dict[str, Any], keys: dict[str, Any]) -> tuple[str, int | None]:
    """``lesmc perceive`` with the detector file ``keys`` through the real entry point:
    exit 2, no traceback, nothing written; its stderr and the size key's line."""
    d = made["dir"]
    toml = _toml(d / "bad.toml", keys)
    out = d / "bad.json"
    r = lesmc("perceive", str(d / "gray"), "--detector", str(toml), "-o", str(out))
    assert r.returncode == 2, r.stderr
    assert "Traceback" not in r.stderr
    assert not out.exists()
    return r.stderr, list(keys).index("size") + 1 if "size" in keys else None


def _refused(made: dict[str, Any], keys: dict[str, Any], load: bool = False) -> str:
    """The InputError reading (``load``: and loading, network checked) the detector file
    ``keys`` raises, in process (faster than the CLI, which :func:`_bad` runs)."""
    from lesmc.common.errors import InputError
    from lesmc.perception.detector_file import load_detector, read_detector_file

    toml = _toml(made["dir"] / "bad.toml", keys)
    with pytest.raises(InputError) as err:
        (load_detector if load else read_detector_file)(toml)
    return str(err.value)


def _line(keys: dict[str, Any]) -> int:
    return list(keys).index("size") + 1


def test_size_with_kind_boxes_is_located(made: dict[str, Any]) -> None:
    keys = {"kind": "boxes", "network": "a.onnx", "threshold": 0.5, "size": "wh"}
    err = _refused(made, keys)
    assert re.search(rf'bad\.toml:{_line(keys)}:1: size: applies to kind = "heatmap", not', err)


def test_size_and_box_both_is_located(made: dict[str, Any]) -> None:
    keys = {**made["runs"]["a"]["base"], "box": [4, 4], "size": "wh"}
    err = _refused(made, keys)
    assert re.search(rf"bad\.toml:{_line(keys)}:1: size: and box exclude each other", err), err


def test_an_unknown_size_is_located(made: dict[str, Any]) -> None:
    keys = {**made["runs"]["a"]["base"], "size": "xywh"}
    err = _refused(made, keys)
    assert re.search(rf'bad\.toml:{_line(keys)}:1: size: must be "wh", got', err), err


@pytest.mark.parametrize("channels", [1, 2])
def test_too_few_channels_is_located(made: dict[str, Any], channels: int) -> None:
    """A network of 1 or 2 output channels with size = "wh": an error at the size line
    naming the output's shape."""
    torch.manual_seed(1)
    net = nn.Sequential(nn.Conv2d(1, 3, 3, padding=1), nn.ReLU(), nn.Conv2d(3, channels, 1))
    _export(net.eval(), 1, made["dir"] / f"few{channels}.onnx")
    keys = {**made["runs"]["a"]["base"], "network": f"few{channels}.onnx", "stride": 1,
            "size": "wh"}  # fmt: skip
    err = _refused(made, keys, load=True)
    assert re.search(rf"bad\.toml:{_line(keys)}:1: size: .*K >= 3", err), err
    assert f"it gave (3, {channels}, {H}, {W})" in err, err


def test_size_channels_without_size_say_so(made: dict[str, Any]) -> None:
    """Network ``a`` without size = "wh": its 3 channels are refused, naming the key."""
    err = _refused(made, made["runs"]["a"]["base"], load=True)
    assert 'declare size = "wh"' in err, err


def test_a_size_not_above_zero_is_located_at_the_frame(made: dict[str, Any]) -> None:
    """Network ``a`` with its width channel's bias lowered so that some detection's width
    is <= 0: exit 2, an error naming the frame file, the detection and the size line."""
    _, net, _ = _nets()[0]
    with torch.no_grad():
        net[-1].bias[1] = -100.0
    _export(net, 1, made["dir"] / "neg.onnx")
    keys = {**made["runs"]["a"]["base"], "network": "neg.onnx", "size": "wh"}
    err, line = _bad(made, keys)
    assert re.search(r"f0\.png: detection 0:0 \(cell row \d+, col \d+\) has width -", err), err
    assert f"bad.toml:{line})" in err, err
