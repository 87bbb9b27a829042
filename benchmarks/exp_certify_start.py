"""Where a certificate's first ball should go: the fit behind ``certify.START_MODEL``.

    python benchmarks/exp_certify_start.py [--frames 30] [--n 300] [--keep 0.88]

Takes bench_certify.py's 300 windows of the default video and 300 others of the same
pool (disjoint), their DeepFool payoffs, and for every window the bound's r*(R) at
radii R = s x r0 on a grid of s, where r0 is the quantile rule's first radius
(``CertifyConfig(start="quantile")``). A window's *frontier* is the geometric middle
of the largest s that certified (r*(R) >= R) and the next. Least squares of
log(frontier) on (1, log(r0/payoff), log(r_near/r0), log(r_far/r0)), fitted on the other
300 and checked on bench_certify's, gives START_MODEL once c0 is lowered by
log(``--keep``). Prints the coefficients, the residuals on both sets, and what share
of first balls certify at each ``keep``. It took 20 minutes here beside the test suite.
"""

from __future__ import annotations

import argparse
import math

import numpy as np
import torch
from bench_certify import window_pool

from lesmc.perception.attack_settings import AttackConfig, threshold_logit
from lesmc.perception.attacks import payoffs
from lesmc.perception.certify import (
    Ball,
    CertifyConfig,
    Chain,
    _dim,
    _start,
    ball_radius,
    centred,
    detect_chain,
    model_features,
    quantile_radii,
)
from lesmc.perception.cnn import load_nets
from lesmc.video.synth import SynthConfig

SCALES = (0.4, 0.5, 0.6, 0.7, 0.8, 0.9, 1.0, 1.15, 1.3, 1.5, 1.7, 2.0, 2.5)


def features(chain: Chain, w: np.ndarray, pay: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Per window: r0 (the quantile rule's first radius) and the fit's four features."""
    cfg = CertifyConfig(start="quantile")
    with torch.inference_mode():
        z0 = centred(chain, torch.from_numpy(w.astype(np.float32)))
        r0 = _start(chain, z0, pay, cfg)[0]  # the quantile rule's, at most seed x payoff
        near, _, far = quantile_radii(chain, z0, cfg)
        x = model_features(r0, near, far, torch.from_numpy(pay)).T.numpy()
    return r0.numpy(), x


def frontier(chain: Chain, w: np.ndarray, r0: np.ndarray) -> np.ndarray:
    """Per window, the geometric middle of the largest certifying scale and the next."""
    ok = np.zeros((len(w), len(SCALES)), bool)
    with torch.inference_mode():
        for a in range(0, len(w), 32):
            z0 = centred(chain, torch.from_numpy(w[a : a + 32].astype(np.float32)))
            for j, s in enumerate(SCALES):
                r = torch.from_numpy(r0[a : a + 32] * s).float()
                ball = Ball(z0, r, _dim(chain), chain.subtract_mean)
                rstar, _ = ball_radius(chain, ball, None, CertifyConfig().give_up)
                ok[a : a + 32, j] = (rstar >= r.double()).numpy()
    sc = np.array(SCALES)
    last = np.array([np.nonzero(o)[0].max() if o.any() else 0 for o in ok])
    return np.sqrt(sc[last] * sc[np.minimum(last + 1, len(sc) - 1)])


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--frames", type=int, default=SynthConfig.frames)
    ap.add_argument("--n", type=int, default=300)
    ap.add_argument("--keep", type=float, nargs="*", default=[0.8, 0.85, 0.88, 0.9, 0.95])
    args = ap.parse_args()
    nets = load_nets()
    chain = detect_chain(nets.dr, threshold_logit(nets.settings.delta_dr))
    pool = window_pool(nets, args.frames)
    bench = np.random.default_rng(0).choice(len(pool), min(args.n, len(pool)), replace=False)
    rest = np.setdiff1d(np.arange(len(pool)), bench)
    other = np.random.default_rng(1).choice(rest, min(args.n, len(rest)), replace=False)
    sets = {}
    for name, pick in (
        ("fit (other windows)", np.sort(other)),
        ("bench_certify's", np.sort(bench)),
    ):
        w = pool[pick]
        pay = payoffs(nets.dr, w, nets.settings.delta_dr, AttackConfig()).payoff
        keep = np.isfinite(pay)
        r0, x = features(chain, w[keep], pay[keep])
        sets[name] = (x, np.log(frontier(chain, w[keep], r0)))
        print(f"{name}: {keep.sum()} windows with a payoff")
    x_fit, y_fit = next(iter(sets.values()))
    coef, *_ = np.linalg.lstsq(x_fit, y_fit, rcond=None)
    print("fitted (c0, c_payoff, c_near, c_far):", np.round(coef, 4).tolist())
    for name, (x, y) in sets.items():
        resid = y - x @ coef
        shares = ", ".join(f"{k}: {np.mean(resid >= math.log(k)):.2f}" for k in args.keep)
        print(
            f"{name}: residual std {resid.std():.3f} mean {resid.mean():+.3f}; "
            f"first balls that certify at keep {shares}"
        )
    for k in args.keep:
        model = tuple(round(float(c), 4) for c in (coef[0] + math.log(k), *coef[1:]))
        print(f"keep {k}: START_MODEL = {model}")


if __name__ == "__main__":
    main()
