"""Cutting the CNN inputs: square windows of the current and m previous aligned frames.

N_dr sees 21x21x(m+1) windows, N_lp 45x45x(m+1) (paper sections 6.4-6.5).
Channels are ordered oldest first, current frame last; values are grey levels
scaled to [0, 1], the pixel scale in which payoffs are measured. Windows that
reach past the frame edge repeat the edge pixels.
"""

from __future__ import annotations

import numpy as np

M_PREVIOUS = 3  #: m, the previous frames a CNN sees (paper: the time a vehicle needs to cross)

#: Grey level -> the [0, 1] pixel scale of the CNNs' inputs (and of the payoffs).
SCALE = np.float32(1.0 / 255.0)


def stack(frame: np.ndarray, aligned: list[np.ndarray], m: int = M_PREVIOUS) -> list[np.ndarray]:
    """The m most recent aligned previous frames and the current one, oldest first."""
    if len(aligned) < m:
        raise ValueError(f"need {m} previous frames, have {len(aligned)}")
    return [*aligned[len(aligned) - m :], frame]


def cut(frames: list[np.ndarray], centres: np.ndarray, size: int) -> np.ndarray:
    """Windows of ``size`` x ``size`` around integer-rounded ``centres`` (n, 2) as float32.

    Returns (n, len(frames), size, size) in [0, 1]. A window inside the frame is a
    view of it (``sliding_window_view``: 4x faster than gathering every pixel); one
    that reaches past the edge gathers its pixels with the edge repeated.
    """
    n = len(centres)
    h, w = frames[0].shape
    half = size // 2
    cx = np.rint(np.asarray(centres, float)[:, 0]).astype(np.int64) if n else np.zeros(0, np.int64)
    cy = np.rint(np.asarray(centres, float)[:, 1]).astype(np.int64) if n else np.zeros(0, np.int64)
    x0, y0 = cx - half, cy - half
    inside = (x0 >= 0) & (y0 >= 0) & (x0 + size <= w) & (y0 + size <= h)
    ii, edge = np.flatnonzero(inside), np.flatnonzero(~inside)
    offs = np.arange(-half, size - half)
    xs = np.clip(cx[edge, None] + offs[None, :], 0, w - 1)  # (edge windows, size)
    ys = np.clip(cy[edge, None] + offs[None, :], 0, h - 1)
    out = np.empty((n, len(frames), size, size), np.float32)
    for c, f in enumerate(frames):
        if len(ii):
            out[ii, c] = np.lib.stride_tricks.sliding_window_view(f, (size, size))[y0[ii], x0[ii]]
        if len(edge):
            out[edge, c] = f[ys[:, :, None], xs[:, None, :]]
    out *= SCALE
    return out


def compact(windows: np.ndarray) -> np.ndarray:
    """Windows of :func:`cut` as their uint8 grey levels (a quarter of the memory): the
    frames they were cut from are uint8, so :func:`expand` gives them back bit for bit."""
    out: np.ndarray = np.rint(windows * np.float32(255.0)).astype(np.uint8)
    return out


def expand(windows: np.ndarray) -> np.ndarray:
    """Windows as :func:`cut` gives them: float32 in [0, 1] (from :func:`compact`'s uint8)."""
    if windows.dtype != np.uint8:
        return windows
    out: np.ndarray = windows.astype(np.float32)
    out *= SCALE
    return out


def origins(centres: np.ndarray, size: int) -> np.ndarray:
    """Top-left pixel (x, y) of the windows ``cut`` takes around ``centres``."""
    c: np.ndarray = np.rint(np.asarray(centres, float).reshape(-1, 2)).astype(np.int64)
    return c - size // 2
