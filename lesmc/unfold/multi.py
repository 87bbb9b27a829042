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

import time
from dataclasses import dataclass, replace

import numpy as np

from lesmc.common.budget import SearchBudget
from lesmc.common.errors import BudgetError, UsageError
from lesmc.model.identity import NONE, last_seen
from lesmc.model.multi import MultiModel
from lesmc.scene import Frame, Scene
from lesmc.tracking.design import CovarianceTable
from lesmc.tracking.multi import (
    ComposedDesign,
    MultiState,
    MultiTargetTracker,
    TargetLook,
    as_box,
    target_id,
    target_look,
    targets_of,
)
from lesmc.tracking.parts.attacker_subsets import (
    attackable,
    option_count,
    subset_cost,
    subset_options,
)
from lesmc.tracking.parts.box_level import expand
from lesmc.tracking.parts.states import MultiBatch, distinct_rows

#: Successors one step may compute when no --max-states is given: a frame with 30
#: attackable detections has 2^30 subsets, which no search can list.
MAX_STEP_SUCCESSORS = 10_000_000


class UnfoldStopped(Exception):
    """The unfolding's deadline (``search``) passed, or would pass during the next step's
    successors (a step is one piece of work that looks at no clock): ``reason`` (as
    :meth:`~lesmc.common.budget.SearchBudget.over` names it), the step it stopped before
    and the states made so far. The caller reports the check as stopped (unknown)."""

    def __init__(self, reason: str, step: int, states: int) -> None:
        super().__init__(f"{reason} before step {step} ({states} states)")
        self.reason = reason
        self.step = step
        self.states = states


def build_multi(
    scene: Scene,
    design: ComposedDesign,
    window: tuple[int, int],
    end: int,
    max_states: int | None = None,
    radius: float | None = None,
    *,
    actions: tuple[str, ...],
    search: SearchBudget | None = None,
) -> MultiModel:
    """The model of ``scene`` under ``design`` for attacks at steps ``window`` (l..u),
    up to step ``end``, by an attacker taking ``actions`` (hide, inject) on the detections
    :func:`~lesmc.tracking.parts.attacker.attackable` (``radius``: ``within R``).
    ``max_states`` bounds the successors computed (before merging): a BudgetError (exit
    status 3) before a step that would pass it; ``search``'s deadline, looked at before
    each step (and the step's successors at the last step's rate a successor), an
    :class:`UnfoldStopped` before a step that would end past it. Each state records the
    box of the track with the target's id (:func:`~lesmc.tracking.multi.target_id`) and
    whether that track was deleted, which the ``dist`` measures read."""
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
    d = tracker.filter.m.dim
    level = MultiBatch.pack([(s0.tracks, s0.next_id, s0.frames, tid0)], d, table)
    st = _Arrays()
    st.add_state(0, tid0, refs[0] is not None, tid0, target_look(ft0, s0, me))
    rate = 0.0  # seconds a successor took at the last step
    for k in range(1, end + 1):
        f = frames[k]
        boxes = np.vstack([design.measurements(f), design.candidate_measurements(f)])
        pay = np.array([d.payoff for d in (*f.detections, *f.candidates)], dtype=float)
        attack = (window[0] <= k <= window[1], actions, attackable(f, refbox[k], radius))
        count = _within_budget(f, k, len(level), attack, st.n, max_states)
        began = _on_time(search, rate * count, k, st.n)
        subsets = subset_options(f, *attack)
        keeps = [_kept(len(f.detections), len(boxes), sub) for sub in subsets]
        base = st.n - len(level)
        if isinstance(tracker, MultiTargetTracker):
            made = _expanded(design, level, boxes, keeps, table, refs[k], me, st.last, base)
        else:
            made = _stepped(design, level, boxes, keeps, table, refs[k], me, st.last, base)
        level = st.add_level(k, made, subsets, pay, refs[k] is not None)
        rate = (time.perf_counter() - began) / max(count, 1)
    shown = frames[: end + 1]
    names = tuple(tuple(d.id for d in (*f.detections, *f.candidates)) for f in shown)
    rows = np.array([np.full(4, np.nan) if r is None else r for r in refbox]).reshape(-1, 4)
    model = st.model(tuple(f.step for f in shown), names, end, window, rows, me)
    return replace(model, detections=tuple(len(f.detections) for f in shown))


def _kept(n: int, size: int, sub: tuple[int, ...]) -> np.ndarray:
    """The indices of the boxes (``n`` detections, then candidates; ``size`` in all) the
    tracker sees under option ``sub``: hidden detections off, injected candidates on."""
    keep = np.arange(size) < n
    keep[list(sub)] ^= True
    return np.flatnonzero(keep)


@dataclass(frozen=True)
class _Made:
    """A level's successors, one per (state, option), by state then option: the source
    state's index in the model, the successors (``last`` set), the target's track id of
    each, and what each shows the ``dist`` measures (:func:`_look`)."""

    src: np.ndarray
    batch: MultiBatch
    tid: np.ndarray
    box: np.ndarray
    gone: np.ndarray


def _expanded(
    design: ComposedDesign,
    level: MultiBatch,
    boxes: np.ndarray,
    keeps: list[np.ndarray],
    table: CovarianceTable,
    ref: np.ndarray | None,
    me: int,
    last: list[int],
    base: int,
) -> _Made:
    """The successors of a box tracker's level, all at once (parts/box_level.py)."""
    out = expand(design.tracker, level, boxes, keeps, table)
    b = out.batch
    if ref is None:
        tid = np.full(len(b), NONE, dtype=np.int64)
    else:
        tid = targets_of(out.boxes, b.id, out.confirmed, ref)
    src = base + out.src
    b = replace(b, last=last_seen(np.asarray(last, dtype=np.int64)[src], tid))
    mine = b.id == me
    has = mine.any(axis=1)
    at = np.argmax(mine, axis=1)
    box = np.where(has[:, None], out.boxes[np.arange(len(b)), at], np.nan).reshape(-1, 4)
    gone = ~has & (me != NONE) & (me < b.next_id)
    return _Made(src, b, tid, box, gone)


def _stepped(
    design: ComposedDesign,
    level: MultiBatch,
    boxes: np.ndarray,
    keeps: list[np.ndarray],
    table: CovarianceTable,
    ref: np.ndarray | None,
    me: int,
    last: list[int],
    base: int,
) -> _Made:
    """The successors of a level, one tracker step each (any composed tracker)."""
    src, states, tids, lasts, looks = [], [], [], [], []
    for i in range(len(level)):
        tr = level.tracks(i, table)
        state = MultiState(tr, int(level.next_id[i]), int(level.frames[i]))
        for keep in keeps:
            nxt, ft = design.tracker.step(state, boxes[keep])
            tid = NONE if ref is None else design.target_of(ft, ref)
            src.append(base + i)
            states.append(nxt)
            tids.append(tid)
            lasts.append(int(last_seen(np.array([last[base + i]]), np.array([tid]))[0]))
            looks.append(target_look(ft, nxt, me))
    d = design.tracker.filter.m.dim
    packed = [(s.tracks, s.next_id, s.frames, x) for s, x in zip(states, lasts, strict=True)]
    return _Made(
        np.array(src, dtype=np.int64),
        MultiBatch.pack(packed, d, table),
        np.array(tids, dtype=np.int64),
        np.array([x[0] for x in looks], dtype=float).reshape(-1, 4),
        np.array([x[1] for x in looks], dtype=bool),
    )


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
) -> int:
    """A BudgetError unless step ``k`` may compute the successors of its ``states`` states
    under the attacker's options (``attack``: attacked, actions, attackable detections),
    checked before any is listed; else how many it computes."""
    count = states * option_count(f, *attack)
    if max_states is not None and so_far + count > max_states:
        raise BudgetError(
            f"--max-states {max_states}: step {k} would compute {count} "
            f"successors of {states} states ({so_far} so far); {_fewer(f, attack)}"
        )
    if count > MAX_STEP_SUCCESSORS:
        cands = f" and {len(f.candidates)} candidates" if "inject" in attack[1] else ""
        hidable = int(attack[2].sum()) if "hide" in attack[1] else 0
        raise BudgetError(
            f"step {k} would compute {count} successors of {states} states (every "
            f"subset of {hidable} detections{cands}): more than "
            f"{MAX_STEP_SUCCESSORS:,}; {_fewer(f, attack)}"
        )
    return count


def _fewer(f: Frame, attack: tuple[bool, tuple[str, ...], np.ndarray]) -> str:
    """What limits a step's options: ``within R`` the detections hidden; the injection
    candidates only the scene does (``within R`` does not reach them)."""
    hide = "shorten the attack window or limit hiding to the target's neighbourhood (attack "
    hide += "window L..U within R)"
    if "inject" not in attack[1] or not f.candidates:
        return hide
    inj = (
        f"offer fewer injection candidates a frame (frame {f.step} has {len(f.candidates)}: "
        "perceive --inject-cap N or a smaller --inject-within PX; a lower import mot --threshold)"
    )
    return inj if "hide" not in attack[1] else f"{inj}; {hide}"


def _on_time(search: SearchBudget | None, seconds: float, k: int, states: int) -> float:
    """An :class:`UnfoldStopped` when ``search``'s deadline has passed, or would pass during
    step ``k``'s successors (``seconds``, estimated), with ``states`` made so far; else the
    time now (``time.perf_counter``), when the step starts."""
    if search is not None:
        reason = search.over() or search.would_pass(seconds)
        if reason is not None:
            raise UnfoldStopped(reason, k, states)
    return time.perf_counter()


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

    def add_state(self, k: int, tid: int, ref: bool, last: int, look: TargetLook) -> None:
        self.step.append(k)
        self.tid.append(tid)
        self.ref.append(ref)
        self.last.append(last)
        self.box.append(look[0])
        self.gone.append(look[1])

    def add_level(
        self, k: int, made: _Made, subsets: list[tuple[int, ...]], pay: np.ndarray, ref: bool
    ) -> MultiBatch:
        """Add step ``k``'s successors ``made`` (one per state and option of ``subsets``, by
        state then option), merged; returns the level's distinct states in order of first
        sight."""
        batch = made.batch
        rank, keep = distinct_rows(batch.words(batch.X.shape[1]))
        base = self.n
        self.step.extend([k] * len(keep))
        self.tid.extend(made.tid[keep].tolist())
        self.ref.extend([ref] * len(keep))
        self.last.extend(batch.last[keep].tolist())
        self.box.extend(made.box[keep])
        self.gone.extend(made.gone[keep].tolist())
        dst = base + rank
        option = np.tile(np.arange(len(subsets)), len(made.src) // max(len(subsets), 1))
        cost = np.array([subset_cost(pay, sub) for sub in subsets], dtype=float)[option]
        size = np.array([len(sub) for sub in subsets], dtype=np.int64)[option]
        # one transition per (source, successor), in order of first sight, at its cheapest
        # (the first of equals) by payoff and by count
        _, at, group = np.unique(made.src * (base + len(keep)) + dst, return_index=True,
                                 return_inverse=True)  # fmt: skip
        group = group.reshape(-1)
        seq = np.arange(len(group))
        by_pay = np.lexsort((seq, cost, group))
        by_cnt = np.lexsort((seq, size, group))
        heads = np.searchsorted(group[by_pay], np.arange(len(at)))
        pay_pick, cnt_pick = by_pay[heads], by_cnt[heads]
        for g in np.argsort(at, kind="stable"):
            p, c = int(pay_pick[g]), int(cnt_pick[g])
            sp, sc = subsets[option[p]], subsets[option[c]]
            self.trans.append((int(made.src[p]), int(dst[p]), float(cost[p]), len(sc), sp, sc))
        return batch.take(keep)

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
