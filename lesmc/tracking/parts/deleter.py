"""The deleter: which tracks end. ``max_age`` (``sort``): a track not updated for more
than ``max_age`` frames ends (SORT: 1); a track whose predicted box is not a box (``nan``,
where its area and aspect ratio have opposite signs) ends before association, as SORT
drops it. The covariance-trace limit (``single``, ``joint``, :class:`TraceDeleter`): a
track halts when trace(P) exceeds ``max_trace``. Pruning (``joint``,
:class:`DistanceDeleter`): refining tracks far from the primary end."""

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


@dataclass(frozen=True)
class TraceDeleter:
    """A point track ends (halts) when trace(P) exceeds ``max_trace`` (today's ``max_trace``
    of the tracker file; the paper's divergence guard)."""

    max_trace: float

    def halts(self, P: np.ndarray) -> np.ndarray:
        """Which covariances P (k, d, d) end their track."""
        out: np.ndarray = np.trace(P, axis1=1, axis2=2) > self.max_trace
        return out


@dataclass(frozen=True)
class DistanceDeleter:
    """The joint design's pruning (section 7.2): refining tracks farther than
    ``prune_radius`` from the primary end; the primary stays."""

    prune_radius: float

    def prune(
        self, at: np.ndarray, keep: np.ndarray, pos: np.ndarray, prim: np.ndarray, M: int
    ) -> tuple[np.ndarray, np.ndarray]:
        """Rows' tracks without those farther than ``prune_radius`` from the primary.

        ``at`` (rows, W) are table rows, ``pos`` their positions, ``M`` the table's
        padding row. The kept tracks move up in order; returns the trimmed ``at``
        and each row's track count.
        """
        dp = np.hypot(pos[..., 0] - prim[:, 0, None], pos[..., 1] - prim[:, 1, None])
        keep &= dp <= self.prune_radius
        keep[:, 0] = True  # the primary stays (halted or not)
        nt = keep.sum(axis=1)
        at = np.where(keep, at, M)
        gap = np.flatnonzero((keep[:, 1:] & ~keep[:, :-1]).any(axis=1))  # a kept after a dropped
        if gap.size:  # the kept tracks of those rows move up, in order
            order = np.argsort(~keep[gap], axis=1, kind="stable")
            at[gap] = np.take_along_axis(at[gap], order, axis=1)
        return at[:, : int(nt.max(initial=1))], nt
