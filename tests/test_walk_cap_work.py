"""The cap on the walk several properties of one tree share (engines/check.py
``check_shared``) on a model unfolded on demand counts the unfolding's work, not seconds.

With a cap in seconds (round 23's SHARED_LAZY_SECONDS) whether the walk or each
property's own search answered depended on the machine's load, and with it the states
built and, among paths of equal cost, the counterexample printed. Now the cap is
check.SHARED_LAZY_WORK, in the units of GrowingModel.work (lesmc/model/growing.py: what
the expansions report, Expansion.work; one per transition by default; on the joint design
the rows it examined before merging equal outcomes, times their tracks), and the walk
looks at it in slices counted in states (enumerate._work_slice), so that where it stops
is the same on every run.

The checks: ``lesmc check``'s results document (api.check, CheckResult.to_dict; the
seconds aside) is the same under the real clock and under a clock running 1000x slower,
whether the walk answers (the default cap) or gives up halfway (a cap of half the
walk's work); the model's work counter against an independent count.
"""

from __future__ import annotations

import functools
import time
from typing import Any

import numpy as np
import pytest
from test_count_frames_bound import _bound, _eps, _lazy, _scene, _spec

import lesmc.engines.check as check_mod
import lesmc.engines.lazy as lazy
from lesmc import api
from lesmc.common.budget import Budget
from lesmc.model.growing import Expansion, GrowingModel
from lesmc.scene import Scene

#: How much slower the slowed clock runs.
SLOWER = 1000.0


def _slow_clock(monkeypatch: pytest.MonkeyPatch) -> None:
    """time.perf_counter and time.monotonic running SLOWER times slower than real time
    (as on a machine SLOWER times as loaded)."""
    for name in ("perf_counter", "monotonic"):
        real = getattr(time, name)
        t0 = real()
        monkeypatch.setattr(time, name, lambda real=real, t0=t0: t0 + (real() - t0) * SLOWER)


@functools.cache
def _case() -> tuple[Scene, int, float]:
    """The scene, its end and the constraint's ε (the whole model built once)."""
    scene, end = _scene()
    return scene, end, _eps(scene, end)


def _document(cap: int | None, monkeypatch: pytest.MonkeyPatch) -> list[dict[str, Any]]:
    """The results of ``rob`` and ``frames`` (one tree) on the joint scene with injection
    candidates, as ``lesmc check --json`` prints them, without the seconds; ``cap``: the
    walk's work cap (None: the default)."""
    if cap is not None:
        monkeypatch.setattr(check_mod, "SHARED_LAZY_WORK", cap, raising=False)
    scene, end, eps = _case()
    got = api.check(scene, api.parse_spec(_spec(end, eps)))
    out = []
    for r in got:
        d = r.to_dict()
        d["stats"].pop("seconds", None)
        out.append(d)
    return out


@functools.cache
def _walk_work() -> int:
    """The work the shared walk of the two properties does when it answers (counted on a
    model of its own, without a cap)."""
    scene, end, eps = _case()
    model = _lazy(scene, end)
    before = model.work
    tried = check_mod.check_many(model, _bound(scene, end, eps), Budget())
    assert all(r.stats.stopped == "finished" for r in tried)
    return model.work - before


@pytest.mark.parametrize("half", [False, True], ids=["walked", "given_up"])
def test_the_results_do_not_depend_on_the_clock(
    monkeypatch: pytest.MonkeyPatch, half: bool
) -> None:
    """The same document, counterexample, states built and ``exhaustive`` included, when
    every second counts 1000x: the walk answers both times, or (a cap of half its work)
    gives up at the same place both times and the same searches answer. With the 2 s cap
    the slow clock gave the walk up and the searches answered (no ``exhaustive``)."""
    cap = _walk_work() // 2 if half else None
    fast = _document(cap, monkeypatch)
    walked = ["exhaustive" in d["stats"] for d in fast]
    assert walked == [not half] * 2
    assert all(d["verdict"] in ("violated", "holds") for d in fast)
    with monkeypatch.context() as slowed:
        _slow_clock(slowed)
        slow = _document(cap, slowed)
    assert slow == fast


def test_work_counts_the_rows_times_the_tracks() -> None:
    """GrowingModel.work adds what each expansion reports, one per transition where it
    reports none; on the joint design under inject at least the transitions kept (each
    kept outcome is one examined row, moving at least one track), and the same for the
    same walk however its states are batched."""
    model = GrowingModel(("x", "y"), 2)

    class Two:
        def __init__(self, work: int | None) -> None:
            self.work = work

        def expand(self, states: np.ndarray, step: int) -> Expansion:
            first = model.add_states(step + 1, np.zeros((2 * len(states), 2)),
                                     np.zeros(2 * len(states), dtype=np.int32),
                                     np.zeros(2 * len(states), dtype=bool))  # fmt: skip
            n = 2 * len(states)
            z = np.zeros(n)
            return Expansion(np.full(len(states), 2), first + np.arange(n), z,
                             np.tile([0, 1], len(states)), np.full(n, -1), None,
                             self.work)  # fmt: skip

    model.add_states(0, np.zeros((1, 2)), np.zeros(1, dtype=np.int32), np.zeros(1, dtype=bool))
    model.expander = Two(None)
    model.expand(np.array([0]), 0)
    assert (model.work, model.states_expanded) == (2, 1)
    model.expander = Two(7)
    model.expand(np.array([1, 2]), 1)
    assert (model.work, model.states_expanded) == (9, 3)

    scene, end, eps = _case()
    bps = _bound(scene, end, eps)
    works = []
    for batch in (1 << 8, 1 << 30):  # a few states a batch; every state of a step at once
        with pytest.MonkeyPatch.context() as mp:
            mp.setattr(lazy, "BATCH_WORK", batch)
            model = _lazy(scene, end)
            check_mod.check_many(model, bps, Budget())
        assert model.work >= model.n_transitions > model.states_expanded > 1
        works.append((model.work, model.n_states, model.states_expanded))
    assert works[0] == works[1]
