"""Round 22's hostile leftovers:

- a ``lesmc-multi-check`` document whose ``meta.scene`` names another scene, with the
  detections its counterexample hides moved, was not noticed before its replay (the ids
  matched): now, as lesmc/replay/scene_match.py does for the point designs' results, each
  step's ``attacked`` entry (id and box, as the check wrote it) is looked up in the scene
  and a missing or moved one is refused at that entry's ``FILE:LINE:COL``, before the
  frames are read;
- ``lesmc replay`` and ``lesmc perceive`` printed "replaying/perceiving: started" before
  their input errors, and ``perceive`` imported torch before reading the detector file.

Every case goes through the real entry point: exit 2, no traceback."""

from __future__ import annotations

import json
import os
import re
import subprocess
import sys
from pathlib import Path
from typing import Any

import pytest
from cli_run import ROOT, lesmc
from test_hostile_round21 import _joint_scene

#: A hijack: hiding the target's detection in two frames of the window makes SORT (max_age
#: 1) delete its track; the detection's next track is a new id.
SPEC = """property hijack {
    attack window 2..4
    minimize payoff
    subject to switches(0..end) > 0
    holds if optimum > 100
}
"""


def _refused_at(r: Any, path: str, line: int, *said: str) -> str:
    """Exit 2, no traceback, no "started" line, the first line of stderr at
    ``path:line:COL`` and saying ``said``; that line."""
    assert "Traceback" not in r.stderr and "internal error" not in r.stderr, r.stderr
    assert r.returncode == 2, (r.returncode, r.stdout, r.stderr)
    assert "started" not in r.stderr, r.stderr
    first = next(x for x in r.stderr.splitlines() if x.startswith(path))
    assert re.match(rf"{re.escape(path)}:{line}:\d+: ", first), (line, r.stderr)
    for s in said:
        assert s in first, (s, r.stderr)
    return first


def _boxed_scene() -> dict[str, Any]:
    """tests/test_hostile_round21.py's scene (a target 10 px a step, a far detection)
    with 40 x 40 boxes: consecutive boxes of the target overlap (IoU 0.6)."""
    doc = _joint_scene()
    for f in doc["frames"]:
        del f["candidates"]
        for d in f["detections"]:
            d["w"] = d["h"] = 40.0
    doc["version"] = 2
    return doc


@pytest.fixture(scope="module")
def hijacked(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """``lesmc check --design sort --report r`` of the hijack on the boxed scene: its
    directory (r/results.json, a lesmc-multi-check document with ``attacked`` boxes)."""
    base = tmp_path_factory.mktemp("hostile22b")
    (base / "s.json").write_text(json.dumps(_boxed_scene(), indent=1))
    (base / "h.spec").write_text(SPEC)
    r = lesmc("check", "s.json", "h.spec", "--design", "sort", "--report", "r", cwd=base)
    assert r.returncode == 1, r.stderr
    (base / "v").mkdir()  # frames never read: the refusal comes first
    return base


def test_multi_check_pointed_at_another_scene_is_refused(hijacked: Path) -> None:
    """``meta.scene`` names a scene whose detections are 3 px to the right (their ids
    unchanged): refused at the first ``attacked`` entry of the counterexample, naming the
    position the results record (the hidden detection's box centre) and the scene's."""
    doc = json.loads((hijacked / "r" / "results.json").read_text())
    assert doc["format"] == "lesmc-multi-check"
    steps = doc["results"][0]["counterexample"]
    k = next(i for i, s in enumerate(steps) if s["attacked"])
    (hit,) = [a for a in steps[k]["attacked"] if a["id"] == steps[k]["hidden"][0]]
    x1, y1, x2, y2 = hit["box"]
    other = _boxed_scene()
    for f in other["frames"]:
        for d in f["detections"]:
            d["x"] += 3.0
    (hijacked / "moved.json").write_text(json.dumps(other))
    doc["meta"] = {"scene": "moved.json", "properties": ["h.spec"]}
    text = json.dumps(doc, indent=1)
    (hijacked / "mc-moved.json").write_text(text)
    r = lesmc("replay", "mc-moved.json", "--frames", "v", cwd=hijacked)
    m = re.search(r'"attacked": \[\s*\{', text)  # the first step with an attacked entry
    assert m is not None
    line = text.count("\n", 0, m.end()) + 1
    cx, cy = (x1 + x2) / 2, (y1 + y2) / 2  # the scene's own place of the hidden detection
    said = f"is at ({cx:g}, {cy:g}) in the results, at ({cx + 3:g}, {cy:g}) in moved.json"
    _refused_at(r, "mc-moved.json", line, f"results[0].counterexample[{k}].attacked[0]", said)
    assert (hijacked / "mc-moved.json").read_text() == text


def test_the_same_scene_passes_the_check(hijacked: Path) -> None:
    """The document with ``meta.scene`` naming its own scene is not refused at the results:
    it goes on to the frames (an empty directory here: refused there, after the check,
    and with no "replaying: started" line before the refusal)."""
    doc = json.loads((hijacked / "r" / "results.json").read_text())
    doc["meta"] = {"scene": "s.json", "properties": ["h.spec"]}
    (hijacked / "mc-same.json").write_text(json.dumps(doc, indent=1))
    r = lesmc("replay", "mc-same.json", "--frames", "v", cwd=hijacked)
    assert "Traceback" not in r.stderr and r.returncode == 2, r.stderr
    assert "attacked" not in r.stderr and "meta.scene" not in r.stderr, r.stderr
    assert "v" in r.stderr and "started" not in r.stderr, r.stderr


#: A detector file with a stride of 0 (line 3) and no threshold.
BAD_DETECTOR = 'kind = "heatmap"\nnetwork = "nope.onnx"\nstride = 0\n'


def test_perceive_refuses_a_bad_detector_file_before_starting(tmp_path: Path) -> None:
    """``lesmc perceive FRAMES --detector bad.toml``: the file's fields are refused at their
    lines, before "perceiving: started" and before torch is imported (it was imported
    first, and the "started" line came first)."""
    from lesmc.video.synth import SynthConfig
    from lesmc.video.write import write_video

    write_video(SynthConfig(frames=2, width=64, height=64, seed=1, density=1.0), tmp_path / "v")
    (tmp_path / "bad.toml").write_text(BAD_DETECTOR)
    r = subprocess.run(
        [sys.executable, "-X", "importtime", "-m", "lesmc", "perceive", "v", "--detector",
         "bad.toml"],
        capture_output=True, text=True, cwd=tmp_path, timeout=600,
        env={**os.environ, "PYTHONPATH": str(ROOT)},
    )  # fmt: skip
    assert not re.search(r"\|\s+torch$", r.stderr, re.M), "torch was imported"
    said = [x for x in r.stderr.splitlines() if not x.startswith("import time:")]
    r = subprocess.CompletedProcess(r.args, r.returncode, r.stdout, "\n".join(said))
    _refused_at(r, "bad.toml", 3, "stride: must be an integer")
    assert "bad.toml: threshold: is missing" in r.stderr, r.stderr


def test_replay_refuses_a_bad_detector_file_before_starting(hijacked: Path) -> None:
    """``lesmc replay RESULTS --frames DIR --detector bad.toml`` of a point design's
    results: refused at the file's line with no "replaying: started" line before."""
    base = hijacked
    (base / "bad.toml").write_text(BAD_DETECTOR)
    (base / "p.spec").write_text(SPEC.replace("switches(0..end) > 0", "dist.sum(0..end) > 20"))
    r = lesmc("check", "s.json", "p.spec", "--design", "single", "--report", "pr", cwd=base)
    assert r.returncode in (0, 1), r.stderr
    r = lesmc("replay", "pr/results.json", "--frames", "v", "--detector", "bad.toml", cwd=base)
    _refused_at(r, "bad.toml", 3, "stride: must be an integer")
