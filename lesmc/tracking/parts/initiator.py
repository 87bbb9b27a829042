"""The initiator: which tracks the tracker outputs (confirms). ``min_hits`` (M of N with
M = N): SORT outputs a track at a frame when it was updated at that frame and its streak
of updates is at least ``min_hits``, or the frame is among the first ``min_hits``
(every detection starts a track; the detector's unmatched ones start new tracks)."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from lesmc.tracking.parts.tracks import Tracks


@dataclass(frozen=True)
class MinHitsInitiator:
    """SORT's output rule with ``min_hits`` ≥ 1."""

    min_hits: int = 3

    def __post_init__(self) -> None:
        if self.min_hits < 1:
            raise ValueError(f"min_hits must be at least 1, got {self.min_hits!r}")

    def confirmed(self, t: Tracks, frame_count: int) -> np.ndarray:
        """Which tracks are output at the ``frame_count``-th frame (1 for the first)."""
        early = frame_count <= self.min_hits
        out: np.ndarray = (t.since < 1) & ((t.streak >= self.min_hits) | early)
        return out
