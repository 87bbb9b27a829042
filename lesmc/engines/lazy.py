"""On-the-fly search space: the model of a scene, built only where the engine looks.

``lesmc check SCENE.json SPEC`` does not write the model out: a state's
successors are computed by the tracker the first time the ``bnb`` engine asks
for them (and then kept), so a long attack window costs only what the search
visits. States, transitions and their contributions are computed exactly as
:func:`lesmc.model.builder.build_model` and :func:`lesmc.engines.space.build_space`
do; tests/test_builder.py checks that both give the same answers.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

from lesmc.engines.space import _OPS, SpaceOps, alarms, contributions
from lesmc.language.semantics import BoundProperty
from lesmc.tracking.design import Design, Outcome, TrackerState
from lesmc.tracking.monitor import tau


@dataclass
class GrowingModel:
    """Per-state and per-transition lists named as in CompiledModel, grown on demand."""

    ids: list[str] = field(default_factory=list)
    step: list[int] = field(default_factory=list)
    halted: list[bool] = field(default_factory=list)
    S: list[np.ndarray] = field(default_factory=list)
    tau: list[float] = field(default_factory=list)
    dst: list[int] = field(default_factory=list)
    rank: list[int] = field(default_factory=list)
    combined: list[float] = field(default_factory=list)
    obs: list[str | None] = field(default_factory=list)
    original: list[int] = field(default_factory=list)


class LazySpace(SpaceOps):
    """A :class:`~lesmc.engines.space.SearchSpace` that calls the tracker as it goes."""

    def __init__(self, design: Design, original: list[TrackerState], bp: BoundProperty) -> None:
        self.design = design
        self.bp = bp
        self.satisfies = _OPS[bp.op]
        self.first_frame = design.scene.target.step
        self.cm = GrowingModel()
        self.dist: list[float] = []
        self.c_obj: list[float] = []
        self.c_con: list[float] = []
        self._tstate: list[TrackerState] = []
        self._index: dict[tuple[int, bytes], int] = {}
        self._succ: dict[int, list[int]] = {}  # allowed transitions, once expanded
        self._out: dict[int, list[int]] = {}  # every transition created from a state
        self._ref_lists = [ts.estimate()[0].tolist() for ts in original[: bp.end + 1]]
        self._pending: dict[int, list[int]] = {}  # per step: built states awaiting their step
        self.cm.original = [self._add(k, ts) for k, ts in enumerate(original[: bp.end + 1])]
        obj = self._dist_term(bp.objective.source, bp.objective.lo, 0)
        con = self._dist_term(bp.constraint.source, bp.constraint.lo, 0)
        for k in range(1, bp.l):  # the common prefix follows the original path
            t = self.entering(self.cm.original[k - 1], self.cm.original[k])
            obj = self.agg(self.obj_max, obj, self.c_obj[t])
            con = self.agg(self.con_max, con, self.c_con[t])
        self.root = self.cm.original[bp.l - 1]
        self.root_obj, self.root_con = obj, con

    @property
    def states_built(self) -> int:
        return len(self.cm.ids)

    def _dist_term(self, source: str, lo: int, q: int) -> float:
        return self.dist[q] if source == "dist" and lo == 0 else 0.0

    def _add(self, step: int, ts: TrackerState) -> int:
        key = (step, ts.key())
        q = self._index.get(key)
        if q is not None:
            return q
        q = len(self.cm.ids)
        s, P = ts.estimate()
        cm = self.cm
        cm.ids.append(f"k{step}.{q}")
        cm.step.append(step)
        cm.halted.append(ts.halted)
        cm.S.append(s)
        comps = self.bp.monitor_components
        cm.tau.append(float(tau(P, comps)) if comps is not None else 0.0)
        self.dist.append(self._deviation(s, step))
        self._tstate.append(ts)
        self._index[key] = q
        k = step + 1
        if not self.bp.l <= k <= self.bp.u and step < self.bp.end and not ts.halted:
            self._pending.setdefault(step, []).append(q)
        return q

    def _deviation(self, s: np.ndarray, step: int) -> float:
        """Eq. 4 for one state, in plain floats (this runs once per state built)."""
        ref = self._ref_lists[step]
        sl = s.tolist()
        d = [abs(sl[i] - ref[i]) for i in self.bp.components]
        p = self.bp.norm
        acc = 0.0
        if p == 2:  # summed in order, as numpy's norm does for short vectors
            for x in d:
                acc += x * x
            return math.sqrt(acc)
        if p == 1:
            for x in d:
                acc += x
            return acc
        return float(max(d))

    def is_leaf(self, q: int) -> bool:
        return self.cm.step[q] >= self.bp.end or self.cm.halted[q]

    def tail(self, q: int) -> tuple[float, float]:
        return self.tail_at(self.cm.step[q])

    def successors(self, q: int) -> list[int]:
        if q not in self._succ:
            self._expand(q)
        return self._succ[q]

    def entering(self, q0: int, q1: int) -> int:
        if q0 not in self._out:
            self._expand(q0)
        return next(t for t in self._out[q0] if self.cm.dst[t] == q1)

    def _expand(self, q: int) -> None:
        """One tracker step from q: every outcome inside the window, else the unattacked one.

        Outside the window the unattacked step of every state of q's step that
        is waiting for it is computed in one batch (its only transition is
        needed as soon as any path through that state is completed).
        """
        bp = self.bp
        step = self.cm.step[q]
        k = step + 1
        frame = self.first_frame + k
        if bp.l <= k <= bp.u:
            self._record([q], k, [self.design.options(self._tstate[q], frame)])
            return
        batch = [x for x in self._pending.pop(step, []) if x not in self._out]
        if q not in batch:
            batch.append(q)
        outs = self.design.unattacked([self._tstate[x] for x in batch], frame)
        self._record(batch, k, [[o] for o in outs])

    def _record(self, sources: list[int], k: int, option_lists: list[list[Outcome]]) -> None:
        """Add the transitions (rank = list position) and their contributions."""
        bp, cm = self.bp, self.cm
        first = len(cm.dst)
        src_of: list[int] = []
        for q, opts in zip(sources, option_lists, strict=True):
            payoffs: list[float] = []
            for rank, o in enumerate(opts):
                cm.dst.append(self._add(k, o.state))
                cm.rank.append(rank)
                cm.combined.append(math.fsum(payoffs) if rank else 0.0)
                cm.obs.append(o.obs)
                payoffs.append(o.payoff)
                src_of.append(q)
        n = len(cm.dst) - first
        ks = np.full(n, k)
        comb = np.array(cm.combined[first:])
        dd = np.array([self.dist[d] for d in cm.dst[first:]])
        self.c_obj.extend(contributions(bp.objective, ks, comb, dd).tolist())
        self.c_con.extend(contributions(bp.constraint, ks, comb, dd).tolist())
        allowed = np.ones(n, dtype=bool)
        if bp.monitor_components is not None:
            t_src = np.array([cm.tau[q] for q in src_of])
            t_dst = np.array([cm.tau[d] for d in cm.dst[first:]])
            allowed &= ~alarms(bp, ks, t_src, t_dst)
        t = first
        for q, opts in zip(sources, option_lists, strict=True):
            ids = list(range(t, t + len(opts)))
            self._out[q] = ids
            self._succ[q] = [i for i in ids if allowed[i - first]]
            t += len(opts)
