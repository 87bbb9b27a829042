"""The ``levels`` engine's exact pass handed to the compiled depth-first pass
(lesmc/engines/compiled.py, numba) once it has spent ``levels.COMPILED_AFTER`` labels:
which spaces it searches, the arrays it reads, and its chunks, between which the budgets
are looked at (docs/engines.md, docs/performance.md "a compiled loop")."""

from __future__ import annotations

import math
from collections.abc import Callable
from typing import Any

import numpy as np

from lesmc.common.budget import SearchBudget
from lesmc.engines import compiled
from lesmc.engines.level_bounds import LAMBDA_GRID, LevelBounds
from lesmc.engines.result import Stats
from lesmc.engines.space import SearchSpace, Space


def applies(space: SearchSpace, bounds: LevelBounds) -> bool:
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


def optimum(
    space: SearchSpace,
    bounds: LevelBounds,
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
    model, bound_arrays, scalars = _arrays(space, bounds)
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


def _arrays(
    space: SearchSpace, bounds: LevelBounds
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
