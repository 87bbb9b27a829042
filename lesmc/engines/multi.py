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

import numpy as np

from lesmc.common.errors import Location, SpecError, UsageError, source_line
from lesmc.language import measures
from lesmc.language.properties import Measure, Property, SpecFile
from lesmc.language.semantics import BoundMeasure, BoundProperty, bind
from lesmc.model.identity import NONE, indicators
from lesmc.model.kernel import COMPARE, contributions, holds, initial_value
from lesmc.model.multi import COMPONENTS, MultiModel


@dataclass(frozen=True)
class MultiResult:
    """A property's verdict on a multi-target model: the optimum (∞: no path satisfies the
    constraint), the constraint's value on the counterexample, and the counterexample as
    the transitions it takes (None when there is none)."""

    holds: bool
    optimum: float
    constraint: float | None
    path: tuple[int, ...] | None
    states: int
    transitions: int


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


def check_multi(model: MultiModel, prop: BoundProperty) -> MultiResult:
    """Minimise ``prop``'s objective over the model's paths from step 0 to the end whose
    constraint holds (docs/trackers.md)."""
    c0, cons = measure_values(model, prop.constraint, prop.components, prop.norm)
    o0, obj = measure_values(model, prop.objective, prop.components, prop.norm)
    add_c, add_o = _combine(prop.constraint), _combine(prop.objective)
    order = np.argsort(model.src, kind="stable")
    ptr = np.searchsorted(model.src[order], np.arange(model.n_states + 1))
    # best[state][constraint value] = (objective, transition taken into it, value before)
    best: list[dict[float, tuple[float, int, float]]] = [{} for _ in range(model.n_states)]
    best[0][c0] = (o0, -1, math.nan)
    for s in range(model.n_states):
        if not best[s]:
            continue
        for t in order[ptr[s] : ptr[s + 1]].tolist():
            d = int(model.dst[t])
            for cv, (ov, _, _) in best[s].items():
                ncv, nov = add_c(cv, float(cons[t])), add_o(ov, float(obj[t]))
                cur = best[d].get(ncv)
                if cur is None or nov < cur[0]:
                    best[d][ncv] = (nov, t, cv)
    op, bound = prop.op, prop.bound
    top: tuple[float, int, float] | None = None
    for s in np.nonzero(model.step == model.end)[0].tolist():
        for cv, (ov, _, _) in best[s].items():
            if COMPARE[op](cv, bound) and (top is None or ov < top[0]):
                top = (ov, s, cv)
    verdict = prop.prop
    if top is None:
        return MultiResult(
            holds(verdict.holds_op, math.inf, verdict.threshold),
            math.inf,
            None,
            None,
            model.n_states,
            model.n_transitions,
        )
    path: list[int] = []
    s, cv = top[1], top[2]
    while True:
        _, t, before = best[s][cv]
        if t < 0:
            break
        path.append(t)
        s, cv = int(model.src[t]), before
    return MultiResult(
        holds(verdict.holds_op, top[0], verdict.threshold),
        top[0],
        top[2],
        tuple(reversed(path)),
        model.n_states,
        model.n_transitions,
    )


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


def _unsupported(spec: SpecFile, what: str, m: Measure) -> SpecError:
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
    if prop.monitor is not None:
        raise _unsupported(spec, "'monitor uncertainty'", obj)
