"""Experiment: CROWN rows of a convolution grouped by position, against one row per neuron.

    python benchmarks/exp_crown_grouped.py [--n 32] [--frames 30]

lesmc/perception/certify.py can propagate, per unstable conv neuron, its lower and
upper rows (+W and -W) side by side, gathering the neuron's patch of relaxation lines
for them (``_crown_conv``, what conv2 gets), or by position: every channel of a
(window, position) that has an unstable neuron at once, 2 x C_out rows sharing one
gather of the lines, stable channels included (``_crown_conv_at``, what
``layer_bounds`` does from ``GROUPED_FROM`` on). This times both on the same balls (bench_certify's
sample of attacked N_dr windows at their first radius), layer by layer, alternately,
with chunks of 1/8 to 1 times ``CHUNK_FLOATS``, and checks that the bounds agree.
Figures: docs/performance.md, fifteenth round.
"""

from __future__ import annotations

import argparse
import math
import sys
import time
from pathlib import Path

import torch

sys.path.insert(0, str(Path(__file__).resolve().parent))

from bench_certify import sample_windows

import lesmc.perception.certify as C
from lesmc.perception import crown
from lesmc.perception.attack_settings import AttackConfig, threshold_logit
from lesmc.perception.attacks import payoffs
from lesmc.perception.cnn import load_nets


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--n", type=int, default=32)
    ap.add_argument("--frames", type=int, default=30)
    args = ap.parse_args()
    nets = load_nets()
    w = sample_windows(nets, args.frames, args.n)
    pay = payoffs(nets.dr, w, nets.settings.delta_dr, AttackConfig()).payoff
    chain = C.detect_chain(nets.dr, threshold_logit(nets.settings.delta_dr))
    z0 = C.centred(chain, torch.from_numpy(w).float())
    r = C._start(chain, z0, pay, C.CertifyConfig())[0]
    ball = C.Ball(z0, r.float(), C._dim(chain), chain.subtract_mean)
    bounds, relaxes = C.layer_bounds(chain, ball)
    for i in range(1, len(chain.layers) - 1):
        layer = chain.layers[i]
        if not isinstance(layer, C.Conv):
            continue
        lo, hi = crown._interval_step(layer, *bounds[i - 1])
        unstable = ((lo < 0) & (hi > 0)).flatten(1)
        todo = unstable.nonzero()
        views = crown._conv_views(chain, i, relaxes, ball)
        cells, cout = layer.out_hw, layer.weight.shape[0]
        places = unstable.view(len(unstable), cout, cells * cells).any(1).nonzero()
        for mult in (0.125, 0.25, 0.5, 1.0, 1.0, 0.5, 0.25, 0.125):
            step = max(1, crown.CHUNK_FLOATS // (2 * crown._row_floats(chain, i)))
            t0 = time.perf_counter()
            rows = [
                crown._crown_conv(
                    chain, i, views, ball, todo[s : s + step, 0], todo[s : s + step, 1]
                )
                for s in range(0, len(todo), step)
            ]
            t1 = time.perf_counter()
            gstep = max(
                1, int(mult * crown.CHUNK_FLOATS) // (2 * cout * crown._row_floats(chain, i))
            )
            low = torch.full((len(unstable), cout, cells * cells), -math.inf)
            up = torch.full_like(low, math.inf)
            for s in range(0, len(places), gstep):
                win, pos = places[s : s + gstep, 0], places[s : s + gstep, 1]
                gl, gu = crown._crown_conv_at(chain, i, views, ball, win, pos)
                low[win, :, pos], up[win, :, pos] = gl.T, gu.T
            t2 = time.perf_counter()
            ch, p = todo[:, 1] // cells**2, todo[:, 1] % cells**2
            d_lo = (low[todo[:, 0], ch, p] - torch.cat([x[0] for x in rows])).abs().max()
            d_up = (up[todo[:, 0], ch, p] - torch.cat([x[1] for x in rows])).abs().max()
            print(f"layer {i}: {len(todo)} unstable rows ({len(todo) / unstable.numel():.0%}), "
                  f"{len(places)} positions; chunk x{mult}: per neuron {t1 - t0:.2f} s, "
                  f"grouped {t2 - t1:.2f} s; bounds differ by {max(d_lo, d_up):.1e}")  # fmt: skip
    return 0


if __name__ == "__main__":
    sys.exit(main())
