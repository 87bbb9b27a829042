"""The scene -> model stage: unfold a tracked scene into a <PO>²-LTS (section 3.3, Alg. 1).

Model step k is frame ``target.step + k``. From step l to u every
attacker-forced outcome of the tracker is a transition (ranked nearest
detection first, tracking/association.py); outside the window each branch
follows the unattacked (rank-0) outcome. States that coincide exactly are
shared. One core serves both modes:

* :func:`build_model` unfolds everything, level by level, each level in
  batches (``lesmc build``, the report);
* :func:`lazy_model` gives the engines a :class:`~lesmc.model.growing.GrowingModel`
  whose successors are computed when the search first asks for them.

Either way the tracker design computes the successors of a whole batch of
states at once (tracking/design.py), and :class:`SceneExpander` shares the
coinciding ones. Following stormpy: ``build_model(scene, ...)``, then
``check(model, property)``.
"""

from __future__ import annotations

from collections.abc import Callable

import numpy as np

from lesmc.common.errors import UsageError
from lesmc.model.arrays import ArrayModel, Tracks
from lesmc.model.growing import BATCH_WORK, Expansion, GrowingModel, counted_batch
from lesmc.scene import Scene
from lesmc.tracking.design import Batch, Design, PayloadStore
from lesmc.tracking.joint import JointDesign
from lesmc.tracking.parts.relaxed import MAX_NODES, Cut, primary_alive
from lesmc.tracking.single import grid_point_name
from lesmc.tracking.trackers import make_tracker
from lesmc.unfold.attack_path import walked_attack_of
from lesmc.unfold.hashing import HashIndex, row_hash

#: States expanded together when building eagerly: bounds the temporaries of one batch.
EAGER_BATCH = 65_536

#: Successors one state is assumed to have at most before a step's first batch is measured
#: (with ``--max-states``; a larger fan-out only makes that first batch a probe of one).
MAX_FAN = 64


def max_end(scene: Scene) -> int:
    """The last model step the scene's frames allow."""
    return scene.last_step - scene.target.step


class SceneExpander:
    """The successors of a scene's tracker states, batch by batch, with exact sharing."""

    def __init__(
        self,
        scene: Scene,
        window: tuple[int, int],
        inject: bool = False,
        hide: bool = True,
        grid: tuple[np.ndarray, float] | None = None,
    ) -> None:
        self.scene = scene
        self.design: Design = make_tracker(scene, inject, hide, grid)
        self.window = window
        names = scene.tracker.state_names
        self.model = GrowingModel(names, len(names))
        self.model.expander = self
        self.objects: PayloadStore | None = None  # whole tracker states, for designs that have them
        self._seen: dict[int, HashIndex] = {}  # per step: state hash -> index
        # detection index -> observation code: frames' detections numbered in order, each
        # frame's injection candidates after its detections under inject (n + j: candidate j)
        # and then, under ``inject grid``, the grid's points (n + m + i: point i)
        per = [
            tuple(d.id for d in f.detections + (f.candidates if inject else ()))
            + grid_names(f.step, grid)
            for f in scene.frames
        ]
        self._obs_offset = np.cumsum([0] + [len(p) for p in per])
        self._first_frame = scene.frames[0].step
        self.model.obs_names = tuple(name for p in per for name in p)
        self.add(0, self.design.initial())

    # ---------------------------------------------------------------- states
    def batch(self, idx: np.ndarray) -> Batch:
        """The tracker states with model indices ``idx`` (read from the model's arrays)."""
        m = self.model
        objs = None if self.objects is None else self.objects.take(idx)
        return Batch(m.S[idx], m.cov[idx].astype(np.int64), m.halted[idx], objs)

    def _append(self, step: int, fresh: Batch) -> int:
        model = self.model
        if len(self.design.covariances) != len(model.P_table):  # the table grew
            model.P_table = self.design.covariances.stack()
        first = model.add_states(step, fresh.X, fresh.cov.astype(np.int32), fresh.halted)
        if fresh.objects is not None:
            if self.objects is None:
                self.objects = fresh.objects.store()
            self.objects.extend(fresh.objects)
        return first

    def add(self, step: int, batch: Batch) -> np.ndarray:
        """Model indices of the states of ``batch`` at ``step``; new ones are appended."""
        model = self.model
        design = self.design
        keys = design.keys(batch)
        h = row_hash(keys)
        uniq, first, inverse = np.unique(h, return_index=True, return_inverse=True)
        inverse = inverse.reshape(-1)
        if not np.array_equal(keys, keys[first[inverse]]):  # two states share a hash
            return self._add_exact(step, batch, keys)
        seen = self._seen.setdefault(step, HashIndex())
        found = seen.find(uniq)
        old = np.nonzero(found >= 0)[0]
        if old.size and not np.array_equal(design.keys(self.batch(found[old])), keys[first[old]]):
            return self._add_exact(step, batch, keys)
        new = np.nonzero(found < 0)[0]
        new = new[np.argsort(first[new], kind="stable")]  # first-occurrence order
        start = model.n_states
        if new.size:
            self._append(step, batch.take(first[new]))
            found[new] = start + np.arange(new.size)
            seen.add(uniq[new], found[new])
        out: np.ndarray = found[inverse]
        return out

    def _add_exact(self, step: int, batch: Batch, keys: np.ndarray) -> np.ndarray:
        """The slow path after a 64-bit hash collision: share by the exact key bytes."""
        at = np.nonzero(self.model.step == step)[0]  # what exists at this step, by exact key
        old_keys = self.design.keys(self.batch(at)) if at.size else keys[:0]
        exact = {old_keys[i].tobytes(): int(q) for i, q in enumerate(at.tolist())}
        out = np.empty(len(batch), dtype=np.int64)
        for i in range(len(batch)):
            kb = keys[i].tobytes()
            q = exact.get(kb)
            if q is None:
                q = self._append(step, batch.take(np.array([i])))
                exact[kb] = q
                self._seen.setdefault(step, HashIndex()).add(
                    row_hash(keys[i : i + 1]), np.array([q])
                )
            out[i] = q
        return out

    # ------------------------------------------------------------ successors
    def primary_alive(
        self,
        q: int,
        end: int,
        cut: Cut,
        max_nodes: int | None = None,
        deadline: float | None = None,
    ) -> bool | None:
        """Whether state ``q`` has a completion to step ``end`` that the monitor ``cut``
        (step entered, P before, P after) allows, by the design's relaxation to its primary
        (lesmc/tracking/parts/relaxed.py: False only if none has; True past ``max_nodes``
        relaxed nodes or the ``deadline``, time.monotonic()); None: the design has no
        such relaxation."""
        if type(self.design) is not JointDesign:  # a subclass may move its primary otherwise
            return None
        m = self.model
        P = np.array(m.P_table[int(m.cov[q])], copy=True)
        c = self.design.track_covariances.add(P)
        k = int(m.step[q])
        nodes = MAX_NODES if max_nodes is None else min(max_nodes, MAX_NODES)
        return primary_alive(
            self.design, m.S[q].copy(), c, k, self.window, end, cut, nodes, deadline
        )

    def expand(self, states: np.ndarray, step: int) -> Expansion:
        """All successors of ``states`` (at ``step``) at step + 1, new states added."""
        k = step + 1
        l, u = self.window
        frame = self.scene.target.step + k
        succ = self.design.successors(self.batch(states), frame, l <= k <= u)
        dst = self.add(k, succ.states)
        obs_base = int(self._obs_offset[frame - self._first_frame])
        obs = np.where(succ.det >= 0, succ.det + obs_base, -1)
        counts = np.bincount(succ.src, minlength=len(states))
        return Expansion(counts, dst, succ.payoff, succ.rank, obs, succ.nis, succ.examined)


def scene_tracks(scene: Scene, steps: int) -> Tracks | None:
    """The scene's ground-truth tracks as model arrays: step k is frame target.step + k,
    positions at the tracker's measured components; None when the scene has none."""
    if not scene.truth:
        return None
    names = scene.tracker.state_names
    pos = scene.tracker.measured
    at = np.full((len(scene.truth), steps, 2), np.nan)
    first = scene.target.step
    for r, tr in enumerate(scene.truth):
        for frame, x, y in tr.positions:
            if 0 <= frame - first < steps:
                at[r, frame - first] = (x, y)
    ids = tuple(t.id for t in scene.truth)
    return Tracks((names[pos[0]], names[pos[1]]), ids, at)


def original_end(scene: Scene, design: Design | None = None, end: int | None = None) -> int:
    """e: the last step of the unattacked track (up to ``end``, or until it halts).

    The unattacked track's states never depend on a payoff: a scene with unpriced
    payoffs is tracked with every payoff 1 (:meth:`~lesmc.scene.Scene.payoff_free`)."""
    if design is None:
        design = make_tracker(scene.payoff_free() if scene.has_unpriced else scene)
    last = last_step(scene, end)
    b = design.initial()
    e = 0
    for k in range(1, last + 1):
        if b.halted[0]:
            break
        b = design.successors(b, scene.target.step + k, False).states
        e = k
    _check_end(e, end, None)
    return e


def last_step(scene: Scene, end: int | None) -> int:
    """The last step to unfold: ``end``, or the last the scene's frames allow."""
    limit = max_end(scene)
    if end is not None and end > limit:
        raise UsageError(
            f"end {end} is beyond the scene: its frames allow steps 0..{limit} "
            f"from the target's frame {scene.target.step}"
        )
    return limit if end is None else end


def _check_end(e: int, end: int | None, window: tuple[int, int] | None) -> None:
    """The unattacked track reaches ``end``, and ``window`` lies within 1..e."""
    if end is not None and e < end:
        raise UsageError(
            f"the unattacked track halts at step {e} (trace(P) > max_trace); use --end {e} or less"
        )
    if window is not None and not 1 <= window[0] <= window[1] <= e:
        raise UsageError(f"window {window[0]}..{window[1]} must satisfy 1 <= l <= u <= end = {e}")


def lazy_model(
    scene: Scene,
    window: tuple[int, int],
    end: int | None = None,
    reference: np.ndarray | None = None,
    inject: bool = False,
    hide: bool = True,
    grid: tuple[np.ndarray, float] | None = None,
    stop: Callable[[], None] | None = None,
) -> GrowingModel:
    """The model of ``scene`` for attacks in ``window``, unfolded as an engine asks.

    The original path is unfolded at once, in the model itself (the engines
    need it); everything else when :meth:`GrowingModel.expand` is called.
    With ``reference`` (a fault variant's: the fault-free track's states,
    lesmc/pipeline/faults.py) deviations are measured against it, and the unattacked
    track may halt anywhere after the window opens: the fault alone lost the target.
    ``inject``: the attacker may also inject the frames' candidates (``allow hide,
    inject``); ``hide``: it may hide detections (not under ``allow inject`` alone);
    ``grid``: ``inject grid``'s offsets (G, 2) from the prediction and payoff; ``stop``:
    called between chunks of a long expansion (the joint design's), raises to end it.
    """
    expander = SceneExpander(scene, window, inject, hide, grid)
    if stop is not None and isinstance(expander.design, JointDesign):
        expander.design.stop = stop
    model = expander.model
    last = last_step(scene, end)
    original = [0]
    while len(original) <= last and not model.halted[original[-1]]:
        q = original[-1]
        model.expand(np.array([q]), len(original) - 1)
        original.append(int(model.dst[model.out_lo[q]]))
    if reference is None:
        _check_end(len(original) - 1, end, window)
    elif len(original) < window[0]:
        raise UsageError(f"the unattacked track halts before the attack window {window}")
    model.original = np.array(original, dtype=np.int64)
    model.reference = reference
    model.tracks = scene_tracks(scene, last + 1)
    return model


def build_model(
    scene: Scene,
    window: tuple[int, int],
    end: int | None = None,
    on_level: Callable[[int, int], None] | None = None,
    on_batch: Callable[[GrowingModel], None] | None = None,
    max_states: int | None = None,
    inject: bool = False,
    hide: bool = True,
    grid: tuple[np.ndarray, float] | None = None,
) -> ArrayModel:
    """The whole LTS of ``scene`` for attacks in ``window`` = (l, u), up to step ``end``.

    Level by level: every state of step k is expanded (in batches of at most
    :data:`EAGER_BATCH`, fewer when states do much work to expand: about
    :data:`~lesmc.model.growing.BATCH_WORK` each, at the last batch's work per state,
    counted and not timed, so that where a budget stops the build is the same on every
    run whatever the machine's load) before any of step k + 1.
    ``on_level(step, states)`` is called after each step (for progress bars),
    ``on_batch(model)`` before each batch (budgets: it raises to stop).
    With ``max_states`` (the caller's budget, enforced by ``on_batch``) batches
    shrink near it, by the most states one expanded state has made so far, so
    that the unfolding stops within about one state's successors of the limit
    instead of one whole batch past it. ``inject``: the attacker may also inject the
    frames' candidates (``allow hide, inject``); ``hide``: it may hide detections (not
    under ``allow inject`` alone); ``grid``: ``inject grid``'s offsets and payoff.
    """
    exp = SceneExpander(scene, window, inject, hide, grid)
    e = original_end(scene, exp.design, end)
    _check_end(e, None, window)
    model = exp.model
    frontier = np.arange(model.n_states, dtype=np.int64)
    cap = EAGER_BATCH
    for k in range(e):
        before = model.n_states
        live = frontier[~model.halted[frontier]]
        lo = 0
        fan = 0.0  # new states per expanded state of this step, the most seen in a batch
        while lo < len(live):
            if on_batch is not None:
                on_batch(model)
            n = cap if max_states is None else _room(max_states - model.n_states, fan, cap)
            batch = live[lo : lo + n]
            work, made = model.work, model.n_states
            model.expand(batch, k)
            fan = max(fan, (model.n_states - made) / len(batch))
            lo += n
            cap = counted_batch(model.work - work, len(batch), EAGER_BATCH, EAGER_BATCH, BATCH_WORK)
        frontier = np.arange(before, model.n_states, dtype=np.int64)
        if on_level is not None:
            on_level(k + 1, model.n_states)
    # the original path is the rank-0 (unattacked) chain of the graph itself
    original = [0]
    while len(original) <= e and model.expanded(original[-1]):
        original.append(int(model.dst[model.out_lo[original[-1]]]))
    model.original = np.array(original, dtype=np.int64)
    cm = freeze(model, scene, window, e, exp.design.name)
    cm.meta.update(_attacker_meta(inject, hide, grid))
    return cm


def _attacker_meta(
    inject: bool, hide: bool, grid: tuple[np.ndarray, float] | None
) -> dict[str, object]:
    """What a built model records of its attacker when not the default: ``actions``, and
    ``inject_grid`` (the modelling device's offsets from the prediction and payoff)."""
    out: dict[str, object] = {}
    if inject or not hide:
        out["actions"] = [a for a, on in (("hide", hide), ("inject", inject)) if on]
    if grid is not None:
        out["inject_grid"] = {"offsets": grid[0].tolist(), "payoff": float(grid[1])}
    return out


def attack_of(
    scene: Scene,
    model: ArrayModel,
    hide: bool = True,
    grid: tuple[np.ndarray, float] | None = None,
) -> Callable[[int, int, int], tuple[list[str], list[str]]] | None:
    """For a model of ``scene`` built with inject: (state, step, rank) -> the ids of the
    detections hidden and of what is injected by the cheapest way to that outcome, from
    the tracker's ``attack_at`` (the state's estimate and covariance suffice: single), else
    from its ``attack_in`` on the whole state walked to (joint: lesmc/unfold/attack_path.py;
    None: its tracker says neither)."""
    design = make_tracker(scene, True, hide, grid)
    at = getattr(design, "attack_at", None)
    if at is None:
        if getattr(design, "attack_in", None) is None:
            return None
        return walked_attack_of(design, model)
    first = int(model.meta.get("first_frame", 0))

    def of(q: int, k: int, rank: int) -> tuple[list[str], list[str]]:
        got: tuple[list[str], list[str]] = at(model.S[q], model.P(q), first + k, rank)
        return got

    return of


def grid_names(step: int, grid: tuple[np.ndarray, float] | None) -> tuple[str, ...]:
    """The observation names of ``inject grid``'s points at frame ``step``: ``STEP:grid``
    and the point's offset from the prediction in px (``3:grid+5-10``); none without one."""
    if grid is None:
        return ()
    return tuple(grid_point_name(step, dx, dy) for dx, dy in grid[0].tolist())


def _room(room: int, fan: float, cap: int) -> int:
    """States to expand next so that about ``room`` more states are made (at least one);
    ``fan``: new states per expanded state measured at this step (0: not yet, then a
    batch of one measures it, unless a whole batch fits in the room whatever it makes)."""
    if fan <= 0:
        return cap if room >= cap * MAX_FAN else 1
    return max(1, min(cap, int(room / fan)))


def freeze(
    model: GrowingModel, scene: Scene, window: tuple[int, int], end: int, design: str
) -> ArrayModel:
    """Freeze a fully unfolded model into an :class:`ArrayModel` (CSR by source state)."""
    lo, hi = model.out_lo, model.out_hi
    counts = np.where(lo >= 0, hi - lo, 0)
    ptr = np.r_[0, np.cumsum(counts)].astype(np.int64)
    done = np.nonzero(lo >= 0)[0]
    by_lo = done[np.argsort(lo[done], kind="stable")]
    src = np.repeat(by_lo, counts[by_lo])  # the source of each stored transition
    order = np.argsort(src, kind="stable")  # identity when expanded in index order
    original = model.original
    return ArrayModel(
        tracks=scene_tracks(scene, end + 1),
        components=model.components,
        step=model.step.astype(np.int64),
        S=model.S.copy(),
        halted=model.halted.copy(),
        ptr=ptr,
        dst=model.dst[order],
        payoff=model.payoff[order],
        rank=model.rank[order],
        original=original.copy(),
        cov=model.cov.astype(np.int64),
        P_table=model.P_table.copy(),
        obs=model.obs[order],
        obs_names=model.obs_names,
        nis=None if model.nis is None else model.nis[order],
        meta={
            "source": "lesmc build",
            "design": design,
            "window": [window[0], window[1]],
            "first_frame": scene.target.step,
            "end": end,
        },
    )
