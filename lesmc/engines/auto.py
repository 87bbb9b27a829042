"""Engine ``auto``: one of the exact engines per instance, chosen from the space's shape.

The rule (docs/engines.md, "auto"; measured by benchmarks/bench_auto.py, docs/performance.md,
issue 62) looks only at what a space is, never at a trial run:

* a space unfolded on demand (a scene): ``levels``, whose batches per step share the
  unfolding's fixed costs (docs/performance.md, fifteenth round);
* an explicit model with a **max** objective (``dist.max``, resilience): ``bnb``. Its
  best-first order stops at the first violating leaf it pops, where ``levels`` pays for
  its bounds, dives and a breadth-first pass over every level: 2-8x ``levels``' time on
  the random layered models;
* any other explicit model (sums: robustness, knapsacks): ``levels``, whose Lagrangian
  bounds, value table and compiled pass decide sums with a constraint to pass
  (5-50x ``bnb`` on knapsacks; about even on robustness).

Small trees are enumerated before either runs, as for every engine that does not walk
every path (engines/check.py, the probe). The engine chosen is ``stats.extra["auto"]``.
"""

from __future__ import annotations

from lesmc.common.budget import Budget
from lesmc.engines.bnb import branch_and_bound
from lesmc.engines.levels import level_search
from lesmc.engines.result import EngineOutcome
from lesmc.engines.space import SearchSpace, Space


def choose(space: SearchSpace) -> str:
    """The engine ``auto`` runs on ``space``: ``bnb`` for an explicit model with a max
    objective, ``levels`` otherwise (the module's docstring says why)."""
    if isinstance(space, Space) and space.obj_max:
        return "bnb"
    return "levels"


def auto_search(space: SearchSpace, limits: Budget | None = None) -> EngineOutcome:
    """The chosen engine's search (:func:`choose`), reported as ``auto``'s."""
    chosen = choose(space)
    search = branch_and_bound if chosen == "bnb" else level_search
    out = search(space, limits)
    out.stats.engine = "auto"
    out.stats.extra["auto"] = chosen
    return out
