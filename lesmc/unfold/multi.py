"""Unfold a multi-target design (lesmc/tracking/multi.py) into its model
(lesmc/model/multi.py): the scene -> model stage for trackers that follow every object.

Step 0 is the scene's first frame, unattacked. At a step of the attack window the attacker
hides any subset of the frame's attackable detections (payoff finite) and, under ``allow
hide, inject``, injects any subset of its injection candidates, at the sum of their
payoffs (the options: lesmc/tracking/parts/attacker.py); outside it only the unattacked
outcome follows. The successors of one
level that are the same state (:meth:`~lesmc.tracking.parts.states.MultiBatch.words`:
every track bit for bit, the counters, and the target's last track id) are one state,
and the subsets that lead from one state to the same successor one transition, kept at
its cheapest (docs/trackers.md, "The multi-target model").
"""

from __future__ import annotations

from dataclasses import dataclass, replace

import numpy as np

from lesmc.common.errors import BudgetError, UsageError
from lesmc.model.identity import NONE, last_seen
from lesmc.model.multi import MultiModel
from lesmc.scene import Frame, Scene
from lesmc.tracking.design import CovarianceTable
from lesmc.tracking.multi import ComposedDesign, FrameTracks, MultiState, target_id
from lesmc.tracking.parts.attacker_subsets import (
    attackable,
    option_count,
    subset_cost,
    subset_options,
)
from lesmc.tracking.parts.states import MultiBatch

#: Successors one step may compute when no --max-states is given: a frame with 30
#: attackable detections has 2^30 subsets, which no search can list.
MAX_STEP_SUCCESSORS = 10_000_000


def build_multi(
    scene: Scene,
    design: ComposedDesign,
    window: tuple[int, int],
    end: int,
    max_states: int | None = None,
    radius: float | None = None,
    *,
    actions: tuple[str, ...],
) -> MultiModel:
    """The model of ``scene`` under ``design`` for attacks at steps ``window`` (l..u),
    up to step ``end``, by an attacker taking ``actions`` (hide, inject) on the detections
    :func:`~lesmc.tracking.parts.attacker.attackable` (``radius``: ``within R``).
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
    refs = design.references([s.tracks for s in run])
    _need_reference(scene, design, refs)
    refbox = [None if r is None else as_box(r) for r in refs]
    tracker, table = design.tracker, CovarianceTable()
    me = target_id([s.target_id for s in run])
    s0, ft0 = tracker.step(tracker.initial(), design.measurements(frames[0]))
    tid0 = NONE if refs[0] is None else design.target_of(ft0, refs[0])
    level: list[MultiState] = [s0]
    st = _Arrays()
    st.add_state(0, tid0, refs[0] is not None, tid0, _look(ft0, s0, me))
    for k in range(1, end + 1):
        f = frames[k]
        boxes = np.vstack([design.measurements(f), design.candidate_measurements(f)])
        pay = np.array([d.payoff for d in (*f.detections, *f.candidates)], dtype=float)
        n = len(f.detections)
        attack = (window[0] <= k <= window[1], actions, attackable(f, refbox[k], radius))
        _within_budget(f, k, len(level), attack, st.n, max_states)
        subsets = subset_options(f, *attack)
        base = st.n - len(level)
        made: list[_Made] = []
        ref = refs[k]
        for i, state in enumerate(level):
            for sub in subsets:
                keep = np.arange(len(boxes)) < n
                keep[list(sub)] ^= True  # hidden detections off, injected candidates on
                nxt, ft = tracker.step(state, boxes[keep])
                tid = NONE if ref is None else design.target_of(ft, ref)
                last = int(last_seen(np.array([st.last[base + i]]), np.array([tid]))[0])
                made.append((base + i, nxt, tid, last, sub, _look(ft, nxt, me)))
        level = st.add_level(k, made, pay, ref is not None, tracker.filter.m.dim, table)
    shown = frames[: end + 1]
    names = tuple(tuple(d.id for d in (*f.detections, *f.candidates)) for f in shown)
    rows = np.array([np.full(4, np.nan) if r is None else r for r in refbox]).reshape(-1, 4)
    model = st.model(tuple(f.step for f in shown), names, end, window, rows, me)
    return replace(model, detections=tuple(len(f.detections) for f in shown))


def as_box(v: np.ndarray) -> np.ndarray:
    """A box [x1, y1, x2, y2]; a point tracker's position (x, y) is the box of size 0 at
    it, so the ``dist`` measures read a point design's w and h as 0."""
    v = np.asarray(v, dtype=float)
    return np.concatenate([v, v]) if v.shape[-1] == 2 else v


def _need_reference(scene: Scene, design: ComposedDesign, refs: list[np.ndarray | None]) -> None:
    """A UsageError when the target has no reference at any step."""
    if any(r is not None for r in refs):
        return
    raise UsageError(
        f"the target ({scene.target.start[0]:g}, {scene.target.start[1]:g} at frame "
        f"{scene.target.step}) has no reference track: {design.no_reference()}; the "
        "identity and dist measures need one"
    )


def _within_budget(
    f: Frame,
    k: int,
    states: int,
    attack: tuple[bool, tuple[str, ...], np.ndarray],
    so_far: int,
    max_states: int | None,
) -> None:
    """A BudgetError unless step ``k`` may compute the successors of its ``states`` states
    under the attacker's options (``attack``: attacked, actions, attackable detections),
    checked before any is listed."""
    count = states * option_count(f, *attack)
    if max_states is not None and so_far + count > max_states:
        raise BudgetError(
            f"--max-states {max_states}: step {k} would compute {count} "
            f"successors of {states} states ({so_far} so far); shorten the attack window"
        )
    if count > MAX_STEP_SUCCESSORS:
        cands = f" and {len(f.candidates)} candidates" if "inject" in attack[1] else ""
        hidable = int(attack[2].sum()) if "hide" in attack[1] else 0
        raise BudgetError(
            f"step {k} would compute {count} successors of {states} states (every "
            f"subset of {hidable} detections{cands}): more than "
            f"{MAX_STEP_SUCCESSORS:,}; shorten the attack window"
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
        return as_box(ft.boxes[mine[0]]).copy(), False
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
            cost = subset_cost(pay, sub)
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


def composed(scene: Scene, path: str) -> ComposedDesign:
    """The multi-target design the scene's tracker names, set up for ``scene`` (read from
    ``path``, the name its errors give): what the layers above unfold build with."""
    from lesmc.tracking.trackers import make_multi

    design = make_multi(scene, path)
    assert isinstance(design, ComposedDesign)
    return design
