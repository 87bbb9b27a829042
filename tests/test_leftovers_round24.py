"""Round 24's leftovers (docs/cli.md "replay", docs/semantics.md): bugs found by other
helpers, each checked through the CLI entry point.

1. An ``allow hide, inject`` counterexample on ``single`` whose path skips at a step
   only an attack forces (every gated detection hidden) replays through a heatmap
   detector file: the skip's hiding is part of the replayed attack, whose recomputed
   cost is the optimum (it was left out, and the replay refused the results).
2. ``lesmc check SCENE SPEC --design sort --tracker FILE --report DIR`` records the tracker
   it ran (``meta.tracker``), and ``lesmc replay DIR/results.json`` tracks with it, not
   with the scene file's block (with which the replay diverged).
3. ``lesmc check SCENE SPEC --design sort`` on a scene whose unattacked run already loses
   and then switches the target (a ground-truth reference, the target's detections
   missing at two frames): each violated result at optimum 0 says so in a note, in the
   JSON and in the text output; a violation that needs an attack has no such note.
4. ``inject grid D within R payoff P`` refuses P above a scene's largest payoff (1e12,
   lesmc/common/numbers.py), at P's FILE:LINE:COL: two such injections summed to inf.
"""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any

import pytest
from cli_run import ROOT, lesmc

from lesmc.schemas import validate

SPEC_INJ = """property grab {
    attack window 3..5 allow hide, inject
    minimize payoff
    subject to dist.max(0..end) > 5
    holds if optimum > 10
    on x, y
}
"""


def test_forced_skip_replays_through_a_heatmap_file(tmp_path: Path) -> None:
    pytest.importorskip("onnx")
    pytest.importorskip("onnxscript")
    pytest.importorskip("cv2")
    from spot_detector import write_spot_detector, write_spot_frames

    frames, toml = write_spot_frames(tmp_path, 12), write_spot_detector(tmp_path)
    scene = tmp_path / "scene.json"
    r = lesmc("perceive", str(frames), "--detector", str(toml), "-o", str(scene),
              "--target", "10,30@0", "--inject-within", "25")  # fmt: skip
    assert r.returncode == 0, r.stderr
    spec = tmp_path / "p.spec"
    spec.write_text(SPEC_INJ)
    rep = tmp_path / "rep"
    r = lesmc("check", str(scene), str(spec), "--design", "single", "--json",
              "--report", str(rep))  # fmt: skip
    assert r.returncode == 1 and "Traceback" not in r.stderr, r.stderr
    res = json.loads(r.stdout)["results"][0]
    steps = res["counterexample"]["steps"]
    skips = [s["step"] for s in steps if s["attacked"] and s["obs"] is None and s["rank"]]
    assert skips, "the scenario no longer has a forced skip"
    r = lesmc("replay", str(rep / "results.json"), "--frames", str(frames),
              "--detector", str(toml), "--json")  # fmt: skip
    assert "Traceback" not in r.stderr
    assert r.returncode == 1, r.stderr  # a violation confirmed (was: exit 2, "differ")
    (row,) = json.loads(r.stdout)["replays"]
    assert row["replay"]["status"] == "confirmed", row["replay"]["reason"]
    perts = row["replay"]["perturbations"]
    assert {p["step"] for p in perts} >= set(skips)  # the skip's hiding is replayed
    doc: dict[str, Any] = json.loads(scene.read_text())
    pay = {d["id"]: d["payoff"] for f in doc["frames"] for d in f["detections"]}
    pay |= {c["id"]: c["payoff"] for f in doc["frames"] for c in f.get("candidates", [])}
    # the scene's own prices of what the replay attacked add up to the optimum
    assert sum(pay[p["obs"]] for p in perts) == pytest.approx(res["optimum"], rel=1e-3)


def test_multi_replay_tracks_with_the_checked_tracker_file(tmp_path: Path) -> None:
    """SORT with min_hits 1, max_age 0 (``--tracker``) on the small video: the check's
    counterexamples replay confirmed, their target ids those of the check's (the scene's
    tracker block, a single design's defaults with SORT's min_hits 3, max_age 1, loses the
    target where the file's tracker gives it a new track)."""
    import tomllib

    from multi_video import SPEC, write_small_video

    write_small_video(tmp_path / "video")
    (tmp_path / "identity.spec").write_text(SPEC)
    scene = tmp_path / "scene.json"
    video = tmp_path / "video"
    r = lesmc("perceive", str(video), "-o", str(scene), "--truth", str(video / "truth.json"),
              "--target", "119.0,71.5@4")  # fmt: skip
    assert r.returncode == 0, r.stderr
    tracker = tmp_path / "t.toml"
    tracker.write_text('design = "sort"\nmin_hits = 1\nmax_age = 0\niou_threshold = 0.2\n')
    rep = tmp_path / "rep"
    r = lesmc("check", str(scene), str(tmp_path / "identity.spec"), "--design", "sort",
              "--tracker", str(tracker), "--report", str(rep), "--json")  # fmt: skip
    assert r.returncode == 1 and "Traceback" not in r.stderr, r.stderr
    doc = json.loads((rep / "results.json").read_text())
    validate(doc, "multi-check")
    ran = doc["meta"]["tracker"]
    given = tomllib.loads(tracker.read_text())
    assert {k: ran[k] for k in given} == given  # the file's, not the scene's single block
    r = lesmc("replay", str(rep / "results.json"), "--frames", str(tmp_path / "video"), "--json")
    assert "Traceback" not in r.stderr
    assert r.returncode == 1, r.stderr  # confirmed (was: exit 3, diverged at step 5)
    rows = json.loads(r.stdout)["replays"]
    assert len(rows) == len(doc["results"]) == 2
    for row, res in zip(rows, doc["results"], strict=True):
        assert row["replay"]["status"] == "confirmed", row["replay"]["reason"]
        assert row["replay"]["target_ids"] == [s["target_id"] for s in res["counterexample"]]


SPEC_IDENTITY = """property hijack {
    attack window 2..5
    minimize payoff
    subject to switches(0..end) > 0
    holds if optimum > 3
}
property lose {
    attack window 2..5
    minimize payoff
    subject to lost(0..end) > 0
    holds if optimum > 3
}
"""


def _identity_scene(path: Path, gap: tuple[int, ...]) -> None:
    """Nine frames: the target (20 x 30 box) moving 8 px a frame, its detection missing at
    the frames ``gap``, a still object far away; the target's ground truth has a box at
    every frame (its reference, docs/trackers.md)."""
    frames = []
    for k in range(9):
        d = [] if k in gap else [{"id": f"{k}:0", "x": 40.0 + 8 * k, "y": 50.0}]
        d.append({"id": f"{k}:1", "x": 200.0, "y": 150.0})
        frames.append(
            {"step": k, "detections": [e | {"w": 20.0, "h": 30.0, "payoff": 1.0} for e in d]}
        )
    truth = [{"id": "v1", "positions": [[k, 40.0 + 8 * k, 50.0, 20.0, 30.0] for k in range(9)]}]
    doc = {"format": "lesmc-scene", "version": 2, "frames": frames, "truth": truth,
           "tracker": {"design": "sort"}, "target": {"step": 0, "start": [40.0, 50.0]}}  # fmt: skip
    path.write_text(json.dumps(doc))


def _first_loss_and_switch(ids: list[int | None]) -> tuple[int | None, int | None]:
    """The first step (from 1) without the target's track, and the first whose track id
    differs from the last id the target had (the reference exists at every step)."""
    lost = next((k for k in range(1, len(ids)) if ids[k] is None), None)
    last, switch = ids[0], None
    for k in range(1, len(ids)):
        if ids[k] is not None:
            if last is not None and ids[k] != last and switch is None:
                switch = k
            last = ids[k]
    return lost, switch


def test_multi_violation_without_attack_says_so(tmp_path: Path) -> None:
    scene, spec = tmp_path / "s.json", tmp_path / "p.spec"
    spec.write_text(SPEC_IDENTITY)
    _identity_scene(scene, (3, 4))
    r = lesmc("check", str(scene), str(spec), "--design", "sort", "--json")
    assert r.returncode == 1 and "Traceback" not in r.stderr, r.stderr
    doc = json.loads(r.stdout)
    validate(doc, "multi-check")
    for res in doc["results"]:
        assert res["verdict"] == "violated" and res["optimum"] == 0
        steps = res["counterexample"]
        assert not any(s["hidden"] or s["injected"] for s in steps)
        lost, switch = _first_loss_and_switch([s["target_id"] for s in steps])
        assert lost is not None and switch is not None
        (note,) = res["notes"]
        assert note.startswith("violated without attack: the unattacked run itself violates")
        assert f"loses the target at step {lost}" in note
        assert f"switches the target's id at step {switch}" in note
    text = lesmc("check", str(scene), str(spec), "--design", "sort")
    assert text.returncode == 1 and "Traceback" not in text.stderr, text.stderr
    assert text.stdout.count("note: violated without attack") == 2
    _identity_scene(scene, ())  # no gap: losing the target takes an attack
    r = lesmc("check", str(scene), str(spec), "--design", "sort", "--json")
    assert "Traceback" not in r.stderr, r.stderr
    for res in json.loads(r.stdout)["results"]:
        assert res["verdict"] == "violated" and res["optimum"] > 0
        assert "notes" not in res


GRID_SPEC = """property g {{
  attack window 6..8 allow hide, inject
  inject grid 5 within 10 payoff {p}
  minimize payoff
  subject to dist.sum(0..end) > 120
  holds if optimum > 3
}}
"""


@pytest.mark.parametrize("p", ["1.5e12", "1e308"])
def test_an_inject_grid_payoff_above_the_scene_cap_is_refused_at_p(tmp_path: Path, p: str) -> None:
    spec = tmp_path / "g.spec"
    spec.write_text(GRID_SPEC.format(p=p))
    line = spec.read_text().split("\n")[2]
    col = line.index(p) + 1  # P's column, counted here
    r = lesmc("check", str(ROOT / "examples" / "merge.json"), "g.spec", cwd=tmp_path)
    assert r.returncode == 2 and "Traceback" not in r.stderr, r.stderr
    assert r.stdout == ""
    first = r.stderr.strip().splitlines()[0]
    assert first.startswith(f"g.spec:3:{col}: "), first
    assert "at most 1e+12" in first and p in first


def test_an_inject_grid_payoff_at_the_cap_is_taken(tmp_path: Path) -> None:
    """P = 1e12 (the cap itself) is a valid price: the check runs (no grid point is then
    worth taking at a threshold of 3)."""
    spec = tmp_path / "g.spec"
    spec.write_text(GRID_SPEC.format(p="1e12"))
    r = lesmc("check", str(ROOT / "examples" / "merge.json"), "g.spec", "--json", cwd=tmp_path)
    assert "Traceback" not in r.stderr, r.stderr
    assert r.returncode in (0, 1), r.stderr
    assert json.loads(r.stdout)["results"][0]["property"] == "g"
