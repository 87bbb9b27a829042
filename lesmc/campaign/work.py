"""One group of units on one unfolded model: what a Dask worker (or the serial mode) runs.

The worker gets the scene as its JSON document (one task per video) and
the spec files as text, so it reads no file. It states the group as one
:class:`~lesmc.pipeline.job.Job` (the same pipeline as ``lesmc verify``) and
answers with plain rows (JSON objects), written to ``results.jsonl`` by the
client alone.
"""

from __future__ import annotations

from typing import Any

from lesmc.campaign.plan import Group
from lesmc.common.budget import Budget
from lesmc.designs import registry
from lesmc.engines.result import CheckResult
from lesmc.language.parser import parse_spec
from lesmc.pipeline.check import run
from lesmc.pipeline.job import Job, Unit
from lesmc.results.document import num
from lesmc.scene import Footage, footage_from_dict
from lesmc.tracking.targets import place_target

#: The scenes this process has parsed, by content key (a worker serves many groups).
_FOOTAGE: dict[str, Footage] = {}


def footage_of(key: str, doc: dict[str, Any]) -> Footage:
    """The scene ``doc`` parsed once per process (it is validated as any scene file)."""
    got = _FOOTAGE.get(key)
    if got is None:
        if len(_FOOTAGE) >= 4:  # a worker of a many-video campaign keeps a few
            _FOOTAGE.pop(next(iter(_FOOTAGE)))
        got = footage_from_dict(doc, "scene")[0]
        _FOOTAGE[key] = got
    return got


def scene_doc(doc: dict[str, Any]) -> dict[str, Any]:
    """The scene document, as a task: the cluster keeps its input, so it can
    compute it again when every worker that held it has died (scattered data
    would be lost for good)."""
    return doc


def group_job(group: Group, doc: dict[str, Any]) -> Job:
    """The group as a job: its designs and windows on the target's scene, the units not yet
    done, each check within ``group.timeout`` seconds and ``group.max_states`` states.

    One model per payoff set is unfolded over the union of the units' windows;
    each property sees only its own window's attacks (lesmc/engines/lazy.py), so
    every row is what ``lesmc verify --window L..U --payoffs MODE`` answers for it.
    """
    scene = place_target(footage_of(group.scene_key, doc), group.target)
    keys = {(u.design, u.window, u.prop) for u in group.units}

    def wanted(u: Unit) -> bool:
        return (u.design, u.window, u.prop) in keys

    return Job(
        tuple(parse_spec(text, path) for path, text in group.specs),
        scene=scene,
        designs=tuple(dict.fromkeys(u.design for u in group.units)),
        windows=tuple(sorted({u.window for u in group.units})),
        payoffs=group.payoffs,
        budget=Budget(max_states=group.max_states, check_timeout=group.timeout),
        wanted=wanted,
        unbounded=lambda _tracker, window: group.unbounded_in(window),
        source="scene",
    )


def run_group(group: Group, doc: dict[str, Any]) -> list[dict[str, Any]]:
    """Check every unit of ``group``; one row per unit (a multi-target design's group:
    lesmc/campaign/multi_rows.py)."""
    if not group.units:
        return []
    if registry.get(group.units[0].design).multi:
        from lesmc.campaign.multi_rows import run_multi_group

        return run_multi_group(group, footage_of(group.scene_key, doc))
    keys = {(u.design, u.window, u.prop): u.key for u in group.units}
    rows = []
    for dr in run(group_job(group, doc)).runs:
        assert dr.window is not None
        for r in dr.results:
            rows.append(
                row(group, keys[(dr.design, dr.window, r.property)], dr.window, dr.design, r)
            )
    return rows


def row(
    group: Group, key: str, window: tuple[int, int], design: str, r: CheckResult
) -> dict[str, Any]:
    """The ``results.jsonl`` object of one unit (docs/campaign.md)."""
    stats = r.stats.to_json()
    if r.certified_stats is not None:
        stats["certified"] = r.certified_stats.to_json()
    extra: dict[str, Any] = {}
    if r.payoffs != "attack":
        extra = {"payoffs": r.payoffs, "notes": list(r.notes)}
    if r.sweep:
        extra["sweep"] = r.sweep_json()
    if r.payoffs == "interval":
        extra |= {
            "optimum_certified": num(r.optimum_certified),
            "optimum_attack": num(r.optimum_attack),
        }
    return {
        "key": key,
        "video": group.video,
        "target": {"step": group.target.step, "x": group.target.x, "y": group.target.y},
        "window": [window[0], window[1]],
        "design": design,
        "property": r.property,
        "spec": r.spec,
        "objective_source": r.objective_source,
        "verdict": r.verdict,
        "status": r.status,
        "vacuous": r.vacuous,
        "optimum": r.optimum_json(),
        "witness_value": num(r.witness_value),
        "bounds": [num(r.lower), num(r.upper)],
        "holds_op": r.holds_op,
        "threshold": r.threshold,
        "holds_if": f"optimum {r.holds_op} {r.threshold:g}",
        "stats": stats,
        "original_alarms": r.original_alarms,
        "attacked_frames": attacked_frames(r),
    } | extra


def attacked_frames(r: CheckResult) -> int | None:
    """How many frames the counterexample's attacker touches (its steps whose outcome is not
    the unattacked one, rank > 0); None without a counterexample."""
    if r.verdict != "violated" or r.counterexample is None:
        return None
    return sum(1 for s in r.counterexample.steps if s.attacked and (s.rank or 0) > 0)
