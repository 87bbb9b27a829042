"""The check of a multi-target design (``sort``, ``gnn``): a scene and spec files in, one
typed result per property out (docs/trackers.md, "Checking a multi-target design").

The scene is unfolded once per attack window, end, radius and actions
(lesmc/unfold/multi.py) and each property minimised on it (lesmc/engines/multi.py).
Objectives: ``payoff``, ``count``, ``count.frames`` or a ``dist`` measure; constraints:
``switches(a..b)``, ``lost(a..b)`` or a ``dist`` measure; anything else is a located
error. ``lesmc check --design sort`` (lesmc/cli/multi_check.py) prints these results and
``lesmc.check(..., designs="sort")`` (lesmc/api.py) returns them.
"""

from __future__ import annotations

import builtins
import math
from dataclasses import dataclass
from typing import Any

from lesmc.common.errors import Location, SpecError, UsageError, source_line
from lesmc.language.properties import Measure, Property, SpecFile
from lesmc.pipeline.multi_tracks import StepDrawing, step_drawings
from lesmc.scene import Scene

#: The version of the ``lesmc-multi-check`` document (2: each counterexample step holds
#: what the report draws: ``switch``, ``reference``, ``tracks``, ``attacked``).
MULTI_CHECK_VERSION = 2


@dataclass(frozen=True)
class AttackStep:
    """One step of a counterexample: the detections hidden and the candidates injected at
    it (``FRAME:K`` ids, as ``lesmc import mot`` numbers them) and the target's track id
    (None: the target has no track at this step); for the report (``lesmc-multi-check``
    version 2): every track after the step, the attacked detections' boxes, the
    reference box and whether the target's id switched here
    (lesmc/pipeline/multi_tracks.py)."""

    step: int
    frame: int
    hidden: tuple[str, ...]
    injected: tuple[str, ...]
    target_id: int | None
    drawing: StepDrawing | None = None

    def to_dict(self) -> dict[str, Any]:
        """The step as ``lesmc check --json`` prints it."""
        out: dict[str, Any] = {
            "step": self.step,
            "frame": self.frame,
            "hidden": list(self.hidden),
            "injected": list(self.injected),
            "target_id": self.target_id,
        }
        d = self.drawing
        if d is not None:
            out["switch"] = d.switch
            out["reference"] = None if d.reference is None else list(d.reference)
            out["tracks"] = list(d.tracks)
            out["attacked"] = list(d.attacked)
        return out


@dataclass(frozen=True)
class MultiCheckResult:
    """One property's result on a multi-target design. ``optimum`` is ``math.inf`` when
    no attack reaches the constraint (JSON: ``null``); ``constraint_value`` is the
    constraint's measure on the optimal path; ``counterexample`` the optimal path's steps
    (None when there is none); ``reference`` what the target's reference is (``truth`` or
    ``unattacked``)."""

    design: str
    reference: str
    property: str
    verdict: str  #: ``holds`` or ``violated``
    optimum: float
    constraint_value: float | None
    states: int
    transitions: int
    counterexample: tuple[AttackStep, ...] | None

    @builtins.property  # the field ``property`` shadows the builtin in the class body
    def status(self) -> str:
        """The verdict word (as :attr:`lesmc.engines.result.CheckResult.status`)."""
        return self.verdict

    def to_dict(self) -> dict[str, Any]:
        """The entry of ``results`` that ``lesmc check --design ... --json`` prints."""
        steps = self.counterexample
        value = self.constraint_value
        return {
            "property": self.property,
            "verdict": self.verdict,
            "optimum": None if math.isinf(self.optimum) else self.optimum,
            "constraint_value": "inf" if value == math.inf else value,
            "states": self.states,
            "transitions": self.transitions,
            "counterexample": None if steps is None else [s.to_dict() for s in steps],
        }


def check_multi_design(
    scene: Scene,
    path: str,
    specs: tuple[SpecFile, ...],
    only: tuple[str, ...] = (),
    max_states: int | None = None,
) -> list[MultiCheckResult]:
    """Each property of ``specs`` (those named in ``only``, or all) checked on the
    multi-target design of ``scene`` (read from ``path``, the name its errors give)."""
    from lesmc.engines.multi import check_multi
    from lesmc.language.semantics import bind
    from lesmc.model.multi import COMPONENTS
    from lesmc.unfold.multi import build_multi, composed

    design = composed(scene, path)
    e = len(scene.frames) - 1
    props = [(s, p) for s in specs for p in s.properties if not only or p.name in only]
    missing = set(only) - {p.name for _, p in props}
    if missing:
        raise UsageError(f"--property {sorted(missing)[0]}: no property of that name")
    models: dict[tuple[int, int, int, float | None, tuple[str, ...]], Any] = {}
    out: list[MultiCheckResult] = []
    kind = design.reference_kind()
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
        res = check_multi(models[key], b)
        steps = _steps(scene, design, models[key], b.objective.source, res.path)
        out.append(
            MultiCheckResult(
                scene.tracker.design,
                kind,
                prop.name,
                "holds" if res.holds else "violated",
                res.optimum,
                res.constraint,
                res.states,
                res.transitions,
                steps,
            )
        )
    return out


def multi_results(
    scene: Scene,
    path: str,
    specs: tuple[SpecFile, ...],
    only: tuple[str, ...] = (),
    max_states: int | None = None,
) -> list[dict[str, Any]]:
    """:func:`check_multi_design`'s results as the JSON entries ``lesmc check --json``
    prints."""
    return [r.to_dict() for r in check_multi_design(scene, path, specs, only, max_states)]


def multi_document(
    design: str,
    reference: str,
    results: list[MultiCheckResult],
    meta: dict[str, Any] | None = None,
    timings: dict[str, float] | None = None,
) -> dict[str, Any]:
    """The ``lesmc-multi-check`` document of ``results`` of ``design`` (``lesmc check
    --design sort --json`` prints it; ``lesmc verify --design sort`` writes it, with
    ``meta`` and ``timings``, as its results.json)."""
    doc: dict[str, Any] = {
        "format": "lesmc-multi-check",
        "version": MULTI_CHECK_VERSION,
        "design": design,
        "reference": reference,
        "results": [r.to_dict() for r in results],
    }
    if meta is not None:
        doc["meta"] = meta
    if timings is not None:
        doc["timings"] = {k: round(float(v), 3) for k, v in timings.items()}
    return doc


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


def _priced(scene: Scene, l: int, u: int) -> None:
    """A payoff objective needs the window's detections priced."""
    for f in scene.frames[l : u + 1]:
        for d in f.detections:
            if math.isnan(d.payoff):
                raise UsageError(
                    f"detection '{d.id}' of frame {f.step} has no payoff (unpriced): minimize "
                    "count or count.frames, or price the scene (lesmc perceive)"
                )


def _steps(
    scene: Scene, design: Any, model: Any, objective: str, path: Any
) -> tuple[AttackStep, ...] | None:
    """The counterexample's steps along ``path`` (the engine's transitions; None: no
    path), each with the detections hidden and the candidates injected at it, the
    target's track id and what the report draws of it."""
    if path is None:
        return None
    hidden = model.by_payoff if objective == "payoff" else model.by_count
    states = [0, *(int(model.dst[t]) for t in path)]
    subs: list[tuple[int, ...]] = [(), *(hidden[t] for t in path)]
    ids = [None if model.tid[s] < 0 else int(model.tid[s]) for s in states]
    frames = scene.frames[: len(subs)]
    drawn = step_drawings(design, frames, subs, model.detections, ids, model.refbox)
    return tuple(
        AttackStep(
            k,
            model.frames[k],
            tuple(model.names[k][j] for j in sub if j < model.detections[k]),
            tuple(model.names[k][j] for j in sub if j >= model.detections[k]),
            ids[k],
            drawn[k],
        )
        for k, sub in enumerate(subs)
    )
