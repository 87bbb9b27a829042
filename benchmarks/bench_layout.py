"""N_dr with channels-last activations against the channels-first reference (issue 31).

    python benchmarks/bench_layout.py [--frames 8] [--repeat 3]

``DetectNet.forward`` hands its convolutions the windows with the channels last
(lesmc/perception/cnn.py). Side by side in one run, alternately, best of
``--repeat``, on the N_dr windows of the default video's first frames: the
shipped network (channels last) and a reference that runs the same layers on the
channels-first tensors (what the forward pass did before). Timed: P(vehicle) of
every candidate window (the detector's N_dr pass) and DeepFool payoffs of every
attacked blob (``perceive -o``, ``verify``). Prints seconds, ratios, and the
largest differences of the outputs (float32 rounding: the layouts sum in another
order). Figures: docs/performance.md.
"""

from __future__ import annotations

import argparse
import time
from dataclasses import replace

import numpy as np
import torch
from torch import nn

from lesmc.perception.attack_settings import AttackConfig
from lesmc.perception.attacks import payoffs
from lesmc.perception.cnn import DR_SIZE, Nets, load_nets
from lesmc.perception.detector import Detector, cut, dr_probability, stack
from lesmc.video.synth import SynthConfig, frames


class ChannelsFirst(nn.Module):
    """The shipped N_dr's layers on channels-first tensors: the reference."""

    def __init__(self, net: nn.Module) -> None:
        super().__init__()
        self.net = net

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        x = x - x.mean(dim=(1, 2, 3), keepdim=True)
        out: torch.Tensor = self.net.head(self.net.features(x))
        return out


def windows(nets: Nets, n_frames: int) -> tuple[np.ndarray, np.ndarray]:
    """Every candidate's N_dr window, and the attacked blobs' windows, of the first frames."""
    det = Detector(nets)
    cands, attacked = [], []
    for img, _ in list(frames(SynthConfig(frames=n_frames))):
        out = det.frontend.push(img)
        if out is None:
            continue
        fd = det.detect(out)
        attacked.append(fd.windows[np.unique(fd.source)])
        m = nets.settings.m
        cands.append(cut(stack(out.frame, out.aligned.frames, m), out.candidates.centroid, DR_SIZE))
    if not cands:
        raise SystemExit(f"no frame past the front end's history in {n_frames}: ask for more")
    return np.concatenate(cands), np.concatenate(attacked)


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--frames", type=int, default=8)
    ap.add_argument("--repeat", type=int, default=3)
    args = ap.parse_args()
    print(f"torch threads: {torch.get_num_threads()}")
    nets = load_nets()
    cand, att = windows(nets, args.frames)
    print(f"{len(cand)} candidate windows, {len(att)} attacked blobs")
    first = ChannelsFirst(nets.dr).eval()
    dr = nets.settings.delta_dr
    fwd: dict[str, list[float]] = {"first": [], "last": []}
    pay: dict[str, list[float]] = {"first": [], "last": []}
    outs: dict[str, tuple[np.ndarray, np.ndarray]] = {}
    for _ in range(args.repeat):
        for name, net in (("first", first), ("last", nets.dr)):
            probe = replace(nets, dr=net)
            t0 = time.perf_counter()
            p = dr_probability(probe, cand)
            t1 = time.perf_counter()
            res = payoffs(net, att, dr, AttackConfig())
            t2 = time.perf_counter()
            fwd[name].append(t1 - t0)
            pay[name].append(t2 - t1)
            outs[name] = (p, res.payoff)
    (p0, a0), (p1, a1) = outs["first"], outs["last"]
    ok = np.isfinite(a0) & np.isfinite(a1)
    for what, d in (("P(vehicle) of the candidates", fwd), ("DeepFool payoffs", pay)):
        f, la = min(d["first"]), min(d["last"])
        print(f"{what:30s} channels first {f:7.3f} s   last {la:7.3f} s   {f / la:.2f}x")
    print(
        f"largest difference: P(vehicle) {np.abs(p0 - p1).max():.2e}, payoff "
        f"{np.abs(a0[ok] - a1[ok]).max():.2e} (relative "
        f"{(np.abs(a0[ok] - a1[ok]) / a0[ok]).max():.2e}); accepted differently: "
        f"{int(((p0 > dr) != (p1 > dr)).sum())}; unattackable {int((~np.isfinite(a0)).sum())} "
        f"and {int((~np.isfinite(a1)).sum())}"
    )


if __name__ == "__main__":
    main()
