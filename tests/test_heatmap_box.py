"""A heatmap detector file's declared box (issue 61 gap: heatmap injection candidates had
no box, so SORT could not use them): ``box = [w, h]`` gives every detection and every
injection candidate that box, centred on its cell's centre; bad values are located
errors (exit 2); a file without it still gives points, which sort refuses.

The network is a tiny heatmap network made here (tests/test_detector_file.py's ``a``);
the detections' and candidates' cells are checked against a decode written here from
onnxruntime's outputs (tests/test_heatmap_candidates.py's reference)."""

from __future__ import annotations

import json
import re
from pathlib import Path
from typing import Any

import numpy as np
import pytest
from cli_run import lesmc

pytest.importorskip("onnx")
pytest.importorskip("onnxscript")
pytest.importorskip("onnxruntime")

import cv2
from test_detector_file import H, W, _nets, export, onnx_input, ort_scores, write_toml
from test_heatmap_candidates import _maxima, _reference, _threshold

BOX = [9.5, 6.0]
WITHIN, CAP = 12.0, 3


@pytest.fixture(scope="module")
def made(tmp_path_factory: pytest.TempPathFactory) -> dict[str, Any]:
    """One grey frame, network ``a`` as ONNX, a detector file declaring BOX, and the
    scene ``lesmc perceive --inject-within`` writes with it."""
    d = tmp_path_factory.mktemp("heatbox")
    rng = np.random.default_rng(62)
    frames = d / "frames"
    frames.mkdir()
    imgs = []
    for k in range(1):
        img = cv2.GaussianBlur(rng.integers(0, 256, (H, W)).astype(np.uint8), (5, 5), 1.5)
        cv2.imwrite(str(frames / f"f{k}.png"), img)
        imgs.append(img)
    name, net, keys = _nets()[0]
    path = export(net, 1, d / f"{name}.onnx")
    lo, hi = keys["scale"]
    scores = [ort_scores(path, onnx_input(img, lo, hi), keys["score"]) for img in imgs]
    thr = _threshold(scores[0], keys["nms_radius"])
    base = {"kind": "heatmap", "network": path.name, **keys, "threshold": thr}
    toml = write_toml(d / "det.toml", {**base, "box": BOX})
    out = d / "scene.json"
    r = lesmc("perceive", str(frames), "--detector", str(toml), "-o", str(out),
              "--inject-within", str(WITHIN), "--inject-cap", str(CAP))  # fmt: skip
    assert r.returncode == 0, r.stderr
    assert "Traceback" not in r.stderr
    return {"dir": d, "base": base, "keys": keys, "scores": scores, "thr": thr, "out": out}


def test_detections_and_candidates_carry_the_declared_box(made: dict[str, Any]) -> None:
    """Every detection and candidate of the scene has w, h = BOX and sits at its cell's
    centre of the reference decode; the scene records the box in meta.detector_file."""
    scene = json.loads(made["out"].read_text())
    keys, thr = made["keys"], made["thr"]
    r, s = keys["nms_radius"], keys["stride"]
    n_cand = 0
    for k, fr in enumerate(scene["frames"]):
        sc = made["scores"][k]
        want = [((j + 0.5) * s, (i + 0.5) * s) for i, j in _maxima(sc, r) if sc[i, j] >= thr]
        assert [(d["x"], d["y"]) for d in fr["detections"]] == want
        cands = _reference(sc, thr, r, s, WITHIN)
        for c in fr.get("candidates", []):
            q = int(c["id"].split(":c")[1])
            assert (c["x"], c["y"]) == cands[q][1]
        for d in [*fr["detections"], *fr.get("candidates", [])]:
            assert [d["w"], d["h"]] == BOX, d
        n_cand += len(fr.get("candidates", []))
    assert n_cand  # some candidate was priced and carries the box
    assert scene["meta"]["detector_file"]["box"] == BOX


def test_sort_tracks_a_scene_of_the_box(made: dict[str, Any], tmp_path: Path) -> None:
    """``lesmc track --design sort`` runs on the scene (its IoU reads every detection's
    box); the same scene with the boxes taken out is refused for having none; the frames
    answer boxes [x - w/2, y - h/2, x + w/2, y + h/2] for detections and candidates."""
    from lesmc.api import load_scene

    r = lesmc("track", str(made["out"]), "--design", "sort", "--json")
    assert r.returncode == 0, r.stderr
    assert "Traceback" not in r.stderr
    doc = json.loads(made["out"].read_text())
    for fr in doc["frames"]:
        for d in [*fr["detections"], *fr.get("candidates", [])]:
            d.pop("w")
            d.pop("h")
    bare = tmp_path / "points.json"
    bare.write_text(json.dumps(doc))
    r = lesmc("track", str(bare), "--design", "sort", "--json")
    assert r.returncode == 2 and "has no box" in r.stderr, r.stderr
    first = doc["frames"][0]["detections"][0]
    scene = load_scene(made["out"], target=f"{first['x']},{first['y']}@0")
    for f in scene.frames:
        assert f.has_boxes and f.candidates_have_boxes
        for d, b in zip(f.detections, f.boxes(), strict=True):
            want = [d.x - BOX[0] / 2, d.y - BOX[1] / 2, d.x + BOX[0] / 2, d.y + BOX[1] / 2]
            assert b.tolist() == pytest.approx(want)


def test_sort_with_a_heatmap_file_needs_a_box(made: dict[str, Any]) -> None:
    """verify's refusal of a point detector for a box design: with the box declared it
    passes; without it, it names ``box = [w, h]``."""
    from lesmc.common.errors import UsageError
    from lesmc.experiment.multi_verify import refuse_points_for_boxes

    d = made["dir"]
    refuse_points_for_boxes(str(d / "det.toml"), "sort")
    points = write_toml(d / "points.toml", made["base"])
    with pytest.raises(UsageError, match=re.escape("box = [w, h]")):
        refuse_points_for_boxes(str(points), "sort")


BAD = [
    ([0, 5], "heatmap", r"box: must be \[w, h\], two finite numbers > 0"),
    ([4], "heatmap", r"box: must be \[w, h\]"),
    ("8x6", "heatmap", r"box: must be \[w, h\]"),
    ([4, -1], "heatmap", r"box: must be \[w, h\]"),
    ([4, 4], "boxes", r'box: applies to kind = "heatmap", not "boxes"'),
]


def _bad_file(d: Path, base: dict[str, Any], box: Any, kind: str) -> tuple[Path, int]:
    """A detector file with ``box`` (of ``kind``) and the line the box is on."""
    keys = {**base, "box": box}
    if kind == "boxes":
        keys = {"kind": "boxes", "network": base["network"], "threshold": 0.5, "box": box}
    return write_toml(d / "bad.toml", keys), list(keys).index("box") + 1


@pytest.mark.parametrize(("box", "kind", "pattern"), BAD)
def test_a_bad_box_is_a_located_error(
    made: dict[str, Any], box: Any, kind: str, pattern: str
) -> None:
    """Read in process: an InputError at the box's line."""
    from lesmc.common.errors import InputError
    from lesmc.perception.detector_file import read_detector_file

    toml, line = _bad_file(made["dir"], made["base"], box, kind)
    with pytest.raises(InputError) as err:
        read_detector_file(toml)
    assert re.search(rf"bad\.toml:{line}:1: " + pattern, str(err.value)), str(err.value)


def test_a_bad_box_exits_2_from_the_cli(made: dict[str, Any]) -> None:
    """Through the real entry point: exit 2 at the box's line, nothing written."""
    d = made["dir"]
    toml, line = _bad_file(d, made["base"], [0, 5], "heatmap")
    r = lesmc("perceive", str(d / "frames"), "--detector", str(toml), "-o", str(d / "x.json"))
    assert r.returncode == 2, r.stderr
    assert "Traceback" not in r.stderr
    assert re.search(rf"bad\.toml:{line}:1: " + BAD[0][2], r.stderr), r.stderr
    assert not (d / "x.json").exists()
