"""The compiled depth-first pass of ``levels`` (lesmc/engines/compiled.py, issue 62) forced on
from the first label, against the brute force on random models and knapsacks.

The kernel is run as plain Python (the same function numba compiles), so these tests need
no numba; one test compares the compiled kernel too, when numba is installed.
"""

from __future__ import annotations

import math
import random
from collections.abc import Iterator
from contextlib import contextmanager

import numpy as np
import pytest
from hypothesis import HealthCheck, assume, given, settings
from hypothesis import strategies as st
from oracle import brute_force
from test_engines import OPS, _bound_property

from lesmc.common.budget import Budget
from lesmc.engines import compiled, level_compiled, levels
from lesmc.engines.check import to_result
from lesmc.engines.level_bounds import LevelBounds
from lesmc.engines.space import build_space
from lesmc.language.parser import parse_spec
from lesmc.language.semantics import bind
from lesmc.model.knapsack import Item, knapsack_lts, knapsack_spec
from lesmc.model.lts import to_arrays
from lesmc.model.random_models import RandomModelConfig, random_lts

SUMS = ["payoff", "count", "dist.sum({a}..{b})", "dist.at({b})"]


@contextmanager
def forced(kernel: object = None) -> Iterator[None]:
    """levels hands the optimum to the compiled pass at once, run by ``kernel`` (default:
    the plain Python function). The dives' beam has no width, so that every dive drops
    labels: a dive that kept them all would be the exact pass, and no pass would follow."""
    saved = (levels.COMPILED_AFTER, compiled._kernel, compiled._tried, levels.VALUE_CELLS)
    beam = levels.BEAM
    levels.COMPILED_AFTER, levels.VALUE_CELLS = 0, -1  # no value table (values.py) either
    levels.BEAM = 0
    compiled._kernel, compiled._tried = kernel or compiled.dfs_chunk, True
    try:
        yield
    finally:
        levels.COMPILED_AFTER, compiled._kernel, compiled._tried, levels.VALUE_CELLS = saved
        levels.BEAM = beam


@st.composite
def sum_cases(draw: st.DrawFn) -> tuple:
    """Random DAGs (shared states, halts, real or integer values) and a property whose
    objective and constraint are sums, the constraint ``>`` or ``>=`` a bound."""
    cfg = RandomModelConfig(
        steps=draw(st.integers(2, 7)),
        width=draw(st.integers(1, 5)),
        branching=(1, draw(st.integers(1, 4))),
        dim=draw(st.integers(1, 3)),
        halt_prob=draw(st.sampled_from([0.0, 0.1, 0.3])),
        covariance=True,
        tree=draw(st.booleans()),
        integer_values=draw(st.booleans()),
    )
    model = random_lts(cfg, draw(st.integers(0, 2**31)))
    e = model.end
    l = draw(st.integers(1, e))
    u = draw(st.integers(l, e))
    end = draw(st.integers(u, e))
    a = draw(st.integers(0, end))
    b = draw(st.integers(a, end))
    obj = draw(st.sampled_from(SUMS)).format(a=a, b=b)
    con = draw(st.sampled_from(SUMS)).format(a=draw(st.integers(0, b)), b=b)
    op = draw(st.sampled_from([">", ">="]))
    norm = draw(st.sampled_from(["1", "2", "inf"]))
    monitor = draw(st.sampled_from(["", "monitor uncertainty tolerance 0.2"]))
    return model, (l, u, end, obj, con, op, norm, monitor), draw(st.floats(0.5, 1))


@settings(max_examples=300, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(sum_cases())
def test_compiled_pass_equals_brute_force(case: tuple) -> None:
    """Optimum, θ*, the counterexample's own values and the verdict: the brute force's."""
    model, params, quantile = case
    bp = _bound_property(model, params, quantile)
    truth = brute_force(model, bp)
    by_states = {tuple(p): (o, c) for p, o, c in truth.paths}
    space = build_space(to_arrays(model), bp)
    with forced():
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
        fails = not OPS[bp.prop.holds_op](o, bp.prop.threshold)
        assert (r.counterexample is not None) == fails
    if truth.witness_value is not None:
        assert r.witness_value == pytest.approx(truth.witness_value, rel=1e-12, abs=1e-12)


@settings(max_examples=150, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(sum_cases(), st.integers(1, 40))
def test_compiled_pass_under_a_budget_brackets_the_truth(case: tuple, budget: int) -> None:
    """Stopped by ``max_states`` in the compiled pass, the bounds still contain the truth."""
    model, params, quantile = case
    bp = _bound_property(model, params, quantile)
    truth = brute_force(model, bp)
    space = build_space(to_arrays(model), bp)
    with forced():
        r = to_result(space, levels.level_search(space, Budget(max_states=budget)))
    tol = 1e-9 * max(1.0, abs(truth.optimum)) if math.isfinite(truth.optimum) else 0
    assert r.lower - tol <= truth.optimum <= r.upper + tol
    if r.optimum is not None:
        assert r.optimum == pytest.approx(truth.optimum, rel=1e-12, abs=1e-12)


def knapsack(seed: int, n: int, real: bool) -> tuple[list[Item], float]:
    rng = random.Random(seed)
    items = [
        Item(rng.uniform(1, 1000) if real else float(rng.randint(1, 10**6)), rng.randint(1, 999))
        for _ in range(n)
    ]
    return items, sum(i.capacity for i in items) / 2


def brute_knapsack(items: list[Item], demand: float) -> float:
    """The cheapest subset whose capacity exceeds the demand, over all subsets."""
    cost, cap = np.zeros(1), np.zeros(1)
    for it in items:
        cost, cap = np.r_[cost, cost + it.cost], np.r_[cap, cap + it.capacity]
    return float(cost[cap > demand].min())


def solve(items: list[Item], demand: float) -> tuple[float | None, dict[str, object], list[str]]:
    model = knapsack_lts(items)
    spec = parse_spec(knapsack_spec(len(items), demand, 0.0), "<knapsack>")
    bp = bind(spec, spec.properties[0], model.end, model.components, model.has_covariance)
    space = build_space(model, bp)
    r = to_result(space, levels.level_search(space))
    assert r.stats.stopped == "finished"
    assert r.cheapest is not None
    return r.optimum, r.stats.extra, list(r.cheapest.states)


@pytest.mark.parametrize("real", [False, True])
@pytest.mark.parametrize("seed", range(3))
def test_compiled_pass_on_knapsacks(seed: int, real: bool) -> None:
    """n = 16: the compiled pass decides the optimum, the brute force's; its path takes
    items whose costs add up to it and whose capacities exceed the demand."""
    items, demand = knapsack(seed, 16, real)
    with forced():
        opt, extra, states = solve(items, demand)
    assert extra.get("compiled") is True
    want = brute_knapsack(items, demand)
    assert opt == pytest.approx(want, rel=1e-12)
    taken = [i for i, s in enumerate(states[1:]) if s.endswith(":1")]
    assert sum(items[i].cost for i in taken) == pytest.approx(want, rel=1e-12)
    assert sum(items[i].capacity for i in taken) > demand


def test_numba_kernel_equals_the_python_one() -> None:
    """With numba installed, the compiled kernel gives the Python function's answers."""
    numba = pytest.importorskip("numba")
    run = numba.njit(cache=False)(compiled.dfs_chunk)
    for seed in range(3):
        items, demand = knapsack(seed, 20, real=seed == 2)
        with forced():
            want = solve(items, demand)
        with forced(run):
            got = solve(items, demand)
        assert got[0] == want[0] == pytest.approx(brute_knapsack(items, demand), rel=1e-12)
        assert got[1].get("compiled") is True


def test_without_numba_the_exact_pass_has_no_cap() -> None:
    """No kernel (numba missing): the exact pass is not capped (no label of it is spent
    twice), and the optimum is the brute force's."""
    items, demand = knapsack(5, 16, real=False)
    saved = (levels.COMPILED_AFTER, compiled._kernel, compiled._tried, levels.BEAM)
    try:
        levels.COMPILED_AFTER, compiled._kernel, compiled._tried = 3, None, True
        levels.BEAM = 0  # dives that drop labels: the exact pass runs (see forced)
        opt, extra, _ = solve(items, demand)
        levels.COMPILED_AFTER = 10**12  # never reached: the same search, uncapped
        _, plain, _ = solve(items, demand)
    finally:
        levels.COMPILED_AFTER, compiled._kernel, compiled._tried, levels.BEAM = saved
    assert "compiled" not in extra
    assert extra["optimum_states"] == plain["optimum_states"]
    assert opt == brute_knapsack(items, demand)


def test_a_kernel_that_will_not_load_leaves_the_exact_pass_to_decide(
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    """numba found but not importable: the capped exact pass runs again without the cap."""
    items, demand = knapsack(6, 16, real=True)
    monkeypatch.setattr(levels, "COMPILED_AFTER", 0)
    monkeypatch.setattr(levels, "BEAM", 0)  # dives that drop labels: the exact pass runs
    monkeypatch.setattr(compiled, "available", lambda: True)
    monkeypatch.setattr(compiled, "kernel", lambda: None)
    opt, extra, _ = solve(items, demand)
    assert "compiled" not in extra
    assert opt == pytest.approx(brute_knapsack(items, demand), rel=1e-12)


def test_shared_dag_sum_property_is_decided_by_the_compiled_pass() -> None:
    """A random DAG with shared states: the pass applies (sums, ``>``) and agrees."""
    model = random_lts(RandomModelConfig(steps=7, width=5, branching=(2, 3)), seed=3)
    spec = parse_spec(
        "property p { attack window 1..end minimize payoff "
        "subject to dist.sum(0..end) > 40 holds if optimum > 1 }"
    )
    bp = bind(spec, spec.properties[0], model.end, model.components, False)
    space = build_space(to_arrays(model), bp)
    with forced():
        out = levels.level_search(space)
    assert out.stats.extra.get("compiled") is True
    assert out.optimum == pytest.approx(brute_force(model, bp).optimum, rel=1e-12)


@st.composite
def full_window_cases(draw: st.DrawFn) -> tuple:
    """As :func:`sum_cases`, with the attack window over every step and measures that add
    up over all of it (so that the Lagrangian table, and with it the pass, applies often)."""
    model, (_, _, _, _, _, op, norm, monitor), quantile = draw(sum_cases())
    e = model.end
    whole = ["payoff", "count", "dist.sum(0..end)"]
    obj, con = draw(st.sampled_from(whole)), draw(st.sampled_from(whole))
    return model, (1, e, e, obj, con, op, norm, monitor), quantile


@settings(
    max_examples=300,
    deadline=None,
    suppress_health_check=[HealthCheck.too_slow, HealthCheck.filter_too_much],
)
@given(full_window_cases())
def test_compiled_pass_alone_finds_the_optimum_from_no_incumbent(case: tuple) -> None:
    """The pass by itself, from an infinite incumbent (no dive): the brute-force optimum,
    and a path whose own sums (recomputed here from the transitions) are that optimum and
    violate the constraint."""
    from lesmc.engines.result import Stats

    model, params, quantile = case
    bp = _bound_property(model, params, quantile)
    truth = brute_force(model, bp)
    space = build_space(to_arrays(model), bp)
    bounds = LevelBounds(space)
    assume(level_compiled.applies(space, bounds))
    stats = Stats(engine="levels")
    best, path, lower, why = level_compiled.optimum(
        space, bounds, Budget().search(None), stats, math.inf, None, compiled.dfs_chunk
    )
    assert why is None and lower == best
    if math.isinf(truth.optimum):
        assert best == math.inf and path is None
        return
    assert best == pytest.approx(truth.optimum, rel=1e-12, abs=1e-12)
    assert path is not None
    q, o, c = space.root, space.root_obj, space.root_con
    for t in path:
        assert space.cm.src[t] == q
        q, o, c = int(space.cm.dst[t]), o + space.c_obj[t], c + space.c_con[t]
    assert space.leaves()[q]
    to, tc = space.tail(q)
    assert o + to == pytest.approx(best, rel=1e-12, abs=1e-12)
    assert space.violates(c + tc)
