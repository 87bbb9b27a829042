"""Benchmark: the networks' scoring with and without recording unit maxima (issue 31).

    python benchmarks/bench_maxima.py [--frames 8] [--repeat 5]

Renders the first frames of the default video, runs the front end once, then scores
every frame's candidate windows with N_dr (and N_lp on the crowded ones' windows, as
the detector does) twice, alternately, best of ``--repeat``: plainly, and while
``UnitMaxima.recording()`` folds every hidden ReLU's output into the maxima (what
neuron faults need, and what perception did on every run before it became opt-in).
Both give the same probabilities (checked). Figures: docs/performance.md.
"""

from __future__ import annotations

import argparse
import time

import numpy as np

from lesmc.perception.cnn import DR_SIZE, LP_SIZE, load_nets
from lesmc.perception.detector import Detector, dr_probability, lp_maps
from lesmc.perception.neurons import UnitMaxima
from lesmc.perception.windows import cut, stack
from lesmc.video.synth import SynthConfig, frames


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--frames", type=int, default=8)
    ap.add_argument("--repeat", type=int, default=5)
    args = ap.parse_args()
    nets = load_nets()
    det = Detector(nets)
    dr_windows, lp_windows = [], []
    for img, _ in list(frames(SynthConfig(frames=args.frames))):
        out = det.frontend.push(img)
        if out is None:
            continue
        stacked = stack(out.frame, out.aligned.frames, nets.settings.m)
        dr_windows.append(cut(stacked, out.candidates.centroid, DR_SIZE))
        # N_lp's windows: a tenth of the candidates, about the share the detector sends
        lp_windows.append(cut(stacked, out.candidates.centroid[::10], LP_SIZE))
    maxima = UnitMaxima(nets)

    def score() -> list[np.ndarray]:
        return [dr_probability(nets, w) for w in dr_windows] + [
            lp_maps(nets, w) for w in lp_windows
        ]

    plain = recorded = float("inf")
    for _ in range(args.repeat):
        t0 = time.perf_counter()
        want = score()
        plain = min(plain, time.perf_counter() - t0)
        t0 = time.perf_counter()
        with maxima.recording():
            got = score()
        recorded = min(recorded, time.perf_counter() - t0)
        assert all(np.array_equal(a, b) for a, b in zip(want, got, strict=True))
    n = sum(len(w) for w in dr_windows)
    print(f"{len(dr_windows)} frames, {n} N_dr windows, {sum(map(len, lp_windows))} N_lp")
    print(f"plain     {plain:.3f} s")
    print(f"recording {recorded:.3f} s ({recorded / plain:.2f}x)")


if __name__ == "__main__":
    main()
