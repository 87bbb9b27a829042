"""Engine ``bnb``: exact best-first branch and bound with dominance at shared states.

Phase 1 finds the optimum: labels (partial paths) are popped in order of a
lower bound on their final objective; the first complete path that violates
the constraint is optimal. Phase 2, the representative path ρ* (the largest
objective below the optimum), is levels' search (levels.representative): one
ρ* algorithm for both engines. Both measures only grow along a path (space.py), so

* prefix value ⊕ suffix bound is a valid bound (⊕ is + or max);
* at a shared state, a label whose objective is no worse and whose constraint
  value is no less favourable dominates another: every completion of the
  second is matched by the same completion of the first.

For a max-aggregate the "effective" value max(value, smallest suffix) is what
a completion can still see, so dominance compares effective values. Suffix
bounds come from one dynamic programme over the reachable sub-DAG, which is
linear in the model (not in the number of paths).
"""

from __future__ import annotations

import heapq
import math
import time
from dataclasses import dataclass

from lesmc.common.budget import Budget, SearchBudget
from lesmc.engines.bounds import Bounds, suffix_bounds
from lesmc.engines.result import EngineOutcome, Stats
from lesmc.engines.space import SearchSpace, Space


@dataclass
class _Label:
    """A partial path: accumulated values, its state and a link to its parent."""

    obj: float
    con: float
    q: int
    parent: _Label | None
    t: int  # transition entering q (−1 at the root)
    complete: bool = False


class _Budget(SearchBudget):
    """bnb counts an expansion first, then asks whether it may be made."""

    stopped = "finished"

    def spend(self) -> bool:
        """Count one expansion; False once a budget is exhausted."""
        self.used += 1
        why = self.over()
        if why is not None:
            self.stopped = why
            return False
        return True


#: Expansions between two looks at the process's memory (one look reads /proc, ~10 µs).
_MEMORY_EVERY = 64


def branch_and_bound(
    space: SearchSpace, budget: Budget | None = None, use_bounds: bool = True
) -> EngineOutcome:
    """Optimum, counterexample and representative path, exactly (or bounds if a budget ran out)."""
    t0 = time.perf_counter()
    stats = Stats(engine="bnb")
    b = budget or Budget()
    search = _Budget(
        b.max_states,
        b.seconds_left(),
        b.max_memory,
        getattr(space.cm, "capacity_bytes", None),
        _MEMORY_EVERY,
    )
    bounds = suffix_bounds(space) if use_bounds and isinstance(space, Space) else None
    if bounds is not None:
        stats.extra["bound_states"] = bounds.states
    opt, lower, upper, cex = _optimum(space, bounds, search, stats)
    stats.extra["optimum_states"] = search.used
    exact = search.stopped == "finished"
    witness, w_exact = None, False
    if exact:  # phase 2, ρ*: the same search as levels' (docs/engines.md)
        from lesmc.engines.levels import representative

        witness, w_value, w_upper, why = representative(space, search, stats, opt, bounds)
        w_exact = why is None
        if not w_exact:
            search.stopped = why or "finished"
            stats.extra["witness_bounds"] = [w_value, w_upper]  # to_result moves them
        stats.extra["witness_states"] = search.used - stats.extra["optimum_states"]
    stats.states_expanded = search.used
    stats.stopped = search.stopped  # type: ignore[assignment]
    stats.seconds = time.perf_counter() - t0
    return EngineOutcome(
        optimum=opt if exact else math.inf,
        lower=lower,
        upper=upper,
        counterexample=_transitions(cex),
        witness=witness,
        witness_exact=w_exact,
        stats=stats,
    )


def _optimum(
    space: SearchSpace, b: Bounds | None, budget: _Budget, stats: Stats
) -> tuple[float, float, float, _Label | None]:
    """Phase 1: best-first on the lower bound of the objective."""
    cm = space.cm
    con_up = space.con_up
    obj_mx, con_mx = space.obj_max, space.con_max
    best_con: dict[int, float] = {}  # per state, best effective constraint value popped so far
    heap: list[tuple[float, int, _Label]] = []
    tick = 0
    upper, incumbent = math.inf, None

    def push(lab: _Label) -> None:
        nonlocal tick, upper, incumbent
        if lab.complete or space.is_leaf(lab.q):
            lab = _completed(space, lab)
            if not space.violates(lab.con):
                return  # in P−: phase 2's business
            if lab.obj < upper:
                upper, incumbent = lab.obj, lab
            key = lab.obj
        else:
            bound = lab.obj if b is None else _bound_key(space, b, lab)
            if bound is None or bound > upper:
                return
            key = bound
        tick += 1
        heapq.heappush(heap, (key, tick, lab))

    push(_Label(space.root_obj, space.root_con, space.root, None, -1))
    while heap:
        key, _, lab = heapq.heappop(heap)
        if lab.complete:
            return lab.obj, lab.obj, lab.obj, lab
        q = lab.q
        eff = _effective(con_mx, lab.con, None if b is None else b.con_min[q])
        prev = best_con.get(q)
        if prev is not None and (prev >= eff if con_up else prev <= eff):
            continue  # dominated: an earlier label here has no larger effective objective
        best_con[q] = eff
        if not budget.spend():
            return math.inf, key, upper, incumbent
        for t in space.successors(q):
            stats.transitions += 1
            push(
                _Label(
                    space.agg(obj_mx, lab.obj, float(space.c_obj[t])),
                    space.agg(con_mx, lab.con, float(space.c_con[t])),
                    int(cm.dst[t]),
                    lab,
                    int(t),
                )
            )
    return math.inf, math.inf, math.inf, None


#: Relative slack on suffix bounds: they are summed in another order than a path's own
#: value, so rounding may differ in the last bits; a looser bound stays exact.
_SLACK = 1e-9


def _completed(space: SearchSpace, lab: _Label) -> _Label:
    """A label at a leaf with the rest of its path (the unattacked tail) added."""
    if lab.complete:
        return lab
    to, tc = space.tail(lab.q)
    return _Label(
        space.agg(space.obj_max, lab.obj, to),
        space.agg(space.con_max, lab.con, tc),
        lab.q,
        lab.parent,
        lab.t,
        True,
    )


def _bound_key(space: SearchSpace, b: Bounds, lab: _Label) -> float | None:
    """The least objective any completion of ``lab`` can reach (its heap key), or None
    when no completion can violate the constraint (or the state is dead)."""
    q = lab.q
    if not b.alive[q]:
        return None
    if space.con_up:
        reach = _hi(space.agg(space.con_max, lab.con, b.con_max[q]))
    else:
        reach = _lo(space.agg(space.con_max, lab.con, b.con_min[q]))
    if not space.violates(reach):
        return None
    return _lo(space.agg(space.obj_max, lab.obj, b.obj_min[q]))


def _lo(x: float) -> float:
    """A lower bound made safe against rounding."""
    return x - _SLACK * max(1.0, abs(x)) if math.isfinite(x) else x


def _hi(x: float) -> float:
    """An upper bound made safe against rounding."""
    return x + _SLACK * max(1.0, abs(x)) if math.isfinite(x) else x


def _effective(is_max: bool, value: float, least_suffix: float | None) -> float:
    if is_max and least_suffix is not None:
        return max(value, least_suffix)
    return value


def _transitions(lab: _Label | None) -> list[int] | None:
    if lab is None:
        return None
    out = []
    while lab is not None and lab.t >= 0:
        out.append(lab.t)
        lab = lab.parent
    out.reverse()
    return out
