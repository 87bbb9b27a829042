"""Detector files (issue 60, first slice): the user's whole-frame heatmap detector.

lesmc's detections (``lesmc perceive FRAMES --detector det.toml -o scene.json``)
must equal a decode written here from onnxruntime's outputs, on three random
small fully convolutional heatmap networks, each exported to ONNX and ``.pt2``;
a bad detector file or network is a located error with exit status 2.
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
from cli_run import ROOT, lesmc
from torch import nn

onnx = pytest.importorskip("onnx")
ort = pytest.importorskip("onnxruntime")
pytest.importorskip("onnxscript")

H, W = 48, 64
BATCH = ({0: torch.export.Dim("batch")},)


class Squeezed(nn.Module):
    """A body whose (B, 1, h, w) output is squeezed to (B, h, w)."""

    def __init__(self, body: nn.Module) -> None:
        super().__init__()
        self.body = body

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        out: torch.Tensor = self.body(x)[:, 0]
        return out


def _nets() -> list[tuple[str, nn.Module, dict[str, Any]]]:
    """Three random fully convolutional heatmap networks and their detector files' keys."""
    torch.manual_seed(60)
    a = nn.Sequential(
        nn.Conv2d(1, 4, 3, padding=1), nn.ReLU(),
        nn.Conv2d(4, 4, 3, stride=2, padding=1), nn.ReLU(),
        nn.Conv2d(4, 1, 1),
    )  # fmt: skip
    bn = nn.BatchNorm2d(6)
    bn.running_mean.uniform_(-0.2, 0.2)
    bn.running_var.uniform_(0.5, 2.0)
    b = nn.Sequential(
        nn.Conv2d(1, 6, 5, stride=2, padding=2), bn, nn.ReLU(),
        nn.Conv2d(6, 6, 3, stride=2, padding=1), nn.ReLU(),
        nn.Conv2d(6, 1, 3, padding=1),
    )  # fmt: skip
    c = Squeezed(
        nn.Sequential(
            nn.Conv2d(3, 4, 3, stride=2, padding=1), nn.ReLU(), nn.MaxPool2d(2),
            nn.Conv2d(4, 4, 3, padding=1), nn.ReLU(),
            nn.Conv2d(4, 1, 3, stride=2, padding=1),
        )
    )  # fmt: skip
    return [
        ("a", a.eval(), {"channels": "gray", "scale": [0.0, 1.0], "stride": 2, "score": "raw",
                         "nms_radius": 1}),
        ("b", b.eval(), {"channels": "gray", "scale": [-1.0, 1.0], "stride": 4,
                         "score": "sigmoid", "nms_radius": 2}),
        ("c", c.eval(), {"channels": "rgb", "scale": [0.0, 255.0], "stride": 8,
                         "score": "sigmoid", "nms_radius": 0}),
    ]  # fmt: skip


def export(net: nn.Module, channels: int, path: Path, dynamic: bool = True) -> Path:
    """``net`` as .pt2 or .onnx (by the suffix), with a dynamic batch unless not ``dynamic``."""
    x = torch.rand(3 if dynamic else 1, channels, H, W)
    shapes = BATCH if dynamic else None
    if path.suffix == ".pt2":
        torch.export.save(torch.export.export(net, (x,), dynamic_shapes=shapes), path)
    else:
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            torch.onnx.export(
                net, (x,), path, dynamic_shapes=shapes, dynamo=True, external_data=False
            )
    return path


def write_toml(path: Path, keys: dict[str, Any]) -> Path:
    """A detector file of ``keys`` (TOML, one key a line)."""
    lines = [f"{k} = {json.dumps(v)}" for k, v in keys.items()]
    path.write_text("\n".join(lines) + "\n")
    return path


@pytest.fixture(scope="module")
def setup(tmp_path_factory: pytest.TempPathFactory) -> dict[str, Any]:
    """Grey and colour frames (5 each, natural order f2 before f10) and the three networks."""
    d = tmp_path_factory.mktemp("detfile")
    rng = np.random.default_rng(60)
    out: dict[str, Any] = {"dir": d}
    for kind, shape in (("gray", (H, W)), ("rgb", (H, W, 3))):
        frames = d / f"frames_{kind}"
        frames.mkdir()
        imgs = []
        for k in range(5):
            img = cv2.GaussianBlur(rng.integers(0, 256, shape).astype(np.uint8), (5, 5), 1.5)
            cv2.imwrite(str(frames / f"f{[2, 10, 11, 30, 100][k]}.png"), img)
            imgs.append(img)
        out[kind] = (frames, imgs)
    out["nets"] = []
    for name, net, keys in _nets():
        c = 3 if keys["channels"] == "rgb" else 1
        onnx_path = export(net, c, d / f"{name}.onnx")
        pt2_path = export(net, c, d / f"{name}.pt2")
        out["nets"].append((name, keys, onnx_path, pt2_path))
    return out


def onnx_input(img: np.ndarray, lo: float, hi: float) -> np.ndarray:
    """A frame as the network's (1, C, H, W) input: RGB from OpenCV's BGR, lo + (hi-lo) v/255."""
    chw = img[None] if img.ndim == 2 else img[:, :, ::-1].transpose(2, 0, 1)
    return (lo + (hi - lo) * (chw.astype(np.float32) / np.float32(255.0)))[None]


def reference_peaks(s: np.ndarray, thr: float, r: int) -> list[tuple[int, int]]:
    """The decoding rule, cell by cell: >= threshold, >= every cell of its square, and of
    equal cells in a square, the first in row-major order wins."""
    rows, cols = s.shape
    got = []
    for i in range(rows):
        for j in range(cols):
            if s[i, j] < thr:
                continue
            ok = True
            for u in range(max(0, i - r), min(rows, i + r + 1)):
                for v in range(max(0, j - r), min(cols, j + r + 1)):
                    if (u, v) == (i, j):
                        continue
                    before = (u, v) < (i, j)
                    if s[u, v] > s[i, j] or (before and s[u, v] == s[i, j]):
                        ok = False
            if ok:
                got.append((i, j))
    return got


def ort_scores(path: Path, x: np.ndarray, how: str) -> np.ndarray:
    sess = ort.InferenceSession(str(path), providers=["CPUExecutionProvider"])
    y = sess.run(None, {sess.get_inputs()[0].name: x})[0].astype(np.float64)
    y = y.reshape(y.shape[-2], y.shape[-1])
    return 1.0 / (1.0 + np.exp(-y)) if how == "sigmoid" else y


def threshold_between(scores: np.ndarray, keep: float = 1 / 3) -> float:
    """A threshold keeping about the top ``keep`` of the cells, far (1e-4) from every score,
    so that float rounding between runtimes cannot move a cell across it."""
    v = np.sort(scores.ravel())
    gaps = np.diff(v)
    start = int(len(v) * (1 - keep))
    k = start + int(np.argmax(gaps[start:] > 2e-4))
    return float((v[k] + v[k + 1]) / 2)


@pytest.mark.parametrize("which", [0, 1, 2])
@pytest.mark.parametrize("fmt", ["onnx", "pt2"])
def test_detections_equal_onnxruntime_decode(setup: dict[str, Any], which: int, fmt: str) -> None:
    name, keys, onnx_path, _ = setup["nets"][which]
    frames, imgs = setup[keys["channels"]]
    lo, hi = keys["scale"]
    scores = [ort_scores(onnx_path, onnx_input(img, lo, hi), keys["score"]) for img in imgs]
    thr = threshold_between(scores[0])
    d: Path = setup["dir"]
    det = write_toml(
        d / f"{name}_{fmt}.toml",
        {"kind": "heatmap", "network": f"{name}.{fmt}", **keys, "threshold": thr},
    )
    out = d / f"{name}_{fmt}.json"
    # one DeepFool step a detection: the payoffs are test_saved_attacks_hide_their_detections'
    r = lesmc("perceive", str(frames), "--detector", str(det), "-o", str(out), "--max-iter", "1")
    assert r.returncode == 0, r.stderr
    assert "Traceback" not in r.stderr
    scene = json.loads(out.read_text())
    assert [f["step"] for f in scene["frames"]] == list(range(len(imgs)))
    total = 0
    for k, (fr, s) in enumerate(zip(scene["frames"], scores, strict=True)):
        want = reference_peaks(s, thr, keys["nms_radius"])
        got = [(dd["id"], dd["x"], dd["y"]) for dd in fr["detections"]]
        stride = keys["stride"]
        assert got == [
            (f"{k}:{n}", (j + 0.5) * stride, (i + 0.5) * stride) for n, (i, j) in enumerate(want)
        ]
        assert all(dd["payoff"] == "unattackable" or dd["payoff"] > 0 for dd in fr["detections"])
        total += len(want)
    assert total > 0
    meta = scene["meta"]
    assert meta["detector_file"]["path"] == str(det)
    assert meta["detector_file"]["network"] == str(d / f"{name}.{fmt}")


@pytest.mark.parametrize("attack", ["pgd", "deepfool"])
def test_saved_attacks_hide_their_detections(setup: dict[str, Any], attack: str) -> None:
    """Each saved perturbation, added to the frame and decoded from onnxruntime's outputs,
    leaves no detection in its detection's square, and its norm is the payoff."""
    name, keys, onnx_path, _ = setup["nets"][1]
    imgs = setup["gray"][1]
    lo, hi = keys["scale"]
    xs = [onnx_input(img, lo, hi) for img in imgs[:3]]
    thr = threshold_between(ort_scores(onnx_path, xs[0], keys["score"]), keep=0.08)
    d: Path = setup["dir"]
    sub = d / f"three_{attack}"
    sub.mkdir()
    for k in range(3):
        cv2.imwrite(str(sub / f"g{k}.png"), imgs[k])
    det = write_toml(
        d / f"att_{attack}.toml",
        {"kind": "heatmap", "network": f"{name}.onnx", **keys, "threshold": thr},
    )
    out, saved = d / f"att_{attack}.json", d / f"saved_{attack}"
    r = lesmc("perceive", str(sub), "--detector", str(det), "-o", str(out), "--attack", attack,
              "--save-attacks", str(saved))  # fmt: skip
    assert r.returncode == 0, r.stderr
    scene = json.loads(out.read_text())
    r_, stride = keys["nms_radius"], keys["stride"]
    priced = 0
    for k, fr in enumerate(scene["frames"]):
        for n, dd in enumerate(fr["detections"]):
            f = saved / f"{k}_{n}.npy"
            if dd["payoff"] == "unattackable":
                assert not f.exists()
                continue
            delta = np.load(f)
            assert delta.dtype == np.float32 and delta.shape == (1, 1, H, W)
            assert abs(float(np.sqrt((delta.astype(np.float64) ** 2).sum())) - dd["payoff"]) < 1e-5
            s = ort_scores(onnx_path, xs[k] + delta, keys["score"])
            i, j = int(dd["y"] // stride), int(dd["x"] // stride)
            left = [(u, v) for u, v in reference_peaks(s, thr, r_)
                    if abs(u - i) <= r_ and abs(v - j) <= r_]  # fmt: skip
            assert left == [], (dd["id"], left)
            priced += 1
    assert priced >= 3


def test_plateau_first_cell_wins() -> None:
    from lesmc.perception.heatmap import peaks

    s = np.array([[1.0, 1.0, 0.0, 0.0], [1.0, 1.0, 0.0, 0.5], [0.0, 0.0, 0.0, 0.0]])
    assert peaks(s, 0.5, 1).tolist() == [[0, 0], [1, 3]]
    assert peaks(s, 0.6, 1).tolist() == [[0, 0]]
    assert peaks(s, 0.5, 0).tolist() == [[0, 0], [0, 1], [1, 0], [1, 1], [1, 3]]
    assert peaks(s, 0.5, 3).tolist() == [[0, 0]]


def test_docs_table_is_the_declared_fields() -> None:
    from lesmc.perception.detector_file import fields_table

    assert fields_table() in (ROOT / "docs" / "detectors.md").read_text()


# ---------------------------------------------------------------- bad input


class NaNNet(nn.Module):
    def __init__(self) -> None:
        super().__init__()
        self.conv = nn.Conv2d(1, 1, 3, stride=2, padding=1)
        with torch.no_grad():
            self.conv.weight[0, 0, 1, 1] = float("nan")

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        out: torch.Tensor = self.conv(x)
        return out


def _bad_cases(d: Path) -> dict[str, tuple[dict[str, Any], str]]:
    """name -> (detector file keys, the error's expected pattern)."""
    base = {"kind": "heatmap", "network": "a.onnx", "stride": 2, "threshold": 0.5}
    (d / "adir.onnx").mkdir(exist_ok=True)
    export(NaNNet().eval(), 1, d / "nan.onnx")
    export(_nets()[0][1], 1, d / "static.onnx", dynamic=False)
    return {
        "output": (
            {**base, "output": "heatmap"},
            r"bad_output\.toml:5:1: output: the network .*a\.onnx has no output 'heatmap'",
        ),
        "kind": (
            {**base, "kind": "windows"},
            r'bad_kind\.toml:1:1: kind: must be "heatmap" or "boxes", got "windows"',
        ),
        "unknown": (
            {**base, "nms": 2},
            r"bad_unknown\.toml:5:1: nms: unknown key",
        ),
        "stride": (
            {**base, "stride": 5},
            r"bad_stride\.toml:3:1: stride: 5 does not divide the network's input, 64x48",
        ),
        "static": (
            {**base, "network": "static.onnx"},
            r"static\.onnx: the batch dimension is fixed at 1",
        ),
        "nan": (
            {**base, "network": "nan.onnx"},
            r"nan\.onnx: weight .* holds 1 NaN or infinite value",
        ),
        "directory": (
            {**base, "network": "adir.onnx"},
            r"bad_directory\.toml:2:1: network: .*adir\.onnx is a directory, not a network file",
        ),
        "missing": (
            {k: v for k, v in base.items() if k != "threshold"},
            r"bad_missing\.toml: threshold: is missing",
        ),
    }


CASES = ["output", "kind", "unknown", "stride", "static", "nan", "directory", "missing"]


@pytest.mark.parametrize("case", CASES)
def test_bad_detector_file_is_a_located_error(setup: dict[str, Any], case: str) -> None:
    d: Path = setup["dir"]
    keys, pattern = _bad_cases(d)[case]
    det = write_toml(d / f"bad_{case}.toml", keys)
    out = d / f"bad_{case}.json"
    r = lesmc("perceive", str(setup["gray"][0]), "--detector", str(det), "-o", str(out))
    assert r.returncode == 2, r.stderr
    assert "Traceback" not in r.stderr
    assert re.search(pattern, r.stderr), r.stderr
    assert not out.exists()


def test_json_detector_file_errors_name_the_line(setup: dict[str, Any]) -> None:
    d: Path = setup["dir"]
    det = d / "bad.json"
    det.write_text('{\n  "kind": "heatmap",\n  "network": "a.onnx",\n  "stride": 2,\n'
                   '  "threshold": 0.5,\n  "score": "softmax"\n}\n')  # fmt: skip
    r = lesmc("perceive", str(setup["gray"][0]), "--detector", str(det))
    assert r.returncode == 2, r.stderr
    assert re.search(r'bad\.json:6:3: score: must be "raw" or "sigmoid", got', r.stderr), r.stderr


def test_window_options_are_refused_with_a_detector_file(setup: dict[str, Any]) -> None:
    d: Path = setup["dir"]
    keys = setup["nets"][0][1]
    det = write_toml(d / "ok.toml", {"kind": "heatmap", "network": "a.onnx", **keys,
                                     "threshold": 0.0})  # fmt: skip
    out = d / "refused.json"
    frames = str(setup["gray"][0])
    r = lesmc("perceive", frames, "--detector", str(det), "--history", "3", "-o", str(out))
    assert r.returncode == 2, r.stderr
    assert "--history does not apply to a detector file" in r.stderr
    r = lesmc("perceive", frames, "--detector", str(det), "--save-attacks", str(d / "sa"))
    assert r.returncode == 2, r.stderr
    assert "--save-attacks saves the attacks that price a scene: it needs -o" in r.stderr
    r = lesmc("perceive", frames, "-o", str(out), "--save-attacks", str(d / "sa"))
    assert r.returncode == 2, r.stderr
    assert "--save-attacks applies to a detector file's payoffs" in r.stderr
    assert not out.exists()


def test_a_detector_files_payoffs_are_not_described_as_n_dr_windows() -> None:
    """The report's payoff unit and source for a scene perceived with a detector file name
    that file's network, not N_dr's 21x21 window (the window pipeline's words)."""
    from types import SimpleNamespace

    from lesmc.results.document import payoff_source, payoff_unit

    meta = {
        "detector": "heatmap detector det.toml",
        "detector_file": {"path": "det.toml"},
        "attack": {"method": "deepfool", "norm": "l2"},
    }
    run = SimpleNamespace(scene=SimpleNamespace(meta=meta))
    unit = payoff_unit([run])  # type: ignore[list-item]
    assert "detector file" in unit and "N_dr" not in unit
    source = payoff_source([run])  # type: ignore[list-item]
    assert "detector file" in source and "N_dr" not in source and "deepfool" in source
    del meta["detector_file"]  # the window pipeline's scene keeps its words
    assert "N_dr" in payoff_unit([run])  # type: ignore[list-item]


def test_a_detector_files_violations_are_replayed_through_the_file(
    tmp_path: Path,
) -> None:
    """A violation on a scene perceived with a detector file offers ``lesmc replay`` through
    that file, never a command replaying it through the window pipeline's networks (which
    ``lesmc verify --scene`` uses); verify checks such a scene, and refuses to replay it
    through the window pipeline (--frames without the detector file: exit 2)."""
    from lesmc.pipeline.check import replay_command
    from lesmc.report.text import not_replayed_text

    meta = {"detector": "heatmap", "detector_file": {"path": "det.toml"}, "source": "frames"}
    command = replay_command("s.json", meta)
    assert command == "lesmc replay RESULTS.json --frames frames --detector det.toml"
    text = not_replayed_text(command)
    assert text.startswith("violated (not replayed)") and "lesmc verify" not in text
    assert "lesmc verify --scene" in replay_command("s.json", {"detector": "N_dr"})
    doc = json.loads((ROOT / "examples" / "merge.json").read_text())
    doc.setdefault("meta", {})["detector_file"] = {"path": "det.toml"}
    scene = tmp_path / "scene.json"
    scene.write_text(json.dumps(doc))
    # checked without a replay (its results offer the replay through the file) ...
    r = lesmc("verify", "--scene", str(scene), "--out", str(tmp_path / "out"))
    assert r.returncode in (0, 1, 3) and "Traceback" not in r.stderr, r.stderr
    # ... and refused with frames but not the file: the window pipeline would replay it
    r = lesmc("verify", "--scene", str(scene), "--frames", str(tmp_path),
              "--out", str(tmp_path / "out2"))  # fmt: skip
    assert r.returncode == 2 and "detector file" in r.stderr and "Traceback" not in r.stderr
