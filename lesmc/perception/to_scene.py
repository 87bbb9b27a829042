"""Detections and payoffs of a video -> a scene file for the tracker and the model builder.

Model step k is video frame k (frames before the first detected frame, which
only fill the background history, are not in the scene). Modelling assumption
(docs/cnn.md): detections and payoffs are computed once on the clean video and
an attack at step k hides detections of frame k only.
"""

from __future__ import annotations

from typing import TYPE_CHECKING, Any

import numpy as np
from scipy.spatial import cKDTree

from lesmc.common.errors import UsageError
from lesmc.perception.quality import TruthFrame
from lesmc.scene import Detection, Footage, Frame, TrackerConfig

if TYPE_CHECKING:  # torch and cv2 only where frames are perceived: not for a cached run
    from lesmc.perception.detector import FrameDetections
    from lesmc.perception.run import PerceiveRun


def frames_of(
    dets: list[FrameDetections],
    pays: list[np.ndarray],
    lower: list[np.ndarray] | None = None,
    inject: list[np.ndarray] | None = None,
    box: float | None = None,
) -> tuple[Frame, ...]:
    """Scene frames: detection ids ``"FRAME:I"``, payoffs [and certified lower bounds],
    homographies to the next frame; with ``inject`` (each frame's injection prices,
    ``PerceiveRun.inject_payoffs``), the injection candidates (:func:`candidates_of`);
    with ``box``, each detection's (and candidate's) box is its window, a ``box`` x
    ``box`` square centred on it (scene format 2; point trackers ignore it)."""
    out = []
    lows: list[np.ndarray | None] = list(lower) if lower else [None] * len(dets)
    injs: list[np.ndarray | None] = list(inject) if inject else [None] * len(dets)
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
                box,
                box,
            )
            for j, (x, y) in enumerate(fd.positions)
        )
        prices = injs[i]
        cands = () if prices is None else candidates_of(fd, prices, box)
        out.append(Frame(fd.index, ds, to_next, candidates=cands))
    return tuple(out)


def candidate_id(frame: int, row: int) -> str:
    """The scene id of the injection candidate that is row ``row`` of frame ``frame``'s
    Q_bc: ``"FRAME:cROW"`` (a replay finds its window by the row). A heatmap detector
    file's candidates (lesmc/perception/heatmap.py) take the same form, ROW their place,
    row-major, among the frame's local maxima below the threshold; a ``c`` never begins a
    detection's ``FRAME:K``, so the ids cannot clash."""
    return f"{frame}:c{row}"


def candidate_row(obs: str) -> int | None:
    """The Q_bc row of an injection candidate's id (:func:`candidate_id`); None for
    another id."""
    _, _, rest = obs.partition(":")
    return int(rest[1:]) if rest[:1] == "c" and rest[1:].isdigit() else None


def candidates_of(
    fd: FrameDetections, prices: np.ndarray, box: float | None = None
) -> tuple[Detection, ...]:
    """A frame's injection candidates (scene format 3): the rejected candidates whose
    attack towards "vehicle" succeeded (a finite price), at their centroids (with
    ``box``, a ``box`` x ``box`` window around each)."""
    return tuple(
        Detection(candidate_id(fd.index, int(r)), float(x), float(y), float(p), None, box, box)
        for r, (x, y), p in zip(fd.rejected, fd.rejected_positions, prices, strict=True)
        if np.isfinite(p)
    )


def footage_from_run(run: PerceiveRun, dt: float, meta: dict[str, Any] | None = None) -> Footage:
    """The scene without a target of a ``perceive`` run: detections ``"FRAME:I"``, payoffs,
    certified lower bounds when the run computed them, homographies; each detection's box
    is the run's window around it (``run.box_px``: N_dr's 21 x 21), so that an IoU
    tracker (``--design sort``) can run on the video."""
    if not run.detections:
        raise UsageError("no frame produced detections: the video is shorter than L+1 frames")
    lower = run.payoffs_lower or None
    inject = run.inject_payoffs if any(len(p) for p in run.inject_payoffs) else None
    frames = frames_of(run.detections, run.payoffs, lower, inject, float(run.box_px))
    return Footage(dt, frames, TrackerConfig(), dict(meta or {}))


def truth_velocity(truth: TruthFrame | None, x: float, y: float) -> tuple[float, float] | None:
    """The velocity (px/s) of the true vehicle nearest to (x, y) within :data:`SNAP_PX`, if
    the truth of the target's frame has one."""
    if truth is None or not len(truth.positions) or truth.velocity is None:
        return None
    d, j = cKDTree(truth.positions).query(np.array([x, y]))
    if d > SNAP_PX:
        return None
    return float(truth.velocity[j, 0]), float(truth.velocity[j, 1])


#: A true vehicle this close (px) to the target is the target.
SNAP_PX = 6.0
