"""levels: a dive whose beam kept every label is the exact pass (docs/engines.md, "dives").

The optimum of random knapsacks is compared with an enumeration of every subset of the
items; the engine runs its label passes (the value table is switched off), with its own
beam (wide enough for every level of 8 items: the first dive is then the whole search)
and with a beam of 2 (the dives drop labels and the exact pass must still run).
"""

from __future__ import annotations

import itertools
import math
import random

import pytest

from lesmc.common.budget import Budget
from lesmc.engines import levels
from lesmc.engines.space import build_space
from lesmc.language.parser import parse_spec
from lesmc.language.semantics import bind
from lesmc.model.knapsack import Item, knapsack_lts, knapsack_spec

#: Random instances per test (each a few milliseconds).
DRAWS = 20


def subsets_optimum(items: list[Item], demand: float) -> float:
    """The least total cost of a subset whose capacity is past ``demand`` (+inf if none),
    by listing every subset; costs summed in item order, as a path sums them."""
    best = math.inf
    for taken in itertools.product((False, True), repeat=len(items)):
        cap = sum(it.capacity for it, t in zip(items, taken, strict=True) if t)
        if cap > demand:
            cost = 0.0
            for it, t in zip(items, taken, strict=True):
                cost += it.cost if t else 0.0
            best = min(best, cost)
    return best


def draw(rng: random.Random, n: int, integer: bool) -> tuple[list[Item], int]:
    """n items (integer costs up to 10^6, or real ones) and a demand of about half their
    capacity."""
    items = [
        Item(
            float(rng.randint(1, 10**6)) if integer else rng.uniform(0.1, 1000.0),
            float(rng.randint(1, 100)),
        )
        for _ in range(n)
    ]
    demand = int(sum(it.capacity for it in items) * rng.uniform(0.2, 0.8))
    return items, demand


def search(items: list[Item], demand: int) -> tuple[float, dict[str, object], list[int] | None]:
    """levels' optimum, stats and counterexample on the knapsack of ``items``."""
    model = knapsack_lts(items)
    spec = parse_spec(knapsack_spec(len(items), demand, 0.0), "<knapsack>")
    bp = bind(spec, spec.properties[0], model.end, model.components, False)
    out = levels.level_search(build_space(model, bp), Budget())
    return out.optimum, out.stats.extra, out.counterexample


def taken_cost(items: list[Item], path: list[int] | None) -> float:
    """The cost of the items a counterexample takes: the states ``i:1`` it enters."""
    assert path is not None
    model = knapsack_lts(items)
    assert model.ids is not None
    ids = [model.ids[int(model.dst[t])] for t in path]
    return sum(items[int(i.split(":")[0]) - 1].cost for i in ids if i.endswith(":1"))


@pytest.mark.parametrize("integer", [True, False])
def test_a_dive_that_kept_every_label_proves_the_optimum(
    integer: bool, monkeypatch: pytest.MonkeyPatch
) -> None:
    monkeypatch.setattr(levels, "VALUE_CELLS", 0)  # the label passes, not the value table
    rng = random.Random(62_7 + integer)
    for _ in range(DRAWS):
        items, demand = draw(rng, 8, integer)
        opt, extra, path = search(items, demand)
        assert "value_cells" not in extra
        assert opt == pytest.approx(subsets_optimum(items, demand), rel=1e-12, abs=0.0)
        # 8 items: at most 2^8 = 256 labels a level, the beam's width; no exact pass ran
        assert extra.get("dive_exact") is True
        assert extra["optimum_states"] == extra["dive_states"]
        if math.isfinite(opt):
            assert taken_cost(items, path) == pytest.approx(opt, rel=1e-12, abs=0.0)


@pytest.mark.parametrize("integer", [True, False])
def test_a_dive_that_dropped_labels_leaves_the_optimum_to_the_exact_pass(
    integer: bool, monkeypatch: pytest.MonkeyPatch
) -> None:
    monkeypatch.setattr(levels, "VALUE_CELLS", 0)
    monkeypatch.setattr(levels, "BEAM", 2)
    rng = random.Random(62_70 + integer)
    exact_passes = 0
    for _ in range(DRAWS):
        items, demand = draw(rng, 10, integer)
        opt, extra, _ = search(items, demand)
        assert opt == pytest.approx(subsets_optimum(items, demand), rel=1e-12, abs=0.0)
        exact_passes += "dive_exact" not in extra
    assert exact_passes >= DRAWS // 4  # a beam of 2 drops labels on many of them
