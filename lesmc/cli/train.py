"""``lesmc train``: train N_dr and N_lp on synthetic video, validate on a held-out one."""

from __future__ import annotations

import click


@click.command("train")
@click.option(
    "--out",
    "out_dir",
    type=click.Path(file_okay=False),
    default="nets",
    show_default=True,
    help="Directory for dr.safetensors, lp.safetensors and nets.json.",
)
@click.option(
    "--frames",
    type=click.IntRange(min=6, max=1000),
    default=16,
    show_default=True,
    help="Frames per training video.",
)
@click.option("--size", "size_text", default="2048x2048", show_default=True, metavar="WxH")
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
    help="Epochs for both networks [default: 8 for N_dr, 10 for N_lp].",
)
def train_cmd(
    out_dir: str, frames: int, size_text: str, seed: int, videos: int, epochs: int | None
) -> None:
    """Train the detection CNNs on `lesmc synth` videos and print held-out metrics.

    The shipped weights were made with the defaults. Point `lesmc perceive
    --nets DIR` at the output to use your own.
    """
    from rich.table import Table

    from lesmc.cli.video import parse_size
    from lesmc.perception.cnn import save_nets
    from lesmc.perception.training import TrainConfig, train
    from lesmc.report.progress import progress_bar
    from lesmc.report.text import make_console

    w, h = parse_size(size_text)
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
    with progress_bar("training", None) as bar:

        def progress(stage: str, done: int, total: int) -> None:
            bar.update(description=stage, completed=done, total=total)

        nets, val = train(cfg, progress)
    save_nets(nets, out_dir)
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
    make_console().print(table)
    click.echo(f"wrote {out_dir}")
