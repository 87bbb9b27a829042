"""The predictor and updater of a point tracker: a Kalman filter per track on the scene's
linear-Gaussian model (lesmc/tracking/kalman.py ``matrices``: the paper's constant velocity
on (x, y, vx, vy), or any model whose H measures the position), all tracks at once, with
kalman.py's batched functions (Eq. 2-3; covariances in Joseph form).

A track starts from one detection z as Stone Soup's ``SimpleMeasurementInitiator`` starts
one from a linear measurement: the measured components are z and their covariance is R,
the other components are 0 with their P0 variances, and the two blocks are uncorrelated.
"""

from __future__ import annotations

from dataclasses import dataclass, replace

import numpy as np

from lesmc.tracking.kalman import (
    Innovation,
    Matrices,
    innovations,
    mahalanobis2,
    measure,
    predict_covariances,
    predict_means,
    update_means,
)
from lesmc.tracking.parts.tracks import Tracks


@dataclass(frozen=True)
class PointFilter:
    """Predict, score and update point tracks with the model ``m``."""

    m: Matrices

    def birth_covariance(self) -> np.ndarray:
        """A new track's covariance: P0 with the measured block R, uncorrelated with the rest."""
        P = self.m.P0.copy()
        pos = list(self.m.pos)
        P[pos, :] = 0.0
        P[:, pos] = 0.0
        P[np.ix_(pos, pos)] = self.m.R
        return P

    def start(self, Z: np.ndarray, first_id: int) -> Tracks:
        """New tracks at detections ``Z`` (k, 2), ids from ``first_id`` on; the detection
        counts as the track's first hit (its ``streak`` too)."""
        X = np.zeros((len(Z), self.m.dim))
        X[:, list(self.m.pos)] = Z
        t = Tracks.new(X, self.birth_covariance(), first_id)
        one = np.ones(len(Z), dtype=np.int64)
        return replace(t, hits=one, streak=one.copy())

    def predict(self, t: Tracks) -> Tracks:
        """Every track one frame on (Eq. 2), ``age`` and ``since`` counted up, the
        ``streak`` of a track missed last frame reset."""
        return Tracks(
            predict_means(self.m, t.X),
            predict_covariances(self.m, t.P),
            t.id,
            t.hits,
            np.where(t.since > 0, 0, t.streak),
            t.age + 1,
            t.since + 1,
        )

    def innovations(self, t: Tracks) -> Innovation:
        """S, S⁻¹, K, P⁺ of every (predicted) track (Eq. 3)."""
        return innovations(self.m, t.P)

    def distances2(self, Z: np.ndarray, t: Tracks, inn: Innovation) -> np.ndarray:
        """(detections, tracks) squared Mahalanobis distances (z − Hx̂)ᵀ S⁻¹ (z − Hx̂)."""
        y = Z[:, None, :] - measure(self.m, t.X)[None, :, :]
        out: np.ndarray = mahalanobis2(y.transpose(1, 0, 2), inn.S_inv).T
        return out

    def update(self, t: Tracks, inn: Innovation, rows: np.ndarray, Z: np.ndarray) -> Tracks:
        """Tracks ``rows`` updated with detections ``Z`` (k, 2), one each (Eq. 2-3); their
        hits and streak counted up, ``since`` 0."""
        if not len(rows):
            return t
        X, P = t.X.copy(), t.P.copy()
        X[rows] = update_means(self.m, t.X[rows], inn.K[rows], Z)
        P[rows] = inn.P_post[rows]
        hits, streak, since = t.hits.copy(), t.streak.copy(), t.since.copy()
        hits[rows] += 1
        streak[rows] += 1
        since[rows] = 0
        return replace(t, X=X, P=P, hits=hits, streak=streak, since=since)

    def positions(self, t: Tracks) -> np.ndarray:
        """The tracks' positions H x (n, 2)."""
        return measure(self.m, t.X)

    def spread_inverse(self, t: Tracks) -> np.ndarray:
        """(H P Hᵀ + R)⁻¹ of every track's current covariance (n, 2, 2): the scale of the
        target's gate around a track (lesmc/tracking/gnn.py)."""
        return innovations(self.m, t.P).S_inv
