"""Review 24's findings (docs/semantics.md, "A root no monitored path leaves" and
"Violated on the frames by another path"): the relaxation to the joint design's primary
on a horizon of hundreds of steps (an explicit stack, no recursion), asked only when the
property can be vacuous and within the check's budget, a dead root's transitions left
out of the allowed mask, ``count`` judged on the frames only where it is the detections
hidden, and the replay cache's key over the code that judges."""

from __future__ import annotations

import json
from pathlib import Path
from types import SimpleNamespace
from typing import Any

import numpy as np
import pytest
from cli_run import lesmc
from test_relaxed_root import _cases, _relaxed

import lesmc.engines.lazy as lazy
import lesmc.tracking.parts.relaxed as relaxed
import lesmc.unfold.unfold as unfold
from lesmc import api
from lesmc.engines import below
from lesmc.results.read import PropertyDoc
from lesmc.results.replay_measures import judged_measures
from lesmc.scene import Detection, Frame, JointConfig, Scene, Target, TrackerConfig, save_scene

TOL = 1e-9  # Eq. 13's default tolerance (monitor uncertainty)
JOINT = TrackerConfig(
    design="joint",
    gate=3.0,
    gate_type="mahalanobis",
    max_trace=1e5,
    joint=JointConfig(init_radius=30.0, init_distance=10.0, prune_radius=60.0),
    sigma_q=1.0,
)


def _long_scene(n: int) -> Scene:
    """A target moving 2 px a frame, one detection on it and one injection candidate
    3 px off in each of ``n`` frames."""
    frames = []
    for k in range(n):
        x = 100.0 + 2.0 * k
        dets = (Detection(f"{k}:0", x, 200.0, 1.0),)
        frames.append(Frame(k, dets, None, candidates=(Detection(f"{k}:1", x + 3, 201.0, 1.0),)))
    return Scene(1.0, tuple(frames), Target(0, (100.0, 200.0), (2.0, 0.0)), JOINT)


def _gap_scene() -> Scene:
    """Three gated detections a frame, then two empty frames (12, 13): the unattacked path
    skips twice and its τ rises (review 24's cap_cost.py)."""
    frames = []
    for k in range(16):
        x = 100.0 + 2.0 * k
        offs = () if k in (12, 13) else (0.0, 1.5, -1.5)
        dets = tuple(Detection(f"{k}:{i}", x + d, 200.0 + d / 2, 1.0) for i, d in enumerate(offs))
        frames.append(Frame(k, dets, None))
    return Scene(1.0, tuple(frames), Target(0, (100.0, 200.0), (2.0, 0.0)), JOINT)


def _spec(window: str, end: int, actions: str = "", monitor: str = "monitor uncertainty") -> str:
    return (
        f"property p {{ attack window {window} {actions} end {end} minimize payoff subject to "
        f"dist.max(0..end) > 3 holds if optimum > 1000 {monitor} }}\n"
    )


@pytest.fixture
def moves(monkeypatch: pytest.MonkeyPatch) -> list[int]:
    """Counts the relaxed nodes expanded (one ``_moves`` call each)."""
    calls = [0]
    orig = relaxed._moves

    def counting(*a: Any) -> Any:
        calls[0] += 1
        return orig(*a)

    monkeypatch.setattr(relaxed, "_moves", counting)
    return calls


# ------------------------------------------------------------------ 1. the horizon
def _tau(P: np.ndarray, pos: tuple[int, ...]) -> float:
    """Eq. 12: the trace of P's position block, written out."""
    return float(sum(P[i, i] for i in pos))


def test_the_relaxation_runs_a_horizon_of_hundreds_of_steps() -> None:
    """Asked directly on 450 steps under Eq. 13's monitor (a skip raises τ, so the only
    paths that pass update at every step: a path 450 deep), the relaxation answers alive
    (the unattacked path passes: its τ never rises) instead of overflowing Python's
    recursion limit."""
    scene, end = _long_scene(451), 450
    pos = scene.tracker.measured
    assert not _unattacked_alarms(scene, (1, 1), end)
    model = unfold.lazy_model(scene, (1, 1), end, inject=True)

    def cut(k: int, p0: np.ndarray, p1: np.ndarray) -> bool:
        return _tau(p1, pos) > _tau(p0, pos) * (1 + TOL)

    ask = model.expander.primary_alive  # type: ignore[union-attr]
    assert ask(int(model.original[0]), end, cut) is True


def test_a_long_joint_check_through_the_cli(tmp_path: Path) -> None:
    """Review 24's repro through the real entry point, 450 steps: `check --design improved`
    (the monitor on) exits with the verdict of the search without the relaxation, no
    traceback (it exited 4, RecursionError, on 5df10d6)."""
    scene = _long_scene(450)
    save_scene(scene, tmp_path / "scene.json")
    spec = _spec("1..1", 449, "allow hide, inject", monitor="")
    (tmp_path / "p.spec").write_text(spec)
    args = ("check", str(tmp_path / "scene.json"), str(tmp_path / "p.spec"))
    run = lesmc(*args, "--design", "improved", "--json")
    assert "Traceback" not in run.stderr and run.returncode in (0, 1), run.stderr[-2000:]
    got = json.loads(run.stdout)["results"][0]
    old = lazy.DEAD_ROOT
    try:
        lazy.DEAD_ROOT = False
        want = api.check(scene, api.parse_spec(spec), designs="improved")[0]
    finally:
        lazy.DEAD_ROOT = old
    assert got["verdict"] == want.verdict
    assert run.returncode == (1 if want.verdict == "violated" else 0)


# ------------------------------------------------------- 2. asked only when it can matter
def _unattacked_alarms(scene: Scene, window: tuple[int, int], end: int) -> bool:
    """τ (Eq. 12, written out) rises by more than TOL on the unattacked path entering some
    step in l..end."""
    model = unfold.lazy_model(scene, window, end, inject=True)
    pos = scene.tracker.measured
    P = model.P_table[model.cov[np.asarray(model.original)]]
    tau = [_tau(p, pos) for p in P]
    return any(
        tau[k] > tau[k - 1] * (1 + TOL) for k in range(window[0], min(end, len(tau) - 1) + 1)
    )


def test_not_asked_when_the_unattacked_path_passes(moves: list[int]) -> None:
    scene = _long_scene(30)
    assert not _unattacked_alarms(scene, (1, 2), 29)
    res = api.check(scene, api.parse_spec(_spec("1..2", 29, "allow hide, inject")))[0]
    assert moves[0] == 0 and res.verdict in ("holds", "violated")


def test_not_asked_under_except_original(moves: list[int]) -> None:
    scene = _gap_scene()
    assert _unattacked_alarms(scene, (1, 2), 15)
    spec = _spec("1..2", 15, monitor="monitor uncertainty except original")
    api.check(scene, api.parse_spec(spec))
    assert moves[0] == 0


def test_the_question_stops_at_the_budget(moves: list[int]) -> None:
    """The gap scene's question hits the 5,000-node cap unbudgeted; --max-states and
    --timeout stop it earlier (and the check then says unknown, not holds)."""
    scene, spec = _gap_scene(), api.parse_spec(_spec("1..2", 15))
    api.check(scene, spec, max_states=40)
    assert 0 < moves[0] <= 40
    moves[0] = 0
    res = api.check(scene, spec, timeout=0.2)[0]
    assert moves[0] < relaxed.MAX_NODES
    assert res.verdict == "unknown"


# ---------------------------------------------------------- 7. the allowed mask
def test_a_dead_roots_transitions_are_not_allowed(monkeypatch: pytest.MonkeyPatch) -> None:
    """Once the root is expanded, none of its transitions is in the space's allowed mask,
    so `below`, which reads the mask, sees none either."""
    scene, window, end = next(c for c in _cases(60, 61) if _relaxed(*c) is False)
    spaces: list[lazy.LazySpace] = []
    init = lazy.LazySpace.__init__

    def keep(self: lazy.LazySpace, *a: Any) -> None:
        init(self, *a)
        spaces.append(self)

    monkeypatch.setattr(lazy.LazySpace, "__init__", keep)
    spec = _spec(f"{window[0]}..{window[1]}", end, "allow hide, inject")
    res = api.check(scene, api.parse_spec(spec))[0]
    assert res.verdict == "holds" and res.vacuous
    space = next(s for s in spaces if s.dead_root)
    root = np.array([space.root])
    space.cm.expand(root, int(space.cm.step[space.root]))
    space.sync()
    lo, hi = int(space.cm.out_lo[space.root]), int(space.cm.out_hi[space.root])
    assert hi > lo and not space.allowed_mask()[lo:hi].any()
    assert below._moves(space, root)[1].size == 0


# -------------------------------------------------------------- 4. one step, once
def test_the_relaxation_reads_the_designs_own_step() -> None:
    """relaxed.py moves the primary with joint_step.py's measurements and predict/gate,
    not a copy of them."""
    src = Path(relaxed.__file__).read_text()
    assert "measurements(" in src and "predict_and_gate(" in src
    for copy in ("warp(", "predict_means(", ".pairs(", ".candidates"):
        assert copy not in src.split('"""', 2)[2], copy


# ------------------------------------------------------------ 5. count on the frames
def _prop(actions: tuple[str, ...]) -> PropertyDoc:
    return PropertyDoc(
        name="p", constraint_source="dist", constraint_aggregate="max", constraint_range=(0, 9),
        bound=3.0, monitor=None, actions=actions, constraint_op=">", components=("x", "y"),
        window=(2, 3),
    )  # fmt: skip


@pytest.mark.parametrize(
    ("actions", "tracker", "judged"),
    [
        (("hide",), "single", True),
        (("hide", "inject"), "single", False),
        (("inject",), "single", False),
        (("hide",), "joint", False),
        (("hide", "inject"), "joint", False),
        (("hide",), "", False),
    ],
)
def test_count_is_judged_only_where_it_counts_hidden_detections(
    actions: tuple[str, ...], tracker: str, judged: bool
) -> None:
    got = judged_measures(_prop(actions), "count", "count", tracker)
    assert isinstance(got, str) is not judged, got
    if not judged:
        assert isinstance(got, str) and "count" in got
    for source, text in (("frames", "count.frames"), ("payoff", "payoff")):  # stay judged
        assert not isinstance(judged_measures(_prop(actions), source, text, tracker), str)


# -------------------------------------------------------------- 6. the cache key
def test_the_replay_key_digests_the_code_that_judges(monkeypatch: pytest.MonkeyPatch) -> None:
    """The replay cache's key covers the packages of every module that decides a cached
    replay object's `on_frames`."""
    import lesmc.experiment.verify_replay as vr
    import lesmc.language.measures as measures
    import lesmc.model.kernel as kernel
    import lesmc.replay.on_frames as on_frames
    import lesmc.results.replay_measures as replay_measures
    from lesmc.experiment.cache import PACKAGE

    asked: list[tuple[str, ...]] = []
    monkeypatch.setattr(vr, "code_digest", lambda *p: asked.append(p) or "x")
    src = SimpleNamespace(net_files=(None, None, None), frames=SimpleNamespace(paths=[]))
    assert vr._replay_key({"runs": [], "perception": {}}, src, []) is not None  # type: ignore[arg-type]
    assert len(asked) == 1
    for mod in (measures, kernel, on_frames, replay_measures):
        top = Path(str(mod.__file__)).resolve().relative_to(PACKAGE.resolve()).parts[0]
        assert top in asked[0], mod.__name__
