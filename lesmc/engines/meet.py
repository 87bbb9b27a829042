"""θ* of ``levels``: the largest objective below the optimum, and its path ρ*.

The representative path ρ* (phase 2 of ``levels``) is an optimisation of its own: the
largest objective below the optimum. A max objective keeps one label per state (the
largest below the optimum); a sum keeps distinct values, pruned by suffix bounds and the
incumbent, and is seeded by a meet-in-the-middle dive against the suffix values of the
last steps (:class:`_SuffixValues`); the exact pass meets a larger table halfway. When
every contribution is a multiple of g, no objective lies strictly between opt − g and
opt, which proves a witness at opt − g optimal at once.
"""

from __future__ import annotations

import math
import time
from typing import Protocol

import numpy as np

from lesmc.common.budget import SearchBudget, resident_bytes
from lesmc.engines import labels
from lesmc.engines.result import Stats
from lesmc.engines.space import SearchSpace, Space
from lesmc.model.kernel import aggregate_arrays


class Ranges(Protocol):
    """What θ*'s passes read of the optimum's bounds (level_bounds.LevelBounds)."""

    #: Reachable states (explicit models only).
    reachable: int

    def range(self, q: np.ndarray, o: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Smallest and largest final objective over all completions."""
        ...


#: Largest table of suffix values the witness dive builds (entries).
SUFFIX_VALUES = 1 << 17

#: ... and the exact pass for θ*, which meets it halfway (see :func:`representative_search`).
EXACT_SUFFIX_VALUES = 1 << 20

#: Most bits (reachable states × objective values below the optimum) of the bit sets
#: of :func:`_theta_by_bits` (256 MB).
REACH_BITS = 1 << 31
#: Most reachable states for which the witness dive builds its suffix table.
SUFFIX_STATES = 50_000

#: Labels a level must have for its time to predict the next, larger level's.
RATE_SAMPLE = 20_000


def witness_cap(space: SearchSpace, opt: float) -> float:
    """An upper bound on θ*: below ``opt`` and, where the values allow, tighter.

    A max objective is one of the contributions (or the root's value), so θ* is at most
    the largest one below ``opt``. On a model unfolded on demand only the transitions
    built so far are known; that suffices, because the exact optimum pass has expanded
    every state a path below ``opt`` passes through (its running value never exceeds
    its final one), so every transition of such a path is built.
    """
    if not math.isfinite(opt):
        return math.inf
    if space.obj_max:
        vals = np.r_[labels.known(space), space.root_obj]
        below = vals[vals < opt]
        return float(below.max()) if below.size else -math.inf
    g = labels.grain(space)
    return opt - g if g is not None else opt


def _witness_pass(
    space: SearchSpace,
    bounds: Ranges,
    budget: SearchBudget,
    stats: Stats,
    opt: float,
    best: float,
    cap: float,
    beam: int | None,
    suffix: _SuffixValues | None = None,
) -> tuple[float, tuple[labels.Trail, int, int, list[int]] | None]:
    """The largest objective below ``opt`` and above ``best``, and where its label is.

    A max objective keeps one label per state (the largest: every completion that
    stays below ``opt`` keeps it largest), a sum each distinct value. Exact without a
    beam or a suffix table; with them a dive.
    """
    trail = labels.Trail()
    root = np.array([space.root], dtype=np.int64)
    trail.add(root, np.array([-1]), np.array([-1]))
    q, o = root, np.array([space.root_obj])
    where: tuple[labels.Trail, int, int, list[int]] | None = None
    cm = space.cm
    rate = 0.0  # seconds per label of sorting, keeping and the next level's leaves
    while q.size and best < cap:
        level = len(trail.q) - 1
        leaf = space.leaves(q)
        found = _largest_leaf(space, q, o, leaf, opt, best)
        if found is not None:
            best, where = found[0], (trail, level, found[1], [])
        live = np.nonzero(~leaf)[0]
        if suffix is not None and live.size and suffix.covers(int(cm.step[q[live[0]]])):
            val, hit = suffix.meet(q[live], o[live], opt, best)
            if hit is not None:
                best, where = val, (trail, level, int(live[hit[0]]), hit[1])
            break
        if not live.size:
            break
        q2, o2, p2, t2 = _witness_children(space, bounds, budget, stats, q, o, live, opt, best)
        why = budget.over(0) or budget.would_pass(rate * q2.size)
        if why is not None:  # a huge level: stop before sorting it (one piece of work)
            raise labels.Stop(why)
        started = time.perf_counter()
        keep = _distinct(q2, o2, space.obj_max)
        if beam is not None and keep.size > beam:
            keep = _witness_beam(space, bounds, keep, q2, o2, min(cap, opt), beam)
        trail.add(q2[keep], p2[keep], t2[keep])
        q, o = q2[keep], o2[keep]
        if q2.size >= RATE_SAMPLE:  # small levels time the overheads, not the sort
            rate = (time.perf_counter() - started) / q2.size
    return best, where


def _largest_leaf(
    space: SearchSpace, q: np.ndarray, o: np.ndarray, leaf: np.ndarray, opt: float, best: float
) -> tuple[float, int] | None:
    """The largest completed objective among the leaves below ``opt`` and above ``best``,
    and its label; None if no leaf has one."""
    if not leaf.any():
        return None
    li = np.nonzero(leaf)[0]
    fo = aggregate_arrays(space.obj_max, o[li], space.tails(q[li])[0])
    ok = (fo < opt) & (fo > best)
    if not ok.any():
        return None
    j = int(np.argmax(np.where(ok, fo, -math.inf)))
    return float(fo[j]), int(li[j])


def _witness_children(
    space: SearchSpace,
    bounds: Ranges,
    budget: SearchBudget,
    stats: Stats,
    q: np.ndarray,
    o: np.ndarray,
    live: np.ndarray,
    opt: float,
    best: float,
) -> tuple[np.ndarray, ...]:
    """The children of labels ``live`` whose completions can end in (best, opt): state,
    objective, parent label, entering transition (expanded slice by slice)."""
    parts: list[tuple[np.ndarray, ...]] = []
    s0 = 0
    while s0 < live.size:
        sl = live[s0 : s0 + labels.slice_size(space)]
        s0 += sl.size
        idx, t = labels.expand(space, q[sl], budget, stats)
        par = sl[idx]
        dst = space.cm.dst[t]
        o2 = aggregate_arrays(space.obj_max, o[par], space.c_obj[t])
        lo, hi = bounds.range(dst, o2)
        # o2 itself is exact and never decreases: o2 >= opt can never end below opt
        keep = (o2 < opt) & (lo < opt) & (hi > best)
        parts.append((dst[keep], o2[keep], par[keep], t[keep]))
    return labels.joined(parts)


def _witness_beam(
    space: SearchSpace,
    bounds: Ranges,
    keep: np.ndarray,
    q: np.ndarray,
    o: np.ndarray,
    target: float,
    beam: int,
) -> np.ndarray:
    """The ``beam`` labels of ``keep`` likeliest to complete near ``target``."""
    lo, hi = bounds.range(q[keep], o[keep])
    with np.errstate(invalid="ignore"):  # inf − inf (no optimum): NaN sorts last
        gap = np.maximum(target - hi, 0.0) + np.maximum(lo - target, 0.0)
        # a max keeps the largest; a sum aims at the middle of what the rest can add
        aim = -o[keep] if space.obj_max else np.abs(target - (lo + hi) / 2)
    out: np.ndarray = keep[np.lexsort((aim, gap))[:beam]]
    return out


def _distinct(q: np.ndarray, o: np.ndarray, obj_max: bool) -> np.ndarray:
    """Labels worth keeping for ρ*: per state the largest (max objective) or each value."""
    if q.size == 0:
        return np.arange(0)
    if obj_max:
        order = np.lexsort((-o, q))
        first = np.concatenate(([True], q[order][1:] != q[order][:-1]))
        return np.asarray(order[first])
    order = np.lexsort((o, q))
    qs, os_ = q[order], o[order]
    first = np.concatenate(([True], (qs[1:] != qs[:-1]) | (os_[1:] != os_[:-1])))
    return np.asarray(order[first])


class _SuffixValues:
    """The distinct sums of objective contributions over every completion of the states of
    the last steps (sum objectives on explicit spaces): a meet-in-the-middle table."""

    def __init__(self, space: Space, budget: SearchBudget, limit: int = SUFFIX_VALUES) -> None:
        self.space = space
        self.budget = budget
        self.start_step: int | None = None
        self.table: dict[int, tuple[np.ndarray, np.ndarray, np.ndarray]] = {}
        self.entries = 0
        self._next = len(space.reachable_levels()) - 1  # the next level to add
        self._pending: dict[int, tuple[np.ndarray, np.ndarray, np.ndarray]] | None = None
        self.grow(limit)

    def grow(self, limit: int) -> None:
        """Add levels, the last steps first, while the table stays within ``limit`` entries
        (a level built that did not fit is kept for a later, larger limit)."""
        levels = self.space.reachable_levels()
        while self._next >= 0:
            why = self.budget.over(0)  # a level of the table is built in one go
            if why is not None:
                raise labels.Stop(why)
            entries = self._pending if self._pending is not None else self._level(self._next)
            self._pending = None
            if not entries:  # a state with a completion the table lacks: it ends here
                self._next = -1
                break
            size = sum(e[0].size for e in entries.values())
            if self.entries + size > limit:
                self._pending = entries
                break
            self.entries += size
            self.table.update(entries)
            self.start_step = int(self.space.cm.step[levels[self._next][0]])
            self._next -= 1

    def _level(self, li: int) -> dict[int, tuple[np.ndarray, np.ndarray, np.ndarray]]:
        """The entries of the states of reachable level ``li`` (empty: some completion
        leaves the table)."""
        space, cm = self.space, self.space.cm
        level = space.reachable_levels()[li]
        leaf = space.leaves(level)
        entries: dict[int, tuple[np.ndarray, np.ndarray, np.ndarray]] = {}
        for q in level[leaf].tolist():
            to = space.tail(int(q))[0]
            entries[q] = (np.array([to]), np.array([-1]), np.array([-1]))
        inner, t, seg, _ = space.level_moves(li)
        for i, q in enumerate(inner.tolist()):
            vs: list[np.ndarray] = []
            ts: list[np.ndarray] = []
            js: list[np.ndarray] = []
            for tt in t[seg[i] : seg[i + 1]].tolist():
                d = int(cm.dst[tt])
                if d not in self.table:
                    return {}
                sub = self.table[d][0]
                vs.append(sub + space.c_obj[tt])
                ts.append(np.full(sub.size, tt))
                js.append(np.arange(sub.size))
            if not vs:
                return {}
            v, tt_, jj = np.concatenate(vs), np.concatenate(ts), np.concatenate(js)
            v, first = np.unique(v, return_index=True)
            entries[q] = (v, tt_[first], jj[first])
        return entries

    def covers(self, step: int) -> bool:
        return self.start_step is not None and step >= self.start_step

    def meet(
        self, q: np.ndarray, o: np.ndarray, opt: float, best: float
    ) -> tuple[float, tuple[int, list[int]] | None]:
        """The largest o + suffix value below ``opt`` and above ``best``, over labels (q, o):
        exact, as each state's table holds every completion's sum. One ``searchsorted`` per
        distinct state (the labels of a state at once)."""
        val, hit = best, None
        states, inverse = np.unique(q, return_inverse=True)
        order = np.argsort(inverse, kind="stable")
        bounds = np.searchsorted(inverse[order], np.arange(states.size + 1))
        for k, qq in enumerate(states.tolist()):
            if (why := self.budget.over(0)) is not None:
                raise labels.Stop(why)
            idx = order[bounds[k] : bounds[k + 1]]
            v, oo = self.table[qq][0], o[idx]
            with np.errstate(invalid="ignore"):
                j = np.searchsorted(v, labels.lo(opt - oo), side="left") - 1
            # rounding: o + v[j] may still reach opt; step down until it is below
            while True:
                bad = (j >= 0) & ~(oo + v[np.maximum(j, 0)] < opt)
                if not bad.any():
                    break
                j = np.where(bad, j - 1, j)
            ok = j >= 0
            if not ok.any():
                continue
            total = np.where(ok, oo + v[np.maximum(j, 0)], -math.inf)
            i = int(np.argmax(total))
            if total[i] > val:
                val, hit = float(total[i]), (int(idx[i]), self._path(qq, int(j[i])))
        return val, hit

    def _path(self, q: int, j: int) -> list[int]:
        out: list[int] = []
        while True:
            _, ts, js = self.table[q]
            t = int(ts[j])
            if t < 0:
                return out
            out.append(t)
            q, j = int(self.space.cm.dst[t]), int(js[j])


def representative_search(
    space: SearchSpace, bounds: Ranges, budget: SearchBudget, stats: Stats, opt: float
) -> tuple[list[int] | None, float, float, str | None]:
    """ρ*: dives (beam, then meet-in-the-middle for sums), then the exact pass.

    Returns the path, θ*, a proven upper bound on θ*, and why it stopped early.
    """
    cap = witness_cap(space, opt)
    best, at = -math.inf, None
    try:
        value, got = _witness_pass(space, bounds, budget, stats, opt, best, cap, labels.BEAM)
        if got is not None:
            best, at = value, got
        tables = (
            isinstance(space, Space)
            and not space.obj_max
            and math.isfinite(opt)
            and bounds.reachable <= SUFFIX_STATES  # the table is built state by state
        )
        suffix = None
        if best < cap and tables:
            assert isinstance(space, Space)
            suffix = _SuffixValues(space, budget)
            if suffix.entries:
                value, got = _witness_pass(
                    space, bounds, budget, stats, opt, best, cap, labels.BEAM, suffix
                )
                if got is not None:
                    best, at = value, got
        if best < cap and isinstance(space, Space):
            # the values every state reaches, as bit sets, where they fit (issue 62)
            bits = _theta_by_bits(space, budget, stats, opt, best)
            if bits is not None:
                stats.extra["witness_bits"] = True
                if bits[1] is not None:
                    return bits[1], bits[0], bits[0], None
                return _witness_path(at), best, best, None
        if best < cap:
            # the exact pass meets a larger table halfway (built only now: the dives above
            # end most searches, docs/performance.md, issue 62)
            exact = None
            if tables:
                assert isinstance(space, Space)
                if suffix is None:
                    suffix = _SuffixValues(space, budget, EXACT_SUFFIX_VALUES)
                else:
                    suffix.grow(EXACT_SUFFIX_VALUES)
                exact = suffix if suffix.entries else None
            value, got = _witness_pass(space, bounds, budget, stats, opt, best, cap, None, exact)
            if got is not None:
                best, at = value, got
        return _witness_path(at), best, best, None
    except labels.Stop as stop:
        return _witness_path(at), best, cap, stop.reason


def _theta_by_bits(
    space: Space, budget: SearchBudget, stats: Stats, opt: float, best: float
) -> tuple[float, list[int] | None] | None:
    """θ* exactly from the objective values each reachable state reaches, one bit set
    (a Python integer, bit v: some path reaches the state with objective v·g) per state:
    a transition of contribution w·g ors its source's set shifted by w into its target's,
    cut to the values below the optimum. θ* is the highest bit of a leaf's set (times g);
    ρ* is read back level by level through sets that hold its prefixes' values. Sums of
    multiples of a grain g only (integer values, then exactly the label passes' sums), where
    every reachable leaf's tail adds 0 (or +inf: never below the optimum), and where the
    sets fit :data:`REACH_BITS` and the memory ceiling.

    Returns (θ*, ρ*) when θ* is above ``best`` (ρ*: its transitions from the root),
    (best, None) when it proves that nothing lies in (best, opt), and None where it does
    not apply.
    """
    g = labels.grain(space)
    if g is None or space.obj_max or not math.isfinite(opt) or not g.is_integer():
        return None
    top = math.ceil(opt / g)  # values v·g below opt: v < top
    levels = space.reachable_levels()
    cells = sum(int(x.size) for x in levels) * top
    if cells > REACH_BITS or (
        budget.max_memory is not None and resident_bytes() + cells // 8 > budget.max_memory
    ):
        return None
    leaf = space.leaves()
    ends = np.concatenate([x[leaf[x]] for x in levels])
    if ends.size:
        to = space.tails(ends)[0]
        if not np.all((to == 0) | (to == math.inf)):
            return None
        ends = ends[to == 0]
    r0 = space.root_obj / g
    if not r0.is_integer():
        return None
    sets = _reached_sets(space, budget, stats, g, top, int(r0))
    value, end = -1, -1
    for q in ends.tolist():
        v = sets.get(q, 0).bit_length() - 1
        if v > value:
            value, end = v, q
    if value < 0 or value * g <= best:
        return best, None
    return value * g, _bits_path(space, sets, end, value, g)


def _reached_sets(
    space: Space, budget: SearchBudget, stats: Stats, g: float, top: int, r0: int
) -> dict[int, int]:
    """:func:`_theta_by_bits`'s sets, level by level from the root's value ``r0``·g (bits
    ``top`` and up cut)."""
    levels = space.reachable_levels()
    mask = (1 << top) - 1
    sets: dict[int, int] = {space.root: (1 << r0) & mask}
    dst = space.cm.dst
    for i in range(len(levels)):
        if (why := budget.over(0)) is not None:
            raise labels.Stop(why)
        inner, t, seg, _ = space.level_moves(i)
        src = np.repeat(inner, np.diff(seg))
        w = space.c_obj[t] / g
        into: set[int] = set()
        for p, d, k in zip(src.tolist(), dst[t].tolist(), w.tolist(), strict=True):
            have = sets.get(p, 0)
            if have and math.isfinite(k) and k < top:
                sets[d] = sets.get(d, 0) | (have << int(k))
                into.add(d)
        for d in into:  # cut once per state, not per transition
            sets[d] &= mask
        budget.used += int(inner.size)
        stats.transitions += int(t.size)
    return sets


def _bits_path(space: Space, sets: dict[int, int], end: int, value: int, g: float) -> list[int]:
    """The transitions of a path from the root to ``end`` with objective ``value``·g, read
    back through the bit sets of :func:`_theta_by_bits` (the first transition in rank
    order whose source reaches the value less its contribution)."""
    levels = space.reachable_levels()
    step = {q: i for i, x in enumerate(levels) for q in x.tolist()}
    dst = space.cm.dst
    out: list[int] = []
    q, v = end, value
    for i in range(step[end] - 1, -1, -1):
        inner, t, seg, _ = space.level_moves(i)
        src = np.repeat(inner, np.diff(seg))
        into = np.flatnonzero(dst[t] == q)
        for j in into.tolist():
            k = int(space.c_obj[t[j]] / g)
            p = int(src[j])
            if v - k >= 0 and (sets.get(p, 0) >> (v - k)) & 1:
                out.append(int(t[j]))
                q, v = p, v - k
                break
    out.reverse()
    return out


def _witness_path(at: tuple[labels.Trail, int, int, list[int]] | None) -> list[int] | None:
    if at is None:
        return None
    trail, level, i, tail = at
    return trail.path(level, i) + tail
