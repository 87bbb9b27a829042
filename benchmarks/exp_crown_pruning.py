"""Experiment: can CROWN skip the neurons that matter least to the margin? (issue 31)

Certified bounds (lesmc/perception/certify.py) spend most of their time on CROWN rows
for the unstable neurons of conv3 and conv4. This experiment asks whether a cheaper
interval bound would do for the neurons whose looseness matters least, judged with
hindsight: after a full CROWN propagation at each window's first radius, the margin's
own coefficients on the layer (its influence, lambda) are known; the layer's
interval-unstable neurons are ranked by |lambda| times their interval width, CROWN is
kept for the top fraction only, the deeper layers are bounded again, and the margin's
r*(R) is compared with R. With hindsight this is the best such a rule can do, so if it
loses the certificates, a rule that must guess lambda first loses them too.

Run ``python benchmarks/exp_crown_pruning.py [--n 30] [--fractions 1,0.6,0.4,0.25]``
(the sample is every tenth of bench_certify.py's windows). Figures: docs/performance.md.
"""

from __future__ import annotations

import argparse
import contextlib
import io
import sys
from pathlib import Path

import numpy as np
import torch

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))
sys.path.insert(0, str(Path(__file__).resolve().parent))

from bench_certify import sample_windows

from lesmc.perception import certify as C
from lesmc.perception import crown, relaxations
from lesmc.perception.attack_settings import AttackConfig, threshold_logit
from lesmc.perception.attacks import payoffs
from lesmc.perception.cnn import load_nets


def influence(chain: C.Chain, relaxes: list[C.Relax], layer: int, nb: int) -> torch.Tensor:
    """The margin's coefficients on the post-activations of ``layer`` (channels last)."""
    last = len(chain.layers) - 1
    out = chain.layers[last]
    a = relaxations.channels_last(out.weight.expand(1, nb, -1), crown._shape(chain, last - 1))
    const = out.bias.expand(1, nb)
    for j in range(last - 1, layer, -1):
        a, const = relaxations.relu_back(a, const, relaxations.relax_lines(relaxes[j].maps))
        a, const = relaxations.back_full(a, const, chain.layers[j], crown._shape(chain, j - 1))
    return a[0]


def deeper(chain: C.Chain, ball: C.Ball, bounds: C.Bounds, relaxes: list[C.Relax]) -> torch.Tensor:
    """r*(R) of the margin when the layers after ``bounds`` get CROWN bounds again: the
    steps of ``certify.layer_bounds`` from a given layer on (which layer_bounds cannot
    do without recomputing, and so tightening, the layers before)."""
    bounds, relaxes = list(bounds), list(relaxes)
    for i in range(len(bounds), len(chain.layers) - 1):
        lo, hi = (t.contiguous() for t in crown._interval_step(chain.layers[i], *bounds[-1]))
        todo = ((lo < 0) & (hi > 0)).flatten(1).nonzero()
        win, neuron = todo[:, 0], todo[:, 1]
        layer = chain.layers[i]
        if isinstance(layer, C.Conv):
            views = crown._conv_views(chain, i, relaxes, ball)
            low, up = crown._crown_conv(chain, i, views, ball, win, neuron)
        else:
            w, b = layer.weight[neuron], layer.bias[neuron]
            rows, bias = torch.stack([w, -w]), torch.stack([b, -b])
            value, norm = crown._crown_full(chain, i, relaxes, ball, win, rows, bias)
            bound = value - ball.eps[win] * norm
            low, up = bound[0], -bound[1]
        flo, fhi = lo.flatten(1), hi.flatten(1)
        flo[win, neuron] = torch.maximum(flo[win, neuron], low)
        fhi[win, neuron] = torch.minimum(fhi[win, neuron], up)
        bounds.append((lo, hi))
        relaxes.append(C.Relax.of(lo, hi))
    value, norm = C.margin_form(chain, ball, relaxes)
    return value.double() / norm.double()


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--n", type=int, default=30)
    ap.add_argument("--fractions", default="1,0.6,0.4,0.25")
    args = ap.parse_args()
    nets = load_nets()
    with contextlib.redirect_stdout(io.StringIO()):
        w = sample_windows(nets, 30, 300)[::10][: args.n]
    pay = payoffs(nets.dr, w, nets.settings.delta_dr, AttackConfig()).payoff
    chain = C.detect_chain(nets.dr, threshold_logit(nets.settings.delta_dr))
    with torch.inference_mode():
        x = torch.from_numpy(np.ascontiguousarray(w, np.float32))
        z0 = C.centred(chain, x)
        r = C._start(chain, z0, pay, C.CertifyConfig())[0]
        ball = C.Ball(z0, r.float(), C._dim(chain), chain.subtract_mean)
        bounds, relaxes = C.layer_bounds(chain, ball, None, C.CertifyConfig.give_up)
        full = deeper(chain, ball, bounds, relaxes)
        print(f"{len(w)} windows; full CROWN certifies {int((full >= r).sum())} at their "
              f"first radius, median r*/R {float((full / r).median()):.2f}")  # fmt: skip
        for layer, name in ((2, "conv3"), (3, "conv4")):
            lam = influence(chain, relaxes, layer, len(w))
            ilo, ihi = crown._interval_step(chain.layers[layer], *bounds[layer - 1])
            unstable = ((ilo < 0) & (ihi > 0)).movedim(1, -1)
            score = (lam.abs() * (ihi - ilo).movedim(1, -1) * unstable).flatten(1)
            for frac in (float(f) for f in args.fractions.split(",")):
                k = (unstable.flatten(1).sum(1).float() * frac).long()
                keep = torch.zeros_like(score, dtype=torch.bool)
                for b in range(len(w)):
                    keep[b, score[b].topk(int(k[b])).indices] = True
                keep = keep.view_as(unstable).movedim(-1, 1)
                clo, chi = bounds[layer]
                lo = torch.where(keep, clo, ilo).contiguous()
                hi = torch.where(keep, chi, ihi).contiguous()
                mine = [*bounds[:layer], (lo, hi)]
                rs = deeper(chain, ball, mine, [*relaxes[:layer], C.Relax.of(lo, hi)])
                ok, med = int((rs >= r).sum()), float((rs / r).median())
                print(f"{name}: CROWN for {frac:4.0%} of its interval-unstable neurons "
                      f"({int(keep.sum())} of {int(unstable.sum())}): certifies {ok}, "
                      f"median r*/R {med:.2f}")  # fmt: skip


if __name__ == "__main__":
    main()
