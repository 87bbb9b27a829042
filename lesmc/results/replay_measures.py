"""A results document's property as the replay judges it on the replayed run
(docs/semantics.md, "Replay", "Violated on the frames by another path"): its objective and
constraint bound again from what the document records (lesmc/results/read.py
``PropertyDoc``), through the measures registry (lesmc/language/measures/), for the
kernel (lesmc/model/kernel.py) to fold over the replayed run's steps.

Only properties whose objective is a cost the attack pays (the measure reads Eq. 5's
combined payoffs or their counts: ``payoff``, ``payoff.mean``, ``count``,
``count.frames``) and whose constraint is the deviation from the original path (Eq. 4:
the ``dist`` measures), with no monitor, are judged: :func:`judged_measures` says why
another one is not. ``count`` is judged only where the model's count is the number of
detections hidden, what the replay counts (windows perturbed): without injection, on a
design other than ``joint`` (docs/semantics.md, "Violated on the frames by another path").
"""

from __future__ import annotations

from dataclasses import dataclass

from lesmc.language import measures
from lesmc.language.semantics import BoundMeasure
from lesmc.results.read import PropertyDoc

#: The per-transition quantities of an attack's cost (lesmc/language/measures/base.py
#: ``Quantities``): the combined payoff and its count.
COST_QUANTITIES = ("combined", "counted")


@dataclass(frozen=True)
class Judged:
    """What the replay folds over the replayed run: the objective (a cost), the constraint
    (a deviation), its comparison and bound, Eq. 4's norm and components."""

    objective: BoundMeasure
    constraint: BoundMeasure
    op: str
    bound: float
    norm: float
    components: tuple[str, ...]


def judged_measures(
    prop: PropertyDoc, objective_source: str, objective_text: str, tracker: str
) -> Judged | str:
    """``prop``'s objective (``objective_source``, spelled ``objective_text``) and constraint
    bound to its window and range, or why the replay cannot judge it on the frames
    (``tracker``: the run's design's tracker, lesmc/designs/registry.py; "" unknown)."""
    if prop.monitor is not None:
        return "the property has a monitor, which the replay does not run"
    if prop.constraint_op is None or not prop.components or prop.window is None:
        return "the results do not record the constraint's comparison, components or window"
    if not measures.plotted(prop.constraint_source):
        return f"its constraint ({prop.constraint_source}) is no deviation from the original path"
    try:
        declared = measures.by_source(objective_source)
    except KeyError:
        return f"its objective ({objective_source}) is no measure this lesmc knows"
    if declared.quantity not in COST_QUANTITIES:
        return f"its objective ({objective_text}) is not a cost the attack pays"
    l, u = prop.window[0], prop.window[1]
    _, _, aggregate = objective_text.partition(".")
    bound = declared.bind(aggregate or "sum", l, u, l, u)
    if bound.source == "count" and (why := _count_differs(prop, tracker)):
        return f"its objective ({objective_text}) {why}"
    objective = BoundMeasure(bound.source, bound.aggregate, l, u, bound.weight, objective_text)
    lo, hi = prop.constraint_range[0], prop.constraint_range[1]
    constraint = BoundMeasure(
        prop.constraint_source, prop.constraint_aggregate, lo, hi, 1.0, prop.constraint_source
    )
    return Judged(objective, constraint, prop.constraint_op, prop.bound, prop.norm, prop.components)


def _count_differs(prop: PropertyDoc, tracker: str) -> str:
    """Why the model's ``count`` (Eq. 5 over unit payoffs: the outcomes ranked below the
    one taken) is not the number of windows the replay perturbs on this design, or ""
    where it is: the detections hidden, on ``single`` and the multi-target designs without
    injection. Under injection it counts cheaper outcomes, not detections; on ``joint`` the
    outcomes are joint states merged and ranked by cost, so even without injection a rank
    is not the number of detections hidden (docs/semantics.md, "Consequences")."""
    if "inject" in prop.actions:
        return "counts, under injection, the outcomes ranked below the one taken, not windows"
    if tracker == "joint":
        return "is the rank among the joint design's merged outcomes, not the windows perturbed"
    if not tracker:
        return "is counted by a design this lesmc does not know"
    return ""
