"""``lesmc synth``: a synthetic WAMI video and its truth."""

from __future__ import annotations

import re
import time
from pathlib import Path

import click

from lesmc.cli.documents import emit, file_facts, run_provenance, say
from lesmc.cli.options import FiniteRange
from lesmc.common.errors import UsageError, escape_control
from lesmc.video import DEFAULT_DENSITY


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
    type=FiniteRange(min=0.0, max=20.0),
    default=DEFAULT_DENSITY,
    show_default=True,
    help="Vehicles per 100 m of road.",
)
@click.option("--tiff16", is_flag=True, help="Write 16-bit TIFF frames instead of 8-bit PNG.")
@click.option(
    "--json",
    "as_json",
    is_flag=True,
    help="Print what was written as JSON on stdout (format lesmc-synth, schema "
    "lesmc/schemas/synth.json).",
)
def synth_cmd(
    out_dir: str,
    frames: int,
    size_text: str,
    seed: int,
    density: float,
    tiff16: bool,
    as_json: bool,
) -> None:
    """Generate a synthetic WAMI video: frames plus truth.json (vehicles, camera motion).

    Deterministic for a seed. See docs/synthetic.md for what it models and what not.
    Exit status: 0 written, 2 bad input, 4 internal error, 130 interrupted.
    """
    started = time.monotonic()
    from lesmc.common.progress import progress_bar
    from lesmc.video.synth import SynthConfig
    from lesmc.video.write import write_video

    w, h = parse_size(size_text)
    cfg = SynthConfig(
        frames=frames, width=w, height=h, seed=seed, density=density, depth=16 if tiff16 else 8
    )
    with progress_bar("synth", "rendering", frames) as bar:
        paths = write_video(cfg, Path(out_dir), progress=bar.advance)
    say(f"wrote {len(paths)} frames ({w}x{h}) and truth.json to {escape_control(out_dir)}", as_json)
    if as_json:
        truth = Path(out_dir) / "truth.json"
        emit(
            {
                "format": "lesmc-synth",
                "version": 1,
                "provenance": run_provenance({"video": seed}),
                "out_dir": out_dir,
                "frames": [file_facts(p) for p in paths],
                "truth": file_facts(truth),
                "vehicles": _vehicles(truth),
                "width": w,
                "height": h,
                "seed": seed,
                "density": density,
                "bit_depth": cfg.depth,
                "bytes": sum(p.stat().st_size for p in paths) + truth.stat().st_size,
                "seconds": time.monotonic() - started,
            }
        )


def _vehicles(truth: Path) -> int:
    """Distinct vehicle ids in a truth.json this run wrote."""
    import json

    doc = json.loads(truth.read_text(encoding="utf-8"))
    return len({v["id"] for f in doc["frames"] for v in f["vehicles"]})
