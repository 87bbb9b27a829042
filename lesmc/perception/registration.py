"""Feature-based image registration: ORB features, Hamming matching, RANSAC homography.

Paper section 6.2: ``h_k^{k-1}`` maps frame k-1's pixels to frame k's. Each frame
is described once; its features are kept to register the next frame (Eq. 15
then chains the homographies, see ``background``).
"""

from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np
from scipy.spatial import cKDTree


@dataclass(frozen=True)
class RegistrationConfig:
    """ORB and RANSAC settings."""

    features: int = 6000  #: ORB keypoints per 2048x2048 pixels (scaled with the frame area)
    max_features: int = 40000
    ratio: float = 0.8  #: Lowe's ratio test on the two nearest descriptors
    ransac_px: float = 2.0  #: RANSAC inlier threshold, pixels
    min_inliers: int = 12
    guided_above: int = 12000  #: features per frame above which matching is guided
    guided_subset: int = 4000  #: features used for the coarse homography
    guided_px: float = 12.0  #: search radius around each predicted position
    max_hamming: int = 64  #: a lone candidate in the radius must be at least this close
    lk_window: int = 11  #: Lucas-Kanade window for the subpixel refinement
    refine_px: float = 0.3  #: inlier threshold after refinement, pixels


class RegistrationError(RuntimeError):
    """Two frames could not be registered (too few consistent matches)."""


@dataclass
class Features:
    """Keypoint positions (n, 2) and their ORB descriptors (n, 32)."""

    points: np.ndarray
    descriptors: np.ndarray


@dataclass(frozen=True)
class Registration:
    """A homography and how well it is supported."""

    homography: np.ndarray  # 3x3, previous frame -> this frame
    matches: int
    inliers: int
    rms_px: float  # reprojection error over the inliers


def describe(image: np.ndarray, cfg: RegistrationConfig) -> Features:
    """ORB keypoints and descriptors of a uint8 grey image."""
    area = image.shape[0] * image.shape[1] / 2048**2
    n = int(min(max(cfg.features * area, 500), cfg.max_features))
    orb = cv2.ORB.create(nfeatures=n, scaleFactor=1.3, nlevels=4, fastThreshold=10)
    kps, desc = orb.detectAndCompute(image, None)
    if desc is None:
        return Features(np.zeros((0, 2), np.float32), np.zeros((0, 32), np.uint8))
    return Features(np.array([k.pt for k in kps], np.float32), desc)


def register(
    prev: Features,
    cur: Features,
    cfg: RegistrationConfig,
    prev_image: np.ndarray | None = None,
    cur_image: np.ndarray | None = None,
) -> Registration:
    """The homography taking ``prev``'s pixels to ``cur``'s.

    Matches with the ratio test, RANSAC, and, when the images are given,
    subpixel refinement of the inliers (``_refine``).
    """
    if len(prev.points) < cfg.min_inliers or len(cur.points) < cfg.min_inliers:
        raise RegistrationError(f"too few features ({len(prev.points)}, {len(cur.points)})")
    qi, ti = _matches(prev, cur, cfg)
    if len(qi) < cfg.min_inliers:
        raise RegistrationError(f"only {len(qi)} feature matches")
    src, dst = prev.points[qi], cur.points[ti]
    h, mask = cv2.findHomography(
        src, dst, cv2.RANSAC, cfg.ransac_px, maxIters=4000, confidence=0.999
    )
    if h is None:
        raise RegistrationError("RANSAC found no homography")
    inl = mask.ravel().astype(bool)
    if inl.sum() < cfg.min_inliers:
        raise RegistrationError(f"only {int(inl.sum())} RANSAC inliers")
    h = h / h[2, 2]
    if prev_image is not None and cur_image is not None:
        src, dst, h = _refine(prev_image, cur_image, src[inl], h, cfg)
        inl = np.ones(len(src), bool)
    proj = cv2.perspectiveTransform(src[inl][None], h)[0]
    rms = float(np.sqrt(np.mean(np.sum((proj - dst[inl]) ** 2, axis=1))))
    return Registration(h, len(qi), int(inl.sum()), rms)


def _ratio_bf(a: np.ndarray, b: np.ndarray, ratio: float) -> tuple[np.ndarray, np.ndarray]:
    """Brute-force Hamming 2-NN with Lowe's ratio test: (query rows, train rows).

    faiss's exact binary index (one thread: registration runs beside the CNNs) finds
    each query's two smallest distances. A query passes when d1 < ratio * d2, so its
    nearest train row is then unique and the matches do not depend on how ties are
    broken: they are those of OpenCV's ``BFMatcher.knnMatch`` (tests/test_perception.py),
    in about a fifth of its CPU time (docs/performance.md, "Issue 31, ninth round").
    """
    import faiss

    if len(a) == 0 or len(b) < 2:
        empty = np.zeros(0, int)
        return empty, empty
    # faiss and torch share the OpenMP runtime: the calling thread's count is restored
    before = faiss.omp_get_max_threads()
    faiss.omp_set_num_threads(1)
    try:
        index = faiss.IndexBinaryFlat(8 * a.shape[1])
        index.add(np.ascontiguousarray(b, np.uint8))
        dist, nearest = index.search(np.ascontiguousarray(a, np.uint8), 2)
    finally:
        faiss.omp_set_num_threads(before)
    keep = dist[:, 0] < ratio * dist[:, 1]
    return np.flatnonzero(keep).astype(int), nearest[keep, 0].astype(int)


def _matches(
    prev: Features, cur: Features, cfg: RegistrationConfig
) -> tuple[np.ndarray, np.ndarray]:
    """Ratio-test matches: brute force, or guided by a coarse homography for large sets.

    Brute force costs n² descriptor comparisons (4 s for 40000 features); above
    ``guided_above`` features a homography from an evenly thinned subset predicts
    where each feature lands, and only features within ``guided_px`` of the
    prediction are compared.
    """
    if max(len(prev.points), len(cur.points)) <= cfg.guided_above:
        return _ratio_bf(prev.descriptors, cur.descriptors, cfg.ratio)
    k = cfg.guided_subset
    sp = np.linspace(0, len(prev.points) - 1, min(k, len(prev.points))).astype(int)
    sc = np.linspace(0, len(cur.points) - 1, min(k, len(cur.points))).astype(int)
    q, t = _ratio_bf(prev.descriptors[sp], cur.descriptors[sc], cfg.ratio)
    coarse = None
    if len(q) >= cfg.min_inliers:
        coarse, _ = cv2.findHomography(
            prev.points[sp[q]],
            cur.points[sc[t]],
            cv2.RANSAC,
            cfg.ransac_px,
            maxIters=4000,
            confidence=0.999,
        )
    if coarse is None:  # too few coarse matches: pay for brute force
        return _ratio_bf(prev.descriptors, cur.descriptors, cfg.ratio)
    pred = cv2.perspectiveTransform(prev.points[None].astype(np.float64), coarse)[0]
    near = cKDTree(cur.points).query_ball_point(pred, cfg.guided_px)
    qi = np.repeat(np.arange(len(near)), [len(n) for n in near])
    if len(qi) == 0:
        return qi, qi
    ti = np.fromiter((j for n in near for j in n), int, count=len(qi))
    dist = _POPCOUNT[np.bitwise_xor(prev.descriptors[qi], cur.descriptors[ti])].sum(axis=1)
    order = np.lexsort((dist, qi))
    qi, ti, dist = qi[order], ti[order], dist[order]
    first = np.flatnonzero(np.r_[True, qi[1:] != qi[:-1]])  # each feature's best candidate
    nxt = np.minimum(first + 1, len(qi) - 1)
    has_second = (first + 1 < len(qi)) & (qi[nxt] == qi[first])
    second = np.where(has_second, dist[nxt], cfg.max_hamming / cfg.ratio)
    keep = dist[first] < cfg.ratio * second
    return qi[first][keep], ti[first][keep]


_POPCOUNT = (
    np.unpackbits(np.arange(256, dtype=np.uint8)[:, None], axis=1).sum(axis=1).astype(np.int32)
)


def _refine(
    prev_image: np.ndarray,
    cur_image: np.ndarray,
    src: np.ndarray,
    h: np.ndarray,
    cfg: RegistrationConfig,
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Subpixel refinement: Lucas-Kanade from the RANSAC prediction, then a tight refit.

    ORB keypoints sit on a pixel grid (about 1 px of error), enough for RANSAC
    but not for subtracting high-contrast edges; pyramidal LK started at
    ``h(src)`` moves each match to a subpixel optimum.
    """
    guess = cv2.perspectiveTransform(src[None], h)[0].astype(np.float32)
    dst, status, _ = cv2.calcOpticalFlowPyrLK(
        prev_image,
        cur_image,
        src.astype(np.float32),
        guess.copy(),
        winSize=(cfg.lk_window, cfg.lk_window),
        maxLevel=1,
        flags=cv2.OPTFLOW_USE_INITIAL_FLOW,
        criteria=(cv2.TERM_CRITERIA_COUNT | cv2.TERM_CRITERIA_EPS, 30, 0.005),
    )
    ok = status.ravel().astype(bool) & (np.linalg.norm(dst - guess, axis=1) < 2 * cfg.ransac_px)
    if ok.sum() < cfg.min_inliers:
        return src, guess, h
    s, d = src[ok], dst[ok]
    h2, mask = cv2.findHomography(s, d, cv2.RANSAC, cfg.refine_px, maxIters=2000, confidence=0.999)
    if h2 is None or mask.sum() < cfg.min_inliers:
        return src, guess, h
    keep = mask.ravel().astype(bool)
    h3, _ = cv2.findHomography(s[keep], d[keep], 0)  # least squares on the inliers
    h_best = h3 if h3 is not None else h2
    return s[keep], d[keep], h_best / h_best[2, 2]
