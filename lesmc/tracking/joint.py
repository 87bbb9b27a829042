"""Design "joint": joint Kalman filters around the target (paper section 7.2).

A joint state holds the primary track, the refining tracks of nearby vehicles
and the unassociated detections of the previous frame (candidates to start
tracks). One step:

1. carry every position into the new frame (homography) and predict every track;
2. score every gated (track, detection) pair by the likelihood N(z; Hx̂, S), sort
   from the largest (ties: lower track, then lower detection), and associate
   greedily one-to-one;
3. update the associated tracks (the others skip the update);
4. an unassociated detection within ``init_radius`` of the primary starts a
   refining track if a previous unassociated detection lies within
   ``init_distance`` (their difference over dt is its velocity; detections in
   index order, each with the nearest remaining previous one); otherwise it is
   kept for the next step;
5. refining tracks farther than ``prune_radius`` from the primary, or whose
   trace(P) exceeds ``max_trace``, are dropped.

Attacks (docs/scene-format.md#joint-design): the attacker hides the detections
nearest to the primary's prediction, as for the single design: option j hides
the j nearest (up to the last one the primary's gate accepts) and costs their
payoffs. The hidden detections are gone for every track. Outcomes that leave
the whole joint state identical are merged (the cheapest kept).

Speed: a batch of joint states travels as padded arrays (:class:`JointStates`),
and a whole batch is expanded with array operations, in chunks that bound the
(rows × (tracks + detections)) temporaries. What derives from a track's
covariance is computed once per distinct P (tracking/design.py's
:class:`~lesmc.tracking.design.Gains` over the design's table of track
covariances). The states of a batch share most of their tracks (on the dense
benchmark scene about 40 slots per distinct track), so a track's prediction,
gated detections, likelihoods (``math.exp``, as the per-state loop) and updated
means are computed once per distinct track and (track, detection) pair; a
state's pairs are those of its tracks, each with its place in the scan
(likelihood rank, track, detection). Its options become rows; the greedy
association runs on all rows at once, in rounds (every pair that is first among
the remaining pairs of both its track and its detection is taken, then the
spent tracks' and detections' pairs go), and so do track initiation (one round
per candidate detection) and pruning (a mask). The next states' tracks are rows
of one table of the step's possible tracks; they keep those ids
(:class:`TrackTable`) and 128-bit hashes, so the next step neither hashes their
means nor searches for the distinct ones. Outside the window only option 0 is
built, plus as many further options as its own payoff needs.
tests/joint_oracle.py is an independent oracle written from the paper
(filterpy filters, one path at a time); tests/test_joint.py compares paths.
"""

from __future__ import annotations

import dataclasses
import functools
import math
from dataclasses import dataclass

import numpy as np

from lesmc.common.mixing import mix
from lesmc.model.growing import GrowArray
from lesmc.scene import Scene, TrackerConfig
from lesmc.tracking.association import gate_test, mahalanobis_gate
from lesmc.tracking.design import Batch, CovarianceTable, GainRows, Schedule, Successors
from lesmc.tracking.kalman import (
    Matrices,
    initial_mean,
    mahalanobis2,
    matrices,
    measure,
    positions,
    predict_means,
    update_means,
    warp,
)
from lesmc.tracking.parts.attacker import hiding_options, ranks_and_payoffs, visible

#: The association rounds' "no pair yet" value.
_UNSET = np.iinfo(np.int64).max
#: (states × (tracks + detections)) cells of one chunk: bounds the temporaries of an expansion.
CHUNK_CELLS = 1 << 20


@dataclass(frozen=True)
class TrackTable:
    """Tracks that states of one batch point into (see ``JointStates.tid``)."""

    X: np.ndarray  # (m, d) means
    cov: np.ndarray  # (m,) covariance indices
    zero: int  # a row of zeros (mean 0, covariance index 0): where padding points


def _used_rows(size: int, *ids: np.ndarray | int) -> tuple[np.ndarray, np.ndarray]:
    """The rows of a table of ``size`` rows that ``ids`` name, and every row's number
    among them (valid for those rows)."""
    used = np.zeros(size, dtype=bool)
    for i in ids:
        used[i] = True
    return np.flatnonzero(used), np.cumsum(used) - 1


def _compact(js: JointStates) -> JointStates:
    """``js`` with its track table cut to the rows its states use (and the row of zeros):
    a table holds every track a step could make, a stored batch needs only its own."""
    if js.tid is None or js.table is None:
        return js
    rows, at = _used_rows(len(js.table.X), js.tid, js.table.zero)
    if rows.size == len(js.table.X):
        return js
    table = TrackTable(js.table.X[rows], js.table.cov[rows], int(at[js.table.zero]))
    return dataclasses.replace(js, tid=at[js.tid], table=table)


def _joined(tables: list[TrackTable]) -> tuple[TrackTable, list[int]]:
    """One table holding ``tables`` one after another (and a row of zeros), and where each
    begins in it."""
    if len(tables) == 1:
        return tables[0], [0]
    starts = np.cumsum([0, *(len(t.X) for t in tables)]).tolist()
    X = np.concatenate([*(t.X for t in tables), np.zeros((1, tables[0].X.shape[1]))])
    cov = np.concatenate([*(t.cov for t in tables), np.zeros(1, dtype=np.int64)])
    return TrackTable(X, cov, starts[-1]), starts[:-1]


@dataclass
class JointStates:
    """n joint states as padded arrays: the :class:`~lesmc.tracking.design.Payload` of the design.

    Track 0 is the primary; tracks beyond ``ntrack[i]`` and pending detections
    beyond ``npend[i]`` are padding (zeros). ``tcov`` indexes the design's
    table of track covariances. ``key`` caches :func:`digest` once computed,
    ``th`` the tracks' own 128-bit hashes (:func:`track_hashes`). States made
    together may also say where their tracks are in a shared :class:`TrackTable`
    (``tid``; equal ids are equal tracks, equal tracks may have different ids),
    which spares finding their distinct tracks again.
    """

    _tracks: np.ndarray | None  # (n, T, d) means (None: read from ``table`` when asked)
    _tcov: np.ndarray | None  # (n, T) int64 (likewise)
    ntrack: np.ndarray  # (n,) int64, >= 1
    pending: np.ndarray  # (n, K, 2) unassociated detections of the previous frame
    npend: np.ndarray  # (n,) int64
    key: np.ndarray | None = None  # (n, 2) uint64
    th: np.ndarray | None = None  # (n, T, 2) uint64, padding 0
    tid: np.ndarray | None = None  # (n, T) rows of ``table`` (padding: its zero row)
    table: TrackTable | None = None

    def __len__(self) -> int:
        return int(self.ntrack.shape[0])

    @property
    def width(self) -> int:
        """T: the track slots of each state, padding included."""
        a = self._tcov if self._tcov is not None else self.tid
        assert a is not None
        return int(a.shape[1])

    @property
    def tracks(self) -> np.ndarray:
        """(n, T, d) the tracks' means (padding zeros)."""
        if self._tracks is None:
            self._tracks = self._from_table().X[self.tid]
        return self._tracks

    @property
    def tcov(self) -> np.ndarray:
        """(n, T) the tracks' covariance indices (padding 0)."""
        if self._tcov is None:
            self._tcov = self._from_table().cov[self.tid]
        return self._tcov

    def _from_table(self) -> TrackTable:
        """The table the states' ``tid`` point into (states made without one have their
        arrays)."""
        assert self.table is not None and self.tid is not None
        return self.table

    def primary(self) -> tuple[np.ndarray, np.ndarray]:
        """Track 0 of every state: means (n, d) and covariance indices (n,)."""
        if self._tracks is None and self.table is not None and self.tid is not None:
            return self.table.X[self.tid[:, 0]], self.table.cov[self.tid[:, 0]]
        return self.tracks[:, 0].copy(), self.tcov[:, 0]

    def take(self, idx: np.ndarray) -> JointStates:
        nt, npd = self.ntrack[idx], self.npend[idx]
        T = int(nt.max(initial=1))
        K = int(npd.max(initial=0))
        key = None if self.key is None else self.key[idx]
        th = None if self.th is None else self.th[idx, :T]
        tid = None if self.tid is None else self.tid[idx, :T]
        return JointStates(
            None if self._tracks is None else self._tracks[idx, :T],
            None if self._tcov is None else self._tcov[idx, :T],
            nt,
            self.pending[idx, :K],
            npd,
            key,
            th,
            tid,
            self.table,
        )

    def store(self) -> JointStore:
        return JointStore()

    def words(self) -> tuple[np.ndarray, np.ndarray]:
        """The state as 64-bit words: per track (x bits, covariance index) and per pending
        detection (position bits); (n, T, 5) and (n, K, 2)."""
        n, T = self.tcov.shape
        d = self.tracks.shape[-1]
        t = np.empty((n, T, d + 1), dtype=np.uint64)
        t[..., :d] = np.ascontiguousarray(self.tracks).view(np.uint64)
        t[..., d] = self.tcov.astype(np.uint64)
        p = np.ascontiguousarray(self.pending).view(np.uint64).reshape(n, self.pending.shape[1], 2)
        return t, p


def concat(parts: list[JointStates]) -> JointStates:
    """The states of ``parts`` in order, padded to the widest."""
    if len(parts) == 1:
        return parts[0]
    n = sum(len(p) for p in parts)
    T = max(p.width for p in parts)
    K = max(p.pending.shape[1] for p in parts)
    # states that point into track tables stay so (their tables joined); others are copied
    by_id = all(p.tid is not None and p.table is not None for p in parts)
    out = JointStates(
        None if by_id else np.zeros((n, T, parts[0].tracks.shape[-1])),
        None if by_id else np.zeros((n, T), dtype=np.int64),
        np.concatenate([p.ntrack for p in parts]),
        np.zeros((n, K, 2)),
        np.concatenate([p.npend for p in parts]),
    )
    if all(p.key is not None for p in parts):
        out.key = np.concatenate([p.key for p in parts if p.key is not None])
    if all(p.th is not None for p in parts):
        out.th = np.zeros((n, T, 2), dtype=np.uint64)
    offset: dict[int, int] = {}  # each distinct table's first row in the joined one
    if by_id:
        tables = {id(p.table): p.table for p in parts if p.table is not None}
        out.table, starts = _joined(list(tables.values()))
        offset = dict(zip(tables, starts, strict=True))
        out.tid = np.full((n, T), out.table.zero, dtype=np.int64)
    lo = 0
    for p in parts:
        hi = lo + len(p)
        if not by_id:
            out.tracks[lo:hi, : p.width] = p.tracks
            out.tcov[lo:hi, : p.width] = p.tcov
        out.pending[lo:hi, : p.pending.shape[1]] = p.pending
        if out.th is not None and p.th is not None:
            out.th[lo:hi, : p.th.shape[1]] = p.th
        if by_id and out.tid is not None and p.tid is not None:
            out.tid[lo:hi, : p.tid.shape[1]] = p.tid + offset[id(p.table)]
        lo = hi
    return out


#: Batches smaller than this are gathered into one part once they add up to it: a search
#: that expands a few states at a time would otherwise keep thousands of tiny parts.
STORE_GATHER = 4096


class JointStore:
    """Joint states kept by the unfolder: each batch as it was added (its arrays not
    copied, its track table cut to the rows it uses, small batches gathered into one
    part), and where every state is (part, row).

    Batches keep their digests and track hashes, so states read back need
    neither again.
    """

    def __init__(self) -> None:
        self._parts: list[JointStates] = []
        self._part = GrowArray(np.int64)
        self._row = GrowArray(np.int64)
        self._small = 0  # trailing parts smaller than STORE_GATHER, not gathered yet
        self._small_states = 0

    def extend(self, payload: object, /) -> None:
        assert isinstance(payload, JointStates)
        digest(payload)
        payload = _compact(payload)
        small = len(payload) < STORE_GATHER
        if not small:
            self._gather()
        self._part.extend(np.full(len(payload), len(self._parts), dtype=np.int64))
        self._row.extend(np.arange(len(payload), dtype=np.int64))
        self._parts.append(payload)
        if small:
            self._small += 1
            self._small_states += len(payload)
            if self._small_states >= STORE_GATHER:
                self._gather()

    def _gather(self) -> None:
        """The trailing small parts as one (their states are the last ones added)."""
        k, m = self._small, self._small_states
        self._small = self._small_states = 0
        if k < 2:
            return
        merged = concat(self._parts[-k:])
        del self._parts[-k:]
        self._parts.append(merged)
        n = self._part.n
        self._part.data[n - m : n] = len(self._parts) - 1
        self._row.data[n - m : n] = np.arange(m)

    def take(self, idx: np.ndarray) -> JointStates:
        part, row = self._part.data[idx], self._row.data[idx]
        if not part.size:
            return _empty(1, 0, _dim(self._parts[0]) if self._parts else 4)
        if part.min() == part.max():
            return self._parts[int(part[0])].take(row)
        order = np.argsort(part, kind="stable")
        sp = part[order]
        cut = np.flatnonzero(np.r_[True, sp[1:] != sp[:-1]])
        ends = np.r_[cut[1:], sp.size]
        pieces = [
            self._parts[int(sp[c])].take(row[order[c:e]])
            for c, e in zip(cut.tolist(), ends.tolist(), strict=True)
        ]
        back = np.empty_like(order)
        back[order] = np.arange(order.size)
        return concat(pieces).take(back)


# ------------------------------------------------------------------ digests

_M64 = (1 << 64) - 1


@functools.cache
def _positions(count: int, section: int, lane: int) -> np.ndarray:
    """Per-position constants of a digest section (independent of any padding); read-only."""
    base = np.uint64((0x9E3779B97F4A7C15 * (4 * section + lane + 1)) & _M64)
    with np.errstate(over="ignore"):
        out = mix(
            np.arange(1, count + 1, dtype=np.uint64) * np.uint64(0x9E3779B97F4A7C15) + base, lane
        )
    out.flags.writeable = False
    return out


def hash_tracks(means: np.ndarray, cov: np.ndarray) -> np.ndarray:
    """A 128-bit hash (..., 2) of each track: its mean's bits (..., d) and covariance index."""
    d = means.shape[-1]
    w = np.empty((*cov.shape, d + 1), dtype=np.uint64)
    w[..., :d] = np.ascontiguousarray(means).view(np.uint64)
    w[..., d] = cov.astype(np.uint64)
    out = np.empty((*cov.shape, 2), dtype=np.uint64)
    with np.errstate(over="ignore"):
        for lane in (0, 1):
            out[..., lane] = mix(w ^ _positions(d + 1, 4, lane), lane).sum(axis=-1, dtype=np.uint64)
    return out


def track_hashes(js: JointStates) -> np.ndarray:
    """Each track's :func:`hash_tracks` (n, T, 2), padding 0; cached in ``js.th``."""
    if js.th is None:
        live = np.arange(js.width) < js.ntrack[:, None]
        js.th = np.where(live[..., None], hash_tracks(js.tracks, js.tcov), np.uint64(0))
    return js.th


def digest(js: JointStates) -> np.ndarray:
    """A 128-bit digest (n, 2) of each whole joint state: its track and pending counts,
    each track's hash (:func:`hash_tracks`: mean bits and covariance index), each
    pending detection's position bits.

    Every word is mixed with a constant of its position and the mixed words are
    summed (mod 2⁶⁴), padding left out: the digest does not depend on how wide
    the arrays of a batch are.
    """
    if js.key is not None:
        return js.key
    th = track_hashes(js)
    n, T = len(js), js.width
    p = np.ascontiguousarray(js.pending).view(np.uint64).reshape(n, js.pending.shape[1], 2)
    K = p.shape[1]
    tm = np.arange(T) < js.ntrack[:, None]
    pm = (np.arange(K) < js.npend[:, None])[..., None]
    zero = np.uint64(0)
    out = np.empty((n, 2), dtype=np.uint64)
    with np.errstate(over="ignore"):
        for lane in (0, 1):
            h = mix(js.ntrack.astype(np.uint64) ^ _positions(1, 0, lane), lane)
            h += mix(js.npend.astype(np.uint64) ^ _positions(1, 1, lane), lane)
            ct = _positions(T, 2, lane)
            h += np.where(tm, mix(th[..., lane] ^ ct, lane), zero).sum(axis=1, dtype=np.uint64)
            if K:
                cp = _positions(K * 2, 3, lane).reshape(K, 2)
                h += np.where(pm, mix(p ^ cp, lane), zero).sum(axis=(1, 2), dtype=np.uint64)
            out[:, lane] = h
    return out


def _in_strip(Z: np.ndarray, x: np.ndarray, half: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The detections Z whose x lies within ``half`` of each ``x`` (a superset of any
    circle or box of that radius around it): (owner, detection) pairs, by owner, each
    owner's in x order."""
    by_x = np.argsort(Z[:, 0], kind="stable")
    zx = Z[by_x, 0]
    first = np.searchsorted(zx, x - half, "left")
    cnt = np.searchsorted(zx, x + half, "right") - first
    return np.repeat(np.arange(x.size), cnt), by_x[np.repeat(first, cnt) + _within(cnt)]


def _distinct_tracks(
    js: JointStates, live: np.ndarray
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The distinct tracks (mean bits and covariance index) among the live ones of ``js``:
    each slot's index among them (n, T; padding 0), their means (u, d) and covariance
    indices (u,).

    Only "each slot's track is its row" matters to the caller: every row's
    results are a function of the track alone, so neither the order of the rows
    nor a duplicate row (possible when the states carry ids of a shared
    :class:`TrackTable`) changes them. Without ids, tracks are told apart by
    their hash, checked bit for bit.
    """
    ls, lt = np.nonzero(live)
    if js.tid is not None and js.table is not None:  # ids of a shared table: keep those used
        ids = js.tid[ls, lt]
        rows, at = _used_rows(len(js.table.X), ids)
        tu = np.zeros(live.shape, dtype=np.int64)
        tu[ls, lt] = at[ids]
        return tu, js.table.X[rows], js.table.cov[rows]
    h = track_hashes(js)[ls, lt, 0]
    _, first, inv = np.unique(h, return_index=True, return_inverse=True)
    x = np.ascontiguousarray(js.tracks[ls, lt]).view(np.uint64)
    c = js.tcov[ls, lt]
    rep = first[inv.reshape(-1)]
    if not (np.array_equal(x, x[rep]) and np.array_equal(c, c[rep])):  # a 64-bit collision
        t = np.concatenate([x, c[:, None].astype(np.uint64)], axis=1)
        _, first, inv = np.unique(t, axis=0, return_index=True, return_inverse=True)
    order = np.argsort(first, kind="stable")  # first appearance
    rename = np.empty_like(order)
    rename[order] = np.arange(order.size)
    first = first[order]
    tu = np.zeros(live.shape, dtype=np.int64)
    tu[ls, lt] = rename[inv.reshape(-1)]
    return tu, js.tracks[ls[first], lt[first]].copy(), js.tcov[ls[first], lt[first]]


# ------------------------------------------------------------------ the design


@dataclass
class _Expanded:
    """Successors of one chunk of states (see :meth:`JointDesign._expand`)."""

    src: np.ndarray
    rank: np.ndarray
    payoff: np.ndarray
    det: np.ndarray
    halted: np.ndarray
    states: JointStates
    nis: np.ndarray  # the primary's NIS yᵀ S⁻¹ y where it updates, NaN where it skips


@dataclass
class _Prepared:
    """What the options of a chunk of states share (see :meth:`JointDesign._prepare`).

    Predictions, gains and the primary's nearest detections are kept per distinct
    track (``tu`` maps each state's track slots to them; padding maps to 0).
    """

    Z: np.ndarray  # (z, 2) the frame's detections
    X: np.ndarray  # (u, d) predicted distinct tracks
    g: GainRows  # (u,) their gains
    tu: np.ndarray  # (n, T) each state's tracks among the distinct ones
    live: np.ndarray  # (n, T) real tracks
    pend: np.ndarray  # (n, K, 2) pending detections, in this frame's coordinates
    npend: np.ndarray
    n_opt: np.ndarray  # (n,) the attacker's options
    cost: np.ndarray  # (n, w + 1) cost of option j: hiding the j nearest
    rank_of: np.ndarray  # (u, z) each detection's position among a primary's nearest
    ps: np.ndarray  # gated pairs (state, track, detection), grouped by state
    pt: np.ndarray
    pz: np.ndarray
    prio: np.ndarray  # each pair's place in its state's scan (smaller first), unique per state
    pu: np.ndarray  # each pair among the distinct (track, detection) pairs
    # every track a state's track can become: the u predicted ones (a skipped update),
    # then the distinct pairs' updated ones (Eq. 2); means, covariance indices, hashes, halts
    child_X: np.ndarray  # (u + distinct pairs, d)
    child_cov: np.ndarray
    child_h: np.ndarray  # (u + distinct pairs, 2)
    child_halt: np.ndarray
    near_z: np.ndarray  # (u, w) a primary's nearest detections (valid up to n_near)
    n_near: np.ndarray  # (u,)
    pos: tuple[int, int] = (0, 1)  # the measured components (Matrices.pos)

    def visible_rank(self, s: np.ndarray) -> np.ndarray:
        """(len(s), z): each detection's position among the nearest of state s's primary."""
        out: np.ndarray = self.rank_of[self.tu[s, 0]]
        return out


class JointDesign:
    """Primary plus refining tracks with likelihood-sorted one-to-one association."""

    name = "joint"

    def __init__(self, scene: Scene) -> None:
        self.scene = scene
        self.cfg = scene.tracker
        self.m: Matrices = matrices(self.cfg, scene.dt)
        self.covariances = CovarianceTable()  # the primaries' (the model's table)
        self.track_covariances = CovarianceTable()  # every track's
        self.schedule = Schedule(self.m, self.cfg, self.track_covariances)
        self._model_cov = np.full(0, -1, dtype=np.int64)  # track table -> model table
        self._p0 = self.track_covariances.add(self.m.P0.copy())
        self._p0_kept = float(np.trace(self.m.P0)) <= self.cfg.max_trace
        self._firsts: list[np.ndarray] = [np.empty(0, np.int64)] * 2  # see _unset

    def initial(self) -> Batch:
        t = self.scene.target
        x0 = initial_mean(self.m, t.start, t.velocity)
        Z = self.scene.frame(t.step).positions()
        near = Z[np.hypot(*(Z - np.array(t.start)).T) <= self.cfg.init_radius] if len(Z) else Z
        near = near.reshape(-1, 2)
        js = JointStates(
            x0.reshape(1, 1, -1),
            np.array([[self._p0]], dtype=np.int64),
            np.ones(1, dtype=np.int64),
            near[None].copy(),
            np.array([len(near)], dtype=np.int64),
        )
        return self._batch(js, np.zeros(1, dtype=bool))

    def _batch(self, js: JointStates, halted: np.ndarray) -> Batch:
        """Joint states as a batch: the primary's estimate and covariance are the model's."""
        X, cov = js.primary()
        return Batch(X, self._to_model(cov), halted, js)

    def _to_model(self, c: np.ndarray) -> np.ndarray:
        """Model-table indices of track-table covariances (new ones added in order of first use)."""
        if len(self.track_covariances) > len(self._model_cov):
            grow = len(self.track_covariances) - len(self._model_cov)
            self._model_cov = np.r_[self._model_cov, np.full(grow, -1, dtype=np.int64)]
        u, first = np.unique(c, return_index=True)
        new = u[self._model_cov[u] < 0]
        if new.size:
            order = np.argsort(first[self._model_cov[u] < 0], kind="stable")
            for ci in new[order].tolist():
                self._model_cov[ci] = self.covariances.add(self.track_covariances[ci])
        out: np.ndarray = self._model_cov[c]
        return out

    def keys(self, batch: Batch) -> np.ndarray:
        """A 128-bit digest of each whole joint state (tracks and pending detections)."""
        assert isinstance(batch.objects, JointStates)
        return digest(batch.objects)

    def successors(self, batch: Batch, step: int, attacked: bool) -> Successors:
        """Every state's outcomes, chunk by chunk of states, each chunk with array operations."""
        js = batch.objects
        assert isinstance(js, JointStates)
        Z = self.scene.frame(step).positions()
        T = js.width
        size = max(1, CHUNK_CELLS // (T + len(Z)))
        parts = []
        for lo in range(0, len(js), size):
            part = js.take(np.arange(lo, min(lo + size, len(js))))
            e = self._expand(part, step, attacked)
            e.src += lo
            parts.append(e)
        if not parts:
            parts.append(self._expand(js, step, attacked))
        states = concat([e.states for e in parts])
        succ = self._batch(states, np.concatenate([e.halted for e in parts]))
        return Successors(
            np.concatenate([e.src for e in parts]),
            np.concatenate([e.rank for e in parts]),
            np.concatenate([e.payoff for e in parts]),
            np.concatenate([e.det for e in parts]),
            succ,
            np.concatenate([e.nis for e in parts]),
        )

    # -------------------------------------------------------------- one chunk
    def _expand(self, js: JointStates, step: int, attacked: bool) -> _Expanded:
        """The outcomes of the states ``js`` at frame ``step`` (see the module docstring)."""
        p = self._prepare(js, step)
        n = len(js)
        if attacked:
            s, opt, assign, halt, states = self._rows(p, np.zeros(n, dtype=np.int64), p.n_opt)
            rows = np.nonzero(self._merge(states, s))[0]
            rank, payoff = ranks_and_payoffs(s[rows], p.cost[s[rows], opt[rows]])
            return _Expanded(
                s[rows].astype(np.int64),
                rank,
                payoff,
                assign[rows, 0].astype(np.int64),
                halt[rows, 0],
                states.take(rows),
                _primary_nis(p, s[rows], assign[rows, 0]),
            )
        # unattacked: option 0, and its own payoff, the cost of the first option that differs
        s, opt, assign, halt, states = self._rows(
            p, np.zeros(n, dtype=np.int64), np.minimum(p.n_opt, 1)
        )
        states.key = key0 = digest(states)
        payoff = np.zeros(n)
        sure = _option_one_differs(p, assign[:, 0])
        if sure.any():
            payoff[sure] = p.cost[sure, 1]
        todo = np.flatnonzero(~sure)
        j = 1
        while True:
            todo = todo[p.n_opt[todo] > j]
            if not todo.size:
                break
            lo = np.zeros(n, dtype=np.int64)
            lo[todo] = j
            hi = lo.copy()
            hi[todo] = j + 1
            sj, _, _, _, nxt = self._rows(p, lo, hi)
            differs = (digest(nxt) != key0[sj]).any(axis=1)
            same = nxt.take(np.nonzero(~differs)[0])
            if not _same_as(same, states, sj[~differs]):
                raise AssertionError("joint state digest collision")
            payoff[sj[differs]] = p.cost[sj[differs], j]
            todo = sj[~differs]
            j += 1
        return _Expanded(
            s.astype(np.int64),
            np.zeros(n, dtype=np.int64),
            payoff,
            assign[:, 0].astype(np.int64),
            halt[:, 0],
            states,
            _primary_nis(p, s, assign[:, 0]),
        )

    def _prepare(self, js: JointStates, step: int) -> _Prepared:
        """What every option of a state shares: predictions, gains, the primary's nearest
        detections and what hiding them costs, and the gated pairs with their priorities.

        A track's prediction, gains, gated detections and likelihoods depend only on
        the track (its mean and covariance), and the states of a batch share most
        of their tracks; all of that is computed once per distinct track.
        """
        cfg = self.cfg
        frame = self.scene.frame(step)
        Z = frame.positions()
        nz = len(Z)
        T = js.width
        Hm = self.scene.frame(step - 1).to_next
        live = np.arange(T) < js.ntrack[:, None]
        tu, X, cu = _distinct_tracks(js, live)
        m, gains = self.schedule.at(step)
        if Hm is not None:
            X[:, list(m.pos)] = warp(Hm, positions(m, X))
        X = predict_means(m, X)
        pend = warp(Hm, js.pending) if Hm is not None else js.pending
        g = gains.rows(cu)
        U = len(cu)

        track, pz, dx, dy, d2, ok = _candidate_pairs(Z, measure(m, X), g, cfg)
        hiding = hiding_options(tu[:, 0], track, pz, dx, dy, ok, g.radius, frame.payoffs(), U, nz)
        n_opt, cost, rank_of, near_z, per = hiding
        track, pz, d2 = track[ok], pz[ok], d2[ok]
        del dx, dy, ok, hiding  # the candidates' arrays: only the gated pairs go on
        ps, pt, pair_z, prio, idx = _ranked_pairs(track, pz, d2, g.norm, tu, live, U, T, nz)
        X_up = update_means(m, X[track], g.K[track], Z[pz])
        child_cov = np.concatenate([g.pred, g.post[track]])
        child_X = np.concatenate([X, X_up])
        return _Prepared(
            Z=Z,
            X=X,
            g=g,
            tu=tu,
            live=live,
            pend=pend,
            npend=js.npend,
            n_opt=n_opt,
            cost=cost,
            rank_of=rank_of,
            ps=ps,
            pt=pt,
            pz=pair_z,
            prio=prio,
            pu=idx,
            child_X=child_X,
            child_cov=child_cov,
            child_h=hash_tracks(child_X, child_cov),
            child_halt=np.concatenate([g.halt_pred, g.halt_post[track]]),
            near_z=near_z,
            n_near=per,
            pos=self.m.pos,
        )

    def _rows(
        self, p: _Prepared, lo: np.ndarray, hi: np.ndarray
    ) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, JointStates]:
        """The next states of options lo[i] .. hi[i] − 1 of every state i, as rows (by state,
        then option): source, option, association (rows, tracks), halted flags (rows, tracks)."""
        Z = p.Z
        nz = len(Z)
        count = hi - lo
        R = int(count.sum())
        s = np.repeat(np.arange(len(count)), count)
        start = _starts(count)
        opt = np.repeat(lo, count) + _within(count)
        visible_ = visible(p.visible_rank(s), opt)  # option j hides the j nearest to the primary
        assign, pair = self._associate(p, lo, hi, start, R)
        a = assign >= 0
        child = np.where(a, len(p.X) + pair, p.tu[s])  # rows of the p.child_* tables
        halt = p.child_halt[child]
        ra, ta = np.nonzero(a)
        used = np.zeros((R, nz), dtype=bool)
        used[ra, assign[ra, ta]] = True
        states = self._initiate_and_prune(
            p, child, halt, p.live[s], visible_ & ~used, p.pend[s], p.npend[s]
        )
        return s, opt, assign, halt, states

    def _associate(
        self, p: _Prepared, lo: np.ndarray, hi: np.ndarray, start: np.ndarray, R: int
    ) -> tuple[np.ndarray, np.ndarray]:
        """The greedy one-to-one association of every option row: (R, T) detection per track,
        −1 for none, and (R, T) the distinct pair taken (``p.pu``; −1).

        Pairs are scored once per state; a row sees those whose detection its
        option leaves visible. Scanning a row's pairs in (−likelihood, track,
        detection) order (``p.prio``) takes a pair when its track and detection
        are both unspent. In rounds: every pair that comes first among the
        remaining pairs of its track and among those of its detection is taken
        (nothing before it can spend either), then the pairs of spent tracks and
        detections go.
        """
        T, nz = p.tu.shape[1], len(p.Z)
        ps, pt, pz = p.ps, p.pt, p.pz
        if len(lo) == R and not lo.any():  # option 0 of every state: one row each, all pairs
            pair, prio = np.arange(ps.size), p.prio
            kt = ps * T + pt  # flat (row, track) and (row, detection) positions
            kz = ps * nz + pz
        else:  # a pair serves the options up to its detection's place among the primary's nearest
            reps = np.maximum(np.minimum(hi[ps], p.rank_of[p.tu[ps, 0], pz] + 1) - lo[ps], 0)
            pair = np.repeat(np.arange(ps.size), reps)
            row = start[ps[pair]] + _within(reps)
            pz = pz[pair]
            prio = p.prio[pair]
            kt = row * T + pt[pair]
            kz = row * nz + pz
        assign = np.full(R * T, -1, dtype=np.int64)
        taken = np.full(R * T, -1, dtype=np.int64)
        used_t = np.zeros(R * T, dtype=bool)
        used_z = np.zeros(R * nz, dtype=bool)
        buf_t, buf_z = self._unset(0, R * T), self._unset(1, R * nz)
        self._firsts = [np.empty(0, np.int64)] * 2  # taken: a failure below leaves them dirty
        first_t, first_z = buf_t[: R * T], buf_z[: R * nz]
        while prio.size:
            # a pair first among the remaining pairs of both its track and its detection
            # is the one the scan takes for them: take all such pairs at once
            np.minimum.at(first_t, kt, prio)
            np.minimum.at(first_z, kz, prio)
            take = np.flatnonzero((first_t[kt] == prio) & (first_z[kz] == prio))
            first_t[kt] = _UNSET  # back to unset for the next round
            first_z[kz] = _UNSET
            assign[kt[take]] = pz[take]
            taken[kt[take]] = pair[take]
            used_t[kt[take]] = True
            used_z[kz[take]] = True
            left = np.flatnonzero(~(used_t[kt] | used_z[kz]))
            prio, kt, kz, pz, pair = prio[left], kt[left], kz[left], pz[left], pair[left]
        self._firsts = [buf_t, buf_z]  # every entry unset again: reusable
        got = taken >= 0
        taken[got] = p.pu[taken[got]]
        return assign.reshape(R, T), taken.reshape(R, T)

    def _unset(self, which: int, size: int) -> np.ndarray:
        """A scratch array of at least ``size`` entries, all :data:`_UNSET` (kept between
        calls: the association rounds put back every entry they touch, and filling afresh
        cost more than the rounds on big chunks)."""
        buf = self._firsts[which]
        if buf.size < size:
            buf = np.full(max(size, 2 * buf.size), _UNSET)
        return buf

    def _initiate_and_prune(
        self,
        p: _Prepared,
        child: np.ndarray,
        halt: np.ndarray,
        live: np.ndarray,
        free: np.ndarray,
        pend: np.ndarray,
        npend: np.ndarray,
    ) -> JointStates:
        """Rows' next states: new tracks from free detections near the primary, pruning.

        ``child`` (rows, T) gives each track's next value as a row of the
        ``p.child_*`` tables. Free detections within ``init_radius`` of the
        updated primary are taken in index order, one round each: each is matched
        to the nearest remaining pending detection (first of equals) closer than
        ``init_distance``, which starts a track, or is kept pending for the next step.
        """
        cfg = self.cfg
        Z = p.Z
        R, T = child.shape
        prim = positions(self.m, p.child_X[child[:, 0]])
        cr, cz, partner = _start_candidates(Z, prim, free, pend, npend, cfg)
        matched = partner >= 0
        # new tracks after the old ones, in the order they started
        mr = cr[matched]
        mz = Z[cz[matched]]
        v = (mz - pend[mr, partner[matched]]) / self.scene.dt
        nnew = np.bincount(mr, minlength=R)
        W = T + int(nnew.max(initial=0))
        # the tracks of the next states as rows of one table: the children, a row of
        # zeros (padding), the new tracks
        M = len(p.child_X)
        table_X, table_cov, table_h = self._track_table(p, mz, v)
        at = np.full((R, W), M, dtype=np.int64)
        at[:, :T] = child
        keep = np.zeros((R, W), dtype=bool)
        keep[:, :T] = live & ~halt
        slot = live.sum(axis=1)[mr] + _within(nnew)
        at[mr, slot] = M + 1 + np.arange(mr.size)
        keep[mr, slot] = self._p0_kept
        at, nt = self._pruned(at, keep, positions(self.m, table_X)[at], prim, M)
        th = table_h[at]  # the means and covariance indices are read from the table when asked
        pending, npd = _still_pending(Z, cr[~matched], cz[~matched], R)
        return JointStates(
            None,
            None,
            nt.astype(np.int64),
            pending,
            npd.astype(np.int64),
            th=th,
            tid=at,
            table=TrackTable(table_X, table_cov, M),
        )

    def _track_table(
        self, p: _Prepared, mz: np.ndarray, v: np.ndarray
    ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Means, covariance indices and hashes of the children, a padding row, then new tracks.

        A new track starts at position ``mz`` with velocity ``v`` and covariance P0.
        """
        new_X = np.zeros((mz.shape[0], self.m.dim))
        new_X[:, list(self.m.pos)] = mz
        if self.m.vel is not None:
            new_X[:, list(self.m.vel)] = v
        new_cov = np.full(mz.shape[0], self._p0, dtype=np.int64)
        table_X = np.concatenate([p.child_X, np.zeros((1, self.m.dim)), new_X])
        table_cov = np.concatenate([p.child_cov, np.zeros(1, dtype=np.int64), new_cov])
        table_h = np.concatenate(
            [p.child_h, np.zeros((1, 2), dtype=np.uint64), hash_tracks(new_X, new_cov)]
        )
        return table_X, table_cov, table_h

    def _pruned(
        self, at: np.ndarray, keep: np.ndarray, pos: np.ndarray, prim: np.ndarray, M: int
    ) -> tuple[np.ndarray, np.ndarray]:
        """Rows' tracks without those farther than ``prune_radius`` from the primary.

        ``at`` (rows, W) are table rows, ``pos`` their positions, ``M`` the table's
        padding row. The kept tracks move up in order; returns the trimmed ``at``
        and each row's track count.
        """
        dp = np.hypot(pos[..., 0] - prim[:, 0, None], pos[..., 1] - prim[:, 1, None])
        keep &= dp <= self.cfg.prune_radius
        keep[:, 0] = True  # the primary stays (halted or not)
        nt = keep.sum(axis=1)
        at = np.where(keep, at, M)
        gap = np.flatnonzero((keep[:, 1:] & ~keep[:, :-1]).any(axis=1))  # a kept after a dropped
        if gap.size:  # the kept tracks of those rows move up, in order
            order = np.argsort(~keep[gap], axis=1, kind="stable")
            at[gap] = np.take_along_axis(at[gap], order, axis=1)
        return at[:, : int(nt.max(initial=1))], nt

    def _merge(self, states: JointStates, s: np.ndarray) -> np.ndarray:
        """Which rows are the first (cheapest) of their state's identical outcomes."""
        states.key = key = digest(states)
        o = np.lexsort((np.arange(len(s)), key[:, 1], key[:, 0], s))
        ks, k0, k1 = s[o], key[o, 0], key[o, 1]
        head = np.r_[True, (ks[1:] != ks[:-1]) | (k0[1:] != k0[:-1]) | (k1[1:] != k1[:-1])]
        rep = np.empty(len(s), dtype=np.int64)
        rep[o] = o[np.maximum.accumulate(np.where(head, np.arange(len(s)), 0))]
        if not _same(states, rep):  # two different outcomes share a 128-bit digest
            raise AssertionError("joint state digest collision")
        kept = np.zeros(len(s), dtype=bool)
        kept[o[head]] = True
        return kept


def _primary_nis(p: _Prepared, s: np.ndarray, det: np.ndarray) -> np.ndarray:
    """The NIS yᵀ S⁻¹ y of the primary's update in each outcome (state ``s``, detection
    ``det`` of the frame, −1: it skips the update, NaN)."""
    out = np.full(len(s), np.nan)
    upd = det >= 0
    if upd.any():
        u = p.tu[s[upd], 0]
        y = p.Z[det[upd]] - p.X[u][:, list(p.pos)]
        out[upd] = mahalanobis2(y, p.g.S_inv[u])
    return out


def _option_one_differs(p: _Prepared, primary: np.ndarray) -> np.ndarray:
    """States whose option 1 surely leads elsewhere than option 0, without building it.

    When option 0's primary updates with the nearest detection, hiding it
    leaves the primary either skipping (its P differs) or updating with another
    detection within its gate; if every such detection lies at least δ away
    and K's position block (nonsingular) moves the estimate by at least
    σ_min(K)·δ, far above rounding, the primary's estimate differs.
    """
    n, w = len(primary), p.near_z.shape[1]
    u0 = p.tu[:, 0]
    if not w:
        return np.zeros(n, dtype=bool)
    ok: np.ndarray = (p.n_opt > 1) & (p.n_near[u0] > 0)
    ok[ok] = primary[ok] == p.near_z[u0[ok], 0]
    if not ok.any():
        return ok
    u = np.unique(u0[ok])  # what follows depends on the primary track only
    z0 = p.Z[p.near_z[u, 0]]
    dz = p.Z[p.near_z[u]] - z0[:, None]
    gap = np.where(np.arange(w) < p.n_near[u, None], np.hypot(dz[..., 0], dz[..., 1]), np.inf)
    delta = gap[:, 1:].min(axis=1, initial=np.inf)
    K = p.g.K[u][:, list(p.pos), :]  # (u, 2, 2): how the position moves with the innovation
    sigma_min = np.sqrt(np.maximum(np.linalg.eigvalsh(np.swapaxes(K, 1, 2) @ K)[:, 0], 0.0))
    at = p.X[u][:, list(p.pos)]
    scale = 1.0 + np.abs(at).max(axis=1) + np.abs(dz).max(axis=(1, 2), initial=0.0)
    moves = np.zeros(len(p.X), dtype=bool)
    moves[u] = sigma_min * delta > 1e-6 * scale
    out: np.ndarray = ok & moves[u0]
    return out


def _starts(counts: np.ndarray) -> np.ndarray:
    """Where each group of a flattened grouping begins, for group sizes ``counts``."""
    out: np.ndarray = np.cumsum(counts) - counts
    return out


def _still_pending(
    Z: np.ndarray, ur: np.ndarray, uz: np.ndarray, R: int
) -> tuple[np.ndarray, np.ndarray]:
    """Each row's pending detections: the candidates (ur, uz) that started no track, in order."""
    npd = np.bincount(ur, minlength=R)
    pending = np.zeros((R, int(npd.max(initial=0)), 2))
    pending[ur, _within(npd)] = Z[uz]
    return pending, npd


def _within(counts: np.ndarray) -> np.ndarray:
    """Each element's position within its group, for consecutive groups of sizes ``counts``."""
    out: np.ndarray = np.arange(int(counts.sum())) - np.repeat(_starts(counts), counts)
    return out


def _same_as(a: JointStates, b: JointStates, idx: np.ndarray) -> bool:
    """State i of ``a`` equals state idx[i] of ``b`` bit for bit."""
    if not len(a):
        return True
    bb = b.take(idx)
    T, K = max(a.tcov.shape[1], bb.tcov.shape[1]), max(a.pending.shape[1], bb.pending.shape[1])
    a, bb = (concat([x, _empty(T, K, _dim(a))]) for x in (a, bb))
    return _same(concat([a, bb]), np.r_[np.arange(len(a), 2 * len(a)), np.arange(len(a))])


def _empty(T: int, K: int, d: int) -> JointStates:
    """No states, arrays T tracks of dimension d and K pending detections wide (for padding
    with concat)."""
    z = np.zeros(0, dtype=np.int64)
    return JointStates(np.zeros((0, T, d)), np.zeros((0, T), np.int64), z, np.zeros((0, K, 2)), z)


def _dim(js: JointStates) -> int:
    """d: the dimension of the tracks' state."""
    return int((js._tracks if js._tracks is not None else js._from_table().X).shape[-1])


def _same(js: JointStates, rep: np.ndarray) -> bool:
    """Every state equals the state ``rep[i]`` bit for bit (padding included: it is zero)."""
    t, p = js.words()
    return bool(
        np.array_equal(js.ntrack, js.ntrack[rep])
        and np.array_equal(js.npend, js.npend[rep])
        and np.array_equal(t, t[rep])
        and np.array_equal(p, p[rep])
    )


def _candidate_pairs(
    Z: np.ndarray, at: np.ndarray, g: GainRows, cfg: TrackerConfig
) -> tuple[np.ndarray, ...]:
    """The (track, detection) pairs within each track's gate radius around its predicted
    position ``at`` (u, 2) (a little wider: the
    gate decides), found in the strip of detections sorted by x, by track then detection:
    track, detection, dx, dy, Mahalanobis d², and whether the gate admits the pair."""
    nz = len(Z)
    r = g.radius * (1 + 1e-9)
    track, pz = _in_strip(Z, at[:, 0], r)
    o = np.argsort(track * max(nz, 1) + pz, kind="stable")
    track, pz = track[o], pz[o]
    dx = Z[pz, 0] - at[track, 0]
    dy = Z[pz, 1] - at[track, 1]
    keep = dx * dx + dy * dy <= r[track] ** 2
    track, pz, dx, dy = track[keep], pz[keep], dx[keep], dy[keep]
    y = np.stack([dx, dy], axis=-1)
    S_inv = g.S_inv[track]
    d2 = mahalanobis2(y, S_inv)
    if cfg.gate_type == "mahalanobis":
        ok = mahalanobis_gate(d2, cfg.gate)
    else:
        ok = gate_test(y, S_inv, g.spread[track], cfg.gate, cfg.gate_type)
    return track, pz, dx, dy, d2, ok


def _ranked_pairs(
    track: np.ndarray,
    pz: np.ndarray,
    d2: np.ndarray,
    norm: np.ndarray,
    tu: np.ndarray,
    live: np.ndarray,
    U: int,
    T: int,
    nz: int,
) -> tuple[np.ndarray, ...]:
    """The gated pairs of every state (those of its tracks), scored by N(z; Hx̂, S) as the
    per-state loop does (math.exp) and ranked from the likeliest: state, track slot,
    detection, priority (likelihood, then track, then detection) and the pair's index."""
    like = np.fromiter(map(math.exp, (-0.5 * d2).tolist()), float, d2.size) / norm[track]
    values, dense = np.unique(like, return_inverse=True)
    score = len(values) - 1 - dense.reshape(-1)  # 0 for the likeliest
    gcount = np.bincount(track, minlength=U)
    ls, lt = np.nonzero(live)
    c = gcount[tu[ls, lt]]
    idx = np.repeat(_starts(gcount)[tu[ls, lt]], c) + _within(c)
    ps, pt, pz = np.repeat(ls, c), np.repeat(lt, c), pz[idx]
    prio = (score[idx] * T + pt) * max(nz, 1) + pz
    return ps, pt, pz, prio, idx


def _start_candidates(
    Z: np.ndarray,
    prim: np.ndarray,
    free: np.ndarray,
    pend: np.ndarray,
    npend: np.ndarray,
    cfg: TrackerConfig,
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The free detections within ``init_radius`` of each row's updated primary ``prim``
    (by row, then detection index) and the pending detection each starts a track with
    (-1: none). One round per candidate, in index order: the nearest remaining pending
    detection (first of equals) closer than ``init_distance``."""
    R = len(prim)
    box = cfg.init_radius * (1 + 1e-9)
    # candidates from the strip of detections sorted by x (a little wider), then the
    # exact box and circle tests
    cr, cz = _in_strip(Z, prim[:, 0], box + 1e-6 * (box + np.abs(prim[:, 0])))
    ddx = Z[cz, 0] - prim[cr, 0]
    ddy = Z[cz, 1] - prim[cr, 1]
    ok = free[cr, cz] & (np.abs(ddx) <= box) & (np.abs(ddy) <= box)
    ok[ok] = np.hypot(ddx[ok], ddy[ok]) <= cfg.init_radius
    o = np.flatnonzero(ok)
    o = o[np.argsort(cr[o] * max(len(Z), 1) + cz[o], kind="stable")]
    cr, cz = cr[o], cz[o]  # by row, then detection index
    nc = np.bincount(cr, minlength=R)
    k = _within(nc)
    pool = np.arange(pend.shape[1]) < npend[:, None]
    partner = np.full(cr.size, -1, dtype=np.int64)
    todo = np.asarray(pool[cr].any(axis=1))
    by_k = np.argsort(k, kind="stable")
    bounds = np.searchsorted(k[by_k], np.arange(int(k.max(initial=-1)) + 2))
    for j in range(len(bounds) - 1):
        sel = by_k[bounds[j] : bounds[j + 1]]
        sel = sel[todo[sel]]
        rows = cr[sel]
        sel, rows = sel[pool[rows].any(axis=1)], rows[pool[rows].any(axis=1)]
        if not sel.size:
            continue
        z = Z[cz[sel]]
        dd = np.hypot(z[:, 0, None] - pend[rows, :, 0], z[:, 1, None] - pend[rows, :, 1])
        dd = np.where(pool[rows], dd, np.inf)
        b = np.argmin(dd, axis=1)
        hit = dd[np.arange(sel.size), b] < cfg.init_distance
        partner[sel[hit]] = b[hit]
        pool[rows[hit], b[hit]] = False
    return cr, cz, partner
