"""``lesmc verify``: the paper's whole experiment in one call (section 8).

frames -> scene (perception, payoffs) -> the check pipeline for every design
(lesmc/pipeline/check.py) -> results document -> replay of the counterexamples
-> report. Each stage is the code of its own verb; this module chains them and
picks the defaults: the embedded synthetic video, a target with neighbouring
traffic, the bundled robustness and resilience specs, the paper's designs. Its parts:
what it was asked and the scene it checks (verify_request.py), the embedded default
video (default_video.py), the video's perception (verify_perception.py), the results
document (verify_results.py) and the replay of its counterexamples (verify_replay.py).
"""

from __future__ import annotations

import dataclasses
import time
from dataclasses import dataclass
from importlib import resources
from pathlib import Path
from typing import TYPE_CHECKING, Any

from lesmc.common.budget import Budget
from lesmc.common.errors import UsageError
from lesmc.common.files import json_text
from lesmc.common.memory import release
from lesmc.common.progress import Reporter
from lesmc.experiment import detector_verify, video_perception
from lesmc.experiment.cache import FigureStore, StageCache
from lesmc.experiment.default_video import video_and_truth
from lesmc.experiment.neuron_faults import NeuronRuns, check_units, neuron_faults, neuron_frames
from lesmc.experiment.pricing import priced_meta
from lesmc.experiment.verify_perception import file_perception, perception
from lesmc.experiment.verify_request import Request, Source, spent
from lesmc.experiment.verify_results import design_search, document, truth_frames
from lesmc.language.parser import load_faults, load_spec
from lesmc.language.properties import FaultSet, SpecFile
from lesmc.perception import HISTORY
from lesmc.perception.quality import TruthFrame, load_truth
from lesmc.pipeline.check import run as run_job
from lesmc.pipeline.job import Certifier, Job
from lesmc.results.record import Results
from lesmc.scene import Scene, TrackerConfig, load_tracker, scene_to_dict
from lesmc.tracking.targets import check_target, load_scene_with_target, parse_target
from lesmc.unfold.unfold import original_end
from lesmc.video import FPS

if TYPE_CHECKING:  # reading frames imports cv2: only where a video is read
    from lesmc.report.figures import ImageFor
    from lesmc.video.reader import FrameSet


@dataclass
class Outcome:
    """What a verification produced: the typed results (after the replay), the results
    document and the report's path."""

    results: Results
    doc: dict[str, Any]
    report: Path


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
        src = scene_file(req)
    else:
        on_demand = req.payoffs == "attack" and faults is None and not req.price_all
        src = perceived(req, specs, rep, bool(neuron_faults(faults)), on_demand)
    if req.window is not None:
        check_window(src.scene, req.window)
    if req.space is not None and (src.frames is None or src.truth is None):  # before work
        raise UsageError("--space needs the video's truth (--truth): tune runs its vehicles")
    src.meta["target"] = target_text(src.scene)
    src.meta["properties"] = ", ".join(s.path for s in specs)
    rep.log(f"target: {src.meta['target']}")
    neuron = _neuron_runs(req, faults, src, rep)
    checked = time.monotonic()
    try:  # the job is not kept: the scene it checked gives way to the settled one
        results = run_job(_job(req, specs, faults, neuron, src, rep))
        search = None if req.space is None else design_search(req, src, specs, rep)
    finally:  # what was priced is kept, even when a budget or an interrupt stops the checks
        _keep_priced(src)
    results = _settled(results, src, rep)
    timings = {"video, perception and scene": checked - started}
    timings["models and checks"] = time.monotonic() - checked - (search[1] if search else 0.0)
    if src.pricing is not None:  # within the models and checks
        timings["payoffs on demand"] = src.pricing[1].seconds
    doc = document(req, src, specs, results, timings, rep)
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
    src: Source,
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


def _neuron_runs(req: Request, faults: FaultSet | None, src: Source, rep: Reporter) -> NeuronRuns:
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
        lambda stage: spent(req.budget, stage),
        req.payoffs != "attack",
    )


def scene_file(req: Request) -> Source:
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
    from lesmc.perception.attack_settings import frontend_of

    # the front end the scene records, refused out of range before any work (the replay
    # reruns it: its history frames before the first)
    history = frontend_of(dict(scene.meta), req.scene_path or "").get("history", HISTORY)
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

    least = 1 if by_file else history + 1  # a detector file has no background
    frames = open_frames(req.scene_frames, least) if req.scene_frames else None
    nets = req.nets if frames is not None else None  # loaded by the replay, if it runs
    return Source(
        scene, frames, meta={"scene": req.scene_path}, net_files=nets, cache=StageCache(req.out)
    )


def perceived(
    req: Request, specs: list[SpecFile], rep: Reporter, maxima: bool, on_demand: bool
) -> Source:
    """The scene of a video: rendered (the default), perceived, its target placed or chosen;
    with ``maxima`` the networks' unit maxima too (neuron faults read them); ``on_demand``:
    payoffs priced when a model reads them (lesmc/experiment/pricing.py)."""
    if req.scene_frames is not None:
        raise UsageError("--frames goes with --scene; a video is given as FRAMES_DIR")
    frames_dir, truth, meta, fresh = video_and_truth(req, rep)
    # after the video: these imports (scipy.spatial, 0.45 s) would delay its rendering
    from lesmc.experiment.targets import auto_target, target_scene, truth_tracks

    if not req.target and not truth:
        raise UsageError("--target is needed (or --truth, to choose one)")
    from lesmc.video.reader import open_frames

    # frames this run rendered need no decoding up front to be checked (0.7 s); any
    # other file beside them (an older video's) makes every frame checked
    by_file = detector_verify.detector_file_of(req.nets)
    if by_file is not None and req.payoffs != "attack":  # before perceiving, as campaign
        detector_verify.refuse_uncertifiable(by_file, "--payoffs certified|interval")
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
        seen = perception(req, frames, frames_dir, dt, cache, rep, maxima, on_demand)
    else:
        seen = file_perception(
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
    return Source(
        scene, frames, truths, seen.nets, seen.run, meta, True, req.nets, truth, cache,
        (seen.key, seen.unit_max, dt) if by_file is None or seen.pricing else None,
        seen.pricing, seen.detections, seen.certified,
    )  # fmt: skip


def _settled(results: Results, src: Source, rep: Reporter) -> Results:
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


def _keep_priced(src: Source) -> None:
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


def target_text(scene: Scene) -> str:
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


def _certifier(src: Source, rep: Reporter, budget: Budget) -> Certifier | None:
    """Perception's certification of the video's detections, or the detector file's
    (lesmc/experiment/detector_verify.py); none for a scene file (its bounds come with it,
    from ``perceive --certify``) nor for a video whose detections were all certified up
    front (``--price-all``: ``src.certified``, decided by verify_perception.py)."""

    def stop(_: str) -> None:
        spent(budget, "certifying payoff lower bounds")

    if src.run is not None:
        return video_perception.certifier(src.nets, src.run, "certifying", rep, stop)
    by_file = detector_verify.detector_file_of(src.net_files or (None, None, None))
    if by_file is None or not src.new or src.frames is None or src.certified:
        return None
    return detector_verify.verify_certifier(by_file, src.frames, src.scene, rep, stop)


def video_truth(
    req: Request, rep: Reporter, priced: bool = False
) -> tuple[Scene, list[TruthFrame], tuple[int, int]]:
    """What ``lesmc verify`` measures the monitor's false alarms on (``lesmc alarms`` on a
    video): the video's scene, perceived (or read from OUT/cache) with its target chosen
    as verify chooses it, without payoffs (``priced``: with the payoffs priced when a
    model reads them, as verify checks it; ``lesmc tune``); the truth frames from the
    target's frame on; the frame size."""
    specs = load_specs([Path(s) for s in req.specs] or bundled_specs(), req.window)
    src = perceived(req, specs, rep, False, True)
    if src.frames is None or src.truth is None:
        raise UsageError("the video has no truth.json: give --truth (the truth tracks to run)")
    scene = src.scene if priced else src.scene.payoff_free()
    return scene, truth_frames(src, scene), (src.frames.width, src.frames.height)


def _write(doc: dict[str, Any], out: Path, src: Source, results: Results, rep: Reporter) -> Path:
    """report.html, figures/ and results.json into ``out`` (staged: all or nothing), then
    the scene this run made or certified."""
    from lesmc.report.html import write_report

    rep.stage("writing the report")
    files = {}
    if src.new or results.certified is not None:  # published with the results that use it
        scene = results.scene if results.scene is not None else src.scene
        files["scene.json"] = json_text(scene_to_dict(scene))
    store = None if src.cache is None else FigureStore(src.cache)
    page = write_report(doc, out, frame_reader(src.frames), files, store)
    if store is not None and store.found:
        rep.log(f"reused {store.found} of {store.asked} distinct figures from {store.cache.dir}")
    return page


def frame_reader(frames: FrameSet | None) -> ImageFor | None:
    """``index -> grey frame`` for the report's images (None past the video's end, or for
    a frame that cannot be read)."""
    from lesmc.report.publish import frame_reader

    return None if frames is None else frame_reader(frames, skip_unreadable=True)
