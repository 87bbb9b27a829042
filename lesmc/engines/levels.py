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
from collections.abc import Callable
from typing import Any, NamedTuple

import numpy as np

from lesmc.common.budget import Budget, SearchBudget, resident_bytes
from lesmc.engines import compiled
from lesmc.engines.below import greedy_witness
from lesmc.engines.bounds import Bounds, suffix_bounds
from lesmc.engines.labels import BEAM, SLICE
from lesmc.engines.labels import Stop as _Stop
from lesmc.engines.labels import Trail as _Trail
from lesmc.engines.labels import expand as _expand
from lesmc.engines.labels import grain as _grain
from lesmc.engines.labels import hi as _hi
from lesmc.engines.labels import joined as _joined
from lesmc.engines.labels import lo as _lo
from lesmc.engines.labels import slice_size as _slice
from lesmc.engines.labels import truth as _truth
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
#: λ values of the Lagrangian bound.
LAMBDAS = 48
#: :meth:`_Bounds._useful_lambdas` looks at this many states (at most) and constraint values.
LAMBDA_SAMPLE_STATES = 4096
LAMBDA_SAMPLE_VALUES = 33
#: Grid points over [0, B] at which :meth:`_Bounds._best_lambdas` picks each state's λ.
LAMBDA_GRID = 64
#: Levels up to this many labels rank constraint values by a searchsorted (see _pareto).
PARETO_SEARCHSORTED = 1 << 14


#: Labels the exact pass for the optimum expands before the compiled depth-first pass
#: takes over, where it applies (:func:`_compiled_applies`) and numba is installed.
COMPILED_AFTER = 1_000_000

#: the value table (values.py) runs instead of the label passes where it has at most this
#: many cells (states × objective values over the levels; 8 bytes each) ...
VALUE_CELLS = 1 << 23
#: ... and at most this many moves (one numpy call each)
VALUE_MOVES = 4096
#: θ* of a max objective by one backward pass over the states built (below.py) before any
#: witness search; False: the label passes alone (tests compare both).
STATE_WITNESS = True


# ----------------------------------------------------------------------------- bounds
class _Bounds:
    """What can still happen after a label: trivial on a lazy space, exact suffix bounds
    (and Lagrangian ones) on an explicit one."""

    def __init__(
        self, space: SearchSpace, lagrangian: bool = True, suffix: Bounds | None = None
    ) -> None:
        self.space = space
        self.omin = self.omax = self.cmin = self.cmax = None
        self.alive: np.ndarray | None = None
        self.lam: np.ndarray | None = None
        self.h: np.ndarray | None = None  # (n, K): min suffix Σ(c_obj − sλ c_con)
        self.best_k: np.ndarray | None = None  # see _best_lambdas
        self.grain: float | None = None  # every objective a multiple of it (explicit sums)
        if isinstance(space, Space):
            b = suffix if suffix is not None else suffix_bounds(space)
            self.omin, self.omax, self.cmin, self.cmax = b.obj_min, b.obj_max, b.con_min, b.con_max
            self.alive = b.alive
            self.reachable = b.states
            if lagrangian and not space.obj_max and not space.con_max:
                self._lagrangian(space)
            if not space.obj_max:
                self.grain = _grain(space)

    @property
    def exact(self) -> bool:
        return self.omin is not None

    def cut(self, best: float) -> float:
        """Labels whose violating lower bound is not below this cannot beat ``best``.

        On an explicit model whose objective contributions are all multiples of g
        (sums), a better path ends at best − g or lower, so the cut is best − g
        (less a hair, so that a bound equal to best − g is kept).
        """
        g = self.grain
        return best if g is None or not math.isfinite(best) else best - g * (1 - 1e-9)

    def violating_lb(self, q: np.ndarray, o: np.ndarray, c: np.ndarray) -> np.ndarray:
        """A lower bound on the final objective of any *violating* completion; +inf
        where none can violate."""
        sp = self.space
        if self.omin is None:
            return o.copy()
        assert self.alive is not None and self.cmax is not None and self.cmin is not None
        # a dead state's suffix bounds are ±inf: with an infinite label value they give
        # nan, which the `can` mask below replaces by +inf
        with np.errstate(invalid="ignore"):
            lb = _lo(aggregate_arrays(sp.obj_max, o, self.omin[q]))
            if sp.con_up:
                reach = _hi(aggregate_arrays(sp.con_max, c, self.cmax[q]))
            else:
                reach = _lo(aggregate_arrays(sp.con_max, c, self.cmin[q]))
        can = self.alive[q] & _truth(sp.satisfies(reach, sp.bp.bound))
        if self.h is not None and self.lam is not None:
            lb = np.maximum(lb, _lo(o + self._lagrangian_at(q, c)))
        return np.where(can, lb, math.inf)

    def _lagrangian_at(self, q: np.ndarray, c: np.ndarray) -> np.ndarray:
        """max over λ of h[q, λ] + sλ(B − c): a lower bound on the objective still to come
        of a violating completion (each λ alone gives one).

        Where ``best_k`` is built, each label tries only the two λ that are best at the
        grid points around its x = B − min(c, B) (the max over λ is convex in x), not
        every λ: a max over fewer λ is still a valid bound, and nearly as tight.
        """
        assert self.h is not None and self.lam is not None
        sp = self.space
        B = sp.bp.bound
        s = 1.0 if sp.con_up else -1.0
        # past the bound, λ·(B − c) ≤ 0 only weakens the bound; λ = 0 alone is valid there
        cb = np.minimum(c, B) if sp.con_up else c
        with np.errstate(invalid="ignore"):
            x = s * (B - cb)
        finite = bool(np.isfinite(x).all())
        if self.best_k is not None and finite:
            j = np.minimum((x * ((LAMBDA_GRID - 1) / B)).astype(np.int64), LAMBDA_GRID - 2)
            row = q * LAMBDA_GRID + j
            k1, k2 = self.best_k[row], self.best_k[row + 1]
            v1 = self.h[q, k1] + self.lam[k1] * x
            v2 = self.h[q, k2] + self.lam[k2] * x
            best: np.ndarray = np.maximum(v1, v2)
            return best
        lag = np.multiply.outer(x, self.lam)  # (labels × λ)
        lag += self.h[q]
        if not finite:  # only then can inf − inf give nan
            lag[np.isnan(lag)] = -math.inf
        out: np.ndarray = lag.max(axis=1)
        return out

    def _best_lambdas(self) -> np.ndarray | None:
        """best_k[q·G + j]: the λ that maximizes h[q, λ] + λ x_j at G grid points x_j
        spanning [0, B] (``>``/``>=`` constraints with a finite bound B > 0 only, and one
        whose grid step (G − 1)/B is finite: not a subnormal B; None where the table would
        be too big to be worth it)."""
        assert self.h is not None and self.lam is not None
        sp = self.space
        B = sp.bp.bound
        n, k = self.h.shape
        if not (sp.con_up and math.isfinite(B) and B > 0) or n * k * LAMBDA_GRID > 1 << 26:
            return None
        if not math.isfinite((LAMBDA_GRID - 1) / B):  # B subnormal: the exact max instead
            return None
        return _winning_lambdas(self.h, self.lam, np.linspace(0.0, B, LAMBDA_GRID)).ravel()

    def least_lb(self, q: np.ndarray, o: np.ndarray, c: np.ndarray) -> float:
        """The least :meth:`violating_lb` of many labels, in chunks (its λ grid is wide)."""
        out = math.inf
        for a in range(0, q.size, SLICE):
            lb = self.violating_lb(q[a : a + SLICE], o[a : a + SLICE], c[a : a + SLICE])
            out = min(out, float(lb.min(initial=math.inf)))
        return out

    def range(self, q: np.ndarray, o: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Smallest and largest final objective over all completions (dead: +inf, −inf)."""
        sp = self.space
        if self.omin is None:
            return o.copy(), np.full(o.shape, math.inf)
        assert self.omax is not None and self.alive is not None
        lo = _lo(aggregate_arrays(sp.obj_max, o, self.omin[q]))
        hi = _hi(aggregate_arrays(sp.obj_max, o, self.omax[q]))
        return np.where(self.alive[q], lo, math.inf), np.where(self.alive[q], hi, -math.inf)

    def _lagrangian(self, space: Space) -> None:
        """h[q, k] = min over completions of Σ(c_obj − sλ_k c_con), tails included.

        λ runs over a geometric grid spanning the transitions' cost/constraint ratios,
        then over a finer grid around the λ that bounds the root best.
        """
        co, cc = space.c_obj[space.adj], space.c_con[space.adj]
        ok = (cc > 0) & np.isfinite(cc) & np.isfinite(co) & (co > 0)
        if not ok.any() or space.cm.n_states == 0:
            return
        k = max(2, min(LAMBDAS, int(1e7 // max(space.cm.n_states, 1))))
        lo, hi = np.quantile(co[ok] / cc[ok], [0.01, 0.99])
        lam = np.r_[0.0, np.geomspace(lo / 4, hi * 4, k - 1)]
        h = self._suffix_lagrangian(space, lam)
        s = 1.0 if space.con_up else -1.0
        with np.errstate(invalid="ignore"):
            root = h[space.root] + s * lam * (space.bp.bound - space.root_con)
        i = int(np.nanargmax(np.where(np.isnan(root), -math.inf, root)))
        fine = np.linspace(lam[max(i - 1, 0)], lam[min(i + 1, lam.size - 1)], k + 2)[1:-1]
        self.lam = np.r_[lam, fine]
        self.h = np.concatenate([h, self._suffix_lagrangian(space, fine)], axis=1)
        if space.con_up:
            keep = self._useful_lambdas(space)
            self.lam, self.h = self.lam[keep], self.h[:, keep]
        self.best_k = self._best_lambdas()

    def _useful_lambdas(self, space: Space) -> np.ndarray:
        """The λ that give the best bound for some state and some constraint value in
        [0, B] (sampled): every λ gives a valid bound, so dropping the others keeps the
        bound valid; on the knapsack classes a quarter of the grid wins anywhere, and
        each label's bound then costs a quarter as much."""
        assert self.h is not None and self.lam is not None
        h, lam = self.h, self.lam
        states = np.flatnonzero(np.isfinite(h).any(axis=1))
        if states.size > LAMBDA_SAMPLE_STATES:
            states = np.random.default_rng(0).choice(states, LAMBDA_SAMPLE_STATES, replace=False)
        B = space.bp.bound
        if not (math.isfinite(B) and B > 0 and states.size):
            return np.arange(lam.size)
        win = np.zeros(lam.size, dtype=bool)
        win[0] = True  # λ = 0: the plain suffix minimum, kept always
        xs = B - np.linspace(0.0, B, LAMBDA_SAMPLE_VALUES)  # x = B − c
        win[_winning_lambdas(h[states], lam, xs)] = True
        return np.flatnonzero(win)

    @staticmethod
    def _suffix_lagrangian(space: Space, lam: np.ndarray) -> np.ndarray:
        cm = space.cm
        s = 1.0 if space.con_up else -1.0
        leaf = space.leaves()
        h = np.full((cm.n_states, lam.size), math.inf)
        levels = space.reachable_levels()
        for i in reversed(range(len(levels))):
            level = levels[i]
            ends = level[leaf[level]]
            if ends.size:
                to, tc = space.tails(ends)
                with np.errstate(invalid="ignore"):
                    rows = to[:, None] - s * lam[None, :] * tc[:, None]
                h[ends] = np.where(np.isnan(rows), to[:, None], rows)
            inner, t, seg, has = space.level_moves(i)
            if not t.size:
                continue
            vals = (space.c_obj[t] - s * np.outer(space.c_con[t], lam).T).T + h[cm.dst[t]]
            vals = np.where(np.isnan(vals), math.inf, vals)
            h[inner[has]] = np.minimum.reduceat(vals, seg[:-1][has], axis=0)
        return h


def _winning_lambdas(h: np.ndarray, lam: np.ndarray, xs: np.ndarray) -> np.ndarray:
    """(states × x): the index of the λ that maximizes h[q, λ] + λ x at each x (a nan
    from inf − inf counts as −inf); in chunks of states of 4 M values at most."""
    out = np.empty((h.shape[0], xs.size), dtype=np.int64)
    rows = max(1, (1 << 22) // max(1, lam.size * xs.size))
    lx = lam[None, :] * xs[:, None]  # (x, λ)
    exact = bool(np.isfinite(lx).all())  # then no inf − inf (h holds no nan)
    for a in range(0, h.shape[0], rows):
        with np.errstate(invalid="ignore"):
            v = h[a : a + rows, None, :] + lx[None]
        if not exact:
            v[np.isnan(v)] = -math.inf
        out[a : a + rows] = v.argmax(axis=2)
    return out


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
    bounds: _Bounds,
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
    bounds = _Bounds(space)
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
    space: SearchSpace, bounds: _Bounds, budget: SearchBudget, stats: Stats
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
    bounds: _Bounds,
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
    switch = _compiled_applies(space, bounds) and compiled.available()
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
    upper, path, lower, stopped = _compiled_optimum(
        space, bounds, budget, stats, upper, _path_of(at), run
    )
    return upper, at, path, lower, stopped


def _compiled_applies(space: SearchSpace, bounds: _Bounds) -> bool:
    """The compiled pass (compiled.py) searches this space: explicit, objective and
    constraint both sums, a constraint that must rise past a finite bound B > 0 (the
    Lagrangian table with each state's λ per grid point is built)."""
    return (
        isinstance(space, Space)
        and not space.obj_max
        and not space.con_max
        and space.con_up
        and bounds.h is not None
        and bounds.best_k is not None
    )


def _compiled_optimum(
    space: SearchSpace,
    bounds: _Bounds,
    budget: SearchBudget,
    stats: Stats,
    upper: float,
    path: list[int] | None,
    run: Callable[..., Any],
) -> tuple[float, list[int] | None, float, str | None]:
    """The exact optimum below ``upper`` (whose path is ``path``) by the compiled
    depth-first pass, in chunks between which the budgets are looked at.

    Returns the optimum or incumbent, its path, a proven lower bound (the least bound of
    the labels left when it stopped early) and why it stopped (None: it finished).
    """
    model, bound_arrays, scalars = _compiled_arrays(space, bounds)
    depth = int(space.cm.step.max(initial=0)) + 2
    deg = int(np.diff(model[0]).max(initial=1))
    stack = np.zeros(((depth + 1) * max(deg, 1) + 1, 3), dtype=np.int64)
    stack_f = np.zeros(stack.shape)
    stack[0] = (space.root, 0, -1)
    stack_f[0] = (space.root_obj, space.root_con, -math.inf)
    trail = np.zeros(depth, dtype=np.int64)
    best_path = np.zeros(depth, dtype=np.int64)
    state = np.array([1.0, upper, 0.0, 0.0, 0.0])
    arrays = (model, bound_arrays, scalars, stack, stack_f, trail, best_path, state)
    found, expanded = False, 0
    while True:
        why = budget.over(0)
        if why is not None:
            top = int(state[0])
            lower = min(float(state[1]), float(stack_f[:top, 2].min(initial=math.inf)))
            break
        before = state[1]
        left = run(*arrays, compiled.CHUNK)
        found = found or state[1] < before
        expanded += int(state[3])  # the chunk's labels and transitions, counted as they go
        budget.used += int(state[3])
        stats.transitions += int(state[4])
        state[3] = state[4] = 0.0
        if left == 0:
            lower, why = float(state[1]), None
            break
    stats.extra["compiled_states"] = expanded
    out = best_path[: int(state[2])].tolist() if found else path
    return float(state[1]), out, lower, why


def _compiled_arrays(
    space: SearchSpace, bounds: _Bounds
) -> tuple[tuple[np.ndarray, ...], tuple[np.ndarray, ...], tuple[int, float, bool, float]]:
    """compiled.dfs_chunk's ``model``, ``bounds`` and ``scalars`` for this space."""
    assert isinstance(space, Space)
    assert bounds.h is not None and bounds.lam is not None and bounds.best_k is not None
    assert bounds.omin is not None and bounds.cmax is not None and bounds.alive is not None
    cm = space.cm
    leaf = space.leaves()
    tail_obj = np.zeros(cm.n_states)
    tail_con = np.zeros(cm.n_states)
    ends = np.flatnonzero(leaf)
    if ends.size:
        tail_obj[ends], tail_con[ends] = space.tails(ends)
    c_obj = np.asarray(space.c_obj, dtype=float)
    c_con = np.asarray(space.c_con, dtype=float)
    model = (space.adj_ptr, space.adj, cm.dst, c_obj, c_con, leaf, tail_obj, tail_con)
    b = (bounds.omin, bounds.cmax, bounds.alive, bounds.h, bounds.lam, bounds.best_k)
    scalars = (LAMBDA_GRID, float(space.bp.bound), space.bp.op == ">", bounds.grain or 0.0)
    return model, b, scalars


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
    bounds: _Bounds,
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
        bounds = _Bounds(space, lagrangian=False, suffix=suffix)
        return _representative(space, bounds, budget, stats, opt)
    except _Stop as stop:  # raised while the bounds were built: nothing found yet
        return None, -math.inf, _witness_cap(space, opt), stop.reason


def _path_of(at: tuple[_Trail, int, int] | None) -> list[int] | None:
    if at is None:
        return None
    trail, level, i = at
    return trail.path(level, i)
