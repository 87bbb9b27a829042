"""The data associator: which detection updates which track. Nearest neighbour (the
paper's single, :class:`NearestNeighbourAssociator`); ordered greedy by likelihood (the
paper's joint KFs, :class:`GreedyAssociator`); global assignment of detections to tracks
(GNN / Hungarian, ``scipy.optimize.linear_sum_assignment``), SORT's way
(:class:`GlobalAssociator`).

SORT (``associate_detections_to_trackers``): when every detection and every track has at
most one pair scoring above the threshold, those pairs are the assignment; otherwise the
assignment maximising the total score over all pairs (scipy's solution among equal
totals). Pairs of that assignment scoring below the threshold are dropped. The shortcut is
part of the rule: it is not always the thresholded optimum (a pair above the threshold
wins even where two pairs below it would sum to more, then both be dropped).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from lesmc.tracking.parts.groups import starts, within


@dataclass(frozen=True)
class Assignment:
    """The matched (detection, track) pairs (k, 2), by detection; the detections left
    unmatched, in the order SORT starts tracks on them (those the assignment left out by
    index, then those of dropped pairs); the tracks left unmatched."""

    pairs: np.ndarray
    new: np.ndarray
    missed: np.ndarray


@dataclass(frozen=True)
class GlobalAssociator:
    """Global assignment on a score matrix (larger is better) with SORT's threshold rule."""

    def assign(self, score: np.ndarray, threshold: float) -> Assignment:
        """The assignment of detections (rows) to tracks (columns) of ``score``."""
        n, m = score.shape
        pairs = np.zeros((0, 2), dtype=np.int64)
        if n and m:
            above = score > threshold
            if above.sum(axis=1).max() == 1 and above.sum(axis=0).max() == 1:
                pairs = np.argwhere(above)
            else:
                from scipy.optimize import linear_sum_assignment

                rows, cols = linear_sum_assignment(-score)
                pairs = np.stack([rows, cols], axis=1).astype(np.int64)
        low = score[pairs[:, 0], pairs[:, 1]] < threshold
        kept, dropped = pairs[~low], pairs[low]
        rows, cols = np.ones(n, dtype=bool), np.ones(m, dtype=bool)
        rows[pairs[:, 0]] = False  # the rows and columns the assignment left out, in order
        cols[pairs[:, 1]] = False
        new = np.concatenate([np.flatnonzero(rows), dropped[:, 0]])
        missed = np.concatenate([np.flatnonzero(cols), dropped[:, 1]])
        return Assignment(kept, new.astype(np.int64), missed.astype(np.int64))

    @staticmethod
    def by_shortcut(
        above: np.ndarray, groups: np.ndarray, keeps: np.ndarray
    ) -> tuple[np.ndarray, np.ndarray]:
        """Where :meth:`assign`'s shortcut decides, for many (track set, rows kept) pairs at
        once. ``above`` (N, L): which scores pass the threshold, the columns in groups
        (``groups``: each group's first column, then L), rows kept ``keeps`` (J, N) bool.
        Returns (G, J) whether :meth:`assign` on rows ``keeps[j]`` and group g's columns is
        decided by the shortcut or has no pair to make (no row or no column: no pair; else
        every kept row and every column has at most one score above the threshold, and one
        has one), and each (group, row)'s one column above the threshold (−1: none or
        several). There the assignment is those pairs, and the rows without one start
        tracks in order."""
        a = above.astype(np.int64)
        G = len(groups) - 1
        width = np.diff(groups)
        some = np.flatnonzero(width > 0)  # reduceat's segments run from one start to the next
        row_sum = np.zeros((G, a.shape[0]), dtype=np.int64)
        col_max = np.zeros((G, len(keeps)), dtype=np.int64)
        if some.size:
            row_sum[some] = np.add.reduceat(a, groups[some], axis=1).T
            cols = keeps.astype(np.int64) @ a  # (J, L): kept rows above, per column
            col_max[some] = np.maximum.reduceat(cols, groups[some], axis=1).T
        kept_max = np.where(keeps[None], row_sum[:, None, :], 0).max(axis=2, initial=0)
        empty = (width[:, None] == 0) | ~np.asarray(keeps.any(axis=1))[None, :]
        ok = empty | ((kept_max == 1) & (col_max == 1))
        owner = np.repeat(np.arange(G), width)
        partner = np.full((G, a.shape[0]), -1, dtype=np.int64)
        r, c = np.nonzero(above)
        one = row_sum[owner[c], r] == 1
        partner[owner[c[one]], r[one]] = c[one]
        return ok, partner


@dataclass(frozen=True)
class NearestNeighbourAssociator:
    """Nearest neighbour (the paper's single, Eq. 11): the track takes the nearest visible
    detection if it passes the gate, else skips the update."""

    @staticmethod
    def assign(valid: np.ndarray, gated: np.ndarray) -> np.ndarray:
        """Per row of candidates (nearest first; ``valid`` real ones, ``gated`` those the
        gate admits): the column taken, 0 (the nearest) or −1 (skip the update)."""
        if not valid.shape[1]:
            return -np.ones(valid.shape[0], dtype=np.int64)
        out: np.ndarray = np.where(valid[:, 0] & gated[:, 0], 0, -1)
        return out


#: The association rounds' "no pair yet" value.
_UNSET = np.iinfo(np.int64).max


class GreedyAssociator:
    """Ordered greedy association by likelihood (the paper's joint KFs, section 7.2): every
    gated (track, detection) pair scored by N(z; Hx̂, S), taken from the likeliest (ties:
    lower track, then lower detection) while its track and detection are both unspent.
    Keeps scratch arrays between calls (:meth:`_unset`)."""

    def __init__(self) -> None:
        self._firsts: list[np.ndarray] = [np.empty(0, np.int64)] * 2  # see _unset

    @staticmethod
    def ranked_pairs(
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
        idx = np.repeat(starts(gcount)[tu[ls, lt]], c) + within(c)
        ps, pt, pz = np.repeat(ls, c), np.repeat(lt, c), pz[idx]
        prio = (score[idx] * T + pt) * max(nz, 1) + pz
        return ps, pt, pz, prio, idx

    def assign(
        self,
        ps: np.ndarray,
        pt: np.ndarray,
        pz: np.ndarray,
        prio: np.ndarray,
        pu: np.ndarray,
        pair_rank: np.ndarray | None,
        lo: np.ndarray,
        hi: np.ndarray,
        start: np.ndarray,
        R: int,
        T: int,
        nz: int,
    ) -> tuple[np.ndarray, np.ndarray]:
        """The greedy one-to-one association of every option row: (R, T) detection per track,
        −1 for none, and (R, T) the distinct pair taken (``pu``; −1).

        Pairs are scored once per state; a row sees those whose detection its
        option leaves visible. Scanning a row's pairs in (−likelihood, track,
        detection) order (``prio``) takes a pair when its track and detection
        are both unspent. In rounds: every pair that comes first among the
        remaining pairs of its track and among those of its detection is taken
        (nothing before it can spend either), then the pairs of spent tracks and
        detections go.

        The pairs (state ``ps``, track slot ``pt``, detection ``pz``, priority ``prio``,
        distinct pair ``pu``) are :meth:`ranked_pairs`'s; ``pair_rank`` is each pair's
        detection's place among its state's primary's nearest (option j hides the j
        nearest: lesmc/tracking/parts/attacker.py ``visible``), None when every state asks
        for its option 0 alone; rows of state i are its options lo[i] .. hi[i] − 1 from row
        ``start[i]`` on, R rows of T track slots, nz detections.
        """
        if pair_rank is None:  # option 0 of every state: one row each, all pairs
            pair = np.arange(ps.size)
            kt = ps * T + pt  # flat (row, track) and (row, detection) positions
            kz = ps * nz + pz
        else:  # a pair serves the options up to its detection's place among the primary's nearest
            reps = np.maximum(np.minimum(hi[ps], pair_rank + 1) - lo[ps], 0)
            pair = np.repeat(np.arange(ps.size), reps)
            row = start[ps[pair]] + within(reps)
            pz = pz[pair]
            prio = prio[pair]
            kt = row * T + pt[pair]
            kz = row * nz + pz
        assign, taken = self._rounds(prio, kt, kz, pz, pair, R * T, R * nz)
        got = taken >= 0
        taken[got] = pu[taken[got]]
        return assign.reshape(R, T), taken.reshape(R, T)

    def _rounds(
        self,
        prio: np.ndarray,
        kt: np.ndarray,
        kz: np.ndarray,
        pz: np.ndarray,
        pair: np.ndarray,
        n_t: int,
        n_z: int,
    ) -> tuple[np.ndarray, np.ndarray]:
        """The greedy scan of :meth:`assign` in rounds, over pairs at flat (row, track)
        positions ``kt`` (of ``n_t``) and (row, detection) positions ``kz`` (of ``n_z``):
        the detection (``pz``) and pair (``pair``) taken at each (row, track), −1 for none."""
        assign = np.full(n_t, -1, dtype=np.int64)
        taken = np.full(n_t, -1, dtype=np.int64)
        used_t = np.zeros(n_t, dtype=bool)
        used_z = np.zeros(n_z, dtype=bool)
        buf_t, buf_z = self._unset(0, n_t), self._unset(1, n_z)
        self._firsts = [np.empty(0, np.int64)] * 2  # taken: a failure below leaves them dirty
        first_t, first_z = buf_t[:n_t], buf_z[:n_z]
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
        return assign, taken

    def _unset(self, which: int, size: int) -> np.ndarray:
        """A scratch array of at least ``size`` entries, all :data:`_UNSET` (kept between
        calls: the association rounds put back every entry they touch, and filling afresh
        cost more than the rounds on big chunks)."""
        buf = self._firsts[which]
        if buf.size < size:
            buf = np.full(max(size, 2 * buf.size), _UNSET)
        return buf
