"""A detector file's heatmap network on a whole frame: detecting, pricing, certifying
(issue 60; docs/performance.md, "Issue 60").

    python benchmarks/bench_heatmap.py [--detections 20] [--attack deepfool|pgd|both]
        [--whole-frame] [--no-certify]

A random four-layer fully convolutional network (16 channels, stride 4, receptive
field 17 x 17 pixels) exported to ONNX and read through a detector file; one
768 x 576 grey frame of blurred noise, the threshold set so that the frame has
exactly ``--detections`` detections. Side by side in one run: the detector alone
(one forward pass of the whole frame), pricing every detection (the attack on each
detection's crop, each perturbation decoded on the whole frame), and certifying
every detection (CROWN on the peak cell's crop). ``--whole-frame`` also prices
with the network run on the whole frame at each step (the first round's way).
Targets (2 cores): under 0.5 s per payoff and under 2 s per certificate.
"""

from __future__ import annotations

import argparse
import tempfile
import time
import warnings
from pathlib import Path

import numpy as np
import torch
from torch import nn

from lesmc.perception.attack_settings import AttackConfig
from lesmc.perception.detector_file import load_detector
from lesmc.perception.heatmap import decode, peaks
from lesmc.perception.heatmap_attack import price_frame, pricing, raw_threshold

H, W = 576, 768


def _network() -> nn.Module:
    torch.manual_seed(60)
    return nn.Sequential(
        nn.Conv2d(1, 16, 5, padding=2), nn.ReLU(),
        nn.Conv2d(16, 16, 3, stride=2, padding=1), nn.ReLU(),
        nn.Conv2d(16, 16, 3, stride=2, padding=1), nn.ReLU(),
        nn.Conv2d(16, 1, 1),
    ).eval()  # fmt: skip


def _frame() -> np.ndarray:
    import cv2

    rng = np.random.default_rng(60)
    img = cv2.GaussianBlur(rng.integers(0, 256, (H, W)).astype(np.uint8), (7, 7), 2.0)
    return (img.astype(np.float32) / 255.0)[None, None]


def _setup(d: Path, n: int) -> tuple[object, np.ndarray]:
    """The detector (threshold leaving ``n`` detections on the frame) and the frame."""
    net, frame = _network(), _frame()
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        torch.onnx.export(
            net, (torch.rand(2, 1, H, W),), d / "bench.onnx", dynamo=True, external_data=False,
            dynamic_shapes=({0: torch.export.Dim("batch")},),
        )  # fmt: skip
    with torch.no_grad():
        raw = net(torch.from_numpy(frame))[0, 0].double().numpy()
    cells = peaks(raw, -np.inf, 2)
    tops = np.sort(raw[cells[:, 0], cells[:, 1]])[::-1]
    thr = float((tops[n - 1] + tops[n]) / 2)
    (d / "bench.toml").write_text(
        f'kind = "heatmap"\nnetwork = "bench.onnx"\nstride = 4\nthreshold = {thr!r}\n'
        'score = "raw"\nnms_radius = 2\n'
    )
    return load_detector(d / "bench.toml"), frame


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--detections", type=int, default=20)
    ap.add_argument("--attack", choices=["deepfool", "pgd", "both"], default="both")
    ap.add_argument("--whole-frame", action="store_true")
    ap.add_argument("--no-certify", action="store_true")
    args = ap.parse_args()
    print(f"torch threads: {torch.get_num_threads()}")
    with tempfile.TemporaryDirectory() as tmp:
        det, frame = _setup(Path(tmp), args.detections)
        x = torch.from_numpy(frame)
        t0 = time.perf_counter()
        reps = 5
        for _ in range(reps):
            with torch.no_grad():
                y = det.net.module(x)  # type: ignore[attr-defined]
        alone = (time.perf_counter() - t0) / reps
        fd = decode(y.reshape(det.cells).double().numpy(), det, 0)  # type: ignore[attr-defined]
        n = len(fd.cells)
        print(f"frame {W}x{H}, {n} detections; detector alone {alone * 1000:.0f} ms")
        methods = ["deepfool", "pgd"] if args.attack == "both" else [args.attack]
        pays = None
        for method in methods:
            how = pricing(det, AttackConfig(method=method))  # type: ignore[arg-type]
            ways = [("crop", how)]
            if args.whole_frame:
                ways.append(("whole frame", type(how)(how.det, how.cfg, None, how.field)))
            for where, p in ways:
                t0 = time.perf_counter()
                got = price_frame(p, frame, fd)
                dt = time.perf_counter() - t0
                ok = int(np.isfinite(got).sum())
                print(
                    f"{method:8s} on the {where:11s}: {dt:7.2f} s for {n} ({dt / n:.3f} s "
                    f"per detection, {dt / n / alone:.1f}x the detector alone), {ok} hidden, "
                    f"median payoff {np.median(got[np.isfinite(got)]):.4f}"
                )
                if method == "deepfool" and where == "crop":
                    pays = got
        if not args.no_certify:
            from lesmc.perception.heatmap_certify import certify_frame

            t0 = time.perf_counter()
            lower = certify_frame(det, frame, fd, pays, raw_threshold(det))  # type: ignore[arg-type]
            dt = time.perf_counter() - t0
            ratio = "" if pays is None else f", median lower/payoff {np.median(lower / pays):.3f}"
            print(
                f"certify  on the crop       : {dt:7.2f} s for {n} ({dt / n:.3f} s per "
                f"detection, {dt / n / alone:.1f}x the detector alone){ratio}"
            )


if __name__ == "__main__":
    main()
