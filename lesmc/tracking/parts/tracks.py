"""Every track of a multi-target tracker, as arrays (one row per track, in the tracker's
order: older tracks first, new ones appended)."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np


@dataclass(frozen=True)
class Tracks:
    """n tracks: Kalman means X (n, d) and covariances P (n, d, d), ids, and the counts the
    initiator and deleter read: ``hits`` (updates in all), ``streak`` (updates in a row),
    ``age`` (predictions), ``since`` (predictions since the last update; 0: updated at
    this frame)."""

    X: np.ndarray
    P: np.ndarray
    id: np.ndarray
    hits: np.ndarray
    streak: np.ndarray
    age: np.ndarray
    since: np.ndarray

    def __len__(self) -> int:
        return int(self.X.shape[0])

    @staticmethod
    def empty(d: int) -> Tracks:
        """No tracks, for states of dimension d."""
        z = np.zeros(0, dtype=np.int64)
        return Tracks(np.zeros((0, d)), np.zeros((0, d, d)), z, z, z, z, z)

    @staticmethod
    def new(X: np.ndarray, P0: np.ndarray, first_id: int) -> Tracks:
        """Tracks started at means X (k, d) with covariance P0, ids from ``first_id`` on;
        no hits yet."""
        k = len(X)
        z = np.zeros(k, dtype=np.int64)
        ids = np.arange(first_id, first_id + k, dtype=np.int64)
        P = np.broadcast_to(P0, (k, *P0.shape)).copy()
        return Tracks(np.asarray(X, dtype=float), P, ids, z, z.copy(), z.copy(), z.copy())

    def take(self, idx: np.ndarray) -> Tracks:
        """The tracks at positions (or where the mask) ``idx``."""
        return Tracks(*(a[idx] for a in self._arrays()))

    def concat(self, other: Tracks) -> Tracks:
        """These tracks, then ``other``'s."""
        pairs = zip(self._arrays(), other._arrays(), strict=True)
        return Tracks(*(np.concatenate([a, b]) for a, b in pairs))

    def _arrays(self) -> tuple[np.ndarray, ...]:
        return (self.X, self.P, self.id, self.hits, self.streak, self.age, self.since)
