"""Recall's and precision's counts live in one function (quality.visible_counts): verify
--detector's detection facts and lesmc train --kind heatmap's validation both call it."""

from __future__ import annotations

import itertools
from pathlib import Path
from types import SimpleNamespace

import numpy as np

from lesmc.perception.quality import visible_counts


def _most_pairs(det: np.ndarray, truth: np.ndarray, radius: float) -> int:
    """The largest one-to-one matching within ``radius``, by trying every assignment."""
    ok = np.linalg.norm(det[:, None, :] - truth[None, :, :], axis=2) <= radius
    n, m = ok.shape
    best = 0
    if n <= m:
        for perm in itertools.permutations(range(m), n):
            best = max(best, sum(bool(ok[i, perm[i]]) for i in range(n)))
    else:
        for perm in itertools.permutations(range(n), m):
            best = max(best, sum(bool(ok[perm[j], j]) for j in range(m)))
    return best


def test_counts_equal_a_brute_force_matching() -> None:
    rng = np.random.default_rng(5)
    frames = []
    for _ in range(12):
        det = rng.uniform(0, 20, (int(rng.integers(0, 6)), 2))
        truth = rng.uniform(0, 20, (int(rng.integers(0, 6)), 2))
        frames.append((det, truth))
    got = visible_counts(frames, 4.0)
    assert got.vehicles == sum(len(t) for _, t in frames)
    assert got.detections == sum(len(d) for d, _ in frames)
    tp = sum(_most_pairs(d, t, 4.0) for d, t in frames if len(d) and len(t))
    assert got.true_positives == tp
    assert got.recall == tp / got.vehicles
    assert got.precision == tp / got.detections


def test_no_vehicle_or_detection_has_no_rate() -> None:
    got = visible_counts([(np.zeros((0, 2)), np.zeros((0, 2)))], 4.0)
    assert (got.vehicles, got.detections, got.true_positives) == (0, 0, 0)
    assert got.recall is None and got.precision is None


def test_verify_facts_count_the_visible_vehicles_only() -> None:
    """detector_verify.quality: occluded vehicles are left out, frames without truth too."""
    from lesmc.experiment.detector_verify import quality
    from lesmc.perception.quality import Truth, TruthFrame
    from lesmc.scene import Detection, Footage, Frame, TrackerConfig

    def frame(i: int, xy: list[tuple[float, float]]) -> Frame:
        return Frame(i, tuple(Detection(f"{i}:{k}", x, y, 1.0) for k, (x, y) in enumerate(xy)))

    a = TruthFrame(
        np.array([[10.0, 10.0], [50.0, 50.0], [90.0, 90.0]]),
        np.zeros(3),
        np.array([False, True, False]),
    )
    truth = Truth(0.5, {"a.png": a})
    frames = SimpleNamespace(paths=[Path("a.png"), Path("b.png")])
    # frame a: one hit (10,10), one on the occluded vehicle (a false positive), one far
    # frame b has no truth: its detections do not count
    footage = Footage(
        0.5,
        (frame(0, [(11.0, 10.0), (50.0, 50.0), (200.0, 0.0)]), frame(1, [(10.0, 10.0)])),
        TrackerConfig(),
        {},
    )
    got = quality(footage, frames, truth)  # type: ignore[arg-type]
    assert (got["vehicles"], got["true_positives"]) == (2, 1)
    assert got["recall"] == 0.5 and got["precision"] == 1 / 3
