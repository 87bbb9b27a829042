"""Benchmark: the networks' batches side by side on one torch thread each (issue 31).

    python benchmarks/bench_lanes.py [--frames 10] [--repeat 3]

Renders the first frames of the default video and runs the detector once, keeping,
frame by frame, the windows it scores with N_dr (every candidate) and attacks with
DeepFool (the blobs that gave detections). Then, alternately, best of ``--repeat``:

- the reference: each frame's batches one after the other, torch on every free core
  (what perception did before ``in_lanes``), written out here;
- lesmc: ``dr_probability`` and ``payoffs`` as shipped (lesmc/perception/threads.py).

Prints the seconds of each, their ratio, and how many payoffs and probabilities
differ in any bit between the two (a batch on two threads may round otherwise than
on one). Figures: docs/performance.md.
"""

from __future__ import annotations

import argparse
import time

import numpy as np
import torch

from lesmc.perception.attack_settings import AttackConfig, threshold_logit
from lesmc.perception.attacks import deepfool, margin, payoffs
from lesmc.perception.cnn import DR_SIZE, Nets, load_nets
from lesmc.perception.detector import DR_BATCH, Detector, cut, dr_probability, stack
from lesmc.video.synth import SynthConfig, frames


def recorded(nets: Nets, n_frames: int) -> list[tuple[np.ndarray, np.ndarray]]:
    """Per frame the detector scored: (candidate windows, attacked windows)."""
    det = Detector(nets)
    out = []
    for img, _ in list(frames(SynthConfig(frames=n_frames))):  # rendered first
        res = det.push(img)
        if res is None:
            continue
        fo, fd = res
        m = nets.settings.m
        cand = cut(stack(fo.frame, fo.aligned.frames, m), fo.candidates.centroid, DR_SIZE)
        out.append((cand, fd.windows[np.unique(fd.source)]))
    return out


def reference(nets: Nets, cand: np.ndarray, att: np.ndarray, cfg: AttackConfig) -> tuple:
    """One frame's N_dr scores and DeepFool payoffs, batch after batch on torch's threads."""
    probs = []
    with torch.inference_mode():
        for a in range(0, len(cand), DR_BATCH):
            logits = nets.dr(torch.from_numpy(cand[a : a + DR_BATCH]))
            probs.append(torch.softmax(logits, dim=1)[:, 1].numpy())
    t = threshold_logit(nets.settings.delta_dr)
    pays = []
    for a in range(0, len(att), cfg.batch):
        x0 = torch.from_numpy(np.ascontiguousarray(att[a : a + cfg.batch]))
        x_adv, _ = deepfool(nets.dr, x0, t, cfg)
        with torch.no_grad():
            ok = (margin(nets.dr, x_adv, t) <= 0).numpy()
        d = (x_adv - x0).numpy().astype(np.float64).reshape(len(x0), -1)
        pays.append(np.where(ok, np.sqrt((d**2).sum(axis=1)), np.inf))
    return np.concatenate(probs), np.concatenate(pays) if pays else np.zeros(0)


def shipped(nets: Nets, cand: np.ndarray, att: np.ndarray, cfg: AttackConfig) -> tuple:
    return dr_probability(nets, cand), payoffs(nets.dr, att, nets.settings.delta_dr, cfg).payoff


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--frames", type=int, default=10)
    ap.add_argument("--repeat", type=int, default=3)
    args = ap.parse_args()
    nets = load_nets()  # fits torch's threads to the free cores
    cfg = AttackConfig()
    work = recorded(nets, args.frames)
    best = {"reference": float("inf"), "lesmc": float("inf")}
    answers = {}
    for _ in range(args.repeat):
        for name, fn in (("reference", reference), ("lesmc", shipped)):
            t0 = time.perf_counter()
            answers[name] = [fn(nets, c, a, cfg) for c, a in work]
            best[name] = min(best[name], time.perf_counter() - t0)
    n_cand = sum(len(c) for c, _ in work)
    n_att = sum(len(a) for _, a in work)
    diff_p = sum(
        int((r[0] != s[0]).sum())
        for r, s in zip(answers["reference"], answers["lesmc"], strict=True)
    )
    diff_pay = sum(
        int((r[1] != s[1]).sum())
        for r, s in zip(answers["reference"], answers["lesmc"], strict=True)
    )
    print(f"{len(work)} frames, {n_cand} N_dr windows, {n_att} attacked; torch threads "
          f"{torch.get_num_threads()}")  # fmt: skip
    print(f"reference (batches in turn) {best['reference']:.3f} s")
    print(f"lesmc (side by side)        {best['lesmc']:.3f} s "
          f"({best['reference'] / best['lesmc']:.2f}x)")  # fmt: skip
    print(f"bits differing: {diff_p} of {n_cand} probabilities, {diff_pay} of {n_att} payoffs")


if __name__ == "__main__":
    main()
