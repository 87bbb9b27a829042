"""The search engines, in one registry: each declared once, with its name, a one-line summary
and its behaviour (the search function and whether it walks every path).

Everything that names engines reads this module: ``--engine``'s choices and help
(lesmc/cli/check.py), the JSON schemas' ``#/$defs/engines`` (lesmc/schemas), the
API's argument check (lesmc/api.py) and the table of docs/cli.md ("Engines"),
which tests/test_registries.py compares with it. Adding an engine is one module
with its search function and one :func:`register` line at the end of this file.
Importing this module is cheap (``--help`` loads it): a search function is
imported when an engine first searches.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from typing import TYPE_CHECKING

if TYPE_CHECKING:
    from lesmc.engines.result import EngineOutcome

#: A search: a property's search space (lesmc/engines/space.py or lazy.py) and a budget
#: in, the optimum, the bounds and the paths out.
Search = Callable[..., "EngineOutcome"]


@dataclass(frozen=True)
class Engine:
    """One registered engine.

    ``load`` returns its search function (imported then); ``exhaustive``: it walks
    every path of the tree (no probe first, and the properties that share a tree are
    always answered by one walk of it, lesmc/engines/check.py); ``own_probe``: the
    search decides itself whether to enumerate a small tree first (check_bound's probe
    is left to it).
    """

    name: str
    summary: str  #: one line for --help and docs
    load: Callable[[], Search]
    exhaustive: bool = False
    own_probe: bool = False


_ENGINES: dict[str, Engine] = {}

#: The engine of every verb unless told otherwise.
DEFAULT = "levels"
#: The multi-target designs' exact engine (lesmc/engines/multi.py): not a registered
#: engine (no --engine choice), the name a campaign row's ``stats.engine`` gives it.
MULTI = "multi"


def register(engine: Engine) -> Engine:
    """Add ``engine`` (replacing one of the same name); returns it."""
    _ENGINES[engine.name] = engine
    return engine


def names() -> tuple[str, ...]:
    """Every registered engine, in registration order (the default first)."""
    return tuple(_ENGINES)


def get(name: str) -> Engine:
    """The engine called ``name`` (KeyError if none)."""
    return _ENGINES[name]


def help_text() -> str:
    """``--engine``'s help: each engine and its summary."""
    return "; ".join(f"{e.name}: {e.summary}" for e in _ENGINES.values()) + "."


def _levels() -> Search:
    from lesmc.engines.levels import level_search

    return level_search


def _bnb() -> Search:
    from lesmc.engines.bnb import branch_and_bound

    return branch_and_bound


def _auto() -> Search:
    from lesmc.engines.auto import auto_search

    return auto_search


def _enumerate() -> Search:
    from lesmc.engines.enumerate import enumerate_paths

    return enumerate_paths


register(
    Engine(
        "levels",
        "exact search in lock step with bounds, dominance and a dive for an incumbent (anytime)",
        _levels,
    )
)
register(Engine("bnb", "best-first branch and bound", _bnb))
register(Engine("enumerate", "the paper's Algorithms 1-2 (all paths)", _enumerate, True))
register(
    Engine(
        "auto",
        "levels or bnb, chosen per instance from the model's shape (bnb for an explicit "
        "model's max objective)",
        _auto,
        own_probe=True,
    )
)
