"""Design "single": one Kalman filter with gated nearest-neighbour association (section 6.7).

A state is (x, P) plus a halted flag; states travel in batches (tracking/design.py).
For a batch, :meth:`SingleDesign.successors` returns every outcome an attacker
can force at the next frame, in rank order; rank 0 is what the unattacked
tracker does.

The design is a composition of parts (:class:`SingleParts`, docs/trackers.md
"Parts"): the Kalman predictor and updater (tracking/kalman.py), the gate
hypothesiser, the nearest-neighbour associator, the trace deleter, and the
attacker's options of lesmc/tracking/parts/attacker.py (``attack_option_rows``).

Speed: P̂, S, K, the gate and the updated P depend only on the parent's P,
which is shared by every state with the same history of updates and skips. So
covariances live in a table, what derives from each is computed once, for
all new covariances of a batch together (tracking/design.py's :class:`Gains`),
and a batch is processed with array arithmetic only: predict, the candidate
detections (an x-sorted band of the frame, or a k-d tree), gate, the attacker's
options (parts/attacker.py: attack_option_rows) and one mean update per outcome.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from lesmc.scene import Frame, Scene
from lesmc.tracking.design import Batch, CovarianceTable, GainRows, Schedule, Successors
from lesmc.tracking.kalman import (
    Matrices,
    initial_mean,
    mahalanobis2,
    matrices,
    measure,
    positions,
    predict_means,
    update_means,
    warp,
)
from lesmc.tracking.parts.associator import NearestNeighbourAssociator
from lesmc.tracking.parts.attacker import (
    OptionRows,
    attack_option_rows,
    injection_option_rows,
)
from lesmc.tracking.parts.deleter import TraceDeleter
from lesmc.tracking.parts.hypothesiser import GateHypothesiser


def carried_prediction(m: Matrices, X: np.ndarray, to_next: np.ndarray | None) -> np.ndarray:
    """States ``X`` of one frame carried into the next (its positions through the
    homography ``to_next``, None: the camera did not move), then predicted: what the
    single tracker's gate and the attacker's options are measured from."""
    if to_next is not None:
        X = X.copy()
        X[..., list(m.pos)] = warp(to_next, positions(m, X))
    return predict_means(m, X)


@dataclass(frozen=True)
class SingleParts:
    """The parts the single design is composed of (docs/trackers.md, "Parts"); its
    predictor and updater are lesmc/tracking/kalman.py's functions (through the
    Schedule's gains), its attacker's options lesmc/tracking/parts/attacker.py's
    ``attack_option_rows``."""

    hypothesiser: GateHypothesiser  # the detections within the gate, nearest first
    associator: NearestNeighbourAssociator  # the nearest visible detection, if gated
    deleter: TraceDeleter  # trace(P) > max_trace halts the track


class SingleDesign:
    """The plain tracker; ``scene`` gives detections, camera motion and the configuration;
    ``inject``: the attacker may also inject the frames' candidates (``allow hide,
    inject``; parts/attacker.py: injection_option_rows); ``hide``: it may hide detections
    (not under ``allow inject`` alone)."""

    name = "single"
    #: it takes attack action ``inject`` (lesmc/tracking/trackers.py: make_tracker)
    injects = True
    #: and ``inject grid D within R payoff P`` (candidates around its prediction)
    injects_grid = True

    def __init__(
        self,
        scene: Scene,
        inject: bool = False,
        hide: bool = True,
        grid: tuple[np.ndarray, float] | None = None,
    ) -> None:
        self.scene = scene
        self.inject = inject
        self.hide = hide
        #: ``inject grid D within R payoff P``: the grid's offsets (G, 2) from the
        #: prediction, nearest first, and P (lesmc/language/properties.py: InjectGrid)
        self.grid = grid
        self.cfg = scene.tracker
        self.m: Matrices = matrices(self.cfg, scene.dt)
        self.covariances = CovarianceTable()
        self.parts = SingleParts(
            GateHypothesiser(self.cfg.gate, self.cfg.gate_type),
            NearestNeighbourAssociator(),
            TraceDeleter(self.cfg.max_trace),
        )
        self.schedule = Schedule(
            self.m, self.cfg, self.covariances, self.parts.hypothesiser, self.parts.deleter
        )

    def initial(self) -> Batch:
        """At the target's frame: (start, velocity) with P0; that frame's detections unused."""
        t = self.scene.target
        x0 = initial_mean(self.m, t.start, t.velocity)[None]
        c0 = self.covariances.add(self.m.P0.copy())
        return Batch(x0, np.array([c0], dtype=np.int64), np.zeros(1, dtype=bool))

    def keys(self, batch: Batch) -> np.ndarray:
        """(x bits, covariance index) per state: equal rows are equal states."""
        out: np.ndarray = np.column_stack(
            [np.ascontiguousarray(batch.X).view(np.uint64), batch.cov.astype(np.uint64)]
        )
        return out

    def predict(self, X: np.ndarray, step: int, m: Matrices) -> np.ndarray:
        """Carry positions into frame ``step`` (homography of the previous frame), then predict."""
        return carried_prediction(m, X, self.scene.frame(step - 1).to_next)

    def successors(self, batch: Batch, step: int, attacked: bool) -> Successors:
        """Outcomes of moving the states of ``batch`` (none halted) to frame ``step``.

        One pass over the whole batch: what derives from each state's covariance
        (gate, S⁻¹, K, the next covariances) is computed once per distinct P and
        spread to the rows, so states with different histories share the arrays.
        """
        frame = self.scene.frame(step)
        m, gains = self.schedule.at(step)
        Xp = self.predict(batch.X, step, m)
        rows = gains.rows(batch.cov)
        src, rank, payoff, det, X, cov, halted, nis = self._rows(frame, Xp, rows, attacked, m)
        if src.size > 1 and (np.diff(src) < 0).any():  # by source, then rank
            order = np.lexsort((rank, src))
            src, rank, payoff, det = src[order], rank[order], payoff[order], det[order]
            X, cov, halted, nis = X[order], cov[order], halted[order], nis[order]
        return Successors(src, rank, payoff, det, Batch(X, cov, halted), nis)

    def _rows(
        self, frame: Frame, Xp: np.ndarray, g: GainRows, attacked: bool, m: Matrices
    ) -> tuple[np.ndarray, ...]:
        """Successors of predictions ``Xp``, row i with the gain rows ``g`` of its P."""
        at = measure(m, Xp)
        if attacked and self.inject and (frame.candidates or not self.hide or self.grid):
            return self._inject_rows(frame, Xp, at, g, m)
        idx, valid = self.parts.hypothesiser.nearest(frame, at, g.radius, wide=attacked)
        Z = frame.positions()[np.where(valid, idx, 0)]
        y = Z - at[:, None, :]
        gated = valid & self.parts.hypothesiser.test(y, g.S_inv, g.spread)
        if attacked:
            same = frame.position_ids()[np.where(valid, idx, 0)] if frame.has_repeats else None
            pays = np.full(idx.shape, np.inf)
            pays[valid] = frame.payoffs()[idx[valid]]
            opts = attack_option_rows(gated, pays, valid, same)
            row, col, payoff = opts.row, opts.col, opts.payoff
            counts = np.bincount(row, minlength=len(Xp))
            rank = np.arange(row.size) - np.repeat(np.r_[0, np.cumsum(counts)[:-1]], counts)
        else:  # the unattacked tracker: the nearest visible detection, if it passes the gate
            row = np.arange(len(Xp))
            col = self.parts.associator.assign(valid, gated)
            payoff = np.zeros(row.size)
            rank = np.zeros(row.size, dtype=np.int64)
        return self._outcomes(Xp, g, m, row, rank, payoff, col, idx, Z, y)

    def _outcomes(
        self,
        Xp: np.ndarray,
        g: GainRows,
        m: Matrices,
        row: np.ndarray,
        rank: np.ndarray,
        payoff: np.ndarray,
        col: np.ndarray,
        idx: np.ndarray,
        Z: np.ndarray,
        y: np.ndarray,
    ) -> tuple[np.ndarray, ...]:
        """The successor of each option (``row``, ``rank``, ``payoff``, column ``col`` of
        the candidates ``idx`` at ``Z``, innovations ``y``; −1: skip)."""
        upd = col >= 0
        X = Xp[row].copy()
        ru = row[upd]
        X[upd] = update_means(m, Xp[ru], g.K[ru], Z[ru, col[upd]])
        det = np.where(upd, idx[row, np.maximum(col, 0)] if idx.shape[1] else -1, -1)
        cov = np.where(upd, g.post[row], g.pred[row]).astype(np.int64)
        halted = np.where(upd, g.halt_post[row], g.halt_pred[row])
        nis = np.full(row.size, np.nan)  # the innovation's NIS yᵀ S⁻¹ y where it updates
        if ru.size:
            nis[upd] = mahalanobis2(y[ru, col[upd]], g.S_inv[ru])
        return row, rank, payoff, det, X, cov, halted, nis

    def _inject_rows(
        self, frame: Frame, Xp: np.ndarray, at: np.ndarray, g: GainRows, m: Matrices
    ) -> tuple[np.ndarray, ...]:
        """Successors at an attacked step under ``allow hide, inject``: the detections and
        the injection candidates within the gate's radius merged nearest first (a
        detection before a candidate at equal distance), each outcome at its cheapest
        cost (parts/attacker.py: injection_option_rows). The observation of an update
        with candidate j is n + j (n: the frame's detections); under ``inject grid`` the
        grid's point i (at the prediction plus its offset, within the gate's radius, a
        detection and then a candidate first at equal distance) is n + m + i (m: the
        frame's candidates)."""
        code, Z, y, opts = self._inject_columns(frame, at, g)
        row, col, payoff = opts.row, opts.col, opts.payoff
        counts = np.bincount(row, minlength=len(Xp))
        rank = np.arange(row.size) - np.repeat(np.r_[0, np.cumsum(counts)[:-1]], counts)
        return self._outcomes(Xp, g, m, row, rank, payoff, col, code, Z, y)

    def _inject_columns(
        self, frame: Frame, at: np.ndarray, g: GainRows
    ) -> tuple[np.ndarray, np.ndarray, np.ndarray, OptionRows]:
        """Under inject, each prediction's columns nearest first (code: detection i, n +
        candidate j, n + m + grid point; positions; innovations) and the options."""
        hyp = self.parts.hypothesiser
        n = len(frame.detections)
        idx_d, ok_d = hyp.nearest(frame, at, g.radius, wide=True)
        idx_c, ok_c = hyp.nearest(frame.injectable, at, g.radius, wide=True)
        w = idx_d.shape[1]
        code = np.concatenate([np.where(ok_d, idx_d, -1), np.where(ok_c, idx_c + n, -1)], axis=1)
        Z_all = np.vstack([frame.positions(), frame.injectable.positions(), np.zeros((1, 2))])
        hide_pay = frame.payoffs() if self.hide else np.full(n, np.inf)  # inf: cannot hide
        pay_all = np.r_[hide_pay, frame.injectable.payoffs(), np.inf]
        key_all = np.r_[frame.joint_position_ids(), -1]
        d = np.where(code >= 0, np.sqrt(((Z_all[code] - at[:, None, :]) ** 2).sum(axis=2)), np.inf)
        # each list keeps its own order (made monotone), a detection first at equal distance
        d[:, :w] = np.maximum.accumulate(d[:, :w], axis=1)
        d[:, w:] = np.maximum.accumulate(d[:, w:], axis=1)
        Z = Z_all[code]  # code −1: the padding row
        pay, key = pay_all[code], key_all[code]
        if self.grid is not None:
            first = n + len(frame.candidates)
            code, Z, d, pay, key = self._with_grid(code, Z, d, pay, key, at, g.radius, first)
        order = np.argsort(d, axis=1, kind="stable")
        code, Z = (
            np.take_along_axis(code, order, axis=1),
            np.take_along_axis(Z, order[..., None], 1),
        )
        pay, key = np.take_along_axis(pay, order, axis=1), np.take_along_axis(key, order, axis=1)
        valid = code >= 0
        y = Z - at[:, None, :]
        gated = valid & hyp.test(y, g.S_inv, g.spread)
        return code, Z, y, injection_option_rows(gated, pay, valid, code >= n, key)

    def attack_at(
        self, X: np.ndarray, P: np.ndarray, step: int, rank: int
    ) -> tuple[list[str], list[str]]:
        """Under inject: the ids of the detections hidden and of what is injected (a
        candidate's id or a grid point's name) by the cheapest way to force the outcome of
        rank ``rank`` from the state (``X``, ``P``) at frame ``step`` (lesmc/results/
        document.py lists them for a counterexample)."""
        frame = self.scene.frame(step)
        m, gains = self.schedule.at(step)
        g = gains.rows(np.array([self.covariances.add(np.asarray(P, dtype=float))]))
        at = measure(m, self.predict(np.asarray(X, dtype=float)[None], step, m))
        code, _, _, opts = self._inject_columns(frame, at, g)
        assert opts.via is not None
        via, row = int(opts.via[rank]), code[0]
        n, m_c = len(frame.detections), len(frame.candidates)
        hidden = [frame.detections[int(c)].id for c in row[:via] if 0 <= c < n]
        if via >= len(row) or row[via] < n:
            return hidden, []
        c = int(row[via])
        if c < n + m_c:
            return hidden, [frame.candidates[c - n].id]
        assert self.grid is not None
        dx, dy = self.grid[0][c - n - m_c].tolist()
        return hidden, [grid_point_name(frame.step, dx, dy)]

    def _with_grid(
        self,
        code: np.ndarray,
        Z: np.ndarray,
        d: np.ndarray,
        pay: np.ndarray,
        key: np.ndarray,
        at: np.ndarray,
        radius: np.ndarray,
        first: int,
    ) -> tuple[np.ndarray, ...]:
        """The columns (code, position, distance, payoff, position key) of the detections
        and candidates, then the grid's points around each prediction ``at`` within its
        gate's ``radius``: code ``first`` + i (n + m), payoff P, a key of its own unless it lies
        exactly on a detection or candidate of the row (then that one's: the same
        updated state)."""
        assert self.grid is not None
        off, price = self.grid
        G, rows = len(off), len(at)
        dist = np.broadcast_to(np.hypot(off[:, 0], off[:, 1]), (rows, G))
        ok = dist <= radius[:, None]
        gZ = at[:, None, :] + off[None, :, :]
        gkey = np.broadcast_to(first + np.arange(G), (rows, G)).copy()  # keys below: n + m
        if Z.shape[1]:
            same = ((gZ[:, :, None, :] == Z[:, None, :, :]).all(axis=3)) & (code >= 0)[:, None, :]
            hit = same.any(axis=2)
            gkey[hit] = np.take_along_axis(key, same.argmax(axis=2), axis=1)[hit]
        return (
            np.concatenate([code, np.where(ok, first + np.arange(G), -1)], axis=1),
            np.concatenate([Z, np.where(ok[..., None], gZ, 0.0)], axis=1),
            np.concatenate([d, np.where(ok, dist, np.inf)], axis=1),
            np.concatenate([pay, np.full((rows, G), float(price))], axis=1),
            np.concatenate([key, gkey], axis=1),
        )


def grid_point_name(step: int, dx: float, dy: float) -> str:
    """The observation name of ``inject grid``'s point at offset (dx, dy) px from the
    prediction at frame ``step``: ``3:grid+0-4``."""
    return f"{step}:grid{dx:+g}{dy:+g}"
