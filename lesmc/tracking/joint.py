"""Design "joint": joint Kalman filters around the target (paper section 7.2).

A joint state holds the primary track, the refining tracks of nearby vehicles and the
unassociated detections of the previous frame (candidates to start tracks). The design is a
composition of parts (:class:`JointParts`, docs/trackers.md "Parts"); one step:

1. carry every position into the new frame (homography), predict every track (kalman.py);
2. score every gated (track, detection) pair by the likelihood N(z; Hx̂, S), sort from the
   largest (ties: lower track, then lower detection), and associate greedily one-to-one
   (the hypothesiser ``GateHypothesiser``, the data associator ``GreedyAssociator``);
3. update the associated tracks (the others skip the update);
4. an unassociated detection within ``init_radius`` of the primary starts a refining track
   if a previous unassociated detection lies within ``init_distance`` (their difference
   over dt is its velocity; detections in index order, each with the nearest remaining
   previous one); otherwise it is kept for the next step (``NearTargetInitiator``);
5. refining tracks farther than ``prune_radius`` from the primary, or whose trace(P)
   exceeds ``max_trace``, are dropped (the deleters ``DistanceDeleter``, ``TraceDeleter``).

Attacks (docs/scene-format.md#joint-design): as for the single design, option j hides the
j detections nearest the primary's prediction (up to the last its gate accepts) at their
payoffs (lesmc/tracking/parts/attacker.py), gone for every track. Outcomes that leave the
whole joint state identical merge (the cheapest kept). Under ``allow hide, inject`` each
hiding option is combined with every subset of the injection candidates that can change
the state's successor (docs/semantics.md, "Injection on the joint design" and "Pruning
injection candidates"; :meth:`_expand_injected`).

Speed: batches of joint states as padded arrays (lesmc/tracking/parts/joint_states.py), in
chunks; :attr:`JointDesign.stop` is called between chunks (a deadline: docs/engines.md).
tests/joint_oracle.py is an independent oracle from the paper (filterpy, one path at a time).
"""

from __future__ import annotations

from collections.abc import Callable

import numpy as np

from lesmc.scene import Scene
from lesmc.tracking.design import Batch, CovarianceTable, Schedule, Successors
from lesmc.tracking.kalman import Matrices, initial_mean, matrices, positions
from lesmc.tracking.parts.associator import GreedyAssociator
from lesmc.tracking.parts.attacker import ranks_and_payoffs, visible
from lesmc.tracking.parts.attacker_subsets import (
    pruned_subsets,
    shown_and_cost,
    within_inject_budget,
)
from lesmc.tracking.parts.deleter import DistanceDeleter, TraceDeleter
from lesmc.tracking.parts.groups import starts, within
from lesmc.tracking.parts.hypothesiser import GateHypothesiser
from lesmc.tracking.parts.initiator import NearTargetInitiator, still_pending
from lesmc.tracking.parts.joint_states import JointStates, TrackTable, concat, digest, same_as
from lesmc.tracking.parts.joint_step import (
    Expanded,
    JointParts,
    Prepared,
    candidate_relevance,
    first_of_equals,
    option_one_differs,
    prepare,
    primary_nis,
    track_table,
    with_subsets,
)

#: (states × (tracks + detections)) cells of one chunk: bounds the temporaries of an expansion.
CHUNK_CELLS = 1 << 20


class JointDesign:
    """Primary plus refining tracks with likelihood-sorted one-to-one association."""

    name = "joint"
    #: it takes attack action ``inject`` (lesmc/tracking/trackers.py: make_tracker)
    injects = True

    def __init__(self, scene: Scene, inject: bool = False, hide: bool = True) -> None:
        self.scene = scene
        self.inject = inject
        self.hide = hide
        self.cfg = scene.tracker
        self.m: Matrices = matrices(self.cfg, scene.dt)
        self.covariances = CovarianceTable()  # the primaries' (the model's table)
        self.track_covariances = CovarianceTable()  # every track's
        self.parts = JointParts(  # the predictor and updater: kalman.py, in the Schedule
            GateHypothesiser(self.cfg.gate, self.cfg.gate_type),
            GreedyAssociator(),
            NearTargetInitiator(self.cfg.joint.init_radius, self.cfg.joint.init_distance),
            TraceDeleter(self.cfg.max_trace),
            DistanceDeleter(self.cfg.joint.prune_radius),
        )
        self.schedule = Schedule(
            self.m, self.cfg, self.track_covariances, self.parts.hypothesiser, self.parts.deleter
        )
        self._model_cov = np.full(0, -1, dtype=np.int64)  # track table -> model table
        self._p0 = self.track_covariances.add(self.m.P0.copy())
        self._p0_kept = not bool(self.parts.deleter.halts(self.m.P0[None])[0])
        self.stop: Callable[[], None] = lambda: None

    def initial(self) -> Batch:
        t = self.scene.target
        x0 = initial_mean(self.m, t.start, t.velocity)
        near = self.parts.initiator.near(self.scene.frame(t.step).positions(), t.start)
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
            self.stop()
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
            sum(e.track_rows for e in parts),
        )

    def _expand(self, js: JointStates, step: int, attacked: bool) -> Expanded:
        """The outcomes of the states ``js`` at frame ``step`` (see the module docstring)."""
        frame = self.scene.frame(step)
        if attacked and self.inject and (frame.candidates or not self.hide):
            return self._expand_injected(js, step)
        p = prepare(self.scene, self.schedule, self.parts, self.m.pos, js, step)
        n = len(js)
        if attacked:
            s, opt, assign, halt, states = self._rows(p, np.zeros(n, dtype=np.int64), p.n_opt)
            rows = np.nonzero(first_of_equals(states, s))[0]
            rank, payoff = ranks_and_payoffs(s[rows], p.cost[s[rows], opt[rows]])
            return Expanded(
                s[rows].astype(np.int64),
                rank,
                payoff,
                assign[rows, 0].astype(np.int64),
                halt[rows, 0],
                states.take(rows),
                primary_nis(p, s[rows], assign[rows, 0]),
                opt[rows].astype(np.int64),
                np.zeros(rows.size, dtype=np.int64),
                track_rows=js.tracks_moved(s),
            )
        return self._expand_unattacked(js, p)

    def _expand_unattacked(self, js: JointStates, p: Prepared) -> Expanded:
        """The outcome of each state of ``js`` at an unattacked frame (``p``: prepared):
        option 0, and its own payoff, the cost of the first option that differs."""
        n = len(js)
        s, _, assign, halt, states = self._rows(
            p, np.zeros(n, dtype=np.int64), np.minimum(p.n_opt, 1)
        )
        states.key = key0 = digest(states)
        payoff = np.zeros(n)
        sure = option_one_differs(p, assign[:, 0])
        if sure.any():
            payoff[sure] = p.cost[sure, 1]
        todo = np.flatnonzero(~sure)
        j, moved = 1, js.tracks_moved(s)
        while True:
            todo = todo[p.n_opt[todo] > j]
            if not todo.size:
                break
            lo = np.zeros(n, dtype=np.int64)
            lo[todo] = j
            hi = lo.copy()
            hi[todo] = j + 1
            sj, _, _, _, nxt = self._rows(p, lo, hi)
            moved += js.tracks_moved(sj)
            differs = (digest(nxt) != key0[sj]).any(axis=1)
            same = nxt.take(np.nonzero(~differs)[0])
            if not same_as(same, states, sj[~differs]):
                raise AssertionError("joint state digest collision")
            payoff[sj[differs]] = p.cost[sj[differs], j]
            todo = sj[~differs]
            j += 1
        return Expanded(
            s.astype(np.int64),
            np.zeros(n, dtype=np.int64),
            payoff,
            assign[:, 0].astype(np.int64),
            halt[:, 0],
            states,
            primary_nis(p, s, assign[:, 0]),
            track_rows=moved,
        )

    def _expand_injected(self, js: JointStates, step: int) -> Expanded:
        """The outcomes of ``js`` at an attacked frame under ``allow hide, inject``: each
        hiding option × each subset of the candidates that can change the state's successor
        (candidate j: measurement n + j; the others only add their payoff: attacker_subsets.py
        ``relevant_candidates``), equal joint states merged at the cheapest, ranked by cost
        (docs/semantics.md)."""
        frame = self.scene.frame(step)
        p = prepare(self.scene, self.schedule, self.parts, self.m.pos, js, step, True, self.hide)
        nd, nz, cpay = len(frame.detections), len(p.Z), frame.injectable.payoffs()
        relevant = candidate_relevance(p, self.parts.initiator, nd)
        within_inject_budget(relevant, step, p.n_opt)
        vstate, local, sub_id, subsets = pruned_subsets(relevant)
        rows: list[tuple[np.ndarray, ...]] = []
        parts: list[JointStates] = []
        size = max(1, CHUNK_CELLS // ((js.width + nz) * int(p.n_opt.max(initial=1))))
        for lo in range(0, len(vstate), size):
            self.stop()
            v = np.arange(lo, min(lo + size, len(vstate)))
            shown, vcost = shown_and_cost(sub_id[v], subsets, nd, nz, cpay)
            q = with_subsets(p, vstate[v], shown)
            s, opt, assign, halt, states = self._rows(q, np.zeros(v.size, np.int64), q.n_opt, shown)
            cost = q.cost[s, opt] + vcost[s]
            rows.append(
                (vstate[v][s], opt, local[v][s], sub_id[v][s], cost, assign[:, 0], halt[:, 0])
            )
            parts.append(states)
        s, opt, sub_k, sid, cost, det, halted = (np.concatenate(a) for a in zip(*rows, strict=True))
        unattacked = (opt == 0) & (sub_k == 0)
        order = np.lexsort((opt, sub_k, ~unattacked, cost, s))
        states = concat(parts).take(order)
        s, cost, det, halted = s[order], cost[order], det[order], halted[order]
        kept = np.nonzero(first_of_equals(states, s))[0]  # the first of equals: the cheapest
        rank, payoff = ranks_and_payoffs(s[kept], cost[kept])
        return Expanded(
            s[kept].astype(np.int64),
            rank,
            payoff,
            det[kept].astype(np.int64),
            halted[kept],
            states.take(kept),
            primary_nis(p, s[kept], det[kept]),
            opt[order][kept].astype(np.int64),
            sid[order][kept].astype(np.int64),
            subsets,
            js.tracks_moved(s),  # every (state, hiding option, subset) row's tracks
        )

    def forcing(
        self, batch: Batch, step: int
    ) -> tuple[Successors, list[tuple[list[str], list[str]]]]:
        """The outcomes of ``batch`` at attacked frame ``step`` (as :meth:`successors`, in
        one chunk: a small batch) and, per outcome, the cheapest way to force it that the
        model kept: the ids of the frame's detections it hides (the primary's nearest) and
        of the candidates it injects (docs/semantics.md, "Injection on the joint design";
        the replay applies them, lesmc/replay/inject.py)."""
        js = batch.objects
        assert isinstance(js, JointStates)
        e = self._expand(js, step, True)
        assert e.opt is not None and e.subset is not None
        frame = self.scene.frame(step)
        inj = self.inject and bool(frame.candidates or not self.hide)
        p = prepare(self.scene, self.schedule, self.parts, self.m.pos, js, step, inj, self.hide)
        nd = len(frame.detections)
        shown = visible(p.visible_rank(e.src), e.opt)[:, :nd]
        subsets = e.subsets or [()]
        how = [
            (
                [frame.detections[int(j)].id for j in np.flatnonzero(~row)],
                [frame.candidates[c].id for c in subsets[int(k)]],
            )
            for row, k in zip(shown, e.subset, strict=True)
        ]
        succ = self._batch(e.states, e.halted)
        return Successors(e.src, e.rank, e.payoff, e.det, succ, e.nis), how

    def attack_in(self, batch: Batch, step: int, rank: int) -> tuple[list[str], list[str]]:
        """Under inject: the ids of the detections hidden and candidates injected by the
        cheapest way to force outcome ``rank`` from ``batch``'s one joint state at frame
        ``step`` (:meth:`forcing`'s; lesmc/unfold/attack_path.py walks a path's states)."""
        assert isinstance(batch.objects, JointStates) and len(batch.objects) == 1
        succ, how = self.forcing(batch, step)
        return how[int(np.flatnonzero(succ.rank == rank)[0])]

    def _rows(
        self, p: Prepared, lo: np.ndarray, hi: np.ndarray, shown: np.ndarray | None = None
    ) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, JointStates]:
        """The next states of options lo[i] .. hi[i] − 1 of every state i, as rows (by state,
        then option): source, option, association (rows, tracks), halted flags (rows, tracks).
        ``shown`` (n, z): the measurements of ``p.Z`` each state's rows may see at all (the
        injected candidates among them; its pairs already filtered: ``with_subsets``; None:
        every one)."""
        Z = p.Z
        nz = len(Z)
        count = hi - lo
        R = int(count.sum())
        s = np.repeat(np.arange(len(count)), count)
        start = starts(count)
        opt = np.repeat(lo, count) + within(count)
        visible_ = visible(p.visible_rank(s), opt)  # option j hides the j nearest to the primary
        ps, pt, pz, prio, pu = p.ps, p.pt, p.pz, p.prio, p.pu
        if shown is not None:
            visible_ &= shown[s]
        first = len(lo) == R and not lo.any()  # option 0 of every state
        pair_rank = None if first else p.rank_of[p.tu[ps, 0], pz]
        assign, pair = self.parts.associator.assign(
            ps, pt, pz, prio, pu, pair_rank, lo, hi, start, R, p.tu.shape[1], nz
        )
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

    def _initiate_and_prune(
        self,
        p: Prepared,
        child: np.ndarray,
        halt: np.ndarray,
        live: np.ndarray,
        free: np.ndarray,
        pend: np.ndarray,
        npend: np.ndarray,
    ) -> JointStates:
        """Rows' next states: new tracks from free detections near the primary, pruning.

        ``child`` (rows, T) gives each track's next value as a row of the ``p.child_*``
        tables. Free detections within ``init_radius`` of the updated primary are taken in
        index order, one round each: each is matched to the nearest remaining pending
        detection (first of equals) closer than ``init_distance``, which starts a track, or
        is kept pending for the next step."""
        Z = p.Z
        R, T = child.shape
        prim = positions(self.m, p.child_X[child[:, 0]])
        cr, cz, partner = self.parts.initiator.candidates(Z, prim, free, pend, npend)
        matched = partner >= 0
        # new tracks after the old ones, in the order they started
        mr = cr[matched]
        mz = Z[cz[matched]]
        v = (mz - pend[mr, partner[matched]]) / self.scene.dt
        nnew = np.bincount(mr, minlength=R)
        W = T + int(nnew.max(initial=0))
        # the next states' tracks as rows of one table: the children, zeros (padding), the new
        M = len(p.child_X)
        table_X, table_cov, table_h = track_table(p, self.m, self._p0, mz, v)
        at = np.full((R, W), M, dtype=np.int64)
        at[:, :T] = child
        keep = np.zeros((R, W), dtype=bool)
        keep[:, :T] = live & ~halt
        slot = live.sum(axis=1)[mr] + within(nnew)
        at[mr, slot] = M + 1 + np.arange(mr.size)
        keep[mr, slot] = self._p0_kept
        at, nt = self.parts.pruner.prune(at, keep, positions(self.m, table_X)[at], prim, M)
        th = table_h[at]  # the means and covariance indices are read from the table when asked
        pending, npd = still_pending(Z, cr[~matched], cz[~matched], R)
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
