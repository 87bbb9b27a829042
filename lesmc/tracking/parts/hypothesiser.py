"""The hypothesiser: how well each detection fits each track, and which fits are
admissible. The IoU hypothesiser scores a (detection, track) pair by the IoU of the
detection's box with the track's predicted box; a pair is admissible when its IoU is at
least ``threshold`` (SORT: 0.3)."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from lesmc.tracking.parts.boxes import iou


@dataclass(frozen=True)
class IouHypothesiser:
    """IoU scores (larger is better) with an admission threshold in (0, 1]."""

    threshold: float = 0.3

    def __post_init__(self) -> None:
        if not 0 < self.threshold <= 1:
            raise ValueError(f"an IoU threshold must lie in (0, 1], got {self.threshold!r}")

    def scores(self, det_boxes: np.ndarray, track_boxes: np.ndarray) -> np.ndarray:
        """(detections, tracks) IoU of every pair."""
        return iou(det_boxes, track_boxes)
