"""``lesmc verify``'s results document: the runs, the truth and the monitor's false alarms
on it (lesmc/experiment/false_alarms.py), what perception did, the replay's findings
(lesmc/experiment/verify_replay.py); and ``--space``'s design search on the video.
"""

from __future__ import annotations

import time
from pathlib import Path
from typing import Any

from lesmc.common.progress import Reporter
from lesmc.designs import registry
from lesmc.experiment.cache import code_digest, digest, file_digests
from lesmc.experiment.default_video import DEFAULT_VIDEO
from lesmc.experiment.false_alarms import false_alarm_report, truth_track
from lesmc.experiment.verify_replay import replay_counterexamples
from lesmc.experiment.verify_request import Request, Source
from lesmc.language.properties import SpecFile
from lesmc.perception.quality import TruthFrame
from lesmc.results.document import provenance, results_document
from lesmc.results.record import Results
from lesmc.scene import Scene, scene_to_dict


def document(
    req: Request,
    src: Source,
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
    replay_counterexamples(doc, results, src, timings, rep, req.budget)
    doc["timings"] = {k: round(float(v), 3) for k, v in timings.items()}
    return doc


def design_search(
    req: Request, src: Source, specs: list[SpecFile], rep: Reporter
) -> tuple[dict[str, Any], float]:
    """``--space``: lesmc tune's search on this video's scene (lesmc/experiment/tune.py),
    while its payoffs are still priced on demand; and the seconds it took."""
    from lesmc.experiment import tune

    assert req.space is not None and src.frames is not None and src.truth is not None
    t0 = time.monotonic()
    tfs = truth_frames(src, src.scene)
    size = (src.frames.width, src.frames.height)
    where = req.scene_path or str(req.out / "scene.json")

    def told(i: int, g: Any) -> None:
        rep.stage(f"searching designs: {g.designs[0].label().rsplit(' + ', 1)[0]} ({i + 1})")

    out = tune.design_search(
        src.scene, specs, tfs, size, req.space, where, req.budget.max_states, told
    )
    return out, time.monotonic() - t0


def _truth_facts(
    src: Source, results: Results, timings: dict[str, float]
) -> tuple[Any, dict[str, Any]]:
    """With the video's truth: the target's true track and the monitor's false alarms on
    every truth track (lesmc/experiment/false_alarms.py)."""
    if src.frames is None or src.truth is None:
        return None, {}

    scene = src.scene.payoff_free()  # the monitor reads only the unattacked states
    tfs = truth_frames(src, scene)
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


def truth_frames(src: Source, scene: Scene) -> list[TruthFrame]:
    """The truth of the frames from the scene's target frame on, up to the first frame
    the truth file lacks."""
    assert src.frames is not None and src.truth is not None
    tfs = [src.truth.frames.get(p.name) for p in src.frames.paths[scene.target.step :]]
    return [t for t in tfs[: next((i for i, t in enumerate(tfs) if t is None), len(tfs))] if t]


def perception_facts(src: Source, where: str) -> dict[str, Any]:
    """How the scene's detections were made, for the report and the replay (the results'
    ``perception``; a multi-target document's too: lesmc/experiment/multi_verify.py): the
    scene's part (:func:`~lesmc.perception.attack_settings.scene_perception`, which ``lesmc
    check --report`` records too: the attack's settings, the front end's ``history`` and
    ``delta_bc`` as the scene's ``meta.frontend`` records them; ``lesmc perceive -o`` and
    verify's own perception write them; a scene that records none, older or made through
    a detector file, has none, and the replay then says it uses the defaults), the
    networks and the frames. ``where``: the scene file, for a recorded setting out of
    range."""
    from lesmc.perception.attack_settings import scene_perception

    meta = dict(src.scene.meta)
    out = scene_perception(meta, where)
    if src.nets is not None:
        out["nets"] = str(src.nets.settings.trained_on)
    elif isinstance(meta.get("detector"), str) and meta["detector"]:
        out["nets"] = meta["detector"]
    if src.frames is not None and src.frames.paths:
        out["frames"] = str(src.frames.paths[0].parent.resolve())
    return out


def _perception_facts(req: Request, src: Source, results: Results) -> dict[str, Any]:
    """:func:`perception_facts` and what the point designs' check adds: the payoffs asked,
    the certification and pricing this run did, the detector file and its detections."""
    out = perception_facts(src, req.scene_path or str(req.out / "scene.json"))
    out["payoffs"] = req.payoffs
    if results.certified is not None:  # this run's certification (a --scene keeps its own)
        out["certified"] = results.certified
    if src.pricing is not None:  # this run priced on demand (lesmc/experiment/pricing.py)
        out["priced"] = src.scene.meta["priced"]
    if isinstance(src.scene.meta.get("detector_file"), dict):  # docs/detectors.md
        out["detector_file"] = src.scene.meta["detector_file"]
    if src.detections is not None:
        out["detections"] = src.detections
    return out
