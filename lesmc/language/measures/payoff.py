"""``payoff`` and ``payoff.mean``: the combined payoffs (Eq. 5) over the attack window,
summed (Eq. 8) or averaged over the attacked steps (Algorithm 1)."""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np

from lesmc.language.measures.base import Bound, DeclaredMeasure, Parsed, Quantities, Step


class Payoff(DeclaredMeasure):
    """``payoff[.sum|.mean]`` over the attack window L..U."""

    name = "payoff"
    rules = ("payoff",)
    sources = ("payoff",)
    quantity = "combined"
    ranged = False
    multi_objective = True
    docs = (
        (
            "`payoff` (or `payoff.sum`)",
            "Σ over the transitions entering steps L..U of the combined payoff (Eq. 8 with Eq. 5).",
        ),
        (
            "`payoff.mean`",
            "The same divided by the number of attacked steps, U − L + 1 (the averaged "
            "payoff of Algorithm 1; see [semantics](semantics.md#sum-or-mean-payoff)).",
        ),
    )

    def parse(self, rule: str, tokens: Sequence[str], steps: Sequence[Step]) -> Parsed:
        return Parsed(self.name, tokens[0] if tokens else "sum")

    def text(self, aggregate: str, lo: Step, hi: Step) -> str:
        return self.name if aggregate == "sum" else f"{self.name}.{aggregate}"

    def bind(self, aggregate: str, l: int, u: int, lo: int, hi: int) -> Bound:
        weight = 1.0 / (u - l + 1) if aggregate == "mean" else 1.0
        return Bound("payoff", "sum", l, u, weight)

    def per_transition(self, source: str, weight: float, q: Quantities) -> np.ndarray:
        out: np.ndarray = q.combined * weight
        return out


MEASURE = Payoff()
