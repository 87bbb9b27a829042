"""The measures of the property language, in one registry (docs/language.md, "Measures";
issue 58): one declared object per measure, one module each.

Every layer reads a measure's decisions here rather than testing its name: the parser
(which grammar rule spells which measure), the property objects (its text, whether its
range follows the window), the binding (its bound sources, multi-target only, needs the
covariance), the kernel (lesmc/model/kernel.py: its per-transition contribution, its value
at step 0, its tail after a halt), the identity indicators (lesmc/model/identity.py), the
multi-target engine (which measures it minimises and takes as constraint) and the report.
:func:`docs_table` is the table of docs/language.md. Adding a measure is one module here
and one entry in :data:`_MODULES` (docs/language.md, "Adding a measure").
"""

from __future__ import annotations

from lesmc.language.measures import count, dist, lost, payoff, switches, tau
from lesmc.language.measures.base import (
    Bound,
    DeclaredMeasure,
    MeasureError,
    Parsed,
    Quantities,
)

__all__ = [
    "Bound",
    "DeclaredMeasure",
    "MeasureError",
    "Parsed",
    "Quantities",
    "by_rule",
    "by_source",
    "docs_table",
    "get",
    "names",
    "plotted",
    "register",
    "sources",
    "unregister",
]

#: The measures, in the order of the docs table.
_MODULES = (payoff, count, dist, tau, switches, lost)

_BY_NAME: dict[str, DeclaredMeasure] = {}
_BY_SOURCE: dict[str, DeclaredMeasure] = {}


def register(measure: DeclaredMeasure) -> None:
    """Declare a measure (its name and its sources must be new)."""
    if measure.name in _BY_NAME:
        raise ValueError(f"measure {measure.name!r} is registered already")
    for s in measure.sources:
        if s in _BY_SOURCE:
            raise ValueError(f"measure source {s!r} is registered already")
        _BY_SOURCE[s] = measure
    _BY_NAME[measure.name] = measure


for _module in _MODULES:
    register(_module.MEASURE)


def unregister(name: str) -> None:
    """Forget the measure ``name`` (a test's toy measure; KeyError: none)."""
    measure = _BY_NAME.pop(name)
    for s in measure.sources:
        del _BY_SOURCE[s]


def names() -> tuple[str, ...]:
    """The measures' names (``Measure.kind``), in registration order."""
    return tuple(_BY_NAME)


def get(name: str) -> DeclaredMeasure:
    """The measure called ``name`` (KeyError: none)."""
    return _BY_NAME[name]


def sources() -> tuple[str, ...]:
    """Every bound source of every measure (``BoundMeasure.source``; the documents'
    ``objective_source`` and ``constraint_source``), in registration order."""
    return tuple(_BY_SOURCE)


def by_source(source: str) -> DeclaredMeasure:
    """The measure a bound source (``BoundMeasure.source``) belongs to (KeyError: none)."""
    return _BY_SOURCE[source]


def by_rule(rule: str, name: str | None) -> DeclaredMeasure:
    """The measure grammar rule ``rule`` spells; a rule several measures share
    (``identity_range``) names it by its first token ``name``."""
    spelled = [m for m in _BY_NAME.values() if rule in m.rules]
    if len(spelled) == 1:
        return spelled[0]
    return next(m for m in spelled if m.name == name)


def plotted(source: str) -> bool:
    """A constraint on ``source`` is the deviation the report's figure shows, so the figure
    draws its bound (False for a source no measure declares, e.g. an older document's)."""
    measure = _BY_SOURCE.get(source)
    return measure is not None and measure.plotted(source)


def docs_table() -> str:
    """The Markdown table of docs/language.md, "Measures"."""
    rows = ["| measure | definition |", "|---|---|"]
    for m in _BY_NAME.values():
        rows.extend(f"| {spelling} | {text} |" for spelling, text in m.docs)
    return "\n".join(rows) + "\n"
