"""Engines against an independent brute force, and against each other (hypothesis)."""

from __future__ import annotations

import itertools
import math
import operator

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st
from oracle import brute_force

from lesmc.common.budget import Budget
from lesmc.engines.check import check_bound
from lesmc.engines.space import build_space
from lesmc.language.parser import parse_spec
from lesmc.language.semantics import bind
from lesmc.model.lts import to_arrays
from lesmc.model.random_models import RandomModelConfig, random_lts

#: The comparisons of ``holds if``, written out again (section 4).
OPS = {">": operator.gt, ">=": operator.ge, "<": operator.lt, "<=": operator.le}

ENGINES = [
    pytest.param({"engine": "enumerate"}, id="enumerate"),
    pytest.param({"engine": "bnb"}, id="bnb"),
    pytest.param({"engine": "levels"}, id="levels"),
]

MEASURES = [
    "payoff",
    "payoff.mean",
    "count",
    "count.frames",
    "dist.sum({a}..{b})",
    "dist.max({a}..{b})",
    "dist.at({b})",
]


@st.composite
def cases(draw: st.DrawFn) -> tuple:
    steps = draw(st.integers(2, 7))
    cfg = RandomModelConfig(
        steps=steps,
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
    obj = draw(st.sampled_from(MEASURES)).format(a=a, b=b)
    con = draw(st.sampled_from(MEASURES)).format(a=draw(st.integers(0, b)), b=b)
    op = draw(st.sampled_from([">", ">=", "<", "<="]))
    norm = draw(st.sampled_from(["1", "2", "inf"]))
    monitor = draw(
        st.sampled_from(
            [
                "",
                "monitor uncertainty",
                "monitor uncertainty tolerance 0.2",
                "monitor uncertainty except original",
                "monitor uncertainty tolerance 0.2 except original",
            ]
        )
    )
    return model, (l, u, end, obj, con, op, norm, monitor), draw(st.floats(0, 1))


def _spec(params: tuple, bound: float) -> str:
    l, u, end, obj, con, op, norm, monitor = params
    return (
        f"property p {{ attack window {l}..{u} end {end} minimize {obj} "
        f"subject to {con} {op} {bound!r} holds if optimum > 1 norm {norm} {monitor} }}"
    )


def _bound_property(model, params, quantile, names=None, tracks=None):  # type: ignore[no-untyped-def]
    """Pick the constraint threshold among the values that occur, so both P+ and P− are used
    (``names``, ``tracks``: ground-truth tracks' components and positions, for dist.nearest)."""
    spec = parse_spec(_spec(params, 0.0))
    bp = bind(spec, spec.properties[0], model.end, model.components, True, names)
    paths = brute_force(model, bp, tracks=tracks).paths
    values = sorted(v for _, _, v in paths if math.isfinite(v)) or [0.0]
    threshold = values[min(int(quantile * len(values)), len(values) - 1)]
    spec = parse_spec(_spec(params, threshold))
    return bind(spec, spec.properties[0], model.end, model.components, True, names)


def _assert_optimum_and_theta(r, truth) -> None:  # type: ignore[no-untyped-def]
    """A result's optimum and θ* are the brute force's (math.inf for an infinite optimum)."""
    if math.isinf(truth.optimum):
        assert r.optimum == math.inf
    else:
        assert r.optimum == pytest.approx(truth.optimum, rel=1e-12, abs=1e-12)
    if truth.witness_value is not None:
        assert r.witness_value == pytest.approx(truth.witness_value, rel=1e-12, abs=1e-12)


@settings(max_examples=300, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(cases())
def test_optimum_and_witness_equal_brute_force(case: tuple) -> None:
    model, params, quantile = case
    bp = _bound_property(model, params, quantile)
    truth = brute_force(model, bp)
    cm = to_arrays(model)
    by_states = {tuple(p): (o, c) for p, o, c in truth.paths}
    for engine in ("enumerate", "bnb", "levels"):
        r = check_bound(cm, bp, engine)  # type: ignore[arg-type]
        assert r.stats.stopped == "finished"
        if math.isinf(truth.optimum):
            assert r.optimum == math.inf
            assert r.cheapest is None or math.isinf(r.cheapest.objective)
            assert r.counterexample is None
        else:
            assert r.optimum == pytest.approx(truth.optimum, rel=1e-12, abs=1e-12)
            assert r.cheapest is not None
            o, c = by_states[r.cheapest.states]
            assert o == pytest.approx(truth.optimum, rel=1e-12, abs=1e-12)
            assert (r.cheapest.objective, r.cheapest.constraint) == pytest.approx((o, c))
            # a counterexample exactly when the optimum fails "holds if" (section 4)
            fails = not OPS[bp.prop.holds_op](o, bp.prop.threshold)
            assert (r.counterexample is not None) == fails == (r.verdict == "violated")
        if truth.witness_value is None:
            assert r.witness is None
        else:
            assert r.witness_value == pytest.approx(truth.witness_value, rel=1e-12, abs=1e-12), (
                engine
            )
            assert by_states[r.witness.states][0] == pytest.approx(truth.witness_value)
        _assert_monitor_facts(model, bp, truth, r)


@settings(max_examples=200, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(cases(), st.lists(st.floats(0.0, 1.5), min_size=1, max_size=4))
def test_exact_lanes_each_find_a_path_below_their_threshold_iff_one_exists(
    case: tuple, fractions: list[float]
) -> None:
    """Lanes side by side in one exact pass (levels._optimum_pass): the incumbent is the
    brute-force optimum when it lies below some lane's cut, and a lane hits exactly when
    the optimum lies below its own (the cut is the threshold, less the grain g when every
    objective is a multiple of g: the pass then looks for objectives of T − g or less)."""
    from lesmc.common.budget import Budget as B
    from lesmc.engines import levels
    from lesmc.engines.level_bounds import LevelBounds
    from lesmc.engines.result import Stats

    model, params, quantile = case
    bp = _bound_property(model, params, quantile)
    opt = brute_force(model, bp).optimum
    scale = opt if math.isfinite(opt) and opt > 0 else 1.0
    tries = np.array(sorted({f * scale for f in fractions}, reverse=True))
    space = build_space(to_arrays(model), bp)
    bounds = LevelBounds(space)
    got = levels._optimum_pass(space, bounds, B().search(None), Stats(engine="levels"), tries, None)
    cuts = [bounds.cut(float(t)) for t in tries]
    assert got.why is None
    if opt < max(cuts):
        assert got.best == pytest.approx(opt, rel=1e-12, abs=1e-12)
        assert got.where is not None
    else:
        assert got.where is None
    assert list(got.hits) == [bool(opt < cut) for cut in cuts]


@settings(max_examples=150, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(cases(), st.integers(1, 5))
def test_dives_side_by_side_change_no_answer(case: tuple, lanes: int) -> None:
    """levels with its bisecting dives run as lanes (as on models unfolded on demand) on
    explicit models: the optimum and θ* of the brute force."""
    from unittest import mock

    from lesmc.engines import levels

    model, params, quantile = case
    bp = _bound_property(model, params, quantile)
    truth = brute_force(model, bp)
    with mock.patch.object(levels, "_dive_lanes", lambda space: lanes):
        r = check_bound(to_arrays(model), bp, "levels")
    assert r.stats.stopped == "finished"
    _assert_optimum_and_theta(r, truth)


@st.composite
def count_cases(draw: st.DrawFn) -> tuple:
    """Trees with wide branching (so that outcomes of rank 2 and more occur) and a property
    minimizing ``count`` or ``count.frames`` over a window of at least two steps."""
    cfg = RandomModelConfig(
        steps=draw(st.integers(3, 6)),
        width=draw(st.integers(2, 5)),
        branching=(1, draw(st.integers(2, 4))),
        dim=2,
        halt_prob=draw(st.sampled_from([0.0, 0.1])),
        covariance=True,
        tree=True,
        integer_values=draw(st.booleans()),
    )
    model = random_lts(cfg, draw(st.integers(0, 2**31)))
    e = model.end
    l = draw(st.integers(1, max(1, e - 1)))
    obj = draw(st.sampled_from(["count", "count.frames"]))
    con = draw(st.sampled_from(["dist.sum(0..end)", "dist.at(end)", "payoff", "count"]))
    params = (l, e, e, obj, con, ">", draw(st.sampled_from(["1", "2", "inf"])), "")
    return model, params, draw(st.floats(0, 0.8))


@settings(max_examples=200, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(count_cases())
def test_count_objectives_equal_brute_force(case: tuple) -> None:
    """``minimize count`` and ``minimize count.frames`` (issue 30): every path's objective as
    the engines compute it, and every engine's optimum, equal the brute force's, counted
    from the definitions (tests/oracle.py)."""
    model, params, quantile = case
    bp = _bound_property(model, params, quantile)
    truth = brute_force(model, bp)
    cm = to_arrays(model)
    space = build_space(cm, bp)
    for states, objective, _ in truth.paths:
        q = [cm.index(s) for s in states]
        edges = [cm.edge(a, b) for a, b in itertools.pairwise(q)]
        got = space.root_obj + sum(float(space.c_obj[t]) for t in edges[bp.l - 1 :])
        assert got == objective, states
    for engine in ("enumerate", "bnb", "levels"):
        r = check_bound(cm, bp, engine)  # type: ignore[arg-type]
        assert r.stats.stopped == "finished"
        if math.isinf(truth.optimum):
            assert r.optimum == math.inf
        else:
            assert r.optimum == truth.optimum, engine


def _model_and_window(draw: st.DrawFn, covariance: bool) -> tuple:
    """A small random model (tree or DAG, halting sometimes) and a window l..u, end."""
    cfg = RandomModelConfig(
        steps=draw(st.integers(2, 6)),
        width=draw(st.integers(1, 4)),
        branching=(1, draw(st.integers(1, 3))),
        dim=draw(st.integers(1, 3)),
        halt_prob=draw(st.sampled_from([0.0, 0.2])),
        covariance=covariance,
        tree=draw(st.booleans()),
        integer_values=draw(st.booleans()),
    )
    model = random_lts(cfg, draw(st.integers(0, 2**31)))
    e = model.end
    l = draw(st.integers(1, e))
    u = draw(st.integers(l, e))
    return model, l, u, draw(st.integers(u, e))


@st.composite
def trend_cases(draw: st.DrawFn) -> tuple:
    """Random models with covariances and a property whose objective or constraint is
    ``tau.rise(a..b)`` (issue 30: the trend of section 9.1), with or without the monitor."""
    model, l, u, end = _model_and_window(draw, covariance=True)
    a = draw(st.integers(1, end))
    b = draw(st.integers(a, end))
    trend = f"tau.rise({a}..{b})"
    other = draw(st.sampled_from(["payoff", "count", f"dist.max(0..{b})", trend]))
    obj, con = (trend, other) if draw(st.booleans()) else (other, trend)
    op = draw(st.sampled_from([">", ">=", "<", "<="]))
    monitor = draw(st.sampled_from(["", "monitor uncertainty tolerance 0.2"]))
    params = (l, u, end, obj, con, op, draw(st.sampled_from(["1", "2", "inf"])), monitor)
    return model, params, draw(st.floats(0, 1))


@settings(max_examples=200, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(trend_cases())
def test_trend_measure_equals_brute_force(case: tuple) -> None:
    """``tau.rise(a..b)`` as objective or constraint: every engine's optimum equals the brute
    force's, which takes τ from each state's P (tests/oracle.py)."""
    model, params, quantile = case
    bp = _bound_property(model, params, quantile)
    assert bp.tau_components is not None
    truth = brute_force(model, bp)
    cm = to_arrays(model)
    for engine in ("enumerate", "bnb", "levels"):
        r = check_bound(cm, bp, engine)  # type: ignore[arg-type]
        assert r.stats.stopped == "finished"
        if math.isinf(truth.optimum):
            assert r.optimum == math.inf, engine
        else:
            assert r.optimum == pytest.approx(truth.optimum, rel=1e-12, abs=1e-12), engine


@st.composite
def nearest_cases(draw: st.DrawFn) -> tuple:
    """Random models with ground-truth tracks (random positions near the states, absent at
    random steps) and a property with ``dist.nearest(k)`` as objective or constraint."""
    model, l, u, end = _model_and_window(draw, covariance=False)
    k = draw(st.integers(0, end))
    near = f"dist.nearest({k})"
    other = draw(st.sampled_from(["payoff", "count", f"dist.max(0..{end})", near]))
    obj, con = (near, other) if draw(st.booleans()) else (other, near)
    op = draw(st.sampled_from([">", ">=", "<", "<="]))
    dim = len(model.components)
    used = draw(st.integers(1, dim))
    seed = draw(st.integers(0, 2**31))
    rng = np.random.default_rng(seed)
    n_tracks = draw(st.integers(0, 3))
    at = rng.normal(scale=3.0, size=(n_tracks, model.end + 1, used))
    at[rng.random((n_tracks, model.end + 1)) < 0.3] = np.nan
    at[:, 0] = rng.normal(size=(n_tracks, used))  # present at least once
    names = model.components[:used]
    on = ", ".join(names)
    params = (l, u, end, obj, con, op, draw(st.sampled_from(["1", "2", "inf"])), f"on {on}")
    return model, params, draw(st.floats(0, 1)), names, at


@settings(max_examples=200, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(nearest_cases())
def test_nearest_track_measure_equals_brute_force(case: tuple) -> None:
    """``dist.nearest(k)``: the deviation from the nearest of the original path and the
    ground-truth tracks present at step k; every engine's optimum equals the brute force's."""
    from lesmc.model.arrays import Tracks

    model, params, quantile, names, at = case
    ids = tuple(f"g{i}" for i in range(len(at)))
    bp = _bound_property(model, params, quantile, names, at)
    truth = brute_force(model, bp, tracks=at)
    cm = to_arrays(model)
    cm.tracks = Tracks(names, ids, at)
    for engine in ("enumerate", "bnb", "levels"):
        r = check_bound(cm, bp, engine)  # type: ignore[arg-type]
        assert r.stats.stopped == "finished"
        if math.isinf(truth.optimum):
            assert r.optimum == math.inf, engine
        else:
            assert r.optimum == pytest.approx(truth.optimum, rel=1e-12, abs=1e-12), engine


def _assert_monitor_facts(model, bp, truth, r) -> None:  # type: ignore[no-untyped-def]
    """``vacuous`` iff the brute force never reaches the unattacked track's end; alarms from P."""
    if bp.monitor_components is None:
        assert r.original_alarms is None and not r.vacuous
        return
    orig = list(model.original[: bp.end + 1])
    reached = any(p == orig for p, _, _ in truth.paths)
    assert r.vacuous == (not reached)
    taus = [sum(model.state(q).P[i, i] for i in bp.monitor_components) for q in orig]
    expect = [
        k
        for k in range(bp.l, len(orig))
        if taus[k] > taus[k - 1] * (1 + bp.monitor_tolerance) + 1e-300
    ]
    assert r.original_alarms == expect


@settings(max_examples=150, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(cases())
def test_engines_agree_and_bounds_do_not_change_answers(case: tuple) -> None:
    from lesmc.engines.bnb import branch_and_bound
    from lesmc.engines.enumerate import enumerate_paths
    from lesmc.engines.space import build_space

    model, params, quantile = case
    bp = _bound_property(model, params, quantile)
    space = build_space(to_arrays(model), bp)
    a = enumerate_paths(space)
    b = branch_and_bound(space, use_bounds=True)
    c = branch_and_bound(space, use_bounds=False)
    assert a.optimum == b.optimum == c.optimum
    wa = [space.c_obj[t] for t in a.witness] if a.witness is not None else None
    for other in (b, c):
        assert (other.witness is None) == (wa is None)


@pytest.mark.parametrize("kw", ENGINES)
def test_budget_exhaustion_reports_unknown_with_bounds(kw: dict) -> None:
    model = random_lts(RandomModelConfig(steps=8, width=8, branching=(3, 4), tree=True), seed=3)
    spec = parse_spec(
        "property p { attack window 1..8 minimize payoff "
        "subject to dist.max(0..end) > 60 holds if optimum > 1 }"
    )
    bp = bind(spec, spec.properties[0], model.end, model.components, False)
    r = check_bound(to_arrays(model), bp, budget=Budget(max_states=3), **kw)
    assert r.stats.stopped == "max_states"
    assert r.verdict == "unknown" and r.optimum is None
    assert r.lower <= r.upper


@settings(max_examples=200, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(cases(), st.integers(1, 60))
def test_budgeted_bounds_contain_the_truth(case: tuple, budget: int) -> None:
    """Under any state budget, the reported bounds contain the true optimum and θ*,
    a reported optimum is the true one, and a counterexample really violates."""
    model, params, quantile = case
    bp = _bound_property(model, params, quantile)
    truth = brute_force(model, bp)
    cm = to_arrays(model)
    by_states = {tuple(p): (o, c) for p, o, c in truth.paths}
    for engine in ("bnb", "levels"):
        r = check_bound(cm, bp, engine, Budget(max_states=budget))  # type: ignore[arg-type]
        tol = 1e-9 * max(1.0, abs(truth.optimum)) if math.isfinite(truth.optimum) else 0
        assert r.lower - tol <= truth.optimum <= r.upper + tol
        if r.optimum is not None:
            assert r.optimum == pytest.approx(truth.optimum, rel=1e-12, abs=1e-12)
        if r.counterexample is not None and math.isfinite(r.counterexample.objective):
            assert r.counterexample.objective >= truth.optimum - tol
            assert r.counterexample.objective <= r.upper + tol
        doc = r.to_dict()
        if doc["optimum"] is None:
            assert math.isinf(truth.optimum)
        if r.witness_bounds is not None and truth.witness_value is not None:
            lo, hi = r.witness_bounds
            assert lo - 1e-9 <= truth.witness_value <= hi + 1e-9
        if r.witness is not None and r.witness_exact:
            assert by_states[r.witness.states][0] == pytest.approx(truth.witness_value)


def _shared_dag() -> tuple:
    """A 10-step random DAG with shared states (47,623 tree nodes) and a robustness property."""
    model = random_lts(RandomModelConfig(steps=10, width=6, branching=(3, 4)), seed=11)
    spec = parse_spec(
        "property p { attack window 2..9 minimize payoff "
        "subject to dist.sum(0..end) > 300 holds if optimum > 1 }"
    )
    bp = bind(spec, spec.properties[0], model.end, model.components, False)
    return to_arrays(model), bp


def test_bnb_expands_far_fewer_states_than_enumerate_on_shared_dags() -> None:
    cm, bp = _shared_dag()
    e = check_bound(cm, bp, "enumerate")
    b = check_bound(cm, bp, "bnb")
    assert e.optimum == b.optimum
    assert b.stats.states_expanded * 100 < e.stats.states_expanded


@settings(max_examples=60, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(cases())
def test_small_trees_are_enumerated_by_bnb_and_levels(case: tuple) -> None:
    """With the production threshold, bnb and levels answer a small explicit model by
    enumerating it (marked ``exhaustive``), and the answer is still the brute force's."""
    from lesmc.engines import enumerate as enumerate_engine

    with pytest.MonkeyPatch.context() as mp:
        mp.setattr(enumerate_engine, "SMALL_TREE", 1 << 15)
        _small_tree_case(case)


def _small_tree_case(case: tuple) -> None:
    model, params, quantile = case
    bp = _bound_property(model, params, quantile)
    truth = brute_force(model, bp)
    cm = to_arrays(model)
    nodes = check_bound(cm, bp, "enumerate").stats.states_expanded
    for engine in ("bnb", "levels"):
        r = check_bound(cm, bp, engine)  # type: ignore[arg-type]
        assert r.stats.engine == engine
        assert r.stats.extra.get("exhaustive") == (nodes if nodes <= 1 << 15 else None)
        _assert_optimum_and_theta(r, truth)


def test_a_large_tree_is_counted_not_made_and_then_searched(
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    """Past the threshold the tree is only counted (enumerate.tree_size): the search answers
    with the whole budget, and none of its states went to a probe."""
    from lesmc.engines import enumerate as enumerate_engine

    monkeypatch.setattr(enumerate_engine, "SMALL_TREE", 1 << 10)
    cm, bp = _shared_dag()
    e = check_bound(cm, bp, "enumerate")
    assert e.stats.states_expanded > 1 << 10
    for engine in ("bnb", "levels"):
        r = check_bound(cm, bp, engine)  # type: ignore[arg-type]
        assert "exhaustive" not in r.stats.extra and "probe_states" not in r.stats.extra
        assert r.optimum == e.optimum and r.witness_value == e.witness_value
        small = check_bound(cm, bp, engine, Budget(max_states=1500))  # type: ignore[arg-type]
        assert "probe_states" not in small.stats.extra
        assert small.stats.states_expanded <= 1500
    monkeypatch.setattr(enumerate_engine, "SMALL_TREE", 1 << 15)  # more than the budget:
    r = check_bound(cm, bp, "levels", Budget(max_states=50))  # no probe, the search has it all
    assert "exhaustive" not in r.stats.extra and r.stats.states_expanded <= 50


@settings(max_examples=200, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(cases())
def test_the_tree_counted_is_the_tree_enumerated(case: tuple) -> None:
    """enumerate.tree_size, which decides whether bnb and levels enumerate, counts exactly
    the nodes enumerate makes (paths into each state pushed forward, without the tree)."""
    from lesmc.engines.enumerate import tree_size

    model, params, quantile = case
    bp = _bound_property(model, params, quantile)
    cm = to_arrays(model)
    space = build_space(cm, bp)
    nodes = check_bound(cm, bp, "enumerate").stats.states_expanded
    assert tree_size(space) == nodes
    assert tree_size(space, past=nodes - 1) >= nodes  # the early stop says "more than"


@pytest.mark.parametrize("bound", [2.225073858507203e-309, 5e-324, 1e-300])
def test_a_subnormal_constraint_bound_is_checked_exactly(bound: float) -> None:
    """A tiny positive bound (a sweep found 2.2e-309) overflowed the λ grid of the levels
    engine's Lagrangian bound to an out-of-range index; it must give the brute force's
    optimum like any other bound."""
    seen = 0
    for seed in range(40):
        cfg = RandomModelConfig(steps=3, width=4, branching=(1, 3), dim=1, covariance=True)
        model = random_lts(cfg, seed)
        spec = parse_spec(
            f"property p {{ attack window 1..{model.end} minimize payoff "
            f"subject to payoff > {bound!r} holds if optimum > 1 }}"
        )
        bp = bind(spec, spec.properties[0], model.end, model.components, True)
        truth = brute_force(model, bp).optimum
        for engine in ("levels", "bnb", "enumerate"):
            r = check_bound(to_arrays(model), bp, engine)  # type: ignore[arg-type]
            assert r.optimum == truth
        seen += math.isfinite(truth)
    assert seen > 10


@settings(max_examples=150, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(cases(), st.sampled_from(MEASURES), st.sampled_from(MEASURES), st.floats(0, 1))
def test_one_walk_for_several_properties_equals_one_walk_each(
    case: tuple, obj2: str, con2: str, q2: float
) -> None:
    """``enumerate_many`` (issue 31: one tree walk for every property that shares the tree)
    gives each property exactly what ``enumerate_paths`` gives it alone."""
    from lesmc.engines.enumerate import enumerate_many, enumerate_paths

    model, params, quantile = case
    l, u, end, _, _, op, norm, monitor = params
    b = min(end, 1)
    second = (l, u, end, obj2.format(a=0, b=b), con2.format(a=0, b=b), op, norm, monitor)
    bps = [_bound_property(model, params, quantile), _bound_property(model, second, q2)]
    cm = to_arrays(model)
    spaces = [build_space(cm, bp) for bp in bps]
    together = enumerate_many(spaces)
    for space, got in zip(spaces, together, strict=True):
        alone = enumerate_paths(build_space(cm, space.bp))
        assert (got.optimum, got.lower, got.upper) == (alone.optimum, alone.lower, alone.upper)
        assert got.counterexample == alone.counterexample
        assert got.witness == alone.witness
        assert got.stats.paths == alone.stats.paths
