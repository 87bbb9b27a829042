"""Background model: the per-pixel median of the L previous frames aligned to the current one.

Paper section 6.2. Eq. 14 writes a mean but the text says median; the median
is used here (a vehicle present in fewer than half of the L frames does not
enter the background, a mean would leave a ghost of it). Alignment follows
Eq. 15: one registration per frame, older frames reached by chaining
``h_k^{k-i} = h_k^{k-1} h_{k-1}^{k-i}``; each raw previous frame is warped once
per use, so interpolation blur does not accumulate.
"""

from __future__ import annotations

from collections import deque
from dataclasses import dataclass

import cv2
import numpy as np


@dataclass
class Aligned:
    """The previous frames warped into the current frame, oldest first, and where all are valid."""

    frames: list[np.ndarray]
    valid: np.ndarray  # uint8 mask, 255 where every aligned frame has data


class FrameHistory:
    """The last ``length`` raw frames and the homographies taking each to the newest frame."""

    def __init__(self, length: int) -> None:
        self.length = length
        self.frames: deque[np.ndarray] = deque(maxlen=length)
        self.to_current: deque[np.ndarray] = deque(maxlen=length)

    def full(self) -> bool:
        return len(self.frames) == self.length

    def advance(self, h: np.ndarray) -> None:
        """A new frame arrived whose homography from the newest stored frame is ``h`` (Eq. 15)."""
        for i, m in enumerate(self.to_current):
            self.to_current[i] = h @ m

    def push(self, frame: np.ndarray) -> None:
        """Store the newest frame (after ``advance`` has re-aimed the older ones at it)."""
        self.frames.append(frame)
        self.to_current.append(np.eye(3))

    def aligned(self, size: tuple[int, int]) -> Aligned:
        """Warp every stored frame into the current frame's pixels."""
        width, height = size
        valid = np.full((height, width), 255, np.uint8)
        covered = np.empty_like(valid)  # one buffer for every frame's footprint
        out = []
        for frame, m in zip(self.frames, self.to_current, strict=True):
            out.append(cv2.warpPerspective(frame, m, (width, height), flags=cv2.INTER_LINEAR))
            corners = np.array(
                [
                    [0, 0],
                    [frame.shape[1], 0],
                    [frame.shape[1], frame.shape[0]],
                    [0, frame.shape[0]],
                ],
                np.float32,
            )
            quad = cv2.perspectiveTransform(corners[None], m)[0]
            covered.fill(0)
            cv2.fillConvexPoly(covered, np.round(quad).astype(np.int32), 255)
            cv2.bitwise_and(valid, covered, dst=valid)
        # a pixel next to the edge of a warped frame mixes in the border value
        cv2.erode(valid, np.ones((5, 5), np.uint8), dst=valid)
        return Aligned(out, valid)


def median(frames: list[np.ndarray]) -> np.ndarray:
    """Per-pixel median of uint8 frames (an even count averages the two middle values).

    A compare-exchange sorting network on whole images: much faster than
    ``np.median`` for the handful of frames used here, and no float copy.
    """
    if not frames:
        raise ValueError("median of no frames")
    vals = [f.copy() for f in frames]
    n = len(vals)
    for rnd in range(n):  # odd-even transposition sort
        for i in range(rnd % 2, n - 1, 2):
            lo = np.minimum(vals[i], vals[i + 1])
            np.maximum(vals[i], vals[i + 1], out=vals[i + 1])
            vals[i] = lo
    if n % 2:
        return vals[n // 2]
    a, b = vals[n // 2 - 1], vals[n // 2]
    mid: np.ndarray = ((a.astype(np.uint16) + b + 1) >> 1).astype(np.uint8)
    return mid


def gain(median_bg: np.ndarray, frame: np.ndarray, valid: np.ndarray) -> float:
    """The factor that brings the median ``median_bg`` to ``frame``'s mean brightness over
    ``valid`` (1 where the median is black): it removes slow illumination drift between
    the L frames and now."""
    m_bg = cv2.mean(median_bg, mask=valid)[0]
    m_fr = cv2.mean(frame, mask=valid)[0]
    return float(m_fr / m_bg) if m_bg > 1.0 else 1.0


def background(aligned: Aligned, frame: np.ndarray) -> np.ndarray:
    """The median background, rescaled to the current frame's mean brightness (:func:`gain`;
    a gain of 1 leaves the uint8 median as it is, uncopied)."""
    bg = median(aligned.frames)
    alpha = gain(bg, frame, aligned.valid)
    if alpha == 1.0:
        return bg
    out: np.ndarray = cv2.convertScaleAbs(bg, alpha=alpha)
    return out
