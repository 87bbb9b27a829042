"""Benchmark: the networks' scoring with and without recording unit maxima (issue 31).

    python benchmarks/bench_maxima.py [--frames 8] [--repeat 5]

Renders the first frames of the default video and runs the detector once, keeping the
windows it hands to N_dr (every candidate) and to N_lp (the crowded blobs), then
scores them all twice, alternately, best of ``--repeat``: plainly, and while
``UnitMaxima.recording()`` folds every hidden ReLU's output into the maxima (what
neuron faults need, and what perception did on every run before it became opt-in).
As in the detector, the plain scoring runs its batches side by side and the recording
one after the other (the hooks are not thread-safe; both on one torch thread a batch,
lesmc/perception/threads.py). Both give the same probabilities (checked). Figures:
docs/performance.md.
"""

from __future__ import annotations

import argparse
import time
from typing import Any

import numpy as np

from lesmc.perception import detector
from lesmc.perception.cnn import load_nets
from lesmc.perception.detector import Detector, dr_probability, lp_maps
from lesmc.perception.neurons import UnitMaxima
from lesmc.video.synth import SynthConfig, frames


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--frames", type=int, default=8)
    ap.add_argument("--repeat", type=int, default=5)
    args = ap.parse_args()
    nets = load_nets()
    dr_calls: list[tuple[np.ndarray, tuple[Any, ...]]] = []
    lp_calls: list[tuple[np.ndarray, tuple[Any, ...]]] = []

    def keep_dr(n: Any, windows: np.ndarray, *rest: Any) -> np.ndarray:
        dr_calls.append((windows, rest[:1]))  # the batch size
        return dr_probability(n, windows, *rest)

    def keep_lp(n: Any, windows: np.ndarray, *rest: Any) -> np.ndarray:
        lp_calls.append((windows, rest[:1]))
        return lp_maps(n, windows, *rest)

    # the detector's own calls, recorded: the windows a real run scores
    detector.dr_probability, detector.lp_maps = keep_dr, keep_lp  # type: ignore[assignment]
    det = Detector(nets)
    for img, _ in list(frames(SynthConfig(frames=args.frames))):
        det.push(img)
    detector.dr_probability, detector.lp_maps = dr_probability, lp_maps
    maxima = UnitMaxima(nets)

    def score(side_by_side: bool) -> list[np.ndarray]:  # the calls as the detector made them
        return [dr_probability(nets, w, *r, side_by_side=side_by_side) for w, r in dr_calls] + [
            lp_maps(nets, w, *r, side_by_side=side_by_side) for w, r in lp_calls
        ]

    plain = recorded = float("inf")
    for _ in range(args.repeat):
        t0 = time.perf_counter()
        want = score(True)
        plain = min(plain, time.perf_counter() - t0)
        t0 = time.perf_counter()
        with maxima.recording():
            got = score(False)
        recorded = min(recorded, time.perf_counter() - t0)
        assert all(np.array_equal(a, b) for a, b in zip(want, got, strict=True))
    n_dr, n_lp = (sum(len(w) for w, _ in calls) for calls in (dr_calls, lp_calls))
    print(f"{n_dr} N_dr windows, {n_lp} N_lp windows")
    print(f"plain     {plain:.3f} s")
    print(f"recording {recorded:.3f} s ({recorded / plain:.2f}x)")


if __name__ == "__main__":
    main()
