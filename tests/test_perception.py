"""The classical front end: registration, median background, subtraction, quality scoring."""

from __future__ import annotations

import itertools
from collections.abc import Iterator
from pathlib import Path

import cv2
import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from hypothesis.extra.numpy import arrays

from lesmc.perception.background import median
from lesmc.perception.frontend import FrontEnd, FrontEndConfig, FrontEndOutput
from lesmc.perception.quality import match, score
from lesmc.perception.registration import RegistrationConfig, describe, register


def texture(size: int, seed: int) -> np.ndarray:
    """A static scene with detail at several scales (what registration needs)."""
    rng = np.random.default_rng(seed)
    img = np.zeros((size, size), np.float32)
    for cells, amp in ((8, 50.0), (32, 30.0), (128, 20.0)):
        low = rng.normal(0, amp, (cells, cells)).astype(np.float32)
        img += cv2.resize(low, (size, size), interpolation=cv2.INTER_CUBIC)
    img = cv2.GaussianBlur(img + 128, (0, 0), 0.8)
    return img.clip(0, 255).astype(np.uint8)


def known_homography(size: int) -> np.ndarray:
    c = size / 2
    ang = np.deg2rad(1.5)
    rot = np.array([[np.cos(ang), -np.sin(ang), 0], [np.sin(ang), np.cos(ang), 0], [0, 0, 1]])
    move = np.array([[1.01, 0, c + 7.3], [0, 1.01, c - 4.6], [2e-6, -1e-6, 1]])
    return move @ rot @ np.array([[1, 0, -c], [0, 1, -c], [0, 0, 1]])


def warped_pair(size: int, seed: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """A textured image, the same seen through ``known_homography``, and that homography."""
    a = texture(size, seed)
    h = known_homography(size)
    b = cv2.warpPerspective(
        a, h, (size, size), flags=cv2.INTER_CUBIC, borderMode=cv2.BORDER_REFLECT
    )
    return a, b, h


def mapping_error(h_est: np.ndarray, h_true: np.ndarray, size: int) -> float:
    """Largest distance between where the two homographies send an inner grid of points."""
    g = np.stack(
        np.meshgrid(np.linspace(size * 0.1, size * 0.9, 9), np.linspace(size * 0.1, size * 0.9, 9)),
        -1,
    ).reshape(1, -1, 2)
    a = cv2.perspectiveTransform(g, h_est)[0]
    b = cv2.perspectiveTransform(g, h_true)[0]
    return float(np.linalg.norm(a - b, axis=1).max())


def test_registration_recovers_a_known_homography_to_subpixel_accuracy() -> None:
    size = 768
    a, b, h = warped_pair(size, 3)
    cfg = RegistrationConfig()
    reg = register(describe(a, cfg), describe(b, cfg), cfg, a, b)
    assert mapping_error(reg.homography, h, size) < 0.1
    assert reg.inliers > 100


def _opencv_ratio_matches(a: np.ndarray, b: np.ndarray, ratio: float) -> set[tuple[int, int]]:
    """The oracle: OpenCV's brute-force 2-NN and Lowe's ratio test (what registration
    used before faiss)."""
    pairs = cv2.BFMatcher(cv2.NORM_HAMMING).knnMatch(a, b, k=2)
    return {
        (p[0].queryIdx, p[0].trainIdx)
        for p in pairs
        if len(p) == 2 and p[0].distance < ratio * p[1].distance
    }


@settings(max_examples=60, deadline=None)
@given(
    st.integers(0, 2**31),
    st.integers(0, 60),
    st.integers(0, 60),
    st.sampled_from([0.5, 0.8, 1.0]),
)
def test_ratio_matches_are_opencvs(seed: int, n_a: int, n_b: int, ratio: float) -> None:
    """Exact 2-NN by faiss: the same matches as OpenCV's, ties and repeated rows included
    (descriptors drawn from a few patterns so that equal distances are common)."""
    from lesmc.perception.registration import _ratio_bf

    rng = np.random.default_rng(seed)
    patterns = rng.integers(0, 256, (5, 32), dtype=np.uint8)
    flips = rng.random((n_a + n_b, 32)) < 0.05
    noise = rng.integers(0, 256, (n_a + n_b, 32), dtype=np.uint8)
    rows = np.where(flips, noise, patterns[rng.integers(0, 5, n_a + n_b)])
    a, b = rows[:n_a], rows[n_a:]
    q, t = _ratio_bf(a, b, ratio)
    assert set(zip(q.tolist(), t.tolist(), strict=True)) == (
        _opencv_ratio_matches(a, b, ratio) if n_a and n_b else set()
    )
    assert list(q) == sorted(q)  # in query order, as OpenCV's


def test_ratio_matches_of_real_orb_features_are_opencvs() -> None:
    import torch

    from lesmc.perception.registration import _ratio_bf

    a, b, _ = warped_pair(768, 5)
    cfg = RegistrationConfig()
    fa, fb = describe(a, cfg), describe(b, cfg)
    threads = torch.get_num_threads()
    torch.set_num_threads(2)
    try:
        q, t = _ratio_bf(fa.descriptors, fb.descriptors, cfg.ratio)
        # faiss runs on one thread of the OpenMP runtime it shares with torch, and
        # leaves torch's count as it was (certification after it needs both cores)
        assert torch.get_num_threads() == 2
    finally:
        torch.set_num_threads(threads)
    want = _opencv_ratio_matches(fa.descriptors, fb.descriptors, cfg.ratio)
    assert len(want) > 500
    assert set(zip(q.tolist(), t.tolist(), strict=True)) == want


def test_guided_matching_agrees_with_brute_force() -> None:
    """Large feature sets are matched near a coarse homography's prediction: same answer."""
    size = 768
    a, b, h = warped_pair(size, 5)
    brute = RegistrationConfig()
    guided = RegistrationConfig(guided_above=500, guided_subset=300)
    fa, fb = describe(a, brute), describe(b, brute)
    assert len(fa.points) > 500  # the guided path is taken
    r_g = register(fa, fb, guided, a, b)
    r_b = register(fa, fb, brute, a, b)
    assert mapping_error(r_g.homography, h, size) < 0.1
    assert r_g.inliers >= 0.8 * r_b.inliers


def test_registration_without_refinement_is_only_pixel_accurate() -> None:
    """The subpixel step matters: without images, the ORB-only estimate is coarser."""
    size = 768
    a, b, h = warped_pair(size, 4)
    cfg = RegistrationConfig()
    coarse = register(describe(a, cfg), describe(b, cfg), cfg)
    fine = register(describe(a, cfg), describe(b, cfg), cfg, a, b)
    assert mapping_error(fine.homography, h, size) < mapping_error(coarse.homography, h, size)
    assert mapping_error(coarse.homography, h, size) < 2.0


@settings(max_examples=60, deadline=None)
@given(
    st.integers(1, 7).flatmap(lambda n: st.lists(arrays(np.uint8, (3, 4)), min_size=n, max_size=n))
)
def test_median_network_equals_numpy_median(frames: list[np.ndarray]) -> None:
    got = median(frames)
    want = np.median(np.stack(frames).astype(float), axis=0)
    # even counts: mean of the middle two, rounded half up
    assert np.array_equal(got, np.floor(want + 0.5).astype(np.uint8))


def _video(n: int, size: int, blob_path: list[tuple[float, float]], shift: tuple[float, float]):
    """A static textured scene seen by a translating camera, with a dark 5x5 blob driving."""
    world = texture(size + 64, 11)
    for k in range(n):
        dx, dy = 32 + shift[0] * k, 32 + shift[1] * k
        m = np.array([[1, 0, -dx], [0, 1, -dy]], np.float64)
        img = cv2.warpAffine(world, m, (size, size), flags=cv2.INTER_CUBIC)
        x, y = blob_path[k]
        xi, yi = round(x), round(y)
        img[yi - 2 : yi + 3, xi - 2 : xi + 3] = 20
        yield img


def test_median_background_removes_static_content_and_a_moving_blob_is_found() -> None:
    size, n = 320, 7
    path = [(60.0 + 12 * k, 150.0 + 3 * k) for k in range(n)]
    fe = FrontEnd(FrontEndConfig(history=4))
    outs = [
        o for o in (fe.push(img) for img in _video(n, size, path, (1.7, -0.9))) if o is not None
    ]
    assert [o.index for o in outs] == [4, 5, 6]
    for o in outs:
        valid = o.aligned.valid > 0
        # static texture is gone: away from the blob the difference is tiny
        diff = cv2.absdiff(o.frame, o.background).astype(float)
        x, y = path[o.index]
        far = valid.copy()
        far[int(y) - 8 : int(y) + 9, int(x) - 8 : int(x) + 9] = False
        assert np.percentile(diff[far], 99.5) < 6
        # exactly one candidate, at the blob
        assert len(o.candidates) == 1
        assert np.allclose(o.candidates.centroid[0], (x, y), atol=0.5)


def test_a_stopped_blob_vanishes_into_the_background() -> None:
    size, n = 256, 7
    # fixed on the ground (whole-pixel camera steps, so drawing it does not jitter)
    path = [(100.0 - 1.0 * k, 100.0 - 2.0 * k) for k in range(n)]
    fe = FrontEnd(FrontEndConfig(history=4))
    outs = [o for o in (fe.push(img) for img in _video(n, size, path, (1.0, 2.0))) if o is not None]
    assert all(len(o.candidates) == 0 for o in outs)


def brute_force_matching(det: np.ndarray, truth: np.ndarray, radius: float) -> tuple[int, float]:
    """(most pairs within radius, least total distance among those): by enumeration."""
    best = (0, 0.0)
    n, m = len(det), len(truth)
    for k in range(min(n, m), 0, -1):
        for ds in itertools.combinations(range(n), k):
            for ts in itertools.permutations(range(m), k):
                d = [np.linalg.norm(det[i] - truth[j]) for i, j in zip(ds, ts, strict=True)]
                if max(d) <= radius and (k > best[0] or sum(d) < best[1]):
                    best = (k, sum(d)) if k > best[0] or sum(d) < best[1] else best
        if best[0] == k:
            return best
    return best


@settings(max_examples=80, deadline=None)
@given(
    arrays(np.float64, st.tuples(st.integers(0, 4), st.just(2)), elements=st.floats(0, 10)),
    arrays(np.float64, st.tuples(st.integers(0, 4), st.just(2)), elements=st.floats(0, 10)),
)
def test_matching_is_maximal_and_optimal(det: np.ndarray, truth: np.ndarray) -> None:
    pairs = match(det, truth, 3.0)
    assert len({i for i, _, _ in pairs}) == len(pairs) == len({j for _, j, _ in pairs})
    k, total = brute_force_matching(det, truth, 3.0)
    assert len(pairs) == k
    assert sum(d for _, _, d in pairs) == pytest.approx(total, abs=1e-9)


def test_score_counts_dont_care_vehicles_as_neither_hit_nor_false_alarm() -> None:
    truth = np.array([[0.0, 0.0], [10.0, 0.0], [20.0, 0.0]])
    care = np.array([True, False, True])
    det = np.array([[0.5, 0.0], [10.2, 0.0], [40.0, 0.0]])
    s = score(det, truth, care, 2.0)
    assert (s.tp, s.fp, s.fn, s.ignored) == (1, 1, 1, 1)
    assert s.precision == 0.5 and s.recall == 0.5
    assert s.error == pytest.approx(0.5)


def _moving_video(n: int) -> list[np.ndarray]:
    base = texture(384, 11)
    video = []
    for k in range(n):  # the camera moves a few pixels a frame; a blob moves across
        shift = np.array([[1, 0, 2.5 * k], [0, 1, -1.5 * k]], np.float32)
        img = cv2.warpAffine(base, shift, (384, 384), borderMode=cv2.BORDER_REFLECT)
        cv2.circle(img, (60 + 25 * k, 200), 4, 255, -1)
        video.append(img)
    return video


def _same_outputs(got: list[FrontEndOutput | None], want: list[FrontEndOutput | None]) -> None:
    """Two front ends' outputs, frame by frame: the same bits."""
    from dataclasses import fields

    for a, b in zip(got, want, strict=True):
        assert (a is None) == (b is None)
        if a is None or b is None:
            continue
        assert np.array_equal(a.background, b.background)
        for f in fields(a.candidates):
            assert np.array_equal(getattr(a.candidates, f.name), getattr(b.candidates, f.name))
        assert np.array_equal(a.registration.homography, b.registration.homography)


def test_known_registrations_give_the_front_end_of_a_full_pass() -> None:
    """A front end given an earlier pass's registrations (what the replay of lesmc verify
    does) neither describes nor matches those frames, and its outputs are the same bits."""
    import lesmc.perception.frontend as fe_module

    video = _moving_video(7)
    cfg = FrontEndConfig(history=3)
    full = FrontEnd(cfg)
    want = [full.push(f) for f in video]
    described = []
    real = fe_module.describe

    def counting(img: np.ndarray, c: RegistrationConfig) -> object:
        described.append(1)
        return real(img, c)

    fe_module.describe = counting  # type: ignore[assignment]
    try:
        again = FrontEnd(cfg, known={k: full.registrations[k] for k in range(1, 5)})
        got = [again.push(f) for f in video]
    finally:
        fe_module.describe = real
    assert len(described) == 3  # frames 4 (its previous one) and 5, 6: the unknown ones
    _same_outputs(got, want)


def test_frames_registered_ahead_give_the_front_end_of_a_plain_pass() -> None:
    """Registration one frame ahead on a second thread (perception's loop) hands the
    front end the registrations it would have made itself: the same bits."""
    from lesmc.perception.frontend import registered_ahead

    video = _moving_video(7)
    cfg = FrontEndConfig(history=3)
    plain = FrontEnd(cfg)
    want = [plain.push(f) for f in video]
    ahead = FrontEnd(cfg)
    pairs = list(registered_ahead(video, cfg.registration))
    assert [img is f for (img, _), f in zip(pairs, video, strict=True)] == [True] * 7
    assert pairs[0][1] is None
    got = [ahead.push(img, reg) for img, reg in pairs]
    for k in range(1, 7):
        a, b = ahead.registrations[k], plain.registrations[k]
        assert np.array_equal(a.homography, b.homography) and a.inliers == b.inliers
    _same_outputs(got, want)


def test_a_frame_that_cannot_be_registered_fails_in_its_turn_and_closing_stops_reading() -> None:
    from lesmc.perception.frontend import registered_ahead
    from lesmc.perception.registration import RegistrationError

    video = _moving_video(6)
    video[3] = np.full_like(video[3], 128)  # no features: frame 3 cannot be registered
    read: list[int] = []

    def frames() -> Iterator[np.ndarray]:
        for k, img in enumerate(video):
            read.append(k)
            yield img

    ahead = registered_ahead(frames(), RegistrationConfig())
    got = [next(ahead) for _ in range(3)]  # frames 0-2 arrive before frame 3's error
    assert [img is video[k] for k, (img, _) in enumerate(got)] == [True] * 3
    with pytest.raises(RegistrationError):
        next(ahead)
    assert read == [0, 1, 2, 3]

    read.clear()
    ahead = registered_ahead(frames(), RegistrationConfig())
    next(ahead)
    ahead.close()  # the caller stops (an error, Ctrl-C): at most one frame read ahead
    assert read in ([0], [0, 1])


def test_perceive_names_the_frame_that_cannot_be_registered(tmp_path: Path) -> None:
    """Through the real entry point: the frame registered ahead on the second thread
    fails as FILE: what is wrong, exit 2, no traceback, nothing written."""
    from cli_run import lesmc

    video = _moving_video(7)
    video[5] = np.full_like(video[5], 128)
    for k, img in enumerate(video):
        assert cv2.imwrite(str(tmp_path / f"frame_{k:05d}.png"), img)
    r = lesmc("perceive", str(tmp_path), "-o", str(tmp_path / "scene.json"), timeout=300)
    assert r.returncode == 2 and "Traceback" not in r.stderr, r.stderr
    assert f"{tmp_path / 'frame_00005.png'}: cannot register with the previous frame" in r.stderr
    assert not (tmp_path / "scene.json").exists()


@settings(max_examples=40, deadline=None)
@given(st.integers(0, 2**31), st.sampled_from([np.uint8, np.float32, np.float64]))
def test_windows_are_the_frames_pixels_with_the_edge_repeated(seed: int, dtype: type) -> None:
    """cut(): each window, inside the frame or past its edge, pixel by pixel (an oracle
    that reads one pixel at a time, clamping the coordinates)."""
    from lesmc.perception.windows import cut

    rng = np.random.default_rng(seed)
    h, w, size = int(rng.integers(5, 40)), int(rng.integers(5, 40)), int(rng.choice([3, 5, 21]))
    frames = [(rng.random((h, w)) * 255).astype(dtype) for _ in range(2)]
    centres = rng.uniform(-size, [w + size, h + size], (int(rng.integers(0, 12)), 2))
    got = cut(frames, centres, size)
    assert got.shape == (len(centres), 2, size, size) and got.dtype == np.float32
    for i, (x, y) in enumerate(np.rint(centres).astype(int)):
        for c, f in enumerate(frames):
            for r in range(size):
                for q in range(size):
                    yy = min(max(y - size // 2 + r, 0), h - 1)
                    xx = min(max(x - size // 2 + q, 0), w - 1)
                    assert got[i, c, r, q] == np.float32(f[yy, xx]) * np.float32(1 / 255)
