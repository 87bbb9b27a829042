"""The report's crops (issue 60, round 3): a detector file's replay records perturbations of
any size; the report draws the frame's crop of that size at the recorded origin, zero
outside the frame (lesmc.report.figures.crop), and N_dr's 21x21 patch is that crop."""

from __future__ import annotations

import numpy as np

from lesmc.report import figures


def _padded(img: np.ndarray, left: int, top: int, w: int, h: int, pad: int = 50) -> np.ndarray:
    big = np.pad(img.astype(float), pad)
    return big[top + pad : top + pad + h, left + pad : left + pad + w]


def test_crop_is_the_zero_padded_window() -> None:
    img = np.arange(40 * 30, dtype=float).reshape(30, 40)
    for left, top, w, h in [(0, 0, 17, 17), (-5, -3, 12, 9), (30, 25, 17, 11), (10, 4, 1, 1)]:
        assert np.array_equal(figures.crop(img, left, top, w, h), _padded(img, left, top, w, h))


def test_patch_is_the_21x21_crop_around_the_centre() -> None:
    img = np.random.default_rng(0).integers(0, 256, (30, 40)).astype(float)
    for cx, cy in [(3.4, 2.6), (20.0, 15.0), (38.7, 29.2)]:
        want = _padded(img, round(cx) - 10, round(cy) - 10, 21, 21)
        assert np.array_equal(figures.patch(img, (cx, cy)), want)
