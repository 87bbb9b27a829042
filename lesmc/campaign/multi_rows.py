"""A campaign group of a multi-target design (``sort``, ``gnn``): its units checked by the
multi-target check (lesmc/pipeline/multi.py), as ``lesmc verify --scene SCENE --target
X,Y@STEP --window L..U --design sort`` checks them, one row per unit (docs/campaign.md,
"Multi-target designs"). The campaign does not replay: a violation is ``violated (not
replayed)``, as the point designs' rows are.
"""

from __future__ import annotations

import time
from typing import Any

from lesmc.campaign.plan import Group, Unit, design_specs
from lesmc.common.budget import Budget
from lesmc.common.errors import BudgetError
from lesmc.engines import registry as engines
from lesmc.language.parser import parse_spec
from lesmc.language.properties import Property, SpecFile
from lesmc.pipeline.multi import MultiCheckResult, bound_properties, check_multi_design
from lesmc.results.document import num
from lesmc.tracking.targets import place_target


def run_multi_group(group: Group, footage: Any) -> list[dict[str, Any]]:
    """Check every unit of ``group`` (a multi-target design's) on ``footage``, the video's
    scene without a target; one row per unit. One model per (window, design) is built
    for all the properties that share its attack window, radius and actions; a model
    past ``--max-states`` makes its units' rows ``unknown``, and so does a unit's check
    (unfolding included) past ``--timeout`` (stats.stopped ``timeout``)."""
    specs = [parse_spec(text, path) for path, text in group.specs]
    scene = place_target(footage, group.target)
    by_run: dict[tuple[tuple[int, int], str], list[Unit]] = {}
    for u in group.units:
        by_run.setdefault((u.window, u.design), []).append(u)
    rows = []
    for (window, design), units in by_run.items():
        moved = design_specs(specs, window, design)
        props = {p.name: (s, p) for s in moved for p in s.properties}
        bound = bound_properties(moved, scene)
        t0 = time.monotonic()
        try:
            results = check_multi_design(
                scene.with_tracker(design=design),
                group.scene_file or group.video,
                tuple(moved),
                tuple(u.prop for u in units),
                group.max_states,
                budget=Budget(check_timeout=group.timeout),
            )
        except BudgetError:
            results = []
        seconds = (time.monotonic() - t0) / max(len(units), 1)
        got = {r.property: r for r in results}
        for u in units:
            spec, prop = props[u.prop]
            row = _base(group, u, spec, prop, bound[u.prop].objective.source)
            rows.append(row | _answer(got.get(u.prop), prop, seconds))
    return rows


def _base(group: Group, u: Unit, spec: SpecFile, prop: Property, source: str) -> dict[str, Any]:
    """What a row says of its unit before any check: the point designs' fields
    (lesmc/campaign/work.py ``row``)."""
    return {
        "key": u.key,
        "video": group.video,
        "target": {"step": group.target.step, "x": group.target.x, "y": group.target.y},
        "window": [u.window[0], u.window[1]],
        "design": u.design,
        "property": u.prop,
        "spec": spec.path,
        "objective_source": source,
        "vacuous": False,
        "holds_op": prop.holds_op,
        "threshold": prop.threshold,
        "holds_if": f"optimum {prop.holds_op} {prop.threshold:g}",
    }


def _answer(r: MultiCheckResult | None, prop: Property, seconds: float) -> dict[str, Any]:
    """The check's answer in a row: the exact optimum as both bounds (a check stopped by
    ``--timeout``: its bounds, ``unknown`` unless they decide it) and the constraint's
    value on the counterexample as ``witness_value``; None: the model passed
    ``--max-states`` (``unknown``, nothing known)."""
    stats = {"engine": engines.MULTI, "seconds": round(seconds, 6)}
    if r is None:
        return {
            "verdict": "unknown",
            "status": "unknown",
            "optimum": "unknown",
            "witness_value": None,
            "bounds": [None, None],
            "stats": stats | {"states_expanded": 0, "stopped": "max_states"},
            "attacked_frames": None,
        }
    steps = r.counterexample or ()
    value = r.constraint_value
    violated = r.verdict == "violated"
    lower, upper = (r.optimum, r.optimum) if r.bounds is None else r.bounds
    expanded = r.states if r.states_expanded is None else r.states_expanded
    return {
        "verdict": r.verdict,
        "status": "violated (not replayed)" if violated else r.verdict,
        "optimum": num(r.optimum) if r.optimum_known else "unknown",
        "witness_value": None if value is None else num(value),
        "bounds": [num(lower), num(upper)],
        "stats": stats
        | {"states_expanded": expanded, "transitions": r.transitions, "stopped": r.stopped},
        "attacked_frames": sum(1 for s in steps if s.hidden or s.injected) if violated else None,
    }
