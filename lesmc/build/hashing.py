"""Exact sharing of coinciding states while unfolding: 64-bit hashes in sorted runs.

States are identified by rows of 64-bit words (a design's ``keys``); their hash
(:func:`splitmix`) finds equal rows among those already made, and a collision
falls back to comparing the words themselves (lesmc/build/unfold.py).
"""

from __future__ import annotations

import numpy as np


def splitmix(words: np.ndarray) -> np.ndarray:
    """One 64-bit hash per row of 64-bit words (splitmix64 finaliser, folded over columns)."""
    h = np.zeros(words.shape[0], dtype=np.uint64)
    with np.errstate(over="ignore"):
        for j in range(words.shape[1]):
            h ^= words[:, j] + np.uint64(0x9E3779B97F4A7C15) + (h << np.uint64(6))
            h ^= h >> np.uint64(30)
            h *= np.uint64(0xBF58476D1CE4E5B9)
            h ^= h >> np.uint64(27)
            h *= np.uint64(0x94D049BB133111EB)
            h ^= h >> np.uint64(31)
    return h


class HashIndex:
    """Model indices by 64-bit state hash, as sorted runs of arrays (no per-state objects).

    New entries come as a run of their own; runs of similar size are merged, so
    a lookup searches O(log n) sorted arrays and every entry is copied O(log n)
    times in all (a log-structured merge).
    """

    def __init__(self) -> None:
        self._runs: list[tuple[np.ndarray, np.ndarray]] = []  # (sorted hashes, indices)

    def find(self, h: np.ndarray) -> np.ndarray:
        """The index stored under each hash of ``h``, −1 where there is none."""
        out = np.full(h.shape, -1, dtype=np.int64)
        for keys, vals in self._runs:
            at = np.minimum(np.searchsorted(keys, h), len(keys) - 1)
            hit = keys[at] == h
            out[hit] = vals[at[hit]]
        return out

    def add(self, h: np.ndarray, idx: np.ndarray) -> None:
        """Store ``idx`` under the (new, distinct) hashes ``h``."""
        order = np.argsort(h, kind="stable")
        self._runs.append((h[order], idx[order].astype(np.int64)))
        while len(self._runs) > 1 and 2 * len(self._runs[-1][0]) >= len(self._runs[-2][0]):
            (k2, v2), (k1, v1) = self._runs.pop(), self._runs.pop()
            keys, vals = np.concatenate([k1, k2]), np.concatenate([v1, v2])
            order = np.argsort(keys, kind="stable")
            self._runs.append((keys[order], vals[order]))
