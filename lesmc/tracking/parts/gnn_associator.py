"""The global nearest neighbour associator (GNN): the assignment of detections to tracks
of least total distance, where leaving a track unassigned costs the gate's distance, by
``scipy.optimize.linear_sum_assignment``, as Stone Soup's ``GNNWith2DAssignment`` sets it
up: one row per track with at least one admissible detection, one column per detection
and one "missed" column per such row (the gate on its diagonal, ∞ elsewhere); ∞ marks an
inadmissible pair. Tracks without an admissible detection are missed without entering the
problem."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from lesmc.tracking.parts.associator import Assignment


@dataclass(frozen=True)
class GnnAssociator:
    """Global nearest neighbour assignment on distances (smaller is better)."""

    def assign(self, dist: np.ndarray, gate: float) -> Assignment:
        """The assignment of detections (rows of ``dist``, (n, m), ∞: inadmissible) to
        tracks (columns); ``gate`` is a missed track's cost. Unmatched detections are
        listed in their order, pairs by detection."""
        n, m = dist.shape
        live = np.flatnonzero(np.isfinite(dist).any(axis=0)) if n else np.zeros(0, np.int64)
        pairs = np.zeros((0, 2), dtype=np.int64)
        if live.size:
            from scipy.optimize import linear_sum_assignment

            k = live.size
            cost = np.full((k, n + k), np.inf)
            cost[:, :n] = dist[:, live].T
            cost[np.arange(k), n + np.arange(k)] = gate
            rows, cols = linear_sum_assignment(cost)
            hit = cols < n
            pairs = np.stack([cols[hit], live[rows[hit]]], axis=1).astype(np.int64)
            pairs = pairs[np.argsort(pairs[:, 0], kind="stable")]
        new = np.setdiff1d(np.arange(n), pairs[:, 0]).astype(np.int64)
        missed = np.setdiff1d(np.arange(m), pairs[:, 1]).astype(np.int64)
        return Assignment(pairs, new, missed)
