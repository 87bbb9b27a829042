"""Unfold a multi-target design (lesmc/tracking/multi.py) into its model
(lesmc/model/multi.py): the scene -> model stage for trackers that follow every object.

Step 0 is the scene's first frame, unattacked. At a step of the attack window the attacker
hides any subset of the frame's attackable detections (payoff finite), at the sum of
their payoffs; outside it only the unattacked outcome follows. The successors of one
level that are the same state (:meth:`~lesmc.tracking.parts.states.MultiBatch.words`:
every track bit for bit, the counters, and the target's last track id) are one state,
and the subsets that lead from one state to the same successor one transition, kept at
its cheapest (docs/trackers.md, "The multi-target model").
"""

from __future__ import annotations

import itertools
import math
from collections.abc import Iterator
from dataclasses import dataclass

import numpy as np

from lesmc.common.errors import BudgetError, UsageError
from lesmc.model.identity import NONE, last_seen
from lesmc.model.multi import MultiModel
from lesmc.scene import Frame, Scene
from lesmc.tracking.design import CovarianceTable
from lesmc.tracking.multi import (
    FrameTracks,
    MultiState,
    SortDesign,
    reference_boxes,
    reference_kind,
    target_id,
    target_of,
)
from lesmc.tracking.parts.states import MultiBatch


def attackable(frame: Frame, ref: np.ndarray | None, radius: float | None) -> np.ndarray:
    """Which of the frame's detections the attacker may hide: those of finite payoff and,
    with ``attack window L..U within R`` (``radius`` R), whose position lies within R px of
    the centre of the target's reference box ``ref`` (none where the reference does not
    exist)."""
    can = np.array([not math.isinf(d.payoff) for d in frame.detections], dtype=bool)
    if radius is None or not len(can):
        return can
    if ref is None:
        return np.zeros(len(can), dtype=bool)
    c = np.array([(ref[0] + ref[2]) / 2.0, (ref[1] + ref[3]) / 2.0])
    near: np.ndarray = can & (np.hypot(*(frame.positions() - c).T) <= radius)
    return near


def hidden_subsets(
    frame: Frame, attacked: bool, can: np.ndarray | None = None
) -> Iterator[tuple[int, ...]]:
    """The subsets of the frame's detections the attacker may hide (indices), the empty
    one (unattacked) first: every subset of the attackable ones (``can``, default
    :func:`attackable` without a radius) when ``attacked``."""
    if not attacked:
        yield ()
        return
    mask = attackable(frame, None, None) if can is None else can
    idx = np.nonzero(mask)[0].tolist()
    for r in range(len(idx) + 1):
        yield from itertools.combinations(idx, r)


def subset_count(frame: Frame, attacked: bool, can: np.ndarray | None = None) -> int:
    """How many subsets :func:`hidden_subsets` yields, counted without listing them."""
    mask = attackable(frame, None, None) if can is None else can
    return 2 ** int(mask.sum()) if attacked else 1


#: Successors one step may compute when no --max-states is given: a frame with 30
#: attackable detections has 2^30 subsets, which no search can list.
MAX_STEP_SUCCESSORS = 10_000_000


def build_multi(
    scene: Scene,
    design: SortDesign,
    window: tuple[int, int],
    end: int,
    max_states: int | None = None,
    radius: float | None = None,
) -> MultiModel:
    """The model of ``scene`` under ``design`` for attacks at steps ``window`` (l..u),
    up to step ``end``, on the detections :func:`attackable` (``radius``: ``within R``).
    ``max_states`` bounds the successors computed (before merging): a BudgetError (exit
    status 3) before a step that would pass it. Each state records the box of the track
    with the target's id (:func:`~lesmc.tracking.multi.target_id`) and whether that track
    was deleted, which the ``dist`` measures read."""
    frames = scene.frames
    if not 1 <= window[0] <= window[1] <= end <= len(frames) - 1:
        raise UsageError(
            f"window {window[0]}..{window[1]} must satisfy 1 <= l <= u <= end = {end} "
            f"<= {len(frames) - 1} (the scene's last step)"
        )
    run = design.run(end)
    refs = reference_boxes(scene, [s.tracks for s in run])
    _need_reference(scene, refs)
    tracker, table = design.tracker, CovarianceTable()
    me = target_id([s.target_id for s in run])
    s0, ft0 = tracker.step(tracker.initial(), frames[0].boxes())
    tid0 = NONE if refs[0] is None else target_of(ft0, refs[0])
    level: list[MultiState] = [s0]
    st = _Arrays()
    st.add_state(0, tid0, refs[0] is not None, tid0, _look(ft0, s0, me))
    for k in range(1, end + 1):
        f = frames[k]
        boxes, pay = f.boxes(), np.array([d.payoff for d in f.detections], dtype=float)
        attacked = window[0] <= k <= window[1]
        can = attackable(f, refs[k], radius)
        _budget(k, len(level), subset_count(f, attacked, can), st.n, max_states, f)
        subsets = list(hidden_subsets(f, attacked, can))
        base = st.n - len(level)
        made: list[_Made] = []
        ref = refs[k]
        for i, state in enumerate(level):
            for sub in subsets:
                keep = np.ones(len(boxes), dtype=bool)
                keep[list(sub)] = False
                nxt, ft = tracker.step(state, boxes[keep])
                tid = NONE if ref is None else target_of(ft, ref)
                last = int(last_seen(np.array([st.last[base + i]]), np.array([tid]))[0])
                made.append((base + i, nxt, tid, last, sub, _look(ft, nxt, me)))
        level = st.add_level(k, made, pay, ref is not None, tracker.filter.m.dim, table)
    names = tuple(tuple(d.id for d in f.detections) for f in frames[: end + 1])
    refbox = np.array([np.full(4, np.nan) if r is None else r for r in refs]).reshape(-1, 4)
    return st.model(tuple(f.step for f in frames[: end + 1]), names, end, window, refbox, me)


def _need_reference(scene: Scene, refs: list[np.ndarray | None]) -> None:
    """A UsageError when the target has no reference at any step."""
    if any(r is not None for r in refs):
        return
    why = (
        "no ground-truth box of its frame holds its start"
        if reference_kind(scene) == "truth"
        else "no detection box of its frame holds its start, or its track is never output"
    )
    raise UsageError(
        f"the target ({scene.target.start[0]:g}, {scene.target.start[1]:g} at frame "
        f"{scene.target.step}) has no reference track: {why}; switches and lost need one"
    )


def _budget(k: int, n: int, subsets: int, so_far: int, max_states: int | None, f: Frame) -> None:
    """A BudgetError before step ``k`` when its successors (``n`` states times ``subsets``
    each, counted before any is listed) would pass ``max_states`` or the per-step limit."""
    count = n * subsets
    if max_states is not None and so_far + count > max_states:
        raise BudgetError(
            f"--max-states {max_states}: step {k} would compute {count} "
            f"successors of {n} states ({so_far} so far); shorten the attack window"
        )
    if count > MAX_STEP_SUCCESSORS:
        raise BudgetError(
            f"step {k} would compute {count} successors of {n} states (every "
            f"subset of {len(f.detections)} detections): more than {MAX_STEP_SUCCESSORS:,}; "
            "shorten the attack window"
        )


#: What a state shows the ``dist`` measures: the box of the track with the target's id
#: (nan: no such track now) and whether that track was deleted (born, and gone since).
_Look = tuple[np.ndarray, bool]

#: One successor: source, state, target's track id, last, the subset hidden, its look.
_Made = tuple[int, MultiState, int, int, tuple[int, ...], _Look]


def _look(ft: FrameTracks, state: MultiState, me: int) -> _Look:
    """The track of id ``me`` after a frame whose tracks are ``ft`` (the state after it:
    ``state``): its box, and whether it was deleted."""
    mine = np.nonzero(ft.ids == me)[0]
    if mine.size:
        return ft.boxes[mine[0]].copy(), False
    return np.full(4, np.nan), bool(me != NONE and me < state.next_id)


@dataclass
class _Cheapest:
    """The cheapest subsets found so far that force one transition: by payoff, by count."""

    payoff: float
    by_payoff: tuple[int, ...]
    by_count: tuple[int, ...]


class _Arrays:
    """The model's arrays as they grow, level by level."""

    def __init__(self) -> None:
        self.step: list[int] = []
        self.tid: list[int] = []
        self.ref: list[bool] = []
        self.last: list[int] = []
        self.box: list[np.ndarray] = []
        self.gone: list[bool] = []
        self.trans: list[tuple[int, int, float, int, tuple[int, ...], tuple[int, ...]]] = []

    @property
    def n(self) -> int:
        return len(self.step)

    def add_state(self, k: int, tid: int, ref: bool, last: int, look: _Look) -> None:
        self.step.append(k)
        self.tid.append(tid)
        self.ref.append(ref)
        self.last.append(last)
        self.box.append(look[0])
        self.gone.append(look[1])

    def add_level(
        self,
        k: int,
        made: list[_Made],
        pay: np.ndarray,
        ref: bool,
        d: int,
        table: CovarianceTable,
    ) -> list[MultiState]:
        """Add step ``k``'s successors ``made`` (source, state, target's track id, last,
        hidden), merged; returns the level's distinct states in index order."""
        batch = MultiBatch.pack(
            [(m[1].tracks, m[1].next_id, m[1].frames, m[3]) for m in made], d, table
        )
        words = batch.words(batch.X.shape[1])
        _, first, inverse = np.unique(words, axis=0, return_index=True, return_inverse=True)
        inverse = inverse.reshape(-1)
        order = np.argsort(first, kind="stable")  # distinct states in order of first sight
        rank = np.empty_like(order)
        rank[order] = np.arange(len(order))
        base = self.n
        level = []
        for j in first[order]:
            _, state, tid, last, _, look = made[int(j)]
            self.add_state(k, tid, ref, last, look)
            level.append(state)
        best: dict[tuple[int, int], _Cheapest] = {}
        for j, (src, _, _, _, sub, _) in enumerate(made):
            dst = base + int(rank[inverse[j]])
            cost = math.fsum(pay[list(sub)]) if sub else 0.0
            cur = best.get((src, dst))
            if cur is None:
                best[(src, dst)] = _Cheapest(cost, sub, sub)
                continue
            if cost < cur.payoff:
                cur.payoff, cur.by_payoff = cost, sub
            if len(sub) < len(cur.by_count):
                cur.by_count = sub
        for (src, dst), c in best.items():
            self.trans.append((src, dst, c.payoff, len(c.by_count), c.by_payoff, c.by_count))
        return level

    def model(
        self,
        frames: tuple[int, ...],
        names: tuple[tuple[str, ...], ...],
        end: int,
        window: tuple[int, int],
        refbox: np.ndarray,
        me: int,
    ) -> MultiModel:
        t = self.trans
        return MultiModel(
            step=np.array(self.step, dtype=np.int64),
            tid=np.array(self.tid, dtype=np.int64),
            ref=np.array(self.ref, dtype=bool),
            last=np.array(self.last, dtype=np.int64),
            src=np.array([x[0] for x in t], dtype=np.int64),
            dst=np.array([x[1] for x in t], dtype=np.int64),
            payoff=np.array([x[2] for x in t], dtype=float),
            count=np.array([x[3] for x in t], dtype=np.int64),
            by_payoff=tuple(x[4] for x in t),
            by_count=tuple(x[5] for x in t),
            frames=frames,
            names=names,
            end=end,
            window=window,
            box=np.array(self.box, dtype=float).reshape(-1, 4),
            gone=np.array(self.gone, dtype=bool),
            refbox=refbox,
            target=me,
        )
