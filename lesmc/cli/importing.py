"""``lesmc import``: scenes from other tools' files (MOTChallenge detections)."""

from __future__ import annotations

import math
from typing import TYPE_CHECKING, Any

import click

from lesmc.cli.documents import (
    emit,
    file_facts,
    print_warnings,
    run_provenance,
    say,
    unattacked_warnings,
)
from lesmc.cli.options import (
    distinct_files,
    frames_option,
    refuse_output_among_frames,
    tracker_option,
)
from lesmc.common.errors import UsageError, escape_control
from lesmc.language import actions

if TYPE_CHECKING:
    from lesmc.scene import Footage, Scene
    from lesmc.scene.mot import Inject, Payoffs


def _inject_takers() -> str:
    """The trackers that take ``inject``, as the registry declares them
    (lesmc/language/actions.py; docs/language.md, "Attack actions")."""
    takers = actions.get("inject").trackers
    return "every design" if takers is None else ", ".join(sorted(takers))


@click.group("import")
def import_group() -> None:
    """Make a scene from another tool's files."""


@import_group.command("mot")
@click.argument("det", type=click.Path(dir_okay=False))
@click.option(
    "-o", "--output", required=True, type=click.Path(dir_okay=False), help="The scene to write."
)
@click.option(
    "--gt",
    "gt_path",
    type=click.Path(dir_okay=False),
    default=None,
    help="A gt.txt: with --track, the target starts at that track's first box, with the "
    "velocity to its next box; the file's tracks within the detections' frames become the "
    "scene's truth (for dist.nearest).",
)
@click.option("--track", "track_id", type=int, default=None, help="The gt.txt track to follow.")
@click.option(
    "--point",
    type=click.Choice(["center", "bottom"]),
    default="center",
    show_default=True,
    help="Where a box puts its detection: its centre, or its bottom centre (the ground point).",
)
@click.option(
    "--payoff",
    "payoff_constant",
    type=float,
    default=None,
    help="Every detection's payoff [default: 1, so the optimum counts the detections an "
    "attacker must hide].",
)
@click.option(
    "--payoff-column",
    type=click.IntRange(min=7, max=10),
    default=None,
    help="Read each detection's payoff from this column (1-based; 7 is conf; inf: unattackable).",
)
@click.option(
    "--inject-column",
    type=click.IntRange(min=7, max=10),
    default=None,
    help="With --threshold: the lines whose conf (column 7) is below the threshold become "
    "injection candidates (not detections), priced by this column (1-based; a number >= 0): "
    f"what `allow inject` in a spec lets the attacker add ({_inject_takers()}).",
)
@click.option(
    "--threshold",
    "inject_threshold",
    type=float,
    default=None,
    help="With --inject-column: the detector's score threshold; lines of lower conf are "
    "injection candidates.",
)
@click.option(
    "--fps",
    type=float,
    default=30.0,
    show_default=True,
    help="Frames per second of the sequence (seqinfo.ini's frameRate): dt = 1/fps.",
)
@tracker_option
@frames_option(
    "With --detector: the sequence's frames (MOT frame f is the directory's frame f - 1, "
    "natural sort order)."
)
@click.option(
    "--detector",
    "detector_file",
    type=click.Path(dir_okay=False),
    default=None,
    help="A detector file (FILE.toml or .json, docs/detectors.md) run on --frames: each box "
    "takes the payoff of the detection it matches (IoU >= 0.5 for a box detector; for a "
    "heatmap, the nearest peak within nms_radius cells); an unmatched box is unpriced, "
    "with a warning naming its line.",
)
@click.option(
    "--json",
    "as_json",
    is_flag=True,
    help="Print what was written as JSON on stdout (format lesmc-import, schema "
    "lesmc/schemas/import.json).",
)
def mot_cmd(
    det: str,
    output: str,
    gt_path: str | None,
    track_id: int | None,
    point: str,
    payoff_constant: float | None,
    payoff_column: int | None,
    inject_column: int | None,
    inject_threshold: float | None,
    fps: float,
    tracker_file: str | None,
    frames_dir: str | None,
    detector_file: str | None,
    as_json: bool,
) -> None:
    """Make a scene from a MOTChallenge DET file (det.txt or gt.txt layout).

    \b
    One detection per line (frame,id,bb_left,bb_top,bb_width,bb_height,...), at the box's
    centre, keeping its width and height (or --point bottom: the bottom centre, no box).
    Steps are the file's frame numbers; a frame without lines has no detections. Without
    --gt/--track the scene has no target: give --target X,Y@STEP to track, build, check
    or verify. With a target, warns when its unattacked track does not follow it (a
    single-target design's; a multi-target design such as sort tracks every object).
    With --frames and --detector FILE.toml, each box is priced by the user's detector
    (docs/detectors.md, "MOT detections priced").
    Exit status: 0 written, 2 bad input, 4 internal error, 130 interrupted.
    """
    from lesmc.scene import Scene, load_tracker, save_scene
    from lesmc.scene.io import check_fits
    from lesmc.scene.mot import Point, import_mot

    if (gt_path is None) != (track_id is None):
        raise UsageError("--gt and --track go together: the target is a track of the gt file")
    distinct_files(
        {"DET": det, "--gt": gt_path, "--tracker": tracker_file}, {"-o/--output": output}
    )
    refuse_output_among_frames(frames_dir, output, "-o/--output")
    from lesmc.scene.io import MAX_DT

    if not (math.isfinite(fps) and 0 < fps <= 1e6 and 1.0 / fps <= MAX_DT):
        shown = f"[1/{MAX_DT:g}, 1e6] (dt = 1/fps at most {MAX_DT:g} s)"
        raise UsageError(f"--fps must be a number in {shown}, got {fps:g}")
    payoffs = _payoffs(payoff_constant, payoff_column)
    inject = _inject(inject_column, inject_threshold)
    _refuse_with_detector(frames_dir, detector_file, payoff_constant, payoff_column, inject)
    tracker = load_tracker(tracker_file) if tracker_file else None
    at: Point = "bottom" if point == "bottom" else "center"
    scene = import_mot(det, 1.0 / fps, at, payoffs, gt_path, track_id, tracker, inject)
    if tracker is not None and isinstance(scene, Scene):  # refused here, where it is named
        check_fits(tracker, scene.target, tracker_file or "--tracker", "model.state")
    scene, unmatched = _priced(scene, det, frames_dir, detector_file)
    save_scene(scene, output)
    doc = _document(scene, det, output, at, payoffs, f"{gt_path} track {track_id}")
    doc["warnings"] = unmatched + doc["warnings"]
    _summary(doc, output, track_id, as_json)
    print_warnings(doc["warnings"], err=as_json)
    if as_json:
        emit(doc)


def _summary(doc: dict[str, Any], output: str, track_id: int | None, as_json: bool) -> None:
    """The line saying what was written (on stderr with --json)."""
    target = doc["target"]
    where = (
        "no target (give --target X,Y@STEP to track it)"
        if target is None
        else f"target: track {track_id} from frame {target['step']}, "
        f"truth: {doc['truth_tracks']} gt tracks"
    )
    frames = f"frames {doc['first_frame']}..{doc['last_frame']}" + (
        f" (and {doc['candidates']} injection candidates)" if "candidates" in doc else ""
    )
    say(
        f"wrote {escape_control(output)}: {doc['detections']} detections in {frames}, {where}",
        as_json,
    )


def _refuse_with_detector(
    frames_dir: str | None,
    detector_file: str | None,
    constant: float | None,
    column: int | None,
    inject: Inject | None,
) -> None:
    """--detector needs --frames (and a detector file); it replaces the other payoffs."""
    if (frames_dir is None) != (detector_file is None):
        raise UsageError(
            "--frames and --detector go together: the detector file prices the boxes on the frames"
        )
    if detector_file is None:
        return
    from lesmc.perception.detector_file import is_detector_file

    if not is_detector_file(detector_file):
        raise UsageError(
            f"--detector {detector_file}: give a detector file (FILE.toml or FILE.json, "
            "docs/detectors.md)"
        )
    given = [
        name
        for name, v in (
            ("--payoff", constant),
            ("--payoff-column", column),
            ("--inject-column", inject),
        )
        if v is not None
    ]
    if given:
        raise UsageError(f"{given[0]} prices the boxes too: give it or --detector, not both")


def _priced(
    scene: Footage | Scene, det: str, frames_dir: str | None, detector_file: str | None
) -> tuple[Footage | Scene, list[str]]:
    """``scene`` with each box priced by the detector file (lesmc/experiment/mot_priced.py),
    and one warning per unmatched box; unchanged without --detector."""
    if frames_dir is None or detector_file is None:
        return scene, []
    from lesmc.experiment.mot_priced import price_mot, refuse_outside
    from lesmc.scene.mot import read_boxes

    boxes = read_boxes(det, True)
    refuse_outside(boxes, det)
    priced = price_mot(scene, boxes, det, frames_dir, detector_file)
    return priced.footage, priced.warnings


def _inject(column: int | None, threshold: float | None) -> Inject | None:
    """``--inject-column`` and ``--threshold``, both or neither."""
    from lesmc.scene.mot import Inject

    if (column is None) != (threshold is None):
        raise UsageError(
            "--inject-column and --threshold go together: lines of conf below the "
            "threshold are candidates, priced by the column"
        )
    if column is None or threshold is None:
        return None
    if not math.isfinite(threshold):
        raise UsageError(f"--threshold must be a finite number, got {threshold:g}")
    return Inject(column, threshold)


def _payoffs(constant: float | None, column: int | None) -> Payoffs:
    """``--payoff`` or ``--payoff-column`` (default: every detection costs 1)."""
    from lesmc.common.numbers import MAX_PAYOFF
    from lesmc.scene.mot import Payoffs

    if constant is not None and column is not None:
        raise UsageError("give --payoff or --payoff-column, not both")
    if constant is not None and not (0 <= constant <= MAX_PAYOFF):
        raise UsageError(f"--payoff must be a number in [0, {MAX_PAYOFF:g}], got {constant:g}")
    return Payoffs(1.0 if constant is None else constant, column)


def _document(
    scene: Footage | Scene, det: str, output: str, point: str, payoffs: Payoffs, origin: str
) -> dict[str, Any]:
    """The ``lesmc-import`` document (lesmc/schemas/import.json) of the scene written."""
    from lesmc.scene import Scene

    target = None
    if isinstance(scene, Scene):
        t = scene.target
        target = {
            "step": t.step,
            "start": list(t.start),
            "velocity": list(t.velocity),
            "from": origin,
        }
    priced = f"column {payoffs.column}" if payoffs.column else f"constant {payoffs.constant:g}"
    return {
        "format": "lesmc-import",
        "version": 1,
        "provenance": run_provenance(),
        "source": "mot",
        "input": det,
        "scene": file_facts(output),
        "frames": len(scene.frames),
        "detections": sum(len(f.detections) for f in scene.frames),
        "first_frame": scene.frames[0].step,
        "last_frame": scene.last_step,
        "point": point,
        "payoffs": priced,
        "target": target,
        "truth_tracks": len(scene.truth),
        "warnings": unattacked_warnings(scene) if isinstance(scene, Scene) else [],
        **(
            {"candidates": sum(len(f.candidates) for f in scene.frames)}
            if "candidates" in scene.meta
            else {}
        ),
    }
