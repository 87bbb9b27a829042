"""``lesmc import mot DET --frames DIR --detector FILE.toml``: MOT detections priced by the
user's detector (docs/detectors.md, "MOT detections priced").

The detector file runs on every frame and prices each of its detections
(:func:`~lesmc.experiment.perceive.perceive_with_file`). MOT frame ``f`` (numbered from
1) is frame ``f - 1`` of the directory (natural sort order). Each det.txt box takes the
payoff of the detector's detection it matches, one to one, greedily, best match first:

* a box detector, or a heatmap detector with size outputs (``size = "wh"``: each
  detection's box from them): the detection box of largest IoU with it, IoU >= 0.5;
* another heatmap detector: the detection whose peak cell is nearest (in pixels, between cell
  centres) to the cell the box's centre falls in, within ``nms_radius`` cells
  (Chebyshev) of it: the square whose cells hiding lowers.

A box that matches nothing, or lies in a frame the directory lacks, is never priced: it
is ``"unpriced"`` in the scene (a check that reads it stops with exit 2), listed in the
scene's ``meta.unmatched`` and returned as a warning line.
"""

from __future__ import annotations

from collections.abc import Container
from dataclasses import dataclass, replace
from typing import TYPE_CHECKING

import numpy as np

from lesmc.common.errors import InputError, Location

if TYPE_CHECKING:
    from lesmc.perception.boxes import BoxDetections
    from lesmc.perception.detector_file import LoadedDetector
    from lesmc.perception.heatmap import HeatmapDetections
    from lesmc.scene import Footage, Scene
    from lesmc.scene.mot import Box

#: A box detector's detection matches a det.txt box with at least this IoU.
MIN_IOU = 0.5


@dataclass(frozen=True)
class Priced:
    """The footage with the matched boxes priced, and one warning per unmatched box."""

    footage: Footage | Scene
    warnings: list[str]


def price_mot(
    footage: Footage | Scene, boxes: list[Box], det_path: str, frames_dir: str, detector: str
) -> Priced:
    """``footage`` (from ``boxes`` of ``det_path``, ids ``FRAME:K``) with each box's payoff
    that of the detector's detection it matches (module docstring); the others unpriced."""
    from lesmc.experiment.perceive import PerceiveRequest, perceive_with_file

    req = PerceiveRequest(frames_dir, (None, detector, None), dt=footage.dt)
    got = perceive_with_file(req, detector)
    by_index = {d.index: d for d in got.detections}
    pays: dict[str, float] = {}
    where: dict[str, Box] = {}
    lines: dict[int, int] = {}
    per_frame: dict[int, list[tuple[str, Box]]] = {}
    for b in boxes:  # ids as footage_from_boxes gives them: K, the line's place in its frame
        k = lines[b.frame] = lines.get(b.frame, -1) + 1
        per_frame.setdefault(b.frame, []).append((f"{b.frame}:{k}", b))
        where[f"{b.frame}:{k}"] = b
    for frame, items in per_frame.items():
        found = by_index.get(frame - 1)
        if found is None:
            continue
        for (obs, _), j in zip(items, _match(got.detector, found, [b for _, b in items]),
                               strict=True):  # fmt: skip
            if j is not None and found.payoffs is not None:
                pays[obs] = float(found.payoffs[j])
    unmatched = [obs for obs in where if obs not in pays]
    frames = tuple(
        replace(
            fr,
            detections=tuple(
                replace(d, payoff=pays.get(d.id, float("nan"))) for d in fr.detections
            ),
        )
        for fr in footage.frames
    )
    meta = dict(footage.meta)
    meta["payoffs"] = (
        f"the detector file {detector}'s payoff of the detection each box matches "
        f"(frames {frames_dir}; import mot --detector; docs/detectors.md)"
    )
    meta["detector"] = got.detector.spec.describe()
    meta["detector_file"] = got.detector.spec.to_meta()
    meta["frames"] = frames_dir  # what a replay reads (lesmc/pipeline/check.py replay_command)
    meta["frames_offset"] = -1  # MOT frame f is the directory's frame f - 1 (a replay's too)
    if got.scene is not None and "attack" in got.scene.meta:
        meta["attack"] = got.scene.meta["attack"]
    if unmatched:
        meta["unmatched"] = unmatched
    warnings = [_warning(det_path, where[obs], obs, frames_dir, by_index) for obs in unmatched]
    return Priced(replace(footage, frames=frames, meta=meta), warnings)


def _warning(det_path: str, b: Box, obs: str, frames_dir: str, known: Container[int]) -> str:
    """One unmatched box, located at its line of the det.txt."""
    why = (
        f"frame {b.frame} is not in {frames_dir} (MOT frame f is its frame f - 1)"
        if b.frame - 1 not in known
        else "no detection of the detector matches it"
    )
    return (
        f"{Location(det_path, b.line, 1).prefix()}: box {obs} ({b.left:g}, {b.top:g}, "
        f"{b.width:g} x {b.height:g}) is unpriced: {why}"
    )


def _match(
    det: LoadedDetector, found: HeatmapDetections | BoxDetections, boxes: list[Box]
) -> list[int | None]:
    """For each box, the index of the detection it matches (one to one, best first), or
    None."""
    n = len(found.positions)
    if not n or not boxes:
        return [None] * len(boxes)
    pairs: list[tuple[float, int, int]] = []  # (badness, box, detection)
    boxed = _boxes_of(found)
    if boxed is not None:
        from lesmc.perception.boxes import iou

        for i, b in enumerate(boxes):
            xyxy = np.array([b.left, b.top, b.left + b.width, b.top + b.height])
            for j, v in enumerate(iou(xyxy, boxed)):
                if v >= MIN_IOU:
                    pairs.append((-float(v), i, j))
    else:
        s, r = det.spec.stride, det.spec.nms_radius
        cells = np.asarray(found.cells)  # type: ignore[union-attr]
        for i, b in enumerate(boxes):
            cx, cy = b.left + b.width / 2.0, b.top + b.height / 2.0
            row, col = int(np.floor(cy / s)), int(np.floor(cx / s))
            for j, (pr, pc) in enumerate(cells.tolist()):
                if max(abs(pr - row), abs(pc - col)) <= r:
                    pairs.append((float(np.hypot(pr - row, pc - col)) * s, i, j))
    out: list[int | None] = [None] * len(boxes)
    taken: set[int] = set()
    for _, i, j in sorted(pairs):
        if out[i] is None and j not in taken:
            out[i] = j
            taken.add(j)
    return out


def _boxes_of(found: HeatmapDetections | BoxDetections) -> np.ndarray | None:
    """(n, 4) the detections' boxes [x1, y1, x2, y2] where the detector measures them (a box
    detector's; a heatmap's with ``size = "wh"``, centred on each detection), else None."""
    from lesmc.perception.heatmap import HeatmapDetections

    if not isinstance(found, HeatmapDetections):
        return np.asarray(found.boxes)
    if found.sizes is None:
        return None
    half = found.sizes / 2.0
    return np.concatenate([found.positions - half, found.positions + half], axis=1)


def refuse_outside(boxes: list[Box], det_path: str) -> None:
    """MOT frames are numbered from 1: a box of frame 0 or less cannot be a frame of the
    directory (an error at its line)."""
    for b in boxes:
        if b.frame < 1:
            raise InputError(
                f"frame {b.frame}: MOT frames are numbered from 1 (frame f is frame f - 1 of "
                "--frames)",
                Location(det_path, b.line, 1),
            )
