"""Every attacked path of a built model and its measures (the paper's Table 3).

A path starts at the initial state and follows transitions to the last step
(or a halted state). In a model from ``lesmc build`` alternatives exist only
inside the attack window, so these are exactly the attacked tracks of Figure 9c.
Measures are computed here directly from the states, independently of the
engines (the tests compare the two).
"""

from __future__ import annotations

import itertools
import math
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from lesmc.language.semantics import BoundMeasure, BoundProperty
from lesmc.model import kernel
from lesmc.model.kernel import LOCATION, alarm, tau
from lesmc.model.lts import LTS, Transition


@dataclass(frozen=True)
class TrackPath:
    """One path: its states and entering transitions, and its Table 3 measures."""

    states: tuple[str, ...]
    transitions: tuple[Transition, ...]
    payoff: float  # combined payoff (Eq. 5, summed as Eq. 8) over the window
    dist: tuple[float, ...]  # dist.at(k) for k = 0..end (inf after a halt)

    @property
    def dist_sum(self) -> float:
        return math.fsum(self.dist)

    @property
    def dist_max(self) -> float:
        return max(self.dist)

    @property
    def dist_end(self) -> float:
        return self.dist[-1]

    def labels(self) -> list[str]:
        """Node labels "step-detection" (the paper's Figure 9c); "none": no observation."""
        out = ["0-start"]
        for k, t in enumerate(self.transitions, start=1):
            out.append(f"{k}-{_short(t.obs)}")
        return out


def _short(obs: str | None) -> str:
    if obs is None:
        return "none"
    return obs.split(":")[-1]


@dataclass(frozen=True)
class PathSet:
    """The enumerated paths (up to a cap), and how many exist in all."""

    paths: list[TrackPath]  # in tree order (sorted by states)
    total: int

    @property
    def left_out(self) -> int:
        return self.total - len(self.paths)


def position(model: LTS, sid: str, comps: tuple[int, ...] = (0, 1)) -> np.ndarray:
    """The state's components ``comps`` (those it has; a 1-D state gets y = 0)."""
    s = np.asarray(model.state(sid).s, float)
    out = np.zeros(len(comps))
    for i, c in enumerate(comps):
        if c < len(s):
            out[i] = s[c]
    return out


def count_paths(model: LTS) -> int:
    """Number of root-to-leaf paths (dynamic programming over the DAG)."""
    memo: dict[str, int] = {}
    order = sorted(model.graph.nodes, key=lambda q: -model.state(q).step)
    for q in order:
        succ = list(model.graph.successors(q))
        memo[q] = sum(memo[c] for c in succ) if succ else 1
    return memo[model.initial]


def enumerate_tracks(
    model: LTS,
    window: tuple[int, int],
    limit: int = 20000,
    comps: tuple[int, ...] = (0, 1),
    first: list[tuple[str, ...]] | None = None,
) -> PathSet:
    """Up to ``limit`` paths, depth first in rank order; ``first`` paths are always included.

    The result lists them in tree order (sorted by their state sequences).
    """
    found: list[tuple[str, ...]] = []
    seen: set[tuple[str, ...]] = set()
    for p in first or []:
        if p not in seen:
            seen.add(p)
            found.append(p)
    stack: list[tuple[str, ...]] = [(model.initial,)]
    while stack and len(found) < limit:
        path = stack.pop()
        out = model.out(path[-1])
        if not out:
            if path not in seen:
                seen.add(path)
                found.append(path)
            continue
        for t in reversed(out):  # rank order when popped
            stack.append((*path, t.dst))
    paths = [_measure(model, p, window, comps) for p in sorted(found)]
    return PathSet(paths, count_paths(model))


def _measure(
    model: LTS, states: tuple[str, ...], window: tuple[int, int], comps: tuple[int, ...]
) -> TrackPath:
    trans = [model.graph.edges[a, b]["transition"] for a, b in itertools.pairwise(states)]
    l, u = window
    payoff = math.fsum(
        model.combined_payoff(t) for k, t in enumerate(trans, start=1) if l <= k <= u
    )
    dist = deviations(model, states, comps, 2.0)
    return TrackPath(tuple(states), tuple(trans), payoff, tuple(dist.tolist()))


def deviations(
    model: LTS, states: Sequence[str], components: tuple[int, ...], norm: float
) -> np.ndarray:
    """dist.at(k) of a path against the original path, k = 0..end (Eq. 4); inf after a halt."""
    out = np.full(model.end + 1, np.inf)
    for k, sid in enumerate(states):
        diff = position(model, sid, components) - position(model, model.original[k], components)
        out[k] = float(kernel.deviation(diff, norm))
    return out


def tau_series(model: LTS, path: TrackPath, components: tuple[int, ...] = LOCATION) -> np.ndarray:
    """τ (Eq. 12) along a path, nan where a state has no covariance."""
    vals = []
    for sid in path.states:
        P = model.state(sid).P
        idx = [c for c in components if P is not None and c < len(P)]  # a 1-D model has no y
        vals.append(math.nan if P is None else float(tau(np.asarray(P), idx)))
    return np.array(vals)


@dataclass(frozen=True)
class Judged:
    """A path seen through one property: objective, constraint, breaks the system, monitored out."""

    path: TrackPath
    objective: float
    constraint: float
    violates: bool
    alarmed: bool
    admissible: bool  # attacks (non-minimal transitions) only inside the property's window


def judge(model: LTS, path: TrackPath, bp: BoundProperty) -> Judged:
    """Evaluate a property's measures on one path with the semantics kernel."""
    dist = deviations(model, path.states, bp.components, bp.norm)
    pays = np.zeros(model.end + 1)
    for k, t in enumerate(path.transitions, start=1):
        pays[k] = model.combined_payoff(t)

    steps = np.arange(1, model.end + 1)

    def value(m: BoundMeasure) -> float:
        """The measure along the path: the kernel's contributions, aggregated step by step."""
        acc = kernel.initial_value(m, float(dist[0]))
        for c in kernel.contributions(m, steps, pays[1:], dist[1:]).tolist():
            acc = kernel.aggregate(m.aggregate == "max", acc, c)
        return float(acc)

    alarmed = False
    if bp.monitor_components is not None:
        taus = tau_series(model, path, bp.monitor_components)
        ks = np.arange(max(bp.l, 1), min(len(taus), bp.end + 1))
        fired = alarm(taus[ks - 1], taus[ks], bp.monitor_tolerance)
        if bp.monitor_except_original:  # alarms where the unattacked track alarms too: excused
            orig = TrackPath(tuple(model.original), (), 0.0, ())
            excused = kernel.original_alarms(
                tau_series(model, orig, bp.monitor_components), bp.monitor_tolerance
            )
            fired &= ~excused[ks]
        alarmed = bool(fired.any())
    admissible = all(
        bp.l <= k <= bp.u
        for k, t in enumerate(path.transitions, start=1)
        if t.rank > min(o.rank for o in model.out(t.src))
    )
    con = value(bp.constraint)
    return Judged(
        path, value(bp.objective), con, kernel.compare(bp.op, con, bp.bound), alarmed, admissible
    )
