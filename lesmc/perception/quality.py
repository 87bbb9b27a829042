"""Detection quality against truth: one-to-one matching, precision, recall, F1, error.

A detection matches a true vehicle within ``radius`` pixels, one to one, by the
assignment that minimises the total distance (Hungarian method). Vehicles the
detector cannot be expected to see are "don't care": a detection on one is
neither a hit nor a false alarm, and missing one is not a miss. They are the
vehicles that are occluded, slower than ``min_speed``, or outside the region
where all L aligned frames have data (``valid``).
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any

import numpy as np
from scipy.optimize import linear_sum_assignment
from scipy.spatial import cKDTree

from lesmc.errors import InputError, Location
from lesmc.fileio import read_json


@dataclass(frozen=True)
class Score:
    """Counts and localisation error of one frame (or summed over frames)."""

    tp: int
    fp: int
    fn: int
    ignored: int  # true vehicles that were don't care
    error_sum: float  # sum of matched distances, pixels

    @property
    def precision(self) -> float:
        return self.tp / (self.tp + self.fp) if self.tp + self.fp else 0.0

    @property
    def recall(self) -> float:
        return self.tp / (self.tp + self.fn) if self.tp + self.fn else 0.0

    @property
    def f1(self) -> float:
        p, r = self.precision, self.recall
        return 2 * p * r / (p + r) if p + r else 0.0

    @property
    def error(self) -> float:
        """Mean distance of the matched pairs, pixels."""
        return self.error_sum / self.tp if self.tp else 0.0

    def __add__(self, other: Score) -> Score:
        return Score(
            self.tp + other.tp,
            self.fp + other.fp,
            self.fn + other.fn,
            self.ignored + other.ignored,
            self.error_sum + other.error_sum,
        )

    def to_json(self) -> dict[str, Any]:
        return {
            "tp": self.tp,
            "fp": self.fp,
            "fn": self.fn,
            "ignored": self.ignored,
            "precision": self.precision,
            "recall": self.recall,
            "f1": self.f1,
            "error_px": self.error,
        }


def match(det: np.ndarray, truth: np.ndarray, radius: float) -> list[tuple[int, int, float]]:
    """Optimal one-to-one pairs ``(i_det, j_truth, distance)`` with distance <= radius."""
    if len(det) == 0 or len(truth) == 0:
        return []
    pairs = cKDTree(det).query_ball_tree(cKDTree(truth), radius)
    rows = sorted({i for i, js in enumerate(pairs) if js})
    cols = sorted({j for js in pairs for j in js})
    if not rows:
        return []
    big = 1e6
    d = np.linalg.norm(det[rows][:, None, :] - truth[cols][None, :, :], axis=2)
    cost = np.where(d <= radius, d, big)
    r, c = linear_sum_assignment(cost)
    return [
        (rows[a], cols[b], float(d[a, b])) for a, b in zip(r, c, strict=True) if d[a, b] <= radius
    ]


def score(det: np.ndarray, truth: np.ndarray, care: np.ndarray, radius: float) -> Score:
    """Score detections against true positions; ``care`` marks the vehicles that count."""
    pairs = match(det, truth, radius)
    tp = sum(1 for _, j, _ in pairs if care[j])
    on_ignored = sum(1 for _, j, _ in pairs if not care[j])
    err = sum(dist for _, j, dist in pairs if care[j])
    return Score(tp, len(det) - tp - on_ignored, int(care.sum()) - tp, int((~care).sum()), err)


@dataclass
class TruthFrame:
    """The true vehicles of a frame: positions, speeds, occlusion."""

    positions: np.ndarray  # (n, 2)
    speed_mps: np.ndarray
    occluded: np.ndarray
    ids: list[int] = field(default_factory=list)
    velocity: np.ndarray | None = None  # (n, 2) frame px per second


def truth_frame(vehicles: list[dict[str, Any]]) -> TruthFrame:
    """The vehicles of one frame of ``truth.json`` (or of ``synth.frames``) as arrays."""
    return TruthFrame(
        np.array([[float(v["x"]), float(v["y"])] for v in vehicles]).reshape(-1, 2),
        np.array([float(v.get("speed_mps", 0.0)) for v in vehicles]),
        np.array([bool(v.get("occluded", False)) for v in vehicles], bool),
        [int(v["id"]) for v in vehicles],
        np.array([[float(v.get("vx", 0.0)), float(v.get("vy", 0.0))] for v in vehicles]).reshape(
            -1, 2
        ),
    )


@dataclass(frozen=True)
class Truth:
    """A truth file: seconds between frames (if recorded) and the frames by file name."""

    dt: float | None
    frames: dict[str, TruthFrame]


def load_truth(path: str) -> Truth:
    """Read ``truth.json`` (as written by ``lesmc synth``)."""
    data = read_json(path, InputError)
    if not isinstance(data, dict) or data.get("format") != "lesmc-truth":
        raise InputError("not a lesmc truth file (format must be 'lesmc-truth')", Location(path))
    out: dict[str, TruthFrame] = {}
    for i, fr in enumerate(data.get("frames", [])):
        try:
            out[str(fr["file"])] = truth_frame(fr["vehicles"])
        except (KeyError, TypeError, ValueError) as exc:
            raise InputError(
                f"frame {i}: malformed entry ({exc})", Location(path, item=f"frame {i}")
            ) from None
    if not out:
        raise InputError("no frames", Location(path))
    dt = data.get("dt")
    return Truth(float(dt) if isinstance(dt, (int, float)) and dt > 0 else None, out)


def care_mask(tf: TruthFrame, valid: np.ndarray, min_speed: float) -> np.ndarray:
    """The vehicles that count: moving, visible, inside the background's coverage."""
    h, w = valid.shape
    xi = np.clip(tf.positions[:, 0].astype(int), 0, w - 1)
    yi = np.clip(tf.positions[:, 1].astype(int), 0, h - 1)
    inside: np.ndarray = valid[yi, xi] > 0
    care: np.ndarray = (tf.speed_mps >= min_speed) & ~tf.occluded & inside
    return care
