"""``lesmc build`` (scene -> model) and ``lesmc track`` (the unattacked track and its monitor)."""

from __future__ import annotations

import json
import time
from typing import TYPE_CHECKING, Any

import click

from lesmc.cli.budgets import stop_if_spent, write_model
from lesmc.cli.documents import emit, file_facts, run_provenance, say
from lesmc.cli.options import (
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
from lesmc.common.errors import escape_control, escape_text

if TYPE_CHECKING:
    from lesmc.model.arrays import ArrayModel
    from lesmc.scene import Scene

_DESIGN = design_option("Override the tracker design the scene names.")


@click.command("build")
@click.argument("scene", type=click.Path(dir_okay=False))
@click.option(
    "--window",
    "window_text",
    required=True,
    metavar="L..U",
    help="Attack window: steps whose observation the attacker may change.",
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
    window_text: str,
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
    outside it, the unattacked one. Exit status: 0 written, 2 bad input,
    3 a budget ran out (nothing written), 4 internal error, 130 interrupted.
    """
    budget = budget_from(timeout, max_states, max_memory)
    distinct_files({"SCENE": scene, "--tracker": tracker_file}, {"-o/--output": output})
    from lesmc.build.unfold import build_model, max_end
    from lesmc.common.progress import Reporter
    from lesmc.scene import UnpricedPayoff

    window = parse_window(window_text)
    sc = load_scene_file(scene, design, target_text, tracker_file)
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
    written = time.monotonic()
    say(
        f"wrote {escape_control(output)}: {model.n_states} states, "
        f"{model.n_transitions} transitions, steps 0..{model.end}, "
        f"design {model.meta['design']}, window {window[0]}..{window[1]}",
        as_json,
    )
    if as_json:
        seconds = {
            "load": loaded - budget.started,
            "unfold": unfolded - loaded,
            "write": written - unfolded,
            "total": time.monotonic() - budget.started,
        }
        emit(_build_document(scene, output, model, sc, window, seconds))


def _build_document(
    scene: str,
    output: str,
    model: ArrayModel,
    sc: Scene,
    window: tuple[int, int],
    seconds: dict[str, float],
) -> dict[str, Any]:
    """``lesmc build --json``: what was built (format lesmc-build, schemas/build.json)."""
    from lesmc.results.document import model_hash

    return {
        "format": "lesmc-build",
        "version": 1,
        "provenance": run_provenance(),
        "scene": scene,
        "model": file_facts(output),
        "model_sha256": model_hash(model),
        "states": model.n_states,
        "transitions": model.n_transitions,
        "end": model.end,
        "window": [window[0], window[1]],
        "design": model.meta["design"],
        "target": {
            "step": sc.target.step,
            "x": float(sc.target.start[0]),
            "y": float(sc.target.start[1]),
        },
        "seconds": seconds,
    }


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
    """Run the tracker on SCENE unattacked: estimates, τ (Eq. 12) and monitor alarms (Eq. 13)."""
    from rich.table import Table

    from lesmc.build.unfold import last_step
    from lesmc.common.numbers import fmt
    from lesmc.designs.registry import make_tracker
    from lesmc.report.text import make_console
    from lesmc.tracking.monitor import track

    sc = load_scene_file(scene, design, target_text, tracker_file)
    if sc.has_unpriced:  # the unattacked states never depend on a payoff
        sc = sc.payoff_free()
    if end is not None:
        last_step(sc, end)  # refuses steps past the scene's last frame
    points = track(make_tracker(sc), end)
    if as_json:
        doc = {
            "format": "lesmc-track",
            "version": 1,
            "design": sc.tracker.design,
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
    table = Table(title=f"unattacked track ({sc.tracker.design} design)", title_justify="left")
    for col in ("step", "frame", "obs", "x", "y", "vx", "vy", "τ", "NIS", "alarm"):
        table.add_column(col, justify="left" if col in ("obs", "alarm") else "right")
    for p in points:
        table.add_row(
            str(p.step),
            str(p.frame),
            escape_text(p.obs or "-"),
            *(fmt(v, 2) for v in p.x),
            fmt(p.tau, 2),
            "-" if p.nis is None else fmt(p.nis, 3),
            "ALARM" if p.alarm else ("halted" if p.halted else ""),
        )
    make_console().print(table)
