"""What every verb's ``--json`` shares: one versioned document on stdout, and option checks.

With ``--json`` a verb prints exactly one JSON document on stdout (its
``format`` names the schema ``lesmc/schemas/*.json`` that describes it, see
:data:`lesmc.schemas.SCHEMAS`); everything meant for a human goes to stderr.

Options that would be silently ignored in some combination are errors (exit 2):
:func:`given` tells an option the user typed from one left at its default, so a
default never counts as a conflict.
"""

from __future__ import annotations

import json
import os
from collections.abc import Iterable
from pathlib import Path
from typing import TYPE_CHECKING, Any

import click
from click.core import ParameterSource

from lesmc.common.errors import UsageError, escape_control

if TYPE_CHECKING:
    from lesmc.model.arrays import ArrayModel
    from lesmc.model.multi import MultiModel
    from lesmc.scene import Scene


def emit(doc: dict[str, Any]) -> None:
    """Print ``doc`` as the command's one JSON document on stdout (NaN and inf refused)."""
    click.echo(json.dumps(doc, indent=1, allow_nan=False))


def say(text: str, as_json: bool) -> None:
    """A line for a human: on stdout, or on stderr when stdout carries the JSON document."""
    click.echo(text, err=as_json)


def file_facts(path: str | Path) -> dict[str, Any]:
    """``{"path": ..., "bytes": ...}`` of a file this run wrote."""
    return {"path": str(path), "bytes": os.stat(path).st_size}


def run_provenance(seeds: dict[str, Any] | None = None) -> dict[str, Any]:
    """Tool version, Python, command line, date and seeds (as in results files)."""
    from lesmc.results.document import provenance

    doc = provenance([], seeds=seeds)
    del doc["specs"]
    return doc


def given(name: str) -> bool:
    """True when the current command's option ``name`` (its Python name) was given by the
    user (command line or environment), not left at its default."""
    ctx = click.get_current_context()
    source = ctx.get_parameter_source(name)
    return source in (ParameterSource.COMMANDLINE, ParameterSource.ENVIRONMENT)


def flag(name: str) -> str:
    """The option's spelling on the command line (``--max-iter`` for ``max_iter``)."""
    ctx = click.get_current_context()
    for p in ctx.command.params:
        if p.name == name and isinstance(p, click.Option):
            longs = [o for o in p.opts if o.startswith("--")]
            return (longs or p.opts)[0]
    return "--" + name.replace("_", "-")


def refuse_given(names: Iterable[str], why: str) -> None:
    """Exit 2 naming the first of ``names`` the user gave: ``--X <why>``."""
    for n in names:
        if given(n):
            raise UsageError(f"{flag(n)} {why}")


def unattacked_warnings(scene: Scene, design: str | None = None) -> list[str]:
    """Signs that the scene's unattacked track does not follow its target
    (lesmc/tracking/monitor.py: follow_warnings), run with tracker ``design`` (default:
    the scene's own)."""
    from lesmc.designs import registry
    from lesmc.tracking.monitor import follow_warnings, track
    from lesmc.tracking.trackers import make_tracker

    sc = scene if design is None else scene.with_tracker(design=registry.get(design).tracker)
    if registry.get(sc.tracker.design).multi:  # tracks every object: no one track to follow
        return []
    if sc.has_unpriced:  # the unattacked states never depend on a payoff
        sc = sc.payoff_free()
    tracker = make_tracker(sc)
    return follow_warnings(tracker, track(tracker))


def print_warnings(warnings: Iterable[str], err: bool = False) -> None:
    """Each warning on a line of its own, ``warning: ...`` (on stderr if ``err``)."""
    for w in warnings:
        click.echo(f"warning: {escape_control(w)}", err=err)


def build_document(
    scene: str,
    output: str,
    model: ArrayModel | MultiModel,
    sha256: str,
    sc: Scene,
    window: tuple[int, int],
    seconds: dict[str, float],
) -> dict[str, Any]:
    """``lesmc build --json``: what was built (format lesmc-build, schemas/build.json);
    ``sha256``: the model's (a single-target model's hash, a multi-target model file's)."""
    return {
        "format": "lesmc-build",
        "version": 1,
        "provenance": run_provenance(),
        "scene": scene,
        "model": file_facts(output),
        "model_sha256": sha256,
        "states": model.n_states,
        "transitions": model.n_transitions,
        "end": model.end,
        "window": [window[0], window[1]],
        "design": model.meta["design"],
        "target": {
            "step": sc.target.step,
            "x": float(sc.target.start[0]),
            "y": float(sc.target.start[1]),
        },
        "seconds": seconds,
    }
