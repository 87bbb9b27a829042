"""What to verify: a :class:`Job` (the input of :func:`lesmc.pipeline.check.run`).

A job names the properties (spec files), what they are checked on (a .lts
model, or a scene and the designs to unfold it with), the payoff mode, the
engine and one :class:`~lesmc.common.budget.Budget`. Every verb that checks
(check, verify, campaign, the Python API) states its work as a job.
"""

from __future__ import annotations

from collections.abc import Callable, Mapping
from dataclasses import dataclass, field

import numpy as np

from lesmc.common.budget import Budget
from lesmc.engines import payoff_modes
from lesmc.engines import registry as engines
from lesmc.engines.check import DEFAULT_MAX_STATES, EngineName
from lesmc.language.properties import FaultSet, SpecFile
from lesmc.model.arrays import ArrayModel
from lesmc.pipeline.faults import NeuronFrames
from lesmc.scene import Scene

#: ``--payoffs``: which payoffs a scene's model uses, a name of
#: lesmc/engines/payoff_modes.py (docs/semantics.md, "Payoff intervals").
PayoffMode = str

#: Detections to certify (frame step -> detection indices) -> their certified lower payoffs
#: (frame step -> one value per detection of the frame, ``nan`` where none was computed).
Certifier = Callable[[Mapping[int, np.ndarray]], dict[int, np.ndarray]]

#: ``(tracker, window) -> detections the window's model can hide that carry no bound``
#: (-1: not known, the probe stopped), when the caller found them already (campaigns).
Unbounded = Callable[[str, tuple[int, int]], int]


@dataclass(frozen=True)
class Unit:
    """One check: a design, the attack window its properties are moved to (None: their own)
    and a property's name."""

    design: str
    window: tuple[int, int] | None
    prop: str


def no_stage(_text: str) -> None:
    """The default progress callback: says nothing."""


@dataclass(frozen=True)
class Job:
    """A verification to run.

    Give ``model`` (a .lts: checked as it is) or ``scene`` (unfolded with each of
    ``designs``; none: the tracker the scene names, without the monitor). Each
    property is checked in each of ``windows`` (None: its own window) for each
    design, unless ``only`` (property names) or ``wanted`` leaves the unit out.
    ``full_models`` builds each design's whole model first (the report draws it);
    otherwise the engines unfold
    what they visit. ``certify`` (perception's certifier) bounds the detections the
    models can hide when ``payoffs`` is not ``attack``; ``unbounded`` says how many
    of them lack a bound when the caller already probed (a campaign's client).
    ``faults`` (a ``faults`` block, lesmc/pipeline/faults.py) adds, per property, a result
    for every combination of faults the block allows; its neuron faults need
    ``neuron_frames``, the video perceived with their units stuck (``lesmc verify``),
    and in a certified payoff mode ``neuron_certify``, those runs' certifiers.
    ``source`` names the input in messages.
    """

    specs: tuple[SpecFile, ...]
    model: ArrayModel | None = None
    scene: Scene | None = None
    designs: tuple[str, ...] = ()
    windows: tuple[tuple[int, int] | None, ...] = (None,)
    payoffs: PayoffMode = payoff_modes.DEFAULT
    engine: EngineName = engines.DEFAULT
    budget: Budget = field(default_factory=lambda: Budget(max_states=DEFAULT_MAX_STATES))
    only: tuple[str, ...] = ()
    wanted: Callable[[Unit], bool] | None = None
    full_models: bool = False
    certify: Certifier | None = None
    unbounded: Unbounded | None = None
    faults: FaultSet | None = None
    neuron_frames: NeuronFrames | None = None
    neuron_certify: Mapping[frozenset[str], Certifier] | None = None
    source: str = "<scene>"
    on_stage: Callable[[str], None] = no_stage
