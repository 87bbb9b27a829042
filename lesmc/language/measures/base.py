"""What a measure of the property language is: one declared object per measure
(docs/language.md, "Measures" and "Adding a measure").

A measure declares its grammar facts (the rules of grammars/lesmc.lark that spell it,
its suffixes, whether it takes a step range), how it binds (its bound sources, whether
it needs a multi-target design or the covariance), the per-transition quantity it reads
and how the kernel folds it (lesmc/model/kernel.py computes the quantities: the deviation
of Eq. 4, the combined payoff of Eq. 5, the rise of τ; the measure picks and weights
them), and its rows of the docs table.

This module imports nothing of lesmc's but the errors: the property objects
(lesmc/language/properties.py), the binding (semantics.py) and the kernel all read it.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

#: A step reference in a spec: a number, or None for ``end``.
Step = int | None


class MeasureError(Exception):
    """A measure written or bound wrongly; the caller locates it at the measure."""


@dataclass(frozen=True)
class Parsed:
    """A measure as the parser reads it: its kind, aggregate and step range."""

    kind: str
    aggregate: str
    lo: Step = None
    hi: Step = None


@dataclass(frozen=True)
class Bound:
    """A measure bound to a window: its source (what the kernel folds), how a path's value
    grows (``sum`` or ``max``), its concrete steps and its weight."""

    source: str
    aggregate: str
    lo: int
    hi: int
    weight: float = 1.0


@dataclass(frozen=True)
class Quantities:
    """The per-transition quantities the kernel computes for a batch of transitions
    (lesmc/model/kernel.py ``contributions``): ``combined``, the combined payoff (Eq. 5);
    ``dist_dst``, the entered state's deviation (Eq. 4); ``counted``, Eq. 5 over unit
    payoffs; ``rise``, τ's rise (Eq. 12, section 9.1); ``near_dst``, the entered state's
    deviation from the nearest acceptable track; ``identity``, the transition's identity
    indicator (lesmc/model/identity.py). None: not computed for this model."""

    combined: np.ndarray
    dist_dst: np.ndarray
    counted: np.ndarray | None = None
    rise: np.ndarray | None = None
    near_dst: np.ndarray | None = None
    identity: np.ndarray | None = None

    def need(self, name: str) -> np.ndarray:
        """The quantity ``name``; a programming error when the caller did not compute it."""
        value: np.ndarray | None = getattr(self, name)
        if value is None:
            raise ValueError(f"the measure reads '{name}', which was not computed")
        return value


def step_text(ref: Step) -> str:
    """A step as the language writes it."""
    return "end" if ref is None else str(ref)


class DeclaredMeasure:
    """One measure of the language. A subclass sets the class attributes and overrides the
    methods whose default does not fit it; one module per measure (lesmc/language/measures/).

    Attributes: ``name`` (the kind, as ``Measure.kind``), ``rules`` (the grammar rules that
    spell it), ``sources`` (what it binds to: ``BoundMeasure.source``), ``quantity`` (the
    :class:`Quantities` field it reads, for the docs), ``ranged`` (takes a step range
    a..b; else it counts over the attack window), ``multi_only`` (only a multi-target
    design has it), ``needs_covariance`` (reads τ, Eq. 12), ``multi_objective`` and
    ``multi_constraint`` (the multi-target engine minimises it / takes it as constraint),
    ``docs`` (its rows of docs/language.md: spelling, definition).
    """

    name: str = ""
    rules: tuple[str, ...] = ()
    sources: tuple[str, ...] = ()
    quantity: str = ""
    ranged: bool = True
    multi_only: bool = False
    needs_covariance: bool = False
    multi_objective: bool = False
    multi_constraint: bool = False
    docs: tuple[tuple[str, str], ...] = ()

    def parse(self, rule: str, tokens: Sequence[str], steps: Sequence[Step]) -> Parsed:
        """The measure of grammar rule ``rule`` whose tokens (its suffix or name) and steps
        the parser read. Default: ``NAME.AGG(a..b)``."""
        return Parsed(self.name, tokens[0], steps[0], steps[1])

    def text(self, aggregate: str, lo: Step, hi: Step) -> str:
        """The measure as the language writes it. Default: ``NAME.AGG(a..b)``."""
        return f"{self.name}.{aggregate}({step_text(lo)}..{step_text(hi)})"

    def follows_window(self, aggregate: str) -> bool:
        """A range written as the property's window follows it when a sweep or a campaign
        moves the window (``Property.with_window``)."""
        return False

    def bind(self, aggregate: str, l: int, u: int, lo: int, hi: int) -> Bound:
        """The bound measure, in attack window l..u with its own range lo..hi resolved and
        checked (lo <= hi <= end) for a ranged measure."""
        raise NotImplementedError

    def per_transition(self, source: str, weight: float, q: Quantities) -> np.ndarray:
        """Each transition's contribution before the range is applied (the kernel keeps the
        transitions entering steps lo..hi)."""
        raise NotImplementedError

    def at_step0(self, source: str, dist0: float, near0: float) -> float:
        """The value on step 0 alone, when the range starts at 0 (only deviations count it)."""
        return 0.0

    def halted_tail(self, source: str) -> bool:
        """After a halted path's last state, the steps left in the range add +∞ (a lost
        target's deviation); else nothing."""
        return False

    def indicator(
        self, last_src: np.ndarray, tid_dst: np.ndarray, ref_dst: np.ndarray
    ) -> np.ndarray:
        """An identity measure's 0/1 per transition (lesmc/model/identity.py)."""
        raise NotImplementedError(f"'{self.name}' is not an identity measure")

    def multi_takes(self, role: str, aggregate: str) -> bool:
        """The multi-target engine (lesmc/engines/multi.py) takes the measure with
        ``aggregate`` as ``role`` (``objective`` or ``constraint``)."""
        return bool(self.multi_objective if role == "objective" else self.multi_constraint)

    @property
    def reads_payoffs(self) -> bool:
        """It reads the detections' payoffs (the combined payoff of Eq. 5): an unpriced
        detection in its window is an error, and lower payoffs can only lower it."""
        return self.quantity == "combined"

    def plotted(self, source: str) -> bool:
        """The report draws the constraint's bound on the deviation plot (the measure is the
        deviation from the original path that figure shows)."""
        return False
