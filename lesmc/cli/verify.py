"""``lesmc verify``: video in, verdicts, counterexamples and a report out (paper section 8)."""

from __future__ import annotations

import json
import sys
from pathlib import Path
from typing import Any

import click
from rich.console import Console
from rich.table import Table

from lesmc.cli.options import load_scene_file, parse_window
from lesmc.errors import UsageError
from lesmc.perception.attacks import AttackConfig
from lesmc.perception.cnn import load_nets
from lesmc.perception.quality import load_truth, truth_dt
from lesmc.perception.run import PerceiveOptions, perceive
from lesmc.perception.to_scene import make_scene, parse_target
from lesmc.report.exit import exit_status
from lesmc.report.html import write_report
from lesmc.report.progress import progress_bar
from lesmc.report.text import fmt, make_console
from lesmc.tracking.scene import Scene, save_scene
from lesmc.verify import (
    DEFAULT_VIDEO,
    DESIGNS,
    bundled_specs,
    check_designs,
    follows,
    load_specs,
    rank_targets,
)
from lesmc.video.reader import FrameSet, open_frames
from lesmc.video.synth import FPS, SynthConfig, write_video

HISTORY = 4


@click.command("verify")
@click.argument("frames_dir", required=False, type=click.Path(file_okay=False))
@click.option(
    "--scene",
    "scene_path",
    type=click.Path(dir_okay=False),
    default=None,
    help="Reuse a scene (from lesmc perceive -o) instead of perceiving a video.",
)
@click.option(
    "--target",
    "target_text",
    default=None,
    metavar="X,Y[@STEP]",
    help="The vehicle to track [default: chosen from --truth where traffic is dense].",
)
@click.option(
    "--truth",
    type=click.Path(dir_okay=False),
    default=None,
    help="truth.json of the video (target choice, initial velocity).",
)
@click.option(
    "--spec",
    "specs",
    multiple=True,
    type=click.Path(dir_okay=False),
    help="Property file (repeatable) [default: the bundled robustness and resilience].",
)
@click.option(
    "--window",
    "window_text",
    default=None,
    metavar="L..U",
    help="Override every property's attack window.",
)
@click.option(
    "--design",
    type=click.Choice(["single", "joint", "improved", "both", "all"]),
    default="all",
    show_default=True,
    help="single: plain KF; joint: joint KFs; improved: joint KFs + runtime monitor "
    "(section 7); both: single and improved (Table 5); all: the three.",
)
@click.option(
    "--out",
    "out_dir",
    type=click.Path(file_okay=False),
    default="lesmc-verify",
    show_default=True,
    help="Directory for scene.json, report.html, figures/, results.json.",
)
@click.option(
    "--nets",
    "nets_dir",
    type=click.Path(file_okay=False),
    default=None,
    help="Trained networks [default: the shipped ones].",
)
@click.option("--json", "as_json", is_flag=True, help="Print results.json on stdout.")
def verify_cmd(
    frames_dir: str | None,
    scene_path: str | None,
    target_text: str | None,
    truth: str | None,
    specs: tuple[str, ...],
    window_text: str | None,
    design: str,
    out_dir: str,
    nets_dir: str | None,
    as_json: bool,
) -> None:
    """Verify a tracker on a video end to end: perceive, build, check, report.

    \b
    With no FRAMES_DIR and no --scene, runs the embedded default: a synthetic
    WAMI video (seed 1, 24 frames, 2048x2048) is generated into OUT/video and a
    target with neighbouring traffic is chosen from its truth.
    Writes OUT/scene.json, OUT/report.html (self-contained), OUT/figures/*.png
    and OUT/results.json. Exit status as for lesmc check: 0 all hold,
    1 some violated, 2 bad input, 3 some unknown.
    """
    out = Path(out_dir)
    window = parse_window(window_text) if window_text else None
    spec_files = load_specs([Path(s) for s in specs] or bundled_specs(), window)
    err = Console(stderr=True)
    frames: FrameSet | None = None
    meta: dict[str, Any] = {}
    if scene_path is not None:
        if frames_dir is not None:
            raise UsageError("give FRAMES_DIR or --scene, not both")
        scene = load_scene_file(scene_path)
        src = scene.meta.get("source")
        if isinstance(src, str) and Path(src).is_dir():
            frames = open_frames(src, 1)
        meta["scene"] = scene_path
    else:
        if frames_dir is None:
            frames_dir, truth = _default_video(out, err)
            meta["video"] = (
                f"embedded default: lesmc synth {out / 'video'} --seed {DEFAULT_VIDEO['seed']} "
                f"--frames {DEFAULT_VIDEO['frames']}"
            )
        else:
            meta["video"] = frames_dir
        if not target_text and not truth:
            raise UsageError("--target is needed (or --truth, to choose one)")
        frames = open_frames(frames_dir, HISTORY + 1)
        truths = load_truth(truth) if truth else None
        dt = (truth_dt(truth) if truth else None) or 1 / FPS
        nets = load_nets(nets_dir)
        opts = PerceiveOptions(history=HISTORY, nets=nets, attack=AttackConfig())
        with progress_bar("perceiving", len(frames)) as bar:
            run = perceive(frames, opts, None, bar.advance)
        if not run.detections:
            raise UsageError("the video produced no detections")
        scene_meta = {"source": str(frames_dir), "detector": nets.settings.trained_on}
        first = run.detections[0].index
        if target_text:
            spec = parse_target(target_text)
            step = spec.step if spec.step is not None else first
            known = truths is not None and 0 <= step < len(frames)
            tf = truths.get(frames.paths[step].name) if truths is not None and known else None
            scene = make_scene(run.detections, run.payoffs, dt, spec, tf, meta=scene_meta)
        elif truths is not None:
            scene = _auto_target(run, frames, truths, spec_files, scene_meta, dt)
            meta["target choice"] = scene.meta["target_choice"]
        else:
            raise UsageError("--target is needed (or --truth, to choose one)")
        meta["detector"] = nets.settings.trained_on
        out.mkdir(parents=True, exist_ok=True)
        save_scene(scene, out / "scene.json")
        meta["scene"] = str(out / "scene.json")
    if window is not None:
        _check_window(scene, window)
    meta["target"] = (
        f"({scene.target.start[0]:.1f}, {scene.target.start[1]:.1f}) in frame "
        f"{scene.target.step}, velocity ({scene.target.velocity[0]:.1f}, "
        f"{scene.target.velocity[1]:.1f}) px/s"
    )
    meta["properties"] = ", ".join(s.path for s in spec_files)
    err.print(f"target: {meta['target']}")
    with err.status("checking") as status:
        runs = check_designs(
            scene, spec_files, DESIGNS[design], on_stage=lambda s: status.update(s)
        )
    fs = frames

    def image_for(index: int) -> Any:
        if fs is None or not 0 <= index < len(fs):
            return None
        return fs.read(index)

    with err.status("writing the report"):
        report = write_report(runs, out, image_for, meta)
    results = [r for run in runs for r in run.results]
    if as_json:
        click.echo((out / "results.json").read_text(), nl=False)
    else:
        _summary(runs)
        click.echo(f"report: {report}")
    sys.exit(exit_status(results))


def _auto_target(
    run: Any, frames: FrameSet, truths: Any, spec_files: Any, meta: dict[str, Any], dt: float
) -> Scene:
    """The best-ranked vehicle (rank_targets) whose unattacked track follows it."""
    first = run.detections[0].index
    tfs = [truths[p.name] for p in frames.paths[first:] if p.name in truths]
    window = (
        min(p.window[0] for s in spec_files for p in s.properties),
        max(p.window[1] or len(tfs) - 1 for s in spec_files for p in s.properties),
    )
    cands = rank_targets(tfs, (frames.width, frames.height), window)
    for rank, c in enumerate(cands[:40]):
        scene = make_scene(run.detections, run.payoffs, dt, c.spec, tfs[0], meta=dict(meta))
        if follows(scene, c.truth_track):
            scene.meta["target_choice"] = (
                f"vehicle {c.vid} of the truth: rank {rank + 1} of {len(cands)} by neighbouring "
                f"traffic ({c.crowd} vehicle-frames within 40 px in the window), the first whose "
                "unattacked track follows it"
            )
            return scene
    raise UsageError(
        "no vehicle with neighbouring traffic is tracked correctly unattacked; give --target"
    )


def _check_window(scene: Scene, window: tuple[int, int]) -> None:
    """--window against the unattacked track's length, before any model is built."""
    from lesmc.model.builder import original_run
    from lesmc.tracking.design import make_design

    e = len(original_run(make_design(scene))) - 1
    if not 1 <= window[0] <= window[1] <= e:
        raise UsageError(
            f"--window {window[0]}..{window[1]} must satisfy 1 <= L <= U <= {e}, the last step "
            f"of the unattacked track from frame {scene.target.step}"
        )


def _default_video(out: Path, err: Console) -> tuple[str, str]:
    """Generate (or reuse, when it is the same) the embedded default video under OUT/video."""
    video = out / "video"
    truth = video / "truth.json"
    cfg = SynthConfig(**DEFAULT_VIDEO)
    if truth.is_file():
        from dataclasses import asdict

        try:
            same = json.loads(truth.read_text()).get("config") == asdict(cfg)
        except ValueError:
            same = False
        n = len(list(video.glob("frame_*.png")))
        if same and n == cfg.frames:
            err.print(f"reusing the default video in {video}")
            return str(video), str(truth)
    with progress_bar("rendering", cfg.frames) as bar:
        write_video(cfg, video, progress=bar.advance)
    return str(video), str(truth)


def _summary(runs: list[Any]) -> None:
    console = make_console()
    table = Table(title="lesmc verify", title_justify="left")
    for c in ("design", "property", "verdict", "optimum", "holds if", "θ*", "model"):
        table.add_column(
            c,
            justify="left" if c in ("design", "property", "verdict", "holds if") else "right",
            no_wrap=True,
        )
    colours = {"holds": "green", "violated": "red", "unknown": "yellow"}
    for run in runs:
        n = run.model.graph.number_of_nodes()
        for r in run.results:
            opt = fmt(r.optimum) if r.optimum is not None else "+inf"
            table.add_row(
                run.name,
                r.property,
                f"[{colours[r.verdict]}]{r.verdict}[/]",
                opt,
                f"{r.holds_op} {r.threshold:g}",
                fmt(r.witness_value),
                f"{n} states",
            )
    console.print(table)
