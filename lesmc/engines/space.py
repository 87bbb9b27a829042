"""The search space of one property on one model, as integer arrays.

Both engines work on this: the states reachable under the attack window, each
transition's contribution to the objective and to the constraint measure, and
(optionally) exact suffix bounds. Every path measure is an aggregate, sum or
max, of non-negative per-step contributions, so it never decreases along a
path; this is what makes best-first search and dominance pruning exact.
"""

from __future__ import annotations

import math
import operator
from collections.abc import Callable
from dataclasses import dataclass

import numpy as np

from lesmc.language.semantics import BoundMeasure, BoundProperty
from lesmc.model.lts import LTS

_OPS: dict[str, Callable[[float, float], bool]] = {
    ">": operator.gt,
    ">=": operator.ge,
    "<": operator.lt,
    "<=": operator.le,
}


@dataclass
class CompiledModel:
    """A model's arrays, independent of any property (compile once, check many)."""

    ids: list[str]
    index: dict[str, int]
    step: np.ndarray  # (n,) int
    S: np.ndarray  # (n, d) state estimates
    P: np.ndarray | None  # (n, d, d) covariances or None
    halted: np.ndarray  # (n,) bool
    ptr: np.ndarray  # (n+1,) CSR offsets into the transition arrays, rank order per state
    dst: np.ndarray  # (m,) int
    payoff: np.ndarray  # (m,) own payoff
    rank: np.ndarray  # (m,) int
    combined: np.ndarray  # (m,) Eq. 5, strict: payoffs of lower-ranked siblings
    obs: list[str | None]
    original: np.ndarray  # (e+1,) state indices

    @classmethod
    def from_lts(cls, model: LTS) -> CompiledModel:
        states = sorted(model.states(), key=lambda st: (st.step, st.id))
        ids = [st.id for st in states]
        index = {sid: i for i, sid in enumerate(ids)}
        ptr = [0]
        dst: list[int] = []
        payoff: list[float] = []
        rank: list[int] = []
        combined: list[float] = []
        obs: list[str | None] = []
        for st in states:
            out = model.out(st.id)
            for t in out:
                dst.append(index[t.dst])
                payoff.append(t.payoff)
                rank.append(t.rank)
                combined.append(math.fsum(o.payoff for o in out if o.rank < t.rank))
                obs.append(t.obs)
            ptr.append(len(dst))
        has_p = all(st.P is not None for st in states)
        return cls(
            ids=ids,
            index=index,
            step=np.array([st.step for st in states], dtype=np.int64),
            S=np.array([st.s for st in states], dtype=float),
            P=np.array([st.P for st in states], dtype=float) if has_p else None,
            halted=np.array([st.halted for st in states], dtype=bool),
            ptr=np.array(ptr, dtype=np.int64),
            dst=np.array(dst, dtype=np.int64),
            payoff=np.array(payoff, dtype=float),
            rank=np.array(rank, dtype=np.int64),
            combined=np.array(combined, dtype=float),
            obs=obs,
            original=np.array([index[q] for q in model.original], dtype=np.int64),
        )


def deviations(cm: CompiledModel, norm: float, components: tuple[int, ...]) -> np.ndarray:
    """dist(ρ_k, ρ̃_k) = ||s_k − s̃_k||_p of every state against the original (Eq. 4)."""
    ref = cm.S[cm.original[cm.step]]
    diff = (cm.S - ref)[:, list(components)]
    out: np.ndarray = np.linalg.norm(diff, ord=norm, axis=1)
    return out


def location_trace(cm: CompiledModel, components: tuple[int, ...]) -> np.ndarray:
    """τ = tr(Σ_ll) of every state (Eq. 12) over the given components."""
    assert cm.P is not None
    idx = list(components)
    out: np.ndarray = np.trace(cm.P[:, idx][:, :, idx], axis1=1, axis2=2)
    return out


@dataclass
class Space:
    """One property's search space: allowed transitions and their contributions.

    ``adj_ptr``/``adj`` list, per state, the transitions an attacked path may
    take (all of them when the entered step is in the window, else only the
    rank-minimal one; minus those the monitor forbids), in rank order.
    """

    cm: CompiledModel
    bp: BoundProperty
    dist: np.ndarray
    adj_ptr: np.ndarray
    adj: np.ndarray
    c_obj: np.ndarray  # per transition
    c_con: np.ndarray
    root: int
    root_obj: float
    root_con: float
    satisfies: Callable[[float, float], bool]

    @property
    def obj_max(self) -> bool:
        return self.bp.objective.aggregate == "max"

    @property
    def con_max(self) -> bool:
        return self.bp.constraint.aggregate == "max"

    @property
    def con_up(self) -> bool:
        """True when a larger constraint value brings a path closer to violating."""
        return self.bp.op in (">", ">=")

    def violates(self, con: float) -> bool:
        """The constraint holds for this value: the path is in P+ (breaks the system)."""
        return self.satisfies(con, self.bp.bound)

    def is_leaf(self, q: int) -> bool:
        return bool(self.cm.step[q] >= self.bp.end or self.cm.halted[q])

    def successors(self, q: int) -> np.ndarray:
        return self.adj[self.adj_ptr[q] : self.adj_ptr[q + 1]]

    def tail(self, q: int) -> tuple[float, float]:
        """Contributions of the steps after a leaf q: +inf deviation after a halt."""
        h = int(self.cm.step[q])
        return _tail(self.bp.objective, h, self.bp.end), _tail(self.bp.constraint, h, self.bp.end)

    def agg(self, is_max: bool, acc: float, c: float) -> float:
        return max(acc, c) if is_max else acc + c


def _tail(m: BoundMeasure, h: int, end: int) -> float:
    if h >= end or m.source == "payoff":
        return 0.0
    return math.inf if m.hi > h else 0.0


def contributions(
    cm: CompiledModel, m: BoundMeasure, dist: np.ndarray, bp: BoundProperty
) -> np.ndarray:
    """Each transition's contribution to measure ``m`` (entering step k = step(dst))."""
    k = cm.step[cm.dst]
    inside = (k >= m.lo) & (k <= m.hi)
    if m.source == "payoff":
        return np.where(inside, cm.combined * m.weight, 0.0)
    return np.where(inside, dist[cm.dst], 0.0)


def build_space(cm: CompiledModel, bp: BoundProperty) -> Space:
    """Compile a bound property against a compiled model."""
    dist = deviations(cm, bp.norm, bp.components)
    m = len(cm.dst)
    src = np.repeat(np.arange(len(cm.ids)), np.diff(cm.ptr))
    k = cm.step[cm.dst] if m else np.zeros(0, dtype=np.int64)
    in_window = (k >= bp.l) & (k <= bp.u)
    first = np.zeros(m, dtype=bool)
    first[cm.ptr[:-1][np.diff(cm.ptr) > 0]] = True  # rank-minimal transition of each state
    allowed = in_window | first
    if bp.monitor_components is not None:
        tau = location_trace(cm, bp.monitor_components)
        rise = tau[cm.dst] > tau[src] * (1.0 + bp.monitor_tolerance) + 1e-300
        allowed &= ~((k >= bp.l) & rise)
    adj = np.nonzero(allowed)[0]
    counts = np.bincount(src[adj], minlength=len(cm.ids)) if m else np.zeros(len(cm.ids), int)
    adj_ptr = np.concatenate([[0], np.cumsum(counts)]).astype(np.int64)
    c_obj = contributions(cm, bp.objective, dist, bp)
    c_con = contributions(cm, bp.constraint, dist, bp)
    # the common prefix: steps 0..l−1 follow the original path
    obj = _initial(bp.objective, dist, cm)
    con = _initial(bp.constraint, dist, cm)
    for kk in range(1, bp.l):
        q0, q1 = int(cm.original[kk - 1]), int(cm.original[kk])
        t = _edge(cm, q0, q1)
        obj = _agg(bp.objective, obj, float(c_obj[t]))
        con = _agg(bp.constraint, con, float(c_con[t]))
    return Space(
        cm=cm,
        bp=bp,
        dist=dist,
        adj_ptr=adj_ptr,
        adj=adj,
        c_obj=c_obj,
        c_con=c_con,
        root=int(cm.original[bp.l - 1]),
        root_obj=obj,
        root_con=con,
        satisfies=_OPS[bp.op],
    )


def _initial(m: BoundMeasure, dist: np.ndarray, cm: CompiledModel) -> float:
    if m.source == "dist" and m.lo == 0:
        return float(dist[cm.original[0]])
    return 0.0


def _agg(m: BoundMeasure, acc: float, c: float) -> float:
    return max(acc, c) if m.aggregate == "max" else acc + c


def _edge(cm: CompiledModel, q0: int, q1: int) -> int:
    lo, hi = int(cm.ptr[q0]), int(cm.ptr[q0 + 1])
    hits = np.nonzero(cm.dst[lo:hi] == q1)[0]
    return lo + int(hits[0])
