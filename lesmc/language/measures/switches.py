"""``switches(a..b)``: the steps at which the target's track changes id (multi-target
designs; lesmc/model/identity.py keeps each state's ``last`` id and the target's track)."""

from __future__ import annotations

import numpy as np

from lesmc.language.measures.base import Quantities
from lesmc.language.measures.identity import NONE, IdentityMeasure


class Switches(IdentityMeasure):
    """``switches(a..b)``: 1 for each transition entering a step of a..b at which the
    target's track exists and its id differs from the last one it had."""

    name = "switches"
    sources = ("switches",)
    docs = (
        (
            "`switches(a..b)`",
            "Multi-target designs only (`--design sort`, `gnn`): the number of steps k in a..b "
            "at which the target's track exists and its id differs from its id at the last "
            "earlier step (from step 0) at which it existed. The target's track at step k "
            "is, for `sort`, the output track of largest IoU ≥ 0.5 with the target's "
            "reference box (its ground-truth track when the scene's truth has boxes, else its "
            "unattacked track where that is output); for `gnn`, the output track nearest the "
            "reference position (its unattacked track) within the gate; the lower id of "
            "equals. On a single-target design: an error at the measure (exit status 2). See "
            "[trackers](trackers.md#checking-a-multi-target-design).",
        ),
    )

    def indicator(
        self, last_src: np.ndarray, tid_dst: np.ndarray, ref_dst: np.ndarray
    ) -> np.ndarray:
        hit = (tid_dst != NONE) & (last_src != NONE) & (tid_dst != last_src)
        out: np.ndarray = hit.astype(float)
        return out

    def per_transition(self, source: str, weight: float, q: Quantities) -> np.ndarray:
        return q.need("identity")


MEASURE = Switches()
