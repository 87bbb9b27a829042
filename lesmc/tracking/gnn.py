"""The ``gnn`` preset: a multi-target point tracker composed of parts (docs/trackers.md,
"The gnn preset"), as Stone Soup's ``MultiTargetTracker`` with a
``MultiMeasurementInitiator`` runs it.

One frame: every track is predicted; the confirmed tracks take detections by global
nearest neighbour on the Mahalanobis distance inside the χ² gate (the hypothesiser and
associator parts); confirmed tracks missed more than ``max_age`` frames end; the
tentative tracks take the detections left, the same way; a tentative track with
``min_hits`` hits is confirmed, one in its ``confirm_window``-th frame without them ends;
every detection still left starts a tentative track (ids from a counter, 1 first, in the
detections' order). The tracker outputs its confirmed tracks (updated or coasting).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from lesmc.common.errors import UsageError
from lesmc.model.identity import NONE, target_track
from lesmc.scene import Footage, Frame, Scene
from lesmc.scene.scene import m_of_n_problem
from lesmc.tracking.kalman import Matrices, mahalanobis2, matrices
from lesmc.tracking.multi import ComposedDesign, FrameTracks, MultiState, follow
from lesmc.tracking.parts.deleter import MaxAgeDeleter
from lesmc.tracking.parts.gnn_associator import GnnAssociator
from lesmc.tracking.parts.m_of_n import MOfNInitiator
from lesmc.tracking.parts.mahalanobis import MahalanobisHypothesiser
from lesmc.tracking.parts.point_filter import PointFilter
from lesmc.tracking.parts.tracks import Tracks


@dataclass(frozen=True)
class PointFrameTracks(FrameTracks):
    """A point tracker's tracks after a frame (``boxes``: positions (n, 2)) and each
    track's (H P Hᵀ + R)⁻¹, the scale of the target's gate around it."""

    spread_inv: np.ndarray


@dataclass(frozen=True)
class GnnTracker:
    """A point filter, a Mahalanobis hypothesiser, a GNN associator, an M-of-N initiator
    and a ``max_age`` deleter."""

    filter: PointFilter
    hypothesiser: MahalanobisHypothesiser
    associator: GnnAssociator
    initiator: MOfNInitiator
    deleter: MaxAgeDeleter

    def initial(self) -> MultiState:
        """No tracks before the first frame."""
        return MultiState(Tracks.empty(self.filter.m.dim))

    def step(self, state: MultiState, Z: np.ndarray) -> tuple[MultiState, PointFrameTracks]:
        """One frame with detections ``Z`` (k, 2): the next state and its tracks."""
        was = self.initiator.confirmed(state.tracks)
        t = self.filter.predict(state.tracks)
        inn = self.filter.innovations(t)
        dist = self.hypothesiser.scores(self.filter.distances2(Z, t, inn))
        gate = self.hypothesiser.gate
        det = np.full(len(t), -1, dtype=np.int64)
        free = np.arange(len(Z))
        for rows in (np.flatnonzero(was), np.flatnonzero(~was)):  # confirmed, then tentative
            a = self.associator.assign(dist[free][:, rows], gate)
            tracks, dets = rows[a.pairs[:, 1]], free[a.pairs[:, 0]]
            t = self.filter.update(t, inn, tracks, Z[dets])
            det[tracks] = dets
            free = free[a.new]
        keep = np.where(was, self.deleter.alive(t), ~self.initiator.expired(t))
        t = t.take(keep).concat(self.filter.start(Z[free], state.next_id))
        det = np.concatenate([det[keep], free])
        out = PointFrameTracks(
            self.filter.positions(t),
            t.id,
            self.initiator.confirmed(t),
            det,
            t.since,
            self.filter.spread_inverse(t),
        )
        return MultiState(t, state.next_id + len(free), state.frames + 1), out


def gnn_tracker(
    m: Matrices,
    gate_probability: float = 0.99,
    min_hits: int = 3,
    confirm_window: int = 5,
    max_age: int = 1,
) -> GnnTracker:
    """The ``gnn`` preset on the model ``m``."""
    return GnnTracker(
        PointFilter(m),
        MahalanobisHypothesiser(gate_probability),
        GnnAssociator(),
        MOfNInitiator(min_hits, confirm_window),
        MaxAgeDeleter(max_age),
    )


class GnnDesign(ComposedDesign):
    """The ``gnn`` design on a scene's detection positions (the tracker file's model,
    ``sigma_q``, ``sigma_r``, ``P0_sd``, ``gate_probability``, ``min_hits``,
    ``confirm_window``, ``max_age``; the scene's ``dt``)."""

    def __init__(self, scene: Scene | Footage, path: str = "<scene>") -> None:
        cfg = scene.tracker
        if (why := m_of_n_problem(cfg.min_hits, cfg.confirm_window)) is not None:
            raise UsageError(f"{path}: the gnn design: {why}")
        self.scene = scene
        self.tracker = gnn_tracker(
            matrices(cfg, scene.dt),
            cfg.gate_probability,
            cfg.min_hits,
            cfg.confirm_window,
            cfg.max_age,
        )

    def measurements(self, frame: Frame) -> np.ndarray:
        """The detections' positions (k, 2)."""
        return frame.positions()

    def no_reference(self) -> str:
        """Why :meth:`references` finds none (its rule)."""
        return (
            "no detection of its frame is within the gate of its start, or its track is "
            "never output"
        )

    def candidate_measurements(self, frame: Frame) -> np.ndarray:
        """The injection candidates' positions (m, 2)."""
        return np.array([[c.x, c.y] for c in frame.candidates], dtype=float).reshape(-1, 2)

    def references(self, steps: list[FrameTracks]) -> list[np.ndarray | None]:
        """The target's reference: the unattacked track that took, at the target's frame,
        the detection nearest its start among those within the gate of it under R alone
        ((z − start)ᵀ R⁻¹ (z − start) < the gate; the first of equals), at the steps where
        the tracker outputs it."""
        none: list[np.ndarray | None] = [None] * len(steps)
        scene = self.scene
        if not isinstance(scene, Scene):
            return none
        k0 = scene.target.step - scene.frames[0].step
        if not 0 <= k0 < len(steps) or not len(scene.frames[k0].detections):
            return none
        y = scene.frames[k0].positions() - np.asarray(scene.target.start)
        d2 = mahalanobis2(y, np.linalg.inv(self.tracker.filter.m.R))
        d2 = np.where(d2 < self.tracker.hypothesiser.gate2, d2, np.inf)
        if not np.isfinite(d2).any():
            return none
        return follow(steps, k0, int(np.argmin(d2)))

    def target_of(self, ft: FrameTracks, ref: np.ndarray) -> int:
        """The output track nearest the reference position in Mahalanobis distance under
        its own (H P Hᵀ + R), among those within the gate (d² < the gate), the lower id of
        equals (lesmc/model/identity.py ``target_track``)."""
        if not len(ft.ids):
            return NONE
        assert isinstance(ft, PointFrameTracks)
        d2 = mahalanobis2(ref[None, :] - ft.boxes, ft.spread_inv)
        gate2 = self.tracker.hypothesiser.gate2
        return target_track(-d2, ft.ids, ft.confirmed & (d2 < gate2), floor=-np.inf)
