"""Detection boxes in scene files (format version 2) and from ``lesmc import mot``."""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any

import numpy as np
import pytest
from cli_run import lesmc

from lesmc.common.errors import InputError
from lesmc.scene import scene_from_dict, scene_to_dict

MOT = "1,-1,10,20,30,40,1\n1,-1,100,50,8,6,1\n2,-1,12.5,21,30,41,1\n"


def _doc(version: int, det: dict[str, Any]) -> dict[str, Any]:
    base = {"id": "0:0", "x": 5.0, "y": 6.0, "payoff": 1.0}
    return {
        "format": "lesmc-scene",
        "version": version,
        "frames": [{"step": 0, "detections": [{**base, **det}]}],
        "target": {"step": 0, "start": [5.0, 6.0]},
    }


def test_a_box_round_trips_and_gives_corners() -> None:
    sc = scene_from_dict(_doc(2, {"w": 4.0, "h": 2.0}))
    fr = sc.frames[0]
    assert fr.has_boxes
    assert fr.boxes().tolist() == [[3.0, 5.0, 7.0, 7.0]]
    out = scene_to_dict(sc)
    assert out["version"] == 2
    assert out["frames"][0]["detections"][0]["w"] == 4.0
    assert scene_from_dict(out) == sc


def test_a_point_scene_is_written_as_version_1_and_has_no_boxes() -> None:
    sc = scene_from_dict(_doc(1, {}))
    assert not sc.frames[0].has_boxes
    with pytest.raises(ValueError):
        sc.frames[0].boxes()
    assert scene_to_dict(sc)["version"] == 1
    assert scene_from_dict(_doc(2, {})) == sc


@pytest.mark.parametrize(
    ("version", "det", "want"),
    [
        (1, {"w": 4.0, "h": 2.0}, "w (a box) needs scene format version 2, the file says 1"),
        (2, {"w": 4.0}, "w needs h too"),
        (2, {"h": 4.0}, "h needs w too"),
        (2, {"w": 0, "h": 2.0}, "w must be a number in (0, 1e+07], got 0"),
        (2, {"w": 4.0, "h": "x"}, "h must be a number in (0, 1e+07]"),
        (4, {}, "version: must be 1, 2 or 3, got 4"),
    ],
)
def test_a_bad_box_is_located(version: int, det: dict[str, Any], want: str) -> None:
    with pytest.raises(InputError) as info:
        scene_from_dict(_doc(version, det), "s.json")
    assert want in str(info.value)
    if "version:" not in want:
        assert "s.json: frame 0, detection '0:0': " in str(info.value)


def test_import_mot_keeps_the_box_at_the_centre_only(tmp_path: Path) -> None:
    det = tmp_path / "det.txt"
    det.write_text(MOT)
    for point in ("center", "bottom"):
        out = tmp_path / f"{point}.json"
        r = lesmc("import", "mot", str(det), "-o", str(out), "--point", point)
        assert r.returncode == 0, r.stderr
        doc = json.loads(out.read_text())
        dets = [d for f in doc["frames"] for d in f["detections"]]
        if point == "bottom":
            assert doc["version"] == 1 and all("w" not in d for d in dets)
            continue
        assert doc["version"] == 2
        rows = [[float(v) for v in line.split(",")] for line in MOT.split("\n") if line]
        for d, row in zip(dets, rows, strict=True):
            left, top, w, h = row[2:6]
            assert (d["w"], d["h"]) == (w, h)
            assert np.allclose([d["x"] - w / 2, d["y"] - h / 2], [left, top], atol=1e-12)


def test_point_trackers_ignore_boxes(tmp_path: Path) -> None:
    det = tmp_path / "det.txt"
    det.write_text(MOT)
    boxed = tmp_path / "boxed.json"
    assert lesmc("import", "mot", str(det), "-o", str(boxed)).returncode == 0
    doc = json.loads(boxed.read_text())
    for f in doc["frames"]:
        for d in f["detections"]:
            del d["w"], d["h"]
    doc["version"] = 1
    plain = tmp_path / "plain.json"
    plain.write_text(json.dumps(doc))
    runs = [
        lesmc("track", str(p), "--target", "25,40@1", "--json", "--design", design)
        for design in ("single", "joint")
        for p in (boxed, plain)
    ]
    for r in runs:
        assert r.returncode == 0 and "Traceback" not in r.stderr, r.stderr
    assert runs[0].stdout == runs[1].stdout
    assert runs[2].stdout == runs[3].stdout
