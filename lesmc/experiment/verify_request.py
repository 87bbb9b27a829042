"""What ``lesmc verify`` was asked (:class:`Request`), the scene it checks with what came
with it (:class:`Source`), and the budget's stop between its stages (:func:`spent`):
what every stage of the run (lesmc/experiment/experiment.py) reads.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING, Any

from lesmc.common.budget import Budget
from lesmc.common.errors import BudgetError
from lesmc.designs import registry
from lesmc.experiment.cache import StageCache
from lesmc.experiment.pricing import VideoPricer
from lesmc.experiment.video_perception import UnitMax
from lesmc.perception import NetFiles
from lesmc.pipeline.job import PayoffMode
from lesmc.scene import Footage, OnDemandPayoffs, Scene

if TYPE_CHECKING:  # reading frames imports cv2: only where a video is read
    from lesmc.video.reader import FrameSet


@dataclass(frozen=True)
class Request:
    """What ``lesmc verify`` was asked: a video (``frames_dir``; None: the embedded default)
    or a scene file, the target, the specs (none: the bundled ones), the designs, the
    payoff mode, where to write and the budget."""

    frames_dir: str | None = None
    scene_path: str | None = None
    target: str | None = None
    truth: str | None = None
    specs: tuple[str, ...] = ()
    window: tuple[int, int] | None = None
    designs: tuple[str, ...] = registry.SETS["paper"]
    out: Path = Path("lesmc-verify")
    nets: NetFiles = (None, None, None)  #: ``--nets``, ``--detector``, ``--locator``
    scene_frames: str | None = None  #: with ``scene_path``: the video's frames (replay, images)
    tracker: str | None = None  #: a tracker file replacing the scene's (``--tracker``)
    payoffs: PayoffMode = "attack"
    budget: Budget = field(default_factory=Budget)
    faults: str | None = None  #: a file with a ``faults`` block (``--faults``)
    #: attack every detection of the video up front (``--price-all``), not only those
    #: the checked models read (lesmc/experiment/pricing.py)
    price_all: bool = False
    #: a space file (``--space``): lesmc tune's design search on the video, and the best
    #: design under the file's false-alarm budget (results' ``design_search``)
    space: str | None = None
    #: injection candidates (``--inject-within``, ``--inject-cap``; docs/cnn.md): None:
    #: none; else (px, cap)
    inject: tuple[float, int] | None = None


@dataclass
class Source:
    """The scene to check and what came with it: the video's frames, truth and networks,
    the perception run (for certification), the facts for the results' meta."""

    scene: Scene
    frames: FrameSet | None = None
    truth: Any = None
    nets: Any = None
    run: Any = None
    meta: dict[str, Any] = field(default_factory=dict)
    new: bool = False  #: made by this run: written to OUT/scene.json
    net_files: NetFiles | None = None  #: the networks to load when needed (cached perception)
    truth_path: str | None = None
    cache: StageCache | None = None
    #: verify's own perception of the video: its cache key, each hidden unit's largest
    #: value, the seconds between frames (neuron faults perceive it again)
    perceived: tuple[str, UnitMax, float] | None = None
    #: payoffs priced on demand (lesmc/experiment/pricing.py): the shared prices, the pricer
    #: and the footage they price (stored again in OUT/cache with what was priced)
    pricing: tuple[OnDemandPayoffs, VideoPricer, Footage] | None = None
    #: a detector file's detections: counts, recall and precision, payoffs (detector_verify)
    detections: dict[str, Any] | None = None
    #: every detection certified up front (lesmc/experiment/verify_perception.py decides):
    #: no certifier on demand then
    certified: bool = False

    def networks(self) -> Any:
        """The networks: loaded now if perception came from the cache."""
        if self.nets is None and self.net_files is not None:
            from lesmc.perception.cnn import load_nets

            self.nets = load_nets(*self.net_files)
        return self.nets


def spent(budget: Budget, stage: str) -> None:
    """Stop before a verdict exists (exit 3, nothing written) once the budget is spent."""
    reason = budget.exceeded()
    if reason is not None:
        raise BudgetError(f"{budget.describe(reason)} ran out while {stage}; nothing was written")
