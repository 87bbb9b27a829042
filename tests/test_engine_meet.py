"""θ* by the exact meet-in-the-middle pass of ``levels`` (issue 62), against independent
enumerations of the knapsack's subsets."""

from __future__ import annotations

import itertools
import random

import numpy as np
import pytest

from lesmc.common.budget import Budget
from lesmc.engines.check import check_bound
from lesmc.language.parser import parse_spec
from lesmc.language.semantics import bind
from lesmc.model.knapsack import Item, knapsack_lts, knapsack_spec


def run(items: list[Item], demand: float, max_states: int | None = None) -> tuple[float, float]:
    """(optimum, θ*) from ``levels``, which must have finished."""
    model = knapsack_lts(items)
    spec = parse_spec(knapsack_spec(len(items), demand, 0.0), "<knapsack>")
    bp = bind(spec, spec.properties[0], model.end, model.components, model.has_covariance)
    r = check_bound(model, bp, "levels", Budget(max_states=max_states))
    assert r.stats.stopped == "finished", r.stats.stopped
    assert r.optimum is not None and r.witness_exact
    return r.optimum, r.witness_value


def subsets(items: list[Item]) -> tuple[np.ndarray, np.ndarray]:
    """(cost, capacity) of every subset of ``items``."""
    cost = np.zeros(1)
    cap = np.zeros(1)
    for it in items:
        cost = np.concatenate([cost, cost + it.cost])
        cap = np.concatenate([cap, cap + it.capacity])
    return cost, cap


def brute(items: list[Item], demand: float) -> tuple[float, float]:
    """(optimum, θ*) over all subsets: the cheapest whose capacity exceeds the demand, and
    the largest cost below it (any subset: one below the optimum cannot exceed it)."""
    cost, cap = subsets(items)
    opt = float(cost[cap > demand].min())
    return opt, float(cost[cost < opt].max())


def halves(items: list[Item], demand: float) -> tuple[float, float]:
    """The same by meet in the middle (for n too large for :func:`brute`)."""
    a_cost, a_cap = subsets(items[: len(items) // 2])
    b_cost, b_cap = subsets(items[len(items) // 2 :])
    # optimum: per subset of the first half, the cheapest of the second with capacity
    # above demand − its own
    order = np.argsort(b_cap)
    caps, tail_min = b_cap[order], np.minimum.accumulate(b_cost[order][::-1])[::-1]
    j = np.searchsorted(caps, demand - a_cap, side="right")
    ok = j < caps.size
    opt = float((a_cost[ok] + tail_min[j[ok]]).min())
    # θ*: the largest a + b below opt
    b_sorted = np.unique(b_cost)
    k = np.searchsorted(b_sorted, opt - a_cost, side="left") - 1
    ok = k >= 0
    return opt, float((a_cost[ok] + b_sorted[k[ok]]).max())


@pytest.mark.parametrize("seed", range(8))
def test_real_costs_theta_equals_brute_force(seed: int) -> None:
    """Real-valued costs have no common grain, so the dives never prove θ* and the exact
    pass (meeting the suffix table) always decides it."""
    rng = random.Random(seed)
    items = [Item(rng.uniform(0.5, 50.0), float(rng.randint(1, 40))) for _ in range(16)]
    demand = sum(i.capacity for i in items) / 2
    opt, theta = run(items, demand)
    want_opt, want_theta = brute(items, demand)
    assert opt == pytest.approx(want_opt, rel=1e-12)
    assert theta == pytest.approx(want_theta, rel=1e-12)
    assert theta < opt


@pytest.mark.parametrize("seed", [0, 1])
def test_large_weights_theta_is_exact_within_a_small_budget(seed: int) -> None:
    """n = 32, costs up to 10^6: θ* is a subset sum that the dives miss. Meeting the suffix
    table halfway ends it in about 25,000 labels; a pass over every level took 0.8 M and
    8.9 M labels on these two instances."""
    rng = random.Random(seed * 1000 + 32)
    cap = [rng.randint(1, 10**6) for _ in range(32)]
    cost = [rng.randint(1, 10**6) for _ in range(32)]
    items = [Item(float(c), float(g)) for c, g in zip(cost, cap, strict=True)]
    demand = sum(cap) // 2
    opt, theta = run(items, demand, max_states=200_000)
    want_opt, want_theta = halves(items, demand)
    assert (opt, theta) == (want_opt, want_theta)


def test_halves_agrees_with_brute_force() -> None:
    """The test's own meet in the middle against full enumeration."""
    rng = random.Random(7)
    items = [Item(float(rng.randint(1, 999)), float(rng.randint(1, 999))) for _ in range(14)]
    demand = sum(i.capacity for i in items) / 2
    assert halves(items, demand) == brute(items, demand)


def test_itertools_agrees_with_subsets() -> None:
    """:func:`subsets` lists every subset's cost once."""
    items = [Item(float(c), 1.0) for c in (3, 5, 11, 20)]
    want = sorted(sum(s) for k in range(5) for s in itertools.combinations([3, 5, 11, 20], k))
    assert sorted(subsets(items)[0].tolist()) == want
