"""Option parsing shared by several verbs.

Every ``lesmc/cli`` module imports at module level only what its option
declarations need (click, the standard library, lesmc.errors): the rest is
imported inside the command, so that ``lesmc --help`` and the light verbs do
not pay for numpy, torch, cv2, matplotlib or scipy (tests/test_startup.py).
"""

from __future__ import annotations

import re
from collections.abc import Callable
from pathlib import Path
from typing import TYPE_CHECKING, Any, TypeVar

import click

from lesmc.errors import InputError, UsageError
from lesmc.fileio import read_json

if TYPE_CHECKING:
    from lesmc.model.arrays import ArrayModel
    from lesmc.tracking.scene import Scene

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


def target_option(help_text: str) -> Callable[[F], F]:
    """``--target X,Y@STEP``: where the tracked vehicle starts, overriding a scene's own."""
    return click.option(
        "--target", "target_text", default=None, metavar="X,Y[@STEP]", help=help_text
    )


#: ``--target`` of the verbs that read a scene.
scene_target = target_option(
    "Track the vehicle at X,Y of frame STEP [default: the first], overriding the scene's "
    "target (needed when the scene has none)."
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


def load_model_or_scene(
    path: str, design: str | None = None, target: str | None = None
) -> ArrayModel | Scene:
    """A .lts model or a scene, told apart by the file's ``format`` field."""
    from lesmc.model.lts_format import lts_from_dict

    data = read_json(Path(path), InputError)
    kind = data.get("format") if isinstance(data, dict) else None
    if kind == "lesmc-scene":
        return _scene(data, path, design, target)
    if design:
        raise UsageError("--design applies to scenes, not to .lts models")
    if target:
        raise UsageError("--target applies to scenes, not to .lts models (built for one target)")
    return lts_from_dict(data, path)


def load_scene_file(path: str, design: str | None = None, target: str | None = None) -> Scene:
    """A scene file; ``target`` (``X,Y@STEP``) overrides or supplies its target."""
    return _scene(read_json(Path(path), InputError), path, design, target)


def _scene(data: Any, path: str, design: str | None, target: str | None) -> Scene:
    from lesmc.tracking.scene import footage_from_dict
    from lesmc.tracking.targets import parse_target, place_target

    footage, own = footage_from_dict(data, path)
    if target is not None:
        scene = place_target(footage, parse_target(target))
    elif own is None:
        raise UsageError(f"{path} has no target: give --target X,Y@STEP")
    else:
        scene = footage.with_target(own, footage.meta)
    return scene.with_tracker(design=design) if design else scene
