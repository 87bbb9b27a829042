"""The Python API: every verb of the command line as a function (docs/api.md).

Each function validates its inputs and raises :class:`~lesmc.common.errors.InputError`
(or another :class:`~lesmc.common.errors.LesmcError`) with the file, line and
column of a bad input; none of them exits the interpreter. The command line
(lesmc/cli) is a thin layer over these functions.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Sequence
from pathlib import Path
from typing import TYPE_CHECKING, Any, get_args

from lesmc.common.budget import Budget
from lesmc.common.errors import InputError, UsageError
from lesmc.common.files import read_json
from lesmc.common.progress import Reporter
from lesmc.designs import registry
from lesmc.engines.check import DEFAULT_MAX_STATES, EngineName
from lesmc.engines.result import CheckResult
from lesmc.experiment.perceive import (
    Perceived,
    PerceiveRequest,
    open_inputs,
    perceive_frames,
    refuse_mismatched,
)
from lesmc.language.parser import load_spec, parse_spec
from lesmc.language.properties import SpecFile
from lesmc.model.arrays import ArrayModel
from lesmc.model.lts_binary import is_binary, load_lts_npz
from lesmc.model.lts_format import load_lts, lts_from_dict
from lesmc.pipeline.check import run
from lesmc.pipeline.job import Job, PayoffMode
from lesmc.results.record import DesignRun, Results
from lesmc.scene import Scene, TrackerConfig, load_tracker, save_scene
from lesmc.tracking.targets import scene_with_target
from lesmc.unfold.unfold import build_model

if TYPE_CHECKING:
    from lesmc.experiment.experiment import Outcome as VerifyOutcome
    from lesmc.experiment.experiment import Request as VerifyRequest

__all__ = [
    "CheckResult",
    "DesignRun",
    "PerceiveRequest",
    "Perceived",
    "Results",
    "VerifyOutcome",
    "VerifyRequest",
    "build",
    "check",
    "check_job",
    "expand_designs",
    "export_model",
    "load_model",
    "load_model_or_scene",
    "load_scene",
    "load_spec",
    "parse_spec",
    "perceive",
    "save_scene",
    "verify",
]


def load_model(path: str | Path) -> ArrayModel:
    """A .lts model file, validated (docs/lts-format.md)."""
    return load_lts(path)


def load_scene(
    path: str | Path,
    target: str | None = None,
    design: str | None = None,
    tracker: str | Path | TrackerConfig | None = None,
) -> Scene:
    """A scene file (docs/scene-format.md); ``target`` (``X,Y@STEP``) places or moves its
    target, ``tracker`` (a tracker file or configuration) replaces its tracker, ``design``
    names another tracker design of the registry."""
    _check_designs((design,) if design is not None else ())
    cfg = _tracker_config(tracker)
    return scene_with_target(read_json(Path(path), InputError), str(path), target, design, cfg)


def _tracker_config(tracker: str | Path | TrackerConfig | None) -> TrackerConfig | None:
    if tracker is None or isinstance(tracker, TrackerConfig):
        return tracker
    return load_tracker(tracker)


def load_model_or_scene(
    path: str | Path,
    target: str | None = None,
    design: str | None = None,
    tracker: str | Path | TrackerConfig | None = None,
) -> ArrayModel | Scene:
    """A model (.lts, or its binary .npz form) or a scene, told apart by the file's
    ``format`` field."""
    binary = is_binary(path)
    data = None if binary else read_json(Path(path), InputError)
    if isinstance(data, dict) and data.get("format") == "lesmc-scene":
        return scene_with_target(data, str(path), target, design, _tracker_config(tracker))
    if tracker is not None:
        raise UsageError("--tracker applies to scenes, not to .lts models (built with one)")
    if design:
        raise UsageError("--design applies to scenes, not to .lts models")
    if target:
        raise UsageError("--target applies to scenes, not to .lts models (built for one target)")
    return load_lts_npz(path) if binary else lts_from_dict(data, str(path))


def expand_designs(choice: str) -> tuple[str, ...]:
    """The designs a ``--design`` choice names (a design, a set, or ``all``)."""
    if choice not in registry.choices():
        raise UsageError(
            f"unknown design {choice!r}; choose one of {', '.join(registry.choices())}"
        )
    if choice in registry.names() and registry.get(choice).multi:
        raise UsageError(f"--design {choice}: {registry.not_yet(choice)}")
    return registry.expand(choice)


def build(
    scene: Scene,
    window: tuple[int, int],
    end: int | None = None,
    design: str | None = None,
    max_states: int | None = None,
) -> ArrayModel:
    """The whole model of ``scene`` attacked in ``window`` (Algorithm 1), up to step ``end``,
    unfolded with tracker ``design`` (default: the scene's own)."""
    _need(isinstance(scene, Scene), "scene must be a Scene (lesmc.load_scene)", scene)
    _need(
        _steps(window, 2) and window[0] <= window[1], "window must be (l, u), 0 <= l <= u", window
    )
    _need(end is None or _steps((end,), 1), "end must be None or a step >= 0", end)
    _check_limits(None, max_states)
    _check_designs((design,) if design is not None else ())
    sc = scene if design is None else scene.with_tracker(design=registry.get(design).tracker)
    return build_model(sc, window, end, max_states=max_states)


def check_job(job: Job) -> Results:
    """Run a :class:`~lesmc.pipeline.job.Job` (the pipeline behind every verb)."""
    return run(job)


def check(
    source: ArrayModel | Scene,
    specs: SpecFile | Sequence[SpecFile],
    engine: EngineName = "levels",
    payoffs: PayoffMode = "attack",
    timeout: float | None = None,
    max_states: int | None = DEFAULT_MAX_STATES,
    designs: Sequence[str] = (),
    only: Sequence[str] = (),
) -> list[CheckResult]:
    """Check every property of ``specs`` on a model or a scene; one result per property
    (and per design, for a scene checked with several ``designs``)."""
    spec_list = (specs,) if isinstance(specs, SpecFile) else _items(specs, "specs")
    _need(isinstance(source, (ArrayModel, Scene)), "source must be a model or a Scene", source)
    ok = bool(spec_list) and all(isinstance(x, SpecFile) for x in spec_list)
    _need(ok, "specs must be one or more SpecFile (lesmc.load_spec)", specs)
    _need(engine in get_args(EngineName), f"engine must be one of {get_args(EngineName)}", engine)
    _need(
        payoffs in get_args(PayoffMode), f"payoffs must be one of {get_args(PayoffMode)}", payoffs
    )
    _check_limits(timeout, max_states)
    _check_designs(_items(designs, "designs"))
    _need(all(isinstance(n, str) for n in _items(only, "only")), "only holds names", only)
    budget = Budget(timeout, max_states)
    scene, model = (source, None) if isinstance(source, Scene) else (None, source)
    job = Job(
        spec_list,
        model=model,
        scene=scene,
        engine=engine,
        payoffs=payoffs,
        budget=budget,
        designs=tuple(designs),
        only=tuple(only),
    )
    return run(job).results


def export_model(
    model: ArrayModel,
    path: str | Path,
    fmt: str,
    spec: SpecFile | None = None,
    prop: str | None = None,
    strict: bool = False,
    roles: dict[str, list[int]] | None = None,
    max_nodes: int | None = None,
) -> dict[str, object]:
    """Write ``model`` as ``fmt`` (a format of lesmc/exporters/formats.py) to ``path``
    (docs/export.md).

    A format that states a property exports ``prop`` of ``spec`` (``strict``: refuse an
    objective that is no sum of rewards); ``roles`` marks paths (rows) where the format
    marks paths; ``max_nodes`` bounds what the format limits. Returns facts about what
    was written (``lesmc export --json``).
    """
    from lesmc.exporters import formats
    from lesmc.exporters.request import Request

    _need(isinstance(model, ArrayModel), "model must be a model (lesmc.load_model)", model)
    _need(fmt in formats.names(), f"fmt: {formats.spelled()}", fmt)
    _need(spec is None or isinstance(spec, SpecFile), "spec must be a SpecFile or None", spec)
    ok = roles is None or (
        isinstance(roles, dict) and all(isinstance(v, list) for v in roles.values())
    )
    _need(ok, "roles must map role names to lists of model rows", roles)
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
    req = request if isinstance(request, PerceiveRequest) else PerceiveRequest(str(request))
    refuse_mismatched(req)
    return perceive_frames(req, open_inputs(req), on_frame)


def verify(request: VerifyRequest, reporter: Reporter | None = None) -> VerifyOutcome:
    """The paper's whole experiment (``lesmc verify``): see :class:`VerifyRequest`."""
    from lesmc.experiment.experiment import verify as run_verify

    if reporter is not None:
        return run_verify(request, reporter)
    with Reporter("verify", live=False) as rep:
        return run_verify(request, rep)


def __getattr__(name: str) -> Any:
    """``VerifyRequest`` and ``VerifyOutcome``, imported when first asked for: the verify
    stage loads the perception's libraries, which checking a model does not need."""
    if name in ("VerifyRequest", "VerifyOutcome"):
        from lesmc.experiment import experiment

        return experiment.Request if name == "VerifyRequest" else experiment.Outcome
    raise AttributeError(f"module 'lesmc.api' has no attribute {name!r}")


# ------------------------------------------------------------------ arguments


def _need(ok: bool, what: str, got: Any) -> None:
    """A UsageError naming the argument's rule and the value given, unless ``ok``."""
    if not ok:
        shown = repr(got)
        raise UsageError(f"{what}; got {shown if len(shown) <= 60 else shown[:57] + '...'}")


def _items(values: Any, name: str) -> tuple[Any, ...]:
    """A sequence argument as a tuple; one string is refused (it would iterate by letter)."""
    ok = not isinstance(values, (str, bytes)) and isinstance(values, Sequence | set | frozenset)
    _need(ok, f"{name} must be a list or tuple (not one string)", values)
    return tuple(values)


def _steps(values: Any, n: int) -> bool:
    """``values`` is ``n`` integer steps in 0..10^6 (booleans are not integers here)."""
    return (
        isinstance(values, Sequence)
        and len(values) == n
        and all(type(v) is int and 0 <= v <= 10**6 for v in values)
    )


def _check_limits(timeout: float | None, max_states: int | None) -> None:
    good_t = timeout is None or (
        isinstance(timeout, int | float) and math.isfinite(timeout) and timeout > 0
    )
    _need(good_t, "timeout must be None or a finite number of seconds > 0", timeout)
    good_n = max_states is None or (type(max_states) is int and max_states > 0)
    _need(good_n, "max_states must be None or an integer > 0", max_states)


def _check_designs(designs: tuple[Any, ...]) -> None:
    known = registry.names()
    bad = [d for d in designs if not (isinstance(d, str) and d in known)]
    _need(
        not bad,
        f"designs are names among {', '.join(known)} (expand_designs turns "
        "'paper', 'both' and 'all' into them)",
        bad[0] if bad else None,
    )
