"""What a counterexample hides under ``allow hide, inject`` on ``single`` (issue 61): the
results document's ``hidden`` list. The ranks are ordered by cost, so the transitions
ranked before the one taken are the cheaper outcomes, not the detections hidden (the old
``_hidden`` listed them: a detection the attack never touched). The cheapest way to force
each outcome is written out here from the scene's geometry."""

from __future__ import annotations

from typing import Any

import pytest
from test_inject_single import _cases

from lesmc import api
from lesmc.pipeline.check import run
from lesmc.pipeline.job import Job
from lesmc.results.document import run_json
from lesmc.scene import scene_from_dict


def _hidden(frames: list[dict[str, Any]], extra: str = "") -> tuple[float, list[str], Any]:
    doc = _cases(1, 1)[0]["doc"]
    doc["frames"] = frames
    spec = api.parse_spec(
        f"property p {{ attack window 1..1 allow hide, inject{extra} end 2 minimize payoff "
        "subject to dist.max(0..end) > 3 holds if optimum > 10 }\n"
    )
    res = run(Job((spec,), scene=scene_from_dict(doc), full_models=True))
    (r,) = res.results
    got = run_json(res.runs[0])["hidden"]["p"]
    return float(r.optimum), [h["obs"] for h in got], r


def test_an_injection_nearer_than_every_detection_hides_nothing() -> None:
    """The prediction is (10, 0); 1:0 lies 6 px above it, the candidate 1:1 3 px below:
    injecting 1:1 (1) is the cheapest attack and hides nothing. The old list named 1:0,
    the outcome ranked before the one taken (the unattacked update)."""
    frames = [
        {"step": 0, "detections": []},
        {
            "step": 1,
            "detections": [{"id": "1:0", "x": 10.0, "y": 6.0, "payoff": 5.0}],
            "candidates": [{"id": "1:1", "x": 10.0, "y": -3.0, "payoff": 1.0}],
        },
        {"step": 2, "detections": [{"id": "2:0", "x": 20.0, "y": 0.0, "payoff": 5.0}]},
    ]
    optimum, hidden, r = _hidden(frames)
    assert optimum == pytest.approx(1.0)
    assert [s.obs for s in r.cheapest.steps if s.attacked] == ["1:1"]
    assert hidden == []


def test_an_injection_beyond_a_detection_hides_it() -> None:
    """1:0 lies 0.5 px from the prediction, the candidate 1:1 12 px: forcing 1:1 hides 1:0
    (5) and injects 1:1 (1); 1:0 is listed with its own payoff and position."""
    frames = [
        {"step": 0, "detections": []},
        {
            "step": 1,
            "detections": [{"id": "1:0", "x": 10.0, "y": 0.5, "payoff": 5.0}],
            "candidates": [{"id": "1:1", "x": 10.0, "y": 12.0, "payoff": 1.0}],
        },
        {"step": 2, "detections": [{"id": "2:0", "x": 20.0, "y": 0.0, "payoff": 5.0}]},
    ]
    optimum, hidden, _ = _hidden(frames)
    assert optimum == pytest.approx(6.0)
    assert hidden == ["1:0"]


def test_a_grid_point_beyond_two_detections_hides_both() -> None:
    """Two detections 1 and 1.5 px above the prediction: a grid point 4 px off is reached
    by hiding both (2 + 2) and injecting it (0.5); nothing cheaper strays 3."""
    frames = [
        {"step": 0, "detections": []},
        {
            "step": 1,
            "detections": [
                {"id": "1:0", "x": 10.0, "y": 1.0, "payoff": 2.0},
                {"id": "1:1", "x": 10.0, "y": 1.5, "payoff": 2.0},
            ],
        },
        {"step": 2, "detections": [{"id": "2:0", "x": 20.0, "y": 0.0, "payoff": 5.0}]},
    ]
    optimum, hidden, r = _hidden(frames, " inject grid 4 within 4 payoff 0.5")
    assert optimum == pytest.approx(4.5)
    assert next(s.obs for s in r.cheapest.steps if s.attacked).startswith("1:grid")
    assert sorted(hidden) == ["1:0", "1:1"]
