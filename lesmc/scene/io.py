"""Scene files (.json): reading, validating and writing them (docs/scene-format.md).

Validation is as strict as the .lts loader's and reports every problem at
once, each by frame and detection id. The limits below keep the tracker's
arithmetic finite for any real video.
"""

from __future__ import annotations

import itertools
import math
from pathlib import Path
from typing import Any

import numpy as np

from lesmc.common.errors import InputError, Problems
from lesmc.common.fields import (
    MAX_STEP,
    is_finite,
    is_int,
    is_version,
    positive,
    show,
    within,
)
from lesmc.common.files import read_json, write_json
from lesmc.common.numbers import MAX_PAYOFF
from lesmc.scene.frames import Detection, Frame
from lesmc.scene.located import scene_error
from lesmc.scene.meta_attack import recorded_attack, recorded_frontend
from lesmc.scene.scene import (
    UNATTACKABLE,
    UNPRICED,
    Footage,
    Scene,
    Target,
    TrackerConfig,
    TruthTrack,
)
from lesmc.scene.tracker_file import tracker_block
from lesmc.scene.tracker_model import (
    VELOCITY,
    velocity,
)

#: Ranges of a scene's numbers (docs/scene-format.md, "Limits"): wide enough for any
#: real video, narrow enough that the tracker's arithmetic stays finite.
MAX_DT = 3600.0  #: seconds between frames
MAX_COORD = 1e7  #: |x|, |y| of detections and of the target's start (pixels)
MAX_VELOCITY = 1e6  #: |vx|, |vy| of the target's initial velocity (pixels per second)
MAX_HOMOGRAPHY = 1e6  #: |entry| of a frame-to-frame homography
FORMAT = "lesmc-scene"
#: The newest version: 2 added detection boxes (``w``, ``h``), 3 injection candidates
#: (a frame's ``candidates``). The loader reads every version in :data:`VERSIONS`; the
#: writer writes the lowest one that holds the scene (1 when no detection has a box and
#: no frame a candidate), so older lesmc releases still read the scenes they could.
VERSION = 3
VERSIONS = (1, 2, 3)
#: The version that added each feature a scene may use.
BOXES_VERSION, CANDIDATES_VERSION = 2, 3


def load_scene(path: str | Path) -> Scene:
    """Read and validate a scene file (every problem reported by frame and detection id)."""
    return scene_from_dict(read_json(path, InputError), str(path))


def scene_from_dict(data: Any, path: str = "<scene>") -> Scene:
    """A scene with its target (a file without one is an error)."""
    footage, target = footage_from_dict(data, path, need_target=True)
    assert target is not None
    return footage.with_target(target, footage.meta)


def footage_from_dict(
    data: Any, path: str = "<scene>", need_target: bool = False
) -> tuple[Footage, Target | None]:
    """A scene file's frames and tracker, and its target if it has one."""
    pr = Problems()
    if not isinstance(data, dict):
        raise InputError.many(path, [("", "the top level must be a JSON object")])
    allowed = {
        "format",
        "version",
        "dt",
        "frames",
        "target",
        "tracker",
        "meta",
        "comment",
        "truth",
    }
    for key in sorted(set(data) - allowed):
        pr.add(f"key '{key}'", "unknown top-level key")
    version = _version(data, pr)
    dt = data.get("dt", 1.0)
    if not (is_finite(dt) and 0 < dt <= MAX_DT):
        pr.add("dt", f"must be a number of seconds in (0, {MAX_DT:g}], got {show(dt)}")
        dt = 1.0
    frames = _frames(data.get("frames"), pr, version)
    truth = _truth(data.get("truth", []), _steps(data.get("frames"), frames), pr, version)
    tracker = tracker_block(data.get("tracker", {}), pr)
    target = None
    if need_target or data.get("target") is not None:
        target = _target(data.get("target"), pr)
    raw = data.get("frames")  # every frame read, else the steps are not all known
    whole = isinstance(raw, list) and len(frames) == len(raw)
    if (
        target is not None
        and frames
        and whole
        and not frames[0].step <= target.step <= frames[-1].step
    ):
        pr.add(
            "target",
            f"step {target.step} is not among the frames {frames[0].step}..{frames[-1].step}",
        )
    raw_meta = data.get("meta")
    meta: dict[str, Any] = raw_meta if isinstance(raw_meta, dict) else {}
    if raw_meta is not None and not isinstance(raw_meta, dict):
        pr.add("meta", f"must be an object, got {show(raw_meta)}")
    recorded_attack(meta, pr)
    recorded_frontend(meta, pr)
    if pr.items:
        raise scene_error(path, data, pr.items)
    assert tracker is not None
    check_fits(tracker, target, path)
    return Footage(float(dt), tuple(frames), tracker, meta, truth), target


#: Most ground-truth tracks a scene may carry.
MAX_TRUTH = 10_000


def _steps(raw_frames: Any, frames: list[Frame]) -> set[int]:
    """The scene's frame steps, for the truth's rows: those of the frames read, and of
    every frame object with a valid step when some frame had a problem (else a bad payoff
    in frame 4 would also report every truth row of frame 4 as outside the scene)."""
    steps = {fr.step for fr in frames}
    if isinstance(raw_frames, list) and len(frames) != len(raw_frames):
        steps |= {
            rf["step"]
            for rf in raw_frames
            if isinstance(rf, dict) and is_int(rf.get("step")) and 0 <= rf["step"] <= MAX_STEP
        }
    return steps


def _truth(
    raw: Any, steps: set[int], pr: Problems, version: int = VERSION
) -> tuple[TruthTrack, ...]:
    """``truth``: ground-truth tracks, each ``{"id", "positions": [[frame, x, y], ...]}``
    with frames among the scene's (``steps``), increasing; from version 2 a track's
    positions may all be ``[frame, x, y, w, h]``, its boxes (w, h around x, y)."""
    if not isinstance(raw, list) or len(raw) > MAX_TRUTH:
        pr.add("truth", f"must be a list of at most {MAX_TRUTH} tracks, got {show(raw)}")
        return ()
    out: list[TruthTrack] = []
    seen: set[str] = set()
    for i, tr in enumerate(raw):
        where = f"truth[{i}]"
        if not (isinstance(tr, dict) and set(tr) <= {"id", "positions"}):
            pr.add(where, "must be an object with id and positions")
            continue
        tid = tr.get("id")
        if not (isinstance(tid, str) and tid) or tid in seen:
            pr.add(where, f"id must be a non-empty string used once, got {show(tid)}")
            continue
        seen.add(tid)
        where = f"truth track '{tid}'"
        got = tr.get("positions")
        if not isinstance(got, list) or not got:
            pr.add(where, "positions must be a non-empty list of [frame, x, y]")
            continue
        track = _truth_rows(got, steps, version, where, pr)
        if track is not None:
            out.append(TruthTrack(tid, *track))
    return tuple(out)


def _truth_rows(
    got: list[Any], steps: set[int], version: int, where: str, pr: Problems
) -> tuple[tuple[tuple[int, float, float], ...], tuple[tuple[float, float], ...] | None] | None:
    """A truth track's positions and, when every row is ``[frame, x, y, w, h]`` (version
    2), its box sizes; None (and a problem added) at the first bad row."""
    size = 5 if version >= 2 and isinstance(got[0], list) and len(got[0]) == 5 else 3
    form = "[frame, x, y, w, h]" if size == 5 else "[frame, x, y]"
    rows: list[tuple[int, float, float]] = []
    sizes: list[tuple[float, float]] = []
    for j, p in enumerate(got):
        ok = (
            isinstance(p, list)
            and len(p) == size
            and is_int(p[0])
            and p[0] in steps
            and all(within(v, MAX_COORD) for v in p[1:])
            and (not rows or p[0] > rows[-1][0])
        )
        why = None if not ok or size == 3 else box_problem(p[1], p[2], p[3], p[4])
        if not ok or why is not None:
            pr.add(
                where,
                f"positions[{j}] must be {form} with a frame of the scene after the "
                f"previous one and |x|, |y| <= {MAX_COORD:g}"
                + (f" ({why})" if why else "")
                + f", got {show(p)}",
            )
            return None
        rows.append((int(p[0]), float(p[1]), float(p[2])))
        if size == 5:
            sizes.append((float(p[3]), float(p[4])))
    return tuple(rows), (tuple(sizes) if size == 5 else None)


def _version(data: dict[str, Any], pr: Problems) -> int:
    """The file's ``format`` and ``version`` (one of :data:`VERSIONS`; the newest if bad)."""
    if data.get("format") != FORMAT:
        pr.add("format", f'must be "{FORMAT}", got {show(data.get("format"))}')
    got = data.get("version")
    for v in VERSIONS:
        if is_version(got, v):
            return v
    shown = ", ".join(str(v) for v in VERSIONS[:-1]) + f" or {VERSIONS[-1]}"
    pr.add("version", f"must be {shown}, got {show(got)}")
    return VERSION


def _frames(raw_frames: Any, pr: Problems, version: int = VERSION) -> list[Frame]:
    """The frames of a scene file: each valid, consecutive steps, homographies that keep
    every detection in front of the camera."""
    if not isinstance(raw_frames, list) or not raw_frames:
        pr.add("frames", "must be a non-empty list")
        return []
    frames = [
        fr for i, rf in enumerate(raw_frames) if (fr := _frame(rf, i, pr, version)) is not None
    ]
    if len(frames) == len(raw_frames):
        for a, b in itertools.pairwise(frames):
            if b.step != a.step + 1:
                pr.add(f"frame {b.step}", f"steps must be consecutive: follows frame {a.step}")
    for fr in frames:
        if fr.to_next is None or not fr.detections:
            continue
        xy = fr.positions()
        w = fr.to_next[2, 0] * xy[:, 0] + fr.to_next[2, 1] * xy[:, 1] + fr.to_next[2, 2]
        if not (w > 0).all():
            bad = fr.detections[int(np.argmin(w))].id
            pr.add(
                f"frame {fr.step}",
                f"to_next sends detection '{bad}' to infinity or behind the camera "
                "(its third homogeneous coordinate must be > 0 at every detection)",
            )
    return frames


def _frame(raw: Any, i: int, pr: Problems, version: int) -> Frame | None:
    if not isinstance(raw, dict):
        pr.add(f"frames[{i}]", "must be an object")
        return None
    step = raw.get("step")
    item = f"frame {step}" if is_int(step) else f"frames[{i}]"
    ok = True
    for key in sorted(set(raw) - {"step", "detections", "to_next", "meta", "candidates"}):
        pr.add(item, f"unknown key '{key}'")
        ok = False
    if not is_int(step) or not 0 <= step <= MAX_STEP:
        pr.add(item, f"step must be an integer in 0..{MAX_STEP}, got {show(step)}")
        ok = False
    dets_raw = raw.get("detections", [])
    dets: list[Detection] = []
    if not isinstance(dets_raw, list):
        pr.add(item, "detections must be a list")
        ok = False
        dets_raw = []
    seen: set[str] = set()
    for j, rd in enumerate(dets_raw):
        d = _detection(rd, f"{item}, detections[{j}]", pr, version)
        if d is None:
            ok = False
            continue
        if d.id in seen:
            pr.add(f"{item}, detection '{d.id}'", "duplicate detection id")
            ok = False
        seen.add(d.id)
        dets.append(d)
    cands = _candidates(raw, item, pr, version, seen)
    ok = ok and cands is not None
    H = None
    if raw.get("to_next") is not None:
        H = _matrix3(raw["to_next"])
        if H is None:
            pr.add(
                item,
                f"to_next must be an invertible 3x3 matrix of numbers within ±{MAX_HOMOGRAPHY:g}",
            )
            ok = False
    if not ok or cands is None:
        return None
    return Frame(int(step), tuple(dets), H, candidates=cands)  # type: ignore[arg-type]


def _candidates(
    raw: dict[str, Any], item: str, pr: Problems, version: int, seen: set[str]
) -> tuple[Detection, ...] | None:
    """A frame's ``candidates`` (scene format 3): injection candidates, each an object
    ``{"id", "x", "y", "payoff"[, "w", "h"]}`` whose payoff (a number >= 0) is the price
    of injecting it; ids unique among the frame's detections and candidates. None after
    a problem."""
    if "candidates" not in raw:
        return ()
    got = raw["candidates"]
    if version < CANDIDATES_VERSION:
        pr.add(
            item,
            f"candidates (injection candidates) need scene format version "
            f"{CANDIDATES_VERSION}, the file says {version}",
        )
        return None
    if not isinstance(got, list):
        pr.add(item, f"candidates must be a list, got {show(got)}")
        return None
    out: list[Detection] = []
    ok = True
    for j, rc in enumerate(got):
        c = _detection(rc, f"{item}, candidates[{j}]", pr, version, "candidate")
        if c is None:
            ok = False
            continue
        if c.id in seen:
            pr.add(f"{item}, candidate '{c.id}'", "duplicate id (detections and candidates)")
            ok = False
        seen.add(c.id)
        out.append(c)
    return tuple(out) if ok else None


def _detection(
    raw: Any, where: str, pr: Problems, version: int, kind: str = "detection"
) -> Detection | None:
    """A detection (or, ``kind`` "candidate", an injection candidate: its payoff a number
    >= 0, the price of injecting it; no payoff_lower)."""
    if not isinstance(raw, dict):
        pr.add(where, "must be an object")
        return None
    did = raw.get("id")
    item = where if not isinstance(did, str) else f"{where.split(',')[0]}, {kind} '{did}'"
    ok = True
    keys = {"id", "x", "y", "payoff", "meta", "w", "h"}
    if kind == "detection":
        keys.add("payoff_lower")
    for key in sorted(set(raw) - keys):
        pr.add(item, f"unknown key '{key}'")
        ok = False
    if not (isinstance(did, str) and did):
        pr.add(item, "id must be a non-empty string")
        ok = False
    for c in ("x", "y"):
        if not within(raw.get(c), MAX_COORD):
            pr.add(item, f"{c} must be a number within ±{MAX_COORD:g}, got {show(raw.get(c))}")
            ok = False
    payoff = _payoff(raw, item, pr, kind)
    ok = ok and payoff is not None
    has_lower = "payoff_lower" in raw and kind == "detection"  # a candidate's is unknown
    lower = raw.get("payoff_lower", None) if has_lower else None
    if has_lower and raw.get("payoff") == UNPRICED:
        pr.add(item, 'payoff_lower needs a priced payoff, not "unpriced"')
        ok = False
    elif has_lower:
        if lower == UNATTACKABLE:
            lower = math.inf
        elif not is_finite(lower) or lower < 0:
            pr.add(
                item,
                f'payoff_lower must be a finite number >= 0 or "unattackable", got {lower!r}',
            )
            ok = False
            lower = None
        if ok and lower is not None and lower > payoff:  # type: ignore[operator]
            shown = UNATTACKABLE if lower == math.inf else lower
            pr.add(item, f"payoff_lower {shown!r} exceeds payoff {raw.get('payoff')!r}")
            ok = False
    box = _box(raw, item, pr, version)
    if not ok or box is False or payoff is None:
        return None
    low = None if lower is None else float(lower)
    wh = box if isinstance(box, tuple) else (None, None)
    return Detection(str(did), float(raw["x"]), float(raw["y"]), payoff, low, *wh)


def _payoff(raw: dict[str, Any], item: str, pr: Problems, kind: str) -> float | None:
    """A detection's payoff (a number >= 0, "unattackable": inf, "unpriced": nan) or a
    candidate's (a number >= 0: the price of injecting it); None after a problem."""
    payoff = raw.get("payoff")
    if kind == "candidate":
        if is_finite(payoff) and 0 <= payoff <= MAX_PAYOFF:
            return float(payoff)
        pr.add(
            item,
            f"payoff (the price of injecting it) must be a number in [0, {MAX_PAYOFF:g}], "
            f"got {show(payoff) if 'payoff' in raw else 'nothing'}",
        )
        return None
    if "payoff" not in raw:
        pr.add(item, 'payoff is missing (a number >= 0, "unattackable" or "unpriced")')
        return None
    if payoff == UNATTACKABLE:
        return math.inf
    if payoff == UNPRICED:
        return math.nan
    if is_finite(payoff) and 0 <= payoff <= MAX_PAYOFF:
        return float(payoff)
    pr.add(
        item,
        f'payoff must be a number in [0, {MAX_PAYOFF:g}], "unattackable" or "unpriced", '
        f"got {show(payoff)}",
    )
    return None


def _box(
    raw: dict[str, Any], item: str, pr: Problems, version: int
) -> tuple[float, float] | bool | None:
    """A detection's box ``w``, ``h`` (both or neither, each in (0, MAX_COORD]; scene
    format 2): the pair, None for a point detection, False after a problem."""
    given = [k for k in ("w", "h") if k in raw]
    if not given:
        return None
    if version < BOXES_VERSION:
        pr.add(
            item,
            f"{given[0]} (a box) needs scene format version {BOXES_VERSION}, "
            f"the file says {version}",
        )
        return False
    if len(given) == 1:
        pr.add(item, f"{given[0]} needs {'h' if given[0] == 'w' else 'w'} too: a box is w and h")
        return False
    bad = [k for k in given if not positive(raw[k], MAX_COORD)]
    for k in bad:
        pr.add(item, f"{k} must be a number in (0, {MAX_COORD:g}], got {show(raw[k])}")
    if bad or not (within(raw.get("x"), MAX_COORD) and within(raw.get("y"), MAX_COORD)):
        return False
    if (why := box_problem(raw["x"], raw["y"], raw["w"], raw["h"])) is not None:
        pr.add(item, why)
        return False
    return (float(raw["w"]), float(raw["h"]))


def box_problem(x: float, y: float, w: float, h: float) -> str | None:
    """Why the box ``w``, ``h`` around (``x``, ``y``) is no box in floating point, or None.

    Its corners are x ± w/2, y ± h/2 (lesmc/scene/frames.py ``Frame.boxes``), and a box
    tracker reads back the width and height between them, their product (the area) and
    their ratio (lesmc/tracking/parts/boxes.py ``to_z``): each must be positive and
    finite, which a box narrower than the spacing of floats at its position is not (a
    width of 1e-300 at x = 100 has both corners at 100)."""
    cw = (x + w / 2.0) - (x - w / 2.0)
    ch = (y + h / 2.0) - (y - h / 2.0)
    if cw > 0 and ch > 0 and cw * ch > 0 and math.isfinite(cw / ch) and math.isfinite(ch / cw):
        return None
    return (
        f"the box w = {w!r}, h = {h!r} at ({x!r}, {y!r}) has corners x ± w/2, y ± h/2 "
        f"{cw!r} wide and {ch!r} high: too small for its position (a box needs a "
        "positive width, height and area between its corners)"
    )


def check_fits(
    tracker: TrackerConfig, target: Target | None, path: str, item: str = "target"
) -> None:
    """The target's velocity needs components named vx, vy in the tracker's state (an
    error of file ``path`` at ``item``: the scene's target, or a tracker file's state)."""
    if target is None or target.velocity == (0.0, 0.0) or velocity(tracker.model) is not None:
        return
    state = ", ".join(tracker.state_names)
    # 12 significant digits: 17.975 as the input wrote it, not 17.974999999999994
    shown = ", ".join(f"{v:.12g}" for v in target.velocity)
    whose = "velocity" if item == "target" else "the target's velocity"
    why = f"{whose} [{shown}] needs state components named {' and '.join(VELOCITY)}"
    raise scene_error(path, None, [(item, f"{why}; the tracker's state is {state}")])


def _target(raw: Any, pr: Problems) -> Target | None:
    if not isinstance(raw, dict):
        pr.add("target", "is missing (an object with step and start)")
        return None
    ok = True
    for key in sorted(set(raw) - {"step", "start", "velocity"}):
        pr.add("target", f"unknown key '{key}'")
        ok = False
    step = raw.get("step")
    if not is_int(step) or not 0 <= step <= MAX_STEP:
        pr.add("target", f"step must be an integer in 0..{MAX_STEP}, got {show(step)}")
        ok = False
    pairs = {}
    for key, hi in (("start", MAX_COORD), ("velocity", MAX_VELOCITY)):
        v = raw.get(key, [0.0, 0.0] if key == "velocity" else None)
        if not (isinstance(v, list) and len(v) == 2 and all(within(x, hi) for x in v)):
            pr.add("target", f"{key} must be [x, y], numbers within ±{hi:g}, got {show(v)}")
            ok = False
            continue
        pairs[key] = (float(v[0]), float(v[1]))
    if not ok:
        return None
    return Target(int(step), pairs["start"], pairs["velocity"])  # type: ignore[arg-type]


def _matrix3(raw: Any) -> np.ndarray | None:
    if not (isinstance(raw, list) and len(raw) == 3):
        return None
    if not all(
        isinstance(r, list) and len(r) == 3 and all(within(x, MAX_HOMOGRAPHY) for x in r)
        for r in raw
    ):
        return None
    m = np.array(raw, dtype=float)
    if abs(np.linalg.det(m)) < 1e-12:
        return None
    return m


# ---------------------------------------------------------------- writing


def target_to_dict(target: Target) -> dict[str, Any]:
    """The file form of a scene's target (its ``target`` object: step, start, velocity)."""
    return {"step": target.step, "start": list(target.start), "velocity": list(target.velocity)}


def scene_to_dict(scene: Scene | Footage) -> dict[str, Any]:
    """The file form of a scene (a :class:`Footage` is written without ``target``)."""
    frames = []
    for fr in scene.frames:
        d: dict[str, Any] = {
            "step": fr.step,
            "detections": [_det_json(det) for det in fr.detections],
        }
        if fr.to_next is not None:
            d["to_next"] = fr.to_next.tolist()
        if fr.candidates:
            d["candidates"] = [_det_json(c) for c in fr.candidates]
        frames.append(d)
    doc: dict[str, Any] = {
        "format": FORMAT,
        "version": written_version(scene),
        "dt": scene.dt,
        "frames": frames,
    }
    if isinstance(scene, Scene):
        doc["target"] = target_to_dict(scene.target)
    doc["tracker"] = scene.tracker.to_json()
    if scene.truth:
        doc["truth"] = [{"id": t.id, "positions": _truth_json(t)} for t in scene.truth]
    if scene.meta:
        doc["meta"] = scene.meta
    return doc


def written_version(scene: Scene | Footage) -> int:
    """The lowest format version that holds the scene: 3 with injection candidates, 2
    with boxes (on detections or truth rows), else 1."""
    if any(fr.candidates for fr in scene.frames):
        return CANDIDATES_VERSION
    boxed = any(d.w is not None for fr in scene.frames for d in fr.detections)
    if boxed or any(t.sizes is not None for t in scene.truth):
        return BOXES_VERSION
    return 1


def _truth_json(t: TruthTrack) -> list[list[float]]:
    """A truth track's positions, with their boxes (w, h) when it has them."""
    if t.sizes is None:
        return [[k, x, y] for k, x, y in t.positions]
    return [[k, x, y, w, h] for (k, x, y), (w, h) in zip(t.positions, t.sizes, strict=True)]


def _det_json(det: Detection) -> dict[str, Any]:
    out: dict[str, Any] = {
        "id": det.id,
        "x": det.x,
        "y": det.y,
        "payoff": det.payoff if det.attackable else UNATTACKABLE if det.priced else UNPRICED,
    }
    if det.payoff_lower is not None:
        low = det.payoff_lower
        out["payoff_lower"] = low if math.isfinite(low) else UNATTACKABLE
    if det.w is not None and det.h is not None:
        out["w"], out["h"] = det.w, det.h
    return out


def save_scene(scene: Scene | Footage, path: str | Path) -> None:
    """Write a scene (or a scene without a target) atomically."""
    write_json(path, scene_to_dict(scene))
