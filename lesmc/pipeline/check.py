"""The one check pipeline: a :class:`~lesmc.pipeline.job.Job` in, typed results out.

``lesmc check``, ``verify``, ``campaign`` and the Python API all call
:func:`run`; none of them decides on its own how a property is checked.
For a scene, per design (lesmc/designs/registry.py) and attack window:

1. the properties are moved to the window, filtered by the monitor when the
   design has it (Eq. 12-13), and bound to the scene's unattacked track;
2. in a certified payoff mode, the detections the models can hide are found
   and, with the job's certifier, bounded (lesmc/pipeline/certify.py);
3. one model per tracker and payoff set serves every design, window and
   property that use that tracker: unfolded whole (``full_models``) or on demand
   over the union of the windows (each property sees only its own window's
   attacks, lesmc/engines/lazy.py);
4. each property is checked in the payoff mode (lesmc/pipeline/payoffs.py)
   within the job's one budget.
"""

from __future__ import annotations

import os
from collections.abc import Iterable, Mapping
from dataclasses import dataclass, field, replace

import numpy as np

from lesmc.common.budget import Budget, stop_requested
from lesmc.common.errors import BudgetError, Location, SpecError, UsageError
from lesmc.designs import registry
from lesmc.engines.check import bind_all, model_design
from lesmc.engines.result import CheckResult
from lesmc.language import monitors
from lesmc.language.actions import DEFAULT as DEFAULT_ACTIONS
from lesmc.language.properties import InjectGrid, SpecFile
from lesmc.language.semantics import BoundProperty, bind
from lesmc.model.arrays import ArrayModel, reference_states
from lesmc.model.growing import ExpansionStopped, GrowingModel
from lesmc.pipeline import certify
from lesmc.pipeline.job import Certifier, Job, Unit
from lesmc.pipeline.payoffs import check_all, check_payoffs, mode_of
from lesmc.results.record import DesignRun, Results
from lesmc.scene import Scene, UnpricedPayoff
from lesmc.unfold.unfold import attack_of, build_model, lazy_model, original_end


def run(job: Job) -> Results:
    """Check every unit of ``job``; one :class:`DesignRun` per design and window.

    A model that reads a payoff the scene leaves unpriced stops the job with
    :class:`~lesmc.scene.UnpricedPayoff` naming ``job.source`` (exit 2).
    """
    try:
        return _run(job)
    except UnpricedPayoff as exc:
        raise exc.at(job.source) from None


def _run(job: Job) -> Results:
    if (job.model is None) == (job.scene is None):
        raise UsageError("a job checks a model or a scene: give exactly one")
    if job.model is not None:
        if job.faults is not None:
            raise UsageError("faults change the tracker: they need a scene, not a model file")
        return Results([_model_run(job, job.model)])
    assert job.scene is not None
    plans = _plans(job, job.scene)
    if job.faults is not None:
        from lesmc.pipeline.faults import validate

        for p in plans:
            validate(job.faults, p.scene, p.bound, job.neuron_frames)
    scene, certified, probes = _certified_scene(job, job.scene, plans)
    models = _Models(scene, plans, job)
    runs = [_design_run(job, p, models, probes) for p in plans]
    return Results(runs, scene, certified)


def bind_scene(
    scene: Scene, specs: Iterable[SpecFile], end: int | None = None
) -> list[BoundProperty]:
    """Bind properties to a scene's model: steps 0..e of the unattacked track.

    ``end``: e when the caller already has it (:func:`original_end` runs the tracker
    over the whole video; a campaign binds hundreds of windows to one scene).
    """
    e = original_end(scene) if end is None else end
    names = scene.tracker.state_names
    pos = scene.tracker.measured
    tracks = (names[pos[0]], names[pos[1]]) if scene.truth else None
    t = scene.tracker.design
    return [
        bind(spec, prop, e, names, True, tracks, tracker=t)
        for spec in specs
        for prop in spec.properties
    ]


def window_of(bound: Iterable[BoundProperty]) -> tuple[int, int]:
    """The union of the properties' attack windows."""
    bound = list(bound)
    return min(bp.l for bp in bound), max(bp.u for bp in bound)


# ------------------------------------------------------------------ planning


@dataclass
class _Plan:
    """One design in one window: its tracker's scene and its bound properties."""

    design: str
    window: tuple[int, int] | None
    scene: Scene
    bound: list[BoundProperty]
    #: each property's place among the design's in this window (the specs' order)
    order: tuple[int, ...] = ()

    @property
    def tracker(self) -> str:
        return self.scene.tracker.design

    @property
    def actions(self) -> tuple[str, ...]:
        """Its properties' attacker's actions (``allow hide, inject``): every property of a
        plan has the same (:func:`_plans`)."""
        return self.bound[0].prop.actions

    @property
    def grid(self) -> InjectGrid | None:
        """Its properties' ``inject grid`` (the same for every property of a plan)."""
        return self.bound[0].prop.grid


#: a model's key: tracker, payoffs, the attacker's actions and ``inject grid``
_ModelKey = tuple[str, str, tuple[str, ...], InjectGrid | None]


def grid_points(grid: InjectGrid | None) -> tuple[np.ndarray, float] | None:
    """``inject grid``'s offsets (G, 2) from the prediction and its payoff, as the tracker
    takes them (lesmc/tracking/single.py); None without one."""
    if grid is None:
        return None
    return np.array(grid.offsets(), dtype=float).reshape(-1, 2), grid.payoff


def grid_notes(bp: BoundProperty) -> list[str]:
    """A property's note that names its ``inject grid`` as the modelling device it is."""
    g = bp.prop.grid
    if g is None:
        return []
    return [
        f"{g.text()} is a modelling device: the attacker may also inject at "
        f"{len(g.offsets())} grid points around the tracker's prediction, {g.payoff:g} "
        'each, places no perception stage proposed (docs/language.md, "Injection grid")'
    ]


def _plans(job: Job, scene: Scene) -> list[_Plan]:
    """Every (design, window) with the properties the job wants checked there."""
    designs = job.designs or (scene.tracker.design,)
    ends: dict[str, int] = {}
    plans: list[_Plan] = []
    for name in designs:
        d = registry.get(name)
        sc = scene.with_tracker(design=d.tracker)
        if d.tracker not in ends:
            ends[d.tracker] = original_end(sc)
        for w in job.windows:
            specs = [s.with_window(w) for s in job.specs]
            if d.monitor:  # the tracker's declared monitor, else Eq. 13's
                mon = monitors.declared(sc.tracker.monitor)
                reason = monitors.unchecked_reason(mon)
                if reason is not None and any(
                    p.monitor is None for s in specs for p in s.properties
                ):
                    raise UsageError(f"the tracker's monitor: {reason}")
                specs = [s.with_monitor(mon) for s in specs]
            bound = _selected(job, name, w, bind_scene(sc, specs, ends[d.tracker]))
            by_actions: dict[tuple[tuple[str, ...], InjectGrid | None], list[int]] = {}
            for i, bp in enumerate(bound):  # one model per attacker: hide only, or inject
                by_actions.setdefault((bp.prop.actions, bp.prop.grid), []).append(i)
            plans.extend(
                _Plan(name, w, sc, [bound[i] for i in idx], tuple(idx))
                for idx in by_actions.values()
            )
    return plans


def _selected(
    job: Job, design: str, window: tuple[int, int] | None, bound: list[BoundProperty]
) -> list[BoundProperty]:
    """The properties of ``bound`` that the job's ``only`` and ``wanted`` keep."""
    _unique_names(bound)
    if job.only:
        known_names(job.only, {bp.name for bp in bound})
        bound = [bp for bp in bound if bp.name in job.only]
    if job.wanted is not None:
        wanted = job.wanted
        bound = [bp for bp in bound if wanted(Unit(design, window, bp.name))]
    return bound


def _unique_names(bound: list[BoundProperty]) -> None:
    """A property name once across the spec files: the second definition is located."""
    seen: dict[str, BoundProperty] = {}
    for bp in bound:
        first = seen.setdefault(bp.name, bp)
        if first is bp:
            continue
        at, was = bp.prop.pos, first.prop.pos
        where = Location(bp.spec, at.line, at.column) if at.line else None
        same = os.path.realpath(first.spec) == os.path.realpath(bp.spec)
        again = "again (the same file given twice?)" if same else "also"
        raise SpecError(
            f"property name '{bp.name}' is {again} defined at "
            f"{first.spec}:{was.line}:{was.column}: names must be unique across the spec files",
            where,
        )


def known_names(only: Iterable[str], names: set[str]) -> None:
    """``--property`` must name properties the specs define."""
    missing = [n for n in only if n not in names]
    if missing:
        raise UsageError(
            f"no property named {', '.join(missing)}; the specs define {', '.join(sorted(names))}"
        )


# ------------------------------------------------------------------ a .lts model


def _model_run(job: Job, model: ArrayModel) -> DesignRun:
    """Every property on a model file (its payoffs are built in: attack mode only)."""
    bound = bind_all(model, job.specs)
    _unique_names(bound)
    modes = {mode_of(bp, job.payoffs) for bp in bound}
    if modes != {"attack"}:
        mode = sorted(modes - {"attack"})[0]
        raise UsageError(f"--payoffs {mode} needs a scene: a model's payoffs are built in")
    if job.only:
        known_names(job.only, {bp.name for bp in bound})
        bound = [bp for bp in bound if bp.name in job.only]
    results = check_all(
        lambda _p: model,
        bound,
        "attack",
        job.engine,
        job.budget,
        lambda _bp: [],
        lambda bp: job.on_stage(f"checking {bp.name} ({job.engine})"),
    )
    design = model_design(model)
    return DesignRun(design, bound, [replace(r, design=design) for r in results], model)


# ------------------------------------------------------------------ certified payoffs


def _certified_scene(
    job: Job, scene: Scene, plans: list[_Plan]
) -> tuple[Scene, dict[str, object] | None, dict[str, list[certify.Probed]]]:
    """In a certified payoff mode: the probes of each tracker's windows (unless the caller
    counted what lacks a bound already) and, with a certifier, the scene with bounds for
    what they found."""
    certified = any(mode_of(bp, job.payoffs) != "attack" for p in plans for bp in p.bound)
    if not certified or job.unbounded is not None:
        return scene, None, {}
    probes: dict[str, list[certify.Probed]] = {}
    for tracker, sc, windows in _tracker_windows(plans):
        if job.certify is None and scene.has_lower:
            continue  # every detection is bounded: nothing to find
        job.on_stage(f"finding the detections the {registry.label(tracker)} models can hide")
        probes[tracker] = certify.probe_all(sc, windows, job.budget)
    if job.certify is None:
        return scene, None, probes
    job.on_stage("certifying payoff lower bounds")
    low = certify.certify(
        scene,
        (p for ps in probes.values() for p in ps),
        job.certify,
        "the detections the checked models can hide; the others have no bound",
        designs=sorted({p.design for p in plans}),
        windows=[list(w) for w in sorted({w for _, _, ws in _tracker_windows(plans) for w in ws})],
    )
    return low, low.meta["certified"], probes


def _tracker_windows(plans: list[_Plan]) -> list[tuple[str, Scene, set[tuple[int, int]]]]:
    """Per tracker: its scene and the attack windows of its properties."""
    out: dict[str, tuple[Scene, set[tuple[int, int]]]] = {}
    for p in plans:
        out.setdefault(p.tracker, (p.scene, set()))[1].update((bp.l, bp.u) for bp in p.bound)
    return [(t, sc, ws) for t, (sc, ws) in out.items()]


def _certified_notes(
    job: Job, scene: Scene, tracker: str, bp: BoundProperty, probes: dict[str, list[certify.Probed]]
) -> list[str]:
    """What a certified check of ``bp`` says about detections without a bound."""
    window = (bp.l, bp.u)
    if job.unbounded is not None:
        return certify.unbounded_note(job.unbounded(tracker, window))
    if tracker not in probes:
        return []  # the scene bounds every detection
    return certify.unbounded_note(certify.unbounded(scene, probes[tracker], window))


# ------------------------------------------------------------------ models and checks


@dataclass
class _Models:
    """One model per (tracker, payoff set), made when first needed, over the union of the
    windows and the last end of every plan that unfolds with that tracker."""

    scene: Scene
    plans: list[_Plan]
    job: Job
    made: dict[_ModelKey, ArrayModel | GrowingModel] = field(default_factory=dict)
    #: the fault variants' certifiers (:func:`_variant_certifiers`), made when first needed
    certifiers: dict[frozenset[str] | None, Certifier] | None = None

    def get(
        self,
        tracker: str,
        payoffs: str,
        actions: tuple[str, ...] = DEFAULT_ACTIONS,
        grid: InjectGrid | None = None,
    ) -> ArrayModel | GrowingModel:
        """The model of ``tracker`` on ``payoffs`` for an attacker taking ``actions`` (and
        ``inject grid``)."""
        key = (tracker, payoffs, actions, grid)
        if key not in self.made:
            self.made[key] = self._make(tracker, payoffs, actions, grid)
        return self.made[key]

    def _make(
        self, tracker: str, payoffs: str, actions: tuple[str, ...], grid: InjectGrid | None
    ) -> ArrayModel | GrowingModel:
        bound = [
            bp
            for p in self.plans
            if p.tracker == tracker and p.actions == actions and p.grid == grid
            for bp in p.bound
        ]
        inject, hide = "inject" in actions, "hide" in actions
        window, end = window_of(bound), max(bp.end for bp in bound)
        sc = self.scene.with_tracker(design=tracker).priced(payoffs, self.job.source)
        if not self.job.full_models:
            stop = _StopPast(self.job.budget, f"unfolding the {registry.label(tracker)} model")
            try:
                made = lazy_model(
                    sc, window, end, inject=inject, hide=hide, grid=grid_points(grid), stop=stop
                )
            except ExpansionStopped as e:  # on the unattacked path, before any search
                raise BudgetError(f"{e}; nothing was written") from None
            stop.searching = True
            return made
        what = f"the {registry.label(tracker)} model" + (
            " with certified payoffs" if payoffs == "certified" else ""
        )
        self.job.on_stage(f"building {what}")
        budget = self.job.budget
        return build_model(  # to the plans' last end, as lazy_model: the same model
            sc,
            window,
            end,
            on_batch=lambda m: _spent(budget, m, f"building {what}"),
            inject=inject,
            hide=hide,
            grid=grid_points(grid),
        )


def _spent(budget: Budget, model: GrowingModel, stage: str) -> None:
    """Stop a build past the budget (exit 3: a whole model could not be made)."""
    reason = budget.exceeded(model.n_states)
    if reason is not None:
        raise BudgetError(
            f"{budget.describe(reason)} ran out while {stage} ({model.n_states} states); "
            "nothing was written"
        )


class _StopPast:
    """What a long expansion calls between its chunks: an ExpansionStopped once ``--timeout``
    or ``--max-memory`` has passed (the search ends ``unknown``; on the unattacked path,
    before a search, a BudgetError), naming ``stage``; once ``searching``, also when a signal
    asked the searches to stop (before, the signal is left to the search, as it was)."""

    def __init__(self, budget: Budget, stage: str) -> None:
        self.budget, self.stage, self.searching = budget, stage, False

    def __call__(self) -> None:
        asked = self.searching and stop_requested() is not None
        reason = "interrupted" if asked else self.budget.exceeded()
        if reason is not None:
            why = "a signal" if reason == "interrupted" else self.budget.describe(reason)
            raise ExpansionStopped(
                reason,
                f"{why} stopped the work while {self.stage}, inside one expansion "
                '(docs/performance.md, "Round 24: injection on a small video")',
            )


def _not_replayed(r: CheckResult, command: str | None) -> CheckResult:
    """A violation found on the model of a perceived scene: its counterexample is a claim
    about the model until it is replayed through the detector (docs/semantics.md, "Replay");
    ``command`` replays it (None: no replay is built for it). No note says so: the status
    and the ``replay`` object do, and a replay (lesmc/replay/run.py) replaces both."""
    if r.verdict != "violated":
        return r
    return replace(r, replay="not replayed", replay_command=command)


def replay_command(
    scene_path: str, meta: Mapping[str, object], specs: Iterable[str] = (), design: str = ""
) -> str:
    """``lesmc verify --scene SCENE --frames VIDEO/`` for a scene made by perception, with the
    frames (``meta.source``) and the networks (``meta.networks``: ``--nets``, ``--detector``,
    ``--locator`` as perceive was given them) it was made with, and the ``specs`` and
    ``design`` that were checked; for a scene made with a detector file
    (``meta.detector_file``), ``lesmc replay RESULTS.json --frames VIDEO/ --detector FILE``
    (verify refuses such scenes)."""
    import shlex

    frames = meta.get("frames", meta.get("source"))  # import mot --detector: its --frames
    given = meta.get("detector_file")
    if isinstance(given, Mapping):  # through the detector file (lesmc/replay/detector_file.py)
        words = ["lesmc", "replay", "RESULTS.json", "--frames"]
        words.append(str(frames) if isinstance(frames, str) and frames else "VIDEO/")
        words += ["--detector", str(given.get("path", "DETECTOR.toml"))]
        return " ".join(w if w in ("VIDEO/", "RESULTS.json") else shlex.quote(w) for w in words)
    words = ["lesmc", "verify", "--scene", scene_path, "--frames"]
    words.append(str(frames) if isinstance(frames, str) and frames else "VIDEO/")
    nets = meta.get("networks")
    if isinstance(nets, Mapping):
        for key in ("nets", "detector", "locator"):
            if isinstance(nets.get(key), str):
                words += [f"--{key}", str(nets[key])]
    for spec in dict.fromkeys(specs):
        words += ["--spec", spec]
    if design:
        words += ["--design", design]
    return " ".join(shlex.quote(w) if w != "VIDEO/" else w for w in words)


def _design_run(
    job: Job, plan: _Plan, models: _Models, probes: dict[str, list[certify.Probed]]
) -> DesignRun:
    """Every property of one plan, in the job's payoff mode."""
    tracker = plan.tracker
    results = check_all(
        lambda payoffs: models.get(tracker, payoffs, plan.actions, plan.grid),
        plan.bound,
        job.payoffs,
        job.engine,
        job.budget,
        lambda bp: (
            grid_notes(bp)
            + (
                []
                if mode_of(bp, job.payoffs) == "attack"
                else _certified_notes(job, models.scene, tracker, bp, probes)
            )
        ),
        lambda bp: job.on_stage(f"checking {bp.name} ({registry.label(plan.design)})"),
    )
    if models.scene.meta.get("detector"):  # perception's scene: replayable on its video
        specs = [bp.spec for bp in plan.bound]
        command = replay_command(job.source, models.scene.meta, specs, plan.design)
        results = [  # an inject grid is a modelling device: nothing on the frames to replay
            _not_replayed(r, None if bp.prop.grid is not None else command)
            for r, bp in zip(results, plan.bound, strict=True)
        ]
    results = [
        replace(r, design=plan.design, notes=[*grid_notes(bp), *r.notes])
        for r, bp in zip(results, plan.bound, strict=True)
    ]
    run = DesignRun(plan.design, plan.bound, results, window=plan.window, order=plan.order)
    if job.faults is not None:
        for bp in plan.bound:
            job.on_stage(f"checking {bp.name} under faults ({registry.label(plan.design)})")
            for fbp, r in _fault_results(job, tracker, bp, models):
                run.fault_bound.append(fbp)
                run.fault_results.append(replace(r, design=plan.design))
    model = models.get(tracker, "attack", plan.actions, plan.grid) if job.full_models else None
    assert model is None or isinstance(model, ArrayModel)
    run.model, run.scene = model, models.scene.with_tracker(design=tracker)
    if model is not None and "inject" in plan.actions:  # what a counterexample hides
        sc = run.scene.priced("attack", job.source)
        run.attack_of = attack_of(sc, model, "hide" in plan.actions, grid_points(plan.grid))
    return run


def _fault_results(
    job: Job, tracker: str, bp: BoundProperty, models: _Models
) -> list[tuple[BoundProperty, CheckResult]]:
    """``bp`` under every combination of the job's faults (lesmc/pipeline/faults.py): each
    activation's variant scene unfolded on demand, deviations measured against the
    fault-free unattacked track; in a certified payoff mode, the variant's hideable
    detections certified on the network that perceived them."""
    from lesmc.pipeline.faults import check_faults

    assert job.faults is not None
    mode = mode_of(bp, job.payoffs)
    actions = bp.prop.actions
    payoffs = "certified" if mode == "certified" else "attack"
    nominal = models.get(tracker, payoffs, actions, bp.prop.grid)
    reference = reference_states(nominal)[: bp.end + 1].copy()
    scene = models.scene.with_tracker(design=tracker)
    if models.certifiers is None:
        models.certifiers = _variant_certifiers(job)
    certifiers = models.certifiers

    def check_variant(
        variant: Scene, vbp: BoundProperty, perceived: Mapping[int, frozenset[str]]
    ) -> CheckResult:
        notes: list[str] = []
        if mode != "attack":
            variant, notes = _certified_variant(job, variant, vbp, certifiers, perceived)
        made: dict[str, GrowingModel] = {}

        def model_of(payoffs: str) -> GrowingModel:
            if payoffs not in made:
                sc = variant.priced(payoffs, job.source)
                made[payoffs] = lazy_model(
                    sc,
                    (vbp.l, vbp.u),
                    vbp.end,
                    reference,
                    inject="inject" in actions,
                    hide="hide" in actions,
                    grid=grid_points(bp.prop.grid),
                )
            return made[payoffs]

        r = check_payoffs(model_of, vbp, mode, job.engine, job.budget, notes)
        if r.verdict == "violated" and scene.meta.get("detector"):
            r = replace(r, replay="not replayed", notes=[*r.notes, FAULT_NOT_REPLAYED_NOTE])
        return r

    return check_faults(job.faults, scene, bp, check_variant, job.neuron_frames)


def _variant_certifiers(job: Job) -> dict[frozenset[str] | None, Certifier]:
    """The certifiers of the fault variants' frames, each certifying a detection once per
    job: the fault-free run's (key None) and each set of neuron faults' run's."""
    out: dict[frozenset[str] | None, Certifier] = {}
    if job.certify is not None:
        out[None] = certify.MemoCertifier(job.certify)
    for key, c in (job.neuron_certify or {}).items():
        out[key] = certify.MemoCertifier(c)
    return out


def _certified_variant(
    job: Job,
    variant: Scene,
    bp: BoundProperty,
    certifiers: dict[frozenset[str] | None, Certifier],
    perceived: Mapping[int, frozenset[str]],
) -> tuple[Scene, list[str]]:
    """The variant with bounds for the detections its model can hide (each on the network
    that perceived it), and the note on those left without one."""
    window = (bp.l, bp.u)
    probes = certify.probe_all(variant, [window], job.budget)
    if certifiers:
        variant = certify.certify(
            variant,
            probes,
            certify.split_certifier(certifiers, perceived),
            "the detections the checked models can hide; the others have no bound",
        )
    return variant, certify.unbounded_note(certify.unbounded(variant, probes, window))


#: Why a counterexample under a fault is not replayed through the detector.
FAULT_NOT_REPLAYED_NOTE = (
    "violated (not replayed): a counterexample under a fault is the model's; replay runs "
    "the fault-free system, so it cannot confirm it"
)
