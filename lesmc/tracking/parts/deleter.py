"""The deleter: which tracks end. ``max_age``: a track not updated for more than
``max_age`` frames ends (SORT: 1); a track whose predicted box is not a box (``nan``,
where its area and aspect ratio have opposite signs) ends before association, as SORT
drops it."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from lesmc.tracking.parts.tracks import Tracks


@dataclass(frozen=True)
class MaxAgeDeleter:
    """End tracks missed more than ``max_age`` frames in a row."""

    max_age: int = 1

    def __post_init__(self) -> None:
        if self.max_age < 0:
            raise ValueError(f"max_age must be at least 0, got {self.max_age!r}")

    def alive(self, t: Tracks) -> np.ndarray:
        """Which tracks go on after this frame."""
        out: np.ndarray = t.since <= self.max_age
        return out

    @staticmethod
    def valid(boxes: np.ndarray) -> np.ndarray:
        """Which predicted boxes (n, 4) are boxes (no ``nan``)."""
        out: np.ndarray = ~np.isnan(boxes).any(axis=1)
        return out
