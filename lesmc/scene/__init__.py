"""The scene stage: frames of detections with payoffs, a target, a tracker (docs/scene-format.md).

``frames.py`` holds the detections and their geometry, ``scene.py`` the scene
objects, ``tracker_model.py`` the tracker's linear-Gaussian model, ``io.py`` the
file format, ``toy.py`` hand-made scenes.
"""

from lesmc.scene.frames import (
    Detection,
    Frame,
    OnDemandPayoffs,
    PricedFrame,
    Pricer,
    UnpricedPayoff,
    WatchedFrame,
    lower_frames,
)
from lesmc.scene.io import (
    FORMAT,
    VERSION,
    check_fits,
    footage_from_dict,
    load_scene,
    save_scene,
    scene_from_dict,
    scene_to_dict,
    target_to_dict,
)
from lesmc.scene.scene import (
    UNATTACKABLE,
    UNPRICED,
    Footage,
    JointConfig,
    Scene,
    Target,
    TrackerConfig,
    TruthTrack,
)
from lesmc.scene.tracker_file import load_tracker, tracker_from_dict

__all__ = [
    "FORMAT",
    "UNATTACKABLE",
    "UNPRICED",
    "VERSION",
    "Detection",
    "Footage",
    "Frame",
    "JointConfig",
    "OnDemandPayoffs",
    "PricedFrame",
    "Pricer",
    "Scene",
    "Target",
    "TrackerConfig",
    "TruthTrack",
    "UnpricedPayoff",
    "WatchedFrame",
    "check_fits",
    "footage_from_dict",
    "load_scene",
    "load_tracker",
    "lower_frames",
    "save_scene",
    "scene_from_dict",
    "scene_to_dict",
    "target_to_dict",
    "tracker_from_dict",
]
