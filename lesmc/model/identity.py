"""Identity measures of multi-target designs, as per-transition contributions
(docs/trackers.md, "The multi-target model"; the kernel sums them over a step range).

``switches(a..b)``: the number of steps k in a..b at which the target's track exists and
its id differs from its id at the last earlier step (from step 0) at which it existed.
A path's count is a sum of per-transition contributions, as the kernel's other sums
(lesmc/model/kernel.py), once each state carries ``last``: the id of the target's track
at the last step up to it at which it existed (−1: none yet). The transition entering
step k from a state with ``last`` to one whose target's track id is ``tid`` (−1: none)
adds 1 when k is in a..b, ``tid`` ≥ 0, ``last`` ≥ 0 and ``tid`` ≠ ``last``; the entered
state's ``last`` is ``tid`` if ≥ 0, else ``last``. ``last`` is part of the state (two
states that differ only in it do not merge), so the sum is exact on a merged model.

``lost(a..b)``: the steps k in a..b at which the target's reference exists and no output
track matches it: the transition entering k adds 1 when the entered state has the
reference (``ref``) and no target's track.

The target's track of a state (:func:`target_track`): the output (confirmed) track of
largest IoU ≥ :data:`TARGET_IOU` with the reference box, the lower id of equals.
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np

from lesmc.language import measures
from lesmc.language.measures.identity import NONE

__all__ = ["NONE", "TARGET_IOU", "indicators", "last_seen", "switches", "target_track"]

#: The IoU an output track needs with the target's reference box to be the target's track.
TARGET_IOU = 0.5


def target_track(
    score: np.ndarray, ids: np.ndarray, confirmed: np.ndarray, floor: float = TARGET_IOU
) -> int:
    """The target's track id among tracks ``ids`` (n,) whose IoU with the reference box is
    ``score`` (n,): the confirmed one of largest IoU ≥ ``floor`` (:data:`TARGET_IOU`), the
    lower id of equals; :data:`NONE` when none qualifies. (A point tracker's score is the
    negated squared distance, its gate applied to ``confirmed``, lesmc/tracking/gnn.py.)"""
    ok = confirmed & (score >= floor)
    if not ok.any():
        return NONE
    best = ok & (score == score[ok].max())
    return int(ids[best].min())


def indicators(
    source: str, last_src: np.ndarray, tid_dst: np.ndarray, ref_dst: np.ndarray
) -> np.ndarray:
    """Each transition's 0/1 of identity measure ``source`` (``switches`` or ``lost``) at
    the step it enters (the kernel keeps those inside the measure's range): the measure's
    own indicator (lesmc/language/measures/)."""
    return measures.by_source(source).indicator(last_src, tid_dst, ref_dst)


def switch_contributions(
    k: np.ndarray, lo: int, hi: int, last_src: np.ndarray, tid_dst: np.ndarray
) -> np.ndarray:
    """Each transition's contribution to ``switches(lo..hi)``: it enters step ``k`` from a
    state with ``last_src`` to one whose target's track id is ``tid_dst``."""
    switched = indicators("switches", last_src, tid_dst, np.zeros(len(tid_dst), dtype=bool))
    return np.where((k >= lo) & (k <= hi), switched, 0.0)


def last_seen(last_src: np.ndarray, tid_dst: np.ndarray) -> np.ndarray:
    """The entered state's ``last``: its target's track id, else its source's ``last``."""
    out: np.ndarray = np.where(tid_dst != NONE, tid_dst, last_src)
    return out


def switches(ids: Sequence[int | None], lo: int, hi: int) -> int:
    """``switches(lo..hi)`` of one path whose target's track id at step k is ``ids[k]``
    (None: none), summed transition by transition from step 0's ``last``."""
    tid = np.array([NONE if i is None else i for i in ids], dtype=np.int64)
    if not len(tid):
        return 0
    last = tid[:-1].copy()
    for k in range(1, len(last)):
        last[k] = last_seen(last[k - 1], tid[k])
    steps = np.arange(1, len(tid))
    return int(switch_contributions(steps, lo, hi, last, tid[1:]).sum())
