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

Small trees are enumerated first (the probe of engines/check.py, as for ``levels`` and
``bnb``), except on the value table's class (:func:`table_class`) past
:data:`TABLE_TREE` nodes: there ``levels`` decides in a few numpy calls a level what
the probe lists node by node (a knapsack of 20 items: 2 M nodes). The engine chosen is
``stats.extra["auto"]`` (``enumerate`` when the probe answered).
"""

from __future__ import annotations

from lesmc.common.budget import Budget
from lesmc.engines.bnb import branch_and_bound
from lesmc.engines.enumerate import probe_then, tree_bound, tree_size
from lesmc.engines.labels import grain
from lesmc.engines.levels import level_search
from lesmc.engines.result import EngineOutcome
from lesmc.engines.space import SearchSpace, Space

#: On the value table's class, trees past this many nodes are not probed.
TABLE_TREE = 1 << 14


def choose(space: SearchSpace) -> str:
    """The engine ``auto`` searches ``space`` with: ``bnb`` for an explicit model with a
    max objective, ``levels`` otherwise (the module's docstring says why)."""
    if isinstance(space, Space) and space.obj_max:
        return "bnb"
    return "levels"


def table_class(space: Space) -> bool:
    """``levels``' value table may decide this space (engines/values.py): a sum objective
    of multiples of a grain and a sum constraint to rise past its bound."""
    return not space.obj_max and not space.con_max and space.con_up and grain(space) is not None


def probes(space: Space) -> bool:
    """Enumerate a small tree first: everywhere but on the value table's class past
    :data:`TABLE_TREE` nodes."""
    if not table_class(space):
        return True
    return tree_bound(space) <= TABLE_TREE or tree_size(space, TABLE_TREE) <= TABLE_TREE


def auto_search(space: SearchSpace, limits: Budget | None = None) -> EngineOutcome:
    """The chosen engine's search (:func:`choose`), after the probe where :func:`probes`
    says so; reported as ``auto``'s."""
    budget = limits or Budget()
    chosen = choose(space)
    search = branch_and_bound if chosen == "bnb" else level_search
    if isinstance(space, Space) and probes(space):
        out = probe_then(space, "auto", budget, search)
        if "exhaustive" in out.stats.extra:
            chosen = "enumerate"
    else:
        out = search(space, budget)
    out.stats.engine = "auto"
    out.stats.extra["auto"] = chosen
    return out
