"""The payoff modes, in one registry: which payoffs a property is checked with.

A *payoff set* is a model's payoffs: ``attack`` (those the attack achieved, the
paper's) or ``certified`` (certified lower bounds of the cheapest attack,
``payoff_lower``). A *payoff mode* checks a property on the models of one or more
sets, in order, and merges their results into one (docs/semantics.md, "Payoff
intervals"). Each mode is declared once here, with its name, a one-line summary
and its behaviour (its sets and its merge).

Everything that names payoff modes reads this module: ``--payoffs``' choices and
help (lesmc/cli/options.py), the JSON schemas' ``#/$defs/payoff_modes``
(lesmc/schemas), the API's argument check (lesmc/api.py), the pipeline
(lesmc/pipeline/payoffs.py) and the table of docs/semantics.md, which
tests/test_registries.py compares with it. Importing this module is cheap.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from dataclasses import dataclass
from typing import TYPE_CHECKING

if TYPE_CHECKING:
    from lesmc.engines.result import CheckResult
    from lesmc.language.semantics import BoundProperty

#: One result per payoff set of the mode (in its order) -> the mode's result.
Merge = Callable[[Sequence["CheckResult"], "BoundProperty"], "CheckResult"]


@dataclass(frozen=True)
class PayoffMode:
    """One registered payoff mode: the payoff sets it checks (a budget shared evenly, the
    last taking what is left) and how their results make its own."""

    name: str
    summary: str  #: one line for --help and docs
    sets: tuple[str, ...]
    merge: Merge

    @property
    def certified(self) -> bool:
        """Whether it needs certified lower bounds (a scene's ``payoff_lower``)."""
        return "certified" in self.sets


_MODES: dict[str, PayoffMode] = {}

#: The mode of every verb unless told otherwise (the paper's).
DEFAULT = "attack"


def register(mode: PayoffMode) -> PayoffMode:
    """Add ``mode`` (replacing one of the same name); returns it."""
    _MODES[mode.name] = mode
    return mode


def names() -> tuple[str, ...]:
    """Every registered payoff mode, in registration order (the default first)."""
    return tuple(_MODES)


def get(name: str) -> PayoffMode:
    """The payoff mode called ``name`` (KeyError if none)."""
    return _MODES[name]


def help_text() -> str:
    """``--payoffs``' help: each mode and its summary."""
    return "; ".join(f"{m.name}: {m.summary}" for m in _MODES.values()) + "."


def _alone(results: Sequence[CheckResult], _bp: BoundProperty) -> CheckResult:
    """A mode of one payoff set: that set's result."""
    return results[0]


def _interval(results: Sequence[CheckResult], bp: BoundProperty) -> CheckResult:
    """Certified and attack results -> the interval verdict (lesmc/engines/interval.py)."""
    from lesmc.engines.interval import combine, payoff_monotone

    certified, attack = results
    return combine(certified, attack, payoff_monotone(bp))


register(PayoffMode("attack", "the payoffs the attack achieved (the paper)", ("attack",), _alone))
register(
    PayoffMode(
        "certified",
        "certified lower bounds of the cheapest attack (payoff_lower): a holds is proven "
        "against every attack, a violation proves nothing",
        ("certified",),
        _alone,
    )
)
register(
    PayoffMode(
        "interval",
        "both: holds only if proven with the lower bounds, violated only with the attack's "
        "counterexample, else unknown",
        ("certified", "attack"),
        _interval,
    )
)
