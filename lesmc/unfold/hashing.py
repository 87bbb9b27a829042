"""Exact sharing of coinciding states while unfolding: 64-bit hashes in sorted runs.

States are identified by rows of 64-bit words (a design's ``keys``); their hash
(:func:`row_hash`) finds equal rows among those already made, and a collision
falls back to comparing the words themselves (lesmc/unfold/unfold.py).
"""

from __future__ import annotations

import functools

import numpy as np

from lesmc.common.mixing import mix


@functools.cache
def _multipliers(width: int) -> np.ndarray:
    """One odd 64-bit multiplier per word position (the same in every run); read-only."""
    with np.errstate(over="ignore"):
        out = mix(np.arange(1, width + 1, dtype=np.uint64) * np.uint64(0x9E3779B97F4A7C15))
    out |= np.uint64(1)
    out.flags.writeable = False
    return out


def row_hash(words: np.ndarray) -> np.ndarray:
    """One 64-bit hash per row of 64-bit words: the words times odd multipliers, summed
    modulo 2^64, then splitmix64's finaliser (lesmc/common/mixing.py). A handful of array
    operations whatever the width (small batches pay numpy's per-call cost, not the
    words); equal rows hash equally, and a collision only costs the exact comparison
    that follows it."""
    words = words.view(np.uint64)  # int64 or float64 words: the same bits
    return mix((words * _multipliers(words.shape[1])).sum(axis=1, dtype=np.uint64))


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
