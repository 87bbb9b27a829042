"""``dist.at(k)``, ``dist.nearest(k)``, ``dist.sum(a..b)``, ``dist.max(a..b)``: the entered
states' deviations (Eq. 4) from the original path (or the nearest acceptable track)."""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np

from lesmc.language.measures.base import (
    Bound,
    DeclaredMeasure,
    Parsed,
    Quantities,
    Step,
    step_text,
)


class Dist(DeclaredMeasure):
    """The deviation measures: sources ``dist`` (against the original path) and ``near``
    (``dist.nearest``, against the nearest acceptable track)."""

    name = "dist"
    rules = ("dist_range", "dist_at", "dist_nearest")
    sources = ("dist", "near")
    quantity = "dist_dst"
    multi_objective = True
    multi_constraint = True
    docs = (
        (
            "`dist.at(k)`",
            "dist^{k,k} = ‖s_k − s̃_k‖_p against the original path's state at step k (Eq. 4).",
        ),
        (
            "`dist.nearest(k)`",
            "‖s_k − g_k‖_p for the nearest acceptable track g: the original path or any "
            'ground-truth track of the scene present at step k (section 4.2: recovery "to '
            "some path that does not necessarily have to be the original one, so long as it "
            "is acceptable\"). Needs the scene's `truth` (or the model's `tracks`) and `on` "
            "naming exactly their components (x, y); see "
            "[semantics](semantics.md#recovery-to-any-acceptable-track-section-42).",
        ),
        ("`dist.sum(a..b)`", "Σ_{k=a..b} dist.at(k) (Eq. 9 on a range)."),
        ("`dist.max(a..b)`", "max_{k=a..b} dist.at(k) (dist^max)."),
    )

    def parse(self, rule: str, tokens: Sequence[str], steps: Sequence[Step]) -> Parsed:
        if rule == "dist_range":
            return Parsed(self.name, tokens[0], steps[0], steps[1])
        agg = "at" if rule == "dist_at" else "nearest"
        return Parsed(self.name, agg, steps[0], steps[0])

    def text(self, aggregate: str, lo: Step, hi: Step) -> str:
        if aggregate in ("at", "nearest"):
            return f"dist.{aggregate}({step_text(lo)})"
        return super().text(aggregate, lo, hi)

    def follows_window(self, aggregate: str) -> bool:
        return aggregate not in ("at", "nearest")

    def bind(self, aggregate: str, l: int, u: int, lo: int, hi: int) -> Bound:
        if aggregate == "nearest":
            return Bound("near", "sum", lo, hi)
        return Bound("dist", "sum" if aggregate in ("sum", "at") else "max", lo, hi)

    def per_transition(self, source: str, weight: float, q: Quantities) -> np.ndarray:
        return q.need("near_dst") if source == "near" else q.dist_dst

    def at_step0(self, source: str, dist0: float, near0: float) -> float:
        return near0 if source == "near" else dist0

    def multi_takes(self, role: str, aggregate: str) -> bool:
        """Not ``dist.nearest``: a multi-target model has no ground-truth tracks' states."""
        return aggregate != "nearest"

    def halted_tail(self, source: str) -> bool:
        return True

    def plotted(self, source: str) -> bool:
        return source == "dist"


MEASURE = Dist()
