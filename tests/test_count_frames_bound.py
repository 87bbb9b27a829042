"""Issue 61, ``minimize count.frames`` under inject: the walk that several properties of
one tree share (engines/check.py ``check_shared``) must not unfold a model far past what
it may.

``lesmc check`` of the bundled robustness property as ``minimize payoff`` and as
``minimize count.frames`` (one window: one tree) first tries one enumeration of their
shared tree. On the joint design with injection candidates (2^m candidate subsets a
state) that walk unfolded whole levels before it looked at its node limit, 900,783
states and minutes on seed 3 of the default video, where each property's own search
needs about 20,000 (docs/performance.md, "Issue 61, frames under inject"). Now a level's
nodes are counted as it unfolds (enumerate._unfold) and the walk on a model unfolded on
demand has a cap on the unfolding's work (check.SHARED_LAZY_WORK; counted, not timed:
tests/test_walk_cap_work.py).

Checked on a small random joint scene with injection candidates (tests/test_inject_joint.py
``random_scene``, three candidates a frame inside the gates and birth regions,
tests/test_joint_inject_prune.py ``with_candidates``), attack window 1..3:
- with the node limit set just past the first level, the walk builds at most
  limit + D states, D the largest out-degree of the whole model (built apart,
  unfold.build_model): each state it unfolds makes at most D, and it stops within one
  state of the limit (slices of one state). The old walk unfolded the whole second level;
- with a work cap of 0, the walk builds nothing and gives way to the searches;
- either way (the walk answering or the searches), both optima equal those of the
  ``enumerate`` engine on the whole model, each property checked alone.
"""

from __future__ import annotations

import math

import numpy as np
import pytest
from test_inject_joint import random_scene
from test_joint_inject_prune import with_candidates

import lesmc.engines.check as check_mod
import lesmc.engines.lazy as lazy
import lesmc.unfold.unfold as unfold
from lesmc import api
from lesmc.common.budget import Budget
from lesmc.engines.check import check_bound, check_shared
from lesmc.language.semantics import BoundProperty
from lesmc.model.arrays import ArrayModel
from lesmc.model.growing import GrowingModel
from lesmc.pipeline.check import bind_scene
from lesmc.scene import Scene
from lesmc.tracking.trackers import make_tracker

WINDOW = (1, 3)
#: A states budget, so that check_shared's node limit is SHARED_LAZY_TREE (without one it
#: is enumerate.SMALL_TREE, which tests/conftest.py sets to 0)
BUDGET = Budget(max_states=1 << 30)


def _scene() -> tuple[Scene, int]:
    """Seed 1 of the joint injection scenes: 4,340 states in window 1..3, the root 44
    successors, a state at most 80 (measured by the test, not assumed)."""
    rng = np.random.default_rng(1)
    scene = with_candidates(random_scene(rng, max_trace=1e12), rng, 0, 3)
    return scene, unfold.original_end(scene, make_tracker(scene))


def _spec(end: int, eps: float) -> str:
    body = f"subject to dist.sum(0..end) > {eps} holds if optimum > 1000 on x, y }}\n"
    return (
        f"property rob {{ attack window {WINDOW[0]}..{WINDOW[1]} allow hide, inject end {end} "
        f"minimize payoff {body}"
        f"property frames {{ attack window {WINDOW[0]}..{WINDOW[1]} allow hide, inject "
        f"end {end} minimize count.frames {body}"
    )


def _bound(scene: Scene, end: int, eps: float) -> list[BoundProperty]:
    return bind_scene(scene, [api.parse_spec(_spec(end, eps))], end)


def _lazy(scene: Scene, end: int) -> GrowingModel:
    return unfold.lazy_model(scene, WINDOW, end, inject=True)


def _eps(scene: Scene, end: int) -> float:
    """Half the largest deviation of a state of the whole model: the path through that
    state violates ``dist.sum(0..end) > ε``, the unattacked path (deviation 0) does not."""
    cm = unfold.build_model(scene, WINDOW, end, inject=True)
    xy = list(scene.tracker.measured)
    dev = np.hypot(*(cm.S[:, xy] - cm.S[cm.original[cm.step]][:, xy]).T)
    return round(float(dev.max()) / 2, 6)


def _tree_levels(cm: ArrayModel, root: int, levels: int) -> list[np.ndarray]:
    """The nodes (states, repeated per path) of the first ``levels`` levels of the tree of
    paths from ``root``, read off the whole model's arrays (every transition of a state
    in the window is an attack the property allows)."""
    out = [np.array([root])]
    for _ in range(levels - 1):
        q = out[-1]
        out.append(np.concatenate([cm.dst[cm.ptr[x] : cm.ptr[x + 1]] for x in q.tolist()]))
    return out


def test_a_shared_walk_stops_within_its_node_limit(monkeypatch: pytest.MonkeyPatch) -> None:
    """Node limit: the root, the first two window levels, and D more. The walk unfolds
    those levels (at most 1 + n1 + n2 - 1 states made) and then at most D states'
    successors past the limit: at most limit + D states in all. Unfolding the third
    level whole, as the old walk did, makes every distinct state of it: many more."""
    scene, end = _scene()
    whole = unfold.build_model(scene, WINDOW, end, inject=True)
    degree = np.diff(whole.ptr)
    most = int(degree.max())
    tree = _tree_levels(whole, int(whole.original[0]), 4)
    limit = 1 + tree[1].size + tree[2].size + most
    third = np.unique(tree[3]).size  # states the third level reaches
    assert third > 4 * (limit + most)  # so the bound below can fail
    monkeypatch.setattr(check_mod, "SHARED_LAZY_TREE", limit)
    monkeypatch.setattr(lazy, "BATCH_WORK", 0)  # slices of one state once measured
    model = _lazy(scene, end)
    bps = _bound(scene, end, _eps(scene, end))
    before = model.n_states
    assert check_shared(model, bps, "levels", BUDGET) is None  # the tree is larger
    built = model.n_states - before
    assert built <= limit + most, (built, limit, most, third)


def test_a_shared_walk_past_its_work_cap_builds_nothing(monkeypatch: pytest.MonkeyPatch) -> None:
    scene, end = _scene()
    monkeypatch.setattr(check_mod, "SHARED_LAZY_WORK", 0, raising=False)
    model = _lazy(scene, end)
    bps = _bound(scene, end, _eps(scene, end))
    before = model.n_states
    assert check_shared(model, bps, "levels", BUDGET) is None
    assert model.n_states == before


@pytest.mark.parametrize("cap", [0, 1 << 40])
def test_both_properties_in_one_check_equal_enumerate_alone(
    monkeypatch: pytest.MonkeyPatch, cap: int
) -> None:
    """Searched (work cap 0) or walked (2^40: the tree is small), the
    optima are those of ``enumerate`` on the whole model, each property alone."""
    scene, end = _scene()
    eps = _eps(scene, end)
    monkeypatch.setattr(check_mod, "SHARED_LAZY_WORK", cap, raising=False)
    got = api.check(scene, api.parse_spec(_spec(end, eps)))
    whole = unfold.build_model(scene, WINDOW, end, inject=True)
    wanted = [check_bound(whole, bp, "enumerate", Budget()) for bp in _bound(scene, end, eps)]
    walked = ["exhaustive" in r.stats.extra for r in got]
    assert walked == [cap > 0] * 2
    for r, want in zip(got, wanted, strict=True):
        assert r.optimum is not None and want.optimum is not None
        assert math.isfinite(float(want.optimum))
        assert float(r.optimum) == pytest.approx(float(want.optimum), abs=1e-9)
    assert float(got[1].optimum or 0) >= 1  # count.frames: an attack touches a frame
