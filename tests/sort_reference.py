"""Bewley's SORT (PyPI ``sort-tracker-py``, module ``sort_tracker``), run unchanged as the
oracle of lesmc's ``sort`` design. Test-only; it needs filterpy (its Kalman filter) and
uses ``lap`` for the assignment when importable, else scipy's ``linear_sum_assignment``."""

from __future__ import annotations

import importlib
import sys
from collections.abc import Iterator, Sequence
from contextlib import contextmanager

import numpy as np


@contextmanager
def _without_lap() -> Iterator[None]:
    """``import lap`` fails inside: SORT takes its scipy branch (its own fallback)."""
    saved = sys.modules.get("lap")
    sys.modules["lap"] = None  # type: ignore[assignment]
    try:
        yield
    finally:
        if saved is None:
            del sys.modules["lap"]
        else:
            sys.modules["lap"] = saved


def reference_sort(
    frames: Sequence[np.ndarray],
    use_lap: bool = False,
    max_age: int = 1,
    min_hits: int = 3,
    iou_threshold: float = 0.3,
) -> list[dict[int, np.ndarray]]:
    """SORT's output per frame: {id: box [x1, y1, x2, y2]}; ``frames`` holds each frame's
    boxes (k, 4). Ids count from 1 in every run (``KalmanBoxTracker.count`` reset)."""
    sort = importlib.import_module("sort_tracker.sort")
    sort.KalmanBoxTracker.count = 0
    tracker = sort.Sort(max_age=max_age, min_hits=min_hits, iou_threshold=iou_threshold)
    out: list[dict[int, np.ndarray]] = []
    for boxes in frames:
        dets = np.empty((0, 5)) if not len(boxes) else np.hstack([boxes, np.ones((len(boxes), 1))])
        if use_lap:
            res = tracker.update(dets)
        else:
            with _without_lap():
                res = tracker.update(dets)
        out.append({int(r[-1]): np.asarray(r[:4], dtype=float) for r in res})
    return out
