"""Design "single": one Kalman filter with gated nearest-neighbour association (section 6.7).

A tracker state is (x, P) plus a halted flag. :meth:`SingleDesign.options`
returns every outcome an attacker can force at the next frame, in rank order;
option 0 is what the unattacked tracker does.

Speed: P̂, S, K and the updated P depend only on the parent's P (which is
shared by every state with the same history of updates and skips), so they
are computed once per distinct P and cached; a successor then costs one
mean update, and the detections near the prediction come from a k-d tree.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from lesmc.tracking.association import attack_options, gate_mask, gate_radius
from lesmc.tracking.design import Outcome, merge_equal
from lesmc.tracking.kalman import (
    Innovation,
    Matrices,
    innovation,
    matrices,
    predict_means,
    update_means,
    warp,
)
from lesmc.tracking.scene import Frame, Scene


@dataclass(frozen=True, eq=False)
class SingleState:
    """ρ = (s, P) of one Kalman filter."""

    x: np.ndarray
    P: np.ndarray
    halted: bool = False

    def estimate(self) -> tuple[np.ndarray, np.ndarray]:
        return self.x, self.P

    def key(self) -> bytes:
        """Exact identity, so coinciding states can be shared."""
        return self.x.tobytes() + self.P.tobytes()


@dataclass(frozen=True)
class _Covariance:
    """Everything that depends on the parent's P only (Eq. 2-3 and the gate)."""

    P_pred: np.ndarray
    inn: Innovation
    radius: float
    halt_pred: bool
    halt_post: bool


class SingleDesign:
    """The plain tracker; ``scene`` gives detections, camera motion and the configuration."""

    name = "single"

    def __init__(self, scene: Scene) -> None:
        self.scene = scene
        self.cfg = scene.tracker
        self.m: Matrices = matrices(self.cfg, scene.dt)
        self._cov: dict[bytes, _Covariance] = {}

    def initial(self) -> SingleState:
        """At the target's frame: (start, velocity) with P0; that frame's detections unused."""
        t = self.scene.target
        return SingleState(np.array([*t.start, *t.velocity], dtype=float), self.m.P0.copy())

    def covariance(self, P: np.ndarray) -> _Covariance:
        """Predict and gain for a parent covariance, cached by value."""
        key = P.tobytes()
        c = self._cov.get(key)
        if c is None:
            m, cfg = self.m, self.cfg
            P_pred = m.F @ P @ m.F.T + m.Q
            inn = innovation(m, P_pred)
            c = _Covariance(
                P_pred,
                inn,
                gate_radius(inn, P_pred, cfg.gate, cfg.gate_type),
                float(np.trace(P_pred)) > cfg.max_trace,
                float(np.trace(inn.P_post)) > cfg.max_trace,
            )
            self._cov[key] = c
        return c

    def _predict(self, X: np.ndarray, step: int) -> np.ndarray:
        """Carry positions into frame ``step`` (homography of the previous frame), then predict."""
        to_next = self.scene.frame(step - 1).to_next
        if to_next is not None:
            X = X.copy()
            X[..., :2] = warp(to_next, X[..., :2])
        return predict_means(X, self.scene.dt)

    def options(self, st: SingleState, step: int) -> list[Outcome]:
        """All attacker-forced outcomes of moving from frame ``step − 1`` to ``step``."""
        cfg = self.cfg
        c = self.covariance(st.P)
        x_pred = self._predict(st.x, step)
        frame = self.scene.frame(step)
        near = frame.near(x_pred[:2], c.radius)
        skip = Outcome(SingleState(x_pred, c.P_pred, c.halt_pred), None, 0.0)
        if not near:
            return [skip]
        Z = frame.positions()[near]
        y = Z - x_pred[:2]
        dist = np.sqrt(y[:, 0] ** 2 + y[:, 1] ** 2)
        gated = gate_mask(y, c.inn, c.P_pred, cfg.gate, cfg.gate_type)
        opts = attack_options(dist, gated, frame.payoffs()[near])
        rows = [o.detection for o in opts if o.detection is not None]
        X = update_means(x_pred, c.inn.K, Z[rows]) if rows else None
        out: list[Outcome] = []
        r = 0
        for o in opts:
            if o.detection is None:
                out.append(Outcome(skip.state, None, o.payoff))
            else:
                assert X is not None
                det = frame.detections[near[o.detection]]
                out.append(Outcome(SingleState(X[r], c.inn.P_post, c.halt_post), det.id, o.payoff))
                r += 1
        return merge_equal(out)

    @staticmethod
    def _nearest(frame: Frame, points: np.ndarray, radius: float) -> np.ndarray:
        """Index of the nearest detection within ``radius`` of each point (−1: none).

        Distances as in :meth:`options`; ties go to the lowest detection index.
        The k-d tree proposes the 3 nearest, which are re-ranked with that arithmetic.
        """
        idx = frame.nearest(points, 3, radius)  # (n, 3), −1 where fewer
        valid = idx >= 0
        if not valid.any():
            return np.full(len(points), -1)
        y = frame.positions()[np.where(valid, idx, 0)] - points[:, None, :]
        dist = np.where(valid, np.sqrt(y[..., 0] ** 2 + y[..., 1] ** 2), np.inf)
        key = np.where(valid, idx, np.iinfo(np.int64).max)
        best = np.lexsort((key, dist), axis=1)[:, 0]
        rows = np.arange(len(points))
        out: np.ndarray = np.where(valid[rows, best], idx[rows, best], -1)
        return out

    def unattacked(self, states: list[SingleState], step: int) -> list[Outcome]:
        """The rank-minimal outcome (no attack) of many states at once: ``options(st)[0]``.

        Nearest detection (ties: lowest index), gate, update or skip; the same
        arithmetic as :meth:`options`, batched over states that share P.
        """
        cfg = self.cfg
        frame = self.scene.frame(step)
        Zall = frame.positions()
        Xp_all = self._predict(np.array([s.x for s in states], dtype=float).reshape(-1, 4), step)
        groups: dict[bytes, list[int]] = {}
        for i, s in enumerate(states):
            groups.setdefault(s.P.tobytes(), []).append(i)
        out: list[Outcome | None] = [None] * len(states)
        for members in groups.values():
            c = self.covariance(states[members[0]].P)
            Xp = Xp_all[members]
            picks = self._nearest(frame, Xp[:, :2], c.radius)
            has = picks >= 0
            ok = np.zeros(len(members), dtype=bool)
            if has.any():
                y = Zall[picks[has]] - Xp[has, :2]
                ok[has] = gate_mask(y, c.inn, c.P_pred, cfg.gate, cfg.gate_type)
            Xu = update_means(Xp[ok], c.inn.K, Zall[picks[ok]]) if ok.any() else None
            r = 0
            for i, g in enumerate(members):
                if ok[i]:
                    assert Xu is not None
                    det = frame.detections[int(picks[i])]
                    out[g] = Outcome(SingleState(Xu[r], c.inn.P_post, c.halt_post), det.id, 0.0)
                    r += 1
                else:
                    out[g] = Outcome(SingleState(Xp[i], c.P_pred, c.halt_pred), None, 0.0)
        return out  # type: ignore[return-value]
