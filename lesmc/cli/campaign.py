"""``lesmc campaign``: every target of some videos over many windows and designs, in parallel."""

from __future__ import annotations

import json
import os
import sys
from collections.abc import Iterator
from contextlib import contextmanager, suppress
from pathlib import Path
from typing import TYPE_CHECKING, Any

import click

from lesmc.cli.options import (
    DEFAULT_MAX_STATES,
    FiniteRange,
    designs_option,
    finite_seconds,
    nets_option,
    network_options,
    payoffs_option,
    spec_option,
    tracker_option,
)
from lesmc.cli.signals import resumable
from lesmc.common.errors import UsageError

if TYPE_CHECKING:
    from lesmc.campaign.summary import Summary
    from lesmc.perception import NetFiles

DEFAULT_WINDOWS = "4..12:1..4"
"""``lesmc.campaign.plan.DEFAULT_WINDOWS``, repeated so that the option's declaration
imports nothing heavy."""


def _cores() -> int:
    try:
        return len(os.sched_getaffinity(0))
    except AttributeError:  # pragma: no cover - not Linux
        return os.cpu_count() or 1


@click.command("campaign")
@click.argument("frames_dirs", nargs=-1, type=click.Path(file_okay=False))
@click.option(
    "--out",
    "out_dir",
    required=True,
    type=click.Path(file_okay=False),
    help="Directory for results.jsonl, scenes/, campaign.html, figures/ (rerun to resume).",
)
@click.option(
    "--targets",
    "targets_text",
    default="10",
    show_default=True,
    metavar="N|all|FILE",
    help="The N best-ranked automatic targets per video, all of them, or a file with one "
    "X,Y@STEP per line ('VIDEO X,Y@STEP' with several videos).",
)
@click.option(
    "--windows",
    "windows_text",
    default=DEFAULT_WINDOWS,
    show_default=True,
    metavar="L1..L2:D1..D2",
    help="Attack windows l..u with l in L1..L2 and u - l in D1..D2 (the paper's: 36).",
)
@designs_option()
@spec_option
@click.option(
    "--workers",
    type=click.IntRange(min=0),
    default=None,
    help="Dask worker processes of the local cluster; 0 runs in this process, one group "
    "after the other (debugging) [default: the cores available].",
)
@click.option(
    "--scheduler",
    default=None,
    metavar="tcp://HOST:PORT",
    help="Run on this Dask cluster (started with `dask scheduler` and `dask worker`) "
    "instead of a local one.",
)
@click.option(
    "--timeout",
    type=FiniteRange(min=0, min_open=True),
    callback=finite_seconds,
    default=60.0,
    show_default=True,
    help="Seconds per result (with --payoffs interval: half for the certified search, the rest "
    "for the attack's); past it the result "
    "is 'unknown' with the bounds found.",
)
@click.option(
    "--max-states",
    type=click.IntRange(min=1),
    default=DEFAULT_MAX_STATES,
    show_default=True,
    help="Budget of expanded states per result; past it the verdict may be 'unknown'.",
)
@click.option(
    "--no-truth",
    is_flag=True,
    help="Find targets from tracks initiated on the detections even where FRAMES_DIR has "
    "a truth.json.",
)
@nets_option
@network_options
@tracker_option
@payoffs_option(
    "",
    " certified|interval first certify every detection the campaign's models can hide "
    "(about a second each; kept in OUT/scenes for reruns).",
)
@click.option("--json", "as_json", is_flag=True, help="Print the summary's numbers as JSON.")
def campaign_cmd(
    frames_dirs: tuple[str, ...],
    out_dir: str,
    targets_text: str,
    windows_text: str,
    design: str,
    specs: tuple[str, ...],
    workers: int | None,
    scheduler: str | None,
    timeout: float,
    max_states: int,
    no_truth: bool,
    nets_dir: str | None,
    detector_file: str | None,
    locator_file: str | None,
    tracker_file: str | None,
    payoffs: str,
    as_json: bool,
) -> None:
    """Verify many targets of each video over the paper's attack windows and designs.

    \b
    Each video (FRAMES_DIR; none: the embedded default, generated into
    OUT/video) is perceived once into OUT/scenes/VIDEO.json, a scene without a
    target (with --detector FILE.toml, through that whole-frame detector, every
    detection priced: docs/detectors.md). Targets come from --targets: automatic
    ones from the video's truth.json when it has one, else from tracks the
    tracker initiates on the detections and keeps through the last window.
    Every (target, window, design, property) is one line of OUT/results.jsonl,
    appended as soon as it is known; a rerun of the same command skips the
    lines already there.
    Each line is reproduced by
      lesmc verify --scene OUT/scenes/VIDEO.json --target X,Y@STEP --window L..U --design D
    (and --payoffs MODE).
    Writes OUT/campaign.html and OUT/figures/campaign_*.png. Exit status:
    0 all hold, 1 some violated, 2 bad input, 3 some unknown, 4 internal error,
    130 interrupted (the lines written are kept).
    """
    from lesmc.api import expand_designs
    from lesmc.campaign.plan import parse_windows

    designs = expand_designs(design, multi=True)
    multi = _multi(designs, payoffs)  # before any work
    limits = _limits(workers, scheduler, timeout, max_states)
    windows = parse_windows(windows_text)
    spec_files = _spec_files(specs, multi)
    out = Path(out_dir)
    count, target_file = _targets_option(targets_text)
    nets = (nets_dir, detector_file, locator_file)
    _check_detector_file(nets, designs if multi else ())
    listed = _file_targets(target_file, _video_names(frames_dirs))
    with _removed_if_empty(out):
        videos = _videos(frames_dirs, out, no_truth)
        out.mkdir(parents=True, exist_ok=True)
        prepared = _prepared(videos, out, nets, tracker_file, payoffs != "attack")
        _choose_targets(prepared, count, listed, windows, not no_truth)
        with resumable(lambda: _kept(out)):
            rows = _run(prepared, spec_files, windows, designs, out, limits, payoffs, nets)
    _finish(rows, out, out_dir, prepared, windows, design, as_json)


def _check_detector_file(nets: NetFiles, multi: tuple[str, ...] = ()) -> None:
    """``--detector FILE.toml``: a detector file replaces the window pipeline's networks
    (--nets and --locator are errors beside it), checked before any video is perceived;
    so is a heatmap file without a box for a multi-target design of ``multi`` that reads
    boxes (sort), as lesmc verify checks it."""
    from lesmc.experiment.detector_verify import detector_file_of, refuse_window_options
    from lesmc.experiment.multi_verify import refuse_points_for_boxes
    from lesmc.perception.detector_file import read_detector_file

    path = detector_file_of(nets)
    if path is not None:
        refuse_window_options(nets, False)
        read_detector_file(path)
        for design in multi:
            refuse_points_for_boxes(path, design)


@contextmanager
def _removed_if_empty(out: Path) -> Iterator[None]:
    """OUT as the run leaves it when it fails: the directories this run created (OUT, its
    subdirectories, the parents ``mkdir`` made for it) are removed again if nothing was
    written in them (only empty directories are ever removed)."""
    top = out.absolute()
    if top.exists():
        yield
        return
    while not top.parent.exists():  # the highest directory this run will create
        top = top.parent
    try:
        yield
    except BaseException:
        with suppress(OSError):  # rmdir fails on a directory that holds anything
            for below, _, _ in os.walk(out, topdown=False):  # children first
                os.rmdir(below)
            up = out.absolute().parent
            while up != top.parent:
                os.rmdir(up)
                up = up.parent
        raise


def _kept(out: Path) -> str:
    """What an interrupted campaign leaves for its rerun: the whole lines of its results
    (counted, not parsed or repaired: the signal's handler writes nothing and cannot
    fail; the rerun repairs a torn last line)."""
    results = out / "results.jsonl"
    kept = results.read_bytes().count(b"\n") if results.exists() else 0
    return f"{kept} results kept in {results} and the scenes in {out / 'scenes'}"


#: Where and how long a campaign runs: --workers, --scheduler, --timeout, --max-states.
Limits = tuple[int | None, str | None, float, int]


def _limits(workers: int | None, scheduler: str | None, timeout: float, max_states: int) -> Limits:
    """The cluster options, checked: --workers sizes a local cluster only."""
    if scheduler is not None and workers is not None:
        raise UsageError("--workers sizes the local cluster: it does not apply with --scheduler")
    return workers, scheduler, timeout, max_states


def _prepared(
    videos: list[Any],
    out: Path,
    nets: NetFiles,
    tracker_file: str | None,
    certified: bool = False,
) -> list[Any]:
    """Each video perceived into OUT/scenes (or read back from there), with the tracker of
    ``tracker_file`` (``--tracker``) as its scene's tracker; ``certified`` (--payoffs
    certified|interval): a detector file that gives no certified bounds is refused."""
    from lesmc.campaign.run import prepare
    from lesmc.scene import load_tracker

    tracker = load_tracker(tracker_file) if tracker_file else None
    if tracker is not None and tracker.monitor is not None:  # it would be ignored
        raise UsageError(
            f"--tracker {tracker_file}: a campaign's monitored designs use Eq. 13's monitor; "
            f"it cannot apply the tracker's monitor ({tracker.monitor}) yet"
        )
    return [prepare(v, out, nets, tracker, certified) for v in videos]


def _multi(designs: tuple[str, ...], payoffs: str) -> bool:
    """Whether the campaign checks a multi-target design (``--design sort|gnn``: on attack
    payoffs only, as lesmc verify checks one)."""
    from lesmc.experiment.multi_verify import multi_designs, refuse_point_options

    multi = bool(multi_designs(designs))
    if multi:
        refuse_point_options(designs[0], payoffs)
    return multi


def _spec_files(specs: tuple[str, ...], multi: bool = False) -> list[Any]:
    """The property files (default: the bundled ones; a multi-target design's:
    specs/identity.spec), each property named once."""
    from lesmc.experiment.experiment import bundled_specs, load_specs
    from lesmc.experiment.multi_verify import identity_specs

    default = identity_specs() if multi else bundled_specs()
    spec_files = load_specs([Path(s) for s in specs] or default, None)
    names = [p.name for s in spec_files for p in s.properties]
    dup = sorted({n for n in names if names.count(n) > 1})
    if dup:
        raise UsageError(f"property name '{dup[0]}' is defined more than once")
    return spec_files


def _videos(frames_dirs: tuple[str, ...], out: Path, no_truth: bool) -> list[Any]:
    """The videos: each FRAMES_DIR (named after its directory), or the embedded default."""
    from lesmc.campaign.run import Video

    if not frames_dirs:
        from lesmc.common.progress import progress_bar
        from lesmc.experiment.default_video import (
            DEFAULT_VIDEO,
            default_video_ready,
            write_default_video,
        )

        video = out / "video"
        if not default_video_ready(video):
            if video.exists() and any(video.iterdir()):
                raise UsageError(f"{video} exists and is not the default video: use another --out")
            with progress_bar("campaign", "rendering", DEFAULT_VIDEO["frames"]) as bar:
                write_default_video(video, bar.advance)
        origin = (
            f"embedded default: lesmc synth {video} --seed {DEFAULT_VIDEO['seed']} "
            f"--frames {DEFAULT_VIDEO['frames']}"
        )
        truth = None if no_truth else video / "truth.json"
        return [Video(DEFAULT_NAME, video, truth, origin)]
    out_v = []
    for d, name in zip(frames_dirs, _video_names(frames_dirs), strict=True):
        p = Path(d)
        truth = p / "truth.json"
        out_v.append(Video(name, p, truth if truth.is_file() and not no_truth else None, d))
    return out_v


#: The name of the embedded default video (no FRAMES_DIR), as a ``--targets`` file names it.
DEFAULT_NAME = "default"


def _video_names(frames_dirs: tuple[str, ...]) -> list[str]:
    """Each video's name: its directory's (``video`` for one without a name), or
    :data:`DEFAULT_NAME` for the embedded default; two of the same name are an error.
    Known before any video is rendered or read, for the ``--targets`` file."""
    if not frames_dirs:
        return [DEFAULT_NAME]
    seen: dict[str, str] = {}
    for d in frames_dirs:
        name = Path(d).resolve().name or "video"
        if name in seen:
            raise UsageError(f"two videos are named '{name}' ({seen[name]} and {d}): rename one")
        seen[name] = d
    return list(seen)


def _targets_option(text: str) -> tuple[int | None, Path | None]:
    """``--targets``: N (> 0), ``all``, or a file."""
    if text == "all":
        return None, None
    if text.isdigit():
        n = int(text)
        if n < 1:
            raise UsageError("--targets N needs N >= 1")
        return n, None
    path = Path(text)
    if not path.is_file():
        raise UsageError(f"--targets must be a number, 'all' or a file; no file '{text}'")
    return None, path


def _file_targets(target_file: Path | None, names: list[str]) -> dict[str, list[Any]] | None:
    """The targets of ``--targets FILE`` by video name (None without a file), read before
    any video is rendered or perceived and before OUT is made, so that a mistake in the
    file costs nothing and leaves nothing behind."""
    from lesmc.campaign.targets import file_targets

    return None if target_file is None else file_targets(target_file, names)


def _choose_targets(
    prepared: list[Any],
    count: int | None,
    by_video: dict[str, list[Any]] | None,
    windows: list[tuple[int, int]],
    use_truth: bool,
) -> None:
    from rich.console import Console

    from lesmc.campaign.targets import auto_targets, check_file_target

    err = Console(stderr=True)
    if by_video is not None:
        for p in prepared:
            for spec, where in by_video[p.video.name]:
                check_file_target(p, spec, where, windows)
                p.targets.append(spec)
                p.origins.append(f"{where.path}:{where.line}")
        return
    for p in prepared:
        with err.status(f"choosing targets of {p.video.name}"):
            found = auto_targets(p, windows, use_truth)
        if not found:
            raise UsageError(
                f"no automatic target in video {p.video.name}: no vehicle is tracked through "
                f"step {max(w[1] for w in windows) + 1}; give --targets FILE or shorter --windows"
            )
        chosen = found if count is None else found[:count]
        p.targets.extend(a.spec for a in chosen)
        p.origins.extend(a.origin for a in chosen)
        err.print(f"{p.video.name}: {len(chosen)} targets ({len(found)} found)")


def _run(
    prepared: list[Any],
    spec_files: list[Any],
    windows: list[tuple[int, int]],
    designs: tuple[str, ...],
    out: Path,
    limits: Limits,
    payoffs: str,
    nets: NetFiles,
) -> list[dict[str, Any]]:
    """Run what is not yet in results.jsonl; return the rows of this campaign."""
    workers, scheduler, timeout, max_states = limits
    from lesmc.campaign.plan import plan_units
    from lesmc.campaign.run import certify_scenes, execute, make_groups
    from lesmc.campaign.store import Appender, read_rows
    from lesmc.common.progress import Reporter

    results = out / "results.jsonl"
    existing = read_rows(results, repair=True)
    done = {str(r["key"]) for r in existing}
    groups, total = make_groups(
        prepared, spec_files, windows, designs, done, timeout, max_states, payoffs
    )
    if payoffs != "attack" and groups:
        groups = certify_scenes(prepared, groups, nets)
    keys = {
        u.key
        for p in prepared
        for t in p.targets
        for us in plan_units(p.key, t, spec_files, windows, designs, payoffs).values()
        for u in us
    }
    docs = {p.doc_key: p.doc for p in prepared}
    todo = sum(len(g.units) for g in groups)
    with (
        Appender(results, done) as app,
        Reporter("campaign") as rep,
        rep.bar("campaign", total) as bar,
    ):
        bar.advance(total - todo)

        def on_rows(rows: list[dict[str, Any]]) -> None:
            for r in rows:
                app.append(r)
            bar.advance(len(rows))

        execute(groups, docs, on_rows, _cores() if workers is None else workers, scheduler)
    seen: set[str] = set()
    mine = []
    for r in read_rows(results):
        if r["key"] in keys and r["key"] not in seen:
            seen.add(r["key"])
            mine.append(r)
    return mine


def _finish(
    rows: list[dict[str, Any]],
    out: Path,
    out_dir: str,
    prepared: list[Any],
    windows: list[tuple[int, int]],
    design: str,
    as_json: bool,
) -> None:
    from lesmc.campaign.summary import figures, summarise, write_html
    from lesmc.results.exit import EXIT_HOLDS, EXIT_UNKNOWN, EXIT_VIOLATED

    scenes = f"{out_dir.rstrip('/')}/scenes"
    summary = summarise(rows, scenes)
    meta = {
        "videos": "; ".join(f"{p.video.name}: {p.video.origin}" for p in prepared),
        "windows": f"{len(windows)} ({windows[0][0]}..{windows[0][1]} to "
        f"{windows[-1][0]}..{windows[-1][1]})",
        "design": design,
        "payoffs": summary.payoffs,
        "results": str(out / "results.jsonl"),
    }
    report = write_html(summary, figures(summary), out, meta)
    if as_json:
        click.echo(json.dumps(summary.to_dict(), indent=1, allow_nan=False))
    else:
        _print(summary)
        click.echo(f"results: {out / 'results.jsonl'}\nreport: {report}")
    verdicts = {r["verdict"] for r in rows}
    sys.exit(
        EXIT_VIOLATED
        if "violated" in verdicts
        else EXIT_UNKNOWN
        if "unknown" in verdicts
        else EXIT_HOLDS
    )


def _print(summary: Summary) -> None:
    from rich.table import Table

    from lesmc.campaign.summary import CELL_HEADER, cell_rows
    from lesmc.designs import registry
    from lesmc.report.text import make_console

    console = make_console()
    table = Table(
        title=f"lesmc campaign: {summary.targets} targets x {summary.windows} windows"
        + ("" if summary.payoffs == "attack" else f", {summary.payoffs} payoffs"),
        title_justify="left",
    )
    for c in (*CELL_HEADER, "median optimum"):
        table.add_column(c, justify="left" if c in ("design", "property") else "right")
    for row in cell_rows(summary, ("median",)):
        table.add_row(*row)
    console.print(table)
    for p, imp in summary.improvements.items():
        for d, v in imp.designs.items():
            console.print(
                f"{p}: {registry.label(d)} removes {v.removed} of the "
                f"{imp.baseline_violated} "
                f"adversarial cases of {registry.label(imp.baseline)} (adds {v.added})"
                + (
                    f"; {v.vacuous} more hold only vacuously (the monitor flags the "
                    "unattacked track too)"
                    if v.vacuous
                    else ""
                )
            )
