"""``lesmc check MODEL SPEC...``: verdicts, optimum, counterexample and witness."""

from __future__ import annotations

import math
import sys
import time
from typing import TYPE_CHECKING

import click

from lesmc.cli.options import design_option, load_model_or_scene, scene_target
from lesmc.errors import UsageError

if TYPE_CHECKING:
    from lesmc.engines.result import CheckResult
    from lesmc.language.properties import SpecFile
    from lesmc.language.semantics import BoundProperty
    from lesmc.model.arrays import ArrayModel
    from lesmc.tracking.scene import Scene

DEFAULT_MAX_STATES = 10_000_000
"""``lesmc.engines.check.DEFAULT_MAX_STATES``, repeated so that the option's declaration
does not import the engines (tests/test_startup.py checks that the two agree)."""


@click.command("check")
@click.argument("model", metavar="MODEL|SCENE", type=click.Path(dir_okay=False))
@click.argument("specs", nargs=-1, required=True, type=click.Path(dir_okay=False))
@click.option(
    "--engine",
    type=click.Choice(["bnb", "enumerate"]),
    default="bnb",
    show_default=True,
    help="bnb: exact branch and bound; enumerate: the paper's Algorithms 1-2 (all paths).",
)
@click.option("--json", "as_json", is_flag=True, help="Print the results as JSON on stdout.")
@click.option(
    "--max-states",
    type=click.IntRange(min=1),
    default=DEFAULT_MAX_STATES,
    show_default=True,
    help="Budget of expanded states per property; past it the verdict may be 'unknown'.",
)
@click.option(
    "--timeout",
    type=click.FloatRange(min=0, min_open=True),
    default=None,
    callback=lambda _ctx, _p, v: _finite_seconds(v),
    help="Seconds for the whole command, loading included; past it the remaining "
    "properties are 'unknown' with the bounds found so far.",
)
@click.option(
    "--property",
    "only",
    multiple=True,
    metavar="NAME",
    help="Check only the named properties (repeatable).",
)
@click.option("--no-paths", is_flag=True, help="Table output: omit the step-by-step paths.")
@click.option(
    "--report",
    "report_dir",
    type=click.Path(file_okay=False),
    default=None,
    help="Also write DIR/report.html, DIR/figures/ and DIR/results.json (a scene is then "
    "checked on its built model).",
)
@design_option("For a scene: override the tracker design it names.")
@scene_target
def check_cmd(
    model: str,
    specs: tuple[str, ...],
    engine: str,
    as_json: bool,
    max_states: int,
    timeout: float | None,
    only: tuple[str, ...],
    no_paths: bool,
    report_dir: str | None,
    design: str | None,
    target_text: str | None,
) -> None:
    """Check the properties in SPEC files on MODEL (a .lts file) or on a SCENE (.json).

    A scene's model is built on the fly from each property's attack window
    (engine bnb expands only the states it needs; enumerate builds it whole).

    For each property: the verdict (holds iff optimum > threshold), the optimum,
    the counterexample (cheapest path that breaks the system) and the witness
    (the paper's representative path ρ* and value θ*).
    Exit status: 0 all hold, 1 some violated, 2 bad input, 3 some unknown,
    4 internal error, 130 interrupted.
    """
    started = time.monotonic()
    from rich.console import Console
    from rich.progress import Progress, SpinnerColumn, TextColumn, TimeElapsedColumn

    from lesmc.engines.check import bind_all, check_bound, window_notes
    from lesmc.language.parser import load_spec
    from lesmc.report.exit import exit_status
    from lesmc.report.text import make_console, print_results, results_json
    from lesmc.tracking.scene import Scene
    from lesmc.unfold import bind_scene, check_scene_bound

    parsed = [load_spec(s) for s in specs]
    source = load_model_or_scene(model, design, target_text)
    bound = bind_scene(source, parsed) if isinstance(source, Scene) else bind_all(source, parsed)
    if only:
        names = {bp.name for bp in bound}
        missing = [n for n in only if n not in names]
        if missing:
            raise UsageError(
                f"no property named {', '.join(missing)}; the specs define "
                f"{', '.join(sorted(names))}"
            )
        bound = [bp for bp in bound if bp.name in only]
    names_seen: set[str] = set()
    for bp in bound:
        if bp.name in names_seen:
            raise UsageError(f"property name '{bp.name}' is defined in more than one spec file")
        names_seen.add(bp.name)
    cm = None if isinstance(source, Scene) else source
    err = Console(stderr=True)
    results: list[CheckResult] = []
    with Progress(
        SpinnerColumn(),
        TextColumn("{task.description}"),
        TimeElapsedColumn(),
        console=err,
        transient=True,
        disable=not err.is_terminal,
    ) as progress:
        task = progress.add_task("checking", total=len(bound))
        for bp in bound:
            progress.update(task, description=f"checking {bp.name} ({engine})")
            left = None if timeout is None else max(0.0, timeout - (time.monotonic() - started))
            if cm is None:
                assert isinstance(source, Scene)
                results.append(check_scene_bound(source, bp, engine, max_states, left))  # type: ignore[arg-type]
            else:
                r = check_bound(cm, bp, engine, max_states, left)  # type: ignore[arg-type]
                r.notes.extend(window_notes(source, bp))  # type: ignore[arg-type]
                results.append(r)
            progress.advance(task)
    if report_dir is not None:
        results = _report(source, parsed, bound, results, engine, report_dir, model, only)
    if as_json:
        click.echo(results_json(results))
    else:
        print_results(make_console(), results, paths=not no_paths)
    sys.exit(exit_status(results))


def _report(
    source: ArrayModel | Scene,
    parsed: list[SpecFile],
    bound: list[BoundProperty],
    results: list[CheckResult],
    engine: str,
    report_dir: str,
    path: str,
    only: tuple[str, ...],
) -> list[CheckResult]:
    """Write the report; a scene is checked again on its built model (same verdicts)."""
    from rich.console import Console

    from lesmc.model.lts import to_lts
    from lesmc.report.html import DesignRun, write_report
    from lesmc.tracking.scene import Scene
    from lesmc.verify import check_designs, frame_reader, scene_frames

    err = Console(stderr=True)
    image_for = None
    if isinstance(source, Scene):
        with err.status("building the model for the report"):
            runs = check_designs(
                source,
                parsed,
                [source.tracker.design],
                engine,
                only=(lambda n: n in only) if only else None,
            )
        image_for = frame_reader(scene_frames(source))
        results = runs[0].results
    else:
        design = str(source.meta.get("design", "model"))
        runs = [DesignRun(design, to_lts(source), bound, results, None)]
    with err.status("writing the report"):
        out = write_report(runs, report_dir, image_for, {"model": path})
    err.print(f"report: {out}")
    return results


def _finite_seconds(value: float | None) -> float | None:
    """``--timeout``: a finite number of seconds (nan and inf are refused)."""
    if value is not None and not math.isfinite(value):
        raise click.BadParameter(f"{value} is not a finite number of seconds")
    return value
