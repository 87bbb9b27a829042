"""An independent brute force: every attacked path, measures straight from the definitions.

It reads the LTS object (not lesmc's compiled arrays) and recomputes Eq. 4, 5,
8, 9 and dist^max per path, then optimum and ρ* as in section 5.2.
"""

from __future__ import annotations

import math
from collections.abc import Iterator
from dataclasses import dataclass
from typing import Any

import numpy as np

from lesmc.language.semantics import BoundMeasure, BoundProperty
from lesmc.model.lts import LTS


@dataclass
class BruteResult:
    optimum: float  # +inf when no path violates
    witness_value: float | None
    paths: list[tuple[list[str], float, float]]  # (states, objective, constraint)


def every_path(model: LTS) -> Iterator[list[Any]]:
    """Every complete path of ``model`` from its initial state, as its transitions."""

    def walk(q: str, acc: list[Any]) -> Iterator[list[Any]]:
        out = model.out(q)
        if not out:
            yield acc
        for t in out:
            yield from walk(t.dst, [*acc, t])

    return walk(model.initial, [])


def brute_force(
    model: LTS,
    bp: BoundProperty,
    reference: list[np.ndarray] | None = None,
    tracks: np.ndarray | None = None,
) -> BruteResult:
    """``reference``: the states deviations are measured against, one per step (default:
    the model's original path's). ``tracks``: ground-truth tracks (r, steps, c) over the
    components ``bp.near_components``, NaN where absent (``dist.nearest``)."""
    orig = [model.state(q) for q in model.original]
    ref = [o.s for o in orig] if reference is None else reference
    comps = list(bp.components)

    def dist(sid: str) -> float:
        st = model.state(sid)
        d = st.s[comps] - ref[st.step][comps]
        if bp.norm == 1:
            return float(np.sum(np.abs(d)))
        if math.isinf(bp.norm):
            return float(np.max(np.abs(d)))
        return float(np.sqrt(np.sum(d * d)))

    def tau(sid: str) -> float:
        P = model.state(sid).P
        idx = list(bp.monitor_components or ())
        return float(sum(P[i, i] for i in idx))

    def allowed(sid: str) -> list:
        out = sorted(model.out(sid), key=lambda t: t.rank)
        k = model.state(sid).step + 1
        ts = out if bp.l <= k <= bp.u else [min(out, key=lambda t: t.rank)] if out else []
        if bp.monitor_components is not None and k >= bp.l:
            excused = k < len(orig) and rises(model.original[k - 1 : k + 1])
            if bp.monitor_except_original and excused:
                return ts  # the unattacked track alarms here too: not the attack's doing
            ts = [t for t in ts if not rises([t.src, t.dst])]
        return ts

    def rises(pair: list[str]) -> bool:
        return tau(pair[1]) > tau(pair[0]) * (1 + bp.monitor_tolerance) + 1e-300

    complete: list[tuple[list[str], list]] = []

    def walk(path: list[str], edges: list) -> None:
        st = model.state(path[-1])
        if st.step >= bp.end or st.halted:
            complete.append((path, edges))
            return
        for t in allowed(path[-1]):
            walk([*path, t.dst], [*edges, t])

    walk([model.initial], [])

    def nearest(sid: str) -> float:  # the least deviation from the reference or any track
        st = model.state(sid)
        comps_n = list(bp.near_components or ())
        best = _norm(st.s[comps_n] - ref[st.step][comps_n], bp.norm)
        for tr in [] if tracks is None else tracks:
            g = tr[min(st.step, len(tr) - 1)]
            if not np.isnan(g).any():
                best = min(best, _norm(st.s[comps_n] - g, bp.norm))
        return best

    def trace(sid: str) -> float:  # τ of Eq. 12 on tau.rise's components
        P = model.state(sid).P
        return float(sum(P[i, i] for i in bp.tau_components or ()))

    def value(m: BoundMeasure, path: list[str], edges: list) -> float:
        per_step = {}
        for k in range(m.lo, m.hi + 1):
            if k < len(path):
                if m.source == "dist":
                    per_step[k] = dist(path[k])
                elif m.source == "near":
                    per_step[k] = nearest(path[k])
                elif m.source == "tau":  # how much τ rose entering step k (never below 0)
                    per_step[k] = max(0.0, trace(path[k]) - trace(path[k - 1]))
                else:
                    t = edges[k - 1]
                    lower = [o for o in model.out(t.src) if o.rank < t.rank]
                    if m.source == "payoff":  # Eq. 5
                        comb = math.fsum(o.payoff for o in lower)
                    elif any(math.isinf(o.payoff) for o in lower):  # out of the attacker's reach
                        comb = math.inf
                    elif m.source == "count":  # the outcomes ruled out
                        comb = float(len(lower))
                    else:  # frames: was this step attacked?
                        comb = 1.0 if lower else 0.0
                    per_step[k] = comb * m.weight
            else:  # after a halt
                per_step[k] = math.inf if m.source in ("dist", "near", "tau") else 0.0
        vals = [per_step[k] for k in sorted(per_step)]
        if m.source == "tau":
            return max([0.0, *vals])
        if m.aggregate == "max":
            return max(vals)
        acc = 0.0
        for v in vals:
            acc += v
        return acc

    ops = {
        ">": lambda a, b: a > b,
        ">=": lambda a, b: a >= b,
        "<": lambda a, b: a < b,
        "<=": lambda a, b: a <= b,
    }
    rows = [(p, value(bp.objective, p, e), value(bp.constraint, p, e)) for p, e in complete]
    plus = [r for r in rows if ops[bp.op](r[2], bp.bound)]
    opt = min((r[1] for r in plus), default=math.inf)
    below = [r[1] for r in rows if not ops[bp.op](r[2], bp.bound) and r[1] < opt]
    return BruteResult(opt, max(below) if below else None, rows)


def _norm(d: np.ndarray, p: float) -> float:
    if p == 1:
        return float(np.sum(np.abs(d)))
    if math.isinf(p):
        return float(np.max(np.abs(d)))
    return float(np.sqrt(np.sum(d * d)))
