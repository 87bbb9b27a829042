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
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from typing import Any, Protocol

import numpy as np

from lesmc.language.semantics import BoundMeasure, BoundProperty
from lesmc.model.lts import LTS
from lesmc.tracking.monitor import alarm, tau

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
    return deviation((cm.S - ref)[:, list(components)], norm)


def location_trace(cm: CompiledModel, components: tuple[int, ...]) -> np.ndarray:
    """τ = tr(Σ_ll) of every state (Eq. 12) over the given components."""
    assert cm.P is not None
    return tau(cm.P, components)


class SearchSpace(Protocol):
    """What the engines and reports need: the explicit :class:`Space` or the lazy one."""

    bp: BoundProperty
    cm: Any  # per-state and per-transition sequences, named as in CompiledModel
    dist: Any
    c_obj: Any
    c_con: Any
    root: int
    root_obj: float
    root_con: float

    @property
    def obj_max(self) -> bool: ...

    @property
    def con_max(self) -> bool: ...

    @property
    def con_up(self) -> bool: ...

    def violates(self, con: float) -> bool: ...

    def agg(self, is_max: bool, acc: float, c: float) -> float: ...

    def is_leaf(self, q: int) -> bool: ...

    def successors(self, q: int) -> Sequence[int] | np.ndarray: ...

    def tail(self, q: int) -> tuple[float, float]: ...

    def entering(self, q0: int, q1: int) -> int: ...


class SpaceOps:
    """Operations shared by the explicit :class:`Space` and the on-the-fly one (lazy.py)."""

    bp: BoundProperty
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

    def agg(self, is_max: bool, acc: float, c: float) -> float:
        return max(acc, c) if is_max else acc + c

    def tail_at(self, h: int) -> tuple[float, float]:
        """Contributions of the steps after a leaf at step h: +inf deviation after a halt."""
        return _tail(self.bp.objective, h, self.bp.end), _tail(self.bp.constraint, h, self.bp.end)


@dataclass
class Space(SpaceOps):
    """One property's search space on an explicit model: allowed transitions, contributions.

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

    def is_leaf(self, q: int) -> bool:
        return bool(self.cm.step[q] >= self.bp.end or self.cm.halted[q])

    def successors(self, q: int) -> np.ndarray:
        return self.adj[self.adj_ptr[q] : self.adj_ptr[q + 1]]

    def tail(self, q: int) -> tuple[float, float]:
        return self.tail_at(int(self.cm.step[q]))

    def entering(self, q0: int, q1: int) -> int:
        """The transition from q0 to q1."""
        return _edge(self.cm, q0, q1)


def _tail(m: BoundMeasure, h: int, end: int) -> float:
    if h >= end or m.source == "payoff":
        return 0.0
    return math.inf if m.hi > h else 0.0


def contributions(
    m: BoundMeasure, k: np.ndarray, combined: np.ndarray, dist_dst: np.ndarray
) -> np.ndarray:
    """Contributions to measure ``m`` of transitions entering steps ``k``."""
    inside = (k >= m.lo) & (k <= m.hi)
    if m.source == "payoff":
        return np.where(inside, combined * m.weight, 0.0)
    return np.where(inside, dist_dst, 0.0)


def alarms(
    bp: BoundProperty, k: np.ndarray, tau_src: np.ndarray, tau_dst: np.ndarray
) -> np.ndarray:
    """Transitions on which the monitor Γ fires (Eq. 13): τ rises on a step in l..end."""
    out: np.ndarray = (k >= bp.l) & alarm(tau_src, tau_dst, bp.monitor_tolerance)
    return out


def deviation(diff: np.ndarray, norm: float) -> np.ndarray:
    """‖·‖_p of each row (Eq. 4)."""
    out: np.ndarray = np.linalg.norm(diff, ord=norm, axis=-1)
    return out


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
        allowed &= ~alarms(bp, k, tau[src], tau[cm.dst])
    adj = np.nonzero(allowed)[0]
    counts = np.bincount(src[adj], minlength=len(cm.ids)) if m else np.zeros(len(cm.ids), int)
    adj_ptr = np.concatenate([[0], np.cumsum(counts)]).astype(np.int64)
    c_obj = contributions(bp.objective, k, cm.combined, dist[cm.dst])
    c_con = contributions(bp.constraint, k, cm.combined, dist[cm.dst])
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
