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

from lesmc.engines.space import _OPS, SpaceOps, alarms, contributions, deviation
from lesmc.language.semantics import BoundProperty
from lesmc.tracking.design import Design, TrackerState
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
        self._ref = [ts.estimate()[0] for ts in original[: bp.end + 1]]
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
        if key in self._index:
            return self._index[key]
        q = len(self.cm.ids)
        s, P = ts.estimate()
        self.cm.ids.append(f"k{step}.{q}")
        self.cm.step.append(step)
        self.cm.halted.append(ts.halted)
        self.cm.S.append(s)
        comps = self.bp.monitor_components
        self.cm.tau.append(float(tau(P, comps)) if comps is not None else 0.0)
        diff = (s - self._ref[step])[list(self.bp.components)]
        self.dist.append(float(deviation(diff, self.bp.norm)))
        self._tstate.append(ts)
        self._index[key] = q
        return q

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
        """One tracker step from q: every outcome inside the window, else the unattacked one."""
        bp, cm = self.bp, self.cm
        k = cm.step[q] + 1
        opts = self.design.options(self._tstate[q], self.first_frame + k)
        if not bp.l <= k <= bp.u:
            opts = opts[:1]
        first = len(cm.dst)
        for rank, o in enumerate(opts):
            cm.dst.append(self._add(k, o.state))
            cm.rank.append(rank)
            cm.combined.append(math.fsum(x.payoff for x in opts[:rank]))
            cm.obs.append(o.obs)
        ts = np.arange(first, len(cm.dst))
        dst = np.array(cm.dst[first:], dtype=np.int64)
        ks = np.full(len(ts), k)
        comb = np.array(cm.combined[first:])
        dd = np.array([self.dist[d] for d in dst])
        self.c_obj.extend(contributions(bp.objective, ks, comb, dd).tolist())
        self.c_con.extend(contributions(bp.constraint, ks, comb, dd).tolist())
        allowed = np.ones(len(ts), dtype=bool)
        if bp.monitor_components is not None:
            tau = np.array(cm.tau)
            allowed &= ~alarms(bp, ks, np.full(len(ts), tau[q]), tau[dst])
        self._out[q] = ts.tolist()
        self._succ[q] = ts[allowed].tolist()
