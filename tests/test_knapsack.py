"""The knapsack reduction (section 4.5) against an independent dynamic programme."""

from __future__ import annotations

import math
from pathlib import Path

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from lesmc.engines.check import check
from lesmc.language.parser import parse_spec
from lesmc.model.knapsack import Item, knapsack_lts, knapsack_spec, read_items

GOLDEN = Path(__file__).parent / "golden" / "knapsack12"


def min_cost_dp(items: list[Item], demand: int) -> float:
    """Minimum cost with total (integer) capacity > demand; +inf if unreachable."""
    need = demand + 1
    best = [0.0] + [math.inf] * need  # best[c]: min cost reaching capacity >= c (capped)
    for it in items:
        g = int(it.capacity)
        for c in range(need, 0, -1):
            best[c] = min(best[c], best[max(c - g, 0)] + it.cost)
    return best[need]


items_strategy = st.lists(
    st.builds(Item, st.integers(0, 30).map(float), st.integers(0, 20).map(float)),
    min_size=1,
    max_size=14,
)


@settings(max_examples=120, deadline=None)
@given(items_strategy, st.integers(0, 120))
def test_optimum_equals_dynamic_programme(items: list[Item], demand: int) -> None:
    spec = parse_spec(knapsack_spec(len(items), demand, 10))
    expected = min_cost_dp(items, demand)
    for engine in ("enumerate", "bnb"):
        r = check(knapsack_lts(items), [spec], engine=engine)[0]  # type: ignore[arg-type]
        got = math.inf if r.optimum is None else r.optimum
        assert got == expected
        if r.cheapest is not None:
            taken = [i for i, s in enumerate(r.cheapest.states[1:]) if s.endswith(":1")]
            assert sum(items[i].cost for i in taken) == expected
            assert sum(items[i].capacity for i in taken) > demand


def test_golden_instance_matches_dp() -> None:
    items = read_items(GOLDEN / "items.csv")
    import json

    expected = json.loads((GOLDEN / "expected.json").read_text())[0]
    assert expected["optimum"] == min_cost_dp(items, 70)


def test_forty_items_are_checked_exactly() -> None:
    import random

    rng = random.Random(40)
    items = [Item(float(rng.randint(1, 100)), float(rng.randint(1, 60))) for _ in range(40)]
    demand = int(sum(i.capacity for i in items) * 0.4)
    r = check(knapsack_lts(items), [parse_spec(knapsack_spec(40, demand, 0))])[0]
    assert r.stats.stopped == "finished"
    assert r.optimum == min_cost_dp(items, demand)


@pytest.mark.parametrize(
    ("text", "message"),
    [
        ("cost,weight\n1,2\n", "lacks a 'capacity' column"),
        ("cost,capacity\n1,x\n", "2:3: 'x' is not a number"),
        ("cost,capacity\n1,-2\n", "capacity must be finite and >= 0"),
        ("cost,capacity\n1,2,3\n", "3 fields, the header has 2"),
        ("cost,capacity\n", "no items"),
    ],
)
def test_bad_items_are_reported_with_position(tmp_path: Path, text: str, message: str) -> None:
    from lesmc.common.errors import InputError

    p = tmp_path / "items.csv"
    p.write_text(text)
    with pytest.raises(InputError) as exc:
        read_items(p)
    assert message in exc.value.render()


def test_the_example_items_reduce_to_their_brute_force_optimum(tmp_path: Path) -> None:
    """examples/items.csv through the real entry point: the optimum is the cheapest subset
    whose capacity exceeds the demand, found here by trying every subset."""
    import csv
    import itertools
    import json
    import subprocess
    import sys

    root = Path(__file__).resolve().parents[1]
    items = [
        (float(r["cost"]), float(r["capacity"]))
        for r in csv.DictReader((root / "examples" / "items.csv").read_text().splitlines())
    ]
    best = min(
        sum(c for c, _ in s)
        for k in range(len(items) + 1)
        for s in itertools.combinations(items, k)
        if sum(g for _, g in s) > 12
    )

    def run(*args: str) -> subprocess.CompletedProcess[str]:
        return subprocess.run(
            [sys.executable, "-m", "lesmc", *args], capture_output=True, text=True, cwd=root
        )

    out = tmp_path / "k.lts"
    r = run("reduce", "knapsack", "examples/items.csv", "--demand", "12", "--budget", "8",
            "-o", str(out))  # fmt: skip
    assert r.returncode == 0 and "Traceback" not in r.stderr, r.stderr
    r = run("check", str(out), str(out.with_suffix(".spec")), "--json")
    assert "Traceback" not in r.stderr
    (res,) = json.loads(r.stdout)["results"]
    assert res["optimum"] == pytest.approx(best) and res["status"] == "holds"  # 8.5 > 8
    assert r.returncode == 0
