"""``lesmc check SCENE SPEC --design sort`` (or ``gnn``): the exact cheapest identity attack on a
multi-target design (docs/trackers.md, "Checking a multi-target design").

The scene is unfolded once per attack window and end (lesmc/unfold/multi.py) and each
property minimised on it (lesmc/engines/multi.py). Objectives: ``payoff``, ``count``,
``count.frames`` or a ``dist`` measure; constraints: ``switches(a..b)``, ``lost(a..b)`` or
a ``dist`` measure (the track of the target's id against its reference, on the box's
x, y, w, h); anything else is an error (exit status 2), as are the options a
multi-target check does not take yet.
"""

from __future__ import annotations

import json
import math
import sys
from typing import Any

import click

from lesmc.common.errors import Location, SpecError, UsageError, source_line
from lesmc.language.properties import Measure, Property, SpecFile
from lesmc.scene import Scene


def _unsupported(spec: SpecFile, what: str, m: Measure) -> SpecError:
    loc = Location(spec.path, m.pos.line, m.pos.column, source_line(spec.text, m.pos.line))
    return SpecError(f"{what} (multi-target designs: not supported yet)", loc)


def _supported(spec: SpecFile, prop: Property) -> None:
    """The property is one the multi-target engine answers."""
    from lesmc.engines.multi import CONSTRAINTS

    obj, con = prop.objective, prop.constraint.measure
    if obj.kind not in ("payoff", "count", "dist") or obj.aggregate == "nearest":
        raise _unsupported(
            spec, f"objective '{obj.text()}': minimize payoff, count or a dist measure", obj
        )
    if con.kind not in (*CONSTRAINTS, "dist") or con.aggregate == "nearest":
        raise _unsupported(
            spec,
            f"constraint '{con.text()}': the constraint must be switches, lost or a dist measure",
            con,
        )
    if prop.monitor is not None:
        raise _unsupported(spec, "'monitor uncertainty'", obj)


def check_multi_scene(
    scene: Scene,
    path: str,
    specs: tuple[SpecFile, ...],
    only: tuple[str, ...],
    as_json: bool,
    max_states: int | None = None,
) -> None:
    """Check every property (or those named in ``only``) of ``specs`` on the multi-target
    design of ``scene``; print the results; exit 0 (all hold) or 1 (some violated)."""
    from lesmc.tracking.trackers import make_multi

    out = multi_results(scene, path, specs, only, max_states)
    kind = make_multi(scene, path).reference_kind()
    _print(out, scene.tracker.design, kind, as_json)
    sys.exit(0 if all(r["verdict"] == "holds" for r in out) else 1)


def multi_results(
    scene: Scene,
    path: str,
    specs: tuple[SpecFile, ...],
    only: tuple[str, ...] = (),
    max_states: int | None = None,
) -> list[dict[str, Any]]:
    """Each property's result (:func:`_entry`) on the multi-target design of ``scene``."""
    from lesmc.engines.multi import check_multi
    from lesmc.language.semantics import bind
    from lesmc.model.multi import COMPONENTS
    from lesmc.tracking.multi import ComposedDesign
    from lesmc.tracking.trackers import make_multi
    from lesmc.unfold.multi import build_multi

    design = make_multi(scene, path)
    assert isinstance(design, ComposedDesign)
    e = len(scene.frames) - 1
    props = [(s, p) for s in specs for p in s.properties if not only or p.name in only]
    missing = set(only) - {p.name for _, p in props}
    if missing:
        raise UsageError(f"--property {sorted(missing)[0]}: no property of that name")
    models: dict[tuple[int, int, int, float | None, tuple[str, ...]], Any] = {}
    out: list[dict[str, Any]] = []
    for spec, prop in props:
        _supported(spec, prop)
        b = bind(spec, prop, e, COMPONENTS, False, multi=True)
        if b.objective.source == "payoff":
            _priced(scene, b.l, b.u)
        key = (b.l, b.u, b.end, b.radius, prop.actions)
        if key not in models:
            models[key] = build_multi(
                scene, design, (b.l, b.u), b.end, max_states, b.radius, actions=prop.actions
            )
        model = models[key]
        res = check_multi(model, b)
        out.append(_entry(prop, b.objective.source, model, res))
    return out


def _priced(scene: Scene, l: int, u: int) -> None:
    """A payoff objective needs the window's detections priced."""
    for f in scene.frames[l : u + 1]:
        for d in f.detections:
            if math.isnan(d.payoff):
                raise UsageError(
                    f"detection '{d.id}' of frame {f.step} has no payoff (unpriced): minimize "
                    "count or count.frames, or price the scene (lesmc perceive)"
                )


def _entry(prop: Property, objective: str, model: Any, res: Any) -> dict[str, Any]:
    """One property's result as JSON: verdict, optimum and the counterexample's steps, each
    with the detections hidden and the candidates injected at it (``FRAME:K`` ids) and
    the target's track id."""
    steps = None
    if res.path is not None:
        hidden = model.by_payoff if objective == "payoff" else model.by_count
        states = [0, *(int(model.dst[t]) for t in res.path)]
        subs: list[tuple[int, ...]] = [(), *(hidden[t] for t in res.path)]
        steps = [
            {
                "step": k,
                "frame": model.frames[k],
                "hidden": [model.names[k][j] for j in sub if j < model.detections[k]],
                "injected": [model.names[k][j] for j in sub if j >= model.detections[k]],
                "target_id": None if model.tid[s] < 0 else int(model.tid[s]),
            }
            for k, (s, sub) in enumerate(zip(states, subs, strict=True))
        ]
    return {
        "property": prop.name,
        "verdict": "holds" if res.holds else "violated",
        "optimum": None if math.isinf(res.optimum) else res.optimum,
        "constraint_value": "inf" if res.constraint == math.inf else res.constraint,
        "states": res.states,
        "transitions": res.transitions,
        "counterexample": steps,
    }


def _print(out: list[dict[str, Any]], design: str, reference: str, as_json: bool) -> None:
    if as_json:
        doc = {
            "format": "lesmc-multi-check",
            "version": 1,
            "design": design,
            "reference": reference,
            "results": out,
        }
        click.echo(json.dumps(doc, indent=1))
        return
    for r in out:
        opt = "inf" if r["optimum"] is None else f"{r['optimum']:g}"
        click.echo(
            f"{r['property']}: {r['verdict']}, optimum {opt} "
            f"({r['states']} states, {r['transitions']} transitions)"
        )
        for s in r["counterexample"] or []:
            hid = ", ".join(s["hidden"]) or "-"
            inj = f"; injected {', '.join(s['injected'])}" if s["injected"] else ""
            click.echo(
                f"  step {s['step']} frame {s['frame']}: hidden {hid}{inj}; target {s['target_id']}"
            )
