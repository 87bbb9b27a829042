"""The optimum and θ* of small integer sums by one table of objective values per level.

On an explicit layered space whose objective is a sum of non-negative multiples of a
grain g and whose constraint is a sum that must rise past its bound (the knapsack
class, paper section 5.2), a path's objective is one of few values v·g. Per level and
state, ``table[row, v]`` holds the largest constraint value of the paths that reach the
state with objective v·g (−inf: none). A larger constraint value dominates at the same
state and objective (what follows adds the same to both, and violating is monotone in
it), so the table keeps every path that matters, and it is exact:

* the optimum is the least completed objective of a leaf cell whose completed
  constraint violates (only the cell's largest constraint value needs testing);
* θ* is the largest completed objective below the optimum of any leaf cell (a path
  below the optimum cannot violate, section 5.2).

A level is one ``np.maximum`` per transition over the previous row, shifted by the
transition's v: a few numpy calls per level where the label passes of ``levels`` take
dozens (docs/performance.md, issue 62 third round). ``levels`` runs it first where the
table is small (:func:`plan`), and its passes otherwise.
"""

from __future__ import annotations

import math
from typing import NamedTuple

import numpy as np

from lesmc.engines.space import Space


class ValueAnswer(NamedTuple):
    """The optimum and its path, θ* and its path (None, −inf: no path below the
    optimum; the optimum +inf: no violating path), and the table's cells."""

    optimum: float
    counterexample: list[int] | None
    theta: float
    witness: list[int] | None
    cells: int
    updates: int  # cells written: the moves' row widths summed


class Layers(NamedTuple):
    """The space's levels as the table needs them: per level the states and the row
    width (objective values), per level's moves the source row, target row, shift (in
    grains) and transition."""

    levels: tuple[np.ndarray, ...]
    moves: list[tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]]
    widths: list[int]

    @property
    def cells(self) -> int:
        """The table's size: states × values summed over the levels."""
        return sum(int(lv.size) * w for lv, w in zip(self.levels, self.widths, strict=True))


def plan(space: Space, grain: float | None, max_moves: int, max_cells: int) -> Layers | None:
    """The table's levels and moves, or None where it does not apply: a max objective
    or constraint, a constraint that must fall, no grain, a contribution that is
    negative, not finite or past 2^52, a move that skips a level, more than
    ``max_moves`` moves (each is a numpy call) or more than ``max_cells`` cells (looked
    at level by level, so that a big table is declined after a few levels)."""
    if space.obj_max or space.con_max or not space.con_up or grain is None:
        return None
    return _layers(space, grain, max_moves, max_cells)


def _layers(space: Space, grain: float, max_moves: int, max_cells: int) -> Layers | None:
    """The levels and moves of :func:`plan` (None where it does not apply)."""
    if not (math.isfinite(space.root_obj) and math.isfinite(space.root_con)):
        return None
    if space.root_obj < 0:
        return None
    levels = space.reachable_levels()
    row = np.full(space.cm.n_states, -1, dtype=np.int64)
    depth = np.full(space.cm.n_states, -1, dtype=np.int64)
    for i, lv in enumerate(levels):
        row[lv] = np.arange(lv.size)
        depth[lv] = i
    moves = []
    widths = [int(space.root_obj / grain) + 1]
    total, cells = 0, 0
    for i in range(len(levels)):
        inner, t, seg, _ = space.level_moves(i)
        total += int(t.size)
        cells += int(levels[i].size) * widths[i]
        if total > max_moves or cells > max_cells:
            return None
        co, cc = space.c_obj[t], space.c_con[t]
        if not (np.isfinite(co).all() and np.isfinite(cc).all() and (co >= 0).all()):
            return None
        dst = space.cm.dst[t]
        if t.size and (depth[dst] != i + 1).any():
            return None  # a move to a state of another level: not layered
        src = np.repeat(inner, np.diff(seg))
        k = np.rint(co / grain).astype(np.int64)
        moves.append((row[src], row[dst], k, t))
        if i + 1 < len(levels):
            widths.append(widths[-1] + int(k.max(initial=0)))
    if widths[-1] * grain >= 2.0**52:
        return None
    return Layers(levels, moves, widths)


def value_search(space: Space, grain: float, layers: Layers) -> ValueAnswer:
    """The optimum and θ* with their paths by the value table (``layers``: :func:`plan`'s)."""
    leaf = space.leaves()
    tables = [np.full((1, layers.widths[0]), -math.inf)]
    tables[0][0, int(space.root_obj / grain)] = space.root_con
    ends: list[tuple[int, np.ndarray, np.ndarray, np.ndarray]] = []  # level, rows, tails
    for i, lv in enumerate(layers.levels):
        here = np.flatnonzero(leaf[lv])
        if here.size:
            to, tc = space.tails(lv[here])
            ends.append((i, here, to, tc))
        if i + 1 == len(layers.levels):
            break
        src, dst, k, t = layers.moves[i]
        prev, width = tables[i], layers.widths[i]
        nxt = np.full((layers.levels[i + 1].size, layers.widths[i + 1]), -math.inf)
        cc = space.c_con[t]
        for j in range(t.size):  # the source row shifted by the move's value, plus its c_con
            view = nxt[dst[j], k[j] : k[j] + width]
            np.maximum(view, prev[src[j]] + cc[j], out=view)
        tables.append(nxt)
    cells = sum(int(np.count_nonzero(tb > -math.inf)) for tb in tables)
    updates = sum(int(m[3].size) * w for m, w in zip(layers.moves, layers.widths, strict=False))
    opt, o_at = _optimum(space, grain, tables, ends)
    theta, w_at = _theta(grain, tables, ends, opt)
    cex = _path(layers, tables, space, o_at, True) if o_at is not None else None
    wit = _path(layers, tables, space, w_at, False) if w_at is not None else None
    return ValueAnswer(opt, cex, theta, wit, cells, updates)


def _optimum(
    space: Space,
    grain: float,
    tables: list[np.ndarray],
    ends: list[tuple[int, np.ndarray, np.ndarray, np.ndarray]],
) -> tuple[float, tuple[int, int, int] | None]:
    """The least completed objective of a violating leaf cell, and the cell (level, row,
    value index); +inf and None when no path violates."""
    best, at = math.inf, None
    for i, rows, to, tc in ends:
        for r, o_tail, c_tail in zip(rows.tolist(), to.tolist(), tc.tolist(), strict=True):
            con = tables[i][r]
            present = con > -math.inf
            with np.errstate(invalid="ignore"):
                bad = present & np.asarray(space.satisfies(con + c_tail, space.bp.bound), bool)
            if not bad.any():
                continue
            v = np.flatnonzero(bad)
            obj = v * grain + o_tail
            j = int(np.argmin(obj))
            if obj[j] < best:
                best, at = float(obj[j]), (i, r, int(v[j]))
    return best, at


def _theta(
    grain: float,
    tables: list[np.ndarray],
    ends: list[tuple[int, np.ndarray, np.ndarray, np.ndarray]],
    opt: float,
) -> tuple[float, tuple[int, int, int] | None]:
    """The largest completed objective below ``opt`` of any leaf cell, and the cell;
    −inf and None when there is none."""
    best, at = -math.inf, None
    for i, rows, to, _ in ends:
        for r, o_tail in zip(rows.tolist(), to.tolist(), strict=True):
            v = np.flatnonzero(tables[i][r] > -math.inf)
            obj = v * grain + o_tail
            ok = obj < opt
            if not ok.any():
                continue
            j = int(np.argmax(np.where(ok, obj, -math.inf)))
            if obj[j] > best:
                best, at = float(obj[j]), (i, r, int(v[j]))
    return best, at


def _path(
    layers: Layers,
    tables: list[np.ndarray],
    space: Space,
    at: tuple[int, int, int],
    largest: bool,
) -> list[int]:
    """The transitions of a path into cell ``at``: through cells that hold the cell's
    constraint value exactly (``largest``: the path that reaches the optimum's cell
    with its largest constraint value), or through any filled cell."""
    i, r, v = at
    out: list[int] = []
    while i > 0:
        src, dst, k, t = layers.moves[i - 1]
        prev, want = tables[i - 1], tables[i][r, v]
        for j in np.flatnonzero(dst == r).tolist():
            u = v - int(k[j])
            if not 0 <= u < prev.shape[1] or prev[src[j], u] == -math.inf:
                continue
            if largest and prev[src[j], u] + space.c_con[t[j]] != want:
                continue
            out.append(int(t[j]))
            r, v = int(src[j]), u
            break
        else:  # pragma: no cover - every filled cell was filled by some move
            raise AssertionError("value table: a filled cell without a source")
        i -= 1
    out.reverse()
    return out
