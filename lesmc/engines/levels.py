"""Engine ``levels``: exact label search in lock step, one numpy pass per step.

Every transition enters the next step, so the partial paths of a search
space advance together: a *level* holds the labels (state, objective so far,
constraint so far) of the paths that have reached one step. Both measures
only grow along a path (space.py), which makes three prunings exact:

* **bounds**: a label whose objective can no longer end below the incumbent,
  or whose constraint can no longer be violated, has no useful completion;
* **dominance** at shared states: a label with no larger objective and a
  constraint value no less favourable makes another one redundant (every
  completion of the second is matched by the same completion of the first),
  kept as a Pareto front per state by one sort;
* **an incumbent first**: a beam dive (the best labels per level only) finds a
  violating path before the exact pass, so the exact pass prunes from the start.

On an explicit model the bounds are suffix minima and maxima (one backward
pass) and, when objective and constraint are both sums, Lagrangian bounds
``o + min_suffix Σ(c_obj − sλ c_con) + sλ(B − c)`` for a grid of λ ≥ 0: the
relaxation that makes the 0-1 knapsack's fractional bound (docs/engines.md).

The representative path ρ* and θ* (phase 2), an optimisation of their own, are in
meet.py; what both phases share (labels, their trail, the rounding slack) in labels.py.
For a max objective one backward pass over the states built (below.py) decides θ*
first, wherever those states suffice.

Under a budget both phases stop with proven bounds (docs/engines.md, "anytime").
"""

from __future__ import annotations

import math
import time
from typing import NamedTuple

import numpy as np

from lesmc.common.budget import Budget, SearchBudget, resident_bytes
from lesmc.engines import compiled, level_compiled
from lesmc.engines.below import greedy_witness
from lesmc.engines.bounds import Bounds
from lesmc.engines.labels import BEAM
from lesmc.engines.labels import Stop as _Stop
from lesmc.engines.labels import Trail as _Trail
from lesmc.engines.labels import expand as _expand
from lesmc.engines.labels import grain as _grain
from lesmc.engines.labels import joined as _joined
from lesmc.engines.labels import lo as _lo
from lesmc.engines.labels import slice_size as _slice
from lesmc.engines.labels import truth as _truth
from lesmc.engines.level_bounds import LevelBounds
from lesmc.engines.meet import representative_search as _representative
from lesmc.engines.meet import witness_cap as _witness_cap
from lesmc.engines.result import EngineOutcome, Stats
from lesmc.engines.space import SearchSpace, Space
from lesmc.engines.values import plan, value_search
from lesmc.model.kernel import aggregate_arrays

#: Labels kept per level by the dives for the optimum on a model unfolded on demand
#: (see :func:`_dive_beam`; on an explicit model labels.BEAM).
LAZY_BEAM = 32
#: Dives side by side per pass of :func:`_tighten` on a model unfolded on demand.
LAZY_LANES = 4
#: Most extra dives that bisect a threshold, and the relative gap at which they stop.
TIGHTEN = 8
TIGHT_GAP = 0.02
#: Levels up to this many labels rank constraint values by a searchsorted (see _pareto).
PARETO_SEARCHSORTED = 1 << 14


#: Labels the exact pass for the optimum expands before the compiled depth-first pass takes
#: over, where it applies (lesmc/engines/level_compiled.py) and numba is installed.
COMPILED_AFTER = 1_000_000

#: the value table (values.py) runs instead of the label passes where it has at most this
#: many cells (states × objective values over the levels; 8 bytes each) ...
VALUE_CELLS = 1 << 23
#: ... and at most this many moves (one numpy call each)
VALUE_MOVES = 4096
#: θ* of a max objective by one backward pass over the states built (below.py) before any
#: witness search; False: the label passes alone (tests compare both).
STATE_WITNESS = True


# ----------------------------------------------------------------------------- search
def _pareto(q: np.ndarray, o: np.ndarray, c: np.ndarray, up: bool) -> np.ndarray:
    """Indices of the labels no other label at the same state dominates.

    Sorted by state, objective ascending and constraint best-first, a label is
    kept when its constraint beats every earlier label of its state (ranks, so
    that one running maximum serves all states at once).
    """
    if q.size <= 1:
        return np.arange(q.size)
    cc = c if up else -c
    order = np.lexsort((-cc, o, q))
    qs, cs = q[order], cc[order]
    # equal constraint values share a rank: a later equal label is dominated (ranks by
    # np.unique on big levels, where a searchsorted of unsorted values is 5x slower; on
    # small ones the searchsorted is cheaper: np.unique's own overhead dominates)
    if cs.size > PARETO_SEARCHSORTED:
        rank = np.unique(cs, return_inverse=True)[1].astype(np.int64, copy=False)
    else:
        rank = np.searchsorted(np.sort(cs), cs)
    start = np.concatenate(([True], qs[1:] != qs[:-1]))
    group = np.cumsum(start) - 1
    key = group * (cs.size + 1) + rank
    best_before = np.maximum.accumulate(np.concatenate(([-1], key[:-1])))
    keep = start | (best_before < key)
    return np.asarray(order[keep])


class _Pass(NamedTuple):
    """What :func:`_optimum_pass` found: the best objective, where its label is (trail,
    level, index), a proven lower bound on the optimum (−inf for a beam that dropped
    labels), why it stopped early (None: it finished), and per lane whether it found a
    path below its threshold.

    A dive whose beam never had to drop a label (no level of any lane past ``beam``
    labels after the cuts and the Pareto filter) kept exactly the labels the exact pass
    keeps: the lane of the highest threshold is then the exact pass below it, and its
    best is proven, as the exact pass's is (docs/engines.md, `levels` item 3).
    """

    best: float
    where: tuple[_Trail, int, int] | None
    lower: float
    why: str | None
    hits: np.ndarray


def _optimum_pass(
    space: SearchSpace,
    bounds: LevelBounds,
    budget: SearchBudget,
    stats: Stats,
    upper: float | np.ndarray,
    beam: int | None,
    saturated_first: bool = True,
) -> _Pass:
    """The cheapest violating path with objective below ``upper`` (exact unless ``beam``;
    ``saturated_first``: how the beam ranks labels that already violate, see :func:`_beam`).

    Several thresholds (beam only) are dives side by side, one *lane* each, unfolded in
    one batch a level: a label keeps its lane, whose threshold (and the incumbent) cuts
    it and whose beam it shares. Stopped early, the lower bound is the least label bound.
    """
    thresholds = np.atleast_1d(np.asarray(upper, dtype=float))
    lane_cut = np.array([bounds.cut(float(x)) for x in thresholds])
    hits = np.zeros(thresholds.size, dtype=bool)
    trail, fq, fo, fc, fg = _roots(space, thresholds.size)
    best, where, cm, whole = float(thresholds.max()), None, space.cm, True  # whole: see _Pass
    while fq.size:
        leaf = space.leaves(fq)
        found = _cheapest_leaf(space, fq, fo, fc, leaf, best, thresholds, fg, hits)
        if found is not None:
            best, where = found[0], (trail, len(trail.q) - 1, found[1])
        live = np.nonzero(~leaf)[0]
        parts: list[tuple[np.ndarray, ...]] = []
        s0 = 0
        while s0 < live.size:
            sl = live[s0 : s0 + _slice(space)]
            s0 += sl.size
            try:
                idx, t = _expand(space, fq[sl], budget, stats)
            except _Stop as stop:
                if beam is not None:
                    return _Pass(best, where, -math.inf, stop.reason, hits)
                rest = live[s0 - sl.size :]  # this slice was not expanded
                lower = min(best, bounds.least_lb(fq[rest], fo[rest], fc[rest]), _least(parts))
                return _Pass(best, where, lower, stop.reason, hits)
            par, dst = sl[idx], cm.dst[t]
            o2 = aggregate_arrays(space.obj_max, fo[par], space.c_obj[t])
            c2 = _saturate(space, aggregate_arrays(space.con_max, fc[par], space.c_con[t]))
            lb2 = bounds.violating_lb(dst, o2, c2)
            fine = lb2 < np.minimum(bounds.cut(best), lane_cut[fg[par]])
            parts.append((dst[fine], o2[fine], c2[fine], par[fine], t[fine], lb2[fine]))
        if not parts:
            break
        q, o, c, p, t, lb = _joined(parts)
        why = budget.over(0)
        if why is not None and beam is None:  # a huge level: stop before filtering it
            return _Pass(best, where, min(best, float(lb.min(initial=math.inf))), why, hits)
        g = fg[p]
        cut = np.minimum(bounds.cut(best), lane_cut[g])
        keep, all_kept = _kept(space, q, o, c, lb, cut, g, beam, saturated_first)
        whole = whole and all_kept
        trail.add(q[keep], p[keep], t[keep])
        fq, fo, fc, fg = q[keep], o[keep], c[keep], g[keep]
    return _Pass(best, where, (best if beam is None or whole else -math.inf), None, hits)


def _roots(
    space: SearchSpace, lanes: int
) -> tuple[_Trail, np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """A trail whose first level is the root once per lane, and that level's states,
    objectives, constraint values and lanes."""
    trail = _Trail()
    lane = np.arange(lanes)
    q = np.full(lanes, space.root, dtype=np.int64)
    trail.add(q, np.full(lanes, -1), np.full(lanes, -1))
    return trail, q, np.full(lanes, space.root_obj), np.full(lanes, space.root_con), lane


def _saturate(space: SearchSpace, c: np.ndarray) -> np.ndarray:
    """Constraint values that already violate, whatever follows, made one value (+inf).

    With ``>``/``>=`` the constraint measure only grows along a path, so once it
    is past the bound (with the rounding slack) every completion violates and
    the exact value no longer matters: the labels of a state that are all past
    it then differ only in their objective, and the Pareto filter keeps one.
    """
    if not space.con_up:
        return c
    done = _truth(space.satisfies(_lo(c), space.bp.bound)) & np.isfinite(c)
    return np.where(done, math.inf, c) if done.any() else c


def _beam(
    space: SearchSpace,
    keep: np.ndarray,
    lb: np.ndarray,
    q: np.ndarray,
    c: np.ndarray,
    b: int,
    saturated_first: bool,
) -> np.ndarray:
    """The labels a dive keeps: half the best bounds, half the closest to violating.

    Labels that already violate (saturated, :func:`_saturate`) either come first in
    the second half, the better bound first, or are left to the first half; which
    gives the better incumbent depends on the model, so phase 1 dives both ways.
    """
    half = max(1, b // 2)
    by_bound = keep[np.argsort(lb[keep], kind="stable")[:half]]
    proxy = c[keep] + np.asarray(space.dist)[q[keep]]
    if not saturated_first:
        proxy = np.where(np.isinf(c[keep]), -math.inf if space.con_up else math.inf, proxy)
    by_con = keep[np.lexsort((lb[keep], -proxy if space.con_up else proxy))[:half]]
    chosen = np.zeros(q.size, dtype=bool)  # the union, in label order
    chosen[by_bound] = True
    chosen[by_con] = True
    return np.flatnonzero(chosen)


def _kept(
    space: SearchSpace,
    q: np.ndarray,
    o: np.ndarray,
    c: np.ndarray,
    lb: np.ndarray,
    cut: np.ndarray,
    lane: np.ndarray,
    beam: int | None,
    saturated_first: bool,
) -> tuple[np.ndarray, bool]:
    """The labels of a level worth going on with: under their cut (the incumbent, which
    may have improved, and their lane's threshold), not dominated at their state within
    their lane, and within their lane's beam; and whether the beam kept all of them."""
    keep: np.ndarray = np.nonzero(lb < cut)[0]
    lanes = int(lane.max(initial=0)) + 1
    at = q[keep] if lanes == 1 else q[keep] * lanes + lane[keep]  # a state of one lane
    keep = keep[_pareto(at, o[keep], c[keep], space.con_up)]
    if beam is None or keep.size <= beam:
        return keep, True
    if lanes == 1:
        return _beam(space, keep, lb, q, c, beam, saturated_first), False
    parts = [keep[lane[keep] == g] for g in range(lanes)]
    kept = [_beam(space, x, lb, q, c, beam, saturated_first) if x.size > beam else x for x in parts]
    out: np.ndarray = np.sort(np.concatenate(kept))
    return out, all(x.size <= beam for x in parts)


def _cheapest_leaf(
    space: SearchSpace,
    q: np.ndarray,
    o: np.ndarray,
    c: np.ndarray,
    leaf: np.ndarray,
    best: float,
    thresholds: np.ndarray,
    lane: np.ndarray,
    hits: np.ndarray,
) -> tuple[float, int] | None:
    """The least completed objective below ``best`` among the leaves whose completed path
    violates the constraint, and its label; None if no leaf has one. Marks in ``hits`` the
    lanes with such a leaf below their threshold (``thresholds``: per lane; ``lane``: each
    label's)."""
    li = np.nonzero(leaf)[0]
    if not li.size:
        return None
    to, tc = space.tails(q[li])
    lo = aggregate_arrays(space.obj_max, o[li], to)
    lc = aggregate_arrays(space.con_max, c[li], tc)
    bad = _truth(space.satisfies(lc, space.bp.bound))
    hits[lane[li[bad & (lo < thresholds[lane[li]])]]] = True
    bad &= lo < best
    if not bad.any():
        return None
    j = int(np.argmin(np.where(bad, lo, math.inf)))
    return float(lo[j]), int(li[j])


def _least(parts: list[tuple[np.ndarray, ...]]) -> float:
    """The least lower bound (the 6th array) of the children made so far."""
    return min((float(part[5].min()) for part in parts if part[5].size), default=math.inf)


# ----------------------------------------------------------------------------- engine
def level_search(space: SearchSpace, limits: Budget | None = None) -> EngineOutcome:
    """Optimum, counterexample and ρ*, exactly; under a budget (states, seconds, bytes of
    memory), proven bounds on both."""
    t0 = time.perf_counter()
    stats = Stats(engine="levels")
    budget = (limits or Budget()).search(getattr(space.cm, "capacity_bytes", None))
    by_values = _by_values(space, budget, stats, t0)
    if by_values is not None:
        return by_values
    bounds = LevelBounds(space)
    if bounds.exact:
        stats.extra["bound_states"] = bounds.reachable
    # phase 1: dives for an incumbent, then the exact pass below it
    upper, at, lower, stopped = _dives(space, bounds, budget, stats)
    stats.extra["dive_states"] = budget.used
    stats.extra["dive_upper"] = upper if math.isfinite(upper) else None
    cex = None
    if stopped is None and lower >= upper:  # a dive kept every label: it was the exact pass
        stats.extra["dive_exact"] = True
    elif stopped is None:
        upper, at, cex, lower, stopped = _exact_optimum(space, bounds, budget, stats, upper, at)
    cex = cex if cex is not None else _path_of(at)
    stats.extra["optimum_states"] = budget.used
    exact = stopped is None
    # phase 2: ρ*, the largest objective below the optimum
    witness, w_exact, w_value, w_upper = None, False, -math.inf, upper
    greedy = greedy_witness(space, upper) if exact and STATE_WITNESS else None
    if greedy is not None:  # θ* of a max objective decided by the states built (below.py)
        witness, w_value = greedy
        w_upper, w_exact = w_value, True
        stats.extra["witness_by_states"] = True
    elif exact:
        witness, w_value, w_upper, stopped = _representative(space, bounds, budget, stats, upper)
        w_exact = stopped is None
    stats.extra["witness_states"] = budget.used - stats.extra["optimum_states"]
    if not w_exact:
        stats.extra["witness_bounds"] = [w_value, w_upper]  # to_result moves them
    stats.states_expanded = budget.used
    stats.stopped = stopped or "finished"  # type: ignore[assignment]
    stats.seconds = time.perf_counter() - t0
    return EngineOutcome(
        optimum=upper if exact else math.inf,
        lower=upper if exact else lower,
        upper=upper,
        counterexample=cex,
        witness=witness,
        witness_exact=w_exact,
        stats=stats,
    )


def _dives(
    space: SearchSpace, bounds: LevelBounds, budget: SearchBudget, stats: Stats
) -> tuple[float, tuple[_Trail, int, int] | None, float, str | None]:
    """Phase 1's dives: the incumbent, where it was found, a proven lower bound on the
    optimum (−inf unless a dive's beam kept every label, :func:`_optimum_pass`) and why
    they stopped early (None: they finished).

    A first dive ranks the labels that already violate first, a second one below its
    incumbent leaves them to the bounds (``>``/``>=`` constraints, :func:`_beam`); then
    :func:`_tighten` bisects, unless a dive already proved its incumbent the optimum.
    """
    beam = _dive_beam(space)
    upper, at, lower, stopped, _ = _optimum_pass(space, bounds, budget, stats, math.inf, beam)
    if stopped is None and space.con_up and lower < upper:
        best, got, low, stopped, _ = _optimum_pass(space, bounds, budget, stats, upper, beam, False)
        if got is not None and best < upper:
            upper, at = best, got
        lower = max(lower, low)
    if stopped is None and math.isfinite(upper) and lower < upper:
        upper, at, stopped = _tighten(space, bounds, budget, stats, upper, at)
    return upper, at, lower, stopped


def _by_values(
    space: SearchSpace, budget: SearchBudget, stats: Stats, t0: float
) -> EngineOutcome | None:
    """The optimum and θ* by the value table (values.py) where it applies, is at most
    :data:`VALUE_CELLS` cells and fits the budget (states: one a cell; memory: 16 bytes
    a cell); None otherwise (the label passes)."""
    if not isinstance(space, Space) or space.obj_max or not space.con_up:
        return None
    grain = _grain(space)
    layers = plan(space, grain, VALUE_MOVES, VALUE_CELLS)
    if grain is None or layers is None or budget.over(layers.cells):
        return None
    if budget.max_memory is not None and resident_bytes() + 16 * layers.cells > budget.max_memory:
        return None  # the table (8 bytes a cell) and a row's temporaries past the ceiling
    got = value_search(space, grain, layers)
    budget.used += got.cells
    stats.transitions += got.updates
    stats.extra["value_cells"] = got.cells
    stats.extra["optimum_states"] = budget.used
    stats.extra["witness_states"] = 0
    stats.states_expanded = budget.used
    stats.stopped = "finished"
    stats.seconds = time.perf_counter() - t0
    return EngineOutcome(
        optimum=got.optimum,
        lower=got.optimum,
        upper=got.optimum,
        counterexample=got.counterexample,
        witness=got.witness,
        witness_exact=True,
        stats=stats,
    )


def _exact_optimum(
    space: SearchSpace,
    bounds: LevelBounds,
    budget: SearchBudget,
    stats: Stats,
    upper: float,
    at: tuple[_Trail, int, int] | None,
) -> tuple[float, tuple[_Trail, int, int] | None, list[int] | None, float, str | None]:
    """The exact pass below the dives' incumbent ``upper`` (found at ``at``); where the
    compiled pass applies, up to :data:`COMPILED_AFTER` labels, and then that pass.

    Returns the optimum (or incumbent), where the exact pass found it, the compiled pass's
    path when that pass improved on it (else None), a proven lower bound and why it
    stopped early (None: it finished).
    """
    switch = level_compiled.applies(space, bounds) and compiled.available()
    allowed = budget.max_states
    if switch:  # the exact pass first, up to COMPILED_AFTER labels
        cap = budget.used + COMPILED_AFTER
        budget.max_states = cap if allowed is None else min(allowed, cap)
    try:
        best, at2, lower, stopped, _ = _optimum_pass(space, bounds, budget, stats, upper, None)
    finally:
        budget.max_states = allowed
    if at2 is not None:
        upper, at = best, at2
    if not (switch and stopped == "max_states" and (allowed is None or budget.used < allowed)):
        return upper, at, None, lower, stopped
    run = compiled.kernel()
    if run is None:  # numba would not import: the exact pass again, without the cap
        best, at2, lower, stopped, _ = _optimum_pass(space, bounds, budget, stats, upper, None)
        return (
            (best, at2, None, lower, stopped)
            if at2 is not None
            else (upper, at, None, lower, stopped)
        )
    stats.extra["compiled"] = True
    upper, path, lower, stopped = level_compiled.optimum(
        space, bounds, budget, stats, upper, _path_of(at), run
    )
    return upper, at, path, lower, stopped


def _dive_beam(space: SearchSpace) -> int:
    """How many labels a dive for the optimum keeps per level.

    On an explicit model a label costs a lookup, and a wide beam buys a better
    incumbent for the exact pass. On a model unfolded on demand each label the dive
    keeps is a state to unfold (the tracker's step and its attacker's options), and
    the states a dive unfolds above the optimum are the ones the exact pass never
    needs: a narrow beam reaches an incumbent as good in fewer of them
    (docs/performance.md, fifteenth round).
    """
    return BEAM if isinstance(space, Space) else LAZY_BEAM


def _tighten(
    space: SearchSpace,
    bounds: LevelBounds,
    budget: SearchBudget,
    stats: Stats,
    upper: float,
    at: tuple[_Trail, int, int] | None,
) -> tuple[float, tuple[_Trail, int, int] | None, str | None]:
    """Bisect a threshold with more dives while the incumbent is far above the root's bound.

    A dive below threshold T keeps only labels that can still end below T; when it
    finds a violating path the incumbent improves, otherwise T only guides the next try
    (a beam proves nothing). Cheap next to an exact pass that a poor incumbent would widen.
    One dive at a time (an explicit model): after two misses in a row the next dive looks
    just below the incumbent (by the gap the dives aim at) instead of halfway down; when
    it misses too, the dives end. Several side by side (:func:`_dive_lanes`): each round
    looks just below the incumbent U and at L + (U − L)/2, /4, ... (L: the highest
    threshold that missed so far), and the dives end when none of them finds anything.
    """
    root = np.array([space.root], dtype=np.int64)
    low = float(
        bounds.violating_lb(root, np.array([space.root_obj]), np.array([space.root_con]))[0]
    )
    low = max(low, space.root_obj) if math.isfinite(low) else space.root_obj
    lanes = _dive_lanes(space)
    misses = 0  # dives in a row that found nothing (one lane)
    for _ in range(TIGHTEN):
        gap = TIGHT_GAP * max(abs(upper), 1e-12)
        if not upper - low > gap:
            break
        probe = misses == 2 or lanes > 1  # look just below the incumbent
        tries = [upper - gap] if probe else []
        tries += [low + (upper - low) / 2**i for i in range(1, lanes + (not probe))]
        best, got, _, why, hits = _optimum_pass(
            space, bounds, budget, stats, np.array(tries), _dive_beam(space)
        )
        if got is not None and best < upper:
            upper, at, misses = best, got, 0
        if why is not None:
            return upper, at, why
        if got is None and probe:
            break  # nothing better by the gap the dives aim at: the exact pass decides
        missed = [t for t, hit in zip(tries, hits, strict=True) if not hit and t <= upper]
        if missed:
            low, misses = max(low, *missed), misses + 1
    return upper, at, None


def _dive_lanes(space: SearchSpace) -> int:
    """How many dives :func:`_tighten` runs side by side in one pass: one on an explicit
    model; on a model unfolded on demand, where each level's unfolding has a fixed cost
    (about 0.5 ms a batch on a dense scene) that lanes share, :data:`LAZY_LANES`."""
    return 1 if isinstance(space, Space) else LAZY_LANES


def representative(
    space: SearchSpace,
    budget: SearchBudget,
    stats: Stats,
    opt: float,
    suffix: Bounds | None = None,
) -> tuple[list[int] | None, float, float, str | None]:
    """ρ* and θ* below an exact optimum ``opt`` found by another engine (bnb's phase 2).

    Returns the path's transitions, θ*, a proven upper bound on θ* and why it stopped
    early (None: finished). The constraint plays no part (section 5.2: a path below the
    optimum cannot violate), so only suffix bounds are needed (``suffix``: already built).
    """
    try:
        bounds = LevelBounds(space, lagrangian=False, suffix=suffix)
        return _representative(space, bounds, budget, stats, opt)
    except _Stop as stop:  # raised while the bounds were built: nothing found yet
        return None, -math.inf, _witness_cap(space, opt), stop.reason


def _path_of(at: tuple[_Trail, int, int] | None) -> list[int] | None:
    if at is None:
        return None
    trail, level, i = at
    return trail.path(level, i)
