"""``lesmc tune``: search a space of tracker and monitor settings for the designs that
verifiably hold, against their false alarms on unattacked tracks (docs/cli.md)."""

from __future__ import annotations

import math
from collections.abc import Callable, Iterable, Sequence
from pathlib import Path
from typing import TYPE_CHECKING, Any

import click

from lesmc.cli.documents import emit
from lesmc.cli.options import (
    DEFAULT_MAX_STATES,
    FiniteRange,
    distinct_files,
    finite_seconds,
    load_scene_file,
    tracker_option,
    video_truth_option,
)
from lesmc.common.errors import UsageError
from lesmc.engines import payoff_modes
from lesmc.engines import registry as engines

if TYPE_CHECKING:
    from lesmc.experiment.false_alarms import TruthStart
    from lesmc.experiment.tune import Group, Outcome, Tuned
    from lesmc.experiment.tune_space import Space
    from lesmc.language.properties import SpecFile
    from lesmc.scene import Scene

#: SOURCE naming the embedded default video (rendered in OUT/video, as lesmc verify).
DEFAULT_VIDEO = "default"


@click.command("tune")
@click.argument("source", required=True, type=click.Path())
@click.argument("specs", nargs=-1, required=False, type=click.Path(dir_okay=False))
@click.option(
    "--space",
    "space_file",
    required=True,
    type=click.Path(dir_okay=False),
    help="The space file (TOML): the trackers, parameters and monitors to try (docs/cli.md).",
)
@click.option(
    "--budget",
    type=FiniteRange(0.0, 1.0),
    default=None,
    help="The false-alarm rate (alarms per step of the unattacked tracks) the best design "
    "may cost [default: the space file's budget, else 0.01].",
)
@click.option(
    "--best-out",
    type=click.Path(dir_okay=False),
    default=None,
    help="Write the best design under --budget as a tracker file (TOML; JSON for .json).",
)
@click.option(
    "--plot",
    type=click.Path(dir_okay=False),
    default=None,
    help="Draw each property's optimum against the false-alarm rate, the front highlighted "
    "(PNG, SVG or PDF by the name's suffix).",
)
@click.option(
    "--steps",
    type=click.IntRange(min=1),
    default=None,
    help="Steps to run the unattacked tracks from the start frame [default: to the last].",
)
@video_truth_option
@click.option(
    "--out",
    "out_dir",
    type=click.Path(file_okay=False),
    default="lesmc-verify",
    show_default=True,
    help="A video's perception cache (OUT/cache, shared with lesmc verify --out OUT).",
)
@click.option(
    "--max-states",
    type=click.IntRange(min=1),
    default=DEFAULT_MAX_STATES,
    show_default=True,
    help="Budget of states expanded per property; past it the property is unknown.",
)
@click.option(
    "--timeout",
    type=FiniteRange(min=0, min_open=True),
    default=None,
    callback=finite_seconds,
    help="Seconds for the checks of one tracker configuration (its monitors together).",
)
@click.option(
    "--workers",
    type=click.IntRange(min=0),
    default=0,
    show_default=True,
    help="Dask worker processes, one tracker configuration each (0: this process).",
)
@click.option(
    "--scheduler",
    default=None,
    metavar="ADDRESS",
    help="A running Dask scheduler to use instead of local workers.",
)
@tracker_option
@click.option("--json", "as_json", is_flag=True, help="Print the lesmc-tune document.")
def tune_cmd(
    source: str,
    specs: tuple[str, ...],
    space_file: str,
    budget: float | None,
    best_out: str | None,
    plot: str | None,
    steps: int | None,
    truth: str | None,
    out_dir: str,
    max_states: int,
    timeout: float | None,
    workers: int,
    scheduler: str | None,
    tracker_file: str | None,
    as_json: bool,
) -> None:
    """Check every design of a space on SOURCE and measure its false alarms.

    \b
    SOURCE is a scene file with truth tracks, or a video (a directory of frames with
    truth.json, perceived as lesmc verify does; payoffs priced when a model reads
    them; "default": the embedded default video in OUT/video, as lesmc verify).
    SPECS default to the paper's robustness and resilience (specs/, as verify).
    A design is a tracker with parameter values and a runtime monitor (or none), as
    the space file declares them. Each is checked exactly on every property of
    SPECS (as lesmc check --design D --tracker T checks it), its monitor run on the
    unattacked tracks started at every moving truth vehicle (as lesmc alarms), and
    its tracking error measured there against the truth. Designs that differ only
    in the monitor share one model. Prints the table, the Pareto front (each
    property's optimum up, false alarms and tracking error down) and the best design
    whose false-alarm rate is within --budget.
    """
    from lesmc.experiment import tune, tune_space

    _refuse_early(bool(workers and scheduler), [source, *specs], space_file, truth,
                  tracker_file, best_out, plot)  # fmt: skip
    specs, parsed = _specs(specs)
    scene, starts, truths, last, space, where = _source(
        source, space_file, truth, out_dir, tracker_file, bool(workers or scheduler)
    )
    if budget is None:
        budget = tune_space.DEFAULT_BUDGET if space.budget is None else space.budget
    all_groups = tune.groups(
        scene, parsed, space, starts, truths, min(last, steps or last), engines.DEFAULT,
        payoff_modes.DEFAULT, max_states, timeout, where,
    )  # fmt: skip
    tuned = _evaluate(all_groups, budget, workers, scheduler)
    checker = _checker(source, specs, truth, out_dir)
    if best_out is not None:
        _write_best(tuned, best_out, scene, checker)
    if plot is not None:
        from lesmc.cli.tune_plot import draw

        draw(tuned.outcomes, budget, plot)
    doc = tune.document(tuned.outcomes, tuned.best, budget, source, space, specs)
    if as_json:
        emit(doc)
        return
    _print(tuned, source, checker, best_out)


def _refuse_early(
    both: bool, sources: list[str], space_file: str, truth: str | None,
    tracker_file: str | None, best_out: str | None, plot: str | None,
) -> None:  # fmt: skip
    """Refuse, before any work, --workers with --scheduler (``both``) and an output that
    names an input (SOURCE, then SPECS) or the other output (writing it would destroy it)."""
    if both:
        raise UsageError("--workers and --scheduler exclude each other")
    inputs = {"SOURCE": sources[0], "--space": space_file, "--truth": truth}
    inputs |= {"--tracker": tracker_file}
    inputs |= {f"SPECS ({i + 1})": s for i, s in enumerate(sources[1:])}
    outputs = {k: v for k, v in (("--best-out", best_out), ("--plot", plot)) if v is not None}
    distinct_files(inputs, outputs)
    if plot is not None and not plot.lower().endswith((".png", ".svg", ".pdf")):
        raise UsageError(
            f"--plot {plot}: the figure's format comes from its name: .png, .svg or .pdf"
        )


def _specs(specs: tuple[str, ...]) -> tuple[tuple[str, ...], tuple[SpecFile, ...]]:
    """The spec files (none: the paper's robustness and resilience, as verify) and parsed."""
    from lesmc.api import load_spec

    if not specs:
        from lesmc.experiment.experiment import bundled_specs

        specs = tuple(str(p) for p in bundled_specs())
    return specs, tuple(load_spec(s) for s in specs)


def _source(
    source: str,
    space_file: str,
    truth: str | None,
    out_dir: str,
    tracker_file: str | None,
    on_dask: bool,
) -> tuple[Scene, list[TruthStart], list[dict[int, tuple[float, float]]], int, Space, str]:
    """SOURCE's scene, starts, their truth, the last step, the space read for its tracker,
    and the name checks give the scene in messages."""
    from lesmc.experiment.tune_space import read_space

    if Path(source).is_file():
        scene, starts, truths, last = _scene_source(source, truth, tracker_file)
        space = read_space(space_file, scene.tracker)
        where = source
    else:
        if on_dask:
            raise UsageError(
                "a video's payoffs are priced in this process when a model reads them: "
                "--workers and --scheduler need a scene file"
            )
        from lesmc.scene.scene import TrackerConfig
        from lesmc.scene.tracker_file import load_tracker

        base = load_tracker(tracker_file) if tracker_file else TrackerConfig()
        read_space(space_file, base)  # its mistakes before the video's perception
        scene, starts, truths, last = _video_source(source, truth, out_dir, tracker_file)
        space = read_space(space_file, scene.tracker)
        where = str(Path(out_dir) / "scene.json")
    return scene, starts, truths, last, space, where


def _scene_source(
    source: str, truth: str | None, tracker_file: str | None
) -> tuple[Scene, list[TruthStart], list[dict[int, tuple[float, float]]], int]:
    """A scene file's scene, the starts of its truth tracks, their truth and the last step."""
    from lesmc.experiment import tune
    from lesmc.experiment.alarms import scene_starts

    if truth is not None:
        raise UsageError("--truth applies to a video, not to a scene")
    scene = _no_monitor(load_scene_file(source, None, None, tracker_file))
    if not scene.truth:
        raise UsageError(f"{source}: the scene has no truth tracks to run unattacked")
    starts, _ids = scene_starts(scene)
    return scene, starts, tune.scene_truth(scene, starts), scene.last_step - scene.target.step


def _video_source(
    source: str, truth: str | None, out_dir: str, tracker_file: str | None
) -> tuple[Scene, list[TruthStart], list[dict[int, tuple[float, float]]], int]:
    """A video's scene (payoffs priced on demand), starts, their truth and the last step."""
    from lesmc.cli.alarms import video_source
    from lesmc.experiment import tune

    default = source == DEFAULT_VIDEO and not Path(source).exists()
    if not default and not Path(source).is_dir():
        raise UsageError(f"{source}: no such video directory or scene file")
    scene, starts, _ids, tfs = video_source(
        None if default else source, truth, out_dir, tracker_file, priced=True, verb="tune"
    )
    return _no_monitor(scene), starts, tune.video_truth_tracks(tfs, starts), len(tfs) - 1


def _no_monitor(scene: Scene) -> Scene:
    """A scene whose tracker declares no monitor: the space's ``[monitor]`` chooses them."""
    if scene.tracker.monitor is not None:
        raise UsageError("the tracker declares a monitor: the space's [monitor] table chooses")
    return scene


def _evaluate(
    all_groups: Sequence[Group], budget: float, workers: int, scheduler: str | None
) -> Tuned:
    """Every group, here (with progress) or on Dask."""
    if workers or scheduler:
        return _on_dask(all_groups, budget, workers, scheduler)
    from lesmc.common.progress import Reporter
    from lesmc.experiment import tune

    with Reporter("tune") as rep:

        def told(i: int, g: Group) -> None:
            label = g.designs[0].label().rsplit(" + ", 1)[0]
            rep.stage(f"checking {label} ({i + 1}/{len(all_groups)})")

        return tune.tune(all_groups, budget, on_group=told)


def _on_dask(
    all_groups: Sequence[Group], budget: float, workers: int, scheduler: str | None
) -> Tuned:
    """:func:`lesmc.experiment.tune.tune` with each group on a Dask worker (the campaign's
    cluster, lesmc/campaign/run.py)."""
    from lesmc.campaign.run import dask_client
    from lesmc.experiment import tune

    client, cluster = dask_client(workers, scheduler)

    def mapper(f: Callable[[Group], list[Outcome]], gs: Sequence[Group]) -> Iterable[list[Outcome]]:
        futures = client.map(f, gs, pure=False)
        return [fut.result() for fut in futures]

    try:
        return tune.tune(all_groups, budget, mapper)
    finally:
        client.close()
        if cluster is not None:
            cluster.close()


def _write_best(tuned: Tuned, path: str, scene: Any, checker: list[str]) -> None:
    """The best design under the budget as a tracker file (none: an error, exit 2)."""
    from lesmc.experiment import tune

    b = tuned.best
    if b is None:
        raise UsageError(
            f"--best-out: no design of the space has at most {tuned.budget:g} false alarms "
            "per step; nothing was written"
        )
    comment = (
        f"lesmc tune: the best design under a false-alarm budget of {tuned.budget:g}\n"
        f"{b.design.label()}: {b.holding} of {len(b.results)} properties hold; "
        f"{b.alarms} false alarms in {b.steps} steps\n"
        f"check it: {_check_command(b, checker, path)}"
    )
    tune.write_tracker(path, b.design.config(scene.tracker), comment)


def _checker(source: str, specs: Sequence[str], truth: str | None, out_dir: str) -> list[str]:
    """The command that checks one design of SOURCE, up to its ``--design`` and
    ``--tracker``: ``lesmc check`` (a scene), ``lesmc verify`` (a video)."""
    if Path(source).is_file():
        return ["lesmc", "check", source, *specs]
    words = ["lesmc", "verify"]
    if not (source == DEFAULT_VIDEO and not Path(source).exists()):  # else verify's default
        words += [source, "--truth", truth or str(Path(source) / "truth.json")]
    words += [w for s in specs for w in ("--spec", s)]
    return [*words, "--out", out_dir]


def _check_command(o: Outcome, checker: list[str], tracker: str) -> str:
    """``checker`` for design ``o`` with its tracker file ``tracker``, quoted for a shell."""
    import shlex

    words = [*checker, "--design", o.design.check_design(), "--tracker", tracker]
    return " ".join(shlex.quote(w) for w in words)


def _optimum(r: Any) -> str:
    if r.optimum is None or not r.optimum_known:
        return "?"
    return "inf" if math.isinf(r.optimum) else f"{r.optimum:.4g}"


def _print(tuned: Tuned, source: str, checker: list[str], best_out: str | None) -> None:
    """The table (front marked *), then the best design under the budget."""
    outs = tuned.outcomes
    if not outs:
        return
    props = [r.property for r in outs[0].results]
    width = max(len(o.design.label()) for o in outs)
    head = f"  {'#':>3}  {'design':<{width}}"
    for p in props:
        head += f"  {p[:30]:>30}"
    head += f"  {'false alarms':>16}  {'track err':>9}"
    click.echo(f"{len(outs)} designs in {tuned.groups} tracker configurations on {source}")
    click.echo(head)
    for i, o in enumerate(outs):
        line = f"{'*' if o.front else ' '} {i:>3}  {o.design.label():<{width}}"
        for r in o.results:
            line += f"  {(r.status + ' ' + _optimum(r))[:30]:>30}"
        err = "—" if o.tracking_error is None else f"{o.tracking_error:.2f}"
        line += f"  {o.alarms:>5}/{o.steps:<5} {o.rate:>5.1%}  {err:>9}"
        click.echo(line)
    click.echo(
        f"* the Pareto front: {sum(o.front for o in outs)} designs (each property's "
        "optimum, fewer false alarms, smaller tracking error)"
    )
    b = tuned.best
    if b is None:
        closest = min(outs, key=lambda o: o.rate)
        click.echo(
            f"no design has at most {tuned.budget:.1%} false alarms; the fewest: "
            f"{closest.design.label()} ({closest.rate:.1%})"
        )
        return
    holds = "every property holds" if b.holding == len(b.results) else (
        f"{b.holding} of {len(b.results)} properties hold: nothing in the space holds "
        "on every property within the budget"
    )  # fmt: skip
    click.echo(f"best under {tuned.budget:.1%} false alarms: {b.design.label()} ({holds})")
    if best_out is not None:
        click.echo(f"  written to {best_out}; check it: {_check_command(b, checker, best_out)}")
