"""Hashes of the joint design's states (lesmc/tracking/parts/joint_states.py): a track's
128-bit hash (its mean's bits and covariance index) and a whole state's digest, from 64-bit
words mixed with lesmc/common/mixing.py's ``mix``."""

from __future__ import annotations

import functools

import numpy as np

from lesmc.common.mixing import mix

_M64 = (1 << 64) - 1


@functools.cache
def _positions(count: int, section: int, lane: int) -> np.ndarray:
    """Per-position constants of a digest section (independent of any padding); read-only."""
    base = np.uint64((0x9E3779B97F4A7C15 * (4 * section + lane + 1)) & _M64)
    with np.errstate(over="ignore"):
        out = mix(
            np.arange(1, count + 1, dtype=np.uint64) * np.uint64(0x9E3779B97F4A7C15) + base, lane
        )
    out.flags.writeable = False
    return out


def hash_tracks(means: np.ndarray, cov: np.ndarray) -> np.ndarray:
    """A 128-bit hash (..., 2) of each track: its mean's bits (..., d) and covariance index."""
    d = means.shape[-1]
    w = np.empty((*cov.shape, d + 1), dtype=np.uint64)
    w[..., :d] = np.ascontiguousarray(means).view(np.uint64)
    w[..., d] = cov.astype(np.uint64)
    out = np.empty((*cov.shape, 2), dtype=np.uint64)
    with np.errstate(over="ignore"):
        for lane in (0, 1):
            out[..., lane] = mix(w ^ _positions(d + 1, 4, lane), lane).sum(axis=-1, dtype=np.uint64)
    return out


def state_digest(
    th: np.ndarray, width: int, ntrack: np.ndarray, pending: np.ndarray, npend: np.ndarray
) -> np.ndarray:
    """A 128-bit digest (n, 2) of each joint state from its tracks' hashes ``th`` (n, T, 2;
    T = ``width``), track counts, pending detections (n, K, 2) and their counts.

    Every word is mixed with a constant of its position and the mixed words are
    summed (mod 2⁶⁴), padding left out: the digest does not depend on how wide
    the arrays of a batch are.
    """
    n, T = len(ntrack), width
    p = np.ascontiguousarray(pending).view(np.uint64).reshape(n, pending.shape[1], 2)
    K = p.shape[1]
    tm = np.arange(T) < ntrack[:, None]
    pm = (np.arange(K) < npend[:, None])[..., None]
    zero = np.uint64(0)
    out = np.empty((n, 2), dtype=np.uint64)
    with np.errstate(over="ignore"):
        for lane in (0, 1):
            h = mix(ntrack.astype(np.uint64) ^ _positions(1, 0, lane), lane)
            h += mix(npend.astype(np.uint64) ^ _positions(1, 1, lane), lane)
            ct = _positions(T, 2, lane)
            h += np.where(tm, mix(th[..., lane] ^ ct, lane), zero).sum(axis=1, dtype=np.uint64)
            if K:
                cp = _positions(K * 2, 3, lane).reshape(K, 2)
                h += np.where(pm, mix(p ^ cp, lane), zero).sum(axis=(1, 2), dtype=np.uint64)
            out[:, lane] = h
    return out
