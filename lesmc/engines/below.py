"""θ* of a max objective by one backward pass over the states built so far (issue 62).

For a max objective (``dist.max``: resilience) the largest objective below the optimum
is a property of the states, not of the labels: a path's objective is the largest of
its contributions, so the best a state can still do below ``opt`` is

    M(q) = max over allowed t = (q, d) with c(t) < opt and M(d) > −inf of max(c(t), M(d))

(a leaf: its tail value if below ``opt``, else −inf; no such t: −inf), and θ* is
max(o_root, M(root)) whenever M(root) > −inf. On a model unfolded on demand a state
not yet expanded is *unknown*: M = +inf there, which makes M an upper bound everywhere
(+inf is above any value) and exact wherever it is finite (no unknown state lies on a
path below ``opt`` from there). After the exact optimum pass every state that a path
below the optimum passes through is expanded (levels._witness_cap), so M(root) is
finite and a greedy descent along M's argmax gives ρ* without a label search.
The proof is in docs/engines.md ("θ* of a max objective by states").
"""

from __future__ import annotations

import math

import numpy as np

from lesmc.engines.lazy import LazySpace
from lesmc.engines.space import SearchSpace, ranges


def _moves(space: SearchSpace, q: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The allowed transitions of the *expanded* states among ``q`` (position in ``q``,
    transition), in order, without expanding any state."""
    if not isinstance(space, LazySpace):
        return space.successors_batch(q)  # an explicit model: every state is built
    cm = space.cm
    lo, hi = cm.out_lo[q], cm.out_hi[q]
    built = lo >= 0
    owner, t = ranges(np.where(built, lo, 0), np.where(built, hi, 0))
    ok = space.allowed_mask()[t]
    return owner[ok], t[ok]


def _expanded(space: SearchSpace) -> np.ndarray:
    """Per state built so far: its successors are built."""
    cm = space.cm
    if not isinstance(space, LazySpace):
        return np.ones(cm.n_states, dtype=bool)
    out: np.ndarray = np.asarray(cm.out_lo) >= 0
    return out


def _values(dst: np.ndarray, c: np.ndarray, m: np.ndarray, opt: float) -> np.ndarray:
    """max(c, M(dst)) per transition where the path can stay below ``opt``, else −inf."""
    md = m[dst]
    with np.errstate(invalid="ignore"):
        out: np.ndarray = np.where((c < opt) & (md > -math.inf), np.maximum(c, md), -math.inf)
    return out


def best_below(space: SearchSpace, opt: float) -> np.ndarray:
    """M(q) of the module's docstring for every state built so far (max objectives only):
    an upper bound on the largest objective contribution of any completion from q that
    stays below ``opt`` (−inf: none does), exact where finite."""
    assert space.obj_max
    if isinstance(space, LazySpace):
        space.sync()  # what another space sharing the model unfolded
    cm = space.cm
    n = int(cm.n_states)
    m = np.full(n, math.inf)
    steps = np.asarray(cm.step)[:n]
    leaf = space.leaves()[:n]
    ends = np.flatnonzero(leaf)
    if ends.size:
        to = space.tails(ends)[0]
        m[ends] = np.where(to < opt, to, -math.inf)
    inner = np.flatnonzero(~leaf & _expanded(space)[:n])
    inner = inner[np.argsort(steps[inner], kind="stable")]  # by step, then index
    cuts = np.flatnonzero(np.diff(steps[inner])) + 1
    c_obj = np.asarray(space.c_obj)
    for qs in reversed(np.split(inner, cuts)):  # successors lie one step later
        owner, t = _moves(space, qs)
        best = np.full(qs.size, -math.inf)
        if t.size:  # owner ascends: one reduceat per step
            first = np.flatnonzero(np.r_[True, owner[1:] != owner[:-1]])
            vals = _values(cm.dst[t], c_obj[t], m, opt)
            best[owner[first]] = np.maximum.reduceat(vals, first)
        m[qs] = best
    return m


def greedy_witness(space: SearchSpace, opt: float) -> tuple[list[int] | None, float] | None:
    """ρ* and θ* (the largest objective below ``opt``) of a max objective, when the states
    built so far decide them: (path, θ*), (None, −inf) when no path ends below ``opt``;
    None when an unknown state could hold a better path (then a search must decide)."""
    if not space.obj_max or not space.root_obj < opt:
        return None
    m = best_below(space, opt)
    root = space.root
    if m[root] == math.inf:
        return None
    if m[root] == -math.inf:
        return None, -math.inf
    path: list[int] = []
    q = root
    c_obj = np.asarray(space.c_obj)
    while not space.is_leaf(q):  # follow M's argmax: M(q) = max(c(t), M(d)) there
        _, t = _moves(space, np.array([q], dtype=np.int64))
        vals = _values(space.cm.dst[t], c_obj[t], m, opt)
        j = int(np.argmax(vals))
        path.append(int(t[j]))
        q = int(space.cm.dst[t[j]])
    return path, max(space.root_obj, float(m[root]))
