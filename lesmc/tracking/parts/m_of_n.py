"""The M-of-N initiator: a track starts tentative on one detection (its first hit) and is
confirmed once it has ``min_hits`` (M) hits within its first ``window`` (N) frames, its
birth frame included; a tentative track that has not is deleted after its N-th frame.
As Stone Soup's ``MultiMeasurementInitiator`` (``min_points`` M, counting updates, the
first detection included) with a holding-track deleter that deletes a track of N states:
confirmation is decided from the frame after the birth on, after that frame's
association, and before the N-th frame's deletion."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from lesmc.tracking.parts.tracks import Tracks


@dataclass(frozen=True)
class MOfNInitiator:
    """Confirm after ``min_hits`` hits within the first ``window`` frames of a track."""

    min_hits: int = 3
    window: int = 5

    def __post_init__(self) -> None:
        if not 1 <= self.min_hits <= self.window:
            raise ValueError(
                f"M of N needs 1 <= M <= N, got M = {self.min_hits!r}, N = {self.window!r}"
            )

    def confirmed(self, t: Tracks) -> np.ndarray:
        """Which tracks are confirmed (after a frame's association, or between frames): a
        track that reached M hits at a frame after its birth stays confirmed."""
        out: np.ndarray = (t.hits >= self.min_hits) & (t.age >= 1)
        return out

    def expired(self, t: Tracks) -> np.ndarray:
        """Which tentative tracks end after this frame: those in their N-th frame or later
        (``age`` + 1 frames since their birth, its frame included)."""
        out: np.ndarray = ~self.confirmed(t) & (t.age + 1 >= self.window)
        return out
