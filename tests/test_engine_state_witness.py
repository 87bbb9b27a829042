"""θ* of a max objective by a backward pass over the states built (engines/below.py,
issue 62) against the independent brute force (tests/oracle.py), on random models:
whole (explicit) and partly unfolded (a model grown on demand from the same arrays)."""

from __future__ import annotations

import math

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st
from oracle import brute_force
from test_engines import _bound_property, cases

from lesmc.engines import levels
from lesmc.engines.below import best_below, greedy_witness
from lesmc.engines.check import check_bound, check_lazy
from lesmc.engines.lazy import LazySpace
from lesmc.engines.space import build_space
from lesmc.model.arrays import ArrayModel
from lesmc.model.growing import Expansion, GrowingModel
from lesmc.model.lts import to_arrays


@st.composite
def max_cases(draw: st.DrawFn) -> tuple:
    """test_engines' random cases with a dist.max objective (the one below.py serves)."""
    model, params, quantile = draw(cases())
    l, u, end, _, con, op, norm, monitor = params
    a = draw(st.integers(0, end))
    b = draw(st.integers(a, end))
    return model, (l, u, end, f"dist.max({a}..{b})", con, op, norm, monitor), quantile


def _theta(paths: list[tuple[list[str], float, float]], below: float) -> float:
    """The largest objective below ``below`` over every path (−inf: none)."""
    return max((o for _, o, _ in paths if o < below), default=-math.inf)


class _FromArrays:
    """An expander that grows a model from an explicit one: the same states, indices and
    transitions, built only when asked (the states are all added up front)."""

    def __init__(self, cm: ArrayModel, model: GrowingModel) -> None:
        self.cm = cm
        self.model = model

    def expand(self, states: np.ndarray, step: int) -> Expansion:
        cm = self.cm
        lo, hi = cm.ptr[states], cm.ptr[states + 1]
        t = np.concatenate([np.arange(a, b) for a, b in zip(lo, hi, strict=True)] or [[]])
        t = t.astype(np.int64)
        obs = cm.obs[t] if cm.obs is not None else np.full(t.size, -1)
        nis = cm.nis[t] if cm.nis is not None else None
        return Expansion(hi - lo, cm.dst[t], cm.payoff[t], cm.rank[t], obs, nis)


def _grown(cm: ArrayModel) -> GrowingModel:
    """A GrowingModel of ``cm``'s states, its original path expanded, nothing else."""
    model = GrowingModel(cm.components, cm.S.shape[1])
    cov = cm.cov if cm.cov is not None else np.full(cm.n_states, -1)
    for q in range(cm.n_states):
        model.add_states(int(cm.step[q]), cm.S[q : q + 1], cov[q : q + 1], cm.halted[q : q + 1])
    if cm.P_table is not None:
        model.P_table = cm.P_table
    model.obs_names = cm.obs_names
    model.expander = _FromArrays(cm, model)
    model.original = cm.original
    model.reference = cm.reference
    for q in cm.original[:-1].tolist():
        if not model.expanded(q) and not cm.halted[q]:
            model.expand(np.array([q]), int(cm.step[q]))
    return model


@settings(max_examples=200, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(max_cases(), st.booleans())
def test_levels_with_and_without_the_state_witness_equal_brute_force(
    case: tuple, by_states: bool
) -> None:
    model, params, quantile = case
    bp = _bound_property(model, params, quantile)
    truth = brute_force(model, bp)
    path_values = {tuple(p): o for p, o, _ in truth.paths}
    old = levels.STATE_WITNESS
    levels.STATE_WITNESS = by_states
    try:
        r = check_bound(to_arrays(model), bp, "levels")
    finally:
        levels.STATE_WITNESS = old
    assert r.stats.stopped == "finished"
    if not by_states:
        assert "witness_by_states" not in r.stats.extra
    if math.isinf(truth.optimum):
        assert r.optimum == math.inf
    else:
        assert r.optimum == pytest.approx(truth.optimum, rel=1e-12, abs=1e-12)
    if truth.witness_value is None:
        assert r.witness is None
    else:
        assert r.witness_value == pytest.approx(truth.witness_value, rel=1e-12, abs=1e-12)
        assert path_values[r.witness.states] == pytest.approx(truth.witness_value)


@settings(max_examples=200, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(max_cases(), st.floats(0, 1))
def test_greedy_witness_forced_at_any_threshold_equals_brute_force(
    case: tuple, where: float
) -> None:
    """The pass forced on, below any threshold (not only the optimum): its θ* is the
    largest path objective below it and its path has that objective."""
    model, params, quantile = case
    bp = _bound_property(model, params, quantile)
    truth = brute_force(model, bp)
    values = sorted({o for _, o, _ in truth.paths if math.isfinite(o)}) or [0.0]
    below = [*values, math.inf][int(where * len(values))]
    space = build_space(to_arrays(model), bp)
    got = greedy_witness(space, below)
    expected = _theta(truth.paths, below)
    if not space.root_obj < below:
        assert got is None
        return
    assert got is not None  # a whole model decides it
    path, theta = got
    assert theta == expected
    if path is None:
        assert expected == -math.inf
        return
    q, o = space.root, space.root_obj
    for t in path:  # the path is one: each transition leaves the state before it
        assert space.cm.ptr[q] <= t < space.cm.ptr[q + 1]
        o = max(o, float(space.c_obj[t]))
        q = int(space.cm.dst[t])
    assert space.is_leaf(q)
    assert max(o, space.tails(np.array([q]))[0][0]) == expected


@settings(max_examples=200, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(max_cases(), st.floats(0, 1), st.integers(0, 2**31))
def test_on_a_partly_unfolded_model_the_pass_is_exact_or_declines(
    case: tuple, where: float, seed: int
) -> None:
    """Some states expanded at random: the bound is never below the truth, the answer is
    the brute force's or None (unknown states could hold better paths)."""
    model, params, quantile = case
    bp = _bound_property(model, params, quantile)
    truth = brute_force(model, bp)
    cm = to_arrays(model)
    grown = _grown(cm)
    rng = np.random.default_rng(seed)
    for q in range(cm.n_states):
        open_ = not grown.expanded(q) and not cm.halted[q] and cm.ptr[q + 1] > cm.ptr[q]
        if open_ and rng.random() < 0.6:
            grown.expand(np.array([q]), int(cm.step[q]))
    space = LazySpace(grown, bp)
    values = sorted({o for _, o, _ in truth.paths if math.isfinite(o)}) or [0.0]
    below = [*values, math.inf][int(where * len(values))]
    if not space.root_obj < below:
        return
    m = best_below(space, below)
    exact = build_space(cm, bp)
    m_exact = best_below(exact, below)
    reach = np.zeros(cm.n_states, dtype=bool)
    reach[np.concatenate(exact.reachable_levels())] = True
    assert np.all(m[reach] >= m_exact[reach])
    fin = reach & np.isfinite(m)
    assert np.array_equal(m[fin], m_exact[fin])
    got = greedy_witness(space, below)
    if got is not None:
        assert got[1] == _theta(truth.paths, below)


@settings(max_examples=60, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(max_cases())
def test_levels_on_a_model_unfolded_on_demand_equals_brute_force(case: tuple) -> None:
    """The engine on the grown model (its search expands what it visits): the optimum and θ*
    of the brute force, θ* decided by the states the optimum pass built."""
    model, params, quantile = case
    bp = _bound_property(model, params, quantile)
    truth = brute_force(model, bp)
    r = check_lazy(_grown(to_arrays(model)), bp, "levels")
    assert r.stats.stopped == "finished"
    if math.isinf(truth.optimum):
        assert r.optimum == math.inf
    else:
        assert r.optimum == pytest.approx(truth.optimum, rel=1e-12, abs=1e-12)
    if truth.witness_value is None:
        assert r.witness is None
    else:
        assert r.witness_value == pytest.approx(truth.witness_value, rel=1e-12, abs=1e-12)
