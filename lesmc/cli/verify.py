"""``lesmc verify``: video in, verdicts, counterexamples and a report out (paper section 8)."""

from __future__ import annotations

import json
import sys
import time
from dataclasses import asdict
from pathlib import Path
from typing import Any

import click

from lesmc.cli.budgets import stop_if_spent
from lesmc.cli.check import DEFAULT_MAX_STATES
from lesmc.cli.options import (
    budget_from,
    budget_options,
    designs_option,
    frames_option,
    load_scene_file,
    nets_option,
    parse_window,
    payoffs_option,
    spec_option,
)
from lesmc.errors import UsageError
from lesmc.video import FPS

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
    help="The vehicle to track, X,Y of frame STEP; with --scene it overrides the scene's "
    "target [default: chosen from --truth where traffic is dense].",
)
@click.option(
    "--truth",
    type=click.Path(dir_okay=False),
    default=None,
    help="truth.json of the video (target choice, initial velocity).",
)
@spec_option
@click.option(
    "--window",
    "window_text",
    default=None,
    metavar="L..U",
    help="Override every property's attack window.",
)
@designs_option(
    "single: plain KF; joint: joint KFs; improved: joint KFs + runtime monitor "
    "(section 7); both: single and improved (Table 5); all: the three."
)
@click.option(
    "--out",
    "out_dir",
    type=click.Path(file_okay=False),
    default="lesmc-verify",
    show_default=True,
    help="Directory for scene.json, report.html, figures/, results.json.",
)
@nets_option
@frames_option(
    "With --scene: the video's frames, for the replay of counterexamples and the "
    "report's images (read from nowhere else).",
    "frames_opt",
)
@payoffs_option(
    "The attack's payoffs (the paper), the certified lower bounds, or both (holds only "
    "if proven with the lower bounds, violated only with the attack's counterexample; "
    "docs/semantics.md). On a video, certified|interval certify the detections the "
    "models can hide (about a second each; `perceive --certify` certifies them all)."
)
@click.option("--json", "as_json", is_flag=True, help="Print results.json on stdout.")
@budget_options(
    DEFAULT_MAX_STATES,
    "the remaining verdicts are 'unknown' (while perceiving or building a model, verify "
    "stops with exit 3 and writes nothing)",
)
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
    frames_opt: str | None,
    payoffs: str,
    as_json: bool,
    max_states: int,
    timeout: float | None,
    max_memory: int | None,
) -> None:
    """Verify a tracker on a video end to end: perceive, build, check, report.

    \b
    With no FRAMES_DIR and no --scene, runs the embedded default: a synthetic
    WAMI video (seed 1, 24 frames, 2048x2048) is generated into OUT/video and a
    target with neighbouring traffic is chosen from its truth.
    Writes OUT/scene.json, OUT/report.html (self-contained), OUT/figures/*.png
    and OUT/results.json. Exit status as for lesmc check: 0 all hold,
    1 some violated, 2 bad input, 3 some unknown, 4 internal error, 130 interrupted.
    """
    budget = budget_from(timeout, max_states, max_memory, preload=("torch", "cv2"))
    # Imported here, not at module level: torch, cv2, matplotlib and scipy cost seconds.
    from rich.console import Console

    from lesmc.perception.attacks import AttackConfig
    from lesmc.perception.cnn import load_nets
    from lesmc.perception.quality import load_truth
    from lesmc.perception.run import PerceiveOptions, perceive
    from lesmc.perception.to_scene import check_target, parse_target, scene_from_run
    from lesmc.report.exit import exit_status
    from lesmc.report.progress import progress_bar
    from lesmc.tracking.scene import save_scene
    from lesmc.verify import (
        DEFAULT_VIDEO,
        DESIGNS,
        auto_target,
        bundled_specs,
        check_designs,
        check_window,
        default_video_ready,
        load_specs,
        write_default_video,
    )
    from lesmc.video.reader import open_frames

    started = time.monotonic()
    out = Path(out_dir)
    window = parse_window(window_text) if window_text else None
    spec_files = load_specs([Path(s) for s in specs] or bundled_specs(), window)
    err = Console(stderr=True)
    meta: dict[str, Any] = {}
    new_scene = None
    run = None
    if scene_path is not None:
        if frames_dir is not None:
            raise UsageError("give FRAMES_DIR or --scene, not both")
        if truth is not None:
            raise UsageError("--truth applies to a video, not to --scene")
        scene = load_scene_file(scene_path, None, target_text)
        truths = None
        # images only from a directory named on the command line
        frames = open_frames(frames_opt, HISTORY + 1) if frames_opt else None
        nets = load_nets(nets_dir) if frames is not None else None
        if nets_dir is not None and frames is None:
            raise UsageError("--nets with --scene applies only to the replay: give --frames too")
        meta["scene"] = scene_path
    else:
        if frames_dir is None and truth is not None:
            raise UsageError("--truth is FRAMES_DIR's truth: the default video brings its own")
        if frames_opt is not None:
            raise UsageError("--frames goes with --scene; a video is given as FRAMES_DIR")
        if frames_dir is None:
            video = out / "video"
            if default_video_ready(video):
                err.print(f"reusing the default video in {video}")
            else:
                with progress_bar("rendering", DEFAULT_VIDEO["frames"]) as bar:

                    def rendered() -> None:
                        bar.advance()
                        stop_if_spent(budget, None, "rendering the default video")

                    write_default_video(video, rendered)
            frames_dir, truth = str(video), str(video / "truth.json")
            meta["video"] = (
                f"embedded default: lesmc synth {video} --seed {DEFAULT_VIDEO['seed']} "
                f"--frames {DEFAULT_VIDEO['frames']}"
            )
        else:
            meta["video"] = frames_dir
        if not target_text and not truth:
            raise UsageError("--target is needed (or --truth, to choose one)")
        frames = open_frames(frames_dir, HISTORY + 1)
        target = parse_target(target_text) if target_text else None
        if target is not None:
            check_target(target, frames.width, frames.height, len(frames))
        truths = load_truth(truth) if truth else None
        dt = (truths.dt if truths else None) or 1 / FPS
        nets = load_nets(nets_dir)
        opts = PerceiveOptions(history=HISTORY, nets=nets, attack=AttackConfig())
        with progress_bar("perceiving", len(frames)) as bar:

            def advance() -> None:
                bar.advance()
                stop_if_spent(budget, None, "perceiving the video")

            stop_if_spent(budget, None, "loading the video and the networks")
            run = perceive(frames, opts, None, advance)
        if not run.detections:
            raise UsageError("the video produced no detections")
        scene_meta = {"source": str(frames_dir), "detector": nets.settings.trained_on}
        if target is not None:
            scene = scene_from_run(run, frames, target, dt, truths, scene_meta)
        else:
            assert truths is not None
            scene = auto_target(run, frames, truths, spec_files, dt, scene_meta)
            meta["target choice"] = scene.meta["target_choice"]
        meta["detector"] = nets.settings.trained_on
        new_scene = scene  # written after the report: an interrupted run leaves --out as it was
        meta["scene"] = str(out / "scene.json")
    if window is not None:
        check_window(scene, window)
    certified = None
    if run is not None and payoffs != "attack":
        assert nets is not None
        scene = _certify(scene, run, nets, spec_files, DESIGNS[design], budget, err)
        certified = scene.meta["certified"]
        new_scene = scene
    meta["target"] = (
        f"({scene.target.start[0]:.1f}, {scene.target.start[1]:.1f}) in frame "
        f"{scene.target.step}, velocity ({scene.target.velocity[0]:.1f}, "
        f"{scene.target.velocity[1]:.1f}) px/s"
    )
    meta["properties"] = ", ".join(s.path for s in spec_files)
    err.print(f"target: {meta['target']}")
    checked = time.monotonic()
    with err.status("checking") as status:
        runs = check_designs(
            scene,
            spec_files,
            DESIGNS[design],
            on_stage=lambda s: status.update(s),
            budget=budget,
            on_batch=lambda m: stop_if_spent(budget, m, "building a model"),
            payoffs=payoffs,
        )
    timings = {"video, perception and scene": checked - started}
    timings["models and checks"] = time.monotonic() - checked
    perception = {
        "history": HISTORY,
        "delta_bc": 12,
        "nets": nets.settings.trained_on if nets is not None else "",
        "attack": asdict(_attack_of(scene) if scene_path is not None else AttackConfig()),
        "payoffs": payoffs,
    }
    if certified is not None:  # this run's certification (a --scene keeps its own meta)
        perception["certified"] = certified
    report, doc = _publish(
        runs, out, meta, spec_files, frames, truths, scene, timings, nets, perception, budget
    )
    if new_scene is not None:
        save_scene(new_scene, out / "scene.json")
    results = [r for run in runs for r in run.results]
    if as_json:
        click.echo(json.dumps(doc, indent=1, allow_nan=False))
    else:
        _summary(runs)
        click.echo(f"report: {report}")
    sys.exit(exit_status(results))


def _certify(
    scene: Any,
    run: Any,
    nets: Any,
    spec_files: list[Any],
    designs: list[str],
    budget: Any,
    err: Any,
) -> Any:
    """``scene`` with certified lower payoffs for the detections its models can hide.

    Only those enter a certified model's combined payoffs (lesmc.verify.hideable);
    the others keep no bound, which the certified model reads as 0 (docs/semantics.md).
    """
    from dataclasses import replace

    from lesmc.perception.run import certification_meta, certify_on_demand
    from lesmc.report.progress import progress_bar
    from lesmc.verify import design_windows, hideable

    started = time.monotonic()
    units = design_windows(scene, spec_files, designs)
    with err.status("finding the detections the models can hide"):
        wanted = hideable(
            units, lambda m: stop_if_spent(budget, m, "finding the detections to certify")
        )
    with progress_bar("certifying", None) as bar:

        def certified(done: int, total: int) -> None:
            bar.update(total=total, completed=done)
            stop_if_spent(budget, None, "certifying payoff lower bounds")

        low = scene.with_lower(certify_on_demand(nets, run, wanted, certified))
    summary = certification_meta(
        low.frames,
        "the detections the checked models can hide; the others have no bound",
        time.monotonic() - started,
        designs=designs,
        windows=[list(w) for w in sorted({win for *_, win in units})],
    )
    err.print(
        f"certified lower payoffs of {summary['detections']} of {summary['of']} detections "
        "(those the models can hide)"
    )
    return replace(low, meta={**scene.meta, "certified": summary})


def _attack_of(scene: Any) -> Any:
    """The attack settings a scene's meta records (lesmc perceive -o), defaults otherwise."""
    from lesmc.perception.attacks import AttackConfig

    a = scene.meta.get("attack")
    if not isinstance(a, dict):
        return AttackConfig()
    keys = {"method": str, "overshoot": float, "max_iter": int, "norm": str}
    got = {k: t(a[k]) for k, t in keys.items() if k in a and isinstance(a[k], (str, int, float))}
    return AttackConfig(**got)


def _publish(
    runs: list[Any],
    out: Path,
    meta: dict[str, Any],
    specs: list[Any],
    frames: Any,
    truths: Any,
    scene: Any,
    timings: dict[str, float],
    nets: Any = None,
    perception: dict[str, Any] | None = None,
    budget: Any = None,
) -> tuple[Path, dict[str, Any]]:
    """results.json and the report from it; with the truth, the target's true track and the
    monitor's false alarms on every truth track (lesmc/false_alarms.py); with the frames,
    every violated property's counterexample replayed (lesmc/replay.py), which may turn its
    verdict into unknown (``runs``' results are updated to match)."""
    from rich.console import Console

    from lesmc.report.html import write_report
    from lesmc.report.results import provenance, results_document
    from lesmc.verify import DEFAULT_VIDEO, frame_reader

    truth: Any = None
    extra: dict[str, Any] = {}
    if frames is not None and truths is not None:
        from lesmc.false_alarms import false_alarm_report, truth_track

        tfs = [truths.frames.get(p.name) for p in frames.paths[scene.target.step :]]
        tfs = tfs[: next((i for i, t in enumerate(tfs) if t is None), len(tfs))]
        if tfs:
            truth = truth_track(tfs, scene.target.start) or None
            t0 = time.monotonic()
            end = max(run.model.end for run in runs)
            extra["monitor_false_alarms"] = false_alarm_report(
                scene, tfs, (frames.width, frames.height), min(end, len(tfs) - 1)
            )
            timings["monitor false alarms"] = time.monotonic() - t0
    seeds = {"video": DEFAULT_VIDEO["seed"]} if "embedded default" in meta.get("video", "") else {}
    if perception is not None:
        extra["perception"] = perception
    doc = results_document(runs, meta, provenance(specs, seeds=seeds), timings, truth, extra)
    _replay(runs, doc, frames, nets, timings, budget)
    doc["timings"] = {k: round(float(v), 3) for k, v in timings.items()}
    with Console(stderr=True).status("writing the report"):
        return write_report(doc, out, frame_reader(frames)), doc


def _replay(
    runs: list[Any],
    doc: dict[str, Any],
    frames: Any,
    nets: Any,
    timings: dict[str, float],
    budget: Any,
) -> None:
    """Replay every violated property on the frames (lesmc/replay.py) and record it in ``doc``
    and in ``runs``' results; without frames, each violated result says it was not replayed."""
    from lesmc.cli.budgets import stop_if_spent
    from lesmc.replay import apply_to_doc, apply_to_results, cases, replay

    if not cases(doc):
        return
    if frames is None or nets is None:
        for run, rd in zip(runs, doc["runs"], strict=True):
            for r, res in zip(run.results, rd["results"], strict=True):
                if r.verdict == "violated":
                    note = (
                        "not replayed through the detector and tracker (no frames: give "
                        "--frames with --scene)"
                    )
                    r.notes.append(note)
                    res["notes"].append(note)
        return
    from lesmc.report.progress import progress_bar

    t0 = time.monotonic()
    with progress_bar("replaying", len(frames)) as bar:

        def advance() -> None:
            bar.advance()
            stop_if_spent(budget, None, "replaying the counterexamples")

        outcome = replay(doc, frames, nets, on_frame=advance)
    apply_to_doc(doc, outcome)
    doc["replay"] = {"replayed": len(outcome.replays), "seconds": round(outcome.seconds, 3)}
    for i, run in enumerate(runs):
        objs = [outcome.replays.get((i, j)) for j in range(len(run.results))]
        run.results[:] = apply_to_results(run.results, objs)
    timings["replay"] = time.monotonic() - t0


def _summary(runs: list[Any]) -> None:
    from rich.table import Table

    from lesmc.errors import escape_text
    from lesmc.report.text import fmt, make_console, optimum_cell

    console = make_console()
    table = Table(title="lesmc verify", title_justify="left")
    for c in ("design", "property", "verdict", "optimum", "holds if", "θ*", "model"):
        table.add_column(
            c,
            justify="left" if c in ("design", "property", "verdict", "holds if") else "right",
            overflow="fold",
        )
    colours = {"holds": "green", "violated": "red", "unknown": "yellow"}
    for run in runs:
        n = run.model.graph.number_of_nodes()
        for r in run.results:
            known = r.optimum_known and r.stats.stopped == "finished"
            opt = optimum_cell(r.optimum, known, r.lower, r.upper, r.payoffs == "interval")
            table.add_row(
                escape_text(run.name),
                escape_text(r.property),
                f"[{colours[r.verdict]}]{escape_text(r.verdict_text())}[/]",
                opt,
                f"{r.holds_op} {r.threshold:g}",
                fmt(r.witness_value),
                f"{n} states",
            )
    console.print(table)
