"""Exact suffix bounds: what any completion of a state can still add to each measure.

Both measures only grow along a path (space.py), so prefix value ⊕ suffix
bound (⊕ is + or max) bounds every completion. One dynamic programme over the
reachable sub-DAG computes them, linear in the model (not in its paths); bnb
and levels both start from it.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from lesmc.engines.space import Space
from lesmc.model.kernel import aggregate_arrays


@dataclass(frozen=True)
class Bounds:
    """Per state: smallest/largest suffix aggregate of objective and constraint.

    ``alive`` is False for states from which no admissible complete path exists
    (every continuation is cut by the monitor).
    """

    obj_min: np.ndarray
    obj_max: np.ndarray
    con_min: np.ndarray
    con_max: np.ndarray
    alive: np.ndarray
    states: int


def suffix_bounds(space: Space) -> Bounds:
    """Exact suffix min/max of both measures over the states reachable from the root.

    Vectorised level by level (a transition always enters the next step): one
    forward pass collects the reachable states of each step, one backward pass
    reduces each state's allowed transitions with ``minimum/maximum.reduceat``.
    """
    cm = space.cm
    n = cm.n_states
    leaf = space.leaves()
    levels = space.reachable_levels()
    inf = math.inf
    omin, omax = np.full(n, inf), np.full(n, -inf)
    cmin, cmax = np.full(n, inf), np.full(n, -inf)
    alive = np.zeros(n, dtype=bool)
    for i in reversed(range(len(levels))):
        level = levels[i]
        leaves = level[leaf[level]]
        if leaves.size:
            to, tc = space.tails(leaves)
            omin[leaves] = omax[leaves] = to
            cmin[leaves] = cmax[leaves] = tc
            alive[leaves] = True
        inner, t, seg, has = space.level_moves(i)
        if not t.size:
            continue
        d = cm.dst[t]
        ok = alive[d]
        o_mx, c_mx = space.obj_max, space.con_max
        co, cc = space.c_obj[t], space.c_con[t]
        starts = seg[:-1][has]
        q = inner[has]
        alive[q] = np.add.reduceat(ok.astype(np.int64), starts) > 0
        for arr, c, bound, is_max, red, fill in (
            (omin, co, omin, o_mx, np.minimum, inf),
            (omax, co, omax, o_mx, np.maximum, -inf),
            (cmin, cc, cmin, c_mx, np.minimum, inf),
            (cmax, cc, cmax, c_mx, np.maximum, -inf),
        ):
            vals = np.where(ok, aggregate_arrays(is_max, c, bound[d]), fill)
            arr[q] = red.reduceat(vals, starts)
    return Bounds(omin, omax, cmin, cmax, alive, int(sum(len(lv) for lv in levels)))
