"""Boxes [x1, y1, x2, y2] and a box tracker's measurement z = (cx, cy, s, r) (SORT: s the
area, r the aspect ratio w/h), and the intersection over union of two sets of boxes.
Written as SORT writes them (the same operations in the same order), so that thresholds
decide alike."""

from __future__ import annotations

import numpy as np


def to_z(boxes: np.ndarray) -> np.ndarray:
    """Boxes (n, 4) -> measurements (n, 4): centre, area w·h, aspect ratio w/h."""
    w = boxes[:, 2] - boxes[:, 0]
    h = boxes[:, 3] - boxes[:, 1]
    return np.stack([boxes[:, 0] + w / 2.0, boxes[:, 1] + h / 2.0, w * h, w / h], axis=1)


def to_boxes(X: np.ndarray) -> np.ndarray:
    """Box states (n, ≥ 4: cx, cy, s, r, ...) -> boxes (n, 4): w = sqrt(s·r), h = s/w
    (``nan`` where s·r < 0; the deleter drops such a track)."""
    with np.errstate(invalid="ignore", divide="ignore"):
        w = np.sqrt(X[:, 2] * X[:, 3])
        h = X[:, 2] / w
    cx, cy = X[:, 0], X[:, 1]
    return np.stack([cx - w / 2.0, cy - h / 2.0, cx + w / 2.0, cy + h / 2.0], axis=1)


#: Pairs of boxes :func:`iou` computes in one block: its temporaries (about ten arrays of
#: this many floats, 20 MB) stay bounded whatever the frames' sizes; the (n, m) result is
#: all that grows (two frames of 3,000 boxes: 72 MB, not 583 MB).
IOU_BLOCK = 1 << 18


def iou(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """IoU (n, m) of boxes ``a`` (n, 4) with boxes ``b`` (m, 4), computed in blocks of rows
    of at most :data:`IOU_BLOCK` pairs (each entry as if computed at once)."""
    rows = max(1, IOU_BLOCK // max(len(b), 1))
    if len(a) <= rows:
        return _iou(a, b)
    out = np.empty((len(a), len(b)))
    for i in range(0, len(a), rows):
        out[i : i + rows] = _iou(a[i : i + rows], b)
    return out


def _iou(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    A, B = a[:, None, :], b[None, :, :]
    xx1 = np.maximum(A[..., 0], B[..., 0])
    yy1 = np.maximum(A[..., 1], B[..., 1])
    xx2 = np.minimum(A[..., 2], B[..., 2])
    yy2 = np.minimum(A[..., 3], B[..., 3])
    wh = np.maximum(0.0, xx2 - xx1) * np.maximum(0.0, yy2 - yy1)
    area_a = (A[..., 2] - A[..., 0]) * (A[..., 3] - A[..., 1])
    area_b = (B[..., 2] - B[..., 0]) * (B[..., 3] - B[..., 1])
    out: np.ndarray = wh / (area_a + area_b - wh)
    return out
