"""Detections and payoffs of a video -> a scene file for the tracker and the model builder.

Model step k is video frame k (frames before the first detected frame, which
only fill the background history, are not in the scene). Modelling assumption
(docs/cnn.md): detections and payoffs are computed once on the clean video and
an attack at step k hides detections of frame k only.
"""

from __future__ import annotations

import re
from dataclasses import dataclass
from typing import Any

import numpy as np
from scipy.spatial import cKDTree

from lesmc.errors import UsageError, escape_control
from lesmc.perception.detector import FrameDetections
from lesmc.perception.quality import Truth, TruthFrame
from lesmc.perception.run import PerceiveRun
from lesmc.tracking.kalman import warp
from lesmc.tracking.scene import Detection, Frame, Scene, Target, TrackerConfig
from lesmc.video.reader import FrameSet


@dataclass(frozen=True)
class TargetSpec:
    """``--target X,Y[@STEP]``: where the tracked vehicle is, in which frame (default: first)."""

    x: float
    y: float
    step: int | None = None


def parse_target(text: str) -> TargetSpec:
    """``X,Y`` or ``X,Y@STEP`` (pixels of that frame) -> TargetSpec; a UsageError otherwise.

    ASCII digits only; coordinates of at most 9 digits before the point, STEP at most 10**6.
    """
    num = r"\s*(-?[0-9]{1,9}(?:\.[0-9]{0,12})?)\s*"
    m = re.fullmatch(num + "," + num + r"(?:@\s*([0-9]{1,7})\s*)?", text, re.ASCII)
    if not m or (m.group(3) and int(m.group(3)) > 10**6):
        shown = escape_control(text if len(text) <= 40 else text[:37] + "...")
        raise UsageError(
            f"--target must look like X,Y or X,Y@STEP (e.g. 812.5,96@4), got '{shown}'"
        )
    return TargetSpec(float(m.group(1)), float(m.group(2)), int(m.group(3)) if m.group(3) else None)


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
    frames: tuple[Frame, ...],
    spec: TargetSpec,
    step: int,
    dt: float,
    truth: TruthFrame | None,
    snap_px: float = 6.0,
    max_move_px: float = 45.0,
) -> tuple[tuple[float, float], str]:
    """The target's initial velocity (px/s) and how it was obtained.

    From the truth when given (the nearest true vehicle within ``snap_px``);
    otherwise from the nearest detection in the previous frame, mapped into this
    frame, within ``max_move_px``; otherwise zero (the tracker's P0 covers it).
    """
    here = np.array([spec.x, spec.y])
    if truth is not None and len(truth.positions):
        d, j = cKDTree(truth.positions).query(here)
        if d <= snap_px and truth.velocity is not None:
            return (float(truth.velocity[j, 0]), float(truth.velocity[j, 1])), "truth"
    first = frames[0].step
    if step - 1 >= first:
        prev, cur = frames[step - 1 - first], frames[step - first]
        if len(cur.detections) and len(prev.detections) and prev.to_next is not None:
            d, j = cKDTree(cur.positions()).query(here)
            p0 = cur.positions()[j] if d <= snap_px else here
            pts = warp(prev.to_next, prev.positions())
            d2, k = cKDTree(pts).query(p0)
            if d2 <= max_move_px:
                v = (p0 - pts[k]) / dt
                return (float(v[0]), float(v[1])), "previous frame"
    return (0.0, 0.0), "none (zero)"


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
    vel, how = target_velocity(frames, spec, step, dt, truth)
    info = dict(meta or {})
    info["target_velocity_from"] = how
    return Scene(dt, frames, Target(step, (spec.x, spec.y), vel), tracker or TrackerConfig(), info)


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
