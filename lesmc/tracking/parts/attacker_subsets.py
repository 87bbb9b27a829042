"""The attacker's options for multi-target trackers (``sort``, ``gnn``): the subset view of
the threat model of lesmc/tracking/parts/attacker.py (the two modules are one part;
docs/trackers.md, "Parts").

At an attacked step the attacker hides any subset of the frame's attackable detections
(:func:`attackable`: payoff finite, and ``within R`` of the target's reference), at the
sum of their payoffs: :func:`hidden_subsets` (``(frame, attacked, can) -> iterator of
index tuples``, the empty one first), :func:`subset_count` and :func:`subset_cost`
(``(payoffs (z,), subset) -> float``). With ``allow hide, inject`` (issue 61) it also
adds any subset of the frame's injection candidates (scene format 3) at their payoffs:
:func:`injected_subsets`, and :func:`subset_options` / :func:`option_count` (``(frame,
attacked, actions, can)``) combine both. lesmc/unfold/multi.py merges the options that
lead to the same successor.
"""

from __future__ import annotations

import itertools
import math
from collections.abc import Iterator

import numpy as np

from lesmc.common.errors import BudgetError
from lesmc.scene import Frame

#: (states × candidate subsets) one attacked step under inject may build at most: past it
#: the step is a BudgetError (exit 3) before any subset is listed, not a memory blow-up
MAX_INJECT_ROWS = 1 << 20


def within_inject_budget(states: int, candidates: int, step: int) -> None:
    """A BudgetError unless ``states`` joint states × every subset of ``candidates``
    injection candidates fit in :data:`MAX_INJECT_ROWS` (checked before listing any)."""
    if candidates >= 64 or states << candidates > MAX_INJECT_ROWS:
        raise BudgetError(
            f"frame {step}: the joint design under inject would build {states} state(s) × "
            f"2^{candidates} subsets of the frame's injection candidates (more than "
            f"{MAX_INJECT_ROWS:,}); offer fewer candidates a frame (perceive --inject-cap N)"
        )


def attackable(frame: Frame, ref: np.ndarray | None, radius: float | None) -> np.ndarray:
    """Which of the frame's detections a multi-target tracker's attacker may hide: those
    of finite payoff and, with ``attack window L..U within R`` (``radius`` R), whose
    position lies within R px of the centre of the target's reference box ``ref``
    [x1, y1, x2, y2] (none where the reference does not exist). Injection candidates are
    not limited by R: the scene places them."""
    can = np.array([not math.isinf(d.payoff) for d in frame.detections], dtype=bool)
    if radius is None or not len(can):
        return can
    if ref is None:
        return np.zeros(len(can), dtype=bool)
    c = np.array([(ref[0] + ref[2]) / 2.0, (ref[1] + ref[3]) / 2.0])
    near: np.ndarray = can & (np.hypot(*(frame.positions() - c).T) <= radius)
    return near


def hidden_subsets(
    frame: Frame, attacked: bool, can: np.ndarray | None = None
) -> Iterator[tuple[int, ...]]:
    """The subsets of the frame's detections the attacker may hide (indices), the empty
    one (unattacked) first: every subset of the attackable ones (``can``, default
    :func:`attackable` without a radius) when ``attacked``."""
    if not attacked:
        yield ()
        return
    mask = attackable(frame, None, None) if can is None else can
    idx = np.nonzero(mask)[0].tolist()
    for r in range(len(idx) + 1):
        yield from itertools.combinations(idx, r)


def subset_count(frame: Frame, attacked: bool, can: np.ndarray | None = None) -> int:
    """How many subsets :func:`hidden_subsets` yields, counted without listing them."""
    mask = attackable(frame, None, None) if can is None else can
    return 2 ** int(mask.sum()) if attacked else 1


def subset_cost(payoffs: np.ndarray, subset: tuple[int, ...]) -> float:
    """What hiding the detections ``subset`` costs: the sum of their ``payoffs``."""
    return math.fsum(payoffs[list(subset)]) if subset else 0.0


def injected_subsets(frame: Frame, attacked: bool) -> Iterator[tuple[int, ...]]:
    """The subsets of the frame's injection candidates the attacker may inject (indices
    into its candidates), the empty one first: every subset when ``attacked``."""
    if not attacked:
        yield ()
        return
    for r in range(len(frame.candidates) + 1):
        yield from itertools.combinations(range(len(frame.candidates)), r)


def subset_options(
    frame: Frame, attacked: bool, actions: tuple[str, ...], can: np.ndarray | None = None
) -> list[tuple[int, ...]]:
    """Every option of a multi-target tracker's attacker taking ``actions``
    (lesmc/language/actions.py) at the frame, the unattacked one first: the detections
    hidden (indices i < n into ``can``, the attackable ones, n the frame's detections),
    then the candidates injected (n + j for candidate j)."""
    n = len(frame.detections)
    inject = attacked and "inject" in actions
    added = [tuple(n + j for j in s) for s in injected_subsets(frame, inject)]
    hidden = hidden_subsets(frame, attacked and "hide" in actions, can)
    return [h + a for h in hidden for a in added]


def option_count(
    frame: Frame, attacked: bool, actions: tuple[str, ...], can: np.ndarray | None = None
) -> int:
    """How many options :func:`subset_options` lists, counted without listing them."""
    adds = 2 ** len(frame.candidates) if attacked and "inject" in actions else 1
    return subset_count(frame, attacked and "hide" in actions, can) * adds
