"""Whole-detector and payoff speed on the default synthetic video (docs/performance.md).

    python benchmarks/bench_detector.py [--frames 10] [--density 1.5]

Targets (2 cores): a 2048x2048 frame with about 300 vehicles through the whole
detector in <= 2 s; payoffs for 300 detections in <= 2 s.
"""

from __future__ import annotations

import argparse
import time

import numpy as np
import torch

from lesmc.perception.attack_settings import AttackConfig
from lesmc.perception.attacks import payoffs
from lesmc.perception.cnn import load_nets
from lesmc.perception.detector import Detector
from lesmc.video.synth import SynthConfig, frames


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--frames", type=int, default=10)
    ap.add_argument("--density", type=float, default=SynthConfig.density)
    args = ap.parse_args()
    print(f"torch threads: {torch.get_num_threads()}")
    nets = load_nets()
    det = Detector(nets)
    t_front, t_cnn, t_pay, n_veh, n_det, n_blob = [], [], [], [], [], []
    for method in ("deepfool", "pgd"):
        det = Detector(nets)
        # rendered first: frames() renders on a second thread, which would run beside the timing
        video = list(frames(SynthConfig(frames=args.frames, density=args.density)))
        for img, truth in video:
            t0 = time.perf_counter()
            out = det.frontend.push(img)
            t1 = time.perf_counter()
            if out is None:
                continue
            fd = det.detect(out)
            t2 = time.perf_counter()
            used = np.unique(fd.source)
            payoffs(nets.dr, fd.windows[used], nets.settings.delta_dr, AttackConfig(method=method))
            t3 = time.perf_counter()
            if method == "deepfool":
                t_front.append(t1 - t0)
                t_cnn.append(t2 - t1)
                n_veh.append(len(truth.vehicles))
                n_det.append(len(fd.positions))
                n_blob.append(len(used))
            t_pay.append((method, t3 - t2))
    print(
        f"vehicles in view: {np.mean(n_veh):.0f}, detections {np.mean(n_det):.0f}, "
        f"attacked blobs {np.mean(n_blob):.0f} per frame"
    )
    print(f"front end      {np.mean(t_front) * 1000:7.0f} ms/frame")
    print(f"CNNs           {np.mean(t_cnn) * 1000:7.0f} ms/frame")
    print(f"detector total {np.mean(np.add(t_front, t_cnn)) * 1000:7.0f} ms/frame")
    for m in ("deepfool", "pgd"):
        ts = [t for k, t in t_pay if k == m]
        print(
            f"payoffs {m:<8} {np.mean(ts) * 1000:7.0f} ms/frame "
            f"({np.mean(ts) / np.mean(n_blob) * 300 * 1000:.0f} ms per 300 detections)"
        )


if __name__ == "__main__":
    main()
