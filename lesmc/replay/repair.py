"""The repaired attack's rounds, for every replay (docs/semantics.md, "Repaired attack").

When a frame's perturbations, applied together, do not leave the detections the model
has (a hidden detection survives, an extra one appears, an injected candidate is not
detected), the replay repairs the attack: round after round, on the frame as every
perturbation so far leaves it, the detections the model does not have are attacked
away, then the injected candidates that are not detected are attacked towards a
detection, the frame detected again after each. :func:`run_repair` is that loop and its
bookkeeping (``FrameAttack.repaired_rounds``, ``extra_cost``, ``extra_windows``); a
:class:`Repairable` says what is wrong with a frame and attacks it, through the window
pipeline's detector (lesmc/replay/perturbed.py) or a detector file
(lesmc/replay/detector_file.py).
"""

from __future__ import annotations

from typing import TYPE_CHECKING, Protocol, TypeVar

if TYPE_CHECKING:
    from lesmc.perception.attacks import Towards
    from lesmc.replay.case import FrameAttack

#: What a repair round's perturbations are, as the detector that applies them has them.
P = TypeVar("P")


class Repairable(Protocol[P]):
    """One attacked frame as a repair sees it: the frame as its perturbations leave it."""

    def wrong(self) -> bool:
        """Whether the frame's detections are not the model's: a detection it does not
        have (a hidden one that survives, an extra one), or an injected candidate that is
        not detected."""
        ...

    def attack(self, towards: Towards) -> tuple[float, int, P] | None:
        """On the frame as it is now: ``hide``, every detection the model does not have
        attacked away; ``inject``, every injected candidate not detected attacked towards
        a detection. The cost, the number of windows (or detections) and the
        perturbations of the attacks that succeed alone (None: nothing to attack, or no
        attack succeeds)."""
        ...

    def apply(self, more: P) -> None:
        """``more`` added to the frame's perturbations; the frame detected again and
        compared with the clean one (the :class:`FrameAttack`'s diagnosis)."""
        ...


def run_repair(fa: FrameAttack, frame: Repairable[P], limit: int) -> None:
    """Repair ``frame``'s attack in up to ``limit`` rounds: each round attacks what is
    wrong (``hide`` then ``inject``, each applied and the frame detected again before the
    next); a round in which no attack succeeds ends the repair and is not counted, as
    does a frame with nothing wrong. Records the rounds and the cost of the extra
    perturbations (each extra one at its own norm) and their number into ``fa``."""
    rounds = 0
    while rounds < limit and frame.wrong():
        hid = _step(fa, frame, "hide")
        injected = _step(fa, frame, "inject")
        if not hid and not injected:  # a round that changes nothing is not counted
            break
        rounds += 1
    fa.repaired_rounds = rounds


def _step(fa: FrameAttack, frame: Repairable[P], towards: Towards) -> bool:
    """One step of a repair round: ``frame``'s attack ``towards``, applied, its cost added
    to ``fa.extra_cost`` and its windows to ``fa.extra_windows``; whether it succeeded."""
    got = frame.attack(towards)
    if got is None:
        return False
    cost, windows, more = got
    fa.extra_cost += cost
    fa.extra_windows += windows
    frame.apply(more)
    return True
