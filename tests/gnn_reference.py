"""The ``gnn`` composition built in Stone Soup 1.9 (``import stonesoup``), the test-only
oracle of lesmc's ``gnn`` design (docs/trackers.md, "The gnn preset").

``MultiTargetTracker`` with ``GNNWith2DAssignment`` on a ``DistanceHypothesiser`` with the
``Mahalanobis`` measure (``missed_distance``: the square root of scipy's χ²(2) quantile of
the gate probability), ``KalmanPredictor`` / ``KalmanUpdater`` on two ``ConstantVelocity``
models (q = σ_q²) and a ``LinearGaussian`` measurement of (x, y) (R = σ_r² I), a
``MultiMeasurementInitiator`` (``min_points`` = M, the same associator; its holding tracks
deleted at their N-th state by :class:`WindowDeleter`), and ``UpdateTimeStepsDeleter``
with ``time_steps_since_update`` = ``max_age`` + 1 (Stone Soup deletes a track whose last
``time_steps_since_update`` states hold no update: max_age + 1 states without an update
is "missed more than max_age frames")."""

from __future__ import annotations

import datetime
from collections.abc import Iterator, Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np
from scipy.stats import chi2
from stonesoup.base import Property
from stonesoup.buffered_generator import BufferedGenerator
from stonesoup.dataassociator.neighbour import GNNWith2DAssignment
from stonesoup.deleter.base import Deleter
from stonesoup.deleter.time import UpdateTimeStepsDeleter
from stonesoup.hypothesiser.distance import DistanceHypothesiser
from stonesoup.initiator.simple import MultiMeasurementInitiator
from stonesoup.measures import Mahalanobis
from stonesoup.models.measurement.linear import LinearGaussian
from stonesoup.models.transition.linear import (
    CombinedLinearGaussianTransitionModel,
    ConstantVelocity,
)
from stonesoup.predictor.kalman import KalmanPredictor
from stonesoup.reader.base import DetectionReader
from stonesoup.tracker.simple import MultiTargetTracker
from stonesoup.types.detection import Detection
from stonesoup.types.state import GaussianState
from stonesoup.updater.kalman import KalmanUpdater

T0 = datetime.datetime(2026, 1, 1)


@dataclass(frozen=True)
class Params:
    """The gnn design's parameters (the tracker file's keys) and the scene's dt."""

    dt: float = 1.0
    sigma_q: float = 3.0
    sigma_r: float = 5.0
    P0_sd: tuple[float, float, float, float] = (30.0, 30.0, 20.0, 20.0)  # x, y, vx, vy
    gate_probability: float = 0.99
    min_hits: int = 3
    confirm_window: int = 5
    max_age: int = 1


class WindowDeleter(Deleter):
    """Deletes a (holding) track once it has ``n`` states: the N of M-of-N."""

    n: int = Property(doc="states a tentative track may reach")

    def check_for_deletion(self, track: Any, **kwargs: Any) -> bool:
        return len(track) >= self.n


class FrameReader(DetectionReader):
    """Detections per frame from arrays (k, 2), at times T0 + k·dt; each detection's
    metadata holds its index in its frame."""

    frames: Any = Property()
    dt: float = Property(default=1.0)
    model: Any = Property()

    @BufferedGenerator.generator_method
    def detections_gen(self) -> Iterator[tuple[datetime.datetime, set[Detection]]]:
        for k, Z in enumerate(self.frames):
            t = T0 + datetime.timedelta(seconds=k * self.dt)
            dets = {
                Detection(
                    np.array([[z[0]], [z[1]]]),
                    timestamp=t,
                    measurement_model=self.model,
                    metadata={"index": j},
                )
                for j, z in enumerate(Z)
            }
            yield t, dets


def tracker(frames: Sequence[np.ndarray], p: Params) -> MultiTargetTracker:
    """The Stone Soup tracker of ``p`` on ``frames``."""
    q = p.sigma_q**2
    transition = CombinedLinearGaussianTransitionModel([ConstantVelocity(q), ConstantVelocity(q)])
    measurement = LinearGaussian(ndim_state=4, mapping=(0, 2), noise_covar=np.eye(2) * p.sigma_r**2)
    predictor = KalmanPredictor(transition)
    updater = KalmanUpdater(measurement)
    gate = float(np.sqrt(chi2.ppf(p.gate_probability, 2)))
    hyp = DistanceHypothesiser(predictor, updater, measure=Mahalanobis(), missed_distance=gate)
    sx, sy, svx, svy = p.P0_sd
    prior = GaussianState(np.zeros((4, 1)), np.diag([sx**2, svx**2, sy**2, svy**2]))
    initiator = MultiMeasurementInitiator(
        prior_state=prior,
        measurement_model=measurement,
        deleter=WindowDeleter(p.confirm_window),
        data_associator=GNNWith2DAssignment(hyp),
        updater=updater,
        min_points=p.min_hits,
    )
    return MultiTargetTracker(
        initiator=initiator,
        deleter=UpdateTimeStepsDeleter(time_steps_since_update=p.max_age + 1),
        detector=FrameReader(frames=list(frames), dt=p.dt, model=measurement),
        data_associator=GNNWith2DAssignment(hyp),
        updater=updater,
    )


def run(frames: Sequence[np.ndarray], p: Params) -> list[dict[str, np.ndarray]]:
    """Stone Soup's output tracks per frame: {track id: state [x, y, vx, vy]}."""
    out = []
    for _, tracks in tracker(frames, p):
        out.append(
            {t.id: np.asarray(t.state_vector, dtype=float).ravel()[[0, 2, 1, 3]] for t in tracks}
        )
    return out
