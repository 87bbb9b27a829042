"""``lesmc campaign VIDEOS --detector det.toml`` (issue 60: a detector file in campaigns).

Two tiny videos (a bright spot moving past a static one) and a hand-set two-layer heatmap
network made here: the campaign perceives each video through the detector file into
OUT/scenes (detections equal a decode written here from onnxruntime's output, every
detection priced), checks a property per (target, window, design) into results.jsonl,
and a rerun reuses the scenes and the rows. A detector file changed since is an error
(exit 2), as are the window pipeline's networks beside it.
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

pytest.importorskip("onnx")
ort = pytest.importorskip("onnxruntime")
pytest.importorskip("onnxscript")

N = 12
WINDOWS = "5..6:2..2"  # 5..7 and 6..8
DESIGNS = ("single",)


def _frames(d: Path, dy: int) -> Path:
    """N frames: a spot accelerating to the right past a static one (shifted ``dy``), Gaussian
    spots at off-grid centres, so that no two cells of a peak's square score alike."""
    fr = d / f"video{dy}"
    fr.mkdir()
    yy, xx = np.mgrid[0:H, 0:W].astype(np.float64)
    for k in range(N):
        img = np.full((H, W), 20.0)
        for x, y in ((10.3 + 6 * k + 0.15 * k * k, 29.3 + 0.13 * k * k + dy), (60.4, 44.3)):
            img += 210 * np.exp(-((xx - x) ** 2 + (yy - y) ** 2) / (2 * 2.0**2))
        cv2.imwrite(str(fr / f"f{k:02d}.png"), np.clip(np.rint(img), 0, 255).astype(np.uint8))
    return fr


def _decode(path: Path, sess: Any) -> list[tuple[float, float]]:
    """The detections of one frame, decoded here: raw cells >= 0 that are the maximum of
    their 5x5 square (first in row-major order among equals), at the cells' centres."""
    img = cv2.imread(str(path), cv2.IMREAD_GRAYSCALE).astype(np.float32) / np.float32(255)
    raw = sess.run(None, {sess.get_inputs()[0].name: img[None, None]})[0][0, 0]
    s = raw.astype(np.float64)
    out = []
    for i in range(s.shape[0]):
        for j in range(s.shape[1]):
            sq = s[max(0, i - 2) : i + 3, max(0, j - 2) : j + 3]
            if s[i, j] >= 0.0 and s[i, j] == sq.max():
                # no near tie: another runtime's rounding could not pick another cell
                assert np.sort(sq, axis=None)[-2] < s[i, j] - 1e-4
                assert abs(s[i, j]) > 1e-4  # nor a score at the threshold
                out.append(((j + 0.5) * 4, (i + 0.5) * 4))
    return out


def _campaign(c: dict[str, Any], *extra: str) -> Any:
    return lesmc(
        "campaign", str(c["videos"][0]), str(c["videos"][1]), "--detector", str(c["toml"]),
        "--out", str(c["out"]), "--workers", "0", "--spec", str(c["spec"]),
        "--windows", WINDOWS, "--targets", str(c["targets"]), "--design", "single", *extra,
    )  # fmt: skip


@pytest.fixture(scope="module")
def camp(tmp_path_factory: pytest.TempPathFactory) -> dict[str, Any]:
    d = tmp_path_factory.mktemp("campdet")
    videos = [_frames(d, 0), _frames(d, 4)]
    toml = write_spot_detector(d)
    (d / "p.spec").write_text(SPEC)
    targets = d / "targets.txt"
    targets.write_text("video0 10,30@0\nvideo4 10,34@0\n")
    c = {"dir": d, "videos": videos, "toml": toml, "spec": d / "p.spec", "targets": targets,
         "out": d / "out"}  # fmt: skip
    c["r"] = _campaign(c)
    return c


def _rows(c: dict[str, Any]) -> list[dict[str, Any]]:
    lines = (c["out"] / "results.jsonl").read_text().splitlines()
    return [json.loads(line) for line in lines]


def test_campaign_runs_every_unit(camp: dict[str, Any]) -> None:
    r = camp["r"]
    assert "Traceback" not in r.stderr and "internal error" not in r.stderr, r.stderr
    assert r.returncode in (0, 1), r.stdout + r.stderr
    rows = _rows(camp)
    got = sorted((x["video"], tuple(x["window"]), x["design"]) for x in rows)
    want = sorted(
        (v, w, design) for v in ("video0", "video4") for w in ((5, 7), (6, 8)) for design in DESIGNS
    )
    assert got == want
    assert all(x["property"] == "hide_cheap" for x in rows)
    assert all(x["verdict"] in ("holds", "violated") for x in rows), rows
    assert (camp["out"] / "campaign.html").is_file()


def test_scenes_hold_the_detector_files_detections(camp: dict[str, Any]) -> None:
    """Each scene's detections equal onnxruntime's decode of the video's frames; every one
    is priced; the scene records the detector file."""
    sess = ort.InferenceSession(str(camp["dir"] / "spot.onnx"))
    for video in camp["videos"]:
        scene = json.loads((camp["out"] / "scenes" / f"{video.name}.json").read_text())
        assert scene["meta"]["detector_file"]["kind"] == "heatmap"
        frames = sorted(video.glob("*.png"))
        assert len(scene["frames"]) == len(frames)
        for fr, path in zip(scene["frames"], frames, strict=True):
            got = [(d["x"], d["y"]) for d in fr["detections"]]
            assert got == pytest.approx(_decode(path, sess))
            assert all(isinstance(d["payoff"], (int, float)) for d in fr["detections"])


def test_a_rerun_reuses_the_scenes_and_rows(camp: dict[str, Any]) -> None:
    scene = camp["out"] / "scenes" / "video0.json"
    before = (scene.stat().st_mtime_ns, (camp["out"] / "results.jsonl").read_text())
    r = _campaign(camp)
    assert r.returncode == camp["r"].returncode, r.stdout + r.stderr
    assert "perceiving" not in r.stderr
    assert (scene.stat().st_mtime_ns, (camp["out"] / "results.jsonl").read_text()) == before


def test_another_detector_file_is_refused(camp: dict[str, Any]) -> None:
    other = camp["dir"] / "other.toml"
    other.write_text(camp["toml"].read_text().replace("threshold = 0.0", "threshold = 0.1"))
    r = _campaign({**camp, "toml": other})
    assert r.returncode == 2, r.stdout + r.stderr
    assert "Traceback" not in r.stderr and "another detector file" in r.stderr


def test_window_networks_beside_a_detector_file_are_refused(camp: dict[str, Any]) -> None:
    out = camp["dir"] / "o2"
    r = _campaign({**camp, "out": out}, "--locator", str(camp["dir"] / "spot.onnx"))
    assert r.returncode == 2, r.stdout + r.stderr
    assert "Traceback" not in r.stderr and "--locator" in r.stderr
    assert not out.exists()


def test_certified_payoffs_certify_the_kept_scene(camp: dict[str, Any]) -> None:
    """--payoffs certified on the attack run's OUT: each kept scene (not perceived again:
    the same detections and payoffs) gets certified bounds on the detections its models
    can hide (round 22: on demand; tests/test_boxes_lazy.py compares them with the up-front
    ones), each bound at most its payoff."""
    scene0 = camp["out"] / "scenes" / "video0.json"
    pays = [d["payoff"] for f in json.loads(scene0.read_text())["frames"] for d in f["detections"]]
    before = len(_rows(camp))
    r = _campaign(camp, "--payoffs", "certified")
    assert "Traceback" not in r.stderr and r.returncode in (0, 1), r.stdout + r.stderr
    assert "perceiving" not in r.stderr
    rows = _rows(camp)[before:]
    assert len(rows) == before and all(x["payoffs"] == "certified" for x in rows)
    for video in camp["videos"]:
        scene = json.loads((camp["out"] / "scenes" / f"{video.name}.json").read_text())
        assert scene["meta"]["certified"]["detections"] > 0
        bounded = 0
        for fr in scene["frames"]:
            for d in fr["detections"]:
                low, pay = d.get("payoff_lower"), d["payoff"]
                bounded += low is not None
                assert (
                    low is None
                    or low == "unattackable"
                    or pay == "unattackable"
                    or (low <= pay + 1e-9)
                )
        assert bounded == scene["meta"]["certified"]["detections"]
    after = json.loads(scene0.read_text())
    assert [d["payoff"] for f in after["frames"] for d in f["detections"]] == pays
