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
from lesmc.language.parser import parse_spec
from lesmc.language.properties import Property, SpecFile
from lesmc.pipeline.multi import MultiCheckResult, bound_properties, check_multi_design
from lesmc.results.document import num
from lesmc.tracking.targets import place_target

#: The engine a multi-target row names in its ``stats`` (lesmc/engines/multi.py).
ENGINE = "multi"


def run_multi_group(group: Group, footage: Any) -> list[dict[str, Any]]:
    """Check every unit of ``group`` (a multi-target design's) on ``footage``, the video's
    scene without a target; one row per unit. One model per (window, design) is built
    for all the properties that share its attack window, radius and actions."""
    specs = [parse_spec(text, path) for path, text in group.specs]
    scene = place_target(footage, group.target)
    by_run: dict[tuple[tuple[int, int], str], list[Unit]] = {}
    for u in group.units:
        by_run.setdefault((u.window, u.design), []).append(u)
    rows = []
    for (window, design), units in by_run.items():
        moved = design_specs(specs, window, design)
        t0 = time.monotonic()
        results = check_multi_design(
            scene.with_tracker(design=design),
            f"<scene of {group.video}>",
            tuple(moved),
            tuple(u.prop for u in units),
            group.max_states,
        )
        seconds = (time.monotonic() - t0) / max(len(results), 1)
        props = {p.name: (s, p) for s in moved for p in s.properties}
        bound = bound_properties(moved, scene)
        keys = {u.prop: u.key for u in units}
        for r in results:
            spec, prop = props[r.property]
            source = bound[r.property].objective.source
            rows.append(multi_row(group, keys[r.property], window, r, spec, prop, source, seconds))
    return rows


def multi_row(
    group: Group,
    key: str,
    window: tuple[int, int],
    r: MultiCheckResult,
    spec: SpecFile,
    prop: Property,
    source: str,
    seconds: float,
) -> dict[str, Any]:
    """The ``results.jsonl`` object of one multi-target unit: the point designs' fields
    (lesmc/campaign/work.py ``row``), the exact optimum as both bounds, and the
    constraint's value on the counterexample as ``witness_value``."""
    steps = r.counterexample or ()
    value = r.constraint_value
    return {
        "key": key,
        "video": group.video,
        "target": {"step": group.target.step, "x": group.target.x, "y": group.target.y},
        "window": [window[0], window[1]],
        "design": r.design,
        "property": r.property,
        "spec": spec.path,
        "objective_source": source,
        "verdict": r.verdict,
        "status": "violated (not replayed)" if r.verdict == "violated" else "holds",
        "vacuous": False,
        "optimum": num(r.optimum),
        "witness_value": None if value is None else num(value),
        "bounds": [num(r.optimum), num(r.optimum)],
        "holds_op": prop.holds_op,
        "threshold": prop.threshold,
        "holds_if": f"optimum {prop.holds_op} {prop.threshold:g}",
        "stats": {
            "engine": ENGINE,
            "states_expanded": r.states,
            "transitions": r.transitions,
            "seconds": round(seconds, 6),
            "stopped": "finished",
        },
        "attacked_frames": (
            sum(1 for s in steps if s.hidden or s.injected) if r.verdict == "violated" else None
        ),
    }
