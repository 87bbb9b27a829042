"""``lesmc check`` and ``lesmc verify`` build the same model of a property (round 22, task
states): verify's check path (lesmc/experiment/experiment.py ``_job``: ``full_models``, the
whole model built first for the report, lesmc/unfold/unfold.py ``build_model``) and check's
(the model unfolded on demand, ``lazy_model``) unfold the same steps.

Before the fix the whole model was built to the last step the unattacked track reaches
whatever the properties' ``end``: a property ``end N`` below it got a bigger model under
verify (and ``check --report``) than ``lesmc check`` would ever unfold. Checked on random
small joint scenes with injection candidates under ``allow hide, inject``:
- the whole model has no state past the property's end, and as many states as the on-demand
  model once every state it can reach is expanded (the same model, by either verb);
- the on-demand search built no more states than that (the difference of round 22's seed 3,
  21,807 states against 2,493,061, is the search not needing the rest: docs/engines.md,
  "States built: on demand or whole");
- both paths' optimum is the brute force's (tests/test_inject_joint.py's oracle).
"""

from __future__ import annotations

import math

import numpy as np
import pytest
from inject_scale import cases
from joint_oracle import oracle_paths
from test_inject_joint import _deviation, _spec, brute_paths
from test_joint_inject_prune import scenes

from lesmc import api
from lesmc.model.arrays import ArrayModel
from lesmc.model.growing import GrowingModel
from lesmc.pipeline.check import run
from lesmc.pipeline.job import Job
from lesmc.tracking.trackers import make_tracker
from lesmc.unfold import unfold


def expanded_to(model: GrowingModel, end: int) -> int:
    """The on-demand model's states once every live state before ``end`` is expanded,
    step by step (the engines' own interface: :meth:`GrowingModel.expand`)."""
    while True:
        n = model.n_states
        todo = np.flatnonzero((model.out_lo[:n] < 0) & ~model.halted[:n] & (model.step[:n] < end))
        if not todo.size:
            return n
        k = int(model.step[todo].min())
        model.expand(todo[model.step[todo] == k], k)


def brute_optimum(scene: object, window: tuple[int, int], end: int, bound: float) -> float:
    """The cheapest cost of a path whose dist.max(0..end) exceeds ``bound`` (inf: none),
    from the brute force over every hiding option and candidate subset."""
    original = oracle_paths(scene, (end + 1, end + 1), end)[0][0]  # type: ignore[arg-type]
    leaves = brute_paths(scene, window, end)  # type: ignore[arg-type]
    costs = [c for xs, _, c in leaves if _deviation(xs, original) > bound]
    return min(costs, default=math.inf)


def optimum(res: object) -> float:
    r = res.runs[0].results[0]  # type: ignore[attr-defined]
    return math.inf if r.optimum is None else float(r.optimum)


def test_check_and_verify_build_the_same_model_with_candidates() -> None:
    """Ends below the unattacked track's last step and at it: the whole model (verify's
    path) equals the fully expanded on-demand model (check's) in states, stops at the
    property's end, and both optima are the brute force's. Fails on the old code, whose
    whole model went on to the last step (more states than check's model has)."""
    rng = np.random.default_rng(3)
    short = 0
    for scene, window in scenes(cases(12, 60), 31, far=3, mid=2, width=2):
        scene = scene.with_tracker(max_trace=1e12)
        e = unfold.original_end(scene, make_tracker(scene))
        end = int(rng.integers(window[1], e + 1))
        short += end < e
        bound = float(rng.choice([0.5, 3.0, 10.0]))
        spec = api.parse_spec(_spec(window, end, bound, " allow hide, inject"))
        whole = run(Job((spec,), scene=scene, full_models=True))  # verify's path
        lazy = run(Job((spec,), scene=scene))  # check's path
        model = whole.runs[0].model
        assert isinstance(model, ArrayModel)
        assert int(model.step.max()) <= end and model.end == end, (window, end, e)
        grown = expanded_to(unfold.lazy_model(scene, window, end, inject=True), end)
        assert model.n_states == grown, (window, end, e)
        built = lazy.runs[0].results[0].stats.extra["states_built"]
        assert built <= model.n_states
        want = brute_optimum(scene, window, end, bound)
        assert optimum(whole) == pytest.approx(want, abs=1e-9), (window, end, bound)
        assert optimum(lazy) == pytest.approx(want, abs=1e-9), (window, end, bound)
    assert short  # some property ends before the track does: the case the fix is for
