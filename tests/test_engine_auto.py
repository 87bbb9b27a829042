"""Engine ``auto`` (issue 62): the engine it chooses from a space's shape, its answers
against the brute force, and ``--engine auto`` through the real entry point."""

from __future__ import annotations

import json
import random

import pytest
from cli_run import ROOT, lesmc
from hypothesis import HealthCheck, given, settings
from oracle import brute_force
from test_engines import _assert_optimum_and_theta, _bound_property, cases

from lesmc.engines import enumerate as enumerate_engine
from lesmc.engines import registry
from lesmc.engines.auto import TABLE_TREE, choose
from lesmc.engines.check import check_bound
from lesmc.engines.space import build_space
from lesmc.language.parser import parse_spec
from lesmc.language.semantics import bind
from lesmc.model.knapsack import Item, knapsack_lts, knapsack_spec
from lesmc.model.lts import to_arrays
from lesmc.model.random_models import RandomModelConfig, random_lts


def _layered(objective: str) -> tuple[object, object]:
    """A random layered model (branching 3, window 2..7) and a property minimizing
    ``objective`` subject to a deviation at the end."""
    cfg = RandomModelConfig(steps=9, width=6, branching=(3, 3), dim=2, halt_prob=0.0)
    model = random_lts(cfg, seed=11)
    spec = parse_spec(
        f"property p {{ attack window 2..7 minimize {objective} "
        "subject to dist.at(end) > 5 holds if optimum > 1 }"
    )
    bp = bind(spec, spec.properties[0], model.end, model.components, False)
    return model, bp


@pytest.mark.parametrize(
    ("objective", "want"),
    [("dist.max(2..7)", "bnb"), ("payoff", "levels"), ("dist.sum(2..7)", "levels")],
)
def test_a_max_objective_goes_to_bnb_and_sums_to_levels(objective: str, want: str) -> None:
    model, bp = _layered(objective)
    space = build_space(to_arrays(model), bp)  # type: ignore[arg-type]
    assert choose(space) == want
    r = check_bound(to_arrays(model), bp, "auto")  # type: ignore[arg-type]
    assert r.stats.engine == "auto"
    assert r.stats.extra["auto"] == want
    truth = brute_force(model, bp)  # type: ignore[arg-type]
    _assert_optimum_and_theta(r, truth)


def test_a_knapsack_goes_to_levels_and_matches_its_subsets() -> None:
    """n = 12: the optimum and θ* by listing every subset."""
    items, demand, model, bp = _knapsack(12, 3)
    r = check_bound(model, bp, "auto")  # type: ignore[arg-type]
    assert r.stats.extra["auto"] == "levels"
    subsets = [(0.0, 0.0)]
    for it in items:
        subsets += [(c + it.cost, k + it.capacity) for c, k in subsets]
    opt = min(c for c, k in subsets if k > demand)
    assert r.optimum == opt
    assert r.witness_value == max(c for c, _ in subsets if c < opt)


@settings(max_examples=120, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(cases())
def test_auto_equals_brute_force(case: tuple) -> None:  # type: ignore[type-arg]
    """Whatever it chooses, auto's optimum and θ* are the brute force's."""
    model, params, quantile = case
    bp = _bound_property(model, params, quantile)
    r = check_bound(to_arrays(model), bp, "auto")
    assert r.stats.stopped == "finished"
    _assert_optimum_and_theta(r, brute_force(model, bp))
    if "exhaustive" not in r.stats.extra:  # searched, not probed
        assert r.stats.extra["auto"] == ("bnb" if bp.objective.aggregate == "max" else "levels")


def _knapsack(n: int, seed: int) -> tuple[list[Item], float, object, object]:
    rng = random.Random(seed)
    items = [Item(float(rng.randint(1, 900)), float(rng.randint(1, 900))) for _ in range(n)]
    demand = sum(i.capacity for i in items) / 2
    model = knapsack_lts(items)
    spec = parse_spec(knapsack_spec(n, demand, 0.0), "<knapsack>")
    bp = bind(spec, spec.properties[0], model.end, model.components, model.has_covariance)
    return items, demand, model, bp


def test_the_value_tables_class_is_not_probed(monkeypatch: pytest.MonkeyPatch) -> None:
    """With the probe on (its default): levels lists a knapsack's tree of 2^17 nodes,
    auto leaves it to levels' value table (the same answers); a layered model's small
    tree auto still lists."""
    monkeypatch.setattr(enumerate_engine, "SMALL_TREE", 1 << 21)
    _, _, model, bp = _knapsack(16, 5)
    space = build_space(model, bp)  # type: ignore[arg-type]
    assert enumerate_engine.tree_size(space) > TABLE_TREE
    listed = check_bound(model, bp, "levels")  # type: ignore[arg-type]
    got = check_bound(model, bp, "auto")  # type: ignore[arg-type]
    assert "exhaustive" in listed.stats.extra
    assert "exhaustive" not in got.stats.extra and "value_cells" in got.stats.extra
    assert (got.optimum, got.witness_value) == (listed.optimum, listed.witness_value)
    lts, small = _layered("payoff")
    r = check_bound(to_arrays(lts), small, "auto")  # type: ignore[arg-type]
    assert "exhaustive" in r.stats.extra and r.stats.extra["auto"] == "enumerate"
    assert r.stats.engine == "auto"


def test_auto_is_registered() -> None:
    assert "auto" in registry.names()
    assert "auto:" in registry.help_text()


def test_cli_check_with_engine_auto() -> None:
    """``lesmc check --engine auto --json``: the answers are bnb's, the engine is auto."""
    tiny = ROOT / "tests" / "golden" / "tiny"
    args = [str(tiny / "model.lts"), str(tiny / "properties.spec"), "--json"]
    got = lesmc("check", *args, "--engine", "auto")
    want = lesmc("check", *args, "--engine", "bnb")
    assert "Traceback" not in got.stderr
    assert got.returncode == want.returncode
    rows, ref = json.loads(got.stdout)["results"], json.loads(want.stdout)["results"]
    assert [r["stats"]["engine"] for r in rows] == ["auto"] * len(rows)
    for a, b in zip(rows, ref, strict=True):
        assert (a["optimum"], a["witness_value"]) == (b["optimum"], b["witness_value"])


@settings(max_examples=150, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(cases())
def test_the_cheap_tree_bound_is_above_the_count(case: tuple) -> None:  # type: ignore[type-arg]
    """enumerate.tree_bound (the probe's shortcut) is never below the exact count."""
    model, params, quantile = case
    bp = _bound_property(model, params, quantile)
    space = build_space(to_arrays(model), bp)
    assert enumerate_engine.tree_bound(space) >= enumerate_engine.tree_size(space)


def test_a_small_tree_is_listed_without_counting(monkeypatch: pytest.MonkeyPatch) -> None:
    """Under the cheap bound the probe enumerates without counting (the same answer)."""
    monkeypatch.setattr(enumerate_engine, "SMALL_TREE", 1 << 21)
    lts, bp = _layered("payoff")
    space = build_space(to_arrays(lts), bp)  # type: ignore[arg-type]
    assert enumerate_engine.tree_bound(space) <= enumerate_engine.SMALL_TREE

    def no_count(*_: object) -> float:
        raise AssertionError("counted")

    monkeypatch.setattr(enumerate_engine, "tree_size", no_count)
    r = check_bound(to_arrays(lts), bp, "levels")  # type: ignore[arg-type]
    assert "exhaustive" in r.stats.extra
    _assert_optimum_and_theta(r, brute_force(lts, bp))  # type: ignore[arg-type]
