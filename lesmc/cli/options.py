"""Option parsing shared by several verbs."""

from __future__ import annotations

import re
from collections.abc import Callable
from pathlib import Path
from typing import Any, TypeVar

import click

from lesmc.errors import InputError, UsageError
from lesmc.fileio import read_json
from lesmc.model.lts import LTS
from lesmc.model.lts_format import lts_from_dict
from lesmc.tracking.scene import Scene, scene_from_dict

F = TypeVar("F", bound=Callable[..., Any])

#: ``-o/--output`` of the verbs that write a model.
model_output = click.option(
    "-o",
    "--output",
    required=True,
    type=click.Path(dir_okay=False),
    help="The model file to write (.lts).",
)


def design_option(help_text: str) -> Callable[[F], F]:
    """``--design single|joint``, overriding the design a scene names."""
    return click.option(
        "--design", type=click.Choice(["single", "joint"]), default=None, help=help_text
    )


def parse_window(text: str) -> tuple[int, int]:
    """``L..U`` -> (L, U)."""
    m = re.fullmatch(r"\s*(\d+)\s*\.\.\s*(\d+)\s*", text)
    if not m:
        raise UsageError(f"--window must look like L..U (e.g. 6..8), got '{text}'")
    lo, hi = int(m.group(1)), int(m.group(2))
    if lo > hi:
        raise UsageError(f"--window {text}: L must not exceed U")
    return lo, hi


def load_model_or_scene(path: str, design: str | None = None) -> LTS | Scene:
    """A .lts model or a scene, told apart by the file's ``format`` field."""
    data = read_json(Path(path), InputError)
    kind = data.get("format") if isinstance(data, dict) else None
    if kind == "lesmc-scene":
        scene = scene_from_dict(data, path)
        return scene.with_tracker(design=design) if design else scene
    if design:
        raise UsageError("--design applies to scenes, not to .lts models")
    return lts_from_dict(data, path)


def load_scene_file(path: str, design: str | None = None) -> Scene:
    data = read_json(Path(path), InputError)
    scene = scene_from_dict(data, path)
    return scene.with_tracker(design=design) if design else scene
