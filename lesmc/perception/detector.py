"""The whole detector of the paper's Figure 4, frame by frame.

Front end -> candidates Q_bc -> N_dr keeps the windows that hold a moving
vehicle (Q_dr) -> a blob of Q_dr that is larger than ``big_px`` or closer than
``close_px`` to another goes to N_lp, whose map peaks are the vehicles (or,
with no peak, the blob itself: the paper's "default blob"); every other blob
is output directly. Each detection remembers the Q_dr blob it came from: that
blob's N_dr window is what an attacker perturbs to hide it (see attacks.py).

Injection candidates (issue 61): with ``DetectorConfig.inject_within`` R, the
candidates of Q_bc that N_dr rejects and whose centroid lies within R px of one of
the frame's detections, nearest first, at most ``inject_cap`` a frame, and that
would be output directly once accepted (not crowded: :func:`near_rejected`), are kept
with their N_dr windows: where an attacker can make a vehicle appear by perturbing
that window until N_dr accepts it (priced in run.py, ``towards="inject"``).
"""

from __future__ import annotations

from contextlib import AbstractContextManager, nullcontext
from dataclasses import dataclass, field

import numpy as np
import torch
from scipy.spatial import cKDTree

from lesmc.perception.blobs import Blobs
from lesmc.perception.cnn import DR_SIZE, LP_SIZE, LP_STRIDE, Nets
from lesmc.perception.frontend import FrontEnd, FrontEndConfig, FrontEndOutput
from lesmc.perception.neurons import UnitMaxima
from lesmc.perception.threads import in_lanes
from lesmc.perception.windows import cut, origins, stack

#: Windows per forward pass. Small batches keep each layer's activations in the
#: caches of a CPU: N_dr over 6,000 windows takes 0.21 s in batches of 384 against
#: 0.67 s in batches of 2,048, N_lp 4x less time in batches of 64 than of 512. A
#: window's answer does not depend on its batch, up to float32 rounding where oneDNN
#: picks another kernel for a batch's shape (the default video's scene came out the
#: same bytes; docs/performance.md, "The main job").
DR_BATCH = 384
LP_BATCH = 64


@dataclass(frozen=True)
class DetectorConfig:
    """Detector settings beyond the front end's and the networks' thresholds."""

    frontend: FrontEndConfig = field(default_factory=FrontEndConfig)
    big_px: int = 20  #: a blob wider or taller than this may hold several vehicles
    close_px: float = 10.0  #: blobs nearer than this may be pieces of one vehicle or a queue
    merge_px: float = 3.0  #: N_lp peaks nearer than this are one vehicle
    batch: int = DR_BATCH  #: N_dr windows per forward pass
    #: keep the rejected candidates within this many px of a detection as injection
    #: candidates (None: none kept)
    inject_within: float | None = None
    #: at most this many injection candidates a frame, nearest a detection first
    inject_cap: int = 32


@dataclass
class FrameDetections:
    """The detections of one frame and what the attack needs to hide each of them."""

    index: int
    positions: np.ndarray  # (n, 2) x, y
    source: np.ndarray  # (n,) row of ``windows`` (the Q_dr blob) each detection came from
    via_lp: np.ndarray  # (n,) True when N_lp located it
    #: (b, m+1, 21, 21) N_dr inputs of the source blobs: float32, or uint8 grey levels
    #: when kept compact (windows.compact; windows.expand gives the float32 back)
    windows: np.ndarray
    from_prev: np.ndarray  # homography from the previous frame's pixels to this frame's
    n_candidates: int  # |Q_bc|
    n_accepted: int  # |Q_dr|
    #: the rows of Q_bc that N_dr accepts, in the order of ``windows`` (None: not kept)
    accepted: np.ndarray | None = None
    #: injection candidates (``DetectorConfig.inject_within``): rows of Q_bc N_dr rejects
    rejected: np.ndarray = field(default_factory=lambda: np.zeros(0, np.int64))
    #: (c, 2) their centroids and (c, m+1, 21, 21) their N_dr windows (emptied once priced)
    rejected_positions: np.ndarray = field(default_factory=lambda: np.zeros((0, 2)))
    rejected_windows: np.ndarray = field(
        default_factory=lambda: np.zeros((0, 0, DR_SIZE, DR_SIZE), np.float32)
    )


def dr_probability(
    nets: Nets, windows: np.ndarray, batch: int = DR_BATCH, side_by_side: bool = True
) -> np.ndarray:
    """P(vehicle) of N_dr for (n, m+1, 21, 21) windows; batches side by side, each on one
    torch thread (:func:`~lesmc.perception.threads.in_lanes`; not ``side_by_side`` while
    forward hooks that are not thread-safe record the units' maxima)."""

    def one(a: int) -> np.ndarray:
        with torch.inference_mode():
            logits = nets.dr(torch.from_numpy(windows[a : a + batch]))
            out: np.ndarray = torch.softmax(logits, dim=1)[:, 1].numpy()
            return out

    parts = in_lanes(one, range(0, len(windows), batch), side_by_side)
    return np.concatenate([np.empty(0, np.float32), *parts])


def lp_maps(
    nets: Nets, windows: np.ndarray, batch: int = LP_BATCH, side_by_side: bool = True
) -> np.ndarray:
    """N_lp maps (n, 15, 15) for (n, m+1, 45, 45) windows (batches as :func:`dr_probability`)."""

    def one(a: int) -> np.ndarray:
        with torch.inference_mode():
            out: np.ndarray = nets.lp(torch.from_numpy(windows[a : a + batch])).numpy()
            return out

    parts = in_lanes(one, range(0, len(windows), batch), side_by_side)
    return np.concatenate([np.empty((0, 15, 15), np.float32), *parts])


def peaks(maps: np.ndarray, threshold: float) -> list[np.ndarray]:
    """Per map, the local maxima above ``threshold`` as window pixel (x, y) and value.

    A cell covers 3x3 input pixels; the position is refined by the value-weighted
    centroid of the cell's 3x3 neighbourhood.
    """
    t = torch.from_numpy(maps)[:, None]
    pooled = torch.nn.functional.max_pool2d(t, 3, stride=1, padding=1)[:, 0].numpy()
    result = []
    padded = np.pad(maps, ((0, 0), (1, 1), (1, 1)))
    for i in range(len(maps)):
        ys, xs = np.nonzero((maps[i] >= pooled[i]) & (maps[i] > threshold))
        rows = []
        for y, x in zip(ys, xs, strict=True):
            nb = padded[i, y : y + 3, x : x + 3]
            w = nb.sum()
            dy = float((nb.sum(axis=1) * np.array([-1, 0, 1])).sum() / w)
            dx = float((nb.sum(axis=0) * np.array([-1, 0, 1])).sum() / w)
            rows.append(((x + dx) * LP_STRIDE + 1, (y + dy) * LP_STRIDE + 1, float(maps[i, y, x])))
        result.append(np.array(rows, float).reshape(-1, 3))
    return result


def crowded_blobs(cents: np.ndarray, boxes: np.ndarray, big_px: int, close_px: float) -> np.ndarray:
    """Blobs that may hold several vehicles or a piece of one (section 6.6): to N_lp."""
    crowded: np.ndarray = (boxes[:, 2] > big_px) | (boxes[:, 3] > big_px)
    if len(cents) > 1:
        d, _ = cKDTree(cents).query(cents, k=2)
        crowded |= d[:, 1] < close_px
    return crowded


def near_rejected(
    cand: Blobs,
    accepted: np.ndarray,
    rejected: np.ndarray,
    positions: np.ndarray,
    cfg: DetectorConfig,
) -> np.ndarray:
    """The ``rejected`` rows of Q_bc (``cand``) within ``cfg.inject_within`` px of one of
    ``positions`` (the frame's detections), nearest first (ties: the lower row), at most
    ``cfg.inject_cap``: the injection candidates a frame offers. A candidate that, once
    accepted, would go to N_lp (:func:`crowded_blobs`: larger than ``big_px``, or within
    ``close_px`` of an accepted blob, which would then go to N_lp too) is left out: where
    its detection would appear is N_lp's to say, not its centroid."""
    if not len(rejected) or not len(positions) or cfg.inject_within is None:
        return np.zeros(0, np.int64)
    big = (cand.box[rejected, 2] > cfg.big_px) | (cand.box[rejected, 3] > cfg.big_px)
    close = np.zeros(len(rejected), bool)
    if len(accepted):
        d_acc, _ = cKDTree(cand.centroid[accepted]).query(cand.centroid[rejected])
        close = d_acc < cfg.close_px
    d, _ = cKDTree(positions).query(cand.centroid[rejected])
    near = np.flatnonzero((d <= cfg.inject_within) & ~big & ~close)
    cap = cfg.inject_cap
    order = near[np.lexsort((rejected[near], d[near]))][:cap]
    out: np.ndarray = rejected[order].astype(np.int64)
    return out


class Detector:
    """Runs front end and CNNs on a video, one ``push`` per frame."""

    def __init__(
        self, nets: Nets, cfg: DetectorConfig | None = None, record_maxima: bool = False
    ) -> None:
        self.nets = nets
        self.cfg = cfg or DetectorConfig()
        if self.cfg.frontend.history < nets.settings.m:
            raise ValueError(f"history L={self.cfg.frontend.history} < m={nets.settings.m}")
        self.frontend = FrontEnd(self.cfg.frontend)
        #: with ``record_maxima``, each hidden unit's largest value on the windows scored
        #: (a stuck-at-max fault's: perception's run keeps them); else None
        self.maxima = UnitMaxima(nets) if record_maxima else None

    def _recording(self) -> AbstractContextManager[None]:
        return self.maxima.recording() if self.maxima is not None else nullcontext()

    def push(self, frame: np.ndarray) -> tuple[FrontEndOutput, FrameDetections] | None:
        out = self.frontend.push(frame)
        if out is None:
            return None
        return out, self.detect(out)

    def detect(self, out: FrontEndOutput) -> FrameDetections:
        """N_dr on every candidate, N_lp on the crowded ones (Figure 4)."""
        cfg, nets = self.cfg, self.nets
        frames = stack(out.frame, out.aligned.frames, nets.settings.m)
        cand = out.candidates
        win = cut(frames, cand.centroid, DR_SIZE)
        with self._recording():
            probability = dr_probability(nets, win, cfg.batch, self.maxima is None)
        keep = np.flatnonzero(probability > nets.settings.delta_dr)
        every = win
        cents, boxes, win = cand.centroid[keep], cand.box[keep], win[keep]
        crowded = crowded_blobs(cents, boxes, cfg.big_px, cfg.close_px)
        pos: list[np.ndarray] = [cents[~crowded]]
        src: list[np.ndarray] = [np.flatnonzero(~crowded)]
        lp: list[np.ndarray] = [np.zeros(int((~crowded).sum()), bool)]
        rows = np.flatnonzero(crowded)
        if len(rows):
            p, s = self._locate(frames, cents[rows], boxes[rows], rows)
            pos.append(p)
            src.append(s)
            lp.append(np.ones(len(p), bool))
        positions = np.concatenate(pos).reshape(-1, 2)
        rejected = np.zeros(0, np.int64)
        if cfg.inject_within is not None:
            rows_out = np.flatnonzero(probability <= nets.settings.delta_dr)
            rejected = near_rejected(cand, keep, rows_out, positions, cfg)
        return FrameDetections(
            index=out.index,
            positions=positions,
            source=np.concatenate(src).astype(int),
            via_lp=np.concatenate(lp),
            windows=win,
            from_prev=out.registration.homography,
            n_candidates=len(cand),
            n_accepted=len(keep),
            accepted=keep,
            rejected=rejected,
            rejected_positions=cand.centroid[rejected].reshape(-1, 2).astype(float),
            rejected_windows=every[rejected],
        )

    def _locate(
        self, frames: list[np.ndarray], cents: np.ndarray, boxes: np.ndarray, rows: np.ndarray
    ) -> tuple[np.ndarray, np.ndarray]:
        """N_lp peaks inside each crowded blob's box (3 px margin), merged across blobs."""
        with self._recording():
            maps = lp_maps(self.nets, cut(frames, cents, LP_SIZE), LP_BATCH, self.maxima is None)
        org = origins(cents, LP_SIZE)
        found: list[tuple[float, float, float, int]] = []
        for i, pk in enumerate(peaks(maps, self.nets.settings.delta_lp)):
            x0, y0, bw, bh = boxes[i]
            xy = pk[:, :2] + org[i]
            inside = (
                (xy[:, 0] >= x0 - 3)
                & (xy[:, 0] <= x0 + bw + 2)
                & (xy[:, 1] >= y0 - 3)
                & (xy[:, 1] <= y0 + bh + 2)
            )
            if inside.any():
                found += [
                    (x, y, v, int(rows[i]))
                    for (x, y), v in zip(xy[inside], pk[inside, 2], strict=True)
                ]
            else:  # the paper's "default blob": keep the blob itself
                found.append((float(cents[i, 0]), float(cents[i, 1]), 0.0, int(rows[i])))
        found.sort(key=lambda r: -r[2])
        kept: list[tuple[float, float, float, int]] = []
        for r in found:  # greedy merge, strongest peak first
            if all((r[0] - k[0]) ** 2 + (r[1] - k[1]) ** 2 >= self.cfg.merge_px**2 for k in kept):
                kept.append(r)
        arr = np.array([(r[0], r[1]) for r in kept], float).reshape(-1, 2)
        return arr, np.array([r[3] for r in kept], int)
