"""Engine ``enumerate``: the paper's Algorithms 1 and 2, faithfully.

Algorithm 1 unfolds the tree of every attacked path from ρ_{l−1} (no sharing
of states between paths: a tree, as in Figure 3) and runs each to the end;
Algorithm 2 splits the paths into P+ (constraint holds: the system fails) and
P−, takes the optimum over P+ and the representative path ρ* over P−. The
tree is expanded level by level with numpy, one array entry per tree node, so
the reference engine is also a fast baseline. On a scene the model is unfolded
on demand as the levels are reached (lesmc/engines/lazy.py), so a budget stops
it with the paths finished so far (``unknown`` with bounds), as the other engines.
"""

from __future__ import annotations

import math
import time
from collections.abc import Callable
from dataclasses import dataclass, replace

import numpy as np

from lesmc.common.budget import Budget, SearchBudget
from lesmc.engines.result import EngineOutcome, Stats
from lesmc.engines.space import Space
from lesmc.language.semantics import BoundProperty
from lesmc.model.kernel import COMPARE, aggregate_arrays


def enumerate_paths(space: Space, budget: Budget | None = None) -> EngineOutcome:
    """Run Algorithms 1 and 2 on ``space``; stop early (unknown) past a budget."""
    return enumerate_many([space], budget)[0]


def tree_key(bp: BoundProperty) -> tuple[object, ...]:
    """What fixes the tree of attacked paths: the window, the end and the monitor. Properties
    with the same key on one model share their tree (:func:`enumerate_many`)."""
    return (
        bp.l,
        bp.u,
        bp.end,
        bp.monitor_components,
        bp.monitor_kind,
        bp.monitor_parameter,
        bp.monitor_window,
        bp.monitor_except_original,
    )


def enumerate_many(
    spaces: list[Space], budget: Budget | None = None, max_work: int | None = None
) -> list[EngineOutcome]:
    """Algorithms 1 and 2 for several properties of one model whose trees are the same
    (:func:`tree_key`): the tree is walked once, each property's measures aggregated
    along it, then Algorithm 2 per property (one unfolding per scene, issue 31);
    ``max_work``: a cap on the unfolding's work since the walk began (:func:`_over_work`)."""
    t0 = time.perf_counter()
    first = spaces[0]
    assert all(tree_key(s.bp) == tree_key(first.bp) and s.cm is first.cm for s in spaces)
    search = (budget or Budget()).search()
    cap = None if max_work is None else WorkCap(_work(first), max_work)
    search.used = 1  # the root
    cm = first.cm
    # one level of the tree: state, accumulated objective/constraint (per property),
    # parent, entering transition
    node = np.array([first.root], dtype=np.int64)
    obj = [np.array([s.root_obj]) for s in spaces]
    con = [np.array([s.root_con]) for s in spaces]
    levels: list[tuple[np.ndarray, np.ndarray]] = []  # (parent index, transition) per level
    done: list[list[tuple[int, np.ndarray, np.ndarray, np.ndarray]]] = [[] for _ in spaces]
    # finished paths per property: (level, node index, objective, constraint)
    stopped, transitions = "finished", 0
    shared = {"tree_shared_by": len(spaces)} if len(spaces) > 1 else {}
    level = 0
    rate = 0.0  # seconds per expanded node of the last level's array work
    while node.size:
        leaf = first.leaves(node)
        if leaf.any():
            idx = np.nonzero(leaf)[0]
            for i, s in enumerate(spaces):
                done[i].append((level, idx, *_completed(s, node[idx], obj[i][idx], con[i][idx])))
        live = np.nonzero(~leaf)[0]
        why = _unfold(first, node[live], search, cap)  # looks at its budget between slices
        started = time.perf_counter()  # the rate is the level's array work's, unfolding aside
        why = why or _would_overrun(search, rate, int(live.size))
        if why is not None:
            stopped = why
            break
        # children: for each live node, each allowed transition in rank order
        owner, trans = first.successors_batch(node[live])
        total = int(trans.size)
        why = search.over(total)
        if why is not None:
            stopped = why
            break
        parent = live[owner]
        levels.append((parent, trans))
        for i, s in enumerate(spaces):
            if i:  # the first space unfolded: the others read the new transitions too
                s.sync()
            obj[i] = aggregate_arrays(s.obj_max, obj[i][parent], s.c_obj[trans])
            con[i] = aggregate_arrays(s.con_max, con[i][parent], s.c_con[trans])
        node = cm.dst[trans]
        search.used += total
        transitions += total
        level += 1
        rate = (time.perf_counter() - started) / max(int(live.size), 1)
    stats = [Stats("enumerate", search.used, transitions, extra=dict(shared)) for _ in spaces]
    return [_outcome(s, done[i], levels, stats[i], stopped, t0) for i, s in enumerate(spaces)]


def _outcome(
    space: Space,
    done: list[tuple[int, np.ndarray, np.ndarray, np.ndarray]],
    levels: list[tuple[np.ndarray, np.ndarray]],
    stats: Stats,
    stopped: str,
    t0: float,
) -> EngineOutcome:
    """One property's Algorithm 2 over the paths it finished on the shared tree."""
    stats.stopped = stopped  # type: ignore[assignment]
    all_obj, all_con, done_ref = _finished(done)
    stats.paths = int(all_obj.size)
    out = _algorithm2(space, all_obj, all_con, done_ref, levels, stats)
    stats.seconds = time.perf_counter() - t0
    return out


def _finished(
    done: list[tuple[int, np.ndarray, np.ndarray, np.ndarray]],
) -> tuple[np.ndarray, np.ndarray, list[tuple[int, np.ndarray]]]:
    """Every finished path's objective and constraint, and where it ended (level, node)."""
    if not done:
        return np.zeros(0), np.zeros(0), []
    obj = np.concatenate([d[2] for d in done])
    con = np.concatenate([d[3] for d in done])
    return obj, con, [(level, idx) for level, idx, _, _ in done]


def _completed(
    space: Space, leaves: np.ndarray, obj: np.ndarray, con: np.ndarray
) -> tuple[np.ndarray, np.ndarray]:
    """The objective and constraint of the paths ending at ``leaves``, tails included."""
    t_obj, t_con = space.tails(leaves)
    return aggregate_arrays(space.obj_max, obj, t_obj), aggregate_arrays(space.con_max, con, t_con)


def _would_overrun(search: SearchBudget, rate: float, nodes: int) -> str | None:
    """Expanding ``nodes`` at the last level's ``rate`` seconds a node would end past the
    deadline: stop before it (a level is one piece of array work, not interruptible), so
    that a timeout ends in a result and not in the hard alarm."""
    if search.deadline is None or rate <= 0.0:
        return None
    return "timeout" if time.perf_counter() + rate * nodes > search.deadline else None


#: Before bnb or levels searches an explicit model, :func:`exhaustive_probe` tries to
#: enumerate its tree of attacked paths within this many nodes: below it, walking every
#: path in a few array operations per level (about 40 M nodes a second) costs less than
#: computing bounds (0.3-1.4 s of fixed costs on the dense benchmark's models;
#: lesmc/engines/check.py; docs/engines.md, benchmarks/bench_storm.py).
SMALL_TREE = 1 << 21


@dataclass(frozen=True)
class Probe:
    """What :func:`exhaustive_probe` found: the answer, or the budgets left for a search."""

    outcome: EngineOutcome | None
    left: Budget  #: what the search still has
    states: int  #: tree nodes the probe expanded
    seconds: float


def exhaustive_probe(space: Space, engine: str, budget: Budget) -> Probe:
    """Enumerate an explicit model's tree of attacked paths when it has at most
    :data:`SMALL_TREE` nodes (:func:`tree_bound` without counting, else :func:`tree_size`,
    counted exactly before any is made; not
    under a ``max_states`` below the tree: a budget that small is left whole to the search
    and its anytime bounds).

    The outcome when it finished, reported as ``engine``'s with
    ``stats.extra["exhaustive"]`` = the tree's nodes; otherwise (a larger tree, or the
    clock ran out) what is left of the budget for the search.
    """
    t0 = time.perf_counter()
    limit = SMALL_TREE if budget.max_states is None else min(SMALL_TREE, budget.max_states)
    if limit <= 0 or (tree_bound(space) > limit and tree_size(space, limit) > limit):
        return Probe(None, budget, 0, time.perf_counter() - t0)
    out = enumerate_paths(space, budget)
    used, seconds = out.stats.states_expanded, time.perf_counter() - t0
    if out.stats.stopped == "finished":
        out.stats.engine = engine
        out.stats.extra["exhaustive"] = used
        out.stats.seconds = seconds  # the count included
        return Probe(out, budget, used, seconds)
    states = None if budget.max_states is None else max(1, budget.max_states - used)
    return Probe(None, replace(budget, max_states=states), used, seconds)


def probe_then(
    space: Space, engine: str, budget: Budget, search: Callable[[Space, Budget], EngineOutcome]
) -> EngineOutcome:
    """:func:`exhaustive_probe`'s answer, or ``search`` with what is left of the budget
    (the probe's states then in ``stats.extra["probe_states"]``, its seconds added)."""
    probe = exhaustive_probe(space, engine, budget)
    if probe.outcome is not None:
        return probe.outcome
    out = search(space, probe.left)
    if probe.states:
        out.stats.extra["probe_states"] = probe.states
        out.stats.seconds += probe.seconds
    return out


def tree_bound(space: Space) -> float:
    """An upper bound on :func:`tree_size` without counting: 1 + D + ... + D^d, with D the
    most allowed transitions out of any state and d the steps from the root to the
    property's end (the count itself costs a tenth to a fifth of enumerating a tree of a
    few thousand nodes; bench_auto.py)."""
    deg = float(np.diff(space.adj_ptr).max(initial=0))
    depth = max(0, int(space.bp.end) - int(space.cm.step[space.root]))
    if deg <= 1:
        return depth + 1.0
    if (depth + 1) * math.log(deg) > 60:
        return math.inf
    return (deg ** (depth + 1) - 1) / (deg - 1)


def tree_size(space: Space, past: float = math.inf) -> float:
    """The nodes of the tree of attacked paths (Algorithm 1's tree: one per path prefix),
    counted without making them: the number of paths into each state, pushed forward
    along the allowed transitions step by step; stops once the count passes ``past``
    (then it is only a lower bound)."""
    cm = space.cm
    src, dst = cm.src[space.adj], cm.dst[space.adj]
    inner = ~space.leaves()[src]  # a path ends at a leaf: nothing leaves it
    src, dst = src[inner], dst[inner]
    step = cm.step[src]
    order = np.argsort(step, kind="stable")
    src, dst, step = src[order], dst[order], step[order]
    cuts = np.flatnonzero(np.diff(step)) + 1
    count = np.zeros(cm.n_states)
    count[space.root] = 1.0
    total = 1.0
    for s_block, d_block in zip(np.split(src, cuts), np.split(dst, cuts), strict=True):
        into = count[s_block]
        total += float(into.sum())
        if total > past:
            break
        np.add.at(count, d_block, into)
    return total


@dataclass(frozen=True)
class WorkCap:
    """A walk's cap on the unfolding's work: ``start``, the model's work when it began;
    ``most``, the work it may add."""

    start: int
    most: int


def _work(space: Space) -> int:
    """The work the model of ``space`` has done unfolding so far (GrowingModel.work: rows
    its expander examined, the same on every run); 0 for an explicit model."""
    return int(getattr(space.cm, "work", 0))


def _over_work(space: Space, cap: WorkCap | None) -> str | None:
    """``max_states`` once the unfolding has done the work ``cap`` allows (:func:`_work`,
    looked at between :func:`_unfold`'s slices, which are counted too: where a walk stops
    is the same on every run, whatever the machine's load), else None."""
    if cap is None or _work(space) - cap.start < cap.most:
        return None
    return "max_states"


def _unfold(
    space: Space, q: np.ndarray, budget: SearchBudget, cap: WorkCap | None = None
) -> str | None:
    """On a model unfolded on demand (lesmc/engines/lazy.py): unfold the distinct states
    of ``q`` in slices of about ``slice_size()`` states (a count: lazy.BATCH_WORK of work),
    looking at the budget and the work cap ``cap`` between slices, so that a deadline
    holds while a large level unfolds; why it stopped, or None.
    An explicit model has nothing to unfold.

    The tree nodes the level makes are counted as its slices unfold (a node of ``q``
    makes one per allowed transition of its state), so that a level past the budget's
    node limit stops within a slice of the limit instead of being unfolded whole first
    (on the joint design with injection a level's unfolding is most of the walk's time).
    """
    size = getattr(space, "slice_size", None)
    if size is None:
        return None
    todo, times = np.unique(q, return_counts=True)
    lo, made = 0, 0
    while lo < todo.size:
        why = budget.over(made) or _over_work(space, cap)
        if why is not None:
            return why
        n = max(1, int(size()))
        owner, _ = space.successors_batch(todo[lo : lo + n])
        made += int(times[lo : lo + n][owner].sum())
        lo += n
    return None


def _algorithm2(
    space: Space,
    obj: np.ndarray,
    con: np.ndarray,
    refs: list[tuple[int, np.ndarray]],
    levels: list[tuple[np.ndarray, np.ndarray]],
    stats: Stats,
) -> EngineOutcome:
    """Optimum over P+, representative path ρ* = argmax obj over P− below the optimum."""
    plus = COMPARE[space.bp.op](con, space.bp.bound)
    finished = stats.stopped == "finished"
    optimum, cex = math.inf, None
    if plus.any():
        i = int(np.flatnonzero(plus)[np.argmin(obj[plus])])
        optimum, cex = float(obj[i]), _path(i, refs, levels)
    below = ~plus & (obj < optimum)
    witness = None
    if below.any():
        i = int(np.flatnonzero(below)[np.argmax(obj[below])])
        witness = _path(i, refs, levels)
    return EngineOutcome(
        optimum=optimum if finished else math.inf,
        lower=optimum if finished else 0.0,
        upper=optimum,
        counterexample=cex,
        witness=witness,
        witness_exact=finished,
        stats=stats,
    )


def _path(
    i: int, refs: list[tuple[int, np.ndarray]], levels: list[tuple[np.ndarray, np.ndarray]]
) -> list[int]:
    """Transitions from the root to the i-th finished path, walking parent links up."""
    level, node = 0, 0
    for lv, idx in refs:
        if i < idx.size:
            level, node = lv, int(idx[i])
            break
        i -= idx.size
    out: list[int] = []
    for lv in range(level - 1, -1, -1):
        parent, trans = levels[lv]
        out.append(int(trans[node]))
        node = int(parent[node])
    out.reverse()
    return out
