"""One group of units on one unfolded model: what a Dask worker (or the serial mode) runs.

The worker gets the scene as its JSON document (one task per video) and
the spec files as text, so it reads no file. Its answer is plain rows (JSON
objects), written to ``results.jsonl`` by the client alone.
"""

from __future__ import annotations

import math
from typing import Any

from lesmc.campaign.plan import Group, Unit, design_specs
from lesmc.engines.result import CheckResult
from lesmc.language.properties import SpecFile
from lesmc.language.semantics import BoundProperty
from lesmc.tracking.scene import Footage, Scene

#: The note of a unit whose window's probe a budget stopped (lesmc.campaign.run.probe).
PROBE_STOPPED_NOTE = (
    "finding the detections this window's model can hide stopped at the campaign's "
    "--max-states or --timeout: some may carry no certified bound and count as 0, the "
    "trivial bound (the certified optimum is sound but may be far below the true one)"
)

#: The scenes this process has parsed, by content key (a worker serves many groups).
_FOOTAGE: dict[str, Footage] = {}


def footage_of(key: str, doc: dict[str, Any]) -> Footage:
    """The scene ``doc`` parsed once per process (it is validated as any scene file)."""
    from lesmc.tracking.scene import footage_from_dict

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


def run_group(group: Group, doc: dict[str, Any]) -> list[dict[str, Any]]:
    """Check every unit of ``group`` on one lazily unfolded model; one row per unit.

    The model is unfolded for the union of the units' windows; each property
    sees only its own window's attacks (a rank-minimal transition elsewhere),
    so every row is what ``lesmc verify --window L..U --payoffs MODE`` answers
    for it. Each check has ``group.timeout`` seconds: past it the row is
    'unknown' with the bounds found. Payoff modes other than ``attack`` check a
    second model, of the certified lower payoffs (``interval``: both, combined
    by lesmc/engines/interval.py), with a budget of its own.
    """
    from dataclasses import replace

    from lesmc.engines.interval import combine
    from lesmc.language.parser import parse_spec
    from lesmc.tracking.targets import place_target
    from lesmc.unfold import payoff_monotone, unbounded_text

    if not group.units:
        return []
    scene = place_target(footage_of(group.scene_key, doc), group.target)
    scene = scene.with_tracker(design=group.tracker)
    specs = [parse_spec(text, path) for path, text in group.specs]
    window = (min(u.window[0] for u in group.units), max(u.window[1] for u in group.units))
    attack = None if group.payoffs == "certified" else _Checker(scene, window, group)
    low = None if group.payoffs == "attack" else _Checker(scene.priced("certified"), window, group)
    rows = []
    for u in group.units:
        if low is None:
            assert attack is not None
            rows.append(row(group, u.key, u.window, u.design, attack.check(u, specs)[0]))
            continue
        cert, bp = low.check(u, specs)
        # from the client's probe of the unit's window: the lazy model's own reads also
        # come from the other units' paths, which the unit's attacks may not reach
        n = group.unbounded_in(u.window)
        notes = unbounded_text(n) if n >= 0 else [PROBE_STOPPED_NOTE]
        cert = replace(cert, notes=[*cert.notes, *notes])
        if attack is None:
            rows.append(row(group, u.key, u.window, u.design, replace(cert, payoffs="certified")))
        else:
            r = combine(cert, attack.check(u, specs)[0], payoff_monotone(bp))
            rows.append(row(group, u.key, u.window, u.design, r, cert))
    return rows


class _Checker:
    """The units' checks on one scene's lazily unfolded model (built at the first check)."""

    def __init__(self, scene: Scene, window: tuple[int, int], group: Group) -> None:
        from lesmc.unfold import original_end

        self.scene = scene
        self.window = window
        self.group = group
        self.end = original_end(scene)  # the same for every unit (and payoff set) of the group
        self.model: Any = None

    def check(self, u: Unit, specs: list[SpecFile]) -> tuple[CheckResult, BoundProperty]:
        """Unit ``u``'s property checked on this model, and the property as bound."""
        from lesmc.engines.check import check_lazy
        from lesmc.unfold import bind_scene, lazy_model

        found = bind_scene(self.scene, design_specs(specs, u.window, u.design), self.end)
        bp = next(b for b in found if b.name == u.prop)
        if self.model is None:
            self.model = lazy_model(self.scene, self.window, bp.end)
        return check_lazy(self.model, bp, self.group.max_states, self.group.timeout), bp


def row(
    group: Group,
    key: str,
    window: tuple[int, int],
    design: str,
    r: CheckResult,
    certified: CheckResult | None = None,
) -> dict[str, Any]:
    """The ``results.jsonl`` object of one unit (docs/campaign.md); ``certified``: the
    check with certified payoffs behind an interval result."""
    stats = r.stats.to_json()
    exact = r.stats.stopped == "finished"
    if certified is not None:
        stats["certified"] = certified.stats.to_json()
        exact = exact and certified.stats.stopped == "finished"
    optimum: float | str | None = r.optimum
    if r.payoffs == "interval" and not r.optimum_known and exact:
        optimum = "unknown"  # strictly between optimum_certified and optimum_attack
    elif r.optimum is None and exact:
        optimum = "inf"  # no attacked path violates
    extra: dict[str, Any] = {}
    if r.payoffs != "attack":
        extra = {"payoffs": r.payoffs, "notes": list(r.notes)}
    if r.payoffs == "interval":
        extra |= {
            "optimum_certified": _num(r.optimum_certified),
            "optimum_attack": _num(r.optimum_attack),
        }
    return (
        {
            "key": key,
            "video": group.video,
            "target": {"step": group.target.step, "x": group.target.x, "y": group.target.y},
            "window": [window[0], window[1]],
            "design": design,
            "property": r.property,
            "verdict": r.verdict,
            "optimum": optimum,
            "witness_value": _num(r.witness_value),
            "bounds": [_num(r.lower), _num(r.upper)],
            "holds_if": f"optimum {r.holds_op} {r.threshold:g}",
            "stats": stats,
        }
        | r.monitor_json()
        | extra
    )  # monitored: the original's alarms, and vacuity


def _num(x: float | None) -> float | str | None:
    """JSON has no infinity: "inf" / "-inf" as strings (as in ``lesmc check --json``)."""
    if x is None or math.isfinite(x):
        return x
    return "inf" if x > 0 else "-inf"
