"""The checking pipeline's public API: model + properties -> one result per property."""

from __future__ import annotations

import math
from collections.abc import Callable, Iterable
from dataclasses import replace
from typing import Any, cast

import numpy as np

from lesmc.common.budget import Budget
from lesmc.engines import enumerate as enum_engine
from lesmc.engines import registry as engines
from lesmc.engines.enumerate import enumerate_many, probe_then, tree_size
from lesmc.engines.lazy import LazySpace
from lesmc.engines.result import (
    CheckResult,
    EngineOutcome,
    PathInfo,
    Stats,
    StopReason,
    Verdict,
    path_info,
)
from lesmc.engines.space import (
    SearchSpace,
    build_space,
    original_nis,
    transition_nis,
    unattacked_alarm_steps,
)
from lesmc.language import actions
from lesmc.language.properties import SpecFile
from lesmc.language.semantics import BoundProperty, bind
from lesmc.model import kernel
from lesmc.model.arrays import ArrayModel
from lesmc.model.growing import ExpansionStopped, GrowingModel
from lesmc.model.kernel import holds

#: An engine's name (lesmc/engines/registry.py).
EngineName = str

#: Default budget on expanded states: keeps a runaway search inside 2 cores / 24 GiB.
DEFAULT_MAX_STATES = 10_000_000


def bind_all(model: ArrayModel, specs: Iterable[SpecFile]) -> list[BoundProperty]:
    """Bind every property of every spec file to the model (semantic errors raise)."""
    return [
        bind(
            spec,
            prop,
            model.end,
            model.components,
            model.has_covariance,
            None if model.tracks is None else model.tracks.components,
            model.nis is not None,
            model_actions=tuple(model.meta.get("actions", actions.DEFAULT)),
            model_grid=model.meta.get("inject_grid"),
        )
        for spec in specs
        for prop in spec.properties
    ]


def check(
    model: ArrayModel,
    specs: Iterable[SpecFile],
    engine: EngineName = engines.DEFAULT,
    budget: Budget | None = None,
) -> list[CheckResult]:
    """Check every property of ``specs`` on ``model`` with the chosen engine (each check
    within what is left of ``budget``)."""
    b = budget or Budget(max_states=DEFAULT_MAX_STATES)
    design = model_design(model)
    return [
        replace(check_bound(model, bp, engine, b.for_check()), design=design)
        for bp in bind_all(model, specs)
    ]


def model_design(model: ArrayModel) -> str:
    """The design a model file's results name: the one its meta names, else ``model``."""
    return str(model.meta.get("design", "model"))


def check_bound(
    cm: ArrayModel,
    bp: BoundProperty,
    engine: EngineName = engines.DEFAULT,
    budget: Budget | None = None,
) -> CheckResult:
    """Check one bound property on a model, within ``budget`` (default: no limit).

    ``bnb`` and ``levels`` first try to enumerate a small tree (enumerate.exhaustive_probe):
    its answer is theirs when it finishes; otherwise they search with what is left of the
    budget, and report the probe's states as ``stats.extra["probe_states"]`` (an engine
    with ``own_probe``, ``auto``, decides itself whether to probe). A model built
    for another attack window than the property's says so in a note.
    """
    b = budget or Budget()
    space = build_space(cm, bp)
    chosen = engines.get(engine)
    if chosen.exhaustive or chosen.own_probe:
        out = chosen.load()(space, b)
    else:
        out = probe_then(space, engine, b, chosen.load())
    out.stats.extra["states_built"] = cm.n_states  # the whole model's
    result = to_result(space, out)
    result.notes.extend(window_notes(cm, bp))
    return result


def to_result(space: SearchSpace, out: EngineOutcome) -> CheckResult:
    """Turn an engine's outcome into a verdict with readable paths (section 4's rule)."""
    bp = space.bp
    prop = bp.prop

    def above(x: float) -> bool:
        return holds(prop.holds_op, x, prop.threshold)

    known, optimum, lower, upper, verdict, notes = bounded_verdict(out, above)
    cex = None if out.counterexample is None else path_info(space, out.counterexample)
    wit = None if out.witness is None else path_info(space, out.witness)
    if not out.witness_exact and wit is not None:
        notes.append("the witness is the best found before the budget ran out, maybe not ρ*")
    if known and math.isinf(optimum):
        notes.append(
            "no attacked path violates: optimum is +inf"
            if cex is None
            else "only paths with an infinite objective violate (a halted track): optimum is +inf"
        )
    alarms, vacuous = monitor_facts(space)
    if vacuous:
        notes.append(
            "the monitor excludes the unattacked track itself (alarms at steps "
            + ", ".join(map(str, alarms or []))
            + "): every path is monitored out, so 'holds' says nothing about the attack"
        )
    return CheckResult(
        property=prop.name,
        verdict=verdict,
        optimum=optimum if known else None,
        threshold=prop.threshold,
        holds_op=prop.holds_op,
        objective=bp.objective.text,
        constraint=f"{bp.constraint.text} {bp.op} {bp.bound:g}",
        lower=lower,
        upper=upper,
        cheapest=cex,
        witness=wit,
        witness_value=None if wit is None else wit.objective,
        witness_exact=out.witness_exact,
        stats=out.stats,
        notes=notes,
        optimum_known=known,
        witness_bounds=_witness_bounds(out, wit, known, upper),
        original_alarms=alarms,
        vacuous=vacuous,
        spec=bp.spec,
        objective_source=bp.objective.source,
        constraint_source=bp.constraint.source,
        constraint_op=bp.op,
        constraint_bound=bp.bound,
        sweep=dict(prop.sweep),
    )


def bounded_verdict(
    out: EngineOutcome, above: Callable[[float], bool]
) -> tuple[bool, float, float, float, Verdict, list[str]]:
    """Section 4's rule on the engine's bounds: whether the optimum is known, the optimum
    (or the best upper bound), the bounds, the verdict, and a note when stopped early
    (every engine's, the multi-target search's too: lesmc/pipeline/multi.py)."""
    exact = out.stats.stopped == "finished"
    notes: list[str] = []
    verdict: Verdict
    # the optimum is known when the search finished, or when its proven bounds meet
    known = exact or (out.lower >= out.upper and math.isfinite(out.upper))
    optimum = out.optimum if exact else out.upper
    if known:
        verdict = "holds" if above(optimum) else "violated"
        lower = upper = optimum
    else:
        lower, upper = out.lower, out.upper
        verdict = "holds" if above(lower) else "violated" if not above(upper) else "unknown"
    if not exact:
        notes.append(
            f"search stopped ({out.stats.stopped}) before it finished: the optimum "
            + (
                f"is proven to be {optimum:g}"
                if known
                else f"lies in [{lower:g}, {upper:g}]"
                + ("" if verdict == "unknown" else f", which already decides '{verdict}'")
            )
        )
    return known, optimum, lower, upper, verdict, notes


def _witness_bounds(
    out: EngineOutcome, wit: PathInfo | None, known: bool, upper: float
) -> tuple[float, float] | None:
    """Proven bounds on θ*: the witness itself when exact, else what the engine proved."""
    if out.witness_exact and wit is not None:
        return (wit.objective, wit.objective)
    got = out.stats.extra.pop("witness_bounds", None)
    if got is not None:
        lo, hi = (float(x) for x in got)
        return (lo, hi)
    if not known:
        return (-math.inf, upper)
    return None


def monitor_facts(space: SearchSpace) -> tuple[list[int] | None, bool]:
    """A monitored property: the steps l..end where the unattacked track raises Eq. 13's
    alarm, and whether the monitor thereby excludes the unattacked track (vacuity)."""
    bp, cm = space.bp, space.cm
    if bp.monitor_components is None:
        return None, False
    tau_orig = np.zeros(len(cm.original))
    if bp.monitor_components:
        tau_orig = kernel.tau(cm.P_table, bp.monitor_components)[cm.cov[cm.original]]
    steps = unattacked_alarm_steps(bp, tau_orig, original_nis(cm, transition_nis(cm, bp)))
    return steps, bool(steps) and not bp.monitor_except_original


def check_lazy(
    model: GrowingModel,
    bp: BoundProperty,
    engine: EngineName = engines.DEFAULT,
    budget: Budget | None = None,
) -> CheckResult:
    """One bound property on a model unfolded on demand (the engine expands what it visits;
    ``enumerate`` every state its paths reach)."""
    space = LazySpace(model, bp, budget)
    try:
        out = engines.get(engine).load()(space, budget or Budget())
    except ExpansionStopped as stop:
        out = stopped_outcome(engine, stop)
    out.stats.extra["states_built"] = space.states_built
    return to_result(space, out)


def stopped_outcome(engine: str, stop: ExpansionStopped) -> EngineOutcome:
    """What a search stopped inside one long expansion answers: unknown, within the bounds
    that hold without a search (its own are lost with its stack)."""
    stats = Stats(engine, stopped=cast(StopReason, stop.reason))
    stats.extra["stopped_inside"] = str(stop)
    return EngineOutcome(math.inf, -math.inf, math.inf, None, None, False, stats)


def check_many(
    model: ArrayModel | GrowingModel,
    bps: list[BoundProperty],
    budget: Budget | None = None,
    max_work: int | None = None,
) -> list[CheckResult]:
    """Properties whose trees are the same (enumerate.tree_key) by ``enumerate`` with one
    walk of the tree (enumerate.enumerate_many, ``max_work`` its cap on the unfolding's
    work): the results of checking each alone."""
    budget = budget or Budget()
    return _walk_once(model, _spaces(model, bps, budget), budget, max_work)


def _spaces(
    model: ArrayModel | GrowingModel, bps: list[BoundProperty], budget: Budget | None = None
) -> list[Any]:
    """Each property's search space on ``model`` (explicit or unfolded on demand; a lazy
    space's dead-root question within ``budget``)."""
    if isinstance(model, GrowingModel):
        return [LazySpace(model, bp, budget) for bp in bps]
    return [build_space(model, bp) for bp in bps]


def _walk_once(
    model: ArrayModel | GrowingModel,
    spaces: list[Any],
    budget: Budget,
    max_work: int | None = None,
) -> list[CheckResult]:
    """:func:`check_many` on spaces already built."""
    try:
        outs = enumerate_many(spaces, budget, max_work)
    except ExpansionStopped as stop:
        outs = [stopped_outcome("enumerate", stop) for _ in spaces]
    results = []
    for space, out in zip(spaces, outs, strict=True):
        out.stats.extra["states_built"] = (
            space.states_built if isinstance(model, GrowingModel) else model.n_states
        )
        result = to_result(space, out)
        if isinstance(model, ArrayModel):
            result.notes.extend(window_notes(model, space.bp))
        results.append(result)
    return results


#: A shared enumeration tried for ``levels``/``bnb`` on a model unfolded on demand stops
#: past this many tree nodes (then each property is searched on its own) ...
SHARED_LAZY_TREE = 1 << 19
#: ... or once the unfolding has done more than this much work since the walk began
#: (GrowingModel.work: the rows its expander examined, e.g. (state, candidate subset)
#: pairs on the joint design under inject, 2^m a state): the walk unfolds every state of
#: the tree, which on a costly unfolding takes minutes where each property's search
#: unfolds the few states its bounds keep (docs/performance.md, "Issue 61, frames under
#: inject", "Issue 61, the walk's cap counted"); the states it unfolded stay in the model
#: for those searches. Work, not seconds, so that which of the two answers, and so the
#: states built and the counterexample printed, is the same on every run.
SHARED_LAZY_WORK = 1 << 18


def check_shared(
    model: ArrayModel | GrowingModel,
    bps: list[BoundProperty],
    engine: EngineName,
    budget: Budget,
) -> list[CheckResult] | None:
    """Properties that share their tree (a sweep's variants, robustness and resilience of
    one window) in one walk of it (:func:`check_many`), for any engine: ``enumerate``
    always; ``levels`` and ``bnb`` when the tree is small (on a whole model: counted,
    at most enumerate.SMALL_TREE nodes; on one unfolded on demand: the walk finishes
    within SHARED_LAZY_TREE nodes and SHARED_LAZY_WORK work; the user's --timeout is its
    only clock), the answers then marked ``exhaustive`` as their probe's are. None: search
    each property on its own."""
    if engines.get(engine).exhaustive:
        return check_many(model, bps, budget)
    limit = enum_engine.SMALL_TREE if budget.max_states is None else budget.max_states
    if isinstance(model, ArrayModel):
        limit = min(limit, enum_engine.SMALL_TREE)
        spaces = _spaces(model, bps)  # built once: counted, then walked
        if tree_size(spaces[0], limit) > limit:
            return None
        tried = _walk_once(model, spaces, budget)
    else:
        limit = min(limit, SHARED_LAZY_TREE)
        walk = Budget(budget.seconds_left(), limit, budget.max_memory)
        tried = check_many(model, bps, walk, SHARED_LAZY_WORK)
    if any(r.stats.stopped != "finished" for r in tried):
        return None
    for r in tried:
        r.stats.engine = engine
        r.stats.extra["exhaustive"] = r.stats.states_expanded
    return tried


def same_but_bound(a: BoundProperty, b: BoundProperty) -> bool:
    """``a`` and ``b`` differ at most in the constraint's bound (an ε sweep's variants)."""
    return replace(a, prop=b.prop, bound=b.bound) == b


def loosest_first(bps: list[BoundProperty]) -> list[int]:
    """The order in which each constraint admits a subset of the paths of those before it:
    bounds ascending for ``>``/``>=``, descending for ``<``/``<=``."""
    up = bps[0].op in (">", ">=")
    return sorted(range(len(bps)), key=lambda i: bps[i].bound if up else -bps[i].bound)


def carried_over(r: CheckResult, bp: BoundProperty) -> CheckResult | None:
    """The answer to ``bp`` read off ``r``, the finished answer to the same property with a
    looser constraint, when ``r``'s counterexample satisfies ``bp``'s constraint too.

    The counterexample is a violating path of least objective (Eq. 6-7). A tighter
    constraint admits a subset of the paths, so its optimum is at least ``r``'s, and at
    most that path's objective, which is ``r``'s: the optimum and the counterexample
    are ``r``'s. So is ρ*: the paths whose objective lies below the optimum are
    non-violating under either constraint, and ρ* is the best of them. An empty set of
    violating paths stays empty. None when ``r`` is not finished or its counterexample
    fails the tighter constraint (then ``bp`` needs its own search).
    """
    if r.stats.stopped != "finished" or not r.optimum_known:
        return None
    cex = r.cheapest
    if cex is None:
        if r.optimum != math.inf:
            return None
    elif not (kernel.compare(bp.op, cex.constraint, bp.bound) and cex.objective == r.optimum):
        return None
    stats = replace(r.stats, states_expanded=0, transitions=0, seconds=0.0, paths=None)
    stats.extra = {"answered_by": r.property}
    return replace(
        r,
        property=bp.name,
        constraint=f"{bp.constraint.text} {bp.op} {bp.bound:g}",
        constraint_bound=bp.bound,
        sweep=dict(bp.prop.sweep),
        stats=stats,
        notes=[
            *r.notes,
            f"answered by the search of {r.property}: its cheapest path that breaks the "
            "system satisfies this tighter constraint, which cannot lower the optimum",
        ],
    )


def window_notes(model: ArrayModel, bp: BoundProperty) -> list[str]:
    """Warn when a built model holds fewer alternatives than the property's window asks."""
    built = model.meta.get("window")
    if not (isinstance(built, list) and len(built) == 2):
        return []
    lo, hi = built
    if lo <= bp.l and bp.u <= hi:
        return []
    return [
        f"the model was built for attacks in {lo}..{hi}; outside those steps it holds only the "
        f"unattacked transitions, so window {bp.l}..{bp.u} is checked on fewer paths than the "
        f"system has (build with --window {bp.l}..{bp.u}, or check the scene directly)"
    ]
