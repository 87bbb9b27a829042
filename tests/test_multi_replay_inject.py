"""Replay of a multi-target counterexample that injects candidates (issues 58 and 61;
lesmc/replay/multi.py with lesmc/replay/inject.py's ``attack_listed``): on the small
injection video of tests/test_inject_wami.py (768 x 768, seed 4, its first 12 frames),
``lesmc perceive --inject-within 30`` prices the candidates N_dr rejects; the scene keeps
each frame's two candidates nearest the target's path (a smaller threat model: any subset
of the perceived candidates is one), and ``lesmc verify --scene --frames --design gnn``
under ``allow inject`` finds a hijack that only injects. Its replay perturbs the
candidate's N_dr window until the detector reports it and is confirmed; the same
counterexample with the frame's other candidate swapped in diverges. Both replayed runs
are checked independently with the plain gnn tracker (tests/gnn_plain.py) on the
replayed detections."""

from __future__ import annotations

import json
import re
from pathlib import Path
from typing import Any

import numpy as np
import pytest
from cli_run import lesmc

from lesmc.schemas import validate

pytest.importorskip("gnn_reference")  # the plain tracker's own oracle: stonesoup
import test_gnn_attack as scoring
import test_multi_replay_gnn as gnn

#: The target of tests/test_inject_wami.py: a car on a busy road, rejected blobs near it.
TARGET = "206.434,202.672@4"

SPEC = """property hijack {
    attack window 2..4 within 15 allow inject
    minimize payoff
    subject to switches(0..end) > 0
    holds if optimum > 100
}
"""


def _near_path(scene: dict[str, Any], keep: int, radius: float) -> dict[str, Any]:
    """``scene`` with each frame's ``keep`` candidates nearest the target's straight path
    (its start and velocity) within ``radius`` px (their ids unchanged)."""
    t = scene["target"]
    x, y = t["start"]
    vx, vy = t["velocity"]
    for i, f in enumerate(scene["frames"]):
        at = np.array([x + vx * scene["dt"] * i, y + vy * scene["dt"] * i])
        d = {c["id"]: float(np.hypot(c["x"] - at[0], c["y"] - at[1])) for c in f["candidates"]}
        near = sorted((c for c in f["candidates"] if d[c["id"]] < radius), key=lambda c: d[c["id"]])
        f["candidates"] = near[:keep]
    return scene


@pytest.fixture(scope="module")
def verified(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """The video, its scene with candidates near the target, and ``lesmc verify --scene
    --design gnn`` of the hijack under ``allow inject``: its OUT."""
    base = tmp_path_factory.mktemp("injectreplay")
    video, scene = base / "video", base / "perceived.json"
    r = lesmc("synth", str(video), "--frames", "12", "--size", "768x768", "--seed", "4",
              "--density", "2.5")  # fmt: skip
    assert r.returncode == 0, r.stderr
    r = lesmc("perceive", str(video), "-o", str(scene), "--target", TARGET,
              "--truth", str(video / "truth.json"), "--inject-within", "30")  # fmt: skip
    assert r.returncode == 0 and "Traceback" not in r.stderr, r.stderr
    near = _near_path(json.loads(scene.read_text()), 2, 30.0)
    (base / "scene.json").write_text(json.dumps(near))
    (base / "hijack.spec").write_text(SPEC)
    out, spec = base / "out", base / "hijack.spec"
    r = lesmc("verify", "--scene", str(base / "scene.json"), "--frames", str(video),
              "--design", "gnn", "--spec", str(spec), "--out", str(out))  # fmt: skip
    assert "Traceback" not in r.stderr, r.stderr
    assert r.returncode == 1, r.stderr  # violated, and the replay confirmed it
    return out


def _injected(steps: list[dict[str, Any]]) -> list[tuple[int, str]]:
    return [(k, c) for k, s in enumerate(steps) for c in s["injected"]]


def _scene(out: Path) -> dict[str, Any]:
    return json.loads((out.parent / "scene.json").read_text())


def test_an_injection_counterexample_replays_confirmed(verified: Path) -> None:
    doc = json.loads((verified / "results.json").read_text())
    validate(doc, "multi-check")
    scene = _scene(verified)
    (res,) = doc["results"]
    assert res["verdict"] == "violated"
    steps = res["counterexample"]
    injected = _injected(steps)
    assert injected and not any(s["hidden"] for s in steps)  # injection only
    rp = res["replay"]
    assert rp["status"] == "confirmed", rp["reason"]
    assert rp["target_ids"] == [s["target_id"] for s in steps]
    cands = {c["id"]: c for f in scene["frames"] for c in f["candidates"]}
    perts = rp["perturbations"]
    assert [(p["obs"], p["action"]) for p in perts] == [(c, "inject") for _, c in injected]
    for p in perts:
        c = cands[p["obs"]]
        # the attack towards "vehicle" recomputed at the price the scene gives ...
        assert p["payoff_recomputed"] == pytest.approx(c["payoff"], rel=1e-3)
        assert np.linalg.norm(np.asarray(p["delta"])) == pytest.approx(c["payoff"], rel=1e-3)
        # ... and the detector now reports the candidate where the scene has it
        (again,) = [d["positions"] for d in rp["detections"] if d["frame"] == p["frame"]]
        assert np.linalg.norm(np.array(again) - [c["x"], c["y"]], axis=1).min() < 1.0
    assert rp["objective"] == pytest.approx(res["optimum"], rel=1e-3)
    # independently: the plain gnn tracker on the replayed detections switches the
    # target's identity as often as the replay says, and not without the attack
    p, end = gnn._params(scene), len(steps) - 1
    refs = gnn._references(steps)
    got = scoring._score(gnn._run(p, gnn._frames(scene, rp, end)), refs, 0, end)
    assert got[0] == rp["constraint_value"] == res["constraint_value"] > 0
    assert scoring._score(gnn._run(p, gnn._frames(scene, None, end)), refs, 0, end)[0] == 0


def test_a_swapped_candidate_replays_diverged(verified: Path, tmp_path: Path) -> None:
    """The injected candidate swapped for its frame's other candidate: ``lesmc replay``
    attacks that one's window instead, the target keeps its track, the replay diverges
    (exit 3: unknown) and the plain tracker on the replayed detections sees no switch
    either."""
    doc = json.loads((verified / "results.json").read_text())
    scene = _scene(verified)
    steps = doc["results"][0]["counterexample"]
    k, was = _injected(steps)[0]
    (other,) = [c for c in scene["frames"][k]["candidates"] if c["id"] != was]
    steps[k]["injected"] = [other["id"]]
    del doc["results"][0]["replay"]
    bad = tmp_path / "results.json"
    bad.write_text(json.dumps(doc))
    r = lesmc("replay", str(bad), "--frames", str(verified.parent / "video"), "--json")
    assert "Traceback" not in r.stderr, r.stderr
    assert r.returncode == 3, r.stderr
    out = json.loads(r.stdout)
    validate(out, "replay")
    (row,) = out["replays"]
    rp = row["replay"]
    assert (row["verdict_model"], row["verdict"]) == ("violated", "unknown")
    assert rp["status"] == "diverged" and rp["constraint_value"] == 0
    assert [(p["obs"], p["action"]) for p in rp["perturbations"]] == [(other["id"], "inject")]
    assert f"injected {other['id']}" in " ".join(rp["frames"])  # the frame's story
    end = len(steps) - 1
    frames = gnn._frames(scene, rp, end)
    got = scoring._score(gnn._run(gnn._params(scene), frames), gnn._references(steps), 0, end)
    assert got[0] == 0


def test_an_injected_id_the_scene_lacks_is_a_located_error(verified: Path, tmp_path: Path) -> None:
    """A candidate id that is none of its frame's: an input error at the id's
    ``FILE:LINE:COL`` in the results file, raised while the cases are read (before the
    video; in process: the CLI's exit 2 for it is tests/test_multi_replay.py's)."""
    from lesmc.common.errors import InputError
    from lesmc.replay.multi_cases import multi_cases
    from lesmc.scene import scene_from_dict

    doc = json.loads((verified / "results.json").read_text())
    steps = doc["results"][0]["counterexample"]
    k, _ = _injected(steps)[0]
    steps[k]["injected"] = [f"{steps[k]['frame']}:c9999"]
    odd = tmp_path / "odd.json"
    odd.write_text(json.dumps(doc, indent=1))
    scene = scene_from_dict(_scene(verified))
    with pytest.raises(InputError) as err:
        multi_cases(doc, scene, {"hijack": object()}, None, str(odd))
    text = err.value.render()
    assert re.search(rf"{re.escape(str(odd))}:\d+:\d+: ", text), text  # FILE:LINE:COL
    assert f"results[0].counterexample[{k}].injected[0]" in text
    assert "is not an injection candidate of the scene's frame" in text
