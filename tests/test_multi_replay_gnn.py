"""Replay of ``gnn`` counterexamples through the real detector and the production tracker
(issue 58; lesmc/replay/multi.py): ``lesmc verify --design gnn`` replays a hijack and a
loss of the target on the small video (tests/multi_video.py) and both are confirmed; a
hand-corrupted hijack replays diverged through ``lesmc replay``. Each replayed run is
checked independently with the plain gnn tracker of tests/gnn_plain.py (itself checked
against Stone Soup's composition in tests/test_gnn_attack.py) on the replayed
detections: the unattacked run gives the references the results list, and the
replayed run switches / loses the target as the replay says."""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any

import numpy as np
import pytest
from cli_run import lesmc
from multi_video import SPEC, write_small_video

from lesmc.schemas import validate

gnn_reference = pytest.importorskip("gnn_reference")  # test_gnn_attack's oracle: stonesoup
import gnn_plain  # noqa: E402
import test_gnn_attack as scoring  # noqa: E402

#: The target whose hijack and loss cost under 3 on this video (as for sort:
#: tests/test_multi_replay.py).
TARGET = "119.0,71.5@4"


@pytest.fixture(scope="module")
def verified(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """``lesmc verify VIDEO --design gnn`` on the 12-frame 448 x 448 video: its OUT."""
    base = tmp_path_factory.mktemp("gnnreplay")
    video = base / "video"
    write_small_video(video)
    (base / "identity.spec").write_text(SPEC)
    out, spec = base / "out", base / "identity.spec"
    r = lesmc("verify", str(video), "--truth", str(video / "truth.json"), "--out", str(out),
              "--design", "gnn", "--spec", str(spec), "--target", TARGET)  # fmt: skip
    assert "Traceback" not in r.stderr, r.stderr
    assert r.returncode == 1, r.stderr  # violated, and the replay confirmed it
    return out


def _params(scene: dict[str, Any]) -> Any:
    """The plain tracker's parameters: the scene's model (its tracker block's sigma_q,
    sigma_r, P0_sd and dt) with the gnn preset's own (gate probability 0.99, M = 3 of
    N = 5, max_age 1: docs/trackers.md, "The gnn preset")."""
    t = scene["tracker"]
    return gnn_reference.Params(
        dt=float(scene["dt"]),
        sigma_q=float(t["sigma_q"]),
        sigma_r=float(t["sigma_r"]),
        P0_sd=tuple(float(v) for v in t["P0_sd"]),
        gate_probability=0.99,
        min_hits=3,
        confirm_window=5,
        max_age=1,
    )


def _frames(scene: dict[str, Any], replay: dict[str, Any] | None, end: int) -> list[np.ndarray]:
    """Each step's detections (positions): the scene's, and on an attacked frame the
    replayed ones."""
    again = {} if replay is None else {d["frame"]: d["positions"] for d in replay["detections"]}
    out = []
    for f in scene["frames"][: end + 1]:
        xy = again.get(f["step"], [[d["x"], d["y"]] for d in f["detections"]])
        out.append(np.array(xy, dtype=float).reshape(-1, 2))
    return out


def _run(p: Any, frames: list[np.ndarray]) -> list[dict[int, tuple[np.ndarray, np.ndarray]]]:
    t = gnn_plain.Plain(p)
    return [t.step(z) for z in frames]


def _references(steps: list[dict[str, Any]]) -> list[np.ndarray | None]:
    """The references the results list (a point design's box is [x, y, x, y])."""
    return [None if s["reference"] is None else np.array(s["reference"][:2]) for s in steps]


def test_verify_gnn_replays_its_counterexamples_confirmed(verified: Path) -> None:
    doc = json.loads((verified / "results.json").read_text())
    validate(doc, "multi-check")
    scene = json.loads((verified / "scene.json").read_text())
    p = _params(scene)
    by_id = {d["id"]: d for f in scene["frames"] for d in f["detections"]}
    assert doc["design"] == "gnn" and doc["reference"] == "unattacked"
    assert doc["perception"]["history"] == 4 and doc["perception"]["delta_bc"] == 12
    assert [r["property"] for r in doc["results"]] == ["hijack", "lose"]
    for res, which in zip(doc["results"], (0, 1), strict=True):
        assert res["verdict"] == "violated" and res["optimum"] < 3.0
        rp = res["replay"]
        assert rp["status"] == "confirmed", rp["reason"]
        assert rp["frontend"] == {
            "history": 4,
            "delta_bc": 12,
            "recorded": ["history", "delta_bc"],
            "from": "results",
        }
        steps = res["counterexample"]
        end = len(steps) - 1
        assert rp["target_ids"] == [s["target_id"] for s in steps]
        refs = _references(steps)
        # the references are the target's unattacked track, by the plain tracker too
        clean = _run(p, _frames(scene, None, end))
        for ref, tracks in zip(refs, clean, strict=True):
            if ref is not None:
                assert min(np.abs(x - ref).max() for x, _ in tracks.values()) < 1e-6
        hidden = [h for s in steps for h in s["hidden"]]
        assert hidden and [q["obs"] for q in rp["perturbations"]] == hidden
        for h in hidden:  # gone from its frame's replayed detections
            det, frame = by_id[h], int(h.split(":")[0])
            (again,) = [d["positions"] for d in rp["detections"] if d["frame"] == frame]
            assert np.linalg.norm(np.array(again) - [det["x"], det["y"]], axis=1).min() > 1.0
        got = scoring._score(_run(p, _frames(scene, rp, end)), refs, 0, end)
        assert got[which] == rp["constraint_value"] == res["constraint_value"]
        assert got[which] > 0
        # and unattacked, the plain tracker neither switches nor loses the target
        assert scoring._score(clean, refs, 0, end) == (0, 0)


def test_a_corrupted_gnn_counterexample_replays_diverged(verified: Path, tmp_path: Path) -> None:
    """The hijack's hidden detections replaced by their frames' detections farthest from
    them: the target keeps its track, ``lesmc replay`` says diverged (exit 3: unknown)
    and the plain tracker on the replayed detections sees no switch either. The document
    is made older too (no ``perception``): the replay runs the default front end and
    says so."""
    doc = json.loads((verified / "results.json").read_text())
    scene = json.loads((verified / "scene.json").read_text())
    doc["results"] = doc["results"][:1]
    steps = doc["results"][0]["counterexample"]
    first = None
    for k, s in enumerate(steps):
        if not s["hidden"]:
            continue
        first = k if first is None else first
        dets = scene["frames"][k]["detections"]
        was = next(d for d in dets if d["id"] == s["hidden"][0])
        far = max(dets, key=lambda d: (d["x"] - was["x"]) ** 2 + (d["y"] - was["y"]) ** 2)
        s["hidden"] = [far["id"]]
    assert first is not None
    del doc["results"][0]["replay"], doc["perception"]
    bad = tmp_path / "results.json"
    bad.write_text(json.dumps(doc))
    r = lesmc("replay", str(bad), "--json")
    assert "Traceback" not in r.stderr, r.stderr
    assert r.returncode == 3, r.stderr
    out = json.loads(r.stdout)
    validate(out, "replay")
    (row,) = out["replays"]
    rp = row["replay"]
    assert (row["verdict_model"], row["verdict"]) == ("violated", "unknown")
    assert rp["status"] == "diverged" and rp["constraint_value"] == 0
    assert rp["frontend"] == {"history": 4, "delta_bc": 12, "recorded": [], "from": "defaults"}
    assert "records no front-end settings" in r.stderr and "delta_bc 12" in r.stderr
    end = len(steps) - 1
    got = scoring._score(_run(_params(scene), _frames(scene, rp, end)), _references(steps), 0, end)
    assert got[0] == 0
