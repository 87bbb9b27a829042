"""What the label passes of ``levels`` share: the optimum's (levels.py) and θ*'s (meet.py).

A label is a partial path (its state, objective and constraint so far); a level holds
the labels at one step, and a :class:`Trail` their parents, to read paths back.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

from lesmc.common.budget import SearchBudget
from lesmc.engines.result import Stats
from lesmc.engines.space import SearchSpace

#: Labels expanded per slice: the clock and the budgets are checked between slices.
SLICE = 16_384
#: Labels kept per level by the beam dives (the optimum's, on an explicit model, and θ*'s).
BEAM = 256


#: Relative slack on bounds summed in another order than a path's own value.
SLACK = 1e-9


class Stop(Exception):
    """A budget ran out."""

    def __init__(self, reason: str) -> None:
        super().__init__(reason)
        self.reason = reason


@dataclass
class Trail:
    """Every label's state, parent (index in the previous level) and entering transition."""

    q: list[np.ndarray] = field(default_factory=list)
    parent: list[np.ndarray] = field(default_factory=list)
    t: list[np.ndarray] = field(default_factory=list)

    def add(self, q: np.ndarray, parent: np.ndarray, t: np.ndarray) -> int:
        self.q.append(q)
        self.parent.append(parent)
        self.t.append(t)
        return len(self.q) - 1

    def path(self, level: int, i: int) -> list[int]:
        """Transitions from the root to label i of ``level``."""
        out = []
        while level > 0:
            out.append(int(self.t[level][i]))
            i = int(self.parent[level][i])
            level -= 1
        out.reverse()
        return out


def expand(
    space: SearchSpace, q: np.ndarray, budget: SearchBudget, stats: Stats
) -> tuple[np.ndarray, np.ndarray]:
    """The allowed transitions out of labels ``q`` (all at one step): label index, transition."""
    why = budget.over(int(q.size))
    if why is not None:
        raise Stop(why)
    budget.used += int(q.size)
    idx, t = space.successors_batch(q)
    stats.transitions += int(t.size)
    return idx, t


def slice_size(space: SearchSpace) -> int:
    """Labels expanded between two looks at the budgets: fewer where unfolding is slow."""
    size = getattr(space, "slice_size", None)
    return SLICE if size is None else min(SLICE, int(size()))


def joined(parts: list[tuple[np.ndarray, ...]]) -> tuple[np.ndarray, ...]:
    """The slices' arrays, each kind concatenated; one slice (a level's usual case) as it
    is: its arrays are fresh, and copying six of them a level cost a small search up to 15%."""
    if len(parts) == 1:
        return parts[0]
    return tuple(np.concatenate(kind) for kind in zip(*parts, strict=True))


def grain(space: SearchSpace) -> float | None:
    """g when every objective contribution (and the root value) is an integer multiple of
    g; None otherwise. Then no sum objective lies strictly between opt − g and opt."""
    vals = known(space)
    vals = vals[np.isfinite(vals)]
    vals = np.r_[vals, space.root_obj if math.isfinite(space.root_obj) else 0.0]
    if vals.size == 0 or np.abs(vals).max() >= 2.0**52:
        return None
    if not np.all(vals == np.round(vals)):
        return None
    g = int(np.gcd.reduce(np.abs(vals).astype(np.int64)))
    return float(g) if g > 0 else None


def known(space: SearchSpace) -> np.ndarray:
    """The objective contributions of the transitions built so far."""
    return np.asarray(space.c_obj)[: space.cm.n_transitions]


def truth(x: object) -> np.ndarray:
    """A comparison's result as a boolean array."""
    out: np.ndarray = np.asarray(x).astype(bool)
    return out


def lo(x: np.ndarray | float) -> np.ndarray:
    """Lower bounds made safe against rounding: a − slack·max(1, |a|); ±inf and nan as
    they are (the scale is capped at 1e300, so an infinite a never meets inf − inf)."""
    a = np.asarray(x, dtype=float)
    out: np.ndarray = a - SLACK * np.minimum(np.maximum(np.abs(a), 1.0), 1e300)
    return out


def hi(x: np.ndarray | float) -> np.ndarray:
    """Upper bounds made safe against rounding (see :func:`lo`)."""
    a = np.asarray(x, dtype=float)
    out: np.ndarray = a + SLACK * np.minimum(np.maximum(np.abs(a), 1.0), 1e300)
    return out
