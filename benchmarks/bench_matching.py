"""Benchmark: registration's feature matching, faiss against OpenCV's brute force (issue 31).

    python benchmarks/bench_matching.py [--frames 8] [--repeat 3]

Renders the first frames of the default video, describes each (ORB, 6,000 features a
2048x2048 frame) and matches every consecutive pair with Lowe's ratio test,
alternately, best of ``--repeat``:

- the reference: OpenCV's ``BFMatcher(NORM_HAMMING).knnMatch(k=2)`` (what registration
  used before), on OpenCV's default threads and on one;
- lesmc: ``registration._ratio_bf`` (faiss's exact binary index, one thread).

Prints the seconds per pair of each and whether the matches are the same pairs.
Figures: docs/performance.md.
"""

from __future__ import annotations

import argparse
import itertools
import time

import cv2
import numpy as np

from lesmc.perception.registration import RegistrationConfig, _ratio_bf, describe
from lesmc.video.synth import SynthConfig, frames


def opencv(a: np.ndarray, b: np.ndarray, ratio: float) -> set[tuple[int, int]]:
    pairs = cv2.BFMatcher(cv2.NORM_HAMMING).knnMatch(a, b, k=2)
    return {
        (p[0].queryIdx, p[0].trainIdx)
        for p in pairs
        if len(p) == 2 and p[0].distance < ratio * p[1].distance
    }


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--frames", type=int, default=8)
    ap.add_argument("--repeat", type=int, default=3)
    args = ap.parse_args()
    cfg = RegistrationConfig()
    feats = [describe(img, cfg).descriptors for img, _ in frames(SynthConfig(frames=args.frames))]
    pairs = list(itertools.pairwise(feats))
    threads = cv2.getNumThreads()
    best = {"opencv": np.inf, "opencv, 1 thread": np.inf, "lesmc": np.inf}
    same = True
    for _ in range(args.repeat):
        for name in best:
            cv2.setNumThreads(1 if name == "opencv, 1 thread" else threads)
            t0 = time.perf_counter()
            if name == "lesmc":
                got = [_ratio_bf(a, b, cfg.ratio) for a, b in pairs]
            else:
                want = [opencv(a, b, cfg.ratio) for a, b in pairs]
            best[name] = min(best[name], (time.perf_counter() - t0) / len(pairs))
        cv2.setNumThreads(threads)
        same &= all(
            set(zip(q.tolist(), t.tolist(), strict=True)) == w
            for (q, t), w in zip(got, want, strict=True)
        )
    n = np.mean([len(f) for f in feats])
    print(f"{len(pairs)} frame pairs, {n:.0f} features a frame; OpenCV threads {threads}")
    for name, sec in best.items():
        print(f"{name:17s} {sec * 1e3:7.1f} ms a pair ({best['opencv'] / sec:.2f}x OpenCV's)")
    print(f"the same matches: {same}")


if __name__ == "__main__":
    main()
