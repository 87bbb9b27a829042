"""The initiator: which tracks start, and which the tracker outputs (confirms).

``min_hits`` (M of N with M = N; ``sort``): SORT outputs a track at a frame when it was
updated at that frame and its streak of updates is at least ``min_hits``, or the frame is
among the first ``min_hits`` (every detection starts a track; the detector's unmatched
ones start new tracks). Births near the target (``joint``, :class:`NearTargetInitiator`):
a free detection near the primary starts a refining track when a pending detection of the
previous frame lies close enough."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from lesmc.tracking.parts.groups import within
from lesmc.tracking.parts.hypothesiser import in_strip
from lesmc.tracking.parts.tracks import Tracks


@dataclass(frozen=True)
class MinHitsInitiator:
    """SORT's output rule with ``min_hits`` ≥ 1."""

    min_hits: int = 3

    def __post_init__(self) -> None:
        if self.min_hits < 1:
            raise ValueError(f"min_hits must be at least 1, got {self.min_hits!r}")

    def confirmed(self, t: Tracks, frame_count: int) -> np.ndarray:
        """Which tracks are output at the ``frame_count``-th frame (1 for the first)."""
        early = frame_count <= self.min_hits
        out: np.ndarray = (t.since < 1) & ((t.streak >= self.min_hits) | early)
        return out


@dataclass(frozen=True)
class NearTargetInitiator:
    """The joint design's births near the target (section 7.2): a detection no track took,
    within ``init_radius`` of the updated primary, starts a refining track when a previous
    unassociated detection lies within ``init_distance`` (their difference over dt is its
    velocity); otherwise it stays pending for the next step."""

    init_radius: float
    init_distance: float

    def near(self, Z: np.ndarray, start: tuple[float, float]) -> np.ndarray:
        """The detections Z (z, 2) within ``init_radius`` of ``start``: the first frame's
        pending detections."""
        near = Z[np.hypot(*(Z - np.array(start)).T) <= self.init_radius] if len(Z) else Z
        out: np.ndarray = near.reshape(-1, 2)
        return out

    def in_region(self, Z: np.ndarray, centres: np.ndarray) -> np.ndarray:
        """(c, z) whether each detection of Z lies in the birth region (within
        ``init_radius``, the test of :meth:`candidates`, a hair wider) of each updated
        primary position ``centres`` (c, 2): a superset of the detections that can be
        born or kept pending there."""
        d = np.hypot(Z[None, :, 0] - centres[:, 0, None], Z[None, :, 1] - centres[:, 1, None])
        out: np.ndarray = d <= self.init_radius * (1 + 1e-9) + 1e-9
        return out

    def candidates(
        self,
        Z: np.ndarray,
        prim: np.ndarray,
        free: np.ndarray,
        pend: np.ndarray,
        npend: np.ndarray,
    ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """The free detections within ``init_radius`` of each row's updated primary ``prim``
        (by row, then detection index) and the pending detection each starts a track with
        (-1: none). One round per candidate, in index order: the nearest remaining pending
        detection (first of equals) closer than ``init_distance``."""
        R = len(prim)
        box = self.init_radius * (1 + 1e-9)
        # candidates from the strip of detections sorted by x (a little wider), then the
        # exact box and circle tests
        cr, cz = in_strip(Z, prim[:, 0], box + 1e-6 * (box + np.abs(prim[:, 0])))
        ddx = Z[cz, 0] - prim[cr, 0]
        ddy = Z[cz, 1] - prim[cr, 1]
        ok = free[cr, cz] & (np.abs(ddx) <= box) & (np.abs(ddy) <= box)
        ok[ok] = np.hypot(ddx[ok], ddy[ok]) <= self.init_radius
        o = np.flatnonzero(ok)
        o = o[np.argsort(cr[o] * max(len(Z), 1) + cz[o], kind="stable")]
        cr, cz = cr[o], cz[o]  # by row, then detection index
        nc = np.bincount(cr, minlength=R)
        k = within(nc)
        pool = np.arange(pend.shape[1]) < npend[:, None]
        partner = np.full(cr.size, -1, dtype=np.int64)
        todo = np.asarray(pool[cr].any(axis=1))
        by_k = np.argsort(k, kind="stable")
        bounds = np.searchsorted(k[by_k], np.arange(int(k.max(initial=-1)) + 2))
        for j in range(len(bounds) - 1):
            sel = by_k[bounds[j] : bounds[j + 1]]
            sel = sel[todo[sel]]
            rows = cr[sel]
            sel, rows = sel[pool[rows].any(axis=1)], rows[pool[rows].any(axis=1)]
            if not sel.size:
                continue
            z = Z[cz[sel]]
            dd = np.hypot(z[:, 0, None] - pend[rows, :, 0], z[:, 1, None] - pend[rows, :, 1])
            dd = np.where(pool[rows], dd, np.inf)
            b = np.argmin(dd, axis=1)
            hit = dd[np.arange(sel.size), b] < self.init_distance
            partner[sel[hit]] = b[hit]
            pool[rows[hit], b[hit]] = False
        return cr, cz, partner


def still_pending(
    Z: np.ndarray, ur: np.ndarray, uz: np.ndarray, R: int
) -> tuple[np.ndarray, np.ndarray]:
    """Each row's pending detections: the candidates (ur, uz) that started no track, in order."""
    npd = np.bincount(ur, minlength=R)
    pending = np.zeros((R, int(npd.max(initial=0)), 2))
    pending[ur, within(npd)] = Z[uz]
    return pending, npd
