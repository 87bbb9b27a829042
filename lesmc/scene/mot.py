"""Detections from MOTChallenge text files (det.txt, gt.txt): the user's own detector output.

A line is ``frame,id,bb_left,bb_top,bb_width,bb_height[,conf[,x,y,z]]`` (the MOT15-MOT20
layouts; gt.txt's 7th-9th columns are a flag, a class and a visibility), comma-separated,
spaces allowed around the numbers. One detection per line, at the box's centre or, with
``point="bottom"``, at its bottom centre (the ground point). docs/own-system.md has
the rules; in short:

* frames are integers >= 0 (MOTChallenge counts from 1); a frame with no line is a
  frame without detections, so the scene's steps run from the first frame to the last;
* det.txt lines must come in non-decreasing frame order (every MOTChallenge det.txt
  does); gt.txt lines may come in any order (MOT17's are sorted by track);
* widths and heights are > 0, every number finite, ids integers (-1: none).

Payoffs: one constant for every detection (1 makes the optimum the number of
detections an attacker must hide), or a column of the file (``inf`` there: unattackable).
With :class:`Inject` (``--inject-column K --threshold T``), the lines whose conf (column
7) is below T are injection candidates, not detections (scene format 3; issue 61): the
low-score detections a two-stage tracker such as ByteTrack keeps, which an attacker may
raise above the threshold at the price in column K.
Writing (:func:`write_det`, :func:`write_gt`) is the inverse, used by tests and examples.
"""

from __future__ import annotations

import math
from collections.abc import Iterable, Sequence
from dataclasses import dataclass, replace
from pathlib import Path
from typing import Literal

from lesmc.common.errors import InputError, Location, UsageError
from lesmc.common.fields import MAX_STEP
from lesmc.common.files import atomic_write_text, read_text
from lesmc.common.numbers import MAX_PAYOFF
from lesmc.scene.frames import Detection, Frame
from lesmc.scene.io import MAX_COORD, MAX_TRUTH, box_problem
from lesmc.scene.scene import Footage, Scene, Target, TrackerConfig, TruthTrack

Point = Literal["center", "bottom"]
#: Columns a line must have, and may have.
MIN_COLUMNS, MAX_COLUMNS = 6, 10


@dataclass(frozen=True)
class Box:
    """One line of a MOT file: frame, id, box, the line's number and its extra columns."""

    frame: int
    id: int
    left: float
    top: float
    width: float
    height: float
    line: int
    extra: tuple[float, ...]  # columns 7.. (conf, x, y, z or flag, class, visibility)

    def point(self, where: Point) -> tuple[float, float]:
        """The detection's position: the box's centre or its bottom centre."""
        x = self.left + self.width / 2.0
        y = self.top + (self.height if where == "bottom" else self.height / 2.0)
        return (x, y)


def read_boxes(path: str | Path, sorted_frames: bool) -> list[Box]:
    """Every line of a MOT file as a :class:`Box`; a malformed line is an
    ``InputError`` at ``FILE:LINE:COL``. ``sorted_frames``: frames must not decrease."""
    text = read_text(path)
    name = str(path)
    boxes: list[Box] = []
    last = -1
    for n, raw in enumerate(text.split("\n"), start=1):
        line = raw.removesuffix("\r")
        if not line.strip():
            continue
        box = _box(line, n, name)
        if sorted_frames and box.frame < last:
            raise InputError(
                f"frame {box.frame} comes after frame {last}: det.txt lines must be in "
                "non-decreasing frame order",
                Location(name, n, 1, line),
            )
        last = max(last, box.frame)
        boxes.append(box)
    if not boxes:
        raise InputError("no detections: the file has no lines", Location(name))
    return boxes


def _box(line: str, n: int, path: str) -> Box:
    cols = _split(line)
    if not MIN_COLUMNS <= len(cols) <= MAX_COLUMNS:
        raise InputError(
            f"expected {MIN_COLUMNS} to {MAX_COLUMNS} comma-separated columns "
            f"(frame,id,bb_left,bb_top,bb_width,bb_height[,conf,x,y,z]), got {len(cols)}",
            Location(path, n, 1, line),
        )
    values: list[float] = []
    for i, (col, text) in enumerate(cols):
        values.append(_number(text, i, _at_column(path, n, line, col, text)))
    frame, ident = values[0], values[1]
    if not (frame.is_integer() and 0 <= frame <= MAX_STEP):
        raise InputError(
            f"frame must be an integer in 0..{MAX_STEP}, got {cols[0][1].strip()}",
            Location(path, n, 1, line),
        )
    if not ident.is_integer():
        raise InputError(
            f"id must be an integer (-1: none), got {cols[1][1].strip()}",
            Location(path, n, cols[1][0] + 1, line),
        )
    for i, what in ((4, "bb_width"), (5, "bb_height")):
        if not values[i] > 0:
            raise InputError(
                f"{what} must be > 0, got {cols[i][1].strip()}",
                Location(path, n, cols[i][0] + 1, line),
            )
    left, top, width, height = values[2:6]
    return Box(int(frame), int(ident), left, top, width, height, n, tuple(values[6:]))


def _split(line: str) -> list[tuple[int, str]]:
    """The comma-separated fields of ``line`` with their offsets."""
    out, start = [], 0
    for part in line.split(","):
        out.append((start, part))
        start += len(part) + 1
    return out


_NAMES = (
    "frame",
    "id",
    "bb_left",
    "bb_top",
    "bb_width",
    "bb_height",
    "column 7",
    "column 8",
    "column 9",
    "column 10",
)


def _number(text: str, i: int, where: Location) -> float:
    """Column ``i``'s number: ASCII digits only (Python's ``float`` also takes other
    scripts' digits and ``1_000``, which no MOT reader does)."""
    s = text.strip()
    try:
        if not s.isascii() or "_" in s:
            raise ValueError(s)
        v = float(s)
    except ValueError:
        raise InputError(f"{_NAMES[i]} must be a number, got '{s[:20]}'", where) from None
    if i < 6 and not (math.isfinite(v) and abs(v) <= MAX_COORD):
        raise InputError(
            f"{_NAMES[i]} must be a finite number within ±{MAX_COORD:g}, got {s}", where
        )
    if i >= 6 and math.isnan(v):
        raise InputError(f"{_NAMES[i]} must be a number, got {s}", where)
    if math.isinf(v) and s.lstrip("+-").lower() not in ("inf", "infinity"):
        raise InputError(f"{_NAMES[i]} {s} is beyond the range of a float (write inf)", where)
    return v


# ---------------------------------------------------------------- to a scene


@dataclass(frozen=True)
class Payoffs:
    """How detections are priced: one ``constant`` or the 1-based ``column`` of the file."""

    constant: float = 1.0
    column: int | None = None

    def words(self) -> str:
        """Where the payoffs come from, for the scene's ``meta.payoffs`` (the report says)."""
        if self.column is None:
            return f"the constant {self.constant:g} for every detection (import mot --payoff)"
        conf = " (conf)" if self.column == 7 else ""
        return f"column {self.column}{conf} of the det.txt (import mot --payoff-column)"


@dataclass(frozen=True)
class Inject:
    """Which lines are injection candidates: those whose conf (column 7) is below
    ``threshold``; each costs the number in the 1-based ``column`` to inject."""

    column: int
    threshold: float

    def words(self) -> str:
        """Where the candidates come from, for the scene's ``meta.candidates``."""
        return (
            f"the lines of conf (column 7) < {self.threshold:g}, priced by column "
            f"{self.column} (import mot --inject-column --threshold)"
        )


def footage_from_boxes(
    boxes: Sequence[Box],
    path: str,
    dt: float,
    point: Point = "center",
    payoffs: Payoffs = Payoffs(),
    tracker: TrackerConfig | None = None,
    inject: Inject | None = None,
) -> Footage:
    """Frames of detections (steps = MOT frame numbers, every frame from the first to the
    last; ids ``FRAME:K``, K the line's place among the frame's lines), each with its
    box's w, h when ``point`` is the centre; with ``inject``, the lines it selects are
    the frames' injection candidates instead."""
    by_frame: dict[int, list[Detection]] = {}
    cands: dict[int, list[Detection]] = {}
    lines: dict[int, int] = {}
    for b in boxes:
        x, y = b.point(point)
        if not (abs(x) <= MAX_COORD and abs(y) <= MAX_COORD):
            raise InputError(
                f"the detection's point ({x:g}, {y:g}) lies beyond ±{MAX_COORD:g}",
                Location(path, b.line, 1),
            )
        by_frame.setdefault(b.frame, [])
        # the box is kept around a centre point only (at the bottom centre it is not around it)
        w, h = (b.width, b.height) if point == "center" else (None, None)
        if point == "center" and (why := box_problem(x, y, b.width, b.height)) is not None:
            raise InputError(why, Location(path, b.line, 1))
        k = lines[b.frame] = lines.get(b.frame, -1) + 1
        if inject is not None and _is_candidate(b, inject, path):
            pay = _inject_payoff(b, inject, path)
            cands.setdefault(b.frame, []).append(Detection(f"{b.frame}:{k}", x, y, pay, None, w, h))
            continue
        pay = _payoff(b, payoffs, path)
        by_frame[b.frame].append(Detection(f"{b.frame}:{k}", x, y, pay, None, w, h))
    first, last = min(by_frame), max(by_frame)
    frames = tuple(
        Frame(k, tuple(by_frame.get(k, ())), candidates=tuple(cands.get(k, ())))
        for k in range(first, last + 1)
    )
    meta = {"source": path, "format": "MOTChallenge", "point": point, "payoffs": payoffs.words()}
    if inject is not None:
        meta["candidates"] = inject.words()
    return Footage(dt, frames, tracker or TrackerConfig(), meta)


def _is_candidate(b: Box, inject: Inject, path: str) -> bool:
    """The line's conf (column 7) is below the threshold (a line without one: an error)."""
    if not b.extra:
        raise InputError(
            f"--threshold compares conf (column 7) with {inject.threshold:g}, but the line "
            "has only 6 columns",
            _end_of_line(path, b.line),
        )
    return b.extra[0] < inject.threshold


def _inject_payoff(b: Box, inject: Inject, path: str) -> float:
    """A candidate's price: column ``inject.column``, a number in [0, MAX_PAYOFF]."""
    k = inject.column - 7
    if not 0 <= k < len(b.extra):
        raise InputError(
            f"--inject-column {inject.column}: the line has only {6 + len(b.extra)} columns",
            _end_of_line(path, b.line),
        )
    v = b.extra[k]
    if not 0 <= v <= MAX_PAYOFF:
        raise InputError(
            f"column {inject.column} is the price of injecting this line (its conf is below "
            f"--threshold {inject.threshold:g}): a number in [0, {MAX_PAYOFF:g}], got {v:g}",
            _column_at(path, b.line, inject.column - 1),
        )
    return v


def _end_of_line(path: str, n: int) -> Location:
    """Just past the end of line ``n``, the line quoted: where a missing column would be."""
    line = read_text(path).split("\n")[n - 1].removesuffix("\r")
    return Location(path, n, len(line) + 1, line)


def _payoff(b: Box, p: Payoffs, path: str) -> float:
    if p.column is None:
        return p.constant
    k = p.column - 7
    if not 0 <= k < len(b.extra):
        raise InputError(
            f"--payoff-column {p.column}: the line has only {6 + len(b.extra)} columns",
            Location(path, b.line, 1),
        )
    v = b.extra[k]
    if not (v >= 0 and (math.isinf(v) or v <= MAX_PAYOFF)):
        raise InputError(
            f"column {p.column} is the payoff: a number in [0, {MAX_PAYOFF:g}] "
            f"or inf (unattackable), got {v:g}",
            _column_at(path, b.line, p.column - 1),
        )
    return v


def _column_at(path: str, n: int, i: int) -> Location:
    """Where column ``i`` (0-based) of line ``n`` starts, the line quoted: read again, as
    only an error needs it."""
    line = read_text(path).split("\n")[n - 1].removesuffix("\r")
    return _at_column(path, n, line, *_split(line)[i])


def _at_column(path: str, n: int, line: str, col: int, text: str) -> Location:
    """Line ``n``'s field ``text``, starting at offset ``col``: where its number begins."""
    return Location(path, n, col + 1 + (len(text) - len(text.lstrip())), line)


def one_box_a_frame(gt: Sequence[Box], path: str) -> None:
    """A ground-truth track has one box a frame, in every frame of the file (not only the
    detections'): a second box of a track in a frame is an error at the later line.
    Boxes of id -1 (no track) are exempt."""
    seen: dict[tuple[int, int], Box] = {}
    for b in sorted(gt, key=lambda b: b.line):
        if b.id < 0:
            continue
        a = seen.setdefault((b.id, b.frame), b)
        if a is not b:
            raise InputError(
                f"track {b.id} has two boxes in frame {b.frame} (lines {a.line} and "
                f"{b.line}): a ground-truth track has one box a frame",
                _column_at(path, b.line, 0),
            )


def truth_from_gt(gt: Sequence[Box], path: str, point: Point = "center") -> tuple[TruthTrack, ...]:
    """The scene's ``truth``: every track of ``gt`` (ids >= 0; one box a frame, see
    :func:`one_box_a_frame`) as the point of each of its boxes, by frame; the track's id
    is the gt id written as a string. At the box centres (``point`` "center") the tracks
    keep their boxes' sizes (scene format 2), and are a box tracker's reference
    (lesmc/tracking/multi.py ``reference_boxes``)."""
    by_track: dict[int, list[tuple[int, float, float]]] = {}
    sizes: dict[int, list[tuple[float, float]]] = {}
    for b in sorted(gt, key=lambda b: (b.id, b.frame)):
        if b.id < 0:
            continue
        x, y = b.point(point)
        if not (abs(x) <= MAX_COORD and abs(y) <= MAX_COORD):
            raise InputError(
                f"the box's point ({x:g}, {y:g}) lies beyond ±{MAX_COORD:g}",
                Location(path, b.line, 1),
            )
        by_track.setdefault(b.id, []).append((b.frame, x, y))
        sizes.setdefault(b.id, []).append((b.width, b.height))
    if len(by_track) > MAX_TRUTH:
        raise InputError(
            f"{len(by_track)} ground-truth tracks within the detections' frames: a scene "
            f"carries at most {MAX_TRUTH}",
            Location(path),
        )
    boxed = point == "center" and all(w > 0 and h > 0 for s in sizes.values() for w, h in s)
    return tuple(
        TruthTrack(str(t), tuple(rows), tuple(sizes[t]) if boxed else None)
        for t, rows in by_track.items()
    )


def target_from_gt(
    gt: Sequence[Box], track: int, path: str, dt: float, point: Point = "center"
) -> Target:
    """The target of ground-truth track ``track``: its first box's point and frame, and its
    velocity to its next box (zero if it has none). One box a frame: :func:`one_box_a_frame`."""
    rows = sorted((b for b in gt if b.id == track), key=lambda b: (b.frame, b.line))
    if not rows:
        ids = sorted({b.id for b in gt})
        shown = ", ".join(str(i) for i in ids[:12]) + (" ..." if len(ids) > 12 else "")
        raise UsageError(
            f"--track {track}: {path} has no such track within the detections' frames "
            f"(its tracks there: {shown})"
        )
    first = rows[0]
    start = first.point(point)
    vel = (0.0, 0.0)
    if len(rows) > 1:
        nxt = rows[1]
        p = nxt.point(point)
        gap = (nxt.frame - first.frame) * dt
        vel = ((p[0] - start[0]) / gap, (p[1] - start[1]) / gap)
    return Target(first.frame, start, vel)


def import_mot(
    det: str,
    dt: float,
    point: Point = "center",
    payoffs: Payoffs = Payoffs(),
    gt: str | None = None,
    track: int | None = None,
    tracker: TrackerConfig | None = None,
    inject: Inject | None = None,
) -> Footage | Scene:
    """``lesmc import mot``: the scene of a det.txt, with the target of ground-truth track
    ``track`` of ``gt`` if given (a :class:`Footage` otherwise): its first box among the
    detections' frames. The gt file's tracks within those frames become the scene's
    ``truth`` (what ``dist.nearest`` measures against). ``inject``: which lines are
    injection candidates (:class:`Inject`)."""
    boxes = read_boxes(det, True)
    footage = footage_from_boxes(boxes, det, dt, point, payoffs, tracker, inject)
    if gt is None:
        return footage
    assert track is not None
    first, last = footage.frames[0].step, footage.last_step
    boxes = read_boxes(gt, False)
    one_box_a_frame(boxes, gt)
    inside = [b for b in boxes if first <= b.frame <= last]
    target = target_from_gt(inside, track, gt, dt, point)
    truth = truth_from_gt(inside, gt, point)
    footage = replace(footage, truth=truth)
    return footage.with_target(target, {**footage.meta, "target_from": f"{gt} track {track}"})


# ---------------------------------------------------------------- writing


def _num(v: float) -> str:
    return "inf" if math.isinf(v) else repr(float(v))


def write_det(footage: Footage | Scene, path: str | Path, size: tuple[float, float]) -> None:
    """A det.txt of the scene's detections: boxes of ``size`` (w, h) centred on each
    detection, the payoff in the conf column (7), x, y, z unset (-1)."""
    w, h = size
    lines = [
        ",".join(
            [
                str(f.step),
                "-1",
                _num(d.x - w / 2),
                _num(d.y - h / 2),
                _num(w),
                _num(h),
                _num(d.payoff),
                "-1",
                "-1",
                "-1",
            ]
        )
        for f in footage.frames
        for d in f.detections
    ]
    atomic_write_text(path, "\n".join(lines) + "\n")


def write_gt(
    tracks: Iterable[tuple[int, int, float, float]], path: str | Path, size: tuple[float, float]
) -> None:
    """A gt.txt of ``(track id, frame, x, y)`` centres: boxes of ``size``, flag 1, class 1
    (pedestrian in MOT; lesmc reads neither), visibility 1."""
    w, h = size
    lines = [
        ",".join(
            [str(fr), str(tid), _num(x - w / 2), _num(y - h / 2), _num(w), _num(h), "1", "1", "1"]
        )
        for tid, fr, x, y in tracks
    ]
    atomic_write_text(path, "\n".join(lines) + "\n")
