"""The replay's repair round re-injects (issue 61 item 4; docs/semantics.md, "Repaired
attack"; lesmc/replay/perturbed.py ``repair_frame``).

On the small WAMI video of tests/wami_video.py (its first 6 frames: ``lesmc synth`` gives
the same frames for any length), the car at (162.9, 480.0) in frame 4 is the target. At
frame 5 its detection 5:29 (160.5, 453.0) and the candidate 5:c488 (160.5, 443.0), 10 px
ahead, have N_dr windows that overlap (21 x 21 px, 11 rows in common). A ``single``
counterexample under ``allow hide, inject`` takes 5:c488 at step 1, so the replay hides
5:29 and injects 5:c488. Each perturbation flips N_dr on its own window, but applied
together the candidate is not detected, and re-hiding what survives does not bring it
back (the replay before this change diverged here). The repair that perturbs the
candidate's window again, on the perturbed frame, does: the replay is ``confirmed``
with the repair's cost reported. With the round limit at one round (it takes two) the
same counterexample stays ``diverged``, and the reason names the overlapping windows.

A repaired attack costs more than the model's optimum (the repair's norms added): under a
``minimize payoff`` property the replay checks that this cost still breaks the property
(``holds if optimum > T``). With every detection of frame 5 but 5:29 made expensive, the
cheapest attack hides 5:29 (0.6429) and the repair re-hides what survives (0.1202): at
T = 0.7 the repaired attack's 0.7631 makes the property hold, so the replay is
``diverged`` (exit 3); at T = 100 it is ``confirmed`` (exit 1).

The scene keeps 5:c488 as the only injection candidate (a smaller threat model: any subset
of the candidates is one) and a tracker that trusts its prediction more (``sigma_r`` 20,
``P0_sd`` 5): the detector reports the injected candidate 0.9 px from its clean centroid
(its blob moved under the perturbation), inside the 1 px detection tolerance, and the
Kalman gain keeps the track within the 0.5 px track tolerance.
"""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any

import numpy as np
import pytest
from cli_run import lesmc
from wami_video import perceive_with_candidates, synth_wami_video

TARGET = "162.9,480.0@4"
HIDDEN, INJECTED = "5:29", "5:c488"

SPEC = """property hijack {
    attack window 1..1 allow hide, inject
    minimize dist.max(0..end)
    subject to dist.max(0..end) > 0.5
    holds if optimum > 100
    end 1
    on x, y
}
"""


@pytest.fixture(scope="module")
def checked(tmp_path_factory: pytest.TempPathFactory) -> tuple[Path, dict[str, Any]]:
    """The video, and ``lesmc check --report`` of :data:`SPEC` on its perceived scene with
    5:c488 as the only candidate: the directory and the scene."""
    tmp = tmp_path_factory.mktemp("reinject")
    video = tmp / "video"
    synth_wami_video(video, frames=6)
    perceive_with_candidates(video, tmp / "perceived.json", TARGET)
    scene = json.loads((tmp / "perceived.json").read_text())
    for f in scene["frames"]:
        f["candidates"] = [c for c in f.get("candidates", []) if c["id"] == INJECTED]
    scene["tracker"].update(sigma_r=20.0, P0_sd=[5.0, 5.0, 5.0, 5.0])
    (tmp / "scene.json").write_text(json.dumps(scene))
    (tmp / "hijack.spec").write_text(SPEC)
    r = lesmc("check", str(tmp / "scene.json"), str(tmp / "hijack.spec"), "--design",
              "single", "--report", str(tmp / "out"))  # fmt: skip
    assert r.returncode == 1 and "Traceback" not in r.stderr, r.stderr
    return tmp, scene


def _item(scene: dict[str, Any], did: str) -> dict[str, Any]:
    """The scene's detection or candidate ``did``."""
    f = next(f for f in scene["frames"] if f["step"] == int(did.split(":")[0]))
    return next(d for d in f["detections"] + f["candidates"] if d["id"] == did)


def test_the_fixture_is_the_overlapping_case(checked: tuple[Path, dict[str, Any]]) -> None:
    """The counterexample takes the candidate at step 1; the two windows overlap."""
    tmp, scene = checked
    doc = json.loads((tmp / "out" / "results.json").read_text())
    (run,) = doc["runs"]
    (res,) = run["results"]
    assert res["verdict"] == "violated"
    h, c = _item(scene, HIDDEN), _item(scene, INJECTED)
    # 21 x 21 windows around both centres share pixels
    assert abs(h["x"] - c["x"]) <= 20 and abs(h["y"] - c["y"]) <= 20


def test_the_repair_reinjects_and_the_replay_confirms(
    checked: tuple[Path, dict[str, Any]],
) -> None:
    tmp, scene = checked
    r = lesmc("replay", str(tmp / "out" / "results.json"), "--frames", str(tmp / "video"),
              "--json")  # fmt: skip
    assert "Traceback" not in r.stderr, r.stderr
    assert r.returncode == 1, r.stderr  # violated: confirmed
    (row,) = json.loads(r.stdout)["replays"]
    rp = row["replay"]
    assert rp["status"] == "confirmed", rp["reason"]
    assert row["verdict"] == "violated"
    assert rp["attack"] == "repaired"
    assert rp["repair_cost"] > 0  # the extra perturbations' norms, reported
    assert rp["max_error_px"] <= 0.5
    # the first application: the scene's two attacks, recomputed at the scene's prices
    perts = {p["obs"]: p for p in rp["perturbations"]}
    assert set(perts) == {HIDDEN, INJECTED}
    assert perts[INJECTED]["action"] == "inject"
    for did, p in perts.items():
        assert p["payoff_recomputed"] == pytest.approx(_item(scene, did)["payoff"], rel=1e-3)
        assert np.linalg.norm(np.asarray(p["delta"])) == pytest.approx(
            _item(scene, did)["payoff"], rel=1e-3
        )
    assert "not detected" not in " ".join(rp["frames"])


def test_within_one_round_the_repair_fails_and_the_replay_diverges(
    checked: tuple[Path, dict[str, Any]], monkeypatch: pytest.MonkeyPatch
) -> None:
    """The round limit at 1 (the re-injection needs 2): the candidate stays undetected,
    the replay diverges at step 1, and the reason says why (the windows overlap)."""
    from lesmc.perception.cnn import load_nets
    from lesmc.replay import perturbed
    from lesmc.replay.run import replay
    from lesmc.results.load import load_results
    from lesmc.results.read import results_of
    from lesmc.video.reader import open_frames

    tmp, _ = checked
    monkeypatch.setattr(perturbed, "REPAIR_ROUNDS", 1)
    doc = results_of(load_results(str(tmp / "out" / "results.json")))
    out = replay(doc, open_frames(str(tmp / "video"), 5), load_nets(None, None, None))
    rp = out.replays[(0, 0)]
    assert rp["status"] == "diverged"
    assert rp["step"] == 1
    assert rp["attack"] == "repaired"
    assert f"injected {INJECTED} not detected after all" in rp["reason"]
    assert f"(21x21 windows overlap {HIDDEN})" in rp["reason"]


PAY_SPEC = """property PROP {
    attack window 1..1 allow hide, inject
    minimize payoff
    subject to dist.max(0..end) > 0.5
    holds if optimum > T
    end 1
    on x, y
}
"""
HIDE_ONLY = "5:29"  #: the one detection of frame 5 cheap to hide in the payoff scene
THRESHOLDS = {"tight": 0.7, "loose": 100.0}


@pytest.fixture(scope="module")
def priced_check(checked: tuple[Path, dict[str, Any]]) -> tuple[Path, dict[str, Any]]:
    """``lesmc check --report`` of two ``minimize payoff`` properties (``tight`` at
    T = 0.7, ``loose`` at T = 100) on :func:`checked`'s scene with every detection of
    frame 5 but 5:29 costing 1e6 to hide: the directory and its results document."""
    tmp, scene = checked
    scene = json.loads(json.dumps(scene))
    for f in scene["frames"]:
        if f["step"] == 5:
            for d in f["detections"]:
                if d["id"] != HIDE_ONLY:
                    d["payoff"] = 1e6
    (tmp / "pay.json").write_text(json.dumps(scene))
    spec = "".join(
        PAY_SPEC.replace("PROP", name).replace("> T", f"> {t}") for name, t in THRESHOLDS.items()
    )
    (tmp / "pay.spec").write_text(spec)
    r = lesmc("check", str(tmp / "pay.json"), str(tmp / "pay.spec"), "--design", "single",
              "--report", str(tmp / "pay"))  # fmt: skip
    assert r.returncode == 1 and "Traceback" not in r.stderr, r.stderr
    return tmp, json.loads((tmp / "pay" / "results.json").read_text())


def _replay_one(tmp: Path, prop: str) -> tuple[int, dict[str, Any], dict[str, Any]]:
    """``lesmc replay --property PROP --json`` of :func:`priced_check`'s results: the exit
    status, the row and its replay."""
    r = lesmc("replay", str(tmp / "pay" / "results.json"), "--frames", str(tmp / "video"),
              "--property", prop, "--json")  # fmt: skip
    assert "Traceback" not in r.stderr, r.stderr
    (row,) = json.loads(r.stdout)["replays"]
    return r.returncode, row, row["replay"]


def _optimum(doc: dict[str, Any], prop: str) -> float:
    (run,) = doc["runs"]
    res = next(x for x in run["results"] if x["property"] == prop)
    assert res["verdict"] == "violated"  # optimum <= T: the model says it breaks
    return float(res["optimum"])


def _hiding_cost(scene: dict[str, Any]) -> float:
    """What hiding 5:29 costs in the scene: the cheapest attack's price."""
    return float(_item(scene, HIDE_ONLY)["payoff"])


def test_a_repaired_attack_that_costs_too_much_diverges(
    checked: tuple[Path, dict[str, Any]], priced_check: tuple[Path, dict[str, Any]]
) -> None:
    """T = 0.7: optimum (hiding 5:29) + the repair's cost > 0.7, so the property holds
    for the attack that replays: ``diverged``, exit 3 (unknown)."""
    tmp, doc = priced_check
    optimum = _optimum(doc, "tight")
    assert optimum == pytest.approx(_hiding_cost(checked[1]), rel=1e-9)
    assert optimum <= THRESHOLDS["tight"]
    code, row, rp = _replay_one(tmp, "tight")
    assert rp["attack"] == "repaired" and rp["repair_cost"] > 0
    cost = optimum + rp["repair_cost"]
    assert cost > THRESHOLDS["tight"]  # the reviewer's run: 0.6429 + 0.1202
    assert rp["status"] == "diverged", rp
    assert f"costs {cost:.4f}: the property holds for it" in rp["reason"], rp["reason"]
    assert row["verdict"] == "unknown"
    assert code == 3


def test_a_repaired_attack_within_the_threshold_confirms(
    priced_check: tuple[Path, dict[str, Any]],
) -> None:
    """T = 100: the same repaired attack (the same cost) still breaks the property:
    ``confirmed``, exit 1 (violated)."""
    tmp, doc = priced_check
    optimum = _optimum(doc, "loose")
    code, row, rp = _replay_one(tmp, "loose")
    assert rp["attack"] == "repaired" and rp["repair_cost"] > 0
    assert optimum + rp["repair_cost"] <= THRESHOLDS["loose"]
    assert rp["status"] == "confirmed", rp["reason"]
    assert row["verdict"] == "violated"
    assert code == 1
