"""The tracker a design unfolds with, set up for a scene.

The design registry (lesmc/designs/registry.py) declares each tracker's class as a
``module:Class`` string, so that naming designs (the command line's choices, the
schemas) imports no tracker; the class is imported here, when a scene is unfolded.
"""

from __future__ import annotations

import importlib

from lesmc.designs import registry
from lesmc.scene import Scene
from lesmc.tracking.design import Design


def tracker_class(design: str) -> type[Design]:
    """The class of the tracker that ``design`` unfolds with (imported now)."""
    module, _, cls = registry.implementation(design).partition(":")
    found: type[Design] = getattr(importlib.import_module(module), cls)
    return found


def make_tracker(scene: Scene) -> Design:
    """The tracker the scene's configuration names, set up for the scene."""
    made: Design = tracker_class(scene.tracker.design)(scene)  # type: ignore[call-arg]
    return made
