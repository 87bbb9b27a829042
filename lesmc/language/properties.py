"""Property objects: the typed, position-carrying form of a spec file.

A property is the constrained minimisation of the paper's Eq. 6 (robustness)
or Eq. 7 (resilience), generalised: minimise a path measure over the attacked
paths subject to one threshold constraint on another measure, and compare the
optimum with a threshold (section 4: holds iff optimum > threshold).
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass, field, replace
from typing import TYPE_CHECKING, Literal, Protocol, TypeVar

from lesmc.common.errors import UsageError

if TYPE_CHECKING:  # the registry loads numpy: imported where a measure is asked for
    from lesmc.language import measures

#: A step reference in a spec: a number, or None for ``end``.
StepRef = int | None

#: Relative rise of τ the runtime monitor ignores by default: it only absorbs rounding.
DEFAULT_MONITOR_TOLERANCE = 1e-9

#: A measure's kind: the name of a registered measure (lesmc/language/measures/).
MeasureKind = str
Aggregate = Literal["sum", "mean", "max", "at", "frames", "rise", "nearest"]
Comparison = Literal[">", ">=", "<", "<="]


@dataclass(frozen=True)
class Pos:
    """A 1-based source position, kept so semantic errors can point at the text."""

    line: int
    column: int


@dataclass(frozen=True)
class Measure:
    """A quantity of a path.

    ``payoff`` (sum, Eq. 8 over the attack window), ``payoff.mean`` (the same
    divided by the number of attacked steps, Algorithm 1), ``dist.sum(a..b)``
    (Eq. 9 on a range), ``dist.max(a..b)`` (dist^max) and ``dist.at(k)``
    (dist^{k,k}), ``dist.nearest(k)`` (the same against the nearest acceptable track:
    the original path or a ground-truth track, section 4.2); ``count`` (Eq. 8 with
    every payoff 1: the outcomes hidden) and
    ``count.frames`` (the attacked steps) over the attack window; ``tau.rise(a..b)``
    (the largest one-step rise of the uncertainty τ of Eq. 12 entering steps a..b, 0
    when τ never rises: section 9.1's trend); ``switches(a..b)`` and ``lost(a..b)`` (the
    identity measures of multi-target designs). ``kind`` names a measure of the registry
    (lesmc/language/measures/), which decides everything measure-specific.
    """

    kind: MeasureKind
    aggregate: Aggregate
    lo: StepRef = None
    hi: StepRef = None
    pos: Pos = field(default=Pos(0, 0), compare=False)

    def text(self) -> str:
        """The measure as it is written in the language."""
        return self.declared.text(self.aggregate, self.lo, self.hi)

    @property
    def declared(self) -> measures.DeclaredMeasure:
        """The measure's declaration (lesmc/language/measures/)."""
        from lesmc.language import measures

        return measures.get(self.kind)


@dataclass(frozen=True)
class Constraint:
    """``subject to MEASURE CMP NUMBER``: the paths that break the system."""

    measure: Measure
    op: Comparison
    threshold: float
    pos: Pos = field(default=Pos(0, 0), compare=False)

    def text(self) -> str:
        return f"{self.measure.text()} {self.op} {_num(self.threshold)}"


@dataclass(frozen=True)
class Monitor:
    """``monitor KIND [PARAM]``: a runtime monitor filters paths (docs/semantics.md).

    An attacked path counts only if the monitor's alarm (lesmc/language/monitors.py:
    ``tau_rise``, Eq. 13, the default and what ``monitor uncertainty`` names; ``nis``;
    ``misses``; ``trace``) never fires on a transition entering steps l..end.
    ``parameter`` is the kind's number (tau_rise: the relative tolerance of τ's rise;
    nis: the χ² quantile; misses: k steps; trace: the bound on τ), ``window`` the NIS
    monitor's sliding window of steps, ``components`` those of τ (Eq. 12). With
    ``except_original`` (``... except original``) an alarm counts only at a step where
    the original (unattacked) track raises none: the attack, not the scene, caused it.
    """

    components: tuple[str, ...] | None = None
    parameter: float = DEFAULT_MONITOR_TOLERANCE
    pos: Pos = field(default=Pos(0, 0), compare=False)
    except_original: bool = False
    kind: str = "tau_rise"
    window: int = 1

    @property
    def tolerance(self) -> float:
        """The parameter under its ``tau_rise`` name (the relative tolerance of Eq. 13)."""
        return self.parameter

    def text(self) -> str:
        """The monitor as a spec writes it, e.g. ``nis 0.99 window 3``."""
        win = f" window {self.window}" if self.window != 1 else ""
        return f"{self.kind} {_num(self.parameter)}{win}"


@dataclass(frozen=True)
class InjectGrid:
    """``inject grid D within R payoff P`` (issue 61): a modelling device, not a
    perception stage's output. At an attacked step the attacker may also inject a
    detection at any point of a D-px grid centred on the tracker's predicted position,
    within R px of it, at payoff P each (docs/language.md, "Injection grid")."""

    spacing: float
    radius: float
    payoff: float

    def offsets(self) -> list[tuple[float, float]]:
        """The grid's points as offsets (dx, dy) from the prediction, nearest first (ties:
        by dy, then dx)."""
        n = int(self.radius // self.spacing)
        pts = [
            (i * self.spacing, j * self.spacing)
            for j in range(-n, n + 1)
            for i in range(-n, n + 1)
            if math.hypot(i * self.spacing, j * self.spacing) <= self.radius
        ]
        return sorted(pts, key=lambda p: (math.hypot(*p), p[1], p[0]))

    def text(self) -> str:
        """The clause as a spec writes it."""
        d, r, p = _num(self.spacing), _num(self.radius), _num(self.payoff)
        return f"inject grid {d} within {r} payoff {p}"


@dataclass(frozen=True)
class Property:
    """One ``property NAME { ... }`` block, before it is bound to a model."""

    name: str
    window: tuple[int, StepRef]
    objective: Measure
    constraint: Constraint
    holds_op: Literal[">", ">="]
    threshold: float
    #: ``attack window L..U within R``: multi-target designs attack only the detections
    #: within R px of the target's reference (None: every detection)
    radius: float | None = None
    end: int | None = None
    norm: float = 2.0
    components: tuple[str, ...] | None = None
    monitor: Monitor | None = None
    #: the payoff mode of this property (attack, certified, interval), set by a sweep
    #: over payoff sources; None: the job's (``--payoffs``)
    payoffs: str | None = None
    #: a sweep's variant: each swept parameter and its value (``(("eps", 10.782),)``),
    #: in the order of the sweeps (lesmc/language/sweep.py); empty: not a variant
    sweep: tuple[tuple[str, float | str], ...] = ()
    pos: Pos = field(default=Pos(0, 0), compare=False)
    clause_pos: dict[str, Pos] = field(default_factory=dict, compare=False, hash=False)
    #: the attacker's actions (``attack window L..U allow hide, inject``;
    #: lesmc/language/actions.py): hide only by default
    actions: tuple[str, ...] = ("hide",)
    #: ``inject grid D within R payoff P``: grid injection candidates (None: none)
    grid: InjectGrid | None = None

    def holds_text(self) -> str:
        return f"optimum {self.holds_op} {_num(self.threshold)}"

    def with_window(self, window: tuple[int, int]) -> Property:
        """The property attacked in ``window`` instead: measure ranges written as the
        property's own window (``dist.max(6..8)`` in ``attack window 6..8``, resilience's
        "maximum deviation within the window", Eq. 7) follow it."""
        own = self.window

        def move(m: Measure) -> Measure:
            moves = m.declared.follows_window(m.aggregate)
            if moves and (m.lo, m.hi) == own:
                return replace(m, lo=window[0], hi=window[1])
            return m

        return replace(
            self,
            window=window,
            objective=move(self.objective),
            constraint=replace(self.constraint, measure=move(self.constraint.measure)),
        )


#: What a matrix fault does to its entry: ``*`` scales it, ``=`` sets it.
FaultOp = Literal["*", "="]


@dataclass(frozen=True)
class Fault:
    """``fault NAME: ...``: one component failure (section 9.2) the system may suffer.

    ``matrix``: an entry of the Kalman filter's F, H, Q or R scaled (``*``) or set
    (``=``; ``= 0`` drops it) from the activation step on; ``row``/``col`` are indices
    or component names, checked against the tracker when bound. ``outage``: no
    measurement reaches the tracker for ``length`` consecutive steps from the
    activation step (a sensor outage; a detector that answers nothing for a frame is
    ``outage 1``). ``neuron``: hidden unit ``col`` of hidden layer ``row`` of the
    network ``net`` (``detector``: N_dr, ``locator``: N_lp) outputs ``value``, or the
    largest value it takes on the video's windows (``at_max``), from the activation
    step's frame on. ``steps``: the activation steps the adversary chooses from (None:
    the attack window of the property checked).
    """

    name: str
    kind: Literal["matrix", "outage", "neuron"]
    matrix: str = ""
    row: int | str = 0
    col: int | str = 0
    op: FaultOp = "*"
    value: float = 1.0
    length: int = 0
    net: str = ""
    at_max: bool = False
    steps: tuple[int, StepRef] | None = None
    pos: Pos = field(default=Pos(0, 0), compare=False)

    def text(self) -> str:
        """The fault as it is written in the language (without its name and steps)."""
        if self.kind == "outage":
            return f"outage {self.length}"
        if self.kind == "neuron":
            stuck = "max" if self.at_max else _num(self.value)
            return f"neuron {self.net}[{self.row},{self.col}] = {stuck}"
        return f"{self.matrix}[{self.row},{self.col}] {self.op} {_num(self.value)}"


@dataclass(frozen=True)
class FaultSet:
    """A ``faults { ... }`` block: the faults and how many may strike at once (``budget``)."""

    budget: int
    faults: tuple[Fault, ...]
    path: str = ""
    text: str = field(default="", compare=False, repr=False)
    pos: Pos = field(default=Pos(0, 0), compare=False)


@dataclass(frozen=True)
class SpecFile:
    """A parsed property file; ``text`` is kept for error messages."""

    path: str
    text: str
    properties: tuple[Property, ...]
    faults: FaultSet | None = None

    def with_window(self, window: tuple[int, int] | None) -> SpecFile:
        """Every property attacked in ``window`` (:meth:`Property.with_window`); None keeps it."""
        if window is None:
            return self
        return replace(self, properties=tuple(p.with_window(window) for p in self.properties))

    def with_monitor(self, monitor: Monitor | None = None) -> SpecFile:
        """Every property without a monitor filtered by ``monitor`` (default: the runtime
        monitor of section 7.1, Eq. 13; the improved design)."""
        mon = monitor or Monitor()
        props = tuple(p if p.monitor else replace(p, monitor=mon) for p in self.properties)
        return replace(self, properties=props)


def _num(x: float) -> str:
    return f"{x:g}"


class Named(Protocol):
    """A property, bound or not: anything with a name."""

    @property
    def name(self) -> str: ...


P = TypeVar("P", bound=Named)


def chosen_property(bound: Sequence[P], spec_path: str, prop: str | None) -> P:
    """The property a verb acts on (an export's, ``lesmc build --spec``'s): the one called
    ``prop`` among ``bound`` (the properties of ``spec_path``, bound or not), or the only
    one."""
    if prop is not None:
        bound = [b for b in bound if b.name == prop]
        if not bound:
            raise UsageError(f"no property '{prop}' in {spec_path}")
    elif len(bound) > 1:
        names = ", ".join(b.name for b in bound)
        raise UsageError(f"{spec_path} has several properties ({names}): choose with --property")
    return bound[0]
