"""``lesmc verify``: video in, verdicts, counterexamples and a report out (paper section 8)."""

from __future__ import annotations

import json
import sys
from pathlib import Path
from typing import TYPE_CHECKING

import click

from lesmc.cli.documents import refuse_given
from lesmc.cli.options import (
    DEFAULT_MAX_STATES,
    FiniteRange,
    budget_from,
    budget_options,
    designs_option,
    faults_option,
    frames_option,
    nets_option,
    network_options,
    parse_window,
    payoffs_option,
    spec_option,
    target_option,
    tracker_option,
)
from lesmc.cli.signals import resumable

if TYPE_CHECKING:
    from lesmc.experiment.experiment import Outcome
    from lesmc.experiment.multi_verify import MultiOutcome
    from lesmc.experiment.verify_request import Request as VerifyRequest


@click.command("verify")
@click.argument("frames_dir", required=False, type=click.Path(file_okay=False))
@click.option(
    "--scene",
    "scene_path",
    type=click.Path(dir_okay=False),
    default=None,
    help="Reuse a scene (from lesmc perceive -o) instead of perceiving a video.",
)
@target_option(
    "The vehicle to track, X,Y of frame STEP; with --scene it overrides the scene's "
    "target [default: chosen from --truth where traffic is dense]."
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
@designs_option()
@click.option(
    "--out",
    "out_dir",
    type=click.Path(file_okay=False),
    default="lesmc-verify",
    show_default=True,
    help="Directory for scene.json, report.html, figures/, results.json.",
)
@nets_option
@network_options
@frames_option(
    "With --scene: the video's frames, for the replay of counterexamples and the "
    "report's images (read from nowhere else).",
    "frames_opt",
)
@payoffs_option(
    "",
    " On a video, certified|interval certify the detections the models can hide (about "
    "a second each; `perceive --certify` certifies them all).",
)
@click.option(
    "--price-all",
    is_flag=True,
    help="Attack every detection of the video up front. By default verify attacks only "
    'the detections whose payoffs its models read (the others are "unpriced" in '
    "OUT/scene.json; a later check that reads one stops with exit 2), through the window "
    "pipeline or a heatmap or box-list detector file alike (docs/detectors.md). Certified "
    "payoffs and --faults price every detection up front anyway. With a heatmap detector "
    "file and --payoffs certified|interval, --price-all also certifies every detection up "
    "front (by default, only those the models can hide are certified, on demand).",
)
@click.option(
    "--inject-within",
    type=FiniteRange(min=0.0),
    default=None,
    metavar="PX",
    help="On a video: also injection candidates, the candidates N_dr rejects within PX of "
    "a detection, priced up front by the attack towards 'vehicle' (what `allow hide, "
    'inject` in a spec reads; docs/cnn.md, "Injection candidates").',
)
@click.option(
    "--inject-cap",
    type=click.IntRange(min=1),
    default=32,
    show_default=True,
    metavar="N",
    help="With --inject-within: at most N candidates a frame, nearest a detection first.",
)
@tracker_option
@click.option(
    "--space",
    "space_file",
    type=click.Path(dir_okay=False),
    default=None,
    help="Also search the designs of a space file as lesmc tune does (docs/cli.md); the "
    "report's 'A design that holds' shows the best under the file's false-alarm budget.",
)
@faults_option(
    " The report shows which faults break which design. A neuron fault perceives the video "
    "again with the unit stuck (once per set of them, kept in OUT/cache)."
)
@click.option("--json", "as_json", is_flag=True, help="Print results.json on stdout.")
@budget_options(
    DEFAULT_MAX_STATES,
    "the remaining verdicts are 'unknown' (while perceiving or building a point design's "
    "model, verify stops with exit 3 and writes nothing; a --design sort|gnn unfolding "
    "past --timeout gives 'unknown' results that are written, past --max-states it stops)",
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
    detector_file: str | None,
    locator_file: str | None,
    frames_opt: str | None,
    payoffs: str,
    price_all: bool,
    inject_within: float | None,
    inject_cap: int,
    tracker_file: str | None,
    space_file: str | None,
    faults_file: str | None,
    as_json: bool,
    max_states: int,
    timeout: float | None,
    max_memory: int | None,
) -> None:
    """Verify a tracker on a video end to end: perceive, build, check, replay, report.

    \b
    With no FRAMES_DIR and no --scene, runs the embedded default: a synthetic
    WAMI video (seed 1, 24 frames, 2048x2048) is generated into OUT/video and a
    target with neighbouring traffic is chosen from its truth.
    Writes OUT/scene.json, OUT/report.html, OUT/figures/*.png and OUT/results.json.
    --design sort|gnn (multi-target): specs/identity.spec by default, replayed by
    the production tracker, results.json a lesmc-multi-check document.
    OUT/cache keeps perception, replays and figures by content. Exit status as check's.
    """
    preload = ("torch", "cv2", *_checks_on(design)) if timeout is not None else ()
    budget = budget_from(timeout, max_states, max_memory, preload=preload)  # under a watchdog
    from lesmc.api import VerifyRequest, expand_designs  # --help stays light

    request = VerifyRequest(
        frames_dir=frames_dir,
        scene_path=scene_path,
        target=target_text,
        truth=truth,
        specs=specs,
        window=parse_window(window_text) if window_text else None,
        designs=expand_designs(design, multi=True),
        out=Path(out_dir),
        nets=(nets_dir, detector_file, locator_file),
        scene_frames=frames_opt,
        tracker=tracker_file,
        payoffs=payoffs,
        budget=budget,
        faults=faults_file,
        price_all=price_all,
        space=_space(space_file, tracker_file),
        inject=_inject(inject_within, inject_cap, scene_path),
    )
    _run(request, as_json)


def _checks_on(design: str | None) -> tuple[str, ...]:
    """The modules a check of ``design`` imports as it runs, when it is a multi-target
    design (lesmc/pipeline/multi.py ``RUNS_ON``): imported with torch, before the clock's
    alarm can stop the check in an import, so that its deadline ends in a result."""
    from lesmc.designs import registry

    if design not in registry.multi_names():
        return ()
    from lesmc.pipeline.multi import RUNS_ON

    return RUNS_ON


def _inject(within: float | None, cap: int, scene_path: str | None) -> tuple[float, int] | None:
    """``--inject-within`` and ``--inject-cap``: injection candidates perceived from the
    video (refused with --scene, which is perceived already; the cap alone is refused)."""
    if within is None:
        refuse_given(("inject_cap",), "limits the candidates of --inject-within: give it too")
        return None
    if scene_path is not None:
        refuse_given(
            ("inject_within",),
            "perceives candidates from the video: a --scene brings its own "
            "(lesmc perceive --inject-within)",
        )
    return within, cap


def _space(space_file: str | None, tracker_file: str | None) -> str | None:
    """``--space``: read now, so that its mistakes stop verify before any work (exit 2)."""
    if space_file is not None:
        from lesmc.experiment.tune_space import read_space
        from lesmc.scene.scene import TrackerConfig
        from lesmc.scene.tracker_file import load_tracker

        read_space(space_file, load_tracker(tracker_file) if tracker_file else TrackerConfig())
    return space_file


def _run(request: VerifyRequest, as_json: bool) -> None:
    """Verify ``request``, then print its results."""
    from lesmc.api import verify
    from lesmc.common.progress import Reporter

    with resumable(lambda: _kept(request.out)), Reporter("verify") as rep:
        outcome = verify(request, rep)
    _finish(outcome, as_json)


def _finish(outcome: Outcome | MultiOutcome, as_json: bool) -> None:
    """The results on stdout (results.json, or the table and the report's path), then the
    exit status."""
    from lesmc.experiment.multi_verify import MultiOutcome
    from lesmc.report.text import make_console, print_runs
    from lesmc.results.exit import exit_status

    if isinstance(outcome, MultiOutcome):  # a multi-target design: lesmc check's lines
        from lesmc.cli.multi_check import multi_exit_status, print_multi

        print_multi(outcome.doc, as_json)
        if not as_json:
            click.echo(f"report: {outcome.report}")
        sys.exit(multi_exit_status(outcome.doc))
    if as_json:
        click.echo(json.dumps(outcome.doc, indent=1, allow_nan=False))
    else:
        print_runs(make_console(), "lesmc verify", outcome.results.runs)
        click.echo(f"report: {outcome.report}")
    sys.exit(exit_status(outcome.results.results))


def _kept(out: Path) -> str:
    """What an interrupted verify leaves for its rerun: the rendered default video; the
    report in OUT is the previous run's or none (it is moved in whole, at the end)."""
    from lesmc.experiment.default_video import default_video_ready

    video = out / "video"
    report = "the previous report" if (out / "results.json").exists() else "no report"
    if default_video_ready(video):
        return f"the rendered default video in {video}; {out} holds {report}"
    return f"{out} holds {report}"
