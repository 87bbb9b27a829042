"""Injection on the joint design (issue 61): ``attack window L..U allow hide, inject`` on
``joint``. Against a brute force written here on top of tests/joint_oracle.py (filterpy
filters, the greedy likelihood scan, written from the paper, not from lesmc): at an
attacked step every hiding option (the j nearest the primary's prediction, as without
injection) is combined with every subset of the frame's injection candidates, which join
the frame after its detections (in their order), at the sum of the payoffs; outcomes with
the same joint state keep the cheapest. The model lesmc unfolds must hold exactly the
brute force's paths (primary estimates, halted, total cost), and every engine's optimum
of ``minimize payoff subject to dist.max(0..end) > D`` must be the brute force's."""

from __future__ import annotations

import dataclasses
import itertools
import math
import sys
import types
from pathlib import Path

import numpy as np
import pytest
from inject_scale import cases
from joint_oracle import Joint, Oracle, _warp, oracle_paths
from test_joint import _canonical, model_paths

import lesmc.unfold.unfold as unfold
from lesmc import api
from lesmc.common.errors import LesmcError
from lesmc.designs import registry
from lesmc.engines import registry as engines
from lesmc.scene import Detection, Frame, JointConfig, Scene, Target, TrackerConfig
from lesmc.tracking.single import SingleDesign
from lesmc.tracking.trackers import make_tracker

#: random scenes of the default run; LESMC_INJECT_FULL=1 runs the issue's 200
SCENES = cases(40, 200)


class InjectOracle(Oracle):
    """The paper's joint tracker, one state at a time, under hide (if ``hide``) + inject."""

    def __init__(self, scene: Scene, hide: bool = True) -> None:
        super().__init__(scene)
        self.hide = hide

    def options(self, st: Joint, frame_step: int, attacked: bool) -> list[tuple[float, Joint]]:
        if not attacked:
            return super().options(st, frame_step, attacked)
        Hm = self.scene.frame(frame_step - 1).to_next
        preds = []
        for x, P in st.tracks:
            x = x.copy()
            x[:2] = _warp(Hm, x[:2])
            kf = self._kf(x, P)
            kf.predict()
            preds.append(kf)
        pending = np.array([_warp(Hm, p) for p in st.pending]).reshape(-1, 2)
        frame = self.scene.frame(frame_step)
        Z = frame.positions().reshape(-1, 2)
        C = np.array([[c.x, c.y] for c in frame.candidates]).reshape(-1, 2)
        pays, cpays = frame.payoffs(), [c.payoff for c in frame.candidates]
        n = len(Z)
        xp = preds[0].x[:2, 0]
        by_dist = sorted(range(n), key=lambda i: (math.dist(Z[i], xp), i))
        gated = [r for r, i in enumerate(by_dist) if self._gate(preds[0], Z[i])]
        last = max(gated) + 1 if gated and self.hide else 0
        best: dict[bytes, tuple[float, Joint]] = {}
        ZC = np.vstack([Z, C])
        for j in range(last + 1):
            hidden = by_dist[:j]
            if any(not math.isfinite(pays[i]) for i in hidden):
                break
            for r in range(len(C) + 1):
                for sub in itertools.combinations(range(len(C)), r):
                    shown = {n + c for c in sub}
                    off = set(hidden) | {n + c for c in range(len(C)) if n + c not in shown}
                    nxt = self._step(preds, pending, ZC, off)
                    cost = float(sum(pays[i] for i in hidden) + sum(cpays[c] for c in sub))
                    if nxt.key() not in best or cost < best[nxt.key()][0]:
                        best[nxt.key()] = (cost, nxt)
        return sorted(best.values(), key=lambda cn: cn[0])


def brute_paths(
    scene: Scene, window: tuple[int, int], end: int, hide: bool = True
) -> list[tuple[tuple[tuple[float, ...], ...], bool, float]]:
    """Every complete path under hide (+ inject): primary estimates, halted, total cost."""
    oracle = InjectOracle(scene, hide)
    out = []
    todo = [(0, oracle.initial(), (), 0.0)]
    while todo:
        k, st, xs, cost = todo.pop()
        xs = (*xs, tuple(st.tracks[0][0]))
        if st.halted or k == end:
            out.append((xs, st.halted, cost))
            continue
        attacked = window[0] <= k + 1 <= window[1]
        for c, nxt in oracle.options(st, scene.target.step + k + 1, attacked):
            todo.append((k + 1, nxt, xs, cost + c))
    return out


def random_scene(rng: np.random.Generator, max_trace: float | None = None) -> Scene:
    """A target among a few vehicles with clutter and injection candidates on a coarse grid
    (ties in likelihood and position are common), camera motion now and then."""
    frames = int(rng.integers(4, 7))
    grid = float(rng.choice([1.0, 5.0, 20.0]))

    def coord() -> float:
        return 500.0 + int(rng.integers(-8, 9)) * grid

    def payoff() -> float:
        return float(rng.integers(1, 5)) if rng.random() < 0.85 else math.inf

    vehicles = [
        (coord(), coord(), float(rng.integers(-3, 4)), float(rng.integers(-3, 4)), payoff())
        for _ in range(int(rng.integers(0, 4)))
    ]
    tx, ty, tvx = coord(), coord(), float(rng.integers(-3, 4))
    out = []
    for k in range(frames):
        dets = []
        if rng.integers(0, 5):
            dets.append((tx + tvx * k, ty, payoff()))
        for x, y, vx, vy, p in vehicles:
            if rng.integers(0, 5):
                dets.append((x + vx * k, y + vy * k, p))
        for _ in range(int(rng.integers(0, 2))):
            dets.append((coord(), coord(), payoff()))
        cands = []
        for _ in range(int(rng.integers(0, 3))):  # near the target, or a twin of a detection
            if dets and rng.random() < 0.2:
                x, y, _ = dets[int(rng.integers(0, len(dets)))]
            else:
                x, y = (
                    tx + tvx * k + int(rng.integers(-3, 4)) * grid,
                    ty + int(rng.integers(-3, 4)) * grid,
                )
            cands.append((x, y, float(rng.integers(0, 4)) + 0.5 * float(rng.integers(0, 2))))
        detections = tuple(Detection(f"{k}:{i}", x, y, p) for i, (x, y, p) in enumerate(dets))
        candidates = tuple(
            Detection(f"{k}:{len(dets) + i}", x, y, p) for i, (x, y, p) in enumerate(cands)
        )
        Hm = None
        if rng.integers(0, 4) == 0:
            Hm = np.array([[1.0, 0.001, 2.0], [0.0, 1.0, -1.5], [0.0, 0.0, 1.0]])
        out.append(Frame(k, detections, Hm, candidates=candidates))
    tracker = TrackerConfig(
        design="joint",
        gate=float(rng.choice([1.0, 2.0, 3.0, 6.0])),
        gate_type=str(rng.choice(["mahalanobis", "euclidean"])),
        max_trace=float(rng.choice([1e5, 3000.0, 2000.0])) if max_trace is None else max_trace,
        joint=JointConfig(
            init_radius=float(rng.choice([30.0, 150.0, 400.0])),
            init_distance=float(rng.choice([10.0, 60.0, 200.0])),
            prune_radius=float(rng.choice([20.0, 60.0, 200.0])),
        ),
        sigma_q=float(rng.choice([1.0, 3.0])),
    )
    return Scene(1.0, tuple(out), Target(0, (tx, ty), (tvx, 0.0)), tracker)


def _window(scene: Scene, rng: np.random.Generator) -> tuple[int, int] | None:
    """A window of one or two steps with a candidate in it (None: the scene has none)."""
    e = unfold.original_end(scene, make_tracker(scene))
    if e < 1:
        return None
    lo = int(rng.integers(1, e + 1))
    hi = min(e, lo + int(rng.integers(0, 2)))
    if not any(scene.frame(scene.target.step + k).candidates for k in range(lo, hi + 1)):
        return None
    return lo, hi


def _cases(n: int, seed: int, **kw: float) -> list[tuple[Scene, tuple[int, int]]]:
    rng = np.random.default_rng(seed)
    out = []
    while len(out) < n:
        scene = random_scene(rng, **kw)
        window = _window(scene, rng)
        if window is not None:
            out.append((scene, window))
    return out


@pytest.mark.parametrize("chunk", range(4))
def test_joint_paths_under_inject_equal_the_brute_force(chunk: int) -> None:
    """Every run of the joint tracker under hide + inject (tests/joint_oracle.py's filters
    and association on the detections left and the candidates injected) is a path of the
    model at its cheapest cost, and no other."""
    more = 0
    for scene, window in _cases(SCENES // 4, 300 + chunk):
        cm = unfold.build_model(scene, window, inject=True)
        ours = _canonical(model_paths(cm))
        assert ours == _canonical(brute_paths(scene, window, cm.end)), window
        hide_only = unfold.build_model(scene, window)
        more += len(ours) > len(_canonical(model_paths(hide_only)))
    assert more  # injection added outcomes somewhere


def test_joint_inject_alone_equals_the_brute_force() -> None:
    """``allow inject`` alone: no detection is hidden."""
    for scene, window in _cases(10, 77):
        cm = unfold.build_model(scene, window, inject=True, hide=False)
        assert _canonical(model_paths(cm)) == _canonical(brute_paths(scene, window, cm.end, False))


def _deviation(
    path: tuple[tuple[float, ...], ...], original: tuple[tuple[float, ...], ...]
) -> float:
    return max(math.dist(a, b) for a, b in zip(path, original, strict=True))


def _spec(window: tuple[int, int], end: int, bound: float, allow: str) -> str:
    return (
        f"property p {{ attack window {window[0]}..{window[1]}{allow} end {end} minimize "
        f"payoff subject to dist.max(0..end) > {bound} holds if optimum > 1000 }}\n"
    )


def test_every_engine_equals_the_brute_force_on_joint() -> None:
    """The optimum of every engine on joint under hide + inject is the brute force's, and
    hide only is never below it (some case strictly above)."""
    rng = np.random.default_rng(9)
    strict = 0
    for scene, window in _cases(cases(10, 200), 500, max_trace=1e12):
        end = unfold.original_end(scene, make_tracker(scene))
        original = oracle_paths(scene, (end + 1, end + 1), end)
        assert len(original) == 1
        leaves = [
            (c, _deviation(xs, original[0][0])) for xs, _, c in brute_paths(scene, window, end)
        ]
        hide_leaves = [
            (c, _deviation(xs, original[0][0])) for xs, _, c in oracle_paths(scene, window, end)
        ]
        devs = sorted({round(d, 6) for _, d in leaves})
        if len(devs) < 2:
            continue
        i = int(rng.integers(0, len(devs) - 1))
        bound = round((devs[i] + devs[i + 1]) / 2, 6)
        want = min((c for c, d in leaves if d > bound), default=math.inf)
        for engine in engines.names():
            res = api.check(
                scene,
                api.parse_spec(_spec(window, end, bound, " allow hide, inject")),
                engine=engine,
            )
            got = math.inf if res[0].optimum is None else float(res[0].optimum)
            assert got == pytest.approx(want, abs=1e-9), (engine, window, bound)
        want_hide = min((c for c, d in hide_leaves if d > bound), default=math.inf)
        res = api.check(scene, api.parse_spec(_spec(window, end, bound, "")))
        got_hide = math.inf if res[0].optimum is None else float(res[0].optimum)
        assert got_hide == pytest.approx(want_hide, abs=1e-9)
        assert got_hide >= want  # adding inject never raises an optimum
        strict += got_hide > want
    assert strict


class _NoInject(SingleDesign):
    """A user's design that does not register for ``inject``."""


def test_inject_on_a_design_that_does_not_take_it_is_a_located_error() -> None:
    """Every built-in single-target design takes inject now; a registered one that the
    action's registry does not list is refused at the ``allow`` clause."""
    module = types.ModuleType("lesmc_noinject_design")
    module.NoInject = _NoInject  # type: ignore[attr-defined]
    sys.modules["lesmc_noinject_design"] = module
    registry.tracker("noinject", "lesmc_noinject_design:NoInject", "no inject", "a test's")
    try:
        scene, window = _cases(1, 3)[0]
        scene = scene.with_tracker(design="noinject")
        spec = "\n" + _spec(window, 2, 1.0, " allow hide, inject")
        with pytest.raises(LesmcError) as err:
            api.check(scene, api.parse_spec(spec, "p.spec"))
        text = str(err.value)
        assert "p.spec:2:" in text and "not supported for the noinject design" in text, text
    finally:
        registry.unregister("noinject")
        del sys.modules["lesmc_noinject_design"]


def test_improved_takes_inject_and_its_monitor_only_removes_paths() -> None:
    """``improved`` (joint + the runtime monitor) under hide + inject: the monitor keeps a
    subset of joint's attacked paths, so its optimum is never below joint's."""
    for scene, window in _cases(5, 41, max_trace=1e12):
        end = unfold.original_end(scene, make_tracker(scene))
        text = _spec(window, end, 0.5, " allow hide, inject")
        joint = api.check(scene, api.parse_spec(text), designs="joint")[0]
        improved = api.check(scene, api.parse_spec(text), designs="improved")[0]
        low = math.inf if joint.optimum is None else float(joint.optimum)
        assert (math.inf if improved.optimum is None else float(improved.optimum)) >= low


def test_storm_agrees_on_joint_drn_exports_with_injections(tmp_path: Path) -> None:
    """Storm's exact optimum of the exported MDP of a joint model built with injection
    (rewards: the own payoffs of Eq. 5, the ranks ordered by cost) equals the brute
    force's (10 models; LESMC_INJECT_FULL=1: 60)."""
    pytest.importorskip("stormpy")
    from test_export import assert_equal_exactly, storm_optimum

    from lesmc.engines.check import bind_all
    from lesmc.exporters.drn import to_drn

    rng = np.random.default_rng(61)
    done = 0
    for scene, window in _cases(cases(10, 60) * 2, 610, max_trace=1e12):
        if done == cases(10, 60):
            break
        end = unfold.original_end(scene, make_tracker(scene))
        original = oracle_paths(scene, (end + 1, end + 1), end)[0][0]
        leaves = [(c, _deviation(xs, original)) for xs, _, c in brute_paths(scene, window, end)]
        devs = sorted({round(d, 6) for _, d in leaves})
        if len(devs) < 2:
            continue
        i = int(rng.integers(0, len(devs) - 1))
        bound = round((devs[i] + devs[i + 1]) / 2, 6)
        want = min((c for c, d in leaves if d > bound), default=math.inf)
        model = unfold.build_model(scene, window, end, inject=True)
        spec = api.parse_spec(_spec(window, end, bound, " allow hide, inject"))
        text, _ = to_drn(model, bind_all(model, [spec])[0])
        assert_equal_exactly(storm_optimum(text, tmp_path), want, text, end + 1)
        done += 1
    assert done == cases(10, 60)


def test_a_joint_injection_result_no_longer_says_its_hidden_detections_are_not_listed() -> None:
    """joint now says which detections the cheapest way to an injected outcome hides
    (tests/test_inject_joint_listed.py checks the lists): no result carries round 20's
    note that they are not listed, on joint or on single."""
    scene, window = _cases(1, 501, max_trace=1e12)[0]
    end = unfold.original_end(scene, make_tracker(scene))
    spec = api.parse_spec(_spec(window, end, 0.0, " allow hide, inject"))
    joint = api.check(scene, spec)[0]
    assert not any("does not yet say which detections" in n for n in joint.notes), joint.notes
    single = dataclasses.replace(scene, tracker=dataclasses.replace(scene.tracker, design="single"))
    res = api.check(single, spec)[0]
    assert not any("does not yet say which detections" in n for n in res.notes), res.notes
