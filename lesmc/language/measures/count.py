"""``count`` and ``count.frames``: Eq. 5 over unit payoffs (the outcomes the attacker rules
out) and the attacked steps, over the attack window."""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np

from lesmc.language.measures.base import Bound, DeclaredMeasure, Parsed, Quantities, Step


class Count(DeclaredMeasure):
    """``count`` (source ``count``) and ``count.frames`` (source ``frames``)."""

    name = "count"
    rules = ("count",)
    sources = ("count", "frames")
    quantity = "counted"
    ranged = False
    multi_objective = True
    docs = (
        (
            "`count`",
            "`payoff` with every transition's payoff 1 (∞ stays ∞): the number of outcomes "
            "the attacker rules out over steps L..U, i.e. the detections hidden under hide "
            "only; with `allow hide, inject` it also counts injections (multi-target designs) "
            "or the cheaper outcomes ruled out (`single`, `joint`; see "
            "[semantics](semantics.md#attack-count)).",
        ),
        (
            "`count.frames`",
            "The number of attacked steps in L..U: steps whose transition is not the "
            "unattacked one (rank > 0); ∞ where hiding is impossible. `minimize count.frames` "
            "is the fewest frames an attacker must touch.",
        ),
    )

    def parse(self, rule: str, tokens: Sequence[str], steps: Sequence[Step]) -> Parsed:
        return Parsed(self.name, tokens[0] if tokens else "sum")

    def text(self, aggregate: str, lo: Step, hi: Step) -> str:
        return self.name if aggregate == "sum" else f"{self.name}.{aggregate}"

    def bind(self, aggregate: str, l: int, u: int, lo: int, hi: int) -> Bound:
        return Bound("frames" if aggregate == "frames" else "count", "sum", l, u)

    def per_transition(self, source: str, weight: float, q: Quantities) -> np.ndarray:
        """``count``: the counted outcomes; ``frames``: 1 for each attacked step (a positive
        count), ∞ where the count is."""
        per = q.need("counted")
        if source == "frames":
            per = np.where(np.isinf(per), np.inf, (per > 0).astype(float))
        out: np.ndarray = per * weight
        return out


MEASURE = Count()
