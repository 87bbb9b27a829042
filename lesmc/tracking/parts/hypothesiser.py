"""The hypothesiser: how well each detection fits each track, and which fits are
admissible. The IoU hypothesiser (box trackers: ``sort``) scores a (detection, track) pair
by the IoU of the detection's box with the track's predicted box; a pair is admissible when
its IoU is at least ``threshold`` (SORT: 0.3). The gate hypothesiser (point trackers:
``single``, ``joint``) admits a detection whose innovation passes the Mahalanobis or
Euclidean gate (lesmc/tracking/association.py) and lists the candidates within the gate's
radius."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from lesmc.scene import Frame
from lesmc.tracking.association import gate_radii, gate_test, mahalanobis_gate
from lesmc.tracking.kalman import mahalanobis2
from lesmc.tracking.parts.boxes import iou
from lesmc.tracking.parts.groups import within


@dataclass(frozen=True)
class IouHypothesiser:
    """IoU scores (larger is better) with an admission threshold in (0, 1]."""

    threshold: float = 0.3

    def __post_init__(self) -> None:
        if not 0 < self.threshold <= 1:
            raise ValueError(f"an IoU threshold must lie in (0, 1], got {self.threshold!r}")

    def scores(self, det_boxes: np.ndarray, track_boxes: np.ndarray) -> np.ndarray:
        """(detections, tracks) IoU of every pair."""
        return iou(det_boxes, track_boxes)


@dataclass(frozen=True)
class GateHypothesiser:
    """Point trackers' hypothesiser: a detection fits a track when its innovation y passes
    the gate (lesmc/tracking/association.py): ``mahalanobis`` (Eq. 19, sqrt(yᵀ S⁻¹ y) ≤ g)
    or ``euclidean`` (‖y‖ ≤ k · sqrt(trace(H P̂ Hᵀ))). The candidates it lists are those
    within the gate's radius, nearest first (``single``) or by track then index
    (``joint``); the exact gate then decides."""

    gate: float
    gate_type: str

    def radii(self, S: np.ndarray, spread: np.ndarray) -> np.ndarray:
        """How far (Euclidean) from the prediction a detection passing the gate can lie, for
        innovation covariances S (k, 2, 2) and spreads (k,)."""
        return gate_radii(S, spread, self.gate, self.gate_type)

    def test(self, y: np.ndarray, S_inv: np.ndarray, spread: np.ndarray) -> np.ndarray:
        """Which innovations y (..., 2) pass the gate (association.gate_test)."""
        return gate_test(y, S_inv, spread, self.gate, self.gate_type)

    def nearest(
        self, frame: Frame, points: np.ndarray, radius: np.ndarray, wide: bool
    ) -> tuple[np.ndarray, np.ndarray]:
        """The detections within ``radius[i]`` of each point i, nearest first (ties: lower
        index), from the frame's k-d tree.

        Returns indices (n, k) and a validity mask; ``wide=False`` asks only for the
        nearest few (the unattacked tracker needs the nearest alone; three resolve ties).
        """
        n, m = len(points), len(frame.detections)
        if not m:
            return np.zeros((n, 0), dtype=np.int64), np.zeros((n, 0), dtype=bool)
        reach = float(radius.max()) if n else 0.0
        k = min(FIRST_K if wide else 3, m)
        idx, d2 = frame.nearest_d2(points, k, reach)
        while wide and k < m:  # rows that filled every slot ask again for twice as many
            full = np.nonzero(idx[:, -1] >= 0)[0]
            if not full.size:
                break
            k2 = min(2 * k, m)
            more_idx, more_d2 = frame.nearest_d2(points[full], k2, reach)
            idx = np.c_[idx, np.full((n, k2 - k), -1, dtype=np.int64)]
            d2 = np.c_[d2, np.full((n, k2 - k), np.inf)]
            idx[full], d2[full], k = more_idx, more_d2, k2
        # sorted by (distance, index), so each row's own radius keeps a prefix
        valid = (idx >= 0) & (np.sqrt(d2) <= radius[:, None])
        return idx, valid

    def pairs(
        self,
        Z: np.ndarray,
        at: np.ndarray,
        radius: np.ndarray,
        S_inv_all: np.ndarray,
        spread: np.ndarray,
    ) -> tuple[np.ndarray, ...]:
        """The (track, detection) pairs within each track's gate ``radius`` around its
        predicted position ``at`` (u, 2) (a little wider: the gate decides), found in the
        strip of detections sorted by x, by track then detection: track, detection, dx, dy,
        Mahalanobis d² (``S_inv_all`` (u, 2, 2) per track), and whether the gate admits the
        pair (``spread`` (u,) per track)."""
        nz = len(Z)
        r = radius * (1 + 1e-9)
        track, pz = in_strip(Z, at[:, 0], r)
        o = np.argsort(track * max(nz, 1) + pz, kind="stable")
        track, pz = track[o], pz[o]
        dx = Z[pz, 0] - at[track, 0]
        dy = Z[pz, 1] - at[track, 1]
        keep = dx * dx + dy * dy <= r[track] ** 2
        track, pz, dx, dy = track[keep], pz[keep], dx[keep], dy[keep]
        y = np.stack([dx, dy], axis=-1)
        S_inv = S_inv_all[track]
        d2 = mahalanobis2(y, S_inv)
        if self.gate_type == "mahalanobis":
            ok = mahalanobis_gate(d2, self.gate)
        else:
            ok = gate_test(y, S_inv, spread[track], self.gate, self.gate_type)
        return track, pz, dx, dy, d2, ok


#: Candidates asked of the k-d tree at first; rows that fill them all ask again for twice as many.
FIRST_K = 8


def in_strip(Z: np.ndarray, x: np.ndarray, half: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The detections Z whose x lies within ``half`` of each ``x`` (a superset of any
    circle or box of that radius around it): (owner, detection) pairs, by owner, each
    owner's in x order."""
    by_x = np.argsort(Z[:, 0], kind="stable")
    zx = Z[by_x, 0]
    first = np.searchsorted(zx, x - half, "left")
    cnt = np.searchsorted(zx, x + half, "right") - first
    return np.repeat(np.arange(x.size), cnt), by_x[np.repeat(first, cnt) + within(cnt)]
