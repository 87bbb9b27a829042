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
from dataclasses import dataclass, replace
from typing import TYPE_CHECKING, Any, cast

from lesmc.common.budget import Budget, SearchBudget
from lesmc.common.errors import InputError, ModelError, UsageError
from lesmc.engines.multi import (
    BuildKey,
    MultiResult,
    bind_model,
    bind_multi,
    build_key,
    unpriced_text,
)
from lesmc.engines.result import StopReason
from lesmc.language.properties import Property, SpecFile
from lesmc.language.semantics import BoundProperty
from lesmc.model.multi import MultiModel
from lesmc.pipeline.multi_tracks import StepDrawing, step_drawings
from lesmc.results.document import num
from lesmc.scene import Scene

if TYPE_CHECKING:
    from lesmc.unfold.multi import UnfoldStopped

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
    ``unattacked``).

    A check stopped by its budget (``stopped``: ``timeout``, ``interrupted``) says so as the
    point designs' results do: ``bounds`` (lower, upper) on the optimum, the best path
    found (its steps as ``counterexample``, its cost ``optimum`` when ``optimum_known``,
    else JSON ``"unknown"``), ``states_expanded`` and a note; the verdict is ``unknown``
    unless the bounds decide it (lesmc/engines/check.py ``bounded_verdict``)."""

    design: str
    reference: str
    property: str
    verdict: str  #: ``holds`` or ``violated``
    optimum: float
    constraint_value: float | None
    states: int
    transitions: int
    counterexample: tuple[AttackStep, ...] | None
    stopped: str = "finished"
    optimum_known: bool = True
    bounds: tuple[float, float] | None = None  #: None: the search finished
    states_expanded: int | None = None
    notes: tuple[str, ...] = ()

    @builtins.property  # the field ``property`` shadows the builtin in the class body
    def status(self) -> str:
        """The verdict word (as :attr:`lesmc.engines.result.CheckResult.status`)."""
        return self.verdict

    def to_dict(self) -> dict[str, Any]:
        """The entry of ``results`` that ``lesmc check --design ... --json`` prints."""
        steps = self.counterexample
        value = self.constraint_value
        out: dict[str, Any] = {
            "property": self.property,
            "verdict": self.verdict,
            "optimum": (None if math.isinf(self.optimum) else self.optimum)
            if self.optimum_known
            else "unknown",
            "constraint_value": "inf" if value == math.inf else value,
            "states": self.states,
            "transitions": self.transitions,
            "counterexample": None if steps is None else [s.to_dict() for s in steps],
            "stopped": self.stopped,
        }
        if self.bounds is not None:
            out["bounds"] = {"lower": num(self.bounds[0]), "upper": num(self.bounds[1])}
            out["states_expanded"] = self.states_expanded
        if self.bounds is not None or self.notes:
            out["notes"] = list(self.notes)
        return out


#: The check arguments the exact search of a multi-target design does not read, each with
#: why (``lesmc.check``'s names; ``lesmc check`` spells them ``--engine``, ``--timeout``):
#: refused when given, by the API (lesmc/api.py) and the command line (lesmc/cli/check.py).
DESIGN_IGNORES: dict[str, str] = {
    "engine": "a multi-target design has one search",
}

#: The check arguments the search of a built multi-target model does not read (its one
#: search, on the model as built, with the payoffs it was built with), each with why:
#: refused when given, by the API and the command line alike.
MODEL_IGNORES: dict[str, str] = {
    "engine": "a multi-target model has one search",
    "payoffs": "a model's are built in",
    "max_states": "a built multi-target model is searched whole",
}


def check_multi_design(
    scene: Scene,
    path: str,
    specs: tuple[SpecFile, ...],
    only: tuple[str, ...] = (),
    max_states: int | None = None,
    draw: bool = False,
    budget: Budget | None = None,
) -> list[MultiCheckResult]:
    """Each property of ``specs`` (those named in ``only``, or all) checked on the
    multi-target design of ``scene`` (read from ``path``, the name its errors give); with
    ``draw``, each counterexample step also holds what the report draws of it (every
    track: ``lesmc verify`` and ``check --report``), else the steps are those a check of
    the built model gives. Each property gets :meth:`Budget.check_seconds` of ``budget``
    (the unfolding of a model it is the first to need included); past them it is
    ``unknown`` (:class:`MultiCheckResult`). A model whose unfolding ran out of time is
    not unfolded again for the properties that share it: they are ``unknown`` too."""
    from lesmc.unfold.multi import UnfoldStopped

    models: dict[BuildKey, MultiModel | UnfoldStopped] = {}
    out: list[MultiCheckResult] = []
    for spec, prop in _chosen(specs, only):
        b = bind_multi(spec, prop, len(scene.frames) - 1)
        if b.objective.declared.reads_payoffs:
            _priced(scene, b.l, b.u)
        key, search = build_key(b), _search(budget)
        if key not in models:
            try:
                models[key] = build_for(scene, path, key, max_states, search)
            except UnfoldStopped as stop:
                models[key] = stop
        got = models[key]
        if isinstance(got, UnfoldStopped):
            out.append(_unfinished(scene, path, b, got))
        else:
            out.append(_result(got, b, scene if draw else None, path, search))
    return out


def _search(budget: Budget | None) -> SearchBudget | None:
    """The running deadline of one property's check starting now (None: no budget)."""
    if budget is None:
        return None
    return SearchBudget(None, budget.check_seconds())


#: The modules a multi-target check imports as it runs (the unfolding, SORT's and GNN's
#: assignment, the verdict rule of a stopped check): :func:`preload` imports them.
RUNS_ON = ("lesmc.unfold.multi", "scipy.optimize", "lesmc.engines.check")


def preload() -> None:
    """Import :data:`RUNS_ON` now: a command sets its ``--timeout`` alarm after this, so
    that the check's first look at the clock comes before any long import (one that looks
    at no clock; scipy's takes about a second on a loaded machine)."""
    import importlib

    for name in RUNS_ON:
        importlib.import_module(name)


def bound_properties(specs: list[SpecFile], scene: Scene) -> dict[str, BoundProperty]:
    """Every property of ``specs`` bound to the multi-target model of ``scene``, by name
    (what the replay of its counterexamples checks them with: lesmc/replay/multi.py)."""
    last = len(scene.frames) - 1
    return {p.name: bind_multi(s, p, last) for s in specs for p in s.properties}


def check_multi_model(
    model: MultiModel,
    specs: tuple[SpecFile, ...],
    only: tuple[str, ...] = (),
    budget: Budget | None = None,
) -> list[MultiCheckResult]:
    """Each property of ``specs`` (those named in ``only``, or all) checked on a built
    multi-target model (``lesmc check MODEL SPEC``): the same results as checking the
    scene it was built from, for the properties whose attack window, end, radius and
    actions are the model's (any other is a located error); each within what is left of
    ``budget``'s time, as :func:`check_multi_design`."""
    out: list[MultiCheckResult] = []
    for spec, prop in _chosen(specs, only):
        b = bind_model(model, spec, prop)
        out.append(_result(model, b, search=_search(budget)))
    return out


def build_for(
    scene: Scene,
    path: str,
    key: BuildKey,
    max_states: int | None = None,
    search: SearchBudget | None = None,
) -> MultiModel:
    """The model of ``scene``'s multi-target design (read from ``path``, the name its
    errors give) unfolded for ``key`` (:func:`build_key`), with what it was built for in
    its ``meta`` (the file's header: lesmc/model/multi_format.py); past ``search``'s
    deadline an :class:`~lesmc.unfold.multi.UnfoldStopped`."""
    from lesmc.unfold.multi import build_multi, composed

    design = composed(scene, path)
    l, u, end, radius, actions = key
    model = build_multi(
        scene, design, (l, u), end, max_states, radius, actions=actions, search=search
    )
    first = next(
        ((f.step, d.id) for f in scene.frames[l : u + 1] for d in f.detections if not d.priced),
        None,
    )
    meta = {
        "design": scene.tracker.design,
        "tracker": scene.tracker.to_json(),
        "reference": design.reference_kind(),
        "radius": radius,
        "actions": list(actions),
        "last_step": len(scene.frames) - 1,
        "unpriced": None if first is None else [first[0], first[1]],
    }
    return replace(model, meta=meta)


def build_within(
    scene: Scene, path: str, key: BuildKey, max_states: int | None, budget: Budget, limit: str
) -> MultiModel:
    """:func:`build_for` within what is left of ``budget``'s time (``lesmc build``,
    ``lesmc.build``): past it a BudgetError (exit 3, nothing written) naming ``limit``
    (``--timeout 9 s``), the step and the states made."""
    from lesmc.common.errors import BudgetError
    from lesmc.unfold.multi import UnfoldStopped

    try:
        return build_for(scene, path, key, max_states, _search(budget))
    except UnfoldStopped as stop:
        what = limit if stop.reason == "timeout" else stop.reason
        raise BudgetError(
            f"{what} ran out while unfolding the model, before step {stop.step} "
            f"({stop.states} states made); nothing was written"
        ) from None


def check_meta(model: MultiModel, where: str) -> MultiModel:
    """``model`` (read from ``where``) if its header's ``meta.design`` is a registered
    multi-target design and ``meta.tracker`` a valid tracker block of that design, as
    :func:`build_for` writes them (the model layer cannot read the registry); else a
    located ModelError, exit 2."""
    from lesmc.designs import registry
    from lesmc.scene.tracker_file import tracker_from_dict

    design, tracker = model.meta.get("design"), model.meta.get("tracker")
    multi = tuple(n for n in registry.tracker_names() if registry.get(n).multi)
    if design not in multi:
        got = design if isinstance(design, str) else str(design)
        raise ModelError.many(
            where, [("header.meta.design", f"must be {' or '.join(multi)}, got {got!r}")]
        )
    try:
        cfg = tracker_from_dict(tracker, "header.meta.tracker")
    except InputError as exc:
        raise ModelError.many(where, [("", line) for line in exc.render().splitlines()]) from None
    if cfg.design != design:
        raise ModelError.many(
            where,
            [("header.meta.tracker", f"design {cfg.design!r} must be meta.design {design!r}")],
        )
    return model


def property_key(scene: Scene, spec: SpecFile, name: str | None) -> BuildKey:
    """What the model of ``scene`` is unfolded for to check property ``name`` of ``spec``
    (None: its only property): ``lesmc build --spec``."""
    from lesmc.language.properties import chosen_property

    bound = [bind_multi(spec, p, len(scene.frames) - 1) for p in spec.properties]
    return build_key(chosen_property(bound, spec.path, name))


def _chosen(specs: tuple[SpecFile, ...], only: tuple[str, ...]) -> list[tuple[SpecFile, Property]]:
    """The properties of ``specs`` named in ``only`` (all without)."""
    props = [(s, p) for s in specs for p in s.properties if not only or p.name in only]
    missing = set(only) - {p.name for _, p in props}
    if missing:
        raise UsageError(f"--property {sorted(missing)[0]}: no property of that name")
    return props


def _result(
    model: MultiModel,
    b: BoundProperty,
    scene: Scene | None = None,
    path: str = "",
    search: SearchBudget | None = None,
) -> MultiCheckResult:
    """Property ``b`` checked on ``model`` (lesmc/engines/multi.py) within ``search``'s
    deadline as a typed result; with the ``scene`` it was built from (read from
    ``path``), each counterexample step holds what the report draws (a built model alone
    has no frames to re-run)."""
    from lesmc.engines.multi import check_multi

    res = check_multi(model, b, search)
    steps = _steps(model, b.objective.declared.reads_payoffs, res.path, scene, path)
    head = (str(model.meta["design"]), str(model.meta["reference"]), b.name)
    if res.stopped == "finished":
        verdict = "holds" if res.holds else "violated"
        note = unattacked_note(model, steps) if verdict == "violated" else None
        return MultiCheckResult(
            *head, verdict, res.optimum, res.constraint, res.states, res.transitions, steps,
            notes=() if note is None else (note,),
        )  # fmt: skip
    return _stopped(head, b, res, steps)


def unattacked_note(model: MultiModel, steps: tuple[AttackStep, ...] | None) -> str | None:
    """A violation whose counterexample attacks no step is the unattacked run's own: the
    note that says so, with the first step where that run loses the target and the first
    where it switches its id (the ``lost`` and ``switches`` measures' indicators,
    lesmc/model/identity.py); None when the counterexample attacks."""
    import numpy as np

    from lesmc.model.identity import NONE, indicators, last_seen

    if not steps or any(s.hidden or s.injected for s in steps):
        return None
    head = "violated without attack: the unattacked run itself violates the property"
    tid = np.array([NONE if s.target_id is None else s.target_id for s in steps], np.int64)
    last = tid.copy()
    for k in range(1, len(tid)):
        last[k] = last_seen(last[k - 1 : k], tid[k : k + 1])[0]
    ref = ~np.isnan(np.asarray(model.refbox, float)[[s.step for s in steps[1:]]]).any(axis=1)
    said = []
    for what, source in (("loses the target", "lost"), ("switches the target's id", "switches")):
        hit = np.flatnonzero(indicators(source, last[:-1], tid[1:], ref))
        if hit.size:
            said.append((int(hit[0]) + 1, f"{what} at step {int(hit[0]) + 1}"))
    return f"{head} ({'; '.join(w for _, w in sorted(said))})" if said else head


def _stopped(
    head: tuple[str, str, str],
    b: BoundProperty,
    res: MultiResult,
    steps: tuple[AttackStep, ...] | None,
    note: str | None = None,
) -> MultiCheckResult:
    """The result of a check its budget stopped (``res.stopped``), as the point designs'
    engines report one (lesmc/engines/check.py ``bounded_verdict``: the bounds, the verdict
    they decide, else ``unknown``, and the note; ``note`` instead, when given)."""
    from lesmc.engines import registry as engines
    from lesmc.engines.check import bounded_verdict
    from lesmc.engines.result import EngineOutcome, Stats
    from lesmc.model.kernel import holds

    stats = Stats(engines.MULTI, res.expanded, res.transitions, stopped=res.stopped)
    out = EngineOutcome(res.optimum, res.lower, res.optimum, None, None, False, stats)
    prop = b.prop
    known, optimum, lower, upper, verdict, notes = bounded_verdict(
        out, lambda v: holds(prop.holds_op, v, prop.threshold)
    )
    return MultiCheckResult(
        *head,
        verdict,
        optimum,
        res.constraint,
        res.states,
        res.transitions,
        steps,
        res.stopped,
        known,
        (lower, upper),
        res.expanded,
        tuple(notes if note is None else [note]),
    )


def _unfinished(scene: Scene, path: str, b: BoundProperty, stop: UnfoldStopped) -> MultiCheckResult:
    """The result of a check whose model's unfolding ``stop`` ended: nothing is known of
    the optimum (bounds -∞..∞), no path was searched."""
    from lesmc.unfold.multi import composed

    reason = cast(StopReason, stop.reason)
    res = MultiResult(False, math.inf, None, None, stop.states, 0, reason, -math.inf, 0)
    head = (scene.tracker.design, composed(scene, path).reference_kind(), b.name)
    note = (
        f"search stopped ({stop.reason}) while unfolding the model, before step {stop.step} "
        f"({stop.states} states made): nothing is known of the optimum"
    )
    return _stopped(head, b, res, None, note)


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


def _priced(scene: Scene, l: int, u: int) -> None:
    """A payoff objective needs the window's detections priced."""
    for f in scene.frames[l : u + 1]:
        for d in f.detections:
            if math.isnan(d.payoff):
                raise UsageError(unpriced_text(d.id, f.step))


def _steps(
    model: Any, by_payoff: bool, trans: Any, scene: Scene | None, path: str
) -> tuple[AttackStep, ...] | None:
    """The counterexample's steps along ``trans`` (the engine's transitions; None: no
    path), each with the detections hidden and the candidates injected at it, the
    target's track id and, with the ``scene`` (read from ``path``), what the report
    draws of it; ``by_payoff``: the objective reads the payoffs (each merged transition's
    cheapest subset, else its smallest)."""
    if trans is None:
        return None
    hidden = model.by_payoff if by_payoff else model.by_count
    states = [0, *(int(model.dst[t]) for t in trans)]
    subs: list[tuple[int, ...]] = [(), *(hidden[t] for t in trans)]
    ids = [None if model.tid[s] < 0 else int(model.tid[s]) for s in states]
    drawn: list[StepDrawing | None] = [None] * len(subs)
    if scene is not None:
        from lesmc.unfold.multi import composed

        design = composed(scene, path)
        frames = scene.frames[: len(subs)]
        drawn = list(step_drawings(design, frames, subs, model.detections, ids, model.refbox))
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
