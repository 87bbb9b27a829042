"""θ* from the values each state reaches, as bit sets (meet._theta_by_bits, issue 62),
against listing every subset of a knapsack and against the brute force on random models."""

from __future__ import annotations

import itertools
import math
import random

import pytest
from hypothesis import HealthCheck, given, settings
from oracle import brute_force
from test_engines import _bound_property, cases

from lesmc.common.budget import Budget
from lesmc.engines import meet
from lesmc.engines.result import Stats
from lesmc.engines.space import Space, build_space
from lesmc.language.parser import parse_spec
from lesmc.language.semantics import bind
from lesmc.model.knapsack import Item, knapsack_lts, knapsack_spec
from lesmc.model.lts import to_arrays


def _space(items: list[Item], demand: float) -> Space:
    model = knapsack_lts(items)
    spec = parse_spec(knapsack_spec(len(items), demand, 0.0), "<knapsack>")
    bp = bind(spec, spec.properties[0], model.end, model.components, model.has_covariance)
    return build_space(model, bp)


def _path_cost(space: Space, path: list[int]) -> float:
    """The objective of a path's transitions, summed here (not by the engine)."""
    assert int(space.cm.src[path[0]]) == space.root
    for a, b in itertools.pairwise(path):
        assert int(space.cm.dst[a]) == int(space.cm.src[b])
    assert bool(space.leaves()[int(space.cm.dst[path[-1]])])
    return space.root_obj + math.fsum(float(space.c_obj[t]) for t in path)


@pytest.mark.parametrize("seed", range(8))
def test_knapsack_theta_is_the_largest_subset_cost_below_any_bound(seed: int) -> None:
    """Below an arbitrary bound (not only the optimum), the largest subset cost, and a path
    that costs exactly it."""
    rng = random.Random(seed)
    items = [Item(float(rng.randint(1, 5000)), float(rng.randint(1, 50))) for _ in range(13)]
    space = _space(items, sum(i.capacity for i in items) / 2)
    costs = [0.0]
    for it in items:
        costs += [c + it.cost for c in costs]
    below = float(rng.randint(1, int(sum(i.cost for i in items))))
    want = max(c for c in costs if c < below)
    got = meet._theta_by_bits(space, Budget().search(None), Stats(engine="levels"), below, -1.0)
    assert got is not None
    value, path = got
    assert value == want
    assert path is not None and _path_cost(space, path) == want
    # nothing above ``best`` below the bound: a proof, no path
    proof = meet._theta_by_bits(space, Budget().search(None), Stats(engine="levels"), below, want)
    assert proof == (want, None)


def test_real_costs_and_too_many_bits_do_not_apply(monkeypatch: pytest.MonkeyPatch) -> None:
    items = [Item(1.5, 2.0), Item(2.25, 3.0), Item(3.0, 1.0)]
    space = _space(items, 3.0)
    assert meet._theta_by_bits(space, Budget().search(None), Stats(engine="x"), 5.0, -1.0) is None
    whole = _space([Item(3.0, 2.0), Item(4.0, 3.0), Item(5.0, 1.0)], 3.0)
    monkeypatch.setattr(meet, "REACH_BITS", 10)
    assert meet._theta_by_bits(whole, Budget().search(None), Stats(engine="x"), 9.0, -1.0) is None


@settings(max_examples=200, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(cases())
def test_random_models_where_it_applies(case: tuple) -> None:  # type: ignore[type-arg]
    """Where the bit sets apply (integer sums), θ* below the brute force's optimum is the
    brute force's θ*, and the path has that objective."""
    model, params, quantile = case
    bp = _bound_property(model, params, quantile)
    truth = brute_force(model, bp)
    if not math.isfinite(truth.optimum) or truth.witness_value is None:
        return
    space = build_space(to_arrays(model), bp)
    got = meet._theta_by_bits(
        space, Budget().search(None), Stats(engine="x"), truth.optimum, -math.inf
    )
    if got is None:
        return
    value, path = got
    assert value == pytest.approx(truth.witness_value, rel=1e-12, abs=1e-12)
    if path:
        assert _path_cost(space, path) == pytest.approx(value, rel=1e-12, abs=1e-12)


@pytest.mark.parametrize("seed", range(25))
def test_integer_random_models(seed: int) -> None:
    """Random DAGs with shared states and integer payoffs (the bit sets apply): θ* is the
    brute force's and the path costs it."""
    from lesmc.model.random_models import RandomModelConfig, random_lts

    rng = random.Random(seed)
    cfg = RandomModelConfig(
        steps=rng.randint(3, 6),
        width=rng.randint(2, 5),
        branching=(1, rng.randint(2, 4)),
        dim=2,
        halt_prob=0.0,
        covariance=True,
        integer_values=True,
    )
    model = random_lts(cfg, seed)
    e = model.end
    params = (1, e, e, "payoff", f"dist.sum(0..{e})", ">", "1", "")
    bp = _bound_property(model, params, rng.random())
    truth = brute_force(model, bp)
    if not math.isfinite(truth.optimum) or truth.witness_value is None:
        pytest.skip("no optimum or no path below it")
    space = build_space(to_arrays(model), bp)
    got = meet._theta_by_bits(
        space, Budget().search(None), Stats(engine="x"), truth.optimum, -math.inf
    )
    assert got is not None
    value, path = got
    assert value == truth.witness_value
    assert path is not None and _path_cost(space, path) == value
