"""What the model builder needs from a tracker design, and the factory for the two designs."""

from __future__ import annotations

from dataclasses import dataclass
from typing import Protocol

import numpy as np

from lesmc.tracking.scene import Scene


class TrackerState(Protocol):
    """A tracker state ρ: its estimate (s, P) for the model, identity and halting."""

    @property
    def halted(self) -> bool: ...

    def estimate(self) -> tuple[np.ndarray, np.ndarray]: ...

    def key(self) -> bytes: ...


@dataclass(frozen=True)
class Outcome:
    """A successor of a tracker state: the observation used (None: no update), own payoff."""

    state: TrackerState
    obs: str | None
    payoff: float


class Design(Protocol):
    """A tracker design: an initial state and, per state, the attacker-forced outcomes."""

    name: str
    scene: Scene

    def initial(self) -> TrackerState: ...

    def options(self, st: TrackerState, step: int) -> list[Outcome]: ...

    def unattacked(self, states: list[TrackerState], step: int) -> list[Outcome]:
        """``options(st, step)[0]`` for every state (designs may batch it)."""
        ...


def make_design(scene: Scene) -> Design:
    """The design the scene's tracker configuration names."""
    from lesmc.tracking.joint import JointDesign
    from lesmc.tracking.single import SingleDesign

    if scene.tracker.design == "joint":
        return JointDesign(scene)  # type: ignore[return-value]
    return SingleDesign(scene)  # type: ignore[return-value]


def merge_equal(options: list[Outcome]) -> list[Outcome]:
    """Drop outcomes whose state equals an earlier one's (a costlier way to the same place).

    The dropped payoff is added to the kept outcome just before it, so the
    combined payoff (Eq. 5, sum over lower ranks) of every later outcome is unchanged.
    """
    seen: set[bytes] = set()
    out: list[Outcome] = []
    for o in options:
        key = o.state.key()
        if key in seen:
            prev = out[-1]
            out[-1] = Outcome(prev.state, prev.obs, prev.payoff + o.payoff)
            continue
        seen.add(key)
        out.append(o)
    return out
