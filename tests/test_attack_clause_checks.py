"""The checks of a spec's attack clauses, callable apart from the parser
(lesmc/language/actions.py): an ``allow`` list against the registry, an ``inject grid``
within its limits. The grid's point limit is compared with a count of the lattice
points made here; the parser's located messages are tests/test_inject_grid.py's."""

from __future__ import annotations

import math

import pytest

from lesmc.language import actions
from lesmc.language.properties import InjectGrid


def _points(spacing: float, radius: float) -> int:
    """The grid's points counted here: (i, j) with |(i, j)| * spacing <= radius."""
    n = int(radius // spacing) + 1
    return sum(
        1
        for i in range(-n, n + 1)
        for j in range(-n, n + 1)
        if math.hypot(i * spacing, j * spacing) <= radius
    )


def test_a_grid_is_refused_exactly_past_the_point_limit() -> None:
    """The largest whole radius (spacing 1) within the limit passes, the next is refused
    at D with the limit's message."""
    r = max(k for k in range(1, 40) if _points(1.0, k) <= actions.MAX_GRID_POINTS)
    assert actions.grid_problem(InjectGrid(1.0, r, 0.5), ["1", str(r), "0.5"]) is None
    got = actions.grid_problem(InjectGrid(1.0, r + 1, 0.5), ["1", str(r + 1), "0.5"])
    assert got is not None and got[0] == 0
    assert f"more than {actions.MAX_GRID_POINTS} points" in got[1]


@pytest.mark.parametrize(
    ("grid", "at", "words"),
    [
        (InjectGrid(0.0, 20.0, 1.0), 0, "spacing must be positive (px), got 0"),
        (InjectGrid(5.0, -1.0, 1.0), 1, "radius must be at least 0 (px), got -1"),
        (InjectGrid(5.0, 20.0, -1.0), 2, "payoff must be at least 0, got -1"),
    ],
)
def test_each_grid_number_is_checked_where_it_is_written(
    grid: InjectGrid, at: int, words: str
) -> None:
    written = [f"{v:g}" for v in (grid.spacing, grid.radius, grid.payoff)]
    got = actions.grid_problem(grid, written)
    assert got is not None and got[0] == at and words in got[1]


@pytest.mark.parametrize(
    ("listed", "at", "words"),
    [
        (["hide", "inject"], None, ""),
        (["hide", "hide"], 1, "attack action 'hide' is allowed twice"),
        (["inject", "fabricate"], 1, "unknown attack action 'fabricate': allow takes"),
        (["end"], 0, "'end' is a keyword, not an action"),
    ],
)
def test_an_allow_list_names_each_registered_action_once(
    listed: list[str], at: int | None, words: str
) -> None:
    got = actions.allow_problem(listed, {"end", "minimize"}, listed)
    if at is None:
        assert got is None
    else:
        assert got is not None and got[0] == at and words in got[1]
