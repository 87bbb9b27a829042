"""The joint design under ``allow hide, inject`` offers each state the subsets of only the
injection candidates that can change its successor (lesmc/tracking/parts/attacker_subsets.py
``relevant_candidates``; the proof: docs/semantics.md, "Pruning injection candidates").

Checked on random small scenes with many candidates far from everything (and some at
middle distance, near the edges of gates and birth regions):
- the model equals, array for array, the model built with every candidate offered to every
  state (the engine before pruning: ``candidate_relevance`` patched to "all relevant"), and
  far fewer (state, subset) rows are built;
- its paths equal the brute force of tests/test_inject_joint.py (filterpy oracle, every
  hiding option × every subset of the frame's candidates), and every engine's optimum and
  the counterexample's listed attack (applied through the oracle, at its cost) are the
  brute force's and the unpruned engine's;
- a candidate inside a gate (and outside every birth region) is kept: where injecting it is
  the only attack, the optimum is its payoff, and a pruning that ignores gates loses it.
"""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Iterator

import numpy as np
import pytest
from inject_scale import cases
from joint_oracle import oracle_paths
from test_inject_joint import _canonical, _deviation, _spec, brute_paths, random_scene
from test_inject_joint_listed import Applied, cost_of
from test_joint import model_paths

import lesmc.tracking.joint as joint_mod
import lesmc.tracking.parts.joint_step as joint_step
import lesmc.unfold.unfold as unfold
from lesmc import api
from lesmc.engines import registry as engines
from lesmc.model.arrays import ArrayModel
from lesmc.pipeline.check import run
from lesmc.pipeline.job import Job
from lesmc.results.document import run_json
from lesmc.scene import Detection, Frame, JointConfig, Scene, Target, TrackerConfig
from lesmc.tracking.trackers import make_tracker


def with_candidates(scene: Scene, rng: np.random.Generator, far: int, mid: int) -> Scene:
    """``scene`` with, in every frame, ``far`` more candidates 5,000-9,000 px from the
    target (beyond every gate and birth region of these scenes) and ``mid`` 50-600 px away
    (inside or outside them), of payoffs 0-3 (0 included: a free candidate)."""
    x0, y0 = scene.target.start
    frames = []
    for f in scene.frames:
        extra = []
        for i in range(far + mid):
            r = rng.uniform(5000, 9000) if i < far else rng.uniform(50, 600)
            a = rng.uniform(0, 2 * math.pi)
            cid = f"{f.step}:{len(f.detections) + len(f.candidates) + i}"
            pay = float(rng.integers(0, 4))
            extra.append(Detection(cid, x0 + r * math.cos(a), y0 + r * math.sin(a), pay))
        frames.append(dataclasses.replace(f, candidates=f.candidates + tuple(extra)))
    return dataclasses.replace(scene, frames=tuple(frames))


def scenes(n: int, seed: int, far: int, mid: int, width: int) -> Iterator[tuple[Scene, tuple]]:
    """``n`` random joint scenes with candidates added and an attack window of ``width``
    (1 or 2) steps."""
    rng = np.random.default_rng(seed)
    done = 0
    while done < n:
        scene = random_scene(rng)
        e = unfold.original_end(scene, make_tracker(scene))
        if e < 1:
            continue
        lo = int(rng.integers(1, e + 1))
        done += 1
        yield with_candidates(scene, rng, far, mid), (lo, min(e, lo + width - 1))


class Counted:
    """Counts the (state, candidate subset) rows the joint design builds under inject."""

    def __init__(self, monkeypatch: pytest.MonkeyPatch, prune: bool = True) -> None:
        self.rows = 0
        inner = joint_mod.pruned_subsets

        def counting(relevant: np.ndarray) -> tuple:
            out = inner(relevant)
            self.rows += len(out[0])
            return out

        monkeypatch.setattr(joint_mod, "pruned_subsets", counting)
        if not prune:  # every candidate offered to every state: the engine before pruning
            monkeypatch.setattr(
                joint_mod,
                "candidate_relevance",
                lambda p, _init, nd: np.ones((len(p.tu), len(p.Z) - nd), dtype=bool),
            )


def unpruned(scene: Scene, window: tuple[int, int]) -> tuple[ArrayModel, int]:
    """The model without pruning and the rows it built."""
    with pytest.MonkeyPatch.context() as mp:
        c = Counted(mp, prune=False)
        return unfold.build_model(scene, window, inject=True), c.rows


def assert_same_model(a: ArrayModel, b: ArrayModel) -> None:
    for f in ("ptr", "dst", "rank", "payoff", "S", "halted"):
        assert np.array_equal(getattr(a, f), getattr(b, f)), f


def test_pruned_models_equal_the_unpruned_ones_and_build_fewer_subsets(
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    """8 far and 2 middle candidates a frame, windows of 2 steps: the same model, array for
    array, and fewer (state, subset) rows (2^10+ a state unpruned)."""
    pruned_rows = all_rows = 0
    for scene, window in scenes(cases(8, 40), 11, far=8, mid=2, width=2):
        want, rows = unpruned(scene, window)
        c = Counted(monkeypatch)
        got = unfold.build_model(scene, window, inject=True)
        monkeypatch.undo()
        assert_same_model(got, want)
        assert c.rows <= rows
        pruned_rows += c.rows
        all_rows += rows
    assert pruned_rows * 50 < all_rows, (pruned_rows, all_rows)


def test_pruned_paths_equal_the_brute_force() -> None:
    """3 far and 1 middle candidate a frame (and the scene's own, near the target), one
    attacked step: every path of the model is a run of the brute force at its cheapest
    cost, and no other."""
    for scene, window in scenes(cases(10, 60), 12, far=3, mid=1, width=1):
        cm = unfold.build_model(scene, window, inject=True)
        assert _canonical(model_paths(cm)) == _canonical(brute_paths(scene, window, cm.end))


def test_optimum_and_counterexample_equal_the_brute_force_and_the_unpruned_engine() -> None:
    """Every engine's optimum of ``dist.max(0..end) > D`` equals the brute force's; the
    counterexample's listed attack is the unpruned engine's, costs the optimum and, applied
    through the oracle, moves the track beyond D."""
    rng = np.random.default_rng(5)
    checked = 0
    for scene, window in scenes(cases(6, 30), 13, far=3, mid=1, width=1):
        scene = scene.with_tracker(max_trace=1e12)
        end = unfold.original_end(scene, make_tracker(scene))
        original = oracle_paths(scene, (end + 1, end + 1), end)[0][0]
        leaves = [(c, _deviation(xs, original)) for xs, _, c in brute_paths(scene, window, end)]
        devs = sorted({round(d, 6) for _, d in leaves})
        if len(devs) < 2:
            continue
        i = int(rng.integers(0, len(devs) - 1))
        bound = round((devs[i] + devs[i + 1]) / 2, 6)
        want = min((c for c, d in leaves if d > bound), default=math.inf)
        spec = api.parse_spec(_spec(window, end, bound, " allow hide, inject"))
        for engine in engines.names():
            res = api.check(scene, spec, engine=engine)
            got = math.inf if res[0].optimum is None else float(res[0].optimum)
            assert got == pytest.approx(want, abs=1e-9), (engine, window, bound)
        if math.isinf(want):
            continue
        doc = listed(scene, spec)
        with pytest.MonkeyPatch.context() as mp:
            Counted(mp, prune=False)
            assert listed(scene, spec) == doc
        oracle, st, cost, xs = Applied(scene), Applied(scene).initial(), 0.0, []
        xs.append(st.tracks[0][0][:2])
        for k in range(1, end + 1):
            if st.halted:
                break
            hid, inj = doc.get(k, ([], []))
            cost += cost_of(scene, scene.target.step + k, hid, inj)
            st = oracle.apply(st, scene.target.step + k, hid, inj)
            xs.append(st.tracks[0][0][:2])
        assert cost == pytest.approx(want, abs=1e-9)
        assert max(math.dist(a, b[:2]) for a, b in zip(xs, original, strict=False)) > bound
        checked += 1
    assert checked


def listed(scene: Scene, spec: object) -> dict[int, tuple[list[str], list[str]]]:
    """The counterexample's hidden and injected ids per step (results document)."""
    res = run(Job((spec,), scene=scene, full_models=True))  # type: ignore[arg-type]
    doc = run_json(res.runs[0])
    steps: dict[int, tuple[list[str], list[str]]] = {}
    for key, i in (("hidden", 0), ("injected", 1)):
        for item in doc[key]["p"]:
            steps.setdefault(item["step"], ([], []))[i].append(item["obs"])
    return steps


def gated_only_scene() -> Scene:
    """The target at (500, 500) moving right 10 px a step; at frame 2 it is missed and a
    candidate 4 px below its prediction (inside the gate, 3σ) costs 1; birth regions
    (init_radius 0.001 px) reach no candidate: only the gate makes it relevant."""
    frames = []
    for k in range(4):
        dets = () if k == 2 else (Detection(f"{k}:0", 500.0 + 10 * k, 500.0, 5.0),)
        cands = (Detection("2:1", 520.0, 504.0, 1.0),) if k == 2 else ()
        frames.append(Frame(k, dets, None, candidates=cands))
    tracker = TrackerConfig(
        design="joint",
        gate=3.0,
        gate_type="mahalanobis",
        joint=JointConfig(init_radius=1e-3, init_distance=1e-3, prune_radius=100.0),
    )
    return Scene(1.0, tuple(frames), Target(0, (500.0, 500.0), (10.0, 0.0)), tracker)


def test_a_candidate_inside_a_gate_is_kept(monkeypatch: pytest.MonkeyPatch) -> None:
    """Injecting the gated candidate is the only attack that moves the track (hiding alone
    leaves the missed frame a coast on the original path): the optimum is its payoff 1,
    the counterexample injects it; a pruning that drops gated candidates (relevance from
    births only) finds no attack, so this test fails on it."""
    scene = gated_only_scene()
    spec = api.parse_spec(
        "property p { attack window 1..3 allow hide, inject end 3 minimize payoff "
        "subject to dist.max(0..end) > 0.5 holds if optimum > 100 }\n"
    )
    res = api.check(scene, spec)
    assert res[0].optimum is not None and float(res[0].optimum) == pytest.approx(1.0)
    assert listed(scene, spec) == {2: ([], ["2:1"])}
    inner = joint_step.relevant_candidates
    none = np.zeros(0, dtype=np.int64)
    monkeypatch.setattr(
        joint_step,
        "relevant_candidates",
        lambda n, nd, _pairs, primary, births: inner(n, nd, (none, none), primary, births),
    )
    res = api.check(scene, spec)
    assert res[0].optimum is None or math.isinf(float(res[0].optimum))
