"""``lesmc check MODEL SPEC...``: verdicts, optimum, counterexample and witness."""

from __future__ import annotations

import sys
import time
from typing import TYPE_CHECKING

import click

from lesmc.cli.budgets import stop_if_spent
from lesmc.cli.options import (
    budget_from,
    budget_options,
    design_option,
    frames_option,
    load_model_or_scene,
    payoffs_option,
    scene_target,
)
from lesmc.errors import UsageError

if TYPE_CHECKING:
    from lesmc.engines.budget import Budget
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
    type=click.Choice(["levels", "bnb", "enumerate"]),
    default="levels",
    show_default=True,
    help="levels: exact search in lock step with bounds, dominance and a dive for an incumbent "
    "(anytime); bnb: best-first branch and bound; enumerate: the paper's Algorithms 1-2 "
    "(all paths).",
)
@click.option("--json", "as_json", is_flag=True, help="Print the results as JSON on stdout.")
@budget_options(
    DEFAULT_MAX_STATES,
    "the remaining properties are 'unknown' with the bounds found so far",
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
    help="Also write DIR/results.json, DIR/report.html and DIR/figures/ (a scene is then "
    "checked once, on its built model).",
)
@frames_option(
    "With --report: the video's frames, for the report's images (read from nowhere else)."
)
@payoffs_option(
    "For a scene: the attack's payoffs (the paper), the certified lower bounds "
    "(payoff_lower), or both: holds only if proven with the lower bounds, violated only "
    "with the attack's counterexample, else unknown (docs/semantics.md)."
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
    frames_dir: str | None,
    payoffs: str,
    design: str | None,
    max_memory: int | None,
    target_text: str | None,
) -> None:
    """Check the properties in SPEC files on MODEL (a .lts file) or on a SCENE (.json).

    A scene's model is unfolded on the fly from each property's attack window
    (levels and bnb unfold only the states they visit, enumerate every state its
    paths reach); a budget stops every engine with 'unknown' and the bounds found.

    For each property: the verdict (holds iff optimum > threshold), the optimum,
    the counterexample (cheapest path that breaks the system) and the witness
    (the paper's representative path ρ* and value θ*).
    Exit status: 0 all hold, 1 some violated, 2 bad input, 3 some unknown,
    4 internal error, 130 interrupted.
    """
    budget = budget_from(timeout, None, max_memory)
    started = budget.started
    from rich.console import Console
    from rich.progress import Progress, SpinnerColumn, TextColumn, TimeElapsedColumn

    from lesmc.engines.check import bind_all, check_bound, window_notes
    from lesmc.language.parser import load_spec
    from lesmc.report.exit import exit_status
    from lesmc.report.text import make_console, print_results, results_json
    from lesmc.tracking.scene import Scene
    from lesmc.unfold import bind_scene, check_scene_payoffs

    if frames_dir is not None and report_dir is None:
        raise UsageError("--frames gives the report's images: it needs --report DIR")
    if no_paths and as_json:
        raise UsageError("--no-paths shortens the table: --json always carries the paths")
    parsed = [load_spec(s) for s in specs]
    source = load_model_or_scene(model, design, target_text)
    if payoffs != "attack" and not isinstance(source, Scene):
        raise UsageError(f"--payoffs {payoffs} needs a scene: a model's payoffs are built in")
    if payoffs != "attack" and report_dir is not None:
        raise UsageError("--report draws the attack payoffs' model: use --payoffs attack")
    bound = bind_scene(source, parsed) if isinstance(source, Scene) else bind_all(source, parsed)
    scene: Scene | None = None
    if report_dir is not None and isinstance(source, Scene):
        scene = source  # the report draws the whole model: build it, check once on it
        bound, source = _built(source, parsed, bound, only, budget)
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
                results.append(
                    check_scene_payoffs(
                        source,
                        bp,
                        payoffs,
                        engine,  # type: ignore[arg-type]
                        max_states,
                        left,
                        model,
                        max_memory,
                    )
                )
            else:
                r = check_bound(cm, bp, engine, max_states, left, max_memory)  # type: ignore[arg-type]
                r.notes.extend(window_notes(source, bp))  # type: ignore[arg-type]
                results.append(r)
            progress.advance(task)
    if report_dir is not None:
        _report(source, parsed, bound, results, report_dir, model, frames_dir, started, scene)
    if as_json:
        click.echo(results_json(results, parsed))
    else:
        print_results(make_console(), results, paths=not no_paths)
    sys.exit(exit_status(results))


def _built(
    scene: Scene,
    parsed: list[SpecFile],
    bound: list[BoundProperty],
    only: tuple[str, ...],
    budget: Budget,
) -> tuple[list[BoundProperty], ArrayModel]:
    """For --report: the scene's whole model over the properties' windows, built once, and
    the properties bound to it; the check then runs on it (one check, one model). Past a
    budget while building, exit 3 with nothing written (lesmc/cli/budgets.py)."""
    from rich.console import Console

    from lesmc.engines.check import bind_all
    from lesmc.report.results import window_of
    from lesmc.unfold import build_model

    wanted = [bp for bp in bound if not only or bp.name in only] or bound
    with Console(stderr=True).status("building the model for the report"):
        cm = build_model(
            scene,
            window_of(wanted),
            on_batch=lambda m: stop_if_spent(budget, m, "building the model for --report"),
        )
    return bind_all(cm, parsed), cm


def _report(
    source: ArrayModel | Scene,
    parsed: list[SpecFile],
    bound: list[BoundProperty],
    results: list[CheckResult],
    report_dir: str,
    path: str,
    frames_dir: str | None,
    started: float,
    scene: Scene | None,
) -> None:
    """Write the results file and draw the report from it (lesmc/report/publish.py)."""
    from rich.console import Console

    from lesmc.model.lts import to_lts
    from lesmc.report.publish import frames_reader, publish
    from lesmc.report.results import DesignRun, provenance
    from lesmc.tracking.scene import Scene

    assert not isinstance(source, Scene)
    err = Console(stderr=True)
    design = str(source.meta.get("design", "model"))
    runs = [DesignRun(design, to_lts(source), bound, results, scene)]
    meta = {"model" if scene is None else "scene": path}
    timings = {"load, build and check": time.monotonic() - started}
    with err.status("writing the report"):
        out, _ = publish(
            runs, report_dir, meta, provenance(parsed), frames_reader(frames_dir), timings
        )
    err.print(f"report: {out}")
