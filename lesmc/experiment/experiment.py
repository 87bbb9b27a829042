"""``lesmc verify``: the paper's whole experiment in one call (section 8).

frames -> scene (perception, payoffs) -> the check pipeline for every design
(lesmc/pipeline/check.py) -> results document -> replay of the counterexamples
-> report. Each stage is the code of its own verb; this module chains them and
picks the defaults: the embedded synthetic video, a target with neighbouring
traffic, the bundled robustness and resilience specs, the paper's designs.
"""

from __future__ import annotations

import dataclasses
import json
import time
from collections.abc import Callable
from dataclasses import asdict, dataclass, field
from importlib import resources
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np

from lesmc.common.budget import Budget
from lesmc.common.errors import BudgetError, UsageError
from lesmc.common.files import json_text
from lesmc.common.memory import release
from lesmc.common.progress import Reporter
from lesmc.designs import registry
from lesmc.experiment import detector_verify, video_perception
from lesmc.experiment.cache import (
    FigureStore,
    StageCache,
    code_digest,
    digest,
    file_digests,
    net_files,
)
from lesmc.experiment.false_alarms import false_alarm_report, truth_track
from lesmc.experiment.neuron_faults import NeuronRuns, check_units, neuron_faults, neuron_frames
from lesmc.experiment.perceive import networks_meta
from lesmc.experiment.pricing import VideoPricer, priced_meta
from lesmc.experiment.pricing import on_demand as on_demand_footage
from lesmc.experiment.video_perception import UnitMax
from lesmc.language.parser import load_faults, load_spec
from lesmc.language.properties import FaultSet, SpecFile
from lesmc.perception import DELTA_BC, HISTORY, NetFiles
from lesmc.perception.quality import TruthFrame, load_truth
from lesmc.pipeline.check import run as run_job
from lesmc.pipeline.job import Certifier, Job, PayoffMode
from lesmc.replay.run import apply, cases, replay
from lesmc.results.document import provenance, results_document
from lesmc.results.read import results_of
from lesmc.results.record import Results
from lesmc.scene import (
    Footage,
    OnDemandPayoffs,
    Scene,
    TrackerConfig,
    load_tracker,
    scene_to_dict,
)
from lesmc.tracking.targets import check_target, load_scene_with_target, parse_target
from lesmc.unfold.unfold import original_end
from lesmc.video import FPS

if TYPE_CHECKING:  # reading frames imports cv2: only where a video is read
    from lesmc.video.reader import FrameSet

#: The embedded default video: `lesmc synth` with these settings.
DEFAULT_VIDEO = {"frames": 24, "width": 2048, "height": 2048, "seed": 1}


@dataclass(frozen=True)
class Request:
    """What ``lesmc verify`` was asked: a video (``frames_dir``; None: the embedded default)
    or a scene file, the target, the specs (none: the bundled ones), the designs, the
    payoff mode, where to write and the budget."""

    frames_dir: str | None = None
    scene_path: str | None = None
    target: str | None = None
    truth: str | None = None
    specs: tuple[str, ...] = ()
    window: tuple[int, int] | None = None
    designs: tuple[str, ...] = registry.SETS["paper"]
    out: Path = Path("lesmc-verify")
    nets: NetFiles = (None, None, None)  #: ``--nets``, ``--detector``, ``--locator``
    scene_frames: str | None = None  #: with ``scene_path``: the video's frames (replay, images)
    tracker: str | None = None  #: a tracker file replacing the scene's (``--tracker``)
    payoffs: PayoffMode = "attack"
    budget: Budget = field(default_factory=Budget)
    faults: str | None = None  #: a file with a ``faults`` block (``--faults``)
    #: attack every detection of the video up front (``--price-all``), not only those
    #: the checked models read (lesmc/experiment/pricing.py)
    price_all: bool = False
    #: a space file (``--space``): lesmc tune's design search on the video, and the best
    #: design under the file's false-alarm budget (results' ``design_search``)
    space: str | None = None
    #: injection candidates (``--inject-within``, ``--inject-cap``; docs/cnn.md): None:
    #: none; else (px, cap)
    inject: tuple[float, int] | None = None


@dataclass
class Outcome:
    """What a verification produced: the typed results (after the replay), the results
    document and the report's path."""

    results: Results
    doc: dict[str, Any]
    report: Path


@dataclass
class _Source:
    """The scene to check and what came with it: the video's frames, truth and networks,
    the perception run (for certification), the facts for the results' meta."""

    scene: Scene
    frames: FrameSet | None = None
    truth: Any = None
    nets: Any = None
    run: Any = None
    meta: dict[str, Any] = field(default_factory=dict)
    new: bool = False  #: made by this run: written to OUT/scene.json
    net_files: NetFiles | None = None  #: the networks to load when needed (cached perception)
    truth_path: str | None = None
    cache: StageCache | None = None
    #: verify's own perception of the video: its cache key, each hidden unit's largest
    #: value, the seconds between frames (neuron faults perceive it again)
    perceived: tuple[str, UnitMax, float] | None = None
    #: payoffs priced on demand (lesmc/experiment/pricing.py): the shared prices, the pricer
    #: and the footage they price (stored again in OUT/cache with what was priced)
    pricing: tuple[OnDemandPayoffs, VideoPricer, Footage] | None = None
    #: a detector file's detections: counts, recall and precision, payoffs (detector_verify)
    detections: dict[str, Any] | None = None

    def networks(self) -> Any:
        """The networks: loaded now if perception came from the cache."""
        if self.nets is None and self.net_files is not None:
            from lesmc.perception.cnn import load_nets

            self.nets = load_nets(*self.net_files)
        return self.nets


def bundled_specs() -> list[Path]:
    """The robustness and resilience specs shipped with lesmc (specs/ in the repository)."""
    names = ("robustness.spec", "resilience.spec")
    packaged = resources.files("lesmc") / "specs"
    if all((packaged / n).is_file() for n in names):  # an installed wheel
        return [Path(str(packaged / n)) for n in names]
    repo = Path(__file__).resolve().parents[2] / "specs"  # an editable install or a checkout
    return [repo / n for n in names]


def load_specs(paths: list[Path], window: tuple[int, int] | None) -> list[SpecFile]:
    """The spec files, every property moved to ``window`` (None: their own)."""
    if not paths:
        raise UsageError("no property files")
    return [load_spec(str(p)).with_window(window) for p in paths]


def verify(req: Request, rep: Reporter) -> Outcome:
    """Run the experiment of ``req``; progress goes to ``rep`` (a multi-target design:
    lesmc/experiment/multi_verify.py, which lesmc.api.verify calls instead)."""
    started = time.monotonic()
    specs = load_specs([Path(s) for s in req.specs] or bundled_specs(), req.window)
    faults = load_faults(req.faults) if req.faults is not None else None
    if detector_verify.detector_file_of(req.nets) is not None:  # docs/detectors.md
        detector_verify.refuse_window_options(
            req.nets, bool(neuron_faults(faults)), req.inject is not None
        )
    _check_neuron_faults(req, faults)
    if req.scene_path is not None:
        src = _scene_file(req)
    else:
        on_demand = req.payoffs == "attack" and faults is None and not req.price_all
        src = _perceived(req, specs, rep, bool(neuron_faults(faults)), on_demand)
    if req.window is not None:
        check_window(src.scene, req.window)
    if req.space is not None and (src.frames is None or src.truth is None):  # before work
        raise UsageError("--space needs the video's truth (--truth): tune runs its vehicles")
    src.meta["target"] = _target_text(src.scene)
    src.meta["properties"] = ", ".join(s.path for s in specs)
    rep.log(f"target: {src.meta['target']}")
    neuron = _neuron_runs(req, faults, src, rep)
    checked = time.monotonic()
    try:  # the job is not kept: the scene it checked gives way to the settled one
        results = run_job(_job(req, specs, faults, neuron, src, rep))
        search = None if req.space is None else _design_search(req, src, specs, rep)
    finally:  # what was priced is kept, even when a budget or an interrupt stops the checks
        _keep_priced(src)
    results = _settled(results, src, rep)
    timings = {"video, perception and scene": checked - started}
    timings["models and checks"] = time.monotonic() - checked - (search[1] if search else 0.0)
    if src.pricing is not None:  # within the models and checks
        timings["payoffs on demand"] = src.pricing[1].seconds
    doc = _document(req, src, specs, results, timings, rep)
    if search is not None:  # --space: the designs searched, before the payoffs settled
        doc["design_search"] = search[0]
        doc["timings"]["design search"] = round(search[1], 3)
    report = _write(doc, req.out, src, results, rep)
    return Outcome(results, doc, report)


def _job(
    req: Request,
    specs: list[SpecFile],
    faults: FaultSet | None,
    neuron: NeuronRuns,
    src: _Source,
    rep: Reporter,
) -> Job:
    """The check pipeline's job: every design's model built whole (the report draws it)."""
    return Job(
        tuple(specs),
        scene=src.scene,
        designs=req.designs,
        payoffs=req.payoffs,
        budget=req.budget,
        full_models=True,
        certify=_certifier(src, rep, req.budget) if req.payoffs != "attack" else None,
        faults=faults,
        neuron_frames=neuron.frames or None,
        neuron_certify=neuron.certify or None,
        source=req.scene_path or str(req.out / "scene.json"),
        on_stage=rep.stage,
    )


def _check_neuron_faults(req: Request, faults: FaultSet | None) -> None:
    """Each neuron fault checked against the networks before any perception runs."""
    if not neuron_faults(faults):
        return
    assert faults is not None
    if req.scene_path is None:
        from lesmc.perception.cnn import load_nets

        check_units(faults, load_nets(*req.nets))


def _neuron_runs(req: Request, faults: FaultSet | None, src: _Source, rep: Reporter) -> NeuronRuns:
    """The video perceived under every set of neuron faults (lesmc/experiment/neuron_faults.py);
    none without neuron faults, or on a scene file (the pipeline then says why)."""
    seen = src.perceived
    if not neuron_faults(faults) or seen is None or src.frames is None or src.cache is None:
        return NeuronRuns()
    assert faults is not None
    return neuron_frames(
        faults,
        src.frames,
        src.networks,
        seen,
        src.cache,
        rep,
        lambda stage: _spent(req.budget, stage),
        req.payoffs != "attack",
    )


# ------------------------------------------------------------------ the scene


def _scene_file(req: Request) -> _Source:
    """A scene from ``lesmc perceive -o``; frames only from the directory named."""

    if req.frames_dir is not None:
        raise UsageError("give FRAMES_DIR or --scene, not both")
    if req.truth is not None:
        raise UsageError("--truth applies to a video, not to --scene")
    if req.price_all:
        raise UsageError("--price-all prices a video's detections: a scene has its payoffs")
    if any(req.nets) and req.scene_frames is None:
        raise UsageError(
            "--nets, --detector and --locator with --scene apply only to the replay: give "
            "--frames too"
        )
    scene = load_scene_with_target(req.scene_path or "", req.target, None, _tracker(req))
    by_file = detector_verify.detector_file_of(req.nets) is not None
    if isinstance(scene.meta.get("detector_file"), dict) != by_file and req.scene_frames:
        raise UsageError(
            f"{req.scene_path} was perceived with a detector file (meta.detector_file): give it "
            "as --detector FILE.toml to replay through it (docs/detectors.md)"
            if not by_file
            else f"--detector {req.nets[1]} is a detector file; {req.scene_path} was perceived "
            "by the window pipeline (no meta.detector_file)"
        )
    from lesmc.video.reader import open_frames

    least = 1 if by_file else HISTORY + 1  # a detector file has no background
    frames = open_frames(req.scene_frames, least) if req.scene_frames else None
    nets = req.nets if frames is not None else None  # loaded by the replay, if it runs
    return _Source(
        scene, frames, meta={"scene": req.scene_path}, net_files=nets, cache=StageCache(req.out)
    )


def _perceived(
    req: Request, specs: list[SpecFile], rep: Reporter, maxima: bool, on_demand: bool
) -> _Source:
    """The scene of a video: rendered (the default), perceived, its target placed or chosen;
    with ``maxima`` the networks' unit maxima too (neuron faults read them); ``on_demand``:
    payoffs priced when a model reads them (lesmc/experiment/pricing.py)."""
    if req.scene_frames is not None:
        raise UsageError("--frames goes with --scene; a video is given as FRAMES_DIR")
    frames_dir, truth, meta, fresh = _video(req, rep)
    # after the video: these imports (scipy.spatial, 0.45 s) would delay its rendering
    from lesmc.experiment.targets import auto_target, target_scene, truth_tracks

    if not req.target and not truth:
        raise UsageError("--target is needed (or --truth, to choose one)")
    from lesmc.video.reader import open_frames

    # frames this run rendered need no decoding up front to be checked (0.7 s); any
    # other file beside them (an older video's) makes every frame checked
    by_file = detector_verify.detector_file_of(req.nets)
    least = HISTORY + 1 if by_file is None else 1  # a detector file has no background
    frames = open_frames(frames_dir, least, check=fresh is None)
    if fresh is not None and frames.paths != fresh:
        frames = open_frames(frames_dir, least)
    target = parse_target(req.target) if req.target else None
    if target is not None:
        check_target(target, frames.width, frames.height, len(frames))
    truths = load_truth(truth) if truth else None
    dt = (truths.dt if truths else None) or 1 / FPS
    cache = StageCache(req.out)
    if by_file is None:
        seen = _perception(req, frames, frames_dir, dt, cache, rep, maxima, on_demand)
    else:
        seen = _file_perception(
            req, frames, frames_dir, by_file, (truth, truths), dt, rep, on_demand
        )
        assert seen.detections is not None
        meta["detections"] = detector_verify.describe(seen.detections)
        rep.log(f"detector file: {meta['detections']}")
    footage = seen.footage
    tracker = _tracker(req)
    if tracker is not None:
        footage = dataclasses.replace(footage, tracker=tracker)
    if truths is not None:  # the acceptable paths of dist.nearest (section 4.2)
        footage = dataclasses.replace(footage, truth=truth_tracks(footage, frames, truths))
    if target is not None:
        scene = target_scene(footage, target, frames, truths)
    else:
        assert truths is not None
        scene = auto_target(footage, frames, truths, specs)
        meta["target choice"] = scene.meta["target_choice"]
    meta |= {"detector": footage.meta.get("detector", ""), "scene": str(req.out / "scene.json")}
    return _Source(
        scene, frames, truths, seen.nets, seen.run, meta, True, req.nets, truth, cache,
        (seen.key, seen.unit_max, dt) if by_file is None or seen.pricing else None,
        seen.pricing, seen.detections,
    )  # fmt: skip


@dataclass
class _Perception:
    """The video's footage, with the networks and run that made it (None when read from
    OUT/cache), each hidden unit's largest value, and the cache key of the inputs."""

    footage: Footage
    nets: Any
    run: Any
    unit_max: UnitMax
    key: str
    pricing: tuple[OnDemandPayoffs, VideoPricer, Footage] | None = None
    #: a detector file's detections: counts, recall and precision, payoffs (detector_verify)
    detections: dict[str, Any] | None = None


def _perception(
    req: Request,
    frames: FrameSet,
    frames_dir: str,
    dt: float,
    cache: StageCache,
    rep: Reporter,
    maxima: bool,
    on_demand: bool,
) -> _Perception:
    """The video's detections and attack payoffs: read from OUT/cache when this video was
    perceived before with the same networks, settings and code (then no network is
    loaded; in a certified payoff mode the run is needed, so the video is perceived
    again), else perceived now and stored. ``maxima``: the networks' unit maxima are
    needed too; an entry stored without them (by a run without neuron faults) is then
    perceived again, recording them. ``on_demand``: a payoff is priced when a model
    first reads it (lesmc/experiment/pricing.py); otherwise every detection is priced now,
    and an entry with unpriced payoffs is perceived again."""
    key = _perception_key(req, frames, frames_dir, dt)
    hit = video_perception.read(cache, "perception", key) if req.payoffs == "attack" else None
    if hit is not None and maxima and not hit[1]:
        rep.log("perceiving the video again: its cached perception has no unit maxima")
        hit = None
    if hit is not None and not on_demand and hit[0].has_unpriced:
        rep.log("perceiving the video again: its cached perception has unpriced payoffs")
        hit = None

    def perceive() -> tuple[Footage, Any, Any]:
        return _perceive_now(req, frames, frames_dir, dt, rep, maxima, on_demand)

    if hit is not None:
        rep.log(f"reusing the perception of {frames_dir} from {cache.dir}")
        seen = _Perception(hit[0], None, None, hit[1], key)
        if not on_demand or not hit[0].has_unpriced:
            return seen

        def again() -> tuple[Any, Any]:  # a payoff the cached entry lacks: its windows
            rep.log("perceiving the video again: a check reads payoffs its cache lacks")
            footage, nets, run = perceive()
            _same_detections(hit[0], footage, cache)
            return nets, run

        return _on_demand(seen, VideoPricer(None, None, again), req.budget)
    footage, nets, run = perceive()
    video_perception.store(cache, "perception", key, footage, run.unit_max)
    seen = _Perception(footage, nets, run, run.unit_max, key)
    if not on_demand:
        return seen
    return _on_demand(seen, VideoPricer(nets, run, lambda: (nets, run)), req.budget)


def _file_perception(
    req: Request,
    frames: FrameSet,
    frames_dir: str,
    path: str,
    truth: tuple[str | None, Any],
    dt: float,
    rep: Reporter,
    on_demand: bool,
) -> _Perception:
    """The video through the detector file ``path`` (lesmc/experiment/detector_verify.py),
    kept in OUT/cache: a heatmap or box detector's payoffs priced when a model reads them
    (as the window pipeline's: ``on_demand``, --payoffs attack, no --price-all), else every
    detection priced now (a multi-target design reads the scene's payoffs directly)."""
    lazy = on_demand and req.payoffs == "attack" and not req.price_all
    footage, facts, key = detector_verify.perceive_cached(
        frames_dir, frames, path, truth[0], truth[1], req.payoffs != "attack", dt, rep,
        lambda stage: _spent(req.budget, stage), StageCache(req.out), lazy,
    )  # fmt: skip
    seen = _Perception(footage, None, None, {}, key, detections=facts)
    if not lazy or not footage.has_unpriced:
        return seen
    return _on_demand(seen, detector_verify.FilePricer(path, frames, footage), req.budget)


def _perception_key(req: Request, frames: FrameSet, frames_dir: str, dt: float) -> str:
    """The cache key of a video's perception: its frames' bytes, the networks' files, the
    settings and the code that perceives."""
    from lesmc.perception.attack_settings import AttackConfig

    return digest(
        {
            "code": code_digest("perception", "video", "scene"),
            "frames": file_digests(frames.paths),
            "nets": file_digests(net_files(req.nets)),
            "source": str(frames_dir),
            "dt": dt,
            "history": HISTORY,
            "attack": asdict(AttackConfig()),
        }
        | _inject_key(req)
    )


def _inject_key(req: Request) -> dict[str, Any]:
    """The injection candidates' part of the perception's cache key (none without them:
    the keys of runs without candidates stay as they were)."""
    return {} if req.inject is None else {"inject": list(req.inject)}


def _same_detections(cached: Footage, again: Footage, cache: StageCache) -> None:
    """The video perceived again must give the cached perception's detections, else its
    payoffs would be priced for other detections than the cached ones."""
    same = len(cached.frames) == len(again.frames) and all(
        f.step == g.step and np.array_equal(f.positions(), g.positions())
        for f, g in zip(cached.frames, again.frames, strict=True)
    )
    if not same:
        raise UsageError(
            f"{cache.dir}: the cached perception's detections differ from the video's "
            f"perceived again; remove {cache.dir} and run again"
        )


def _perceive_now(
    req: Request,
    frames: FrameSet,
    frames_dir: str,
    dt: float,
    rep: Reporter,
    maxima: bool,
    on_demand: bool,
) -> tuple[Footage, Any, Any]:
    """The video perceived now: its footage, the networks and the perception run (without
    an attack when ``on_demand``; keeping the N_dr windows that certification or pricing
    read)."""
    from lesmc.perception.cnn import load_nets

    nets = load_nets(*req.nets)
    _spent(req.budget, "loading the video and the networks")
    with rep.bar("perceiving", len(frames)) as bar:

        def advance() -> None:
            bar.advance()
            _spent(req.budget, "perceiving the video")

        meta = {"source": str(frames_dir), "detector": nets.settings.trained_on}
        meta |= networks_meta(req.nets)
        keep = req.payoffs != "attack" or on_demand
        footage, run = video_perception.perceive_video(
            frames, nets, dt, meta, keep, advance, maxima, not on_demand, req.inject
        )
    return footage, nets, run


def _on_demand(seen: _Perception, pricer: VideoPricer, budget: Budget) -> _Perception:
    """``seen`` with its unpriced payoffs priced by ``pricer`` when a model reads them
    (within ``budget``: past it, verify stops as while building a model)."""
    pricer.on_price = lambda _n: _spent(budget, "pricing payoffs")
    footage, prices = on_demand_footage(seen.footage, pricer)
    return dataclasses.replace(seen, footage=footage, pricing=(prices, pricer, footage))


def _settled(results: Results, src: _Source, rep: Reporter) -> Results:
    """``results`` and ``src`` with the payoffs priced on demand written into their scenes'
    detections (one copy of the frames) and ``meta.priced`` saying which; the pricer's
    windows let go. Unchanged without pricing."""
    if src.pricing is None:
        return results
    prices, pricer, footage = src.pricing
    pricer.release()  # the replay reads only the detections' positions
    settled = src.scene.settled()  # one copy of the frames, shared by every run's scene
    meta = priced_meta(settled)
    src.scene = dataclasses.replace(settled, meta={**settled.meta, "priced": meta})
    rep.log(
        f"priced {prices.asked} detections on demand ({pricer.seconds:.1f} s); "
        f"{meta['detections']} of {meta['of']} carry a payoff"
    )
    src.meta["payoffs"] = (
        f"{meta['detections']} of {meta['of']} detections attacked, on demand: the ones the "
        "checked models read (the others are unpriced in scene.json)"
    )
    if src.detections is not None:  # a detector file's: its payoffs' facts as settled
        src.detections |= detector_verify.payoff_facts(settled.frames)
        src.meta["detections"] = detector_verify.describe(src.detections)
    for run in results.runs:
        if run.scene is not None:
            run.scene = dataclasses.replace(run.scene, frames=settled.frames)
    footage = dataclasses.replace(footage, frames=settled.frames)  # as perception made it
    src.pricing = (prices, pricer, footage)  # the frames priced on demand are let go
    release()  # the windows' and the frames' pages go back to the system before the replay
    return dataclasses.replace(results, scene=src.scene)


def _keep_priced(src: _Source) -> None:
    """OUT/cache's perception stored again with the payoffs this run priced on demand (a
    rerun of the same checks prices nothing)."""
    if src.pricing is None or src.cache is None or src.perceived is None:
        return
    prices, _, footage = src.pricing
    if prices.asked:
        key, unit_max, _ = src.perceived
        video_perception.store(src.cache, "perception", key, footage.settled(), unit_max)


def _tracker(req: Request) -> TrackerConfig | None:
    """The tracker file's configuration, if ``--tracker`` gave one."""
    return None if req.tracker is None else load_tracker(req.tracker)


def _video(
    req: Request, rep: Reporter
) -> tuple[str, str | None, dict[str, Any], list[Path] | None]:
    """The video's frames and truth: FRAMES_DIR, or the embedded default in OUT/video; and
    the frames this run rendered (None: it rendered none)."""
    if req.frames_dir is not None:
        return req.frames_dir, req.truth, {"video": req.frames_dir}, None
    if req.truth is not None:
        raise UsageError("--truth is FRAMES_DIR's truth: the default video brings its own")
    video = req.out / "video"
    fresh = None
    if default_video_ready(video):
        rep.log(f"reusing the default video in {video}")
    else:
        with rep.bar("rendering", DEFAULT_VIDEO["frames"]) as bar:

            def rendered() -> None:
                bar.advance()
                _spent(req.budget, "rendering the default video")

            fresh = write_default_video(video, rendered, meanwhile=_import_perception)
        release()  # what rendering or the imports freed goes back before perception
    what = (
        f"embedded default: lesmc synth {video} --seed {DEFAULT_VIDEO['seed']} "
        f"--frames {DEFAULT_VIDEO['frames']}"
    )
    return str(video), str(video / "truth.json"), {"video": what}, fresh


def _spent(budget: Budget, stage: str) -> None:
    """Stop before a verdict exists (exit 3, nothing written) once the budget is spent."""
    reason = budget.exceeded()
    if reason is not None:
        raise BudgetError(f"{budget.describe(reason)} ran out while {stage}; nothing was written")


def _target_text(scene: Scene) -> str:
    t = scene.target
    return (
        f"({t.start[0]:.1f}, {t.start[1]:.1f}) in frame {t.step}, velocity "
        f"({t.velocity[0]:.1f}, {t.velocity[1]:.1f}) px/s"
    )


def check_window(scene: Scene, window: tuple[int, int]) -> None:
    """``--window`` against the unattacked track's length, before any model is built."""

    e = original_end(scene)
    if not 1 <= window[0] <= window[1] <= e:
        raise UsageError(
            f"--window {window[0]}..{window[1]} must satisfy 1 <= L <= U <= {e}, the last step "
            f"of the unattacked track from frame {scene.target.step}"
        )


def default_video_ready(video: Path) -> bool:
    """Whether ``video`` already holds exactly the embedded default video."""
    from lesmc.video.synth import SynthConfig

    truth = video / "truth.json"
    if not truth.is_file():
        return False
    try:
        same = json.loads(truth.read_text()).get("config") == asdict(SynthConfig(**DEFAULT_VIDEO))
    except ValueError:
        return False
    return same and len(list(video.glob("frame_*.png"))) == DEFAULT_VIDEO["frames"]


def write_default_video(
    video: Path,
    progress: Callable[[], None] | None = None,
    meanwhile: Callable[[], None] | None = None,
) -> list[Path]:
    """Generate the embedded default video (``lesmc synth`` with ``DEFAULT_VIDEO``); the
    frames written. With ``meanwhile``, a child process renders while it runs here
    (:func:`lesmc.video.write.write_video`)."""
    from lesmc.video.synth import SynthConfig
    from lesmc.video.write import write_video

    return write_video(SynthConfig(**DEFAULT_VIDEO), video, progress, meanwhile)


def _import_perception() -> None:
    """Import perception's code (torch and the networks', scipy.spatial, faiss) and the
    targets' while the default video renders aside: a video just rendered is perceived
    next (2-2.5 s of imports off the critical path)."""
    import lesmc.experiment.targets
    import lesmc.perception.run  # noqa: F401


def _certifier(src: _Source, rep: Reporter, budget: Budget) -> Certifier | None:
    """Perception's certification of the video's detections (none for a scene file: its
    bounds come with it, from ``perceive --certify``)."""
    if src.run is None:
        return None
    return video_perception.certifier(
        src.nets,
        src.run,
        "certifying",
        rep,
        lambda _: _spent(budget, "certifying payoff lower bounds"),
    )


# ------------------------------------------------------------------ results and report


def _document(
    req: Request,
    src: _Source,
    specs: list[SpecFile],
    results: Results,
    timings: dict[str, float],
    rep: Reporter,
) -> dict[str, Any]:
    """The results document: the runs, the truth and the monitor's false alarms on it,
    what perception did; then every violated counterexample replayed."""
    truth, extra = _truth_facts(src, results, timings)
    extra["perception"] = _perception_facts(req, src, results)
    seeds = (
        {"video": DEFAULT_VIDEO["seed"]}
        if req.frames_dir is None and req.scene_path is None
        else {}
    )
    rep.stage("writing the results")
    doc = results_document(
        results.runs, src.meta, provenance(specs, seeds=seeds), timings, truth, extra
    )
    _replay(doc, results, src, timings, rep, req.budget)
    doc["timings"] = {k: round(float(v), 3) for k, v in timings.items()}
    return doc


def _design_search(
    req: Request, src: _Source, specs: list[SpecFile], rep: Reporter
) -> tuple[dict[str, Any], float]:
    """``--space``: lesmc tune's search on this video's scene (lesmc/experiment/tune.py),
    while its payoffs are still priced on demand; and the seconds it took."""
    from lesmc.experiment.tune import design_search

    assert req.space is not None and src.frames is not None and src.truth is not None
    t0 = time.monotonic()
    tfs = _truth_frames(src, src.scene)
    size = (src.frames.width, src.frames.height)
    where = req.scene_path or str(req.out / "scene.json")

    def told(i: int, g: Any) -> None:
        rep.stage(f"searching designs: {g.designs[0].label().rsplit(' + ', 1)[0]} ({i + 1})")

    out = design_search(src.scene, specs, tfs, size, req.space, where, req.budget.max_states, told)
    return out, time.monotonic() - t0


def _truth_facts(
    src: _Source, results: Results, timings: dict[str, float]
) -> tuple[Any, dict[str, Any]]:
    """With the video's truth: the target's true track and the monitor's false alarms on
    every truth track (lesmc/experiment/false_alarms.py)."""
    if src.frames is None or src.truth is None:
        return None, {}

    scene = src.scene.payoff_free()  # the monitor reads only the unattacked states
    tfs = _truth_frames(src, scene)
    if not tfs:
        return None, {}
    t0 = time.monotonic()
    end = max(run.model.end for run in results.runs if run.model is not None)
    monitored = sorted(
        {registry.get(r.design).tracker for r in results.runs if registry.get(r.design).monitor}
    )
    size = (src.frames.width, src.frames.height)
    steps, designs = min(end, len(tfs) - 1), monitored or [registry.BASELINE]
    key = None
    if src.cache is not None and src.truth_path is not None:
        key = digest(
            {
                "code": code_digest("verify", "tracking", "scene", "designs", "model"),
                "scene": scene_to_dict(scene),
                "truth": file_digests([Path(src.truth_path)]),
                "frames": [p.name for p in src.frames.paths],
                "size": size,
                "steps": steps,
                "designs": designs,
            }
        )
    report = src.cache.get("false-alarms", key) if src.cache and key else None
    if not (isinstance(report, dict) and isinstance(report.get("rows"), list)):
        report = false_alarm_report(scene, tfs, size, steps, designs)
        if src.cache is not None and key is not None:
            src.cache.put("false-alarms", key, report)
    timings["monitor false alarms"] = time.monotonic() - t0
    return truth_track(tfs, scene.target.start) or None, {"monitor_false_alarms": report}


def _truth_frames(src: _Source, scene: Scene) -> list[TruthFrame]:
    """The truth of the frames from the scene's target frame on, up to the first frame
    the truth file lacks."""
    assert src.frames is not None and src.truth is not None
    tfs = [src.truth.frames.get(p.name) for p in src.frames.paths[scene.target.step :]]
    return [t for t in tfs[: next((i for i, t in enumerate(tfs) if t is None), len(tfs))] if t]


def video_truth(
    req: Request, rep: Reporter, priced: bool = False
) -> tuple[Scene, list[TruthFrame], tuple[int, int]]:
    """What ``lesmc verify`` measures the monitor's false alarms on (``lesmc alarms`` on a
    video): the video's scene, perceived (or read from OUT/cache) with its target chosen
    as verify chooses it, without payoffs (``priced``: with the payoffs priced when a
    model reads them, as verify checks it; ``lesmc tune``); the truth frames from the
    target's frame on; the frame size."""
    specs = load_specs([Path(s) for s in req.specs] or bundled_specs(), req.window)
    src = _perceived(req, specs, rep, False, True)
    if src.frames is None or src.truth is None:
        raise UsageError("the video has no truth.json: give --truth (the truth tracks to run)")
    scene = src.scene if priced else src.scene.payoff_free()
    return scene, _truth_frames(src, scene), (src.frames.width, src.frames.height)


def _perception_facts(req: Request, src: _Source, results: Results) -> dict[str, Any]:
    """How the scene's detections and payoffs were made (for the report and the replay)."""
    from lesmc.perception.attack_settings import AttackConfig, attack_of, frontend_of

    attack = (
        attack_of(src.scene.meta, str(req.scene_path))
        if req.scene_path is not None
        else AttackConfig()
    )
    # a scene's front end as it records it (lesmc perceive -o), else the defaults
    fe = frontend_of(dict(src.scene.meta)) if req.scene_path is not None else {}
    out: dict[str, Any] = {
        "history": fe.get("history", HISTORY),
        "delta_bc": fe.get("delta_bc", DELTA_BC),
        "nets": (
            src.nets.settings.trained_on
            if src.nets is not None
            else str(src.scene.meta.get("detector", ""))
        ),
        "attack": asdict(attack),
        "payoffs": req.payoffs,
    }
    if src.frames is not None and src.frames.paths:
        out["frames"] = str(src.frames.paths[0].parent.resolve())
    if results.certified is not None:  # this run's certification (a --scene keeps its own)
        out["certified"] = results.certified
    if src.pricing is not None:  # this run priced on demand (lesmc/experiment/pricing.py)
        out["priced"] = src.scene.meta["priced"]
    if isinstance(src.scene.meta.get("detector_file"), dict):  # docs/detectors.md
        out["detector_file"] = src.scene.meta["detector_file"]
    if src.detections is not None:
        out["detections"] = src.detections
    return out


def _replay(
    doc: dict[str, Any],
    results: Results,
    src: _Source,
    timings: dict[str, float],
    rep: Reporter,
    budget: Budget,
) -> None:
    """Replay every violated property through the real detector (lesmc/replay); the
    results and the document record what each replay found. The same counterexamples on
    the same frames and networks replay from OUT/cache."""
    from lesmc.replay.run import Outcome

    typed = results_of(doc)
    todo = cases(typed)
    if not todo or src.frames is None or (src.nets is None and src.net_files is None):
        return
    t0 = time.monotonic()
    key = _replay_key(doc, src, todo)
    hit = None if src.cache is None or key is None else src.cache.get("replay", key)
    outcome = _cached_replay(hit, doc)
    if outcome is not None:
        rep.log(f"reusing the replay of {len(outcome.replays)} counterexamples from the cache")
    else:
        outcome = _replay_now(typed, src, rep, budget)
        if src.cache is not None and key is not None:
            rows = [[i, j, obj] for (i, j), obj in outcome.replays.items()]
            src.cache.put("replay", key, {"replays": rows, "seconds": outcome.seconds})
    assert isinstance(outcome, Outcome)
    apply(doc, outcome, results)
    timings["replay"] = time.monotonic() - t0


def _replay_now(typed: Any, src: _Source, rep: Reporter, budget: Budget) -> Any:
    """The counterexamples of ``typed`` replayed now: through the detector file, or the
    window pipeline's networks (only the attacked frames redone when this run perceived)."""
    assert src.frames is not None
    by_file = detector_verify.detector_file_of(src.net_files or (None, None, None))
    if by_file is not None:  # through the detector file (lesmc/replay/detector_file.py)
        frames_dir = str(src.frames.paths[0].parent)
        return detector_verify.replay(typed, frames_dir, by_file, rep)
    frames, nets = src.frames, src.networks()
    # this run's perception made the clean detections: only attacked frames are redone
    clean = None if src.run is None else {fd.index: fd for fd in src.run.detections}
    known = None if src.run is None else src.run.registrations
    with rep.bar("replaying", len(frames) if clean is None else None) as bar:

        def advance() -> None:
            bar.advance()
            _spent(budget, "replaying the counterexamples")

        return replay(
            typed, frames, nets, on_frame=advance, clean=clean, registrations=known,
            scene=src.scene,
        )  # fmt: skip


def _replay_key(doc: dict[str, Any], src: _Source, todo: list[Any]) -> str | None:
    """The digest of what the replay reads: each case's run (its scene, paths and results
    without their timings), the frames, the networks and the code; None: not cacheable
    (networks given as loaded objects)."""
    if src.net_files is None or src.frames is None:
        return None
    runs = []
    for i in sorted({c.run for c in todo}):
        run = {k: v for k, v in doc["runs"][i].items() if k != "faults"}  # not replayed
        run["results"] = [
            {k: v for k, v in r.items() if k not in ("stats", "certified_stats")}
            for r in run["results"]
        ]
        runs.append([i, run])
    perception = doc.get("perception", {})
    return digest(
        {
            "code": code_digest("replay", "perception", "video", "tracking", "scene", "designs"),
            "frames": file_digests(src.frames.paths),
            "nets": file_digests(net_files(src.net_files)),
            **detector_verify.replay_key(src.net_files),
            "settings": {k: perception.get(k) for k in ("history", "delta_bc", "attack")},
            "runs": runs,
            "cases": [[c.run, c.result] for c in todo],
        }
    )


def _cached_replay(hit: Any, doc: dict[str, Any]) -> Any:
    """A cache entry as the replay's Outcome, if it is one for these cases; else None."""
    from lesmc.replay.run import Outcome
    from lesmc.results.load import replay_ok

    if not isinstance(hit, dict) or not isinstance(hit.get("replays"), list):
        return None
    replays: dict[tuple[int, int], dict[str, Any]] = {}
    for row in hit["replays"]:
        if not (isinstance(row, list) and len(row) == 3 and isinstance(row[2], dict)):
            return None
        i, j, obj = row
        ok = isinstance(i, int) and isinstance(j, int) and 0 <= i < len(doc["runs"])
        if not ok or not 0 <= j < len(doc["runs"][i]["results"]) or not replay_ok(obj, "results"):
            return None
        replays[(i, j)] = obj
    seconds = hit.get("seconds")
    return Outcome(replays, float(seconds) if isinstance(seconds, (int, float)) else 0.0)


def _write(doc: dict[str, Any], out: Path, src: _Source, results: Results, rep: Reporter) -> Path:
    """report.html, figures/ and results.json into ``out`` (staged: all or nothing), then
    the scene this run made or certified."""
    from lesmc.report.html import write_report

    rep.stage("writing the report")
    files = {}
    if src.new or results.certified is not None:  # published with the results that use it
        scene = results.scene if results.scene is not None else src.scene
        files["scene.json"] = json_text(scene_to_dict(scene))
    store = None if src.cache is None else FigureStore(src.cache)
    page = write_report(doc, out, _frame_reader(src.frames), files, store)
    if store is not None and store.found:
        rep.log(f"reused {store.found} of {store.asked} distinct figures from {store.cache.dir}")
    return page


def _frame_reader(frames: FrameSet | None) -> Callable[[int], np.ndarray | None] | None:
    """``index -> grey frame`` for the report's images (None past the video's end, or for
    a frame that cannot be read)."""
    from lesmc.report.publish import frame_reader

    return None if frames is None else frame_reader(frames, skip_unreadable=True)
