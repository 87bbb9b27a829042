"""The value table of ``levels`` (lesmc/engines/values.py, issue 62 third round): the
optimum and θ* of integer sums, against the brute force on random models and knapsacks."""

from __future__ import annotations

import math
import random

import pytest
from hypothesis import HealthCheck, given, settings
from oracle import brute_force
from test_engine_compiled import brute_knapsack, sum_cases
from test_engines import _bound_property

from lesmc.common.budget import Budget
from lesmc.engines import levels
from lesmc.engines.check import to_result
from lesmc.engines.result import CheckResult
from lesmc.engines.space import build_space
from lesmc.language.parser import parse_spec
from lesmc.language.semantics import bind
from lesmc.model.knapsack import Item, knapsack_lts, knapsack_spec
from lesmc.model.lts import to_arrays


def brute_theta(items: list[Item], demand: float, opt: float) -> float:
    """The largest cost below ``opt`` over all subsets, by listing them."""
    costs = [0.0]
    for it in items:
        costs += [c + it.cost for c in costs]
    return max(c for c in costs if c < opt)


def knapsack_result(items: list[Item], demand: float, limits: Budget | None = None) -> CheckResult:
    model = knapsack_lts(items)
    spec = parse_spec(knapsack_spec(len(items), demand, 0.0), "<knapsack>")
    bp = bind(spec, spec.properties[0], model.end, model.components, model.has_covariance)
    space = build_space(model, bp)
    return to_result(space, levels.level_search(space, limits))


@pytest.mark.parametrize("seed", range(6))
def test_value_table_decides_small_knapsacks(seed: int) -> None:
    """n = 14, integer costs: the table decides (no label pass), the optimum and θ* are
    the brute force's, and both paths take items that add up to them."""
    rng = random.Random(seed)
    items = [Item(float(rng.randint(1, 300)), float(rng.randint(1, 300))) for _ in range(14)]
    demand = sum(i.capacity for i in items) / 2
    r = knapsack_result(items, demand)
    assert r.stats.stopped == "finished"
    assert "value_cells" in r.stats.extra
    want = brute_knapsack(items, demand)
    assert r.optimum == want
    assert r.witness_value == brute_theta(items, demand, want)
    assert r.cheapest is not None and r.witness is not None
    taken = [i for i, s in enumerate(r.cheapest.states[1:]) if s.endswith(":1")]
    assert sum(items[i].cost for i in taken) == want
    assert sum(items[i].capacity for i in taken) > demand
    chosen = [i for i, s in enumerate(r.witness.states[1:]) if s.endswith(":1")]
    assert sum(items[i].cost for i in chosen) == r.witness_value


def test_real_costs_and_big_tables_go_to_the_label_passes() -> None:
    """No grain (real costs), or a table past VALUE_CELLS: the label passes decide,
    with the same optimum."""
    rng = random.Random(7)
    real = [Item(rng.uniform(1, 300), float(rng.randint(1, 300))) for _ in range(12)]
    demand = sum(i.capacity for i in real) / 2
    r = knapsack_result(real, demand)
    assert "value_cells" not in r.stats.extra
    assert r.optimum == pytest.approx(brute_knapsack(real, demand), rel=1e-12)
    ints = [Item(float(rng.randint(1, 300)), float(rng.randint(1, 300))) for _ in range(12)]
    demand = sum(i.capacity for i in ints) / 2
    saved = levels.VALUE_CELLS
    try:
        levels.VALUE_CELLS = 10
        plain = knapsack_result(ints, demand)
    finally:
        levels.VALUE_CELLS = saved
    table = knapsack_result(ints, demand)
    assert "value_cells" not in plain.stats.extra and "value_cells" in table.stats.extra
    assert plain.optimum == table.optimum == brute_knapsack(ints, demand)
    assert plain.witness_value == table.witness_value


def test_a_state_budget_below_the_table_leaves_it_to_the_label_passes() -> None:
    """A table bigger than the state budget is not built: the label passes stop at the
    budget with proven bounds around the truth."""
    rng = random.Random(3)
    items = [Item(float(rng.randint(1, 300)), float(rng.randint(1, 300))) for _ in range(14)]
    demand = sum(i.capacity for i in items) / 2
    r = knapsack_result(items, demand, Budget(max_states=50))
    assert "value_cells" not in r.stats.extra
    want = brute_knapsack(items, demand)
    assert r.stats.stopped == "max_states"
    assert r.lower <= want <= r.upper


@settings(max_examples=300, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(sum_cases())
def test_value_table_equals_brute_force(case: tuple) -> None:
    """Random DAGs (shared states, halts, monitors): wherever the table decides, the
    optimum, θ*, the counterexample's own values and the verdict are the brute force's."""
    model, params, quantile = case
    bp = _bound_property(model, params, quantile)
    truth = brute_force(model, bp)
    by_states = {tuple(p): (o, c) for p, o, c in truth.paths}
    space = build_space(to_arrays(model), bp)
    r = to_result(space, levels.level_search(space))
    assert r.stats.stopped == "finished"
    if math.isinf(truth.optimum):
        assert r.optimum == math.inf
        assert r.counterexample is None
    else:
        assert r.optimum == pytest.approx(truth.optimum, rel=1e-12, abs=1e-12)
        assert r.cheapest is not None
        o, c = by_states[r.cheapest.states]
        assert o == pytest.approx(truth.optimum, rel=1e-12, abs=1e-12)
        assert (r.cheapest.objective, r.cheapest.constraint) == pytest.approx((o, c))
    if truth.witness_value is not None:
        assert r.witness_value == pytest.approx(truth.witness_value, rel=1e-12, abs=1e-12)
        assert r.witness is not None
        assert by_states[r.witness.states][0] == pytest.approx(truth.witness_value, rel=1e-12)
