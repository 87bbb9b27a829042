"""The array model's layout and the converters between it and the LTS object view.

The layout (states by (step, id), transitions by (rank, target id) within a
source) is what the engines' tie-breaking and the golden files depend on: it
is checked here against the construction the engines used before the array
model (``CompiledModel.from_lts``), and the writer against the old writer.
"""

from __future__ import annotations

import dataclasses
import json
import math
from pathlib import Path
from typing import Any

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as hs

from lesmc.common.errors import ModelError
from lesmc.model.arrays import ArrayModel
from lesmc.model.kernel import combined_counts, combined_payoffs
from lesmc.model.knapsack import Item, knapsack_lts, read_items
from lesmc.model.lts import LTS, State, Transition, to_arrays, to_lts
from lesmc.model.lts_format import load_lts, lts_from_dict, lts_to_dict
from lesmc.model.random_models import RandomModelConfig, random_lts

GOLDEN = Path(__file__).parent / "golden"


def old_layout(model: LTS) -> dict[str, Any]:
    """What ``CompiledModel.from_lts`` built (before the array model), as plain lists."""
    states = sorted(model.states(), key=lambda st: (st.step, st.id))
    ids = [st.id for st in states]
    index = {sid: i for i, sid in enumerate(ids)}
    ptr, dst, payoff, rank, combined, obs = [0], [], [], [], [], []
    for st in states:
        out = model.out(st.id)
        for t in out:
            dst.append(index[t.dst])
            payoff.append(t.payoff)
            rank.append(t.rank)
            combined.append(math.fsum(o.payoff for o in out if o.rank < t.rank))
            obs.append(t.obs)
        ptr.append(len(dst))
    return {
        "ids": ids,
        "step": [st.step for st in states],
        "S": [list(st.s) for st in states],
        "P": [None if st.P is None else st.P.tolist() for st in states],
        "halted": [st.halted for st in states],
        "ptr": ptr,
        "dst": dst,
        "payoff": payoff,
        "rank": rank,
        "combined": combined,
        "obs": obs,
        "original": [index[q] for q in model.original],
    }


def new_layout(m: ArrayModel) -> dict[str, Any]:
    n = m.n_states
    return {
        "ids": [m.state_id(i) for i in range(n)],
        "step": m.step.tolist(),
        "S": m.S.tolist(),
        "P": [None if m.cov is None or m.cov[i] < 0 else m.P(i).tolist() for i in range(n)],
        "halted": m.halted.tolist(),
        "ptr": m.ptr.tolist(),
        "dst": m.dst.tolist(),
        "payoff": m.payoff.tolist(),
        "rank": m.rank.tolist(),
        "combined": m.combined.tolist(),
        "obs": [m.obs_of(t) for t in range(m.n_transitions)],
        "original": m.original.tolist(),
    }


def old_writer(model: LTS) -> dict[str, Any]:
    """The .lts writer before the array model, on the object view."""
    states = sorted(model.states(), key=lambda st: (st.step, st.id))
    doc_states = []
    for st in states:
        d: dict[str, Any] = {"id": st.id, "step": st.step, "s": [float(x) for x in st.s]}
        if st.P is not None:
            d["P"] = [[float(x) for x in row] for row in st.P]
        if st.labels:
            d["labels"] = sorted(st.labels)
        doc_states.append(d)
    doc_trans = []
    for st in states:
        for t in model.out(st.id):
            d = {"src": t.src, "dst": t.dst, "payoff": t.payoff, "rank": t.rank}
            if t.obs is not None:
                d["obs"] = t.obs
            doc_trans.append(d)
    return {
        "format": "lesmc-lts",
        "version": 1,
        "components": list(model.components),
        "initial": model.initial,
        "original": list(model.original),
        "states": doc_states,
        "transitions": doc_trans,
        **({"meta": model.meta} if model.meta else {}),
    }


def _check_dtypes(m: ArrayModel) -> None:
    n, mm = m.n_states, m.n_transitions
    assert m.step.dtype == np.int64 and m.step.shape == (n,)
    assert m.S.dtype == np.float64 and m.S.shape == (n, len(m.components))
    assert m.halted.dtype == bool and m.halted.shape == (n,)
    assert m.ptr.dtype == np.int64 and m.ptr.shape == (n + 1,) and m.ptr[-1] == mm
    for a in (m.dst, m.rank):
        assert a.dtype == np.int64 and a.shape == (mm,)
    assert m.payoff.dtype == np.float64 and m.payoff.shape == (mm,)
    assert m.original.dtype == np.int64
    if m.cov is not None:
        assert m.cov.dtype == np.int64 and m.P_table is not None
        assert m.P_table.dtype == np.float64 and m.P_table.ndim == 3
        assert len({m.P_table[i].tobytes() for i in range(len(m.P_table))}) == len(m.P_table)
    if m.obs is not None:
        assert m.obs.dtype == np.int64 and len(set(m.obs_names)) == len(m.obs_names)


configs = hs.builds(
    RandomModelConfig,
    steps=hs.integers(1, 8),
    width=hs.integers(1, 14),
    branching=hs.sampled_from([(1, 2), (2, 4), (3, 5)]),
    dim=hs.integers(1, 3),
    halt_prob=hs.sampled_from([0.0, 0.2]),
    covariance=hs.booleans(),
    tree=hs.booleans(),
    integer_values=hs.booleans(),
)


@settings(max_examples=60, deadline=None)
@given(configs, hs.integers(0, 2**31))
def test_layout_equals_the_old_compiled_model(cfg: RandomModelConfig, seed: int) -> None:
    lts = random_lts(cfg, seed)
    m = to_arrays(lts)
    _check_dtypes(m)
    assert new_layout(m) == old_layout(lts)
    # the file and the object view give the same arrays and the old writer's document
    doc = lts_to_dict(m)
    assert doc == old_writer(lts)
    assert new_layout(lts_from_dict(json.loads(json.dumps(doc)))) == new_layout(m)
    back = to_lts(m)
    assert old_writer(back) == doc
    assert new_layout(to_arrays(back)) == new_layout(m)


@pytest.mark.parametrize("path", sorted(GOLDEN.glob("*/model.lts")), ids=lambda p: p.parent.name)
def test_golden_models_through_the_object_view(path: Path) -> None:
    m = load_lts(path)
    _check_dtypes(m)
    lts = to_lts(m)
    assert new_layout(to_arrays(lts)) == new_layout(m) == old_layout(lts)
    assert old_writer(lts) == lts_to_dict(m)
    assert lts.meta == m.meta


def test_writer_sorts_models_without_ids() -> None:
    """A model named ``k{step}.{i}`` (the unfolder's) is written in (step, id) order."""
    m = to_arrays(random_lts(RandomModelConfig(steps=4, width=12), seed=5))
    anon = dataclasses.replace(m, ids=None)
    assert anon.state_id(11) == f"k{anon.step[11]}.11"
    doc = lts_to_dict(anon)
    assert doc == old_writer(to_lts(anon))
    ids = [st["id"] for st in doc["states"]]
    assert ids != [anon.state_id(i) for i in range(anon.n_states)]  # k1.10 before k1.2
    assert lts_to_dict(lts_from_dict(doc)) == doc


def test_to_lts_keeps_labels_meta_and_covariances() -> None:
    m = load_lts(GOLDEN / "tiny" / "model.lts")
    m.labels[m.index("a")] = ("seen",)
    m.meta["source"] = "test"
    lts = to_lts(m)
    assert lts.state("a").labels == frozenset({"seen"})
    assert lts.state("bH").labels == frozenset({"halted"}) and lts.state("bH").halted
    assert lts.state("b2").P is not None and lts.state("b2").P[0, 0] == 6  # type: ignore[index]
    assert lts.meta == {"source": "test"} and lts.components == ("x",)
    assert [t.dst for t in lts.out("q0")] == ["a", "b", "c"]
    again = to_arrays(lts)
    assert again.labels == {again.index("a"): ("seen",)}


def test_from_parts_still_validates() -> None:
    states = [State("q0", 0, np.zeros(1)), State("a", 1, np.zeros(1)), State("a", 1, np.ones(2))]
    trans = [Transition("q0", "a", 1.0, 0), Transition("q0", "zz", -1.0, 1)]
    with pytest.raises(ModelError) as exc:
        LTS.from_parts(states, trans, "q0", ["q0", "a"], path="p")
    assert exc.value.render().splitlines() == [
        "p: state 'a': duplicate state id",
        "p: transition 1 (q0 -> zz): unknown state 'zz'",
    ]
    with pytest.raises(ModelError, match="the model has no states"):
        LTS.from_parts([], [], "q0", ["q0"])
    states = [State("q0", 0, np.zeros(1), np.eye(2)), State("a", 1, np.zeros(1))]
    trans = [Transition("q0", "a", math.inf, 0)]
    with pytest.raises(ModelError) as exc:
        LTS.from_parts(states, trans, "q0", ["q0", "a"], path="p")
    assert exc.value.render().splitlines() == [
        "p: state 'q0': P must be 1x1, got 2x2",
        "p: transition 0 (q0 -> a): payoff must be finite and >= 0, got inf",
    ]


def test_a_long_chain_is_checked_by_search() -> None:
    """More distinct steps than the level-by-level pass handles: depth-first search."""
    n = 5000
    doc = {
        "format": "lesmc-lts",
        "version": 1,
        "initial": "s0",
        "original": [f"s{k}" for k in range(n)],
        "states": [{"id": f"s{k}", "step": k, "s": [k]} for k in range(n)],
        "transitions": [
            {"src": f"s{k}", "dst": f"s{k + 1}", "payoff": 0, "rank": 0} for k in range(n - 1)
        ],
    }
    m = lts_from_dict(doc)
    assert m.end == n - 1 and m.original.tolist() == list(range(n))
    doc["states"].append({"id": "x", "step": 7, "s": [0]})
    doc["states"].append({"id": "y", "step": 8, "s": [0], "labels": ["halted"]})
    doc["transitions"].append({"src": "x", "dst": "y", "payoff": 0, "rank": 0})
    with pytest.raises(ModelError) as exc:
        lts_from_dict(doc, "c")
    assert exc.value.render().splitlines() == [
        "c: state 'x': not reachable from the initial state",
        "c: state 'y': not reachable from the initial state",
    ]


def test_knapsack_model_is_the_golden_one() -> None:
    d = GOLDEN / "knapsack12"
    m = knapsack_lts(read_items(d / "items.csv"))
    assert isinstance(m, ArrayModel)
    _check_dtypes(m)
    assert lts_to_dict(m) == json.loads((d / "model.lts").read_text())


def test_knapsack_layout() -> None:
    m = knapsack_lts([Item(3.0, 2.0), Item(1.0, 5.0)])
    assert m.ids == ["0:1", "1:0", "1:1", "2:0", "2:1"]
    assert m.ptr.tolist() == [0, 2, 4, 6, 6, 6]
    assert m.dst.tolist() == [1, 2, 3, 4, 3, 4] and m.rank.tolist() == [0, 1] * 3
    assert m.payoff.tolist() == [3.0, 0.0, 1.0, 0.0, 1.0, 0.0]
    assert m.combined.tolist() == [0.0, 3.0, 0.0, 1.0, 0.0, 1.0]
    assert m.S[:, 0].tolist() == [0.0, 0.0, 2.0, 0.0, 5.0]
    assert [m.obs_of(t) for t in m.out(0)] == ["skip1", "take1"]


payoff_values = hs.one_of(
    hs.integers(0, 10**6).map(float),  # unit payoffs, integer weights
    hs.just(math.inf),  # unattackable outcomes
    hs.floats(0, 1e6, allow_nan=False, allow_infinity=False),  # real payoffs
    hs.just(2.0**53 - 1),  # integers whose sums round
)


@settings(max_examples=200, deadline=None)
@given(hs.lists(hs.lists(hs.tuples(hs.integers(0, 4), payoff_values), max_size=9), max_size=12))
def test_combined_payoffs_are_fsums_of_the_lower_ranks(rows: list[list[tuple[int, float]]]) -> None:
    """Eq. 5 over a CSR of rank-sorted rows (ties share a rank), exactly against
    math.fsum of each transition's strictly lower-ranked siblings (the kernel's one- and
    two-term sums are vectorised, longer ones summed exactly); and over unit payoffs,
    against a count of those siblings."""
    ptr, payoff, rank, want = [0], [], [], []
    for row in rows:
        row = sorted(row, key=lambda x: x[0])
        for r, p in row:
            rank.append(r)
            payoff.append(p)
            want.append(math.fsum(q for s, q in row if s < r))
        ptr.append(len(payoff))
    got = combined_payoffs(np.array(ptr), np.array(payoff, dtype=float), np.array(rank))
    assert np.array_equal(np.array(want, dtype=float), got)  # exact (0.0 == -0.0)
    # over unit payoffs (each 1, ∞ staying ∞): the outcomes ruled out, ∞ past an unattackable one
    counts = []
    for row in rows:
        for r, _ in sorted(row, key=lambda x: x[0]):
            lower = [q for s, q in row if s < r]
            counts.append(math.inf if math.inf in lower else float(len(lower)))
    got = combined_counts(np.array(ptr), np.array(payoff, dtype=float), np.array(rank))
    assert np.array_equal(np.array(counts, dtype=float), got)
