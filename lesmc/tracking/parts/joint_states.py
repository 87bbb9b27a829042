"""The joint design's states (lesmc/tracking/joint.py) as padded arrays, the store the
unfolder keeps them in, and their digests.

A joint state holds the primary track, the refining tracks of nearby vehicles and the
unassociated detections of the previous frame (candidates to start tracks). A batch of
them is a :class:`JointStates` (the :class:`~lesmc.tracking.design.Payload` of the design);
states made together may point into a shared :class:`TrackTable` of the step's possible
tracks, which spares finding their distinct tracks again.

Speed: a batch of joint states travels as padded arrays (:class:`JointStates`), and
a whole batch is expanded with array operations, in chunks that bound the
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
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass

import numpy as np

from lesmc.model.growing import GrowArray
from lesmc.tracking.parts.joint_digest import hash_tracks, state_digest


@dataclass(frozen=True)
class TrackTable:
    """Tracks that states of one batch point into (see ``JointStates.tid``)."""

    X: np.ndarray  # (m, d) means
    cov: np.ndarray  # (m,) covariance indices
    zero: int  # a row of zeros (mean 0, covariance index 0): where padding points


def used_rows(size: int, *ids: np.ndarray | int) -> tuple[np.ndarray, np.ndarray]:
    """The rows of a table of ``size`` rows that ``ids`` name, and every row's number
    among them (valid for those rows)."""
    used = np.zeros(size, dtype=bool)
    for i in ids:
        used[i] = True
    return np.flatnonzero(used), np.cumsum(used) - 1


def compact(js: JointStates) -> JointStates:
    """``js`` with its track table cut to the rows its states use (and the row of zeros):
    a table holds every track a step could make, a stored batch needs only its own."""
    if js.tid is None or js.table is None:
        return js
    rows, at = used_rows(len(js.table.X), js.tid, js.table.zero)
    if rows.size == len(js.table.X):
        return js
    table = TrackTable(js.table.X[rows], js.table.cov[rows], int(at[js.table.zero]))
    return dataclasses.replace(js, tid=at[js.tid], table=table)


def joined(tables: list[TrackTable]) -> tuple[TrackTable, list[int]]:
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

    def tracks_moved(self, rows: np.ndarray) -> int:
        """The work of evaluating rows whose source states are ``rows`` (positions in
        these states): each row moves every track of its state (at least one unit a row),
        counted per state so that it does not depend on how the states were batched
        (Successors.examined, GrowingModel.work)."""
        return int(np.maximum(self.ntrack[rows], 1).sum())

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
        out.table, starts = joined(list(tables.values()))
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
        payload = compact(payload)
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
            return empty_states(1, 0, state_dim(self._parts[0]) if self._parts else 4)
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


def track_hashes(js: JointStates) -> np.ndarray:
    """Each track's :func:`hash_tracks` (n, T, 2), padding 0; cached in ``js.th``."""
    if js.th is None:
        live = np.arange(js.width) < js.ntrack[:, None]
        js.th = np.where(live[..., None], hash_tracks(js.tracks, js.tcov), np.uint64(0))
    return js.th


def digest(js: JointStates) -> np.ndarray:
    """A 128-bit digest (n, 2) of each whole joint state (joint_digest.state_digest): its
    track and pending counts, each track's hash (mean bits and covariance index), each
    pending detection's position bits; cached in ``js.key``."""
    if js.key is not None:
        return js.key
    return state_digest(track_hashes(js), js.width, js.ntrack, js.pending, js.npend)


def same_as(a: JointStates, b: JointStates, idx: np.ndarray) -> bool:
    """State i of ``a`` equals state idx[i] of ``b`` bit for bit."""
    if not len(a):
        return True
    bb = b.take(idx)
    T, K = max(a.tcov.shape[1], bb.tcov.shape[1]), max(a.pending.shape[1], bb.pending.shape[1])
    a, bb = (concat([x, empty_states(T, K, state_dim(a))]) for x in (a, bb))
    return same_states(concat([a, bb]), np.r_[np.arange(len(a), 2 * len(a)), np.arange(len(a))])


def empty_states(T: int, K: int, d: int) -> JointStates:
    """No states, arrays T tracks of dimension d and K pending detections wide (for padding
    with concat)."""
    z = np.zeros(0, dtype=np.int64)
    return JointStates(np.zeros((0, T, d)), np.zeros((0, T), np.int64), z, np.zeros((0, K, 2)), z)


def state_dim(js: JointStates) -> int:
    """d: the dimension of the tracks' state."""
    return int((js._tracks if js._tracks is not None else js._from_table().X).shape[-1])


def same_states(js: JointStates, rep: np.ndarray) -> bool:
    """Every state equals the state ``rep[i]`` bit for bit (padding included: it is zero)."""
    t, p = js.words()
    return bool(
        np.array_equal(js.ntrack, js.ntrack[rep])
        and np.array_equal(js.npend, js.npend[rep])
        and np.array_equal(t, t[rep])
        and np.array_equal(p, p[rep])
    )
