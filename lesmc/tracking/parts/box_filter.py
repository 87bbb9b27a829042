"""The predictor and updater of a box tracker: a Kalman filter per track on SORT's box
model (lesmc/tracking/kalman.py ``sort_box``), all tracks at once, with kalman.py's
batched functions (Eq. 2-3; covariances in Joseph form, as filterpy's)."""

from __future__ import annotations

from dataclasses import dataclass, replace

import numpy as np

from lesmc.tracking.kalman import (
    Matrices,
    innovations,
    predict_covariances,
    predict_means,
    sort_box,
    update_means,
)
from lesmc.tracking.parts.boxes import to_boxes, to_z
from lesmc.tracking.parts.tracks import Tracks

#: Components of the box state (kalman.BOX_STATE) the area rule reads.
S, VS = 2, 6


@dataclass(frozen=True)
class BoxFilter:
    """Predict and update box tracks. SORT's one rule beyond the Kalman filter: a track
    whose area would not stay positive (s + vs ≤ 0) has its area velocity set to 0 first
    (``vs *= 0``, kept in the track's state)."""

    m: Matrices

    @staticmethod
    def sort() -> BoxFilter:
        """SORT's model and noise."""
        return BoxFilter(sort_box())

    def start(self, boxes: np.ndarray, first_id: int) -> Tracks:
        """New tracks at ``boxes`` (k, 4): mean (z, 0, 0, 0), covariance P0, ids from
        ``first_id`` on."""
        X = np.zeros((len(boxes), self.m.dim))
        X[:, :4] = to_z(boxes)
        return Tracks.new(X, self.m.P0, first_id)

    def predict(self, t: Tracks) -> Tracks:
        """Every track one frame on (Eq. 2): the means and covariances predicted, ``age``
        and ``since`` counted up, the ``streak`` of a track missed last frame reset."""
        X = t.X.copy()
        stall = X[:, VS] + X[:, S] <= 0
        X[stall, VS] *= 0.0
        return Tracks(
            predict_means(self.m, X),
            predict_covariances(self.m, t.P),
            t.id,
            t.hits,
            np.where(t.since > 0, 0, t.streak),
            t.age + 1,
            t.since + 1,
        )

    def update(self, t: Tracks, rows: np.ndarray, boxes: np.ndarray) -> Tracks:
        """Tracks ``rows`` updated with ``boxes`` (k, 4), one each (Eq. 2-3); their hits and
        streak counted up, ``since`` 0."""
        if not len(rows):
            return t
        inn = innovations(self.m, t.P[rows])
        X, P = t.X.copy(), t.P.copy()
        X[rows] = update_means(self.m, t.X[rows], inn.K, to_z(boxes))
        P[rows] = inn.P_post
        hits, streak, since = t.hits.copy(), t.streak.copy(), t.since.copy()
        hits[rows] += 1
        streak[rows] += 1
        since[rows] = 0
        return replace(t, X=X, P=P, hits=hits, streak=streak, since=since)

    @staticmethod
    def boxes(t: Tracks) -> np.ndarray:
        """The tracks' boxes (n, 4) [x1, y1, x2, y2]."""
        return to_boxes(t.X)
