"""``lesmc alarms``: a runtime monitor's false alarms on the unattacked tracks of a video
or a scene (docs/cli.md)."""

from __future__ import annotations

from pathlib import Path
from typing import TYPE_CHECKING, Any

import click

from lesmc.cli.documents import emit
from lesmc.cli.options import (
    LazyHelpOption,
    RegistryChoice,
    load_scene_file,
    tracker_option,
    video_truth_option,
)
from lesmc.common.errors import UsageError
from lesmc.designs import registry

if TYPE_CHECKING:
    from lesmc.experiment.false_alarms import TruthStart
    from lesmc.perception.quality import TruthFrame
    from lesmc.scene import Scene


def _monitor_help() -> str:
    """``--monitor``'s help, from the monitor registry (imported when shown: it loads numpy)."""
    from lesmc.language import monitors

    return (
        f"The monitor: {monitors.spelled()} (lesmc/language/monitors.py) [default: the "
        "tracker's monitor, else tau_rise 1e-9, the paper's Eq. 13]."
    )


@click.command("alarms")
@click.argument("source", required=False, type=click.Path())
@click.option(
    "--design",
    type=RegistryChoice(registry.names),
    default=registry.BASELINE,
    show_default=True,
    help="The design whose tracker runs (a monitored design's tracker, e.g. improved: joint).",
)
@click.option(
    "--monitor",
    "monitor_args",
    nargs=2,
    default=None,
    metavar="KIND PARAM",
    cls=LazyHelpOption,
    help_from=_monitor_help,
)
@click.option(
    "--window",
    type=int,
    default=1,
    show_default=True,
    help="The nis monitor's sliding window of steps.",
)
@video_truth_option
@click.option(
    "--steps",
    type=click.IntRange(min=1),
    default=None,
    help="Steps to track from the start frame [default: to the last frame].",
)
@click.option(
    "--out",
    "out_dir",
    type=click.Path(file_okay=False),
    default="lesmc-verify",
    show_default=True,
    help="A video's perception cache (OUT/cache, shared with lesmc verify --out OUT).",
)
@tracker_option
@click.option("--json", "as_json", is_flag=True, help="Print the lesmc-alarms document.")
def alarms_cmd(
    source: str | None,
    design: str,
    monitor_args: tuple[str, str] | None,
    window: int,
    truth: str | None,
    steps: int | None,
    out_dir: str,
    tracker_file: str | None,
    as_json: bool,
) -> None:
    """Run every moving truth track of SOURCE unattacked and count the monitor's alarms.

    \b
    SOURCE is a video (a directory of frames with truth.json; none: the embedded
    default video in OUT/video, as lesmc verify) or a scene file with truth tracks.
    A video is perceived (or read from OUT/cache) and its target chosen as lesmc
    verify does; each vehicle's track starts at the target's frame with its true
    position and velocity. Nothing is attacked: every alarm is a false alarm.
    Reports alarms per step and per track and the rate; --json prints a
    lesmc-alarms document (lesmc/schemas/alarms.json).
    """
    from lesmc.experiment.alarms import alarms_document, chosen_monitor

    monitor = None
    if monitor_args is not None:
        monitor = chosen_monitor(monitor_args[0], monitor_args[1], window)
    elif window != 1:
        raise UsageError("--window goes with --monitor nis QUANTILE")
    if source is not None and Path(source).is_file():
        if truth is not None:
            raise UsageError("--truth applies to a video, not to a scene")
        from lesmc.experiment.alarms import scene_starts

        scene = load_scene_file(source, None, None, tracker_file)
        if scene.has_unpriced:  # the unattacked states never depend on a payoff
            scene = scene.payoff_free()
        if not scene.truth:
            raise UsageError(f"{source}: the scene has no truth tracks to run")
        starts, ids = scene_starts(scene)
        last = scene.last_step - scene.target.step
    else:
        scene, starts, ids, tfs = video_source(source, truth, out_dir, tracker_file)
        last = len(tfs) - 1
    if not starts:
        raise UsageError("no moving truth vehicle at the start frame: nothing to track")
    if monitor is None:  # the tracker's declared monitor, else Eq. 13's
        from lesmc.language.monitors import declared

        monitor = declared(scene.tracker.monitor)
    doc = alarms_document(scene, starts, ids, min(last, steps or last), design, monitor)
    if as_json:
        emit(doc)
        return
    _print(doc)


def video_source(
    source: str | None,
    truth: str | None,
    out_dir: str,
    tracker_file: str | None,
    priced: bool = False,
    verb: str = "alarms",
) -> tuple[Scene, list[TruthStart], list[str], list[TruthFrame]]:
    """A video's scene, starts (and their ids) and truth frames from the target's frame on,
    as lesmc verify measures its false alarms (``priced``: the scene's payoffs priced when
    a model reads them, for ``lesmc tune``'s checks)."""
    from lesmc.common.progress import Reporter
    from lesmc.experiment.alarms import video_starts
    from lesmc.experiment.experiment import video_truth
    from lesmc.experiment.verify_request import Request

    if source is not None and not Path(source).is_dir():
        raise UsageError(f"{source}: no such video directory or scene file")
    if source is not None and truth is None:
        truth = str(Path(source) / "truth.json")
    req = Request(frames_dir=source, truth=truth, out=Path(out_dir), tracker=tracker_file)
    with Reporter(verb) as rep:
        scene, tfs, size = video_truth(req, rep, priced)
    starts, ids = video_starts(tfs[0], size)
    return scene, list(starts), ids, list(tfs)


def _print(doc: dict[str, Any]) -> None:
    """The alarms per track (the steps they fire at) and the rate, for a human."""
    mon = doc["monitor"]
    window = f" window {mon['window']}" if mon["window"] != 1 else ""
    click.echo(
        f"monitor {mon['kind']} {mon['parameter']:g}{window} on the unattacked tracks of "
        f"design {doc['design']} (tracker {doc['tracker']}), from frame {doc['start_frame']}"
    )
    for t in doc["tracks"]:
        fired = [str(s["step"]) for s in t["steps"] if s["alarm"]]
        where = f"alarms at steps {', '.join(fired)}" if fired else "no alarm"
        click.echo(f"  vehicle {t['truth_id']}: {len(t['steps'])} steps, {where}")
    r = doc["rate"]
    share = r["alarms"] / r["steps"] if r["steps"] else 0.0
    click.echo(
        f"false alarms: {r['alarms']} of {r['steps']} steps ({share:.1%}); "
        f"{r['tracks_with_alarm']} of {r['tracks']} tracks raise at least one"
    )
