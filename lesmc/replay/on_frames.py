"""A diverged replay's property judged on the replayed run (docs/semantics.md, "Replay",
"Violated on the frames by another path").

A replay that leaves the model's path is no proof that the model's counterexample
happens; but the property is about the real system. The replayed run is one: the real
frames, perturbed by the attacks the replay applied, through the real detector and the
production tracker. It violates the property when its deviation from the unattacked run
(the same tracker on the clean detections) meets the constraint and the perturbations
it applied cost little enough for the property to fail (``holds if``). The deviation is
Eq. 4 (lesmc/model/kernel.py ``deviation``), folded over the constraint's range by the
kernel as the engines fold it (``initial_value``, ``contributions``, ``aggregate``,
``tail`` after a halt); the cost is the objective folded the same way over the attacked
steps, from each frame's applied perturbations (:func:`frame_cost`, :func:`frame_count`:
the repair's included). Only a run that was replayed and costed so is ever called
violated.
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from typing import TYPE_CHECKING, Any

import numpy as np

from lesmc.model import kernel
from lesmc.replay.case import Case, FrameAttack, footage
from lesmc.results.result_doc import number
from lesmc.tracking.monitor import track
from lesmc.tracking.trackers import make_tracker

if TYPE_CHECKING:
    from lesmc.perception.detector import FrameDetections
    from lesmc.results.replay_measures import Judged
    from lesmc.tracking.monitor import TrackPoint

#: Digits kept of the positions the object records.
DIGITS = 6


def frame_cost(fa: FrameAttack | None) -> float:
    """The recomputed cost of a frame's attack: the norms of the perturbations it applied
    (infinite where an attack found none that flips) and the repair's."""
    if fa is None:
        return 0.0
    norms = [number(p["payoff_recomputed"]) for p in fa.perturbations]
    return float(sum(norms)) + fa.extra_cost


def frame_count(fa: FrameAttack) -> float:
    """The windows a frame's attack perturbed: one per hidden detection or injected
    candidate, and the repair's; infinite (no count is claimed) when one of them has no
    finite payoff (the model counts such an outcome ∞) or a repair cost something but did
    not count its windows."""
    if not math.isfinite(frame_cost(fa)) or (fa.extra_cost > 0 and fa.extra_windows == 0):
        return math.inf
    return float(len(fa.perturbations) + fa.extra_windows)


def judge(
    c: Case, clean: Mapping[int, FrameDetections], attacked: Mapping[int, FrameAttack]
) -> dict[str, Any]:
    """The replay's ``on_frames`` object of case ``c`` (the replay schema's): the
    constraint's measure on the replayed run, whether it meets the constraint, the cost of
    the attack applied, whether the run violates the property, why, and both runs'
    positions on the property's components; only ``violated`` (False) and ``why`` when
    it cannot be judged."""
    j = c.judged
    if isinstance(j, str):
        return _not_judged(j)
    comps = [c.state_names.index(n) for n in j.components if n in c.state_names]
    steps = sorted(fa.step for fa in attacked.values())
    hi = j.constraint.hi
    dets = {c.first_frame + k: clean.get(c.first_frame + k) for k in range(hi + 1)}
    if len(comps) != len(j.components):
        return _not_judged(f"the state has no component {', '.join(j.components)}")
    if any(not j.objective.lo <= k <= j.objective.hi for k in steps):
        return _not_judged("the replay attacks a frame outside the property's window")
    if any(d is None for d in dets.values()):
        return _not_judged(f"the frames stop before step {hi}, the constraint's last")
    frames = {k: d for k, d in dets.items() if d is not None}
    base = track(make_tracker(footage(frames, c, {})), hi)
    if len(base) <= hi:
        return _not_judged(f"the unattacked run halts at step {len(base) - 1}")
    after = {k: fa.detections for k, fa in attacked.items()}
    got = track(make_tracker(footage(frames, c, after)), hi)
    value = _deviation(j, c.end, comps, got, base)
    cost = _cost(j, [attacked[k] for k in sorted(attacked)])
    met = kernel.compare(j.op, value, j.bound)
    violated = met and not kernel.holds(c.holds_op, cost, c.threshold)
    return {
        "constraint": _num(value),
        "constraint_met": met,
        "cost": _num(cost),
        "violated": violated,
        "why": _why(c, j, (value, met), cost, violated),
        "track": _positions(got, comps),
        "unattacked": _positions(base, comps),
    }


def _not_judged(why: str) -> dict[str, Any]:
    return {"violated": False, "why": f"not judged on the frames: {why}"}


def _deviation(
    j: Judged, end: int, comps: list[int], got: Sequence[TrackPoint], base: Sequence[TrackPoint]
) -> float:
    """The constraint's measure on the replayed run ``got`` against ``base``: Eq. 4 at each
    step, folded over the range by the kernel; +inf for the steps after a halt."""
    m = j.constraint
    n = len(got)
    diff = np.array([p.x for p in got])[:, comps] - np.array([p.x for p in base[:n]])[:, comps]
    d = kernel.deviation(diff, j.norm)
    ks = np.arange(1, n)
    per = kernel.contributions(m, ks, np.zeros(n - 1), d[1:])
    is_max = m.aggregate == "max"
    value = kernel.initial_value(m, float(d[0]))
    for c in per.tolist():
        value = kernel.aggregate(is_max, value, c)
    if got[-1].halted:
        value = kernel.aggregate(is_max, value, kernel.tail(m, n - 1, end))
    return value


def _cost(j: Judged, fas: list[FrameAttack]) -> float:
    """The objective on the replayed run: each attacked frame's applied cost (Eq. 5's
    combined payoff) and count, folded over the window by the kernel."""
    m = j.objective
    if not fas:
        return kernel.initial_value(m, 0.0)
    ks = np.array([fa.step for fa in fas], dtype=np.int64)
    combined = np.array([frame_cost(fa) for fa in fas])
    counted = np.array([frame_count(fa) for fa in fas])
    per = kernel.contributions(m, ks, combined, np.zeros(len(fas)), counted)
    value = kernel.initial_value(m, 0.0)
    for c in per.tolist():
        value = kernel.aggregate(m.aggregate == "max", value, c)
    return value


def _why(c: Case, j: Judged, measured: tuple[float, bool], cost: float, violated: bool) -> str:
    """The judgement in words."""
    value, met = measured
    measure = c.constraint.rpartition(f" {j.op} ")[0] or c.constraint
    on = f"on the replayed run {measure} is {value:.4g} (constraint {j.op} {j.bound:g})"
    paid = f"at a cost of {cost:.4g} ({j.objective.text}, the repair's included)"
    if violated:
        return (
            f"violated on the frames by another path: {on} {paid}, for which the property "
            f"fails (holds if optimum {c.holds_op} {c.threshold:g})"
        )
    if not met:
        return f"not violated on the frames: {on}, the constraint is not met"
    return (
        f"not violated on the frames: {on} {paid}, for which the property holds "
        f"(optimum {c.holds_op} {c.threshold:g})"
    )


def _positions(points: Sequence[TrackPoint], comps: list[int]) -> list[list[float]]:
    return [[round(float(p.x[i]), DIGITS) for i in comps] for p in points]


def _num(x: float) -> float | str:
    return x if math.isfinite(x) else "inf"
