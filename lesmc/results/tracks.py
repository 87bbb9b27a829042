"""Every attacked track of a built model and how each property judges it (Table 3).

A track is a path from the initial state to the last step (or to a halt). In
a model from ``lesmc build`` alternatives exist only inside the attack window,
so these are exactly the attacked tracks of Figure 9c. Their measures come
from the engines' search space (lesmc/engines/space.py), that is from the
semantics kernel: Eq. 5's combined payoffs, Eq. 4's deviations, the monitor's
cuts (Eq. 13). Nothing here is a second copy of an equation.
"""

from __future__ import annotations

import itertools
from dataclasses import dataclass

import numpy as np

from lesmc.engines.space import Space
from lesmc.model import kernel
from lesmc.model.arrays import ArrayModel, reference_states

#: Components and norm of the track table's deviations: the position (Eq. 4 with p = 2).
POSITION = (0, 1)


@dataclass(frozen=True)
class Track:
    """One path: its states and the transitions entering states 1.. (model indices)."""

    states: tuple[int, ...]
    transitions: tuple[int, ...]


@dataclass(frozen=True)
class Judged:
    """A track seen through one property: its measures, whether it breaks the system,
    where the monitor cuts it, whether it attacks only inside the property's window."""

    objective: float
    constraint: float
    violates: bool
    alarms: tuple[int, ...]
    admissible: bool


def count_paths(cm: ArrayModel) -> int:
    """Number of root-to-leaf paths (dynamic programming over the DAG, last step first)."""
    paths = np.ones(cm.n_states, dtype=object)
    for k in sorted(set(cm.step.tolist()), reverse=True):
        for q in np.flatnonzero(cm.step == k).tolist():
            lo, hi = int(cm.ptr[q]), int(cm.ptr[q + 1])
            if hi > lo:
                paths[q] = sum(paths[int(d)] for d in cm.dst[lo:hi].tolist())
    return int(paths[cm.initial])


def track_of(cm: ArrayModel, states: tuple[int, ...]) -> Track:
    """The track through ``states`` (consecutive states joined by their first transition)."""
    ts = tuple(cm.edge(a, b) for a, b in itertools.pairwise(states))
    return Track(states, ts)


def enumerate_tracks(
    cm: ArrayModel, limit: int, first: list[tuple[int, ...]] | None = None
) -> list[Track]:
    """Up to ``limit`` tracks, depth first in rank order; ``first`` are always included.

    Listed in tree order (sorted by their state sequences' ids).
    """
    found: list[tuple[int, ...]] = []
    seen: set[tuple[int, ...]] = set()
    for p in first or []:
        if p not in seen:
            seen.add(p)
            found.append(p)
    stack: list[tuple[int, ...]] = [(cm.initial,)]
    while stack and len(found) < limit:
        path = stack.pop()
        lo, hi = int(cm.ptr[path[-1]]), int(cm.ptr[path[-1] + 1])
        if hi == lo:
            if path not in seen:
                seen.add(path)
                found.append(path)
            continue
        for d in reversed(cm.dst[lo:hi].tolist()):  # rank order when popped
            stack.append((*path, int(d)))
    found.sort(key=lambda p: [cm.state_id(q) for q in p])
    return [track_of(cm, p) for p in found]


def complete(cm: ArrayModel, states: tuple[int, ...]) -> tuple[int, ...]:
    """A path that stops at a property's end, extended with unattacked steps to the model's end."""
    out = list(states)
    while int(cm.ptr[out[-1] + 1]) > int(cm.ptr[out[-1]]):
        out.append(int(cm.dst[cm.ptr[out[-1]]]))
    return tuple(out)


def payoff(cm: ArrayModel, track: Track, window: tuple[int, int]) -> float:
    """The track's combined payoff (Eq. 5) summed over ``window`` (Eq. 8)."""
    return kernel.exact_sum(
        float(cm.combined[t])
        for k, t in enumerate(track.transitions, start=1)
        if window[0] <= k <= window[1]
    )


def deviations(
    cm: ArrayModel, track: Track, components: tuple[int, ...] | None = None, norm: float = 2.0
) -> np.ndarray:
    """dist.at(k) of a track against the original path, k = 0..end (Eq. 4); inf after a halt.

    ``components``: default the position (the first two components, or the only one)."""
    if components is None:
        components = POSITION[: len(cm.components)]
    out = np.full(cm.end + 1, np.inf)
    states = np.array(track.states[: cm.end + 1], dtype=np.int64)
    ref = reference_states(cm)[: len(states)]
    out[: len(states)] = kernel.deviation((cm.S[states] - ref)[:, list(components)], norm)
    return out


def judge(space: Space, track: Track) -> Judged:
    """``track`` through the property of ``space``: the kernel's contributions from step 0,
    aggregated to the property's end, then the tail after a halt (docs/semantics.md)."""
    bp, cm = space.bp, space.cm
    ts = [t for t in track.transitions if int(cm.step[cm.dst[t]]) <= bp.end]
    q0 = track.states[0]
    d0 = float(space.dist[q0])
    n0 = 0.0 if space.near is None else float(space.near[q0])
    obj = kernel.initial_value(bp.objective, d0, n0)
    con = kernel.initial_value(bp.constraint, d0, n0)
    for t in ts:
        obj = kernel.aggregate(space.obj_max, obj, float(space.c_obj[t]))
        con = kernel.aggregate(space.con_max, con, float(space.c_con[t]))
    last = int(cm.dst[ts[-1]]) if ts else track.states[0]
    t_obj, t_con = space.tail(last)
    obj = kernel.aggregate(space.obj_max, obj, t_obj)
    con = kernel.aggregate(space.con_max, con, t_con)
    alarms = () if space.cut is None else tuple(int(cm.step[cm.dst[t]]) for t in ts if space.cut[t])
    admissible = all(
        bp.l <= int(cm.step[cm.dst[t]]) <= bp.u for t in ts if t != int(cm.ptr[cm.src[t]])
    )
    return Judged(obj, con, bool(space.violates(con)), alarms, admissible)
