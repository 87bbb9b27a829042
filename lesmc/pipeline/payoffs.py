"""One property in one payoff mode: the attack's payoffs, certified lower bounds, or both.

The modes, their payoff sets and how their results merge are declared in
lesmc/engines/payoff_modes.py (``attack``, the paper's; ``certified``, the
certified lower payoffs; ``interval``, both, combined by lesmc/engines/interval.py).

Budget rule (one for every verb): a check gets :meth:`Budget.check_seconds`;
a mode of several payoff sets shares it evenly, in order, each search taking
what the ones before left (interval: the certified search half, the attack's the
rest).
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import replace

from lesmc.common.budget import Budget
from lesmc.engines import payoff_modes
from lesmc.engines.check import (
    EngineName,
    carried_over,
    check_bound,
    check_lazy,
    check_shared,
    loosest_first,
    same_but_bound,
)
from lesmc.engines.enumerate import tree_key
from lesmc.engines.result import CheckResult
from lesmc.language.semantics import BoundProperty
from lesmc.model.arrays import ArrayModel
from lesmc.model.growing import GrowingModel
from lesmc.pipeline.job import PayoffMode

#: The model of one payoff set (``attack`` or ``certified``), made when first asked for.
ModelOf = Callable[[str], ArrayModel | GrowingModel]

#: The payoff sets whose models a payoff mode reads, in the order :func:`check_payoffs`
#: reads them.
PAYOFF_SETS: dict[str, tuple[str, ...]] = {
    "attack": ("attack",),
    "certified": ("certified",),
    "interval": ("certified", "attack"),
}


def check_model(
    model: ArrayModel | GrowingModel, bp: BoundProperty, engine: EngineName, budget: Budget
) -> CheckResult:
    """One property on a whole model or on one unfolded on demand."""
    if isinstance(model, ArrayModel):
        return check_bound(model, bp, engine, budget)
    return check_lazy(model, bp, engine, budget)


def mode_of(bp: BoundProperty, default: PayoffMode) -> PayoffMode:
    """The payoff mode of ``bp``: its own (a payoff-source sweep's variant), else the job's."""
    own = bp.prop.payoffs
    return default if own is None else own


def check_all(
    model_of: ModelOf,
    bound: list[BoundProperty],
    mode: PayoffMode,
    engine: EngineName,
    budget: Budget,
    notes_of: Callable[[BoundProperty], list[str]],
    on_check: Callable[[BoundProperty], None],
) -> list[CheckResult]:
    """Every property of ``bound``, in order, each in its payoff mode (:func:`mode_of`,
    ``mode`` by default): :func:`check_payoffs` one by one, except that
    on attack payoffs the properties whose trees are the same (enumerate.tree_key: a
    sweep's variants, robustness and resilience of one window) are enumerated together,
    the tree walked once, when the engine is ``enumerate`` or the tree is small
    (engines.check.check_shared); on a larger tree, the variants of one property that
    differ only in the constraint's bound are searched loosest first, reusing answers
    (:func:`_bound_families`)."""
    results: dict[int, CheckResult] = {}
    groups: dict[tuple[object, ...], list[int]] = {}
    for i, bp in enumerate(bound):
        groups.setdefault((mode_of(bp, mode), *tree_key(bp)), []).append(i)
    for key, idx in groups.items():
        shared = key[0] == "attack" and len(idx) > 1
        if shared:
            model = model_of("attack")  # built (and announced) before its checks are
            for i in idx:
                on_check(bound[i])
            bps = [bound[i] for i in idx]
            many = check_shared(model, bps, engine, budget.for_check())
            if many is not None:
                results.update(zip(idx, many, strict=True))
                continue
            idx = _bound_families(bound, idx, model_of, engine, budget, results)
        for i in idx:
            own = mode_of(bound[i], mode)
            if not shared:  # announced above
                for payoffs in PAYOFF_SETS[own]:
                    model_of(payoffs)  # built (and announced) before the check is
                on_check(bound[i])
            results[i] = check_payoffs(model_of, bound[i], own, engine, budget, notes_of(bound[i]))
    return [results[i] for i in range(len(bound))]


def _bound_families(
    bound: list[BoundProperty],
    idx: list[int],
    model_of: ModelOf,
    engine: EngineName,
    budget: Budget,
    results: dict[int, CheckResult],
) -> list[int]:
    """Of properties ``idx`` (one tree, too large to walk whole), the variants of one
    property that differ only in the constraint's bound (an ε sweep) searched loosest
    first, each answered by a looser one's search when that counterexample satisfies
    the tighter constraint (engines.check.carried_over): one search per step of the
    optimum as a function of ε. Into ``results``; returns the properties left."""
    families: list[list[int]] = []
    for i in idx:
        fam = next((f for f in families if same_but_bound(bound[f[0]], bound[i])), None)
        if fam is None:
            families.append([i])
        else:
            fam.append(i)
    left = []
    for fam in families:
        if len(fam) == 1:
            left.extend(fam)
            continue
        last: CheckResult | None = None
        for j in loosest_first([bound[i] for i in fam]):
            i = fam[j]
            got = None if last is None else carried_over(last, bound[i])
            if got is None:
                got = check_model(model_of("attack"), bound[i], engine, budget.for_check())
            results[i] = got
            if got.stats.stopped == "finished":
                last = got
    return left


def check_payoffs(
    model_of: ModelOf,
    bp: BoundProperty,
    mode: PayoffMode,
    engine: EngineName,
    budget: Budget,
    certified_notes: list[str],
) -> CheckResult:
    """``bp`` checked in payoff mode ``mode`` within one check's share of ``budget``;
    ``certified_notes`` go with the certified result (detections without a bound)."""
    b = budget.for_check()
    chosen = payoff_modes.get(mode)
    got = []
    for i, payoffs in enumerate(chosen.sets):
        left = len(chosen.sets) - i
        r = check_model(model_of(payoffs), bp, engine, b if left == 1 else b.share(1 / left))
        if payoffs == "certified":
            r = replace(r, notes=[*r.notes, *certified_notes], payoffs="certified")
        got.append(r)
    return chosen.merge(got, bp)
