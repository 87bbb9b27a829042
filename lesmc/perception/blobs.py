"""Background subtraction, morphology and connected blobs: the candidate set Q_bc.

Paper Eq. 16: pixels where ``|I_bg - I_k| > delta_bc``, then morphology (an
optional closing, then an area opening that drops blobs below ``min_area``
pixels), then blobs with their statistics (centroid, box, area, contrast).
"""

from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np

from lesmc.perception import DELTA_BC


@dataclass(frozen=True)
class BlobConfig:
    """Subtraction threshold and blob filters."""

    delta_bc: int = DELTA_BC  #: grey levels
    close_px: int = 1  #: odd closing kernel size; 1 = no closing (see docs/perception.md)
    min_area: int = 3  #: area opening: blobs of fewer pixels are noise

    def __post_init__(self) -> None:
        # an even kernel has no centre and shifts every blob by half a pixel
        if self.close_px < 1 or self.close_px % 2 == 0:
            raise ValueError("close_px must be a positive odd number")


@dataclass(frozen=True)
class Blobs:
    """Candidates as parallel arrays (one row per blob)."""

    centroid: np.ndarray  # (n, 2) x, y
    box: np.ndarray  # (n, 4) x, y, w, h
    area: np.ndarray  # (n,)
    contrast: np.ndarray  # (n,) mean |difference| inside the blob

    def __len__(self) -> int:
        return len(self.area)

    @staticmethod
    def empty() -> Blobs:
        return Blobs(np.zeros((0, 2)), np.zeros((0, 4), int), np.zeros(0, int), np.zeros(0))


def foreground(
    frame: np.ndarray, bg: np.ndarray, valid: np.ndarray, cfg: BlobConfig
) -> tuple[np.ndarray, np.ndarray]:
    """The absolute difference image and the cleaned foreground mask P_bc."""
    diff = cv2.absdiff(frame, bg)
    _, mask = cv2.threshold(diff, cfg.delta_bc, 255, cv2.THRESH_BINARY)
    cv2.bitwise_and(mask, valid, dst=mask)
    if cfg.close_px > 1:
        kernel = cv2.getStructuringElement(cv2.MORPH_CROSS, (cfg.close_px, cfg.close_px))
        mask = cv2.morphologyEx(mask, cv2.MORPH_CLOSE, kernel)
    return diff, mask


def blobs(mask: np.ndarray, diff: np.ndarray, cfg: BlobConfig) -> Blobs:
    """Connected components (8-neighbourhood) of the mask with at least ``min_area`` pixels."""
    n, labels, stats, cents = cv2.connectedComponentsWithStats(mask, connectivity=8)
    keep = np.flatnonzero(stats[1:, cv2.CC_STAT_AREA] >= cfg.min_area) + 1
    if len(keep) == 0:
        return Blobs.empty()
    fg = np.flatnonzero(mask)  # the blobs' pixels only, not the whole frame
    sums = np.bincount(labels.ravel()[fg], weights=diff.ravel()[fg], minlength=n)
    area = stats[keep, cv2.CC_STAT_AREA]
    return Blobs(
        centroid=cents[keep].astype(float),
        box=stats[keep, :4].astype(int),
        area=area.astype(int),
        contrast=sums[keep] / area,
    )
