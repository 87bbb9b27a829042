"""Scene files (.json): what the perception unit hands the tracker, frame by frame.

Documented in docs/scene-format.md. A scene holds, per frame, the detections
(candidate observations Z_k with the attack payoff of hiding each one), the
camera motion to the next frame, where the target's track starts, and the
tracker's configuration. Validation is as strict as the .lts loader's.
"""

from __future__ import annotations

import itertools
import math
from collections.abc import Mapping
from dataclasses import dataclass, field, fields
from functools import cached_property
from pathlib import Path
from typing import TYPE_CHECKING, Any, Literal, TypeGuard

import numpy as np

from lesmc.errors import InputError, Problems
from lesmc.fileio import read_json, write_json

if TYPE_CHECKING:
    from scipy.spatial import cKDTree

#: Frames with at most this many detections are searched by a numpy scan, larger ones by a
#: k-d tree (scipy.spatial, imported only then).
SCAN_LIMIT = 2048
#: Distances computed at once by the scan (bounds its temporaries).
SCAN_CELLS = 1 << 20

#: Ranges of a scene's numbers (docs/scene-format.md, "Limits"): wide enough for any
#: real video, narrow enough that the tracker's arithmetic stays finite.
MAX_DT = 3600.0  #: seconds between frames
MAX_STEP = 10**6  #: frame steps
MAX_COORD = 1e7  #: |x|, |y| of detections and of the target's start (pixels)
MAX_VELOCITY = 1e6  #: |vx|, |vy| of the target's initial velocity (pixels per second)
MAX_PAYOFF = 1e12  #: a detection's payoff
MAX_HOMOGRAPHY = 1e6  #: |entry| of a frame-to-frame homography
#: Upper limits of the tracker's parameters (all must also be > 0).
TRACKER_LIMITS = {
    "sigma_q": 1e6,
    "sigma_r": 1e6,
    "P0_sd": 1e6,
    "gate": 1e6,
    "max_trace": 1e30,
    "init_radius": 1e7,
    "init_distance": 1e7,
    "prune_radius": 1e7,
}
FORMAT = "lesmc-scene"
VERSION = 1
UNATTACKABLE = "unattackable"
"""Payoff marker of a detection the attack could not flip within its iteration cap."""


@dataclass(frozen=True)
class Detection:
    """A candidate observation z ∈ Z_k and the payoff of hiding it (∞ if unattackable)."""

    id: str
    x: float
    y: float
    payoff: float
    #: certified lower bound on every hiding perturbation's norm (docs/cnn.md); None: not computed
    payoff_lower: float | None = None

    @property
    def attackable(self) -> bool:
        return math.isfinite(self.payoff)


@dataclass(frozen=True)
class Frame:
    """One frame: its detections and the homography to the next frame's coordinates."""

    step: int
    detections: tuple[Detection, ...]
    to_next: np.ndarray | None = None

    @cached_property
    def _positions(self) -> np.ndarray:
        arr = np.array([[d.x, d.y] for d in self.detections], dtype=float).reshape(-1, 2)
        arr.flags.writeable = False
        return arr

    @cached_property
    def _payoffs(self) -> np.ndarray:
        arr = np.array([d.payoff for d in self.detections], dtype=float)
        arr.flags.writeable = False
        return arr

    def positions(self) -> np.ndarray:
        """(n, 2) detection positions (computed once, read-only)."""
        return self._positions

    @cached_property
    def _tree(self) -> cKDTree | None:
        if not len(self.detections):
            return None
        # scipy.spatial costs 0.3-1 s to import: only frames too large to scan pay it.
        from scipy.spatial import cKDTree

        return cKDTree(self._positions)

    def nearest(self, points: np.ndarray, k: int, radius: float) -> np.ndarray:
        """For each point (n, 2), the indices of its k nearest detections within ``radius``
        (nearest first, ties to the lower index), −1 where there are fewer."""
        return self.nearest_d2(points, k, radius)[0]

    def nearest_d2(
        self, points: np.ndarray, k: int, radius: float
    ) -> tuple[np.ndarray, np.ndarray]:
        """:meth:`nearest`, and the squared distances (inf where −1).

        A frame of at most :data:`SCAN_LIMIT` detections is scanned with numpy:
        only the detections whose x lies within ``radius`` of the point's (sorted
        once per frame), in chunks of points; a larger frame is searched with a
        k-d tree, built once. Ties in distance go to the lower detection index.
        """
        n, m = len(points), len(self.detections)
        res = np.full((n, k), -1, dtype=np.int64)
        res_d2 = np.full((n, k), np.inf)
        if not m or not n:
            return res, res_d2
        bound = radius * (1 + 1e-12)
        Z = self._positions
        if m > SCAN_LIMIT:
            assert self._tree is not None
            _, found = self._tree.query(points, k=k, distance_upper_bound=bound)
            found = np.asarray(found, dtype=np.int64).reshape(n, k)
            cand = [(points, np.minimum(found, m - 1), found < m)]
        else:
            xs, by_x = self._by_x
            lo = np.searchsorted(xs, points[:, 0] - bound, side="left")
            hi = np.searchsorted(xs, points[:, 0] + bound, side="right")
            width = int((hi - lo).max())
            if width == 0:
                return res, res_d2
            step = max(1, SCAN_CELLS // width)
            cand = []
            for s in range(0, n, step):
                cols = lo[s : s + step, None] + np.arange(width)
                inside = cols < hi[s : s + step, None]
                cand.append((points[s : s + step], by_x[np.minimum(cols, m - 1)], inside))
        s = 0
        for p, idx, inside in cand:
            d2 = (p[:, 0:1] - Z[idx, 0]) ** 2 + (p[:, 1:2] - Z[idx, 1]) ** 2
            d2 = np.where(inside & (d2 <= bound * bound), d2, np.inf)
            kk = min(k, idx.shape[1])
            order = np.argsort(d2, axis=1, kind="stable")[:, : kk + 1]
            dd = np.take_along_axis(d2, order, axis=1)
            near = np.take_along_axis(idx, order, axis=1)
            # equal distances go to the lower index: rows with a tie among the first kk + 1
            # (the kept and the first one left out) are sorted again by (distance, index)
            tied = np.isfinite(dd[:, 1:]) & (dd[:, 1:] == dd[:, :-1])
            dd, near = dd[:, :kk], near[:, :kk]
            rows = np.nonzero(tied.any(axis=1))[0]
            if rows.size:
                d2r, idxr = d2[rows], idx[rows]
                full = np.lexsort((np.where(np.isinf(d2r), m, idxr), d2r), axis=1)[:, :kk]
                dd[rows] = np.take_along_axis(d2r, full, axis=1)
                near[rows] = np.take_along_axis(idxr, full, axis=1)
            e = s + len(p)
            res[s:e, :kk] = np.where(np.isinf(dd), -1, near)
            res_d2[s:e, :kk] = dd
            s = e
        return res, res_d2

    @cached_property
    def _by_x(self) -> tuple[np.ndarray, np.ndarray]:
        """Detections sorted by x (values, indices): a point's candidates lie in an x band."""
        order = np.argsort(self._positions[:, 0], kind="stable")
        return self._positions[order, 0], order

    def payoffs(self) -> np.ndarray:
        """(n,) payoffs of hiding each detection (inf: unattackable); read-only."""
        return self._payoffs

    @cached_property
    def _position_ids(self) -> np.ndarray:
        _, first, inverse = np.unique(
            self._positions, axis=0, return_index=True, return_inverse=True
        )
        out: np.ndarray = first[inverse.reshape(-1)]
        out.flags.writeable = False
        return out

    def position_ids(self) -> np.ndarray:
        """(n,) for each detection, the lowest index of a detection at the same position."""
        return self._position_ids

    @cached_property
    def has_repeats(self) -> bool:
        """Two detections of this frame sit at exactly the same position."""
        return bool(len(self.detections)) and bool(
            (self._position_ids != np.arange(len(self.detections))).any()
        )


@dataclass(frozen=True)
class TrackerConfig:
    """The tracker's parameters (paper section 6.7 and 7); defaults are the paper's."""

    design: Literal["single", "joint"] = "single"
    sigma_q: float = 3.0  # process noise σ_q of Eq. 17 (the paper's code used 5)
    sigma_r: float = 5.0  # measurement noise σ_r of Eq. 18 (the paper's code used 6)
    P0_sd: tuple[float, float, float, float] = (30.0, 30.0, 20.0, 20.0)  # P0 = diag(P0_sd)²
    gate: float = 2.0  # g of Eq. 19 (Mahalanobis) or k of the Euclidean gate
    gate_type: Literal["mahalanobis", "euclidean"] = "mahalanobis"
    max_trace: float = 1e5  # halt the track when trace(P) exceeds this
    # joint design (section 7.2)
    init_radius: float = 150.0  # unassociated detections this close to the primary may start tracks
    init_distance: float = 60.0  # max distance to a previous unassociated detection to start one
    prune_radius: float = 200.0  # refining tracks farther than this from the primary are dropped

    def to_json(self) -> dict[str, Any]:
        d: dict[str, Any] = {}
        for f in fields(self):
            v = getattr(self, f.name)
            d[f.name] = list(v) if isinstance(v, tuple) else v
        return d


class PayoffReads:
    """A frame's payoff column that notes which of its ``watched`` entries (None: all) are
    read; any use other than indexing counts as reading all of them."""

    def __init__(self, values: np.ndarray, reads: set[int], watched: np.ndarray | None) -> None:
        self._values = values
        self._reads = reads
        self._watched = watched

    def __getitem__(self, key: Any) -> np.ndarray:
        out: np.ndarray = self._values[key]
        self._note(np.arange(len(self._values))[key])
        return out

    def __len__(self) -> int:
        return len(self._values)

    def __array__(self, dtype: object = None, copy: object = None) -> np.ndarray:
        self._note(np.arange(len(self._values)))
        return self._values

    def _note(self, idx: np.ndarray) -> None:
        idx = np.unique(idx)
        if self._watched is not None:
            idx = idx[self._watched[idx]]
        self._reads.update(idx.tolist())


@dataclass(frozen=True)
class WatchedFrame(Frame):
    """A frame whose :meth:`payoffs` note which ``watched`` detections (None: all) a model
    reads: the probe of :func:`lesmc.unfold.priced_detections`, and a certified scene's
    detections without a bound (:meth:`Scene.unbounded_reads`)."""

    watched: np.ndarray | None = field(default=None, compare=False)
    reads: set[int] = field(default_factory=set, compare=False)

    def payoffs(self) -> np.ndarray:
        return PayoffReads(self._payoffs, self.reads, self.watched)  # type: ignore[return-value]


def lower_frames(frames: tuple[Frame, ...], lower: Mapping[int, np.ndarray]) -> tuple[Frame, ...]:
    """``frames`` with certified lower payoffs ``lower[step][i]`` for detection i of frame
    ``step`` (``nan``: none; capped by the payoff); detections not given keep theirs."""
    from dataclasses import replace

    out = []
    for f in frames:
        low = lower.get(f.step)
        if low is not None:
            f = replace(
                f,
                detections=tuple(
                    d if math.isnan(v) else replace(d, payoff_lower=min(v, d.payoff))
                    for d, v in zip(f.detections, low.tolist(), strict=True)
                ),
            )
        out.append(f)
    return tuple(out)


@dataclass(frozen=True)
class Target:
    """Where the track starts: frame step, position, and (default zero) velocity."""

    step: int
    start: tuple[float, float]
    velocity: tuple[float, float] = (0.0, 0.0)


class _Frames:
    """Frames numbered ``frames[0].step``, ``frames[0].step + 1``, ...: the steps of a video."""

    frames: tuple[Frame, ...]

    def frame(self, step: int) -> Frame:
        return self.frames[step - self.frames[0].step]

    @property
    def last_step(self) -> int:
        return self.frames[-1].step


@dataclass(frozen=True)
class Footage(_Frames):
    """A scene without a target: what perception produces once per video.

    ``lesmc perceive -o`` without ``--target`` writes one; ``--target X,Y@STEP``
    (lesmc/tracking/targets.py) turns it into a :class:`Scene` per vehicle.
    """

    dt: float
    frames: tuple[Frame, ...]
    tracker: TrackerConfig = field(default_factory=TrackerConfig)
    meta: dict[str, Any] = field(default_factory=dict, compare=False)

    def with_target(self, target: Target, meta: dict[str, Any] | None = None) -> Scene:
        """The scene tracking from ``target`` (its step must be one of the frames)."""
        info = dict(self.meta) if meta is None else meta
        return Scene(self.dt, self.frames, target, self.tracker, info)


@dataclass(frozen=True)
class Scene(_Frames):
    """A validated scene; ``frames[i].step == first_step + i``."""

    dt: float
    frames: tuple[Frame, ...]
    target: Target
    tracker: TrackerConfig = field(default_factory=TrackerConfig)
    meta: dict[str, Any] = field(default_factory=dict, compare=False)

    @property
    def has_lower(self) -> bool:
        """Every detection carries ``payoff_lower`` (perceive --certify)."""
        return all(d.payoff_lower is not None for f in self.frames for d in f.detections)

    @property
    def any_lower(self) -> bool:
        """Some detection carries ``payoff_lower`` (all of them, or those a model can hide)."""
        return any(d.payoff_lower is not None for f in self.frames for d in f.detections)

    def priced(self, payoffs: str, path: str = "<scene>") -> Scene:
        """The scene whose ``payoff`` column the model uses: ``attack`` or ``certified``.

        ``certified`` puts each detection's ``payoff_lower`` in place of its
        payoff (docs/semantics.md, "Payoff intervals"). A detection without one
        gets 0, the trivial lower bound (sound: no perturbation is cheaper than
        nothing), and its frame notes whether a model reads it
        (:meth:`unbounded_reads`); ``verify`` certifies only the detections its
        models can hide. At least one detection must carry a bound, unless
        ``meta["certified"]`` says that ``verify`` found none to certify.
        """
        if payoffs == "attack":
            return self
        if payoffs != "certified":
            raise ValueError(f"unknown payoff column {payoffs!r}")
        from dataclasses import replace

        if not self.any_lower and "certified" not in self.meta:
            f = next((f for f in self.frames if f.detections), self.frames[0])
            where = f"frame {f.step}" + (
                f", detection '{f.detections[0].id}'" if f.detections else ""
            )
            raise InputError.many(
                path,
                [
                    (
                        where,
                        "payoff_lower is missing (needed by --payoffs certified|"
                        "interval; write the scene with `lesmc perceive --certify`)",
                    )
                ],
            )
        frames: list[Frame] = []
        for f in self.frames:
            dets = tuple(
                replace(d, payoff=0.0 if d.payoff_lower is None else d.payoff_lower)
                for d in f.detections
            )
            missing = np.array([d.payoff_lower is None for d in f.detections], dtype=bool)
            if missing.any():
                frames.append(WatchedFrame(f.step, dets, f.to_next, missing))
            else:
                frames.append(replace(f, detections=dets))
        return replace(self, frames=tuple(frames))

    def unbounded_reads(self, window: tuple[int, int]) -> int:
        """How many detections without ``payoff_lower`` the models of this certified scene
        (:meth:`priced`) attacked in ``window`` have read so far in its frames (each counted
        as 0, the trivial bound); reads elsewhere never enter a combined payoff (Eq. 5)."""
        first, last = self.target.step + window[0], self.target.step + window[1]
        return sum(
            len(f.reads)
            for f in self.frames
            if isinstance(f, WatchedFrame) and first <= f.step <= last
        )

    def with_lower(self, lower: Mapping[int, np.ndarray]) -> Scene:
        """The scene with certified lower payoffs: ``lower[step][i]`` for detection i of
        frame ``step`` (``nan``: none); detections not given keep theirs."""
        from dataclasses import replace

        return replace(self, frames=lower_frames(self.frames, lower))

    def with_tracker(self, **changes: Any) -> Scene:
        """The same scene with some tracker parameters replaced (e.g. design)."""
        from dataclasses import replace

        return replace(self, tracker=replace(self.tracker, **changes))

    @property
    def footage(self) -> Footage:
        """The scene without its target."""
        return Footage(self.dt, self.frames, self.tracker, self.meta)


# ---------------------------------------------------------------- loading


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
    allowed = {"format", "version", "dt", "frames", "target", "tracker", "meta", "comment"}
    for key in sorted(set(data) - allowed):
        pr.add(f"key '{key}'", "unknown top-level key")
    if data.get("format") != FORMAT:
        pr.add("format", f'must be "{FORMAT}", got {data.get("format")!r}')
    if data.get("version") != VERSION:
        pr.add("version", f"must be {VERSION}, got {data.get('version')!r}")
    dt = data.get("dt", 1.0)
    if not (_num(dt) and 0 < dt <= MAX_DT):
        pr.add("dt", f"must be a number of seconds in (0, {MAX_DT:g}], got {_show(dt)}")
        dt = 1.0
    raw_frames = data.get("frames")
    frames: list[Frame] = []
    if not isinstance(raw_frames, list) or not raw_frames:
        pr.add("frames", "must be a non-empty list")
    else:
        for i, rf in enumerate(raw_frames):
            fr = _frame(rf, i, pr)
            if fr is not None:
                frames.append(fr)
        pairs = list(itertools.pairwise(frames)) if len(frames) == len(raw_frames) else []
        for a, b in pairs:
            if b.step != a.step + 1:
                pr.add(f"frame {b.step}", f"steps must be consecutive: follows frame {a.step}")
        for fr in frames:
            if fr.to_next is not None and fr.detections:
                xy = np.array([(d.x, d.y) for d in fr.detections])
                w = fr.to_next[2, 0] * xy[:, 0] + fr.to_next[2, 1] * xy[:, 1] + fr.to_next[2, 2]
                if not (w > 0).all():
                    bad = fr.detections[int(np.argmin(w))].id
                    pr.add(
                        f"frame {fr.step}",
                        f"to_next sends detection '{bad}' to infinity or behind the camera "
                        "(its third homogeneous coordinate must be > 0 at every detection)",
                    )
    tracker = _tracker(data.get("tracker", {}), pr)
    target = None
    if need_target or data.get("target") is not None:
        target = _target(data.get("target"), pr)
    if target is not None and frames and not frames[0].step <= target.step <= frames[-1].step:
        pr.add(
            "target",
            f"step {target.step} is not among the frames {frames[0].step}..{frames[-1].step}",
        )
    if pr.items:
        raise InputError.many(path, pr.items)
    assert tracker is not None
    raw_meta = data.get("meta")
    meta: dict[str, Any] = raw_meta if isinstance(raw_meta, dict) else {}
    return Footage(float(dt), tuple(frames), tracker, meta), target


def _frame(raw: Any, i: int, pr: Problems) -> Frame | None:
    if not isinstance(raw, dict):
        pr.add(f"frames[{i}]", "must be an object")
        return None
    step = raw.get("step")
    item = f"frame {step}" if _int(step) else f"frames[{i}]"
    ok = True
    for key in sorted(set(raw) - {"step", "detections", "to_next", "meta"}):
        pr.add(item, f"unknown key '{key}'")
        ok = False
    if not _int(step) or not 0 <= step <= MAX_STEP:
        pr.add(item, f"step must be an integer in 0..{MAX_STEP}, got {_show(step)}")
        ok = False
    dets_raw = raw.get("detections", [])
    dets: list[Detection] = []
    if not isinstance(dets_raw, list):
        pr.add(item, "detections must be a list")
        ok = False
        dets_raw = []
    seen: set[str] = set()
    for j, rd in enumerate(dets_raw):
        d = _detection(rd, f"{item}, detections[{j}]", pr)
        if d is None:
            ok = False
            continue
        if d.id in seen:
            pr.add(f"{item}, detection '{d.id}'", "duplicate detection id")
            ok = False
        seen.add(d.id)
        dets.append(d)
    H = None
    if raw.get("to_next") is not None:
        H = _matrix3(raw["to_next"])
        if H is None:
            pr.add(
                item,
                f"to_next must be an invertible 3x3 matrix of numbers within ±{MAX_HOMOGRAPHY:g}",
            )
            ok = False
    if not ok:
        return None
    return Frame(int(step), tuple(dets), H)  # type: ignore[arg-type]


def _detection(raw: Any, where: str, pr: Problems) -> Detection | None:
    if not isinstance(raw, dict):
        pr.add(where, "must be an object")
        return None
    did = raw.get("id")
    item = where if not isinstance(did, str) else f"{where.split(',')[0]}, detection '{did}'"
    ok = True
    for key in sorted(set(raw) - {"id", "x", "y", "payoff", "payoff_lower", "meta"}):
        pr.add(item, f"unknown key '{key}'")
        ok = False
    if not (isinstance(did, str) and did):
        pr.add(item, "id must be a non-empty string")
        ok = False
    for c in ("x", "y"):
        if not _within(raw.get(c), MAX_COORD):
            pr.add(item, f"{c} must be a number within ±{MAX_COORD:g}, got {_show(raw.get(c))}")
            ok = False
    payoff = raw.get("payoff", None)
    if "payoff" not in raw:
        pr.add(item, 'payoff is missing (a number >= 0, or "unattackable")')
        ok = False
    elif payoff == UNATTACKABLE:
        payoff = math.inf
    elif not (_num(payoff) and 0 <= payoff <= MAX_PAYOFF):
        pr.add(
            item,
            f'payoff must be a number in [0, {MAX_PAYOFF:g}] or "unattackable", '
            f"got {_show(payoff)}",
        )
        ok = False
    lower = raw.get("payoff_lower", None)
    if "payoff_lower" in raw:
        if lower == UNATTACKABLE:
            lower = math.inf
        elif not _num(lower) or lower < 0:
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
    if not ok:
        return None
    return Detection(
        str(did),
        float(raw["x"]),
        float(raw["y"]),
        float(payoff),  # type: ignore[arg-type]
        None if lower is None else float(lower),
    )


def _tracker(raw: Any, pr: Problems) -> TrackerConfig | None:
    if not isinstance(raw, dict):
        pr.add("tracker", "must be an object")
        return None
    defaults = TrackerConfig()
    names = {f.name for f in fields(TrackerConfig)}
    values: dict[str, Any] = {}
    for key, v in raw.items():
        if key not in names:
            pr.add("tracker", f"unknown key '{key}'")
            continue
        if key == "design":
            if v not in ("single", "joint"):
                pr.add("tracker", f'design must be "single" or "joint", got {v!r}')
                continue
        elif key == "gate_type":
            if v not in ("mahalanobis", "euclidean"):
                pr.add("tracker", f'gate_type must be "mahalanobis" or "euclidean", got {v!r}')
                continue
        elif key == "P0_sd":
            hi = TRACKER_LIMITS[key]
            if not (isinstance(v, list) and len(v) == 4 and all(_positive(x, hi) for x in v)):
                pr.add("tracker", f"P0_sd must be a list of 4 numbers in (0, {hi:g}]")
                continue
            v = tuple(float(x) for x in v)
        elif not _positive(v, TRACKER_LIMITS[key]):
            hi = TRACKER_LIMITS[key]
            pr.add("tracker", f"{key} must be a number in (0, {hi:g}], got {_show(v)}")
            continue
        values[key] = v
    try:
        return TrackerConfig(**{**defaults.__dict__, **values})
    except TypeError as exc:  # pragma: no cover - names are checked above
        pr.add("tracker", str(exc))
        return None


def _target(raw: Any, pr: Problems) -> Target | None:
    if not isinstance(raw, dict):
        pr.add("target", "is missing (an object with step and start)")
        return None
    ok = True
    for key in sorted(set(raw) - {"step", "start", "velocity"}):
        pr.add("target", f"unknown key '{key}'")
        ok = False
    step = raw.get("step")
    if not _int(step) or not 0 <= step <= MAX_STEP:
        pr.add("target", f"step must be an integer in 0..{MAX_STEP}, got {_show(step)}")
        ok = False
    pairs = {}
    for key, hi in (("start", MAX_COORD), ("velocity", MAX_VELOCITY)):
        v = raw.get(key, [0.0, 0.0] if key == "velocity" else None)
        if not (isinstance(v, list) and len(v) == 2 and all(_within(x, hi) for x in v)):
            pr.add("target", f"{key} must be [x, y], numbers within ±{hi:g}, got {_show(v)}")
            ok = False
            continue
        pairs[key] = (float(v[0]), float(v[1]))
    if not ok:
        return None
    return Target(int(step), pairs["start"], pairs["velocity"])  # type: ignore[arg-type]


def _num(x: Any) -> TypeGuard[int | float]:
    return isinstance(x, int | float) and not isinstance(x, bool) and math.isfinite(x)


def _int(x: Any) -> TypeGuard[int]:
    return isinstance(x, int) and not isinstance(x, bool)


def _within(x: Any, limit: float) -> bool:
    """A number with ``|x| <= limit``."""
    return _num(x) and -limit <= x <= limit


def _positive(x: Any, limit: float) -> bool:
    """A number in ``(0, limit]``."""
    return _num(x) and 0 < x <= limit


def _show(x: Any) -> str:
    """``repr(x)``, clipped to 40 characters (a value quoted in an error)."""
    text = repr(x)
    return text if len(text) <= 40 else text[:37] + "..."


def _matrix3(raw: Any) -> np.ndarray | None:
    if not (isinstance(raw, list) and len(raw) == 3):
        return None
    if not all(
        isinstance(r, list) and len(r) == 3 and all(_within(x, MAX_HOMOGRAPHY) for x in r)
        for r in raw
    ):
        return None
    m = np.array(raw, dtype=float)
    if abs(np.linalg.det(m)) < 1e-12:
        return None
    return m


# ---------------------------------------------------------------- writing


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
        frames.append(d)
    doc: dict[str, Any] = {
        "format": FORMAT,
        "version": VERSION,
        "dt": scene.dt,
        "frames": frames,
    }
    if isinstance(scene, Scene):
        doc["target"] = {
            "step": scene.target.step,
            "start": list(scene.target.start),
            "velocity": list(scene.target.velocity),
        }
    doc["tracker"] = scene.tracker.to_json()
    if scene.meta:
        doc["meta"] = scene.meta
    return doc


def _det_json(det: Detection) -> dict[str, Any]:
    out: dict[str, Any] = {
        "id": det.id,
        "x": det.x,
        "y": det.y,
        "payoff": det.payoff if det.attackable else UNATTACKABLE,
    }
    if det.payoff_lower is not None:
        low = det.payoff_lower
        out["payoff_lower"] = low if math.isfinite(low) else UNATTACKABLE
    return out


def save_scene(scene: Scene | Footage, path: str | Path) -> None:
    """Write a scene (or a scene without a target) atomically."""
    write_json(path, scene_to_dict(scene))
