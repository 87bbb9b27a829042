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
from lesmc.common.files import json_text
from lesmc.common.progress import Reporter
from lesmc.designs import registry
from lesmc.pipeline.multi import MultiCheckResult, check_multi_design, multi_document
from lesmc.scene import scene_to_dict

if TYPE_CHECKING:
    from lesmc.experiment.experiment import Request


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


def verify_multi(req: Request, rep: Reporter) -> MultiOutcome:
    """Run the experiment of ``req`` (one multi-target design) and write its report."""
    from lesmc.experiment import detector_verify as dv
    from lesmc.experiment import experiment as ex
    from lesmc.unfold.multi import composed

    started = time.monotonic()
    (design,) = req.designs
    paths = [Path(s) for s in req.specs] or identity_specs()
    specs = ex.load_specs(paths, req.window)
    if req.faults is not None or req.space is not None or req.payoffs != "attack":
        raise UsageError(
            f"--design {design}: --faults, --space and --payoffs certified|interval apply to "
            "the point designs; a multi-target design is checked on attack payoffs"
        )
    detector = dv.detector_file_of(req.nets)
    if detector is not None:  # docs/detectors.md
        dv.refuse_window_options(req.nets, False, req.inject is not None)
        if req.scene_path is None:
            _refuse_points_for_boxes(detector, design)
    if req.scene_path is not None:
        src = ex._scene_file(req)
    else:  # every detection priced up front: the multi-target check reads payoffs directly
        src = ex._perceived(req, specs, rep, False, False)
    where = req.scene_path or str(req.out / "scene.json")
    scene = src.scene.with_tracker(design=design)
    rep.log(f"target: {ex._target_text(scene)}")
    checked = time.monotonic()
    rep.stage(f"checking the {registry.label(design)} design")
    results = check_multi_design(scene, where, tuple(specs), (), req.budget.max_states, draw=True)
    timings = {
        "video, perception and scene": checked - started,
        "models and checks": time.monotonic() - checked,
    }
    doc = multi_document(
        design,
        composed(scene, where).reference_kind(),
        results,
        {**src.meta, "target": ex._target_text(scene), "properties": [str(p) for p in paths]},
        timings,
    )
    rep.stage("writing the report")
    from lesmc.report.multi import write_multi_report

    files = {"scene.json": json_text(scene_to_dict(src.scene))} if src.new else {}
    report = write_multi_report(doc, req.out, ex._frame_reader(src.frames), files)
    return MultiOutcome(results, doc, report)


def _refuse_points_for_boxes(detector: str, design: str) -> None:
    """A heatmap detector file that declares no ``box`` gives points: a design that reads a
    box on every detection (SORT's IoU) is refused before the video is perceived."""
    from lesmc.perception.detector_file import read_detector_file
    from lesmc.tracking.trackers import tracker_class

    spec = read_detector_file(detector)
    points = spec.kind == "heatmap" and spec.box is None
    if points and getattr(tracker_class(design), "needs_boxes", False):
        raise UsageError(
            f"--design {design} reads a box on every detection, and --detector {detector} "
            "is a heatmap detector file that declares no box, whose detections are points: "
            'declare one (box = [w, h]), use a box detector file (kind = "boxes") or a '
            "point design such as gnn (docs/detectors.md)"
        )
