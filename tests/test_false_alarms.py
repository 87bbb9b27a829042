"""The monitor's false alarms on truth tracks (lesmc/experiment/false_alarms.py): the batched
run of every vehicle's unattacked track against ``track`` of a scene with that vehicle as
its target, one by one (issue 31: 22x faster, the same bits)."""

from __future__ import annotations

import dataclasses
from pathlib import Path

import numpy as np
import pytest

from lesmc.experiment.false_alarms import TruthStart, unattacked_taus
from lesmc.scene import Target, load_scene
from lesmc.tracking.monitor import track
from lesmc.tracking.trackers import make_tracker

SCENES = Path(__file__).parent / "scenes"


@pytest.mark.parametrize("name", ["rq4_merge", "rq1_platoon", "rq2_stop"])
@pytest.mark.parametrize("design", ["single", "joint"])
def test_batched_tracks_equal_each_track_alone(name: str, design: str) -> None:
    scene = load_scene(SCENES / f"{name}.json")
    rng = np.random.default_rng(3)
    frame = scene.frame(scene.target.step)
    starts = [
        TruthStart(i, d.x + rng.normal(0, 2), d.y + rng.normal(0, 2), *rng.normal(0, 5, 2))
        for i, d in enumerate(frame.detections)
    ]
    starts.append(TruthStart(99, 5000.0, 5000.0, 0.0, 0.0))  # nothing near: it drifts
    steps = scene.last_step - scene.target.step
    got = unattacked_taus(scene, starts, design, steps)
    assert len(got) == len(starts)
    for s, taus in zip(starts, got, strict=True):
        sc = dataclasses.replace(
            scene.with_tracker(design=design),
            target=Target(scene.target.step, (s.x, s.y), (s.vx, s.vy)),
        )
        want = np.array([p.tau for p in track(make_tracker(sc), steps)])
        np.testing.assert_array_equal(taus, want)
