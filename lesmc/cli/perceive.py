"""``lesmc perceive``: frames -> detections (-> payoffs -> scene), with quality against truth."""

from __future__ import annotations

import math
import time
from pathlib import Path
from typing import TYPE_CHECKING, Any

import click

from lesmc.cli.documents import emit, file_facts, refuse_given, run_provenance, say
from lesmc.cli.options import (
    FiniteRange,
    distinct_files,
    network_options,
    refuse_output_among_frames,
    tracker_option,
)
from lesmc.common.errors import escape_control
from lesmc.experiment.perceive import (
    Perceived,
    PerceiveRequest,
    open_inputs,
    perceive_frames,
    refuse_mismatched,
)
from lesmc.video import FPS

if TYPE_CHECKING:
    from lesmc.perception.cnn import Nets
    from lesmc.perception.run import PerceiveRun
    from lesmc.scene import Footage, Scene


@click.command("perceive")
@click.argument("frames_dir", type=click.Path(file_okay=False))
@click.option(
    "-o",
    "--output",
    type=click.Path(dir_okay=False),
    default=None,
    help="Write the scene (detections, payoffs, homographies, and the target if --target "
    "is given) here.",
)
@click.option(
    "--target",
    "target_text",
    default=None,
    metavar="X,Y[@STEP]",
    help="The tracked vehicle: its position in frame STEP [default: first detected frame].",
)
@click.option(
    "--truth",
    type=click.Path(dir_okay=False),
    default=None,
    help="truth.json of the video: print precision, recall, F1 and error.",
)
@click.option(
    "--nets",
    "nets_dir",
    type=click.Path(file_okay=False),
    default=None,
    help="Trained networks (lesmc train --out) [default: the shipped ones].",
)
@network_options
@tracker_option
@click.option("--no-cnn", is_flag=True, help="Front end only: the candidates Q_bc.")
@click.option(
    "--attack",
    type=click.Choice(["deepfool", "pgd"]),
    default="deepfool",
    show_default=True,
    help="How payoffs are computed (docs/cnn.md).",
)
@click.option(
    "--payoff-norm",
    type=click.Choice(["l2", "per-pixel"]),
    default="l2",
    show_default=True,
    help="l2: ||delta||_2 on [0,1] pixels; per-pixel: divided by 441 (the paper's code).",
)
@click.option("--overshoot", type=FiniteRange(min=0.0, max=1.0), default=0.02, show_default=True)
@click.option("--max-iter", type=click.IntRange(min=1, max=10000), default=50, show_default=True)
@click.option(
    "--certify",
    is_flag=True,
    help="Also certify a lower bound on each payoff (payoff_lower; docs/cnn.md; with a "
    "detector file, on each peak cell's crop: docs/detectors.md). Slow: about 0.15-0.25 s "
    "per detection on 2 idle cores (docs/performance.md).",
)
@click.option(
    "--inject-within",
    type=FiniteRange(min=0.0),
    default=None,
    metavar="PX",
    help="With -o: injection candidates (scene format 3; issue 61): the candidates N_dr "
    "rejects within PX of one of the frame's detections (at most --inject-cap a frame, "
    "nearest first), each priced by the attack towards 'vehicle' (what `allow hide, inject` in a "
    'spec lets the attacker add; docs/cnn.md, "Injection candidates"). With a heatmap '
    "detector file: its local maxima below the threshold within PX of a detection, ids "
    "FRAME:cK, each priced by the smallest crop perturbation found that makes it a "
    'detection (docs/detectors.md, "Injection candidates").',
)
@click.option(
    "--inject-cap",
    type=click.IntRange(min=1),
    default=32,
    show_default=True,
    metavar="N",
    help="With --inject-within: at most N injection candidates a frame, nearest a "
    "detection first (each costs an attack: docs/cnn.md).",
)
@click.option(
    "--save-attacks",
    type=click.Path(file_okay=False),
    default=None,
    metavar="DIR",
    help="With a detector file and -o: write each hiding perturbation to DIR/FRAME_K.npy "
    "(with --inject-within, each injecting one to DIR/FRAME_cK.npy; docs/detectors.md).",
)
@click.option(
    "--history",
    type=click.IntRange(min=3, max=16),
    default=4,
    show_default=True,
    help="L, the number of previous frames in the background median (at least m=3).",
)
@click.option(
    "--delta-bc",
    type=click.IntRange(min=1, max=255),
    default=12,
    show_default=True,
    help="Background subtraction threshold (grey levels).",
)
@click.option(
    "--dt",
    type=FiniteRange(min=0.0, min_open=True),
    default=None,
    help=f"Seconds between frames [default: from --truth, else {1 / FPS:g} (1.25 Hz)].",
)
@click.option(
    "--radius",
    type=FiniteRange(min=0.1),
    default=4.0,
    show_default=True,
    help="Match distance for --truth, pixels.",
)
@click.option(
    "--min-speed",
    type=FiniteRange(min=0.0),
    default=1.5,
    show_default=True,
    help="Slower vehicles (m/s) are don't care for --truth.",
)
@click.option(
    "--json",
    "as_json",
    is_flag=True,
    help="Print the per-frame figures (and the scene written) as JSON on stdout (format "
    "lesmc-perceive, schema lesmc/schemas/perceive.json).",
)
def perceive_cmd(
    frames_dir: str,
    output: str | None,
    target_text: str | None,
    truth: str | None,
    nets_dir: str | None,
    detector_file: str | None,
    locator_file: str | None,
    tracker_file: str | None,
    no_cnn: bool,
    attack: str,
    payoff_norm: str,
    overshoot: float,
    max_iter: int,
    certify: bool,
    inject_within: float | None,
    inject_cap: int,
    save_attacks: str | None,
    history: int,
    delta_bc: int,
    dt: float | None,
    radius: float,
    min_speed: float,
    as_json: bool,
) -> None:
    """Run the vehicle detector of the paper's Figure 4 on FRAMES_DIR (PNG/TIFF/JPEG).

    Registration, median background and subtraction give candidates Q_bc; N_dr
    keeps the vehicles, N_lp splits crowded blobs. With -o, each
    detection's payoff (the smallest perturbation that hides it from N_dr) is
    computed and a scene is written for `lesmc build` / `lesmc check`. Without
    --target the scene has no target: give one to check, build or verify with
    --target X,Y@STEP (lesmc campaign finds them itself). Options that only
    shape the scene (--attack, --payoff-norm, --overshoot, --max-iter, --dt,
    --certify, --target) need -o; --radius and --min-speed need --truth.
    With --detector FILE.toml (or .json), a detector file (docs/detectors.md),
    the user's whole-frame heatmap network runs on every frame instead, without
    the front end; with -o, each payoff is the smallest perturbation found of
    the detection's receptive-field crop that hides it (--save-attacks DIR), and
    --certify bounds it from below on the peak cell's crop.
    Exit status: 0 done, 2 bad input, 4 internal error, 130 interrupted.
    """
    started = time.monotonic()
    req = PerceiveRequest(
        frames_dir, (nets_dir, detector_file, locator_file), not no_cnn, output is not None,
        target_text, truth, tracker_file, "pgd" if attack == "pgd" else "deepfool",
        "per-pixel" if payoff_norm == "per-pixel" else "l2", overshoot, max_iter,
        certify, history, delta_bc, dt, radius, min_speed, inject_within, inject_cap,
    )  # fmt: skip
    refuse_mismatched(req)
    _refuse_ignored(output, truth)
    if inject_within is None:
        refuse_given(("inject_cap",), "limits the candidates of --inject-within: give it too")
    from lesmc.perception.detector_file import is_detector_file

    if detector_file is not None and is_detector_file(detector_file):
        _with_detector_file(req, detector_file, output, save_attacks)
        return
    refuse_given(("save_attacks",), "applies to a detector file's payoffs (docs/detectors.md)")
    _with_windows(req, output, as_json, started)


def _with_windows(req: PerceiveRequest, output: str | None, as_json: bool, started: float) -> None:
    """The paper's pipeline (front end, N_dr, N_lp) on the frames; the scene with -o."""
    from lesmc.common.progress import progress_bar  # rich: imported when a verb runs

    inputs = open_inputs(req)
    if output is not None:
        named: dict[str, str | None] = {p.name: str(p) for p in inputs.frames.paths}
        named |= {"--truth": req.truth, "--tracker": req.tracker, "--detector": req.nets[1]}
        distinct_files(named | {"--locator": req.nets[2]}, {"-o/--output": output})
    with progress_bar("perceive", "perceiving", len(inputs.frames)) as bar:
        got = perceive_frames(req, inputs, bar.advance)
    _log_networks(got)
    written = (
        None
        if got.scene is None or output is None
        else _write_scene(got.scene, got.run.unattackable, got.target_note, output, as_json)
    )
    with_truth = req.truth is not None
    if as_json:
        emit(_document(req.frames_dir, got.nets, got.run, written, with_truth, started))
        return
    _print(got.run, with_truth, got.nets is not None)


#: Options of the window pipeline (front end, N_dr and N_lp) that a detector file replaces.
_WINDOW_ONLY = (
    "nets_dir", "locator_file", "no_cnn", "history", "delta_bc", "truth",
    "payoff_norm", "as_json",
)  # fmt: skip


def _with_detector_file(
    req: PerceiveRequest, path: str, output: str | None, save_attacks: str | None
) -> None:
    """``--detector FILE.toml|.json``: the user's whole-frame detector on every frame
    (docs/detectors.md); with -o, each detection's payoff and the scene."""
    from lesmc.common.progress import deferred_bar
    from lesmc.experiment.perceive import perceive_with_file

    refuse_given(_WINDOW_ONLY, "does not apply to a detector file (docs/detectors.md)")
    if output is None:
        refuse_given(("save_attacks",), "saves the attacks that price a scene: it needs -o")
    else:
        distinct_files({"--detector": path, "--tracker": req.tracker}, {"-o/--output": output})
        refuse_output_among_frames(req.frames_dir, output, "-o/--output")
    with deferred_bar("perceive", "perceiving") as bar:  # started once the file is read

        def start(n: int) -> Any:
            bar.update(total=n)
            return bar.advance

        got = perceive_with_file(req, path, start, save_attacks)
    click.echo(
        f"lesmc perceive: detector: {escape_control(got.detector.spec.describe())}", err=True
    )
    if got.scene is not None and output is not None:
        pays = [float(p) for d in got.detections if d.payoffs is not None for p in d.payoffs]
        hard = sum(1 for p in pays if math.isinf(p))
        _write_scene(got.scene, hard, got.target_note, output, False)
    n = sum(len(d.positions) for d in got.detections)
    say(f"{len(got.detections)} frames, {n} detections", False)


def _log_networks(got: Perceived) -> None:
    """On stderr: which networks ran (the scene's ``meta.detector`` records the same), and
    a warning when the detector accepted none of the front end's candidates."""
    if got.nets is None:
        return
    from lesmc.perception.cnn import describe_nets
    from lesmc.perception.run import nothing_detected

    click.echo(f"lesmc perceive: networks: {escape_control(describe_nets(got.nets))}", err=True)
    warning = nothing_detected(got.run)
    if warning is not None:
        click.echo(f"lesmc perceive: warning: {warning}", err=True)


def _refuse_ignored(output: str | None, truth: str | None) -> None:
    """Options that only apply with -o or --truth are errors without them."""
    if output is None:
        refuse_given(
            ("attack", "payoff_norm", "overshoot", "max_iter", "dt"),
            "shapes the scene's payoffs or time step: it needs -o/--output",
        )
        refuse_given(("tracker_file",), "is the tracker of the scene written: it needs -o/--output")
    if truth is None:
        refuse_given(("radius", "min_speed"), "applies to the comparison with --truth")


def _write_scene(
    scene: Scene | Footage, unattackable: int, target_note: str, output: str, as_json: bool
) -> dict[str, Any]:
    """``scene`` written to ``output``; its facts for --json."""
    from lesmc.scene import Scene, save_scene

    save_scene(scene, output)
    n = sum(len(f.detections) for f in scene.frames)
    say(
        f"wrote {escape_control(output)}: {len(scene.frames)} frames (steps "
        f"{scene.frames[0].step}..{scene.last_step}), {n} detections, "
        f"{_priced(scene, unattackable)}{_candidates(scene)}; {target_note}",
        as_json,
    )
    target = None
    if isinstance(scene, Scene):
        start = scene.target.start
        target = {"step": scene.target.step, "x": float(start[0]), "y": float(start[1])}
    return file_facts(output) | {
        "steps": [scene.frames[0].step, scene.last_step],
        "detections": n,
        "unattackable": unattackable,
        "target": target,
    }


def _candidates(scene: Scene | Footage) -> str:
    """How many injection candidates the scene has (none: nothing said, unless
    ``--inject-within`` asked for them: then that it found none)."""
    n = sum(len(f.candidates) for f in scene.frames)
    if n:
        return f", {n} injection candidates"
    made = scene.meta.get("candidates")
    if isinstance(made, dict):
        return f", no injection candidates (none within {made.get('within_px')} px of a detection)"
    return ""


def _priced(scene: Scene | Footage, unattackable: int) -> str:
    """How many detections are unattackable (or unpriced, and then nothing more)."""
    if scene.unpriced:
        return f"{scene.unpriced} unpriced"
    return f"{unattackable} unattackable{_unattackable_note(scene)}"


def _unattackable_note(scene: Any) -> str:
    """What "unattackable" means for this scene: the attack found no perturbation hiding
    the detection, which proves nothing; with --certify, the range of those detections'
    certified lower bounds (a bound near 0: the certificate proves nothing either)."""
    lows = [
        d.payoff_lower
        for f in scene.frames
        for d in f.detections
        if d.priced and not d.attackable and d.payoff_lower is not None
    ]
    if not any(d.priced and not d.attackable for f in scene.frames for d in f.detections):
        return ""
    note = " (the attack found no perturbation that hides them, which is no proof that none"
    finite = [v for v in lows if math.isfinite(v)]
    if not finite:
        return note + " exists)"
    return (
        f"{note} exists; {len(finite)} have certified lower bounds, {min(finite):.3g} to "
        f"{max(finite):.3g}: no perturbation of a smaller norm hides them, a bound near 0 "
        "proves nothing; docs/scene-format.md)"
    )


def _document(
    frames_dir: str,
    nets: Nets | None,
    run: PerceiveRun,
    written: dict[str, Any] | None,
    with_truth: bool,
    started: float,
) -> dict[str, Any]:
    """``lesmc perceive --json`` (format lesmc-perceive, schemas/perceive.json)."""
    doc: dict[str, Any] = {
        "format": "lesmc-perceive",
        "version": 1,
        "provenance": run_provenance(),
        "frames_dir": frames_dir,
        "detector": None if nets is None else nets.settings.trained_on,
        "frames": run.rows,
        "scene": written,
        "seconds": time.monotonic() - started,
    }
    if with_truth:
        doc["overall"] = {"frontend": run.frontend_total.to_json()}
        if nets is not None:
            doc["overall"]["detector"] = run.detector_total.to_json()
    return doc


def _print(run: PerceiveRun, with_truth: bool, with_cnn: bool) -> None:
    from rich.table import Table

    from lesmc.report.text import make_console

    console = make_console()
    table = Table(title="detector" if with_cnn else "front end (candidates Q_bc)")
    cols = ["frame", "candidates"] + (["accepted", "detections"] if with_cnn else [])
    quality = ["tp", "fp", "fn", "precision", "recall", "f1", "error_px"]
    stage = "detector" if with_cnn else "frontend"
    for c in cols + (quality if with_truth else []):
        table.add_column(_HEAD.get(c, c), justify="left" if c == "frame" else "right", no_wrap=True)
    for r in run.rows:
        q = [_cell(r[stage][c]) for c in quality] if with_truth else []
        table.add_row(Path(r["frame"]).stem, *(_cell(r[c]) for c in cols[1:]), *q)
    if with_truth:
        table.add_section()
        blanks = [""] * (len(cols) - 1)
        if with_cnn:
            table.add_row(
                "front end", *blanks, *(_cell(run.frontend_total.to_json()[c]) for c in quality)
            )
        total = run.detector_total if with_cnn else run.frontend_total
        table.add_row("overall", *blanks, *(_cell(total.to_json()[c]) for c in quality))
    console.print(table)


_HEAD = {
    "candidates": "Q_bc",
    "accepted": "Q_dr",
    "detections": "dets",
    "precision": "prec",
    "recall": "rec",
    "error_px": "err px",
}


def _cell(v: Any) -> str:
    return f"{v:.3f}" if isinstance(v, float) else str(v)
