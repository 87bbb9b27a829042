"""The tracker a design unfolds with, set up for a scene.

The design registry (lesmc/designs/registry.py) declares each tracker's class as a
``module:Class`` string, so that naming designs (the command line's choices, the
schemas) imports no tracker; the class is imported here, when a scene is unfolded.
"""

from __future__ import annotations

import importlib
from typing import Any

import numpy as np

from lesmc.common.errors import UsageError
from lesmc.designs import registry
from lesmc.scene import Footage, Scene
from lesmc.tracking.design import Design
from lesmc.tracking.multi import MultiDesign


def tracker_class(design: str) -> Any:
    """The class of the tracker that ``design`` unfolds with (imported now)."""
    module, _, cls = registry.implementation(design).partition(":")
    return getattr(importlib.import_module(module), cls)


def make_tracker(
    scene: Scene,
    inject: bool = False,
    hide: bool = True,
    grid: tuple[np.ndarray, float] | None = None,
) -> Design:
    """The tracker the scene's configuration names, set up for the scene; ``inject``: the
    attacker may also inject the frames' candidates (``allow hide, inject``; a tracker
    whose class does not declare ``injects``, or a multi-target design: a UsageError);
    ``hide``: it may hide detections (False only with ``inject``: ``allow inject``);
    ``grid``: ``inject grid``'s offsets and payoff (a tracker that does not declare
    ``injects_grid``: a UsageError)."""
    design = registry.get(scene.tracker.design)
    if design.multi:
        raise UsageError(
            registry.not_yet(design.name, "this single-target step (e.g. `lesmc alarms`)")
        )
    cls = tracker_class(design.name)
    if not inject and hide:
        made: Design = cls(scene)
        return made
    if not getattr(cls, "injects", False):
        raise UsageError(f"the {design.name} design does not take attack action 'inject'")
    if grid is None:
        made = cls(scene, inject=True, hide=hide)
        return made
    if not getattr(cls, "injects_grid", False):
        raise UsageError(f"the {design.name} design does not take 'inject grid'")
    made = cls(scene, inject=True, hide=hide, grid=grid)
    return made


def make_multi(scene: Scene | Footage, path: str) -> MultiDesign:
    """The multi-target tracker the scene's configuration names, set up for the scene
    (read from ``path``, the name its errors give)."""
    design = registry.get(scene.tracker.design)
    assert design.multi
    made: MultiDesign = tracker_class(design.name)(scene, path)
    return made
