"""Replay of multi-target (sort) counterexamples through the real detector and the production
tracker (issue 58; lesmc/replay/multi.py): ``lesmc verify --design sort`` replays its
counterexample on a small video and it is confirmed; a hand-corrupted one (the hidden
detection changed to one far from the target) replays diverged through ``lesmc replay``.
Both replayed runs are checked independently with Bewley's SORT (sort-tracker-py) on
the replayed detections: the target's reference is lost as the replay says."""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any

import numpy as np
import pytest
from cli_run import lesmc

from lesmc.schemas import validate
from lesmc.video.synth import SynthConfig
from lesmc.video.write import write_video

pytest.importorskip("sort_tracker")
import sort_reference

#: A target of the video (seed 5) that one hidden detection in frame 6 loses for good
#: (SORT's max_age 1): ``lost(0..end) > 1`` at a payoff under 3.
SPEC = """property lose {
    attack window 2..3 within 40
    minimize payoff
    subject to lost(0..end) > 1
    holds if optimum > 3.0
}
"""
TARGET = "222.1,222.9@4"


@pytest.fixture(scope="module")
def verified(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """``lesmc verify VIDEO --design sort`` on a 9-frame 448 x 448 video: its OUT."""
    base = tmp_path_factory.mktemp("multireplay")
    video = base / "video"
    write_video(SynthConfig(frames=9, width=448, height=448, seed=5, density=3.0), video)
    spec = base / "lose.spec"
    spec.write_text(SPEC)
    out = base / "out"
    r = lesmc("verify", str(video), "--truth", str(video / "truth.json"), "--out", str(out),
              "--design", "sort", "--spec", str(spec), "--target", TARGET)  # fmt: skip
    assert "Traceback" not in r.stderr, r.stderr
    assert r.returncode == 1, r.stderr  # violated, and the replay confirmed it
    assert "replay: confirmed" in r.stdout
    return out


def _iou(a: np.ndarray, b: np.ndarray) -> float:
    w = max(0.0, min(a[2], b[2]) - max(a[0], b[0]))
    h = max(0.0, min(a[3], b[3]) - max(a[1], b[1]))
    inter = w * h
    return inter / ((a[2] - a[0]) * (a[3] - a[1]) + (b[2] - b[0]) * (b[3] - b[1]) - inter)


def _replayed_boxes(out: Path, replay: dict[str, Any], end: int) -> list[np.ndarray]:
    """Each step's detection boxes as the replay's tracker read them: the scene's, and on
    an attacked frame the replayed detections with the frame's window size (every WAMI
    detection's box is its 21 x 21 N_dr window)."""
    scene = json.loads((out / "scene.json").read_text())
    again = {d["frame"]: np.array(d["positions"], dtype=float) for d in replay["detections"]}
    boxes = []
    for f in scene["frames"][: end + 1]:
        (w,) = {d["w"] for d in f["detections"]}
        xy = again.get(f["step"], np.array([[d["x"], d["y"]] for d in f["detections"]]))
        boxes.append(np.hstack([xy - w / 2, xy + w / 2]).reshape(-1, 4))
    return boxes


def _lost_by_reference_sort(steps: list[dict[str, Any]], boxes: list[np.ndarray]) -> int:
    """``lost(0..end)`` computed independently: the steps at which the target's reference
    exists and no box Bewley's SORT outputs overlaps it with IoU >= 0.5."""
    out = sort_reference.reference_sort(boxes)
    lost = 0
    for s, tracks in zip(steps, out, strict=True):
        ref = s["reference"]
        if ref is not None and not any(_iou(np.array(ref), b) >= 0.5 for b in tracks.values()):
            lost += 1
    return lost


def test_verify_sort_replays_its_counterexample_confirmed(verified: Path) -> None:
    doc = json.loads((verified / "results.json").read_text())
    validate(doc, "multi-check")
    (res,) = doc["results"]
    assert res["verdict"] == "violated" and res["optimum"] < 3.0
    rp = res["replay"]
    assert rp["status"] == "confirmed", rp["reason"]
    steps = res["counterexample"]
    assert rp["target_ids"] == [s["target_id"] for s in steps]
    (hidden,) = [h for s in steps for h in s["hidden"]]
    # the hidden detection is gone from its frame's replayed detections
    frame = int(hidden.split(":")[0])
    scene = json.loads((verified / "scene.json").read_text())
    det = next(d for f in scene["frames"] if f["step"] == frame for d in f["detections"]
               if d["id"] == hidden)  # fmt: skip
    (again,) = [np.array(d["positions"]) for d in rp["detections"] if d["frame"] == frame]
    assert np.linalg.norm(again - [det["x"], det["y"]], axis=1).min() > 1.0
    # the attack was recomputed at the payoff the results priced
    (p,) = rp["perturbations"]
    assert (
        p["obs"] == hidden and abs(p["payoff_recomputed"] - det["payoff"]) <= 1e-3 * det["payoff"]
    )
    lost = _lost_by_reference_sort(steps, _replayed_boxes(verified, rp, len(steps) - 1))
    assert lost == rp["constraint_value"] > 1
    assert "replay: confirmed" in (verified / "report.html").read_text()


def test_a_corrupted_counterexample_replays_diverged(verified: Path, tmp_path: Path) -> None:
    """The hidden detection replaced by the frame's detection farthest from it: the target
    keeps its track, so ``lesmc replay`` says diverged (exit 3: unknown)."""
    doc = json.loads((verified / "results.json").read_text())
    scene = json.loads((verified / "scene.json").read_text())
    steps = doc["results"][0]["counterexample"]
    k = next(i for i, s in enumerate(steps) if s["hidden"])
    dets = scene["frames"][k]["detections"]
    was = next(d for d in dets if d["id"] == steps[k]["hidden"][0])
    far = max(dets, key=lambda d: (d["x"] - was["x"]) ** 2 + (d["y"] - was["y"]) ** 2)
    steps[k]["hidden"] = [far["id"]]
    del doc["results"][0]["replay"]
    bad = tmp_path / "results.json"
    bad.write_text(json.dumps(doc))
    (tmp_path / "scene.json").write_text((verified / "scene.json").read_text())
    r = lesmc("replay", str(bad), "--json")
    assert "Traceback" not in r.stderr, r.stderr
    assert r.returncode == 3, r.stderr
    out = json.loads(r.stdout)
    validate(out, "replay")
    (row,) = out["replays"]
    rp = row["replay"]
    assert (row["verdict_model"], row["verdict"], rp["status"]) == (
        "violated",
        "unknown",
        "diverged",
    )
    assert rp["step"] == k and f"at step {k}" in rp["reason"]
    assert rp["target_ids"][k] is not None
    assert _lost_by_reference_sort(steps, _replayed_boxes(verified, rp, len(steps) - 1)) <= 1


def test_replay_of_multi_results_refuses_bad_input(verified: Path, tmp_path: Path) -> None:
    """An unknown property, and results whose scene is nowhere: exit 2 before the video is
    read, no traceback."""
    r = lesmc("replay", str(verified / "results.json"), "--property", "nope")
    assert r.returncode == 2 and "Traceback" not in r.stderr, r.stderr
    assert "no property named nope" in r.stderr
    doc = json.loads((verified / "results.json").read_text())
    doc["meta"]["scene"] = str(tmp_path / "gone.json")
    from lesmc.common.errors import UsageError
    from lesmc.experiment.multi_verify import replay_document

    with pytest.raises(UsageError) as err:
        # the scene is looked for before the frames, the networks and the bar
        replay_document(doc, str(tmp_path / "results.json"), None, (None, None, None), None, None)
    assert "scene" in err.value.message
