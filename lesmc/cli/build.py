"""``lesmc build`` (scene -> model) and ``lesmc track`` (the unattacked track and its monitor)."""

from __future__ import annotations

import json
import time
from typing import TYPE_CHECKING

import click

from lesmc.cli.budgets import stop_if_spent, write_model
from lesmc.cli.documents import (
    build_document,
    emit,
    print_warnings,
    say,
)
from lesmc.cli.options import (
    arm_budget,
    budget_from,
    budget_options,
    design_option,
    distinct_files,
    load_scene_file,
    model_output,
    parse_window,
    scene_target,
    tracker_option,
)
from lesmc.common.errors import UsageError, escape_control, escape_text
from lesmc.designs import registry

if TYPE_CHECKING:
    from rich.table import Table

    from lesmc.model.arrays import ArrayModel
    from lesmc.scene import Footage, Scene
    from lesmc.tracking.monitor import TrackPoint

_DESIGN = design_option("Override the tracker design the scene names.")


@click.command("build")
@click.argument("scene", type=click.Path(dir_okay=False))
@click.option(
    "--window",
    "window_text",
    default=None,
    metavar="L..U",
    help="Attack window: steps whose observation the attacker may change (required, "
    "except for a multi-target design built for --spec's property).",
)
@click.option(
    "--spec",
    "spec_path",
    type=click.Path(dir_okay=False),
    default=None,
    help="Multi-target designs (sort, gnn): build the model for this file's property (its "
    "attack window, end, within R and allow; --property NAME when it holds several), "
    "which lesmc check MODEL then checks.",
)
@click.option(
    "--property",
    "prop",
    default=None,
    metavar="NAME",
    help="With --spec: the property the model is built for.",
)
@click.option(
    "--end",
    type=click.IntRange(min=1),
    default=None,
    help="Last step of the model [default: the scene's last frame].",
)
@model_output
@_DESIGN
@tracker_option
@budget_options(None, "the build stops with exit 3 and writes nothing")
@scene_target
@click.option(
    "--json",
    "as_json",
    is_flag=True,
    help="Print what was built as JSON on stdout (format lesmc-build, schema "
    "lesmc/schemas/build.json): sizes, timings, the model's sha256.",
)
def build_cmd(
    scene: str,
    window_text: str | None,
    spec_path: str | None,
    prop: str | None,
    end: int | None,
    output: str,
    design: str | None,
    max_states: int | None,
    timeout: float | None,
    tracker_file: str | None,
    max_memory: int | None,
    target_text: str | None,
    as_json: bool,
) -> None:
    """Unfold SCENE into a <PO>²-LTS (Algorithm 1): every attacked run in the window.

    Step 0 is the target's frame. Within the window each state gets one
    transition per outcome an attacker can force (nearest detection first);
    outside it, the unattacked one. A multi-target design (sort, gnn) starts at
    the scene's first frame and is written as -o MODEL.npz (format
    lesmc-multi-npz, docs/lts-format.md), for --window or --spec's property.
    Exit status: 0 written, 2 bad input, 3 a budget ran out (nothing written),
    4 internal error, 130 interrupted.
    """
    budget = budget_from(timeout, max_states, max_memory, armed=False)  # armed once valid
    inputs = {"SCENE": scene, "--tracker": tracker_file, "--spec": spec_path}
    distinct_files(inputs, {"-o/--output": output})
    from lesmc.common.progress import Reporter
    from lesmc.scene import UnpricedPayoff
    from lesmc.unfold.unfold import build_model, max_end

    window = None if window_text is None else parse_window(window_text)
    sc = load_scene_file(scene, design, target_text, tracker_file)
    if registry.get(sc.tracker.design).multi:
        from lesmc.cli.multi_build import build_multi_model

        args = (window, end, spec_path, prop, output, max_states, as_json, budget)
        return build_multi_model(sc, scene, *args)
    window = _single_window(sc, window, spec_path, prop)
    arm_budget(budget)
    loaded = time.monotonic()
    stop_if_spent(budget, None, "loading the scene")
    with Reporter("build") as rep, rep.bar("building", end or max_end(sc)) as bar:
        try:
            model = build_model(
                sc,
                window,
                end,
                on_level=lambda k, n: bar.update(completed=k, description=f"building ({n} states)"),
                on_batch=lambda m: stop_if_spent(budget, m, "unfolding"),
                max_states=max_states,
            )
        except UnpricedPayoff as exc:  # a verify scene's payoff that nobody priced
            raise exc.at(scene) from None
    stop_if_spent(budget, model, "unfolding")
    unfolded = time.monotonic()
    write_model(model, output, budget)
    times = (budget.started, loaded, unfolded, time.monotonic())
    _say_built(scene, output, model, sc, window, times, as_json)


def _single_window(
    sc: Scene, window: tuple[int, int] | None, spec_path: str | None, prop: str | None
) -> tuple[int, int]:
    """The window a single-target model is built for: ``--window``, required; ``--spec``
    and ``--property`` are a multi-target design's."""
    if spec_path is not None or prop is not None:
        raise UsageError(
            "--spec and --property choose what a multi-target design (sort, gnn) is built "
            f"for; design {sc.tracker.design} is built for --window L..U"
        )
    if window is None:
        raise UsageError("--window L..U is required: the attack window the model is built for")
    return window


def _say_built(
    scene: str,
    output: str,
    model: ArrayModel,
    sc: Scene,
    window: tuple[int, int],
    times: tuple[float, float, float, float],
    as_json: bool,
) -> None:
    """What was written, for a human; with ``as_json`` the lesmc-build document too
    (``times``: started, loaded, unfolded, written)."""
    started, loaded, unfolded, written = times
    say(
        f"wrote {escape_control(output)}: {model.n_states} states, "
        f"{model.n_transitions} transitions, steps 0..{model.end}, "
        f"design {model.meta['design']}, window {window[0]}..{window[1]}",
        as_json,
    )
    if as_json:
        seconds = {
            "load": loaded - started,
            "unfold": unfolded - loaded,
            "write": written - unfolded,
            "total": time.monotonic() - started,
        }
        from lesmc.results.document import model_hash

        emit(build_document(scene, output, model, model_hash(model), sc, window, seconds))


@click.command("track")
@click.argument("scene", type=click.Path(dir_okay=False))
@click.option("--end", type=click.IntRange(min=0), default=None, help="Last step to track.")
@click.option("--json", "as_json", is_flag=True, help="Print the track as JSON.")
@_DESIGN
@tracker_option
@scene_target
def track_cmd(
    scene: str,
    end: int | None,
    as_json: bool,
    design: str | None,
    tracker_file: str | None,
    target_text: str | None,
) -> None:
    """Run the tracker on SCENE unattacked: estimates, τ (Eq. 12) and monitor alarms (Eq. 13).

    Warns when the track does not follow its target (no detection in its first
    steps, or an end far from the target's truth; docs/own-system.md). A multi-target
    design (sort, gnn) tracks every object from the scene's first frame and prints every
    track's id, box (gnn: position) and status per step, and the target's track id
    (--target or the scene's; none without one).
    """
    from lesmc.designs import registry
    from lesmc.scene import Scene

    loaded = _footage_or_scene(scene, design, target_text, tracker_file)
    if registry.get(loaded.tracker.design).multi:
        from lesmc.cli.multi_track import track_multi

        track_multi(loaded, scene, end, as_json)
        return
    if not isinstance(loaded, Scene):
        raise UsageError(f"{scene} has no target: give --target X,Y@STEP")
    _print_track(loaded, end, as_json)


def _print_track(sc: Scene, end: int | None, as_json: bool) -> None:
    """The unattacked track of a single-target design, as JSON or a table, and the
    warnings when it does not follow its target."""
    from lesmc.report.text import make_console
    from lesmc.tracking.monitor import follow_warnings, track
    from lesmc.tracking.trackers import make_tracker
    from lesmc.unfold.unfold import last_step

    if sc.has_unpriced:  # the unattacked states never depend on a payoff
        sc = sc.payoff_free()
    if end is not None:
        last_step(sc, end)  # refuses steps past the scene's last frame
    tracker = make_tracker(sc)
    points = track(tracker, end)
    warnings = follow_warnings(tracker, points)
    if as_json:
        doc = {
            "format": "lesmc-track",
            "version": 1,
            "design": sc.tracker.design,
            "state": list(sc.tracker.state_names),
            "warnings": warnings,
            "track": [
                {
                    "step": p.step,
                    "frame": p.frame,
                    "obs": p.obs,
                    "s": p.x.tolist(),
                    "tau": p.tau,
                    "nis": p.nis,
                    "alarm": p.alarm,
                    "halted": p.halted,
                }
                for p in points
            ],
        }
        click.echo(json.dumps(doc, indent=1))
        return
    make_console().print(_track_table(sc, points))
    print_warnings(warnings)


def _track_table(sc: Scene, points: list[TrackPoint]) -> Table:
    """The unattacked track as a table: one column per state component, named as the
    tracker names them (a ca2d state has six); values to 1/100 of a pixel, τ (px²) to
    four significant digits."""
    from rich.table import Table

    from lesmc.common.numbers import fmt

    table = Table(title=f"unattacked track ({sc.tracker.design} design)", title_justify="left")
    for col in ("step", "frame", "obs", *(escape_text(n) for n in sc.tracker.state_names)):
        table.add_column(col, justify="left" if col == "obs" else "right")
    table.add_column("τ", justify="right")
    table.add_column("NIS", justify="right")
    table.add_column("alarm", justify="left")
    for p in points:
        table.add_row(
            str(p.step),
            str(p.frame),
            escape_text(p.obs or "-"),
            *(f"{v:.2f}" for v in p.x),
            fmt(p.tau, 4),
            "-" if p.nis is None else fmt(p.nis, 3),
            "ALARM" if p.alarm else ("halted" if p.halted else ""),
        )
    return table


def _footage_or_scene(
    path: str, design: str | None, target: str | None, tracker: str | None
) -> Scene | Footage:
    """The scene file as ``load_scene_file`` reads it, or its footage when it has no target
    and none is given (a multi-target design needs none)."""
    from pathlib import Path

    from lesmc.common.errors import InputError
    from lesmc.common.files import read_json
    from lesmc.scene import load_tracker
    from lesmc.tracking.targets import footage_or_scene

    cfg = load_tracker(tracker, design) if tracker is not None else None
    return footage_or_scene(read_json(Path(path), InputError), path, target, design, cfg)
