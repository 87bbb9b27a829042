"""``lesmc synth`` (a synthetic WAMI video) and ``lesmc perceive`` (frames -> detections)."""

from __future__ import annotations

import json
import re
from pathlib import Path
from typing import Any

import click
from rich.table import Table

from lesmc.errors import InputError, Location, UsageError
from lesmc.perception.frontend import FrontEnd, FrontEndConfig
from lesmc.perception.quality import Score, care_mask, load_truth, score
from lesmc.perception.registration import RegistrationError
from lesmc.report.progress import progress_bar
from lesmc.report.text import make_console
from lesmc.video.reader import open_frames
from lesmc.video.synth import SynthConfig, write_video


def parse_size(text: str) -> tuple[int, int]:
    """``WxH`` -> (W, H)."""
    m = re.fullmatch(r"\s*(\d+)\s*[xX]\s*(\d+)\s*", text)
    if not m:
        raise UsageError(f"--size must look like WIDTHxHEIGHT (e.g. 2048x2048), got '{text}'")
    w, h = int(m.group(1)), int(m.group(2))
    if not (64 <= w <= 20000 and 64 <= h <= 20000):
        raise UsageError(f"--size {text}: width and height must be between 64 and 20000")
    return w, h


@click.command("synth")
@click.argument("out_dir", type=click.Path(file_okay=False))
@click.option("--frames", type=click.IntRange(min=1, max=100000), default=30, show_default=True)
@click.option("--size", "size_text", default="2048x2048", show_default=True, metavar="WxH")
@click.option("--seed", type=int, default=1, show_default=True)
@click.option(
    "--density",
    type=click.FloatRange(min=0.0, max=20.0),
    default=SynthConfig.density,
    show_default=True,
    help="Vehicles per 100 m of road.",
)
@click.option("--tiff16", is_flag=True, help="Write 16-bit TIFF frames instead of 8-bit PNG.")
def synth_cmd(
    out_dir: str, frames: int, size_text: str, seed: int, density: float, tiff16: bool
) -> None:
    """Generate a synthetic WAMI video: frames plus truth.json (vehicles, camera motion).

    Deterministic for a seed. See docs/synthetic.md for what it models and what not.
    """
    w, h = parse_size(size_text)
    cfg = SynthConfig(
        frames=frames, width=w, height=h, seed=seed, density=density, depth=16 if tiff16 else 8
    )
    with progress_bar("rendering", frames) as bar:
        paths = write_video(cfg, Path(out_dir), progress=bar.advance)
    click.echo(f"wrote {len(paths)} frames ({w}x{h}) and truth.json to {out_dir}")


@click.command("perceive")
@click.argument("frames_dir", type=click.Path(file_okay=False))
@click.option(
    "--truth",
    type=click.Path(dir_okay=False),
    default=None,
    help="truth.json of the video: print precision, recall, F1 and error.",
)
@click.option(
    "--history",
    type=click.IntRange(min=1, max=16),
    default=4,
    show_default=True,
    help="L, the number of previous frames in the background median.",
)
@click.option(
    "--delta-bc",
    type=click.IntRange(min=1, max=255),
    default=12,
    show_default=True,
    help="Background subtraction threshold (grey levels).",
)
@click.option(
    "--radius",
    type=click.FloatRange(min=0.1),
    default=4.0,
    show_default=True,
    help="Match distance for --truth, pixels.",
)
@click.option(
    "--min-speed",
    type=click.FloatRange(min=0.0),
    default=1.5,
    show_default=True,
    help="Slower vehicles (m/s) are don't care for --truth.",
)
@click.option("--json", "as_json", is_flag=True, help="Print the quality figures as JSON.")
def perceive_cmd(
    frames_dir: str,
    truth: str | None,
    history: int,
    delta_bc: int,
    radius: float,
    min_speed: float,
    as_json: bool,
) -> None:
    """Run the detector front end on FRAMES_DIR (PNG/TIFF/JPEG, natural order).

    Registration (ORB + RANSAC + subpixel refinement), median background of the
    L previous aligned frames, subtraction and blobs: the candidates Q_bc.
    """
    frames = open_frames(frames_dir, history + 1)
    truths = load_truth(truth) if truth else None
    if truths is not None:
        missing = [p.name for p in frames.paths if p.name not in truths]
        if missing:
            raise InputError(f"no truth for frame {missing[0]}", Location(truth or ""))
    from lesmc.perception.blobs import BlobConfig

    fe = FrontEnd(FrontEndConfig(history=history, blobs=BlobConfig(delta_bc=delta_bc)))
    rows: list[dict[str, Any]] = []
    total = Score(0, 0, 0, 0, 0.0)
    with progress_bar("perceiving", len(frames)) as bar:
        for i, img in enumerate(frames):
            try:
                out = fe.push(img)
            except RegistrationError as exc:
                raise InputError(
                    f"cannot register with the previous frame: {exc}",
                    Location(str(frames.paths[i])),
                ) from None
            bar.advance()
            if out is None:
                continue
            row: dict[str, Any] = {
                "frame": frames.paths[i].name,
                "candidates": len(out.candidates),
                "inliers": out.registration.inliers,
                "reg_rms_px": out.registration.rms_px,
            }
            if truths is not None:
                tf = truths[frames.paths[i].name]
                care = care_mask(tf, out.aligned.valid, min_speed)
                sc = score(out.candidates.centroid, tf.positions, care, radius)
                total = total + sc
                row |= sc.to_json()
            rows.append(row)
    if as_json:
        doc: dict[str, Any] = {"frames": rows}
        if truths is not None:
            doc["overall"] = total.to_json()
        click.echo(json.dumps(doc, indent=1))
        return
    _print_quality(rows, total if truths is not None else None)


def _print_quality(rows: list[dict[str, Any]], total: Score | None) -> None:
    console = make_console()
    table = Table(title="front end (candidates Q_bc)")
    cols = ["frame", "candidates", "inliers", "reg_rms_px"]
    if total is not None:
        cols += ["tp", "fp", "fn", "precision", "recall", "f1", "error_px"]
    for c in cols:
        table.add_column(c, justify="left" if c == "frame" else "right")
    for r in rows:
        table.add_row(*(_cell(r[c]) for c in cols))
    if total is not None:
        t = total.to_json()
        table.add_section()
        table.add_row(
            "overall",
            str(sum(r["candidates"] for r in rows)),
            "",
            "",
            *(_cell(t[c]) for c in cols[4:]),
        )
    console.print(table)


def _cell(v: Any) -> str:
    return f"{v:.3f}" if isinstance(v, float) else str(v)
