"""The data associator: global assignment of detections to tracks (GNN / Hungarian,
``scipy.optimize.linear_sum_assignment``), SORT's way.

SORT (``associate_detections_to_trackers``): when every detection and every track has at
most one pair scoring above the threshold, those pairs are the assignment; otherwise the
assignment maximising the total score over all pairs (scipy's solution among equal
totals). Pairs of that assignment scoring below the threshold are dropped. The shortcut is
part of the rule: it is not always the thresholded optimum (a pair above the threshold
wins even where two pairs below it would sum to more, then both be dropped).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np


@dataclass(frozen=True)
class Assignment:
    """The matched (detection, track) pairs (k, 2), by detection; the detections left
    unmatched, in the order SORT starts tracks on them (those the assignment left out by
    index, then those of dropped pairs); the tracks left unmatched."""

    pairs: np.ndarray
    new: np.ndarray
    missed: np.ndarray


@dataclass(frozen=True)
class GlobalAssociator:
    """Global assignment on a score matrix (larger is better) with SORT's threshold rule."""

    def assign(self, score: np.ndarray, threshold: float) -> Assignment:
        """The assignment of detections (rows) to tracks (columns) of ``score``."""
        n, m = score.shape
        pairs = np.zeros((0, 2), dtype=np.int64)
        if n and m:
            above = score > threshold
            if above.sum(axis=1).max() == 1 and above.sum(axis=0).max() == 1:
                pairs = np.argwhere(above)
            else:
                from scipy.optimize import linear_sum_assignment

                rows, cols = linear_sum_assignment(-score)
                pairs = np.stack([rows, cols], axis=1).astype(np.int64)
        low = score[pairs[:, 0], pairs[:, 1]] < threshold
        kept, dropped = pairs[~low], pairs[low]
        new = np.concatenate([np.setdiff1d(np.arange(n), pairs[:, 0]), dropped[:, 0]])
        missed = np.concatenate([np.setdiff1d(np.arange(m), pairs[:, 1]), dropped[:, 1]])
        return Assignment(kept, new.astype(np.int64), missed.astype(np.int64))
