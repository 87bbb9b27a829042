"""The batched joint design against an oracle written from the paper (tests/joint_oracle.py).

The oracle enumerates every attacked run of the joint tracker one path at a
time (filterpy filters, the greedy likelihood scan, the attacker's
nearest-first options); the model lesmc unfolds must hold exactly those paths,
with the same primary estimates (to 1e-6) and the same total combined payoff
(Eq. 5). The batched parts (chunks, track tables, digests) are checked against
the design itself run other ways.
"""

from __future__ import annotations

import sys
from pathlib import Path

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st
from joint_oracle import oracle_paths

import lesmc.unfold.unfold as unfold
from lesmc.model.arrays import ArrayModel
from lesmc.scene import Detection, Frame, JointConfig, Scene, Target, TrackerConfig, load_scene
from lesmc.tracking.joint import JointDesign
from lesmc.tracking.parts.joint_states import JointStates, JointStore, TrackTable, digest
from lesmc.tracking.trackers import make_tracker

ROOT = Path(__file__).resolve().parents[1]
SCENES = ROOT / "tests" / "scenes"
NAMES = ["rq1_platoon", "rq1_oncoming", "rq2_parallel", "rq2_stop", "rq4_merge"]


def assert_same_models(ours: ArrayModel, ref: ArrayModel) -> None:
    assert ours.n_states == ref.n_states and ours.n_transitions == ref.n_transitions
    for name in ("step", "halted", "ptr", "dst", "rank", "obs", "original", "cov"):
        assert np.array_equal(getattr(ours, name), getattr(ref, name)), name
    assert np.array_equal(ours.payoff, ref.payoff)
    np.testing.assert_allclose(ours.S, ref.S, rtol=0, atol=1e-9)
    np.testing.assert_allclose(ours.P_table, ref.P_table, rtol=0, atol=1e-9)
    assert ours.obs_names == ref.obs_names and ours.meta == ref.meta


def test_dense_scene_equals_the_oracle() -> None:
    sys.path.insert(0, str(ROOT / "benchmarks"))
    from bench_unfold import dense_scene

    scene = dense_scene(40, 20, seed=1, design="joint")
    cm = unfold.build_model(scene, (4, 5), 8)
    assert _canonical(model_paths(cm)) == _canonical(oracle_paths(scene, (4, 5), cm.end))


# ------------------------------------------------------------ random small scenes


@st.composite
def scenes(draw: st.DrawFn) -> Scene:
    """A target among a few vehicles with clutter (some appearing late, some twins, some
    detections repeated): coarse positions make likelihood ties common, and states of one
    batch start and drop tracks at different steps."""
    frames = draw(st.integers(4, 8))
    grid = draw(st.sampled_from([1.0, 5.0, 20.0]))
    coord = st.integers(-12, 12).map(lambda v: 500 + v * grid)
    speed = st.integers(-3, 3).map(float)
    payoff = st.one_of(st.integers(1, 4).map(float), st.just(float("inf")))
    nveh = draw(st.integers(0, 8))
    seen = st.tuples(st.integers(0, frames), st.integers(0, frames)).map(sorted)
    vehicles = [
        (draw(coord), draw(coord), draw(speed), draw(speed), draw(payoff), *draw(seen))
        for _ in range(nveh)
    ]
    if vehicles and draw(st.booleans()):  # twins: identical tracks, so likelihoods tie
        vehicles.append(vehicles[draw(st.integers(0, len(vehicles) - 1))])
    tx, ty, tvx = draw(coord), draw(coord), draw(speed)
    out = []
    for k in range(frames):
        dets = []
        if draw(st.integers(0, 4)):  # the target, mostly seen
            dets.append((tx + tvx * k, ty, draw(payoff)))
        for x, y, vx, vy, p, first, last in vehicles:  # appearing and leaving: tracks start late
            if first <= k <= last and draw(st.integers(0, 5)):
                dets.append((x + vx * k, y + vy * k, p))
        for _ in range(draw(st.integers(0, 3))):  # clutter
            dets.append((draw(coord), draw(coord), draw(payoff)))
        if dets and draw(st.booleans()):  # a detection repeated at the same position
            x, y, _ = dets[draw(st.integers(0, len(dets) - 1))]
            dets.append((x, y, draw(payoff)))
        detections = tuple(Detection(f"{k}:{i}", x, y, p) for i, (x, y, p) in enumerate(dets))
        Hm = None
        if draw(st.integers(0, 3)) == 0:
            Hm = np.array([[1.0, 0.001, 2.0], [0.0, 1.0, -1.5], [0.0, 0.0, 1.0]])
        out.append(Frame(k, detections, Hm))
    tracker = TrackerConfig(
        design="joint",
        gate=draw(st.sampled_from([1.0, 2.0, 3.0, 6.0])),
        gate_type=draw(st.sampled_from(["mahalanobis", "euclidean"])),
        max_trace=draw(st.sampled_from([1e5, 3000.0, 2000.0])),
        joint=JointConfig(
            init_radius=draw(st.sampled_from([30.0, 150.0, 400.0])),
            init_distance=draw(st.sampled_from([10.0, 60.0, 200.0])),
            prune_radius=draw(st.sampled_from([20.0, 60.0, 200.0])),
        ),
        sigma_q=draw(st.sampled_from([1.0, 3.0])),
    )
    return Scene(1.0, tuple(out), Target(0, (tx, ty), (tvx, 0.0)), tracker)


def test_chunks_do_not_change_the_model(monkeypatch: pytest.MonkeyPatch) -> None:
    scene = load_scene(SCENES / "rq4_merge.json").with_tracker(design="joint")
    whole = unfold.build_model(scene, (4, 7))
    monkeypatch.setattr("lesmc.tracking.joint.CHUNK_CELLS", 1)
    assert_same_models(unfold.build_model(scene, (4, 7)), whole)


def _random_states(rng: np.random.Generator, n: int, T: int, K: int) -> JointStates:
    """n random joint states of up to T tracks and K pending detections (padding zeros)."""
    nt = rng.integers(1, T + 1, n)
    npd = rng.integers(0, K + 1, n)
    tracks = np.where((np.arange(T) < nt[:, None])[..., None], rng.normal(size=(n, T, 4)), 0.0)
    tcov = np.where(np.arange(T) < nt[:, None], rng.integers(0, 5, (n, T)), 0)
    pending = np.where((np.arange(K) < npd[:, None])[..., None], rng.normal(size=(n, K, 2)), 0.0)
    return JointStates(tracks, tcov, nt, pending, npd)


def _table_backed(js: JointStates) -> JointStates:
    """The same states with their tracks as ids into a table (one row per slot, an unused
    row, a row of zeros for padding), as the design makes them."""
    n, T = js.tcov.shape
    live = np.arange(T) < js.ntrack[:, None]
    X = np.concatenate([js.tracks.reshape(-1, 4), np.ones((1, 4)), np.zeros((1, 4))])
    cov = np.concatenate([js.tcov.reshape(-1), [7, 0]])
    tid = np.where(live, np.arange(n * T).reshape(n, T), n * T + 1)
    return JointStates(
        None, None, js.ntrack, js.pending, js.npend, tid=tid, table=TrackTable(X, cov, n * T + 1)
    )


def test_store_round_trip_and_digest_ignores_padding() -> None:
    rng = np.random.default_rng(3)
    n = 9
    js = _random_states(rng, n, 4, 3)
    tracks, tcov, nt, pending, npd = js.tracks, js.tcov, js.ntrack, js.pending, js.npend
    wider = JointStates(
        np.concatenate([tracks, np.zeros((n, 2, 4))], axis=1),
        np.concatenate([tcov, np.zeros((n, 2), dtype=np.int64)], axis=1),
        nt,
        np.concatenate([pending, np.zeros((n, 1, 2))], axis=1),
        npd,
    )
    assert np.array_equal(digest(js), digest(wider))
    assert len({tuple(r) for r in digest(js).tolist()}) == n
    store = JointStore()
    store.extend(js.take(np.arange(4)))
    store.extend(wider.take(np.arange(4, n)))
    back = store.take(np.arange(n)[::-1])
    flip = js.take(np.arange(n)[::-1])
    for a, b in ((back.tracks, flip.tracks), (back.tcov, flip.tcov), (back.pending, flip.pending)):
        assert np.array_equal(a[:, : b.shape[1]], b)
    assert np.array_equal(
        digest(JointStates(back.tracks, back.tcov, back.ntrack, back.pending, back.npend)),
        digest(flip),
    )
    # a changed word (here a pending position, and a covariance index) changes the digest
    other = JointStates(tracks, tcov.copy(), nt, pending.copy(), npd)
    other.tcov[0, 0] += 1
    assert not np.array_equal(digest(other)[0], digest(js)[0])


def test_comparing_states_pads_tracks_of_any_dimension() -> None:
    """A constant-acceleration tracker's states (d = 6) compared across batches of different
    widths: the padding has the states' own dimension (it was fixed at 4, the CV model's;
    found by the fault tests' joint ca2d cases)."""
    from lesmc.tracking.parts.joint_states import same_as

    rng = np.random.default_rng(5)
    d = 6
    tracks = rng.normal(size=(3, 1, d))
    narrow = JointStates(tracks, np.zeros((3, 1), np.int64), np.ones(3, np.int64),
                         np.zeros((3, 0, 2)), np.zeros(3, np.int64))  # fmt: skip
    wide = JointStates(np.concatenate([tracks, np.zeros((3, 2, d))], axis=1),
                       np.zeros((3, 3), np.int64), np.ones(3, np.int64), np.zeros((3, 1, 2)),
                       np.zeros(3, np.int64))  # fmt: skip
    assert same_as(narrow, wide, np.arange(3))
    assert not same_as(narrow, wide, np.array([1, 0, 2]))
    store = JointStore()
    store.extend(wide)
    assert store.take(np.zeros(0, np.int64)).tracks.shape == (0, 1, d)


@pytest.mark.parametrize("by_table", [False, True])
def test_store_gathers_small_batches(monkeypatch: pytest.MonkeyPatch, by_table: bool) -> None:
    """Many tiny batches (a search expanding a few states at a time) and big ones: every
    state reads back as it was added, in any order, whatever parts the store made (also
    for states whose tracks are ids into a table, which the store cuts and joins)."""
    monkeypatch.setattr("lesmc.tracking.parts.joint_states.STORE_GATHER", 5)
    rng = np.random.default_rng(7)
    n = 60
    js = _random_states(rng, n, 4, 3)
    stored = _table_backed(js) if by_table else js
    store = JointStore()
    lo = 0
    for size in [1, 1, 2, 0, 1, 7, 1, 1, 1, 1, 1, 1, 3, 9, 2, 2, 1, 25]:
        store.extend(stored.take(np.arange(lo, lo + size)))
        lo += size
    assert lo == n
    assert len(store._parts) < 18  # some were gathered
    for idx in (np.arange(n), rng.permutation(n), rng.integers(0, n, 40), np.array([3])):
        back, want = store.take(idx), js.take(idx)
        for a, b in (
            (back.tracks, want.tracks),
            (back.tcov, want.tcov),
            (back.pending, want.pending),
        ):
            assert np.array_equal(a[:, : b.shape[1]], b)
            assert not a[:, b.shape[1] :].any()
        assert np.array_equal(back.ntrack, want.ntrack)
        assert np.array_equal(back.npend, want.npend)
        assert np.array_equal(digest(back), digest(want))


def test_make_design_names_the_batched_design() -> None:
    scene = load_scene(SCENES / "rq4_merge.json").with_tracker(design="joint")
    assert isinstance(make_tracker(scene), JointDesign)


def test_track_started_in_a_state_narrower_than_its_batch(monkeypatch: pytest.MonkeyPatch) -> None:
    """Found by hypothesis: a state with fewer tracks than its batch's widest starts one (it
    must get P0, not what the padding slot would have held)."""
    inf = float("inf")
    Hm = np.array([[1.0, 0.001, 2.0], [0.0, 1.0, -1.5], [0.0, 0.0, 1.0]])
    rows = [
        [],
        [(501, 492, 1.0), (500, 500, inf)],
        [(502, 492, inf), (500, 500, inf)],
        [(503, 492, inf), (500, 503, inf)],
        [],
        [(505, 492, inf)],
        [(500, 500, inf)],
    ]
    frames = tuple(
        Frame(k, tuple(Detection(f"{k}:{i}", x, y, p) for i, (x, y, p) in enumerate(r)), Hm)
        for k, r in enumerate(rows)
    )
    tracker = TrackerConfig(
        design="joint",
        sigma_q=1.0,
        gate=1.0,
        joint=JointConfig(init_radius=30.0, init_distance=10.0, prune_radius=20.0),
    )
    scene = Scene(1.0, frames, Target(0, (500.0, 492.0), (1.0, 0.0)), tracker)
    ours = unfold.build_model(scene, (1, 1))
    assert _canonical(model_paths(ours)) == _canonical(oracle_paths(scene, (1, 1), ours.end))
    assert ours.obs[-1] == 7  # the primary takes detection 6:0 on the attacked branch


# ------------------------------------------------ the oracle written from the paper


def model_paths(cm: ArrayModel) -> list[tuple[tuple[tuple[float, ...], ...], bool, float]]:
    """Every root-to-leaf path of the model: the estimates, halted, and the sum of the
    combined payoffs (Eq. 5: the own payoffs of the strictly lower-ranked siblings)."""
    out = []
    todo = [(0, (), 0.0)]
    while todo:
        q, xs, cost = todo.pop()
        xs = (*xs, tuple(cm.S[q]))
        lo, hi = int(cm.ptr[q]), int(cm.ptr[q + 1])
        if lo == hi:
            out.append((xs, bool(cm.halted[q]), cost))
        for t in range(lo, hi):
            combined = sum(float(cm.payoff[s]) for s in range(lo, hi) if cm.rank[s] < cm.rank[t])
            todo.append((int(cm.dst[t]), xs, cost + combined))
    return out


def _canonical(paths: list, digits: int = 6) -> list:
    return sorted(
        (tuple(tuple(round(v, digits) for v in x) for x in xs), h, round(c, digits))
        for xs, h, c in paths
    )


@pytest.mark.parametrize("name", NAMES)
def test_scenes_equal_the_oracle_written_from_the_paper(name: str) -> None:
    """Every attacked run of the joint tracker (tests/joint_oracle.py: filterpy filters,
    greedy association by likelihood, the attacker's nearest-first options) is a path of
    the model with the same estimates and the same total combined payoff, and no other."""
    scene = load_scene(SCENES / f"{name}.json").with_tracker(design="joint")
    for window in ((4, 6), (8, 9)):
        cm = unfold.build_model(scene, window)
        ours = _canonical(model_paths(cm))
        assert len(ours) > 1
        assert ours == _canonical(oracle_paths(scene, window, cm.end))


@settings(max_examples=150, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(scene=scenes(), data=st.data())
def test_random_scenes_equal_the_oracle_written_from_the_paper(
    scene: Scene, data: st.DataObject
) -> None:
    """Late vehicles, twins (likelihoods that tie), repeated detections, camera motion,
    unhideable detections, halting tracks: the model's paths are the oracle's."""
    e = unfold.original_end(scene, make_tracker(scene))
    if e < 1:
        return
    l = data.draw(st.integers(1, e))
    u = data.draw(st.integers(l, e))
    cm = unfold.build_model(scene, (l, u))
    assert _canonical(model_paths(cm)) == _canonical(oracle_paths(scene, (l, u), cm.end))
