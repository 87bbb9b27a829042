"""The designs lesmc verifies, in one registry: trackers, and the runtime monitor on top.

A *tracker* unfolds a scene: its class (tracking/single.py, tracking/joint.py)
computes the successors of batches of states (the :class:`~lesmc.tracking.design.Design`
protocol). A *design* is what a verification checks: a tracker, with or
without the runtime monitor of section 7.1 filtering every property (Eq. 13).

Everything that names designs reads this module: the command line's choices,
the JSON schemas' enums (lesmc/schemas), the display names of tables and
reports, the campaign's tables. Adding a design is one module and one line
at the end of this file (or a call of :func:`register` from the user's code);
docs/architecture.md says how. Importing this module is cheap: a tracker's
class is imported only when a scene is unfolded with it (lesmc/tracking/trackers.py),
and this module imports nothing of lesmc: it sits below every layer that names designs.
"""

from __future__ import annotations

from dataclasses import dataclass


@dataclass(frozen=True)
class Design:
    """One registered design.

    ``tracker`` is the name of the tracker it unfolds with (for a plain design,
    its own name), ``implementation`` the ``module:Class`` of that tracker
    (None: the design reuses another design's tracker), ``monitor`` whether
    every property is filtered by the runtime monitor (Eq. 12-13).
    """

    name: str
    label: str  #: how tables and reports name it
    summary: str  #: one line for --help and docs
    tracker: str
    monitor: bool = False
    implementation: str | None = None
    cost: float = (
        1.0  #: relative cost of unfolding with the tracker (campaigns start costly work first)
    )
    #: a multi-target tracker (lesmc/tracking/multi.py): ``lesmc track`` runs it, ``lesmc
    #: check`` checks identity properties on it (lesmc/pipeline/multi.py); it is not among
    #: the designs ``all`` names
    multi: bool = False


_DESIGNS: dict[str, Design] = {}

#: Named sets of designs (``--design paper``); ``all`` is every registered design.
SETS: dict[str, tuple[str, ...]] = {}

#: The design every other one is compared with (the paper's Table 5: the plain tracker).
BASELINE = "single"


def register(design: Design) -> Design:
    """Add ``design`` (replacing one of the same name); returns it."""
    if design.implementation is None and design.tracker not in _DESIGNS:
        raise ValueError(f"design {design.name!r}: no tracker named {design.tracker!r}")
    if design.name in SETS or design.name == "all":
        raise ValueError(f"design {design.name!r}: the name of a set of designs")
    _DESIGNS[design.name] = design
    return design


def unregister(name: str) -> None:
    """Remove a design (the tests' toy design)."""
    _DESIGNS.pop(name, None)


def tracker(name: str, impl: str, label: str, summary: str, cost: float = 1.0) -> Design:
    """Register a tracker and its plain design (no monitor) under ``name``."""
    return register(Design(name, label, summary, name, False, impl, cost))


def multi_tracker(name: str, impl: str, label: str, summary: str) -> Design:
    """Register a multi-target tracker (built, checked and exported by its own stages:
    lesmc/unfold/multi.py, lesmc/engines/multi.py, lesmc/exporters/multi.py)."""
    return register(Design(name, label, summary, name, False, impl, multi=True))


def not_yet(name: str, what: str) -> str:
    """What a verb says of multi-target design ``name`` when it needs ``what``, which the
    multi-target designs do not support yet."""
    return (
        f"design '{name}' is a multi-target tracker: `lesmc track`, `build`, `check`, "
        "`export --format drn|prism`, `verify`, `replay` and `campaign` take it; "
        f"{what} is not supported yet (docs/trackers.md)"
    )


def monitored(name: str, of: str, label: str, summary: str) -> Design:
    """Register the design ``of``'s tracker with the runtime monitor on every property."""
    base = _DESIGNS[of]
    return register(Design(name, label, summary, base.tracker, True, cost=base.cost))


def names() -> tuple[str, ...]:
    """Every registered design, in registration order."""
    return tuple(_DESIGNS)


def tracker_names() -> tuple[str, ...]:
    """The designs that bring a tracker of their own (what a scene's ``tracker.design`` names)."""
    return tuple(n for n, d in _DESIGNS.items() if d.implementation is not None)


def multi_names() -> tuple[str, ...]:
    """The multi-target designs (what a ``lesmc-multi-check`` document's ``design`` names)."""
    return tuple(n for n, d in _DESIGNS.items() if d.multi)


def get(name: str) -> Design:
    """The design called ``name`` (KeyError if none)."""
    return _DESIGNS[name]


def choices() -> tuple[str, ...]:
    """What ``--design`` of verify and campaign accepts: designs and named sets."""
    return (*names(), *SETS, "all")


def expand(choice: str) -> tuple[str, ...]:
    """The designs a ``--design`` choice names (``all``: every single-target design)."""
    if choice == "all":
        return tuple(n for n, d in _DESIGNS.items() if not d.multi)
    return SETS.get(choice, (choice,))


def label(name: str) -> str:
    """How tables name a design (the name itself when it is not registered)."""
    d = _DESIGNS.get(name)
    return name if d is None else d.label


def implementation(name: str) -> str:
    """The ``module:Class`` of the tracker design ``name`` unfolds with (declared here,
    imported by :func:`lesmc.tracking.trackers.tracker_class` when a scene is unfolded)."""
    impl = _DESIGNS[_DESIGNS[name].tracker].implementation
    assert impl is not None
    return impl


def implementations() -> tuple[str, ...]:
    """Every tracker's ``module:Class`` (tests/test_layers.py reads them as imports)."""
    return tuple(d.implementation for d in _DESIGNS.values() if d.implementation is not None)


def docs_table() -> str:
    """The table of docs/cli.md (the designs ``--design`` accepts), from the registry."""
    rows = ["| design | label in tables | what it is |", "| --- | --- | --- |"]
    rows += [f"| `{d.name}` | {d.label} | {d.summary} |" for d in _DESIGNS.values()]
    return "\n".join(rows)


tracker(
    "single",
    "lesmc.tracking.single:SingleDesign",
    "single",
    "one Kalman filter, gated nearest-neighbour association (section 6.7)",
)
tracker(
    "joint",
    "lesmc.tracking.joint:JointDesign",
    "joint KFs",
    "joint Kalman filters: the target and its neighbours (section 7.2)",
    cost=10.0,
)
monitored(
    "monitor",
    "single",
    "single + monitor",
    "the single tracker, with the runtime monitor on every property (section 7.1)",
)
monitored(
    "improved",
    "joint",
    "joint KFs + monitor",
    "the paper's improved design: joint KFs and the runtime monitor (sections 7.1-7.2)",
)
multi_tracker(
    "sort",
    "lesmc.tracking.multi:SortDesign",
    "SORT",
    "SORT (Bewley et al. 2016): box Kalman filters, IoU assignment, min_hits, max_age; "
    "multi-target: `lesmc track`, `lesmc check` and `lesmc verify` of switches, lost, dist",
)
multi_tracker(
    "gnn",
    "lesmc.tracking.gnn:GnnDesign",
    "GNN",
    "point Kalman filters, Mahalanobis chi-square gate, global nearest neighbour, M-of-N "
    "birth, max_age death; multi-target: `lesmc track`, `lesmc check`, `lesmc verify`",
)
SETS["paper"] = ("single", "joint", "improved")
SETS["both"] = ("single", "improved")
