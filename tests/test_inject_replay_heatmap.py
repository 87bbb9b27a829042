"""Replay of an ``allow hide, inject`` counterexample through a heatmap detector file
(issue 61, item 4; docs/detectors.md, "Replay").

A bright spot moves past a static one with a faint spot 16 px below it; the hand-set
heatmap network of tests/test_detector_replay.py finds the bright spots, and the faint
one is a local maximum below the threshold: an injection candidate (``lesmc perceive
--inject-within``). Hiding the spot and injecting the faint one below it is cheaper
than hiding alone; ``lesmc replay --detector`` derives that attack from the path,
recomputes both perturbations, decodes the frame again and confirms the track.
onnxruntime, given the frame plus the replayed perturbations, decodes a detection at
the candidate's cell and none in the hidden detection's square.
"""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any

import cv2
import numpy as np
import pytest
from cli_run import lesmc
from spot_detector import write_spot_detector, write_spot_frames

from lesmc.schemas import schema

pytest.importorskip("onnx")
ort = pytest.importorskip("onnxruntime")
pytest.importorskip("onnxscript")
jsonschema = pytest.importorskip("jsonschema")

SPEC = """property grab {{
    attack window 3..5{allow}
    minimize payoff
    subject to dist.max(0..end) > 5
    holds if optimum > 10
    on x, y
}}
"""
STRIDE, RADIUS = 4, 2  # the network's (tests/test_detector_replay.py)


def _check(d: Path, scene: Path, allow: str) -> dict[str, Any]:
    spec = d / f"p{len(allow)}.spec"
    spec.write_text(SPEC.format(allow=allow))
    r = lesmc("check", str(scene), str(spec), "--design", "single", "--json",
              "--report", str(d / f"rep{len(allow)}"))  # fmt: skip
    assert "Traceback" not in r.stderr
    assert r.returncode == 1, r.stderr
    out: dict[str, Any] = json.loads(r.stdout)["results"][0]
    return out | {"results": d / f"rep{len(allow)}" / "results.json"}


@pytest.fixture(scope="module")
def checked(tmp_path_factory: pytest.TempPathFactory) -> dict[str, Any]:
    d = tmp_path_factory.mktemp("injheat")
    frames, toml = write_spot_frames(d, 16), write_spot_detector(d)
    scene = d / "scene.json"
    r = lesmc("perceive", str(frames), "--detector", str(toml), "-o", str(scene),
              "--target", "10,30@0", "--inject-within", "25")  # fmt: skip
    assert r.returncode == 0, r.stderr
    hide, both = _check(d, scene, ""), _check(d, scene, " allow hide, inject")
    doc = json.loads(scene.read_text())
    return {"dir": d, "frames": frames, "toml": toml, "scene": doc, "hide": hide, "both": both}


def test_the_injection_counterexample_is_cheaper_and_takes_the_candidate(
    checked: dict[str, Any],
) -> None:
    hide, both = checked["hide"], checked["both"]
    assert both["optimum"] < hide["optimum"]
    taken = [s["obs"] for s in both["counterexample"]["steps"] if s.get("obs")]
    assert any(":c" in o for o in taken), taken


def test_injection_replays_confirmed_through_the_file(checked: dict[str, Any]) -> None:
    both, scene = checked["both"], checked["scene"]
    r = lesmc("replay", str(both["results"]), "--frames", str(checked["frames"]),
              "--detector", str(checked["toml"]), "--json")  # fmt: skip
    assert "Traceback" not in r.stderr
    assert r.returncode == 1, r.stderr  # a violation confirmed
    out = json.loads(r.stdout)
    jsonschema.validate(out, schema("replay"))  # with the registries' $defs (attack_actions)
    (row,) = out["replays"]
    assert row["replay"]["status"] == "confirmed", row["replay"]["reason"]
    perts = row["replay"]["perturbations"]
    pay = {d["id"]: d["payoff"] for f in scene["frames"] for d in f["detections"]}
    pay |= {c["id"]: c["payoff"] for f in scene["frames"] for c in f.get("candidates", [])}
    inj = [p for p in perts if p.get("action") == "inject"]
    assert inj and all(p["obs"] in pay for p in perts)
    for p in perts:  # the recomputed attacks are those the scene priced
        assert p["payoff_recomputed"] == pytest.approx(pay[p["obs"]], rel=1e-3)
    assert sum(p["payoff_recomputed"] for p in perts) == pytest.approx(both["optimum"], rel=1e-3)
    _decoded_by_onnxruntime(checked, perts)


def _decoded_by_onnxruntime(checked: dict[str, Any], perts: list[dict[str, Any]]) -> None:
    """Each attacked frame plus all its replayed perturbations, through onnxruntime: a
    detection (a local maximum of its square at or above the threshold 0) at each injected
    candidate's cell, every cell of each hidden detection's square below the threshold."""
    sess = ort.InferenceSession(str(checked["dir"] / "spot.onnx"))
    for frame in sorted({int(p["frame"]) for p in perts}):
        img = cv2.imread(str(sorted(checked["frames"].iterdir())[frame]), cv2.IMREAD_GRAYSCALE)
        x = (img.astype(np.float32) / np.float32(255.0))[None, None]
        here = [p for p in perts if p["frame"] == frame]
        for p in here:
            delta = np.asarray(p["delta"], np.float32)
            x0, y0 = p["window_origin"]
            x[0, :, y0 : y0 + delta.shape[1], x0 : x0 + delta.shape[2]] += delta
        y = sess.run(None, {sess.get_inputs()[0].name: x})[0][0, 0]
        for p in here:
            i, j = int(p["y"] // STRIDE), int(p["x"] // STRIDE)
            square = y[max(0, i - RADIUS) : i + RADIUS + 1, max(0, j - RADIUS) : j + RADIUS + 1]
            if p.get("action") == "inject":
                assert y[i, j] >= 0.0 and y[i, j] == square.max()
            else:
                assert float(square.max()) < 0.0
