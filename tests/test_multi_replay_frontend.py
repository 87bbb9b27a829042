"""The front end's settings of a multi-target verify reach its replay (issue 58, left
open in round 21): ``lesmc perceive --delta-bc 16`` records them in the scene's
``meta.frontend``, ``lesmc verify --scene --frames --design sort`` records them in the
``lesmc-multi-check`` document's ``perception``, and the replay detects the frames with
them: its counterexamples are confirmed. The same document without ``perception`` (as
documents were before) replays with the defaults (delta_bc 12), whose detections are
not the scene's: a located input error that names the settings, exit 2."""

from __future__ import annotations

import json
from pathlib import Path

import pytest
from cli_run import lesmc
from multi_video import SPEC, write_small_video

from lesmc.perception.blobs import BlobConfig
from lesmc.schemas import validate

#: Not the default (12): blobs need a larger difference from the background.
DELTA_BC = 16
TARGET = "119.0,71.5@4"  # as tests/test_multi_replay.py's


@pytest.fixture(scope="module")
def verified(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """The small video perceived with ``--delta-bc 16`` and verified from its scene: OUT."""
    base = tmp_path_factory.mktemp("frontend")
    video, scene = base / "video", base / "scene.json"
    write_small_video(video)
    r = lesmc("perceive", str(video), "-o", str(scene), "--delta-bc", str(DELTA_BC))
    assert r.returncode == 0 and "Traceback" not in r.stderr, r.stderr
    spec, out = base / "identity.spec", base / "out"
    spec.write_text(SPEC)
    r = lesmc("verify", "--scene", str(scene), "--frames", str(video), "--design", "sort",
              "--spec", str(spec), "--target", TARGET, "--out", str(out))  # fmt: skip
    assert "Traceback" not in r.stderr, r.stderr
    assert r.returncode == 1, r.stderr
    return out


def test_the_recorded_front_end_settings_replay_confirmed(verified: Path) -> None:
    assert BlobConfig().delta_bc != DELTA_BC
    scene = json.loads((verified.parent / "scene.json").read_text())
    assert scene["meta"]["frontend"] == {"history": 4, "delta_bc": DELTA_BC}
    doc = json.loads((verified / "results.json").read_text())
    validate(doc, "multi-check")
    assert doc["perception"]["delta_bc"] == DELTA_BC and doc["perception"]["history"] == 4
    assert doc["perception"]["frames"] == str((verified.parent / "video").resolve())
    for res in doc["results"]:
        rp = res["replay"]
        assert rp["status"] == "confirmed", rp["reason"]
        assert rp["frontend"] == {
            "history": 4,
            "delta_bc": DELTA_BC,
            "recorded": ["history", "delta_bc"],
            "from": "results",
        }
    # lesmc replay finds the frames from the perception (verify --scene records no video)
    r = lesmc("replay", str(verified / "results.json"), "--json")
    assert r.returncode == 1 and "Traceback" not in r.stderr, r.stderr
    rows = json.loads(r.stdout)["replays"]
    assert [row["replay"]["status"] for row in rows] == ["confirmed"] * len(doc["results"])


def test_without_the_settings_the_defaults_do_not_reproduce_the_scene(
    verified: Path, tmp_path: Path
) -> None:
    doc = json.loads((verified / "results.json").read_text())
    frames = doc["perception"]["frames"]
    del doc["perception"]
    for res in doc["results"]:
        del res["replay"]
    old = tmp_path / "results.json"
    old.write_text(json.dumps(doc))
    r = lesmc("replay", str(old), "--frames", frames)
    assert r.returncode == 2 and "Traceback" not in r.stderr, r.stderr
    assert "the detector does not reproduce detection" in r.stderr
    assert "delta_bc 12 (the defaults: the results record no perception settings)" in r.stderr
