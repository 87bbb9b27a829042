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

import time
from collections.abc import Callable, Iterable, Mapping

import numpy as np

from lesmc.engines.check import DEFAULT_MAX_STATES, EngineName, check_lazy
from lesmc.engines.lazy import BATCH_SECONDS
from lesmc.engines.result import CheckResult
from lesmc.errors import UsageError
from lesmc.language.properties import SpecFile
from lesmc.language.semantics import BoundProperty, bind
from lesmc.model.arrays import ArrayModel
from lesmc.model.growing import Expansion, GrowingModel
from lesmc.tracking.design import Batch, Design, PayloadStore, make_design
from lesmc.tracking.scene import Detection, Scene, WatchedFrame

COMPONENTS = ("x", "y", "vx", "vy")

#: States expanded together when building eagerly: bounds the temporaries of one batch.
EAGER_BATCH = 65_536

#: Successors one state is assumed to have at most before a step's first batch is measured
#: (with ``--max-states``; a larger fan-out only makes that first batch a probe of one).
MAX_FAN = 64


def max_end(scene: Scene) -> int:
    """The last model step the scene's frames allow."""
    return scene.last_step - scene.target.step


def _splitmix(words: np.ndarray) -> np.ndarray:
    """One 64-bit hash per row of 64-bit words (splitmix64 finaliser, folded over columns)."""
    h = np.zeros(words.shape[0], dtype=np.uint64)
    with np.errstate(over="ignore"):
        for j in range(words.shape[1]):
            h ^= words[:, j] + np.uint64(0x9E3779B97F4A7C15) + (h << np.uint64(6))
            h ^= h >> np.uint64(30)
            h *= np.uint64(0xBF58476D1CE4E5B9)
            h ^= h >> np.uint64(27)
            h *= np.uint64(0x94D049BB133111EB)
            h ^= h >> np.uint64(31)
    return h


class HashIndex:
    """Model indices by 64-bit state hash, as sorted runs of arrays (no per-state objects).

    New entries come as a run of their own; runs of similar size are merged, so
    a lookup searches O(log n) sorted arrays and every entry is copied O(log n)
    times in all (a log-structured merge).
    """

    def __init__(self) -> None:
        self._runs: list[tuple[np.ndarray, np.ndarray]] = []  # (sorted hashes, indices)

    def find(self, h: np.ndarray) -> np.ndarray:
        """The index stored under each hash of ``h``, −1 where there is none."""
        out = np.full(h.shape, -1, dtype=np.int64)
        for keys, vals in self._runs:
            at = np.minimum(np.searchsorted(keys, h), len(keys) - 1)
            hit = keys[at] == h
            out[hit] = vals[at[hit]]
        return out

    def add(self, h: np.ndarray, idx: np.ndarray) -> None:
        """Store ``idx`` under the (new, distinct) hashes ``h``."""
        order = np.argsort(h, kind="stable")
        self._runs.append((h[order], idx[order].astype(np.int64)))
        while len(self._runs) > 1 and 2 * len(self._runs[-1][0]) >= len(self._runs[-2][0]):
            (k2, v2), (k1, v1) = self._runs.pop(), self._runs.pop()
            keys, vals = np.concatenate([k1, k2]), np.concatenate([v1, v2])
            order = np.argsort(keys, kind="stable")
            self._runs.append((keys[order], vals[order]))


class SceneExpander:
    """The successors of a scene's tracker states, batch by batch, with exact sharing."""

    def __init__(self, scene: Scene, window: tuple[int, int]) -> None:
        self.scene = scene
        self.design: Design = make_design(scene)
        self.window = window
        self.model = GrowingModel(COMPONENTS, 4)
        self.model.expander = self
        self.objects: PayloadStore | None = None  # whole tracker states, for designs that have them
        self._seen: dict[int, HashIndex] = {}  # per step: state hash -> index
        # detection index -> observation code: frames' detections numbered in order
        self._obs_offset = np.cumsum([0] + [len(f.detections) for f in scene.frames])
        self._first_frame = scene.frames[0].step
        self.model.obs_names = tuple(d.id for f in scene.frames for d in f.detections)
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
        h = _splitmix(keys)
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
                    _splitmix(keys[i : i + 1]), np.array([q])
                )
            out[i] = q
        return out

    # ------------------------------------------------------------ successors
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
        return Expansion(counts, dst, succ.payoff, succ.rank, obs)


def original_end(scene: Scene, design: Design | None = None, end: int | None = None) -> int:
    """e: the last step of the unattacked track (up to ``end``, or until it halts)."""
    design = make_design(scene) if design is None else design
    last = _last_step(scene, end)
    b = design.initial()
    e = 0
    for k in range(1, last + 1):
        if b.halted[0]:
            break
        b = design.successors(b, scene.target.step + k, False).states
        e = k
    _check_end(e, end, None)
    return e


def _last_step(scene: Scene, end: int | None) -> int:
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


def lazy_model(scene: Scene, window: tuple[int, int], end: int | None = None) -> GrowingModel:
    """The model of ``scene`` for attacks in ``window``, unfolded as an engine asks.

    The original path is unfolded at once, in the model itself (the engines
    need it); everything else when :meth:`GrowingModel.expand` is called.
    """
    model = SceneExpander(scene, window).model
    last = _last_step(scene, end)
    original = [0]
    while len(original) <= last and not model.halted[original[-1]]:
        q = original[-1]
        model.expand(np.array([q]), len(original) - 1)
        original.append(int(model.dst[model.out_lo[q]]))
    _check_end(len(original) - 1, end, window)
    model.original = np.array(original, dtype=np.int64)
    return model


def build_model(
    scene: Scene,
    window: tuple[int, int],
    end: int | None = None,
    on_level: Callable[[int, int], None] | None = None,
    on_batch: Callable[[GrowingModel], None] | None = None,
    max_states: int | None = None,
) -> ArrayModel:
    """The whole LTS of ``scene`` for attacks in ``window`` = (l, u), up to step ``end``.

    Level by level: every state of step k is expanded (in batches of at most
    :data:`EAGER_BATCH`, fewer when states are slow to expand: about
    :data:`~lesmc.engines.lazy.BATCH_SECONDS` each) before any of step k + 1.
    ``on_level(step, states)`` is called after each step (for progress bars),
    ``on_batch(model)`` before each batch (budgets: it raises to stop).
    With ``max_states`` (the caller's budget, enforced by ``on_batch``) batches
    shrink near it, by the most states one expanded state has made so far, so
    that the unfolding stops within about one state's successors of the limit
    instead of one whole batch past it.
    """
    exp = SceneExpander(scene, window)
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
            t0, made = time.perf_counter(), model.n_states
            model.expand(batch, k)
            took = (time.perf_counter() - t0) / len(batch)
            fan = max(fan, (model.n_states - made) / len(batch))
            lo += n
            cap = max(1, min(EAGER_BATCH, int(BATCH_SECONDS / max(took, 1e-9)) + 1))
        frontier = np.arange(before, model.n_states, dtype=np.int64)
        if on_level is not None:
            on_level(k + 1, model.n_states)
    # the original path is the rank-0 (unattacked) chain of the graph itself
    original = [0]
    while len(original) <= e and model.expanded(original[-1]):
        original.append(int(model.dst[model.out_lo[original[-1]]]))
    model.original = np.array(original, dtype=np.int64)
    return freeze(model, scene, window, e, exp.design.name)


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
        components=COMPONENTS,
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
        meta={
            "source": "lesmc build",
            "design": design,
            "window": [window[0], window[1]],
            "first_frame": scene.target.step,
            "end": end,
        },
    )


def priced_detections(
    scene: Scene,
    window: tuple[int, int],
    end: int | None = None,
    on_batch: Callable[[GrowingModel], None] | None = None,
    reads: dict[int, set[int]] | None = None,
    max_states: int | None = None,
) -> dict[int, np.ndarray]:
    """Per frame step, the detections whose payoffs the model of ``scene`` attacked in
    ``window`` reads: a superset of those one of its attacks can hide.

    ``reads`` (empty; filled as the model grows): what was read so far, should
    ``on_batch`` stop the build by raising (``max_states``: the limit it enforces,
    so that batches shrink near it, as in :func:`build_model`).

    Only the window's frames count: an attack at step k hides detections of
    frame ``target.step + k``, and outside the window no transition has a
    cheaper sibling whose payoff could enter a combined payoff (Eq. 5). The
    model is built once over a copy of the scene in which those frames' payoffs
    are all finite (an attack could hide every candidate) and each notes the
    entries of its payoff column the design reads (:class:`WatchedFrame`). Any
    other use of the column counts as reading all of it. ``verify --payoffs
    certified|interval`` certifies only these (a detection without a bound gets
    the trivial 0 anyway, so a missed one costs tightness, never soundness).
    """
    from dataclasses import replace

    first, last = scene.target.step + window[0], scene.target.step + window[1]
    reads = {} if reads is None else reads
    reads.update({f.step: set() for f in scene.frames if first <= f.step <= last})
    frames = tuple(
        WatchedFrame(f.step, _finite(f.detections), f.to_next, None, reads[f.step])
        if f.step in reads
        else f
        for f in scene.frames
    )
    build_model(
        replace(scene, frames=frames), window, end, on_batch=on_batch, max_states=max_states
    )
    return {k: np.array(sorted(v), dtype=np.int64) for k, v in reads.items() if v}


def merged_detections(sets: Iterable[Mapping[int, np.ndarray]]) -> dict[int, np.ndarray]:
    """The union, per frame step, of several :func:`priced_detections` answers (sorted)."""
    union: dict[int, set[int]] = {}
    for found in sets:
        for k, dets in found.items():
            union.setdefault(k, set()).update(dets.tolist())
    return {k: np.array(sorted(v), dtype=np.int64) for k, v in sorted(union.items())}


def _finite(dets: tuple[Detection, ...]) -> tuple[Detection, ...]:
    """The detections, every one attackable (payoff 1): the probe's frames."""
    from dataclasses import replace

    return tuple(replace(d, payoff=1.0) for d in dets)


def unbounded_note(scene: Scene, window: tuple[int, int]) -> list[str]:
    """The note of a check on a certified scene (:meth:`Scene.priced`) whose model, attacked
    in ``window``, read detections without a certified bound there (each counted as 0)."""
    return unbounded_text(scene.unbounded_reads(window))


def unbounded_text(n: int) -> list[str]:
    """The note of a certified check whose model can hide ``n`` detections without a bound."""
    if not n:
        return []
    return [
        f"{n} detection(s) the model can hide carry no certified bound (payoff_lower) and "
        "count as 0, the trivial bound: the certified optimum is sound but may be far "
        "below the true one"
    ]


def bind_scene(
    scene: Scene, specs: Iterable[SpecFile], end: int | None = None
) -> list[BoundProperty]:
    """Bind properties to a scene's model: steps 0..e of the unattacked track.

    ``end``: e when the caller already has it (:func:`original_end` runs the tracker
    over the whole video; a campaign binds hundreds of windows to one scene).
    """
    e = original_end(scene) if end is None else end
    return [bind(spec, prop, e, COMPONENTS, True) for spec in specs for prop in spec.properties]


def check_scene(
    scene: Scene,
    specs: Iterable[SpecFile],
    engine: EngineName = "levels",
    max_states: int | None = DEFAULT_MAX_STATES,
    timeout: float | None = None,
) -> list[CheckResult]:
    """Check properties on the model of a scene without writing it out.

    The model is unfolded on demand: ``levels`` and ``bnb`` unfold only the states
    they expand, ``enumerate`` every state its paths reach (Algorithm 1), level by level.
    """
    return [
        check_scene_bound(scene, bp, engine, max_states, timeout) for bp in bind_scene(scene, specs)
    ]


def check_scene_bound(
    scene: Scene,
    bp: BoundProperty,
    engine: EngineName = "levels",
    max_states: int | None = DEFAULT_MAX_STATES,
    timeout: float | None = None,
    max_memory: int | None = None,
) -> CheckResult:
    """One bound property on a scene (see :func:`check_scene`), on its model unfolded on
    demand (every engine, ``enumerate`` included: a budget then stops it with bounds)."""
    lazy = lazy_model(scene, (bp.l, bp.u), bp.end)
    return check_lazy(lazy, bp, max_states, timeout, engine, max_memory)


PAYOFF_MODES = ("attack", "certified", "interval")
"""``--payoffs``: which payoff column of a scene the model uses (docs/semantics.md)."""


def check_scene_payoffs(
    scene: Scene,
    bp: BoundProperty,
    payoffs: str = "attack",
    engine: EngineName = "levels",
    max_states: int | None = DEFAULT_MAX_STATES,
    timeout: float | None = None,
    path: str = "<scene>",
    max_memory: int | None = None,
) -> CheckResult:
    """One property with the attack payoffs, the certified lower ones, or both (interval).

    ``interval`` checks twice and combines the verdicts (lesmc/engines/interval.py);
    ``timeout`` is then shared between the two checks.
    """
    from dataclasses import replace

    from lesmc.engines.interval import combine

    if payoffs == "attack":
        return check_scene_bound(scene, bp, engine, max_states, timeout, max_memory)
    low = scene.priced("certified", path)

    def certified(seconds: float | None) -> CheckResult:
        r = check_scene_bound(low, bp, engine, max_states, seconds, max_memory)
        return replace(r, notes=[*r.notes, *unbounded_note(low, (bp.l, bp.u))])

    if payoffs == "certified":
        return replace(certified(timeout), payoffs=payoffs)
    if payoffs != "interval":
        raise UsageError(f"--payoffs must be one of {', '.join(PAYOFF_MODES)}, got {payoffs!r}")
    import time

    started = time.monotonic()
    half = None if timeout is None else timeout / 2
    cert = certified(half)
    left = None if timeout is None else max(0.0, timeout - (time.monotonic() - started))
    att = check_scene_bound(scene, bp, engine, max_states, left, max_memory)
    return combine(cert, att, payoff_monotone(bp))


def payoff_monotone(bp: BoundProperty) -> bool:
    """Lowering payoffs can only lower the optimum: true unless the constraint asks for a
    large payoff (``subject to payoff > c``), which lower payoffs can make false."""
    return not (bp.constraint.source == "payoff" and bp.op in (">", ">="))
