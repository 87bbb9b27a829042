"""The Python API: every verb of the command line as a function (docs/api.md).

Each function validates its inputs and raises :class:`~lesmc.common.errors.InputError`
(or another :class:`~lesmc.common.errors.LesmcError`) with the file, line and
column of a bad input; none of them exits the interpreter. The command line
(lesmc/cli) is a thin layer over these functions.
"""

from __future__ import annotations

import os
from collections.abc import Callable, Sequence
from pathlib import Path
from typing import TYPE_CHECKING, Any

from lesmc.api_checks import (
    are_steps,
    attack_window,
    check_limits,
    design_list,
    file_path,
    format_takes,
    marked_paths,
    need,
    sequence,
    spec_files,
)
from lesmc.common.budget import Budget
from lesmc.common.errors import BudgetError, InputError, UsageError
from lesmc.common.fields import is_int
from lesmc.common.files import read_json
from lesmc.common.progress import Reporter
from lesmc.designs import registry
from lesmc.engines import payoff_modes
from lesmc.engines import registry as engines
from lesmc.engines.check import DEFAULT_MAX_STATES
from lesmc.engines.result import CheckResult
from lesmc.experiment.perceive import (
    Perceived,
    PerceiveRequest,
    open_inputs,
    perceive_frames,
    refuse_mismatched,
)
from lesmc.language import parser as parse
from lesmc.language.properties import SpecFile
from lesmc.model.arrays import ArrayModel
from lesmc.model.growing import GrowingModel
from lesmc.model.lts_binary import is_binary
from lesmc.model.lts_format import lts_from_dict
from lesmc.model.multi import MultiModel
from lesmc.model.multi_format import load_model_file
from lesmc.pipeline.check import run
from lesmc.pipeline.job import Job
from lesmc.pipeline.multi import (
    DESIGN_IGNORES,
    MODEL_IGNORES,
    AttackStep,
    MultiCheckResult,
    check_meta,
    check_multi_design,
    check_multi_model,
)
from lesmc.results.record import DesignRun, Results
from lesmc.scene import Footage, Scene, TrackerConfig, load_tracker
from lesmc.scene import save_scene as write_scene
from lesmc.tracking.targets import scene_with_target
from lesmc.unfold.unfold import build_model

if TYPE_CHECKING:
    from lesmc.experiment.experiment import Outcome as VerifyOutcome
    from lesmc.experiment.multi_verify import MultiOutcome
    from lesmc.experiment.verify_request import Request as VerifyRequest

__all__ = [
    "AttackStep",
    "CheckResult",
    "DesignRun",
    "MultiCheckResult",
    "MultiModel",
    "PerceiveRequest",
    "Perceived",
    "Results",
    "VerifyOutcome",
    "VerifyRequest",
    "build",
    "check",
    "check_job",
    "expand_designs",
    "export",
    "load_model",
    "load_model_or_scene",
    "load_scene",
    "load_spec",
    "parse_spec",
    "perceive",
    "save_model",
    "save_scene",
    "verify",
]

#: A file argument: a path as a string or a :class:`pathlib.Path` (any ``os.PathLike``).
PathArg = str | os.PathLike[str]
#: A spec argument: a parsed spec file, or the path of one.
SpecArg = SpecFile | PathArg
#: An attack window: ``"6..8"``, ``(6, 8)`` or ``range(6, 9)`` (steps 6 to 8).
WindowArg = str | tuple[int, int] | Sequence[int] | range


def load_model(path: PathArg) -> ArrayModel | MultiModel:
    """A model file, validated: a .lts, or its binary .npz form, or a multi-target model
    (``lesmc build --design sort|gnn``'s .npz; docs/lts-format.md)."""
    where = file_path(path, "path")
    return _checked(load_model_file(where), where)


def save_model(model: ArrayModel | MultiModel, path: PathArg) -> None:
    """Write a model (:func:`build`'s) atomically, as ``lesmc build -o`` writes it: a
    single-target model as .lts (JSON) or, for a path ending in .npz, in its binary form;
    a multi-target model in its binary form only (a path ending in .npz)."""
    from lesmc.model.lts_binary import save_lts_npz
    from lesmc.model.lts_format import save_lts
    from lesmc.model.multi_format import save_multi

    where = file_path(path, "path", read=False)
    if isinstance(model, MultiModel):
        need(is_binary(where), "path: a multi-target model is written as .npz only", path)
        save_multi(model, where)
        return
    need(isinstance(model, ArrayModel), "model must be a model (lesmc.build)", model)
    (save_lts_npz if is_binary(where) else save_lts)(model, where)


def load_spec(path: PathArg) -> SpecFile:
    """A property file, parsed (docs/language.md)."""
    return parse.load_spec(file_path(path, "path"))


def parse_spec(text: str, path: str = "<spec>", need_properties: bool = True) -> SpecFile:
    """The text of a property file, parsed; ``path`` names it in messages. With
    ``need_properties=False`` a file of a faults block alone is accepted."""
    need(isinstance(text, str), "text must be the text of a spec file (a str)", text)
    need(isinstance(path, str), "path must be a str (the name used in messages)", path)
    need(
        isinstance(need_properties, bool), "need_properties must be True or False", need_properties
    )
    return parse.parse_spec(text, path, need_properties)


def load_scene(
    path: PathArg,
    target: str | None = None,
    design: str | None = None,
    tracker: PathArg | TrackerConfig | None = None,
) -> Scene:
    """A scene file (docs/scene-format.md); ``target`` (``"X,Y@STEP"``) places or moves its
    target, ``tracker`` (a tracker file or configuration) replaces its tracker, ``design``
    names another tracker of the registry (``single``, ``joint``, ``sort``, ``gnn``)."""
    where = file_path(path, "path")
    cfg = _scene_options(target, design, tracker)
    return scene_with_target(read_json(Path(where), InputError), where, target, design, cfg)


def _scene_options(target: Any, design: Any, tracker: Any) -> TrackerConfig | None:
    """Check a scene's ``target``, ``design`` and ``tracker`` arguments; the tracker's
    configuration (read from its file) or None."""
    need(target is None or isinstance(target, str), 'target must be None or "X,Y@STEP"', target)
    trackers = registry.tracker_names()
    need(
        design is None or design in trackers,
        f"design must be None or a tracker among {', '.join(trackers)} (a monitored design "
        "is a check's: lesmc.check(..., designs=...))",
        design,
    )
    if tracker is None or isinstance(tracker, TrackerConfig):
        return tracker
    return load_tracker(file_path(tracker, "tracker", "or a TrackerConfig"), design)


def load_model_or_scene(
    path: PathArg,
    target: str | None = None,
    design: str | None = None,
    tracker: PathArg | TrackerConfig | None = None,
) -> ArrayModel | MultiModel | Scene:
    """A model (.lts, or its binary .npz form, or a multi-target model's .npz) or a scene,
    told apart by the file's ``format`` field."""
    where = file_path(path, "path")
    cfg = _scene_options(target, design, tracker)
    binary = is_binary(where)
    data = None if binary else read_json(Path(where), InputError)
    if isinstance(data, dict) and data.get("format") == "lesmc-scene":
        return scene_with_target(data, where, target, design, cfg)
    if tracker is not None:
        raise UsageError(
            "--tracker applies to scenes, not to built models (.lts, .npz: built with one)"
        )
    if design:
        raise UsageError("--design applies to scenes, not to built models (.lts, .npz)")
    if target:
        raise UsageError(
            "--target applies to scenes, not to built models (.lts, .npz: built for one target)"
        )
    return _checked(load_model_file(where), where) if binary else lts_from_dict(data, where)


def _checked(model: ArrayModel | MultiModel, where: str) -> ArrayModel | MultiModel:
    """A loaded model, a multi-target one's header checked against the design registry
    (:func:`lesmc.pipeline.multi.check_meta`)."""
    return check_meta(model, where) if isinstance(model, MultiModel) else model


def save_scene(scene: Scene | Footage, path: PathArg) -> None:
    """Write a scene (or a scene without a target, lesmc.perceive's) atomically
    (docs/scene-format.md)."""
    need(
        isinstance(scene, Scene | Footage),
        "scene must be a Scene or a Footage (lesmc.load_scene, lesmc.perceive)",
        scene,
    )
    write_scene(scene, file_path(path, "path", read=False))


def expand_designs(choice: str, multi: bool = False) -> tuple[str, ...]:
    """The designs a ``--design`` choice names (a design, a set, or ``all``); a
    multi-target design (``sort``, ``gnn``) only with ``multi`` (``lesmc verify`` and
    ``lesmc campaign`` pass it; a caller of the point designs' functions does not)."""
    need(isinstance(choice, str), "choice must be a design or a set's name", choice)
    if choice not in registry.choices():
        raise UsageError(
            f"unknown design {choice!r}; choose one of {', '.join(registry.choices())}"
        )
    if not multi and choice in registry.names() and registry.get(choice).multi:
        raise UsageError(
            f"--design {choice} is a multi-target design: expand_designs(..., multi=True) "
            "names it (lesmc verify and lesmc campaign check it; the point designs' "
            "functions do not)"
        )
    return registry.expand(choice)


def build(
    scene: Scene | PathArg,
    window: WindowArg | None,
    end: int | None = None,
    design: str | None = None,
    max_states: int | None = None,
    timeout: float | None = None,
    *,
    spec: SpecArg | None = None,
    property: str | None = None,
) -> ArrayModel | MultiModel:
    """The whole model of ``scene`` (a Scene or a scene file) attacked in ``window``
    (``"6..8"``, ``(6, 8)`` or ``range(6, 9)``; Algorithm 1), up to step ``end``, unfolded
    with tracker ``design`` (default: the scene's own). A
    :class:`~lesmc.common.errors.BudgetError` names ``max_states`` or ``timeout`` when
    the model outgrows them (nothing is returned).

    A multi-target design (``sort``, ``gnn``) gives a :class:`MultiModel`
    (``lesmc build --design sort``'s), unfolded for ``window`` and ``end`` with every
    detection attackable by hiding, or for property ``property`` of ``spec`` (its window,
    end, ``within R`` and ``allow``; ``window`` None, or the property's), within
    ``max_states`` and ``timeout`` alike."""
    sc = scene if isinstance(scene, Scene) else load_scene(file_path(scene, "scene", "or a Scene"))
    steps = None if window is None and spec is not None else attack_window(window)
    need(end is None or are_steps((end,), 1), "end must be None or a step >= 0", end)
    check_limits(timeout, max_states)
    _scene_options(None, design, None)
    if design is not None:
        sc = sc.with_tracker(design=registry.get(design).tracker)
    if registry.get(sc.tracker.design).multi:
        where = scene if isinstance(scene, Scene) else file_path(scene, "scene")
        return _build_multi(sc, where, steps, end, max_states, timeout, spec, property)
    need(spec is None and property is None, "spec, property: for multi-target designs", spec)
    assert steps is not None
    budget = Budget(timeout, max_states)

    def spent(model: GrowingModel | ArrayModel) -> None:
        reason = budget.exceeded(model.n_states)
        if reason is not None:
            limit = f"max_states={max_states}" if reason == "max_states" else f"{reason}"
            if reason == "timeout":
                limit = f"timeout={timeout} s"
            raise BudgetError(f"{limit} ran out while building the model ({model.n_states} states)")

    model = build_model(sc, steps, end, on_batch=spent, max_states=max_states)
    spent(model)
    return model


def _build_multi(
    sc: Scene,
    where: Scene | str,
    window: tuple[int, int] | None,
    end: int | None,
    max_states: int | None,
    timeout: float | None,
    spec: Any,
    prop: Any,
) -> MultiModel:
    """:func:`build` of a multi-target design (lesmc/pipeline/multi.py ``build_for``)."""
    from lesmc.engines.multi import BuildKey
    from lesmc.language.actions import DEFAULT as DEFAULT_ACTIONS
    from lesmc.pipeline.multi import build_within, property_key

    need(prop is None or isinstance(prop, str), "property must be None or a name", prop)
    path = "<scene>" if isinstance(where, Scene) else where
    last = len(sc.frames) - 1
    if spec is None:
        need(prop is None, "property names a property of spec: give spec", prop)
        assert window is not None
        key: BuildKey = (*window, last if end is None else end, None, DEFAULT_ACTIONS)
    else:
        key = property_key(sc, spec_files(spec, "spec")[0], prop)
        need(
            window is None or window == key[:2],
            f"window: the property's is {key[0]}..{key[1]}",
            window,
        )
        need(end is None or end == key[2], f"end: the property's is {key[2]}", end)
    return build_within(sc, path, key, max_states, Budget(timeout), f"timeout={timeout} s")


def check_job(job: Job) -> Results:
    """Run a :class:`~lesmc.pipeline.job.Job` (the pipeline behind every verb)."""
    need(isinstance(job, Job), "job must be a lesmc.pipeline.job.Job", job)
    return run(job)


def check(
    source: ArrayModel | MultiModel | Scene | PathArg,
    specs: SpecArg | Sequence[SpecArg],
    engine: str = engines.DEFAULT,
    payoffs: str = payoff_modes.DEFAULT,
    timeout: float | None = None,
    max_states: int | None = DEFAULT_MAX_STATES,
    designs: str | Sequence[str] = (),
    only: str | Sequence[str] = (),
) -> list[CheckResult] | list[MultiCheckResult]:
    """Check every property of ``specs`` (one spec file or several, parsed or as paths) on
    a model or a scene (or the file of one); one result per property and design, each
    naming its design (``result.design``). ``designs``: a design, a set (``"paper"``,
    ``"all"``) or a list of designs (scenes only); ``only``: a property's name or a list
    of them. On a multi-target design (``designs="sort"`` or ``"gnn"``, or a scene whose
    tracker is one) the results are :class:`MultiCheckResult` (``lesmc check --design sort
    --json``'s entries: ``to_dict()``); ``timeout`` bounds each property's check there
    (unfolding included; past it the result is ``unknown``), and ``engine`` and
    ``payoffs="interval"`` are refused, as the command line refuses them."""
    src = (
        source
        if isinstance(source, ArrayModel | MultiModel | Scene)
        else load_model_or_scene(file_path(source, "source", "or a model or a Scene"))
    )
    spec_list = spec_files(specs)
    need(engine in engines.names(), f"engine must be one of {', '.join(engines.names())}", engine)
    modes = payoff_modes.names()
    need(payoffs in modes, f"payoffs must be one of {', '.join(modes)}", payoffs)
    check_limits(timeout, max_states)
    chosen = design_list(designs)
    need(
        not chosen or isinstance(src, Scene),
        "designs apply to scenes: a model was built with one",
        designs,
    )
    names = (only,) if isinstance(only, str) else sequence(only, "only")
    need(all(isinstance(n, str) for n in names), "only holds property names", only)
    if isinstance(src, MultiModel):
        return _check_multi_model(src, spec_list, names, engine, payoffs, timeout, max_states)
    if isinstance(src, Scene) and _multi(src, chosen):
        where = "<scene>" if isinstance(source, Scene) else file_path(source, "source")
        return _check_multi(
            src, where, spec_list, chosen, engine, payoffs, timeout, max_states, names
        )
    scene, model = (src, None) if isinstance(src, Scene) else (None, src)
    job = Job(
        spec_list,
        model=model,
        scene=scene,
        engine=engine,
        payoffs=payoffs,
        budget=Budget(timeout, max_states),
        designs=chosen,
        only=names,
    )
    return run(job).results


#: :func:`check`'s defaults of the arguments a multi-target search may not read
#: (lesmc.pipeline.multi's ``MODEL_IGNORES``, ``DESIGN_IGNORES``): any other value is refused.
_CHECK_DEFAULTS: dict[str, Any] = {
    "engine": engines.DEFAULT,
    "timeout": None,
    "payoffs": payoff_modes.DEFAULT,
    "max_states": DEFAULT_MAX_STATES,
}


def _check_multi_model(
    model: MultiModel,
    specs: tuple[SpecFile, ...],
    only: tuple[str, ...],
    engine: str,
    payoffs: str,
    timeout: float | None,
    max_states: int | None,
) -> list[MultiCheckResult]:
    """:func:`check` on a built multi-target model (``lesmc check MODEL.npz``): the
    arguments its search does not read are refused, as the command line refuses them."""
    given = {"engine": engine, "timeout": timeout, "payoffs": payoffs, "max_states": max_states}
    for name, why in MODEL_IGNORES.items():
        need(given[name] == _CHECK_DEFAULTS[name], f"{name}: {why}", given[name])
    need(not any(s.faults for s in specs), "specs: faults need a scene", [s.path for s in specs])
    return check_multi_model(model, specs, only, Budget(timeout))  # the clock starts here


def _multi(scene: Scene, designs: tuple[str, ...]) -> bool:
    """Whether a check of ``scene`` with ``designs`` (none: the scene's own) is of a
    multi-target design; a list mixing them with single-target designs is refused."""
    multi = [registry.get(d).multi for d in designs or (scene.tracker.design,)]
    need(
        all(multi) or not any(multi),
        "designs: a multi-target design (sort, gnn) is checked alone, not with others",
        designs,
    )
    return multi[0]


def _check_multi(
    scene: Scene,
    path: str,
    specs: tuple[SpecFile, ...],
    designs: tuple[str, ...],
    engine: str,
    payoffs: str,
    timeout: float | None,
    max_states: int | None,
    only: tuple[str, ...],
) -> list[MultiCheckResult]:
    """:func:`check` on a multi-target design (``lesmc check --design sort``'s check,
    lesmc/pipeline/multi.py): the arguments its exact search does not read are refused, as
    the command line refuses its options."""
    need(len(designs) <= 1, "designs: one multi-target design at a time", designs)
    given = {"engine": engine}
    for name, why in DESIGN_IGNORES.items():
        need(given[name] == _CHECK_DEFAULTS[name], f"{name}: {why}", given[name])
    need(
        payoffs != "interval",
        "payoffs: interval is not supported yet on a multi-target design",
        payoffs,
    )
    need(
        not any(s.faults for s in specs),
        "specs: faults with a multi-target design are not supported yet",
        [s.path for s in specs if s.faults],
    )
    sc = scene if not designs else scene.with_tracker(design=designs[0])
    sc = sc.priced(payoffs, path)
    budget = Budget(timeout)  # the clock starts once the arguments are checked
    return check_multi_design(sc, path, specs, only, max_states, False, budget)


def export(
    model: ArrayModel | MultiModel | PathArg,
    path: PathArg,
    *,
    format: str,
    spec: SpecArg | None = None,
    property: str | None = None,
    strict: bool = False,
    roles: CheckResult | dict[str, list[int]] | None = None,
    max_nodes: int | None = None,
) -> dict[str, object]:
    """Write ``model`` (a model or a model file) to ``path`` as ``format`` (a format of
    lesmc/exporters/formats.py; docs/export.md).

    A format that states a property exports ``property`` of ``spec`` (a spec file or its
    path; the property may be left out when the file has one), ``strict`` refusing an
    objective that is no sum of rewards; ``roles`` marks paths where the format marks
    paths: a :class:`CheckResult` (its counterexample and witness) or role names mapped
    to lists of model rows; ``max_nodes`` bounds what the format limits. Returns facts
    about what was written (``lesmc export --json``).
    """
    return export_model(model, path, format, spec, property, strict, roles, max_nodes)


def export_model(
    model: ArrayModel | MultiModel | PathArg,
    path: PathArg,
    fmt: str,
    spec: SpecArg | None = None,
    prop: str | None = None,
    strict: bool = False,
    roles: CheckResult | dict[str, list[int]] | None = None,
    max_nodes: int | None = None,
) -> dict[str, object]:
    """:func:`export` with positional arguments (``fmt`` is ``format``, ``prop``
    ``property``): what ``lesmc export`` calls. Not in ``__all__``: the API's one way to
    export is :func:`export`, whose keyword names its messages use."""
    from lesmc.exporters import formats
    from lesmc.exporters.request import Request

    model, path, spec, roles = _export_arguments(model, path, spec, prop, strict, roles, max_nodes)
    ok = isinstance(model, ArrayModel | MultiModel)
    need(ok, "model must be a model (lesmc.load_model, lesmc.build)", model)
    need(fmt in formats.names(), f"format: {formats.spelled()}", fmt)
    if isinstance(model, MultiModel):
        formats.refuse_multi(formats.get(fmt))
    format_takes(formats.get(fmt), spec, prop, strict, roles, max_nodes)
    need(spec is None or isinstance(spec, SpecFile), "spec must be a SpecFile or None", spec)
    ok = roles is None or (
        isinstance(roles, dict) and all(isinstance(v, list) for v in roles.values())
    )
    need(ok, "roles must map role names to lists of model rows", roles)
    request = Request(spec, prop, strict, roles, max_nodes)
    return {"export_format": fmt} | formats.get(fmt).write(model, path, request)


def perceive(
    request: PerceiveRequest | str | Path,
    on_frame: Callable[[], None] | None = None,
) -> Perceived:
    """Frames -> detections, payoffs and a scene (``lesmc perceive``).

    ``request`` is a :class:`PerceiveRequest`, or a frames directory for the
    defaults (the shipped CNNs, DeepFool payoffs, a scene without a target).
    Returns the per-frame figures (``run``) and the scene (``scene``: a ``Scene``
    when ``target`` was given, a ``Footage`` without); write it with
    :func:`save_scene`. ``on_frame`` is called after each frame (progress).
    """
    req = (
        request
        if isinstance(request, PerceiveRequest)
        else PerceiveRequest(file_path(request, "request", "or a PerceiveRequest"))
    )
    need(on_frame is None or callable(on_frame), "on_frame must be None or callable", on_frame)
    refuse_mismatched(req)
    return perceive_frames(req, open_inputs(req), on_frame)


def verify(
    request: VerifyRequest, reporter: Reporter | None = None
) -> VerifyOutcome | MultiOutcome:
    """The paper's whole experiment (``lesmc verify``): see :class:`VerifyRequest`. On a
    multi-target design (``designs=("sort",)``) the outcome is a
    :class:`~lesmc.experiment.multi_verify.MultiOutcome`."""
    from lesmc.experiment.experiment import verify as run_verify
    from lesmc.experiment.verify_request import Request

    need(isinstance(request, Request), "request must be a lesmc.VerifyRequest", request)
    need(
        reporter is None or isinstance(reporter, Reporter),
        "reporter must be None or a lesmc.common.progress.Reporter",
        reporter,
    )
    from lesmc.experiment.multi_verify import multi_designs, verify_multi

    run = verify_multi if multi_designs(request.designs) else run_verify
    if reporter is not None:
        return run(request, reporter)
    with Reporter("verify", live=False) as rep:
        return run(request, rep)


def __getattr__(name: str) -> Any:
    """``VerifyRequest`` and ``VerifyOutcome``, imported when first asked for: the verify
    stage loads the perception's libraries, which checking a model does not need."""
    if name in ("VerifyRequest", "VerifyOutcome"):
        from lesmc.experiment import experiment, verify_request

        return verify_request.Request if name == "VerifyRequest" else experiment.Outcome
    raise AttributeError(f"module 'lesmc.api' has no attribute {name!r}")


def _export_arguments(
    model: Any, path: Any, spec: Any, prop: Any, strict: Any, roles: Any, max_nodes: Any
) -> tuple[ArrayModel | MultiModel, str, SpecFile | None, dict[str, list[int]] | None]:
    """Check :func:`export_model`'s arguments; the model and spec (read when given as
    paths) and the roles as model rows (a CheckResult's paths looked up)."""
    where = file_path(path, "path", read=False)
    inputs = {"model": model, "spec": spec}
    for name, given in inputs.items():
        if isinstance(given, str | os.PathLike) and Path(given).resolve() == Path(where).resolve():
            need(False, f"path and {name} name the same file (writing would destroy it)", path)
    if not isinstance(model, ArrayModel | MultiModel):
        model = load_model(file_path(model, "model", "or a model (lesmc.load_model)"))
    if spec is not None:
        one = isinstance(spec, SpecFile | str | os.PathLike)
        spec = spec_files(spec, "spec")[0] if one else spec
    need(prop is None or isinstance(prop, str), "property must be None or a name", prop)
    need(isinstance(strict, bool), "strict must be True or False", strict)
    good_n = max_nodes is None or (is_int(max_nodes) and max_nodes >= 1)
    need(good_n, "max_nodes must be None or an integer >= 1", max_nodes)
    if isinstance(model, MultiModel):
        need(roles is None, "roles: a multi-target model's paths are not marked", roles)
        return model, where, spec, None
    return model, where, spec, marked_paths(model, roles)
