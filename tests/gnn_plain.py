"""An independent plain-Python ``gnn`` tracker (no lesmc code): the brute-force oracle of
the exact gnn attacks (tests/test_gnn_attack.py), itself checked against Stone Soup
(tests/gnn_reference.py) there. Written from the semantics of docs/trackers.md ("The gnn
preset"), state in Stone Soup's order [x, vx, y, vy], one track at a time."""

from __future__ import annotations

import copy
import math
from dataclasses import dataclass, field
from typing import Any

import numpy as np
from scipy.optimize import linear_sum_assignment
from scipy.stats import chi2

H = np.array([[1.0, 0.0, 0.0, 0.0], [0.0, 0.0, 1.0, 0.0]])


@dataclass
class Track:
    id: int
    x: np.ndarray
    P: np.ndarray
    hits: int = 1
    states: int = 1
    since: int = 0
    confirmed: bool = False


@dataclass
class Plain:
    """The gnn tracker of ``p`` (tests/gnn_reference.py ``Params``)."""

    p: Any
    tracks: list[Track] = field(default_factory=list)
    next_id: int = 1

    def copy(self) -> Plain:
        return copy.deepcopy(self)

    def _models(self) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        dt, q = self.p.dt, self.p.sigma_q**2
        f = np.array([[1.0, dt], [0.0, 1.0]])
        qb = q * np.array([[dt**3 / 3, dt**2 / 2], [dt**2 / 2, dt]])
        F, Q = np.zeros((4, 4)), np.zeros((4, 4))
        F[:2, :2] = F[2:, 2:] = f
        Q[:2, :2] = Q[2:, 2:] = qb
        return F, Q, np.eye(2) * self.p.sigma_r**2

    def _gnn(self, idx: list[int], Z: np.ndarray, dets: list[int]) -> list[tuple[int, int]]:
        """(track, detection) pairs of the global nearest neighbour assignment."""
        _, _, R = self._models()
        gate = math.sqrt(chi2.ppf(self.p.gate_probability, 2))
        d = np.full((len(idx), len(dets)), np.inf)
        for a, i in enumerate(idx):
            t = self.tracks[i]
            S = H @ t.P @ H.T + R
            for b, j in enumerate(dets):
                y = Z[j] - H @ t.x
                v = math.sqrt(float(y @ np.linalg.solve(S, y)))
                if v < gate:
                    d[a, b] = v
        rows = [a for a in range(len(idx)) if np.isfinite(d[a]).any()]
        if not rows:
            return []
        cost = np.full((len(rows), len(dets) + len(rows)), np.inf)
        for r, a in enumerate(rows):
            cost[r, : len(dets)] = d[a]
            cost[r, len(dets) + r] = gate
        rr, cc = linear_sum_assignment(cost)
        return [(idx[rows[r]], dets[c]) for r, c in zip(rr, cc, strict=True) if c < len(dets)]

    def _update(self, i: int, z: np.ndarray) -> None:
        _, _, R = self._models()
        t = self.tracks[i]
        S = H @ t.P @ H.T + R
        K = t.P @ H.T @ np.linalg.inv(S)
        t.x = t.x + K @ (z - H @ t.x)
        t.P = (np.eye(4) - K @ H) @ t.P
        t.hits += 1
        t.since = 0

    def step(self, Z: np.ndarray) -> dict[int, tuple[np.ndarray, np.ndarray]]:
        """One frame: the output tracks {id: (position, H P Hᵀ + R)}."""
        F, Q, R = self._models()
        for t in self.tracks:
            t.x, t.P = F @ t.x, F @ t.P @ F.T + Q
            t.states += 1
            t.since += 1
        free = list(range(len(Z)))
        conf = [i for i, t in enumerate(self.tracks) if t.confirmed]
        for i, j in self._gnn(conf, Z, free):
            self._update(i, Z[j])
            free.remove(j)
        gone = {i for i in conf if self.tracks[i].since > self.p.max_age}
        tent = [i for i, t in enumerate(self.tracks) if not t.confirmed]
        for i, j in self._gnn(tent, Z, free):
            self._update(i, Z[j])
            free.remove(j)
        for i in tent:
            t = self.tracks[i]
            if t.hits >= self.p.min_hits:
                t.confirmed = True
            elif t.states >= self.p.confirm_window:
                gone.add(i)
        self.tracks = [t for i, t in enumerate(self.tracks) if i not in gone]
        _, _, svx, svy = self.p.P0_sd  # x, y: R at birth
        for j in free:
            P = np.diag([0.0, svx**2, 0.0, svy**2])
            P[np.ix_([0, 2], [0, 2])] = R
            x = np.array([Z[j][0], 0.0, Z[j][1], 0.0])
            self.tracks.append(Track(self.next_id, x, P))
            self.next_id += 1
        return {t.id: (H @ t.x, H @ t.P @ H.T + R) for t in self.tracks if t.confirmed}
