"""An optional compiled depth-first pass for the optimum of `levels` (issue 62).

On an explicit model whose objective and constraint are both sums and whose constraint
must rise past its bound (``>``/``>=``: the knapsack's class), :func:`dfs_chunk` searches
depth first with the bounds ``levels`` built (suffix minima and maxima and the Lagrangian
table with each state's two λ per grid point, :class:`level_bounds.LevelBounds`), and improves its
incumbent at every leaf it reaches, where the breadth-first exact pass prunes with the
dives' incumbent down to the last level. numba compiles it (``pip install numba``, the
``fast`` extra) when it is installed; the plain Python function is the same code, which
the tests run without numba. It is imported only by a search that has already spent
:data:`levels.COMPILED_AFTER` labels (docs/performance.md, issue 62), so that verbs which
do not search, and searches that end fast, never pay numba's import (about a second).

:func:`dfs_chunk`'s arguments: ``model`` = (adj_ptr, adj, dst, c_obj, c_con, leaf,
tail_obj, tail_con); ``bounds`` = (omin, cmax, alive, h, lam, best_k) of level_bounds.LevelBounds;
``scalars`` = (the λ grid's size, the bound B, ``>`` (else ``>=``), the grain, 0 for
none); ``stack`` rows (state, depth, entering transition) and ``stack_f`` rows
(objective, constraint, lower bound): the labels left; ``path`` and ``best_path``: the
current path's and the incumbent's transitions by depth; ``state`` = [labels on the
stack, incumbent, its path's length, labels expanded, transitions followed], the last
two counted afresh by each call.
"""

from __future__ import annotations

import importlib
import importlib.util
from collections.abc import Callable
from typing import Any

import numpy as np

#: Transitions one call of the kernel may follow before the budgets are looked at again.
CHUNK = 2_000_000
#: Relative slack on the bounds, as levels._lo.
SLACK = 1e-9

_kernel: Callable[..., Any] | None = None
_tried = False
_found: bool | None = None


def available() -> bool:
    """A kernel can be had: numba is installed (looked up once, not imported), or one is
    set."""
    global _found
    if _tried:
        return _kernel is not None
    if _found is None:
        _found = importlib.util.find_spec("numba") is not None
    return _found


def kernel() -> Callable[..., Any] | None:
    """:func:`dfs_chunk` compiled by numba and cached on disk, or None: without numba, or
    where numba finds no writable place for its cache (then every process would pay the
    compilation, several seconds: the numpy passes decide instead).

    numba keeps the cache in ``NUMBA_CACHE_DIR`` when set, else in the ``__pycache__``
    beside this file when it is writable, else in the user's cache directory
    (``~/.cache/numba``, or under ``XDG_CACHE_HOME``); with none of them writable,
    ``njit(cache=True)`` raises RuntimeError (docs/engines.md, "The compiled depth-first
    pass").
    """
    global _kernel, _tried
    if not _tried:
        _tried = True
        try:
            numba = importlib.import_module("numba")
        except ImportError:
            return None
        try:
            _kernel = numba.njit(cache=True)(dfs_chunk)
        except RuntimeError:  # "cannot cache function ...: no locator available"
            _kernel = None
    return _kernel


def dfs_chunk(
    model: tuple[np.ndarray, ...],
    bounds: tuple[np.ndarray, ...],
    scalars: tuple[int, float, bool, float],
    stack: np.ndarray,
    stack_f: np.ndarray,
    path: np.ndarray,
    best_path: np.ndarray,
    state: np.ndarray,
    limit: int,
) -> int:
    """Go on with a depth-first search for up to ``limit`` transitions; 0 when it ended.

    The arguments are described in the module's docstring (level_compiled._arrays
    makes them). A label is kept while its bound is below the incumbent less the grain
    (the exact pass's cut); the labels left are on the stack.
    """
    adj_ptr, adj, dst, c_obj, c_con, leaf, tail_obj, tail_con = model
    omin, cmax, alive, h, lam, best_k = bounds
    grid, bound, strict, grain = scalars
    off = grain * (1 - 1e-9) if grain > 0 else 0.0
    top, best = int(state[0]), state[1]
    expanded = followed = 0
    while top > 0 and followed < limit:
        top -= 1
        q, depth, o, c = stack[top, 0], stack[top, 1], stack_f[top, 0], stack_f[top, 1]
        if stack_f[top, 2] >= best - off:
            continue  # the incumbent improved since it was pushed
        if depth > 0:
            path[depth - 1] = stack[top, 2]
        if leaf[q]:
            lc = c + tail_con[q]
            if (lc > bound if strict else lc >= bound) and o + tail_obj[q] < best:
                best = o + tail_obj[q]
                best_path[:depth] = path[:depth]
                state[2] = depth
            continue
        expanded += 1
        for i in range(adj_ptr[q + 1] - 1, adj_ptr[q] - 1, -1):  # the first one on top
            t = adj[i]
            d = dst[t]
            followed += 1
            o2, c2 = o + c_obj[t], c + c_con[t]
            reach = c2 + cmax[d]
            reach += SLACK * min(max(abs(reach), 1.0), 1e300)
            if not alive[d] or not (reach > bound if strict else reach >= bound):
                continue
            x = bound - min(c2, bound)
            j = min(int(x * ((grid - 1) / bound)), grid - 2)
            k1, k2 = best_k[d * grid + j], best_k[d * grid + j + 1]
            lb = max(o2 + omin[d], o2 + max(h[d, k1] + lam[k1] * x, h[d, k2] + lam[k2] * x))
            lb -= SLACK * min(max(abs(lb), 1.0), 1e300)
            if lb < best - off:
                stack[top, 0], stack[top, 1], stack[top, 2] = d, depth + 1, t
                stack_f[top, 0], stack_f[top, 1], stack_f[top, 2] = o2, c2, lb
                top += 1
    state[0], state[1] = top, best
    state[3] += expanded
    state[4] += followed
    return top
