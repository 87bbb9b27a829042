"""A diverged replay is judged on the replayed run (issue 61 item 4; docs/semantics.md,
"Violated on the frames by another path"; lesmc/replay/on_frames.py).

The property is about the real system: a replayed run that leaves the model's path but
deviates from the unattacked run beyond the bound, at a cost (the perturbations the
replay applied, the repair's included) that still fails the threshold, is a violation on
the frames. On the small WAMI video of tests/wami_video.py (its first 6 frames), with the
scene of tests/test_replay_reinject.py's payoff case (5:c488 the only candidate; every
detection of frame 5 but 5:29 costing 1e6 to hide), two ``minimize payoff`` properties
share one counterexample (hide 5:29, repaired): ``real`` at T = 100, ``dear`` at T = 0.7,
below the repaired attack's cost. The results are then edited so that the model's
position at step 1 lies 3 px off the replayed one: both replays diverge there. ``real``'s
replayed run still violates (the deviation is the real one, the cost far below 100): the
verdict is ``violated``, exit 1. ``dear``'s costs more than 0.7: ``unknown``. The
deviation is checked against numpy on the replayed positions and the model's own
unattacked path (the unfolder's, not the replay's).
"""

from __future__ import annotations

import json
import math
from typing import Any

import numpy as np
import pytest
from cli_run import lesmc
from wami_video import perceive_with_candidates, synth_wami_video

from lesmc.language import measures
from lesmc.replay.case import FrameAttack
from lesmc.replay.on_frames import frame_count
from lesmc.replay.run import verdict_after
from lesmc.results.document import record_replays
from lesmc.results.read import Monitor, PropertyDoc
from lesmc.results.replay_measures import judged_measures
from lesmc.results.result_doc import read_replay

TARGET = "162.9,480.0@4"
CANDIDATE, CHEAP = "5:c488", "5:29"
THRESHOLDS = {"real": 100.0, "dear": 0.7}
BOUND = 0.5
SHIFT_PX = 3.0

SPEC = """property PROP {
    attack window 1..1 allow hide, inject
    minimize payoff
    subject to dist.max(0..end) > BOUND
    holds if optimum > T
    end 1
    on x, y
}
"""


@pytest.fixture(scope="module")
def replayed(tmp_path_factory: pytest.TempPathFactory) -> tuple[int, dict[str, Any], Any]:
    """``lesmc replay --json`` of the two properties' results, their model path at step 1
    moved by :data:`SHIFT_PX`: the exit status, the rows by property, the results."""
    tmp = tmp_path_factory.mktemp("replayprop")
    video = tmp / "video"
    synth_wami_video(video, frames=6)
    perceive_with_candidates(video, tmp / "perceived.json", TARGET)
    scene = json.loads((tmp / "perceived.json").read_text())
    for f in scene["frames"]:
        f["candidates"] = [c for c in f.get("candidates", []) if c["id"] == CANDIDATE]
        for d in f["detections"] if f["step"] == 5 else []:
            d["payoff"] = d["payoff"] if d["id"] == CHEAP else 1e6
    scene["tracker"].update(sigma_r=20.0, P0_sd=[5.0, 5.0, 5.0, 5.0])
    (tmp / "scene.json").write_text(json.dumps(scene))
    spec = "".join(
        SPEC.replace("PROP", p).replace("> T", f"> {t}").replace("BOUND", str(BOUND))
        for p, t in THRESHOLDS.items()
    )
    (tmp / "p.spec").write_text(spec)
    r = lesmc("check", str(tmp / "scene.json"), str(tmp / "p.spec"), "--design", "single",
              "--report", str(tmp / "out"))  # fmt: skip
    assert r.returncode == 1 and "Traceback" not in r.stderr, r.stderr
    results = tmp / "out" / "results.json"
    doc = json.loads(results.read_text())
    (run,) = doc["runs"]
    moved = {run["paths"][no - 1]["states"][1] for no in run["roles"]["counterexample"]}
    for q in moved:  # the model's position at step 1, 3 px off the frames'
        run["states"][q]["s"][0] += SHIFT_PX
    results.write_text(json.dumps(doc))
    r = lesmc("replay", str(results), "--frames", str(video), "--json")
    assert "Traceback" not in r.stderr, r.stderr
    rows = {row["property"]: row for row in json.loads(r.stdout)["replays"]}
    return r.returncode, rows, doc


def _unattacked(doc: dict[str, Any]) -> np.ndarray:
    """The model's unattacked path's positions, step by step (the unfolder's)."""
    (run,) = doc["runs"]
    path = run["paths"][run["roles"]["original"] - 1]
    return np.array([run["states"][q]["s"][:2] for q in path["states"]], float)


def _optimum(doc: dict[str, Any], prop: str) -> float:
    (run,) = doc["runs"]
    return float(next(r for r in run["results"] if r["property"] == prop)["optimum"])


def _applied_cost(rp: dict[str, Any]) -> float:
    """What the replay's perturbations cost: their recomputed norms and the repair's."""
    return sum(float(p["payoff_recomputed"]) for p in rp["perturbations"]) + rp["repair_cost"]


@pytest.mark.parametrize("prop", sorted(THRESHOLDS))
def test_both_replays_diverge_at_the_moved_step(
    replayed: tuple[int, dict[str, Any], Any], prop: str
) -> None:
    _, rows, doc = replayed
    rp = rows[prop]["replay"]
    assert rows[prop]["verdict_model"] == "violated"
    assert _optimum(doc, prop) <= THRESHOLDS[prop]
    assert rp["status"] == "diverged" and rp["step"] == 1, rp
    assert "on_frames" in rp


@pytest.mark.parametrize("prop", sorted(THRESHOLDS))
def test_the_deviation_is_numpys_on_the_replayed_positions(
    replayed: tuple[int, dict[str, Any], Any], prop: str
) -> None:
    _, rows, doc = replayed
    on = rows[prop]["replay"]["on_frames"]
    track, base = np.array(on["track"], float), _unattacked(doc)
    assert track.shape == base.shape == (2, 2)
    # the replay's unattacked run is the model's unattacked path
    np.testing.assert_allclose(on["unattacked"], base, atol=1e-4)
    want = float(np.max(np.hypot(*(track - base).T)))  # dist.max(0..end), Eq. 4 with p = 2
    assert on["constraint"] == pytest.approx(want, abs=1e-4)
    assert on["constraint_met"] is (want > BOUND)
    assert on["cost"] == pytest.approx(_applied_cost(rows[prop]["replay"]), rel=1e-6)


def test_a_real_run_that_violates_is_a_violation(
    replayed: tuple[int, dict[str, Any], Any],
) -> None:
    """``real`` (T = 100): the replayed run meets the constraint at a cost below 100."""
    code, rows, _ = replayed
    row = rows["real"]
    on = row["replay"]["on_frames"]
    assert on["constraint_met"] and on["cost"] <= THRESHOLDS["real"]
    assert on["violated"] is True
    assert on["why"].startswith("violated on the frames by another path")
    assert row["verdict"] == "violated"
    assert code == 1  # violated


def test_a_real_run_that_costs_too_much_stays_unknown(
    replayed: tuple[int, dict[str, Any], Any],
) -> None:
    """``dear`` (T = 0.7): the same run, but the repaired attack costs more than 0.7."""
    _, rows, doc = replayed
    row = rows["dear"]
    on = row["replay"]["on_frames"]
    assert row["replay"]["repair_cost"] > 0
    assert on["cost"] > THRESHOLDS["dear"] >= _optimum(doc, "dear")
    assert on["violated"] is False
    assert "the property holds" in on["why"]
    assert row["verdict"] == "unknown"


def _doc(verdict: str) -> dict[str, Any]:
    return {"runs": [{"results": [{"verdict": verdict, "vacuous": False, "notes": [],
                                   "optimum": 1.5}]}]}  # fmt: skip


@pytest.mark.parametrize("violated", [True, False])
def test_the_results_keep_violated_only_for_a_violating_run(violated: bool) -> None:
    """lesmc verify's record of a diverged replay: violated (with the run's note) when its
    run violates, unknown otherwise; ``lesmc replay``'s verdict agrees."""
    doc = _doc("violated")
    obj = {"status": "diverged", "step": 1, "reason": "moved",
           "on_frames": {"violated": violated, "why": "the run"}}  # fmt: skip
    record_replays(doc, {(0, 0): obj}, 0.0)
    res = doc["runs"][0]["results"][0]
    want = "violated" if violated else "unknown"
    assert res["verdict"] == res["status"] == want
    assert res["notes"][-1].startswith("the run" if violated else "unknown:")
    assert verdict_after(read_replay(obj)) == want
    assert verdict_after(read_replay({**obj, "on_frames": None})) == "unknown"


def _prop(**kw: Any) -> PropertyDoc:
    base: dict[str, Any] = dict(
        name="p", constraint_source="dist", constraint_aggregate="sum",
        constraint_range=(0, 19), bound=120.0, monitor=None, constraint_op=">",
        components=("x", "y"), window=(6, 8),
    )  # fmt: skip
    return PropertyDoc(**{**base, **kw})


def test_the_cost_objectives_are_bound_by_the_registry() -> None:
    mean = judged_measures(_prop(), "payoff", "payoff.mean", "single")
    assert not isinstance(mean, str)
    assert mean.objective.weight == pytest.approx(1 / 3)  # window 6..8: three steps
    assert (mean.objective.lo, mean.objective.hi) == (6, 8)
    frames = judged_measures(_prop(), "frames", "count.frames", "single")
    assert not isinstance(frames, str) and frames.objective.source == "frames"
    assert frames.constraint.source == "dist" and frames.constraint.hi == 19


@pytest.mark.parametrize(
    ("kw", "source", "text"),
    [
        ({"monitor": Monitor(("x", "y"), 0.0, False)}, "payoff", "payoff"),
        ({}, "dist", "dist.max(0..end)"),
        ({"constraint_source": "near"}, "payoff", "payoff"),
        ({"constraint_op": None}, "payoff", "payoff"),
    ],
)
def test_what_the_replay_does_not_judge(kw: dict[str, Any], source: str, text: str) -> None:
    assert "dist" in measures.sources()
    assert isinstance(judged_measures(_prop(**kw), source, text, "single"), str)


def test_a_repair_that_did_not_count_its_windows_claims_no_count() -> None:
    fa = FrameAttack(5, 1, None)  # type: ignore[arg-type]  # the detections are not read
    fa.perturbations = [{"payoff_recomputed": 0.5}]
    assert frame_count(fa) == 1
    fa.extra_cost, fa.extra_windows = 0.1, 2
    assert frame_count(fa) == 3
    fa.extra_windows = 0
    assert math.isinf(frame_count(fa))
    fa.extra_windows, fa.perturbations = 2, [{"payoff_recomputed": "inf"}]
    assert math.isinf(frame_count(fa))  # an outcome the attack cannot force counts ∞
