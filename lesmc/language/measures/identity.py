"""What the identity measures of multi-target designs share (``switches``, ``lost``): the
grammar rule ``identity_range`` (``NAME(a..b)``), a sum over the range of a 0/1 per
transition (:meth:`~lesmc.language.measures.base.DeclaredMeasure.indicator`), and a
multi-target design to bind to."""

from __future__ import annotations

from collections.abc import Sequence

from lesmc.language.measures.base import Bound, DeclaredMeasure, Parsed, Step, step_text

NONE = -1
"""A step without the target's track (and a state that never saw it)."""


class IdentityMeasure(DeclaredMeasure):
    """A sum of per-transition identity indicators over a step range a..b."""

    rules = ("identity_range",)
    quantity = "identity"
    multi_only = True
    multi_constraint = True

    def parse(self, rule: str, tokens: Sequence[str], steps: Sequence[Step]) -> Parsed:
        return Parsed(self.name, "sum", steps[0], steps[1])

    def text(self, aggregate: str, lo: Step, hi: Step) -> str:
        return f"{self.name}({step_text(lo)}..{step_text(hi)})"

    def bind(self, aggregate: str, l: int, u: int, lo: int, hi: int) -> Bound:
        return Bound(self.name, "sum", lo, hi)
