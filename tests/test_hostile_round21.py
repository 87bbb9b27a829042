"""The hostile-input run repeated on round 21's inputs: ``lesmc replay RESULTS --frames
VIDEO`` on a ``lesmc-multi-check`` document edited by hand. Each case was mishandled
before its fix: an internal error (exit 4: a ``meta.window`` or ``meta.properties`` of
the wrong type, a document whose ``design`` is not the one its tracks were made with), a
replay that ran on a counterexample whose steps were cut or renumbered or moved to other
frames (a silent ``diverged``, exit 1), or an error naming the whole counterexample
("matches none of the allowed forms") rather than the field. Every case goes through the
real entry point and must exit 2, at the offending field's ``FILE:LINE:COL``, with no
traceback, and leave the results file as it was.

And OUT/cache: a replay entry corrupted or edited by hand (a replay object the results
schema refuses, a multi-target entry for a result that is not there) was copied into
results.json or crashed ``lesmc verify`` (IndexError, exit 4); it is replayed again."""

from __future__ import annotations

import copy
import json
import re
from collections.abc import Callable
from pathlib import Path
from typing import Any

import pytest
from cli_run import lesmc

from lesmc.video.synth import SynthConfig
from lesmc.video.write import write_video

#: A hijack of the target of the seed-5 video (as tests/test_multi_replay.py finds it).
SPEC = """property hijack {
    attack window 2..4 within 30
    minimize payoff
    subject to switches(0..end) > 0
    holds if optimum > 3.0
}
"""
TARGET = "119.0,71.5@4"


@pytest.fixture(scope="module")
def verified(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """``lesmc verify VIDEO --design sort`` on a 12-frame 448 x 448 video: the base dir
    (``video/``, ``out/results.json``, ``out/scene.json``)."""
    base = tmp_path_factory.mktemp("hostile21")
    write_video(SynthConfig(frames=12, width=448, height=448, seed=5, density=3.0), base / "video")
    (base / "hijack.spec").write_text(SPEC)
    r = lesmc("verify", "video", "--truth", "video/truth.json", "--out", "out", "--design",
              "sort", "--spec", "hijack.spec", "--target", TARGET, cwd=base)  # fmt: skip
    assert "Traceback" not in r.stderr, r.stderr
    assert r.returncode == 1, r.stderr  # violated, and the counterexample has hidden steps
    return base


def _steps(d: dict[str, Any]) -> list[dict[str, Any]]:
    return d["results"][0]["counterexample"]  # type: ignore[no-any-return]


def _line_of(text: str, pattern: str, nth: int = 0) -> int:
    """The 1-based line of the ``nth`` match of ``pattern`` in ``text`` (found here, by a
    regex over the written file, independently of lesmc's JSON locator)."""
    m = list(re.finditer(pattern, text))[nth]
    return text.count("\n", 0, m.start()) + 1


#: (label, edit of the document, the field named, pattern of its line, its match index)
EDITS: list[tuple[str, Callable[[dict[str, Any]], None], str, str, int]] = [
    ("a step cut", lambda d: _steps(d).pop(4), "counterexample[4].step", r'"step": 5', 0),
    (
        "a frame moved",
        lambda d: _steps(d)[2].update(frame=5),
        "counterexample[2].frame",
        r'"frame": 5',
        1,
    ),
    (
        "a step's frame missing",
        lambda d: _steps(d)[2].pop("frame"),
        "counterexample[2]: missing 'frame'",
        r'\{\s*\n\s*"step": 2',
        0,
    ),
    (
        "meta.window from step 0",
        lambda d: d["meta"].update(window=[0, 3]),
        "meta.window[0]",
        r'(?<="window": \[\n)\s+0,',
        0,
    ),
    (
        "the design another than the tracks'",
        lambda d: d.update(design="gnn"),
        "counterexample[0].tracks[0].box",
        r'"box": \[',
        0,
    ),
]


@pytest.mark.parametrize(
    ("label", "edit", "field", "pattern", "nth"), EDITS, ids=[e[0] for e in EDITS]
)
def test_edited_multi_check_refused_at_its_field(
    verified: Path,
    label: str,
    edit: Callable[[dict[str, Any]], None],
    field: str,
    pattern: str,
    nth: int,
) -> None:
    doc = json.loads((verified / "out" / "results.json").read_text())
    bad = copy.deepcopy(doc)
    edit(bad)
    path = verified / "edited.json"
    text = json.dumps(bad, indent=1)
    path.write_text(text)
    r = lesmc("replay", "edited.json", "--frames", "video", cwd=verified)
    assert "Traceback" not in r.stderr and "internal error" not in r.stderr, r.stderr
    assert r.returncode == 2, (label, r.returncode, r.stdout, r.stderr)
    line = _line_of(text, pattern, nth)
    assert re.search(rf"edited\.json:{line}:\d+: .*{re.escape(field)}", r.stderr), (
        line,
        r.stderr,
    )
    assert path.read_text() == text  # nothing written over the refused file


def _entry(cache: Path, stage: str) -> Path:
    """The one OUT/cache entry of ``stage``."""
    (path,) = cache.glob(f"{stage}-*.json")
    return path


def _corrupt(entry: Path, value: Any) -> None:
    whole = json.loads(entry.read_text())
    whole["value"] = value
    entry.write_text(json.dumps(whole))


def test_a_corrupted_multi_replay_cache_entry_is_replayed_again(verified: Path) -> None:
    """A multi-target replay entry naming a result the document lacks (index 7 of 1)."""
    out = verified / "out"  # the fixture's run kept its replay
    args = ("verify", "video", "--truth", "video/truth.json", "--design", "sort", "--spec",
            "hijack.spec", "--target", TARGET, "--out", "out")  # fmt: skip
    entry = _entry(out / "cache", "multi-replay")
    kept = json.loads(entry.read_text())["value"]
    assert list(kept) == ["0"]
    _corrupt(entry, {"7": kept["0"]})
    r = lesmc(*args, cwd=verified)
    assert "Traceback" not in r.stderr and "internal error" not in r.stderr, r.stderr
    assert r.returncode == 1, r.stderr
    assert "reusing the replay" not in r.stderr, r.stderr
    (res,) = json.loads((out / "results.json").read_text())["results"]
    assert res["replay"]["status"] == "confirmed"
    assert json.loads(entry.read_text())["value"] == kept  # the entry made again


@pytest.fixture(scope="module")
def spot(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """tests/test_campaign_detector.py's tiny video (video0/) and heatmap network
    (spot.toml, spot.onnx), and that file with a declared box (boxed.toml)."""
    pytest.importorskip("onnx")
    pytest.importorskip("onnxruntime")
    pytest.importorskip("onnxscript")
    from spot_detector import write_spot_detector
    from test_campaign_detector import _frames

    d = tmp_path_factory.mktemp("spot")
    _frames(d, 0)
    write_spot_detector(d)
    (d / "boxed.toml").write_text((d / "spot.toml").read_text() + "box = [4, 4]\n")
    return d


def test_corrupted_cache_entries_of_verify_detector_are_made_again(spot: Path) -> None:
    """A point design's replay entry (verify --detector FILE.toml) whose replay object has
    a status the results schema does not know; then its perception entry cut short."""
    from spot_detector import SPEC as DET_SPEC

    (spot / "p.spec").write_text(DET_SPEC)
    args = ("verify", "video0", "--detector", "spot.toml", "--target", "10,30@0", "--spec",
            "p.spec", "--design", "single", "--out", "out")  # fmt: skip
    assert lesmc(*args, cwd=spot).returncode == 1  # violated: its replay is kept
    entry = _entry(spot / "out" / "cache", "replay")
    kept = json.loads(entry.read_text())["value"]
    (row,) = kept["replays"]
    assert row[2]["status"] == "confirmed"
    _corrupt(entry, {"replays": [[row[0], row[1], {"status": "zzz"}]], "seconds": 1.0})
    r = lesmc(*args, cwd=spot)
    assert "Traceback" not in r.stderr and "internal error" not in r.stderr, r.stderr
    assert r.returncode == 1, r.stderr
    assert "reusing the replay" not in r.stderr, r.stderr
    doc = json.loads((spot / "out" / "results.json").read_text())
    (res,) = [x for run in doc["runs"] for x in run["results"]]
    assert res["replay"]["status"] == "confirmed"
    # the perception entry cut to 2 of the video's 12 frames: trusted, the spec was blamed
    # ("attack window 6..8 must satisfy 1 <= l <= u <= end = 1"); perceived again now
    entry = _entry(spot / "out" / "cache", "perception")
    whole = json.loads(entry.read_text())
    footage = whole["value"]["footage"]
    assert len(footage["frames"]) == 12
    footage["frames"] = footage["frames"][:2]
    entry.write_text(json.dumps(whole))
    r = lesmc(*args, cwd=spot)
    assert "Traceback" not in r.stderr and "internal error" not in r.stderr, r.stderr
    assert r.returncode == 1, r.stderr
    assert "its cached perception is not of every frame" in r.stderr, r.stderr
    scene = json.loads((spot / "out" / "scene.json").read_text())
    assert len(scene["frames"]) == 12


def test_verify_through_a_heatmap_file_with_a_box_checks_sort(spot: Path) -> None:
    """``verify FRAMES --detector FILE.toml --design sort``: a heatmap file's payoffs were
    left to be priced on demand, which only the point designs do, and the check refused
    its own scene (exit 2, "has no payoff (unpriced) ... price the scene"); every
    detection is priced up front now, as the multi-target check reads the payoffs."""
    (spot / "identity.spec").write_text(SPEC)
    r = lesmc("verify", "video0", "--detector", "boxed.toml", "--target", "14,30@0", "--spec",
              "identity.spec", "--design", "sort", "--out", "sort", cwd=spot)  # fmt: skip
    assert "Traceback" not in r.stderr and "internal error" not in r.stderr, r.stderr
    assert r.returncode in (0, 1), r.stderr
    scene = json.loads((spot / "sort" / "scene.json").read_text())
    dets = [d for f in scene["frames"] for d in f["detections"]]
    assert dets and all(isinstance(d["payoff"], float) and d["payoff"] > 0 for d in dets), dets
    assert all((d["w"], d["h"]) == (4.0, 4.0) for d in dets)
    doc = json.loads((spot / "sort" / "results.json").read_text())
    assert {x["property"] for x in doc["results"]} == {"hijack"}


def _joint_scene() -> dict[str, Any]:
    """A target moving 10 px a step past a cheap injection candidate 30 px off its track
    (each frame), and a far detection: joint's cheapest attack injects the candidate."""
    frames = []
    for k in range(8):
        x = 100.0 + 10 * k
        dets = [{"id": f"{k}:0", "x": x, "y": 50.0, "payoff": 5.0},
                {"id": f"{k}:1", "x": x + 200, "y": 50.0, "payoff": 5.0}]  # fmt: skip
        cands = [{"id": f"{k}:c0", "x": x, "y": 80.0, "payoff": 0.1}]
        frames.append({"step": k, "detections": dets, "candidates": cands})
    return {"format": "lesmc-scene", "version": 3, "dt": 1.0, "frames": frames,
            "target": {"step": 0, "start": [100.0, 50.0], "velocity": [10.0, 0.0]}}  # fmt: skip


INJECT_SPEC = """property inj {
    attack window 2..4 allow hide, inject
    minimize payoff
    subject to dist.sum(0..end) > 20
    holds if optimum > 100
    on x, y
}
"""


def test_joint_injection_results_whose_target_is_off_the_scene(tmp_path: Path) -> None:
    """A joint injection counterexample's ``replay_inputs.target`` moved past the scene's
    frames: the replay walked the path on the scene and crashed (IndexError, exit 4)."""
    (tmp_path / "scene.json").write_text(json.dumps(_joint_scene()))
    (tmp_path / "inj.spec").write_text(INJECT_SPEC)
    r = lesmc("check", "scene.json", "inj.spec", "--design", "joint", "--report", "r",
              cwd=tmp_path)  # fmt: skip
    assert r.returncode == 1, r.stderr
    doc = json.loads((tmp_path / "r" / "results.json").read_text())
    (res,) = doc["runs"][0]["results"]
    assert any(":c" in (s["obs"] or "") for s in res["counterexample"]["steps"])  # injects
    doc["runs"][0]["replay_inputs"]["target"]["step"] = 500
    (tmp_path / "edited.json").write_text(json.dumps(doc))
    write_video(SynthConfig(frames=6, width=64, height=64, seed=1, density=1.0), tmp_path / "v")
    r = lesmc("replay", "edited.json", "--frames", "v", cwd=tmp_path)
    assert "Traceback" not in r.stderr and "internal error" not in r.stderr, r.stderr
    assert r.returncode == 2, r.stderr
    assert "runs[0].replay_inputs.target" in r.stderr and "0..7" in r.stderr, r.stderr
