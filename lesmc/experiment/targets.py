"""Choosing the vehicle to verify: where neighbouring traffic is dense (section 8.2).

An attacker who hides detections can only make the tracker take another
observation if there is one nearby, so the interesting targets are vehicles
with traffic around them that the unattacked tracker follows correctly.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from lesmc.common.errors import UsageError
from lesmc.designs.registry import BASELINE
from lesmc.language.properties import SpecFile
from lesmc.perception.quality import Truth, TruthFrame
from lesmc.perception.to_scene import truth_velocity
from lesmc.scene import Footage, Scene, TruthTrack
from lesmc.tracking.monitor import TrackPoint, track
from lesmc.tracking.targets import TargetSpec, place_target
from lesmc.tracking.trackers import make_tracker
from lesmc.video.reader import FrameSet


@dataclass(frozen=True)
class Candidate:
    """A possible target: where it starts and where it truly is at each later step."""

    vid: int
    crowd: int  # moving neighbours within ``near`` px, summed over the window's frames
    spec: TargetSpec
    truth_track: np.ndarray  # (n, 2) true positions at steps 0..n-1


def rank_targets(
    frames: list[TruthFrame],
    size: tuple[int, int],
    window: tuple[int, int],
    margin: float = 150.0,
    near: float = 40.0,
    min_speed: float = 5.0,
    max_turn_deg: float = 30.0,
) -> list[Candidate]:
    """Vehicles of ``frames[0]`` worth attacking, most neighbouring traffic first.

    A candidate keeps moving (>= ``min_speed`` m/s), stays visible and inside the
    frame, and does not turn by more than ``max_turn_deg`` between frames until
    two steps after the window (the tracker's model is constant velocity); its
    score is the number of moving vehicles within ``near`` pixels of it over the
    window's frames: the observations an attacker can make the tracker take.
    Ties go to the lower vehicle id, so the choice is deterministic.
    """
    l, u = window
    horizon = min(u + 2, len(frames) - 1)
    first = frames[0]
    out = []
    for vid in first.ids:
        track, ok = [], True
        for tf in frames[: horizon + 1]:
            if vid not in tf.ids:
                ok = False
                break
            j = tf.ids.index(vid)
            x, y = tf.positions[j]
            if (
                tf.occluded[j]
                or tf.speed_mps[j] < min_speed
                or not (margin <= x <= size[0] - margin and margin <= y <= size[1] - margin)
            ):
                ok = False
                break
            track.append((x, y))
        if not ok:
            continue
        pts = np.array(track)
        steps = np.diff(pts, axis=0)
        ang = np.degrees(np.arctan2(steps[:, 1], steps[:, 0]))
        turn = np.abs((np.diff(ang) + 180) % 360 - 180)
        if len(turn) and turn.max() > max_turn_deg:
            continue
        crowd = 0
        for k in range(l, min(horizon, u) + 1):
            tf = frames[k]
            moving = (tf.speed_mps >= 1.5) & ~tf.occluded
            d = np.linalg.norm(tf.positions[moving] - pts[k], axis=1)
            crowd += int(((d > 0.5) & (d < near)).sum())
        if crowd == 0:
            continue
        out.append(Candidate(vid, crowd, TargetSpec(float(pts[0, 0]), float(pts[0, 1])), pts))
    out.sort(key=lambda c: (-c.crowd, c.vid))
    return out


#: How far (px) the unattacked track may be from the true vehicle and still follow it.
TOLERANCE_PX = 6.0


def follows(scene: Scene, truth_track: np.ndarray, tolerance: float = TOLERANCE_PX) -> bool:
    """Whether the unattacked single-KF track stays on the vehicle for ``truth_track``'s steps."""
    return on_vehicle(scene, baseline_track(scene, len(truth_track) - 1), truth_track, tolerance)


def baseline_track(scene: Scene, end: int) -> list[TrackPoint]:
    """The unattacked track of the plain tracker (``BASELINE``) through step ``end``, or
    until it halts."""
    return track(make_tracker(scene.with_tracker(design=BASELINE)), end)


def on_vehicle(
    scene: Scene, run: list[TrackPoint], truth_track: np.ndarray, tolerance: float = TOLERANCE_PX
) -> bool:
    """Whether the unattacked track ``run`` lasts ``truth_track``'s steps and stays within
    ``tolerance`` of the vehicle at each after the first."""
    if len(run) < len(truth_track):
        return False
    est = np.array([p.x[list(scene.tracker.measured)] for p in run[: len(truth_track)]])
    return bool((np.linalg.norm(est[1:] - truth_track[1:], axis=1) <= tolerance).all())


def target_scene(
    footage: Footage, spec: TargetSpec, frames: FrameSet, truth: Truth | None
) -> Scene:
    """The scene tracking ``spec``: its initial velocity from the truth of its frame when
    a true vehicle is there, else from the previous frame."""
    step = spec.step if spec.step is not None else footage.frames[0].step
    tf = None
    if truth is not None and 0 <= step < len(frames):
        tf = truth.frames.get(frames.paths[step].name)
    return place_target(footage, spec, truth_velocity(tf, spec.x, spec.y))


def auto_target(
    footage: Footage, frames: FrameSet, truth: Truth, spec_files: list[SpecFile]
) -> Scene:
    """The scene of the best-ranked vehicle (``rank_targets``) whose unattacked track follows it."""
    first = footage.frames[0].step
    tfs = [truth.frames[p.name] for p in frames.paths[first:] if p.name in truth.frames]
    window = (
        min(p.window[0] for s in spec_files for p in s.properties),
        max(p.window[1] or len(tfs) - 1 for s in spec_files for p in s.properties),
    )
    cands = rank_targets(tfs, (frames.width, frames.height), window)
    for rank, c in enumerate(cands[:40]):
        scene = place_target(footage, c.spec, truth_velocity(tfs[0], c.spec.x, c.spec.y))
        if follows(scene, c.truth_track):
            scene.meta["target_choice"] = (
                f"vehicle {c.vid} of the truth: rank {rank + 1} of {len(cands)} by neighbouring "
                f"traffic ({c.crowd} vehicle-frames within 40 px in the window), the first whose "
                "unattacked track follows it"
            )
            return scene
    raise UsageError(
        "no vehicle with neighbouring traffic is tracked correctly unattacked; give --target"
    )


def truth_tracks(footage: Footage, frames: FrameSet, truth: Truth) -> tuple[TruthTrack, ...]:
    """The video's true vehicles as the scene's ground-truth tracks (``dist.nearest``'s
    acceptable paths, section 4.2): vehicle ``v{id}`` at its true position in every
    scene frame whose truth lists it."""
    rows: dict[int, list[tuple[int, float, float]]] = {}
    for fr in footage.frames:
        if not 0 <= fr.step < len(frames):
            continue
        tf = truth.frames.get(frames.paths[fr.step].name)
        if tf is None:
            continue
        for vid, (x, y) in zip(tf.ids, tf.positions.tolist(), strict=True):
            rows.setdefault(int(vid), []).append((fr.step, float(x), float(y)))
    return tuple(TruthTrack(f"v{vid}", tuple(pos)) for vid, pos in sorted(rows.items()))
