"""Targets apart from perception: ``--target X,Y@STEP`` on a scene, and automatic targets.

A video is perceived once into a scene without a target (a :class:`Footage`:
detections, payoffs, homographies, tracker settings); each vehicle to verify
is then a :class:`TargetSpec` placed on it (:func:`place_target`). Where a
vehicle starts is given by the user, or found here: :func:`initiated_targets`
lets the tracker start tracks from the detections, as the joint design's
initiation does (section 7.2: a detection with a previous detection close
enough starts a track whose velocity is their difference over dt), and keeps
those the unattacked tracker follows, one update per frame, through the
horizon. Targets from a truth file are chosen in lesmc/experiment/targets.py.
"""

from __future__ import annotations

import dataclasses
import re
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from lesmc.common.errors import InputError, UsageError, clipped
from lesmc.common.files import read_json
from lesmc.scene import Footage, Scene, Target, TrackerConfig, check_fits, footage_from_dict
from lesmc.scene.tracker_model import velocity as velocity_components
from lesmc.tracking.association import gate_mask
from lesmc.tracking.design import Batch
from lesmc.tracking.kalman import (
    initial_mean,
    innovation,
    matrices,
    position_spread,
    positions,
    warp,
)
from lesmc.tracking.single import SingleDesign

#: A detection this close (px) to the given position is the target's own detection.
SNAP_PX = 6.0
#: The target's detection in the previous frame lies at most this far (px) from it.
MAX_MOVE_PX = 45.0
#: Other detections this close (px) to a track are the traffic an attacker can use.
NEAR_PX = 40.0


@dataclass(frozen=True)
class TargetSpec:
    """``--target X,Y[@STEP]``: where the tracked vehicle is, in which frame (default: first)."""

    x: float
    y: float
    step: int | None = None

    def text(self) -> str:
        """The ``X,Y@STEP`` form; :func:`parse_target` reads back exactly these numbers
        for a target rounded with :func:`rounded`."""
        at = "" if self.step is None else f"@{self.step}"
        return f"{self.x:.2f},{self.y:.2f}{at}"


def rounded(x: float, y: float, step: int | None) -> TargetSpec:
    """A target at 0.01 px, so that its ``X,Y@STEP`` text reproduces it bit for bit."""
    return TargetSpec(float(f"{x:.2f}"), float(f"{y:.2f}"), step)


def parse_target(text: str) -> TargetSpec:
    """``X,Y`` or ``X,Y@STEP`` (pixels of that frame) -> TargetSpec; a UsageError otherwise.

    ASCII digits only; coordinates of at most 9 digits before the point, STEP at most 10**6.
    """
    num = r"\s*(-?[0-9]{1,9}(?:\.[0-9]{0,20})?)\s*"
    m = re.fullmatch(num + "," + num + r"(?:@\s*([0-9]{1,7})\s*)?", text, re.ASCII)
    if not m or (m.group(3) and int(m.group(3)) > 10**6):
        shown = clipped(text)
        raise UsageError(
            f"--target must look like X,Y or X,Y@STEP (e.g. 812.5,96@4), got '{shown}'"
        )
    return TargetSpec(float(m.group(1)), float(m.group(2)), int(m.group(3)) if m.group(3) else None)


def target_step(footage: Footage, spec: TargetSpec) -> int:
    """The target's frame (default: the first); an error if the scene has no such frame."""
    step = spec.step if spec.step is not None else footage.frames[0].step
    if not footage.frames[0].step <= step <= footage.last_step:
        raise UsageError(
            f"--target step {step} is not a frame of the scene ({footage.frames[0].step}.."
            f"{footage.last_step}; a video's first L frames only build the background)"
        )
    return step


def previous_velocity(
    footage: Footage, x: float, y: float, step: int
) -> tuple[tuple[float, float], str]:
    """The initial velocity (px/s) from the previous frame, and how it was obtained.

    The target's detection (the nearest within :data:`SNAP_PX`, else the given
    position) minus the nearest detection of the previous frame, carried into
    this frame, within :data:`MAX_MOVE_PX`, over dt; zero without one (P0
    covers it).
    """
    first = footage.frames[0].step
    if step - 1 < first:
        return (0.0, 0.0), "none (zero)"
    prev, cur = footage.frame(step - 1), footage.frame(step)
    if not (len(cur.detections) and len(prev.detections) and prev.to_next is not None):
        return (0.0, 0.0), "none (zero)"
    here = np.array([x, y])
    Z = cur.positions()
    d = np.hypot(*(Z - here).T)
    j = int(np.argmin(d))
    p0 = Z[j] if d[j] <= SNAP_PX else here
    pts = warp(prev.to_next, prev.positions())
    d2 = np.hypot(*(pts - p0).T)
    k = int(np.argmin(d2))
    if d2[k] > MAX_MOVE_PX:
        return (0.0, 0.0), "none (zero)"
    v = (p0 - pts[k]) / footage.dt
    return (float(v[0]), float(v[1])), "previous frame"


def check_gate(footage: Footage, spec: TargetSpec, step: int) -> None:
    """A target must have a detection inside the tracker's gate at its step.

    The gate is the tracker's own (Eq. 19) for the initial covariance P0: a
    target far from every detection is a typing mistake, not a vehicle.
    """
    cfg = footage.tracker
    m = matrices(cfg, footage.dt)
    Z = footage.frame(step).positions()
    y = Z - np.array([spec.x, spec.y])
    spread = float(position_spread(m, m.P0))
    if len(Z) and gate_mask(y, innovation(m, m.P0), spread, cfg.gate, cfg.gate_type).any():
        return
    near = f"; the nearest is {float(np.hypot(*y.T).min()):.1f} px away" if len(Z) else ""
    raise UsageError(
        f"--target {spec.x:g},{spec.y:g}@{step}: no detection of frame {step} lies inside the "
        f"tracker's gate around it{near}"
    )


def place_target(
    footage: Footage, spec: TargetSpec, velocity: tuple[float, float] | None = None
) -> Scene:
    """The scene tracking the vehicle at ``spec``; its initial velocity is ``velocity``
    (the truth's, say), else measured from the previous frame."""
    step = target_step(footage, spec)
    check_gate(footage, spec, step)
    if velocity is not None:
        vel, how = velocity, "truth"
    else:
        vel, how = previous_velocity(footage, spec.x, spec.y, step)
    if velocity_components(footage.tracker.model) is None:
        vel, how = (0.0, 0.0), "none (the tracker's state has no vx, vy)"
    meta = dict(footage.meta)
    meta["target_velocity_from"] = how
    return footage.with_target(Target(step, (spec.x, spec.y), vel), meta)


@dataclass(frozen=True)
class AutoTarget:
    """A target found automatically, with why it was chosen."""

    spec: TargetSpec
    traffic: int  # other detections within NEAR_PX of the track, summed over the window
    origin: str


def initiated_targets(
    footage: Footage,
    horizon: int,
    window: tuple[int, int],
    min_move_px: float = 2.0,
) -> list[AutoTarget]:
    """Tracks the tracker itself starts from the detections and keeps through ``horizon``.

    At every frame s with a previous frame and ``horizon`` frames after it,
    each detection whose previous-frame detection lies within
    :data:`MAX_MOVE_PX` (and at least ``min_move_px`` away: a moving vehicle)
    starts a track (:func:`previous_velocity`). A track persists if the
    unattacked plain tracker takes a detection at every step 1..horizon.
    Tracks ending on the same detection follow one vehicle: the earliest is
    kept. Ranked by the traffic around them in ``window`` (model steps), most
    first; ties by frame, then position.
    """

    found: dict[tuple[int, int], AutoTarget] = {}
    order: list[tuple[int, int, float, float, tuple[int, int]]] = []
    first = footage.frames[0].step
    for s in range(first + 1, footage.last_step - horizon + 1):
        specs, vels = _moving_starts(footage, s, min_move_px)
        if not specs:
            continue
        specs, traffic, last_det = _persisting(footage, s, specs, vels, horizon, window)
        for i, sp in enumerate(specs):
            end = (s + horizon, int(last_det[i]))
            if end in found:
                continue
            found[end] = AutoTarget(
                sp, int(traffic[i]), f"track initiated at frame {s} from the detections"
            )
            order.append((-int(traffic[i]), s, sp.x, sp.y, end))
    order.sort()
    return [found[o[-1]] for o in order]


def _moving_starts(
    footage: Footage, s: int, min_move_px: float
) -> tuple[list[TargetSpec], list[tuple[float, float]]]:
    """Step ``s``'s detections that moved at least ``min_move_px`` from the previous frame."""
    specs, vels = [], []
    for x, y in footage.frame(s).positions():
        spec = rounded(float(x), float(y), s)
        vel, how = previous_velocity(footage, spec.x, spec.y, s)
        if how == "previous frame" and np.hypot(*vel) * footage.dt >= min_move_px:
            specs.append(spec)
            vels.append(vel)
    return specs, vels


def _persisting(
    footage: Footage,
    s: int,
    specs: list[TargetSpec],
    vels: list[tuple[float, float]],
    horizon: int,
    window: tuple[int, int],
) -> tuple[list[TargetSpec], np.ndarray, np.ndarray]:
    """The tracks started at step ``s`` that take a detection at every step 1..``horizon``.

    Returns them with the traffic around each in ``window`` and the detection each ends on.
    """
    design = SingleDesign(footage.with_target(Target(s, (0.0, 0.0))))
    c0 = design.covariances.add(design.m.P0.copy())
    X0 = np.array(
        [initial_mean(design.m, (sp.x, sp.y), v) for sp, v in zip(specs, vels, strict=True)]
    )
    b = Batch(X0, np.full(len(specs), c0, dtype=np.int64), np.zeros(len(specs), dtype=bool))
    traffic = np.zeros(len(specs), dtype=np.int64)
    last_det = np.full(len(specs), -1, dtype=np.int64)
    for k in range(1, horizon + 1):
        frame = footage.frame(s + k)
        succ = design.successors(b, s + k, False)
        b = succ.states
        if window[0] <= k <= window[1]:
            near = frame.nearest(positions(design.m, b.X), 8, NEAR_PX)
            traffic += (near >= 0).sum(axis=1) - (succ.det >= 0)
        keep = np.nonzero((succ.det >= 0) & ~b.halted)[0]
        b = b.take(keep)
        specs = [specs[i] for i in keep.tolist()]
        traffic, last_det = traffic[keep], succ.det[keep]
        if not specs:
            break
    return specs, traffic, last_det


def scene_with_target(
    data: Any,
    path: str,
    target: str | None = None,
    design: str | None = None,
    tracker: TrackerConfig | None = None,
) -> Scene:
    """A scene document's scene; ``target`` (``X,Y@STEP``) overrides or supplies its target,
    ``tracker`` (a tracker file's, ``--tracker``) replaces its tracker block, ``design``
    the tracker design it names."""
    scene = footage_or_scene(data, path, target, design, tracker)
    if not isinstance(scene, Scene):
        raise UsageError(f"{path} has no target: give --target X,Y@STEP")
    return scene


def footage_or_scene(
    data: Any,
    path: str,
    target: str | None = None,
    design: str | None = None,
    tracker: TrackerConfig | None = None,
) -> Scene | Footage:
    """:func:`scene_with_target`, or the footage when it has no target and none is given
    (a multi-target design tracks every object without one)."""
    footage, own = footage_from_dict(data, path)
    if tracker is not None:
        footage = dataclasses.replace(footage, tracker=tracker)
        check_fits(tracker, own if target is None else None, path)
    if design:
        footage = dataclasses.replace(
            footage, tracker=dataclasses.replace(footage.tracker, design=design)
        )
    if target is not None:
        return place_target(footage, parse_target(target))
    return footage if own is None else footage.with_target(own, footage.meta)


def load_scene_with_target(
    path: str,
    target: str | None = None,
    design: str | None = None,
    tracker: TrackerConfig | None = None,
) -> Scene:
    """:func:`scene_with_target` of a scene file."""
    return scene_with_target(read_json(Path(path), InputError), path, target, design, tracker)


def check_target(spec: TargetSpec, width: int, height: int, n_frames: int) -> None:
    """``--target`` inside a ``width`` x ``height`` frame and among the ``n_frames`` frames
    of a video (before it is perceived)."""
    if not (0 <= spec.x < width and 0 <= spec.y < height):
        raise UsageError(
            f"--target {spec.x:g},{spec.y:g} is outside the frames: x must lie in 0..{width} "
            f"and y in 0..{height} (pixels)"
        )
    if spec.step is not None and spec.step >= n_frames:
        raise UsageError(f"--target step {spec.step}: the video has frames 0..{n_frames - 1}")
