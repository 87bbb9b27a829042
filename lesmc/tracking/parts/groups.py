"""Flattened groupings: consecutive groups of given sizes, as the batched trackers lay out
their rows (a state's options, a track's candidates)."""

from __future__ import annotations

import numpy as np


def starts(counts: np.ndarray) -> np.ndarray:
    """Where each group of a flattened grouping begins, for group sizes ``counts``."""
    out: np.ndarray = np.cumsum(counts) - counts
    return out


def within(counts: np.ndarray) -> np.ndarray:
    """Each element's position within its group, for consecutive groups of sizes ``counts``."""
    out: np.ndarray = np.arange(int(counts.sum())) - np.repeat(starts(counts), counts)
    return out
