"""``lesmc verify --design sort`` (or ``gnn``): the experiment on a video for a multi-target
design (docs/trackers.md, "Verifying a multi-target design on a video").

The video is perceived as for the point designs (lesmc/experiment/experiment.py: the
same scene, each detection with its N_dr window as its box, every payoff priced up
front); the properties are checked by the multi-target check (lesmc/pipeline/multi.py);
the results file is a ``lesmc-multi-check`` document (version 2, with ``meta`` and
``timings``) from which lesmc/report/multi.py draws the report. Default properties:
specs/identity.spec (the paper's robustness and resilience on the target's track, and
a hijack: its identity switched), each attacking the detections within 40 px of the
target's reference (a frame of the video has hundreds of detections: every subset of
them is no search).
"""

from __future__ import annotations

import time
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING, Any

from lesmc.common.errors import UsageError
from lesmc.common.files import json_text, read_text
from lesmc.common.locations import error_at_items
from lesmc.common.progress import Reporter
from lesmc.designs import registry
from lesmc.language.properties import SpecFile
from lesmc.pipeline.multi import (
    MultiCheckResult,
    bound_properties,
    check_multi_design,
    multi_document,
)
from lesmc.scene import Scene, scene_to_dict, target_to_dict, tracker_from_dict

if TYPE_CHECKING:
    from lesmc.common.budget import Budget
    from lesmc.common.progress import Bar
    from lesmc.experiment.verify_request import Request
    from lesmc.perception import NetFiles
    from lesmc.replay.run import Outcome


@dataclass
class MultiOutcome:
    """What a verification of a multi-target design produced: the typed results, the
    results document (``lesmc-multi-check``) and the report's path."""

    results: list[MultiCheckResult]
    doc: dict[str, Any]
    report: Path


def identity_specs() -> list[Path]:
    """The properties verify checks on a multi-target design by default (specs/ in the
    repository, or the installed package's copy)."""
    from importlib import resources

    packaged = resources.files("lesmc") / "specs" / "identity.spec"
    if packaged.is_file():
        return [Path(str(packaged))]
    return [Path(__file__).resolve().parents[2] / "specs" / "identity.spec"]


def multi_designs(designs: tuple[str, ...]) -> tuple[str, ...]:
    """The multi-target designs among ``designs``: all of them or none (a mixed request is
    a UsageError: one results file holds one kind of result)."""
    multi = tuple(d for d in designs if registry.get(d).multi)
    if multi and len(multi) != len(designs):
        raise UsageError(
            f"--design: {', '.join(multi)} (multi-target) cannot be verified in one run with "
            f"{', '.join(d for d in designs if d not in multi)}; run verify once for each"
        )
    if len(multi) > 1:
        raise UsageError(f"--design: verify checks one multi-target design a run, got {multi}")
    return multi


def refuse_point_options(design: str, payoffs: str, given: tuple[str, ...] = ()) -> None:
    """A multi-target design is checked on attack payoffs only (``lesmc verify`` and
    ``lesmc campaign``): ``--payoffs certified|interval`` and the point designs' options
    ``given`` (verify's ``--faults``, ``--space``) are a UsageError before any work."""
    used = [*given, *([f"--payoffs {payoffs}"] if payoffs != "attack" else [])]
    if used:
        raise UsageError(
            f"--design {design}: {', '.join(used)} {'apply' if len(used) > 1 else 'applies'} "
            "to the point designs; a multi-target design is checked on attack payoffs"
        )


def verify_multi(req: Request, rep: Reporter) -> MultiOutcome:
    """Run the experiment of ``req`` (one multi-target design) and write its report."""
    from lesmc.experiment import detector_verify as dv
    from lesmc.experiment import experiment as ex
    from lesmc.unfold.multi import composed

    started = time.monotonic()
    (design,) = req.designs
    paths = [Path(s) for s in req.specs] or identity_specs()
    specs = ex.load_specs(paths, req.window)
    given = (("--faults", req.faults), ("--space", req.space))
    refuse_point_options(design, req.payoffs, tuple(o for o, v in given if v is not None))
    detector = dv.detector_file_of(req.nets)
    if detector is not None:  # docs/detectors.md
        dv.refuse_window_options(req.nets, False, req.inject is not None)
        if req.scene_path is None:
            refuse_points_for_boxes(detector, design)
    if req.scene_path is not None:
        src = ex.scene_file(req)
    else:  # every detection priced up front: the multi-target check reads payoffs directly
        src = ex.perceived(req, specs, rep, False, False)
    where = req.scene_path or str(req.out / "scene.json")
    scene = src.scene.with_tracker(design=design)
    rep.log(f"target: {ex.target_text(scene)}")
    checked = time.monotonic()
    rep.stage(f"checking the {registry.label(design)} design")
    results = check_multi_design(
        scene, where, tuple(specs), (), req.budget.max_states, True, req.budget
    )
    timings = {
        "video, perception and scene": checked - started,
        "models and checks": time.monotonic() - checked,
    }
    meta = {
        **src.meta,
        "target": ex.target_text(scene),
        **replay_meta(scene, req.scene_path, paths, req.window),
    }
    doc = multi_document(design, composed(scene, where).reference_kind(), results, meta, timings)
    from lesmc.experiment.verify_results import perception_facts

    doc["perception"] = perception_facts(src, where)  # as the point designs record it
    _replay(doc, scene, where, specs, src, rep, req.budget)
    rep.stage("writing the report")
    from lesmc.report.multi import write_multi_report

    files = {"scene.json": json_text(scene_to_dict(src.scene))} if src.new else {}
    report = write_multi_report(doc, req.out, ex.frame_reader(src.frames), files)
    return MultiOutcome(results, doc, report)


def replay_meta(
    scene: Scene,
    scene_file: str | None,
    properties: list[Path],
    window: tuple[int, int] | None,
) -> dict[str, Any]:
    """What a ``lesmc-multi-check`` document's ``meta`` records for ``lesmc replay``
    (:func:`replay_document` reads it): the target the check placed on the scene
    (``scene_target``), the property files (``properties``), the window they were moved
    to (``window``; None: as written), the tracker the check ran (``tracker``: the
    scene's block, or ``--tracker FILE``'s, which replaces it) and the scene file the check
    read (``scene``; none for ``scene_file`` None: verify's own perception, whose
    scene.json sits beside the results). ``lesmc verify --design sort|gnn`` and ``lesmc
    check --design sort|gnn --report DIR`` (lesmc/cli/multi_check.py) both record it."""
    meta: dict[str, Any] = {
        "scene_target": target_to_dict(scene.target),  # what lesmc replay places on meta.scene
        "tracker": scene.tracker.to_json(),  # what lesmc replay tracks with (not the file's)
        "properties": [str(p.resolve()) for p in properties],
        "window": None if window is None else list(window),
    }
    if scene_file is not None:
        meta["scene"] = str(Path(scene_file).resolve())
    return meta


def refuse_points_for_boxes(detector: str, design: str) -> None:
    """A heatmap detector file that declares no ``box`` and no ``size`` gives points: a
    design that reads a box on every detection (SORT's IoU) is refused before the video is
    perceived."""
    from lesmc.perception.detector_file import read_detector_file
    from lesmc.tracking.trackers import tracker_class

    spec = read_detector_file(detector)
    points = spec.kind == "heatmap" and spec.box is None and spec.size is None
    if points and getattr(tracker_class(design), "needs_boxes", False):
        raise UsageError(
            f"--design {design} reads a box on every detection, and --detector {detector} "
            "is a heatmap detector file that declares no box, whose detections are points: "
            'declare one (box = [w, h], or size = "wh" for a network with size outputs), use '
            'a box detector file (kind = "boxes") or a point design such as gnn '
            "(docs/detectors.md)"
        )


def _replay(
    doc: dict[str, Any],
    scene: Scene,
    where: str,
    specs: list[SpecFile],
    src: Any,
    rep: Reporter,
    budget: Budget,
) -> None:
    """Replay every violated counterexample of ``doc`` through the real detector and the
    production tracker (lesmc/replay/multi.py); each result records its replay and the
    timings the replay's seconds. Not through a detector file (its replay is the point
    designs'): the counterexamples stay as the model gives them."""
    from lesmc.experiment import detector_verify as dv
    from lesmc.experiment.verify_request import spent
    from lesmc.replay.multi import replay_multi
    from lesmc.replay.multi_cases import multi_cases

    bound = bound_properties(specs, scene)
    todo = multi_cases(doc, scene, bound, where=where)
    if not todo or src.frames is None or (src.nets is None and src.net_files is None):
        return
    if dv.detector_file_of(src.net_files or (None, None, None)) is not None:
        rep.log("a detector file's multi-target counterexamples are not replayed (yet)")
        return
    t0 = time.monotonic()
    key = _replay_key(doc, scene, src)
    hit = None if src.cache is None or key is None else src.cache.get("multi-replay", key)
    if _cached_replays_ok(hit, {str(c.result) for c in todo}):
        assert isinstance(hit, dict)
        rep.log(f"reusing the replay of {len(hit)} counterexamples from the cache")
        replays = {(0, int(j)): obj for j, obj in hit.items()}
    else:
        clean = None if src.run is None else {fd.index: fd for fd in src.run.detections}
        known = None if src.run is None else src.run.registrations
        with rep.bar("replaying", len(src.frames) if clean is None else None) as bar:

            def advance() -> None:  # the clock, as the point designs' replay checks it
                bar.advance()
                spent(budget, "replaying the counterexamples")

            nets = src.networks()
            outcome = replay_multi(
                doc, scene, where, bound, src.frames, nets, None, advance, clean, known
            )
        replays = outcome.replays
        if src.cache is not None and key is not None:
            src.cache.put("multi-replay", key, {str(j): obj for (_, j), obj in replays.items()})
    record_multi_replays(doc, replays)
    doc.setdefault("timings", {})["replay"] = round(time.monotonic() - t0, 3)


def _replay_key(doc: dict[str, Any], scene: Scene, src: Any) -> str | None:
    """The digest of what the replay reads (the results without their timings, the
    scene, the frames, the networks and the code), as the point designs' replay keys
    OUT/cache (lesmc/experiment/verify_replay.py); None: not cacheable."""
    from lesmc.experiment.cache import code_digest, digest, file_digests, net_files

    if src.net_files is None or src.frames is None:
        return None
    return digest(
        {
            "code": code_digest(
                "replay", "perception", "video", "tracking", "scene", "engines", "model"
            ),
            "frames": file_digests(src.frames.paths),
            "nets": file_digests(net_files(src.net_files)),
            "scene": scene_to_dict(scene),
            "results": doc["results"],
        }
    )


def _cached_replays_ok(hit: Any, wanted: set[str]) -> bool:
    """Whether an OUT/cache entry holds a replay object for each result ``wanted`` (their
    indices), and nothing else: a corrupted or hand-edited entry is replayed again."""
    from lesmc.results.load import replay_ok

    return (
        isinstance(hit, dict)
        and set(hit) == wanted
        and all(replay_ok(v, "multi-check") for v in hit.values())
    )


def record_multi_replays(doc: dict[str, Any], replays: dict[tuple[int, int], Any]) -> None:
    """Each replay into its result of the ``lesmc-multi-check`` document ``doc``."""
    for (_, j), obj in sorted(replays.items()):
        doc["results"][j]["replay"] = obj


def replay_document(
    doc: dict[str, Any],
    path: str,
    frames_dir: str | None,
    nets: NetFiles,
    prop: str | None,
    bar: Bar,
) -> tuple[Outcome, str]:
    """``lesmc replay`` of a ``lesmc-multi-check`` document ``doc`` (read from ``path``, as
    ``lesmc verify --design sort|gnn`` or ``lesmc check --design sort|gnn --report`` wrote
    it): its scene (``meta.scene``, else the scene.json beside it) with the target the
    check placed (``meta.scene_target``), its properties (``meta.properties``, moved to
    ``meta.window``),
    the frames (``frames_dir``, else the first of ``meta.video`` and ``perception.frames``
    that is a directory) and the networks; the replays and the frames' directory."""
    from lesmc.replay.multi import perception_settings, replay_multi
    from lesmc.replay.multi_cases import known_property, multi_cases

    known_property(doc, prop)  # bad input is refused before anything heavy is imported
    meta = doc.get("meta") or {}
    scene_path = _scene_of(meta, path)
    seen = doc.get("perception") or {}  # verify --scene S --frames DIR: no meta.video
    named = [v for v in (meta.get("video"), seen.get("frames")) if isinstance(v, str)]
    # meta.video is as verify was given it (relative to its directory; for the default
    # video, a description): the first that is a directory here, else the first named
    here = [v for v in named if Path(v).is_dir()]
    frames_dir = frames_dir or next(iter(here + named), None)
    if frames_dir is None:
        raise UsageError(
            "replay runs the detector on the video: give its frames with --frames DIR (the "
            "results file does not name them)"
        )
    from lesmc.experiment import experiment as ex
    from lesmc.perception.cnn import load_nets
    from lesmc.perception.detector_file import is_detector_file
    from lesmc.video.reader import open_frames

    if nets[1] is not None and is_detector_file(nets[1]):
        raise UsageError(
            f"--detector {nets[1]}: a multi-target design's counterexamples replay through the "
            "window pipeline's networks (--nets, --detector, --locator) only, so far"
        )
    scene = _placed_scene(meta, (scene_path, path), doc["design"])
    window = meta.get("window")
    props = [Path(p) for p in meta.get("properties") or ()] or identity_specs()
    specs = ex.load_specs(props, None if window is None else (int(window[0]), int(window[1])))
    bound = bound_properties(specs, scene)
    multi_cases(
        doc, scene, bound, prop, path, scene_path
    )  # bad input is refused before the video is read
    fe, _ = perception_settings(doc)  # the front end the replay runs: its frames before
    frames = open_frames(frames_dir, fe.history + 1)
    bar.update(total=len(frames))
    outcome = replay_multi(
        doc, scene, scene_path, bound, frames, load_nets(*nets), prop, bar.advance, path=path
    )
    return outcome, frames_dir


def _placed_scene(meta: dict[str, Any], paths: tuple[str, str], design: str) -> Scene:
    """The scene file ``paths[0]`` with the target the check placed on it
    (``meta.scene_target``, as ``verify --scene S --target X,Y@K`` recorded it; else the
    file's own target), the tracker the check ran (``meta.tracker``: ``--tracker FILE``'s
    when given; else the file's own block) and the results' ``design``; ``paths[1]``:
    the results file, which a bad ``meta.tracker`` is an error of."""
    from lesmc.common.errors import InputError
    from lesmc.common.files import read_json
    from lesmc.tracking.targets import footage_or_scene

    scene_path, path = paths
    data = read_json(Path(scene_path), InputError)
    placed = meta.get("scene_target")
    if isinstance(placed, dict) and isinstance(data, dict):
        data = {**data, "target": placed}
    ran = meta.get("tracker")
    tracker = None if ran is None else tracker_from_dict(ran, f"{path}: meta.tracker")
    scene = footage_or_scene(data, scene_path, None, design, tracker)
    if not isinstance(scene, Scene):
        raise UsageError(
            f"{scene_path} has no target and the results record none (meta.scene_target): "
            "make them again with this lesmc's verify to replay them"
        )
    return scene


def _scene_of(meta: dict[str, Any], path: str) -> str:
    """The scene the results were made from: ``meta.scene``, else scene.json beside them."""
    named = meta.get("scene")
    for p in (Path(named) if isinstance(named, str) else None, Path(path).parent / "scene.json"):
        if p is not None and p.is_file():
            return str(p)
    why = (
        f"the scene the results were made from is not found (meta.scene {named!r}, nor "
        "scene.json beside the results): the replay reads its detections"
    )
    if not Path(path).is_file():
        raise UsageError(f"{path}: {why}")
    raise error_at_items(path, read_text(path), [("meta.scene", why)])


def multi_rows(
    doc: dict[str, Any], outcome: Outcome, prop: str | None
) -> tuple[list[dict[str, Any]], set[str]]:
    """One ``lesmc replay`` row per replayed counterexample (as lesmc/replay/run.py's
    ``verdict_rows``: confirmed is violated, diverged unknown) and every verdict after it."""
    rows = []
    for (_, j), obj in sorted(outcome.replays.items()):
        verdict = "violated" if obj["status"] == "confirmed" else "unknown"
        rows.append(
            {
                "design": doc["design"],
                "property": doc["results"][j]["property"],
                "verdict_model": "violated",
                "verdict": verdict,
                "replay": obj,
            }
        )
    done = {j for _, j in outcome.replays}
    others = {
        r["verdict"]
        for j, r in enumerate(doc["results"])
        if j not in done and prop in (None, r["property"])
    }
    return rows, {r["verdict"] for r in rows} | others
