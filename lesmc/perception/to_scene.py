"""Detections and payoffs of a video -> a scene file for the tracker and the model builder.

Model step k is video frame k (frames before the first detected frame, which
only fill the background history, are not in the scene). Modelling assumption
(docs/cnn.md): detections and payoffs are computed once on the clean video and
an attack at step k hides detections of frame k only.
"""

from __future__ import annotations

from typing import Any

import numpy as np
from scipy.spatial import cKDTree

from lesmc.errors import UsageError
from lesmc.perception.detector import FrameDetections
from lesmc.perception.quality import Truth, TruthFrame
from lesmc.perception.run import PerceiveRun
from lesmc.tracking.scene import Detection, Footage, Frame, Scene, Target, TrackerConfig
from lesmc.tracking.targets import TargetSpec as TargetSpec  # re-exported
from lesmc.tracking.targets import check_gate, previous_velocity
from lesmc.tracking.targets import parse_target as parse_target  # re-exported for the verbs
from lesmc.video.reader import FrameSet


def check_target(spec: TargetSpec, width: int, height: int, n_frames: int) -> None:
    """``--target`` inside a ``width`` x ``height`` frame and among the ``n_frames`` frames."""
    if not (0 <= spec.x < width and 0 <= spec.y < height):
        raise UsageError(
            f"--target {spec.x:g},{spec.y:g} is outside the frames: x must lie in 0..{width} "
            f"and y in 0..{height} (pixels)"
        )
    if spec.step is not None and spec.step >= n_frames:
        raise UsageError(f"--target step {spec.step}: the video has frames 0..{n_frames - 1}")


def frames_of(
    dets: list[FrameDetections], pays: list[np.ndarray], lower: list[np.ndarray] | None = None
) -> tuple[Frame, ...]:
    """Scene frames: detection ids ``"FRAME:I"``, payoffs [and certified lower bounds],
    homographies to the next frame."""
    out = []
    lows: list[np.ndarray | None] = list(lower) if lower else [None] * len(dets)
    for i, (fd, p, lo) in enumerate(zip(dets, pays, lows, strict=True)):
        to_next = None
        if i + 1 < len(dets):
            to_next = dets[i + 1].from_prev
        ds = tuple(
            Detection(
                f"{fd.index}:{j}",
                float(x),
                float(y),
                float(p[j]),
                None if lo is None else float(lo[j]),
            )
            for j, (x, y) in enumerate(fd.positions)
        )
        out.append(Frame(fd.index, ds, to_next))
    return tuple(out)


def target_velocity(
    footage: Footage,
    spec: TargetSpec,
    step: int,
    truth: TruthFrame | None,
    snap_px: float = 6.0,
) -> tuple[tuple[float, float], str]:
    """The target's initial velocity (px/s) and how it was obtained.

    From the truth when given (the nearest true vehicle within ``snap_px``);
    otherwise from the previous frame (tracking/targets.py: previous_velocity).
    """
    here = np.array([spec.x, spec.y])
    if truth is not None and len(truth.positions):
        d, j = cKDTree(truth.positions).query(here)
        if d <= snap_px and truth.velocity is not None:
            return (float(truth.velocity[j, 0]), float(truth.velocity[j, 1])), "truth"
    return previous_velocity(footage, spec.x, spec.y, step)


def make_scene(
    dets: list[FrameDetections],
    pays: list[np.ndarray],
    dt: float,
    spec: TargetSpec,
    truth: TruthFrame | None = None,
    tracker: TrackerConfig | None = None,
    meta: dict[str, Any] | None = None,
    lower: list[np.ndarray] | None = None,
) -> Scene:
    """Assemble and check a scene; the target's frame must be one of the detected frames."""
    if not dets:
        raise UsageError("no frame produced detections: the video is shorter than L+1 frames")
    frames = frames_of(dets, pays, lower)
    step = spec.step if spec.step is not None else frames[0].step
    if not frames[0].step <= step <= frames[-1].step:
        raise UsageError(
            f"--target step {step} is not a detected frame ({frames[0].step}..{frames[-1].step}; "
            "the first L frames only build the background)"
        )
    footage = Footage(dt, frames, tracker or TrackerConfig(), dict(meta or {}))
    check_gate(footage, spec, step)
    vel, how = target_velocity(footage, spec, step, truth)
    info = dict(meta or {})
    info["target_velocity_from"] = how
    return footage.with_target(Target(step, (spec.x, spec.y), vel), info)


def footage_from_run(run: PerceiveRun, dt: float, meta: dict[str, Any] | None = None) -> Footage:
    """The scene without a target of a ``perceive`` run (``lesmc perceive -o`` alone)."""
    if not run.detections:
        raise UsageError("no frame produced detections: the video is shorter than L+1 frames")
    return Footage(dt, frames_of(run.detections, run.payoffs), TrackerConfig(), dict(meta or {}))


def scene_from_run(
    run: PerceiveRun,
    frames: FrameSet,
    spec: TargetSpec,
    dt: float,
    truth: Truth | None = None,
    meta: dict[str, Any] | None = None,
) -> Scene:
    """The scene of a ``perceive`` run; the truth of the target's frame gives its velocity."""
    check_target(spec, frames.width, frames.height, len(frames))
    first = run.detections[0].index if run.detections else 0
    step = spec.step if spec.step is not None else first
    tf = None
    if truth is not None and 0 <= step < len(frames):
        tf = truth.frames.get(frames.paths[step].name)
    lower = run.payoffs_lower or None
    return make_scene(run.detections, run.payoffs, dt, spec, tf, meta=meta, lower=lower)
