"""Box-list detectors on whole frames: decoding (B, N, 5) rows, and payoffs by attack.

Decoding (docs/detectors.md, "Boxes"): a row [x1, y1, x2, y2, raw] is a candidate
when its score (``score`` of the detector file applied to ``raw``) is ``>=
threshold``; candidates are taken by decreasing score (of equal scores, the earlier
row first), and one is dropped when its IoU with a box already kept is ``>
iou_nms``. Detections come in the order of their rows; detection K of frame k is
``k:K``, at its box's centre, with the box's width and height.

Payoffs: a detection is hidden when no row of the perturbed frame's output has
IoU ``>= 0.5`` with the detection's box and a score ``>= threshold`` (before
non-maximum suppression: so no decoded box does either). The attack (DeepFool or
the PGD minimum-norm search, attacks.py) runs on the whole frame, on the margin
*largest raw score of the rows overlapping the box by IoU >= 0.5 − the threshold's
raw value* (which rows overlap is read at each step); each perturbation is checked
by decoding the perturbed frame. Box detectors get no certified bounds.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass, replace
from typing import TYPE_CHECKING, Any

import numpy as np
import torch
from torch import nn

if TYPE_CHECKING:
    from lesmc.perception.attack_settings import AttackConfig
    from lesmc.perception.detector_file import LoadedDetector
    from lesmc.scene import Footage

#: IoU with a detection's box from which a row still counts as that detection.
HIDE_IOU = 0.5


@dataclass(frozen=True)
class BoxDetections:
    """One frame's detections: frame index, (n, 4) boxes [x1, y1, x2, y2], (n,) scores,
    (n,) the network's rows they came from; their payoffs once priced."""

    index: int
    boxes: np.ndarray
    scores: np.ndarray
    rows: np.ndarray
    payoffs: np.ndarray | None = None  #: (n,) inf: unattackable; None: unpriced

    @property
    def positions(self) -> np.ndarray:
        """(n, 2) the boxes' centres."""
        return np.asarray((self.boxes[:, :2] + self.boxes[:, 2:]) / 2)


def iou(box: np.ndarray, boxes: np.ndarray) -> np.ndarray:
    """(n,) IoU of one [x1, y1, x2, y2] box with each of (n, 4) boxes (0 for empty boxes)."""
    b = np.asarray(boxes, dtype=np.float64).reshape(-1, 4)
    a = np.asarray(box, dtype=np.float64)
    w = np.clip(np.minimum(a[2], b[:, 2]) - np.maximum(a[0], b[:, 0]), 0, None)
    h = np.clip(np.minimum(a[3], b[:, 3]) - np.maximum(a[1], b[:, 1]), 0, None)
    inter = w * h
    union = _area(a) + _area(b) - inter
    with np.errstate(invalid="ignore", divide="ignore"):
        return np.where(union > 0, inter / union, 0.0)


def _area(c: np.ndarray) -> np.ndarray:
    """Boxes' areas (0 where empty)."""
    w = np.clip(c[..., 2] - c[..., 0], 0, None)
    return np.asarray(w * np.clip(c[..., 3] - c[..., 1], 0, None))


def decode_boxes(raw: np.ndarray, det: LoadedDetector, index: int) -> BoxDetections:
    """Frame ``index``'s detections from the network's (N, 5) rows (module docstring)."""
    from lesmc.perception.detector_file import score_of

    rows = np.asarray(raw, dtype=np.float64).reshape(-1, 5)
    sc = score_of(rows[:, 4], det.spec.score)
    cand = np.nonzero(sc >= det.spec.threshold)[0]
    order = cand[np.argsort(-sc[cand], kind="stable")]
    kept: list[int] = []
    for r in order:
        if kept and bool((iou(rows[r, :4], rows[kept, :4]) > det.spec.iou_nms).any()):
            continue
        kept.append(int(r))
    idx = np.array(sorted(kept), dtype=np.int64)
    return BoxDetections(index, rows[idx, :4], sc[idx], idx)


def run_boxes(
    frames: Any,
    det: LoadedDetector,
    on_frame: Callable[[], None] | None = None,
    price: Callable[[np.ndarray, BoxDetections], BoxDetections] | None = None,
) -> list[BoxDetections]:
    """The box detector on every frame, one frame a batch; with ``price``, the payoffs."""
    from lesmc.perception.heatmap import frame_input

    out = []
    for i in range(len(frames)):
        arr = frame_input(frames, i, det)
        bd = detect_boxes(arr, det, i)
        out.append(bd if price is None else price(arr, bd))
        if on_frame is not None:
            on_frame()
    return out


def detect_boxes(arr: np.ndarray, det: LoadedDetector, index: int) -> BoxDetections:
    """Frame ``index``'s detections: the network on its input ``arr`` (1, C, H, W), decoded."""
    with torch.no_grad():
        y = det.net.module(torch.from_numpy(arr))
    return decode_boxes(y[0].double().numpy(), det, index)


def price_boxes(
    det: LoadedDetector,
    frame: np.ndarray,
    bd: BoxDetections,
    cfg: AttackConfig,
    save: Callable[[int, np.ndarray], None] | None = None,
) -> BoxDetections:
    """``bd`` with each detection's payoff (``inf`` when the attack finds no perturbation
    that hides it); ``save(K, delta)`` gets each hiding perturbation (float32 (1, C, H, W),
    input units)."""
    return replace(bd, payoffs=price_box_list(det, frame, bd.boxes, cfg, save))


def price_box_list(
    det: LoadedDetector,
    frame: np.ndarray,
    boxes: np.ndarray,
    cfg: AttackConfig,
    save: Callable[[int, np.ndarray], None] | None = None,
) -> np.ndarray:
    """(n,) the payoffs of hiding the (n, 4) ``boxes`` of one frame (:func:`price_boxes`;
    ``save(K, delta)``, K a box's place in ``boxes``). Each box's attack and validation are
    its own, so a box priced alone (``lesmc verify`` on demand,
    lesmc/perception/file_pricing.py) gets the payoff it gets with the others."""
    from lesmc.perception.attacks import payoffs
    from lesmc.perception.heatmap_attack import SLACK, raw_threshold

    out = np.full(len(boxes), np.inf)
    t = raw_threshold(det)
    lo, hi = det.spec.scale
    if math.isfinite(t):
        base_u = ((frame - lo) / (hi - lo)).astype(np.float32)
        for k, box in enumerate(boxes):
            hide = _BoxHide(det, box, t - SLACK * max(1.0, abs(t)))
            res = payoffs(hide, base_u, 0.5, replace(cfg, norm="l2"))
            if not bool(res.flipped[0]):
                continue
            delta = (np.float32(hi - lo) * res.perturbation).astype(np.float32)
            if hidden(det, frame + delta, box):
                out[k] = float(np.sqrt((delta.astype(np.float64) ** 2).sum()))
                if save is not None:
                    save(k, delta)
    return out


def hidden(det: LoadedDetector, x: np.ndarray, box: np.ndarray) -> bool:
    """No row of the network's output on the whole frame ``x`` overlaps ``box`` by IoU
    ``>=`` :data:`HIDE_IOU` with a score ``>= threshold``."""
    from lesmc.perception.detector_file import score_of

    with torch.no_grad():
        y = det.net.module(torch.from_numpy(np.ascontiguousarray(x, np.float32)))
    rows = y[0].double().numpy().reshape(-1, 5)
    live = score_of(rows[:, 4], det.spec.score) >= det.spec.threshold
    return not bool((live & (iou(box, rows[:, :4]) >= HIDE_IOU)).any())


class _BoxHide(nn.Module):
    """Two "logits" ``[0, m]`` of a frame in [0, 1] units: ``m`` = the largest raw score of
    the rows overlapping ``box`` by IoU >= :data:`HIDE_IOU` − ``t`` (−1 when none does;
    which rows overlap is read at each call, without gradient)."""

    def __init__(self, det: LoadedDetector, box: np.ndarray, t: float) -> None:
        super().__init__()
        self.det, self.box, self.t = det, box, t

    def forward(self, x_u: torch.Tensor) -> torch.Tensor:
        lo, hi = self.det.spec.scale
        y = self.det.net.module(lo + (hi - lo) * x_u)
        with torch.no_grad():
            near = np.stack([iou(self.box, r[:, :4]) >= HIDE_IOU for r in y.double().numpy()])
        score = y[:, :, 4]
        raw = torch.where(torch.from_numpy(near), score, torch.full_like(score, -math.inf))
        best = raw.amax(dim=1)
        m = torch.where(torch.isfinite(best), best - self.t, torch.full_like(best, -1.0))
        return torch.stack([torch.zeros_like(m), m], dim=1)


def footage_of_boxes(
    dets: list[BoxDetections],
    det: LoadedDetector,
    dt: float,
    source: str,
    attack: dict[str, Any] | None = None,
) -> Footage:
    """A scene without a target: step k holds frame k's detections ``k:K`` at their boxes'
    centres, with the boxes' widths and heights (scene format 2), and their payoffs."""
    from lesmc.scene import Footage, Frame, TrackerConfig

    frames = tuple(
        Frame(
            bd.index,
            tuple(_detection(bd, k) for k in range(len(bd.boxes))),
        )
        for bd in dets
    )
    meta: dict[str, Any] = {
        "source": source,
        "detector": det.spec.describe(),
        "detector_file": det.spec.to_meta(),
    }
    if attack is None:
        meta["payoffs"] = "unpriced (give -o to price a detector file's detections)"
    else:
        meta["attack"] = attack
    return Footage(dt, frames, TrackerConfig(), meta)


def _detection(bd: BoxDetections, k: int) -> Any:
    """Detection ``k`` of ``bd``: its box's centre, width and height (a point where the box
    is empty)."""
    from lesmc.scene import Detection

    x1, y1, x2, y2 = (float(v) for v in bd.boxes[k])
    pay = float("nan") if bd.payoffs is None else float(bd.payoffs[k])
    w, h = (x2 - x1, y2 - y1) if x2 > x1 and y2 > y1 else (None, None)
    return Detection(f"{bd.index}:{k}", (x1 + x2) / 2, (y1 + y2) / 2, pay, None, w, h)
