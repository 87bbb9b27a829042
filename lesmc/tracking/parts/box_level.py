"""The successors of a whole level of box-tracker states at once (``sort``: the unfolder,
lesmc/unfold/multi.py): what :meth:`~lesmc.tracking.multi.MultiTargetTracker.step` computes
for every (state, detections kept) pair, with the parts shared by the pairs computed once.

Every track of every state of the level is predicted once (its covariance once per
distinct covariance), scored against every box of the frame once (one IoU array), and
updated with every box once (one gain per distinct predicted covariance); the new tracks
every box would start are the same for every state. A successor is then a list of rows
of that table of candidate tracks (a track coasting, a track updated with box j, the track
box j starts). SORT's assignment shortcut (every kept row and every column with at most one
IoU above the threshold) is decided for every (state, option) pair at once
(:meth:`~lesmc.tracking.parts.associator.GlobalAssociator.by_shortcut`) and those
successors are built in arrays; the others call the associator's ``assign``
(``linear_sum_assignment``) one by one. Everything after the assignment (the initiator's
output rule, the deleter, the boxes, the padded state arrays) is done for the whole level
in arrays.

Exact: each candidate is computed by the same functions as ``step`` on the same inputs,
and those are elementwise or one matrix product per matrix (lesmc/tracking/kalman.py), so
a successor is bit for bit the state ``step`` makes (tests/test_sort*.py's oracles check
the unfolded models against the reference SORT).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from lesmc.tracking.design import CovarianceTable
from lesmc.tracking.kalman import innovations, update_means
from lesmc.tracking.parts.boxes import to_boxes, to_z
from lesmc.tracking.parts.states import COUNTS, MultiBatch, distinct_rows
from lesmc.tracking.parts.tracks import Tracks


@dataclass(frozen=True)
class LevelSuccessors:
    """The successors of a level: the state each comes from (``src``), the successors as
    states (``batch``, ``last`` left −1 for the caller), and the tracks each outputs after
    its frame (those alive, in ``batch``'s slots): boxes (S, T, 4), whether confirmed."""

    src: np.ndarray
    batch: MultiBatch
    boxes: np.ndarray
    confirmed: np.ndarray


@dataclass(frozen=True)
class _Candidates:
    """Every track a successor of the level can hold, one row each: the level's tracks
    coasting (rows 0..L−1), track i updated with box j (L + i·N + j), the track box j
    starts (L + L·N + j)."""

    X: np.ndarray
    cov: np.ndarray
    counts: np.ndarray
    boxes: np.ndarray


def expand(
    tracker: object,
    level: MultiBatch,
    boxes: np.ndarray,
    keeps: list[np.ndarray],
    table: CovarianceTable,
) -> LevelSuccessors:
    """The successors of every state of ``level`` (in order) under each of ``keeps`` (the
    indices of ``boxes`` (N, 4) the tracker sees, in order): successor s·len(keeps) + j is
    state s's under ``keeps[j]``. ``tracker`` is a
    :class:`~lesmc.tracking.multi.MultiTargetTracker`."""
    from lesmc.tracking.multi import MultiTargetTracker

    assert isinstance(tracker, MultiTargetTracker)
    n, N = len(level), len(boxes)
    owner, slot = np.nonzero(np.arange(level.X.shape[1]) < level.count[:, None])
    pred, valid = _predict(tracker, level, owner, slot, table)
    owner, pred = owner[valid], pred.take(valid)
    L = len(owner)
    cand = _candidates(tracker, pred, boxes, table)
    score = tracker.hypothesiser.scores(boxes, cand.boxes[:L])  # (N, L)
    first = np.searchsorted(owner, np.arange(n + 1))
    km = np.zeros((len(keeps), N), dtype=bool)
    for j, keep in enumerate(keeps):
        km[j, keep] = True
    thr = tracker.hypothesiser.threshold
    quick, partner = tracker.associator.by_shortcut(score > thr, first, km)
    at, ids, born = _by_shortcut(level, pred.id, first, km, quick, partner, L, N)
    for s, j in zip(*np.nonzero(~quick), strict=True):  # the others: one assignment each
        mine, keep, q = np.arange(first[s], first[s + 1]), keeps[j], s * len(keeps) + j
        a = tracker.associator.assign(score[keep][:, mine], thr)
        at[q, a.pairs[:, 1]] = L + mine[a.pairs[:, 1]] * N + keep[a.pairs[:, 0]]
        fresh = keep[a.new]
        at[q, len(mine) : len(mine) + len(fresh)] = L + L * N + fresh
        ids[q, len(mine) : len(mine) + len(fresh)] = level.next_id[s] + np.arange(len(fresh))
        born[q] = len(fresh)
    src = np.repeat(np.arange(n), len(keeps))
    return _assemble(tracker, level, src, at, ids, born, cand)


def _by_shortcut(
    level: MultiBatch,
    track_ids: np.ndarray,
    first: np.ndarray,
    km: np.ndarray,
    quick: np.ndarray,
    partner: np.ndarray,
    L: int,
    N: int,
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Every successor's candidate rows (S, W) (−1: none), track ids and tracks started,
    filled for those whose assignment the shortcut decides (``quick`` (n, J), ``partner``
    (n, N): :meth:`~lesmc.tracking.parts.associator.GlobalAssociator.by_shortcut`); the
    others hold their state's tracks coasting, for the caller to complete. State s's
    tracks are rows ``first[s]`` .. ``first[s + 1]`` − 1 of the candidates; rows ``km``
    (J, N) kept by each option."""
    n, J = len(level), len(km)
    width = np.diff(first)
    S, W = n * J, int(width.max(initial=0)) + N
    src = np.repeat(np.arange(n), J)
    col = np.arange(W)
    coast = col < width[src][:, None]
    at = np.where(coast, first[src][:, None] + col, -1)
    ids = np.full((S, W), -1, dtype=np.int64)
    ids[coast] = track_ids[at[coast]]
    born = np.zeros(S, dtype=np.int64)
    qs, qj = np.nonzero(quick)
    q = qs * J + qj
    kept, pr = km[qj], partner[qs]
    i, r = np.nonzero(kept & (pr >= 0))  # matched: the row's one track above the threshold
    p = pr[i, r]
    at[q[i], p - first[qs[i]]] = L + p * N + r
    i, r = np.nonzero(kept & (pr < 0))  # the rest start tracks, in row order
    rank = np.arange(len(i)) - np.searchsorted(i, i)
    slot = width[qs[i]] + rank
    at[q[i], slot] = L + L * N + r
    ids[q[i], slot] = level.next_id[qs[i]] + rank
    born[q] = np.bincount(i, minlength=len(q))
    return at, ids, born


def _predict(
    tracker: object, level: MultiBatch, owner: np.ndarray, slot: np.ndarray, table: CovarianceTable
) -> tuple[Tracks, np.ndarray]:
    """Every track of the level predicted (the filter's predict, each distinct covariance
    once), and which predicted boxes the deleter keeps."""
    from lesmc.tracking.multi import MultiTargetTracker

    assert isinstance(tracker, MultiTargetTracker)
    f = tracker.filter
    cov = level.cov[owner, slot]
    uniq, back = np.unique(cov, return_inverse=True)
    P = table.stack()[uniq] if len(uniq) else np.zeros((0, f.m.dim, f.m.dim))
    c = level.counts[owner, slot]
    t = Tracks(level.X[owner, slot], P, level.id[owner, slot], *(c.T.copy()))
    p = f.predict(t)  # t.P holds each distinct covariance once: predicted once each
    t = Tracks(p.X, p.P[back.reshape(-1)], p.id, p.hits, p.streak, p.age, p.since)
    return t, tracker.deleter.valid(f.boxes(t))


def _candidates(
    tracker: object, t: Tracks, boxes: np.ndarray, table: CovarianceTable
) -> _Candidates:
    """The level's candidate tracks (:class:`_Candidates`) for the frame's ``boxes``."""
    from lesmc.tracking.multi import MultiTargetTracker

    assert isinstance(tracker, MultiTargetTracker)
    f = tracker.filter
    L, N, d = len(t), len(boxes), f.m.dim
    start = f.start(boxes, 0)
    if L and N:
        P_pred, back = _distinct(t.P)
        inn = innovations(f.m, P_pred)
        K = inn.K[back][:, None]
        X_up = update_means(f.m, t.X[:, None, :], K, to_z(boxes)[None, :, :]).reshape(-1, d)
        cov_pred = table.add_many(P_pred)[back]
        cov_up = np.repeat(table.add_many(inn.P_post)[back], N)
    else:
        X_up = np.zeros((0, d))
        cov_pred = table.add_many(t.P)
        cov_up = np.zeros(0, dtype=np.int64)
    cov_new = np.full(N, table.add_many(f.m.P0[None])[0] if N else 0, dtype=np.int64)
    pc = np.stack([getattr(t, c) for c in COUNTS], axis=1).reshape(L, len(COUNTS))
    up = np.repeat(pc, N, axis=0)
    up[:, 0] += 1  # hits
    up[:, 1] += 1  # streak
    up[:, 3] = 0  # since
    sc = np.stack([getattr(start, c) for c in COUNTS], axis=1).reshape(N, len(COUNTS))
    X = np.concatenate([t.X, X_up, start.X])
    return _Candidates(
        X,
        np.concatenate([cov_pred, cov_up, cov_new]),
        np.concatenate([pc, up, sc]),
        to_boxes(X),
    )


def _distinct(P: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The distinct matrices of ``P`` (k, d, d) by exact value, and each one's index."""
    if not len(P):
        return P, np.zeros(0, dtype=np.int64)
    back, first = distinct_rows(np.ascontiguousarray(P).reshape(len(P), -1))
    return P[first], back


def _assemble(
    tracker: object,
    level: MultiBatch,
    src: np.ndarray,
    at: np.ndarray,
    tid: np.ndarray,
    born: np.ndarray,
    cand: _Candidates,
) -> LevelSuccessors:
    """The successors whose tracks are candidate rows ``at`` (S, W) (−1: none) with ids
    ``tid``, having started ``born`` tracks each: the initiator's output rule and the
    deleter applied to all at once, the tracks left alive moved up."""
    from lesmc.tracking.multi import MultiTargetTracker

    assert isinstance(tracker, MultiTargetTracker)
    S, W = at.shape
    used = at >= 0
    at = np.where(used, at, 0)
    c = cand.counts[at]
    flat = Tracks(cand.X[at], np.zeros((S, W, 0, 0)), tid, *(np.moveaxis(c, 2, 0)))
    frames = level.frames[src] + 1
    confirmed = tracker.initiator.confirmed(flat, int(frames[0])) if S else used
    alive = used & tracker.deleter.alive(flat)
    count = alive.sum(axis=1)
    order = np.argsort(~alive, axis=1, kind="stable")  # the alive tracks moved up, in order
    T = int(count.max(initial=0))
    at = np.take_along_axis(at, order, axis=1)[:, :T]
    tid = np.take_along_axis(tid, order, axis=1)[:, :T]
    confirmed = np.take_along_axis(confirmed, order, axis=1)[:, :T]
    live = np.arange(T) < count[:, None]
    pad = ~live
    at[pad], tid[pad] = len(cand.X), -1
    X = np.concatenate([cand.X, np.zeros((1, cand.X.shape[1]))])[at]
    cov = np.concatenate([cand.cov, [0]])[at]
    counts = np.concatenate([cand.counts, np.zeros((1, len(COUNTS)), np.int64)])[at]
    bx = np.concatenate([cand.boxes, np.full((1, 4), np.nan)])[at]
    batch = MultiBatch(
        X,
        np.where(live, cov, 0),
        tid,
        counts,
        count,
        level.next_id[src] + born,
        frames,
        np.full(S, -1, dtype=np.int64),
    )
    return LevelSuccessors(src, batch, bx, confirmed & live)
