"""``tau.rise(a..b)``: the largest one-step rise of the uncertainty τ (Eq. 12) entering
steps a..b (section 9.1's trend)."""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np

from lesmc.language.measures.base import (
    Bound,
    DeclaredMeasure,
    MeasureError,
    Parsed,
    Quantities,
    Step,
)


class Tau(DeclaredMeasure):
    """``tau.rise(a..b)``, aggregated by max; needs the covariance P of every state."""

    name = "tau"
    rules = ("tau_range",)
    sources = ("tau",)
    quantity = "rise"
    needs_covariance = True
    docs = (
        (
            "`tau.rise(a..b)`",
            "The largest one-step rise of the uncertainty τ (Eq. 12) over the transitions "
            "entering steps a..b (a ≥ 1): max(0, max_k τ_k − τ_{k−1}). 0 when τ never rises "
            'there: the "decreasing trend" of section 9.1. τ is over the monitor\'s '
            "components when the property has `monitor uncertainty on ...`, else x, y. Needs "
            "P in every state (see [semantics](semantics.md#trends-of-the-uncertainty-"
            "section-91)).",
        ),
    )

    def parse(self, rule: str, tokens: Sequence[str], steps: Sequence[Step]) -> Parsed:
        if steps[0] == 0:
            raise MeasureError(
                "tau.rise starts at step 1 or later (a rise enters a step from the one before)"
            )
        return super().parse(rule, tokens, steps)

    def follows_window(self, aggregate: str) -> bool:
        return True

    def bind(self, aggregate: str, l: int, u: int, lo: int, hi: int) -> Bound:
        if lo < 1:
            raise MeasureError("tau.rise starts at step 1 or later")
        return Bound("tau", "max", lo, hi)

    def per_transition(self, source: str, weight: float, q: Quantities) -> np.ndarray:
        return q.need("rise")

    def halted_tail(self, source: str) -> bool:
        return True


MEASURE = Tau()
