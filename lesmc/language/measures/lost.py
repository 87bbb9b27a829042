"""``lost(a..b)``: the steps at which the target's reference exists and no output track
matches it (multi-target designs)."""

from __future__ import annotations

import numpy as np

from lesmc.language.measures.base import Quantities
from lesmc.language.measures.identity import NONE, IdentityMeasure


class Lost(IdentityMeasure):
    """``lost(a..b)``: 1 for each transition entering a step of a..b whose state has the
    reference and no target's track."""

    name = "lost"
    sources = ("lost",)
    docs = (
        (
            "`lost(a..b)`",
            "Multi-target designs only: the number of steps k in a..b at which the target's "
            "reference exists and no output track matches it (as for `switches`).",
        ),
    )

    def indicator(
        self, last_src: np.ndarray, tid_dst: np.ndarray, ref_dst: np.ndarray
    ) -> np.ndarray:
        hit = ref_dst & (tid_dst == NONE)
        out: np.ndarray = hit.astype(float)
        return out

    def per_transition(self, source: str, weight: float, q: Quantities) -> np.ndarray:
        return q.need("identity")


MEASURE = Lost()
