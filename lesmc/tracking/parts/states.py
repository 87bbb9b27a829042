"""Batches of multi-target tracker states as padded arrays: the states the unfolder of a
multi-target design keeps, level by level (lesmc/unfold/multi.py; docs/trackers.md, "The
multi-target model").

A state is every track (mean, covariance, id, hits, streak, age, since), the next id,
the frames seen, and the id of the target's track at the last step it existed (−1: never
yet; what ``switches`` compares with). n states with at most T tracks are arrays (n, T,
...); slot j of state i holds a track when j < ``count[i]`` and padding (zeros, id −1)
after. Covariances are indices into a :class:`~lesmc.tracking.design.CovarianceTable`:
SORT's P depends only on a track's history of hits and misses, so few are distinct.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from lesmc.tracking.design import CovarianceTable
from lesmc.tracking.parts.tracks import Tracks

#: The per-track count arrays of :class:`Tracks`, in order.
COUNTS = ("hits", "streak", "age", "since")


@dataclass(frozen=True)
class MultiBatch:
    """n multi-target states (see the module's docstring)."""

    X: np.ndarray  # (n, T, d) means
    cov: np.ndarray  # (n, T) covariance table indices
    id: np.ndarray  # (n, T) track ids, −1 in padding
    counts: np.ndarray  # (n, T, 4) hits, streak, age, since
    count: np.ndarray  # (n,) tracks per state
    next_id: np.ndarray  # (n,)
    frames: np.ndarray  # (n,)
    last: np.ndarray  # (n,) the target's last track id, −1: none yet

    def __len__(self) -> int:
        return int(self.count.shape[0])

    @staticmethod
    def pack(
        states: Sequence[tuple[Tracks, int, int, int]], d: int, table: CovarianceTable
    ) -> MultiBatch:
        """States given as (tracks, next id, frames seen, the target's last id), their
        covariances added to ``table``."""
        n, T = len(states), max((len(s[0]) for s in states), default=0)
        X = np.zeros((n, T, d))
        cov = np.zeros((n, T), dtype=np.int64)
        ids = np.full((n, T), -1, dtype=np.int64)
        counts = np.zeros((n, T, len(COUNTS)), dtype=np.int64)
        for i, (t, *_) in enumerate(states):
            k = len(t)
            X[i, :k] = t.X
            cov[i, :k] = table.add_many(t.P)
            ids[i, :k] = t.id
            counts[i, :k] = np.stack([getattr(t, c) for c in COUNTS], axis=1)
        rest = np.array([s[1:] for s in states], dtype=np.int64).reshape(n, 3)
        count = np.array([len(s[0]) for s in states], dtype=np.int64)
        return MultiBatch(X, cov, ids, counts, count, rest[:, 0], rest[:, 1], rest[:, 2])

    def tracks(self, i: int, table: CovarianceTable) -> Tracks:
        """State ``i``'s tracks."""
        k = int(self.count[i])
        d = self.X.shape[2]
        P = table.stack()[self.cov[i, :k]] if k else np.zeros((0, d, d))
        c = self.counts[i, :k]
        return Tracks(self.X[i, :k].copy(), P.copy(), self.id[i, :k].copy(), *(c.T.copy()))

    def take(self, idx: np.ndarray) -> MultiBatch:
        """The states at positions ``idx``."""
        return MultiBatch(
            self.X[idx],
            self.cov[idx],
            self.id[idx],
            self.counts[idx],
            self.count[idx],
            self.next_id[idx],
            self.frames[idx],
            self.last[idx],
        )

    def words(self, width: int) -> np.ndarray:
        """Each state's exact identity as a row of 64-bit words (n, w), with ``width`` ≥ T
        track slots (the same ``width`` makes rows of different batches comparable):
        equal rows iff equal states (same tracks in the same order, bit for bit)."""
        n, T, _ = self.X.shape
        if width < T:
            raise ValueError(f"width {width} < {T} tracks")
        pad = width - T
        X = np.pad(self.X, ((0, 0), (0, pad), (0, 0))).view(np.uint64).reshape(n, -1)
        per = np.concatenate([self.cov[..., None], self.id[..., None], self.counts], axis=2)
        per = np.pad(per, ((0, 0), (0, pad), (0, 0)), constant_values=-1)
        head = np.stack([self.count, self.next_id, self.frames, self.last], axis=1)
        return np.concatenate([head.view(np.uint64), X, per.reshape(n, -1).view(np.uint64)], 1)


def distinct_rows(words: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Each row's class among the distinct rows of ``words`` (n, w), numbered in order of
    first sight, and each class's first row: exact (the rows' bytes are the keys)."""
    raw, w = np.ascontiguousarray(words).tobytes(), words.shape[1] * words.itemsize
    seen: dict[bytes, int] = {}
    rank = np.fromiter(
        (seen.setdefault(raw[i * w : (i + 1) * w], len(seen)) for i in range(len(words))),
        dtype=np.int64,
        count=len(words),
    )
    first = np.full(len(seen), len(words), dtype=np.int64)
    np.minimum.at(first, rank, np.arange(len(words)))
    return rank, first
