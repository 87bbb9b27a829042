"""The exact engine of multi-target models (lesmc/model/multi.py): the cheapest path whose
identity measure (``switches``, ``lost``) satisfies the constraint.

The constraint's measure takes few values (whole numbers up to the path's length), so
a forward pass over the states in index order (a topological order: levels) keeps, per
state and per value of the constraint's measure so far, the cheapest prefix
(objective) reaching it. At the last step the values that satisfy the constraint give
the optimum, and the kept predecessors its counterexample. Every contribution is the
kernel's (lesmc/model/kernel.py ``contributions``, identity indicators from
lesmc/model/identity.py).
"""

from __future__ import annotations

import math
import operator
from collections.abc import Callable
from dataclasses import dataclass
from typing import cast

import numpy as np

from lesmc.common.budget import SearchBudget
from lesmc.common.errors import Location, SpecError, UsageError, source_line
from lesmc.engines.result import StopReason
from lesmc.language import measures
from lesmc.language.properties import Measure, Monitor, Property, SpecFile
from lesmc.language.semantics import BoundMeasure, BoundProperty, bind
from lesmc.model.identity import NONE, indicators
from lesmc.model.kernel import COMPARE, contributions, holds, initial_value
from lesmc.model.multi import COMPONENTS, MultiModel

#: States the forward pass expands between two looks at the clock (one look costs about a
#: microsecond; 256 states of a large model take about a millisecond).
CLOCK_EVERY = 256


@dataclass(frozen=True)
class MultiResult:
    """A property's verdict on a multi-target model: the optimum (∞: no path satisfies the
    constraint), the constraint's value on the counterexample, and the counterexample as
    the transitions it takes (None when there is none).

    A search stopped by its budget (``stopped`` not ``finished``: the deadline passed)
    reports as ``optimum`` the best path found so far (its incumbent; ∞: none), as
    ``lower`` a proven lower bound on the optimum, and in ``expanded`` the states it
    expanded; ``holds`` is then the incumbent's, and the caller decides the verdict from
    the bounds (lesmc/engines/check.py ``bounded_verdict``)."""

    holds: bool
    optimum: float
    constraint: float | None
    path: tuple[int, ...] | None
    states: int
    transitions: int
    stopped: StopReason = "finished"
    lower: float = math.nan
    expanded: int = 0


def measure_values(
    model: MultiModel, m: BoundMeasure, components: tuple[int, ...] = (), norm: float = 2.0
) -> tuple[float, np.ndarray]:
    """Measure ``m``'s value on step 0 alone and each transition's contribution; a ``dist``
    measure over ``components`` in the ``norm`` (:meth:`MultiModel.deviations`)."""
    k = model.step[model.dst]
    ident = None
    reads = m.declared.quantity
    if reads == "identity":
        ident = indicators(
            m.source, model.last[model.src], model.tid[model.dst], model.ref[model.dst]
        )
    dist = model.deviations(components, norm) if reads == "dist_dst" else np.zeros(model.n_states)
    frames = model.count.astype(float)
    per = contributions(m, k, model.payoff, dist[model.dst], counted=frames, identity=ident)
    first = initial_value(m, float(dist[0]))
    if reads == "identity":
        i0 = indicators(m.source, np.array([NONE]), model.tid[:1], model.ref[:1])
        first = float(
            contributions(m, np.zeros(1, dtype=np.int64), np.zeros(1), np.zeros(1), identity=i0)[0]
        )
    return first, per


def _combine(m: BoundMeasure) -> Callable[[float, float], float]:
    """How a path's value of ``m`` grows by a transition's contribution: max or sum."""
    return max if m.aggregate == "max" else operator.add


def measure_value(model: MultiModel, m: BoundMeasure, prop: BoundProperty) -> float:
    """Measure ``m`` of property ``prop`` on a model of one path whose transitions are in
    path order (a replayed run's, lesmc/replay/multi.py): its first value and each
    transition's contribution, combined as :func:`check_multi` combines them (max or sum)."""
    first, per = measure_values(model, m, prop.components, prop.norm)
    value, add = float(first), _combine(m)
    for v in per.tolist():
        value = add(value, float(v))
    return value


#: best[state][constraint value] = (objective, transition taken into it, value before)
Best = list[dict[float, tuple[float, int, float]]]


def check_multi(
    model: MultiModel, prop: BoundProperty, search: SearchBudget | None = None
) -> MultiResult:
    """Minimise ``prop``'s objective over the model's paths from step 0 to the end whose
    constraint holds (docs/trackers.md); ``search``: the deadline (lesmc/common/budget.py),
    looked at every :data:`CLOCK_EVERY` states, past which the search stops with its
    incumbent and bounds (:class:`MultiResult`)."""
    c0, cons = measure_values(model, prop.constraint, prop.components, prop.norm)
    o0, obj = measure_values(model, prop.objective, prop.components, prop.norm)
    best: Best = [{} for _ in range(model.n_states)]
    best[0][c0] = (o0, -1, math.nan)
    adds = (_combine(prop.constraint), _combine(prop.objective))
    stopped, done = _forward(model, best, cons, obj, adds, search)
    top = _top(model, prop, best)
    verdict = prop.prop
    upper = math.inf if top is None else top[0]
    lower = upper if stopped == "finished" else _lower(model, prop, obj, best, done, upper)
    path = None if top is None else _path(model, best, top[1], top[2])
    return MultiResult(
        holds(verdict.holds_op, upper, verdict.threshold),
        upper,
        None if top is None else top[2],
        path,
        model.n_states,
        model.n_transitions,
        stopped,
        lower,
        done,
    )


def _forward(
    model: MultiModel,
    best: Best,
    cons: np.ndarray,
    obj: np.ndarray,
    adds: tuple[Callable[[float, float], float], Callable[[float, float], float]],
    search: SearchBudget | None,
) -> tuple[StopReason, int]:
    """The forward pass over the states in index order (a topological order), keeping in
    ``best`` the cheapest prefix per state and constraint value; why it stopped and the
    states it expanded (all of them when it finished)."""
    add_c, add_o = adds
    order = np.argsort(model.src, kind="stable")
    ptr = np.searchsorted(model.src[order], np.arange(model.n_states + 1))
    for s in range(model.n_states):
        if search is not None and s % CLOCK_EVERY == 0:
            reason = search.over()
            if reason is not None:
                return cast(StopReason, reason), s
        if not best[s]:
            continue
        for t in order[ptr[s] : ptr[s + 1]].tolist():
            d = int(model.dst[t])
            for cv, (ov, _, _) in best[s].items():
                ncv, nov = add_c(cv, float(cons[t])), add_o(ov, float(obj[t]))
                cur = best[d].get(ncv)
                if cur is None or nov < cur[0]:
                    best[d][ncv] = (nov, t, cv)
    return "finished", model.n_states


def _top(model: MultiModel, prop: BoundProperty, best: Best) -> tuple[float, int, float] | None:
    """The cheapest entry of a last step's state whose constraint value satisfies the
    constraint: (objective, state, constraint value); None: no such entry (yet)."""
    top: tuple[float, int, float] | None = None
    for s in np.nonzero(model.step == model.end)[0].tolist():
        for cv, (ov, _, _) in best[s].items():
            if COMPARE[prop.op](cv, prop.bound) and (top is None or ov < top[0]):
                top = (ov, s, cv)
    return top


def _lower(
    model: MultiModel, prop: BoundProperty, obj: np.ndarray, best: Best, done: int, upper: float
) -> float:
    """A proven lower bound on the optimum when the forward pass stopped before state
    ``done``: every path to the end not yet complete enters a state ``>= done`` from one
    expanded, so its objective is at least the least one kept there, when the objective
    never decreases along a path (a max, or no negative contribution); else -∞."""
    if prop.objective.aggregate != "max" and bool((obj < 0).any()):
        return -math.inf
    kept = (ov for s in range(done, model.n_states) for ov, _, _ in best[s].values())
    return min(min(kept, default=math.inf), upper)


def _path(model: MultiModel, best: Best, s: int, cv: float) -> tuple[int, ...]:
    """The transitions of the kept prefix ending at state ``s`` with constraint value
    ``cv``, from step 0 on."""
    path: list[int] = []
    while True:
        _, t, before = best[s][cv]
        if t < 0:
            break
        path.append(t)
        s, cv = int(model.src[t]), before
    return tuple(reversed(path))


# ------------------------------------------------------------ properties and models

#: What one model is unfolded for: attack window l..u, end, radius, the attacker's actions.
BuildKey = tuple[int, int, int, float | None, tuple[str, ...]]


def build_key(b: BoundProperty) -> BuildKey:
    """What a model must be unfolded for to check the bound property ``b``."""
    return (b.l, b.u, b.end, b.radius, b.prop.actions)


def bind_multi(spec: SpecFile, prop: Property, e: int) -> BoundProperty:
    """``prop`` (one this engine answers: :func:`supported`) bound to a multi-target model
    of a scene whose last step is ``e``."""
    supported(spec, prop)
    return bind(spec, prop, e, COMPONENTS, False, multi=True)


def bind_model(model: MultiModel, spec: SpecFile, prop: Property) -> BoundProperty:
    """``prop`` bound to a built model (``lesmc check MODEL``, ``lesmc export MODEL``): as
    on the scene it was built from (its ``meta``), and a located error unless the model
    was unfolded for what the property needs, or when its objective is the payoff and
    the window holds an unpriced detection."""
    b = bind_multi(spec, prop, int(model.meta["last_step"]))
    meta = model.meta
    have: BuildKey = (*model.window, model.end, meta["radius"], tuple(meta["actions"]))
    if have != build_key(b):
        pos = prop.clause_pos.get("window", prop.pos)
        raise SpecError(
            f"property '{prop.name}' needs a model of {_key_text(build_key(b))}; this model was "
            f"built for {_key_text(have)}: build one for it (lesmc build SCENE --spec "
            f"{spec.path} --property {prop.name}) or check the scene",
            Location(spec.path, pos.line, pos.column, source_line(spec.text, pos.line)),
        )
    unpriced = meta.get("unpriced")
    if b.objective.declared.reads_payoffs and unpriced is not None:
        raise UsageError(unpriced_text(str(unpriced[1]), int(unpriced[0])))
    return b


def _key_text(key: BuildKey) -> str:
    l, u, end, radius, actions = key
    within = "" if radius is None else f" within {radius:g}"
    return f"attack window {l}..{u}{within}, allow {', '.join(actions)}, end {end}"


def unpriced_text(detection: str, step: int) -> str:
    """Why a payoff objective cannot be minimised: the window's detection is unpriced."""
    return (
        f"detection '{detection}' of frame {step} has no payoff (unpriced): minimize "
        "count or count.frames, or price the scene (lesmc perceive)"
    )


def _unsupported(spec: SpecFile, what: str, m: Measure | Monitor) -> SpecError:
    """``what`` is not supported yet, at ``m``'s place in the spec."""
    loc = Location(spec.path, m.pos.line, m.pos.column, source_line(spec.text, m.pos.line))
    return SpecError(f"{what} (multi-target designs: not supported yet)", loc)


def _taken(role: str) -> str:
    """The measures this engine takes as ``role`` (objective, constraint), as a message lists
    them: ``payoff, count or a dist measure`` (lesmc/language/measures/)."""
    names = [
        n for n in measures.names() if getattr(measures.get(n), f"multi_{role}") and n != "dist"
    ]
    return ", ".join(names) + " or a dist measure"


def supported(spec: SpecFile, prop: Property) -> None:
    """A located error unless the property is one this engine answers."""
    obj, con = prop.objective, prop.constraint.measure
    if not obj.declared.multi_takes("objective", obj.aggregate):
        raise _unsupported(spec, f"objective '{obj.text()}': minimize {_taken('objective')}", obj)
    if not con.declared.multi_takes("constraint", con.aggregate):
        raise _unsupported(
            spec,
            f"constraint '{con.text()}': the constraint must be {_taken('constraint')}",
            con,
        )
    if prop.monitor is not None:  # at the monitor clause (a spec's own: no design adds one)
        at = prop.monitor if prop.monitor.pos.line > 0 else obj
        raise _unsupported(spec, "a runtime monitor ('monitor')", at)
