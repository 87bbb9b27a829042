"""Detection quality against truth: one-to-one matching, precision, recall, F1, error.

A detection matches a true vehicle within ``radius`` pixels, one to one, by the
assignment that minimises the total distance (Hungarian method). Vehicles the
detector cannot be expected to see are "don't care": a detection on one is
neither a hit nor a false alarm, and missing one is not a miss. They are the
vehicles that are occluded, slower than ``min_speed``, or outside the region
where all L aligned frames have data (``valid``).
"""

from __future__ import annotations

import math
from collections.abc import Iterable
from dataclasses import dataclass, field
from typing import Any, TypeGuard

import numpy as np

from lesmc.common.errors import InputError, Location, Problems
from lesmc.common.fields import header
from lesmc.common.files import read_json


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
    # imported here: scipy.spatial is 0.45 s of imports, on the path of lesmc verify
    # before it starts rendering the default video
    from scipy.spatial import cKDTree

    pairs = cKDTree(det).query_ball_tree(cKDTree(truth), radius)
    rows = sorted({i for i, js in enumerate(pairs) if js})
    cols = sorted({j for js in pairs for j in js})
    if not rows:
        return []
    big = 1e6
    d = np.linalg.norm(det[rows][:, None, :] - truth[cols][None, :, :], axis=2)
    cost = np.where(d <= radius, d, big)
    from scipy.optimize import linear_sum_assignment  # 0.5 s of imports: only when matching

    r, c = linear_sum_assignment(cost)
    return [
        (rows[a], cols[b], float(d[a, b])) for a, b in zip(r, c, strict=True) if d[a, b] <= radius
    ]


@dataclass(frozen=True)
class VisibleCounts:
    """Detections against the visible vehicles over frames: how many of each and how many
    detections matched one (one to one within the radius, :func:`match`)."""

    vehicles: int
    detections: int
    true_positives: int

    @property
    def recall(self) -> float | None:
        """True positives over visible vehicles (None: no vehicle)."""
        return self.true_positives / self.vehicles if self.vehicles else None

    @property
    def precision(self) -> float | None:
        """True positives over detections (None: no detection)."""
        return self.true_positives / self.detections if self.detections else None


def visible_counts(frames: Iterable[tuple[np.ndarray, np.ndarray]], radius: float) -> VisibleCounts:
    """Recall's and precision's counts over ``frames``, each (detections (n, 2), visible
    vehicles (m, 2)): every vehicle counts, moving or not (no don't-care vehicles, unlike
    :func:`score`); a detection is a true positive when it matches one within ``radius``."""
    vehicles = detections = tp = 0
    for det, visible in frames:
        det = np.asarray(det, np.float64).reshape(-1, 2)
        visible = np.asarray(visible, np.float64).reshape(-1, 2)
        vehicles += len(visible)
        detections += len(det)
        tp += len(match(det, visible, radius))
    return VisibleCounts(vehicles, detections, tp)


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


#: Largest magnitude of a truth coordinate or velocity (pixels, pixels per second).
TRUTH_MAX_COORD = 1e6
#: Largest truth speed (m/s) and frame interval (s).
TRUTH_MAX_SPEED, TRUTH_MAX_DT = 1e4, 3600.0
#: The truth.json version this lesmc reads and ``lesmc synth`` writes.
TRUTH_VERSION = 1


def load_truth(path: str) -> Truth:
    """Read ``truth.json`` (as written by ``lesmc synth``), every field checked strictly.

    Problems are reported together, each with its frame and vehicle
    (docs/synthetic.md lists the fields and their ranges).
    """
    data = read_json(path, InputError)
    if not isinstance(data, dict) or data.get("format") != "lesmc-truth":
        raise InputError("not a lesmc truth file (format must be 'lesmc-truth')", Location(path))
    pr = Problems()
    header(data, "lesmc-truth", TRUTH_VERSION, pr)
    dt = data.get("dt")
    if dt is not None and not (_number(dt) and 0 < dt <= TRUTH_MAX_DT):
        pr.add("dt", f"must be a number of seconds in (0, {TRUTH_MAX_DT:g}], got {_show(dt)}")
    frames = data.get("frames")
    out: dict[str, TruthFrame] = {}
    if not isinstance(frames, list) or not frames:
        pr.add("frames", "must be a non-empty list")
        frames = []
    for i, fr in enumerate(frames):
        where = f"frames[{i}]"
        if not isinstance(fr, dict):
            pr.add(where, "must be an object")
            continue
        name = fr.get("file")
        if not (isinstance(name, str) and name):
            pr.add(where, f"file must be a non-empty string, got {_show(name)}")
            continue
        where = f"frame '{name}'"
        if name in out:
            pr.add(where, "appears twice")
            continue
        vehicles = fr.get("vehicles")
        if not isinstance(vehicles, list):
            pr.add(where, "vehicles must be a list")
            continue
        before = len(pr.items)
        for j, v in enumerate(vehicles):
            _check_vehicle(v, f"{where}, vehicles[{j}]", pr)
        if len(pr.items) == before:
            out[name] = truth_frame(vehicles)
    if pr.items:
        raise InputError.many(path, pr.items)
    return Truth(float(dt) if dt is not None else None, out)


def _check_vehicle(v: Any, where: str, pr: Problems) -> None:
    if not isinstance(v, dict):
        pr.add(where, "must be an object")
        return
    vid = v.get("id")
    if not (isinstance(vid, int) and not isinstance(vid, bool) and 0 <= vid < 2**63):
        pr.add(where, f"id must be an integer >= 0, got {_show(vid)}")
    for key, required, limit in (
        ("x", True, TRUTH_MAX_COORD),
        ("y", True, TRUTH_MAX_COORD),
        ("vx", False, TRUTH_MAX_COORD),
        ("vy", False, TRUTH_MAX_COORD),
        ("speed_mps", False, TRUTH_MAX_SPEED),
    ):
        x = v.get(key)
        if x is None and not required and key not in v:
            continue
        low = 0.0 if key == "speed_mps" else -limit
        if not (_number(x) and low <= float(x) <= limit):
            pr.add(where, f"{key} must be a number in [{low:g}, {limit:g}], got {_show(x)}")
    occluded = v.get("occluded", False)
    if not isinstance(occluded, bool):
        pr.add(where, f"occluded must be true or false, got {_show(occluded)}")


def _number(x: Any) -> TypeGuard[int | float]:
    return isinstance(x, int | float) and not isinstance(x, bool) and math.isfinite(x)


def _show(x: Any) -> str:
    text = repr(x)
    return text if len(text) <= 40 else text[:37] + "..."


def care_mask(tf: TruthFrame, valid: np.ndarray, min_speed: float) -> np.ndarray:
    """The vehicles that count: moving, visible, inside the background's coverage."""
    h, w = valid.shape
    xi = np.clip(tf.positions[:, 0].astype(int), 0, w - 1)
    yi = np.clip(tf.positions[:, 1].astype(int), 0, h - 1)
    inside: np.ndarray = valid[yi, xi] > 0
    care: np.ndarray = (tf.speed_mps >= min_speed) & ~tf.occluded & inside
    return care
