"""A scene: frames of detections, where the target's track starts, and the tracker.

A :class:`Footage` is what perception produces once per video (no target);
a :class:`Scene` is footage with a :class:`Target`. Both are immutable: the
variants a verification needs (another tracker design, certified payoffs in
place of the attack's) are new objects.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass, field, fields, replace
from typing import Any, Literal

import numpy as np

from lesmc.common.errors import InputError
from lesmc.scene.frames import Frame, PricedFrame, lower_frames, repriced
from lesmc.scene.tracker_model import (
    DEFAULT_MODEL,
    EntryFault,
    TrackerModel,
    measured,
    state_names,
)

UNATTACKABLE = "unattackable"
"""Payoff marker of a detection the attack could not flip within its iteration cap."""

UNPRICED = "unpriced"
"""Payoff marker of a detection nobody attacked (``lesmc verify`` prices only what its
checks read): ``nan`` in memory; a model that reads it stops (frames.UnpricedPayoff)."""


@dataclass(frozen=True)
class JointConfig:
    """The joint design's own parameters (paper section 7.2; lesmc/tracking/joint.py), apart
    from the parameters every tracker shares. A scene's tracker block and a tracker file
    write them at their top level, under these names."""

    init_radius: float = 150.0  # unassociated detections this close to the primary may start tracks
    init_distance: float = 60.0  # max distance to a previous unassociated detection to start one
    prune_radius: float = 200.0  # refining tracks farther than this from the primary are dropped

    def to_json(self) -> dict[str, Any]:
        """The file form: its keys, in order."""
        return {f.name: getattr(self, f.name) for f in fields(self)}


@dataclass(frozen=True)
class TrackerConfig:
    """The tracker's parameters (paper section 6.7 and 7); defaults are the paper's.

    ``design`` names a tracker of the design registry (lesmc/designs/registry.py);
    ``model`` is the linear-Gaussian model (lesmc/scene/tracker_model.py): a preset
    built from ``sigma_q``, ``sigma_r``, ``P0_sd``, or matrices declared in full
    (then those three are unused).
    """

    design: str = "single"
    sigma_q: float = 3.0  # process noise σ_q of Eq. 17 (the paper's code used 5)
    sigma_r: float = 5.0  # measurement noise σ_r of Eq. 18 (the paper's code used 6)
    P0_sd: tuple[float, ...] = (30.0, 30.0, 20.0, 20.0)  # P0 = diag(P0_sd)², one per component
    gate: float = 2.0  # g of Eq. 19 (Mahalanobis) or k of the Euclidean gate
    gate_type: Literal["mahalanobis", "euclidean"] = "mahalanobis"
    max_trace: float = 1e5  # halt the track when trace(P) exceeds this
    #: the joint design's own parameters (its file keys sit at the top level, here)
    joint: JointConfig = JointConfig()
    # multi-target box trackers (sort; lesmc/tracking/multi.py): SORT's defaults
    min_hits: int = 3  # a track is output once updated this many frames in a row
    max_age: int = 1  # a track missed more than this many frames in a row ends
    iou_threshold: float = 0.3  # a (detection, track) pair is admissible at this IoU or more
    # multi-target point trackers (gnn; lesmc/tracking/gnn.py)
    confirm_window: int = 5  # N of M-of-N: min_hits updates within a track's first N frames
    gate_probability: float = 0.99  # the chi-square gate's probability (2 degrees of freedom)
    model: TrackerModel = DEFAULT_MODEL
    #: the runtime monitor the monitored designs add to properties, as a spec writes it
    #: without ``monitor`` (``"nis 0.99 window 3"``, lesmc/language/monitors.py); None: Eq. 13's
    monitor: str | None = None
    #: matrix faults in force from their frames on (fault variants of lesmc/pipeline/faults.py;
    #: never in a scene file)
    faults: tuple[EntryFault, ...] = ()

    @property
    def state_names(self) -> tuple[str, ...]:
        """The state components' names (a spec's ``on x, y`` refers to them)."""
        return state_names(self.model)

    @property
    def measured(self) -> tuple[int, int]:
        """The state components a detection's x and y measure: the track's position."""
        return measured(self.model)

    def to_json(self) -> dict[str, Any]:
        """The file form; ``model`` is left out when it is the default preset, a
        declared model's unused ``sigma_q``, ``sigma_r`` and ``P0_sd`` are left out, and so
        are the multi-target parameters at their defaults."""
        d: dict[str, Any] = {}
        declared = not isinstance(self.model, str)
        for f in fields(self):
            v = getattr(self, f.name)
            if (
                f.name == "faults"
                or (f.name in MULTI_ONLY and v == f.default)
                or (f.name == "monitor" and v is None)
            ):
                continue
            if f.name == "joint":
                d.update(v.to_json())
            elif f.name == "model":
                if v != DEFAULT_MODEL:
                    d["model"] = v if isinstance(v, str) else v.to_json()
            elif not (declared and f.name in PRESET_ONLY):
                d[f.name] = list(v) if isinstance(v, tuple) else v
        return d


#: The keys of the joint design's parameters in a tracker block (:class:`JointConfig`).
JOINT_KEYS = tuple(f.name for f in fields(JointConfig))


def m_of_n_problem(m: int, n: int) -> str | None:
    """What is wrong with the gnn design's M-of-N confirmation (``min_hits`` M of
    ``confirm_window`` N), if anything: it needs M ≤ N."""
    if m > n:
        return f"min_hits {m} must be at most confirm_window {n} (M of N: M ≤ N)"
    return None


def tracker_keys() -> tuple[str, ...]:
    """The keys of a tracker block, in the order a file writes them: :class:`TrackerConfig`'s
    fields, the joint design's in place of ``joint`` (``faults`` included: never in a file)."""
    out: list[str] = []
    for f in fields(TrackerConfig):
        out.extend(JOINT_KEYS if f.name == "joint" else (f.name,))
    return tuple(out)


#: The parameters only a preset model reads.
PRESET_ONLY = ("sigma_q", "sigma_r", "P0_sd")
#: The parameters only a multi-target tracker reads (written only when not the default).
MULTI_ONLY = ("min_hits", "max_age", "iou_threshold", "confirm_window", "gate_probability")


@dataclass(frozen=True)
class Target:
    """Where the track starts: frame step, position, and (default zero) velocity."""

    step: int
    start: tuple[float, float]
    velocity: tuple[float, float] = (0.0, 0.0)


@dataclass(frozen=True)
class TruthTrack:
    """A ground-truth track of the scene: one vehicle's true position in the frames it is
    in, in each frame's own coordinates (as its detections). The acceptable paths of
    section 4.2 that ``dist.nearest`` measures against (docs/semantics.md)."""

    id: str
    positions: tuple[tuple[int, float, float], ...]  #: (frame step, x, y), by step
    #: each position's box size (w, h) around it (scene format 2; ``import mot --gt`` with
    #: ``--point center``); None: the track has points only
    sizes: tuple[tuple[float, float], ...] | None = None

    def boxes(self) -> dict[int, tuple[float, float, float, float]]:
        """Its boxes [x1, y1, x2, y2] by frame step (empty for a track of points)."""
        if self.sizes is None:
            return {}
        return {
            k: (x - w / 2.0, y - h / 2.0, x + w / 2.0, y + h / 2.0)
            for (k, x, y), (w, h) in zip(self.positions, self.sizes, strict=True)
        }


class _Frames:
    """Frames numbered ``frames[0].step``, ``frames[0].step + 1``, ...: the steps of a video."""

    frames: tuple[Frame, ...]

    def frame(self, step: int) -> Frame:
        return self.frames[step - self.frames[0].step]

    @property
    def last_step(self) -> int:
        return self.frames[-1].step

    @property
    def has_unpriced(self) -> bool:
        """Some detection is unpriced."""
        return any(f.has_unpriced for f in self.frames)

    @property
    def unpriced(self) -> int:
        """How many detections are unpriced (``"unpriced"``: no attack was run on them)."""
        return sum(not d.priced for f in self.frames for d in f.detections)

    def settled(self) -> Any:
        """The same with every payoff priced on demand so far written into its detections
        (plain frames: reading a payoff still unpriced raises UnpricedPayoff)."""
        frames = tuple(
            f.prices.frame(f) if isinstance(f, PricedFrame) and f.prices is not None else f
            for f in self.frames
        )
        return replace(self, frames=frames)  # type: ignore[type-var]

    def payoff_free(self) -> Any:
        """The same with every payoff 1: for what follows only the unattacked outcome (the
        monitor's false alarms, a track's end), whose states never depend on a payoff."""
        return replace(self, frames=repriced(self.frames, lambda _d: 1.0))  # type: ignore[type-var]

    def with_lower(self, lower: Mapping[int, np.ndarray]) -> Any:
        """The same with certified lower payoffs: ``lower[step][i]`` for detection i of
        frame ``step`` (``nan``: none); detections not given keep theirs."""
        return replace(self, frames=lower_frames(self.frames, lower))  # type: ignore[type-var]


@dataclass(frozen=True)
class Footage(_Frames):
    """A scene without a target: what perception produces once per video.

    ``lesmc perceive -o`` without ``--target`` writes one; ``--target X,Y@STEP``
    (lesmc/tracking/targets.py) turns it into a :class:`Scene` per vehicle.
    """

    dt: float
    frames: tuple[Frame, ...]
    tracker: TrackerConfig = field(default_factory=TrackerConfig)
    meta: dict[str, Any] = field(default_factory=dict, compare=False)
    truth: tuple[TruthTrack, ...] = ()  #: ground-truth tracks, if the scene has them

    def with_target(self, target: Target, meta: dict[str, Any] | None = None) -> Scene:
        """The scene tracking from ``target`` (its step must be one of the frames)."""
        info = dict(self.meta) if meta is None else meta
        return Scene(self.dt, self.frames, target, self.tracker, info, self.truth)


@dataclass(frozen=True)
class Scene(_Frames):
    """A validated scene; ``frames[i].step == first_step + i``."""

    dt: float
    frames: tuple[Frame, ...]
    target: Target
    tracker: TrackerConfig = field(default_factory=TrackerConfig)
    meta: dict[str, Any] = field(default_factory=dict, compare=False)
    truth: tuple[TruthTrack, ...] = ()  #: ground-truth tracks, if the scene has them

    @property
    def has_lower(self) -> bool:
        """Every detection carries ``payoff_lower`` (perceive --certify)."""
        return all(d.payoff_lower is not None for f in self.frames for d in f.detections)

    @property
    def any_lower(self) -> bool:
        """Some detection carries ``payoff_lower`` (all of them, or those a model can hide)."""
        return any(d.payoff_lower is not None for f in self.frames for d in f.detections)

    def priced(self, payoffs: str, path: str = "<scene>") -> Scene:
        """The scene whose ``payoff`` column the model uses: ``attack`` or ``certified``.

        ``certified`` puts each detection's ``payoff_lower`` in place of its
        payoff (docs/semantics.md, "Payoff intervals"). A detection without one
        gets 0, the trivial lower bound (sound: no perturbation is cheaper than
        nothing); the check notes how many a model can hide
        (lesmc/pipeline/certify.py). At least one detection must carry a bound,
        unless ``meta["certified"]`` says that a certification found none to certify.
        """
        if payoffs == "attack":
            return self
        if payoffs != "certified":
            raise ValueError(f"unknown payoff column {payoffs!r}")
        if not self.any_lower and "certified" not in self.meta:
            raise InputError.many(path, [(self._first_detection(), _NO_LOWER)])
        frames = repriced(self.frames, lambda d: 0.0 if d.payoff_lower is None else d.payoff_lower)
        return replace(self, frames=frames)

    def _first_detection(self) -> str:
        f = next((f for f in self.frames if f.detections), self.frames[0])
        return f"frame {f.step}" + (f", detection '{f.detections[0].id}'" if f.detections else "")

    def with_tracker(self, **changes: Any) -> Scene:
        """The same scene with some tracker parameters replaced (e.g. design)."""
        return replace(self, tracker=replace(self.tracker, **changes))

    @property
    def footage(self) -> Footage:
        """The scene without its target."""
        return Footage(self.dt, self.frames, self.tracker, self.meta, self.truth)


_NO_LOWER = (
    "payoff_lower is missing (needed by --payoffs certified|interval; write the scene with "
    "`lesmc perceive --certify`, or let `lesmc verify` certify what it needs)"
)
