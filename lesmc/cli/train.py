"""``lesmc train``: train N_dr and N_lp on synthetic video, validate on a held-out one."""

from __future__ import annotations

import time
from pathlib import Path
from typing import TYPE_CHECKING, Any

import click

from lesmc.cli.documents import emit, file_facts, run_provenance, say
from lesmc.common.errors import UsageError, escape_control
from lesmc.common.files import file_sha256

if TYPE_CHECKING:
    from rich.table import Table

    from lesmc.perception.cnn import Nets
    from lesmc.perception.training import TrainConfig, Validation


@click.command("train")
@click.option(
    "--kind",
    type=click.Choice(["windows", "heatmap"]),
    default="windows",
    show_default=True,
    help="windows: N_dr and N_lp of lesmc's own pipeline; heatmap: a small fully "
    "convolutional heatmap detector and its detector file (docs/detectors.md).",
)
@click.option(
    "--out",
    "out_dir",
    type=click.Path(file_okay=False),
    default="nets",
    show_default=True,
    help="Directory for dr.safetensors, lp.safetensors and nets.json "
    "(--kind heatmap: heatmap.onnx and heatmap.toml).",
)
@click.option(
    "--frames",
    type=click.IntRange(min=6, max=1000),
    default=16,
    show_default=True,
    help="Frames per training video.",
)
@click.option(
    "--size",
    "size_text",
    default=None,
    metavar="WxH",
    help="Frame size of the videos [default: 2048x2048; --kind heatmap: 384x384, "
    "which is also the heatmap network's input size].",
)
@click.option(
    "--seed",
    type=int,
    default=0,
    show_default=True,
    help="Seed of the training itself; videos use seeds 101, 102 (train) and 103 (validation).",
)
@click.option(
    "--videos",
    type=click.IntRange(min=1, max=50),
    default=2,
    show_default=True,
    help="Number of training videos.",
)
@click.option(
    "--epochs",
    type=click.IntRange(min=1, max=1000),
    default=None,
    help="Epochs for both networks [default: 8 for N_dr, 10 for N_lp; --kind heatmap: 150].",
)
@click.option(
    "--json",
    "as_json",
    is_flag=True,
    help="Print the run as JSON on stdout (format lesmc-train, schema "
    "lesmc/schemas/train.json): settings, seeds, held-out metrics, files and their sha256.",
)
def train_cmd(
    kind: str,
    out_dir: str,
    frames: int,
    size_text: str | None,
    seed: int,
    videos: int,
    epochs: int | None,
    as_json: bool,
) -> None:
    """Train the detection CNNs on `lesmc synth` videos and print held-out metrics.

    The shipped weights were made with the defaults. Point `lesmc perceive
    --nets DIR` at the output to use your own. With `--kind heatmap`, a heatmap
    detector for `lesmc perceive FRAMES --detector DIR/heatmap.toml` (the shipped
    examples/detectors/heatmap.toml was made with the defaults). Exit status: 0
    written, 2 bad input, 4 internal error, 130 interrupted.
    """
    started = time.monotonic()
    from rich.console import Console

    from lesmc.cli.video import parse_size
    from lesmc.common.progress import progress_bar
    from lesmc.perception.cnn import save_nets
    from lesmc.perception.training import TrainConfig, train
    from lesmc.report.text import make_console

    if kind == "heatmap":
        _train_heatmap(out_dir, frames, size_text, seed, videos, epochs, as_json)
        return
    w, h = parse_size(size_text or "2048x2048")
    cfg = TrainConfig(
        train_seeds=tuple(101 + i for i in range(videos)),
        val_seed=101 + videos,
        frames=frames,
        width=w,
        height=h,
        seed=seed,
        epochs_dr=epochs or TrainConfig.epochs_dr,
        epochs_lp=epochs or TrainConfig.epochs_lp,
    )
    with progress_bar("train", "training", None) as bar:

        def progress(stage: str, done: int, total: int) -> None:
            bar.update(description=stage, completed=done, total=total)

        nets, val = train(cfg, progress)
    trained = time.monotonic()
    save_nets(nets, out_dir)
    (Console(stderr=True) if as_json else make_console()).print(_table(cfg, val))
    say(f"wrote {escape_control(out_dir)}", as_json)
    if as_json:
        seconds = {"training": trained - started, "total": time.monotonic() - started}
        emit(_document(out_dir, cfg, nets, val, seconds))


def _train_heatmap(
    out_dir: str,
    frames: int,
    size_text: str | None,
    seed: int,
    videos: int,
    epochs: int | None,
    as_json: bool,
) -> None:
    """``lesmc train --kind heatmap``: train, validate, write the network and its file."""
    from rich.table import Table

    from lesmc.cli.video import parse_size
    from lesmc.common.progress import progress_bar
    from lesmc.perception.heatmap_training import HeatmapTrainConfig, export, fit, validate
    from lesmc.perception.threads import fit_torch_threads
    from lesmc.report.text import make_console

    if as_json:  # schemas/train.json describes the window networks' run
        raise UsageError("--json: not available with --kind heatmap yet")
    w, h = parse_size(size_text or "384x384")
    if w % 4 or h % 4:
        raise UsageError(f"--size: {w}x{h}: width and height must be multiples of 4 (the stride)")
    cfg = HeatmapTrainConfig(
        train_seeds=tuple(101 + i for i in range(videos)),
        val_seed=101 + videos,
        frames=frames,
        width=w,
        height=h,
        seed=seed,
        epochs=epochs or HeatmapTrainConfig.epochs,
    )
    fit_torch_threads()
    with progress_bar("train", "training", None) as bar:

        def progress(stage: str, done: int, total: int) -> None:
            bar.update(description=stage, completed=done, total=total)

        net = fit(cfg, progress)
    val = validate(net, cfg)
    history = (
        f"lesmc train --kind heatmap --frames {frames} --size {w}x{h} --seed {seed} "
        f"--videos {videos} --epochs {cfg.epochs}: synth seeds {list(cfg.train_seeds)}; "
        f"held-out seed {cfg.val_seed}: recall {val.recall:.3f}, precision {val.precision:.3f}"
    )
    files = export(net, cfg, Path(out_dir), history)
    table = Table(title=f"held-out validation (video seed {cfg.val_seed}, {cfg.radius:g} px)")
    for c in ("network", "frames", "vehicles", "detections", "precision", "recall"):
        table.add_column(c, justify="left" if c == "network" else "right")
    table.add_row("heatmap", str(val.frames), str(val.vehicles), str(val.detections),
                  f"{val.precision:.3f}", f"{val.recall:.3f}")  # fmt: skip
    make_console().print(table)
    say(f"wrote {escape_control(str(files[0]))}", False)


def _table(cfg: TrainConfig, val: Validation) -> Table:
    """The held-out metrics of both networks."""
    from rich.table import Table

    table = Table(title=f"held-out validation (video seed {cfg.val_seed})")
    for c in ("network", "samples", "accuracy", "precision", "recall"):
        table.add_column(c, justify="left" if c == "network" else "right")
    table.add_row(
        "N_dr",
        str(val.samples_dr),
        f"{val.dr_accuracy:.3f}",
        f"{val.dr_precision:.3f}",
        f"{val.dr_recall:.3f}",
    )
    table.add_row(
        "N_lp (peaks, 3 px)",
        str(val.samples_lp),
        "",
        f"{val.lp_precision:.3f}",
        f"{val.lp_recall:.3f}",
    )
    return table


def _document(
    out_dir: str, cfg: TrainConfig, nets: Nets, val: Validation, seconds: dict[str, float]
) -> dict[str, Any]:
    """``lesmc train --json`` (format lesmc-train, schemas/train.json)."""
    files = [Path(out_dir) / n for n in ("dr.safetensors", "lp.safetensors", "nets.json")]
    seeds = {
        "training": cfg.seed,
        "train_videos": list(cfg.train_seeds),
        "validation": cfg.val_seed,
    }
    return {
        "format": "lesmc-train",
        "version": 1,
        "provenance": run_provenance(seeds),
        "out_dir": out_dir,
        "files": [file_facts(p) | {"sha256": file_sha256(p)} for p in files],
        "settings": {
            "frames": cfg.frames,
            "width": cfg.width,
            "height": cfg.height,
            "videos": len(cfg.train_seeds),
            "epochs_dr": cfg.epochs_dr,
            "epochs_lp": cfg.epochs_lp,
            "batch": cfg.batch,
            "learning_rate": cfg.lr,
            "delta_dr": nets.settings.delta_dr,
            "delta_lp": nets.settings.delta_lp,
            "m": nets.settings.m,
            "trained_on": nets.settings.trained_on,
        },
        "validation": {
            "video_seed": cfg.val_seed,
            "dr": {
                "samples": val.samples_dr,
                "accuracy": val.dr_accuracy,
                "precision": val.dr_precision,
                "recall": val.dr_recall,
            },
            "lp": {
                "samples": val.samples_lp,
                "precision": val.lp_precision,
                "recall": val.lp_recall,
            },
        },
        "seconds": seconds,
    }
