"""``lesmc replay RESULTS.json --frames DIR``: counterexamples through the real detector."""

from __future__ import annotations

from typing import TYPE_CHECKING, Any, NoReturn

import click

from lesmc.cli.options import frames_option, nets_option, network_options
from lesmc.cli.signals import resumable
from lesmc.common.errors import UsageError

if TYPE_CHECKING:
    from lesmc.common.progress import Bar
    from lesmc.perception import NetFiles
    from lesmc.replay.run import Outcome
    from lesmc.results.read import ResultsDoc


@click.command("replay")
@click.argument("results", type=click.Path(dir_okay=False, exists=True))
@frames_option(
    "The video's frames (the results' run was made from them) "
    "[default: the frames results.json names]."
)
@click.option(
    "--property",
    "prop",
    default=None,
    metavar="NAME",
    help="Replay only this property's counterexamples [default: every violated property].",
)
@nets_option
@network_options
@click.option("--json", "as_json", is_flag=True, help="Print the replays as JSON (lesmc-replay).")
def replay_cmd(
    results: str,
    frames_dir: str | None,
    prop: str | None,
    nets_dir: str | None,
    detector_file: str | None,
    locator_file: str | None,
    as_json: bool,
) -> None:
    """Replay the counterexamples of RESULTS (results.json of lesmc verify) on the real frames.

    \b
    Each violated property's counterexample: the attack that priced every hidden
    detection is run again, all perturbations of a frame are applied together to
    the detector's inputs of that frame, the real detector (front end, N_dr, N_lp)
    runs on them and the tracker runs over the video. The track is confirmed when
    it takes the same detections as the model's counterexample (within 1 px) and
    stays within 0.5 px of its positions; otherwise the first diverging step and
    the reason are printed (docs/semantics.md, "Replay"); the front end runs with
    the history and delta_bc the results' perception records (the defaults where
    it records none, as said on stderr). With --detector
    FILE.toml (a detector file, docs/detectors.md) the attacks, the perturbed
    frames and the detections go through that file's network instead.
    A multi-target design's results (lesmc-multi-check: verify --design sort|gnn,
    check --design sort|gnn --report DIR):
    the production tracker runs on the replayed detections and the replay is
    confirmed when the property is violated on that run with the model's target
    track ids (docs/trackers.md, "Replaying a multi-target counterexample"); they
    replay through the window pipeline's networks only (a detector file given as
    --detector FILE.toml is refused for them); an injected candidate's N_dr window
    is perturbed until N_dr accepts it; the front end runs with the settings the
    results' perception records (the defaults where it records none, as said on
    stderr).
    A point design's diverged replay whose run violates the property all the same is
    violated "on the frames by another path" (docs/semantics.md). Exit status (the
    verdicts after the replay, as lesmc check): 0 nothing violated, 1 some violation
    confirmed or on the frames, 2 bad input, 3 some replay diverged (unknown) and none
    violated, 4 internal error, 130 interrupted.
    """
    from lesmc.common.progress import deferred_bar
    from lesmc.replay.run import verdict_rows
    from lesmc.replay.scene_match import ResultsMismatch
    from lesmc.results.load import load_results
    from lesmc.results.read import results_of

    raw = load_results(results)
    if raw.get("format") == "lesmc-multi-check":  # verify or check --report, sort|gnn
        _multi(raw, results, frames_dir, prop, (nets_dir, detector_file, locator_file), as_json)
    doc = results_of(raw)
    frames_dir = _frames_of(frames_dir or doc.perception.frames)
    with (
        resumable(lambda: f"nothing: replay writes no file ({results} is unchanged)"),
        deferred_bar("replay", "replaying") as bar,
    ):
        nets = (nets_dir, detector_file, locator_file)
        try:
            outcome = _replay(doc, frames_dir, nets, prop, bar, results)
        except ResultsMismatch as exc:  # a field of the results, located in their file
            raise exc.at(results) from None
    rows, verdicts = verdict_rows(doc, outcome, prop)
    _finish(rows, verdicts, outcome.seconds, results, frames_dir, as_json)


def _frames_of(frames_dir: str | None) -> str:
    """The video's frames directory: --frames DIR, else the one the results name."""
    if frames_dir is None:
        raise UsageError(
            "replay runs the detector on the video: give its frames with --frames DIR (the "
            "results file does not name them)"
        )
    return frames_dir


def _multi(
    doc: dict[str, Any],
    results: str,
    frames_dir: str | None,
    prop: str | None,
    nets: NetFiles,
    as_json: bool,
) -> NoReturn:
    """The replay of a multi-target design's results (lesmc/replay/multi.py), then exit."""
    from lesmc.common.progress import deferred_bar
    from lesmc.experiment.multi_verify import multi_rows, replay_document
    from lesmc.replay.run import frontend_note

    with (
        resumable(lambda: f"nothing: replay writes no file ({results} is unchanged)"),
        deferred_bar("replay", "replaying") as bar,
    ):
        outcome, frames_dir = replay_document(doc, results, frames_dir, nets, prop, bar)
    rows, verdicts = multi_rows(doc, outcome, prop)
    fe = next((r["replay"]["frontend"] for r in rows if "frontend" in r["replay"]), None)
    note = None if fe is None else frontend_note(results, fe)
    if note is not None:  # docs/trackers.md
        click.echo(note, err=True)
    _finish(rows, verdicts, outcome.seconds, results, frames_dir, as_json)


def _finish(
    rows: list[dict[str, Any]],
    verdicts: set[str],
    seconds: float,
    results: str,
    frames_dir: str,
    as_json: bool,
) -> NoReturn:
    """The rows on stdout (a table, or lesmc-replay JSON), then the exit status."""
    import json
    import sys

    if as_json:
        out = {
            "format": "lesmc-replay",
            "version": 1,
            "results": results,
            "frames": frames_dir,
            "seconds": round(seconds, 3),
            "replays": rows,
        }
        click.echo(json.dumps(out, indent=1, allow_nan=False))
    else:
        _table(rows)
    sys.exit(1 if "violated" in verdicts else 3 if "unknown" in verdicts else 0)


def _replay(
    doc: ResultsDoc, frames_dir: str, nets: NetFiles, prop: str | None, bar: Bar, results: str
) -> Outcome:
    """The replay through the window pipeline's networks (lesmc/replay/run.py; a note on
    stderr names the front-end settings ``results`` does not record, as the multi-target
    replay's), or through a detector file given as --detector FILE.toml
    (lesmc/replay/detector_file.py)."""
    from lesmc.perception.detector_file import is_detector_file

    if nets[1] is not None and is_detector_file(nets[1]):
        from lesmc.replay.detector_file import replay_with_file

        return replay_with_file(doc, frames_dir, nets[1], prop, bar)
    from lesmc.replay.run import frontend_note, recorded_frontend, replay_file

    outcome = replay_file(doc, frames_dir, nets, prop, bar)
    fe, recorded = recorded_frontend(doc.perception)  # the front end it ran, as multi says
    used = {"history": fe.history, "delta_bc": fe.blobs.delta_bc, "recorded": recorded}
    note = frontend_note(results, used) if outcome.replays else None
    if note is not None:  # docs/semantics.md, "Replay"
        click.echo(note, err=True)
    return outcome


def _table(rows: list[dict[str, Any]]) -> None:
    from rich.table import Table

    from lesmc.common.errors import escape_text
    from lesmc.report.text import make_console

    console = make_console()
    if not rows:
        console.print("no violated property: nothing to replay")
        return
    table = Table(title="lesmc replay", title_justify="left")
    for c in ("design", "property", "replay", "step", "max error px", "verdict", "reason"):
        table.add_column(c, overflow="fold")
    for r in rows:
        rp = r["replay"]
        colour = "green" if rp["status"] == "confirmed" else "yellow"
        table.add_row(
            escape_text(r["design"]),
            escape_text(r["property"]),
            f"[{colour}]{rp['status']}[/]"
            + (" (repaired)" if rp.get("attack") == "repaired" else ""),
            "-" if rp["step"] is None else str(rp["step"]),
            "-" if rp["max_error_px"] is None else f"{rp['max_error_px']:.3g}",
            r["verdict"],
            escape_text(_reason(rp)),
        )
    console.print(table)


def _reason(rp: dict[str, Any]) -> str:
    """Why the replay diverged, and what its replayed run says of the property (a point
    design's ``on_frames``: violated on the frames by another path, or not)."""
    why = [rp["reason"] or "-"]
    if "on_frames" in rp:
        why.append(rp["on_frames"]["why"])
    return "; ".join(why)
