"""Ground-truth tracks and ``dist.nearest`` (issue 30, section 4.2: recovery to an
acceptable path that need not be the original one): scene and model files, the
step mapping, and the measure through the real CLI."""

from __future__ import annotations

import json
import math
from pathlib import Path
from typing import Any

import numpy as np
import pytest
from cli_run import lesmc

from lesmc.api import build
from lesmc.model.lts_format import load_lts
from lesmc.scene import load_scene, scene_from_dict, scene_to_dict
from lesmc.scene.toy import Vehicle, vehicle_scene

SCENES = Path(__file__).parent / "scenes"

NEAR_SPEC = """
property res_original {
    attack window 6..8
    minimize dist.max(6..8)
    subject to dist.at(end) > 1
    holds if optimum > 30
    on x, y
}
property res_any {
    attack window 6..8
    minimize dist.max(6..8)
    subject to dist.nearest(end) > 1
    holds if optimum > 30
    on x, y
}
"""


def _with_truth(scene_path: Path) -> dict[str, Any]:
    """The scene with each vehicle's detections as its ground-truth track (the toy scenes
    detect every vehicle at its exact position; ids are FRAME:VEHICLE)."""
    doc = json.loads(scene_path.read_text())
    tracks: dict[str, list[list[float]]] = {}
    for fr in doc["frames"]:
        for d in fr["detections"]:
            tracks.setdefault(d["id"].split(":")[-1], []).append([fr["step"], d["x"], d["y"]])
    doc["truth"] = [{"id": k, "positions": v} for k, v in tracks.items()]
    return doc


def test_truth_positions_become_model_tracks_by_step() -> None:
    """Model step k is frame target.step + k; a vehicle not seen in a frame is absent there."""
    a = Vehicle("a", 100.0, 100.0, 5.0, 0.0, 1.0)
    b = Vehicle("b", 100.0, 160.0, 5.0, 0.0, 1.0, first=4, last=9)
    sc = vehicle_scene([a, b], 12, a)
    doc = scene_to_dict(sc)
    doc["target"]["step"] = 3
    doc["target"]["start"] = list(a.at(3))
    doc["truth"] = [
        {"id": v.id, "positions": [[k, *v.at(k)] for k in range(12) if v.first <= k <= v.last]}
        for v in (a, b)
    ]
    scene = scene_from_dict(doc)
    model = build(scene, (2, 3))
    assert model.tracks is not None and model.tracks.ids == ("a", "b")
    assert model.tracks.components == ("x", "y")
    for r, v in enumerate((a, b)):
        for k in range(model.end + 1):
            frame = 3 + k
            got = model.tracks.at[r, k]
            if v.first <= frame <= v.last:
                assert tuple(got) == v.at(frame), (v.id, k)
            else:
                assert np.isnan(got).all(), (v.id, k)


def test_tracks_survive_the_scene_file_and_both_model_forms(tmp_path: Path) -> None:
    doc = _with_truth(SCENES / "rq1_platoon.json")
    sc = scene_from_dict(doc)
    assert scene_to_dict(sc)["truth"] == doc["truth"]
    (tmp_path / "s.json").write_text(json.dumps(doc))
    for suffix in (".lts", ".npz"):
        out = tmp_path / f"m{suffix}"
        res = lesmc("build", str(tmp_path / "s.json"), "--window", "6..8", "-o", str(out))
        assert res.returncode == 0, res.stderr
        m = load_lts(out)
        want = build(load_scene(tmp_path / "s.json"), (6, 8))
        assert m.tracks is not None and want.tracks is not None
        assert m.tracks.ids == want.tracks.ids
        np.testing.assert_array_equal(m.tracks.at, want.tracks.at)


def test_nearest_accepts_recovery_onto_another_vehicle(tmp_path: Path) -> None:
    """On the platoon scene the attacked track that does not return to the target ends on a
    neighbour's path: failing to recover by dist.at, recovered by dist.nearest; every
    engine agrees, and the .lts built from the scene gives the same optima."""
    (tmp_path / "s.json").write_text(json.dumps(_with_truth(SCENES / "rq1_platoon.json")))
    spec = tmp_path / "near.spec"
    spec.write_text(NEAR_SPEC)
    seen = set()
    for engine in ("levels", "bnb", "enumerate"):
        res = lesmc("check", str(tmp_path / "s.json"), str(spec), "--json", "--engine", engine)
        assert res.returncode == 1, res.stderr
        got = {r["property"]: r for r in json.loads(res.stdout)["results"]}
        assert got["res_original"]["verdict"] == "violated"
        assert got["res_any"]["verdict"] == "holds"
        seen.add((got["res_original"]["optimum"], got["res_any"]["optimum"]))
    assert len(seen) == 1


def test_nearest_errors_are_located(tmp_path: Path) -> None:
    spec = tmp_path / "near.spec"
    spec.write_text(NEAR_SPEC)
    res = lesmc("check", str(SCENES / "rq1_platoon.json"), str(spec))
    assert res.returncode == 2
    assert f"{spec}:12:16: dist.nearest needs ground-truth tracks" in res.stderr
    (tmp_path / "s.json").write_text(json.dumps(_with_truth(SCENES / "rq1_platoon.json")))
    spec.write_text(NEAR_SPEC.replace("on x, y\n}\n", "}\n"))
    res = lesmc("check", str(tmp_path / "s.json"), str(spec))
    assert res.returncode == 2 and "write 'on x, y'" in res.stderr, res.stderr
    assert "Traceback" not in res.stderr


@pytest.mark.parametrize(
    ("change", "message"),
    [
        (lambda t: t[0]["positions"].insert(0, [999, 1.0, 2.0]), "positions[0] must be [frame"),
        (lambda t: t[0]["positions"].append(t[0]["positions"][0]), "after the previous one"),
        (lambda t: t.append({"id": t[0]["id"], "positions": [[0, 1, 2]]}), "used once"),
        (lambda t: t[0].update(speed=3), "must be an object with id and positions"),
        (lambda t: t[0]["positions"][1].__setitem__(1, 1e9), "positions[1]"),
        (lambda t: t[0]["positions"][1].__setitem__(1, math.inf), "Infinity is not allowed"),
    ],
)
def test_bad_truth_in_a_scene_is_refused(tmp_path: Path, change: Any, message: str) -> None:
    doc = _with_truth(SCENES / "rq1_platoon.json")
    change(doc["truth"])
    path = tmp_path / "s.json"
    path.write_text(json.dumps(doc, allow_nan=True))
    res = lesmc("build", str(path), "--window", "6..8", "-o", str(tmp_path / "m.lts"))
    assert res.returncode == 2, res.stderr
    assert str(path) in res.stderr and message in res.stderr, res.stderr
    assert not (tmp_path / "m.lts").exists()


@pytest.mark.parametrize(
    ("change", "message"),
    [
        (lambda t: t.update(components=["x", "vz"]), "tracks.components"),
        (lambda t: t["paths"][0]["at"].pop(), "one position per step 0..19"),
        (lambda t: t["paths"][0]["at"].__setitem__(3, [1.0]), "tracks.paths[0].at[3]"),
        (lambda t: t["paths"][0].update(at=[None] * 20), "is absent at every step"),
        (lambda t: t["paths"][1].update(id=t["paths"][0]["id"]), "tracks.ids"),
    ],
)
def test_bad_tracks_in_a_model_file_are_refused(tmp_path: Path, change: Any, message: str) -> None:
    (tmp_path / "s.json").write_text(json.dumps(_with_truth(SCENES / "rq1_platoon.json")))
    model = tmp_path / "m.lts"
    assert (
        lesmc("build", str(tmp_path / "s.json"), "--window", "6..8", "-o", str(model)).returncode
        == 0
    )
    doc = json.loads(model.read_text())
    change(doc["tracks"])
    model.write_text(json.dumps(doc))
    res = lesmc("check", str(model), "specs/resilience.spec")
    assert res.returncode == 2, res.stderr
    assert str(model) in res.stderr and message in res.stderr, res.stderr
    assert "Traceback" not in res.stderr
