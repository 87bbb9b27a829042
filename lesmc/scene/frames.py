"""Frames of a scene: the detections (candidate observations Z_k of Eq. 2) and their payoffs.

A :class:`Frame` answers the tracker's one geometric question, which
detections lie within a radius of a point, nearest first (an x-sorted scan,
or a k-d tree for large frames). :class:`WatchedFrame` notes which payoffs a
model reads: the probe that finds the detections an attack can hide
(lesmc/unfold/probe.py).

A payoff may be *unpriced* (``nan``; ``"unpriced"`` in scene files): nobody
attacked that detection yet. ``lesmc verify`` prices a detection the first
time a model reads its payoff (:class:`PricedFrame`, :class:`OnDemandPayoffs`);
a model that reads an unpriced payoff with nobody to price it stops with
:class:`UnpricedPayoff`, never with a made-up number.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Mapping
from dataclasses import dataclass, field, replace
from functools import cached_property
from typing import TYPE_CHECKING, Any

import numpy as np

from lesmc.common.errors import InputError, Location
from lesmc.scene.located import scene_error

if TYPE_CHECKING:
    from scipy.spatial import cKDTree

#: Frames with at most this many detections are searched by a numpy scan, larger ones by a
#: k-d tree (scipy.spatial, imported only then).
SCAN_LIMIT = 2048
#: Distances computed at once by the scan (bounds its temporaries).
SCAN_CELLS = 1 << 20


@dataclass(frozen=True)
class Detection:
    """A candidate observation z ∈ Z_k and the payoff of hiding it (∞ if unattackable,
    ``nan`` if not priced yet)."""

    id: str
    x: float
    y: float
    payoff: float
    #: certified lower bound on every hiding perturbation's norm (docs/cnn.md); None: not computed
    payoff_lower: float | None = None
    #: the box's width and height, centred on (x, y) (scene format 2); None: a point detection
    w: float | None = None
    h: float | None = None

    @property
    def attackable(self) -> bool:
        return math.isfinite(self.payoff)

    @property
    def priced(self) -> bool:
        """Its payoff is known (a number or unattackable), not ``"unpriced"``."""
        return not math.isnan(self.payoff)


@dataclass(frozen=True)
class Frame:
    """One frame: its detections, the homography to the next frame's coordinates, and its
    injection candidates (scene format 3): places where an attacker may make a detection
    appear, each a :class:`Detection` whose ``payoff`` is the price of injecting it
    (issue 61; read by the multi-target designs, lesmc/unfold/multi.py, and by ``single``
    under ``allow inject``, lesmc/tracking/single.py)."""

    step: int
    detections: tuple[Detection, ...]
    to_next: np.ndarray | None = None
    #: keyword-only: the subclasses' fields keep their places after ``to_next``
    candidates: tuple[Detection, ...] = field(default=(), kw_only=True)

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
    def has_boxes(self) -> bool:
        """Every detection carries a box (a frame without detections has boxes)."""
        return all(d.w is not None and d.h is not None for d in self.detections)

    @cached_property
    def _boxes(self) -> np.ndarray:
        return _box_rows(self.detections)

    def boxes(self) -> np.ndarray:
        """(n, 4) the detections' boxes [x1, y1, x2, y2] (read-only); only for a frame that
        :attr:`has_boxes`."""
        if not self.has_boxes:
            raise ValueError(f"frame {self.step}: a detection has no box")
        return self._boxes

    @cached_property
    def injectable(self) -> Frame:
        """The injection candidates as a frame of their own (their positions, payoffs and
        nearest-neighbour search), for the single design under ``allow inject``."""
        return Frame(self.step, self.candidates)

    @cached_property
    def _joint_position_ids(self) -> np.ndarray:
        both = np.vstack([self.positions(), self.injectable.positions()])
        _, first, inverse = np.unique(both, axis=0, return_index=True, return_inverse=True)
        out: np.ndarray = first[inverse.reshape(-1)]
        out.flags.writeable = False
        return out

    def joint_position_ids(self) -> np.ndarray:
        """(n + m,) for each detection, then each injection candidate, the lowest index
        (in that order) of one at the same position."""
        return self._joint_position_ids

    @cached_property
    def candidates_have_boxes(self) -> bool:
        """Every injection candidate carries a box (true when there are none)."""
        return all(c.w is not None and c.h is not None for c in self.candidates)

    @cached_property
    def _candidate_boxes(self) -> np.ndarray:
        return _box_rows(self.candidates)

    def candidate_boxes(self) -> np.ndarray:
        """(m, 4) the injection candidates' boxes (read-only); only for a frame whose
        candidates all have one (:attr:`candidates_have_boxes`)."""
        if not self.candidates_have_boxes:
            raise ValueError(f"frame {self.step}: an injection candidate has no box")
        return self._candidate_boxes

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
        n = len(points)
        res = np.full((n, k), -1, dtype=np.int64)
        res_d2 = np.full((n, k), np.inf)
        if not len(self.detections) or not n:
            return res, res_d2
        bound = radius * (1 + 1e-12)
        s = 0
        for p, idx, inside in self._candidates(points, k, bound):
            near, dd = self._nearest_of(p, idx, inside, k, bound)
            kk = near.shape[1]
            res[s : s + len(p), :kk] = near
            res_d2[s : s + len(p), :kk] = dd
            s += len(p)
        return res, res_d2

    def _candidates(
        self, points: np.ndarray, k: int, bound: float
    ) -> list[tuple[np.ndarray, np.ndarray, np.ndarray]]:
        """Chunks of (points, candidate detection indices, which are real): the k-d tree's
        k nearest, or the detections of each point's x band."""
        n, m = len(points), len(self.detections)
        if m > SCAN_LIMIT:
            assert self._tree is not None
            _, found = self._tree.query(points, k=k, distance_upper_bound=bound)
            found = np.asarray(found, dtype=np.int64).reshape(n, k)
            return [(points, np.minimum(found, m - 1), found < m)]
        xs, by_x = self._by_x
        lo = np.searchsorted(xs, points[:, 0] - bound, side="left")
        hi = np.searchsorted(xs, points[:, 0] + bound, side="right")
        width = int((hi - lo).max())
        if width == 0:
            return []
        step = max(1, SCAN_CELLS // width)
        out = []
        for s in range(0, n, step):
            cols = lo[s : s + step, None] + np.arange(width)
            inside = cols < hi[s : s + step, None]
            out.append((points[s : s + step], by_x[np.minimum(cols, m - 1)], inside))
        return out

    def _nearest_of(
        self, p: np.ndarray, idx: np.ndarray, inside: np.ndarray, k: int, bound: float
    ) -> tuple[np.ndarray, np.ndarray]:
        """The k nearest candidates of each point within ``bound`` (−1, inf: none), ties in
        distance to the lower index."""
        Z = self._positions
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
            m = len(self.detections)
            full = np.lexsort((np.where(np.isinf(d2r), m, idxr), d2r), axis=1)[:, :kk]
            dd[rows] = np.take_along_axis(d2r, full, axis=1)
            near[rows] = np.take_along_axis(idxr, full, axis=1)
        return np.where(np.isinf(dd), -1, near), dd

    @cached_property
    def _by_x(self) -> tuple[np.ndarray, np.ndarray]:
        """Detections sorted by x (values, indices): a point's candidates lie in an x band."""
        order = np.argsort(self._positions[:, 0], kind="stable")
        return self._positions[order, 0], order

    def payoffs(self) -> np.ndarray:
        """(n,) payoffs of hiding each detection (inf: unattackable); read-only. Reading an
        unpriced one raises :class:`UnpricedPayoff`."""
        if self.has_unpriced:
            return _GuardedPayoffs(self)  # type: ignore[return-value]
        return self._payoffs

    def payoff_values(self) -> np.ndarray:
        """(n,) the payoffs as the detections hold them, ``nan`` where unpriced: to copy,
        not for a model (:meth:`payoffs` guards what a model reads)."""
        return self._payoffs

    @cached_property
    def has_unpriced(self) -> bool:
        """Some detection's payoff is unpriced (``nan``)."""
        return bool(np.isnan(self._payoffs).any())

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


def _box_rows(dets: tuple[Detection, ...]) -> np.ndarray:
    """(n, 4) the boxes [x1, y1, x2, y2] of the detections that carry one (read-only)."""
    rows = [
        [d.x - d.w / 2.0, d.y - d.h / 2.0, d.x + d.w / 2.0, d.y + d.h / 2.0]
        for d in dets
        if d.w is not None and d.h is not None
    ]
    arr = np.array(rows, dtype=float).reshape(-1, 4)
    arr.flags.writeable = False
    return arr


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
    reads: the probe of :func:`lesmc.unfold.probe.priced_detections`."""

    watched: np.ndarray | None = field(default=None, compare=False)
    reads: set[int] = field(default_factory=set, compare=False)

    def payoffs(self) -> np.ndarray:
        return PayoffReads(self._payoffs, self.reads, self.watched)  # type: ignore[return-value]


class UnpricedPayoff(InputError):
    """A model read the payoff of a detection that nobody priced (``"unpriced"``)."""

    def __init__(self, frame: Frame, index: int, path: str = "scene") -> None:
        self.frame, self.index = frame, index
        det = frame.detections[index]
        super().__init__(
            'payoff is "unpriced" and this check reads it (lesmc verify prices only the '
            "detections its own checks read): price every detection with `lesmc verify "
            "--price-all` or `lesmc perceive -o`",
            Location(path, item=f"frame {frame.step}, detection '{det.id}'"),
        )

    def at(self, path: str) -> UnpricedPayoff:
        """The same error, naming the scene file ``path``: at the payoff's ``FILE:LINE:COL``
        when ``path`` is a scene file (:func:`~lesmc.scene.located.scene_error`)."""
        err = UnpricedPayoff(self.frame, self.index, path)
        item = err.location.item if err.location is not None else None
        located = scene_error(path, None, [(item or "", err.message)])
        err.message, err.location = located.message, located.location
        err.preformatted = located.preformatted
        return err


class _GuardedPayoffs:
    """A payoff column with unpriced entries: indexing that reads one raises
    :class:`UnpricedPayoff`; any other use of the column reads all of it."""

    def __init__(self, frame: Frame) -> None:
        self._frame = frame
        self._values = frame._payoffs

    def __getitem__(self, key: Any) -> np.ndarray:
        idx = np.atleast_1d(np.arange(len(self._values))[key])
        bad = idx[np.isnan(self._values[idx])]
        if bad.size:
            raise UnpricedPayoff(self._frame, int(bad[0]))
        out: np.ndarray = self._values[key]
        return out

    def __len__(self) -> int:
        return len(self._values)

    def __array__(self, dtype: object = None, copy: object = None) -> np.ndarray:
        return self[:]


#: Detections to price (frame step -> detection indices) -> their payoffs (frame step ->
#: one value per detection of the frame, ``nan`` where none was computed).
Pricer = Callable[[Mapping[int, np.ndarray]], dict[int, np.ndarray]]


class OnDemandPayoffs:
    """The payoffs of a video's frames, each priced the first time a model reads it.

    ``values[step]``: one payoff per detection of that frame, ``nan`` until priced;
    ``price`` prices the detections asked for (perception's attack,
    lesmc/experiment/pricing.py). Shared by every :class:`PricedFrame` of a scene and
    by the variants made from it (another tracker design), so each detection is
    priced once. ``asked`` counts the detections priced so far.
    """

    def __init__(self, values: Mapping[int, np.ndarray], price: Pricer) -> None:
        self.values = {k: np.array(v, dtype=float) for k, v in values.items()}
        self.price = price
        self.asked = 0

    def read(self, step: int, idx: np.ndarray) -> np.ndarray:
        """The payoffs ``values[step][idx]``, pricing the unpriced ones first."""
        col = self.values[step]
        flat = np.atleast_1d(idx)
        need = np.unique(flat[np.isnan(col[flat])])
        if need.size:
            priced = self.price({step: need})[step]
            if len(priced) != len(col) or np.isnan(priced[need]).any():
                raise RuntimeError(f"the pricer did not price what frame {step} asked for")
            # all it priced (a blob's other detections too): none is ever attacked twice
            new = np.isnan(col) & ~np.isnan(priced)
            col[new] = priced[new]
            self.asked += int(new.sum())
        out: np.ndarray = col[idx]
        return out

    def frame(self, f: Frame) -> Frame:
        """``f`` with the payoffs priced so far (still ``nan`` where none was read)."""
        col = self.values.get(f.step)
        if col is None:
            return f
        return Frame(
            f.step,
            tuple(
                d if d.priced else replace(d, payoff=v)
                for d, v in zip(f.detections, col.tolist(), strict=True)
            ),
            f.to_next,
            candidates=f.candidates,
        )


@dataclass(frozen=True)
class PricedFrame(Frame):
    """A frame whose unpriced payoffs are priced when a model reads them
    (:class:`OnDemandPayoffs`)."""

    prices: OnDemandPayoffs | None = field(default=None, compare=False)

    def __post_init__(self) -> None:
        col = None if self.prices is None else self.prices.values.get(self.step)
        if col is not None and len(col) != len(self.detections):
            raise ValueError(
                f"frame {self.step}: {len(self.detections)} detections, but prices for "
                f"{len(col)} (a PricedFrame keeps the detections its prices were made for)"
            )

    def payoffs(self) -> np.ndarray:
        if self.prices is None or self.step not in self.prices.values:
            return super().payoffs()
        return _OnDemandColumn(self.prices, self.step)  # type: ignore[return-value]


class _OnDemandColumn:
    """One frame's payoff column of :class:`OnDemandPayoffs`: indexing prices what it
    reads; any other use of the column prices all of it."""

    def __init__(self, prices: OnDemandPayoffs, step: int) -> None:
        self._prices = prices
        self._step = step

    def __getitem__(self, key: Any) -> np.ndarray:
        n = len(self._prices.values[self._step])
        return self._prices.read(self._step, np.arange(n)[key])

    def __len__(self) -> int:
        return len(self._prices.values[self._step])

    def __array__(self, dtype: object = None, copy: object = None) -> np.ndarray:
        return self[:]


def repriced(frames: tuple[Frame, ...], payoff: Callable[[Detection], float]) -> tuple[Frame, ...]:
    """Plain frames with each detection's payoff replaced by ``payoff(detection)`` (a
    :class:`PricedFrame` becomes a plain one: its prices are not the new payoffs)."""
    return tuple(
        Frame(
            f.step,
            tuple(replace(d, payoff=payoff(d)) for d in f.detections),
            f.to_next,
            candidates=f.candidates,
        )
        for f in frames
    )


def lower_frames(frames: tuple[Frame, ...], lower: Mapping[int, np.ndarray]) -> tuple[Frame, ...]:
    """``frames`` with certified lower payoffs ``lower[step][i]`` for detection i of frame
    ``step`` (``nan``: none; capped by the payoff); detections not given keep theirs."""
    out = []
    for f in frames:
        low = lower.get(f.step)
        if low is not None:
            bounded = ~np.isnan(low)
            if bounded.any() and np.isnan(f.payoff_values()[bounded]).any():
                raise ValueError(f"frame {f.step}: a lower bound for an unpriced payoff")
            f = replace(
                f,
                detections=tuple(
                    d if math.isnan(v) else replace(d, payoff_lower=min(v, d.payoff))
                    for d, v in zip(f.detections, low.tolist(), strict=True)
                ),
            )
        out.append(f)
    return tuple(out)


def warp(Hm: np.ndarray | None, xy: np.ndarray) -> np.ndarray:
    """Carry positions (…, 2) into the next frame's coordinates with a homography.

    The result of each point does not depend on how many are carried together.
    """
    if Hm is None:
        return xy
    pts = np.asarray(xy, dtype=float)
    x, y = pts[..., 0], pts[..., 1]
    # written out elementwise: a matrix product rounds differently with the batch size
    w = Hm[2, 0] * x + Hm[2, 1] * y + Hm[2, 2]
    out = np.empty(pts.shape)
    out[..., 0] = (Hm[0, 0] * x + Hm[0, 1] * y + Hm[0, 2]) / w
    out[..., 1] = (Hm[1, 0] * x + Hm[1, 1] * y + Hm[1, 2]) / w
    return out
