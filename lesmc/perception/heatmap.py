"""Heatmap detectors on whole frames: decoding a score map, and running a detector file.

Decoding (docs/detectors.md, "Decoding"): a detection is a cell whose score is
``>= threshold`` and ``>=`` every cell of the (2r+1) x (2r+1) square around it
(r = ``nms_radius``; the square is cut at the map's edges); of equal cells in one
square, the first in row-major order wins. It sits at its cell's centre,
((col + 0.5) · stride, (row + 0.5) · stride) in input pixels. Detections come in
row-major order of their cells; frame k of the directory (natural sort order) is
step k, and detection K of it is ``k:K``.

Sizes (docs/detectors.md, "Sizes"): with ``size = "wh"`` the score map is the output's
channel 0 and a detection's box is (w, h) = channels 1, 2 at its peak cell, in input
pixels, centred on the detection. A detection whose w or h is not a finite number > 0
is an error (:func:`with_sizes`); an injection candidate's, a candidate left out.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np

from lesmc.common.errors import InputError, Location

if TYPE_CHECKING:
    from lesmc.perception.detector_file import LoadedDetector
    from lesmc.scene import Detection, Footage
    from lesmc.video.reader import FrameSet


@dataclass(frozen=True)
class HeatmapDetections:
    """One frame's detections: frame index, (n, 2) positions, (n,) scores, (n, 2) cells
    (row, col), in row-major order of the cells; their payoffs once priced."""

    index: int
    positions: np.ndarray
    scores: np.ndarray
    cells: np.ndarray
    payoffs: np.ndarray | None = None  #: (n,) inf: unattackable; None: unpriced
    lower: np.ndarray | None = None  #: (n,) certified lower bounds; None: not certified
    #: injection candidates (:func:`with_candidates`): (c, 2) cells (row, col), row-major
    cand_cells: np.ndarray = field(default_factory=lambda: np.zeros((0, 2), np.int64))
    #: (c,) each candidate's K: its place, row-major, among all of the frame's local maxima
    #: below the threshold (its id is ``FRAME:cK``, to_scene.candidate_id)
    cand_keys: np.ndarray = field(default_factory=lambda: np.zeros(0, np.int64))
    #: (c,) the prices of injecting them (inf: the attack found none); None: unpriced
    cand_payoffs: np.ndarray | None = None
    #: (n, 2) each detection's box (w, h) in input pixels (``size = "wh"``); None: no size
    #: outputs
    sizes: np.ndarray | None = None
    #: (c, 2) each candidate's box (w, h) at its cell (``size = "wh"``); None: no size outputs
    cand_sizes: np.ndarray | None = None


def peaks(scores: np.ndarray, threshold: float, radius: int) -> np.ndarray:
    """(n, 2) the (row, col) of the detections of the (rows, cols) ``scores``, row-major.

    A cell is kept when its score is ``>= threshold`` and it is a local maximum
    (:func:`maxima`).
    """
    s = np.asarray(scores, dtype=np.float64)
    return np.argwhere(maxima(s, radius) & (s >= threshold))


def sub_peaks(scores: np.ndarray, threshold: float, radius: int) -> np.ndarray:
    """(n, 2) the (row, col) of the local maxima (:func:`maxima`) of ``scores`` that score
    below ``threshold``, row-major: where a heatmap detector's injection candidates sit."""
    s = np.asarray(scores, dtype=np.float64)
    return np.argwhere(maxima(s, radius) & (s < threshold))


def maxima(scores: np.ndarray, radius: int) -> np.ndarray:
    """(rows, cols) bool: the cells ``>=`` every cell within ``radius`` (Chebyshev
    distance; the square is cut at the map's edges) and ``>`` every such cell that comes
    before them in row-major order (of equal cells, the first wins)."""
    s = np.asarray(scores, dtype=np.float64)
    rows, cols = s.shape
    r = int(radius)
    padded = np.full((rows + 2 * r, cols + 2 * r), -np.inf)
    padded[r : r + rows, r : r + cols] = s
    keep = np.ones(s.shape, bool)
    for dy in range(-r, r + 1):
        for dx in range(-r, r + 1):
            if dy == 0 and dx == 0:
                continue
            other = padded[r + dy : r + dy + rows, r + dx : r + dx + cols]
            earlier = dy < 0 or (dy == 0 and dx < 0)
            keep &= (s > other) if earlier else (s >= other)
    return keep


def decode(raw: np.ndarray, det: LoadedDetector, index: int) -> HeatmapDetections:
    """Frame ``index``'s detections from the network's raw (rows, cols) output."""
    from lesmc.perception.detector_file import score_of

    spec = det.spec
    sc = score_of(raw, spec.score)
    cells = peaks(sc, spec.threshold, spec.nms_radius)
    pos = cell_positions(cells, spec.stride)
    return HeatmapDetections(index, pos, sc[cells[:, 0], cells[:, 1]], cells)


def sizes_at(maps: np.ndarray, cells: np.ndarray) -> np.ndarray:
    """(n, 2) the (w, h) that channels 1, 2 of the (K, rows, cols) ``maps`` hold at the
    (n, 2) ``cells`` (row, col): the boxes of ``size = "wh"``, in input pixels."""
    c = np.asarray(cells, np.int64).reshape(-1, 2)
    return np.stack([maps[1, c[:, 0], c[:, 1]], maps[2, c[:, 0], c[:, 1]]], axis=1).astype(
        np.float64
    )


def good_sizes(positions: np.ndarray, sizes: np.ndarray) -> np.ndarray:
    """(n,) bool: the (n, 2) boxes (w, h) centred on the (n, 2) ``positions`` (x, y) that
    a scene holds (lesmc/scene/io.py: w and h finite, > 0 and at most ``MAX_COORD``, with
    corners x ± w/2, y ± h/2 apart in floating point, ``box_problem``)."""
    from lesmc.common.fields import positive
    from lesmc.scene.io import MAX_COORD, box_problem

    pos = np.asarray(positions, np.float64).reshape(-1, 2).tolist()
    wh = np.asarray(sizes, np.float64).reshape(-1, 2).tolist()
    ok = [
        positive(w, MAX_COORD) and positive(h, MAX_COORD) and box_problem(x, y, w, h) is None
        for (x, y), (w, h) in zip(pos, wh, strict=True)
    ]
    return np.array(ok, dtype=bool)


def with_sizes(
    fd: HeatmapDetections, maps: np.ndarray, det: LoadedDetector, where: Location
) -> HeatmapDetections:
    """``fd`` with each detection's box read from the (K, rows, cols) ``maps`` at its cell
    (:func:`sizes_at`). A detection whose box a scene cannot hold (:func:`good_sizes`: w
    or h not a finite number > 0, or too small for its position) is an InputError at
    ``where`` (the frame) naming the detector file's ``size`` line: a box the tracker
    could read (SORT's IoU) cannot be made up for it."""
    from lesmc.scene.io import MAX_COORD

    sizes = sizes_at(maps, fd.cells)
    bad = np.flatnonzero(~good_sizes(fd.positions, sizes))
    if len(bad):
        k = int(bad[0])
        (i, j), (w, h), at = fd.cells[k], sizes[k], det.spec.at("size")
        raise InputError(
            f"detection {fd.index}:{k} (cell row {int(i)}, col {int(j)}) has width {w:g} and "
            f"height {h:g} in output channels 1, 2 ({len(bad)} detection(s) of this frame "
            f'have no box a scene can hold); size = "wh" ({at.path}:{at.line}) needs '
            "finite widths and heights > 0 at every detection's cell (each at most "
            f"{MAX_COORD:g}, and not too small for its position)",
            where,
        )
    return replace(fd, sizes=sizes)


def with_candidates(
    raw: np.ndarray,
    det: LoadedDetector,
    fd: HeatmapDetections,
    within: float,
    cap: int,
    maps: np.ndarray | None = None,
) -> HeatmapDetections:
    """``fd`` with its injection candidates (docs/detectors.md, "Injection candidates"):
    the local maxima of the score map ``raw`` decodes to that score below the threshold
    (:func:`sub_peaks`), whose cell centre lies within ``within`` px of one of ``fd``'s
    detections; nearest a detection first (ties: the lower K), at most ``cap``; kept in
    row-major order. With ``maps`` (``size = "wh"``, (K, rows, cols)), each candidate's box
    is the one at its cell, and a candidate whose box a scene cannot hold
    (:func:`good_sizes`) is left out (before the cap)."""
    from scipy.spatial import cKDTree

    from lesmc.perception.detector_file import score_of

    spec = det.spec
    subs = sub_peaks(score_of(raw, spec.score), spec.threshold, spec.nms_radius)
    if not len(subs) or not len(fd.positions):
        return fd
    pos = cell_positions(subs, spec.stride)
    d, _ = cKDTree(fd.positions).query(pos)
    near = np.flatnonzero(d <= within)
    sizes = None if maps is None else sizes_at(maps, subs)
    if sizes is not None:
        near = near[good_sizes(pos[near], sizes[near])]
    keys = np.sort(near[np.lexsort((near, d[near]))][:cap]).astype(np.int64)
    got = replace(fd, cand_cells=subs[keys].astype(np.int64), cand_keys=keys)
    return got if sizes is None else replace(got, cand_sizes=sizes[keys])


def cell_positions(cells: np.ndarray, stride: int) -> np.ndarray:
    """(n, 2) the input-pixel centres (x, y) of (n, 2) cells (row, col)."""
    return ((np.asarray(cells)[:, ::-1].astype(np.float64) + 0.5) * stride).reshape(-1, 2)


def cells_of(positions: np.ndarray, stride: int) -> np.ndarray:
    """(n, 2) the cells (row, col) whose centres are the (n, 2) ``positions`` (x, y): the
    inverse of :func:`cell_positions` (a scene's detections back to their cells)."""
    xy = np.asarray(positions, np.float64).reshape(-1, 2)
    return np.rint(xy[:, ::-1] / stride - 0.5).astype(np.int64)


def frame_input(frames: FrameSet, i: int, det: LoadedDetector) -> np.ndarray:
    """Frame ``i`` as the network's input (1, C, H, W), float32 in the detector file's
    ``scale``: grey as every verb reads frames (``FrameSet.read``), or red, green, blue."""
    spec = det.spec
    if spec.channels == "rgb":
        img = _rgb8(frames.paths[i], frames.scale)
        chw = img.transpose(2, 0, 1)
    else:
        chw = frames.read(i)[None]
    lo, hi = spec.scale
    x = lo + (hi - lo) * (chw.astype(np.float32) / np.float32(255.0))
    return np.ascontiguousarray(x[None], dtype=np.float32)


def _rgb8(path: Path, scale: float) -> np.ndarray:
    """A frame as (H, W, 3) uint8 red, green, blue (grey frames repeated; 16-bit scaled by
    the video's factor, as ``FrameSet.read`` scales grey)."""
    import cv2

    read = cv2.imread(str(path), cv2.IMREAD_UNCHANGED)
    if read is None:  # checked when the frames were opened; gone since
        raise InputError("cannot decode the image", Location(str(path)))
    img: np.ndarray = read
    if img.ndim == 2:
        img = np.repeat(img[:, :, None], 3, axis=2)
    elif img.shape[2] == 1:
        img = np.repeat(img, 3, axis=2)
    else:
        code = cv2.COLOR_BGRA2RGB if img.shape[2] == 4 else cv2.COLOR_BGR2RGB
        img = cv2.cvtColor(img, code)
    if img.dtype == np.uint8 and scale == 1.0:
        return np.asarray(img)
    return np.asarray(cv2.convertScaleAbs(img, alpha=scale))


def check_frames(frames: FrameSet, det: LoadedDetector, frames_dir: str) -> LoadedDetector:
    """The detector reading the frames: a network that reads any size (ONNX exported with
    dynamic H, W) is given theirs; a network of one fixed H x W must have the frames' size."""
    from lesmc.perception.detector_file import sized

    det = sized(det, frames.width, frames.height, Location(frames_dir))
    if (frames.width, frames.height) != (det.width, det.height):
        raise InputError(
            f"the frames are {frames.width}x{frames.height}; the detector's network "
            f"{det.spec.network} takes {det.width}x{det.height} inputs (width x height); "
            "export it with dynamic height and width to read frames of any size "
            "(docs/detectors.md)",
            Location(frames_dir),
        )
    return det


#: ``price(frame input, detections)``: the detections with their payoffs (and certified
#: lower bounds where asked for; lesmc.experiment.perceive).
Pricer = Callable[[np.ndarray, HeatmapDetections], HeatmapDetections]


def run_detector(
    frames: FrameSet,
    det: LoadedDetector,
    on_frame: Callable[[], None] | None = None,
    price: Pricer | None = None,
    inject: tuple[float, int] | None = None,
) -> list[HeatmapDetections]:
    """The detector on every frame, one frame a batch; with ``size = "wh"`` each detection's
    box (:func:`with_sizes`); with ``inject`` (within px, cap), the injection candidates
    (:func:`with_candidates`); with ``price``, the payoffs."""
    import torch

    out = []
    for i in range(len(frames)):
        arr = frame_input(frames, i, det)
        with torch.no_grad():
            y = det.net.module(torch.from_numpy(arr))
        maps = det.maps(y).double().numpy()[0]
        fd = decode(maps[0], det, i)
        sized = det.spec.size is not None
        if sized:
            fd = with_sizes(fd, maps, det, Location(str(frames.paths[i])))
        if inject is not None:
            fd = with_candidates(maps[0], det, fd, *inject, maps if sized else None)
        out.append(fd if price is None else price(arr, fd))
        if on_frame is not None:
            on_frame()
    return out


def footage_of(
    dets: list[HeatmapDetections],
    det: LoadedDetector,
    dt: float,
    source: str,
    attack: dict[str, Any] | None = None,
    certify: dict[str, Any] | None = None,
    candidates: dict[str, Any] | None = None,
) -> Footage:
    """A scene without a target: step k holds frame k's detections ``k:K``, their payoffs
    (``"unpriced"`` where not priced), no homographies (a still camera); ``meta`` records
    the detector file and its network, ``attack``, the settings of the payoffs, and
    ``certify``, those of the certified lower bounds (``payoff_lower``) if computed, and
    ``candidates``, where the injection candidates came from (scene format 3: the priced
    ones, :func:`with_candidates`, ids ``FRAME:cK``) if asked for."""
    from lesmc.scene import Detection, Footage, Frame, TrackerConfig

    frames = tuple(
        Frame(
            fd.index,
            tuple(
                Detection(
                    f"{fd.index}:{k}",
                    float(x),
                    float(y),
                    float("nan") if fd.payoffs is None else float(fd.payoffs[k]),
                    None if fd.lower is None else float(fd.lower[k]),
                    *_size(det, fd.sizes, k),
                )
                for k, (x, y) in enumerate(fd.positions)
            ),
            candidates=_candidates(fd, det),
        )
        for fd in dets
    )
    meta: dict[str, Any] = {
        "source": source,
        "detector": det.spec.describe(),
        "detector_file": det.spec.to_meta(),
    }
    if attack is None:
        meta["payoffs"] = "unpriced (give -o to price a detector file's detections)"
    else:
        meta["attack"] = attack
    if certify is not None:
        meta["certify"] = certify
    if candidates is not None:
        meta["candidates"] = candidates
    return Footage(dt, frames, TrackerConfig(), meta)


def _candidates(fd: HeatmapDetections, det: LoadedDetector) -> tuple[Detection, ...]:
    """Frame ``fd``'s priced injection candidates (scene format 3), ids ``FRAME:cK``, at
    their cells' centres, with the box at their cell or the detector file's declared box
    if any (:func:`_size`); those the attack found no perturbation for are left out."""
    from lesmc.perception.to_scene import candidate_id
    from lesmc.scene import Detection

    if fd.cand_payoffs is None:
        return ()
    pos = cell_positions(fd.cand_cells, det.spec.stride)
    return tuple(
        Detection(
            candidate_id(fd.index, int(k)), float(x), float(y), float(p), None,
            *_size(det, fd.cand_sizes, n),
        )
        for n, (k, (x, y), p) in enumerate(zip(fd.cand_keys, pos, fd.cand_payoffs, strict=True))
        if np.isfinite(p)
    )  # fmt: skip


def _size(
    det: LoadedDetector, sizes: np.ndarray | None, k: int
) -> tuple[float | None, float | None]:
    """The (w, h) detection or candidate ``k`` of a heatmap file carries: its own, from the
    size outputs (``sizes``, ``size = "wh"``), else the file's declared ``box``
    (docs/detectors.md), else (None, None): points."""
    if sizes is not None:
        return float(sizes[k, 0]), float(sizes[k, 1])
    box = det.spec.box
    return (None, None) if box is None else box
