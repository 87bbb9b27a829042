"""The tracker against independent computations: textbook KF equations and filterpy."""

from __future__ import annotations

import json
import math
from pathlib import Path

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from kf_reference import reference_filter
from oracle import every_path

from lesmc.common.errors import InputError
from lesmc.model.lts import to_lts
from lesmc.scene import Detection, Frame, Scene, load_scene, scene_from_dict, scene_to_dict
from lesmc.scene.toy import Vehicle, vehicle_scene
from lesmc.tracking.association import gate_radii
from lesmc.tracking.kalman import innovations, matrices, predict_covariances, white_noise_q
from lesmc.tracking.monitor import track
from lesmc.tracking.parts.attacker import attack_options
from lesmc.tracking.trackers import make_tracker
from lesmc.unfold.unfold import build_model

SCENES = Path(__file__).parent / "scenes"


def textbook_track(scene: Scene, choose=None):  # type: ignore[no-untyped-def]
    """Eq. 1-3 and 16-19 written out: NCV model, nearest neighbour, Mahalanobis gate."""
    cfg, dt = scene.tracker, scene.dt
    F = np.array([[1, 0, dt, 0], [0, 1, 0, dt], [0, 0, 1, 0], [0, 0, 0, 1]], float)
    q = cfg.sigma_q**2
    Q = q * np.array(
        [
            [dt**3 / 3, 0, dt**2 / 2, 0],
            [0, dt**3 / 3, 0, dt**2 / 2],
            [dt**2 / 2, 0, dt, 0],
            [0, dt**2 / 2, 0, dt],
        ]
    )
    H = np.array([[1, 0, 0, 0], [0, 1, 0, 0]], float)
    R = cfg.sigma_r**2 * np.eye(2)
    x = np.array([*scene.target.start, 0.0, 0.0])
    P = np.diag(np.square(cfg.P0_sd))
    out = [x.copy()]
    for k in range(scene.target.step + 1, scene.last_step + 1):
        Hm = scene.frame(k - 1).to_next
        if Hm is not None:
            p = Hm @ np.array([x[0], x[1], 1.0])
            x[:2] = p[:2] / p[2]
        x, P = F @ x, F @ P @ F.T + Q
        S = H @ P @ H.T + R
        Z = scene.frame(k).positions()
        z = None
        if choose is not None:
            z = choose(k, scene.frame(k))
        elif len(Z):
            j = int(np.argmin(np.linalg.norm(Z - x[:2], axis=1)))
            y = Z[j] - x[:2]
            if math.sqrt(y @ np.linalg.inv(S) @ y) <= cfg.gate:
                z = Z[j]
        if z is not None:
            K = P @ H.T @ np.linalg.inv(S)
            x = x + K @ (z - H @ x)
            P = (np.eye(4) - K @ H) @ P
        out.append(x.copy())
    return out


def with_camera_motion(scene: Scene) -> Scene:
    """The same scene seen by a moving camera: each frame shifted and slightly rotated."""
    from dataclasses import replace

    a = 0.01
    Hm = np.array([[math.cos(a), -math.sin(a), 3.0], [math.sin(a), math.cos(a), -2.0], [0, 0, 1]])
    frames, M = [], np.eye(3)
    for fr in scene.frames:
        pts = fr.positions()
        hom = np.c_[pts, np.ones(len(pts))] @ M.T
        moved = hom[:, :2] / hom[:, 2:]
        dets = tuple(
            replace(d, x=float(p[0]), y=float(p[1]))
            for d, p in zip(fr.detections, moved, strict=True)
        )
        frames.append(Frame(fr.step, dets, Hm))
        M = Hm @ M
    return replace(scene, frames=tuple(frames))


@pytest.mark.parametrize("name", ["rq1_platoon", "rq4_merge", "rq2_stop"])
@pytest.mark.parametrize("camera", [False, True], ids=["static", "moving camera"])
def test_unattacked_track_equals_textbook_kalman_filter(name: str, camera: bool) -> None:
    scene = load_scene(SCENES / f"{name}.json")
    if camera:
        scene = with_camera_motion(scene)
    ours = [p.x for p in track(make_tracker(scene))]
    theirs = textbook_track(scene)
    assert len(ours) == len(theirs)
    np.testing.assert_allclose(np.array(ours), np.array(theirs), rtol=1e-9, atol=1e-9)


def test_every_attacked_path_equals_filterpy_replaying_its_observations() -> None:
    """Each path of a built model, replayed with filterpy's KalmanFilter."""
    scene = load_scene(SCENES / "rq1_platoon.json")
    model = to_lts(build_model(scene, (6, 8)))
    m = matrices(scene.tracker, scene.dt)
    ids = {d.id: (d.x, d.y) for fr in scene.frames for d in fr.detections}

    count = 0
    for path in every_path(model):
        kf = reference_filter(m, np.array([*scene.target.start, 0, 0]))
        for t in path:
            kf.predict()
            if t.obs is not None:
                kf.update(np.array(ids[t.obs]))
            st = model.state(t.dst)
            np.testing.assert_allclose(kf.x.ravel(), st.s, rtol=1e-9, atol=1e-9)
            np.testing.assert_allclose(kf.P, st.P, rtol=1e-9, atol=1e-9)
        count += 1
    assert count > 10


@pytest.mark.parametrize("dt", [0.8, 1 / 1.25, 0.1, 1.0, 2.5, 1e-3, 37.0])
@pytest.mark.parametrize("sigma_q", [0.0, 0.5, 1.0, 3.0, 12.3])
def test_q_is_bit_for_bit_filterpy(dt: float, sigma_q: float) -> None:
    """Eq. 17 written out equals filterpy's Q_continuous_white_noise exactly."""
    from filterpy.common import Q_continuous_white_noise

    theirs = Q_continuous_white_noise(
        dim=2, dt=dt, spectral_density=sigma_q**2, block_size=2, order_by_dim=False
    )
    ours = white_noise_q(dt, sigma_q**2)
    assert np.array_equal(ours, theirs)
    assert ours.dtype == theirs.dtype and ours.tobytes() == theirs.tobytes()


def test_attack_options_combined_payoff_is_the_cost_of_hiding_every_nearer_detection() -> None:
    dist = np.array([5.0, 1.0, 3.0, 9.0, 7.0])
    gated = np.array([True, True, False, True, False])
    pay = np.array([1.0, 2.0, 4.0, 8.0, 16.0])
    opts = attack_options(dist, gated, pay)
    # by distance: d1 (g, 2), d2 (not gated -> skip, 4), d0 (g, 1), d4 (not gated, 16), d3 (g, 8)
    assert [o.detection for o in opts] == [1, None, 0, 3]
    combined = np.cumsum([0.0] + [o.payoff for o in opts])[:-1]
    # to take d0 hide d1 and d2; to take d3 hide d1, d2, d0 and d4
    assert list(combined) == [0.0, 2.0, 6.0, 23.0]


def test_unattackable_detection_ends_the_options() -> None:
    opts = attack_options(
        np.array([1.0, 2.0, 3.0]), np.array([True, True, True]), np.array([1.0, math.inf, 1.0])
    )
    assert [o.detection for o in opts] == [0, 1]  # nothing beyond the unattackable one


def test_skipping_updates_raises_the_monitor_alarm() -> None:
    t = Vehicle("t", 0, 0, 10, 0, 1.0, last=9)  # vanishes after frame 9
    scene = vehicle_scene([t], 14, t)
    points = track(make_tracker(scene))
    assert [p.alarm for p in points][:10] == [False] * 10
    assert all(p.alarm for p in points[10:])
    assert all(points[k].tau > points[k - 1].tau for k in range(10, 14))


def test_dense_frames_keep_branching_small() -> None:
    rng = np.random.default_rng(0)
    t = Vehicle("t", 500, 500, 10, 0, 3.0)
    others = [
        Vehicle(f"v{i}", float(x), float(y), float(vx), float(vy), 1.0 + i % 5)
        for i, (x, y, vx, vy) in enumerate(
            zip(
                rng.uniform(0, 1000, 400),
                rng.uniform(0, 1000, 400),
                rng.uniform(-10, 10, 400),
                rng.uniform(-10, 10, 400),
                strict=True,
            )
        )
    ]
    scene = vehicle_scene([t, *others], 20, t)
    model = to_lts(build_model(scene, (6, 9)))
    assert max(len(model.out(q)) for q in model.graph.nodes) <= 10
    assert model.graph.number_of_nodes() < 5000


BAD = [
    (
        lambda d: d["frames"][1]["detections"][0].pop("payoff"),
        "frame 1, detection '1:t': payoff is missing",
    ),
    (
        lambda d: d["frames"][1]["detections"][0].update(x="NaN"),
        "frame 1, detection '1:t': x must be a number within ±1e+07, got 'NaN'",
    ),
    (lambda d: d["tracker"].update(design="triple"), 'tracker: design must be "single" or "joint"'),
    (lambda d: d["frames"].pop(3), "frame 4: steps must be consecutive: follows frame 2"),
    (
        lambda d: d["frames"][2]["detections"].append(dict(d["frames"][2]["detections"][0])),
        "frame 2, detection '2:t': duplicate detection id",
    ),
    (
        lambda d: d["frames"][0].update(to_next=[[1, 0, 0], [0, 1, 0], [0, 0, 0]]),
        "frame 0: to_next must be an invertible 3x3",
    ),
    (lambda d: d["target"].update(step=99), "target: step 99 is not among the frames 0..19"),
    (
        lambda d: d["frames"][1]["detections"][0].update(payoff=-1),
        "frame 1, detection '1:t': payoff must be a number in [0, 1e+12]",
    ),
    (
        lambda d: d["tracker"].update(sigma_q=0),
        "tracker: sigma_q must be a number in (0, 1e+06], got 0",
    ),
    (lambda d: d.update(dt=0), "dt: must be a number of seconds in (0, 3600], got 0"),
]


@pytest.mark.parametrize(("mutate", "message"), BAD, ids=[b[1][:40] for b in BAD])
def test_bad_scenes_are_reported_by_frame_and_detection(mutate, message: str) -> None:  # type: ignore[no-untyped-def]
    doc = scene_to_dict(load_scene(SCENES / "rq2_parallel.json"))
    mutate(doc)
    with pytest.raises(InputError) as exc:
        scene_from_dict(doc, "s.json")
    assert f"s.json: {message}" in exc.value.render(), exc.value.render()


def test_nan_in_scene_file_is_refused(tmp_path: Path) -> None:
    p = tmp_path / "s.json"
    p.write_text(
        json.dumps(scene_to_dict(load_scene(SCENES / "rq2_parallel.json"))).replace("3.0", "NaN", 1)
    )
    with pytest.raises(InputError) as exc:
        load_scene(p)
    assert "NaN is not allowed" in exc.value.render()


def test_scene_round_trip(tmp_path: Path) -> None:
    from lesmc.scene import save_scene

    s = with_camera_motion(load_scene(SCENES / "rq4_merge.json"))
    save_scene(s, tmp_path / "s.json")
    assert scene_to_dict(load_scene(tmp_path / "s.json")) == scene_to_dict(s)


@settings(max_examples=60, deadline=None)
@given(
    st.integers(1, 60),
    st.integers(1, 12),
    st.floats(0.5, 40.0),
    st.integers(0, 2**32 - 1),
)
def test_nearest_equals_a_full_scan(m: int, k: int, radius: float, seed: int) -> None:
    """Frame.nearest's x-band scan gives the k nearest within the radius, ties to the
    lower index, exactly as sorting every (distance, index) pair does."""
    rng = np.random.default_rng(seed)
    grid = rng.integers(0, 12, size=(m, 2)).astype(float) * 3.0  # many equal distances
    dets = tuple(Detection(f"d{i}", float(x), float(y), 1.0) for i, (x, y) in enumerate(grid))
    frame = Frame(0, dets)
    points = np.r_[grid[: min(m, 5)], rng.integers(0, 36, size=(30, 2)).astype(float)]
    got = frame.nearest(points, k, radius)
    for p, row in zip(points, got, strict=True):
        d = [math.hypot(x - p[0], y - p[1]) for x, y in grid]
        want = sorted((di, i) for i, di in enumerate(d) if di <= radius)[:k]
        assert [i for i in row if i >= 0] == [i for _, i in want]


@settings(max_examples=40, deadline=None)
@given(st.integers(0, 2**32 - 1), st.sampled_from(["mahalanobis", "euclidean"]))
def test_batched_gain_equals_the_textbook_and_does_not_depend_on_the_batch(
    seed: int, gate_type: str
) -> None:
    """innovations/gate_radii over a stack: each entry equals the same matrix done alone
    (bit for bit) and the textbook Eq. 3 with numpy's inverse and eigvalsh (to 1e-9)."""
    rng = np.random.default_rng(seed)
    m = matrices(load_scene(SCENES / "rq4_merge.json").tracker, 1.0)
    A = rng.normal(size=(int(rng.integers(6, 300)), 4, 4))
    P = np.einsum("nij,nkj->nik", A, A) + 0.1 * np.eye(4)
    P_pred = predict_covariances(m, P)
    inn = innovations(m, P_pred)
    radii = gate_radii(inn.S, P_pred[:, 0, 0] + P_pred[:, 1, 1], 3.0, gate_type)
    cut = np.sort(rng.choice(np.arange(1, len(P)), size=3, replace=False))
    chunks = [innovations(m, predict_covariances(m, c)) for c in np.split(P, cut)]
    for field in ("S", "S_inv", "K", "P_post"):  # the same bits in any chunks
        got = np.concatenate([getattr(c, field) for c in chunks])
        assert got.tobytes() == getattr(inn, field).tobytes()
    for i in range(6):
        Pp_one = predict_covariances(m, P[i : i + 1])
        assert Pp_one[0].tobytes() == P_pred[i].tobytes()
        one = innovations(m, Pp_one)
        assert one.P_post[0].tobytes() == inn.P_post[i].tobytes()
        assert one.K[0].tobytes() == inn.K[i].tobytes()
        Pp = m.F @ P[i] @ m.F.T + m.Q
        S = m.H @ Pp @ m.H.T + m.R
        K = Pp @ m.H.T @ np.linalg.inv(S)
        P_post = (np.eye(4) - K @ m.H) @ Pp  # the simple form: equal to Joseph's in exact math
        assert np.allclose(P_pred[i], Pp, rtol=1e-9, atol=1e-9)
        assert np.allclose(inn.K[i], K, rtol=1e-9, atol=1e-9)
        assert np.allclose(inn.P_post[i], P_post, rtol=1e-7, atol=1e-7)
        if gate_type == "mahalanobis":
            want = 3.0 * math.sqrt(max(np.linalg.eigvalsh(S)))
        else:
            want = 3.0 * math.sqrt(Pp[0, 0] + Pp[1, 1])
        assert want <= radii[i] <= want * (1 + 1e-9)
